"""Solver strategies as objects (core/strategies.py) and the one loop (core/solvers.py).

- ``TrustRegion`` (Levenberg-Marquardt with Ceres' rules) on a bundle-adjustment FactorGraph
  (an analytic CustomFactor over SO(3) x R(3) x R(3) cameras and R(3) points) against a dense,
  literal re-implementation of Ceres' ``TrustRegionMinimizer`` + ``LevenbergMarquardtStrategy``
  written here (scaled Jacobian, damping as extra rows solved by ``numpy.linalg.lstsq``, the
  J-based model), and on problem-49-7776 against Ceres'
  reference (benchmarks/results/bundle_adjustment-latest.md: 850912.46 -> 13344.3184,
  31 iterations, ``benchmarks/ceres_bal``).
- LM, GN, dogleg and trust-region against ``scipy.optimize.least_squares``.
- Iteration records against finite differences and the dense model.
- The strategy API: registry, options, reuse, errors.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from threadpoolctl import threadpool_limits

from microlie import SO3
from microlie.optim import (
    CustomFactor,
    Dogleg,
    FactorGraph,
    GaussNewton,
    LevenbergMarquardt,
    PriorFactor,
    Strategy,
    TrustRegion,
)
from microlie.optim.core.strategies import STRATEGIES, make_strategy
from microlie.optim.io.bal import read_bal
from microlie.optim.sfm.bundle import BundleProblem, synthetic_scene
from microlie.optim.sfm.camera import reproject


# ----------------------------------------------------------------------------- bundle graph
def bundle_graph(p: BundleProblem, fix_cameras=(), loss=None):
    """The bundle problem as a FactorGraph: rotation R Exp(dphi) (SO3), translation t + dt,
    intrinsics K + dK, points X + dX; residual = projection - observation (pixels)."""
    g = FactorGraph()
    rot = g.add_variables(SO3.from_matrix(p.rotations, normalize=True), name="R")
    tr = g.add_variables(p.translations.copy(), name="t")
    K = g.add_variables(p.intrinsics.copy(), name="K")
    X = g.add_variables(p.points.copy(), name="X")
    model = p.model

    def fn(R, t, k, x, z):
        i = np.arange(len(z))
        rp = reproject(model, np.asarray(R.matrix()), t, k, x, i, i, z)
        Jc = rp.J_cam  # (dt, dphi, dK)
        return rp.residuals, [Jc[:, :, 3:6], Jc[:, :, 0:3], Jc[:, :, 6:], rp.J_point]

    c, j = p.camera_index, p.point_index
    g.add(CustomFactor(fn, [(rot, c), (tr, c), (K, c), (X, j)], 2, data=[p.observations],
                       jac="analytic", loss=loss))
    for f in fix_cameras:
        rot.fix(f)
        tr.fix(f)
    return g, (rot, tr, K, X)


# ----------------------------------------------------------------------------- Ceres oracle
def _ceres_lm(p: BundleProblem, fixed_pose: int, huber: float | None = None,
              max_iter: int = 100):
    """Ceres' LM, literally and densely: the Jacobian's columns scaled by 1 / (1 + |col|)
    (fixed at iteration 0), the LM diagonal clamp(|scaled col|^2, 1e-6, 1e32) / radius appended
    as rows and solved by least squares, step = scale * y, model decrease -(J d).(f + J d / 2),
    rho > 1e-3 accepts, radius /= max(1/3, 1 - (2 rho - 1)^3), rejections halve the radius
    with a doubling factor; stops: gradient 1e-10, |dcost| <= 1e-6 cost, |d| <= 1e-8 (|x| +
    1e-8) (from the first accepted step), radius <= 1e-32. Returns [(accepted, candidate
    cost)] per try, the final cost and the stop. Huber as Ceres' corrector (sqrt(rho') scaled rows,
    Triggs' alpha)."""
    nc, npt, k = p.n_cameras, p.n_points, p.model.n_intrinsics
    d = 6 + k
    cam, pt, obs = p.camera_index, p.point_index, p.observations
    free = np.ones(nc * d + 3 * npt, bool)
    free[fixed_pose * d: fixed_pose * d + 6] = False

    def rho(s):
        if huber is None:
            return s, np.ones_like(s), np.zeros_like(s)
        b = huber * huber
        big = s > b
        r = np.where(big, 2 * np.sqrt(b * s) - b, s)
        r1 = np.where(big, np.sqrt(b / np.maximum(s, 1e-300)), 1.0)
        r2 = np.where(big, -0.5 * np.sqrt(b) * np.maximum(s, 1e-300) ** -1.5, 0.0)
        return r, r1, r2

    def evaluate(state, jac):
        R, t, K, X = state
        rp = reproject(p.model, R, t, K, X, cam, pt, obs, jac=jac)
        r = rp.residuals
        s = (r * r).sum(1)
        r0, r1, r2 = rho(s)
        cost = 0.5 * r0.sum()
        if not jac:
            return cost
        J = np.zeros((2 * len(cam), nc * d + 3 * npt))
        for a in range(len(cam)):
            J[2 * a:2 * a + 2, cam[a] * d:(cam[a] + 1) * d] = rp.J_cam[a]
            J[2 * a:2 * a + 2, nc * d + 3 * pt[a]:nc * d + 3 * pt[a] + 3] = rp.J_point[a]
        # Ceres' Corrector: J <- sqrt(rho') (I - alpha r r^T / |r|^2) J, r <- sqrt(rho') / (1 -
        # alpha) r, alpha = 1 - sqrt(1 + 2 s rho'' / rho')
        D = 1.0 + 2.0 * s * r2 / r1
        alpha = np.where(D > 0, 1.0 - np.sqrt(np.maximum(D, 0.0)), 0.0)
        alpha = np.where((s > 0) & (r2 > 0), alpha, 0.0)  # Ceres: no alpha when rho'' <= 0
        sq = np.sqrt(r1)
        f = np.empty(2 * len(cam))
        for a in range(len(cam)):
            ra = r[a]
            Ja = J[2 * a:2 * a + 2]
            if alpha[a] != 0.0:
                Ja = Ja - (alpha[a] / s[a]) * np.outer(ra, ra @ Ja)
            J[2 * a:2 * a + 2] = sq[a] * Ja
            f[2 * a:2 * a + 2] = sq[a] / (1.0 - alpha[a]) * ra
        return cost, f, J[:, free]

    def retract(state, dx):
        full = np.zeros(free.size)
        full[free] = dx
        dc = full[:nc * d].reshape(nc, d)
        dp = full[nc * d:].reshape(npt, 3)
        R, t, K, X = state
        dR = Rotation.from_rotvec(dc[:, 3:6]).as_matrix()
        return R @ dR, t + dc[:, :3], K + dc[:, 6:], X + dp

    def xnorm(state):
        R, t, K, X = state
        w = Rotation.from_matrix(R).as_rotvec()
        keep = np.ones(nc, bool)
        keep[fixed_pose] = False
        return np.sqrt((w[keep] ** 2).sum() + (t[keep] ** 2).sum() + (K ** 2).sum()
                       + (X ** 2).sum())

    x = (p.rotations, p.translations, p.intrinsics, p.points)
    cost, f, J = evaluate(x, True)
    scale = 1.0 / (1.0 + np.sqrt((J * J).sum(0)))
    radius, decrease, x_norm = 1e4, 2.0, None
    tries, it = [], 0
    while True:
        if np.abs(J.T @ f).max() <= 1e-10:
            return tries, cost, "gradient tolerance"
        if radius <= 1e-32:
            return tries, cost, "minimum trust region radius"
        if it >= max_iter:
            return tries, cost, "max_iter"
        it += 1
        Js = J * scale
        diag = np.clip((Js * Js).sum(0), 1e-6, 1e32)
        A = np.vstack([Js, np.diag(np.sqrt(diag / radius))])
        b = np.concatenate([-f, np.zeros(J.shape[1])])
        y = np.linalg.lstsq(A, b, rcond=None)[0]
        step = scale * y
        Jd = J @ step
        model = -Jd @ (f + 0.5 * Jd)
        if not model > 0:
            radius /= decrease
            decrease *= 2
            tries.append((False, np.nan))
            continue
        cand = retract(x, step)
        ccost = evaluate(cand, False)
        if x_norm is not None and np.linalg.norm(step) <= 1e-8 * (x_norm + 1e-8):
            tries.append((False, ccost))
            return tries, cost, "parameter tolerance"
        if abs(cost - ccost) <= 1e-6 * cost:
            tries.append((False, ccost))
            return tries, cost, "function tolerance"
        r = (cost - ccost) / model
        if r > 1e-3:
            x = cand
            x_norm = xnorm(x)
            cost, f, J = evaluate(x, True)
            radius = min(1e16, radius / max(1 / 3, 1 - (2 * r - 1) ** 3))
            decrease = 2.0
        else:
            radius /= decrease
            decrease *= 2
        tries.append((r > 1e-3, ccost))


