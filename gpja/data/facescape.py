"""Read one subject/expression in FaceScape's multiview layout.

Layout (the synthetic benchmark writes the same):
    {images_root}/{subject}/{expression}/{view}.jpg|png
    {images_root}/{subject}/{expression}/params.json   # {view}_K, _Rt, _distortion, _width, _height, _valid
    {scans_root}/{subject}/{expression}.ply            # raw scan
    Rt_scale_dict.json (optional)                      # [subject][expression number] = [scale, Rt]

With ``Rt_scale_dict.json`` the scan is brought into the aligned millimetre
frame as ``X' = R (s X) + t`` and the cameras consistently with it. Images are
undistorted once (optionally cached on disk), so everything downstream uses
plain pinhole cameras.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from gpja.camera import Camera
from gpja.data.units import check_head_units
from gpja.errors import InputError
from gpja.io import from_uint8, read_image, read_json, to_uint8, write_image
from gpja.mesh import read_ply

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".jpg", ".png", ".jpeg")


@dataclass
class View:
    """One undistorted reference image and its camera.

    Attributes:
        name: the view's name in ``params.json``.
        camera: undistorted pinhole camera in the aligned (mm) frame.
        image: (H, W, 3) float32 RGB in [0, 1], undistorted.
        path: the source image file.
    """

    name: str
    camera: Camera
    image: np.ndarray
    path: Path


@dataclass
class Scan:
    """A raw scan in the aligned frame. ``V`` (n, 3) float64 mm, ``F`` (m, 3) int64."""

    V: np.ndarray
    F: np.ndarray
    path: Path


@dataclass
class ExpressionData:
    """Everything GPJA needs for one expression of one subject."""

    subject: str
    expression: str
    views: list[View]
    scan: Scan | None
    scale: float = 1.0
    R: np.ndarray | None = None
    t: np.ndarray | None = None

    @property
    def cameras(self) -> list[Camera]:
        return [v.camera for v in self.views]

    @property
    def images(self) -> list[np.ndarray]:
        return [v.image for v in self.views]


def expression_number(expression: str) -> int:
    """FaceScape's expression number: ``"3_mouth_stretch"`` -> 3."""
    head = expression.split("_", 1)[0]
    if not head.isdigit():
        raise InputError("config", f"expression {expression!r} does not follow FaceScape's '<number>_<name>' naming")
    return int(head)


def expression_dir(images_root: str | Path, subject: str, expression: str) -> Path:
    return Path(images_root) / str(subject) / expression


def scan_path(scans_root: str | Path, subject: str, expression: str) -> Path:
    return Path(scans_root) / str(subject) / f"{expression}.ply"


def read_params(path: str | Path) -> dict:
    """Load a ``params.json``; missing or corrupt files raise :class:`InputError`."""
    params = read_json(path)
    if not isinstance(params, dict):
        raise InputError(path, "expected a JSON object of '{view}_{key}' entries")
    return params


#: The per-view keys of a ``params.json``: ``{view}_K``, ... (``Camera.from_params`` reads all but ``valid``).
VIEW_KEYS = ("K", "Rt", "distortion", "width", "height", "valid")


def list_views(params: dict) -> list[str]:
    """Every view ``params`` describes (by any of its :data:`VIEW_KEYS`), in numeric then name order.

    A view counts as described when any one of its keys is present, so a view that lacks one
    (say ``{view}_K``) is still listed, and reading its camera names the missing key.
    """
    names = {k[: -len(suffix) - 1] for k in params for suffix in VIEW_KEYS
             if k.endswith(f"_{suffix}") and len(k) > len(suffix) + 1}
    return sorted(names, key=lambda n: (0, int(n), "") if n.isdigit() else (1, 0, n))


def read_cameras(params_path: str | Path, views: Sequence[str] | None = None) -> list[Camera]:
    """The valid cameras of an expression, as written in its ``params.json``.

    Only ``{view}_valid: false`` drops a described view (with a warning); a view
    missing any other key is an error, never silently left out.

    Args:
        views: view names to keep (in this order); None keeps every valid view.
    Raises:
        InputError: a requested view is absent, a key is missing or malformed
        (naming the file and the key), or no valid view remains.
    """
    params = read_params(params_path)
    available = list_views(params)
    wanted = available if views is None else [str(v) for v in views]
    cameras = []
    for view in wanted:
        if view not in available:
            raise InputError(params_path, f"view {view!r} requested but not described (available: {', '.join(available[:12])}{' ...' if len(available) > 12 else ''})")
        if f"{view}_valid" not in params:
            raise InputError(params_path, f"view {view!r}: key '{view}_valid' missing")
        if not params[f"{view}_valid"]:
            log.warning("%s: view %s is marked invalid; skipped", params_path, view)
            continue
        cameras.append(Camera.from_params(params, view, params_path))
    if not cameras:
        raise InputError(params_path, "no valid view to use")
    return cameras


