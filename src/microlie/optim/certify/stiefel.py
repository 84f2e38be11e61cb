"""Riemannian trust region on a product of Stiefel manifolds, for ``min tr(Y^T Q Y)``.

``Y`` is ``(n d, r)``: ``n`` blocks ``Y_i`` of shape ``(d, r)`` with orthonormal rows
(``Y_i Y_i^T = I_d``; at ``r = d`` the blocks are orthogonal matrices ``R_i^T``). With the
embedded (Frobenius) metric:

- tangent projection ``P_Y(Z)_i = Z_i - sym(Z_i Y_i^T) Y_i``;
- gradient ``2 (Q Y - Lambda Y)`` with ``Lambda_i = sym((Q Y)_i Y_i^T)``;
- Hessian ``P_Y(2 (Q Ydot - Lambda Ydot))``;
- retraction: the polar factor of each block ``Y_i + Ydot_i``.

The trust-region loop and its truncated conjugate-gradient (Steihaug-Toint) inner solver follow
Absil, Baker and Gallivan, "Trust-region methods on Riemannian manifolds" (FoCM 2007).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["project", "retract", "trust_region", "TrustRegionOutcome"]


def project(Y: np.ndarray, Z: np.ndarray, d: int) -> np.ndarray:
    """Project ``Z`` onto the tangent space at ``Y``: ``Z_i - sym(Z_i Y_i^T) Y_i``.

    Parameters
    ----------
    Y : numpy.ndarray
        ``(n d, r)``, blocks with orthonormal rows.
    Z : numpy.ndarray
        ``(n d, r)``.
    d : int
        Rows per block.

    Returns
    -------
    numpy.ndarray
        ``(n d, r)``; ``sym(P_i Y_i^T) = 0`` for every block.

    Examples
    --------
    >>> import numpy as np
    >>> Y = np.eye(2)
    >>> project(Y, np.array([[1.0, 2.0], [0.0, 3.0]]), 2).tolist()  # the skew part
    [[0.0, 1.0], [-1.0, 0.0]]
    """
    r = Y.shape[1]
    Yb, Zb = Y.reshape(-1, d, r), Z.reshape(-1, d, r)
    B = Zb @ np.swapaxes(Yb, 1, 2)
    return (Zb - 0.5 * (B + np.swapaxes(B, 1, 2)) @ Yb).reshape(Y.shape)


def retract(Y: np.ndarray, V: np.ndarray, d: int) -> np.ndarray:
    """The polar retraction: each block of ``Y + V`` replaced by its nearest matrix with
    orthonormal rows.

    Parameters
    ----------
    Y : numpy.ndarray
        ``(n d, r)``, blocks with orthonormal rows.
    V : numpy.ndarray
        ``(n d, r)`` tangent at ``Y``.
    d : int
        Rows per block.

    Returns
    -------
    numpy.ndarray
        ``(n d, r)`` on the manifold.

    Examples
    --------
    >>> import numpy as np
    >>> Yn = retract(np.eye(2), np.array([[0.0, 0.5], [-0.5, 0.0]]), 2)
    >>> bool(np.allclose(Yn @ Yn.T, np.eye(2)))
    True
    """
    r = Y.shape[1]
    U, _, Wt = np.linalg.svd((Y + V).reshape(-1, d, r), full_matrices=False)
    return (U @ Wt).reshape(Y.shape)


@dataclass
class TrustRegionOutcome:
    """Where :func:`trust_region` stopped.

    Attributes
    ----------
    Y : numpy.ndarray
        The point.
    f : float
        Its objective ``tr(Y^T Q Y)``.
    QY : numpy.ndarray
        ``Q Y``.
    grad_norm : float
        The Riemannian gradient's norm.
    iterations, inner : int
        Outer iterations, Hessian products.

    Examples
    --------
    >>> import numpy as np
    >>> out = TrustRegionOutcome(np.eye(2), 0.0, np.zeros((2, 2)), 0.0, 0, 0)
    >>> out.f
    0.0
    """

    Y: np.ndarray
    f: float
    QY: np.ndarray
    grad_norm: float
    iterations: int
    inner: int


def trust_region(Q: Callable[[np.ndarray], np.ndarray], Y: np.ndarray, d: int, *,
                 grad_tol: float, max_iter: int = 500, max_inner: int = 200,
                 delta: float | None = None, rel_decrease: float = 1e-14,
                 precon: Callable[[np.ndarray], np.ndarray] | None = None
                 ) -> TrustRegionOutcome:
    """Minimise ``tr(Y^T Q Y)`` over the product of Stiefel manifolds from ``Y``.

    Parameters
    ----------
    Q : callable
        ``Y -> Q Y`` for ``(n d, k)`` arrays (``Q`` symmetric).
    Y : numpy.ndarray
        ``(n d, r)`` start on the manifold.
    d : int
        Rows per block.
    grad_tol : float
        Stop when the Riemannian gradient's Frobenius norm is at most this.
    max_iter, max_inner : int
        Outer iterations; conjugate-gradient steps per outer iteration.
    delta : float, optional
        Initial trust radius, in the norm of the preconditioner's inverse (default:
        ``sqrt(f)`` with one, ``sqrt(n d) / 8`` without).
    rel_decrease : float
        Also stop when an accepted step lowers the objective by less than this fraction.
    precon : callable, optional
        ``Z -> P Z``, ``P`` symmetric positive definite approximating the Hessian's inverse
        (projected onto the tangent space here).

    Returns
    -------
    TrustRegionOutcome

    Examples
    --------
    >>> import numpy as np
    >>> Q = np.array([[2.0, -1, -1], [-1, 2, -1], [-1, -1, 2]])  # a triangle's Laplacian
    >>> a = np.array([0.0, 1.0, 2.0])  # three unit vectors (blocks of one row) in R^2
    >>> out = trust_region(lambda Y: Q @ Y, np.c_[np.cos(a), np.sin(a)], 1, grad_tol=1e-10)
    >>> round(out.f, 9) + 0.0  # sum over edges of |y_i - y_j|^2: all aligned
    0.0
    """
    QY = Q(Y)
    f = float(np.sum(Y * QY))
    if precon is None:
        big = np.sqrt(Y.shape[0])
        delta = big / 8 if delta is None else delta
    else:
        delta = np.sqrt(max(f, 1e-300)) if delta is None else delta
        big = 1e6 * delta
    inner_total = 0
    it = 0
    for it in range(1, max_iter + 1):  # noqa: B007
        Lam = _lam(Y, QY, d)
        g = 2.0 * project(Y, QY, d)
        gn = float(np.linalg.norm(g))
        if gn <= grad_tol:
            return TrustRegionOutcome(Y, f, QY, gn, it - 1, inner_total)

        def hess(V: np.ndarray, Y: np.ndarray = Y, Lam: np.ndarray = Lam) -> np.ndarray:
            r = Y.shape[1]
            LV = (Lam @ V.reshape(-1, d, r)).reshape(V.shape)
            return project(Y, 2.0 * (Q(V) - LV), d)

        eta, Heta, k, k_boundary = _tcg(g, hess, delta, max_inner, Y, d, precon)
        inner_total += k
        Yn = retract(Y, eta, d)
        QYn = Q(Yn)
        fn = float(np.sum(Yn * QYn))
        model = -float(np.sum(g * eta)) - 0.5 * float(np.sum(eta * Heta))
        actual = f - fn
        rho = actual / model if model > 0 else (1.0 if actual >= 0 else -1.0)
        if rho < 0.25:
            delta = 0.25 * delta
        elif rho > 0.75 and k_boundary:
            delta = min(2.0 * delta, big)
        if rho > 0.1 and actual >= 0:
            small = actual <= rel_decrease * max(abs(f), 1e-300)
            Y, QY, f = Yn, QYn, fn
            if small:
                g = 2.0 * project(Y, QY, d)
                return TrustRegionOutcome(Y, f, QY, float(np.linalg.norm(g)), it, inner_total)
        if delta < 1e-14 * big:
            break
    g = 2.0 * project(Y, QY, d)
    return TrustRegionOutcome(Y, f, QY, float(np.linalg.norm(g)), it, inner_total)


def _lam(Y: np.ndarray, QY: np.ndarray, d: int) -> np.ndarray:
    r = Y.shape[1]
    B = QY.reshape(-1, d, r) @ np.swapaxes(Y.reshape(-1, d, r), 1, 2)
    return 0.5 * (B + np.swapaxes(B, 1, 2))


def _tcg(g: np.ndarray, hess: Callable[[np.ndarray], np.ndarray], delta: float,
         max_inner: int, Y: np.ndarray, d: int,
         precon: Callable[[np.ndarray], np.ndarray] | None
         ) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """Steihaug-Toint truncated CG for ``min <g, e> + 1/2 <e, H e>`` with ``|e|_P <= delta``
    (the norm of the preconditioner's inverse; Euclidean without one); returns the step,
    ``H`` times it, the number of Hessian products and whether it stopped on the boundary."""
    def prec(r: np.ndarray) -> np.ndarray:
        return r if precon is None else project(Y, precon(r), d)

    eta = np.zeros_like(g)
    Heta = np.zeros_like(g)
    r = g.copy()
    z = prec(r)
    zr = float(np.sum(z * r))
    p = -z
    e_pe, e_pd, d_pd = 0.0, 0.0, zr
    r0 = float(np.linalg.norm(r))
    k = 0
    for k in range(1, max_inner + 1):  # noqa: B007
        Hp = hess(p)
        pHp = float(np.sum(p * Hp))
        alpha = zr / pHp if pHp > 0 else 0.0
        e_pe_new = e_pe + 2.0 * alpha * e_pd + alpha * alpha * d_pd
        if pHp <= 0 or e_pe_new >= delta * delta:
            t = (-e_pd + np.sqrt(max(e_pd * e_pd + d_pd * (delta * delta - e_pe), 0.0))) / d_pd
            return eta + t * p, Heta + t * Hp, k, True
        e_pe = e_pe_new
        eta, Heta = eta + alpha * p, Heta + alpha * Hp
        r = project(Y, r + alpha * Hp, d)  # keep it tangent (rounding)
        if np.linalg.norm(r) <= r0 * min(r0, 0.1):  # superlinear: kappa = 0.1, theta = 1
            break
        z = prec(r)
        zr_new = float(np.sum(z * r))
        beta = zr_new / zr
        zr = zr_new
        p = -z + beta * p
        e_pd = beta * (e_pd + alpha * d_pd)
        d_pd = zr + beta * beta * d_pd
    return eta, Heta, k, False
