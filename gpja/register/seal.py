"""The lips sealed where the photographs show a closed mouth (beyond the paper, ``Schedule.lip_seal``).

Why (docs/experiments.md, "The lips sealed where the mouth is closed"): the template is fitted to an open
mouth (``3_mouth_stretch``), and its mouth mask's rim, the socket's boundary (:func:`gpja.register.jaw.socket_rim`),
is where the photographs of that expression show the lips' colour give way to the dark cavity: the inner
face of each lip. A closed mouth presses those inner faces together, out of sight. In our benchmark's
ground truth the lower rim's material lies 1-3 mm inside the mouth behind the visible lips in every closed
expression. After the flow stage GPJA's lower rim lay 5-9 mm below the upper one, half-way down the
front of the lower lip: the inner face, lip-coloured in the shared texture, was laid over the lip's front,
and the lower lip's own material sat 2-3 mm too low below it. The colour constraint cannot see it (one
lip colour on both sides of the rim), nor can depth or normals (both faces lie on the scan's lip).

What can be seen is whether the mouth is closed: between the lower rim and the upper rim, a reference of an
open mouth shows the dark cavity, a closed one only lip colour and the thin dark line where the lips meet.
So, after a flow stage, every lower-rim vertex (the rim's jaw side, :func:`gpja.register.jaw.jaw_weights`)
is paired with the nearest upper-rim vertex, the segment between them is projected into every reference that
sees the lower vertex, and the longest dark run along it (pixels darker than ``DARK_FRACTION`` of the head's
median brightness in that view) is measured in mm. Where it is at most ``CONTACT_MM`` in every such view (and the two are at most
``MAX_SEAL_MM`` apart), the lower rim vertex is moved ``fraction`` of the way to its upper partner; the rest of the lower lip follows by
the flow stage's smooth displacement (:func:`gpja.register.flow.solve_displacement`), the upper lip, the upper
rim and everything beyond ``FAR_MM`` of the rim pulled to stay where they are (the same weight as the rim's
targets, so on a coarse mesh, with few vertices between the two, the rim gets part of the way). The descent then puts the moved lip back onto
the scan along its normals. No landmark or ground truth is read: the template's mouth mask, the references,
their coverage by the scan.
"""
from __future__ import annotations

import time

import numpy as np
import torch

from gpja.camera import Camera
from gpja.mesh import TexturedMesh

#: a reference pixel is dark (the mouth's cavity) below this fraction of the head's median brightness in its view
#: (the template's mouth mask splits the socket's texels at the same fraction: ``mouth_mask_dark``)
DARK_FRACTION = 0.5
#: the lips count as closed along a segment whose longest dark run is at most this long (mm): the line where
#: the lips meet is 1-2 pixels (about a millimetre at 512 px) in every closed mouth of the benchmark, an
#: opening 10-20
CONTACT_MM = 2.5
#: a lower-rim vertex further than this (mm) from its upper partner is not sealed: a closed lip's inner face is
#: at most this high (5-11 mm after the flow stage on the benchmark's closed mouths); further apart, the pair spans
#: an opening whose segment the references may not show as dark (it runs behind a lip no view sees past)
MAX_SEAL_MM = 12.0
#: vertices further than this (mm, straight line) from the socket's rim keep their place
FAR_MM = 15.0
#: a lower-rim vertex is seen by a view when its normal faces the camera at least this much (cosine)
MIN_FACING = 0.3


