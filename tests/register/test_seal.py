"""gpja.register.seal: the dark run along a segment, the rim's pairs, and the lower lip sealed only under closed lips."""
import numpy as np
import pytest
import torch

from gpja.camera import Camera
from gpja.register.flow import socket_vertices
from gpja.register.multiscale import Schedule
from gpja.register.seal import CONTACT_MM, FAR_MM, dark_gaps, longest_dark_run, rim_pairs, seal_lips

#: float64 identities, mm.
EXACT = 1e-9
#: what stays (beyond ``FAR_MM``) moves, by the median, less than this fraction of the rim's median move (the pull to
#: stay is as strong as the rim's targets, so their neighbours on the coarse bust give a little)
STAY_FRACTION = 0.05


def test_longest_dark_run():
    assert longest_dark_run(np.array([], dtype=bool)) == 0
    assert longest_dark_run(np.array([0, 1, 1, 0, 1, 1, 1, 0], dtype=bool)) == 3
    assert longest_dark_run(np.ones(5, dtype=bool)) == 5


def test_dark_gaps_measure_a_band_in_mm():
    """A camera 500 mm in front of the plane z = 0 (1 px = 1 mm at f = 500), a dark horizontal band 6 px high:
    a vertical 20 mm segment across it has a 6 mm dark run (to a pixel), one beside it none."""
    K = np.array([[500.0, 0.0, 64.0], [0.0, 500.0, 64.0], [0.0, 0.0, 1.0]])
    camera = Camera.look_at([0.0, 0.0, 500.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], K, 128, 128)
    lum = np.full((128, 128), 0.6)
    lum[61:67, :] = 0.05
    coverage = np.ones((128, 128))
    start = np.array([[0.0, -10.0, 0.0], [0.0, 20.0, 0.0]])
    end = np.array([[0.0, 10.0, 0.0], [0.0, 40.0, 0.0]])
    gaps = dark_gaps(camera, start, end, lum, coverage)
    assert gaps[0] == pytest.approx(6.0, abs=1.5)
    assert gaps[1] == 0.0
    # off the head (no coverage) there is no evidence of an opening
    assert (dark_gaps(camera, start, end, lum, np.zeros_like(coverage)) == 0.0).all()


def opened_bust(small_bust, degrees: float):
    """The bust with its jaw opened ``degrees`` (3: the rims 8-11 mm apart; 5: 11-13 mm), placed at the origin; its
    mouth mask; a ring of cameras."""
    from gpja.mesh import TexturedMesh
    from gpja.register.jaw import jaw_weights, pose_jaw, socket_rim
    from tests.render.scenes import ring_cameras

    mesh = small_bust.mesh
    mask = torch.tensor(small_bust.mouth_mask(256))[..., None]
    socket = socket_vertices(mesh, mask)
    opened = pose_jaw(mesh.V, jaw_weights(mesh.V, socket, socket_rim(mesh.F, socket)), degrees)
    placed = TexturedMesh(opened - opened.mean(0), mesh.F, mesh.UV, mesh.F_uv)
    return placed, mask, ring_cameras(3, 256)


@pytest.fixture(scope="module")
def bust_scene(small_bust):
    return opened_bust(small_bust, 3.0)


def references(placed, mask, cameras, cavity: float):
    """Targets rendered from the bust itself with a plain skin texture whose socket is ``cavity`` bright."""
    from gpja.lighting import uniform_sh
    from gpja.register.hra import ExpressionTargets
    from gpja.render import Topology, render_views

    socket_texels = torch.nn.functional.interpolate(mask.permute(2, 0, 1)[None], size=(64, 64), mode="nearest")[0, 0] < 0.5
    texture = torch.full((64, 64, 3), 0.6)
    texture[socket_texels] = cavity
    sh = torch.tensor(uniform_sh(), dtype=torch.float32)
    ref = render_views(torch.tensor(placed.V, dtype=torch.float32), Topology(torch.from_numpy(placed.F), torch.from_numpy(placed.F_uv)),
                       cameras, ("color", "depth", "normal"), uv=torch.tensor(placed.UV, dtype=torch.float32),
                       texture=texture, mask_texture=mask, sh=sh)
    return ExpressionTargets(cameras, *(ref.dense(p).detach() for p in ("color", "depth", "normal", "coverage")), sh)


