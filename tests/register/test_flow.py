"""gpja.register.flow: optical-flow correspondences before the descent."""
import numpy as np
import pytest
import torch

from gpja.mesh import TexturedMesh
from gpja.register.flow import (FlowSettings, align_by_flow, bilinear, combine_views, dense_flow, solve_displacement,
                                red_green_chroma, to_grey_u8, to_match_u8, unproject)
from gpja.register.hra import ExpressionTargets
from tests.tolerances import EXACT_F64

#: Sub-pixel accuracy of DIS flow on a smooth random texture shifted by whole pixels (px, median).
FLOW_SHIFT_PX = 0.25
#: Median error (px) of DIS flow on a smooth sub-pixel warp (1.5 and 1 px sine waves) computed on the full image
#: (``finest_scale`` 0; measured 0.17-0.19 on four seeds, against 0.37-0.39 at the medium preset's half size).
FLOW_WARP_FULL_PX = 0.25
#: What the half-size field must lose against the full one on that warp (ratio of median errors; measured 2.1).
FLOW_WARP_HALF_RATIO = 1.5
#: Median error (mm) of the sphere's front after 4 rounds of the flow stage, from a 16-degree turn (measured 1.09;
#: the descent alone keeps 5.8 mm, tests/register/test_pipeline.py).
FLOW_TURN_MAX_ERROR_MM = 1.5
FLOW_TURN_DEG = 16.0
#: What the solve's pull to no motion leaves of a rigid shift of 2.55 mm (mm).
STAY_SHIFT_MM = 0.01
#: A sphere whose vertices are pushed +-0.6 mm off it (normals tilted ~10 degrees) under a side light: the
#: matches' median error with the render shaded by the scan's normals, as a share of the error with its own
#: normals (measured 0.377 / 0.534 mm = 0.71).
SCAN_SHADING_RATIO = 0.85
#: ``FlowSettings.socket_margin_px`` of the socket tests (px at 128 x 128; the patch is about 20 x 12 px in view 0)
SOCKET_MARGIN_PX = 6.0


def smooth_random_image(size: int, seed: int = 0) -> np.ndarray:
    """(size, size) uint8 band-limited noise: texture everywhere, as skin pores and freckles give."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.random((size, size)).astype(np.float32)
    blurred = cv2.GaussianBlur(noise, (0, 0), 2.0)
    blurred = (blurred - blurred.min()) / (blurred.max() - blurred.min())
    return np.round(255 * blurred).astype(np.uint8)


def test_bilinear_is_exact_on_a_linear_ramp():
    y, x = np.mgrid[0:8, 0:10].astype(np.float64)
    image = np.stack([2.0 * x + 3.0 * y, x - y], axis=-1)
    xy = np.array([[0.0, 0.0], [3.25, 4.5], [8.9, 6.1], [9.0, 7.0]])
    expect = np.stack([2 * xy[:, 0] + 3 * xy[:, 1], xy[:, 0] - xy[:, 1]], axis=1)
    np.testing.assert_allclose(bilinear(image, xy), expect, atol=EXACT_F64)


def test_unproject_inverts_project():
    from tests.render.scenes import ring_cameras

    camera = ring_cameras(3, 64)[1]
    X = np.array([[10.0, -5.0, 20.0], [-30.0, 12.0, 0.0], [0.0, 0.0, 45.0]])
    xy, z = camera.project(X)
    np.testing.assert_allclose(unproject(camera, xy, z), X, atol=1e-9 * 1e3)


def test_grey_conversion_is_gamma_encoded_and_clipped():
    image = np.zeros((1, 3, 3))
    image[0, 1] = 0.5
    image[0, 2] = 2.0
    grey = to_grey_u8(image)
    assert grey.dtype == np.uint8
    assert grey[0, 0] == 0 and grey[0, 2] == 255
    assert abs(int(grey[0, 1]) - round(255 * 0.5 ** (1 / 2.2))) <= 1


def test_the_match_channel_adds_chroma_to_the_luminance():
    """Two colours of equal luminance (a lip's red on the skin's grey-pink): one grey value without the chroma,
    told apart with it; chroma 0 is the luminance channel exactly."""
    red = np.array([0.8, 0.2, 0.2])
    luminance = red @ np.array([0.299, 0.587, 0.114])
    image = np.stack([red, np.full(3, luminance)])[None]  # (1, 2, 3): red, then the grey of the same luminance
    np.testing.assert_allclose(red_green_chroma(image)[0], [0.6 / 1.2, 0.0], atol=EXACT_F64)
    assert np.array_equal(to_match_u8(image, 0.0), to_grey_u8(image))
    assert abs(int(to_grey_u8(image)[0, 0]) - int(to_grey_u8(image)[0, 1])) <= 1
    both = to_match_u8(image, 1.0).astype(int)[0]
    assert both[0] - both[1] == pytest.approx(255 * 0.5 / 2.0, abs=1.0)
    assert np.array_equal(to_match_u8(np.zeros((2, 2, 3)), 1.0), np.zeros((2, 2), np.uint8))  # black: no chroma


def test_a_disc_of_equal_luminance_is_tracked_only_with_the_chroma():
    """A red disc on grey of the same luminance, shifted 4 px: the luminance flow sees nothing there, the
    chroma channel follows the disc's rim."""
    size, shift = 96, 4
    y, x = np.mgrid[0:size, 0:size].astype(np.float64)
    red = np.array([0.8, 0.2, 0.2])
    grey = np.full(3, red @ np.array([0.299, 0.587, 0.114]))

    def disc(cx):
        inside = (x - cx) ** 2 + (y - size / 2) ** 2 < 15.0 ** 2
        return np.where(inside[..., None], red, grey)

    source, target = disc(size / 2), disc(size / 2 + shift)
    angle = np.arctan2(y - size / 2, x - size / 2)
    rim = np.abs(np.hypot(x - size / 2, y - size / 2) - 15.0) < 1.5
    rim &= np.abs(np.cos(angle)) > 0.7  # where the disc's edge crosses the shift
    flow_grey = dense_flow(to_match_u8(source, 0.0), to_match_u8(target, 0.0))
    flow_chroma = dense_flow(to_match_u8(source, 1.0), to_match_u8(target, 1.0))
    assert np.median(np.abs(flow_grey[rim, 0])) < 1.0
    assert np.median(np.abs(flow_chroma[rim, 0] - shift)) < 1.0


