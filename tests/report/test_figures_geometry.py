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


def test_texture_error_title_names_the_psnr_of_observed_and_unobserved_texels(tmp_path):
    import json

    from gpja.report.figures_geometry import texture_error_title

    path = tmp_path / "texture_quality.json"
    assert "PSNR" not in texture_error_title(path)  # no scores yet: the panel is still titled
    path.write_text(json.dumps({"observed": {"psnr": 31.25}, "unobserved": {"psnr": None}}))
    assert texture_error_title(path).endswith("PSNR observed 31.2 dB")
    path.write_text(json.dumps({"observed": {"psnr": 31.25}, "unobserved": {"psnr": 22.0}}))
    assert texture_error_title(path).endswith("PSNR observed 31.2 dB\nPSNR unobserved 22.0 dB")
