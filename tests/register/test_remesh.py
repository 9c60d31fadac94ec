import numpy as np
import torch

from gpja.lighting import uniform_sh
from gpja.mesh import TexturedMesh
from gpja.register.remesh import refine_by_factor, split_long_edges, unique_edges
from gpja.render import Topology, render_views
from tests.render.scenes import ring_cameras, sphere

#: Texture-mapped renders before and after refinement must agree to this PSNR (issue: >= 40 dB).
MIN_PSNR_DB = 40.0
#: Hausdorff distance between the surfaces before and after, as a fraction of the mean edge length.
MAX_HAUSDORFF_FRACTION = 0.01


def seamed_sphere(subdivisions=3):
    """A sphere with a longitude seam: UVs split along x < 0, z ~ 0 (positions welded)."""
    V, F = sphere(subdivisions=subdivisions, radius=60.0)
    theta = np.arctan2(V[:, 0], V[:, 2])
    u = 0.5 + theta / (2 * np.pi)
    v = 0.5 + np.arcsin(np.clip(V[:, 1] / 60.0, -1, 1)) / np.pi
    UV = list(np.stack([u, v], 1))
    F_uv = F.copy()
    extra = {}
    for f, tri in enumerate(F):
        us = u[tri]
        if us.max() - us.min() > 0.5:  # face straddles the seam: give its small-u corners shifted copies
            for k, vi in enumerate(tri):
                if u[vi] < 0.5:
                    if vi not in extra:
                        extra[vi] = len(UV)
                        UV.append(np.array([u[vi] + 1.0, v[vi]]))
                    F_uv[f, k] = extra[vi]
    UV = np.array(UV)
    UV[:, 0] /= 1.5  # keep in [0, 1]
    return TexturedMesh(V, F, UV, F_uv)


def test_single_split_templates_analytic():
    # edges 10, ~5.1, ~5.1: one split -> 2 triangles, two -> 3, three -> 4
    V = np.array([[0.0, 0, 0], [10, 0, 0], [5, 1, 0]])
    m = TexturedMesh(V, np.array([[0, 1, 2]]), V[:, :2] / 10, np.array([[0, 1, 2]]))
    one = split_long_edges(m, 6.0)
    assert len(one.F) == 2 and len(one.V) == 4
    np.testing.assert_allclose(one.V[3], [5, 0, 0])
    np.testing.assert_allclose(one.UV[3], [0.5, 0])
    W = np.array([[0.0, 0, 0], [10, 0, 0], [0, 1, 0]])  # edges 10, ~10.05, 1
    two = split_long_edges(TexturedMesh(W, np.array([[0, 1, 2]])), 5.0)
    assert len(two.F) == 3 and len(two.V) == 5
    np.testing.assert_allclose(sum(np.linalg.norm(np.cross(*(two.V[f[1:]] - two.V[f[0]]))) / 2 for f in two.F), 5.0)
    three = split_long_edges(m, 0.5)
    assert len(three.F) == 4 and len(three.V) == 6
    # orientation kept: all normals along +z
    assert (three.face_normals()[:, 2] > 0.99).all()


def test_refinement_is_conforming_and_keeps_seams():
    mesh = seamed_sphere()
    fine = refine_by_factor(mesh, 2.5)
    assert 2.3 < len(fine.V) / len(mesh.V) < 2.7
    edges, face_edge = unique_edges(fine.F)
    counts = np.bincount(face_edge.ravel(), minlength=len(edges))
    assert (counts == 2).all()  # closed, no T-junctions
    assert len(fine.V) - len(edges) + len(fine.F) == 2  # still genus 0
    np.testing.assert_array_equal(fine.V[: len(mesh.V)], mesh.V)  # old vertices keep their indices
    # seam edges stay seams: faces sharing a geometric edge across the seam have distinct UV edges
    assert len(fine.UV) - len(mesh.UV) > len(fine.V) - len(mesh.V)  # seam midpoints were duplicated in UV
    fine.validate("refined")


def test_refinement_keeps_texture_mapped_renders():
    mesh = seamed_sphere()
    fine = refine_by_factor(mesh, 2.5)
    tex = torch.rand(64, 64, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    cams = ring_cameras(3, 96)
    sh = torch.tensor(uniform_sh(), dtype=torch.float64)

    def render(m):
        out = render_views(torch.tensor(m.V), Topology(torch.tensor(m.F), torch.tensor(m.F_uv)), cams, ("color",),
                           uv=torch.tensor(m.UV), texture=tex, sh=sh)
        return out.dense("color")

    a, b = render(mesh), render(fine)
    mse = float(((a - b) ** 2).mean())
    psnr = 10 * np.log10(1.0 / max(mse, 1e-20))
    assert psnr >= MIN_PSNR_DB, psnr


def test_hausdorff_distance_is_tiny():
    import open3d as o3d

    mesh = seamed_sphere()
    fine = refine_by_factor(mesh, 2.5)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.V.astype(np.float32)), o3d.core.Tensor(mesh.F.astype(np.uint32)))
    d = scene.compute_distance(o3d.core.Tensor(fine.V.astype(np.float32))).numpy()
    assert d.max() <= MAX_HAUSDORFF_FRACTION * mesh.edge_lengths().mean()


def test_regression_counts():
    mesh = seamed_sphere(subdivisions=2)
    fine = refine_by_factor(mesh, 2.5)
    assert (len(mesh.V), len(mesh.F)) == (162, 320)
    # 1.5 x 162 = 243 new vertices asked; equal-length edges at the threshold are not split
    assert len(fine.V) == 402
    assert len(fine.F) == len(fine.V) * 2 - 4  # closed genus-0 triangle mesh: F = 2V - 4
