"""Glue between files and the registration: load an expression's targets, run, write results.

The workflow's ``gpja template`` and ``gpja register`` commands call these.
"""
from __future__ import annotations

import logging
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from gpja.data.facescape import ExpressionData
from gpja.errors import InputError
from gpja.io import read_image, read_npz, write_image, write_json
from gpja.lighting import uniform_sh
from gpja.mesh import TexturedMesh, read_obj, write_obj
from gpja.register.hra import ExpressionTargets, Switches
from gpja.register.multiscale import Schedule, optimise
from gpja.register.template import Template
from gpja.render import render_scan_targets

TEMPLATE_FILES = ("template.obj", "template.mtl", "texture.png", "mouth_mask.png", "template.json")
#: A template and a scan whose sizes differ by more than this factor are in different units.
MAX_SCALE_RATIO = 3.0


def lighting_for(subject: str, expression: str, ground_truth_root: str | Path | None) -> np.ndarray:
    """(9, 3) SH lighting: the synthetic ground truth when present, else uniform white light.

    FaceScape was captured under near-uniform light (paper: "a reasonable simplification").
    """
    if ground_truth_root:
        return read_npz(Path(ground_truth_root) / subject / f"{expression}.npz")["sh"]
    return uniform_sh(1.0)


def expression_targets(data: ExpressionData, targets_path: str | Path, sh: np.ndarray) -> ExpressionTargets:
    """Targets of one expression from its loaded views and cached scan renders."""
    cams = data.cameras
    t = render_scan_targets(data.scan.V, data.scan.F, cams, cache_path=targets_path)
    images = torch.tensor(np.stack(data.images), dtype=torch.float32)
    for view, cov in zip(data.views, t["coverage"]):
        if float(cov.sum()) == 0:
            logging.warning("%s/%s view %s: the scan covers no pixel of this view", data.subject, data.expression, view.name)
    return ExpressionTargets(cams, images, t["depth"], t["normal"], t["coverage"], torch.tensor(sh, dtype=torch.float32))


def check_units(template: TexturedMesh, scan_V: np.ndarray, source: str | Path) -> None:
    """Raise if template and scan sizes differ by more than ``MAX_SCALE_RATIO`` (different units)."""
    size_t = float(np.linalg.norm(np.ptp(template.V, axis=0)))
    size_s = float(np.linalg.norm(np.percentile(scan_V, 98, axis=0) - np.percentile(scan_V, 2, axis=0)))
    ratio = max(size_t, size_s) / max(min(size_t, size_s), 1e-9)
    if ratio > MAX_SCALE_RATIO:
        raise InputError(source, f"template ({size_t:.4g}) and scan ({size_s:.4g}) differ in size by {ratio:.1f}x: "
                                 "different units? (both must be millimetres)")


def warn_on_holes(data: ExpressionData) -> None:
    """A scan with open boundaries is normal (MVS); say so once, with its size, so a user can judge."""
    from gpja.render.silhouettes import face_adjacency

    open_edges = int((face_adjacency(data.scan.F) < 0).sum())
    if open_edges:
        logging.warning("%s: the scan has holes (%d boundary edges); depth and normals are fitted where it has data",
                        data.scan.path, open_edges)


def write_template(template: Template, out_dir: str | Path) -> None:
    """Write template.obj/.mtl, texture.png, mouth_mask.png, template.json and stages/*.obj."""
    out = Path(out_dir)
    write_obj(out / "template.obj", template.mesh, texture_name="texture.png")
    write_image(out / "mouth_mask.png", template.mouth_mask)
    for name, mesh in template.stages.items():
        write_obj(out / "stages" / f"{name}.obj", mesh, texture_name=f"{name}.png" if mesh.texture is not None else None)
    write_json(out / "template.json", template.log)


def read_template(template_dir: str | Path) -> tuple[TexturedMesh, np.ndarray]:
    """The template mesh (with texture) and its mouth mask (T, T) from a template folder."""
    d = Path(template_dir)
    mesh = read_obj(d / "template.obj")
    if mesh.texture is None or not mesh.has_uv:
        raise InputError(d / "template.obj", "a template needs texture coordinates and a texture image")
    mask = read_image(d / "mouth_mask.png", mode="L")
    return mesh, mask


def warn_on_uncovered_views(mesh: TexturedMesh, targets: ExpressionTargets, source: str = "") -> list[int]:
    """Warn for each view in which the starting mesh covers no pixel; return their indices.

    Such a view contributes no gradient at all (a misplaced template or a wrong
    camera), which otherwise only shows as a poor fit.
    """
    from gpja.render import render_views

    with torch.no_grad():
        out = render_views(torch.tensor(mesh.V, dtype=torch.float32), torch.from_numpy(mesh.F), targets.cameras,
                           passes=(), antialias_edges=False)
    n_views, height, width = out.shape
    covered = np.bincount(out.pixels.numpy() // (height * width), minlength=n_views)
    empty = [int(i) for i in np.flatnonzero(covered == 0)]
    for i in empty:
        camera = targets.cameras[i]
        logging.warning("%sview %s: the mesh covers no pixel of this view; it contributes nothing to the fit "
                        "(check the template placement and the camera)", f"{source}: " if source else "",
                        camera.name or i)
    return empty


def register(template: TexturedMesh, mouth_mask: np.ndarray, targets: ExpressionTargets, schedule: Schedule,
             switches: Switches, progress: Callable[[str], None] = print):
    """Register the template to one expression (GPJA or an ablation variant)."""
    warn_on_uncovered_views(template, targets)
    texture = torch.tensor(template.texture, dtype=torch.float32)
    mask = torch.tensor(mouth_mask, dtype=torch.float32)[..., None]
    return optimise(template, targets, switches, schedule, texture=texture, mask_texture=mask, progress=progress)


def write_registration(mesh: TexturedMesh, log: dict, obj_path: str | Path, texture_ref: str) -> None:
    """Write a registered mesh (OBJ referencing the shared template texture) and its JSON log."""
    write_obj(obj_path, TexturedMesh(mesh.V, mesh.F, mesh.UV, mesh.F_uv), texture_name=texture_ref)
    write_json(Path(obj_path).with_suffix(".json"), log)
