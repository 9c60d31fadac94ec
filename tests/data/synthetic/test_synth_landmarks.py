import numpy as np

from gpja.data.synthetic.head import HeadParams, build_head_program, evaluate_sdf
from gpja.data.synthetic.landmarks import N_LANDMARKS, NOSE_TIP, rest_landmark_guesses, rest_landmarks

SURFACE_TOL_MM = 0.05
SNAP_MAX_MM = 16.0
MIRROR = ([16 - i for i in range(17)] + [26 - i for i in range(10)] + [27, 28, 29, 30] + [35, 34, 33, 32, 31]
          + [45, 44, 43, 42, 47, 46, 39, 38, 37, 36, 41, 40] + [54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55]
          + [64, 63, 62, 61, 60, 67, 66, 65])


def test_on_surface_and_near_guesses():
    p = HeadParams()
    L = rest_landmarks(p)
    assert L.shape == (N_LANDMARKS, 3)
    assert np.abs(evaluate_sdf(L, build_head_program(p)["head"])).max() < SURFACE_TOL_MM
    assert np.linalg.norm(L - rest_landmark_guesses(p), axis=1).max() < SNAP_MAX_MM


def test_mirror_symmetry_of_the_symmetric_head():
    L = rest_landmarks(HeadParams())
    M = L[MIRROR] * np.array([-1, 1, 1])
    assert np.abs(M - L).max() < 0.05


def test_ibug_layout_regression():
    L = rest_landmarks(HeadParams())
    assert L[NOSE_TIP, 2] == L[27:36, 2].max()   # the nose tip sticks out most
    assert L[0, 0] < 0 < L[16, 0]                # jaw runs from the subject's right (-X) to left
    assert L[8, 1] == L[:17, 1].min()            # chin lowest
    assert L[36, 0] < L[39, 0] < L[42, 0] < L[45, 0]
    assert L[51, 1] > L[62, 1] > L[66, 1] > L[57, 1]
