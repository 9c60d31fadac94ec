"""The applications end to end through the command line (``gpja triangulate|remesh|export|animate|artist|
reparametrize``, gpja/apply/steps.py and gpja/cli.py), on a tiny template folder.

The template is a UV-mapped lat-long sphere of radius 80 mm (``uv_sphere`` of test_remesh: welded positions, a
seam column, one texture coordinate per pole triangle; v made quadratic in the latitude) with a smooth coloured
texture, uniform lighting and an observed-texel mask with one unobserved band of rows. Its "registered
expressions" share its atlas but not its triangulation: refinements of it (``refine_by_factor``, different
factors) moved by a smooth map each, an anisotropic scaling (linear: commutes with barycentric interpolation)
and a Gaussian bump (nonlinear: the common triangulation must be refined to follow it). The template's own
expression is ``template.obj`` itself.

Every step runs once (a module fixture) through ``gpja.cli.main``; the tests read what the steps wrote. Bad
inputs must make ``main`` return 2, name the offending file or option on stderr and leave no output behind.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gpja.apply.export import split_at_seams
from gpja.apply.remesh import SEAM_AGREEMENT_MM, UV_OFF_ATLAS
from gpja.apply.settings import AnimationSettings
from gpja.cli import main
from gpja.io import from_uint8, read_image, read_json, read_npz, to_uint8, write_image, write_json
from gpja.lighting import uniform_sh
from gpja.mesh import TexturedMesh, read_obj, write_obj
from gpja.register.lighting_estimate import CONVENTION
from gpja.register.remesh import refine_by_factor
from gpja.results import LIGHTING_FILE, OBSERVED_TEXELS_FILE, lighting_record, read_template_lighting
from gpja.surface import prepare_surface
from tests.apply.test_export import decode
from tests.apply.test_remesh import uv_sphere
from tests.tolerances import CLOSEST_POINT_F32_MM, EXACT_F64

# --- tolerances -------------------------------------------------------------------------------------------

#: The chord tolerance the common triangulation is fitted to (``gpja triangulate``'s ``tolerance_mm``), mm.
CHORD_TOLERANCE_MM = 0.05
#: The largest sampled deviation, both ways, between a remeshed expression and its source, mm. The fit bounds the
#: chord error at edge midpoints only; inside a face the linear interpolant of a smooth surface can miss it by up
#: to 4/3 of that (a quadratic's interpolation error sum_ij l_i l_j d_ij is d_ij / 4 at edge midpoints and
#: (d_01 + d_02 + d_12) / 9 at the centroid). Measured 0.0512 mm on the bumped expression.
DEVIATION_MM = 4.0 / 3.0 * CHORD_TOLERANCE_MM
#: The 99th percentile of that deviation stays within the chord tolerance (measured 0.011 mm).
DEVIATION_P99_MM = CHORD_TOLERANCE_MM
#: The frontal renders of a remeshed expression and of its source (one texture, uniform light), dB (measured
#: 62 dB for the template, 93 dB for the bump, 152 dB for the scaling).
MIN_RENDER_PSNR_DB = 40.0
#: The same for the stand-in artist mesh with its resampled texture, dB: here a 300-face sphere with a 64 px texture
#: (measured 30.9-31.1; the default run's 30000 faces and 1024 px give 37-38 under white light).
MIN_ARTIST_PSNR_DB = 28.0
#: float64 identities through remeshing (the template onto the common triangulation, which lies on it; a linear
#: expression onto it, which commutes with barycentric interpolation) of ~85 mm coordinates, mm.
IDENTITY_MM = EXACT_F64
#: Vertices read back from the .glb (float32 metres; deltas against the float32 base), mm.
GLB_MM = 1e-5
#: A reparametrized vertex vs the registered surface (Open3D's float32 closest points), mm.
ON_SOURCE_MM = CLOSEST_POINT_F32_MM
#: The texture coordinate v of a point on the faceted template vs :func:`atlas_v` of it (from its polar angle):
#: facets interpolate the rings' v linearly, the angle is not (measured 1.8e-3), UV units. Faces whose centroid
#: is this close to an edge of the unobserved band may be counted either way.
LATLONG_V = 1e-2

#: Mean absolute difference between a decoded frame of the H.264 video and the same frame kept in the film-strip
#: .npz, uint8 levels: libx264 at crf 10, yuv420p halving the chroma of a 48 x 96 image with sharp silhouettes
#: (measured 3.0-3.4; the neighbouring frames are 6.6 and more away).
VIDEO_VS_STRIP_LEVELS = 5.0

# --- the fixture ------------------------------------------------------------------------------------------

RADIUS_MM = 80.0
N_LAT, N_LON = 16, 24  # rings between the poles, meridians: 386 positions, 768 faces
UV_MARGIN = 0.05  # uv_sphere maps its atlas into [UV_MARGIN, 1 - UV_MARGIN]^2
TEXTURE_PX = 128
#: Rows of texture_observed.png no camera saw (0), as fractions of its height from the top: texture coordinates
#: v in (0.55, 0.90], a cap around the north pole (15 % of the sphere's area, with v quadratic in the latitude:
#: :func:`template_mesh`); rows read the wrong way up would be the band v in (0.10, 0.45], 62 % of it.
UNOBSERVED_ROWS = (0.10, 0.45)
#: The scaled expression's factors per axis (linear: remeshing it is exact).
SCALE = np.array([1.06, 0.94, 1.03])
#: The bumped expression: a Gaussian radial bump of this height (mm) and width (sigma, mm) around (0, 0, R).
BUMP_MM, BUMP_SIGMA_MM = 3.0, 18.0

SUBJECT = "S0"
TEMPLATE_EXPRESSION = "3_mouth_stretch"
#: The registered expressions: name -> refine_by_factor's factor (each its own triangulation of the atlas).
REFINE = {"1_neutral": 2.0, "2_smile": 3.0}
REMESH_SETTINGS = {"initial_vertices": 2 * (2 + N_LAT * N_LON), "tolerance_mm": CHORD_TOLERANCE_MM,
                   "tangential_tolerance_mm": 2 * CHORD_TOLERANCE_MM, "max_vertices": 20000, "max_rounds": 8,
                   "face_samples": 1}
SEQUENCE = ["1_neutral", "2_smile", TEMPLATE_EXPRESSION, "1_neutral"]
ANIMATION_SETTINGS = {"sequence": SEQUENCE, "frames_per_transition": 2, "size": 48, "strip_frames": 3}
ARTIST_SETTINGS = {"standin_faces": 300, "texture_size": 64}
#: The reparametrize steps run with the untangling on (the default is off), through the CLI's --settings.
REPARAM_SETTINGS = {"untangle_iterations": 20, "untangle_rings": 1}
EXPORT_BASE = "1_neutral"


def template_mesh() -> TexturedMesh:
    """``uv_sphere`` of test_remesh with v made quadratic in its latitude parameter s = 1 - theta / pi (the
    northern hemisphere takes 3/4 of the atlas' height), so the sphere's north-south symmetry is not the atlas'."""
    mesh = uv_sphere(N_LAT, N_LON, RADIUS_MM)
    s = (mesh.UV[:, 1] - UV_MARGIN) / (1 - 2 * UV_MARGIN)
    mesh.UV[:, 1] = UV_MARGIN + (1 - 2 * UV_MARGIN) * s**2
    return mesh


def atlas_v(points: np.ndarray) -> np.ndarray:
    """(q,) the template texture coordinate v of points on (or near) the sphere, from their polar angle."""
    theta = np.arccos(np.clip(points[:, 1] / np.linalg.norm(points, axis=1), -1.0, 1.0))
    return UV_MARGIN + (1 - 2 * UV_MARGIN) * (1 - theta / np.pi) ** 2


def smooth_texture(size: int = TEXTURE_PX) -> np.ndarray:
    """(size, size, 3) float32 in [0.1, 0.9]: one low-frequency sine per channel."""
    v, u = np.mgrid[0:size, 0:size] / size
    return np.stack([0.5 + 0.4 * np.sin(2 * np.pi * u), 0.5 + 0.4 * np.cos(2 * np.pi * v),
                     0.5 + 0.3 * np.sin(2 * np.pi * (u + 2 * v))], axis=-1).astype(np.float32)


def observed_mask(size: int = TEXTURE_PX) -> np.ndarray:
    """(size, size) uint8: 255 (observed) everywhere except the rows of :data:`UNOBSERVED_ROWS` (0)."""
    mask = np.full((size, size), 255, dtype=np.uint8)
    mask[int(UNOBSERVED_ROWS[0] * size):int(UNOBSERVED_ROWS[1] * size)] = 0
    return mask


def scaled(mesh: TexturedMesh) -> TexturedMesh:
    return mesh.with_vertices(mesh.V * SCALE)


def bumped(mesh: TexturedMesh) -> TexturedMesh:
    """``mesh`` pushed outward along the radius by a Gaussian of height :data:`BUMP_MM` around (0, 0, R)."""
    centre = np.array([0.0, 0.0, RADIUS_MM])
    height = BUMP_MM * np.exp(-((mesh.V - centre) ** 2).sum(1) / (2 * BUMP_SIGMA_MM ** 2))
    return mesh.with_vertices(mesh.V * (1.0 + height / np.linalg.norm(mesh.V, axis=1))[:, None])


MOVES = {"1_neutral": scaled, "2_smile": bumped}


def run(*argv: str | Path) -> int:
    """``gpja ARGV...`` in this process: its exit status."""
    return main([str(a) for a in argv])


class Run:
    """The fixture's files (laid out as ``gpja.results.Layout`` lays out a subject) and each step's status."""

    def __init__(self, root: Path):
        self.root = root
        self.template_dir = root / "template"
        self.common = root / "remeshed" / "common.obj"
        self.common_again = root / "again" / "common.obj"
        self.glb = root / "blendshapes.glb"
        self.video = root / "animation.mp4"
        self.frames = root / "animation_frames.npz"
        self.artist = root / "reparam" / "artist.obj"
        self.status: dict[str, int] = {}
        #: expression -> its registered mesh; the template's own expression is the template
        self.sources = {TEMPLATE_EXPRESSION: self.template_dir / "template.obj",
                        **{name: root / "registered" / f"{name}.obj" for name in REFINE}}

    def remeshed(self, name: str) -> Path:
        return self.root / "remeshed" / f"{name}.obj"

    def reparametrized(self, name: str) -> Path:
        return self.root / "reparam" / f"{name}.obj"

    def named(self, paths: dict[str, Path] | None = None) -> list[str]:
        """``NAME=PATH`` arguments of the registered meshes (or of ``paths``)."""
        return [f"{k}={v}" for k, v in (paths or self.sources).items()]

    def named_remeshed(self) -> list[str]:
        return self.named({name: self.remeshed(name) for name in self.sources})


def build_inputs(r: Run) -> TexturedMesh:
    """The template folder and the registered expressions; the template."""
    template = template_mesh()
    template.texture = smooth_texture()
    write_obj(r.template_dir / "template.obj", template, texture_name="texture.png")  # writes texture.png too
    write_json(r.template_dir / LIGHTING_FILE, lighting_record(uniform_sh(1.0), "uniform", CONVENTION))
    write_image(r.template_dir / OBSERVED_TEXELS_FILE, observed_mask())
    for name, factor in REFINE.items():
        write_obj(r.sources[name], MOVES[name](refine_by_factor(template, factor)),
                  texture_name="../template/texture.png")
    return template


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory) -> Run:
    """Every step once, in the workflow's order, through ``gpja.cli.main``."""
    r = Run(tmp_path_factory.mktemp("steps"))
    build_inputs(r)
    settings = json.dumps(REMESH_SETTINGS)
    for key, out in (("triangulate", r.common), ("triangulate again", r.common_again)):
        r.status[key] = run("triangulate", "--subject", SUBJECT, "--template-dir", r.template_dir,
                            "--meshes", *r.named(), "--settings", settings, "--output", out)
    for name, path in r.sources.items():
        r.status[f"remesh {name}"] = run("remesh", "--subject", SUBJECT, "--expression", name, "--common", r.common,
                                         "--mesh", path, "--template-dir", r.template_dir,
                                         "--output", r.remeshed(name))
    r.status["export"] = run("export", "--subject", SUBJECT, "--meshes", *r.named_remeshed(),
                             "--template-dir", r.template_dir, "--settings", json.dumps({"base": EXPORT_BASE}),
                             "--output", r.glb)
    r.status["animate"] = run("animate", "--subject", SUBJECT, "--meshes", *r.named_remeshed(),
                              "--template-dir", r.template_dir, "--settings", json.dumps(ANIMATION_SETTINGS),
                              "--output", r.video, "--frames-output", r.frames)
    r.status["artist"] = run("artist", "--subject", SUBJECT, "--template-dir", r.template_dir,
                             "--settings", json.dumps(ARTIST_SETTINGS), "--output", r.artist)
    for name, path in r.sources.items():
        r.status[f"reparametrize {name}"] = run("reparametrize", "--subject", SUBJECT, "--expression", name,
                                                "--artist", r.artist, "--mesh", path, "--template-dir",
                                                r.template_dir, "--settings", json.dumps(REPARAM_SETTINGS),
                                                "--output", r.reparametrized(name))
    return r