def test_dense_flow_recovers_a_shift_of_many_pixels():
    image = smooth_random_image(128)
    shift = (9, -6)  # (x, y) px: beyond a per-pixel descent's reach
    moved = np.roll(image, shift=(shift[1], shift[0]), axis=(0, 1))
    flow = dense_flow(image, moved)
    inner = flow[20:-20, 20:-20].reshape(-1, 2)
    assert np.median(np.abs(inner - np.array(shift, dtype=np.float32)).max(axis=1)) < FLOW_SHIFT_PX


def test_the_full_image_field_follows_a_sub_pixel_warp_closer_than_the_half_size_one():
    """``finest_scale``: a smooth warp of under two pixels (a face's slide between two levels) is followed to a
    fifth of a pixel on the full image, and twice as coarsely at the medium preset's half size (the default)."""
    import cv2

    size = 128
    image = smooth_random_image(size, seed=1)
    y, x = np.mgrid[0:size, 0:size].astype(np.float32)
    u, v = 1.5 * np.sin(2 * np.pi * y / 48.0), 1.0 * np.cos(2 * np.pi * x / 40.0)
    moved = cv2.remap(image, x - u, y - v, cv2.INTER_CUBIC)  # content at p moves to p + (u, v)

    def median_error(finest_scale):
        flow = dense_flow(image, moved, finest_scale)
        return float(np.median(np.hypot(flow[..., 0] - u, flow[..., 1] - v)[16:-16, 16:-16]))

    full, half = median_error(0), median_error(1)
    assert full < FLOW_WARP_FULL_PX
    assert half > FLOW_WARP_HALF_RATIO * full
    assert np.array_equal(dense_flow(image, moved), dense_flow(image, moved, 1))  # the default is the preset's


