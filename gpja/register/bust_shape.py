"""The implicit bust surface that :mod:`gpja.register.bust` samples into a mesh.

A smooth union of ellipsoids (cranium, jaw, chin, cheek bones, brow, nose,
lips) and a vertical neck cylinder cut flat at the bottom, in the canonical
head frame (face +Z, top +Y, X to the subject's left, mm). The surface is
star-shaped from a centre ``c0`` on the neck axis, so it is sampled by rays
from there (:func:`cast_rays`); :func:`relax_on_surface` then evens out a
sampled grid while keeping it on the surface.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class BustShape:
    """Proportions of the bust, mm, canonical head frame (origin near the head centre)."""

    cranium_center: tuple = (0.0, 20.0, -5.0)
    cranium_axes: tuple = (74.0, 92.0, 99.0)
    neck_radius: float = 52.0
    neck_axis_z: float = -10.0
    neck_cut_y: float = -210.0
    mouth_y: float = -58.0
    mouth_half_width: float = 24.0
    centre_y: float = -60.0  # y of the ray centre c0 (on the neck axis)

    def primitives(self) -> list[tuple[float, tuple, tuple]]:
        """(blend radius k, centre, semi-axes) of the ellipsoids, smooth-unioned in order."""
        my = self.mouth_y
        w = self.mouth_half_width
        prims = [
            (0.0, self.cranium_center, self.cranium_axes),
            (22.0, (0.0, -41.0, 18.0), (57.0, 59.0, 72.0)),          # jaw / lower face
            (12.0, (0.0, -93.0, 70.0), (20.0, 16.0, 17.0)),          # chin
            (12.0, (-42.0, -19.0, 62.0), (20.0, 15.0, 20.0)),        # cheek bones
            (12.0, (42.0, -19.0, 62.0), (20.0, 15.0, 20.0)),
            (10.0, (0.0, 31.0, 82.0), (58.0, 10.0, 13.0)),           # brow ridge
            (6.0, (0.0, 2.0, 95.0), (7.0, 22.0, 9.0)),               # nose bridge
            (4.0, (0.0, -15.0, 107.0), (9.0, 8.0, 9.0)),             # nose tip
            (6.0, (0.0, -11.0, 90.0), (13.0, 12.0, 11.0)),           # nose base
            (4.0, (-12.0, -19.0, 98.0), (7.0, 6.5, 7.0)),            # alae
            (4.0, (12.0, -19.0, 98.0), (7.0, 6.5, 7.0)),
            (3.0, (0.0, my + 6.0, 90.0), (w + 1.0, 6.0, 8.0)),       # upper lip
            (3.0, (0.0, my - 7.0, 88.5), (w - 2.0, 6.5, 8.5)),       # lower lip
        ]
        return prims

    def ray_centre(self) -> np.ndarray:
        """(3,) float64 centre ``c0`` the surface is star-shaped from, mm."""
        return np.array([0.0, self.centre_y, self.neck_axis_z])


def _ellipsoid_sdf(P: np.ndarray, c, a) -> np.ndarray:
    """Approximate signed distance to an axis-aligned ellipsoid (Quilez's bound), mm."""
    q = (P - np.asarray(c)) / np.asarray(a)
    k0 = np.linalg.norm(q, axis=-1)
    k1 = np.linalg.norm(q / np.asarray(a), axis=-1)
    return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)