def on_surface_distance(mesh: TexturedMesh, points: np.ndarray) -> np.ndarray:
    """(q,) distance (mm) from ``points`` to ``mesh``'s surface (Open3D, float32)."""
    return prepare_surface(mesh.V, mesh.F, find_boundary=False).closest(points).distance


# --- the inputs and the run ---------------------------------------------------------------------------------

def test_template_folder_reads_back(pipeline):
    d = pipeline.template_dir
    template = read_obj(d / "template.obj")  # with the texture its MTL names
    assert template.has_uv and template.texture.shape == (TEXTURE_PX, TEXTURE_PX, 3)
    np.testing.assert_array_equal(template.texture, from_uint8(to_uint8(smooth_texture())))
    np.testing.assert_array_equal(read_template_lighting(d), uniform_sh(1.0))
    np.testing.assert_array_equal(read_image(d / OBSERVED_TEXELS_FILE, mode="L") > 0.5, observed_mask() == 255)
    assert 0 < (observed_mask() == 0).mean() < 1
    for name in REFINE:  # the registered expressions: the template's atlas refined (its UVs first), moved
        mesh = read_obj(pipeline.sources[name], load_texture=False)
        assert len(mesh.V) > len(template.V) and len(mesh.UV) > len(template.UV)
        np.testing.assert_array_equal(mesh.UV[: len(template.UV)], template.UV)
    counts = {len(read_obj(p, load_texture=False).F) for p in pipeline.sources.values()}
    assert len(counts) == len(pipeline.sources)  # three triangulations


