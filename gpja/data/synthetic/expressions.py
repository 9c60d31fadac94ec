"""Expressions as smooth maps phi_e from rest space to expression space.

Each expression is a sum of "action unit" displacement fields with smooth
weights, evaluated on rest-space (material) points:
``phi_e(X) = X + sum_a d_a(X)``. Because the map is evaluated on material
points, the ground truth of any surface sample is exact.

Action units: jaw (open / sideways / forward, a weighted rigid motion of the
lower face), lip closing, lip-corner pull, pucker, cheek puff, lid close
(rotation of the upper lid about the eye's horizontal axis), brow raise /
lower, lip roll, mouth shift, chin raise.
"""
from __future__ import annotations

import math

import numpy as np

from gpja.data.synthetic.head import EYE_RADIUS_MM, HeadParams

#: FaceScape's 20 expressions, all implemented, in FaceScape order.
EXPRESSIONS: tuple[str, ...] = (
    "1_neutral", "2_smile", "3_mouth_stretch", "4_anger", "5_jaw_left", "6_jaw_right",
    "7_jaw_forward", "8_mouth_left", "9_mouth_right", "10_dimpler", "11_chin_raiser",
    "12_lip_puckerer", "13_lip_funneler", "14_sadness", "15_lip_roll", "16_grin",
    "17_cheek_blowing", "18_eye_closed", "19_brow_raiser", "20_brow_lower",
)
#: The default set of ten.
DEFAULT_EXPRESSIONS: tuple[str, ...] = (
    "1_neutral", "2_smile", "3_mouth_stretch", "5_jaw_left", "6_jaw_right",
    "12_lip_puckerer", "13_lip_funneler", "17_cheek_blowing", "18_eye_closed", "19_brow_raiser",
)

#: Closing the rest-pose lip gap (mm, total) so the lips just touch.
LIP_GAP_MM = 5.6
JAW_PIVOT_MM = np.array([0.0, -8.0, -2.0])

# Action-unit amounts of each expression (see :func:`expression_displacement`).
_RECIPES: dict[str, dict[str, float]] = {
    "1_neutral": {"lips_close": LIP_GAP_MM},
    "2_smile": {"lips_close": LIP_GAP_MM - 0.6, "corner_up": 6.0, "corner_out": 7.0, "corner_back": 4.0},
    "3_mouth_stretch": {"jaw_open": 22.0, "corner_out": 2.0, "corner_up": -1.0},
    "4_anger": {"lips_close": LIP_GAP_MM + 0.8, "brow_lower": 5.0, "corner_up": -1.5},
    "5_jaw_left": {"jaw_open": 4.0, "jaw_side": 7.0, "jaw_yaw": 4.0, "lips_close": LIP_GAP_MM - 1.5},
    "6_jaw_right": {"jaw_open": 4.0, "jaw_side": -7.0, "jaw_yaw": -4.0, "lips_close": LIP_GAP_MM - 1.5},
    "7_jaw_forward": {"jaw_open": 4.0, "jaw_forward": 7.0, "lips_close": LIP_GAP_MM - 1.5},
    "8_mouth_left": {"lips_close": LIP_GAP_MM, "mouth_side": 8.0},
    "9_mouth_right": {"lips_close": LIP_GAP_MM, "mouth_side": -8.0},
    "10_dimpler": {"lips_close": LIP_GAP_MM, "corner_back": 5.0, "corner_out": 2.0},
    "11_chin_raiser": {"lips_close": LIP_GAP_MM - 1.5, "chin_raise": 3.0},
    "12_lip_puckerer": {"lips_close": LIP_GAP_MM + 0.4, "pucker": 9.0},
    "13_lip_funneler": {"lips_close": -3.0, "pucker": 7.0, "jaw_open": 5.0},
    "14_sadness": {"lips_close": LIP_GAP_MM, "corner_up": -4.0, "inner_brow_raise": 5.0},
    "15_lip_roll": {"lips_close": LIP_GAP_MM + 0.5, "lip_roll": 4.0},
    "16_grin": {"jaw_open": 7.0, "lips_close": -1.0, "corner_up": 5.0, "corner_out": 9.0, "corner_back": 4.0},
    "17_cheek_blowing": {"lips_close": LIP_GAP_MM + 0.8, "cheek_puff": 9.0, "pucker": 3.0},
    "18_eye_closed": {"lips_close": LIP_GAP_MM, "lid_close": 1.0},
    "19_brow_raiser": {"lips_close": LIP_GAP_MM, "brow_raise": 8.0},
    "20_brow_lower": {"lips_close": LIP_GAP_MM, "brow_lower": 5.0},
}
assert tuple(_RECIPES) == EXPRESSIONS


def expression_number(expression: str) -> int:
    """FaceScape's number of an expression name ("3_mouth_stretch" -> 3)."""
    return int(expression.split("_", 1)[0])


def expression_recipe(expression: str) -> dict[str, float]:
    """Action-unit amounts of one expression (mm or degrees); raises KeyError if unknown."""
    if expression == "rest":
        return {}
    return dict(_RECIPES[expression])


