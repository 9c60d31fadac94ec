import numpy as np
import torch

from gpja.render import interpolate_rows, rasterize_fragments, scatter_to_image
from gpja.render.interpolate import interpolate_attribute
from tests.render.scenes import screen_triangles


def test_interpolating_positions_reproduces_pixel_centres():
    xy = np.array([[0.0, 0], [9, 0], [0, 9]])
    s = screen_triangles(xy)
    faces = torch.tensor([[0, 2, 1]])
    frags = rasterize_fragments(s, faces, 10, 10)
    pos = interpolate_attribute(torch.tensor(xy), faces, frags)
    torch.testing.assert_close(pos[:, 0], (frags.pixel % 10).double())
    torch.testing.assert_close(pos[:, 1], (frags.pixel // 10).double())


def test_gradcheck_interpolate_float64():
    torch.manual_seed(1)
    attr = torch.rand(7, 4, dtype=torch.float64, requires_grad=True)
    bary = torch.rand(5, 3, dtype=torch.float64, requires_grad=True)
    index = torch.randint(0, 7, (5, 3))
    assert torch.autograd.gradcheck(lambda a, b: interpolate_rows(a, b, index), (attr, bary))


def test_separate_uv_index():
    # one triangle whose UV corners are rows 2, 0, 1 of the UV table
    s = screen_triangles(np.array([[0.0, 0], [9, 0], [0, 9]]))
    frags = rasterize_fragments(s, torch.tensor([[0, 2, 1]]), 10, 10)
    uv = torch.tensor([[0.0, 1.0], [1.0, 0.0], [0.0, 0.0]], dtype=torch.float64)
    out = interpolate_attribute(uv, torch.tensor([[2, 0, 1]]), frags)
    # corner 0 (uv row 2 = (0,0)) at pixel (0,0)
    assert torch.allclose(out[frags.pixel == 0], torch.tensor([[0.0, 0.0]], dtype=torch.float64))


def test_scatter_to_image_background_and_values():
    s = screen_triangles(np.array([[0.0, 0], [5, 0], [0, 5]]))
    frags = rasterize_fragments(s, torch.tensor([[0, 2, 1]]), 8, 8)
    img = scatter_to_image(torch.ones(len(frags.pixel), 2, dtype=torch.float64), frags, background=torch.tensor([0.5, 0.25]))
    assert img.shape == (1, 8, 8, 2)
    assert float(img[0, 7, 7, 0]) == 0.5 and float(img[0, 1, 1, 1]) == 1.0
