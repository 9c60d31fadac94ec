import json

import numpy as np
import pytest
import trimesh

from gpja.errors import InputError
from gpja.io import read_npz, write_npz
from gpja.mesh import TexturedMesh, read_ply, write_obj, write_ply
from gpja.metrics.correspondence import (correspondence_error, correspondence_error_files, correspondence_reference,
                                         material_coordinates, material_positions, score_correspondence)
from tests.tolerances import CORRESPONDENCE_EXACT_MM

SUBJECT = "S01"
EXPRESSION = "1_neutral"
TEMPLATE_EXPRESSION = "3_mouth_stretch"


def hemisphere(radius=100.0, subdivisions=4):
    """The rest surface: an open upper hemisphere (its rim is the scan's boundary)."""
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    return V, F[V[F].mean(axis=1)[:, 2] > 0]


def grid(size=200.0, step=5.0):
    """The rest surface: a flat square patch in z = 0, centred on the origin."""
    ticks = np.arange(-size / 2, size / 2 + step / 2, step)
    x, y = np.meshgrid(ticks, ticks, indexing="ij")
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    k = len(ticks)
    i, j = np.meshgrid(np.arange(k - 1), np.arange(k - 1), indexing="ij")
    a = (i * k + j).ravel()
    F = np.concatenate([np.column_stack([a, a + k, a + 1]), np.column_stack([a + 1, a + k, a + k + 1])])
    return V, F


def points_on(V, F, faces, seed=0):
    """One random point inside each of ``faces`` of the rest surface (not on scan vertices)."""
    w = np.random.default_rng(seed).dirichlet([2.0, 2.0, 2.0], size=len(faces))
    return np.einsum("qk,qkc->qc", w, V[F[faces]])


#: Expressions as affine maps x -> A x + b: they keep triangles flat, so the scans
#: below are exact and the interpolated rest coordinates too.
AFFINE = {TEMPLATE_EXPRESSION: (np.array([[1.1, 0.1, 0.0], [0.0, 0.9, 0.05], [0.0, 0.0, 1.2]]), np.array([2.0, -30.0, 5.0])),
          EXPRESSION: (np.array([[0.95, -0.1, 0.0], [0.1, 1.05, 0.0], [0.05, 0.0, 0.8]]), np.array([-4.0, 10.0, 0.0]))}


def deform(X, expression):
    A, b = AFFINE[expression]
    return X @ A.T + b


def scans_of(V, F):
    """Scan (V, F) and rest coordinates of both expressions: the rest surface deformed."""
    return {e: ((deform(V, e), F), V) for e in AFFINE}


def test_one_reference_scores_many_meshes_as_each_scored_alone():
    """``gpja stages`` prepares the expression's side once and scores every stage against it: the same numbers,
    bit for bit, as a whole correspondence_error per mesh, and the reference is not changed by a scoring."""
    V, F = hemisphere()
    scans = scans_of(V, F)
    inner = np.flatnonzero(V[F].mean(axis=1)[:, 2] > 20.0)
    P = points_on(V, F, inner)
    V_template = deform(P, TEMPLATE_EXPRESSION)
    landmarks = deform(points_on(V, F, inner[:68], seed=3), TEMPLATE_EXPRESSION)
    reference = correspondence_reference(V_template, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION],
                                         landmarks_rest=landmarks)
    frozen = reference.m_tpl.copy()
    rng = np.random.default_rng(4)
    for shift in (0.0, 0.3, 1.5):  # a registration's stages, each a little further off
        V_reg = deform(P, EXPRESSION) + shift * rng.normal(size=P.shape)
        alone = correspondence_error(V_reg, V_template, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION],
                                     landmarks_rest=landmarks)
        shared = score_correspondence(V_reg, reference)
        assert alone.keys() == shared.keys()
        for key, value in alone.items():
            if isinstance(value, np.ndarray):
                np.testing.assert_array_equal(shared[key], value, err_msg=key)
            else:
                assert shared[key] == value, key
    np.testing.assert_array_equal(reference.m_tpl, frozen)
    with pytest.raises(InputError, match="fewer|vertices"):
        score_correspondence(V_template[:10], reference)


