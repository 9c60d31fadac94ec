"""The tangential hold (beyond the paper, ``Schedule.hold_tangential``): what the first phase left in place stays there.

Measured on the synthetic benchmark (docs/experiments.md, "Issue 15: the tangential hold"): most of
a face does not move between two expressions (the template itself, left unmoved, scores a median
correspondence error of 0.00 mm on ``1_neutral``, nose 0.04), yet GPJA moved it. Registering the
template to its own expression slides the nose 1.0 mm, and on a closed-mouth expression the neck
slides 3-5 mm after the jaw. Nothing in the paper's energy charges a surface for sliding along
itself where it has no texture: depth and normals are blind to it, and every step is smoothed by
``(I + lambda L)^-1`` over many edges, so the jaw's motion spreads into the neck.

The hold is a weak spring on that sliding. After the warm-up (which moves the lips and the jaw),
each vertex gets a weight from how far the warm-up moved it: 1 where it moved less than
``hold_moved_mm[0]``, 0 beyond ``hold_moved_mm[1]``, linear in between, then smoothed once by the
first level's ``(I + lambda L)^-1``. At every iteration of the levels, a held vertex loses
``hold_tangential x weight`` of its tangential offset from its *starting* position (the component
in the plane of its starting normal), so motion along the normal (onto the scan) is free, the
warm-up's own drift is pulled back, and what the warm-up moved far (the mouth, a jaw) moves freely.
The correction is applied to the LargeSteps variable as ``u += (I + lambda L) dx``, so the vertices
move by exactly ``dx``. New vertices of a refinement inherit the mean start, normal and weight of
their edge's ends, as their position does.

Without a warm-up (``warmup_iterations: 0``, the default since the flow stage), the first flow stage
plays its part: it moves the lips and the jaw onto the references' and leaves the rest nearly in
place, so its displacement gives the weights. The hold then stays through the later flow stages (their
slides of held parts are pulled back in the next level). With neither (the colour constraint off, or
both at 0) there is nothing to tell moving parts from still ones, and the hold stays off.

The first phase's motion under-reports what an expression moves: cheeks and a chin it hardly moved
may still have millimetres to go. With ``hold_gap_mm`` the target's scan says so, without the
ground truth: per vertex of the starting surface, its gap to the scan as the views see it
(:func:`scan_gap`), and the weight is multiplied by a second ramp, 1 at or below ``held`` mm, 0 at
or beyond ``free`` mm (:func:`gap_factor`).

Edge springs (``Schedule.spring_rate``, beyond the paper, off by default): inside a region of uniform
colour (a lip) nothing in the energy says which material lies where, and the held weights are 0
where the expression moves. The springs keep the material's spacing there: at every iteration each
edge gives back ``spring_rate`` of its length change from the start, split between its two ends,
each vertex taking the mean over its edges (:func:`edge_spring_step`; a Jacobi step of position-based
dynamics' distance constraint), in the plane of its starting normal, so the depth fit along the normal
is untouched. They ride on the same start as the hold, carried through refinement the same way.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from gpja.mesh import TexturedMesh, unique_edges
from gpja.register.hra import ExpressionTargets
from gpja.register.largesteps import SmoothingSolver
from gpja.register.laplacian import system_matrix
from gpja.register.remesh import refine_carrying
from gpja.render.normals import tangential_part, vertex_normals


def hold_weights(start: np.ndarray, moved: np.ndarray, F: np.ndarray, lam: float,
                 moved_mm: tuple[float, float]) -> np.ndarray:
    """Per-vertex hold weight from how far a first phase moved each vertex.

    Args:
        start: (n, 3) float64 positions before it, mm; moved: (n, 3) after it, mm.
        F: (m, 3) int64 faces. lam: the smoothing's lambda (the first level's).
        moved_mm: (held, free): displacement (mm) at or below which the weight is 1, at or above which 0.
    Returns:
        (n,) float64 in [0, 1], smoothed by ``(I + lam L)^-1``.
    """
    held, free = moved_mm
    distance = np.linalg.norm(np.asarray(moved) - np.asarray(start), axis=1)
    raw = np.clip((free - distance) / (free - held), 0.0, 1.0)
    if lam > 0:
        solver = SmoothingSolver(system_matrix(np.asarray(start, dtype=np.float64), F, lam))
        raw = solver.solve(torch.from_numpy(raw[:, None])).numpy()[:, 0]
    return np.clip(raw, 0.0, 1.0)


def edge_spring_step(x: torch.Tensor, rest: torch.Tensor, edges: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """The move that gives every edge back its rest length, each vertex taking the mean of its edges' shares.

    Per edge (i, j): ``c = (|x_i - x_j| - |r_i - r_j|) / (2 |x_i - x_j|) (x_i - x_j)``; i moves by ``-c``,
    j by ``+c`` (alone, that edge would get exactly its rest length back). Each vertex's sum is divided by
    its edge count, then projected onto the plane of its normal.

    Args:
        x: (n, 3) current positions, mm. rest: (n, 3) rest positions, mm (same dtype).
        edges: (e, 2) int64 unique vertex pairs. normals: (n, 3) unit normals of the plane each move
            is kept in.
    Returns:
        (n, 3) move, mm, dtype of ``x``; zero where no edge changed length (a rigid motion of ``rest``).
    """
    i, j = edges[:, 0], edges[:, 1]
    e = x[i] - x[j]
    length = e.norm(dim=1, keepdim=True).clamp_min(1e-12)
    rest_length = (rest[i] - rest[j]).norm(dim=1, keepdim=True)
    c = 0.5 * (length - rest_length) / length * e
    move = torch.zeros_like(x).index_add_(0, i, -c).index_add_(0, j, c)
    ones = torch.ones_like(length)
    degree = torch.zeros(len(x), 1, dtype=x.dtype).index_add_(0, i, ones).index_add_(0, j, ones)
    move = move / degree.clamp_min(1.0)
    return tangential_part(move, normals)


#: A view counts in :func:`scan_gap` where the surface faces it at least this much (cos of normal and
#: view direction) and the scan covers the whole pixel (coverage at least ``SCAN_GAP_COVERAGE``).
SCAN_GAP_MIN_COS, SCAN_GAP_COVERAGE = 0.3, 0.999


def scan_gap(V: np.ndarray, F: np.ndarray, targets: ExpressionTargets) -> np.ndarray:
    """Per-vertex gap (mm) between a surface and the target's scan, as the views see it.

    In every view that sees the vertex (inside the image, facing the camera by at least
    ``SCAN_GAP_MIN_COS``, on a pixel the scan fully covers): ``|z - scan depth| x cos``, the camera-depth
    difference brought to the surface's normal (a surface parallel to the scan, ``d`` mm off, gives
    ``d`` in every view). The median over those views; no occlusion test, so a vertex hidden behind
    another part in some view counts that view's larger gap, which the median outvotes.

    Args:
        V: (n, 3) float64 positions, mm. F: (m, 3) int64 faces.
        targets: the expression's cameras and scan ``depth`` (B, H, W, 1) mm, ``coverage`` (B, H, W, 1).
    Returns:
        (n,) float64 gap, mm; NaN where no view sees the vertex.
    """
    V = np.asarray(V, dtype=np.float64)
    normals = vertex_normals(torch.from_numpy(V), torch.from_numpy(np.asarray(F, dtype=np.int64))).numpy()
    gaps = np.full((len(targets.cameras), len(V)), np.nan)
    for b, camera in enumerate(targets.cameras):
        depth = targets.depth[b, ..., 0].numpy().astype(np.float64)
        coverage = targets.coverage[b, ..., 0].numpy().astype(np.float64)
        h, w = depth.shape
        xy, z = camera.project(V)
        inside = np.isfinite(xy).all(axis=1) & (z > 0) & (xy[:, 0] >= 0) & (xy[:, 0] <= w - 1) \
            & (xy[:, 1] >= 0) & (xy[:, 1] <= h - 1)
        pix = np.rint(np.where(inside[:, None], xy, 0.0)).astype(np.int64)
        to_camera = camera.center[None, :] - V
        cos = (normals * to_camera).sum(axis=1) / np.linalg.norm(to_camera, axis=1).clip(1e-12)
        seen = inside & (cos >= SCAN_GAP_MIN_COS) & (coverage[pix[:, 1], pix[:, 0]] >= SCAN_GAP_COVERAGE)
        gaps[b, seen] = np.abs(z[seen] - depth[pix[seen, 1], pix[seen, 0]]) * cos[seen]
    out = np.full(len(V), np.nan)
    any_view = np.isfinite(gaps).any(axis=0)
    out[any_view] = np.nanmedian(gaps[:, any_view], axis=0)
    return out


def gap_factor(gap: np.ndarray, gap_mm: tuple[float, float]) -> np.ndarray:
    """(n,) float64 in [0, 1]: 1 at or below ``gap_mm[0]`` mm, 0 at or beyond ``gap_mm[1]``, linear between;
    1 where the gap is unknown (NaN: no view sees the vertex, nothing says it moves)."""
    held, free = gap_mm
    ramp = np.clip((free - np.asarray(gap, dtype=np.float64)) / (free - held), 0.0, 1.0)
    return np.where(np.isfinite(gap), ramp, 1.0)


def mouth_factor(V: np.ndarray, socket: np.ndarray, mouth_mm: tuple[float, float]) -> np.ndarray:
    """(n,) float64 in [0, 1]: 0 within ``mouth_mm[0]`` mm of the nearest socket vertex, 1 from ``mouth_mm[1]`` mm on,
    linear between (straight-line distance on the start's positions ``V`` (n, 3) mm; ``socket``: (n,) bool, e.g.
    :func:`gpja.register.flow.socket_vertices`). 1 everywhere when there is no socket vertex."""
    free, held = mouth_mm
    if not np.any(socket):
        return np.ones(len(V))
    from scipy.spatial import cKDTree

    distance = cKDTree(np.asarray(V)[socket]).query(np.asarray(V), k=1)[0]
    return np.clip((distance - free) / (held - free), 0.0, 1.0)


@dataclass
class TangentialHold:
    """The spring of the hold on one mesh's vertices.

    Attributes:
        start: (n, 3) float64 starting positions, mm.
        normals: (n, 3) float64 unit vertex normals of the starting surface.
        weight: (n,) float64 in [0, 1] (:func:`hold_weights`).
        rate: fraction of a fully held vertex's tangential offset removed per iteration.
        spring_rate: fraction of each edge's length change from ``start`` given back per iteration
            (:func:`edge_spring_step`; 0 = no springs).
        edges: (e, 2) int64 unique edges of the mesh the hold is on (needed when ``spring_rate`` > 0).
    """

    start: np.ndarray
    normals: np.ndarray
    weight: np.ndarray
    rate: float
    spring_rate: float = 0.0
    edges: np.ndarray | None = None
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    @classmethod
    def after_first_phase(cls, start: TexturedMesh, moved: TexturedMesh, lam: float, rate: float,
                          moved_mm: tuple[float, float], gap: np.ndarray | None = None,
                          gap_mm: tuple[float, float] | None = None, spring_rate: float = 0.0,
                          factor: np.ndarray | None = None) -> "TangentialHold":
        """The hold of a registration that started at ``start`` and was at ``moved`` after its first phase
        (the warm-up, or without one the first flow stage); with ``gap`` ((n,) mm, :func:`scan_gap` of
        ``start``) and ``gap_mm``, the weights are also multiplied by :func:`gap_factor`; with ``factor``
        ((n,) in [0, 1], e.g. :func:`mouth_factor`), by that too; with ``spring_rate`` > 0, edge springs to
        ``start``'s edge lengths as well."""
        normals = vertex_normals(torch.from_numpy(start.V), torch.from_numpy(start.F)).numpy()
        weight = hold_weights(start.V, moved.V, start.F, lam, moved_mm)
        if gap is not None and gap_mm is not None:
            weight = weight * gap_factor(gap, gap_mm)
        if factor is not None:
            weight = weight * np.asarray(factor, dtype=np.float64)
        return cls(start.V.copy(), normals, weight, float(rate), float(spring_rate), unique_edges(start.F)[0])

    def reanchored(self, V: np.ndarray, F: np.ndarray, weight: np.ndarray) -> "TangentialHold":
        """This hold with the vertices where ``weight`` (n,) in [0, 1] is above 0 anchored at ``V`` (n, 3) mm (their
        normals ``V``'s, faces ``F``) and held at least that much; the others keep their start, normal and weight
        (``Schedule.hold_mouth_at_flow_mm``: the mouth held where the last flow stage put it)."""
        weight = np.asarray(weight, dtype=np.float64)
        moved = weight > 0
        normals = vertex_normals(torch.from_numpy(np.asarray(V, dtype=np.float64)), torch.from_numpy(F)).numpy()
        start, unit = self.start.copy(), self.normals.copy()
        start[moved], unit[moved] = np.asarray(V, dtype=np.float64)[moved], normals[moved]
        return TangentialHold(start, unit, np.maximum(self.weight, weight), self.rate, self.spring_rate, self.edges)

    @property
    def held_fraction(self) -> float:
        """Fraction of the vertices held with weight above 0.5."""
        return float(np.mean(self.weight > 0.5))

    def refine(self, mesh: TexturedMesh, factor: float) -> tuple[TexturedMesh, "TangentialHold"]:
        """``refine_by_factor(mesh, factor)`` and this hold on the refined vertices."""
        rows = np.concatenate([self.start, self.normals, self.weight[:, None]], axis=1)
        refined, rows = refine_carrying(mesh, factor, rows)
        normals = rows[:, 3:6] / np.linalg.norm(rows[:, 3:6], axis=1, keepdims=True).clip(1e-12)
        return refined, TangentialHold(rows[:, :3], normals, rows[:, 6], self.rate, self.spring_rate,
                                       unique_edges(refined.F)[0])

    def _tensors(self, dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """start, normals, weight (n, 1) as tensors of ``dtype``, converted once (called every iteration)."""
        if dtype not in self._cache:
            self._cache[dtype] = (torch.as_tensor(self.start, dtype=dtype), torch.as_tensor(self.normals, dtype=dtype),
                            torch.as_tensor(self.weight, dtype=dtype)[:, None])
        return self._cache[dtype]

    def correction(self, x: torch.Tensor) -> torch.Tensor:
        """The move ``dx`` (n, 3) (dtype of ``x``, mm) that removes ``rate x weight`` of each vertex's
        tangential offset from its start, then (with springs) gives back ``spring_rate`` of the edges'
        length changes from there (:func:`edge_spring_step`); ``x``: (n, 3) current positions, mm."""
        start, normals, weight = self._tensors(x.dtype)
        offset = x.detach() - start
        dx = -self.rate * weight * tangential_part(offset, normals)
        if self.spring_rate > 0:
            if "edges" not in self._cache:
                self._cache["edges"] = torch.as_tensor(self.edges, dtype=torch.int64)
            dx = dx + self.spring_rate * edge_spring_step(x.detach() + dx, start, self._cache["edges"], normals)
        return dx
