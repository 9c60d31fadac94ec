"""gpja.report.timing: the timing table from benchmark TSVs and registration logs."""
from __future__ import annotations

import pytest

from gpja.errors import InputError
from gpja.report.formats import to_csv, to_markdown
from gpja.report.runs import load_run
from gpja.report.timing import timing_table
from tests.report import E1, E2, md_row, read_csv_rows, write_benchmark, write_log


def test_timing_table_from_benchmarks_and_registration_logs(run_dir, tmp_path):
    bench = tmp_path / "benchmarks"
    for s, seconds in (("S01", 10.0), ("S02", 30.0)):
        write_benchmark(bench / s / "build_template.tsv", seconds, 500.0)
        write_benchmark(bench / s / "check_expression" / f"{E1}.tsv", 1.0, "NA")
        for i, e in enumerate((E1, E2)):
            write_benchmark(bench / s / "gpja" / f"{e}.tsv", seconds + i, 900.0 + i)
            write_benchmark(bench / s / "gpja" / "metrics" / f"{e}.tsv", 5.0, 100.0)
            write_log(run_dir, s, "gpja", e, {"seconds": seconds, "levels": [
                {"vertices": 100, "seconds": 2.0}, {"vertices": 400, "seconds": seconds - 2.0}]})
            write_log(run_dir, s, "nicp", e, {"vertices": 100, "seconds": {"total": 4.0}})
    write_benchmark(bench / "S01" / "old_method" / "metrics" / f"{E1}.tsv", 99.0, 1.0)  # not requested: left out
    run = load_run(run_dir, ["S01", "S02"], ["gpja", "nicp"], [E1, E2])
    table = timing_table(run_dir, bench, run)
    rows = {(r["step"], r["source"]): r for r in read_csv_rows(to_csv(table))}
    assert list(rows) == [("check_expression", "benchmark"), ("build_template", "benchmark"),
                          ("GPJA registration", "benchmark"), ("GPJA optimisation", "log"), ("GPJA level 0", "log"),
                          ("GPJA level 1", "log"), ("GPJA metrics", "benchmark"), ("NICP optimisation", "log")]
    reg = rows[("GPJA registration", "benchmark")]
    assert reg["jobs"] == "4"
    assert (float(reg["median_s"]), float(reg["max_s"]), float(reg["max_rss_mb"])) == (20.5, 31.0, 901.0)
    assert rows[("check_expression", "benchmark")]["max_rss_mb"] == ""
    assert float(rows[("GPJA level 1", "log")]["vertices"]) == 400
    assert float(rows[("GPJA optimisation", "log")]["median_s"]) == 20
    assert md_row(to_markdown(table), "build_template") == ["benchmark", "2", "20.0", "30.0", "500", "–"]
    (run_dir / "S02/nicp/2_smile.json").unlink()
    with pytest.raises(InputError, match="registration log of subject S02, method nicp"):
        timing_table(run_dir, bench, run)


def test_stage_labels_name_the_warm_up_the_flow_stages_and_the_levels():
    from gpja.report.timing import stage_label

    entries = [{"stage": "flow"}, {"stage": "level", "level": 0}, {"stage": "flow2"}, {"stage": "warmup"},
               {"stage": "level", "level": 2}, {"stage": "untangle"}, {"level": 1}]
    assert [stage_label(e, i) for i, e in enumerate(entries)] == ["flow", "level 0", "flow2", "warm-up", "level 2",
                                                                  "untangle", "level 1"]


def test_a_registration_counts_the_vertices_of_its_last_level_not_of_a_stage_after_it():
    from gpja.report.timing import log_vertices

    log = {"levels": [{"stage": "level", "level": 0, "vertices": 16}, {"stage": "level", "level": 1, "vertices": 40},
                      {"stage": "untangle", "folded_before": 3, "folded_after": 0}]}
    assert log_vertices(log) == 40
    assert log_vertices({"levels": [{"stage": "untangle"}]}) is None
    assert log_vertices({"vertices": 7, "levels": []}) == 7
