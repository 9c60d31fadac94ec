"""Quad-grid helpers for building the bust's patches (:mod:`gpja.register.bust`).

Grids are index arrays ``G[p, q]``; quads list their corners in cyclic order
``(i, j), (i+1, j), (i+1, j+1), (i, j+1)``.
"""
from __future__ import annotations

import numpy as np


def quads_to_tris(V: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Split quads along the diagonal giving the larger minimum angle.

    Args:
        V: (n, 3) float64 vertices, mm. quads: (q, 4) int indices a, b, c, d in cyclic order.
    Returns:
        (2q, 3) local-order triangles: rows 0..q-1 are the first triangle of each quad, rows
        q..2q-1 the second; the pairs are (a,b,c),(a,c,d) or (a,b,d),(b,c,d).
    """
    def min_angle(t):
        P = V[t]
        ang = []
        for i in range(3):
            u = P[:, (i + 1) % 3] - P[:, i]
            w = P[:, (i + 2) % 3] - P[:, i]
            cos = (u * w).sum(1) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-12)
            ang.append(np.arccos(np.clip(cos, -1, 1)))
        return np.min(ang, axis=0)

    a, b, c, d = quads.T
    s1 = np.minimum(min_angle(np.stack([a, b, c], 1)), min_angle(np.stack([a, c, d], 1)))
    s2 = np.minimum(min_angle(np.stack([a, b, d], 1)), min_angle(np.stack([b, c, d], 1)))
    use1 = s1 >= s2
    t1 = np.where(use1[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    t2 = np.where(use1[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    return np.concatenate([t1, t2])


def split_like(quads: np.ndarray, tris: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Triangles of the quads ``other`` (q, 4) split along the same diagonals as ``tris`` split ``quads``.

    Args:
        quads: (q, 4) int quads; tris: (2q, 3) their :func:`quads_to_tris` triangles.
        other: (q, 4) int quads over other indices (e.g. the UV corners of the same cells).
    Returns:
        (2q, 3) int triangles of ``other``, in the order of ``tris``.
    """
    split1 = tris[: len(quads), 2] == quads[:, 2]
    a, b, c, d = other.T
    t1 = np.where(split1[:, None], np.stack([a, b, c], 1), np.stack([a, b, d], 1))
    t2 = np.where(split1[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    return np.concatenate([t1, t2])


def coons_grid(bd: np.ndarray, a: int, b: int, smooth_iters: int = 60) -> np.ndarray:
    """Fill an (a+1, b+1) grid from its boundary loop (Coons patch + Laplacian smoothing).

    Args:
        bd: (2(a+b), d) float64 boundary points in loop order starting at grid corner
            (0, b): top row p = 0..a, right column q = b..0, bottom row
            p = a..0, left column q = 0..b.
    Returns:
        (a+1, b+1, d) float64 grid, G[p, q], boundary equal to ``bd``.
    """
    L = 2 * (a + b)
    assert len(bd) == L
    p = np.arange(a + 1)
    q = np.arange(b + 1)
    T = bd[p]                                   # q = b
    R = bd[a + (b - q)]                         # p = a
    B = bd[a + b + (a - p)]                     # q = 0
    Lf = bd[(2 * a + b + q) % L]                # p = 0
    u = (p / a)[:, None, None]
    v = (q / b)[None, :, None]
    G = ((1 - v) * B[:, None] + v * T[:, None] + (1 - u) * Lf[None, :] + u * R[None, :]
         - ((1 - u) * (1 - v) * B[0] + u * (1 - v) * B[a] + (1 - u) * v * T[0] + u * v * T[a]))
    for _ in range(smooth_iters):  # Tutte-like relaxation of the interior (convex boundary: no flips)
        G[1:-1, 1:-1] = 0.25 * (G[:-2, 1:-1] + G[2:, 1:-1] + G[1:-1, :-2] + G[1:-1, 2:])
    return G


def grid_quads(idx: np.ndarray) -> np.ndarray:
    """(P-1)(Q-1, 4) quads of an index grid idx (P, Q): (i,j),(i+1,j),(i+1,j+1),(i,j+1)."""
    return np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)


def cumulative_length(points: np.ndarray) -> np.ndarray:
    """(n,) float64 cumulative polyline length along axis 0 of (n, ..., 3), averaged over the trailing curves, mm."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=-1)
    if seg.ndim > 1:
        seg = seg.mean(axis=tuple(range(1, seg.ndim)))
    return np.concatenate([[0.0], np.cumsum(seg)])


def resample(param: np.ndarray, s: np.ndarray, n: int) -> np.ndarray:
    """(n+1,) values of ``param`` at uniform steps of the monotone length ``s`` (both (k,) float64)."""
    return np.interp(np.linspace(s[0], s[-1], n + 1), s, param)


def split_ab(L2: int, ratio: float) -> tuple[int, int]:
    """Sides (a, b) of a grid cap with a + b = L2, a even, a / b ~ ratio."""
    a = int(round(L2 * ratio / (1 + ratio) / 2)) * 2
    a = min(max(a, 2), L2 - 1 - ((L2 - 1) % 1))
    return a, L2 - a
