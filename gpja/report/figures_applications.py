"""Figures of the paper's applications (``gpja.apply``): the animation's film strip and the artist mesh.

- ``animation``: evenly spaced frames of the animation through the remeshed expressions (paper Fig.
  "animation"), read from ``animation_frames.npz`` (``gpja animate``), each labelled with where it is.
- ``reparam``: the artist mesh on the template with its edges drawn, then the artist mesh carried onto every
  expression, rendered with the shared texture resampled into its UVs (paper Fig. "reparam").
- ``turns``: per hop of the registration tree, the artist mesh's faces turned over (``reparam/turns.json``,
  ``gpja turns``): GPJA's and, on synthetic data, the true motion's, marked on the artist mesh through its surface.

Each ``draw_*`` takes a :class:`~gpja.report.figures.FigureRequest` and returns the matplotlib figure.
"""
from __future__ import annotations

import numpy as np

from gpja.camera import framing_camera
from gpja.errors import InputError
from gpja.io import read_npz
from gpja.mesh import read_obj
from gpja.report.drawing import new_grid, render_surface, set_title, shaded_image
from gpja.report.figures import FigureRequest

#: Frames per row of the film strip.
STRIP_COLUMNS = 4
#: Colour and width of the artist mesh's edges over its shaded render.
EDGE_COLOUR, EDGE_WIDTH, EDGE_ALPHA = (0.1, 0.35, 0.85), 0.06, 0.6
#: Marks of the turned faces: GPJA's (filled) and the true motion's (rings).
OURS_COLOUR, TRUTH_COLOUR = (0.85, 0.1, 0.1), (0.1, 0.3, 0.95)
#: Hops per row of the turns figure.
TURN_COLUMNS = 2


def draw_animation(request: FigureRequest):
    """The animation's kept frames, in order, each titled with its transition and t."""
    path = request.files.layout.animation_frames(request.subject)
    arrays = read_npz(path)
    for key in ("frames", "labels", "index", "count"):
        if key not in arrays:
            raise InputError(path, f"no array {key!r}: not written by gpja animate")
    frames, labels = arrays["frames"], arrays["labels"]
    rows = int(np.ceil(len(frames) / STRIP_COLUMNS))
    aspect = frames.shape[2] / frames.shape[1]
    fig, axes = new_grid(rows, STRIP_COLUMNS, panel_in=1.6, aspects=[aspect] * STRIP_COLUMNS)
    for k, ax in enumerate(np.ravel(axes)):
        if k < len(frames):
            ax.imshow(frames[k])
            ax.set_title(f"frame {int(arrays['index'][k])}: {labels[k]}", fontsize=5.5)
        else:
            ax.axis("off")
    set_title(fig, f"Animation, subject {request.subject}: {int(arrays['count'])} frames interpolated between the "
                   "remeshed expressions (frontal | three-quarter)", fontsize=9)
    return fig


def _edges_overlay(ax, V: np.ndarray, F: np.ndarray, camera, front: np.ndarray) -> None:
    """Draw the edges of the faces ``front`` (bool per face) of ``V``, ``F`` projected by ``camera``."""
    from matplotlib.collections import LineCollection

    xy, _ = camera.project(V)
    tri = xy[F[front]]
    segments = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
    ax.add_collection(LineCollection(segments, colors=[EDGE_COLOUR], linewidths=EDGE_WIDTH,
                                     alpha=EDGE_ALPHA))


def draw_reparam(request: FigureRequest):
    """The artist mesh with its edges on the template, then on every expression with its resampled texture."""
    layout, subject = request.files.layout, request.subject
    artist = read_obj(layout.artist_mesh(subject))
    if artist.texture is None or not artist.has_uv:
        raise InputError(layout.artist_mesh(subject), "the artist mesh has no texture coordinates or texture")
    carried = {e: read_obj(layout.reparametrized(subject, e), load_texture=False) for e in request.expressions}
    size = request.settings.render_size
    camera = framing_camera(np.concatenate([m.V for m in carried.values()] + [artist.V]), size)
    panels, titles = [], []
    shaded = render_surface(artist.V, artist.F, camera, render=request.render)
    panels.append(shaded_image(shaded))
    titles.append(f"artist mesh ({len(artist.F)} faces)\non the template")
    coverage = shaded.coverage.copy()
    for expression, mesh in carried.items():
        out = render_surface(mesh.V, artist.F, camera, uv=artist.UV, uv_faces=artist.F_uv, texture=artist.texture,
                             render=request.render)
        # the texture under a headlight, so the shape shows as well as the colour
        lit = out.color * (0.45 + 0.55 * out.shade[..., None])
        panels.append(np.where(out.coverage[..., None], lit, 1.0))
        titles.append(f"{expression}\n(artist topology, its UVs)")
        coverage |= out.coverage
    # one crop for all panels, so the edges drawn on the first stay in register
    rows_cols = np.argwhere(coverage)
    (r0, c0), (r1, c1) = rows_cols.min(0), rows_cols.max(0)
    margin = 8
    r0, c0 = max(r0 - margin, 0), max(c0 - margin, 0)
    r1, c1 = min(r1 + margin + 1, size), min(c1 + margin + 1, size)
    aspect = (c1 - c0) / max(r1 - r0, 1)
    fig, axes = new_grid(1, len(panels), panel_in=2.4, aspects=[aspect] * len(panels))
    for k, (img, title) in enumerate(zip(panels, titles)):
        ax = axes[0][k]
        ax.imshow(img[r0:r1, c0:c1], extent=(c0 - 0.5, c1 - 0.5, r1 - 0.5, r0 - 0.5))
        ax.set_title(title, fontsize=6)
    normals = artist.face_normals()
    to_camera = camera.center[None, :] - artist.V[artist.F].mean(axis=1)
    _edges_overlay(axes[0][0], artist.V, artist.F, camera, (normals * to_camera).sum(axis=1) > 0)
    axes[0][0].set_xlim(c0 - 0.5, c1 - 0.5)
    axes[0][0].set_ylim(r1 - 0.5, r0 - 0.5)
    set_title(fig, f"Re-parametrisation, subject {subject}: an artist mesh carried to every expression through the "
                   "template's texture space", fontsize=9)
    return fig


