"""Closest points, rims and normals of triangle meshes: one convention for every user.

The metrics (distances to a scan, correspondence on synthetic data), the NICP
baseline (correspondences, landmarks), the import check of external meshes and
the synthetic capture all query triangle meshes the same way, here.

Conventions:

* Closest points use Open3D's ``RaycastingScene.compute_closest_points``
  (a float32 BVH). Coordinates are shifted by an ``origin`` (by default the
  centre of the mesh's bounding box) before the float32 conversion, so float32
  keeps ~1e-5 mm resolution wherever the mesh sits; points and distances come
  back in float64, in the caller's frame.
* The rim (boundary) of a mesh: an edge is open when no other face shares it,
  after welding vertices at exactly the same position (scans saved with
  per-corner attributes repeat positions; unwelded, every edge of such a file
  would look open). Edges shared by three or more faces count as closed. A
  vertex is on the rim when it (or a copy at its position) ends an open edge.
* A closest point lies on the rim when it is on an open edge (the barycentric
  weight of the opposite corner is at most :data:`BARYCENTRIC_ON_EDGE`) or at
  a rim vertex (that corner's weight is at least ``1 - BARYCENTRIC_ON_EDGE``).
* Face and vertex numbering: edge ``k`` of a face joins its corners ``k`` and
  ``k + 1`` (as :func:`gpja.mesh.unique_edges`); barycentric weights are those
  of corners 0, 1, 2.
"""
from __future__ import annotations

import importlib
import sys
import types
from dataclasses import dataclass

import numpy as np

from gpja.mesh import TexturedMesh, unique_edges

#: A barycentric weight at most this small puts the closest point on the
#: opposite edge. Open3D clamps points in an edge's region exactly onto it;
#: the margin absorbs its float32 rounding (1e-4 of a ~1 mm triangle is 0.1 um).
BARYCENTRIC_ON_EDGE = 1e-4


# --- normals and areas ------------------------------------------------------------------------

def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals.

    Args:
        V: (n, 3) float64 positions (any length unit); F: (m, 3) int faces.
    Returns:
        (n, 3) float64 unit normals; zero for vertices of no face (or only degenerate ones).
    """
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.zeros_like(V)
    for k in range(3):
        for c in range(3):
            N[:, c] += np.bincount(F[:, k], weights=fn[:, c], minlength=len(V))
    return N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)


def vertex_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n,) float64 barycentric vertex areas (a third of each adjacent face), units of ``V (n, 3)`` squared."""
    fa = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    return np.bincount(F.ravel(), weights=np.repeat(fa / 3.0, 3), minlength=len(V))


# --- rim ----------------------------------------------------------------------------------------

def open_edges(F: np.ndarray) -> np.ndarray:
    """(m, 3) bool: edge k of each face (corners k, k+1) belongs to no other face.

    No welding (see :func:`rim` for that). Edges shared by three or more faces
    (non-manifold) count as closed.

    Args:
        F: (m, 3) int64 faces.
    """
    if len(F) == 0:
        return np.zeros((0, 3), dtype=bool)
    _, face_edge = unique_edges(F)
    return np.bincount(face_edge.ravel())[face_edge] == 1


def coincident_vertex_ids(V: np.ndarray) -> np.ndarray:
    """(n,) int64 id per vertex, shared by vertices at exactly the same position ``V (n, 3)``."""
    rows = np.ascontiguousarray(V, dtype=np.float64).view(np.dtype((np.void, 24))).ravel()
    _, ids = np.unique(rows, return_inverse=True)  # a 1-D unique of byte rows: ~2x faster than axis=0
    return ids.ravel().astype(np.int64)


