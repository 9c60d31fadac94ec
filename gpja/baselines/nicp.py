"""Optimal-step non-rigid ICP (Amberg, Romdhani & Vetter, CVPR 2007): the geometric baseline.

The subject's template (the same mesh GPJA starts from) is deformed onto each
expression scan. Every template vertex ``v_i`` carries its own affine map
``X_i`` (4x3: ``x_i = X_i^T [v_i; 1]``); each iteration minimises

    sum_i a_i w_i |X_i^T v~_i - u_i|^2                 (data: closest scan point u_i)
  + alpha^2 sum_(i,j) in edges |G (X_i - X_j)|^2       (stiffness, G = diag(1, 1, 1, gamma))
  + beta^2 (A / L) sum_l |x_l - u_l|^2                  (landmarks x_l, see TemplateLandmarks)

in closed form: in Amberg's notation the least-squares solution of
``[alpha M (x) G; W D; beta D_L] X = [0; W U; U_L]``. We solve its normal
equations (a 4n x 4n sparse SPD system with three right-hand sides) with a
sparse Cholesky factor (cholespy / CHOLMOD), reused as a CG preconditioner
while the system changes little (:class:`AffineSolver`). For each stiffness
``alpha`` of a decreasing schedule, correspondences and solves alternate until
the mean vertex move of an iteration drops below ``convergence_mm``.

Scale invariance: positions are centred and divided by their RMS radius
before solving, so ``gamma = 1`` weighs translation and linear parts evenly;
data weights carry the vertex area ``a_i`` (normalised units), so a stiffness
means the same on a 2K- and a 16K-vertex template (the edge sum approximates a
Dirichlet energy, which does not depend on the resolution). ``A`` is the
template's area: ``beta = 1`` makes the landmarks weigh as much as the whole
dense data term. Roughly, a level of stiffness ``alpha`` follows deformations
whose length scale exceeds ``alpha`` head radii (~100 mm).

Correspondences are rejected (``w_i = 0``) when the closest scan point lies on
the scan's boundary (holes, the cropped neck and scalp: Amberg's rule, which
keeps the back of the head and the underside of the neck from being dragged
onto the scan's rim), when it is farther than ``max_distance_mm``, or when the
scan and template normals differ by more than ``max_normal_angle_deg`` (the
mouth interior, the far side of thin parts). Rejected vertices follow their
neighbours through the stiffness term.

Schedule (:data:`DEFAULT_STEPS`: alpha 0.06 -> 0.0075 halving, beta 1 -> 0.1),
tuned on the synthetic subject S01 (template -> 1_neutral, 2_smile) against
scan-to-mesh distance and the correspondence error measured with the ground
truth's rest coordinates. The template is the subject's own head fitted to
``3_mouth_stretch``, and the rigid stage already aligns the parts an
expression leaves alone (forehead, scalp, nose) to ~0.1 mm, so there is no
identity difference for the usual stiff, near-global levels (alpha >= 0.25)
to absorb. Worse, at those levels the jaw landmarks (mouth open -> closed
moves the chin ~40 mm) bend the whole head, and point-to-point data does not
resist the resulting tangential sliding: starting at alpha = 3 (beta 10) slid
the forehead and scalp 5-8 mm and gave a mean correspondence error of 7.3 mm,
against 1.5 mm when starting at 0.06, at the same scan-to-mesh distance
(0.17 mm). Starting at 0.06 keeps the landmark pull local to the jaw and
lips. The landmark weight halves with each level but stays at 0.1, not 0:
released, the landmarks drift 2 mm for a 0.01 mm better scan-to-mesh
distance. Detected landmarks are noisy; with 2 mm of Gaussian noise the
scan-to-mesh distance did not change and the correspondence error grew to
2.0 mm. Below alpha = 0.0075 the fit gains little (0.116 -> 0.101 mm at
0.004 in an earlier variant) while folds grow. The remaining folds (~50-100
edges more than the template) are where the template's open mouth is
closed: lip interior and under the chin. For a template of another person,
prepend stiffer levels (e.g. alpha 3, 1, 0.5, 0.25 with beta 1).

Why not ``trimesh.registration.nricp_amberg``: profiled (cProfile) on the 16K-
vertex synthetic template against a 208K-vertex scan, one iteration took
~29 s: ~18 s in ``trimesh.proximity.closest_point`` (an R-tree plus per-triangle
numpy), ~9 s in SuperLU (``spsolve`` of the normal equations, factorised from
scratch each iteration) and ~1.5 s building a ``lil_matrix``. It also has no
boundary rejection, and its stiffness depends on the mesh resolution. Open3D's
BVH closest points (~60 ms per query of 16K points) and the reused Cholesky
factor (~0.2-0.5 s per solve) make an iteration ~50x cheaper: ~9 s for a whole
registration on S01 (~30 iterations), on a shared 2-core machine.
"""
from __future__ import annotations

import os
import time
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import scipy.sparse as sp

from gpja.errors import InputError
from gpja.io import fill_path_pattern
from gpja.mesh import TexturedMesh, unique_edges

#: iBUG-68 points that an expression barely moves (nose bridge, nostrils, eye
#: corners): the rigid pre-alignment uses only these when 68 landmarks are given,
#: so an open-mouth template is not tilted towards a closed-mouth scan.
IBUG_STABLE = (27, 28, 29, 30, 31, 32, 33, 34, 35, 36, 39, 42, 45)
#: A landmark farther than this from the scan surface means landmarks and scan are
#: in different frames or units (GT and detected landmarks lie on the scan), mm.
LANDMARK_TO_SCAN_MAX_MM = 10.0


