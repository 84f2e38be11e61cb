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
    """Project ``Z`` onto the tangent space at ``Y`` (both ``(n d, r)``)."""
    r = Y.shape[1]
    Yb, Zb = Y.reshape(-1, d, r), Z.reshape(-1, d, r)
    B = Zb @ np.swapaxes(Yb, 1, 2)
    return (Zb - 0.5 * (B + np.swapaxes(B, 1, 2)) @ Yb).reshape(Y.shape)


def retract(Y: np.ndarray, V: np.ndarray, d: int) -> np.ndarray:
    """The polar retraction: each block of ``Y + V`` replaced by its nearest matrix with
    orthonormal rows."""
    r = Y.shape[1]
    U, _, Wt = np.linalg.svd((Y + V).reshape(-1, d, r), full_matrices=False)
    return (U @ Wt).reshape(Y.shape)


@dataclass
class TrustRegionOutcome:
    """Where :func:`trust_region` stopped: the point, its objective, ``Q Y``, the gradient's
    norm, the number of outer and inner iterations."""

    Y: np.ndarray
    f: float
    QY: np.ndarray
    grad_norm: float
    iterations: int
    inner: int


def trust_region(Q: Callable[[np.ndarray], np.ndarray], Y: np.ndarray, d: int, *,
                 grad_tol: float, max_iter: int = 500, max_inner: int = 200,
                 delta: float | None = None, rel_decrease: float = 1e-14
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
        Initial trust radius (default: ``sqrt(n d) / 8``, an eighth of the manifold's scale).
    rel_decrease : float
        Also stop when an accepted step lowers the objective by less than this fraction.

    Returns
    -------
    TrustRegionOutcome
    """
    QY = Q(Y)
    f = float(np.sum(Y * QY))
    big = np.sqrt(Y.shape[0])
    delta = big / 8 if delta is None else delta
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

        eta, Heta, k = _tcg(g, hess, delta, max_inner, Y, d)
        inner_total += k
        Yn = retract(Y, eta, d)
        QYn = Q(Yn)
        fn = float(np.sum(Yn * QYn))
        model = -float(np.sum(g * eta)) - 0.5 * float(np.sum(eta * Heta))
        actual = f - fn
        rho = actual / model if model > 0 else (1.0 if actual >= 0 else -1.0)
        en = float(np.linalg.norm(eta))
        if rho < 0.25:
            delta = 0.25 * delta
        elif rho > 0.75 and en >= 0.99 * delta:
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
         max_inner: int, Y: np.ndarray, d: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Steihaug-Toint truncated CG for ``min <g, e> + 1/2 <e, H e>`` with ``|e| <= delta``;
    returns the step, ``H`` times it and the number of Hessian products."""
    eta = np.zeros_like(g)
    Heta = np.zeros_like(g)
    r = g.copy()
    p = -r
    rr = float(np.sum(r * r))
    r0 = np.sqrt(rr)
    k = 0
    for k in range(1, max_inner + 1):  # noqa: B007
        Hp = hess(p)
        pHp = float(np.sum(p * Hp))
        if pHp <= 0:
            t = _to_boundary(eta, p, delta)
            return eta + t * p, Heta + t * Hp, k
        alpha = rr / pHp
        en = eta + alpha * p
        if np.linalg.norm(en) >= delta:
            t = _to_boundary(eta, p, delta)
            return eta + t * p, Heta + t * Hp, k
        eta, Heta = en, Heta + alpha * Hp
        r = r + alpha * Hp
        r = project(Y, r, d)  # keep it tangent (rounding)
        rr_new = float(np.sum(r * r))
        if np.sqrt(rr_new) <= r0 * min(r0, 0.1):  # superlinear: kappa = 0.1, theta = 1
            break
        p = -r + (rr_new / rr) * p
        rr = rr_new
    return eta, Heta, k


def _to_boundary(eta: np.ndarray, p: np.ndarray, delta: float) -> float:
    """``t >= 0`` with ``|eta + t p| = delta``."""
    a = float(np.sum(p * p))
    b = 2.0 * float(np.sum(eta * p))
    c = float(np.sum(eta * eta)) - delta * delta
    return (-b + np.sqrt(max(b * b - 4 * a * c, 0.0))) / (2 * a) if a > 0 else 0.0
