"""What a loaded expression looks like: the ``check-data`` summary, and the checks and preview of its scan targets.

Plain numpy on :class:`gpja.data.facescape.ExpressionData` and on the arrays of
``render_scan_targets``; nothing here renders.
"""
from __future__ import annotations

import logging
from typing import Sequence

import numpy as np

from gpja.data.facescape import ExpressionData
from gpja.errors import InputError
from gpja.mesh import TexturedMesh

#: Below this fraction of the scan's vertices projecting into a view, its camera and the scan look misaligned.
MIN_SCAN_FRACTION_IN_VIEW = 0.05


def summarize_expression(data: ExpressionData) -> dict:
    """A JSON-able summary of a loaded expression, with consistency checks.

    Returns:
        ``{"subject", "expression", "views": [{name, width, height, image, mean_rgb, scan_fraction_in_view}],
        "rt_scale": None | {scale, R, t}, "scan": {path, n_vertices, n_faces, bbox_min_mm, bbox_max_mm,
        median_edge_mm}}`` (``scan`` and ``scan_fraction_in_view`` only with a scan); a warning is logged for a
        view into which less than :data:`MIN_SCAN_FRACTION_IN_VIEW` of the scan projects.
    """
    views = []
    for view in data.views:
        entry = {"name": view.name, "width": view.camera.width, "height": view.camera.height,
                 "image": str(view.path), "mean_rgb": view.image.reshape(-1, 3).mean(axis=0).round(4).tolist()}
        if data.scan is not None:
            uv, z = view.camera.project(data.scan.V)
            inside = (z > 0) & (uv[:, 0] >= -0.5) & (uv[:, 0] <= view.camera.width - 0.5) \
                & (uv[:, 1] >= -0.5) & (uv[:, 1] <= view.camera.height - 0.5)
            entry["scan_fraction_in_view"] = round(float(inside.mean()), 4)
            if inside.mean() < MIN_SCAN_FRACTION_IN_VIEW:
                logging.warning("view %s: only %.1f%% of the scan projects into the image; cameras and scan may be misaligned",
                                view.name, 100 * inside.mean())
        views.append(entry)
    summary = {"subject": data.subject, "expression": data.expression, "views": views,
               "rt_scale": None if data.R is None else {"scale": data.scale, "R": data.R.tolist(), "t": data.t.tolist()}}
    if data.scan is not None:
        V = data.scan.V
        edges = TexturedMesh(V, data.scan.F).edge_lengths()
        summary["scan"] = {"path": str(data.scan.path), "n_vertices": int(len(V)), "n_faces": int(len(data.scan.F)),
                           "bbox_min_mm": V.min(axis=0).round(3).tolist(), "bbox_max_mm": V.max(axis=0).round(3).tolist(),
                           "median_edge_mm": round(float(np.median(edges)), 4)}
    return summary


def check_one_image_size(data: ExpressionData, source: str) -> tuple[int, int]:
    """The (width, height) px all views share (scan targets are rendered as one batch).

    Raises:
        InputError(source, ...): the views differ in size (``data.max_image_size`` makes them share one).
    """
    sizes = {(v.camera.width, v.camera.height) for v in data.views}
    if len(sizes) != 1:
        raise InputError(source, f"{data.subject}/{data.expression}: views differ in size {sorted(sizes)}; "
                                 "set data.max_image_size so they share one")
    return next(iter(sizes))


def warn_on_empty_targets(names: Sequence[str], coverage: np.ndarray) -> list[str]:
    """Log a warning for each view whose scan coverage is zero everywhere; return their names.

    Args:
        names: view names, one per view.
        coverage: (n_views, H, W) float32 in [0, 1], the scan targets' coverage.
    """
    empty = [name for name, cov in zip(names, coverage) if cov.sum() == 0]
    for name in empty:
        logging.warning("view %s: the scan covers no pixel of this view", name)
    return empty


def targets_preview(images: Sequence[np.ndarray], normal: np.ndarray, depth: np.ndarray,
                    coverage: np.ndarray) -> np.ndarray:
    """One row per view: reference image | scan normals | scan depth (near = bright, per view).

    Args:
        images: n_views reference images, each (H, W, 3) float32 in [0, 1].
        normal: (n_views, H, W, 3) float32 unit world normals of the scan targets.
        depth: (n_views, H, W) float32 camera depth of the scan targets, mm (0 = background).
        coverage: (n_views, H, W) float32 in [0, 1], the fraction of each pixel the scan covers.
    Returns:
        (n_views * H, 3 * W, 3) float image in [0, 1].
    """
    normal = (0.5 + 0.5 * normal) * coverage[..., None]
    rows = []
    for image, n, d, cov in zip(images, normal, depth, coverage):
        full = cov > 0.99  # silhouette pixels blend depth with the 0 background
        lo, hi = np.percentile(d[full], [1, 99]) if full.any() else (0.0, 1.0)  # per view: near = bright
        shade = np.clip(0.15 + 0.85 * (hi - d) / max(hi - lo, 1e-6), 0, 1) * cov
        rows.append(np.concatenate([image, n, np.repeat(shade[..., None], 3, -1)], axis=1))
    return np.concatenate(rows, axis=0)
