"""The capture's SH lighting estimated from the data: colours, surface normals and (optionally) an albedo.

A real capture comes without its lighting, so the method estimates it from what it sees
(the synthetic ground truth's lighting is for scoring only). Model (``gpja.lighting``):
a pixel of colour ``c`` (3,) seeing a Lambertian surface point of unit normal ``n`` and albedo
``a`` has ``c = a * irradiance_over_pi(n, sh) = a * (sh_basis(n) @ (A / pi * sh))`` per channel.
The shading is linear in ``sh``, so for a known albedo ``sh`` is a linear least-squares fit
(9 unknowns per channel). (A fused albedo is no such knowledge: it is the colours divided by the
shading of the lighting it was fused under, and refitting with it returns that lighting.)

Without an albedo, the fit (:func:`fit_sh`) assumes one constant albedo per channel (skin) and
treats what is not skin (hair, brows, lips, eyes, moles, the mouth, cast shadows on real data) as
outliers:

- iteratively reweighted least squares with Tukey's biweight on the colour's relative residual,
  its scale from the median; Tukey's loss is not convex and hair can cover a third of a head's
  pixels, so it runs from several starts (all samples, and windows of half the samples by
  brightness) and keeps the run that fits most of the samples within ``CONSENSUS_RELATIVE``;
- clipped colours (``CLIP_LEVEL``) are censored: they count only where the model predicts less
  than their value (an active set). Dropping them biases the fit (the bright, clipped skin is what
  shows the light's direction: on 256 px captures 20-45% of the samples clip in red); imputing the
  model's value converges too slowly;
- the light is grey (``GREY_LIGHT``): one SH shape for the three channels, each with its own DC
  (a studio light of one tint); ``grey=False`` fits a shape per channel;
- the band-2 coefficients are weakly determined by a face (its normals cover little more than a
  hemisphere, and skin albedo varies at the scale of the shading): a ridge pulls them towards 0
  (``BAND2_RIDGE``, relative to the data's own weight on them: 1 = as much prior as data);
- the scan's normal images are blurred by ``NORMAL_BLUR_PX`` (:func:`scan_samples`).

A constant albedo and the light share one scale per channel, which the data cannot separate; the
convention fixes it: **the DC term of the estimate equals that of uniform white light of radiance 1**
(``uniform_sh(1.0)[0]``, so the mean irradiance over the sphere is that of the paper's FaceScape
assumption and an estimate without directional part *is* uniform light); the albedo (the fused
texture) takes the overall level and tint of the capture. A set of normals that cannot determine
bands 0-1 (e.g. all equal) raises :class:`~gpja.errors.InputError`.

Measured (``/tmp``-only sweeps, scan normals of the mouth-open expression, relative L2 error over the
27 coefficients after DC matching, ``gpja.metrics.lighting``): default data S01 2.7%, S02 2.4%; five
held-out seeds at 256 px, 8 views 2.3-3.7%, 6 views and 0.2 mm scan noise 3.4%, 0.3 mm noise 2.3%;
4 views (front, +-36 deg, 70 deg) 8.9%: with few views the skin albedo's low-frequency variation
(freckles on the cheeks, redness) correlates with the normals; with the true albedo the same fit
is within 1%. Uniform light is 29-45% off on these subjects.

Why not a library: scikit-learn's ``HuberRegressor``/``RANSACRegressor`` fit one output at a time
(no shared outlier weights across the 3 channels), know no censored samples and no per-coefficient
ridge, and would be a new dependency for a 9-unknown weighted solve that numpy does in a few lines.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gpja.errors import InputError
from gpja.lighting import LAMBERT_FACTORS, sh_basis, uniform_sh

if TYPE_CHECKING:
    from gpja.register.hra import ExpressionTargets

#: The scale convention of an estimate without albedo (module docstring), also written to ``lighting.json``.
CONVENTION = ("gpja.lighting radiance SH (9, 3): rows Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21, Y22, columns RGB; "
              "outgoing = albedo * irradiance_over_pi(n, sh). Albedo (texture.png) and light share one scale per "
              "channel: the estimate's DC term is uniform_sh(1.0)'s, times one factor the template may move into the "
              "light so the texture does not clip (template.json texture.albedo_scale); compare lightings after "
              "matching their DC terms")
#: IRLS iterations of the constant-albedo fit (it converges in 5-10 on faces; it stops early when the weights settle).
ROBUST_ITERATIONS = 20
#: Tukey biweight cut-off in robust standard deviations (4.685: 95% efficiency under Gaussian residuals).
TUKEY_C = 4.685
#: Ridge on the band-2 coefficients, relative to the data's total weight (module docstring).
BAND2_RIDGE = 1.0
#: A fit whose (regularised) normal matrix is worse conditioned than this is refused: the normals do not
#: determine the lighting.
MAX_CONDITION = 1e8
#: Weight changes below this end the IRLS.
WEIGHT_TOLERANCE = 1e-4
#: Floor of the robust scale of the relative residuals (8-bit images quantise colours to ~0.2%).
MIN_SCALE = 1e-6
#: Whether the fit gives the three channels one SH shape by default (``fit_sh(grey=...)``, module docstring).
GREY_LIGHT = True
#: Colour channels at or above this are taken as clipped by the camera (8-bit: 253/255 and up).
CLIP_LEVEL = 0.99
#: Lower ends of the brightness windows (half the samples each) the robust fit also starts from.
START_WINDOWS = (0.0, 0.25, 0.5)
#: A sample counts towards a run's consensus when its relative residual is below this.
CONSENSUS_RELATIVE = 0.1
#: The most samples a fit uses (a deterministic stride through the given ones): a 512 px capture has ~500K;
#: 100K give the same estimate (within 0.1% on four synthetic subjects) in several times the time.
MAX_SAMPLES = 25_000
#: Fewer samples than this are refused (9 unknowns per channel, plus outliers).
MIN_SAMPLES = 30


@dataclass(frozen=True)
class ShFit:
    """An SH estimate and how it was reached.

    Attributes:
        sh: (9, 3) float64 radiance SH coefficients (``gpja.lighting`` convention; without albedo, DC fixed).
        albedo: (3,) float64 the constant albedo of a fit without albedo (what the DC convention left for the
            albedo), or None when an albedo was given.
        inlier_fraction: share of the samples' weight with a final robust weight above 0.5.
        relative_rms: RMS over inliers and channels of (colour - model) / model.
        iterations: IRLS iterations of the chosen run.
        samples: number of samples given.
        consensus: share of the samples' weight the chosen run fits within ``CONSENSUS_RELATIVE``.
    """

    sh: np.ndarray
    albedo: np.ndarray | None
    inlier_fraction: float
    relative_rms: float
    iterations: int
    samples: int
    consensus: float = 1.0

    def to_json(self) -> dict:
        return {"sh": self.sh.tolist(), "albedo": None if self.albedo is None else self.albedo.tolist(),
                "inlier_fraction": round(self.inlier_fraction, 4), "relative_rms": round(self.relative_rms, 5),
                "iterations": self.iterations, "samples": self.samples, "consensus": round(self.consensus, 4)}


def _check_samples(colors, normals, albedo, weights) -> tuple[np.ndarray, ...]:
    """float64 copies of the samples, shapes and values checked; normals made unit."""
    c = np.asarray(colors, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise InputError("colors", f"expected (k, 3) colours, got shape {c.shape}")
    if n.shape != c.shape:
        raise InputError("normals", f"expected {c.shape} normals (one per colour), got shape {n.shape}")
    if len(c) < MIN_SAMPLES:
        raise InputError("colors", f"{len(c)} samples cannot determine the lighting (at least {MIN_SAMPLES})")
    a = None
    if albedo is not None:
        a = np.asarray(albedo, dtype=np.float64)
        if a.shape != c.shape:
            raise InputError("albedo", f"expected {c.shape} albedos (one per colour), got shape {a.shape}")
    w = np.ones(len(c)) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (len(c),):
        raise InputError("weights", f"expected ({len(c)},) weights, got shape {w.shape}")
    for name, arr in (("colors", c), ("normals", n), ("albedo", a), ("weights", w)):
        if arr is not None and not np.isfinite(arr).all():
            raise InputError(name, "contains NaN or infinite values")
    if (w < 0).any() or not w.sum() > 0:
        raise InputError("weights", "weights must be >= 0 and not all 0")
    length = np.linalg.norm(n, axis=1, keepdims=True)
    if not (length > 1e-9).all():
        raise InputError("normals", "contains zero-length normals")
    return c, n / length, a, w


def _normal_matrix(design: np.ndarray, w: np.ndarray, penalty: np.ndarray) -> np.ndarray:
    """(9, 9) weighted normal matrix plus ridge; InputError when it is too badly conditioned."""
    gram = (design * w[:, None]).T @ design + np.diag(penalty)
    evals = np.linalg.eigvalsh(gram)
    if not evals[0] > evals[-1] / MAX_CONDITION:
        raise InputError("normals", f"the normals (and albedos) do not determine the lighting: normal matrix "
                                    f"condition {evals[-1] / max(evals[0], 1e-300):.3g} (they span too few "
                                    "directions, e.g. all equal)")
    return gram


def _solve(basis: np.ndarray, colors: np.ndarray, albedo: np.ndarray | None, w: np.ndarray,
           ridge: float) -> np.ndarray:
    """Weighted ridge least squares of ``colors ~ (albedo *) basis @ x`` per channel: (9, 3) ``x``.

    ``w``: (k, 3) weights per sample and channel (a clipped channel may count where the others do not).
    """
    x = np.empty((9, 3))
    for ch in range(3):
        design = basis if albedo is None else basis * albedo[:, ch : ch + 1]
        penalty = np.zeros(9)
        penalty[4:] = ridge * w[:, ch].sum() / (4.0 * math.pi)  # E[Y_2m^2] over the sphere is 1 / (4 pi)
        x[:, ch] = np.linalg.solve(_normal_matrix(design, w[:, ch], penalty), design.T @ (w[:, ch] * colors[:, ch]))
    return x


def _tukey(residual: np.ndarray, prior: np.ndarray) -> np.ndarray:
    """Tukey biweights (k,) of residuals (k,) >= 0, scale from the median over samples of positive prior weight
    (floored at MIN_SCALE)."""
    # floored: when most samples fit exactly, the others are still rejected (and exact data keeps all)
    scale = max(1.4826 * float(np.median(residual[prior > 0])), MIN_SCALE)
    u = residual / (TUKEY_C * scale)
    return np.where(u < 1.0, (1.0 - u * u) ** 2, 0.0)


@dataclass
class _Run:
    """One IRLS run: coefficients (9, 3) of ``(albedo *) basis @ x``, final robust weights and residuals (k,)."""

    x: np.ndarray
    robust: np.ndarray
    residual: np.ndarray
    iterations: int
    consensus: float = 0.0


def _one_shape(x: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(9, 3) coefficients with one shape for the three channels: each column's DC kept, the DC-normalised
    columns averaged with weights (3,) ``w`` (a white light of one tint; module docstring)."""
    shape = (x / x[0]) @ (w / w.sum())
    return np.outer(shape, x[0])


