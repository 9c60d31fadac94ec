"""Discrete Laplacians of a triangle mesh and the LargeSteps system matrix ``I + lambda L``.

The paper (Multiscale Regularized Optimization) re-parametrises the vertices as
``u = (I + lambda L) x`` with ``L`` the cotangent Laplacian::

    L_ij = -w_ij                 if (i, j) is an edge
    L_ii = sum_k w_ik            (over the edges (i, k))
    L_ij = 0                     otherwise

    w_ij = (cot alpha_ij + cot beta_ij) / 2      (Desbrun et al. 1999)

where ``alpha_ij`` and ``beta_ij`` are the two angles opposite edge ``(i, j)``.
A boundary edge has one opposite angle and so only one cotangent term. ``L`` is
the (un-mass-weighted) P1 finite-element stiffness matrix of the Dirichlet
energy: ``x^T L x = sum_t area_t |grad x|^2`` summed over triangles. Each
triangle's 3x3 contribution is positive semi-definite, so ``L`` is symmetric
positive semi-definite (null space: the constants on each connected component)
even when obtuse angles make some weights negative.

Cotangents are dimensionless, so ``L`` does not change when the mesh is scaled
(millimetres or metres give the same matrix) and ``lambda`` is dimensionless.

Degenerate triangles (zero or numerically zero area) are skipped: their
cotangents are unbounded, and dropping a triangle removes one PSD term, which
keeps ``L`` PSD (clamping single cotangents would not). A triangle counts as
degenerate when ``|e1 x e2| <= DEGENERATE_REL * (longest edge)^2``.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from gpja.errors import InputError
from gpja.mesh import unique_edges

#: A triangle with twice its area below this fraction of its longest edge squared is skipped.
DEGENERATE_REL = 1e-12


def _check_mesh(V: np.ndarray, F: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Validate and convert ``V (n, 3)`` -> float64 and ``F (m, 3)`` -> int64."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputError(where, f"V must have shape (n, 3), got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3:
        raise InputError(where, f"F must have shape (m, 3), got {F.shape}")
    if F.size and not np.issubdtype(F.dtype, np.integer):
        raise InputError(where, f"F must hold integer vertex indices, got dtype {F.dtype}")
    F = F.astype(np.int64, copy=False)
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        raise InputError(where, f"F indexes vertices outside [0, {len(V)})")
    if not np.isfinite(V).all():
        raise InputError(where, "V contains NaN or infinite coordinates")
    return V, F


def cotangent_weights(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Half-cotangent of every triangle corner.

    Args:
        V: (n, 3) float vertex positions, mm (any unit; the result is dimensionless).
        F: (m, 3) int vertex indices per triangle.

    Returns:
        (m, 3) float64: entry ``[t, k]`` is ``cot(angle at corner k of triangle t) / 2``,
        the weight that corner adds to its opposite edge ``(F[t, k+1], F[t, k+2])``.
        Rows of degenerate triangles (see module docstring) are zero.
    """
    V, F = _check_mesh(V, F, "cotangent_weights")
    P = V[F]  # (m, 3 corners, 3 xyz)
    # Edge vectors from corner k to the other two corners.
    a = np.roll(P, -1, axis=1) - P  # (m, 3, 3): corner k -> k+1
    b = np.roll(P, -2, axis=1) - P  # (m, 3, 3): corner k -> k+2
    dot = np.einsum("mkc,mkc->mk", a, b)
    cross = np.linalg.norm(np.cross(a, b), axis=2)  # (m, 3): twice the area, same for every corner
    edge2 = np.einsum("mkc,mkc->mk", a, a).max(axis=1)  # (m,) longest edge squared
    ok = cross[:, 0] > DEGENERATE_REL * edge2
    half_cot = np.zeros_like(dot)
    half_cot[ok] = 0.5 * dot[ok] / cross[ok]
    return half_cot