def read_rt_scale(path: str | Path, subject: str, expression: str) -> tuple[float, np.ndarray, np.ndarray]:
    """The raw-to-aligned transform ``X' = R (s X) + t`` of one expression.

    Returns:
        scale: s (float); R: (3, 3) float64; t: (3,) float64 mm.
    """
    table = read_json(path)
    num = str(expression_number(expression))
    try:
        entry = table[str(subject)][num]
        scale = float(entry[0])
        Rt = np.asarray(entry[1], dtype=np.float64)
    except (KeyError, IndexError, TypeError, ValueError):
        raise InputError(path, f"no valid [scale, Rt] entry for subject {subject!r}, expression {num}") from None
    if Rt.shape == (4, 4):
        Rt = Rt[:3]
    if Rt.shape != (3, 4) or not np.isfinite(Rt).all() or not np.isfinite(scale) or scale <= 0:
        raise InputError(path, f"subject {subject!r}, expression {num}: expected a positive scale and a 3x4 Rt")
    R = Rt[:, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-4):
        raise InputError(path, f"subject {subject!r}, expression {num}: Rt's 3x3 part is not a rotation")
    return scale, R, Rt[:, 3]


def find_image(folder: Path, view: str) -> Path:
    for suffix in IMAGE_SUFFIXES:
        candidate = folder / f"{view}{suffix}"
        if candidate.is_file():
            return candidate
    raise InputError(folder / f"{view}.jpg", f"image of view {view!r} not found (looked for {', '.join(view + s for s in IMAGE_SUFFIXES)})")


def load_view_image(camera: Camera, path: Path, cache_dir: Path | None = None) -> np.ndarray:
    """Read a view's image, check its size against the camera, undistort it.

    With ``cache_dir`` the undistorted image is stored there as PNG and reused
    while it is newer than its source, so undistortion runs once per image.
    The undistorted image is always quantised to 8 bits, as the PNG cache
    stores it: otherwise the job that happens to fill the cache would see
    different colours from every job that reads it, and results would depend
    on the order the workflow ran its jobs in.
    """
    cached = None if cache_dir is None else Path(cache_dir) / f"{camera.name}.png"
    if cached is not None and cached.is_file() and cached.stat().st_mtime >= path.stat().st_mtime:
        try:
            image = read_image(cached)
        except InputError as err:  # a cache file cut off mid-write or overwritten: rebuild it
            log.warning("%s; undistorting %s again", err, path)
        else:
            if image.shape[:2] == (camera.height, camera.width):
                return image
            log.warning("%s: cached image is %dx%d, the camera %dx%d; undistorting %s again", cached,
                        image.shape[1], image.shape[0], camera.width, camera.height, path)
    image = read_image(path)
    if image.shape[:2] != (camera.height, camera.width):
        raise InputError(path, f"image is {image.shape[1]}x{image.shape[0]} but params.json says {camera.width}x{camera.height}")
    image = from_uint8(to_uint8(camera.undistort_image(image)))
    if cached is not None and camera.has_distortion:
        write_image(cached, image)
    return image


def read_scan(path: str | Path, scale: float = 1.0, R: np.ndarray | None = None, t: np.ndarray | None = None) -> Scan:
    """Read a scan PLY and bring it into the aligned frame ``X' = R (s X) + t``.

    Raises:
        InputError: missing/corrupt/empty file, NaN vertices, or an extent that
        does not look like a head in millimetres.
    """
    path = Path(path)
    V, F = read_ply(path)
    V = scale * V
    if R is not None:
        V = V @ np.asarray(R).T + np.asarray(t)
    check_head_units(V, path)
    return Scan(V=V, F=F, path=path)


def resize_view(view: View, max_size: int) -> View:
    """Downsample a view so its longer side is at most ``max_size`` pixels (area filter)."""
    cam = view.camera
    scale = max_size / max(cam.width, cam.height)
    if scale >= 1.0:
        return view
    w, h = max(1, round(cam.width * scale)), max(1, round(cam.height * scale))
    image = cv2.resize(view.image, (w, h), interpolation=cv2.INTER_AREA)
    return View(view.name, cam.resized(w, h), image, view.path)


def load_expression(
    images_root: str | Path,
    subject: str,
    expression: str,
    *,
    views: Sequence[str] | None = None,
    scans_root: str | Path | None = None,
    rt_scale_path: str | Path | None = None,
    cache_dir: str | Path | None = None,
    max_image_size: int | None = None,
) -> ExpressionData:
    """Load the undistorted views (and scan) of one expression in the aligned frame.

    Args:
        views: names of the views to use (the paper uses 6-8); None = all valid ones.
        scans_root: where ``{subject}/{expression}.ply`` scans live; None skips the scan.
        rt_scale_path: FaceScape's ``Rt_scale_dict.json``; None means data already in mm.
        cache_dir: folder for undistorted images (reused across runs).
        max_image_size: downsample images (and intrinsics) to this longer side.
    """
    subject = str(subject)
    folder = expression_dir(images_root, subject, expression)
    params_path = folder / "params.json"
    if not folder.is_dir():
        raise InputError(folder, f"expression folder of subject {subject!r} not found")
    cameras = read_cameras(params_path, views)
    scale, R, t = 1.0, None, None
    if rt_scale_path is not None:
        scale, R, t = read_rt_scale(rt_scale_path, subject, expression)
    loaded = []
    cache = None if cache_dir is None else Path(cache_dir) / subject / expression
    for cam in cameras:
        path = find_image(folder, cam.name)
        image = load_view_image(cam, path, cache)
        aligned = cam.undistorted() if R is None else cam.undistorted().transformed(scale, R, t)
        view = View(cam.name, aligned, image, path)
        loaded.append(resize_view(view, max_image_size) if max_image_size else view)
    scan = None
    if scans_root is not None:
        scan = read_scan(scan_path(scans_root, subject, expression), scale, R, t)
    return ExpressionData(subject, expression, loaded, scan, scale, R, t)
