"""SE(3): rigid motions, stored as ``(tx, ty, tz, qx, qy, qz, qw)``.

Tangent vectors are ``tau = (rho, phi)``: translation part first, then the rotation vector.
"""

from __future__ import annotations

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
    small = t2 < M.SMALL2
    t2s = t2 + small
    t = o.sqrt(t2s)
    st, ct = o.sin(t), o.cos(t)
    t4 = t2s * t2s
    c2 = o.where(small, M.horner(t2, M.C_COS4), (t2s + 2.0 * ct - 2.0) / (2.0 * t4))
    c3 = o.where(small, M.horner(t2, M.C_SIN5), (2.0 * t - 3.0 * st + t * ct) / (2.0 * t4 * t))
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


def _block_transpose(m: tuple) -> tuple:
    """Transpose each 3x3 block of a 6x6 component matrix (keeping the blocks in place)."""
    return tuple(tuple(m[3 * (i // 3) + j % 3][3 * (j // 3) + i % 3] for j in range(6))
                 for i in range(6))


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

    @classmethod
    def _jr_inv_pair(cls, o, tau):
        """``Jr^-1(tau)`` and ``Jl^-1(tau) = Jr^-1(-tau)``: every 3x3 block of the second is
        the transpose of the first's (``Jl^-1_SO3 = (Jr^-1_SO3)^T``, ``Q(-rho, -phi) =
        Q(rho, phi)^T``)."""
        right = cls._jr_inv(o, tau)
        return right, _block_transpose(right)
