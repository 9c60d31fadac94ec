"""Tests of gpja.data.units: a head in millimetres, and a template and a scan in the same units."""
import numpy as np
import pytest

from gpja.data.units import HEAD_EXTENT_MM, MAX_SCALE_RATIO, check_head_units, check_units
from gpja.errors import InputError
from gpja.mesh import TexturedMesh


def box(size_mm: float) -> np.ndarray:
    """The 8 corners of a cube of side ``size_mm`` (bounding-box diagonal ``sqrt(3) size_mm``)."""
    return size_mm * np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)


def test_head_extent_in_millimetres():
    check_head_units(box(200.0), "head.ply")  # diagonal 346 mm
    for size in (0.2, 2000.0):  # metres; micrometres
        with pytest.raises(InputError, match=r"head.ply: bounding-box diagonal is .* millimetres"):
            check_head_units(box(size), "head.ply")
    lo, hi = HEAD_EXTENT_MM
    check_head_units(box(lo / np.sqrt(3.0) * 1.001), "head.ply")
    check_head_units(box(hi / np.sqrt(3.0) * 0.999), "head.ply")


def test_template_and_scan_in_different_units_are_refused():
    rng = np.random.default_rng(0)
    scan = rng.uniform(-100.0, 100.0, size=(2000, 3))
    template = TexturedMesh(box(200.0) - 100.0, np.array([[0, 1, 2]]))
    check_units(template, scan, "scan.ply")
    check_units(template, scan * (MAX_SCALE_RATIO * 0.9), "scan.ply")
    with pytest.raises(InputError, match="scan.ply: template .* differ in size by .*different units"):
        check_units(template, scan / 1000.0, "scan.ply")
