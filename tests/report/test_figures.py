"""gpja.report.figures: the figure registry, the per-configuration plan the rules are built from, and the
one path every figure is drawn and written by (``gpja figure`` -> :func:`make_figure`).

The built-in figures are drawn end to end by the CI workflow test (tests/test_project.py).
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gpja.cli import main
from gpja.errors import InputError
from gpja.report.drawing import new_grid
from gpja.report.figures import (
    COMPARED,
    FIGURES,
    FigurePlan,
    FigureRequest,
    FigureSettings,
    RunFiles,
    make_figure,
    register_figure,
    unregister_figure,
)
from gpja.results import Layout

ROOT = Path(__file__).resolve().parents[2]
E1, E2 = "1_neutral", "12_lip_puckerer"


def plan(**kwargs) -> FigurePlan:
    base = dict(layout=Layout("results/x"), expressions=(E1, E2), compared=("gpja", "nicp"),
                ablation_variants=("gpja-no_normal", "gpja-no_mask"), ablation_subjects=("S01",),
                ablation_expressions=(E2,), photometric=True)
    return FigurePlan(**{**base, **kwargs})


def test_a_toy_figure_registered_through_the_registry_is_drawn_by_gpja_figure(tmp_path):
    seen = []

    @register_figure("toy", methods=COMPARED, needs=("template",))
    def draw(request: FigureRequest):
        seen.append(request)
        fig, axes = new_grid(1, 1)
        axes[0][0].imshow(np.zeros((4, 4, 3)))
        return fig

    try:
        assert FIGURES["toy"].function() is draw and FIGURES["toy"].caption == "figure_toy.rst"
        with pytest.raises(ValueError, match="already registered"):
            register_figure("toy")(draw)
        out = tmp_path / "figures" / "toy_S01.png"
        argv = ["figure", "toy", "--subject", "S01", "--methods", "gpja", "nicp", "--expressions", E1, E2,
                "--results", str(tmp_path / "results"), "--scans-root", str(tmp_path / "scans"),
                "--settings", '{"render_size": 64}', "--backend", "cpu", "--output", str(out)]
        assert main(argv) == 0
        assert out.read_bytes()[:4] == b"\x89PNG" and out.with_suffix(".pdf").read_bytes()[:4] == b"%PDF"
        (request,) = seen
        assert (request.subject, request.methods, request.expressions) == ("S01", ("gpja", "nicp"), (E1, E2))
        assert request.settings == FigureSettings(render_size=64) and request.backend == "cpu"
        assert request.files.layout == Layout(tmp_path / "results")
        assert request.files.data.scans_root == tmp_path / "scans"
        # the rules get it too: drawn for every subject, its inputs are what it needs
        p = plan()
        assert "toy" in p.figures("S02") and p.methods(FIGURES["toy"]) == ["gpja", "nicp"]
        assert p.inputs(FIGURES["toy"], "S02") == ["results/x/S02/template/template.obj",
                                                   "results/x/S02/template/texture.png"]
    finally:
        unregister_figure("toy")
    assert "toy" not in FIGURES
    with pytest.raises(SystemExit):  # no longer a choice of `gpja figure`
        main(argv)


def test_plan_draws_each_figure_when_the_config_produces_what_it_shows():
    p = plan()
    everything = ["template_stages", "geometric_errors", "convergence", "photometric_errors", "closeups",
                  "ablation_normal", "ablation_mask"]
    assert p.figures("S01") == everything
    assert p.figures("S02") == everything[:5]  # not an ablation subject
    assert plan(photometric=False).figures("S01") == ["template_stages", "geometric_errors", "convergence",
                                                      "ablation_normal"]
    assert plan(ablation_variants=("gpja-no_mask",)).figures("S01") == everything[:5] + ["ablation_mask"]
    assert plan(ablation_expressions=("5_jaw_left",)).figures("S01") == everything[:5]  # not run
    assert plan(ablation_variants=()).figures("S01") == everything[:5]
    assert p.outputs("S02")[:2] == ["results/x/figures/template_stages_S02.png",
                                    "results/x/figures/template_stages_S02.pdf"]


def test_plan_lists_each_figures_methods_expressions_and_inputs():
    p = plan()
    template = ["results/x/S01/template/template.obj", "results/x/S01/template/texture.png"]
    assert p.inputs(FIGURES["template_stages"], "S01") == template
    assert p.inputs(FIGURES["convergence"], "S01") == template + [f"results/x/S01/gpja/{e}.json" for e in (E1, E2)]
    assert p.inputs(FIGURES["geometric_errors"], "S01") == template + [
        f"results/x/S01/{m}/metrics/{e}.json" for m in ("gpja", "nicp") for e in (E1, E2)]
    ablation = FIGURES["ablation_mask"]
    assert p.methods(ablation) == ["gpja", "gpja-no_mask"] and p.expressions_of(ablation) == [E2]
    assert p.inputs(ablation, "S01") == template + [f"results/x/S01/{m}/metrics/{E2}.json"
                                                    for m in ("gpja", "gpja-no_mask")]


def test_every_figure_has_a_draw_function():
    """(Their captions: tests/test_project.py.)"""
    for name, entry in FIGURES.items():
        assert callable(entry.function()), name


def test_the_registry_imports_neither_matplotlib_nor_torch():
    """The Snakefile imports it while it parses."""
    code = ("import sys, gpja.report.figures; "
            "sys.exit(sorted({'matplotlib', 'torch'} & set(sys.modules)) != [])")
    assert subprocess.run([sys.executable, "-c", code], cwd=ROOT).returncode == 0


def test_bad_requests_name_the_problem(tmp_path):
    request = FigureRequest(RunFiles(Layout(tmp_path)), "S01", ("gpja",), (E1,))
    with pytest.raises(InputError, match=r"\.png"):
        make_figure("convergence", request, tmp_path / "x.jpg")
    with pytest.raises(InputError, match="unknown figure 'nope'"):
        make_figure("nope", request, tmp_path / "x.png")
    with pytest.raises(InputError, match="--expressions"):
        make_figure("convergence", FigureRequest(RunFiles(Layout(tmp_path)), "S01"), tmp_path / "x.png")
    with pytest.raises(InputError, match="not found|missing"):  # no registration logs
        make_figure("convergence", request, tmp_path / "x.png")
    with pytest.raises(InputError, match="--scans-root"):  # no scans given
        make_figure("geometric_errors", request, tmp_path / "x.png")
    with pytest.raises(InputError, match="colour"):
        FigureSettings.from_config({"colour": "red"}, "figures")
    with pytest.raises(ValueError, match="unknown needs"):
        register_figure("bad", needs=("scans",))(lambda request: None)
    assert "bad" not in FIGURES
    assert not (tmp_path / "x.png").exists()
