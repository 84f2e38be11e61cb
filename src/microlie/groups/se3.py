"""SE(3): rigid motions, stored as ``(tx, ty, tz, qx, qy, qz, qw)``.

Tangent vectors are ``tau = (rho, phi)``: translation part first, then the rotation vector.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

from . import _math as M
from . import so3
from ._pose import Pose
from .so3 import SO3


def q_block(o: Any, rho: tuple, phi: tuple) -> tuple:
    """The block ``Q(rho, phi)`` of the left Jacobian of SE(3) (Sola et al. eq. 180, Barfoot's
    ``Q``); the right Jacobian uses ``Q(-rho, -phi) = Q(rho, phi)^T``.

    With ``hat(a) hat(b) = b a^T - (a.b) I`` the textbook products reduce to
    ``Q = P/2 + c1 (rho phi^T + phi rho^T - 2d I - d F) + c2 (hat(phi x (phi x rho)) + d F)
    - 2 c3 d F^2`` (``d = rho . phi``, ``P = hat(rho)``, ``F = hat(phi)``): a symmetric part
    ``E = c1 (rho phi^T + phi rho^T) - 2 c3 d phi phi^T + (2 c3 d t^2 - 2 c1 d) I`` plus the
    antisymmetric ``hat(w)``, ``w = rho/2 + (c2 - c1) d phi + c2 phi x (phi x rho)``. The
    even and odd degrees in ``(rho, phi)`` are exactly these two parts, hence the transpose.
    """
    t2 = M.norm2(*phi)
    k, ch = so3.half_angle(o, t2)
    c1 = so3.coef_b(o, t2, k, ch)
    c2, c3 = o.select(t2 < M.SMALL2, _q_series, partial(_q_closed, o), t2)
    d = M.dot(rho, phi)
    a = M.cross(phi, M.cross(phi, rho))
    e = (c2 - c1) * d
    w = tuple(0.5 * rho[i] + e * phi[i] + c2 * a[i] for i in range(3))
    f = 2.0 * c3 * d
    diag = f * t2 - 2.0 * c1 * d
    u = tuple(c1 * x for x in rho)
    v = tuple(u[i] - f * phi[i] for i in range(3))  # E_ij = v_i phi_j + phi_i u_j (+ diag)
    E = [[v[i] * phi[j] + phi[i] * u[j] for j in range(3)] for i in range(3)]
    return ((E[0][0] + diag, E[0][1] - w[2], E[0][2] + w[1]),
            (E[1][0] + w[2], E[1][1] + diag, E[1][2] - w[0]),
            (E[2][0] - w[1], E[2][1] + w[0], E[2][2] + diag))


def _q_series(t2: Any) -> tuple:
    return M.horner(t2, M.C_COS4), M.horner(t2, M.C_SIN5)


def _q_closed(o: Any, t2: Any) -> tuple:
    """``(t^2 + 2 cos t - 2) / (2 t^4)`` and ``(2 t - 3 sin t + t cos t) / (2 t^5)``."""
    t2s = t2 + (t2 < M.SMALL2)  # safe substitute below SMALL2
    t = o.sqrt(t2s)
    st, ct = o.sin(t), o.cos(t)
    t4 = t2s * t2s
    return (t2s + 2.0 * ct - 2.0) / (2.0 * t4), (2.0 * t - 3.0 * st + t * ct) / (2.0 * t4 * t)


def _jinv_block(Ji: tuple, Q: tuple) -> tuple:
    """``[[Ji, -Ji Q Ji], [0, Ji]]``: the inverse of ``[[J, Q], [0, J]]`` with ``Ji = J^-1``."""
    return M.blocks([[Ji, M.matmul(M.matmul(Ji, M.neg(Q)), Ji)],
                     [M.zeros(3, 3, Ji[0][0]), Ji]])


def v_times(o: Any, phi: tuple, t2: Any, k: Any, ch: Any, v: tuple) -> tuple:
    """``V(phi) v = v + a (phi x v) + b phi x (phi x v)`` (``V = Jl_SO3``), given
    ``half_angle``'s ``k, ch``: ``a = (1 - cos t)/t^2 = 2 k^2``, ``b = (t - sin t)/t^3``."""
    a = 2.0 * k * k
    b = so3.coef_b(o, t2, k, ch)
    c = M.cross(phi, v)
    d = M.cross(phi, c)
    return tuple(v[i] + a * c[i] + b * d[i] for i in range(3))


def _block2(J: tuple, B: tuple) -> tuple:
    """``[[J, B], [0, J]]`` from 3x3 component matrices (constant zeros)."""
    return tuple((*J[i], *B[i]) for i in range(3)) + tuple((0.0, 0.0, 0.0, *J[i])
                                                          for i in range(3))


