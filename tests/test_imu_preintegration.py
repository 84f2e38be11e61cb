"""IMU preintegration against GTSAM 4.3 (saved fixtures, made by
tests/fixtures/imu/make_gtsam_fixtures.py), against a brute-force integration at 100x the rate,
against Forster's sequential recursions, and the IMU residual's Jacobians against finite
differences."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import fd_jacobian

from microlie import SE23, SO3
from microlie.imu import Preintegration
from microlie.imu.residual import Deltas, imu_residual

FIX = np.load(Path(__file__).parent / "fixtures" / "imu" / "gtsam_preintegration.npz")
# GTSAM (rotation, position, velocity) -> ours (rotation, velocity, position)
ORDER = np.r_[0:3, 6:9, 3:6]


def _pim(scheme="manifold", coriolis=False, bias_gyro=None, bias_accel=None):
    f = FIX
    pim = Preintegration(gyro_noise=float(f["gyro_noise"]), accel_noise=float(f["accel_noise"]),
                         bias_gyro=f["bias_gyro"] if bias_gyro is None else bias_gyro,
                         bias_accel=f["bias_accel"] if bias_accel is None else bias_accel,
                         gravity=(0.0, 0.0, -float(f["gravity"])), scheme=scheme,
                         omega_coriolis=f["omega_coriolis"] if coriolis else None)
    return pim.integrate(f["accel"], f["gyro"], float(f["dt"]))


def _blockdiag(*blocks):
    out = np.zeros((9, 9))
    for k, b in enumerate(blocks):
        out[3 * k:3 * k + 3, 3 * k:3 * k + 3] = b
    return out


@pytest.mark.parametrize("scheme,name", [("manifold", "man"), ("tangent", "tan")])
def test_deltas_covariance_and_bias_jacobians_match_gtsam(scheme, name):
    pim = _pim(scheme)
    dR = FIX[f"{name}_deltaRij"]
    np.testing.assert_allclose(pim.delta_rotation.matrix(), dR, atol=1e-9)
    np.testing.assert_allclose(pim.delta_velocity, FIX[f"{name}_deltaVij"], atol=1e-9)
    np.testing.assert_allclose(pim.delta_position, FIX[f"{name}_deltaPij"], atol=1e-9)
    assert abs(pim.dt - float(FIX[f"{name}_deltaTij"])) < 1e-12
    # map GTSAM's covariance to ours: reorder, then the frames of its error coordinates
    P = FIX[f"{name}_preintMeasCov"][np.ix_(ORDER, ORDER)]
    if scheme == "manifold":  # GTSAM: v + dR dv_g, p + dR dp_g  ->  ours additive: dR dv_g
        M = _blockdiag(np.eye(3), dR, dR)
    else:  # GTSAM: additive on theta = Log dR;  ours: dR Exp(dphi), dphi = Jr(theta) dtheta
        M = _blockdiag(SO3.jr(SO3.from_matrix(dR).log()), np.eye(3), np.eye(3))
    ref = M @ P @ M.T
    rel = np.abs(pim.covariance - ref).max() / np.abs(ref).max()
    assert rel < 1e-6, rel
    np.testing.assert_allclose(pim.covariance, ref, rtol=1e-6, atol=1e-6 * np.abs(ref).max())
    J = FIX[f"{name}_bias_jacobian"]  # rows (Log dR, dv, dp), columns (gyro, accel)
    np.testing.assert_allclose(pim.bias_jacobian, J, rtol=1e-6, atol=1e-6 * np.abs(J).max())


def test_schemes_differ_as_documented():
    """The two GTSAM classes differ by ~1e-4 rad over these 400 samples: compare like with
    like (each of ours matches its own GTSAM class above to 1e-9)."""
    d = (_pim("tangent").delta_rotation.inverse() @ _pim("manifold").delta_rotation).log()
    assert 1e-6 < np.linalg.norm(d) < 1e-3
    man = SO3.from_matrix(FIX["man_deltaRij"])
    tan = SO3.from_matrix(FIX["tan_deltaRij"])
    np.testing.assert_allclose((tan.inverse() @ man).log(), d, atol=1e-9)


def _states():
    return (SE23(FIX["state_i"]), SE23(FIX["state_j"]), FIX["state_bias"])


def _to_gtsam_error(r, Xi, Xj):
    """Ours (R, v, p) -> GTSAM's X_j.localCoordinates(prediction): (-r_R, -Rji r_p, -Rji r_v)."""
    Rji = np.swapaxes(Xj.rotation().matrix(), -1, -2) @ Xi.rotation().matrix()
    rp = (Rji @ r[:, 6:9, None])[..., 0]
    rv = (Rji @ r[:, 3:6, None])[..., 0]
    return -np.concatenate([r[:, :3], rp, rv], -1)


