"""The jaw search (beyond the paper, ``Schedule.jaw_search_deg``): turn the lower face about a hinge before the flow.

Why (docs/experiments.md, "The jaw searched before the flow stage"): from a start whose mouth is open
(the template, ``3_mouth_stretch``) or half open (a lip funneler), a closed mouth needs the lower lip and
chin to travel 5-25 mm. The optical flow of the first flow stage (:mod:`gpja.register.flow`) does not
follow that motion: the socket's dark pixels vanish between render and reference, the lower lip's
luminance hardly differs from the skin, and the flow fills the chin, which has little texture, smoothly
between the lips and the still neck. Its matches put the chin's bottom 1-6 mm too low and the band under
the lower lip 1-3 mm too high, and no later stage takes that back. A jaw is one degree of freedom of a
head's lower face, and one number can be found by search where a descent does not (its colour loss
is a few percent deep over 20 degrees): the stage scores the render against the references at a grid
of pitch angles and keeps the best. The flow then starts with a few millimetres left to find.

The rig comes from the template's design, not from data: the mouth mask marks the socket, whose rim is
the lips' inner edge; the jaw is what lies below the mouth slit, fading out towards the ears and down
the neck in proportions of the head's own depth (:func:`jaw_weights`). A pose blends one rigid motion
into the vertices by their weights: ``x' = x + w (R (x - p) + p - x)`` (:func:`pose_jaw`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from gpja.errors import InputError
from gpja.mesh import TexturedMesh

#: Proportions of the jaw region, as fractions of the head's depth ``L`` (front of the face to the back of
#: the skull, mm). Anatomical rules of thumb: the mandible's ramus stands in front of the ear, about half
#: the head's depth behind the face; the chin's underside ends about a quarter of it below the mouth, and
#: the soft tissue under it follows the jaw part of the way to the hyoid.
JAW_BACK_FADE = (0.65, 0.40)      # weight 0 at 0.65 L behind the face front, 1 at 0.40 L
JAW_NECK_FADE = (0.45, 0.25)      # weight 0 at 0.45 L below the mouth, 1 at 0.25 L
JAW_CHEEK_WIDEN = 0.15            # the slit's split widens over 0.15 L beyond the mouth corners
JAW_SPLIT_MM = (3.0, 15.0)        # width (mm) of the split between the lips, and its growth at the cheeks
JAW_PIVOT = (0.50, 0.10)          # hinge: 0.50 L behind the face front, 0.10 L above the mouth
#: the search's coarse and fine steps (degrees): the coarse grid brackets the minimum, the fine one
#: (within a coarse step of it) places it
COARSE_STEP_DEG = 2.5
FINE_STEP_DEG = 0.5
#: the jaw turns only when the best pose's score is at least this fraction below the start's: a turn that
#: explains the images no better than the start is noise (a flat score, an expression that keeps the jaw)
MIN_GAIN = 0.01
#: the rig's blend between the jaw (weight 1) and the still skull (0) is a guess about soft tissue; the
#: hold (:mod:`gpja.register.hold`) releases the vertices whose weight lies strictly between these
BLEND_RELEASE = (0.05, 0.95)
#: the lips' own closing (``search_jaw``'s ``lips_mm``): a lip moves whole within the first distance (mm) of the
#: socket's rim and not at all beyond the second, the lower lip with the jaw's side, the upper with the skull's
LIP_FADE_MM = (6.0, 16.0)
#: the references are compared at this fraction of their resolution (the score is a sum over the face;
#: the chin's travel is tens of pixels at full size)
SEARCH_IMAGE_FACTOR = 2
#: the search over pitch and forward shift (``search_jaw``'s ``shift_mm``): its coarse grid's steps (degrees, mm);
#: the fine steps are ``FINE_STEP_DEG`` for the pitch and ``FINE_STEP_MM`` for the shift, within a coarse step
COARSE_2D_STEP_DEG = 5.0
COARSE_SHIFT_STEP_MM = 5.0
FINE_STEP_MM = 0.5
#: the mouth's window (``search_jaw``'s ``window_mm``) is the box of the start's vertices within that distance of the
#: socket's rim as each view sees them, widened by this many pixels of the compared (downsampled) images
WINDOW_MARGIN_PX = 4


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Cubic Hermite step: 0 at ``e0``, 1 at ``e1`` (``e0 > e1`` gives a falling step)."""
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def socket_rim(F: np.ndarray, socket: np.ndarray) -> np.ndarray:
    """(k,) int64 socket vertices that share a face with a vertex outside it: the lips' inner edge.

    Args:
        F: (m, 3) int faces. socket: (n,) bool (:func:`gpja.register.flow.socket_vertices`).
    Raises:
        InputError: no socket, or a rim of fewer than 4 vertices (no mouth to hinge).
    """
    if not socket.any() or socket.all():
        raise InputError("mouth mask", "marks no mouth socket on the template: the jaw search needs one")
    inside = socket[F]
    mixed = inside.any(1) & ~inside.all(1)
    rim = np.zeros(len(socket), dtype=bool)
    rim[F[mixed].ravel()] = True
    rim = np.flatnonzero(rim & socket)
    if len(rim) < 4:
        raise InputError("mouth mask", f"the mouth socket's rim has {len(rim)} vertices: no lips to hinge")
    return rim


