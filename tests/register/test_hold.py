"""gpja.register.hold: the tangential hold's weights, correction and refinement."""
import numpy as np
import pytest
import torch

from gpja.mesh import TexturedMesh, unique_edges
from gpja.camera import Camera
from gpja.register.hold import TangentialHold, edge_spring_step, gap_factor, hold_weights, mouth_factor, scan_gap
from gpja.register.hra import ExpressionTargets
from gpja.register.largesteps import LargeStepsParametrization
from gpja.register.multiscale import Schedule
from gpja.register.remesh import refine_by_factor, refine_carrying

#: Tolerance of exact identities (float64 arithmetic).
EXACT = 1e-10
#: Tolerance of a gap read from a float32 depth image 400 mm away, with the off-axis cosine (<= 1e-4 relative).
GAP_MM = 1e-3


def grid(n: int = 6, size: float = 10.0) -> TexturedMesh:
    """A flat n x n grid in the z = 0 plane (mm), normals +z, UVs from x, y."""
    xs = np.linspace(0.0, size, n)
    X, Y = np.meshgrid(xs, xs)
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(n * n)], axis=1)
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            F += [(a, b, d), (a, d, c)]
    F = np.array(F, dtype=np.int64)
    return TexturedMesh(V, F, V[:, :2] / size, F.copy())


def test_the_correction_removes_its_rate_of_the_tangential_offset_only():
    mesh = grid()
    hold = TangentialHold(mesh.V.copy(), np.tile([0.0, 0.0, 1.0], (len(mesh.V), 1)), np.ones(len(mesh.V)), 0.25)
    offset = np.array([2.0, -1.0, 3.0])  # (2, -1) along the plane, 3 along the normal
    dx = hold.correction(torch.from_numpy(mesh.V + offset))
    np.testing.assert_allclose(dx.numpy(), np.tile([-0.5, 0.25, 0.0], (len(mesh.V), 1)), atol=EXACT)


def test_the_correction_scales_with_the_weight_and_is_zero_at_the_start():
    mesh = grid()
    weight = np.linspace(0.0, 1.0, len(mesh.V))
    hold = TangentialHold(mesh.V.copy(), np.tile([0.0, 0.0, 1.0], (len(mesh.V), 1)), weight, 0.5)
    assert torch.count_nonzero(hold.correction(torch.from_numpy(mesh.V))) == 0
    dx = hold.correction(torch.from_numpy(mesh.V + [1.0, 0.0, 0.0])).numpy()
    np.testing.assert_allclose(dx[:, 0], -0.5 * weight, atol=EXACT)


def test_weights_hold_what_did_not_move_and_free_what_moved_far():
    mesh = grid(8)
    moved = mesh.V.copy()
    far = mesh.V[:, 0] > 7.0
    moved[far] += [0.0, 0.0, 10.0]
    moved[~far] += [0.1, 0.0, 0.0]
    raw = hold_weights(mesh.V, moved, mesh.F, 0.0, (0.75, 2.5))
    np.testing.assert_array_equal(raw[far], 0.0)
    np.testing.assert_array_equal(raw[~far], 1.0)
    # linear between the two distances
    half = hold_weights(mesh.V, mesh.V + [1.625, 0.0, 0.0], mesh.F, 0.0, (0.75, 2.5))
    np.testing.assert_allclose(half, 0.5, atol=EXACT)
    # smoothing keeps the values in [0, 1] and spreads the step across the boundary
    smooth = hold_weights(mesh.V, moved, mesh.F, 10.0, (0.75, 2.5))
    assert smooth.min() >= 0.0 and smooth.max() <= 1.0
    assert 0.0 < smooth[far].max() and smooth[~far].min() < 1.0
    assert smooth[mesh.V[:, 0] < 2.0].mean() > 0.75 and smooth[far].mean() < 0.5


