"""gpja.render.output: the spatial face order (a Z-order curve of the face centroids)."""
import numpy as np
import pytest
import torch

from gpja.lighting import uniform_sh
from gpja.register.multiscale import Schedule
from gpja.render import Topology, render_views
from gpja.render.output import spatial_face_order
from tests.render.scenes import ring_cameras, sphere, spherical_uv
from tests.tolerances import FACE_ORDER_RELATIVE


def test_corner_faces_follow_the_curve():
    # five tiny faces at the corners of a unit box: the curve interleaves x (lowest bit), y, z (highest), so
    # the order is origin, +x, +y, +z, (1, 1, 1), whatever order the faces come in
    corners = np.array([[1, 1, 1], [0, 0, 1], [0, 1, 0], [0, 0, 0], [1, 0, 0]], dtype=np.float64)
    V = np.repeat(corners, 3, axis=0) + np.tile(np.array([[0, 0, 0], [1e-4, 0, 0], [0, 1e-4, 0]]), (5, 1))
    F = np.arange(15).reshape(5, 3)
    order = spatial_face_order(V, F)
    assert corners[order].tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]]


def test_a_permutation_that_brings_neighbours_together():
    V, F = sphere(subdivisions=4, radius=60.0)
    shuffled = F[np.random.default_rng(0).permutation(len(F))]
    order = spatial_face_order(V, shuffled)
    assert np.array_equal(np.sort(order), np.arange(len(F)))
    centroids = V[shuffled].mean(axis=1)
    step = lambda C: np.median(np.linalg.norm(np.diff(C, axis=0), axis=1))  # noqa: E731
    # a shuffled sphere's consecutive faces are a radius apart; along the curve, about one face apart
    assert step(centroids[order]) < 0.1 * step(centroids)
    # the order depends on the faces, not on their input order
    assert np.array_equal(shuffled[order], F[spatial_face_order(V, F)])
    assert spatial_face_order(V, F[:0]).shape == (0,)


def shuffled_sphere_scene():
    """A sphere with its faces shuffled, texture coordinates, a random texture, 3 cameras at 64 px and random
    weights for 7 channels of their images."""
    V, F = sphere(subdivisions=3, radius=60.0)
    F = F[np.random.default_rng(1).permutation(len(F))]
    uv = torch.tensor(spherical_uv(V), dtype=torch.float32)
    tex = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0))
    weights = torch.rand(3, 64, 64, 7, generator=torch.Generator().manual_seed(2))
    return V, F, uv, tex, ring_cameras(3, 64), weights


def test_rendering_in_spatial_order_gives_the_same_images_and_gradients():
    V, F, uv, tex, cams, weights = shuffled_sphere_scene()
    results = []
    for topo in (Topology(F, F), Topology.in_spatial_order(V, F, F)):
        Vt = torch.tensor(V, dtype=torch.float32, requires_grad=True)
        out = render_views(Vt, topo, cams, ("color", "depth", "normal"), uv=uv, texture=tex,
                           sh=torch.tensor(uniform_sh(), dtype=torch.float32))
        images = torch.cat([out.dense(k) for k in ("color", "depth", "normal")], dim=-1)
        (images * weights).sum().backward()
        results.append((images.detach(), out.dense("coverage"), Vt.grad))
    (a, cov_a, grad_a), (b, cov_b, grad_b) = results
    assert torch.equal(cov_a, cov_b)
    assert (a - b).abs().max() <= FACE_ORDER_RELATIVE * a.abs().max()
    assert (grad_a - grad_b).abs().max() <= FACE_ORDER_RELATIVE * grad_a.abs().max()
    # and it is another order: the identity would pass the comparisons above trivially
    assert not torch.equal(Topology.in_spatial_order(V, F, F).faces, torch.as_tensor(F))


def test_the_visiting_order_is_built_at_the_second_render_and_changes_nothing():
    V, F, uv, tex, cams, weights = shuffled_sphere_scene()
    topo = Topology(F, F)
    results = []
    for _ in range(3):
        Vt = torch.tensor(V, dtype=torch.float32, requires_grad=True)
        out = render_views(Vt, topo, cams, ("color", "depth", "normal"), uv=uv, texture=tex,
                           sh=torch.tensor(uniform_sh(), dtype=torch.float32), cull_backfaces=True)
        images = torch.cat([out.dense(k) for k in ("color", "depth", "normal", "coverage")], dim=-1)
        (images[..., :7] * weights).sum().backward()
        results.append((images.detach(), Vt.grad, topo._visit))
    assert results[0][2] is None and results[1][2] is not None  # built by the second render, kept after
    ids, ordered, candidates = results[2][2]
    assert not np.array_equal(ids, np.arange(len(F))) and np.array_equal(np.sort(ids), np.arange(len(F)))
    np.testing.assert_array_equal(ordered, F[ids])
    np.testing.assert_array_equal(np.sort(candidates[:, 3]), np.arange(len(candidates)))
    for images, grad, _ in results[1:]:  # the same bits as the render in the faces' own order
        assert torch.equal(images, results[0][0]) and torch.equal(grad, results[0][1])


def test_the_schedule_names_a_bad_face_order():
    with pytest.raises(ValueError, match="face_order must be one of mesh, spatial"):
        Schedule(face_order="random")
