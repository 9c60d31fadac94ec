"""CI regression check: identical, better, within-tolerance and worse runs; missing files; reference round trip."""
from __future__ import annotations

import json

import pytest

from gpja.cli import main
from gpja.errors import InputError
from gpja.report import regression as R
from tests.report import write_metrics

E1, E2 = "1_neutral", "12_lip_puckerer"


def write_run(root, cd=0.10, psnr=25.0, lpips=0.20, f05=0.90, corr=(1.0, 0.5, 3.0), photo=True):
    """S01 x gpja, nicp x two expressions; the gpja/1_neutral scores are the ones a test varies."""
    for method in ("gpja", "nicp"):
        for e in (E1, E2):
            vary = method == "gpja" and e == E1
            write_metrics(root, "S01", method, e, cd=cd if vary else 0.2, nc=0.98, f05=f05 if vary else 0.8,
                          f1=0.95, photo=((psnr if vary else 24.0, 0.75, lpips if vary else 0.3) if photo else None),
                          corr=corr)
    return root


@pytest.fixture
def reference(tmp_path):
    path = tmp_path / "ci_reference_metrics.json"
    assert R.write_reference(write_run(tmp_path / "ref"), path) == 4
    return path


def check(tmp_path, reference, tolerances=None, **run):
    failures, compared = R.check_regression(write_run(tmp_path / "run", **run), reference, tolerances)
    return [f.line() for f in failures], compared


def test_reference_round_trip_and_identical_run_passes(tmp_path, reference):
    data = json.loads(reference.read_text())
    assert data["format"] == R.REFERENCE_FORMAT
    entry = data["metrics"]["S01"]["gpja"][E1]
    assert entry["chamfer_l1_mm"] == 0.10 and entry["fscore@0.5"] == 0.90 and entry["psnr"] == 25.0
    assert entry["correspondence_p95_mm"] == 3.0 and len(entry) == 12
    failures, compared = check(tmp_path, reference)
    assert failures == [] and compared == 4 * 12


def test_worse_beyond_tolerance_fails_naming_metric_place_values_and_direction(tmp_path, reference):
    failures, _ = check(tmp_path, reference, cd=0.2, psnr=23.5, lpips=0.25, f05=0.8)
    assert len(failures) == 6  # C.D. and both directions (the fake run sets all three), PSNR, LPIPS, F@0.5
    chamfer = next(f for f in failures if "chamfer_l1_mm" in f)
    assert chamfer.startswith(f"FAIL S01/gpja/{E1} chamfer_l1_mm: reference 0.1, run 0.2, worse by 0.1")
    assert "tolerance 0.05 (higher is worse, allowed +max(0.05 mm, 30% of reference))" in chamfer
    psnr = next(f for f in failures if " psnr:" in f)
    assert "reference 25, run 23.5" in psnr and "lower is worse, allowed -1 dB" in psnr
    assert any(" lpips:" in f and "higher is worse, allowed +0.03)" in f for f in failures)
    assert any(" fscore@0.5:" in f and "lower is worse" in f for f in failures)


def test_better_and_within_tolerance_pass(tmp_path, reference):
    assert check(tmp_path, reference, cd=0.05, psnr=30.0, lpips=0.1, f05=0.99)[0] == []
    assert check(tmp_path, reference, cd=0.149, psnr=24.1, lpips=0.229, f05=0.845)[0] == []
    # correspondence mean of 1.0 mm: the 0.5 mm absolute allowance exceeds 30% of it
    assert check(tmp_path, reference, corr=(1.49, 0.5, 3.0))[0] == []
    assert len(check(tmp_path, reference, corr=(1.6, 0.5, 3.0))[0]) == 4  # every entry's mean


def test_missing_run_file_or_metric_fails_clearly(tmp_path, reference):
    run = write_run(tmp_path / "run")
    (run / "S01/nicp/metrics" / f"{E2}.json").unlink()
    failures, compared = R.check_regression(run, reference)
    assert [f.line() for f in failures] == [
        f"FAIL S01/nicp/{E2}: metrics file missing: {run / 'S01/nicp/metrics' / f'{E2}.json'}"]
    assert compared == 3 * 12
    failures, _ = check(tmp_path, reference, photo=False)
    assert len(failures) == 4 * 3 and all("missing or not finite in the run" in f for f in failures)


def test_tolerances_are_overridable_and_checked(tmp_path, reference):
    override = tmp_path / "tol.json"
    override.write_text(json.dumps({"psnr": {"absolute": 1.5}, **{name: {"relative": 0.6} for name in
                                        ("chamfer_l1_mm", "mesh_to_scan_mm", "scan_to_mesh_mm")}}))
    tolerances = R.load_tolerances(override)
    assert tolerances["psnr"] == {"worse": "lower", "absolute": 1.5, "relative": 0.0}
    assert check(tmp_path, reference, tolerances, psnr=24.0, cd=0.15)[0] == []
    override.write_text(json.dumps({"psnr": {"worse": "higher"}}))
    with pytest.raises(InputError, match="only absolute and relative"):
        R.load_tolerances(override)
    override.write_text(json.dumps({"psnrr": {"absolute": 1}}))
    with pytest.raises(InputError, match="unknown metric 'psnrr'"):
        R.load_tolerances(override)


def test_bad_reference_file_is_an_input_error(tmp_path):
    bad = tmp_path / "ref.json"
    bad.write_text(json.dumps({"metrics": {}}))
    with pytest.raises(InputError, match="not a reference file"):
        R.check_regression(tmp_path, bad)
    bad.write_text(json.dumps({"format": R.REFERENCE_FORMAT, "metrics": {"S01": {"gpja": {E1: {"iou": 1.0}}}}}))
    with pytest.raises(InputError, match="without a tolerance: iou"):
        R.check_regression(tmp_path, bad)
    with pytest.raises(InputError, match="no metrics JSON found"):
        R.write_reference(tmp_path / "empty", tmp_path / "out.json")


def test_cli_exit_status_and_report(tmp_path, capsys):
    ref = tmp_path / "ref.json"
    base = ["check-regression", "--reference", str(ref), "--metrics"]
    assert main(base + [str(write_run(tmp_path / "ref")), "--write-reference", "--methods", "gpja"]) == 0
    assert set(json.loads(ref.read_text())["metrics"]["S01"]) == {"gpja"}
    assert main(base + [str(write_run(tmp_path / "same"))]) == 0
    assert "24 metrics compared" in capsys.readouterr().out
    assert main(base + [str(write_run(tmp_path / "worse", cd=0.2))]) == 1
    out = capsys.readouterr().out
    assert f"FAIL S01/gpja/{E1} chamfer_l1_mm: reference 0.1, run 0.2" in out and "3 failure(s)" in out
    assert "lpips: higher is worse" in out and "psnr: lower is worse" in out
    assert main(base[:-1] + ["--metrics", str(tmp_path), "--reference", str(tmp_path / "absent.json")]) == 2
