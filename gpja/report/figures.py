"""The one registry of figures: name -> draw function, what it draws, what it reads, when the workflow draws it.

A figure is one function with one signature, ``draw(request: FigureRequest) -> matplotlib.figure.Figure``,
and one :class:`Figure` entry in :data:`FIGURES` (or a :func:`register_figure` decorator). Its caption is
``workflow/report/figure_{name}.rst``. ``gpja figure <name>`` (:func:`make_figure`) draws it and writes the
PNG and the PDF; ``workflow/rules/figures.smk`` makes one rule per entry, with its inputs and the
per-subject list from :class:`FigurePlan`. Adding a figure is one draw function plus one entry plus its
caption.

This module is imported by the Snakefile while it parses: it imports neither matplotlib nor torch (nor
numpy); the draw functions are imported when a figure is drawn.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from gpja.errors import InputError
from gpja.results import FIGURE_FORMATS, Layout
from gpja.settings import from_section

if TYPE_CHECKING:
    from gpja.data.source import DataSource

#: ``Figure.methods`` value: every method of the comparison (GPJA, the enabled baselines, imported meshes).
COMPARED = "compared"
#: What a figure can read besides the run's data: the subject's template (``template.obj``, ``texture.png``),
#: the metrics JSONs (and their detail folders) or the registration logs of its methods and expressions, and
#: on synthetic data the texture's quality against the ground truth (``template/texture_quality.json`` and its
#: error image; an input only where the run has ground truth).
NEEDS = ("template", "metrics", "registration_logs", "texture_quality", "stages", "animation", "reparam", "turns")
#: The texture-quality files of a template folder (``gpja texture-quality``; gpja.metrics.texture_quality).
TEXTURE_QUALITY_FILES = ("texture_quality.json", "texture_error.png")


@dataclass(frozen=True)
class FigureSettings:
    """The ``figures`` section of the config.

    Attributes:
        view: the data view of photometric figures; None = the most frontal one.
        heatmap_max_mm: top of the geometric-error colour bar (mm).
        render_size: side of the geometry renders (px).
    """

    view: str | None = None
    heatmap_max_mm: float = 1.0
    render_size: int = 512

    #: ``FigureSettings.from_config(section, source)``: from the ``figures`` section, see gpja.settings.
    from_config = classmethod(from_section)


@dataclass(frozen=True)
class RunFiles:
    """Where a run's files are: its results layout and the dataset it was run on.

    Attributes:
        layout: ``results/{dataset}`` (:class:`gpja.results.Layout`).
        source: the dataset's roots (scans, images) as the workflow passes them; None = none given (a figure
            that needs the scans or the images then fails naming the missing option).
    """

    layout: Layout
    source: "DataSource | None" = None

    @property
    def data(self) -> "DataSource":
        """The dataset (an empty :class:`~gpja.data.source.DataSource` when none was given)."""
        if self.source is not None:
            return self.source
        from gpja.data.source import DataSource

        return DataSource()

    def metrics(self, subject: str, method_name: str, expression: str) -> dict:
        """The metrics JSON of one (subject, method, expression)."""
        from gpja.io import read_json

        return read_json(self.layout.metrics(subject, method_name, expression))

    def registration_log(self, subject: str, method_name: str, expression: str) -> dict:
        """The JSON log written beside a method's mesh."""
        from gpja.io import read_json

        return read_json(self.layout.registration_log(subject, method_name, expression))


@dataclass(frozen=True)
class FigureRequest:
    """Everything a draw function gets: which files, which subject, methods and expressions, which settings.

    Attributes:
        files: the run's files.
        subject: the subject drawn.
        methods: the methods drawn (columns, or the one drawn: :attr:`method`).
        expressions: the expressions drawn (rows or columns), at least one.
        settings: the config's ``figures`` section.
        backend: the render backend of the figure's renders (``gpja.render.BACKENDS``; "auto" is resolved, and
            a backend that cannot run reported, when the figure first renders).
    """

    files: RunFiles
    subject: str
    methods: tuple[str, ...] = ("gpja",)
    expressions: tuple[str, ...] = ()
    settings: FigureSettings = FigureSettings()
    backend: str = "cpu"

    @property
    def method(self) -> str:
        """The method of a one-method figure: the first one given."""
        return self.methods[0] if self.methods else "gpja"

    @property
    def render(self) -> Callable:
        """The backend's ``render_views`` (imports torch; ``gpja.render.renderer`` resolves :attr:`backend`)."""
        from gpja.render import renderer

        return renderer(self.backend)