def test_combine_views_drops_a_view_far_from_the_median():
    per_view = np.full((3, 2, 3), np.nan)
    per_view[:, 0] = [[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [10.0, 0.0, 0.0]]  # the third disagrees
    target, count = combine_views(per_view, spread_mm=2.0)
    np.testing.assert_allclose(target[0], [0.1, 0.0, 0.0], atol=EXACT_F64)
    assert count.tolist() == [2, 0]
    assert np.isnan(target[1]).all()


def test_a_rigid_shift_is_followed_exactly_and_untargeted_vertices_come_along():
    from tests.render.scenes import sphere

    V, F = sphere(subdivisions=2, radius=30.0)
    offset = np.array([1.5, -2.0, 0.5])
    target = V + offset
    target[::3] = np.nan  # a third of the vertices have no match
    d = solve_displacement(V, F, target, np.ones(len(V)), smoothness=30.0, spread_mm=2.0)
    # the weak pull to no motion (STAY_WEIGHT) costs ~0.1% of the shift (measured 0.0037 mm of 2.55)
    np.testing.assert_allclose(d, np.broadcast_to(offset, d.shape), atol=STAY_SHIFT_MM)


def test_one_wrong_match_does_not_pull_its_neighbourhood():
    from tests.render.scenes import sphere

    V, F = sphere(subdivisions=3, radius=30.0)
    target = V.copy()
    target[0] += np.array([0.0, 0.0, 15.0])  # an outlier match
    weight = np.ones(len(V))
    d = solve_displacement(V, F, target, weight, smoothness=30.0, spread_mm=2.0)
    # re-weighted by its residual, the outlier keeps little pull: its own move is a fraction of 15 mm
    assert np.linalg.norm(d[0]) < 3.0
    assert np.median(np.linalg.norm(d, axis=1)) < 1e-3


#: Agreement of the preconditioned re-weighted solves with a factorisation of each system (mm).
SOLVE_AGREEMENT_MM = 1e-4


@pytest.mark.parametrize("backend", ["supernodal", "simplicial"])
def test_reweighted_solves_match_a_factorisation_of_each_system(monkeypatch, backend):
    import scipy.sparse as sp

    from gpja.baselines import nicp_solver
    from gpja.cholesky import factorize
    from gpja.register.flow import REWEIGHT_PASSES, smoothness_system
    from tests.render.scenes import sphere

    V, F = sphere(subdivisions=3, radius=30.0)
    rng = np.random.default_rng(0)
    target = V + np.array([0.0, 2.0, 1.0]) + rng.normal(0.0, 0.3, V.shape)
    target[rng.random(len(V)) < 0.05] += 12.0  # outliers: the re-weighting changes their weights a lot
    target[V[:, 2] < -10.0] = np.nan
    weight = rng.integers(1, 4, len(V)).astype(float)
    factorizations = []
    monkeypatch.setattr(nicp_solver, "factorize",
                        lambda H, b: factorizations.append((H.shape, b)) or factorize(H, b))
    d = solve_displacement(V, F, target, weight, smoothness=30.0, spread_mm=2.0, backend=backend)
    # the re-weighted passes are preconditioned by the first pass's factor, of the backend asked for
    assert factorizations == [((len(V), len(V)), backend)]
    # the same passes, each system factorised anew
    has = np.isfinite(target).all(1)
    residual = np.where(has[:, None], target - V, 0.0)
    S = smoothness_system(F, len(V), 30.0)
    w = np.where(has, weight, 0.0)
    for _ in range(REWEIGHT_PASSES + 1):
        direct = factorize(S + sp.diags(w), "simplicial").solve(w[:, None] * residual)
        w = np.where(has, weight / (1.0 + (np.linalg.norm(direct - residual, axis=1) / 2.0) ** 2), 0.0)
    np.testing.assert_allclose(d, direct, atol=SOLVE_AGREEMENT_MM)


def sphere_scene(degrees: float, size: int = 128):
    """A textured sphere seen by three cameras, and targets of the same sphere turned about y."""
    from gpja.lighting import uniform_sh
    from gpja.render import Topology, render_views
    from tests.render.scenes import ring_cameras, sphere, spherical_uv

    V, F = sphere(subdivisions=4, radius=60.0)
    uv = spherical_uv(V)
    texture = torch.tensor(smooth_random_image(64, seed=1)[..., None].repeat(3, -1) / 255.0, dtype=torch.float32)
    cameras, sh = ring_cameras(3, size), torch.tensor(uniform_sh(), dtype=torch.float32)
    a = np.radians(degrees)
    turn = np.array([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]])
    ref = render_views(torch.tensor(V @ turn.T, dtype=torch.float32), Topology(torch.from_numpy(F), torch.from_numpy(F)),
                       cameras, ("color", "depth", "normal"), uv=torch.tensor(uv, dtype=torch.float32), texture=texture,
                       sh=sh)
    targets = ExpressionTargets(cameras, *(ref.dense(p).detach() for p in ("color", "depth", "normal", "coverage")), sh)
    return TexturedMesh(V, F, uv, F), texture, targets, V @ turn.T


