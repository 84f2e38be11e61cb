"""IMU factors for :class:`microlie.optim.FactorGraph`.

* :class:`ImuFactor`: one batch of preintegrated IMU measurements between navigation states
  ``X_i, X_j`` (``SE23`` variables) with the bias ``b_i`` (an ``(n, 6)`` vector variable,
  ``(b_g, b_a)``); residual of :func:`microlie.imu.residual.imu_residual` (Forster et al. 2017
  eq. 45, or ``error="logmap"`` for GTSAM 4.3's default), weighted by the preintegration
  covariance, with analytic right Jacobians.
* :class:`BiasRandomWalkFactor`: ``r = b_j - b_i`` with covariance
  ``diag(s_gw^2, s_aw^2) T`` from the bias random-walk densities (rad/s^2/sqrt(Hz),
  m/s^3/sqrt(Hz)) and the time ``T`` between the keyframes.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..groups import SE23, R
from ..optim.core.factors import Factor
from ..optim.core.noise import Covariance, Diagonal, NoiseModel
from ..optim.core.variables import Variables
from .preintegration import Preintegration
from .residual import ERRORS, Deltas, imu_residual

__all__ = ["ImuFactor", "BiasRandomWalkFactor", "PositionFactor"]


def _stacked(factors: Sequence[Any], merge: Any, extra: Any = None) -> list[Any]:
    """``factors`` (batches of one factor class) as few batches, the ``stack`` of every factor
    of this module: grouped by what one batch must share (variable handles, loss and
    ``extra(f)``), in first-appearance order; a group of one batch is kept as it is, a larger
    one becomes ``merge(group)``, one batch with the group's rows in the order given."""
    out: dict[Any, list[Any]] = {}
    for f in factors:
        key = (tuple(id(v) for v, _ in f.args), id(f.loss), None if extra is None else extra(f))
        out.setdefault(key, []).append(f)
    return [grp[0] if len(grp) == 1 else merge(grp) for grp in out.values()]


def _indices(group: Sequence[Factor], a: int) -> np.ndarray:
    return np.concatenate([f.args[a][1] for f in group])


def _noise(group: Sequence[Factor]) -> NoiseModel:
    """The rows' square-root informations, stacked."""
    return NoiseModel(np.concatenate([np.broadcast_to(f.noise.sqrt_info.reshape(
        -1, f.dim, f.dim), (f.count, f.dim, f.dim)) for f in group]))


