"""The NumPy path of ``Problem.linearize`` (``MICROLIE_FAST=0``): work arrays, the whitening
product and the sparse sum into the pattern, against ``H = J^T J`` and ``g = J^T e`` of a dense
central-difference Jacobian of the whitened residuals of the whole problem (every factor
batch: SE(3) edges with fixed ends, a duplicate and a reversed edge, per-edge, shared and
diagonal noise, an SE(3) prior batch, a vector between batch and a custom factor over a pose and
a vector), with and without robust losses (the Triggs-corrected rows written out here from the
loss's derivatives)."""

from __future__ import annotations

import numpy as np
import pytest

from microlie import SE3
from microlie.optim import (
    BetweenFactor,
    CustomFactor,
    Diagonal,
    FactorGraph,
    Information,
    Isotropic,
    PriorFactor,
)
from microlie.optim.core.problem import Problem


def _graph(rng, per_edge=True, loss=None):
    n = 8
    X = SE3.exp(rng.standard_normal((n, 6)))
    ii = [0, 1, 2, 3, 4, 5, 6, 0, 2, 5, 5]  # 2-5 twice, and 5-2 reversed
    jj = [1, 2, 3, 4, 5, 6, 7, 4, 5, 2, 2]
    m = len(ii)
    Z = X[np.array(ii)].inverse().compose(X[np.array(jj)]).compose(
        SE3.exp(0.2 * rng.standard_normal((m, 6))))
    if per_edge == "diagonal":  # one Diagonal model per edge: whitening is a scale
        noise = Diagonal(rng.uniform(0.2, 2.0, (m, 6)))
    else:
        B = rng.standard_normal((m, 6, 6) if per_edge else (6, 6))
        noise = Information(B @ np.swapaxes(B, -1, -2) + 0.5 * np.eye(6))
    fg = FactorGraph()
    x = fg.add_variables(X, fixed=[0, 6])
    v = fg.add_variables(rng.standard_normal((3, 2)))
    fg.add(BetweenFactor(x, ii, jj, Z, noise, loss=loss))
    fg.add(PriorFactor(x, [3, 6, 7], SE3.exp(0.3 * rng.standard_normal((3, 6))),
                       Isotropic(6, 0.5)))
    fg.add(BetweenFactor(v, [0, 1], [1, 2], rng.standard_normal((2, 2)), Isotropic(2, 0.3)))

    def rel(X, p):  # a position measured from a pose
        return X.inverse().act(np.concatenate([p, np.ones((len(p), 1))], 1)) - 1.0

    fg.add(CustomFactor(rel, [(x, [2, 7]), (v, [0, 2])], 3, Isotropic(3, 2.0),
                        jac="numerical", loss=loss))
    return fg


def _whitened(p, states):
    """The whitened residuals of every factor, per factor batch."""
    out = []
    for f in p.factors:
        r = np.asarray(f.evaluate(p.gather(f, states), False))
        L = np.broadcast_to(f.noise.sqrt_info, (f.count, f.dim, f.dim))
        out.append(np.einsum("mij,mj->mi", L, r))
    return out


def _dense_system(p, states, h=1e-6):
    e0 = _whitened(p, states)
    cols = []
    for k in range(p.size):
        d = np.zeros(p.size)
        d[k] = h
        ep, em = _whitened(p, p.retract(states, d)), _whitened(p, p.retract(states, -d))
        cols.append([(a - b) / (2 * h) for a, b in zip(ep, em, strict=True)])
    H = np.zeros((p.size, p.size))
    g = np.zeros(p.size)
    for fi, f in enumerate(p.factors):
        e = e0[fi]  # (m, dim)
        J = np.stack([c[fi] for c in cols], axis=-1)  # (m, dim, size)
        if f.loss is not None:
            # Ceres' corrector: sqrt(rho') (I - alpha e e^T / |e|^2) J and
            # sqrt(rho') / (1 - alpha) e, with alpha = 0 where rho'' <= 0
            s = (e * e).sum(1)
            _, r1, r2 = f.loss.evaluate(s)
            alpha = np.where(r2 > 0, 1 - np.sqrt(np.maximum(1 + 2 * s * r2 / r1, 0)), 0.0)
            eJ = np.einsum("mi,mij->mj", e, J)
            J = np.sqrt(r1)[:, None, None] * (
                J - (alpha / s)[:, None, None] * e[:, :, None] * eJ[:, None, :])
            e = (np.sqrt(r1) / (1 - alpha))[:, None] * e
        H += np.einsum("mik,mil->kl", J, J)
        g += np.einsum("mik,mi->k", J, e)
    return H, g


