"""LargeSteps vertex optimisation (Nicolet et al. 2021) on the CPU.

The paper updates vertices with ``x <- x - eta (I + lambda L)^-2 dLoss/dx`` by
optimising ``u = M x`` with ``M = I + lambda L`` (:func:`gpja.register.laplacian.system_matrix`)
and recovering ``x = M^-1 u``. Back-propagating through ``x = M^-1 u`` gives
``dLoss/du = M^-1 dLoss/dx`` (``M`` is symmetric), and a gradient step on ``u``
moves ``x`` by ``M^-1`` of it: ``M^-2`` in all. The paper pairs this with
:class:`UniformAdam`, whose single scalar second-moment normaliser keeps the
smoothed step smooth (per-entry Adam would rescale each coordinate and undo it).

This is our own implementation; the ``largesteps`` package hard-codes CUDA in
its matrix builders. ``M`` is factorised once per mesh resolution with
cholespy's CPU sparse Cholesky (CHOLMOD); each iteration costs one solve
forward (``x`` from ``u``) and one backward (``dLoss/du``).

Units: ``M`` is dimensionless (cotangents), so ``u`` and ``x`` are both in
millimetres and ``dLoss/du`` has the unit of ``dLoss/dx`` (loss per mm).

Threads: cholespy's CPU solve is single-threaded. With libgomp's default
``OMP_WAIT_POLICY`` torch's idle OpenMP workers spin and compete with it for
the cores; set ``OMP_WAIT_POLICY=PASSIVE`` before torch is imported
(benchmarks/bench_largesteps.py measures both).

Typical loop::

    par = LargeStepsParametrization(V, F, lam=20.0)
    opt = UniformAdam([par.u], lr=1e-2)
    for it in range(n_iter):
        opt.zero_grad()
        loss = render_loss(par.vertices())
        loss.backward()
        opt.step()
    # after refining the mesh to (V2, F2): par.rebuild(V2, F2, lam2) and make a new optimiser
"""
from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable

import numpy as np
import scipy.sparse as sp
import torch
from cholespy import CholeskySolverD, CholeskySolverF, MatrixType

from gpja.errors import InputError
from gpja.register.laplacian import system_matrix


def sparse_to_torch(M: sp.spmatrix, dtype: torch.dtype = torch.float32,
                    device: torch.device | str | None = None) -> torch.Tensor:
    """A scipy sparse matrix as a coalesced torch sparse COO tensor.

    Args:
        M: (n, n) scipy sparse matrix (any format).
        dtype: torch dtype of the values.
        device: torch device (default CPU).

    Returns:
        (n, n) torch sparse COO tensor of ``dtype`` on ``device``.
    """
    C = sp.csr_matrix(M, copy=True)
    C.sum_duplicates()  # also sorts indices: row-major, unique -> a coalesced COO
    M = C.tocoo()
    idx = torch.from_numpy(np.stack([M.row, M.col]).astype(np.int64))
    return torch.sparse_coo_tensor(
        idx, torch.from_numpy(M.data.astype(np.float64)), size=M.shape,
        is_coalesced=True, check_invariants=False,
    ).to(dtype=dtype, device=device)