@dataclass(frozen=True)
class NicpStep:
    """One stiffness level of the schedule.

    Attributes:
        stiffness: alpha (normalised units; see the module docstring).
        landmark_weight: beta; 0 drops the landmark term.
        max_iterations: cap on correspondence/solve alternations at this level.
    """

    stiffness: float
    landmark_weight: float
    max_iterations: int


#: Default schedule (see the module docstring, "Schedule").
DEFAULT_STEPS = (
    NicpStep(0.06, 1.0, 8),
    NicpStep(0.03, 0.5, 10),
    NicpStep(0.015, 0.2, 10),
    NicpStep(0.0075, 0.1, 10),
)


@dataclass(frozen=True)
class NicpSettings:
    """Optimal-step NICP parameters.

    Attributes:
        steps: stiffness schedule, stiffest first.
        gamma: weight of the translation column in the stiffness term.
        max_distance_mm: reject correspondences farther than this.
        max_normal_angle_deg: reject correspondences whose normals differ by more.
        reject_boundary: reject closest points on the scan's boundary (holes, crops).
        convergence_mm: a level ends when the mean vertex move of an iteration drops below this.
        rigid_iterations: trimmed rigid ICP iterations after the landmark Procrustes.
        rigid_keep: fraction of the (valid) correspondences the rigid ICP keeps, closest first.
        similarity: let the pre-alignment scale the template (False: both are mm already).
    """

    steps: tuple[NicpStep, ...] = DEFAULT_STEPS
    gamma: float = 1.0
    max_distance_mm: float = 10.0
    max_normal_angle_deg: float = 60.0
    reject_boundary: bool = True
    convergence_mm: float = 0.02
    rigid_iterations: int = 10
    rigid_keep: float = 0.8
    similarity: bool = False

    def to_dict(self) -> dict:
        return asdict(self)


def settings_from_config(cfg: dict | None, source: str | Path = "config") -> NicpSettings:
    """NICP settings from a config mapping; missing keys keep their defaults.

    ``steps`` is a list of ``[stiffness, landmark_weight, max_iterations]`` (or
    mappings with those keys); every other key is a :class:`NicpSettings` field.

    Raises:
        InputError: an unknown key, or a malformed step.
    """
    cfg = dict(cfg or {})
    fields = set(NicpSettings.__dataclass_fields__)
    unknown = sorted(set(cfg) - fields)
    if unknown:
        raise InputError(source, f"unknown NICP setting(s) {', '.join(unknown)} (known: {', '.join(sorted(fields))})")
    if "steps" in cfg:
        steps = []
        for k, step in enumerate(cfg["steps"]):
            try:
                step = NicpStep(**step) if isinstance(step, dict) else NicpStep(*step)
                steps.append(NicpStep(float(step.stiffness), float(step.landmark_weight), int(step.max_iterations)))
            except (TypeError, ValueError):
                raise InputError(source, f"NICP step {k}: expected [stiffness, landmark_weight, max_iterations], "
                                         f"got {step!r}") from None
            if steps[-1].stiffness <= 0 or steps[-1].landmark_weight < 0 or steps[-1].max_iterations < 1:
                raise InputError(source, f"NICP step {k}: stiffness must be > 0, landmark weight >= 0, "
                                         f"iterations >= 1, got {step!r}")
        if not steps:
            raise InputError(source, "NICP needs at least one step")
        cfg["steps"] = tuple(steps)
    return NicpSettings(**cfg)


# --- geometry helpers ------------------------------------------------------------------------

def vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n, 3) float64 area-weighted unit vertex normals of ``V (n, 3)``, ``F (m, 3)``."""
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    n = np.zeros_like(V)
    for k in range(3):
        np.add.at(n, F[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def vertex_areas(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n,) float64 barycentric vertex areas (a third of each adjacent face), units of V squared."""
    fa = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    return np.bincount(F.ravel(), weights=np.repeat(fa / 3.0, 3), minlength=len(V))


