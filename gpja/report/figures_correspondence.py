"""The figure of where the correspondence fails (synthetic data): ``correspondence_errors``.

Per expression (rows) and method (columns): the subject's template mesh (its own expression, the one it
was fitted to), rendered frontally and coloured by each vertex's correspondence error against the
synthetic ground truth in that expression (``metrics/{expression}/correspondence_errors.npz``, written by
``gpja metrics``; :mod:`gpja.metrics.correspondence`). Vertices the metric does not score (off the scan,
over holes) are grey. One colour bar for every panel, in mm: from 0 to the 95th percentile of every
scored vertex of the figure, rounded up to a 1-2-5 step, so that the panels compare and a few outliers do
not wash the rest out. Each panel names the median error of its scored vertices and of those in the mouth
region (``correspondence.regions.mouth`` of the metrics JSON).
"""
from __future__ import annotations

import math

import numpy as np

from gpja.methods import label
from gpja.report.drawing import (
    HEATMAP_COLORMAP,
    crop_to_coverage,
    frontal_camera,
    new_grid,
    read_vertex_values,
    render_surface,
    set_title,
)
from gpja.report.figures import FigureRequest, RunFiles

#: Colour of the vertices the correspondence metric does not score.
UNSCORED_RGB = (0.75, 0.75, 0.75)
#: Percentile of the scored errors at the top of the shared colour bar.
TOP_PERCENTILE = 95.0
#: Width of the colour bar's strip right of the panels, inches.
BAR_STRIP_IN = 1.1


def correspondence_vertex_errors(files: RunFiles, subject: str, method: str, expression: str,
                                 n_template: int) -> np.ndarray:
    """(n_template,) float64 correspondence error of every template vertex (mm, NaN where unscored)."""
    path = files.layout.metrics_details(subject, method, expression) / "correspondence_errors.npz"
    return read_vertex_values(path, "vertex_error_mm", n_template, "vertex errors")


def nice_ceiling(value: float) -> float:
    """The smallest 1, 2 or 5 times a power of ten that is >= ``value`` (> 0)."""
    if not value > 0 or not math.isfinite(value):
        return 1.0
    power = 10.0 ** math.floor(math.log10(value))
    return next(step * power for step in (1.0, 2.0, 5.0, 10.0) if step * power >= value * (1 - 1e-12))


def error_image(V: np.ndarray, F: np.ndarray, errors: np.ndarray, camera, top_mm: float):
    """The template coloured by ``errors (n,)`` mm (grey where NaN), shaded; returns (image, coverage)."""
    import matplotlib

    scored = np.isfinite(errors)
    values = np.column_stack([np.where(scored, errors, 0.0), scored.astype(np.float64)])
    r = render_surface(V, F, camera, vertex_values=values)
    # a pixel is scored when its face's corners are (mostly) scored; the value is then their weighted mean
    weight = r.values[..., 1:2]
    mean = np.where(weight > 0, r.values[..., :1] / np.maximum(weight, 1e-12), 0.0)
    colours = matplotlib.colormaps[HEATMAP_COLORMAP](np.clip(mean[..., 0] / top_mm, 0.0, 1.0))[..., :3]
    colours = np.where(weight >= 0.5, colours, np.array(UNSCORED_RGB))
    lit = colours * (0.35 + 0.65 * r.shade[..., None])
    return np.where(r.coverage[..., None], lit, 1.0), r.coverage


def draw_correspondence_errors(request: FigureRequest):
    """Rows: expressions; columns: methods; the template coloured by its per-vertex correspondence error."""
    import matplotlib

    from gpja.mesh import read_obj

    files, subject, settings = request.files, request.subject, request.settings
    methods, expressions = request.methods, request.expressions
    template = read_obj(files.layout.template_file(subject, "template.obj"), load_texture=False)
    errors = {(m, e): correspondence_vertex_errors(files, subject, m, e, len(template.V))
              for e in expressions for m in methods}
    scored = np.concatenate([v[np.isfinite(v)] for v in errors.values()])
    top = nice_ceiling(float(np.percentile(scored, TOP_PERCENTILE)) if scored.size else 1.0)
    camera = frontal_camera(template.V, settings.render_size)
    crops = {}
    for key in errors:
        image, coverage = error_image(template.V, template.F, errors[key], camera, top)
        crops[key] = np.clip(crop_to_coverage([image], coverage)[0], 0, 1)
    # cells as wide as the crops (a head is taller than wide) and the colour bar in its own strip
    aspect = max(c.shape[1] / c.shape[0] for c in crops.values())
    fig, axes = new_grid(len(expressions), len(methods), aspects=[aspect] * len(methods), right_in=BAR_STRIP_IN)
    fig.subplots_adjust(wspace=0.05, hspace=0.12)
    for i, expression in enumerate(expressions):
        for j, method in enumerate(methods):
            ax = axes[i][j]
            ax.imshow(crops[(method, expression)])
            regions = (files.metrics(subject, method, expression).get("correspondence") or {}).get("regions") or {}
            mouth = (regions.get("mouth") or {}).get("median_mm")
            e = errors[(method, expression)]
            text = f"median {np.nanmedian(e):.2f} mm" if np.isfinite(e).any() else "no scored vertex"
            text += f"\nmouth {mouth:.2f} mm" if mouth is not None else ""
            ax.text(0.5, 0.02, text, transform=ax.transAxes, fontsize=6.5, color="black", ha="center",
                    bbox=dict(facecolor="white", alpha=0.7, lw=0, pad=1))
            if i == 0:
                ax.set_title(label(method), fontsize=9)
            if j == 0:
                ax.set_ylabel(expression, fontsize=8)
    mappable = matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(0.0, top), HEATMAP_COLORMAP)
    width = fig.get_figwidth()
    cax = fig.add_axes(((width - BAR_STRIP_IN + 0.15) / width, 0.15, 0.18 / width, 0.7))
    bar = fig.colorbar(mappable, cax=cax)
    bar.set_label(f"correspondence error (mm, clipped at {top:g}; grey: not scored)")
    set_title(fig, f"Correspondence error on the template, subject {subject}", fontsize=10)
    return fig
