"""Visibility for a batch of views: one numba kernel rasterises every view in one call.

Vertices are snapped to a fixed-point grid (``SUBPIXEL_BITS`` fractional bits)
and coverage is decided with exact integer edge functions plus the top-left
fill rule, so pixels on an edge shared by two triangles belong to exactly one
of them: no pinholes, no double coverage. Depth order uses perspective-correct
camera depth; of two faces at exactly the same depth the lower face index wins,
so the output does not depend on the order the faces are visited in, and a caller
may pass an order that keeps consecutive faces near each other on the screen
(``Topology.visit_order``): the depth buffer then stays in cache. The kernel runs
in parallel over views.

Written with numba rather than taken from Open3D's ray caster because
rebuilding a ``RaycastingScene`` for a deforming mesh every iteration is the
bottleneck of the straightforward approach (see benchmarks/bench_render.py).
"""
from __future__ import annotations

import numba as nb
import numpy as np

#: Fractional bits of the fixed-point screen coordinates (1/256 pixel).
SUBPIXEL_BITS = 8
#: Triangles with a vertex closer than this to the camera plane (mm) are skipped
#: (no near-plane clipping: the rig never gets this close to a head).
NEAR_MM = 1.0
BACKGROUND = -1


@nb.njit(cache=True, inline="always")
def _is_top_left(ax, ay, bx, by):
    # Top-left fill rule for the positive winding used below (y-down pixels):
    # a top edge is horizontal and runs right to left (ay == by, bx < ax);
    # a left edge runs downwards (by > ay). Pixels exactly on such edges belong
    # to the triangle, on all others to its neighbour.
    return (ay == by and bx < ax) or (by > ay)


@nb.njit(cache=True, parallel=True)
def _rasterize_kernel(screen, faces, face_ids, height, width, cull_sign, tri_id, depth, facing):
    # faces[k] is face face_ids[k]: any order of the faces gives the same output (ties go to the lower index)
    # screen may be float32 or float64: every read is widened to float64, so the
    # result does not depend on the storage dtype (and no float64 copy is made)
    n_views, n_vertices = screen.shape[0], screen.shape[1]
    scale = float(1 << SUBPIXEL_BITS)
    # snap every vertex once per view (each is shared by ~6 triangles); coordinates
    # far outside the image are clamped so the fixed-point products cannot overflow
    fixed = np.empty((n_views, n_vertices, 2), dtype=np.int64)
    limit = float(4 * max(height, width) + 64)
    for b in nb.prange(n_views):
        for i in range(n_vertices):
            fixed[b, i, 0] = np.int64(np.round(min(max(np.float64(screen[b, i, 0]), -limit), limit) * scale))
            fixed[b, i, 1] = np.int64(np.round(min(max(np.float64(screen[b, i, 1]), -limit), limit) * scale))
    for b in nb.prange(n_views):
        for k in range(faces.shape[0]):
            f = face_ids[k]
            i0, i1, i2 = faces[k, 0], faces[k, 1], faces[k, 2]
            # orientation in float (the antialiasing pass's silhouette test), computed here
            # because this loop already has the face's vertices at hand
            fx0, fy0 = np.float64(screen[b, i0, 0]), np.float64(screen[b, i0, 1])
            fx1, fy1 = np.float64(screen[b, i1, 0]), np.float64(screen[b, i1, 1])
            fx2, fy2 = np.float64(screen[b, i2, 0]), np.float64(screen[b, i2, 1])
            facing[b, f] = (fx1 - fx0) * (fy2 - fy0) - (fy1 - fy0) * (fx2 - fx0) < 0.0
            z0, z1, z2 = np.float64(screen[b, i0, 2]), np.float64(screen[b, i1, 2]), np.float64(screen[b, i2, 2])
            if z0 < NEAR_MM or z1 < NEAR_MM or z2 < NEAR_MM:
                continue
            x0, y0 = fixed[b, i0, 0], fixed[b, i0, 1]
            x1, y1 = fixed[b, i1, 0], fixed[b, i1, 1]
            x2, y2 = fixed[b, i2, 0], fixed[b, i2, 1]
            area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
            if area == 0:
                continue
            if cull_sign != 0 and (area > 0) != (cull_sign > 0):
                continue
            if area < 0:  # make the winding positive so one inside test serves both
                x1, x2 = x2, x1
                y1, y2 = y2, y1
                z1, z2 = z2, z1
                i1, i2 = i2, i1
                area = -area
            # pixel-centre bounding box (pixel centres at integer coordinates)
            xmin = max(0, (min(x0, x1, x2) + (1 << SUBPIXEL_BITS) - 1) >> SUBPIXEL_BITS)
            xmax = min(width - 1, max(x0, x1, x2) >> SUBPIXEL_BITS)
            ymin = max(0, (min(y0, y1, y2) + (1 << SUBPIXEL_BITS) - 1) >> SUBPIXEL_BITS)
            ymax = min(height - 1, max(y0, y1, y2) >> SUBPIXEL_BITS)
            if xmin > xmax or ymin > ymax:
                continue
            # fill-rule bias: pixels exactly on a non-top-left edge are excluded
            bias0 = 0 if _is_top_left(x1, y1, x2, y2) else -1
            bias1 = 0 if _is_top_left(x2, y2, x0, y0) else -1
            bias2 = 0 if _is_top_left(x0, y0, x1, y1) else -1
            inv_area = 1.0 / float(area)
            iz0, iz1, iz2 = 1.0 / z0, 1.0 / z1, 1.0 / z2
            # the edge functions step exactly (integers) along a row; a row's covered pixels are one run
            # (the triangle is convex), so the row ends where the run does
            step = np.int64(1) << SUBPIXEL_BITS
            d0, d1, d2 = (y2 - y1) * step, (y0 - y2) * step, (y1 - y0) * step
            for py in range(ymin, ymax + 1):
                sy = np.int64(py) << SUBPIXEL_BITS
                sx = np.int64(xmin) << SUBPIXEL_BITS
                w0 = (x2 - x1) * (sy - y1) - (y2 - y1) * (sx - x1)
                w1 = (x0 - x2) * (sy - y2) - (y0 - y2) * (sx - x2)
                w2 = (x1 - x0) * (sy - y0) - (y1 - y0) * (sx - x0)
                entered = False
                for px in range(xmin, xmax + 1):
                    if ((w0 + bias0) | (w1 + bias1) | (w2 + bias2)) < 0:  # some edge function below its bias
                        if entered:
                            break
                    else:
                        entered = True
                        inv_z = (w0 * iz0 + w1 * iz1 + w2 * iz2) * inv_area
                        z = np.float32(1.0 / inv_z)  # stored and compared as float32: half the memory traffic
                        held = depth[b, py, px]
                        if z < held or (z == held and f < tri_id[b, py, px]):
                            depth[b, py, px] = z
                            tri_id[b, py, px] = f
                    w0 -= d0
                    w1 -= d1
                    w2 -= d2


