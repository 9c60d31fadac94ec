"""gpja.register.jaw: the jaw rig on the bust, the blended turn and its inverse, and the pitch search."""
import numpy as np
import pytest
import torch

from gpja.errors import InputError
from gpja.mesh import TexturedMesh
from gpja.register.flow import socket_vertices
from gpja.register.jaw import (FINE_STEP_DEG, jaw_weights, lift, lip_weights, pitch_matrix, pose_jaw, search_grid,
                               search_jaw, socket_rim, unpose_jaw)
from gpja.register.multiscale import Schedule

#: float64 identities (rotations, rigid round trips), mm.
EXACT = 1e-9


@pytest.fixture(scope="module")
def rig(small_bust):
    mask = torch.tensor(small_bust.mouth_mask(256))[..., None]
    socket = socket_vertices(small_bust.mesh, mask)
    rim = socket_rim(small_bust.mesh.F, socket)
    return socket, rim, jaw_weights(small_bust.mesh.V, socket, rim)


def test_pitch_matrix_is_a_rotation_about_x_that_turns_y_towards_z():
    R = pitch_matrix(90.0)
    np.testing.assert_allclose(R @ [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], atol=EXACT)
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [1.0, 0.0, 0.0], atol=EXACT)
    for a in (-17.0, 3.5):
        np.testing.assert_allclose(pitch_matrix(a) @ pitch_matrix(a).T, np.eye(3), atol=EXACT)
        np.testing.assert_allclose(pitch_matrix(a) @ pitch_matrix(-a), np.eye(3), atol=EXACT)


def test_the_rim_is_the_socket_vertices_next_to_the_outside():
    """A 5 x 5 grid of vertices whose middle 3 x 3 block is the socket: the rim is the block's ring of 8."""
    n = 5
    F = np.array([f for i in range(n - 1) for j in range(n - 1)
                  for f in ((i * n + j, i * n + j + 1, (i + 1) * n + j + 1), (i * n + j, (i + 1) * n + j + 1, (i + 1) * n + j))])
    i, j = np.divmod(np.arange(n * n), n)
    socket = (i >= 1) & (i <= 3) & (j >= 1) & (j <= 3)
    ring = np.flatnonzero(socket & ~((i == 2) & (j == 2)))
    np.testing.assert_array_equal(socket_rim(F, socket), ring)
    with pytest.raises(InputError, match="mouth mask"):
        socket_rim(F, np.zeros(n * n, dtype=bool))
    with pytest.raises(InputError, match="rim"):
        socket_rim(F, (i == 0) & (j <= 1))  # two vertices: no lips to hinge


def test_pose_is_rigid_where_the_weight_is_one_still_where_zero_and_undone_by_unpose(rig, small_bust):
    _, _, jaw = rig
    V = small_bust.mesh.V
    moved = pose_jaw(V, jaw, -12.0)
    still, rigid = jaw.weight == 0, jaw.weight == 1
    assert still.any() and rigid.any()
    np.testing.assert_allclose(moved[still], V[still], atol=EXACT)
    # the rigid part keeps its distances and turns about the hinge
    a, b = np.flatnonzero(rigid)[[0, -1]]
    assert abs(np.linalg.norm(moved[a] - moved[b]) - np.linalg.norm(V[a] - V[b])) < EXACT
    np.testing.assert_allclose(np.linalg.norm(moved[rigid] - jaw.pivot, axis=1),
                               np.linalg.norm(V[rigid] - jaw.pivot, axis=1), atol=EXACT)
    both = still | rigid
    np.testing.assert_allclose(unpose_jaw(moved, jaw, -12.0)[both], V[both], atol=EXACT)
    np.testing.assert_allclose(pose_jaw(V, jaw, 0.0), V, atol=EXACT)


def test_jaw_weights_follow_the_head_the_bust_was_designed_as(rig, small_bust):
    socket, rim, jaw = rig
    V, w, marks = small_bust.mesh.V, jaw.weight, small_bust.landmarks
    nearest = lambda p: int(np.argmin(np.linalg.norm(V - p, axis=1)))  # noqa: E731
    assert w[nearest(marks["chin"])] > 0.95
    for still in ("nose_tip", "head_top", "neck_cut"):
        assert w[nearest(marks[still])] < 0.05, still
    lips = V[rim]
    assert np.abs(lips[:, 1] - marks["mouth"][1]).max() < 10.0
    lower = rim[lips[:, 1] < marks["mouth"][1] - 1.0]
    upper = rim[lips[:, 1] > marks["mouth"][1] + 1.0]
    assert len(lower) and len(upper)
    assert w[lower].min() > 0.9 and w[upper].max() < 0.1
    assert 0.0 <= w.min() and w.max() <= 1.0
    assert jaw.pivot[2] < marks["mouth"][2] - 40.0  # the hinge stands behind the mouth, inside the head


def test_the_grid_search_finds_a_minimum_to_its_fine_step_and_prefers_no_motion_on_ties():
    best, tried = search_grid(-30.0, 10.0, lambda a: (a + 12.3) ** 2)
    assert abs(best + 12.3) <= FINE_STEP_DEG / 2 + EXACT
    assert min(a for a, _ in tried) == -30.0 and max(a for a, _ in tried) == 10.0
    best, _ = search_grid(-30.0, 10.0, lambda a: 1.0)  # a flat score: the start stays
    assert best == 0.0
    best, _ = search_grid(-30.0, 10.0, lambda a: abs(a - 10.0))  # at the range's end
    assert best == 10.0


