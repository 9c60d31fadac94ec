"""The paper's tables from the per-expression metrics JSONs, written as CSV, Markdown and LaTeX.

Input: one metrics JSON per (subject, method, expression) (``gpja metrics``; read by
``gpja.report.runs``), the registration logs and Snakemake's benchmark TSVs (``gpja.report.timing``).
The methods' labels and kinds (which rows are ablation variants) come from ``gpja.methods``; the paper's
numbers from ``gpja.report.published``; the table model is ``gpja.report.table_model`` and the three
formats ``gpja.report.formats``.

Tables (file stem: content):

- ``geometry``: the paper's Table 1: per subject and method the means over the
  expressions of C.D. (L1 Chamfer, mm), N.C. and the F-scores, plus an
  ``Average`` (mean of the subject means) per method. Ablation variants are left
  to ``ablation``. References with geometric scores (the oracle: the true surface
  against its scan, what the scan's noise costs) follow as unbolded rows (CSV:
  source ``reference``).
- ``photometric``: Table 2: per subject and the average, PSNR (dB), SSIM and
  LPIPS per method; a method without texture coordinates shows "–". References
  (``gpja.methods`` kind ``reference``: the oracle, the ground truth rendered by our
  renderer) follow the methods as their own column group (CSV: rows with source
  ``reference``); of the other tables only ``geometry`` shows them.
- ``ablation``: Table 3: GPJA and each ablation variant present, mean ± sample
  standard deviation (n - 1) over every (subject, expression) pair of the run
  (the mean alone for one pair; the mean is what is bolded): the paper's
  geometric error (the scan-to-mesh, "point of GT to mesh", distance in mm),
  C.D. (mm), PSNR, SSIM, LPIPS (and the correspondence median/mean on
  synthetic data). A second block, "Paired differences against full GPJA":
  per variant and key metric (C.D., PSNR, the correspondence median/mean) the
  mean of variant - GPJA over the pairs both are scored on, its seeded
  percentile bootstrap 95 % interval (``BOOTSTRAP_SEED``; "–" below 2 pairs)
  and "GPJA better in k of n". CSV: the means' rows gain ``<metric>_sd``
  columns; rows with source ``paired_difference`` fill ``metric``,
  ``mean_difference``, ``ci_low``, ``ci_high``, ``gpja_better``, ``pairs``.
- ``correspondence`` (synthetic data only): mean/median/p95 of the
  correspondence error (mm) per subject and method, means over expressions.
- ``correspondence_regions``, ``position_regions`` and ``texture`` (synthetic data only): the correspondence
  error by facial region, the position error (the ground truth's side of it) overall and by region, and the
  texture's quality against the ground-truth albedo (``gpja.report.tables_truth``).
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

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gpja.errors import InputError
from gpja.methods import label as method_label
from gpja.methods import method
from gpja.metrics.texture_quality import QUALITY_FILE
from gpja.report.published import (
    PAPER_ABLATION_KEYS,
    PAPER_GEOMETRY_KEYS,
    PUBLISHED_ABLATION,
    PUBLISHED_CHOICES,
    PUBLISHED_GEOMETRY,
    PUBLISHED_PHOTOMETRIC,
    published_stats,
)
from gpja.report.runs import (
    AVERAGE,
    CORRESPONDENCE_NAMES,
    PHOTOMETRIC_KEYS,
    POSITION_NAMES,
    REGION_NAMES,
    Run,
    count_values,
    fscore_names,
    load_run,
    means,
    metric_family,
    sds,
    subject_stats,
    with_floors,
)
from gpja.report.table_model import (
    BETTER,
    DASH,
    Block,
    Label,
    Table,
    header,
    label_text,
    mark_best,
    metric_cell,
    paper_label,
    plural,
    subject_label,
)
from gpja.report.tables_truth import (correspondence_regions_table, floor_note, position_regions_table, row_label,
                                     texture_table)
from gpja.report.tables_applications import turns_table
from gpja.report.timing import timing_table
from gpja.results import Layout

#: Every table ``gpja tables`` can write (file stems).
TABLE_NAMES = ("geometry", "photometric", "ablation", "correspondence", "correspondence_regions", "position_regions",
               "texture", "turns", "timing")


def is_reference(name: str) -> bool:
    """Whether ``name`` is a reference, not a method (``gpja.methods`` kind ``reference``: the oracle)."""
    return method(name).kind == "reference"


def is_ablation(name: str) -> bool:
    """Whether ``name`` is an ablation variant of GPJA (``gpja.methods`` kind ``ablation``)."""
    return method(name).kind == "ablation"


def ablation_label(name: str) -> Label:
    """Row label of Table 3: ``GPJA`` or ``w/o L_normal`` (LaTeX ``w/o $\\mathcal{L}_{normal}$``)."""
    return method(name).ablation_label


def comparison_methods(methods) -> list[str]:
    """The methods of Tables 1 and 2: all but the ablation variants (all when only variants are given)."""
    main = [m for m in methods if not is_ablation(m)]
    return main or list(methods)


def ablation_methods(methods) -> list[str]:
    """The rows of Table 3: ``gpja`` first, then the ablation variants in the given order."""
    return [m for m in methods if method(m).kind == "gpja"] + [m for m in methods if is_ablation(m)]


# ---------------------------------------------------------------------------------------------------------------
# Table 1: geometry


def geometry_block(columns, methods, stats, published, names, title, refs=()) -> Block:
    """Rows: methods, then the references ``refs`` (the oracle; their statistics in ``stats`` too), then published
    rows; column groups: subjects and the average; columns: ``names``. Only the methods' rows are bolded."""
    rows = [[method_label(m)] + [metric_cell(stats[(g, m)][n], n) for g in columns for n in names] for m in methods]
    reference = [[method_label(m)] + [metric_cell(stats[(g, m)][n], n) for g in columns for n in names] for m in refs]
    reference += [[paper_label(label)] + [metric_cell(per[g].get(n), n) for g in columns for n in names]
                  for label, per in published.items()]
    block = Block(headers=["Method"] + [header(n) for _ in columns for n in names], rows=rows + reference,
                  groups=[(subject_label(g), len(names)) for g in columns],
                  rules={len(rows)} if reference else set(),
                  reference_rows=set(range(len(rows), len(rows) + len(reference))),
                  better=[None] + [BETTER[metric_family(n)] for _ in columns for n in names], title=title)
    mark_best(block)
    return block


