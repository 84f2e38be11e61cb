"""Kalman filters for IMU navigation on composite states, batched over leading axes.

* :class:`ErrorStateEKF`: the error-state EKF (Sola, "Quaternion kinematics for the error-state
  Kalman filter", 2017) on ``Product(SO3, R(3), R(3), R(3), R(3))`` = (attitude, position,
  velocity, gyro bias, accel bias); error ``side="right"`` (``R = R_hat Exp(dtheta)``, local
  attitude error) or ``side="left"`` (``R = Exp(dtheta) R_hat``, global), the vectors additive.
  Tangent order ``(dtheta, dp, dv, db_g, db_a)``.
* :class:`InvariantEKF`: the (imperfect) invariant EKF of Barrau and Bonnabel ("The invariant
  extended Kalman filter as a stable observer", IEEE TAC 2017) on ``Product(SE23, R(3), R(3))``
  with the left-multiplied error ``X = Exp(xi) X_hat`` on SE_2(3) (its right-invariant error
  ``X X_hat^-1``), biases additive. Tangent order ``(rho, phi, nu, db_g, db_a)`` (SE23's
  ``(position, rotation, velocity)``). Without biases its error dynamics do not depend on the
  estimate.

**The three orders differ** (each follows its reference, and code indexing ``cov`` relies on
it, so none is changed): ``ErrorStateEKF`` ``(dtheta, dp, dv, db_g, db_a)`` (attitude first),
``InvariantEKF`` ``(rho, phi, nu, db_g, db_a)`` (position first), ``Preintegration``
``(dphi, dv, dp)`` (velocity before position). Each class states its order in its
``tangent_order`` attribute and its ``repr``.

Both propagate with the first-order scheme of :class:`~microlie.imu.Preintegration` on each IMU
sample (``R' = R Exp((w - b_g) dt)``, ``v' = v + (R (a - b_a) + g) dt``,
``p' = p + v dt + (R (a - b_a) + g) dt^2 / 2``), white noise of densities ``gyro_noise`` /
``accel_noise`` and bias random walks ``gyro_walk`` / ``accel_walk``. ``update(z, h, H, R)``
fuses any measurement ``z ~ h(state) + N(0, R)`` given its Jacobian ``H`` with respect to the
filter's error; :meth:`update_position` is the position fix.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, cast

import numpy as np

from ..groups import SE23, SO3, Product, R
from ..uncertainty import Gaussian, _check_finite, check_covariance
from .preintegration import _hat

__all__ = ["ErrorStateEKF", "InvariantEKF", "UpdateResult"]

ESKF_STATE = Product(SO3, R(3), R(3), R(3), R(3))
IEKF_STATE = Product(SE23, R(3), R(3))


def _mv(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    return (M @ x[..., :, None])[..., 0]


@dataclass(frozen=True)
class UpdateResult:
    """What :meth:`ErrorStateEKF.update` (and :meth:`InvariantEKF.update`) did.

    Attributes
    ----------
    nis : numpy.ndarray
        Shape ``batch``: the innovation's squared Mahalanobis norm ``y^T S^-1 y`` (``y = z - h``,
        ``S = H P H^T + noise``), computed before the update.
    applied : numpy.ndarray
        Boolean, shape ``batch``: where the measurement was fused (all True without a gate;
        elsewhere the filter is unchanged).
    threshold : float
        The gate on ``nis`` (the chi-square quantile of ``gate`` with ``m`` degrees of
        freedom), ``inf`` without a gate.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.imu.filters import ErrorStateEKF, ESKF_STATE
    >>> f = ErrorStateEKF(ESKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
    ...                   accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
    >>> r = f.update_position([0.1, 0.0, 0.0], 0.01, gate=0.99)
    >>> round(float(r.nis), 6), bool(r.applied), round(r.threshold, 4)  # 10 cm against 1.4 cm
    (50.0, False, 11.3449)
    """

    nis: np.ndarray
    applied: np.ndarray
    threshold: float


def _so3_exp(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrices and right Jacobians of rotation vectors ``(..., 3)``."""
    return np.asarray(SO3.exp(phi).matrix()), np.asarray(SO3.jr(phi))


class _ImuFilter:
    """Shared state, propagation of the mean, Kalman update."""

    dof = 15
    side: Literal["right", "left"]
    #: the names of the 15 error coordinates, in order (``cov``, ``update``'s ``H``, ``error``)
    tangent_order: tuple[str, ...]

    def __init__(self, Rm: np.ndarray, p: np.ndarray, v: np.ndarray, bg: np.ndarray,
                 ba: np.ndarray, cov: Any, gyro_noise: float, accel_noise: float,
                 gyro_walk: float, accel_walk: float, gravity: Any) -> None:
        self.Rm, self.p, self.v, self.bg, self.ba = Rm, p, v, bg, ba
        batch = p.shape[:-1]
        P = np.asarray(cov, dtype=np.float64)
        if P.shape[-2:] != (15, 15):
            raise ValueError(f"cov must be (..., 15, 15), got {P.shape}")
        self.cov = np.broadcast_to(P, (*batch, 15, 15)).copy()
        self.gravity = np.asarray(gravity, dtype=np.float64)
        self.q = np.array([gyro_noise, accel_noise, gyro_walk, accel_walk], dtype=np.float64) ** 2
        if np.any(self.q < 0) or not np.all(np.isfinite(self.q)):
            raise ValueError("noise densities must be finite and >= 0")

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.p.shape[:-1])

    def __repr__(self) -> str:
        side = f"side={self.side!r}, " if type(self) is ErrorStateEKF else ""
        return (f"{type(self).__name__}({side}batch_shape={self.batch_shape}, "
                f"tangent_order=({', '.join(self.tangent_order)}))")

    # ------------------------------------------------------------------ prediction
    def predict(self, accel: Any, gyro: Any, dt: Any) -> None:
        """Propagate the state and covariance over IMU samples.

        Parameters
        ----------
        accel, gyro : array_like
            ``(*batch, 3)`` (one sample) or ``(N, *batch, 3)``: specific force (m/s^2) and angular
            rate (rad/s) in the body frame.
        dt : float or array_like
            Sample interval(s), seconds: a scalar or ``(N,)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.imu.filters import ErrorStateEKF, ESKF_STATE
        >>> f = ErrorStateEKF(ESKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
        ...                   accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
        >>> f.predict(np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.005)  # at rest
        >>> float(np.abs(f.p).max()) < 1e-12, bool(f.cov[3, 3] > 1e-4)
        (True, True)
        """
        a = np.asarray(accel, dtype=np.float64)
        w = np.asarray(gyro, dtype=np.float64)
        if a.shape != w.shape or a.shape[-1:] != (3,):
            raise ValueError(f"accel and gyro must have the same shape (..., 3), got {a.shape} "
                             f"and {w.shape}")
        one = a.shape[:-1] == self.batch_shape
        if one:
            a, w = a[None], w[None]
        elif a.shape[1:-1] != self.batch_shape:
            raise ValueError(f"accel and gyro must be (*batch, 3) or (N, *batch, 3) with batch "
                             f"{self.batch_shape}, got {a.shape}")
        for x, name in ((a, "accel"), (w, "gyro")):
            bad = ~np.isfinite(x).reshape(len(x), -1).all(axis=1)
            if bad.any():
                raise ValueError(f"{name} sample {int(np.argmax(bad))} contains NaN or infinite "
                                 "values; drop or repair it (the filter is unchanged)")
        try:
            d = np.broadcast_to(np.asarray(dt, dtype=np.float64), (len(a),))
        except ValueError:
            raise ValueError(f"dt must be a scalar or ({len(a)},), got shape "
                             f"{np.shape(dt)}") from None
        good = np.isfinite(d) & (d > 0)
        if not good.all():
            raise ValueError(f"dt must be finite and > 0 (sample {int(np.argmin(good))}); "
                             "the filter is unchanged")
        saved = self._save()
        try:
            with np.errstate(over="ignore", invalid="ignore"):  # found by _check_state
                for k in range(len(a)):
                    self._step(a[k], w[k], float(d[k]))
            self._check_state("predict")
        except BaseException:
            self._restore(saved)
            raise

    def _save(self) -> tuple:
        # every step and update replaces these arrays (none is written in place)
        return self.Rm, self.p, self.v, self.bg, self.ba, self.cov

    def _restore(self, saved: tuple) -> None:
        self.Rm, self.p, self.v, self.bg, self.ba, self.cov = saved

    def _check_state(self, what: str) -> None:
        for x in self._save():
            if not np.all(np.isfinite(x)):
                raise ValueError(f"{what}: the state or covariance would become NaN or "
                                 "infinite (an overflow); the filter is unchanged")

    def _step(self, a: np.ndarray, w: np.ndarray, dt: float) -> None:
        ah = a - self.ba
        dR, Jr = _so3_exp((w - self.bg) * dt)
        R0 = self.Rm
        f = _mv(R0, ah) + self.gravity
        F, Gg, Ga = self._jacobians(R0, R0 @ dR, ah, Jr, dt, f)
        self.Rm = R0 @ dR
        self.p = self.p + self.v * dt + 0.5 * f * dt * dt
        self.v = self.v + f * dt
        qg, qa, qgw, qaw = self.q
        Ft = np.swapaxes(F, -1, -2)
        P = F @ self.cov @ Ft
        P += (qg / dt) * (Gg @ np.swapaxes(Gg, -1, -2))
        P += (qa / dt) * (Ga @ np.swapaxes(Ga, -1, -2))
        i = np.arange(9, 12)
        P[..., i, i] += qgw * dt
        P[..., i + 3, i + 3] += qaw * dt
        self.cov = P

    def _jacobians(self, R0, R1, ah, Jr, dt, f):  # pragma: no cover - abstract
        raise NotImplementedError

    # ------------------------------------------------------------------ update
    def update(self, z: Any, h: Any, H: Any, noise: Any, *,
               gate: float | None = None) -> UpdateResult:
        """Fuse a measurement ``z ~ h + N(0, noise)`` (Joseph-form covariance update).

        All or nothing: the inputs are checked first (``z``, ``h``, ``H`` finite, ``noise``
        symmetric positive semi-definite, ``S = H P H^T + noise`` positive definite), and when
        anything raises the filter is unchanged. With ``gate``, the measurement is fused only
        where its NIS is at most the ``gate`` quantile of the chi-square distribution with
        ``m`` degrees of freedom (an outlier test); elsewhere the filter is unchanged.

        Parameters
        ----------
        z : array_like
            ``(*batch, m)`` measurement.
        h : array_like or callable
            The predicted measurement ``(*batch, m)``, or a callable of the filter returning it.
        H : array_like or callable
            Its Jacobian ``(*batch, m, 15)`` with respect to the filter's error, in the
            filter's ``tangent_order`` (they differ by class), or a callable.
        noise : array_like
            ``(m, m)`` or ``(*batch, m, m)`` measurement covariance.
        gate : float, optional
            Probability in ``(0, 1)``, e.g. ``0.997``; ``None`` (default) fuses every
            measurement.

        Returns
        -------
        UpdateResult
            Its ``nis``, ``applied`` and ``threshold``.

        Raises
        ------
        ValueError
            A non-finite ``z``, ``h`` or ``H``, an invalid ``noise`` or ``gate``, shapes that
            do not match, or a singular ``S``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.imu.filters import ErrorStateEKF, ESKF_STATE
        >>> f = ErrorStateEKF(ESKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
        ...                   accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
        >>> H = np.zeros((1, 15)); H[0, 3] = 1.0  # measure p_x
        >>> res = f.update([0.01], f.p[:1], H, [[1e-4]])
        >>> round(float(res.nis), 6), round(float(f.p[0]), 6)  # the fix is halfway trusted
        (0.5, 0.005)
        >>> res = f.update([1.0], f.p[:1], H, [[1e-4]], gate=0.997)  # a 1 m outlier
        >>> bool(res.applied), round(float(f.p[0]), 6)
        (False, 0.005)
        """
        batch = self.batch_shape
        hv = np.asarray(h(self) if callable(h) else h, dtype=np.float64)
        Hm = np.asarray(H(self) if callable(H) else H, dtype=np.float64)
        zv = np.asarray(z, dtype=np.float64)
        if Hm.ndim < 2 or Hm.shape[-1] != self.dof:
            raise ValueError(f"H must be (*batch, m, {self.dof}), got shape {Hm.shape}")
        m = Hm.shape[-2]
        for x, name in ((zv, "z"), (hv, "h")):
            if x.shape[-1:] != (m,) or np.broadcast_shapes(x.shape[:-1], batch) != batch:
                raise ValueError(f"{name} must be (*batch, {m}) with batch {batch} (m from H), "
                                 f"got shape {x.shape}")
        if np.broadcast_shapes(Hm.shape[:-2], batch) != batch:
            raise ValueError(f"H must be (*batch, m, {self.dof}) with batch {batch}, got "
                             f"shape {Hm.shape}")
        for x, name in ((zv, "z"), (hv, "h"), (Hm, "H")):
            _check_finite(x, f"update: {name}")
        Rn = np.asarray(noise, dtype=np.float64)
        check_covariance(Rn, m, "update: noise")
        if np.broadcast_shapes(Rn.shape[:-2], batch) != batch:
            raise ValueError(f"noise must be ({m}, {m}) or (*batch, {m}, {m}) with batch "
                             f"{batch}, got shape {Rn.shape}")
        threshold = np.inf
        if gate is not None:
            if not 0.0 < gate < 1.0:
                raise ValueError(f"gate must be a probability in (0, 1), e.g. 0.997, got {gate!r}")
            from scipy.stats import chi2

            threshold = float(chi2.ppf(gate, m))
        with np.errstate(over="ignore"):
            y = zv - hv
        P = self.cov
        Ht = np.swapaxes(Hm, -1, -2)
        S = Hm @ P @ Ht + Rn
        S = 0.5 * (S + np.swapaxes(S, -1, -2))
        try:
            np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise ValueError("update: S = H P H^T + noise is singular (a measured direction "
                             "with zero variance in both the filter and noise): give noise "
                             "positive variances; the filter is unchanged") from None
        PHt = np.broadcast_to(P @ Ht, (*batch, 15, m))
        K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)  # P H^T S^-1
        y = np.broadcast_to(y, (*batch, m))
        with np.errstate(over="ignore", invalid="ignore"):
            nis = np.sum(y * np.linalg.solve(S, y[..., None])[..., 0], -1)
        if not np.all(np.isfinite(nis)):
            raise ValueError("update: the innovation z - h or its NIS is NaN or infinite (an "
                             "overflow); the filter is unchanged")
        applied = np.asarray(nis <= threshold)
        dx = np.where(applied[..., None], _mv(K, y), 0.0)
        IKH = np.eye(15) - K @ Hm
        Pn = IKH @ P @ np.swapaxes(IKH, -1, -2) + K @ Rn @ np.swapaxes(K, -1, -2)
        saved = self._save()
        try:
            self.cov = np.where(applied[..., None, None], Pn, P)
            self._inject(dx)
            self._check_state("update")
        except BaseException:
            self._restore(saved)
            raise
        return UpdateResult(nis, applied, threshold)

    def update_position(self, z: Any, sigma: float, *,
                        gate: float | None = None) -> UpdateResult:
        """Fuse a position fix ``z = p + N(0, sigma^2 I)`` (:meth:`update`).

        Parameters
        ----------
        z : array_like
            ``(*batch, 3)`` measured position.
        sigma : float
            Its standard deviation, metres.
        gate : float, optional
            As in :meth:`update`.

        Returns
        -------
        UpdateResult

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.imu.filters import ErrorStateEKF, ESKF_STATE
        >>> f = ErrorStateEKF(ESKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
        ...                   accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
        >>> res = f.update_position(np.array([0.01, 0.0, 0.0]), 0.01)
        >>> round(float(f.p[0]), 6)
        0.005
        """
        return self.update(z, self.p, self._position_jacobian(), sigma**2 * np.eye(3),
                           gate=gate)

    def _position_jacobian(self) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _inject(self, dx: np.ndarray) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    # ------------------------------------------------------------------ views
    @property
    def state(self) -> Any:  # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def gaussian(self) -> Gaussian:
        """The estimate as a ``Gaussian`` on the filter's product group (``frame`` = the side
        of its error)."""
        return Gaussian(self.state, self.cov, frame=self.side)

    def error(self, truth: Any) -> np.ndarray:
        """The filter's error of a true state: the tangent ``e`` with ``truth = estimate (+) e`` on
        the filter's side, in its ``tangent_order``.

        Parameters
        ----------
        truth : Product
            An element of the filter's product group.

        Returns
        -------
        numpy.ndarray
            ``(*batch, 15)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.imu.filters import ErrorStateEKF, ESKF_STATE
        >>> f = ErrorStateEKF(ESKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
        ...                   accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
        >>> f.error(ESKF_STATE.identity()).shape
        (15,)
        """
        X = self.state
        return truth.minus(X) if self.side == "right" else truth.lminus(X)

    def nees(self, truth: Any) -> np.ndarray:
        """Normalised estimation error squared ``e^T P^-1 e`` of a true state.

        Parameters
        ----------
        truth : Product
            An element of the filter's product group.

        Returns
        -------
        numpy.ndarray
            Shape ``batch``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.imu.filters import ErrorStateEKF, ESKF_STATE
        >>> f = ErrorStateEKF(ESKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
        ...                   accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
        >>> float(f.nees(ESKF_STATE.identity()))
        0.0
        """
        e = self.error(truth)
        return np.sum(e * np.linalg.solve(self.cov, e[..., None])[..., 0], -1)