class SmoothingSolver:
    """Solves ``M x = b`` for a fixed SPD sparse ``M`` (factorised once, CPU).

    The float32 Cholesky factor (``cholespy.CholeskySolverF``) is built at
    construction and serves float32 right-hand sides, the optimisation's dtype.
    A float64 factor (``CholeskySolverD``) is built on first use by a float64
    right-hand side (gradient checks, reference computations). Rebuild the
    solver (the caller's job) whenever the mesh or ``lambda`` changes.

    Args:
        M: (n, n) scipy sparse matrix, float64, symmetric positive definite
            (e.g. :func:`gpja.register.laplacian.system_matrix`); both triangles stored.
    """

    def __init__(self, M: sp.spmatrix):
        M = sp.csr_matrix(M, dtype=np.float64)
        if M.shape[0] != M.shape[1]:
            raise InputError("SmoothingSolver", f"M must be square, got shape {M.shape}")
        M.sum_duplicates()
        M.sort_indices()
        self.n = M.shape[0]
        self._csr = (M.indptr.astype(np.int32), M.indices.astype(np.int32), M.data.astype(np.float64))
        self._solvers: dict[torch.dtype, object] = {}
        self._factor(torch.float32)

    def _factor(self, dtype: torch.dtype):
        if dtype not in self._solvers:
            cls = {torch.float32: CholeskySolverF, torch.float64: CholeskySolverD}[dtype]
            self._solvers[dtype] = cls(self.n, *self._csr, MatrixType.CSR)
        return self._solvers[dtype]

    def solve(self, b: torch.Tensor) -> torch.Tensor:
        """``M^-1 b`` (not differentiable by itself; see :func:`from_differential`).

        Args:
            b: (n,) or (n, k) float32 or float64 tensor, any device, any unit.

        Returns:
            Tensor of ``b``'s shape, dtype and device (unit of ``b``; ``M`` is dimensionless).
        """
        if b.dtype not in (torch.float32, torch.float64):
            raise InputError("SmoothingSolver.solve", f"b must be float32 or float64, got {b.dtype}")
        if b.ndim not in (1, 2) or b.shape[0] != self.n:
            raise InputError("SmoothingSolver.solve",
                             f"b must have shape ({self.n},) or ({self.n}, k), got {tuple(b.shape)}")
        rhs = b.detach().to("cpu").contiguous().numpy()
        x = np.empty_like(rhs)
        self._factor(b.dtype).solve(rhs, x)
        return torch.from_numpy(x).to(b.device)


class _FromDifferential(torch.autograd.Function):
    """``x = M^-1 u``; backward ``dL/du = M^-1 dL/dx`` (``M`` symmetric)."""

    @staticmethod
    def forward(ctx, u: torch.Tensor, solver: SmoothingSolver) -> torch.Tensor:
        ctx.solver = solver
        return solver.solve(u)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad_x: torch.Tensor):
        return ctx.solver.solve(grad_x), None


def from_differential(u: torch.Tensor, solver: SmoothingSolver) -> torch.Tensor:
    """Vertex positions from differential coordinates: ``x = M^-1 u`` (differentiable in ``u``).

    Args:
        u: (n, 3) float32 (or float64) differential coordinates, mm, any device.
        solver: :class:`SmoothingSolver` of ``M = I + lambda L``.

    Returns:
        (n, 3) vertex positions ``x``, mm, same dtype and device as ``u``. Its
        gradient flows back as ``dLoss/du = M^-1 dLoss/dx`` (first order only).
    """
    return _FromDifferential.apply(u, solver)


def to_differential(x: torch.Tensor, M: sp.spmatrix | torch.Tensor) -> torch.Tensor:
    """Differential coordinates of vertex positions: ``u = M x`` (differentiable in ``x``).

    Args:
        x: (n, 3) float32 or float64 vertex positions, mm, any device.
        M: (n, n) system matrix, dimensionless: a scipy sparse matrix or a torch
            sparse (CSR/COO) tensor (converted to ``x``'s dtype and device).

    Returns:
        (n, 3) ``u``, mm, same dtype and device as ``x``.
    """
    if isinstance(M, torch.Tensor):
        Mt = M.to(dtype=x.dtype, device=x.device)
    else:
        Mt = sparse_to_torch(M, dtype=x.dtype, device=x.device)
    if Mt.shape[1] != x.shape[0]:
        raise InputError("to_differential", f"M is {tuple(Mt.shape)} but x has {x.shape[0]} rows")
    return Mt @ x


