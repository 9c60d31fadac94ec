"""The 68 iBUG facial landmarks of a synthetic head, on its rest surface.

Layout (iBUG-68): jaw line 0-16 (from the subject's right, -X, to the left),
brows 17-26, nose bridge 27-30 and nostrils 31-35, eyes 36-47, outer lip
48-59, inner lip 60-67. Each landmark is placed from the head's construction
and snapped onto the rest surface; expression-space landmarks are
``phi_e(landmarks_rest)``.
"""
from __future__ import annotations

import math

import numpy as np

from gpja.data.synthetic.albedo import project_to_surface
from gpja.data.synthetic.head import EYE_RADIUS_MM, HeadParams, build_head_program

N_LANDMARKS = 68
NOSE_TIP = 30


def rest_landmark_guesses(p: HeadParams) -> np.ndarray:
    """(68, 3) float64 approximate landmark positions (before snapping), mm."""
    f, my, mw = p.face_length, p.mouth_y, p.mouth_half_width
    L = np.zeros((68, 3))
    jw = p.jaw_half_width + 6.0
    chin_y = -86.0 * f - 15.0 * f
    for k in range(17):
        t = (k - 8) / 8.0 * math.radians(85.0)
        L[k] = (jw * math.sin(t), -12.0 + (chin_y + 12.0) * math.cos(t) ** 1.5, 15.0 + 68.0 * math.cos(t))
    ex, ey = p.eye_half_spacing, 12.0
    ez = p.eye_center(1)[2]
    for i in range(5):  # right brow outer->inner, left brow inner->outer
        for s, idx in ((-1, 17 + i), (1, 26 - i)):
            u = 20.0 - 9.5 * i
            L[idx] = (s * (ex + u), ey + 17.0 + 3.0 * (1.0 - (u / 22.0) ** 2) - 0.06 * u, ez + 25.0)
    for i, (y, z) in enumerate(((14.0, 100.0), (3.0, 104.0), (-7.0, 110.0), (-14.0 * f, 118.0))):
        L[27 + i] = (0.0, y, z)
    for i, x in enumerate((-13.0, -6.5, 0.0, 6.5, 13.0)):
        L[31 + i] = (x * p.nose_width, -20.0 * f + (1.5 if i in (1, 3) else 0.0), 97.0)
    R = EYE_RADIUS_MM
    eye = [(-11.0, 0.0, 7.0), (-4.5, 6.0, 11.5), (4.5, 6.0, 11.5), (11.0, 0.0, 7.0), (4.5, -5.5, 11.5), (-4.5, -5.5, 11.5)]
    for s, base in ((-1, 36), (1, 42)):
        c = p.eye_center(s)
        pts = eye if s == -1 else [(-e[0], e[1], e[2]) for e in (eye[3], eye[2], eye[1], eye[0], eye[5], eye[4])]
        for i, (dx, dy, dz) in enumerate(pts):
            L[base + i] = c + np.array([dx if s == 1 else dx, dy, dz * (R + 1.0) / R])
    outer = [(-1.0, 0.0), (-0.62, 5.0), (-0.28, 7.0), (0.0, 6.0), (0.28, 7.0), (0.62, 5.0), (1.0, 0.0),
             (0.62, -6.0), (0.28, -8.0), (0.0, -8.5), (-0.28, -8.0), (-0.62, -6.0)]
    for i, (u, v) in enumerate(outer):
        L[48 + i] = (u * mw, my + v * f, 100.0 if abs(u) < 0.9 else 92.0)
    inner = [(-0.85, 0.0), (-0.4, 2.4), (0.0, 2.4), (0.4, 2.4), (0.85, 0.0), (0.4, -2.4), (0.0, -2.4), (-0.4, -2.4)]
    for i, (u, v) in enumerate(inner):
        L[60 + i] = (u * mw, my + v, 96.0 if abs(u) < 0.8 else 90.0)
    return L


def rest_landmarks(p: HeadParams) -> np.ndarray:
    """(68, 3) float64 landmarks on the rest surface, mm."""
    return project_to_surface(rest_landmark_guesses(p), build_head_program(p)["head"])
