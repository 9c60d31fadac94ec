"""The paper's tables from the per-expression metrics JSONs, written as CSV, Markdown and LaTeX.

Input: one metrics JSON per (subject, method, expression) at
``{results}/{subject}/{method}/metrics/{expression}.json`` (``gpja metrics``),
the registration logs ``{results}/{subject}/{method}/{expression}.json`` and
Snakemake's benchmark TSVs under ``{benchmarks}/{subject}/``.

Tables (file stem: content):

- ``geometry``: the paper's Table 1: per subject and method the means over the
  expressions of C.D. (L1 Chamfer, mm), N.C. and the F-scores, plus an
  ``Average`` (mean of the subject means) per method. Ablation variants are left
  to ``ablation``.
- ``photometric``: Table 2: per subject and the average, PSNR (dB), SSIM and
  LPIPS per method; a method without texture coordinates shows "–".
- ``ablation``: Table 3: GPJA and each ablation variant present, means over
  every (subject, expression): the paper's geometric error (the scan-to-mesh,
  "point of GT to mesh", distance in mm), C.D. (mm), PSNR, SSIM, LPIPS.
- ``correspondence`` (synthetic data only): mean/median/p95 of the
  correspondence error (mm) per subject and method, means over expressions.
- ``timing``: per workflow step the median and max wall-clock seconds and the
  max RSS (MB) of its jobs (benchmark TSVs), and the registration logs' own
  optimisation seconds, per level for GPJA.

The best value of a column is bolded in Markdown/LaTeX where the paper bolds
(Tables 1 and 3); ties at the printed precision are all bolded. With
``published="facescape"`` the paper's numbers are printed beside the
reproduced ones (rows or columns marked "(paper)"; never bolded).
CSV files are long format with full precision; a missing value is empty.
"""
from __future__ import annotations

import csv
import io
import math
import statistics
from dataclasses import dataclass, field
from pathlib import Path

from gpja.errors import InputError
from gpja.io import read_json, write_text

DASH = "–"
AVERAGE = "Average"
FORMATS = ("csv", "md", "tex")
TABLE_NAMES = ("geometry", "photometric", "ablation", "correspondence", "timing")
PUBLISHED_CHOICES = ("facescape",)

# the ablation variants and the constraint each switches off
ABLATION_CONSTRAINTS = {"gpja-no_normal": "normal", "gpja-no_depth": "depth", "gpja-no_color": "color",
                        "gpja-no_mask": "mask"}
METHOD_LABELS = {"gpja": "GPJA", "nicp": "NICP"}
DATA_STEPS = ("synthesize_subject", "check_expression", "render_scan_targets", "build_template")

GEOMETRY_REQUIRED = ("chamfer_l1_mm", "mesh_to_scan_mm", "scan_to_mesh_mm", "normal_consistency")
PHOTOMETRIC_KEYS = ("psnr", "ssim", "lpips")
CORRESPONDENCE_KEYS = ("mean_mm", "median_mm", "p95_mm")
CORRESPONDENCE_NAMES = tuple(f"correspondence_{k}" for k in CORRESPONDENCE_KEYS)

# printed decimals per metric, as in the paper's tables
DIGITS = {"chamfer_l1_mm": 3, "mesh_to_scan_mm": 3, "scan_to_mesh_mm": 3, "normal_consistency": 3, "fscore": 3,
          "psnr": 2, "ssim": 4, "lpips": 5, "correspondence_mean_mm": 3, "correspondence_median_mm": 3,
          "correspondence_p95_mm": 3}
# which end of a metric is better
BETTER = {"chamfer_l1_mm": "min", "mesh_to_scan_mm": "min", "scan_to_mesh_mm": "min", "normal_consistency": "max",
          "fscore": "max", "psnr": "max", "ssim": "max", "lpips": "min", "correspondence_mean_mm": "min",
          "correspondence_median_mm": "min", "correspondence_p95_mm": "min"}
HEADERS = {"chamfer_l1_mm": "C.D. (mm) ↓", "mesh_to_scan_mm": "Mesh→scan (mm) ↓",
           "scan_to_mesh_mm": "Geometric error (mm) ↓", "normal_consistency": "N.C. ↑", "psnr": "PSNR (dB) ↑",
           "ssim": "SSIM ↑", "lpips": "LPIPS ↓", "correspondence_mean_mm": "Mean (mm) ↓",
           "correspondence_median_mm": "Median (mm) ↓", "correspondence_p95_mm": "P95 (mm) ↓"}

# ---------------------------------------------------------------------------------------------------------------
# The paper's published numbers (FaceScape subjects), transcribed from paper/gpja.tex.