@dataclass(frozen=True)
class JawRig:
    """Where the jaw is on one mesh.

    Attributes:
        weight: (n,) float64 in [0, 1], 1 on the lower lip, chin and jaw, 0 above the mouth and behind.
        pivot: (3,) float64 hinge point, mm.
    """

    weight: np.ndarray
    pivot: np.ndarray


def jaw_weights(V: np.ndarray, socket: np.ndarray, rim: np.ndarray) -> JawRig:
    """The jaw's per-vertex weight and hinge on a head in the canonical frame (module docstring).

    Args:
        V: (n, 3) float64 positions, mm, +Y up, +Z forward.
        socket: (n,) bool mouth-socket vertices; rim: (k,) int64 its rim (:func:`socket_rim`).
    Raises:
        InputError: no depth behind the mouth (not a head in the canonical frame).
    """
    V = np.asarray(V, dtype=np.float64)
    lips = V[rim]
    mouth = lips.mean(axis=0)
    half_width = float(np.percentile(np.abs(lips[:, 0] - mouth[0]), 98))
    front = float(V[:, 2].max())
    upper = V[(V[:, 1] > mouth[1]) & ~socket]
    depth = front - float(np.percentile(upper[:, 2] if len(upper) else V[:, 2], 1))
    if not depth > 0:
        raise InputError("template", "has no depth behind the mouth: not a head in the canonical frame")
    x, y, z = V[:, 0] - mouth[0], V[:, 1], V[:, 2]
    width = JAW_SPLIT_MM[0] + JAW_SPLIT_MM[1] * smoothstep(half_width, half_width + JAW_CHEEK_WIDEN * depth, np.abs(x))
    below = smoothstep(-0.5, 0.5, (mouth[1] - y) / width)
    back = smoothstep(front - JAW_BACK_FADE[0] * depth, front - JAW_BACK_FADE[1] * depth, z)
    neck = smoothstep(mouth[1] - JAW_NECK_FADE[0] * depth, mouth[1] - JAW_NECK_FADE[1] * depth, y)
    # the socket's walls have no neck or back to fade to: their lower wall follows the jaw whole
    weight = np.where(socket, below, below * back * neck)
    pivot = np.array([mouth[0], mouth[1] + JAW_PIVOT[1] * depth, front - JAW_PIVOT[0] * depth])
    return JawRig(weight, pivot)


def limit_reach(rig: JawRig, V: np.ndarray, rim: np.ndarray, reach_mm: tuple[float, float]) -> JawRig:
    """``rig`` with its weights faded out from ``reach_mm[0]`` to ``reach_mm[1]`` mm from the socket's ``rim``
    (k,) on ``V`` (n, 3) mm: the chin and lips move with the jaw, the neck under it does not.

    Why (docs/experiments.md, "The jaw searched in the mouth's window"): the rig's weights run 40-60 mm down the
    neck, and a turn of 25 degrees (from the wide-open template to a closed mouth) swings that skin 20 mm about
    the hinge, where the ground truth moves it by 5-7.
    """
    from scipy.spatial import cKDTree

    distance = cKDTree(np.asarray(V, dtype=np.float64)[rim]).query(V)[0]
    return JawRig(rig.weight * smoothstep(float(reach_mm[1]), float(reach_mm[0]), distance), rig.pivot)


