"""NICP's correspondences and its rigid pre-alignment.

Correspondences: each vertex of the deformed template takes its closest scan
point (:mod:`gpja.surface`), rejected when it lies on the scan's rim, too far
away, or with a normal too different (see :mod:`gpja.baselines.nicp`). The
rigid pre-alignment fits the template's landmarks to the scan's (weighted
Umeyama), then refines with trimmed rigid ICP on those correspondences.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from gpja.baselines.landmarks import IBUG_STABLE, TemplateLandmarks
from gpja.surface import Surface, interpolate, vertex_areas, vertex_normals

if TYPE_CHECKING:
    from gpja.baselines.nicp import NicpSettings


def similarity_transform(P: np.ndarray, Q: np.ndarray, weights: np.ndarray | None = None,
                         allow_scale: bool = False) -> tuple[float, np.ndarray, np.ndarray]:
    """Weighted Umeyama fit of ``Q ~ s R P + t``.

    Args:
        P, Q: (k, 3) float64 corresponding points, mm. weights: (k,) non-negative, or None.
        allow_scale: fit ``s``; otherwise ``s = 1`` (rigid).
    Returns:
        s (float), R (3, 3) proper rotation, t (3,) mm.
    """
    w = np.ones(len(P)) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    cp, cq = w @ P, w @ Q
    P0, Q0 = P - cp, Q - cq
    C = (Q0 * w[:, None]).T @ P0
    U, S, Vt = np.linalg.svd(C)
    d = np.sign(np.linalg.det(U @ Vt)) or 1.0
    D = np.diag([1.0, 1.0, d])
    R = U @ D @ Vt
    s = float(np.trace(np.diag(S) @ D) / (w @ (P0 ** 2).sum(axis=1))) if allow_scale else 1.0
    return s, R, cq - s * R @ cp


def find_correspondences(target: Surface, X: np.ndarray, normals: np.ndarray, settings: NicpSettings
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest scan points of the deformed template and which of them to trust.

    Args:
        X: (n, 3) float64 current template positions, mm. normals: (n, 3) their unit normals.
    Returns:
        U: (n, 3) float64 closest scan points, mm; valid: (n,) bool; dist: (n,) float64 mm.
    """
    hit = target.closest(X)
    U = interpolate(target, hit, target.V)  # in float64, exactly on the scan's triangles
    dist = np.linalg.norm(U - X, axis=1)
    cos = np.einsum("ij,ij->i", normals, hit.normal)
    valid = (dist <= settings.max_distance_mm) & (cos >= np.cos(np.radians(settings.max_normal_angle_deg)))
    if settings.reject_boundary:
        valid &= ~hit.on_boundary
    return U, valid, dist


def rigid_align(V: np.ndarray, F: np.ndarray, target: Surface, landmarks: TemplateLandmarks,
                scan_landmarks: np.ndarray, settings: NicpSettings) -> tuple[np.ndarray, np.ndarray, dict]:
    """Landmark Procrustes, then trimmed rigid (or similarity) ICP.

    Args:
        V: (n, 3) float64 template positions, mm; F: (m, 3) faces.
        landmarks: the template's landmarks; scan_landmarks: (L, 3) float64 the same on the scan, mm.
    Returns:
        (n, 3) aligned template positions and (L, 3) aligned template landmark points, mm, and a log dict.
    """
    L = len(scan_landmarks)
    stable = np.array(IBUG_STABLE) if L == 68 else np.arange(L)
    P = landmarks.points
    s, R, t = similarity_transform(P[stable], scan_landmarks[stable], allow_scale=settings.similarity)
    area = vertex_areas(V, F)
    lm_w = np.full(len(stable), area.sum() / len(stable))  # landmarks weigh as much as the surface
    history = []
    for _ in range(settings.rigid_iterations):
        X = s * V @ R.T + t
        U, valid, dist = find_correspondences(target, X, vertex_normals(X, F), settings)
        if valid.sum() < 10:
            break
        keep = valid & (dist <= np.quantile(dist[valid], settings.rigid_keep))
        src = np.concatenate([V[keep], P[stable]])
        dst = np.concatenate([U[keep], scan_landmarks[stable]])
        w = np.concatenate([area[keep], lm_w])
        s, R, t = similarity_transform(src, dst, w, allow_scale=settings.similarity)
        history.append(float(dist[keep].mean()))
    P_aligned = s * P @ R.T + t
    lm_err = np.linalg.norm(P_aligned - scan_landmarks, axis=1)
    return s * V @ R.T + t, P_aligned, {"scale": s, "R": R.tolist(), "t": t.tolist(),
                                        "icp_mean_distance_mm": history, "landmark_error_mm": float(lm_err.mean())}
