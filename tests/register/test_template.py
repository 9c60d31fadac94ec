import numpy as np
import pytest
import torch

from gpja.lighting import uniform_sh
from gpja.mesh import TexturedMesh
from gpja.register.hra import ExpressionTargets
from gpja.register.multiscale import Schedule
from gpja.register.remesh import refine_by_factor
from gpja.register.template import (TemplateSettings, build_texture, create_template, decimate_with_texture,
                                    LUMINANCE, mask_mouth_interior, reconstruct_texture)
from gpja.render import Topology, render_scan_targets, render_views
from tests.render.test_passes import surface_distance, tetrahedral_cameras
from tests.register.test_remesh import seamed_sphere
from tests.tolerances import TEMPLATE_ALBEDO_UP_TO_SCALE, TEMPLATE_LIGHTING_RELATIVE, TEMPLATE_REFINE_CHANGE

#: Render of a reconstructed texture vs the references, dB over covered pixels.
MIN_TEXTURE_PSNR_DB = 30.0
#: Renders before/after texture-preserving decimation, dB.
MIN_DECIMATION_PSNR_DB = 25.0


def render_color(mesh, texture, cams, sh):
    out = render_views(torch.tensor(mesh.V, dtype=torch.float32), Topology(torch.tensor(mesh.F), torch.tensor(mesh.F_uv)),
                       cams, ("color",), uv=torch.tensor(mesh.UV, dtype=torch.float32), texture=texture, sh=sh)
    return out.dense("color").detach(), out.dense("coverage").detach()[..., 0] > 0.99


def psnr(a, b, mask):
    return float(10 * np.log10(1.0 / ((a - b) ** 2)[mask].mean().clamp_min(1e-12).item()))


def smooth_texture(size=64):
    v, u = np.mgrid[0:size, 0:size] / size
    return torch.tensor(np.stack([0.5 + 0.3 * np.sin(6 * u), 0.5 + 0.3 * np.cos(5 * v), 0.4 + 0.2 * np.sin(4 * (u + v))], -1),
                        dtype=torch.float32)


def test_texture_reconstruction_reproduces_the_references():
    mesh = seamed_sphere(subdivisions=4)
    cams = tetrahedral_cameras(96)
    sh = torch.tensor(uniform_sh(), dtype=torch.float32)
    images, mask = render_color(mesh, smooth_texture(), cams, sh)
    t = render_scan_targets(mesh.V, mesh.F, cams)
    targets = ExpressionTargets(cams, images, t["depth"], t["normal"], t["coverage"], sh)
    tex = reconstruct_texture(mesh, targets, size=64, iterations=150, lr=0.05, progress=lambda m: None)
    assert tex.shape == (64, 64, 3) and 0 <= tex.min() and tex.max() <= 1
    again, _ = render_color(mesh, torch.tensor(tex), cams, sh)
    assert psnr(again, images, mask) >= MIN_TEXTURE_PSNR_DB


def test_decimation_keeps_the_texture_mapping():
    mesh = refine_by_factor(refine_by_factor(seamed_sphere(subdivisions=3), 2.5), 2.5)
    tex = smooth_texture()
    coarse = decimate_with_texture(TexturedMesh(mesh.V, mesh.F, mesh.UV, mesh.F_uv, tex.numpy()), 1500)
    assert abs(len(coarse.F) - 1500) <= 10 and coarse.has_uv and coarse.texture is not None
    cams = tetrahedral_cameras(96)
    sh = torch.tensor(uniform_sh(), dtype=torch.float32)
    a, mask = render_color(mesh, tex, cams, sh)
    b, _ = render_color(coarse, tex, cams, sh)
    assert psnr(a, b, mask) >= MIN_DECIMATION_PSNR_DB
    assert surface_distance(coarse.V, mesh.V, mesh.F).max() < 0.05 * mesh.edge_lengths().mean() * 10


def spotted_texture(size=64):
    """Skin-like constant albedo with a few dark spots (what the constant-albedo light fit must reject)."""
    tex = np.empty((size, size, 3), np.float32)
    tex[:] = (0.7, 0.5, 0.4)
    tex[10:16, 10:20] = (0.2, 0.1, 0.1)
    tex[40:44, 30:50] = (0.3, 0.15, 0.1)
    return torch.tensor(tex)