def smoothstep(e0, e1, x):
    """Cubic Hermite step: 0 at ``e0``, 1 at ``e1`` (``e0 > e1`` gives a falling step)."""
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _gauss(X, c, s):
    q = (X - np.asarray(c, float)) / np.asarray(s, float)
    return np.exp(-np.sum(q * q, axis=-1))


def _rot_x(deg):
    a = math.radians(deg)
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def _rot_y(deg):
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def lower_face_weight(X: np.ndarray, p: HeadParams, lips_only: bool = False) -> np.ndarray:
    """Weight (n,) in [0, 1] of the jaw: 1 on the lower lip, chin and jaw, 0 above.

    The split runs through the middle of the mouth slit (narrow between the
    lips, widening towards the cheeks and inside the oral cavity) and fades
    towards the back of the head and down the neck.

    Args:
        X: (n, 3) rest points, mm.
    """
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    mw = p.mouth_half_width
    width = 4.5 + 20.0 * smoothstep(mw - 12.0, mw + 22.0, np.abs(x)) + 10.0 * smoothstep(86.0, 64.0, z)
    w = smoothstep(-0.5, 0.5, (p.mouth_y - y) / width)
    if not lips_only:
        w = w * smoothstep(-20.0, 30.0, z) * smoothstep(-138.0, -100.0, y)
    return w


def _jaw(X, p, open_deg, yaw_deg, side, fwd):
    w = lower_face_weight(X, p)
    R = _rot_y(yaw_deg) @ _rot_x(open_deg)
    moved = (X - JAW_PIVOT_MM) @ R.T + JAW_PIVOT_MM + np.array([side, 0.0, fwd + 0.25 * open_deg])
    return w[:, None] * (moved - X)


def _mouth_region(X, p, sx=12.0, sy=22.0):
    my = p.mouth_y
    return _gauss(X[:, :2], (0.0, my), (p.mouth_half_width + sx, sy)) * smoothstep(45.0, 72.0, X[:, 2])


def _lips_close(X, p, amount):
    """Upper lip down and lower lip up by amount/2 each (negative opens)."""
    w = lower_face_weight(X, p, lips_only=True)
    g = _mouth_region(X, p)
    d = np.zeros_like(X)
    d[:, 1] = 0.5 * amount * g * (2.0 * w - 1.0)
    return d


def _corners(X, p, up, out, back):
    d = np.zeros_like(X)
    front = smoothstep(50.0, 75.0, X[:, 2])
    for s in (-1.0, 1.0):
        g = _gauss(X[:, :2], (s * p.mouth_half_width, p.mouth_y), (14.0, 13.0)) * front
        d += g[:, None] * np.array([s * out, up, -back])
        if up > 0:
            gc = _gauss(X, (s * 40.0, -20.0 * p.face_length, 70.0), (16.0, 14.0, 20.0))
            d[:, 1] += 0.4 * up * gc
    return d


def _pucker(X, p, amount):
    g = _gauss(X[:, :2], (0.0, p.mouth_y), (p.mouth_half_width + 6.0, 16.0)) * smoothstep(55.0, 85.0, X[:, 2])
    d = np.zeros_like(X)
    d[:, 0] = -0.045 * amount * X[:, 0] * g
    d[:, 2] = amount * g
    return d


def _cheek_puff(X, p, amount):
    d = np.zeros_like(X)
    my = p.mouth_y
    for s in (-1.0, 1.0):
        g = _gauss(X, (s * 40.0, my + 10.0, 66.0), (17.0, 17.0, 20.0))
        v = X - np.array([s * 15.0, my + 8.0, 40.0])
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        d += amount * g[:, None] * v
    return d


#: Lateral distance from the eye centre at which the lid-closing rotation has faded out, mm.
CANTHUS_MM = 16.0


def _lid_close(X, p, amount):
    """Rotate the upper lids down over the eyeballs about the eyes' horizontal axes."""
    d = np.zeros_like(X)
    R = EYE_RADIUS_MM
    for s in (-1, 1):
        c = p.eye_center(s)
        q = X - c
        r = np.linalg.norm(q, axis=1)
        # the rotation fades out laterally so the canthi (eye corners, |q_x| ~ 11 mm)
        # move less than the lid's middle, as in a real blink
        w = (smoothstep(R + 0.25, R + 0.9, r) * smoothstep(-8.5, 8.5, q[:, 1])
             * smoothstep(R + 16.0, R + 6.0, r) * smoothstep(CANTHUS_MM, CANTHUS_MM - 6.0, np.abs(q[:, 0])))
        ang = np.radians(70.0) * amount * w
        ca, sa = np.cos(ang), np.sin(ang)
        d[:, 1] += (q[:, 1] * ca - q[:, 2] * sa) - q[:, 1]
        d[:, 2] += (q[:, 1] * sa + q[:, 2] * ca) - q[:, 2]
    return d


