"""Unit checks: is a point set a head in millimetres, and are a template and a scan in the same units?

Every step that reads a mesh or a scan checks it here, so that data in metres (or
with a missing FaceScape ``Rt_scale_dict`` transform) stops with a message naming
the file instead of producing a meaningless fit or score.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from gpja.errors import InputError
from gpja.mesh import TexturedMesh

#: A head scan in millimetres spans roughly 150-500 mm; outside this range the
#: units (or the Rt_scale transform) are almost certainly wrong.
HEAD_EXTENT_MM = (80.0, 1500.0)
#: A template and a scan whose sizes differ by more than this factor are in different units.
MAX_SCALE_RATIO = 3.0


def check_head_units(V: np.ndarray, source: str | Path) -> None:
    """Raise :class:`InputError` if the extent of ``V (n, 3)`` is not that of a head in mm."""
    extent = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    lo, hi = HEAD_EXTENT_MM
    if not lo <= extent <= hi:
        raise InputError(source, f"bounding-box diagonal is {extent:.4g}, expected {lo:g}-{hi:g} for a head in millimetres "
                                 "(wrong units, or a missing/incorrect Rt_scale_dict transform?)")


def check_units(template: TexturedMesh, scan_V: np.ndarray, source: str | Path) -> None:
    """Raise if template and scan ``scan_V (k, 3)`` sizes differ by more than ``MAX_SCALE_RATIO`` (different units).

    The template's size is its bounding-box diagonal; the scan's is the diagonal of
    its 2nd-98th percentile box (robust to stray points).
    """
    size_t = float(np.linalg.norm(np.ptp(template.V, axis=0)))
    size_s = float(np.linalg.norm(np.percentile(scan_V, 98, axis=0) - np.percentile(scan_V, 2, axis=0)))
    ratio = max(size_t, size_s) / max(min(size_t, size_s), 1e-9)
    if ratio > MAX_SCALE_RATIO:
        raise InputError(source, f"template ({size_t:.4g}) and scan ({size_s:.4g}) differ in size by {ratio:.1f}x: "
                                 "different units? (both must be millimetres)")