PAPER_GEOMETRY_KEYS = ("chamfer_l1_mm", "normal_consistency", "fscore@0.5", "fscore@1")
# Table 1 (\label{tab:geoMetric}), "Geometric evaluations on 10 expressions per subject in millimeter":
# C.D. (mm), N.C., F@0.5, F@1.0 per FaceScape subject. The paper's "NICP" row is FaceScape's own
# topologically uniform (TU) meshes, obtained by NICP; "NPHM" is the NPHM model's output.
PUBLISHED_GEOMETRY = {
    "NICP": {"7": (0.477, 0.910, 0.708, 0.852), "32": (0.355, 0.942, 0.800, 0.918),
             "122": (0.404, 0.943, 0.738, 0.901), "212": (0.614, 0.915, 0.549, 0.799),
             "340": (0.383, 0.944, 0.743, 0.913), "344": (0.340, 0.936, 0.792, 0.922),
             "350": (0.428, 0.912, 0.746, 0.879)},
    "NPHM": {"7": (0.347, 0.958, 0.814, 0.923), "32": (0.377, 0.970, 0.778, 0.925),
             "122": (0.325, 0.968, 0.825, 0.945), "212": (0.429, 0.949, 0.731, 0.899),
             "340": (0.285, 0.973, 0.858, 0.956), "344": (0.338, 0.957, 0.814, 0.938),
             "350": (0.489, 0.937, 0.682, 0.872)},
    "GPJA": {"7": (0.229, 0.981, 0.909, 0.960), "32": (0.147, 0.992, 0.957, 0.975),
             "122": (0.264, 0.984, 0.880, 0.959), "212": (0.180, 0.980, 0.921, 0.963),
             "340": (0.215, 0.981, 0.912, 0.961), "344": (0.224, 0.975, 0.912, 0.960),
             "350": (0.239, 0.970, 0.891, 0.957)},
}
# Table 2 (\label{tab:ImgMetric}), "Photometric evaluations on 10 expressions per subject" (GPJA only):
# PSNR (dB), SSIM, LPIPS per FaceScape subject; the paper's "Average" row (the mean of the subject rows)
# is kept for reference: the table prints the mean over the subjects of the run instead.
PUBLISHED_PHOTOMETRIC = {
    "GPJA": {"7": (24.75, 0.7810, 0.06868), "32": (20.79, 0.6621, 0.07516), "122": (23.56, 0.7443, 0.07081),
             "212": (25.51, 0.7699, 0.09368), "340": (24.10, 0.7378, 0.06802), "344": (23.08, 0.7569, 0.06791),
             "350": (25.38, 0.7320, 0.07857)},
}
PUBLISHED_PHOTOMETRIC_AVERAGE = {"GPJA": (23.88, 0.7406, 0.07469)}
PAPER_ABLATION_KEYS = ("scan_to_mesh_mm", "psnr", "ssim", "lpips")
# Table 3 (\label{tab:alba}), ablations "on four publishable subjects" (not named in the paper): geometric error
# (the point-to-mesh distance, mm), PSNR (dB), SSIM, LPIPS. The paper has no "w/o mask" row.
PUBLISHED_ABLATION = {
    "gpja": (0.167, 24.06, 0.7523, 0.07511),
    "gpja-no_normal": (0.377, 24.49, 0.7498, 0.07578),
    "gpja-no_depth": (0.455, 23.67, 0.7535, 0.07544),
    "gpja-no_color": (0.447, 22.04, 0.7364, 0.07820),
}

# ---------------------------------------------------------------------------------------------------------------
# Reading the run


def metrics_path(results: str | Path, subject: str, method: str, expression: str) -> Path:
    """Where ``gpja metrics`` writes the scores of one (subject, method, expression)."""
    return Path(results) / subject / method / "metrics" / f"{expression}.json"


def registration_log_path(results: str | Path, subject: str, method: str, expression: str) -> Path:
    """The JSON log a registration (GPJA, NICP) or import writes beside its mesh."""
    return Path(results) / subject / method / f"{expression}.json"