def rim(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Open edges and rim vertices of a triangle mesh, coincident vertices welded first.

    Args:
        V: (n, 3) float64 positions; F: (m, 3) int64 faces.
    Returns:
        edge_open: (m, 3) bool, edge k of face f (corners k, k+1) is open.
        vertex_open: (n,) bool, the vertex (or a copy at its position) ends an open edge.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if len(V) == 0:
        return np.zeros(F.shape, dtype=bool), np.zeros(0, dtype=bool)
    ids = coincident_vertex_ids(V)
    F_welded = ids[F]
    edge_open = open_edges(F_welded)
    on_rim = np.zeros(int(ids.max()) + 1, dtype=bool)
    on_rim[F_welded[edge_open]] = True
    on_rim[np.roll(F_welded, -1, axis=1)[edge_open]] = True
    return edge_open, on_rim[ids]


# --- closest points -----------------------------------------------------------------------------

class _DeferredPackage(types.ModuleType):
    """A placeholder in ``sys.modules`` for a package not yet imported: the first attribute it does not have
    imports the real package (which replaces it in ``sys.modules`` and on its parent) and reads it there."""

    def __getattr__(self, name: str):
        sys.modules.pop(self.__name__, None)
        real = importlib.import_module(self.__name__)  # also binds it on the parent package
        self.__dict__.update(real.__dict__)
        return getattr(real, name)


def load_open3d():
    """The ``open3d`` module, imported without its visualisation package until something uses it.

    ``import open3d`` imports ``open3d.visualization``, whose web viewer imports plotly and dash: 0.4 of
    the 0.9 s a first query takes, in every job that queries a surface (``benchmarks/bench_startup.py``).
    gpja uses Open3D's ray-casting scene alone, so ``open3d.visualization`` is first registered as a
    :class:`_DeferredPackage` that imports the real one on first use. Should Open3D's layout not allow it
    (another version), the plain import serves.
    """
    if "open3d" in sys.modules:
        return sys.modules["open3d"]
    name = "open3d.visualization"
    placeholder = _DeferredPackage(name)
    sys.modules[name] = placeholder  # `import open3d.visualization` in open3d's __init__ finds it there
    try:
        import open3d
    except Exception:
        for module in [m for m in sys.modules if m == "open3d" or m.startswith("open3d.")]:
            del sys.modules[module]
        import open3d  # noqa: F811: the plain import, visualisation and all
        return open3d
    if sys.modules.get(name) is placeholder:
        open3d.visualization = placeholder
    return open3d


def raycasting_scene(V: np.ndarray, F: np.ndarray):
    """An Open3D ``RaycastingScene`` of the triangle mesh ``V (n, 3)``, ``F (m, 3)`` (stored as float32, uint32)."""
    o3d = load_open3d()

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(V, dtype=np.float32)),
                        o3d.core.Tensor(np.ascontiguousarray(F, dtype=np.uint32)))
    return scene


@dataclass
class Surface:
    """A triangle mesh prepared for closest-point queries (:func:`prepare_surface`).

    Attributes:
        V: (n, 3) float64 positions, mm; F: (m, 3) int64 faces.
        face_normals: (m, 3) float64 unit normals (zero for degenerate faces).
        boundary_edge: (m, 3) bool, edge k of face f (corners k, k+1) is open (:func:`rim`).
        boundary_vertex: (n,) bool, the vertex is on the rim (:func:`rim`).
        origin: (3,) float64 shift applied before the float32 conversion, mm.
        scene: Open3D ``RaycastingScene`` of ``V - origin``.
    """

    V: np.ndarray
    F: np.ndarray
    face_normals: np.ndarray
    boundary_edge: np.ndarray
    boundary_vertex: np.ndarray
    origin: np.ndarray
    scene: object

    def closest(self, P: np.ndarray) -> "ClosestPoints":
        """:func:`closest_points` of ``P (q, 3)`` float64 mm on this surface."""
        return closest_points(self, P)


@dataclass
class ClosestPoints:
    """Closest surface points of q query points.

    Attributes:
        point: (q, 3) float64 closest points, mm (Open3D's float32 answer, shifted back by the origin:
            within ~1e-5 mm of the surface; :func:`interpolate` gives points exactly on the float64 triangles).
        distance: (q,) float64 query-to-``point`` distance, mm.
        face: (q,) int64 triangle the closest point lies on.
        barycentric: (q, 3) float64 weights of the triangle's corners 0, 1, 2.
        normal: (q, 3) float64 unit normal of that triangle (zero if degenerate).
        on_boundary: (q,) bool, the closest point lies on an open edge or at a rim vertex
            (always False on a surface prepared with ``find_boundary=False``).
    """

    point: np.ndarray
    distance: np.ndarray
    face: np.ndarray
    barycentric: np.ndarray
    normal: np.ndarray
    on_boundary: np.ndarray


