import numpy as np
import pytest
import torch

from gpja.lighting import uniform_sh
from gpja.register.hra import ExpressionTargets, Switches, constraint_loss, passes_for
from gpja.render import Topology, render_views
from tests.render.scenes import ring_cameras, sphere, spherical_uv
from tests.tolerances import EXACT_F64

#: What is left of a radial gradient after the projection on a level-3 sphere: its area-weighted vertex normals are
#: within a fraction of a degree of radial (unit gradient, so this is sin of that angle).
NORMAL_RESIDUE = 0.02


def setup(size=48):
    V, F = sphere(subdivisions=3, radius=60.0)
    topo = Topology(torch.tensor(F), torch.tensor(F))
    uv = torch.tensor(spherical_uv(V), dtype=torch.float32)
    tex = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0))
    cams = ring_cameras(2, size)
    sh = torch.tensor(uniform_sh(), dtype=torch.float32)
    Vt = torch.tensor(V, dtype=torch.float32)
    ref = render_views(Vt, topo, cams, ("color", "depth", "normal"), uv=uv, texture=tex, sh=sh)
    targets = ExpressionTargets(cams, ref.dense("color").detach(), ref.dense("depth").detach(),
                                ref.dense("normal").detach(), ref.dense("coverage").detach(), sh)
    return Vt, topo, uv, tex, targets


def loss_of(constraint, V, topo, uv, tex, targets, switches, mask):
    out = render_views(V, topo, targets.cameras, passes_for(constraint, switches), uv=uv, texture=tex,
                       mask_texture=mask, sh=targets.sh)
    return constraint_loss(constraint, out, targets, switches)


@pytest.mark.parametrize("constraint", ["color", "depth", "normal"])
def test_zero_at_the_target_and_positive_when_moved(constraint):
    V, topo, uv, tex, targets = setup()
    mask = torch.ones(8, 8, 1)
    assert float(loss_of(constraint, V, topo, uv, tex, targets, Switches(), mask)) < 1e-5
    moved = V * torch.tensor([1.08, 0.95, 1.0])
    assert float(loss_of(constraint, moved, topo, uv, tex, targets, Switches(), mask)) > 1e-3


def test_mouth_mask_removes_masked_texels_from_the_colour_loss():
    V, topo, uv, tex, targets = setup()
    wrong = targets.images.clone()
    wrong[...] = 0.0  # every covered pixel differs
    targets.images = wrong
    all_masked = torch.zeros(8, 8, 1)  # the whole texture is "mouth interior"
    assert float(loss_of("color", V, topo, uv, tex, targets, Switches(mask=True), all_masked)) == 0.0
    assert float(loss_of("color", V, topo, uv, tex, targets, Switches(mask=False), all_masked)) > 0.1


def test_rotation_and_switches():
    assert Switches().rotation() == ("color", "depth", "normal")
    assert Switches(color=False).rotation() == ("depth", "normal")
    assert passes_for("color", Switches(mask=False)) == ("color",)
    with pytest.raises(ValueError, match="switched off"):
        Switches(color=False, depth=False, normal=False).rotation()


def test_depth_counts_only_where_the_scan_has_data():
    V, topo, uv, tex, targets = setup()
    targets.coverage = torch.zeros_like(targets.coverage)  # a scan with no data in these views
    targets.depth = torch.zeros_like(targets.depth)
    assert float(loss_of("depth", V, topo, uv, tex, targets, Switches(), torch.ones(8, 8, 1))) == 0.0


