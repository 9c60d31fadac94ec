"""Synthetic multiview-stereo scans: an independent triangulation of the surface.

The scan of an expression is the marching-cubes mesh of the rest SDF (its own
grid, never the render mesh) mapped forward by ``phi_e``, keeping only the
triangles that at least two capture cameras see (unoccluded, facing the camera
enough, inside the image) and that lie above a cut below the neck, like a real
multiview-stereo reconstruction with holes at the back and top of the skull.
"""
from __future__ import annotations

import math

import numpy as np

from gpja.camera import Camera
from gpja.data.synthetic.capture import build_scene, cast

#: A triangle counts as seen by a camera if its normal is within this angle of the view ray.
MAX_VIEW_ANGLE_DEG = 65.0
#: Minimum number of cameras that must see a triangle.
MIN_VIEWS = 2
#: Rest-space y (mm) below which the neck is cut off.
NECK_CUT_Y_MM = -165.0
#: Occlusion tolerance along the ray (mm).
OCCLUSION_TOL_MM = 0.05


def visible_face_counts(V: np.ndarray, F: np.ndarray, cameras: list[Camera], scene=None) -> np.ndarray:
    """Number of cameras that see each triangle.

    Args:
        V: (n, 3) float64 expression-space vertices, mm; F: (m, 3) faces.
        cameras: the capture rig.
        scene: optional prebuilt RaycastingScene of (V, F).
    Returns:
        (m,) int count of cameras.
    """
    if scene is None:
        scene = build_scene(V, F)
    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    cen = (A + B + C) / 3.0
    fn = np.cross(B - A, C - A)
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-12)
    count = np.zeros(len(F), np.int32)
    cos_max = math.cos(math.radians(MAX_VIEW_ANGLE_DEG))
    for cam in cameras:
        ray = cen - cam.center
        dist = np.linalg.norm(ray, axis=1)
        ray /= dist[:, None]
        front = -(fn * ray).sum(1) > cos_max
        uv, z = cam.project(cen)
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] <= cam.width - 1) & (uv[:, 1] <= cam.height - 1)
        idx = np.flatnonzero(front & inside)
        if len(idx) == 0:
            continue
        rays = np.concatenate([np.broadcast_to(cam.center, (len(idx), 3)), ray[idx]], 1).astype(np.float32)
        t, pid, _ = cast(scene, rays)
        ok = (pid == idx) | (t >= dist[idx] - OCCLUSION_TOL_MM)
        count[idx[ok]] += 1
    return count


def cut_scan(V_rest: np.ndarray, V_expr: np.ndarray, F: np.ndarray, cameras: list[Camera]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Keep the part of a mapped marching-cubes mesh that the rig sees.

    Args:
        V_rest: (n, 3) rest positions (the ground-truth material points), mm.
        V_expr: (n, 3) the same vertices mapped by phi_e, mm.
        F: (m, 3) faces.
    Returns:
        V: (n', 3) scan vertices (expression space), F': (m', 3) faces,
        rest: (n', 3) their rest positions.
    """
    seen = visible_face_counts(V_expr, F, cameras) >= MIN_VIEWS
    seen &= V_rest[F].max(axis=1)[:, 1] > NECK_CUT_Y_MM
    Fk = F[seen]
    used = np.zeros(len(V_rest), bool)
    used[Fk.ravel()] = True
    remap = np.cumsum(used) - 1
    return V_expr[used], remap[Fk], V_rest[used]


def edge_lengths(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(3m,) lengths of the triangle edges (each interior edge counted twice), mm."""
    return np.concatenate([np.linalg.norm(V[F[:, i]] - V[F[:, (i + 1) % 3]], axis=1) for i in range(3)])
