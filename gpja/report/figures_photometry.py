"""Figures of appearance in one of the data's views: photometric errors, close-ups, the mask ablation.

- ``photometric_errors``: per expression, the reference image, the render with the shared texture and
  their L1 error (paper Fig. "photometric errors"; ``metrics/{expression}/render|l1/{view}.png``).
- ``closeups``: eyes and mouth of the reference and the render, and a checkerboard that alternates the
  two, where any misalignment shows as a break at the squares' edges (paper Fig. "close-up views").
- ``ablation_mask``: the mouth socket (the rendered mask B) over the reference image, with and without
  the mask operation.

The view is ``figures.view`` or the most frontal one. Each ``draw_*`` takes a
:class:`~gpja.report.figures.FigureRequest` and returns the matplotlib figure.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from gpja.camera import Camera
from gpja.errors import InputError
from gpja.io import read_image
from gpja.methods import label
from gpja.camera import most_frontal_view
from gpja.report.drawing import crop_to_coverage, new_grid, set_title
from gpja.report.figures import FigureRequest, FigureSettings, RunFiles

#: Feature boxes in the canonical head frame relative to the mouth centre (mm): centre offset, width, height.
#: Adult faces put the eyes 60-75 mm above the mouth (the synthetic heads too); the boxes leave slack.
EYES_BOX_MM = ((0.0, 68.0, 0.0), 120.0, 50.0)
MOUTH_BOX_MM = ((0.0, -2.0, 0.0), 80.0, 50.0)
#: Squares per crop height in the checkerboard close-ups.
CHECKER_SQUARES = 5
#: Reds the mouth socket is painted with in the mask ablation (RGB, opacity).
SOCKET_COLOUR, SOCKET_ALPHA = (1.0, 0.1, 0.1), 0.55


def load_view(files: RunFiles, subject: str, expression: str, view: str | None):
    """``(camera, reference image (H, W, 3) float [0, 1], view name)`` of one (or the most frontal) view."""
    data = files.data.load(subject, expression, with_scan=False)
    names = [v.name for v in data.views]
    if view is not None and view not in names:
        raise InputError("figures.view", f"view {view!r} is not among the expression's views {names}")
    index = names.index(view) if view is not None else most_frontal_view(data.cameras)
    image = np.asarray(data.images[index], dtype=np.float32)
    if image.max() > 1.0:
        image = image / 255.0
    return data.cameras[index], image, names[index]


def view_entry(record: dict, view: str, source) -> dict:
    """The per-view photometric entry of ``view`` in a metrics JSON (``source``: its path, for errors)."""
    for entry in (record.get("photometric") or {}).get("per_view", []):
        if str(entry.get("view")) == view:
            return entry
    raise InputError(source, f"no photometric scores for view {view!r}; was the mesh scored with photometric: true?")


def photometric_panels(files: RunFiles, subject: str, method: str, expression: str, settings: FigureSettings):
    """``(reference, render, L1 image, coverage, camera, view entry)`` of one expression's chosen view."""
    camera, reference, view = load_view(files, subject, expression, settings.view)
    details = files.layout.metrics_details(subject, method, expression)
    entry = view_entry(files.metrics(subject, method, expression), view,
                       files.layout.metrics(subject, method, expression))
    render = read_image(details / entry["render"])
    l1 = read_image(details / entry["error_image"])
    if render.shape != reference.shape:
        raise InputError(details / entry["render"], f"render {render.shape} and reference {reference.shape} differ")
    coverage = render.max(axis=-1) > 0
    return reference, render, l1, coverage, camera, entry


def mouth_centre(mesh, mask: np.ndarray) -> np.ndarray:
    """(3,) mean position (mm) of the mesh's mouth-socket vertices: faces whose UV centre lies where B = 0.

    Args:
        mesh: a textured mesh (``V`` mm, ``F``, ``UV``, ``F_uv``).
        mask: (T, T) float mouth mask B in [0, 1] (0 = socket).
    """
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


def template_mouth(files: RunFiles, subject: str) -> tuple[np.ndarray, np.ndarray]:
    """``(mouth mask B (T, T) float, mouth centre (3,) mm)`` of the subject's template."""
    from gpja.mesh import read_obj

    layout = files.layout
    mask = read_image(layout.template_file(subject, "mouth_mask.png"), mode="L")
    template = read_obj(layout.template_file(subject, "template.obj"), load_texture=False)
    return mask, mouth_centre(template, mask)


def draw_photometric_errors(request: FigureRequest):
    """Columns: the shared texture, then expressions; rows: reference, render with the shared texture, L1 error."""
    import matplotlib

    from gpja.metrics.photometric import ERROR_COLORMAP, ERROR_SCALE

    files, subject, method, expressions = request.files, request.subject, request.method, request.expressions
    fig, axes = new_grid(3, len(expressions) + 1)
    axes[1][0].imshow(read_image(files.layout.template_file(subject, "texture.png")))
    axes[1][0].set_title("shared texture", fontsize=8)
    for i, name in enumerate(("reference", f"{label(method)} render", "L1 error")):
        axes[i][1].set_ylabel(name, fontsize=8)
    for j, expression in enumerate(expressions, start=1):
        reference, render, l1, coverage, _, entry = photometric_panels(files, subject, method, expression,
                                                                       request.settings)
        for i, img in enumerate(crop_to_coverage([reference, render, l1], coverage, margin=12)):
            axes[i][j].imshow(np.clip(img, 0, 1))
        axes[0][j].set_title(f"{expression}\nview {entry['view']}", fontsize=8)
        axes[2][j].text(0.03, 0.03, f"PSNR {entry['psnr']:.2f} dB", transform=axes[2][j].transAxes, fontsize=7,
                        color="white")
    mappable = matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(0.0, ERROR_SCALE), ERROR_COLORMAP)
    bar = fig.colorbar(mappable, ax=axes[2].tolist(), shrink=0.9, pad=0.01)
    bar.set_label("mean |render - reference| (RGB, [0, 1])", fontsize=7)
    set_title(fig, f"Photometric error of {label(method)}, subject {subject}", fontsize=10)
    return fig