def pitch_matrix(degrees: float) -> np.ndarray:
    """(3, 3) rotation by ``degrees`` about +X, which turns +Y towards +Z. On a head facing +Z with the hinge
    behind and above the mouth, a negative angle swings the chin forward and up: it closes the jaw."""
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def pose_jaw(V: np.ndarray, rig: JawRig, degrees: float, shift_mm: float = 0.0) -> np.ndarray:
    """(n, 3) ``V + w (R (V - p) + p + s z - V)``: the jaw of ``V`` (n, 3) mm turned by ``degrees`` about the rig's
    hinge (x axis) and moved ``shift_mm`` forward (+Z; 0 = the turn alone), blended by its weights.

    A turn and a forward shift together are a turn about another hinge in the face's midplane: the shift covers
    the rig's guess of the hinge and the condyle's glide, which carries the jaw forward as the mouth opens wide
    (so that closing a wide-open mouth brings the chin up and forward rather than up alone)."""
    moved = (V - rig.pivot) @ pitch_matrix(degrees).T + rig.pivot
    moved[:, 2] += float(shift_mm)
    return V + rig.weight[:, None] * (moved - V)


def lip_weights(V: np.ndarray, rim: np.ndarray, rig: JawRig) -> tuple[np.ndarray, np.ndarray]:
    """(n,) float64 weights in [0, 1] of the lower and the upper lip: the vertices near the socket's ``rim`` (k,)
    (``LIP_FADE_MM``), split by the rig's jaw weight (the lower lip is the jaw's side of the slit)."""
    from scipy.spatial import cKDTree

    distance = cKDTree(np.asarray(V, dtype=np.float64)[rim]).query(V)[0]
    near = smoothstep(LIP_FADE_MM[1], LIP_FADE_MM[0], distance)
    return rig.weight * near, (1.0 - rig.weight) * near


def lift(V: np.ndarray, weight: np.ndarray, mm: float) -> np.ndarray:
    """(n, 3) ``V`` moved by ``mm`` along +Y (up in the canonical frame), scaled by ``weight`` (n,)."""
    out = np.array(V, dtype=np.float64)
    out[:, 1] += weight * mm
    return out


def unpose_jaw(V: np.ndarray, rig: JawRig, degrees: float, shift_mm: float = 0.0) -> np.ndarray:
    """The inverse of :func:`pose_jaw` where the weight is 0 or 1 (a blend has no closed-form inverse elsewhere)."""
    unshifted = np.array(V, dtype=np.float64)
    unshifted[:, 2] -= float(shift_mm)
    back = (unshifted - rig.pivot) @ pitch_matrix(degrees) + rig.pivot
    return V + rig.weight[:, None] * (back - V)


def search_grid(lo: float, hi: float, score: Callable[[float], float]) -> tuple[float, list[tuple[float, float]]]:
    """The value in [``lo``, ``hi``] of the lowest ``score``: a coarse grid (``COARSE_STEP_DEG``, both ends
    included), then a fine one within a coarse step of its best. Returns the value and every (value, score)
    tried, in order. Ties go to the value nearest 0 (no motion). The jaw's pitch searches degrees, the lips'
    lift (``search_jaw``'s ``lips_mm``) millimetres on the same steps."""
    tried: dict[float, float] = {}

    def best_of(angles: np.ndarray) -> float:
        for a in angles:
            a = round(float(a), 6)
            if a not in tried:
                tried[a] = float(score(a))
        return min(tried, key=lambda a: (tried[a], abs(a)))

    coarse = np.unique(np.append(np.arange(lo, hi, COARSE_STEP_DEG), hi))
    b = best_of(coarse)
    fine = np.arange(max(lo, b - COARSE_STEP_DEG), min(hi, b + COARSE_STEP_DEG) + 1e-9, FINE_STEP_DEG)
    b = best_of(fine)
    return b, list(tried.items())