def test_every_step_exits_0(pipeline):
    assert pipeline.status == dict.fromkeys(pipeline.status, 0)


# --- triangulate and remesh -------------------------------------------------------------------------------

def test_triangulate_is_deterministic(pipeline):
    for suffix in (".obj", ".mtl"):  # the folders are equally deep: the MTL names the same relative texture
        first, again = (path.with_suffix(suffix).read_bytes() for path in (pipeline.common, pipeline.common_again))
        assert first == again, suffix


def test_triangulate_log(pipeline):
    log = read_json(pipeline.common.with_suffix(".json"))
    common = read_obj(pipeline.common, load_texture=False)
    counts = (log["vertices"], log["faces"], log["texture_coordinates"])
    assert counts == (len(common.V), len(common.F), len(common.UV))
    # the bump needed splits beyond the uniform refinement; nowhere near the cap
    assert REMESH_SETTINGS["initial_vertices"] < log["vertices"] < REMESH_SETTINGS["max_vertices"]
    assert log["settings"] == REMESH_SETTINGS
    assert set(log["expressions"]) == set(pipeline.sources)


def test_remeshed_expressions_share_the_common_triangulation(pipeline):
    common = read_obj(pipeline.common, load_texture=False)
    template_texture = read_obj(pipeline.sources[TEMPLATE_EXPRESSION]).texture
    for name in pipeline.sources:
        mesh = read_obj(pipeline.remeshed(name))  # and its MTL names the shared texture
        assert mesh.V.shape == common.V.shape, name
        for attr in ("F", "UV", "F_uv"):
            a, b = getattr(mesh, attr), getattr(common, attr)
            assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), (name, attr)
        np.testing.assert_array_equal(mesh.texture, template_texture)


