"""Timestamp association and alignment (Umeyama, scale, origin) against brute force and known
transforms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from microlie import SE3, SO3, Sim3
from microlie import traj as T


def brute_match(q: np.ndarray, t: np.ndarray, max_diff: float):
    """Nearest target stamp for each query stamp: smallest |difference| wins; on equal
    differences a target at or before the query wins (the latest such one), otherwise the
    earliest target after it."""
    iq, it = [], []
    for a, s in enumerate(q):
        d = np.abs(t - s)
        m = d.min()
        if m > max_diff:
            continue
        cands = np.nonzero(d == m)[0]
        before = [c for c in cands if t[c] <= s]
        it.append(max(before) if before else min(cands))
        iq.append(a)
    return np.array(iq, dtype=int), np.array(it, dtype=int)


@pytest.mark.parametrize("seed", range(5))
def test_match_timestamps_against_brute_force(seed):
    rng = np.random.default_rng(seed)
    t = np.sort(np.round(rng.uniform(0, 10, 400), 2))  # rounded: ties and duplicates occur
    q = np.round(rng.uniform(-0.5, 10.5, 150), 3)
    for max_diff in (0.005, 0.01, 0.05):
        iq, it = T.match_timestamps(q, t, max_diff)
        bq, bt = brute_match(q, t, max_diff)
        np.testing.assert_array_equal(iq, bq)
        np.testing.assert_array_equal(it, bt)


def test_unsorted_target_takes_first_minimum():
    t = np.array([3.0, 1.0, 2.0, 1.0])
    iq, it = T.match_timestamps(np.array([1.001, 2.5, 9.0]), t, 0.01)
    np.testing.assert_array_equal(iq, [0])
    np.testing.assert_array_equal(it, [1])


def _traj(stamps):
    n = len(stamps)
    p = np.column_stack([np.arange(n, dtype=float), np.zeros(n), np.zeros(n)])
    return T.Trajectory.from_arrays(p, np.tile([0, 0, 0, 1.0], (n, 1)), np.asarray(stamps))


def test_associate_shorter_side_and_offset():
    ref = _traj(np.arange(100) * 0.1)            # 100 poses
    est = _traj(np.arange(20) * 0.5 + 100.003)   # 20 poses, clock 100 s ahead
    with pytest.raises(ValueError, match="no matching timestamps"):
        T.associate(ref, est)
    r, e, info = T.associate(ref, est, 0.01, offset=-100.0, return_info=True)
    assert info.num_pairs == 20 and info.max_pairs == 20
    np.testing.assert_allclose(r.timestamps, np.arange(20) * 0.5, atol=1e-12)
    np.testing.assert_array_equal(e.timestamps, est.timestamps)
    # swapping the roles gives the same pairs (offset sign flips)
    e2, r2 = T.associate(est, ref, 0.01, offset=100.0)
    np.testing.assert_array_equal(r2.timestamps, r.timestamps)
    np.testing.assert_array_equal(e2.timestamps, e.timestamps)


def test_associate_duplicates():
    ref = _traj([0.0, 1.0, 1.0, 2.0, 3.0])
    est = _traj([1.0, 1.0, 2.004])
    r, e, info = T.associate(ref, est, return_info=True)
    # both estimate poses at t=1 pair with the last reference pose carrying t=1 (index 2)
    np.testing.assert_array_equal(r.positions[:, 0], [2.0, 2.0, 3.0])
    assert (info.duplicates_first, info.duplicates_second) == (1, 1)


def test_associate_needs_timestamps():
    a = T.Trajectory.from_arrays(np.zeros((3, 3)), np.tile([0, 0, 0, 1.0], (3, 1)))
    with pytest.raises(ValueError, match="timestamps"):
        T.associate(a, a)


# ----------------------------------------------------------------------------- Umeyama
def _sim3_apply(r, t, s, x):
    return s * x @ r.T + t


@pytest.mark.parametrize("seed", range(4))
def test_umeyama_recovers_known_similarity(seed):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(50, 3)) * [5, 2, 1]
    r = Rotation.random(random_state=seed).as_matrix()
    t = rng.normal(size=3) * 10
    s = rng.uniform(0.2, 5)
    y = _sim3_apply(r, t, s, x)
    r1, t1, s1 = T.umeyama(x, y, with_scale=True)
    np.testing.assert_allclose(r1, r, atol=1e-12)
    np.testing.assert_allclose(t1, t, atol=1e-11)
    assert s1 == pytest.approx(s, rel=1e-12)
    r2, t2, s2 = T.umeyama(x, _sim3_apply(r, t, 1.0, x))
    np.testing.assert_allclose(r2, r, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-11)
    assert s2 == 1.0


def test_umeyama_never_returns_a_reflection():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(30, 3))
    y = x * [1, 1, -1] + rng.normal(scale=0.01, size=(30, 3))  # mirrored target
    r, _, _ = T.umeyama(x, y)
    assert np.linalg.det(r) == pytest.approx(1.0, abs=1e-12)
    with pytest.raises(ValueError, match="degenerate"):
        T.umeyama(np.outer(np.arange(5.0), [1, 2, 3]), np.outer(np.arange(5.0), [3, 2, 1]))


def _random_traj(n, seed):
    rng = np.random.default_rng(seed)
    return T.Trajectory.from_arrays(rng.normal(size=(n, 3)) * 3,
                                    Rotation.random(n, random_state=seed).as_quat(),
                                    np.arange(n) * 0.1)


def test_align_methods_recover_transform():
    gt = _random_traj(60, 1)
    r = Rotation.from_rotvec([0.2, -0.4, 1.1])
    t = np.array([1.0, -2.0, 0.5])
    g_se3 = SE3.from_rotation_translation(SO3.from_matrix(r.as_matrix()), t)
    g_sim3 = Sim3.from_rotation_translation_scale(SO3.from_matrix(r.as_matrix()), t, 2.5)
    # est = g^-1 applied to gt, so aligning est must bring back gt (poses, not only positions)
    for g, method in ((g_se3, "se3"), (g_sim3, "sim3")):
        est = gt.transform(g.inverse())
        aligned, found = T.align(gt, est, method)
        np.testing.assert_allclose(aligned.matrices(), gt.matrices(), atol=1e-11)
        np.testing.assert_allclose(found.params, g.params, atol=1e-11)
    # scale only: est = gt positions / 3
    est = T.Trajectory.from_arrays(gt.positions / 3, gt.quat_xyzw, gt.timestamps)
    aligned, found = T.align(gt, est, "scale")
    np.testing.assert_allclose(aligned.positions, gt.positions, atol=1e-12)
    assert float(np.asarray(found.scale())) == pytest.approx(3.0, rel=1e-12)
    # origin: first poses coincide, relative motion unchanged
    est = _random_traj(60, 2)
    aligned, _ = T.align(gt, est, "origin")
    np.testing.assert_allclose(aligned.matrices()[0], gt.matrices()[0], atol=1e-12)
    m0 = est.matrices()
    m1 = aligned.matrices()
    np.testing.assert_allclose(np.linalg.inv(m1[0]) @ m1[5], np.linalg.inv(m0[0]) @ m0[5],
                               atol=1e-12)
    same, g = T.align(gt, est, "none")
    assert same is est and g is None


def test_align_first_n_only():
    gt = _random_traj(40, 4)
    g = SE3.from_rotation_translation(SO3.from_rotvec([0.0, 0.0, 0.7]), np.array([3.0, 0, 0]))
    est = gt.transform(g.inverse())
    # corrupt the tail: with n=10 the transform comes from the clean head only
    p = est.positions.copy()
    p[10:] += 5.0
    est = T.Trajectory.from_arrays(p, est.quat_xyzw, est.timestamps)
    _, found = T.align(gt, est, "se3", n=10)
    np.testing.assert_allclose(found.params, g.params, atol=1e-11)
    with pytest.raises(ValueError, match="unknown alignment"):
        T.align(gt, est, "affine")


def test_georeferenced_large_coordinates_alignment():
    """evo issue 687's file: UTM-sized coordinates (~5e6 m). Umeyama centres the points, so a
    known rigid transform is undone to micrometre level (float64 spacing at 5e6 m is 1e-9 m)."""
    from conftest import data_file

    gt = T.read_tum(data_file("trajectory/evo/georeferenced.tum"))
    g = SE3.from_rotation_translation(SO3.from_rotvec([0.01, -0.02, 0.3]),
                                      np.array([-4.5e5, -5.4e6, 10.0]))
    est = gt.transform(g)  # now near the origin
    res = T.evaluate_ape(gt, est, align="se3")
    assert res.errors.size == len(gt)
    assert res.stats["max"] < 1e-6
    unaligned = T.evaluate_ape(gt, est, align="none")
    p = gt.positions
    np.testing.assert_allclose(
        unaligned.errors,
        np.linalg.norm(p @ Rotation.from_rotvec([0.01, -0.02, 0.3]).as_matrix().T
                       + [-4.5e5, -5.4e6, 10.0] - p, axis=1), rtol=1e-9)
