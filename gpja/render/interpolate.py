"""Attribute interpolation and scattering of per-pixel values into images."""
from __future__ import annotations

import numba as nb
import numpy as np
import torch

from gpja.render.fragments import Fragments


@nb.njit(cache=True, parallel=True)
def _interp_forward(attr, bary, index, out):
    for p in nb.prange(index.shape[0]):
        for c in range(attr.shape[1]):
            out[p, c] = bary[p, 0] * attr[index[p, 0], c] + bary[p, 1] * attr[index[p, 1], c] + bary[p, 2] * attr[index[p, 2], c]


@nb.njit(cache=True, parallel=True)
def _interp_grad_bary(attr, index, grad_out, grad_bary):
    for p in nb.prange(index.shape[0]):
        for k in range(3):
            acc = 0.0
            for c in range(attr.shape[1]):
                acc += attr[index[p, k], c] * grad_out[p, c]
            grad_bary[p, k] = acc


@nb.njit(cache=True, parallel=True)
def _interp_grad_attr(bary, index, grad_out, partial):
    # one private accumulator per chunk (fragments of different views share rows), summed by the caller
    n_chunks = partial.shape[0]
    size = (index.shape[0] + n_chunks - 1) // n_chunks
    for chunk in nb.prange(n_chunks):
        acc = partial[chunk]
        for p in range(chunk * size, min(index.shape[0], (chunk + 1) * size)):
            for k in range(3):
                row = index[p, k]
                for c in range(grad_out.shape[1]):
                    acc[row, c] += bary[p, k] * grad_out[p, c]


class _Interpolate(torch.autograd.Function):
    """out[p] = sum_k bary[p, k] * attr[index[p, k]], numba forward and scatter-add backward.

    Fused loops avoid materialising the (P, 3, C) corner gather that torch's
    indexing would build (and zero-fill again in its backward).
    """

    @staticmethod
    def forward(ctx, attr, bary, index):
        a = np.ascontiguousarray(attr.detach().numpy())
        b = np.ascontiguousarray(bary.detach().numpy(), dtype=a.dtype)
        out = np.empty((index.shape[0], a.shape[1]), dtype=a.dtype)
        _interp_forward(a, b, index.numpy(), out)
        ctx.save_for_backward(attr, bary, index)
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad_out):
        attr, bary, index = ctx.saved_tensors
        g = np.ascontiguousarray(grad_out.numpy())
        idx = index.numpy()
        grad_attr = grad_bary = None
        if ctx.needs_input_grad[0]:
            partial = np.zeros((nb.get_num_threads(), *attr.shape), dtype=g.dtype)
            _interp_grad_attr(np.ascontiguousarray(bary.detach().numpy()), idx, g, partial)
            grad_attr = torch.from_numpy(partial.sum(axis=0)).to(attr.dtype)
        if ctx.needs_input_grad[1]:
            gb = np.empty((idx.shape[0], 3), dtype=g.dtype)
            _interp_grad_bary(np.ascontiguousarray(attr.detach().numpy()), idx, g, gb)
            grad_bary = torch.from_numpy(gb).to(bary.dtype)
        return grad_attr, grad_bary, None


def interpolate_attribute(attr: torch.Tensor, faces: torch.Tensor, frags: Fragments) -> torch.Tensor:
    """Interpolate a per-vertex (or per-UV) attribute at every covered pixel.

    Args:
        attr: (k, C) float attribute rows, e.g. positions (n, 3) with ``faces=F``
            or texture coordinates (k, 2) with ``faces=F_uv``.
        faces: (m, 3) int64 rows of ``attr`` at each triangle corner.
        frags: fragments from ``rasterize_fragments``.
    Returns:
        (P, C) interpolated values, differentiable in ``attr`` and the barycentrics.
    """
    index = faces.to(attr.device)[frags.face]
    return interpolate_rows(attr, frags.bary, index)


def interpolate_rows(attr: torch.Tensor, bary: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Public wrapper of the interpolation op.

    Args:
        attr: (k, C) float rows; bary: (P, 3) weights; index: (P, 3) int64 rows of ``attr``.
    Returns:
        (P, C) ``sum_k bary[:, k] * attr[index[:, k]]``.
    """
    return _Interpolate.apply(attr.contiguous(), bary.contiguous(), index.contiguous())


def scatter_to_image(values: torch.Tensor, frags: Fragments, background: float | torch.Tensor = 0.0) -> torch.Tensor:
    """Place per-pixel values into (B, H, W, C) images, ``background`` elsewhere.

    Args:
        values: (P, C) values of the covered pixels (or (P,) for one channel).
        background: scalar or (C,) value of empty pixels.
    Returns:
        (B, H, W, C) images, differentiable in ``values``.
    """
    if values.dim() == 1:
        values = values[:, None]
    n_views, height, width = frags.shape
    channels = values.shape[1]
    bg = torch.as_tensor(background, dtype=values.dtype, device=values.device).expand(channels)
    image = bg.repeat(n_views * height * width, 1)
    image = image.index_put((frags.pixel,), values)
    return image.reshape(n_views, height, width, channels)