@dataclass(frozen=True)
class Figure:
    """One figure of the registry.

    Attributes:
        name: ``gpja figure <name>``, rule ``plot_<name>``, files ``figures/<name>_{subject}.png|pdf``.
        draw: ``"module:function"`` (imported when drawn) or the function; ``draw(request) -> Figure``.
        methods: the methods it draws, in order, or :data:`COMPARED`.
        ablation: drawn on the ablation subjects and expressions only (and only when the config runs the
            ablation variants among ``methods``).
        photometric: drawn only when ``metrics.photometric`` is on (it reads the photometric renders).
        needs: which of :data:`NEEDS` are its workflow inputs.
        ground_truth: drawn only on synthetic data with its ground truth (it reads scores against it).
        applications: drawn only when the config runs the applications (``applications.enabled``).
    """

    name: str
    draw: str | Callable[[FigureRequest], Any]
    methods: tuple[str, ...] | str = ("gpja",)
    ablation: bool = False
    photometric: bool = False
    needs: tuple[str, ...] = ("template", "metrics")
    ground_truth: bool = False
    applications: bool = False

    def __post_init__(self):
        unknown = set(self.needs) - set(NEEDS)
        if unknown:
            raise ValueError(f"figure {self.name!r}: unknown needs {sorted(unknown)}; known: {NEEDS}")
        if isinstance(self.methods, str) and self.methods != COMPARED:
            raise ValueError(f"figure {self.name!r}: methods is a tuple of names or {COMPARED!r}")

    @property
    def caption(self) -> str:
        """The caption file in ``workflow/report/``."""
        return f"figure_{self.name}.rst"

    def function(self) -> Callable[[FigureRequest], Any]:
        """The draw function (imported on demand)."""
        if callable(self.draw):
            return self.draw
        module, _, name = self.draw.partition(":")
        return getattr(importlib.import_module(module), name)


#: Every figure, in the order the workflow lists them per subject.
FIGURES: dict[str, Figure] = {f.name: f for f in [
    Figure("template_stages", "gpja.report.figures_geometry:draw_template_stages",
           needs=("template", "texture_quality")),
    Figure("geometric_errors", "gpja.report.figures_geometry:draw_geometric_errors", methods=COMPARED),
    Figure("correspondence_errors", "gpja.report.figures_correspondence:draw_correspondence_errors",
           methods=COMPARED, ground_truth=True),
    Figure("convergence", "gpja.report.figures_convergence:draw_convergence",
           needs=("template", "registration_logs")),
    Figure("registration_stages", "gpja.report.figures_stages:draw_registration_stages",
           needs=("template", "stages"), ground_truth=True),
    Figure("photometric_errors", "gpja.report.figures_photometry:draw_photometric_errors", photometric=True),
    Figure("closeups", "gpja.report.figures_photometry:draw_closeups", photometric=True),
    Figure("ablation_normal", "gpja.report.figures_geometry:draw_ablation_normal",
           methods=("gpja", "gpja-no_normal"), ablation=True),
    Figure("ablation_mask", "gpja.report.figures_photometry:draw_ablation_mask",
           methods=("gpja", "gpja-no_mask"), ablation=True, photometric=True),
    Figure("animation", "gpja.report.figures_applications:draw_animation", needs=("animation",), applications=True),
    Figure("reparam", "gpja.report.figures_applications:draw_reparam", needs=("template", "reparam"),
           applications=True),
    Figure("turns", "gpja.report.figures_applications:draw_turns", needs=("template", "turns"), applications=True),
]}


def register_figure(name: str, *, methods: tuple[str, ...] | str = ("gpja",), ablation: bool = False,
                    photometric: bool = False, needs: tuple[str, ...] = ("template", "metrics"),
                    ground_truth: bool = False, applications: bool = False):
    """Decorator: add ``draw(request) -> Figure`` to :data:`FIGURES` under ``name`` (a new name only)."""

    def decorate(draw: Callable[[FigureRequest], Any]):
        if name in FIGURES:
            raise ValueError(f"figure {name!r} is already registered")
        FIGURES[name] = Figure(name, draw, methods, ablation, photometric, tuple(needs), ground_truth, applications)
        return draw

    return decorate


def unregister_figure(name: str) -> None:
    """Remove a figure added by :func:`register_figure`."""
    FIGURES.pop(name, None)


def figure(name: str) -> Figure:
    """The registry entry of ``name``; an unknown name raises :class:`InputError`."""
    if name not in FIGURES:
        raise InputError("figure", f"unknown figure {name!r}; choose from {', '.join(FIGURES)}")
    return FIGURES[name]