def rim_pairs(mesh: TexturedMesh, socket: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The lower rim's vertices, their nearest upper-rim vertices, and the whole rim.

    Args:
        mesh: the registration's mesh (canonical frame, mm). socket: (n,) bool socket vertices.
    Returns:
        lower (k,) int64, partner (k,) int64 (same order), rim (r,) int64, and the jaw's weight of every vertex
        (n,) float64 (:func:`gpja.register.jaw.jaw_weights`, which splits the rim).
    Raises:
        InputError: no socket or too small a rim (:func:`gpja.register.jaw.socket_rim`).
    """
    from scipy.spatial import cKDTree

    from gpja.register.jaw import jaw_weights, socket_rim

    rim = socket_rim(mesh.F, socket)
    jaw = jaw_weights(mesh.V, socket, rim).weight
    lower, upper = rim[jaw[rim] > 0.5], rim[jaw[rim] <= 0.5]
    if not len(lower) or not len(upper):
        return np.zeros(0, np.int64), np.zeros(0, np.int64), rim, jaw
    partner = upper[cKDTree(mesh.V[upper]).query(mesh.V[lower])[1]]
    return lower, partner, rim, jaw


def longest_dark_run(dark: np.ndarray) -> int:
    """Length of the longest run of True in a (m,) bool array."""
    best = run = 0
    for d in dark:
        run = run + 1 if d else 0
        best = max(best, run)
    return best


def dark_gaps(camera: Camera, start: np.ndarray, end: np.ndarray, luminance: np.ndarray,
              coverage: np.ndarray) -> np.ndarray:
    """(k,) float64 longest dark run (mm) along each 3D segment ``start`` -> ``end`` (k, 3) mm seen in one view.

    ``luminance``: (H, W) float the reference's brightness; ``coverage``: (H, W) the scan's coverage (the head).
    Dark is below ``DARK_FRACTION`` of the median over the covered pixels. Samples are one per pixel along the
    projected segment; samples outside the image or the head count as not dark (no evidence of an opening).
    """
    head = coverage > 0.5
    if not head.any():
        return np.zeros(len(start))
    dark = luminance < DARK_FRACTION * float(np.median(luminance[head]))
    a, _ = camera.project(start)
    b, _ = camera.project(end)
    H, W = luminance.shape
    out = np.zeros(len(start))
    for k in range(len(start)):
        m = int(np.ceil(np.linalg.norm(b[k] - a[k]))) + 1
        px = np.linspace(a[k], b[k], m).round().astype(int)
        inside = (px[:, 0] >= 0) & (px[:, 1] >= 0) & (px[:, 0] < W) & (px[:, 1] < H)
        d = np.zeros(m, dtype=bool)
        d[inside] = dark[px[inside, 1], px[inside, 0]] & head[px[inside, 1], px[inside, 0]]
        out[k] = longest_dark_run(d) / m * float(np.linalg.norm(end[k] - start[k]))
    return out


def seal_lips(mesh: TexturedMesh, targets, mask_texture: torch.Tensor, fraction: float, smoothness: float,
              progress=print) -> tuple[TexturedMesh, dict]:
    """Move the lower lip's rim towards the upper one where every reference that sees it shows closed lips.

    Args:
        mesh: the mesh after a flow stage (template topology or refined; canonical frame, mm).
        targets: the expression's :class:`~gpja.register.hra.ExpressionTargets` (cameras, images (B, H, W, 3)
            float in [0, 1], coverage (B, H, W, 1)).
        mask_texture: (T, T, 1) float mouth mask, 0 = socket.
        fraction: in (0, 1]: how far along the segment to its upper partner a sealed rim vertex moves.
        smoothness: the displacement's smoothness (the flow stage's ``flow_smoothness``).
    Returns:
        the moved mesh and a log entry (``sealed`` rim vertices of ``lower``, their median move, seconds).
    """
    from gpja.register.flow import socket_vertices, solve_displacement
    from gpja.render import vertex_normals

    from scipy.spatial import cKDTree

    from gpja.errors import InputError

    start = time.perf_counter()
    socket = socket_vertices(mesh, mask_texture)
    try:
        lower, partner, rim, jaw = rim_pairs(mesh, socket)
    except InputError:  # a mask without a mouth (a template of another kind): nothing to seal
        lower = partner = rim = np.zeros(0, dtype=np.int64)
    entry = {"stage": "seal", "lower_rim": int(len(lower)), "seen": 0, "sealed": 0, "median_move_mm": 0.0,
             "vertices": int(len(mesh.V))}
    if not len(lower):
        entry["seconds"] = round(time.perf_counter() - start, 3)
        progress("seal: no lower lip on the mouth mask's rim; nothing moved")
        return mesh, entry
    V = mesh.V
    normals = vertex_normals(torch.from_numpy(V), torch.from_numpy(mesh.F)).numpy()
    images = targets.images.double().numpy()
    coverage = targets.coverage.double().numpy()[..., 0]
    gap = np.zeros(len(lower))
    seen = np.zeros(len(lower), dtype=bool)
    for b, camera in enumerate(targets.cameras):
        to_camera = camera.center[None, :] - V[lower]
        to_camera /= np.linalg.norm(to_camera, axis=1, keepdims=True)
        facing = (normals[lower] * to_camera).sum(1) >= MIN_FACING
        if not facing.any():
            continue
        runs = dark_gaps(camera, V[lower[facing]], V[partner[facing]], images[b].mean(-1), coverage[b])
        gap[facing] = np.maximum(gap[facing], runs)
        seen |= facing
    sealed = seen & (gap <= CONTACT_MM) & (np.linalg.norm(V[partner] - V[lower], axis=1) <= MAX_SEAL_MM)
    entry.update(seen=int(seen.sum()), sealed=int(sealed.sum()))
    if not sealed.any():
        entry["seconds"] = round(time.perf_counter() - start, 3)
        progress(f"seal: the references show the mouth open at all {int(seen.sum())} seen lower-rim vertices; "
                 "nothing moved")
        return mesh, entry
    target = np.full_like(V, np.nan)
    weight = np.zeros(len(V))
    distance = cKDTree(V[rim]).query(V)[0]
    stay = (distance > FAR_MM) | ((jaw <= 0.5) & ~socket)
    stay[np.setdiff1d(rim, lower)] = True  # the upper rim is where the lips meet: it stays, the lower one comes to it
    target[stay], weight[stay] = V[stay], 1.0
    target[lower] = V[lower]
    target[lower[sealed]] += fraction * (V[partner[sealed]] - V[lower[sealed]])
    weight[lower] = 1.0
    move = solve_displacement(V, mesh.F, target, weight, smoothness, spread_mm=np.inf)
    moved = mesh.with_vertices(V + move)
    entry.update(median_move_mm=round(float(np.median(np.linalg.norm(move[lower[sealed]], axis=1))), 3),
                 seconds=round(time.perf_counter() - start, 3))
    progress(f"seal: {entry['sealed']} of {entry['seen']} lower-rim vertices under closed lips moved "
             f"{fraction:.0%} of the way to the upper rim (median {entry['median_move_mm']:.1f} mm; "
             f"{entry['seconds']:.1f} s)")
    return moved, entry
