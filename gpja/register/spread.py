"""The lips' material spread between the mouth's corners (beyond the paper, ``Schedule.lip_spread``).

Why (docs/experiments.md, "The lips' material spread between the mouth's corners"): a child of the registration
tree starts from its parent's result, and a parent with pursed lips (the lip funneler) hands down lips whose
material is pressed towards the middle: before the first flow stage, S01 ``1_neutral``'s lower lip lies 3.3 mm
too far in on one side, seed 47's 3.9 and 3.1 mm on both. The lips are one colour, so neither the flow nor the
colour descent sees where their material lies along them; the flow moves the corners, which the skin's texture
around them shows, and the lips between them stay pressed. In the benchmark's ground truth the lips' material
lies between the corners as the template spreads it (0.2-0.3 mm off a proportional spread, median over the
shown lip band).

So, after the first flow stage: the corners are the skin just beyond either end of the mouth mask's rim (the
rim's ends are the inner corners, which a closed mouth hides; the mean of ``ANCHOR_VERTICES`` skin vertices
nearest each end, beyond it along x, is seen and placed by the flow). Every vertex within ``REACH_MM`` (in the
template) of the rim and between the corners keeps the share of the corners' span along x that the template
gives it: it moves along x to that share of the current span, faded out over the band's outer ``FADE_MM``,
and back onto the surface at the closest point. A mouth the template already spreads like the start is left
where it is (the shares agree). A band the spread would move by more than ``MAX_MEDIAN_SHIFT_MM`` (median) is
left alone: the flow carried the lower face sideways as a whole (a jaw turned sideways), which the template's
spread does not describe. No landmark or ground truth is read: the template, its mouth mask, the mesh.
"""
from __future__ import annotations

import time

import numpy as np
import torch

from gpja.errors import InputError
from gpja.mesh import TexturedMesh

#: the lips' band: vertices within this distance (mm, measured on the template) of the mouth mask's rim
REACH_MM = 14.0
#: the spread fades out linearly over the band's outer this many mm
FADE_MM = 6.0
#: each corner is the mean of this many skin vertices nearest the rim's end, beyond it along x
ANCHOR_VERTICES = 6
#: the spread is left out when it would move the band by more than this (mm, median): undoing a parent's pressed
#: lips moved it 0.5-2.2 mm on the benchmark's trees; a jaw turned sideways (``5_jaw_left``), whose lower lip and
#: chin the flow rightly carried sideways past the corners, 3.3-4.2 mm, and spreading it cost its mouth 1-2.6 mm
#: (docs/experiments.md, "The lips' material spread between the mouth's corners")
MAX_MEDIAN_SHIFT_MM = 2.5


