"""Second-order spherical-harmonics lighting of Lambertian surfaces.

Convention (Ramamoorthi & Hanrahan 2001, "An efficient representation for
irradiance environment maps"): ``sh`` (9, 3) are the SH coefficients of the
incident *radiance* per RGB channel, in the real orthonormal basis ordered
(Y00, Y1-1, Y10, Y11, Y2-2, Y2-1, Y20, Y21, Y22). Irradiance is
E(n) = sum_k A_k sh_k Y_k(n) with A = (pi, 2pi/3 x3, pi/4 x5), and outgoing
radiance of a Lambertian surface is albedo * E(n) / pi. A uniform white
environment of radiance 1 therefore shades an albedo to itself.

Works for numpy arrays and torch tensors alike (the renderer reuses it).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np
import torch

# Real SH normalisation constants.
_C0 = 0.5 * math.sqrt(1.0 / math.pi)
_C1 = math.sqrt(3.0 / (4.0 * math.pi))
_C2 = 0.5 * math.sqrt(15.0 / math.pi)
_C20 = 0.25 * math.sqrt(5.0 / math.pi)
_C22 = 0.25 * math.sqrt(15.0 / math.pi)
#: Lambertian convolution factors A_l, one per basis function.
LAMBERT_FACTORS = np.array([math.pi] + [2.0 * math.pi / 3.0] * 3 + [math.pi / 4.0] * 5)


def _stack(parts, like):
    if isinstance(like, np.ndarray):
        return np.stack(parts, axis=-1)
    return torch.stack(parts, dim=-1)


def sh_basis(normals):
    """Evaluate the 9 real SH basis functions at unit directions.

    Args:
        normals: (..., 3) unit vectors, numpy or torch, any float dtype.
    Returns:
        (..., 9) basis values, same type and dtype as ``normals``.
    """
    x, y, z = normals[..., 0], normals[..., 1], normals[..., 2]
    one = x * 0 + 1
    return _stack(
        [
            _C0 * one,
            _C1 * y,
            _C1 * z,
            _C1 * x,
            _C2 * x * y,
            _C2 * y * z,
            _C20 * (3.0 * z * z - 1.0),
            _C2 * x * z,
            _C22 * (x * x - y * y),
        ],
        normals,
    )


def irradiance_over_pi(normals, sh):
    """Lambertian shading factor E(n)/pi per channel.

    Args:
        normals: (..., 3) unit normals (numpy or torch).
        sh: (9, 3) radiance SH coefficients, same array type as ``normals``.
    Returns:
        (..., 3) shading factor (dimensionless; 1 under uniform white light).
    """
    if isinstance(normals, np.ndarray):
        weights = np.asarray(sh) * (LAMBERT_FACTORS / math.pi)[:, None]
        return sh_basis(normals) @ weights
    if normals.device.type == "cpu" and not sh.requires_grad and normals.dim() == 2:
        return _Irradiance.apply(normals, sh)
    basis = sh_basis(normals)
    factors = torch.as_tensor(LAMBERT_FACTORS / math.pi, dtype=basis.dtype, device=basis.device)
    return basis @ (sh * factors[:, None])


@nb.njit(cache=True, parallel=True)
def _irradiance_forward(normals, weights, out):
    for p in nb.prange(normals.shape[0]):
        x, y, z = np.float64(normals[p, 0]), np.float64(normals[p, 1]), np.float64(normals[p, 2])
        basis = (_C0, _C1 * y, _C1 * z, _C1 * x, _C2 * x * y, _C2 * y * z, _C20 * (3.0 * z * z - 1.0),
                 _C2 * x * z, _C22 * (x * x - y * y))
        for c in range(3):
            e = 0.0
            for k in range(9):
                e += basis[k] * weights[k, c]
            out[p, c] = e


@nb.njit(cache=True, parallel=True)
def _irradiance_backward(normals, weights, grad_out, grad_normals):
    for p in nb.prange(normals.shape[0]):
        x, y, z = np.float64(normals[p, 0]), np.float64(normals[p, 1]), np.float64(normals[p, 2])
        # derivatives of the 9 basis functions (module order) along x, y and z
        dx = (0.0, 0.0, 0.0, _C1, _C2 * y, 0.0, 0.0, _C2 * z, 2.0 * _C22 * x)
        dy = (0.0, _C1, 0.0, 0.0, _C2 * x, _C2 * z, 0.0, 0.0, -2.0 * _C22 * y)
        dz = (0.0, 0.0, _C1, 0.0, 0.0, _C2 * y, 6.0 * _C20 * z, _C2 * x, 0.0)
        gx = gy = gz = 0.0
        for c in range(3):
            g = np.float64(grad_out[p, c])
            for k in range(9):
                w = g * weights[k, c]
                gx += w * dx[k]
                gy += w * dy[k]
                gz += w * dz[k]
        grad_normals[p, 0] = gx
        grad_normals[p, 1] = gy
        grad_normals[p, 2] = gz


class _Irradiance(torch.autograd.Function):
    """E(n)/pi for (P, 3) CPU normals and fixed lighting: one numba pass each way.

    torch's version stacks nine (P,) basis columns and a matmul, and keeps them all
    for its backward: forward + backward at 620K pixels (a render's covered pixels),
    30 ms against 9.2 ms (``benchmarks/bench_render.py --ops``).
    """

    @staticmethod
    def forward(ctx, normals, sh):
        n = normals.detach().contiguous()
        weights = sh.detach().cpu().double().numpy() * (LAMBERT_FACTORS / math.pi)[:, None]
        out = np.empty(n.shape, dtype=n.numpy().dtype)
        _irradiance_forward(n.numpy(), weights, out)
        ctx.save_for_backward(n)
        ctx.weights = weights
        return torch.from_numpy(out)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_out):
        (n,) = ctx.saved_tensors
        grad = np.empty(n.shape, dtype=n.numpy().dtype)
        _irradiance_backward(n.numpy(), ctx.weights, np.ascontiguousarray(grad_out.numpy()), grad)
        return torch.from_numpy(grad), None


def shade_lambertian(albedo, normals, sh):
    """Outgoing radiance of a Lambertian surface under SH lighting.

    Args:
        albedo: (..., 3) diffuse reflectance in [0, 1].
        normals: (..., 3) unit normals, world frame.
        sh: (9, 3) radiance SH coefficients (see module docstring).
    Returns:
        (..., 3) linear RGB, same type as the inputs.
    """
    return albedo * irradiance_over_pi(normals, sh)


def uniform_sh(intensity: float = 1.0) -> np.ndarray:
    """SH coefficients (9, 3) float64 of a uniform white environment of given radiance."""
    sh = np.zeros((9, 3))
    sh[0, :] = intensity * 2.0 * math.sqrt(math.pi)
    return sh
