"""Photometric metrics: PSNR/SSIM definitions, a tiny rendered scene, files and bad input."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from gpja.data.source import DataSource
from gpja.errors import InputError
from gpja.io import read_image, write_image, write_json
from gpja.lighting import uniform_sh
from gpja.mesh import TexturedMesh, write_obj
from gpja.metrics.photometric import (
    composite, evaluate_photometric, evaluate_photometric_files, head_mask, mask_crop, masked_psnr, masked_ssim,
    render_with_texture,
)
from gpja.render import render_scan_targets
from gpja.results import LIGHTING_FILE, lighting_record
from tests.conftest import EXPRESSION, SUBJECT
from tests.render.scenes import ring_cameras, sphere, spherical_uv
from tests.tolerances import PHOTOMETRIC_EXACT, SELF_RENDER_PSNR_DB, SSIM_VS_SKIMAGE


def smooth_texture(size: int = 64) -> np.ndarray:
    """(size, size, 3) float32 stripes: enough structure for every metric to see a shift."""
    v, u = np.mgrid[0:size, 0:size].astype(np.float32) / size
    return np.stack([0.5 + 0.4 * np.sin(12 * u), 0.5 + 0.4 * np.cos(9 * v), 0.5 + 0.3 * np.sin(7 * (u + v))], -1)


def textured_sphere(radius: float = 60.0) -> TexturedMesh:
    V, F = sphere(subdivisions=3, radius=radius)
    return TexturedMesh(V, F, spherical_uv(V), F)


@pytest.fixture(scope="module")
def tiny_scene():
    """A textured sphere seen by 2 cameras at 40 px, its own render as reference, its coverage."""
    mesh = textured_sphere()
    texture = smooth_texture()
    cameras = ring_cameras(2, 40, distance=250.0)
    sh = np.zeros((9, 3))
    sh[0] = 2.0 * np.sqrt(np.pi)  # uniform white light: radiance = albedo
    images = render_with_texture(mesh, texture, cameras, sh)
    coverage = render_scan_targets(mesh.V, mesh.F, cameras)["coverage"]
    return mesh, texture, cameras, images, coverage, sh


# --- definitions on arrays ----------------------------------------------------------------

def test_psnr_of_a_uniform_error():
    rng = np.random.default_rng(0)
    reference = rng.uniform(0.2, 0.8, (16, 16, 3))
    mask = np.zeros((16, 16), bool)
    mask[4:12, 2:9] = True
    render = reference + 0.1
    render[~mask] = 0.0  # outside the mask nothing counts
    assert masked_psnr(render, reference, mask) == pytest.approx(-10 * np.log10(0.1 ** 2), abs=PHOTOMETRIC_EXACT)
    assert masked_psnr(reference, reference, mask) == np.inf


def test_ssim_identity_and_a_perturbation_match_scikit_image():
    rng = np.random.default_rng(1)
    reference = rng.uniform(0, 1, (40, 40, 3))
    noisy = np.clip(reference + rng.normal(0, 0.1, reference.shape), 0, 1)
    full = np.ones((40, 40), bool)
    assert masked_ssim(reference, reference, full) == pytest.approx(1.0, abs=PHOTOMETRIC_EXACT)
    _, ssim_full = structural_similarity(noisy, reference, gaussian_weights=True, sigma=1.5, win_size=11,
                                         use_sample_covariance=False, data_range=1, channel_axis=-1, full=True)
    mask = np.zeros((40, 40), bool)
    mask[10:30, 5:25] = True
    assert masked_ssim(noisy, reference, full) == pytest.approx(ssim_full.mean(), abs=SSIM_VS_SKIMAGE)
    assert masked_ssim(noisy, reference, mask) == pytest.approx(ssim_full[mask].mean(), abs=SSIM_VS_SKIMAGE)
    assert masked_ssim(noisy, reference, mask) < 0.99


def test_ssim_on_the_crop_equals_ssim_on_the_whole_image():
    """The module docstring's claim: the crop margin exceeds SSIM's window, so cropping changes nothing."""
    rng = np.random.default_rng(2)
    reference = rng.uniform(0, 1, (80, 90, 3)).astype(np.float32)
    render = np.clip(reference + rng.normal(0, 0.1, reference.shape), 0, 1).astype(np.float32)
    mask = np.zeros((80, 90), bool)
    mask[30:50, 40:60] = True
    rows, cols = mask_crop(mask)
    assert (rows.stop - rows.start, cols.stop - cols.start) < (80, 90)
    whole = masked_ssim(composite(render, reference, mask), reference, mask)
    cropped = masked_ssim(composite(render, reference, mask)[rows, cols], reference[rows, cols], mask[rows, cols])
    assert cropped == pytest.approx(whole, abs=SSIM_VS_SKIMAGE)


def test_crop_reaches_the_minimum_side_inside_the_image():
    mask = np.zeros((40, 60), bool)
    mask[0, 58] = True
    rows, cols = mask_crop(mask, margin=2, min_side=31)
    assert (rows.start, rows.stop - rows.start) == (0, 31)
    assert cols.stop == 60 and cols.stop - cols.start == 31


def test_head_mask_is_scan_coverage_intersected_with_the_user_mask():
    coverage = np.array([[[0.2, 0.5, 1.0]]], np.float32)[..., None]  # (1, 1, 3, 1)
    assert head_mask(coverage).tolist() == [[[False, True, True]]]
    assert head_mask(coverage, np.array([[True, True, False]])).tolist() == [[[False, True, False]]]


# --- a rendered scene ---------------------------------------------------------------------

def test_same_mesh_scores_perfectly_and_a_displaced_one_does_not(tiny_scene, tmp_path):
    mesh, texture, cameras, images, coverage, sh = tiny_scene
    same = evaluate_photometric(mesh, texture, cameras, images, coverage, sh, out_dir=tmp_path)
    assert same["psnr"] >= SELF_RENDER_PSNR_DB
    assert same["ssim"] == pytest.approx(1.0, abs=1e-6) and same["lpips"] == pytest.approx(0.0, abs=1e-6)
    near, moved = (evaluate_photometric(mesh.with_vertices(mesh.V + [shift_mm, 0.0, 0.0]), texture, cameras, images,
                                        coverage, sh) for shift_mm in (3.0, 12.0))
    assert np.isfinite(near["psnr"]) and near["psnr"] < 30.0
    assert moved["psnr"] < near["psnr"] and moved["ssim"] < near["ssim"] < 1.0 - 1e-3
    assert moved["lpips"] > near["lpips"] > 1e-4
    assert [v["view"] for v in moved["per_view"]] == ["0", "1"] and all(v["mask_pixels"] > 0 for v in moved["per_view"])
    json.dumps(moved)
    for view in same["per_view"]:
        assert read_image(tmp_path / view["render"]).shape == (40, 40, 3)
        assert read_image(tmp_path / view["error_image"]).shape == (40, 40, 3)


def test_view_with_empty_mask_is_left_out(tiny_scene):
    mesh, texture, cameras, images, coverage, sh = tiny_scene
    coverage = coverage.numpy().copy()
    coverage[1] = 0.0
    result = evaluate_photometric(mesh, texture, cameras, images, coverage, sh)
    assert result["per_view"][1]["psnr"] is None and result["psnr"] == result["per_view"][0]["psnr"]
    with pytest.raises(InputError, match="empty in every view"):
        evaluate_photometric(mesh, texture, cameras, images, np.zeros_like(coverage), sh)


# --- bad input ----------------------------------------------------------------------------

def test_mesh_without_uvs_or_with_nan_is_rejected(tiny_scene):
    mesh, texture, cameras, images, coverage, sh = tiny_scene
    with pytest.raises(InputError, match="no texture coordinates") as err:
        evaluate_photometric(TexturedMesh(mesh.V, mesh.F), texture, cameras, images, coverage, sh, source="m.obj")
    assert err.value.path == "m.obj"
    V = mesh.V.copy()
    V[3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        evaluate_photometric(mesh.with_vertices(V), texture, cameras, images, coverage, sh, source="m.obj")


@pytest.fixture
def files(facescape_root, tmp_path):
    """Arguments of evaluate_photometric_files for the conftest expression (a 100 mm sphere scan)."""
    template = tmp_path / "template"
    write_image(template / "texture.png", smooth_texture())
    write_json(template / LIGHTING_FILE, lighting_record(uniform_sh(1.0), "uniform", "test"))
    return {"template_dir": template,
            "source": DataSource(images_root=facescape_root["images"], scans_root=facescape_root["scans"]),
            "subject": SUBJECT, "expression": EXPRESSION, "targets_path": tmp_path / "targets.npz"}


def test_files_entry_point(files, tmp_path):
    mesh_path = tmp_path / "registered.obj"
    write_obj(mesh_path, textured_sphere(100.0), texture_name="texture.png")
    two_views = {**files, "source": replace(files["source"], views=("0", "1"))}
    result = evaluate_photometric_files(mesh_path, **two_views, out_dir=tmp_path / "out")
    assert result["mesh"] == str(mesh_path) and result["views"] == 2
    assert all(np.isfinite([result["psnr"], result["ssim"], result["lpips"]]))
    assert (tmp_path / "out" / "l1" / "1.png").is_file() and files["targets_path"].is_file()


def test_the_renders_use_the_template_lighting(files, tmp_path):
    """Every method is rendered under the template's lighting.json (its texture is relative to it)."""
    mesh_path = tmp_path / "registered.obj"
    write_obj(mesh_path, textured_sphere(100.0), texture_name="texture.png")
    one = {**files, "source": replace(files["source"], views=("0",))}
    uniform = evaluate_photometric_files(mesh_path, **one, out_dir=tmp_path / "u")
    assert uniform["lighting"] == str(files["template_dir"] / LIGHTING_FILE)
    dim = uniform_sh(0.5)
    write_json(files["template_dir"] / LIGHTING_FILE, lighting_record(dim, "estimated", "test"))
    estimated = evaluate_photometric_files(mesh_path, **one, out_dir=tmp_path / "e")
    np.testing.assert_allclose(read_image(tmp_path / "e/render/0.png"), 0.5 * read_image(tmp_path / "u/render/0.png"),
                               atol=2.0 / 255)
    given = evaluate_photometric_files(mesh_path, **one, sh=dim)
    assert given["lighting"] == "given" and given["psnr"] == pytest.approx(estimated["psnr"])
    (files["template_dir"] / LIGHTING_FILE).unlink()
    with pytest.raises(InputError, match="not found") as err:
        evaluate_photometric_files(mesh_path, **one)
    assert err.value.path == str(files["template_dir"] / LIGHTING_FILE)


