"""What every figure draws with: the PNG + PDF output, panel grids, a frontal camera and one-view renders.

Renders of geometry use a frontal pinhole camera framed on the surface in the canonical head frame (face
towards +Z, top towards +Y) and a headlight. matplotlib and torch are imported inside the functions.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from gpja.camera import Camera, framing_camera
from gpja.io import atomic_path

#: Colour map of the geometric-error heatmaps (perceptually ordered, dark = small).
HEATMAP_COLORMAP = "inferno"
#: Camera distance of the geometry renders (mm; the data's rig is about this far).
RENDER_DISTANCE_MM = 600.0


# ---------------------------------------------------------------------------------------------------------------
# Output


def save_figure(fig, png_path: str | Path) -> tuple[Path, Path]:
    """Write ``fig`` as PNG (150 dpi) and as PDF beside it (same stem), each atomically; closes the figure."""
    import matplotlib.pyplot as plt

    png = Path(png_path)
    pdf = png.with_suffix(".pdf")
    try:
        # both land or neither does
        with atomic_path(png) as tmp_png, atomic_path(pdf) as tmp_pdf:
            fig.savefig(tmp_png, format="png", dpi=150, bbox_inches="tight")
            fig.savefig(tmp_pdf, format="pdf", bbox_inches="tight")
    finally:
        plt.close(fig)
    return png, pdf


def set_title(fig, text: str, fontsize: float = 10) -> None:
    """A figure title just above the panels' own titles (0.35 inch above the top, whatever the height)."""
    fig.suptitle(text, fontsize=fontsize, y=1.0 + 0.35 / fig.get_figheight())


#: Height kept above a grid for its panels' titles (two lines), inches.
TITLE_ROOM_IN = 0.4


