import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from gpja.camera import Camera, framing_camera, most_frontal_view
from gpja.errors import InputError
from tests.conftest import distort_image, make_cameras, smooth_image
from tests.tolerances import EXACT_F64, FIGURE_CENTRE_PX, IMAGE_ROUNDTRIP_RATIO, UNDISTORT_PX


def frontal(distortion=None):
    K = np.array([[1000.0, 0, 255.5], [0, 1000.0, 255.5], [0, 0, 1]])
    return Camera.look_at((0, 0, 600), (0, 0, 0), (0, 1, 0), K, 512, 512, distortion=distortion, name="0")


def test_project_analytic_pinhole():
    cam = frontal()
    uv, z = cam.project(np.array([[0.0, 0, 0], [0, 60, 0], [30, 0, 0]]))
    # the head frame's +Y is image-up and +X image-right for a camera in front of the face
    np.testing.assert_allclose(uv, [[255.5, 255.5], [255.5, 155.5], [305.5, 255.5]], atol=EXACT_F64)
    np.testing.assert_allclose(z, [600, 600, 600], atol=EXACT_F64)
    np.testing.assert_allclose(cam.center, [0, 0, 600], atol=EXACT_F64)


def test_project_matches_opencv():
    cam = make_cameras()[2]
    X = np.random.default_rng(0).normal(scale=60, size=(50, 3))
    rvec, _ = cv2.Rodrigues(cam.R)
    ref, _ = cv2.projectPoints(X, rvec, cam.t, cam.K, cam.distortion)
    uv, _ = cam.project(X)
    np.testing.assert_allclose(uv, ref[:, 0], atol=1e-6)


def test_pixel_rays_invert_projection():
    cam = make_cameras()[1]
    X = np.random.default_rng(1).normal(scale=50, size=(100, 3))
    uv, _ = cam.project(X)
    origins, dirs = cam.pixel_rays(uv)
    along = origins + dirs * np.linalg.norm(X - origins, axis=1, keepdims=True)
    np.testing.assert_allclose(along, X, atol=UNDISTORT_PX)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=1), 1.0, atol=EXACT_F64)


def test_transformed_keeps_pixels_and_scales_depth():
    cam = make_cameras()[2]
    X = np.random.default_rng(2).normal(scale=50, size=(20, 3))
    s, R, t = 1.7, Rotation.random(random_state=3).as_matrix(), np.array([10.0, -4.0, 250.0])
    moved = cam.transformed(s, R, t)
    uv0, z0 = cam.project(X)
    uv1, z1 = moved.project((s * X) @ R.T + t)
    np.testing.assert_allclose(uv1, uv0, atol=1e-8)
    np.testing.assert_allclose(z1, s * z0, atol=1e-8)


def test_params_round_trip():
    cam = make_cameras()[2]
    back = Camera.from_params(cam.to_params("5"), "5", "params.json")
    for a in ("K", "Rt", "distortion"):
        np.testing.assert_array_equal(getattr(back, a), getattr(cam, a))
    assert (back.width, back.height, back.name) == (cam.width, cam.height, "5")


@pytest.mark.parametrize("key", ["K", "Rt", "distortion", "width", "height"])
def test_params_missing_key_names_file_and_key(key):
    params = make_cameras()[0].to_params("0")
    del params[f"0_{key}"]
    with pytest.raises(InputError, match=rf"cams\.json: view '0': key '0_{key}' missing"):
        Camera.from_params(params, "0", "cams.json")


def test_params_bad_shape():
    params = make_cameras()[0].to_params("0")
    params["0_K"] = [[1, 0], [0, 1]]
    with pytest.raises(InputError, match="shape"):
        Camera.from_params(params, "0", "cams.json")


def test_undistort_image_inverts_distortion():
    cam = make_cameras(size=128)[0]
    ideal = smooth_image(cam)
    distorted = distort_image(cam, ideal)
    back = cam.undistort_image(distorted)
    interior = np.s_[8:-8, 8:-8]  # the border holds replicated pixels
    change = np.abs(distorted[interior] - ideal[interior]).mean()
    assert change > 1e-3  # distortion did change the image, so the check is not vacuous
    assert np.abs(back[interior] - ideal[interior]).mean() < IMAGE_ROUNDTRIP_RATIO * change


def test_resized_camera_matches_resampled_pixels():
    cam = frontal()
    small = cam.resized(128, 128)
    X = np.random.default_rng(4).normal(scale=50, size=(10, 3))
    uv, _ = cam.project(X)
    uv_small, _ = small.project(X)
    # pixel centres at integers: u_small + 0.5 = (u + 0.5) * 128 / 512
    np.testing.assert_allclose(uv_small + 0.5, (uv + 0.5) / 4, atol=EXACT_F64)


def test_regression_fixed_camera():
    cam = Camera.look_at((400, 50, 450), (0, 10, 0), (0, 1, 0),
                         np.array([[800.0, 0, 320], [0, 810.0, 240], [0, 0, 1]]), 640, 480,
                         distortion=[-0.1, 0.02, 0.001, 0.002, 0.0])
    uv, z = cam.project(np.array([[10.0, 20.0, 30.0]]))
    np.testing.assert_allclose(uv, [[302.634998, 228.636027]], atol=1e-4)
    np.testing.assert_allclose(z, [573.742107], atol=1e-4)


