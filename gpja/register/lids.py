"""The lid search (beyond the paper, ``Schedule.lid_search_deg``): close the upper lids before the flow.

Why (docs/experiments.md, "The lids searched before the flow stage"): every start of a registration has open
eyes (the template is the mouth-open expression, and a child of the registration tree starts from a parent
that has them too). A closed eye needs the upper lid to slide 10-15 mm down over the eyeball. The optical
flow of the first flow stage does not follow it: a closing lid is an occlusion (the iris and sclera vanish),
and 9 % of the eye region's vertices passed the flow's forward-backward check. The descent then closes the
render by stretching the eyeball's material over the lid, which the depth and normal constraints pull onto the
scan: the lids' material ends up 3-6 mm from where it belongs. A blink is, to a first approximation, one degree
of freedom: the upper lid turns about the eyeball's horizontal axis. One number is found by search where a
descent does not, as the jaw's pitch is (:mod:`gpja.register.jaw`).

The rig comes from the shared texture and the start's geometry, not from any ground truth:

1. The eye openings are where the texture shows the white of the eye (:func:`find_openings`): texels of low
   saturation and at least skin brightness, outside the mouth's socket (teeth are white too), grouped into the two
   largest clusters (a white too small to start one, as a few views' fusion leaves it in fragments, joins the
   cluster next to it); an opening is the convex hull of its cluster's texels (the iris between the two whites
   included). A cluster over 3 % of the texture, or one whose eyeball would not sit above the mouth, is no eye.
2. On the start mesh, the opening's texels lie on the eyeball. A sphere of the adult eyeball's radius
   (``EYE_RADIUS_MM``) fitted to them gives the centre the lid turns about; the hull's boundary gives the upper
   and the lower lid margin as angles about that centre's horizontal axis, as functions of x (:func:`eye_rigs`).
3. Closing by an angle (:func:`pose_lids`): the upper lid (``LID_ARC_MM`` of arc above its margin, within
   ``LID_DEPTH_MM`` of the eyeball's surface) turns down about the axis by up to the angle, never past the lower
   margin; the opening's own material is compressed towards the lower margin, under the lid. The angle tapers
   towards the eye's corners with the opening's height. Material keeps its distance from the centre: the lid
   slides over the globe.

The search scores the render with the shared texture against the references over a grid of angles
(:func:`search_lids`, the jaw's :func:`~gpja.register.jaw.search_grid` and
:func:`~gpja.register.jaw.colour_score`) and closes only when that is at least ``jaw.MIN_GAIN`` better than the
start: an open eye's best angle is 0, and a start whose lids are already closed has little opening left to close.
One angle serves both eyes (a blink; a wink is left to the flow and the descent).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from gpja.mesh import TexturedMesh
from gpja.register.jaw import smoothstep

#: adult eyeball radius (mm): the globe's axial length is about 24 mm
EYE_RADIUS_MM = 12.0
#: the white of the eye: texels whose saturation ((max - min) / max of RGB) is below this ...
SCLERA_MAX_SATURATION = 0.22
#: ... and whose value (max of RGB) is at least this fraction of the skin's median value
SCLERA_MIN_VALUE = 0.9
#: a cluster of white texels smaller than this fraction of the texture's texels is noise (a highlight, a mole's rim);
#: an eye's whites larger than the second is no eye (a pale face, a white backdrop; the default's are 0.04 %)
MIN_CLUSTER_FRACTION = 2e-5
MAX_EYE_FRACTION = 0.03
#: an eyeball's centre lies at least this far above the mouth's socket (mm; adults: 60-75): what is not is no eye
EYES_ABOVE_MOUTH_MM = 30.0
#: the upper lid: it turns whole up to the first arc length (mm) above its margin and not at all beyond the second
#: (anatomically the lid is 8-10 mm from margin to crease, the brow 10-20 mm above the margin). A narrower band,
#: (4, 12), needed turns to the search's end (89.5 degrees) on a seed-7 capture and moved its lids away
#: (docs/experiments.md, "The lids searched before the flow stage").
LID_ARC_MM = (10.0, 20.0)
#: ... and within the first distance (mm) of the eyeball's surface, not at all beyond the second (the lid and its
#: soft tissue lie over the globe; the brow ridge and the nose's bridge stand further out)
LID_DEPTH_MM = (10.0, 16.0)
#: the opening's material is compressed under the closed lid to at least this fraction of its height, so that no
#: triangle collapses
MIN_OPENING_FRACTION = 0.1
#: the turn fades out over this many mm beyond the openings' corners
CORNER_FADE_MM = 3.0


@dataclass(frozen=True)
class EyeRig:
    """One eye's lid rig in the start's frame (mm, +Y up, +Z forward).

    centre: (3,) the eyeball's centre; x_range: the opening's corners' x (lo, hi);
    upper, lower: the margins as (xs (k,), angles (k,) radians about the centre's x axis, 0 = straight ahead,
    positive upwards), xs increasing; gap_max: the opening's height (radians) at the centre's x.
    """

    centre: np.ndarray
    x_range: tuple[float, float]
    upper: tuple[np.ndarray, np.ndarray]
    lower: tuple[np.ndarray, np.ndarray]
    gap_max: float


def find_openings(texture: np.ndarray, mouth_mask: np.ndarray | None = None,
                  join_fragments: bool = True) -> list[np.ndarray]:
    """The eye openings of a texture: up to two convex hulls (k, 2) float32 in texel coordinates (column, row),
    largest first (module docstring, step 1). ``texture``: (T, T, 3) float albedo in [0, 1]; ``mouth_mask``: (T', T')
    float, 0 on the mouth's socket (its teeth are white too), resampled to T; None = no socket. [] when the texture
    shows no white of an eye."""
    import cv2  # OpenCV's connected components and convex hull: the well-kept versions of both

    t = np.asarray(texture, dtype=np.float32)
    value = t.max(axis=2)
    saturation = (value - t.min(axis=2)) / np.maximum(value, 1e-6)
    lit = value[value > 0.2]
    if lit.size == 0:
        return []
    white = (saturation < SCLERA_MAX_SATURATION) & (value >= SCLERA_MIN_VALUE * float(np.median(lit)))
    if mouth_mask is not None:
        mask = cv2.resize(np.asarray(mouth_mask, dtype=np.float32), (t.shape[1], t.shape[0]),
                          interpolation=cv2.INTER_NEAREST)
        white &= mask >= 0.5
    white = white.astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(white, connectivity=8)
    min_area = max(4, int(MIN_CLUSTER_FRACTION * white.size))
    parts = sorted(range(1, n), key=lambda k: -stats[k, cv2.CC_STAT_AREA])
    if not join_fragments:
        parts = [k for k in parts if stats[k, cv2.CC_STAT_AREA] >= min_area]
    # an eye shows two whites, one either side of the iris: a part joins a group whose box it comes within the
    # group's first part's height of; only a part of at least min_area starts a group. A white that few views saw
    # is broken into fragments smaller than that (a 5-view capture: one eye's inner white in pieces of 4-13
    # texels); they still join the eye next to them (join_fragments), so that its opening spans the iris.
    groups: list[dict] = []
    for k in parts:
        x, y, w, h = (int(v) for v in stats[k, :4])
        for g in groups:
            x0, y0, x1, y1 = g["box"]
            reach = g["height"]
            if x <= x1 + reach and x + w >= x0 - reach and y <= y1 + reach and y + h >= y0 - reach:
                g["parts"].append(k)
                g["box"] = (min(x0, x), min(y0, y), max(x1, x + w), max(y1, y + h))
                g["area"] += int(stats[k, cv2.CC_STAT_AREA])
                break
        else:
            if stats[k, cv2.CC_STAT_AREA] >= min_area:
                groups.append({"parts": [k], "box": (x, y, x + w, y + h), "height": h,
                               "area": int(stats[k, cv2.CC_STAT_AREA])})
    groups = sorted((g for g in groups if g["area"] <= MAX_EYE_FRACTION * white.size), key=lambda g: -g["area"])
    hulls = []
    for g in groups[:2]:
        texels = np.concatenate([np.argwhere(labels == k)[:, ::-1] for k in g["parts"]]).astype(np.float32)
        hulls.append(cv2.convexHull(texels)[:, 0].astype(np.float32))
    return hulls


def texel_uv(texels: np.ndarray, size: int) -> np.ndarray:
    """(k, 2) texture coordinates of texel centres (column, row) of a ``size``-square texture (row 0 at v = 1)."""
    texels = np.asarray(texels, dtype=np.float64)
    return np.stack([(texels[:, 0] + 0.5) / size, 1.0 - (texels[:, 1] + 0.5) / size], axis=1)


def hull_samples(hull: np.ndarray, per_texel: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Texel coordinates along a hull's boundary (about one per texel) and on the texel grid inside it."""
    import cv2

    closed = np.vstack([hull, hull[:1]]).astype(np.float64)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    s = np.arange(0.0, arc[-1], 1.0 / per_texel)
    boundary = np.stack([np.interp(s, arc, closed[:, 0]), np.interp(s, arc, closed[:, 1])], axis=1)
    (x0, y0), (x1, y1) = hull.min(axis=0), hull.max(axis=0)
    xs, ys = np.meshgrid(np.arange(np.floor(x0), np.ceil(x1) + 1), np.arange(np.floor(y0), np.ceil(y1) + 1))
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1)
    contour = hull.reshape(-1, 1, 2).astype(np.float32)
    inside = np.array([cv2.pointPolygonTest(contour, (float(a), float(b)), False) >= 0 for a, b in grid], dtype=bool)
    return boundary, grid[inside]


