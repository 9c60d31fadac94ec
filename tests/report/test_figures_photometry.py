"""gpja.report.figures_photometry: the checkerboard composite and the mouth centre the close-ups are framed on."""
from __future__ import annotations

import numpy as np
import pytest

from gpja.errors import InputError
from gpja.mesh import TexturedMesh
from gpja.report import figures_photometry as FP
from tests.report.test_drawing import quad


def test_checkerboard_alternates_and_is_the_identity_on_equal_images():
    a = np.zeros((20, 20, 3))
    b = np.ones((20, 20, 3))
    board = FP.checkerboard(a, b, squares=5)  # 4-px squares; the render (b) in even squares
    assert board[0, 0, 0] == 1 and board[0, 4, 0] == 0 and board[4, 4, 0] == 1 and board[4, 0, 0] == 0
    assert board.mean() == pytest.approx(0.5, abs=0.05)
    np.testing.assert_array_equal(FP.checkerboard(a, a), a)


def test_mouth_centre_is_the_mean_of_the_socket_vertices():
    V, F = quad()
    # UVs: the first triangle in the left half of the atlas, the second in the right half
    UV = np.array([[0.1, 0.1], [0.4, 0.1], [0.4, 0.4], [0.6, 0.1], [0.9, 0.9], [0.6, 0.9]])
    F_uv = np.array([[0, 1, 2], [3, 4, 5]])
    mesh = TexturedMesh(V, F, UV, F_uv)
    mask = np.ones((32, 32), np.float32)
    mask[:, 16:] = 0.0  # the right half of the atlas is the socket: the second triangle
    np.testing.assert_allclose(FP.mouth_centre(mesh, mask), V[[0, 2, 3]].mean(axis=0))
    with pytest.raises(InputError, match="no mouth socket"):
        FP.mouth_centre(mesh, np.ones((32, 32), np.float32))


def test_view_entry_names_the_metrics_file_when_the_view_was_not_scored(tmp_path):
    record = {"photometric": {"per_view": [{"view": 3, "psnr": 20.0}]}}
    assert FP.view_entry(record, "3", tmp_path / "m.json")["psnr"] == 20.0
    with pytest.raises(InputError, match=r"m\.json.*view '4'"):
        FP.view_entry(record, "4", tmp_path / "m.json")