def read_required_json(path: str | Path, what: str) -> dict:
    """Read a JSON object; a missing file raises :class:`InputError` naming it and ``what`` it should hold."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, f"missing: {what}")
    data = read_json(path)
    if not isinstance(data, dict):
        raise InputError(path, "expected a JSON object")
    return data


def is_number(value) -> bool:
    """True for an int or float (not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def check_metrics_record(path: str | Path, record: dict) -> None:
    """Raise :class:`InputError` naming ``path`` when a metrics JSON lacks a score the tables read."""
    geometry = record.get("geometry")
    if not isinstance(geometry, dict):
        raise InputError(path, "no 'geometry' section (not a `gpja metrics` JSON?)")
    for key in GEOMETRY_REQUIRED:
        if not is_number(geometry.get(key)):
            raise InputError(path, f"geometry.{key} is missing or not a number")
    fscore = geometry.get("fscore")
    if not isinstance(fscore, dict) or not fscore or not all(is_number(v) for v in fscore.values()):
        raise InputError(path, "geometry.fscore must map thresholds (mm) to numbers")
    for section, keys in (("photometric", PHOTOMETRIC_KEYS), ("correspondence", CORRESPONDENCE_KEYS)):
        part = record.get(section)
        if part is not None and not (isinstance(part, dict) and all(is_number(part.get(k)) for k in keys)):
            raise InputError(path, f"'{section}' must be null or hold numbers {', '.join(keys)}")


def fscore_name(threshold: str | float) -> str:
    """Metric name of the F-score at ``threshold`` mm: ``fscore@0.5``, ``fscore@1``."""
    return f"fscore@{float(threshold):g}"


def metric_family(name: str) -> str:
    """``fscore@0.5`` -> ``fscore``; other names are their own family."""
    return name.split("@", 1)[0]


def flat_metrics(record: dict) -> dict[str, float]:
    """A metrics JSON's headline scores as ``{name: value}``.

    Names: ``chamfer_l1_mm``, ``mesh_to_scan_mm``, ``scan_to_mesh_mm`` (mm), ``normal_consistency``,
    ``fscore@<t>`` (t in mm); with photometry ``psnr`` (dB), ``ssim``, ``lpips``; with synthetic ground
    truth ``correspondence_mean_mm``, ``correspondence_median_mm``, ``correspondence_p95_mm`` (mm).
    """
    geometry = record["geometry"]
    values = {key: float(geometry[key]) for key in GEOMETRY_REQUIRED}
    values.update({fscore_name(t): float(v) for t, v in geometry["fscore"].items()})
    if record.get("photometric"):
        values.update({key: float(record["photometric"][key]) for key in PHOTOMETRIC_KEYS})
    if record.get("correspondence"):
        values.update({f"correspondence_{k}": float(record["correspondence"][k]) for k in CORRESPONDENCE_KEYS})
    return values


@dataclass
class Run:
    """A run's flattened scores: ``values[(subject, method, expression)] = {metric: value}``."""

    subjects: list[str]
    methods: list[str]
    expressions: list[str]
    values: dict[tuple[str, str, str], dict[str, float]]
    paths: dict[tuple[str, str, str], Path]


def load_run(results: str | Path, subjects, methods, expressions) -> Run:
    """Read every metrics JSON of ``subjects`` x ``methods`` x ``expressions``; a missing one raises InputError."""
    values, paths = {}, {}
    for subject in subjects:
        for method in methods:
            for expression in expressions:
                path = metrics_path(results, subject, method, expression)
                what = f"metrics of subject {subject}, method {method}, expression {expression} (`gpja metrics`)"
                record = read_required_json(path, what)
                check_metrics_record(path, record)
                values[(subject, method, expression)] = flat_metrics(record)
                paths[(subject, method, expression)] = path
    return Run(list(subjects), list(methods), list(expressions), values, paths)


def fscore_names(run: Run) -> list[str]:
    """The F-score names every record of ``run`` has, by threshold."""
    common = set.intersection(*({n for n in v if n.startswith("fscore@")} for v in run.values.values()))
    return sorted(common, key=lambda n: float(n.split("@")[1]))


# ---------------------------------------------------------------------------------------------------------------
# Statistics


def mean_or_none(values: list[float]) -> float | None:
    """Arithmetic mean, None for no values."""
    return statistics.fmean(values) if values else None


def means(dicts: list[dict], names) -> dict[str, float | None]:
    """Per name, the mean over the dicts that have a value for it (None where none has)."""
    return {n: mean_or_none([d[n] for d in dicts if d.get(n) is not None]) for n in names}


def subject_stats(run: Run, methods, names) -> dict[tuple[str, str], dict[str, float | None]]:
    """``{(subject, method): means over expressions}`` plus ``(AVERAGE, method)``: the mean of the subject means."""
    stats = {}
    for method in methods:
        for subject in run.subjects:
            stats[(subject, method)] = means([run.values[(subject, method, e)] for e in run.expressions], names)
        stats[(AVERAGE, method)] = means([stats[(s, method)] for s in run.subjects], names)
    return stats


def count_values(run: Run, subjects, method: str, name: str) -> int:
    """How many expressions of ``subjects`` have a value of metric ``name`` for ``method``."""
    return sum(run.values[(s, method, e)].get(name) is not None for s in subjects for e in run.expressions)


def paper_subject(subject: str) -> str:
    """FaceScape subject id as the paper writes it (``007`` -> ``7``)."""
    return (subject.lstrip("0") or "0") if subject.isdigit() else subject


def published_stats(table: dict, keys, subjects) -> dict[str, dict[str, dict[str, float | None]]]:
    """``{label: {subject: {metric: value}}}`` of a published table for the run's ``subjects`` (None where
    the paper has no such subject), plus ``AVERAGE``: the mean over the subjects the paper has."""
    out = {}
    for label, per_subject in table.items():
        rows = {s: dict(zip(keys, per_subject[paper_subject(s)])) for s in subjects if paper_subject(s) in per_subject}
        out[label] = {s: rows.get(s, dict.fromkeys(keys)) for s in subjects}
        out[label][AVERAGE] = means(list(rows.values()), keys)
    return out


# ---------------------------------------------------------------------------------------------------------------
# Table model

# a label is plain text (escaped for LaTeX) or a (markdown, latex) pair
Label = str | tuple[str, str]


@dataclass
class Cell:
    """A number printed with ``digits`` decimals ("–" for None)."""

    value: float | None
    digits: int
    bold: bool = False

    def text(self) -> str:
        return DASH if self.value is None else f"{self.value:.{self.digits}f}"


@dataclass
class Block:
    """One header and its rows: ``label_columns`` leading label columns, then number columns.

    ``groups``: spanning headers ``(label, span)`` over the number columns; ``rules``: row indices a
    horizontal rule is drawn before; ``reference_rows``: rows of published numbers (never bolded);
    ``better``: per column ``"min"``/``"max"`` (bold the best) or None.
    """

    headers: list[Label]
    rows: list[list]
    label_columns: int = 1
    groups: list[tuple[Label, int]] = field(default_factory=list)
    rules: set[int] = field(default_factory=set)
    reference_rows: set[int] = field(default_factory=set)
    better: list[str | None] = field(default_factory=list)
    title: str = ""


@dataclass
class Table:
    """A table's Markdown/LaTeX blocks and its long-format CSV."""

    name: str
    caption: str
    blocks: list[Block]
    csv_header: list[str]
    csv_rows: list[list]
    notes: list[str] = field(default_factory=list)


def mark_best(block: Block) -> None:
    """Bold the best printed value of each column with a ``better`` direction (ties all bolded)."""
    for col, better in enumerate(block.better):
        if better is None:
            continue
        cells = [row[col] for i, row in enumerate(block.rows)
                 if i not in block.reference_rows and isinstance(row[col], Cell) and row[col].value is not None]
        printed = [float(c.text()) for c in cells]
        if len(printed) < 2:
            continue
        best = min(printed) if better == "min" else max(printed)
        for cell, value in zip(cells, printed):
            cell.bold = value == best


def plural(n: int, noun: str) -> str:
    """``1 expression``, ``4 expressions``."""
    return f"{n} {noun}" + ("" if n == 1 else "s")


def metric_cell(value: float | None, name: str) -> Cell:
    """A cell of metric ``name`` printed with the paper's decimals."""
    return Cell(value, DIGITS[metric_family(name)])


def header(name: str) -> str:
    """Column header of a metric, with its unit and the arrow of better."""
    if metric_family(name) == "fscore":
        threshold = float(name.split("@")[1])
        return f"F@{threshold:.1f} ↑" if threshold.is_integer() else f"F@{threshold:g} ↑"
    return HEADERS[name]


def method_label(method: str) -> str:
    """Display name of a method (``gpja`` -> ``GPJA``); imported methods keep their config name."""
    if method in ABLATION_CONSTRAINTS:
        return f"GPJA w/o {ABLATION_CONSTRAINTS[method]}"
    return METHOD_LABELS.get(method, method)


def ablation_label(method: str) -> Label:
    """Row label of Table 3: ``GPJA`` or ``w/o L_normal`` (LaTeX ``w/o $\\mathcal{L}_{normal}$``)."""
    constraint = ABLATION_CONSTRAINTS.get(method)
    if constraint is None:
        return method_label(method)
    if constraint == "mask":
        return "w/o mask"
    return (f"w/o L_{constraint}", rf"w/o $\mathcal{{L}}_{{{constraint}}}$")


def paper_label(label: Label) -> Label:
    """The label of a row or column of published numbers."""
    if isinstance(label, tuple):
        return (f"{label[0]} (paper)", f"{label[1]} (paper)")
    return f"{label} (paper)"


def subject_label(subject: str) -> str:
    """``7`` -> ``Subject 7``; the average keeps its name."""
    return subject if subject == AVERAGE else f"Subject {subject}"


def comparison_methods(methods) -> list[str]:
    """The methods of Tables 1 and 2: all but the ablation variants (all when only variants are given)."""
    main = [m for m in methods if m not in ABLATION_CONSTRAINTS]
    return main or list(methods)


def ablation_methods(methods) -> list[str]:
    """The rows of Table 3: ``gpja`` first, then the ablation variants in the given order."""
    return [m for m in methods if m == "gpja"] + [m for m in methods if m in ABLATION_CONSTRAINTS]


# ---------------------------------------------------------------------------------------------------------------
# Table 1: geometry


def geometry_block(columns, methods, stats, published, names, title) -> Block:
    """Rows: methods (then published rows); column groups: subjects and the average; columns: ``names``."""
    rows = [[method_label(m)] + [metric_cell(stats[(g, m)][n], n) for g in columns for n in names] for m in methods]
    reference = [[paper_label(label)] + [metric_cell(per[g].get(n), n) for g in columns for n in names]
                 for label, per in published.items()]
    block = Block(headers=["Method"] + [header(n) for _ in columns for n in names], rows=rows + reference,
                  groups=[(subject_label(g), len(names)) for g in columns],
                  rules={len(rows)} if reference else set(),
                  reference_rows=set(range(len(rows), len(rows) + len(reference))),
                  better=[None] + [BETTER[metric_family(n)] for _ in columns for n in names], title=title)
    mark_best(block)
    return block


def geometry_table(run: Run, published: str | None = None) -> Table:
    """Table 1: C.D. (mm), N.C., F-scores per subject and method (means over expressions), and their average."""
    methods = comparison_methods(run.methods)
    fscores = fscore_names(run)
    names = ["chamfer_l1_mm", "normal_consistency", *fscores]
    stats = subject_stats(run, methods, names)
    columns = run.subjects + [AVERAGE]
    paper = published_stats(PUBLISHED_GEOMETRY, PAPER_GEOMETRY_KEYS, run.subjects) if published else {}
    blocks = [geometry_block(columns, methods, stats, paper, names[:2], "C.D. and N.C."),
              geometry_block(columns, methods, stats, paper, fscores, "F-scores")]
    csv_header = ["subject", "method", "source", "expressions", *names]
    csv_rows = [[g, m, "reproduced", count_values(run, run.subjects if g == AVERAGE else [g], m, names[0]),
                 *[stats[(g, m)][n] for n in names]] for m in methods for g in columns]
    csv_rows += [[g, label, "paper", "", *[per[g].get(n) for n in names]]
                 for label, per in paper.items() for g in columns]
    notes = [(f"Means over {plural(len(run.expressions), 'expression')} per subject; {AVERAGE}: the mean of the "
              "subject means. C.D.: L1 Chamfer distance; N.C.: normal consistency; F@t: F-score at t mm.")]
    if paper:
        notes.append("(paper): Table 1 of the paper (FaceScape); its NICP row is FaceScape's TU meshes; "
                     f"its {AVERAGE} is the mean over the subjects of this run that the paper has.")
    caption = "Geometric evaluation: C.D. (mm), N.C. and F-scores per subject, means over the expressions."
    return Table("geometry", caption, blocks, csv_header, csv_rows, notes)


# ---------------------------------------------------------------------------------------------------------------
# Table 2: photometry


def photometric_table(run: Run, published: str | None = None) -> Table:
    """Table 2: PSNR (dB), SSIM, LPIPS per subject (means over expressions) and their average, per method."""
    methods = comparison_methods(run.methods)
    names = list(PHOTOMETRIC_KEYS)
    stats = subject_stats(run, methods, names)
    paper = published_stats(PUBLISHED_PHOTOMETRIC, names, run.subjects) if published else {}
    lines = run.subjects + [AVERAGE]
    rows = [[subject_label(s)] + [metric_cell(stats[(s, m)][n], n) for m in methods for n in names]
            + [metric_cell(per[s][n], n) for per in paper.values() for n in names] for s in lines]
    groups = [(method_label(m), len(names)) for m in methods] + [(paper_label(label), len(names)) for label in paper]
    block = Block(headers=["Subject"] + [header(n) for _ in groups for n in names], rows=rows, groups=groups,
                  rules={len(run.subjects)})
    csv_header = ["subject", "method", "source", "expressions", *names]
    csv_rows = [[s, m, "reproduced", count_values(run, run.subjects if s == AVERAGE else [s], m, "psnr"),
                 *[stats[(s, m)][n] for n in names]] for m in methods for s in lines]
    csv_rows += [[s, label, "paper", "", *[per[s][n] for n in names]] for label, per in paper.items() for s in lines]
    notes = [f"Means over the expressions; {AVERAGE}: the mean of the subject means."]
    if any(stats[(AVERAGE, m)]["psnr"] is None for m in methods):
        notes.append(f"{DASH}: no photometric scores (the method's meshes have no texture coordinates).")
    if paper:
        notes.append(f"(paper): Table 2 of the paper (FaceScape, GPJA); its {AVERAGE} is the mean over the "
                     "subjects of this run that the paper has.")
    caption = "Photometric evaluation: PSNR (dB), SSIM and LPIPS per subject, means over the expressions."
    return Table("photometric", caption, [block], csv_header, csv_rows, notes)


# ---------------------------------------------------------------------------------------------------------------
# Table 3: ablations


def ablation_table(run: Run, published: str | None = None) -> Table:
    """Table 3: GPJA and its ablation variants, means over every (subject, expression) of the run."""
    variants = ablation_methods(run.methods)
    if not variants:
        raise InputError("--methods", "the ablation table needs gpja or an ablation variant (gpja-no_*)")
    names = ["scan_to_mesh_mm", "chamfer_l1_mm", *PHOTOMETRIC_KEYS]
    stats = {m: means([run.values[(s, m, e)] for s in run.subjects for e in run.expressions], names)
             for m in variants}
    rows = [[ablation_label(m)] + [metric_cell(stats[m][n], n) for n in names] for m in variants]
    paper = {m: dict(zip(PAPER_ABLATION_KEYS, v)) for m, v in PUBLISHED_ABLATION.items()} if published else {}
    reference = [[paper_label(ablation_label(m))] + [metric_cell(v.get(n), n) for n in names] for m, v in paper.items()]
    rules = ({1} if variants[0] == "gpja" and len(variants) > 1 else set()) | ({len(rows)} if reference else set())
    block = Block(headers=["Method"] + [header(n) for n in names], rows=rows + reference, rules=rules,
                  reference_rows=set(range(len(rows), len(rows) + len(reference))),
                  better=[None] + [BETTER[n] for n in names])
    mark_best(block)
    pairs = len(run.subjects) * len(run.expressions)
    csv_header = ["method", "source", "expressions", *names]
    csv_rows = [[m, "reproduced", pairs, *[stats[m][n] for n in names]] for m in variants]
    csv_rows += [[m, "paper", "", *[v.get(n) for n in names]] for m, v in paper.items()]
    notes = [(f"Means over {plural(len(run.subjects), 'subject')} x {plural(len(run.expressions), 'expression')}. "
              "Geometric error: the scan-to-mesh (point of the scan to mesh) distance, as in the paper; "
              "C.D.: L1 Chamfer distance.")]
    if paper:
        notes.append("(paper): Table 3 of the paper (FaceScape, four unnamed subjects; no C.D. given).")
    caption = "Ablations: geometric error (mm), C.D. (mm), PSNR (dB), SSIM and LPIPS of GPJA without each constraint."
    return Table("ablation", caption, [block], csv_header, csv_rows, notes)


# ---------------------------------------------------------------------------------------------------------------
# Correspondence (synthetic ground truth)


def correspondence_table(run: Run) -> Table:
    """Mean/median/p95 correspondence error (mm) per subject and method, means over expressions."""
    names = list(CORRESPONDENCE_NAMES)
    if not any(names[0] in v for v in run.values.values()):
        first = next(iter(run.paths.values()))
        raise InputError(first, "no correspondence scores in any metrics JSON (they need synthetic ground truth)")
    stats = subject_stats(run, run.methods, names)
    lines = run.subjects + [AVERAGE]
    rows = [[subject_label(s), method_label(m)] + [metric_cell(stats[(s, m)][n], n) for n in names]
            for s in lines for m in run.methods]
    block = Block(headers=["Subject", "Method"] + [header(n) for n in names], rows=rows, label_columns=2,
                  rules={i * len(run.methods) for i in range(1, len(lines))})
    csv_header = ["subject", "method", "expressions", *names]
    csv_rows = [[s, m, count_values(run, run.subjects if s == AVERAGE else [s], m, names[0]),
                 *[stats[(s, m)][n] for n in names]] for s in lines for m in run.methods]
    notes = [("Distance (mm) between where a template vertex lands and where its ground-truth point moved, means "
              f"over the expressions of the per-expression mean, median and 95th percentile. {DASH}: not scored.")]
    caption = "Correspondence error against the synthetic ground truth (mm) per subject and method."
    return Table("correspondence", caption, [block], csv_header, csv_rows, notes)


# ---------------------------------------------------------------------------------------------------------------
# Timing


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
    levels = log.get("levels") or []
    return int(levels[-1]["vertices"]) if levels and is_number(levels[-1].get("vertices")) else None


def load_logs(results: str | Path, subjects, method: str, expressions) -> list[dict]:
    """The registration logs of one method; a missing one raises InputError."""
    return [read_required_json(registration_log_path(results, s, method, e),
                               f"registration log of subject {s}, method {method}, expression {e}")
            for s in subjects for e in expressions]


def log_rows(method: str, logs: list[dict]) -> list[tuple[str, list, list]]:
    """``(step, seconds, vertices)`` rows from a method's logs: the total, then each level (GPJA)."""
    rows = [(f"{method_label(method)} optimisation", [log_seconds(g) for g in logs], [log_vertices(g) for g in logs])]
    depth = max((len(g.get("levels") or []) for g in logs), default=0)
    for i in range(depth):
        levels = [g["levels"][i] for g in logs if len(g.get("levels") or []) > i]
        stage = "warm-up" if levels[0].get("stage") == "warmup" else f"level {levels[0].get('level', i)}"
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


# ---------------------------------------------------------------------------------------------------------------
# Rendering


def md_label(label: Label) -> str:
    """Markdown text of a label (pipes escaped)."""
    text = label[0] if isinstance(label, tuple) else label
    return text.replace("|", "\\|")


def latex_escape(text: str) -> str:
    """Plain text as LaTeX: specials escaped, arrows and the dash made LaTeX."""
    specials = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
                "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
                "↓": r"$\downarrow$", "↑": r"$\uparrow$", "→": r"$\rightarrow$", DASH: "--"}
    return "".join(specials.get(ch, ch) for ch in text)


