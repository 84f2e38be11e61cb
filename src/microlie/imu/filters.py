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

Both propagate with the first-order scheme of :class:`~microlie.imu.Preintegration` on each IMU
sample (``R' = R Exp((w - b_g) dt)``, ``v' = v + (R (a - b_a) + g) dt``,
``p' = p + v dt + (R (a - b_a) + g) dt^2 / 2``), white noise of densities ``gyro_noise`` /
``accel_noise`` and bias random walks ``gyro_walk`` / ``accel_walk``. ``update(z, h, H, R)``
fuses any measurement ``z ~ h(state) + N(0, R)`` given its Jacobian ``H`` with respect to the
filter's error; :meth:`update_position` is the position fix.
"""

from __future__ import annotations

from typing import Any, Literal, cast

import numpy as np

from ..groups import SE23, SO3, Product, R
from ..uncertainty import Gaussian
from .preintegration import _hat

__all__ = ["ErrorStateEKF", "InvariantEKF"]

ESKF_STATE = Product(SO3, R(3), R(3), R(3), R(3))
IEKF_STATE = Product(SE23, R(3), R(3))


def _mv(M: np.ndarray, x: np.ndarray) -> np.ndarray:
    return (M @ x[..., :, None])[..., 0]


def _so3_exp(phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation matrices and right Jacobians of rotation vectors ``(..., 3)``."""
    return np.asarray(SO3.exp(phi).matrix()), np.asarray(SO3.jr(phi))


class _ImuFilter:
    """Shared state, propagation of the mean, Kalman update."""

    dof = 15
    side: Literal["right", "left"]

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
        if a.shape != w.shape or a.shape[-1] != 3:
            raise ValueError(f"accel and gyro must have the same shape (..., 3), got {a.shape} "
                             f"and {w.shape}")
        one = a.shape[:-1] == self.batch_shape
        if one:
            a, w = a[None], w[None]
        d = np.broadcast_to(np.asarray(dt, dtype=np.float64), (len(a),))
        if np.any(d <= 0):
            raise ValueError("dt must be > 0")
        for k in range(len(a)):
            self._step(a[k], w[k], float(d[k]))

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
    def update(self, z: Any, h: Any, H: Any, noise: Any) -> np.ndarray:
        """Fuse a measurement ``z ~ h + N(0, noise)`` (Joseph-form covariance update).

        Parameters
        ----------
        z : array_like
            ``(*batch, m)`` measurement.
        h : array_like or callable
            The predicted measurement ``(*batch, m)``, or a callable of the filter returning it.
        H : array_like or callable
            Its Jacobian ``(*batch, m, 15)`` with respect to the filter's error, or a callable.
        noise : array_like
            ``(m, m)`` measurement covariance.

        Returns
        -------
        numpy.ndarray
            The squared Mahalanobis norm of the innovation (NIS), shape ``batch``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.imu.filters import ErrorStateEKF, ESKF_STATE
        >>> f = ErrorStateEKF(ESKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
        ...                   accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
        >>> H = np.zeros((1, 15)); H[0, 3] = 1.0  # measure p_x
        >>> nis = f.update([0.01], f.p[:1], H, [[1e-4]])
        >>> round(float(nis), 6), round(float(f.p[0]), 6)  # the fix is halfway trusted
        (0.5, 0.005)
        """
        hv = np.asarray(h(self) if callable(h) else h, dtype=np.float64)
        Hm = np.asarray(H(self) if callable(H) else H, dtype=np.float64)
        Rn = np.asarray(noise, dtype=np.float64)
        y = np.asarray(z, dtype=np.float64) - hv
        P = self.cov
        Ht = np.swapaxes(Hm, -1, -2)
        S = Hm @ P @ Ht + Rn
        K = np.swapaxes(np.linalg.solve(S, Hm @ P), -1, -2)  # P H^T S^-1 (S, P symmetric)
        dx = _mv(K, y)
        IKH = np.eye(15) - K @ Hm
        self.cov = IKH @ P @ np.swapaxes(IKH, -1, -2) + K @ Rn @ np.swapaxes(K, -1, -2)
        self._inject(dx)
        return np.sum(y * np.linalg.solve(S, y[..., None])[..., 0], -1)

    def update_position(self, z: Any, sigma: float) -> np.ndarray:
        """Fuse a position fix ``z = p + N(0, sigma^2 I)``.

        Parameters
        ----------
        z : array_like
            ``(*batch, 3)`` measured position.
        sigma : float
            Its standard deviation, metres.

        Returns
        -------
        numpy.ndarray
            The NIS of the fix.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.imu.filters import ErrorStateEKF, ESKF_STATE
        >>> f = ErrorStateEKF(ESKF_STATE.identity(), np.eye(15) * 1e-4, gyro_noise=1.7e-4,
        ...                   accel_noise=2e-3, gyro_walk=2e-5, accel_walk=3e-3)
        >>> nis = f.update_position(np.array([0.01, 0.0, 0.0]), 0.01)
        >>> round(float(f.p[0]), 6)
        0.005
        """
        return self.update(z, self.p, self._position_jacobian(), sigma**2 * np.eye(3))

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
        the filter's side.

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
    """

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
    ``X = Exp(xi) X_hat`` on SE_2(3) (``side="left"``), tangent order
    ``(rho, phi, nu, db_g, db_a)``.

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
    >>> nis = f.update_position(np.array([0.01, 0.0, 0.0]), 0.01)
    >>> f.gaussian.frame
    'left'
    """

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
