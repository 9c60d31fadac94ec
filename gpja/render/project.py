"""Differentiable projection of mesh vertices into a batch of pinhole views."""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from gpja.camera import Camera


def camera_matrices(cameras: Sequence[Camera], like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Stack the views' intrinsics and extrinsics as tensors.

    Returns:
        K: (B, 3, 3) pixels; Rt: (B, 3, 4) world-to-camera, mm. dtype/device of ``like``.
    Raises:
        ValueError: a camera has lens distortion (undistort the images first) or
        the views differ in image size.
    """
    for cam in cameras:
        if cam.has_distortion:
            raise ValueError(f"camera {cam.name!r} has lens distortion: render with undistorted cameras")
    sizes = {(c.width, c.height) for c in cameras}
    if len(sizes) != 1:
        raise ValueError(f"all views must share one image size, got {sorted(sizes)}")
    K = torch.as_tensor(np.stack([c.K for c in cameras]), dtype=like.dtype, device=like.device)
    Rt = torch.as_tensor(np.stack([c.Rt for c in cameras]), dtype=like.dtype, device=like.device)
    return K, Rt


def project_to_screen(V: torch.Tensor, cameras: Sequence[Camera]) -> torch.Tensor:
    """Project world vertices into every view.

    Args:
        V: (n, 3) float vertex positions, world frame, mm.
        cameras: B undistorted cameras of one image size.
    Returns:
        (B, n, 3) same dtype as ``V``: pixel x, pixel y (pixel centres at
        integers, y down) and camera depth z in mm. Differentiable in ``V``.
    """
    K, Rt = camera_matrices(cameras, V)
    Xc = torch.einsum("bij,nj->bni", Rt[:, :, :3], V) + Rt[:, None, :, 3]
    z = Xc[..., 2:3]
    xy = Xc[..., :2] / z
    pix = torch.einsum("bij,bnj->bni", K[:, :2, :2], xy) + K[:, None, :2, 2]
    return torch.cat([pix, z], dim=-1)
