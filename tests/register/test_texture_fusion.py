import numpy as np
import pytest
import torch

from gpja.camera import Camera
from gpja.errors import InputError
from gpja.lighting import uniform_sh
from gpja.mesh import TexturedMesh
from gpja.register.texture_fill import fill_texture, sample_bilinear
from gpja.register.texture_fusion import (FULL_WEIGHT, FusionSettings, choose_texture_size, finish_texture,
                                          observe_texture, robust_mean, texel_albedo, texels_off_scan, view_buffers)
from gpja.render import Topology, render_views
from gpja.render.uv_raster import rasterize_uv, seam_copies, uv_to_texel
from tests.register.test_remesh import seamed_sphere
from tests.render.test_passes import tetrahedral_cameras
from tests.tolerances import FUSION_FLAT_ALBEDO, FUSION_RENDER_PSNR_DB, FUSION_SEAM_AGREEMENT, FUSION_SPHERE_ALBEDO


def plane(size_mm=100.0, n=8, z=0.0, uv_box=(0.05, 0.05, 0.95, 0.95), centre=(0.0, 0.0)):
    """A square grid facing +z (counter-clockwise seen from +z), UVs filling ``uv_box``."""
    t = np.linspace(0.0, 1.0, n + 1)
    gx, gy = np.meshgrid(t, t)
    V = np.stack([centre[0] + (gx.ravel() - 0.5) * size_mm, centre[1] + (gy.ravel() - 0.5) * size_mm,
                  np.full(gx.size, z)], axis=1)
    u0, v0, u1, v1 = uv_box
    UV = np.stack([u0 + gx.ravel() * (u1 - u0), v0 + gy.ravel() * (v1 - v0)], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return TexturedMesh(V, F, UV, F.copy())


def merge(*meshes):
    """One mesh of several whose UV rows are their vertex rows (as :func:`plane`'s)."""
    V, F, UV, off_v = [], [], [], 0
    for m in meshes:
        V.append(m.V)
        F.append(m.F + off_v)
        UV.append(m.UV)
        off_v += len(m.V)
    F = np.concatenate(F)
    return TexturedMesh(np.concatenate(V), F, np.concatenate(UV), F.copy())


def camera(eye, size=96, focal=1.4, target=(0.0, 0.0, 0.0)):
    K = np.array([[focal * size, 0, (size - 1) / 2], [0, focal * size, (size - 1) / 2], [0, 0, 1.0]])
    return Camera.look_at(np.asarray(eye, float), target, (0, 1, 0), K, size, size, name=str(eye))


def render(mesh, texture, cams, sh, antialias=False):
    """Colour images (B, H, W, 3), the depth buffer (B, H, W) (inf = empty) and the fully covered pixels."""
    out = render_views(torch.tensor(mesh.V, dtype=torch.float32), Topology(torch.tensor(mesh.F), torch.tensor(mesh.F_uv)),
                       cams, ("color",), uv=torch.tensor(mesh.UV, dtype=torch.float32),
                       texture=torch.as_tensor(texture, dtype=torch.float32), sh=torch.as_tensor(sh, dtype=torch.float32),
                       antialias_edges=antialias)
    return (out.dense("color").detach().numpy(), out.fragments.depth.copy(),
            out.dense("coverage")[..., 0].detach().numpy() > 0.99)


def fuse(mesh, cams, images, depth, size, sh, settings=FusionSettings(), scan_V=None):
    buffers = view_buffers(depth, cams, settings.fusion_feather_px)
    obs = observe_texture(mesh, cams, images, buffers, size, settings, scan_V=scan_V)
    texture, observed = finish_texture(obs, texel_albedo(obs, sh))
    return texture, observed, obs


def ramp_texture(size=64):
    v, u = np.mgrid[0:size, 0:size] / size
    return np.stack([0.2 + 0.6 * u, 0.3 + 0.4 * v, 0.5 + 0.2 * u - 0.2 * v], -1).astype(np.float32)


def test_flat_plane_seen_frontally_gives_back_its_texture():
    mesh, truth = plane(), ramp_texture()
    cams = [camera((0.0, 0.0, 400.0), size=160)]
    images, depth, _ = render(mesh, truth, cams, uniform_sh())
    texture, observed, obs = fuse(mesh, cams, images, depth, 64, uniform_sh())
    assert texture.shape == (64, 64, 3) and observed.sum() > 0.85 * len(obs.texels.rows)
    assert np.abs(texture[observed] - truth[observed]).max() < FUSION_FLAT_ALBEDO
    # unobserved texels (the outline, the gutter) are filled, not left black
    assert texture[~observed].min() > 0.05


def test_occluded_texels_take_their_colour_from_the_view_that_sees_them():
    # a red card 60 mm in front of the textured plane hides its middle from the frontal view;
    # the oblique view sees behind it. No red may reach the plane's texels.
    back = plane(uv_box=(0.02, 0.3, 0.68, 0.98))
    card = plane(size_mm=30.0, n=2, z=60.0, uv_box=(0.75, 0.05, 0.95, 0.25))
    mesh = merge(back, card)
    truth = ramp_texture()
    truth[..., 0] *= 0.2  # the plane carries little red
    truth[48:, 44:] = (1.0, 0.0, 0.0)  # the card's chart
    cams = [camera((0.0, 0.0, 400.0), size=160), camera((260.0, 0.0, 300.0), size=160)]
    images, depth, _ = render(mesh, truth, cams, uniform_sh())
    texture, observed, obs = fuse(mesh, cams, images, depth, 64, uniform_sh())
    plane_texels = np.zeros((64, 64), bool)
    plane_texels[obs.texels.rows[obs.texels.face < len(back.F)], obs.texels.cols[obs.texels.face < len(back.F)]] = True
    seen = plane_texels & observed
    assert seen.sum() > 0.85 * plane_texels.sum()
    assert np.abs(texture[seen] - truth[seen]).max() < FUSION_FLAT_ALBEDO
    # the texels right behind the card (as seen from the front) are among them
    behind = np.abs(obs.texels.surface(mesh.V, mesh.F)[:, :2]).max(1) < 10.0
    assert observed[obs.texels.rows[behind], obs.texels.cols[behind]].all()


def test_robust_mean_down_weights_a_disagreeing_view():
    colors = np.array([[[0.5, 0.5, 0.5]], [[0.52, 0.5, 0.5]], [[0.48, 0.5, 0.5]], [[1.0, 0.0, 0.0]]], np.float32)
    weights = np.ones((4, 1), np.float32)
    plain, total = robust_mean(colors, weights, 0, 0.05)
    robust, _ = robust_mean(colors, weights, 3, 0.05)
    np.testing.assert_allclose(plain[0], colors[:, 0].mean(0), atol=1e-6)
    assert total[0] == 4.0
    assert np.abs(robust[0] - [0.5, 0.5, 0.5]).max() < 0.03 < np.abs(plain[0] - [0.5, 0.5, 0.5]).max()
    # views of weight 0 never count; a texel no view sees stays 0
    colors[3] = 0.5
    weights[0] = 0.0
    mean, _ = robust_mean(colors, weights, 2, 0.05)
    assert mean[0].tolist() == pytest.approx([0.5, 0.5, 0.5], abs=1e-6)
    none, total = robust_mean(colors, np.zeros((4, 1), np.float32), 2, 0.05)
    assert total[0] == 0.0 and np.all(none == 0.0)


def baked_texture(mesh, size=64):
    """A smooth colour field of the 3D position baked into ``mesh``'s atlas (so both sides of a seam agree)."""
    texels = rasterize_uv(mesh.UV, mesh.F_uv, size)
    P = texels.surface(mesh.V, mesh.F)
    colour = np.stack([0.5 + 0.3 * np.sin(P[:, 0] / 40.0), 0.5 + 0.3 * np.cos(P[:, 1] / 40.0),
                       0.45 + 0.25 * np.sin((P[:, 2] + P[:, 0]) / 40.0)], axis=1).astype(np.float32)
    chart = np.where(texels.face_image >= 0, 0, -1)
    return fill_texture(texels.scatter(colour), texels.scatter(np.ones(len(P), np.float32)), chart)


def directional_sh():
    """A tinted light from above and the side: one SH shape, scaled per channel (as the generator's)."""
    sh = uniform_sh(1.0)
    sh[1:4] = np.array([0.3, 0.5, -0.2])[:, None]
    sh[6] = 0.1
    return sh * np.array([1.0, 0.9, 0.8])[None, :]


@pytest.fixture(scope="module")
def sphere_fusion():
    mesh = seamed_sphere(subdivisions=4)
    cams = tetrahedral_cameras(96)
    sh = directional_sh()
    truth = baked_texture(mesh)
    images, depth, covered = render(mesh, truth, cams, sh, antialias=True)
    texture, observed, obs = fuse(mesh, cams, images, depth, 64, sh)
    return dict(mesh=mesh, cams=cams, sh=sh, truth=truth, images=images, depth=depth, covered=covered,
                texture=texture, observed=observed, obs=obs)


def test_sphere_albedo_is_recovered_under_directional_light(sphere_fusion):
    f = sphere_fusion
    obs, observed = f["obs"], f["observed"]
    # four tetrahedral views see every point, some only at cos ~1/3 (weight ~0.07, near FULL_WEIGHT / 2)
    assert observed[obs.texels.rows, obs.texels.cols].mean() > 0.95
    assert np.abs(f["texture"][observed] - f["truth"][observed]).mean() < FUSION_SPHERE_ALBEDO


def test_sphere_renders_with_the_fused_texture_match_the_references(sphere_fusion):
    f = sphere_fusion
    again, _, _ = render(f["mesh"], f["texture"], f["cams"], f["sh"], antialias=True)
    mse = ((again - f["images"]) ** 2)[f["covered"]].mean()
    assert 10 * np.log10(1.0 / mse) > FUSION_RENDER_PSNR_DB


def test_both_sides_of_a_seam_agree(sphere_fusion):
    mesh = sphere_fusion["mesh"]
    pairs = seam_copies(mesh.F, mesh.F_uv)

    def mismatch(texture):
        a = sample_bilinear(texture, uv_to_texel(mesh.UV[pairs[:, 0]], 64))
        b = sample_bilinear(texture, uv_to_texel(mesh.UV[pairs[:, 1]], 64))
        return np.abs(a - b)

    # each side's texels sit half a texel from the seam on their own side, so even the baked truth differs
    # there by about the colour change over one texel; the fused texture must do no worse
    fused, truth = mismatch(sphere_fusion["texture"]), mismatch(sphere_fusion["truth"])
    assert fused.mean() < FUSION_SEAM_AGREEMENT and fused.max() <= truth.max()


def test_fusion_is_deterministic(sphere_fusion):
    f = sphere_fusion
    again, _, _ = fuse(f["mesh"], f["cams"], f["images"], f["depth"], 64, f["sh"])
    assert np.array_equal(again, f["texture"])


def test_scan_normals_shade_where_the_fitted_mesh_is_smoother_than_the_surface():
    # the surface seen is a bumpy sphere of constant albedo; the "fitted" mesh is the smooth sphere under it:
    # divided by the shading of the scan's normals the albedo comes out flat, by the mesh's it keeps the bumps
    from gpja.render import render_scan_targets

    smooth = seamed_sphere(subdivisions=4)
    V = smooth.V * (1.0 + 0.04 * np.sin(smooth.V[:, 0] / 8.0) * np.cos(smooth.V[:, 1] / 9.0))[:, None]
    bumpy = TexturedMesh(V, smooth.F, smooth.UV, smooth.F_uv)
    cams, sh = tetrahedral_cameras(96), directional_sh()
    albedo = np.full((64, 64, 3), 0.6, np.float32)
    images, _, _ = render(bumpy, albedo, cams, sh)
    depth = render(smooth, albedo, cams, sh)[1]
    scan = render_scan_targets(bumpy.V, bumpy.F, cams)
    settings = FusionSettings()
    buffers = view_buffers(depth, cams, settings.fusion_feather_px)
    errors = []
    for normals in ((scan["normal"].numpy(), scan["coverage"][..., 0].numpy()), (None, None)):
        obs = observe_texture(smooth, cams, images, buffers, 64, settings, *normals)
        seen = obs.weight >= FULL_WEIGHT
        errors.append(np.abs(texel_albedo(obs, sh)[seen] - 0.6).mean())
    assert errors[0] < errors[1] / 10, errors  # measured 1.1e-4 against 6.8e-3


def test_texture_size_is_what_the_images_resolve():
    # 100 mm across the whole atlas seen from 400 mm at focal 1.4 x 512 px: 179 px per atlas side,
    # so a 256 texture has texels of 0.70 px (a 128 one would have 1.4 px texels)
    mesh = plane(uv_box=(0.0, 0.0, 1.0, 1.0))
    cams = [camera((0.0, 0.0, 400.0), size=512)]
    _, depth, _ = render(mesh, np.full((4, 4, 3), 0.5), cams, uniform_sh())
    buffers = view_buffers(depth, cams, 3.0)
    size, footprint = choose_texture_size(mesh, cams, buffers, 1024)
    assert size == 256
    assert footprint == pytest.approx(100.0 * 1.4 * 512 / 400.0 / 256, rel=1e-6)
    assert choose_texture_size(mesh, cams, buffers, 128)[0] == 128
    far = [camera((0.0, 0.0, 4000.0), size=64)]
    _, depth, _ = render(mesh, np.full((4, 4, 3), 0.5), far, uniform_sh())
    assert choose_texture_size(mesh, far, view_buffers(depth, far, 3.0), 1024)[0] == 64  # the smallest size


def test_view_buffers_mark_background_and_depth_jumps():
    depth = np.full((1, 12, 12), 500.0, np.float32)
    depth[0, :, 8:] = np.inf
    depth[0, :, :3] = 400.0
    cam = camera((0.0, 0.0, 400.0), size=120)  # focal 168 px: 2.4 mm pixels at 400 mm, a 14.5 mm jump is an edge
    buffers = view_buffers(depth, [cam], 2.0)
    assert buffers.nearest[0, 5, 7] == -np.inf  # block (7..8) holds background
    assert buffers.nearest[0, 5, 2] == pytest.approx(400.0)  # block (2..3): the nearer surface
    assert buffers.nearest[0, 5, 5] == pytest.approx(500.0)
    assert buffers.feather[0, 5, 2] == 0.0 and buffers.feather[0, 5, 3] == 0.0  # both sides of the jump
    assert buffers.feather[0, 5, 5] == pytest.approx(1.0)
    assert buffers.feather[0, 5, 7] == pytest.approx(0.5) and buffers.feather[0, 5, 8] == 0.0
    # pixels the scan does not cover count a fraction
    support = np.ones((1, 12, 12))
    support[0, :6] = 0.0
    scaled = view_buffers(depth, [cam], 2.0, support, 0.1)
    assert scaled.feather[0, 3, 5] == pytest.approx(0.1 * buffers.feather[0, 3, 5])
    assert scaled.feather[0, 8, 5] == pytest.approx(buffers.feather[0, 8, 5])
    np.testing.assert_array_equal(scaled.nearest, buffers.nearest)


def test_texels_off_scan_is_the_distance_to_the_nearest_scan_vertex():
    scan_V = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]])
    P = np.array([[0.0, 4.9, 0.0], [0.0, 5.1, 0.0], [10.0, 0.0, 4.0], [5.0, 0.0, 0.0], [30.0, 0.0, 0.0]])
    np.testing.assert_array_equal(texels_off_scan(P, scan_V, 5.0), [False, True, False, False, True])
    assert not texels_off_scan(P, scan_V, 0.0).any()  # 0 = no test
    assert texels_off_scan(P, np.zeros((0, 3)), 5.0).all()  # an empty scan measures nothing


