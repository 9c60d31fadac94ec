"""gpja.report.drawing: the frontal camera, one-view renders, crops and the atomic PNG + PDF output."""
from __future__ import annotations

import numpy as np
import pytest

from gpja.camera import Camera
from gpja.report import drawing as D
from tests.tolerances import FIGURE_CENTRE_PX, INTERPOLATED_CONSTANT


def quad(z: float = 0.0, half: float = 50.0):
    """A square of side 2*half mm facing +Z (counter-clockwise seen from +Z), two triangles."""
    V = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], dtype=np.float64)
    F = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    return V, F


def test_frontal_camera_centres_and_frames_the_points():
    V, _ = quad(half=50.0)
    camera = D.frontal_camera(V, size=200, margin=1.0)
    px, depth = camera.project(V)
    assert np.all(depth > 0)
    centre = camera.project(V.mean(axis=0, keepdims=True))[0][0]
    np.testing.assert_allclose(centre, [99.5, 99.5], atol=FIGURE_CENTRE_PX)
    # the square spans the image (percentile framing of 4 corners is the full extent), up is up
    assert px[:, 0].min() == pytest.approx(-0.5, abs=1.0) and px[:, 0].max() == pytest.approx(199.5, abs=1.0)
    top, bottom = camera.project(np.array([[0.0, 40.0, 0.0], [0.0, -40.0, 0.0]]))[0][:, 1]
    assert top < bottom
    left, right = camera.project(np.array([[-40.0, 0.0, 0.0], [40.0, 0.0, 0.0]]))[0][:, 0]
    assert left < right  # +X (the subject's left) on the image's right, as seen from the front


def test_render_surface_interpolates_vertex_values_and_shades_facing_surfaces():
    V, F = quad(half=40.0)
    camera = D.frontal_camera(V * 1.5, size=64)
    r = D.render_surface(V, F, camera, vertex_values=np.full(4, 0.7))
    assert 0.2 < r.coverage.mean() < 0.6
    np.testing.assert_allclose(r.values[r.coverage, 0], 0.7, atol=INTERPOLATED_CONSTANT)
    assert np.all(r.values[~r.coverage] == 0)
    # a headlight on a surface facing the camera: nearly full brightness
    assert r.shade[r.coverage].min() > 0.95
    # a linear ramp comes back linear: x = -40 .. 40 mm mapped to 0 .. 1 increases left to right
    ramp = D.render_surface(V, F, camera, vertex_values=(V[:, 0] + 40.0) / 80.0)
    row = ramp.values[32, :, 0][ramp.coverage[32]]
    assert np.all(np.diff(row) > 0)


def test_render_surface_uses_the_given_backend_render_except_for_vertex_values():
    from gpja.render import render_views

    V, F = quad(half=40.0)
    camera = D.frontal_camera(V * 1.5, size=32)
    calls = []

    def spy(*args, **kwargs):
        calls.append(args[3])
        return render_views(*args, **kwargs)

    shaded = D.render_surface(V, F, camera, render=spy)
    assert calls == [("normal",)]
    np.testing.assert_array_equal(shaded.shade, D.render_surface(V, F, camera).shade)
    D.render_surface(V, F, camera, vertex_values=np.zeros(4), render=spy)  # values need the CPU fragments
    assert len(calls) == 1


def test_crop_to_coverage_keeps_the_covered_box_and_a_margin():
    coverage = np.zeros((20, 30), bool)
    coverage[5:8, 10:15] = True
    image = np.arange(20 * 30).reshape(20, 30)
    (crop,) = D.crop_to_coverage([image], coverage, margin=2)
    np.testing.assert_array_equal(crop, image[3:10, 8:17])
    assert D.crop_to_coverage([image], np.zeros_like(coverage))[0] is image


def test_a_figure_that_fails_to_save_leaves_no_file(tmp_path, monkeypatch):
    import matplotlib.figure

    fig, _ = D.new_grid(1, 1)
    real = matplotlib.figure.Figure.savefig

    def fail_on_pdf(self, fname, *args, format=None, **kwargs):
        if format == "pdf":
            raise OSError("disk full")
        return real(self, fname, *args, format=format, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", fail_on_pdf)
    with pytest.raises(OSError, match="disk full"):
        D.save_figure(fig, tmp_path / "f.png")
    assert list(tmp_path.iterdir()) == []