class ImuFactor(Factor):
    """IMU factors ``(X_i, X_j, b_i)`` for ``m`` keyframe pairs.

    The noise is each preintegration's covariance.

    Parameters
    ----------
    states : Variables
        An ``SE23`` variable handle.
    biases : Variables
        An ``(n, 6)`` vector handle (``(b_g, b_a)``).
    i, j : array_like
        Index arrays of the state pairs (the bias of state ``i`` is used).
    pims : sequence of Preintegration
        One per pair.
    error : str
        The residual form (see :func:`~microlie.imu.imu_residual`).
    loss : str or RobustLoss, optional
        A robust loss, as for every factor.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE23
    >>> from microlie.imu import ImuFactor, Preintegration
    >>> from microlie.optim import FactorGraph
    >>> pim = Preintegration(gyro_noise=1e-3, accel_noise=1e-2).integrate(
    ...     np.tile([0.0, 0.0, 9.81], (100, 1)), np.zeros((100, 3)), 0.01)
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE23.identity(2))
    >>> b = g.add_variables(np.zeros((2, 6)))
    >>> _ = g.add(ImuFactor(x, b, [0], [1], [pim]))
    >>> round(g.cost(), 9)  # at rest, the identity states satisfy the measurement exactly
    0.0
    """

    def __init__(self, states: Variables, biases: Variables, i: Any, j: Any,
                 pims: Sequence[Preintegration], *, error: str = "forster",
                 loss: Any = None) -> None:
        if states.group is not SE23:
            raise TypeError("ImuFactor: states must be SE23 variables")
        if biases.group is not R(6):
            raise TypeError("ImuFactor: biases must be an (n, 6) vector variable (b_g, b_a)")
        if error not in ERRORS:
            raise ValueError(f"ImuFactor: error must be one of {ERRORS}, got {error!r}")
        pims = list(pims)
        m = max(np.size(i), np.size(j))
        if len(pims) != m:
            raise ValueError(f"ImuFactor: {len(pims)} preintegrations for {m} pairs")
        self.pims = pims
        self.deltas = Deltas(pims)
        super().__init__([(states, i), (states, j), (biases, i)], 9,
                         Covariance(self.deltas.cov if error == "forster" else
                                    self._logmap_cov(self.deltas)), loss)
        self.error = error

    @classmethod
    def stack(cls, factors: Sequence[ImuFactor]) -> list[ImuFactor]:
        """Several batches as few: one per set of variable handles, loss and ``error``, the
        rows in the order given (a window of batches of one evaluated in one call).

        Parameters
        ----------
        factors : sequence of ImuFactor

        Returns
        -------
        list of ImuFactor

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> from microlie.imu import ImuFactor, Preintegration
        >>> from microlie.optim import FactorGraph
        >>> pim = Preintegration(1e-3, 1e-2).integrate(np.tile([0, 0, 9.81], (10, 1)),
        ...                                           np.zeros((10, 3)), 0.01)
        >>> g = FactorGraph()
        >>> x, b = g.add_variables(SE23.identity(3)), g.add_variables(np.zeros((3, 6)))
        >>> [f.count for f in ImuFactor.stack([ImuFactor(x, b, [0], [1], [pim]),
        ...                                    ImuFactor(x, b, [1], [2], [pim])])]
        [2]
        """
        return _stacked(factors, lambda grp: cls(
            grp[0].args[0][0], grp[0].args[2][0], _indices(grp, 0), _indices(grp, 1),
            [p for f in grp for p in f.pims], error=grp[0].error, loss=grp[0].loss),
            extra=lambda f: f.error)

    @staticmethod
    def _logmap_cov(d: Deltas) -> np.ndarray:
        """The covariance of the Logmap residual ``(phi, nu, rho)``: velocity and position
        errors are in the frame of ``dR`` (``dR^T`` times ours), as GTSAM's."""
        from ..groups import SO3

        Rt = np.swapaxes(np.asarray(SO3.from_params(d.q, check=False).matrix()), -1, -2)
        T = np.zeros((len(d), 9, 9))
        T[:, 0:3, 0:3] = np.eye(3)
        T[:, 3:6, 3:6] = Rt
        T[:, 6:9, 6:9] = Rt
        return T @ d.cov @ np.swapaxes(T, -1, -2)

    def residual(self, Xi: Any, Xj: Any, b: Any, jac: bool = False) -> Any:
        """The residual of :func:`~microlie.imu.imu_residual` and, with ``jac``, its right
        Jacobians ``[d r / d X_i, d r / d X_j, d r / d b_i]`` (:meth:`Factor.residual`).

        Parameters
        ----------
        Xi, Xj : SE23
            The batches of states ``i`` and ``j``.
        b : numpy.ndarray
            ``(m, 6)`` biases of the states ``i``.
        jac : bool
            Also return the Jacobians.

        Returns
        -------
        numpy.ndarray or tuple
            ``r`` ``(m, 9)``, or ``(r, [J_i, J_j, J_b])``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> from microlie.imu import ImuFactor, Preintegration
        >>> from microlie.optim import FactorGraph
        >>> pim = Preintegration(gyro_noise=1e-3, accel_noise=1e-2).integrate(
        ...     np.tile([0.0, 0.0, 9.81], (10, 1)), np.zeros((10, 3)), 0.01)
        >>> g = FactorGraph()
        >>> f = ImuFactor(g.add_variables(SE23.identity(2)), g.add_variables(np.zeros((2, 6))),
        ...               [0], [1], [pim])
        >>> r, Js = f.residual(SE23.identity(1), SE23.identity(1), np.zeros((1, 6)), jac=True)
        >>> r.shape, [J.shape for J in Js]
        ((1, 9), [(1, 9, 9), (1, 9, 9), (1, 9, 6)])
        """
        out = imu_residual(self.deltas, Xi, Xj, b, jac=jac, error=self.error)
        return (out[0], list(out[1:])) if jac else out


