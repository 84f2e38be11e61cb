"""Issue 20: the public way to write a factor with analytic Jacobians (a ``Factor`` subclass
implementing ``residual``), ``check_jacobians``, and the checks the graph applies to it.

The reference Jacobians are central differences of residuals computed here from the poses'
matrices, perturbed by SciPy's matrix exponential of the tangent's hat (right perturbation,
translation first): independent of microlie's ``plus``, ``log`` and the factors' own maths."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import require
from scipy.linalg import expm

from microlie import SE2, SE3
from microlie.optim import (
    BetweenFactor,
    CustomFactor,
    Diagonal,
    Factor,
    FactorGraph,
    Huber,
    Isotropic,
    PriorFactor,
    check_jacobians,
)

ROOT = Path(__file__).resolve().parents[1]


class RangeFactor(Factor):
    """``r = |l_j - t_i| - z`` between SE(2) poses and 2-D landmarks."""

    def __init__(self, poses, i, landmarks, j, z, noise=None, loss=None):
        super().__init__([(poses, i), (landmarks, j)], 1, noise, loss)
        self.z = self.per_factor(z, "z").reshape(-1, 1)

    def residual(self, X, l, jac=False):
        d = l - X.translation()
        n = np.linalg.norm(d, axis=1, keepdims=True)
        if not jac:
            return n - self.z
        u = (d / n)[:, None, :]
        dt = np.concatenate([X.rotation().matrix(), np.zeros((len(n), 2, 1), n.dtype)], axis=2)
        return n - self.z, [-u @ dt, u]


class WrongRange(RangeFactor):
    """The pose Jacobian without the rotation (a frame mistake a user could make)."""

    def residual(self, X, l, jac=False):
        out = super().residual(X, l, jac)
        if not jac:
            return out
        r, (_, Jl) = out
        dt = np.broadcast_to(np.eye(2, 3, dtype=r.dtype), (len(r), 2, 3))
        return r, [-Jl @ dt, Jl]


class PositionFactor(Factor):
    """A GPS-like fix on SE(3) poses: ``r = t - z``, ``d r / d delta = [R 0]``."""

    jacobians_with_residuals = True

    def __init__(self, poses, i, z, noise=None, loss=None):
        super().__init__([(poses, i)], 3, noise, loss)
        self.z = self.per_factor(z, "z")

    def residual(self, X, jac=False):
        r = X.translation() - self.z
        if not jac:
            return r
        R = X.rotation().matrix()
        return r, [np.concatenate([R, np.zeros_like(R)], axis=2)]


def _hat(G, tau):
    """The Lie algebra matrix of ``tau`` (translation first), written out here."""
    if G is SE2:
        x, y, th = tau
        return np.array([[0.0, -th, x], [th, 0.0, y], [0.0, 0.0, 0.0]])
    rho, (a, b, c) = tau[:3], tau[3:]
    H = np.zeros((4, 4))
    H[:3, :3] = [[0.0, -c, b], [c, 0.0, -a], [-b, a, 0.0]]
    H[:3, 3] = rho
    return H


def _range_from_matrices(T, l, z):
    return np.array([np.linalg.norm(l - T[:2, 2]) - z])


def _independent_jacobians(G, res, mats, others, h=1e-6):
    """Central differences of ``res(T, *others)`` per factor in ``T expm(hat(+-h e_a))``, and
    in ``other + h e_a`` for the first vector argument."""
    m = len(mats)
    d = G.dof
    r0 = res(mats[0], *[o[0] for o in others])
    JX = np.empty((m, r0.size, d))
    Jv = np.empty((m, r0.size, others[0].shape[1])) if others and others[0].ndim == 2 else None
    for k in range(m):
        args = [o[k] for o in others]
        for a in range(d):
            e = np.zeros(d)
            e[a] = h
            JX[k, :, a] = (res(mats[k] @ expm(_hat(G, e)), *args)
                           - res(mats[k] @ expm(_hat(G, -e)), *args)) / (2 * h)
        if Jv is not None:
            for a in range(Jv.shape[2]):
                e = np.zeros(Jv.shape[2])
                e[a] = h
                Jv[k, :, a] = (res(mats[k], args[0] + e, *args[1:])
                               - res(mats[k], args[0] - e, *args[1:])) / (2 * h)
    return JX, Jv


def _range_setup(m=6, seed=0):
    rng = np.random.default_rng(seed)
    g = FactorGraph()
    X = SE2.from_xy_theta(rng.uniform(-3, 3, m), rng.uniform(-3, 3, m), rng.uniform(-3, 3, m))
    L = rng.uniform(-5, 5, (3, 2))
    x, p = g.add_variables(X), g.add_variables(L)
    j = rng.integers(0, 3, m)
    z = rng.uniform(1, 4, m)
    f = g.add(RangeFactor(x, np.arange(m), p, j, z, Isotropic(1, 0.1)))
    return g, f, X, L[j], z


def test_user_factor_jacobians_match_independent_differences():
    _, f, X, Lj, z = _range_setup()
    r, (JX, Jl) = f.evaluate([X, Lj], True)
    mats = list(X.matrix())
    ref = np.array([_range_from_matrices(T, l, zz) for T, l, zz in zip(mats, Lj, z, strict=True)])
    np.testing.assert_allclose(r, ref, atol=1e-12)
    nX, nl = _independent_jacobians(SE2, _range_from_matrices, mats, [Lj, z])
    np.testing.assert_allclose(JX, nX, atol=1e-8)
    np.testing.assert_allclose(Jl, nl, atol=1e-8)
    # SE(3): the position factor, one pose repeated over three fixes (a broadcast index)
    g = FactorGraph()
    Y = SE3.random(1, rng=3)
    y = g.add_variables(Y)
    zs = np.arange(9.0).reshape(3, 3)
    pf = g.add(PositionFactor(y, [0, 0, 0], zs))
    assert pf.count == 3 and pf.args[0][1].tolist() == [0, 0, 0]
    _, (JY,) = pf.evaluate([SE3(np.repeat(Y.params, 3, axis=0))], True)
    nY, _ = _independent_jacobians(SE3, lambda T, z: T[:3, 3] - z,
                                   [Y.matrix()[0]] * 3, [zs])
    np.testing.assert_allclose(JY, nY, atol=1e-8)


def test_check_jacobians_agrees_with_independent_differences_and_catches_errors():
    g, f, X, Lj, z = _range_setup(seed=1)
    c = check_jacobians(f)
    assert c.ok and max(c.errors) < 1e-8
    nX, nl = _independent_jacobians(SE2, _range_from_matrices, list(X.matrix()), [Lj, z])
    np.testing.assert_allclose(c.numerical[0], nX, atol=1e-8)
    np.testing.assert_allclose(c.numerical[1], nl, atol=1e-8)
    # the same point given explicitly, as graph values and as one batch per argument
    assert check_jacobians(f, g.initial_values()).errors == c.errors
    assert check_jacobians(f, [X, Lj]).errors == c.errors
    x, p = (var for var, _ in f.args)
    bad = WrongRange(x, f.args[0][1], p, f.args[1][1], z)
    w = check_jacobians(bad)
    assert not w.ok and w.errors[0] > 1e-2 and w.errors[1] < 1e-8
    assert "argument 0 (x0)" in w.worst and "WrongRange" not in repr(c)
    with pytest.raises(ValueError, match=r"RangeFactor\): 1 values for 2 arguments"):
        check_jacobians(f, [X])
    with pytest.raises(ValueError, match=r"value 1 \(argument x1\) must be an? array batch of 6"):
        check_jacobians(f, [X, Lj[:2]])


def test_check_jacobians_in_float32():
    """float32 values are evaluated and differenced in float32 (step and tolerance of float32);
    the graph's evaluation hands float64 back."""
    _, f, X, Lj, _ = _range_setup(seed=2)
    X32, L32 = SE2(X.params.astype(np.float32)), Lj.astype(np.float32)
    seen = []

    class Spy(RangeFactor):
        def residual(self, X, l, jac=False):
            seen.append((X.params.dtype, l.dtype))
            return super().residual(X, l, jac)

    x, p = (var for var, _ in f.args)
    spy = Spy(x, f.args[0][1], p, f.args[1][1], f.z[:, 0])
    c = check_jacobians(spy, [X32, L32])
    assert c.ok and c.tol == 1e-2 and max(c.errors) < 1e-2
    assert set(seen) == {(np.dtype(np.float32), np.dtype(np.float32))}
    r, Js = spy.evaluate([X32, L32], True)
    assert r.dtype == np.float64 and all(J.dtype == np.float64 for J in Js)
    r64, Js64 = spy.evaluate([X, Lj], True)
    np.testing.assert_allclose(r, r64, atol=1e-5)
    bad = WrongRange(x, f.args[0][1], p, f.args[1][1], f.z[:, 0])
    assert not check_jacobians(bad, [X32, L32]).ok


