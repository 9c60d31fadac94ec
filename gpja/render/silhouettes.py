"""Analytic edge antialiasing, so coverage changes give vertex gradients.

In the spirit of nvdiffrast's ``antialias``: for every pair of horizontally or
vertically adjacent pixels covered by different triangles (or one triangle and
the background), the nearer triangle is checked for a *silhouette* edge (a
boundary edge, or one whose two faces face opposite ways in that view) that
crosses the segment between the two pixel centres. Where one does, the two
colours are blended by how far the edge lies from the pixel boundary, and the
crossing point is computed in torch from the projected edge vertices, so the
blend's derivative moves the silhouette. Finding the pairs is integer work
done by a numba kernel; the blend is a small differentiable torch step.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
import torch

from gpja.mesh import unique_edges
from gpja.render.fragments import Fragments


def face_adjacency(faces: np.ndarray) -> np.ndarray:
    """Neighbouring face across each edge.

    Args:
        faces: (m, 3) int vertex indices; edge k joins corners k and (k+1) % 3.
    Returns:
        (m, 3) int64 index of the face sharing edge k, -1 on boundary (and
        non-manifold) edges.
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    m = len(faces)
    if m == 0:
        return np.zeros((0, 3), dtype=np.int64)
    _, face_edge = unique_edges(faces)
    inverse = face_edge.ravel()
    counts = np.bincount(inverse)
    order = np.argsort(inverse, kind="stable")
    adj = np.full(3 * m, -1, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pair = counts[inverse[order[starts]]] == 2
    a = order[starts[pair]]
    b = order[starts[pair] + 1]
    adj[a] = b // 3
    adj[b] = a // 3
    return adj.reshape(m, 3)


#: How many faces the search may cross along a pixel segment before giving up.
MAX_WALK = 16


@nb.njit(cache=True, inline="always")
def _segment_crossing(screen, b, va, vb, ox, oy, qx, qy):
    """Parameter t of the segment o->q where it crosses edge (va, vb); -1 if it misses."""
    xa, ya = np.float64(screen[b, va, 0]), np.float64(screen[b, va, 1])
    xb, yb = np.float64(screen[b, vb, 0]), np.float64(screen[b, vb, 1])
    if oy == qy:  # horizontal pair: the edge must span the row y = oy
        if (ya - oy) * (yb - oy) > 0.0 or ya == yb:
            return -1.0
        return (xa + (oy - ya) * (xb - xa) / (yb - ya) - ox) * (qx - ox)
    if (xa - ox) * (xb - ox) > 0.0 or xa == xb:
        return -1.0
    return (ya + (ox - xa) * (yb - ya) / (xb - xa) - oy) * (qy - oy)


@nb.njit(cache=True)
def _find_edge(screen, facing, b, faces, adj, f, ox, oy, qx, qy):
    """The silhouette edge the segment from pixel centre o (inside face f) to q leaves through.

    Walks from f across non-silhouette edges along the segment, because near a
    silhouette the triangle under the pixel centre is often not the one whose
    edge forms the outline (grazing triangles are thin in projection).
    Returns the edge's two vertex indices, or (-1, -1).
    """
    entry = -1
    t_prev = -1e-9
    for _ in range(MAX_WALK):
        front = facing[b, f]
        best_k = -1
        best_t = 2.0
        for k in range(3):
            if k == entry:
                continue
            t = _segment_crossing(screen, b, faces[f, k], faces[f, (k + 1) % 3], ox, oy, qx, qy)
            if t >= t_prev and t < best_t:
                best_t = t
                best_k = k
        if best_k < 0 or best_t > 1.0:
            return -1, -1
        g = adj[f, best_k]
        if g < 0 or facing[b, g] != front:
            return faces[f, best_k], faces[f, (best_k + 1) % 3]
        entry = -1
        for k in range(3):
            if adj[g, k] == f:
                entry = k
        f = g
        t_prev = best_t
    return -1, -1


@nb.njit(cache=True, inline="always")
def _emit(tri_id, depth, screen, facing, faces, adj, b, x, y, qx, qy, va, vb, axis, out, base, n, capacity, row):
    """Record pixel pair (x, y)-(qx, qy) if edge (va, vb) is the silhouette its face walk finds (``row``: the
    edge's candidate index)."""
    height, width = tri_id.shape[1], tri_id.shape[2]
    if x < 0 or y < 0 or qx >= width or qy >= height:
        return n
    t0 = tri_id[b, y, x]
    t1 = tri_id[b, qy, qx]
    if t0 == t1:
        return n
    if t1 < 0 or (t0 >= 0 and depth[b, y, x] <= depth[b, qy, qx]):
        f, ox, oy, px, py = t0, x, y, qx, qy  # occluder at the first pixel
    else:
        f, ox, oy, px, py = t1, qx, qy, x, y
    ea, eb = _find_edge(screen, facing, b, faces, adj, f, float(ox), float(oy), float(px), float(py))
    if not ((ea == va and eb == vb) or (ea == vb and eb == va)):
        return n  # another edge (or none) bounds the visible surface here: hidden or interior
    if n < capacity:  # past capacity only count; the caller retries larger
        r = base + n
        out[r, 0] = (b * height + oy) * width + ox
        out[r, 1] = (b * height + py) * width + px
        out[r, 2] = b
        out[r, 3] = ea
        out[r, 4] = eb
        out[r, 5] = axis
        out[r, 6] = row
    return n + 1


def edge_candidates(adjacency: np.ndarray) -> np.ndarray:
    """The edges a silhouette can run along, each once: every rim edge, and every interior edge from its
    lower-numbered face, in face order.

    Args:
        adjacency: (m, 3) int64 from :func:`face_adjacency`.
    Returns:
        (c, 4) int64 rows ``(f, k, g, i)``: face ``f``'s edge ``k`` (corners k, k + 1), ``g`` the face across it
        (-1 on the rim), ``i`` the row's own index (which :func:`find_edge_pairs` orders its pairs by, so that
        the rows may be visited in another order: ``Topology.visit_order``). Built once per topology
        (``Topology.silhouette_candidates``), so that each rasterisation's search reads only these (half the
        face-edges) instead of testing all of them.
    """
    adj = np.asarray(adjacency, dtype=np.int64).reshape(-1, 3)
    f = np.repeat(np.arange(len(adj), dtype=np.int64), 3).reshape(-1, 3)
    first = (adj < 0) | (adj > f)  # row-major order of (f, k): the order the kernel visited them in
    f_idx, k_idx = np.nonzero(first)
    return np.ascontiguousarray(np.stack([f_idx, k_idx, adj[f_idx, k_idx], np.arange(len(f_idx))],
                                         axis=1).astype(np.int64))


@nb.njit(cache=True, parallel=True)
def _edge_pairs_kernel(tri_id, depth, screen, facing, faces, adj, candidates, counts, capacity, out):
    """For every view, the pixel pairs straddling a visible silhouette edge.

    Candidates come from the silhouette edges themselves (each edge is walked
    along the pixel rows and columns it crosses), so the work scales with the
    outline length, not with the image area. ``candidates`` (:func:`edge_candidates`) lists each edge once,
    so a view only tests whether the faces on its two sides face it alike. Each pair's column 6 is its edge's
    candidate index, by which the caller puts the pairs in candidate order.
    """
    n_views, height, width = tri_id.shape
    for b in nb.prange(n_views):
        n = 0
        base = b * capacity
        for c in range(candidates.shape[0]):
            f = candidates[c, 0]
            g = candidates[c, 2]
            if g >= 0 and facing[b, g] == facing[b, f]:
                continue  # interior edge: both faces look the same way
            k = candidates[c, 1]
            va = faces[f, k]
            vb = faces[f, (k + 1) % 3]
            xa, ya = np.float64(screen[b, va, 0]), np.float64(screen[b, va, 1])
            xb, yb = np.float64(screen[b, vb, 0]), np.float64(screen[b, vb, 1])
            if screen[b, va, 2] < 1.0 or screen[b, vb, 2] < 1.0:
                continue
            # horizontal pairs: rows y with the edge crossing between x and x + 1
            if ya != yb:
                y0 = max(0, int(np.ceil(min(ya, yb))))
                y1 = min(height - 1, int(np.floor(max(ya, yb))))
                for y in range(y0, y1 + 1):
                    xc = xa + (y - ya) * (xb - xa) / (yb - ya)
                    x = int(np.floor(xc))
                    if x < -1 or x >= width:
                        continue
                    n = _emit(tri_id, depth, screen, facing, faces, adj, b, x, y, x + 1, y, va, vb, 0, out, base, n, capacity,
                               candidates[c, 3])
            # vertical pairs: columns x with the edge crossing between y and y + 1
            if xa != xb:
                x0 = max(0, int(np.ceil(min(xa, xb))))
                x1 = min(width - 1, int(np.floor(max(xa, xb))))
                for x in range(x0, x1 + 1):
                    yc = ya + (x - xa) * (yb - ya) / (xb - xa)
                    y = int(np.floor(yc))
                    if y < -1 or y >= height:
                        continue
                    n = _emit(tri_id, depth, screen, facing, faces, adj, b, x, y, x, y + 1, va, vb, 1, out, base, n, capacity,
                               candidates[c, 3])
        counts[b] = n


@dataclass
class EdgePairs:
    """Pixel pairs straddling a silhouette edge, found once per rasterisation.

    Attributes (all (E,) int64 tensors):
        occluder, other: flat pixel indices (``(b * H + y) * W + x``) of the
            pixel covered by the near triangle and of its neighbour.
        view: the view index b.
        va, vb: the silhouette edge's vertex indices.
        axis: 0 for a horizontal pair, 1 for a vertical one.
    """

    occluder: torch.Tensor
    other: torch.Tensor
    view: torch.Tensor
    va: torch.Tensor
    vb: torch.Tensor
    axis: torch.Tensor


def find_edge_pairs(frags: Fragments, screen: torch.Tensor, faces: torch.Tensor, adjacency: np.ndarray,
                    candidates: np.ndarray | None = None) -> EdgePairs:
    """Find the pixel pairs the antialiasing pass blends (no gradient).

    Uses the rasteriser's per-view face orientation (``frags.facing``); ``screen``
    may be float32 or float64 (read as float64 by the kernels, never copied). ``candidates``:
    :func:`edge_candidates` of ``adjacency`` when the caller keeps them (``Topology``), in any row order
    (``Topology.visit_order``: the search then walks neighbouring edges one after another); None builds them.
    Each view's pairs come out in candidate-index order, whatever order the rows were searched in.
    """
    scr = np.ascontiguousarray(screen.detach().numpy())
    fcs = np.ascontiguousarray(faces.detach().numpy(), dtype=np.int64)
    facing = frags.facing
    if candidates is None:
        candidates = edge_candidates(adjacency)
    n_views = scr.shape[0]
    counts = np.zeros(n_views, dtype=np.int64)
    height, width = frags.tri_id.shape[1:]
    capacity = 8 * (height + width)  # a few outline lengths per view; retried if exceeded
    while True:
        out = np.empty((n_views * capacity, 7), dtype=np.int64)
        _edge_pairs_kernel(frags.tri_id, frags.depth, scr, facing, fcs, adjacency, candidates, counts, capacity, out)
        if counts.max() <= capacity:
            break
        capacity = int(counts.max())
    views = [out[b * capacity : b * capacity + counts[b]] for b in range(n_views)]
    # candidate order (stable: an edge's own pairs keep the order it emitted them in)
    out = np.concatenate([v[np.argsort(v[:, 6], kind="stable"), :6] for v in views])
    cols = torch.from_numpy(out).to(screen.device).unbind(1)
    return EdgePairs(*cols)


def edge_crossings(screen: torch.Tensor, pairs: EdgePairs, width: int, height: int) -> torch.Tensor:
    """Where each silhouette edge crosses its pixel pair, from the occluder's centre.

    Returns:
        (E,) in [0, 1]: 0 at the occluder pixel's centre, 1 at the other's.
        Differentiable in ``screen`` (B, n, 3).
    """
    n_vertices = screen.shape[1]
    flat = screen.reshape(-1, 3)
    # index_select: its backward (index_add_) is deterministic on the CPU, advanced indexing's is not;
    # one call for both ends, so the backward zero-fills one screen-sized gradient, not two
    rows = pairs.view * n_vertices
    ends = flat.index_select(0, torch.cat([rows + pairs.va, rows + pairs.vb]))
    a, b = ends[: len(rows)], ends[len(rows):]
    rem_o = pairs.occluder % (width * height)
    rem_q = pairs.other % (width * height)
    ox, oy = (rem_o % width).to(screen.dtype), (rem_o // width).to(screen.dtype)
    qx, qy = (rem_q % width).to(screen.dtype), (rem_q // width).to(screen.dtype)
    horizontal = pairs.axis == 0
    # along x for horizontal pairs, along y for vertical ones
    u_a = torch.where(horizontal, a[:, 0], a[:, 1])
    u_b = torch.where(horizontal, b[:, 0], b[:, 1])
    w_a = torch.where(horizontal, a[:, 1], a[:, 0])
    w_b = torch.where(horizontal, b[:, 1], b[:, 0])
    o_u = torch.where(horizontal, ox, oy)
    o_w = torch.where(horizontal, oy, ox)
    step = torch.where(horizontal, qx - ox, qy - oy)
    crossing = u_a + (o_w - w_a) * (u_b - u_a) / (w_b - w_a)
    return ((crossing - o_u) * step).clamp(0.0, 1.0)


def blend_across_edges(values: torch.Tensor, t: torch.Tensor, occluder_row: torch.Tensor,
                       other_row: torch.Tensor) -> torch.Tensor:
    """Blend pixel values across silhouette edges (the antialiasing step).

    The occluding triangle covers its pixel along the pair's axis from the far
    side up to the edge at ``t``: for t > 1/2 it spills into the neighbour by
    t - 1/2 of a pixel, for t < 1/2 it leaves 1/2 - t of its own pixel to the
    neighbour's surface. Works on a render's sparse pixel table.

    Args:
        values: (R, C) values of the render's pixel rows (background filled in).
        t: (E,) edge crossings from ``edge_crossings`` (differentiable).
        occluder_row, other_row: (E,) int64 rows of each pair's two pixels.
    Returns:
        (R, C) antialiased values, differentiable in ``values`` and ``t``.
    """
    t = t[:, None]
    c_occ = values[occluder_row]
    c_oth = values[other_row]
    into_other = torch.relu(t - 0.5) * (c_occ - c_oth)
    into_occluder = torch.relu(0.5 - t) * (c_oth - c_occ)
    return values.index_add(0, other_row, into_other).index_add(0, occluder_row, into_occluder)


def antialias(values: torch.Tensor, screen: torch.Tensor, pairs: EdgePairs, occluder_row: torch.Tensor,
              other_row: torch.Tensor, width: int, height: int) -> torch.Tensor:
    """Antialias a sparse pixel table; gradients reach the silhouette edges' vertices.

    Args:
        values: (R, C) values of the render's pixel rows (background filled in).
        screen: (B, n, 3) projected vertices the render was rasterised from.
        pairs: from ``find_edge_pairs`` for the same rasterisation.
        occluder_row, other_row: (E,) int64 rows of ``values`` of each pair's pixels.
        width, height: image size in pixels.
    Returns:
        (R, C) antialiased values.
    """
    if len(pairs.occluder) == 0:
        return values
    return blend_across_edges(values, edge_crossings(screen, pairs, width, height), occluder_row, other_row)