@pytest.mark.parametrize("rounds", [0, 4])
def test_a_turn_beyond_the_colour_basin_is_matched(rounds):
    """The sphere's texture turned 16 degrees (~17 mm at the front, the open template's lip to the closed
    one's): the flow stage moves the front's vertices onto their turned positions; no rounds, no move."""
    template, texture, targets, truth = sphere_scene(FLOW_TURN_DEG)
    front = template.V[:, 2] > 20.0
    moved, log = align_by_flow(template, targets, texture, torch.ones(4, 4, 1), FlowSettings(rounds=rounds),
                               progress=lambda m: None)
    error = np.median(np.linalg.norm(moved.V - truth, axis=1)[front])
    start_error = np.median(np.linalg.norm(template.V - truth, axis=1)[front])
    assert start_error > 10.0
    if rounds == 0:
        assert error == start_error and log["rounds"] == []
    else:
        assert error < FLOW_TURN_MAX_ERROR_MM
        assert len(log["rounds"]) == rounds and log["rounds"][0]["matched_fraction"] > 0.2


def test_the_mouth_socket_is_not_matched():
    """Vertices whose mask texel is 0 (the mouth interior) get no target of their own."""
    from gpja.register.flow import match_round

    template, texture, targets, _ = sphere_scene(FLOW_TURN_DEG)
    target, _ = match_round(template, targets, texture, torch.ones(4, 4, 1), FlowSettings())
    masked, _ = match_round(template, targets, texture, torch.zeros(4, 4, 1), FlowSettings())
    assert np.isfinite(target).all(1).sum() > 100
    assert not np.isfinite(masked).any()


def test_socket_vertices_are_those_whose_texel_the_mask_leaves_out():
    """Two triangles side by side, their UVs on the left and right halves of a mask whose left half is 0."""
    from gpja.register.flow import socket_vertices

    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [5.0, 0.0, 0.0], [6.0, 0.0, 0.0], [5.0, 1.0, 0.0]])
    F = np.array([[0, 1, 2], [3, 4, 5]])
    UV = np.array([[0.1, 0.2], [0.2, 0.2], [0.1, 0.8], [0.8, 0.2], [0.9, 0.2], [0.8, 0.8]])
    mesh = TexturedMesh(V, F, UV, F.copy())
    mask = torch.ones(8, 8, 1)
    mask[:, :4] = 0.0  # columns u < 0.5: the socket
    np.testing.assert_array_equal(socket_vertices(mesh, mask), [True, True, True, False, False, False])
    assert not socket_vertices(mesh, torch.ones(8, 8, 1)).any()


def test_a_match_smaller_than_still_mm_holds_its_vertex_and_a_large_one_is_kept():
    """``still_mm``: the sphere turned 0.5 degrees (0.5 mm at the front) gives matches under 1 mm, which become
    the vertices themselves; the 16-degree turn's matches (~17 mm) are the same with and without it."""
    from gpja.register.flow import match_round

    mask = torch.ones(4, 4, 1)
    for degrees, moved in ((0.5, False), (FLOW_TURN_DEG, True)):
        template, texture, targets, _ = sphere_scene(degrees)
        plain, _ = match_round(template, targets, texture, mask, FlowSettings())
        held, _ = match_round(template, targets, texture, mask, FlowSettings(still_mm=1.0))
        matched = np.isfinite(plain).all(1)
        assert matched.sum() > 100 and np.array_equal(matched, np.isfinite(held).all(1))
        small = matched & (np.linalg.norm(plain - template.V, axis=1) < 1.0)
        np.testing.assert_array_equal(held[small], template.V[small])
        np.testing.assert_array_equal(held[matched & ~small], plain[matched & ~small])
        assert (small.sum() < 0.1 * matched.sum()) if moved else (small.sum() > 0.5 * matched.sum())


def side_light() -> torch.Tensor:
    """(9, 3) SH lighting lit from above and the side: the shading depends on the normal."""
    from gpja.lighting import uniform_sh

    sh = uniform_sh(0.6)
    sh[1] += 0.25
    sh[3] += 0.35
    return torch.tensor(sh, dtype=torch.float32)


