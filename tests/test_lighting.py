import math

import numpy as np
import torch

from gpja.lighting import irradiance_over_pi, sh_basis, shade_lambertian, uniform_sh
from tests.tolerances import EXACT_F64, SPHERE_QUADRATURE


def fibonacci_sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * i / n)
    theta = math.pi * (1 + 5**0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


def test_uniform_light_shades_albedo_to_itself():
    n = fibonacci_sphere(100)
    albedo = np.random.default_rng(0).random((100, 3))
    np.testing.assert_allclose(shade_lambertian(albedo, n, uniform_sh()), albedo, atol=EXACT_F64)


def test_basis_is_orthonormal():
    n = fibonacci_sphere(20000)
    Y = sh_basis(n)
    gram = Y.T @ Y * (4 * math.pi / len(n))
    np.testing.assert_allclose(gram, np.eye(9), atol=SPHERE_QUADRATURE)


def test_linear_band_analytic():
    # radiance L(w) = Y10(w) = c1 z  ->  irradiance E(n) = (2pi/3) c1 n_z
    sh = np.zeros((9, 3))
    sh[2] = 1.0
    n = fibonacci_sphere(50)
    c1 = math.sqrt(3 / (4 * math.pi))
    np.testing.assert_allclose(irradiance_over_pi(n, sh), (2 / 3 * c1 * n[:, 2])[:, None].repeat(3, 1), atol=EXACT_F64)


def test_torch_matches_numpy_and_gradcheck():
    n = fibonacci_sphere(7)
    sh = np.random.default_rng(1).normal(size=(9, 3))
    ref = irradiance_over_pi(n, sh)
    nt = torch.tensor(n, dtype=torch.float64, requires_grad=True)
    st = torch.tensor(sh, dtype=torch.float64, requires_grad=True)
    np.testing.assert_allclose(irradiance_over_pi(nt, st).detach().numpy(), ref, atol=EXACT_F64)
    assert torch.autograd.gradcheck(irradiance_over_pi, (nt, st))


def test_regression_values():
    sh = uniform_sh(0.8)
    sh[1:4] = [[0.1, 0.0, 0.0], [0.0, 0.2, 0.0], [0.0, 0.0, 0.3]]
    out = irradiance_over_pi(np.array([[0.0, 0.0, 1.0]]), sh)
    np.testing.assert_allclose(out, [[0.8, 0.8 + 2 / 3 * 0.2 * math.sqrt(3 / (4 * math.pi)), 0.8]], atol=EXACT_F64)


def test_fixed_lighting_op_matches_numpy_and_gradcheck():
    # CPU torch normals under lighting without gradient take the fused numba op
    n = fibonacci_sphere(40)
    sh = np.random.default_rng(2).normal(size=(9, 3))
    nt = torch.tensor(n, dtype=torch.float64, requires_grad=True)
    out = irradiance_over_pi(nt, torch.tensor(sh))
    np.testing.assert_allclose(out.detach().numpy(), irradiance_over_pi(n, sh), atol=EXACT_F64)
    st = torch.tensor(sh)
    assert torch.autograd.gradcheck(lambda v: irradiance_over_pi(v, st), (nt[:8].detach().requires_grad_(True),))
    # float32 in, float32 out
    assert irradiance_over_pi(nt.detach().float(), st.float()).dtype == torch.float32
