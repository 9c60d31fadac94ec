import importlib.util

import pytest
import torch

from gpja.errors import InputError
from gpja.render import BACKENDS, renderer, resolve_backend, render_views
from gpja.render import backend as backend_module
from gpja.render.nvdiffrast_backend import front_facing, render_views_nvdiffrast, screen_to_clip


def test_auto_falls_back_to_cpu_without_cuda():
    if importlib.util.find_spec("nvdiffrast") is not None and torch.cuda.is_available():
        pytest.skip("a GPU with nvdiffrast is present")
    assert resolve_backend("auto") == "cpu"
    assert renderer("auto") is render_views
    assert renderer("cpu") is render_views


def test_requesting_missing_nvdiffrast_fails_clearly():
    if importlib.util.find_spec("nvdiffrast") is not None and torch.cuda.is_available():
        pytest.skip("a GPU with nvdiffrast is present")
    with pytest.raises(InputError, match="render.backend: 'nvdiffrast' is not installed or no CUDA device"):
        resolve_backend("nvdiffrast")
    with pytest.raises(InputError, match="render.backend: must be one of auto, cpu, nvdiffrast"):
        resolve_backend("opengl")
    with pytest.raises(InputError, match="nvdiffrast"):
        renderer("nvdiffrast")


@pytest.mark.parametrize("found, cuda, auto", [(False, False, "cpu"), (False, True, "cpu"), (True, False, "cpu"),
                                               (True, True, "nvdiffrast")])
def test_auto_needs_both_nvdiffrast_and_cuda(monkeypatch, found, cuda, auto):
    monkeypatch.setattr(backend_module.importlib.util, "find_spec", lambda name: object() if found else None)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: cuda)
    assert resolve_backend("auto") == auto
    assert resolve_backend("cpu") == "cpu"
    assert renderer("cpu") is render_views
    assert renderer("auto") is (render_views_nvdiffrast if auto == "nvdiffrast" else render_views)
    if auto == "cpu":
        with pytest.raises(InputError, match="nvdiffrast"):
            resolve_backend("nvdiffrast")
    else:
        assert resolve_backend("nvdiffrast") == "nvdiffrast"
    assert set(BACKENDS) == {"auto", "cpu", "nvdiffrast"}


def test_front_facing_matches_the_cpu_rasteriser():
    """The nvdiffrast backend's culling uses the CPU rasteriser's orientation convention."""
    from gpja.render import project_to_screen, rasterize_fragments
    from tests.render.scenes import ring_cameras, sphere

    V, F = sphere(subdivisions=2)
    cams = ring_cameras(2, 32)
    screen = project_to_screen(torch.tensor(V, dtype=torch.float32), cams)
    frags = rasterize_fragments(screen, torch.tensor(F), 32, 32)
    assert torch.equal(front_facing(screen, torch.tensor(F)), torch.from_numpy(frags.facing))


def test_screen_to_clip_maps_pixel_centres_and_depth():
    # pixel (0, 0) centre -> NDC (-1 + 1/W, 1 - 1/H); w carries the camera depth
    screen = torch.tensor([[[0.0, 0.0, 500.0], [99.0, 49.0, 500.0]]], dtype=torch.float64)
    clip = screen_to_clip(screen, 100, 50)
    ndc = clip[..., :3] / clip[..., 3:]
    torch.testing.assert_close(ndc[0, 0, :2], torch.tensor([-1 + 1 / 100, 1 - 1 / 50], dtype=torch.float64))
    torch.testing.assert_close(ndc[0, 1, :2], torch.tensor([1 - 1 / 100, -1 + 1 / 50], dtype=torch.float64))
    assert torch.all(ndc[..., 2].abs() < 1)
    torch.testing.assert_close(clip[..., 3], screen[..., 2])
