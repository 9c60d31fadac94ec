"""gpja.metrics.texture_quality: texels -> template surface -> scan -> rest space -> albedo, and the scores."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gpja.cli import main
from gpja.data.synthetic.albedo import albedo_tables, evaluate_albedo
from gpja.data.synthetic.head import HeadParams
from gpja.errors import InputError
from gpja.io import read_image, write_image, write_json, write_npz
from gpja.mesh import TexturedMesh, write_obj, write_ply
from gpja.metrics.texture_quality import (
    ERROR_IMAGE_FILE,
    OBSERVED_FILE,
    QUALITY_FILE,
    fit_gain,
    texel_albedo,
    texture_quality,
)
from tests.tolerances import PHOTOMETRIC_EXACT, UINT8_STEP

SQUARE_UV = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])


def plane_grid(half: float, step: float, z: float):
    """A flat square grid in the plane ``z``, mm: (V, F), counter-clockwise seen from +Z."""
    ticks = np.arange(-half, half + step / 2, step)
    x, y = np.meshgrid(ticks, ticks, indexing="xy")
    V = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    k = len(ticks)
    i, j = np.meshgrid(np.arange(k - 1), np.arange(k - 1), indexing="ij")
    a = (i * k + j).ravel()
    return V, np.concatenate([np.column_stack([a, a + 1, a + k + 1]), np.column_stack([a, a + k + 1, a + k])])


def square_template(half: float = 40.0, z: float = 100.0):
    """The template: one square of two triangles in the plane z, its UVs spanning the whole texture."""
    V = np.column_stack([(SQUARE_UV * 2 - 1) * half, np.full(4, z)])
    return V, SQUARE_F


def test_texel_albedo_is_the_albedo_of_each_texels_rest_point():
    V, F = square_template()
    scan = plane_grid(60.0, 5.0, 100.0)
    rest = scan[0] * 0.5 + np.array([1.0, 2.0, 3.0])  # an affine rest map: interpolation is exact

    def albedo(X):
        return np.column_stack([0.5 + X[:, 0] / 100.0, 0.5 + X[:, 1] / 100.0, np.full(len(X), 0.25)])

    truth, valid = texel_albedo(V, F, SQUARE_UV, SQUARE_F, 16, scan, rest, albedo)
    assert valid.all()
    rows, cols = np.mgrid[0:16, 0:16]
    x = ((cols + 0.5) / 16 * 2 - 1) * 40.0  # the texel's template point
    y = ((1 - (rows + 0.5) / 16) * 2 - 1) * 40.0
    np.testing.assert_allclose(truth[..., 0], 0.5 + (0.5 * x + 1.0) / 100.0, atol=1e-6)
    np.testing.assert_allclose(truth[..., 1], 0.5 + (0.5 * y + 2.0) / 100.0, atol=1e-6)
    # farther than the cap from the scan, or over its rim: no truth
    far, _ = texel_albedo(V + [0, 0, 3.0], F, SQUARE_UV, SQUARE_F, 16, scan, rest, albedo)
    assert not far.any()
    small = plane_grid(20.0, 5.0, 100.0)
    _, inside = texel_albedo(V, F, SQUARE_UV, SQUARE_F, 16, small, small[0], albedo)
    assert inside.sum() == 8 * 8 and inside[4:12, 4:12].all()  # the texels over the small scan, none over its rim


def test_a_texture_equal_to_the_truth_up_to_a_gain_scores_infinite_psnr():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0.1, 0.9, (16, 16, 3))
    valid = np.ones((16, 16), dtype=bool)
    observed = np.zeros((16, 16), dtype=bool)
    observed[:, :10] = True
    scores, image = texture_quality(truth * [0.8, 1.0, 1.1], truth, valid, observed)
    np.testing.assert_allclose(scores["gain"], [0.8, 1.0, 1.1], atol=PHOTOMETRIC_EXACT)
    assert scores["observed"]["psnr"] == math.inf or scores["observed"]["psnr"] > 150
    assert scores["observed"]["ssim"] == pytest.approx(1.0, abs=1e-9)
    assert scores["observed"]["texels"] == 160 and scores["unobserved"]["texels"] == 96
    assert image.shape == (16, 16, 3) and image.dtype == np.float32


def test_unobserved_errors_are_scored_apart_and_the_gain_comes_from_the_observed_texels():
    truth = np.full((16, 16, 3), 0.5)
    texture = truth.copy()
    valid = np.ones((16, 16), dtype=bool)
    valid[0] = False  # a gutter row: neither scored nor in the gain
    observed = np.zeros((16, 16), dtype=bool)
    observed[:8] = True
    texture[8:] += 0.1  # the filled half is off by 0.1: MSE 0.01
    texture[0] = 0.0
    scores, _ = texture_quality(texture, truth, valid, observed)
    np.testing.assert_allclose(scores["gain"], 1.0, atol=PHOTOMETRIC_EXACT)
    assert scores["unobserved"]["psnr"] == pytest.approx(20.0, abs=1e-9)
    assert scores["observed"]["texels"] == 7 * 16 and scores["valid_texels"] == 15 * 16
    assert scores["all"]["psnr"] < scores["observed"]["psnr"]
    with pytest.raises(InputError, match="no texel maps"):
        texture_quality(texture, truth, np.zeros((16, 16), dtype=bool))
    with pytest.raises(ValueError, match="non-zero albedo"):
        fit_gain(texture, np.zeros_like(truth), valid)


def write_template_case(root, size=32):
    """A square template in front of the synthetic head's face, its scan, ground truth and a true texture."""
    V, F = square_template(half=30.0, z=90.0)
    template_dir = root / "template"
    template_dir.mkdir(parents=True)
    write_obj(template_dir / "template.obj", TexturedMesh(V, F, SQUARE_UV, SQUARE_F))
    scan = plane_grid(45.0, 3.0, 90.0)
    write_ply(root / "scans" / "S01" / "3_mouth_stretch.ply", *scan)
    rest = scan[0] + np.array([0.0, -10.0, 8.0])  # rest points near the face's front
    write_npz(root / "gt" / "S01" / "3_mouth_stretch.npz", scan_rest_coords=rest)
    head = HeadParams()
    write_json(root / "gt" / "S01" / "subject.json", {"identity": head.to_dict()})
    tables = albedo_tables(head)
    truth, valid = texel_albedo(V, F, SQUARE_UV, SQUARE_F, size, scan, rest,
                                lambda X: evaluate_albedo(X, tables))
    assert valid.all()
    write_image(template_dir / "texture.png", truth * 0.9)
    return template_dir


