"""SO(3): 3-D rotations, stored as unit quaternions ``(qx, qy, qz, qw)``.

Tangent vectors are rotation vectors ``phi`` (axis times angle, radians).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from .. import _array as A
from .. import _linalg as L
from .._array import Array
from .._kernels import Kernel, add, run
from . import _math as M
from .base import LieGroup

# ---------------------------------------------------------------------------- coefficients


def half_angle(o: Any, t2: Any) -> tuple[Any, Any]:
    """``(sin(t/2) / t, cos(t/2))`` as functions of ``t2 = t^2``.

    Below ``TINY2`` the second-order Taylor polynomials (exact to rounding there) replace the
    closed forms, whose square root has an infinite slope at 0; ``t2 + small`` is the safe
    substitute that keeps the discarded branch finite.
    """
    small = t2 < M.TINY2
    t = o.sqrt(t2 + small)
    # sin(t/2) and cos(t/2) from u = tan(t/4): one vectorised tan instead of sin and cos
    # (several times cheaper in NumPy); exact for every t, with no pole below t = 2 pi
    u = o.tan(0.25 * t)
    u2 = u * u
    r = 1.0 / (1.0 + u2)
    k = o.where(small, 0.5 - t2 * (1.0 / 48.0), (2.0 * r) * u / t)
    ch = o.where(small, 1.0 - 0.125 * t2, (1.0 - u2) * r)
    return k, ch


def coef_b(o: Any, t2: Any, k: Any, ch: Any) -> Any:
    """``(t - sin t) / t^3 = (1 - 2 k ch) / t^2`` given ``half_angle``'s ``k, ch`` (the Taylor
    series below ``SMALL2``, each branch evaluated only where it is used)."""
    return o.select(t2 < M.SMALL2, _b_series, _b_closed, t2, k, ch)


def _b_series(t2: Any, k: Any, ch: Any) -> Any:
    return M.horner(t2, M.C_T_SIN)


def _b_closed(t2: Any, k: Any, ch: Any) -> Any:
    return (1.0 - 2.0 * k * ch) / (t2 + (t2 < M.SMALL2))  # safe substitute below SMALL2


def coef_c(o: Any, t2: Any, k: Any, ch: Any) -> Any:
    """``(1 - (t/2) cot(t/2)) / t^2 = (1 - ch / (2 k)) / t^2``, the ``hat(phi)^2`` coefficient
    of ``Jr^-1``, given ``half_angle``'s ``k, ch``."""
    return o.select(t2 < M.SMALL2, _c_series, _c_closed, t2, k, ch)


def _c_series(t2: Any, k: Any, ch: Any) -> Any:
    return M.horner(t2, M.C_COT)


def coef_c_quat(o: Any, t2: Any, kl: Any, aw: Any) -> Any:
    """:func:`coef_c` from :func:`quat_log_parts`'s ``kl = theta / |v|`` and ``aw = |w|``:
    ``ch / (2 k) = aw kl / 2`` (the norm of the quaternion cancels: no division by ``kl``)."""
    return o.select(t2 < M.SMALL2, _c_series, _c_closed_quat, t2, kl, aw)


def _c_closed_quat(t2: Any, kl: Any, aw: Any) -> Any:
    return (1.0 - 0.5 * aw * kl) / (t2 + (t2 < M.SMALL2))  # safe substitute below SMALL2


def coef_c_slope(o: Any, t2: Any, k: Any, ch: Any) -> tuple[Any, Any]:
    """:func:`coef_c` and its derivative in ``t2``,
    ``c' = (1 / (4 k^2) + ch / (2 k) - 2) / (2 t^4)`` (from ``c = (1 - h cot h) / (4 h^2)``,
    ``h = t/2``); both from their Taylor series below ``SMALL2``."""
    return o.select(t2 < M.SMALL2, _cs_series, _cs_closed, t2, k, ch)


_C_COT_SLOPE = tuple((i + 1) * x for i, x in enumerate(M.C_COT[1:]))


def _cs_series(t2: Any, k: Any, ch: Any) -> tuple:
    return M.horner(t2, M.C_COT), M.horner(t2, _C_COT_SLOPE)


