import numpy as np
import torch

from gpja.render import face_adjacency
from gpja.render.silhouettes import blend_across_edges
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


def test_edge_candidates_list_every_edge_once_in_face_order():
    from gpja.render.silhouettes import edge_candidates

    # two triangles sharing edge (0, 2): face 0's edge 2 (corners 2 -> 0) meets face 1's edge 0 (0 -> 2)
    np.testing.assert_array_equal(edge_candidates(face_adjacency(np.array([[0, 1, 2], [0, 2, 3]]))),
                                  [[0, 0, -1, 0], [0, 1, -1, 1], [0, 2, 1, 2], [1, 1, -1, 3], [1, 2, -1, 4]])
    V, F = sphere(subdivisions=2)
    adj = face_adjacency(F)
    c = edge_candidates(adj)
    assert len(c) == 3 * len(F) // 2  # closed surface: each edge once
    keys = {frozenset((F[f, k], F[f, (k + 1) % 3])) for f, k, _, _ in c}
    assert len(keys) == len(c)
    assert (c[:, 2] > c[:, 0]).all() and (np.diff(c[:, 0] * 3 + c[:, 1]) > 0).all()
    np.testing.assert_array_equal(c[:, 2], adj[c[:, 0], c[:, 1]])
    np.testing.assert_array_equal(c[:, 3], np.arange(len(c)))


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


def test_edge_pairs_match_a_brute_force_scan_of_all_pixel_pairs():
    """The outline-driven pair search finds exactly the pairs a scan of every pixel pair finds."""
    import trimesh

    from gpja.render import project_to_screen, rasterize_fragments
    from gpja.render.silhouettes import _find_edge, edge_candidates, find_edge_pairs
    from tests.render.scenes import ring_cameras

    big = trimesh.creation.icosphere(subdivisions=4, radius=60)
    small = trimesh.creation.icosphere(subdivisions=2, radius=25)  # in front of it: interior occlusion edges
    V = np.concatenate([big.vertices, np.asarray(small.vertices) + [20, 10, 60]])
    F = np.concatenate([big.faces, np.asarray(small.faces) + len(big.vertices)]).astype(np.int64)
    size = 64
    cams = ring_cameras(2, size)
    screen = project_to_screen(torch.tensor(V), cams)
    frags = rasterize_fragments(screen, torch.tensor(F), size, size)
    adj = face_adjacency(F)
    pairs = find_edge_pairs(frags, screen, torch.tensor(F), adj)
    found = set(zip(pairs.occluder.tolist(), pairs.other.tolist()))
    kept = find_edge_pairs(frags, screen, torch.tensor(F), adj, edge_candidates(adj))  # the candidates kept by a Topology
    for a, b in zip(vars(pairs).values(), vars(kept).values()):
        torch.testing.assert_close(a, b, rtol=0, atol=0)  # the same pairs in the same order
    shuffled = edge_candidates(adj)[np.random.default_rng(0).permutation(len(adj) * 3 // 2)]
    searched = find_edge_pairs(frags, screen, torch.tensor(F), adj, shuffled)  # rows searched in another order
    for a, b in zip(vars(pairs).values(), vars(searched).values()):
        torch.testing.assert_close(a, b, rtol=0, atol=0)  # put back in candidate order
    S = screen.numpy()
    # front-facing: negative signed area in y-down pixels (the rasteriser's by-product, checked here)
    tri = S[:, F]  # (B, m, 3 corners, 3)
    d1, d2 = tri[:, :, 1, :2] - tri[:, :, 0, :2], tri[:, :, 2, :2] - tri[:, :, 0, :2]
    facing = d1[..., 0] * d2[..., 1] - d1[..., 1] * d2[..., 0] < 0.0
    np.testing.assert_array_equal(frags.facing, facing)
    expected = set()
    for b in range(len(cams)):
        T, D = frags.tri_id[b], frags.depth[b]
        for axis in range(2):
            for y in range(size - axis):
                for x in range(size - 1 + axis):
                    qy, qx = y + axis, x + 1 - axis
                    if T[y, x] == T[qy, qx]:
                        continue
                    first = T[qy, qx] < 0 or (T[y, x] >= 0 and D[y, x] <= D[qy, qx])
                    (ox, oy), (px, py) = ((x, y), (qx, qy)) if first else ((qx, qy), (x, y))
                    va, _ = _find_edge(S, facing, b, F, adj, T[oy, ox], float(ox), float(oy), float(px), float(py))
                    if va >= 0:
                        expected.add(((b * size + oy) * size + ox, (b * size + py) * size + px))
    assert len(found) > 100
    assert found == expected
