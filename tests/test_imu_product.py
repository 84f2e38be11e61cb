"""Composite states: R(n) and Product(...) against independent references (the matrix
exponential of the block-diagonal algebra, finite differences, the factors' own operations),
on every backend, as a Gaussian mean and as a solver variable."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import fd_jacobian, to_backend, to_numpy
from scipy.linalg import expm

from microlie import SE3, SE23, SO3, Gaussian, Product, R, Sim3
from microlie.groups import ProductGroup

STATE = Product(SE23, R(3), R(3))
PRODUCTS = [STATE, Product(SO3, R(2)), Product(Sim3, SE3), R(4)]
ids = [G.__name__ for G in PRODUCTS]


def _tau(G, rng, size=None, scale=0.8):
    return scale * rng.standard_normal((G.dof,) if size is None else (size, G.dof))


def test_classes_are_cached_and_sized():
    assert Product(SE23, R(3), R(3)) is STATE and R(3) is R(3)
    assert (STATE.dof, STATE.param_dim, STATE.matrix_dim) == (15, 16, 13)
    with pytest.raises(ValueError, match="positive integer"):
        R(0)
    with pytest.raises(TypeError, match="LieGroup classes"):
        Product(SE23, 3)
    with pytest.raises(ValueError, match="at least one"):
        Product()


@pytest.mark.parametrize("G", PRODUCTS, ids=ids)
def test_axioms_exp_log_and_adjoint(G):
    rng = np.random.default_rng(0)
    for _ in range(5):
        t = _tau(G, rng)
        X, Y = G.exp(t), G.exp(_tau(G, rng))
        np.testing.assert_allclose(X.matrix(), expm(G.hat(t)), atol=1e-12)
        np.testing.assert_allclose(X.log(), t, atol=1e-12)
        np.testing.assert_allclose((X @ Y).matrix(), X.matrix() @ Y.matrix(), atol=1e-12)
        np.testing.assert_allclose(X.inverse().matrix(), np.linalg.inv(X.matrix()), atol=1e-12)
        u = 0.3 * _tau(G, rng)
        np.testing.assert_allclose((X @ G.exp(u)).matrix(), (G.exp(X.adjoint() @ u) @ X).matrix(),
                                   atol=1e-12)
        np.testing.assert_allclose(G.jr(t), G._jr_series(t), atol=1e-12)
        a, b = _tau(G, rng), _tau(G, rng)
        np.testing.assert_allclose(G.ad(a) @ b, G.bracket(a, b), atol=1e-12)


def test_parts_follow_the_factors():
    rng = np.random.default_rng(1)
    X = SE23.random(5, rng=rng)
    bg, ba = R(3)(rng.standard_normal((5, 3))), R(3)(rng.standard_normal((5, 3)))
    S = STATE.from_parts(X, bg, ba)
    d = rng.standard_normal((5, 15))
    Sp = S.plus(d)
    np.testing.assert_allclose(Sp.part(0).matrix(), X.plus(d[:, :9]).matrix(), atol=1e-13)
    np.testing.assert_allclose(Sp.part(1).params, bg.params + d[:, 9:12], atol=1e-15)
    np.testing.assert_allclose(Sp.part(2).params, ba.params + d[:, 12:], atol=1e-15)
    np.testing.assert_allclose(Sp.minus(S), d, atol=1e-12)
    with pytest.raises(TypeError, match="part 1"):
        STATE.from_parts(X, X, ba)
    with pytest.raises(ValueError, match="3 factors"):
        STATE.from_parts(X, bg)
    assert isinstance(S, ProductGroup) and len(S.parts()) == 3
    bad = np.array(STATE._identity_params)
    bad[6] = 2.0  # the quaternion of the SE23 part
    with pytest.raises(ValueError, match="norm"):
        STATE(bad)


@pytest.mark.parametrize("G", PRODUCTS, ids=ids)
@pytest.mark.parametrize("side", ["right", "left"])
def test_every_jacobian_against_finite_differences(G, side):
    rng = np.random.default_rng(2)
    X, Y = G.exp(_tau(G, rng)), G.exp(_tau(G, rng))
    t = _tau(G, rng)
    p = rng.standard_normal(G.point_dim)
    cases = [
        (lambda a: a.inverse(), [X], X.inverse(jac=True, side=side)[1:]),
        (lambda a, b: a @ b, [X, Y], X.compose(Y, jac=True, side=side)[1:]),
        (lambda a, b: a.between(b), [X, Y], X.between(Y, jac=True, side=side)[1:]),
        (lambda a, b: b.minus(a), [X, Y], Y.minus(X, jac=True, side=side)[1:][::-1]),
        (lambda a, u: a.plus(u), [X, t], X.plus(t, jac=True, side=side)[1:]),
        (lambda a, q: a.act(q), [X, p], X.act(p, jac=True, side=side)[1:]),
    ]
    for f, args, Js in cases:
        for i, J in enumerate(Js):
            num = fd_jacobian(f, args, i, side=side)
            np.testing.assert_allclose(J, num, atol=2e-6 * max(1.0, np.abs(num).max()))


def test_backends_and_batches(backend):
    rng = np.random.default_rng(3)
    t = rng.standard_normal((6, 15))
    ref = STATE.exp(t)
    X = STATE.exp(to_backend(t, backend))
    np.testing.assert_allclose(to_numpy(X.params), ref.params, atol=1e-13)
    np.testing.assert_allclose(to_numpy(X.log()), ref.log(), atol=1e-12)
    np.testing.assert_allclose(to_numpy(STATE.jr(to_backend(t, backend))), STATE.jr(t),
                               atol=1e-12)
    for k in range(6):  # batch equals element-wise
        np.testing.assert_allclose(STATE.exp(t[k]).adjoint(), ref[k].adjoint(), atol=1e-13)


def test_gaussian_mean_compose_matches_monte_carlo():
    """A Gaussian on the product: the covariance of X Y (right errors) from the block adjoint
    equals the sample covariance of composed samples."""
    rng = np.random.default_rng(4)
    X, Y = STATE.exp(0.5 * rng.standard_normal(15)), STATE.exp(0.5 * rng.standard_normal(15))
    A = 0.02 * rng.standard_normal((15, 15))
    gx = Gaussian(X, A @ A.T + 1e-4 * np.eye(15), frame="right")
    gy = Gaussian(Y, 1e-4 * np.eye(15), frame="right")
    Ad = Y.inverse().adjoint()
    P = Ad @ gx.cov @ Ad.T + gy.cov  # MATH.md eq. 17
    Z = gx.sample(20000, rng=rng) @ gy.sample(20000, rng=rng)
    e = Z.minus(X @ Y)
    C = np.cov(e.T)
    np.testing.assert_allclose(C, P, atol=0.05 * np.abs(P).max())
    # the Gaussian's own Mahalanobis distance of the samples averages the dof
    assert abs(np.mean(gx.mahalanobis(gx.sample(4000, rng=rng), squared=True)) - 15) < 0.5


def test_solver_variable_matches_separate_variables():
    """Priors and between factors on Product(SE23, R(3)) variables give the same optimum as
    the same factors on separate SE23 and R(3) variables (the problem separates)."""
    from microlie.optim import BetweenFactor, FactorGraph, Isotropic, PriorFactor

    G = Product(SE23, R(3))
    rng = np.random.default_rng(5)
    n = 6
    Z = G.exp(0.3 * rng.standard_normal((n - 1, 12)))
    prior = G.exp(0.1 * rng.standard_normal(12))
    init = G.exp(rng.standard_normal((n, 12)))
    g = FactorGraph()
    x = g.add_variables(init)
    g.add(PriorFactor(x, 0, prior, Isotropic(12, 0.1)))
    g.add(BetweenFactor(x, np.arange(n - 1), np.arange(1, n), Z, Isotropic(12, 0.05)))
    # loops make it a real least-squares problem
    g.add(BetweenFactor(x, [0], [n - 1], Z[0], Isotropic(12, 0.5)))
    res = g.optimize()
    out = res.values[x]

    h = FactorGraph()
    p = h.add_variables(SE23(np.asarray(init.params)[:, :10]))
    v = h.add_variables(np.asarray(init.params)[:, 10:])
    h.add(PriorFactor(p, 0, prior.part(0), Isotropic(9, 0.1)))
    h.add(PriorFactor(v, 0, np.asarray(prior.part(1).params), Isotropic(3, 0.1)))
    zp, zv = Z.part(0), np.asarray(Z.part(1).params)
    h.add(BetweenFactor(p, np.arange(n - 1), np.arange(1, n), zp, Isotropic(9, 0.05)))
    h.add(BetweenFactor(v, np.arange(n - 1), np.arange(1, n), zv, Isotropic(3, 0.05)))
    h.add(BetweenFactor(p, [0], [n - 1], zp[0], Isotropic(9, 0.5)))
    h.add(BetweenFactor(v, [0], [n - 1], zv[0], Isotropic(3, 0.5)))
    ref = h.optimize()
    np.testing.assert_allclose(out.part(0).matrix(), ref.values[p].matrix(), atol=1e-7)
    np.testing.assert_allclose(np.asarray(out.part(1).params), ref.values[v], atol=1e-7)
    assert abs(res.final_cost - ref.final_cost) < 1e-8 * max(1.0, ref.final_cost)


def test_pickle_roundtrip_of_generated_classes():
    import pickle

    for G in (STATE, R(4), Product(Product(SO3, R(2)), SE3)):
        X = G.random(3, rng=0)
        Y = pickle.loads(pickle.dumps(X))
        assert type(Y) is G
        np.testing.assert_array_equal(Y.params, X.params)
