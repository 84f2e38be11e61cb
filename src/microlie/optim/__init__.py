"""Factor graphs on Lie groups: sparse non-linear least squares (specification: MATH.md section 8).

API in one paragraph: ``g = FactorGraph()``; ``poses = g.add_variables(SE3_batch, fixed=...)``
adds one batch of variables of one type (any :class:`~microlie.LieGroup`; an ``(n, d)``
array of vectors is a batch of ``R(d)``, whose values stay plain arrays) and returns a handle;
``g.fix(handle, idx, components=[...])`` holds whole variables or some of their tangent
coordinates; factors are batches too:
``PriorFactor(poses, idx, Z, noise)`` (``r = X (-) Z``), ``BetweenFactor(poses, i, j, Z, noise)``
(``r = (X_i^-1 X_j) (-) Z_ij``) and ``CustomFactor(fn, [(var, idx), ...], dim, noise,
jac="numerical"|"analytic"|"jax"|"torch")``, each added with ``g.add(...)``; a factor type of
your own with analytic Jacobians is a :class:`Factor` subclass implementing
``residual(*values, jac=False)``, checked with ``check_jacobians(factor)``; noise models are
``Information``, ``SqrtInformation``, ``Covariance``, ``Diagonal``, ``Isotropic``; robust losses
(``loss=Huber(1.0)`` or ``"cauchy:2"``) are ``Huber``, ``Cauchy``, ``Tukey``, ``GemanMcClure``,
``DCS``, ``Barron``, applied as in Ceres; ``g.optimize(robust="gnc-tls")`` (or a :class:`GNC`
with known inliers and the chi-square quantile) finds the outliers by graduated non-convexity
and returns ``result.inliers`` and ``result.weights``.
``result = g.optimize(solver="lm"|"gn"|"dogleg"|"trust-region", linear_solver="auto"|
"cholesky"|"schur"|"scipy"|"qdldl"|"pardiso"|"dense")`` returns a :class:`Result` with ``values``
(``result.values[poses]`` is the optimised batch), ``initial_cost``, ``final_cost``
(``0.5 * sum r^T Omega r``, GTSAM's error), ``iterations``, ``converged``, ``message``,
``history`` and ``time_s``; ``solver`` also takes a strategy object with its options
(``LevenbergMarquardt(...)``, GTSAM's rules; ``GaussNewton()``; ``Dogleg(...)``;
``TrustRegion(...)``, Levenberg-Marquardt with Ceres' rules); a graph without a prior or a
fixed variable is a ``GaugeError`` unless ``gauge="fix_first"``. ``g.marginals(result.values,
poses, idx)`` gives :class:`~microlie.Gaussian` marginals in the right-perturbation frame.
Conventions: every variable is perturbed on the right (``X Exp(delta)``), every Jacobian is a
right Jacobian, tangents are translation first.

Files: ``read_g2o``/``write_g2o`` (:mod:`microlie.optim.io.g2o`), ``read_toro``/``write_toro``
(:mod:`microlie.optim.io.toro`), both with a :class:`microlie.optim.io.pose_graph.PoseGraph`, and
``read_bal``/``write_bal`` (:mod:`microlie.optim.io.bal`), all importable from here; every writer
replaces its file only once the new one is complete. Initialisation: :mod:`microlie.optim.init`.
Certified global optimum of a pose graph: ``certified_pose_graph(graph)`` and
``certify_poses(graph, poses)`` (:mod:`microlie.optim.certify`), returning a
``CertifiedResult``.
"""

# Submodules load on first use (PEP 562), so that ``microlie optimize``'s argument parser and the
# file readers (``microlie.optim.io.g2o``) do not pay for the solver's SciPy imports.
import importlib
from typing import TYPE_CHECKING, Any

