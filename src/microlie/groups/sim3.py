"""Sim(3): similarity transforms (monocular scale), stored as ``(t, q, s)``.

Parameters ``(tx, ty, tz, qx, qy, qz, qw, s)`` with ``s > 0``; the matrix is ``[[s R, t], [0, 1]]``
(the convention of the lecture notes and evo; GTSAM's Similarity3 uses ``[[R, t], [0, 1/s]]``).
Tangent ``zeta = (rho, phi, sigma)`` with ``s = exp(sigma)``.

``Exp``, ``Log``, ``Jr`` and ``Jr^-1`` are closed forms, accurate to 1e-12 relative (each
Jacobian block, max-norm; measured worst 2e-13) for ``|sigma| <= SIGMA_MAX = 50`` at every
rotation angle up to and including pi. Outside that range they raise ``ValueError``: a scale
beyond ``e^50`` is not a monocular scale, and the closed forms were verified against 50-digit
references only up to there.
"""

from __future__ import annotations

from fractions import Fraction
from functools import partial
from math import factorial
from typing import Any

import numpy as np

from .. import _array as A
from .._array import Array
from . import _math as M
from . import so3
from ._pose import Pose, concat_last
from .se3 import SE3
from .so3 import SO3

# ---------------------------------------------------------------------------- coefficients
#
# Exp(zeta) = [[e^sigma R, W rho], [0, 1]] with W = int_0^1 e^(s sigma) Exp(s phi) ds
# = a I + b hat(phi) + c hat(phi)^2. The right Jacobian needs W and its
# partial derivatives in sigma and in t2 = theta^2. Each of b and c is written as a weighted mean
# f = (sigma^2 P + t2 Q) / (sigma^2 + t2) of two cancellation-free combinations of one-variable
# functions (the phi-functions of sigma, the SO(3) coefficients of theta), so no two-variable
# series is needed near sigma = theta = 0. Their derivatives follow by the quotient rule; its one
# cancelling difference P - Q is always multiplied by enough powers of theta (in W and in the
# Jacobian blocks) that its error stays at rounding level there.

SIGMA_MAX = 50.0
"""Largest ``|sigma|`` (``|log s|``) accepted by ``exp``, ``log``, ``jr`` and ``jr_inv``."""
SIGMA_BOUND = SIGMA_MAX * (1.0 + 1e-12)  # what the checks compare: room for log(exp(50))

# phi_4(x) = sum_k x^k / (k + 4)!; then phi_3 = 1/6 + x phi_4, phi_2 = 1/2 + x phi_3, ...
_PHI4 = M._series(lambda k: Fraction(1, factorial(k + 4)), 20)
_PHI_SMALL = 2.0  # below this |sigma| the series; above, the recurrence (loses < 10 ulp)
# c6 = -d c4 / d t2 = sum_k (k + 1) (-1)^k t2^k / (2k + 6)!
_C_COS6 = M._series(lambda k: Fraction((-1) ** k * (k + 1), factorial(2 * k + 6)), 11)
_TINY = 1e-30  # sigma^2 + theta^2 below this: the values at 0 (exact to rounding there)


def phi_functions(o: Any, sigma: Any) -> tuple[Any, Any, Any, Any, Any]:
    """``(e^x, phi_1, phi_2, phi_3, phi_4)`` at ``x = sigma``, with ``phi_0 = e^x`` and
    ``phi_(n+1) = (phi_n - 1/n!) / x``: ``phi_1 = (e^x - 1)/x``, ``phi_2 = (e^x - 1 - x)/x^2``,
    ... (``phi_n' = phi_n - n phi_(n+1)``). Taylor series below ``|x| = 2``, recurrence above."""
    a, d, e, f = o.select(o.abs(sigma) < _PHI_SMALL, _phi_series, partial(_phi_closed, o),
                          sigma)
    return o.exp(sigma), a, d, e, f


def _phi_series(sigma: Any) -> tuple:
    f = M.horner(sigma, _PHI4)
    e = 1.0 / 6.0 + sigma * f
    d = 0.5 + sigma * e
    return 1.0 + sigma * d, d, e, f


def _phi_closed(o: Any, sigma: Any) -> tuple:
    x = o.where(o.abs(sigma) < _PHI_SMALL, 3.0, sigma)  # safe substitute: never 0 where kept
    a = o.expm1(x) / x
    d = (a - 1.0) / x
    e = (d - 0.5) / x
    return a, d, e, (e - 1.0 / 6.0) / x