def _tries(res):
    """(accepted, candidate cost) of each record of a trust-region Result."""
    return [(h.accepted, h.cost if h.accepted else h.cost - h.cost_change) for h in res.history]


@pytest.mark.parametrize("model, huber, perturb, seed", [
    ("bal", None, 0.08, 7), ("bal", 2.0, 0.08, 7),
    ("pinhole-radtan", None, 0.08, 7),  # 100 tries (max_iter), 2 rejected
    ("bal", None, 0.5, 8),  # 41 tries, 10 rejected
])
def test_trust_region_follows_a_dense_ceres_oracle(model, huber, perturb, seed):
    _, start = synthetic_scene(4, 25, noise=1.0, perturb=perturb, seed=seed, model=model)
    with threadpool_limits(1):  # a multithreaded BLAS on a busy machine: 100x slower
        tries, final, why = _ceres_lm(start, 0, huber)
    g, _ = bundle_graph(start, [0], loss=None if huber is None else f"huber:{huber}")
    r = g.optimize(solver=TrustRegion(), gauge="none", linear_solver="dense")
    got = _tries(r)
    assert [a for a, _ in got] == [a for a, _ in tries]
    assert len(tries) >= 4 and any(a for a, _ in tries)
    np.testing.assert_allclose([c for _, c in got], [c for _, c in tries], rtol=1e-9)
    assert r.final_robust_cost == pytest.approx(final, rel=1e-9)
    stopped = why in ("function tolerance", "parameter tolerance")  # that try: not counted
    assert r.iterations == len(tries) - stopped == len(r.history) - stopped
    assert r.accepted_steps == sum(a for a, _ in tries)
    assert why in r.message


