"""The compiled edge loop (``microlie._c._graph``,
``microlie.optim.core.compiled``)
against the NumPy path of ``Problem``: the same linear system (CSC values of H and the gradient),
costs and solutions to rounding, on SE(3) graphs with the hard residuals (rotation angle 0,
1e-12, near pi, exactly pi), fixed ends, duplicate edges, per-edge and shared noise, robust
losses and a prior batch on the NumPy path beside it. The reference runs with every compiled
kernel unregistered (the generic NumPy component kernels: independent code, not the C element
functions). ``MICROLIE_FAST=0`` turns the compiled loop off."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require

from microlie import SE2, SE3
from microlie.optim import BetweenFactor, FactorGraph, Information, Isotropic, PriorFactor
from microlie.optim.core.problem import Problem


@pytest.fixture
def graph_mod(monkeypatch):
    monkeypatch.delenv("MICROLIE_FAST", raising=False)
    return require("microlie._c._graph")


def _generic_problem(fg: FactorGraph, monkeypatch) -> Problem:
    """The problem on the NumPy path with the generic kernels (compiled group kernels
    unregistered while it is evaluated by the caller: see ``_generic``)."""
    monkeypatch.setenv("MICROLIE_FAST", "0")
    p = Problem(fg.variables, fg.factors, "check")
    monkeypatch.delenv("MICROLIE_FAST")
    assert all(pl is None for pl in p.plans)
    return p


class _generic:
    """Context: every compiled group kernel unregistered (restored on exit)."""

    def __enter__(self):
        from microlie import _kernels as K

        self.saved = {n: k.impl for n, k in K.KERNELS.items() if k.impl is not None}
        for n in self.saved:
            K.register(n, None)

    def __exit__(self, *exc):
        from microlie import _kernels as K

        for n, impl in self.saved.items():
            K.register(n, impl)


def _tangent(G, rng, angle=None):
    """A tangent vector of G (translation first) with a random rotation of ``angle``."""
    if G is SE2:
        th = rng.uniform(-2, 2) if angle is None else angle
        return np.concatenate([rng.standard_normal(2), [th]])
    ax = rng.standard_normal(3)
    ax /= np.linalg.norm(ax)
    th = rng.uniform(0, 2) if angle is None else angle
    return np.concatenate([rng.standard_normal(3), th * ax])


def _hard_graph(rng, G=SE3, per_edge_noise=True, loss=None, exact_pi=True):
    """Poses 0..n-1 (0 and 3 fixed); a chain, loop closures, a duplicate and a reversed edge,
    and edges whose residual at the start has rotation angle 0, 1e-12, pi - 1e-6 and exactly
    pi."""
    n, d = 14, G.dof
    X = G.exp(np.stack([_tangent(G, rng) for _ in range(n)])).params.copy()
    # hard residuals: X_i = identity, Z = identity, X_j = Exp(angle about an axis)
    X[9] = G.identity().params
    for j, th in {10: 0.0, 11: 1e-12, 12: np.pi - 1e-6}.items():
        X[j] = G.exp(_tangent(G, rng, th)).params
    # a rotation by exactly pi (w = 0; cos = -1, sin = 0)
    X[13] = [0.3, -0.2, 0.5, 0.0, 0.0, 1.0, 0.0] if G is SE3 else [0.3, -0.2, -1.0, 0.0]
    ii = list(range(9)) + [0, 2, 5, 1, 1, 6] + [9, 9, 9, 9]  # 1-6 twice and 6-1
    jj = list(range(1, 10)) + [7, 8, 11, 6, 6, 1] + [10, 11, 12, 13]
    if not exact_pi:
        ii, jj = ii[:-1], jj[:-1]
    m = len(ii)
    Xs = G(X)
    Z = Xs[np.array(ii)].inverse().compose(Xs[np.array(jj)]).compose(
        G.exp(0.1 * rng.standard_normal((m, d))))
    Zp = Z.params.copy()
    Zp[-4 + (not exact_pi):] = G.identity().params  # the hard edges measure the identity
    Z = G(Zp)
    if per_edge_noise:
        B = rng.standard_normal((m, d, d))
        noise = Information(B @ np.swapaxes(B, 1, 2) + 0.5 * np.eye(d))
    else:
        B = rng.standard_normal((d, d))
        noise = Information(B @ B.T + 0.5 * np.eye(d))
    fg = FactorGraph()
    x = fg.add_variables(G(X), fixed=[0, 3] if exact_pi else [0, 3, 13])
    fg.add(BetweenFactor(x, ii, jj, Z, noise, loss=loss))
    fg.add(PriorFactor(x, [4, 6], G.exp(0.2 * rng.standard_normal((2, d))), Isotropic(d, 0.5)))
    return fg


@pytest.mark.parametrize("G", [SE3, SE2], ids=["SE3", "SE2"])
@pytest.mark.parametrize("per_edge", [True, False])
@pytest.mark.parametrize("loss", [None, "huber:0.5", "cauchy:1.0"])
def test_same_linear_system(graph_mod, monkeypatch, G, per_edge, loss):
    rng = np.random.default_rng(7)
    fg = _hard_graph(rng, G, per_edge, loss)
    pc = Problem(fg.variables, fg.factors, "check")
    assert pc.plans[0] is not None and pc.plans[1] is None  # between compiled, prior NumPy
    pn = _generic_problem(fg, monkeypatch)
    states = [v.initial for v in pc.variables]
    with _generic():
        ref = pn.linearize(states)
        ref_costs = pn.costs(states)
    got = pc.linearize(states)
    scale = np.abs(ref.data).max()
    assert np.abs(got.data - ref.data).max() <= 1e-13 * scale
    assert np.abs(got.grad - ref.grad).max() <= 1e-13 * np.abs(ref.grad).max()
    assert got.cost == pytest.approx(ref.cost, rel=1e-13)
    assert got.robust_cost == pytest.approx(ref.robust_cost, rel=1e-13)
    assert pc.costs(states) == pytest.approx(ref_costs, rel=1e-13)
    # the fixed poses' rows and columns stay out of H, duplicate edges add up: H is the dense
    # sum over edges of A^T A built by hand from the reference Jacobians
    H = pc.matrix(got.data).toarray()
    assert np.allclose(H, H.T, rtol=0, atol=1e-13 * scale)
    assert np.all(np.linalg.eigvalsh(H) > -1e-9 * scale)
    # reuse of a linearisation's arrays gives the same numbers
    again = pc.linearize(states, out=pc.linearize(states))
    np.testing.assert_array_equal(again.data, got.data)


@pytest.mark.parametrize("G", [SE3, SE2], ids=["SE3", "SE2"])
def test_against_dense_jacobian(graph_mod, G):
    """H = J^T J and g = J^T e against a central-difference Jacobian of the whitened residuals
    (without the edge at exactly pi, where Log is not differentiable: the axis flips)."""
    rng = np.random.default_rng(3)
    fg = _hard_graph(rng, G, True, None, exact_pi=False)
    p = Problem(fg.variables, fg.factors, "check")
    f = p.factors[0]
    states = [v.initial for v in p.variables]
    L = f.noise.sqrt_info

    def e_of(st):
        r = np.asarray(f.evaluate(p.gather(f, st), False))
        return np.einsum("mij,mj->mi", L, r).ravel()


    e0 = e_of(states)
    h = 1e-6
    J = np.zeros((e0.size, p.size))
    for k in range(p.size):
        d = np.zeros(p.size)
        d[k] = h
        J[:, k] = (e_of(p.retract(states, d)) - e_of(p.retract(states, -d))) / (2 * h)
    data, grad = np.zeros(p.nnz), np.zeros(p.size)
    s = p.plans[0].normal(states, data, grad, None)
    np.testing.assert_allclose(s, (e0.reshape(-1, G.dof) ** 2).sum(1), rtol=1e-12)
    H = p.matrix(data).toarray()
    np.testing.assert_allclose(H, J.T @ J, atol=1e-6 * np.abs(H).max())
    np.testing.assert_allclose(grad, J.T @ e0, atol=1e-6 * np.abs(grad).max())


@pytest.mark.parametrize("G", [SE3, SE2], ids=["SE3", "SE2"])
def test_same_solution(graph_mod, monkeypatch, G):
    rng = np.random.default_rng(11)
    fg = _hard_graph(rng, G, True, "huber:1.0")
    res = fg.optimize(max_iter=30)
    monkeypatch.setenv("MICROLIE_FAST", "0")
    fg._changed()  # rebuild the problem on the NumPy path
    with _generic():
        ref = fg.optimize(max_iter=30)
    assert res.iterations == ref.iterations
    assert res.final_cost == pytest.approx(ref.final_cost, rel=1e-10)
    x = fg.variables[0]
    np.testing.assert_allclose(res.values.params(x), ref.values.params(x), atol=1e-9)


def test_any_memory_layout(graph_mod):
    """States that are not C-contiguous rows (a user's view, a Fortran-ordered array) give the
    same numbers."""
    fg = _hard_graph(np.random.default_rng(5))
    p = Problem(fg.variables, fg.factors, "check")
    states = [v.initial for v in p.variables]
    odd = [np.asfortranarray(s) for s in states]
    assert not odd[0].flags.c_contiguous
    a, b = p.linearize(states), p.linearize(odd)
    np.testing.assert_array_equal(a.data, b.data)
    np.testing.assert_array_equal(p.plans[0].cost(states), p.plans[0].cost(odd))


def test_switched_off(graph_mod, monkeypatch):
    from microlie.optim.core import compiled

    monkeypatch.setenv("MICROLIE_FAST", "0")
    assert not compiled.available()
    fg = _hard_graph(np.random.default_rng(0))
    assert Problem(fg.variables, fg.factors, "check").plans == [None, None]
    monkeypatch.delenv("MICROLIE_FAST")
    assert compiled.available()


def test_bad_arguments(graph_mod):
    rng = np.random.default_rng(0)
    fg = _hard_graph(rng)
    p = Problem(fg.variables, fg.factors, "check")
    pl = p.plans[0]
    X = p.variables[0].initial
    s = np.empty(pl.ii.size)
    data, grad = np.zeros(p.nnz), np.zeros(p.size)
    args = [X, pl.ii, pl.jj, pl.Z, pl.L, None, pl.starts, pl.lens, pl.goff, s, data, grad]
    with pytest.raises(ValueError, match="X must be a C-contiguous float64"):
        graph_mod.se3_between_normal(X[:, :6].copy(), *args[1:])
    with pytest.raises(ValueError, match="Z must be"):
        graph_mod.se3_between_cost(X, pl.ii, pl.jj, pl.Z[:-1], pl.L, s)
    with pytest.raises(IndexError, match="variable index out of range"):
        graph_mod.se3_between_cost(X, pl.ii + X.shape[0], pl.jj, pl.Z, pl.L, s)
    bad = pl.starts.copy()
    bad[2, 3] = p.nnz
    with pytest.raises(IndexError, match="edge 2: pattern positions outside"):
        graph_mod.se3_between_normal(*args[:6], bad, *args[7:])
    with pytest.raises(TypeError, match="expected 12 arguments"):
        graph_mod.se3_between_normal(*args[:5])
    with pytest.raises(ValueError, match="X must be"):  # SE(3) parameters to the SE(2) loop
        graph_mod.se2_between_normal(*args)