def geometry_table(run: Run, published: str | None = None, references: Run | None = None) -> Table:
    """Table 1: C.D. (mm), N.C., F-scores per subject and method (means over expressions), and their average;
    then the references of ``references`` that have geometric scores (the oracle: the true surface against the scan),
    then the paper's numbers."""
    methods = comparison_methods(run.methods)
    fscores = fscore_names(run)
    names = ["chamfer_l1_mm", "normal_consistency", *fscores]
    stats = subject_stats(run, methods, names)
    refs = [m for m in (references.methods if references is not None else [])
            if count_values(references, references.subjects, m, names[0])]
    if refs:
        stats.update(subject_stats(references, refs, names))
    columns = run.subjects + [AVERAGE]
    paper = published_stats(PUBLISHED_GEOMETRY, PAPER_GEOMETRY_KEYS, run.subjects) if published else {}
    blocks = [geometry_block(columns, methods, stats, paper, names[:2], "C.D. and N.C.", refs),
              geometry_block(columns, methods, stats, paper, fscores, "F-scores", refs)]
    csv_header = ["subject", "method", "source", "expressions", *names]
    csv_rows = [[g, m, "reproduced", count_values(run, run.subjects if g == AVERAGE else [g], m, names[0]),
                 *[stats[(g, m)][n] for n in names]] for m in methods for g in columns]
    csv_rows += [[g, m, "reference", count_values(references, references.subjects if g == AVERAGE else [g], m,
                                                  names[0]), *[stats[(g, m)][n] for n in names]]
                 for m in refs for g in columns]
    csv_rows += [[g, label, "paper", "", *[per[g].get(n) for n in names]]
                 for label, per in paper.items() for g in columns]
    notes = [(f"Means over {plural(len(run.expressions), 'expression')} per subject; {AVERAGE}: the mean of the "
              "subject means. C.D.: L1 Chamfer distance; N.C.: normal consistency; F@t: F-score at t mm.")]
    if refs:
        notes.append(f"{', '.join(method_label(m) for m in refs)}: the expression's true (noise-free) surface scored "
                     "against its scan like every method (gpja/metrics/oracle.py): what the scan's noise alone costs, "
                     "C.D. 0 and N.C. 0.9997 (its vertex normals against its faces') on a noise-free scan; not bolded.")
    if paper:
        notes.append("(paper): Table 1 of the paper (FaceScape); its NICP row is FaceScape's TU meshes; "
                     f"its {AVERAGE} is the mean over the subjects of this run that the paper has.")
    caption = "Geometric evaluation: C.D. (mm), N.C. and F-scores per subject, means over the expressions."
    return Table("geometry", caption, blocks, csv_header, csv_rows, notes)