def latex_label(label: Label) -> str:
    """LaTeX of a label: the given LaTeX of a pair, else the escaped text."""
    return label[1] if isinstance(label, tuple) else latex_escape(label)


def cell_markdown(item) -> str:
    if isinstance(item, Cell):
        return f"**{item.text()}**" if item.bold else item.text()
    return md_label(item)


def cell_latex(item) -> str:
    if isinstance(item, Cell):
        text = latex_escape(item.text())
        return rf"\textbf{{{text}}}" if item.bold else text
    return latex_label(item)


def flat_headers(block: Block) -> list[str]:
    """Markdown headers: a number column's group label prefixed (Markdown has no spanning header)."""
    groups = [md_label(label) for label, span in block.groups for _ in range(span)]
    labels = [md_label(h) for h in block.headers]
    if not groups:
        return labels
    return labels[:block.label_columns] + [f"{g} {h}" for g, h in zip(groups, labels[block.label_columns:])]


def markdown_block(block: Block) -> str:
    """One GitHub-flavoured pipe table."""
    align = [":---"] * block.label_columns + ["---:"] * (len(block.headers) - block.label_columns)
    lines = ["| " + " | ".join(flat_headers(block)) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(cell_markdown(c) for c in row) + " |" for row in block.rows]
    return "\n".join(lines) + "\n"