def test_refinement_carries_rows_as_it_places_the_new_vertices():
    mesh = grid(5)
    refined, rows = refine_carrying(mesh, 2.5, mesh.V.copy())
    np.testing.assert_allclose(rows, refined.V, atol=EXACT)  # identity: positions carried are the positions
    assert np.array_equal(refined.F, refine_by_factor(mesh, 2.5).F)
    with pytest.raises(ValueError, match="one entry per vertex"):
        refine_carrying(mesh, 2.5, mesh.V[:-1])


def test_a_refined_hold_keeps_unit_normals_and_the_old_vertices_rows():
    mesh = grid(5)
    normals = np.tile([0.0, 0.6, 0.8], (len(mesh.V), 1))
    hold = TangentialHold(mesh.V.copy(), normals, np.linspace(0, 1, len(mesh.V)), 0.1)
    refined, fine = hold.refine(mesh, 2.0)
    assert len(fine.start) == len(refined.V) > len(mesh.V)
    np.testing.assert_allclose(np.linalg.norm(fine.normals, axis=1), 1.0, atol=EXACT)
    np.testing.assert_array_equal(fine.weight[: len(mesh.V)], hold.weight)
    assert fine.rate == hold.rate


def test_shift_moves_the_parametrised_vertices_by_exactly_dx():
    mesh = grid(5)
    param = LargeStepsParametrization(mesh.V, mesh.F, 5.0, dtype=torch.float64)
    before = param.vertices().detach().clone()
    dx = torch.from_numpy(np.random.default_rng(0).normal(size=mesh.V.shape))
    param.shift(dx)
    np.testing.assert_allclose((param.vertices().detach() - before).numpy(), dx.numpy(), atol=1e-9)
    assert param.u.requires_grad


def plane_targets(offset_mm: float, covered_from_x_px: int = 0, size: int = 64) -> ExpressionTargets:
    """One camera 400 mm above the 10 x 10 mm grid's centre looking down -z, and a scan that is the plane
    ``offset_mm`` below the grid (camera depth 400 + offset), covering the pixels from column
    ``covered_from_x_px`` on."""
    K = np.array([[1000.0, 0.0, (size - 1) / 2], [0.0, 1000.0, (size - 1) / 2], [0.0, 0.0, 1.0]])
    camera = Camera.look_at((5.0, 5.0, 400.0), (5.0, 5.0, 0.0), (0.0, 1.0, 0.0), K, size, size)
    depth = torch.full((1, size, size, 1), 400.0 + offset_mm)
    coverage = torch.zeros((1, size, size, 1))
    coverage[:, :, covered_from_x_px:] = 1.0
    zeros = torch.zeros((1, size, size, 3))
    return ExpressionTargets([camera], zeros, depth * coverage, zeros, coverage, torch.zeros(9, 3))


def test_the_scan_gap_is_the_distance_to_a_parallel_scan_and_unknown_where_none_is_seen():
    mesh = grid(6)
    np.testing.assert_allclose(scan_gap(mesh.V, mesh.F, plane_targets(2.5)), 2.5, atol=GAP_MM)
    np.testing.assert_allclose(scan_gap(mesh.V, mesh.F, plane_targets(0.0)), 0.0, atol=GAP_MM)
    # a scan that covers only the right of the image: the left's gap is unknown
    targets = plane_targets(1.0, covered_from_x_px=32)
    gap = scan_gap(mesh.V, mesh.F, targets)
    px, _ = targets.cameras[0].project(mesh.V)
    left = np.rint(px[:, 0]) < 32
    assert left.any() and (~left).any()
    assert np.isnan(gap[left]).all()
    np.testing.assert_allclose(gap[~left], 1.0, atol=GAP_MM)
    # a surface facing away from the camera is not seen
    flipped = mesh.F[:, ::-1].copy()
    assert np.isnan(scan_gap(mesh.V, flipped, plane_targets(1.0))).all()