class BiasRandomWalkFactor(Factor):
    """``r = b_j - b_i`` between bias variables, noise ``diag(s_gw^2 I, s_aw^2 I) dt``.

    Parameters
    ----------
    biases : Variables
        An ``(n, 6)`` vector handle (``(b_g, b_a)``).
    i, j : array_like
        Index arrays of the pairs.
    gyro_walk, accel_walk : float
        Random-walk densities (rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz)).
    dt : float or array_like
        Time between the keyframes (scalar or one per pair).
    loss : str or RobustLoss, optional
        A robust loss.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.imu import BiasRandomWalkFactor
    >>> from microlie.optim import FactorGraph
    >>> g = FactorGraph()
    >>> b = g.add_variables(np.array([[0.0] * 6, [0.01, 0, 0, 0, 0, 0]]))
    >>> _ = g.add(BiasRandomWalkFactor(b, [0], [1], gyro_walk=0.01, accel_walk=0.1, dt=1.0))
    >>> round(g.cost(), 9)  # 0.5 * (0.01 / 0.01)^2
    0.5
    """

    def __init__(self, biases: Variables, i: Any, j: Any, gyro_walk: float, accel_walk: float,
                 dt: Any, loss: Any = None) -> None:
        if biases.group is not R(6):
            raise TypeError("BiasRandomWalkFactor: biases must be an (n, 6) vector variable")
        t = np.atleast_1d(np.asarray(dt, dtype=np.float64))
        if np.any(t <= 0) or not np.all(np.isfinite(t)):
            raise ValueError("BiasRandomWalkFactor: dt must be positive and finite")
        if not (gyro_walk > 0 and accel_walk > 0):
            raise ValueError("BiasRandomWalkFactor: random-walk densities must be positive")
        sig = np.concatenate([np.full(3, gyro_walk), np.full(3, accel_walk)])
        super().__init__([(biases, i), (biases, j)], 6, Diagonal(sig * np.sqrt(t)[:, None]),
                         loss)

    def residual(self, bi: Any, bj: Any, jac: bool = False) -> Any:
        """``r = b_j - b_i`` and, with ``jac``, ``[-I, I]`` (:meth:`Factor.residual`).

        Parameters
        ----------
        bi, bj : numpy.ndarray
            ``(m, 6)`` biases at both ends.
        jac : bool
            Also return the Jacobians.

        Returns
        -------
        numpy.ndarray or tuple
            ``r`` ``(m, 6)``, or ``(r, [-I, I])``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.imu import BiasRandomWalkFactor
        >>> from microlie.optim import FactorGraph
        >>> f = BiasRandomWalkFactor(FactorGraph().add_variables(np.zeros((2, 6))), [0], [1],
        ...                          gyro_walk=0.01, accel_walk=0.1, dt=1.0)
        >>> f.residual(np.zeros((1, 6)), np.ones((1, 6))).tolist()
        [[1.0, 1.0, 1.0, 1.0, 1.0, 1.0]]
        """
        r = np.asarray(bj) - np.asarray(bi)
        if not jac:
            return r
        eye = np.broadcast_to(np.eye(6), (self.count, 6, 6))
        return r, [-eye, eye]

    @classmethod
    def stack(cls, factors: Sequence[BiasRandomWalkFactor]) -> list[BiasRandomWalkFactor]:
        """Several batches as few (as :meth:`ImuFactor.stack`).

        Parameters
        ----------
        factors : sequence of BiasRandomWalkFactor

        Returns
        -------
        list of BiasRandomWalkFactor

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.imu import BiasRandomWalkFactor
        >>> from microlie.optim import FactorGraph
        >>> b = FactorGraph().add_variables(np.zeros((3, 6)))
        >>> fs = [BiasRandomWalkFactor(b, [k], [k + 1], 1e-4, 1e-3, 0.1) for k in (0, 1)]
        >>> [f.count for f in BiasRandomWalkFactor.stack(fs)]
        [2]
        """
        def merge(grp: list[BiasRandomWalkFactor]) -> BiasRandomWalkFactor:
            f = cls.__new__(cls)  # the rows keep their own noise: no (walks, dt) to rebuild
            Factor.__init__(f, [(grp[0].args[0][0], _indices(grp, 0)),
                                (grp[0].args[1][0], _indices(grp, 1))], 6, _noise(grp),
                            grp[0].loss)
            return f

        return _stacked(factors, merge)