def boundary_flags(F: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Which edges and vertices of a triangle mesh lie on its boundary.

    Returns:
        edge_open: (m, 3) bool, True where the edge opposite corner k of face f
            belongs to one face only.
        vertex_open: (n,) bool, True for vertices on a boundary edge.
    """
    # edge opposite corner k: (F[:, k+1], F[:, k+2])
    a = F[:, [1, 2, 0]].ravel()
    b = F[:, [2, 0, 1]].ravel()
    key = np.minimum(a, b) * np.int64(n_vertices) + np.maximum(a, b)
    _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
    open_ = counts[inverse] == 1
    vertex_open = np.zeros(n_vertices, dtype=bool)
    vertex_open[a[open_]] = True
    vertex_open[b[open_]] = True
    return open_.reshape(-1, 3), vertex_open


class ClosestPoints:
    """Closest-point queries on a triangle mesh (Open3D BVH), with boundary and normal data.

    Args:
        V: (n, 3) float64 positions, mm. F: (m, 3) int64 faces.
    """

    def __init__(self, V: np.ndarray, F: np.ndarray):
        import open3d as o3d

        self.V = np.asarray(V, dtype=np.float64)
        self.F = np.asarray(F, dtype=np.int64)
        self.scene = o3d.t.geometry.RaycastingScene()
        # Open3D's scene needs float32 positions and uint32 indices
        self.scene.add_triangles(self.V.astype(np.float32), self.F.astype(np.uint32))
        self.edge_open, self.vertex_open = boundary_flags(self.F, len(self.V))

    def query(self, P: np.ndarray, tol: float = 1e-4) -> dict[str, np.ndarray]:
        """Closest surface points to ``P (k, 3)`` (mm).

        Returns a dict of ``points`` (k, 3) float64 mm, ``normals`` (k, 3) float64
        face normals, ``faces`` (k,) int64, ``bary`` (k, 3) float64 and
        ``on_boundary`` (k,) bool: the closest point lies (within ``tol`` in
        barycentric units) on a boundary edge or at a boundary vertex.
        """
        r = self.scene.compute_closest_points(np.ascontiguousarray(P, dtype=np.float32))
        faces = r["primitive_ids"].numpy().astype(np.int64)
        uv = r["primitive_uvs"].numpy().astype(np.float64)
        bary = np.stack([1.0 - uv[:, 0] - uv[:, 1], uv[:, 0], uv[:, 1]], axis=1)
        # recompute the point in float64 from the barycentrics (Open3D returns float32)
        points = np.einsum("kj,kjd->kd", bary, self.V[self.F[faces]])
        near_zero = bary < tol
        on_edge = (near_zero & self.edge_open[faces]).any(axis=1)
        at_vertex = (~near_zero & self.vertex_open[self.F[faces]]) & (near_zero.sum(axis=1) == 2)[:, None]
        return {"points": points, "normals": r["primitive_normals"].numpy().astype(np.float64),
                "faces": faces, "bary": bary, "on_boundary": on_edge | at_vertex.any(axis=1)}


def similarity_transform(P: np.ndarray, Q: np.ndarray, weights: np.ndarray | None = None,
                         allow_scale: bool = False) -> tuple[float, np.ndarray, np.ndarray]:
    """Weighted Umeyama fit of ``Q ~ s R P + t``.

    Args:
        P, Q: (k, 3) float64 corresponding points, mm. weights: (k,) non-negative, or None.
        allow_scale: fit ``s``; otherwise ``s = 1`` (rigid).
    Returns:
        s (float), R (3, 3) proper rotation, t (3,) mm.
    """
    w = np.ones(len(P)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    cp, cq = w @ P, w @ Q
    P0, Q0 = P - cp, Q - cq
    C = (Q0 * w[:, None]).T @ P0
    U, S, Vt = np.linalg.svd(C)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (w @ (P0 ** 2).sum(axis=1))) if allow_scale else 1.0
    return s, R, cq - s * R @ cp


# --- correspondences -------------------------------------------------------------------------

def find_correspondences(target: ClosestPoints, X: np.ndarray, normals: np.ndarray, settings: NicpSettings
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest scan points of the deformed template and which of them to trust.

    Args:
        X: (n, 3) float64 current template positions, mm. normals: (n, 3) their unit normals.
    Returns:
        U: (n, 3) float64 closest scan points, mm; valid: (n,) bool; dist: (n,) float64 mm.
    """
    hit = target.query(X)
    U = hit["points"]
    dist = np.linalg.norm(U - X, axis=1)
    cos = np.einsum("ij,ij->i", normals, hit["normals"])
    valid = (dist <= settings.max_distance_mm) & (cos >= np.cos(np.radians(settings.max_normal_angle_deg)))
    if settings.reject_boundary:
        valid &= ~hit["on_boundary"]
    return U, valid, dist


# --- rigid pre-alignment ---------------------------------------------------------------------

@dataclass
class TemplateLandmarks:
    """Landmarks on the template, each carried by the affine maps of one template face.

    Attributes:
        faces: (L,) int64 the face each landmark belongs to.
        bary: (L, 3) float64 barycentric weights of the face's corners (those of
            the closest surface point).
        points: (L, 3) float64 the landmark positions, mm, template frame. They
            may lie off the surface where the template does not follow the scan
            it was fitted to (deep eye corners, the open mouth): the landmark is
            then the point ``p`` itself, moved by ``sum_k b_k X_k^T [p; 1]``,
            so its offset from the surface is kept rather than snapped away.
    """

    faces: np.ndarray
    bary: np.ndarray
    points: np.ndarray

    def __len__(self) -> int:
        return len(self.faces)


def rigid_align(V: np.ndarray, F: np.ndarray, target: ClosestPoints, landmarks: TemplateLandmarks,
                scan_landmarks: np.ndarray, settings: NicpSettings) -> tuple[np.ndarray, np.ndarray, dict]:
    """Landmark Procrustes, then trimmed rigid (or similarity) ICP.

    Args:
        V: (n, 3) float64 template positions, mm; F: (m, 3) faces.
        landmarks: the template's landmarks; scan_landmarks: (L, 3) float64 the same on the scan, mm.
    Returns:
        (n, 3) aligned template positions and (L, 3) aligned template landmark points, mm, and a log dict.
    """
    L = len(scan_landmarks)
    stable = np.array(IBUG_STABLE) if L == 68 else np.arange(L)
    P = landmarks.points
    s, R, t = similarity_transform(P[stable], scan_landmarks[stable], allow_scale=settings.similarity)
    area = vertex_areas(V, F)
    lm_w = np.full(len(stable), area.sum() / len(stable))  # landmarks weigh as much as the surface
    history = []
    for _ in range(settings.rigid_iterations):
        X = s * V @ R.T + t
        U, valid, dist = find_correspondences(target, X, vertex_normals(X, F), settings)
        if valid.sum() < 10:
            break
        keep = valid & (dist <= np.quantile(dist[valid], settings.rigid_keep))
        src = np.concatenate([V[keep], P[stable]])
        dst = np.concatenate([U[keep], scan_landmarks[stable]])
        w = np.concatenate([area[keep], lm_w])
        s, R, t = similarity_transform(src, dst, w, allow_scale=settings.similarity)
        history.append(float(dist[keep].mean()))
    P_aligned = s * P @ R.T + t
    lm_err = np.linalg.norm(P_aligned - scan_landmarks, axis=1)
    return s * V @ R.T + t, P_aligned, {"scale": s, "R": R.tolist(), "t": t.tolist(),
                                        "icp_mean_distance_mm": history, "landmark_error_mm": float(lm_err.mean())}


# --- the optimal-step system -----------------------------------------------------------------

def stiffness_matrix(F: np.ndarray, n: int, gamma: float) -> sp.csr_matrix:
    """(4n, 4n) ``(M^T M) (x) G^2``: sum over edges of ``|G (X_i - X_j)|^2`` as a quadratic form."""
    E, _ = unique_edges(F)
    e = len(E)
    M = sp.csr_matrix((np.r_[np.ones(e), -np.ones(e)], (np.r_[np.arange(e), np.arange(e)], np.r_[E[:, 0], E[:, 1]])),
                      shape=(e, n))
    return sp.kron(M.T @ M, sp.diags([1.0, 1.0, 1.0, gamma ** 2]), format="csr")


def block_diagonal(Vh: np.ndarray, w: np.ndarray) -> sp.csr_matrix:
    """(4n, 4n) ``D^T W D``: per vertex the 4x4 block ``w_i v~_i v~_i^T`` (``Vh (n, 4)`` homogeneous)."""
    n = len(Vh)
    blocks = w[:, None, None] * Vh[:, :, None] * Vh[:, None, :]
    rows = (4 * np.arange(n))[:, None, None] + np.arange(4)[None, :, None] + np.zeros((1, 1, 4), dtype=np.int64)
    cols = (4 * np.arange(n))[:, None, None] + np.arange(4)[None, None, :] + np.zeros((1, 4, 1), dtype=np.int64)
    return sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(4 * n, 4 * n))


