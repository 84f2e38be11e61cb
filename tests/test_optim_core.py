"""Core of microlie.optim: factor Jacobians, solvers, noise models, gauge errors, marginals."""

from __future__ import annotations

import numpy as np
import pytest

from microlie import SE2, SE3, SO2, SO3, Sim3
from microlie.optim import (
    BetweenFactor,
    Covariance,
    CustomFactor,
    Diagonal,
    FactorGraph,
    GaugeError,
    Huber,
    Information,
    Isotropic,
    PriorFactor,
    SqrtInformation,
    available_solvers,
    from_pose_graph,
)
from microlie.optim.core.problem import Problem

GROUPS = [SO2, SE2, SO3, SE3, Sim3]
RNG = np.random.default_rng(7)


def _spd(d, m=None, rng=RNG):
    A = rng.standard_normal((m or 1, d, d))
    S = A @ np.swapaxes(A, 1, 2) + d * np.eye(d)
    return S if m else S[0]


def _num_jac(f, var, states, k, h=1e-6):
    """d residual / d delta_k of element k by central differences in the tangent."""
    p = states[0]
    d = var.dof
    cols = []
    for a in range(d):
        dp = np.zeros((1, d))
        dp[0, a] = h
        plus = p.copy()
        minus = p.copy()
        plus[k] = var.retract(p[k:k + 1], dp)[0]
        minus[k] = var.retract(p[k:k + 1], -dp)[0]
        cols.append((f([plus]) - f([minus])) / (2 * h))
    return np.stack(cols, -1)


def _factor_jacobians(g, fac, var):
    prob = Problem(g.variables, g.factors, gauge="none")
    states = [v.initial for v in g.variables]
    vals = prob.gather(fac, states)
    r, Js = fac.evaluate(vals, True)

    def res(st):
        return np.asarray(fac.evaluate(prob.gather(fac, st), False))

    for k, (_, idx) in enumerate(fac.args):
        for e in range(fac.count):
            num = _num_jac(lambda st, e=e: res(st)[e], var, states, int(idx[e]))
            np.testing.assert_allclose(Js[k][e], num, atol=1e-6, rtol=1e-6)
    return r


@pytest.mark.parametrize("G", GROUPS + [None], ids=lambda g: g.__name__ if g else "vector")
def test_prior_and_between_jacobians_match_finite_differences(G):
    g = FactorGraph()
    if G is None:
        X = RNG.standard_normal((4, 3))
        Z = RNG.standard_normal((3, 3))
        Zp = RNG.standard_normal(3)
    else:
        X = G.random(4, rng=1)
        # include a relative rotation near pi between elements 0 and 1
        tau = np.zeros(G.dof)
        tau[-1 if G not in (Sim3,) else -2] = np.pi - 1e-4
        X = G(np.concatenate([X.params[:1], (X[0] @ G.exp(tau)).params[None], X.params[2:]]))
        Z = G.random(3, rng=2)
        Zp = G.random((), rng=3)
    var = g.add_variables(X)
    fb = g.add(BetweenFactor(var, [0, 1, 2], [1, 2, 3], Z, Information(_spd(var.dof, 3))))
    fp = g.add(PriorFactor(var, [0, 3], Zp, Isotropic(var.dof, 0.5)))
    _factor_jacobians(g, fb, var)
    _factor_jacobians(g, fp, var)


def test_between_residual_definition():
    g = FactorGraph()
    X = SE3.random(2, rng=4)
    Z = SE3.random((), rng=5)
    var = g.add_variables(X, fixed=[0])
    g.add(BetweenFactor(var, 0, 1, Z, Information(np.eye(6))))
    # independent: matrix logarithm of Z^-1 X_i^-1 X_j
    from scipy.linalg import logm

    M = np.linalg.inv(Z.matrix()) @ np.linalg.inv(X[0].matrix()) @ X[1].matrix()
    L = np.real(logm(M))
    r = np.r_[L[:3, 3], L[2, 1], L[0, 2], L[1, 0]]
    assert g.cost() == pytest.approx(0.5 * r @ r, rel=1e-10)


