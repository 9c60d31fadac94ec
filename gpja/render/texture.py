"""Bilinear texture sampling with gradients to the coordinates and the image."""
from __future__ import annotations

import torch
import torch.nn.functional as nnf


def sample_texture(texture: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
    """Bilinearly sample a texture at UV coordinates.

    Args:
        texture: (T_h, T_w, C) float texture image, row 0 at the top.
        uv: (P, 2) float texture coordinates in [0, 1], OBJ convention (origin
            bottom-left, v up); outside [0, 1] the border texel is repeated.
    Returns:
        (P, C) sampled values, differentiable in ``texture`` and ``uv``.
    """
    # grid_sample: x = -1 is the left edge of texel column 0, y = -1 the top edge of row 0.
    grid = torch.stack([2.0 * uv[:, 0] - 1.0, 1.0 - 2.0 * uv[:, 1]], dim=-1)
    out = nnf.grid_sample(texture.permute(2, 0, 1)[None], grid[None, None], mode="bilinear",
                          padding_mode="border", align_corners=False)
    return out[0, :, 0, :].T