def bounding_box_centre(V: np.ndarray) -> np.ndarray:
    """(3,) float64 centre of the axis-aligned bounding box of ``V (n, 3)``."""
    return 0.5 * (V.min(axis=0) + V.max(axis=0))


def prepare_surface(V: np.ndarray, F: np.ndarray, origin: np.ndarray | None = None,
                    find_boundary: bool = True) -> Surface:
    """Build the closest-point structure of ``V (n, 3)`` mm, ``F (m, 3)``.

    Args:
        origin: (3,) mm subtracted before the float32 conversion; None = the bounding box's centre.
            Two surfaces queried together (e.g. a mesh and its scan) may share one.
        find_boundary: False for a surface whose rim no rule looks at: every edge counts as
            closed, saving the edge search.
    """
    o3d = load_open3d()

    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    origin = bounding_box_centre(V) if origin is None else np.asarray(origin, dtype=np.float64)
    if find_boundary:
        edge_open, boundary_vertex = rim(V, F)
    else:
        edge_open, boundary_vertex = np.zeros(F.shape, dtype=bool), np.zeros(len(V), dtype=bool)
    scene = raycasting_scene(V - origin, F)
    # Open3D builds its BVH lazily on the first query; one point builds it here
    # so that the query timings measure queries only.
    scene.compute_closest_points(o3d.core.Tensor(np.zeros((1, 3), dtype=np.float32)))
    normals = TexturedMesh(V, F).face_normals()
    return Surface(V, F, normals, edge_open, boundary_vertex, origin, scene)


def closest_points(surface: Surface, P: np.ndarray) -> ClosestPoints:
    """Closest points on ``surface`` of the query points ``P (q, 3)`` float64 mm."""
    o3d = load_open3d()

    P = np.asarray(P, dtype=np.float64)
    query = o3d.core.Tensor(np.ascontiguousarray(P - surface.origin, dtype=np.float32))
    ans = surface.scene.compute_closest_points(query)
    face = ans["primitive_ids"].numpy().astype(np.int64)
    uv = ans["primitive_uvs"].numpy().astype(np.float64)  # weights of corners 1 and 2
    bary = np.column_stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]])
    nearest = ans["points"].numpy().astype(np.float64) + surface.origin
    distance = np.linalg.norm(P - nearest, axis=1)
    return ClosestPoints(nearest, distance, face, bary, surface.face_normals[face],
                         lies_on_boundary(surface, face, bary))


def lies_on_boundary(surface: Surface, face: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """(q,) bool: the point with barycentrics ``bary (q, 3)`` in ``face (q,)`` is on an open edge or rim vertex.

    A point at a rim vertex may be reported in a triangle that touches the rim
    only at that vertex, hence the separate vertex test.
    """
    on = np.zeros(len(face), dtype=bool)
    corners = surface.F[face]
    for k in range(3):
        on |= surface.boundary_edge[face, k] & (bary[:, (k + 2) % 3] <= BARYCENTRIC_ON_EDGE)
        on |= surface.boundary_vertex[corners[:, k]] & (bary[:, k] >= 1.0 - BARYCENTRIC_ON_EDGE)
    return on


def interpolate(surface: Surface, hit: ClosestPoints, values: np.ndarray) -> np.ndarray:
    """Per-vertex ``values (n, c)`` interpolated at the closest points ``hit``: (q, c) float64.

    ``interpolate(surface, hit, surface.V)`` is the closest point recomputed in
    float64 from its barycentrics, exactly on the float64 triangle.
    """
    return np.einsum("qk,qkc->qc", hit.barycentric, np.asarray(values)[surface.F[hit.face]])
