import importlib.util

import pytest
import torch

from gpja.render import renderer, resolve_backend, render_views
from gpja.render.nvdiffrast_backend import screen_to_clip


def test_auto_falls_back_to_cpu_without_cuda():
    if importlib.util.find_spec("nvdiffrast") is not None and torch.cuda.is_available():
        pytest.skip("a GPU with nvdiffrast is present")
    assert resolve_backend("auto") == "cpu"
    assert renderer("auto") is render_views
    assert renderer("cpu") is render_views


def test_requesting_missing_nvdiffrast_fails_clearly():
    if importlib.util.find_spec("nvdiffrast") is not None and torch.cuda.is_available():
        pytest.skip("a GPU with nvdiffrast is present")
    with pytest.raises(RuntimeError, match="nvdiffrast is not installed or no CUDA device"):
        resolve_backend("nvdiffrast")
    with pytest.raises(ValueError, match="must be one of"):
        resolve_backend("opengl")


def test_screen_to_clip_maps_pixel_centres_and_depth():
    # pixel (0, 0) centre -> NDC (-1 + 1/W, 1 - 1/H); w carries the camera depth
    screen = torch.tensor([[[0.0, 0.0, 500.0], [99.0, 49.0, 500.0]]], dtype=torch.float64)
    clip = screen_to_clip(screen, 100, 50)
    ndc = clip[..., :3] / clip[..., 3:]
    torch.testing.assert_close(ndc[0, 0, :2], torch.tensor([-1 + 1 / 100, 1 - 1 / 50], dtype=torch.float64))
    torch.testing.assert_close(ndc[0, 1, :2], torch.tensor([1 - 1 / 100, -1 + 1 / 50], dtype=torch.float64))
    assert torch.all(ndc[..., 2].abs() < 1)
    torch.testing.assert_close(clip[..., 3], screen[..., 2])