def _linear_problem(noise_kind="diag"):
    """Vector variables with linear factors: the optimum is a weighted linear least squares."""
    rng = np.random.default_rng(11)
    n, d = 6, 2
    g = FactorGraph()
    x = g.add_variables(rng.standard_normal((n, d)))
    i = np.array([0, 1, 2, 3, 4, 0, 2])
    j = np.array([1, 2, 3, 4, 5, 3, 5])
    z = rng.standard_normal((i.size, d))
    sig = rng.uniform(0.2, 2.0, (i.size, d))
    g.add(BetweenFactor(x, i, j, z, Diagonal(sig)))
    zp = rng.standard_normal(d)
    g.add(PriorFactor(x, 0, zp, Isotropic(d, 0.1)))
    # dense weighted least squares
    rows, rhs, w = [], [], []
    for e in range(i.size):
        for a in range(d):
            r = np.zeros(n * d)
            r[j[e] * d + a], r[i[e] * d + a] = 1.0, -1.0
            rows.append(r)
            rhs.append(z[e, a])
            w.append(1.0 / sig[e, a])
    for a in range(d):
        r = np.zeros(n * d)
        r[a] = 1.0
        rows.append(r)
        rhs.append(zp[a])
        w.append(10.0)
    A = np.array(rows) * np.array(w)[:, None]
    b = np.array(rhs) * np.array(w)
    xs = np.linalg.lstsq(A, b, rcond=None)[0].reshape(n, d)
    cost = 0.5 * float(np.sum((A @ xs.ravel() - b) ** 2))
    return g, x, xs, cost


@pytest.mark.parametrize("solver", ["lm", "gn", "dogleg"])
@pytest.mark.parametrize("ls", ["cholesky", "scipy", "dense"])
def test_linear_least_squares_closed_form(solver, ls):
    g, x, xs, cost = _linear_problem()
    r = g.optimize(solver=solver, linear_solver=ls, rel_tol=1e-12, abs_tol=1e-14)
    np.testing.assert_allclose(r.values[x], xs, atol=1e-7)
    assert r.final_cost == pytest.approx(cost, rel=1e-9)
    assert r.converged


def _se3_loop(noise=0.05, n=8, seed=3):
    rng = np.random.default_rng(seed)
    truth = SE3.exp(np.cumsum(rng.standard_normal((n, 6)) * 0.5, 0))
    i = np.r_[np.arange(n - 1), 0, 2]
    j = np.r_[np.arange(1, n), n - 1, n - 2]
    Z = truth[i].between(truth[j]).plus(noise * rng.standard_normal((i.size, 6)))
    X0 = truth.plus(0.3 * rng.standard_normal((n, 6)))
    g = FactorGraph()
    poses = g.add_variables(X0, fixed=[0], name="poses")
    g.add(BetweenFactor(poses, i, j, Z, Information(_spd(6, i.size, rng))))
    return g, poses, truth


def test_lm_gn_dogleg_reach_the_same_optimum():
    g, poses, _ = _se3_loop()
    res = {s: g.optimize(solver=s, rel_tol=1e-14, abs_tol=1e-14, max_iter=200)
           for s in ("lm", "gn", "dogleg")}
    ref = res["lm"]
    assert ref.final_cost < 0.1 * ref.initial_cost
    for s, r in res.items():
        assert r.final_cost == pytest.approx(ref.final_cost, rel=1e-9), s
        d = r.values[poses].minus(ref.values[poses])
        assert np.abs(d).max() < 1e-6, s


# every backend installed here (qdldl is in the test extra, so CI runs it; PARDISO only where
# microlie[mkl] is installed)
@pytest.mark.parametrize("ls", available_solvers())
def test_linear_solvers_agree(ls):
    g, poses, _ = _se3_loop(n=12)
    a = g.optimize(linear_solver="dense", rel_tol=1e-12)
    b = g.optimize(linear_solver=ls, rel_tol=1e-12)
    assert b.linear_solver == ls
    assert b.final_cost == pytest.approx(a.final_cost, rel=1e-10)


