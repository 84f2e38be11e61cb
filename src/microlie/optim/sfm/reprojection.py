"""The reprojection factor: bundle adjustment as factors of a :class:`FactorGraph`.

``r = project(P, K) - observed`` (2 rows, pixels) with the camera-frame point ``P = R X + t``
(``R, t`` the world-to-camera transform, as BAL stores it) and a camera model of
:mod:`microlie.optim.sfm.camera`. The camera pose is one of

* an ``SE3`` variable ``T_cw = (R, t)``, perturbed on the right, ``T Exp(rho, phi)``
  (``R <- R Exp(phi)``, ``t <- t + R rho``): ``d r / d (rho, phi) = [A R, -A R [X]_x]``;
* an ``SO3`` variable ``R`` and an ``R(3)`` variable ``t`` (``R Exp(dphi)``, ``t + dt``; the
  parametrisation of BAL and Ceres): ``d r / d dphi = -A R [X]_x``, ``d r / d dt = A``;

with ``A = d uv / d P`` and ``d r / d X = A R``. With ``camera_to_world=True`` the pose variables
are the camera-to-world ``T_wc = (R_wc, c)`` instead (GTSAM's ``PinholeCamera`` pose, the
frame of pose graphs and odometry): ``P = R_wc^T (X - c)``, ``d P / d (rho, phi) = [-I,
[P]_x]`` for ``T_wc Exp(rho, phi)``, ``d P / d dphi = [P]_x`` and ``d P / d dc = -R_wc^T`` for
``R_wc Exp(dphi)``, ``c + dc``. Intrinsics are an ``R(k)`` variable (held per camera with
``fix``) or constants. Residuals and Jacobians come from
:func:`~microlie.optim.sfm.camera.reproject`, the same code as :class:`BALProblem`'s residuals.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ...groups import SE3, SO3, LieGroup
from ...groups.product import VectorSpace
from ..core.factors import Factor
from ..core.noise import NoiseModel
from ..core.robust import RobustLoss
from ..core.variables import Variables
from .camera import BEHIND, CameraModel, Reprojection, camera_model, reproject

__all__ = ["ReprojectionFactor"]


def _is_vector(var: Variables, dim: int) -> bool:
    """A vector variable of dimension ``dim`` (an ``(n, d)`` array or ``R(d)``)."""
    return var.dof == dim and (var.group is None or issubclass(var.group, VectorSpace))


def _is_pair(x: Any) -> bool:
    return isinstance(x, tuple | list) and len(x) == 2 and isinstance(x[0], Variables)


def _array(v: Any) -> np.ndarray:
    """The ``(m, d)`` array of a vector value (an array, or an ``R(d)`` batch)."""
    return np.asarray(v.params if isinstance(v, LieGroup) else v)


class ReprojectionFactor(Factor):
    """Reprojection residuals ``r = project(R X + t, K) - observed`` of ``m`` observations.

    Parameters
    ----------
    pose : (Variables, indices) or ((Variables, indices), (Variables, indices))
        The world-to-camera pose of each observation: one ``SE3`` handle ``T_cw`` (right
        perturbation ``T Exp(rho, phi)``, tangent translation first), or an ``SO3`` handle and
        an ``R(3)`` handle (``R Exp(dphi)``, ``t + dt``: BAL's parametrisation).
    point : (Variables, indices)
        The world point of each observation: a 3-vector handle.
    observations : array_like
        ``(m, 2)`` observed pixels (``(2,)`` for one observation).
    model : {"bal", "pinhole", "pinhole-radtan"} or CameraModel
        The projection (:mod:`microlie.optim.sfm.camera`): ``"bal"`` ``(f, k1, k2)``,
        ``"pinhole"`` ``(fx, fy, cx, cy)``, ``"pinhole-radtan"`` ``(fx, fy, cx, cy, k1, k2,
        p1, p2)``.
    intrinsics : (Variables, indices) or array_like
        A ``k``-vector handle (``K + dK``; hold cameras' intrinsics with ``fix``) or constant
        intrinsics, ``(k,)`` for all observations or ``(m, k)``. Required.
    noise : NoiseModel, optional
        The pixel noise (default :class:`~microlie.optim.Unit`); one model or one per factor.
    loss : str or RobustLoss, optional
        A robust loss on the whitened residual (``"huber:1.0"``, ...).
    behind : {"evaluate", "drop"}
        Points behind the camera (see :mod:`microlie.optim.sfm.camera`): projected like any
        other (``"evaluate"``, the BAL convention) or given a zero residual and zero
        Jacobians (``"drop"``, as GTSAM's ``GeneralSFMFactor`` and COLMAP).
    camera_to_world : bool
        The pose variables are camera-to-world ``T_wc`` (``R_wc``, camera centre ``c``)
        instead of world-to-camera ``T_cw`` (module docstring): the pose a
        :class:`~microlie.optim.BetweenFactor` of odometry or a position prior refers to.

    Attributes
    ----------
    model : CameraModel
        The projection.
    observations : numpy.ndarray
        ``(m, 2)`` float64.
    intrinsics : numpy.ndarray or None
        ``(m, k)`` constant intrinsics, ``None`` when they are a variable.
    behind : str
        The option used.
    pose_form : {"SE3", "SO3xR3"}
        How the pose is parametrised.
    camera_to_world : bool
        The option used.

    Raises
    ------
    ValueError
        A handle of the wrong type or dimension, observations or intrinsics of the wrong shape
        or not finite, an unknown model or ``behind``.

    Examples
    --------
    Two BAL cameras (SO3 x R(3) poses, ``(f, k1, k2)`` intrinsics) seeing three points:

    >>> import numpy as np
    >>> from microlie import SO3
    >>> from microlie.optim import FactorGraph, ReprojectionFactor, check_jacobians
    >>> g = FactorGraph()
    >>> rot = g.add_variables(SO3.exp([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0]]))
    >>> trans = g.add_variables(np.array([[0.0, 0.0, -5.0], [-0.5, 0.0, -5.0]]))
    >>> K = g.add_variables(np.array([[500.0, 0.0, 0.0], [500.0, 0.0, 0.0]]))
    >>> X = g.add_variables(np.array([[0.1, 0.2, 0.0], [-0.3, 0.1, 0.5], [0.2, -0.2, 0.3]]))
    >>> cam, pt = np.repeat([0, 1], 3), np.tile([0, 1, 2], 2)
    >>> f = ReprojectionFactor(((rot, cam), (trans, cam)), (X, pt), np.zeros((6, 2)),
    ...                        intrinsics=(K, cam))
    >>> np.round(f.evaluate([rot.wrap(rot.initial[cam]), trans.initial[cam], X.initial[pt],
    ...                      K.initial[cam]], False)[0], 6).tolist()  # -f P_xy / P_z
    [10.0, 20.0]
    >>> check_jacobians(f).ok
    True
    """

    jacobians_with_residuals = False

    def __init__(self, pose: Any, point: tuple[Variables, Any], observations: Any, *,
                 model: str | CameraModel = "bal", intrinsics: Any = None,
                 noise: NoiseModel | None = None, loss: RobustLoss | str | None = None,
                 behind: str = "evaluate", camera_to_world: bool = False) -> None:
        what = type(self).__name__
        if not isinstance(camera_to_world, bool | np.bool_):
            raise ValueError(f"{what}: camera_to_world must be a bool, got {camera_to_world!r}")
        self.camera_to_world = bool(camera_to_world)
        self.model = camera_model(model)
        if behind not in BEHIND:
            raise ValueError(f"{what}: behind must be one of {BEHIND}, got {behind!r}")
        self.behind = behind
        k = self.model.n_intrinsics
        if _is_pair(pose):
            var = pose[0]
            if var.group is not SE3:
                raise ValueError(f"{what}: pose must be (SE3 handle, indices) or ((SO3 handle, "
                                 f"indices), (R(3) handle, indices)); got a {var!r} handle")
            args: list[tuple[Variables, Any]] = [tuple(pose)]  # type: ignore[list-item]
            self.pose_form = "SE3"
        elif isinstance(pose, tuple | list) and len(pose) == 2 and all(map(_is_pair, pose)):
            (rv, _), (tv, _) = pose
            if rv.group is not SO3 or not _is_vector(tv, 3):
                raise ValueError(f"{what}: a two-part pose must be ((SO3 handle, indices), "
                                 f"(R(3) handle, indices)); got {rv!r} and {tv!r}")
            args = [tuple(pose[0]), tuple(pose[1])]  # type: ignore[list-item]
            self.pose_form = "SO3xR3"
        else:
            raise ValueError(f"{what}: pose must be (SE3 handle, indices) or ((SO3 handle, "
                             f"indices), (R(3) handle, indices)), got {type(pose).__name__}")
        if not _is_pair(point) or not _is_vector(point[0], 3):
            raise ValueError(f"{what}: point must be (R(3) handle, indices) of 3-vector "
                             f"variables, got {point!r}")
        args.append(tuple(point))  # type: ignore[arg-type]
        const = None
        if intrinsics is None:
            raise ValueError(f"{what}: intrinsics are required ({self.model.name} model: "
                             f"{', '.join(self.model.intrinsic_names)}): a (handle, indices) "
                             f"pair of {k}-vector variables or a constant ({k},) / (m, {k}) "
                             f"array")
        if _is_pair(intrinsics):
            if not _is_vector(intrinsics[0], k):
                raise ValueError(f"{what}: intrinsics of the {self.model.name} model must be "
                                 f"R({k}) variables ({', '.join(self.model.intrinsic_names)}), "
                                 f"got {intrinsics[0]!r}")
            args.append(tuple(intrinsics))
        else:
            const = np.asarray(intrinsics)
            if not np.issubdtype(const.dtype, np.number) or const.shape[-1:] != (k,) \
                    or const.ndim not in (1, 2):
                raise ValueError(f"{what}: constant intrinsics of the {self.model.name} model "
                                 f"must be a ({k},) or (m, {k}) array "
                                 f"({', '.join(self.model.intrinsic_names)}), got "
                                 f"{const.dtype} of shape {const.shape}")
        super().__init__(args, 2, noise, loss)
        obs = np.asarray(observations)
        if obs.shape == (2,) and self.count == 1:
            obs = obs[None]
        if not np.issubdtype(obs.dtype, np.number) or obs.shape != (self.count, 2):
            raise ValueError(f"{what}: observations must be an ({self.count}, 2) array of "
                             f"pixels (one row per factor), got {obs.dtype} of shape "
                             f"{obs.shape}")
        # float32 / integer pixels are widened exactly; the graph works in float64
        self.observations = self.per_factor(obs.astype(np.float64), "observations")
        self.intrinsics = (None if const is None else
                           self.per_factor(np.atleast_2d(const).astype(np.float64),
                                           "intrinsics"))

    def _reproject(self, values: Sequence[Any], jac: bool
                   ) -> tuple[Reprojection, np.ndarray | None]:
        """The reprojection (camera Jacobian in ``T_cw``'s SO3 x R3 tangent) and, for
        ``camera_to_world``, the camera-frame points ``P``."""
        if self.pose_form == "SE3":
            p = np.asarray(values[0].params, dtype=np.float64)
            R = np.asarray(SO3.from_params(p[:, 3:], check=False).matrix())
            t = p[:, :3]
        else:
            R = np.asarray(values[0].matrix(), dtype=np.float64)
            t = _array(values[1])
        n = 1 if self.pose_form == "SE3" else 2
        X = _array(values[n])
        K = self.intrinsics if self.intrinsics is not None else _array(values[n + 1])
        P = None
        if self.camera_to_world:   # T_cw = (R^T, -R^T c); P = R^T (X - c)
            R = np.swapaxes(R, 1, 2)
            P = np.matmul(R, (X - t)[:, :, None])[:, :, 0]
            t = -np.matmul(R, t[:, :, None])[:, :, 0]
        rep = reproject(self.model, R, t, K, X, None, None, self.observations, jac=jac,
                        behind=self.behind)  # type: ignore[arg-type]
        return rep, P

    def _pose_jacobians(self, rep: Reprojection, P: np.ndarray | None
                        ) -> tuple[np.ndarray, np.ndarray]:
        """The two 3-column blocks of the pose tangent, in argument order: SE3 ``(rho, phi)``,
        SO3 x R3 ``(dphi, dt)`` (``dc`` for ``camera_to_world``)."""
        Jc, Jp = rep.J_cam, rep.J_point
        assert Jc is not None and Jp is not None
        A = Jc[:, :, 0:3]                      # d uv / d P (zero rows where dropped)
        if not self.camera_to_world:
            return (Jp, Jc[:, :, 3:6]) if self.pose_form == "SE3" else (Jc[:, :, 3:6], A)
        assert P is not None
        AP = np.cross(A, P[:, None, :])        # row i: A_i [P]_x = A_i x P
        return (-A, AP) if self.pose_form == "SE3" else (AP, -Jp)

    def residual(self, *values: Any, jac: bool = False) -> Any:
        """The residuals ``(m, 2)`` and, with ``jac``, the right Jacobians per argument
        (:meth:`Factor.residual`): pose (``SE3``: ``(m, 2, 6)``; or ``SO3`` ``(m, 2, 3)`` and
        translation ``(m, 2, 3)``), point ``(m, 2, 3)``, then intrinsics ``(m, 2, k)`` when
        they are a variable.

        Parameters
        ----------
        *values : LieGroup or numpy.ndarray
            One batch of ``m`` values per argument, in the order above.
        jac : bool
            Also return the Jacobians.

        Returns
        -------
        numpy.ndarray or tuple
            ``r``, or ``(r, [J_1, ..., J_K])``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3
        >>> from microlie.optim import FactorGraph, ReprojectionFactor
        >>> g = FactorGraph()
        >>> T = g.add_variables(SE3.identity(1))
        >>> X = g.add_variables(np.array([[0.2, 0.1, 2.0]]))
        >>> f = ReprojectionFactor((T, 0), (X, 0), [320.0, 240.0], model="pinhole",
        ...                        intrinsics=[500.0, 500.0, 320.0, 240.0])
        >>> r, (JT, JX) = f.residual(SE3.identity(1), X.initial, jac=True)
        >>> r.tolist(), JT.shape, JX.shape
        ([[50.0, 25.0]], (1, 2, 6), (1, 2, 3))
        """
        rep, P = self._reproject(values, jac)
        if not jac:
            return rep.residuals
        Jc, Jp = rep.J_cam, rep.J_point
        assert Jc is not None and Jp is not None
        a, b = self._pose_jacobians(rep, P)
        Js = [np.concatenate([a, b], axis=2)] if self.pose_form == "SE3" else [a, b]
        Js.append(Jp)
        if self.intrinsics is None:
            Js.append(Jc[:, :, 6:])
        return rep.residuals, Js

    def evaluate_into(self, values: Sequence[Any], out: np.ndarray) -> np.ndarray:
        """The residuals, with the Jacobians written side by side into ``out``
        (:meth:`Factor.evaluate_into`).

        Parameters
        ----------
        values : sequence
            One batch of ``m`` values per argument.
        out : numpy.ndarray
            ``(m, 2, D)``, ``D`` the sum of the arguments' dofs.

        Returns
        -------
        numpy.ndarray
            ``(m, 2)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3
        >>> from microlie.optim import FactorGraph, ReprojectionFactor
        >>> g = FactorGraph()
        >>> T = g.add_variables(SE3.identity(1))
        >>> X = g.add_variables(np.array([[0.2, 0.1, 2.0]]))
        >>> f = ReprojectionFactor((T, 0), (X, 0), [320.0, 240.0], model="pinhole",
        ...                        intrinsics=[500.0, 500.0, 320.0, 240.0])
        >>> J = np.empty((1, 2, 9))
        >>> r = f.evaluate_into([SE3.identity(1), X.initial], J)
        >>> r.tolist(), J[0, :, 6:].tolist()  # d r / d X = A R = A
        ([[50.0, 25.0]], [[250.0, 0.0, -25.0], [0.0, 250.0, -12.5]])
        """
        rep, P = self._reproject(values, True)
        Jc, Jp = rep.J_cam, rep.J_point
        assert Jc is not None and Jp is not None
        out[:, :, 0:3], out[:, :, 3:6] = self._pose_jacobians(rep, P)
        out[:, :, 6:9] = Jp
        if self.intrinsics is None:
            out[:, :, 9:] = Jc[:, :, 6:]
        return rep.residuals
