"""Textured template creation (paper, "Textured Template Mesh Creation").

1. A genus-0 bust with a designed UV atlas and mouth pocket (``bust.py``) is
   placed over the subject's mouth-open scan (``bust_placement.py``: position
   and scale from the scan).
2. It is fitted with depth-only GPJA (multiscale LargeSteps), ending densely
   tessellated.
3. With the geometry fixed, the texture is reconstructed by gradient descent of
   the colour constraint on the texture image.
4. The dense mesh is decimated with pymeshlab's texture-preserving quadric edge
   collapse to the coarse template, which keeps the same texture map.
The mouth mask B is the bust's mouth-pocket chart in UV space.
"""
from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import torch.nn.functional as nnf

from gpja.errors import InputError
from gpja.lighting import irradiance_over_pi
from gpja.mesh import TexturedMesh, read_obj, write_obj
from gpja.register.bust import Bust, make_bust
from gpja.register.bust_placement import place_bust
from gpja.register.hra import ExpressionTargets, Switches
from gpja.register.multiscale import Schedule, optimise
from gpja.render import Topology, render_views, sample_texture
from gpja.settings import CONFIG_KEY, HIDDEN, from_section


@dataclass(frozen=True)
class TemplateSettings:
    """Template creation settings.

    Attributes:
        bust_edge_mm: edge length of the initial bust (coarse; refined by the schedule).
        schedule: the depth-only multiscale fit; read from the section's own ``lambdas``,
            ``iterations``, ``refine_factor``, ``lr_fraction`` and ``lr_decay`` keys (the colour
            constraint's ``color_pool`` and warm-up do not apply to a depth-only fit).
        texture_size: side of the square texture image, texels.
        texture_iterations, texture_lr: gradient descent of the colour constraint on the texture.
        template_faces: face count of the decimated template (paper: ~16K vertices, ~32K faces);
            config key ``faces``.
    """

    bust_edge_mm: float = 6.0
    schedule: Schedule = field(default_factory=lambda: Schedule(lambdas=(200.0, 120.0, 80.0), iterations=(150, 150, 150)),
                               metadata={HIDDEN: ("color_pool", "warmup_iterations")})
    texture_size: int = 1024
    texture_iterations: int = 200
    texture_lr: float = 0.05
    template_faces: int = field(default=32000, metadata={CONFIG_KEY: "faces"})

    #: ``TemplateSettings.from_config(section, source)``: from ``registration.template``, see gpja.settings.
    from_config = classmethod(from_section)

    def __post_init__(self) -> None:
        if not float(self.bust_edge_mm) > 0:
            raise ValueError(f"bust_edge_mm must be > 0, got {self.bust_edge_mm}")
        for name, key in (("texture_size", "texture_size"), ("texture_iterations", "texture_iterations"),
                          ("template_faces", "faces")):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{key} must be >= 1, got {getattr(self, name)}")
        if not float(self.texture_lr) > 0:
            raise ValueError(f"texture_lr must be > 0, got {self.texture_lr}")


