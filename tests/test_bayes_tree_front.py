"""The front kernel of the compiled Bayes tree (microlie._c._incremental.factor_front: the
partial Cholesky of a clique front, on SciPy's BLAS/LAPACK or on loops) against NumPy's dense
Cholesky of the whole front."""

import numpy as np
import pytest

from microlie import _fast
from microlie.optim.online.bayes_tree import BayesTree

SIZES = [(1, 1), (6, 6), (12, 6), (31, 7), (64, 16), (150, 48), (300, 150), (420, 36)]


@pytest.fixture(scope="module")
def mod():
    m = _fast.module("_incremental")
    if m is None:
        pytest.skip("microlie._c._incremental is not built (or MICROLIE_FAST=0)")
    BayesTree()  # hands SciPy's BLAS/LAPACK to the module
    return m


def _spd(rng, w):
    """A symmetric positive definite front with a spread of scales (condition ~1e6)."""
    Q, _ = np.linalg.qr(rng.standard_normal((w, w)))
    return (Q * np.logspace(0, 6, w)) @ Q.T


@pytest.mark.parametrize("blas", [True, False])
@pytest.mark.parametrize("w,K", SIZES)
def test_front_equals_dense_cholesky(mod, w, K, blas):
    rng = np.random.default_rng(w * 1000 + K)
    A = _spd(rng, w)
    g = rng.standard_normal(w)
    L = np.linalg.cholesky(A)  # A = L L^T; the front's partial factor is its first K columns
    F = np.asfortranarray(np.tril(A) + np.triu(rng.standard_normal((w, w)), 1))  # upper: junk
    junk = np.triu(F, 1)
    y = g.copy()
    assert mod.factor_front(F, y, K, blas) == -1
    scale = np.abs(A).max()
    tol = 1e-12
    # L11 and L21
    assert np.abs(np.tril(F[:, :K]) - L[:, :K]).max() <= tol * np.abs(L).max()
    # the Schur complement A22 - L21 L21^T = L22 L22^T
    S = L[K:, K:] @ L[K:, K:].T
    assert np.abs(np.tril(F[K:, K:]) - np.tril(S)).max(initial=0.0) <= tol * scale
    # y = L11^-1 g1 and g2 - L21 y: the forward substitution of the whole front L z = g
    z = np.linalg.solve(L, g)
    expect = np.concatenate([z[:K], L[K:, K:] @ z[K:]])
    assert np.abs(y - expect).max() <= tol * max(1.0, np.abs(expect).max()) * np.sqrt(w)
    # the strictly upper part is never touched
    assert (np.triu(F, 1) == junk).all()


@pytest.mark.parametrize("blas", [True, False])
@pytest.mark.parametrize("w,K,c", [(6, 6, 0), (12, 6, 3), (80, 40, 29)])
def test_front_reports_first_bad_column(mod, w, K, c, blas):
    """A pivot made negative at column c (its Schur complement -1): the kernel names c."""
    rng = np.random.default_rng(c)
    A = _spd(rng, w)
    L = np.linalg.cholesky(A)
    A[c, c] = L[c, :c] @ L[c, :c] - 1.0
    F = np.asfortranarray(A)
    assert mod.factor_front(F, np.zeros(w), K, blas) == c


def test_front_bad_input(mod):
    A = np.eye(4)
    with pytest.raises(ValueError, match="Fortran-ordered"):
        mod.factor_front(np.ascontiguousarray(np.ones((4, 3))), np.zeros(4), 2, True)
    with pytest.raises(ValueError, match="K must be"):
        mod.factor_front(np.asfortranarray(A), np.zeros(4), 5, True)
    with pytest.raises(ValueError, match="g must be"):
        mod.factor_front(np.asfortranarray(A), np.zeros(3), 2, True)