def _irls(basis, c, a, prior, clipped, robust, iterations: int, ridge: float, grey: bool) -> _Run:
    """IRLS from the robust weights ``robust`` (k,); clipped colours (k, 3) bool are censored.

    A clipped channel only says "at least this bright": it is left out of the fit while the model predicts at
    least its value, and fitted like any other where the model predicts less (an active set, updated with the
    robust weights; imputing the model's value instead converges too slowly when many pixels clip).
    """
    active = ~clipped
    x, residual, it = None, None, 0
    for it in range(1, max(1, int(iterations)) + 1):
        w = (prior * robust)[:, None] * active
        x = _solve(basis, c, a, w, ridge)
        if grey and (x[0] > 0).all():
            x = _one_shape(x, w.sum(axis=0))
        model = basis @ x if a is None else a * (basis @ x)
        relative = (c - model) / np.maximum(np.abs(model), 1e-6)
        relative = np.where(clipped, np.maximum(relative, 0.0), relative)
        residual = np.sqrt((relative ** 2).mean(axis=1))
        updated = _tukey(residual, prior)
        settled = np.abs(updated - robust).max() < WEIGHT_TOLERANCE
        robust = updated
        now = ~clipped | (model < c)
        settled &= bool((now == active).all())
        active = now
        if settled:
            break
    return _Run(x, robust, residual, it)


