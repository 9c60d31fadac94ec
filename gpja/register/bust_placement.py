"""Placement of the genus-0 bust (:mod:`gpja.register.bust`) over a scan.

:func:`place_bust` scales and translates the bust onto a scan in the
canonical head frame (face +Z, top +Y, X to the subject's left, mm): an
initial guess from robust scan percentiles and the nose tip, refined by a
trimmed scale+translation ICP of the scan points onto the bust surface.
"""
from __future__ import annotations

import numpy as np

from gpja.errors import InputError
from gpja.mesh import TexturedMesh, unique_edges
from gpja.register.bust import Bust

#: Scan extents (robust, mm) accepted as a head in millimetres.
SCAN_EXTENT_RANGE_MM = (80.0, 1500.0)


def _scan_points(scan_V) -> np.ndarray:
    """(k, 3) float64 finite scan vertices, mm, checked to look like a head in millimetres."""
    P = np.asarray(scan_V, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0:
        raise InputError("scan", f"expected a non-empty (n, 3) array of scan vertices, got shape {P.shape}")
    P = P[np.isfinite(P).all(1)]
    if len(P) < 100:
        raise InputError("scan", f"only {len(P)} finite scan vertices; too few to place the bust")
    lo, hi = np.percentile(P, [1, 99], axis=0)
    ext = float((hi - lo).max())
    if not SCAN_EXTENT_RANGE_MM[0] <= ext <= SCAN_EXTENT_RANGE_MM[1]:
        raise InputError("scan", f"robust extent {ext:.4g} is outside [{SCAN_EXTENT_RANGE_MM[0]:g}, "
                                 f"{SCAN_EXTENT_RANGE_MM[1]:g}]: the scan does not look like a head in millimetres")
    return P


def fit_placement(bust: Bust, scan_V, iterations: int = 80, trim: float = 0.8, max_points: int = 20000,
                  seed: int = 0) -> tuple[float, np.ndarray]:
    """Scale and translation taking ``bust`` onto a scan in the canonical frame.

    Initial guess: the scale of the robust head width (X, percentiles 2-98 of
    the points above the mouth level) and the nose tip (the front-most
    points); refined by a trimmed ICP with uniform scale + translation only (no
    rotation: the frame is canonical) matching scan points to their nearest
    bust surface samples, so the scan's holes (back/top of skull) do not bias it.

    Args:
        scan_V: (n, 3) float64 scan vertices, mm.
        trim: fraction of closest correspondences kept per iteration.
    Returns:
        (scale, translation (3,)) such that ``bust.transformed(scale, translation)`` overlaps the scan.
    Raises:
        InputError: empty scan, or not in millimetres (robust extent outside 80-1500 mm).
    """
    from scipy.spatial import cKDTree

    P = _scan_points(scan_V)
    rng = np.random.default_rng(seed)
    if len(P) > max_points:
        P = P[rng.choice(len(P), max_points, replace=False)]
    B = _surface_samples(bust.mesh, spacing_mm=2.0)
    # initial guess
    zq = np.percentile(P[:, 2], 99.5)
    tip_s = P[P[:, 2] >= zq].mean(0)
    tip_b = bust.landmarks["nose_tip"]
    yb_mouth = bust.landmarks["mouth"][1]
    up_b = B[(B[:, 1] > yb_mouth) & (B[:, 1] < bust.landmarks["head_top"][1])]
    wb = np.subtract(*np.percentile(up_b[:, 0], [98, 2]))
    band = P[P[:, 1] > tip_s[1] - 0.5 * (tip_b[1] - yb_mouth)]
    ws = np.subtract(*np.percentile((band if len(band) > 50 else P)[:, 0], [98, 2]))
    s = float(np.clip(ws / wb, 0.6, 1.6))
    t = tip_s - s * tip_b
    t[0] = 0.5 * np.sum(np.percentile(P[:, 0], [2, 98])) - s * 0.0
    tree = cKDTree(B)
    for _ in range(iterations):
        # nearest bust sample for each scan point, in bust coordinates
        d, idx = tree.query((P - t) / s)
        keep = d <= np.quantile(d, trim)
        q, b = P[keep], B[idx[keep]]
        qm, bm = q.mean(0), b.mean(0)
        bc, qc = b - bm, q - qm
        s_new = float((bc * qc).sum() / max((bc * bc).sum(), 1e-12))
        s_new = float(np.clip(s_new, 0.5 * s, 2.0 * s))
        t_new = qm - s_new * bm
        done = abs(s_new - s) < 1e-5 and np.linalg.norm(t_new - t) < 1e-3
        s, t = s_new, t_new
        if done:
            break
    return s, t


def place_bust(bust: Bust, scan_V, **kwargs) -> Bust:
    """The bust scaled and translated to approximately overlap a scan (see :func:`fit_placement`).

    Args:
        scan_V: (n, 3) float64 scan vertices in the canonical head frame, mm.
    Raises:
        InputError: empty scan, or not in millimetres.
    """
    s, t = fit_placement(bust, scan_V, **kwargs)
    return bust.transformed(s, t)


def _surface_samples(mesh: TexturedMesh, spacing_mm: float = 2.0) -> np.ndarray:
    """(k, 3) points on the surface: vertices, face centroids and edge midpoints (deterministic)."""
    V, F = mesh.V, mesh.F
    tri = V[F]
    pts = [V, tri.mean(1)]
    e, _ = unique_edges(F)
    pts.append(0.5 * (V[e[:, 0]] + V[e[:, 1]]))
    return np.concatenate(pts)