def test_exact_registration_has_zero_error():
    V, F = hemisphere()
    scans = scans_of(V, F)
    inner = np.flatnonzero(V[F].mean(axis=1)[:, 2] > 20.0)  # away from the rim
    P = points_on(V, F, inner)
    V_template = deform(P, TEMPLATE_EXPRESSION)
    refined = deform(points_on(V, F, inner[:50], seed=1), EXPRESSION)  # appended by refinement: ignored
    V_reg = np.concatenate([deform(P, EXPRESSION), refined])
    out = correspondence_error(V_reg, V_template, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION])
    assert out["mean_mm"] < CORRESPONDENCE_EXACT_MM and out["max_mm"] < CORRESPONDENCE_EXACT_MM
    assert out["n_used"] == len(P) == out["n_template_vertices"] and out["fraction_used"] == 1.0
    assert out["vertex_error_mm"].shape == (len(P),) and out["vertex_used"].all()


def test_shift_along_the_surface_is_measured_in_rest_space():
    V, F = grid()
    scans = {TEMPLATE_EXPRESSION: ((V, F), V),                       # template expression = rest
             EXPRESSION: ((V * [2.0, 1.0, 1.0], F), V)}              # expression stretches x by 2
    P = points_on(V, F, np.flatnonzero(np.abs(V[F].mean(axis=1)[:, :2]).max(axis=1) < 80.0))
    V_reg = P * [2.0, 1.0, 1.0] + [0.6, 0.0, 0.0]                    # slid 0.6 mm in expression space
    out = correspondence_error(V_reg, P, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION])
    # 0.6 mm along a 2x stretch is 0.3 mm of material
    for key in ("mean_mm", "median_mm", "p95_mm", "max_mm"):
        assert out[key] == pytest.approx(0.3, abs=CORRESPONDENCE_EXACT_MM), key
    np.testing.assert_allclose(out["vertex_error_mm"], 0.3, atol=CORRESPONDENCE_EXACT_MM)


def test_vertices_off_the_scan_are_excluded():
    V, F = grid()
    scans = {e: ((V, F), V) for e in AFFINE}
    P = np.array([[0.0, 0.0, 0.0], [10.0, 3.0, 0.5],                  # on the scan, or 0.5 mm above it
                  [10.0, 3.0, 3.0],                                   # 3 mm above: past the 2 mm cap
                  [130.0, 0.0, 0.0]])                                 # beyond the patch: projects to its rim
    V_reg = P + [0.2, 0.0, 0.0]
    out = correspondence_error(V_reg, P, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION])
    np.testing.assert_array_equal(out["vertex_used"], [True, True, False, False])
    assert out["n_used"] == 2 and out["fraction_used"] == 0.5
    assert np.isnan(out["vertex_error_mm"][2:]).all()
    assert out["mean_mm"] == pytest.approx(0.2, abs=CORRESPONDENCE_EXACT_MM)
    wider = correspondence_error(V_reg, P, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION], max_distance_mm=5.0)
    np.testing.assert_array_equal(wider["vertex_used"], [True, True, True, False])  # the rim rule still holds
    with pytest.raises(InputError, match="no template vertex lies within"):
        correspondence_error(V_reg[2:], P[2:], *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION])


# --- position error (the ground truth's side) ---------------------------------------------

def test_material_positions_inverts_material_coordinates():
    V, F = hemisphere()
    scans = scans_of(V, F)
    P = points_on(V, F, np.flatnonzero(V[F].mean(axis=1)[:, 2] > 20.0))
    (scan, rest) = scans[EXPRESSION]
    X = deform(P, EXPRESSION)                                        # on the expression's scan
    material, usable = material_coordinates(X, scan, rest, 2.0)
    assert usable.all()
    where, present, hidden_mm = material_positions(material, scan, rest)
    assert present.all() and (hidden_mm < CORRESPONDENCE_EXACT_MM).all()
    np.testing.assert_allclose(where, X, atol=CORRESPONDENCE_EXACT_MM)
    np.testing.assert_allclose(material, P, atol=CORRESPONDENCE_EXACT_MM)