@pytest.fixture(scope="module")
def lit_sphere():
    from tests.register.test_texture_fusion import directional_sh

    mesh = seamed_sphere(subdivisions=4)
    cams = tetrahedral_cameras(96)
    sh = directional_sh()
    images, _ = render_color(mesh, spotted_texture(), cams, torch.tensor(sh, dtype=torch.float32))
    t = render_scan_targets(mesh.V, mesh.F, cams)
    # the targets' own lighting is a decoy: template creation must not use it
    targets = ExpressionTargets(cams, images, t["depth"], t["normal"], t["coverage"], torch.zeros(9, 3))
    return mesh, targets, sh


def test_build_texture_estimates_the_lighting_and_fuses_the_albedo(lit_sphere):
    from gpja.metrics.lighting import sh_relative_error

    mesh, targets, sh = lit_sphere
    settings = TemplateSettings(texture_size=64, texture_size_from_images=False)
    texture, observed, estimate, log = build_texture(mesh, targets, settings, progress=lambda m: None)
    assert texture.shape == (64, 64, 3) and observed.shape == (64, 64) and log["size"] == 64
    assert sh_relative_error(estimate, sh) < TEMPLATE_LIGHTING_RELATIVE
    # the albedo is the truth up to the light's per-channel scale
    truth = spotted_texture().numpy()
    ratio = np.median(texture[observed] / truth[observed], axis=0)
    assert np.abs(texture[observed] / ratio - truth[observed]).mean() < TEMPLATE_ALBEDO_UP_TO_SCALE
    np.testing.assert_allclose(estimate[0] * ratio, sh[0], rtol=TEMPLATE_LIGHTING_RELATIVE)


def test_build_texture_with_uniform_light_and_with_the_papers_optimisation(lit_sphere):
    mesh, targets, _ = lit_sphere
    quiet = dict(progress=lambda m: None)
    fused, observed, sh, _ = build_texture(mesh, targets, TemplateSettings(texture_size=64), "uniform", **quiet)
    np.testing.assert_array_equal(sh, uniform_sh(1.0))
    settings = TemplateSettings(texture_size=64, texture_method="optimise", texture_iterations=20)
    optimised, observed_opt, _, log = build_texture(mesh, targets, settings, "uniform", **quiet)
    assert log["method"] == "optimise" and optimised.shape == (64, 64, 3)
    np.testing.assert_array_equal(observed_opt, observed)
    with pytest.raises(ValueError):
        TemplateSettings(texture_method="bake")


def test_refinement_starts_from_the_fused_texture_and_keeps_it_smooth(lit_sphere):
    mesh, targets, _ = lit_sphere
    quiet = dict(progress=lambda m: None)
    fused, observed, sh, _ = build_texture(mesh, targets, TemplateSettings(texture_size=64), **quiet)
    lit = ExpressionTargets(targets.cameras, targets.images, targets.depth, targets.normal, targets.coverage,
                            torch.tensor(sh, dtype=torch.float32))
    # no iteration: the fused texture itself
    np.testing.assert_array_equal(reconstruct_texture(mesh, lit, 64, 0, 0.01, init=fused, **quiet), fused)
    refined = reconstruct_texture(mesh, lit, 64, 30, 0.01, init=fused, smoothness=0.5, **quiet)
    assert np.abs(refined - fused)[observed].mean() < TEMPLATE_REFINE_CHANGE


def test_written_template_has_its_observed_texels_and_lighting(tmp_path, lit_sphere):
    from gpja.io import read_image, read_json
    from gpja.register.pipeline import write_template
    from gpja.register.template import Template
    from gpja.results import read_template_lighting

    mesh, _, sh = lit_sphere
    observed = np.zeros((16, 16), bool)
    observed[:8] = True
    textured = TexturedMesh(mesh.V, mesh.F, mesh.UV, mesh.F_uv, np.full((16, 16, 3), 0.5, np.float32))
    template = Template(textured, np.ones((16, 16), np.float32), {"template": textured}, {}, observed, sh, "estimated")
    write_template(template, tmp_path)
    np.testing.assert_array_equal(read_image(tmp_path / "texture_observed.png", mode="L"), observed.astype(np.float32))
    np.testing.assert_allclose(read_template_lighting(tmp_path), sh)
    assert read_json(tmp_path / "lighting.json")["source"] == "estimated"


def socket_texture():
    """A 4x6 texture: skin left, a socket (columns 3-5) of lip, interior, one tooth and one unobserved lip texel."""
    texture = np.full((4, 6, 3), 0.4, dtype=np.float32)
    texture[:, :3] = (0.5, 0.4, 0.3)  # skin: luminance 0.41, red chromaticity 0.42
    texture[:, 3:] = (0.5, 0.25, 0.2)  # lips: luminance 0.30, red 0.53
    texture[1:3, 4:] = (0.05, 0.03, 0.03)  # the cavity: luminance 0.04
    texture[3, 3] = (0.8, 0.8, 0.8)  # a tooth: light but grey (red 0.33)
    socket = np.ones((4, 6), dtype=np.float32)
    socket[:, 3:] = 0.0
    observed = np.ones((4, 6), dtype=bool)
    observed[0, 5] = False
    return socket, texture, observed


