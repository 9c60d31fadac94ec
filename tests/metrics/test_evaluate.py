"""The one-JSON-per-expression scorer: settings from the config, and the headline line.

The full path (geometry + photometry + correspondence on real workflow files)
runs in the CI workflow test (tests/test_project.py).
"""
import pytest

from gpja.metrics.evaluate import MetricSettings, summary_line


def test_settings_come_from_the_config_section_and_reject_unknown_keys():
    s = MetricSettings.from_config({"samples": 5000, "thresholds_mm": [0.25, 1], "coverage": "distance"})
    assert s.samples == 5000 and s.thresholds_mm == (0.25, 1.0) and s.coverage == "distance"
    assert MetricSettings.from_config({}) == MetricSettings()
    with pytest.raises(TypeError):
        MetricSettings(unknown_key=1)  # the CLI turns this into an InputError naming --settings


def test_summary_line_names_every_headline_score():
    result = {"geometry": {"chamfer_l1_mm": 0.1234, "normal_consistency": 0.98, "fscore": {"0.5": 0.9, "1": 0.95}},
              "photometric": {"psnr": 25.0, "ssim": 0.8, "lpips": 0.2}, "correspondence": {"mean_mm": 1.5}}
    line = summary_line(result)
    for text in ("C.D. 0.1234 mm", "N.C. 0.9800", "F@0.5 0.9000", "F@1 0.9500", "PSNR 25.00 dB", "SSIM 0.8000",
                 "LPIPS 0.2000", "corr. mean 1.500 mm"):
        assert text in line
    assert "PSNR" not in summary_line({**result, "photometric": None, "correspondence": None})
    assert "position" not in line  # metrics JSONs before the position error
    result["correspondence"]["position"] = {"mean_mm": 0.75, "regions": {"mouth": {"median_mm": 2.25}}}
    assert "position mean 0.750 mm, position mouth median 2.250 mm" in summary_line(result)


def test_a_metric_family_is_one_function_plus_one_registry_entry(monkeypatch, tmp_path):
    """Every family of METRICS is scored into its key of the JSON, in order, with its wall time."""
    from gpja.data.source import DataSource
    from gpja.metrics import evaluate

    seen = []

    def toy(request, result):
        seen.append((request.subject, request.expression, request.method, request.settings.samples))
        result["toy_note"] = "a family may add top-level keys"
        return {"value": 1.5}

    monkeypatch.setattr(evaluate, "METRICS", {"toy": toy, "not_applicable": lambda request, result: None})
    result = evaluate.evaluate_expression(
        mesh_path=tmp_path / "m.obj", subject="S01", expression="1_neutral", method="gpja",
        template_dir=tmp_path, source=DataSource(), targets_path=None, out_dir=tmp_path,
        settings=MetricSettings(samples=7))
    assert seen == [("S01", "1_neutral", "gpja", 7)]
    assert result["toy"] == {"value": 1.5} and result["toy_note"].startswith("a family")
    assert result["not_applicable"] is None
    assert set(result["seconds"]) == {"toy"}  # only families that scored are timed
    assert list(result)[:4] == ["subject", "expression", "method", "mesh"]