def _slam(kind, loss=None):
    """SE(2) poses with odometry and a prior, 2-D landmarks seen by range factors of
    ``kind``: the user subclass, or CustomFactor with numerical or JAX Jacobians."""
    rng = np.random.default_rng(4)
    n, nl = 8, 4
    truth = SE2.from_xy_theta(np.cumsum(np.full(n, 1.0)), 0.3 * np.sin(np.arange(n)),
                              0.2 * np.arange(n))
    L = rng.uniform(-3, 10, (nl, 2))
    i = np.repeat(np.arange(n), nl)
    j = np.tile(np.arange(nl), n)
    z = np.linalg.norm(L[j] - truth.translation()[i], axis=1) + 0.05 * rng.standard_normal(i.size)
    g = FactorGraph()
    x = g.add_variables(truth.plus(0.1 * rng.standard_normal((n, 3))))
    p = g.add_variables(L + 0.3 * rng.standard_normal(L.shape))
    g.add(PriorFactor(x, 0, truth[0], Isotropic(3, 0.01)))
    odo = truth[:-1].between(truth[1:]).plus(0.02 * rng.standard_normal((n - 1, 3)))
    g.add(BetweenFactor(x, np.arange(n - 1), np.arange(1, n), odo, Diagonal([0.05, 0.05, 0.02])))
    noise = Isotropic(1, 0.05)
    if kind == "subclass":
        g.add(RangeFactor(x, i, p, j, z, noise, loss))
    elif kind == "numerical":
        def fn(X, l, zz):
            return np.linalg.norm(l - X.translation(), axis=1, keepdims=True) - zz
        g.add(CustomFactor(fn, [(x, i), (p, j)], 1, noise, data=[z[:, None]], loss=loss))
    else:
        jnp = require("jax.numpy")
        require("jax").config.update("jax_enable_x64", True)

        def fn(X, l, zz):
            return jnp.linalg.norm(l - X.translation(), keepdims=True) - zz
        g.add(CustomFactor(fn, [(x, i), (p, j)], 1, noise, data=[z[:, None]], jac="jax",
                           loss=loss))
    return g, x, p