_LAZY = {
    "io.bal": ("BALProblem", "read_bal", "write_bal"),
    "sfm.bundle": ("BundleGraph", "BundleProblem", "bundle_adjust", "bundle_graph", "plot_bundle"),
    "sfm.camera": ("BALCamera", "PinholeCamera"),
    "sfm.reprojection": ("ReprojectionFactor",),
    "core.factors": ("BetweenFactor", "CustomFactor", "Factor", "JacobianCheck", "PriorFactor",
                "check_jacobians"),
    "io.g2o": ("read_g2o", "write_g2o"),
    "core.graph": ("FactorGraph", "from_pose_graph"),
    "linalg.base": ("LinearSolver", "SingularSystemError"),
    "linalg.linear": ("available_solvers", "make_solver"),
    "linalg.schur_solver": ("SchurSolver",),
    "core.noise": ("Covariance", "Diagonal", "Information", "Isotropic", "NoiseModel",
              "SqrtInformation", "Unit"),
    "io.pose_graph": ("PoseGraph",),
    "core.problem": ("GaugeError", "NonFiniteError", "Problem"),
    "core.robust": ("DCS", "Barron", "Cauchy", "GemanMcClure", "Huber", "RobustLoss", "Tukey",
               "make_loss"),
    "core.solvers": ("IterationRecord", "Result"),
    "core.gnc": ("GNC",),
    "core.strategies": ("Dogleg", "GaussNewton", "LevenbergMarquardt", "Strategy",
                        "TrustRegion"),
    "io.toro": ("read_toro", "write_toro"),
    "core.variables": ("Values", "Variables"),
    "certify": ("CertifiedResult", "certified_pose_graph", "certify_poses"),
    "online.incremental": ("IncrementalSmoother", "UpdateRecord"),
    "online.fixed_lag": ("BatchFixedLagSmoother", "IncrementalFixedLagSmoother"),
}
_WHERE = {name: module for module, names in _LAZY.items() for name in names}


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_WHERE])


if TYPE_CHECKING:
    from .certify import CertifiedResult, certified_pose_graph, certify_poses
    from .core.factors import (
        BetweenFactor,
        CustomFactor,
        Factor,
        JacobianCheck,
        PriorFactor,
        check_jacobians,
    )
    from .core.gnc import GNC
    from .core.graph import FactorGraph, from_pose_graph
    from .core.noise import (
        Covariance,
        Diagonal,
        Information,
        Isotropic,
        NoiseModel,
        SqrtInformation,
        Unit,
    )
    from .core.problem import GaugeError, NonFiniteError, Problem
    from .core.robust import DCS, Barron, Cauchy, GemanMcClure, Huber, RobustLoss, Tukey, make_loss
    from .core.solvers import IterationRecord, Result
    from .core.strategies import Dogleg, GaussNewton, LevenbergMarquardt, Strategy, TrustRegion
    from .core.variables import Values, Variables
    from .io.bal import BALProblem, read_bal, write_bal
    from .io.g2o import read_g2o, write_g2o
    from .io.pose_graph import PoseGraph
    from .io.toro import read_toro, write_toro
    from .linalg.base import LinearSolver, SingularSystemError
    from .linalg.linear import available_solvers, make_solver
    from .linalg.schur_solver import SchurSolver
    from .online.incremental import IncrementalSmoother, UpdateRecord
    from .sfm.bundle import (
        BundleGraph,
        BundleProblem,
        bundle_adjust,
        bundle_graph,
        plot_bundle,
    )
    from .sfm.camera import BALCamera, PinholeCamera
    from .sfm.reprojection import ReprojectionFactor

__all__ = ["FactorGraph", "from_pose_graph", "Variables", "Values", "Factor", "PriorFactor",
           "BetweenFactor", "CustomFactor", "check_jacobians", "JacobianCheck", "NoiseModel",
           "Information", "SqrtInformation",
           "Covariance", "Diagonal", "Isotropic", "Unit", "RobustLoss", "Huber", "Cauchy", "Tukey",
           "GemanMcClure", "DCS", "Barron", "make_loss", "GNC", "Result", "IterationRecord",
           "Strategy", "LevenbergMarquardt", "GaussNewton", "Dogleg", "TrustRegion",
           "LinearSolver", "SingularSystemError", "GaugeError", "NonFiniteError", "Problem",
           "available_solvers", "SchurSolver",
           "make_solver", "BALProblem", "read_bal", "write_bal", "BundleProblem",
           "BundleGraph", "bundle_graph", "bundle_adjust", "plot_bundle", "BALCamera",
           "PinholeCamera", "ReprojectionFactor",
           "PoseGraph", "read_g2o",
           "write_g2o", "read_toro", "write_toro", "CertifiedResult", "certified_pose_graph",
           "certify_poses", "IncrementalSmoother", "UpdateRecord"]