def corner_anchors(template_V: np.ndarray, socket: np.ndarray, rim: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The left and right corners' anchor vertices: (k,) int64 each, the ``ANCHOR_VERTICES`` skin (non-socket)
    vertices nearest the rim's leftmost (rightmost) vertex on the template, beyond it along x.

    Args:
        template_V: (n, 3) float64 template positions, mm (x: the frame's left-right axis).
        socket: (n,) bool socket vertices. rim: (r,) int64 the socket's rim vertices.
    Raises:
        InputError: a rim end with no skin beyond it.
    """
    T = np.asarray(template_V, dtype=np.float64)
    ends = (rim[np.argmin(T[rim, 0])], rim[np.argmax(T[rim, 0])])
    anchors = []
    for end, side in zip(ends, (-1.0, 1.0)):
        candidates = np.flatnonzero(~socket & (side * (T[:, 0] - T[end, 0]) > 0))
        if not len(candidates):
            raise InputError("template", "no skin beyond an end of the mouth mask's rim")
        order = np.argsort(np.linalg.norm(T[candidates] - T[end], axis=1))
        anchors.append(candidates[order[:ANCHOR_VERTICES]])
    return anchors[0], anchors[1]


def spread_along_x(V: np.ndarray, template_V: np.ndarray, rim: np.ndarray, left: np.ndarray,
                   right: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The x-shifts that give the lips' band the template's shares of the corners' span.

    Args:
        V: (n, 3) float64 current positions, mm. template_V: (n, 3) float64 the template's, mm.
        rim: (r,) int64 the mouth mask's rim. left, right: (k,) int64 the corners' anchor vertices.
    Returns:
        shift (n,) float64 mm along x (0 outside the band) and the band's weight (n,) in [0, 1].
    """
    from scipy.spatial import cKDTree

    V = np.asarray(V, dtype=np.float64)
    T = np.asarray(template_V, dtype=np.float64)
    t_left, t_right = T[left, 0].mean(), T[right, 0].mean()
    share = (T[:, 0] - t_left) / (t_right - t_left)
    distance = cKDTree(T[rim]).query(T)[0]
    weight = np.clip((REACH_MM - distance) / FADE_MM, 0.0, 1.0) * ((share > 0.0) & (share < 1.0))
    x_left, x_right = V[left, 0].mean(), V[right, 0].mean()
    shift = np.where(weight > 0, weight * (x_left + share * (x_right - x_left) - V[:, 0]), 0.0)
    return shift, weight


def spread_lips(mesh: TexturedMesh, template_V: np.ndarray, mask_texture: torch.Tensor,
                progress=print) -> tuple[TexturedMesh, dict]:
    """``mesh`` with its lips' material spread between the mouth's corners as the template spreads it.

    Args:
        mesh: the mesh after the first flow stage (template topology; canonical frame, mm).
        template_V: (n, 3) float64 the template's positions on ``mesh``'s topology, mm.
        mask_texture: (T, T, 1) float mouth mask, 0 = socket.
    Returns:
        the moved mesh (same topology, texture coordinates) and a log entry (``stage`` "spread", ``moved``
        vertices, ``median_shift_mm``, ``max_shift_mm``, ``vertices``, ``seconds``; ``skipped_median_shift_mm``
        when the band's shift was over ``MAX_MEDIAN_SHIFT_MM`` and nothing moved).
    """
    from gpja.register.flow import socket_vertices
    from gpja.register.jaw import socket_rim
    from gpja.surface import prepare_surface

    start = time.perf_counter()
    entry = {"stage": "spread", "vertices": int(len(mesh.V)), "moved": 0, "median_shift_mm": 0.0, "max_shift_mm": 0.0}
    template_V = np.asarray(template_V, dtype=np.float64)
    if template_V.shape != mesh.V.shape:
        raise ValueError(f"the template's positions have shape {template_V.shape}, the mesh's {mesh.V.shape}")
    socket = socket_vertices(mesh, mask_texture)
    try:
        rim = socket_rim(mesh.F, socket)
        left, right = corner_anchors(template_V, socket, rim)
    except InputError:  # a mask without a mouth (a template of another kind): nothing to spread
        entry["seconds"] = round(time.perf_counter() - start, 3)
        progress("spread: no mouth on the mask's rim; nothing moved")
        return mesh, entry
    shift, weight = spread_along_x(mesh.V, template_V, rim, left, right)
    band = np.flatnonzero(weight > 0)
    size = np.abs(shift[band])
    median_shift = float(np.median(size)) if len(band) else 0.0
    if median_shift > MAX_MEDIAN_SHIFT_MM:
        entry.update(seconds=round(time.perf_counter() - start, 3), skipped_median_shift_mm=round(median_shift, 3))
        progress(f"spread: left out (it would move the lips' band {median_shift:.1f} mm by the median, over "
                 f"{MAX_MEDIAN_SHIFT_MM:g}: the lower face moved as a whole, a jaw sideways)")
        return mesh, entry
    V = np.array(mesh.V, dtype=np.float64)
    if len(band):
        moved = V[band].copy()
        moved[:, 0] += shift[band]
        V[band] = prepare_surface(mesh.V, mesh.F, find_boundary=False).closest(moved).point
        entry.update(moved=int(len(band)), median_shift_mm=round(median_shift, 3),
                     max_shift_mm=round(float(size.max()), 3))
    entry["seconds"] = round(time.perf_counter() - start, 3)
    progress(f"spread: {entry['moved']} vertices of the lips spread between the mouth's corners as the template "
             f"spreads them (shift median {entry['median_shift_mm']:.2f}, at most {entry['max_shift_mm']:.2f} mm; "
             f"{entry['seconds']:.1f} s)")
    return mesh.with_vertices(V), entry
