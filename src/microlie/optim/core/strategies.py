"""Solver strategies: how a step is chosen, accepted and the run stopped.

:func:`~microlie.optim.core.solvers.solve` runs one loop for every strategy: it linearises the
problem (``H = J^T J``, ``g = J^T e``, whitened, robust weights with Triggs' correction), asks the
strategy for one iteration (:meth:`Strategy.iterate`: it may solve damped systems and evaluate
trial points through the :class:`SolveState` it gets), records one
:class:`~microlie.optim.core.solvers.IterationRecord` and returns one
:class:`~microlie.optim.core.solvers.Result`. Steps are applied on the right, ``X <- X Exp(dx)``,
tangents in each group's order.

The strategies (``g.optimize(solver=...)`` takes the name or an instance):

* ``"lm"`` :class:`LevenbergMarquardt`: GTSAM's ``LevenbergMarquardtOptimizer`` rules (default).
* ``"gn"`` :class:`GaussNewton`: the undamped step, accepted if it decreases the cost.
* ``"dogleg"`` :class:`Dogleg`: Powell's dogleg in a trust region.
* ``"trust-region"`` :class:`TrustRegion`: Levenberg-Marquardt with Ceres' rules
  (``TrustRegionMinimizer`` with ``LevenbergMarquardtStrategy``: Jacobi scaling, trust radius,
  Ceres' stopping tests), what :func:`~microlie.optim.sfm.bundle.bundle_adjust` runs.

Adding a strategy is one :class:`Strategy` subclass (its options as constructor parameters) and
one line in :data:`STRATEGIES`.
"""

from __future__ import annotations

import copy
import inspect
import math
import time
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from ..linalg.linear import LinearSolver, SingularSystemError
from .landmarks import bundle_landmarks
from .problem import Linearization, Problem

__all__ = ["Strategy", "LevenbergMarquardt", "GaussNewton", "Dogleg", "TrustRegion",
           "SolveState", "Trial", "Outcome", "STRATEGIES", "DAMPINGS", "make_strategy"]

#: :class:`LevenbergMarquardt`'s damping matrices (``damping=``, ``microlie optimize --damping``)
DAMPINGS = ("auto", "identity", "diagonal")
#: The first ``lambda`` of ``damping="auto"`` on a bundle adjustment (``D = diag(H)``): Ceres'
#: (``1 / initial_trust_region_radius``, ``1e4``).
BUNDLE_LAMBDA = 1e-4


def dot(a: np.ndarray, b: np.ndarray) -> float:
    """``a . b`` of two vectors without BLAS: a multithreaded BLAS ``ddot`` on a shared machine
    took 7.6 ms for 50k entries (measured, OpenBLAS with its default threads, load 4), this
    loop 18 us.

    Parameters
    ----------
    a, b : numpy.ndarray
        Vectors of one length.

    Returns
    -------
    float

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.core.strategies import dot
    >>> dot(np.array([1.0, 2.0]), np.array([3.0, 4.0]))
    11.0
    """
    return float(np.einsum("i,i->", a, b))


def norm(x: np.ndarray) -> float:
    """The Euclidean norm of a vector (:func:`dot` without BLAS).

    Parameters
    ----------
    x : numpy.ndarray
        A vector.

    Returns
    -------
    float

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.core.strategies import norm
    >>> norm(np.array([3.0, 4.0]))
    5.0
    """
    return math.sqrt(dot(x, x))


@dataclass
class Trial:
    """A trial point of a solve: the states after a step and their costs.

    Attributes
    ----------
    states : list of numpy.ndarray
        The parameters of each variable batch.
    cost, robust_cost : float
        Plain and robust cost there (``robust_cost`` is ``inf`` when not finite).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.core.strategies import Trial
    >>> Trial([np.zeros((1, 2))], 1.0, 1.0).robust_cost
    1.0
    """

    states: list[np.ndarray]
    cost: float
    robust_cost: float


@dataclass
class Outcome:
    """What one :meth:`Strategy.iterate` did.

    Attributes
    ----------
    accepted : bool
        Whether a step was taken (then ``trial`` is the new point and ``dx`` the step).
    solves : int
        Linear solves (one per damping or radius tried).
    damping : float
        ``lambda`` for LM, the trust radius for dogleg and trust-region, 0 for GN (after the
        iteration's update).
    tr_radius : float
        Ceres' ``tr_radius`` column: ``1 / lambda`` for LM, the radius for dogleg and
        trust-region, NaN for GN.
    trial : Trial, optional
        The last point tried.
    dx : numpy.ndarray, optional
        The last step tried.
    predicted : float
        Its model's cost decrease (NaN if none).
    stop : tuple of (str, str), optional
        ``(termination, message)`` when the run ends here without taking the step.
    bad_trial : list of numpy.ndarray, optional
        A trial point of this iteration whose cost was not finite.

    Examples
    --------
    >>> from microlie.optim.core.strategies import Outcome
    >>> Outcome(False, 1, 0.0, float("nan")).stop is None
    True
    """

    accepted: bool
    solves: int
    damping: float
    tr_radius: float
    trial: Trial | None = None
    dx: np.ndarray | None = None
    predicted: float = math.nan
    stop: tuple[str, str] | None = None
    bad_trial: list[np.ndarray] | None = None