def _cs_closed(t2: Any, k: Any, ch: Any) -> tuple:
    small = t2 < M.SMALL2
    ks = k + small  # k > 0 on the branch that is kept
    ts = t2 + small
    r = ch / (2.0 * ks)
    return (1.0 - r) / ts, (0.25 / (ks * ks) + r - 2.0) / (2.0 * ts * ts)


def _c_closed(t2: Any, k: Any, ch: Any) -> Any:
    small = t2 < M.SMALL2
    ks = k + small  # k > 0 on the branch that is kept
    return (1.0 - ch / (2.0 * ks)) / (t2 + small)


# ---------------------------------------------------------------------------- quaternions


def quat_exp(o: Any, w: tuple) -> tuple:
    k, ch = half_angle(o, M.norm2(*w))
    return (*o.times(k, w), ch)


def quat_log(o: Any, q: tuple) -> tuple:
    """Rotation vector of a unit quaternion, accurate at 0 and at pi.

    ``theta = 2 atan2(|v|, |w|)``; the sign of ``w`` picks the representative with ``w >= 0``.
    """
    phi, _, _ = quat_log_parts(o, q)
    return phi


def quat_log_parts(o: Any, q: tuple) -> tuple:
    """``(phi, kl, aw)``: the rotation vector, ``kl = theta / |v|`` and ``aw = |w|``
    (``cos(theta/2)``), for callers that need the half-angle functions too."""
    x, y, z, w = q
    # |w| whose derivative at w = 0 is 1 (abs's is 0 in torch): at a rotation by exactly pi
    # that derivative carries the change of the angle
    aw = o.abs1(w)
    n2 = x * x + y * y + z * z
    small = n2 < M.TINY2
    n = o.sqrt(n2 + small)
    # 2 atan2(n, |w|) / n; for a unit quaternion and tiny n it is 2 asin(n) / n = 2 + n^2/3
    kl = o.where(small, 2.0 + n2 * (1.0 / 3.0), 2.0 * o.atan2(n, aw) / n)
    ks = kl - 2.0 * (kl * (w < 0))  # w < 0: use -q
    return o.times(ks, (x, y, z)), kl, aw


def quat_mul(a: tuple, b: tuple) -> tuple:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def quat_conj(q: tuple) -> tuple:
    return (-q[0], -q[1], -q[2], q[3])


def quat_rotate(q: tuple, v: tuple) -> tuple:
    """``R(q) v = v + 2 w (u x v) + 2 u x (u x v)`` for a unit quaternion ``(u, w)``."""
    x, y, z, w = q
    v0, v1, v2 = v[0], v[1], v[2]  # v may carry more components (only the first 3 are used)
    x2, y2, z2 = x + x, y + y, z + z
    c0 = y2 * v2 - z2 * v1  # c = 2 u x v
    c1 = z2 * v0 - x2 * v2
    c2 = x2 * v1 - y2 * v0
    return (v0 + w * c0 + (y * c2 - z * c1),  # v + w c + u x c
            v1 + w * c1 + (z * c0 - x * c2),
            v2 + w * c2 + (x * c1 - y * c0))


def quat_to_matrix(q: tuple) -> tuple:
    x, y, z, w = q
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    return (
        (1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)),
        (2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)),
        (2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)),
    )


