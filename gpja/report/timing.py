"""The timing table: per workflow step the wall clock and peak memory of its jobs, and the seconds the
registration logs report themselves.

Snakemake's benchmark TSVs lie under ``benchmarks/{dataset}/{subject}/`` mirroring the step
(:meth:`gpja.results.Layout.benchmark`): ``{step}.tsv`` and ``{step}/{expression}.tsv`` are data steps,
``{method}/{expression}.tsv`` a method's registration (or import) and ``{method}/metrics/{expression}.tsv``
its scoring. The registration logs are :meth:`gpja.results.Layout.registration_log`.
"""
from __future__ import annotations

import csv
import math
import statistics
from pathlib import Path

from gpja.errors import InputError
from gpja.methods import label as method_label
from gpja.report.runs import Run, is_number, read_required_json
from gpja.report.table_model import Block, Cell, Table
from gpja.results import Layout

#: The data steps (rules) in workflow order: their rows come first.
DATA_STEPS = ("synthesize_subject", "check_expression", "render_scan_targets", "build_template")



def parse_number(text) -> float | None:
    """A benchmark field as a float; None for '-', 'NA', empty or NaN."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(value) else value


def read_benchmark(path: str | Path) -> list[tuple[float | None, float | None]]:
    """``(seconds, max RSS in MB)`` of each row (repeat) of a Snakemake benchmark TSV."""
    with open(path, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    if not rows or "s" not in rows[0]:
        raise InputError(path, "not a Snakemake benchmark TSV (no 's' column or no row)")
    return [(parse_number(r.get("s")), parse_number(r.get("max_rss"))) for r in rows]


def benchmark_step(subject_dir: Path, path: Path, methods, expressions) -> tuple[str, str] | None:
    """The timing row ``(method or "", step)`` a benchmark TSV under ``subject_dir`` belongs to, or None.

    ``{step}.tsv`` and ``{step}/{expression}.tsv`` are data steps (any expression): ``("", step)``;
    ``{method}/{expression}.tsv`` is ``(method, "registration")`` and ``{method}/metrics/{expression}.tsv``
    ``(method, "metrics")``, for the requested methods and expressions only. Folders with a ``metrics``
    subfolder that are not requested (other methods) are left out.
    """
    parts = path.relative_to(subject_dir).parts
    if len(parts) == 1:
        return ("", path.stem)
    top, expression = parts[0], path.stem
    if top in methods:
        if expression not in expressions:
            return None
        if len(parts) == 2:
            return (top, "registration")
        return (top, "metrics") if parts[1:-1] == ("metrics",) else None
    if len(parts) == 2 and not (subject_dir / top / "metrics").is_dir():
        return ("", top)
    return None


def collect_benchmarks(benchmarks: str | Path, subjects, methods, expressions) -> dict[tuple[str, str], list]:
    """``{(method or "", step): [(seconds, max RSS MB), ...]}`` over the subjects' benchmark TSVs."""
    steps: dict[tuple[str, str], list] = {}
    for subject in subjects:
        subject_dir = Path(benchmarks) / subject
        for path in sorted(subject_dir.rglob("*.tsv")) if subject_dir.is_dir() else []:
            step = benchmark_step(subject_dir, path, methods, expressions)
            if step is not None:
                steps.setdefault(step, []).extend(read_benchmark(path))
    return steps


def log_seconds(log: dict) -> float | None:
    """A registration log's own wall-clock seconds (GPJA: ``seconds``; NICP: ``seconds.total``)."""
    seconds = log.get("seconds")
    if isinstance(seconds, dict):
        seconds = seconds.get("total")
    return float(seconds) if is_number(seconds) else None


def log_vertices(log: dict) -> int | None:
    """Vertex count of the registered mesh (``vertices``, or the last level's)."""
    if is_number(log.get("vertices")):
        return int(log["vertices"])
    # the last entry that counts them: a stage after the last level (``untangle``) keeps its mesh
    counted = [lv["vertices"] for lv in log.get("levels") or [] if is_number(lv.get("vertices"))]
    return int(counted[-1]) if counted else None


def load_logs(results: str | Path, subjects, method: str, expressions) -> list[dict]:
    """The registration logs of one method; a missing one raises InputError."""
    layout = Layout(results)
    return [read_required_json(layout.registration_log(s, method, e),
                               f"registration log of subject {s}, method {method}, expression {e}")
            for s in subjects for e in expressions]


