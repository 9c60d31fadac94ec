"""gpja.register.jaw: the jaw rig on the bust, the blended rigid motion, and the stage's fit."""
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from gpja.errors import InputError
from gpja.register.bust import make_bust
from gpja.register.jaw import fit_jaw, jaw_weights, pose_jaw, rotation_matrix, socket_vertices, unpose_jaw
from gpja.register.multiscale import Schedule

#: float64 identities (rotations, rigid round trips), mm.
EXACT = 1e-9
#: The jaw's pose recovered by the stage's own Adam on an analytic loss, degrees and mm.
RECOVERED_DEG = 0.3
RECOVERED_MM = 0.3


@pytest.fixture(scope="module")
def bust():
    return make_bust(target_edge_mm=6.0)


@pytest.fixture(scope="module")
def rig(bust):
    socket, rim = socket_vertices(bust.mesh, bust.mouth_mask(256))
    return socket, rim, jaw_weights(bust.mesh.V, socket, rim)


def test_rotation_matrix_matches_scipy_and_is_a_rotation():
    for rv in ([0.0, 0.0, 0.0], [0.3, -0.1, 0.05], [0.0, 1e-6, 0.0], [2.0, 0.5, -1.0]):
        R = rotation_matrix(torch.tensor(rv, dtype=torch.float64)).numpy()
        np.testing.assert_allclose(R, Rotation.from_rotvec(rv).as_matrix(), atol=EXACT)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=EXACT)


def test_rotation_has_a_finite_gradient_at_zero():
    r = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda r: rotation_matrix(r), (r,))


def test_pose_is_rigid_where_the_weight_is_one_still_where_zero_and_undone_by_unpose():
    rng = np.random.default_rng(0)
    V = torch.tensor(rng.normal(size=(50, 3)) * 30.0)
    weight = torch.tensor((np.arange(50) % 2).astype(np.float64))
    pivot, r, t = (torch.tensor(a, dtype=torch.float64) for a in ([1.0, -5.0, -40.0], [0.3, 0.1, -0.05], [2.0, -1.0, 4.0]))
    moved = pose_jaw(V, weight, pivot, r, t)
    still, rigid = weight == 0, weight == 1
    np.testing.assert_allclose(moved[still].numpy(), V[still].numpy(), atol=EXACT)
    d0 = torch.cdist(V[rigid], V[rigid])
    np.testing.assert_allclose(torch.cdist(moved[rigid], moved[rigid]).numpy(), d0.numpy(), atol=1e-8)
    np.testing.assert_allclose(unpose_jaw(moved, weight, pivot, r, t).numpy(), V.numpy(), atol=EXACT)
    np.testing.assert_allclose(pose_jaw(V, weight, pivot, torch.zeros(3, dtype=torch.float64),
                                        torch.zeros(3, dtype=torch.float64)).numpy(), V.numpy(), atol=EXACT)


def test_pose_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    V = torch.tensor(rng.normal(size=(12, 3)) * 20.0)
    weight = torch.tensor(rng.uniform(size=12))
    pivot = torch.tensor([0.0, 2.0, -30.0], dtype=torch.float64)
    r = torch.tensor([0.2, -0.1, 0.3], dtype=torch.float64, requires_grad=True)
    t = torch.tensor([1.0, 0.0, -2.0], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda r, t: pose_jaw(V, weight, pivot, r, t), (r, t))


def test_the_socket_and_its_rim_come_from_the_mouth_mask(bust, rig):
    socket, rim, _ = rig
    pocket_vertices = np.unique(bust.mesh.F[bust.pocket_faces])
    assert set(np.flatnonzero(socket)) == set(pocket_vertices.tolist())
    # the rim is the slit: at the mouth's height, in front
    lips = bust.mesh.V[rim]
    assert np.abs(lips[:, 1] - bust.landmarks["mouth"][1]).max() < 10.0
    assert lips[:, 2].min() > bust.landmarks["pocket_end"][2]


def test_jaw_weights_follow_the_head_the_bust_was_designed_as(bust, rig):
    socket, rim, jaw = rig
    V, w = bust.mesh.V, jaw.weight
    nearest = lambda p: int(np.argmin(np.linalg.norm(V - p, axis=1)))  # noqa: E731
    assert w[nearest(bust.landmarks["chin"])] > 0.95
    for still in ("nose_tip", "head_top", "neck_cut"):
        assert w[nearest(bust.landmarks[still])] < 0.05, still
    lips = V[rim]
    lower = rim[lips[:, 1] < bust.landmarks["mouth"][1] - 1.0]
    upper = rim[lips[:, 1] > bust.landmarks["mouth"][1] + 1.0]
    assert len(lower) and len(upper)
    assert w[lower].min() > 0.9 and w[upper].max() < 0.1
    assert 0.0 <= w.min() and w.max() <= 1.0
    # the hinge stands behind the mouth, inside the head
    assert jaw.pivot[2] < bust.landmarks["mouth"][2] - 40.0


def test_a_mask_without_a_socket_is_refused(bust):
    with pytest.raises(InputError, match="mouth mask"):
        socket_vertices(bust.mesh, np.ones((64, 64), np.float32))


def test_the_stage_recovers_a_known_jaw_pose(bust, rig):
    socket, rim, jaw = rig
    V0 = torch.tensor(bust.mesh.V, dtype=torch.float32)
    w = torch.tensor(jaw.weight, dtype=torch.float32)
    p = torch.tensor(jaw.pivot, dtype=torch.float32)
    r_true = torch.tensor([math.radians(-12.0), math.radians(3.0), 0.0])
    t_true = torch.tensor([1.5, 0.0, 2.0])
    target = pose_jaw(V0, w, p, r_true, t_true)

    def loss(constraint, V):
        return (V - target).abs().sum(1).mean()

    posed, entry = fit_jaw(bust.mesh, torch.tensor(bust.mouth_mask(256))[..., None], 240, 1.0, 1.0, 0.1, loss,
                           ("color", "depth"), progress=lambda s: None)
    np.testing.assert_allclose(entry["rotation_deg"], np.degrees(r_true.numpy()), atol=RECOVERED_DEG)
    np.testing.assert_allclose(entry["translation_mm"], t_true.numpy(), atol=RECOVERED_MM)
    assert np.abs(posed.V - target.numpy()).max() < 1.0
    assert set(entry["losses"]) == {"color", "depth"} and entry["iterations"] == 240


def test_jaw_settings_are_checked():
    assert Schedule().jaw_iterations == 0  # the paper has no jaw stage
    with pytest.raises(ValueError, match="jaw_iterations"):
        Schedule(jaw_iterations=-1)
    with pytest.raises(ValueError, match="jaw_lr"):
        Schedule(jaw_lr_deg=0.0)
