import numpy as np
import torch

from gpja.render import rasterize_fragments
from gpja.render.fragments import perspective_barycentrics
from tests.render.scenes import screen_triangles


def test_barycentrics_analytic_constant_depth():
    # right triangle (0,0) (8,0) (0,8) at one depth: barycentrics are the affine ones
    s = screen_triangles(np.array([[0.0, 0], [8, 0], [0, 8]]))
    frags = rasterize_fragments(s, torch.tensor([[0, 2, 1]]), 10, 10)
    x = (frags.pixel % 10).double()
    y = (frags.pixel // 10).double()
    expected = torch.stack([1 - x / 8 - y / 8, y / 8, x / 8], 1)  # corners in face order (0, 2, 1)
    torch.testing.assert_close(frags.bary, expected)
    torch.testing.assert_close(frags.z, torch.full_like(frags.z, 100.0))


def test_perspective_correct_depth_along_a_tilted_edge():
    # an edge from depth 100 to depth 300: the midpoint in screen space is at the harmonic mean depth
    scr = torch.tensor([[0.0, 0.0, 100.0], [10.0, 0.0, 300.0], [0.0, 10.0, 100.0]], dtype=torch.float64)
    bary, z = perspective_barycentrics(scr, torch.tensor([[0, 1, 2]]), torch.tensor([5.0], dtype=torch.float64),
                                       torch.tensor([0.0], dtype=torch.float64))
    torch.testing.assert_close(z, torch.tensor([150.0], dtype=torch.float64))  # 1 / (0.5/100 + 0.5/300)
    torch.testing.assert_close(bary, torch.tensor([[0.75, 0.25, 0.0]], dtype=torch.float64))


def test_gradcheck_barycentrics_float64():
    torch.manual_seed(0)
    scr = torch.rand(9, 3, dtype=torch.float64) * 20
    scr[:, 2] += 50
    scr.requires_grad_(True)
    # two chunks (as two views) whose fragments touch disjoint rows, as the renderer guarantees
    corners = torch.tensor([[0, 1, 2], [1, 2, 3], [4, 5, 6], [6, 7, 8]])
    px = torch.rand(4, dtype=torch.float64) * 20
    py = torch.rand(4, dtype=torch.float64) * 20
    assert torch.autograd.gradcheck(lambda s: perspective_barycentrics(s, corners, px, py, torch.tensor([0, 2, 4])), (scr,))
    # one chunk (the default) may share rows freely
    shared = torch.tensor([[0, 1, 2], [3, 4, 5], [6, 7, 8], [1, 5, 7]])
    assert torch.autograd.gradcheck(lambda s: perspective_barycentrics(s, shared, px, py), (scr,))


def test_regression_fragment_count():
    xy = np.array([[0.3, 0.2], [9.1, 1.7], [2.2, 8.9]])
    frags = rasterize_fragments(screen_triangles(xy), torch.tensor([[0, 2, 1]]), 10, 10)
    # no pixel centre lies on an edge here, so coverage is the plain point-in-triangle set
    from matplotlib.path import Path

    yy, xx = np.mgrid[0:10, 0:10]
    inside = Path(xy).contains_points(np.stack([xx.ravel(), yy.ravel()], 1))
    assert len(frags.pixel) == int(inside.sum()) == 35
    np.testing.assert_array_equal(frags.pixel.numpy(), np.flatnonzero(inside))
