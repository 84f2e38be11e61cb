"""Issue 23: one factor at a time. BetweenFactor and PriorFactor batches of a few rows are
evaluated row by row by the compiled module ``microlie._c._factors`` (``Factor.linearize``,
``evaluate``, ``evaluate_into``); this checks that path against the batched NumPy path (to
1e-12), the matrix logarithm (scipy) and central differences, on hard inputs (identity, angles
near pi), in float64 and float32, with every noise model and a robust loss, and that bad input
still raises."""

from __future__ import annotations

import os

import numpy as np
import pytest
import scipy.linalg
from conftest import IN_CI

import microlie.optim.core.factors as F
from microlie import SE2, SE3, SE23, SO2, SO3, _fast
from microlie.optim import (
    BetweenFactor,
    Diagonal,
    FactorGraph,
    Information,
    Isotropic,
    PriorFactor,
    check_jacobians,
)
from microlie.optim.core.problem import Problem

GROUPS = [SO2, SO3, SE2, SE3, SE23]


@pytest.fixture
def rows():
    """The compiled row module (skipped locally, a failure in CI, when it is not built)."""
    if os.environ.get("MICROLIE_FAST", "1").strip() == "0":
        pytest.skip("MICROLIE_FAST=0: the row loop is off (both paths are the batched one)")
    mod = _fast.module("_factors")
    if mod is None:
        if IN_CI:
            pytest.fail("microlie._c._factors is not built; CI builds every module")
        pytest.skip("microlie._c._factors is not built (python setup.py build_ext --inplace)")
    return mod


def _hard(G, rng):
    """Pairs (X_i, X_j) and a measurement: random, identical, and relative rotations within
    1e-7 of pi."""
    out = [(G.random(rng=rng), G.random(rng=rng), G.random(rng=rng))]
    I = G.identity()
    out.append((I, I, I))
    tau = np.zeros(G.dof)
    k = {SO2: 0, SO3: 0, SE2: 2, SE3: 3, SE23: 0}[G]
    tau[k] = np.pi - 1e-7
    X = G.random(rng=rng)
    out.append((X, X @ G.exp(tau), G.identity()))
    out.append((X, X @ G.exp(0.5 * tau), G.exp(-0.5 * tau)))  # (X_i Z)^-1 X_j near pi
    return out


def _noises(d, rng):
    A = rng.standard_normal((d, d))
    return [None, Isotropic(d, 0.3), Diagonal(np.linspace(0.1, 0.9, d)),
            Information(A @ A.T + d * np.eye(d))]


def _batched(monkeypatch, fn):
    """``fn()`` with the row loop turned off (every batch on the batched kernels)."""
    with monkeypatch.context() as m:
        m.setattr(F, "SMALL_BATCH", 0)
        return fn()


@pytest.mark.parametrize("G", GROUPS, ids=lambda G: G.__name__)
def test_between_rows_equal_batched_path(G, rows, monkeypatch):
    rng = np.random.default_rng(1)
    for Xi, Xj, Z in _hard(G, rng):
        g = FactorGraph()
        x = g.add_variables(G.from_params(np.stack([Xi.params, Xj.params])))
        for N in _noises(G.dof, rng):
            f = BetweenFactor(x, 0, 1, Z, N)
            P = [x.initial[[0]], x.initial[[1]]]
            vals = [x.wrap(p) for p in P]
            e, A = f.linearize(P)
            r, J = f.evaluate(vals, True)
            out = np.empty((1, G.dof, 2 * G.dof))
            r2 = f.evaluate_into(vals, out)
            ref_e, ref_A = _batched(monkeypatch, lambda f=f, P=P: f.linearize(P))
            ref_r, ref_J = _batched(monkeypatch, lambda f=f, vals=vals: f.evaluate(vals, True))
            assert np.abs(e - ref_e).max() <= 1e-12 * max(1.0, np.abs(ref_e).max())
            assert np.abs(A - ref_A).max() <= 1e-12 * max(1.0, np.abs(ref_A).max())
            assert np.abs(r - ref_r).max() <= 1e-12
            for a, b in zip(J, ref_J, strict=True):
                assert np.abs(a - b).max() <= 1e-12 * max(1.0, np.abs(b).max())
            assert np.array_equal(r2, r) and np.array_equal(out, np.concatenate(J, axis=2))
            assert np.abs(f.residual(*vals) - ref_r).max() <= 1e-12


