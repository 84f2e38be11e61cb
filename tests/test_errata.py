"""Every erratum of ../shared/MATH.md, pinned by a named test.

Each test checks the corrected statement against an independent computation (SciPy's
matrix exponential and logarithm, finite differences) and shows that the statement as printed
in the source notes is wrong.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm, logm

from microlie import SE3, SO3


def _hat(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _log_so3(R):
    return SO3.vee(np.real(logm(R)))


PHI = np.array([0.4, -0.7, 1.1])
DPHI = 1e-6 * np.array([0.3, 0.5, -0.2])


def test_erratum_jr_is_jl_of_minus_phi_not_jl():
    """Notes: "Jr(phi) = Jl(phi)". Correct: Jr(phi) = Jl(-phi) (= Jl(phi)^T)."""
    Jr, Jl = SO3.jr(PHI), SO3.jl(PHI)
    np.testing.assert_allclose(Jr, SO3.jl(-PHI), atol=1e-15)
    np.testing.assert_allclose(Jr, Jl.T, atol=1e-15)
    assert np.abs(Jr - Jl).max() > 0.1  # the printed statement is false
    # and independently of our Jr: Exp(phi + d) = Exp(phi) Exp(Jr d) by finite differences
    h = 1e-6
    fd = np.stack([_log_so3(expm(-_hat(PHI)) @ expm(_hat(PHI + h * e)))
                   - _log_so3(expm(-_hat(PHI)) @ expm(_hat(PHI - h * e)))
                   for e in np.eye(3)], axis=-1) / (2 * h)
    np.testing.assert_allclose(Jr, fd, atol=1e-8)


def test_erratum_right_increment_uses_jr_inverse():
    """Notes: "exp(phi^) exp(dphi^) = exp((phi + Jl^-1 dphi)^)". Correct: Jr^-1 on the right,
    Jl^-1 on the left."""
    right = _log_so3(expm(_hat(PHI)) @ expm(_hat(DPHI)))
    left = _log_so3(expm(_hat(DPHI)) @ expm(_hat(PHI)))
    np.testing.assert_allclose(right, PHI + SO3.jr_inv(PHI) @ DPHI, atol=1e-12)
    np.testing.assert_allclose(left, PHI + SO3.jl_inv(PHI) @ DPHI, atol=1e-12)
    wrong = PHI + SO3.jl_inv(PHI) @ DPHI
    assert np.abs(right - wrong).max() > 1e-7  # the printed statement misses by O(|dphi|)
    # Exp(phi + dphi) ~= Exp(phi) Exp(Jr dphi) = Exp(Jl dphi) Exp(phi)
    E = expm(_hat(PHI + DPHI))
    np.testing.assert_allclose(E, expm(_hat(PHI)) @ expm(_hat(SO3.jr(PHI) @ DPHI)), atol=1e-12)
    np.testing.assert_allclose(E, expm(_hat(SO3.jl(PHI) @ DPHI)) @ expm(_hat(PHI)), atol=1e-12)


def test_erratum_rodrigues_uses_sin_hat_a():
    """Notes: "cos t I + (1 - cos t) a a^T + sin t a^T". Correct: ``+ sin t hat(a)``."""
    t = np.linalg.norm(PHI)
    a = PHI / t
    good = np.cos(t) * np.eye(3) + (1 - np.cos(t)) * np.outer(a, a) + np.sin(t) * _hat(a)
    np.testing.assert_allclose(good, expm(_hat(PHI)), atol=1e-14)
    np.testing.assert_allclose(SO3.exp(PHI).matrix(), good, atol=1e-15)
    bad = np.cos(t) * np.eye(3) + (1 - np.cos(t)) * np.outer(a, a) + np.sin(t) * a[None, :]
    assert np.abs(bad - good).max() > 0.1


def test_erratum_series_step_one_minus_cos():
    """Notes: the series step "(a - cos t)". Correct: ``(1 - cos t) hat(a)^2``:
    Exp(phi) = I + sin t hat(a) + (1 - cos t) hat(a)^2."""
    t = np.linalg.norm(PHI)
    A = _hat(PHI / t)
    good = np.eye(3) + np.sin(t) * A + (1 - np.cos(t)) * A @ A
    np.testing.assert_allclose(good, expm(_hat(PHI)), atol=1e-14)
    np.testing.assert_allclose(SO3.exp(PHI).matrix(), good, atol=1e-15)


def test_erratum_se3_bracket():
    """Notes: "[xi1, xi2] = (hat(phi1) rho2 - hat(phi2) rho1, 0)". Correct:
    ``(phi1 x rho2 - phi2 x rho1, phi1 x phi2)``."""
    rng = np.random.default_rng(0)
    x1, x2 = rng.standard_normal((2, 6))
    r1, p1, r2, p2 = x1[:3], x1[3:], x2[:3], x2[3:]
    H1, H2 = SE3.hat(x1), SE3.hat(x2)
    ref = SE3.vee(H1 @ H2 - H2 @ H1)  # the matrix commutator, independently
    good = np.concatenate([np.cross(p1, r2) - np.cross(p2, r1), np.cross(p1, p2)])
    np.testing.assert_allclose(ref, good, atol=1e-14)
    np.testing.assert_allclose(SE3.bracket(x1, x2), good, atol=1e-14)
    np.testing.assert_allclose(SE3.ad(x1) @ x2, good, atol=1e-14)
    bad = np.concatenate([np.cross(p1, r2) - np.cross(p2, r1), np.zeros(3)])
    assert np.abs(bad - good).max() > 0.1


def test_erratum_se3_exp_bottom_right_is_one():
    """Notes: one derivation ends with ``[[R, J rho], [0, 0]]``; the bottom-right entry is 1."""
    tau = np.array([0.3, -0.2, 0.5, 0.4, -0.7, 1.1])
    T = SE3.exp(tau).matrix()
    np.testing.assert_allclose(T, expm(SE3.hat(tau)), atol=1e-14)
    assert T[3, 3] == 1.0
    np.testing.assert_allclose(T[:3, 3], SO3.jl(tau[3:]) @ tau[:3], atol=1e-15)  # V = Jl


def test_erratum_bch_first_order_is_one_half():
    """Notes: the bracket term of BCH as "1/12 [A, B]". Correct: ``1/2 [A, B]``."""
    a = 1e-2 * np.array([0.3, -0.5, 0.8])
    b = 1e-2 * np.array([-0.6, 0.2, 0.4])
    A, B = _hat(a), _hat(b)
    Z = logm(expm(A) @ expm(B)).real
    br = A @ B - B @ A
    third = (A @ br - br @ A) / 12 - (B @ br - br @ B) / 12
    good = A + B + br / 2 + third
    bad = A + B + br / 12 + third
    err_good = np.abs(Z - good).max()
    err_bad = np.abs(Z - bad).max()
    assert err_good < 1e-9  # fourth order: |a|^4 ~ 1e-8 times small constants
    assert err_bad > 1e-5  # misses the second-order term 5/12 [A, B]
    # and the first-order BCH forms of MATH.md section 10
    big = np.array([0.9, -0.3, 0.5])
    small = 1e-6 * np.array([0.2, 0.7, -0.4])
    np.testing.assert_allclose(SO3.exp(small).compose(SO3.exp(big)).log(),
                               SO3.jl_inv(big) @ small + big, atol=1e-12)
    np.testing.assert_allclose(SO3.exp(big).compose(SO3.exp(small)).log(),
                               SO3.jr_inv(big) @ small + big, atol=1e-12)


def test_peers_trap_jaxlie_small_angle_translation():
    """PEERS.md: jaxlie 1.5.0 SE3.exp([1,0,0,0,0,1e-6]) gives t_y = 1e-6; the right value is
    theta/2 * |v| = 5e-7 (V = I + 1/2 hat(omega) + ...)."""
    T = SE3.exp(np.array([1.0, 0, 0, 0, 0, 1e-6]))
    np.testing.assert_allclose(T.translation(), expm(SE3.hat([1.0, 0, 0, 0, 0, 1e-6]))[:3, 3],
                               rtol=1e-15, atol=1e-22)
    assert abs(T.translation()[1] - 5e-7) < 1e-18


def test_first_order_term_at_tiny_angles():
    """PEERS.md: several libraries drop the first-order term at theta = 1e-9 (errors ~3e-10)."""
    tau = np.array([0.3, -0.2, 0.5, 1e-9, -2e-9, 0.5e-9])
    T = SE3.exp(tau)
    ref = np.eye(4) + SE3.hat(tau) + SE3.hat(tau) @ SE3.hat(tau) / 2
    np.testing.assert_allclose(T.matrix(), ref, atol=1e-17)
    np.testing.assert_allclose(T.log(), tau, atol=1e-18)


def test_jr_inverse_coefficient_precision_near_1e_3():
    """PEERS.md: the textbook Jr^-1 coefficient loses ~1e-10 near t = 1e-3; ours does not."""
    import mpmath

    mpmath.mp.dps = 40
    for t in (1e-3, 3e-3, 0.3, 0.99, 1.01, 3.0):
        phi = np.array([t, 0.0, 0.0]) @ np.eye(3)
        c = SO3.jr_inv(phi)[1, 1] - 1.0  # = -c t^2 on the diagonal of hat(phi)^2
        tt = mpmath.mpf(t)
        ref = -(1 / tt**2 - (1 + mpmath.cos(tt)) / (2 * tt * mpmath.sin(tt))) * tt**2
        assert abs(c - float(ref)) <= 2e-16 * max(1.0, abs(float(ref)))
