"""Synthetic multiview capture: camera rig, SH lighting and ray-cast rendering.

Images are rendered by ray casting (Open3D's RaycastingScene) against a
render mesh in expression space, with ``supersample`` x ``supersample`` rays
per pixel. Each ray goes through the *distorted* pixel position, so the
images carry the rig's lens distortion. Per hit: the rest-space point
(barycentric interpolation of the render mesh's rest positions) -> procedural
albedo -> Lambertian shading (:mod:`gpja.lighting`) with smooth interpolated
normals. Pixel values are the linear shaded radiance (no gamma curve), so the
SH model in the ground truth reproduces them exactly.
"""
from __future__ import annotations

import math

import numpy as np

from gpja.camera import Camera
from gpja.lighting import shade_lambertian, sh_basis
# the scene and the normals are the shared surface layer's (re-exported for the generator's modules)
from gpja.surface import raycasting_scene as build_scene
from gpja.surface import load_open3d, vertex_normals

#: Background colour (linear RGB) of every image.
BACKGROUND_RGB = np.array([0.22, 0.22, 0.23])
#: Point the rig looks at (rest frame, mm): between the nose and the chin.
RIG_TARGET_MM = np.array([0.0, -22.0, 20.0])
#: (azimuth, elevation) of the eight default views in degrees; azimuth 0 looks
#: at the face, positive towards the subject's left (+X).
RIG_DIRECTIONS_DEG = ((0.0, 6.0), (38.0, 12.0), (-38.0, 12.0), (72.0, -2.0), (-72.0, -2.0),
                      (100.0, 6.0), (-100.0, 6.0), (0.0, -28.0))
#: Focal length in units of the image width.
FOCAL_PER_WIDTH = 1.6


def make_rig(rng: np.random.Generator, n_views: int, image_size: int, distance_mm: float,
             distortion: bool = True) -> list[Camera]:
    """Cameras around the head, named "0".."n-1".

    Args:
        rng: per-subject generator (small jitter of the intrinsics and distortion).
        n_views: number of cameras; the first 8 follow :data:`RIG_DIRECTIONS_DEG`,
            more are spread on a ring.
        image_size: width = height in pixels.
        distance_mm: distance of each camera from :data:`RIG_TARGET_MM`.
    Returns:
        list of :class:`gpja.camera.Camera` (world = rest/aligned frame, mm).
    """
    dirs = list(RIG_DIRECTIONS_DEG[:n_views])
    for i in range(len(dirs), n_views):
        dirs.append((-150.0 + 300.0 * (i - 8 + 0.5) / max(1, n_views - 8), 20.0))
    cams = []
    W = int(image_size)
    for i, (az, el) in enumerate(dirs):
        a, e = math.radians(az), math.radians(el)
        eye = RIG_TARGET_MM + distance_mm * np.array([math.sin(a) * math.cos(e), math.sin(e), math.cos(a) * math.cos(e)])
        f = FOCAL_PER_WIDTH * W * (1.0 + rng.uniform(-0.02, 0.02))
        cx = (W - 1) / 2.0 + rng.uniform(-0.01, 0.01) * W
        cy = (W - 1) / 2.0 + rng.uniform(-0.01, 0.01) * W
        K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        dist = np.zeros(5)
        if distortion:
            dist = np.array([rng.uniform(-0.08, 0.04), rng.uniform(-0.05, 0.08), rng.uniform(-5e-4, 5e-4),
                             rng.uniform(-5e-4, 5e-4), rng.uniform(-0.02, 0.02)])
        cams.append(Camera.look_at(eye, RIG_TARGET_MM, (0.0, 1.0, 0.0), K, W, W, dist, name=str(i)))
    return cams


