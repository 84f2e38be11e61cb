"""IMU preintegration on the manifold (Forster, Carlone, Dellaert, Scaramuzza, T-RO 2017).

Between two keyframes ``i`` and ``j`` the samples (specific force ``a``, angular rate ``w``, in the
body frame, biases removed) give the preintegrated deltas

    dR_ij = prod_k Exp((w_k - b_g) dt_k)
    dv_ij = sum_k dR_ik (a_k - b_a) dt_k
    dp_ij = sum_k dv_ik dt_k + 1/2 dR_ik (a_k - b_a) dt_k^2

which relate the states by ``R_j = R_i dR_ij``, ``v_j = v_i + g T + R_i dv_ij``,
``p_j = p_i + v_i T + g T^2 / 2 + R_i dp_ij`` (``T = sum dt``, ``g`` the gravity vector).

Error convention (the covariance and the bias Jacobians): tangent order ``(dphi, dv, dp)``,
``dR = dR_true Exp(dphi)`` (right perturbation), ``dv = dv_true + delta_v`` and
``dp = dp_true + delta_p`` (additive, in the frame of keyframe ``i``), as in Forster et al.
GTSAM orders ``(rotation, position, velocity)`` and expresses the velocity and position
errors in the frame of ``dR_ij`` (``v + dR delta``): its blocks are ``diag(I, dR^T, dR^T)``
times ours, reordered.

Two schemes: ``"manifold"`` (Forster's product of exponentials, the default; GTSAM's
``PreintegratedImuMeasurementsManifold``) and ``"tangent"`` (GTSAM's default
``PreintegratedImuMeasurements``: ``theta += Jr^-1(theta) w dt`` on the rotation vector of
``dR``; sequential, for comparison). The manifold scheme is vectorised: a parallel prefix
product of the rotation increments, cumulative sums, and one matrix product for the covariance.
"""

from __future__ import annotations

import math
from fractions import Fraction
from math import factorial
from typing import Any

import numpy as np

from .._array import NUMPY, SCALAR
from ..groups import SO3
from ..groups import _math as _M
from ..groups import so3 as _so3

__all__ = ["Preintegration"]

# Below this many samples per call, integrate() buffers them; a buffer of BUFFER samples (or
# any read of a result) is integrated at once, below SMALL samples one at a time.
SMALL = 24
BUFFER = 4096
# integrate() processes at most CHUNK samples at once (about 1 KB of temporaries per sample):
# its memory does not grow with the number of samples of a call, and the temporaries stay small
# enough for the CPU caches (benchmarks/preintegration_memory.py)
CHUNK = 16384


def _vec3(x: Any, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0:
        a = np.full(3, float(a))
    if a.shape != (3,):
        raise ValueError(f"{what} must be a scalar or have shape (3,), got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what} has NaN or infinite entries")
    return a


def _sample_row(accel: Any, gyro: Any, dt: Any) -> list[float] | None:
    """``[ax, ay, az, wx, wy, wz, dt]`` for one valid sample, else None (the array path then
    checks and reports)."""
    try:
        a = accel.tolist() if type(accel) is np.ndarray else accel
        w = gyro.tolist() if type(gyro) is np.ndarray else gyro
        row = [float(a[0]), float(a[1]), float(a[2]), float(w[0]), float(w[1]), float(w[2]),
               float(dt)]
        if len(a) != 3 or len(w) != 3:
            return None
    except (TypeError, ValueError, IndexError):
        return None
    if not math.isfinite(sum(row)) or row[6] <= 0:
        return None
    return row


def _hat(v: np.ndarray) -> np.ndarray:
    """Skew matrices ``(..., 3, 3)`` of vectors ``(..., 3)``."""
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1),
                     np.stack([-y, x, z], -1)], -2)


