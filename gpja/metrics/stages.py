"""Scores after every stage of one registration (synthetic data): where the alignment is won or lost.

``gpja register --stages-dir`` saves the mesh it starts from, the mesh after the warm-up and after each
level (:func:`gpja.results.stage_writer`). This module scores each of them as the final mesh
is scored: the dense correspondence error against the ground truth (:mod:`gpja.metrics.correspondence`,
with its regions, its floor and the position error, which tells a lid that moved from an eyeball laid over
it) and, in the most frontal view, the render with the shared texture against the
reference (PSNR over the scan's pixels, and the colour-mapped L1 image of the photometric figures).
The figure ``registration_stages`` draws them.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from gpja.camera import most_frontal_view
from gpja.data.source import DataSource
from gpja.io import read_image, read_npz, write_json, write_npz
from gpja.mesh import read_obj
from gpja.metrics.correspondence import (DEFAULT_MAX_DISTANCE_MM, TEMPLATE_EXPRESSION, correspondence_reference,
                                         read_landmarks_rest, read_rest_coords, score_correspondence)
from gpja.metrics.photometric import head_mask, l1_error_image, masked_psnr, render_with_texture
from gpja.metrics.regions import REGIONS
from gpja.results import read_stages, read_template_lighting


def score_stages(stages_dir: str | Path, template_dir: str | Path, source: DataSource, ground_truth_root: str | Path,
                 subject: str, expression: str, targets_path: str | Path, out_path: str | Path, *,
                 template_expression: str = TEMPLATE_EXPRESSION, max_distance_mm: float = DEFAULT_MAX_DISTANCE_MM,
                 render: Callable | None = None) -> dict:
    """Score every saved stage of one registration; write ``out_path`` (.json) and its arrays (.npz beside it).

    Args:
        stages_dir: the registration's ``--stages-dir``.
        template_dir: the subject's template folder (template.obj, texture.png, lighting.json).
        source: the dataset (images, scans in mm).
        ground_truth_root: the synthetic ground truth (rest coordinates, landmarks).
        targets_path: the expression's scan targets (their coverage is the scored head region).
        render: a backend's ``render_views``; None = the CPU renderer.
    Returns:
        ``{"subject", "expression", "view", "stages": [{"stage", "median_mm", "mean_mm", "p95_mm",
        "regions": {region: median_mm}, "floor_regions": {region: median_mm}, "position": {"median_mm", "mean_mm",
        "regions": {region: median_mm}}, "psnr"}]}`` (also written to ``out_path``): the correspondence error, its
        floor and the position error (:mod:`gpja.metrics.correspondence`). The ``.npz`` holds
        ``stage_names`` (S,), ``vertex_error_mm`` (S, n_template) float32 (NaN where unscored) and ``l1``
        (S, H, W, 3) uint8 colour-mapped L1 images of the view.
    """
    template = read_obj(Path(template_dir) / "template.obj", load_texture=False)
    texture = read_image(Path(template_dir) / "texture.png")
    sh = read_template_lighting(template_dir)
    data = source.load(subject, expression)
    scan_t = data.scan if expression == template_expression else source.scan(subject, template_expression)
    rest_e = read_rest_coords(ground_truth_root, subject, expression, len(data.scan.V))
    rest_t = read_rest_coords(ground_truth_root, subject, template_expression, len(scan_t.V))
    landmarks = read_landmarks_rest(ground_truth_root, subject, template_expression)
    view = most_frontal_view(data.cameras)
    reference = np.asarray(data.images[view], np.float32)
    reference = reference / 255.0 if reference.max() > 1.0 else reference
    mask = head_mask(read_npz(targets_path)["coverage"][view:view + 1])[0]
    names, errors, l1_images, rows = [], [], [], []
    truth = correspondence_reference(template.V, (data.scan.V, data.scan.F), rest_e, (scan_t.V, scan_t.F), rest_t,
                                         max_distance_mm=max_distance_mm, landmarks_rest=landmarks)
    for name, mesh in read_stages(stages_dir):
        c = score_correspondence(mesh.V, truth, mesh_source=f"{stages_dir} stage {name}")
        image = render_with_texture(mesh, texture, [data.cameras[view]], sh, render=render)[0]
        names.append(name)
        errors.append(c["vertex_error_mm"].astype(np.float32))
        l1_images.append(np.round(l1_error_image(image, reference, mask) * 255).astype(np.uint8))
        position, floor = c["position"], c["floor"]
        rows.append({"stage": name, "median_mm": c["median_mm"], "mean_mm": c["mean_mm"], "p95_mm": c["p95_mm"],
                     "regions": {r: s["median_mm"] for r, s in (c.get("regions") or {}).items()},
                     "floor_regions": {r: s["median_mm"] for r, s in (floor.get("regions") or {}).items()},
                     "position": {"median_mm": position["median_mm"], "mean_mm": position["mean_mm"],
                                  "regions": {r: s["median_mm"] for r, s in (position.get("regions") or {}).items()}},
                     "psnr": masked_psnr(image, reference, mask)})
    out = {"subject": subject, "expression": expression, "view": data.views[view].name, "stages": rows,
           "region_names": list(REGIONS)}
    out_path = Path(out_path)
    write_npz(out_path.with_suffix(".npz"), stage_names=np.array(names), vertex_error_mm=np.stack(errors),
              l1=np.stack(l1_images))
    write_json(out_path, out)
    return out
