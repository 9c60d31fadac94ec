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

import numpy as np

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
    import torch

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
    basis = sh_basis(normals)
    if isinstance(basis, np.ndarray):
        weights = np.asarray(sh) * (LAMBERT_FACTORS / math.pi)[:, None]
        return basis @ weights
    import torch

    factors = torch.as_tensor(LAMBERT_FACTORS / math.pi, dtype=basis.dtype, device=basis.device)
    return basis @ (sh * factors[:, None])


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
