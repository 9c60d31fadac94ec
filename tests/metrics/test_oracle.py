"""gpja.metrics.oracle: the ground truth rendered by our renderer and scored like a method."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from gpja.camera import Camera
from gpja.cli import main
from gpja.data.source import DataSource
from gpja.errors import InputError
from gpja.lighting import uniform_sh
from gpja.metrics.evaluate import MetricSettings
from gpja.metrics.oracle import evaluate_oracle, render_ground_truth, score_renders, score_true_geometry
from tests.tolerances import LPIPS_FLOAT32, NOISE_MEAN_DISTANCE_RELATIVE, SCAN_AGAINST_ITSELF_MM

SUBJECT, EXPRESSION = "S01", "3_mouth_stretch"


def plane(half=120.0, step=8.0):
    """A square grid in the plane z = 0 facing +Z, mm."""
    ticks = np.arange(-half, half + step / 2, step)
    x, y = np.meshgrid(ticks, ticks, indexing="xy")
    V = np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])
    k = len(ticks)
    i, j = np.meshgrid(np.arange(k - 1), np.arange(k - 1), indexing="ij")
    a = (i * k + j).ravel()
    return V, np.concatenate([np.column_stack([a, a + 1, a + k + 1]), np.column_stack([a, a + k + 1, a + k])])


def frontal(size=24):
    f = 1.6 * size
    K = np.array([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1.0]])
    return Camera.look_at((0, 0, 300), (0, 0, 0), (0, 1, 0), K, size, size, name="0")


def linear_albedo(X):
    return np.column_stack([0.5 + X[:, 0] / 200.0, 0.5 + X[:, 1] / 200.0, np.full(len(X), 0.3)])


def test_each_pixel_shows_the_albedo_of_its_rest_point_under_uniform_light():
    V, F = plane()
    rest = V * 0.5 + np.array([10.0, -4.0, 0.0])  # an affine rest map: its interpolation is exact
    camera = frontal()
    image = render_ground_truth(V, F, rest, linear_albedo, uniform_sh(1.0), np.ones(3), [camera])[0]
    # the plane z = 0 at each pixel centre, mapped to rest space
    v, u = np.mgrid[0:camera.height, 0:camera.width]
    origins, directions = camera.pixel_rays(np.column_stack([u.ravel(), v.ravel()]).astype(np.float64))
    hits = origins - directions * (origins[:, 2:] / directions[:, 2:])
    expected = linear_albedo(hits * 0.5 + [10.0, -4.0, 0.0]).reshape(image.shape)
    np.testing.assert_allclose(image, expected, atol=1e-4)  # float32 barycentrics
    # a colour gain scales it; supersampling a linear albedo changes nothing but rounding
    gained = render_ground_truth(V, F, rest, linear_albedo, uniform_sh(1.0), np.array([0.5, 1.0, 1.0]), [camera])[0]
    np.testing.assert_allclose(gained[..., 0], 0.5 * image[..., 0], atol=1e-6)
    fine = render_ground_truth(V, F, rest, linear_albedo, uniform_sh(1.0), np.ones(3), [camera], supersample=3)[0]
    np.testing.assert_allclose(fine, image, atol=1e-3)
    with pytest.raises(ValueError, match="supersample"):
        render_ground_truth(V, F, rest, linear_albedo, uniform_sh(1.0), np.ones(3), [camera], supersample=0)


def test_scores_of_identical_renders_are_perfect_and_an_empty_mask_raises():
    rng = np.random.default_rng(1)
    images = rng.uniform(0, 1, (2, 40, 40, 3)).astype(np.float32)
    coverage = np.zeros((2, 40, 40, 1), np.float32)
    coverage[:, 5:35, 5:35] = 1.0
    coverage[1] = 0.0  # view 1 sees nothing: left out of the means
    scores = score_renders(images, images, coverage, ["a", "b"])
    assert scores["psnr"] == math.inf and scores["ssim"] == pytest.approx(1.0)
    assert scores["lpips"] == pytest.approx(0.0, abs=LPIPS_FLOAT32)
    assert [v["view"] for v in scores["per_view"]] == ["a", "b"] and scores["per_view"][1]["psnr"] is None
    with pytest.raises(InputError, match="empty in every view"):
        score_renders(images, images, np.zeros_like(coverage), ["a", "b"])


@pytest.fixture(scope="module")
def tiny_subject(tmp_path_factory):
    """One synthetic expression at 64 px, eight views, the generator's 2x2 supersampling."""
    from gpja.data.synthetic import SynthConfig, synthesize_subject

    root = tmp_path_factory.mktemp("oracle")
    cfg = SynthConfig(seed=3, image_size=64, n_views=8, supersample=2, scan_voxel_mm=1.5, render_voxel_mm=1.5,
                      raw_variant=False, expressions=(EXPRESSION,))
    synthesize_subject(SUBJECT, 1, cfg, root / "images", root / "scans", root / "gt", root / "raw", root / "sheet.png",
                       progress=lambda msg: None)
    return root


