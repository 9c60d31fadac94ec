"""gpja.register.jaw: the jaw rig on the bust, the blended turn and its inverse, and the pitch search."""
import numpy as np
import pytest
import torch

from gpja.errors import InputError
from gpja.mesh import TexturedMesh
from gpja.register.flow import socket_vertices
from gpja.register.jaw import (FINE_STEP_DEG, FINE_STEP_MM, colour_score, jaw_weights, lift, limit_reach, lip_weights,
                               mouth_window, pitch_matrix, pose_jaw, search_grid, search_grid_2d, search_jaw, socket_rim, unpose_jaw)
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


def test_the_forward_shift_moves_the_rigid_jaw_along_z_and_is_undone_by_unpose(rig, small_bust):
    _, _, jaw = rig
    V = small_bust.mesh.V
    still, rigid = jaw.weight == 0, jaw.weight == 1
    shifted = pose_jaw(V, jaw, 0.0, 4.0)
    np.testing.assert_allclose(shifted[rigid] - V[rigid], np.tile([0.0, 0.0, 4.0], (rigid.sum(), 1)), atol=EXACT)
    np.testing.assert_allclose(shifted[still], V[still], atol=EXACT)
    moved = pose_jaw(V, jaw, -12.0, 3.0)
    # the turn, then the shift: the rigid part is the turned jaw moved 3 mm forward
    np.testing.assert_allclose(moved[rigid], pose_jaw(V, jaw, -12.0)[rigid] + [0.0, 0.0, 3.0], atol=EXACT)
    both = still | rigid
    np.testing.assert_allclose(unpose_jaw(moved, jaw, -12.0, 3.0)[both], V[both], atol=EXACT)


def test_the_reach_keeps_the_chin_and_lets_the_neck_stay(rig, small_bust):
    """Faded out from 30 to 45 mm of the rim: the lower lip keeps its weight, what lies beyond 45 mm has none, the
    weights never grow, and a turn leaves the far vertices where they were."""
    _, rim, jaw = rig
    V, marks = small_bust.mesh.V, small_bust.landmarks
    near = limit_reach(jaw, V, rim, (30.0, 45.0))
    from scipy.spatial import cKDTree
    distance = cKDTree(V[rim]).query(V)[0]
    lower = rim[V[rim, 1] < marks["mouth"][1] - 1.0]
    np.testing.assert_allclose(near.weight[lower], jaw.weight[lower], atol=EXACT)
    assert (near.weight <= jaw.weight + EXACT).all() and (near.weight[distance >= 45.0] == 0.0).all()
    assert (jaw.weight[distance >= 45.0] > 0.5).any()  # the rig alone reaches further (the neck)
    np.testing.assert_array_equal(near.pivot, jaw.pivot)
    far = distance >= 45.0
    np.testing.assert_allclose(pose_jaw(V, near, -20.0, 5.0)[far], V[far], atol=EXACT)


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


def test_the_2d_search_finds_pitch_and_shift_to_their_fine_steps_and_prefers_no_motion_on_ties():
    (a, t), tried = search_grid_2d((-30.0, 10.0), (-5.0, 15.0), lambda a, t: (a + 12.3) ** 2 + 4.0 * (t - 7.2) ** 2)
    assert abs(a + 12.3) <= FINE_STEP_DEG / 2 + EXACT and abs(t - 7.2) <= FINE_STEP_MM / 2 + EXACT
    assert {(-30.0, -5.0), (10.0, 15.0), (0.0, 0.0)} <= {(x, y) for x, y, _ in tried}  # the coarse grid's corners, the start
    assert len(tried) <= 45 + 2 * 20  # coarse 9 x 5, then one axis at a time
    assert search_grid_2d((-30.0, 10.0), (-5.0, 15.0), lambda a, t: 1.0)[0] == (0.0, 0.0)  # flat: the start stays
    assert search_grid_2d((-30.0, 10.0), (-5.0, 15.0), lambda a, t: abs(a - 10.0) + abs(t + 5.0))[0] == (10.0, -5.0)


