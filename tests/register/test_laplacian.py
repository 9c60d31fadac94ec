"""Tests of gpja.register.laplacian: cotangent/uniform Laplacians and I + lambda L."""
from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
import trimesh

from gpja.errors import InputError
from gpja.register.laplacian import (
    DEGENERATE_REL,
    cotangent_laplacian,
    cotangent_weights,
    system_matrix,
    uniform_laplacian,
)

#: Vectorised Laplacian vs the dense per-triangle-loop reference (float64, dimensionless).
DENSE_REFERENCE = 1e-10
#: Analytic identities in float64 (row sums, symmetry, linear precision, hand-computed entries).
ANALYTIC_F64 = 1e-12
#: Smallest eigenvalue a PSD matrix may show from round-off.
PSD_SLACK = 1e-10
#: Recorded regression entries (float64 round-off across numpy/BLAS builds).
REGRESSION_REL = 1e-12


# ---------------------------------------------------------------- meshes
def grid(nx: int = 6, ny: int = 5, jitter: float = 0.3, z_amp: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A planar (z_amp=0) or bumpy (nx+1)x(ny+1) grid with boundary, 10 mm spacing.

    Interior vertices are moved in-plane by a deterministic pattern (``jitter`` of
    the spacing) so triangles are irregular, some obtuse; no RNG involved.

    Returns:
        V: ((nx+1)(ny+1), 3) float64, mm. F: (2 nx ny, 3) int64.
    """
    h = 10.0
    j, i = np.mgrid[0 : ny + 1, 0 : nx + 1]
    x, y = i * h, j * h
    interior = (i > 0) & (i < nx) & (j > 0) & (j < ny)
    x = x + interior * jitter * h * np.sin(1.7 * i + 2.3 * j)
    y = y + interior * jitter * h * np.cos(2.9 * i - 1.1 * j)
    z = z_amp * np.sin(0.9 * i) * np.cos(0.7 * j)
    V = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1).astype(np.float64)
    idx = np.arange((nx + 1) * (ny + 1)).reshape(ny + 1, nx + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return V, F


def noisy_sphere(subdivisions: int = 2, radius: float = 100.0, noise: float = 0.15, seed: int = 0):
    """Icosphere (radius mm) with every vertex moved by ``noise`` x edge length, seeded."""
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    V = np.asarray(m.vertices, dtype=np.float64).copy()
    F = np.asarray(m.faces, dtype=np.int64)
    edge = np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean()
    V += np.random.default_rng(seed).normal(scale=noise * edge, size=V.shape)
    return V, F


def dense_cotangent_reference(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(n, n) dense cotangent Laplacian by explicit loops over triangles and corners (angles via arccos)."""
    n = len(V)
    L = np.zeros((n, n))
    for f in F:
        P = V[f]
        longest2 = max(np.sum((P[k] - P[(k + 1) % 3]) ** 2) for k in range(3))
        if np.linalg.norm(np.cross(P[1] - P[0], P[2] - P[0])) <= DEGENERATE_REL * longest2:
            continue  # degenerate triangle: skipped, as documented
        for k in range(3):
            o, a, b = f[k], f[(k + 1) % 3], f[(k + 2) % 3]
            ea, eb = V[a] - V[o], V[b] - V[o]
            angle = math.acos(np.clip(ea @ eb / (np.linalg.norm(ea) * np.linalg.norm(eb)), -1.0, 1.0))
            w = 0.5 / math.tan(angle)
            L[a, b] -= w
            L[b, a] -= w
            L[a, a] += w
            L[b, b] += w
    return L


MESHES = {
    "noisy_sphere": noisy_sphere,
    "bumpy_grid_with_boundary": lambda: grid(z_amp=4.0),
    "flat_grid_with_boundary": lambda: grid(),
}


# ---------------------------------------------------------------- analytic tiny cases
def test_single_right_triangle_analytic():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    L = cotangent_laplacian(V, np.array([[0, 1, 2]])).toarray()
    # boundary edges, one opposite angle each: cot 45 deg / 2 = 0.5 on the legs, cot 90 deg = 0 on the hypotenuse
    expected = np.array([[1.0, -0.5, -0.5], [-0.5, 0.5, 0.0], [-0.5, 0.0, 0.5]])
    np.testing.assert_allclose(L, expected, atol=ANALYTIC_F64)


def test_corner_tetrahedron_analytic():
    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    L = cotangent_laplacian(V, F).toarray()
    s3 = math.sqrt(3.0)
    # edges from the right-angled corner: two 45-degree opposite angles -> w = (1 + 1) / 2 = 1
    np.testing.assert_allclose(L[0], [3.0, -1.0, -1.0, -1.0], atol=ANALYTIC_F64)
    # edges of the equilateral face: opposite angles 90 deg and 60 deg -> w = (0 + 1/sqrt3) / 2
    np.testing.assert_allclose(L[1], [-1.0, 1.0 + 1.0 / s3, -0.5 / s3, -0.5 / s3], atol=ANALYTIC_F64)
    U = uniform_laplacian(V, F).toarray()
    np.testing.assert_array_equal(U, 4 * np.eye(4) - np.ones((4, 4)))


@pytest.mark.parametrize("name", MESHES)
def test_constants_in_null_space_and_symmetric(name):
    V, F = MESHES[name]()
    L = cotangent_laplacian(V, F)
    assert L.dtype == np.float64 and L.shape == (len(V), len(V)) and sp.isspmatrix_csr(L)
    np.testing.assert_allclose(L @ np.ones(len(V)), 0.0, atol=ANALYTIC_F64 * abs(L).max())
    assert abs(L - L.T).max() == 0.0


def test_linear_precision_on_flat_irregular_grid():
    V, F = grid(nx=7, ny=6, jitter=0.3)
    L = cotangent_laplacian(V, F)
    lin = 0.3 * V[:, 0] - 1.7 * V[:, 1] + 5.0  # a linear function of the plane, mm
    n_x = 8
    i, j = np.arange(len(V)) % n_x, np.arange(len(V)) // n_x
    interior = (i > 0) & (i < 7) & (j > 0) & (j < 6)
    r = L @ lin
    np.testing.assert_allclose(r[interior], 0.0, atol=ANALYTIC_F64 * np.abs(lin).max())
    assert np.abs(r[~interior]).max() > 1.0  # the boundary is not harmonic: the test can fail


def test_scale_invariant():
    V, F = noisy_sphere(1)
    np.testing.assert_allclose(cotangent_laplacian(1000.0 * V, F).toarray(),
                               cotangent_laplacian(V, F).toarray(), atol=DENSE_REFERENCE)


# ---------------------------------------------------------------- reference / identity checks
@pytest.mark.parametrize("name", MESHES)
def test_matches_dense_loop_reference(name):
    V, F = MESHES[name]()
    np.testing.assert_allclose(cotangent_laplacian(V, F).toarray(), dense_cotangent_reference(V, F),
                               rtol=0, atol=DENSE_REFERENCE)


@pytest.mark.parametrize("name", MESHES)
def test_positive_semidefinite(name):
    V, F = MESHES[name]()
    L = cotangent_laplacian(V, F).toarray()
    assert (cotangent_weights(V, F) < 0).any(), "mesh should contain obtuse angles (negative weights)"
    assert np.linalg.eigvalsh(L).min() > -PSD_SLACK


def test_degenerate_triangle_skipped():
    V, F = grid(nx=3, ny=3, jitter=0.0)
    V = np.vstack([V, V[0] + 0.5 * (V[1] - V[0])])  # a vertex on the segment 0-1: collinear triangle
    F = np.vstack([F, [[0, 1, len(V) - 1]], [[2, 2, 5]]])  # also a repeated-index triangle
    w = cotangent_weights(V, F)
    assert np.isfinite(w).all() and (w[-2:] == 0).all()
    L = cotangent_laplacian(V, F)
    np.testing.assert_allclose(L.toarray(), dense_cotangent_reference(V, F), atol=DENSE_REFERENCE)
    np.testing.assert_allclose(L.toarray(), np.pad(cotangent_laplacian(V[:-1], F[:-2]).toarray(), (0, 1)),
                               atol=ANALYTIC_F64)
    M = system_matrix(V, F, 5.0)  # the isolated vertex keeps M SPD: its row is the identity's
    assert M[len(V) - 1, len(V) - 1] == 1.0
    assert np.linalg.eigvalsh(M.toarray()).min() >= 1.0 - PSD_SLACK


@pytest.mark.parametrize("lam", [0.0, 0.5, 37.0])
def test_system_matrix_matches_dense(lam):
    V, F = grid(z_amp=4.0)
    M = system_matrix(V, F, lam)
    assert sp.isspmatrix_csr(M) and M.dtype == np.float64
    np.testing.assert_allclose(M.toarray(), np.eye(len(V)) + lam * dense_cotangent_reference(V, F),
                               atol=DENSE_REFERENCE * max(lam, 1.0))
    assert np.linalg.eigvalsh(M.toarray()).min() >= 1.0 - PSD_SLACK
    Mu = system_matrix(V, F, lam, laplacian="uniform")
    np.testing.assert_allclose(Mu.toarray(), np.eye(len(V)) + lam * uniform_laplacian(V, F).toarray())


def test_face_weights_scale_each_triangles_stiffness():
    V, F = grid(z_amp=4.0)
    L = cotangent_laplacian(V, F)
    np.testing.assert_array_equal(cotangent_laplacian(V, F, np.ones(len(F))).toarray(), L.toarray())
    np.testing.assert_allclose(cotangent_laplacian(V, F, np.full(len(F), 3.0)).toarray(), 3.0 * L.toarray(),
                               atol=ANALYTIC_F64 * abs(L).max())
    # one triangle alone, weighted: its own stiffness matrix times the weight (the right triangle's, analytic)
    right = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    np.testing.assert_allclose(cotangent_laplacian(right, np.array([[0, 1, 2]]), np.array([2.5])).toarray(),
                               2.5 * np.array([[1.0, -0.5, -0.5], [-0.5, 0.5, 0.0], [-0.5, 0.0, 0.5]]), atol=ANALYTIC_F64)
    # the sum of per-triangle parts: weights on the left half only change the left half's rows
    weight = np.where(V[F].mean(axis=1)[:, 0] < V[:, 0].mean(), 4.0, 1.0)
    Lw = cotangent_laplacian(V, F, weight)
    assert abs(Lw - Lw.T).max() == 0.0
    np.testing.assert_allclose(Lw @ np.ones(len(V)), 0.0, atol=ANALYTIC_F64 * abs(Lw).max())
    assert np.linalg.eigvalsh(Lw.toarray()).min() > -PSD_SLACK
    far_right = V[:, 0] > V[:, 0].max() - 1.0
    np.testing.assert_allclose(Lw.toarray()[far_right], L.toarray()[far_right], atol=ANALYTIC_F64)
    assert abs(Lw - L).max() > 1.0  # the left half did change: the test can fail
    M = system_matrix(V, F, 2.0, face_weight=weight)
    np.testing.assert_allclose(M.toarray(), np.eye(len(V)) + 2.0 * Lw.toarray(), atol=DENSE_REFERENCE)


def test_bad_input_raises():
    V, F = grid(2, 2)
    with pytest.raises(InputError, match="lam"):
        system_matrix(V, F, -1.0)
    with pytest.raises(InputError, match="laplacian"):
        system_matrix(V, F, 1.0, laplacian="mean")
    with pytest.raises(InputError, match=r"V must have shape"):
        cotangent_laplacian(V[:, :2], F)
    with pytest.raises(InputError, match="outside"):
        cotangent_laplacian(V, F + 100)
    with pytest.raises(InputError, match="integer"):
        cotangent_laplacian(V, F.astype(float))
    with pytest.raises(InputError, match="face_weight"):
        cotangent_laplacian(V, F, np.ones(len(F) - 1))
    with pytest.raises(InputError, match="face_weight"):
        cotangent_laplacian(V, F, np.full(len(F), -1.0))
    with pytest.raises(InputError, match="cotangent"):
        system_matrix(V, F, 1.0, laplacian="uniform", face_weight=np.ones(len(F)))


# ---------------------------------------------------------------- regression
def test_regression_bumpy_grid():
    V, F = grid(nx=4, ny=3, jitter=0.25, z_amp=3.0)
    L = cotangent_laplacian(V, F)
    assert L.shape == (20, 20)
    assert L.nnz == 20 + 2 * 43  # diagonal + both directions of the 43 edges of a 4x3 split grid
    got = [L[0, 0], L[6, 6], L[6, 7], L[6, 12], L[13, 8], L.diagonal().sum()]
    # values recorded from this implementation (cross-checked by the dense reference test above)
    expected = [0.896296390565559, 4.161471799269042, -1.1300445095195097, 0.18133553224181975,
                -0.7295334674057214, 53.76909903528187]
    np.testing.assert_allclose(got, expected, rtol=REGRESSION_REL, atol=0)
