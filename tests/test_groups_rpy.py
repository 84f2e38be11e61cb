"""Issue 19 item 2: ``SO3.as_rpy`` gives angles that reproduce the rotation at every pitch,
including the gimbal lock (pitch = +-pi/2) and next to it, on every backend; ``write_toro``
(which writes SE(3) poses as roll, pitch, yaw) therefore keeps them."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import BACKENDS, to_backend, to_numpy
from scipy.spatial.transform import Rotation

from microlie import SE3, SO3
from microlie.optim.io.pose_graph import PoseGraph
from microlie.optim.io.toro import read_toro, write_toro


def _rzyx(rpy: np.ndarray) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` written out in float64 (independent of the library)."""
    r, p, y = (np.asarray(rpy, dtype=np.float64)[..., k] for k in range(3))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1),
        np.stack([-sp, cp * sr, cp * cr], -1)], -2)


def _hard_quaternions(rng: np.random.Generator) -> np.ndarray:
    """Random rotations, then pitch exactly +-pi/2 (quaternions whose half-angle pair is
    exactly zero), and pitch +-(pi/2 - d) for d = 1e-9, 1e-12 with random roll and yaw."""
    q = rng.standard_normal((64, 4))
    qs = [q / np.linalg.norm(q, axis=1, keepdims=True)]
    r, y = rng.uniform(-np.pi, np.pi, (2, 16))
    s = np.sqrt(0.5)
    # pitch +pi/2, roll 0: (x, y, z, w) = s (-sin(yaw/2), cos(yaw/2), sin(yaw/2), cos(yaw/2))
    qs.append(s * np.stack([-np.sin(y / 2), np.cos(y / 2), np.sin(y / 2), np.cos(y / 2)], -1))
    # pitch -pi/2, roll 0
    qs.append(s * np.stack([np.sin(y / 2), -np.cos(y / 2), np.sin(y / 2), np.cos(y / 2)], -1))
    for d in (0.0, 1e-12, 1e-9):
        for sign in (1.0, -1.0):
            pitch = sign * (np.pi / 2 - d)
            qs.append(Rotation.from_euler("xyz", np.stack([r, np.full(16, pitch), y], -1))
                      .as_quat())
    return np.concatenate(qs)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("backend", BACKENDS)
def test_issue19_item2_as_rpy_round_trip_at_and_near_gimbal_lock(backend, dtype):
    q = _hard_quaternions(np.random.default_rng(19))
    X = SO3(to_backend(q, backend, dtype))
    R_ref = Rotation.from_quat(q.astype(dtype).astype(np.float64)).as_matrix()
    tol = 5e-15 if dtype == np.float64 else 2e-6
    rpy = to_numpy(X.as_rpy())
    assert rpy.dtype == dtype and rpy.shape == (len(q), 3)
    assert np.all(np.abs(rpy) <= np.pi + 1e-6) and np.all(np.abs(rpy[:, 1]) <= np.pi / 2 + 1e-6)
    np.testing.assert_allclose(_rzyx(rpy), R_ref, rtol=0, atol=tol)
    # the library's own inverse, batched (a batch shape with two axes) and one by one
    back = SO3.from_rpy(*(X.as_rpy().reshape(4, -1, 3)[..., k] for k in range(3)))
    np.testing.assert_allclose(to_numpy(back.matrix()).reshape(-1, 3, 3), R_ref, atol=tol)
    for k in (0, 80, 130):  # random, -pi/2 exactly, 1e-12 from +pi/2
        one = to_numpy(X[k].as_rpy())
        np.testing.assert_allclose(_rzyx(one), R_ref[k], rtol=0, atol=tol)
    # at the lock exactly, roll is 0 (one documented split of yaw and roll)
    lock = to_numpy(X[64:96].as_rpy())
    np.testing.assert_allclose(lock[:, 0], 0.0, atol=tol)
    np.testing.assert_allclose(np.abs(lock[:, 1]), np.pi / 2, atol=tol * 10)


def test_issue19_item2_write_toro_keeps_se3_poses_at_gimbal_lock(tmp_path):
    q = _hard_quaternions(np.random.default_rng(20))[60:]
    n = len(q)
    t = np.random.default_rng(21).standard_normal((n, 3))
    poses = SE3(np.concatenate([t, q], axis=1))
    meas = poses[:-1].inverse() @ poses[1:]
    g = PoseGraph(SE3, ids=np.arange(n), poses=poses, i=np.arange(n - 1), j=np.arange(1, n),
                  measurements=meas, information=np.broadcast_to(np.eye(6), (n - 1, 6, 6)))
    out = tmp_path / "lock.graph"
    write_toro(out, g)
    back = read_toro(out)
    np.testing.assert_allclose(back.poses.matrix(), _se3_ref(t, q), rtol=0, atol=5e-15)
    np.testing.assert_allclose(back.measurements.matrix(), meas.matrix(), rtol=0, atol=5e-15)


def _se3_ref(t: np.ndarray, q: np.ndarray) -> np.ndarray:
    M = np.zeros((len(q), 4, 4))
    M[:, :3, :3] = Rotation.from_quat(q).as_matrix()
    M[:, :3, 3] = t
    M[:, 3, 3] = 1.0
    return M


def test_issue19_item2_optimize_command_writes_toro_poses_at_gimbal_lock(tmp_path):
    """``microlie optimize in.g2o -o out.graph`` on a consistent graph (its optimum is its own
    vertices) whose poses are at and next to pitch +-pi/2."""
    import io

    from microlie.cli import main
    from microlie.optim.io.g2o import write_g2o

    q = _hard_quaternions(np.random.default_rng(22))[60:140:4]
    n = len(q)
    t = np.random.default_rng(23).standard_normal((n, 3))
    poses = SE3(np.concatenate([t, q], axis=1))
    meas = poses[:-1].inverse() @ poses[1:]
    g = PoseGraph(SE3, ids=np.arange(n), poses=poses, i=np.arange(n - 1), j=np.arange(1, n),
                  measurements=meas, information=np.broadcast_to(np.eye(6), (n - 1, 6, 6)))
    src, out = tmp_path / "lock.g2o", tmp_path / "out.graph"
    write_g2o(src, g)
    code = main(["optimize", str(src), "-o", str(out)], out=io.StringIO(), err=io.StringIO())
    assert code == 0
    np.testing.assert_allclose(read_toro(out).poses.matrix(), _se3_ref(t, q), rtol=0, atol=1e-9)
