"""Reading a finished run: every metrics JSON of (subject, method, expression), checked and flattened,
and the means the tables are built from.

One metrics JSON per (subject, method, expression) at :meth:`gpja.results.Layout.metrics` (written by
``gpja metrics``). Its headline scores are flattened to ``{metric: value}`` (:func:`flat_metrics`): the
names the tables, the regression check and its reference file use.
"""
from __future__ import annotations

import statistics
from dataclasses import dataclass
from pathlib import Path

from gpja.errors import InputError
from gpja.io import read_json
from gpja.metrics.regions import REGIONS
from gpja.results import Layout

#: The key of the mean over the subjects (of the per-subject means) in :func:`subject_stats`.
AVERAGE = "Average"

GEOMETRY_REQUIRED = ("chamfer_l1_mm", "mesh_to_scan_mm", "scan_to_mesh_mm", "normal_consistency")
PHOTOMETRIC_KEYS = ("psnr", "ssim", "lpips")
CORRESPONDENCE_KEYS = ("mean_mm", "median_mm", "p95_mm")
CORRESPONDENCE_NAMES = tuple(f"correspondence_{k}" for k in CORRESPONDENCE_KEYS)
#: The position error's scores (``correspondence.position``, :mod:`gpja.metrics.correspondence`): the same keys.
POSITION_NAMES = tuple(f"position_{k}" for k in CORRESPONDENCE_KEYS)
#: The per-region correspondence scores the tables read (``correspondence.regions.{region}.{key}``).
REGION_KEYS = ("median_mm", "mean_mm")
#: The prefix of the correspondence score's floor (``correspondence.floor``, :mod:`gpja.metrics.correspondence`) in
#: the flat names: ``floor_median_mm``, ``floor_{region}_median_mm``, ...
FLOOR_SCORE = "floor"
FLOOR_PREFIX = f"{FLOOR_SCORE}_"
#: What a method's floor row is called after the method (``gpja:floor``; :func:`with_floors`).
FLOOR_SUFFIX = ":floor"


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


def is_reference_record(record: dict) -> bool:
    """Whether a metrics JSON is a reference's (``gpja.methods`` kind ``reference``, e.g. the oracle): scored
    photometrically only, without geometry."""
    from gpja.methods import method

    return isinstance(record.get("method"), str) and method(record["method"]).kind == "reference"


def check_metrics_record(path: str | Path, record: dict) -> None:
    """Raise :class:`InputError` naming ``path`` when a metrics JSON lacks a score the tables read.

    A reference's JSON (:func:`is_reference_record`) has no geometry but must have the photometric scores.
    """
    geometry = record.get("geometry")
    if is_reference_record(record) and geometry is None:
        part = record.get("photometric")
        if not (isinstance(part, dict) and all(is_number(part.get(k)) for k in PHOTOMETRIC_KEYS)):
            raise InputError(path, f"a reference's metrics need photometric numbers {', '.join(PHOTOMETRIC_KEYS)}")
        return
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


def flat_metrics(record: dict, regions: bool = False) -> dict[str, float]:
    """A metrics JSON's headline scores as ``{name: value}`` (the regression check's names), and with
    ``regions`` the per-region correspondence scores (the tables').

    Names: ``chamfer_l1_mm``, ``mesh_to_scan_mm``, ``scan_to_mesh_mm`` (mm), ``normal_consistency``,
    ``fscore@<t>`` (t in mm); with photometry ``psnr`` (dB), ``ssim``, ``lpips``; with synthetic ground
    truth ``correspondence_mean_mm``, ``correspondence_median_mm``, ``correspondence_p95_mm`` (mm) and per
    facial region ``correspondence_{region}_median_mm``, ``correspondence_{region}_mean_mm`` (mm; regions of
    :data:`gpja.metrics.regions.REGIONS` with a scored vertex); the position error (``correspondence.position``)
    likewise as ``position_*``; with ``regions`` also the score's floor (``correspondence.floor``, the least the
    scored vertices can score: the tables' floor rows, not the regression check) as ``floor_*``. A reference's
    record (the oracle) has no geometry names.
    """
    values = {}
    geometry = record.get("geometry")
    if geometry is not None:
        values.update({key: float(geometry[key]) for key in GEOMETRY_REQUIRED})
        values.update({fscore_name(t): float(v) for t, v in geometry["fscore"].items()})
    if record.get("photometric"):
        values.update({key: float(record["photometric"][key]) for key in PHOTOMETRIC_KEYS})
    correspondence = record.get("correspondence")
    if correspondence:
        values.update({f"correspondence_{k}": float(correspondence[k]) for k in CORRESPONDENCE_KEYS})
        position = correspondence.get("position") or {}  # metrics JSONs written before it have none
        values.update({f"position_{k}": float(position[k]) for k in CORRESPONDENCE_KEYS if is_number(position.get(k))})
        floor = (correspondence.get("floor") or {}) if regions else {}  # metrics JSONs written before it have none
        values.update({FLOOR_PREFIX + k: float(floor[k]) for k in CORRESPONDENCE_KEYS if is_number(floor.get(k))})
        scored = (("correspondence", correspondence), ("position", position), (FLOOR_SCORE, floor))
        for score, scores in scored if regions else ():
            for region, stats in (scores.get("regions") or {}).items():
                values.update({region_name(region, k, score): float(stats[k])
                               for k in REGION_KEYS if is_number(stats.get(k))})
    return values