def landmark_matrix(Ph: np.ndarray, F: np.ndarray, landmarks: TemplateLandmarks, n: int) -> sp.csr_matrix:
    """(L, 4n) ``D_L``: row l gives landmark l's position ``sum_k b_k X_(f_k)^T p~_l``.

    Args:
        Ph: (L, 4) homogeneous landmark points (normalised units); n: template vertex count.
    """
    L = len(landmarks)
    verts = F[landmarks.faces]  # (L, 3)
    rows = np.repeat(np.arange(L), 12)
    cols = (4 * verts[:, :, None] + np.arange(4)).ravel()
    vals = (landmarks.bary[:, :, None] * Ph[:, None, :]).ravel()
    return sp.csr_matrix((vals, (rows, cols)), shape=(L, 4 * n))


def factorize(H: sp.spmatrix):
    """A sparse Cholesky factor (CHOLMOD via cholespy) of SPD ``H (N, N)``; ``.solve(b, x)`` fills ``x``."""
    from cholespy import CholeskySolverD, MatrixType

    H = sp.csr_matrix(H)
    H.sum_duplicates()
    H.sort_indices()
    return CholeskySolverD(H.shape[0], H.indptr.astype(np.int32), H.indices.astype(np.int32),
                           H.data.astype(np.float64), MatrixType.CSR)


def solve_with(factor, B: np.ndarray) -> np.ndarray:
    """``H^-1 B`` for ``B (N, k)`` float64 with a factor from :func:`factorize`."""
    X = np.empty((B.shape[0], B.shape[1]))
    factor.solve(np.ascontiguousarray(B, dtype=np.float64), X)
    return X


def block_pcg(H: sp.spmatrix, B: np.ndarray, X0: np.ndarray, factor, rtol: float, max_iterations: int
              ) -> tuple[np.ndarray, int, bool]:
    """Conjugate gradients on the k columns of ``H X = B`` at once, preconditioned by ``factor``.

    ``factor`` is the Cholesky factor of a nearby SPD matrix (same stiffness
    structure, other weights or stiffness). Each column stops updating once its
    residual is below ``rtol`` times its right-hand side's norm.

    Returns:
        X (N, k) float64, the iterations used, and whether every column converged.
    """
    X = X0.copy()
    R = B - H @ X
    target = rtol * np.maximum(np.linalg.norm(B, axis=0), 1e-300)
    active = np.linalg.norm(R, axis=0) > target
    if not active.any():
        return X, 0, True
    Z = solve_with(factor, R)
    P = Z.copy()
    rz = np.einsum("ij,ij->j", R, Z)
    for it in range(1, max_iterations + 1):
        HP = H @ P
        step = np.where(active, rz / np.maximum(np.einsum("ij,ij->j", P, HP), 1e-300), 0.0)
        X += P * step
        R -= HP * step
        active &= np.linalg.norm(R, axis=0) > target
        if not active.any():
            return X, it, True
        Z = solve_with(factor, R)
        rz_new = np.einsum("ij,ij->j", R, Z)
        P = Z + P * np.where(active, rz_new / np.maximum(rz, 1e-300), 0.0)
        rz = rz_new
    return X, max_iterations, False


