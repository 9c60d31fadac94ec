"""gpja.report.figures: cameras, renders, composites and the loss curves the figures are drawn from.

The figures themselves are drawn end to end by the CI workflow test (tests/test_project.py).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from gpja.errors import InputError
from gpja.mesh import TexturedMesh
from gpja.report import figures as FG
from tests.tolerances import FIGURE_CENTRE_PX, INTERPOLATED_CONSTANT


def quad(z: float = 0.0, half: float = 50.0):
    """A square of side 2*half mm facing +Z (counter-clockwise seen from +Z), two triangles."""
    V = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], dtype=np.float64)
    F = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)
    return V, F


def test_frontal_camera_centres_and_frames_the_points():
    V, _ = quad(half=50.0)
    camera = FG.frontal_camera(V, size=200, margin=1.0)
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


def test_most_frontal_view_picks_the_camera_facing_the_face():
    V, _ = quad()
    K = np.array([[500.0, 0, 64], [0, 500.0, 64], [0, 0, 1]])
    side = FG.Camera.look_at([600.0, 0, 100.0], [0, 0, 0], [0, 1, 0], K, 128, 128, name="side")
    front = FG.Camera.look_at([0.0, 0, 600.0], [0, 0, 0], [0, 1, 0], K, 128, 128, name="front")
    assert FG.most_frontal_view([side, front]) == 1
    assert FG.most_frontal_view([front, side]) == 0


def test_render_surface_interpolates_vertex_values_and_shades_facing_surfaces():
    V, F = quad(half=40.0)
    camera = FG.frontal_camera(V * 1.5, size=64)
    r = FG.render_surface(V, F, camera, vertex_values=np.full(4, 0.7))
    assert 0.2 < r.coverage.mean() < 0.6
    np.testing.assert_allclose(r.values[r.coverage, 0], 0.7, atol=INTERPOLATED_CONSTANT)
    assert np.all(r.values[~r.coverage] == 0)
    # a headlight on a surface facing the camera: nearly full brightness
    assert r.shade[r.coverage].min() > 0.95
    # a linear ramp comes back linear: x = -40 .. 40 mm mapped to 0 .. 1 increases left to right
    ramp = FG.render_surface(V, F, camera, vertex_values=(V[:, 0] + 40.0) / 80.0)
    row = ramp.values[32, :, 0][ramp.coverage[32]]
    assert np.all(np.diff(row) > 0)


def test_checkerboard_alternates_and_is_the_identity_on_equal_images():
    a = np.zeros((20, 20, 3))
    b = np.ones((20, 20, 3))
    board = FG.checkerboard(a, b, squares=5)  # 4-px squares; the render (b) in even squares
    assert board[0, 0, 0] == 1 and board[0, 4, 0] == 0 and board[4, 4, 0] == 1 and board[4, 0, 0] == 0
    assert board.mean() == pytest.approx(0.5, abs=0.05)
    np.testing.assert_array_equal(FG.checkerboard(a, a), a)


def test_loss_curves_spread_rotating_constraints_over_their_levels():
    log = {"levels": [{"iterations": 6, "losses": {"color": [3, 2], "depth": [5, 4], "normal": [1, 1]}},
                      {"iterations": 9, "losses": {"color": [2, 1, 1], "depth": [4, 3, 2], "normal": [1, 0.5, 0.5]}}]}
    curves, starts = FG.loss_curves(log)
    assert starts == [0, 6]
    x, y = curves["depth"]
    np.testing.assert_allclose(x, [1.5, 4.5, 7.5, 10.5, 13.5])
    np.testing.assert_array_equal(y, [5, 4, 4, 3, 2])
    assert all(np.all(np.diff(c[0]) > 0) for c in curves.values())


def test_mouth_centre_is_the_mean_of_the_socket_vertices():
    V, F = quad()
    # UVs: the first triangle in the left half of the atlas, the second in the right half
    UV = np.array([[0.1, 0.1], [0.4, 0.1], [0.4, 0.4], [0.6, 0.1], [0.9, 0.9], [0.6, 0.9]])
    F_uv = np.array([[0, 1, 2], [3, 4, 5]])
    mesh = TexturedMesh(V, F, UV, F_uv)
    mask = np.ones((32, 32), np.float32)
    mask[:, 16:] = 0.0  # the right half of the atlas is the socket: the second triangle
    np.testing.assert_allclose(FG.mouth_centre(mesh, mask), V[[0, 2, 3]].mean(axis=0))
    with pytest.raises(InputError, match="no mouth socket"):
        FG.mouth_centre(mesh, np.ones((32, 32), np.float32))


def test_scan_errors_must_match_the_scan(tmp_path):
    files = FG.RunFiles(results=tmp_path)
    details = files.details("S01", "gpja", "1_neutral")
    details.mkdir(parents=True)
    np.savez(details / "geometry_errors.npz", scan_vertex_error_mm=np.zeros(5))
    assert FG.scan_errors(files, "S01", "gpja", "1_neutral", 5).shape == (5,)
    with pytest.raises(InputError, match="geometry_errors.npz.*re-run the metrics"):
        FG.scan_errors(files, "S01", "gpja", "1_neutral", 6)


def test_bad_requests_name_the_problem(tmp_path):
    files = FG.RunFiles(results=tmp_path)
    settings = FG.FigureSettings()
    with pytest.raises(InputError, match=r"\.png"):
        FG.make_figure("convergence", files, "S01", ["gpja"], ["1_neutral"], settings, tmp_path / "x.jpg")
    with pytest.raises(InputError, match="unknown figure"):
        FG.make_figure("nope", files, "S01", ["gpja"], ["1_neutral"], settings, tmp_path / "x.png")
    with pytest.raises(InputError, match="not found|missing"):  # no registration logs
        FG.make_figure("convergence", files, "S01", ["gpja"], ["1_neutral"], settings, tmp_path / "x.png")
    with pytest.raises(InputError, match="unknown figure settings"):
        FG.FigureSettings.from_config({"colour": "red"})
    assert not (tmp_path / "x.png").exists()


def test_convergence_figure_writes_png_and_pdf(tmp_path):
    """Regression case: a figure from a tiny log, both files written, nothing left behind on failure."""
    log = {"levels": [{"iterations": 6, "losses": {"color": [0.3, 0.2], "depth": [5, 4], "normal": [0.4, 0.3]}}]}
    (tmp_path / "S01" / "gpja").mkdir(parents=True)
    (tmp_path / "S01" / "gpja" / "1_neutral.json").write_text(json.dumps(log))
    png, pdf = FG.make_figure("convergence", FG.RunFiles(results=tmp_path), "S01", ["gpja"], ["1_neutral"],
                              FG.FigureSettings(), tmp_path / "fig" / "convergence_S01.png")
    assert png.read_bytes()[:4] == b"\x89PNG" and pdf.read_bytes()[:4] == b"%PDF"
    assert sorted(p.name for p in (tmp_path / "fig").iterdir()) == ["convergence_S01.pdf", "convergence_S01.png"]


def test_a_figure_that_fails_to_save_leaves_no_file(tmp_path, monkeypatch):
    import matplotlib.figure

    fig, _ = FG.new_grid(1, 1)
    real = matplotlib.figure.Figure.savefig

    def fail_on_pdf(self, fname, *args, format=None, **kwargs):
        if format == "pdf":
            raise OSError("disk full")
        return real(self, fname, *args, format=format, **kwargs)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", fail_on_pdf)
    with pytest.raises(OSError, match="disk full"):
        FG.save_figure(fig, tmp_path / "f.png")
    assert list(tmp_path.iterdir()) == []
