import numpy as np
import pytest
import torch

from gpja.lighting import uniform_sh
from gpja.mesh import TexturedMesh
from gpja.register.hra import ExpressionTargets
from gpja.register.multiscale import Schedule
from gpja.register.remesh import refine_by_factor
from gpja.register.template import TemplateSettings, create_template, decimate_with_texture, reconstruct_texture
from gpja.render import Topology, render_scan_targets, render_views
from tests.render.test_passes import surface_distance, tetrahedral_cameras
from tests.register.test_remesh import seamed_sphere

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
                                texture_size=128, texture_iterations=60, template_faces=6000)
    template = create_template(data.scan.V, targets, settings, progress=lambda m: None)
    bust, fitted = template.stages["bust"], template.stages["fitted"]
    before = np.median(surface_distance(data.scan.V, bust.V, bust.F))
    after = np.median(surface_distance(data.scan.V, fitted.V, fitted.F))
    assert after < before / 3, (before, after)
    assert abs(len(template.mesh.F) - 6000) <= 20
    assert template.mouth_mask.shape == (128, 128) and 0 < template.mouth_mask.mean() < 1