def rasterize_with_facing(screen: np.ndarray, faces: np.ndarray, height: int, width: int,
                          cull_backfaces: bool = False, visit: tuple[np.ndarray, np.ndarray] | None = None
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`rasterize`, plus which faces look towards each camera.

    ``visit``: ``(ids (m,) int64, faces[ids] (m, 3) int64)``, the order to visit the faces in (a
    permutation; ``Topology.visit_order``), or None for their own order. The output is the same.

    Returns:
        tri_id: (B, H, W) int32, ``BACKGROUND`` where empty.
        depth: (B, H, W) float32 camera depth in mm, ``inf`` where empty.
        facing: (B, m) bool, face f is front-facing in view b (negative signed
            area in y-down pixels, from the float coordinates).
    """
    if height <= 0 or width <= 0:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if screen.dtype not in (np.float32, np.float64):
        screen = screen.astype(np.float64)
    screen = np.ascontiguousarray(screen)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    n_views = screen.shape[0]
    tri_id = np.full((n_views, height, width), BACKGROUND, dtype=np.int32)
    depth = np.full((n_views, height, width), np.inf, dtype=np.float32)
    facing = np.empty((n_views, len(faces)), dtype=np.bool_)
    # In y-down pixel coordinates a counter-clockwise (outward-facing) triangle
    # seen from the front has negative signed area.
    if visit is None:
        ids, ordered = np.arange(len(faces), dtype=np.int64), faces
    else:
        ids, ordered = (np.ascontiguousarray(a, dtype=np.int64) for a in visit)
        if ids.shape != (len(faces),) or ordered.shape != faces.shape:
            raise ValueError(f"visit order for {len(ids)} faces, given {len(faces)}")
    _rasterize_kernel(screen, ordered, ids, height, width, -1 if cull_backfaces else 0, tri_id, depth, facing)
    return tri_id, depth, facing


def rasterize(screen: np.ndarray, faces: np.ndarray, height: int, width: int, cull_backfaces: bool = False
              ) -> tuple[np.ndarray, np.ndarray]:
    """Triangle id and depth of the nearest surface at every pixel of every view.

    Args:
        screen: (B, n, 3) float32/float64 projected vertices: pixel x, pixel y
            (pixel centres at integers, y down) and camera depth z in mm.
        faces: (m, 3) int vertex indices; counter-clockwise seen from outside.
        height, width: image size in pixels (> 0).
        cull_backfaces: drop triangles facing away from the camera.
    Returns:
        tri_id: (B, H, W) int32 face index, ``BACKGROUND`` (-1) where empty.
        depth: (B, H, W) float32 camera depth in mm, ``inf`` where empty.
    """
    tri_id, depth, _ = rasterize_with_facing(screen, faces, height, width, cull_backfaces)
    return tri_id, depth
