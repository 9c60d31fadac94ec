import numpy as np
import pytest
import torch

from gpja.camera import Camera
from gpja.render.project import project_to_screen, project_to_screen_torch
from tests.render.scenes import ring_cameras
from tests.tolerances import EXACT_F64


def test_analytic_pinhole_with_skew():
    K = np.array([[1000.0, 3.0, 255.5], [0, 900.0, 250.0], [0, 0, 1]])
    cam = Camera.look_at((0, 0, 600), (0, 0, 0), (0, 1, 0), K, 512, 512, name="0")
    V = torch.tensor([[0.0, 0, 0], [0, 60, 0], [30, 0, 100]], dtype=torch.float64)
    screen = project_to_screen(V, [cam])
    # camera looks down -Z at the origin: x_cam = X, y_cam = -Y, z_cam = 600 - Z
    expected = [[255.5, 250.0, 600.0], [255.5 + 3.0 * -0.1, 250.0 - 90.0, 600.0], [255.5 + 1000.0 * 0.06, 250.0, 500.0]]
    np.testing.assert_allclose(screen[0].numpy(), expected, atol=EXACT_F64)


def test_matches_the_torch_expression_and_its_gradient():
    torch.manual_seed(0)
    V = (torch.randn(200, 3, dtype=torch.float64) * 40).requires_grad_(True)
    cams = ring_cameras(3, 64)
    grad = torch.randn(3, 200, 3, dtype=torch.float64)
    fused = project_to_screen(V, cams)
    (g_fused,) = torch.autograd.grad(fused, V, grad)
    plain = project_to_screen_torch(V, cams)
    (g_plain,) = torch.autograd.grad(plain, V, grad)
    torch.testing.assert_close(fused, plain, rtol=0, atol=EXACT_F64)
    torch.testing.assert_close(g_fused, g_plain, rtol=1e-12, atol=EXACT_F64)


def test_gradcheck_float64():
    torch.manual_seed(1)
    V = (torch.randn(12, 3, dtype=torch.float64) * 40).requires_grad_(True)
    cams = ring_cameras(2, 32)
    assert torch.autograd.gradcheck(lambda v: project_to_screen(v, cams), (V,))


def test_float32_is_computed_in_float64_and_rounded_once():
    torch.manual_seed(2)
    V = torch.randn(500, 3) * 60
    cams = ring_cameras(4, 512)
    reference = project_to_screen_torch(V.double(), cams)
    fused = project_to_screen(V, cams)
    assert fused.dtype == torch.float32
    # one rounding: within half a float32 ulp of the float64 value (torch's float32 chain errs by more)
    half_ulp = 0.5 * np.spacing(np.abs(reference.numpy()).astype(np.float32)).astype(np.float64)
    assert np.all(np.abs(fused.double().numpy() - reference.numpy()) <= half_ulp)


def test_distorted_camera_is_refused():
    cam = ring_cameras(1, 32)[0]
    distorted = Camera(cam.K, cam.Rt, np.array([0.1, 0, 0, 0, 0]), cam.width, cam.height, name="d")
    with pytest.raises(ValueError, match="distortion"):
        project_to_screen(torch.zeros(3, 3), [distorted])
