"""The paper's figures, drawn with matplotlib from a finished run's files (each as PNG and PDF).

Every figure reads what earlier steps wrote; nothing is re-optimised:

- ``template_stages``: the template-creation pipeline (paper Fig. "template creation"): the genus-0 bust,
  the fitted dense mesh with its reconstructed texture, the decimated template, its texture map and the
  mouth mask B (``{results}/{subject}/template/``).
- ``geometric_errors``: per expression and method, the scan rendered frontally and coloured by the
  distance of each scan vertex to the method's mesh (the paper's "point (of GT) to mesh" error), one
  shared colour bar in mm (``metrics/{expression}/geometry_errors.npz``).
- ``photometric_errors``: per expression, the reference image, the render with the shared texture and
  their L1 error (paper Fig. "photometric errors"; ``metrics/{expression}/render|l1/{view}.png``).
- ``closeups``: eyes and mouth of the reference and the render, and a checkerboard that alternates the
  two, where any misalignment shows as a break at the squares' edges (paper Fig. "close-up views").
- ``ablation_normal``: shaded renders of the scan, GPJA and GPJA without the normal constraint.
- ``ablation_mask``: the mouth socket (the rendered mask B) over the reference image, with and without
  the mask operation.
- ``convergence``: each constraint's loss against the iteration, per expression, levels marked.

Renders of geometry use a frontal pinhole camera framed on the scan in the canonical head frame (face
towards +Z, top towards +Y) and a headlight; photometric figures use one of the data's views.
"""
from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Sequence

import numpy as np

from gpja.camera import Camera
from gpja.errors import InputError
from gpja.io import atomic_path, read_image, read_json, read_npz

FIGURES = ("template_stages", "geometric_errors", "photometric_errors", "closeups", "ablation_normal",
           "ablation_mask", "convergence")
#: Colour map of the geometric-error heatmaps (perceptually ordered, dark = small).
HEATMAP_COLORMAP = "inferno"
#: Camera distance of the geometry renders (mm; the data's rig is about this far).
RENDER_DISTANCE_MM = 600.0
#: Feature boxes in the canonical head frame relative to the mouth centre (mm): centre offset, width, height.
#: Adult faces put the eyes 60-75 mm above the mouth (the synthetic heads too); the boxes leave slack.
EYES_BOX_MM = ((0.0, 68.0, 0.0), 120.0, 50.0)
MOUTH_BOX_MM = ((0.0, -2.0, 0.0), 80.0, 50.0)
#: Squares per crop height in the checkerboard close-ups.
CHECKER_SQUARES = 5
#: Reds the mouth socket is painted with in the mask ablation (RGB, opacity).
SOCKET_COLOUR, SOCKET_ALPHA = (1.0, 0.1, 0.1), 0.55
CONSTRAINT_LABELS = {"color": r"$\mathcal{L}_{color}$", "depth": r"$\mathcal{L}_{depth}$",
                     "normal": r"$\mathcal{L}_{normal}$"}


@dataclass(frozen=True)
class FigureSettings:
    """The ``figures`` section of the config.

    Attributes:
        view: the data view of photometric figures; None = the most frontal one.
        heatmap_max_mm: top of the geometric-error colour bar (mm).
        render_size: side of the geometry renders (px).
    """

    view: str | None = None
    heatmap_max_mm: float = 1.0
    render_size: int = 512

    @classmethod
    def from_config(cls, cfg: dict | None) -> "FigureSettings":
        cfg = dict(cfg or {})
        unknown = set(cfg) - {f.name for f in fields(cls)}
        if unknown:
            raise InputError("--settings", f"unknown figure settings {sorted(unknown)}")
        return cls(**cfg)


