"""The one description of where a run's files are: results, logs and benchmarks.

Every path the workflow writes is named here once. The Snakemake rules call
these with wildcard placeholders (``Layout("results/x").registration("{subject}",
"{method}", "{expression}")`` gives the rule's output pattern); the CLI, the
tables, the figures and the regression check call them with real names, so the
rules and the readers cannot disagree about a path.

    results/{dataset}/{subject}/data/{expression}.json         check_expression summary
    results/{dataset}/{subject}/targets/{expression}.npz|.png  scan depth/normal/coverage targets
    results/{dataset}/{subject}/template/                      template.obj|.mtl, texture.png, mouth_mask.png,
                                                               template.json, lighting.json,
                                                               texture_observed.png, stages/
    results/{dataset}/{subject}/{method}/{expression}.obj|.json   a method's mesh and its log
    results/{dataset}/{subject}/{method}/metrics/{expression}.json (+ folder of per-vertex errors, renders)
    results/{dataset}/{subject}/contact_sheet.png, all.done
    results/{dataset}/{subject}/remeshed/common.obj, {expression}.obj   every expression on one triangulation
    results/{dataset}/{subject}/reparam/artist.obj, {expression}.obj    the artist mesh on every expression
    results/{dataset}/{subject}/animation.mp4, animation_frames.npz, {subject}.glb
    results/{dataset}/tables/{table}.csv|md|tex
    results/{dataset}/figures/{figure}_{subject}.png|pdf
    results/{dataset}/undistorted/                             cache of undistorted reference images
    results/{dataset}/report.html
    logs/{dataset}/... and benchmarks/{dataset}/...            mirror the step that wrote them
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the mesh and image readers load on use: the Snakefile imports this module for paths only
    from typing import Callable

    import numpy as np

    from gpja.mesh import TexturedMesh

#: The files of a template folder (``Layout.template_dir``).
TEMPLATE_FILES = ("template.obj", "template.mtl", "texture.png", "mouth_mask.png", "template.json", "lighting.json",
                  "texture_observed.png")
#: The template's mask of observed texels: 255 = at least one view saw the texel, 0 = filled (``gpja.register.template``).
OBSERVED_TEXELS_FILE = "texture_observed.png"
#: The template's SH lighting (:func:`read_template_lighting`, :func:`lighting_record`): what every registration
#: and every photometric score renders with, since the texture's albedo is relative to it.
LIGHTING_FILE = "lighting.json"
#: Where a template's lighting came from: fitted to its images (``gpja.register.lighting_estimate``) or the
#: paper's uniform white light (``gpja.lighting.uniform_sh(1.0)``); config ``registration.lighting``.
LIGHTING_SOURCES = ("estimated", "uniform")
#: Formats every table is written in.
TABLE_FORMATS = ("csv", "md", "tex")
#: Formats every figure is written in (the PNG goes into the HTML report).
FIGURE_FORMATS = ("png", "pdf")


@dataclass(frozen=True)
class Layout:
    """Paths of one dataset's run. ``root`` is ``results/{dataset}``; logs and benchmarks sit beside it.

    Every method takes names (or Snakemake wildcard placeholders such as ``"{subject}"``) and returns a
    :class:`~pathlib.Path`; nothing is created or checked here.
    """

    root: Path
    logs_root: Path | None = None
    benchmarks_root: Path | None = None

    @classmethod
    def for_dataset(cls, dataset: str, base: str | Path = ".") -> "Layout":
        """``results/{dataset}``, ``logs/{dataset}`` and ``benchmarks/{dataset}`` under ``base``."""
        base = Path(base)
        return cls(base / "results" / dataset, base / "logs" / dataset, base / "benchmarks" / dataset)

    def __post_init__(self):
        object.__setattr__(self, "root", Path(self.root))

    # --- per subject -----------------------------------------------------------------------------------------
    def subject_dir(self, subject: str) -> Path:
        return self.root / str(subject)

    def data_summary(self, subject: str, expression: str) -> Path:
        """The ``check_expression`` summary JSON of one expression."""
        return self.subject_dir(subject) / "data" / f"{expression}.json"

    def scan_targets(self, subject: str, expression: str) -> Path:
        """The cached scan depth/normal/coverage targets of one expression (.npz; a .png preview beside it)."""
        return self.subject_dir(subject) / "targets" / f"{expression}.npz"

    def scan_targets_preview(self, subject: str, expression: str) -> Path:
        """The .png preview beside :meth:`scan_targets`."""
        return self.scan_targets(subject, expression).with_suffix(".png")

    def contact_sheet(self, subject: str) -> Path:
        return self.subject_dir(subject) / "contact_sheet.png"

    def subject_done(self, subject: str) -> Path:
        return self.subject_dir(subject) / "all.done"

    def template_dir(self, subject: str) -> Path:
        return self.subject_dir(subject) / "template"

    def template_file(self, subject: str, name: str) -> Path:
        """One of :data:`TEMPLATE_FILES` (or ``stages``) of the subject's template folder."""
        return self.template_dir(subject) / name

    def template_stage(self, subject: str, stage: str) -> Path:
        """A mesh the template step keeps of one of its stages (``bust``, ``fitted``): ``stages/{stage}.obj``."""
        return self.template_file(subject, "stages") / f"{stage}.obj"

    def registration_order(self, subject: str) -> Path:
        """Which expression each GPJA registration starts from (``gpja order``, ``registration.start: tree``)."""
        return self.subject_dir(subject) / "registration_order.json"

    # --- per (subject, method, expression) -------------------------------------------------------------------
    def method_dir(self, subject: str, method: str) -> Path:
        return self.subject_dir(subject) / method

    def registration(self, subject: str, method: str, expression: str) -> Path:
        """A method's mesh of one expression (.obj); its JSON log is :meth:`registration_log`."""
        return self.method_dir(subject, method) / f"{expression}.obj"

    def registration_log(self, subject: str, method: str, expression: str) -> Path:
        """The JSON log a registration (GPJA, a baseline) or an import writes beside its mesh."""
        return self.method_dir(subject, method) / f"{expression}.json"

    def registration_start(self, subject: str, method: str, expression: str) -> Path:
        """The .obj a registration hands its children in the tree (``gpja register --start-output``): the template's
        vertices where it put them before the snap (``gpja.register.pipeline.chain_start``)."""
        return self.method_dir(subject, method) / "starts" / f"{expression}.obj"

    def registration_stages(self, subject: str, method: str, expression: str) -> Path:
        """The folder of a registration's stage meshes (``gpja register --stages-dir``)."""
        return self.method_dir(subject, method) / "stages" / expression

    def stage_scores(self, subject: str, method: str, expression: str) -> Path:
        """The scores of those stages (``gpja stages``, synthetic data): a .json and an .npz beside it."""
        return self.method_dir(subject, method) / "stages" / f"{expression}.json"

    def stage_arrays(self, subject: str, method: str, expression: str) -> Path:
        """The arrays beside :meth:`stage_scores` (per-vertex errors, L1 images)."""
        return self.stage_scores(subject, method, expression).with_suffix(".npz")

    def metrics(self, subject: str, method: str, expression: str) -> Path:
        """Where ``gpja metrics`` writes the scores of one (subject, method, expression)."""
        return self.method_dir(subject, method) / "metrics" / f"{expression}.json"

    def metrics_details(self, subject: str, method: str, expression: str) -> Path:
        """The folder of per-vertex errors, renders and L1 images beside :meth:`metrics`."""
        return self.method_dir(subject, method) / "metrics" / expression

    def find_metrics(self) -> list[tuple[str, str, str]]:
        """``(subject, method, expression)`` of every :meth:`metrics` JSON present under ``root``, sorted."""
        pattern = self.metrics("*", "*", "*").relative_to(self.root)
        return [(p.parent.parent.parent.name, p.parent.parent.name, p.stem) for p in sorted(self.root.glob(str(pattern)))]

    # --- applications (gpja.apply), per subject --------------------------------------------------------------
    def remeshed_dir(self, subject: str) -> Path:
        return self.subject_dir(subject) / "remeshed"

    def common_triangulation(self, subject: str) -> Path:
        """The triangulation every remeshed expression shares (``gpja triangulate``): .obj, and a .json log."""
        return self.remeshed_dir(subject) / "common.obj"

    def remeshed(self, subject: str, expression: str) -> Path:
        """One expression on the common triangulation (``gpja remesh``): .obj (+ .mtl), a .json log beside it."""
        return self.remeshed_dir(subject) / f"{expression}.obj"

    def reparam_dir(self, subject: str) -> Path:
        return self.subject_dir(subject) / "reparam"

    def artist_mesh(self, subject: str) -> Path:
        """The artist mesh carried onto every expression (a copy of the configured one, or the stand-in): .obj,
        and its own texture ``reparam/texture.png`` resampled from the shared one."""
        return self.reparam_dir(subject) / "artist.obj"

    def reparametrized(self, subject: str, expression: str) -> Path:
        """One expression in the artist mesh's topology and UVs (``gpja reparametrize``), a .json log beside it."""
        return self.reparam_dir(subject) / f"{expression}.obj"

    def reparam_turns(self, subject: str) -> Path:
        """The artist mesh's faces turned over along the registration tree's hops (``gpja turns``), JSON."""
        return self.reparam_dir(subject) / "turns.json"

    def animation(self, subject: str) -> Path:
        """The animation of the remeshed expressions (``gpja animate``); ``.gif`` when no ffmpeg is found."""
        return self.subject_dir(subject) / "animation.mp4"

    def animation_frames(self, subject: str) -> Path:
        """The animation's key frames (.npz) the film-strip figure draws."""
        return self.subject_dir(subject) / "animation_frames.npz"

    def blendshapes(self, subject: str) -> Path:
        """The glTF 2.0 binary: the base expression and every other as a morph target (``gpja export``)."""
        return self.subject_dir(subject) / f"{subject}.glb"

    # --- dataset-wide ----------------------------------------------------------------------------------------
    @property
    def undistorted(self) -> Path:
        """The cache of undistorted reference images."""
        return self.root / "undistorted"

    @property
    def tables_dir(self) -> Path:
        return self.root / "tables"

    def table(self, name: str, fmt: str) -> Path:
        return self.tables_dir / f"{name}.{fmt}"

    @property
    def figures_dir(self) -> Path:
        return self.root / "figures"

    def figure(self, kind: str, subject: str, fmt: str = "png") -> Path:
        return self.figures_dir / f"{kind}_{subject}.{fmt}"

    @property
    def report(self) -> Path:
        return self.root / "report.html"

    # --- logs and benchmarks mirror the step -----------------------------------------------------------------
    def log(self, *parts: str) -> Path:
        """``logs/{dataset}/<parts...>.log``: e.g. ``log(subject, method, expression)``."""
        return self._mirror(self.logs_root, "logs", parts, ".log")

    def benchmark(self, *parts: str) -> Path:
        """``benchmarks/{dataset}/<parts...>.tsv``: Snakemake's benchmark file of the same step."""
        return self._mirror(self.benchmarks_root, "benchmarks", parts, ".tsv")

    def _mirror(self, base: Path | None, kind: str, parts, suffix: str) -> Path:
        if base is None:
            base = self.root.parent.parent / kind / self.root.name
        *head, last = [str(p) for p in parts]
        return Path(base, *head, f"{last}{suffix}")