@pytest.fixture
def numpy_path(monkeypatch):
    """The NumPy path, with chunks of 3 factors (the batches here have 2 to 11: several
    chunks and a partial last one)."""
    from microlie.optim.core import problem

    monkeypatch.setenv("MICROLIE_FAST", "0")
    monkeypatch.setattr(problem, "_CHUNK", 3)


@pytest.mark.parametrize("per_edge", [True, False, "diagonal"])
@pytest.mark.parametrize("loss", [None, "huber:0.5", "cauchy:1.0"])
def test_linear_system_matches_dense_jacobian(numpy_path, per_edge, loss):
    fg = _graph(np.random.default_rng(3), per_edge, loss)
    p = Problem(fg.variables, fg.factors, "check")
    assert all(pl is None for pl in p.plans)
    states = [v.initial for v in p.variables]
    lin = p.linearize(states)
    H, g = _dense_system(p, states)
    got = p.matrix(lin.data).toarray()
    scale = np.abs(H).max()
    np.testing.assert_allclose(got, H, rtol=0, atol=1e-6 * scale)
    np.testing.assert_allclose(lin.grad, g, rtol=0, atol=1e-6 * np.abs(g).max())
    np.testing.assert_array_equal(got, got.T)
    cost, rcost = p.costs(states)
    assert lin.cost == pytest.approx(cost, rel=1e-13)
    assert lin.robust_cost == pytest.approx(rcost, rel=1e-13)
    assert cost == pytest.approx(0.5 * sum((e * e).sum() for e in _whitened(p, states)),
                                 rel=1e-13)


def test_linearisations_do_not_share_memory(numpy_path):
    """A kept linearisation is not changed by a later one (the work arrays are internal), and
    reusing one through ``out`` gives the same numbers."""
    fg = _graph(np.random.default_rng(5))
    p = Problem(fg.variables, fg.factors, "check")
    s0 = [v.initial for v in p.variables]
    s1 = p.retract(s0, 0.1 * np.random.default_rng(1).standard_normal(p.size))
    a = p.linearize(s0)
    a_data, a_grad = a.data.copy(), a.grad.copy()
    b = p.linearize(s1)
    np.testing.assert_array_equal(a.data, a_data)
    np.testing.assert_array_equal(a.grad, a_grad)
    assert not np.array_equal(b.data, a_data)
    again = p.linearize(s0, out=b)
    np.testing.assert_array_equal(again.data, a_data)
    np.testing.assert_array_equal(again.grad, a_grad)


@pytest.mark.parametrize("loss", [None, "huber:0.5"])
def test_jacobians_kept_by_a_trial_cost(numpy_path, loss):
    """``costs(states, keep=True)`` keeps the whitened Jacobians for ``linearize`` of the same
    list: the same numbers as a fresh linearisation, and never stale ones for another list."""
    fg = _graph(np.random.default_rng(9), loss=loss)
    p = Problem(fg.variables, fg.factors, "check")
    fresh = Problem(fg.variables, fg.factors, "check")
    s0 = [v.initial for v in p.variables]
    s1 = p.retract(s0, 0.1 * np.random.default_rng(2).standard_normal(p.size))
    for st in (s0, s1):
        ref = fresh.linearize(st)
        assert p.costs(st, keep=True) == pytest.approx(fresh.costs(st), rel=1e-14)
        p.costs(s1 if st is s0 else s0)  # a plain cost elsewhere leaves the kept arrays alone
        got = p.linearize(st)
        np.testing.assert_array_equal(got.data, ref.data)
        np.testing.assert_array_equal(got.grad, ref.grad)
        assert (got.cost, got.robust_cost) == (ref.cost, ref.robust_cost)
    p.costs(s0, keep=True)
    other = [s.copy() for s in s1]  # another list: evaluated afresh
    np.testing.assert_array_equal(p.linearize(other).data, fresh.linearize(s1).data)
    np.testing.assert_array_equal(p.linearize(s0).data, fresh.linearize(s0).data)


