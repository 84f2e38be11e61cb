"""Bundle adjustment as a factor graph: the problem type, its graph, and the one-call solve.

Unknowns: per camera a world-to-camera rotation ``R`` (perturbed ``R Exp(dphi)``), a translation
``t`` (``t + dt``) and intrinsics ``K`` (``K + dK``), tangent ``(dt, dphi, dK)``; per point a
3-vector. Cost ``0.5 * sum rho(|r|^2)`` in pixels (``rho(s) = s`` without a robust loss).

:func:`bundle_graph` builds the problem as a :class:`~microlie.optim.FactorGraph` (one
:class:`~microlie.optim.ReprojectionFactor` per observation; add other factors beside them);
:func:`bundle_adjust` is the convenience that builds it and runs the one engine,
:meth:`FactorGraph.optimize <microlie.optim.FactorGraph.optimize>`, by default with
:class:`~microlie.optim.TrustRegion` (Levenberg-Marquardt with Ceres' rules: Jacobi scaling,
trust radius, Ceres' stopping tests and iteration count) and ``linear_solver="schur"`` (the
points eliminated). It returns the engine's :class:`~microlie.optim.core.solvers.Result`;
:meth:`BundleProblem.with_values` turns its values back into a :class:`BundleProblem`.
Marginal covariances of cameras come from the graph's one marginals path
(:meth:`BundleGraph.camera_covariance`, :meth:`BundleGraph.marginals`).

The gauge (7 degrees of freedom for BAL: rotation, translation, scale) is left free by default
(the damping keeps the system definite, as in Ceres); ``fix_cameras=[0]`` holds camera 0 (and
with it 6 of the 7), ``fix_points`` holds points.

>>> from microlie.optim.sfm.bundle import bundle_adjust, synthetic_scene
>>> truth, start = synthetic_scene(n_cameras=3, n_points=40, noise=0.0, seed=1)
>>> result = bundle_adjust(start, fix_cameras=[0])
>>> result.converged, result.final_cost < 1e-12
(True, True)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..._files import save_figure
from ..io.bal import BALProblem
from .camera import BALCamera, CameraModel, camera_model, reproject

if TYPE_CHECKING:
    from ..core.solvers import Result
    from ..core.strategies import Strategy
    from ..linalg.base import LinearSolver

__all__ = ["BundleProblem", "BundleGraph", "bundle_adjust", "bundle_graph", "synthetic_scene",
           "plot_bundle", "rotvec_to_matrix", "matrix_to_rotvec"]


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

    def with_values(self, values: Any) -> BundleProblem:
        """This problem (observations, camera model) at the cameras and points of ``values``:
        ``result.values`` of :func:`bundle_adjust`, or of a :func:`bundle_graph` graph. Reads
        the batches that :func:`bundle_graph` names ``rotations``, ``translations``,
        ``intrinsics`` and ``points``.

        Parameters
        ----------
        values : Values
            Values of a bundle graph of this problem (same numbers of cameras and points).

        Returns
        -------
        BundleProblem

        Raises
        ------
        ValueError
            ``values`` lack one of the four batches, or their sizes differ from this problem's.

        Examples
        --------
        >>> from microlie.optim.sfm.bundle import bundle_adjust, synthetic_scene
        >>> truth, start = synthetic_scene(3, 20, noise=0.0, seed=1)
        >>> result = bundle_adjust(start, fix_cameras=[0])
        >>> solved = start.with_values(result.values)   # a BundleProblem; .to_bal() for BAL
        >>> bool(abs(solved.cost() - result.final_cost) <= 1e-12 * max(start.cost(), 1.0))
        True
        """
        names = [h.name for h in values]
        found = {}
        for name, n in (("rotations", self.n_cameras), ("translations", self.n_cameras),
                        ("intrinsics", self.n_cameras), ("points", self.n_points)):
            hs = [h for h in values if h.name == name]
            if len(hs) != 1:
                raise ValueError(f"values must hold one batch named {name!r} (the values of a "
                                 f"bundle_graph graph), got batches {names}")
            if hs[0].n != n:
                raise ValueError(f"values: batch {name!r} has {hs[0].n} variables, this problem "
                                 f"{n}")
            found[name] = hs[0]
        return replace(self, rotations=np.asarray(values[found["rotations"]].matrix()),
                       translations=values.params(found["translations"]),
                       intrinsics=values.params(found["intrinsics"]),
                       points=values.params(found["points"]))


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

    def camera_covariance(self, values: Any, cameras: Sequence[int], *,
                          linear_solver: str = "auto", blas_threads: int | None = 1
                          ) -> np.ndarray:
        """Marginal covariances of the camera tangents ``(dt, dphi, dK)`` at ``values``, through
        :meth:`FactorGraph.marginal_covariance <microlie.optim.FactorGraph.marginal_covariance>`
        (the graph's one marginals path: ``H^-1`` of the Gauss-Newton matrix, robust weights
        in, no damping). The gauge must be held (``fix_cameras`` and a point for BAL's 7
        degrees of freedom), else ``H`` is singular. Held unknowns have zero covariance.

        Parameters
        ----------
        values : Values
            Where (``result.values``).
        cameras : sequence of int
            The cameras.
        linear_solver : str
            The solver of ``H`` (:meth:`FactorGraph.marginal_covariance
            <microlie.optim.FactorGraph.marginal_covariance>`).
        blas_threads : int or None
            BLAS threads while factorising and solving (default 1; ``None`` keeps the process's
            setting).

        Returns
        -------
        numpy.ndarray
            ``(len(cameras), 6 + k, 6 + k)``.

        Raises
        ------
        ValueError
            A free camera without observations (its covariance is infinite: hold it or remove
            it); a free gauge (:class:`~microlie.optim.GaugeError`).

        Examples
        --------
        >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
        >>> truth, start = synthetic_scene(3, 20, seed=1)
        >>> bg = bundle_graph(start, fix_cameras=[0], fix_points=[0])
        >>> res = bg.graph.optimize(solver="trust-region", linear_solver="schur")
        >>> bg.camera_covariance(res.values, [0, 2]).shape
        (2, 9, 9)
        """
        cams = [int(c) for c in np.asarray(cameras, dtype=np.intp).reshape(-1)]
        parts = (self.translations, self.rotations, self.intrinsics)
        nobs = np.bincount(self.factor.args[0][1], minlength=self.rotations.n)
        free = np.zeros(self.rotations.n, bool)
        for v in parts:
            free |= ~v.fixed
        blind = np.flatnonzero(free & (nobs == 0))
        if blind.size:
            raise ValueError(f"camera(s) {blind.tolist()} are not observable (0 observations): "
                             f"their covariance is infinite; hold them (fix_cameras and "
                             f"fix_intrinsics) or remove them")
        offs = np.cumsum([0] + [v.dof for v in parts])
        items, cols = [], []
        for k, c in enumerate(cams):
            for v, o in zip(parts, offs[:-1], strict=True):
                if not v.fixed[v.indices(c)[0]]:
                    items.append((v, c))
                    cols.append(k * offs[-1] + o + np.arange(v.dof))
        out = np.zeros((len(cams) * offs[-1],) * 2)
        if items:
            ix = np.concatenate(cols)
            out[np.ix_(ix, ix)] = self.graph.marginal_covariance(values, items, linear_solver,
                                                                  blas_threads=blas_threads)
        d = int(offs[-1])
        return np.stack([out[k * d:(k + 1) * d, k * d:(k + 1) * d] for k in range(len(cams))])

    def marginals(self, values: Any, cameras: Sequence[int], *,
                  linear_solver: str = "auto", blas_threads: int | None = 1) -> list[Any]:
        """Marginal Gaussians of camera poses as world-to-camera ``SE3`` elements,
        ``frame="right"`` (``T = Tbar Exp(rho, phi)``), from :meth:`camera_covariance`: the
        translation step ``dt`` is ``R rho`` to first order, so the covariance is
        ``blockdiag(R^T, I) P blockdiag(R, I)`` of its pose block ``P`` (intrinsics
        marginalised out).

        Parameters
        ----------
        values : Values
            Where (``result.values``).
        cameras : sequence of int
            The cameras.
        linear_solver : str
            As :meth:`camera_covariance`.
        blas_threads : int or None
            As :meth:`camera_covariance`.

        Returns
        -------
        list of Gaussian
            One per camera.

        Examples
        --------
        >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
        >>> truth, start = synthetic_scene(3, 20, seed=1)
        >>> bg = bundle_graph(start, fix_cameras=[0], fix_points=[0])
        >>> res = bg.graph.optimize(solver="trust-region", linear_solver="schur")
        >>> g = bg.marginals(res.values, [1])[0]
        >>> g.frame, g.cov.shape
        ('right', (6, 6))
        """
        from ...uncertainty import Gaussian

        covs = self.camera_covariance(values, cameras, linear_solver=linear_solver,
                                      blas_threads=blas_threads)
        p = self.problem(values)
        poses = p.poses()
        out = []
        for c, P in zip(cameras, covs, strict=True):
            T = np.eye(6)
            T[:3, :3] = p.rotations[c].T
            Pse3 = T @ P[:6, :6] @ T.T
            out.append(Gaussian(poses[c], 0.5 * (Pse3 + Pse3.T), frame="right"))
        return out


#: What ``fix_cameras``, ``fix_points`` and ``fix_intrinsics`` take: indices, a boolean mask,
#: ``True`` (all) or ``None``/``False`` (none).
Held = Sequence[int] | Sequence[bool] | bool | None


def bundle_graph(problem: BundleProblem | BALProblem, *, robust: Any = None,
                 behind: str = "evaluate", fix_cameras: Held = None,
                 fix_points: Held = None,
                 fix_intrinsics: Held = None) -> BundleGraph:
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
    fix_cameras : sequence of int or bool, optional
        Cameras whose pose (rotation and translation) is held: indices, a boolean mask over the
        cameras, or ``True`` for all.
    fix_points : sequence of int or bool, optional
        Held points: indices, a boolean mask over the points, or ``True`` for all.
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
    cams = _indices("fix_cameras", fix_cameras, problem.n_cameras)
    if cams is not None:
        g.fix(rot, cams)
        g.fix(tr, cams)
    held_k = _indices("fix_intrinsics", fix_intrinsics, problem.n_cameras)
    if held_k is not None:
        g.fix(K, held_k)
    pts = _indices("fix_points", fix_points, problem.n_points)
    if pts is not None:
        g.fix(X, pts)
    ci, pi = problem.camera_index, problem.point_index
    f = g.add(ReprojectionFactor(((rot, ci), (tr, ci)), (X, pi), problem.observations,
                                 model=problem.model, intrinsics=(K, ci), loss=robust,
                                 behind=behind))
    return BundleGraph(g, rot, tr, K, X, f, problem.model)


def bundle_adjust(problem: BundleProblem | BALProblem, *, robust: Any = None,
                  behind: str = "evaluate", fix_cameras: Held = None,
                  fix_points: Held = None,
                  fix_intrinsics: Held = None,
                  solver: str | Strategy = "trust-region",
                  linear_solver: str | LinearSolver = "schur", max_iter: int = 100,
                  gauge: str = "none", verbose: bool | None = False,
                  blas_threads: int | None = 1, **options: Any) -> Result:
    """Bundle adjustment through the one engine: :func:`bundle_graph` then
    :meth:`FactorGraph.optimize <microlie.optim.FactorGraph.optimize>`, by default with
    :class:`~microlie.optim.TrustRegion` (Levenberg-Marquardt with Ceres' rules, so that
    iterations count as Ceres') on the Schur complement of the points. Costs are
    ``0.5 * sum rho(|r|^2)`` in pixels; the gauge (7 degrees of freedom for BAL) is left to the
    damping, as in Ceres, unless ``fix_cameras`` (and ``fix_points``) hold it.

    Parameters
    ----------
    problem : BundleProblem or BALProblem
        The starting point.
    robust : str or RobustLoss, optional
        A loss of :mod:`microlie.optim.core.robust` or a spec such as ``"huber:1.0"`` (scale in
        pixels) on each observation's squared residual norm.
    behind : {"evaluate", "drop"}
        Points behind a camera: evaluated (BAL convention) or dropped (GTSAM/COLMAP), see
        :mod:`microlie.optim.sfm.camera`.
    fix_cameras : sequence of int or bool, optional
        Cameras whose *pose* is held: indices, a boolean mask over the cameras, or ``True``.
    fix_points : sequence of int or bool, optional
        Held points: indices, a boolean mask over the points, or ``True`` for all.
    fix_intrinsics : sequence of int or bool, optional
        Cameras whose intrinsics are held (``True``: all).
    solver : str or Strategy
        The strategy (default ``"trust-region"``; any of :meth:`FactorGraph.optimize
        <microlie.optim.FactorGraph.optimize>`'s, or an instance with its options).
    linear_solver : str or LinearSolver
        Default ``"schur"`` (the points eliminated); any of :func:`~microlie.optim.make_solver`'s
        (``"auto"``, ``"cholesky"``, ``"dense"``, ...) for the full system.
    max_iter : int
        Iteration limit, as the strategy counts (``"trust-region"``: every try, as Ceres).
    gauge : {"none", "check", "fix_first"}
        :meth:`FactorGraph.optimize <microlie.optim.FactorGraph.optimize>`'s (default
        ``"none"``: the damping handles the free gauge).
    verbose : bool or None
        Ceres' iteration table on stderr (``None``: when stderr is a terminal).
    blas_threads : int or None
        BLAS threads during the call (default 1; ``None`` keeps the process's setting).
    **options
        The named strategy's options: ``function_tolerance``, ``gradient_tolerance``,
        ``parameter_tolerance``, ``radius_initial``, ``jacobi_scaling``, ... (``TypeError``
        for one it does not take).

    Returns
    -------
    Result
        The engine's :class:`~microlie.optim.core.solvers.Result`;
        ``problem.with_values(result.values)`` (:meth:`BundleProblem.with_values`) is the
        optimised :class:`BundleProblem` (``.to_bal()`` for BAL). For marginal covariances
        build the graph with :func:`bundle_graph` and use :meth:`BundleGraph.marginals`.

    Raises
    ------
    ValueError
        An index out of range, an unknown option, or a non-finite initial residual (naming
        the observation: a point on the plane of its camera, ``P_z = 0``; use
        ``behind="drop"`` or move it).

    Examples
    --------
    >>> from microlie.optim.sfm.bundle import bundle_adjust, synthetic_scene
    >>> truth, start = synthetic_scene(n_cameras=3, n_points=40, noise=0.0, seed=1)
    >>> result = bundle_adjust(start, fix_cameras=[0])
    >>> result.converged, result.final_cost < 1e-12, result.solver
    (True, True, 'trust-region')
    >>> start.with_values(result.values).cost() < 1e-12
    True
    """
    from ..core.problem import NonFiniteError

    if isinstance(problem, BALProblem):
        problem = BundleProblem.from_bal(problem)
    bg = bundle_graph(problem, robust=robust, behind=behind, fix_cameras=fix_cameras,
                      fix_points=fix_points, fix_intrinsics=fix_intrinsics)
    try:
        return bg.graph.optimize(solver=solver, linear_solver=linear_solver, max_iter=max_iter,
                                 gauge=gauge, verbose=verbose, blas_threads=blas_threads,
                                 **options)
    except NonFiniteError as e:
        if e.factor != bg.graph.factors.index(bg.factor):
            raise
        k = e.row
        raise NonFiniteError(
            f"{e} (observation {k} is not finite: camera {problem.camera_index[k]}, point "
            f"{problem.point_index[k]}; a point on the plane of its camera, P_z = 0, or "
            f"non-finite intrinsics; use behind='drop' or move it)", e.factor, e.row,
            e.variables) from None


def _indices(name: str, idx: Any, n: int) -> Any:
    """``fix_*`` as indices (``True``: all), checked against ``n``; ``None`` and ``False``:
    nothing held."""
    if idx is None or idx is False:
        return None
    if idx is True:
        return np.arange(n)
    a = np.asarray(idx).reshape(-1)
    if a.dtype == bool:
        if a.size != n:
            raise ValueError(f"{name}: a mask must have {n} entries, got {a.size}")
        return np.flatnonzero(a)
    if a.size and (not np.issubdtype(a.dtype, np.integer) or a.min() < 0 or a.max() >= n):
        raise ValueError(f"{name}: indices must be integers in 0..{n - 1}, got {idx!r}")
    return a.astype(np.intp)


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
    >>> before = BundleProblem.from_bal(noisy)
    >>> fig = plot_bundle(before, before.with_values(res.values))
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
