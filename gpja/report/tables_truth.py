"""Tables that need the synthetic ground truth: the correspondence error by facial region and the texture's
quality against the generator's albedo.

- ``correspondence_regions``: per subject (and the ``Average`` of the subject means) and method, the
  median and mean correspondence error (mm) of each facial region (:mod:`gpja.metrics.regions`), means
  over the expressions of the per-expression values in ``correspondence.regions`` of the metrics JSONs.
  Both correspondence tables give each method's floor a row under it (``correspondence.floor``: the least its
  scored vertices can score; :func:`gpja.report.runs.with_floors`).
- ``position_regions``: the same from the ground truth's side (``correspondence.position``: the distance from
  each registered vertex to where the expression put its material, which also counts the vertices that left
  the scan), with the overall median, mean and 95th percentile first.
- ``texture``: per subject, PSNR (dB) and SSIM of the template's texture against the ground-truth albedo
  over the observed and the unobserved texels, the fitted per-channel gain and the texel counts
  (``template/texture_quality.json``, :mod:`gpja.metrics.texture_quality`).
"""
from __future__ import annotations

from pathlib import Path

from gpja.errors import InputError
from gpja.methods import label as method_label
from gpja.metrics.regions import RADII_MM, REGION_LABELS, REGIONS
from gpja.metrics.texture_quality import QUALITY_FILE
from gpja.report.runs import (
    AVERAGE,
    CORRESPONDENCE_KEYS,
    FLOOR_SUFFIX,
    POSITION_NAMES,
    POSITION_REGION_NAMES,
    REGION_KEYS,
    REGION_NAMES,
    Run,
    count_values,
    floor_label,
    mean_or_none,
    read_required_json,
    region_name,
    subject_stats,
    with_floors,
)
from gpja.report.table_model import DASH, Block, Cell, Table, header, metric_cell, subject_label
from gpja.results import Layout

#: Flat metric of each per-region key (digits and headers as the correspondence table's).
REGION_METRIC = {"median_mm": "correspondence_median_mm", "mean_mm": "correspondence_mean_mm"}
#: What the correspondence tables' floor rows are (gpja.report.runs.with_floors).
FLOOR_NOTE = ("A method's floor: the least its scored vertices can score (gpja/metrics/correspondence.py), each at "
              "the rest-space distance from its material to the nearest material the expression shows: 0 where the "
              "material is visible, more where it is hidden (an eyeball under a closed lid, the inner lips of a "
              "closed mouth). No vertex scores below its floor; a method that leaves hidden material off the scan "
              "is not scored on it and has a lower floor.")


def floor_note(run: Run) -> list[str]:
    """The floor rows' note when ``run`` has them (:func:`gpja.report.runs.with_floors`)."""
    return [FLOOR_NOTE] if any(m.endswith(FLOOR_SUFFIX) for m in run.methods) else []


def row_label(name: str) -> str:
    """A table row's method label: the method's, or ``GPJA floor`` for its floor row."""
    return floor_label(name) or method_label(name)


def correspondence_regions_table(run: Run) -> Table:
    """Median and mean correspondence error (mm) per facial region, per subject and method (means over expressions)."""
    names = list(REGION_NAMES)
    if not any(n in v for v in run.values.values() for n in names):
        first = next(iter(run.paths.values()))
        raise InputError(first, "no per-region correspondence scores in any metrics JSON (they need the synthetic "
                                "ground truth's landmarks_rest)")
    run = with_floors(run)
    columns = [(region_name(r, k), REGION_METRIC[k]) for r in REGIONS for k in REGION_KEYS]
    stats, lines, block = score_block(run, columns, [(REGION_LABELS[r], len(REGION_KEYS)) for r in REGIONS])
    csv_header = ["subject", "method", "region", "expressions", *REGION_KEYS]
    csv_rows = [[s, m, r, count_values(run, run.subjects if s == AVERAGE else [s], m, names_of(r)[0]),
                 *[stats[(s, m)][n] for n in names_of(r)]] for s in lines for m in run.methods for r in REGIONS]
    radii = ", ".join(f"{REGION_LABELS[g]} {RADII_MM[g]:g} mm" for g in RADII_MM)
    notes = [("Correspondence error (mm) of the template vertices by the facial region of their rest-space point, "
              "means over the expressions of the per-expression median and mean. Regions from the 68 ground-truth "
              f"rest landmarks (gpja/metrics/regions.py): the nearest feature group within its radius ({radii}; "
              "mouth, eyes and nose also inside their frontal contours, the mouth also its cavity), else the rest of "
              f"the face inside the jaw line and the raised brows, else ears/scalp/neck. {DASH}: no scored vertex in "
              "the region."), *floor_note(run)]
    caption = "Correspondence error by facial region against the synthetic ground truth (mm): median and mean."
    return Table("correspondence_regions", caption, [block], csv_header, csv_rows, notes)


