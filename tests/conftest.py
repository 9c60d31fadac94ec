"""Shared fixtures: a tiny hand-made expression in FaceScape's layout."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gpja.camera import Camera
from gpja.io import write_image
from gpja.mesh import write_ply

SUBJECT = "7"
EXPRESSION = "3_mouth_stretch"


def smooth_image(camera: Camera) -> np.ndarray:
    """(H, W, 3) float32 smooth pattern (resampling it twice adds little error of its own)."""
    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float32)
    return np.stack([0.5 + 0.4 * np.sin(u / 6), 0.5 + 0.4 * np.cos(v / 7), 0.5 + 0.3 * np.sin((u + v) / 9)], axis=-1)


def distort_image(camera: Camera, ideal: np.ndarray) -> np.ndarray:
    """Resample an undistorted image into the camera's distorted image (bilinear)."""
    import cv2

    v, u = np.mgrid[0 : camera.height, 0 : camera.width].astype(np.float64)
    xy = camera.pixels_to_normalized(np.stack([u.ravel(), v.ravel()], axis=1))
    src = camera.undistorted().normalized_to_pixels(xy).astype(np.float32)
    return cv2.remap(ideal, src[:, 0].reshape(u.shape), src[:, 1].reshape(u.shape), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def make_cameras(size: int = 96) -> list[Camera]:
    f = 1.6 * size
    K = np.array([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1.0]])
    dist = np.array([-0.08, 0.03, 0.0005, -0.0003, 0.0])
    eyes = [(0, 0, 600), (600, 0, 0), (-420, 100, 420)]
    return [Camera.look_at(e, (0, 0, 0), (0, 1, 0), K, size, size, distortion=dist, name=str(i)) for i, e in enumerate(eyes)]


def sphere_scan(radius: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    return np.asarray(s.vertices), np.asarray(s.faces)


@pytest.fixture
def facescape_root(tmp_path: Path) -> dict:
    """One subject/expression: 3 distorted views (+ an invalid one), a sphere scan in mm."""
    images = tmp_path / "images"
    scans = tmp_path / "scans"
    folder = images / SUBJECT / EXPRESSION
    cams = make_cameras()
    params = {}
    ideals = {}
    for cam in cams:
        params.update(cam.to_params())
        ideals[cam.name] = smooth_image(cam)
        write_image(folder / f"{cam.name}.png", distort_image(cam, ideals[cam.name]))
    invalid = cams[0].to_params("9")
    invalid["9_valid"] = False
    params.update(invalid)
    (folder / "params.json").write_text(json.dumps(params))
    V, F = sphere_scan()
    write_ply(scans / SUBJECT / f"{EXPRESSION}.ply", V, F)
    return {"images": images, "scans": scans, "cameras": cams, "ideals": ideals, "scan": (V, F),
            "folder": folder, "subject": SUBJECT, "expression": EXPRESSION}
