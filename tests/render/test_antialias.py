import numpy as np
import torch

from gpja.render import face_adjacency
from gpja.render.antialias import blend_across_edges
from tests.render.scenes import sphere


def test_face_adjacency_closed_and_open():
    V, F = sphere(subdivisions=1)
    adj = face_adjacency(F)
    assert (adj >= 0).all()  # closed surface: every edge has a neighbour
    for f in range(len(F)):
        for k in range(3):
            g = adj[f, k]
            assert f in adj[g]  # symmetric
            edge = {F[f, k], F[f, (k + 1) % 3]}
            assert edge <= set(F[g])
    open_adj = face_adjacency(np.array([[0, 1, 2], [0, 2, 3]]))
    np.testing.assert_array_equal(open_adj, [[-1, -1, 1], [0, -1, -1]])


def test_blend_analytic():
    values = torch.tensor([[1.0], [0.0]], dtype=torch.float64)  # occluder 1, neighbour 0
    occ, oth = torch.tensor([0]), torch.tensor([1])
    out = blend_across_edges(values, torch.tensor([0.8], dtype=torch.float64), occ, oth)
    torch.testing.assert_close(out[:, 0], torch.tensor([1.0, 0.3], dtype=torch.float64))  # spills 0.3 into the neighbour
    out = blend_across_edges(values, torch.tensor([0.2], dtype=torch.float64), occ, oth)
    torch.testing.assert_close(out[:, 0], torch.tensor([0.7, 0.0], dtype=torch.float64))  # loses 0.3 of its own pixel


def test_gradcheck_blend_float64():
    torch.manual_seed(3)
    values = torch.rand(6, 2, dtype=torch.float64, requires_grad=True)
    t = torch.tensor([0.1, 0.7, 0.35, 0.9], dtype=torch.float64, requires_grad=True)
    occ, oth = torch.tensor([0, 1, 2, 2]), torch.tensor([3, 4, 5, 1])
    assert torch.autograd.gradcheck(lambda v, tt: blend_across_edges(v, tt, occ, oth), (values, t))