@dataclass(frozen=True)
class RunFiles:
    """Where a run's files are: ``results/{dataset}`` and the dataset's roots (as the workflow passes them)."""

    results: Path
    images_root: Path | None = None
    scans_root: Path | None = None
    rt_scale: Path | None = None
    views: Sequence[str] | None = None
    cache_dir: Path | None = None
    max_image_size: int | None = None

    def metrics(self, subject: str, method: str, expression: str) -> dict:
        return read_json(self.results / subject / method / "metrics" / f"{expression}.json")

    def details(self, subject: str, method: str, expression: str) -> Path:
        return self.results / subject / method / "metrics" / expression

    def mesh(self, subject: str, method: str, expression: str) -> Path:
        return self.results / subject / method / f"{expression}.obj"

    def template_dir(self, subject: str) -> Path:
        return self.results / subject / "template"


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


def new_grid(rows: int, cols: int, panel_in: float = 2.2):
    """A figure with a ``rows x cols`` grid of image axes (ticks off); returns (fig, axes[rows][cols])."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(rows, cols, figsize=(panel_in * cols, panel_in * rows), squeeze=False)
    for ax in axes.ravel():
        ax.set_xticks([])
        ax.set_yticks([])
        for spine in ax.spines.values():
            spine.set_visible(False)
    return fig, axes


# ---------------------------------------------------------------------------------------------------------------
# Cameras and renders of geometry


def frontal_camera(points: np.ndarray, size: int, distance_mm: float = RENDER_DISTANCE_MM,
                   margin: float = 1.12) -> Camera:
    """A pinhole camera looking at the points from the front (+Z), framing their x-y extent.

    Args:
        points: (n, 3) float positions in the canonical head frame, mm.
        size: image side (px).
    Returns:
        an undistorted ``size x size`` camera, y up in the world = up in the image.
    """
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0 or not np.isfinite(points).all():
        raise ValueError("frontal_camera needs finite points")
    lo, hi = np.percentile(points, [0.5, 99.5], axis=0)
    centre = (lo + hi) / 2.0
    half = max(hi[0] - lo[0], hi[1] - lo[1]) / 2.0 * margin
    depth = distance_mm + (hi[2] - centre[2])
    focal = (size / 2.0) * depth / max(half, 1e-6)
    K = np.array([[focal, 0.0, (size - 1) / 2.0], [0.0, focal, (size - 1) / 2.0], [0.0, 0.0, 1.0]])
    eye = np.array([centre[0], centre[1], hi[2] + distance_mm])
    return Camera.look_at(eye, centre, (0.0, 1.0, 0.0), K, size, size, name="frontal")


def most_frontal_view(cameras: Sequence[Camera]) -> int:
    """Index of the camera looking most directly at the face (its optical axis closest to -Z)."""
    return int(np.argmin([cam.R[2, 2] for cam in cameras]))


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
                   texture: np.ndarray | None = None) -> SurfaceRender:
    """Render a mesh into one view for figures (no antialiasing, no gradients).

    Args:
        V: (n, 3) float vertices, mm. F: (m, 3) int faces.
        vertex_values: (n,) or (n, C) float values interpolated over the surface (e.g. errors, mm).
        uv, uv_faces, texture: (k, 2) UVs, (m, 3) UV faces and a (T, T, 3) albedo: fills ``color``.
    """
    import torch

    from gpja.lighting import uniform_sh
    from gpja.render import Topology, interpolate_rows, render_views, scatter_to_image

    textured = texture is not None and uv is not None and uv_faces is not None
    topo = Topology(torch.from_numpy(np.asarray(F, dtype=np.int64)),
                    torch.from_numpy(np.asarray(uv_faces, dtype=np.int64)) if textured else None)
    with torch.no_grad():
        Vt = torch.from_numpy(np.asarray(V, dtype=np.float32))
        passes = ("normal", "color") if textured else ("normal",)
        extra = dict(uv=torch.from_numpy(np.asarray(uv, dtype=np.float32)),
                     texture=torch.from_numpy(np.asarray(texture, dtype=np.float32)),
                     sh=torch.from_numpy(uniform_sh(1.0).astype(np.float32))) if textured else {}
        out = render_views(Vt, topo, [camera], passes, antialias_edges=False, **extra)
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


# ---------------------------------------------------------------------------------------------------------------
# Data access


def load_scan_mm(files: RunFiles, subject: str, expression: str):
    """The expression's scan in the aligned frame (mm) as read by every other step."""
    from gpja.data.facescape import read_rt_scale, read_scan, scan_path

    if files.scans_root is None:
        raise InputError("--scans-root", "this figure needs the scans")
    scale, R, t = read_rt_scale(files.rt_scale, subject, expression) if files.rt_scale else (1.0, None, None)
    return read_scan(scan_path(files.scans_root, subject, expression), scale, R, t)


