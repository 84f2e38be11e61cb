"""Filter consistency on synthetic IMU data from EuRoC V1_02: 100 Monte Carlo runs (batched),
average NEES inside the 95% chi-square band for the ESKF (right and left error) and the
invariant EKF; dropping the bias-attitude correlation breaks it."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file
from scipy.stats import chi2

from microlie import R
from microlie.imu import EUROC_ADIS16448, SmoothTrajectory, simulate_imu
from microlie.imu.filters import ESKF_STATE, IEKF_STATE, ErrorStateEKF, InvariantEKF
from microlie.imu.simulate import load_euroc_groundtruth

M = 100  # Monte Carlo runs
DURATION = 6.0
FIX_EVERY, FIX_SIGMA = 20, 0.05  # position fixes at 10 Hz, 5 cm
# initial standard deviations (attitude rad, position m, velocity m/s, b_g rad/s, b_a m/s^2)
# in the ESKF order; larger bias uncertainties (0.01 rad/s) make attitude errors of several
# degrees within seconds and the linearisation visibly optimistic (NEES ~17 after 6 s)
P0_STD = np.r_[np.full(3, 0.01), np.full(3, 0.05), np.full(3, 0.05), np.full(3, 0.003),
               np.full(3, 0.02)]


@pytest.fixture(scope="module")
def data():
    t, poses = load_euroc_groundtruth(data_file("trajectory/evo/V102_groundtruth.csv"))
    traj = SmoothTrajectory.from_poses(t, poses, knot_dt=0.1)
    return simulate_imu(traj, duration=DURATION, start=traj.t0 + 15.0, rng=7, runs=M)


def _truth(kind, data, k):
    X = data.truth[k]
    bg, ba = data.bias_gyro[min(k, len(data.t) - 1)], data.bias_accel[min(k, len(data.t) - 1)]
    if kind == "iekf":
        from microlie import SE23

        Xb = SE23(np.broadcast_to(np.asarray(X.params), (M, 10)))
        return IEKF_STATE.from_parts(Xb, R(3)(bg), R(3)(ba))
    from microlie import SO3

    Rq = SO3(np.broadcast_to(np.asarray(X.rotation().params), (M, 4)))
    vec = [np.broadcast_to(np.asarray(a), (M, 3)) for a in (X.translation(), X.velocity())]
    return ESKF_STATE.from_parts(Rq, R(3)(vec[0]), R(3)(vec[1]), R(3)(bg), R(3)(ba))


def _run(kind, data, drop_correlation=False):
    rng = np.random.default_rng(11)
    if kind == "iekf":
        std = np.r_[P0_STD[3:6], P0_STD[0:3], P0_STD[6:15]]  # (rho, phi, nu, b_g, b_a)
    else:
        std = P0_STD
    P0 = np.diag(std**2)
    truth0 = _truth(kind, data, 0)
    e0 = rng.standard_normal((M, 15)) * std
    # the initial estimate: truth = estimate (+) e0 on the filter's side
    if kind == "iekf":
        est = type(truth0).exp(-e0) @ truth0  # truth = Exp(e0) estimate
        f = InvariantEKF(est, P0, **EUROC_ADIS16448)
    else:
        side = "left" if kind == "eskf-left" else "right"
        G = type(truth0)
        est = truth0 @ G.exp(-e0) if side == "right" else G.exp(-e0) @ truth0
        f = ErrorStateEKF(est, P0, side=side, **EUROC_ADIS16448)
    nees = []
    th, bgs = (slice(3, 6), slice(9, 12)) if kind == "iekf" else (slice(0, 3), slice(9, 12))
    for k0 in range(0, len(data.t), FIX_EVERY):
        s = slice(k0, k0 + FIX_EVERY)
        for kk in range(s.start, min(s.stop, len(data.t))):
            f.predict(data.accel[kk], data.gyro[kk], data.dt)
            if drop_correlation:
                f.cov[..., th, bgs] = 0.0
                f.cov[..., bgs, th] = 0.0
        k = min(s.stop, len(data.t))
        z = np.asarray(data.truth[k].translation()) + FIX_SIGMA * rng.standard_normal((M, 3))
        f.update_position(z, FIX_SIGMA)
        nees.append(f.nees(_truth(kind, data, k)))
    return np.array(nees)  # (fixes, M)


def _band(dof=15, runs=M, p=0.95):
    return chi2.ppf([(1 - p) / 2, (1 + p) / 2], dof * runs) / runs


@pytest.mark.parametrize("kind", ["eskf-right", "eskf-left", "iekf"])
def test_average_nees_inside_the_95_percent_band(kind, data):
    nees = _run(kind, data)
    lo, hi = _band()
    final = nees[-1].mean()
    assert lo < final < hi, (kind, final, lo, hi)
    # and over the run: at most 10% of the fix times outside the pointwise band
    outside = np.mean((nees.mean(1) < lo) | (nees.mean(1) > hi))
    assert outside <= 0.1, (kind, nees.mean(1))


def test_dropping_the_bias_attitude_correlation_makes_the_eskf_inconsistent(data):
    nees = _run("eskf-right", data, drop_correlation=True)
    lo, hi = _band()
    assert nees[-1].mean() > hi, nees.mean(1)


# ------------------------------------------------------------- issue 19 item 7: hostile input


def _filter(kind, batch=()):
    P0 = np.broadcast_to(np.eye(15) * 1e-4, (*batch, 15, 15))
    noise = dict(gyro_noise=1.7e-4, accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
    if kind == "iekf":
        X = IEKF_STATE.exp(np.random.default_rng(3).standard_normal((*batch, 15)) * 0.1)
        return InvariantEKF(X, P0, **noise)
    X = ESKF_STATE.exp(np.random.default_rng(3).standard_normal((*batch, 15)) * 0.1)
    return ErrorStateEKF(X, P0, side="left" if kind == "eskf-left" else "right", **noise)


def _snapshot(f):
    return [np.array(x) for x in (f.Rm, f.p, f.v, f.bg, f.ba, f.cov)]


def _assert_unchanged(f, snap):
    for a, b in zip(_snapshot(f), snap, strict=True):
        np.testing.assert_array_equal(a, b)


def _px(f):
    """``(h, H)`` of a measurement of the position's x and y: ``p = p_hat + dp`` (ESKF) or
    ``p_hat + rho + phi x p_hat`` (IEKF), the first two rows of the position Jacobian."""
    return f.p[..., :2], f._position_jacobian()[..., :2, :]


@pytest.mark.parametrize("kind", ["eskf-right", "eskf-left", "iekf"])
def test_issue19_item7_update_refuses_bad_noise_and_measurements_and_changes_nothing(kind):
    f = _filter(kind)
    snap = _snapshot(f)
    h, H = _px(f)
    z = h + 0.01
    bad = [
        (dict(noise=-2e-4 * np.eye(2)), "noise is not positive semi-definite"),
        (dict(noise=[[1e-4, 5e-5], [0.0, 1e-4]]), "noise is not symmetric"),
        (dict(noise=np.full((2, 2), np.nan)), "noise contains NaN"),
        (dict(noise=np.eye(3)), "noise"),
        (dict(noise=np.broadcast_to(np.eye(2), (4, 2, 2))), r"noise must be \(2, 2\)"),
        (dict(z=[np.nan, 0.0]), "z contains NaN"),
        (dict(z=[0.0, 0.0, 0.0]), "z must be"),
        (dict(h=np.array([np.inf, 0.0])), "h contains NaN"),
        (dict(H=np.full((2, 15), np.nan)), "H contains NaN"),
        (dict(H=np.zeros((2, 14))), "H must be"),
        (dict(H=np.zeros((2, 15)), noise=np.zeros((2, 2))), "singular"),  # S = 0
        # finite inputs whose innovation overflows: the failure is found after the update
        (dict(z=[1e308, 0.0], h=[-1e308, 0.0]), "NaN or infinite"),
        (dict(gate=1.0), "gate must be a probability"),
    ]
    for change, msg in bad:
        args = dict(z=z, h=h, H=H, noise=1e-4 * np.eye(2)) | change
        with pytest.raises(ValueError, match=msg):
            f.update(args.pop("z"), args.pop("h"), args.pop("H"), args.pop("noise"), **args)
        _assert_unchanged(f, snap)
    # and the filter still works: a fix halfway trusted moves p by half the innovation
    # (P = 1e-4 I on p for the ESKF: K = P / (P + R) = 1/2)
    res = f.update(z, h, H, 1e-4 * np.eye(2))
    assert res.applied and res.threshold == np.inf
    if kind != "iekf":
        np.testing.assert_allclose(f.p[:2], snap[1][:2] + 0.005, rtol=1e-12)


@pytest.mark.parametrize("kind", ["eskf-right", "iekf"])
def test_issue19_item7_predict_is_all_or_nothing(kind):
    f = _filter(kind, batch=(2,))
    snap = _snapshot(f)
    a = np.tile([0.1, -0.2, 9.81], (5, 2, 1))
    w = np.tile([0.01, 0.02, -0.03], (5, 2, 1))
    for name, arr in (("accel", a), ("gyro", w)):
        for value in (np.nan, np.inf):
            x = arr.copy()
            x[2, 1, 0] = value  # the third sample of the second filter
            args = (x, w) if name == "accel" else (a, x)
            with pytest.raises(ValueError, match=f"{name} sample 2 contains NaN"):
                f.predict(*args, 0.005)
            _assert_unchanged(f, snap)
    for dt in (np.nan, [0.005, 0.005, -1.0, 0.005, 0.005], [0.005] * 4):
        with pytest.raises(ValueError, match="dt must"):
            f.predict(a, w, dt)
        _assert_unchanged(f, snap)
    big = a.copy()
    big[2] = 1e300  # finite, but the state overflows at the third sample
    with pytest.raises(ValueError, match="NaN or infinite"):
        f.predict(big, w, 0.005)
    _assert_unchanged(f, snap)
    with pytest.raises(ValueError, match=r"\(N, \*batch, 3\)"):
        f.predict(a[:, :1], w[:, :1], 0.005)
    # the good batch runs, sample by sample as one call
    g = _filter(kind, batch=(2,))
    f.predict(a, w, 0.005)
    for k in range(5):
        g.predict(a[k], w[k], 0.005)
    for x, y in zip(_snapshot(f), _snapshot(g), strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("kind", ["eskf-right", "iekf"])
def test_issue19_item7_innovation_gate_against_the_chi_square_quantile(kind):
    p = 0.99
    # with m = 2 the chi-square CDF is 1 - exp(-x/2): the quantile is -2 log(1 - p)
    thr = -2.0 * np.log1p(-p)
    f = _filter(kind, batch=(3,))
    snap = _snapshot(f)
    h, H = _px(f)
    R = 1e-4 * np.eye(2)
    S = H @ f.cov @ np.swapaxes(H, -1, -2) + R
    # innovations along the first eigenvector of each S, of NIS thr (1 - 1e-6), thr (1 + 1e-6)
    # and 0.5 thr
    lam, V = np.linalg.eigh(S)
    scale = np.array([1 - 1e-6, 1 + 1e-6, 0.5]) * thr
    y = V[..., :, 0] * np.sqrt(lam[..., 0] * scale)[:, None]
    res = f.update(h + y, h, H, R, gate=p)
    assert res.threshold == pytest.approx(thr, rel=1e-12)
    np.testing.assert_allclose(res.nis, scale, rtol=1e-9)
    assert res.applied.tolist() == [True, False, True]
    # the rejected filter is unchanged, the others equal an ungated update
    g = _filter(kind, batch=(3,))
    g.update(h + y, h, H, R)
    for x, y0, y1 in zip(_snapshot(f), snap, _snapshot(g), strict=True):
        np.testing.assert_array_equal(x[1], y0[1])
        np.testing.assert_array_equal(x[[0, 2]], y1[[0, 2]])
    assert not np.array_equal(f.p[0], snap[1][0]) and not np.array_equal(f.cov[2], snap[5][2])
    # m = 3: the threshold is SciPy's chi-square quantile; a single filter
    z = f.p[0] + 1.0
    r3 = _filter(kind).update_position(z, 0.05, gate=0.997)
    assert r3.threshold == pytest.approx(chi2.ppf(0.997, 3), rel=1e-12)
    assert not r3.applied and r3.nis > r3.threshold


def test_issue19_item19_each_class_states_its_tangent_order_in_repr_and_docstring():
    """The three orders differ (kept, see the filters' module docstring); each class names its
    own in its docstring, ``tangent_order`` and ``repr``, and the names match the numbers."""
    from microlie.imu import Preintegration

    eskf, iekf = _filter("eskf-right", batch=(2,)), _filter("iekf")
    pim = Preintegration(gyro_noise=1e-3, accel_noise=2e-2)
    n, dt = 200, 0.01
    pim.integrate(np.tile([0.0, 0.0, 9.81], (n, 1)), np.zeros((n, 3)), dt)
    cases = [(eskf, "(dtheta, dp, dv, db_g, db_a)", "dp"),
             (iekf, "(rho, phi, nu, db_g, db_a)", "rho"),
             (pim, "(dphi, dv, dp)", None)]
    for obj, order, _ in cases:
        assert f"tangent_order={order}" in repr(obj), repr(obj)
        assert f"``{order}``" in " ".join(type(obj).__doc__.split())
        assert "(" + ", ".join(obj.tangent_order) + ")" == order
    assert "side='right'" in repr(eskf) and "batch_shape=(2,)" in repr(eskf)
    # the named position block is where a position fix's Jacobian has the identity
    for f, _, pos in cases[:2]:
        k = 3 * f.tangent_order.index(pos)
        np.testing.assert_array_equal(f._position_jacobian()[..., :, k:k + 3],
                                      np.broadcast_to(np.eye(3), (*f.batch_shape, 3, 3)))
    # preintegration at rest: d(dv)/d(b_a) = -T I, d(dp)/d(b_a) = -T^2/2 I, d(dphi)/d(b_a) = 0
    T = n * dt
    J = pim.bias_jacobian
    rows = {name: slice(3 * i, 3 * i + 3) for i, name in enumerate(pim.tangent_order)}
    np.testing.assert_allclose(J[rows["dphi"], 3:6], 0.0, atol=1e-15)
    np.testing.assert_allclose(J[rows["dv"], 3:6], -T * np.eye(3), atol=1e-12)
    np.testing.assert_allclose(J[rows["dp"], 3:6], -0.5 * T * T * np.eye(3), atol=1e-12)
