"""SE_2(3): extended poses (rotation, position, velocity), stored as
``(px, py, pz, qx, qy, qz, qw, vx, vy, vz)``.

Tangent vectors are ``tau = (rho, phi, nu)``: position part, rotation vector, velocity part. This
is manif's order and it makes the first six entries exactly SE(3)'s tangent ``(rho, phi)`` in
the project's translation-first convention (an SE_2(3) tangent restricted to its first six
entries is the SE(3) tangent of the pose ``(R, p)``).

The 5x5 matrix is ``[[R, p, v], [0, 1, 0], [0, 0, 1]]`` (position in column 3, velocity in column
4, as in manif). ``X.act(x) = R x + p`` (the pose acting on a point).
"""

from __future__ import annotations

from typing import Any, cast

import numpy as np

from .. import _array as A
from . import _math as M
from . import so3
from ._pose import Pose, check_bottom_row, concat_last
from .se3 import q_block, v_times
from .so3 import SO3


def _neg(v: tuple) -> tuple:
    return tuple(-x for x in v)


class SE23(Pose):
    """Extended poses in 3-D (rotation, position, velocity): the group of IMU navigation states.

    Tangent ``tau = (rho, phi, nu)`` (position, rotation, velocity; the first six are SE(3)'s
    tangent). Matrix ``[[R, p, v], [0, 1, 0], [0, 0, 1]]``. ``X.act(x) = R x + p``. Right
    plus/minus and right Jacobians by default; ``side="left"`` for left ones.

    Parameters
    ----------
    params : array_like
        ``(..., 10)``: ``(px, py, pz, qx, qy, qz, qw, vx, vy, vz)``; the quaternion must be
        unit within tolerance (``ValueError`` otherwise) unless ``normalize=True``.
    normalize : bool
        Normalise the quaternion.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE23
    >>> X = SE23.exp(np.array([1.0, 0, 0, 0, 0, np.pi / 2, 0, 2.0, 0]))
    >>> np.round(X.translation(), 6), np.round(X.velocity(), 6)
    (array([0.63662, 0.63662, 0.     ]), array([-1.27324,  1.27324,  0.     ]))
    """

    dof = 9
    param_dim = 10
    matrix_dim = 5
    point_dim = 3
    _identity_params = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    _rotation = SO3
    _generators = np.concatenate([
        np.eye(5)[:3, :, None] * np.eye(5)[3][None, None, :],  # rho_i: entry (i, 3)
        np.pad(SO3._generators, ((0, 0), (0, 2), (0, 2))),
        np.eye(5)[:3, :, None] * np.eye(5)[4][None, None, :],  # nu_i: entry (i, 4)
    ])

    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        return np.concatenate([rng.standard_normal((*batch_shape, 3)),
                               SO3._random_params(rng, batch_shape),
                               rng.standard_normal((*batch_shape, 3))], -1)

    @staticmethod
    def _exp(o, tau):
        rho, phi, nu = tau[:3], tau[3:6], tau[6:]
        t2 = M.norm2(*phi)
        k, ch = so3.half_angle(o, t2)
        p = v_times(o, phi, t2, k, ch, rho)
        v = v_times(o, phi, t2, k, ch, nu)
        return (*p, k * phi[0], k * phi[1], k * phi[2], ch, *v)

    @staticmethod
    def _log(o, p):
        t, q, v = p[:3], p[3:7], p[7:]
        phi, kl, aw = so3.quat_log_parts(o, q)
        t2 = M.norm2(*phi)
        c = so3.coef_c(o, t2, 1.0 / kl, aw)

        def v_inv(x):  # Jl_SO3(phi)^-1 x = x - (phi x x)/2 + c phi x (phi x x)
            a = M.cross(phi, x)
            b = M.cross(phi, a)
            return tuple(x[i] - 0.5 * a[i] + c * b[i] for i in range(3))

        return (*v_inv(t), *phi, *v_inv(v))

    @staticmethod
    def _compose(o, p, q):
        a = p[3:7]
        r = so3.quat_rotate(a, q)  # q[0:3], the position of q
        s = so3.quat_rotate(a, q[7:])
        return (p[0] + r[0], p[1] + r[1], p[2] + r[2], *so3.quat_mul(a, q[3:7]),
                p[7] + s[0], p[8] + s[1], p[9] + s[2])

    @staticmethod
    def _inverse(o, p):
        qi = so3.quat_conj(p[3:7])
        t = so3.quat_rotate(qi, p[:3])
        v = so3.quat_rotate(qi, p[7:])
        return (-t[0], -t[1], -t[2], *qi, -v[0], -v[1], -v[2])

    @staticmethod
    def _act(o, p, v):
        r = so3.quat_rotate(p[3:7], v)
        return (r[0] + p[0], r[1] + p[1], r[2] + p[2])

    @staticmethod
    def _act_jac(o, p, v):
        R = so3.quat_to_matrix(p[3:7])
        return M.blocks([[R, M.neg(M.matmul(R, M.hat3(v))), M.zeros(3, 3, p[0])]]), R

    @staticmethod
    def _adjoint(o, p):
        R = so3.quat_to_matrix(p[3:7])
        Z = M.zeros(3, 3, p[0])
        return M.blocks([[R, M.matmul(M.hat3(p[:3]), R), Z],
                         [Z, R, Z],
                         [Z, M.matmul(M.hat3(p[7:]), R), R]])

    @staticmethod
    def _matrix(o, p):
        R = so3.quat_to_matrix(p[3:7])
        z = 0.0 * p[0]
        return tuple((*R[i], p[i], p[7 + i]) for i in range(3)) + (
            (z, z, z, z + 1.0, z), (z, z, z, z, z + 1.0))

    @classmethod
    def _jr(cls, o, tau):
        rho, phi, nu = tau[:3], tau[3:6], tau[6:]
        J = so3.jr(o, phi)
        Z = M.zeros(3, 3, rho[0])
        Qr = q_block(o, _neg(rho), _neg(phi))
        Qn = q_block(o, _neg(nu), _neg(phi))
        return M.blocks([[J, Qr, Z], [Z, J, Z], [Z, Qn, J]])

    @classmethod
    def _jr_inv(cls, o, tau):
        rho, phi, nu = tau[:3], tau[3:6], tau[6:]
        Ji = so3.jr_inv(o, phi)
        Z = M.zeros(3, 3, rho[0])
        Qr = q_block(o, _neg(rho), _neg(phi))
        Qn = q_block(o, _neg(nu), _neg(phi))
        return M.blocks([[Ji, M.neg(M.matmul(Ji, M.matmul(Qr, Ji))), Z],
                         [Z, Ji, Z],
                         [Z, M.neg(M.matmul(Ji, M.matmul(Qn, Ji))), Ji]])

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_rotation_translation(cls, rotation: Any, translation: Any,
                                  velocity: Any = None) -> SE23:
        """From rotations, positions and velocities (the batch axes broadcast).

        Parameters
        ----------
        rotation : SO3 or array_like
            Rotations, or rotation matrices ``(..., 3, 3)``.
        translation : array_like
            Positions ``(..., 3)``.
        velocity : array_like, optional
            Velocities ``(..., 3)`` (zero if omitted).

        Returns
        -------
        SE23

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23, SO3
        >>> X = SE23.from_rotation_translation(SO3.identity(), [1.0, 2.0, 3.0], [0.5, 0, 0])
        >>> X.params.tolist()
        [1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0, 0.5, 0.0, 0.0]
        """
        R = rotation if isinstance(rotation, SO3) else SO3.from_matrix(rotation)
        t = A.as_float_array(translation, like=R.params)
        v = A.as_float_array(0.0 * t if velocity is None else velocity, like=R.params)
        for x, what in ((t, "translation"), (v, "velocity")):
            A.check_last_dim(x, 3, what)
            A.check_finite(x, what)
        return cast(SE23, cls._wrap(concat_last(t, R.params, v)))

    @classmethod
    def from_matrix(cls, matrix: Any, normalize: bool = False) -> SE23:
        """From 5x5 matrices ``[[R, p, v], [0, 1, 0], [0, 0, 1]]``.

        Parameters
        ----------
        matrix : array_like
            ``(..., 5, 5)``; ``R`` must be a rotation within tolerance (``ValueError``
            otherwise) and the last two rows ``[0 0 0 1 0]``, ``[0 0 0 0 1]``.
        normalize : bool
            Project ``R`` onto SO(3).

        Returns
        -------
        SE23

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> X = SE23.random(rng=0)
        >>> bool(np.allclose(SE23.from_matrix(X.matrix()).matrix(), X.matrix()))
        True
        """
        T = A.as_float_array(matrix)
        A.check_last_dim(T, (5, 5), "SE23 matrix")
        A.check_finite(T, "SE23 matrix")
        check_bottom_row(T, "SE23.from_matrix")
        check_bottom_row(T[..., :4, :4], "SE23.from_matrix")
        v = A.host_values(T)  # read on the host: never a traced value
        if v is not None and v.size:
            if float(np.max(np.abs(v[..., 3, 4]))) > 1e-9:
                raise ValueError("SE23.from_matrix: the last two rows must be "
                                 "[0 0 0 1 0] and [0 0 0 0 1]")
        R = SO3.from_matrix(T[..., :3, :3], normalize=normalize)
        return cls.from_rotation_translation(R, T[..., :3, 3], T[..., :3, 4])

    def velocity(self) -> Any:
        """The velocity part.

        Returns
        -------
        array
            ``(..., 3)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> SE23.exp(np.array([0, 0, 0, 0, 0, 0, 1.0, 2.0, 3.0])).velocity().tolist()
        [1.0, 2.0, 3.0]
        """
        return self.params[..., 7:]

    def pose(self) -> Any:
        """The ``SE3`` pose ``(R, p)`` (the velocity dropped).

        Returns
        -------
        SE3

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> SE23.exp(np.array([1.0, 0, 0, 0, 0, 0, 2.0, 0, 0])).pose().translation().tolist()
        [1.0, 0.0, 0.0]
        """
        from .se3 import SE3

        return SE3._wrap(self.params[..., :7])
