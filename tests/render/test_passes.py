import numpy as np
import open3d as o3d
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

from gpja.lighting import uniform_sh
from gpja.render import Topology, image_l1, render_scan_targets, render_views
from tests.render.scenes import ring_cameras, sphere, spherical_uv
from tests.tolerances import DEPTH_VS_RAYCAST_MM, FD_RELATIVE, NORMAL_VS_RAYCAST_DEG


def raycast(V, F, cam):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    v, u = np.mgrid[0 : cam.height, 0 : cam.width]
    o, d = cam.pixel_rays(np.stack([u.ravel(), v.ravel()], 1))
    hit = scene.cast_rays(o3d.core.Tensor(np.concatenate([o, d], 1).astype(np.float32)))
    t = hit["t_hit"].numpy().astype(np.float64)
    z = t * (d @ cam.R[2])  # distance along the ray -> camera depth
    return z.reshape(cam.height, cam.width), hit["primitive_normals"].numpy().reshape(cam.height, cam.width, 3)


def test_depth_and_normals_match_open3d_ray_casting():
    V, F = sphere(subdivisions=5, radius=70.0)
    cams = ring_cameras(2, 128)
    out = render_views(torch.tensor(V), torch.tensor(F), cams, passes=("depth", "normal"), antialias_edges=False)
    depth, normal = out.dense("depth").numpy()[..., 0], out.dense("normal").numpy()
    for b, cam in enumerate(cams):
        z_ref, n_ref = raycast(V, F, cam)
        both = np.isfinite(z_ref) & (depth[b] > 0)
        assert both.sum() > 1000
        assert np.median(np.abs(depth[b][both] - z_ref[both])) <= DEPTH_VS_RAYCAST_MM
        cos = np.clip((normal[b][both] * n_ref[both]).sum(-1), -1, 1)
        assert np.degrees(np.median(np.arccos(cos))) <= NORMAL_VS_RAYCAST_DEG


def scene(dtype=torch.float64, size=48):
    V, F = sphere(subdivisions=3, radius=60.0)
    uv = spherical_uv(V)
    topo = Topology(torch.tensor(F), torch.tensor(F))
    tex = torch.rand(32, 32, 3, dtype=dtype, generator=torch.Generator().manual_seed(0))
    return torch.tensor(V, dtype=dtype), topo, torch.tensor(uv, dtype=dtype), tex, ring_cameras(2, size)


def test_finite_differences_interior_pixels():
    V, topo, uv, tex, cams = scene()
    sh = torch.tensor(uniform_sh(), dtype=torch.float64)
    base = render_views(V, topo, cams, ("depth", "normal", "color"), uv=uv, texture=tex, sh=sh, antialias_edges=False)
    # interior pixels: covered, with all four neighbours covered (away from silhouettes)
    cov = base.dense("coverage")[..., 0] > 0
    interior = cov.clone()
    interior[:, 1:-1, 1:-1] &= cov[:, :-2, 1:-1] & cov[:, 2:, 1:-1] & cov[:, 1:-1, :-2] & cov[:, 1:-1, 2:]
    interior[:, [0, -1], :] = False
    interior[:, :, [0, -1]] = False
    gen = torch.Generator().manual_seed(1)
    weights = {k: torch.rand(*cov.shape, c, dtype=torch.float64, generator=gen) * interior[..., None]
               for k, c in (("depth", 1), ("normal", 3), ("color", 3))}

    def loss(Vx):
        out = render_views(Vx, topo, cams, ("depth", "normal", "color"), uv=uv, texture=tex, sh=sh, antialias_edges=False)
        return sum((out.dense(k) * w).sum() for k, w in weights.items())

    Vg = V.clone().requires_grad_(True)
    loss(Vg).backward()
    grad = Vg.grad
    for vertex in torch.argsort(grad.norm(dim=1), descending=True)[:5]:
        for axis in range(3):
            eps = 1e-5
            Vp, Vm = V.clone(), V.clone()
            Vp[vertex, axis] += eps
            Vm[vertex, axis] -= eps
            fd = (loss(Vp) - loss(Vm)) / (2 * eps)
            assert abs(fd - grad[vertex, axis]) <= FD_RELATIVE * max(1.0, abs(float(fd)))


def test_silhouette_shift_gives_gradient_of_the_right_sign():
    V, topo, _, _, cams = scene(size=64)
    cams = cams[:1]
    shift = torch.tensor([4.0, 0.0, 0.0], dtype=torch.float64)  # target moved towards image right (+X seen from front-right)
    target = render_views(V + shift, topo, cams, ("depth",)).dense("coverage").detach()
    Vg = V.clone().requires_grad_(True)
    out = render_views(Vg, topo, cams, ("depth",))
    image_l1(out, "coverage", target).backward()
    gx = Vg.grad[:, 0].sum()
    assert gx < 0, "moving the mesh towards the target must lower the loss"
    # without antialiasing coverage is piecewise constant: no gradient at all
    Vn = V.clone().requires_grad_(True)
    out = render_views(Vn, topo, cams, ("depth",), antialias_edges=False)
    assert not image_l1(out, "coverage", target).requires_grad