class SolveState:
    """What a strategy sees of a running solve: the problem, its linear solver, the current
    point and its linearisation, and the operations a step needs.

    Parameters
    ----------
    problem : Problem
        The problem.
    ls : LinearSolver
        Its analysed linear solver.
    states : list of numpy.ndarray
        The current point.
    lin : Linearization
        The linearisation there.
    timings : dict
        Seconds spent per part (``factorize``, ``solve``, ``retract``, ``cost``), added to.

    Attributes
    ----------
    cost, robust_cost : float
        At the current point (``lin.cost``, ``lin.robust_cost`` until a step is taken).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> from microlie.optim.core.strategies import SolveState
    >>> g = FactorGraph()
    >>> x = g.add_variables(np.zeros((1, 2)))
    >>> _ = g.add(PriorFactor(x, 0, np.array([[1.0, 0.0]])))
    >>> p = g.problem()
    >>> st = [v.initial for v in p.variables]
    >>> s = SolveState(p, p.analysed("dense"), st, p.linearize(st), {})
    >>> dx = s.solve()
    >>> (np.round(dx, 12) + 0.0).tolist(), s.trial(dx).robust_cost
    ([1.0, 0.0], 0.0)
    """

    def __init__(self, problem: Problem, ls: LinearSolver, states: list[np.ndarray],
                 lin: Linearization, timings: dict[str, float]) -> None:
        self.problem, self.ls, self.timings = problem, ls, timings
        self.states = states
        self.lin = lin
        self.cost, self.robust_cost = lin.cost, lin.robust_cost
        self._H: Any = None
        self._H_of: Linearization | None = None

    def move(self, trial: Trial, lin: Linearization | None) -> None:
        """Make ``trial`` the current point, linearised as ``lin`` (``None``: not linearised
        again, the run ends there).

        Parameters
        ----------
        trial : Trial
            The accepted point.
        lin : Linearization or None
            Its linearisation.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.zeros((1, 2)))
        >>> _ = g.add(PriorFactor(x, 0, np.array([[1.0, 0.0]])))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> s = SolveState(p, p.analysed("dense"), st, p.linearize(st), {})
        >>> s.move(s.trial(s.solve()), None)
        >>> s.robust_cost
        0.0
        """
        self.states, self.cost, self.robust_cost = trial.states, trial.cost, trial.robust_cost
        if lin is not None:
            self.lin = lin

    def diagonal(self) -> np.ndarray:
        """The diagonal of the current (undamped) ``H``, a copy.

        Returns
        -------
        numpy.ndarray
            ``(problem.size,)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.zeros((1, 2)))
        >>> _ = g.add(PriorFactor(x, 0, np.array([[1.0, 0.0]])))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> SolveState(p, p.analysed("dense"), st, p.linearize(st), {}).diagonal().tolist()
        [1.0, 1.0]
        """
        return self.lin.data[self.problem.diag_pos]

    def solve(self, damping: np.ndarray | float | None = None, *,
              diagonal: np.ndarray | None = None, gauss_newton: bool = False
              ) -> np.ndarray | None:
        """The step ``dx`` of ``(H + diag(damping)) dx = -g``.

        The damping is added to the diagonal of the current ``H`` in place and the diagonal is
        restored exactly after the solve (no copy of the matrix per trial).

        Parameters
        ----------
        damping : numpy.ndarray or float, optional
            Added to the diagonal (``None``: the undamped system).
        diagonal : numpy.ndarray, optional
            The undamped diagonal (:meth:`diagonal`), when the caller has it already.
        gauss_newton : bool
            A singular system is an error naming the first variable it involves (instead of
            ``None``).

        Returns
        -------
        numpy.ndarray or None
            The step, or ``None`` when the system is singular.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.zeros((1, 2)))
        >>> _ = g.add(PriorFactor(x, 0, np.array([[1.0, 0.0]])))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> s = SolveState(p, p.analysed("dense"), st, p.linearize(st), {})
        >>> (np.round(s.solve(1.0), 12) + 0.0).tolist()  # (1 + 1) dx = 1
        [0.5, 0.0]
        """
        data, pos = self.lin.data, self.problem.diag_pos
        tm = self.timings
        dg = None
        if damping is not None:
            dg = data[pos] if diagonal is None else diagonal
            data[pos] = dg + damping
        try:
            t0 = time.perf_counter()
            try:
                self.ls.factorize(data)
            except SingularSystemError as e:
                if gauss_newton:
                    at = (f", first at {self.problem.unknown_name(e.unknown)}"
                          if e.unknown is not None else "")
                    raise SingularSystemError(
                        f"{e}: the Gauss-Newton system is rank deficient (a gauge freedom or an "
                        f"unobservable variable{at}); add priors or use solver='lm'",
                        unknown=e.unknown) from None
                return None
            finally:
                tm["factorize"] = tm.get("factorize", 0.0) + time.perf_counter() - t0
            t1 = time.perf_counter()
            try:
                return self.ls.solve(-self.lin.grad)
            finally:
                tm["solve"] = tm.get("solve", 0.0) + time.perf_counter() - t1
        finally:
            if dg is not None:
                data[pos] = dg

    def hessian(self) -> Any:
        """The current undamped ``H`` as a SciPy CSC matrix (built once per linearisation).

        Returns
        -------
        scipy.sparse.csc_matrix

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.zeros((1, 2)))
        >>> _ = g.add(PriorFactor(x, 0, np.array([[1.0, 0.0]])))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> SolveState(p, p.analysed("dense"), st, p.linearize(st), {}).hessian().shape
        (2, 2)
        """
        if self._H_of is not self.lin:
            self._H = self.problem.matrix(self.lin.data)
            self._H_of = self.lin
        return self._H

    def model_decrease(self, dx: np.ndarray) -> float:
        """The decrease of the quadratic model ``-(g . dx + dx . H dx / 2)`` (undamped ``H``;
        with ``J`` and ``e``: ``-(J dx) . (e + J dx / 2)``, Ceres' ``model_cost_change``).

        Parameters
        ----------
        dx : numpy.ndarray
            A step.

        Returns
        -------
        float

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.zeros((1, 2)))
        >>> _ = g.add(PriorFactor(x, 0, np.array([[1.0, 0.0]])))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> s = SolveState(p, p.analysed("dense"), st, p.linearize(st), {})
        >>> s.model_decrease(np.array([1.0, 0.0]))  # the whole cost 0.5
        0.5
        """
        return -(dot(self.lin.grad, dx) + 0.5 * dot(dx, self.hessian() @ dx))

    def trial(self, dx: np.ndarray, keep: bool = False) -> Trial:
        """The point ``X Exp(dx)`` and its costs (a non-finite robust cost becomes ``inf``).

        Parameters
        ----------
        dx : numpy.ndarray
            The step.
        keep : bool
            The point will likely be accepted: the factors whose Jacobians come with their
            residuals keep them for its linearisation (:meth:`Problem.costs`).

        Returns
        -------
        Trial

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.zeros((1, 2)))
        >>> _ = g.add(PriorFactor(x, 0, np.array([[1.0, 0.0]])))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> s = SolveState(p, p.analysed("dense"), st, p.linearize(st), {})
        >>> s.trial(np.array([2.0, 0.0])).cost
        0.5
        """
        tm = self.timings
        t0 = time.perf_counter()
        new = self.problem.retract(self.states, dx)
        t1 = time.perf_counter()
        c, rc = self.problem.costs(new, keep=keep)
        t2 = time.perf_counter()
        tm["retract"] = tm.get("retract", 0.0) + t1 - t0
        tm["cost"] = tm.get("cost", 0.0) + t2 - t1
        if not np.isfinite(rc):
            rc = np.inf
        return Trial(new, c, rc)

    def gradient_max(self) -> float:
        """The max-norm of the current gradient ``g`` (0 without unknowns).

        Returns
        -------
        float

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.zeros((1, 2)))
        >>> _ = g.add(PriorFactor(x, 0, np.array([[1.0, 0.0]])))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> SolveState(p, p.analysed("dense"), st, p.linearize(st), {}).gradient_max()
        1.0
        """
        g = self.lin.grad
        return float(np.abs(g).max()) if g.size else 0.0

    def state_norm(self) -> float:
        """The norm of the free variables' coordinates: ``sqrt(sum |Log(X)|^2)`` over every free
        variable (the vector itself for vector variables; rotation vectors for SO(3), as the
        angle-axis parameters of Ceres' BAL problems).

        Returns
        -------
        float

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.array([[3.0, 4.0]]))
        >>> _ = g.add(PriorFactor(x, 0, np.zeros((1, 2))))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> SolveState(p, p.analysed("dense"), st, p.linearize(st), {}).state_norm()
        5.0
        """
        total = 0.0
        for k, (v, p) in enumerate(zip(self.problem.variables, self.states, strict=True)):
            free = self.problem.node_of[k] >= 0
            if not free.any():
                continue
            q = p if free.all() else p[free]
            c = np.asarray(v.log(v.wrap(q)), dtype=np.float64)
            total += float(np.sum(c * c))
        return math.sqrt(total)