def fit_centre(points: np.ndarray, radius: float = EYE_RADIUS_MM) -> np.ndarray:
    """(3,) the centre of the sphere of ``radius`` (mm) nearest (least squares) to ``points`` (k, 3) mm, started
    ``radius`` behind their mean (+Z forward); the start itself when the fit lands in front of the points."""
    from scipy.optimize import least_squares

    start = points.mean(axis=0) - np.array([0.0, 0.0, radius])
    centre = least_squares(lambda c: np.linalg.norm(points - c, axis=1) - radius, start).x
    return centre if centre[2] < points[:, 2].mean() else start


Margin = tuple[np.ndarray, np.ndarray]


def margin_angles(centre: np.ndarray, boundary: np.ndarray) -> tuple[Margin, Margin]:
    """The upper and lower margin of an opening's ``boundary`` (k, 3) mm as (xs, angles) about ``centre``'s x axis:
    the boundary split by the line between its corners (its leftmost and rightmost points)."""
    phi = np.arctan2(boundary[:, 1] - centre[1], boundary[:, 2] - centre[2])
    x = boundary[:, 0]
    a, b = int(np.argmin(x)), int(np.argmax(x))
    line = phi[a] + (phi[b] - phi[a]) * (x - x[a]) / max(x[b] - x[a], 1e-9)
    chains = []
    for part in (phi >= line, phi <= line):
        order = np.argsort(x[part])
        chains.append((x[part][order], phi[part][order]))
    return chains[0], chains[1]