def reconstruct_texture(mesh: TexturedMesh, targets: ExpressionTargets, size: int, iterations: int, lr: float,
                        progress: Callable[[str], None] = print, render: Callable | None = None) -> np.ndarray:
    """Texture image that best explains the reference images on a fixed mesh.

    Gradient descent of the colour constraint (L1, Lambertian SH shading) on
    the texture. The texture is parametrised as a sum of a 1/4-, a 1/2- and a
    full-resolution image, so texels between the pixels' sample points get
    gradients through the coarser levels (a plain texel grid leaves holes where
    the texture is finer than the images).

    Args:
        mesh: (fixed) geometry with UVs, mm.
        targets: cameras, reference images and lighting.
        size: texture side, texels. iterations, lr: Adam settings.
        render: a backend's ``render_views`` (``gpja.render.renderer``) for the one render of the
            mesh's normals and texture coordinates; None = the CPU renderer.
    Returns:
        (size, size, 3) float32 albedo in [0, 1], row 0 at the top (v = 1).
    """
    V = torch.tensor(mesh.V, dtype=torch.float32)
    topo = Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv))
    render = render or render_views
    with torch.no_grad():
        out = render(V, topo, targets.cameras, ("normal", "uv"), uv=torch.tensor(mesh.UV, dtype=torch.float32),
                     antialias_edges=False, cull_backfaces=True)
        hit = out.values["coverage"][:, 0] > 0  # the CPU renderer lists covered pixels only; nvdiffrast all
        uv = out.values["uv"][hit]
        normals = out.values["normal"][hit]
        shading = irradiance_over_pi(normals, targets.sh.float())
        observed = targets.images.reshape(-1, 3)[out.pixels[hit]]
    if len(uv) == 0:
        raise InputError("template", "the fitted mesh covers no pixel of any view: cannot reconstruct a texture")
    init = (observed / shading.clamp_min(1e-3)).clamp(0, 1).mean(0)
    levels = [size // 4, size // 2, size]
    params = [torch.zeros(s, s, 3, requires_grad=True) for s in levels]
    with torch.no_grad():
        params[0] += init
    opt = torch.optim.Adam(params, lr=lr)

    def compose() -> torch.Tensor:
        total = 0
        for p in params:
            up = p if p.shape[0] == size else nnf.interpolate(p.permute(2, 0, 1)[None], size=(size, size),
                                                               mode="bilinear", align_corners=False)[0].permute(1, 2, 0)
            total = total + up
        return total

    for it in range(iterations):
        texture = compose()
        pred = sample_texture(texture, uv) * shading
        loss = (pred - observed).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        if (it + 1) % max(1, iterations // 4) == 0:
            progress(f"texture iter {it + 1}/{iterations}: colour L1 {loss.item():.4f}")
    with torch.no_grad():
        return compose().clamp(0, 1).numpy().astype(np.float32)


def decimate_with_texture(mesh: TexturedMesh, faces: int) -> TexturedMesh:
    """Texture-preserving quadric edge collapse (pymeshlab) to about ``faces`` triangles.

    pymeshlab refuses meshes built from arrays with wedge UVs, so the mesh goes
    through an OBJ we write; UV seams and the atlas survive the collapse.
    """
    import pymeshlab

    if faces >= len(mesh.F):
        return mesh
    with tempfile.TemporaryDirectory(prefix="gpja_decimate_") as tmp:
        dense, coarse = Path(tmp) / "dense.obj", Path(tmp) / "coarse.obj"
        write_obj(dense, TexturedMesh(mesh.V, mesh.F, mesh.UV, mesh.F_uv), texture_name=None)
        ms = pymeshlab.MeshSet()
        ms.load_new_mesh(str(dense))
        ms.meshing_decimation_quadric_edge_collapse_with_texture(targetfacenum=int(faces), preserveboundary=True,
                                                                 planarquadric=True)
        ms.save_current_mesh(str(coarse), save_wedge_texcoord=True, save_vertex_color=False,
                             save_vertex_normal=False, save_textures=False)
        out = read_obj(coarse, load_texture=False)
    return TexturedMesh(out.V, out.F, out.UV, out.F_uv, mesh.texture)


@dataclass
class Template:
    """A subject's textured template and the stages that produced it."""

    mesh: TexturedMesh          # coarse template with texture
    mouth_mask: np.ndarray      # (T, T) float32, 0 = mouth interior
    stages: dict[str, TexturedMesh]
    log: dict


def create_template(scan_V: np.ndarray, targets: ExpressionTargets, settings: TemplateSettings,
                    progress: Callable[[str], None] = print, render: Callable | None = None) -> Template:
    """Build a subject's template from its mouth-open expression.

    Args:
        scan_V: (n, 3) the mouth-open scan's vertices, mm (placement).
        targets: that expression's views, reference images, scan targets and lighting.
        render: a backend's ``render_views`` (``gpja.render.renderer``) for every render of the fit and
            the texture reconstruction; None = the CPU renderer.
    """
    t0 = time.perf_counter()
    bust: Bust = place_bust(make_bust(target_edge_mm=settings.bust_edge_mm), scan_V)
    progress(f"template: bust placed ({len(bust.mesh.V)} vertices)")
    dummy_tex, dummy_mask = torch.ones(4, 4, 3), torch.ones(4, 4, 1)
    fitted, fit_log = optimise(bust.mesh, targets, Switches(color=False, normal=False), settings.schedule,
                               texture=dummy_tex, mask_texture=dummy_mask, render=render, progress=progress)
    t_fit = time.perf_counter()
    progress(f"template: depth-only fit done ({len(fitted.V)} vertices, {t_fit - t0:.1f} s)")
    texture = reconstruct_texture(fitted, targets, settings.texture_size, settings.texture_iterations,
                                  settings.texture_lr, progress, render=render)
    t_tex = time.perf_counter()
    dense = TexturedMesh(fitted.V, fitted.F, fitted.UV, fitted.F_uv, texture)
    coarse = decimate_with_texture(dense, settings.template_faces)
    progress(f"template: decimated to {len(coarse.V)} vertices / {len(coarse.F)} faces")
    stages = {"bust": bust.mesh, "fitted": dense, "template": coarse}
    log = {"fit": fit_log.to_json(), "seconds": {"fit": t_fit - t0, "texture": t_tex - t_fit,
                                                  "decimate": time.perf_counter() - t_tex},
           "vertices": {k: int(len(m.V)) for k, m in stages.items()}}
    return Template(coarse, bust.mouth_mask(settings.texture_size), stages, log)