def test_position_error_counts_vertices_that_left_the_scan():
    V, F = grid()
    scans = {e: ((V, F), V) for e in AFFINE}                         # every expression = rest: the flat patch
    P = np.array([[0.0, 0.0, 0.0], [10.0, 3.0, 0.0], [-20.0, 5.0, 0.0]])
    # vertex 0 exact, vertex 1 slid 0.4 mm along the patch, vertex 2 sunk 6 mm below it (and 1 mm sideways)
    V_reg = P + [[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [1.0, 0.0, -6.0]]
    out = correspondence_error(V_reg, P, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION])
    # the correspondence error drops the sunk vertex (past the 2 mm cap); the position error measures it
    np.testing.assert_array_equal(out["vertex_used"], [True, True, False])
    np.testing.assert_allclose(out["vertex_position_error_mm"], [0.0, 0.4, np.hypot(1.0, 6.0)],
                               atol=CORRESPONDENCE_EXACT_MM)
    position = out["position"]
    assert position["n_used"] == 3 and position["fraction_used"] == 1.0
    assert position["median_mm"] == pytest.approx(0.4, abs=CORRESPONDENCE_EXACT_MM)
    assert position["max_mm"] == pytest.approx(np.hypot(1.0, 6.0), abs=CORRESPONDENCE_EXACT_MM)
    assert out["max_mm"] == pytest.approx(0.4, abs=CORRESPONDENCE_EXACT_MM)


def test_position_error_skips_material_hidden_in_the_expression():
    V, F = grid()
    # the expression's scan lacks the strip x in (-20, 20): that material is hidden there (a closed mouth's inside)
    centre = V[F].mean(axis=1)
    visible = F[np.abs(centre[:, 0]) > 20.0]
    scans = {TEMPLATE_EXPRESSION: ((V, F), V), EXPRESSION: ((V + [0.0, 0.0, 2.0], visible), V)}
    P = np.array([[-50.0, 0.0, 0.0], [0.0, 0.0, 0.0], [50.0, 10.0, 0.0]])
    V_reg = P + [0.0, 0.0, 2.0] + [[0.3, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.3, 0.0]]
    out = correspondence_error(V_reg, P, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION])
    e = out["vertex_position_error_mm"]
    assert np.isnan(e[1]) and out["position"]["n_used"] == 2
    np.testing.assert_allclose(e[[0, 2]], 0.3, atol=CORRESPONDENCE_EXACT_MM)


# --- floor (the score's lower bound) ------------------------------------------------------

def hidden_strip_case():
    """The flat patch; the expression's scan lacks the strip |x| < 20 (its material hidden, a closed lid)."""
    V, F = grid()
    centre = V[F].mean(axis=1)
    scans = {TEMPLATE_EXPRESSION: ((V, F), V), EXPRESSION: ((V + [0.0, 0.0, 2.0], F[np.abs(centre[:, 0]) > 20.0]), V)}
    return V, F, scans


