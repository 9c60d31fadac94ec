"""Filling a texture where no view saw it: push-pull inside each UV chart, seams made to agree, gutters dilated.

Push-pull (Gortler et al. 1996, "The Lumigraph", Sec. 3.4): a pyramid of
weighted averages is built down to one texel ("push"), then each level's holes
are filled from the level below ("pull"). Texels of full weight keep their
value exactly; holes get a smooth interpolation of what surrounds them at the
scale of the hole. It runs once per chart, with every other chart's texels at
weight 0, so no colour crosses from one chart into another that happens to lie
next to it in the atlas. The result beyond the chart's edge is a smooth
extension of the chart and is what the gutter texels nearest to it get, so
bilinear lookups at chart borders read no foreign colour.

The pyramid levels are OpenCV's ``pyrDown`` / ``pyrUp`` (Gaussian 5x5): a
well-kept, fast implementation of exactly the filtering push-pull needs.
OpenCV's ``inpaint`` (Telea / Navier-Stokes) is not used: it marches in from
every known pixel, including other charts' texels, and slows down on large
holes (the back of the head, the mouth pocket).

Seams: a UV seam gives one surface point two texture positions. Where some
view sees it, both sides were fused from the same 3D points and agree; where
no view sees it, each side would be filled from its own chart. So after a
first fill the two copies of every seam vertex are set to their
confidence-weighted mean (seeds), and the fill runs again with the seeds as
known texels.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

#: Weights below this count as "no information" in the pyramid (division guard).
_EPS = 1e-8
#: Confidence floor of a seam copy in the seeds' weighted mean (copies no view saw still count a little).
_SEAM_FLOOR = 1e-3


def push_pull(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Fill low-weight texels from their surroundings; full-weight texels keep their value.

    Args:
        values: (h, w, C) float32 values (ignored where the weight is 0).
        weights: (h, w) float32 confidence in [0, 1] (1 = known, 0 = hole).
    Returns:
        (h, w, C) float32: ``weights * values + (1 - weights) * (fill from the coarser level)``
        at every level; where all weights are 0, zeros.
    """
    values = np.asarray(values, dtype=np.float32)
    w = np.clip(np.asarray(weights, dtype=np.float32), 0.0, 1.0)
    h, wd = w.shape
    if h <= 1 or wd <= 1 or float(w.min()) >= 1.0:
        if h <= 1 or wd <= 1:
            total = float(w.sum())
            mean = (values * w[..., None]).sum((0, 1)) / max(total, _EPS)
            return (w[..., None] * values + (1.0 - w[..., None]) * mean).astype(np.float32)
        return values.copy()
    weighted = cv2.pyrDown(np.ascontiguousarray(values * w[..., None]))
    w_small = cv2.pyrDown(w)
    weighted = weighted.reshape(w_small.shape + (values.shape[2],))
    coarse_values = weighted / np.maximum(w_small, _EPS)[..., None]
    # a coarse texel is fully known once the fine texels under it carry one texel's worth of weight
    coarse = push_pull(coarse_values, np.clip(4.0 * w_small, 0.0, 1.0))
    up = cv2.pyrUp(np.ascontiguousarray(coarse), dstsize=(wd, h)).reshape(values.shape)
    return (w[..., None] * values + (1.0 - w[..., None]) * up).astype(np.float32)


def nearest_chart(chart_image: np.ndarray) -> np.ndarray:
    """(T, T) int64 chart of every texel: its own inside a chart, the nearest chart's in the gutter (-1 if none)."""
    outside = chart_image < 0
    if not outside.any() or outside.all():
        return chart_image.astype(np.int64)
    _, (ri, ci) = ndimage.distance_transform_edt(outside, return_indices=True)
    return chart_image[ri, ci].astype(np.int64)


def _fill_pass(values: np.ndarray, weights: np.ndarray, owner: np.ndarray, n_charts: int) -> np.ndarray:
    """One push-pull per chart over its bounding box; every texel takes the fill of the chart that owns it."""
    out = np.empty_like(values)
    known = weights > 0
    fallback = (values[known] * weights[known][:, None]).sum(0) / max(float(weights[known].sum()), _EPS)
    for c in range(n_charts):
        mine = owner == c
        if not mine.any():
            continue
        rr, cc = np.nonzero(mine)
        r0, r1, c0, c1 = rr.min(), rr.max() + 1, cc.min(), cc.max() + 1
        w = np.where(mine[r0:r1, c0:c1], weights[r0:r1, c0:c1], 0.0).astype(np.float32)
        if float(w.sum()) <= 0.0:  # nothing known in this chart (yet): the global mean
            out[mine] = fallback
            continue
        filled = push_pull(values[r0:r1, c0:c1], w)
        out[r0:r1, c0:c1][mine[r0:r1, c0:c1]] = filled[mine[r0:r1, c0:c1]]
    return out


