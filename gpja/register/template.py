"""Textured template creation (paper, "Textured Template Mesh Creation").

1. A genus-0 bust with a designed UV atlas and mouth pocket (``bust.py``) is
   placed over the subject's mouth-open scan (``bust_placement.py``: position
   and scale from the scan).
2. It is fitted with depth-only GPJA (multiscale LargeSteps), ending densely
   tessellated.
3. With the geometry fixed, the SH lighting is estimated from the images and
   the fitted mesh's normals (``lighting_estimate.py``; or taken as given), and
   the texture is fused from the views in texture space (``texture_fusion.py``,
   beyond the paper) or, as in the paper, reconstructed by gradient descent of
   the colour constraint on the texture image (``texture_method: optimise``).
4. The dense mesh is decimated with pymeshlab's texture-preserving quadric edge
   collapse to the coarse template, which keeps the same texture map.
The mouth mask B marks the mouth interior in UV space. The paper draws it by hand on the
template's texture; here it is the bust's mouth-socket charts (``mouth_mask: socket``), or those
without the texels that look like lips (``interior``, :func:`mask_mouth_interior`, the default config's): the
depth fit lays part of the socket onto the lower lip's inner face, and a mask over lip material lets
the socket cover the target's lips at no colour cost (docs/experiments.md, "The mouth mask over the
lips": alone it helps where the target shows the inner lip, not where a closed mouth hides it).
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
from gpja.lighting import irradiance_over_pi, uniform_sh
from gpja.mesh import TexturedMesh, read_obj, write_obj
from gpja.register.bust import Bust, make_bust
from gpja.register.bust_placement import place_bust
from gpja.register.hra import ExpressionTargets, Switches
from gpja.register.lighting_estimate import blurred_normals, estimate_sh, scan_samples
from gpja.register.multiscale import Schedule, optimise
from gpja.register.texture_fusion import (FULL_WEIGHT, FusionSettings, TextureObservations, ViewBuffers,
                                          choose_texture_size, finish_texture, observe_texture, texel_albedo,
                                          view_buffers)
from gpja.render import Topology, render_views, sample_texture
from gpja.settings import CONFIG_KEY, HIDDEN, from_section


#: Texture methods: the fusion (beyond the paper; default) and the paper's gradient descent.
TEXTURE_METHODS = ("fusion", "optimise")
#: ``TemplateSettings.mouth_mask``: the whole socket charts (default) or their texels that do not look like lips.
MOUTH_MASKS = ("socket", "interior")
#: Rec. 709 luminance weights of linear RGB (the mouth mask's darkness test).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
#: Lighting the texture's albedo is relative to (config ``registration.lighting``).
LIGHTING_CHOICES = ("estimate", "uniform")
#: After the lighting estimate, albedo and light are rescaled (they share one global scale) so that
#: this quantile of the observed texels' brightest channel sits at :data:`ALBEDO_CEILING`.
ALBEDO_QUANTILE, ALBEDO_CEILING = 0.995, 0.95


@dataclass(frozen=True)
class TemplateSettings:
    """Template creation settings.

    Attributes:
        bust_edge_mm: edge length of the initial bust (coarse; refined by the schedule).
        schedule: the depth-only multiscale fit; read from the section's own ``lambdas``,
            ``iterations``, ``refine_factor``, ``lr_fraction`` and ``lr_decay`` keys (the colour
            constraint's ``color_pool`` and warm-up do not apply to a depth-only fit).
        texture_method: ``fusion`` (multi-view fusion in texture space, ``texture_fusion.py``) or
            ``optimise`` (the paper: gradient descent of the colour constraint on the texture).
        texture_size: side of the square texture image, texels; with ``texture_size_from_images``
            the largest size the fusion may pick.
        texture_size_from_images: pick the size the images support (``choose_texture_size``);
            false = always ``texture_size`` (the ``optimise`` method always uses ``texture_size``).
        fusion: how the fusion weights and combines the views (``fusion_*`` keys).
        texture_iterations, texture_lr: gradient descent of the colour constraint on the texture
            (``optimise``; ``texture_lr`` also steps the refinement).
        texture_refine_iterations: ``fusion`` only, beyond the paper: iterations of a refinement of
            the fused texture by the colour constraint (0 = none).
        texture_refine_smoothness: weight of the refinement's total-variation prior on its correction.
        template_faces: face count of the decimated template (paper: ~16K vertices, ~32K faces);
            config key ``faces``.
        mouth_mask: ``socket``: every texel of the bust's socket charts is masked;
            ``interior`` (beyond the paper, an automatic version of its hand-drawn mask): the socket charts'
            texels that look like lips (as light as ``mouth_mask_dark`` x the observed skin's median
            luminance, as red as the skin) are unmasked (:func:`mask_mouth_interior`; the default config's).
        mouth_mask_dark: that fraction (0, 1).
    """

    bust_edge_mm: float = 6.0
    schedule: Schedule = field(default_factory=lambda: Schedule(lambdas=(200.0, 120.0, 80.0), iterations=(150, 150, 150)),
                               metadata={HIDDEN: ("color_pool", "warmup_iterations", "warmup_geometry", "optimizer_state",
                                                   "hold_tangential", "hold_moved_mm", "hold_gap_mm", "hold_mouth_mm", "hold_mouth_at_flow_mm", "hold_moved_at_flow",
                                                   "mouth_stiffness", "jaw_search_deg", "jaw_lips_mm", "jaw_shift_mm", "jaw_window_mm", "jaw_reach_mm", "lid_search_deg", "lip_seal", "color_gain", "color_scan_px", "mask_where_open", "lip_spread",
                                                   "spring_rate",
                                                   "flow_rounds",
                                                   "flow_levels", "flow_final_rounds", "flow_smoothness", "flow_still_mm", "flow_socket_margin_px", "flow_chroma", "flow_finest_scale", "flow_scan_shading_px",
                                                   "flow_cholesky",
                                                   "color_gradient",
                                                   "average_iterations", "views_per_iteration", "image_factor",
                                                   "seed", "face_order", "untangle_iterations", "untangle_rings",
                                                   "untangle_turned", "snap_mm", "snap_smoothness")})
    texture_method: str = "fusion"
    texture_size: int = 1024
    texture_size_from_images: bool = True
    fusion: FusionSettings = field(default_factory=FusionSettings)
    texture_iterations: int = 200
    texture_lr: float = 0.05
    texture_refine_iterations: int = 0
    texture_refine_smoothness: float = 0.5
    template_faces: int = field(default=32000, metadata={CONFIG_KEY: "faces"})
    mouth_mask: str = "socket"
    mouth_mask_dark: float = 0.5

    #: ``TemplateSettings.from_config(section, source)``: from ``registration.template``, see gpja.settings.
    from_config = classmethod(from_section)

    def __post_init__(self) -> None:
        if not float(self.bust_edge_mm) > 0:
            raise ValueError(f"bust_edge_mm must be > 0, got {self.bust_edge_mm}")
        if self.texture_method not in TEXTURE_METHODS:
            raise ValueError(f"texture_method must be one of {', '.join(TEXTURE_METHODS)}, got {self.texture_method!r}")
        for name, key in (("texture_size", "texture_size"), ("texture_iterations", "texture_iterations"),
                          ("template_faces", "faces")):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{key} must be >= 1, got {getattr(self, name)}")
        if not float(self.texture_lr) > 0:
            raise ValueError(f"texture_lr must be > 0, got {self.texture_lr}")
        if self.mouth_mask not in MOUTH_MASKS:
            raise ValueError(f"mouth_mask must be one of {', '.join(MOUTH_MASKS)}, got {self.mouth_mask!r}")
        if not 0.0 < float(self.mouth_mask_dark) < 1.0:
            raise ValueError(f"mouth_mask_dark must be in (0, 1), got {self.mouth_mask_dark}")
        if int(self.texture_refine_iterations) < 0 or float(self.texture_refine_smoothness) < 0:
            raise ValueError("texture_refine_iterations and texture_refine_smoothness must be >= 0, got "
                             f"{self.texture_refine_iterations} and {self.texture_refine_smoothness}")


def reconstruct_texture(mesh: TexturedMesh, targets: ExpressionTargets, size: int, iterations: int, lr: float,
                        progress: Callable[[str], None] = print, render: Callable | None = None,
                        init: np.ndarray | None = None, smoothness: float = 0.0) -> np.ndarray:
    """Texture image that best explains the reference images on a fixed mesh.

    Gradient descent of the colour constraint (L1, Lambertian SH shading) on
    the texture. The texture is parametrised as a sum of a 1/4-, a 1/2- and a
    full-resolution image, so texels between the pixels' sample points get
    gradients through the coarser levels (a plain texel grid leaves holes where
    the texture is finer than the images).

    With ``init`` (the fused texture) it refines instead: the parameters are a
    correction added to ``init``, and ``smoothness`` times the correction's
    mean absolute difference between neighbouring texels (L1 total variation)
    is added to the loss, so the correction cannot bring back texel-scale noise.

    Args:
        mesh: (fixed) geometry with UVs, mm.
        targets: cameras, reference images and lighting.
        size: texture side, texels. iterations, lr: Adam settings.
        render: a backend's ``render_views`` (``gpja.render.renderer``) for the one render of the
            mesh's normals and texture coordinates; None = the CPU renderer.
        init: (size, size, 3) float32 texture to refine; None = the paper's fit from the mean colour.
        smoothness: weight of the correction's total variation (with ``init``).
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
    levels = [size // 4, size // 2, size]
    params = [torch.zeros(s, s, 3, requires_grad=True) for s in levels]
    base = torch.zeros(size, size, 3) if init is None else torch.tensor(init, dtype=torch.float32)
    if init is None:
        with torch.no_grad():
            params[0] += (observed / shading.clamp_min(1e-3)).clamp(0, 1).mean(0)
    opt = torch.optim.Adam(params, lr=lr)

    def correction() -> torch.Tensor:
        total = 0
        for p in params:
            up = p if p.shape[0] == size else nnf.interpolate(p.permute(2, 0, 1)[None], size=(size, size),
                                                               mode="bilinear", align_corners=False)[0].permute(1, 2, 0)
            total = total + up
        return total

    for it in range(iterations):
        delta = correction()
        pred = sample_texture(base + delta, uv) * shading
        loss = (pred - observed).abs().mean()
        if init is not None and smoothness > 0:
            loss = loss + smoothness * ((delta[1:] - delta[:-1]).abs().mean() + (delta[:, 1:] - delta[:, :-1]).abs().mean())
        opt.zero_grad()
        loss.backward()
        opt.step()
        if (it + 1) % max(1, iterations // 4) == 0:
            progress(f"texture iter {it + 1}/{iterations}: colour L1 {loss.item():.4f}")
    with torch.no_grad():
        return (base + correction()).clamp(0, 1).numpy().astype(np.float32)


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
    """A subject's textured template and the stages that produced it.

    Attributes:
        mesh: coarse template with its (T, T, 3) texture.
        mouth_mask: (T, T) float32, 0 = mouth interior.
        stages: name -> mesh of each stage (``bust``, ``fitted``, ``template``).
        log: JSON-able record (fit log, seconds per stage, texture size, lighting).
        observed: (T, T) bool, the views' colour makes the texel (the rest was filled from its chart).
        lighting: (9, 3) float64 SH radiance (``gpja.lighting``) the texture's albedo is relative to.
        lighting_source: ``"estimated"`` (from the images) or ``"uniform"`` (``gpja.results.LIGHTING_SOURCES``).
    """

    mesh: TexturedMesh
    mouth_mask: np.ndarray
    stages: dict[str, TexturedMesh]
    log: dict
    observed: np.ndarray | None = None
    lighting: np.ndarray | None = None
    lighting_source: str = "uniform"


def _view_buffers(mesh: TexturedMesh, targets: ExpressionTargets, fusion: FusionSettings,
                  render: Callable | None) -> ViewBuffers:
    """The fusion's occlusion and feathering buffers from one depth render of the fitted mesh."""
    render = render or render_views
    with torch.no_grad():
        out = render(torch.tensor(mesh.V, dtype=torch.float32), torch.from_numpy(mesh.F), targets.cameras, ("depth",),
                     antialias_edges=False)
    covered = out.dense("coverage")[..., 0].numpy() > 0.5
    if not covered.any():
        raise InputError("template", "the fitted mesh covers no pixel of any view: cannot reconstruct a texture")
    depth = np.where(covered, out.dense("depth")[..., 0].numpy(), np.inf)
    return view_buffers(depth, targets.cameras, fusion.fusion_feather_px, targets.coverage[..., 0].numpy(),
                        fusion.fusion_off_scan_weight)


#: The scan's normals take over from the fitted mesh's over this many pixels from the scan's edges (holes,
#: silhouettes). Wider ramps soften the albedo's edge where the shading normal changes source, but bring
#: the fitted mesh's shading errors back in: default data 37.86 / 37.85 / 37.64 / 37.20 dB for 1 / 4 / 8 / 16 px;
#: held-out 256 px subjects lose 0.3-0.7 dB at 4 px.
SCAN_NORMAL_RAMP_PX = 1.0


def _scan_normal_images(targets: ExpressionTargets, fusion: FusionSettings) -> tuple[np.ndarray, np.ndarray]:
    """(B, H, W, 3) the scan's normal images (blurred by ``fusion_normal_blur_px``) and (B, H, W) how much
    to trust them: 0 off the scan, ramping to 1 over :data:`SCAN_NORMAL_RAMP_PX` from its edges."""
    import cv2

    coverage = targets.coverage[..., 0].numpy()
    normal = targets.normal.numpy()
    if fusion.fusion_normal_blur_px > 0:
        normal = np.stack([blurred_normals(n, c, fusion.fusion_normal_blur_px) for n, c in zip(normal, coverage)])
    trust = np.empty_like(coverage)
    for b, c in enumerate(coverage):
        inside = (c >= 0.5).astype(np.uint8)
        trust[b] = np.clip(cv2.distanceTransform(inside, cv2.DIST_L2, 5) / SCAN_NORMAL_RAMP_PX, 0.0, 1.0)
    return normal, trust


def _estimate_lighting(targets: ExpressionTargets) -> np.ndarray:
    """(9, 3) float64 SH lighting from the template expression's images and its scan's normals.

    The constant-albedo robust fit of ``lighting_estimate`` on the pixels the scan covers
    (``scan_samples``). The scan's normals, not the fitted mesh's: on the CI data (128 px views,
    6K-vertex fit) 10-20% of the fitted mesh's pixel normals are more than 25 degrees off the
    scan's, and the fit from them is 300% off the truth, from the scan's 6%.

    No alternation with the fused albedo: the fused albedo is the fused colour divided by the
    current shading at the same normals, so a refit with it returns the current lighting (up to
    the fitted mesh's and the scan's normals differing, which made it worse on the CI data: 17%).
    Albedo and light are separated only by a prior on the albedo; the constant-albedo fit with
    robust rejection of what is not skin is that prior.
    """
    colors, normals, weights = scan_samples(targets)
    return np.asarray(estimate_sh(colors, normals, weights=weights), dtype=np.float64)


def _rescale(sh: np.ndarray, albedo: np.ndarray, obs: TextureObservations) -> tuple[np.ndarray, np.ndarray, float]:
    """Move the shared albedo/light scale into the light when the observed albedo would clip above 1.

    Only when the :data:`ALBEDO_QUANTILE` of the brightest channel exceeds :data:`ALBEDO_CEILING`:
    the albedo is divided and the SH multiplied by the same factor (renders are unchanged).
    Returns (sh, albedo, factor).
    """
    seen = obs.weight >= FULL_WEIGHT
    if not seen.any():
        return sh, albedo, 1.0
    k = float(np.quantile(albedo[seen].max(axis=1), ALBEDO_QUANTILE)) / ALBEDO_CEILING
    if not k > 1.0:  # fits already: keep the estimate's own scale convention (its DC term)
        return sh, albedo, 1.0
    return sh * k, (albedo / k).astype(np.float32), k


def build_texture(mesh: TexturedMesh, targets: ExpressionTargets, settings: TemplateSettings, lighting: str = "estimate",
                  progress: Callable[[str], None] = print, render: Callable | None = None,
                  scan_V: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The texture of the fitted mesh, which texels the views see, and the lighting it is relative to.

    Args:
        mesh: the fitted (dense) mesh with the bust's UVs, mm.
        targets: the template expression's views and images (its ``sh`` is not used).
        lighting: one of :data:`LIGHTING_CHOICES`: ``estimate`` = fitted to the images,
            ``uniform`` = white light of radiance 1 (the paper's FaceScape assumption).
        render: a backend's ``render_views``; None = the CPU renderer.
        scan_V: (n, 3) the template expression's scan vertices, mm: the fusion leaves texels off the
            scan unobserved (``fusion_scan_distance_mm``); None = no such test.
    Returns:
        texture (T, T, 3) float32 in [0, 1], observed (T, T) bool, sh (9, 3) float64, log dict.
    """
    t0 = time.perf_counter()
    fusion = settings.fusion
    buffers = _view_buffers(mesh, targets, fusion, render)
    t_render = time.perf_counter()
    size, footprint = settings.texture_size, None
    if settings.texture_method == "fusion" and settings.texture_size_from_images:
        size, footprint = choose_texture_size(mesh, targets.cameras, buffers, settings.texture_size,
                                              fusion.fusion_min_cos)
    t1 = time.perf_counter()
    scan = _scan_normal_images(targets, fusion) if fusion.fusion_scan_normals else (None, None)
    obs = observe_texture(mesh, targets.cameras, targets.images.numpy(), buffers, size, fusion, *scan, scan_V=scan_V)
    t2 = time.perf_counter()
    if lighting == "estimate":
        sh = _estimate_lighting(targets)
        sh, albedo, scale = _rescale(sh, texel_albedo(obs, sh), obs)
    else:
        sh, scale = uniform_sh(1.0), 1.0
        albedo = texel_albedo(obs, sh)
    t3 = time.perf_counter()
    lit = ExpressionTargets(targets.cameras, targets.images, targets.depth, targets.normal, targets.coverage,
                            torch.tensor(sh, dtype=torch.float32))
    if settings.texture_method == "fusion":
        texture, observed = finish_texture(obs, albedo)
        if settings.texture_refine_iterations > 0:
            texture = reconstruct_texture(mesh, lit, size, settings.texture_refine_iterations, settings.texture_lr,
                                          progress, render=render, init=texture,
                                          smoothness=settings.texture_refine_smoothness)
    else:
        texture = reconstruct_texture(mesh, lit, size, settings.texture_iterations, settings.texture_lr, progress,
                                      render=render)
        observed = obs.observed
    t4 = time.perf_counter()
    progress(f"template: {settings.texture_method} texture {size}x{size}, {observed.mean():.0%} of texels observed, "
             f"{t4 - t0:.1f} s")
    log = {"method": settings.texture_method, "size": int(size), "median_footprint_px": footprint,
           "observed_fraction": float(observed.mean()), "albedo_scale": scale,
           "seconds": {"render": t_render - t0, "size": t1 - t_render, "fusion": t2 - t1, "lighting": t3 - t2,
                       "texture": t4 - t3}}
    return texture, observed, sh, log


def mask_mouth_interior(socket: np.ndarray, texture: np.ndarray, observed: np.ndarray | None,
                        dark_fraction: float) -> np.ndarray:
    """The mouth mask of the socket's dark texels: the mouth interior as the texture shows it.

    The bust's socket charts (:meth:`gpja.register.bust.Bust.mouth_mask`) are where the mouth interior
    may be, not where it is: the depth-only fit pulls the socket's first rings onto whatever the scan
    has behind the lip loop, which on a mouth-open scan is the lower lip's inner face. Masking those
    texels takes lip material out of the colour constraint, so a registration can leave them over the
    target's lips at no cost. Lips are as light as skin and redder; the interior is dark (the socket
    receives little light, and the albedo division leaves that in), and teeth are light but grey. A
    socket texel is unmasked when a view saw it, its luminance is at least ``dark_fraction`` x the median
    luminance of the observed texels outside the socket (the skin), and its red chromaticity
    ``R / (R + G + B)`` is at least the skin's median.

    Args:
        socket: (T, T) float32 mask of the socket charts (0 = socket, 1 elsewhere).
        texture: (T, T, 3) float32 albedo in [0, 1] (linear).
        observed: (T, T) bool, a view's colour makes the texel; None = every texel.
        dark_fraction: in (0, 1).
    Returns:
        (T, T) float32 mask, 0 = mouth interior, 1 elsewhere (the socket's light texels included).
    """
    socket = np.asarray(socket) < 0.5
    seen = np.ones(socket.shape, dtype=bool) if observed is None else np.asarray(observed, dtype=bool)
    skin = seen & ~socket
    if not skin.any():  # nothing to compare with: keep the socket charts
        return np.where(socket, 0.0, 1.0).astype(np.float32)
    rgb = np.asarray(texture, dtype=np.float64)[..., :3]
    luminance = rgb @ LUMINANCE
    red = rgb[..., 0] / np.maximum(rgb.sum(axis=-1), 1e-12)
    lip = (seen & (luminance >= float(dark_fraction) * float(np.median(luminance[skin])))
           & (red >= float(np.median(red[skin]))))
    return np.where(socket & ~lip, 0.0, 1.0).astype(np.float32)


def create_template(scan_V: np.ndarray, targets: ExpressionTargets, settings: TemplateSettings,
                    progress: Callable[[str], None] = print, render: Callable | None = None,
                    lighting: str = "estimate") -> Template:
    """Build a subject's template from its mouth-open expression.

    Args:
        scan_V: (n, 3) the mouth-open scan's vertices, mm (placement).
        targets: that expression's views, reference images and scan targets (its ``sh`` is not used).
        render: a backend's ``render_views`` (``gpja.render.renderer``) for every render of the fit and
            the texture reconstruction; None = the CPU renderer.
        lighting: ``estimate`` (SH fitted to the images between the fit and the fusion) or
            ``uniform`` (config ``registration.lighting``).
    """
    if lighting not in LIGHTING_CHOICES:
        raise InputError("registration.lighting", f"must be one of {', '.join(LIGHTING_CHOICES)}, got {lighting!r}")
    t0 = time.perf_counter()
    bust: Bust = place_bust(make_bust(target_edge_mm=settings.bust_edge_mm), scan_V)
    progress(f"template: bust placed ({len(bust.mesh.V)} vertices)")
    dummy_tex, dummy_mask = torch.ones(4, 4, 3), torch.ones(4, 4, 1)
    fitted, fit_log = optimise(bust.mesh, targets, Switches(color=False, normal=False), settings.schedule,
                               texture=dummy_tex, mask_texture=dummy_mask, render=render, progress=progress)
    t_fit = time.perf_counter()
    progress(f"template: depth-only fit done ({len(fitted.V)} vertices, {t_fit - t0:.1f} s)")
    texture, observed, sh, tex_log = build_texture(fitted, targets, settings, lighting, progress, render, scan_V)
    t_tex = time.perf_counter()
    dense = TexturedMesh(fitted.V, fitted.F, fitted.UV, fitted.F_uv, texture)
    coarse = decimate_with_texture(dense, settings.template_faces)
    progress(f"template: decimated to {len(coarse.V)} vertices / {len(coarse.F)} faces")
    stages = {"bust": bust.mesh, "fitted": dense, "template": coarse}
    source = "estimated" if lighting == "estimate" else "uniform"
    log = {"fit": fit_log.to_json(), "seconds": {"fit": t_fit - t0, "texture": t_tex - t_fit,
                                                  "decimate": time.perf_counter() - t_tex},
           "vertices": {k: int(len(m.V)) for k, m in stages.items()}, "texture": tex_log,
           "lighting": np.asarray(sh).tolist(), "lighting_source": source}
    mask = bust.mouth_mask(texture.shape[0])
    if settings.mouth_mask == "interior":
        socket_texels = int((mask < 0.5).sum())
        mask = mask_mouth_interior(mask, texture, observed, settings.mouth_mask_dark)
        log["mouth_mask"] = {"kind": "interior", "socket_texels": socket_texels,
                             "masked_texels": int((mask < 0.5).sum())}
        progress(f"template: mouth mask: {log['mouth_mask']['masked_texels'] / max(socket_texels, 1):.0%} of the "
                 "socket's texels are dark (interior), the rest is unmasked")
    else:
        log["mouth_mask"] = {"kind": "socket", "socket_texels": int((mask < 0.5).sum())}
    return Template(coarse, mask, stages, log, observed, np.asarray(sh, np.float64), source)