def test_rim_pairs_split_the_rim_and_pair_across_the_mouth(bust_scene, small_bust):
    placed, mask, _ = bust_scene
    socket = socket_vertices(placed, mask)
    lower, partner, rim, _ = rim_pairs(placed, socket)
    assert len(lower) and set(lower) <= set(rim) and set(partner) <= set(rim)
    assert not set(lower) & set(partner)
    assert np.median(placed.V[lower, 1]) < np.median(placed.V[partner, 1])


def test_an_open_mouth_is_left_open(small_bust):
    """References that show the socket's dark cavity between the lips: the mouth stays open (at the corners of
    the 3-degree scene the coarse bust's socket is under a pixel wide, so the test opens it further)."""
    placed, mask, cameras = opened_bust(small_bust, 5.0)
    targets = references(placed, mask, cameras, cavity=0.03)
    socket = socket_vertices(placed, mask)
    lower, partner, _, _ = rim_pairs(placed, socket)
    before = np.linalg.norm(placed.V[partner] - placed.V[lower], axis=1)
    moved, entry = seal_lips(placed, targets, mask, 1.0, 30.0, progress=lambda s: None)
    assert entry["seen"] > 0 and entry["sealed"] == 0
    assert moved is placed


def test_closed_lips_pull_the_lower_rim_up_and_leave_the_rest(bust_scene):
    """References whose socket shows skin, not a cavity: the lips read as closed, so the lower rim moves towards
    the upper one by about the fraction asked for, and the upper lip and what lies far from the mouth stay."""
    placed, mask, cameras = bust_scene
    targets = references(placed, mask, cameras, cavity=0.6)
    socket = socket_vertices(placed, mask)
    lower, partner, rim, _ = rim_pairs(placed, socket)
    moved, entry = seal_lips(placed, targets, mask, 0.5, 30.0, progress=lambda s: None)
    assert entry["sealed"] == entry["seen"] > 0
    before = np.linalg.norm(placed.V[partner] - placed.V[lower], axis=1)
    after = np.linalg.norm(placed.V[partner] - moved.V[lower], axis=1)
    assert np.median(after / before) < 0.9  # half-way asked; on the coarse bust the smooth solve gets part of it
    assert (after <= before + EXACT).mean() > 0.9
    shift = np.linalg.norm(moved.V - placed.V, axis=1)
    rim_move = np.median(shift[lower])
    from scipy.spatial import cKDTree
    far = cKDTree(placed.V[rim]).query(placed.V)[0] > FAR_MM
    assert np.median(shift[far]) < STAY_FRACTION * rim_move
    upper_rim = np.setdiff1d(rim, lower)
    assert np.median(shift[upper_rim]) < 0.25 * rim_move
    # deterministic, and the same mesh with fraction 1 moves further
    again, _ = seal_lips(placed, targets, mask, 0.5, 30.0, progress=lambda s: None)
    np.testing.assert_array_equal(again.V, moved.V)
    further, _ = seal_lips(placed, targets, mask, 1.0, 30.0, progress=lambda s: None)
    assert np.median(np.linalg.norm(placed.V[partner] - further.V[lower], axis=1)) < np.median(after)


def test_the_gap_that_counts_as_contact_is_a_few_millimetres():
    assert 1.0 <= CONTACT_MM <= 4.0


def test_lip_seal_setting_is_checked():
    Schedule(lambdas=(1.0,), iterations=(1,), lip_seal=0.5)
    for bad in (0.0, -0.2, 1.5):
        with pytest.raises(ValueError, match="lip_seal"):
            Schedule(lambdas=(1.0,), iterations=(1,), lip_seal=bad)