# ---------------------------------------------------------------------------------------------------------------
# Table 2: photometry


def photometric_table(run: Run, published: str | None = None, references: Run | None = None) -> Table:
    """Table 2: PSNR (dB), SSIM, LPIPS per subject (means over expressions) and their average, per method;
    then the references of ``references`` (the oracle), then the paper's numbers."""
    methods = comparison_methods(run.methods)
    names = list(PHOTOMETRIC_KEYS)
    stats = subject_stats(run, methods, names)
    refs = list(references.methods) if references is not None else []
    if refs:
        stats.update(subject_stats(references, refs, names))
    paper = published_stats(PUBLISHED_PHOTOMETRIC, names, run.subjects) if published else {}
    lines = run.subjects + [AVERAGE]
    rows = [[subject_label(s)] + [metric_cell(stats[(s, m)][n], n) for m in methods + refs for n in names]
            + [metric_cell(per[s][n], n) for per in paper.values() for n in names] for s in lines]
    groups = [(method_label(m), len(names)) for m in methods + refs]
    groups += [(paper_label(label), len(names)) for label in paper]
    block = Block(headers=["Subject"] + [header(n) for _ in groups for n in names], rows=rows, groups=groups,
                  rules={len(run.subjects)})
    csv_header = ["subject", "method", "source", "expressions", *names]
    csv_rows = [[s, m, "reproduced", count_values(run, run.subjects if s == AVERAGE else [s], m, "psnr"),
                 *[stats[(s, m)][n] for n in names]] for m in methods for s in lines]
    csv_rows += [[s, m, "reference", count_values(references, references.subjects if s == AVERAGE else [s], m, "psnr"),
                  *[stats[(s, m)][n] for n in names]] for m in refs for s in lines]
    csv_rows += [[s, label, "paper", "", *[per[s][n] for n in names]] for label, per in paper.items() for s in lines]
    notes = [f"Means over the expressions; {AVERAGE}: the mean of the subject means."]
    if refs:
        notes.append(f"{', '.join(method_label(m) for m in refs)}: the expression's scan at its true (noise-free) "
                     "positions with the ground-truth albedo "
                     "and SH lighting, rendered by our renderer at the reference cameras and scored like every method "
                     "(gpja/metrics/oracle.py): the best any method can score here.")
    if any(stats[(AVERAGE, m)]["psnr"] is None for m in methods):
        notes.append(f"{DASH}: no photometric scores (the method's meshes have no texture coordinates).")
    if paper:
        notes.append(f"(paper): Table 2 of the paper (FaceScape, GPJA); its {AVERAGE} is the mean over the "
                     "subjects of this run that the paper has.")
    caption = "Photometric evaluation: PSNR (dB), SSIM and LPIPS per subject, means over the expressions."
    return Table("photometric", caption, [block], csv_header, csv_rows, notes)


# ---------------------------------------------------------------------------------------------------------------
# Table 3: ablations


#: The seed of Table 3's bootstrap intervals (:func:`bootstrap_interval`): the table is deterministic.
BOOTSTRAP_SEED = 0
#: Resamples (with replacement) of the bootstrap intervals.
BOOTSTRAP_RESAMPLES = 2000
#: Confidence level of the bootstrap intervals.
BOOTSTRAP_LEVEL = 0.95
#: Below about this many (subject, expression) pairs an ordering of Table 3's rows is not evidence (its notes).
FEW_PAIRS = 5
#: The metrics each variant is compared on pair by pair against GPJA (the correspondence ones where scored).
PAIRED_NAMES = ("chamfer_l1_mm", "psnr", "correspondence_median_mm", "correspondence_mean_mm")
#: Table 3's CSV columns of a paired difference (empty on the other rows).
PAIRED_COLUMNS = ("metric", "mean_difference", "ci_low", "ci_high", "gpja_better", "pairs")


def ablation_records(run: Run, name: str) -> list[dict]:
    """Method ``name``'s flat metrics per (subject, expression) of ``run``, subject-major: Table 3's pairs."""
    return [run.values[(s, name, e)] for s in run.subjects for e in run.expressions]


