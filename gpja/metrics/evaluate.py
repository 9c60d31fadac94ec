"""All scores of one method's mesh for one expression, in one JSON: what ``gpja metrics`` writes.

Geometry always; photometry when the mesh has texture coordinates (the
template's UVs); correspondence when synthetic ground truth is given. Every
method is scored by this one function with the same settings, so the tables
compare like with like.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from gpja.data.source import DataSource
from gpja.mesh import read_obj, reading_once, referenced_texture
from gpja.metrics import geometry as geo
from gpja.metrics.correspondence import DEFAULT_MAX_DISTANCE_MM as CORRESPONDENCE_MAX_DISTANCE_MM
from gpja.metrics.correspondence import TEMPLATE_EXPRESSION, correspondence_error_files
from gpja.metrics.lighting import score_lighting
from gpja.metrics.photometric import evaluate_photometric_files
from gpja.settings import from_section


@dataclass(frozen=True)
class MetricSettings:
    """The scoring protocol (config section ``metrics``); see each metric module for definitions."""

    samples: int = geo.DEFAULT_SAMPLES
    seed: int = geo.DEFAULT_SEED
    thresholds_mm: tuple[float, ...] = geo.DEFAULT_THRESHOLDS_MM
    coverage: str = "boundary"
    max_distance_mm: float = geo.DEFAULT_MAX_DISTANCE_MM
    correspondence_max_distance_mm: float = CORRESPONDENCE_MAX_DISTANCE_MM
    photometric: bool = True

    #: ``MetricSettings.from_config(section, source)``: from the ``metrics`` section, see gpja.settings.
    from_config = classmethod(from_section)


@dataclass(frozen=True)
class MetricRequest:
    """What every metric family is computed from: one method's mesh of one expression and the run's data.

    Attributes:
        mesh_path: the method's mesh (.obj; template UVs for the photometric scores).
        subject, expression, method: names.
        template_dir: the subject's template folder (shared texture, template mesh).
        source: the dataset (:class:`~gpja.data.source.DataSource`).
        targets_path: the expression's scan-target cache (.npz), or None.
        out_dir: the folder for per-vertex errors, renders and error images.
        ground_truth_root: synthetic ground truth, or None (real data).
        template_expression: the expression the template was built from.
        settings: the scoring protocol.
        render: the backend's ``render_views`` (``gpja.render.renderer``); None = the CPU renderer.
    """

    mesh_path: Path
    subject: str
    expression: str
    method: str
    template_dir: Path
    source: DataSource
    targets_path: Path | None
    out_dir: Path
    ground_truth_root: Path | None
    template_expression: str
    settings: MetricSettings
    render: Callable | None = None


def score_geometry(request: MetricRequest, result: dict) -> dict:
    """L1-Chamfer, normal consistency, F-scores against the scan (:mod:`gpja.metrics.geometry`)."""
    r, s = request, request.settings
    return geo.evaluate_geometry_files(
        r.mesh_path, r.source.scan_file(r.subject, r.expression), rt_scale=r.source.rt_scale, subject=r.subject,
        expression=r.expression, errors_path=r.out_dir / "geometry_errors.npz", samples=s.samples, seed=s.seed,
        thresholds=s.thresholds_mm, coverage=s.coverage, max_distance_mm=s.max_distance_mm)


def score_photometry(request: MetricRequest, result: dict) -> dict | None:
    """PSNR, SSIM, LPIPS of the mesh rendered with the shared texture (:mod:`gpja.metrics.photometric`);
    None without texture coordinates or with ``metrics.photometric: false``."""
    r = request
    if not r.settings.photometric:
        return None
    if not read_obj(r.mesh_path, load_texture=False).has_uv:
        logging.warning("%s: no texture coordinates; photometric metrics are skipped for %s", r.mesh_path, r.method)
        return None
    # GPJA, its ablations and NICP reference the template's texture; an imported mesh may bring its own
    texture = referenced_texture(r.mesh_path) or r.template_dir / "texture.png"
    result["texture"] = str(texture)
    return evaluate_photometric_files(r.mesh_path, r.template_dir, r.source, r.subject, r.expression,
                                      r.targets_path, out_dir=r.out_dir,
                                      texture_path=texture, render=r.render)


def score_correspondence(request: MetricRequest, result: dict) -> dict | None:
    """Dense correspondence error against the synthetic ground truth (:mod:`gpja.metrics.correspondence`);
    None on real data."""
    r = request
    if r.ground_truth_root is None or r.source.rt_scale is not None:
        return None
    return correspondence_error_files(
        r.mesh_path, r.template_dir / "template.obj", r.source.scans_root, r.ground_truth_root, r.subject,
        r.expression, template_expression=r.template_expression, errors_path=r.out_dir / "correspondence_errors.npz",
        max_distance_mm=r.settings.correspondence_max_distance_mm)


#: The metric families of a metrics JSON, in order: key -> ``score(request, result) -> dict | None``. A family
#: returns its scores (None = not applicable to this mesh or data); it may add top-level keys to ``result``
#: (photometry records the texture it used). Its wall time goes to ``result["seconds"][key]``. Adding a metric
#: family is one function plus one entry here; the tables read the JSON by key (gpja/report/runs.py).
METRICS: dict[str, Callable[[MetricRequest, dict], dict | None]] = {
    "geometry": score_geometry,
    "photometric": score_photometry,
    "correspondence": score_correspondence,
    "lighting": score_lighting,
}


def evaluate_expression(*, mesh_path: str | Path, subject: str, expression: str, method: str,
                        template_dir: str | Path, source: DataSource, targets_path: str | Path | None,
                        out_dir: str | Path, ground_truth_root: str | Path | None = None,
                        template_expression: str = TEMPLATE_EXPRESSION,
                        settings: MetricSettings = MetricSettings(), render=None) -> dict:
    """Score ``mesh_path`` (``method``'s result for ``subject``/``expression``) with every family of
    :data:`METRICS`, against ``source``'s data.

    Writes into ``out_dir``: ``geometry_errors.npz`` (per-vertex distances for
    heatmaps), ``render/`` and ``l1/`` (photometric renders and error images),
    ``correspondence_errors.npz`` (synthetic data). Returns the JSON-able scores.
    ``render``: the backend's ``render_views`` (``gpja.render.renderer``) of the photometric
    renders; None = the CPU renderer.
    """
    request = MetricRequest(
        Path(mesh_path), subject, expression, method, Path(template_dir), source,
        None if targets_path is None else Path(targets_path), Path(out_dir),
        None if ground_truth_root is None else Path(ground_truth_root), template_expression, settings, render)
    result: dict = {"subject": subject, "expression": expression, "method": method, "mesh": str(mesh_path)}
    timings = {}
    with reading_once():  # the families read the same mesh and scans from their paths
        for key, score in METRICS.items():
            start = time.perf_counter()
            result[key] = score(request, result)
            if result[key] is not None:
                timings[key] = time.perf_counter() - start
    result["seconds"] = {k: round(v, 3) for k, v in timings.items()}
    return result


def summary_line(result: dict) -> str:
    """One human-readable line of the headline scores."""
    g = result["geometry"]
    parts = [f"C.D. {g['chamfer_l1_mm']:.4f} mm", f"N.C. {g['normal_consistency']:.4f}"]
    parts += [f"F@{k} {v:.4f}" for k, v in g["fscore"].items()]
    p = result.get("photometric")
    if p:
        parts += [f"PSNR {p['psnr']:.2f} dB", f"SSIM {p['ssim']:.4f}", f"LPIPS {p['lpips']:.4f}"]
    c = result.get("correspondence")
    if c:
        parts.append(f"corr. mean {c['mean_mm']:.3f} mm")
        mouth = ((c.get("regions") or {}).get("mouth") or {}).get("median_mm")
        if mouth is not None:
            parts.append(f"corr. mouth median {mouth:.3f} mm")
        position = c.get("position") or {}
        if position.get("mean_mm") is not None:
            parts.append(f"position mean {position['mean_mm']:.3f} mm")
        mouth = (((position.get("regions") or {}).get("mouth")) or {}).get("median_mm")
        if mouth is not None:
            parts.append(f"position mouth median {mouth:.3f} mm")
    return ", ".join(parts)