def draw_figure(name: str, request: FigureRequest):
    """The matplotlib figure ``name`` of ``request`` (not saved)."""
    if not request.expressions:
        raise InputError("--expressions", "no expressions given")
    return figure(name).function()(request)


def make_figure(name: str, request: FigureRequest, output: str | Path) -> tuple[Path, Path]:
    """Draw figure ``name`` into ``output`` (.png) and the .pdf beside it; return both paths.

    Nothing is written when drawing fails.
    """
    if Path(output).suffix.lower() != ".png":
        raise InputError(output, "the figure's output must be a .png (the .pdf is written beside it)")
    entry = figure(name)
    fig = draw_figure(entry.name, request)
    from gpja.report.drawing import save_figure

    return save_figure(fig, output)


@dataclass(frozen=True)
class FigurePlan:
    """Which figures a configuration draws, of which methods and expressions, from which files.

    Attributes:
        layout: the run's results layout.
        expressions: the expressions every compared method is run on.
        compared: the methods of the comparison (GPJA, enabled baselines, imported methods).
        ablation_variants: the ablation variants the config runs.
        ablation_subjects: the subjects they run on.
        ablation_expressions: the expressions they run on (those outside ``expressions`` are not run).
        photometric: ``metrics.photometric``.
        ground_truth: the data is synthetic with its ground truth (``data.ground_truth_root``, no Rt_scale).
        applications: ``applications.enabled``.
        application_expressions: the expressions the applications run on (the run's and the template's).
    """

    layout: Layout
    expressions: tuple[str, ...]
    compared: tuple[str, ...]
    ablation_variants: tuple[str, ...] = ()
    ablation_subjects: tuple[str, ...] = ()
    ablation_expressions: tuple[str, ...] = ()
    photometric: bool = True
    ground_truth: bool = False
    applications: bool = False
    application_expressions: tuple[str, ...] = ()

    def methods(self, entry: Figure) -> list[str]:
        """The methods the figure draws in this configuration."""
        return list(self.compared) if entry.methods == COMPARED else list(entry.methods)

    def expressions_of(self, entry: Figure) -> list[str]:
        """The expressions the figure draws: the ablation expressions that are run, or every expression."""
        if entry.ablation:
            return [e for e in self.ablation_expressions if e in self.expressions]
        if entry.applications:
            return list(self.application_expressions or self.expressions)
        return list(self.expressions)

    def draws(self, entry: Figure, subject: str) -> bool:
        """Whether the configuration draws the figure for ``subject``: its methods are all produced there."""
        if (entry.photometric and not self.photometric) or (entry.ground_truth and not self.ground_truth):
            return False
        if entry.applications and not self.applications:
            return False
        produced = set(self.compared)
        if entry.ablation:
            if subject not in self.ablation_subjects or not self.expressions_of(entry):
                return False
            produced |= set(self.ablation_variants)
        return all(m in produced for m in self.methods(entry))

    def figures(self, subject: str) -> list[str]:
        """The names of the figures drawn for ``subject``, in registry order."""
        return [name for name, entry in FIGURES.items() if self.draws(entry, subject)]

    def outputs(self, subject: str) -> list[str]:
        """The PNG and PDF of every figure drawn for ``subject``."""
        return [str(self.layout.figure(name, subject, fmt)) for name in self.figures(subject)
                for fmt in FIGURE_FORMATS]

    def inputs(self, entry: Figure, subject: str) -> list[str]:
        """The workflow inputs of the figure for ``subject`` (see :attr:`Figure.needs`)."""
        files = []
        if "template" in entry.needs:
            files += [self.layout.template_file(subject, "template.obj"),
                      self.layout.template_file(subject, "texture.png")]
        pairs = [(m, e) for m in self.methods(entry) for e in self.expressions_of(entry)]
        if "registration_logs" in entry.needs:
            files += [self.layout.registration_log(subject, m, e) for m, e in pairs]
        if "metrics" in entry.needs:
            files += [self.layout.metrics(subject, m, e) for m, e in pairs]
        if "stages" in entry.needs:
            files += [self.layout.stage_scores(subject, m, e) for m, e in pairs]
        if "animation" in entry.needs:
            files.append(self.layout.animation_frames(subject))
        if "reparam" in entry.needs:
            files += [self.layout.artist_mesh(subject)]
            files += [self.layout.reparametrized(subject, e) for e in self.expressions_of(entry)]
        if "turns" in entry.needs:
            files += [self.layout.artist_mesh(subject), self.layout.reparam_turns(subject)]
        if "texture_quality" in entry.needs and self.ground_truth:
            files += [self.layout.template_file(subject, name) for name in TEXTURE_QUALITY_FILES]
        return [str(f) for f in files]