@pytest.mark.parametrize("coriolis", [False, True])
@pytest.mark.parametrize("scheme,key", [("tangent", "err"), ("manifold", "man_err")])
def test_imu_residual_equals_gtsam_imufactor_error(scheme, key, coriolis):
    """Forster's residual, mapped, is GTSAM's ImuFactor error in its ComponentWise mode."""
    Xi, Xj, b = _states()
    deltas = Deltas([_pim(scheme, coriolis)] * len(b))
    r = imu_residual(deltas, Xi, Xj, b)
    ref = FIX[("cor_" if coriolis else "") + key]
    np.testing.assert_allclose(_to_gtsam_error(r, Xi, Xj), ref, atol=1e-9)


@pytest.mark.parametrize("coriolis", [False, True])
def test_logmap_residual_equals_gtsam_default_imufactor_error(coriolis):
    """GTSAM 4.3's default ImuFactor error (Logmap mode) is -Log(X_p^-1 X_j) in NavState's
    order (rotation, position, velocity)."""
    Xi, Xj, b = _states()
    deltas = Deltas([_pim("tangent", coriolis)] * len(b))
    r = imu_residual(deltas, Xi, Xj, b, error="logmap")  # (phi, nu, rho)
    ref = FIX[("cor_" if coriolis else "") + "log_err"]
    np.testing.assert_allclose(-r[:, np.r_[0:3, 6:9, 3:6]], ref, atol=1e-9)


@pytest.mark.parametrize("error", ["forster", "logmap"])
@pytest.mark.parametrize("scheme", ["manifold", "tangent"])
@pytest.mark.parametrize("coriolis", [False, True])
def test_imu_residual_jacobians_against_finite_differences(scheme, coriolis, error):
    Xi, Xj, b = _states()
    pim = _pim(scheme, coriolis)
    deltas = Deltas([pim])
    for k in range(2):
        args = [Xi[k:k + 1], Xj[k:k + 1], b[k:k + 1]]
        _, Ji, Jj, Jb = imu_residual(deltas, *args, jac=True, error=error)

        def f(xi, xj, bb):
            return imu_residual(deltas, xi, xj, bb, error=error)

        for idx, J in enumerate((Ji, Jj, Jb)):
            num = fd_jacobian(f, args, idx)
            np.testing.assert_allclose(J, num, atol=2e-6 * max(1.0, np.abs(num).max()))


def test_prediction_makes_the_residual_zero_and_bias_correction_is_first_order():
    pim = _pim()
    Xi = SE23.random(1, rng=3)
    bg, ba = FIX["bias_gyro"] + 1e-3, FIX["bias_accel"] - 2e-2
    Xj = pim.predict(Xi, bg, ba)
    for error in ("forster", "logmap"):
        r = imu_residual(Deltas([pim]), Xi, Xj, np.concatenate([bg, ba])[None], error=error)
        np.testing.assert_allclose(r, 0.0, atol=1e-12)
    # first-order bias correction vs re-integrating with the new biases: error O(db^2)
    errs = []
    for s in (1.0, 0.5, 0.25):
        dbg, dba = s * np.array([2e-3, -1e-3, 3e-3]), s * np.array([0.05, 0.02, -0.04])
        R, v, p = pim.correct(FIX["bias_gyro"] + dbg, FIX["bias_accel"] + dba)
        ref = _pim(bias_gyro=FIX["bias_gyro"] + dbg, bias_accel=FIX["bias_accel"] + dba)
        errs.append(np.linalg.norm(ref.delta_velocity - v) + np.linalg.norm(
            ref.delta_position - p) + np.linalg.norm((ref.delta_rotation.inverse() @ R).log()))
    slope = np.polyfit(np.log([1.0, 0.5, 0.25]), np.log(errs), 1)[0]
    assert 1.8 < slope < 2.2, errs