def search_grid_2d(pitch: tuple[float, float], shift: tuple[float, float],
                   score: Callable[[float, float], float]) -> tuple[tuple[float, float], list[tuple[float, float, float]]]:
    """The (pitch, shift) in [``pitch``] x [``shift``] of the lowest ``score(pitch, shift)``: a coarse grid
    (``COARSE_2D_STEP_DEG`` x ``COARSE_SHIFT_STEP_MM``, the ends and 0 included), then the pitch on the fine step
    within a coarse step of the best at its shift, then the shift likewise at that pitch. Returns the pair and every
    (pitch, shift, score) tried, in order. Ties go to the pair nearest (0, 0) (no motion)."""
    tried: dict[tuple[float, float], float] = {}

    def best_of(pairs) -> tuple[float, float]:
        for a, t in pairs:
            key = (round(float(a), 6), round(float(t), 6))
            if key not in tried:
                tried[key] = float(score(*key))
        return min(tried, key=lambda k: (tried[k], abs(k[0]) + abs(k[1])))

    def axis(lo: float, hi: float, step: float) -> np.ndarray:
        return np.unique(np.concatenate([np.arange(lo, hi, step), [lo, hi, 0.0]]))

    a, t = best_of((a, t) for a in axis(*pitch, COARSE_2D_STEP_DEG) for t in axis(*shift, COARSE_SHIFT_STEP_MM))
    fine_a = np.arange(max(pitch[0], a - COARSE_2D_STEP_DEG), min(pitch[1], a + COARSE_2D_STEP_DEG) + 1e-9, FINE_STEP_DEG)
    a, t = best_of((x, t) for x in fine_a)
    fine_t = np.arange(max(shift[0], t - COARSE_SHIFT_STEP_MM), min(shift[1], t + COARSE_SHIFT_STEP_MM) + 1e-9,
                       FINE_STEP_MM)
    a, t = best_of((a, x) for x in fine_t)
    return (a, t), [(k[0], k[1], v) for k, v in tried.items()]


def mouth_window(V: np.ndarray, rim: np.ndarray, cameras, height: int, width: int, radius_mm: float) -> torch.Tensor:
    """(B, height, width, 1) float32 in {0, 1}: per camera, the box around what lies near the mouth.

    Args:
        V: (n, 3) float64 the start's vertices, mm; rim: (k,) int64 the socket's rim (:func:`socket_rim`).
        cameras: B cameras of images ``height`` x ``width`` px (the compared, downsampled ones).
        radius_mm: the vertices within this distance of the rim make the box (widened by ``WINDOW_MARGIN_PX``).
    """
    from scipy.spatial import cKDTree

    V = np.asarray(V, dtype=np.float64)
    near = V[cKDTree(V[rim]).query(V)[0] <= radius_mm]
    window = torch.zeros((len(cameras), height, width, 1))
    for b, camera in enumerate(cameras):
        xy, z = camera.project(near)
        xy = xy[z > 0]
        if not len(xy):
            continue
        x0, y0 = np.clip(np.floor(xy.min(0)).astype(int) - WINDOW_MARGIN_PX, 0, [width, height])
        x1, y1 = np.clip(np.ceil(xy.max(0)).astype(int) + WINDOW_MARGIN_PX + 1, 0, [width, height])
        window[b, y0:y1, x0:x1] = 1.0
    return window


