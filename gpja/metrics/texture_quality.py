"""How close the template's texture is to the generator's albedo (synthetic data only).

Every texel of ``template/texture.png`` is taken back to the material point it stands for:

1. texel -> surface: the template's UV faces are rasterised into the texture
   (:func:`gpja.render.uv_raster.rasterize_uv`, the texture fusion's own texel map): face +
   barycentrics -> a 3-D point on the template, which lies in the frame of the expression it was
   fitted to (``3_mouth_stretch``);
2. surface -> scan: the closest point on that expression's scan (:mod:`gpja.surface`), kept when it
   is within ``max_distance_mm`` (2 mm, the correspondence metric's cap) and not on the scan's rim
   (off the scan, the rim's material point has nothing to do with the texel);
3. scan -> rest space: ``scan_rest_coords`` interpolated with the closest point's barycentrics;
4. rest space -> albedo: the generator's ``evaluate_albedo`` with the subject's tables
   (:func:`gpja.metrics.oracle.subject_albedo`).

Albedo and light share one scale per channel (a texture fitted under estimated light is the albedo
times an unknown gain), so a per-channel gain ``g`` is fitted by least squares over the observed
texels, ``g_c = sum(t_c a_c) / sum(a_c^2)``, and reported; the texture is then compared with
``clip(g a, 0, 1)``.

Scores, over the texels that map to the scan ("valid"), separately for those some view observes
(``template/texture_observed.png`` > 0.5, written with the texture; without it every valid texel
counts as observed and ``observed_source`` says so) and those none observes (filled):
PSNR (dB, data range 1, :func:`gpja.metrics.photometric.masked_psnr`) and SSIM (the photometric
metric's Gaussian-window SSIM, :func:`gpja.metrics.photometric.masked_ssim`, averaged over the
texels; the reference image holds the texture itself at invalid texels, so windows that reach into
gutters and off-scan texels see identical content there).

Error image: per texel ``mean_c |t - g a|`` on the valid texels, coloured as the photometric error
images (:func:`gpja.metrics.photometric.l1_error_image`), black elsewhere.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from gpja.errors import InputError
from gpja.results import OBSERVED_TEXELS_FILE

#: Distance cap of a texel's surface point from the scan, mm (as the correspondence metric's).
DEFAULT_MAX_DISTANCE_MM = 2.0
#: The mask of observed texels beside the texture (255 = seen by a view, 0 = filled; written with the template).
OBSERVED_FILE = OBSERVED_TEXELS_FILE
#: A texel of the observed mask counts as observed above this value ([0, 1]).
OBSERVED_THRESHOLD = 0.5
#: Files the texture-quality step writes into the template folder.
QUALITY_FILE = "texture_quality.json"
ERROR_IMAGE_FILE = "texture_error.png"


def texel_albedo(V: np.ndarray, F: np.ndarray, UV: np.ndarray, F_uv: np.ndarray, size: int,
                 scan: tuple[np.ndarray, np.ndarray], rest: np.ndarray, albedo, *,
                 max_distance_mm: float = DEFAULT_MAX_DISTANCE_MM) -> tuple[np.ndarray, np.ndarray]:
    """The ground-truth albedo of every texel (steps 1-4 of the module docstring).

    Args:
        V: (n, 3) float64 template vertices, mm, in the scan's expression frame. F: (m, 3) int64 faces.
        UV: (k, 2) float64 UVs; F_uv: (m, 3) int64 UV faces.
        size: side T of the square texture, texels.
        scan: (V_s (p, 3) float64 mm, F_s (q, 3) int64) of the template expression's scan.
        rest: (p, 3) float64 rest-space coordinate of every scan vertex, mm.
        albedo: rest points (j, 3) float64 mm -> (j, 3) float64 linear RGB in [0, 1].
        max_distance_mm: cap of the texel point's distance to the scan.
    Returns:
        truth: (T, T, 3) float64 albedo (0 at invalid texels).
        valid: (T, T) bool, the texel maps onto the scan (within the cap, off its rim).
    """
    from gpja.render.uv_raster import rasterize_uv
    from gpja.surface import interpolate, prepare_surface

    texels = rasterize_uv(UV, F_uv, size)
    surface = prepare_surface(*scan)
    hit = surface.closest(texels.surface(V, np.asarray(F, dtype=np.int64)))
    ok = (hit.distance <= max_distance_mm) & ~hit.on_boundary
    values = np.zeros((len(ok), 3))
    values[ok] = albedo(interpolate(surface, hit, rest)[ok])
    return texels.scatter(values), texels.scatter(ok)


def fit_gain(texture: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(3,) float64 least-squares per-channel gain ``g`` of ``texture ~ g * truth`` over ``mask``.

    Args:
        texture, truth: (H, W, 3) float in [0, 1]. mask: (H, W) bool, non-empty.
    """
    t, a = np.asarray(texture, np.float64)[mask], np.asarray(truth, np.float64)[mask]
    denominator = (a * a).sum(axis=0)
    if not mask.any() or (denominator <= 0).any():
        raise ValueError("a gain needs texels with non-zero albedo in every channel")
    return (t * a).sum(axis=0) / denominator


