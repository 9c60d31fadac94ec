import numpy as np
import pytest

from gpja.data.synthetic.expressions import (DEFAULT_EXPRESSIONS, EXPRESSIONS, JAW_PIVOT_MM, _rot_x,
                                             expression_displacement, jacobian_determinants,
                                             lower_face_weight, map_to_expression, smoothstep)
from gpja.data.synthetic.head import HeadParams, build_head_program, extract_rest_mesh

IDENTITY_TOL_MM = 1e-3
JACOBIAN_MIN = 0.0
SAMPLE_VOXEL_MM = 1.2


@pytest.fixture(scope="module")
def rest_points():
    p = HeadParams()
    V, _ = extract_rest_mesh(build_head_program(p)["head"], SAMPLE_VOXEL_MM)
    return p, V[::3]


def test_names_and_defaults():
    assert len(EXPRESSIONS) == 20 and EXPRESSIONS[0] == "1_neutral" and EXPRESSIONS[-1] == "20_brow_lower"
    assert len(DEFAULT_EXPRESSIONS) == 10 and set(DEFAULT_EXPRESSIONS) <= set(EXPRESSIONS)
    for e in ("1_neutral", "2_smile", "3_mouth_stretch", "5_jaw_left", "12_lip_puckerer", "13_lip_funneler",
              "17_cheek_blowing", "18_eye_closed", "19_brow_raiser"):
        assert e in DEFAULT_EXPRESSIONS


def test_smoothstep_analytic():
    assert smoothstep(0.0, 1.0, np.array([-1.0, 0.0, 0.5, 1.0, 2.0])).tolist() == [0.0, 0.0, 0.5, 1.0, 1.0]
    assert smoothstep(1.0, 0.0, np.array([0.25]))[0] == pytest.approx(1 - 0.15625)


def test_rest_is_identity_and_neutral_local(rest_points):
    p, X = rest_points
    assert np.array_equal(map_to_expression(X, p, "rest"), X)
    d = np.linalg.norm(expression_displacement(X, p, "1_neutral"), axis=1)
    assert d.max() < 3.5  # lips close by ~2.8 mm each
    far = X[:, 1] > 20.0  # eyes and up: untouched
    assert d[far].max() < IDENTITY_TOL_MM


def test_jaw_is_rigid_where_weight_is_one():
    p = HeadParams()
    X = np.array([[0.0, p.mouth_y - 30.0, 85.0]])
    assert lower_face_weight(X, p)[0] == pytest.approx(1.0)
    Y = map_to_expression(X, p, "3_mouth_stretch")
    R = _rot_x(22.0)
    expect = (X - JAW_PIVOT_MM) @ R.T + JAW_PIVOT_MM + np.array([0, 0, 0.25 * 22.0])
    from gpja.data.synthetic.expressions import _corners
    expect = expect + _corners(X, p, -1.0, 2.0, 0.0)
    assert np.allclose(Y, expect, atol=1e-9)


@pytest.mark.parametrize("expression", EXPRESSIONS)
def test_no_folds_on_the_surface(rest_points, expression):
    p, X = rest_points
    det = jacobian_determinants(X, p, expression)
    assert det.min() > JACOBIAN_MIN, X[np.argmin(det)]


def test_mouth_opens_and_eyes_close():
    from gpja.data.synthetic.landmarks import rest_landmarks

    p = HeadParams()
    L = rest_landmarks(p)
    gap = lambda e: np.linalg.norm(np.diff(map_to_expression(L[[62, 66]], p, e), axis=0))  # noqa: E731
    assert gap("1_neutral") < 1.0 and gap("rest") > 4.0 and gap("3_mouth_stretch") > 20.0
    lid = map_to_expression(L[[37, 38]], p, "18_eye_closed")
    low = L[[41, 40]]
    assert np.all(lid[:, 1] < low[:, 1] + 1.0)  # upper lid reaches the lower lid


def test_regression_mouth_stretch_chin_drop():
    p = HeadParams()
    X = np.array([[0.0, -105.0, 80.0]])
    d = expression_displacement(X, p, "3_mouth_stretch")[0]
    assert d[1] == pytest.approx(-22.53, abs=0.05)