def _c4(t2: Any, h: Any) -> Any:
    return M.horner(t2, M.C_COS4)


def _c4_closed(t2: Any, h: Any) -> Any:
    return (0.5 - h) / (t2 + (t2 < M.SMALL2))  # (t^2 + 2 cos t - 2)/(2 t^4)


def _c56(t2: Any, cb: Any, h: Any, c4: Any) -> tuple:
    return M.horner(t2, M.C_SIN5), M.horner(t2, _C_COS6)


def _c56_closed(t2: Any, cb: Any, h: Any, c4: Any) -> tuple:
    ts = t2 + (t2 < M.SMALL2)
    return (3.0 * cb - h) / (2.0 * ts), (2.0 * c4 - 0.5 * cb) / ts


def coefficients(o: Any, sigma: Any, t2: Any, k: Any = None, ch: Any = None,
                 derivatives: bool = False, cauchy_riemann: bool = False) -> tuple:
    """The coefficients of ``W = a I + b hat(phi) + c hat(phi)^2``, ``t2 = |phi|^2``.

    ``a = (e^sigma - 1)/sigma``, ``b = int_0^1 e^(s sigma) sin(s theta)/theta ds``,
    ``c = int_0^1 e^(s sigma) (1 - cos(s theta))/theta^2 ds``. ``k, ch`` are
    :func:`so3.half_angle`'s ``sin(theta/2)/theta, cos(theta/2)`` if the caller has them.

    Returns ``((a, b, c), (E, sinc, h, k, ch))`` with ``E = e^sigma``, ``sinc = sin t / t``,
    ``h = (1 - cos t)/t^2``; with ``derivatives=True`` also the partial derivatives
    ``(a_s, b_s, c_s, b_t, c_t)`` in ``sigma`` (``_s``) and ``t2`` (``_t``) and ``cb``.
    ``phi_1(sigma + i theta) = (a - c t2) + i theta b`` is analytic, and by Cauchy-Riemann
    ``b_s = 2 (c + t2 c_t)`` and ``a_s - t2 c_s = b + 2 t2 b_t``; ``cauchy_riemann=True``
    takes ``b_s`` from the first (one quotient-rule slope fewer; equal to the default to
    ~1e-13 relative), the default keeps the quotient rule that the compiled ``jr`` shares.
    """
    E, a, d, e, f = phi_functions(o, sigma)
    if k is None:
        k, ch = so3.half_angle(o, t2)
    sinc = 2.0 * k * ch
    h = 2.0 * k * k
    cos = 1.0 - t2 * h
    cb = so3.coef_b(o, t2, k, ch)  # (t - sin t)/t^3
    small = t2 < M.SMALL2
    c4 = o.select(small, _c4, _c4_closed, t2, h)  # (t^2 + 2 cos t - 2)/(2 t^4)
    k3 = k * k - 0.5 * cb  # (sin t - t cos t)/(2 t^3)
    z2 = sigma * sigma + t2
    tiny = z2 < _TINY
    z2 = z2 + tiny
    ws = sigma * sigma / z2
    wt = t2 / z2
    Pb = a * sinc - d * cos
    Qb = h + 2.0 * sigma * k3
    Pc = e + a * h - d * sinc
    Qc = cb + sigma * (cb - c4)
    b = o.where(tiny, 0.5 + sigma / 3.0, ws * Pb + wt * Qb)
    c = o.where(tiny, 1.0 / 6.0 + sigma / 8.0, ws * Pc + wt * Qc)
    if not derivatives:
        return (a, b, c), (E, sinc, h, k, ch)
    # c5 = -d cb / d t2, c6 = -d c4 / d t2
    c5, c6 = o.select(small, _c56, _c56_closed, t2, cb, h, c4)
    ad = a - d  # phi_1'
    args = (sigma, z2, ws, wt, a, d, e, f, sinc, cos, h, k3, cb, c4, c5, c6, Pb, Qb, Pc, Qc)
    if cauchy_riemann:
        cs, bt, ct = o.select(tiny, _slopes_at_zero, _slopes, *args)
        bs = 2.0 * (c + t2 * ct)
    else:
        bs, cs, bt, ct = o.select(tiny, _slopes_at_zero_b, _slopes_b, *args)
    return (a, b, c), (E, sinc, h, k, ch), (ad, bs, cs, bt, ct), cb