def score_texels(texture: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> dict:
    """``{"psnr", "ssim", "texels"}`` over ``mask`` (None scores for an empty mask).

    Args:
        texture, reference: (H, W, 3) float in [0, 1] (``reference`` equal to ``texture`` off the valid texels).
        mask: (H, W) bool.
    """
    from gpja.metrics.photometric import masked_psnr, masked_ssim

    if not mask.any():
        return {"psnr": None, "ssim": None, "texels": 0}
    return {"psnr": masked_psnr(texture, reference, mask), "ssim": masked_ssim(texture, reference, mask),
            "texels": int(mask.sum())}


def texture_quality(texture: np.ndarray, truth: np.ndarray, valid: np.ndarray,
                    observed: np.ndarray | None = None) -> tuple[dict, np.ndarray]:
    """Scores of a texture against the ground-truth albedo of its texels (module docstring).

    Args:
        texture: (H, W, 3) float in [0, 1], the template's texture.
        truth: (H, W, 3) float64 ground-truth albedo of every texel (:func:`texel_albedo`).
        valid: (H, W) bool texels with a ground truth.
        observed: (H, W) bool texels some view observes; None = every valid texel.
    Returns:
        scores: ``gain`` (3 values), ``observed``/``unobserved``/``all`` ({psnr, ssim, texels}),
        ``valid_texels``, ``texture_size`` [H, W] (JSON-able; +inf PSNR for an exact texture).
        error_image: (H, W, 3) float32 colour-mapped per-texel L1 error.
    Raises:
        InputError: no texel maps onto the scan.
    """
    from gpja.metrics.photometric import l1_error_image

    texture = np.asarray(texture, dtype=np.float64)
    if texture.shape[:2] != valid.shape or truth.shape != texture.shape:
        raise ValueError(f"texture {texture.shape}, truth {truth.shape} and mask {valid.shape} differ in size")
    if not valid.any():
        raise InputError("texture", "no texel maps onto the template expression's scan: is the template in its frame?")
    seen = valid if observed is None else valid & observed
    gain = fit_gain(texture, truth, seen if seen.any() else valid)
    reference = np.where(valid[..., None], np.clip(truth * gain, 0.0, 1.0), texture)
    scores = {"gain": gain.tolist(), "texture_size": list(texture.shape[:2]), "valid_texels": int(valid.sum()),
              "observed": score_texels(texture, reference, seen),
              "unobserved": score_texels(texture, reference, valid & ~seen),
              "all": score_texels(texture, reference, valid)}
    return scores, l1_error_image(texture, reference, valid)


def texture_quality_files(template_dir: str | Path, scans_root: str | Path, ground_truth_root: str | Path,
                          subject: str, template_expression: str, output: str | Path | None = None,
                          error_image: str | Path | None = None, *,
                          max_distance_mm: float = DEFAULT_MAX_DISTANCE_MM) -> dict:
    """:func:`texture_quality` of a template folder against the synthetic ground truth.

    Args:
        template_dir: ``template.obj`` (with UVs, in the template expression's frame), ``texture.png`` and,
            when present, ``texture_observed.png``.
        scans_root: ``{scans_root}/{subject}/{expression}.ply`` (synthetic: mm).
        ground_truth_root: ``{root}/{subject}/{template_expression}.npz`` and ``subject.json``.
        output: the JSON to write (None: not written). error_image: the PNG to write (None: not written).
        max_distance_mm: cap of a texel's distance to the scan.
    Returns:
        the scores, plus ``subject``, ``template_expression``, ``observed_source``, ``max_distance_mm``.
    Raises:
        InputError: missing or corrupt files, a template without UVs, a template in other units than the scan.
    """
    from gpja.data.source import DataSource
    from gpja.data.synthetic.albedo import evaluate_albedo
    from gpja.data.units import check_units
    from gpja.io import read_image, write_image, write_json
    from gpja.mesh import read_obj
    from gpja.metrics.correspondence import read_rest_coords
    from gpja.metrics.oracle import subject_albedo

    d = Path(template_dir)
    template = read_obj(d / "template.obj", load_texture=False)
    if not template.has_uv:
        raise InputError(d / "template.obj", "the template has no texture coordinates")
    texture = read_image(d / "texture.png")
    if texture.shape[0] != texture.shape[1]:
        raise InputError(d / "texture.png", f"is {texture.shape[1]}x{texture.shape[0]}: a template texture is square")
    scan = DataSource(scans_root=scans_root).scan(subject, template_expression)
    check_units(template, scan.V, scan.path)
    rest = read_rest_coords(ground_truth_root, subject, template_expression, len(scan.V))
    tables = subject_albedo(ground_truth_root, subject)
    truth, valid = texel_albedo(template.V, template.F, template.UV, template.F_uv, texture.shape[0],
                                (scan.V, scan.F), rest, lambda X: evaluate_albedo(X, tables),
                                max_distance_mm=max_distance_mm)
    observed, observed_source = None, f"all valid texels ({OBSERVED_FILE} absent)"
    if (d / OBSERVED_FILE).is_file():
        mask = read_image(d / OBSERVED_FILE, mode="L")
        if mask.shape != texture.shape[:2]:
            raise InputError(d / OBSERVED_FILE, f"is {mask.shape[1]}x{mask.shape[0]}, the texture "
                                                f"{texture.shape[1]}x{texture.shape[0]}")
        observed, observed_source = mask > OBSERVED_THRESHOLD, OBSERVED_FILE
    scores, image = texture_quality(texture, truth, valid, observed)
    out = {"subject": str(subject), "template_expression": template_expression, "texture": str(d / "texture.png"),
           "observed_source": observed_source, "max_distance_mm": float(max_distance_mm), **scores,
           "error_image": None if error_image is None else str(error_image)}
    if error_image is not None:
        write_image(error_image, image)
    if output is not None:
        write_json(output, out)
    return out
