"""gpja.report.runs: reading a run's metrics JSONs, and errors naming the file."""
from __future__ import annotations

import pytest

from gpja.errors import InputError
from gpja.report.runs import load_run
from tests.report import E1


def test_missing_metrics_file_names_it(run_dir):
    with pytest.raises(InputError) as err:
        load_run(run_dir, ["S01", "S03"], ["gpja"], [E1])
    assert str(run_dir / "S03/gpja/metrics/1_neutral.json") in str(err.value)
    assert "subject S03, method gpja, expression 1_neutral" in str(err.value)
    (run_dir / "S01/gpja/metrics/1_neutral.json").write_text('{"geometry": {"chamfer_l1_mm": 1}}')
    with pytest.raises(InputError, match="geometry.mesh_to_scan_mm"):
        load_run(run_dir, ["S01"], ["gpja"], [E1])
