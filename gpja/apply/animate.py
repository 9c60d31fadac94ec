"""Animation between a subject's expressions: interpolated vertex positions, rendered frames, a video.

Registered (or remeshed) expressions share one triangulation and one UV layout, so an animation is a linear
interpolation of vertex positions: :func:`sequence_positions` walks a sequence of expressions (e.g.
``["1_neutral", "2_smile", "3_mouth_stretch", "1_neutral"]``) with ``k`` frames per transition,
:func:`render_frames` renders every frame into a few cameras with the shared texture
(``gpja.metrics.photometric.render_with_texture``, the renders the photometric metrics score),
:func:`tile_views` puts the cameras side by side and :func:`write_video` encodes the result.

Video: H.264 in MP4 (yuv420p, ``VIDEO_QUALITY``), encoded by the ffmpeg the ``imageio-ffmpeg`` wheel ships,
through imageio; odd image sides are padded by one replicated row / column (yuv420p needs even sides). Where
no ffmpeg is found the frames go to an animated GIF beside the requested path (suffix ``.gif``) with a warning.
The output is written atomically and depends only on the frames (and the encoder's version).
"""
from __future__ import annotations

import sys

import warnings
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from gpja.camera import Camera
from gpja.errors import InputError
from gpja.io import atomic_path, to_uint8
from gpja.mesh import TexturedMesh

#: imageio's quality (0-10) of the H.264 video: libx264 constant rate factor ``int((1 - q / 10) * 51)`` = 10,
#: visually lossless for renders.
VIDEO_QUALITY = 8
#: Default grey (0 black .. 1 white) of pixels no surface covers.
BACKGROUND = 1.0


# --- positions ------------------------------------------------------------------------------------------