class SE3(Pose):
    """Rigid motions in 3-D. Parameters ``(tx, ty, tz, qx, qy, qz, qw)``.

    Tangent ``tau = (rho, phi)`` (translation first; Jacobians: Sola et al. eqs. 179-180).
    ``X.act(p) = R p + t``. Right plus/minus and right Jacobians by default; ``side="left"``
    for left ones.

    Parameters
    ----------
    params : array_like
        ``(*batch, 7)``: translation, then the quaternion ``(x, y, z, w)``.
    normalize : bool
        Normalise the quaternion instead of raising ``ValueError`` on a norm off 1.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE3
    >>> T = SE3.exp(np.array([1.0, 0.0, 0.0, 0.0, 0.0, np.pi / 2]))
    >>> np.round(T.translation(), 6)  # (2 / pi, 2 / pi, 0): a quarter screw
    array([0.63662, 0.63662, 0.     ])
    """

    dof = 6
    param_dim = 7
    matrix_dim = 4
    point_dim = 3
    _identity_params = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)
    _rotation = SO3
    _generators = np.concatenate([
        np.eye(4)[:3, :, None] * np.eye(4)[3][None, None, :],  # rho_i: entry (i, 3)
        np.pad(SO3._generators, ((0, 0), (0, 1), (0, 1))),
    ])


    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        return np.concatenate(
            [rng.standard_normal((*batch_shape, 3)), SO3._random_params(rng, batch_shape)], -1)

    @staticmethod
    def _exp(o, tau):
        rho, phi = tau[:3], tau[3:]
        t2 = M.norm2(*phi)
        k, ch = so3.half_angle(o, t2)
        t = v_times(o, phi, t2, k, ch, rho)
        return (*t, *o.times(k, phi), ch)

    @staticmethod
    def _log(o, p):
        t, q = p[:3], p[3:]
        phi, kl, aw = so3.quat_log_parts(o, q)
        t2 = M.norm2(*phi)
        # half-angle functions straight from the quaternion: sin(t/2)/t = 1/kl, cos(t/2) = |w|
        c = so3.coef_c(o, t2, 1.0 / kl, aw)
        a = M.cross(phi, t)
        b = M.cross(phi, a)
        return (*(t[i] - 0.5 * a[i] + c * b[i] for i in range(3)), *phi)

    @staticmethod
    def _compose(o, p, q):
        a = p[3:]
        r = so3.quat_rotate(a, q)  # reads q[0:3], the translation of q
        return (p[0] + r[0], p[1] + r[1], p[2] + r[2], *so3.quat_mul(a, q[3:]))

    @staticmethod
    def _inverse(o, p):
        qi = so3.quat_conj(p[3:])
        t = so3.quat_rotate(qi, p[:3])
        return (-t[0], -t[1], -t[2], *qi)

    @staticmethod
    def _act(o, p, v):
        r = so3.quat_rotate(p[3:], v)
        return (r[0] + p[0], r[1] + p[1], r[2] + p[2])

    @staticmethod
    def _act_jac(o, p, v):
        R = so3.quat_to_matrix(p[3:])
        return M.blocks([[R, M.neg(M.matmul(R, M.hat3(v)))]]), R

    @staticmethod
    def _adjoint(o, p):
        R = so3.quat_to_matrix(p[3:])
        return M.blocks([[R, M.matmul(M.hat3(p[:3]), R)], [M.zeros(3, 3, p[0]), R]])

    @staticmethod
    def _matrix(o, p):
        R = so3.quat_to_matrix(p[3:])
        z = 0.0 * p[0]
        return tuple((*R[i], p[i]) for i in range(3)) + ((z, z, z, z + 1.0),)

    @classmethod
    def _jr(cls, o, tau):
        rho, phi = tau[:3], tau[3:]
        J = so3.jr(o, phi)
        return M.blocks([[J, M.transpose(q_block(o, rho, phi))], [M.zeros(3, 3, rho[0]), J]])

    @classmethod
    def _jr_inv(cls, o, tau):
        rho, phi = tau[:3], tau[3:]
        return _jinv_block(so3.jr_inv(o, phi), M.transpose(q_block(o, rho, phi)))

    @staticmethod
    def _minus_jac(o, y, x):
        """``tau = Log(x^-1 y)``, ``Jr^-1(tau)`` and ``-Jl^-1(tau)`` in one pass.

        ``Jr^-1 = [[Ji, B], [0, Ji]]`` with ``Ji = Jr^-1_SO3(phi)`` and, written out,
        ``B = hat(rho)/2 + c (rho phi^T + phi rho^T - 2 d I) + 2 d c' hat(phi)^2``
        (``d = rho . phi``, ``c`` the ``hat(phi)^2`` coefficient of ``Ji`` and ``c' = dc/dt2``):
        the upper block of a function of ``ad_tau`` is its derivative along ``hat(rho)``
        (equal to ``-Ji Q^T Ji`` of Sola et al. eq. 180). Every block of ``Jl^-1(tau) =
        Jr^-1(-tau)`` is the transpose of the right one's, so ``-Jl^-1`` is
        ``[[hat(phi)/2 - S, hat(rho)/2 - E], [0, hat(phi)/2 - S]]`` with ``S``, ``E`` the
        symmetric parts of ``Ji`` and ``B``.
        """
        z = SE3._compose(o, SE3._inverse(o, x), y)
        t, q = z[:3], z[3:]
        phi, kl, aw = so3.quat_log_parts(o, q)
        t2 = M.norm2(*phi)
        c, cp = so3.coef_c_slope(o, t2, 1.0 / kl, aw)
        a = M.cross(phi, t)
        b = M.cross(phi, a)
        rho = tuple(t[i] - 0.5 * a[i] + c * b[i] for i in range(3))  # as SE3._log
        Ji, mJi = so3.jr_inv_pair_c(o, c, phi, t2)
        d = M.dot(rho, phi)
        g = 2.0 * d * cp
        u = tuple(c * r for r in rho)
        w = tuple(u[i] + g * phi[i] for i in range(3))  # E_ij = u_i phi_j + phi_i w_j + e I
        e = -2.0 * c * d - g * t2
        px, py, pz = phi
        B, mB = so3.sym_pair(o, (px * (u[0] + w[0]), py * (u[1] + w[1]), pz * (u[2] + w[2])), e,
                             (u[0] * py + px * w[1], u[0] * pz + px * w[2],
                              u[1] * pz + py * w[2]),
                             (0.5 * rho[0], 0.5 * rho[1], 0.5 * rho[2]))
        return ((*rho, *phi), _block2(Ji, B), _block2(mJi, mB))