def _slopes(sigma: Any, z2: Any, ws: Any, wt: Any, a: Any, d: Any, e: Any, f: Any, sinc: Any,
            cos: Any, h: Any, k3: Any, cb: Any, c4: Any, c5: Any, c6: Any, Pb: Any, Qb: Any,
            Pc: Any, Qc: Any) -> tuple:
    """``(c_s, b_t, c_t)`` of :func:`coefficients` away from ``sigma = theta = 0``: the
    quotient rule on ``f = (sigma^2 P + t2 Q) / (sigma^2 + t2)``."""
    ht = c4 - 0.5 * cb  # d h / d t2 (and d sinc / d t2 = -k3, d cos / d t2 = -sinc / 2)
    k3t = 0.5 * (ht + c5)
    ad, de = a - d, d - 2.0 * e  # phi_1', phi_2'
    Db, Dc = (Pb - Qb) / z2, (Pc - Qc) / z2
    s2 = 2.0 * sigma
    bt = ws * (d * (0.5 * sinc) - a * k3 - Db) + wt * (ht + s2 * k3t)
    cs = ws * ((e - 3.0 * f) + ad * h - de * sinc) + wt * ((cb - c4) + s2 * Dc)
    ct = ws * (a * ht + d * k3 - Dc) + wt * (sigma * (c6 - c5) - c5)
    return cs, bt, ct


def _slopes_at_zero(sigma: Any, *_: Any) -> tuple:
    z = 0.0 * sigma
    return z + 1.0 / 8.0, z - 1.0 / 24.0, z - 1.0 / 120.0


def _slopes_b(sigma: Any, z2: Any, ws: Any, wt: Any, a: Any, d: Any, e: Any, f: Any,
              sinc: Any, cos: Any, h: Any, k3: Any, cb: Any, c4: Any, c5: Any, c6: Any, Pb: Any,
              Qb: Any, Pc: Any, Qc: Any) -> tuple:
    """``(b_s, c_s, b_t, c_t)``: :func:`_slopes` and ``b_s`` by the quotient rule too."""
    ad, de = a - d, d - 2.0 * e
    bs = ws * (ad * sinc - de * cos) + wt * (2.0 * k3) + 2.0 * sigma * wt * ((Pb - Qb) / z2)
    return (bs, *_slopes(sigma, z2, ws, wt, a, d, e, f, sinc, cos, h, k3, cb, c4, c5, c6, Pb,
                         Qb, Pc, Qc))


def _slopes_at_zero_b(sigma: Any, *_: Any) -> tuple:
    return (0.0 * sigma + 1.0 / 3.0, *_slopes_at_zero(sigma))


def w_coefficients(o: Any, sigma: Any, t2: Any) -> tuple[Any, Any, Any]:
    """``(a, b, c)`` of ``W = a I + b hat(phi) + c hat(phi)^2`` (see :func:`coefficients`)."""
    return coefficients(o, sigma, t2)[0]


def poly_mul(p: tuple, q: tuple, t2: Any) -> tuple:
    """Product of two polynomials in ``hat(w)`` (``hat(w)^3 = -t2 hat(w)``)."""
    return (p[0] * q[0],
            p[0] * q[1] + p[1] * q[0] - t2 * (p[1] * q[2] + p[2] * q[1]),
            p[0] * q[2] + p[1] * q[1] + p[2] * q[0] - t2 * (p[2] * q[2]))


def poly_inv(p: tuple, t2: Any) -> tuple:
    """Inverse of ``p0 I + p1 hat(w) + p2 hat(w)^2`` (``p0 != 0``): on the axis ``1/p0``, on the
    plane ``1/lambda`` with ``lambda = p0 + i p1 t - p2 t^2``."""
    q1, q2 = p[1] / p[0], p[2] / p[0]
    u = 1.0 - q2 * t2
    L = u * u + q1 * q1 * t2  # |lambda / p0|^2
    s = 1.0 / p[0]
    return (s, -s * q1 / L, s * (q1 * q1 - u * q2) / L)


def poly_apply(p: tuple, w: tuple, v: tuple) -> tuple:
    """``(p0 I + p1 hat(w) + p2 hat(w)^2) v``."""
    u = M.cross(w, v)
    x = M.cross(w, u)
    return tuple(p[0] * v[i] + p[1] * u[i] + p[2] * x[i] for i in range(3))