def test_pooled_colour_loss_is_the_plain_one_at_pool_1_and_reaches_farther_when_coarser():
    """Identity: a 1-px box is the per-pixel loss. Analytic: a shift larger than the texture's detail
    leaves the per-pixel loss flat, while a coarse box still sees the mass moving back."""
    from gpja.register.hra import pooled_color_l1

    V, topo, uv, tex, targets = setup(size=64)
    mask = torch.ones(8, 8, 1)
    moved = V + torch.tensor([6.0, 0.0, 0.0])
    out = render_views(moved, topo, targets.cameras, ("color", "mask"), uv=uv, texture=tex, mask_texture=mask,
                       sh=targets.sh)
    plain = constraint_loss("color", out, targets, Switches())
    assert float(pooled_color_l1(out, targets, "mask", 1)) == pytest.approx(float(plain), rel=1e-5)
    assert float(constraint_loss("color", out, targets, Switches(), color_pool=8)) < float(plain)
    at_target = render_views(V, topo, targets.cameras, ("color", "mask"), uv=uv, texture=tex, mask_texture=mask,
                             sh=targets.sh)
    assert float(constraint_loss("color", at_target, targets, Switches(), color_pool=8)) < 1e-5
    # a gradient flows to the vertices through the pooled comparison
    moved = moved.clone().requires_grad_(True)
    out = render_views(moved, topo, targets.cameras, ("color", "mask"), uv=uv, texture=tex, mask_texture=mask,
                       sh=targets.sh)
    constraint_loss("color", out, targets, Switches(), color_pool=8).backward()
    assert moved.grad is not None and float(moved.grad.abs().sum()) > 0


def test_schedule_checks_the_colour_pool():
    from gpja.register.multiscale import Schedule

    assert Schedule(lambdas=(1.0, 2.0), iterations=(1, 1), color_pool=(4, 1)).pool(0) == 4
    assert Schedule(lambdas=(1.0,), iterations=(1,)).pool(0) == 1
    with pytest.raises(ValueError, match="color_pool"):
        Schedule(lambdas=(1.0, 2.0), iterations=(1, 1), color_pool=(4,))


def test_render_constraint_renders_with_the_given_function():
    from gpja.register.hra import render_constraint

    V, topo, uv, tex, targets = setup(size=32)
    calls = []

    def spy(*args, **kwargs):
        calls.append(args[3])
        return render_views(*args, **kwargs)

    mask = torch.ones(8, 8, 1)
    moved = V * torch.tensor([1.05, 0.97, 1.0])
    for constraint in ("color", "depth", "normal"):
        default, _ = render_constraint(constraint, moved, topo, targets, Switches(), uv, tex, mask)
        spied, _ = render_constraint(constraint, moved, topo, targets, Switches(), uv, tex, mask, render=spy)
        assert torch.equal(default, spied)
    assert calls == [("color", "mask"), ("depth",), ("normal",)]


def test_along_surface_keeps_the_values_and_drops_the_normal_part_of_the_gradient():
    """Analytic case: on a sphere about the origin the vertex normals are (nearly) radial, so a loss pulling
    every vertex outwards has no gradient left, and one turning the sphere about z keeps all of it."""
    from gpja.register.hra import along_surface

    V, F = sphere(subdivisions=3, radius=60.0)
    faces = torch.from_numpy(F)
    x = torch.tensor(V, dtype=torch.float64, requires_grad=True)
    y = along_surface(x, faces)
    assert torch.equal(y, x)
    radial = x / x.norm(dim=1, keepdim=True)
    (y * radial.detach()).sum().backward()  # gradient = the radial direction: all normal
    assert x.grad.norm(dim=1).max() < NORMAL_RESIDUE
    x.grad = None
    turn = torch.stack([-x[:, 1], x[:, 0], torch.zeros_like(x[:, 0])], dim=1).detach()
    (along_surface(x, faces) * turn).sum().backward()  # gradient = a tangent field: kept
    torch.testing.assert_close(x.grad, turn, atol=NORMAL_RESIDUE * 60.0, rtol=0.0)