class AffineSolver:
    """Solves a sequence of nearby SPD systems, refactorising only when it pays.

    Consecutive optimal-step systems differ only in a few correspondence
    weights (within a stiffness level) or in the stiffness (a factor ``r`` away:
    preconditioned eigenvalues then lie in ``[1/r^2, 1]``). So the last
    Cholesky factor preconditions CG on the new system, which converges in a
    handful of solves (~35 ms each for 16K vertices) instead of a new
    factorisation (~2 s). When CG does not converge within ``max_cg``
    iterations the system is refactorised and solved directly.

    Args:
        rtol: CG's relative residual tolerance.
        max_cg: CG iterations before falling back to a factorisation.
        max_stiffness_ratio: refactorise when the stiffness changed more than this since the factor.
    """

    def __init__(self, rtol: float = 1e-6, max_cg: int = 30, max_stiffness_ratio: float = 3.0):
        self.rtol, self.max_cg, self.max_ratio = rtol, max_cg, max_stiffness_ratio
        self.factor = None
        self.factor_stiffness = None
        self.stats = {"factorizations": 0, "cg_solves": 0, "cg_iterations": 0, "cg_failures": 0,
                      "per_solve": []}  # CG iterations of each solve, or "factorize"

    def solve(self, H: sp.spmatrix, B: np.ndarray, X0: np.ndarray, stiffness: float) -> np.ndarray:
        """``H^-1 B`` for SPD ``H (N, N)``, ``B (N, k)``, warm-started at ``X0 (N, k)``."""
        near = (self.factor is not None and
                max(stiffness, self.factor_stiffness) <= self.max_ratio * min(stiffness, self.factor_stiffness))
        if near:
            X, its, ok = block_pcg(H, B, X0, self.factor, self.rtol, self.max_cg)
            self.stats["cg_solves"] += 1
            self.stats["cg_iterations"] += its
            self.stats["per_solve"].append(its)
            if ok:
                return X
            self.stats["cg_failures"] += 1
        self.factor = factorize(H)
        self.factor_stiffness = stiffness
        self.stats["factorizations"] += 1
        self.stats["per_solve"].append("factorize")
        return solve_with(self.factor, B)


@dataclass
class _Problem:
    """Normalised quantities fixed for one registration (positions scaled by ``1 / scale``)."""

    Vh: np.ndarray          # (n, 4) homogeneous normalised rest positions
    F: np.ndarray           # (m, 3)
    K: sp.csr_matrix        # (4n, 4n) stiffness quadratic form
    area: np.ndarray        # (n,) normalised vertex areas
    DL: sp.csr_matrix       # (L, 4n)
    UL: np.ndarray          # (L, 3) normalised scan landmarks
    center: np.ndarray      # (3,) mm
    scale: float            # mm per normalised unit


def prepare_problem(V: np.ndarray, F: np.ndarray, landmarks: TemplateLandmarks, P: np.ndarray,
                    scan_landmarks: np.ndarray, gamma: float) -> _Problem:
    """Normalise the (pre-aligned) template ``V (n, 3)`` and landmark points ``P (L, 3)``, mm,
    and build the fixed matrices."""
    center = V.mean(axis=0)
    scale = float(np.sqrt(((V - center) ** 2).sum(axis=1).mean()))
    Vn = (V - center) / scale
    Vh = np.c_[Vn, np.ones(len(V))]
    return _Problem(Vh=Vh, F=F, K=stiffness_matrix(F, len(V), gamma), area=vertex_areas(Vn, F),
                    DL=landmark_matrix(np.c_[(P - center) / scale, np.ones(len(P))], F, landmarks, len(V)),
                    UL=(scan_landmarks - center) / scale,
                    center=center, scale=scale)


def solve_affine(prob: _Problem, solver: AffineSolver, U: np.ndarray, w: np.ndarray, alpha: float, beta: float,
                 X_prev: np.ndarray) -> np.ndarray:
    """One optimal-step solve: the (4n, 3) affine maps minimising the energy for fixed correspondences.

    Args:
        U: (n, 3) normalised target points; w: (n,) data weights (area x validity).
        X_prev: (4n, 3) current maps: CG's warm start, and the target of a
            1e-8 pull that keeps the system definite even if every
            correspondence were rejected.
    """
    n = len(prob.Vh)
    A_tot = prob.area.sum()
    H = alpha ** 2 * prob.K + block_diagonal(prob.Vh, w)
    B = (w[:, None, None] * prob.Vh[:, :, None] * U[:, None, :]).reshape(4 * n, 3)
    if beta > 0 and prob.DL.shape[0]:
        lw = beta ** 2 * A_tot / prob.DL.shape[0]
        H = H + lw * (prob.DL.T @ prob.DL)
        B = B + lw * (prob.DL.T @ prob.UL)
    eps = 1e-8 * A_tot / n
    H = (H + eps * sp.eye(4 * n, format="csr")).tocsr()
    return solver.solve(H, B + eps * X_prev, X_prev, alpha)


def apply_affine(prob: _Problem, X: np.ndarray) -> np.ndarray:
    """(n, 3) deformed positions in mm from (4n, 3) affine maps."""
    n = len(prob.Vh)
    Xn = np.einsum("nk,nkd->nd", prob.Vh, X.reshape(n, 4, 3))
    return Xn * prob.scale + prob.center


# --- the registration ------------------------------------------------------------------------

