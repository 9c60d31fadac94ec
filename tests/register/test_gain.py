"""gpja.register.gain: the capture's colour gain per expression, measured against the start's render."""
import dataclasses

import numpy as np
import pytest
import torch

from gpja.lighting import uniform_sh
from gpja.register.gain import GAIN_RANGE, MIN_PIXELS, UnlikelyGain, match_gain, measure_gain, with_gain
from gpja.register.hra import ExpressionTargets, Switches
from gpja.render import Topology, render_views
from tests.register.test_seal import opened_bust
from tests.tolerances import GAIN_EXACT, GAIN_MISALIGNED

TRUE_GAIN = np.array([1.05, 0.97, 1.02])


def test_match_gain_is_the_median_ratio_and_ignores_a_minority_of_outliers():
    rng = np.random.default_rng(0)
    rendered = rng.uniform(0.1, 0.9, (1000, 3))
    reference = rendered * TRUE_GAIN
    reference[:300] = rng.uniform(0.0, 1.0, (300, 3))  # misaligned pixels: anything
    assert np.allclose(match_gain(rendered[300:], reference[300:]), TRUE_GAIN, rtol=1e-12)
    assert np.allclose(match_gain(rendered, reference), TRUE_GAIN, rtol=0.02)
    with pytest.raises(ValueError, match="positive"):
        match_gain(np.zeros((3, 3)), np.ones((3, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        match_gain(np.ones((0, 3)), np.ones((0, 3)))


def _scene(small_bust, degrees: float = 0.0):
    """The bust, a textured albedo (so the gain is measured on varied colours), its mouth mask and three cameras."""
    placed, mask, cameras = opened_bust(small_bust, degrees)
    v, u = torch.meshgrid(torch.linspace(0, 1, 64), torch.linspace(0, 1, 64), indexing="ij")
    texture = torch.stack([0.5 + 0.3 * torch.sin(9 * u), 0.4 + 0.2 * torch.cos(7 * v), 0.35 + 0.1 * u], dim=-1)
    return placed, mask, cameras, texture


def _targets(mesh, mask, cameras, texture, gain) -> ExpressionTargets:
    """References rendered from ``mesh`` under uniform light times ``gain``; the targets carry the plain light."""
    sh = torch.tensor(uniform_sh(), dtype=torch.float32)
    ref = render_views(torch.tensor(mesh.V, dtype=torch.float32), Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv)),
                       cameras, ("color", "depth", "normal"), uv=torch.tensor(mesh.UV, dtype=torch.float32),
                       texture=texture, mask_texture=mask, sh=sh * torch.tensor(gain, dtype=torch.float32)[None, :])
    return ExpressionTargets(cameras, *(ref.dense(p).detach() for p in ("color", "depth", "normal", "coverage")), sh)


def test_with_gain_scales_every_render_per_channel_and_inverts(small_bust):
    placed, mask, cameras, texture = _scene(small_bust)
    plain = _targets(placed, mask, cameras, texture, np.ones(3))
    gained = with_gain(plain, TRUE_GAIN)
    topology = Topology(torch.from_numpy(placed.F), torch.from_numpy(placed.F_uv))
    args = (torch.tensor(placed.V, dtype=torch.float32), topology, cameras, ("color",))
    kw = dict(uv=torch.tensor(placed.UV, dtype=torch.float32), texture=texture, mask_texture=mask)
    base = render_views(*args, sh=plain.sh, **kw).values["color"]
    scaled = render_views(*args, sh=gained.sh, **kw).values["color"]
    assert torch.allclose(scaled, base * torch.tensor(TRUE_GAIN, dtype=torch.float32), rtol=1e-5, atol=1e-7)
    assert torch.allclose(with_gain(gained, 1.0 / TRUE_GAIN).sh, plain.sh, rtol=1e-6)
    assert gained.images is plain.images  # nothing else changes
    with pytest.raises(ValueError, match="three positive"):
        with_gain(plain, [1.0, -1.0, 1.0])


def test_measure_gain_recovers_a_known_exposure(small_bust):
    placed, mask, cameras, texture = _scene(small_bust)
    gain, entry = measure_gain(placed, _targets(placed, mask, cameras, texture, TRUE_GAIN), texture, mask)
    assert entry["measured"] and entry["pixels"] >= MIN_PIXELS
    np.testing.assert_allclose(gain, TRUE_GAIN, rtol=GAIN_EXACT)


def test_measure_gain_from_a_start_that_is_millimetres_off(small_bust):
    """The start is the parent expression's registration: the mouth differs, the median does not mind."""
    placed, mask, cameras, texture = _scene(small_bust)
    opened = _scene(small_bust, 3.0)[0]
    gain, _ = measure_gain(placed, _targets(opened, mask, cameras, texture, TRUE_GAIN), texture, mask)
    np.testing.assert_allclose(gain, TRUE_GAIN, rtol=GAIN_MISALIGNED)


def test_measure_gain_without_enough_skin_is_one_and_refuses_the_absurd(small_bust):
    placed, mask, cameras, texture = _scene(small_bust)
    targets = _targets(placed, mask, cameras, texture, np.ones(3))
    dark = dataclasses.replace(targets, images=torch.zeros_like(targets.images))  # nothing to divide
    gain, entry = measure_gain(placed, dark, texture, mask)
    assert not entry["measured"] and np.array_equal(gain, np.ones(3))
    too_bright = _targets(placed, mask, cameras, 0.3 * texture, np.full(3, GAIN_RANGE[1] + 0.5))
    with pytest.raises(UnlikelyGain, match="times as bright"):
        measure_gain(placed, too_bright, 0.3 * texture, mask)


def test_the_registration_measures_the_gain_first_when_asked(small_bust):
    from gpja.register.multiscale import Schedule, optimise

    placed, mask, cameras, texture = _scene(small_bust)
    targets = _targets(placed, mask, cameras, texture, TRUE_GAIN)
    schedule = Schedule(lambdas=(50.0,), iterations=(1,), color_gain=True)
    _, log = optimise(placed, targets, Switches(), schedule, texture=texture, mask_texture=mask, progress=lambda m: None)
    first = log.levels[0]
    assert first["stage"] == "color_gain" and first["measured"]
    np.testing.assert_allclose(first["gain"], TRUE_GAIN, rtol=1e-4)
    _, log = optimise(placed, targets, Switches(), dataclasses.replace(schedule, color_gain=False), texture=texture,
                      mask_texture=mask, progress=lambda m: None)
    assert all(entry.get("stage") != "color_gain" for entry in log.levels)
