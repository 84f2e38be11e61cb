"""Reprojection residuals and their analytic Jacobians (both camera models) against central
finite differences, and the convention for points at or behind the camera."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from microlie.optim.sfm.camera import BALCamera, PinholeCamera, reproject

MODELS = {
    "bal": (BALCamera(), np.array([480.0, -0.05, 0.02])),
    "bal-nodist": (BALCamera(), np.array([480.0, 0.0, 0.0])),
    "pinhole": (PinholeCamera(), np.array([500.0, 520.0, 320.0, 240.0])),
    "pinhole-radtan": (PinholeCamera(distortion=True),
                       np.array([500.0, 520.0, 320.0, 240.0, -0.2, 0.05, 1e-3, -2e-3])),
}


def _scene(model, K, rng, n=40):
    R = Rotation.random(3, random_state=1).as_matrix()
    t = rng.normal(size=(3, 3))
    cam = rng.integers(0, 3, n)
    # points in front of their camera at depth 2..6 (BAL looks down -z)
    sign = -1.0 if isinstance(model, BALCamera) else 1.0
    P = np.column_stack([rng.uniform(-1, 1, (n, 2)), sign * rng.uniform(2, 6, n)])
    X = np.einsum("nji,nj->ni", R[cam], P - t[cam])      # X = R^T (P - t)
    return R, t, np.tile(K, (3, 1)), X, cam, np.arange(n), rng.normal(size=(n, 2))


@pytest.mark.parametrize("name", list(MODELS))
def test_jacobians_match_finite_differences(name):
    model, K0 = MODELS[name]
    rng = np.random.default_rng(3)
    R, t, K, X, cam, pt, obs = _scene(model, K0, rng)
    out = reproject(model, R, t, K, X, cam, pt, obs)
    n, d = len(cam), 6 + len(K0)

    def res(R_, t_, K_, X_):
        return reproject(model, R_, t_, K_, X_, cam, pt, obs, jac=False).residuals

    # camera tangent (dt, dphi, dK): perturb every camera at once, read off per observation
    Jc_fd = np.zeros((n, 2, d))
    for k in range(d):
        h = 1e-6 * (1.0 if k < 6 else max(1.0, abs(K0[k - 6])))
        rs = []
        for s in (1.0, -1.0):
            dt = np.zeros((3, 3))
            dphi = np.zeros((3, 3))
            dK = np.zeros_like(K)
            if k < 3:
                dt[:, k] = s * h
            elif k < 6:
                dphi[:, k - 3] = s * h
            else:
                dK[:, k - 6] = s * h
            Rp = R @ Rotation.from_rotvec(dphi).as_matrix()          # right perturbation
            rs.append(res(Rp, t + dt, K + dK, X))
        Jc_fd[:, :, k] = (rs[0] - rs[1]) / (2 * h)
    Jp_fd = np.zeros((n, 2, 3))
    for k in range(3):
        h = 1e-6
        dX = np.zeros_like(X)
        dX[:, k] = h
        Jp_fd[:, :, k] = (res(R, t, K, X + dX) - res(R, t, K, X - dX)) / (2 * h)
    scale = np.abs(Jc_fd).max()
    np.testing.assert_allclose(out.J_cam, Jc_fd, rtol=1e-6, atol=1e-7 * scale)
    np.testing.assert_allclose(out.J_point, Jp_fd, rtol=1e-6, atol=1e-7 * np.abs(Jp_fd).max())


def test_bal_projection_formula_by_hand():
    # P = R X + t, p = -P_xy / P_z, uv = f (1 + k1 r2 + k2 r2^2) p
    R = Rotation.from_rotvec([0.1, -0.2, 0.3]).as_matrix()
    t = np.array([0.5, -0.25, -4.0])
    X = np.array([0.3, 0.2, -0.1])
    f, k1, k2 = 700.0, -0.1, 0.03
    P = R @ X + t
    p = -P[:2] / P[2]
    r2 = p @ p
    uv = f * (1 + k1 * r2 + k2 * r2 * r2) * p
    out = reproject(BALCamera(), R[None], t[None], np.array([[f, k1, k2]]), X[None],
                    np.array([0]), np.array([0]), np.zeros((1, 2)), jac=False)
    np.testing.assert_allclose(out.residuals[0], uv, rtol=1e-14)


def test_pinhole_radtan_formula_by_hand():
    # OpenCV's model: x_d = x a + 2 p1 x y + p2 (r2 + 2 x^2), y_d = y a + p1 (r2 + 2 y^2) + 2 p2 x y
    fx, fy, cx, cy, k1, k2, p1, p2 = 500.0, 510.0, 320.0, 240.0, -0.2, 0.05, 1e-3, -2e-3
    P = np.array([0.4, -0.3, 2.0])
    x, y = P[0] / P[2], P[1] / P[2]
    r2 = x * x + y * y
    a = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * a + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * a + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    out = reproject(PinholeCamera(distortion=True), np.eye(3)[None], np.zeros((1, 3)),
                    np.array([[fx, fy, cx, cy, k1, k2, p1, p2]]), P[None], np.array([0]),
                    np.array([0]), np.zeros((1, 2)), jac=False)
    np.testing.assert_allclose(out.residuals[0], [fx * xd + cx, fy * yd + cy], rtol=1e-14)


def test_behind_camera_convention():
    # one point in front of a BAL camera (P_z < 0), one behind (P_z > 0), one on the plane
    model, K = BALCamera(), np.array([[500.0, 0.0, 0.0]])
    X = np.array([[0.1, 0.1, -3.0], [0.1, 0.1, 3.0], [0.1, 0.1, 0.0]])
    obs = np.ones((3, 2))
    args = (np.eye(3)[None], np.zeros((1, 3)), K, X, np.zeros(3, int), np.arange(3), obs)
    ev = reproject(model, *args, behind="evaluate")
    dr = reproject(model, *args, behind="drop")
    assert ev.valid.all()
    assert dr.valid.tolist() == [True, False, False]
    np.testing.assert_array_equal(dr.residuals[0], ev.residuals[0])
    np.testing.assert_array_equal(dr.residuals[1:], 0.0)
    np.testing.assert_array_equal(dr.J_cam[1:], 0.0)
    np.testing.assert_array_equal(dr.J_point[1:], 0.0)
    assert np.all(np.isfinite(ev.residuals[:2]))
    with pytest.raises(ValueError, match="behind"):
        reproject(model, *args, behind="skip")