def interpolate(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """Linear interpolation ``(1 - t) a + t b`` of two vertex arrays.

    Args:
        a, b: (n, 3) float vertex positions of one topology, mm.
        t: interpolation parameter; 0 gives ``a``, 1 gives ``b`` (bit for bit: both endpoints are returned as
            copies, not computed), values outside [0, 1] extrapolate.
    Returns:
        (n, 3) float64 positions, mm (a new array).
    Raises:
        ValueError: ``a`` and ``b`` are not (n, 3) arrays of one shape, or ``t`` is not finite.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"interpolate needs two (n, 3) arrays of one shape, got {a.shape} and {b.shape}")
    t = float(t)
    if not np.isfinite(t):
        raise ValueError(f"interpolation parameter must be finite, got {t}")
    if t == 0.0:
        return a.copy()
    if t == 1.0:
        return b.copy()
    return (1.0 - t) * a + t * b


def sequence_positions(positions: dict[str, np.ndarray], sequence: Sequence[str], frames_per_transition: int,
                       source: str = "animation") -> tuple[list[np.ndarray], list[tuple[str, str, float]]]:
    """Vertex positions of every frame of an animation through a sequence of expressions.

    Transition ``i`` (``sequence[i]`` to ``sequence[i + 1]``) contributes the frames t = 0, 1/k, ..., (k-1)/k
    with k = ``frames_per_transition``; the last expression's frame is appended once at the end, so there are
    ``(len(sequence) - 1) * k + 1`` frames and a sequence that ends where it starts loops seamlessly when the
    last frame is dropped. Keyframes (t = 0, and the last frame) are the expressions' positions bit for bit.

    Args:
        positions: expression name -> (n, 3) float vertex positions, mm, one topology for all.
        sequence: expression names in order, at least 2 (repeats allowed, e.g. back to the first).
        frames_per_transition: k >= 1.
        source: where the sequence comes from (e.g. the config key), named in errors.
    Returns:
        frames: one (n, 3) float64 array per frame, mm.
        labels: one ``(from, to, t)`` per frame; the last frame is ``(sequence[-2], sequence[-1], 1.0)``.
    Raises:
        InputError: a sequence shorter than 2, k < 1 or not an integer, an expression of the sequence missing
            from ``positions``, or an expression whose positions are not (n, 3) with the first one's n.
    """
    sequence = [str(name) for name in sequence]
    if len(sequence) < 2:
        raise InputError(source, f"an animation needs a sequence of at least 2 expressions, got {sequence}")
    k = frames_per_transition
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
        raise InputError(source, f"frames per transition must be an integer >= 1, got {k!r}")
    k = int(k)
    missing = [name for name in dict.fromkeys(sequence) if name not in positions]
    if missing:
        raise InputError(source, f"expression(s) {', '.join(missing)} of the sequence have no mesh "
                                 f"(available: {', '.join(sorted(positions)) or 'none'})")
    arrays: dict[str, np.ndarray] = {}
    for name in dict.fromkeys(sequence):
        V = np.asarray(positions[name], dtype=np.float64)
        if V.ndim != 2 or V.shape[1] != 3:
            raise InputError(source, f"expression {name!r}: vertex positions must be an (n, 3) array, "
                                     f"got shape {V.shape}")
        if arrays and V.shape != arrays[sequence[0]].shape:
            raise InputError(source, f"expression {name!r} has {len(V)} vertices but {sequence[0]!r} has "
                                     f"{len(arrays[sequence[0]])}: the expressions must share one topology")
        arrays[name] = V

    frames: list[np.ndarray] = []
    labels: list[tuple[str, str, float]] = []
    for start, end in zip(sequence[:-1], sequence[1:]):
        for j in range(k):
            t = j / k
            frames.append(interpolate(arrays[start], arrays[end], t))
            labels.append((start, end, t))
    frames.append(arrays[sequence[-1]].copy())
    labels.append((sequence[-2], sequence[-1], 1.0))
    return frames, labels


# --- frames -------------------------------------------------------------------------------------------------

class _KeepCoverage:
    """A backend's ``render_views`` that remembers the coverage of its last render ((B, H, W, 1) float32)."""

    def __init__(self, render: Callable):
        self.render = render
        self.coverage: np.ndarray | None = None

    def __call__(self, *args, **kwargs):
        out = self.render(*args, **kwargs)
        self.coverage = out.dense("coverage").detach().cpu().numpy().astype(np.float32, copy=False)
        return out


def render_frames(frames: Sequence[np.ndarray], F: np.ndarray, UV: np.ndarray, F_uv: np.ndarray,
                  texture: np.ndarray, cameras: Sequence[Camera], sh: np.ndarray, render: Callable | None = None,
                  progress: bool = True, background: float | Sequence[float] = BACKGROUND) -> np.ndarray:
    """Render every frame of an animation into every camera with the shared texture.

    Each frame is ``gpja.metrics.photometric.render_with_texture`` of the mesh (texture x Lambertian SH shading,
    antialiased silhouettes, shading clipped to 1) over a black background, composited onto ``background`` with
    the render's coverage c (1 inside the surface, fractional on antialiased silhouettes, 0 where nothing
    is): ``image = colour + background * (1 - c)``. The colour pass blends into the black background with the
    same weights the coverage has, so this is the render over the grey background (up to shading clipped
    above 1 on silhouette pixels).

    Args:
        frames: per frame, (n, 3) float vertex positions, mm.
        F: (m, 3) int vertex indices per triangle. UV: (k, 2) float texture coordinates in [0, 1] (OBJ
            convention, v up). F_uv: (m, 3) int indices into ``UV``.
        texture: (T, T, 3) float albedo in [0, 1].
        cameras: C undistorted cameras of one image size (H, W), world frame mm.
        sh: (9, 3) float SH radiance coefficients (``gpja.lighting``; ``uniform_sh()`` shows the albedo).
        render: a backend's ``render_views`` (``gpja.render.renderer``); None = the CPU renderer.
        progress: show a tqdm progress bar over the frames (on stderr).
        background: grey level in [0, 1] (scalar) or (3,) RGB of uncovered pixels; 1 = white.
    Returns:
        (n_frames, C, H, W, 3) float32 RGB in [0, 1].
    Raises:
        ValueError: no frame or camera, cameras of different sizes, a background outside [0, 1], or a
            frame that is not a renderable (n, 3) array for ``F``.
    """
    from tqdm import tqdm

    from gpja.metrics.photometric import render_with_texture
    from gpja.render import Topology, render_views

    if len(frames) == 0:
        raise ValueError("no frame to render")
    if len(cameras) == 0:
        raise ValueError("no camera given")
    sizes = {(cam.height, cam.width) for cam in cameras}
    if len(sizes) != 1:
        raise ValueError(f"cameras differ in image size {sorted(sizes)}; frames need one size (H, W)")
    height, width = sizes.pop()
    bg = np.broadcast_to(np.asarray(background, dtype=np.float32), (3,))
    if not (np.all(bg >= 0.0) and np.all(bg <= 1.0)):
        raise ValueError(f"background must lie in [0, 1], got {background}")
    keep = _KeepCoverage(render or render_views)
    out = np.empty((len(frames), len(cameras), height, width, 3), dtype=np.float32)
    # in a log file (no terminal) a line every 10 s, not one per frame
    bar = tqdm(frames, desc="rendering frames", unit="frame", disable=not progress,
               mininterval=0.1 if sys.stderr.isatty() else 10.0)
    topology = Topology(F, F_uv)  # every frame has these faces: their adjacency is built once
    for i, V in enumerate(bar):
        mesh = TexturedMesh(np.asarray(V, dtype=np.float64), F, UV, F_uv)
        color = render_with_texture(mesh, texture, cameras, sh, keep, topology)
        out[i] = np.clip(color + bg * (1.0 - keep.coverage), 0.0, 1.0)
    return out


def tile_views(frames_views: np.ndarray) -> np.ndarray:
    """Put each frame's views side by side, camera 0 on the left.

    Args:
        frames_views: (n_frames, C, H, W, 3) images (any dtype), as :func:`render_frames` returns them.
    Returns:
        (n_frames, H, C * W, 3) images, same dtype.
    """
    x = np.asarray(frames_views)
    if x.ndim != 5 or x.shape[-1] != 3:
        raise ValueError(f"expected (n_frames, n_cameras, H, W, 3) images, got shape {x.shape}")
    n, c, h, w, _ = x.shape
    return np.ascontiguousarray(x.transpose(0, 2, 1, 3, 4)).reshape(n, h, c * w, 3)


# --- video --------------------------------------------------------------------------------------------------

def ffmpeg_problem() -> str | None:
    """Why no ffmpeg can encode the video (None where ``imageio_ffmpeg`` finds one)."""
    try:
        import imageio_ffmpeg
    except ImportError:
        return "the imageio-ffmpeg package is not installed"
    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except Exception as exc:  # RuntimeError where neither its binary nor a system one is found
        return f"imageio_ffmpeg.get_ffmpeg_exe() failed ({exc})"
    return None


def _video_frames(frames: np.ndarray) -> np.ndarray:
    """(n, H, W, 3) float in [0, 1] or uint8 -> uint8 (clipped, rounded like ``gpja.io.to_uint8``)."""
    x = np.asarray(frames)
    if x.ndim != 4 or x.shape[-1] != 3 or x.shape[0] == 0 or x.shape[1] == 0 or x.shape[2] == 0:
        raise ValueError(f"expected (n_frames >= 1, H, W, 3) frames, got shape {x.shape}")
    if x.dtype != np.uint8 and not np.isfinite(x).all():
        raise ValueError("frames contain NaN or infinite values")
    return to_uint8(x)


def _pad_even(frames: np.ndarray) -> np.ndarray:
    """(n, H, W, 3) -> (n, H + H % 2, W + W % 2, 3), the last row / column repeated where a side is odd."""
    _, h, w, _ = frames.shape
    if h % 2 == 0 and w % 2 == 0:
        return frames
    return np.pad(frames, ((0, 0), (0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def _encode_mp4(frames: np.ndarray, path: Path, fps: float) -> None:
    import imageio.v2 as imageio

    with imageio.get_writer(str(path), format="FFMPEG", mode="I", fps=fps, codec="libx264",
                            pixelformat="yuv420p", quality=VIDEO_QUALITY, macro_block_size=1,
                            ffmpeg_log_level="error", output_params=["-f", "mp4"]) as writer:
        for frame in frames:
            writer.append_data(frame)


def _write_gif(frames: np.ndarray, path: Path, fps: float) -> None:
    from PIL import Image

    images = [Image.fromarray(frame) for frame in frames]
    # GIF delays are whole centiseconds; Pillow merges identical consecutive frames (adding their delays)
    images[0].save(path, format="GIF", save_all=True, append_images=images[1:],
                   duration=max(10, int(round(1000.0 / fps))), loop=0)


def write_video(frames: np.ndarray, path: str | Path, fps: float = 24) -> Path:
    """Encode frames as an H.264 MP4 (or, without ffmpeg, an animated GIF), atomically.

    Args:
        frames: (n_frames, H, W, 3) RGB, float in [0, 1] (clipped, rounded to 8 bits) or uint8; e.g.
            :func:`tile_views` of :func:`render_frames`.
        path: the ``.mp4`` to write (its folder is created).
        fps: frames per second (> 0).
    Returns:
        the path written: ``path``, or ``path`` with suffix ``.gif`` where no ffmpeg was found (a
        ``RuntimeWarning`` says why; an older file at ``path`` is left as it was). The MP4 has
        H + H % 2 x W + W % 2 pixels (odd sides padded by repeating the last row / column), yuv420p; the GIF
        keeps H x W, a per-frame 256-colour palette and delays rounded to 10 ms.
    Raises:
        InputError: ``path`` does not end in ``.mp4``.
        ValueError: frames that are not (n >= 1, H, W, 3) finite values, or fps <= 0.
    """
    path = Path(path)
    if path.suffix.lower() != ".mp4":
        raise InputError(path, "a video is written as MP4: the file name must end in .mp4")
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be positive, got {fps}")
    frames = _video_frames(frames)
    problem = ffmpeg_problem()
    if problem is None:
        # atomic_path's temporary file keeps the suffix (".part.mp4"), and "-f mp4" names the muxer anyway
        with atomic_path(path) as tmp:
            _encode_mp4(_pad_even(frames), tmp, fps)
        return path
    gif = path.with_suffix(".gif")
    warnings.warn(f"{path}: no ffmpeg to encode an MP4 ({problem}); wrote an animated GIF {gif} instead "
                  "(pip install imageio-ffmpeg for the video)", RuntimeWarning, stacklevel=2)
    with atomic_path(gif) as tmp:
        _write_gif(frames, tmp, fps)
    return gif