def turned_scene(rig, small_bust, degrees, lower_mm=0.0):
    """References rendered from the bust with its jaw turned ``degrees`` and its lower lip lifted ``lower_mm``; returns
    the bust placed at the origin (the start), the turned positions, the targets, the texture and the mask."""
    from gpja.lighting import uniform_sh
    from gpja.register.hra import ExpressionTargets
    from gpja.render import Topology, render_views
    from tests.render.scenes import ring_cameras

    _, rim, jaw = rig
    mesh = small_bust.mesh
    texture = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0))
    mask = torch.tensor(small_bust.mouth_mask(256))[..., None]
    cameras, sh = ring_cameras(3, 128), torch.tensor(uniform_sh(), dtype=torch.float32)
    centre = mesh.V.mean(0)
    placed = TexturedMesh(mesh.V - centre, mesh.F, mesh.UV, mesh.F_uv)  # the ring looks at the origin
    placed_rig = jaw.__class__(jaw.weight, jaw.pivot - centre)
    turned = lift(pose_jaw(placed.V, placed_rig, degrees), lip_weights(placed.V, rim, placed_rig)[0], lower_mm)
    topology = Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv))
    ref = render_views(torch.tensor(turned, dtype=torch.float32), topology, cameras, ("color", "depth", "normal"),
                       uv=torch.tensor(mesh.UV, dtype=torch.float32), texture=texture, mask_texture=mask, sh=sh)
    targets = ExpressionTargets(cameras, *(ref.dense(p).detach() for p in ("color", "depth", "normal", "coverage")), sh)
    return placed, turned, targets, texture, mask


def test_the_search_recovers_a_jaw_turned_in_the_references(rig, small_bust):
    placed, turned, targets, texture, mask = turned_scene(rig, small_bust, -10.0)
    posed, entry, _ = search_jaw(placed, targets, texture, mask, (-30.0, 10.0), progress=lambda s: None)
    assert entry["pitch_deg"] == pytest.approx(-10.0, abs=FINE_STEP_DEG / 2 + EXACT)
    assert entry["score"] < entry["score_at_start"]
    assert np.abs(posed.V - turned).max() < 0.5


def test_the_search_keeps_the_start_when_the_references_show_it(rig, small_bust):
    placed, _, targets, texture, mask = turned_scene(rig, small_bust, 0.0)
    posed, entry, _ = search_jaw(placed, targets, texture, mask, (-30.0, 10.0), progress=lambda s: None)
    assert entry["pitch_deg"] == 0.0 and posed is placed


def test_lip_weights_split_the_rim_by_the_jaw_and_fade_away_from_it(rig, small_bust):
    _, rim, jaw = rig
    V, marks = small_bust.mesh.V, small_bust.landmarks
    lower, upper = lip_weights(V, rim, jaw)
    below = rim[V[rim, 1] < marks["mouth"][1] - 1.0]
    above = rim[V[rim, 1] > marks["mouth"][1] + 1.0]
    assert lower[below].min() > 0.9 and upper[above].min() > 0.9
    assert lower[above].max() < 0.1 and upper[below].max() < 0.1
    nearest = lambda p: int(np.argmin(np.linalg.norm(V - p, axis=1)))  # noqa: E731
    for far in ("nose_tip", "head_top", "neck_cut"):
        assert lower[nearest(marks[far])] == 0.0 and upper[nearest(marks[far])] == 0.0, far
    np.testing.assert_allclose(lift(V, lower, 2.0) - V, np.stack([0 * lower, 2.0 * lower, 0 * lower], 1), atol=EXACT)


def test_the_search_recovers_a_lifted_lower_lip_after_the_turn(rig, small_bust):
    placed, turned, targets, texture, mask = turned_scene(rig, small_bust, -10.0, lower_mm=2.0)
    posed, entry, _ = search_jaw(placed, targets, texture, mask, (-30.0, 10.0), progress=lambda s: None,
                                 lips_mm=(-6.0, 6.0))
    assert entry["pitch_deg"] == pytest.approx(-10.0, abs=1.0)
    assert entry["lower_lip_mm"] == pytest.approx(2.0, abs=0.5)
    assert abs(entry["upper_lip_mm"]) <= 0.5
    assert np.abs(posed.V - turned).max() < 1.0


def test_jaw_settings_are_checked():
    assert Schedule().jaw_search_deg is None  # the paper has no jaw search
    Schedule(jaw_search_deg=(-30.0, 10.0))
    for bad in ((5.0, 10.0), (-30.0, -5.0), (-100.0, 10.0), (-30.0,)):
        with pytest.raises(ValueError, match="jaw_search_deg"):
            Schedule(jaw_search_deg=bad)
    assert Schedule().jaw_lips_mm is None
    Schedule(jaw_lips_mm=(-6.0, 6.0))
    for bad in ((1.0, 6.0), (-6.0, -1.0), (-40.0, 6.0)):
        with pytest.raises(ValueError, match="jaw_lips_mm"):
            Schedule(jaw_lips_mm=bad)
