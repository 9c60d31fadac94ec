"""OpenCV pinhole cameras: projection, rays, distortion and image undistortion.

Conventions (DESIGN.md): ``K`` (3, 3), ``Rt`` (3, 4) world-to-camera so that
``X_cam = R X + t``, distortion ``(k1, k2, p1, p2, k3)`` in OpenCV's model,
image origin top-left, pixel centres at integer coordinates, world units mm.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any, Sequence

import cv2
import numpy as np

from gpja.errors import InputError

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated pinhole camera with OpenCV lens distortion.

    Attributes:
        K: (3, 3) float64 intrinsics in pixels.
        Rt: (3, 4) float64 world-to-camera rigid transform (mm).
        distortion: (5,) float64 ``(k1, k2, p1, p2, k3)``.
        width, height: image size in pixels.
        name: the view's name (FaceScape uses "0", "1", ...).
    """

    K: np.ndarray
    Rt: np.ndarray
    distortion: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width: int = 0
    height: int = 0
    name: str = ""

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        Rt = np.asarray(self.Rt, dtype=np.float64)
        dist = np.zeros(5) if self.distortion is None else np.asarray(self.distortion, dtype=np.float64).ravel()
        if K.shape != (3, 3) or Rt.shape != (3, 4) or dist.shape != (5,):
            raise ValueError(f"camera {self.name!r}: K must be 3x3, Rt 3x4, distortion 5 values; got {K.shape}, {Rt.shape}, {dist.shape}")
        if not (np.isfinite(K).all() and np.isfinite(Rt).all() and np.isfinite(dist).all()):
            raise ValueError(f"camera {self.name!r}: non-finite calibration values")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "Rt", Rt)
        object.__setattr__(self, "distortion", dist)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # --- construction -------------------------------------------------------------
    @classmethod
    def look_at(cls, eye, target, up, K, width: int, height: int, distortion=None, name: str = "") -> "Camera":
        """A camera at ``eye`` (3,) mm looking at ``target`` (3,), image up along ``up``.

        OpenCV axes: camera x right, y down, z forward.
        """
        eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
        z = target - eye
        z /= np.linalg.norm(z)
        x = np.cross(z, up)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        Rt = np.concatenate([R, (-R @ eye)[:, None]], axis=1)
        return cls(K=K, Rt=Rt, distortion=distortion, width=width, height=height, name=name)

    @classmethod
    def from_params(cls, params: dict[str, Any], view: str, path: str | Path = "params.json") -> "Camera":
        """Read view ``view`` from a FaceScape ``params.json`` dictionary.

        Raises:
            InputError: a key is missing or a value has the wrong shape.
        """
        values = {}
        for key, shape in (("K", (3, 3)), ("Rt", (3, 4)), ("distortion", None), ("width", ()), ("height", ())):
            full = f"{view}_{key}"
            if full not in params:
                raise InputError(path, f"view {view!r}: key {full!r} missing")
            try:
                arr = np.asarray(params[full], dtype=np.float64)
            except (TypeError, ValueError):
                raise InputError(path, f"view {view!r}: key {full!r} is not numeric") from None
            if key == "distortion":
                arr = arr.ravel()
                if arr.size not in (4, 5, 8, 12, 14):
                    raise InputError(path, f"view {view!r}: {full!r} has {arr.size} values, expected 5 (k1,k2,p1,p2,k3)")
                if arr.size > 5 and np.any(arr[5:] != 0):
                    raise InputError(path, f"view {view!r}: {full!r} uses distortion terms beyond k3, which are unsupported")
                arr = np.pad(arr[:5], (0, max(0, 5 - arr.size)))
            elif arr.shape != shape:
                raise InputError(path, f"view {view!r}: {full!r} has shape {arr.shape}, expected {shape}")
            if not np.isfinite(arr).all():
                raise InputError(path, f"view {view!r}: {full!r} has non-finite values")
            values[key] = arr
        if values["width"] <= 0 or values["height"] <= 0:
            raise InputError(path, f"view {view!r}: image size must be positive")
        return cls(K=values["K"], Rt=values["Rt"], distortion=values["distortion"],
                   width=int(values["width"]), height=int(values["height"]), name=str(view))

    def to_params(self, view: str | None = None) -> dict[str, Any]:
        """FaceScape ``params.json`` entries for this camera (``valid`` true)."""
        v = self.name if view is None else view
        return {f"{v}_K": self.K.tolist(), f"{v}_Rt": self.Rt.tolist(), f"{v}_distortion": self.distortion.tolist(),
                f"{v}_width": self.width, f"{v}_height": self.height, f"{v}_valid": True}

    # --- geometry -------------------------------------------------------------------
    @property
    def R(self) -> np.ndarray:
        """(3, 3) world-to-camera rotation."""
        return self.Rt[:, :3]

    @property
    def t(self) -> np.ndarray:
        """(3,) world-to-camera translation, mm."""
        return self.Rt[:, 3]

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, mm."""
        return -self.R.T @ self.t

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.distortion != 0))

    def to_camera(self, X: np.ndarray) -> np.ndarray:
        """World points (n, 3) mm -> camera-frame points (n, 3) mm."""
        return np.asarray(X, dtype=np.float64) @ self.R.T + self.t

    def project(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points to (distorted) pixel coordinates.

        Args:
            X: (n, 3) world points, mm.
        Returns:
            uv: (n, 2) float64 pixel coordinates (x right, y down).
            z: (n,) float64 camera depth, mm (points behind the camera have z <= 0).
        """
        Xc = self.to_camera(X)
        z = Xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = Xc[:, :2] / z[:, None]
        return self.normalized_to_pixels(distort_normalized(xy, self.distortion)), z

    def normalized_to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """(n, 2) normalised image-plane coordinates -> (n, 2) pixels via ``K``."""
        return xy @ self.K[:2, :2].T + self.K[:2, 2]

    def pixels_to_normalized(self, uv: np.ndarray) -> np.ndarray:
        """(n, 2) pixel coordinates -> (n, 2) undistorted normalised coordinates."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if not self.has_distortion:
            return (uv - self.K[:2, 2]) @ np.linalg.inv(self.K[:2, :2]).T
        out = cv2.undistortPoints(uv[:, None, :], self.K, self.distortion, None, None, None, _UNDISTORT_CRITERIA)
        return out[:, 0, :]

    def pixel_rays(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World rays through pixel positions of the (distorted) image.

        Args:
            uv: (n, 2) pixel coordinates; pixel centres are integers.
        Returns:
            origins: (n, 3) float64, the camera centre, mm.
            directions: (n, 3) float64 unit directions, world frame.
        """
        xy = self.pixels_to_normalized(uv)
        d = np.concatenate([xy, np.ones((len(xy), 1))], axis=1) @ self.R
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return np.broadcast_to(self.center, d.shape).copy(), d

    # --- derived cameras -------------------------------------------------------------
    def undistorted(self) -> "Camera":
        """The same camera without lens distortion (for undistorted images)."""
        return replace(self, distortion=np.zeros(5))

    def transformed(self, scale: float, R: np.ndarray, t: np.ndarray) -> "Camera":
        """This camera expressed in the world frame ``X' = R (s X) + t``.

        Projections of corresponding points are unchanged; depths get multiplied by
        ``s`` (so a raw FaceScape camera becomes a millimetre camera).
        """
        R = np.asarray(R, dtype=np.float64)
        t = np.asarray(t, dtype=np.float64).ravel()
        Rc = self.R @ R.T
        tc = scale * self.t - Rc @ t
        return replace(self, Rt=np.concatenate([Rc, tc[:, None]], axis=1))

    def resized(self, width: int, height: int) -> "Camera":
        """The camera for the image resampled to ``width`` x ``height`` pixels."""
        sx, sy = width / self.width, height / self.height
        S = np.array([[sx, 0, 0.5 * sx - 0.5], [0, sy, 0.5 * sy - 0.5], [0, 0, 1.0]])
        return replace(self, K=S @ self.K, width=width, height=height)

    def cache_key(self) -> bytes:
        return self.K.tobytes() + self.distortion.tobytes() + np.array([self.width, self.height]).tobytes()

    def undistort_image(self, image: np.ndarray) -> np.ndarray:
        """Resample an image of this camera to the undistorted camera (same ``K``).

        Args:
            image: (H, W, C) or (H, W) array, H and W equal to the camera's.
        Returns:
            The undistorted image, same shape and dtype (bilinear, border replicated).
        """
        if image.shape[:2] != (self.height, self.width):
            raise ValueError(f"image is {image.shape[1]}x{image.shape[0]}, camera {self.name!r} expects {self.width}x{self.height}")
        if not self.has_distortion:
            return image
        map_x, map_y = _undistort_maps(self.cache_key())
        return cv2.remap(image, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


@lru_cache(maxsize=64)
def _undistort_maps(key: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Per-camera undistortion maps, computed once per intrinsics (cached by value)."""
    K = np.frombuffer(key[:72], dtype=np.float64).reshape(3, 3)
    dist = np.frombuffer(key[72:112], dtype=np.float64)
    w, h = np.frombuffer(key[112:], dtype=np.int64)
    return cv2.initUndistortRectifyMap(K, dist, None, K, (int(w), int(h)), cv2.CV_32FC1)


def distort_normalized(xy: np.ndarray, distortion: np.ndarray) -> np.ndarray:
    """Apply OpenCV's radial-tangential model to normalised coordinates.

    Args:
        xy: (n, 2) undistorted normalised image coordinates.
        distortion: (5,) ``(k1, k2, p1, p2, k3)``.
    Returns:
        (n, 2) distorted normalised coordinates.
    """
    k1, k2, p1, p2, k3 = np.asarray(distortion, dtype=np.float64)
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def framing_camera(points: np.ndarray, size: int, yaw_deg: float = 0.0, distance_mm: float = 600.0,
                   margin: float = 1.12, name: str = "") -> Camera:
    """A square pinhole camera in the canonical head frame that looks at the points and frames them.

    The view direction is the frontal one (from +Z towards -Z) turned by ``yaw_deg`` about +Y (right-handed):
    the camera centre lies along ``(sin yaw, 0, cos yaw)`` from the points, so 0 is frontal, +90 looks along
    -X from the +X side (the subject's left: the face looks towards +Z with its top towards +Y, so its left
    side is +X) and e.g. +35 is a three-quarter view of the subject's left cheek, -35 of the right one.

    Framing (in the camera-aligned frame, i.e. the points turned by -yaw about +Y): the 0.5 / 99.5
    percentiles of the points per axis give a box; the camera looks at its centre from ``distance_mm`` in
    front of its near face, and the larger of its width and height times ``margin`` fills the image at the
    depth of the box centre. Image up is world +Y.

    Args:
        points: (n, 3) float positions in the canonical head frame, mm (finite, n >= 1).
        size: image side, px.
        yaw_deg: rotation of the view direction about +Y, degrees.
        distance_mm: camera distance to the nearest part of the framed box, mm.
        margin: extent scale (> 1 leaves a border).
        name: the camera's name.
    Returns:
        an undistorted ``size x size`` camera.
    Raises:
        ValueError: no points, or non-finite ones.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0 or not np.isfinite(points).all():
        raise ValueError("framing_camera needs finite points")
    yaw = np.deg2rad(float(yaw_deg))
    c, s = np.cos(yaw), np.sin(yaw)
    # columns: the camera-aligned frame's right (image x), up (+Y) and backwards (towards the camera) axes;
    # at yaw 0 the points are used as they are, so the frontal camera's arithmetic is unchanged
    axes = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    local = points if yaw_deg == 0 else points @ axes
    lo, hi = np.percentile(local, [0.5, 99.5], axis=0)
    centre = (lo + hi) / 2.0
    half = max(hi[0] - lo[0], hi[1] - lo[1]) / 2.0 * margin
    depth = distance_mm + (hi[2] - centre[2])
    focal = (size / 2.0) * depth / max(half, 1e-6)
    K = np.array([[focal, 0.0, (size - 1) / 2.0], [0.0, focal, (size - 1) / 2.0], [0.0, 0.0, 1.0]])
    eye = np.array([centre[0], centre[1], hi[2] + distance_mm])
    if yaw_deg != 0:
        centre, eye = axes @ centre, axes @ eye
    return Camera.look_at(eye, centre, (0.0, 1.0, 0.0), K, size, size, name=name)


def most_frontal_view(cameras: Sequence[Camera]) -> int:
    """Index of the camera looking most directly at the face (its optical axis closest to -Z)."""
    return int(np.argmin([cam.R[2, 2] for cam in cameras]))
