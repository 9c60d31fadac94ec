import numpy as np
import pytest

from gpja.data.synthetic.albedo import albedo_tables, evaluate_albedo, project_to_surface, skin_rgb
from gpja.data.synthetic.head import EYE_RADIUS_MM, HeadParams, build_head_program, evaluate_sdf, sample_head_params

SURFACE_TOL_MM = 0.05


@pytest.fixture(scope="module")
def head():
    p = HeadParams()
    return p, albedo_tables(p)


def test_range_and_determinism(head):
    p, tab = head
    X = np.random.default_rng(0).uniform(-100, 100, (5000, 3))
    a = evaluate_albedo(X, tab)
    assert a.shape == (5000, 3) and a.min() >= 0 and a.max() <= 1
    assert np.array_equal(a, evaluate_albedo(X, albedo_tables(p)))


def test_eye_pupil_and_mouth_cavity_are_dark_sclera_bright(head):
    p, tab = head
    c = p.eye_center(1)
    pupil = c + np.array([0, 0, EYE_RADIUS_MM])
    sclera = c + EYE_RADIUS_MM * np.array([np.sin(np.radians(50)), 0, np.cos(np.radians(50))])
    prog = build_head_program(p)["head"]
    cavity = project_to_surface(np.array([[0.0, p.mouth_y - 6.0, 62.0]]), prog)[0]
    a = evaluate_albedo(np.stack([pupil, sclera, cavity]), tab)
    assert a[0].max() < 0.1 and a[1].min() > 0.5 and a[2].max() < 0.12


def test_high_frequency_detail_on_cheek(head):
    p, tab = head
    prog = build_head_program(p)["head"]
    # a 10 mm line across the cheek, 0.25 mm steps: the texture must vary at pixel scale
    line = np.stack([np.linspace(30, 40, 41), np.full(41, -25.0), np.full(41, 100.0)], 1)
    X = project_to_surface(line, prog)
    assert np.abs(evaluate_sdf(X, prog)).max() < SURFACE_TOL_MM
    lum = evaluate_albedo(X, tab).mean(1)
    assert np.abs(np.diff(lum)).mean() > 0.003


def test_skin_tone_follows_seed():
    a = skin_rgb(sample_head_params(np.random.default_rng(0)))
    b = skin_rgb(sample_head_params(np.random.default_rng(1)))
    assert not np.allclose(a, b)


def test_regression_nose_tip_albedo(head):
    p, tab = head
    from gpja.data.synthetic.landmarks import rest_landmarks

    a = evaluate_albedo(rest_landmarks(p)[30:31], tab)[0]
    assert a == pytest.approx(REGRESSION_NOSE_TIP_RGB, abs=1e-6)


REGRESSION_NOSE_TIP_RGB = [0.7704582908928281, 0.4974076141038878, 0.4120300458625195]
