"""Photometric alignment of a registered mesh: PSNR, SSIM and LPIPS against the captured views.

Every method's output mesh keeps the subject's template UVs, so rendering it
with the template's shared texture at the reference cameras and comparing with
the captured (undistorted) images measures how well texture and geometry are
aligned (paper, "Metrics" and Table 2).

Definitions (the same for every method, so the scores are comparable):
    Render: ``gpja.render.render_views`` "color" pass (template texture x
        Lambertian SH shading under the template's lighting, ``lighting.json``
        of its folder: the texture's albedo is relative to that estimate, or
        uniform white light; never the synthetic ground truth), antialiased,
        black background, clipped to [0, 1]. No back-face culling: z-buffer
        visibility is exact for open meshes too.
    Head mask: pixels the expression's *scan* covers, coverage >= 0.5 in the
        scan targets of ``render_scan_targets``; derived from the data, never
        from the method's render, so a method is charged for head pixels it
        leaves empty. Optionally intersected with a user mask (B, H, W).
    Composite: outside the head mask the render is replaced by the reference
        image, so SSIM windows and LPIPS receptive fields that reach past the
        mask see identical content there, and nothing outside the head region
        (background, shoulders, the method's overhang) changes any score.
    PSNR: 10 log10(1 / MSE), data range 1, MSE over the mask's pixels and the
        3 channels; +inf when render and reference agree exactly.
    SSIM: scikit-image ``structural_similarity(gaussian_weights=True,
        sigma=1.5, win_size=11, use_sample_covariance=False, data_range=1,
        channel_axis=-1, full=True)`` of the composite and the reference; the
        mean of the full SSIM map over the mask's pixels and the 3 channels.
        Computed on the crop below: the Gaussian window reaches 5 px, less than
        the crop margin, so the values are those of the whole image.
    LPIPS: AlexNet v0.1 (``gpja.metrics.lpips``) spatial map of the composite
        and the reference, averaged over the mask's pixels; evaluated on the
        mask's bounding box grown by ``CROP_MARGIN_PX`` (clipped to the image,
        at least 31 px a side), the same crop for every method, so the score
        does not depend on how much background a camera sees (and 8 views at
        512 px stay fast on a CPU).
    Views: each metric per view; the reported value is the unweighted mean over
        the views whose mask is non-empty (views with an empty mask get None).
    Error images: per-pixel L1 |render - reference| averaged over channels, on
        the mask, coloured with ``ERROR_COLORMAP`` over [0, ``ERROR_SCALE``]
        (brighter = larger; values above the scale saturate); black outside
        the mask.

Entry points: :func:`evaluate_photometric` (arrays in memory) and
:func:`evaluate_photometric_files` (files, as the CLI and workflow use it).
"""
from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np
import torch

from gpja.camera import Camera
from gpja.errors import InputError
from gpja.mesh import TexturedMesh

if TYPE_CHECKING:
    from gpja.data.source import DataSource

log = logging.getLogger(__name__)

#: A pixel belongs to the head region when the scan covers at least this fraction of it.
COVERAGE_THRESHOLD = 0.5
#: Pixels added around the head mask's bounding box for SSIM and LPIPS (must exceed SSIM's 5 px window radius).
CROP_MARGIN_PX = 16
#: AlexNet needs this many pixels on each side (``gpja.metrics.lpips.MIN_IMAGE_SIDE``).
MIN_CROP_SIDE = 31
#: scikit-image SSIM settings (Wang et al. 2004's Gaussian-window SSIM).
SSIM_SETTINGS = {"gaussian_weights": True, "sigma": 1.5, "win_size": 11, "use_sample_covariance": False,
                 "data_range": 1.0}
#: L1 error mapped to the full colour map range, [0, 1] image units (64/255 grey levels).
ERROR_SCALE = 0.25
ERROR_COLORMAP = "viridis"

MASK_DEFINITION = (f"scan coverage >= {COVERAGE_THRESHOLD} (render_scan_targets of the expression's scan), "
                   "intersected with the user mask when given; identical for every method")


# --- metrics on arrays --------------------------------------------------------------------

def _as_float32(array: np.ndarray | torch.Tensor) -> np.ndarray:
    """A numpy float32 copy-free view where possible (torch tensors are detached and moved to the CPU)."""
    if isinstance(array, torch.Tensor):
        array = array.detach().cpu().numpy()
    return np.asarray(array, dtype=np.float32)


