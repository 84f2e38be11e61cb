"""SE(2): planar rigid motions, stored as ``(x, y, cos theta, sin theta)``.

Tangent vectors are ``(rho_x, rho_y, theta)``: translation first.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _array as A
from .._array import Array
from . import _math as M
from ._pose import Pose
from .so2 import SO2
from .so3 import coef_b, half_angle


def half_cot(o: Any, h: Any) -> Any:
    """``h cot h`` (``h`` in ``[-pi/2, pi/2]``), 1 at ``h = 0``."""
    h2 = h * h
    small = h2 < M.TINY2
    hs = h + small
    return o.where(small, M.horner(h2, M.X_COT), hs * o.cos(hs) / o.sin(hs))


class SE2(Pose):
    """Planar rigid motions. Parameters ``(x, y, cos theta, sin theta)``.

    Tangent ``(rho_x, rho_y, theta)`` (translation first, as manif and GTSAM's Pose2).
    ``X.act(p) = R p + t``. Right plus/minus and right Jacobians by default.

    Parameters
    ----------
    params : array_like
        ``(*batch, 4)``.
    normalize : bool
        Normalise ``(cos, sin)`` instead of raising ``ValueError`` on a norm off 1.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> T = SE2.from_xy_theta(1.0, 2.0, np.pi / 2)
    >>> np.round(T.act(np.array([1.0, 0.0])), 12)
    array([1., 3.])
    """

    dof = 3
    param_dim = 4
    matrix_dim = 3
    point_dim = 2
    _identity_params = (0.0, 0.0, 1.0, 0.0)
    _rotation = SO2
    _generators = np.array([
        [[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]],
        [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
    ])


    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        return np.concatenate(
            [rng.standard_normal((*batch_shape, 2)), SO2._random_params(rng, batch_shape)], -1)

    @staticmethod
    def _exp(o, tau):
        r1, r2, th = tau
        t2 = th * th
        hs, hc = half_angle(o, t2)
        a = 2.0 * hs * hc  # sin(t)/t
        b = 2.0 * th * hs * hs  # (1 - cos t)/t
        return (a * r1 - b * r2, b * r1 + a * r2, o.cos(th), o.sin(th))

    @staticmethod
    def _log(o, p):
        x, y, c, s = p
        th = o.atan2(s, c)
        h = 0.5 * th
        k = half_cot(o, h)
        return (k * x + h * y, -h * x + k * y, th)

    @staticmethod
    def _compose(o, p, q):
        c, s = p[2], p[3]
        return (p[0] + c * q[0] - s * q[1], p[1] + s * q[0] + c * q[1],
                c * q[2] - s * q[3], s * q[2] + c * q[3])

    @staticmethod
    def _inverse(o, p):
        x, y, c, s = p
        return (-(c * x + s * y), s * x - c * y, c, -s)

    @staticmethod
    def _act(o, p, v):
        x, y, c, s = p
        return (c * v[0] - s * v[1] + x, s * v[0] + c * v[1] + y)

    @staticmethod
    def _act_jac(o, p, v):
        c, s = p[2], p[3]
        rx, ry = c * v[0] - s * v[1], s * v[0] + c * v[1]
        return ((c, -s, -ry), (s, c, rx)), ((c, -s), (s, c))

    @staticmethod
    def _adjoint(o, p):
        x, y, c, s = p
        z = 0.0 * x
        return ((c, -s, y), (s, c, -x), (z, z, z + 1.0))

    @staticmethod
    def _matrix(o, p):
        x, y, c, s = p
        z = 0.0 * x
        return ((c, -s, x), (s, c, y), (z, z, z + 1.0))

    @classmethod
    def _jr(cls, o, tau):
        r1, r2, th = tau
        t2 = th * th
        hs, hc = half_angle(o, t2)
        a = 2.0 * hs * hc  # sin(t)/t
        b = 2.0 * th * hs * hs  # (1 - cos t)/t
        d1 = th * coef_b(o, t2, hs, hc)  # (t - sin t)/t^2
        d2 = 2.0 * hs * hs  # (1 - cos t)/t^2
        z = 0.0 * th
        return ((a, b, r1 * d1 - r2 * d2), (-b, a, r1 * d2 + r2 * d1), (z, z, z + 1.0))

    @classmethod
    def _jr_inv(cls, o, tau):
        r1, r2, th = tau
        t2 = th * th
        h = 0.5 * th
        k = half_cot(o, h)
        hs, hc = half_angle(o, t2)
        d1 = th * coef_b(o, t2, hs, hc)
        d2 = 2.0 * hs * hs
        v1, v2 = r1 * d1 - r2 * d2, r1 * d2 + r2 * d1
        z = 0.0 * th
        return ((k, -h, -(k * v1 - h * v2)), (h, k, -(h * v1 + k * v2)), (z, z, z + 1.0))

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_xy_theta(cls, x: Any, y: Any, theta: Any) -> SE2:
        """From positions and headings; all broadcast.

        Parameters
        ----------
        x, y : array_like
            Positions.
        theta : array_like
            Headings, radians.

        Returns
        -------
        SE2

        Examples
        --------
        >>> from microlie import SE2
        >>> SE2.from_xy_theta([0.0, 1.0], 2.0, 0.0).params.tolist()
        [[0.0, 2.0, 1.0, 0.0], [1.0, 2.0, 1.0, 0.0]]
        """
        xx = A.as_float_array(x)
        xp = A.namespace(xx)
        x, y, th = xp.broadcast_arrays(xx, A.as_float_array(y, like=xx),
                                       A.as_float_array(theta, like=xx))
        return cls._wrap(xp.stack([x, y, xp.cos(th), xp.sin(th)], axis=-1))

    def angle(self) -> Array:
        """The heading in ``(-pi, pi]``.

        Returns
        -------
        array
            Shape ``batch_shape``.

        Examples
        --------
        >>> from microlie import SE2
        >>> round(float(SE2.from_xy_theta(1.0, 2.0, 0.3).angle()), 12)
        0.3
        """
        xp = A.namespace(self.params)
        return xp.atan2(self.params[..., 3], self.params[..., 2])

