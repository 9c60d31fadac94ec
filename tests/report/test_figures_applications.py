"""gpja.report.figures_applications: the turns figure, drawn from turns.json and the artist mesh."""
from __future__ import annotations

import matplotlib
import numpy as np
import pytest
import trimesh

from gpja.errors import InputError
from gpja.io import write_json
from gpja.mesh import TexturedMesh, write_obj
from gpja.report.figures import FigureRequest, FigureSettings, RunFiles, make_figure
from gpja.report.figures_applications import draw_turns
from gpja.results import Layout

matplotlib.use("Agg")


def write_run(tmp_path, hops):
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=80.0)
    layout = Layout(tmp_path)
    write_obj(layout.artist_mesh("S01"), TexturedMesh(np.asarray(sphere.vertices), np.asarray(sphere.faces)))
    write_json(layout.reparam_turns("S01"), {"subject": "S01", "faces": len(sphere.faces), "hops": hops})
    return FigureRequest(RunFiles(layout), "S01", ("gpja",), ("1_neutral",), FigureSettings(render_size=64))


def test_turns_figure_marks_each_hops_faces(tmp_path):
    hops = [{"parent": "a", "expression": "b", "turned": 3, "turned_observed": 1, "turned_faces": [0, 5, 9],
             "truth_turned": 1, "truth_turned_observed": 1, "both": 1, "near_truth": 0, "truth_turned_faces": [5]},
            {"parent": "b", "expression": "c", "turned": 0, "turned_observed": 0, "turned_faces": []}]
    request = write_run(tmp_path, hops)
    fig = draw_turns(request)
    panels = [ax for ax in fig.axes if ax.images]
    assert len(panels) == 2
    marks = [[len(c.get_offsets()) for c in ax.collections] for ax in panels]
    assert marks == [[1, 3], [0]]  # the truth's rings, then GPJA's dots; no truth on the second hop
    assert "true motion 1; both 1, near 0" in panels[0].get_title() and "true motion" not in panels[1].get_title()
    png, pdf = make_figure("turns", request, tmp_path / "fig" / "turns_S01.png")
    assert png.read_bytes()[:4] == b"\x89PNG" and pdf.read_bytes()[:4] == b"%PDF"


def test_turns_figure_names_a_bad_file(tmp_path):
    request = write_run(tmp_path, [{"parent": "a", "expression": "b", "turned": 1, "turned_observed": 0,
                                    "turned_faces": [10 ** 6]}])
    with pytest.raises(InputError, match="turns.json: turned_faces of a -> b index faces"):
        draw_turns(request)
    request = write_run(tmp_path, [])
    with pytest.raises(InputError, match="no hop to draw"):
        draw_turns(request)
