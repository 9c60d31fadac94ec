"""Refinement between optimisation levels that keeps the texture parametrisation exactly.

Selective midpoint edge splitting: every edge longer than a threshold gets a
midpoint, and each triangle is replaced by the conforming template for its
number of split edges (1 -> 2, 2 -> 3, 3 -> 4 triangles; "red-green"
refinement), so no T-junctions arise. Positions of new vertices are edge
midpoints, so the surface does not move at all; texture coordinates are
interpolated on the UV edge of each side of a seam separately, so seams stay
seams and every texture-mapped render is unchanged.

Written here rather than taken from pymeshlab's isotropic remeshing because the
split-only schedule must also carry the separate UV index (``F_uv``) exactly,
and because choosing the threshold as an edge-length quantile gives the
paper's ~2.5x vertex growth per level (uniform 1-to-4 subdivision gives ~4x).
"""
from __future__ import annotations

import numpy as np

from gpja.mesh import TexturedMesh, unique_edges


def _split_faces(F: np.ndarray, face_edge: np.ndarray, split: np.ndarray, midpoint_id: np.ndarray) -> np.ndarray:
    """Conforming red-green templates for one index buffer.

    Args:
        F: (m, 3) corners; face_edge: (m, 3) edge ids; split: (e,) bool per edge;
        midpoint_id: (e,) index of each split edge's new vertex in this buffer.
    Returns:
        (m', 3) refined faces, orientation preserved.
    """
    s = split[face_edge]  # (m, 3): edge k of face f is split
    n_split = s.sum(axis=1)
    out = [F[n_split == 0]]
    # one split edge: rotate so it is edge 0 (corners a, b), then (a, m, c), (m, b, c)
    for k in range(3):
        sel = (n_split == 1) & s[:, k]
        if sel.any():
            a, b, c = F[sel, k], F[sel, (k + 1) % 3], F[sel, (k + 2) % 3]
            m = midpoint_id[face_edge[sel, k]]
            out += [np.stack([a, m, c], 1), np.stack([m, b, c], 1)]
    # two split edges: rotate so the unsplit edge is edge 2 (c, a); edges 0 (a,b) and 1 (b,c) split
    for k in range(3):
        sel = (n_split == 2) & ~s[:, (k + 2) % 3]
        if sel.any():
            a, b, c = F[sel, k], F[sel, (k + 1) % 3], F[sel, (k + 2) % 3]
            m_ab = midpoint_id[face_edge[sel, k]]
            m_bc = midpoint_id[face_edge[sel, (k + 1) % 3]]
            out += [np.stack([m_ab, b, m_bc], 1), np.stack([a, m_ab, m_bc], 1), np.stack([a, m_bc, c], 1)]
    sel = n_split == 3
    if sel.any():
        a, b, c = F[sel, 0], F[sel, 1], F[sel, 2]
        m0, m1, m2 = (midpoint_id[face_edge[sel, k]] for k in range(3))
        out += [np.stack([a, m0, m2], 1), np.stack([m0, b, m1], 1), np.stack([m2, m1, c], 1), np.stack([m0, m1, m2], 1)]
    return np.concatenate(out, axis=0)


def split_long_edges(mesh: TexturedMesh, max_edge_mm: float) -> TexturedMesh:
    """Split every edge longer than ``max_edge_mm`` at its midpoint (conforming, UV-exact).

    Args:
        mesh: a triangle mesh, optionally with UVs (``UV``, ``F_uv``); positions in mm.
        max_edge_mm: edges strictly longer than this are split once.
    Returns:
        The refined mesh: the original vertices keep their indices and come
        first; new vertices follow. The texture image is shared.
    """
    return _split_long_edges(mesh, max_edge_mm, None)[0]


def _split_long_edges(mesh: TexturedMesh, max_edge_mm: float,
                      rows: np.ndarray | None) -> tuple[TexturedMesh, np.ndarray | None]:
    """:func:`split_long_edges`, and per-vertex ``rows`` (n, k) extended by the same midpoints (or None)."""
    edges, _ = unique_edges(mesh.F)
    length = np.linalg.norm(mesh.V[edges[:, 0]] - mesh.V[edges[:, 1]], axis=1)
    return split_edges(mesh, length > max_edge_mm, rows)