def load_view(files: RunFiles, subject: str, expression: str, view: str | None):
    """``(camera, reference image (H, W, 3) float [0, 1], view name)`` of one (or the most frontal) view."""
    from gpja.data.facescape import load_expression

    if files.images_root is None:
        raise InputError("--images-root", "this figure needs the reference images")
    data = load_expression(files.images_root, subject, expression, views=files.views, scans_root=None,
                           rt_scale_path=files.rt_scale, cache_dir=files.cache_dir,
                           max_image_size=files.max_image_size)
    names = [v.name for v in data.views]
    if view is not None and view not in names:
        raise InputError("figures.view", f"view {view!r} is not among the expression's views {names}")
    index = names.index(view) if view is not None else most_frontal_view(data.cameras)
    image = np.asarray(data.images[index], dtype=np.float32)
    if image.max() > 1.0:
        image = image / 255.0
    return data.cameras[index], image, names[index]


def scan_errors(files: RunFiles, subject: str, method: str, expression: str, n_scan: int) -> np.ndarray:
    """(n_scan,) float64 distance (mm) of every scan vertex to the method's mesh, from ``gpja metrics``."""
    path = files.details(subject, method, expression) / "geometry_errors.npz"
    errors = read_npz(path)
    if "scan_vertex_error_mm" not in errors:
        raise InputError(path, "no 'scan_vertex_error_mm' array (written by `gpja metrics`)")
    values = np.asarray(errors["scan_vertex_error_mm"], dtype=np.float64)
    if values.shape != (n_scan,):
        raise InputError(path, f"has {values.shape[0]} scan errors but the scan has {n_scan} vertices; "
                               "re-run the metrics step")
    return values


def method_label(method: str) -> str:
    from gpja.report.tables import method_label as label

    return label(method)


# ---------------------------------------------------------------------------------------------------------------
# Figures


def plot_template_stages(files: RunFiles, subject: str, settings: FigureSettings, output: str | Path):
    """Bust -> fitted dense mesh with texture -> decimated template; its texture map and mouth mask B."""
    from gpja.mesh import read_obj

    d = files.template_dir(subject)
    bust = read_obj(d / "stages" / "bust.obj", load_texture=False)
    fitted = read_obj(d / "stages" / "fitted.obj")
    template = read_obj(d / "template.obj")
    texture = read_image(d / "texture.png")
    mask = read_image(d / "mouth_mask.png", mode="L")
    camera = frontal_camera(np.concatenate([fitted.V, bust.V]), settings.render_size)
    panels = [("(a) genus-0 bust", bust), ("(b) fitted, textured", fitted), ("(c) template", template)]
    fig, axes = new_grid(1, 5, panel_in=2.6)
    for ax, (title, mesh) in zip(axes[0], panels):
        r = render_surface(mesh.V, mesh.F, camera, uv=mesh.UV, uv_faces=mesh.F_uv, texture=mesh.texture)
        img = (np.where(r.coverage[..., None], r.color * (0.45 + 0.55 * r.shade[..., None]), 1.0)
               if r.color is not None else shaded_image(r))
        ax.imshow(np.clip(img, 0, 1))
        ax.set_title(f"{title}\n{len(mesh.V):,} vertices, {len(mesh.F):,} faces", fontsize=8)
    axes[0][3].imshow(texture)
    axes[0][3].set_title(r"texture $\mathbf{C}_T$" + f" ({texture.shape[1]}²)", fontsize=8)
    axes[0][4].imshow(mask, cmap="gray", vmin=0, vmax=1)
    axes[0][4].set_title("mouth mask B (black: socket)", fontsize=8)
    for spine in axes[0][4].spines.values():
        spine.set_visible(True)
    set_title(fig, f"Template creation, subject {subject}", fontsize=10)
    return save_figure(fig, output)


