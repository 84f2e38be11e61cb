"""APE / RPE relations, pair selection, statistics and the KITTI metric against independent
re-computations (plain 4x4 matrices, SciPy's matrix logarithm, brute-force loops)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import data_file
from scipy.linalg import logm
from scipy.spatial.transform import Rotation

from microlie import SE3, SO3
from microlie import traj as T


def make_traj(n: int, seed: int, stamps: bool = True, step: float = 0.3) -> T.Trajectory:
    rng = np.random.default_rng(seed)
    p = np.cumsum(rng.normal(scale=step, size=(n, 3)), axis=0)
    q = Rotation.random(n, random_state=seed).as_quat()
    return T.Trajectory.from_arrays(p, q, np.arange(n) * 0.1 if stamps else None)


def mats(t: T.Trajectory) -> np.ndarray:
    """4x4 matrices built with SciPy from the stored quaternions (independent of the core)."""
    m = np.tile(np.eye(4), (len(t), 1, 1))
    m[:, :3, :3] = Rotation.from_quat(t.quat_xyzw).as_matrix()
    m[:, :3, 3] = t.positions
    return m


def perturbed(t: T.Trajectory, seed: int, scale: float = 0.05) -> T.Trajectory:
    rng = np.random.default_rng(seed)
    noise = SE3.exp(rng.normal(scale=scale, size=(len(t), 6)))
    return T.Trajectory(t.poses @ noise, t.timestamps)


# ----------------------------------------------------------------------------- statistics
@pytest.mark.parametrize("n", [1, 2, 7, 10])
def test_statistics_definitions(n):
    e = np.abs(np.random.default_rng(n).normal(size=n))
    s = T.statistics(e)
    srt = sorted(e.tolist())
    med = srt[n // 2] if n % 2 else 0.5 * (srt[n // 2 - 1] + srt[n // 2])
    mean = sum(srt) / n
    assert s["rmse"] == pytest.approx((sum(x * x for x in srt) / n) ** 0.5, rel=1e-14)
    assert s["mean"] == pytest.approx(mean, rel=1e-14)
    assert s["median"] == pytest.approx(med, rel=1e-14)
    assert s["std"] == pytest.approx((sum((x - mean) ** 2 for x in srt) / n) ** 0.5,
                                     rel=1e-12, abs=1e-15)
    assert s["min"] == srt[0] and s["max"] == srt[-1]
    assert s["sse"] == pytest.approx(sum(x * x for x in srt), rel=1e-14)
    with pytest.raises(ValueError):
        T.statistics(np.array([]))


# ----------------------------------------------------------------------------- APE relations
def test_ape_relations_against_matrices():
    gt = make_traj(50, 1)
    est = perturbed(gt, 2, scale=0.2)
    g, e = mats(gt), mats(est)
    err = np.linalg.inv(g) @ e
    trans = np.linalg.norm(e[:, :3, 3] - g[:, :3, 3], axis=1)
    ang = Rotation.from_matrix(err[:, :3, :3]).magnitude()
    full = np.linalg.norm(err - np.eye(4), axis=(1, 2))
    rot_part = np.linalg.norm(err[:, :3, :3] - np.eye(3), axis=(1, 2))
    se3 = []
    for m in err:
        lg = np.real(logm(m))
        se3.append(np.linalg.norm(np.r_[lg[:3, 3], lg[2, 1], lg[0, 2], lg[1, 0]]))
    expected = {"trans": trans, "angle_rad": ang, "angle_deg": np.degrees(ang), "full": full,
                "rot_part": rot_part, "se3": np.array(se3), "point_distance": trans}
    for rel, ref in expected.items():
        np.testing.assert_allclose(T.ape(gt, est, rel).errors, ref, rtol=1e-10, err_msg=rel)
    np.testing.assert_allclose(T.ape(gt, est, "rot").errors, np.degrees(ang), rtol=1e-10)
    np.testing.assert_allclose(T.ape(gt, est, "rot", angle_unit="rad").errors, ang, rtol=1e-10)


def test_se3_relation_is_lecture_notes_rmse():
    """MATH.md section 9: RMSE = sqrt(mean |Log(T_gt^-1 T_est)|^2)."""
    gt = make_traj(30, 3)
    xi = np.random.default_rng(4).normal(scale=0.1, size=(30, 6))
    est = T.Trajectory(gt.poses @ SE3.exp(xi), gt.timestamps)
    res = T.ape(gt, est, "se3")
    np.testing.assert_allclose(res.errors, np.linalg.norm(xi, axis=1), rtol=1e-10)
    assert res.stats["rmse"] == pytest.approx(np.sqrt(np.mean(np.sum(xi**2, axis=1))), rel=1e-10)


def test_ape_requires_pairs_and_known_relation():
    gt = make_traj(5, 1)
    with pytest.raises(ValueError, match="paired"):
        T.ape(gt, make_traj(6, 1))
    with pytest.raises(ValueError, match="unknown pose relation"):
        T.ape(gt, gt, "yaw")


# ----------------------------------------------------------------------------- RPE
def test_rpe_against_matrices_all_relations():
    gt = make_traj(40, 5)
    est = perturbed(gt, 6)
    g, e = mats(gt), mats(est)
    for d in (1, 3):
        i = np.arange(0, 40, d)
        i, j = i[:-1], i[1:]
        q = np.linalg.inv(g[i]) @ g[j]
        p = np.linalg.inv(e[i]) @ e[j]
        err = np.linalg.inv(q) @ p
        res = T.rpe(gt, est, "trans", d)
        np.testing.assert_array_equal(res.pairs, np.stack([i, j], 1))
        np.testing.assert_allclose(res.errors, np.linalg.norm(err[:, :3, 3], axis=1), rtol=1e-10)
        np.testing.assert_allclose(T.rpe(gt, est, "angle_deg", d).errors,
                                   np.degrees(Rotation.from_matrix(err[:, :3, :3]).magnitude()),
                                   rtol=1e-10)
        np.testing.assert_allclose(T.rpe(gt, est, "full", d).errors,
                                   np.linalg.norm(err - np.eye(4), axis=(1, 2)), rtol=1e-10)
        dist = np.abs(np.linalg.norm(g[j, :3, 3] - g[i, :3, 3], axis=1)
                      - np.linalg.norm(e[j, :3, 3] - e[i, :3, 3], axis=1))
        np.testing.assert_allclose(T.rpe(gt, est, "point_distance", d).errors, dist,
                                   rtol=1e-10, atol=1e-14)


def test_rpe_invariant_to_global_transform():
    gt = make_traj(30, 7)
    est = perturbed(gt, 8)
    g = SE3.from_rotation_translation(SO3.from_rotvec([0.3, -1.0, 2.0]), np.array([5.0, 1, 2]))
    a = T.rpe(gt, est, "trans", 2).errors
    b = T.rpe(gt, est.transform(g), "trans", 2).errors
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_frame_pairs():
    t = make_traj(10, 1)
    np.testing.assert_array_equal(T.pose_pairs(t, 3), [[0, 3], [3, 6], [6, 9]])
    np.testing.assert_array_equal(T.pose_pairs(t, 4, all_pairs=True),
                                  [[i, i + 4] for i in range(6)])
    with pytest.raises(ValueError, match="integer"):
        T.pose_pairs(t, 1.5)
    with pytest.raises(ValueError, match="no pose pairs"):
        T.pose_pairs(t, 10)


def _path_pairs_loop(p: np.ndarray, delta: float) -> list:
    """Restatement of the consecutive metre rule: pose 0 opens the first pair; summing step
    lengths, the first index where the sum reaches delta closes the pair, the sum restarts."""
    ids, acc = [0], 0.0
    for k in range(1, len(p)):
        acc += float(np.linalg.norm(p[k] - p[k - 1]))
        if acc >= delta:
            ids.append(k)
            acc = 0.0
    return list(zip(ids[:-1], ids[1:], strict=True))


def _all_pairs_loop(p: np.ndarray, delta: float, tol: float) -> list:
    """Brute force: for each i the j > i with travelled distance closest to delta."""
    d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    out = []
    for i in range(len(p) - 1):
        c = np.abs((d[i + 1:] - d[i]) - delta)
        k = int(np.argmin(c))
        if c[k] <= tol:
            out.append((i, i + 1 + k))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_metre_pairs_against_loops(seed):
    t = make_traj(300, seed)
    # standing still for a while (repeated positions) must not confuse tie-breaking
    p = t.positions.copy()
    p[100:120] = p[100]
    t = T.Trajectory.from_arrays(p, t.quat_xyzw, t.timestamps)
    for delta in (0.5, 2.0, 7.3):
        np.testing.assert_array_equal(T.pose_pairs(t, delta, "m"), _path_pairs_loop(p, delta))
        np.testing.assert_array_equal(T.pose_pairs(t, delta, "m", all_pairs=True),
                                      np.array(_all_pairs_loop(p, delta, 0.1 * delta)))


def test_pairs_from_reference_or_estimate():
    gt = make_traj(200, 3)
    est = T.Trajectory.from_arrays(gt.positions * 2.0, gt.quat_xyzw, gt.timestamps)
    a = T.rpe(gt, est, "trans", 5.0, "m", pairs_from="ref").pairs
    b = T.rpe(gt, est, "trans", 10.0, "m", pairs_from="est").pairs
    np.testing.assert_array_equal(a, b)  # est path is twice as long


# ----------------------------------------------------------------------------- KITTI metric
def devkit_kitti(g: np.ndarray, e: np.ndarray, lengths=T.KITTI_LENGTHS, step=10):
    """Re-statement of the KITTI devkit's evaluate_odometry on 4x4 matrices (float64)."""
    dist = [0.0]
    for k in range(1, len(g)):
        dist.append(dist[-1] + float(np.linalg.norm(g[k, :3, 3] - g[k - 1, :3, 3])))
    dist = np.array(dist)
    t_errs, r_errs = [], []
    for first in range(0, len(g), step):
        for length in lengths:
            beyond = np.nonzero(dist > dist[first] + length)[0]
            if beyond.size == 0:
                continue
            last = beyond[0]
            d_gt = np.linalg.inv(g[first]) @ g[last]
            d_est = np.linalg.inv(e[first]) @ e[last]
            err = np.linalg.inv(d_est) @ d_gt
            c = 0.5 * (np.trace(err[:3, :3]) - 1.0)
            r_errs.append(np.arccos(max(min(c, 1.0), -1.0)) / length)
            t_errs.append(np.linalg.norm(err[:3, 3]) / length)
    return 100 * np.mean(t_errs), np.degrees(np.mean(r_errs)), len(t_errs)