def test_never_worse_than_start_and_history():
    g, poses, _ = _se3_loop()
    r = g.optimize(rel_tol=1e-14, abs_tol=0, max_iter=100)
    g.set_values(r.values)
    for s in ("lm", "gn", "dogleg"):
        again = g.optimize(solver=s, max_iter=5)
        assert again.final_robust_cost <= again.initial_robust_cost
    costs = [h.cost for h in r.history]
    assert all(b <= a for a, b in zip(costs, costs[1:], strict=False))
    assert r.history[0].cost <= r.initial_cost
    assert r.iterations == len([h for h in r.history if h.step_norm > 0])


def test_gauss_newton_divergent_step_keeps_the_start():
    # a 1-D problem whose Gauss-Newton step overshoots: r = atan(x) - 0 from x = 3
    g = FactorGraph()
    x = g.add_variables(np.array([[3.0]]))

    def f(v):
        return np.arctan(v)

    def fj(v):
        return np.arctan(v), [1.0 / (1.0 + v[:, :, None] ** 2)]

    g.add(CustomFactor(fj, [(x, 0)], 1, jac="analytic"))
    r = g.optimize(solver="gn")
    assert r.final_cost <= r.initial_cost
    assert not r.converged and "did not decrease" in r.message
    assert f(np.array(3.0)) is not None


def test_gauge_freedom_is_reported():
    rng = np.random.default_rng(0)
    g = FactorGraph()
    poses = g.add_variables(SE2.random(5, rng=rng), name="poses")
    g.add(BetweenFactor(poses, [0, 1, 3], [1, 2, 4], SE2.random(3, rng=rng), Isotropic(3, 1)))
    with pytest.raises(GaugeError, match=r"gauge freedom: 5 variables .*2 connected comp"):
        g.optimize()
    g.add(PriorFactor(poses, 0, SE2.identity(), Isotropic(3, 1)))
    with pytest.raises(GaugeError, match=r"gauge freedom: 2 variables .*poses\[3\]"):
        g.optimize()
    r = g.optimize(gauge="fix_first")
    assert [(v.name, i) for v, i in r.gauge_fixed] == [("poses", 3)]
    assert r.final_cost < 1e-12
    np.testing.assert_allclose(r.values[poses][3].params, poses.initial[3])
    with pytest.raises(ValueError, match="gauge must be"):
        g.optimize(gauge="bogus")


def test_gauss_newton_rank_deficiency_is_an_error_not_nan():
    # the graph is anchored but a variable is unobservable (custom factor on x only)
    g = FactorGraph()
    v = g.add_variables(np.zeros((1, 2)))
    g.add(CustomFactor(lambda a: a[:, :1] - 1.0, [(v, 0)], 1))
    with pytest.raises(ValueError, match="rank deficient|singular|positive definite"):
        g.optimize(solver="gn", linear_solver="dense")
    r = g.optimize(solver="lm")  # damped: fine
    assert r.final_cost < 1e-12


def test_noise_models_give_identical_steps():
    rng = np.random.default_rng(5)
    S = _spd(6, 9, rng)
    Om = np.linalg.inv(S)
    U = np.linalg.cholesky(Om)  # Om = U U^T -> sqrt info = U^T
    models = [Covariance(S), Information(Om), SqrtInformation(np.swapaxes(U, 1, 2))]
    out = []
    for nm in models:
        g, poses, _ = _se3_loop()
        g.factors[0].noise = nm  # same graph, the noise model swapped
        g._changed()
        out.append(g.optimize(solver="gn", max_iter=1).values[poses].params)
    for o in out[1:]:
        np.testing.assert_allclose(o, out[0], atol=1e-12)
    sig = rng.uniform(0.1, 1.0, 6)
    np.testing.assert_allclose(Diagonal(sig).information, np.diag(sig ** -2))
    np.testing.assert_allclose(Isotropic(6, 0.5).information, 4 * np.eye(6))
    np.testing.assert_allclose(Covariance(S[0]).information, Om[0], rtol=1e-10)


