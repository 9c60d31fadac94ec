"""Small scenes shared by the renderer tests."""
from __future__ import annotations

import numpy as np
import torch
import trimesh

from gpja.camera import Camera


def ring_cameras(n: int, size: int, distance: float = 400.0, focal: float | None = None) -> list[Camera]:
    """``n`` undistorted cameras on a ring around the origin, slightly above it."""
    f = focal if focal is not None else 1.4 * size
    K = np.array([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1.0]])
    angles = np.linspace(-np.pi / 2, np.pi / 2, n) if n > 1 else [0.0]
    return [Camera.look_at(distance * np.array([np.sin(a), 0.15, np.cos(a)]), (0, 0, 0), (0, 1, 0), K, size, size,
                           name=str(i)) for i, a in enumerate(angles)]


def sphere(subdivisions: int = 3, radius: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices, dtype=np.float64), np.asarray(s.faces, dtype=np.int64)


def spherical_uv(V: np.ndarray) -> np.ndarray:
    r = np.linalg.norm(V, axis=1)
    return np.stack([0.5 + np.arctan2(V[:, 0], V[:, 2]) / (2 * np.pi), 0.5 + np.arcsin(V[:, 1] / r) / np.pi], axis=1)


def to_screen_cam() -> Camera:
    """Identity-pose camera with f = 100 px at the origin, for hand-made screen-space scenes."""
    K = np.array([[100.0, 0, 0], [0, 100.0, 0], [0, 0, 1]])
    return Camera(K=K, Rt=np.concatenate([np.eye(3), np.zeros((3, 1))], 1), width=16, height=16, name="s")


def screen_triangles(xy: np.ndarray, depth: float = 100.0) -> torch.Tensor:
    """(B=1, n, 3) screen-space vertices from pixel positions (n, 2) at constant depth."""
    return torch.tensor(np.concatenate([xy, np.full((len(xy), 1), depth)], axis=1)[None], dtype=torch.float64)