def _forster_sequential(a, w, dt, sg, sa):
    """Forster et al. 2017, eqs. 38 (covariance) and Appendix B (bias Jacobians), one sample
    at a time with rotation matrices (``dt`` scalar or per sample, noise densities scalar or
    per axis)."""
    from scipy.spatial.transform import Rotation

    def hat(x):
        return np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]])

    def jr(x):  # MATH.md eq. 8
        t = np.linalg.norm(x)
        W = hat(x)
        return np.eye(3) - (1 - np.cos(t)) / t**2 * W + (t - np.sin(t)) / t**3 * W @ W

    R, v, p = np.eye(3), np.zeros(3), np.zeros(3)
    P, J = np.zeros((9, 9)), np.zeros((9, 6))
    dts = np.broadcast_to(dt, (len(a),))
    for k in range(len(a)):
        dt = dts[k]
        dRk = Rotation.from_rotvec(w[k] * dt).as_matrix()
        Jr = jr(w[k] * dt)
        Ah = R @ hat(a[k])
        A = np.eye(9)
        A[0:3, 0:3] = dRk.T
        A[3:6, 0:3] = -Ah * dt
        A[6:9, 0:3] = -0.5 * Ah * dt * dt
        A[6:9, 3:6] = np.eye(3) * dt
        B = np.zeros((9, 6))
        B[0:3, 0:3] = Jr * dt
        B[3:6, 3:6] = R * dt
        B[6:9, 3:6] = 0.5 * R * dt * dt
        Q = np.diag(np.r_[np.broadcast_to(sg, 3) ** 2, np.broadcast_to(sa, 3) ** 2] / dt)
        P = A @ P @ A.T + B @ Q @ B.T
        J = A @ J - B
        p = p + v * dt + 0.5 * R @ a[k] * dt * dt
        v = v + R @ a[k] * dt
        R = R @ dRk
    return R, v, p, P, J


def test_vectorised_scheme_equals_forster_recursions_and_is_split_invariant():
    rng = np.random.default_rng(5)
    n = 300
    a = rng.standard_normal((n, 3)) + [0, 0, 9.81]
    w = 0.8 * rng.standard_normal((n, 3))
    dt = 0.005
    R, v, p, P, J = _forster_sequential(a, w, dt, 1e-3, 2e-2)
    pim = Preintegration(gyro_noise=1e-3, accel_noise=2e-2).integrate(a, w, dt)
    np.testing.assert_allclose(pim.delta_rotation.matrix(), R, atol=1e-12)
    np.testing.assert_allclose(pim.delta_velocity, v, atol=1e-12)
    np.testing.assert_allclose(pim.delta_position, p, atol=1e-12)
    np.testing.assert_allclose(pim.covariance, P, rtol=1e-9, atol=1e-12 * np.abs(P).max())
    np.testing.assert_allclose(pim.bias_jacobian, J, atol=1e-11)
    # calling integrate repeatedly (uneven pieces, per-sample dt) gives the same result
    pim2 = Preintegration(gyro_noise=1e-3, accel_noise=2e-2)
    for s in (slice(0, 1), slice(1, 117), slice(117, 300)):
        pim2.integrate(a[s], w[s], np.full(s.stop - s.start, dt))
    np.testing.assert_allclose(pim2.covariance, P, rtol=1e-9, atol=1e-12 * np.abs(P).max())
    np.testing.assert_allclose(pim2.bias_jacobian, J, atol=1e-11)
    np.testing.assert_allclose(pim2.delta_position, p, atol=1e-12)