def _brows(X, p, raise_mm, lower_mm, inner_raise):
    d = np.zeros_like(X)
    R = EYE_RADIUS_MM
    front = smoothstep(50.0, 78.0, X[:, 2])
    for s in (-1, 1):
        c = p.eye_center(s)
        keep_lid = smoothstep(R + 2.0, R + 9.0, np.linalg.norm(X - c, axis=1))
        g = _gauss(X[:, :2], (c[0], c[1] + 20.0), (24.0, 16.0)) * front * keep_lid
        d[:, 1] += g * (raise_mm - lower_mm)
        d[:, 0] += g * (-s * 0.5 * lower_mm)
        d[:, 2] += g * 0.2 * lower_mm
        if inner_raise:
            gi = _gauss(X[:, :2], (c[0] - s * 10.0, c[1] + 18.0), (11.0, 12.0)) * front * keep_lid
            d[:, 1] += inner_raise * gi
    return d


def _lip_roll(X, p, amount):
    g = _gauss(X[:, :2], (0.0, p.mouth_y), (p.mouth_half_width + 2.0, 8.0)) * smoothstep(80.0, 95.0, X[:, 2])
    d = np.zeros_like(X)
    d[:, 2] = -amount * g
    return d


def _mouth_side(X, p, amount):
    g = _mouth_region(X, p, sx=8.0, sy=16.0)
    d = np.zeros_like(X)
    d[:, 0] = amount * g
    return d


def _chin_raise(X, p, amount):
    g = _gauss(X[:, :2], (0.0, p.mouth_y - 22.0), (26.0, 22.0)) * smoothstep(45.0, 75.0, X[:, 2])
    w = lower_face_weight(X, p, lips_only=True)
    d = np.zeros_like(X)
    d[:, 1] = amount * g * w
    d[:, 2] = 0.4 * amount * g * w
    return d


def expression_displacement(X: np.ndarray, p: HeadParams, expression: str) -> np.ndarray:
    """Displacement field ``phi_e(X) - X`` of one expression.

    Args:
        X: (n, 3) float64 rest-space points, mm.
        p: identity of the subject.
        expression: a FaceScape name from :data:`EXPRESSIONS` (or ``"rest"``).
    Returns:
        (n, 3) float64 displacements, mm.
    """
    X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
    a = expression_recipe(expression)
    d = np.zeros_like(X)
    if any(a.get(k, 0.0) for k in ("jaw_open", "jaw_yaw", "jaw_side", "jaw_forward")):
        d += _jaw(X, p, a.get("jaw_open", 0.0), a.get("jaw_yaw", 0.0), a.get("jaw_side", 0.0), a.get("jaw_forward", 0.0))
    if a.get("lips_close"):
        d += _lips_close(X, p, a["lips_close"])
    if any(a.get(k, 0.0) for k in ("corner_up", "corner_out", "corner_back")):
        d += _corners(X, p, a.get("corner_up", 0.0), a.get("corner_out", 0.0), a.get("corner_back", 0.0))
    if a.get("pucker"):
        d += _pucker(X, p, a["pucker"])
    if a.get("cheek_puff"):
        d += _cheek_puff(X, p, a["cheek_puff"])
    if a.get("lid_close"):
        d += _lid_close(X, p, a["lid_close"])
    if any(a.get(k, 0.0) for k in ("brow_raise", "brow_lower", "inner_brow_raise")):
        d += _brows(X, p, a.get("brow_raise", 0.0), a.get("brow_lower", 0.0), a.get("inner_brow_raise", 0.0))
    if a.get("lip_roll"):
        d += _lip_roll(X, p, a["lip_roll"])
    if a.get("mouth_side"):
        d += _mouth_side(X, p, a["mouth_side"])
    if a.get("chin_raise"):
        d += _chin_raise(X, p, a["chin_raise"])
    return d


def map_to_expression(X: np.ndarray, p: HeadParams, expression: str) -> np.ndarray:
    """``phi_e``: rest-space points (n, 3) mm -> expression-space points (n, 3) mm."""
    X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
    return X + expression_displacement(X, p, expression)


def central_jacobians(space_map, X: np.ndarray, h: float) -> np.ndarray:
    """(n, 3, 3) float64 central-difference Jacobians ``d space_map / d X`` at ``X (n, 3)`` mm, step ``h`` mm, of a
    map of space ``(n, 3) -> (n, 3)`` (an expression's ``phi_e``, or any other)."""
    X = np.asarray(X, dtype=np.float64)
    J = np.empty((len(X), 3, 3))
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        J[:, :, k] = (space_map(X + e) - space_map(X - e)) / (2 * h)
    return J


def jacobian_determinants(X: np.ndarray, p: HeadParams, expression: str, h: float = 1e-3) -> np.ndarray:
    """Central-difference det(d phi_e / d X) at rest points X (n, 3) mm -> (n,)."""
    return np.linalg.det(central_jacobians(lambda R: map_to_expression(R, p, expression), X, h))
