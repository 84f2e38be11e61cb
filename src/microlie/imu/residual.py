"""The IMU residual between two navigation states (``SE23``) and a bias, batched over factors.

For preintegrated deltas ``(dR, dv, dp)`` over ``T`` seconds (first-order bias-corrected to the
bias ``b = (b_g, b_a)`` of keyframe ``i``), the residual in the order ``(dphi, dv, dp)`` is
(Forster et al. 2017, eq. 45)

    r_R = Log(dR_c^T R_i^T R_j)
    r_v = R_i^T (v_j - v_i - g T) - dv_c
    r_p = R_i^T (p_j - p_i - v_i T - g T^2 / 2) - dp_c

(with the Coriolis terms of :func:`microlie.imu.preintegration._predict` when a rate is set):
``r = 0`` exactly when ``X_j`` is the prediction ``X_p``. GTSAM's ``ImuFactor`` error in its
``ComponentWise`` mode is ``X_j.localCoordinates(X_p)`` = ``-(r_R, R_j^T R_i r_p,
R_j^T R_i r_v)`` in its order (rotation, position, velocity).

``error="logmap"`` is the residual of GTSAM 4.3's default mode (``ImuFactorErrorMode.Logmap``):
``r = Log(X_p^-1 X_j)`` on SE_2(3), reordered to ``(phi, nu, rho)``; GTSAM's error is ``-r``.

Jacobians are right Jacobians with respect to ``X_i Exp(delta_i)``, ``X_j Exp(delta_j)`` (SE23
tangent ``(rho, phi, nu)``) and ``b + delta``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..groups import SE23, SO3
from .preintegration import Preintegration, _hat, _predict


class Deltas:
    """The preintegrated deltas of ``m`` :class:`Preintegration` objects, stacked (one scheme,
    gravity and Coriolis rate for all).

    Parameters
    ----------
    pims : sequence of Preintegration
        ``m >= 1`` preintegrations.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE23
    >>> from microlie.imu import Deltas, Preintegration, imu_residual
    >>> pim = Preintegration(gyro_noise=1e-3, accel_noise=1e-2).integrate(
    ...     np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
    >>> d = Deltas([pim, pim])
    >>> d.dv.shape, d.cov.shape
    ((2, 3), (2, 9, 9))
    """

    def __init__(self, pims: Sequence[Preintegration]) -> None:
        if not pims:
            raise ValueError("no preintegrated measurements")
        schemes = {p.scheme for p in pims}
        if len(schemes) != 1:
            raise ValueError("all preintegrations of one factor batch must use one scheme")
        self.scheme = schemes.pop()
        for p in pims:
            p._flush()
        self.q = np.stack([p._q for p in pims])
        self.theta = np.stack([p._theta for p in pims])
        self.dv = np.stack([p.delta_velocity for p in pims])
        self.dp = np.stack([p.delta_position for p in pims])
        self.T = np.array([p.dt for p in pims])
        self.J = np.stack([p.bias_jacobian for p in pims])  # (m, 9, 6), ours
        self.H = np.stack([p._jac_left for p in pims])  # tangent scheme: d theta / d b
        self.bias = np.stack([np.concatenate([p.bias_gyro, p.bias_accel]) for p in pims])
        self.cov = np.stack([p.covariance for p in pims])
        g = {tuple(p.gravity) for p in pims}
        w = {None if p.omega_coriolis is None else tuple(p.omega_coriolis) for p in pims}
        if len(g) != 1 or len(w) != 1:
            raise ValueError("all preintegrations of one factor batch must share gravity and "
                             "the Coriolis rate")
        self.gravity = np.array(g.pop())
        wc = w.pop()
        self.omega = None if wc is None else np.array(wc)

    def __len__(self) -> int:
        return len(self.T)

    def corrected(self, bias: np.ndarray) -> tuple:
        """The deltas corrected to other biases, to first order.

        Parameters
        ----------
        bias : numpy.ndarray
            ``(m, 6)`` biases ``(b_g, b_a)``.

        Returns
        -------
        dR_c : SO3
            ``(m,)`` corrected rotations.
        dv_c, dp_c : numpy.ndarray
            ``(m, 3)`` corrected velocity and position deltas.
        K : numpy.ndarray
            ``(m, 3, 6)``: maps a bias perturbation to the right perturbation of ``dR_c``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> from microlie.imu import Deltas, Preintegration, imu_residual
        >>> pim = Preintegration(gyro_noise=1e-3, accel_noise=1e-2).integrate(
        ...     np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
        >>> d = Deltas([pim, pim])
        >>> dR, dv, dp, K = d.corrected(np.zeros((2, 6)))
        >>> np.round(dv[0], 12).tolist(), K.shape
        ([0.0, 0.0, 9.81], (2, 3, 6))
        """
        db = bias - self.bias
        c = (self.J @ db[:, :, None])[..., 0]
        if self.scheme == "manifold":
            e = c[:, :3]
            dR = SO3.from_params(self.q, check=False) @ SO3.exp(e)
            K = SO3.jr(e) @ self.J[:, :3]
        else:
            th = self.theta + (self.H[:, :3] @ db[:, :, None])[..., 0]
            dR = SO3.exp(th)
            K = SO3.jr(th) @ self.H[:, :3]
        return dR, self.dv + c[:, 3:6], self.dp + c[:, 6:9], K


ERRORS = ("forster", "logmap")
_LOG_ORDER = np.r_[3:6, 6:9, 0:3]  # SE23 tangent (rho, phi, nu) -> (phi, nu, rho)


def imu_residual(deltas: Deltas, Xi: SE23, Xj: SE23, bias: Any, jac: bool = False,
                 error: str = "forster") -> Any:
    """The IMU residuals of state pairs, order ``(dphi, dv, dp)``.

    Parameters
    ----------
    deltas : Deltas
        ``m`` preintegrations.
    Xi, Xj : SE23
        ``(m,)`` states at the first and second keyframe.
    bias : array_like
        ``(m, 6)`` biases ``(b_g, b_a)`` at the first keyframe.
    jac : bool
        Also return the right Jacobians.
    error : str
        The residual form (``"forster"``, the default).

    Returns
    -------
    numpy.ndarray or tuple
        ``(m, 9)`` residuals; with ``jac=True`` also the Jacobians ``(m, 9, 9)``,
        ``(m, 9, 9)``, ``(m, 9, 6)`` with respect to ``X_i``, ``X_j``, ``bias``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE23
    >>> from microlie.imu import Deltas, Preintegration, imu_residual
    >>> pim = Preintegration(gyro_noise=1e-3, accel_noise=1e-2).integrate(
    ...     np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
    >>> d = Deltas([pim, pim])
    >>> X = SE23.identity(2)
    >>> r, Ji, Jj, Jb = imu_residual(d, X, X, np.zeros((2, 6)), jac=True)
    >>> float(np.abs(r).max()) < 1e-12, Jb.shape
    (True, (2, 9, 6))
    """
    if error not in ERRORS:
        raise ValueError(f"error must be one of {ERRORS}, got {error!r}")
    b = np.asarray(bias, dtype=np.float64).reshape(len(deltas), 6)
    dR, dv, dp, K = deltas.corrected(b)
    Xp = _predict(SE23, Xi, dR, dv, dp, deltas.T[:, None], deltas.gravity, deltas.omega)
    if error == "logmap":
        return _logmap(deltas, Xi, Xj, b, Xp, dR, dv, dp, K, jac)
    Ri = np.asarray(Xi.rotation().matrix())
    Rit = np.swapaxes(Ri, -1, -2)
    E = Xp.rotation().inverse() @ Xj.rotation()
    rR, Jri = E.log(jac=True)
    rv = (Rit @ (np.asarray(Xj.velocity()) - np.asarray(Xp.velocity()))[..., None])[..., 0]
    rp = (Rit @ (np.asarray(Xj.translation()) - np.asarray(Xp.translation()))[..., None])[..., 0]
    r = np.concatenate([rR, rv, rp], -1)
    if not jac:
        return r
    if deltas.omega is not None:
        return r, *_numerical(deltas, Xi, Xj, b, "forster")
    m = len(deltas)
    T = deltas.T[:, None]
    g = deltas.gravity
    vi, vj = np.asarray(Xi.velocity()), np.asarray(Xj.velocity())
    pi, pj = np.asarray(Xi.translation()), np.asarray(Xj.translation())
    Rij = Rit @ np.asarray(Xj.rotation().matrix())
    Et = np.swapaxes(np.asarray(E.matrix()), -1, -2)
    Ji = np.zeros((m, 9, 9))
    Jj = np.zeros((m, 9, 9))
    Jb = np.zeros((m, 9, 6))
    # tangent of SE23: (rho, phi, nu) -> columns 0:3, 3:6, 6:9; residual rows (R, v, p)
    Ji[:, 0:3, 3:6] = -Jri @ np.swapaxes(Rij, -1, -2)
    Jj[:, 0:3, 3:6] = Jri
    Ji[:, 3:6, 3:6] = _hat((Rit @ (vj - vi - g * T)[..., None])[..., 0])
    Ji[:, 3:6, 6:9] = -np.eye(3)
    Jj[:, 3:6, 6:9] = Rij
    Ji[:, 6:9, 3:6] = _hat((Rit @ (pj - pi - vi * T - 0.5 * g * T * T)[..., None])[..., 0])
    Ji[:, 6:9, 0:3] = -np.eye(3)
    Ji[:, 6:9, 6:9] = -T[:, :, None] * np.eye(3)
    Jj[:, 6:9, 0:3] = Rij
    Jb[:, 0:3] = -Jri @ Et @ K
    Jb[:, 3:6] = -deltas.J[:, 3:6]
    Jb[:, 6:9] = -deltas.J[:, 6:9]
    return r, Ji, Jj, Jb


def _logmap(deltas: Deltas, Xi: SE23, Xj: SE23, b: np.ndarray, Xp: SE23, dR: SO3,
            dv: np.ndarray, dp: np.ndarray, K: np.ndarray, jac: bool) -> Any:
    tau = Xj.minus(Xp)
    r = tau[:, _LOG_ORDER]
    if not jac:
        return r
    if deltas.omega is not None:
        return r, *_numerical(deltas, Xi, Xj, b, "logmap")
    m = len(deltas)
    T = deltas.T[:, None, None]
    dRt = np.swapaxes(np.asarray(dR.matrix()), -1, -2)
    # right perturbation of the prediction X_p by those of X_i and of the bias
    Di = np.zeros((m, 9, 9))
    Di[:, 0:3, 0:3] = dRt
    Di[:, 0:3, 3:6] = -dRt @ _hat(dp)
    Di[:, 0:3, 6:9] = dRt * T
    Di[:, 3:6, 3:6] = dRt
    Di[:, 6:9, 3:6] = -dRt @ _hat(dv)
    Di[:, 6:9, 6:9] = dRt
    Db = np.zeros((m, 9, 6))
    Db[:, 0:3] = dRt @ deltas.J[:, 6:9]
    Db[:, 3:6] = K
    Db[:, 6:9] = dRt @ deltas.J[:, 3:6]
    Jp = -SE23.jl_inv(tau)
    Jj = SE23.jr_inv(tau)
    return r, (Jp @ Di)[:, _LOG_ORDER], Jj[:, _LOG_ORDER], (Jp @ Db)[:, _LOG_ORDER]


def _numerical(deltas: Deltas, Xi: SE23, Xj: SE23, b: np.ndarray, error: str,
               h: float = 1e-6) -> tuple:
    """Central differences of :func:`imu_residual` (used with the Coriolis terms)."""
    out = []
    for k, dof in ((0, 9), (1, 9), (2, 6)):
        J = np.empty((len(deltas), 9, dof))
        for a in range(dof):
            e = np.zeros(dof)
            e[a] = h
            rs = []
            for s in (1.0, -1.0):
                xi = Xi.plus(s * e) if k == 0 else Xi
                xj = Xj.plus(s * e) if k == 1 else Xj
                bb = b + s * e if k == 2 else b
                rs.append(imu_residual(deltas, xi, xj, bb, error=error))
            J[:, :, a] = (rs[0] - rs[1]) / (2 * h)
        out.append(J)
    return tuple(out)