def plot_geometric_errors(files: RunFiles, subject: str, methods: Sequence[str], expressions: Sequence[str],
                          settings: FigureSettings, output: str | Path):
    """Rows: expressions; columns: methods; the scan coloured by its distance to each method's mesh."""
    import matplotlib

    fig, axes = new_grid(len(expressions), len(methods))
    for i, expression in enumerate(expressions):
        scan = load_scan_mm(files, subject, expression)
        camera = frontal_camera(scan.V, settings.render_size)
        for j, method in enumerate(methods):
            errors = scan_errors(files, subject, method, expression, len(scan.V))
            r = render_surface(scan.V, scan.F, camera, vertex_values=errors)
            ax = axes[i][j]
            ax.imshow(crop_to_coverage([heatmap_image(r, settings.heatmap_max_mm)], r.coverage)[0])
            ax.text(0.03, 0.03, f"mean {errors.mean():.3f} mm", transform=ax.transAxes, fontsize=7,
                    color="black", bbox=dict(facecolor="white", alpha=0.7, lw=0, pad=1))
            if i == 0:
                ax.set_title(method_label(method), fontsize=9)
            if j == 0:
                ax.set_ylabel(expression, fontsize=8)
    mappable = matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(0.0, settings.heatmap_max_mm),
                                            HEATMAP_COLORMAP)
    bar = fig.colorbar(mappable, ax=axes.ravel().tolist(), shrink=0.8, pad=0.02)
    bar.set_label(f"scan-to-mesh distance (mm, clipped at {settings.heatmap_max_mm:g})")
    set_title(fig, f"Geometric error, subject {subject}", fontsize=10)
    return save_figure(fig, output)


def view_entry(record: dict, view: str, source: Path) -> dict:
    for entry in (record.get("photometric") or {}).get("per_view", []):
        if str(entry.get("view")) == view:
            return entry
    raise InputError(source, f"no photometric scores for view {view!r}; was the mesh scored with photometric: true?")


def photometric_panels(files: RunFiles, subject: str, method: str, expression: str, settings: FigureSettings):
    """``(reference, render, L1 image, coverage, camera, view entry)`` of one expression's chosen view."""
    camera, reference, view = load_view(files, subject, expression, settings.view)
    details = files.details(subject, method, expression)
    entry = view_entry(files.metrics(subject, method, expression), view,
                       files.results / subject / method / "metrics" / f"{expression}.json")
    render = read_image(details / entry["render"])
    l1 = read_image(details / entry["error_image"])
    if render.shape != reference.shape:
        raise InputError(details / entry["render"], f"render {render.shape} and reference {reference.shape} differ")
    coverage = render.max(axis=-1) > 0
    return reference, render, l1, coverage, camera, entry


def plot_photometric_errors(files: RunFiles, subject: str, method: str, expressions: Sequence[str],
                            settings: FigureSettings, output: str | Path):
    """Columns: the shared texture, then expressions; rows: reference, render with the shared texture, L1 error."""
    import matplotlib

    from gpja.metrics.photometric import ERROR_COLORMAP, ERROR_SCALE

    fig, axes = new_grid(3, len(expressions) + 1)
    axes[1][0].imshow(read_image(files.template_dir(subject) / "texture.png"))
    axes[1][0].set_title("shared texture", fontsize=8)
    for i, name in enumerate(("reference", f"{method_label(method)} render", "L1 error")):
        axes[i][1].set_ylabel(name, fontsize=8)
    for j, expression in enumerate(expressions, start=1):
        reference, render, l1, coverage, _, entry = photometric_panels(files, subject, method, expression, settings)
        for i, img in enumerate(crop_to_coverage([reference, render, l1], coverage, margin=12)):
            axes[i][j].imshow(np.clip(img, 0, 1))
        axes[0][j].set_title(f"{expression}\nview {entry['view']}", fontsize=8)
        axes[2][j].text(0.03, 0.03, f"PSNR {entry['psnr']:.2f} dB", transform=axes[2][j].transAxes, fontsize=7,
                        color="white")
    mappable = matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(0.0, ERROR_SCALE), ERROR_COLORMAP)
    bar = fig.colorbar(mappable, ax=axes[2].tolist(), shrink=0.9, pad=0.01)
    bar.set_label("mean |render - reference| (RGB, [0, 1])", fontsize=7)
    set_title(fig, f"Photometric error of {method_label(method)}, subject {subject}", fontsize=10)
    return save_figure(fig, output)


