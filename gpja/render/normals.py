"""Area-weighted vertex normals as one numba op, with an analytic backward.

torch's version (gather corners, cross, ``index_add_``, normalise) builds
several (m, 3, 3) intermediates and zero-fills them again in its backward:
forward + backward at 250K faces, 97 ms against 9.9 ms here
(``benchmarks/bench_render.py --ops``). Sums run per vertex over its incident faces in
face order, so the result does not depend on the thread count. Other devices
(the nvdiffrast backend) use the torch expression.
"""
from __future__ import annotations

import numba as nb
import numpy as np
import torch


def vertex_incidence(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Which face corners each vertex is, as CSR.

    Args:
        faces: (m, 3) int vertex indices.
        n_vertices: n.
    Returns:
        starts: (n + 1,) int64 offsets; corners: (3m,) int64 ``3 * face + corner``,
        those of vertex v at ``corners[starts[v]:starts[v + 1]]`` in increasing face order.
    """
    flat = np.asarray(faces, dtype=np.int64).ravel()
    corners = np.argsort(flat, kind="stable").astype(np.int64)
    starts = np.zeros(n_vertices + 1, dtype=np.int64)
    np.cumsum(np.bincount(flat, minlength=n_vertices), out=starts[1:])
    return starts, corners


@nb.njit(cache=True, parallel=True)
def _face_normals(V, faces, out):
    for f in nb.prange(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        ax, ay, az = np.float64(V[i1, 0]) - V[i0, 0], np.float64(V[i1, 1]) - V[i0, 1], np.float64(V[i1, 2]) - V[i0, 2]
        bx, by, bz = np.float64(V[i2, 0]) - V[i0, 0], np.float64(V[i2, 1]) - V[i0, 1], np.float64(V[i2, 2]) - V[i0, 2]
        out[f, 0] = ay * bz - az * by
        out[f, 1] = az * bx - ax * bz
        out[f, 2] = ax * by - ay * bx


@nb.njit(cache=True, parallel=True)
def _vertex_normals_forward(face_n, starts, corners, normals, inv_norm):
    for v in nb.prange(normals.shape[0]):
        sx = sy = sz = 0.0
        for e in range(starts[v], starts[v + 1]):
            f = corners[e] // 3
            sx += face_n[f, 0]
            sy += face_n[f, 1]
            sz += face_n[f, 2]
        r = 1.0 / np.sqrt(max(sx * sx + sy * sy + sz * sz, 1e-24))  # zero rows stay zero
        inv_norm[v] = r
        normals[v, 0] = sx * r
        normals[v, 1] = sy * r
        normals[v, 2] = sz * r


@nb.njit(cache=True, parallel=True)
def _vertex_normals_backward(V, faces, starts, corners, normals, inv_norm, grad_normals, g_face, grad_V):
    # through the normalisation: d(a / |a|) = (I - n n^T) / |a|
    n_vertices = V.shape[0]
    g_acc = np.empty((n_vertices, 3))
    for v in nb.prange(n_vertices):
        nx, ny, nz = np.float64(normals[v, 0]), np.float64(normals[v, 1]), np.float64(normals[v, 2])
        gx, gy, gz = np.float64(grad_normals[v, 0]), np.float64(grad_normals[v, 1]), np.float64(grad_normals[v, 2])
        d = nx * gx + ny * gy + nz * gz
        g_acc[v, 0] = (gx - nx * d) * inv_norm[v]
        g_acc[v, 1] = (gy - ny * d) * inv_norm[v]
        g_acc[v, 2] = (gz - nz * d) * inv_norm[v]
    # every face normal feeds its three corners' sums; N = a x b with a = V1 - V0, b = V2 - V0:
    # dN.g = da.(b x g) + db.(g x a), so V1 gets b x g, V2 gets g x a and V0 minus both (once per face, not
    # once per corner: the per-vertex sums below read them in the same order, the result is the same to the bit)
    for f in nb.prange(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        gx = g_acc[i0, 0] + g_acc[i1, 0] + g_acc[i2, 0]
        gy = g_acc[i0, 1] + g_acc[i1, 1] + g_acc[i2, 1]
        gz = g_acc[i0, 2] + g_acc[i1, 2] + g_acc[i2, 2]
        ax, ay, az = np.float64(V[i1, 0]) - V[i0, 0], np.float64(V[i1, 1]) - V[i0, 1], np.float64(V[i1, 2]) - V[i0, 2]
        bx, by, bz = np.float64(V[i2, 0]) - V[i0, 0], np.float64(V[i2, 1]) - V[i0, 1], np.float64(V[i2, 2]) - V[i0, 2]
        g_face[f, 0], g_face[f, 1], g_face[f, 2] = by * gz - bz * gy, bz * gx - bx * gz, bx * gy - by * gx
        g_face[f, 3], g_face[f, 4], g_face[f, 5] = gy * az - gz * ay, gz * ax - gx * az, gx * ay - gy * ax
    for v in nb.prange(n_vertices):
        sx = sy = sz = 0.0
        for e in range(starts[v], starts[v + 1]):
            f, k = corners[e] // 3, corners[e] % 3
            if k == 0:
                sx -= g_face[f, 0] + g_face[f, 3]
                sy -= g_face[f, 1] + g_face[f, 4]
                sz -= g_face[f, 2] + g_face[f, 5]
            elif k == 1:
                sx += g_face[f, 0]
                sy += g_face[f, 1]
                sz += g_face[f, 2]
            else:
                sx += g_face[f, 3]
                sy += g_face[f, 4]
                sz += g_face[f, 5]
        grad_V[v, 0] = sx
        grad_V[v, 1] = sy
        grad_V[v, 2] = sz


class _VertexNormals(torch.autograd.Function):
    @staticmethod
    def forward(ctx, V, faces, starts, corners):
        vertices = V.detach().contiguous()
        Vn = vertices.numpy()
        face_n = np.empty((faces.shape[0], 3))
        _face_normals(Vn, faces, face_n)
        normals = np.empty(Vn.shape, dtype=Vn.dtype)
        inv_norm = np.empty(len(Vn))
        _vertex_normals_forward(face_n, starts, corners, normals, inv_norm)
        out = torch.from_numpy(normals)
        ctx.save_for_backward(vertices, out)
        ctx.topology = (faces, starts, corners, inv_norm)
        return out

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_normals):
        vertices, normals = ctx.saved_tensors
        faces, starts, corners, inv_norm = ctx.topology
        grad_V = np.empty(vertices.shape, dtype=vertices.numpy().dtype)
        _vertex_normals_backward(vertices.numpy(), faces, starts, corners, normals.numpy(), inv_norm,
                                 np.ascontiguousarray(grad_normals.numpy()), np.empty((faces.shape[0], 6)), grad_V)
        return torch.from_numpy(grad_V), None, None, None


def normalize_rows(x: torch.Tensor) -> torch.Tensor:
    """Rows of ``x`` (k, 3) scaled to unit length (zero rows stay zero).

    rsqrt of the squared norm: cheaper than ``torch.linalg.vector_norm`` on CPU,
    forward and backward.
    """
    return x * torch.rsqrt((x * x).sum(dim=1, keepdim=True).clamp_min(1e-24))


def tangential_part(v: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """Each row of ``v`` (n, 3) projected onto the plane orthogonal to the same row of ``normals`` (n, 3),
    unit: ``v - (v . n) n``. Same dtype and device as ``v``."""
    return v - (v * normals).sum(1, keepdim=True) * normals


def vertex_normals_torch(V: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """:func:`vertex_normals` as plain torch operations (any device)."""
    # index_select, not V[faces]: the backward of advanced indexing (index_put_ with accumulate) is
    # not deterministic on the CPU, and registration must give the same numbers on every run
    tri = V.index_select(0, faces.reshape(-1)).reshape(-1, 3, 3)
    face_n = torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=1)
    acc = torch.zeros_like(V).index_add_(0, faces.reshape(-1), face_n.repeat_interleave(3, dim=0))
    return normalize_rows(acc)


def vertex_normals(V: torch.Tensor, faces: torch.Tensor,
                   incidence: tuple[np.ndarray, np.ndarray] | None = None) -> torch.Tensor:
    """Area-weighted unit vertex normals.

    Args:
        V: (n, 3) float32/float64 positions, mm.
        faces: (m, 3) int64, counter-clockwise seen from outside.
        incidence: ``vertex_incidence(faces, n)`` when the caller keeps it
            (``Topology`` does); computed here otherwise.
    Returns:
        (n, 3) unit normals (world frame), dtype and device of ``V``,
        differentiable in ``V`` (first order). Sums in float64. A vertex in no
        face (or whose faces cancel) gets a zero normal.
    """
    if V.device.type != "cpu":
        return vertex_normals_torch(V, faces)
    F = np.ascontiguousarray(faces.detach().cpu().numpy(), dtype=np.int64)
    if incidence is None or len(incidence[0]) != len(V) + 1:
        incidence = vertex_incidence(F, len(V))
    starts, corners = incidence
    return _VertexNormals.apply(V, F, starts, corners)
