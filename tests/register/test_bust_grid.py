"""Tests of gpja.register.bust_grid: quad-grid helpers of the bust."""
from __future__ import annotations

import numpy as np

from gpja.register.bust_grid import coons_grid, grid_quads, quads_to_tris, split_ab, split_like


def test_coons_grid_keeps_its_boundary_loop():
    a, b = 4, 3
    # boundary of the unit square's (a x b) grid in the documented loop order, starting at corner (0, b)
    top = [(p / a, 1.0) for p in range(a)]
    right = [(1.0, q / b) for q in range(b, 0, -1)]
    bottom = [(p / a, 0.0) for p in range(a, 0, -1)]
    left = [(0.0, q / b) for q in range(b)]
    bd = np.array(top + right + bottom + left)
    G = coons_grid(bd, a, b)
    p, q = np.meshgrid(np.arange(a + 1) / a, np.arange(b + 1) / b, indexing="ij")
    np.testing.assert_allclose(G, np.stack([p, q], -1), atol=1e-12)


def test_quads_split_into_two_triangles_each_and_uv_follow():
    idx = np.arange(12).reshape(3, 4)
    quads = grid_quads(idx)
    assert quads.shape == (6, 4)
    i, j = np.meshgrid(np.arange(3.0), np.arange(4.0) * 3.0, indexing="ij")  # stretched cells: one diagonal is better
    V = np.column_stack([i.ravel(), j.ravel(), np.zeros(12)])
    tris = quads_to_tris(V, quads)
    assert tris.shape == (12, 3)
    for k, quad in enumerate(quads):
        assert set(tris[k]) | set(tris[k + len(quads)]) == set(quad)
    same = split_like(quads, tris, quads)
    np.testing.assert_array_equal(same, tris)


def test_split_ab_gives_an_even_side():
    for L2, ratio in ((20, 1.0), (33, 2.5), (9, 0.3)):
        a, b = split_ab(L2, ratio)
        assert a + b == L2 and a % 2 == 0 and a >= 2