def test_non_positive_information_is_a_value_error():
    info = np.tile(np.eye(3), (4, 1, 1))
    info[2, 1, 1] = -1.0
    with pytest.raises(ValueError, match=r"not positive definite \(factor 2\)"):
        Information(info)
    with pytest.raises(ValueError, match="not symmetric"):
        Information(np.array([[1.0, 0.5], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="sigmas must be positive"):
        Diagonal([1.0, 0.0])
    g = FactorGraph()
    x = g.add_variables(SE2.identity(2))
    with pytest.raises(ValueError, match="dimension 2 for a residual of dimension 3"):
        BetweenFactor(x, 0, 1, SE2.identity(), Isotropic(2, 1.0))
    with pytest.raises(ValueError, match="i == j"):
        BetweenFactor(x, [0, 1], [1, 1], SE2.identity(2))
    with pytest.raises(ValueError, match="out of range"):
        PriorFactor(x, 2, SE2.identity())


def test_custom_factors_analytic_numerical_jax_torch_agree():
    from conftest import require

    jax = require("jax")
    jax.config.update("jax_enable_x64", True)
    rng = np.random.default_rng(2)
    n = 6
    truth = SE2.exp(np.c_[np.cumsum(rng.uniform(0.5, 1, n)), rng.normal(0, .2, n),
                          rng.normal(0, .3, n)])
    gps = truth.translation() + 0.05 * rng.standard_normal((n, 2))

    def build(jac):
        g = FactorGraph()
        x = g.add_variables(SE2.identity(n))
        ii = np.arange(n - 1)
        g.add(BetweenFactor(x, ii, ii + 1, truth[ii].between(truth[ii + 1]),
                            Diagonal([0.1, 0.1, 0.05])))
        if jac == "analytic":
            def fn(X, z):
                t, Jt, _ = X.act(np.zeros(2), jac=True)
                return t - z, [Jt]
        else:
            def fn(X, z):
                return X.act(np.zeros(2) if jac == "numerical" else jax.numpy.zeros(2)) - z
        g.add(CustomFactor(fn, [(x, np.arange(n))], 2, Isotropic(2, 0.05), data=[gps],
                           jac=jac))
        return g, x

    torch = require("torch")

    def build_torch():
        g, x = build("numerical")
        f = g.factors[-1]
        f.mode = "torch"
        f.fn = lambda X, z: X.act(torch.zeros(2, dtype=torch.float64)) - z
        return g, x

    sols = {}
    for jac in ("analytic", "numerical", "jax", "torch"):
        g, x = build_torch() if jac == "torch" else build(jac)
        r = g.optimize(rel_tol=1e-12, abs_tol=1e-14)
        assert r.converged
        sols[jac] = r.values[x]
    for jac in ("numerical", "jax", "torch"):
        assert np.abs(sols[jac].minus(sols["analytic"])).max() < 1e-7, jac


def test_robust_derivatives_and_outlier_downweighting():
    from microlie.optim import DCS, Barron, Cauchy, GemanMcClure, Tukey

    s = np.array([0.01, 0.3, 0.9, 1.7, 4.0, 25.0])
    for L in (Huber(1.3), Cauchy(0.7), Tukey(2.1), GemanMcClure(1.1), DCS(1.5),
              Barron(1.2, 1.0), Barron(0.8, -3.0)):
        rho, r1, r2 = L.evaluate(s)
        h = 1e-6
        d1 = (L.rho(s + h) - L.rho(s - h)) / (2 * h)
        d2 = (L.evaluate(s + h)[1] - L.evaluate(s - h)[1]) / (2 * h)
        np.testing.assert_allclose(r1, d1, rtol=1e-6, atol=1e-9, err_msg=repr(L))
        np.testing.assert_allclose(r2, d2, rtol=1e-5, atol=1e-8, err_msg=repr(L))
        rho0, r10, _ = L.evaluate(np.array([1e-12]))
        assert r10[0] == pytest.approx(1.0, abs=1e-9) and rho0[0] == pytest.approx(1e-12)
    # a robust mean of scalars with one gross outlier
    data = np.r_[RNG.normal(1.0, 0.1, 20), 50.0]
    for loss, close in ((None, False), (Huber(1.0), True), (Cauchy(1.0), True)):
        g = FactorGraph()
        x = g.add_variables(np.zeros((1, 1)))
        g.add(PriorFactor(x, np.zeros(data.size, int), data[:, None], Isotropic(1, 0.1),
                          loss=loss))
        r = g.optimize(rel_tol=1e-12)
        est = float(r.values[x][0, 0])
        assert (abs(est - np.mean(data[:-1])) < 0.05) == close, (loss, est)
        if loss is not None:
            assert r.final_robust_cost < r.final_cost


def test_marginals_match_the_dense_inverse():
    g, poses, _ = _se3_loop(n=6)
    r = g.optimize(rel_tol=1e-12)
    prob = g.problem()
    states = [np.asarray(r.values.params(poses))]
    lin = prob.linearize(states)
    Hinv = np.linalg.inv(prob.matrix(lin.data).toarray())
    m = g.marginals(r.values, poses, [1, 4])
    assert m.frame == "right"
    np.testing.assert_allclose(m.cov[0], Hinv[0:6, 0:6], rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(m.cov[1], Hinv[18:24, 18:24], rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(m.mean.params, r.values[poses][[1, 4]].params)
    J = g.marginal_covariance(r.values, [(poses, 1), (poses, 4)])
    np.testing.assert_allclose(J[:6, 6:], Hinv[0:6, 18:24], rtol=1e-10, atol=1e-14)
    with pytest.raises(ValueError, match="is fixed"):
        g.marginals(r.values, poses, [0])


@pytest.mark.parametrize("name, init, expected", [
    ("sphere2500.g2o", "file", 675.7009629),
    ("tinyGrid3D.g2o", "file", 9.313909434),
    ("input_M3500_g2o.g2o", "file", 68.95743912),
    ("gtsam/pose2example.txt", "file", 0.5494864475),
])
def test_shared_graphs_reach_gtsam_cost(name, init, expected):
    from conftest import data_file

    from microlie.optim.init import initialize
    from microlie.optim.io.g2o import read_g2o

    pg = read_g2o(data_file("pose_graph/" + name))
    g, poses = from_pose_graph(pg, initialize(pg, init))
    r = g.optimize()
    assert r.converged
    assert r.final_cost == pytest.approx(expected, rel=1e-6)
    assert pg.cost(r.values[poses]) == pytest.approx(r.final_cost, rel=1e-12)


@pytest.mark.parametrize("bs, nb", [(6, 40), (3, 120), (2, 7), (1, 50)])
def test_supernodal_cholesky_matches_dense(bs, nb):
    """Random block-sparse SPD matrices (a chain, random long edges and a dense corner) against
    NumPy's dense solve; a matrix made indefinite is a SingularSystemError."""
    import scipy.sparse as sp

    from microlie.optim.linalg.cholesky import SupernodalSolver
    from microlie.optim.linalg.linear import SingularSystemError

    rng = np.random.default_rng(bs * 100 + nb)
    pairs = {(k, k + 1) for k in range(nb - 1)}
    pairs |= {tuple(sorted(rng.choice(nb, 2, replace=False))) for _ in range(nb // 2)}
    pairs |= {(a, b) for a in range(nb - 4, nb) for b in range(a + 1, nb)}
    n = nb * bs
    M = np.zeros((n, n))
    for a, b in pairs:
        J = rng.standard_normal((bs + 1, 2 * bs))
        blk = J.T @ J
        idx = np.r_[a * bs:(a + 1) * bs, b * bs:(b + 1) * bs]
        M[np.ix_(idx, idx)] += blk
    M += 1e-3 * np.eye(n)
    H = sp.csc_matrix(M)
    H.sort_indices()
    s = SupernodalSolver()
    s.analyse(H.indptr, H.indices, n, bs)
    s.factorize(H.data)
    b = rng.standard_normal(n)
    np.testing.assert_allclose(s.solve(b), np.linalg.solve(M, b), rtol=1e-8, atol=1e-10)
    B = rng.standard_normal((n, 3))
    np.testing.assert_allclose(s.solve(B), np.linalg.solve(M, B), rtol=1e-8, atol=1e-10)
    bad = H.copy()
    bad.data[bad.indices == np.repeat(np.arange(n), np.diff(bad.indptr))] *= -1.0
    with pytest.raises(SingularSystemError, match="not positive definite"):
        s.factorize(bad.data)
