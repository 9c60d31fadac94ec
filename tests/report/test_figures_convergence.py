"""gpja.report.figures_convergence: loss curves from a registration log, and the figure drawn from them."""
from __future__ import annotations

import json

import numpy as np

from gpja.report.figures import FigureRequest, RunFiles, make_figure
from gpja.report.figures_convergence import loss_curves
from gpja.results import Layout


def test_loss_curves_spread_rotating_constraints_over_their_levels():
    log = {"levels": [{"iterations": 6, "losses": {"color": [3, 2], "depth": [5, 4], "normal": [1, 1]}},
                      {"iterations": 9, "losses": {"color": [2, 1, 1], "depth": [4, 3, 2], "normal": [1, 0.5, 0.5]}}]}
    curves, starts = loss_curves(log)
    assert starts == [0, 6]
    x, y = curves["depth"]
    np.testing.assert_allclose(x, [1.5, 4.5, 7.5, 10.5, 13.5])
    np.testing.assert_array_equal(y, [5, 4, 4, 3, 2])
    assert all(np.all(np.diff(c[0]) > 0) for c in curves.values())


def test_flow_stages_take_no_iterations_on_the_curves():
    log = {"levels": [{"stage": "flow", "rounds": [{}], "seconds": 1.0},
                      {"stage": "level", "iterations": 4, "losses": {"color": [3, 2]}},
                      {"stage": "flow2", "rounds": [{}], "seconds": 1.0},
                      {"stage": "level", "iterations": 2, "losses": {"color": [1]}}]}
    curves, starts = loss_curves(log)
    assert starts == [0, 4]
    np.testing.assert_allclose(curves["color"][0], [1.0, 3.0, 5.0])


def test_convergence_figure_writes_png_and_pdf(tmp_path):
    """Regression case: a figure from a tiny log, both files written, nothing else."""
    log = {"levels": [{"iterations": 6, "losses": {"color": [0.3, 0.2], "depth": [5, 4], "normal": [0.4, 0.3]}}]}
    layout = Layout(tmp_path)
    path = layout.registration_log("S01", "gpja", "1_neutral")
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(log))
    request = FigureRequest(RunFiles(layout), "S01", ("gpja",), ("1_neutral",))
    png, pdf = make_figure("convergence", request, tmp_path / "fig" / "convergence_S01.png")
    assert png.read_bytes()[:4] == b"\x89PNG" and pdf.read_bytes()[:4] == b"%PDF"
    assert sorted(p.name for p in (tmp_path / "fig").iterdir()) == ["convergence_S01.pdf", "convergence_S01.png"]
