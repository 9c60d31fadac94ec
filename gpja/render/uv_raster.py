"""Texture space: which surface point every texel centre is, and the UV charts of an atlas.

The mesh's UV triangles are rasterised into the texture image by the same
integer-exact rasteriser as the views (``rasterize.py``), with the UVs as
screen coordinates: every texel centre inside the atlas belongs to exactly one
UV triangle (top-left fill rule), so a texel is one surface point, found from
its face and (affine) barycentrics. Texels outside every triangle are the
gutter between charts.

Texel (r, c) of a (T, T) texture has its centre at u = (c + 0.5) / T,
v = 1 - (r + 0.5) / T (row 0 at the top, v up: ``gpja.render.texture``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from gpja.render.rasterize import BACKGROUND, rasterize

#: Depth given to the flat UV "screen" (any value above the rasteriser's near limit).
_UV_DEPTH = 2.0


@dataclass
class Texels:
    """The texels inside a mesh's UV triangles.

    Attributes:
        size: texture side T, texels.
        rows, cols: (N,) int64 texel row (0 = top) and column.
        face: (N,) int64 face whose UV triangle contains the texel centre.
        bary: (N, 3) float64 barycentrics of the texel centre in that UV triangle (affine: the map
            from a UV triangle to its 3D triangle is affine, so these also locate the 3D point).
        face_image: (T, T) int32 face per texel, ``BACKGROUND`` (-1) in the gutter.
    """

    size: int
    rows: np.ndarray
    cols: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    face_image: np.ndarray

    @property
    def flat(self) -> np.ndarray:
        """(N,) int64 index ``row * T + col`` of each texel in a flattened (T, T) image."""
        return self.rows * self.size + self.cols

    def surface(self, V: np.ndarray, F: np.ndarray) -> np.ndarray:
        """(N, 3) float64 the surface point of every texel: ``sum_k bary[:, k] * V[F[face, k]]``, units of ``V``."""
        return np.einsum("nk,nkc->nc", self.bary, np.asarray(V, dtype=np.float64)[F[self.face]])

    def scatter(self, values: np.ndarray, fill: float = 0.0) -> np.ndarray:
        """(T, T, C) image with ``values`` (N, C) at the texels, ``fill`` elsewhere (dtype of ``values``)."""
        values = np.asarray(values)
        vals = values.reshape(len(values), -1)
        image = np.full((self.size * self.size, vals.shape[1]), fill, dtype=vals.dtype)
        image[self.flat] = vals
        return image.reshape(self.size, self.size, *values.shape[1:])


def uv_to_texel(uv: np.ndarray, size: int) -> np.ndarray:
    """(k, 2) UV (OBJ convention) -> (k, 2) float64 texel coordinates (column, row) with centres at integers."""
    uv = np.asarray(uv, dtype=np.float64)
    return np.stack([uv[:, 0] * size - 0.5, (1.0 - uv[:, 1]) * size - 0.5], axis=1)


def rasterize_uv(UV: np.ndarray, F_uv: np.ndarray, size: int) -> Texels:
    """Rasterise the UV triangles into a (size, size) texture: face and barycentrics of every texel centre.

    Args:
        UV: (k, 2) float texture coordinates in [0, 1] (OBJ convention).
        F_uv: (m, 3) int rows of ``UV`` per face corner (either winding).
        size: texture side T (> 0).
    Returns:
        :class:`Texels`. Overlapping UV triangles (not a valid atlas) give each texel to the one drawn first.
    """
    size = int(size)
    if size < 1:
        raise ValueError(f"texture size must be positive, got {size}")
    F_uv = np.asarray(F_uv, dtype=np.int64)
    xy = uv_to_texel(UV, size)
    screen = np.concatenate([xy, np.full((len(xy), 1), _UV_DEPTH)], axis=1)[None]
    face_image, _ = rasterize(screen, F_uv, size, size)
    face_image = face_image[0]
    rows, cols = np.nonzero(face_image != BACKGROUND)
    face = face_image[rows, cols].astype(np.int64)
    tri = xy[F_uv[face]]                                   # (N, 3, 2) texel coordinates of the corners
    p = np.stack([cols, rows], axis=1).astype(np.float64)
    e1, e2, d = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], p - tri[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    b1 = (d[:, 0] * e2[:, 1] - d[:, 1] * e2[:, 0]) / det
    b2 = (e1[:, 0] * d[:, 1] - e1[:, 1] * d[:, 0]) / det
    bary = np.stack([1.0 - b1 - b2, b1, b2], axis=1)
    return Texels(size, rows.astype(np.int64), cols.astype(np.int64), face, bary, face_image)


def uv_charts(F_uv: np.ndarray, n_uv: int | None = None) -> np.ndarray:
    """(m,) int64 chart label of every face: UV triangles sharing a UV vertex belong to one chart.

    Labels are 0..K-1, numbered in the order of each chart's first face (deterministic).
    """
    F_uv = np.asarray(F_uv, dtype=np.int64)
    n_uv = int(F_uv.max()) + 1 if n_uv is None else int(n_uv)
    m = len(F_uv)
    # bipartite graph face <-> UV vertex: faces connected through shared UV vertices
    rows = np.repeat(np.arange(m), 3)
    graph = sp.coo_matrix((np.ones(3 * m), (rows, m + F_uv.ravel())), shape=(m + n_uv, m + n_uv))
    _, labels = connected_components(graph, directed=False)
    face_labels = labels[:m]
    _, first = np.unique(face_labels, return_index=True)
    order = np.argsort(first)                              # charts by their first face
    remap = np.empty(len(order), dtype=np.int64)
    remap[order] = np.arange(len(order))
    return remap[np.searchsorted(np.unique(face_labels), face_labels)]


def seam_copies(F: np.ndarray, F_uv: np.ndarray) -> np.ndarray:
    """(S, 2) int64 pairs of distinct UV rows that are the same mesh vertex (both sides of a UV seam).

    A vertex with k UV copies gives k - 1 pairs (each copy paired with its first), sorted.
    """
    F, F_uv = np.asarray(F, dtype=np.int64).ravel(), np.asarray(F_uv, dtype=np.int64).ravel()
    pairs = np.unique(np.stack([F, F_uv], axis=1), axis=0)  # (vertex, uv) sorted by vertex, then uv
    first = np.ones(len(pairs), dtype=bool)
    first[1:] = pairs[1:, 0] != pairs[:-1, 0]
    head = np.maximum.accumulate(np.where(first, np.arange(len(pairs)), 0))
    dup = ~first
    return np.stack([pairs[head[dup], 1], pairs[dup, 1]], axis=1)