class Strategy:
    """A solver strategy: its options (constructor parameters) and its rules.

    A subclass implements :meth:`iterate` (one iteration from the current point of a
    :class:`SolveState`) and, where its rules have them, :meth:`start` (per-run state, on a
    copy of the instance), :meth:`stop_before` (tests before an iteration) and
    :meth:`converged` (tests after an accepted step).

    Attributes
    ----------
    name : str
        The registry name (``Result.solver``).
    counts_rejected : bool
        Whether a rejected try that does not end the run is an iteration (Ceres: every try
        is); without it an iteration ends with a step or ends the run (GTSAM). A try that ends
        the run without a step is never counted.

    Examples
    --------
    >>> from microlie.optim.core.strategies import STRATEGIES, Strategy
    >>> all(issubclass(c, Strategy) for c in STRATEGIES.values())
    True
    """

    name: ClassVar[str] = ""
    counts_rejected: ClassVar[bool] = False

    def started(self, s: SolveState) -> Strategy:
        """A copy of this strategy with its per-run state set for a solve from ``s`` (the
        instance itself is never changed, so it can be reused).

        Parameters
        ----------
        s : SolveState
            The solve at its start.

        Returns
        -------
        Strategy

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import LevenbergMarquardt, SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.ones((1, 1)))
        >>> _ = g.add(PriorFactor(x, 0, np.zeros((1, 1))))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> s = SolveState(p, p.analysed("dense"), st, p.linearize(st), {})
        >>> lm = LevenbergMarquardt()
        >>> lm.started(s) is lm
        False
        """
        run = copy.copy(self)
        run.start(s)
        return run

    def start(self, s: SolveState) -> None:
        """Set the per-run state (called on a copy, :meth:`started`).

        Parameters
        ----------
        s : SolveState
            The solve at its start.

        Examples
        --------
        >>> from microlie.optim.core.strategies import GaussNewton
        >>> GaussNewton().start(None)  # nothing to set
        """

    def stop_before(self, s: SolveState) -> tuple[str, str] | None:
        """A stop before the next iteration: ``(termination, message)`` or ``None``.

        Parameters
        ----------
        s : SolveState
            The solve.

        Returns
        -------
        tuple of (str, str) or None

        Examples
        --------
        >>> from microlie.optim.core.strategies import GaussNewton
        >>> GaussNewton().stop_before(None) is None
        True
        """
        return None

    def iterate(self, s: SolveState) -> Outcome:
        """One iteration from the current point of ``s``.

        Parameters
        ----------
        s : SolveState
            The solve.

        Returns
        -------
        Outcome

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import GaussNewton, SolveState
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.ones((1, 1)))
        >>> _ = g.add(PriorFactor(x, 0, np.zeros((1, 1))))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> s = SolveState(p, p.analysed("dense"), st, p.linearize(st), {})
        >>> out = GaussNewton().started(s).iterate(s)
        >>> out.accepted, out.trial.robust_cost
        (True, 0.0)
        """
        raise NotImplementedError

    def accepted(self, s: SolveState) -> None:
        """Called after the loop moved to an accepted point (and linearised it, unless the run
        ends there).

        Parameters
        ----------
        s : SolveState
            The solve, at the new point.

        Examples
        --------
        >>> from microlie.optim.core.strategies import GaussNewton
        >>> GaussNewton().accepted(None)  # nothing to update
        """

    def converged(self, old: float, new: float, step_norm: float) -> str | None:
        """After an accepted step from cost ``old`` to ``new``: why the run has converged, or
        ``None``.

        Parameters
        ----------
        old, new : float
            The robust costs before and after.
        step_norm : float
            The step's norm.

        Returns
        -------
        str or None

        Examples
        --------
        >>> from microlie.optim.core.strategies import TrustRegion
        >>> TrustRegion().converged(1.0, 0.5, 0.1) is None  # Ceres' tests come before a step
        True
        """
        return None

    def tr_radius(self) -> float:
        """Ceres' ``tr_radius`` column now (NaN: none).

        Returns
        -------
        float

        Examples
        --------
        >>> from microlie.optim.core.strategies import GaussNewton
        >>> GaussNewton().tr_radius()
        nan
        """
        return math.nan

    def _options(self) -> dict[str, Any]:
        return dict(vars(self))

    def __repr__(self) -> str:
        opts = ", ".join(f"{k}={v!r}" for k, v in self._options().items())
        return f"{type(self).__name__}({opts})"