def _starts(c: np.ndarray, a: np.ndarray | None, prior: np.ndarray) -> list[np.ndarray]:
    """Initial robust weights (k,) of the runs: every sample, then each window of half the samples by the
    brightness of colour / albedo (skin, hair and shadowed skin start apart, so Tukey's non-convex loss cannot
    settle between them)."""
    brightness = (c if a is None else c / np.maximum(a, 1e-6)).mean(axis=1)
    rank = np.empty(len(c))
    rank[np.argsort(brightness, kind="stable")] = np.arange(len(c)) / len(c)
    return [np.ones(len(c))] + [((rank >= lo) & (rank < lo + 0.5)).astype(np.float64) for lo in START_WINDOWS]


def fit_sh(colors, normals, albedo=None, weights=None, *, iterations: int = ROBUST_ITERATIONS,
           band2_ridge: float = BAND2_RIDGE, clip: float | None = CLIP_LEVEL, grey: bool = GREY_LIGHT,
           max_samples: int | None = MAX_SAMPLES) -> ShFit:
    """Least-squares SH lighting from colour samples of a Lambertian surface (module docstring).

    Robust fit: IRLS with Tukey's biweight from several starts (all samples, then windows of half the samples by
    brightness); the run under which most of the samples' weight fits within ``CONSENSUS_RELATIVE`` wins.

    Args:
        colors: (k, 3) float observed linear RGB (any scale; [0, 1] for images).
        normals: (k, 3) float world-frame surface normals of the samples (normalised here).
        albedo: (k, 3) float albedo of each sample, or None: one constant albedo per channel, fitted robustly,
            with the scale fixed by the DC convention.
        weights: (k,) float >= 0 prior weight of each sample (e.g. how squarely its view sees it); None = 1.
        iterations: IRLS iterations per start (1 = plain weighted least squares, one start). With an albedo the
            same robust reweighting runs; exact data ends it after one iteration.
        band2_ridge: ridge on the band-2 coefficients relative to the total weight (0 = none).
        clip: colour channels at or above this are clipped by the camera (censored): they count as "at least
            this bright", pulling the model up only where it predicts less; None = no clipping.
        grey: one SH shape for the three channels (their DC terms free: a light of one tint); False = a
            shape per channel (coloured lights from different directions).
        max_samples: fit at most this many samples, every ``ceil(k / max_samples)``-th in the given order
            (deterministic; 27 unknowns need far fewer than a capture's pixels); None = all.
    Returns:
        :class:`ShFit` with ``sh`` (9, 3) float64.
    Raises:
        InputError: wrong shapes, NaNs, negative weights, fewer than ``MIN_SAMPLES`` samples, normals that
            do not determine bands 0-1, or a fit with a non-positive DC term (no light).
    """
    c, n, a, prior = _check_samples(colors, normals, albedo, weights)
    if max_samples is not None and len(c) > max_samples:
        step = -(-len(c) // int(max_samples))
        c, n, prior = c[::step], n[::step], prior[::step]
        a = None if a is None else a[::step]
    basis = sh_basis(n)
    clipped = np.zeros(c.shape, dtype=bool) if clip is None else c >= clip
    starts = _starts(c, a, prior) if iterations > 1 else [np.ones(len(c))]
    # every sample first: it raises when the normals cannot determine the lighting
    runs = [_irls(basis, c, a, prior, clipped, starts[0], iterations, band2_ridge, grey)]
    for robust in starts[1:]:
        try:
            runs.append(_irls(basis, c, a, prior, clipped, robust, iterations, band2_ridge, grey))
        except InputError:
            continue  # a window's samples alone may not determine the lighting; the others do
    for run in runs:
        run.consensus = float((prior * (run.residual < CONSENSUS_RELATIVE)).sum() / prior.sum())
    best = max(runs, key=lambda r: r.consensus)  # the first of equals: deterministic
    sh = best.x / (LAMBERT_FACTORS / math.pi)[:, None]
    albedo_out = None
    if a is None:
        if not (sh[0] > 0).all():
            raise InputError("colors", f"the fitted constant term {sh[0].round(4).tolist()} is not positive: no light")
        albedo_out = sh[0] / uniform_sh(1.0)[0]
        sh = sh / albedo_out
    elif not (sh[0] > 0).all():
        raise InputError("colors", f"the fitted DC term {sh[0].round(4).tolist()} is not positive: no light")
    kept = prior * (best.robust > 0.5)
    rms = float(np.sqrt((kept * best.residual ** 2).sum() / kept.sum())) if kept.any() else float("nan")
    return ShFit(sh, albedo_out, float(kept.sum() / prior.sum()), rms, best.iterations, len(np.asarray(colors)),
                 best.consensus)


def estimate_sh(colors, normals, albedo=None, weights=None, **options) -> np.ndarray:
    """(9, 3) float64 SH lighting of :func:`fit_sh` (same arguments and keyword options), without the diagnostics."""
    return fit_sh(colors, normals, albedo, weights, **options).sh


#: Samples of :func:`scan_samples`: pixels the scan covers fully (no silhouette blend) ...
MIN_COVERAGE = 0.999
#: ... whose surface faces the camera at least this much (cos of the angle to the viewing ray).
MIN_COS_VIEW = 0.2
#: Gaussian blur (sigma, px) of the scan's normal images before sampling: a pixel's colour integrates the shading
#: over its footprint, and an MVS scan's normals are noisy at its vertex spacing. Measured on 256 px captures:
#: scan noise 0.3 mm, lighting error 6.0% -> 3.7% (0.2 mm, 6 views: 4.5% -> 3.4%); noise-free 3.8% -> 4.1%.
NORMAL_BLUR_PX = 1.0


def blurred_normals(normal: np.ndarray, coverage: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W, 3) normals averaged with a Gaussian of ``sigma`` px over the covered pixels (coverage (H, W) >= 0.5),
    renormalised; OpenCV's separable ``GaussianBlur`` (normalised convolution: the background does not leak in)."""
    import cv2

    inside = (coverage >= 0.5).astype(np.float32)
    num = cv2.GaussianBlur(normal.astype(np.float32) * inside[..., None], (0, 0), sigma)
    den = cv2.GaussianBlur(inside, (0, 0), sigma)[..., None]
    out = num / np.maximum(den, 1e-6)
    return (out / np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-9)) * inside[..., None]