def mouth_centre(mesh, mask: np.ndarray) -> np.ndarray:
    """(3,) mean position (mm) of the mesh's mouth-socket vertices: faces whose UV centre lies where B = 0."""
    import torch

    from gpja.render.texture import sample_texture

    centre_uv = mesh.UV[mesh.F_uv].mean(axis=1)
    with torch.no_grad():
        b = sample_texture(torch.from_numpy(mask[..., None].astype(np.float32)),
                           torch.from_numpy(centre_uv.astype(np.float32)))[:, 0].numpy()
    socket = np.unique(mesh.F[b < 0.5])
    if len(socket) == 0:
        raise InputError("mouth_mask.png", "the mask marks no mouth socket on the mesh")
    return mesh.V[socket].mean(axis=0)


def feature_crop(camera: Camera, centre: np.ndarray, box) -> tuple[slice, slice]:
    """Pixel rows/columns of a box ``(offset, width, height)`` mm around ``centre`` in the head frame."""
    offset, width, height = box
    c = np.asarray(centre) + np.asarray(offset)
    corners = np.array([[c[0] + sx * width / 2, c[1] + sy * height / 2, c[2]] for sx in (-1, 1) for sy in (-1, 1)])
    px, _ = camera.project(corners)
    x0, y0 = np.floor(px.min(axis=0)).astype(int)
    x1, y1 = np.ceil(px.max(axis=0)).astype(int)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1, camera.width), min(y1, camera.height)
    if x1 - x0 < 4 or y1 - y0 < 4:
        raise ValueError("the feature box falls outside the view")
    return slice(y0, y1), slice(x0, x1)


