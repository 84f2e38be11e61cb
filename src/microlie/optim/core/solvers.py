"""The one solve loop: every strategy, one :class:`Result`, one :class:`IterationRecord`.

:func:`solve` linearises the problem at the start (the whitened, robustly corrected normal
equations ``H dx = -g``, ``H = sum A^T A``, ``g = sum A^T e``, assembled in the problem's fixed
pattern), then repeats: the strategy's tests before an iteration
(:meth:`~microlie.optim.core.strategies.Strategy.stop_before`), ``max_iter``, one iteration of
the strategy (:meth:`~microlie.optim.core.strategies.Strategy.iterate`: damped solves and trial
points ``X Exp(dx)`` per variable), one record, and after an accepted step the strategy's tests
(:meth:`~microlie.optim.core.strategies.Strategy.converged`) and the linearisation at the new
point. The strategies and their rules are in :mod:`microlie.optim.core.strategies`
(``"lm"``: GTSAM's Levenberg-Marquardt, the default; ``"gn"``; ``"dogleg"``;
``"trust-region"``: Ceres' Levenberg-Marquardt). Every strategy keeps the best point: the
returned values never have a higher (robust) cost than the start.

``Result.converged`` means that one of the strategy's convergence tests passed
(``termination="convergence"``); ``max_iter`` is ``"no_convergence"`` (usable, as Ceres'
NO_CONVERGENCE). A run that cannot decrease the cost (LM's ``lambda`` above ``lambda_max``,
the dogleg radius collapsing, a Gauss-Newton step that increases it, ...) is ``"failure"`` with
the reason in ``message``, unless the tries changed the cost by no more than the tolerances
(a minimum to rounding: ``"convergence"``; each strategy's docstring says when). A non-finite
cost or linearisation at the start or at an accepted point raises ``ValueError`` naming the
factor; a non-finite cost at a trial point rejects that step (as Ceres does), and is named in
the message if the run then fails.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..linalg.linear import LinearSolver
from .problem import Linearization, NonFiniteError, Problem
from .strategies import Outcome, SolveState, Strategy, make_strategy, norm
from .variables import Values

__all__ = ["Result", "IterationRecord", "solve"]


@dataclass(frozen=True)
class IterationRecord:
    """One iteration of a solve (Ceres' iteration-table columns).

    Attributes
    ----------
    iteration : int
        Its number (1-based).
    cost : float
        The robust cost after it (the current point's: unchanged by a rejected try).
    step_norm : float
        The norm of the step taken (of the last one tried if none was taken; 0 if none).
    damping : float
        ``lambda`` for LM, the trust radius for dogleg and trust-region, 0 for GN, after the
        iteration's update.
    time_s : float
        Time since the start, seconds.
    solves : int
        The linear solves it took.
    cost_change : float
        The cost before it minus the cost at the (last) trial point: the decrease of an
        accepted step, negative or small for a rejected one (NaN: no trial point).
    gradient_max : float
        The max-norm of the gradient ``g`` at the point after it (NaN when that point was not
        linearised: the run ended there).
    tr_ratio : float
        Actual over predicted decrease of the (last) trial (NaN: none).
    tr_radius : float
        Ceres' column: ``1 / lambda`` for LM, the trust radius for dogleg and trust-region,
        NaN for GN (after the update).
    accepted : bool
        Whether a step was taken.
    iter_time_s : float
        The iteration's time (its linearisation included), seconds.

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> _ = g.add(PriorFactor(x, 0, SE2.exp([1.0, 2.0, 0.5])))
    >>> res = g.optimize()
    >>> rec = res.history[0]
    >>> rec.iteration, rec.solves >= 1, rec.accepted
    (1, True, True)
    """

    iteration: int
    cost: float
    step_norm: float
    damping: float
    time_s: float
    solves: int
    cost_change: float = math.nan
    gradient_max: float = math.nan
    tr_ratio: float = math.nan
    tr_radius: float = math.nan
    accepted: bool = True
    iter_time_s: float = math.nan


@dataclass
class Result:
    """The outcome of :meth:`FactorGraph.optimize` (every strategy).

    Attributes
    ----------
    values : Values
        The optimised values.
    initial_cost, final_cost : float
        ``0.5 * sum r^T Omega r`` without robust losses (GTSAM's error).
    initial_robust_cost, final_robust_cost : float
        The minimised ``0.5 * sum rho(r^T Omega r)`` (equal to the plain ones without losses).
    iterations : int
        Iterations as the strategy counts them (what ``max_iter`` limits): accepted ones for
        the GTSAM-rule strategies (``"lm"``, ``"gn"``, ``"dogleg"``: an iteration that takes
        no step ends the run); for ``"trust-region"`` every try, accepted or rejected, as
        Ceres counts. The try that ends a run without a step (a failed LM iteration, Ceres'
        function or parameter tolerance met at a candidate) is recorded in ``history`` but not
        counted (Ceres does not list it either).
    converged : bool
        Whether a convergence test was met: ``termination == "convergence"``.
    message : str
        Why the solver stopped.
    termination : {"convergence", "no_convergence", "failure"}
        As Ceres' termination types: a convergence test met; ``max_iter`` reached (the values
        are usable); the cost could not be decreased (the values are the best point found,
        not a solution).
    history : list of IterationRecord
        One record per iteration, and last the uncounted one of a run that stopped without a
        step.
    time_s : float
        Solve time, seconds (graph construction excluded; the linear solver's symbolic analysis
        included on the first solve of a problem only: it is kept with the problem).
    solver, linear_solver : str
        What ran (the strategy's registry name).
    timings : dict
        ``time_s`` split into linearize / assemble / factorize / solve / cost / retract /
        other.
    gauge_fixed : list
        ``(handle, index)`` of the variables held by ``gauge="fix_first"``.
    accepted_steps : int
        Steps taken (Ceres' ``num_successful_steps`` is this plus one: it counts iteration 0).
    strategy : Strategy or None
        The strategy instance with its options.
    weights, inliers : list of numpy.ndarray or None
        With graduated non-convexity (``optimize(robust="gnc-tls")``,
        :mod:`microlie.optim.core.gnc`): per factor batch, in graph order, the final weights
        in ``[0, 1]`` and whether each factor was judged an inlier; ``None`` otherwise.
    outer_iterations : int
        GNC's weight updates, each followed by a weighted solve (0 without GNC).
    ties : list of AnswerTie or None
        GNC-TLS on a pose graph: the pieces of the answer that a rejected edge could hold
        instead of the accepted one at the same TLS objective
        (:func:`~microlie.optim.core.gnc_ties.answer_ties`; empty: the answer is the only
        optimum of its kind); ``None`` otherwise.

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> _ = g.add(PriorFactor(x, 0, SE2.exp([1.0, 2.0, 0.5])))
    >>> res = g.optimize()
    >>> res.converged, res.termination, round(res.final_cost, 12), res.accepted_steps
    (True, 'convergence', 0.0, 2)
    """

    values: Values
    initial_cost: float
    final_cost: float
    initial_robust_cost: float
    final_robust_cost: float
    iterations: int
    converged: bool
    message: str
    termination: str
    history: list[IterationRecord]
    time_s: float
    solver: str
    linear_solver: str
    timings: dict = field(default_factory=dict)
    gauge_fixed: list = field(default_factory=list)
    accepted_steps: int = 0
    strategy: Strategy | None = field(default=None, repr=False)
    weights: list[np.ndarray] | None = field(default=None, repr=False)
    inliers: list[np.ndarray] | None = field(default=None, repr=False)
    outer_iterations: int = 0
    ties: list | None = field(default=None, repr=False)

    def __repr__(self) -> str:
        n = sum(len(h) for h in self.values)
        return (f"Result({self.solver}, {self.linear_solver}: cost {self.initial_cost:.10g} -> "
                f"{self.final_cost:.10g} in {self.iterations} iterations, {n} variables, "
                f"{self.time_s * 1e3:.1f} ms, {self.termination}: {self.message})")


def solve(problem: Problem, states: list[np.ndarray], strategy: str | Strategy = "lm", *,
          linear_solver: str | LinearSolver = "auto", eliminate: Any = None,
          max_iter: int = 100, verbose: bool | None = None) -> Result:
    """Run a strategy on a problem from ``states`` (what :meth:`FactorGraph.optimize` calls).

    Parameters
    ----------
    problem : Problem
        The linearisable problem.
    states : list of numpy.ndarray
        The starting parameters of each variable batch.
    strategy : str or Strategy
        A name of :data:`~microlie.optim.core.strategies.STRATEGIES` (default options) or an
        instance.
    linear_solver : str or LinearSolver
        See :func:`~microlie.optim.make_solver`; ``"schur"``: Schur elimination
        (:class:`~microlie.optim.linalg.schur_solver.SchurSolver`).
    eliminate : Variables or sequence of Variables, optional
        The batches ``"schur"`` eliminates (default: the landmark-like ones).
    max_iter : int
        Iteration limit (as the strategy counts iterations, :attr:`Result.iterations`).
    verbose : bool, optional
        Ceres' iteration table on stderr (default: when stderr is a terminal).

    Returns
    -------
    Result

    Notes
    -----
    With ``verbose`` each iteration prints one line of Ceres' table to ``sys.stderr``,
    flushed: ``iter``, ``cost`` (the minimised robust cost after it), ``cost_change``,
    ``|gradient|`` (max-norm at the new point; ``-`` after the last step, which is not
    linearised again), ``|step|``, ``tr_ratio`` (actual over predicted decrease),
    ``tr_radius`` (the trust radius; ``1 / lambda`` for LM, Ceres' meaning; ``-`` for GN),
    ``ls_iter`` (linear solves), ``iter_time`` and ``total_time`` (s): the fields of its
    :class:`IterationRecord`, for every iteration the strategy counts.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.core.solvers import solve
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
    >>> p = g.problem()
    >>> res = solve(p, [v.initial for v in p.variables], "gn")
    >>> res.converged, round(res.final_cost, 12)
    (True, 0.0)
    """
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 0:
        raise ValueError(f"max_iter must be an integer >= 0, got {max_iter!r}")
    strategy = make_strategy(strategy)
    t_start = time.perf_counter()
    tm = {"linearize": 0.0, "assemble": 0.0, "factorize": 0.0, "solve": 0.0, "cost": 0.0,
          "retract": 0.0}
    show = bool(verbose) if verbose is not None else sys.stderr.isatty()
    ls = problem.analysed(linear_solver, eliminate)
    lin = _linearize(problem, states, tm)
    _require_finite(problem, states, lin, "at the start")
    c0, rc0 = lin.cost, lin.robust_cost
    s = SolveState(problem, ls, states, lin, tm)
    run = strategy.started(s)
    history: list[IterationRecord] = []
    message, termination = f"reached max_iter={max_iter}", "no_convergence"
    if problem.size == 0:
        message, termination = "no free variables", "convergence"
    log = _IterationLog(t_start, rc0, s.gradient_max(), run.tr_radius()) \
        if show and problem.size else None
    it = accepted_steps = 0
    t_last = t_start
    while problem.size:
        before = run.stop_before(s)
        if before is not None:
            termination, message = before
            break
        if it >= max_iter:
            break
        it += 1
        old_rc = s.robust_cost
        out = run.iterate(s)
        why = None
        gmax = math.nan
        if out.accepted:
            assert out.trial is not None and out.dx is not None
            accepted_steps += 1
            step_norm = norm(out.dx)
            why = run.converged(old_rc, out.trial.robust_cost, step_norm)
            new_lin = None
            if why is None and out.stop is None:
                new_lin = _linearize(problem, out.trial.states, tm, old=s.lin)
                _require_finite(problem, out.trial.states, new_lin, f"after iteration {it}")
            s.move(out.trial, new_lin)
            run.accepted(s)
            if new_lin is not None:
                gmax = s.gradient_max()
        else:  # a rejected try of trust-region: its step, in its record and Ceres' row
            step_norm = norm(out.dx) if out.dx is not None and run.counts_rejected and \
                out.trial is not None else 0.0
            gmax = s.gradient_max()
        now = time.perf_counter()
        rec = _record(it, s, old_rc, out, step_norm, gmax, now - t_start, now - t_last)
        t_last = now
        history.append(rec)
        counted = out.accepted or (run.counts_rejected and out.stop is None)
        if log is not None and counted:
            log.row(rec)
        if out.stop is not None and not out.accepted:
            termination, message = out.stop
            if termination == "failure" and out.bad_trial is not None:
                where = problem.nonfinite(out.bad_trial)
                if where:
                    message += f"; trial points had a non-finite cost ({where})"
            if not counted:
                it -= 1
            break
        if why is not None:
            message, termination = why, "convergence"
            break
    total = time.perf_counter() - t_start
    timings = dict(tm)
    timings["other"] = total - sum(timings.values())
    vals = Values(problem.variables, s.states)
    return Result(vals, c0, s.cost, rc0, s.robust_cost, it, termination == "convergence",
                  message, termination, history, total, run.name, ls.name, timings,
                  list(problem.gauge_fixed), accepted_steps, strategy)


def _record(it: int, s: SolveState, old: float, out: Outcome, step_norm: float, gmax: float,
            total: float, iter_time: float) -> IterationRecord:
    """The record of one iteration."""
    if out.trial is None:
        change = math.nan
    else:
        change = old - out.trial.robust_cost  # -inf for a non-finite trial cost
    ratio = change / out.predicted if out.trial is not None and out.predicted > 0 else math.nan
    return IterationRecord(it, s.robust_cost, step_norm, out.damping, total, out.solves,
                           change, gmax, ratio, out.tr_radius, out.accepted, iter_time)


def _require_finite(problem: Problem, states: list[np.ndarray], lin: Any, when: str) -> None:
    """Raise ``ValueError`` naming the factor when the cost or the normal equations are not
    finite (sums first: a cheap test that every entry is finite)."""
    with np.errstate(over="ignore", invalid="ignore"):
        total = lin.robust_cost + lin.cost + float(lin.data.sum()) + float(lin.grad.sum())
    if math.isfinite(total):
        return
    found = problem._nonfinite(states, jacobians=True)
    if found is None:
        if np.isfinite(lin.data).all() and np.isfinite(lin.grad).all() and \
                math.isfinite(lin.cost) and math.isfinite(lin.robust_cost):
            return  # large finite sums only
        raise ValueError(f"the normal equations overflow {when}: scale the noise models down")
    where, fi, row, args = found
    raise NonFiniteError(f"the cost or its linearisation is not finite {when}: {where}; check "
                         f"that factor's measurement, noise model and variable values",
                         fi, row, args)


class _IterationLog:
    """Ceres' iteration table on ``sys.stderr``, one flushed line per iteration (see
    :func:`solve`), from the iteration records."""

    HEADER = (f"{'iter':>4s} {'cost':>13s} {'cost_change':>12s} {'|gradient|':>10s} "
              f"{'|step|':>9s} {'tr_ratio':>10s} {'tr_radius':>10s} {'ls_iter':>8s} "
              f"{'iter_time':>10s} {'total_time':>11s}")

    def __init__(self, t_start: float, cost: float, gmax: float, radius: float) -> None:
        self._print(self.HEADER)
        now = time.perf_counter()
        self.row(IterationRecord(0, cost, 0.0, 0.0, now - t_start, 0, 0.0, gmax, math.nan,
                                 radius, True, now - t_start))

    @staticmethod
    def _print(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    def row(self, r: IterationRecord) -> None:
        """Print one record (a NaN gradient, not evaluated, prints ``-``)."""
        gmax = "-" if math.isnan(r.gradient_max) else f"{r.gradient_max:.2e}"
        self._print(f"{r.iteration:4d} {r.cost:13.6e} {r.cost_change:12.2e} {gmax:>10s} "
                    f"{r.step_norm:9.2e} {_e(r.tr_ratio, 10)} {_e(r.tr_radius, 10)} "
                    f"{r.solves:8d} {r.iter_time_s:10.2e} {r.time_s:11.2e}")


def _e(v: float, w: int) -> str:
    return f"{'-':>{w}s}" if math.isnan(v) else f"{v:{w}.2e}"


def _linearize(problem: Problem, states: list[np.ndarray], tm: dict[str, float],
               old: Linearization | None = None) -> Linearization:
    lin = problem.linearize(states, out=old)
    tm["linearize"] += lin.times["linearize"] + lin.times["products"] + lin.times["compiled"]
    tm["assemble"] += lin.times["assemble"]
    return lin