def scan_samples(targets: "ExpressionTargets", normal_blur_px: float = NORMAL_BLUR_PX
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Colour/normal samples for :func:`fit_sh` from an expression's images and its scan's normals.

    Every pixel of every view that the scan covers fully and whose scan normal faces the camera by
    at least ``MIN_COS_VIEW``; its prior weight is that cosine (grazing pixels mix neighbours and
    carry the scan's worst normals). Clipped colours are kept: :func:`fit_sh` treats them as censored.

    Args:
        targets: the expression's cameras, (B, H, W, 3) images, (B, H, W, 3) scan normals and
            (B, H, W, 1) scan coverage (``gpja.register.hra.ExpressionTargets``).
        normal_blur_px: sigma (px) of the normal images' blur (``NORMAL_BLUR_PX``); 0 = none.
    Returns:
        colors (k, 3) float64, normals (k, 3) float64 unit, weights (k,) float64 in (0, 1].
    Raises:
        InputError: no pixel qualifies.
    """
    colors, normals, weights = [], [], []
    for i, cam in enumerate(targets.cameras):
        image = targets.images[i].reshape(-1, 3).double().cpu().numpy()
        normal = targets.normal[i].cpu().numpy()
        coverage = targets.coverage[i, ..., 0].cpu().numpy()
        if normal_blur_px > 0:
            normal = blurred_normals(normal, coverage, normal_blur_px)
        normal, coverage = normal.reshape(-1, 3).astype(np.float64), coverage.reshape(-1)
        length = np.linalg.norm(normal, axis=1)
        keep = (coverage >= MIN_COVERAGE) & (length > 0.5)
        idx = np.flatnonzero(keep)
        if not len(idx):
            continue
        n = normal[idx] / length[idx, None]
        uv = np.stack([idx % cam.width, idx // cam.width], axis=1).astype(np.float64)
        _, rays = cam.pixel_rays(uv)
        cos = -(n * rays).sum(axis=1)
        facing = cos >= MIN_COS_VIEW
        colors.append(image[idx[facing]])
        normals.append(n[facing])
        weights.append(cos[facing])
    if not colors or not sum(len(c) for c in colors):
        raise InputError("scan targets", "no pixel of any view sees the scan squarely: cannot estimate the lighting")
    return np.concatenate(colors), np.concatenate(normals), np.concatenate(weights)
