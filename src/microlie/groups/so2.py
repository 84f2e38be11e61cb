"""SO(2): planar rotations, stored as unit complex numbers ``(cos theta, sin theta)``."""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _array as A
from .._array import Array
from .base import LieGroup
from .so3 import checked_unit_quat, unit_tolerance


class SO2(LieGroup):
    """Planar rotations. Parameters ``(cos theta, sin theta)``; tangent ``(theta,)``.

    ``Jr = Jl = 1`` and ``Ad = 1`` (the group is commutative).

    Parameters
    ----------
    params : array_like
        ``(*batch, 2)`` unit complex numbers ``(cos, sin)``.
    normalize : bool
        Normalise instead of raising ``ValueError`` on a norm off 1.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SO2
    >>> R = SO2.from_angle(np.pi / 2)
    >>> np.round(R.act(np.array([1.0, 0.0])), 12)
    array([0., 1.])
    """

    dof = 1
    param_dim = 2
    matrix_dim = 2
    point_dim = 2
    _identity_params = (1.0, 0.0)
    _generators = np.array([[[0.0, -1.0], [1.0, 0.0]]])
    # facts for the generic test suite: the rotation's entries of the tangent vector
    _rotation_slice = slice(0, 1)

    @classmethod
    def _exact_pi_element(cls) -> SO2:
        """The rotation by exactly pi, ``(cos, sin) = (-1, 0)`` with no rounding."""
        return cls(np.array([-1.0, 0.0]))

    @classmethod
    def _validate_params(cls, p: Array, normalize: bool) -> Array:
        return checked_unit_quat(p, normalize, "SO2", kind="complex number (cos, sin)")

    @classmethod
    def _params_of_matrix(cls, R: np.ndarray) -> np.ndarray:
        """``(cos, sin)`` of rotation matrices ``(..., 2, 2)``, unchecked (first column)."""
        return np.ascontiguousarray(R[..., :, 0])

    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        a = rng.uniform(-np.pi, np.pi, batch_shape)
        return np.stack([np.cos(a), np.sin(a)], -1)

    @staticmethod
    def _exp(o, tau):
        return (o.cos(tau[0]), o.sin(tau[0]))

    @staticmethod
    def _log(o, p):
        return (o.atan2(p[1], p[0]),)

    @staticmethod
    def _compose(o, p, q):
        return (p[0] * q[0] - p[1] * q[1], p[1] * q[0] + p[0] * q[1])

    @staticmethod
    def _inverse(o, p):
        return (p[0], -p[1])

    @staticmethod
    def _act(o, p, v):
        c, s = p
        return (c * v[0] - s * v[1], s * v[0] + c * v[1])

    @staticmethod
    def _act_jac(o, p, v):
        c, s = p
        x, y = c * v[0] - s * v[1], s * v[0] + c * v[1]
        return ((-y,), (x,)), ((c, -s), (s, c))

    @staticmethod
    def _adjoint(o, p):
        return ((0.0 * p[0] + 1.0,),)

    @staticmethod
    def _matrix(o, p):
        c, s = p
        return ((c, -s), (s, c))

    @classmethod
    def _jr(cls, o, tau):
        return ((0.0 * tau[0] + 1.0,),)

    @classmethod
    def _jr_inv(cls, o, tau):
        return ((0.0 * tau[0] + 1.0,),)

    @classmethod
    def from_angle(cls, theta: Any) -> SO2:
        """From angles (radians) of any shape.

        Parameters
        ----------
        theta : array_like
            Angles; their shape is the batch shape.

        Returns
        -------
        SO2

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO2
        >>> SO2.from_angle([0.0, np.pi]).params.round(12).tolist()
        [[1.0, 0.0], [-1.0, 0.0]]
        """
        t = A.as_float_array(theta)
        return cls.exp(t[..., None])

    def angle(self) -> Array:
        """The angle in ``(-pi, pi]``.

        Returns
        -------
        array
            Shape ``batch_shape``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO2
        >>> round(float(SO2.from_angle(3 * np.pi / 2).angle()), 12) == round(-np.pi / 2, 12)
        True
        """
        return self.log()[..., 0]

    @classmethod
    def from_matrix(cls, matrix: Any, normalize: bool = False) -> SO2:
        """From rotation matrices (orthogonal, determinant +1).

        Parameters
        ----------
        matrix : array_like
            ``(..., 2, 2)``.
        normalize : bool
            Project onto the rotations instead of raising ``ValueError``.

        Returns
        -------
        SO2

        Examples
        --------
        >>> from microlie import SO2
        >>> SO2.from_matrix([[0.0, -1.0], [1.0, 0.0]]).params.tolist()
        [0.0, 1.0]
        """
        R = A.as_float_array(matrix)
        A.check_last_dim(R, (2, 2), "SO2 matrix")
        A.check_finite(R, "SO2 matrix")
        return cls._wrap(rotation2_params(R, normalize, "SO2.from_matrix"))


def rotation2_params(R: Array, normalize: bool, what: str) -> Array:
    """``(cos, sin)`` of 2x2 rotation matrices, checked (or projected with ``normalize``)."""
    xp = A.namespace(R)
    # the nearest rotation to [[a, b], [c, d]] has (cos, sin) along (a + d, c - b)
    cs = xp.stack([R[..., 0, 0] + R[..., 1, 1], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    v = A.host_values(R)
    if not normalize and v is not None and v.size:
        err = float(np.max(np.abs(np.swapaxes(v, -1, -2) @ v - np.eye(2))))
        tol = unit_tolerance(R.dtype)
        if err > tol:
            raise ValueError(f"{what}: matrix is not orthogonal (max |R^T R - I| = {err:.3g}, "
                             f"tolerance {tol:g}); pass normalize=True to project it")
        if bool(np.any(np.linalg.det(v) < 0)):
            raise ValueError(f"{what}: matrix has determinant -1 (a reflection, not a rotation)")
    n = xp.sqrt(xp.sum(cs * cs, axis=-1, keepdims=True))
    if v is not None and v.size:
        cv = np.stack([v[..., 0, 0] + v[..., 1, 1], v[..., 1, 0] - v[..., 0, 1]], axis=-1)
        if bool(np.any(np.sum(cv * cv, axis=-1) == 0)):
            raise ValueError(f"{what}: matrix has no nearest rotation (zero rotation part)")
    return cs / n
