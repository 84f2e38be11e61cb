"""Synthetic IMU data from a real trajectory.

Samples are synthesised from a ground-truth trajectory (for example EuRoC V1_02's,
``V102_groundtruth.csv`` in the test data of evo):

1. a smooth fit: a cubic spline through the positions and SciPy's ``RotationSpline`` (cubic
   in the rotation increments, continuous angular rate) through the attitudes, both on knots
   every ``knot_dt`` seconds (0.1 s: it smooths the motion-capture jitter);
2. its body angular rate ``w = (R^T dR/dt)^vee`` and specific force ``f = R^T (a - g)``;
3. at ``rate`` Hz, samples ``w + b_g + n_g`` and ``f + b_a + n_a`` with white noise of density
   ``gyro_noise``/``accel_noise`` (standard deviation ``density / sqrt(dt)``) and random-walk
   biases of density ``gyro_walk``/``accel_walk`` (``b_{k+1} = b_k + walk sqrt(dt) N(0, I)``).

The default densities are the EuRoC MAV's ADIS16448 values (its ``imu0/sensor.yaml``):
:data:`EUROC_ADIS16448`. ``truth`` holds the exact states consistent with the discrete model
(the noise-free rates integrated by the same first-order scheme as :class:`Preintegration`),
so a filter fed the noisy samples has exactly the errors its model describes.

>>> import numpy as np
>>> from microlie.imu.simulate import SmoothTrajectory, simulate_imu
>>> t = np.linspace(0.0, 4.0, 41)
>>> pos = np.stack([np.cos(t), np.sin(t), 0.1 * t], -1)
>>> from microlie import SO3
>>> traj = SmoothTrajectory(t, SO3.exp(np.stack([0 * t, 0 * t, t], -1)), pos, knot_dt=0.1)
>>> data = simulate_imu(traj, duration=2.0, rng=0)
>>> data.gyro.shape, round(float(data.dt), 3)
((400, 3), 0.005)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..groups import SE3, SE23, SO3

__all__ = [
    "EUROC_ADIS16448",
    "SmoothTrajectory",
    "ImuData",
    "simulate_imu",
    "load_euroc_groundtruth",
    "integrate_states",
]

#: ADIS16448 densities from the EuRoC MAV dataset's sensor.yaml (Burri et al., IJRR 2016):
#: white noise (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)) and bias random walk (rad/s^2/sqrt(Hz),
#: m/s^3/sqrt(Hz)).
EUROC_ADIS16448 = {
    "gyro_noise": 1.6968e-4,
    "accel_noise": 2.0e-3,
    "gyro_walk": 1.9393e-5,
    "accel_walk": 3.0e-3,
}

GRAVITY = np.array([0.0, 0.0, -9.81])


def load_euroc_groundtruth(path: str | Path) -> tuple[np.ndarray, SE3]:
    """Times and body poses of a EuRoC ground-truth CSV
    (``#timestamp[ns], p_RS_R_xyz, q_RS_wxyz, ...``; quaternion scalar first in the file).

    Parameters
    ----------
    path : str or pathlib.Path
        The CSV file.

    Returns
    -------
    t : numpy.ndarray
        ``(N,)`` seconds since the first stamp.
    poses : SE3
        ``(N,)`` world-from-body poses.

    Examples
    --------
    >>> import os, tempfile
    >>> import numpy as np
    >>> from microlie.imu.simulate import load_euroc_groundtruth
    >>> path = os.path.join(tempfile.mkdtemp(), "gt.csv")
    >>> np.savetxt(path, [[1e9, 1, 2, 3, 1, 0, 0, 0], [2e9, 4, 5, 6, 0, 0, 0, 1]], delimiter=",")
    >>> t, T = load_euroc_groundtruth(path)
    >>> t.tolist(), T.params[1].tolist()  # a 180-degree turn about z in the second row
    ([0.0, 1.0], [4.0, 5.0, 6.0, 0.0, 0.0, 1.0, 0.0])
    """
    a = np.loadtxt(path, delimiter=",", comments="#")
    if a.ndim != 2 or a.shape[1] < 8:
        raise ValueError(f"{path}: expected EuRoC ground truth with >= 8 columns")
    t = (a[:, 0] - a[0, 0]) * 1e-9
    q = SO3.from_quat(a[:, 4:8], scalar_first=True, normalize=True)
    return t, SE3.from_rotation_translation(q, a[:, 1:4])  # type: ignore[return-value]


class SmoothTrajectory:
    """A smooth fit of timed attitudes and positions: cubic position spline, SciPy
    ``RotationSpline`` for the attitude, knots every ``knot_dt`` seconds.

    Parameters
    ----------
    t : array_like
        ``(N,)`` increasing times, seconds.
    rotations : SO3
        ``(N,)`` body-to-world attitudes.
    positions : array_like
        ``(N, 3)`` positions.
    knot_dt : float
        Knot spacing, seconds.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SO3
    >>> from microlie.imu import SmoothTrajectory
    >>> t = np.linspace(0.0, 2.0, 41)
    >>> z = np.zeros_like(t)
    >>> s = SmoothTrajectory(t, SO3.exp(np.c_[z, z, 0.5 * t]), np.c_[t, z, z])
    >>> np.round(s.angular_velocity(1.0), 6).tolist()
    [0.0, 0.0, 0.5]
    """

    def __init__(self, t: Any, rotations: SO3, positions: Any, knot_dt: float = 0.1) -> None:
        from scipy.interpolate import CubicSpline  # type: ignore[import-untyped]
        from scipy.spatial.transform import (  # type: ignore[import-untyped]
            Rotation,
            RotationSpline,
        )

        t = np.asarray(t, dtype=np.float64)
        p = np.asarray(positions, dtype=np.float64)
        if t.ndim != 1 or p.shape != (len(t), 3) or rotations.batch_shape != (len(t),):
            raise ValueError("SmoothTrajectory: t (n,), rotations (n,) and positions (n, 3)")
        if np.any(np.diff(t) <= 0):
            raise ValueError("SmoothTrajectory: times must increase")
        knots = np.arange(t[0], t[-1] + 1e-12, knot_dt)
        idx = np.unique(np.searchsorted(t, knots).clip(0, len(t) - 1))
        self.t0, self.t1 = float(t[idx[0]]), float(t[idx[-1]])
        self._p = CubicSpline(t[idx], p[idx])
        self._R = RotationSpline(t[idx], Rotation.from_quat(np.asarray(rotations.params)[idx]))

    @classmethod
    def from_poses(cls, t: Any, poses: SE3, knot_dt: float = 0.1) -> SmoothTrajectory:
        """The fit of timed SE(3) poses.

        Parameters
        ----------
        t : array_like
            ``(N,)`` times.
        poses : SE3
            ``(N,)`` body-to-world poses.
        knot_dt : float
            Knot spacing, seconds.

        Returns
        -------
        SmoothTrajectory

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3
        >>> from microlie.imu import SmoothTrajectory
        >>> t = np.linspace(0.0, 1.0, 11)
        >>> s = SmoothTrajectory.from_poses(t, SE3.exp(np.c_[t, np.zeros((11, 5))]))
        >>> np.round(s.position(0.5), 6).tolist()
        [0.5, 0.0, 0.0]
        """
        return cls(t, poses.rotation(), poses.translation(), knot_dt)  # type: ignore[arg-type]

    def rotation(self, t: Any) -> SO3:
        """The attitude at times ``t``.

        Parameters
        ----------
        t : float or array_like
            Times, seconds.

        Returns
        -------
        SO3

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> from microlie.imu import SmoothTrajectory
        >>> t = np.linspace(0.0, 2.0, 41)
        >>> z = np.zeros_like(t)
        >>> s = SmoothTrajectory(t, SO3.exp(np.c_[z, z, 0.5 * t]), np.c_[t, z, z])
        >>> np.round(s.rotation(1.0).log(), 6).tolist()
        [0.0, 0.0, 0.5]
        """
        return SO3(self._R(np.asarray(t)).as_quat())

    def position(self, t: Any, order: int = 0) -> np.ndarray:
        """The position (or a time derivative of it) at times ``t``.

        Parameters
        ----------
        t : float or array_like
            Times, seconds.
        order : int
            0 position, 1 velocity, 2 acceleration (world frame).

        Returns
        -------
        numpy.ndarray
            ``(..., 3)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> from microlie.imu import SmoothTrajectory
        >>> t = np.linspace(0.0, 2.0, 41)
        >>> z = np.zeros_like(t)
        >>> s = SmoothTrajectory(t, SO3.exp(np.c_[z, z, 0.5 * t]), np.c_[t, z, z])
        >>> np.round(s.position(1.0), 6).tolist(), np.round(s.position(1.0, 1), 6).tolist()
        ([1.0, 0.0, 0.0], [1.0, 0.0, 0.0])
        """
        return self._p(np.asarray(t), order)

    def angular_velocity(self, t: Any) -> np.ndarray:
        """Body angular rate ``(R^T dR/dt)^vee``.

        Parameters
        ----------
        t : float or array_like
            Times, seconds.

        Returns
        -------
        numpy.ndarray
            ``(..., 3)``, rad/s.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> from microlie.imu import SmoothTrajectory
        >>> t = np.linspace(0.0, 2.0, 41)
        >>> z = np.zeros_like(t)
        >>> s = SmoothTrajectory(t, SO3.exp(np.c_[z, z, 0.5 * t]), np.c_[t, z, z])
        >>> np.round(s.angular_velocity(1.0), 6).tolist()
        [0.0, 0.0, 0.5]
        """
        return self._R(np.asarray(t), 1)

    def specific_force(self, t: Any, gravity: Any = GRAVITY) -> np.ndarray:
        """The specific force ``R^T (a - g)`` in the body frame (what an accelerometer measures).

        Parameters
        ----------
        t : float or array_like
            Times, seconds.
        gravity : array_like
            Gravity in the world frame.

        Returns
        -------
        numpy.ndarray
            ``(..., 3)``, m/s^2.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> from microlie.imu import SmoothTrajectory
        >>> t = np.linspace(0.0, 2.0, 41)
        >>> z = np.zeros_like(t)
        >>> s = SmoothTrajectory(t, SO3.exp(np.c_[z, z, 0.5 * t]), np.c_[t, z, z])
        >>> (np.round(s.specific_force(1.0), 6) + 0.0).tolist()  # constant velocity: gravity
        [0.0, 0.0, 9.81]
        """
        R = self.rotation(t)
        return R.inverse().act(self.position(t, 2) - np.asarray(gravity))

    def state(self, t: Any) -> SE23:
        """The navigation state ``(R, p, v)`` at times ``t``.

        Parameters
        ----------
        t : float or array_like
            Times, seconds.

        Returns
        -------
        SE23

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> from microlie.imu import SmoothTrajectory
        >>> t = np.linspace(0.0, 2.0, 41)
        >>> z = np.zeros_like(t)
        >>> s = SmoothTrajectory(t, SO3.exp(np.c_[z, z, 0.5 * t]), np.c_[t, z, z])
        >>> np.round(s.state(1.0).velocity(), 6).tolist()
        [1.0, 0.0, 0.0]
        """
        return SE23.from_rotation_translation(
            self.rotation(t), self.position(t), self.position(t, 1)
        )


@dataclass
class ImuData:
    """Synthetic IMU samples with their truth (returned by :func:`simulate_imu`).

    Attributes
    ----------
    t : numpy.ndarray
        ``(N,)`` sample times; sample ``k`` acts on ``[t_k, t_k + dt]``.
    dt : float
        The sample interval.
    accel, gyro : numpy.ndarray
        ``(N, 3)`` (or ``(N, M, 3)`` with ``runs=M``) measurements.
    true_accel, true_gyro : numpy.ndarray
        The noise- and bias-free values.
    bias_gyro, bias_accel : numpy.ndarray
        The biases, shaped as the measurements.
    truth : SE23
        The states at ``t`` and one step beyond (``N + 1``).
    gravity : numpy.ndarray
        The gravity used.
    params : dict
        The noise densities used.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SO3
    >>> from microlie.imu import SmoothTrajectory
    >>> t = np.linspace(0.0, 2.0, 41)
    >>> z = np.zeros_like(t)
    >>> s = SmoothTrajectory(t, SO3.exp(np.c_[z, z, 0.5 * t]), np.c_[t, z, z])
    >>> from microlie.imu import simulate_imu
    >>> data = simulate_imu(s, rate=100.0, rng=0)
    >>> data.accel.shape, data.truth.batch_shape
    ((200, 3), (201,))
    """

    t: np.ndarray
    dt: float
    accel: np.ndarray
    gyro: np.ndarray
    true_accel: np.ndarray
    true_gyro: np.ndarray
    bias_gyro: np.ndarray
    bias_accel: np.ndarray
    truth: SE23
    gravity: np.ndarray
    params: dict


def integrate_states(
    X0: SE23, accel: np.ndarray, gyro: np.ndarray, dt: float, gravity: Any = GRAVITY
) -> SE23:
    """States ``X_0 .. X_N`` from bias-free samples by the first-order scheme
    ``R' = R Exp(w dt)``, ``v' = v + (R f + g) dt``, ``p' = p + v dt + (R f + g) dt^2/2`` (the
    scheme of :class:`Preintegration`), vectorised: prefix products and cumulative sums.

    Parameters
    ----------
    X0 : SE23
        The initial state ``(R, p, v)``.
    accel, gyro : numpy.ndarray
        ``(N, 3)`` specific force and angular rate in the body frame.
    dt : float
        The sample interval, seconds.
    gravity : array_like
        Gravity in the world frame.

    Returns
    -------
    SE23
        ``(N + 1,)`` states.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE23
    >>> from microlie.imu.simulate import integrate_states
    >>> n = 100  # one second of 1 m/s^2 forward, gravity compensated
    >>> f, w = np.tile([1.0, 0, 9.81], (n, 1)), np.zeros((n, 3))
    >>> X = integrate_states(SE23.identity(), f, w, 0.01)
    >>> X.batch_shape, np.round(X[-1].velocity(), 12).tolist()
    ((101,), [1.0, 0.0, 0.0])
    >>> np.round(X[-1].translation(), 12).tolist()
    [0.5, 0.0, 0.0]
    """
    from .preintegration import _prefix_scan

    a = np.asarray(accel, dtype=np.float64)
    w = np.asarray(gyro, dtype=np.float64)
    g = np.asarray(gravity, dtype=np.float64)
    dq = np.asarray(SO3.exp(w * dt).params)
    q = np.stack(_prefix_scan([np.ascontiguousarray(dq[:, i]) for i in range(4)]), -1)
    R0 = X0.rotation()
    Rq = R0 @ SO3.from_params(q, check=False)
    Rk = SO3(np.concatenate([np.asarray(R0.params)[None], np.asarray(Rq.params)]))
    f = Rk[:-1].act(a) + g  # navigation-frame acceleration on each step
    v = np.concatenate(
        [np.asarray(X0.velocity())[None], np.asarray(X0.velocity()) + np.cumsum(f * dt, 0)]
    )
    dp = v[:-1] * dt + 0.5 * f * dt * dt
    p = np.concatenate(
        [np.asarray(X0.translation())[None], np.asarray(X0.translation()) + np.cumsum(dp, 0)]
    )
    return SE23.from_rotation_translation(Rk, p, v)


def simulate_imu(
    traj: SmoothTrajectory,
    rate: float = 200.0,
    duration: float | None = None,
    start: float | None = None,
    rng: Any = None,
    gravity: Any = GRAVITY,
    bias_gyro0: Any = None,
    bias_accel0: Any = None,
    truth: bool = True,
    runs: int | None = None,
    **densities: float,
) -> ImuData:
    """Simulated IMU samples along a smooth trajectory.

    Parameters
    ----------
    traj : SmoothTrajectory
        The motion.
    rate : float
        Sample rate, Hz.
    duration, start : float, optional
        The time span, seconds (default: the whole trajectory).
    rng : int or numpy.random.Generator, optional
        The noise source.
    gravity : array_like
        Gravity in the world frame.
    bias_gyro0, bias_accel0 : array_like, optional
        Initial biases (default draws of ``N(0, (0.01 rad/s)^2)`` and
        ``N(0, (0.05 m/s^2)^2)``).
    truth : bool
        Also compute the true states.
    runs : int, optional
        ``M`` independent noise draws on the same motion (Monte Carlo): the measurements and
        biases get shape ``(N, M, 3)``, the truth states are shared.
    **densities : float
        Override :data:`EUROC_ADIS16448` (``gyro_noise``, ``accel_noise``, ``gyro_walk``,
        ``accel_walk``).

    Returns
    -------
    ImuData

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SO3
    >>> from microlie.imu import SmoothTrajectory
    >>> t = np.linspace(0.0, 2.0, 41)
    >>> z = np.zeros_like(t)
    >>> s = SmoothTrajectory(t, SO3.exp(np.c_[z, z, 0.5 * t]), np.c_[t, z, z])
    >>> from microlie.imu import simulate_imu
    >>> data = simulate_imu(s, rate=100.0, rng=0, runs=5)
    >>> data.gyro.shape
    (200, 5, 3)
    """
    unknown = set(densities) - set(EUROC_ADIS16448)
    if unknown:
        raise ValueError(f"unknown noise parameters {sorted(unknown)}")
    prm = {**EUROC_ADIS16448, **densities}
    rng = np.random.default_rng(rng)
    g = np.asarray(gravity, dtype=np.float64)
    dt = 1.0 / rate
    t0 = traj.t0 if start is None else float(start)
    t_end = traj.t1 if duration is None else t0 + float(duration)
    if t_end > traj.t1 + 1e-9 or t0 < traj.t0 - 1e-9:
        raise ValueError("simulate_imu: the interval leaves the trajectory")
    n = int(np.floor((t_end - t0) / dt + 1e-9))
    t = t0 + dt * np.arange(n)
    w = traj.angular_velocity(t)
    f = traj.specific_force(t, g)
    m = () if runs is None else (int(runs),)
    bg0 = 0.01 * rng.standard_normal((*m, 3)) if bias_gyro0 is None else \
        np.broadcast_to(np.asarray(bias_gyro0, float), (*m, 3))
    ba0 = 0.05 * rng.standard_normal((*m, 3)) if bias_accel0 is None else \
        np.broadcast_to(np.asarray(bias_accel0, float), (*m, 3))
    walk = rng.standard_normal((2, n, *m, 3)) * np.sqrt(dt)
    zero = np.zeros((1, *m, 3))
    bg = bg0 + prm["gyro_walk"] * np.concatenate([zero, np.cumsum(walk[0], 0)[:-1]])
    ba = ba0 + prm["accel_walk"] * np.concatenate([zero, np.cumsum(walk[1], 0)[:-1]])
    noise = rng.standard_normal((2, n, *m, 3)) / np.sqrt(dt)
    ws, fs = (w, f) if runs is None else (w[:, None], f[:, None])
    gyro = ws + bg + prm["gyro_noise"] * noise[0]
    accel = fs + ba + prm["accel_noise"] * noise[1]
    X = (
        integrate_states(traj.state(t0), f, w, dt, g)
        if truth
        else traj.state(np.append(t, t[-1] + dt))
    )
    return ImuData(
        t=t,
        dt=dt,
        accel=accel,
        gyro=gyro,
        true_accel=f,
        true_gyro=w,
        bias_gyro=bg,
        bias_accel=ba,
        truth=X,
        gravity=g,
        params=prm,
    )
