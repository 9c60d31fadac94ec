"""A fixed scan's depth, normal and coverage images: rendered once per view set and cached as ``.npz``.

The cache is checked on every load: a file that cannot be read (truncated,
not an npz), that lacks a key, or whose arrays do not fit the cameras (view
count, image size, channels, dtype) or the scan (vertex count) is rendered
again and overwritten, with a warning naming the file and what was wrong. An
error names the file only when the targets cannot be written back.
"""
from __future__ import annotations

import logging
import zipfile
import zlib
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch

from gpja.camera import Camera
from gpja.errors import InputError
from gpja.io import write_npz
from gpja.render.output import CHANNELS
from gpja.render.passes import render_views

log = logging.getLogger(__name__)

#: The target images a cache holds, in order.
TARGETS = ("depth", "normal", "coverage")
#: Every key a scan-targets cache holds.
CACHE_KEYS = ("views_key", "n_vertices") + TARGETS
#: What reading a damaged ``.npz`` can raise.
_UNREADABLE = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)


def views_key(cameras: Sequence[Camera]) -> np.ndarray:
    """(k,) uint8 bytes identifying a view set: each camera's intrinsics, distortion, size and ``Rt``."""
    return np.frombuffer(b"".join(c.cache_key() + c.Rt.tobytes() for c in cameras), dtype=np.uint8)


def cache_problem(cached, cameras: Sequence[Camera], n_vertices: int) -> str | None:
    """Why a loaded cache does not fit these cameras and scan, or None when it does.

    Args:
        cached: the opened ``.npz`` (``np.load``) or a dict of its arrays.
        cameras: the B views the targets are for; n_vertices: the scan's vertex count.
    """
    missing = [k for k in CACHE_KEYS if k not in cached]
    if missing:
        return f"not a scan-targets cache (missing {', '.join(missing)})"
    n = np.asarray(cached["n_vertices"])
    if n.shape != () or not np.issubdtype(n.dtype, np.integer) or int(n) != n_vertices:
        return f"made for another scan ({n.tolist()} vertices, this one has {n_vertices})"
    if not np.array_equal(cached["views_key"], views_key(cameras)):
        return "made for other views or cameras"
    return None


def target_problem(name: str, image: np.ndarray, cameras: Sequence[Camera]) -> str | None:
    """Why a cached target image does not fit the cameras (shape, dtype, finiteness), or None."""
    expected = (len(cameras), cameras[0].height, cameras[0].width, CHANNELS[name])
    if image.shape != expected:
        return f"{name} has shape {image.shape}, the views need {expected}"
    if image.dtype != np.float32:
        return f"{name} is {image.dtype}, not float32"
    if not np.isfinite(image).all():
        return f"{name} holds NaN or infinite values"
    return None


def read_cached_targets(path: str | Path, cameras: Sequence[Camera], n_vertices: int) -> dict[str, torch.Tensor] | None:
    """The cached targets when ``path`` holds a valid cache for these views and scan, else None.

    A file that is unreadable or does not match is reported with a warning naming it and the reason.
    Returns:
        ``"depth"``, ``"normal"``, ``"coverage"``: (B, H, W, C) float32 tensors, or None.
    """
    try:
        cached = np.load(path, allow_pickle=False)
        if not isinstance(cached, np.lib.npyio.NpzFile):
            problem = "not an .npz archive"
        else:
            with cached:
                problem = cache_problem(cached, cameras, n_vertices)
                if problem is None:
                    images = {k: cached[k] for k in TARGETS}
                    problem = next((p for p in (target_problem(k, v, cameras) for k, v in images.items()) if p), None)
                    if problem is None:
                        return {k: torch.from_numpy(v) for k, v in images.items()}
    except _UNREADABLE as err:
        problem = f"unreadable ({type(err).__name__}: {err})"
    log.warning("%s: %s; rendering the scan targets again", path, problem)
    return None


def render_scan_targets(V_scan: np.ndarray, F_scan: np.ndarray, cameras: Sequence[Camera],
                        cache_path: str | Path | None = None, render: Callable | None = None) -> dict[str, torch.Tensor]:
    """Depth, normal and coverage images of a fixed scan, rendered once per view set.

    The scan never moves, so its targets are computed once (no gradient) and,
    with ``cache_path``, stored as ``.npz`` and reused while it matches the views
    and the scan (module docstring: a cache that does not is rendered again).

    Args:
        V_scan: (n, 3) float positions, mm. F_scan: (m, 3) int faces.
        cameras: the B undistorted views (one image size H x W).
        cache_path: ``.npz`` to reuse or create.
        render: a backend's ``render_views`` (``gpja.render.renderer``); None = the CPU renderer.
    Returns:
        ``"depth"`` (B, H, W, 1) mm, ``"normal"`` (B, H, W, 3), ``"coverage"``
        (B, H, W, 1), float32 CPU tensors.
    Raises:
        InputError: the targets could not be written to ``cache_path``.
    """
    if cache_path is not None and Path(cache_path).is_file():
        cached = read_cached_targets(cache_path, cameras, len(V_scan))
        if cached is not None:
            return cached
    render = render or render_views
    with torch.no_grad():
        out = render(torch.as_tensor(np.asarray(V_scan), dtype=torch.float32),
                     torch.as_tensor(np.asarray(F_scan)), cameras, passes=("depth", "normal"))
        targets = {k: out.dense(k).contiguous().cpu() for k in TARGETS}
    if cache_path is not None:
        try:
            write_npz(cache_path, views_key=views_key(cameras), n_vertices=np.int64(len(V_scan)),
                      **{k: v.numpy() for k, v in targets.items()})
        except OSError as err:
            raise InputError(cache_path, f"cannot write the scan targets ({err})") from None
    return targets