def test_shade_by_scan_is_the_albedo_times_the_scan_normals_shading_where_the_render_lies_on_the_scan():
    """Analytic: a constant albedo and scan normal. Pixels the scan does not cover, the mesh does not, or where the
    render lies beyond the far end of ``SCAN_SHADING_NEAR_MM`` from the scan keep the render's own colour; halfway
    along the ramp the two colours mix half and half. Blurring a constant normal image changes nothing."""
    from gpja.lighting import shade_lambertian
    from gpja.register.flow import SCAN_SHADING_NEAR_MM, shade_by_scan

    near, far = SCAN_SHADING_NEAR_MM
    albedo = np.full((4, 6, 3), 0.5)
    render_depth = np.full((4, 6), 100.0)
    render_depth[0, 0] = 0.0  # empty
    scan_depth = np.full((4, 6), 100.0)
    scan_depth[1, 1] = 100.0 + far + 0.1  # the render lies in front of the scan: another part
    scan_depth[2, 1] = 100.0 - 0.5 * (near + far)  # halfway along the ramp
    own = np.full((4, 6, 3), 0.123)
    normal = np.zeros((4, 6, 3))
    normal[..., 2] = 1.0
    coverage = np.ones((4, 6))
    coverage[:, 3:] = 0.0
    sh = side_light()
    shaded = shade_lambertian(torch.full((1, 3), 0.5, dtype=torch.float64),
                              torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64), sh.double()).numpy()[0]
    for blur in (0.0, 1.5):
        out = shade_by_scan(albedo, render_depth, own, normal, scan_depth, coverage, sh, blur)
        full = (render_depth > 0) & (coverage > 0.5)
        full[1, 1] = full[2, 1] = False
        np.testing.assert_allclose(out[full], np.broadcast_to(shaded, out[full].shape), atol=1e-6)
        np.testing.assert_allclose(out[2, 1], 0.5 * shaded + 0.5 * own[2, 1], atol=1e-6)
        kept = ~full
        kept[2, 1] = False
        np.testing.assert_array_equal(out[kept], own[kept])


def test_a_surface_shaded_by_its_own_normal_images_is_its_own_render():
    """Identity: a sphere's render, shaded again by the normal images of the same render, is unchanged."""
    from gpja.register.flow import shade_by_scan
    from gpja.render import Topology, render_views, sample_texture
    from tests.render.scenes import ring_cameras, sphere, spherical_uv

    V, F = sphere(subdivisions=4, radius=60.0)
    texture = torch.tensor(smooth_random_image(64, seed=2)[..., None].repeat(3, -1) / 255.0, dtype=torch.float64)
    sh = side_light().double()
    out = render_views(torch.from_numpy(V), Topology(torch.from_numpy(F), torch.from_numpy(F)), ring_cameras(2, 64),
                       ("color", "normal", "uv", "depth"), uv=torch.from_numpy(spherical_uv(V)), texture=texture, sh=sh,
                       antialias_edges=False)
    colour, normal, depth = out.dense("color").numpy(), out.dense("normal").numpy(), out.dense("depth").numpy()[..., 0]
    coverage = out.dense("coverage")[..., 0].numpy()
    uv = out.dense("uv")
    for b in range(2):
        albedo = sample_texture(texture, uv[b].reshape(-1, 2)).numpy().reshape(colour[b].shape)
        again = shade_by_scan(albedo, depth[b], colour[b], normal[b], depth[b], coverage[b], sh, 0.0)
        np.testing.assert_allclose(again, colour[b], atol=1e-9)


