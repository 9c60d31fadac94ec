"""Figures of geometry: the template's stages, the scan-to-mesh error heatmaps, the normal-constraint ablation.

- ``template_stages``: the template-creation pipeline (paper Fig. "template creation"): the genus-0 bust,
  the fitted dense mesh with its reconstructed texture, the decimated template, its texture map and the
  mouth mask B (``{results}/{subject}/template/``); on synthetic data also the texture's error against the
  ground-truth albedo (``texture_error.png`` of ``gpja texture-quality``, when it exists).
- ``geometric_errors``: per expression and method, the scan rendered frontally and coloured by the
  distance of each scan vertex to the method's mesh (the paper's "point (of GT) to mesh" error), one
  shared colour bar in mm (``metrics/{expression}/geometry_errors.npz``).
- ``ablation_normal``: shaded renders of the scan, GPJA and GPJA without the normal constraint.

Each ``draw_*`` takes a :class:`~gpja.report.figures.FigureRequest` and returns the matplotlib figure.
"""
from __future__ import annotations

import numpy as np

from gpja.io import read_image, read_json
from gpja.methods import label
from gpja.metrics.texture_quality import ERROR_IMAGE_FILE, QUALITY_FILE
from gpja.report.drawing import (
    HEATMAP_COLORMAP,
    crop_to_coverage,
    frontal_camera,
    heatmap_image,
    new_grid,
    read_vertex_values,
    render_surface,
    set_title,
    shaded_image,
)
from gpja.report.figures import FigureRequest, RunFiles


def scan_errors(files: RunFiles, subject: str, method: str, expression: str, n_scan: int) -> np.ndarray:
    """(n_scan,) float64 distance (mm) of every scan vertex to the method's mesh, from ``gpja metrics``."""
    path = files.layout.metrics_details(subject, method, expression) / "geometry_errors.npz"
    return read_vertex_values(path, "scan_vertex_error_mm", n_scan, "scan errors")


def draw_template_stages(request: FigureRequest):
    """Bust -> fitted dense mesh with texture -> decimated template; its texture map and mouth mask B."""
    from gpja.mesh import read_obj

    layout, subject, settings = request.files.layout, request.subject, request.settings
    bust = read_obj(layout.template_stage(subject, "bust"), load_texture=False)
    fitted = read_obj(layout.template_stage(subject, "fitted"))
    template = read_obj(layout.template_file(subject, "template.obj"))
    texture = read_image(layout.template_file(subject, "texture.png"))
    mask = read_image(layout.template_file(subject, "mouth_mask.png"), mode="L")
    error_path = layout.template_file(subject, ERROR_IMAGE_FILE)
    camera = frontal_camera(np.concatenate([fitted.V, bust.V]), settings.render_size)
    panels = [("(a) genus-0 bust", bust), ("(b) fitted, textured", fitted), ("(c) template", template)]
    fig, axes = new_grid(1, 6 if error_path.is_file() else 5, panel_in=2.6)
    for ax, (title, mesh) in zip(axes[0], panels):
        r = render_surface(mesh.V, mesh.F, camera, uv=mesh.UV, uv_faces=mesh.F_uv, texture=mesh.texture,
                           render=request.render)
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
    if error_path.is_file():
        axes[0][5].imshow(read_image(error_path))
        axes[0][5].set_title(texture_error_title(layout.template_file(subject, QUALITY_FILE)), fontsize=8)
    set_title(fig, f"Template creation, subject {subject}", fontsize=10)
    return fig


def texture_error_title(quality_path) -> str:
    """The title of the texture-error panel: what it shows and the PSNR over observed / unobserved texels."""
    from gpja.metrics.photometric import ERROR_SCALE

    title = f"texture error vs. true albedo\n(L1, 0-{ERROR_SCALE:g}; black: off scan)"
    if not quality_path.is_file():
        return title
    quality = read_json(quality_path)
    parts = [f"{name} {quality[name]['psnr']:.1f} dB" for name in ("observed", "unobserved")
             if isinstance(quality.get(name), dict) and quality[name].get("psnr") is not None]
    return title + "".join(f"\nPSNR {part}" for part in parts)  # one per line: the panel is narrow


def draw_geometric_errors(request: FigureRequest):
    """Rows: expressions; columns: methods; the scan coloured by its distance to each method's mesh."""
    import matplotlib

    files, subject, settings = request.files, request.subject, request.settings
    methods, expressions = request.methods, request.expressions
    fig, axes = new_grid(len(expressions), len(methods))
    for i, expression in enumerate(expressions):
        scan = files.data.scan(subject, expression)
        camera = frontal_camera(scan.V, settings.render_size)
        for j, method in enumerate(methods):
            errors = scan_errors(files, subject, method, expression, len(scan.V))
            r = render_surface(scan.V, scan.F, camera, vertex_values=errors)
            ax = axes[i][j]
            ax.imshow(crop_to_coverage([heatmap_image(r, settings.heatmap_max_mm)], r.coverage)[0])
            ax.text(0.03, 0.03, f"mean {errors.mean():.3f} mm", transform=ax.transAxes, fontsize=7,
                    color="black", bbox=dict(facecolor="white", alpha=0.7, lw=0, pad=1))
            if i == 0:
                ax.set_title(label(method), fontsize=9)
            if j == 0:
                ax.set_ylabel(expression, fontsize=8)
    mappable = matplotlib.cm.ScalarMappable(matplotlib.colors.Normalize(0.0, settings.heatmap_max_mm),
                                            HEATMAP_COLORMAP)
    bar = fig.colorbar(mappable, ax=axes.ravel().tolist(), shrink=0.8, pad=0.02)
    bar.set_label(f"scan-to-mesh distance (mm, clipped at {settings.heatmap_max_mm:g})")
    set_title(fig, f"Geometric error, subject {subject}", fontsize=10)
    return fig


def draw_ablation_normal(request: FigureRequest):
    """Per expression: the scan, then each method (GPJA, GPJA without the normal constraint), shaded."""
    from gpja.mesh import read_obj

    files, subject, settings, expressions = request.files, request.subject, request.settings, request.expressions
    columns = ["scan", *request.methods]
    fig, axes = new_grid(len(expressions), len(columns), panel_in=2.8)
    for i, expression in enumerate(expressions):
        scan = files.data.scan(subject, expression)
        camera = frontal_camera(scan.V, settings.render_size)
        reference = render_surface(scan.V, scan.F, camera, render=request.render)
        for j, name in enumerate(columns):
            if name == "scan":
                r, text = reference, "scan"
            else:
                mesh = read_obj(files.layout.registration(subject, name, expression), load_texture=False)
                r = render_surface(mesh.V, mesh.F, camera, render=request.render)
                geometry = files.metrics(subject, name, expression)["geometry"]
                text = f"{label(name)}\nscan-to-mesh {geometry['scan_to_mesh_mm']:.3f} mm"
            axes[i][j].imshow(crop_to_coverage([shaded_image(r)], reference.coverage)[0])
            axes[i][j].set_title(text if i == 0 or name != "scan" else "", fontsize=8)
        axes[i][0].set_ylabel(expression, fontsize=8)
    set_title(fig, f"Ablation: with and without the normal constraint, subject {subject}", fontsize=10)
    return fig
