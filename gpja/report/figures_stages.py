"""The figure of a registration stage by stage (synthetic data): ``registration_stages``.

Per expression, two rows; one column per stage of the GPJA registration (the mesh it starts from, after
the warm-up, after each level; ``gpja stages``, :mod:`gpja.metrics.stages`): the template coloured by
each vertex's correspondence error after that stage (as in ``correspondence_errors``, one colour bar for
the figure), and the L1 image of its render with the shared texture in the most frontal view. Each panel
names the stage's correspondence median and its mouth median, or the view's PSNR. It shows where the
alignment is won or lost: whether the start already has the mouth closed, what the warm-up moves, and
which level drags a feature off its place.
"""
from __future__ import annotations

import numpy as np

from gpja.io import read_json, read_npz
from gpja.report.drawing import HEATMAP_COLORMAP, crop_to_coverage, frontal_camera, new_grid, set_title
from gpja.report.figures import FigureRequest
from gpja.report.figures_correspondence import BAR_STRIP_IN, TOP_PERCENTILE, error_image, nice_ceiling

#: Height of a row, inches (two rows per expression).
ROW_IN = 1.8


def read_stage_scores(files, subject: str, method: str, expression: str) -> tuple[dict, dict]:
    """The stage scores JSON and its arrays (``stage_names``, ``vertex_error_mm``, ``l1``) of one registration."""
    path = files.layout.stage_scores(subject, method, expression)
    return read_json(path), read_npz(files.layout.stage_arrays(subject, method, expression))


def draw_registration_stages(request: FigureRequest):
    """Rows: per expression, correspondence error on the template and the L1 image; columns: stages."""
    import matplotlib

    from gpja.mesh import read_obj

    files, subject, method = request.files, request.subject, request.method
    template = read_obj(files.layout.template_file(subject, "template.obj"), load_texture=False)
    scores = {e: read_stage_scores(files, subject, method, e) for e in request.expressions}
    errors = np.concatenate([a["vertex_error_mm"].ravel() for _, a in scores.values()])
    top = nice_ceiling(float(np.nanpercentile(errors, TOP_PERCENTILE)) if np.isfinite(errors).any() else 1.0)
    n_stages = max(len(j["stages"]) for j, _ in scores.values())
    camera = frontal_camera(template.V, request.settings.render_size)
    fig, axes = new_grid(2 * len(scores), n_stages, panel_in=ROW_IN, right_in=BAR_STRIP_IN)
    fig.subplots_adjust(wspace=0.04, hspace=0.1)
    for i, (expression, (record, arrays)) in enumerate(scores.items()):
        for j, row in enumerate(record["stages"]):
            heat, coverage = error_image(template.V, template.F, arrays["vertex_error_mm"][j].astype(np.float64),
                                         camera, top)
            ax = axes[2 * i][j]
            ax.imshow(np.clip(crop_to_coverage([heat], coverage)[0], 0, 1))
            mouth = row["regions"].get("mouth")
            text = f"median {row['median_mm']:.2f} mm" + (f"\nmouth {mouth:.2f} mm" if mouth is not None else "")
            ax.text(0.5, 0.02, text, transform=ax.transAxes, fontsize=6, ha="center",
                    bbox=dict(facecolor="white", alpha=0.7, lw=0, pad=1))
            l1 = arrays["l1"][j]
            ax = axes[2 * i + 1][j]
            ax.imshow(crop_to_coverage([l1], l1.max(axis=-1) > 0)[0])
            ax.text(0.5, 0.02, f"PSNR {row['psnr']:.2f} dB", transform=ax.transAxes, fontsize=6, ha="center",
                    bbox=dict(facecolor="white", alpha=0.7, lw=0, pad=1))
            if i == 0:
                axes[0][j].set_title(row["stage"], fontsize=8)
        axes[2 * i][0].set_ylabel(f"{expression}\ncorrespondence", fontsize=7)
        axes[2 * i + 1][0].set_ylabel(f"L1, view {record['view']}", fontsize=7)
    mappable = matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(0.0, top), HEATMAP_COLORMAP)
    width = fig.get_figwidth()
    cax = fig.add_axes(((width - BAR_STRIP_IN + 0.15) / width, 0.15, 0.18 / width, 0.7))
    fig.colorbar(mappable, cax=cax).set_label(f"correspondence error (mm, clipped at {top:g})")
    set_title(fig, f"GPJA stage by stage, subject {subject}", fontsize=10)
    return fig