def check_landmarks(points: np.ndarray, count: int | None, source: str | Path) -> np.ndarray:
    """(L, 3) float64 landmarks, or :class:`InputError` naming ``source`` (wrong shape or count, NaN)."""
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InputError(source, f"landmarks must be an (L, 3) array, got shape {P.shape}")
    if count is not None and len(P) != count:
        raise InputError(source, f"expected {count} landmarks, got {len(P)}")
    if len(P) < 3:
        raise InputError(source, f"at least 3 landmarks are needed for the rigid pre-alignment, got {len(P)}")
    if not np.isfinite(P).all():
        bad = int(np.argmax(~np.isfinite(P).all(axis=1)))
        raise InputError(source, f"landmarks contain NaN or infinite coordinates (first: landmark {bad})")
    return P


def vertex_landmarks(template: TexturedMesh, indices: np.ndarray, source: str | Path) -> TemplateLandmarks:
    """Landmarks at template vertices ``indices (L,)`` (e.g. FaceScape's TU-model landmark indices)."""
    lm = np.asarray(indices, dtype=np.int64)
    if len(lm) < 3:
        raise InputError(source, f"at least 3 landmarks are needed, got {len(lm)}")
    if lm.min() < 0 or lm.max() >= len(template.V):
        raise InputError(source, f"landmark vertex indices out of range [0, {len(template.V)}) "
                                 f"(min {lm.min()}, max {lm.max()})")
    face_of = np.full(len(template.V), -1)
    face_of[template.F.ravel()] = np.repeat(np.arange(len(template.F)), 3)  # any face of the vertex
    faces = face_of[lm]
    if (faces < 0).any():
        raise InputError(source, f"landmark vertex {int(lm[np.argmax(faces < 0)])} belongs to no face")
    bary = (template.F[faces] == lm[:, None]).astype(np.float64)
    return TemplateLandmarks(faces, bary, template.V[lm].copy())


def template_landmark_points(template: TexturedMesh, template_landmarks: np.ndarray, source: str | Path
                             ) -> TemplateLandmarks:
    """Attach landmarks to the template.

    Args:
        template_landmarks: (L,) integer vertex indices, or (L, 3) float
            positions, mm, in the template's frame (e.g. the landmarks of the
            expression the template was fitted to); each position is attached
            to the face of its closest surface point.
    Raises:
        InputError: indices out of range, NaN, or positions a median of more
        than ``LANDMARK_TO_SCAN_MAX_MM`` off the template (another frame or units).
    """
    lm = np.asarray(template_landmarks)
    if lm.ndim == 1 and np.issubdtype(lm.dtype, np.integer):
        return vertex_landmarks(template, lm, source)
    P = check_landmarks(lm, None, source)
    hit = ClosestPoints(template.V, template.F).query(P)
    gap = np.linalg.norm(hit["points"] - P, axis=1)
    if np.median(gap) > LANDMARK_TO_SCAN_MAX_MM:
        raise InputError(source, f"template landmarks lie a median {np.median(gap):.3g} mm off the template "
                                 f"(> {LANDMARK_TO_SCAN_MAX_MM:g} mm): not in the template's frame or units?")
    return TemplateLandmarks(hit["faces"], hit["bary"], P)


def check_landmarks_on_scan(target: ClosestPoints, landmarks: np.ndarray, source: str | Path) -> None:
    """Raise if landmarks ``(L, 3)`` mm lie far from the scan: another frame, or other units."""
    gap = np.linalg.norm(target.query(landmarks)["points"] - landmarks, axis=1)
    if np.median(gap) > LANDMARK_TO_SCAN_MAX_MM:
        raise InputError(source, f"landmarks lie a median {np.median(gap):.3g} mm off the scan surface "
                                 f"(> {LANDMARK_TO_SCAN_MAX_MM:g} mm): not in the scan's frame or units?")


def run_level(prob: _Problem, solver: AffineSolver, target: ClosestPoints, F: np.ndarray, step: NicpStep,
              settings: NicpSettings, X: np.ndarray, cur: np.ndarray, corr: tuple, timings: dict
              ) -> tuple[np.ndarray, np.ndarray, tuple, int, float]:
    """Alternate correspondences and solves at one stiffness until the vertices settle.

    Args:
        X: (4n, 3) current affine maps; cur: (n, 3) their positions, mm;
        corr: ``(U, valid, dist)`` correspondences of ``cur``.
    Returns:
        X, cur, the correspondences of the final ``cur``, iterations run, last mean move (mm).
    """
    its, moved = 0, float("nan")
    for its in range(1, step.max_iterations + 1):
        U, valid, _ = corr
        t = time.perf_counter()
        X = solve_affine(prob, solver, (U - prob.center) / prob.scale, prob.area * valid,
                         step.stiffness, step.landmark_weight, X)
        timings["solve"] += time.perf_counter() - t
        new = apply_affine(prob, X)
        moved = float(np.linalg.norm(new - cur, axis=1).mean())
        cur = new
        t = time.perf_counter()
        corr = find_correspondences(target, cur, vertex_normals(cur, F), settings)
        timings["closest_points"] += time.perf_counter() - t
        if moved < settings.convergence_mm:
            break
    return X, cur, corr, its, moved


