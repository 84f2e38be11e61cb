"""Vector variables are ``R(d)`` variables (arrays in, arrays out) and per-component fixing
(``FactorGraph.fix(variables, idx, components)``), against independent computations:
``scipy.optimize.least_squares`` on the same problems written by hand (over the free components
only), central differences, dense inverses."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from conftest import _jax
from scipy.optimize import least_squares

from microlie import SE3, R
from microlie.optim import (
    BetweenFactor,
    CustomFactor,
    FactorGraph,
    GaugeError,
    Isotropic,
    PriorFactor,
    check_jacobians,
)
from microlie.optim.core.variables import VectorVariables
from microlie.optim.linalg.linear import available_solvers

JAC_MODES = ["numerical", "analytic"] + [m for m in ("jax", "torch")
                                         if importlib.util.find_spec(m) is not None]
SIG_F, SIG_P, SIG_B = 0.1, 0.5, 0.3


def _cubic(x, y, z):
    """``r = x^3 + x y - z`` elementwise: any backend, whole batches or single rows."""
    return x ** 3 + x * y - z


def _cubic_analytic(x, y, z):
    r = _cubic(x, y, z)
    m, d = x.shape
    Jx, Jy = np.zeros((m, d, d)), np.zeros((m, d, d))
    k = np.arange(d)
    Jx[:, k, k] = 3 * x ** 2 + y
    Jy[:, k, k] = x
    return r, [Jx, Jy]


def _vector_problem(seed: int = 0):
    rng = np.random.default_rng(seed)
    n, d = 4, 2
    x0 = 1.0 + 0.3 * rng.standard_normal((n, d))
    y0 = 0.5 + 0.3 * rng.standard_normal((n, d))
    z = rng.uniform(1.0, 3.0, (n, d))
    yp = 0.5 + 0.1 * rng.standard_normal((n, d))
    b = 0.2 * rng.standard_normal((n - 1, d))
    return x0, y0, z, yp, b


def _build_vector_graph(mode: str, as_batch: bool = False, seed: int = 0):
    if mode == "jax":
        _jax()  # jac="jax" needs float64 JAX (x64 on, for this test only)
    x0, y0, z, yp, b = _vector_problem(seed)
    n = len(x0)
    g = FactorGraph()
    seen: list[type] = []
    if as_batch:
        x, y = g.add_variables(R(2)(x0), name="x"), g.add_variables(R(2)(y0), name="y")
    else:
        x, y = g.add_variables(x0, name="x"), g.add_variables(y0, name="y")

    def fn(xv, yv, zv):
        seen.append(type(xv))
        return _cubic(xv, yv, zv)

    def fa(xv, yv, zv):
        seen.append(type(xv))
        return _cubic_analytic(xv, yv, zv)

    ix = np.arange(n)
    g.add(CustomFactor(fa if mode == "analytic" else fn, [(x, ix), (y, ix)], 2,
                       Isotropic(2, SIG_F), data=[z], jac=mode))
    g.add(PriorFactor(y, ix, yp, Isotropic(2, SIG_P)))
    g.add(BetweenFactor(x, ix[:-1], ix[1:], b, Isotropic(2, SIG_B)))
    return g, x, y, seen


def _vector_residuals(v, held_x=None, x_init=None):
    """The whitened residuals of ``_build_vector_graph`` by hand; ``v`` holds the free
    coordinates of ``x`` (the held ones stay at ``x_init``), then ``y``."""
    x0, y0, z, yp, b = _vector_problem()
    n, d = x0.shape
    if held_x is None:
        x, y = v[:n * d].reshape(n, d), v[n * d:].reshape(n, d)
    else:
        x = x_init.copy()
        free = ~held_x
        k = int(free.sum())
        x[free] = v[:k]
        y = v[k:].reshape(n, d)
    return np.concatenate([(_cubic(x, y, z) / SIG_F).ravel(), ((y - yp) / SIG_P).ravel(),
                           ((x[1:] - x[:-1] - b) / SIG_B).ravel()])


@pytest.mark.parametrize("mode", JAC_MODES)
def test_vector_variables_solve_as_scipy_in_every_jacobian_mode(mode):
    """Vector variables through CustomFactor (each jac mode), PriorFactor and BetweenFactor:
    the optimum is scipy's on the same cost written by hand; residual functions receive
    arrays and ``result.values[x]`` is an ``(n, d)`` array."""
    g, x, y, seen = _build_vector_graph(mode)
    assert x.group is R(2) and isinstance(x, VectorVariables)
    res = g.optimize(rel_tol=1e-14, abs_tol=1e-16, max_iter=200)
    x0, y0 = _vector_problem()[:2]
    ref = least_squares(_vector_residuals, np.concatenate([x0.ravel(), y0.ravel()]),
                        method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert abs(res.final_cost - 0.5 * ref.fun @ ref.fun) <= 1e-9 * ref.cost
    X, Y = res.values[x], res.values[y]
    assert type(X) is np.ndarray and X.shape == (4, 2) and X.dtype == np.float64
    np.testing.assert_allclose(np.concatenate([X.ravel(), Y.ravel()]), ref.x, atol=1e-7)
    if mode in ("numerical", "analytic"):  # jax/torch see their own arrays
        assert seen and all(t is np.ndarray for t in seen)
    # the Jacobians of the three factor batches against central differences
    for f in g.factors:
        assert check_jacobians(f, res.values).ok


def test_R_batch_and_array_give_the_same_handle_and_values():
    """``add_variables(R(d) batch)`` is ``add_variables(array)``: group ``R(d)``, arrays in
    residual functions and in ``values``, the same solve to the last bit."""
    ga, xa, ya, seen_a = _build_vector_graph("analytic")
    gb, xb, yb, seen_b = _build_vector_graph("analytic", as_batch=True)
    assert xa.group is xb.group is R(2) and type(xa) is type(xb) is VectorVariables
    assert repr(xb) == "Variables('x', R2, n=4, fixed=0)"
    ra, rb = ga.optimize(), gb.optimize()
    assert type(rb.values[xb]) is np.ndarray
    np.testing.assert_array_equal(ra.values[xa], rb.values[xb])
    assert ra.final_cost == rb.final_cost
    assert all(t is np.ndarray for t in seen_b)
    assert [type(v) for _, v in gb.initial_values().items()] == [np.ndarray, np.ndarray]
    # measurements of vector priors: an array or an R(d) element, the same factor
    p1 = PriorFactor(xb, [0, 1], np.array([1.0, 2.0]))
    p2 = PriorFactor(xb, [0, 1], R(2)(np.array([1.0, 2.0])))
    assert type(p1.Z) is type(p2.Z) is np.ndarray
    np.testing.assert_array_equal(p1.Z, p2.Z)
    # check_jacobians takes an R(d) batch for a vector argument (given to the factor as array)
    f = ga.factors[0]
    vals = [R(2)(xa.initial), ya.initial]
    assert check_jacobians(f, vals).ok


def test_vector_marginals_are_the_dense_inverse():
    """Marginals of vector variables: a VectorGaussian whose covariance is the block of
    ``(J^T J)^-1``, ``J`` by central differences of the hand-written residuals."""
    g, x, y, _ = _build_vector_graph("analytic")
    res = g.optimize(rel_tol=1e-14, abs_tol=1e-16)
    v = np.concatenate([res.values[x].ravel(), res.values[y].ravel()])
    h = 1e-6
    J = np.stack([(_vector_residuals(v + h * e) - _vector_residuals(v - h * e)) / (2 * h)
                  for e in np.eye(v.size)], axis=1)
    C = np.linalg.inv(J.T @ J)
    m = g.marginals(res.values, y)
    assert type(m).__name__ == "VectorGaussian"
    np.testing.assert_allclose(m.mean, res.values[y])
    for i in range(4):
        blk = C[8 + 2 * i:10 + 2 * i, 8 + 2 * i:10 + 2 * i]
        np.testing.assert_allclose(m.cov[i], blk, rtol=1e-6, atol=1e-12)


def test_float32_vectors_checked_in_float32():
    g, x, y, _ = _build_vector_graph("analytic")
    f = g.factors[0]
    c = check_jacobians(f, [x.initial.astype(np.float32), y.initial.astype(np.float32)])
    assert c.ok and c.tol == 1e-2 and c.numerical[0].dtype == np.float64


# ------------------------------------------------------------------ per-component fixing
HELD_X = np.array([[False, True], [False, False], [True, False], [False, True]])


def _hold_x(g, x):
    g.fix(x, [0, 3], components=[1])
    g.fix(x, 2, components=0)


def test_held_vector_components_match_scipy_over_free_components():
    """``fix(x, idx, components)`` on vectors: the optimum is scipy's over the free
    coordinates only, with the held ones at their start."""
    g, x, y, _ = _build_vector_graph("analytic")
    _hold_x(g, x)
    assert (x.held == HELD_X).all() and g.problem().size == 16
    res = g.optimize(rel_tol=1e-14, abs_tol=1e-16, max_iter=200)
    x0, y0 = _vector_problem()[:2]
    ref = least_squares(_vector_residuals, np.concatenate([x0[~HELD_X], y0.ravel()]),
                        method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                        args=(HELD_X, x0))
    assert abs(res.final_cost - ref.cost) <= 1e-9 * ref.cost
    X = res.values[x]
    np.testing.assert_array_equal(X[HELD_X], x0[HELD_X])
    np.testing.assert_allclose(X[~HELD_X], ref.x[:5], atol=1e-7)
    np.testing.assert_allclose(res.values[y].ravel(), ref.x[5:], atol=1e-7)
    # marginals: zero variance in held components, (J_free^T J_free)^-1 elsewhere
    v = np.concatenate([X[~HELD_X], res.values[y].ravel()])
    h = 1e-6
    J = np.stack([(_vector_residuals(v + h * e, HELD_X, x0)
                   - _vector_residuals(v - h * e, HELD_X, x0)) / (2 * h)
                  for e in np.eye(v.size)], axis=1)
    C = np.linalg.inv(J.T @ J)
    S = g.marginal_covariance(res.values, [(x, 0), (x, 1), (x, 2), (x, 3)])
    held = HELD_X.ravel()
    assert (S[held] == 0).all() and (S[:, held] == 0).all()
    np.testing.assert_allclose(S[np.ix_(~held, ~held)], C[:5, :5], rtol=1e-6, atol=1e-12)
    m = g.marginals(res.values, x)
    np.testing.assert_array_equal(m.cov.reshape(4, 2, 2)[HELD_X], 0.0)
    # releasing them frees the whole problem again (scipy's full optimum)
    x.unfix(components=[0, 1])
    assert not x.held.any() and g.problem().size == 16
    assert abs(g.optimize(rel_tol=1e-14, abs_tol=1e-16).final_cost
               - least_squares(_vector_residuals, np.concatenate([x0.ravel(), y0.ravel()]),
                               method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).cost) < 1e-9


def _pose_problem(seed: int = 3):
    rng = np.random.default_rng(seed)
    truth = SE3.exp(np.concatenate([rng.uniform(-2, 2, (3, 3)), rng.uniform(-1, 1, (3, 3))], 1))
    noise = lambda k, s: SE3.exp(s * rng.standard_normal((k, 6)))  # noqa: E731
    init = truth.compose(noise(3, 0.3))
    ii, jj = np.array([0, 1, 0]), np.array([1, 2, 2])
    Z = truth[ii].inverse().compose(truth[jj]).compose(noise(3, 0.05))
    prior = truth[0].compose(noise(1, 0.05)[0])
    land0 = rng.standard_normal((2, 3)) + 1.0
    obs = np.asarray(truth.translation())[[1, 2]] - np.array([[0.3, 0.1, 0.2], [0.1, 0.2, 0.3]])
    return init, ii, jj, Z, prior, land0, obs


def _build_pose_graph(seed: int = 3):
    init, ii, jj, Z, prior, land0, obs = _pose_problem(seed)
    g = FactorGraph()
    T = g.add_variables(init, name="T")
    L = g.add_variables(land0, name="L")
    g.add(PriorFactor(T, 0, prior, Isotropic(6, 0.1)))
    g.add(BetweenFactor(T, ii, jj, Z, Isotropic(6, 0.2)))
    g.add(CustomFactor(lambda X, lm, o: X.translation() - lm - o, [(T, [1, 2]), (L, [0, 1])],
                       3, Isotropic(3, 0.1), data=[obs], jac="numerical"))
    g.add(PriorFactor(L, [0, 1], np.zeros(3), Isotropic(3, 10.0)))
    # pose 1: rotation held; pose 2: translation held; landmark 1: its z held
    g.fix(T, 1, components=[3, 4, 5])
    g.fix(T, 2, components=[0, 1, 2])
    g.fix(L, 1, components=2)
    return g, T, L


def _pose_residuals(v):
    """The whitened residuals of ``_build_pose_graph`` over the free coordinates: pose 0 in
    the chart ``X0 Exp(d)``, pose 1's translation (rotation at its start), pose 2's rotation
    in the chart ``R2 Exp(phi)`` (translation at its start), landmark 0, landmark 1's x, y."""
    init, ii, jj, Z, prior, land0, obs = _pose_problem()
    P = np.asarray(init.params)
    X0 = init[0].plus(v[0:6])
    R1 = P[1, 3:]
    X1 = SE3(np.concatenate([v[6:9], R1]))
    X2 = SE3(np.concatenate([P[2, :3], np.asarray(init[2].plus(
        np.concatenate([np.zeros(3), v[9:12]])).params)[3:]]))
    Ls = np.array([v[12:15], [v[15], v[16], land0[1, 2]]])
    Xs = SE3.stack([X0, X1, X2])
    r_prior = prior.inverse().compose(X0).log() / 0.1
    r_between = (Xs[ii].compose(Z)).inverse().compose(Xs[jj]).log() / 0.2
    r_obs = (np.asarray(Xs[[1, 2]].translation()) - Ls - obs) / 0.1
    r_land = Ls / 10.0
    return np.concatenate([np.ravel(r_prior), np.ravel(r_between), r_obs.ravel(), r_land.ravel()])