def test_image_l1_equals_dense_l1():
    V, topo, _, _, cams = scene()
    target = torch.rand(2, 48, 48, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    out = render_views(V, topo, cams, ("normal",))
    torch.testing.assert_close(image_l1(out, "normal", target), (out.dense("normal") - target).abs().sum())


def uniform_laplacian(F, n):
    e = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(float)
    return sp.diags(np.asarray(A.sum(1)).ravel()) - A


def tetrahedral_cameras(size):
    """Four views from the corners of a tetrahedron: together they see the whole object."""
    from gpja.camera import Camera

    K = np.array([[1.4 * size, 0, (size - 1) / 2], [0, 1.4 * size, (size - 1) / 2], [0, 0, 1.0]])
    dirs = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]) / np.sqrt(3)
    return [Camera.look_at(400 * d, (0, 0, 0), (0, 0, 1) if abs(d[2]) < 0.9 else (0, 1, 0), K, size, size, name=str(i))
            for i, d in enumerate(dirs)]


def surface_distance(P, V, F):
    """(k,) distance of points P to the triangle mesh (V, F), mm (Open3D)."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(V.astype(np.float32)), o3d.core.Tensor(F.astype(np.uint32)))
    return scene.compute_distance(o3d.core.Tensor(P.astype(np.float32))).numpy()


def test_inverse_rendering_sphere_to_ellipsoid():
    """Fit a sphere to an ellipsoid from 4 views with depth + normal losses and a smoothing preconditioner."""
    V, F = sphere(subdivisions=3, radius=55.0)
    Vt, Ft = sphere(subdivisions=5, radius=1.0)
    Vt = Vt * np.array([75.0, 60.0, 45.0])
    cams = tetrahedral_cameras(96)
    targets = render_scan_targets(Vt, Ft, cams)
    topo = Topology(torch.tensor(F))
    # smoothness-preserving update (Nicolet et al. 2021): x <- x - eta (I + lambda L)^-2 dL/dx
    solve = spla.factorized((sp.eye(len(V)) + 10.0 * uniform_laplacian(F, len(V))).tocsc())

    def chamfer(X):
        return 0.5 * (surface_distance(X, Vt, Ft).mean() + surface_distance(Vt, X, F).mean())

    x = torch.tensor(V, dtype=torch.float32)
    start = chamfer(V)
    for it in range(150):
        xg = x.clone().requires_grad_(True)
        out = render_views(xg, topo, cams, ("depth", "normal"))
        # depth and normals are compared where the target has data; coverage moves the outline
        seen = out.gather(targets["coverage"])
        loss = (image_l1(out, "depth", targets["depth"], weight=seen)
                + 20.0 * image_l1(out, "normal", targets["normal"], weight=seen)
                + 50.0 * image_l1(out, "coverage", targets["coverage"]))
        loss.backward()
        step = solve(solve(xg.grad.double().numpy()))
        x = x - torch.tensor(0.5 * step / (np.abs(step).max() + 1e-12), dtype=torch.float32) * (1.0 if it < 100 else 0.3)
    end = chamfer(x.numpy().astype(np.float64))
    assert end < start / 10, (start, end)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda V, F: (V.index_fill(0, torch.tensor([3]), float("nan")), F), "NaN or infinite"),
        (lambda V, F: (V.index_fill(0, torch.tensor([3]), float("inf")), F), "NaN or infinite"),
        (lambda V, F: (V, F + 10_000), "face indices must lie in"),
        (lambda V, F: (V[:0], F), "non-empty"),
        (lambda V, F: (V, F[:0]), "no faces"),
    ],
)
def test_bad_input(mutate, message):
    V, F = sphere(subdivisions=1)
    Vb, Fb = mutate(torch.tensor(V), torch.tensor(F))
    with pytest.raises(ValueError, match=message):
        render_views(Vb, Fb, ring_cameras(1, 16), ("depth",))


def test_zero_size_image_and_distorted_camera_rejected():
    from dataclasses import replace

    V, F = sphere(subdivisions=1)
    cam = ring_cameras(1, 16)[0]
    with pytest.raises(ValueError, match="zero-size image"):
        render_views(torch.tensor(V), torch.tensor(F), [replace(cam, width=0)], ("depth",))
    with pytest.raises(ValueError, match="lens distortion"):
        render_views(torch.tensor(V), torch.tensor(F), [replace(cam, distortion=np.array([0.1, 0, 0, 0, 0]))], ("depth",))


def test_gradients_are_bitwise_reproducible():
    """Registration must give the same numbers on every run: no op on the gradient path may
    accumulate in a thread-dependent order (advanced-indexing backward does on the CPU)."""
    from tests.render.scenes import ring_cameras, sphere

    V, F = sphere(4)
    cams = ring_cameras(4, 64)
    topo = Topology(torch.from_numpy(F))

    def gradient():
        x = torch.tensor(V, dtype=torch.float32, requires_grad=True)
        out = render_views(x, topo, cams, ("normal", "depth"))
        (out.dense("normal").square().sum() + out.dense("depth").sum()).backward()
        return x.grad

    first, second = gradient(), gradient()
    assert torch.count_nonzero(first) > 0
    assert torch.equal(first, second)


def test_uv_pass_is_the_interpolated_texture_coordinates():
    from gpja.render import interpolate_attribute, project_to_screen, rasterize_fragments

    V, topo, uv, _, cams = scene(dtype=torch.float32)
    out = render_views(V, topo, cams, ("uv",), uv=uv, antialias_edges=False)
    frags = rasterize_fragments(project_to_screen(V, cams), topo.faces, cams[0].height, cams[0].width)
    assert torch.equal(out.pixels, frags.pixel)
    assert torch.equal(out.values["uv"], interpolate_attribute(uv, topo.uv_faces, frags))
    with pytest.raises(ValueError, match="need texture coordinates"):
        render_views(V, topo.faces, cams, ("uv",))