def _positive(name: str, value: float, zero: bool = False) -> float:
    v = float(value)
    if not (v >= 0 if zero else v > 0) or math.isnan(v):
        raise ValueError(f"{name} must be {'>= 0' if zero else 'positive'}, got {value!r}")
    return v


class _GTSAMRules(Strategy):
    """The stopping tests of GTSAM's optimizers (shared by LM, GN and dogleg)."""

    def __init__(self, rel_tol: float, abs_tol: float, cost_tol: float, step_tol: float
                 ) -> None:
        self.rel_tol = _positive("rel_tol", rel_tol, zero=True)
        self.abs_tol = _positive("abs_tol", abs_tol, zero=True)
        self.cost_tol = _positive("cost_tol", cost_tol, zero=True)
        self.step_tol = _positive("step_tol", step_tol, zero=True)

    def _decrease_test(self, old: float, new: float) -> str | None:
        dec = old - new
        if new <= self.cost_tol:
            return f"cost {new:.6g} below cost_tol"
        if dec >= 0 and dec < self.abs_tol:
            return f"absolute cost decrease {dec:.3g} below abs_tol"
        if dec >= 0 and old > 0 and dec / old < self.rel_tol:
            return f"relative cost decrease {dec / old:.3g} below rel_tol"
        return None

    def converged(self, old: float, new: float, step_norm: float) -> str | None:
        """GTSAM's tests after an accepted step from cost ``old`` to ``new``: cost below
        ``cost_tol``, absolute decrease below ``abs_tol``, relative decrease below
        ``rel_tol``, step norm below ``step_tol``.

        Parameters
        ----------
        old, new : float
            The robust costs before and after.
        step_norm : float
            The step's norm.

        Returns
        -------
        str or None
            Why the run has converged, or ``None``.

        Examples
        --------
        >>> from microlie.optim.core.strategies import LevenbergMarquardt
        >>> LevenbergMarquardt().converged(1.0, 0.999999, 0.1)
        'absolute cost decrease 1e-06 below abs_tol'
        >>> LevenbergMarquardt(abs_tol=0.0).converged(1.0, 0.5, 0.1) is None
        True
        """
        why = self._decrease_test(old, new)
        if why is None and step_norm <= self.step_tol:
            why = f"step norm {step_norm:.3g} below step_tol"
        return why

    def _final(self, cost: float, predicted: float) -> bool:
        """Whether a step whose model decrease is ``predicted`` would likely end the run (then
        its trial point is not worth linearising in advance)."""
        return self._decrease_test(cost, cost - predicted) is not None

    def _within(self, old: float, new: float) -> bool:
        """A cost change (either sign) no larger than the tolerances: a minimum to rounding."""
        return abs(new - old) <= max(self.abs_tol, self.rel_tol * old)

    def _at_minimum(self, cost: float, first_cost: float, first_pred: float, stop: str
                    ) -> tuple[str, str]:
        """Whether a run that found no decrease from ``cost`` stopped at a minimum (to
        rounding): the first (least damped) trial changed the cost, or its model predicted a
        decrease, by no more than the tolerances. Else it failed: the linearisation does not
        describe the cost."""
        if self._within(cost, first_cost) or self._final(cost, first_pred):
            return "convergence", (
                f"no step decreases the cost; the first changed it by {first_cost - cost:.3g} "
                f"with a predicted decrease of {first_pred:.3g}, within abs_tol/rel_tol ({stop})")
        return "failure", (f"{stop}: the first step changed it by {first_cost - cost:.3g} where "
                           f"its model predicted a decrease of {first_pred:.3g}")