def test_variable_dt_and_per_axis_noise():
    """Jittered sample times (each dt different) and per-axis noise densities."""
    rng = np.random.default_rng(6)
    n = 250
    a = rng.standard_normal((n, 3)) + [0, 0, 9.81]
    w = 0.8 * rng.standard_normal((n, 3))
    dt = 0.005 * (1 + 0.2 * rng.uniform(-1, 1, n))
    sg, sa = np.array([1e-3, 2e-3, 3e-3]), np.array([2e-2, 1e-2, 3e-2])
    Rr, vr, pr, Pr, Jr = _forster_sequential(a, w, dt, sg, sa)
    pim = Preintegration(gyro_noise=sg, accel_noise=sa).integrate(a[:100], w[:100], dt[:100])
    pim.integrate(a[100:], w[100:], dt[100:])
    np.testing.assert_allclose(pim.delta_rotation.matrix(), Rr, atol=1e-12)
    np.testing.assert_allclose(pim.delta_position, pr, atol=1e-12)
    np.testing.assert_allclose(pim.covariance, Pr, rtol=1e-9, atol=1e-12 * np.abs(Pr).max())
    np.testing.assert_allclose(pim.bias_jacobian, Jr, atol=1e-11)
    assert abs(pim.dt - dt.sum()) < 1e-15


def _omega(t):
    return np.stack([0.6 * np.sin(1.3 * t), 0.4 * np.cos(0.7 * t), 0.9 * np.sin(0.5 * t)], -1)


def _force(t):
    return np.stack([1.5 * np.cos(2.0 * t), 0.8 * np.sin(1.1 * t), 9.81 + 0.5 * np.sin(3 * t)], -1)


def _ode_reference(T):
    """R' = R hat(w), v' = R f, p' = v by an adaptive Runge-Kutta solver (independent of us)."""
    from scipy.integrate import solve_ivp

    def rhs(t, y):
        R = y[:9].reshape(3, 3)
        w, f = _omega(t), _force(t)
        return np.concatenate([(R @ SO3.hat(w)).ravel(), R @ f, y[9:12]])

    y0 = np.concatenate([np.eye(3).ravel(), np.zeros(6)])
    y = solve_ivp(rhs, (0.0, T), y0, method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1]
    return y[:9].reshape(3, 3), y[9:12], y[12:15]


def _sampled(n, dt):
    """Samples at the start of each interval (what the discrete scheme assumes)."""
    t = np.arange(n) * dt
    return _force(t), _omega(t)


def test_against_brute_force_integration_at_100x_the_rate():
    """2 s of a continuous motion: the 200 Hz preintegration against a brute-force integration
    at 100x the rate (20 kHz) and both against an adaptive ODE solution. The scheme is first
    order in dt (Euler in time, exact rotation increments): its error halves when the rate
    doubles, and the 20 kHz integration is ~100x closer."""
    T = 2.0
    R, v, p = _ode_reference(T)

    def errors(rate):
        n = int(round(T * rate))
        pim = Preintegration(gyro_noise=0.0, accel_noise=0.0).integrate(*_sampled(n, T / n),
                                                                        T / n)
        return np.array([np.linalg.norm(SO3.hat((SO3.from_matrix(R).inverse()
                                                 @ pim.delta_rotation).log())),
                         np.linalg.norm(pim.delta_velocity - v),
                         np.linalg.norm(pim.delta_position - p)])

    e200, e400, e20k = errors(200), errors(400), errors(20000)
    np.testing.assert_allclose(e200 / e400, 2.0, rtol=0.05)  # first order
    np.testing.assert_allclose(e200 / e20k, 100.0, rtol=0.05)
    assert e200[1] < 0.05 and e200[2] < 0.05  # m/s and m over 2 s of motion at 200 Hz
    assert e20k.max() < 5e-4