def nicp(template: TexturedMesh, V_scan: np.ndarray, F_scan: np.ndarray, template_landmarks: np.ndarray,
         scan_landmarks: np.ndarray, settings: NicpSettings = NicpSettings(),
         progress: Callable[[str], None] = print, source: str | Path = "scan",
         landmark_source: str | Path = "scan landmarks") -> tuple[TexturedMesh, dict]:
    """Register ``template`` to a scan with landmark-guided optimal-step NICP.

    Args:
        template: the subject template (its F, UV, F_uv are kept exactly), positions mm.
        V_scan: (k, 3) float64 scan positions, mm, roughly in the template's frame.
        F_scan: (f, 3) int64 scan faces (open surfaces and holes are fine).
        template_landmarks: (L,) int vertex indices, or (L, 3) float64 positions
            in the template's frame, mm (see :func:`template_landmark_points`).
        scan_landmarks: (L, 3) float64 the same landmarks on the scan, mm.
        settings: schedule and rejection parameters.
        progress: called with one line for the rigid stage and one per stiffness level.
        source, landmark_source: name the scan and its landmarks in errors.
    Returns:
        The registered mesh (the template with new ``V``) and a JSON-able log.
    Raises:
        InputError: empty scan, NaN, a landmark count mismatch, landmarks off the scan.
    """
    t_start = time.perf_counter()
    V_scan = np.asarray(V_scan, dtype=np.float64)
    F_scan = np.asarray(F_scan, dtype=np.int64)
    TexturedMesh(V_scan, F_scan).validate(source)
    scan_landmarks = check_landmarks(scan_landmarks, None, landmark_source)
    landmarks = template_landmark_points(template, template_landmarks, "template landmarks")
    if len(landmarks) != len(scan_landmarks):
        raise InputError(landmark_source, f"{len(scan_landmarks)} landmarks, but the template has {len(landmarks)}")

    timings = {"closest_points": 0.0, "solve": 0.0}
    t = time.perf_counter()
    target = ClosestPoints(V_scan, F_scan)
    check_landmarks_on_scan(target, scan_landmarks, landmark_source)
    timings["build_target"] = time.perf_counter() - t

    t = time.perf_counter()
    F = template.F
    cur, P, rigid = rigid_align(template.V, F, target, landmarks, scan_landmarks, settings)
    timings["rigid"] = time.perf_counter() - t
    icp_last = rigid["icp_mean_distance_mm"][-1] if rigid["icp_mean_distance_mm"] else float("nan")
    progress(f"nicp rigid: landmark error {rigid['landmark_error_mm']:.2f} mm, trimmed ICP mean distance "
             f"{icp_last:.2f} mm ({timings['rigid']:.1f} s)")

    prob = prepare_problem(cur, F, landmarks, P, scan_landmarks, settings.gamma)
    X = np.tile(np.eye(4, 3), (len(cur), 1))  # identity affine per vertex: x_i = v_i
    solver = AffineSolver()
    corr = find_correspondences(target, cur, vertex_normals(cur, F), settings)
    steps_log = []
    for k, step in enumerate(settings.steps):
        t = time.perf_counter()
        X, cur, corr, its, moved = run_level(prob, solver, target, F, step, settings, X, cur, corr, timings)
        _, valid, dist = corr
        lm_err = np.linalg.norm((prob.DL @ X) * prob.scale + prob.center - scan_landmarks, axis=1)
        entry = {"stiffness": step.stiffness, "landmark_weight": step.landmark_weight, "iterations": its,
                 "last_move_mm": moved,
                 "mean_distance_mm": float(dist[valid].mean()) if valid.any() else float("nan"),
                 "matched_fraction": float(valid.mean()), "landmark_error_mm": float(lm_err.mean()),
                 "seconds": time.perf_counter() - t}
        steps_log.append(entry)
        progress(f"nicp step {k + 1}/{len(settings.steps)}: stiffness {step.stiffness:g}, landmark weight "
                 f"{step.landmark_weight:g}: {its} it, mean distance {entry['mean_distance_mm']:.3f} mm "
                 f"({100 * entry['matched_fraction']:.0f}% matched), landmark error "
                 f"{entry['landmark_error_mm']:.2f} mm, {entry['seconds']:.1f} s")
    timings["total"] = time.perf_counter() - t_start
    log_ = {"method": "nicp", "settings": settings.to_dict(), "vertices": len(cur), "scan_vertices": len(V_scan),
            "scan_faces": len(F_scan), "landmarks": len(landmarks), "rigid": rigid, "steps": steps_log,
            "solver": solver.stats, "seconds": timings}
    return template.with_vertices(cur), log_  # shares F, UV, F_uv (and the texture) with the template


# --- files -----------------------------------------------------------------------------------

def read_landmark_array(path: str | Path) -> np.ndarray:
    """The array stored in a landmark file, unchecked.

    Formats: ``.npz`` (key ``landmarks``), ``.npy``, ``.json`` (a list, or an
    object with a ``landmarks`` or ``indices`` list), anything else as text
    (one landmark per line; whitespace or commas).
    """
    from gpja.io import read_json

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "landmark file not found")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npz":
            with np.load(path) as data:
                if "landmarks" not in data.files:
                    raise InputError(path, f"no 'landmarks' array (keys: {', '.join(data.files) or 'none'})")
                return np.asarray(data["landmarks"])
        if suffix == ".npy":
            return np.load(path)
        if suffix == ".json":
            obj = read_json(path)
            if isinstance(obj, dict):
                key = next((k for k in ("landmarks", "indices") if k in obj), None)
                if key is None:
                    raise InputError(path, "expected a list, or an object with a 'landmarks' or 'indices' list")
                obj = obj[key]
            return np.asarray(obj)
        text = path.read_text(encoding="utf-8").replace(",", " ")
        rows = [line.split() for line in text.splitlines() if line.strip() and not line.lstrip().startswith("#")]
        return np.asarray(rows, dtype=np.float64)
    except InputError:
        raise
    except (ValueError, TypeError, OSError, EOFError, UnicodeDecodeError, zipfile.BadZipFile) as err:
        raise InputError(path, f"corrupt or unreadable landmark file ({type(err).__name__}: {err})") from None