def _smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum of two distance fields with blend radius ``k`` (mm; 0 = plain min)."""
    if k <= 0:
        return np.minimum(a, b)
    h = np.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b + (a - b) * h - k * h * (1.0 - h)


def bust_sdf(P: np.ndarray, shape: BustShape) -> np.ndarray:
    """Signed distance (negative inside, approximate away from the surface) of the bust.

    Args:
        P: (..., 3) float64 points, mm.
    Returns:
        (...,) float64, mm.
    """
    d = None
    for k, c, a in shape.primitives():
        e = _ellipsoid_sdf(P, c, a)
        d = e if d is None else _smin(d, e, k)
    # neck: vertical cylinder from y = -20 down, smooth-unioned, then cut flat
    radial = np.hypot(P[..., 0], P[..., 2] - shape.neck_axis_z) - shape.neck_radius
    neck = np.maximum(radial, P[..., 1] + 20.0)
    d = _smin(d, neck, 25.0)
    return np.maximum(d, shape.neck_cut_y - P[..., 1])


def cast_rays(shape: BustShape, c0: np.ndarray, dirs: np.ndarray, step: float = 2.5,
              t_max: float = 280.0) -> np.ndarray:
    """Distance along each ray from ``c0`` to the outermost surface crossing.

    Marches in steps of ``step`` mm to the last inside sample, then bisects 22 times.

    Args:
        c0: (3,) float64 ray origin inside the bust, mm; dirs: (n, 3) float64 unit directions.
    Returns:
        (n,) float64 distances, mm.
    """
    dirs = np.asarray(dirs, dtype=np.float64).reshape(-1, 3)
    ts = np.arange(step, t_max + step, step)
    out = np.empty(len(dirs))
    for s in range(0, len(dirs), 4096):
        D = dirs[s : s + 4096]
        inside = bust_sdf(c0 + ts[None, :, None] * D[:, None, :], shape) < 0
        last = len(ts) - 1 - np.argmax(inside[:, ::-1], axis=1)  # outermost inside sample
        lo, hi = ts[last], ts[last] + step
        for _ in range(22):
            mid = 0.5 * (lo + hi)
            ins = bust_sdf(c0 + mid[:, None] * D, shape) < 0
            lo, hi = np.where(ins, mid, lo), np.where(ins, hi, mid)
        out[s : s + 4096] = 0.5 * (lo + hi)
    return out


def ray_dirs(theta: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Unit directions (..., 3) float64 for azimuth theta (0 = +Z, +pi/2 = +X) and elevation alpha, radians."""
    ca = np.cos(alpha)
    return np.stack([ca * np.sin(theta), np.sin(alpha), ca * np.cos(theta)], axis=-1)


def surface_points(shape: BustShape, c0: np.ndarray, theta: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """(k, 3) float64 surface points, mm, hit by the rays from ``c0`` at azimuths/elevations (broadcast, flattened)."""
    D = ray_dirs(theta, alpha).reshape(-1, 3)
    return c0 + cast_rays(shape, c0, D)[:, None] * D


def sdf_gradient(P: np.ndarray, shape: BustShape, eps: float = 0.05) -> np.ndarray:
    """(n, 3) float64 gradient of :func:`bust_sdf` at (n, 3) points by central differences (not normalised)."""
    g = np.empty_like(P)
    for i in range(3):
        d = np.zeros(3)
        d[i] = eps
        g[:, i] = (bust_sdf(P + d, shape) - bust_sdf(P - d, shape)) / (2 * eps)
    return g


def project_to_surface(P: np.ndarray, shape: BustShape, steps: int = 4) -> np.ndarray:
    """(n, 3) points near the surface taken onto it by ``steps`` Newton steps, mm."""
    for _ in range(steps):
        g = sdf_gradient(P, shape)
        f = bust_sdf(P, shape)
        P = P - (f / np.maximum((g * g).sum(1), 1e-12))[:, None] * g
    return P


def relax_on_surface(V: np.ndarray, quads: np.ndarray, free: np.ndarray, shape: BustShape,
                     iterations: int = 40, step: float = 0.5) -> np.ndarray:
    """Tangential umbrella smoothing of the ``free`` vertices, re-projected onto the implicit surface.

    Args:
        V: (n, 3) float64 vertices, mm. quads: (q, 4) int vertex indices (the mesh's cells).
        free: (n,) bool, the vertices that may move.
    Returns:
        (n, 3) float64 relaxed vertices (a copy; ``V`` itself when nothing moves).
    """
    import scipy.sparse as sp

    if iterations <= 0 or not free.any():
        return V
    e = np.concatenate([quads[:, [0, 1]], quads[:, [1, 2]], quads[:, [2, 3]], quads[:, [3, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    n = len(V)
    A = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])), shape=(n, n)).tocsr()
    A.data[:] = 1.0
    deg = np.asarray(A.sum(1)).ravel()
    idx = np.flatnonzero(free)
    V = V.copy()
    for _ in range(iterations):
        avg = (A[idx] @ V) / deg[idx, None]
        d = avg - V[idx]
        nrm = sdf_gradient(V[idx], shape)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
        d -= (d * nrm).sum(1, keepdims=True) * nrm
        V[idx] = project_to_surface(V[idx] + step * d, shape, steps=2)
    V[idx] = project_to_surface(V[idx], shape, steps=4)
    return V