@pytest.mark.slow
def test_the_oracle_beats_a_misregistered_or_mislit_ground_truth(tiny_subject, tmp_path):
    from gpja.data.synthetic.albedo import evaluate_albedo
    from gpja.metrics.oracle import expression_truth, subject_albedo
    from gpja.render import render_scan_targets

    source = DataSource(images_root=tiny_subject / "images", scans_root=tiny_subject / "scans")
    out = evaluate_oracle(source, tiny_subject / "gt", SUBJECT, EXPRESSION, targets_path=tmp_path / "targets.npz",
                          out_dir=tmp_path / "details")
    oracle = out["photometric"]
    assert out["method"] == "oracle" and out["oracle"]["supersample"] == 2
    geometry = out["geometry"]  # a noise-free capture: the true surface is the scan itself
    assert geometry["chamfer_l1_mm"] < SCAN_AGAINST_ITSELF_MM and geometry["normal_consistency"] > 0.999
    assert geometry["fscore"]["0.5"] == 1.0
    assert (tmp_path / "details" / "render" / "0.png").is_file() and (tmp_path / "details" / "l1" / "1.png").is_file()
    json.dumps(out)
    # at 64 px the scan's rims and the lids' creases weigh (measured 26.0 dB; 32.3 dB on the CI data, 128 px)
    assert oracle["psnr"] > 24.0

    data = source.load(SUBJECT, EXPRESSION)
    truth = expression_truth(tiny_subject / "gt", SUBJECT, EXPRESSION, len(data.scan.V))
    tables = subject_albedo(tiny_subject / "gt", SUBJECT)
    coverage = render_scan_targets(data.scan.V, data.scan.F, data.cameras, cache_path=tmp_path / "targets.npz")
    images = np.stack(data.images)

    def psnr_of(rest, gain, sh):
        renders = render_ground_truth(data.scan.V, data.scan.F, rest, lambda X: evaluate_albedo(X, tables), sh,
                                      gain, data.cameras, 2)
        return score_renders(renders, images, coverage["coverage"].numpy(), [c.name for c in data.cameras])["psnr"]

    shifted = psnr_of(truth["rest"] + [1.5, 0.0, 0.0], truth["gain"], truth["sh"])  # the albedo slid by 1.5 mm
    mislit = psnr_of(truth["rest"], truth["gain"], uniform_sh(1.0))  # the paper's uniform white light
    assert oracle["psnr"] > shifted + 1.0 and oracle["psnr"] > mislit + 1.0


def test_bad_inputs_name_the_problem(tmp_path, capsys):
    source = DataSource(images_root=tmp_path / "images", scans_root=tmp_path / "scans", rt_scale=tmp_path / "rt.json")
    with pytest.raises(InputError, match="synthetic data in mm"):
        evaluate_oracle(source, tmp_path / "gt", SUBJECT, EXPRESSION)
    argv = ["oracle", "--subject", SUBJECT, "--expression", EXPRESSION, "--images-root", str(tmp_path / "images"),
            "--scans-root", str(tmp_path / "scans"), "--ground-truth-root", str(tmp_path / "gt"),
            "--backend", "cpu", "--output", str(tmp_path / "o.json"), "--output-dir", str(tmp_path / "o")]
    assert main(argv) == 2
    assert "error:" in capsys.readouterr().err and not (tmp_path / "o.json").exists()


def test_the_true_surface_is_the_noise_free_scan(tiny_subject, tmp_path):
    from gpja.data.synthetic import SynthConfig, synthesize_subject
    from gpja.metrics.oracle import expression_truth, true_surface_vertices

    def true_and_scan(root):
        data = DataSource(images_root=root / "images", scans_root=root / "scans").load(SUBJECT, EXPRESSION)
        rest = expression_truth(root / "gt", SUBJECT, EXPRESSION, len(data.scan.V))["rest"]
        return true_surface_vertices(root / "gt", SUBJECT, EXPRESSION, rest), data.scan.V

    V_true, V_scan = true_and_scan(tiny_subject)
    assert np.abs(V_true - V_scan).max() < 1e-3  # no noise: the scan itself (up to the PLY's float32)
    noisy = tmp_path / "noisy"
    cfg = SynthConfig(seed=3, image_size=32, n_views=2, supersample=1, scan_voxel_mm=1.5, render_voxel_mm=1.5,
                      raw_variant=False, expressions=(EXPRESSION,), scan_noise_mm=0.5)
    synthesize_subject(SUBJECT, 1, cfg, noisy / "images", noisy / "scans", noisy / "gt", noisy / "raw",
                       noisy / "sheet.png", progress=lambda msg: None)
    V_true, V_scan = true_and_scan(noisy)
    offset = np.linalg.norm(V_true - V_scan, axis=1)
    assert 0.25 < float(np.median(offset)) < 0.6  # |N(0, 0.5 mm)| has median 0.34 mm: the noise is undone

    # scored like a method, the true surface pays for the noise: each scan vertex lies |N(0, sigma)| off it
    scan = DataSource(images_root=noisy / "images", scans_root=noisy / "scans").load(SUBJECT, EXPRESSION).scan
    geometry = score_true_geometry(V_true, scan.V, scan.F, MetricSettings(samples=20000), scan.path)
    expected = 0.5 * math.sqrt(2.0 / math.pi)
    assert abs(geometry["scan_to_mesh_mm"] - expected) < NOISE_MEAN_DISTANCE_RELATIVE * expected
    assert geometry["mesh_to_scan_mm"] < geometry["scan_to_mesh_mm"]  # the noisy surface runs through the true one
    clean = score_true_geometry(V_true, V_true, scan.F, MetricSettings(samples=20000), scan.path)
    assert clean["chamfer_l1_mm"] < SCAN_AGAINST_ITSELF_MM
    assert geometry["normal_consistency"] < clean["normal_consistency"] - 0.05