def test_the_gap_factor_keeps_what_is_on_the_scan_and_frees_what_is_off_it():
    gap = np.array([0.0, 0.5, 1.25, 2.0, 5.0, np.nan])
    np.testing.assert_allclose(gap_factor(gap, (0.5, 2.0)), [1.0, 1.0, 0.5, 0.0, 0.0, 1.0], atol=EXACT)


def test_a_gated_hold_frees_the_vertices_off_the_scan():
    mesh = grid(8)
    gap = np.where(mesh.V[:, 0] > 7.0, 3.0, 0.1)  # the right columns start 3 mm off the scan
    plain = TangentialHold.after_first_phase(mesh, mesh, 0.0, 0.1, (0.75, 2.5))
    gated = TangentialHold.after_first_phase(mesh, mesh, 0.0, 0.1, (0.75, 2.5), gap, (0.5, 2.0))
    np.testing.assert_array_equal(plain.weight, 1.0)  # nothing moved in the first phase: all held
    np.testing.assert_array_equal(gated.weight, np.where(gap > 2.0, 0.0, 1.0))
    np.testing.assert_array_equal(TangentialHold.after_first_phase(mesh, mesh, 0.0, 0.1, (0.75, 2.5), gap, None).weight,
                                  plain.weight)


def test_the_mouth_factor_ramps_with_the_distance_to_the_nearest_socket_vertex():
    V = np.array([[0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 12.0, 0.0], [0.0, 0.0, 30.0], [-20.0, 0.0, 0.0]])
    socket = np.array([True, False, False, False, False])
    # 0 within 10 mm, 1 from 20 mm on, linear between: distances 0, 5, 12, 30, 20
    np.testing.assert_allclose(mouth_factor(V, socket, (10.0, 20.0)), [0.0, 0.0, 0.2, 1.0, 1.0], atol=EXACT)
    socket[3] = True  # the nearest socket vertex counts: vertex 3 is now in the socket
    np.testing.assert_allclose(mouth_factor(V, socket, (10.0, 20.0)), [0.0, 0.0, 0.2, 0.0, 1.0], atol=EXACT)
    np.testing.assert_array_equal(mouth_factor(V, np.zeros(5, dtype=bool), (10.0, 20.0)), 1.0)  # no socket: no release


def test_a_hold_released_around_the_mouth_multiplies_its_weights():
    mesh = grid(8)
    factor = mouth_factor(mesh.V, mesh.V[:, 0] == 0.0, (2.0, 6.0))  # the left column is the "socket"
    plain = TangentialHold.after_first_phase(mesh, mesh, 0.0, 0.1, (0.75, 2.5))
    released = TangentialHold.after_first_phase(mesh, mesh, 0.0, 0.1, (0.75, 2.5), factor=factor)
    np.testing.assert_allclose(released.weight, plain.weight * factor, atol=EXACT)
    assert released.weight[mesh.V[:, 0] <= 2.0].max() == 0.0 and released.weight[mesh.V[:, 0] >= 6.0].min() == 1.0
    # a released vertex is not pulled back, a held one is
    moved = torch.from_numpy(mesh.V + np.array([1.0, 0.0, 0.0]))
    dx = released.correction(moved).numpy()
    np.testing.assert_allclose(dx[mesh.V[:, 0] <= 2.0], 0.0, atol=EXACT)
    np.testing.assert_allclose(dx[mesh.V[:, 0] >= 6.0], [[-0.1, 0.0, 0.0]] * int((mesh.V[:, 0] >= 6.0).sum()), atol=EXACT)