def split_edges(mesh: TexturedMesh, split: np.ndarray,
                rows: np.ndarray | None = None) -> tuple[TexturedMesh, np.ndarray | None]:
    """Split the chosen edges at their midpoints (conforming, UV-exact), carrying per-vertex ``rows``.

    Args:
        mesh: a triangle mesh, optionally with UVs; positions in mm.
        split: (e,) bool per edge of ``unique_edges(mesh.F)``, in its order.
        rows: (n, k) float per-vertex values, or None; new vertices get their edge's mean.
    Returns:
        The refined mesh (original vertices first, in order; the texture image shared) and the rows.
    """
    V, F = mesh.V, mesh.F
    edges, face_edge = unique_edges(F)
    split = np.asarray(split, dtype=bool)
    if split.shape != (len(edges),):
        raise ValueError(f"split must have one entry per edge ({len(edges)}), got shape {split.shape}")
    if not split.any():
        return mesh, rows
    mid_v = np.full(len(edges), -1, dtype=np.int64)
    mid_v[split] = len(V) + np.arange(int(split.sum()))
    V_new = np.concatenate([V, 0.5 * (V[edges[split, 0]] + V[edges[split, 1]])])
    if rows is not None:
        rows = np.concatenate([rows, 0.5 * (rows[edges[split, 0]] + rows[edges[split, 1]])])
    F_new = _split_faces(F, face_edge, split, mid_v)
    UV_new = F_uv_new = None
    if mesh.has_uv:
        # UV edges: the same geometric edge may be two UV edges across a seam; each gets its own
        # midpoint, and a UV edge is split exactly when its geometric edge is (buffers stay face-aligned)
        uv_edges, uv_face_edge = unique_edges(mesh.F_uv)
        uv_split = np.zeros(len(uv_edges), dtype=bool)
        uv_split[uv_face_edge[split[face_edge]]] = True
        mid_uv = np.full(len(uv_edges), -1, dtype=np.int64)
        mid_uv[uv_split] = len(mesh.UV) + np.arange(int(uv_split.sum()))
        UV_new = np.concatenate([mesh.UV, 0.5 * (mesh.UV[uv_edges[uv_split, 0]] + mesh.UV[uv_edges[uv_split, 1]])])
        F_uv_new = _split_faces(mesh.F_uv, uv_face_edge, uv_split, mid_uv)
    return TexturedMesh(V_new, F_new, UV_new, F_uv_new, mesh.texture), rows


def refine_by_factor(mesh: TexturedMesh, factor: float = 2.5) -> TexturedMesh:
    """Split the longest edges so the vertex count grows by about ``factor`` (1 < factor <= 4).

    New vertices = number of split edges, so the threshold is the edge-length
    quantile that splits ``(factor - 1) * n_vertices`` edges.
    """
    return refine_carrying(mesh, factor, None)[0]


def refine_carrying(mesh: TexturedMesh, factor: float,
                    rows: np.ndarray | None) -> tuple[TexturedMesh, np.ndarray | None]:
    """:func:`refine_by_factor`, and per-vertex ``rows`` (n, k) float carried along: each new vertex
    gets the mean of its edge's two rows, as its position is (None passes through)."""
    if not 1.0 < factor <= 4.0:
        raise ValueError(f"refinement factor must be in (1, 4], got {factor}")
    if rows is not None and len(rows) != len(mesh.V):
        raise ValueError(f"rows ({len(rows)}) must have one entry per vertex ({len(mesh.V)})")
    edges, _ = unique_edges(mesh.F)
    length = np.sort(np.linalg.norm(mesh.V[edges[:, 0]] - mesh.V[edges[:, 1]], axis=1))
    n_split = int(round((factor - 1.0) * len(mesh.V)))
    if n_split >= len(length):
        return _split_long_edges(mesh, 0.0, rows)
    threshold = length[len(length) - n_split - 1]
    return _split_long_edges(mesh, threshold, rows)