def sample_bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear samples of an image at points (OpenCV ``remap``; borders repeat the edge pixel).

    ``remap`` rounds each position to 1/32 pixel (its interpolation table): far below the
    registration's accuracy, and the price of its speed.

    Args:
        image: (h, w, C) float32 image, C <= 4 (or (h, w)).
        xy: (k, 2) float (x, y) coordinates, pixel centres at integers.
    Returns:
        (k, C) float32 samples ((k, 1) for a 2-D image).
    """
    xy = np.asarray(xy, dtype=np.float32).reshape(-1, 2)
    k = len(xy)
    row = 1024  # a remap map must stay below 32767 per side: lay the points out in rows
    maps = np.concatenate([xy, np.zeros(((-k) % row, 2), np.float32)]).reshape(-1, row, 2)
    out = cv2.remap(np.ascontiguousarray(image, dtype=np.float32), maps, None, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, image.shape[2] if image.ndim == 3 else 1)[:k]


def fill_texture(values: np.ndarray, weights: np.ndarray, chart_image: np.ndarray,
                 seam_xy: np.ndarray | None = None, seam_charts: np.ndarray | None = None) -> np.ndarray:
    """Fill every texel of a texture: holes inside charts, seams that agree, gutters.

    Args:
        values: (T, T, C) float32 texel values (where ``weights`` > 0).
        weights: (T, T) float32 confidence in [0, 1]; 0 = unobserved.
        chart_image: (T, T) int chart label of every texel inside a UV triangle, -1 in the gutter.
        seam_xy: (S, 2, 2) float texel coordinates (column, row; centres at integers) of the two
            copies of each seam vertex (``gpja.render.uv_raster.seam_copies``); None = no seams.
        seam_charts: (S, 2) int chart of each copy (required with ``seam_xy``).
    Returns:
        (T, T, C) float32 with every texel set; texels of weight 1 unchanged.
    """
    values = np.ascontiguousarray(values, dtype=np.float32)
    weights = np.clip(np.asarray(weights, dtype=np.float32), 0.0, 1.0)
    owner = nearest_chart(np.asarray(chart_image))
    n_charts = int(owner.max()) + 1
    if n_charts <= 0 or not (weights > 0).any():
        raise ValueError("the texture has no observed texel to fill from")
    first = _fill_pass(values, weights, owner, n_charts)
    if seam_xy is None or len(seam_xy) == 0:
        return first
    seam_xy = np.asarray(seam_xy, dtype=np.float64)
    size = values.shape[0]
    a, b = seam_xy[:, 0], seam_xy[:, 1]
    va, vb = sample_bilinear(first, a), sample_bilinear(first, b)
    ca = sample_bilinear(weights, a)[:, 0] + _SEAM_FLOOR
    cb = sample_bilinear(weights, b)[:, 0] + _SEAM_FLOOR
    target = (ca[:, None] * va + cb[:, None] * vb) / (ca + cb)[:, None]
    # seed the nearest texel of each copy with the agreed value, as a known texel of the copy's chart
    acc = np.zeros_like(values)
    count = np.zeros(weights.shape, dtype=np.float32)
    seeds_owner = owner.copy()
    for side in (0, 1):
        rc = np.clip(np.rint(seam_xy[:, side, ::-1]).astype(np.int64), 0, size - 1)
        np.add.at(acc, (rc[:, 0], rc[:, 1]), target)
        np.add.at(count, (rc[:, 0], rc[:, 1]), 1.0)
        seeds_owner[rc[:, 0], rc[:, 1]] = np.asarray(seam_charts)[:, side]
    seeded = count > 0
    seed_values = acc / np.maximum(count, 1.0)[..., None]
    w2 = weights.copy()
    v2 = values.copy()
    blend = w2[seeded][:, None]
    v2[seeded] = blend * values[seeded] + (1.0 - blend) * seed_values[seeded]
    w2[seeded] = 1.0
    return _fill_pass(v2, w2, seeds_owner, n_charts)
