"""Covered pixels and their differentiable perspective-correct barycentrics.

The rasteriser decides *which* triangle covers a pixel (integer output, no
gradient); this module recomputes *where* inside that triangle the pixel lies
from the projected vertex positions in torch, so gradients of anything
interpolated reach the vertices.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
import torch

from gpja.render.rasterize import BACKGROUND, rasterize_with_facing


@dataclass
class Fragments:
    """The visible surface sample of every covered pixel in a batch of views.

    Attributes:
        tri_id: (B, H, W) int32 numpy face index per pixel, -1 where empty.
        depth: (B, H, W) float32 numpy camera depth (mm), inf where empty; no gradient.
        pixel: (P,) int64 flat index ``(b * H + y) * W + x`` of each covered pixel.
        face: (P,) int64 face index of each covered pixel.
        bary: (P, 3) perspective-correct barycentrics, differentiable.
        z: (P,) camera depth in mm, differentiable.
        corners: (P, 3) int64 vertex indices of each pixel's triangle (``faces[face]``).
        facing: (B, m) bool numpy, face f looks towards camera b (for silhouettes).
    """

    tri_id: np.ndarray
    depth: np.ndarray
    pixel: torch.Tensor
    face: torch.Tensor
    bary: torch.Tensor
    z: torch.Tensor
    corners: torch.Tensor
    facing: np.ndarray

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.tri_id.shape)  # type: ignore[return-value]


def rasterize_fragments(screen: torch.Tensor, faces: torch.Tensor, height: int, width: int,
                        cull_backfaces: bool = False, visit: tuple[np.ndarray, np.ndarray] | None = None) -> Fragments:
    """Rasterise all views, then compute differentiable barycentrics of covered pixels.

    Args:
        screen: (B, n, 3) projected vertices from ``project_to_screen`` (pixel x, y; depth mm).
        faces: (m, 3) int64 vertex indices.
        height, width: image size in pixels.
        cull_backfaces: drop triangles facing away from each camera.
        visit: the order the rasteriser visits the faces in (``rasterize_with_facing``; the same output).
    """
    n_views, n_vertices, _ = screen.shape
    screen_np = screen.detach().numpy()  # CPU only: the barycentric op below is a numba kernel
    fcs = np.ascontiguousarray(faces.detach().numpy(), dtype=np.int64)
    tri_id, depth, facing = rasterize_with_facing(screen_np, fcs, height, width, cull_backfaces, visit)
    counts = np.empty(n_views, dtype=np.int64)
    _count_covered(tri_id, counts)
    view_starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    n = int(view_starts[-1])
    pixel = np.empty(n, dtype=np.int64)
    face = np.empty(n, dtype=np.int64)
    vertex_corners = np.empty((n, 3), dtype=np.int64)
    corners = np.empty((n, 3), dtype=np.int64)
    px = np.empty(n, dtype=screen_np.dtype)
    py = np.empty_like(px)
    _list_covered(tri_id, fcs, n_vertices, view_starts, pixel, face, vertex_corners, corners, px, py)
    bary, z = perspective_barycentrics(screen.reshape(-1, 3), torch.from_numpy(corners), torch.from_numpy(px),
                                       torch.from_numpy(py), torch.from_numpy(view_starts))
    return Fragments(tri_id, depth, torch.from_numpy(pixel), torch.from_numpy(face), bary, z,
                     torch.from_numpy(vertex_corners), facing)


@nb.njit(cache=True, parallel=True)
def _count_covered(tri_id, counts):
    """Covered pixels per view."""
    for b in nb.prange(tri_id.shape[0]):
        n = 0
        for y in range(tri_id.shape[1]):
            for x in range(tri_id.shape[2]):
                if tri_id[b, y, x] != BACKGROUND:
                    n += 1
        counts[b] = n


@nb.njit(cache=True, parallel=True)
def _list_covered(tri_id, faces, n_vertices, view_starts, pixel, face, vertex_corners, corners, px, py):
    """The covered pixels in flat-index order: index, face, its corners and the pixel centre."""
    n_views, height, width = tri_id.shape
    for b in nb.prange(n_views):
        k = view_starts[b]
        for y in range(height):
            for x in range(width):
                f = tri_id[b, y, x]
                if f == BACKGROUND:
                    continue
                pixel[k] = (b * height + y) * width + x
                face[k] = f
                for c in range(3):
                    vertex_corners[k, c] = faces[f, c]
                    # rows of screen.reshape(-1, 3)
                    corners[k, c] = faces[f, c] + b * n_vertices
                px[k] = x
                py[k] = y
                k += 1


@nb.njit(cache=True, parallel=True)
def _bary_forward(screen, corners, px, py, bary, z):
    for p in nb.prange(corners.shape[0]):
        r0, r1, r2 = corners[p, 0], corners[p, 1], corners[p, 2]
        dx0, dy0 = screen[r0, 0] - px[p], screen[r0, 1] - py[p]
        dx1, dy1 = screen[r1, 0] - px[p], screen[r1, 1] - py[p]
        dx2, dy2 = screen[r2, 0] - px[p], screen[r2, 1] - py[p]
        e0 = dx1 * dy2 - dy1 * dx2
        e1 = dx2 * dy0 - dy2 * dx0
        e2 = dx0 * dy1 - dy0 * dx1
        q0, q1, q2 = e0 / screen[r0, 2], e1 / screen[r1, 2], e2 / screen[r2, 2]
        qs = q0 + q1 + q2
        bary[p, 0] = q0 / qs
        bary[p, 1] = q1 / qs
        bary[p, 2] = q2 / qs
        z[p] = (e0 + e1 + e2) / qs


@nb.njit(cache=True, parallel=True)
def _bary_backward(screen, corners, px, py, bary, z, g_bary, g_z, g_screen, chunk_starts):
    # Fragments are sorted by view and each view owns its own screen rows, so
    # chunks of whole views scatter into disjoint rows: no write races.
    for chunk in nb.prange(len(chunk_starts) - 1):
      for p in range(chunk_starts[chunk], chunk_starts[chunk + 1]):
          r = (corners[p, 0], corners[p, 1], corners[p, 2])
          dx0, dy0 = screen[r[0], 0] - px[p], screen[r[0], 1] - py[p]
          dx1, dy1 = screen[r[1], 0] - px[p], screen[r[1], 1] - py[p]
          dx2, dy2 = screen[r[2], 0] - px[p], screen[r[2], 1] - py[p]
          e = (dx1 * dy2 - dy1 * dx2, dx2 * dy0 - dy2 * dx0, dx0 * dy1 - dy0 * dx1)
          zc = (screen[r[0], 2], screen[r[1], 2], screen[r[2], 2])
          qs = e[0] / zc[0] + e[1] / zc[1] + e[2] / zc[2]
          gb_dot_b = g_bary[p, 0] * bary[p, 0] + g_bary[p, 1] * bary[p, 1] + g_bary[p, 2] * bary[p, 2]
          g_area = g_z[p] / qs
          ge = np.empty(3)
          for i in range(3):
              g_q = (g_bary[p, i] - gb_dot_b) / qs - g_z[p] * z[p] / qs
              ge[i] = g_q / zc[i] + g_area
              g_screen[r[i], 2] -= g_q * e[i] / (zc[i] * zc[i])
          g_screen[r[0], 0] += -ge[1] * dy2 + ge[2] * dy1
          g_screen[r[0], 1] += ge[1] * dx2 - ge[2] * dx1
          g_screen[r[1], 0] += ge[0] * dy2 - ge[2] * dy0
          g_screen[r[1], 1] += -ge[0] * dx2 + ge[2] * dx0
          g_screen[r[2], 0] += -ge[0] * dy1 + ge[1] * dy0
          g_screen[r[2], 1] += ge[0] * dx1 - ge[1] * dx0


class _PerspectiveBarycentrics(torch.autograd.Function):
    """Fused perspective-correct barycentrics with an analytic backward (numba)."""

    @staticmethod
    def forward(ctx, screen_rows, corners, px, py, chunk_starts):
        scr = screen_rows.detach().numpy()
        n = corners.shape[0]
        bary = np.empty((n, 3), dtype=scr.dtype)
        z = np.empty(n, dtype=scr.dtype)
        _bary_forward(scr, corners.numpy(), px.numpy(), py.numpy(), bary, z)
        bary_t, z_t = torch.from_numpy(bary), torch.from_numpy(z)
        ctx.save_for_backward(screen_rows, corners, px, py, bary_t, z_t, chunk_starts)
        return bary_t, z_t

    @staticmethod
    def backward(ctx, g_bary, g_z):
        screen_rows, corners, px, py, bary, z, chunk_starts = ctx.saved_tensors
        g_screen = np.zeros(screen_rows.shape, dtype=bary.numpy().dtype)
        _bary_backward(screen_rows.detach().numpy(), corners.numpy(), px.numpy(), py.numpy(), bary.numpy(), z.numpy(),
                       np.ascontiguousarray(g_bary.numpy()), np.ascontiguousarray(g_z.numpy()), g_screen, chunk_starts.numpy())
        return torch.from_numpy(g_screen), None, None, None, None


def perspective_barycentrics(screen_rows: torch.Tensor, corners: torch.Tensor, px: torch.Tensor, py: torch.Tensor,
                             chunk_starts: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Perspective-correct barycentrics of pixel centres in projected triangles.

    Args:
        screen_rows: (N, 3) projected vertices (pixel x, pixel y, depth z in mm)
            of all views stacked, i.e. ``screen.reshape(-1, 3)``; CPU tensor.
        corners: (P, 3) int64 rows of ``screen_rows`` of each fragment's triangle.
        px, py: (P,) pixel-centre coordinates, same dtype as ``screen_rows``.
        chunk_starts: (K+1,) int64 fragment offsets of groups whose corner rows
            are disjoint (e.g. one group per view); None = one group.
    Returns:
        bary: (P, 3) weights of the three corners (sum to 1) for attributes
            interpolated on the 3D surface, differentiable in ``screen_rows``.
        z: (P,) camera depth of the surface point, mm, differentiable.
    """
    if chunk_starts is None:
        chunk_starts = torch.tensor([0, len(corners)], dtype=torch.int64)
    return _PerspectiveBarycentrics.apply(screen_rows.contiguous(), corners.contiguous(), px.contiguous(),
                                          py.contiguous(), chunk_starts)