class ErrorStateEKF(_ImuFilter):
    """Error-state EKF on ``Product(SO3, R(3), R(3), R(3), R(3))`` (see the module docstring).

    Error (tangent) order ``(dtheta, dp, dv, db_g, db_a)``: attitude, position, velocity, gyro
    bias, accel bias (``InvariantEKF`` puts position first, ``Preintegration`` velocity before
    position; see the module docstring). ``cov``, the ``H`` of :meth:`update`, :meth:`error`
    and ``repr`` use it.

    Parameters
    ----------
    state : Product
        An element of ``ESKF_STATE`` (attitude, position, velocity, b_g, b_a), batched over
        leading axes to run many filters at once.
    cov : array_like
        ``(..., 15, 15)`` in the tangent order ``(dtheta, dp, dv, db_g, db_a)``.
    gyro_noise, accel_noise : float
        White-noise densities (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)).
    gyro_walk, accel_walk : float
        Bias random-walk densities (rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz)).
    gravity : array_like
        Gravity in the navigation frame (default z up).
    side : {"right", "left"}
        The attitude error side.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.imu.filters import ErrorStateEKF, ESKF_STATE
    >>> f = ErrorStateEKF(ESKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
    ...                   accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
    >>> f.predict(np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.005)  # at rest
    >>> float(np.abs(f.p).max()) < 1e-12
    True
    >>> f
    ErrorStateEKF(side='right', batch_shape=(), tangent_order=(dtheta, dp, dv, db_g, db_a))
    """

    tangent_order = ("dtheta", "dp", "dv", "db_g", "db_a")

    def __init__(self, state: Any, cov: Any, *, gyro_noise: float, accel_noise: float,
                 gyro_walk: float, accel_walk: float, gravity: Any = (0.0, 0.0, -9.81),
                 side: str = "right") -> None:
        if type(state) is not ESKF_STATE:
            raise TypeError(f"ErrorStateEKF: state must be a {ESKF_STATE.__name__}")
        if side not in ("right", "left"):
            raise ValueError(f"side must be 'right' or 'left', got {side!r}")
        self.side = "left" if side == "left" else "right"
        Rm = np.asarray(state.part(0).matrix())
        p, v, bg, ba = (np.asarray(state.part(i).params, dtype=np.float64) for i in range(1, 5))
        super().__init__(Rm, p, v, bg, ba, cov, gyro_noise, accel_noise, gyro_walk, accel_walk,
                         gravity)

    def _jacobians(self, R0, R1, ah, Jr, dt, f):
        F = np.broadcast_to(np.eye(15), (*self.batch_shape, 15, 15)).copy()
        Gg = np.zeros((*self.batch_shape, 15, 3))
        Ga = np.zeros((*self.batch_shape, 15, 3))
        th, p, v = slice(0, 3), slice(3, 6), slice(6, 9)
        if self.side == "right":
            dRt = np.swapaxes(R0, -1, -2) @ R1
            F[..., th, th] = np.swapaxes(dRt, -1, -2)
            Gg[..., th, :] = -Jr * dt
            A = -R0 @ _hat(ah)  # d (R a) / d dtheta
        else:
            Gg[..., th, :] = -(R1 @ Jr) * dt
            A = -_hat(_mv(R0, ah))
        F[..., v, th] = A * dt
        F[..., p, th] = 0.5 * A * dt * dt
        F[..., p, v] = np.eye(3) * dt
        Ga[..., v, :] = -R0 * dt
        Ga[..., p, :] = -0.5 * R0 * dt * dt
        F[..., :, 9:12] += Gg
        F[..., :, 12:15] += Ga
        return F, Gg, Ga

    def _position_jacobian(self) -> np.ndarray:
        H = np.zeros((*self.batch_shape, 3, 15))
        H[..., :, 3:6] = np.eye(3)
        return H

    def _inject(self, dx: np.ndarray) -> None:
        dR = np.asarray(SO3.exp(dx[..., 0:3]).matrix())
        self.Rm = self.Rm @ dR if self.side == "right" else dR @ self.Rm
        self.p = self.p + dx[..., 3:6]
        self.v = self.v + dx[..., 6:9]
        self.bg = self.bg + dx[..., 9:12]
        self.ba = self.ba + dx[..., 12:15]

    @property
    def state(self) -> Any:
        Rq = SO3.from_matrix(self.Rm, normalize=True)
        return ESKF_STATE.from_parts(Rq, *(R(3).from_params(x, check=False) for x in
                                          (self.p, self.v, self.bg, self.ba)))