def matrix_to_quat(o: Any, R: tuple) -> tuple:
    """Unit quaternion of a rotation matrix (Shepperd: the largest component first)."""
    r00, r11, r22 = R[0][0], R[1][1], R[2][2]
    tr = r00 + r11 + r22
    cands = []
    for d in (1.0 + tr, 1.0 + r00 - r11 - r22, 1.0 - r00 + r11 - r22, 1.0 - r00 - r11 + r22):
        s = 2.0 * o.sqrt(o.where(d < 0.25, 1.0, d))  # s = 4 * (largest component)
        cands.append(s)
    sw, sx, sy, sz = cands
    qw = (
        (R[2][1] - R[1][2]) / sw, (R[0][2] - R[2][0]) / sw, (R[1][0] - R[0][1]) / sw, 0.25 * sw)
    qx = (0.25 * sx, (R[0][1] + R[1][0]) / sx, (R[0][2] + R[2][0]) / sx, (R[2][1] - R[1][2]) / sx)
    qy = ((R[0][1] + R[1][0]) / sy, 0.25 * sy, (R[1][2] + R[2][1]) / sy, (R[0][2] - R[2][0]) / sy)
    qz = ((R[0][2] + R[2][0]) / sz, (R[1][2] + R[2][1]) / sz, 0.25 * sz, (R[1][0] - R[0][1]) / sz)
    use_w = (tr >= r00) & (tr >= r11) & (tr >= r22) if not o.is_scalar else \
        (tr >= r00 and tr >= r11 and tr >= r22)
    use_x = (r00 >= r11) & (r00 >= r22) if not o.is_scalar else (r00 >= r11 and r00 >= r22)
    use_y = r11 >= r22
    q = tuple(
        o.where(use_w, a, o.where(use_x, b, o.where(use_y, c, d)))
        for a, b, c, d in zip(qw, qx, qy, qz, strict=True)
    )
    n = o.sqrt(M.norm2(*q))
    return tuple(c / n for c in q)


# ---------------------------------------------------------------------------- Jacobians


def hat_sq(w: tuple, t2: Any) -> tuple:
    """``hat(w)^2 = w w^T - |w|^2 I``."""
    return tuple(
        tuple(w[i] * w[j] - (t2 if i == j else 0.0) for j in range(3)) for i in range(3)
    )


def i_hat_sq(a: Any, b: Any, w: tuple, t2: Any, o: Any = None) -> tuple:
    """``I + a hat(w) + b hat(w)^2``, written out (output components with ``o``, see
    :func:`microlie.groups._math.poly_matrix`)."""
    return M.poly_matrix((1.0, a, b), w, t2, o)


def jr(o: Any, w: tuple) -> tuple:
    """``Jr(w) = I - (1 - cos t)/t^2 hat(w) + (t - sin t)/t^3 hat(w)^2``."""
    t2 = M.norm2(*w)
    k, ch = half_angle(o, t2)
    return i_hat_sq(-2.0 * k * k, coef_b(o, t2, k, ch), w, t2)


def jr_inv(o: Any, w: tuple) -> tuple:
    """``Jr^-1(w) = I + hat(w)/2 + (1 - (t/2) cot(t/2))/t^2 hat(w)^2``."""
    t2 = M.norm2(*w)
    k, ch = half_angle(o, t2)
    return i_hat_sq(0.5, coef_c(o, t2, k, ch), w, t2)


def sym_pair(o: Any, dg: tuple, c: Any, off: tuple, h: tuple) -> tuple[tuple, tuple]:
    """``S + hat(h)`` and ``hat(h) - S`` (the negated transpose of the first) for the symmetric
    ``S`` with diagonal ``dg_i + c`` and off-diagonal ``off = (s01, s02, s12)``, every entry an
    output component (``o.add_out``/``o.sub_out``: computed straight into the output)."""
    add, sub = o.add_out, o.sub_out
    s01, s02, s12 = off
    h0, h1, h2 = h
    d0, d1, d2 = dg
    nc, n0, n1, n2 = -c, -h0, -h1, -h2
    return (((add(d0, c), sub(s01, h2), add(s02, h1)),
             (add(s01, h2), add(d1, c), sub(s12, h0)),
             (sub(s02, h1), add(s12, h0), add(d2, c))),
            ((sub(nc, d0), sub(n2, s01), sub(h1, s02)),
             (sub(h2, s01), sub(nc, d1), sub(n0, s12)),
             (sub(n1, s02), sub(h0, s12), sub(nc, d2))))