def paired_differences(variant: list[dict], reference: list[dict], name: str) -> np.ndarray:
    """``variant - reference`` of metric ``name`` (in its unit), shape (n,), over the pairs both have a value on.

    ``variant``, ``reference``: flat metrics per (subject, expression), in the same order (:func:`ablation_records`).
    """
    return np.array([v[name] - r[name] for v, r in zip(variant, reference)
                     if v.get(name) is not None and r.get(name) is not None], dtype=float)


def bootstrap_interval(diffs, level: float = BOOTSTRAP_LEVEL, resamples: int = BOOTSTRAP_RESAMPLES,
                       seed: int = BOOTSTRAP_SEED) -> tuple[float, float] | None:
    """Percentile bootstrap interval ``(low, high)`` of the mean of ``diffs`` (shape (n,), any unit).

    The ``(1 - level) / 2`` and ``(1 + level) / 2`` quantiles of the means of ``resamples`` resamples of the n values
    with replacement, drawn by numpy ``default_rng(seed)`` (deterministic). None for fewer than 2 values.
    """
    diffs = np.asarray(diffs, dtype=float)
    if diffs.size < 2:
        return None
    draws = np.random.default_rng(seed).integers(0, diffs.size, size=(resamples, diffs.size))
    low, high = np.quantile(diffs[draws].mean(axis=1), [(1 - level) / 2, (1 + level) / 2])
    return float(low), float(high)


def wins(diffs, better: str) -> int:
    """On how many pairs the reference is better, from ``diffs`` = variant - reference (shape (n,)).

    ``better``: ``"min"`` (distances, LPIPS: the positive differences count) or ``"max"`` (PSNR, SSIM: the
    negative ones), as in :data:`gpja.report.table_model.BETTER`; ties count for neither.
    """
    diffs = np.asarray(diffs, dtype=float)
    return int(np.count_nonzero(diffs > 0 if better == "min" else diffs < 0))


@dataclass
class Paired:
    """A variant against GPJA on one metric (its unit) over the ``pairs`` (subject, expression) both are scored on:
    the mean of variant - GPJA (None without pairs), its :func:`bootstrap_interval` (None for fewer than 2 pairs)
    and on how many pairs GPJA is better (:func:`wins`)."""

    pairs: int
    mean: float | None
    interval: tuple[float, float] | None
    gpja_better: int


def paired(variant: list[dict], reference: list[dict], name: str) -> Paired:
    """:class:`Paired` statistics of metric ``name``, ``variant`` against ``reference`` (:func:`paired_differences`)."""
    diffs = paired_differences(variant, reference, name)
    return Paired(int(diffs.size), float(diffs.mean()) if diffs.size else None, bootstrap_interval(diffs),
                  wins(diffs, BETTER[metric_family(name)]))


def signed(value: float | None, name: str) -> str:
    """A difference of metric ``name`` with its sign, at the metric's decimals (``+0.012``; "–" for None)."""
    if value is None:
        return DASH
    digits = metric_cell(value, name).digits
    return f"{round(value, digits) + 0.0:+.{digits}f}"  # + 0.0: no "-0.000"


def paired_block(stats: dict[tuple[str, str], Paired], labels: dict[str, str]) -> Block:
    """Table 3's second block: per (variant, metric) of ``stats`` the mean difference against GPJA, its interval and
    GPJA's wins; ``labels``: the metrics' column headers."""
    rows = []
    for (m, n), c in stats.items():
        interval = DASH if c.interval is None else f"[{signed(c.interval[0], n)}, {signed(c.interval[1], n)}]"
        rows.append([ablation_label(m), labels[n], signed(c.mean, n), interval, f"{c.gpja_better} of {c.pairs}"])
    variants = list(dict.fromkeys(m for m, _ in stats))
    per_variant = len(stats) // len(variants)
    return Block(headers=["Variant", "Metric", "Mean difference (variant - GPJA)",
                          f"{BOOTSTRAP_LEVEL:.0%} interval", "GPJA better in"],
                 rows=rows, label_columns=2, rules={i * per_variant for i in range(1, len(variants))},
                 title="Paired differences against full GPJA")