def read_landmarks(path: str | Path, count: int | None = None) -> np.ndarray:
    """(L, 3) float64 landmark positions from a file (see :func:`read_landmark_array`), checked."""
    return check_landmarks(read_landmark_array(path), count, path)


def read_template_landmarks(path: str | Path) -> np.ndarray:
    """Template landmarks from a file: (L,) int64 vertex indices or (L, 3) float64 positions, mm.

    A 1-D list of whole numbers (or a one-column text file) is read as vertex
    indices, e.g. FaceScape's 68 TU-model landmark indices.
    """
    arr = read_landmark_array(path)
    flat = arr.reshape(-1) if arr.ndim == 2 and arr.shape[1] == 1 else arr
    if flat.ndim == 1:
        try:
            idx = flat.astype(np.float64)
        except (TypeError, ValueError):
            raise InputError(path, "landmark indices must be numbers") from None
        if not np.isfinite(idx).all() or (idx != np.round(idx)).any():
            raise InputError(path, "landmark indices must be whole numbers")
        return idx.astype(np.int64)
    return check_landmarks(arr, None, path)


def transform_points(P: np.ndarray, scale: float, R: np.ndarray | None, t: np.ndarray | None) -> np.ndarray:
    """``R (s P) + t`` for ``P (L, 3)`` (FaceScape's raw-to-aligned transform; R None = identity)."""
    P = scale * np.asarray(P, dtype=np.float64)
    return P if R is None else P @ np.asarray(R).T + np.asarray(t)


def run_nicp_files(template_dir: str | Path, scans_root: str | Path, subject: str, expression: str,
                   out_obj: str | Path, landmarks: str | Path, template_landmarks: str | Path | None = None,
                   template_expression: str = "3_mouth_stretch", rt_scale: str | Path | None = None,
                   settings: NicpSettings = NicpSettings(), progress: Callable[[str], None] = print) -> dict:
    """Register a subject's template to one expression scan with NICP; write OBJ + JSON log.

    Args:
        template_dir: the subject's template folder (template.obj, texture.png, ...).
        scans_root: ``{scans_root}/{subject}/{expression}.ply``.
        out_obj: the registered mesh's OBJ; its log goes next to it as ``.json``.
        landmarks: pattern of the scan landmark files, with ``{subject}`` and
            ``{expression}`` placeholders (e.g. the synthetic ground truth
            ``.../ground_truth/{subject}/{expression}.npz``, or 68x3 JSON/TXT
            files of detected landmarks). Points are in the scan file's frame:
            ``rt_scale`` moves them with the scan.
        template_landmarks: pattern (``{subject}``) of a file of template landmark
            vertex indices or positions in the template's frame; None takes the
            ``landmarks`` file of ``template_expression`` (the expression the
            template was fitted to) and snaps it onto the template.
        rt_scale: FaceScape's ``Rt_scale_dict.json``; None when scans are in mm already.
    Returns:
        The log written next to the OBJ.
    """
    from gpja.data.facescape import read_rt_scale, read_scan, scan_path
    from gpja.register.pipeline import check_units, read_template, write_registration

    subject = str(subject)
    template_dir = Path(template_dir)
    template, _ = read_template(template_dir)

    def aligned(expr: str) -> tuple[float, np.ndarray | None, np.ndarray | None]:
        return read_rt_scale(rt_scale, subject, expr) if rt_scale is not None else (1.0, None, None)

    s, R, t = aligned(expression)
    scan = read_scan(scan_path(scans_root, subject, expression), s, R, t)
    check_units(template, scan.V, scan.path)
    lm_path = fill_path_pattern(landmarks, subject, expression)
    scan_lm = transform_points(read_landmarks(lm_path), s, R, t)
    if template_landmarks is None:
        tl_path = fill_path_pattern(landmarks, subject, template_expression)
        tmpl_lm = transform_points(read_landmarks(tl_path), *aligned(template_expression))
    else:
        tl_path = fill_path_pattern(template_landmarks, subject, template_expression)
        tmpl_lm = read_template_landmarks(tl_path)
    if len(tmpl_lm) != len(scan_lm):
        raise InputError(lm_path, f"{len(scan_lm)} landmarks, but the template's landmark file {tl_path} has {len(tmpl_lm)}")
    try:
        mesh, log_ = nicp(template, scan.V, scan.F, tmpl_lm, scan_lm, settings, progress=progress,
                          source=scan.path, landmark_source=lm_path)
    except InputError as err:
        if err.path == "template landmarks":
            raise InputError(tl_path, err.problem) from None
        raise
    log_.update(subject=subject, expression=expression, template=str(template_dir / "template.obj"),
                scan=str(scan.path), landmarks_file=str(lm_path), template_landmarks_file=str(tl_path),
                rt_scale=None if rt_scale is None else str(rt_scale))
    texture_ref = os.path.relpath(template_dir / "texture.png", Path(out_obj).parent)
    write_registration(mesh, log_, out_obj, texture_ref)
    return log_
