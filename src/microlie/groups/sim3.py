"""Sim(3): similarity transforms (monocular scale), stored as ``(t, q, s)``.

Parameters ``(tx, ty, tz, qx, qy, qz, qw, s)`` with ``s > 0``; the matrix is ``[[s R, t], [0, 1]]``
(the convention of the lecture notes and evo; GTSAM's Similarity3 uses ``[[R, t], [0, 1/s]]``).
Tangent ``zeta = (rho, phi, sigma)`` with ``s = exp(sigma)``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _array as A
from .._array import Array
from . import _math as M
from . import so3
from ._pose import Pose, concat_last
from .se3 import SE3
from .so3 import SO3

# Gauss-Legendre nodes and weights on [0, 1]. The coefficients of W are integrals of smooth
# entire functions of s; 16 nodes integrate them to rounding error for |sigma| + theta up to
# about 15 (scales between 1e-5 and 1e5 at any angle), with no special case at sigma = 0 or
# theta = 0.
_X, _W = np.polynomial.legendre.leggauss(16)
_NODES = tuple(float(x) for x in 0.5 * (_X + 1.0))
_WEIGHTS = tuple(float(w) for w in 0.5 * _W)


def w_coefficients(o: Any, sigma: Any, t2: Any) -> tuple[Any, Any, Any]:
    """``W = a I + b hat(phi) + c hat(phi)^2``, ``W = int_0^1 exp(s sigma) Exp(s phi) ds``.

    ``a = (e^sigma - 1)/sigma``, ``b = int e^(s sigma) sin(s t)/t ds``,
    ``c = int e^(s sigma) (1 - cos(s t))/t^2 ds`` (MATH.md section 5), by quadrature.
    """
    small = o.abs(sigma) < 1e-5
    ss = sigma + small
    a = o.where(small, 1.0 + sigma * (0.5 + sigma * (1.0 / 6.0 + sigma / 24.0)), o.expm1(ss) / ss)
    b = 0.0 * sigma
    c = 0.0 * sigma
    for s, w in zip(_NODES, _WEIGHTS, strict=True):
        u2 = (s * s) * t2
        hs, hc = so3.half_angle(o, u2)  # sin(s t / 2) / (s t), cos(s t / 2)
        e = w * o.exp(s * sigma)
        b = b + e * (2.0 * s) * hs * hc
        c = c + e * (2.0 * s * s) * hs * hs
    return a, b, c


def w_matrix(o: Any, phi: tuple, sigma: Any) -> tuple:
    t2 = M.norm2(*phi)
    a, b, c = w_coefficients(o, sigma, t2)
    F = M.hat3(phi)
    F2 = so3.hat_sq(phi, t2)
    return tuple(
        tuple((a if i == j else 0.0) + b * F[i][j] + c * F2[i][j] for j in range(3))
        for i in range(3)
    )


class Sim3(Pose):
    """Similarity transforms in 3-D. Parameters ``(tx, ty, tz, qx, qy, qz, qw, s)``.

    Tangent ``(rho, phi, sigma)``, ``s = exp(sigma)``; ``X.act(p) = s R p + t``. Right plus/minus
    and right Jacobians by default. ``Jr`` has no short closed form: it is computed from
    ``Jr(tau) = int_0^1 Ad_Exp(-s tau) ds`` (halving plus series, see :meth:`LieGroup.jr`) and
    checked against finite differences in the tests.

    >>> import numpy as np
    >>> from microlie import Sim3
    >>> S = Sim3.exp(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, np.log(2.0)]))
    >>> S.act(np.array([1.0, 2.0, 3.0]))
    array([2., 4., 6.])
    """

    dof = 7
    param_dim = 8
    _has_closed_jr = False
    matrix_dim = 4
    point_dim = 3
    _identity_params = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0)
    _rotation = SO3
    _generators = np.concatenate([
        np.eye(4)[:3, :, None] * np.eye(4)[3][None, None, :],
        np.pad(SO3._generators, ((0, 0), (0, 1), (0, 1))),
        np.diag([1.0, 1.0, 1.0, 0.0])[None],
    ])

    @classmethod
    def _validate_params(cls, p: Array, normalize: bool) -> Array:
        check_positive_scale(p[..., 7])
        return super()._validate_params(p, normalize)

    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        return np.concatenate([
            rng.standard_normal((*batch_shape, 3)),
            SO3._random_params(rng, batch_shape),
            np.exp(0.5 * rng.standard_normal((*batch_shape, 1))),
        ], -1)

    @staticmethod
    def _exp(o, tau):
        rho, phi, sigma = tau[:3], tau[3:6], tau[6]
        W = w_matrix(o, phi, sigma)
        return (*M.matvec(W, rho), *so3.quat_exp(o, phi), o.exp(sigma))

    @staticmethod
    def _log(o, p):
        t, q, s = p[:3], p[3:7], p[7]
        phi = so3.quat_log(o, q)
        sigma = o.log(s)
        W = w_matrix(o, phi, sigma)
        rho = M.matvec(M.adjugate3(W), t)
        det = M.det3(W)
        return (*(r / det for r in rho), *phi, sigma)

    @staticmethod
    def _compose(o, p, q):
        r = so3.quat_rotate(p[3:7], q[:3])
        s = p[7]
        return (p[0] + s * r[0], p[1] + s * r[1], p[2] + s * r[2],
                *so3.quat_mul(p[3:7], q[3:7]), s * q[7])

    @staticmethod
    def _inverse(o, p):
        qi = so3.quat_conj(p[3:7])
        si = 1.0 / p[7]
        t = so3.quat_rotate(qi, p[:3])
        return (-si * t[0], -si * t[1], -si * t[2], *qi, si)

    @staticmethod
    def _act(o, p, v):
        r = so3.quat_rotate(p[3:7], v)
        s = p[7]
        return (s * r[0] + p[0], s * r[1] + p[1], s * r[2] + p[2])

    @staticmethod
    def _act_jac(o, p, v):
        sR = M.scale(so3.quat_to_matrix(p[3:7]), p[7])
        sRv = M.matvec(sR, v)
        return M.blocks([[sR, M.neg(M.matmul(sR, M.hat3(v))), tuple((x,) for x in sRv)]]), sR

    @staticmethod
    def _adjoint(o, p):
        R = so3.quat_to_matrix(p[3:7])
        t = p[:3]
        z = 0.0 * p[0]
        Z3 = M.zeros(3, 3, z)
        col_t = tuple((-x,) for x in t)
        zc = ((z,), (z,), (z,))
        return M.blocks([
            [M.scale(R, p[7]), M.matmul(M.hat3(t), R), col_t],
            [Z3, R, zc],
            [((z, z, z),), ((z, z, z),), ((z + 1.0,),)],
        ])

    @staticmethod
    def _matrix(o, p):
        sR = M.scale(so3.quat_to_matrix(p[3:7]), p[7])
        z = 0.0 * p[0]
        return tuple((*sR[i], p[i]) for i in range(3)) + ((z, z, z, z + 1.0),)

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_rotation_translation_scale(cls, rotation: SO3 | Any, translation: Any,
                                        scale: Any) -> Sim3:
        """From a rotation (:class:`SO3` or matrices), translations ``(..., 3)`` and positive
        scales ``(...)``; the batch axes broadcast."""
        T = SE3.from_rotation_translation(rotation, translation)
        s = A.as_float_array(scale, like=T.params)
        A.check_finite(s, "scale")
        check_positive_scale(s)
        return cls._wrap(concat_last(T.params, s[..., None]))

    @classmethod
    def from_rotation_translation(cls, rotation: Any, translation: Any) -> Sim3:
        """From a rotation and translations, with scale 1."""
        return cls.from_rotation_translation_scale(rotation, translation, 1.0)

    @classmethod
    def from_matrix(cls, matrix: Any, normalize: bool = False) -> Sim3:
        """From matrices ``[[s R, t], [0, 1]]`` ``(..., 4, 4)``; ``s = det(sR)^(1/3)``."""
        sR, t = cls._split_matrix(matrix, normalize)
        xp = A.namespace(sR)
        det = xp.linalg.det(sR)
        v = A.host_values(sR)
        if v is not None and bool(np.any(np.linalg.det(v) <= 0)):
            raise ValueError("Sim3.from_matrix: the 3x3 block must have a positive determinant")
        s = det ** (1.0 / 3.0)
        R = SO3.from_matrix(sR / s[..., None, None], normalize=normalize)
        return cls.from_rotation_translation_scale(R, t, s)

    def scale(self) -> Array:
        """The scale ``s > 0`` (shape ``batch_shape``)."""
        return self.params[..., 7]


def check_positive_scale(s: Array) -> None:
    v = A.host_values(s)
    if v is not None and bool(np.any(v <= 0)):
        raise ValueError("Sim3: scale must be positive")