def test_the_mouth_mask_keeps_the_sockets_dark_and_unseen_texels_only():
    socket, texture, observed = socket_texture()
    mask = mask_mouth_interior(socket, texture, observed, 0.5)  # luminance threshold 0.5 x 0.41
    expected = np.ones((4, 6), dtype=np.float32)
    expected[1:3, 4:] = 0.0  # the cavity
    expected[3, 3] = 0.0  # the tooth
    expected[0, 5] = 0.0  # no view saw it
    np.testing.assert_array_equal(mask, expected)
    # a threshold above the lips' luminance masks them again: the whole socket
    np.testing.assert_array_equal(mask_mouth_interior(socket, texture, observed, 0.9), socket)
    # dark skin (luminance 0.05): the cavity is not dark against it, and is unmasked too
    dark_skin = texture.copy()
    dark_skin[:, :3] = (0.06, 0.05, 0.04)
    assert mask_mouth_interior(socket, dark_skin, observed, 0.5)[:, 3:].sum() == 10
    # nothing observed outside the socket: no skin to compare with, the socket charts stay
    np.testing.assert_array_equal(mask_mouth_interior(socket, texture, socket < 0.5, 0.5), socket)


def test_the_mouth_mask_setting_is_checked():
    with pytest.raises(ValueError, match="mouth_mask must be one of"):
        TemplateSettings(mouth_mask="lips")
    with pytest.raises(ValueError, match="mouth_mask_dark"):
        TemplateSettings(mouth_mask_dark=1.0)


@pytest.mark.slow
def test_create_template_on_a_synthetic_subject(tmp_path):
    from gpja.data.facescape import load_expression
    from gpja.data.synthetic import SynthConfig, subject_seed_index, synthesize_subject
    from gpja.io import read_npz

    e = "3_mouth_stretch"
    synthesize_subject("S01", subject_seed_index("S01"), SynthConfig(seed=1, image_size=96, scan_voxel_mm=1.5, expressions=(e,),
                                                                   raw_variant=False),
                       tmp_path / "i", tmp_path / "s", tmp_path / "g", tmp_path / "r", tmp_path / "c.png", progress=lambda m: None)
    data = load_expression(tmp_path / "i", "S01", e, scans_root=tmp_path / "s")
    t = render_scan_targets(data.scan.V, data.scan.F, data.cameras)
    sh = torch.tensor(read_npz(tmp_path / "g/S01" / f"{e}.npz")["sh"], dtype=torch.float32)
    targets = ExpressionTargets(data.cameras, torch.tensor(np.stack(data.images)), t["depth"], t["normal"], t["coverage"], sh)
    settings = TemplateSettings(bust_edge_mm=8.0, schedule=Schedule(lambdas=(200.0, 120.0), iterations=(90, 90)),
                                texture_size=128, texture_iterations=60, template_faces=6000, mouth_mask="interior")
    template = create_template(data.scan.V, targets, settings, progress=lambda m: None)
    bust, fitted = template.stages["bust"], template.stages["fitted"]
    before = np.median(surface_distance(data.scan.V, bust.V, bust.F))
    after = np.median(surface_distance(data.scan.V, fitted.V, fitted.F))
    assert after < before / 3, (before, after)
    assert abs(len(template.mesh.F) - 6000) <= 20
    size = template.mesh.texture.shape[0]
    assert size <= 128 and template.mouth_mask.shape == (size, size) and 0 < template.mouth_mask.mean() < 1
    assert template.observed.shape == (size, size) and 0.2 < template.observed.mean() < 1
    assert template.lighting.shape == (9, 3) and template.lighting_source == "estimated"
    assert template.log["lighting"] == template.lighting.tolist()
    # the interior mask: within the socket (at 96 px no lip lands on it: all of it stays), dark texels only
    masked = template.log["mouth_mask"]
    assert masked["kind"] == "interior" and 0 < masked["masked_texels"] <= masked["socket_texels"]
    luminance = template.mesh.texture @ LUMINANCE
    assert np.median(luminance[template.mouth_mask < 0.5]) < 0.5 * np.median(luminance[template.mouth_mask > 0.5])