def colour_score(mesh: TexturedMesh, targets, texture: torch.Tensor, mask_texture: torch.Tensor,
                 render: Callable | None = None, window_mm: float | None = None,
                 rim: np.ndarray | None = None) -> Callable[[np.ndarray], float]:
    """``score(V)``: the mean absolute colour difference between ``mesh`` with vertices ``V`` (n, 3) mm, rendered
    with the shared texture under the capture's lighting, and the references, over every pixel of every view
    (``window_mm`` None) or over the mouth's window (:func:`mouth_window` of ``mesh``'s vertices within
    ``window_mm`` of the socket's rim; ``rim`` (k,) int64, :func:`socket_rim`, when the caller has it).

    The reference counts only where the scan covers it (the head, not the backdrop), and the mean is over the
    whole image or window, a fixed denominator: a pose that turns the chin out of the render pays for the
    uncovered reference instead of leaving the sum (the escape of a loss normalised by the render's coverage).

    Why a window (docs/experiments.md, "The jaw searched in the mouth's window"): over the whole image, the
    rig's guess at the neck and cheeks, which a turn drags along, outweighs the mouth, a few hundred pixels of
    a view; from the wide-open template, closing the jaw scored 2 % worse than leaving it open.
    """
    from gpja.render import Topology, render_views

    render = render or render_views
    small = targets.downsampled(SEARCH_IMAGE_FACTOR)
    reference = small.images * small.coverage.clamp(0.0, 1.0)
    weight = None
    if window_mm is not None:
        if rim is None:
            from gpja.register.flow import socket_vertices

            rim = socket_rim(mesh.F, socket_vertices(mesh, mask_texture))
        weight = mouth_window(mesh.V, rim, small.cameras, reference.shape[1], reference.shape[2], float(window_mm))
        weight = weight / weight.sum().clamp(min=1.0)
    topo = Topology(torch.from_numpy(mesh.F), torch.from_numpy(mesh.F_uv))
    uv = torch.tensor(mesh.UV, dtype=torch.float32)

    def score(V: np.ndarray) -> float:
        with torch.no_grad():
            out = render(torch.tensor(V, dtype=torch.float32), topo, small.cameras, ("color",), uv=uv,
                         texture=texture, mask_texture=mask_texture, sh=small.sh, cull_backfaces=True)
            difference = (out.dense("color") - reference).abs()
            if weight is None:
                return float(difference.mean())
            return float((difference.mean(dim=-1, keepdim=True) * weight).sum())

    return score


def blend_release(weight: np.ndarray) -> np.ndarray:
    """(n,) float64 factor of the hold's weights after a turn: 0 where the rig's ``weight`` (n,) blends the jaw
    into the skull (strictly inside ``BLEND_RELEASE``), 1 where the vertex turned rigidly or not at all.

    Why: the hold pulls what the first flow stage did not move back to where the registration started, which
    after a turn is the turned mesh. Where the weight is 1 that keeps a rigid jaw (the lower lip and chin, which
    the flow does not follow); where it is 0 the start; in between the blend, a guess about the cheeks and the
    skin under the chin that the data should correct rather than the hold keep."""
    weight = np.asarray(weight, dtype=np.float64)
    return np.where((weight > BLEND_RELEASE[0]) & (weight < BLEND_RELEASE[1]), 0.0, 1.0)