@pytest.mark.parametrize("name", [TEMPLATE_EXPRESSION, *REFINE])
def test_remesh_log_deviation_and_render(pipeline, name):
    log = read_json(pipeline.remeshed(name).with_suffix(".json"))
    assert log["expression"] == name and log["vertices"] == len(read_obj(pipeline.common, load_texture=False).V)
    for way in ("to_source", "from_source"):
        assert log["deviation"][way]["max_mm"] <= DEVIATION_MM, (way, log["deviation"])
        assert log["deviation"][way]["p99_mm"] <= DEVIATION_P99_MM, (way, log["deviation"])
    render = log["render"]
    assert render["identical"] or render["psnr_db"] >= MIN_RENDER_PSNR_DB, render
    assert render["pixels"] > 0
    assert log["seam_disagreement_mm"] <= SEAM_AGREEMENT_MM and log["off_atlas_uv"] <= UV_OFF_ATLAS
    # and, independently of the log: every remeshed vertex lies on its source's surface
    source = read_obj(pipeline.sources[name], load_texture=False)
    assert on_surface_distance(source, read_obj(pipeline.remeshed(name), load_texture=False).V).max() <= ON_SOURCE_MM


def test_template_remeshed_is_the_identity(pipeline):
    """The common triangulation lies on the template (it refines it), so remeshing the template gives it back."""
    template = read_obj(pipeline.sources[TEMPLATE_EXPRESSION], load_texture=False)
    common = read_obj(pipeline.common, load_texture=False)
    remeshed = read_obj(pipeline.remeshed(TEMPLATE_EXPRESSION), load_texture=False)
    np.testing.assert_array_equal(common.V[: len(template.V)], template.V)  # the template's vertices first
    assert on_surface_distance(template, common.V).max() <= CLOSEST_POINT_F32_MM
    assert np.abs(remeshed.V - common.V).max() <= IDENTITY_MM


