"""benchmarks/: the scripts' own bookkeeping (their timings are measured by running them, not here)."""
import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def load_benchmark(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_register_benchmark_reports_every_kind_of_log_entry():
    """A level, a flow stage (its rounds a list) and the untangling (its rounds a count) each give a row."""
    level_entry = load_benchmark("bench_register").level_entry
    level = {"stage": "level", "level": 0, "vertices": 16, "iterations": 10, "seconds": 3.0, "setup_seconds": 1.0,
             "seconds_by_stage": {"render": 1.5}}
    assert level_entry(level) == {"level": 1, "vertices": 16, "iterations": 10, "seconds": 3.0, "setup_seconds": 1.0,
                                  "iterations_per_second": 5.0, "seconds_by_stage": {"render": 1.5}}
    flow = {"stage": "flow2", "vertices": 40, "seconds": 2.0, "rounds": [{"moved": 1.0}, {"moved": 0.5}]}
    assert level_entry(flow) == {"level": "flow2", "vertices": 40, "seconds": 2.0, "rounds": 2}
    untangle = {"stage": "untangle", "seconds": 4.1, "rounds": 17, "folded_before": 3, "folded_after": 0}
    assert level_entry(untangle) == {"level": "untangle", "vertices": None, "seconds": 4.1, "rounds": 17}


def test_register_presets_are_schedules_and_paper_fast_only_adds_the_speed_levers():
    from gpja.register.multiscale import Schedule

    bench = load_benchmark("bench_register")
    schedules = {name: Schedule.from_config(preset, name) for name, preset in bench.PRESETS.items()}
    assert schedules["paper"].views_per_iteration is None and schedules["paper"].face_order == "mesh"
    added = {k: v for k, v in bench.PAPER_FAST.items() if bench.PAPER.get(k) != v}
    assert set(added) == {"views_per_iteration", "image_factor", "face_order", "average_iterations"}
    assert schedules["paper-fast"].lambdas == schedules["paper"].lambdas
    assert schedules["paper-fast"].iterations == schedules["paper"].iterations


def test_startup_benchmark_commands_stop_where_a_job_without_metrics_does(tmp_path):
    # both variants must run the same command to its expected error (exit 2 -> 0), or the timing compares nothing
    bench = load_benchmark("bench_startup")
    lazy = bench.COMMAND.format(d=str(tmp_path))
    assert bench.run(lazy) > 0 and bench.run(bench.EAGER + lazy) > 0


def test_startup_benchmark_open3d_pair_runs_the_same_query():
    # the pair differs only in the plain import; both must run their query (run() raises on a failed one)
    bench = load_benchmark("bench_startup")
    assert bench.OPEN3D["plain"].endswith(bench.OPEN3D["deferred"])
    assert all(bench.run(code) > 0 for code in bench.OPEN3D.values())
