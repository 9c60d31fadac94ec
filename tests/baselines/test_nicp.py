"""Tests of gpja.baselines.nicp: optimal-step NICP on a bumped ellipsoid, the file driver, bad input."""
from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from gpja.baselines.landmarks import read_template_landmarks
from gpja.baselines.nicp import NicpSettings, NicpStep, nicp, run_baseline
from gpja.data.source import DataSource
from gpja.errors import InputError
from gpja.io import write_image
from gpja.methods import method
from gpja.mesh import TexturedMesh, read_obj, write_obj, write_ply
from gpja.surface import prepare_surface
from tests.tolerances import NICP_BACK_OF_HEAD_MM, NICP_MIN_DISTANCE_REDUCTION

AXES_MM = np.array([80.0, 100.0, 90.0])
SUBJECT, EXPRESSION, TEMPLATE_EXPRESSION = "S9", "2_smile", "3_mouth_stretch"
#: a short schedule for the file-level tests, which check plumbing, not accuracy
QUICK = NicpSettings(steps=(NicpStep(1.0, 3.0, 2), NicpStep(0.2, 1.0, 2)), rigid_iterations=2)
#: the config's ``baselines.nicp`` section with that schedule (its landmark pattern is the test's)
QUICK_SECTION = {"enabled": True, "template_landmarks": None,
                 "settings": {"steps": [[1.0, 3.0, 2], [0.2, 1.0, 2]], "rigid_iterations": 2}}