def test_trust_region_problem_49_reaches_ceres_cost_in_ceres_iterations():
    # Ceres (benchmarks/ceres_bal, SPARSE_SCHUR and DENSE_SCHUR): 850912.46 -> 13344.3184 in
    # 31 iterations with 32 successful steps (iteration 0 included)
    p = BundleProblem.from_bal(read_bal(data_file("bal/problem-49-7776-pre.txt")))
    g, _ = bundle_graph(p)
    r = g.optimize(solver=TrustRegion(), gauge="none")
    assert r.initial_cost == pytest.approx(850912.46, abs=0.01)
    assert r.final_cost == pytest.approx(13344.3184, rel=1e-6)
    assert r.converged and "function tolerance" in r.message
    assert r.iterations == r.accepted_steps == 31
    assert all(h.accepted for h in r.history[:-1])  # the last try is the stopping one


# ----------------------------------------------------------------------------- scipy
def _curve_problem():
    """y = a exp(-b t) + c sin(d t) on noisy samples, and a 2-D range fix of two points."""
    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 4.0, 40)
    truth = np.array([2.0, 0.7, 0.5, 2.5])
    y = truth[0] * np.exp(-truth[1] * t) + truth[2] * np.sin(truth[3] * t)
    y = y + 0.02 * rng.standard_normal(t.size)
    beacons = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 3.0], [5.0, 5.0]])
    pts = np.array([[1.0, 1.0], [3.0, 2.0]])
    ranges = np.linalg.norm(pts[:, None] - beacons[None], axis=2)
    ranges = ranges + 0.01 * rng.standard_normal(ranges.shape)

    def residuals(z):
        a, b, c, d = z[:4]
        p = z[4:].reshape(2, 2)
        r1 = a * np.exp(-b * t) + c * np.sin(d * t) - y
        r2 = (np.linalg.norm(p[:, None] - beacons[None], axis=2) - ranges).ravel()
        return np.concatenate([r1, r2])

    z0 = np.array([1.5, 0.5, 0.4, 2.4, 0.5, 0.5, 2.5, 1.5])

    def graph():
        g = FactorGraph()
        th = g.add_variables(z0[None, :4].copy(), name="theta")
        P = g.add_variables(z0[4:].reshape(2, 2).copy(), name="p")

        def curve(v):
            a, b, c, d = v[:, 0:1], v[:, 1:2], v[:, 2:3], v[:, 3:4]
            r = a * np.exp(-b * t) + c * np.sin(d * t) - y
            J = np.stack([np.exp(-b * t), -a * t * np.exp(-b * t), np.sin(d * t),
                          c * t * np.cos(d * t)], axis=-1)
            return r, [J]

        def rng_(q, bk, m):
            diff = q - bk
            n = np.linalg.norm(diff, axis=1, keepdims=True)
            return n - m, [(diff / n)[:, None, :]]

        g.add(CustomFactor(curve, [(th, [0])], t.size, jac="analytic"))
        idx = np.repeat([0, 1], 4)
        g.add(CustomFactor(rng_, [(P, idx)], 1, data=[np.tile(beacons, (2, 1)),
                                                      ranges.reshape(-1, 1)], jac="analytic"))
        return g, th, P

    return residuals, z0, graph