def jr_upper(o: Any, r: tuple, co: tuple, t2: Any, phi: tuple, rho: tuple) -> tuple:
    """The 3x4 block ``e^-sigma R^T [d(W rho)/d phi | d(W rho)/d sigma]`` of Sim(3)'s ``Jr``
    right of its top-left block, written out, as output components.

    ``r = (r0, r1, r2)`` are the coefficients of ``e^-sigma R^T = r0 I + r1 F + r2 F^2``
    (``F = hat(phi)``), ``co`` :func:`coefficients`'s output with ``derivatives=True``. With
    ``u = phi x rho``, ``d = phi . rho``, ``F^2 rho = d phi - t2 rho`` and ``q0 = r0 - t2 r2``,
    ``R^T`` maps ``rho -> q0 rho + r1 u + r2 d phi``, ``u -> q0 u - t2 r1 rho + r1 d phi`` and
    ``phi -> r0 phi``, and ``R^T hat(rho) = r0 hat(rho) + r1 (rho phi^T - d I) + r2 (u phi^T -
    d F)``. So ``d(W rho)/d phi = -b hat(rho) + c (phi rho^T + d I - 2 rho phi^T) + 2 (b_t u
    + c_t F^2 rho) phi^T = c phi rho^T + w phi^T - b hat(rho) + c d I`` with ``w = 2
    (b_t u + c_t F^2 rho - c rho)`` becomes ``alpha phi rho^T + z
    phi^T + hat(m) + e I``, and ``d(W rho)/d sigma = (a_s - t2 c_s) rho + b_s u + c_s d phi`` a
    combination of ``rho``, ``u`` and ``phi`` again.
    """
    r0, r1, r2 = r
    (_, b, c), _, (a_s, b_s, c_s, b_t, c_t), _ = co
    u = M.cross(phi, rho)
    d = M.dot(phi, rho)
    q0 = r0 - t2 * r2
    wr, wu = -2.0 * (c + t2 * c_t), 2.0 * b_t  # w = wr rho + wu u + 2 c_t d phi
    zr = wr * q0 - (wu * t2 + b) * r1
    zu = wr * r1 + wu * q0 - b * r2
    zp = ((wr + c) * r2 + wu * r1 + 2.0 * c_t * r0) * d
    mr, mp = -b * r0, (b * r2 + c * r1) * d
    e = (b * r1 + c * q0) * d
    sr = a_s - t2 * c_s
    sr, su, sp = sr * q0 - b_s * t2 * r1, sr * r1 + b_s * q0, (sr * r2 + b_s * r1 + c_s * r0) * d
    z = tuple(zr * rho[i] + zu * u[i] + zp * phi[i] for i in range(3))
    m0, m1, m2 = (mr * rho[i] + mp * phi[i] for i in range(3))
    al = c * r0
    ap = tuple(al * x for x in phi)
    G = [[ap[i] * rho[j] + z[i] * phi[j] for j in range(3)] for i in range(3)]
    add, sub = o.add_out, o.sub_out
    col = tuple(add(sr * rho[i] + su * u[i], sp * phi[i]) for i in range(3))
    return ((add(G[0][0], e), sub(G[0][1], m2), add(G[0][2], m1), col[0]),
            (add(G[1][0], m2), add(G[1][1], e), sub(G[1][2], m0), col[1]),
            (sub(G[2][0], m1), add(G[2][1], m0), add(G[2][2], e), col[2]))


