"""The template lighting's error against the synthetic truth: DC matching, analytic values, the metric family."""
from types import SimpleNamespace

import numpy as np
import pytest

from gpja.errors import InputError
from gpja.io import write_json, write_npz
from gpja.lighting import uniform_sh
from gpja.metrics.lighting import dc_matched, lighting_scores, score_lighting, sh_relative_error
from gpja.results import LIGHTING_FILE, lighting_record
from tests.tolerances import EXACT_F64


def truth_sh() -> np.ndarray:
    sh = uniform_sh(1.1)
    sh[1:4] = [[0.5, 0.45, 0.4], [1.0, 0.95, 0.9], [-0.3, -0.3, -0.25]]
    sh[6] = 0.05
    return sh


def test_a_per_channel_rescaled_estimate_has_no_error():
    """Albedo and light share one scale per channel: only the shape of the lighting counts."""
    truth = truth_sh()
    estimate = truth * np.array([0.4, 1.7, 2.5])
    np.testing.assert_allclose(dc_matched(estimate, truth), truth, atol=EXACT_F64)
    assert sh_relative_error(estimate, truth) < EXACT_F64


def test_analytic_error_of_a_missing_directional_part():
    """Uniform light against a light with band-1 part b: error = ||b|| / ||truth||."""
    truth = truth_sh()
    scores = lighting_scores(uniform_sh(1.0), truth)
    band1, band2 = np.linalg.norm(truth[1:4]), np.linalg.norm(truth[4:])
    norm = np.linalg.norm(truth)
    assert scores["relative_error"] == pytest.approx(np.hypot(band1, band2) / norm, rel=1e-12)
    assert scores["relative_error_band1"] == pytest.approx(band1 / norm, rel=1e-12)
    assert scores["relative_error_band0"] == pytest.approx(0.0, abs=EXACT_F64)


def test_lightings_without_light_are_refused():
    with pytest.raises(InputError, match="not positive"):
        sh_relative_error(-uniform_sh(1.0), truth_sh())
    with pytest.raises(InputError, match=r"\(9, 3\)"):
        sh_relative_error(np.ones((4, 3)), truth_sh())


def test_metric_family_reads_the_template_lighting_and_the_template_expression_truth(tmp_path):
    truth = truth_sh()
    write_npz(tmp_path / "gt/S01/3_mouth_stretch.npz", sh=truth)
    estimate = truth.copy()
    estimate[2] *= 1.1
    write_json(tmp_path / "template" / LIGHTING_FILE, lighting_record(estimate * 0.8, "estimated", "test"))
    request = SimpleNamespace(ground_truth_root=tmp_path / "gt", source=SimpleNamespace(rt_scale=None),
                              template_dir=tmp_path / "template", subject="S01", expression="1_neutral",
                              template_expression="3_mouth_stretch")
    scores = score_lighting(request, {})
    assert scores["source"] == "estimated"
    assert scores["relative_error"] == pytest.approx(0.1 * np.linalg.norm(truth[2]) / np.linalg.norm(truth))
    assert score_lighting(SimpleNamespace(**{**vars(request), "ground_truth_root": None}), {}) is None