def test_bad_input():
    pim = Preintegration(gyro_noise=1e-3, accel_noise=1e-2)
    with pytest.raises(ValueError, match="shape"):
        pim.integrate(np.zeros((5, 3)), np.zeros((4, 3)), 0.01)
    with pytest.raises(ValueError, match="dt"):
        pim.integrate(np.zeros((5, 3)), np.zeros((5, 3)), np.zeros(5))
    with pytest.raises(ValueError, match="dt must be a scalar"):
        pim.integrate(np.zeros((5, 3)), np.zeros((5, 3)), np.ones(4))
    with pytest.raises(ValueError, match="NaN"):
        pim.integrate(np.full((5, 3), np.nan), np.zeros((5, 3)), 0.01)
    with pytest.raises(ValueError, match="bias_gyro"):
        Preintegration(gyro_noise=1e-3, accel_noise=1e-2, bias_gyro=np.zeros(4))
    with pytest.raises(ValueError, match="scheme"):
        Preintegration(gyro_noise=1e-3, accel_noise=1e-2, scheme="euler")


@pytest.mark.parametrize("error", ["forster", "logmap"])
def test_imu_factor_cost_in_a_graph(error):
    """FactorGraph.cost with an ImuFactor batch is 0.5 r^T Sigma^-1 r summed, with r from
    imu_residual and Sigma the preintegration covariance (mapped for the Logmap form)."""
    from microlie.imu import ImuFactor
    from microlie.optim import FactorGraph

    Xi, Xj, b = _states()
    g = FactorGraph()
    x = g.add_variables(SE23(np.concatenate([Xi.params, Xj.params])))
    bv = g.add_variables(np.concatenate([b, b]))
    for scheme in ("manifold", "tangent"):
        idx = np.arange(5)
        g.add(ImuFactor(x, bv, idx, idx + 5, [_pim(scheme)] * 5, error=error))
    total = 0.0
    for scheme in ("manifold", "tangent"):
        pim = _pim(scheme)
        r = imu_residual(Deltas([pim] * 5), Xi, Xj, b, error=error)
        S = pim.covariance
        if error == "logmap":
            M = _blockdiag(np.eye(3), *[pim.delta_rotation.matrix().T] * 2)
            S = M @ S @ M.T
        total += 0.5 * np.sum(r * np.linalg.solve(S, r.T).T)
    assert abs(g.cost() - total) < 1e-9 * total


def test_sample_by_sample_calls_equal_one_batch():
    """One integrate() call per sample (buffered internally, results read midway) gives the
    batch result."""
    rng = np.random.default_rng(9)
    n = 600
    a = rng.standard_normal((n, 3)) + [0, 0, 9.81]
    w = 0.5 * rng.standard_normal((n, 3))
    kw = dict(gyro_noise=1e-3, accel_noise=2e-2, bias_gyro=[0.01, 0, -0.02],
              bias_accel=[0.1, -0.1, 0.05])
    ref = Preintegration(**kw).integrate(a, w, 0.005)
    pim = Preintegration(**kw)
    for k in range(n):
        pim.integrate(a[k], list(w[k]), 0.005)
        if k == 250:
            assert pim.count == 251 and abs(pim.dt - 251 * 0.005) < 1e-12
    np.testing.assert_allclose(pim.delta_rotation.matrix(), ref.delta_rotation.matrix(),
                               atol=1e-13)
    np.testing.assert_allclose(pim.delta_position, ref.delta_position, atol=1e-12)
    np.testing.assert_allclose(pim.covariance, ref.covariance, rtol=1e-10,
                               atol=1e-13 * np.abs(ref.covariance).max())
    np.testing.assert_allclose(pim.bias_jacobian, ref.bias_jacobian, atol=1e-11)
    with pytest.raises(ValueError, match="NaN"):
        pim.integrate([np.nan, 0.0, 0.0], [0.0, 0.0, 0.0], 0.005)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-3, 0.7, 0.999, 1.001, 2.5, 3.1])