def stage_label(entry: dict, index: int) -> str:
    """A registration log entry's row label: ``warm-up``, ``level k``, else the stage's own name (``flow`` /
    ``flow2``, ``untangle``)."""
    stage = str(entry.get("stage", ""))
    if stage == "warmup":
        return "warm-up"
    if stage in ("", "level"):
        return f"level {entry.get('level', index)}"
    return stage


def log_rows(method: str, logs: list[dict]) -> list[tuple[str, list, list]]:
    """``(step, seconds, vertices)`` rows from a method's logs: the total, then each level (GPJA)."""
    rows = [(f"{method_label(method)} optimisation", [log_seconds(g) for g in logs], [log_vertices(g) for g in logs])]
    depth = max((len(g.get("levels") or []) for g in logs), default=0)
    for i in range(depth):
        levels = [g["levels"][i] for g in logs if len(g.get("levels") or []) > i]
        stage = stage_label(levels[0], i)
        rows.append((f"{method_label(method)} {stage}", [lv.get("seconds") for lv in levels],
                     [lv.get("vertices") for lv in levels]))
    return [r for r in rows if any(is_number(s) for s in r[1])]


def timing_row(step: str, source: str, seconds, rss, vertices) -> list:
    """One timing row: jobs, median and max seconds, max RSS (MB), median vertices."""
    seconds = [float(s) for s in seconds if is_number(s)]
    rss = [float(r) for r in rss if is_number(r)]
    vertices = [v for v in vertices if is_number(v)]
    return [step, source, Cell(len(seconds), 0), Cell(statistics.median(seconds) if seconds else None, 1),
            Cell(max(seconds) if seconds else None, 1), Cell(max(rss) if rss else None, 0),
            Cell(statistics.median(vertices) if vertices else None, 0)]


def data_step_order(step: str) -> tuple:
    """Data steps in workflow order, unknown ones after them by name."""
    return (DATA_STEPS.index(step), "") if step in DATA_STEPS else (len(DATA_STEPS), step)


def benchmark_row(step: str, samples: list) -> list:
    """A timing row from benchmark samples ``[(seconds, max RSS MB), ...]``."""
    return timing_row(step, "benchmark", [s for s, _ in samples], [r for _, r in samples], [])


def timing_table(results: str | Path, benchmarks: str | Path, run: Run, extra_runs=()) -> Table:
    """Per step: median/max wall-clock seconds and max RSS of its jobs; the registration logs' own seconds.

    Rows: the data steps, then per method its registration jobs, the seconds its logs report (per level
    for GPJA) and its metrics jobs. Steps without benchmark TSVs are left out. ``extra_runs`` (e.g. the
    ablations, run on fewer subjects or expressions) add rows for methods ``run`` does not have.
    """
    steps = collect_benchmarks(benchmarks, run.subjects, run.methods, run.expressions)
    data = sorted((step for method, step in steps if not method), key=data_step_order)
    rows = [benchmark_row(step, steps[("", step)]) for step in data]
    done = set()
    for part in (run, *extra_runs):
        part_steps = steps if part is run else collect_benchmarks(benchmarks, part.subjects, part.methods,
                                                                  part.expressions)
        for method in (m for m in part.methods if m not in done):
            done.add(method)
            if (method, "registration") in part_steps:
                rows.append(benchmark_row(f"{method_label(method)} registration", part_steps[(method, "registration")]))
            logs = load_logs(results, part.subjects, method, part.expressions)
            rows += [timing_row(name, "log", secs, [], verts) for name, secs, verts in log_rows(method, logs)]
            if (method, "metrics") in part_steps:
                rows.append(benchmark_row(f"{method_label(method)} metrics", part_steps[(method, "metrics")]))
    block = Block(headers=["Step", "Source", "Jobs", "Median (s)", "Max (s)", "Max RSS (MB)", "Vertices"],
                  rows=rows, label_columns=2)
    csv_header = ["step", "source", "jobs", "median_s", "max_s", "max_rss_mb", "vertices"]
    csv_rows = [[r[0], r[1], *[c.value for c in r[2:]]] for r in rows]
    notes = [("benchmark: Snakemake's per-job benchmark TSVs (wall clock, max RSS); log: the seconds a registration "
              "reports itself (optimisation only; per level for GPJA). Vertices: median over the jobs.")]
    caption = "Run time: wall-clock seconds (median and max over the jobs) and peak memory of each workflow step."
    return Table("timing", caption, [block], csv_header, csv_rows, notes)