def upper_blocks(o: Any, wi: tuple, co: tuple, cj: Any, t2: Any, phi: tuple,
                 rho: tuple, left: bool = True) -> tuple:
    """``B = -W^-1 d(W rho)/d phi Jr^-1_SO3(phi)`` and ``w = W^-1 d(W rho)/d sigma``: the upper
    blocks ``(B | -w)`` of Sim(3)'s ``Jr^-1`` right of ``A`` (its block inverse of ``Jr``),
    written out; also ``hat(rho) - B``, the same block of ``-Jl^-1 = ad - Jr^-1``. Returns
    ``(B, hat(rho) - B, w)`` (``(B, None, w)`` with ``left=False``), the entries of both blocks
    output components (``o.add_out`` and ``o.sub_out``: computed straight into the output).
    ``co`` must satisfy the Cauchy-Riemann identities below (``cauchy_riemann=True``).

    ``wi = (p0, p1, p2)`` are the coefficients of ``W^-1``, ``co = (b, c, a_s, b_s, c_s, b_t,
    c_t)`` those of ``W`` with their derivatives (:func:`coefficients`), ``cj`` the
    ``hat(phi)^2`` coefficient of ``Jr^-1_SO3``. With ``u = phi x rho``, ``d = phi . rho``,
    ``F = hat(phi)``, ``hat(a) hat(b) = b a^T - (a.b) I`` and ``F hat(rho) F = -d F`` every
    product of polynomials in ``F`` with ``hat(rho)`` reduces to the basis ``hat(rho)``,
    ``rho phi^T``, ``phi rho^T``, ``u phi^T``, ``d I``, ``d F``, ``d F^2`` (``phi u^T`` is
    ``u phi^T - d F + t2 hat(rho)``): ``B = U phi^T + beta_Pr phi rho^T + e I + hat(m)``,
    ``U = beta_rP rho + beta_uP u + beta_F2 d phi``, ``m = beta_H rho + beta_F d phi``,
    ``e = (beta_I - t2 beta_F2) d``; ``w = g(F) rho`` with ``g = W^-1 (a_s + b_s F + c_s F^2)``
    (``F^2 rho = d phi - t2 rho``). The identities ``b_s = 2 (c + t2 c_t)`` and ``a_s - t2 c_s
    = b + 2 t2 b_t`` (Cauchy-Riemann, see :func:`coefficients`) share terms between the two.
    """
    U, V, m, ne, w = _upper_vectors(wi, co, cj, t2, phi, rho)
    G = [[U[i] * phi[j] + phi[i] * V[j] for j in range(3)] for i in range(3)]
    del U, V
    add, sub = o.add_out, o.sub_out
    B = ((sub(G[0][0], ne), sub(G[0][1], m[2]), add(G[0][2], m[1])),
         (add(G[1][0], m[2]), sub(G[1][1], ne), sub(G[1][2], m[0])),
         (sub(G[2][0], m[1]), add(G[2][1], m[0]), sub(G[2][2], ne)))
    if not left:
        return B, None, w
    dm = tuple(m[i] - rho[i] for i in range(3))
    rm = tuple(rho[i] - m[i] for i in range(3))
    nB = ((sub(ne, G[0][0]), sub(dm[2], G[0][1]), sub(rm[1], G[0][2])),
          (sub(rm[2], G[1][0]), sub(ne, G[1][1]), sub(dm[0], G[1][2])),
          (sub(dm[1], G[2][0]), sub(rm[0], G[2][1]), sub(ne, G[2][2])))
    return B, nB, w


def _upper_vectors(wi: tuple, co: tuple, cj: Any, t2: Any, phi: tuple, rho: tuple) -> tuple:
    """``(U, V, m, -e, w)`` of :func:`upper_blocks` (``V = beta_Pr rho``); a function of its
    own, so that its temporaries are freed before the blocks are formed."""
    p0, p1, p2 = wi
    b, c, a_s, b_s, c_s, b_t, c_t = co
    u = M.cross(phi, rho)
    d = M.dot(phi, rho)
    g0, g1, g2 = poly_mul(wi, (a_s, b_s, c_s), t2)
    e0, e2 = g0 - t2 * g2, g2 * d
    w = tuple(e0 * rho[i] + g1 * u[i] + e2 * phi[i] for i in range(3))
    del g0, e0, e2
    ccj, bcj, c2 = c * cj, b * cj, 0.5 * c
    x1 = t2 * ccj + 0.5 * b - c
    x2 = c2 - bcj
    xb = x1 - b
    bH = p0 * (b + t2 * x2)
    bPr = p0 * x1
    buP = g2 + p0 * (x2 - 2.0 * b_t - c_s)
    bF = p1 * xb + p2 * (t2 * (c - x2) - b) - p0 * c
    bF2 = p2 * (xb + b_s) - p0 * (2.0 * (ccj + c_t)) - p1 * (bcj + 2.0 * b_t + c2)
    f2d, fd = bF2 * d, bF * d
    ne = ((g1 + bPr) + t2 * bF2) * d  # -e
    U = tuple(g1 * rho[i] + buP * u[i] + f2d * phi[i] for i in range(3))
    V = tuple(bPr * r for r in rho)
    m = tuple(bH * rho[i] + fd * phi[i] for i in range(3))
    return U, V, m, ne, w