def test_kitti_metric_on_kitti00():
    gt = T.read_kitti(data_file("trajectory/evo/KITTI_00_gt.txt"))
    est = T.read_kitti(data_file("trajectory/evo/KITTI_00_ORB.txt"))
    res = T.kitti_odometry(gt, est)
    t_ref, r_ref, n_ref = devkit_kitti(mats(gt), mats(est))
    assert res.segments.shape[0] == n_ref
    assert res.t_err == pytest.approx(t_ref, rel=1e-10)
    assert res.r_err == pytest.approx(r_ref, rel=1e-7)  # arccos loses digits at small angles
    assert sum(v[2] for v in res.per_length.values()) == n_ref


def test_kitti_metric_straight_line_scale_error():
    """Straight line, 1 m steps, estimate 1% too long: t_err = 1 %, r_err = 0."""
    n = 1000
    p = np.zeros((n, 3))
    p[:, 0] = np.arange(n, dtype=float)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    gt = T.Trajectory.from_arrays(p, q)
    est = T.Trajectory.from_arrays(1.01 * p, q)
    res = T.kitti_odometry(gt, est)
    # segment of length L ends at the first index beyond L: travelled L+1 m, error 0.01 (L+1)
    expected = np.mean([0.01 * (length + 1) / length for f in range(0, n, 10)
                        for length in T.KITTI_LENGTHS if f + length + 1 < n]) * 100
    assert res.t_err == pytest.approx(expected, rel=1e-12)
    assert res.r_err == 0.0
    with pytest.raises(ValueError, match="no KITTI segment"):
        T.kitti_odometry(gt.subset(slice(0, 50)), est.subset(slice(0, 50)))
