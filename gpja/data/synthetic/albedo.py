"""Procedural albedo on the rest (material) surface.

The colour of a surface point is a function of its rest-space coordinates
only, so it moves with the skin. It carries high-frequency, non-repeating
detail a photometric term can lock on to: pores, freckles, moles, brow hair,
lip colour, iris and sclera, a dark oral cavity, hair on the scalp.
"""
from __future__ import annotations

import math

import numba
import numpy as np

from gpja.data.synthetic.head import EYE_RADIUS_MM, HeadParams, _sdf_point, build_head_program

_MOLES = 10


@numba.njit(cache=True, inline="always")
def _hash3(i, j, k, seed):
    h = (i * 73856093) ^ (j * 19349663) ^ (k * 83492791) ^ (seed * 2654435761)
    h = h & 0xFFFFFFFF
    h = ((h >> 16) ^ h) * 0x45D9F3B
    h = h & 0xFFFFFFFF
    h = ((h >> 16) ^ h) * 0x45D9F3B
    h = h & 0xFFFFFFFF
    h = (h >> 16) ^ h
    return (h & 0xFFFFFF) / 16777216.0


@numba.njit(cache=True)
def _value_noise(x, y, z, seed):
    fx, fy, fz = math.floor(x), math.floor(y), math.floor(z)
    i, j, k = int(fx), int(fy), int(fz)
    tx, ty, tz = x - fx, y - fy, z - fz
    tx = tx * tx * (3 - 2 * tx)
    ty = ty * ty * (3 - 2 * ty)
    tz = tz * tz * (3 - 2 * tz)
    acc = 0.0
    for a in range(2):
        wa = tx if a else 1 - tx
        for b in range(2):
            wb = ty if b else 1 - ty
            for c in range(2):
                wc = tz if c else 1 - tz
                acc += wa * wb * wc * _hash3(i + a, j + b, k + c, seed)
    return acc


@numba.njit(cache=True)
def _fbm(x, y, z, seed, octaves):
    s, amp, norm = 0.0, 0.5, 0.0
    for o in range(octaves):
        s += amp * _value_noise(x, y, z, seed + 17 * o)
        norm += amp
        x, y, z = 2.03 * x + 0.31, 2.03 * y + 0.17, 2.03 * z + 0.53
        amp *= 0.5
    return s / norm


@numba.njit(cache=True)
def _spots(x, y, z, cell, seed, prob):
    """Darkness in [0, 1] of sparse round spots, one possible spot per cell."""
    gx, gy, gz = x / cell, y / cell, z / cell
    i, j, k = int(math.floor(gx)), int(math.floor(gy)), int(math.floor(gz))
    if _hash3(i, j, k, seed) > prob:
        return 0.0
    cx = i + 0.3 + 0.4 * _hash3(i, j, k, seed + 1)
    cy = j + 0.3 + 0.4 * _hash3(i, j, k, seed + 2)
    cz = k + 0.3 + 0.4 * _hash3(i, j, k, seed + 3)
    rad = 0.12 + 0.16 * _hash3(i, j, k, seed + 4)
    d = math.sqrt((gx - cx) ** 2 + (gy - cy) ** 2 + (gz - cz) ** 2) / rad
    if d >= 1.0:
        return 0.0
    t = 1.0 - d
    return (0.5 + 0.5 * _hash3(i, j, k, seed + 5)) * min(1.0, 3.0 * t)


