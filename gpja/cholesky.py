"""Sparse Cholesky factors of symmetric positive definite systems, with two CHOLMOD backends.

Both backends are SuiteSparse's CHOLMOD; they differ in the factor's form, and that decides where each pays:

``"supernodal"`` (cvxopt's CHOLMOD, supernodal LL^T; the cvxopt wheel bundles SuiteSparse and a BLAS)
    Factorises column blocks with dense BLAS-3 kernels. The flow stage's bi-Laplacian system
    (``gpja.register.flow``, 21 non-zeros a row) at 100K vertices factors in about 1.2 s, where the
    simplicial factor takes about 12 s (``benchmarks/bench_cholesky.py``). Its solves cost 2-4x the
    simplicial ones.
``"simplicial"`` (cholespy's CHOLMOD, simplicial LL^T, solved by cholespy's own triangular solves)
    Fast solves, slow factorisations when the factor fills in. The choice before ``"supernodal"``
    existed. The LargeSteps parametrisation (``gpja.register.largesteps``: two solves an iteration,
    one factorisation a level) keeps using cholespy directly for that reason.

Why two libraries rather than one: cholespy does not expose CHOLMOD's supernodal mode, and cvxopt's
solves are slower. scikit-sparse would give both, but it has no wheels and needs SuiteSparse's headers to build.
Both backends are single-threaded here, so a job's thread budget (``gpja --threads``) holds.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from gpja.errors import InputError

#: the backends :func:`factorize` accepts
BACKENDS = ("supernodal", "simplicial")
#: every caller's default (the flow stage's and NICP's settings, ``nicp_solver.AffineSolver``): fast solves, and the
#: factor every registration before the supernodal one was computed with (docs/experiments.md)
DEFAULT_BACKEND = "simplicial"


class CholeskyFactor:
    """A sparse Cholesky factor of an SPD ``H (N, N)``; ``solve(B)`` returns ``H^-1 B``.

    Attributes:
        n: the system's size N.
        backend: one of :data:`BACKENDS`.
    """

    def __init__(self, n: int, backend: str, factor):
        self.n, self.backend, self._factor = n, backend, factor

    def solve(self, B: np.ndarray) -> np.ndarray:
        """``H^-1 B`` for ``B (N,)`` or ``(N, k)``, any float dtype; float64 of ``B``'s shape."""
        B = np.asarray(B, dtype=np.float64)
        if B.ndim not in (1, 2) or B.shape[0] != self.n:
            raise InputError("CholeskyFactor.solve", f"B must have shape ({self.n},) or ({self.n}, k), got {B.shape}")
        columns = B.reshape(self.n, -1)
        if self.backend == "supernodal":
            import cvxopt
            import cvxopt.cholmod

            X = cvxopt.matrix(np.asfortranarray(columns))  # solved in place
            cvxopt.cholmod.solve(self._factor, X)
            X = np.array(X)
        else:
            X = np.empty_like(columns)
            self._factor.solve(np.ascontiguousarray(columns), X)
        return X.reshape(B.shape)


def factorize(H: sp.spmatrix, backend: str = DEFAULT_BACKEND) -> CholeskyFactor:
    """The Cholesky factor of SPD ``H (N, N)`` (scipy sparse, both triangles stored).

    Args:
        H: the system; its duplicates are summed.
        backend: ``"simplicial"`` (fast solves; :data:`DEFAULT_BACKEND`) or ``"supernodal"`` (fast
            factorisation); module docstring.
    Raises:
        InputError: an unknown backend, a non-square ``H``, or ``H`` not positive definite.
    """
    if backend not in BACKENDS:
        raise InputError("factorize", f"unknown Cholesky backend {backend!r}; expected one of {', '.join(BACKENDS)}")
    if H.shape[0] != H.shape[1]:
        raise InputError("factorize", f"H must be square, got shape {H.shape}")
    n = H.shape[0]
    if backend == "supernodal":
        import cvxopt
        import cvxopt.cholmod

        lower = sp.tril(H, format="csc")  # CHOLMOD reads one triangle; summing duplicates also sorts
        lower.sum_duplicates()
        columns = np.repeat(np.arange(n, dtype=np.int64), np.diff(lower.indptr))
        A = cvxopt.spmatrix(cvxopt.matrix(lower.data.astype(np.float64)), cvxopt.matrix(lower.indices.astype(np.int64)),
                            cvxopt.matrix(columns), (n, n))
        options = cvxopt.cholmod.options
        previous = options.get("supernodal")
        options["supernodal"] = 2  # always supernodal (CHOLMOD's default picks by the fill's density)
        try:
            factor = cvxopt.cholmod.symbolic(A, uplo="L")
            cvxopt.cholmod.numeric(A, factor)
        except ArithmeticError as err:
            raise InputError("factorize", f"the {n} x {n} system is not positive definite ({err})") from None
        finally:
            if previous is None:
                options.pop("supernodal", None)
            else:
                options["supernodal"] = previous
        return CholeskyFactor(n, backend, factor)
    from cholespy import CholeskySolverD, MatrixType

    H = sp.csr_matrix(H)
    H.sum_duplicates()
    H.sort_indices()
    try:
        factor = CholeskySolverD(n, H.indptr.astype(np.int32), H.indices.astype(np.int32),
                                 H.data.astype(np.float64), MatrixType.CSR)
    except ValueError as err:
        raise InputError("factorize", f"the {n} x {n} system is not positive definite ({err})") from None
    return CholeskyFactor(n, backend, factor)