class LevenbergMarquardt(_GTSAMRules):
    """Levenberg-Marquardt with GTSAM's rules (``LevenbergMarquardtParams()`` defaults).

    Each iteration solves ``(H + lambda D) dx = -g`` from the least damping: a step that
    decreases the cost is accepted and ``lambda`` divided by ``lambda_factor`` (not below
    ``lambda_min``); otherwise ``lambda`` is multiplied by ``lambda_factor`` and the system
    solved again, in the same iteration. The run stops when ``lambda`` exceeds
    ``lambda_max`` ("failure", or "convergence" when the first trial's change or its model's
    predicted decrease is within the tolerances: a minimum to rounding), or after an accepted
    step by GTSAM's tests: cost below ``cost_tol``, absolute decrease below ``abs_tol``,
    relative decrease below ``rel_tol``, step norm below ``step_tol``. An iteration is counted
    only when it takes a step.

    The damping matrix ``D`` (``damping``):

    * ``"identity"``: ``D = I``, from ``lambda = 1e-5`` (GTSAM's default). It depends on the
      units: ``lambda`` changes coordinate ``k``'s curvature by ``lambda / H_kk``, and with
      translations in micrometres ``H_kk`` is ``1e-12`` of its value in metres: the damping
      swamps it, and LM stops far from the minimum (M3500: 1,213,782.6 instead of 68.957)
      while reporting convergence.
    * ``"diagonal"``: ``D = diag(H)`` (Marquardt; a zero entry, a coordinate that no factor
      constrains and whose gradient is zero, is taken as 1), from ``lambda = 1e-12``.
      Rescaling a coordinate rescales its row and column of ``H`` and ``D`` alike, so the
      iterates do not depend on the units. The small start matters: a pose chain's softest
      modes have eigenvalues near ``1e-7`` of the diagonal, and ``lambda = 1e-5`` would damp
      them (manhattan: 21 iterations against 5).
    * ``"auto"`` (default): the identity where it is negligible, else ``diag(H)``. A problem
      with reprojection factors and landmarks (bundle adjustment:
      :func:`~microlie.optim.core.landmarks.bundle_landmarks`) uses ``diag(H)`` throughout
      from ``lambda = 1e-4``, as Ceres does (:data:`BUNDLE_LAMBDA`): with the identity first a
      run stopped in a flat valley (the free gauge, camera coordinates scaled orders of
      magnitude apart) at an iteration that rounding decided (problem-49: 13344.62 or 13356.5,
      and 9.2e-4 apart between the NumPy and device engines), and from ``1e-12`` the steps of
      a mixed graph (reprojections, stiff odometry) stalled far from its minimum. Otherwise
      the run starts with the identity when ``lambda_initial < stall_ratio * min_k H_kk`` at the
      start (the file's units are ones in which GTSAM's default barely touches any
      coordinate: then the iterates are GTSAM's), else with ``diag(H)``. A stop with the
      identity (a decrease test, or ``lambda`` above ``lambda_max``) whose ``lambda`` was not
      below ``stall_ratio * min_k H_kk`` is not trusted either: the run switches to
      ``diag(H)`` there and goes on. The message of a run that used ``diag(H)`` says so.

    Parameters
    ----------
    lambda_initial : float, optional
        The damping at the start (default ``1e-5`` with the identity, ``1e-12`` with
        ``diag(H)``, ``1e-4`` with ``"auto"`` on a bundle adjustment).
    lambda_factor : float
        Its growth after a rejected step and its decrease after an accepted one (> 1).
    lambda_max, lambda_min : float
        Its bounds (above ``lambda_max`` the run stops).
    damping : {"auto", "identity", "diagonal"}
        The damping matrix ``D`` (above).
    stall_ratio : float
        ``"auto"``'s bound on ``lambda / H_kk`` for the identity, in ``(0, 1)``.
    rel_tol, abs_tol, cost_tol, step_tol : float
        GTSAM's stopping tests.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.core.strategies import LevenbergMarquardt
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.5])))
    >>> res = g.optimize(solver=LevenbergMarquardt(lambda_initial=1e-3, abs_tol=0.0))
    >>> res.solver, res.converged, res.final_cost < 1e-20
    ('lm', True, True)
    >>> g.optimize(solver="lm", damping="diagonal", abs_tol=0.0).final_cost < 1e-20
    True
    """

    name = "lm"

    def __init__(self, lambda_initial: float | None = None, lambda_factor: float = 10.0,
                 lambda_max: float = 1e5, lambda_min: float = 0.0, damping: str = "auto", *,
                 stall_ratio: float = 1e-3, rel_tol: float = 1e-5, abs_tol: float = 1e-5,
                 cost_tol: float = 0.0, step_tol: float = 0.0) -> None:
        super().__init__(rel_tol, abs_tol, cost_tol, step_tol)
        self.lambda_initial = None if lambda_initial is None else \
            _positive("lambda_initial", lambda_initial, zero=True)
        self.lambda_factor = float(lambda_factor)
        if not self.lambda_factor > 1.0:
            raise ValueError(f"lambda_factor must be > 1, got {lambda_factor!r}")
        self.lambda_max = _positive("lambda_max", lambda_max)
        self.lambda_min = _positive("lambda_min", lambda_min, zero=True)
        if damping not in DAMPINGS:
            raise ValueError(f"damping must be one of {', '.join(map(repr, DAMPINGS))}, got "
                             f"{damping!r}")
        self.damping = damping
        self.stall_ratio = float(stall_ratio)
        if not 0.0 < self.stall_ratio < 1.0:
            raise ValueError(f"stall_ratio must be in (0, 1), got {stall_ratio!r}")
        self._diagonal = damping == "diagonal"  # the damping in use: diag(H), else I
        self._bundle = False                    # "auto" on a bundle adjustment
        self._why: str | None = None            # why "auto" uses diag(H)
        self._stalled = False                   # the identity was not negligible
        self._lam = self._first_lambda()

    def _options(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items() if not k.startswith("_")}

    def _first_lambda(self) -> float:
        if self.lambda_initial is not None:
            return self.lambda_initial
        if self._bundle:
            return BUNDLE_LAMBDA
        return 1e-12 if self._diagonal else 1e-5

    def start(self, s: SolveState) -> None:
        self._diagonal, self._why, self._stalled = self.damping == "diagonal", None, False
        self._bundle = self.damping == "auto" and bool(bundle_landmarks(s.problem))
        if self._bundle:
            self._diagonal = True
            self._why = "damping auto: diag(H), as the problem has landmarks (bundle adjustment)"
        elif self.damping == "auto":
            lam = self._first_lambda()
            small = _smallest_positive(s.diagonal())
            if not lam < self.stall_ratio * small:
                self._diagonal = True
                self._why = (f"damping auto: diag(H), as lambda {lam:.3g} is not below "
                             f"stall_ratio x the smallest curvature {small:.3g}")
        self._lam = self._first_lambda()

    def tr_radius(self) -> float:
        return 1.0 / self._lam if self._lam > 0 else math.inf

    def _switch(self) -> bool:
        """``"auto"`` at a stop of the identity that is not trusted: go on with ``diag(H)``."""
        if self.damping != "auto" or self._diagonal or not self._stalled:
            return False
        self._diagonal, self._stalled = True, False
        self._lam = self._first_lambda()
        self._why = ("damping auto: switched from I to diag(H) where the identity stopped "
                     "with lambda not below stall_ratio x the smallest curvature")
        return True

    def converged(self, old: float, new: float, step_norm: float) -> str | None:
        why = super().converged(old, new, step_norm)
        if why is not None and self._switch():
            return None
        return f"{why} ({self._why})" if why is not None and self._why else why

    def iterate(self, s: SolveState) -> Outcome:
        dg = s.diagonal()  # the undamped diagonal (a copy)
        while True:
            out = self._iterate(s, dg)
            if out.stop is None or out.accepted or not self._switch():
                return out

    def _iterate(self, s: SolveState, dg: np.ndarray) -> Outcome:
        watch = self.damping == "auto" and not self._diagonal
        damp: np.ndarray | float = np.where(dg > 0, dg, 1.0) if self._diagonal else 1.0
        bound = self.stall_ratio * _smallest_positive(dg) if watch else 0.0
        first: tuple[float, float] | None = None  # the first trial: cost, prediction
        solves = 0
        bad = None
        cur = s.robust_cost
        lam0 = self._lam  # the least damping of this iteration
        while True:
            lam = self._lam
            solves += 1
            dx = s.solve(lam * damp, diagonal=dg)
            if dx is not None:
                # the model's decrease: (H + lam D) dx = -g gives
                # -(g.dx + dx.H dx / 2) = (lam dx.D dx - g.dx) / 2
                pred = 0.5 * (lam * dot(dx, damp * dx) - dot(s.lin.grad, dx))
                trial = s.trial(dx, keep=solves == 1 and not self._final(cur, pred))
                if trial.robust_cost < cur:
                    self._stalled = watch and not lam < bound
                    self._lam = max(lam / self.lambda_factor, self.lambda_min)
                    return Outcome(True, solves, self._lam, self.tr_radius(), trial, dx, pred,
                                   bad_trial=bad)
                if trial.robust_cost == np.inf:
                    bad = trial.states
                if first is None:
                    first = (trial.robust_cost, pred)
            self._lam = lam * self.lambda_factor
            if self._lam > self.lambda_max:
                self._stalled = watch and not lam0 < bound  # the least damped trial's
                stop = f"lambda exceeded {self.lambda_max:g} without decreasing the cost"
                if self._why and not self._stalled:
                    stop += f" ({self._why})"
                if first is not None:
                    end = self._at_minimum(cur, *first, stop)
                else:
                    end = ("failure",
                           stop + " (the damped system was singular at every lambda)")
                return Outcome(False, solves, self._lam, self.tr_radius(), stop=end,
                               bad_trial=bad)