def obj_text(V: np.ndarray, F: np.ndarray) -> str:
    return "".join(f"v {x} {y} {z}\n" for x, y, z in V) + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F)


@pytest.mark.parametrize("case, message", [
    ("no_uv", "no texture coordinates"), ("nan", "NaN"), ("empty", "empty mesh"), ("metres", "different units")])
def test_bad_mesh_files_name_the_file(files, tmp_path, case, message):
    V, F = sphere(subdivisions=2, radius=100.0)
    mesh_path = tmp_path / f"{case}.obj"
    if case == "no_uv":
        mesh_path.write_text(obj_text(V, F))
    elif case == "nan":
        V = V.copy()
        V[0] = np.nan
        mesh_path.write_text(obj_text(V, F))
    elif case == "empty":
        mesh_path.write_text("# nothing\n")
    else:
        write_obj(mesh_path, TexturedMesh(V / 1000.0, F, spherical_uv(V), F), texture_name="texture.png")
    with pytest.raises(InputError, match=message) as err:
        evaluate_photometric_files(mesh_path, **files)
    assert err.value.path == str(mesh_path)


def test_empty_scan_names_the_scan(files, tmp_path):
    mesh_path = tmp_path / "registered.obj"
    write_obj(mesh_path, textured_sphere(100.0), texture_name="texture.png")
    scan = files["source"].scan_file(SUBJECT, EXPRESSION)
    scan.write_bytes(b"")
    with pytest.raises(InputError, match="empty") as err:
        evaluate_photometric_files(mesh_path, **files)
    assert err.value.path == str(scan)
