"""How far the template's lighting (its ``lighting.json``) is from the synthetic ground truth's.

An albedo and the light it is seen under share one scale per colour channel (a texture twice as
bright under half the light renders the same), so the estimate is compared after both are
brought to the same DC term per channel:

    relative_error = || s * est - truth ||_F / || truth ||_F,   s_c = truth[0, c] / est[0, c]

over the 27 coefficients (9 SH x RGB, ``gpja.lighting`` convention). The synthetic generator
lights a subject the same for every expression (``ground_truth/{subject}/{expression}.npz``
``sh``) and varies a per-expression albedo gain, which the per-channel scale absorbs; the
template expression's file is the reference.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from gpja.errors import InputError

if TYPE_CHECKING:
    from gpja.metrics.evaluate import MetricRequest

#: SH rows of each band (Y00 | Y1-1 Y10 Y11 | Y2-2 .. Y22).
BANDS = {"band0": slice(0, 1), "band1": slice(1, 4), "band2": slice(4, 9)}


def dc_matched(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``estimate`` (9, 3) scaled per channel to ``truth``'s (9, 3) DC term; float64.

    Raises:
        InputError: a DC term of either is not positive (no light).
    """
    est, ref = np.asarray(estimate, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    if est.shape != (9, 3) or ref.shape != (9, 3):
        raise InputError("lighting", f"expected two (9, 3) SH arrays, got {est.shape} and {ref.shape}")
    if not ((est[0] > 0).all() and (ref[0] > 0).all()):
        raise InputError("lighting", "a DC term is not positive: cannot compare lightings")
    return est * (ref[0] / est[0])[None, :]


def sh_relative_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Relative L2 error over the 27 coefficients after DC matching (module docstring); dimensionless."""
    ref = np.asarray(truth, dtype=np.float64)
    return float(np.linalg.norm(dc_matched(estimate, ref) - ref) / np.linalg.norm(ref))


def lighting_scores(estimate: np.ndarray, truth: np.ndarray) -> dict:
    """JSON-able comparison: ``relative_error`` and its part per SH band (each relative to the truth's norm)."""
    ref = np.asarray(truth, dtype=np.float64)
    diff = dc_matched(estimate, ref) - ref
    norm = float(np.linalg.norm(ref))
    return {"relative_error": float(np.linalg.norm(diff) / norm),
            **{f"relative_error_{band}": float(np.linalg.norm(diff[rows]) / norm) for band, rows in BANDS.items()},
            "definition": "||s*est - truth|| / ||truth|| over the 27 SH coefficients, s = truth DC / est DC per channel"}


def score_lighting(request: "MetricRequest", result: dict) -> dict | None:
    """The template's lighting against the synthetic truth of the template expression; None on real data.

    The estimate is the same for every expression and method of a subject; each metrics JSON carries it so
    the tables can read it from any of them.
    """
    from gpja.data.ground_truth import lighting_for
    from gpja.io import read_json
    from gpja.results import LIGHTING_FILE, read_template_lighting

    r = request
    if r.ground_truth_root is None or r.source.rt_scale is not None:
        return None
    estimate = read_template_lighting(r.template_dir)
    truth = lighting_for(r.subject, r.template_expression, r.ground_truth_root)
    return {"source": read_json(r.template_dir / LIGHTING_FILE)["source"], **lighting_scores(estimate, truth)}