def test_linear_expression_remeshes_to_its_image(pipeline):
    """A linear map commutes with barycentric interpolation: the scaled expression remeshed is the scaled common."""
    common = read_obj(pipeline.common, load_texture=False)
    remeshed = read_obj(pipeline.remeshed("1_neutral"), load_texture=False)
    assert np.abs(remeshed.V - common.V * SCALE).max() <= IDENTITY_MM


# --- export -----------------------------------------------------------------------------------------------

def test_glb_recovers_every_remeshed_expression(pipeline):
    got = decode(pipeline.glb)  # test_export's reader: struct + json + numpy, no pygltflib
    remeshed = {name: read_obj(pipeline.remeshed(name), load_texture=False) for name in pipeline.sources}
    base = remeshed[EXPORT_BASE]
    vertex_of, uv_of, faces = split_at_seams(base.F, base.F_uv)
    (mesh,) = got["doc"]["meshes"]
    assert mesh["extras"]["base"] == EXPORT_BASE and mesh["name"] == SUBJECT
    assert list(got["targets"]) == [name for name in pipeline.sources if name != EXPORT_BASE]
    np.testing.assert_array_equal(got["faces"], faces)
    assert np.abs(got["V"] - base.V[vertex_of]).max() <= GLB_MM
    for name, V in got["targets"].items():
        assert np.abs(V - remeshed[name].V[vertex_of]).max() <= GLB_MM, name
    np.testing.assert_array_equal(got["texture"], to_uint8(read_image(pipeline.template_dir / "texture.png")))


# --- animate ----------------------------------------------------------------------------------------------

