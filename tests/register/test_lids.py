"""gpja.register.lids: the openings found in a texture, the eyeball's centre, the lid's turn and its search."""
import numpy as np
import pytest
import torch

from gpja.register.jaw import FINE_STEP_DEG
from gpja.register.lids import (EYE_RADIUS_MM, MIN_OPENING_FRACTION, eye_rigs, find_openings, fit_centre, pose_lids,
                                search_lids)
from gpja.register.multiscale import Schedule
from tests.apply.spheres import latlong_sphere

#: float64 identities (rotations about the eyeball's centre), mm and radians.
EXACT = 1e-9
#: the eyeball's centre found from texels on a faceted sphere (chords sag 0.004 mm at 3 degrees), mm
CENTRE_MM = 0.05
#: an opening's height read from texels of 1.4 degrees of latitude each (the hull runs through the outer texels'
#: centres, half a texel inside the almond's edge), degrees
OPENING_DEG = 3.0

SIZE = 128
SKIN = (0.60, 0.42, 0.33)


def eye_texture(columns=(95.5,), seed=0) -> np.ndarray:
    """(SIZE, SIZE, 3) float32 skin with smooth blotches (so a sliding lid is seen) and an almond opening centred on
    each of ``columns`` at the equator's row: white with a blue iris in its middle."""
    rng = np.random.default_rng(seed)
    blotches = np.kron(rng.uniform(-0.08, 0.08, (16, 16, 1)), np.ones((SIZE // 16, SIZE // 16, 1)))
    texture = np.clip(np.array(SKIN)[None, None] + blotches, 0.0, 1.0)
    rows, cols = np.mgrid[0:SIZE, 0:SIZE].astype(np.float64)
    for c in columns:
        opening = ((cols - c) / 14.0) ** 2 + ((rows - 63.5) / 8.0) ** 2 <= 1.0
        texture[opening] = (0.86, 0.85, 0.83)
        texture[opening & ((cols - c) ** 2 + (rows - 63.5) ** 2 <= 5.5 ** 2)] = (0.20, 0.30, 0.60)
    return texture.astype(np.float32)


@pytest.fixture(scope="module")
def eye():
    """An eyeball (a lat-long sphere of the eye's radius at the origin) whose front (+Z, u = 0.75: texel column 95.5)
    shows the opening."""
    mesh = latlong_sphere(64, 128, EYE_RADIUS_MM)
    texture = eye_texture()
    return mesh, texture, eye_rigs(mesh, texture)


def angle(P: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Elevation about the x axis through ``centre``: 0 straight ahead (+Z), positive up."""
    return np.arctan2(P[:, 1] - centre[1], P[:, 2] - centre[2])


def test_two_eyes_are_found_where_the_whites_are_and_a_texture_without_them_has_none():
    hulls = find_openings(eye_texture(columns=(40, 90)))
    assert len(hulls) == 2
    centres = sorted(h.mean(axis=0)[0] for h in hulls)
    np.testing.assert_allclose(centres, [40, 90], atol=2.0)
    for h in hulls:
        assert abs(h.mean(axis=0)[1] - 63.5) < 2.0
        assert 26 <= np.ptp(h[:, 0]) <= 30 and 14 <= np.ptp(h[:, 1]) <= 18  # the almond, iris included
    skin = np.broadcast_to(np.array(SKIN, dtype=np.float32), (SIZE, SIZE, 3)).copy()
    assert find_openings(skin) == []
    skin[10, 10] = (0.9, 0.9, 0.9)  # a highlight's texel is no eye
    assert find_openings(skin) == []


def test_a_white_seen_only_in_fragments_still_joins_its_eye():
    """A white few views saw is fused into isolated texels, each below the size that starts an eye; they join the
    eye next to them, so that its opening spans the iris (a 5-view capture lost one eye's lid search without)."""
    texture = eye_texture(columns=(40, 90))
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    inner = (((cols - 90) / 14.0) ** 2 + ((rows - 63.5) / 8.0) ** 2 <= 1.0) & (cols < 90)  # the inner half
    texture[inner & ((rows % 2 == 1) | (cols % 2 == 1))] = SKIN  # single white texels, none touching another
    scattered = (rows < 30) & (rows % 2 == 0) & (cols % 2 == 0)  # single whites on the brow, far from either eye
    texture[scattered] = (0.86, 0.85, 0.83)
    right = lambda hulls: max(hulls, key=lambda h: h[:, 0].mean())  # noqa: E731
    whole, cut = right(find_openings(texture)), right(find_openings(texture, join_fragments=False))
    assert 24 <= np.ptp(whole[:, 0]) <= 30 and abs(whole[:, 0].mean() - 90) < 3.0  # the almond, iris included
    assert np.ptp(cut[:, 0]) < 16 and cut[:, 0].min() >= 89  # the outer half alone
    assert all(h[:, 1].min() > 50 for h in find_openings(texture))  # the brow's specks join nothing, start nothing


def test_whites_on_the_socket_too_large_or_below_the_mouth_are_no_eyes(eye):
    texture = eye_texture(columns=(40, 90))
    teeth = np.zeros((SIZE, SIZE), dtype=bool)
    teeth[100:108, 30:70] = True  # a row of teeth, larger than either eye's whites (2 % of the texels)
    texture[teeth] = (0.9, 0.9, 0.88)
    assert len(find_openings(texture)) == 2 and find_openings(texture)[0][:, 1].min() >= 100  # taken for an eye
    socket = np.where(teeth, 0.0, 1.0)
    hulls = find_openings(texture, socket)
    assert len(hulls) == 2 and all(abs(h.mean(axis=0)[1] - 63.5) < 2.0 for h in hulls)
    pale = np.full((SIZE, SIZE, 3), 0.85, dtype=np.float32)  # a face as white as an eye's white
    pale[:, :, 0] = 0.88
    assert find_openings(pale) == []
    # the eyeball of the fixture with a mouth socket at its bottom cap (12 mm below its centre, not 30)
    mesh, texture, _ = eye
    cap = np.ones((SIZE, SIZE))
    cap[-8:] = 0.0
    assert eye_rigs(mesh, texture, cap) == []
    assert len(eye_rigs(mesh, texture, np.ones((SIZE, SIZE)))) == 1


def test_the_centre_of_points_on_a_sphere_of_the_eyes_radius_is_found():
    rng = np.random.default_rng(1)
    centre = np.array([31.0, 12.0, 65.0])
    d = rng.normal(size=(200, 3))
    d[:, 2] = np.abs(d[:, 2]) + 1.0  # a cap facing +Z, as an opening does
    points = centre + EYE_RADIUS_MM * d / np.linalg.norm(d, axis=1, keepdims=True)
    np.testing.assert_allclose(fit_centre(points), centre, atol=1e-6)


def test_the_rig_of_the_eyeball_has_its_centre_and_opening(eye):
    _, _, rigs = eye
    assert len(rigs) == 1
    rig = rigs[0]
    np.testing.assert_allclose(rig.centre, 0.0, atol=CENTRE_MM)
    # the almond's half-height is 8 texels of 180 / 128 degrees of latitude each
    assert np.degrees(rig.gap_max) == pytest.approx(2 * 8 * 180 / 128, abs=OPENING_DEG)
    assert np.interp(0.0, *rig.upper) > 0 > np.interp(0.0, *rig.lower)
    # the corners' texels are 13.5 columns of 360 / 128 degrees of longitude from the middle (u = 0.75, +Z)
    half_width = EYE_RADIUS_MM * np.sin(np.radians(13.5 * 360 / 128))
    np.testing.assert_allclose(rig.x_range, (-half_width, half_width), atol=0.05)


def test_no_closing_is_the_identity_and_a_closing_slides_material_over_the_globe(eye):
    mesh, _, rigs = eye
    V = mesh.V
    np.testing.assert_array_equal(pose_lids(V, rigs, 0.0), V)
    np.testing.assert_array_equal(pose_lids(V, [], 30.0), V)
    centre = rigs[0].centre
    for degrees in (10.0, 30.0, 80.0):
        P = pose_lids(V, rigs, degrees)
        np.testing.assert_allclose(np.linalg.norm(P - centre, axis=1), np.linalg.norm(V - centre, axis=1), atol=EXACT)
        np.testing.assert_array_equal(P[:, 0], V[:, 0])  # a turn about the x axis
        behind = V[:, 2] - centre[2] <= 0
        np.testing.assert_array_equal(P[behind], V[behind])
        below = angle(V, centre) < np.interp(V[:, 0], *rigs[0].lower) - EXACT
        np.testing.assert_array_equal(P[below], V[below])
        assert (angle(P, centre) > angle(V, centre) + EXACT).sum() == 0  # lids only come down


def test_the_lid_margin_comes_down_by_the_angle_and_no_further_than_the_lower_margin(eye):
    _, _, rigs = eye
    rig = rigs[0]
    upper, lower = np.interp(0.0, *rig.upper), np.interp(0.0, *rig.lower)
    # a meridian at the opening's middle, from under the lower margin to the brow
    phi = np.linspace(lower - 0.3, upper + 1.2, 400)
    meridian = EYE_RADIUS_MM * np.stack([0 * phi, np.sin(phi), np.cos(phi)], axis=1) + rig.centre
    just_above = np.argmax(phi > upper)
    for degrees in (8.0, 15.0):  # the opening is 21 degrees high
        turned = angle(pose_lids(meridian, rigs, degrees), rig.centre)
        assert turned[just_above] == pytest.approx(phi[just_above] - np.radians(degrees), abs=1e-3)
    for degrees in (15.0, 30.0, 60.0, 90.0):  # 30 and more close more than the opening's height
        turned = angle(pose_lids(meridian, rigs, degrees), rig.centre)
        assert np.all(np.diff(turned) > 0)  # the material keeps its order: nothing folds
        assert np.all(turned[phi > lower] >= lower + MIN_OPENING_FRACTION * (phi[phi > lower] - lower) - EXACT)


def lid_scene(eye, degrees):
    """References of the eyeball with its lid closed by ``degrees``, from three cameras around its front."""
    from gpja.lighting import uniform_sh
    from gpja.register.hra import ExpressionTargets
    from gpja.render import Topology, render_views
    from tests.render.scenes import ring_cameras

    mesh, texture, rigs = eye
    cameras, sh = ring_cameras(3, 128, distance=60.0), torch.tensor(uniform_sh(), dtype=torch.float32)
    closed = pose_lids(mesh.V, rigs, degrees)
    topology = Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv))
    ref = render_views(torch.tensor(closed, dtype=torch.float32), topology, cameras, ("color", "depth", "normal"),
                       uv=torch.tensor(mesh.UV, dtype=torch.float32), texture=torch.tensor(texture), sh=sh)
    targets = ExpressionTargets(cameras, *(ref.dense(p).detach() for p in ("color", "depth", "normal", "coverage")), sh)
    return closed, targets, torch.tensor(texture), torch.ones(4, 4, 1)


def test_the_search_recovers_a_closing_seen_in_the_references(eye):
    closed, targets, texture, mask = lid_scene(eye, 15.0)
    said = []
    posed, entry = search_lids(eye[0], targets, texture, mask, 90.0, progress=said.append)
    assert entry["closing_deg"] == pytest.approx(15.0, abs=FINE_STEP_DEG + EXACT)
    assert entry["score"] < entry["score_at_start"] and entry["eyes"] == 1
    assert "one eye's white found" in said[-1]  # a lid closed alone is said in the log
    assert np.abs(posed.V - closed).max() < 0.5


def test_the_search_keeps_open_eyes_open(eye):
    _, targets, texture, mask = lid_scene(eye, 0.0)
    posed, entry = search_lids(eye[0], targets, texture, mask, 90.0, progress=lambda s: None)
    assert entry["closing_deg"] == 0.0 and posed is eye[0]


def test_a_texture_without_eyes_leaves_the_start(eye):
    _, targets, _, mask = lid_scene(eye, 30.0)
    skin = torch.tensor(SKIN, dtype=torch.float32).expand(SIZE, SIZE, 3).contiguous()
    posed, entry = search_lids(eye[0], targets, skin, mask, 90.0, progress=lambda s: None)
    assert entry["eyes"] == 0 and entry["closing_deg"] == 0.0 and posed is eye[0]


def test_lid_settings_are_checked():
    assert Schedule().lid_search_deg is None  # the paper has no lid search
    Schedule(lid_search_deg=90.0)
    for bad in (0.0, -10.0, 150.0):
        with pytest.raises(ValueError, match="lid_search_deg"):
            Schedule(lid_search_deg=bad)
