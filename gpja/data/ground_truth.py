"""The synthetic ground truth's lighting, for scoring only.

The synthetic benchmark stores, per expression, ``{ground_truth_root}/{subject}/{expression}.npz``
(``scan_rest_coords``, ``landmarks``, ``landmarks_rest``, ``sh``, ``skin_gain``). Only the metrics and the
figures read it (the estimated lighting's error, an oracle render); the template and the registrations
estimate the lighting from the images (``gpja.register.lighting_estimate``) and never import this module
(``tests/test_no_oracle.py``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from gpja.io import read_npz
from gpja.lighting import uniform_sh


def lighting_for(subject: str, expression: str, ground_truth_root: str | Path | None) -> np.ndarray:
    """(9, 3) float64 true SH lighting of a synthetic expression; uniform white light without ground truth.

    FaceScape was captured under near-uniform light (paper: "a reasonable simplification").

    Raises:
        InputError: the ground-truth file is missing or corrupt.
    """
    if ground_truth_root:
        return np.asarray(read_npz(Path(ground_truth_root) / subject / f"{expression}.npz")["sh"], dtype=np.float64)
    return uniform_sh(1.0)