def test_animation_video_and_film_strip(pipeline):
    import imageio.v2 as imageio

    k, strip, size = (ANIMATION_SETTINGS[key] for key in ("frames_per_transition", "strip_frames", "size"))
    count = (len(SEQUENCE) - 1) * k + 1
    assert pipeline.video.is_file() and not pipeline.video.with_suffix(".gif").exists()
    assert pipeline.video.read_bytes()[4:8] == b"ftyp"  # an ISO media file
    strip_npz = read_npz(pipeline.frames)
    frames = strip_npz["frames"]
    views = len(AnimationSettings().yaw_deg)  # the default cameras
    assert frames.dtype == np.uint8 and frames.shape == (strip, size, views * size, 3)
    assert int(strip_npz["count"]) == count
    np.testing.assert_array_equal(strip_npz["index"], np.round(np.linspace(0, count - 1, strip)).astype(int))
    assert len(strip_npz["labels"]) == strip
    assert list(strip_npz["labels"]) == ["1_neutral -> 2_smile, t = 0.00",
                                         f"2_smile -> {TEMPLATE_EXPRESSION}, t = 0.50",
                                         f"{TEMPLATE_EXPRESSION} -> 1_neutral, t = 1.00"]
    # the sequence ends where it starts: first and last frames are one render of one mesh
    np.testing.assert_array_equal(frames[0], frames[-1])
    assert (frames[0] != frames[1]).any()
    with imageio.get_reader(str(pipeline.video), format="FFMPEG") as reader:
        video = np.stack([frame for frame in reader])  # list(reader) asks len(): inf for a stream
    assert video.shape == (count, size, views * size, 3)
    for i, j in enumerate(strip_npz["index"]):
        assert np.abs(video[j].astype(float) - frames[i]).mean() <= VIDEO_VS_STRIP_LEVELS, (i, j)


# --- artist and reparametrize -----------------------------------------------------------------------------

def test_artist_mesh_and_its_texture(pipeline):
    log = read_json(pipeline.artist.with_suffix(".json"))
    artist = read_obj(pipeline.artist)  # its texture.png beside it, in its own folder
    assert artist.has_uv and artist.texture.shape == (ARTIST_SETTINGS["texture_size"],) * 2 + (3,)
    assert log["faces"] == len(artist.F) and abs(len(artist.F) - ARTIST_SETTINGS["standin_faces"]) <= 10
    assert log["artist_mesh"].startswith("stand-in") and 0 < log["covered_texels"] < 1
    # the shared texture is untouched
    np.testing.assert_array_equal(read_image(pipeline.template_dir / "texture.png"),
                                  from_uint8(to_uint8(smooth_texture())))


@pytest.mark.parametrize("name", [TEMPLATE_EXPRESSION, *REFINE])
def test_reparametrized_lies_on_the_expression(pipeline, name):
    log = read_json(pipeline.reparametrized(name).with_suffix(".json"))
    artist = read_obj(pipeline.artist, load_texture=False)
    carried = read_obj(pipeline.reparametrized(name))  # its MTL names the artist's texture
    for attr in ("F", "UV", "F_uv"):
        np.testing.assert_array_equal(getattr(carried, attr), getattr(artist, attr))
    np.testing.assert_array_equal(carried.texture, read_image(pipeline.artist.parent / "texture.png"))
    assert log["vertices"] == len(artist.V)
    assert log["distance_to_source_mm"]["max"] <= ON_SOURCE_MM
    source = read_obj(pipeline.sources[name], load_texture=False)
    assert on_surface_distance(source, carried.V).max() <= ON_SOURCE_MM
    if name == TEMPLATE_EXPRESSION:
        assert log["flipped_faces_against_artist"] == 0 and log["flipped_observed_faces"] == 0
    # the smooth maps fold nothing, so the untangling (on, through --settings) has nothing to do
    assert log["untangle"]["folded_before"] == log["untangle"]["folded_after"] == 0
    assert log["untangle"]["rounds"] == 0 and log["flipped_faces_before_untangle"] == log["flipped_faces_against_artist"]
    # the resampled texture rendered on the artist mesh against the shared one on the source (white light)
    assert log["render"]["psnr_db"] >= MIN_ARTIST_PSNR_DB and "lit_psnr_db" in log["render"], log["render"]


