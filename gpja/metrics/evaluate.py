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

from gpja.data.facescape import scan_path
from gpja.mesh import read_obj, referenced_texture
from gpja.metrics import geometry as geo
from gpja.metrics.correspondence import DEFAULT_MAX_DISTANCE_MM as CORRESPONDENCE_MAX_DISTANCE_MM
from gpja.metrics.correspondence import TEMPLATE_EXPRESSION, correspondence_error_files
from gpja.metrics.photometric import evaluate_photometric_files


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

    @classmethod
    def from_config(cls, cfg: dict) -> "MetricSettings":
        known = dict(cfg)  # unknown keys raise TypeError in the constructor
        if "thresholds_mm" in known:
            known["thresholds_mm"] = tuple(float(t) for t in known["thresholds_mm"])
        return cls(**known)


def evaluate_expression(*, mesh_path: str | Path, subject: str, expression: str, method: str,
                        template_dir: str | Path, images_root: str | Path, scans_root: str | Path,
                        targets_path: str | Path | None, out_dir: str | Path,
                        ground_truth_root: str | Path | None = None, rt_scale: str | Path | None = None,
                        views=None, cache_dir: str | Path | None = None, max_image_size: int | None = None,
                        template_expression: str = TEMPLATE_EXPRESSION,
                        settings: MetricSettings = MetricSettings()) -> dict:
    """Score ``mesh_path`` (``method``'s result for ``subject``/``expression``).

    Writes into ``out_dir``: ``geometry_errors.npz`` (per-vertex distances for
    heatmaps), ``render/`` and ``l1/`` (photometric renders and error images),
    ``correspondence_errors.npz`` (synthetic data). Returns the JSON-able scores.
    """
    out_dir = Path(out_dir)
    result: dict = {"subject": subject, "expression": expression, "method": method, "mesh": str(mesh_path)}
    start = time.perf_counter()
    result["geometry"] = geo.evaluate_geometry_files(
        mesh_path, scan_path(scans_root, subject, expression), rt_scale=rt_scale, subject=subject,
        expression=expression, errors_path=out_dir / "geometry_errors.npz", samples=settings.samples,
        seed=settings.seed, thresholds=settings.thresholds_mm, coverage=settings.coverage,
        max_distance_mm=settings.max_distance_mm)
    timings = {"geometry": time.perf_counter() - start}

    mesh = read_obj(mesh_path, load_texture=False)
    if settings.photometric and mesh.has_uv:
        start = time.perf_counter()
        # GPJA, its ablations and NICP reference the template's texture; an imported mesh may bring its own
        texture = referenced_texture(mesh_path) or Path(template_dir) / "texture.png"
        result["texture"] = str(texture)
        result["photometric"] = evaluate_photometric_files(
            mesh_path, template_dir, images_root, scans_root, subject, expression, targets_path,
            ground_truth_root=ground_truth_root, views=views, rt_scale=rt_scale, cache_dir=cache_dir,
            max_image_size=max_image_size, out_dir=out_dir, texture_path=texture)
        timings["photometric"] = time.perf_counter() - start
    else:
        if settings.photometric:
            logging.warning("%s: no texture coordinates; photometric metrics are skipped for %s", mesh_path, method)
        result["photometric"] = None

    if ground_truth_root is not None and rt_scale is None:
        start = time.perf_counter()
        result["correspondence"] = correspondence_error_files(
            mesh_path, Path(template_dir) / "template.obj", scans_root, ground_truth_root, subject, expression,
            template_expression=template_expression, errors_path=out_dir / "correspondence_errors.npz",
            max_distance_mm=settings.correspondence_max_distance_mm)
        timings["correspondence"] = time.perf_counter() - start
    else:
        result["correspondence"] = None
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
    return ", ".join(parts)