def draw_turns(request: FigureRequest):
    """One panel a hop: the artist mesh on the template, shaded, with the centroid of every face the hop turns over
    marked through the surface (most lie on material the expression hides), GPJA's and the true motion's."""
    from gpja.report.tables_applications import read_turns

    layout, subject = request.files.layout, request.subject
    record = read_turns(layout.root, subject)
    hops = record["hops"]
    if not hops:
        raise InputError(layout.reparam_turns(subject), "no hop to draw (a tree of one expression)")
    artist = read_obj(layout.artist_mesh(subject), load_texture=False)
    centroids = artist.V[artist.F].mean(axis=1)
    for hop in hops:
        for key in ("turned_faces", "truth_turned_faces"):
            ids = np.asarray(hop.get(key, []), dtype=np.int64)
            if ids.size and (ids.min() < 0 or ids.max() >= len(artist.F)):
                raise InputError(layout.reparam_turns(subject), f"{key} of {hop['parent']} -> {hop['expression']} "
                                                                f"index faces the artist mesh ({len(artist.F)}) lacks")
    size = request.settings.render_size
    camera = framing_camera(artist.V, size)
    shaded = render_surface(artist.V, artist.F, camera, render=request.render)
    image = shaded_image(shaded)
    # one window for all panels: around every marked face, a fifth of the head's size beyond them
    head = np.argwhere(shaded.coverage)
    marked = np.unique(np.concatenate([np.asarray(h.get(k, []), dtype=np.int64) for h in hops
                                       for k in ("turned_faces", "truth_turned_faces")]))
    if marked.size:
        xy, _ = camera.project(centroids[marked])
        pad = 0.2 * (head.max(0) - head.min(0)).max()
        lo = np.maximum(np.floor(xy[:, ::-1].min(0) - pad), head.min(0)).astype(int)
        hi = np.minimum(np.ceil(xy[:, ::-1].max(0) + pad), head.max(0)).astype(int)
    else:
        lo, hi = head.min(0), head.max(0)
    (r0, c0), (r1, c1) = lo, hi
    aspect = (c1 - c0 + 1) / max(r1 - r0 + 1, 1)
    cols = min(len(hops), TURN_COLUMNS)
    rows = int(np.ceil(len(hops) / cols))
    fig, axes = new_grid(rows, cols, panel_in=2.6, aspects=[aspect] * cols)
    for k, ax in enumerate(np.ravel(axes)):
        if k >= len(hops):
            ax.axis("off")
            continue
        hop = hops[k]
        ax.imshow(image[r0:r1 + 1, c0:c1 + 1], extent=(c0 - 0.5, c1 + 0.5, r1 + 0.5, r0 - 0.5))
        title = f"{hop['parent']} -> {hop['expression']}\nGPJA {hop['turned']} ({hop['turned_observed']} observed)"
        if "truth_turned_faces" in hop:
            xy, _ = camera.project(centroids[np.asarray(hop["truth_turned_faces"], dtype=np.int64)])
            ax.scatter(xy[:, 0], xy[:, 1], s=14, facecolors="none", edgecolors=[TRUTH_COLOUR], linewidths=0.6)
            title += f"\ntrue motion {hop['truth_turned']}; both {hop['both']}, near {hop.get('near_truth', 0)}"
        xy, _ = camera.project(centroids[np.asarray(hop.get("turned_faces", []), dtype=np.int64)])
        ax.scatter(xy[:, 0], xy[:, 1], s=4, c=[OURS_COLOUR], linewidths=0)
        ax.set_xlim(c0 - 0.5, c1 + 0.5)
        ax.set_ylim(r1 + 0.5, r0 - 0.5)
        ax.set_title(title, fontsize=5.5)
    set_title(fig, f"The artist mesh's faces turned over between adjacent expressions, subject {subject}\n"
                   f"({record.get('faces')} faces; red: GPJA, blue rings: the true motion; seen through the surface)",
              fontsize=8)
    return fig