def test_reparametrize_counts_the_observed_faces(pipeline):
    """The faces on observed texels, bracketed from the carried template-expression mesh: on the lat-long sphere a
    point's texture coordinate v follows its polar angle (:func:`atlas_v`), so a face's centroid v says whether the
    mask's band has it (row 0 of the mask is v = 1)."""
    log = read_json(pipeline.reparametrized(TEMPLATE_EXPRESSION).with_suffix(".json"))
    carried = read_obj(pipeline.reparametrized(TEMPLATE_EXPRESSION), load_texture=False)
    v = atlas_v(carried.V)[carried.F].mean(axis=1)
    # rows r0 <= int((1 - v) * T) < r1 are unobserved: v in (1 - r1 / T, 1 - r0 / T]
    r0, r1 = (int(f * TEXTURE_PX) for f in UNOBSERVED_ROWS)
    low, high = 1 - r1 / TEXTURE_PX, 1 - r0 / TEXTURE_PX
    surely_unobserved = ((v > low + LATLONG_V) & (v < high - LATLONG_V)).sum()
    surely_observed = ((v < low - LATLONG_V) | (v > high + LATLONG_V)).sum()
    assert surely_unobserved > 0.05 * len(carried.F) and surely_observed > 0.5 * len(carried.F)  # measured 35, 259
    assert surely_observed + surely_unobserved > 0.85 * len(carried.F)  # the bracket is tight
    assert surely_observed <= log["observed_faces"] <= len(carried.F) - surely_unobserved


# --- bad inputs -------------------------------------------------------------------------------------------
# Each case writes its bad input under ``tmp`` and returns (argv, the file or option stderr must name first, a
# word the message must contain); every output goes under tmp / "out", which must stay empty.

def _remesh(r: Run, mesh: Path, out: Path) -> list:
    return ["remesh", "--subject", SUBJECT, "--expression", "2_smile", "--common", r.common, "--mesh", mesh,
            "--template-dir", r.template_dir, "--output", out / "2_smile.obj"]


def _artist(r: Run, artist_mesh: str, out: Path) -> list:
    return ["artist", "--subject", SUBJECT, "--template-dir", r.template_dir,
            "--settings", json.dumps({**ARTIST_SETTINGS, "artist_mesh": artist_mesh}), "--output", out / "artist.obj"]


def _registered(r: Run, name: str = "2_smile") -> TexturedMesh:
    return read_obj(r.sources[name], load_texture=False)


def case_remesh_without_uvs(r, tmp, out):
    bad = tmp / "no_uv.obj"
    mesh = _registered(r)
    write_obj(bad, TexturedMesh(mesh.V, mesh.F), texture_name=None)
    return _remesh(r, bad, out), bad, "texture coordinates"


def case_remesh_other_parametrisation(r, tmp, out):
    bad = tmp / "half_uv.obj"
    mesh = _registered(r)
    write_obj(bad, TexturedMesh(mesh.V, mesh.F, mesh.UV * 0.5, mesh.F_uv), texture_name=None)
    return _remesh(r, bad, out), bad, "parametrisation"


def case_remesh_missing_mesh(r, tmp, out):
    bad = tmp / "missing.obj"
    return _remesh(r, bad, out), bad, "not found"


def case_triangulate_corrupt_obj(r, tmp, out):
    bad = tmp / "corrupt.obj"
    bad.write_text("garbage, not a mesh\n\tv ( ) oops\nfff\n")
    return (["triangulate", "--subject", SUBJECT, "--template-dir", r.template_dir,
             "--meshes", *r.named({**r.sources, "2_smile": bad}), "--settings", json.dumps(REMESH_SETTINGS),
             "--output", out / "common.obj"], bad, "empty mesh")


def case_triangulate_other_parametrisation(r, tmp, out):
    bad = tmp / "half_uv.obj"
    mesh = _registered(r)
    write_obj(bad, TexturedMesh(mesh.V, mesh.F, mesh.UV * 0.5, mesh.F_uv), texture_name=None)
    return (["triangulate", "--subject", SUBJECT, "--template-dir", r.template_dir,
             "--meshes", *r.named({**r.sources, "2_smile": bad}), "--settings", json.dumps(REMESH_SETTINGS),
             "--output", out / "common.obj"], bad, "parametrisation")


def case_meshes_name_given_twice(r, tmp, out):
    return (["export", "--subject", SUBJECT, "--meshes", *r.named_remeshed(), f"2_smile={r.remeshed('1_neutral')}",
             "--template-dir", r.template_dir, "--output", out / "blendshapes.glb"], "--meshes", "given twice")