def test_a_hold_reanchored_around_the_mouth_moves_the_start_there_and_raises_the_weights():
    mesh = grid(8)
    hold = TangentialHold.after_first_phase(mesh, mesh, 0.0, 0.1, (0.75, 2.5))
    hold = TangentialHold(hold.start, hold.normals, np.linspace(0.0, 0.5, len(mesh.V)), 0.1, 0.3, hold.edges)
    moved = mesh.V + np.array([0.5, -0.25, 0.0])  # where a flow stage put every vertex
    near = 1.0 - mouth_factor(mesh.V, mesh.V[:, 0] == 0.0, (2.0, 6.0))  # the left column is the "socket"
    again = hold.reanchored(moved, mesh.F, near)
    on = near > 0
    assert on.any() and (~on).any()
    np.testing.assert_array_equal(again.start[on], moved[on])
    np.testing.assert_array_equal(again.start[~on], hold.start[~on])
    np.testing.assert_allclose(again.normals, hold.normals, atol=EXACT)  # the grid only slid: the same normals
    np.testing.assert_array_equal(again.weight, np.maximum(hold.weight, near))
    assert (again.rate, again.spring_rate) == (hold.rate, hold.spring_rate)
    # at the flow's positions the re-anchored vertices are not pulled back, the others are
    dx = again.correction(torch.from_numpy(moved)).numpy()
    np.testing.assert_allclose(dx[on & (mesh.V[:, 0] < 2.0)][:, :2], 0.0, atol=EXACT)
    assert np.abs(dx[~on]).max() > 0.0
    # nothing near the mouth: the same hold
    same = hold.reanchored(moved, mesh.F, np.zeros(len(mesh.V)))
    np.testing.assert_array_equal(same.start, hold.start)
    np.testing.assert_array_equal(same.weight, hold.weight)


def test_one_stretched_edge_gets_its_rest_length_back_in_one_full_step():
    rest = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    x = torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]], dtype=torch.float64)
    edges = torch.tensor([[0, 1]])
    move = edge_spring_step(x, rest, edges, torch.tensor([[0.0, 0.0, 1.0]] * 2, dtype=torch.float64))
    np.testing.assert_allclose(move.numpy(), [[0.5, 0.0, 0.0], [-0.5, 0.0, 0.0]], atol=EXACT)
    # the same edge stretched along the normals: the move is kept in their plane, so nothing moves
    along_normal = edge_spring_step(x, rest, edges, torch.tensor([[1.0, 0.0, 0.0]] * 2, dtype=torch.float64))
    np.testing.assert_allclose(along_normal.numpy(), 0.0, atol=EXACT)