def to_markdown(table: Table) -> str:
    """The table as Markdown: caption, one pipe table per block (titled when several), notes."""
    parts = [f"**{table.caption}**\n"]
    for block in table.blocks:
        if block.title and len(table.blocks) > 1:
            parts.append(f"*{block.title}*\n")
        parts.append(markdown_block(block))
    parts += [note + "\n" for note in table.notes]
    return "\n".join(parts)


def latex_block_header(block: Block) -> list[str]:
    """The header line(s) of a block: spanning group labels with cmidrules, then the column headers."""
    lines = []
    if block.groups:
        cells, rules, col = [""] * block.label_columns, [], block.label_columns + 1
        for label, span in block.groups:
            cells.append(rf"\multicolumn{{{span}}}{{c}}{{{latex_label(label)}}}")
            rules.append(rf"\cmidrule(lr){{{col}-{col + span - 1}}}")
            col += span
        lines += [" & ".join(cells) + r" \\", " ".join(rules)]
    lines.append(" & ".join(latex_label(h) for h in block.headers) + r" \\")
    return lines


def to_latex(table: Table) -> str:
    """The table as a booktabs ``table`` float (needs ``\\usepackage{booktabs}``)."""
    widths = {len(b.headers) for b in table.blocks}
    if len(widths) != 1:
        raise ValueError(f"table {table.name}: blocks differ in column count {sorted(widths)}")
    first = table.blocks[0]
    spec = "l" * first.label_columns + "c" * (len(first.headers) - first.label_columns)
    lines = [f"% {table.name}: written by `gpja tables` (gpja/report/tables.py)"]
    lines += [f"% {note}" for note in table.notes]
    lines += [r"\begin{table}[t]", r"\centering", rf"\caption{{{latex_escape(table.caption)}}}",
              rf"\label{{tab:gpja-{table.name}}}", rf"\begin{{tabular}}{{{spec}}}", r"\toprule"]
    for i, block in enumerate(table.blocks):
        if i:
            lines.append(r"\midrule")
        lines += latex_block_header(block) + [r"\midrule"]
        for j, row in enumerate(block.rows):
            if j in block.rules:
                lines.append(r"\midrule")
            lines.append(" & ".join(cell_latex(c) for c in row) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}", r"\end{table}"]
    return "\n".join(lines) + "\n"