@pytest.mark.parametrize("other", ["numerical", "jax"])
def test_solve_with_the_subclass_reaches_the_custom_factor_optimum(other):
    sols = {}
    for kind in ("subclass", other):
        g, x, p = _slam(kind)
        res = g.optimize(rel_tol=1e-15, abs_tol=1e-15, max_iter=50)
        assert res.final_cost < 0.01 * res.initial_cost
        sols[kind] = (res.values[x], res.values[p], res.final_cost)
    (Xa, La, ca), (Xb, Lb, cb) = sols["subclass"], sols[other]
    # JAX's Jacobians are exact: the fixed points agree to rounding. Central differences with
    # h = 1e-6 carry a rounding error of about eps / h = 2e-10 per Jacobian entry, and the
    # numerical solve stops where J_num^T r = 0, which moves the answer by that error times the
    # conditioning (seen: 2.8e-9 under the generic kernels, 7.1e-10 under the compiled ones)
    tol = 1e-9 if other == "jax" else 2e-8
    assert np.abs(Xa.minus(Xb)).max() < tol
    assert np.abs(La - Lb).max() < tol
    assert ca == pytest.approx(cb, rel=1e-12)


def test_robust_solve_takes_the_autodiff_path():
    """With a Huber loss, the subclass and the JAX-differentiated CustomFactor take the same
    LM iterations (costs equal to rounding); LM's linear convergence under the loss stops both
    within 1e-7 of each other (1e-9 needs the quadratic convergence of the test above)."""
    runs = {}
    for kind in ("subclass", "jax"):
        g, x, p = _slam(kind, "huber:1.0")
        res = g.optimize(rel_tol=1e-15, abs_tol=1e-15, max_iter=50)
        runs[kind] = res, res.values[x], res.values[p]
    (ra, Xa, La), (rb, Xb, Lb) = runs["subclass"], runs["jax"]
    ca, cb = (np.array([h.cost for h in r.history[:10]]) for r in (ra, rb))
    np.testing.assert_allclose(ca, cb, rtol=1e-12)
    assert ca.size == 10
    assert np.abs(Xa.minus(Xb)).max() < 1e-7 and np.abs(La - Lb).max() < 1e-7