def test_springs_do_not_move_a_rigid_motion_of_the_rest_mesh_and_shrink_a_stretch():
    mesh = grid()
    edges = torch.from_numpy(unique_edges(mesh.F)[0])
    rest = torch.from_numpy(mesh.V)
    normals = torch.tensor([[0.0, 0.0, 1.0]] * len(mesh.V), dtype=torch.float64)
    c, s_ = np.cos(0.3), np.sin(0.3)
    R = torch.tensor([[c, -s_, 0.0], [s_, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    moved = rest @ R.T + torch.tensor([3.0, -2.0, 0.0], dtype=torch.float64)
    np.testing.assert_allclose(edge_spring_step(moved, rest, edges, normals).numpy(), 0.0, atol=EXACT)
    stretched = rest * torch.tensor([1.5, 1.0, 1.0], dtype=torch.float64)  # 50 % wider along x
    x = stretched.clone()
    for _ in range(200):
        x = x + 0.5 * edge_spring_step(x, rest, edges, normals)
    width = lambda v: float(v[:, 0].max() - v[:, 0].min())
    assert abs(width(x) - width(rest)) < 0.2 * (width(stretched) - width(rest))  # 0.10 measured


def test_the_correction_adds_the_springs_and_refinement_keeps_them():
    mesh = grid()
    hold = TangentialHold.after_first_phase(mesh, mesh, 0.0, 0.0, (0.75, 2.5), spring_rate=0.5)
    assert hold.spring_rate == 0.5 and len(hold.edges) == len(unique_edges(mesh.F)[0])
    stretched = torch.from_numpy(mesh.V * np.array([1.2, 1.0, 1.0]))
    expected = 0.5 * edge_spring_step(stretched, torch.from_numpy(mesh.V), torch.from_numpy(hold.edges),
                                      torch.from_numpy(hold.normals))
    np.testing.assert_allclose(hold.correction(stretched).numpy(), expected.numpy(), atol=EXACT)
    assert float(expected.abs().max()) > 0.01
    fine_mesh, fine = hold.refine(mesh, 2.0)
    assert fine.spring_rate == 0.5
    np.testing.assert_array_equal(fine.edges, unique_edges(fine_mesh.F)[0])
    np.testing.assert_allclose(fine.correction(torch.from_numpy(fine_mesh.V)).numpy(), 0.0, atol=EXACT)


@pytest.mark.parametrize("bad", [{"spring_rate": -0.1}, {"spring_rate": 1.5}])
def test_schedule_refuses_bad_springs(bad):
    with pytest.raises(ValueError, match="spring_rate"):
        Schedule(lambdas=(10.0,), iterations=(1,), **bad)


@pytest.mark.parametrize("bad", [{"hold_tangential": -0.1}, {"hold_tangential": 1.0},
                                 {"hold_moved_mm": (2.0, 1.0)}, {"hold_moved_mm": (1.0,)},
                                 {"hold_gap_mm": (2.0, 0.5)}, {"hold_gap_mm": (1.0,)}, {"hold_gap_mm": (-1.0, 1.0)},
                                 {"hold_mouth_mm": (20.0, 10.0)}, {"hold_mouth_mm": (10.0,)}, {"hold_mouth_mm": (-1.0, 5.0)},
                                 {"hold_mouth_at_flow_mm": (24.0, 12.0)}, {"hold_mouth_at_flow_mm": (12.0,)},
                                 {"hold_moved_at_flow": "yes"}, {"hold_moved_at_flow": 1}])
def test_schedule_refuses_a_bad_hold(bad):
    with pytest.raises(ValueError, match="hold"):
        Schedule(lambdas=(10.0,), iterations=(1,), **bad)


def test_the_hold_anchors_what_it_left_free_where_the_last_flow_stage_put_it():
    """``hold_moved_at_flow``: the vertices the hold leaves mostly free (weight below 0.5) are anchored at the flow
    stage's positions with weight ``1 - weight``; the held ones keep their start and weight. Off, with no mouth
    anchor either, the hold is the same object."""
    from gpja.register.multiscale import anchor_hold_at_flow

    mesh = grid(8)
    hold = TangentialHold.after_first_phase(mesh, mesh, 0.0, 0.1, (0.75, 2.5))
    weight = np.linspace(0.0, 1.0, len(mesh.V))
    hold = TangentialHold(hold.start, hold.normals, weight, 0.1, 0.0, hold.edges)
    moved = mesh.with_vertices(mesh.V + np.array([0.5, -0.25, 0.0]))  # where the last flow stage put every vertex
    schedule = dict(lambdas=(10.0,), iterations=(1,), hold_tangential=0.1)
    messages = []
    again = anchor_hold_at_flow(hold, moved, Schedule(**schedule, hold_moved_at_flow=True), None, messages.append,
                               "flow2")
    free = weight < 0.5
    assert free.any() and (~free).any()
    np.testing.assert_array_equal(again.start[free], moved.V[free])
    np.testing.assert_array_equal(again.start[~free], hold.start[~free])
    np.testing.assert_array_equal(again.weight, np.where(free, 1.0 - weight, weight))
    assert messages == [f"hold: {np.mean(free):.0%} of the vertices it left free anchored where flow2 put them"]
    # at the flow's positions the anchored vertices are not pulled back, the held ones are
    dx = again.correction(torch.from_numpy(moved.V)).numpy()
    np.testing.assert_allclose(dx[free], 0.0, atol=EXACT)
    np.testing.assert_allclose(dx[~free], -0.1 * weight[~free, None] * np.array([0.5, -0.25, 0.0]), atol=EXACT)
    assert anchor_hold_at_flow(hold, moved, Schedule(**schedule), None, messages.append, "flow2") is hold