@pytest.mark.parametrize("G", GROUPS, ids=lambda G: G.__name__)
def test_prior_rows_equal_batched_path(G, rows, monkeypatch):
    rng = np.random.default_rng(2)
    for X, _, Z in _hard(G, rng):
        g = FactorGraph()
        x = g.add_variables(G.from_params(X.params[None]))
        for N in _noises(G.dof, rng):
            f = PriorFactor(x, 0, Z, N)
            P = [x.initial]
            e, A = f.linearize(P)
            r, (J,) = f.evaluate([x.wrap(P[0])], True)
            ref_e, ref_A = _batched(monkeypatch, lambda f=f, P=P: f.linearize(P))
            ref_r, (ref_J,) = _batched(monkeypatch, lambda f=f, P=P, x=x: f.evaluate(
                [x.wrap(P[0])], True))
            assert np.abs(e - ref_e).max() <= 1e-12 * max(1.0, np.abs(ref_e).max())
            assert np.abs(A - ref_A).max() <= 1e-12 * max(1.0, np.abs(ref_A).max())
            assert np.abs(r - ref_r).max() <= 1e-12
            assert np.abs(J - ref_J).max() <= 1e-12 * max(1.0, np.abs(ref_J).max())


def _vee(G, M):
    """The tangent (translation first) of a Lie-algebra matrix of SO3, SE2 or SE3."""
    if G is SO3:
        return np.array([M[2, 1], M[0, 2], M[1, 0]])
    if G is SE2:
        return np.array([M[0, 2], M[1, 2], M[1, 0]])
    return np.concatenate([M[:3, 3], [M[2, 1], M[0, 2], M[1, 0]]])


@pytest.mark.parametrize("G", [SO3, SE2, SE3], ids=lambda G: G.__name__)
def test_rows_against_matrix_log_and_differences(G, rows):
    """r = vee(logm(Z^-1 X_i^-1 X_j)) (scipy) and the Jacobians by central differences, with
    three rows and one information matrix per row (the row loop's other noise layout)."""
    rng = np.random.default_rng(3)
    X = G.random(6, rng=rng)
    Z = G.random(3, rng=rng)
    g = FactorGraph()
    x = g.add_variables(X)
    B = rng.standard_normal((3, G.dof, G.dof))
    info = B @ np.swapaxes(B, 1, 2) + G.dof * np.eye(G.dof)
    f = BetweenFactor(x, [0, 2, 4], [1, 3, 5], Z, Information(info))
    e, A = f.linearize([x.initial[[0, 2, 4]], x.initial[[1, 3, 5]]])
    L = f.noise.sqrt_info
    for k, (a, b) in enumerate([(0, 1), (2, 3), (4, 5)]):
        M = np.linalg.inv(Z[k].matrix()) @ np.linalg.inv(X[a].matrix()) @ X[b].matrix()
        r = _vee(G, np.real(scipy.linalg.logm(M)))
        assert np.abs(e[k] - L[k] @ r).max() <= 1e-9 * max(1.0, np.abs(e[k]).max())
    c = check_jacobians(f)
    assert c.ok, c
    r, J = f.evaluate([x.wrap(x.initial[[0, 2, 4]]), x.wrap(x.initial[[1, 3, 5]])], True)
    assert np.abs(A - L @ np.concatenate(J, axis=2)).max() <= 1e-12 * np.abs(A).max()


