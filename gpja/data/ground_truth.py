"""What the registration may read from the synthetic ground truth (for now: its lighting).

The synthetic benchmark stores, per expression, ``{ground_truth_root}/{subject}/{expression}.npz``
(``scan_rest_coords``, ``landmarks``, ``landmarks_rest``, ``sh``, ``skin_gain``). Scoring reads it freely; the method
under test should estimate what a real capture lacks, and today reads only the lighting here.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from gpja.io import read_npz
from gpja.lighting import uniform_sh


def lighting_for(subject: str, expression: str, ground_truth_root: str | Path | None) -> np.ndarray:
    """(9, 3) SH lighting: the synthetic ground truth when present, else uniform white light.

    FaceScape was captured under near-uniform light (paper: "a reasonable simplification").
    """
    if ground_truth_root:
        return read_npz(Path(ground_truth_root) / subject / f"{expression}.npz")["sh"]
    return uniform_sh(1.0)