class Sim3(Pose):
    """Similarity transforms in 3-D. Parameters ``(tx, ty, tz, qx, qy, qz, qw, s)``.

    Tangent ``(rho, phi, sigma)``, ``s = exp(sigma)``; ``X.act(p) = s R p + t``. Right
    plus/minus and right Jacobians by default. ``Exp(zeta) = (W rho, Exp(phi), e^sigma)`` with
    ``W = int_0^1 e^(s sigma) Exp(s phi) ds``; ``Jr`` in closed form from the derivatives of
    ``W rho``: ``Jr = [[e^-sigma R^T W, e^-sigma R^T d(W rho)/d phi,
    e^-sigma R^T d(W rho)/d sigma], [0, Jr_SO3(phi), 0], [0, 0, 1]]``, ``Jr^-1`` by its block
    inverse. ``|sigma|`` (and ``|log s|`` for ``log``) must not exceed :data:`SIGMA_MAX`
    ``= 50`` (``ValueError``).

    Parameters
    ----------
    params : array_like
        ``(*batch, 8)``: translation, quaternion ``(x, y, z, w)``, scale ``s > 0``.
    normalize : bool
        Normalise the quaternion instead of raising ``ValueError`` on a norm off 1.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import Sim3
    >>> S = Sim3.exp(np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, np.log(2.0)]))
    >>> S.act(np.array([1.0, 2.0, 3.0]))
    array([2., 4., 6.])
    """

    dof = 7
    param_dim = 8
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

    # ------------------------------------------------------------------ range checks
    @staticmethod
    def _range_check(tau: Array) -> None:
        """Applied by the base class to every tangent vector that enters (exp, jr, jr_inv, jl,
        plus, ...) and leaves (log, minus, lminus): ``|sigma| <= SIGMA_MAX``."""
        check_sigma(tau, "tangent vector")

    _range_bound = (6, SIGMA_BOUND)  # the same check in the compiled single elements

    # ------------------------------------------------------------------ primitives
    @staticmethod
    def _exp(o, tau):
        rho, phi, sigma = tau[:3], tau[3:6], tau[6]
        t2 = M.norm2(*phi)
        (a, b, c), (E, _, _, k, ch) = coefficients(o, sigma, t2)
        t = poly_apply((a, b, c), phi, rho)
        return (*t, k * phi[0], k * phi[1], k * phi[2], ch, E)

    @staticmethod
    def _log(o, p):
        t, q, s = p[:3], p[3:7], p[7]
        phi, kl, aw = so3.quat_log_parts(o, q)
        sigma = o.log(s)
        t2 = M.norm2(*phi)
        # the half-angle functions straight from the quaternion: sin(t/2)/t = 1/kl, cos(t/2) = |w|
        W, _ = coefficients(o, sigma, t2, 1.0 / kl, aw)
        return (*poly_apply(poly_inv(W, t2), phi, t), *phi, sigma)

    @classmethod
    def _jr(cls, o, tau):
        rho, phi, sigma = tau[:3], tau[3:6], tau[6]
        t2 = M.norm2(*phi)
        co = coefficients(o, sigma, t2, derivatives=True)
        (_, (E, sinc, h, _, _), _, cb) = co
        ei = 1.0 / E
        Rt = (ei, -ei * sinc, ei * h)  # e^-sigma R^T = e^-sigma Exp(-phi)
        A = M.poly_matrix(poly_mul(Rt, co[0], t2), phi, t2, o)
        J = so3.i_hat_sq(-h, cb, phi, t2, o)
        return _assemble(A, jr_upper(o, Rt, co, t2, phi, rho), J, 1.0)

    @classmethod
    def _jr_inv(cls, o, tau):
        rho, phi, sigma = tau[:3], tau[3:6], tau[6]
        t2 = M.norm2(*phi)
        co = coefficients(o, sigma, t2, derivatives=True, cauchy_riemann=True)
        (_, b, c), (E, sinc, h, k, ch), slopes, _ = co
        wi = poly_inv(co[0], t2)
        A = M.poly_matrix(poly_mul(wi, (E, E * sinc, E * h), t2), phi, t2, o)  # e^sigma W^-1 R
        cj = so3.coef_c(o, t2, k, ch)
        B, _, w = upper_blocks(o, wi, (b, c, *slopes), cj, t2, phi, rho, left=False)
        top = tuple((*B[i], o.negated(w[i])) for i in range(3))
        return _assemble(A, top, so3.i_hat_sq(0.5, cj, phi, t2, o), 1.0)

    @staticmethod
    def _minus_jac(o, y, x):
        """``tau = Log(x^-1 y)``, ``Jr^-1(tau)`` and ``-Jl^-1(tau)`` in one pass.

        ``Jr^-1 = f(ad_tau)`` with ``f(x) = x / (1 - e^-x)`` and ``ad_tau = [[P, hat(rho), -rho],
        [0, F, 0], [0, 0, 0]]`` (``F = hat(phi)``, ``P = sigma I + F``). As ``f(x) - f(-x) = x``,
        ``-Jl^-1 = -f(-ad) = ad - Jr^-1``: the left Jacobian costs one subtraction per entry.
        The blocks of ``Jr^-1 = [[A, B, b], [0, Ji, 0], [0, 0, 1]]`` are ``A = f(P) = W^-1 + P``
        for ``sigma >= -2`` (``W^-1 = f(-P)``; ``e^P W^-1`` below, where the sum cancels),
        ``Ji = Jr^-1_SO3(phi)``, ``b = -W^-1 d(W rho)/d sigma`` and ``B = -W^-1 d(W rho)/d phi Ji``
        (the block inverse of ``Jr``), the last two written out by :func:`upper_blocks`.
        """
        t, q, s = _between_parts(o, y, x)
        phi, kl, aw = so3.quat_log_parts(o, q)
        sigma = o.log(s)
        t2 = M.norm2(*phi)
        # sin(t/2)/t and cos(t/2) of the normalised quaternion: consistent with each other when
        # |q| is off 1 by rounding (float32 inputs), which the cancelling W coefficients need
        m = o.sqrt(M.norm2(*q))
        del q, s  # (dead arrays go back to the allocator while still in the cache)
        co = coefficients(o, sigma, t2, 1.0 / (kl * m), aw / m, derivatives=True,
                          cauchy_riemann=True)
        del m
        E, sinc, h = co[1][:3]
        wi = p0, p1, p2 = poly_inv(co[0], t2)  # W^-1
        rho = poly_apply(wi, phi, t)  # as Sim3._log (which takes |q| = 1)
        del t
        cj = so3.coef_c_quat(o, t2, kl, aw)
        del kl, aw
        co = (*co[0][1:], *co[2])  # (b, c, a_s, b_s, c_s, b_t, c_t)
        B, nB, w = upper_blocks(o, wi, co, cj, t2, phi, rho)
        del co
        Ji, mJl = so3.jr_inv_pair_c(o, cj, phi, t2)  # Jr^-1_SO3, F - Jr^-1_SO3 = -Jl^-1_SO3
        # A = f(P) = W^-1 + P (f(x) - f(-x) = x): the sum loses at most a factor
        # 1 + e^-sigma <= 1 + e^2 to cancellation for sigma >= -2; below, e^P W^-1
        Wi = M.poly_matrix(wi, phi, t2)
        A = o.select(sigma >= _A_SUM, partial(_a_sum, o), _a_product, sigma, *phi, t2, E, sinc,
                     h, p0, p1, p2, *Wi[0], *Wi[1], *Wi[2])
        A = (A[0:3], A[3:6], A[6:9])
        n = o.negated
        nWi = tuple(tuple(n(x) for x in row) for row in Wi)
        top_r = tuple((*B[i], n(w[i])) for i in range(3))
        top_l = tuple((*nB[i], o.sub_out(w[i], rho[i])) for i in range(3))
        return ((*rho, *phi, sigma), _assemble(A, top_r, Ji, 1.0),
                _assemble(nWi, top_l, mJl, -1.0))

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
        """From rotations, translations and scales; the batch axes broadcast.

        Parameters
        ----------
        rotation : SO3 or array_like
            Rotations or rotation matrices.
        translation : array_like
            ``(..., 3)``.
        scale : array_like
            ``(...)``, positive.

        Returns
        -------
        Sim3

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import Sim3, SO3
        >>> S = Sim3.from_rotation_translation_scale(SO3.exp([0, 0, np.pi / 2]), [0, 0, 1.0], 3.0)
        >>> np.round(S.act([1.0, 0.0, 0.0]), 12).tolist()
        [0.0, 3.0, 1.0]
        """
        T = SE3.from_rotation_translation(rotation, translation)
        s = A.as_float_array(scale, like=T.params)
        A.check_finite(s, "scale")
        check_positive_scale(s)
        return cls._wrap(concat_last(T.params, s[..., None]))

    @classmethod
    def from_rotation_translation(cls, rotation: Any, translation: Any) -> Sim3:
        """From a rotation and translations, with scale 1.

        Parameters
        ----------
        rotation : SO3 or array_like
            Rotations or rotation matrices.
        translation : array_like
            ``(..., 3)``.

        Returns
        -------
        Sim3

        Examples
        --------
        >>> from microlie import Sim3, SO3
        >>> float(Sim3.from_rotation_translation(SO3.identity(), [1.0, 2.0, 3.0]).scale())
        1.0
        """
        return cls.from_rotation_translation_scale(rotation, translation, 1.0)

    @classmethod
    def from_matrix(cls, matrix: Any, normalize: bool = False) -> Sim3:
        """From matrices ``[[s R, t], [0, 1]]``; ``s = det(sR)^(1/3)``.

        Parameters
        ----------
        matrix : array_like
            ``(..., 4, 4)``.
        normalize : bool
            Project ``R`` onto the rotations instead of raising ``ValueError``.

        Returns
        -------
        Sim3

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import Sim3
        >>> M = np.diag([2.0, 2.0, 2.0, 1.0])
        >>> M[:3, 3] = [1.0, 2.0, 3.0]
        >>> S = Sim3.from_matrix(M)
        >>> round(float(S.scale()), 12), S.translation().tolist()
        (2.0, [1.0, 2.0, 3.0])
        """
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
        """The scale ``s > 0``.

        Returns
        -------
        array
            Shape ``batch_shape``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import Sim3
        >>> round(float(Sim3.exp([0, 0, 0, 0, 0, 0, np.log(3.0)]).scale()), 12)
        3.0
        """
        return self.params[..., 7]