# --- reading and writing a run's meshes (plain paths, as the Layout gives them) ----------------------------------

def read_template(template_dir: str | Path) -> "tuple[TexturedMesh, np.ndarray]":
    """The template mesh (with texture) and its mouth mask from a template folder.

    Returns:
        (:class:`gpja.mesh.TexturedMesh` with UVs and texture, (T, T) float32 mouth mask in [0, 1]).
    Raises:
        InputError: a missing or corrupt file, or a template without texture coordinates or texture image.
    """
    from gpja.errors import InputError
    from gpja.io import read_image
    from gpja.mesh import read_obj

    d = Path(template_dir)
    mesh = read_obj(d / "template.obj")
    if mesh.texture is None or not mesh.has_uv:
        raise InputError(d / "template.obj", "a template needs texture coordinates and a texture image")
    mask = read_image(d / "mouth_mask.png", mode="L")
    return mesh, mask


def lighting_record(sh: "np.ndarray", source: str, convention: str) -> dict:
    """The JSON of :data:`LIGHTING_FILE`: ``{"sh": 9x3 list, "convention": ..., "source": ...}``.

    Args:
        sh: (9, 3) float radiance SH coefficients (``gpja.lighting`` convention).
        source: one of :data:`LIGHTING_SOURCES`.
        convention: how the SH is to be read, in words (``gpja.register.lighting_estimate.CONVENTION``).
    """
    import numpy as np

    sh = np.asarray(sh, dtype=np.float64)
    if sh.shape != (9, 3) or not np.isfinite(sh).all():
        raise ValueError(f"lighting: expected a finite (9, 3) SH array, got shape {sh.shape}")
    if source not in LIGHTING_SOURCES:
        raise ValueError(f"lighting source {source!r} is not one of {', '.join(LIGHTING_SOURCES)}")
    return {"sh": sh.tolist(), "convention": convention, "source": source}