def jr_inv_pair_c(o: Any, c: Any, w: tuple, t2: Any) -> tuple[tuple, tuple]:
    """``Jr^-1(w)`` and ``-Jl^-1(w)`` given :func:`coef_c`'s ``c``: ``Jr^-1 = S + hat(w)/2``
    and ``-Jl^-1 = -Jr^-1^T = hat(w)/2 - S``, ``S = I + c hat(w)^2 = (1 - c t2) I + c w w^T``
    (output components, see :func:`sym_pair`)."""
    x, y, z = w
    cx, cy, cz = c * x, c * y, c * z
    return sym_pair(o, (cx * x, cy * y, cz * z), 1.0 - c * t2, (cx * y, cx * z, cy * z),
                    (0.5 * x, 0.5 * y, 0.5 * z))


def jl(o: Any, w: tuple) -> tuple:
    return jr(o, tuple(-c for c in w))


def jl_inv(o: Any, w: tuple) -> tuple:
    return jr_inv(o, tuple(-c for c in w))


# ---------------------------------------------------------------------------- validation


def unit_tolerance(dtype: Any) -> float:
    """How far from 1 a quaternion norm (or from I a R^T R) may be before it is an error."""
    return 1e-6 if np.dtype(str(dtype).replace("torch.", "")).itemsize >= 8 else 1e-4


def checked_unit_quat(q: Array, normalize: bool, what: str, kind: str = "quaternion") -> Array:
    """``q / |q|`` after checking that ``|q|`` is 1 within tolerance (or ``normalize``).

    Also serves SO(2)'s unit complex numbers (``kind``). The check reduces on the device of
    ``q`` (one synchronisation) and is skipped when the values are unknown (a traced value,
    see :func:`microlie._array.values_known`)."""
    xp = A.namespace(q)
    n = xp.sqrt(xp.sum(q * q, axis=-1, keepdims=True))
    if math.prod(q.shape):
        if normalize:
            if A.reduce_values(q, _min_norm2) == 0:
                raise ValueError(f"{what}: a zero {kind} cannot be normalized")
        elif (dev := float(np.max(np.abs(n - 1.0))) if type(n) is np.ndarray
              else A.reduce_values(q, _norm_deviation)) is not None:
            tol = unit_tolerance(q.dtype)
            if dev > tol:
                raise ValueError(
                    f"{what}: {kind} norm differs from 1 by {dev:.3g} (tolerance {tol:g}); "
                    "pass normalize=True to normalize it"
                )
    return q / n


def _min_norm2(xp: Any, q: Array) -> Array:
    return xp.min(xp.sum(q * q, axis=-1))


def _norm_deviation(xp: Any, q: Array) -> Array:
    """``max | |q| - 1 |`` over the batch (a reduction for :func:`A.reduce_values`)."""
    return xp.max(xp.abs(xp.sqrt(xp.sum(q * q, axis=-1)) - 1.0))


_RANK_TOL = 1e-12  # second singular value below this times the first: rank < 2


def checked_rotation_matrix(R: Array, normalize: bool, what: str) -> Array:
    """Check ``R^T R = I`` and ``det R = +1`` within tolerance, or project with ``normalize``."""
    xp = A.namespace(R)
    if normalize:
        U, S, Vt = xp.linalg.svd(R)
        sv = L.concrete(S)
        # rank < 2 (the zero matrix included): every rotation about the null space is as near
        if sv is not None and sv.size and bool(np.any(sv[..., 1] <= _RANK_TOL * sv[..., 0])):
            raise ValueError(f"{what}: matrix has rank < 2, no unique nearest rotation "
                             "(normalize=True cannot project it)")
        d = xp.linalg.det(U @ Vt)
        sign = xp.stack([xp.ones_like(d), xp.ones_like(d), d], axis=-1)
        return (U * sign[..., None, :]) @ Vt
    v = A.host_values(R)
    if v is None or v.size == 0:
        return R
    err = float(np.max(np.abs(np.swapaxes(v, -1, -2) @ v - np.eye(3))))
    tol = unit_tolerance(R.dtype)
    if err > tol:
        raise ValueError(
            f"{what}: matrix is not orthogonal (max |R^T R - I| = {err:.3g}, tolerance {tol:g}); "
            "pass normalize=True to project it onto SO(3)"
        )
    if bool(np.any(np.linalg.det(v) < 0)):
        raise ValueError(f"{what}: matrix has determinant -1 (a reflection, not a rotation)")
    return R


