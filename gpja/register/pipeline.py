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
from gpja.io import write_image, write_json
from gpja.mesh import TexturedMesh, write_obj
from gpja.register.hra import ExpressionTargets, Switches
from gpja.register.multiscale import Schedule, optimise
from gpja.register.template import Template
from gpja.render import render_scan_targets


def expression_targets(data: ExpressionData, targets_path: str | Path, sh: np.ndarray,
                       render: Callable | None = None) -> ExpressionTargets:
    """Targets of one expression from its loaded views and cached scan renders.

    ``render``: the backend's ``render_views`` (``gpja.render.renderer``) when the scan targets must be
    rendered (no valid cache); None = the CPU renderer.
    """
    cams = data.cameras
    t = render_scan_targets(data.scan.V, data.scan.F, cams, cache_path=targets_path, render=render)
    images = torch.tensor(np.stack(data.images), dtype=torch.float32)
    for view, cov in zip(data.views, t["coverage"]):
        if float(cov.sum()) == 0:
            logging.warning("%s/%s view %s: the scan covers no pixel of this view", data.subject, data.expression, view.name)
    return ExpressionTargets(cams, images, t["depth"], t["normal"], t["coverage"], torch.tensor(sh, dtype=torch.float32))


def warn_on_holes(data: ExpressionData) -> None:
    """A scan with open boundaries is normal (MVS); say so once, with its size, so a user can judge."""
    from gpja.render.silhouettes import face_adjacency

    open_edges = int((face_adjacency(data.scan.F) < 0).sum())
    if open_edges:
        logging.warning("%s: the scan has holes (%d boundary edges); depth and normals are fitted where it has data",
                        data.scan.path, open_edges)


def write_template(template: Template, out_dir: str | Path) -> None:
    """Write template.obj/.mtl, texture.png, mouth_mask.png, texture_observed.png (255 = a view saw
    the texel, 0 = filled), lighting.json, template.json and stages/*.obj."""
    from gpja.register.lighting_estimate import CONVENTION
    from gpja.results import LIGHTING_FILE, OBSERVED_TEXELS_FILE, lighting_record

    out = Path(out_dir)
    write_obj(out / "template.obj", template.mesh, texture_name="texture.png")
    write_image(out / "mouth_mask.png", template.mouth_mask)
    if template.observed is not None:
        write_image(out / OBSERVED_TEXELS_FILE, np.where(template.observed, 255, 0).astype(np.uint8))
    if template.lighting is not None:
        write_json(out / LIGHTING_FILE, lighting_record(template.lighting, template.lighting_source, CONVENTION))
    for name, mesh in template.stages.items():
        write_obj(out / "stages" / f"{name}.obj", mesh, texture_name=f"{name}.png" if mesh.texture is not None else None)
    write_json(out / "template.json", template.log)


