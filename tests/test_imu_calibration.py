"""Hand-eye calibration: exact recovery on noise-free data, errors no worse than OpenCV's
calibrateHandEye (all five methods, saved by tests/fixtures/imu/make_opencv_handeye_fixtures.py)
on the same synthetic poses, and a consistent covariance (Monte Carlo NEES)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from microlie import SE3, SO3
from microlie.calibration import (
    hand_eye,
    hand_eye_from_poses,
    hand_eye_robot_world,
    motions_from_poses,
)

FIX = np.load(Path(__file__).parent / "fixtures" / "imu" / "opencv_handeye.npz")
METHODS = ["TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS"]


def _errors(X, est_R, est_t):
    dth = np.linalg.norm((X.rotation().inverse() @ SO3.from_matrix(est_R, normalize=True)).log())
    return dth, np.linalg.norm(np.asarray(est_t) - np.asarray(X.translation()))


def test_exact_recovery_on_noise_free_data():
    X, G, C = SE3(FIX["X"][0]), SE3(FIX["G"][0]), SE3(FIX["C"][0])  # trial 0 has no noise
    for est in (hand_eye(*motions_from_poses(G, C)).mean,
                hand_eye(*motions_from_poses(G, C, "consecutive")).mean,
                hand_eye_from_poses(G, C).mean,
                hand_eye_robot_world(G, C.inverse()).mean.part(0)):
        np.testing.assert_allclose(est.matrix(), X.matrix(), atol=1e-12)
    # AX = YB recovers Y too
    W = G[0] @ X @ C[0]
    np.testing.assert_allclose(hand_eye_robot_world(G, C.inverse()).mean.part(1).matrix(),
                               W.matrix(), atol=1e-12)
    # OpenCV is exact there as well (the fixture is sane)
    for m in METHODS:
        assert max(_errors(X, FIX[f"R_{m}"][0], FIX[f"t_{m}"][0])) < 1e-12


def test_no_worse_than_opencv_on_the_same_noisy_poses():
    ours, theirs = [], {m: [] for m in METHODS}
    for k in range(1, len(FIX["X"])):
        X, G, C = SE3(FIX["X"][k]), SE3(FIX["G"][k]), SE3(FIX["C"][k])
        est = hand_eye_from_poses(G, C).mean
        ours.append(_errors(X, est.rotation().matrix(), est.translation()))
        for m in METHODS:
            theirs[m].append(_errors(X, FIX[f"R_{m}"][k], FIX[f"t_{m}"][k]))
    ours_mean = np.mean(ours, 0)
    for m in METHODS:
        ref = np.mean(theirs[m], 0)
        assert ours_mean[0] <= ref[0] and ours_mean[1] <= ref[1], (m, ours_mean, ref)


def test_robot_world_no_worse_than_opencv_on_the_same_noisy_poses():
    """AX = YB (X camera-to-gripper, Y target-to-base) against OpenCV's
    calibrateRobotWorldHandEye (Shah, Li): mean rotation and translation errors of both."""
    ours, theirs = [], {m: [] for m in ("SHAH", "LI")}
    for k in range(1, len(FIX["X"])):
        X, W, G, C = (SE3(FIX[n][k]) for n in ("X", "W", "G", "C"))
        est = hand_eye_robot_world(G, C.inverse(), b_noise="left").mean
        ex, ew = est.part(0), est.part(1)
        ours.append(_errors(X, ex.rotation().matrix(), ex.translation())
                    + _errors(W, ew.rotation().matrix(), ew.translation()))
        for m in theirs:
            theirs[m].append(_errors(X, FIX[f"RX_{m}"][k], FIX[f"tX_{m}"][k])
                             + _errors(W, FIX[f"RW_{m}"][k], FIX[f"tW_{m}"][k]))
    mine = np.mean(ours, 0)
    for m, v in theirs.items():
        assert np.all(mine <= np.mean(v, 0)), (m, mine, np.mean(v, 0))


def _synthetic(rng, n=15, sigma=1e-3):
    X = SE3.exp(np.r_[0.1 * rng.standard_normal(3), 0.5 * rng.standard_normal(3)])
    W = SE3.exp(np.r_[rng.standard_normal(3), 0.5 * rng.standard_normal(3)])
    G = SE3.exp(np.concatenate([0.3 * rng.standard_normal((n, 3)),
                                0.35 * rng.standard_normal((n, 3))], -1))
    C = (G @ X).inverse() @ W
    return X, G.plus(sigma * rng.standard_normal((n, 6))), C.plus(sigma * rng.standard_normal(
        (n, 6)))


def test_covariance_is_consistent():
    """The returned covariance matches the actual errors: the average NEES of X over 80
    noisy problems is inside the 99% chi-square band of 6 dof."""
    rng = np.random.default_rng(8)
    nees = []
    for _ in range(80):
        X, G, C = _synthetic(rng)
        est = hand_eye_from_poses(G, C)
        e = X.minus(est.mean)  # truth = estimate (+) e
        nees.append(e @ np.linalg.solve(est.cov, e))
    lo, hi = chi2.ppf([0.005, 0.995], 6 * 80) / 80
    assert lo < np.mean(nees) < hi, np.mean(nees)


def test_degenerate_and_bad_input():
    R = SE3.exp(np.array([[0.1, 0, 0, 0.3, 0, 0], [0.2, 0.1, 0, 0.5, 0, 0]]))  # one axis only
    with pytest.raises(ValueError, match="degenerate"):
        hand_eye(R, R)
    with pytest.raises(ValueError, match="same length"):
        hand_eye(SE3.random(3, rng=0), SE3.random(4, rng=0))
    with pytest.raises(TypeError, match="SE3"):
        hand_eye(SO3.random(3, rng=0), SO3.random(3, rng=0))
    with pytest.raises(ValueError, match="b_noise"):
        hand_eye_robot_world(SE3.random(4, rng=0), SE3.random(4, rng=1), b_noise="up")
    with pytest.raises(ValueError, match="pairs"):
        motions_from_poses(SE3.random(4, rng=0), SE3.random(4, rng=1), pairs="some")