def ellipsoid(subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """An ellipsoid head stand-in (mm): face towards +Z, up +Y."""
    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(s.vertices) * AXES_MM, np.asarray(s.faces)


def bump(V: np.ndarray, seed: int = 0, count: int = 6, amp_mm: float = 4.0, width_mm: float = 25.0) -> np.ndarray:
    """Smooth Gaussian bumps (+-amp_mm) along the radial direction, centred on the front half."""
    rng = np.random.default_rng(seed)
    front = np.flatnonzero(V[:, 2] > 0.3 * AXES_MM[2])
    centres = V[rng.choice(front, count, replace=False)]
    signs = rng.choice([-1.0, 1.0], count)
    height = sum(s * amp_mm * np.exp(-((V - c) ** 2).sum(1) / (2 * width_mm ** 2)) for s, c in zip(signs, centres))
    return V + height[:, None] * V / np.linalg.norm(V, axis=1, keepdims=True)


def rigid_offset(V: np.ndarray) -> np.ndarray:
    """A small rigid motion: 4 degrees about Y, 4 mm translation."""
    th = np.radians(4.0)
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    return V @ R.T + np.array([3.0, -2.0, 2.0])


def crop_back(V: np.ndarray, F: np.ndarray, z_min_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Keep the faces in front of ``z_min_mm`` (an open 'face scan' with a rim)."""
    keep = F[(V[F][:, :, 2] > z_min_mm).all(axis=1)]
    used = np.unique(keep)
    remap = np.full(len(V), -1)
    remap[used] = np.arange(len(used))
    return V[used], remap[keep]


def uv_template(V: np.ndarray, F: np.ndarray) -> TexturedMesh:
    """A textured template: spherical UVs with their own (here identical) faces."""
    d = V / np.linalg.norm(V, axis=1, keepdims=True)
    UV = np.c_[0.5 + np.arctan2(d[:, 0], d[:, 2]) / (2 * np.pi), 0.5 + np.arcsin(d[:, 1]) / np.pi]
    tex = np.random.default_rng(3).random((8, 8, 3)).astype(np.float32)
    return TexturedMesh(V, F, UV, F.copy(), tex)


def front_landmarks(V: np.ndarray, count: int = 8) -> np.ndarray:
    """Indices of ``count`` vertices spread over the front (closest to fixed directions)."""
    dirs = np.array([[0, 0, 1], [0.4, 0.3, 1], [-0.4, 0.3, 1], [0.4, -0.3, 1], [-0.4, -0.3, 1],
                     [0, 0.5, 1], [0, -0.5, 1], [0.7, 0, 1]], dtype=np.float64)[:count]
    d = V / np.linalg.norm(V, axis=1, keepdims=True)
    return np.argmax(d @ (dirs / np.linalg.norm(dirs, axis=1, keepdims=True)).T, axis=0)


def distances_to(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(k,) distances of the points ``P (k, 3)`` to the mesh surface ``V, F``, mm."""
    return prepare_surface(V, F, find_boundary=False).closest(P).distance


def scan_to_mesh_mean(V_scan: np.ndarray, mesh_V: np.ndarray, mesh_F: np.ndarray) -> float:
    """Mean distance from scan vertices to a mesh surface, mm."""
    return float(distances_to(V_scan, mesh_V, mesh_F).mean())


def unweld(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same surface with every face on its own three vertex copies (a per-corner PLY)."""
    return V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3)


@pytest.fixture(scope="module")
def bumped_case() -> dict:
    """Source: 2562-vertex ellipsoid. Target: finer ellipsoid, bumped, moved, back cropped (open)."""
    V_src, F_src = ellipsoid(4)
    V_full, F_full = ellipsoid(5)
    V_full = rigid_offset(bump(V_full))
    V_t, F_t = crop_back(V_full, F_full, z_min_mm=-30.0)
    lm = front_landmarks(V_src)
    return {"template": uv_template(V_src, F_src), "V_scan": V_t, "F_scan": F_t, "V_full": V_full,
            "F_full": F_full, "lm_template": lm, "lm_scan": rigid_offset(bump(V_src))[lm]}


@pytest.fixture(scope="module")
def registered(bumped_case) -> tuple[TexturedMesh, dict]:
    c = bumped_case
    return nicp(c["template"], c["V_scan"], c["F_scan"], c["lm_template"], c["lm_scan"], progress=lambda s: None)


def test_nicp_cuts_the_mean_distance_tenfold(bumped_case, registered):
    c = bumped_case
    mesh, log = registered
    before = scan_to_mesh_mean(c["V_scan"], c["template"].V, c["template"].F)
    after = scan_to_mesh_mean(c["V_scan"], mesh.V, mesh.F)
    assert before / after >= NICP_MIN_DISTANCE_REDUCTION, (before, after)
    assert len(log["steps"]) == len(NicpSettings().steps)
    assert log["steps"][-1]["mean_distance_mm"] < log["steps"][0]["mean_distance_mm"]


def test_nicp_does_not_drag_the_uncovered_back_onto_the_rim(bumped_case, registered):
    """The back (z < -60 mm) has no scan data: boundary rejection keeps it off the scan's rim at z = -30."""
    c = bumped_case
    mesh, _ = registered
    back = c["template"].V[:, 2] < -60.0
    gap = distances_to(mesh.V[back], c["V_full"], c["F_full"])
    assert gap.max() < NICP_BACK_OF_HEAD_MM, gap.max()


def test_nicp_keeps_faces_and_uvs_bit_exact(bumped_case, registered):
    t = bumped_case["template"]
    mesh, _ = registered
    for name in ("F", "UV", "F_uv"):
        a, b = getattr(mesh, name), getattr(t, name)
        assert a.dtype == b.dtype and np.array_equal(a, b), name
    assert mesh.V.shape == t.V.shape and not np.array_equal(mesh.V, t.V)


def test_nicp_is_deterministic(bumped_case, registered):
    c = bumped_case
    again, _ = nicp(c["template"], c["V_scan"], c["F_scan"], c["lm_template"], c["lm_scan"], progress=lambda s: None)
    assert np.array_equal(again.V, registered[0].V)


def test_identity_when_template_equals_scan():
    """A scan that is the template itself: every stage keeps the vertices where they are."""
    V, F = ellipsoid(3)
    t = uv_template(V, F)
    lm = front_landmarks(V)
    mesh, log = nicp(t, V, F, lm, V[lm], QUICK, progress=lambda s: None)
    assert np.abs(mesh.V - V).max() < 1e-6
    assert log["rigid"]["landmark_error_mm"] < 1e-9


def test_correspondences_survive_an_unwelded_scan(bumped_case):
    """A scan saved with per-corner vertices has the same rim once welded: NICP matches as on the welded scan.

    Without welding every edge of such a scan is open, so boundary rejection threw every correspondence away.
    """
    c = bumped_case
    V_u, F_u = unweld(c["V_scan"], c["F_scan"])
    welded = nicp(c["template"], c["V_scan"], c["F_scan"], c["lm_template"], c["lm_scan"], QUICK, progress=lambda s: None)
    split = nicp(c["template"], V_u, F_u, c["lm_template"], c["lm_scan"], QUICK, progress=lambda s: None)
    matched = [step["matched_fraction"] for step in split[1]["steps"]]
    assert min(matched) > 0.5, matched
    assert matched == [step["matched_fraction"] for step in welded[1]["steps"]]
    np.testing.assert_array_equal(split[0].V, welded[0].V)


# --- files ------------------------------------------------------------------------------------

@pytest.fixture
def nicp_files(tmp_path: Path) -> dict:
    """A template folder, a scan and ground-truth-style landmark files in the workflow's layout."""
    V, F = ellipsoid(3)
    template = uv_template(V, F)
    tdir = tmp_path / "results" / SUBJECT / "template"
    write_obj(tdir / "template.obj", template, texture_name="texture.png")
    write_image(tdir / "mouth_mask.png", np.zeros((8, 8), dtype=np.float32))
    V_s, F_s = ellipsoid(4)
    V_s, F_s = crop_back(rigid_offset(bump(V_s)), F_s, z_min_mm=-30.0)
    scans = tmp_path / "scans"
    write_ply(scans / SUBJECT / f"{EXPRESSION}.ply", V_s, F_s)
    lm = front_landmarks(V)
    gt = tmp_path / "gt"
    (gt / SUBJECT).mkdir(parents=True)
    np.savez(gt / SUBJECT / f"{TEMPLATE_EXPRESSION}.npz", landmarks=V[lm])
    np.savez(gt / SUBJECT / f"{EXPRESSION}.npz", landmarks=rigid_offset(bump(V))[lm])
    return {"template_dir": tdir, "template": template, "scans": scans, "gt": gt, "lm": lm,
            "pattern": str(gt / "{subject}" / "{expression}.npz"), "out": tmp_path / "results" / SUBJECT / "nicp"}


def run(files: dict, progress=lambda s: None, **section) -> dict:
    """:func:`run_baseline` on the fixture's files, with ``QUICK_SECTION`` updated by ``section``."""
    section = {**QUICK_SECTION, "landmarks": files["pattern"], **section}
    return run_baseline(files["template_dir"], DataSource(scans_root=files["scans"]), SUBJECT, EXPRESSION,
                        files["out"] / f"{EXPRESSION}.obj", section, TEMPLATE_EXPRESSION, progress)


def test_run_baseline_writes_obj_and_log(nicp_files):
    lines = []
    log = run(nicp_files, progress=lines.append)
    out = nicp_files["out"] / f"{EXPRESSION}.obj"
    back = read_obj(out)
    t = nicp_files["template"]
    assert np.array_equal(back.F, t.F) and np.array_equal(back.UV, t.UV) and np.array_equal(back.F_uv, t.F_uv)
    assert back.texture is not None  # the MTL points at the template's texture.png
    assert "../template/texture.png" in out.with_suffix(".mtl").read_text()
    saved = json.loads(out.with_suffix(".json").read_text())
    assert saved["expression"] == EXPRESSION and len(saved["steps"]) == len(QUICK.steps) == len(log["steps"])
    assert {"stiffness", "mean_distance_mm", "iterations", "seconds"} <= set(saved["steps"][0])
    assert len(lines) == 1 + len(QUICK.steps)


def test_run_baseline_accepts_template_vertex_indices(nicp_files, tmp_path):
    idx_file = tmp_path / "tu_landmarks.txt"
    idx_file.write_text("\n".join(str(i) for i in nicp_files["lm"]) + "\n")
    log = run(nicp_files, template_landmarks=str(idx_file))
    assert log["template_landmarks_file"] == str(idx_file)
    assert np.array_equal(read_template_landmarks(idx_file), nicp_files["lm"])


def test_the_registry_runs_this_entry_point():
    assert method("nicp").run_function() is run_baseline


def test_bad_sections_are_named(nicp_files):
    with pytest.raises(InputError, match="baselines.nicp: unknown key.*landmark"):
        run(nicp_files, landmark="x")
    with pytest.raises(InputError, match="baselines.nicp.landmarks: NICP needs"):
        run(nicp_files, landmarks=None)
    with pytest.raises(InputError, match="baselines.nicp.settings: .*stifness"):
        run(nicp_files, settings={"stifness": 1})


def test_missing_landmark_file_is_named(nicp_files):
    with pytest.raises(InputError, match=r"2_smile\.npz: landmark file not found"):
        run(nicp_files, landmarks=str(nicp_files["gt"] / "{subject}" / "elsewhere" / "{expression}.npz"))


def test_wrong_landmark_count_is_named(nicp_files):
    path = nicp_files["gt"] / SUBJECT / f"{EXPRESSION}.npz"
    np.savez(path, landmarks=np.load(path)["landmarks"][:5])
    with pytest.raises(InputError, match=r"2_smile\.npz: 5 landmarks, but the template"):
        run(nicp_files)


def test_nan_landmarks_are_named(nicp_files):
    path = nicp_files["gt"] / SUBJECT / f"{EXPRESSION}.npz"
    P = np.load(path)["landmarks"]
    P[2, 1] = np.nan
    np.savez(path, landmarks=P)
    with pytest.raises(InputError, match=r"2_smile\.npz: landmarks contain NaN .*landmark 2"):
        run(nicp_files)


def test_landmarks_off_the_scan_are_refused(nicp_files):
    path = nicp_files["gt"] / SUBJECT / f"{EXPRESSION}.npz"
    np.savez(path, landmarks=np.load(path)["landmarks"] * 1000.0)  # metres taken for mm, say
    with pytest.raises(InputError, match=r"2_smile\.npz: landmarks lie a median .* off the scan"):
        run(nicp_files)


def test_empty_scan_is_named(nicp_files):
    scan = nicp_files["scans"] / SUBJECT / f"{EXPRESSION}.ply"
    scan.write_bytes(b"")
    with pytest.raises(InputError, match=r"2_smile\.ply: scan file is empty"):
        run(nicp_files)


def test_scan_in_other_units_is_refused(nicp_files):
    V, F = ellipsoid(3)
    write_ply(nicp_files["scans"] / SUBJECT / f"{EXPRESSION}.ply", V / 1000.0, F)  # metres
    with pytest.raises(InputError, match=r"2_smile\.ply: bounding-box diagonal"):
        run(nicp_files)


def test_empty_arrays_are_refused_by_nicp(bumped_case):
    c = bumped_case
    with pytest.raises(InputError, match="empty mesh"):
        nicp(c["template"], np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), c["lm_template"], c["lm_scan"],
             QUICK, progress=lambda s: None)


def test_template_landmark_indices_out_of_range_are_refused(bumped_case):
    c = bumped_case
    bad = c["lm_template"].copy()
    bad[0] = len(c["template"].V)
    with pytest.raises(InputError, match="out of range"):
        nicp(c["template"], c["V_scan"], c["F_scan"], bad, c["lm_scan"], QUICK, progress=lambda s: None)


def test_settings_are_logged(registered):
    _, log = registered
    assert log["settings"]["steps"][0] == asdict(NicpSettings().steps[0])
    json.dumps(log)  # JSON-able as is
    assert replace(NicpSettings(), gamma=2.0).gamma == 2.0


def test_settings_from_config():
    cfg = {"steps": [[0.1, 1, 3], {"stiffness": 0.05, "landmark_weight": 0.5, "max_iterations": 4}],
           "max_distance_mm": 5}
    s = NicpSettings.from_config(cfg)
    assert s.steps == (NicpStep(0.1, 1.0, 3), NicpStep(0.05, 0.5, 4)) and s.max_distance_mm == 5
    assert NicpSettings.from_config(None) == NicpSettings()
    with pytest.raises(InputError, match=r"config: unknown key\(s\) stifness; known: steps"):
        NicpSettings.from_config({"stifness": 1})
    with pytest.raises(InputError, match=r"config: steps\[0\]: expected \[stiffness, landmark_weight, max_iterations\]"):
        NicpSettings.from_config({"steps": [[0.1, 1]]})
    with pytest.raises(InputError, match=r"config: steps\[1\]: stiffness must be > 0"):
        NicpSettings.from_config({"steps": [[0.1, 1, 3], [0, 1, 3]]})
    with pytest.raises(InputError, match="config: NICP needs at least one step"):
        NicpSettings.from_config({"steps": []})