class PositionFactor(Factor):
    """Position fixes of navigation states: ``r = p(X) - z`` (a GNSS or motion-capture fix).

    With the right perturbation ``X Exp(rho, phi, nu)`` the position moves by ``R rho`` to
    first order, so the Jacobian is ``[R, 0, 0]``.

    Parameters
    ----------
    states : Variables
        An ``SE23`` variable handle.
    idx : array_like
        The indices of the ``m`` fixed states.
    z : array_like
        ``(m, 3)`` (or ``(3,)``) measured positions, world frame.
    noise : NoiseModel or array_like, optional
        The fixes' noise (default unit).
    loss : str or RobustLoss, optional
        A robust loss.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE23
    >>> from microlie.imu import PositionFactor
    >>> from microlie.optim import FactorGraph, Isotropic
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE23.identity(1))
    >>> _ = g.add(PositionFactor(x, 0, [0.0, 0.0, 0.2], Isotropic(3, 0.1)))
    >>> round(g.cost(), 9)  # 0.5 (0.2 / 0.1)^2
    2.0
    """

    def __init__(self, states: Variables, idx: Any, z: Any, noise: Any = None,
                 loss: Any = None) -> None:
        if states.group is not SE23:
            raise TypeError("PositionFactor: states must be SE23 variables")
        super().__init__([(states, idx)], 3, noise, loss)
        zz = np.asarray(z, dtype=np.float64)
        if zz.ndim == 1:
            zz = zz[None]
        if zz.shape not in ((1, 3), (self.count, 3)) or not np.all(np.isfinite(zz)):
            raise ValueError(f"PositionFactor: z must be finite, (3,) or ({self.count}, 3), "
                             f"got shape {zz.shape}")
        self.z = zz

    def residual(self, X: Any, jac: bool = False) -> Any:
        """``p(X) - z`` and, with ``jac``, ``[R, 0, 0]`` (:meth:`Factor.residual`).

        Parameters
        ----------
        X : SE23
            The batch of states.
        jac : bool
            Also return the Jacobian.

        Returns
        -------
        numpy.ndarray or tuple
            ``r`` ``(m, 3)``, or ``(r, [J])`` with ``J`` ``(m, 3, 9)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> from microlie.imu import PositionFactor
        >>> from microlie.optim import FactorGraph
        >>> f = PositionFactor(FactorGraph().add_variables(SE23.identity(1)), 0, [1.0, 0, 0])
        >>> f.residual(SE23.identity(1)).tolist()
        [[-1.0, 0.0, 0.0]]
        """
        r = np.asarray(X.translation()) - self.z
        if not jac:
            return r
        J = np.zeros((r.shape[0], 3, 9))
        J[:, :, 0:3] = np.asarray(X.rotation().matrix())
        return r, [J]

    @classmethod
    def stack(cls, factors: Sequence[PositionFactor]) -> list[PositionFactor]:
        """Several batches as few (as :meth:`ImuFactor.stack`).

        Parameters
        ----------
        factors : sequence of PositionFactor

        Returns
        -------
        list of PositionFactor

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE23
        >>> from microlie.imu import PositionFactor
        >>> from microlie.optim import FactorGraph, Isotropic
        >>> x = FactorGraph().add_variables(SE23.identity(2))
        >>> fs = [PositionFactor(x, k, [k, 0.0, 0.0], Isotropic(3, 0.1)) for k in (0, 1)]
        >>> [f.count for f in PositionFactor.stack(fs)]
        [2]
        """
        return _stacked(factors, lambda grp: cls(
            grp[0].args[0][0], _indices(grp, 0),
            np.concatenate([np.broadcast_to(g.z, (g.count, 3)) for g in grp]), _noise(grp),
            grp[0].loss))