def test_files_and_cli_on_a_true_texture(tmp_path, capsys):
    template_dir = write_template_case(tmp_path)
    argv = ["texture-quality", "--subject", "S01", "--template-dir", str(template_dir),
            "--scans-root", str(tmp_path / "scans"), "--ground-truth-root", str(tmp_path / "gt"),
            "--output", str(template_dir / QUALITY_FILE), "--error-image", str(template_dir / ERROR_IMAGE_FILE)]
    assert main(argv) == 0
    out = json.loads((template_dir / QUALITY_FILE).read_text())
    assert out["observed_source"].startswith("all valid texels")
    assert out["observed"]["psnr"] > 20 * math.log10(2 / UINT8_STEP)  # 8-bit quantisation only: > 54 dB
    assert out["unobserved"]["texels"] == 0 and out["unobserved"]["psnr"] is None
    np.testing.assert_allclose(out["gain"], 0.9, atol=0.01)
    assert read_image(template_dir / ERROR_IMAGE_FILE).shape == (32, 32, 3)
    assert "texture-quality: S01: observed PSNR" in capsys.readouterr().out
    # with the observed mask beside the texture: the texels it marks 0 are the unobserved ones
    mask = np.full((32, 32), 255, np.uint8)
    mask[:, :8] = 0
    write_image(template_dir / OBSERVED_FILE, mask)
    assert main(argv) == 0
    out = json.loads((template_dir / QUALITY_FILE).read_text())
    assert out["observed_source"] == OBSERVED_FILE and out["unobserved"]["texels"] == 32 * 8
    write_image(template_dir / OBSERVED_FILE, mask[:16])
    assert main(argv) == 2
    assert f"{template_dir / OBSERVED_FILE}: is 32x16" in capsys.readouterr().err