def ablation_notes(run: Run, compared: bool) -> list[str]:
    """What Table 3's ± and (with ``compared``: paired differences shown) its intervals are, and how few pairs
    are too few."""
    pairs = len(run.subjects) * len(run.expressions)
    notes = [(f"Mean ± sample standard deviation (n - 1 denominator) over the n = {pairs} (subject, expression) "
              f"pairs ({plural(len(run.subjects), 'subject')} x {plural(len(run.expressions), 'expression')}; fewer "
              "where a pair has no value); with a single value, the value alone. "
              "Geometric error: the scan-to-mesh (point of the scan to mesh) distance, as in the paper; "
              "C.D.: L1 Chamfer distance.")]
    if compared:
        notes.append(f"Paired differences: variant - GPJA on each pair both are scored on; their mean, its "
                     f"{BOOTSTRAP_LEVEL:.0%} percentile bootstrap interval over the pairs ({BOOTSTRAP_RESAMPLES} "
                     f"resamples, seed {BOOTSTRAP_SEED}; {DASH} with fewer than 2 pairs) and on how many of the n "
                     "pairs GPJA is better (lower distance, higher PSNR; ties count for neither).")
    notes.append(f"With fewer than about {FEW_PAIRS} pairs (here {pairs}) an ordering of the rows is not evidence, "
                 "and a bootstrap interval from so few values is crude (it never reaches beyond the smallest and "
                 "largest difference).")
    return notes


def ablation_table(run: Run, published: str | None = None) -> Table:
    """Table 3: GPJA and its ablation variants, mean ± sample SD over every (subject, expression) of the run, and
    each variant's paired differences against GPJA on :data:`PAIRED_NAMES`."""
    variants = ablation_methods(run.methods)
    if not variants:
        raise InputError("--methods", "the ablation table needs gpja or an ablation variant (gpja-no_*)")
    names = ["scan_to_mesh_mm", "chamfer_l1_mm", *PHOTOMETRIC_KEYS]
    # synthetic data: what each variant does to the dense correspondence (the mouth, the sliding)
    scored = [n for n in ("correspondence_median_mm", "correspondence_mean_mm")
              if any(v.get(n) is not None for v in run.values.values())]
    names += scored
    records = {m: ablation_records(run, m) for m in variants}
    stats = {m: means(records[m], names) for m in variants}
    spread = {m: sds(records[m], names) for m in variants}
    rows = [[ablation_label(m)] + [metric_cell(stats[m][n], n, spread[m][n]) for n in names] for m in variants]
    paper = {m: dict(zip(PAPER_ABLATION_KEYS, v)) for m, v in PUBLISHED_ABLATION.items()} if published else {}
    reference = [[paper_label(ablation_label(m))] + [metric_cell(v.get(n), n) for n in names] for m, v in paper.items()]
    rules = ({1} if variants[0] == "gpja" and len(variants) > 1 else set()) | ({len(rows)} if reference else set())
    # beside geometry and photometry, the correspondence columns say what they are
    headers = [("Corr. " + header(n)[0].lower() + header(n)[1:]) if n in scored else header(n) for n in names]
    block = Block(headers=["Method"] + headers, rows=rows + reference, rules=rules,
                  reference_rows=set(range(len(rows), len(rows) + len(reference))),
                  better=[None] + [BETTER[n] for n in names], title="Mean ± SD over the (subject, expression) pairs")
    mark_best(block)
    compared = [m for m in variants if m != "gpja"] if "gpja" in variants else []
    versus = {(m, n): paired(records[m], records["gpja"], n) for m in compared for n in PAIRED_NAMES if n in names}
    blocks = [block] + ([paired_block(versus, dict(zip(names, headers)))] if versus else [])
    pairs = len(run.subjects) * len(run.expressions)
    csv_header = ["method", "source", "expressions", *names, *[f"{n}_sd" for n in names], *PAIRED_COLUMNS]
    blank, unpaired = [None] * len(names), [None] * len(PAIRED_COLUMNS)
    csv_rows = [[m, "reproduced", pairs, *[stats[m][n] for n in names], *[spread[m][n] for n in names], *unpaired]
                for m in variants]
    csv_rows += [[m, "paper", "", *[v.get(n) for n in names], *blank, *unpaired] for m, v in paper.items()]
    csv_rows += [[m, "paired_difference", "", *blank, *blank, n, c.mean, *(c.interval or (None, None)),
                  c.gpja_better, c.pairs] for (m, n), c in versus.items()]
    notes = ablation_notes(run, bool(versus))
    if paper:
        notes.append("(paper): Table 3 of the paper (FaceScape, four unnamed subjects; no C.D. given).")
    if scored:
        notes.append("Correspondence: median and mean error against the synthetic ground truth (mm).")
    shown = [label_text(ablation_label(m)) for m in variants if m != "gpja"]
    caption = ("Ablations: geometric error (mm), C.D. (mm), PSNR (dB), SSIM and LPIPS of GPJA"
               + (f" and its variants ({', '.join(shown)})" if shown else "")
               + (", and each variant's paired differences against GPJA." if versus else "."))
    return Table("ablation", caption, blocks, csv_header, csv_rows, notes)