def search_jaw(mesh: TexturedMesh, targets, texture: torch.Tensor, mask_texture: torch.Tensor,
               range_deg: tuple[float, float], render: Callable | None = None,
               progress: Callable[[str], None] = print,
               lips_mm: tuple[float, float] | None = None, shift_mm: tuple[float, float] | None = None,
               window_mm: float | None = None,
               reach_mm: tuple[float, float] | None = None) -> tuple[TexturedMesh, dict, JawRig]:
    """Turn ``mesh``'s jaw to the pitch in ``range_deg`` whose render best matches the references, when it matches
    them at least ``MIN_GAIN`` better than the start (else the start stays, pitch 0).

    Args:
        mesh: the start (template topology, mm, canonical frame) with UVs.
        targets: the expression's :class:`~gpja.register.hra.ExpressionTargets`.
        texture: (T, T, 3) shared albedo; mask_texture: (T', T', 1) mouth mask (0 = socket).
        range_deg: (lo, hi) pitch angles searched, degrees (0 = the start's pose; negative closes).
        lips_mm: (lo, hi) or None: after a turn, the lower lip's lift and then the upper lip's (mm along +Y,
            :func:`lip_weights`) are searched in this range too, each by the same grid (the lips' own closing,
            which the flow stage cannot see either); None = the turn alone.
        shift_mm: (lo, hi) or None: the jaw's forward shift (mm along +Z, :func:`pose_jaw`) is searched with the
            pitch (:func:`search_grid_2d`); None = the pitch alone (:func:`search_grid`).
        window_mm: None = the score over the whole images; else over the mouth's window (:func:`colour_score`).
        reach_mm: None = the rig's weights; else (near, far): they fade out between these distances (mm) from the
            socket's rim (:func:`limit_reach`).
    Returns:
        the posed mesh, a log entry (the angle and shift, the score at them and at the start, every pose tried,
        seconds) and the rig.
    Raises:
        InputError: the mask marks no socket (:func:`socket_rim`).
    """
    from gpja.register.flow import socket_vertices

    start = time.perf_counter()
    socket = socket_vertices(mesh, mask_texture)
    rim = socket_rim(mesh.F, socket)
    rig = jaw_weights(mesh.V, socket, rim)
    if reach_mm is not None:
        rig = limit_reach(rig, mesh.V, rim, reach_mm)
    score_of = colour_score(mesh, targets, texture, mask_texture, render, window_mm, rim)
    if shift_mm is None:
        found_pitch, tried = search_grid(float(range_deg[0]), float(range_deg[1]),
                                         lambda a: score_of(pose_jaw(mesh.V, rig, a)))
        found, tried = (found_pitch, 0.0), [(a, 0.0, s) for a, s in tried]
    else:
        found, tried = search_grid_2d((float(range_deg[0]), float(range_deg[1])),
                                      (float(shift_mm[0]), float(shift_mm[1])),
                                      lambda a, t: score_of(pose_jaw(mesh.V, rig, a, t)))
    scores = {(a, t): s for a, t, s in tried}
    at_zero = scores[(0.0, 0.0)] if (0.0, 0.0) in scores else score_of(mesh.V)
    best = found if scores[found] <= (1.0 - MIN_GAIN) * at_zero else (0.0, 0.0)
    entry = {"stage": "jaw", "pitch_deg": best[0], "best_pitch_deg": found[0], "score": round(scores.get(best, at_zero), 6),
             "score_at_start": round(at_zero, 6),
             "tried": [[a, round(s, 6)] for a, _, s in tried] if shift_mm is None
             else [[a, t, round(s, 6)] for a, t, s in tried],
             "pivot_mm": rig.pivot.round(3).tolist(),
             "jaw_fraction": round(float(np.mean(rig.weight > 0.5)), 4), "vertices": int(len(mesh.V)),
             "seconds": round(time.perf_counter() - start, 3)}
    if shift_mm is not None:
        entry.update(shift_mm=best[1], best_shift_mm=found[1])
    if window_mm is not None:
        entry["window_mm"] = float(window_mm)
    shift_text = "" if shift_mm is None else f", {found[1]:+.1f} mm forward"
    if best == (0.0, 0.0):
        progress(f"jaw: stays (the best pose, {found[0]:+.1f} deg{shift_text}, matches the images "
                 f"{1 - scores[found] / at_zero:.1%} better, under {MIN_GAIN:.0%}; {len(tried)} poses, "
                 f"{entry['seconds']:.1f} s)")
        return mesh, entry, rig
    V = pose_jaw(mesh.V, rig, *best)
    final = scores[best]
    if lips_mm is not None:
        lower, upper = lip_weights(mesh.V, rim, rig)
        for name, weight in (("lower_lip_mm", lower), ("upper_lip_mm", upper)):
            moved, tried_lip = search_grid(float(lips_mm[0]), float(lips_mm[1]), lambda t: score_of(lift(V, weight, t)))
            V = lift(V, weight, moved)
            final = dict(tried_lip)[moved]
            entry[name] = moved
            entry[name.replace("_mm", "_tried")] = [[a, round(s, 6)] for a, s in tried_lip]
        entry["score"] = round(final, 6)
    entry["seconds"] = round(time.perf_counter() - start, 3)
    lips = "" if lips_mm is None else f", lips {entry['lower_lip_mm']:+.1f} / {entry['upper_lip_mm']:+.1f} mm"
    moved = "" if shift_mm is None else f" and {best[1]:+.1f} mm forward"
    progress(f"jaw: turned {best[0]:+.1f} deg about the hinge{moved}{lips} (colour {at_zero:.5f} -> {final:.5f}; "
             f"{entry['seconds']:.1f} s)")
    return mesh.with_vertices(V), entry, rig