def position_regions_table(run: Run) -> Table:
    """The position error (mm): overall median, mean and 95th percentile, then median and mean per facial region,
    per subject and method (means over expressions)."""
    names = list(POSITION_NAMES) + list(POSITION_REGION_NAMES)
    if not any(n in v for v in run.values.values() for n in names):
        first = next(iter(run.paths.values()))
        raise InputError(first, "no position error in any metrics JSON (metrics written before it: run `gpja "
                                "metrics` again)")
    columns = [(n, f"correspondence_{k}") for n, k in zip(POSITION_NAMES, CORRESPONDENCE_KEYS)]
    columns += [(region_name(r, k, "position"), REGION_METRIC[k]) for r in REGIONS for k in REGION_KEYS]
    groups = [("all", len(POSITION_NAMES))] + [(REGION_LABELS[r], len(REGION_KEYS)) for r in REGIONS]
    stats, lines, block = score_block(run, columns, groups)
    csv_header = ["subject", "method", "expressions", *names]
    csv_rows = [[s, m, count_values(run, run.subjects if s == AVERAGE else [s], m, POSITION_NAMES[0]),
                 *[stats[(s, m)][n] for n in names]] for s in lines for m in run.methods]
    notes = [("Position error (mm): the distance from each registered template vertex to the point where the "
              "expression's scan carries the vertex's material (gpja/metrics/correspondence.py), means over the "
              "expressions. Unlike the correspondence error it keeps vertices that left the scan (a lip tucked "
              "inside the mouth); material hidden in the expression (inside a closed mouth, under a closed lid) "
              f"is not scored. Regions as in the correspondence table. {DASH}: no scored vertex.")]
    caption = "Position error against the synthetic ground truth, overall and by facial region (mm)."
    return Table("position_regions", caption, [block], csv_header, csv_rows, notes)


def score_block(run: Run, columns: list[tuple[str, str]], groups: list[tuple[str, int]]) -> tuple[dict, list, Block]:
    """Per-subject (and ``Average``) x method means of the flat scores ``columns`` ((name, kind): ``kind`` the
    metric whose digits, header and better end the cell takes) as one block with column ``groups``.

    Returns the statistics (:func:`gpja.report.runs.subject_stats`), the row subjects and the block."""
    stats = subject_stats(run, run.methods, [n for n, _ in columns])
    lines = run.subjects + [AVERAGE]
    rows = [[subject_label(s), row_label(m)] + [metric_cell(stats[(s, m)][n], kind) for n, kind in columns]
            for s in lines for m in run.methods]
    block = Block(headers=["Subject", "Method"] + [header(kind) for _, kind in columns], rows=rows, label_columns=2,
                  groups=groups, rules={i * len(run.methods) for i in range(1, len(lines))})
    return stats, lines, block


def names_of(region: str) -> list[str]:
    """The flat names of one region's scores, in :data:`gpja.report.runs.REGION_KEYS` order."""
    return [region_name(region, k) for k in REGION_KEYS]


# ---------------------------------------------------------------------------------------------------------------
# Texture quality


TEXTURE_PARTS = ("observed", "unobserved")
TEXTURE_SCORES = ("psnr", "ssim")


def read_texture_quality(results: str | Path, subject: str) -> dict:
    """The ``texture_quality.json`` of a subject's template (``gpja texture-quality``)."""
    path = Layout(results).template_file(subject, QUALITY_FILE)
    record = read_required_json(path, f"texture quality of subject {subject} (`gpja texture-quality`)")
    for part in TEXTURE_PARTS:
        if not isinstance(record.get(part), dict):
            raise InputError(path, f"no {part!r} section (not a `gpja texture-quality` JSON?)")
    return record


def texture_table(results: str | Path, subjects) -> Table:
    """Per subject: PSNR and SSIM of the texture against the ground-truth albedo (observed / unobserved texels),
    the fitted gain, the texel counts; and the mean over the subjects."""
    records = {s: read_texture_quality(results, s) for s in subjects}
    values = {s: {f"{n}_{p}": r[p].get(n) for p in TEXTURE_PARTS for n in TEXTURE_SCORES} for s, r in records.items()}
    keys = [f"{n}_{p}" for p in TEXTURE_PARTS for n in TEXTURE_SCORES]
    values[AVERAGE] = {k: mean_or_none([values[s][k] for s in subjects if values[s][k] is not None]) for k in keys}

    def score_cells(line):
        return [metric_cell(values[line][f"{n}_{p}"], n) for p in TEXTURE_PARTS for n in TEXTURE_SCORES]

    rows = [[subject_label(s)] + score_cells(s) + [Cell(g, 3) for g in records[s]["gain"]]
            + [Cell(records[s][p]["texels"], 0) for p in TEXTURE_PARTS] for s in subjects]
    rows.append([subject_label(AVERAGE)] + score_cells(AVERAGE) + [Cell(None, 3)] * 3 + [Cell(None, 0)] * 2)
    block = Block(headers=["Subject"] + [header(n) for _ in TEXTURE_PARTS for n in TEXTURE_SCORES]
                  + ["R", "G", "B", "observed", "unobserved"], rows=rows,
                  groups=[("observed texels", 2), ("unobserved texels", 2), ("gain", 3), ("texels", 2)],
                  rules={len(subjects)})
    csv_header = ["subject", *keys, "gain_r", "gain_g", "gain_b", "texels_observed", "texels_unobserved",
                  "observed_source"]
    csv_rows = [[s, *[values[s][k] for k in keys], *records[s]["gain"],
                 *[records[s][p]["texels"] for p in TEXTURE_PARTS], records[s].get("observed_source")]
                for s in subjects]
    csv_rows.append([AVERAGE, *[values[AVERAGE][k] for k in keys], None, None, None, None, None, None])
    notes = [("Each texel mapped through the template surface to the closest point of the template expression's "
              "scan (within 2 mm, off its rim), to its rest-space point and the generator's albedo there "
              "(gpja/metrics/texture_quality.py). Texture and albedo share one scale per channel: the texture is "
              "compared with gain x albedo, the gain fitted by least squares over the observed texels. Observed: "
              "texels some view sees (template/texture_observed.png); unobserved: those filled. "
              f"{AVERAGE}: the mean over the subjects.")]
    caption = "Texture quality against the synthetic ground-truth albedo: PSNR (dB) and SSIM per subject."
    return Table("texture", caption, [block], csv_header, csv_rows, notes)