# ---------------------------------------------------------------------------- the class


class SO3(LieGroup):
    """3-D rotations. Parameters: unit quaternion ``(qx, qy, qz, qw)`` (scalar last).

    Tangent: rotation vector ``phi`` (3,). ``Exp(phi)`` is Rodrigues' formula; ``Log`` is
    accurate at 0 and up to and including ``theta = pi``. Right plus/minus and right
    Jacobians by default.

    Parameters
    ----------
    params : array_like
        ``(*batch, 4)`` quaternions ``(x, y, z, w)``.
    normalize : bool
        Normalise instead of raising ``ValueError`` on a norm off 1.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SO3
    >>> R = SO3.exp(np.array([0.0, 0.0, np.pi / 2]))
    >>> np.round(R.act(np.array([1.0, 0.0, 0.0])), 12)
    array([0., 1., 0.])
    """

    dof = 3
    param_dim = 4
    matrix_dim = 3
    point_dim = 3
    _identity_params = (0.0, 0.0, 0.0, 1.0)
    _generators = np.array([
        [[0, 0, 0], [0, 0, -1], [0, 1, 0]],
        [[0, 0, 1], [0, 0, 0], [-1, 0, 0]],
        [[0, -1, 0], [1, 0, 0], [0, 0, 0]],
    ], dtype=float)
    # facts for the generic test suite: the rotation's entries of the tangent vector
    _rotation_slice = slice(0, 3)

    @classmethod
    def _exact_pi_element(cls) -> SO3:
        """The rotation by exactly pi about x, quaternion ``(1, 0, 0, 0)`` (``w = 0`` exactly)."""
        return cls(np.array([1.0, 0.0, 0.0, 0.0]))

    @classmethod
    def _validate_params(cls, p: Array, normalize: bool) -> Array:
        return checked_unit_quat(p, normalize, "SO3")

    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        q = rng.standard_normal((*batch_shape, 4))
        return q / np.linalg.norm(q, axis=-1, keepdims=True)

    _exp = staticmethod(quat_exp)
    _log = staticmethod(quat_log)

    @staticmethod
    def _compose(o, p, q):
        return quat_mul(p, q)

    @staticmethod
    def _inverse(o, p):
        return quat_conj(p)

    @staticmethod
    def _act(o, p, v):
        return quat_rotate(p, v)

    @staticmethod
    def _act_jac(o, p, v):
        R = quat_to_matrix(p)
        return M.neg(M.matmul(R, M.hat3(v))), R

    @staticmethod
    def _adjoint(o, p):
        return quat_to_matrix(p)

    @staticmethod
    def _matrix(o, p):
        return quat_to_matrix(p)

    @classmethod
    def _jr(cls, o, tau):
        return jr(o, tau)

    @classmethod
    def _jr_inv(cls, o, tau):
        return jr_inv(o, tau)

    @staticmethod
    def _minus_jac(o, y, x):
        """``Log(x^-1 y)``, ``Jr^-1`` and ``-Jl^-1`` of it, sharing the half-angle functions of
        the quaternion (``sin(t/2)/t = 1/kl``, ``cos(t/2) = |w|``)."""
        phi, kl, aw = quat_log_parts(o, quat_mul(quat_conj(x), y))
        t2 = M.norm2(*phi)
        return (phi, *jr_inv_pair_c(o, coef_c_quat(o, t2, kl, aw), phi, t2))

    # ------------------------------------------------------------------ constructors
    @classmethod
    def _params_of_matrix(cls, R: np.ndarray) -> np.ndarray:
        """Unit quaternions of rotation matrices ``(..., 3, 3)``, unchecked (Shepperd)."""
        return np.asarray(_quat_from_matrix_array(np.ascontiguousarray(R)))

    @classmethod
    def from_matrix(cls, matrix: Any, normalize: bool = False) -> SO3:
        """From rotation matrices.

        A matrix that is not orthogonal with determinant +1 (within tolerance) raises
        ``ValueError`` unless ``normalize=True``, which projects it onto the nearest rotation (SVD).

        Parameters
        ----------
        matrix : array_like
            ``(..., 3, 3)``.
        normalize : bool
            Project instead of raising.

        Returns
        -------
        SO3

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> M = SO3.exp([0.1, 0.2, 0.3]).matrix()
        >>> bool(np.allclose(SO3.from_matrix(M).log(), [0.1, 0.2, 0.3]))
        True
        """
        R = A.as_float_array(matrix)
        A.check_last_dim(R, (3, 3), "SO3 matrix")
        A.check_finite(R, "SO3 matrix")
        R = checked_rotation_matrix(R, normalize, "SO3.from_matrix")
        return cls._wrap(_quat_from_matrix_array(R))

    @classmethod
    def from_quat(cls, quat: Any, scalar_first: bool = False, normalize: bool = False) -> SO3:
        """From quaternions.

        A norm that differs from 1 by more than the tolerance raises ``ValueError`` unless
        ``normalize=True``. ``q`` and ``-q`` are the same rotation.

        Parameters
        ----------
        quat : array_like
            ``(..., 4)``: ``(x, y, z, w)``, or ``(w, x, y, z)`` with ``scalar_first=True``.
        scalar_first : bool
            The order of ``quat``.
        normalize : bool
            Normalise instead of raising.

        Returns
        -------
        SO3

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> a = SO3.from_quat([0.0, 0.0, np.sin(0.5), np.cos(0.5)])
        >>> b = SO3.from_quat([np.cos(0.5), 0.0, 0.0, np.sin(0.5)], scalar_first=True)
        >>> bool(np.allclose(a.log(), [0, 0, 1.0])), bool(np.allclose(a.matrix(), b.matrix()))
        (True, True)
        """
        q = A.as_float_array(quat)
        A.check_last_dim(q, 4, "quaternion")
        A.check_finite(q, "quaternion")
        if scalar_first:
            q = _roll_quat(q, to_scalar_last=True)
        return cls._wrap(checked_unit_quat(q, normalize, "SO3.from_quat"))

    def as_quat(self, scalar_first: bool = False, canonical: bool = False) -> Array:
        """The quaternion of each rotation.

        Parameters
        ----------
        scalar_first : bool
            Return ``(w, x, y, z)`` instead of ``(x, y, z, w)``.
        canonical : bool
            The representative with ``w >= 0``.

        Returns
        -------
        array
            ``(*batch, 4)``.

        Examples
        --------
        >>> from microlie import SO3
        >>> R = SO3([0.0, 0.0, -0.6, -0.8])
        >>> (R.as_quat(canonical=True) + 0.0).tolist(), R.as_quat(scalar_first=True).tolist()
        ([0.0, 0.0, 0.6, 0.8], [-0.8, 0.0, 0.0, -0.6])
        """
        q = self.params
        if canonical:
            xp = A.namespace(q)
            q = q * xp.where(q[..., 3:] < 0, -1.0, 1.0)
        return _roll_quat(q, to_scalar_last=False) if scalar_first else q

    @classmethod
    def from_rotvec(cls, rotvec: Any, degrees: bool = False) -> SO3:
        """From rotation vectors (axis times angle); the same as :meth:`exp`.

        Parameters
        ----------
        rotvec : array_like
            ``(..., 3)``.
        degrees : bool
            The angle is in degrees.

        Returns
        -------
        SO3

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> R = SO3.from_rotvec([0.0, 0.0, 90.0], degrees=True)
        >>> bool(np.allclose(R.log(), [0, 0, np.pi / 2]))
        True
        """
        v = A.as_float_array(rotvec)
        return cls.exp(v * (np.pi / 180.0) if degrees else v)

    def as_rotvec(self, degrees: bool = False) -> Array:
        """Rotation vectors (axis times angle, angle in ``[0, pi]``); the same as :meth:`log`.

        Parameters
        ----------
        degrees : bool
            Return the angle in degrees.

        Returns
        -------
        array
            ``(*batch, 3)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> np.round(SO3.exp([0.0, np.pi / 2, 0.0]).as_rotvec(degrees=True), 9).tolist()
        [0.0, 90.0, 0.0]
        """
        v = self.log()
        return v * (180.0 / np.pi) if degrees else v

    @classmethod
    def from_euler(cls, seq: str, angles: Any, degrees: bool = False) -> SO3:
        """From Euler angles, SciPy's convention.

        Parameters
        ----------
        seq : str
            One to three letters, all from ``xyz`` (extrinsic: rotations about the fixed axes,
            applied left to right) or all from ``XYZ`` (intrinsic: about the moving axes), no axis
            twice in a row (``"xyx"`` is valid, ``"xxy"`` is not).
        angles : array_like
            ``(..., len(seq))`` (a scalar for one axis).
        degrees : bool
            Angles in degrees instead of radians.

        Returns
        -------
        SO3

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> np.round(SO3.from_euler("z", 90, degrees=True).matrix(), 12)
        array([[ 0., -1.,  0.],
               [ 1.,  0.,  0.],
               [ 0.,  0.,  1.]])
        """
        check_euler_seq(seq)
        a = A.as_float_array(angles)
        if a.ndim == 0:
            a = a[None]
        if a.shape[-1] != len(seq):
            raise ValueError(f"Euler angles: the last dimension must match the {len(seq)} axes "
                             f"of seq {seq!r}, got shape {tuple(a.shape)}")
        A.check_finite(a, "Euler angles")
        if degrees:
            a = a * (np.pi / 180.0)
        out = None
        for i, axis in enumerate(seq):
            idx = "xyz".index(axis.lower())
            onehot = np.zeros(3)
            onehot[idx] = 1.0
            e = a[..., i:i + 1] * cls._const(onehot, a)
            Ri = cls.exp(e)
            if out is None:
                out = Ri
            elif seq.isupper():
                out = out @ Ri
            else:
                out = Ri @ out
        assert out is not None  # seq has at least one axis
        return out

    def as_euler(self, seq: str, degrees: bool = False) -> Array:
        """Euler angles (SciPy's convention and ranges) for NumPy arrays (through
        ``scipy.spatial.transform.Rotation``). For all backends use :meth:`as_rpy`.

        Parameters
        ----------
        seq : str
            As in :meth:`from_euler`.
        degrees : bool
            Return degrees.

        Returns
        -------
        numpy.ndarray
            ``(*batch, len(seq))``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> np.round(SO3.from_euler("xyz", [10, 20, 30], degrees=True).as_euler("xyz", True), 9)
        array([10., 20., 30.])
        """
        if A.namespace(self.params) is not np:
            raise TypeError("as_euler supports NumPy arrays only; use as_rpy() for other backends")
        from scipy.spatial.transform import Rotation

        q = self.params.reshape(-1, 4)
        e = Rotation.from_quat(q).as_euler(seq, degrees=degrees)
        return e.reshape(*self.batch_shape, 3)

    @classmethod
    def from_rpy(cls, roll: Any, pitch: Any, yaw: Any) -> SO3:
        """``R = Rz(yaw) Ry(pitch) Rx(roll)`` (roll about x first, in the fixed frame).

        Parameters
        ----------
        roll, pitch, yaw : array_like
            Radians; they broadcast.

        Returns
        -------
        SO3

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> a, b = SO3.from_rpy(0.1, 0.2, 0.3), SO3.from_euler("xyz", [0.1, 0.2, 0.3])
        >>> bool(np.allclose(a.matrix(), b.matrix()))
        True
        """
        a = A.as_float_array(roll)
        xp = A.namespace(a)
        return cls.from_euler("xyz", xp.stack(xp.broadcast_arrays(
            a, A.as_float_array(pitch, like=a), A.as_float_array(yaw, like=a)), axis=-1))

    def as_rpy(self) -> Array:
        """``(roll, pitch, yaw)`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)``, pitch in
        ``[-pi/2, pi/2]``, roll and yaw in ``(-pi, pi]``; every backend.

        ``from_rpy(*R.as_rpy())`` reproduces ``R`` to rounding at every pitch (computed from
        the quaternion's half-angle sums, not from matrix entries). At the gimbal lock
        (pitch exactly ``+-pi/2``, where only ``yaw - roll`` or ``yaw + roll`` is defined)
        roll is 0 and yaw carries the rest.

        Returns
        -------
        array
            ``(*batch, 3)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> np.round(SO3.from_rpy(0.1, 0.2, 0.3).as_rpy(), 12).tolist()
        [0.1, 0.2, 0.3]
        >>> np.round(SO3.from_rpy(0.3, np.pi / 2, 0.2).as_rpy(), 12).tolist()  # the lock
        [0.0, 1.570796326795, -0.1]
        """
        return run(_K_RPY, self.params)


