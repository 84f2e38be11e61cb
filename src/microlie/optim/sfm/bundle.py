"""Bundle adjustment: Levenberg-Marquardt with Ceres' trust-region rules on the Schur system.

Unknowns: per camera a world-to-camera rotation ``R`` (perturbed ``R Exp(dphi)``), a translation
``t`` (``t + dt``) and intrinsics ``K`` (``K + dK``), tangent ``(dt, dphi, dK)``; per point a
3-vector. Cost ``0.5 * sum rho(|r|^2)`` in pixels (``rho(s) = s`` without a robust loss).

The iteration follows Ceres' ``TrustRegionMinimizer`` with ``LevenbergMarquardtStrategy`` so
that iteration counts compare with Ceres': Jacobi scaling of the columns by
``s = 1 / (1 + |J_col|)`` fixed at iteration 0 (applied exactly, as the equivalent damping
``D^2 / s^2`` of the unscaled system, so the Jacobians are never rescaled); damping
``D^2 = clamp(diag(J^T J), 1e-6, 1e32) / radius`` of the scaled Jacobian (radius starts at
1e4, diagonal reused after a rejected step); step quality
``rho = actual / model cost decrease``; accepted when ``rho > 1e-3``, then
``radius /= max(1/3, 1 - (2 rho - 1)^3)``; rejected: ``radius /= 2, 4, 8, ...``. Stops on
``|cost change| <= 1e-6 cost`` (the step is then not taken, as in Ceres), a step shorter than
``1e-8 (|x| + 1e-8)``, a gradient max-norm below ``1e-10``, ``radius < 1e-32``, or
``max_iter`` tries (accepted plus rejected, Ceres' ``iterations``).

The stops are Ceres', their meaning stricter (``BundleResult.termination``, as
:class:`~microlie.optim.core.solvers.Result`'s): ``"convergence"`` for the gradient test, and for
the function and parameter tests and the radius floor when the candidate decreased the cost,
was the first try from the current point, or the first try's model predicted a decrease
within ``function_tolerance``; otherwise ``"failure"`` (the steps of a shrinking radius change
the cost little only because they are short: Ceres reports CONVERGENCE there). ``max_iter``
is ``"no_convergence"``.

The gauge (7 degrees of freedom for BAL: rotation, translation, scale) is left free by default
(the damping keeps the system definite, as in Ceres); ``fix_cameras=[0]`` holds camera 0 (and
with it 6 of the 7), ``fix_points`` holds points.

>>> import numpy as np
>>> from microlie.optim.sfm.bundle import bundle_adjust, synthetic_scene
>>> truth, start = synthetic_scene(n_cameras=3, n_points=40, noise=0.0, seed=1)
>>> result = bundle_adjust(start, fix_cameras=[0])
>>> result.converged, result.final_cost < 1e-12
(True, True)
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..._files import save_figure
from ..core.threads import with_blas_threads
from ..io.bal import BALProblem
from ..linalg.schur import LinearSolverKind, NormalEquations, SchurStructure
from .camera import BALCamera, CameraModel, camera_model, reproject

__all__ = ["BundleProblem", "BundleResult", "BundleIteration", "BundleGraph", "bundle_adjust",
           "bundle_graph", "synthetic_scene", "plot_bundle", "rotvec_to_matrix",
           "matrix_to_rotvec"]


def rotvec_to_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrices of angle-axis vectors (``SO3.exp``).

    Parameters
    ----------
    w : numpy.ndarray
        ``(n, 3)``.

    Returns
    -------
    numpy.ndarray
        ``(n, 3, 3)``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.sfm.bundle import matrix_to_rotvec, rotvec_to_matrix
    >>> w = np.array([[0.1, 0.2, 0.3]])
    >>> bool(np.allclose(matrix_to_rotvec(rotvec_to_matrix(w)), w))
    True
    """
    from ...groups import SO3

    return np.asarray(SO3.exp(np.asarray(w, dtype=float)).matrix())


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Angle-axis vectors of rotation matrices (``SO3.log``).

    Parameters
    ----------
    R : numpy.ndarray
        ``(n, 3, 3)``.

    Returns
    -------
    numpy.ndarray
        ``(n, 3)``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.sfm.bundle import matrix_to_rotvec
    >>> Rz = np.array([[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]])
    >>> bool(np.allclose(matrix_to_rotvec(Rz), [[0, 0, np.pi / 2]]))
    True
    """
    from ...groups import SO3

    return np.asarray(SO3.from_matrix(np.asarray(R), normalize=True).log())


@dataclass(frozen=True)
class BundleProblem:
    """Cameras ``(R, t, K)`` (world to camera: ``P = R X + t``), points ``X`` and observations.
    Arrays are stored as float64 (and intp indices), whatever the input dtype.

    Parameters
    ----------
    rotations : numpy.ndarray
        ``(n_cameras, 3, 3)`` world-to-camera rotations.
    translations : numpy.ndarray
        ``(n_cameras, 3)``.
    intrinsics : numpy.ndarray
        ``(n_cameras, k)`` in the order of ``model``.
    points : numpy.ndarray
        ``(n_points, 3)`` world points.
    camera_index, point_index : numpy.ndarray
        ``(n_observations,)``.
    observations : numpy.ndarray
        ``(n_observations, 2)`` pixels.
    model : CameraModel
        Projects camera-frame points (default :class:`BALCamera`).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
    >>> cams = np.zeros((2, 9))
    >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
    >>> pts = np.random.default_rng(0).normal(size=(6, 3))
    >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
    >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
    >>> bal = BALProblem(cams, pts, ci, pi, uv)
    >>> problem = BundleProblem.from_bal(bal)
    >>> problem.rotations.shape, problem.intrinsics.shape
    ((2, 3, 3), (2, 3))
    """

    rotations: np.ndarray
    translations: np.ndarray
    intrinsics: np.ndarray
    points: np.ndarray
    camera_index: np.ndarray
    point_index: np.ndarray
    observations: np.ndarray
    model: CameraModel = field(default_factory=BALCamera)

    def __repr__(self) -> str:
        return (f"BundleProblem({self.n_cameras} cameras, {self.n_points} points, "
                f"{len(self.observations)} observations, {type(self.model).__name__})")

    def __post_init__(self) -> None:
        # the solver works in float64 (costs of 1e6 px^2 and 1e-9 steps do not fit float32)
        for name in ("rotations", "translations", "intrinsics", "points", "observations"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        for name in ("camera_index", "point_index"):
            a = np.asarray(getattr(self, name))
            if a.size and not np.issubdtype(a.dtype, np.integer):
                raise ValueError(f"{name} must hold integers, got {a.dtype}")
            object.__setattr__(self, name, a.astype(np.intp))
        nc = self.rotations.shape[0] if np.ndim(self.rotations) == 3 else -1
        if np.shape(self.rotations) != (nc, 3, 3):
            raise ValueError(f"rotations must be (n_cameras, 3, 3), got {np.shape(self.rotations)}")
        if np.shape(self.translations) != (nc, 3):
            raise ValueError(f"translations must be ({nc}, 3), got {np.shape(self.translations)}")
        self.model.check_intrinsics(self.intrinsics, nc)
        if np.ndim(self.points) != 2 or np.shape(self.points)[1] != 3:
            raise ValueError(f"points must be (n_points, 3), got {np.shape(self.points)}")
        no = len(self.camera_index)
        if np.shape(self.point_index) != (no,) or np.shape(self.observations) != (no, 2):
            raise ValueError("camera_index, point_index and observations (n, 2) must agree in "
                             "length")
        for arr, lim, what in ((self.camera_index, nc, "camera"),
                               (self.point_index, len(self.points), "point")):
            if no and (np.min(arr) < 0 or np.max(arr) >= lim):
                raise ValueError(f"an observation refers to a missing {what} (index out of "
                                 f"range 0..{lim - 1})")
        for a, what in ((self.rotations, "rotations"), (self.translations, "translations"),
                        (self.points, "points"), (self.observations, "observations")):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{what} contain non-finite values")
        err = np.abs(np.swapaxes(self.rotations, 1, 2) @ self.rotations - np.eye(3)).max(
            initial=0.0)
        if err > 1e-6 or (nc and np.min(np.linalg.det(self.rotations)) < 0):
            raise ValueError(f"rotations must be rotation matrices (|R^T R - I| = {err:.2e})")

    @classmethod
    def from_bal(cls, bal: BALProblem) -> BundleProblem:
        """The problem of a BAL file (rotation vectors to matrices, the BAL camera model).

        Parameters
        ----------
        bal : BALProblem
            The file's problem.

        Returns
        -------
        BundleProblem

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> problem = BundleProblem.from_bal(bal)
        >>> problem.cost()
        0.0
        """
        c = bal.cameras
        return cls(rotvec_to_matrix(c[:, :3]), c[:, 3:6].copy(), c[:, 6:9].copy(),
                   bal.points.copy(), bal.camera_index, bal.point_index, bal.observations,
                   BALCamera())

    def to_bal(self) -> BALProblem:
        """Back to BAL storage (needs the BAL camera model).

        Returns
        -------
        BALProblem

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> problem = BundleProblem.from_bal(bal)
        >>> bool(np.allclose(problem.to_bal().cameras, cams))
        True
        """
        if not isinstance(self.model, BALCamera):
            raise ValueError("only problems with the BAL camera model can be written as BAL")
        cams = np.concatenate([matrix_to_rotvec(self.rotations), self.translations,
                               self.intrinsics], axis=1)
        return BALProblem(cams, self.points.copy(), self.camera_index, self.point_index,
                          self.observations)

    @property
    def n_cameras(self) -> int:
        return int(self.rotations.shape[0])

    @property
    def n_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def cam_dim(self) -> int:
        return 6 + self.model.n_intrinsics

    def poses(self) -> Any:
        """The cameras as a batch of world-to-camera ``SE3`` elements ``(R, t)``.

        Returns
        -------
        SE3
            Batch ``(n_cameras,)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> problem = BundleProblem.from_bal(bal)
        >>> problem.poses().batch_shape
        (2,)
        """
        from ...groups import SE3, SO3

        q = np.asarray(SO3.from_matrix(self.rotations, normalize=True).params)
        return SE3(np.concatenate([self.translations, q], axis=1))

    def residuals(self, behind: str = "evaluate") -> np.ndarray:
        """Reprojection residuals (predicted minus observed).

        Parameters
        ----------
        behind : {"evaluate", "drop"}
            Points behind a camera: evaluated (BAL convention) or dropped (GTSAM/COLMAP), see
            :mod:`microlie.optim.sfm.camera`.

        Returns
        -------
        numpy.ndarray
            ``(n_observations, 2)``, pixels.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> problem = BundleProblem.from_bal(bal)
        >>> problem.residuals().shape
        (12, 2)
        """
        return reproject(self.model, self.rotations, self.translations, self.intrinsics,
                         self.points, self.camera_index, self.point_index, self.observations,
                         jac=False, behind=behind).residuals  # type: ignore[arg-type]

    def cost(self, behind: str = "evaluate") -> float:
        """``0.5 * sum |r|^2`` in pixels (no robust loss).

        Parameters
        ----------
        behind : {"evaluate", "drop"}
            Points behind a camera: evaluated (BAL convention) or dropped (GTSAM/COLMAP), see
            :mod:`microlie.optim.sfm.camera`.

        Returns
        -------
        float

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> problem = BundleProblem.from_bal(bal)
        >>> problem.cost()
        0.0
        """
        r = self.residuals(behind)
        return 0.5 * float(np.sum(r * r))

    def retract(self, dc: np.ndarray, dp: np.ndarray) -> BundleProblem:
        """The problem at ``R Exp(dphi)``, ``t + dt``, ``K + dK``, ``X + dX``.

        Parameters
        ----------
        dc : numpy.ndarray
            ``(n_cameras, 6 + k)`` camera steps ``(dt, dphi, dK)``.
        dp : numpy.ndarray
            ``(n_points, 3)`` point steps.

        Returns
        -------
        BundleProblem

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> problem = BundleProblem.from_bal(bal)
        >>> moved = problem.retract(np.zeros((2, 9)), np.ones((6, 3)))
        >>> np.round(moved.points - problem.points, 12)[0].tolist()
        [1.0, 1.0, 1.0]
        """
        from ...groups import SO3

        dR = np.asarray(SO3.exp(dc[:, 3:6]).matrix())
        return replace(self, rotations=self.rotations @ dR,
                       translations=self.translations + dc[:, 0:3],
                       intrinsics=self.intrinsics + dc[:, 6:], points=self.points + dp)


@dataclass(frozen=True)
class BundleIteration:
    """One try of :func:`bundle_adjust`.

    Attributes
    ----------
    iteration : int
        Its number.
    cost : float
        The cost after it (the candidate's for a rejected try).
    accepted : bool
        Whether the step was taken.
    rho : float
        The step quality (actual over predicted decrease).
    radius : float
        The trust radius used.
    step_norm : float
        The step norm.

    Examples
    --------
    >>> from microlie.optim.sfm.bundle import bundle_adjust, synthetic_scene
    >>> truth, start = synthetic_scene(3, 20, seed=1)
    >>> rec = bundle_adjust(start, fix_cameras=[0]).history[0]
    >>> rec.iteration, isinstance(rec.accepted, bool)
    (1, True)
    """

    iteration: int
    cost: float
    accepted: bool
    rho: float
    radius: float
    step_norm: float


@dataclass
class BundleResult:
    """Outcome of :func:`bundle_adjust`, with the fields of
    :class:`microlie.optim.core.solvers.Result`.

    Attributes
    ----------
    problem : BundleProblem
        The optimised problem.
    initial_cost, final_cost : float
        ``0.5 sum |r|^2`` in pixels without the robust loss.
    initial_robust_cost, final_robust_cost : float
        The minimised ``0.5 sum rho(|r|^2)`` (equal without a loss).
    iterations : int
        Tries, accepted or not, the stopping one included.
    successful_steps : int
        Ceres' count: accepted steps plus iteration 0.
    converged : bool
        ``termination == "convergence"``, with the reason in ``message``.
    message : str
    termination : {"convergence", "no_convergence", "failure"}
        See :class:`microlie.optim.core.solvers.Result` and the module docstring.
    time_s : float
        Wall time, seconds; ``timings`` its breakdown.
    history : list of BundleIteration
        One per try.
    timings : dict
    behind, solver, linear_solver : str
        The options used.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
    >>> cams = np.zeros((2, 9))
    >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
    >>> pts = np.random.default_rng(0).normal(size=(6, 3))
    >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
    >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
    >>> bal = BALProblem(cams, pts, ci, pi, uv)
    >>> problem = BundleProblem.from_bal(bal)
    >>> d = 0.01 * np.sin(np.arange(18.0)).reshape(6, 3)
    >>> d[0] = 0.0  # point 0 is held at its true value
    >>> noisy = BALProblem(cams, pts + d, ci, pi, uv)
    >>> res = bundle_adjust(noisy, fix_cameras=[0], fix_points=[0], fix_intrinsics=True)
    >>> res.converged, res.final_cost < 1e-6 * res.initial_cost
    (True, True)
    """

    problem: BundleProblem
    initial_cost: float
    final_cost: float
    initial_robust_cost: float
    final_robust_cost: float
    iterations: int
    successful_steps: int
    converged: bool
    message: str
    termination: str
    time_s: float
    history: list[BundleIteration]
    timings: dict[str, float]
    behind: str = "evaluate"
    solver: str = "lm"
    linear_solver: str = "auto"
    _normal: Any = field(default=None, repr=False)

    def __repr__(self) -> str:
        p = self.problem
        return (f"BundleResult({self.solver}, {self.linear_solver}: cost {self.initial_cost:.10g}"
                f" -> {self.final_cost:.10g} in {self.iterations} iterations "
                f"({self.successful_steps} successful), {p.n_cameras} cameras, {p.n_points} "
                f"points, {len(p.observations)} observations, {self.time_s * 1e3:.1f} ms, "
                f"converged={self.converged}: {self.message})")

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready summary (costs, iterations, time, convergence).

        Returns
        -------
        dict

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> problem = BundleProblem.from_bal(bal)
        >>> d = 0.01 * np.sin(np.arange(18.0)).reshape(6, 3)
        >>> d[0] = 0.0  # point 0 is held at its true value
        >>> noisy = BALProblem(cams, pts + d, ci, pi, uv)
        >>> res = bundle_adjust(noisy, fix_cameras=[0], fix_points=[0], fix_intrinsics=True)
        >>> sorted(res.to_dict())[:3]
        ['converged', 'final_cost', 'final_robust_cost']
        """
        return {"initial_cost": self.initial_cost, "final_cost": self.final_cost,
                "initial_robust_cost": self.initial_robust_cost,
                "final_robust_cost": self.final_robust_cost, "iterations": self.iterations,
                "time_s": self.time_s, "converged": self.converged, "message": self.message,
                "termination": self.termination, "successful_steps": self.successful_steps}

    @with_blas_threads
    def camera_covariance(self, cameras: Sequence[int], *,
                          blas_threads: int | None = 1) -> np.ndarray:
        """Marginal covariances of the camera tangents ``(dt, dphi, dK)`` at the solution, from the
        reduced camera system: the camera block of ``(J^T J)^-1`` is ``S^-1`` (``S`` the Schur
        complement of the points). With a free gauge ``S`` is singular: the pseudo-inverse
        (minimum-norm gauge) is returned for a dense ``S``; a sparse one (many cameras) needs the
        gauge held (``fix_cameras`` and a point). Held unknowns have zero covariance. A free
        unknown without any information (a camera with no observations) is unobservable, its
        variance infinite: asking for its camera raises ``LinAlgError``; other cameras are
        independent of it.

        Parameters
        ----------
        cameras : sequence of int
            The cameras.
        blas_threads : int or None
            BLAS threads while factorising and solving (default 1, as :func:`bundle_adjust`;
            ``None`` keeps the process's setting).

        Returns
        -------
        numpy.ndarray
            ``(len(cameras), d, d)``.

        Raises
        ------
        numpy.linalg.LinAlgError
            A requested camera has free unknowns without information (a ``ValueError``).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> problem = BundleProblem.from_bal(bal)
        >>> d = 0.01 * np.sin(np.arange(18.0)).reshape(6, 3)
        >>> d[0] = 0.0  # point 0 is held at its true value
        >>> noisy = BALProblem(cams, pts + d, ci, pi, uv)
        >>> res = bundle_adjust(noisy, fix_cameras=[0], fix_points=[0], fix_intrinsics=True)
        >>> res.camera_covariance([1]).shape
        (1, 9, 9)
        """
        d = self.problem.cam_dim
        idx = np.concatenate([np.arange(c * d, (c + 1) * d) for c in cameras])
        S = _undamped_schur(self)
        n = S.shape[0]
        keep = np.ones(n, bool)
        if self._normal is not None and self._normal.fixed_cameras is not None:
            keep = ~self._normal.fixed_cameras.reshape(-1)
        # free unknowns without information: their rows of S are zero (no observation reaches
        # them), their variance is infinite, never the pseudo-inverse's zero
        empty = keep & ~(np.asarray(S.diagonal()).ravel() > 0)
        asked = idx[empty[idx]]
        if asked.size:
            bad = sorted({int(i) // d for i in asked})
            nobs = np.bincount(self.problem.camera_index, minlength=self.problem.n_cameras)
            raise np.linalg.LinAlgError(
                f"camera(s) {bad} are not observable ({', '.join(str(int(nobs[c])) for c in bad)}"
                f" observations; unknowns {sorted(int(i) % d for i in asked)} of {d} without "
                f"information): their covariance is infinite; hold them (fix_cameras, "
                f"fix_intrinsics) or remove them")
        if empty.any():  # decoupled from the rest: held like fixed unknowns (unit rows)
            keep = keep & ~empty
            unit = empty.astype(float)
            S = S + (_sp_diags(unit) if _issparse(S) else np.diag(unit))
        cov = np.zeros((len(idx), len(idx)))
        sel = keep[idx]
        if _issparse(S):
            from ..linalg.linear import SingularSystemError, make_solver

            solver = make_solver("auto", n)
            E = np.zeros((n, int(sel.sum())))
            E[idx[sel], np.arange(E.shape[1])] = 1.0
            try:
                solver.analyse(S.indptr, S.indices, n)
                solver.factorize(S.data)
                X = np.column_stack([solver.solve(E[:, k]) for k in range(E.shape[1])])
            except SingularSystemError:
                raise np.linalg.LinAlgError(
                    "the reduced camera system is singular: hold the gauge (fix_cameras=[0] "
                    "and fix_points=[k]) to get marginal covariances") from None
            cov[np.ix_(sel, sel)] = X[idx[sel]]
        else:
            Sk = S[np.ix_(keep, keep)]
            pos = -np.ones(n, int)
            pos[keep] = np.arange(keep.sum())
            try:
                cf = np.linalg.cholesky(Sk)
                inv = np.linalg.inv(cf)
                cov_k = inv.T @ inv
            except np.linalg.LinAlgError:
                cov_k = np.linalg.pinv(Sk, hermitian=True)
            cov[np.ix_(sel, sel)] = cov_k[np.ix_(pos[idx][sel], pos[idx][sel])]
        cov = 0.5 * (cov + cov.T)
        return np.stack([cov[i * d:(i + 1) * d, i * d:(i + 1) * d] for i in range(len(cameras))])

    def marginals(self, cameras: Sequence[int]) -> list[Any]:
        """Marginal Gaussians of the chosen camera poses as world-to-camera ``SE3`` elements,
        ``frame="right"``: ``T = Tbar Exp(rho, phi)``. The solver's translation step ``dt`` is
        in the camera frame, so ``rho = R^T dt`` (first order) and the SE(3) covariance is
        ``blockdiag(R^T, I) P blockdiag(R, I)`` of the pose block ``P`` of
        :meth:`camera_covariance` (intrinsics are marginalised out).

        Parameters
        ----------
        cameras : sequence of int
            The cameras.

        Returns
        -------
        list of Gaussian
            One per camera.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
        >>> cams = np.zeros((2, 9))
        >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
        >>> pts = np.random.default_rng(0).normal(size=(6, 3))
        >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
        >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
        >>> bal = BALProblem(cams, pts, ci, pi, uv)
        >>> problem = BundleProblem.from_bal(bal)
        >>> d = 0.01 * np.sin(np.arange(18.0)).reshape(6, 3)
        >>> d[0] = 0.0  # point 0 is held at its true value
        >>> noisy = BALProblem(cams, pts + d, ci, pi, uv)
        >>> res = bundle_adjust(noisy, fix_cameras=[0], fix_points=[0], fix_intrinsics=True)
        >>> g = res.marginals([1])[0]
        >>> g.frame, g.cov.shape
        ('right', (6, 6))
        """
        from ...uncertainty import Gaussian

        covs = self.camera_covariance(cameras)
        poses = self.problem.poses()
        out = []
        for c, P in zip(cameras, covs, strict=True):
            Rt = self.problem.rotations[c].T
            T = np.zeros((6, 6))
            T[:3, :3] = Rt
            T[3:, 3:] = np.eye(3)
            Pse3 = T @ P[:6, :6] @ T.T
            out.append(Gaussian(poses[c], 0.5 * (Pse3 + Pse3.T), frame="right"))
        return out


def _sp_diags(v: np.ndarray) -> Any:
    """A sparse CSC diagonal matrix."""
    import scipy.sparse

    return scipy.sparse.diags(v, format="csc")


def _issparse(S: Any) -> bool:
    """A SciPy sparse matrix (the sparse reduced camera system), not a dense array."""
    import scipy.sparse

    return bool(scipy.sparse.issparse(S))


def _undamped_schur(res: BundleResult) -> Any:
    ne = res._normal
    if ne is None:
        raise ValueError("no linearisation stored in this result")
    st = ne.structure
    Dc2 = np.zeros((st.n_cameras, st.cam_dim))
    Dp2 = np.zeros((st.n_points, 3))
    red = ne.reduced_system(Dc2, Dp2, st.sparse_reduced("auto"))
    if red is None:
        raise np.linalg.LinAlgError("a point block is singular: some point is not determined")
    return red[0]


def _as_mask(idx: Sequence[int] | np.ndarray | None, n: int, what: str) -> np.ndarray | None:
    if idx is None:
        return None
    a = np.asarray(idx)
    if a.dtype == bool:
        if a.shape != (n,):
            raise ValueError(f"{what} mask must have shape ({n},)")
        return a.copy()
    a = a.astype(np.intp).ravel()
    if len(a) and (a.min() < 0 or a.max() >= n):
        raise ValueError(f"{what} index out of range 0..{n - 1}")
    m = np.zeros(n, bool)
    m[a] = True
    return m if m.any() else None


def _camera_mask(pose: np.ndarray | None, intr: np.ndarray | None, n: int, d: int
                 ) -> np.ndarray | None:
    if pose is None and intr is None:
        return None
    m = np.zeros((n, d), bool)
    if pose is not None:
        m[pose, :6] = True
    if intr is not None:
        m[intr, 6:] = True
    return m


@with_blas_threads
def bundle_adjust(problem: BundleProblem | BALProblem, *, robust: Any = None,
                  behind: str = "evaluate", fix_cameras: Sequence[int] | None = None,
                  fix_points: Sequence[int] | None = None,
                  fix_intrinsics: Sequence[int] | bool | None = None,
                  linear_solver: LinearSolverKind = "auto", max_iter: int = 100,
                  function_tolerance: float = 1e-6, gradient_tolerance: float = 1e-10,
                  parameter_tolerance: float = 1e-8, initial_radius: float = 1e4,
                  jacobi_scaling: bool = True, verbose: bool = False,
                  blas_threads: int | None = 1) -> BundleResult:
    """Levenberg-Marquardt bundle adjustment (Ceres' rules, module docstring).

    Parameters
    ----------
    problem : BundleProblem or BALProblem
        The starting point.
    robust : str or RobustLoss, optional
        A loss of :mod:`microlie.optim.core.robust` or a spec such as ``"huber:1.0"`` (scale in
        pixels) applied to each observation's squared residual norm.
    behind : {"evaluate", "drop"}
        Points behind a camera: evaluated (BAL convention) or dropped (GTSAM/COLMAP), see
        :mod:`microlie.optim.sfm.camera`.
    fix_cameras : sequence of int, optional
        Cameras whose *pose* is held (the gauge: one camera holds 6 of BAL's 7 degrees of
        freedom; the scale stays free and the damping handles it).
    fix_points : sequence of int, optional
        Held points.
    fix_intrinsics : sequence of int or bool, optional
        Cameras whose intrinsics are held (``True``: all).
    linear_solver : str
        The reduced camera system's solver (``"auto"``, ...; module docstring).
    max_iter : int
        Iteration limit.
    function_tolerance, gradient_tolerance, parameter_tolerance : float
        Ceres' convergence tests.
    initial_radius : float
        The initial trust radius (``1 / lambda``).
    jacobi_scaling : bool
        Scale the columns as Ceres does.
    verbose : bool
        One line per iteration on stderr.
    blas_threads : int or None
        BLAS threads during the call (default 1, as Ceres' default;
        :mod:`microlie.optim.core.threads`);
        ``None`` keeps the user's setting or the library's default. Restored on return.

    Returns
    -------
    BundleResult

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
    >>> cams = np.zeros((2, 9))
    >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
    >>> pts = np.random.default_rng(0).normal(size=(6, 3))
    >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
    >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
    >>> bal = BALProblem(cams, pts, ci, pi, uv)
    >>> problem = BundleProblem.from_bal(bal)
    >>> d = 0.01 * np.sin(np.arange(18.0)).reshape(6, 3)
    >>> d[0] = 0.0  # point 0 is held at its true value
    >>> noisy = BALProblem(cams, pts + d, ci, pi, uv)
    >>> res = bundle_adjust(noisy, fix_cameras=[0], fix_points=[0], fix_intrinsics=True)
    >>> res.converged, res.initial_cost > 1.0, res.final_cost < 1e-6 * res.initial_cost
    (True, True, True)
    """
    t_start = time.perf_counter()
    if isinstance(problem, BALProblem):
        problem = BundleProblem.from_bal(problem)
    loss = None
    if robust is not None:
        from ..core.robust import make_loss

        loss = make_loss(robust)
    if max_iter < 0:
        raise ValueError("max_iter must be >= 0")
    if initial_radius <= 0:
        raise ValueError("initial_radius must be positive")
    model = problem.model
    nc, npt, d = problem.n_cameras, problem.n_points, problem.cam_dim
    intr: Sequence[int] | np.ndarray | None
    if fix_intrinsics is True:
        intr = np.arange(nc)
    elif fix_intrinsics is False:
        intr = None
    else:
        intr = fix_intrinsics
    fc = _camera_mask(_as_mask(fix_cameras, nc, "fix_cameras"),
                      _as_mask(intr, nc, "fix_intrinsics"), nc, d)
    fp = _as_mask(fix_points, npt, "fix_points")
    # observations sorted by camera (then point), once
    order = np.lexsort((problem.point_index, problem.camera_index))
    cam = np.asarray(problem.camera_index)[order].astype(np.intp)
    pt = np.asarray(problem.point_index)[order].astype(np.intp)
    obs = np.asarray(problem.observations, dtype=float)[order]
    tm: dict[str, Any] = {"structure": 0.0, "evaluate": 0.0, "linearize": 0.0,
                          "schur_form": 0.0, "reduced_solve": 0.0, "back_substitution": 0.0,
                          "step": 0.0}
    t0 = time.perf_counter()
    structure = SchurStructure(cam, pt, nc, npt, d)
    tm["structure"] += time.perf_counter() - t0

    def evaluate(p: BundleProblem) -> float:
        t = time.perf_counter()
        r = reproject(model, p.rotations, p.translations, p.intrinsics, p.points, cam, pt, obs,
                      jac=False, behind=behind).residuals  # type: ignore[arg-type]
        s = (r * r).sum(1)
        c = 0.5 * float(loss.rho(s).sum() if loss is not None else s.sum())
        tm["evaluate"] += time.perf_counter() - t
        return c

    scale_c: np.ndarray | None = None
    scale_p: np.ndarray | None = None

    def linearize(p: BundleProblem) -> tuple[float, NormalEquations, float, np.ndarray]:
        nonlocal scale_c, scale_p
        t = time.perf_counter()
        rp = reproject(model, p.rotations, p.translations, p.intrinsics, p.points, cam, pt, obs,
                       behind=behind)  # type: ignore[arg-type]
        r, Jc, Jp = rp.residuals, rp.J_cam, rp.J_point
        assert Jc is not None and Jp is not None
        s = (r * r).sum(1)
        if loss is not None:
            from ..core.robust import corrected_weights

            rho, rscale, aos = corrected_weights(loss, s)
            cost = 0.5 * float(rho.sum())
            w = np.sqrt(np.maximum(loss.evaluate(s)[1], 0.0))
            if np.any(aos != 0):
                # J <- sqrt(rho') (I - aos r r^T) J, with the unscaled residual
                rJc = np.einsum("nr,nrk->nk", r, Jc)
                rJp = np.einsum("nr,nrk->nk", r, Jp)
                Jc = Jc - (aos[:, None, None] * r[:, :, None]) * rJc[:, None, :]
                Jp = Jp - (aos[:, None, None] * r[:, :, None]) * rJp[:, None, :]
            Jc = Jc * w[:, None, None]
            Jp = Jp * w[:, None, None]
            r = r * rscale[:, None]
        else:
            cost = 0.5 * float(s.sum())
        ne = NormalEquations(structure, r, Jc, Jp, fc, fp, tm)
        if scale_c is None:
            # Ceres' Jacobi scaling 1 / (1 + |J_col|), fixed at iteration 0. Solving the scaled
            # system (S J^T J S + D_s) y = -S g, delta = S y, is solving
            # (J^T J + S^-1 D_s S^-1) delta = -g: the scaling only changes the damping.
            if jacobi_scaling:
                scale_c = 1.0 / (1.0 + np.sqrt(ne.diag_c))
                scale_p = 1.0 / (1.0 + np.sqrt(ne.diag_p))
            else:
                scale_c, scale_p = np.ones((nc, d)), np.ones((npt, 3))
        g = ne.gradient
        gmask = np.ones(len(g), bool)
        if fc is not None:
            gmask[: nc * d] &= ~fc.reshape(-1)
        if fp is not None:
            gmask[nc * d:].reshape(npt, 3)[fp] = False
        gmax = float(np.max(np.abs(g[gmask]))) if gmask.any() else 0.0
        tm["linearize"] += time.perf_counter() - t
        return cost, ne, gmax, r

    def xnorm(p: BundleProblem) -> float:
        return float(np.sqrt(np.sum(p.translations ** 2) + np.sum(p.intrinsics ** 2)
                             + np.sum(p.points ** 2) + np.sum(matrix_to_rotvec(p.rotations) ** 2)))

    x = problem
    cost, ne, gmax, r = linearize(x)
    if not np.isfinite(cost):
        bad = np.nonzero(~np.isfinite(r).all(axis=1))[0]
        k = int(order[bad[0]]) if len(bad) else -1
        raise ValueError(f"the initial residual of observation {k} is not finite (camera "
                         f"{cam[bad[0]]}, point {pt[bad[0]]}: a point on the plane of its "
                         f"camera, P_z = 0, or non-finite intrinsics); use behind='drop' or "
                         f"move it")
    initial_cost = cost
    radius, decrease = float(initial_radius), 2.0
    diag_c = diag_p = None
    reuse = False
    history: list[BundleIteration] = []
    it, successful = 0, 1                      # Ceres counts iteration 0 as successful
    termination, message = "no_convergence", "maximum number of iterations reached"
    first_pred: float | None = None            # the model decrease of the first try from x
    tries = 0                                  # tries from x

    def settled(cand_cost: float) -> bool:
        """Whether a stop at a candidate that changes the cost little is a convergence."""
        return (cand_cost < cost or tries <= 1
                or (first_pred is not None and first_pred <= function_tolerance * cost))
    x_norm = -1.0                              # as Ceres: no parameter test before a step
    t_it = time.perf_counter()
    if verbose:   # Ceres' progress columns
        print("iter      cost      cost_change  |gradient|   |step|    tr_ratio  tr_radius  "
              "iter_time", file=sys.stderr, flush=True)
        print(f"{0:4d} {cost:13.6e} {0.0:12.2e} {gmax:10.2e} {0.0:9.2e} {0.0:10.2e} "
              f"{radius:10.2e} {t_it - t_start:9.2e}", file=sys.stderr, flush=True)
    while True:
        if gmax <= gradient_tolerance:
            termination, message = "convergence", f"gradient tolerance reached ({gmax:.3e})"
            break
        if radius <= 1e-32:
            termination = "convergence" if settled(np.inf) else "failure"
            message = "minimum trust region radius reached" + (
                "" if termination == "convergence" else
                f" without decreasing the cost (the first step's model predicted a decrease "
                f"of {first_pred:.3g})")
            break
        if it >= max_iter:
            break
        it += 1
        tries += 1
        ts = time.perf_counter()
        if not reuse or diag_c is None:
            # LM diagonal of the scaled Jacobian, clamped as Ceres does, in unscaled units
            assert scale_c is not None and scale_p is not None
            diag_c = np.clip(ne.diag_c * scale_c ** 2, 1e-6, 1e32) / scale_c ** 2
            diag_p = np.clip(ne.diag_p * scale_p ** 2, 1e-6, 1e32) / scale_p ** 2
        assert diag_p is not None
        tm["step"] += time.perf_counter() - ts
        step = ne.solve(diag_c / radius, diag_p / radius, linear_solver)
        ts = time.perf_counter()
        if step is None:
            # invalid step: shrink the radius and retry (Ceres' StepIsInvalid)
            radius /= decrease
            decrease *= 2.0
            reuse = True
            history.append(BundleIteration(it, cost, False, 0.0, radius, 0.0))
            tm["step"] += time.perf_counter() - ts
            continue
        dc, dp = step
        Jd = ne.jvp(dc, dp)
        model_change = -float(np.sum(Jd * (r + 0.5 * Jd)))
        tm["step"] += time.perf_counter() - ts
        if not model_change > 0.0:
            radius /= decrease
            decrease *= 2.0
            reuse = True
            history.append(BundleIteration(it, cost, False, 0.0, radius, 0.0))
            continue
        if first_pred is None:
            first_pred = model_change
        cand = x.retract(dc, dp)
        cand_cost = evaluate(cand)
        if not np.isfinite(cand_cost):
            cand_cost = float(np.finfo(float).max)
        step_norm = float(np.sqrt(np.sum(dc * dc) + np.sum(dp * dp)))
        stop = None
        if step_norm <= parameter_tolerance * (x_norm + parameter_tolerance):
            stop = "parameter tolerance reached"
        elif abs(cost - cand_cost) <= function_tolerance * cost:
            stop = (f"function tolerance reached (|cost change|/cost = "
                    f"{abs(cost - cand_cost) / cost:.3e})")
        if stop is not None:
            termination = "convergence" if settled(cand_cost) else "failure"
            message = stop if termination == "convergence" else (
                f"{stop} after {tries - 1} rejected steps, without decreasing the cost (the "
                f"first step's model predicted a decrease of {first_pred:.3g})")
            history.append(BundleIteration(it, cand_cost, False, 0.0, radius, step_norm))
            break
        rho = (cost - cand_cost) / model_change
        cost_change = cost - cand_cost
        used_radius = radius
        if rho > 1e-3:
            x = cand
            x_norm = xnorm(x)
            cost, ne, gmax, r = linearize(x)
            radius = min(1e16, radius / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
            decrease, reuse = 2.0, False
            successful += 1
            first_pred, tries = None, 0
        else:
            radius /= decrease
            decrease *= 2.0
            reuse = True
        history.append(BundleIteration(it, cand_cost, rho > 1e-3, rho, used_radius, step_norm))
        if verbose:
            now = time.perf_counter()
            print(f"{it:4d} {cost:13.6e} {cost_change:12.2e} {gmax:10.2e} {step_norm:9.2e} "
                  f"{rho:10.2e} {radius:10.2e} {now - t_it:9.2e}"
                  f"{'' if rho > 1e-3 else '  (rejected)'}", file=sys.stderr, flush=True)
            t_it = now
    time_s = time.perf_counter() - t_start
    tm["total"] = time_s
    if loss is None:
        plain0, plain1 = initial_cost, cost
    else:
        plain0, plain1 = problem.cost(behind), x.cost(behind)
    return BundleResult(x, plain0, plain1, initial_cost, cost, it, successful,
                        termination == "convergence", message, termination, time_s, history, tm,
                        behind, "lm", linear_solver, ne)


# ---------------------------------------------------------------------------- as a factor graph

@dataclass(frozen=True)
class BundleGraph:
    """A bundle problem as a :class:`~microlie.optim.FactorGraph` (built by
    :func:`bundle_graph`): the graph and its handles.

    Attributes
    ----------
    graph : FactorGraph
        The graph: one :class:`~microlie.optim.ReprojectionFactor` batch (add other factors).
    rotations : Variables
        ``SO3`` world-to-camera rotations (``R Exp(dphi)``).
    translations : Variables
        ``R(3)`` world-to-camera translations (``t + dt``).
    intrinsics : Variables
        ``R(k)`` intrinsics in the model's order.
    points : Variables
        ``R(3)`` world points.
    factor : ReprojectionFactor
        The reprojection factors, one per observation.
    model : CameraModel
        The camera model.

    Examples
    --------
    >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
    >>> truth, start = synthetic_scene(3, 20, seed=1)
    >>> bg = bundle_graph(start, fix_cameras=[0], fix_points=[0])
    >>> res = bg.graph.optimize(solver="trust-region", linear_solver="schur")
    >>> bool(abs(bg.problem(res.values).cost() - res.final_cost) < 1e-9 * res.final_cost)
    True
    """

    graph: Any
    rotations: Any
    translations: Any
    intrinsics: Any
    points: Any
    factor: Any
    model: CameraModel

    def problem(self, values: Any = None) -> BundleProblem:
        """The :class:`BundleProblem` at ``values`` (``result.values``; default: the initial
        values), with the graph's observations.

        Parameters
        ----------
        values : Values, optional
            Values of the graph.

        Returns
        -------
        BundleProblem

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
        >>> truth, start = synthetic_scene(3, 20, seed=1)
        >>> bool(np.allclose(bundle_graph(start).problem().points, start.points))
        True
        """
        v = self.graph.initial_values() if values is None else values
        f = self.factor
        return BundleProblem(np.asarray(v[self.rotations].matrix()),
                             np.asarray(v.params(self.translations)),
                             np.asarray(v.params(self.intrinsics)),
                             np.asarray(v.params(self.points)), f.args[0][1], f.args[2][1],
                             f.observations, self.model)


def bundle_graph(problem: BundleProblem | BALProblem, *, robust: Any = None,
                 behind: str = "evaluate", fix_cameras: Sequence[int] | None = None,
                 fix_points: Sequence[int] | None = None,
                 fix_intrinsics: Sequence[int] | bool | None = None) -> BundleGraph:
    """The bundle problem as a factor graph: ``SO3`` and ``R(3)`` camera poses (BAL's
    parametrisation), ``R(k)`` intrinsics, ``R(3)`` points and one
    :class:`~microlie.optim.ReprojectionFactor` per observation; solve it with
    ``graph.optimize(solver=TrustRegion(), linear_solver="schur")`` (Ceres' rules on the
    Schur complement of the points; add ``gauge="none"`` when nothing is held, as
    :func:`bundle_adjust` leaves BAL's 7-dof gauge to the damping).

    Parameters
    ----------
    problem : BundleProblem or BALProblem
        The starting point.
    robust : str or RobustLoss, optional
        A loss on each observation's squared residual norm (pixels).
    behind : {"evaluate", "drop"}
        Points behind a camera (:mod:`microlie.optim.sfm.camera`).
    fix_cameras : sequence of int, optional
        Cameras whose pose (rotation and translation) is held.
    fix_points : sequence of int, optional
        Held points.
    fix_intrinsics : sequence of int or bool, optional
        Cameras whose intrinsics are held (``True``: all).

    Returns
    -------
    BundleGraph

    Examples
    --------
    >>> from microlie.optim.sfm.bundle import bundle_adjust, bundle_graph, synthetic_scene
    >>> truth, start = synthetic_scene(3, 20, seed=1)
    >>> bg = bundle_graph(start, fix_cameras=[0], fix_points=[0])
    >>> res = bg.graph.optimize(solver="trust-region", linear_solver="schur")
    >>> ref = bundle_adjust(start, fix_cameras=[0], fix_points=[0])
    >>> bool(abs(res.final_cost - ref.final_cost) <= 1e-9 * ref.final_cost)
    True
    """
    from ...groups import SO3
    from ..core.graph import FactorGraph
    from .reprojection import ReprojectionFactor

    if isinstance(problem, BALProblem):
        problem = BundleProblem.from_bal(problem)
    g = FactorGraph()
    rot = g.add_variables(SO3.from_matrix(problem.rotations, normalize=True), name="rotations")
    tr = g.add_variables(problem.translations, name="translations")
    K = g.add_variables(problem.intrinsics, name="intrinsics")
    X = g.add_variables(problem.points, name="points")
    if fix_cameras is not None:
        g.fix(rot, np.asarray(fix_cameras, dtype=np.intp))
        g.fix(tr, np.asarray(fix_cameras, dtype=np.intp))
    if fix_intrinsics is True:
        g.fix(K)
    elif fix_intrinsics is not None and fix_intrinsics is not False:
        g.fix(K, np.asarray(fix_intrinsics, dtype=np.intp))
    if fix_points is not None:
        g.fix(X, np.asarray(fix_points, dtype=np.intp))
    ci, pi = problem.camera_index, problem.point_index
    f = g.add(ReprojectionFactor(((rot, ci), (tr, ci)), (X, pi), problem.observations,
                                 model=problem.model, intrinsics=(K, ci), loss=robust,
                                 behind=behind))
    return BundleGraph(g, rot, tr, K, X, f, problem.model)


# ---------------------------------------------------------------------------- synthetic scenes

def synthetic_scene(n_cameras: int = 5, n_points: int = 100, *, noise: float = 0.5,
                    perturb: float = 0.05, seed: int = 0, model: str | CameraModel = "bal",
                    distance: float = 6.0) -> tuple[BundleProblem, BundleProblem]:
    """An arc of cameras at ``distance`` looking at a point cloud in ``[-1, 1]^3``; every camera
    sees every point.

    Parameters
    ----------
    n_cameras, n_points : int
        The sizes.
    noise : float
        Pixel noise on the observations of ``truth``.
    perturb : float
        Perturbation of ``start``: rotation about ``perturb`` rad, translation and points
        ``perturb`` units.
    seed : int
        The random seed.
    model : str or CameraModel
        See :func:`~microlie.optim.sfm.camera.camera_model`.
    distance : float
        The cameras' distance to the cloud.

    Returns
    -------
    truth, start : BundleProblem

    Examples
    --------
    >>> from microlie.optim.sfm.bundle import synthetic_scene
    >>> truth, start = synthetic_scene(4, 30, noise=0.0)
    >>> truth.observations.shape, round(truth.cost(), 9), start.cost() > 0
    ((120, 2), 0.0, True)
    """
    rng = np.random.default_rng(seed)
    mdl = camera_model(model)
    X = rng.uniform(-1.0, 1.0, (n_points, 3))
    ang = np.linspace(0.0, 0.8, n_cameras)
    centers = np.stack([distance * np.sin(ang), 0.3 * rng.standard_normal(n_cameras),
                        distance * np.cos(ang)], 1)
    Rs, ts = [], []
    for c in centers:
        # camera looking at the origin; BAL looks down -z, the pinhole model down +z
        fwd = -c / np.linalg.norm(c)
        z = -fwd if isinstance(mdl, BALCamera) else fwd
        xax = np.cross([0.0, 1.0, 0.0], z)
        xax /= np.linalg.norm(xax)
        yax = np.cross(z, xax)
        R = np.stack([xax, yax, z])        # rows: camera axes in the world
        Rs.append(R)
        ts.append(-R @ c)
    R = np.array(Rs)
    t = np.array(ts)
    if isinstance(mdl, BALCamera):
        K = np.tile([500.0, 1e-2, -1e-3], (n_cameras, 1))
    elif mdl.n_intrinsics == 4:
        K = np.tile([500.0, 510.0, 320.0, 240.0], (n_cameras, 1))
    else:
        K = np.tile([500.0, 510.0, 320.0, 240.0, -0.1, 0.01, 1e-3, -1e-3], (n_cameras, 1))
    cam = np.repeat(np.arange(n_cameras), n_points)
    pt = np.tile(np.arange(n_points), n_cameras)
    clean = reproject(mdl, R, t, K, X, cam, pt, np.zeros((len(cam), 2)), jac=False).residuals
    obs = clean + noise * rng.standard_normal(clean.shape)
    truth = BundleProblem(R, t, K, X, cam, pt, obs, mdl)
    from ...groups import SO3

    dR = np.asarray(SO3.exp(perturb * rng.standard_normal((n_cameras, 3))).matrix())
    start = replace(truth, rotations=R @ dR,
                    translations=t + perturb * rng.standard_normal(t.shape),
                    points=X + perturb * rng.standard_normal(X.shape))
    return truth, start


# ---------------------------------------------------------------------------- plot

def plot_bundle(initial: BundleProblem, optimised: BundleProblem, path: Any = None,
                title: str | None = None, max_points: int = 20000) -> Any:
    """3-D views of the camera centres ``-R^T t`` and the points before (left) and after
    (right). Builds a ``matplotlib.figure.Figure`` with the Agg canvas (never pyplot, never
    the caller's backend). The view is limited to the 2-98 % range of the points (BAL files
    have a few far-away points).

    Parameters
    ----------
    initial, optimised : BundleProblem
        The two states.
    path : str or os.PathLike, optional
        Save the figure there (PNG).
    title : str, optional
        The figure title.
    max_points : int
        Subsample the points drawn.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import BALProblem, BundleProblem, bundle_adjust
    >>> cams = np.zeros((2, 9))
    >>> cams[:, 5], cams[:, 6], cams[1, 3] = -5.0, 500.0, 1.0  # t_z = -5, f = 500
    >>> pts = np.random.default_rng(0).normal(size=(6, 3))
    >>> ci, pi = np.repeat([0, 1], 6), np.tile(np.arange(6), 2)
    >>> uv = BALProblem(cams, pts, ci, pi, np.zeros((12, 2))).residuals()  # the projections
    >>> bal = BALProblem(cams, pts, ci, pi, uv)
    >>> problem = BundleProblem.from_bal(bal)
    >>> d = 0.01 * np.sin(np.arange(18.0)).reshape(6, 3)
    >>> d[0] = 0.0  # point 0 is held at its true value
    >>> noisy = BALProblem(cams, pts + d, ci, pi, uv)
    >>> res = bundle_adjust(noisy, fix_cameras=[0], fix_points=[0], fix_intrinsics=True)
    >>> from microlie.optim import plot_bundle
    >>> fig = plot_bundle(BundleProblem.from_bal(noisy), res.problem)
    >>> len(fig.axes)
    2
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - exercised only without matplotlib
        raise ImportError("plotting needs matplotlib: pip install 'microlie[plot]'") from exc
    fig = Figure(figsize=(12.0, 6.0), dpi=100)
    FigureCanvasAgg(fig)
    for k, (p, name) in enumerate(((initial, "initial"), (optimised, "optimised"))):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        X = p.points
        if len(X) > max_points:
            X = X[np.linspace(0, len(X) - 1, max_points).astype(int)]
        centres = -np.einsum("nji,nj->ni", p.rotations, p.translations)
        ax.scatter(X[:, 0], X[:, 1], X[:, 2], s=0.3, c="tab:blue", alpha=0.5, label="points")
        ax.scatter(centres[:, 0], centres[:, 1], centres[:, 2], s=12, c="tab:red", marker="^",
                   label="cameras")
        both = np.concatenate([X, centres])
        lo, hi = np.percentile(both, 2, axis=0), np.percentile(both, 98, axis=0)
        mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 1e-9)
        ax.set_xlim(mid[0] - half, mid[0] + half)
        ax.set_ylim(mid[1] - half, mid[1] + half)
        ax.set_zlim(mid[2] - half, mid[2] + half)
        ax.set_xlabel("x")
        ax.set_ylabel("y")
        ax.set_zlabel("z")
        ax.set_title(f"{name}: cost {p.cost():.6g}")
        ax.legend(loc="upper right", fontsize=8)
    if title:
        fig.suptitle(title)
    if path is not None:
        save_figure(fig, path)
    return fig