def check_positive_scale(s: Array) -> None:
    v = A.host_values(s)
    if v is not None and bool(np.any(v <= 0)):
        raise ValueError("Sim3: scale must be positive")


_A_SUM = -2.0  # from this sigma up, Sim3 minus_jac takes A = f(P) as W^-1 + P


def _a_sum(o: Any, sigma: Any, x: Any, y: Any, z: Any, t2: Any, E: Any, sinc: Any, h: Any,
           p0: Any, p1: Any, p2: Any, *wi: Any) -> tuple:
    """``A = W^-1 + P`` (``P = sigma I + hat(phi)``; ``wi`` the 9 entries of ``W^-1``), as
    output components."""
    add, sub = o.add_out, o.sub_out
    return (add(wi[0], sigma), sub(wi[1], z), add(wi[2], y),
            add(wi[3], z), add(wi[4], sigma), sub(wi[5], x),
            sub(wi[6], y), add(wi[7], x), add(wi[8], sigma))


def _a_product(sigma: Any, x: Any, y: Any, z: Any, t2: Any, E: Any, sinc: Any, h: Any, p0: Any,
               p1: Any, p2: Any, *wi: Any) -> tuple:
    """``A = e^P W^-1`` with ``e^P = E (I + sinc F + h F^2)`` (``W^-1 = p0 + p1 F + p2 F^2``)."""
    q0, cos = p0 - t2 * p2, 1.0 - t2 * h
    m = M.poly_matrix((E * p0, E * (sinc * q0 + p1 * cos), E * (p0 * h + p1 * sinc + p2 * cos)),
                    (x, y, z), t2)
    return (*m[0], *m[1], *m[2])