def test_along_surface_gradient_is_the_tangential_projection_of_the_plain_one():
    """Gradient identity on a random loss: projected gradient + its normal part = the plain gradient."""
    from gpja.register.hra import along_surface
    from gpja.render import vertex_normals

    V, F = sphere(subdivisions=2, radius=30.0)
    faces = torch.from_numpy(F)
    weights = torch.randn(len(V), 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    x = torch.tensor(V, dtype=torch.float64, requires_grad=True)
    ((x ** 2) * weights).sum().backward()
    plain = x.grad.clone()
    x.grad = None
    ((along_surface(x, faces) ** 2) * weights).sum().backward()
    n = vertex_normals(x.detach(), faces)
    torch.testing.assert_close(x.grad + (plain * n).sum(1, keepdim=True) * n, plain)
    assert (x.grad * n).sum(1).abs().max() < 1e-9


def test_views_picks_the_targets_of_the_given_views_in_order():
    _, _, _, _, targets = setup(size=16)
    picked = targets.views([1, 0])
    assert [c.name for c in picked.cameras] == [targets.cameras[1].name, targets.cameras[0].name]
    for name in ("images", "depth", "normal", "coverage"):
        torch.testing.assert_close(getattr(picked, name)[0], getattr(targets, name)[1])
        torch.testing.assert_close(getattr(picked, name)[1], getattr(targets, name)[0])
    assert picked.sh is targets.sh


@pytest.mark.parametrize("constraint", ["color", "depth", "normal"])
def test_a_view_subset_scores_what_its_copied_targets_score_to_the_bit(constraint):
    """``views`` reads the losses' pixels from the whole targets (nothing copied): the same loss and gradient as
    from targets built of the copied views."""
    V, topo, uv, tex, targets = setup(size=24)
    targets = ExpressionTargets(list(targets.cameras) * 2, torch.cat([targets.images, targets.images.flip(2)]),
                                torch.cat([targets.depth, targets.depth.flip(2)]),
                                torch.cat([targets.normal, targets.normal.flip(2)]),
                                torch.cat([targets.coverage, targets.coverage.flip(2)]), targets.sh)  # 4 views
    picked = targets.views([3, 0])
    copied = ExpressionTargets(picked.cameras, targets.images[[3, 0]], targets.depth[[3, 0]],
                               targets.normal[[3, 0]], targets.coverage[[3, 0]], targets.sh)
    moved = (V * torch.tensor([1.03, 0.98, 1.0])).requires_grad_(True)
    mask = torch.ones(8, 8, 1)
    grads = []
    for t in (picked, copied):
        loss = loss_of(constraint, moved, topo, uv, tex, t, Switches(), mask)
        (grad,) = torch.autograd.grad(loss, moved)
        grads.append((loss.detach(), grad))
    assert float(grads[0][0]) > 1e-4
    torch.testing.assert_close(grads[0][0], grads[1][0], rtol=0, atol=0)
    torch.testing.assert_close(grads[0][1], grads[1][1], rtol=0, atol=0)


def test_downsampled_targets_are_the_box_averages_a_coarser_render_makes():
    # analytic: the box average of the full-resolution targets, and the cameras resized so that a
    # point lands at (x + 0.5) / f - 0.5 of its full-resolution pixel position
    _, _, _, _, targets = setup(size=48)
    half = targets.downsampled(2)
    assert half.images.shape == (2, 24, 24, 3) and half.coverage.shape == (2, 24, 24, 1)
    torch.testing.assert_close(half.depth[0, 5, 7], targets.depth[0, 10:12, 14:16].mean(dim=(0, 1)))
    torch.testing.assert_close(half.images[1, 3, 9], targets.images[1, 6:8, 18:20].mean(dim=(0, 1)))
    X = np.array([[3.0, -7.0, 11.0], [20.0, 5.0, -9.0]])
    full_px, _ = targets.cameras[0].project(X)
    half_px, _ = half.cameras[0].project(X)
    np.testing.assert_allclose(half_px, (full_px + 0.5) / 2 - 0.5, atol=EXACT_F64)
    assert (half.cameras[0].width, half.cameras[0].height) == (24, 24)
    # identity: factor 1 is the targets themselves
    assert targets.downsampled(1) is targets
    # a coarser render scores the true surface lower than one scaled by 2 % either way against the
    # downsampled scan targets (their outline blends differ from the coarse render's, so not 0)
    Vt, topo, uv, tex, targets = setup(size=96)
    half = targets.downsampled(2)
    for constraint in ("depth", "normal"):
        true, smaller, larger = (loss_of(constraint, Vt * s, topo, uv, tex, half, Switches(), torch.ones(8, 8, 1)).item()
                                 for s in (1.0, 0.98, 1.02))
        assert true < min(smaller, larger), (constraint, true, smaller, larger)


def test_downsampled_refuses_a_factor_that_does_not_divide_the_image():
    _, _, _, _, targets = setup(size=16)
    with pytest.raises(ValueError, match="divide the image size"):
        targets.downsampled(3)


# --- the colour near the scan (Schedule.color_scan_px) -------------------------------------------------------

def test_colour_weight_is_the_scans_coverage_grown_by_the_given_pixels():
    # analytic: one covered pixel grows into a (2k + 1)-pixel square; none = no weight (the paper)
    _, _, _, _, targets = setup(size=16)
    coverage = torch.zeros(2, 16, 16, 1)
    coverage[0, 5, 9] = 0.4
    coverage[1, 0, 0] = 1e-4  # an antialiasing crumb: not covered
    grown = ExpressionTargets(targets.cameras, targets.images, targets.depth, targets.normal, coverage, targets.sh, 2)
    weight = grown.color_weight
    assert weight.shape == (2, 16, 16, 1)
    expected = torch.zeros(2, 16, 16, 1)
    expected[0, 3:8, 7:12] = 1.0
    torch.testing.assert_close(weight, expected, rtol=0, atol=0)
    assert targets.color_weight is None
    one = ExpressionTargets(targets.cameras, targets.images, targets.depth, targets.normal, coverage, targets.sh, 0)
    assert float(one.color_weight.sum()) == 1.0  # k = 0: the covered pixels alone


def test_colour_near_the_scan_drops_the_pixels_away_from_it_and_keeps_the_rest():
    V, topo, uv, tex, targets = setup()
    moved = (V * torch.tensor([1.05, 0.97, 1.0])).requires_grad_(True)
    mask = torch.ones(8, 8, 1)
    plain = loss_of("color", moved, topo, uv, tex, targets, Switches(), mask)
    # identity: a scan covering every pixel, grown or not, weighs every pixel as the paper does
    whole = ExpressionTargets(targets.cameras, targets.images, targets.depth, targets.normal,
                              torch.ones_like(targets.coverage), targets.sh, 3)
    torch.testing.assert_close(loss_of("color", moved, topo, uv, tex, whole, Switches(), mask), plain, rtol=0, atol=0)
    # a scan covering only the images' left halves: the right halves' differences count no more
    left = torch.zeros_like(targets.coverage)
    left[:, :, :20] = 1.0
    half = ExpressionTargets(targets.cameras, targets.images, targets.depth, targets.normal, left, targets.sh, 3)
    wrong = targets.images.clone()
    wrong[:, :, 24:] = 1.0 - wrong[:, :, 24:]  # beyond 20 + 3 px: a different picture
    right_wrong = ExpressionTargets(targets.cameras, wrong, targets.depth, targets.normal, left, targets.sh, 3)
    torch.testing.assert_close(loss_of("color", moved, topo, uv, tex, right_wrong, Switches(), mask),
                               loss_of("color", moved, topo, uv, tex, half, Switches(), mask), rtol=0, atol=0)
    # gradient: what the right halves show does not move a vertex either
    grads = [torch.autograd.grad(loss_of("color", moved, topo, uv, tex, t, Switches(), mask), moved)[0]
             for t in (half, right_wrong)]
    assert float(grads[0].abs().sum()) > 0
    torch.testing.assert_close(grads[0], grads[1], rtol=0, atol=0)


def test_colour_weight_follows_the_views_and_the_downsampling():
    _, _, _, _, targets = setup(size=32)
    left = torch.zeros_like(targets.coverage)
    left[0, :, :10] = 1.0
    grown = ExpressionTargets(targets.cameras, targets.images, targets.depth, targets.normal, left, targets.sh, 1)
    picked = grown.views([1, 0])
    torch.testing.assert_close(picked.color_weight[1], grown.color_weight[0], rtol=0, atol=0)
    half = grown.downsampled(2)
    assert half.color_scan_px == 1
    # made at the coarser level's own pixels: the pooled coverage's first 5 columns, grown by one
    assert half.color_weight.shape == (2, 16, 16, 1)
    assert float(half.color_weight[0, :, :6].min()) == 1.0 and float(half.color_weight[0, :, 6:].max()) == 0.0


def test_schedule_checks_the_colour_scan_pixels():
    from gpja.register.multiscale import Schedule

    assert Schedule(lambdas=(1.0,), iterations=(1,)).color_scan_px is None  # the paper
    assert Schedule(lambdas=(1.0,), iterations=(1,), color_scan_px=3).color_scan_px == 3
    for bad in (-1, 2.5):
        with pytest.raises(ValueError, match="color_scan_px"):
            Schedule(lambdas=(1.0,), iterations=(1,), color_scan_px=bad)


def test_mouth_mask_weight_counts_the_socket_only_where_the_reference_shows_no_opening():
    """Analytic, four pixels: skin (mask 1), socket over a closed mouth, socket over an opening, background. Without
    openings the weight is the paper's mask, unchanged."""
    from gpja.register.hra import mouth_mask_weight

    mask = torch.tensor([[1.0], [0.0], [0.0], [0.0]])
    coverage = torch.tensor([[1.0], [1.0], [1.0], [0.0]])
    opening = torch.tensor([[1.0], [0.0], [1.0], [0.0]])
    np.testing.assert_array_equal(mouth_mask_weight(mask, coverage, opening).numpy().ravel(), [1.0, 1.0, 0.0, 0.0])
    assert mouth_mask_weight(mask, coverage, None) is mask


def test_mask_where_open_charges_socket_texture_over_a_closed_mouth():
    """The whole texture is socket and every reference pixel differs from it. The paper's mask counts nothing; with
    ``mask_where_open`` the references, which show no opening, count everywhere; where they show one, nothing again;
    the subset of views reads the same openings."""
    from dataclasses import replace

    V, topo, uv, tex, targets = setup()
    targets.images = torch.full_like(targets.images, 0.8)
    all_masked = torch.zeros(8, 8, 1)
    assert float(loss_of("color", V, topo, uv, tex, targets, Switches(), all_masked)) == 0.0
    where_open = replace(targets, mask_where_open=True)
    assert not where_open.opening.any()
    charged = float(loss_of("color", V, topo, uv, tex, where_open, Switches(), all_masked))
    assert charged > 0.1
    assert float(loss_of("color", V, topo, uv, tex, where_open.views([1, 0]), Switches(), all_masked)) == pytest.approx(
        charged, rel=1e-6)
    where_open.__dict__["opening"] = torch.ones_like(where_open.opening)  # every pixel an opening
    assert float(loss_of("color", V, topo, uv, tex, where_open, Switches(), all_masked)) == 0.0
    assert replace(where_open, images=where_open.images).downsampled(2).mask_where_open


def test_schedule_refuses_a_mask_where_open_that_is_not_a_boolean():
    from gpja.register.multiscale import Schedule

    assert Schedule().mask_where_open is False
    with pytest.raises(ValueError, match="mask_where_open"):
        Schedule(mask_where_open="yes")