def test_held_pose_components_match_scipy_over_free_components():
    """An SE3 pose with its rotation held, one with its translation held, a landmark with one
    coordinate held: the optimum is scipy's over the free coordinates only."""
    g, T, L = _build_pose_graph()
    res = g.optimize(rel_tol=1e-14, abs_tol=1e-16, max_iter=200)
    init = _pose_problem()[0]
    P0 = np.asarray(init.params)
    v0 = np.concatenate([np.zeros(6), P0[1, :3], np.zeros(3), _pose_problem()[5][0],
                         _pose_problem()[5][1, :2]])
    ref = least_squares(_pose_residuals, v0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    assert abs(res.final_cost - ref.cost) <= 1e-8 * ref.cost
    P = np.asarray(res.values[T].params)
    np.testing.assert_array_equal(P[1, 3:], P0[1, 3:])  # rotation of pose 1: exactly
    np.testing.assert_array_equal(P[2, :3], P0[2, :3])  # translation of pose 2: exactly
    np.testing.assert_allclose(P[1, :3], ref.x[6:9], atol=1e-6)
    X0 = init[0].plus(ref.x[:6])
    np.testing.assert_allclose(res.values[T][0].matrix(), X0.matrix(), atol=1e-6)
    Lr = res.values[L]
    assert Lr[1, 2] == _pose_problem()[5][1, 2]
    np.testing.assert_allclose(Lr[0], ref.x[12:15], atol=1e-6)
    # the rotation-held pose's marginal: zero rotation (co)variance, a PSD Gaussian
    m = g.marginals(res.values, T, [1, 2])
    np.testing.assert_array_equal(m.cov[0, 3:], 0.0)
    np.testing.assert_array_equal(m.cov[1, :3], 0.0)
    assert np.linalg.eigvalsh(m.cov[0, :3, :3]).min() > 0


SOLVERS = ["lm", "gn", "dogleg"]


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("linear_solver", available_solvers())
def test_held_components_never_move(solver, linear_solver):
    """Held coordinates are exactly their start under every strategy and linear solver, and
    every one reaches the same optimum."""
    g, T, L = _build_pose_graph()
    P0 = np.asarray(T.initial).copy()
    L0 = L.initial.copy()
    res = g.optimize(solver=solver, linear_solver=linear_solver, rel_tol=1e-12,
                     abs_tol=1e-14, max_iter=100)
    P = np.asarray(res.values[T].params)
    np.testing.assert_array_equal(P[1, 3:], P0[1, 3:])
    np.testing.assert_array_equal(P[2, :3], P0[2, :3])
    assert res.values[L][1, 2] == L0[1, 2]
    assert np.abs(P[1, :3] - P0[1, :3]).max() > 1e-3  # the free parts moved
    ref = g.optimize(linear_solver="dense", rel_tol=1e-14, abs_tol=1e-16)
    assert abs(res.final_cost - ref.final_cost) <= 1e-6 * ref.final_cost


@pytest.mark.parametrize("solver, linear_solver", [("trust-region", "auto"), ("lm", "schur")])
def test_held_components_never_move_in_the_engine_s_other_options(solver, linear_solver):
    """The same under the Ceres-rules strategy and the Schur linear solver (the landmarks
    eliminated), when the engine has them (issue 20 adds both beside this change)."""
    g, T, L = _build_pose_graph()
    P0 = np.asarray(T.initial).copy()
    try:
        res = g.optimize(solver=solver, linear_solver=linear_solver, max_iter=100)
    except ValueError as e:
        if f"{solver!r}" in str(e) or f"{linear_solver!r}" in str(e):
            pytest.skip(f"this engine has no solver={solver!r} / linear_solver="
                        f"{linear_solver!r}: {e}")
        raise
    P = np.asarray(res.values[T].params)
    np.testing.assert_array_equal(P[1, 3:], P0[1, 3:])
    np.testing.assert_array_equal(P[2, :3], P0[2, :3])
    assert res.values[L][1, 2] == L.initial[1, 2]
    ref = g.optimize(linear_solver="dense", rel_tol=1e-14, abs_tol=1e-16)
    assert abs(res.final_cost - ref.final_cost) <= 1e-6 * ref.final_cost


def test_gauge_partial_hold_is_not_an_anchor():
    """A pose with some components held does not anchor the gauge; all of them held is a
    fixed pose (no unknowns)."""
    g = FactorGraph()
    T = g.add_variables(SE3.random(3, rng=1), name="T")
    g.add(BetweenFactor(T, [0, 1], [1, 2], SE3.random(2, rng=2)))
    g.fix(T, 0, components=[0, 1, 2, 3, 4])
    with pytest.raises(GaugeError, match=r"T\[0\]"):
        g.optimize()
    g.fix(T, 0, components=5)
    assert g.problem().size == 12 and g.problem().held.size == 0
    res = g.optimize()
    np.testing.assert_array_equal(np.asarray(res.values[T].params)[0],
                                  np.asarray(T.initial)[0])
    assert res.final_cost < 1e-20
    with pytest.raises(ValueError, match=r"T\[0\] is fixed"):
        g.marginals(res.values, T, 0)


@pytest.mark.parametrize("components, message", [
    ([3], r"K: components: 3 out of range \(a R3 variable has tangent coordinates 0 to 2\)"),
    ([-1], r"K: components: -1 out of range"),
    ([1, 1], r"K: components: 1 given twice"),
    ([0.5], r"K: components must be an int or a 1-D sequence of ints"),
    ([[0, 1]], r"K: components must be an int or a 1-D sequence of ints"),
    ([True], r"K: components must be an int or a 1-D sequence of ints"),
])
def test_bad_components_are_value_errors(components, message):
    g = FactorGraph()
    K = g.add_variables(np.ones((2, 3)), name="K")
    with pytest.raises(ValueError, match=message):
        g.fix(K, components=components)
    with pytest.raises(ValueError, match=message):
        K.unfix(0, components=components)
    with pytest.raises(ValueError, match="K: index 2 out of range"):
        g.fix(K, 2, components=[0])
    assert not K.held.any()


@pytest.mark.parametrize("values, message", [
    (np.zeros(3), r"v: vector variables must be an \(n, d\) array with d >= 1"),
    (np.zeros((2, 0)), r"v: vector variables must be an \(n, d\) array with d >= 1"),
    (np.array([[1.0, np.nan]]), r"v: initial values have non-finite entries"),
    (R(2)(np.zeros((2, 2, 2))), r"v: variables must be a 1-D batch"),
])
def test_bad_vector_variables(values, message):
    with pytest.raises(ValueError, match=message):
        FactorGraph().add_variables(values, name="v")


def test_imu_factors_take_R6_bias_variables():
    from microlie import SE23
    from microlie.imu import BiasRandomWalkFactor

    g = FactorGraph()
    b = g.add_variables(R(6)(np.zeros((2, 6))))
    f = BiasRandomWalkFactor(b, [0], [1], gyro_walk=0.01, accel_walk=0.1, dt=1.0)
    assert check_jacobians(f).ok
    with pytest.raises(TypeError, match="biases must be an"):
        BiasRandomWalkFactor(g.add_variables(np.zeros((2, 3))), [0], [1], 0.01, 0.1, 1.0)
    with pytest.raises(TypeError, match="biases must be an"):
        BiasRandomWalkFactor(g.add_variables(SE23.identity(2)), [0], [1], 0.01, 0.1, 1.0)


def test_docs_section_prints_what_the_page_shows(capsys):
    """The section "Vector variables and held components" of docs/optim.md runs on its own."""
    import re
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / "docs" / "optim.md").read_text()
    sec = page[page.index("## Vector variables and held components"):]
    sec = sec[:sec.index("\n## ")]
    (kind, code), (kind2, text) = re.findall(r"```(python|text)\n(.*?)```", sec, flags=re.S)
    assert (kind, kind2) == ("python", "text")
    exec(compile(code, "docs/optim.md", "exec"), {})
    assert capsys.readouterr().out == text
