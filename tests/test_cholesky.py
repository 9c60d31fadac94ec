"""gpja.cholesky: both backends factor and solve SPD systems alike, and refuse bad input by name."""
import numpy as np
import pytest
import scipy.sparse as sp

from gpja.cholesky import BACKENDS, factorize
from gpja.errors import InputError
from tests.tolerances import EXACT_F64


def mesh_system(subdivisions: int = 3) -> sp.csr_matrix:
    """The flow stage's bi-Laplacian system on a sphere (2-ring sparsity, the fill the backends differ on)."""
    from gpja.register.flow import smoothness_system
    from tests.render.scenes import sphere

    V, F = sphere(subdivisions=subdivisions, radius=30.0)
    w = np.random.default_rng(0).random(len(V))
    return (smoothness_system(F, len(V), 30.0) + sp.diags(w)).tocsr()


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_diagonal_system_is_solved_exactly(backend):
    d = np.array([1.0, 2.0, 4.0, 8.0])
    x = factorize(sp.diags(d), backend).solve(np.ones((4, 2)))
    np.testing.assert_allclose(x, np.tile(1.0 / d[:, None], (1, 2)), rtol=EXACT_F64)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_two_by_two_system_matches_its_inverse(backend):
    H = sp.csr_matrix(np.array([[4.0, 1.0], [1.0, 3.0]]))
    x = factorize(H, backend).solve(np.array([1.0, 2.0]))
    assert x.shape == (2,)
    np.testing.assert_allclose(x, np.array([1.0, 7.0]) / 11.0, rtol=EXACT_F64)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_mesh_system_is_solved_to_rounding_and_both_backends_agree(backend):
    H = mesh_system()
    B = np.random.default_rng(1).normal(size=(H.shape[0], 3))
    x = factorize(H, backend).solve(B)
    assert x.dtype == np.float64 and x.shape == B.shape
    assert np.abs(H @ x - B).max() < 1e3 * EXACT_F64 * np.abs(B).max()
    other = factorize(H, [b for b in BACKENDS if b != backend][0]).solve(B)
    np.testing.assert_allclose(x, other, atol=1e3 * EXACT_F64 * np.abs(x).max())


def test_only_one_triangle_is_read_and_duplicates_are_summed():
    # the same matrix given with duplicate entries: the supernodal backend reads the lower triangle
    H = mesh_system(2).tocoo()
    doubled = sp.coo_matrix((np.concatenate([H.data, H.data]) / 2, (np.tile(H.row, 2), np.tile(H.col, 2))), H.shape)
    B = np.ones((H.shape[0], 1))
    np.testing.assert_allclose(factorize(doubled, "supernodal").solve(B), factorize(H.tocsr(), "supernodal").solve(B),
                               rtol=1e3 * EXACT_F64)


@pytest.mark.parametrize("backend", BACKENDS)
def test_bad_input_is_refused_by_name(backend):
    with pytest.raises(InputError, match="square"):
        factorize(sp.csr_matrix((3, 2)), backend)
    with pytest.raises(InputError, match=r"shape \(3,\)"):
        factorize(sp.identity(3), backend).solve(np.ones(4))


@pytest.mark.parametrize("backend", BACKENDS)
def test_an_indefinite_system_is_refused(backend):
    with pytest.raises(InputError, match="not positive definite"):
        factorize(sp.diags([1.0, -1.0, 2.0]), backend)


def test_an_unknown_backend_is_refused():
    with pytest.raises(InputError, match="unknown Cholesky backend 'dense'"):
        factorize(sp.identity(3), "dense")
