"""The optimal-step NICP system (Amberg et al. 2007) and its sparse solver.

Every template vertex ``i`` carries an affine map ``X_i`` (4x3); for fixed
correspondences the energy of :mod:`gpja.baselines.nicp` is quadratic in the
stacked maps ``X (4n, 3)``, and its normal equations are a 4n x 4n sparse SPD
system with three right-hand sides. :class:`AffineSolver` solves a sequence of
such systems with one sparse Cholesky factor (:mod:`gpja.cholesky`), reused as a
conjugate-gradient preconditioner while the system changes little. Positions
are normalised (centred, divided by their RMS radius) in :class:`AffineProblem`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from gpja.baselines.landmarks import TemplateLandmarks
from gpja.cholesky import DEFAULT_BACKEND, factorize
from gpja.mesh import unique_edges
from gpja.surface import vertex_areas


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
    Z = factor.solve(R)
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
        Z = factor.solve(R)
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
        backend: the factor's :mod:`gpja.cholesky` backend.
    """

    def __init__(self, rtol: float = 1e-6, max_cg: int = 30, max_stiffness_ratio: float = 3.0,
                 backend: str = DEFAULT_BACKEND):
        self.rtol, self.max_cg, self.max_ratio, self.backend = rtol, max_cg, max_stiffness_ratio, backend
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
        self.factor = factorize(H, self.backend)
        self.factor_stiffness = stiffness
        self.stats["factorizations"] += 1
        self.stats["per_solve"].append("factorize")
        return self.factor.solve(B)


@dataclass
class AffineProblem:
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
                    scan_landmarks: np.ndarray, gamma: float) -> AffineProblem:
    """Normalise the (pre-aligned) template ``V (n, 3)`` and landmark points ``P (L, 3)``, mm,
    and build the fixed matrices."""
    center = V.mean(axis=0)
    scale = float(np.sqrt(((V - center) ** 2).sum(axis=1).mean()))
    Vn = (V - center) / scale
    Vh = np.c_[Vn, np.ones(len(V))]
    return AffineProblem(Vh=Vh, F=F, K=stiffness_matrix(F, len(V), gamma), area=vertex_areas(Vn, F),
                    DL=landmark_matrix(np.c_[(P - center) / scale, np.ones(len(P))], F, landmarks, len(V)),
                    UL=(scan_landmarks - center) / scale,
                    center=center, scale=scale)


def solve_affine(prob: AffineProblem, solver: AffineSolver, U: np.ndarray, w: np.ndarray, alpha: float, beta: float,
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


def apply_affine(prob: AffineProblem, X: np.ndarray) -> np.ndarray:
    """(n, 3) deformed positions in mm from (4n, 3) affine maps."""
    n = len(prob.Vh)
    Xn = np.einsum("nk,nkd->nd", prob.Vh, X.reshape(n, 4, 3))
    return Xn * prob.scale + prob.center