def _prefix_scan(c: list[np.ndarray]) -> list[np.ndarray]:
    """Inclusive prefix products ``q_0, q_0 q_1, ..., q_0 ... q_{n-1}`` of quaternions given as
    four component arrays.

    Two levels: the samples are cut into about sqrt(n) blocks; the products inside all blocks
    advance together (one vectorised step per position in a block), then the block totals are
    chained and each block is multiplied by the product of the blocks before it. About
    2 sqrt(n) vectorised steps on short arrays plus one pass over the samples."""
    n = len(c[0])
    b = max(1, int(np.sqrt(n)))
    L = -(-n // b)  # blocks
    pad = L * b - n
    ident = (0.0, 0.0, 0.0, 1.0)
    # (b, L): column l is block l, row j its j-th element (rows contiguous)
    cols = [np.ascontiguousarray(np.concatenate([x, np.full(pad, e)]).reshape(L, b).T)
            for x, e in zip(c, ident, strict=True)]
    for j in range(1, b):
        new = _so3.quat_mul(tuple(x[j - 1] for x in cols), tuple(x[j] for x in cols))
        for x, y in zip(cols, new, strict=True):
            x[j] = y
    # exclusive prefix of the block totals (sequential over the L blocks, Python floats)
    tot = [x[-1].tolist() for x in cols]
    acc = ident
    pre = np.empty((4, L))
    for l in range(L):
        pre[:, l] = acc
        acc = _so3.quat_mul(acc, (tot[0][l], tot[1][l], tot[2][l], tot[3][l]))
    out = _so3.quat_mul(tuple(pre[:, None, :]), tuple(cols))  # (b, L) each
    return [np.ascontiguousarray(x.T).reshape(-1)[:n] for x in out]


def _cumsum0(x: np.ndarray) -> np.ndarray:
    """``(0, x_0, x_0 + x_1, ...)``."""
    out = np.empty(len(x) + 1)
    out[0] = 0.0
    np.cumsum(x, out=out[1:])
    return out


class Preintegration:
    """Preintegrated IMU measurements between two keyframes.

    Error (tangent) order ``(dphi, dv, dp)``: rotation, velocity, position (Forster et al.;
    the filters order theirs differently, see :mod:`microlie.imu.filters`), in ``covariance``,
    the rows of ``bias_jacobian``, ``tangent_order`` and ``repr``.

    Attributes after :meth:`integrate`: ``delta_rotation`` (an ``SO3``), ``delta_velocity``,
    ``delta_position`` (3,), ``dt`` (total time), ``covariance`` (9x9, tangent order
    ``(dphi, dv, dp)``, see the module docstring), ``bias_jacobian`` (9x6: rows
    ``(dphi, dv, dp)``, columns ``(bias_gyro, bias_accel)``).

    Parameters
    ----------
    gyro_noise, accel_noise : float or array_like
        White-noise densities (rad/s/sqrt(Hz) and m/s^2/sqrt(Hz); scalars or one per axis).
    bias_gyro, bias_accel : array_like
        The biases the samples are corrected with (length 3).
    gravity : array_like
        Gravity in the navigation frame (default ``(0, 0, -9.81)``, z up); enters
        :meth:`predict` and the IMU factor.
    omega_coriolis : array_like, optional
        The earth rate in the navigation frame (off by default): the exact rotating-frame
        prediction of GTSAM 4.3.
    scheme : {"manifold", "tangent"}
        Forster's on-manifold scheme or GTSAM's default (tangent-space) one.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.imu import Preintegration
    >>> pim = Preintegration(gyro_noise=1.7e-4, accel_noise=2e-3, bias_gyro=np.zeros(3),
    ...                      bias_accel=np.zeros(3))
    >>> n = 200  # one second at 200 Hz, turning at 0.5 rad/s about z, accelerating 1 m/s^2 in x
    >>> _ = pim.integrate(np.tile([1.0, 0, 0], (n, 1)), np.tile([0, 0, 0.5], (n, 1)), 0.005)
    >>> round(float(pim.delta_rotation.log()[2]), 12), round(pim.dt, 12)
    (0.5, 1.0)
    >>> pim
    Preintegration(scheme='manifold', samples=200, dt=1, tangent_order=(dphi, dv, dp))
    """

    #: the names of the 9 error coordinates, in order (``covariance``, ``bias_jacobian`` rows)
    tangent_order = ("dphi", "dv", "dp")

    def __init__(self, gyro_noise: Any, accel_noise: Any, bias_gyro: Any = (0.0, 0.0, 0.0),
                 bias_accel: Any = (0.0, 0.0, 0.0), *, gravity: Any = (0.0, 0.0, -9.81),
                 omega_coriolis: Any = None, scheme: str = "manifold") -> None:
        if scheme not in ("manifold", "tangent"):
            raise ValueError(f"scheme must be 'manifold' or 'tangent', got {scheme!r}")
        self.gyro_noise = _vec3(gyro_noise, "gyro_noise")
        self.accel_noise = _vec3(accel_noise, "accel_noise")
        if np.any(self.gyro_noise < 0) or np.any(self.accel_noise < 0):
            raise ValueError("noise densities must be >= 0")
        self.bias_gyro = _vec3(bias_gyro, "bias_gyro")
        self.bias_accel = _vec3(bias_accel, "bias_accel")
        self.gravity = _vec3(gravity, "gravity")
        self.omega_coriolis = None if omega_coriolis is None else \
            _vec3(omega_coriolis, "omega_coriolis")
        self.scheme = scheme
        self.reset()

    def reset(self) -> None:
        """Forget every sample (keep the noise, biases and options).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> from microlie.imu import Preintegration
        >>> pim = Preintegration(gyro_noise=1.7e-4, accel_noise=2e-3)
        >>> _ = pim.integrate(np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
        >>> pim.reset()
        >>> pim.dt, pim.delta_velocity.tolist()
        (0.0, [0.0, 0.0, 0.0])
        """
        self._q = np.array([0.0, 0.0, 0.0, 1.0])
        self._theta = np.zeros(3)  # tangent scheme: the rotation vector of dR
        self._dv = np.zeros(3)
        self._dp = np.zeros(3)
        self._T = 0.0
        self._cov_left = np.zeros((9, 9))  # (psi = dR dphi, dv, dp); tangent: (dtheta, dv, dp)
        self._jac_left = np.zeros((9, 6))
        self._n = 0
        self._pending: list[list[float]] = []  # buffered samples (accel, gyro, dt)

    # ------------------------------------------------------------------ results
    @property
    def delta_rotation(self) -> SO3:
        """``dR_ij`` as an ``SO3`` element."""
        self._flush()
        return SO3.from_params(self._q, check=False)

    @property
    def delta_velocity(self) -> np.ndarray:
        """``dv_ij`` (3,), in the frame of keyframe ``i``."""
        self._flush()
        return self._dv.copy()

    @property
    def delta_position(self) -> np.ndarray:
        """``dp_ij`` (3,), in the frame of keyframe ``i``."""
        self._flush()
        return self._dp.copy()

    @property
    def dt(self) -> float:
        """The integrated time (s)."""
        self._flush()
        return self._T

    @property
    def count(self) -> int:
        """The number of integrated samples."""
        return self._n + len(self._pending)

    def _to_ours(self) -> np.ndarray:
        """The 9x9 map from the internal error coordinates to ``(dphi, dv, dp)``."""
        self._flush()
        T = np.eye(9)
        if self.scheme == "manifold":
            T[:3, :3] = self.delta_rotation.matrix().T  # dphi = dR^T psi
        else:
            T[:3, :3] = SO3.jr(self._theta)  # dphi = Jr(theta) dtheta
        return T

    @property
    def covariance(self) -> np.ndarray:
        """9x9 covariance of ``(dphi, dv, dp)`` (see the module docstring)."""
        T = self._to_ours()
        return T @ self._cov_left @ T.T

    @property
    def bias_jacobian(self) -> np.ndarray:
        """9x6 Jacobian of ``(dphi, dv, dp)`` with respect to ``(bias_gyro, bias_accel)``."""
        return self._to_ours() @ self._jac_left

    # ------------------------------------------------------------------ integration
    def integrate(self, accel: Any, gyro: Any, dt: Any) -> Preintegration:
        """Add IMU samples.

        Parameters
        ----------
        accel : array_like
            ``(N, 3)`` (or ``(3,)`` for one sample) specific force in the body frame, m/s^2.
        gyro : array_like
            ``(N, 3)`` (or ``(3,)``) angular rate in the body frame, rad/s.
        dt : float or array_like
            Sample interval(s), seconds (> 0): a scalar or ``(N,)``.

        Returns
        -------
        Preintegration
            ``self``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> from microlie.imu import Preintegration
        >>> pim = Preintegration(gyro_noise=1.7e-4, accel_noise=2e-3)
        >>> _ = pim.integrate(np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
        >>> round(pim.dt, 12), np.round(pim.delta_velocity, 12).tolist()
        (1.0, [0.0, 0.0, 9.81])
        """
        if self.scheme == "manifold" and getattr(accel, "ndim", 1) == 1 and \
                getattr(gyro, "ndim", 1) == 1 and np.ndim(dt) == 0:
            row = _sample_row(accel, gyro, dt)
            if row is not None:  # one sample: Python-float checks, buffered
                self._pending.append(row)
                if len(self._pending) >= BUFFER:
                    self._flush()
                return self
        a = np.asarray(accel, dtype=np.float64)
        w = np.asarray(gyro, dtype=np.float64)
        if a.ndim == 1:
            a, w = a[None], w[None]
        if a.ndim != 2 or a.shape[1] != 3 or w.shape != a.shape:
            raise ValueError(f"accel and gyro must both have shape (N, 3), got {a.shape} and "
                             f"{w.shape}")
        n = a.shape[0]
        d = np.asarray(dt, dtype=np.float64)
        if d.ndim == 0:
            d = np.full(n, float(d))
        if d.shape != (n,):
            raise ValueError(f"dt must be a scalar or have shape ({n},), got {d.shape}")
        for x, what in ((a, "accel"), (w, "gyro"), (d, "dt")):
            if not np.all(np.isfinite(x)):
                raise ValueError(f"{what} has NaN or infinite entries")
        if np.any(d <= 0):
            raise ValueError("dt must be > 0")
        if n == 0:
            return self
        if self.scheme == "manifold" and n < SMALL:
            # few samples (e.g. one per call): buffered, integrated together when a result is
            # read or the buffer is full (the same arithmetic as one call with all of them)
            self._pending.extend(np.concatenate([a, w, d[:, None]], 1).tolist())
            if len(self._pending) >= BUFFER:
                self._flush()
            return self
        self._flush()
        for s in range(0, n, CHUNK):
            e = s + CHUNK
            self._run(a[s:e] - self.bias_accel, w[s:e] - self.bias_gyro, d[s:e])
        return self

    def _run(self, a: np.ndarray, w: np.ndarray, d: np.ndarray) -> None:
        n = len(d)
        if self.scheme == "tangent":
            self._integrate_tangent(a, w, d)
        elif n < SMALL:
            self._integrate_few(a, w, d)
        else:
            self._integrate_manifold(a, w, d)
        self._n += n

    def _flush(self) -> None:
        if not self._pending:
            return
        rows = np.array(self._pending)
        self._pending = []
        self._run(rows[:, 0:3] - self.bias_accel, rows[:, 3:6] - self.bias_gyro, rows[:, 6])

    def _integrate_manifold(self, a: np.ndarray, w: np.ndarray, d: np.ndarray) -> None:
        # Written on contiguous component arrays (one array of n per matrix entry): several
        # times faster than (n, 3, 3) arrays for these small matrices.
        n = len(d)
        o = NUMPY
        aT = np.ascontiguousarray(a.T)
        phi = tuple(np.ascontiguousarray(w.T) * d)
        dq = _so3.quat_exp(o, phi)
        jr = _so3.jr(o, phi)
        scan = _prefix_scan([np.asarray(c, dtype=np.float64) for c in dq])
        q0 = tuple(float(x) for x in self._q)
        qk = _so3.quat_mul(q0, tuple(scan))  # R_1 .. R_n
        q = [np.concatenate([[q0[i]], qk[i]]) for i in range(4)]  # R_0 .. R_n
        R = _so3.quat_to_matrix(tuple(q))
        R0 = tuple(tuple(x[:-1] for x in row) for row in R)  # R_k, k = 0 .. n-1
        R1 = tuple(tuple(x[1:] for x in row) for row in R)  # R_{k+1}
        f = [R0[i][0] * aT[0] + R0[i][1] * aT[1] + R0[i][2] * aT[2] for i in range(3)]
        d2 = 0.5 * d * d
        s = [_cumsum0(fi * d) for fi in f]  # v_k - v_0, k = 0 .. n
        wk = [_cumsum0(s[i][:-1] * d + f[i] * d2) for i in range(3)]  # p_k - p_0 - v_0 t_k
        tk = _cumsum0(d)
        T = float(tk[-1])
        v0 = self._dv
        # Error transition from step m to the end, in left coordinates (psi = R dphi):
        #   [[I, 0, 0], [-hat(s_n - s_m), I, 0],
        #    [-hat(w_n - w_m - s_m (T - t_m)), (T - t_m) I, I]]
        # Noise of step k enters at m = k + 1 through G_k = [[R_{k+1} Jr_k dt, 0],
        # [0, R_k dt], [0, R_k dt^2 / 2]]; the biases enter the same way with a minus sign.
        # H_k = Phi_(n, k+1) G_k is stored as H[i, a, k] (9, 6, n).
        Bg = _M.matmul(R1, jr)
        rest = T - tk[1:]
        sv = [s[i][-1] - s[i][1:] for i in range(3)]
        sp = [wk[i][-1] - wk[i][1:] - s[i][1:] * rest for i in range(3)]
        H = np.empty((9, 6, n))
        H[0:3, 3:6] = 0.0
        cp = d * (rest + 0.5 * d)
        Bd = [[Bg[i][c] * d for c in range(3)] for i in range(3)]
        for i in range(3):
            j, k = (i + 1) % 3, (i + 2) % 3  # (hat(v) B)_i = v_j B_k - v_k B_j
            for c in range(3):
                H[i, c] = Bd[i][c]
                np.multiply(sv[k], Bd[j][c], out=H[3 + i, c])
                H[3 + i, c] -= sv[j] * Bd[k][c]
                np.multiply(sp[k], Bd[j][c], out=H[6 + i, c])
                H[6 + i, c] -= sp[j] * Bd[k][c]
                np.multiply(R0[i][c], d, out=H[3 + i, 3 + c])
                np.multiply(R0[i][c], cp, out=H[6 + i, 3 + c])
        Phi = np.eye(9)
        s_n = np.array([x[-1] for x in s])
        w_n = np.array([x[-1] for x in wk])
        Phi[3:6, 0:3] = -_hat(s_n)
        Phi[6:9, 0:3] = -_hat(w_n)
        Phi[6:9, 3:6] = T * np.eye(3)
        jsum = H.sum(-1)  # sum_k H_k (9, 6), before the noise scaling
        dev = np.concatenate([self.gyro_noise, self.accel_noise])
        if np.all(d == d[0]):  # constant dt: scale the six products, not the samples
            cov = np.zeros((9, 9))
            for c in range(6):
                Hc = H[:, c]
                cov += (dev[c] ** 2 / d[0]) * (Hc @ Hc.T)
        else:
            H *= dev[:, None] / np.sqrt(d)
            X = H.reshape(9, 6 * n)
            cov = X @ X.T

        self._cov_left = Phi @ self._cov_left @ Phi.T + cov
        self._jac_left = Phi @ self._jac_left - jsum
        self._q = np.array([x[-1] for x in q])
        self._dp = self._dp + v0 * T + w_n
        self._dv = v0 + s_n
        self._T += T

    def _integrate_few(self, a: np.ndarray, w: np.ndarray, d: np.ndarray) -> None:
        """The manifold scheme one sample at a time (few samples: less overhead than the
        vectorised path), in the same left error coordinates."""
        o = SCALAR
        q = tuple(self._q.tolist())
        v, p = self._dv, self._dp
        P, J = self._cov_left, self._jac_left
        qg = np.concatenate([self.gyro_noise**2, self.accel_noise**2])
        A = np.eye(9)
        B = np.zeros((9, 6))
        R0 = np.array(_so3.quat_to_matrix(q))
        eye3 = np.eye(3)
        for k in range(len(d)):
            dt = float(d[k])
            phi = tuple((w[k] * dt).tolist())
            q1 = _so3.quat_mul(q, _so3.quat_exp(o, phi))
            R1 = np.array(_so3.quat_to_matrix(q1))
            f = R0 @ a[k]
            x, y, z = f.tolist()
            Fh = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
            A[3:6, 0:3] = Fh * -dt
            A[6:9, 0:3] = Fh * (-0.5 * dt * dt)
            A[6:9, 3:6] = eye3 * dt
            B[0:3, 0:3] = R1 @ np.array(_so3.jr(o, phi)) * dt
            B[3:6, 3:6] = R0 * dt
            B[6:9, 3:6] = R0 * (0.5 * dt * dt)
            P = A @ P @ A.T + (B * (qg / dt)) @ B.T
            J = A @ J - B
            p = p + v * dt + f * (0.5 * dt * dt)
            v = v + f * dt
            q, R0 = q1, R1
        self._q = np.array(q)
        self._dv, self._dp = v, p
        self._cov_left, self._jac_left = P, J
        self._T += float(d.sum())

    def _integrate_tangent(self, a: np.ndarray, w: np.ndarray, d: np.ndarray) -> None:
        """GTSAM's tangent scheme on ``x = (theta, v, p)``: sequential."""
        th, v, p = self._theta.copy(), self._dv.copy(), self._dp.copy()
        P, J = self._cov_left, self._jac_left
        Qg, Qa = self.gyro_noise**2, self.accel_noise**2
        eye3 = np.eye(3)
        for k in range(len(d)):
            dt = d[k]
            R = SO3.exp(th).matrix()
            jr = SO3.jr(th)
            jri = SO3.jr_inv(th)
            wt = jri @ w[k]
            # d(Jr^-1(theta) w) / d theta, by differentiating Jr(theta) (Jr^-1 w) = w
            wt_th = -jri @ _djr_times(th, wt)
            an = R @ a[k]
            an_th = -R @ _hat(a[k]) @ jr
            A = np.eye(9)
            A[0:3, 0:3] += wt_th * dt
            A[3:6, 0:3] = an_th * dt
            A[6:9, 0:3] = an_th * (0.5 * dt * dt)
            A[6:9, 3:6] = eye3 * dt
            Bw = np.zeros((9, 3))
            Bw[0:3] = jri * dt
            Ba = np.zeros((9, 3))
            Ba[3:6] = R * dt
            Ba[6:9] = R * (0.5 * dt * dt)
            p = p + v * dt + an * (0.5 * dt * dt)
            v = v + an * dt
            th = th + wt * dt
            P = A @ P @ A.T + (Bw * (Qg / dt)) @ Bw.T + (Ba * (Qa / dt)) @ Ba.T
            J = A @ J - np.concatenate([Bw, Ba], 1)
        self._theta, self._dv, self._dp = th, v, p
        self._cov_left, self._jac_left = P, J
        self._q = SO3.exp(th).params
        self._T += float(d.sum())

    # ------------------------------------------------------------------ bias correction
    def correct(self, bias_gyro: Any, bias_accel: Any) -> tuple[SO3, np.ndarray, np.ndarray]:
        """The deltas for other biases, to first order: ``dR Exp(J_Rg db_g)``,
        ``dv + J_vg db_g + J_va db_a``, ``dp + J_pg db_g + J_pa db_a`` (the tangent scheme
        corrects its rotation vector linearly instead, as GTSAM does).

        Parameters
        ----------
        bias_gyro, bias_accel : array_like
            The new biases (length 3).

        Returns
        -------
        dR : SO3
        dv, dp : numpy.ndarray
            ``(3,)`` each.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> from microlie.imu import Preintegration
        >>> pim = Preintegration(gyro_noise=1.7e-4, accel_noise=2e-3)
        >>> _ = pim.integrate(np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
        >>> dR, dv, dp = pim.correct(np.zeros(3), [0.1, 0.0, 0.0])
        >>> np.round(dv, 12).tolist()  # 1 s with 0.1 m/s^2 more accelerometer bias
        [-0.1, 0.0, 9.81]
        """
        self._flush()
        db = np.concatenate([_vec3(bias_gyro, "bias_gyro") - self.bias_gyro,
                             _vec3(bias_accel, "bias_accel") - self.bias_accel])
        if self.scheme == "manifold":
            c = self.bias_jacobian @ db
            R = self.delta_rotation @ SO3.exp(c[:3])
        else:
            c = self._jac_left @ db
            R = SO3.exp(self._theta + c[:3])
        return R, self._dv + c[3:6], self._dp + c[6:9]  # type: ignore

    def predict(self, state: Any, bias_gyro: Any = None, bias_accel: Any = None) -> Any:
        """The state at keyframe ``j`` from the state at ``i`` and the biases, with gravity and
        (if set) the earth rate.

        Parameters
        ----------
        state : SE23
            The navigation state ``(R, p, v)`` at keyframe ``i``.
        bias_gyro, bias_accel : array_like, optional
            The biases (default: the integration biases; others are applied to first order).

        Returns
        -------
        SE23

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> from microlie.imu import Preintegration
        >>> pim = Preintegration(gyro_noise=1.7e-4, accel_noise=2e-3)
        >>> _ = pim.integrate(np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
        >>> Xj = pim.predict(SE23.identity())  # at rest: the state does not change
        >>> bool(np.abs(Xj.log()).max() < 1e-12)
        True
        """
        from ..groups import SE23

        bg = self.bias_gyro if bias_gyro is None else bias_gyro
        ba = self.bias_accel if bias_accel is None else bias_accel
        dR, dv, dp = self.correct(bg, ba)
        return _predict(SE23, state, dR, dv, dp, self.dt, self.gravity, self.omega_coriolis)

    def __repr__(self) -> str:
        return (f"Preintegration(scheme={self.scheme!r}, samples={self.count}, "
                f"dt={self.dt:.6g}, tangent_order=({', '.join(self.tangent_order)}))")


def _predict(SE23: Any, X: Any, dR: SO3, dv: np.ndarray, dp: np.ndarray, T: Any,
             g: np.ndarray, omega: np.ndarray | None) -> Any:
    """The predicted state at ``j``. Without an earth rate: ``R_j = R_i dR``,
    ``v_j = v_i + g T + R_i dv``, ``p_j = p_i + v_i T + g T^2/2 + R_i dp``.

    With an earth rate ``omega`` (navigation frame) the exact rotating-frame prediction that
    GTSAM 4.3 uses (after Brossard et al.): with ``A = Exp(-omega T)``,
    ``G_v = Jl(-omega T)``, ``G_p = Jl(-omega T) - Gamma_2(-omega T)``
    (``Gamma_2(w) = sum_n hat(w)^n / (n+2)!``) and the transported velocity
    ``u = v_i + omega x p_i``: ``R_j = A R_i dR``, ``p_j = G_p g T^2 + A (p_i + u T + R_i dp)``,
    ``v_j = G_v g T + A (u + R_i dv) - omega x p_j``.
    """
    Ri = X.rotation()
    pi, vi = np.asarray(X.translation()), np.asarray(X.velocity())
    Rm = np.asarray(Ri.matrix())
    dv_n = (Rm @ np.asarray(dv)[..., :, None])[..., 0]
    dp_n = (Rm @ np.asarray(dp)[..., :, None])[..., 0]
    if omega is None:
        Rj = Ri @ dR
        vj = vi + g * T + dv_n
        pj = pi + vi * T + 0.5 * g * T * T + dp_n
        return SE23.from_rotation_translation(Rj, pj, vj)
    Tn = np.asarray(T, dtype=np.float64)
    w = -omega * Tn  # (..., 3)
    A = SO3.exp(w)
    Am = np.asarray(A.matrix())
    Gv = np.asarray(SO3.jl(w))
    Gp = Gv - _gamma2(w)
    u = vi + np.cross(omega, pi)

    def mv(M, x):
        return (M @ x[..., :, None])[..., 0]

    Rj = A @ (Ri @ dR)
    pj = mv(Gp, g * Tn * Tn + 0.0 * pi) + mv(Am, pi + u * Tn + dp_n)
    vj = mv(Gv, g * Tn + 0.0 * pi) + mv(Am, u + dv_n) - np.cross(omega, pj)
    return SE23.from_rotation_translation(Rj, pj, vj)


def _gamma2(w: np.ndarray) -> np.ndarray:
    """``Gamma_2(w) = sum_n hat(w)^n / (n+2)! = I/2 + (t - sin t)/t^3 W
    + (t^2 + 2 cos t - 2)/(2 t^4) W^2`` (``W = hat(w)``, ``t = |w|``; series below t = 1)."""
    from ..groups import _math as M

    t2 = np.sum(w * w, -1)[..., None, None]
    small = t2 < 1.0
    ts = np.sqrt(np.where(small, 1.0, t2))
    b = np.where(small, M.horner(t2, M.C_T_SIN), (ts - np.sin(ts)) / ts**3)
    c = np.where(small, M.horner(t2, M.C_COS4), (ts**2 + 2 * np.cos(ts) - 2) / (2 * ts**4))
    W = _hat(w)
    return 0.5 * np.eye(3) + b * W + c * (W @ W)


def _series(term: Any, n: int = 12) -> tuple[float, ...]:
    return tuple(float(term(k)) for k in range(n))


# Taylor coefficients in t^2 of the Jr coefficient a = (1 - cos t)/t^2 = sum (-1)^k t^2k/(2k+2)!
# and of a'(t)/t and b'(t)/t (b = (t - sin t)/t^3 = sum (-1)^k t^2k/(2k+3)!)
C_A = _series(lambda k: Fraction((-1) ** k, factorial(2 * k + 2)))
C_DA = _series(lambda k: Fraction((-1) ** (k + 1) * 2 * (k + 1), factorial(2 * k + 4)))
C_DB = _series(lambda k: Fraction((-1) ** (k + 1) * 2 * (k + 1), factorial(2 * k + 5)))


def _djr_times(theta: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``d (Jr(theta) x) / d theta`` (3x3) for ``Jr(theta) x = x - a theta x x
    + b theta x (theta x x)``, ``a = (1 - cos t)/t^2``, ``b = (t - sin t)/t^3``:
    ``a hat(x) - (theta x x) (a'/t) theta^T + b ((theta.x) I + theta x^T - 2 x theta^T)
    + theta x (theta x x) (b'/t) theta^T`` (series for ``a'/t``, ``b'/t`` below t = 1)."""
    t2 = float(theta @ theta)
    if t2 < 1.0:
        a = _M.horner(t2, C_A)
        b = _M.horner(t2, _M.C_T_SIN)
        da = _M.horner(t2, C_DA)
        db = _M.horner(t2, C_DB)
    else:
        t = math.sqrt(t2)
        st, ct = math.sin(t), math.cos(t)
        a = (1.0 - ct) / t2
        b = (t - st) / (t2 * t)
        da = (t * st - 2.0 * (1.0 - ct)) / (t2 * t2)
        db = ((1.0 - ct) * t - 3.0 * (t - st)) / (t2 * t2 * t)
    c = np.cross(theta, x)
    cc = np.cross(theta, c)
    return (a * _hat(x) - da * np.outer(c, theta)
            + b * (float(theta @ x) * np.eye(3) + np.outer(theta, x) - 2.0 * np.outer(x, theta))
            + db * np.outer(cc, theta))
