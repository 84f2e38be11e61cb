"""SE_2(3)-specific checks (the generic suite in test_groups.py covers the axioms, Exp/Log against
the matrix exponential, every Jacobian against finite differences and all backends)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from microlie import SE3, SE23, SO3


def test_first_six_tangent_entries_are_se3():
    rng = np.random.default_rng(0)
    tau = rng.standard_normal((20, 9))
    tau6 = tau[:, :6]
    X = SE23.exp(np.concatenate([tau6, np.zeros((20, 3))], -1))
    np.testing.assert_allclose(X.pose().matrix(), SE3.exp(tau6).matrix(), atol=1e-13)
    np.testing.assert_allclose(SE23.jr(tau)[:, :6, :6], SE3.jr(tau6), atol=1e-13)
    np.testing.assert_allclose(SE23.exp(tau).pose().matrix(), SE3.exp(tau6).matrix(),
                               atol=1e-13)
    # the velocity block is the same SE(3) structure on (nu, phi)
    tv = np.concatenate([tau[:, 6:], tau[:, 3:6]], -1)
    np.testing.assert_allclose(SE23.exp(tau).velocity(), SE3.exp(tv).translation(), atol=1e-13)
    J = SE23.jr(tau)
    np.testing.assert_allclose(J[:, 6:, 3:6], SE3.jr(tv)[:, :3, 3:], atol=1e-13)


def test_matrix_layout_and_constructors():
    rng = np.random.default_rng(1)
    R = SO3.random(5, rng=rng)
    p, v = rng.standard_normal((2, 5, 3))
    X = SE23.from_rotation_translation(R, p, v)
    T = X.matrix()
    np.testing.assert_allclose(T[:, :3, :3], R.matrix(), atol=1e-15)
    np.testing.assert_allclose(T[:, :3, 3], p)
    np.testing.assert_allclose(T[:, :3, 4], v)
    np.testing.assert_allclose(T[:, 3:, :], np.broadcast_to(np.eye(5)[3:], (5, 2, 5)))
    np.testing.assert_allclose(SE23.from_matrix(T).matrix(), T, atol=1e-14)
    np.testing.assert_allclose(X.rotation().matrix(), R.matrix(), atol=1e-15)
    np.testing.assert_allclose(X.act(v), np.einsum("nij,nj->ni", R.matrix(), v) + p, atol=1e-14)
    # the tangent generators follow the matrix layout: rho -> column 3, nu -> column 4
    e = np.eye(9)
    np.testing.assert_allclose(expm(SE23.hat(e[0]))[:3, 3], [1, 0, 0])
    np.testing.assert_allclose(expm(SE23.hat(e[8]))[:3, 4], [0, 0, 1])
    # zero velocity by default
    np.testing.assert_allclose(SE23.from_rotation_translation(R, p).velocity(), 0.0)


def test_bad_matrices_raise():
    bad = np.eye(5)
    bad[3, 4] = 0.5
    with pytest.raises(ValueError, match="last two rows"):
        SE23.from_matrix(bad)
    bad = np.eye(5)
    bad[4, 0] = 1.0
    with pytest.raises(ValueError, match="last row"):
        SE23.from_matrix(bad)
    bad = np.eye(5)
    bad[0, 0] = 1.1
    with pytest.raises(ValueError, match="not orthogonal"):
        SE23.from_matrix(bad)
    with pytest.raises(ValueError, match="velocity"):
        SE23.from_rotation_translation(SO3.identity(), np.zeros(3), np.zeros(4))