def head_mask(coverage: np.ndarray | torch.Tensor, user_mask: np.ndarray | None = None) -> np.ndarray:
    """The head region of each view.

    Args:
        coverage: (B, H, W, 1) or (B, H, W) scan coverage in [0, 1].
        user_mask: optional (B, H, W) or (H, W) bool, intersected with the coverage mask.
    Returns:
        (B, H, W) bool.
    """
    cov = _as_float32(coverage)
    if cov.ndim == 4:
        cov = cov[..., 0]
    mask = cov >= COVERAGE_THRESHOLD
    if user_mask is not None:
        user = np.asarray(user_mask, dtype=bool)
        if user.shape not in (mask.shape, mask.shape[1:]):
            raise ValueError(f"user mask has shape {user.shape}, expected {mask.shape} or {mask.shape[1:]}")
        mask = mask & user
    return mask


def masked_psnr(render: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """PSNR in dB (data range 1) over the mask's pixels and all channels.

    Args:
        render, reference: (H, W, 3) float in [0, 1]. mask: (H, W) bool, non-empty.
    Returns:
        10 log10(1 / MSE); +inf for identical pixels.
    """
    diff = (np.asarray(render, dtype=np.float64) - np.asarray(reference, dtype=np.float64))[mask]
    if diff.size == 0:
        raise ValueError("PSNR of an empty mask")
    mse = float(np.mean(diff * diff))
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)