def checkerboard(reference: np.ndarray, render: np.ndarray, squares: int = CHECKER_SQUARES) -> np.ndarray:
    """(H, W, 3) alternating squares of ``render`` (even) and ``reference`` (odd); ``squares`` per height."""
    h, w = reference.shape[:2]
    side = max(h // squares, 1)
    yy, xx = np.mgrid[0:h, 0:w]
    even = ((yy // side + xx // side) % 2) == 0
    return np.where(even[..., None], render, reference)


def plot_closeups(files: RunFiles, subject: str, method: str, expressions: Sequence[str],
                  settings: FigureSettings, output: str | Path):
    """Per expression: eyes and mouth of the reference, the render, and the checkerboard of the two."""
    from gpja.mesh import read_obj

    mask = read_image(files.template_dir(subject) / "mouth_mask.png", mode="L")
    # boxes anchored on the template's mouth (the same head frame for every expression), not on the
    # registered mesh, whose socket may be misplaced: that is what the figure is to show
    centre = mouth_centre(read_obj(files.template_dir(subject) / "template.obj", load_texture=False), mask)
    fig, axes = new_grid(len(expressions), 6, panel_in=1.9)
    titles = ["eyes: reference", "eyes: render", "eyes: checkerboard", "mouth: reference", "mouth: render",
              "mouth: checkerboard"]
    for i, expression in enumerate(expressions):
        reference, render, _, _, camera, entry = photometric_panels(files, subject, method, expression, settings)
        for k, box in enumerate((EYES_BOX_MM, MOUTH_BOX_MM)):
            rows, cols = feature_crop(camera, centre, box)
            ref, ren = reference[rows, cols], render[rows, cols]
            for m, img in enumerate((ref, ren, checkerboard(ref, ren))):
                axes[i][3 * k + m].imshow(np.clip(img, 0, 1))
        axes[i][0].set_ylabel(f"{expression}\nview {entry['view']}", fontsize=7)
    for j, title in enumerate(titles):
        axes[0][j].set_title(title, fontsize=7)
    set_title(fig, f"Close-ups, {method_label(method)} render vs reference, subject {subject} "
                 "(checkerboard: alternating render / reference squares)", fontsize=9)
    return save_figure(fig, output)


def plot_ablation_normal(files: RunFiles, subject: str, expressions: Sequence[str], settings: FigureSettings,
                         output: str | Path, variant: str = "gpja-no_normal"):
    """Per expression: the scan, GPJA and GPJA without the normal constraint, shaded (detail, bumps)."""
    from gpja.mesh import read_obj

    columns = ["scan", "gpja", variant]
    fig, axes = new_grid(len(expressions), len(columns), panel_in=2.8)
    for i, expression in enumerate(expressions):
        scan = load_scan_mm(files, subject, expression)
        camera = frontal_camera(scan.V, settings.render_size)
        reference = render_surface(scan.V, scan.F, camera)
        for j, name in enumerate(columns):
            if name == "scan":
                r, label = reference, "scan"
            else:
                mesh = read_obj(files.mesh(subject, name, expression), load_texture=False)
                r = render_surface(mesh.V, mesh.F, camera)
                geometry = files.metrics(subject, name, expression)["geometry"]
                label = f"{method_label(name)}\nscan-to-mesh {geometry['scan_to_mesh_mm']:.3f} mm"
            axes[i][j].imshow(crop_to_coverage([shaded_image(r)], reference.coverage)[0])
            axes[i][j].set_title(label if i == 0 or name != "scan" else "", fontsize=8)
        axes[i][0].set_ylabel(expression, fontsize=8)
    set_title(fig, f"Ablation: with and without the normal constraint, subject {subject}", fontsize=10)
    return save_figure(fig, output)


def socket_overlay(files: RunFiles, subject: str, method: str, expression: str, camera: Camera,
                   reference: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The reference image with the method's rendered mouth socket (B = 0) painted over it."""
    import torch

    from gpja.mesh import read_obj
    from gpja.render import Topology, render_views

    mesh = read_obj(files.mesh(subject, method, expression), load_texture=False)
    if not mesh.has_uv:
        raise InputError(files.mesh(subject, method, expression), "no texture coordinates")
    with torch.no_grad():
        out = render_views(torch.from_numpy(mesh.V.astype(np.float32)),
                           Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv)), [camera], ("mask",),
                           uv=torch.from_numpy(mesh.UV.astype(np.float32)),
                           mask_texture=torch.from_numpy(mask[..., None].astype(np.float32)),
                           antialias_edges=False)
        covered = out.dense("coverage")[0, ..., 0].numpy() > 0.5
        socket = covered & (out.dense("mask")[0, ..., 0].numpy() < 0.5)
    alpha = SOCKET_ALPHA * socket[..., None]
    return reference * (1 - alpha) + np.asarray(SOCKET_COLOUR) * alpha


def plot_ablation_mask(files: RunFiles, subject: str, expressions: Sequence[str], settings: FigureSettings,
                       output: str | Path, variant: str = "gpja-no_mask"):
    """Per expression: the mouth of the reference with the rendered socket of GPJA and of GPJA without the mask."""
    from gpja.mesh import read_obj

    mask = read_image(files.template_dir(subject) / "mouth_mask.png", mode="L")
    columns = ["gpja", variant]
    centre = mouth_centre(read_obj(files.template_dir(subject) / "template.obj", load_texture=False), mask)
    fig, axes = new_grid(len(expressions), len(columns) + 1, panel_in=2.6)
    for i, expression in enumerate(expressions):
        camera, reference, view = load_view(files, subject, expression, settings.view)
        rows, cols = feature_crop(camera, centre, MOUTH_BOX_MM)
        axes[i][0].imshow(reference[rows, cols])
        for j, method in enumerate(columns, start=1):
            overlay = socket_overlay(files, subject, method, expression, camera, reference, mask)
            axes[i][j].imshow(np.clip(overlay[rows, cols], 0, 1))
            psnr = files.metrics(subject, method, expression)["photometric"]["psnr"]
            axes[i][j].set_title(f"{method_label(method)}\nPSNR {psnr:.2f} dB", fontsize=8)
        axes[i][0].set_title("reference" if i == 0 else "", fontsize=8)
        axes[i][0].set_ylabel(f"{expression}\nview {view}", fontsize=8)
    set_title(fig, f"Ablation: the mouth socket (red) with and without the mask, subject {subject}", fontsize=10)
    return save_figure(fig, output)


def loss_curves(log: dict) -> tuple[dict[str, tuple[np.ndarray, np.ndarray]], list[int]]:
    """``({constraint: (iteration, loss)}, level start iterations)`` of a GPJA registration log.

    One constraint is back-propagated per iteration, in rotation, so each constraint's losses are spread
    evenly over its level's iterations.
    """
    curves: dict[str, list] = {}
    starts, start = [], 0
    for level in log.get("levels") or []:
        starts.append(start)
        n = int(level["iterations"])
        for name, values in (level.get("losses") or {}).items():
            values = np.asarray(values, dtype=np.float64)
            if len(values):
                x = start + (np.arange(len(values)) + 0.5) * n / len(values)
                curves.setdefault(name, []).append((x, values))
        start += n
    return {k: (np.concatenate([x for x, _ in v]), np.concatenate([y for _, y in v])) for k, v in curves.items()}, starts


def plot_convergence(files: RunFiles, subject: str, method: str, expressions: Sequence[str], output: str | Path):
    """One panel per constraint: loss against iteration for every expression; dashed lines where a stage ends
    (the warm-up, when the log has one, then each refinement)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    logs = {e: read_json(files.results / subject / method / f"{e}.json") for e in expressions}
    curves = {e: loss_curves(log) for e, log in logs.items()}
    names = [n for n in ("color", "depth", "normal") if any(n in c for c, _ in curves.values())]
    if not names:
        raise InputError(files.results / subject / method, "the registration logs hold no losses")
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.2), squeeze=False)
    for ax, name in zip(axes[0], names):
        for expression, (c, starts) in curves.items():
            if name in c:
                ax.plot(*c[name], lw=1.0, label=expression)
        for s in next(iter(curves.values()))[1][1:]:
            ax.axvline(s, color="grey", ls="--", lw=0.8)
        ax.set_yscale("log")
        ax.set_xlabel("iteration (dashed: end of warm-up or level)")
        ax.set_title(CONSTRAINT_LABELS.get(name, name), fontsize=10)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("L1 loss (per pixel)")
    axes[0][-1].legend(fontsize=7)
    set_title(fig, f"Convergence of {method_label(method)}, subject {subject}", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, output)


def make_figure(kind: str, files: RunFiles, subject: str, methods: Sequence[str], expressions: Sequence[str],
                settings: FigureSettings, output: str | Path) -> tuple[Path, Path]:
    """Draw figure ``kind`` (one of ``FIGURES``) of one subject into ``output`` (.png) and its .pdf."""
    if Path(output).suffix.lower() != ".png":
        raise InputError(output, "the figure's output must be a .png (the .pdf is written beside it)")
    if not expressions:
        raise InputError("--expressions", "no expressions given")
    method = methods[0] if methods else "gpja"
    if kind == "template_stages":
        return plot_template_stages(files, subject, settings, output)
    if kind == "geometric_errors":
        return plot_geometric_errors(files, subject, methods, expressions, settings, output)
    if kind == "photometric_errors":
        return plot_photometric_errors(files, subject, method, expressions, settings, output)
    if kind == "closeups":
        return plot_closeups(files, subject, method, expressions, settings, output)
    if kind == "ablation_normal":
        return plot_ablation_normal(files, subject, expressions, settings, output)
    if kind == "ablation_mask":
        return plot_ablation_mask(files, subject, expressions, settings, output)
    if kind == "convergence":
        return plot_convergence(files, subject, method, expressions, output)
    raise InputError("figure", f"unknown figure {kind!r}; choose from {', '.join(FIGURES)}")