def draw_closeups(request: FigureRequest):
    """Per expression: eyes and mouth of the reference, the render, and the checkerboard of the two."""
    files, subject, method, expressions = request.files, request.subject, request.method, request.expressions
    # boxes anchored on the template's mouth (the same head frame for every expression), not on the
    # registered mesh, whose socket may be misplaced: that is what the figure is to show
    _, centre = template_mouth(files, subject)
    # cells shaped like the boxes (mm), so the crops fill them
    aspects = [box[1] / box[2] for box in (EYES_BOX_MM, MOUTH_BOX_MM) for _ in range(3)]
    fig, axes = new_grid(len(expressions), 6, panel_in=1.2, aspects=aspects)
    titles = ["eyes: reference", "eyes: render", "eyes: checkerboard", "mouth: reference", "mouth: render",
              "mouth: checkerboard"]
    for i, expression in enumerate(expressions):
        reference, render, _, _, camera, entry = photometric_panels(files, subject, method, expression,
                                                                    request.settings)
        for k, box in enumerate((EYES_BOX_MM, MOUTH_BOX_MM)):
            rows, cols = feature_crop(camera, centre, box)
            ref, ren = reference[rows, cols], render[rows, cols]
            for m, img in enumerate((ref, ren, checkerboard(ref, ren))):
                axes[i][3 * k + m].imshow(np.clip(img, 0, 1))
        axes[i][0].set_ylabel(f"{expression}\nview {entry['view']}", fontsize=7)
    for j, title in enumerate(titles):
        axes[0][j].set_title(title, fontsize=7)
    set_title(fig, f"Close-ups, {label(method)} render vs reference, subject {subject} "
                 "(checkerboard: alternating render / reference squares)", fontsize=9)
    return fig


def socket_overlay(files: RunFiles, subject: str, method: str, expression: str, camera: Camera,
                   reference: np.ndarray, mask: np.ndarray, render: Callable | None = None) -> np.ndarray:
    """The reference image (H, W, 3) with the method's rendered mouth socket (B = 0) painted over it.

    ``render``: a backend's ``render_views`` (None = the CPU renderer).
    """
    import torch

    from gpja.mesh import read_obj
    from gpja.render import Topology, render_views

    path = files.layout.registration(subject, method, expression)
    mesh = read_obj(path, load_texture=False)
    if not mesh.has_uv:
        raise InputError(path, "no texture coordinates")
    with torch.no_grad():
        out = (render or render_views)(torch.from_numpy(mesh.V.astype(np.float32)),
                                       Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv)), [camera],
                                       ("mask",), uv=torch.from_numpy(mesh.UV.astype(np.float32)),
                                       mask_texture=torch.from_numpy(mask[..., None].astype(np.float32)),
                                       antialias_edges=False)
        covered = out.dense("coverage")[0, ..., 0].numpy() > 0.5
        socket = covered & (out.dense("mask")[0, ..., 0].numpy() < 0.5)
    alpha = SOCKET_ALPHA * socket[..., None]
    return reference * (1 - alpha) + np.asarray(SOCKET_COLOUR) * alpha


def draw_ablation_mask(request: FigureRequest):
    """Per expression: the mouth of the reference with the rendered socket of each method (GPJA, GPJA
    without the mask)."""
    files, subject, expressions = request.files, request.subject, request.expressions
    columns = list(request.methods)
    mask, centre = template_mouth(files, subject)
    fig, axes = new_grid(len(expressions), len(columns) + 1, panel_in=2.6)
    for i, expression in enumerate(expressions):
        camera, reference, view = load_view(files, subject, expression, request.settings.view)
        rows, cols = feature_crop(camera, centre, MOUTH_BOX_MM)
        axes[i][0].imshow(reference[rows, cols])
        for j, method in enumerate(columns, start=1):
            overlay = socket_overlay(files, subject, method, expression, camera, reference, mask, request.render)
            axes[i][j].imshow(np.clip(overlay[rows, cols], 0, 1))
            psnr = files.metrics(subject, method, expression)["photometric"]["psnr"]
            axes[i][j].set_title(f"{label(method)}\nPSNR {psnr:.2f} dB", fontsize=8)
        axes[i][0].set_title("reference" if i == 0 else "", fontsize=8)
        axes[i][0].set_ylabel(f"{expression}\nview {view}", fontsize=8)
    set_title(fig, f"Ablation: the mouth socket (red) with and without the mask, subject {subject}", fontsize=10)
    return fig