def test_floor_is_the_distance_to_the_nearest_material_shown():
    _, _, scans = hidden_strip_case()
    # material at x = -50 (shown), 0 and 12 (hidden: 20 and 8 mm from the strip's edges' nearest), 30 (shown)
    P = np.array([[-50.0, 0.0, 0.0], [0.0, 5.0, 0.0], [12.0, -5.0, 0.0], [30.0, 10.0, 0.0]])
    # nearly the best registration: every vertex on its own material, the hidden ones 1 mm past the nearest edge
    # of the strip (on the edge itself the projection is on the scan's boundary, which the score drops)
    best = np.array([[-50.0, 0.0, 2.0], [-21.0, 5.0, 2.0], [21.0, -5.0, 2.0], [30.0, 10.0, 2.0]])
    out = correspondence_error(best, P, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION])
    np.testing.assert_allclose(out["vertex_floor_mm"], [0.0, 20.0, 8.0, 0.0], atol=CORRESPONDENCE_EXACT_MM)
    np.testing.assert_allclose(out["vertex_error_mm"], [0.0, 21.0, 9.0, 0.0], atol=CORRESPONDENCE_EXACT_MM)
    floor = out["floor"]
    assert floor["n_used"] == 4 and floor["median_mm"] == pytest.approx(4.0, abs=CORRESPONDENCE_EXACT_MM)
    assert floor["mean_mm"] == pytest.approx(7.0, abs=CORRESPONDENCE_EXACT_MM)
    # a vertex's floor is the template's and the ground truth's, the same for any registration; the statistics
    # are over the scored vertices: a hidden vertex that leaves the scan (2.5 mm above it) takes its floor along
    moved = correspondence_error(best + [[0.0, 0.0, 0.0], [0.0, 0.0, 2.5], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], P,
                                 *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION])
    np.testing.assert_array_equal(moved["vertex_floor_mm"], out["vertex_floor_mm"])
    assert moved["floor"]["n_used"] == 3 and moved["floor"]["max_mm"] == pytest.approx(8.0, abs=CORRESPONDENCE_EXACT_MM)


def test_no_registration_scores_below_its_floor():
    _, _, scans = hidden_strip_case()
    rng = np.random.default_rng(3)
    P = np.column_stack([rng.uniform(-60, 60, 300), rng.uniform(-60, 60, 300), np.zeros(300)])
    for shift in (0.0, 4.0, 15.0):
        V_reg = P + [shift, 0.0, 2.0] + np.column_stack([rng.normal(0, 2, (300, 2)), np.zeros(300)])
        out = correspondence_error(V_reg, P, *scans[EXPRESSION], *scans[TEMPLATE_EXPRESSION])
        used = out["vertex_used"]
        assert used.sum() > 100
        assert (out["vertex_error_mm"][used] >= out["vertex_floor_mm"][used] - CORRESPONDENCE_EXACT_MM).all()
        # over the same vertices, so no statistic of the score is below the floor's
        for key in ("mean_mm", "median_mm", "p95_mm"):
            assert out[key] >= out["floor"][key] - CORRESPONDENCE_EXACT_MM


# --- files --------------------------------------------------------------------------------

def write_subject(root, V, F, P):
    """Synthetic layout of the hemisphere case: scans, ground truth, template and an exact registration."""
    for e in AFFINE:
        write_ply(root / "scans" / SUBJECT / f"{e}.ply", deform(V, e), F)
        write_npz(root / "gt" / SUBJECT / f"{e}.npz", scan_rest_coords=V, sh=np.zeros((9, 3)))
    # meshes need faces: the template's "vertices" are the points, faces are arbitrary triangles over them
    F_tpl = np.arange(len(P) - len(P) % 3).reshape(-1, 3)
    template, registered = root / "template" / "template.obj", root / "gpja" / f"{EXPRESSION}.obj"
    write_obj(template, TexturedMesh(deform(P, TEMPLATE_EXPRESSION), F_tpl), texture_name=None)
    write_obj(registered, TexturedMesh(deform(P, EXPRESSION), F_tpl), texture_name=None)
    return template, registered


def run_files(root, template, registered, **kw):
    return correspondence_error_files(registered, template, root / "scans", root / "gt", SUBJECT, EXPRESSION, **kw)


