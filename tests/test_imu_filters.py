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