def test_texels_bridging_a_hole_of_the_scan_are_not_observed():
    # The fitted mesh is a whole plane; the capture has only its left half, and through the right half the
    # cameras see a red wall 40 mm behind it. Without the scan's vertices the right half's texels take the
    # wall's red; with them, the texels farther than fusion_scan_distance_mm from the scan are unobserved
    # and filled from the left half.
    fitted = plane(uv_box=(0.05, 0.05, 0.9, 0.9))
    on_left = fitted.V[fitted.F].mean(1)[:, 0] < 0
    left = TexturedMesh(fitted.V, fitted.F[on_left], fitted.UV, fitted.F[on_left])
    wall = plane(size_mm=160.0, n=2, z=-40.0, uv_box=(0.97, 0.97, 0.995, 0.995))
    scene = merge(left, wall)
    truth = np.full((64, 64, 3), 0.6, np.float32)
    truth[:3, 61:] = (1.0, 0.0, 0.0)  # the wall's corner of the atlas
    cams = [camera((0.0, 0.0, 400.0), size=160), camera((120.0, 0.0, 380.0), size=160)]
    images, _, _ = render(scene, truth, cams, uniform_sh())
    _, depth, _ = render(fitted, truth, cams, uniform_sh())
    gx, gy = np.meshgrid(np.arange(-50.0, 0.5, 1.0), np.arange(-50.0, 50.5, 1.0))  # the scan: 1 mm samples
    scan_V = np.concatenate([np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1),
                             np.stack([gx.ravel() + 60.0, gy.ravel(), np.full(gx.size, -40.0)], 1)])
    settings = FusionSettings()
    for scan in (None, scan_V):
        texture, observed, obs = fuse(fitted, cams, images, depth, 64, uniform_sh(), settings, scan_V=scan)
        x, y = obs.texels.surface(fitted.V, fitted.F)[:, :2].T
        far = x > settings.fusion_scan_distance_mm + 1.0
        rows, cols = obs.texels.rows[far], obs.texels.cols[far]
        if scan is None:
            assert observed[rows, cols].mean() > 0.8
            assert np.median(texture[rows, cols, 0] - texture[rows, cols, 1]) > 0.5
        else:
            assert not observed[rows, cols].any()
            near = (x < -2.0) & (x > -40.0) & (np.abs(y) < 40.0)  # away from the silhouettes' feather
            assert observed[obs.texels.rows[near], obs.texels.cols[near]].all()
            texels = obs.texels.rows[near], obs.texels.cols[near]
            assert np.abs(texture[texels] - 0.6).max() < FUSION_FLAT_ALBEDO


def test_a_scan_nowhere_near_the_fitted_mesh_is_an_input_error():
    mesh = plane()
    cams = [camera((0.0, 0.0, 400.0), size=64)]
    images, depth, _ = render(mesh, ramp_texture(), cams, uniform_sh())
    with pytest.raises(InputError, match="fusion_scan_distance_mm"):
        fuse(mesh, cams, images, depth, 32, uniform_sh(), scan_V=mesh.V * 1000.0 + 500.0)  # another unit and frame


def test_fusion_settings_are_checked():
    with pytest.raises(ValueError):
        FusionSettings(fusion_min_cos=1.0)
    with pytest.raises(ValueError):
        FusionSettings(fusion_robust_iterations=-1)
    with pytest.raises(ValueError):
        FusionSettings(fusion_scan_distance_mm=-1.0)
    with pytest.raises(ValueError):
        FusionSettings(fusion_feather_px=0.0)
