import numba
import numpy as np
import pytest
import torch

from gpja.render.normals import vertex_incidence, vertex_normals, vertex_normals_torch
from tests.render.scenes import sphere
from tests.tolerances import EXACT_F64


def test_octahedron_normals_point_along_the_vertices():
    V = torch.tensor([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=torch.float64)
    F = torch.tensor([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    torch.testing.assert_close(vertex_normals(V, F), V, rtol=0, atol=EXACT_F64)


def test_area_weighting_and_an_unused_vertex():
    # two faces meeting at vertex 0: one in the z = 0 plane (area 2), one in the x = 0 plane (area 0.5);
    # vertex 4 is in no face and gets a zero normal
    V = torch.tensor([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 1], [5, 5, 5]], dtype=torch.float64)
    F = torch.tensor([[0, 1, 2], [0, 3, 2]])
    n = vertex_normals(V, F)
    expected = torch.tensor([-2.0, 0, 4.0], dtype=torch.float64)  # 2 x area 2 x (0, 0, 1) + 2 x area 0.5 x (-1, 0, 0)
    torch.testing.assert_close(n[0], expected / expected.norm(), rtol=0, atol=EXACT_F64)
    torch.testing.assert_close(n[4], torch.zeros(3, dtype=torch.float64), rtol=0, atol=0)


def test_gradcheck_float64():
    V, F = sphere(subdivisions=1, radius=10.0)
    Vt = torch.tensor(V + np.random.default_rng(0).normal(scale=0.5, size=V.shape), requires_grad=True)
    Ft = torch.from_numpy(F)
    assert torch.autograd.gradcheck(lambda v: vertex_normals(v, Ft), (Vt,))


def test_matches_the_torch_expression_and_its_gradient():
    V, F = sphere(subdivisions=3)
    Vt = torch.tensor(V + np.random.default_rng(1).normal(scale=1.0, size=V.shape), requires_grad=True)
    Ft = torch.from_numpy(F)
    grad = torch.randn(len(V), 3, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    fused = vertex_normals(Vt, Ft, vertex_incidence(F, len(V)))
    (g_fused,) = torch.autograd.grad(fused, Vt, grad)
    plain = vertex_normals_torch(Vt, Ft)
    (g_plain,) = torch.autograd.grad(plain, Vt, grad)
    torch.testing.assert_close(fused, plain, rtol=0, atol=EXACT_F64)
    torch.testing.assert_close(g_fused, g_plain, rtol=1e-9, atol=EXACT_F64)


def test_incidence_lists_each_vertex_corner_in_face_order():
    F = np.array([[0, 1, 2], [2, 1, 3], [3, 0, 2]])
    starts, corners = vertex_incidence(F, 5)
    np.testing.assert_array_equal(starts, [0, 2, 4, 7, 9, 9])
    np.testing.assert_array_equal(corners, [0, 7, 1, 4, 2, 3, 8, 5, 6])


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two numba threads")
def test_regression_result_does_not_depend_on_the_thread_count():
    V, F = sphere(subdivisions=4)
    Vt = torch.tensor(V * [1.0, 1.3, 0.8], dtype=torch.float32, requires_grad=True)
    grad = torch.randn(len(V), 3, generator=torch.Generator().manual_seed(3))
    results = []
    before = numba.get_num_threads()
    try:
        for threads in (1, 2):
            numba.set_num_threads(threads)
            n = vertex_normals(Vt, torch.from_numpy(F))
            (g,) = torch.autograd.grad(n, Vt, grad)
            results.append((n.detach().numpy().tobytes(), g.numpy().tobytes()))
    finally:
        numba.set_num_threads(before)
    assert results[0] == results[1]