def cotangent_laplacian(V: np.ndarray, F: np.ndarray, face_weight: np.ndarray | None = None) -> sp.csr_matrix:
    """Cotangent Laplacian ``L`` (positive semi-definite sign convention).

    Args:
        V: (n, 3) float vertex positions, mm.
        F: (m, 3) int vertex indices per triangle; any orientation.
        face_weight: (m,) float ``>= 0`` or None (all 1): each triangle's stiffness matrix is scaled by its
            weight before the sum, so ``L`` stays symmetric PSD (a sum of PSD matrices with non-negative
            factors) and is the plain Laplacian where every weight is 1.

    Returns:
        (n, n) float64 ``scipy.sparse.csr_matrix``, dimensionless, symmetric PSD:
        ``L[i, j] = -w_ij`` on edges, ``L[i, i] = sum_k w_ik``, sorted indices,
        duplicates summed. Isolated vertices get an all-zero row. Explicit zeros
        (e.g. edges whose weight cancels to 0 on a right-angled grid) are kept so
        the sparsity pattern is the mesh's edge graph plus the diagonal.
    """
    V, F = _check_mesh(V, F, "cotangent_laplacian")
    n = len(V)
    w = cotangent_weights(V, F)  # (m, 3)
    if face_weight is not None:
        face_weight = np.asarray(face_weight, dtype=np.float64)
        if face_weight.shape != (len(F),) or not np.all(np.isfinite(face_weight)) or np.any(face_weight < 0):
            raise InputError("cotangent_laplacian", f"face_weight must be ({len(F)},) finite values >= 0, got shape "
                             f"{face_weight.shape}")
        w = w * face_weight[:, None]
    i = np.roll(F, -1, axis=1).ravel()  # opposite edge of corner k: (k+1, k+2)
    j = np.roll(F, -2, axis=1).ravel()
    w = w.ravel()
    rows = np.concatenate([i, j, i, j])
    cols = np.concatenate([j, i, i, j])
    vals = np.concatenate([-w, -w, w, w])
    L = sp.coo_matrix((vals, (rows, cols)), shape=(n, n)).tocsr()
    L.sum_duplicates()
    L.sort_indices()
    return L


def uniform_laplacian(V: np.ndarray, F: np.ndarray) -> sp.csr_matrix:
    """Combinatorial (graph) Laplacian: ``L[i, j] = -1`` per edge, ``L[i, i] = degree``.

    Args:
        V: (n, 3) float vertex positions, mm (only ``len(V)`` is used).
        F: (m, 3) int vertex indices per triangle.

    Returns:
        (n, n) float64 ``scipy.sparse.csr_matrix``, symmetric PSD, dimensionless.
    """
    V, F = _check_mesh(V, F, "uniform_laplacian")
    n = len(V)
    e, _ = unique_edges(F)  # (low, high) pairs in lexicographic order
    e = e[e[:, 0] != e[:, 1]]
    A = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n))
    A = A.tocsr()
    L = (sp.diags(np.asarray(A.sum(axis=1)).ravel()) - A).tocsr()
    L.sort_indices()
    return L


def system_matrix(V: np.ndarray, F: np.ndarray, lam: float, laplacian: str = "cotangent",
                  face_weight: np.ndarray | None = None) -> sp.csr_matrix:
    """The LargeSteps matrix ``M = I + lam * L``.

    ``L`` is symmetric positive semi-definite (sum of per-triangle P1 stiffness
    matrices, each PSD; see the module docstring), so for ``lam >= 0`` every
    eigenvalue of ``M`` is ``>= 1``: ``M`` is symmetric positive definite and
    has a Cholesky factorisation, whatever the mesh (obtuse triangles,
    boundaries, several components, isolated vertices).

    Args:
        V: (n, 3) float vertex positions, mm.
        F: (m, 3) int vertex indices per triangle.
        lam: regularisation weight ``lambda >= 0``, dimensionless.
        laplacian: ``"cotangent"`` (the paper's choice) or ``"uniform"``.
        face_weight: (m,) per-triangle factor on ``lam`` (cotangent only; None = 1 everywhere, the paper):
            a spatially varying stiffness, ``Schedule.mouth_stiffness``.

    Returns:
        (n, n) float64 ``scipy.sparse.csr_matrix``, dimensionless, SPD, sorted indices.
    """
    lam = float(lam)
    if not np.isfinite(lam) or lam < 0:
        raise InputError("system_matrix", f"lam must be a finite number >= 0, got {lam}")
    if laplacian == "cotangent":
        L = cotangent_laplacian(V, F, face_weight)
    elif face_weight is not None:
        raise InputError("system_matrix", "face_weight needs the cotangent Laplacian")
    elif laplacian == "uniform":
        L = uniform_laplacian(V, F)
    else:
        raise InputError("system_matrix", f"laplacian must be 'cotangent' or 'uniform', got {laplacian!r}")
    M = (sp.identity(L.shape[0], format="csr") + lam * L).tocsr()
    M.sort_indices()
    return M
