"""Every expression of a subject on one triangulation, defined in the template's texture space.

GPJA's meshes share the template's UV parametrisation (refinement splits UV edges exactly,
``gpja.register.remesh``), but each expression's refinement split different edges, so their vertex
samplings differ. The common triangulation is the template's own (V, F, UV, F_uv) refined by the same
UV-exact midpoint splits to a chosen vertex count, on the template's geometry, once per subject
(:func:`common_triangulation`). Each of its vertices is then located in an expression mesh by its texture
coordinate, which gives a face and barycentrics there, hence a 3-D position (:func:`remesh_onto`): the
paper's map between expressions through texture space.

- Seams: a vertex on a seam has one texture coordinate per chart. It exists once in 3-D; it is located
  through each of its charts, the positions must agree (:data:`SEAM_AGREEMENT_MM`), and it takes their mean.
- The mouth socket and other parts no camera saw are in the atlas like the rest and go through the same map.

The point location uses Open3D's closest-point queries on the UV triangles laid in the plane z = 0
(``gpja.surface``: one BVH for every query), then recomputes the barycentrics in float64 from the face it
found, so a point inside a UV triangle lands exactly on the float64 3-D triangle.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Sequence

import numpy as np

from gpja.errors import InputError
from gpja.mesh import TexturedMesh, unique_edges
from gpja.register.remesh import split_edges
from gpja.surface import prepare_surface

#: Texture coordinates of the common triangulation farther than this from the mesh's atlas (UV units: 1e-6 of
#: the texture's side) mean the mesh does not share the template's parametrisation.
UV_OFF_ATLAS = 1e-6
#: The charts of a seam vertex must put it within this distance of each other in 3-D (mm).
SEAM_AGREEMENT_MM = 1e-4
#: :func:`fit_triangulation` splits whole faces once a round leaves more than this share of the previous round's
#: bad edges (on S01's expressions red-green rounds keep 0.5-0.78 of them until only folds are left, then 0.9+).
STALLED = 0.85
#: Where :func:`chord_errors` looks inside each face besides its centre (barycentric weights of its corners), by
#: ``face_samples``: nowhere else (1), or halfway from the centre to each corner (4: a fold of the expression's
#: surface inside one face, which the centre misses, shows at one of those).
FACE_SAMPLES = {1: np.zeros((0, 3)),
                4: np.array([[2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])}
#: Growth per refinement round of :func:`common_triangulation` (the registration's own factor).
GROWTH_PER_ROUND = 2.5


def common_triangulation(template: TexturedMesh, vertices: int) -> TexturedMesh:
    """The template's triangulation refined to exactly ``vertices`` vertices (UV-exact midpoint splits of the
    longest edges, ``GROWTH_PER_ROUND`` at most per round; ties broken by edge order).

    Args:
        template: the subject's template (V (n, 3) mm, F, UV (k, 2), F_uv), which every registered
            expression's UVs refine.
        vertices: the wanted vertex count (at least the template's).
    Returns:
        A mesh whose F, UV and F_uv every remeshed expression shares; its V lies on the template, whose
        vertices come first.
    """
    if not template.has_uv:
        raise ValueError("the template has no texture coordinates")
    if vertices < len(template.V):
        raise ValueError(f"the common triangulation needs at least the template's {len(template.V)} vertices, "
                         f"got {vertices}")
    mesh = TexturedMesh(template.V, template.F, template.UV, template.F_uv)
    while len(mesh.V) < vertices:
        edges, _ = unique_edges(mesh.F)
        length = np.linalg.norm(mesh.V[edges[:, 0]] - mesh.V[edges[:, 1]], axis=1)
        # one new vertex per split edge: the longest ones, as many as this round may add
        count = min(vertices - len(mesh.V), int(np.ceil((GROWTH_PER_ROUND - 1.0) * len(mesh.V))), len(edges))
        split = np.zeros(len(edges), dtype=bool)
        split[np.argsort(-length, kind="stable")[:count]] = True
        mesh = split_edges(mesh, split)[0]
    return mesh


def barycentric_2d(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric weights (q, 3) float64 of points ``p`` in triangles (``a``, ``b``, ``c``), all (q, 2).

    Degenerate triangles get (1, 0, 0).
    """
    v0, v1, v2 = b - a, c - a, p - a
    d00 = (v0 * v0).sum(1)
    d01 = (v0 * v1).sum(1)
    d11 = (v1 * v1).sum(1)
    d20 = (v2 * v0).sum(1)
    d21 = (v2 * v1).sum(1)
    det = d00 * d11 - d01 * d01
    ok = np.abs(det) > 1e-30
    safe = np.where(ok, det, 1.0)
    w1 = np.where(ok, (d11 * d20 - d01 * d21) / safe, 0.0)
    w2 = np.where(ok, (d00 * d21 - d01 * d20) / safe, 0.0)
    return np.column_stack([1.0 - w1 - w2, w1, w2])


def segment_distance_2d(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(q,) float64 distance from points ``p`` to segments (``a``, ``b``), all (q, 2)."""
    ab = b - a
    t = np.clip(((p - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


def hash_uv(uv: np.ndarray) -> np.ndarray:
    """(q,) uint64 keys of texture coordinates (q, 2) float64, from their bits: the same bits, the same key.

    Sorting and searching uint64 is several times faster than complex (u + iv) or row-wise keys; distinct
    coordinates may share a key, so a lookup compares the coordinates too.
    """
    bits = np.ascontiguousarray(uv, dtype=np.float64).view(np.uint64)
    with np.errstate(over="ignore"):
        return bits[:, 0] * np.uint64(0x9E3779B97F4A7C15) ^ (bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)
                                                              + (bits[:, 1] >> np.uint64(29)))


@dataclass
class UVLocation:
    """Where texture coordinates lie in a mesh's atlas.

    Attributes:
        face: (q,) int64 face of the mesh.
        barycentric: (q, 3) float64 weights of its corners (each in [0, 1], summing to 1).
        distance: (q,) float64 distance from the query to that face, UV units (0 inside it).
    """

    face: np.ndarray
    barycentric: np.ndarray
    distance: np.ndarray


class UVIndex:
    """A mesh's UV triangles laid in the plane z = 0, prepared for point location (build once, query often).

    It remembers what it located: :func:`fit_triangulation` asks every round for texture coordinates of a
    triangulation that only grows (its new vertices are the last round's edge midpoints, and the edges beside
    the new faces were asked for before), so after the first round only what the last split made is looked up
    (the answers are the same either way: a location depends on the coordinate alone).
    """

    def __init__(self, mesh: TexturedMesh):
        if not mesh.has_uv:
            raise ValueError("the mesh has no texture coordinates")
        self.mesh = mesh
        lifted = np.column_stack([mesh.UV, np.zeros(len(mesh.UV))])
        self.surface = prepare_surface(lifted, mesh.F_uv, origin=np.array([0.5, 0.5, 0.0]), find_boundary=False)
        # located coordinates by their hash (sorted), the coordinates, and their answers in the same order
        self._keys = np.zeros(0, dtype=np.uint64)
        self._uv = np.zeros((0, 2))
        self._face, self._bary, self._distance = np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0)

    def locate(self, uv: np.ndarray) -> UVLocation:
        """Locate texture coordinates ``uv`` (q, 2) float64 (OBJ convention) in the mesh's UV triangles: the
        closest triangle, the query's float64 barycentrics in it (clipped to the triangle outside the atlas).
        Coordinates located before are answered from memory."""
        uv = np.ascontiguousarray(uv, dtype=np.float64).reshape(-1, 2)
        keys = hash_uv(uv)
        face = np.zeros(len(uv), dtype=np.int64)
        bary, distance = np.zeros((len(uv), 3)), np.zeros(len(uv))
        known = np.zeros(len(uv), dtype=bool)
        if len(self._keys):
            at = np.searchsorted(self._keys, keys).clip(max=len(self._keys) - 1)
            known = (self._keys[at] == keys) & (self._uv[at] == uv).all(axis=1)  # a hash collision is not known
            face[known], bary[known], distance[known] = (self._face[at[known]], self._bary[at[known]],
                                                         self._distance[at[known]])
        if not known.all():
            new_keys, first, inverse = np.unique(keys[~known], return_index=True, return_inverse=True)
            fresh_uv = uv[~known][first]
            fresh = self._locate(fresh_uv)
            exact = (uv[~known] == fresh_uv[inverse]).all(axis=1)
            rows = np.flatnonzero(~known)
            face[rows], bary[rows], distance[rows] = fresh.face[inverse], fresh.barycentric[inverse], fresh.distance[inverse]
            if not exact.all():  # two new coordinates share a hash: the others are located on their own
                alone = self._locate(uv[rows[~exact]])
                face[rows[~exact]], bary[rows[~exact]], distance[rows[~exact]] = (alone.face, alone.barycentric,
                                                                                  alone.distance)
            order = np.argsort(np.concatenate([self._keys, new_keys]), kind="stable")
            self._keys = np.concatenate([self._keys, new_keys])[order]
            self._uv = np.concatenate([self._uv, fresh_uv])[order]
            self._face = np.concatenate([self._face, fresh.face])[order]
            self._bary = np.concatenate([self._bary, fresh.barycentric])[order]
            self._distance = np.concatenate([self._distance, fresh.distance])[order]
        return UVLocation(face, bary, distance)

    def _locate(self, uv: np.ndarray) -> UVLocation:
        """:meth:`locate` without the memory."""
        hit = self.surface.closest(np.column_stack([uv, np.zeros(len(uv))]))
        tri = self.mesh.UV[self.mesh.F_uv[hit.face]]
        raw = barycentric_2d(uv, tri[:, 0], tri[:, 1], tri[:, 2])
        bary = np.clip(raw, 0.0, 1.0)
        bary /= bary.sum(axis=1, keepdims=True)
        distance = np.zeros(len(uv))
        outside = (raw < 0).any(axis=1)
        if outside.any():  # float64 distance to the face's nearest edge
            p, t = uv[outside], tri[outside]
            distance[outside] = np.min([segment_distance_2d(p, t[:, k], t[:, (k + 1) % 3]) for k in range(3)], axis=0)
        return UVLocation(hit.face, bary, distance)


def locate_uv(mesh: TexturedMesh, uv: np.ndarray) -> UVLocation:
    """Locate texture coordinates ``uv`` (q, 2) float64 in ``mesh``'s UV triangles (:class:`UVIndex`, built once)."""
    return UVIndex(mesh).locate(uv)


def positions_at_uv(mesh: TexturedMesh, location: UVLocation) -> np.ndarray:
    """(q, 3) float64 positions (mm) of located texture coordinates on ``mesh``'s surface."""
    return np.einsum("qk,qkc->qc", location.barycentric, mesh.V[mesh.F[location.face]])


def locate_on_atlas(mesh: TexturedMesh, uv: np.ndarray, source: str | Path, what: str,
                    index: UVIndex | None = None) -> UVLocation:
    """Locate texture coordinates ``uv`` (q, 2) that must lie in ``mesh``'s atlas (the mesh keeps the template's
    parametrisation, whose atlas every one of them lies in).

    Raises:
        InputError: ``mesh`` (named ``source``) is unusable, has no UVs, or misses one of ``uv`` (described by
            ``what``, e.g. "of the common triangulation") by more than :data:`UV_OFF_ATLAS`.
    """
    mesh.validate(source)
    if not mesh.has_uv:
        raise InputError(source, "the mesh has no texture coordinates: it must keep the template's UVs")
    location = (index or UVIndex(mesh)).locate(uv)
    off = float(location.distance.max(initial=0.0))
    if off > UV_OFF_ATLAS:
        worst = int(np.argmax(location.distance))
        raise InputError(source, f"texture coordinate {np.round(uv[worst], 6).tolist()} {what} is {off:.2g} UV units "
                                 "outside the mesh's atlas: the mesh does not share the template's texture "
                                 "parametrisation")
    return location


@dataclass
class Remeshed:
    """An expression on the common triangulation.

    Attributes:
        mesh: V (n, 3) float64 mm, and the common triangulation's F, UV, F_uv.
        seam_disagreement_mm: the largest 3-D distance between the positions a seam vertex's charts give.
        off_atlas_uv: the largest distance (UV units) from a common texture coordinate to the mesh's atlas.
    """

    mesh: TexturedMesh
    seam_disagreement_mm: float
    off_atlas_uv: float


def remesh_onto(common: TexturedMesh, mesh: TexturedMesh, source: str | Path = "mesh",
                index: UVIndex | None = None) -> Remeshed:
    """Put ``mesh`` (an expression with the template's parametrisation) on the ``common`` triangulation.

    Every texture coordinate of ``common`` is located in ``mesh``'s atlas (:func:`locate_uv`); each vertex
    of ``common`` takes the mean of the positions its corners' texture coordinates give.

    Args:
        index: ``UVIndex(mesh)``, when the caller keeps one.
    Raises:
        InputError: ``mesh`` (named ``source``) has no UVs, its atlas does not cover the common texture
            coordinates (another parametrisation), or a seam's charts disagree.
    """
    V, disagreement, off = positions_on(common, mesh, source, index)
    return Remeshed(TexturedMesh(V, common.F, common.UV, common.F_uv), disagreement, off)


def positions_on(common: TexturedMesh, mesh: TexturedMesh, source: str | Path = "mesh", index: UVIndex | None = None,
                 first: int = 0) -> tuple[np.ndarray, float, float]:
    """Where ``common``'s vertices ``first`` and on lie on ``mesh`` (:func:`remesh_onto`, which asks for all of them;
    :func:`fit_triangulation` asks for the vertices each round adds, which come last).

    Returns:
        (n - first, 3) float64 mm positions; the largest 3-D distance between the positions a seam vertex's charts
        give (mm); the largest distance from one of their texture coordinates to the mesh's atlas (UV units).
    Raises:
        InputError: as :func:`remesh_onto`.
    """
    n = len(common.V)
    corners_v, corners_uv = common.F.ravel().astype(np.int64), common.F_uv.ravel().astype(np.int64)
    if first:
        mine = corners_v >= first
        corners_v, corners_uv = corners_v[mine], corners_uv[mine]
    # each (vertex, uv) pair once: a seam vertex has one per chart
    keys = np.unique(corners_v * len(common.UV) + corners_uv)  # 1-D: far faster than axis=0
    pairs = np.column_stack([keys // len(common.UV) - first, keys % len(common.UV)])
    used, slot = np.unique(pairs[:, 1], return_inverse=True)
    location = locate_on_atlas(mesh, common.UV[used], source, "of the common triangulation", index)
    at_uv = positions_at_uv(mesh, location)[slot]  # (pairs, 3): one position per pair's texture coordinate
    counts = np.bincount(pairs[:, 0], minlength=n - first).astype(np.float64)
    if (counts == 0).any():
        raise ValueError(f"{int((counts == 0).sum())} vertices of the common triangulation are in no face")
    V = np.zeros((n - first, 3))
    np.add.at(V, pairs[:, 0], at_uv)
    V /= counts[:, None]
    disagreement = float(np.linalg.norm(at_uv - V[pairs[:, 0]], axis=1).max(initial=0.0))
    if disagreement > SEAM_AGREEMENT_MM:
        raise InputError(source, f"the charts of a seam vertex put it {disagreement:.3g} mm apart (more than "
                                 f"{SEAM_AGREEMENT_MM:g} mm): the mesh's seams do not follow the template's")
    return V, disagreement, float(location.distance.max(initial=0.0))


def edge_uv_midpoints(mesh: TexturedMesh) -> np.ndarray:
    """(e, 2) float64: for each edge of ``unique_edges(mesh.F)``, the texture coordinate of its midpoint
    (in the chart of one face that has it; a seam edge's charts map the midpoint to one 3-D point)."""
    edges, face_edge = unique_edges(mesh.F)
    mid = np.zeros((len(edges), 2))
    corner_uv = mesh.UV[mesh.F_uv]  # (m, 3, 2)
    for k in range(3):
        mid[face_edge[:, k]] = 0.5 * (corner_uv[:, k] + corner_uv[:, (k + 1) % 3])
    return mid


def offsets_at_uv(mesh: TexturedMesh, index: UVIndex, uv: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How far ``points`` (q, 3) float64 mm lie from where their texture coordinates ``uv`` (q, 2) land on
    ``mesh``: ((q,) along the normal of the face they land in, (q,) within its plane), float64 mm."""
    location = index.locate(uv)
    on_surface = positions_at_uv(mesh, location)
    corners = mesh.V[mesh.F[location.face]]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    offset = points - on_surface
    along = np.einsum("qc,qc->q", offset, normal)
    return np.abs(along), np.linalg.norm(offset - along[:, None] * normal, axis=1)


def inside_faces(corners: np.ndarray, face_samples: int) -> list[np.ndarray]:
    """The points :func:`chord_errors` checks inside each face, from its corners' values ``corners (f, 3, c)``:
    a list of (f, c) arrays, the centre first (a mean, so that ``face_samples`` 1 keeps the bits it always had),
    then the points :data:`FACE_SAMPLES` ``[face_samples]``."""
    return [corners.mean(axis=1)] + [np.einsum("k,fkc->fc", w, corners) for w in FACE_SAMPLES[face_samples]]


def chord_errors(common: TexturedMesh, meshes: Mapping[str, TexturedMesh] | Sequence[TexturedMesh],
                 indices: Mapping[str, UVIndex] | None = None, tangential_scale: float | None = None,
                 face_samples: int = 1) -> np.ndarray:
    """(e,) float64 mm: per edge of the common triangulation (``unique_edges(common.F)``), the largest error over
    ``meshes`` (by name, or a sequence; ``indices``: their :class:`UVIndex` by name) of the straight edge
    against the surface it stands for.

    - ``tangential_scale`` None: the distance between the point the edge's texture midpoint lands on and the
      midpoint of its two remeshed ends.
    - Otherwise that offset split along the landing face's normal and within its plane, the error being
      ``max(normal, tangential_scale * tangential)``; the same inside every face at the points
      :func:`inside_faces` (1: its texture centre, against the mean of its three remeshed corners; 4: also
      halfway from there to each corner), charged to the face's longest edge in that expression. The normal
      part is the surface's deviation; the tangential part only slides the texture, so it can be allowed more.
    """
    if not isinstance(meshes, Mapping):
        meshes = {f"mesh {i}": m for i, m in enumerate(meshes)}
    check_face_samples(face_samples)
    edges, face_edge = unique_edges(common.F)
    mid_uv = edge_uv_midpoints(common)
    everything = np.ones(len(edges), dtype=bool)
    worst = np.zeros(len(edges))
    for name, mesh in meshes.items():
        index = (indices or {}).get(name) or UVIndex(mesh)
        ends = remesh_onto(common, mesh, name, index).mesh.V
        worst = np.maximum(worst, expression_chord_errors(common, mesh, index, ends, edges, face_edge, mid_uv,
                                                          everything, tangential_scale, face_samples))
    return worst


def check_face_samples(face_samples: int) -> None:
    """Raise ValueError unless ``face_samples`` is a key of :data:`FACE_SAMPLES`."""
    if face_samples not in FACE_SAMPLES:
        raise ValueError(f"face_samples must be one of {sorted(FACE_SAMPLES)}, got {face_samples}")


def expression_chord_errors(common: TexturedMesh, mesh: TexturedMesh, index: UVIndex, ends: np.ndarray,
                            edges: np.ndarray, face_edge: np.ndarray, mid_uv: np.ndarray, which: np.ndarray,
                            tangential_scale: float | None, face_samples: int) -> np.ndarray:
    """(e,) float64 mm: :func:`chord_errors` against one expression, for the edges where ``which`` (e,) bool is set
    (0 elsewhere; an edge's error depends on its ends, its texture midpoint and the faces beside it alone).

    Args:
        ends: (n, 3) float64 mm, ``common``'s vertices on ``mesh`` (:func:`remesh_onto`).
        edges, face_edge: ``unique_edges(common.F)``; mid_uv: ``edge_uv_midpoints(common)``.
    """
    worst = np.zeros(len(edges))
    rows = np.flatnonzero(which)
    chord = 0.5 * (ends[edges[rows, 0]] + ends[edges[rows, 1]])
    if tangential_scale is None:
        worst[rows] = np.linalg.norm(positions_at_uv(mesh, index.locate(mid_uv[rows])) - chord, axis=1)
        return worst
    normal, tangential = offsets_at_uv(mesh, index, mid_uv[rows], chord)
    worst[rows] = np.maximum(normal, tangential_scale * tangential)
    # the faces beside those edges, each charged to its longest edge in this expression (the others' charges
    # land on edges outside ``which``, which the caller does not read)
    faces = np.flatnonzero(which[face_edge].any(axis=1))
    sides = face_edge[faces]
    length = np.linalg.norm(ends[edges[sides, 0]] - ends[edges[sides, 1]], axis=2)
    longest = sides[np.arange(len(faces)), np.argmax(length, axis=1)]
    for uv, points in zip(inside_faces(common.UV[common.F_uv[faces]], face_samples),
                          inside_faces(ends[common.F[faces]], face_samples)):
        normal, tangential = offsets_at_uv(mesh, index, uv, points)
        np.maximum.at(worst, longest, np.maximum(normal, tangential_scale * tangential))
    worst[~which] = 0.0
    return worst


class ChordErrorCache:
    """:func:`chord_errors` of a triangulation that only grows by :func:`~gpja.register.remesh.split_edges`,
    recomputed each round only where it changed: the edges of faces the last split made (the others keep their
    ends, texture midpoints and neighbouring faces, so their errors are the last round's to the bit), with the
    expressions' positions of the new vertices (which come last) alone located.

    Used by :func:`fit_triangulation`; what it returns equals :func:`chord_errors` of the same mesh
    (``tests/apply/test_remesh.py``).
    """

    def __init__(self, meshes: Mapping[str, TexturedMesh], tangential_scale: float | None, face_samples: int):
        check_face_samples(face_samples)
        self.meshes, self.tangential_scale, self.face_samples = meshes, tangential_scale, face_samples
        self.indices = {name: UVIndex(mesh) for name, mesh in meshes.items()}
        self._common: TexturedMesh | None = None
        self._ends: dict[str, np.ndarray] = {}
        self._edges = self._errors = None

    def errors(self, common: TexturedMesh) -> np.ndarray:
        """(e,) float64 mm per edge of ``unique_edges(common.F)``: :func:`chord_errors` of ``common``."""
        edges, face_edge = unique_edges(common.F)
        previous = self._common
        grown = previous is not None and len(common.V) >= len(previous.V) and \
            np.array_equal(common.V[: len(previous.V)], previous.V)
        first = len(previous.V) if grown else 0
        if grown:  # split_edges keeps every unsplit face; each face it makes has one of the vertices it appends
            fresh = np.zeros(len(edges), dtype=bool)
            fresh[face_edge[(common.F >= first).any(axis=1)].ravel()] = True
        else:
            fresh = np.ones(len(edges), dtype=bool)
        n = len(common.V)
        mid_uv = edge_uv_midpoints(common)
        worst = np.zeros(len(edges))
        for name, mesh in self.meshes.items():
            added, _, _ = positions_on(common, mesh, name, self.indices[name], first=first)
            ends = np.concatenate([self._ends[name], added]) if grown else added
            self._ends[name] = ends
            worst = np.maximum(worst, expression_chord_errors(common, mesh, self.indices[name], ends, edges, face_edge,
                                                              mid_uv, fresh, self.tangential_scale, self.face_samples))
        if grown:  # every other edge was an edge of the last round's triangulation: its error is the one kept
            keys, old_keys = edges[:, 0] * n + edges[:, 1], self._edges[:, 0] * n + self._edges[:, 1]
            kept = np.flatnonzero(~fresh)
            worst[kept] = self._errors[np.searchsorted(old_keys, keys[kept])]
        self._common, self._edges, self._errors = common, edges, worst
        return worst


def fit_triangulation(common: TexturedMesh, meshes: Mapping[str, TexturedMesh] | Sequence[TexturedMesh],
                      tolerance_mm: float,
                      max_vertices: int, max_rounds: int = 8,
                      progress: Callable[[str], None] = print,
                      tangential_tolerance_mm: float | None = None, face_samples: int = 1,
                      incremental: bool = True) -> TexturedMesh:
    """Split the common triangulation's edges whose chord misses any expression's surface by more than
    ``tolerance_mm`` (:func:`chord_errors`), round after round, until none is left, ``max_rounds`` have run, or
    the next round would pass ``max_vertices`` (then the worst edges are split up to it).

    ``tangential_tolerance_mm`` None: the whole offset of an edge's midpoint counts against ``tolerance_mm``.
    Otherwise the offset along the surface's normal, at edge midpoints and face centres, counts against
    ``tolerance_mm`` and the offset along the surface (where the texture lands) against
    ``tangential_tolerance_mm``: where the registration's parametrisation stretches between expressions (its
    untangling moves vertices along the surface), a flat patch needs no splitting for its texture to slide a
    tenth of a millimetre. ``face_samples``: where inside each face the normal offset is checked too
    (:func:`chord_errors`).

    A round splits the bad edges alone (each triangle's red-green template), which converges where a
    surface is smooth. Where an expression's surface is folded (crumpled parts no camera saw), the edges a
    red-green split makes (midpoint to opposite corner) cross the fold as the split one did, and the count of
    bad edges stalls; once a round leaves more than :data:`STALLED` of the previous round's bad edges, the next rounds
    split every edge of a face that has a bad edge (1-to-4), which halves the edges across the fold each round.

    ``incremental``: each round recomputes the errors only where the last split changed the triangulation
    (:class:`ChordErrorCache`; the same errors to the bit, a third to a half of the time on a subject's seven
    expressions, ``benchmarks/bench_triangulate.py``); False recomputes every edge every round (:func:`chord_errors`).
    """
    if not isinstance(meshes, Mapping):
        meshes = {f"mesh {i}": m for i, m in enumerate(meshes)}
    scale = None if tangential_tolerance_mm is None else tolerance_mm / tangential_tolerance_mm
    cache = ChordErrorCache(meshes, scale, face_samples)
    previous = None
    for round_ in range(max_rounds):
        errors = cache.errors(common) if incremental else chord_errors(common, meshes, cache.indices, scale, face_samples)
        split = errors > tolerance_mm
        count = int(split.sum())
        stalled = previous is not None and count > STALLED * previous
        progress(f"round {round_ + 1}: {len(common.V)} vertices, chord error max {errors.max():.3f} mm, "
                 f"{count} edges above {tolerance_mm:g} mm" + ("; splitting their faces 1-to-4" if stalled else ""))
        previous = count
        if stalled:
            _, face_edge = unique_edges(common.F)
            split = np.zeros_like(split)
            split[face_edge[(errors[face_edge] > tolerance_mm).any(axis=1)].ravel()] = True
        room = max_vertices - len(common.V)
        if not split.any() or room <= 0:
            break
        if split.sum() > room:  # the worst edges, as many as fit
            keep = np.argsort(-np.where(split, errors, -1.0))[:room]
            split = np.zeros_like(split)
            split[keep] = True
        common = split_edges(common, split)[0]
    return common