def csv_value(value) -> str:
    """A CSV field: full-precision numbers, empty for None."""
    if value is None:
        return ""
    return repr(float(value)) if isinstance(value, float) else str(value)


def to_csv(table: Table) -> str:
    """The table's long-format rows as CSV text."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(table.csv_header)
    writer.writerows([[csv_value(v) for v in row] for row in table.csv_rows])
    return out.getvalue()


def write_table(table: Table, out_dir: str | Path) -> list[Path]:
    """Write ``{out_dir}/{name}.csv``, ``.md`` and ``.tex`` atomically; return their paths."""
    texts = {"csv": to_csv(table), "md": to_markdown(table), "tex": to_latex(table)}
    paths = []
    for ext in FORMATS:
        path = Path(out_dir) / f"{table.name}.{ext}"
        write_text(path, texts[ext])
        paths.append(path)
    return paths


# ---------------------------------------------------------------------------------------------------------------
# Entry point


def default_tables(run: Run, ablation_run: Run | None = None) -> list[str]:
    """The tables a run supports: geometry, photometric and timing; ablation with ablation variants;
    correspondence when a metrics JSON has correspondence scores."""
    names = ["geometry", "photometric"]
    if any(m in ABLATION_CONSTRAINTS for m in (ablation_run or run).methods):
        names.append("ablation")
    if any(CORRESPONDENCE_NAMES[0] in v for v in run.values.values()):
        names.append("correspondence")
    return names + ["timing"]


def build_tables(results: str | Path, benchmarks: str | Path, subjects, methods, expressions,
                 names=None, published: str | None = None, ablation_subjects=None,
                 ablation_expressions=None) -> list[Table]:
    """The requested tables (default: :func:`default_tables`) of a run; ``published``: ``"facescape"`` or None.

    Every method is read for every subject and expression, unless ``ablation_subjects`` or
    ``ablation_expressions`` is given: then the ablation variants (and ``gpja`` beside them, in Table 3)
    are read on those only (default: all), and Tables 1-2 hold the other methods.
    """
    if published is not None and published not in PUBLISHED_CHOICES:
        raise InputError("--published", f"unknown {published!r}; choose from {', '.join(PUBLISHED_CHOICES)}")
    unknown = [n for n in names or [] if n not in TABLE_NAMES]
    if unknown:
        raise InputError("--tables", f"unknown table(s) {', '.join(unknown)}; choose from {', '.join(TABLE_NAMES)}")
    if ablation_subjects is None and ablation_expressions is None:
        run = ablation_run = load_run(results, subjects, methods, expressions)
    else:
        variants = [m for m in methods if m in ABLATION_CONSTRAINTS]
        run = load_run(results, subjects, [m for m in methods if m not in ABLATION_CONSTRAINTS], expressions)
        ablation_run = (load_run(results, ablation_subjects or subjects, ["gpja", *variants],
                                 ablation_expressions or expressions) if variants else None)
    if "ablation" in (names or []) and ablation_run is None:
        raise InputError("--tables", "the ablation table needs ablation variants (gpja-no_*) in --methods")
    extra = [ablation_run] if ablation_run is not None and ablation_run is not run else []
    builders = {"geometry": lambda: geometry_table(run, published),
                "photometric": lambda: photometric_table(run, published),
                "ablation": lambda: ablation_table(ablation_run, published),
                "correspondence": lambda: correspondence_table(run),
                "timing": lambda: timing_table(results, benchmarks, run, extra)}
    return [builders[name]() for name in (names or default_tables(run, ablation_run))]