def test_files_exact_registration_and_error_npz(tmp_path):
    V, F = hemisphere()
    P = points_on(V, F, np.flatnonzero(V[F].mean(axis=1)[:, 2] > 20.0))
    template, registered = write_subject(tmp_path, V, F, P)
    errors = tmp_path / "metrics" / f"{EXPRESSION}.correspondence.npz"
    out = run_files(tmp_path, template, registered, errors_path=errors)
    json.dumps(out)
    assert out["mean_mm"] < CORRESPONDENCE_EXACT_MM and out["fraction_used"] == 1.0
    assert out["template_expression"] == TEMPLATE_EXPRESSION and out["errors"] == str(errors)
    arrays = read_npz(errors)
    assert arrays["vertex_error_mm"].shape == (len(P),) and arrays["vertex_used"].dtype == bool
    # every material is shown in the expression: the floor is 0 everywhere
    assert arrays["vertex_floor_mm"].shape == (len(P),) and np.nanmax(arrays["vertex_floor_mm"]) < CORRESPONDENCE_EXACT_MM
    assert out["floor"]["median_mm"] < CORRESPONDENCE_EXACT_MM


def test_files_break_the_error_down_by_facial_region(tmp_path):
    from gpja.data.synthetic.head import HeadParams
    from gpja.data.synthetic.landmarks import rest_landmark_guesses
    from gpja.metrics.regions import REGIONS, UNLABELLED, label_regions

    V, F = hemisphere()
    P = points_on(V, F, np.flatnonzero(V[F].mean(axis=1)[:, 2] > 20.0))
    template, registered = write_subject(tmp_path, V, F, P)
    # landmarks in the hemisphere's rest frame: the synthetic head's, which sit on its front
    L = rest_landmark_guesses(HeadParams())
    gt = tmp_path / "gt" / SUBJECT / f"{TEMPLATE_EXPRESSION}.npz"
    write_npz(gt, scan_rest_coords=V, landmarks_rest=L)
    # the registration slides the points below y = -40 by 3 mm along the surface (in rest space: x)
    moved = P.copy()
    low = P[:, 1] < -40.0
    moved[low] = P[low] + [3.0, 0.0, 0.0]
    moved[low] *= 100.0 / np.linalg.norm(moved[low], axis=1, keepdims=True)
    write_obj(registered, TexturedMesh(deform(moved, EXPRESSION), np.arange(len(P) - len(P) % 3).reshape(-1, 3)),
              texture_name=None)
    errors = tmp_path / "errors.npz"
    out = run_files(tmp_path, template, registered, errors_path=errors)
    json.dumps(out)
    regions = out["regions"]
    assert list(regions) == list(REGIONS)
    assert sum(r["count"] for r in regions.values()) == out["n_used"]
    arrays = read_npz(errors)
    labels = arrays["vertex_region"]
    assert list(arrays["region_names"]) == list(REGIONS) and labels.dtype == np.int8
    np.testing.assert_array_equal(labels[arrays["vertex_used"]], label_regions(P, L)[arrays["vertex_used"]])
    assert (labels[~arrays["vertex_used"]] == UNLABELLED).all()
    # every region's scores are those of its vertices
    e = arrays["vertex_error_mm"]
    for k, name in enumerate(REGIONS):
        mine = e[labels == k]
        if mine.size:
            assert regions[name]["median_mm"] == pytest.approx(np.median(mine))
            assert regions[name]["mean_mm"] == pytest.approx(mine.mean())
    # the position error has its own breakdown, by the same labels (here every vertex's material is present)
    position = out["position"]["regions"]
    p = arrays["vertex_position_error_mm"]
    assert sum(r["count"] for r in position.values()) == out["position"]["n_used"] == np.isfinite(p).sum()
    assert position["mouth"]["count"] >= regions["mouth"]["count"]
    # and so has the floor (nothing hidden here: 0 in every region)
    assert list(out["floor"]["regions"]) == list(REGIONS)
    assert all(r["median_mm"] is None or r["median_mm"] < CORRESPONDENCE_EXACT_MM for r in out["floor"]["regions"].values())
    # without landmarks_rest there is no breakdown
    write_npz(gt, scan_rest_coords=V)
    assert "regions" not in run_files(tmp_path, template, registered, errors_path=errors)
    assert "vertex_region" not in read_npz(errors)