def test_most_frontal_view_picks_the_camera_facing_the_face():
    K = np.array([[500.0, 0, 64], [0, 500.0, 64], [0, 0, 1]])
    side = Camera.look_at([600.0, 0, 100.0], [0, 0, 0], [0, 1, 0], K, 128, 128, name="side")
    front = Camera.look_at([0.0, 0, 600.0], [0, 0, 0], [0, 1, 0], K, 128, 128, name="front")
    assert most_frontal_view([side, front]) == 1
    assert most_frontal_view([front, side]) == 0


# --- framing_camera ----------------------------------------------------------------------------------------

#: The frontal figure camera after its move into framing_camera vs its own earlier arithmetic (same float ops).
FRAMING_SAME_CAMERA = 1e-12


def head_like_points(seed: int = 0) -> np.ndarray:
    """(400, 3) mm: an ellipsoidal cloud off the origin, deeper than wide (a head's proportions, roughly)."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(400, 3)) * [70.0, 90.0, 60.0] + [12.0, -30.0, 45.0]


#: The frontal camera of ``head_like_points`` before ``frontal_camera`` delegated to ``framing_camera``: focal
#: length (px) and centre (mm), computed with the formula it had then (percentile box, eye in front of the box).
FRONTAL_AS_IT_WAS = {64: (94.06053833630965, (-3.442314084961211, -42.36399832608329, 788.5252974687788)),
                     257: (338.1116366246483, (-3.442314084961211, -42.36399832608329, 638.5252974687788))}


@pytest.mark.parametrize("size, kwargs", [(64, {}), (257, {"distance_mm": 450.0, "margin": 1.0})])
def test_framing_camera_at_yaw_0_is_the_frontal_figure_camera(size, kwargs):
    from gpja.report.drawing import frontal_camera

    P = head_like_points()
    focal, centre = FRONTAL_AS_IT_WAS[size]
    for cam in (frontal_camera(P, size, **kwargs), framing_camera(P, size, yaw_deg=0.0, name="frontal", **kwargs)):
        np.testing.assert_allclose(cam.K, [[focal, 0, (size - 1) / 2], [0, focal, (size - 1) / 2], [0, 0, 1]],
                                   rtol=0, atol=FRAMING_SAME_CAMERA)
        np.testing.assert_allclose(cam.center, centre, rtol=0, atol=FRAMING_SAME_CAMERA)
        np.testing.assert_allclose(cam.R, np.eye(3) * [1, -1, -1], rtol=0, atol=FRAMING_SAME_CAMERA)
        assert (cam.name, cam.width, cam.height) == ("frontal", size, size)
        assert not cam.has_distortion


def test_framing_camera_at_yaw_90_looks_along_minus_x_from_the_subjects_left():
    P = head_like_points()
    cam = framing_camera(P, 64, yaw_deg=90.0, name="side")
    centre = (np.percentile(P, 0.5, axis=0) + np.percentile(P, 99.5, axis=0)) / 2.0
    np.testing.assert_allclose(cam.R[2], [-1.0, 0.0, 0.0], atol=EXACT_F64)  # optical axis along -X
    np.testing.assert_allclose(cam.R[1], [0.0, -1.0, 0.0], atol=EXACT_F64)  # image down = world -Y
    assert cam.center[0] > np.percentile(P[:, 0], 99.5) + 500.0  # on the +X side, ~600 mm out
    np.testing.assert_allclose(cam.center[1:], centre[1:], atol=EXACT_F64)
    assert cam.name == "side"
    # the face (+Z) is on the image's left seen from the subject's left
    left, right = cam.project(np.array([[0.0, 0.0, 40.0], [0.0, 0.0, -40.0]]) + centre)[0][:, 0]
    assert left < right


@pytest.mark.parametrize("yaw", [-35.0, 0.0, 35.0, 90.0, 180.0])
def test_framing_camera_frames_the_points_from_every_yaw(yaw):
    P = head_like_points(1)
    size = 96
    cam = framing_camera(P, size, yaw_deg=yaw, margin=1.12)
    uv, z = cam.project(P)
    assert np.all(z > 0)
    lo, hi = np.percentile(uv, [0.5, 99.5], axis=0)
    assert np.all(lo >= -0.5) and np.all(hi <= size - 0.5)  # the framed 99 % project inside the image
    assert (hi - lo).max() > 0.6 * size  # and fill it (not framed from far too far)
    # the view direction is the frontal one turned by the yaw about +Y, and the framed box's centre
    # (0.5-99.5 percentiles along the image axes and the view direction) is at the image centre
    c, s = np.cos(np.deg2rad(yaw)), np.sin(np.deg2rad(yaw))
    axes = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # rows: image right, world up, towards camera
    np.testing.assert_allclose(-cam.R[2], axes[2], atol=EXACT_F64)
    box_centre = np.percentile(P @ axes.T, [0.5, 99.5], axis=0).mean(axis=0) @ axes
    np.testing.assert_allclose(cam.project(box_centre[None])[0][0], [(size - 1) / 2] * 2, atol=FIGURE_CENTRE_PX)


def test_framing_camera_mirrors_with_the_yaw():
    P = head_like_points(2)
    plus, minus = framing_camera(P, 64, yaw_deg=35.0), framing_camera(P * [-1, 1, 1], 64, yaw_deg=-35.0)
    np.testing.assert_allclose(minus.center, plus.center * [-1, 1, 1], atol=EXACT_F64)
    np.testing.assert_allclose(minus.K, plus.K, atol=EXACT_F64)


def test_framing_camera_rejects_empty_or_non_finite_points():
    with pytest.raises(ValueError, match="finite points"):
        framing_camera(np.zeros((0, 3)), 32)
    with pytest.raises(ValueError, match="finite points"):
        framing_camera(np.array([[0.0, np.nan, 0.0]]), 32)