def _between_parts(o: Any, y: tuple, x: tuple) -> tuple:
    """The translation, quaternion and scale of ``x^-1 y``."""
    z = Sim3._compose(o, Sim3._inverse(o, x), y)
    return z[:3], z[3:7], z[7]


def _assemble(A: tuple, top: tuple, J: tuple, one: Any) -> tuple:
    """``[[A, top], [0, J, 0], [0, 0, one]]`` with ``top`` the 3x4 block right of ``A``."""
    return (tuple((*A[i], *top[i]) for i in range(3))
            + tuple((0.0, 0.0, 0.0, *J[i], 0.0) for i in range(3))
            + ((0.0, 0.0, 0.0, 0.0, 0.0, 0.0, one),))


def check_sigma(tau: Array, what: str) -> None:
    """``ValueError`` unless ``|sigma| <= SIGMA_MAX`` for every Sim3 tangent in ``tau``
    (``(..., 7)``); a NaN or infinite sigma out of a Log fails too. Skipped when traced."""
    if type(tau) is np.ndarray and tau.ndim == 1:
        m = abs(float(tau[6]))
    else:
        x = A.max_abs(tau[..., 6])  # on the device; None when the values are unknown
        if x is None:
            return
        m = x
    if not m <= SIGMA_BOUND:
        raise ValueError(f"Sim3 {what}: |sigma| = {m:.6g} exceeds SIGMA_MAX = {SIGMA_MAX:g} "
                         f"(scales beyond e^+-{SIGMA_MAX:g}), outside the verified range")