def test_noise_and_robust_loss_are_applied_by_the_graph():
    """The graph whitens the subclass's residuals and applies its loss: the costs equal
    ``0.5 sum (r / sigma)^2`` and ``0.5 sum rho((r / sigma)^2)`` (Huber, written out here)."""
    g, f, X, Lj, z = _range_setup(seed=5)
    x, p = (var for var, _ in f.args)
    g2 = FactorGraph()
    x2, p2 = g2.add_variables(X), g2.add_variables(p.initial)
    g2.add(RangeFactor(x2, f.args[0][1], p2, f.args[1][1], z, Isotropic(1, 2.0), "huber:1.0"))
    r = np.linalg.norm(Lj - np.array([T[:2, 2] for T in X.matrix()]), axis=1) - z
    s = (r / 2.0) ** 2
    rho = np.where(s <= 1.0, s, 2 * np.sqrt(s) - 1)
    assert 1.0 < s.max() and s.min() < 1.0  # both branches of the loss
    prob = g2.problem(gauge="none")
    cost, robust = prob.costs([v.initial for v in prob.variables])
    assert cost == pytest.approx(0.5 * s.sum(), rel=1e-12)
    assert robust == pytest.approx(0.5 * rho.sum(), rel=1e-12)
    assert isinstance(g2.factors[0].loss, Huber)


class _Shapes(Factor):
    """Returns what ``defect`` says, to exercise the checks of ``Factor.evaluate``."""

    def __init__(self, var, defect):
        super().__init__([(var, [0, 1])], 2)
        self.defect = defect

    def residual(self, v, jac=False):
        m = len(v)
        r, J = v - 1.0, np.broadcast_to(np.eye(2), (m, 2, 2))
        d = self.defect
        if d == "r 1-D":
            r = r[:, 0]
        if d == "tuple without jac" and not jac:
            return r, [J]
        if not jac:
            return r
        if d == "J shape":
            J = J[:, :, :1]
        if d == "no list":
            return r
        if d == "two J":
            return r, [J, J]
        return r, [J]


@pytest.mark.parametrize("defect,jac,message", [
    ("r 1-D", False, r"_Shapes.residual returned residuals of shape \(2,\), expected \(2, 2\)"),
    ("J shape", True, r"_Shapes.residual: Jacobian 0 \(argument v\) has shape \(2, 2, 1\), "
                      r"expected \(2, 2, 2\)"),
    ("two J", True, r"_Shapes.residual returned 2 Jacobians for 1 arguments"),
    ("no list", True, r"_Shapes.residual\(..., jac=True\) must return \(r, \[J_1, ..., J_1\]\)"),
    ("tuple without jac", False, r"_Shapes.residual\(..., jac=False\) must return the "
                                 r"residuals alone"),
])
def test_bad_shapes_are_value_errors_naming_the_class(defect, jac, message):
    g = FactorGraph()
    v = g.add_variables(np.zeros((2, 2)), name="v")
    f = g.add(_Shapes(v, defect))
    with pytest.raises(ValueError, match=message):
        f.evaluate([np.zeros((2, 2))], jac)
    with pytest.raises(ValueError, match="_Shapes"):  # from the solver too
        g.optimize()
    np.testing.assert_array_equal(g.initial_values()[v], np.zeros((2, 2)))  # left as it was
    assert _Shapes(v, None).evaluate([np.zeros((2, 2))], True)[1][0].shape == (2, 2, 2)


