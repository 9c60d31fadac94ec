"""SH lighting estimated from colour/normal samples: analytic recovery, identities, bad input, pixel sampling."""
import math

import numpy as np
import pytest
import torch

from gpja.camera import Camera
from gpja.errors import InputError
from gpja.lighting import irradiance_over_pi, uniform_sh
from gpja.register.hra import ExpressionTargets
from gpja.register.lighting_estimate import CLIP_LEVEL, MIN_COS_VIEW, estimate_sh, fit_sh, scan_samples
from tests.test_lighting import fibonacci_sphere
from tests.tolerances import EXACT_F64, SH_EXACT_RELATIVE, SH_NOISY_RELATIVE

ALBEDO = np.array([0.62, 0.45, 0.38])


def directional_sh(seed: int = 0) -> np.ndarray:
    """A tinted near-uniform light with a strong band-1 and a weak band-2 part (like the synthetic captures'),
    of one shape in every channel (a grey light of one tint)."""
    rng = np.random.default_rng(seed)
    sh = uniform_sh(1.1)
    sh[1:4] = np.array([0.5, 1.0, -0.35])[:, None]
    sh[4:9] = rng.uniform(-0.08, 0.08, (5, 1))
    return sh * np.array([1.02, 1.0, 0.97])


def dc_scaled(sh: np.ndarray, like: np.ndarray) -> np.ndarray:
    return sh * (like[0] / sh[0])


def relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def test_constant_albedo_sphere_is_recovered_up_to_the_dc_convention():
    n = fibonacci_sphere(3000)
    truth = directional_sh()
    colors = ALBEDO * irradiance_over_pi(n, truth)
    fit = fit_sh(colors, n, band2_ridge=0.0)
    # the convention: the DC term is uniform white light's; the constant albedo takes the rest of the scale
    np.testing.assert_allclose(fit.sh[0], uniform_sh(1.0)[0], rtol=EXACT_F64)
    assert relative(fit.sh, dc_scaled(truth, fit.sh)) < SH_EXACT_RELATIVE
    np.testing.assert_allclose(fit.albedo, ALBEDO * truth[0] / uniform_sh(1.0)[0], rtol=SH_EXACT_RELATIVE)
    np.testing.assert_allclose(fit.albedo * irradiance_over_pi(n, fit.sh), colors, atol=EXACT_F64)
    assert fit.inlier_fraction == 1.0


def test_uniform_light_gives_uniform_sh():
    """Identity: a constant colour on every normal is uniform light, whatever the albedo."""
    n = fibonacci_sphere(500)
    sh = estimate_sh(np.tile(ALBEDO, (len(n), 1)), n)
    np.testing.assert_allclose(sh, uniform_sh(1.0), atol=EXACT_F64)


def test_dark_outliers_and_albedo_noise_are_rejected():
    """20% of the samples 40-80% darker (brows, lips, moles against skin), the rest with +-5% albedo noise."""
    rng = np.random.default_rng(1)
    n = fibonacci_sphere(4000)
    truth = directional_sh(1)
    albedo = ALBEDO * (1.0 + 0.05 * rng.uniform(-1, 1, (len(n), 1)))
    colors = albedo * irradiance_over_pi(n, truth)
    outlier = rng.random(len(n)) < 0.2
    colors[outlier] *= rng.uniform(0.2, 0.6, (outlier.sum(), 1))
    robust = fit_sh(colors, n, band2_ridge=0.0)
    plain = fit_sh(colors, n, band2_ridge=0.0, iterations=1)
    assert relative(robust.sh, dc_scaled(truth, robust.sh)) < SH_NOISY_RELATIVE
    assert relative(plain.sh, dc_scaled(truth, plain.sh)) > 2 * SH_NOISY_RELATIVE  # the robust weights matter
    assert robust.inlier_fraction == pytest.approx(1.0 - outlier.mean(), abs=0.02)
    # exact inliers: the outliers are rejected entirely and the fit is exact
    exact = ALBEDO * irradiance_over_pi(n, truth)
    exact[outlier] *= 0.5
    assert relative(estimate_sh(exact, n, band2_ridge=0.0), dc_scaled(truth, uniform_sh(1.0))) < SH_EXACT_RELATIVE


def test_clipped_colours_count_as_at_least_the_clip_level():
    """The brightest third of the samples clip: censored, the fit stays exact; taken at face value, it flattens."""
    n = fibonacci_sphere(3000)
    truth = directional_sh(4)
    colors = 1.3 * ALBEDO * irradiance_over_pi(n, truth)
    colors = np.minimum(colors, np.quantile(colors[:, 0], 0.67))
    colors = colors / colors.max() * CLIP_LEVEL  # red clips on a third of the sphere
    assert 0.25 < (colors[:, 0] >= CLIP_LEVEL).mean() < 0.4
    censored = fit_sh(colors, n, band2_ridge=0.0)
    assert relative(censored.sh, dc_scaled(truth, censored.sh)) < SH_EXACT_RELATIVE
    naive = fit_sh(colors, n, band2_ridge=0.0, clip=None)
    assert relative(naive.sh, dc_scaled(truth, naive.sh)) > 2 * SH_NOISY_RELATIVE  # measured 5.5%


def test_grey_light_shares_one_shape_and_coloured_light_needs_grey_off():
    n = fibonacci_sphere(2000)
    coloured = directional_sh(5)
    coloured[1:4, 2] *= -1.0  # blue light from the other side
    colors = ALBEDO * irradiance_over_pi(n, coloured)
    free = fit_sh(colors, n, band2_ridge=0.0, grey=False).sh
    assert relative(free, dc_scaled(coloured, free)) < SH_EXACT_RELATIVE
    shared = fit_sh(colors, n, band2_ridge=0.0).sh
    np.testing.assert_allclose(shared[:, 0] / shared[0, 0], shared[:, 2] / shared[0, 2], atol=EXACT_F64)