def region_name(region: str, key: str, score: str = "correspondence") -> str:
    """Flat name of a per-region score: ``correspondence_mouth_median_mm``, ``position_mouth_median_mm``."""
    return f"{score}_{region}_{key}"


#: Every flat per-region name, region by region (:data:`gpja.metrics.regions.REGIONS` order).
REGION_NAMES = tuple(region_name(r, k) for r in REGIONS for k in REGION_KEYS)
#: The same for the position error.
POSITION_REGION_NAMES = tuple(region_name(r, k, "position") for r in REGIONS for k in REGION_KEYS)


def floor_of(method: str) -> str:
    """The name of ``method``'s floor row in the correspondence tables (:func:`with_floors`)."""
    return f"{method}{FLOOR_SUFFIX}"


def floor_label(name: str) -> str | None:
    """``GPJA floor`` for a floor row's name (:func:`floor_of`), None for any other name."""
    from gpja.methods import label

    return f"{label(name[: -len(FLOOR_SUFFIX)])} floor" if name.endswith(FLOOR_SUFFIX) else None


def with_floors(run: Run) -> Run:
    """``run`` with each method's floor (``floor_*`` of its records: the least its scored vertices can score) as a
    row of its own right after the method's, its values under the correspondence names
    (``correspondence_median_mm``, ``correspondence_{region}_median_mm``, ...) so a table reads both alike.
    Methods without a floor in any record (metrics written before it, no ground truth) get no row."""
    methods, values, paths = [], dict(run.values), dict(run.paths)
    for m in run.methods:
        methods.append(m)
        keys = [(s, m, e) for s in run.subjects for e in run.expressions]
        if not any(n.startswith(FLOOR_PREFIX) for k in keys for n in run.values[k]):
            continue
        methods.append(floor_of(m))
        for s, _, e in keys:
            values[(s, floor_of(m), e)] = {"correspondence_" + n[len(FLOOR_PREFIX):]: v
                                           for n, v in run.values[(s, m, e)].items() if n.startswith(FLOOR_PREFIX)}
            paths[(s, floor_of(m), e)] = run.paths[(s, m, e)]
    return Run(list(run.subjects), methods, list(run.expressions), values, paths)


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
    layout = Layout(results)
    values, paths = {}, {}
    for subject in subjects:
        for method in methods:
            for expression in expressions:
                path = layout.metrics(subject, method, expression)
                what = f"metrics of subject {subject}, method {method}, expression {expression} (`gpja metrics`)"
                record = read_required_json(path, what)
                check_metrics_record(path, record)
                values[(subject, method, expression)] = flat_metrics(record, regions=True)
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


def sd_or_none(values: list[float]) -> float | None:
    """Sample standard deviation (n - 1 denominator), None for fewer than 2 values."""
    return statistics.stdev(values) if len(values) >= 2 else None


def present(dicts: list[dict], name: str) -> list[float]:
    """The values of ``name`` in the dicts that have one (not None), in order."""
    return [d[name] for d in dicts if d.get(name) is not None]


def means(dicts: list[dict], names) -> dict[str, float | None]:
    """Per name, the mean over the dicts that have a value for it (None where none has)."""
    return {n: mean_or_none(present(dicts, n)) for n in names}


def sds(dicts: list[dict], names) -> dict[str, float | None]:
    """Per name, the sample standard deviation over the dicts that have a value for it (None for fewer than 2)."""
    return {n: sd_or_none(present(dicts, n)) for n in names}


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
