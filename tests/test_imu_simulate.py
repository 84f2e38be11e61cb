"""Synthetic IMU data from EuRoC V1_02 ground truth, and IMU smoothing with the solver."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file

from microlie import SE23, SO3
from microlie.imu import (
    EUROC_ADIS16448,
    BiasRandomWalkFactor,
    ImuFactor,
    Preintegration,
    SmoothTrajectory,
    simulate_imu,
)
from microlie.imu.simulate import load_euroc_groundtruth


@pytest.fixture(scope="module")
def euroc():
    t, poses = load_euroc_groundtruth(data_file("trajectory/evo/V102_groundtruth.csv"))
    return t, poses, SmoothTrajectory.from_poses(t, poses, knot_dt=0.1)


def test_smooth_fit_follows_the_ground_truth(euroc):
    t, poses, traj = euroc
    sel = (t > traj.t0 + 1) & (t < traj.t1 - 1)
    dp = traj.position(t[sel]) - np.asarray(poses.translation())[sel]
    dR = (SO3(np.asarray(poses.rotation().params)[sel]).inverse()
          @ traj.rotation(t[sel])).log()
    assert np.sqrt(np.mean(np.sum(dp**2, -1))) < 0.01  # m
    assert np.sqrt(np.mean(np.sum(dR**2, -1))) < 0.01  # rad
    # the rates are the derivatives of the fit (independent central differences)
    tt = np.linspace(traj.t0 + 2, traj.t1 - 2, 50)
    h = 1e-5
    w_fd = (traj.rotation(tt - h).inverse() @ traj.rotation(tt + h)).log() / (2 * h)
    np.testing.assert_allclose(traj.angular_velocity(tt), w_fd, atol=1e-5)
    a_fd = (traj.position(tt + h) - 2 * traj.position(tt) + traj.position(tt - h)) / h**2
    np.testing.assert_allclose(traj.position(tt, 2), a_fd, atol=2e-3)


def test_noise_and_bias_statistics(euroc):
    _, _, traj = euroc
    data = simulate_imu(traj, duration=60.0, start=traj.t0 + 1.0, rng=1, truth=False)
    dt = data.dt
    ng = data.gyro - data.true_gyro - data.bias_gyro
    na = data.accel - data.true_accel - data.bias_accel
    np.testing.assert_allclose(ng.std(0), EUROC_ADIS16448["gyro_noise"] / np.sqrt(dt), rtol=0.03)
    np.testing.assert_allclose(na.std(0), EUROC_ADIS16448["accel_noise"] / np.sqrt(dt), rtol=0.03)
    dbg = np.diff(data.bias_gyro, axis=0)
    np.testing.assert_allclose(dbg.std(0), EUROC_ADIS16448["gyro_walk"] * np.sqrt(dt), rtol=0.03)
    # gravity: a body at rest would read +9.81 up; the mean specific force is about that
    assert 9.0 < np.linalg.norm(data.true_accel.mean(0)) < 10.5


def test_truth_is_the_discrete_model_and_close_to_the_fit(euroc):
    _, _, traj = euroc
    data = simulate_imu(traj, duration=5.0, start=traj.t0 + 5.0, rng=2)
    # the truth integrates the bias-free samples exactly: preintegrating them predicts it
    pim = Preintegration(gyro_noise=0.0, accel_noise=0.0).integrate(data.true_accel,
                                                                     data.true_gyro, data.dt)
    Xn = pim.predict(data.truth[0])
    np.testing.assert_allclose(Xn.matrix(), data.truth[-1].matrix(), atol=1e-9)
    # and stays near the continuous fit (first-order scheme at 200 Hz over 5 s)
    cont = traj.state(data.t[-1] + data.dt)
    assert np.linalg.norm(np.asarray(cont.translation()) - data.truth[-1].translation()) < 0.05


def _smoothing_problem(data, every, sigma_fix, rng, perturb, fix_noise=True):
    from microlie.optim import FactorGraph, Isotropic, PriorFactor

    nk = len(data.t) // every
    kf = np.arange(nk + 1) * every
    X = data.truth[kf]
    pims = []
    for k in range(nk):
        s = slice(kf[k], kf[k + 1])
        pims.append(Preintegration(gyro_noise=EUROC_ADIS16448["gyro_noise"],
                                   accel_noise=EUROC_ADIS16448["accel_noise"]).integrate(
            data.accel[s], data.gyro[s], data.dt))
    g = FactorGraph()
    init = X.plus(perturb * rng.standard_normal((nk + 1, 9)))
    x = g.add_variables(init)
    b = g.add_variables(np.zeros((nk + 1, 6)))
    g.add(ImuFactor(x, b, np.arange(nk), np.arange(1, nk + 1), pims))
    T = every * data.dt
    g.add(BiasRandomWalkFactor(b, np.arange(nk), np.arange(1, nk + 1),
                               EUROC_ADIS16448["gyro_walk"], EUROC_ADIS16448["accel_walk"], T))
    g.add(PriorFactor(x, 0, data.truth[0], Isotropic(9, 1e-3)))
    g.add(PriorFactor(b, 0, np.concatenate([data.bias_gyro[0], data.bias_accel[0]]),
                      Isotropic(6, 0.1)))
    z = np.asarray(X.translation()) + fix_noise * sigma_fix * rng.standard_normal((nk + 1, 3))

    def fix(Xv, zz):
        return np.asarray(Xv.translation()) - zz

    from microlie.optim import CustomFactor

    g.add(CustomFactor(fix, [(x, np.arange(nk + 1))], 3, Isotropic(3, sigma_fix), data=[z]))
    return g, x, b


def test_noise_free_smoothing_recovers_the_truth(euroc):
    _, _, traj = euroc
    data = simulate_imu(traj, duration=4.0, start=traj.t0 + 10.0, rng=3, gyro_noise=0.0,
                        accel_noise=0.0, gyro_walk=0.0, accel_walk=0.0,
                        bias_gyro0=[0.01, -0.02, 0.005], bias_accel0=[0.1, 0.05, -0.08])
    g, x, b = _smoothing_problem(data, 40, 0.01, np.random.default_rng(0), 0.05, False)
    res = g.optimize(max_iter=50)
    out = res.values[x]
    err = out.minus(data.truth[::40])
    assert np.max(np.abs(err[:, 3:6])) < 1e-4  # rad
    assert np.max(np.abs(err[:, :3])) < 1e-3  # m
    np.testing.assert_allclose(res.values[b][0], [0.01, -0.02, 0.005, 0.1, 0.05, -0.08],
                               atol=2e-3)


def test_smoothing_cost_is_chi_square(euroc):
    """With the noise the factors assume, twice the final cost of the IMU smoothing problem is
    chi-square with (residuals - unknowns) degrees of freedom: its mean over runs is inside
    the 99% band."""
    from scipy.stats import chi2

    _, _, traj = euroc
    costs, dof = [], None
    for seed in range(5):
        data = simulate_imu(traj, duration=3.0, start=traj.t0 + 20.0 + 3 * seed, rng=seed)
        g, x, b = _smoothing_problem(data, 60, 0.02, np.random.default_rng(seed), 0.01)
        res = g.optimize(max_iter=30)
        n = len(res.values[x])
        dof = 9 * (n - 1) + 6 * (n - 1) + 9 + 6 + 3 * n - (9 + 6) * n
        costs.append(2 * res.final_cost)
    m = len(costs)
    lo, hi = chi2.ppf([0.005, 0.995], m * dof) / m
    assert lo < np.mean(costs) < hi, (np.mean(costs), lo, hi, dof)


def test_factor_bad_input():
    from microlie.optim import FactorGraph

    g = FactorGraph()
    x = g.add_variables(SE23.identity(2))
    b = g.add_variables(np.zeros((2, 6)))
    pim = Preintegration(gyro_noise=1e-3, accel_noise=1e-2).integrate(np.zeros((3, 3)),
                                                                      np.zeros((3, 3)), 0.01)
    with pytest.raises(TypeError, match="SE23"):
        ImuFactor(b, b, [0], [1], [pim])
    with pytest.raises(ValueError, match="2 preintegrations"):
        ImuFactor(x, b, [0], [1], [pim, pim])
    with pytest.raises(ValueError, match="dt"):
        BiasRandomWalkFactor(b, [0], [1], 1e-4, 1e-3, 0.0)