def _smallest_positive(d: np.ndarray) -> float:
    """The smallest positive entry of ``d`` (1 when none is)."""
    pos = d[d > 0]
    return float(pos.min()) if pos.size else 1.0


class GaussNewton(_GTSAMRules):
    """Gauss-Newton: the undamped step ``H dx = -g``, accepted if it decreases the cost.

    A step that does not decrease the cost ends the run: "convergence" when its change is
    within the tolerances (a minimum to rounding), "failure" otherwise. After an accepted step
    GTSAM's tests (as :class:`LevenbergMarquardt`). A singular ``H`` (a gauge freedom, an
    unobservable variable) raises :class:`~microlie.optim.SingularSystemError` naming the
    variable.

    Parameters
    ----------
    rel_tol, abs_tol, cost_tol, step_tol : float
        GTSAM's stopping tests.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.core.strategies import GaussNewton
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.5])))
    >>> g.optimize(solver=GaussNewton(abs_tol=0.0)).final_cost < 1e-20
    True
    """

    name = "gn"

    def __init__(self, *, rel_tol: float = 1e-5, abs_tol: float = 1e-5, cost_tol: float = 0.0,
                 step_tol: float = 0.0) -> None:
        super().__init__(rel_tol, abs_tol, cost_tol, step_tol)

    def iterate(self, s: SolveState) -> Outcome:
        cur = s.robust_cost
        dx = s.solve(gauss_newton=True)
        assert dx is not None
        pred = -0.5 * dot(s.lin.grad, dx)  # H dx = -g
        trial = s.trial(dx, keep=not self._final(cur, pred))
        if trial.robust_cost < cur:
            return Outcome(True, 1, 0.0, math.nan, trial, dx, pred)
        if self._within(cur, trial.robust_cost):
            end = ("convergence", "the Gauss-Newton step no longer decreases the cost")
            return Outcome(False, 1, 0.0, math.nan, trial, dx, pred, stop=end)
        return Outcome(False, 1, 0.0, math.nan, trial, dx, pred,
                       stop=("failure", "the Gauss-Newton step did not decrease the cost"),
                       bad_trial=trial.states if trial.robust_cost == np.inf else None)


class Dogleg(_GTSAMRules):
    """Powell's dogleg in a trust region (GTSAM's ``DoglegOptimizer``-like).

    The Gauss-Newton step ``H dx = -g`` (solved once per iteration) if it fits in the radius;
    else the steepest-descent (Cauchy) step ``-(g.g / g.H g) g`` cut to the radius; else the
    point of the segment between them at the radius. With ``rho`` = actual over predicted
    decrease: ``rho > 0.75`` grows the radius to at least ``3 |dx|``, ``rho < 0.25`` shrinks it
    to ``|dx| / 2``. A step that decreases the cost is accepted; otherwise the iteration tries
    the smaller radius, and the run stops when the radius falls below
    ``1e-12 (1 + |x|)`` ("failure", or "convergence" at a minimum to rounding, as
    :class:`LevenbergMarquardt`). GTSAM's tests after an accepted step.

    Parameters
    ----------
    radius_initial : float
        The trust radius at the start.
    rel_tol, abs_tol, cost_tol, step_tol : float
        GTSAM's stopping tests.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.core.strategies import Dogleg
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.5])))
    >>> g.optimize(solver=Dogleg(radius_initial=0.5, abs_tol=0.0)).final_cost < 1e-20
    True
    """

    name = "dogleg"

    def __init__(self, radius_initial: float = 1.0, *, rel_tol: float = 1e-5,
                 abs_tol: float = 1e-5, cost_tol: float = 0.0, step_tol: float = 0.0) -> None:
        super().__init__(rel_tol, abs_tol, cost_tol, step_tol)
        self.radius_initial = _positive("radius_initial", radius_initial)
        self._radius = self.radius_initial

    def _options(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items() if not k.startswith("_")}

    def start(self, s: SolveState) -> None:
        self._radius = self.radius_initial

    def tr_radius(self) -> float:
        return self._radius

    def iterate(self, s: SolveState) -> Outcome:
        cur = s.robust_cost
        gn_dx = None
        first = True
        first_trial = (math.nan, math.nan)
        g = s.lin.grad
        H = s.hessian()
        Hg = H @ g
        gHg = dot(g, Hg)
        sd = -(dot(g, g) / gHg) * g if gHg > 0 else -g
        solves = 0
        bad = None
        while True:
            if gn_dx is None:
                solves += 1
                gn_dx = s.solve(gauss_newton=True)
                assert gn_dx is not None
            dx = _dogleg_step(gn_dx, sd, self._radius)
            pred = -(dot(g, dx) + 0.5 * dot(dx, H @ dx))
            trial = s.trial(dx, keep=first and not self._final(cur, pred))
            actual = cur - trial.robust_cost
            rho = actual / pred if pred > 0 else -1.0
            step = norm(dx)
            if rho > 0.75:
                self._radius = max(self._radius, 3.0 * step)
            elif rho < 0.25:
                self._radius = 0.5 * step if step > 0 else 0.5 * self._radius
            if actual > 0:
                return Outcome(True, solves, self._radius, self._radius, trial, dx, pred,
                               bad_trial=bad)
            if trial.robust_cost == np.inf:
                bad = trial.states
            if first:
                first_trial = (trial.robust_cost, pred)
            first = False
            if self._radius < 1e-12 * (1.0 + norm(_vec(s.states))):
                end = self._at_minimum(cur, *first_trial,
                                       "trust region collapsed without decreasing the cost")
                return Outcome(False, solves, self._radius, self._radius, trial, dx, pred,
                               stop=end, bad_trial=bad)