def warn_on_uncovered_views(mesh: TexturedMesh, targets: ExpressionTargets, source: str = "",
                            render: Callable | None = None) -> list[int]:
    """Warn for each view in which the starting mesh covers no pixel; return their indices.

    Such a view contributes no gradient at all (a misplaced template or a wrong
    camera), which otherwise only shows as a poor fit. ``render``: the backend's
    ``render_views`` (``gpja.render.renderer``); None = the CPU renderer.
    """
    from gpja.render import render_views

    render = render or render_views
    with torch.no_grad():
        out = render(torch.tensor(mesh.V, dtype=torch.float32), torch.from_numpy(mesh.F), targets.cameras,
                     passes=(), antialias_edges=False)
    n_views, height, width = out.shape
    hit = out.values["coverage"][:, 0] > 0  # the CPU renderer lists covered pixels only; nvdiffrast all
    covered = np.bincount(out.pixels[hit].cpu().numpy() // (height * width), minlength=n_views)
    empty = [int(i) for i in np.flatnonzero(covered == 0)]
    for i in empty:
        camera = targets.cameras[i]
        logging.warning("%sview %s: the mesh covers no pixel of this view; it contributes nothing to the fit "
                        "(check the template placement and the camera)", f"{source}: " if source else "",
                        camera.name or i)
    return empty


def start_from(template: TexturedMesh, registered: TexturedMesh, source: str | Path) -> TexturedMesh:
    """The template's topology at another expression's registered positions (``registration.start: tree``).

    A registered mesh keeps the template's vertices first and in order (refinement appends the new
    ones, ``gpja.register.remesh``), so its first ``n_template`` positions are where that registration
    put the template's vertices. Starting from them on the template's own triangulation, texture and
    mouth mask, the next registration refines exactly as one from the template does.

    Raises:
        InputError: ``registered`` (read from ``source``) is no registration of this template (fewer
            vertices, other UVs) or has non-finite positions.
    """
    from gpja.errors import InputError
    from gpja.mesh import check_vertex_prefix

    n = len(template.V)
    check_vertex_prefix(len(registered.V), n, source)
    if registered.UV is None or len(registered.UV) < len(template.UV) or not np.allclose(
            registered.UV[: len(template.UV)], template.UV, atol=1e-5):
        raise InputError(source, "its texture coordinates do not start with the template's: "
                                 "not a registration of this template")
    V = registered.V[:n]
    if not np.isfinite(V).all():
        raise InputError(source, "has NaN or infinite vertex positions")
    return template.with_vertices(V.astype(np.float64))


def chain_start(template: TexturedMesh, registered: TexturedMesh) -> TexturedMesh:
    """What a registration hands its children in the registration tree: the template's triangulation at the
    registered positions of its vertices (the inverse of :func:`start_from`, which reads it back unchanged).

    ``registered`` is the registration *before* the snap (``Schedule.snap_mm``, :func:`before_snap`): the snap
    finishes an expression's own output, and its children start where the levels left the surface, so a tree run
    with the snap has the same correspondence as one without it.
    """
    n = len(template.V)
    if len(registered.V) < n:
        raise ValueError(f"the registration has {len(registered.V)} vertices, fewer than the template's {n}")
    return template.with_vertices(np.asarray(registered.V[:n], dtype=np.float64))


def before_snap(on_stage: Callable[[str, TexturedMesh], None] | None = None):
    """An ``on_stage`` callback for :func:`register` that also keeps the last stage's mesh before the snap.

    Returns ``(callback, kept)``: ``callback`` forwards every stage to ``on_stage`` (None = to nothing);
    ``kept()`` is that mesh after :func:`register` returns, or None when no stage ran (the caller then has the
    returned mesh, which no snap moved).
    """
    kept: dict[str, TexturedMesh] = {}

    def callback(name: str, mesh: TexturedMesh) -> None:
        if name != "snap":
            kept["mesh"] = mesh
        if on_stage is not None:
            on_stage(name, mesh)

    return callback, lambda: kept.get("mesh")


def register(template: TexturedMesh, mouth_mask: np.ndarray, targets: ExpressionTargets, schedule: Schedule,
             switches: Switches, progress: Callable[[str], None] = print, render: Callable | None = None,
             on_stage: Callable[[str, TexturedMesh], None] | None = None, orientation: np.ndarray | None = None,
             scan: tuple[np.ndarray, np.ndarray] | None = None):
    """Register the template to one expression (GPJA or an ablation variant).

    ``render``: the backend's ``render_views`` (``gpja.render.renderer``) for every render of the
    registration; None = the CPU renderer. ``orientation``: the template's positions (n, 3) when ``template`` is
    another start on its topology (``start_from``), for the untangling's turned faces (``Schedule.untangle_turned``).
    ``scan``: the expression's scan (V, F), mm, for the last step onto it (``Schedule.snap_mm``).
    """
    warn_on_uncovered_views(template, targets, render=render)
    texture = torch.tensor(template.texture, dtype=torch.float32)
    mask = torch.tensor(mouth_mask, dtype=torch.float32)[..., None]
    if on_stage is not None:
        on_stage("start", template)
    return optimise(template, targets, switches, schedule, texture=texture, mask_texture=mask, render=render,
                    progress=progress, on_stage=on_stage, orientation=orientation, scan=scan)