def test_linearize_with_loss_matches_problem_assembly(rows):
    """A^T A and A^T e of ``linearize`` (robust, Ceres' correction) against the engine's
    assembled normal equations of the same one-factor graph."""
    rng = np.random.default_rng(4)
    g = FactorGraph()
    x = g.add_variables(SE3.random(2, rng=rng))
    f = g.add(BetweenFactor(x, 0, 1, SE3.random(rng=rng), Isotropic(6, 0.05), loss="huber:1.0"))
    e, A = f.linearize([x.initial[[0]], x.initial[[1]]])
    p = Problem(g.variables, g.factors, "none")
    lin = p.linearize([v.initial for v in p.variables])
    H = p.matrix(lin.data).toarray()
    H = np.triu(H) + np.triu(H, 1).T  # the pattern may hold one triangle
    assert np.allclose(H, A[0].T @ A[0], rtol=1e-12, atol=1e-9)
    assert np.allclose(lin.grad, A[0].T @ e[0], rtol=1e-12, atol=1e-9)
    assert f.loss.rho(np.array([2.0 * lin.cost]))[0] < 2.0 * lin.cost  # the loss is active


def test_float32_values_take_the_batched_path(monkeypatch):
    rng = np.random.default_rng(5)
    g = FactorGraph()
    X = SE3.random(2, rng=rng)
    x = g.add_variables(X)
    f = BetweenFactor(x, 0, 1, SE3.random(rng=rng), Diagonal([0.1] * 6))
    P32 = [x.initial[[0]].astype(np.float32), x.initial[[1]].astype(np.float32)]
    e32, A32 = f.linearize(P32)
    e64, A64 = f.linearize([x.initial[[0]], x.initial[[1]]])
    assert np.abs(e32 - e64).max() <= 1e-4 * np.abs(e64).max()
    assert np.abs(A32 - A64).max() <= 1e-4 * np.abs(A64).max()
    r32, _ = f.evaluate([SE3.from_params(p, check=False) for p in P32], True)
    ref, _ = _batched(monkeypatch, lambda: f.evaluate(
        [SE3.from_params(p, check=False) for p in P32], True))
    assert np.array_equal(r32, ref)


def test_without_compiled_code_same_numbers(rows, monkeypatch):
    rng = np.random.default_rng(6)
    g = FactorGraph()
    x = g.add_variables(SE2.random(2, rng=rng))
    f = BetweenFactor(x, 0, 1, SE2.random(rng=rng), Information([[4, 1, 0], [1, 3, 0],
                                                                  [0, 0, 2.0]]))
    P = [x.initial[[0]], x.initial[[1]]]
    e, A = f.linearize(P)
    monkeypatch.setenv("MICROLIE_FAST", "0")
    e0, A0 = f.linearize(P)
    assert np.abs(e - e0).max() <= 1e-12 and np.abs(A - A0).max() <= 1e-12


def test_measurement_as_parameters():
    """A parameter array is checked by the group's constructor; equal to the element."""
    g = FactorGraph()
    x = g.add_variables(SE3.random(3, rng=7))
    Z = SE3.random(rng=8)
    a = BetweenFactor(x, 0, 1, np.array(Z.params))
    b = BetweenFactor(x, 0, 1, Z)
    assert np.abs(a.Z.params - b.Z.params).max() <= 1e-15  # normalised: |q| = 1 to rounding
    with pytest.raises(ValueError, match="BetweenFactor: measurement: .*norm differs from 1"):
        BetweenFactor(x, 0, 1, np.array([0, 0, 0, 0, 0, 0, 2.0]))
    with pytest.raises(ValueError, match=r"measurement parameters must have shape \(7,\)"):
        BetweenFactor(x, 0, 1, np.zeros(6))
    with pytest.raises(ValueError, match="PriorFactor: measurement: SE3 parameters contains NaN"):
        PriorFactor(x, 0, np.array([np.nan, 0, 0, 0, 0, 0, 1.0]))