def case_meshes_without_equals(r, tmp, out):
    return (["triangulate", "--subject", SUBJECT, "--template-dir", r.template_dir,
             "--meshes", *r.named(), str(r.sources["2_smile"]), "--settings", json.dumps(REMESH_SETTINGS),
             "--output", out / "common.obj"], "--meshes", "NAME=PATH")


def case_export_base_not_among_meshes(r, tmp, out):
    return (["export", "--subject", SUBJECT, "--meshes", *r.named_remeshed(), "--template-dir", r.template_dir,
             "--settings", json.dumps({"base": "nope"}), "--output", out / "blendshapes.glb"],
            "applications.export.base", "'nope'")


def case_export_different_triangulations(r, tmp, out):
    meshes = {"1_neutral": r.remeshed("1_neutral"), "2_smile": r.sources["2_smile"]}  # one remeshed, one not
    return (["export", "--subject", SUBJECT, "--meshes", *r.named(meshes), "--template-dir", r.template_dir,
             "--settings", json.dumps({"base": "1_neutral"}), "--output", out / "blendshapes.glb"],
            r.sources["2_smile"], "same triangulation")


def case_animate_missing_expression(r, tmp, out):
    settings = {**ANIMATION_SETTINGS, "sequence": ["1_neutral", "9_missing", "2_smile"]}
    return (["animate", "--subject", SUBJECT, "--meshes", *r.named_remeshed(), "--template-dir", r.template_dir,
             "--settings", json.dumps(settings), "--output", out / "animation.mp4",
             "--frames-output", out / "animation_frames.npz"], "applications.animation.sequence", "9_missing")


def case_animate_sequence_of_missing_expressions_only(r, tmp, out):
    settings = {**ANIMATION_SETTINGS, "sequence": ["8_missing", "9_missing"]}
    return (["animate", "--subject", SUBJECT, "--meshes", *r.named_remeshed(), "--template-dir", r.template_dir,
             "--settings", json.dumps(settings), "--output", out / "animation.mp4",
             "--frames-output", out / "animation_frames.npz"], "applications.animation.sequence", "9_missing")


def case_artist_without_uvs(r, tmp, out):
    bad = tmp / "artist_no_uv.obj"
    template = read_obj(r.sources[TEMPLATE_EXPRESSION], load_texture=False)
    write_obj(bad, TexturedMesh(template.V, template.F), texture_name=None)
    return _artist(r, str(bad), out), bad, "texture coordinates"


def case_artist_in_metres(r, tmp, out):
    bad = tmp / "artist_m.obj"
    template = read_obj(r.sources[TEMPLATE_EXPRESSION], load_texture=False)
    write_obj(bad, template.with_vertices(template.V / 1000.0), texture_name=None)
    return _artist(r, str(bad), out), bad, "units"


def case_artist_shifted(r, tmp, out):
    bad = tmp / f"{SUBJECT}_shifted.obj"  # named through the {subject} placeholder
    template = read_obj(r.sources[TEMPLATE_EXPRESSION], load_texture=False)
    write_obj(bad, template.with_vertices(template.V + [30.0, 0.0, 0.0]), texture_name=None)
    return _artist(r, str(tmp / "{subject}_shifted.obj"), out), bad, "too far"


BAD_CASES = [case_remesh_without_uvs, case_remesh_other_parametrisation, case_remesh_missing_mesh,
             case_triangulate_corrupt_obj, case_triangulate_other_parametrisation, case_meshes_without_equals,
             case_export_base_not_among_meshes, case_export_different_triangulations,
             case_animate_missing_expression,
             case_animate_sequence_of_missing_expressions_only, case_meshes_name_given_twice,
             case_artist_without_uvs, case_artist_in_metres, case_artist_shifted]


@pytest.mark.parametrize("case", BAD_CASES, ids=lambda case: case.__name__.removeprefix("case_"))
def test_bad_input_exits_2_naming_it_and_writes_nothing(pipeline, tmp_path, capsys, case):
    out = tmp_path / "out"
    argv, culprit, word = case(pipeline, tmp_path, out)
    capsys.readouterr()
    assert run(*argv) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, errors
    assert errors[0].startswith(f"error: {culprit}: ") and word in errors[0], errors[0]
    assert not out.exists() or not any(out.rglob("*")), sorted(out.rglob("*"))  # not even a temporary file
