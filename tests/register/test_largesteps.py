"""Tests of gpja.register.largesteps: the Cholesky solver, the u <-> x maps, UniformAdam."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import torch
import trimesh

from gpja.errors import InputError
from gpja.register.laplacian import cotangent_laplacian, system_matrix
from gpja.register.largesteps import (
    LargeStepsParametrization,
    SmoothingSolver,
    UniformAdam,
    from_differential,
    sparse_to_torch,
    to_differential,
)
from tests.register.test_laplacian import grid, noisy_sphere

#: float32 Cholesky solve, error relative to the largest |x| (issue: 1e-4).
SOLVE_F32_REL = 1e-4
#: float64 Cholesky solve, error relative to the largest |x|.
SOLVE_F64_REL = 1e-10
#: UniformAdam's first step vs lr, relative (eps = 1e-8 against gradients of order 1).
ADAM_FIRST_STEP_REL = 1e-6
#: Ratio step / gradient must be one number across entries (float32), relative.
ADAM_UNIFORM_REL = 1e-5
#: Distance to the minimiser of a quadratic after the convergence loop, in units of the start distance.
QUADRATIC_CONVERGED = 1e-3
#: The preconditioned step's Rayleigh quotient x^T L x / x^T x must drop by at least this factor.
SMOOTHING_FACTOR = 10.0
#: Regression of a short deterministic optimisation, relative.
REGRESSION_REL = 1e-3


def sphere_2k(seed: int = 0):
    """Noisy icosphere, 2562 vertices, radius 100 mm."""
    return noisy_sphere(subdivisions=4, radius=100.0, noise=0.1, seed=seed)


# ---------------------------------------------------------------- SmoothingSolver
def test_solver_analytic_identity_and_diagonal():
    V, F = grid(3, 3)
    b = torch.arange(48, dtype=torch.float32).reshape(16, 3)
    torch.testing.assert_close(SmoothingSolver(system_matrix(V, F, 0.0)).solve(b), b)  # lam = 0: M = I
    D = sp.diags(np.arange(1.0, 17.0)).tocsr()
    torch.testing.assert_close(SmoothingSolver(D).solve(b[:, 0]), b[:, 0] / torch.arange(1.0, 17.0))


@pytest.mark.parametrize("lam", [1.0, 30.0, 1000.0])
def test_solver_inverts_M_on_2k_mesh(lam):
    V, F = sphere_2k()
    M = system_matrix(V, F, lam)
    solver = SmoothingSolver(M)
    x = torch.from_numpy(V).float()
    b = torch.from_numpy(M @ V).float()
    got = solver.solve(b)
    assert got.shape == (len(V), 3) and got.dtype == torch.float32
    assert (got - x).abs().max() <= SOLVE_F32_REL * x.abs().max()
    got64 = solver.solve(torch.from_numpy(M @ V))
    assert got64.dtype == torch.float64
    assert (got64 - torch.from_numpy(V)).abs().max() <= SOLVE_F64_REL * np.abs(V).max()
    with pytest.raises(InputError, match="shape"):
        solver.solve(b[:-1])
    with pytest.raises(InputError, match="float32 or float64"):
        solver.solve(b.half())


def test_round_trip_to_from_differential():
    V, F = sphere_2k()
    M = system_matrix(V, F, 20.0)
    x = torch.from_numpy(V).float()
    back = from_differential(to_differential(x, M), SmoothingSolver(M))
    assert (back - x).abs().max() <= SOLVE_F32_REL * x.abs().max()
    u_ref = torch.from_numpy(M @ V).float()
    torch.testing.assert_close(to_differential(x, sparse_to_torch(M)), u_ref, rtol=1e-5, atol=1e-3)


def test_gradcheck_float64():
    # cholespy also ships a float64 factor (CholeskySolverD), which the solver builds
    # on first use by a float64 tensor, so the autograd Function is checked exactly.
    V, F = noisy_sphere(subdivisions=1, radius=10.0)  # 42 vertices
    M = system_matrix(V, F, 3.0)
    solver = SmoothingSolver(M)
    u = torch.randn(len(V), 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0), requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: from_differential(t, solver), (u,))
    assert torch.autograd.gradcheck(lambda t: to_differential(t, M), (u,))


def test_backward_is_solve_float32():
    V, F = noisy_sphere(subdivisions=2)
    M = system_matrix(V, F, 10.0)
    solver = SmoothingSolver(M)
    u = torch.from_numpy(M @ V).float().requires_grad_(True)
    g = torch.randn(len(V), 3, generator=torch.Generator().manual_seed(1))
    (from_differential(u, solver) * g).sum().backward()
    expected = np.linalg.solve(M.toarray(), g.double().numpy())
    assert np.abs(u.grad.double().numpy() - expected).max() <= SOLVE_F32_REL * np.abs(expected).max()


# ---------------------------------------------------------------- UniformAdam
def test_uniform_adam_first_step():
    g = torch.tensor([[0.5, -2.0, 1.0], [0.25, 4.0, -3.0]])
    p = torch.zeros(2, 3, requires_grad=True)
    opt = UniformAdam([p], lr=0.1)
    p.grad = g.clone()
    opt.step()
    step = -p.detach()
    torch.testing.assert_close(step.abs().max(), torch.tensor(0.1), rtol=ADAM_FIRST_STEP_REL, atol=0)
    ratio = step / g  # a single number: the denominator is uniform
    torch.testing.assert_close(ratio, torch.full_like(ratio, 0.1 / 4.0), rtol=ADAM_UNIFORM_REL, atol=0)
    # torch's per-entry Adam would move every entry by lr instead
    q = torch.zeros(2, 3, requires_grad=True)
    ref = torch.optim.Adam([q], lr=0.1)
    q.grad = g.clone()
    ref.step()
    torch.testing.assert_close(q.detach().abs(), torch.full((2, 3), 0.1), rtol=ADAM_FIRST_STEP_REL, atol=0)


def test_uniform_adam_matches_formula_over_steps():
    rng = np.random.default_rng(3)
    grads = rng.normal(size=(4, 5, 3))
    lr, b1, b2, eps = 0.05, 0.8, 0.95, 1e-8
    p = torch.zeros(5, 3, dtype=torch.float64, requires_grad=True)
    opt = UniformAdam([p], lr=lr, betas=(b1, b2), eps=eps)
    m = v = 0.0
    x = np.zeros((5, 3))
    for t, g in enumerate(grads, start=1):
        p.grad = torch.from_numpy(g)
        opt.step()
        m = b1 * m + (1 - b1) * g
        v = b2 * v + (1 - b2) * g**2
        x = x - lr * (m / (1 - b1**t)) / (np.sqrt((v / (1 - b2**t)).max()) + eps)
        np.testing.assert_allclose(p.detach().numpy(), x, rtol=1e-12, atol=1e-14)


def test_uniform_adam_converges_on_quadratic():
    target = torch.tensor([3.0, -1.0, 0.5, 2.0])
    scale = torch.tensor([1.0, 4.0, 0.5, 2.0])  # anisotropic bowl
    p = torch.zeros(4, requires_grad=True)
    opt = UniformAdam([p], lr=0.05)
    for _ in range(1000):
        opt.zero_grad()
        (0.5 * (scale * (p - target)) ** 2).sum().backward()
        opt.step()
    assert (p.detach() - target).norm() <= QUADRATIC_CONVERGED * target.norm()


def test_bad_optimizer_args():
    p = torch.zeros(3, requires_grad=True)
    with pytest.raises(InputError, match="lr"):
        UniformAdam([p], lr=-1.0)
    with pytest.raises(InputError, match="betas"):
        UniformAdam([p], betas=(1.0, 0.9))
    with pytest.raises(InputError, match="empty"):
        UniformAdam([])
    with pytest.raises(InputError, match="tensors"):
        UniformAdam([np.zeros(3)])


def test_uniform_adam_groups_zero_grad_and_a_changed_learning_rate():
    p, q = torch.zeros(3, requires_grad=True), torch.zeros(3, requires_grad=True)
    opt = UniformAdam([{"params": [p]}, {"params": [q], "lr": 0.5}], lr=0.1)
    assert [g["lr"] for g in opt.param_groups] == [0.1, 0.5]
    p.grad, q.grad = torch.ones(3), torch.ones(3)
    opt.step()
    torch.testing.assert_close(-p.detach(), torch.full((3,), 0.1), rtol=ADAM_FIRST_STEP_REL, atol=0)
    torch.testing.assert_close(-q.detach(), torch.full((3,), 0.5), rtol=ADAM_FIRST_STEP_REL, atol=0)
    assert opt.state[p]["step"] == 1
    opt.zero_grad()
    assert p.grad is None and q.grad is None
    opt.param_groups[0]["lr"] = 0.0  # what the schedule's decay does between steps
    p.grad = torch.ones(3)
    before = p.detach().clone()
    opt.step()
    torch.testing.assert_close(p.detach(), before)
    opt.zero_grad(set_to_none=False)
    torch.testing.assert_close(p.grad, torch.zeros(3))


def test_uniform_adam_does_not_import_torch_dynamo():
    """torch.optim.Optimizer's constructor imports torch._dynamo (3 s a process); UniformAdam is not one."""
    import subprocess
    import sys

    code = ("import sys, torch; from gpja.register.largesteps import UniformAdam; "
            "UniformAdam([torch.zeros(2, requires_grad=True)]).step(); print('torch._dynamo' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ---------------------------------------------------------------- smoothing behaviour
def dirichlet_quotient(L, d: np.ndarray) -> float:
    """Rayleigh quotient trace(d^T L d) / trace(d^T d) (1/length^0: L is dimensionless)."""
    return float(np.sum(d * (L @ d)) / np.sum(d * d))


def test_preconditioned_step_is_smoother_and_equals_M_inverse_squared():
    V, F = noisy_sphere(subdivisions=3, noise=0.05)
    lam, eta = 10.0, 0.5
    par = LargeStepsParametrization(V, F, lam, dtype=torch.float64)
    g = torch.from_numpy(np.random.default_rng(5).normal(size=V.shape))  # noisy dLoss/dx
    x0 = par.vertices().detach()
    (par.vertices() * g).sum().backward()
    with torch.no_grad():
        par.u -= eta * par.u.grad  # plain gradient step on u
    step = (x0 - par.vertices().detach()).numpy()
    M = par.M.toarray()
    np.testing.assert_allclose(step, eta * np.linalg.solve(M, np.linalg.solve(M, g.numpy())), atol=1e-9)
    L = cotangent_laplacian(V, F)
    assert dirichlet_quotient(L, step) * SMOOTHING_FACTOR < dirichlet_quotient(L, g.numpy())


# ---------------------------------------------------------------- parametrisation
def test_parametrization_vertices_and_rebuild():
    V, F = noisy_sphere(subdivisions=2)
    par = LargeStepsParametrization(V, F, lam=15.0)
    assert par.u.is_leaf and par.u.requires_grad and par.u.dtype == torch.float32 and par.u.shape == V.shape
    x = par.vertices()
    assert x.requires_grad and (x.detach().double() - torch.from_numpy(V)).abs().max() <= SOLVE_F32_REL * 100
    V2, F2 = trimesh.remesh.subdivide(V, F)
    old_u = par.u
    par.rebuild(torch.from_numpy(V2), torch.from_numpy(F2))
    assert par.lam == 15.0 and par.u is not old_u and par.u.shape == V2.shape and par.M.shape == (len(V2),) * 2
    par.rebuild(V2, F2, lam=2.0)
    assert par.lam == 2.0
    x2 = par.vertices().detach().double()
    torch.testing.assert_close(x2, torch.from_numpy(V2), rtol=0, atol=SOLVE_F32_REL * 100)  # radius 100 mm


def test_shift_float32_is_the_float64_product_rounded():
    """``shift`` on the CPU takes scipy's float64 product ``M dx`` and rounds it to ``u``'s dtype: the same
    ``u`` as torch's sparse product in float64, to float32 rounding."""
    V, F = sphere_2k()
    par = LargeStepsParametrization(V, F, lam=20.0)
    u0 = par.u.detach().double().clone()
    dx = torch.from_numpy(np.random.default_rng(1).normal(size=V.shape)).float()
    par.shift(dx)
    expected = u0 + to_differential(dx.double(), par.M)
    assert par.u.dtype == torch.float32 and par.u.requires_grad
    torch.testing.assert_close(par.u.detach().double(), expected, rtol=0, atol=SOLVE_F32_REL * 100)


def test_fit_to_target_regression():
    """Fit a sphere to a squashed copy with L2 on x; deterministic, recorded loss trajectory."""
    V, F = noisy_sphere(subdivisions=2, noise=0.0)
    target = torch.from_numpy(V * np.array([1.0, 0.6, 1.0])).float()
    par = LargeStepsParametrization(V, F, lam=10.0)
    opt = par.optimizer(lr=3.0)  # mm
    losses = []
    for _ in range(100):
        opt.zero_grad()
        loss = ((par.vertices() - target) ** 2).sum(dim=1).mean()  # mm^2
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 1e-3 * losses[0]
    np.testing.assert_allclose([losses[0], losses[9], losses[49]], FIT_REGRESSION, rtol=REGRESSION_REL)


FIT_REGRESSION = [533.3333129882812, 287.87060546875, 0.14573408663272858]  # mm^2, recorded
