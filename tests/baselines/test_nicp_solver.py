"""Tests of gpja.baselines.nicp_solver: the stiffness form and the preconditioned solver."""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from gpja.baselines.nicp_solver import AffineSolver, stiffness_matrix
from tests.baselines.test_nicp import ellipsoid


def test_stiffness_form_is_zero_for_one_affine_map_everywhere():
    """The same affine map on every vertex does not stretch any edge: X^T K X = 0."""
    V, F = ellipsoid(1)
    n = len(V)
    K = stiffness_matrix(F, n, gamma=1.0)
    A = np.random.default_rng(1).normal(size=(4, 3))
    X = np.tile(A, (n, 1))
    assert np.abs(X.T @ (K @ X)).max() < 1e-9
    assert abs((K - K.T)).max() == 0.0


def test_preconditioned_cg_matches_a_direct_solve():
    V, F = ellipsoid(2)
    n = len(V)
    K = stiffness_matrix(F, n, 1.0)
    H1 = (0.5 * K + sp.eye(4 * n)).tocsr()
    H2 = (0.25 * K + sp.diags(np.linspace(0.5, 1.5, 4 * n))).tocsr()  # other stiffness and weights
    B = np.random.default_rng(0).normal(size=(4 * n, 3))
    solver = AffineSolver(rtol=1e-12, max_cg=200)
    solver.solve(H1, B, np.zeros_like(B), stiffness=1.0)
    X = solver.solve(H2, B, np.zeros_like(B), stiffness=0.9)
    assert solver.stats["factorizations"] == 1 and solver.stats["cg_solves"] == 1
    assert np.abs(H2 @ X - B).max() < 1e-9 * np.abs(B).max()
