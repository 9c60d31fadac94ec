"""Tests of gpja.data.ground_truth: the lighting the registration reads."""
import numpy as np

from gpja.data.ground_truth import lighting_for
from gpja.io import write_npz
from gpja.lighting import uniform_sh


def test_ground_truth_lighting_or_uniform_light(tmp_path):
    sh = np.random.default_rng(0).normal(size=(9, 3))
    write_npz(tmp_path / "S01" / "2_smile.npz", sh=sh)
    np.testing.assert_array_equal(lighting_for("S01", "2_smile", tmp_path), sh)
    np.testing.assert_array_equal(lighting_for("S01", "2_smile", None), uniform_sh(1.0))