def test_the_mouth_window_is_the_box_of_what_lies_near_the_rim_in_each_view():
    """Points on a plane at z = 0 seen by a camera on the +Z axis: the window is the box of the points within the
    radius of the 'rim' (the origin), a little wider, and nothing else."""
    from gpja.camera import Camera

    Rt = np.concatenate([np.diag([1.0, -1.0, -1.0]), [[0.0], [0.0], [500.0]]], axis=1)  # on +Z, looking at the origin
    camera = Camera(K=np.array([[200.0, 0.0, 32.0], [0.0, 200.0, 32.0], [0.0, 0.0, 1.0]]), Rt=Rt, width=64, height=64)
    g = np.linspace(-60.0, 60.0, 25)
    V = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    V = np.concatenate([V, np.zeros((len(V), 1))], 1)
    rim = np.array([int(np.argmin(np.linalg.norm(V, axis=1)))])
    window = mouth_window(V, rim, [camera], 64, 64, 20.0)
    assert window.shape == (1, 64, 64, 1) and set(np.unique(window.numpy())) == {0.0, 1.0}
    xy, _ = camera.project(V[np.linalg.norm(V - V[rim], axis=1) <= 20.0])
    cols = np.flatnonzero(window[0, 32, :, 0].numpy())
    assert cols.min() <= xy[:, 0].min() and cols.max() >= xy[:, 0].max()  # covers the near points
    far, _ = camera.project(np.array([[50.0, 0.0, 0.0]]))
    assert window[0, 32, int(far[0, 0]), 0] == 0.0  # and not what lies 50 mm away


def turned_scene(rig, small_bust, degrees, lower_mm=0.0, shift_mm=0.0):
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
    turned = lift(pose_jaw(placed.V, placed_rig, degrees, shift_mm), lip_weights(placed.V, rim, placed_rig)[0], lower_mm)
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


def test_the_windowed_2d_search_recovers_a_jaw_turned_and_shifted_in_the_references(rig, small_bust):
    placed, turned, targets, texture, mask = turned_scene(rig, small_bust, -10.0, shift_mm=4.0)
    posed, entry, _ = search_jaw(placed, targets, texture, mask, (-30.0, 10.0), progress=lambda s: None,
                                 shift_mm=(-5.0, 15.0), window_mm=30.0)
    assert entry["pitch_deg"] == pytest.approx(-10.0, abs=1.0)
    assert entry["shift_mm"] == pytest.approx(4.0, abs=1.0)
    assert entry["window_mm"] == 30.0 and entry["score"] < entry["score_at_start"]
    assert np.abs(posed.V - turned).max() < 1.5
    # the pitch alone cannot reach it: the shifted jaw stays further off
    alone, _, _ = search_jaw(placed, targets, texture, mask, (-30.0, 10.0), progress=lambda s: None)
    assert np.abs(alone.V - turned).max() > np.abs(posed.V - turned).max()


def test_the_windowed_score_counts_only_the_mouths_box(rig, small_bust):
    """A change of the render far from the mouth (the top of the head) moves the whole-image score, not the window's."""
    placed, _, targets, texture, mask = turned_scene(rig, small_bust, 0.0)
    whole = colour_score(placed, targets, texture, mask)
    window = colour_score(placed, targets, texture, mask, window_mm=20.0)
    top = placed.V[:, 1] > np.percentile(placed.V[:, 1], 85)
    bumped = placed.V.copy()
    bumped[top, 0] += 3.0
    assert whole(bumped) > whole(placed.V) + 1e-4
    assert window(bumped) == pytest.approx(window(placed.V), abs=1e-7)


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
    Schedule(jaw_search_deg=(-30.0, 10.0), jaw_shift_mm=(-5.0, 15.0), jaw_window_mm=30.0)
    for bad in ((2.0, 15.0), (-5.0, -1.0), (-5.0, 40.0), (5.0,)):
        with pytest.raises(ValueError, match="jaw_shift_mm"):
            Schedule(jaw_shift_mm=bad)
    for bad in (0.0, -3.0, 500.0):
        with pytest.raises(ValueError, match="jaw_window_mm"):
            Schedule(jaw_window_mm=bad)
    Schedule(jaw_reach_mm=(40.0, 70.0))
    for bad in ((70.0, 40.0), (-1.0, 10.0), (40.0,)):
        with pytest.raises(ValueError, match="jaw_reach_mm"):
            Schedule(jaw_reach_mm=bad)
    assert Schedule().jaw_lips_mm is None
    Schedule(jaw_lips_mm=(-6.0, 6.0))
    for bad in ((1.0, 6.0), (-6.0, -1.0), (-40.0, 6.0)):
        with pytest.raises(ValueError, match="jaw_lips_mm"):
            Schedule(jaw_lips_mm=bad)
