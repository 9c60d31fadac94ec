"""gpja.metrics.turns: the artist mesh's faces turned over between adjacent expressions, and the true motion's."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from gpja.cli import main
from gpja.data.synthetic.expressions import map_to_expression
from gpja.data.synthetic.head import EYE_RADIUS_MM
from gpja.errors import InputError
from gpja.io import read_npz, write_json
from gpja.mesh import TexturedMesh, read_ply, write_obj
from gpja.metrics.oracle import subject_identity
from gpja.metrics.turns import carry_through_truth, hop_turns, invert_map, map_jacobians, tree_hops
from tests.data.synthetic.conftest import TINY, run_tiny
from tests.tolerances import MAP_INVERSE_MM, MAP_JACOBIAN_RELATIVE

SQUARE_V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])


def affine(A, b):
    return lambda X: X @ A.T + b


def twist(X, turns_per_mm=0.01):
    """Rotation about the z axis by an angle growing with z: smooth, invertible, not affine."""
    a = 2 * np.pi * turns_per_mm * X[:, 2]
    c, s = np.cos(a), np.sin(a)
    return np.column_stack([c * X[:, 0] - s * X[:, 1], s * X[:, 0] + c * X[:, 1], X[:, 2]])


def rotation_x(deg):
    a = np.radians(deg)
    return np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])


# --- the maps ------------------------------------------------------------------------------------------------

def test_map_jacobians_of_an_affine_map_are_its_matrix():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    J = map_jacobians(affine(A, np.array([1.0, -2.0, 5.0])), rng.normal(scale=100.0, size=(7, 3)))
    np.testing.assert_allclose(J, np.broadcast_to(A, (7, 3, 3)), rtol=MAP_JACOBIAN_RELATIVE, atol=MAP_JACOBIAN_RELATIVE)


def test_invert_map_solves_an_affine_map_from_anywhere():
    rng = np.random.default_rng(1)
    A, b = rng.normal(size=(3, 3)) + 3 * np.eye(3), rng.normal(size=3)
    R = rng.normal(scale=50.0, size=(20, 3))
    found, residual = invert_map(affine(A, b), affine(A, b)(R), rng.normal(scale=50.0, size=(20, 3)))
    np.testing.assert_allclose(found, R, atol=MAP_INVERSE_MM)
    assert residual.max() < MAP_INVERSE_MM


def test_invert_map_undoes_a_twist():
    rng = np.random.default_rng(2)
    R = rng.uniform(-60, 60, (50, 3))
    X = twist(R)
    found, residual = invert_map(twist, X, X)  # the guess: the image itself (a 0.6-turn twist away)
    np.testing.assert_allclose(found, R, atol=MAP_INVERSE_MM)
    assert residual.max() < MAP_INVERSE_MM


def test_invert_map_damps_steps_that_overshoot():
    """Newton on arctan overshoots from farther than 1.39 of its scale; the halved steps converge."""
    def squash(X):
        return 10.0 * np.arctan(X / 10.0)

    R = np.array([[0.0, 3.0, -5.0], [1.0, 0.0, 2.0]])
    found, residual = invert_map(squash, squash(R), np.full((2, 3), 40.0))
    np.testing.assert_allclose(found, R, atol=MAP_INVERSE_MM)
    assert residual.max() < MAP_INVERSE_MM


# --- the counts ----------------------------------------------------------------------------------------------

def test_hop_turns_counts_a_face_folded_over_and_not_a_rotated_one():
    folded = SQUARE_V.copy()
    folded[3] = [2.0, 0.5, 0.0]  # face 1 (0, 2, 3) now winds the other way: its normal -z
    rotated = SQUARE_V @ rotation_x(80.0).T  # both faces turn by 80 degrees: not over
    carried = {"a": SQUARE_V, "b": folded, "c": rotated}
    hops = [("a", "b"), ("a", "c"), ("b", "a")]
    observed = np.array([True, False])
    rows = hop_turns(carried, SQUARE_F, hops, observed)
    assert [(r["turned"], r["turned_observed"]) for r in rows] == [(1, 0), (0, 0), (1, 0)]
    assert [r["turned_faces"] for r in rows] == [[1], [], [1]]
    assert "truth_turned" not in rows[0]
    # the truth: the rotation turns nothing, the fold face 1; both count it once
    truth = {"a": SQUARE_V, "b": rotated, "c": folded}
    rows = hop_turns(carried, SQUARE_F, hops, np.array([False, True]), truth)
    assert [(r["truth_turned"], r["truth_turned_observed"], r["both"]) for r in rows] == [(0, 0, 0), (1, 1, 0), (0, 0, 0)]
    assert [r["truth_turned_faces"] for r in rows] == [[], [1], []]
    assert rows[0]["turned_observed"] == 1 and rows[0]["faces_compared"] == 2
    # the truth turns the other face: not the same face, but next to it (0.47 mm apart); 100x larger, 47 mm apart
    other = SQUARE_V.copy()
    other[1] = [-1.0, 0.5, 0.0]  # face 0 (0, 1, 2) winds the other way
    row, = hop_turns(carried, SQUARE_F, [("a", "b")], observed, {"a": SQUARE_V, "b": other})
    assert (row["turned_faces"], row["truth_turned_faces"], row["both"], row["near_truth"]) == ([1], [0], 0, 1)
    row, = hop_turns(carried, SQUARE_F, [("a", "b")], observed, {"a": SQUARE_V * 100, "b": other * 100})
    assert row["near_truth"] == 0
    # a face whose vertex the truth could not place is left out of the truth's columns
    rows = hop_turns(carried, SQUARE_F, hops, observed, truth, np.array([True, True, True, False]))
    assert [r["truth_turned"] for r in rows] == [0, 0, 0] and rows[0]["faces_compared"] == 1


def test_tree_hops_follow_the_order_and_skip_the_root():
    order = {"root": "r", "order": ["r", "a", "b", "c"], "parent": {"r": None, "a": "r", "b": "a", "c": "a"}}
    assert tree_hops(order) == [("r", "a"), ("a", "b"), ("a", "c")]
    with pytest.raises(ValueError, match="'order'"):
        tree_hops({"parent": {}})


# --- the true motion, on a tiny synthetic subject ------------------------------------------------------------

#: The tiny subject with a closing eye as well.
EXPRESSIONS = ("1_neutral", "3_mouth_stretch", "18_eye_closed", "2_smile")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("turns_tiny")
    roots, _ = run_tiny(root, cfg=replace(TINY, expressions=EXPRESSIONS), subject="S01")
    return roots


def test_the_true_motion_carries_the_scan_to_its_ground_truth(tiny):
    source, other = "3_mouth_stretch", "1_neutral"  # from the mouth-open expression to the neutral
    scan, _ = read_ply(tiny["scans"] / "S01" / f"{source}.ply")
    rest = read_npz(tiny["gt"] / "S01" / f"{source}.npz")["scan_rest_coords"]
    head = subject_identity(tiny["gt"], "S01")
    pick = np.arange(0, len(scan), 97)
    # on the scan, and 1.5 mm off it (points of space a template's bust has): both placed
    off = scan[pick] + np.array([0.0, 0.0, 1.5])
    V = np.concatenate([scan[pick], off])
    carried, found, distance = carry_through_truth(V, tiny["gt"], tiny["scans"], "S01", source, [source, other])
    assert found.all()
    assert distance[: len(pick)].max() == 0.0 and distance[len(pick):].min() > 0.0
    np.testing.assert_allclose(carried[source], V, atol=1e-6)
    np.testing.assert_allclose(carried[other][: len(pick)], map_to_expression(rest[pick], head, other), atol=1e-6)


def test_the_true_motion_turns_the_lids_and_the_open_mouths_inner_lip_and_nothing_else(tiny):
    """Regression case: the template expression's scan (open mouth and eyes, a 0.8 mm triangulation) carried by the
    true motion. Closing the eyes turns faces over in a band along the upper lids (the skin between the lid's margin
    and the eyeball folds under the closing lid); closing the mouth straight from the open one turns the open mouth's
    inner lower lip over; the smile turns none."""
    V, F = read_ply(tiny["scans"] / "S01" / "3_mouth_stretch.ply")
    carried, found, _ = carry_through_truth(V, tiny["gt"], tiny["scans"], "S01", "3_mouth_stretch", EXPRESSIONS)
    assert found.all()
    eyes, mouth, smile = hop_turns(carried, F, [("1_neutral", "18_eye_closed"), ("3_mouth_stretch", "1_neutral"),
                                                ("1_neutral", "2_smile")], np.ones(len(F), dtype=bool))
    assert eyes["turned"] > 100 and mouth["turned"] > 10 and smile["turned"] == 0
    head = subject_identity(tiny["gt"], "S01")
    # where on the template expression's scan: above an eye's centre, within the shell the generator's lid turns
    centres = np.array([head.eye_center(s) for s in (-1, 1)])
    turned = V[F[eyes["turned_faces"]]].mean(axis=1)
    offset = turned[:, None, :] - centres[None, :, :]
    nearest = offset[np.arange(len(turned)), np.argmin(np.linalg.norm(offset, axis=2), axis=1)]
    assert np.linalg.norm(nearest, axis=1).max() < EYE_RADIUS_MM + 16.0 and (nearest[:, 1] > 0).all()
    # between the mouth's corners, below its rest height (the dropped jaw's lower lip)
    turned = V[F[mouth["turned_faces"]]].mean(axis=1)
    assert (np.abs(turned[:, 0]) < head.mouth_half_width + 5.0).all()
    assert (turned[:, 1] < head.mouth_y).all() and (turned[:, 1] > head.mouth_y - 40.0).all()


def test_carry_through_truth_names_a_missing_or_mismatched_file(tiny, tmp_path):
    V = read_ply(tiny["scans"] / "S01" / "3_mouth_stretch.ply")[0][:10]
    with pytest.raises(InputError, match="subject.json"):
        carry_through_truth(V, tmp_path, tiny["scans"], "S01", "3_mouth_stretch", ["1_neutral"])
    bad = tmp_path / "gt" / "S01"
    bad.mkdir(parents=True)
    (bad / "subject.json").write_text((tiny["gt"] / "S01" / "subject.json").read_text())
    np.savez(bad / "3_mouth_stretch.npz", scan_rest_coords=np.zeros((5, 3)))
    with pytest.raises(InputError, match="5 rest points"):
        carry_through_truth(V, tmp_path / "gt", tiny["scans"], "S01", "3_mouth_stretch", ["1_neutral"])


# --- gpja turns ------------------------------------------------------------------------------------------------

def write_case(tmp_path, moved: np.ndarray | None = None):
    """A template folder (one square, every texel observed), an artist mesh = the square, two expressions."""
    from gpja.io import write_image
    from gpja.results import OBSERVED_TEXELS_FILE

    uv = SQUARE_V[:, :2]
    template = tmp_path / "template"
    write_obj(template / "template.obj", TexturedMesh(SQUARE_V * 100, SQUARE_F, uv, SQUARE_F))
    write_image(template / OBSERVED_TEXELS_FILE, np.full((8, 8), 255, np.uint8))
    write_obj(tmp_path / "artist.obj", TexturedMesh(SQUARE_V * 100, SQUARE_F, uv, SQUARE_F))
    folded = SQUARE_V * 100 if moved is None else moved
    write_obj(tmp_path / "b.obj", TexturedMesh(folded, SQUARE_F, uv, SQUARE_F))
    write_json(tmp_path / "order.json", {"root": "a", "order": ["a", "b"], "parent": {"a": None, "b": "a"}})
    return ["--subject", "S01", "--artist", str(tmp_path / "artist.obj"), "--order", str(tmp_path / "order.json"),
            "--template-dir", str(template), "--output", str(tmp_path / "turns.json")]


def test_gpja_turns_writes_the_count_of_each_hop(tmp_path):
    folded = SQUARE_V * 100
    folded[3] = [200.0, 50.0, 0.0]
    args = write_case(tmp_path, folded)
    assert main(["turns", *args, "--meshes", f"a={tmp_path / 'artist.obj'}", f"b={tmp_path / 'b.obj'}"]) == 0
    log = json.loads((tmp_path / "turns.json").read_text())
    assert log["hops"] == [{"parent": "a", "expression": "b", "turned": 1, "turned_observed": 1, "turned_faces": [1]}]
    assert log["faces"] == 2 and log["observed_faces"] == 2 and log["truth"] is None


def test_gpja_turns_exits_2_naming_the_bad_input_and_writes_nothing(tmp_path, capsys):
    args = write_case(tmp_path)
    write_obj(tmp_path / "other.obj", TexturedMesh(SQUARE_V[:3] * 100, SQUARE_F[:1]))
    meshes = ["--meshes", f"a={tmp_path / 'artist.obj'}", f"b={tmp_path / 'b.obj'}"]
    cases = [(["--meshes", f"a={tmp_path / 'artist.obj'}"], "order.json: expression 'b' of the tree has no re-parametrised mesh"),
             (["--meshes", f"a={tmp_path / 'artist.obj'}", f"b={tmp_path / 'other.obj'}"],
              "other.obj: not in the artist mesh's topology"),
             ([*meshes, "--ground-truth-root", str(tmp_path)], "give the ground truth and the scans together"),
             ([*meshes, "--ground-truth-root", str(tmp_path), "--scans-root", str(tmp_path)], "subject.json: ")]
    for extra, message in cases:
        capsys.readouterr()
        assert main(["turns", *args, *extra]) == 2
        assert message in capsys.readouterr().err, message
    (tmp_path / "order.json").write_text(json.dumps({"order": ["a"]}))
    assert main(["turns", *args, *meshes]) == 2
    assert "order.json: not a registration order" in capsys.readouterr().err
    assert not (tmp_path / "turns.json").exists()
