"""gpja.report.figures_correspondence: the template coloured by per-vertex correspondence error, per method."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh

from gpja.errors import InputError
from gpja.io import read_image, write_npz
from gpja.mesh import TexturedMesh, write_obj
from gpja.report.drawing import frontal_camera
from gpja.report.figures import FIGURES, FigurePlan, FigureRequest, FigureSettings, RunFiles, make_figure
from gpja.report.figures_correspondence import (
    UNSCORED_RGB,
    correspondence_vertex_errors,
    error_image,
    nice_ceiling,
)
from gpja.results import Layout
from tests.report import E1, E2, write_metrics

SUBJECT = "S01"


def sphere():
    s = trimesh.creation.icosphere(subdivisions=3, radius=80.0)
    return np.asarray(s.vertices), np.asarray(s.faces)


def write_run(results, V, F, methods=("gpja", "nicp")):
    """A template and, per method and expression, a metrics JSON and the per-vertex correspondence errors."""
    layout = Layout(results)
    write_obj(layout.template_file(SUBJECT, "template.obj"), TexturedMesh(V, F), texture_name=None)
    for j, method in enumerate(methods):
        for i, expression in enumerate((E1, E2)):
            write_metrics(results, SUBJECT, method, expression, cd=0.1, corr=(1.0, 1.0, 2.0))
            errors = np.abs(V[:, 1]) / 80.0 * (j + 1) + i  # grows away from the equator, larger for nicp
            errors[V[:, 2] < -40] = np.nan  # the back is not scored
            details = layout.metrics_details(SUBJECT, method, expression)
            write_npz(details / "correspondence_errors.npz", vertex_error_mm=errors, vertex_used=np.isfinite(errors))
    return layout


def test_nice_ceiling_rounds_up_to_1_2_5_steps():
    assert [nice_ceiling(v) for v in (0.7, 1.0, 1.3, 2.2, 4.9, 7.0, 12.0)] == [1.0, 1.0, 2.0, 5.0, 5.0, 10.0, 20.0]
    assert nice_ceiling(0.0) == 1.0 and nice_ceiling(float("nan")) == 1.0


def test_unscored_vertices_are_grey_and_errors_follow_the_colour_map():
    V, F = sphere()
    camera = frontal_camera(V, 64)
    image, coverage = error_image(V, F, np.full(len(V), np.nan), camera, 1.0)
    pixels = image[coverage]
    assert coverage.sum() > 1000
    np.testing.assert_allclose(pixels[:, 0] / pixels[:, 2], UNSCORED_RGB[0] / UNSCORED_RGB[2], atol=1e-6)
    low, _ = error_image(V, F, np.zeros(len(V)), camera, 1.0)
    high, _ = error_image(V, F, np.full(len(V), 5.0), camera, 1.0)
    # inferno: dark purple-black at 0, light yellow at the top (blue channel far below red)
    assert low[coverage].mean() < 0.05 and (high[coverage][:, 0] > high[coverage][:, 2]).all()


def test_the_figure_is_drawn_from_the_metrics_for_every_method_and_expression(tmp_path):
    V, F = sphere()
    layout = write_run(tmp_path, V, F)
    request = FigureRequest(RunFiles(layout), SUBJECT, ("gpja", "nicp"), (E1, E2), FigureSettings(render_size=64))
    png, pdf = make_figure("correspondence_errors", request, tmp_path / "figures" / "correspondence_errors_S01.png")
    assert read_image(png).shape[2] == 3 and pdf.read_bytes()[:4] == b"%PDF"
    # the registry: compared methods, synthetic data only
    entry = FIGURES["correspondence_errors"]
    plan = FigurePlan(Layout("results/x"), (E1, E2), ("gpja", "nicp"))
    assert "correspondence_errors" not in plan.figures(SUBJECT)
    truth = FigurePlan(Layout("results/x"), (E1, E2), ("gpja", "nicp"), ground_truth=True)
    assert "correspondence_errors" in truth.figures(SUBJECT) and truth.methods(entry) == ["gpja", "nicp"]
    assert truth.inputs(FIGURES["template_stages"], SUBJECT)[-2:] == [
        "results/x/S01/template/texture_quality.json", "results/x/S01/template/texture_error.png"]
    assert plan.inputs(FIGURES["template_stages"], SUBJECT) == truth.inputs(FIGURES["template_stages"], SUBJECT)[:2]


def test_errors_must_match_the_template(tmp_path):
    V, F = sphere()
    layout = write_run(tmp_path, V, F, methods=("gpja",))
    files = RunFiles(layout)
    assert correspondence_vertex_errors(files, SUBJECT, "gpja", E1, len(V)).shape == (len(V),)
    with pytest.raises(InputError, match="re-run the metrics step"):
        correspondence_vertex_errors(files, SUBJECT, "gpja", E1, len(V) + 1)
    with pytest.raises(InputError, match="correspondence_errors.npz: file not found"):
        correspondence_vertex_errors(files, SUBJECT, "nicp", E1, len(V))


def test_the_registry_names_the_files_the_texture_quality_step_writes():
    """(The registry imports no numpy, so it names them itself.)"""
    from gpja.metrics.texture_quality import ERROR_IMAGE_FILE, QUALITY_FILE
    from gpja.report.figures import TEXTURE_QUALITY_FILES

    assert TEXTURE_QUALITY_FILES == (QUALITY_FILE, ERROR_IMAGE_FILE)