class UniformAdam:
    """Adam with one scalar second-moment normaliser per parameter tensor.

    For a parameter ``p`` with gradient ``g`` at step ``t``::

        m = beta1 m + (1 - beta1) g            v = beta2 v + (1 - beta2) g^2
        m_hat = m / (1 - beta1^t)              v_hat = v / (1 - beta2^t)
        p <- p - lr * m_hat / (sqrt(max(v_hat)) + eps)

    ``max`` runs over every entry of ``p``, so the step is the bias-corrected
    first moment scaled by a single number and keeps its spatial smoothness
    (the LargeSteps paper's variant). The first step has max-abs entry ``lr``
    (up to ``eps``).

    It has a ``torch.optim.Optimizer``'s interface (``param_groups``, ``state``, ``zero_grad``, ``step``)
    without being one: that class's constructor imports ``torch._dynamo`` on its first use, 3 s of every
    registration process (measured with cProfile on ``gpja register``), and nothing else of it is needed.

    Args:
        params: iterable of tensors or parameter groups (typically ``[par.u]``).
        lr: learning rate, in the parameter's unit (mm for ``u``): the largest
            entry of a step is at most about ``lr``.
        betas: (beta1, beta2) moment decay rates in [0, 1).
        eps: added to the normaliser, in the gradient's unit.
    Attributes:
        param_groups: list of dicts, each with ``params`` (tensors) and its ``lr``, ``betas``, ``eps``;
            change ``lr`` there between steps.
        state: per parameter tensor, ``step`` and the moments ``exp_avg``, ``exp_avg_sq``.
    """

    def __init__(self, params: Iterable, lr: float = 1e-3, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8):
        if not lr >= 0.0:
            raise InputError("UniformAdam", f"lr must be >= 0, got {lr}")
        if not (0.0 <= betas[0] < 1.0 and 0.0 <= betas[1] < 1.0):
            raise InputError("UniformAdam", f"betas must lie in [0, 1), got {betas}")
        if not eps >= 0.0:
            raise InputError("UniformAdam", f"eps must be >= 0, got {eps}")
        self.defaults = dict(lr=lr, betas=betas, eps=eps)
        params = list(params)
        groups = params if params and isinstance(params[0], dict) else [{"params": params}]
        self.param_groups = [{**self.defaults, **group, "params": list(group["params"])} for group in groups]
        if not any(group["params"] for group in self.param_groups):
            raise InputError("UniformAdam", "got an empty parameter list")
        for group in self.param_groups:
            if not all(isinstance(p, torch.Tensor) for p in group["params"]):
                raise InputError("UniformAdam", "parameters must be tensors")
        self.state: dict[torch.Tensor, dict] = defaultdict(dict)

    def zero_grad(self, set_to_none: bool = True) -> None:
        """Clear every parameter's gradient (to None, as ``torch.optim.Optimizer.zero_grad`` does by default)."""
        for group in self.param_groups:
            for p in group["params"]:
                if p.grad is None:
                    continue
                if set_to_none:
                    p.grad = None
                else:
                    p.grad.detach_()
                    p.grad.zero_()

    @torch.no_grad()
    def step(self, closure=None):
        """One update of every parameter with a gradient; returns ``closure()`` if given."""
        loss = None
        if closure is not None:
            with torch.enable_grad():
                loss = closure()
        for group in self.param_groups:
            b1, b2 = group["betas"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                g = p.grad
                if g.is_sparse:
                    raise InputError("UniformAdam", "sparse gradients are not supported")
                state = self.state[p]
                if not state:
                    state["step"] = 0
                    state["exp_avg"] = torch.zeros_like(p)
                    state["exp_avg_sq"] = torch.zeros_like(p)
                state["step"] += 1
                t = state["step"]
                m, v = state["exp_avg"], state["exp_avg_sq"]
                m.mul_(b1).add_(g, alpha=1.0 - b1)
                v.mul_(b2).addcmul_(g, g, value=1.0 - b2)
                m_hat = m / (1.0 - b1 ** t)
                denom = math.sqrt(float(v.max()) / (1.0 - b2 ** t)) + group["eps"]
                p.sub_(m_hat, alpha=group["lr"] / denom)
        return loss


class LargeStepsParametrization:
    """Vertices of one mesh resolution parametrised as ``u = (I + lambda L) x``.

    Holds the mesh, ``lambda``, the system matrix ``M`` and its factorisation.
    ``u`` is the leaf tensor to optimise; :meth:`vertices` gives differentiable
    positions. On refinement call :meth:`rebuild`, which replaces ``u`` with a
    new leaf: build a new optimiser over the new ``u`` afterwards.

    Args:
        V: (n, 3) vertex positions, mm: numpy array or torch tensor.
        F: (m, 3) int vertex indices per triangle (numpy array or torch tensor).
        lam: ``lambda >= 0``, dimensionless.
        laplacian: ``"cotangent"`` (paper) or ``"uniform"``.
        dtype: torch dtype of ``u`` (float32 by default, DESIGN.md).
        device: device of ``u``; default: ``V``'s device if a tensor, else CPU.
        face_weight: (m,) per-triangle factor on ``lam`` (None = 1, the paper;
            :func:`gpja.register.laplacian.system_matrix`).

    Attributes:
        V: (n, 3) float64 numpy, mm: the positions ``M`` was built from.
        F: (m, 3) int64 numpy.
        lam: float.
        face_weight: (m,) float64 or None.
        M: (n, n) float64 scipy CSR, dimensionless.
        solver: :class:`SmoothingSolver` of ``M``.
        u: (n, 3) ``dtype`` leaf tensor on ``device``, mm, ``requires_grad=True``.
    """

    def __init__(self, V, F, lam: float, laplacian: str = "cotangent",
                 dtype: torch.dtype = torch.float32, device: torch.device | str | None = None,
                 face_weight: np.ndarray | None = None):
        self.laplacian = laplacian
        self.dtype = dtype
        self.device = device
        self.rebuild(V, F, lam, face_weight)

    def rebuild(self, V, F, lam: float | None = None, face_weight: np.ndarray | None = None) -> None:
        """Rebuild ``M``, its factor and ``u`` for new positions/faces (e.g. after tessellation).

        Args:
            V: (n', 3) vertex positions, mm (numpy or torch; detached).
            F: (m', 3) int vertex indices per triangle.
            lam: new ``lambda``; ``None`` keeps the current one.
            face_weight: (m',) per-triangle factor on ``lambda`` for the new faces (None = 1).
        """
        device = self.device
        if isinstance(V, torch.Tensor):
            device = device if device is not None else V.device
            V = V.detach().cpu().double().numpy()
        if isinstance(F, torch.Tensor):
            F = F.detach().cpu().numpy()
        if lam is None:
            lam = self.lam
        self.V = np.array(V, dtype=np.float64)
        self.F = np.array(F, dtype=np.int64)
        self.lam = float(lam)
        self.face_weight = None if face_weight is None else np.asarray(face_weight, dtype=np.float64)
        self.M = system_matrix(self.V, self.F, self.lam, laplacian=self.laplacian, face_weight=self.face_weight)
        self.solver = SmoothingSolver(self.M)
        self._M_torch = None
        u = torch.from_numpy(self.M @ self.V)  # float64 product, then cast: exact to dtype rounding
        self.u = u.to(dtype=self.dtype, device=device if device is not None else "cpu").requires_grad_(True)

    def vertices(self) -> torch.Tensor:
        """Differentiable positions ``x = M^-1 u``: (n, 3) tensor of ``u``'s dtype/device, mm."""
        return from_differential(self.u, self.solver)

    def shift(self, dx: torch.Tensor) -> None:
        """Move the vertices by exactly ``dx`` ((n, 3), mm): ``u += M dx``, outside autograd.

        The optimiser's moments are kept; the next :meth:`vertices` includes the move. On the CPU the
        product is scipy's CSR one in float64 (then cast, as :meth:`rebuild` does): torch's sparse
        COO product took 38 ms at 164K vertices against scipy's few, and the hold calls this every
        iteration (docs/benchmarks.md). On another device, torch's sparse product.
        """
        with torch.no_grad():
            if self.u.device.type == "cpu":
                du = torch.from_numpy(self.M @ dx.detach().double().numpy())
            else:
                if self._M_torch is None:
                    self._M_torch = sparse_to_torch(self.M, dtype=self.u.dtype, device=self.u.device)
                du = to_differential(dx.to(dtype=self.u.dtype, device=self.u.device), self._M_torch)
            self.u += du.to(dtype=self.u.dtype)

    def optimizer(self, lr: float, betas: tuple[float, float] = (0.9, 0.999), eps: float = 1e-8) -> UniformAdam:
        """A fresh :class:`UniformAdam` over ``[self.u]`` (call again after :meth:`rebuild`)."""
        return UniformAdam([self.u], lr=lr, betas=betas, eps=eps)