def test_shading_by_the_scan_takes_a_bumpy_mesh_s_shading_out_of_the_matches():
    """Regression of the nose's slide (``FlowSettings.scan_shading_px``): a sphere whose vertices lie +-0.6 mm off
    it has the right texture in the right place but normals tilted ~10 degrees, so under a side light its own
    shading differs from the references' and the flow reads that as motion. Shaded by the scan's normals, its
    matches are closer to its vertices' true places."""
    from gpja.register.flow import match_round
    from gpja.render import Topology, render_views
    from tests.render.scenes import ring_cameras, sphere, spherical_uv

    radius = 60.0
    fV, fF = sphere(subdivisions=5, radius=radius)
    texture = torch.tensor(0.3 + 0.5 * smooth_random_image(128, seed=1)[..., None].repeat(3, -1) / 255.0,
                           dtype=torch.float32)
    cameras, sh = ring_cameras(5, 256), side_light()
    ref = render_views(torch.tensor(fV, dtype=torch.float32), Topology(torch.from_numpy(fF), torch.from_numpy(fF)),
                       cameras, ("color", "depth", "normal"), uv=torch.tensor(spherical_uv(fV), dtype=torch.float32),
                       texture=texture, sh=sh)
    targets = ExpressionTargets(cameras, *(ref.dense(p).detach() for p in ("color", "depth", "normal", "coverage")), sh)
    V, F = sphere(subdivisions=4, radius=radius)
    signs = np.random.default_rng(0).choice([-1.0, 1.0], size=len(V))
    mesh = TexturedMesh(V * (1.0 + 0.6 * signs / radius)[:, None], F, spherical_uv(V), F.copy())
    front = V[:, 2] > 20.0
    errors = []
    for blur in (None, 1.0):
        target, _ = match_round(mesh, targets, texture, torch.ones(4, 4, 1),
                                FlowSettings(finest_scale=0, scan_shading_px=blur))
        matched = np.isfinite(target).all(1) & front
        assert matched.sum() > 300
        errors.append(np.median(np.linalg.norm(target[matched] - V[matched], axis=1)))
    assert errors[1] < SCAN_SHADING_RATIO * errors[0]


def test_within_is_the_euclidean_neighbourhood_of_a_region():
    """Analytic: one pixel's neighbourhood is the disc of integer offsets closer than the margin; no region, none."""
    from gpja.register.flow import within

    region = np.zeros((15, 15), dtype=bool)
    region[7, 7] = True
    yy, xx = np.mgrid[:15, :15]
    np.testing.assert_array_equal(within(region, 3.5), np.hypot(xx - 7, yy - 7) < 3.5)
    assert not within(np.zeros((15, 15), dtype=bool), 3.5).any()


def socket_scene(reference_shows_socket: bool, size: int = 128):
    """The sphere with a dark 'socket' patch of its texture facing camera 0 (mask 0 there), and references of the
    unmoved sphere that show the patch dark (an open mouth) or the skin's texture in its place (a closed one)."""
    from gpja.lighting import uniform_sh
    from gpja.render import Topology, render_views
    from tests.render.scenes import ring_cameras, sphere, spherical_uv

    V, F = sphere(subdivisions=4, radius=60.0)
    uv = spherical_uv(V)
    skin = 0.35 + 0.6 * smooth_random_image(64, seed=2)[..., None].repeat(3, -1) / 255.0
    mask = np.ones((64, 64, 1))
    mask[29:36, 27:38] = 0.0  # rows v, columns u around (0.5, 0.5), the +z pole that camera 0 faces
    texture = np.where(mask > 0, skin, 0.03)
    cameras, sh = ring_cameras(3, size), torch.tensor(uniform_sh(), dtype=torch.float32)
    shown = texture if reference_shows_socket else skin
    ref = render_views(torch.tensor(V, dtype=torch.float32), Topology(torch.from_numpy(F), torch.from_numpy(F)),
                       cameras, ("color", "depth", "normal"), uv=torch.tensor(uv, dtype=torch.float32),
                       texture=torch.tensor(shown, dtype=torch.float32), sh=sh)
    targets = ExpressionTargets(cameras, *(ref.dense(p).detach() for p in ("color", "depth", "normal", "coverage")), sh)
    return (TexturedMesh(V, F, uv, F), torch.tensor(texture, dtype=torch.float32), torch.tensor(mask, dtype=torch.float32),
            targets)


def test_matches_beside_the_socket_are_dropped_only_where_the_reference_shows_no_opening():
    """``socket_margin_px``: against references whose patch is skin (a closed mouth), the vertices beside the dark
    patch lose their matches, and those away from it keep theirs exactly; against references that show it dark (an
    open one), every match is kept."""
    from gpja.register.flow import match_round

    dropped = {}
    for shows in (False, True):
        template, texture, mask, targets = socket_scene(shows)
        plain, _ = match_round(template, targets, texture, mask, FlowSettings())
        margin, _ = match_round(template, targets, texture, mask, FlowSettings(socket_margin_px=SOCKET_MARGIN_PX))
        matched, kept = np.isfinite(plain).all(1), np.isfinite(margin).all(1)
        assert not (kept & ~matched).any()
        away = np.linalg.norm(template.UV - 0.5, axis=1) > 0.25
        np.testing.assert_array_equal(margin[away], plain[away])
        dropped[shows] = matched & ~kept
        assert not (dropped[shows] & away).any()
    assert dropped[False].sum() >= 20 and not dropped[True].any()