def test_bad_input_still_raises():
    g = FactorGraph()
    x = g.add_variables(SE2.random(3, rng=9))
    Z = SE2.random(rng=10)
    with pytest.raises(ValueError, match=r"BetweenFactor 0: i == j == 2"):
        BetweenFactor(x, 2, 2, Z)
    with pytest.raises(ValueError, match=r"BetweenFactor 1: i == j == 1"):
        BetweenFactor(x, [0, 1], [1, 1], Z)
    for bad in (3, -1, np.int64(5)):
        with pytest.raises(ValueError, match=f"index {int(bad)} out of range"):
            BetweenFactor(x, 0, bad, Z)
    with pytest.raises(ValueError, match="out of range"):
        PriorFactor(x, [0, 7], Z)
    with pytest.raises(ValueError, match="boolean mask"):
        PriorFactor(x, True, Z)
    with pytest.raises(ValueError, match="must be integers"):
        PriorFactor(x, 1.0, Z)
    nan = SE2.from_params(np.array([np.nan, 0, 1, 0]), check=False)
    with pytest.raises(ValueError, match="measurement has non-finite entries"):
        BetweenFactor(x, 0, 1, nan)
    with pytest.raises(TypeError, match="measurement must be a SE2"):
        BetweenFactor(x, 0, 1, SO3.identity())
    with pytest.raises(ValueError, match="2 parameter arrays for 1 arguments"):
        PriorFactor(x, 0, Z).linearize([x.initial[[0]], x.initial[[1]]])


def test_noise_constructors_check_single_matrices():
    with pytest.raises(ValueError, match="the information matrix is not symmetric"):
        Information([[1.0, 0.5], [0.0, 1.0]])
    with pytest.raises(ValueError, match="not positive definite: smallest eigenvalue -1"):
        Information([[1.0, 0.0], [0.0, -1.0]])
    with pytest.raises(ValueError, match="non-finite"):
        Information([[1.0, np.inf], [np.inf, 1.0]])
    with pytest.raises(ValueError, match="Diagonal sigmas must be positive"):
        Diagonal([0.1, -0.2])
    with pytest.raises(ValueError, match="Isotropic dim must be a positive integer"):
        Isotropic(0, 1.0)
    rng = np.random.default_rng(11)
    for d in (1, 3, 6, 9):
        B = rng.standard_normal((d, d))
        O = B @ B.T + 0.1 * np.eye(d)
        L = Information(O).sqrt_info
        assert L.flags.c_contiguous and np.allclose(np.tril(L, -1), 0.0)
        assert np.allclose(L.T @ L, O, rtol=1e-12, atol=1e-12 * np.abs(O).max())
        assert np.allclose(L, scipy.linalg.cholesky(O, lower=False), rtol=1e-12, atol=1e-14)
    assert np.array_equal(Diagonal([0.5, 0.25]).sqrt_info, np.diag([2.0, 4.0]))


def test_linearize_of_any_factor_is_the_whitened_evaluate():
    """The general path (a CustomFactor, one information matrix per row): e = L r and
    A = L J against dense products of evaluate's output."""
    from microlie.optim import CustomFactor

    rng = np.random.default_rng(12)
    g = FactorGraph()
    x = g.add_variables(rng.standard_normal((4, 2)))
    B = rng.standard_normal((2, 2, 2))
    info = B @ np.swapaxes(B, 1, 2) + np.eye(2)
    f = CustomFactor(lambda a, b: np.sin(a) * b, [(x, [0, 1]), (x, [2, 3])], 2,
                     Information(info), jac="numerical")
    P = [x.initial[[0, 1]], x.initial[[2, 3]]]
    e, A = f.linearize(P)
    r, J = f.evaluate(P, True)
    L = f.noise.sqrt_info
    for k in range(2):
        assert np.allclose(e[k], L[k] @ r[k], rtol=1e-14, atol=1e-14)
        assert np.allclose(A[k], L[k] @ np.hstack([J[0][k], J[1][k]]), rtol=1e-14, atol=1e-14)
    assert np.allclose(r, np.sin(P[0]) * P[1], rtol=1e-14)


@pytest.mark.parametrize("upper", [False, True])
def test_small_cholesky_without_scipy_linalg_equals_lapack(monkeypatch, upper):
    # microlie optimize never imports scipy.linalg: one small matrix then goes through NumPy
    import sys

    from scipy.linalg.lapack import dpotrf

    from microlie.optim.core import noise

    rng = np.random.default_rng(3)
    A = rng.standard_normal((6, 6))
    M = A @ A.T + 6 * np.eye(6)
    want, info = dpotrf(M, lower=0 if upper else 1, clean=1)
    assert info == 0
    monkeypatch.delitem(sys.modules, "scipy.linalg.lapack")
    got = noise._potrf(M, upper)
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13)
    assert noise._potrf(M - 20 * np.eye(6), upper) is None  # indefinite