# ---------------------------------------------------------------------------------------------------------------
# Correspondence (synthetic ground truth)


def correspondence_table(run: Run) -> Table:
    """Mean/median/p95 correspondence error (mm) per subject and method, means over expressions."""
    names = list(CORRESPONDENCE_NAMES)
    if not any(names[0] in v for v in run.values.values()):
        first = next(iter(run.paths.values()))
        raise InputError(first, "no correspondence scores in any metrics JSON (they need synthetic ground truth)")
    run = with_floors(run)
    stats = subject_stats(run, run.methods, names)
    lines = run.subjects + [AVERAGE]
    rows = [[subject_label(s), row_label(m)] + [metric_cell(stats[(s, m)][n], n) for n in names]
            for s in lines for m in run.methods]
    block = Block(headers=["Subject", "Method"] + [header(n) for n in names], rows=rows, label_columns=2,
                  rules={i * len(run.methods) for i in range(1, len(lines))})
    csv_header = ["subject", "method", "expressions", *names]
    csv_rows = [[s, m, count_values(run, run.subjects if s == AVERAGE else [s], m, names[0]),
                 *[stats[(s, m)][n] for n in names]] for s in lines for m in run.methods]
    notes = [("Distance (mm) between where a template vertex lands and where its ground-truth point moved, means "
              f"over the expressions of the per-expression mean, median and 95th percentile. {DASH}: not scored."),
             *floor_note(run)]
    caption = "Correspondence error against the synthetic ground truth (mm) per subject and method."
    return Table("correspondence", caption, [block], csv_header, csv_rows, notes)


# ---------------------------------------------------------------------------------------------------------------
# Entry point


def default_tables(run: Run, ablation_run: Run | None = None, results: str | Path | None = None) -> list[str]:
    """The tables a run supports: geometry, photometric and timing; ablation with ablation variants;
    correspondence when a metrics JSON has correspondence scores, correspondence_regions when one has
    per-region scores; texture when every subject's template has its ``texture_quality.json``; turns when every
    subject has its artist mesh's ``reparam/turns.json``."""
    names = ["geometry", "photometric"]
    if any(is_ablation(m) for m in (ablation_run or run).methods):
        names.append("ablation")
    if any(CORRESPONDENCE_NAMES[0] in v for v in run.values.values()):
        names.append("correspondence")
    if any(n in v for v in run.values.values() for n in REGION_NAMES):
        names.append("correspondence_regions")
    if any(POSITION_NAMES[0] in v for v in run.values.values()):
        names.append("position_regions")
    if results is not None and all(Layout(results).template_file(s, QUALITY_FILE).is_file() for s in run.subjects):
        names.append("texture")
    if results is not None and all(Layout(results).reparam_turns(s).is_file() for s in run.subjects):
        names.append("turns")
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
    references = [m for m in methods if is_reference(m)]
    methods = [m for m in methods if not is_reference(m)]
    reference_run = load_run(results, subjects, references, expressions) if references else None
    if ablation_subjects is None and ablation_expressions is None:
        run = ablation_run = load_run(results, subjects, methods, expressions)
    else:
        variants = [m for m in methods if is_ablation(m)]
        run = load_run(results, subjects, [m for m in methods if not is_ablation(m)], expressions)
        ablation_run = (load_run(results, ablation_subjects or subjects, ["gpja", *variants],
                                 ablation_expressions or expressions) if variants else None)
    if "ablation" in (names or []) and ablation_run is None:
        raise InputError("--tables", "the ablation table needs ablation variants (gpja-no_*) in --methods")
    extra = [ablation_run] if ablation_run is not None and ablation_run is not run else []
    builders = {"geometry": lambda: geometry_table(run, published, reference_run),
                "photometric": lambda: photometric_table(run, published, reference_run),
                "ablation": lambda: ablation_table(ablation_run, published),
                "correspondence": lambda: correspondence_table(run),
                "correspondence_regions": lambda: correspondence_regions_table(run),
                "position_regions": lambda: position_regions_table(run),
                "texture": lambda: texture_table(results, run.subjects),
                "turns": lambda: turns_table(results, run.subjects),
                "timing": lambda: timing_table(results, benchmarks, run, extra)}
    return [builders[name]() for name in (names or default_tables(run, ablation_run, results))]