def read_template_lighting(template_dir: str | Path) -> "np.ndarray":
    """The SH lighting (9, 3) float64 of a template folder's :data:`LIGHTING_FILE`.

    Raises:
        InputError: the file is missing or corrupt, has no (9, 3) finite ``sh`` with a positive DC term, or
            an unknown ``source``.
    """
    import numpy as np

    from gpja.errors import InputError
    from gpja.io import read_json

    path = Path(template_dir) / LIGHTING_FILE
    record = read_json(path)
    if not isinstance(record, dict) or "sh" not in record:
        raise InputError(path, "expected a JSON object with the key \"sh\" (9 x 3 SH coefficients)")
    if record.get("source") not in LIGHTING_SOURCES:
        raise InputError(path, f"source {record.get('source')!r} is not one of {', '.join(LIGHTING_SOURCES)}")
    try:
        sh = np.asarray(record["sh"], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(path, "sh is not a 9 x 3 array of numbers") from None
    if sh.shape != (9, 3) or not np.isfinite(sh).all() or not (sh[0] > 0).all():
        raise InputError(path, f"sh must be 9 x 3 finite numbers with a positive first row, got shape {sh.shape}")
    return sh


def write_registration(mesh: "TexturedMesh", log: dict, obj_path: str | Path, texture_ref: str) -> None:
    """Write a registered mesh (OBJ referencing the shared template texture) and its JSON log beside it.

    Args:
        mesh: the registered :class:`gpja.mesh.TexturedMesh` (its own texture image is not written).
        log: JSON-able log, written to ``obj_path`` with the suffix ``.json``.
        texture_ref: the texture path the MTL names, relative to the OBJ's folder.
    """
    from gpja.io import write_json
    from gpja.mesh import TexturedMesh, write_obj

    write_obj(obj_path, TexturedMesh(mesh.V, mesh.F, mesh.UV, mesh.F_uv), texture_name=texture_ref)
    write_json(Path(obj_path).with_suffix(".json"), log)


#: ``gpja register --stages-dir``: one ``{index}_{stage}.npz`` per stage (start, warmup, level1, ...).
STAGE_ARRAYS = ("V", "F", "UV", "F_uv")


def stage_writer(out_dir: str | Path) -> "Callable[[str, TexturedMesh], None]":
    """``on_stage`` of :func:`gpja.register.multiscale.optimise` that saves each stage's mesh into ``out_dir``
    as ``{index}_{stage}.npz`` (V float32 mm, F/F_uv int32, UV float32), numbered in the order called."""
    import numpy as np

    from gpja.io import write_npz

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    count = [0]

    def write(name: str, mesh: "TexturedMesh") -> None:
        write_npz(out / f"{count[0]}_{name}.npz", V=mesh.V.astype(np.float32), F=mesh.F.astype(np.int32),
                  UV=mesh.UV.astype(np.float32), F_uv=mesh.F_uv.astype(np.int32))
        count[0] += 1

    return write


def read_stages(stages_dir: str | Path) -> "list[tuple[str, TexturedMesh]]":
    """The stage meshes :func:`stage_writer` saved, in order: ``[(stage name, mesh)]``."""
    from gpja.errors import InputError
    from gpja.io import read_npz
    from gpja.mesh import TexturedMesh

    folder = Path(stages_dir)
    if not folder.is_dir():
        raise InputError(folder, "registration stages folder not found (gpja register --stages-dir)")
    files = sorted(folder.glob("*_*.npz"), key=lambda p: int(p.name.split("_", 1)[0]))
    if not files:
        raise InputError(folder, "no stage meshes in the folder")
    stages = []
    for path in files:
        arrays = read_npz(path)
        missing = [k for k in STAGE_ARRAYS if k not in arrays]
        if missing:
            raise InputError(path, f"no {', '.join(missing)} array(s): not a stage mesh")
        stages.append((path.stem.split("_", 1)[1], TexturedMesh(arrays["V"], arrays["F"], arrays["UV"], arrays["F_uv"])))
    return stages