def test_bad_inputs_name_the_file(tmp_path):
    V, F = hemisphere(subdivisions=3)
    P = points_on(V, F, np.flatnonzero(V[F].mean(axis=1)[:, 2] > 20.0))
    template, registered = write_subject(tmp_path, V, F, P)
    gt = tmp_path / "gt" / SUBJECT / f"{EXPRESSION}.npz"

    write_npz(gt, scan_rest_coords=V[:-1])
    shapes = f"shape \\({len(V) - 1}, 3\\), expected \\({len(V)}, 3\\)"
    with pytest.raises(InputError, match=f"{gt}: scan_rest_coords has {shapes}"):
        run_files(tmp_path, template, registered)
    write_npz(gt, sh=np.zeros((9, 3)))
    with pytest.raises(InputError, match=f"{gt}: no 'scan_rest_coords' array"):
        run_files(tmp_path, template, registered)
    gt.unlink()
    with pytest.raises(InputError, match=f"{gt}: file not found"):
        run_files(tmp_path, template, registered)
    write_npz(gt, scan_rest_coords=V)

    short = tmp_path / "short.obj"
    write_obj(short, TexturedMesh(deform(P[:30], EXPRESSION), np.arange(30).reshape(-1, 3)), texture_name=None)
    with pytest.raises(InputError, match=f"{short}: 30 vertices, fewer than the template's {len(P)}"):
        run_files(tmp_path, template, short)
    with pytest.raises(InputError, match="missing.obj: mesh file not found"):
        run_files(tmp_path, template, tmp_path / "missing.obj")
    with pytest.raises(InputError, match=f"{tmp_path / 'scans' / SUBJECT / '2_smile.ply'}: scan file not found"):
        correspondence_error_files(registered, template, tmp_path / "scans", tmp_path / "gt", SUBJECT, "2_smile")


# --- a real synthetic subject -------------------------------------------------------------

@pytest.mark.slow
def test_synthetic_subject_ground_truth_registration(tmp_path):
    """Template = the template expression's scan; registration = the same material points
    mapped by the true expression field: the error must vanish where both scans have data."""
    from gpja.data.synthetic import SynthConfig, map_to_expression, synthesize_subject
    from gpja.data.synthetic.head import HeadParams

    cfg = SynthConfig(seed=5, image_size=32, supersample=1, scan_voxel_mm=1.2, render_voxel_mm=2.0,
                      raw_variant=False, expressions=(EXPRESSION, TEMPLATE_EXPRESSION))
    roots = {k: tmp_path / k for k in ("images", "scans", "gt")}
    synthesize_subject(SUBJECT, 1, cfg, roots["images"], roots["scans"], roots["gt"], tmp_path / "raw",
                       tmp_path / "sheet.png", progress=lambda msg: None)
    head = HeadParams(**json.loads((roots["gt"] / SUBJECT / "subject.json").read_text())["identity"])
    V_t, F_t = read_ply(roots["scans"] / SUBJECT / f"{TEMPLATE_EXPRESSION}.ply")
    rest = read_npz(roots["gt"] / SUBJECT / f"{TEMPLATE_EXPRESSION}.npz")["scan_rest_coords"]
    template, registered = tmp_path / "template.obj", tmp_path / f"{EXPRESSION}.obj"
    write_obj(template, TexturedMesh(V_t, F_t), texture_name=None)
    write_obj(registered, TexturedMesh(map_to_expression(rest, head, EXPRESSION), F_t), texture_name=None)
    out = correspondence_error_files(registered, template, roots["scans"], roots["gt"], SUBJECT, EXPRESSION)
    assert out["fraction_used"] > 0.5  # the face, seen in both expressions
    assert out["median_mm"] < CORRESPONDENCE_EXACT_MM and out["p95_mm"] < 0.05
