import numpy as np
import pytest

from gpja.register.texture_fill import fill_texture, nearest_chart, push_pull, sample_bilinear
from tests.tolerances import FILL_EXACT, FILL_LINEAR_RAMP, FILL_SEAM_AGREEMENT, REMAP_POSITION_PX


def test_push_pull_keeps_known_texels_and_fills_a_constant_exactly():
    rng = np.random.default_rng(0)
    values = np.full((37, 50, 3), 0.25, np.float32)
    weights = (rng.random((37, 50)) < 0.2).astype(np.float32)
    filled = push_pull(np.where(weights[..., None] > 0, values, 9.0), weights)
    np.testing.assert_allclose(filled, 0.25, atol=FILL_EXACT)
    full = rng.random((16, 16, 3)).astype(np.float32)
    assert np.array_equal(push_pull(full, np.ones((16, 16), np.float32)), full)


def test_push_pull_interpolates_a_ramp_across_a_hole():
    x = np.linspace(0.0, 1.0, 64, dtype=np.float32)
    values = np.repeat(np.repeat(x[None, :, None], 64, 0), 3, 2)
    weights = np.ones((64, 64), np.float32)
    weights[20:44, 20:44] = 0.0
    filled = push_pull(np.where(weights[..., None] > 0, values, 0.0), weights)
    hole = weights == 0
    assert np.abs(filled[hole] - values[hole]).max() < FILL_LINEAR_RAMP
    assert filled[hole].min() >= x[19] - FILL_LINEAR_RAMP and filled[hole].max() <= x[44] + FILL_LINEAR_RAMP


def two_charts(size=32):
    """Chart 0 on the left half (cols 1..13), chart 1 on the right (cols 18..30), gutters elsewhere."""
    chart = np.full((size, size), -1, np.int64)
    chart[1:-1, 1:14] = 0
    chart[1:-1, 18:-1] = 1
    return chart


def test_fill_stays_inside_each_chart_and_dilates_into_the_gutter():
    chart = two_charts()
    values = np.zeros((32, 32, 3), np.float32)
    values[chart == 0] = (1.0, 0.0, 0.0)
    values[chart == 1] = (0.0, 0.0, 1.0)
    weights = (chart >= 0).astype(np.float32)
    weights[1:-1, 8:14] = 0.0  # chart 0's right part, next to chart 1 in the atlas: unobserved
    out = fill_texture(values * weights[..., None], weights, chart)
    assert np.abs(out[chart == 0] - [1.0, 0.0, 0.0]).max() < FILL_EXACT  # no blue came across
    assert np.abs(out[chart == 1] - [0.0, 0.0, 1.0]).max() < FILL_EXACT
    owner = nearest_chart(chart)
    assert np.abs(out[(chart < 0) & (owner == 0)] - [1.0, 0.0, 0.0]).max() < FILL_EXACT
    assert np.abs(out[(chart < 0) & (owner == 1)] - [0.0, 0.0, 1.0]).max() < FILL_EXACT


def test_seams_agree_when_one_side_is_unobserved():
    # chart 0's right edge (col 13) and chart 1's left edge (col 18) are one seam; chart 1 is unobserved
    chart = two_charts()
    rows = np.arange(1, 31, dtype=np.float64)
    seam_xy = np.stack([np.stack([np.full(30, 13.0), rows], 1), np.stack([np.full(30, 18.0), rows], 1)], axis=1)
    seam_charts = np.tile([0, 1], (30, 1))
    values = np.zeros((32, 32, 3), np.float32)
    values[1:-1, 1:14] = (rows / 31.0)[:, None, None]  # a vertical ramp in chart 0
    weights = (chart == 0).astype(np.float32)
    out = fill_texture(values, weights, chart, seam_xy, seam_charts)
    a = sample_bilinear(out, seam_xy[:, 0])
    b = sample_bilinear(out, seam_xy[:, 1])
    assert np.abs(a - b).max() < FILL_SEAM_AGREEMENT
    # without the seam pass chart 1 gets one flat colour, which disagrees along the seam
    flat = fill_texture(values, weights, chart)
    assert np.abs(sample_bilinear(flat, seam_xy[:, 0]) - sample_bilinear(flat, seam_xy[:, 1])).max() > 0.2


def test_sample_bilinear_reproduces_a_linear_image():
    y, x = np.mgrid[0:20, 0:30].astype(np.float32)
    image = np.stack([x, y, x + 2 * y], axis=-1)
    pts = np.array([[0.0, 0.0], [3.25, 7.5], [28.9, 18.1]])
    expected = np.stack([pts[:, 0], pts[:, 1], pts[:, 0] + 2 * pts[:, 1]], 1)
    # OpenCV's remap rounds sample positions to 1/32 pixel: errors up to that times the gradient (3 here)
    np.testing.assert_allclose(sample_bilinear(image, pts), expected, atol=3 * REMAP_POSITION_PX)
    assert sample_bilinear(image[..., 0], pts).shape == (3, 1)


def test_fill_needs_some_observation():
    with pytest.raises(ValueError):
        fill_texture(np.zeros((8, 8, 3), np.float32), np.zeros((8, 8), np.float32), np.zeros((8, 8), np.int64))