def ssim_map(render: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Full SSIM map with ``SSIM_SETTINGS``.

    Args:
        render, reference: (H, W, 3) float in [0, 1], H, W >= 11.
    Returns:
        (H, W, 3) float map (1 where the images agree locally).
    """
    from skimage.metrics import structural_similarity

    _, full = structural_similarity(np.asarray(render), np.asarray(reference), channel_axis=-1, full=True,
                                    **SSIM_SETTINGS)
    return full


def masked_ssim(render: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """Mean of the full SSIM map (:func:`ssim_map`) over the mask's pixels and channels.

    Args:
        render, reference: (H, W, 3) float in [0, 1]. mask: (H, W) bool, non-empty.
    """
    if not mask.any():
        raise ValueError("SSIM of an empty mask")
    return float(np.mean(ssim_map(render, reference)[mask], dtype=np.float64))


def composite(render: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The render inside the mask, the reference outside: (H, W, 3), render's dtype."""
    return np.where(mask[..., None], render, reference).astype(render.dtype, copy=False)


def mask_crop(mask: np.ndarray, margin: int = CROP_MARGIN_PX, min_side: int = MIN_CROP_SIDE) -> tuple[slice, slice]:
    """Row and column slices of the mask's bounding box grown by ``margin``, clipped to the image.

    A side shorter than ``min_side`` is grown symmetrically (within the image) to reach it.

    Args:
        mask: (H, W) bool, non-empty.
    """
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))

    def grown(lo: int, hi: int, size: int) -> slice:
        lo, hi = max(lo - margin, 0), min(hi + 1 + margin, size)
        missing = max(min_side - (hi - lo), 0)
        lo = max(lo - (missing + 1) // 2, 0)
        hi = min(max(hi, lo + min_side), size)
        lo = max(min(lo, hi - min_side), 0)
        return slice(lo, hi)

    return grown(rows[0], rows[-1], mask.shape[0]), grown(cols[0], cols[-1], mask.shape[1])


def l1_error_image(render: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Colour-mapped per-pixel L1 error for figures.

    Args:
        render, reference: (H, W, 3) float in [0, 1]. mask: (H, W) bool.
    Returns:
        (H, W, 3) float32 in [0, 1]: ``ERROR_COLORMAP`` of mean_c |render - reference| / ``ERROR_SCALE``
        (clipped) inside the mask, black outside.
    """
    import matplotlib

    err = np.abs(np.asarray(render, np.float32) - np.asarray(reference, np.float32)).mean(axis=-1)
    colours = matplotlib.colormaps[ERROR_COLORMAP](np.clip(err / ERROR_SCALE, 0.0, 1.0))[..., :3]
    return np.where(mask[..., None], colours, 0.0).astype(np.float32)


# --- rendering ----------------------------------------------------------------------------

def check_photometric_mesh(mesh: TexturedMesh, source: str | Path) -> None:
    """Raise :class:`InputError` naming ``source`` if the mesh cannot be rendered with the template texture."""
    mesh.validate(source)  # empty, NaN / infinite vertices, indices out of range
    if not mesh.has_uv:
        raise InputError(source, "the mesh has no texture coordinates ('vt' / UV faces): photometric metrics render "
                                 "it with the template's texture, so it must keep the template's UVs")


def render_with_texture(mesh: TexturedMesh, texture: np.ndarray, cameras: Sequence[Camera],
                        sh: np.ndarray | torch.Tensor, render=None, topology=None) -> np.ndarray:
    """Render a textured mesh into every view ("color" pass, black background).

    Args:
        mesh: V (n, 3) mm, F (m, 3), UV (k, 2), F_uv (m, 3).
        texture: (T, T, 3) float albedo in [0, 1].
        cameras: B undistorted cameras of one image size (H, W).
        sh: (9, 3) SH lighting.
        render: a backend's ``render_views`` (``gpja.render.renderer``); None = the CPU renderer.
        topology: ``gpja.render.Topology(mesh.F, mesh.F_uv)`` when the caller renders one triangulation
            many times (its face adjacency takes longer to build than a frame to render); None = built here.
    Returns:
        (B, H, W, 3) float32 in [0, 1] (shading above 1 is clipped).
    """
    from gpja.render import Topology, render_views

    render = render or render_views
    topology = Topology(mesh.F, mesh.F_uv) if topology is None else topology
    with torch.no_grad():
        out = render(torch.as_tensor(mesh.V, dtype=torch.float32), topology, cameras, passes=("color",),
                     uv=torch.as_tensor(mesh.UV, dtype=torch.float32),
                     texture=torch.from_numpy(_as_float32(texture)), sh=torch.from_numpy(_as_float32(sh)),
                     background=0.0)
        return out.dense("color").clamp(0.0, 1.0).numpy()


# --- evaluation ---------------------------------------------------------------------------

def _check_view_arrays(images: np.ndarray, coverage: np.ndarray, cameras: Sequence[Camera]) -> None:
    if len(cameras) == 0:
        raise ValueError("no camera given")
    sizes = {(c.height, c.width) for c in cameras}
    if len(sizes) != 1:
        raise ValueError(f"cameras differ in image size {sorted(sizes)}; resample the views to one size")
    expected = (len(cameras), *sizes.pop())
    if images.shape != (*expected, 3):
        raise ValueError(f"images have shape {images.shape}, expected {(*expected, 3)}")
    if coverage.shape[:3] != expected:
        raise ValueError(f"coverage has shape {coverage.shape}, expected {expected} (+ a channel)")


def comparison_crop(render: np.ndarray, reference: np.ndarray,
                    mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What SSIM and LPIPS compare: the composite, the reference and the mask, cut to :func:`mask_crop`.

    Args:
        render, reference: (H, W, 3) float32 in [0, 1]. mask: (H, W) bool, non-empty.
    Returns:
        (h, w, 3) composite, (h, w, 3) reference, (h, w) mask, with h, w >= ``MIN_CROP_SIDE``
        where the image allows.
    """
    rows, cols = mask_crop(mask)
    crop_mask = mask[rows, cols]
    crop_reference = reference[rows, cols]
    return composite(render[rows, cols], crop_reference, crop_mask), crop_reference, crop_mask


def view_metrics(render: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> dict:
    """PSNR, SSIM and LPIPS of one view (definitions in the module docstring).

    Args:
        render, reference: (H, W, 3) float32 in [0, 1]. mask: (H, W) bool, non-empty.
    Returns:
        {"psnr" (dB), "ssim", "lpips", "mask_pixels"}.
    """
    from gpja.metrics.lpips import lpips_distance

    crop = comparison_crop(render, reference, mask)
    return {"psnr": masked_psnr(render, reference, mask), "ssim": masked_ssim(*crop), "lpips": lpips_distance(*crop),
            "mask_pixels": int(mask.sum())}


def _mean(values: list[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.mean(kept)) if kept else None


def evaluate_photometric(mesh: TexturedMesh, texture: np.ndarray, cameras: Sequence[Camera],
                         images: np.ndarray | torch.Tensor, coverage: np.ndarray | torch.Tensor,
                         sh: np.ndarray | torch.Tensor, out_dir: str | Path | None = None, *,
                         mask: np.ndarray | None = None, view_names: Sequence[str] | None = None,
                         source: str | Path = "mesh", render=None) -> dict:
    """PSNR, SSIM and LPIPS of a mesh rendered with the template texture (module docstring).

    Args:
        mesh: the registered mesh: V (n, 3) mm, F, UV, F_uv (the template's UVs).
        texture: (T, T, 3) float32 shared template texture in [0, 1].
        cameras: B undistorted cameras of one image size (H, W).
        images: (B, H, W, 3) float32 undistorted reference images in [0, 1].
        coverage: (B, H, W, 1) or (B, H, W) scan coverage in [0, 1] (``render_scan_targets``).
        sh: (9, 3) SH lighting the texture was made under (``gpja.results.read_template_lighting``).
        out_dir: if given, writes ``render/{view}.png`` (the raw render) and ``l1/{view}.png``
            (the error image) there.
        mask: optional (B, H, W) or (H, W) bool user mask, intersected with the coverage mask.
        view_names: B names for the per-view entries and files (default "0", "1", ...).
        source: the mesh's file, named in errors.
        render: a backend's ``render_views`` (``gpja.render.renderer``); None = the CPU renderer.
    Returns:
        JSON-able dict: ``psnr`` (dB), ``ssim``, ``lpips`` (means over views with a non-empty mask),
        ``per_view`` (list of {view, psnr, ssim, lpips, mask_pixels[, render, error_image]}),
        ``views``, ``image_size`` [H, W], ``mask_definition`` and the settings used.
    Raises:
        InputError: the mesh has no UVs, is empty, or has NaN vertices (naming ``source``);
            the head mask is empty in every view.
    """
    check_photometric_mesh(mesh, source)
    images, coverage = _as_float32(images), _as_float32(coverage)
    _check_view_arrays(images, coverage, cameras)
    names = [str(n) for n in view_names] if view_names is not None else [str(i) for i in range(len(cameras))]
    masks = head_mask(coverage, mask)
    if not masks.any():
        raise InputError("coverage", f"the head mask ({MASK_DEFINITION}) is empty in every view: "
                                     "the scan is not seen by these cameras")
    renders = render_with_texture(mesh, texture, cameras, sh, render)
    return score_renders(renders, images, masks, names, out_dir, source)


def write_view_images(out_dir: Path, names: Sequence[str], renders: np.ndarray, images: np.ndarray,
                      masks: np.ndarray, per_view: list[dict]) -> None:
    """Write each view's render and L1 error image (PNG, atomically); record their paths in ``per_view``."""
    from gpja.io import write_image

    for name, render, reference, view_mask, entry in zip(names, renders, images, masks, per_view):
        write_image(out_dir / "render" / f"{name}.png", render)
        write_image(out_dir / "l1" / f"{name}.png", l1_error_image(render, reference, view_mask))
        entry.update(render=f"render/{name}.png", error_image=f"l1/{name}.png")


def score_renders(renders: np.ndarray, images: np.ndarray, masks: np.ndarray, names: Sequence[str],
                  out_dir: str | Path | None = None, source: str | Path = "") -> dict:
    """The photometric protocol on ready-made renders: per-view PSNR, SSIM and LPIPS over the head mask,
    reduced to unweighted means over the views whose mask is not empty. Every method, and the oracle, is
    scored by this one function.

    Args:
        renders, images: (B, H, W, 3) float32 in [0, 1]. masks: (B, H, W) bool head masks (:func:`head_mask`).
        names: B view names. out_dir: where ``render/{view}.png`` and ``l1/{view}.png`` go (None: not written).
        source: what was rendered, named in warnings.
    Returns:
        JSON-able dict: ``psnr`` (dB), ``ssim``, ``lpips``, ``per_view`` (list of {view, psnr, ssim, lpips,
        mask_pixels[, render, error_image]}), ``views``, ``image_size`` [H, W], ``mask_definition`` and the
        settings used.
    """
    per_view = []
    for name, view_render, reference, view_mask in zip(names, renders, images, masks):
        entry = {"view": str(name), "psnr": None, "ssim": None, "lpips": None, "mask_pixels": 0}
        if view_mask.any():
            entry.update(view_metrics(view_render, reference, view_mask))
        else:
            log.warning("%s view %s: the head mask is empty; the view is left out of the means", source, name)
        per_view.append(entry)

    if out_dir is not None:
        write_view_images(Path(out_dir), [str(n) for n in names], renders, images, masks, per_view)
    return {
        "psnr": _mean([v["psnr"] for v in per_view]),
        "ssim": _mean([v["ssim"] for v in per_view]),
        "lpips": _mean([v["lpips"] for v in per_view]),
        "views": len(per_view),
        "image_size": list(images.shape[1:3]),
        "per_view": per_view,
        "mask_definition": MASK_DEFINITION,
        "composite": "render inside the head mask, reference image outside",
        "ssim_settings": {**SSIM_SETTINGS, "channel_axis": -1, "full": True, "reduction": "mean over mask"},
        "lpips_net": "alex, v0.1 lin layers; spatial map averaged over the mask",
        "crop_margin_px": CROP_MARGIN_PX,
        "error_image": {"value": "mean over RGB of |render - reference|", "colormap": ERROR_COLORMAP,
                        "range": [0.0, ERROR_SCALE], "outside_mask": "black"},
    }


def evaluate_photometric_files(mesh_path: str | Path, template_dir: str | Path, source: "DataSource",
                               subject: str, expression: str, targets_path: str | Path | None,
                               out_dir: str | Path | None = None, texture_path: str | Path | None = None,
                               render=None, sh: np.ndarray | None = None) -> dict:
    """:func:`evaluate_photometric` of a registered mesh file against one expression's data.

    Args:
        mesh_path: the method's output OBJ (template UVs).
        template_dir: the subject's template folder (its ``texture.png`` is the shared texture).
        source: the dataset (images, scans, ``Rt_scale_dict.json``, views, image cache and size).
        targets_path: the expression's scan-targets ``.npz`` (reused, or rendered and written);
            None renders the coverage without caching.
        out_dir: where the per-view renders and error images go (None: not written).
        texture_path: the texture to render with; None = the template's shared ``texture.png``
            (an imported mesh with its own UV layout brings its own texture).
        render: a backend's ``render_views`` (``gpja.render.renderer``) for the mesh's renders and,
            without a valid cache, the scan targets; None = the CPU renderer.
        sh: (9, 3) SH lighting of the renders; None = the template's (``lighting.json`` of ``template_dir``,
            the lighting its texture was fused under), the same for every method.
    Returns:
        the dict of :func:`evaluate_photometric` plus ``mesh``, ``subject``, ``expression`` and ``lighting``
        (where the renders' SH came from).
    Raises:
        InputError: missing/corrupt files, a mesh without UVs, NaN vertices, an empty mesh or
            scan, a mesh and scan in different units, views of different sizes.
    """
    from gpja.data.facescape import expression_dir
    from gpja.data.units import check_units
    from gpja.io import read_image
    from gpja.mesh import read_obj
    from gpja.render import render_scan_targets
    from gpja.results import LIGHTING_FILE, read_template_lighting

    mesh = read_obj(mesh_path, load_texture=False)
    check_photometric_mesh(mesh, mesh_path)
    texture = read_image(Path(texture_path) if texture_path is not None else Path(template_dir) / "texture.png")
    data = source.load(subject, expression)
    check_units(mesh, data.scan.V, mesh_path)
    sizes = {(v.camera.width, v.camera.height) for v in data.views}
    if len(sizes) != 1:
        raise InputError(expression_dir(source.images_root, subject, expression),
                         f"views differ in size {sorted(sizes)}; set max_image_size so they share one")
    targets = render_scan_targets(data.scan.V, data.scan.F, data.cameras, cache_path=targets_path, render=render)
    if float(targets["coverage"].max()) < COVERAGE_THRESHOLD:
        raise InputError(data.scan.path, "the scan covers no pixel of any selected view")
    lighting = "given" if sh is not None else str(Path(template_dir) / LIGHTING_FILE)
    sh = read_template_lighting(template_dir) if sh is None else np.asarray(sh, dtype=np.float64)
    result = evaluate_photometric(mesh, texture, data.cameras, np.stack(data.images), targets["coverage"], sh,
                                  out_dir, view_names=[v.name for v in data.views], source=mesh_path, render=render)
    return {"mesh": str(mesh_path), "subject": str(subject), "expression": expression, "lighting": lighting, **result}