def new_grid(rows: int, cols: int, panel_in: float = 2.2, aspects=None, right_in: float = 0.0):
    """A figure with a ``rows x cols`` grid of image axes (ticks off); returns (fig, axes[rows][cols]).

    Args:
        panel_in: height of a row (and width of a square cell), inches.
        aspects: per column, the width / height of the images it shows; the cells take that shape, so
            images that are not square fill them (None = square cells).
        right_in: a strip this wide (inches) kept free right of the grid, e.g. for a colour bar.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    widths = [1.0] * cols if aspects is None else [float(a) for a in aspects]
    width = panel_in * sum(widths) + right_in
    fig, axes = plt.subplots(rows, cols, figsize=(width, panel_in * rows), squeeze=False,
                             gridspec_kw={"width_ratios": widths})
    # room for the panels' titles only above the grid (set_title puts the figure's title above that)
    fig.subplots_adjust(top=1.0 - TITLE_ROOM_IN / (panel_in * rows), right=1.0 - right_in / width)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_visible(False)
    return fig, axes


def read_vertex_values(path: str | Path, key: str, n: int, what: str) -> np.ndarray:
    """(n,) float64 per-vertex values ``key`` of a metrics detail ``.npz`` (written by ``gpja metrics``).

    Raises:
        InputError: a missing or corrupt file, no such array, or not one value per vertex (``what``: "scan
        errors" or "vertex errors", the mesh they belong to being named in the message).
    """
    from gpja.errors import InputError
    from gpja.io import read_npz

    arrays = read_npz(path)
    if key not in arrays:
        raise InputError(path, f"no {key!r} array (written by `gpja metrics`)")
    values = np.asarray(arrays[key], dtype=np.float64)
    if values.shape != (n,):
        raise InputError(path, f"has {values.shape[0]} {what} but the mesh has {n} vertices; re-run the metrics step")
    return values


# ---------------------------------------------------------------------------------------------------------------
# Cameras and renders of geometry


def frontal_camera(points: np.ndarray, size: int, distance_mm: float = RENDER_DISTANCE_MM,
                   margin: float = 1.12) -> Camera:
    """A pinhole camera looking at the points from the front (+Z), framing their x-y extent.

    :func:`gpja.camera.framing_camera` at yaw 0, named "frontal".

    Args:
        points: (n, 3) float positions in the canonical head frame, mm.
        size: image side (px).
    Returns:
        an undistorted ``size x size`` camera, y up in the world = up in the image.
    """
    return framing_camera(points, size, yaw_deg=0.0, distance_mm=distance_mm, margin=margin, name="frontal")


@dataclass
class SurfaceRender:
    """A one-view render of a surface.

    Attributes:
        shade: (H, W) float headlight Lambertian shading in [0, 1] (0 where empty).
        coverage: (H, W) bool covered pixels.
        values: (H, W, C) interpolated per-vertex values (None if none were given).
        color: (H, W, 3) textured albedo (None without a texture).
    """

    shade: np.ndarray
    coverage: np.ndarray
    values: np.ndarray | None = None
    color: np.ndarray | None = None


def render_surface(V: np.ndarray, F: np.ndarray, camera: Camera, vertex_values: np.ndarray | None = None,
                   uv: np.ndarray | None = None, uv_faces: np.ndarray | None = None,
                   texture: np.ndarray | None = None, render: Callable | None = None) -> SurfaceRender:
    """Render a mesh into one view for figures (no antialiasing, no gradients).

    Args:
        V: (n, 3) float vertices, mm. F: (m, 3) int faces.
        vertex_values: (n,) or (n, C) float values interpolated over the surface (e.g. errors, mm).
        uv, uv_faces, texture: (k, 2) UVs, (m, 3) UV faces and a (T, T, 3) albedo: fills ``color``.
        render: a backend's ``render_views`` (``gpja.render.renderer``); None = the CPU renderer. Per-vertex
            values are interpolated through the CPU rasteriser's fragments, which nvdiffrast does not return:
            a render with ``vertex_values`` always runs on the CPU.
    """
    import torch

    from gpja.lighting import uniform_sh
    from gpja.render import Topology, interpolate_rows, render_views, scatter_to_image

    if render is None or vertex_values is not None:
        render = render_views
    textured = texture is not None and uv is not None and uv_faces is not None
    topo = Topology(torch.from_numpy(np.asarray(F, dtype=np.int64)),
                    torch.from_numpy(np.asarray(uv_faces, dtype=np.int64)) if textured else None)
    with torch.no_grad():
        Vt = torch.from_numpy(np.asarray(V, dtype=np.float32))
        passes = ("normal", "color") if textured else ("normal",)
        extra = dict(uv=torch.from_numpy(np.asarray(uv, dtype=np.float32)),
                     texture=torch.from_numpy(np.asarray(texture, dtype=np.float32)),
                     sh=torch.from_numpy(uniform_sh(1.0).astype(np.float32))) if textured else {}
        out = render(Vt, topo, [camera], passes, antialias_edges=False, **extra)
        coverage = out.dense("coverage")[0, ..., 0].numpy() > 0.5
        normals = out.dense("normal")[0].numpy()
        towards_camera = -camera.R[2]  # a headlight: light comes from the camera
        shade = np.where(coverage, 0.15 + 0.85 * np.clip(normals @ towards_camera, 0.0, 1.0), 0.0)
        values = None
        if vertex_values is not None:
            attr = torch.from_numpy(np.asarray(vertex_values, dtype=np.float32).reshape(len(V), -1))
            frags = out.fragments
            values = scatter_to_image(interpolate_rows(attr, frags.bary, frags.corners), frags)[0].numpy()
        color = np.clip(out.dense("color")[0].numpy(), 0.0, 1.0) if textured else None
    return SurfaceRender(shade.astype(np.float32), coverage, values, color)


def shaded_image(render: SurfaceRender, background: float = 1.0) -> np.ndarray:
    """(H, W, 3) grey shading on a ``background`` grey."""
    grey = np.where(render.coverage, render.shade, background)
    return np.repeat(grey[..., None], 3, axis=-1)


def heatmap_image(render: SurfaceRender, max_value: float, background: float = 1.0) -> np.ndarray:
    """(H, W, 3) ``HEATMAP_COLORMAP`` of the rendered values over [0, max_value], modulated by shading."""
    import matplotlib

    colours = matplotlib.colormaps[HEATMAP_COLORMAP](np.clip(render.values[..., 0] / max_value, 0.0, 1.0))[..., :3]
    lit = colours * (0.35 + 0.65 * render.shade[..., None])
    return np.where(render.coverage[..., None], lit, background)


def crop_to_coverage(images: Sequence[np.ndarray], coverage: np.ndarray, margin: int = 8) -> list[np.ndarray]:
    """The images cropped to ``coverage``'s bounding box (grown by ``margin`` px); all if nothing is covered."""
    if not coverage.any():
        return list(images)
    rows, cols = np.flatnonzero(coverage.any(axis=1)), np.flatnonzero(coverage.any(axis=0))
    r0, r1 = max(rows[0] - margin, 0), min(rows[-1] + 1 + margin, coverage.shape[0])
    c0, c1 = max(cols[0] - margin, 0), min(cols[-1] + 1 + margin, coverage.shape[1])
    return [img[r0:r1, c0:c1] for img in images]