@numba.njit(cache=True, inline="always")
def _sstep(e0, e1, x):
    t = min(max((x - e0) / (e1 - e0), 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


@numba.njit(cache=True, inline="always")
def _mix(a0, a1, a2, b0, b1, b2, t):
    return a0 + (b0 - a0) * t, a1 + (b1 - a1) * t, a2 + (b2 - a2) * t


@numba.njit(cache=True, parallel=True)
def _albedo_kernel(P, q, pocket, lips, moles, out):
    # q: scalar parameters, see evaluate_albedo
    seed = int(q[0])
    sk0, sk1, sk2 = q[1], q[2], q[3]
    ir0, ir1, ir2 = q[4], q[5], q[6]
    hr0, hr1, hr2 = q[7], q[8], q[9]
    freck = q[10]
    _mouth_y, mw, lipz = q[11], q[12], q[13]
    ex, ey, ez = q[14], q[15], q[16]
    R = q[17]
    for n in numba.prange(P.shape[0]):
        x, y, z = P[n, 0], P[n, 1], P[n, 2]
        # --- skin -------------------------------------------------------------
        low = _fbm(x / 28.0, y / 28.0, z / 28.0, seed, 3) - 0.5
        mid = _fbm(x / 5.0, y / 5.0, z / 5.0, seed + 101, 2) - 0.5
        pore = _value_noise(x / 0.55, y / 0.55, z / 0.55, seed + 202) - 0.5
        shade = 1.0 + 0.22 * low + 0.10 * mid + 0.10 * pore
        r, g, b = sk0 * shade, sk1 * shade, sk2 * shade
        # redness on cheeks and nose
        red = math.exp(-(((abs(x) - 40.0) / 18.0) ** 2 + ((y + 20.0) / 16.0) ** 2)) + \
            math.exp(-((x / 10.0) ** 2 + ((y + 8.0) / 14.0) ** 2)) * _sstep(95.0, 105.0, z)
        r, g, b = r * (1.0 + 0.10 * red), g * (1.0 - 0.06 * red), b * (1.0 - 0.04 * red)
        # freckles (denser on the cheeks and nose), two offset grids
        dens = freck * (0.25 + 0.75 * math.exp(-((abs(x) - 25.0) / 30.0) ** 2 - ((y + 10.0) / 25.0) ** 2))
        sp = max(_spots(x, y, z, 2.6, seed + 303, 0.35 * dens),
                 _spots(x + 1.1, y + 0.7, z + 1.9, 3.7, seed + 404, 0.3 * dens))
        r, g, b = _mix(r, g, b, r * 0.55, g * 0.42, b * 0.36, 0.8 * sp)
        # moles
        for m in range(moles.shape[0]):
            dm = math.sqrt((x - moles[m, 0]) ** 2 + (y - moles[m, 1]) ** 2 + (z - moles[m, 2]) ** 2)
            t = _sstep(moles[m, 3], 0.6 * moles[m, 3], dm)
            r, g, b = _mix(r, g, b, 0.22 * sk0, 0.15 * sk1, 0.12 * sk2, 0.9 * t)
        # hair on the scalp (front hairline, sides above the ears, the back)
        hairline = 62.0 - 70.0 * _sstep(60.0, -60.0, z)
        ear = min(math.sqrt((abs(x) - 74.0) ** 2 + y * y + (z + 8.0) ** 2) / 36.0, 1.0)
        hm = _sstep(-2.0, 3.0, y - hairline - 6.0 * (_fbm(x / 6.0, 0.0, z / 6.0, seed + 505, 2) - 0.5)) * _sstep(0.85, 1.0, ear)
        if hm > 0.0:
            streak = _fbm(x / 1.2, y / 9.0, z / 1.2, seed + 606, 3)
            hs = 0.6 + 0.8 * streak
            r, g, b = _mix(r, g, b, hr0 * hs, hr1 * hs, hr2 * hs, hm)
        # eyebrows: arcs above each eye
        for s in (-1.0, 1.0):
            u = (x - s * ex) * s  # positive towards the temple
            cy = ey + 17.0 + 3.0 * (1.0 - (u / 22.0) ** 2) - 0.06 * u
            dist = abs(y - cy) / (4.2 - 0.06 * u)
            if abs(u + 2.0) < 26.0 and dist < 1.5 and z > 55.0:
                hair = _fbm(x / 0.9, y / 3.5, z / 0.9, seed + 707, 2)
                t = _sstep(1.3, 0.6, dist) * _sstep(26.0, 19.0, abs(u + 2.0)) * (0.55 + 0.45 * hair)
                r, g, b = _mix(r, g, b, hr0 * 0.8, hr1 * 0.8, hr2 * 0.8, t)
        # lips
        dl = 1e9
        for m in range(lips.shape[0]):
            dl = min(dl, _sdf_point(x, y, z, lips[m:m + 1]))
        tl = _sstep(1.8, -0.5, dl) * _sstep(mw + 4.0, mw - 1.0, abs(x)) * _sstep(70.0, 82.0, z)
        r, g, b = _mix(r, g, b, sk0 * 0.85 + 0.06, sk1 * 0.55, sk2 * 0.62, 0.75 * tl)
        # oral cavity: dark, deeper means darker
        dp = -_sdf_point(x, y, z, pocket)
        tm = _sstep(2.0, 0.3, abs(dp)) * _sstep(lipz - 7.0, lipz - 14.0, z)
        r, g, b = _mix(r, g, b, 0.07, 0.025, 0.025, tm)
        # eyes: eyeball (iris, pupil, sclera) and lash line on the upper lid
        for s in (-1.0, 1.0):
            dx, dy, dz = x - s * ex, y - ey, z - ez
            rr = math.sqrt(dx * dx + dy * dy + dz * dz)
            if rr < R + 0.3:
                ang = math.degrees(math.acos(min(1.0, max(-1.0, dz / max(rr, 1e-9)))))
                vein = _fbm(x / 1.5, y / 1.5, z / 1.5, seed + 808, 2)
                r, g, b = 0.86, 0.80 - 0.12 * vein, 0.76 - 0.14 * vein
                if ang < 31.0:
                    phi = math.atan2(dy, dx)
                    st = _value_noise(8.0 * phi, ang / 3.0, 0.0, seed + 909)
                    k = 0.55 + 0.6 * st
                    r, g, b = ir0 * k, ir1 * k, ir2 * k
                    if ang > 27.0:
                        r, g, b = r * 0.5, g * 0.5, b * 0.5
                    if ang < 12.0:
                        r, g, b = 0.03, 0.03, 0.035
                        if abs(ang - 6.0) < 1.5 and dy > 0 and dx * s < 0:
                            r, g, b = 0.5, 0.5, 0.5  # catch light spot
            elif rr < R + 2.2 and dy > -1.0:
                t = _sstep(R + 2.2, R + 0.9, rr) * _sstep(-1.0, 2.0, dy)
                r, g, b = _mix(r, g, b, 0.06, 0.045, 0.04, t)
        out[n, 0] = min(max(r, 0.0), 1.0)
        out[n, 1] = min(max(g, 0.0), 1.0)
        out[n, 2] = min(max(b, 0.0), 1.0)


def skin_rgb(p: HeadParams) -> np.ndarray:
    """(3,) base skin albedo of a subject from its tone (0 light .. 1 dark) and hue."""
    light = np.array([0.80, 0.60, 0.50])
    dark = np.array([0.38, 0.24, 0.17])
    rgb = light + (dark - light) * p.skin_tone
    rgb = rgb * (1.0 + 0.05 * p.skin_hue * np.array([1.0, -0.4, -0.8]))
    return rgb


def albedo_tables(p: HeadParams) -> dict[str, np.ndarray]:
    """Packed per-subject parameters of :func:`evaluate_albedo` (deterministic in ``p``)."""
    rng = np.random.default_rng(p.albedo_seed)
    iris = np.array([0.25, 0.40, 0.55]) + (np.array([0.35, 0.20, 0.08]) - np.array([0.25, 0.40, 0.55])) * p.iris_hue
    hair = np.array([0.05, 0.04, 0.035]) + (np.array([0.35, 0.22, 0.12]) - np.array([0.05, 0.04, 0.035])) * p.hair_tone
    le = p.eye_center(1)
    q = np.concatenate([[p.albedo_seed % 100000], skin_rgb(p), iris, hair, [p.freckle_density],
                        [p.mouth_y, p.mouth_half_width, p.lip_front_z], le, [EYE_RADIUS_MM]])
    prog = build_head_program(p)
    pocket = prog["pocket"].copy()
    pocket[:, 0], pocket[:, 1] = 0.0, 3.0
    head = prog["head"]
    lip_rows = head[[i for i in range(len(head)) if head[i, 0] == 0 and abs(head[i, 3] - p.mouth_y) < 9.0
                     and head[i, 4] > 85.0 and head[i, 5] > 15.0]].copy()
    lip_rows[:, 0], lip_rows[:, 1] = 0.0, 0.0
    # moles: random face/neck points (rest frame), radius 0.8-1.8 mm
    n = _MOLES
    ang = rng.uniform(-1.2, 1.2, n)
    yy = rng.uniform(-110.0, 40.0, n)
    moles = np.stack([75.0 * np.sin(ang), yy, 20.0 + 80.0 * np.cos(ang), rng.uniform(0.8, 1.8, n)], 1)
    # snap mole centres onto the surface by a few Newton steps along the SDF gradient
    moles[:, :3] = project_to_surface(moles[:, :3], head)
    return {"q": q, "pocket": pocket, "lips": lip_rows, "moles": moles}


def project_to_surface(X: np.ndarray, program: np.ndarray, iters: int = 20) -> np.ndarray:
    """Move points (n, 3) mm onto the zero set of ``program`` along the SDF gradient."""
    from gpja.data.synthetic.head import evaluate_sdf

    X = np.array(X, dtype=np.float64)
    h = 1e-3
    for _ in range(iters):
        d = evaluate_sdf(X, program)
        g = np.stack([(evaluate_sdf(X + e, program) - evaluate_sdf(X - e, program)) / (2 * h)
                      for e in np.eye(3) * h], 1)
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        X -= d[:, None] * g
    return X


def evaluate_albedo(points: np.ndarray, tables: dict[str, np.ndarray]) -> np.ndarray:
    """Albedo of rest-space surface points.

    Args:
        points: (n, 3) float64 rest-space (material) points, mm.
        tables: from :func:`albedo_tables`.
    Returns:
        (n, 3) float64 linear RGB albedo in [0, 1].
    """
    P = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty((len(P), 3))
    _albedo_kernel(P, tables["q"], np.ascontiguousarray(tables["pocket"]), np.ascontiguousarray(tables["lips"]),
                   np.ascontiguousarray(tables["moles"]), out)
    return out