def check_euler_seq(seq: Any) -> None:
    """SciPy's rules for an Euler axis sequence (``ValueError`` naming the problem)."""
    if not isinstance(seq, str) or not 1 <= len(seq) <= 3:
        raise ValueError(f"Euler seq must be a string of 1 to 3 axes, got {seq!r}")
    if not (set(seq) <= set("xyz") or set(seq) <= set("XYZ")):
        raise ValueError("Euler seq axes must all be from 'xyz' (extrinsic) or all from 'XYZ' "
                         f"(intrinsic), got {seq!r}")
    if any(a == b for a, b in zip(seq, seq[1:], strict=False)):
        raise ValueError(f"Euler seq must not repeat an axis consecutively, got {seq!r}")


def _roll_quat(q: Array, to_scalar_last: bool) -> Array:
    xp = A.namespace(q)
    if to_scalar_last:
        return xp.concat([q[..., 1:], q[..., :1]], axis=-1)
    return xp.concat([q[..., 3:], q[..., :3]], axis=-1)


def _rpy(o: Any, p: tuple) -> tuple:
    """``(roll, pitch, yaw)`` from the quaternion's half-angle sums, not from the matrix.

    With ``q = qz(yaw) qy(pitch) qx(roll)``, ``(w + y, z - x)`` has angle ``(yaw - roll)/2``
    and length ``na = sqrt(2) sin(pitch/2 + pi/4)``, ``(w - y, z + x)`` angle
    ``(yaw + roll)/2`` and length ``nb = sqrt(2) cos(pitch/2 + pi/4)``. Every output is then
    an ``atan2`` of well-scaled arguments: the round trip through :meth:`SO3.from_rpy` is
    exact to rounding at every pitch, including the gimbal lock, where one of the two
    half-angles is undefined (``nb = 0`` at ``+pi/2``, ``na = 0`` at ``-pi/2``) and is taken
    equal to the other: roll = 0 there.
    """
    x, y, z, w = p
    na = o.sqrt((w + y) * (w + y) + (z - x) * (z - x))
    nb = o.sqrt((w - y) * (w - y) + (z + x) * (z + x))
    a = o.atan2(z - x, w + y)
    b = o.atan2(z + x, w - y)
    a, b = o.where(na <= 0.0, b, a), o.where(nb <= 0.0, a, b)
    pitch = 2.0 * o.atan2(na, nb) - 0.5 * math.pi
    yaw, roll = a + b, b - a  # in (-2 pi, 2 pi]: wrapped to (-pi, pi]
    return (_wrap_pi(o, roll), pitch, _wrap_pi(o, yaw))


def _wrap_pi(o: Any, t: Any) -> Any:
    """An angle in ``(-2 pi, 2 pi]`` wrapped to ``(-pi, pi]``."""
    return o.where(t > math.pi, t - 2.0 * math.pi, o.where(t <= -math.pi, t + 2.0 * math.pi, t))


def _quat_from_matrix_array(R: Array) -> Array:
    """Unit quaternions ``(..., 4)`` of rotation matrices ``(..., 3, 3)``."""
    return run(_K_FROM_MATRIX, L.reshape(R, (*R.shape[:-2], 9)))


_K_RPY = add(Kernel("SO3.rpy", SO3, _rpy, "p", [(3,)]))
_K_FROM_MATRIX = add(Kernel("SO3.from_matrix", SO3,
                            lambda o, m: matrix_to_quat(o, (m[0:3], m[3:6], m[6:9])),
                            "m", [(4,)]))