def _vec(states: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([s.ravel() for s in states]) if states else np.zeros(0)


def _dogleg_step(gn: np.ndarray, sd: np.ndarray, radius: float) -> np.ndarray:
    ngn = norm(gn)
    if ngn <= radius:
        return gn
    nsd = norm(sd)
    if nsd >= radius:
        return sd * (radius / nsd)
    d = gn - sd
    a, b, c = dot(d, d), 2.0 * dot(sd, d), nsd * nsd - radius * radius
    tau = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)
    return sd + tau * d


class TrustRegion(Strategy):
    """Levenberg-Marquardt with Ceres' rules (``TrustRegionMinimizer`` with
    ``LevenbergMarquardtStrategy``, Ceres' default options), so that iteration counts compare
    with Ceres'.

    * Jacobi scaling: the columns scaled by ``s = 1 / (1 + sqrt(diag H))`` computed at the
      first linearisation and kept (applied exactly as the equivalent damping of the unscaled
      system: solving ``(S H S + D_s) y = -S g``, ``dx = S y``, is solving
      ``(H + S^-1 D_s S^-1) dx = -g``).
    * Damping: ``(H + D / radius) dx = -g`` with ``D = clamp(diag(S H S), min_diagonal,
      max_diagonal) / s^2``; the radius starts at ``radius_initial``.
    * Step quality ``rho`` = actual decrease over the model's ``-(g.dx + dx.H dx / 2)``
      (Ceres' ``-(J dx).(e + J dx / 2)``). A step is accepted when
      ``rho > min_relative_decrease``; then ``radius /= max(1/3, 1 - (2 rho - 1)^3)`` (at most
      ``max_radius``); otherwise ``radius /= 2, 4, 8, ...`` (doubling while rejections run).
      A singular system or a model that predicts no decrease is a rejected try.
    * Stops (Ceres' tests): before an iteration, gradient max-norm ``<= gradient_tolerance``
      or ``radius <= min_radius``; at a candidate (the step is then not taken),
      ``|dx| <= parameter_tolerance (|x| + parameter_tolerance)`` (from the first accepted
      step on; ``|x|`` from :meth:`SolveState.state_norm`) or ``|cost change| <=
      function_tolerance cost``; ``max_iter`` tries. Every try, accepted or rejected, is an
      iteration, except one that ends the run at a candidate (Ceres' count: it does not list
      that one; ``Result.accepted_steps`` counts the accepted tries).

    Termination is stricter than Ceres': "convergence" for the gradient test, and for the
    parameter and function tests and the radius floor when the candidate decreased the cost,
    was the first try from the current point, or the first try's model predicted a decrease
    within ``function_tolerance``; otherwise "failure" (the steps of a shrinking radius change
    the cost little only because they are short: Ceres reports CONVERGENCE there).

    Parameters
    ----------
    radius_initial : float
        The trust radius at the start (``1 / mu`` in Ceres' terms).
    function_tolerance, gradient_tolerance, parameter_tolerance : float
        Ceres' convergence tests.
    min_relative_decrease : float
        The ``rho`` a step needs to be accepted.
    max_radius, min_radius : float
        The radius bounds (below ``min_radius`` the run stops).
    min_diagonal, max_diagonal : float
        The clamp of the scaled LM diagonal.
    jacobi_scaling : bool
        Scale the columns as Ceres does (``False``: ``s = 1``).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.core.strategies import TrustRegion
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.5])))
    >>> res = g.optimize(solver=TrustRegion())
    >>> res.solver, res.converged, res.final_cost < 1e-12
    ('trust-region', True, True)
    """

    name = "trust-region"
    counts_rejected = True

    def __init__(self, radius_initial: float = 1e4, *, function_tolerance: float = 1e-6,
                 gradient_tolerance: float = 1e-10, parameter_tolerance: float = 1e-8,
                 min_relative_decrease: float = 1e-3, max_radius: float = 1e16,
                 min_radius: float = 1e-32, min_diagonal: float = 1e-6,
                 max_diagonal: float = 1e32, jacobi_scaling: bool = True) -> None:
        self.radius_initial = _positive("radius_initial", radius_initial)
        self.function_tolerance = _positive("function_tolerance", function_tolerance, True)
        self.gradient_tolerance = _positive("gradient_tolerance", gradient_tolerance, True)
        self.parameter_tolerance = _positive("parameter_tolerance", parameter_tolerance, True)
        self.min_relative_decrease = float(min_relative_decrease)
        self.max_radius = _positive("max_radius", max_radius)
        self.min_radius = _positive("min_radius", min_radius, True)
        self.min_diagonal = _positive("min_diagonal", min_diagonal)
        self.max_diagonal = _positive("max_diagonal", max_diagonal)
        if self.max_diagonal < self.min_diagonal:
            raise ValueError(f"max_diagonal ({max_diagonal!r}) must be >= min_diagonal "
                             f"({min_diagonal!r})")
        if self.max_radius < self.radius_initial:
            raise ValueError(f"radius_initial ({radius_initial!r}) must be <= max_radius "
                             f"({max_radius!r})")
        self.jacobi_scaling = bool(jacobi_scaling)
        self._radius = self.radius_initial
        self._decrease = 2.0
        self._scale2: np.ndarray | None = None     # s^2 of the Jacobi scaling
        self._lm_diag: tuple[Any, np.ndarray, np.ndarray] | None = None
        self._x_norm = -1.0                          # no parameter test before a step
        self._first_pred: float | None = None        # the first try's model decrease
        self._tries = 0                              # tries from the current point

    def _options(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items() if not k.startswith("_")}

    def start(self, s: SolveState) -> None:
        self._radius, self._decrease = self.radius_initial, 2.0
        dg = s.diagonal()
        sc = 1.0 / (1.0 + np.sqrt(np.maximum(dg, 0.0))) if self.jacobi_scaling else \
            np.ones_like(dg)
        self._scale2 = sc * sc
        self._lm_diag = None
        self._x_norm, self._first_pred, self._tries = -1.0, None, 0

    def tr_radius(self) -> float:
        return self._radius

    def _settled(self, cost: float, cand: float) -> bool:
        """Whether a stop at a candidate that changes the cost little is a convergence."""
        return (cand < cost or self._tries <= 1
                or (self._first_pred is not None
                    and self._first_pred <= self.function_tolerance * cost))

    def stop_before(self, s: SolveState) -> tuple[str, str] | None:
        gmax = s.gradient_max()
        if gmax <= self.gradient_tolerance:
            return "convergence", f"gradient tolerance reached ({gmax:.3e})"
        if self._radius <= self.min_radius:
            if self._settled(s.robust_cost, math.inf):
                return "convergence", "minimum trust region radius reached"
            return "failure", (f"minimum trust region radius reached without decreasing the "
                               f"cost (the first step's model predicted a decrease of "
                               f"{self._first_pred:.3g})")
        return None

    def _reject(self) -> None:
        self._radius /= self._decrease
        self._decrease *= 2.0

    def iterate(self, s: SolveState) -> Outcome:
        self._tries += 1
        cost = s.robust_cost
        if self._lm_diag is None or self._lm_diag[0] is not s.lin:
            # the LM diagonal of the scaled Jacobian, clamped as Ceres does, in unscaled units
            # (kept while the point does not change: Ceres reuses it after a rejected step)
            assert self._scale2 is not None
            dg = s.diagonal()
            d = np.clip(dg * self._scale2, self.min_diagonal, self.max_diagonal) / self._scale2
            self._lm_diag = (s.lin, dg, d)
        _, dg, d = self._lm_diag
        radius = self._radius
        dx = s.solve(d / radius, diagonal=dg)
        pred = s.model_decrease(dx) if dx is not None else math.nan
        if dx is None or not pred > 0.0:
            # an invalid step (Ceres' StepIsInvalid): shrink the radius, try again
            self._reject()
            return Outcome(False, 1, self._radius, self._radius, None, dx, pred)
        if self._first_pred is None:
            self._first_pred = pred
        trial = s.trial(dx, keep=True)
        cand = trial.robust_cost
        step_norm = norm(dx)
        stop = None
        if step_norm <= self.parameter_tolerance * (self._x_norm + self.parameter_tolerance):
            stop = "parameter tolerance reached"
        elif abs(cost - cand) <= self.function_tolerance * cost:
            stop = (f"function tolerance reached (|cost change|/cost = "
                    f"{abs(cost - cand) / cost:.3e})")
        bad = trial.states if cand == np.inf else None
        if stop is not None:
            if self._settled(cost, cand):
                end = ("convergence", stop)
            else:
                end = ("failure", f"{stop} after {self._tries - 1} rejected steps, without "
                                  f"decreasing the cost (the first step's model predicted a "
                                  f"decrease of {self._first_pred:.3g})")
            return Outcome(False, 1, self._radius, self._radius, trial, dx, pred, stop=end,
                           bad_trial=bad)
        rho = (cost - cand) / pred
        if rho > self.min_relative_decrease:
            self._radius = min(self.max_radius,
                               radius / max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
            self._decrease = 2.0
            self._first_pred, self._tries = None, 0
            return Outcome(True, 1, self._radius, self._radius, trial, dx, pred)
        self._reject()
        return Outcome(False, 1, self._radius, self._radius, trial, dx, pred, bad_trial=bad)

    def accepted(self, s: SolveState) -> None:
        """After the loop moved to an accepted point: its norm for the parameter test.

        Parameters
        ----------
        s : SolveState
            The solve, at the new point.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.core.strategies import SolveState, TrustRegion
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.array([[3.0, 4.0]]))
        >>> _ = g.add(PriorFactor(x, 0, np.zeros((1, 2))))
        >>> p = g.problem()
        >>> st = [v.initial for v in p.variables]
        >>> s = SolveState(p, p.analysed("dense"), st, p.linearize(st), {})
        >>> tr = TrustRegion().started(s)
        >>> tr.accepted(s)
        """
        self._x_norm = s.state_norm()


#: The strategies by name (``g.optimize(solver=name)``; ``Result.solver``).
STRATEGIES: dict[str, type[Strategy]] = {
    "lm": LevenbergMarquardt,
    "gn": GaussNewton,
    "dogleg": Dogleg,
    "trust-region": TrustRegion,
}


def make_strategy(solver: str | Strategy, **options: Any) -> Strategy:
    """A strategy by name with its options, or the given instance.

    Parameters
    ----------
    solver : str or Strategy
        A name of :data:`STRATEGIES` (``"lm"``, ``"gn"``, ``"dogleg"``, ``"trust-region"``)
        or an instance (then no options may be given).
    **options
        The strategy's constructor parameters.

    Returns
    -------
    Strategy

    Raises
    ------
    ValueError
        An unknown name.
    TypeError
        An option the strategy does not take, or options with an instance.

    Examples
    --------
    >>> from microlie.optim.core.strategies import make_strategy
    >>> make_strategy("dogleg", radius_initial=2.0).radius_initial
    2.0
    >>> make_strategy("trust-region").name
    'trust-region'
    """
    if isinstance(solver, Strategy):
        if options:
            raise TypeError(f"options {sorted(options)} go to the strategy's constructor, "
                            f"not with an instance ({type(solver).__name__})")
        return solver
    if not isinstance(solver, str) or solver not in STRATEGIES:
        raise ValueError(f"solver must be one of {', '.join(repr(k) for k in STRATEGIES)} or a "
                         f"Strategy instance, got {solver!r}")
    cls = STRATEGIES[solver]
    takes = inspect.signature(cls).parameters
    unknown = sorted(k for k in options if k not in takes)
    if unknown:
        raise TypeError(f"solver {solver!r} ({cls.__name__}) takes no option "
                        f"{', '.join(map(repr, unknown))}; its options: {', '.join(takes)}")
    return cls(**options)