class InvariantEKF(_ImuFilter):
    """Invariant EKF on ``Product(SE23, R(3), R(3))`` (see the module docstring): error
    ``X = Exp(xi) X_hat`` on SE_2(3) (``side="left"``).

    Error (tangent) order ``(rho, phi, nu, db_g, db_a)``: position, attitude, velocity (SE23's
    order), gyro bias, accel bias (``ErrorStateEKF`` puts attitude first; see the module
    docstring). ``cov``, the ``H`` of :meth:`update`, :meth:`error` and ``repr`` use it.

    Parameters
    ----------
    state : Product
        An element of ``IEKF_STATE`` (navigation state, b_g, b_a), batched over leading axes.
    cov : array_like
        ``(..., 15, 15)`` in the tangent order above.
    gyro_noise, accel_noise : float
        White-noise densities (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)).
    gyro_walk, accel_walk : float
        Bias random-walk densities (rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz)).
    gravity : array_like
        Gravity in the navigation frame (default z up).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.imu.filters import InvariantEKF, IEKF_STATE
    >>> f = InvariantEKF(IEKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
    ...                  accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
    >>> res = f.update_position(np.array([0.01, 0.0, 0.0]), 0.01)
    >>> f.gaussian.frame
    'left'
    >>> f
    InvariantEKF(batch_shape=(), tangent_order=(rho, phi, nu, db_g, db_a))
    """

    tangent_order = ("rho", "phi", "nu", "db_g", "db_a")

    def __init__(self, state: Any, cov: Any, *, gyro_noise: float, accel_noise: float,
                 gyro_walk: float, accel_walk: float,
                 gravity: Any = (0.0, 0.0, -9.81)) -> None:
        if type(state) is not IEKF_STATE:
            raise TypeError(f"InvariantEKF: state must be a {IEKF_STATE.__name__}")
        self.side = "left"
        X = cast(SE23, state.part(0))
        Rm = np.asarray(X.rotation().matrix())
        p, v = np.asarray(X.translation()), np.asarray(X.velocity())
        bg, ba = (np.asarray(state.part(i).params, dtype=np.float64) for i in (1, 2))
        super().__init__(Rm, p, v, bg, ba, cov, gyro_noise, accel_noise, gyro_walk, accel_walk,
                         gravity)

    def _jacobians(self, R0, R1, ah, Jr, dt, f):
        F = np.broadcast_to(np.eye(15), (*self.batch_shape, 15, 15)).copy()
        rho, phi, nu = slice(0, 3), slice(3, 6), slice(6, 9)
        gh = _hat(np.broadcast_to(self.gravity, (*self.batch_shape, 3)))
        F[..., rho, nu] = np.eye(3) * dt
        F[..., rho, phi] = 0.5 * dt * dt * gh
        F[..., nu, phi] = dt * gh
        p1 = self.p + self.v * dt + 0.5 * f * dt * dt
        v1 = self.v + f * dt
        B = (R1 @ Jr) * dt
        Gg = np.zeros((*self.batch_shape, 15, 3))
        Ga = np.zeros((*self.batch_shape, 15, 3))
        Gg[..., phi, :] = -B
        Gg[..., rho, :] = -_hat(p1) @ B
        Gg[..., nu, :] = -_hat(v1) @ B
        Ga[..., rho, :] = -0.5 * dt * dt * R0
        Ga[..., nu, :] = -dt * R0
        F[..., :, 9:12] += Gg
        F[..., :, 12:15] += Ga
        return F, Gg, Ga

    def _position_jacobian(self) -> np.ndarray:
        # p = p_hat + phi x p_hat + rho to first order
        H = np.zeros((*self.batch_shape, 3, 15))
        H[..., :, 0:3] = np.eye(3)
        H[..., :, 3:6] = -_hat(self.p)
        return H

    def _inject(self, dx: np.ndarray) -> None:
        E = SE23.exp(dx[..., 0:9])
        dR = np.asarray(E.rotation().matrix())
        self.Rm = dR @ self.Rm
        self.p = _mv(dR, self.p) + np.asarray(E.translation())
        self.v = _mv(dR, self.v) + np.asarray(E.velocity())
        self.bg = self.bg + dx[..., 9:12]
        self.ba = self.ba + dx[..., 12:15]

    @property
    def state(self) -> Any:
        Rq = SO3.from_matrix(self.Rm, normalize=True)
        X = SE23.from_rotation_translation(Rq, self.p, self.v)
        return IEKF_STATE.from_parts(X, R(3).from_params(self.bg, check=False),
                                     R(3).from_params(self.ba, check=False))