def test_a_kept_linearisation_does_not_evaluate_again(numpy_path, monkeypatch):
    """After ``costs(states, keep=True)``, ``linearize(states)`` evaluates no between factor
    again (the kept Jacobians are what it uses); another list is evaluated."""
    from microlie.optim.core import factors

    calls = []
    original = factors.BetweenFactor.evaluate_into

    def counted(self, values, out):
        calls.append(1)
        return original(self, values, out)

    monkeypatch.setattr(factors.BetweenFactor, "evaluate_into", counted)
    fg = _graph(np.random.default_rng(5))
    p = Problem(fg.variables, fg.factors, "check")
    s0 = [v.initial for v in p.variables]
    p.costs(s0, keep=True)
    kept = len(calls)
    assert kept > 0
    p.linearize(s0)
    assert len(calls) == kept
    p.linearize([s.copy() for s in s0])
    assert len(calls) > kept


@pytest.mark.parametrize("solver", ["lm", "gn", "dogleg"])
def test_solvers_take_the_same_run_with_and_without_kept_jacobians(numpy_path, monkeypatch,
                                                                   solver):
    from microlie.optim.core import factors

    runs = []
    for flag in (True, False):
        monkeypatch.setattr(factors.BetweenFactor, "jacobians_with_residuals", flag)
        monkeypatch.setattr(factors.PriorFactor, "jacobians_with_residuals", flag)
        fg = _graph(np.random.default_rng(4), loss="huber:1.0")
        res = fg.optimize(solver=solver, max_iter=20)
        runs.append((res, [res.values.params(v) for v in fg.variables]))
    # the same run to rounding (a kept trial's residual comes from minus(jac=True) and one
    # product, a plain one from minus() and another: equal up to the last bits)
    (a, pa), (b, pb) = runs
    assert a.iterations == b.iterations > 2
    np.testing.assert_allclose([h.cost for h in a.history], [h.cost for h in b.history],
                               rtol=1e-13)
    for u, v in zip(pa, pb, strict=True):
        np.testing.assert_allclose(u, v, rtol=0, atol=1e-12)


def test_a_problem_without_free_variables(numpy_path):
    """Every variable fixed: an empty system, and the cost of the residuals
    ``Log(Z^-1 X_i^-1 X_j)`` written out here (failed in the pattern lookup on 1bd9510)."""
    from microlie import SE2
    from microlie.optim import BetweenFactor, FactorGraph

    X = SE2.exp(np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.3], [2.0, -0.5, 1.0]]))
    Z = SE2.exp(np.array([[0.9, 0.4, 0.2], [1.1, -1.2, 0.6]]))
    fg = FactorGraph()
    x = fg.add_variables(X, fixed=[0, 1, 2])
    fg.add(BetweenFactor(x, [0, 1], [1, 2], Z))
    p = fg.problem(gauge="none")
    lin = p.linearize([x.initial])
    assert p.size == 0 and lin.data.shape == (0,) and lin.grad.shape == (0,)
    r = (Z.inverse() @ X[np.array([0, 1])].inverse() @ X[np.array([1, 2])]).log()
    assert np.isclose(lin.cost, 0.5 * float((r ** 2).sum()), rtol=1e-12)
