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


def test_rendering_in_spatial_order_gives_the_same_images_and_gradients():
    V, F = sphere(subdivisions=3, radius=60.0)
    F = F[np.random.default_rng(1).permutation(len(F))]
    uv = torch.tensor(spherical_uv(V), dtype=torch.float32)
    tex = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0))
    cams = ring_cameras(3, 64)
    weights = torch.rand(3, 64, 64, 7, generator=torch.Generator().manual_seed(2))
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


def test_the_schedule_names_a_bad_face_order():
    with pytest.raises(ValueError, match="face_order must be one of mesh, spatial"):
        Schedule(face_order="random")