def test_given_albedo_is_recovered_exactly():
    rng = np.random.default_rng(2)
    n = fibonacci_sphere(2000)
    truth = directional_sh(2)
    albedo = rng.uniform(0.05, 0.9, (len(n), 3))
    sh = estimate_sh(albedo * irradiance_over_pi(n, truth), n, albedo=albedo, band2_ridge=0.0)
    assert relative(sh, truth) < SH_EXACT_RELATIVE  # no scale convention: the albedo fixes it


def test_the_band2_ridge_pulls_band2_towards_zero():
    n = fibonacci_sphere(2000)
    n = n[n[:, 2] > -0.2]  # about a hemisphere, as a face shows
    truth = directional_sh(3)
    colors = ALBEDO * irradiance_over_pi(n, truth)
    free, ridged = (estimate_sh(colors, n, band2_ridge=r) for r in (0.0, 0.05))
    truth = dc_scaled(truth, free)
    assert relative(free, truth) < SH_EXACT_RELATIVE
    assert np.linalg.norm(ridged[4:]) < np.linalg.norm(truth[4:])
    np.testing.assert_allclose(ridged[0], free[0], rtol=EXACT_F64)


def test_normals_that_cannot_determine_the_lighting_are_refused():
    colors = np.tile(ALBEDO, (100, 1))
    with pytest.raises(InputError, match="do not determine the lighting"):
        fit_sh(colors, np.tile([0.0, 0.0, 1.0], (100, 1)))
    with pytest.raises(InputError, match="do not determine the lighting"):  # a great circle leaves Y10 free
        t = np.linspace(0, 2 * math.pi, 100, endpoint=False)
        fit_sh(colors, np.stack([np.cos(t), np.sin(t), 0 * t], 1), band2_ridge=0.0)


@pytest.mark.parametrize("change, match", [
    (dict(colors=np.ones((50, 4))), "colors"),
    (dict(normals=np.ones((49, 3))), "normals"),
    (dict(albedo=np.ones((50, 1))), "albedo"),
    (dict(weights=-np.ones(50)), "weights"),
    (dict(colors=np.full((50, 3), np.nan)), "NaN"),
    (dict(colors=np.ones((5, 3)), normals=fibonacci_sphere(5)), "samples"),
    (dict(colors=-np.ones((50, 3))), "no light"),
])
def test_bad_input_is_named(change, match):
    args = dict(colors=np.ones((50, 3)), normals=fibonacci_sphere(50), albedo=None, weights=None)
    args.update(change)
    with pytest.raises(InputError, match=match):
        fit_sh(**args)


def test_scan_samples_keep_squarely_seen_fully_covered_pixels():
    size = 8
    K = np.array([[1000.0, 0, (size - 1) / 2], [0, 1000.0, (size - 1) / 2], [0, 0, 1]])  # rays ~ the axis
    cam = Camera.look_at((0, 0, 500.0), (0, 0, 0), (0, 1, 0), K, size, size)
    images = torch.full((1, size, size, 3), 0.5)
    normal = torch.zeros(1, size, size, 3)
    normal[..., 2] = 1.0  # facing the camera (it looks down -z)
    coverage = torch.ones(1, size, size, 1)
    coverage[0, 0, 0] = 0.5                      # a silhouette pixel
    grazing = math.cos(math.acos(MIN_COS_VIEW) + 0.05)
    normal[0, 0, 2] = torch.tensor([math.sqrt(1 - grazing ** 2), 0.0, grazing])  # seen almost edge-on
    normal[0, 0, 3] = 0.0                        # no scan normal
    images[0, 1, 1] = CLIP_LEVEL                 # clipped: kept (the fit treats it as censored)
    targets = ExpressionTargets([cam], images, torch.zeros(1, size, size, 1), normal, coverage, torch.zeros(9, 3))
    colors, normals, weights = scan_samples(targets, normal_blur_px=0.0)
    assert len(colors) == size * size - 3
    assert (colors == 0.5).all(axis=1).sum() == len(colors) - 1
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=EXACT_F64)
    assert ((weights > 0.99) & (weights <= 1.0)).all()  # near the optical axis the normal faces the ray
    targets.coverage.zero_()
    with pytest.raises(InputError, match="cannot estimate the lighting"):
        scan_samples(targets)


def test_normal_blur_keeps_a_plane_and_averages_noise():
    size = 32
    K = np.array([[1000.0, 0, (size - 1) / 2], [0, 1000.0, (size - 1) / 2], [0, 0, 1]])
    cam = Camera.look_at((0, 0, 500.0), (0, 0, 0), (0, 1, 0), K, size, size)
    tilted = torch.tensor([0.3, 0.0, 1.0]) / math.hypot(0.3, 1.0)
    noise = torch.from_numpy(np.random.default_rng(0).normal(0, 0.1, (1, size, size, 3)).astype(np.float32))
    coverage = torch.zeros(1, size, size, 1)
    coverage[:, 4:28, 4:28] = 1.0  # a covered square: the background must not leak in at its border
    for normal, blur_helps in ((tilted.expand(1, size, size, 3).clone(), False), (tilted + noise, True)):
        targets = ExpressionTargets([cam], torch.full((1, size, size, 3), 0.5), torch.zeros(1, size, size, 1),
                                    normal * coverage, coverage, torch.zeros(9, 3))
        errors = [np.arccos(np.clip(scan_samples(targets, blur)[1] @ tilted.double().numpy(), -1, 1)).mean()
                  for blur in (0.0, 1.0)]
        if blur_helps:
            assert errors[1] < 0.5 * errors[0]
        else:
            assert max(errors) < 1e-3