def eye_rigs(mesh: TexturedMesh, texture: np.ndarray, mouth_mask: np.ndarray | None = None) -> list[EyeRig]:
    """The lid rigs of ``mesh`` (the start, template topology with UVs, mm, canonical frame) from the openings
    ``texture`` (T, T, 3) shows (module docstring, steps 1-2); [] when it shows none. ``mouth_mask``: (T', T') float,
    0 on the socket: its texels are no eye's, and an eye's centre must lie ``EYES_ABOVE_MOUTH_MM`` above it."""
    from gpja.apply.remesh import locate_uv, positions_at_uv

    size = int(np.asarray(texture).shape[0])
    mouth_y = None
    if mouth_mask is not None:
        from gpja.register.flow import socket_vertices

        socket = socket_vertices(mesh, torch.as_tensor(np.asarray(mouth_mask, dtype=np.float32))[..., None])
        mouth_y = float(mesh.V[socket, 1].mean()) if socket.any() else None
    rigs = []
    for hull in find_openings(texture, mouth_mask):
        boundary_px, inside_px = hull_samples(hull)
        boundary = positions_at_uv(mesh, locate_uv(mesh, texel_uv(boundary_px, size)))
        inside = positions_at_uv(mesh, locate_uv(mesh, texel_uv(inside_px, size)))
        boundary = boundary[np.isfinite(boundary).all(axis=1)]
        inside = inside[np.isfinite(inside).all(axis=1)]
        if len(boundary) < 8 or len(inside) < 8:
            continue
        centre = fit_centre(inside)
        if mouth_y is not None and centre[1] < mouth_y + EYES_ABOVE_MOUTH_MM:
            continue
        upper, lower = margin_angles(centre, boundary)
        if len(upper[0]) < 2 or len(lower[0]) < 2:
            continue
        gap = float(np.interp(centre[0], *upper) - np.interp(centre[0], *lower))
        if gap <= 0:
            continue
        rigs.append(EyeRig(centre, (float(boundary[:, 0].min()), float(boundary[:, 0].max())), upper, lower, gap))
    return rigs