@pytest.mark.parametrize("strategy", [
    LevenbergMarquardt(rel_tol=1e-14, abs_tol=0.0),
    LevenbergMarquardt(damping="diagonal", rel_tol=1e-14, abs_tol=0.0),
    GaussNewton(rel_tol=1e-14, abs_tol=0.0),
    Dogleg(rel_tol=1e-14, abs_tol=0.0),
    TrustRegion(function_tolerance=1e-14),
])
def test_strategies_reach_scipy_least_squares(strategy):
    residuals, z0, graph = _curve_problem()
    ref = least_squares(residuals, z0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    g, th, P = graph()
    r = g.optimize(solver=strategy, gauge="none", linear_solver="dense", max_iter=200)
    z = np.concatenate([r.values[th].ravel(), r.values[P].ravel()])
    assert r.final_cost == pytest.approx(ref.cost, rel=1e-10)
    np.testing.assert_allclose(z, ref.x, rtol=1e-6, atol=1e-8)
    assert r.termination == "convergence", r.message
    assert r.solver == strategy.name and r.strategy is strategy


# ----------------------------------------------------------------------------- records
@pytest.mark.parametrize("solver", ["lm", "gn", "dogleg", "trust-region"])
def test_first_record_against_finite_differences_and_the_dense_model(solver):
    residuals, z0, graph = _curve_problem()
    g, th, P = graph()
    r = g.optimize(solver=solver, gauge="none", linear_solver="dense", max_iter=1)
    rec = r.history[0]
    assert rec.iteration == 1 and rec.accepted
    z1 = np.concatenate([r.values[th].ravel(), r.values[P].ravel()])
    dx = z1 - z0  # vector variables: X Exp(dx) = X + dx
    h = 1e-7
    J0 = np.column_stack([(residuals(z0 + h * e) - residuals(z0 - h * e)) / (2 * h)
                          for e in np.eye(z0.size)])
    J1 = np.column_stack([(residuals(z1 + h * e) - residuals(z1 - h * e)) / (2 * h)
                          for e in np.eye(z0.size)])
    f0, f1 = residuals(z0), residuals(z1)
    c0, c1 = 0.5 * f0 @ f0, 0.5 * f1 @ f1
    assert rec.cost == pytest.approx(c1, rel=1e-12)
    assert rec.cost_change == pytest.approx(c0 - c1, rel=1e-9)
    assert rec.step_norm == pytest.approx(np.linalg.norm(dx), rel=1e-9)
    Jd = J0 @ dx
    assert rec.tr_ratio == pytest.approx((c0 - c1) / -(Jd @ (f0 + 0.5 * Jd)), rel=1e-5)
    if np.isnan(rec.gradient_max):  # the run converged there: not linearised again
        assert r.termination == "convergence"
    else:
        assert rec.gradient_max == pytest.approx(np.abs(J1.T @ f1).max(), rel=1e-5)
    assert rec.solves >= 1 and rec.iter_time_s <= rec.time_s


def test_trust_region_table_prints_every_try(capsys):
    _, start = synthetic_scene(3, 20, noise=1.0, perturb=0.3, seed=11)
    g, _ = bundle_graph(start, [0])
    r = g.optimize(solver="trust-region", gauge="none", verbose=True)
    rows = [ln.split() for ln in capsys.readouterr().err.splitlines()[1:]]
    assert "function tolerance" in r.message  # its stopping try: recorded, not printed
    assert len(rows) == r.iterations + 1 == len(r.history)
    assert any(not h.accepted for h in r.history[:-1])  # rejected tries have rows
    assert float(rows[0][1]) == pytest.approx(r.initial_robust_cost, rel=1e-6)
    for rec, row in zip(r.history[:-1], rows[1:], strict=True):
        assert int(row[0]) == rec.iteration
        assert float(row[1]) == pytest.approx(rec.cost, rel=1e-6)
        assert float(row[2]) == pytest.approx(rec.cost_change, rel=1e-2, abs=1e-300)
        assert float(row[6]) == pytest.approx(rec.tr_radius, rel=1e-2)


# ----------------------------------------------------------------------------- the API
def _tiny():
    g = FactorGraph()
    x = g.add_variables(np.array([[3.0, -1.0]]), name="x")
    g.add(CustomFactor(lambda v: np.concatenate([v[:, :1] ** 2 - 4.0, v[:, 1:] - 2.0], 1),
                       [(x, 0)], 2))
    g.add(PriorFactor(x, 0, np.array([[2.0, 2.0]])))
    return g, x


def test_registry_names_and_instances():
    assert set(STRATEGIES) == {"lm", "gn", "dogleg", "trust-region"}
    # the command line lists them literally (building its parser imports no solver code)
    from microlie.optim.command import SOLVERS

    assert SOLVERS == tuple(STRATEGIES)
    for name, cls in STRATEGIES.items():
        assert issubclass(cls, Strategy) and cls.name == name
        assert isinstance(make_strategy(name), cls)
    g, x = _tiny()
    for name in STRATEGIES:
        assert g.optimize(solver=name).solver == name


def test_keyword_options_equal_the_strategy_object():
    g, x = _tiny()
    a = g.optimize(solver="lm", lambda_initial=1e-2, damping="diagonal", rel_tol=1e-9)
    b = g.optimize(solver=LevenbergMarquardt(lambda_initial=1e-2, damping="diagonal",
                                             rel_tol=1e-9))
    assert [h.cost for h in a.history] == [h.cost for h in b.history]
    assert [h.damping for h in a.history] == [h.damping for h in b.history]
    assert a.history[0].damping == pytest.approx(1e-3)  # 1e-2 / 10 after the accepted step
    c = g.optimize(solver="dogleg", radius_initial=0.1)
    assert c.history[0].step_norm == pytest.approx(0.1)  # the first step is cut to the radius


def test_a_strategy_instance_is_reusable():
    _, start = synthetic_scene(3, 20, noise=1.0, seed=2)
    g, _ = bundle_graph(start, [0])
    tr = TrustRegion(radius_initial=10.0)
    a = g.optimize(solver=tr, gauge="none")
    b = g.optimize(solver=tr, gauge="none")
    assert [h.cost for h in a.history] == [h.cost for h in b.history]
    assert tr.radius_initial == 10.0 and repr(tr).startswith("TrustRegion(radius_initial=10.0")


def test_bad_strategies_and_options_are_refused():
    g, x = _tiny()
    with pytest.raises(ValueError, match="solver must be one of 'lm'"):
        g.optimize(solver="newton")
    with pytest.raises(TypeError, match="'gn' .*takes no option 'lambda_initial'"):
        g.optimize(solver="gn", lambda_initial=1.0)
    with pytest.raises(TypeError, match="'trust-region' .*takes no option 'rel_tol'"):
        g.optimize(solver="trust-region", rel_tol=1e-3)
    with pytest.raises(TypeError, match="go to the strategy's constructor"):
        g.optimize(solver=GaussNewton(), rel_tol=1e-3)
    with pytest.raises(ValueError, match="lambda_factor must be > 1"):
        LevenbergMarquardt(lambda_factor=1.0)
    with pytest.raises(ValueError, match="radius_initial must be positive"):
        TrustRegion(radius_initial=0.0)
    with pytest.raises(ValueError, match="rel_tol must be >= 0"):
        Dogleg(rel_tol=-1.0)
    with pytest.raises(ValueError, match="max_iter must be an integer >= 0"):
        g.optimize(max_iter=-1)


def test_trust_region_stops():
    # a start at the minimum: the gradient test before any try
    g = FactorGraph()
    x = g.add_variables(np.array([[1.0]]), name="x")
    g.add(PriorFactor(x, 0, np.array([[1.0]])))
    r = g.optimize(solver="trust-region")
    assert r.converged and "gradient tolerance" in r.message and r.iterations == 0
    # max_iter counts tries
    _, start = synthetic_scene(3, 20, noise=1.0, seed=2)
    g, _ = bundle_graph(start, [0])
    r = g.optimize(solver="trust-region", gauge="none", max_iter=2)
    assert r.termination == "no_convergence" and r.iterations == 2 == len(r.history)
    assert "max_iter" in r.message
    # a wrong-sign Jacobian: every step raises the cost; the radius shrinks until the
    # candidates change it by less than function_tolerance: not a convergence
    g = FactorGraph()
    x = g.add_variables(np.array([[3.0]]), name="x")
    g.add(CustomFactor(lambda v: (v - 1.0, [-np.ones((len(v), 1, 1))]), [(x, 0)], 1,
                       jac="analytic"))
    r = g.optimize(solver="trust-region")
    assert r.termination == "failure" and "without decreasing the cost" in r.message
    assert r.final_cost == r.initial_cost == 2.0 and r.accepted_steps == 0
    assert not any(h.accepted for h in r.history)