def test_subclass_contract_errors_name_the_class():
    g = FactorGraph()
    x = g.add_variables(SE2.identity(3), name="x")
    p = g.add_variables(np.zeros((2, 2)), name="p")

    class NoResidual(Factor):
        pass

    with pytest.raises(TypeError, match="NoResidual: a Factor subclass must implement residual"):
        NoResidual([(x, 0)], 3)

    class OneValue(Factor):
        def residual(self, X, jac=False):
            return X.log()

    with pytest.raises(TypeError, match=r"OneValue: residual must take one value per argument "
                                        r"\(2\)"):
        OneValue([(x, 0), (p, 0)], 3)
    with pytest.raises(TypeError, match="Overrides: a Factor subclass implements residual"):
        class Overrides(Factor):
            def evaluate(self, values, jac):  # the checked call is not a hook
                return values
    with pytest.raises(ValueError, match=r"RangeFactor: z must have 3 rows \(one per factor\) "
                                         r"or 1, got shape \(2,\)"):
        RangeFactor(x, [0, 1, 2], p, 0, [1.0, 2.0])
    with pytest.raises(ValueError, match="RangeFactor: z has non-finite entries"):
        RangeFactor(x, [0, 1, 2], p, 0, [1.0, np.nan, 2.0])
    with pytest.raises(ValueError, match="RangeFactor: index arrays of different lengths 3 and 2"):
        RangeFactor(x, [0, 1, 2], p, [0, 1], 1.0)
    with pytest.raises(ValueError, match="OneValue: dim must be a positive integer"):
        OneValue([(x, 0)], 0)
    f = RangeFactor(x, [0, 1, 2], p, 1, 2.5)  # one landmark and one range for three poses
    assert f.count == 3 and f.args[1][1].tolist() == [1, 1, 1] and f.z.tolist() == [[2.5]] * 3


def test_docs_example_prints_what_the_page_shows(capsys):
    """The section "A factor with analytic Jacobians" of docs/optim.md runs on its own."""
    page = (ROOT / "docs" / "optim.md").read_text()
    sec = page[page.index("## A factor with analytic Jacobians"):]
    sec = sec[:sec.index("\n## ")]
    (kind, code), (kind2, text) = re.findall(r"```(python|text)\n(.*?)```", sec, flags=re.S)
    assert (kind, kind2) == ("python", "text")
    lines = code.splitlines()
    body = lines[lines.index("class RangeFactor(Factor):"):lines.index("graph = FactorGraph()")]
    assert len([ln for ln in body if ln.strip()]) <= 20  # the factor itself: 20 lines at most
    exec(compile(code, "docs/optim.md", "exec"), {})
    assert capsys.readouterr().out == text


def test_the_built_in_factors_pass_check_jacobians():
    """Every factor of the package is written on the same API: ``check_jacobians`` accepts
    each at a random point, batched (SE(3) between factors with a relative rotation near pi,
    IMU factors with biases)."""
    from microlie import SE23
    from microlie.imu import BiasRandomWalkFactor, ImuFactor, Preintegration

    rng = np.random.default_rng(9)
    g = FactorGraph()
    X = SE3.random(4, rng=1)
    near_pi = (X[0] @ SE3.exp([0, 0, 0, 0, 0, np.pi - 1e-3])).params[None]
    X = SE3(np.concatenate([X.params[:1], near_pi, X.params[2:]]))
    x = g.add_variables(X)
    s = g.add_variables(SE23.random(3, rng=2))
    b = g.add_variables(0.01 * rng.standard_normal((3, 6)))
    pim = Preintegration(gyro_noise=1e-3, accel_noise=1e-2).integrate(
        rng.normal([0, 0, 9.81], 0.5, (50, 3)), rng.normal(0, 0.3, (50, 3)), 0.01)
    factors = [PriorFactor(x, [0, 3], SE3.random(2, rng=3), Isotropic(6, 0.5)),
               BetweenFactor(x, [0, 1, 2], [1, 2, 3], SE3.random(3, rng=4)),
               ImuFactor(s, b, [0, 1], [1, 2], [pim, pim]),
               BiasRandomWalkFactor(b, [0, 1], [1, 2], 1e-3, 1e-2, 0.5),
               PositionFactor(x, [0, 1, 2], rng.standard_normal((3, 3)))]
    for f in factors:
        c = check_jacobians(f)
        assert c.ok, (f.name, c)
