"""gpja.report.figures_geometry: the scan errors the heatmaps are drawn from must match the scan."""
from __future__ import annotations

import numpy as np
import pytest

from gpja.errors import InputError
from gpja.report.figures import RunFiles
from gpja.report.figures_geometry import scan_errors
from gpja.results import Layout


def test_scan_errors_must_match_the_scan(tmp_path):
    files = RunFiles(Layout(tmp_path))
    details = files.layout.metrics_details("S01", "gpja", "1_neutral")
    details.mkdir(parents=True)
    np.savez(details / "geometry_errors.npz", scan_vertex_error_mm=np.zeros(5))
    assert scan_errors(files, "S01", "gpja", "1_neutral", 5).shape == (5,)
    with pytest.raises(InputError, match="geometry_errors.npz.*re-run the metrics"):
        scan_errors(files, "S01", "gpja", "1_neutral", 6)
    np.savez(details / "geometry_errors.npz", other=np.zeros(5))
    with pytest.raises(InputError, match="scan_vertex_error_mm"):
        scan_errors(files, "S01", "gpja", "1_neutral", 5)