def pose_lids(V: np.ndarray, rigs: list[EyeRig], degrees: float) -> np.ndarray:
    """(n, 3) ``V`` (n, 3) mm with every rig's upper lid closed by ``degrees`` (module docstring, step 3);
    ``degrees`` 0 returns ``V``."""
    out = np.array(V, dtype=np.float64)
    if degrees == 0 or not rigs:
        return out
    closing = np.radians(float(degrees))
    for rig in rigs:
        q = out - rig.centre
        r = np.linalg.norm(q, axis=1)
        phi = np.arctan2(q[:, 1], q[:, 2])
        x = out[:, 0]
        upper = np.interp(x, *rig.upper)
        lower = np.interp(x, *rig.lower)
        gap = np.clip(upper - lower, 0.0, None)
        lateral = (smoothstep(rig.x_range[0] - CORNER_FADE_MM, rig.x_range[0] + CORNER_FADE_MM, x)
                   * smoothstep(rig.x_range[1] + CORNER_FADE_MM, rig.x_range[1] - CORNER_FADE_MM, x))
        near = smoothstep(EYE_RADIUS_MM + LID_DEPTH_MM[1], EYE_RADIUS_MM + LID_DEPTH_MM[0], r) * (q[:, 2] > 0)
        turn = closing * lateral * near * smoothstep(0.0, 0.5 * rig.gap_max, gap)
        new = phi.copy()
        opening = (phi >= lower) & (phi <= upper)
        kept = np.clip((gap - turn) / np.maximum(gap, 1e-9), MIN_OPENING_FRACTION, 1.0)
        new[opening] = (lower + (phi - lower) * kept)[opening]
        lid = phi > upper
        arc = (phi - upper) * np.maximum(r, EYE_RADIUS_MM)
        turned = np.maximum(phi - turn * smoothstep(LID_ARC_MM[1], LID_ARC_MM[0], arc),
                            lower + MIN_OPENING_FRACTION * (phi - lower))
        new[lid] = turned[lid]
        moving = np.flatnonzero(new != phi)  # the others keep their positions to the bit
        d = (new - phi)[moving]
        c, s = np.cos(d), np.sin(d)
        # the turn about the x axis through the centre that takes the angle phi = atan2(y, z) to phi + d
        out[moving, 1] = rig.centre[1] + q[moving, 1] * c + q[moving, 2] * s
        out[moving, 2] = rig.centre[2] + q[moving, 2] * c - q[moving, 1] * s
    return out


def search_lids(mesh: TexturedMesh, targets, texture: torch.Tensor, mask_texture: torch.Tensor, max_deg: float,
                render: Callable | None = None, progress: Callable[[str], None] = print) -> tuple[TexturedMesh, dict]:
    """Close ``mesh``'s upper lids by the angle in [0, ``max_deg``] whose render best matches the references, when
    it matches them at least ``jaw.MIN_GAIN`` better than the start (else the start stays, angle 0).

    Args:
        mesh: the start (template topology, mm, canonical frame) with UVs.
        targets: the expression's :class:`~gpja.register.hra.ExpressionTargets`.
        texture: (T, T, 3) shared albedo; mask_texture: (T', T', 1) mouth mask (0 = socket).
        max_deg: the largest closing searched, degrees.
    Returns:
        the posed mesh and a log entry (the angle, the score at it and at 0, every angle tried, the eyes' centres,
        seconds).
    """
    from gpja.register.jaw import FINE_STEP_DEG, MIN_GAIN, colour_score, search_grid

    start = time.perf_counter()
    rigs = eye_rigs(mesh, texture.detach().cpu().numpy(), mask_texture.detach().cpu().numpy()[..., 0])
    entry = {"stage": "lids", "vertices": int(len(mesh.V)), "eyes": len(rigs),
             "centres_mm": [r.centre.round(2).tolist() for r in rigs],
             "opening_deg": [round(float(np.degrees(r.gap_max)), 2) for r in rigs], "closing_deg": 0.0}
    if not rigs:
        entry["seconds"] = round(time.perf_counter() - start, 3)
        progress("lids: stay (the texture shows no white of an eye)")
        return mesh, entry
    score_of = colour_score(mesh, targets, texture, mask_texture, render)
    best, tried = search_grid(0.0, float(max_deg), lambda a: score_of(pose_lids(mesh.V, rigs, a)))
    scores = dict(tried)
    at_zero = scores[0.0]
    found = best
    if scores[best] > (1.0 - MIN_GAIN) * at_zero:
        best = 0.0
    entry.update(closing_deg=best, best_closing_deg=found, score=round(scores[best], 6),
                 score_at_start=round(at_zero, 6),
                 tried=[[a, round(s, 6)] for a, s in tried], seconds=round(time.perf_counter() - start, 3))
    if best == 0.0:
        progress(f"lids: stay (the best closing, {found:.1f} deg, matches the images {1 - scores[found] / at_zero:.1%} "
                 f"better, under {MIN_GAIN:.0%}; {len(rigs)} eyes, {len(tried)} poses, {entry['seconds']:.1f} s)")
        return mesh, entry
    at_end = " (the search's end: the rig fits these lids poorly)" if best >= float(max_deg) - FINE_STEP_DEG else ""
    one = (" (one eye's white found in the shared texture: the other lid is left to the flow and the descent)"
           if len(rigs) == 1 else "")
    progress(f"lids: closed {best:.1f} deg over {len(rigs)} eyes{at_end}{one} (colour {at_zero:.5f} -> "
             f"{scores[best]:.5f}; {entry['seconds']:.1f} s)")
    return mesh.with_vertices(pose_lids(mesh.V, rigs, best)), entry