def test_tangent_scheme_jacobian_of_jr_times_x(angle):
    """d (Jr(theta) x) / d theta (closed form, series below |theta| = 1) against central
    differences of Jr (the Jacobian of the tangent scheme's rotation update)."""
    from microlie.imu.preintegration import _djr_times

    rng = np.random.default_rng(int(angle * 1000))
    th = rng.standard_normal(3)
    th *= angle / np.linalg.norm(th)
    x = rng.standard_normal(3)
    h = 1e-6
    fd = np.stack([(SO3.jr(th + h * e) @ x - SO3.jr(th - h * e) @ x) / (2 * h)
                   for e in np.eye(3)], -1)
    np.testing.assert_allclose(_djr_times(th, x), fd, atol=2e-9)


def _traced_peak(n):
    import tracemalloc

    rng = np.random.default_rng(0)
    a = rng.standard_normal((n, 3)) + [0, 0, 9.81]
    w = 0.5 * rng.standard_normal((n, 3))
    pim = Preintegration(gyro_noise=1e-3, accel_noise=2e-2, bias_gyro=[0.01, 0, 0])
    tracemalloc.start()
    try:
        pim.integrate(a, w, 0.005)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_issue19_item15_integrate_memory_does_not_grow_with_the_number_of_samples():
    """One call on 2e5 samples needs no more memory than on 5e4 (it held ~1 KB per sample:
    ratio ~4); benchmarks/preintegration_memory.py gives the 1e6 figures."""
    small, large = _traced_peak(50_000), _traced_peak(200_000)
    assert large < 1.5 * small, (small, large)
    assert large < 60e6, large


@pytest.mark.parametrize("dt", ["constant", "jittered"])
def test_issue19_item15_chunked_integration_equals_one_pass_and_the_recursions(monkeypatch, dt):
    """Chunks of 109 samples (9 chunks and a last one of 19, under SMALL) against one pass
    (CHUNK larger than the call) and Forster's per-sample recursions (independent)."""
    import microlie.imu.preintegration as pre

    rng = np.random.default_rng(12)
    n = 1000
    a = rng.standard_normal((n, 3)) + [0, 0, 9.81]
    w = 0.8 * rng.standard_normal((n, 3))
    d = np.full(n, 0.005) if dt == "constant" else 0.005 * (1 + 0.2 * rng.uniform(-1, 1, n))
    bg, ba = np.array([0.01, -0.02, 0.015]), np.array([0.1, -0.05, 0.2])
    kw = dict(gyro_noise=1e-3, accel_noise=2e-2, bias_gyro=bg, bias_accel=ba)
    monkeypatch.setattr(pre, "CHUNK", 10**9)
    one = Preintegration(**kw).integrate(a, w, d)
    monkeypatch.setattr(pre, "CHUNK", 109)
    chunked = Preintegration(**kw).integrate(a, w, d)
    assert chunked.count == n and abs(chunked.dt - d.sum()) < 1e-13
    R, v, p, P, J = _forster_sequential(a - ba, w - bg, d, 1e-3, 2e-2)
    for pim, tol in ((one, 1e-12), (chunked, 1e-12)):
        np.testing.assert_allclose(pim.delta_rotation.matrix(), R, atol=tol)
        np.testing.assert_allclose(pim.delta_velocity, v, atol=tol * 10)
        np.testing.assert_allclose(pim.delta_position, p, atol=tol * 10)
        np.testing.assert_allclose(pim.covariance, P, rtol=1e-9, atol=1e-12 * np.abs(P).max())
        np.testing.assert_allclose(pim.bias_jacobian, J, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(chunked.delta_rotation.matrix(), one.delta_rotation.matrix(),
                               atol=1e-14)
    np.testing.assert_allclose(chunked.delta_position, one.delta_position, rtol=1e-13)
    np.testing.assert_allclose(chunked.covariance, one.covariance, rtol=1e-11,
                               atol=1e-14 * np.abs(P).max())
    np.testing.assert_allclose(chunked.bias_jacobian, one.bias_jacobian, rtol=1e-11,
                               atol=1e-12)