def make_sh(rng: np.random.Generator) -> np.ndarray:
    """Near-uniform SH lighting (9, 3) float64 with a small random directional part.

    Radiance L(w) = I (1 + a w.d) slightly tinted, plus a weak band-2 term.
    """
    I = rng.uniform(1.0, 1.15)
    tint = 1.0 + rng.uniform(-0.03, 0.03, 3)
    d = rng.normal(size=3)
    d[2] = abs(d[2]) + 0.5  # light comes from the front hemisphere
    d[1] = abs(d[1]) * 0.8  # ... and from above
    d /= np.linalg.norm(d)
    a = rng.uniform(0.5, 0.9)
    sh = np.zeros((9, 3))
    sh[0] = 2.0 * math.sqrt(math.pi) * I * tint
    # L(w) = I (1 + a w.d): with Y_1m(w) = C1 (y, z, x) the band-1 coefficients are I a (d_y, d_z, d_x) / C1
    c1 = math.sqrt(3.0 / (4.0 * math.pi))
    sh[1:4] = (I * a / c1 * np.array([d[1], d[2], d[0]]))[:, None] * tint[None, :]
    sh[4:9] = rng.uniform(-0.08, 0.08, (5, 1)) * I
    return sh


class RayBundle:
    """Supersampled rays of one camera, computed once per subject.

    Attributes:
        origins: (H*S*W*S, 3) float32 mm; directions: same, unit.
    """

    def __init__(self, cam: Camera, supersample: int):
        S = int(supersample)
        off = (np.arange(S) + 0.5) / S - 0.5
        us = (np.arange(cam.width)[:, None] + off[None, :]).ravel()
        vs = (np.arange(cam.height)[:, None] + off[None, :]).ravel()
        uu, vv = np.meshgrid(us, vs)
        o, d = cam.pixel_rays(np.stack([uu.ravel(), vv.ravel()], 1))
        self.rays = np.concatenate([o, d], 1).astype(np.float32)
        self.shape = (cam.height, S, cam.width, S)


def cast(scene, rays: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cast rays (n, 6) float32 -> t_hit (n,), primitive id (n,) int64 (-1 = miss), uv (n, 2)."""
    o3d = load_open3d()

    ans = scene.cast_rays(o3d.core.Tensor(rays))
    t = ans["t_hit"].numpy()
    pid = ans["primitive_ids"].numpy().astype(np.int64)
    hit = np.isfinite(t)
    pid[~hit] = -1
    return t, pid, ans["primitive_uvs"].numpy()


def render_view(scene, bundle: RayBundle, V_rest: np.ndarray, N_expr: np.ndarray, F: np.ndarray,
                albedo_fn, sh: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """Render one view of the render mesh.

    Args:
        scene: RaycastingScene of the render mesh in expression space.
        bundle: the camera's supersampled rays.
        V_rest: (n, 3) float64 rest positions of the render mesh's vertices, mm.
        N_expr: (n, 3) unit vertex normals in expression space.
        F: (m, 3) faces.
        albedo_fn: rest points (k, 3) -> albedo (k, 3).
        sh: (9, 3) lighting; gain: (3,) per-expression skin gain.
    Returns:
        (H, W, 3) float32 linear RGB in [0, 1].
    """
    _, pid, uv = cast(scene, bundle.rays)
    hit = pid >= 0
    f = F[pid[hit]]
    w1, w2 = uv[hit, 0:1].astype(np.float64), uv[hit, 1:2].astype(np.float64)
    w0 = 1.0 - w1 - w2
    Xr = w0 * V_rest[f[:, 0]] + w1 * V_rest[f[:, 1]] + w2 * V_rest[f[:, 2]]
    n = w0 * N_expr[f[:, 0]] + w1 * N_expr[f[:, 1]] + w2 * N_expr[f[:, 2]]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    alb = albedo_fn(Xr) * gain[None, :]
    col = np.clip(shade_lambertian(alb, n, sh), 0.0, 1.0)
    img = np.empty((len(hit), 3), np.float64)
    img[:] = BACKGROUND_RGB
    img[hit] = col
    H, S, W, _ = bundle.shape
    return img.reshape(H, S, W, S, 3).mean(axis=(1, 3)).astype(np.float32)


__all__ = ["make_rig", "make_sh", "vertex_normals", "RayBundle", "build_scene", "cast", "render_view",
           "BACKGROUND_RGB", "sh_basis"]
