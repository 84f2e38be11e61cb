"""Levenberg-Marquardt, Gauss-Newton and Powell's dogleg on a :class:`Problem`.

Every solver works on the whitened, robustly corrected normal equations
``H dx = -g`` (``H = sum A^T A``, ``g = sum A^T e``) assembled in the problem's fixed pattern,
retracts ``X <- X Exp(dx)`` per variable, and keeps the best point: the returned values never
have a higher (robust) cost than the start.

Levenberg-Marquardt follows GTSAM's ``LevenbergMarquardtParams()`` defaults: damping
``H + lambda I`` (or ``lambda diag(H)`` with ``diagonal_damping=True``), ``lambda`` starts at
``1e-5``, is divided by 10 after an accepted step and multiplied by 10 after a rejected one,
and the run stops when ``lambda`` exceeds ``1e5``. Stopping rules (all solvers): relative cost
decrease below ``rel_tol``, absolute decrease below ``abs_tol``, cost below ``cost_tol``, step
norm below ``step_tol``, or ``max_iter`` iterations.

``Result.converged`` means that one of those tests passed (``termination="convergence"``);
``max_iter`` is ``"no_convergence"`` (usable, as Ceres' NO_CONVERGENCE). A run that cannot
decrease the cost (LM's ``lambda`` above ``lambda_max``, the dogleg radius collapsing, a
Gauss-Newton step that increases it) is ``"failure"`` with the reason in ``message``, unless
the first step tried from that point changed the cost by no more than the tolerances or its
model predicted no larger decrease (a minimum to rounding: ``"convergence"``). A non-finite
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

from ..linalg.linear import LinearSolver, SingularSystemError
from .problem import NonFiniteError, Problem
from .variables import Values

__all__ = ["Result", "IterationRecord", "SolverOptions", "solve"]


@dataclass(frozen=True)
class IterationRecord:
    """One accepted (or final rejected) iteration of a solve.

    Attributes
    ----------
    iteration : int
        Its number (1-based).
    cost : float
        The robust cost after it.
    step_norm : float
        The norm of the step.
    damping : float
        ``lambda`` for LM, the trust radius for dogleg, 0 for GN.
    time_s : float
        Time since the start, seconds.
    solves : int
        The linear solves it took.

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> _ = g.add(PriorFactor(x, 0, SE2.exp([1.0, 2.0, 0.5])))
    >>> res = g.optimize()
    >>> rec = res.history[0]
    >>> rec.iteration, rec.solves >= 1
    (1, True)
    """

    iteration: int
    cost: float
    step_norm: float
    damping: float
    time_s: float
    solves: int


@dataclass
class Result:
    """The outcome of :meth:`FactorGraph.optimize`.

    Attributes
    ----------
    values : Values
        The optimised values.
    initial_cost, final_cost : float
        ``0.5 * sum r^T Omega r`` without robust losses (GTSAM's error).
    initial_robust_cost, final_robust_cost : float
        The minimised ``0.5 * sum rho(r^T Omega r)`` (equal to the plain ones without losses).
    iterations : int
        Accepted iterations.
    converged : bool
        Whether a convergence test was met: ``termination == "convergence"``.
    message : str
        Why the solver stopped.
    termination : {"convergence", "no_convergence", "failure"}
        As Ceres' termination types: a convergence test met; ``max_iter`` reached (the values
        are usable); the cost could not be decreased (the values are the best point found,
        not a solution).
    history : list of IterationRecord
        One record per iteration.
    time_s : float
        Solve time, seconds (graph construction excluded; the linear solver's symbolic analysis
        included on the first solve of a problem only: it is kept with the problem).
    solver, linear_solver : str
        What ran.
    timings : dict
        ``time_s`` split into linearise / assemble / factorise / solve / other.
    gauge_fixed : list
        ``(handle, index)`` of the variables held by ``gauge="fix_first"``.

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> _ = g.add(PriorFactor(x, 0, SE2.exp([1.0, 2.0, 0.5])))
    >>> res = g.optimize()
    >>> res.converged, res.termination, round(res.final_cost, 12)
    (True, 'convergence', 0.0)
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

    def __repr__(self) -> str:
        n = sum(len(h) for h in self.values)
        return (f"Result({self.solver}, {self.linear_solver}: cost {self.initial_cost:.10g} -> "
                f"{self.final_cost:.10g} in {self.iterations} iterations, {n} variables, "
                f"{self.time_s * 1e3:.1f} ms, {self.termination}: {self.message})")


@dataclass
class SolverOptions:
    """The options of one solve (the keyword arguments of :meth:`FactorGraph.optimize`).

    Parameters
    ----------
    solver : {"lm", "gn", "dogleg"}
        Levenberg-Marquardt, Gauss-Newton or Powell's dogleg.
    linear_solver : str or LinearSolver
        See :func:`~microlie.optim.make_solver`; ``"schur"``: Schur elimination
        (:class:`~microlie.optim.linalg.schur_solver.SchurSolver`).
    eliminate : Variables or sequence of Variables, optional
        The batches ``"schur"`` eliminates (default: the landmark-like ones).
    max_iter : int
        Iteration limit.
    rel_tol, abs_tol, cost_tol, step_tol : float
        Convergence tests.
    lambda_initial, lambda_factor, lambda_max, lambda_min : float
        LM damping: start, growth factor and bounds.
    diagonal_damping : bool
        Damp with ``diag(H)`` (Marquardt) instead of the identity.
    radius_initial : float
        The dogleg trust radius at the start.
    verbose : bool, optional
        Ceres' iteration table on stderr, one flushed line per iteration (default: when stderr
        is a terminal); see :func:`solve`.

    Examples
    --------
    >>> from microlie.optim.core.solvers import SolverOptions
    >>> SolverOptions(solver="gn").lambda_initial
    1e-05
    """
    solver: str = "lm"
    linear_solver: str | LinearSolver = "auto"
    eliminate: Any = None
    max_iter: int = 100
    rel_tol: float = 1e-5
    abs_tol: float = 1e-5
    cost_tol: float = 0.0
    step_tol: float = 0.0
    lambda_initial: float = 1e-5
    lambda_factor: float = 10.0
    lambda_max: float = 1e5
    lambda_min: float = 0.0
    diagonal_damping: bool = False
    radius_initial: float = 1.0
    verbose: bool | None = None


class _Timer:
    def __init__(self) -> None:
        self.t = {"linearize": 0.0, "assemble": 0.0, "factorize": 0.0, "solve": 0.0,
                  "cost": 0.0, "retract": 0.0}


def _converged(o: SolverOptions, old: float, new: float) -> str | None:
    dec = old - new
    if new <= o.cost_tol:
        return f"cost {new:.6g} below cost_tol"
    if dec >= 0 and dec < o.abs_tol:
        return f"absolute cost decrease {dec:.3g} below abs_tol"
    if dec >= 0 and old > 0 and dec / old < o.rel_tol:
        return f"relative cost decrease {dec / old:.3g} below rel_tol"
    return None


def _final(o: SolverOptions, cost: float, predicted: float) -> bool:
    """Whether a step whose model decrease is ``predicted`` would likely end the run (then its
    trial point is not worth linearising in advance)."""
    return _converged(o, cost, cost - predicted) is not None


def solve(problem: Problem, states: list[np.ndarray], o: SolverOptions) -> Result:
    """Run the chosen solver on a problem from ``states`` (what :meth:`FactorGraph.optimize`
    calls).

    Parameters
    ----------
    problem : Problem
        The linearisable problem.
    states : list of numpy.ndarray
        The starting parameters of each variable batch.
    o : SolverOptions
        The options.

    Returns
    -------
    Result

    Notes
    -----
    With ``o.verbose`` each iteration prints one line of Ceres' table to ``sys.stderr``,
    flushed: ``iter``, ``cost`` (the minimised robust cost after it), ``cost_change``,
    ``|gradient|`` (max-norm at the new point; ``-`` after the last step, which is not
    linearised again), ``|step|``, ``tr_ratio`` (actual over predicted decrease),
    ``tr_radius`` (the dogleg radius; ``1 / lambda`` for LM, Ceres' meaning; ``-`` for GN),
    ``ls_iter`` (linear solves, one per damping trial), ``iter_time`` and ``total_time`` (s).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
    >>> from microlie.optim.core.solvers import SolverOptions, solve
    >>> p = g.problem()
    >>> res = solve(p, [v.initial for v in p.variables], SolverOptions(solver="gn"))
    >>> res.converged, round(res.final_cost, 12)
    (True, 0.0)
    """
    if o.solver not in ("lm", "gn", "dogleg"):
        raise ValueError(f"solver must be 'lm', 'gn' or 'dogleg', got {o.solver!r}")
    t_start = time.perf_counter()
    tm = _Timer()
    show = bool(o.verbose) if o.verbose is not None else sys.stderr.isatty()
    ls = problem.analysed(o.linear_solver, o.eliminate)
    lin = _linearize(problem, states, tm)
    _require_finite(problem, states, lin, "at the start")
    c0, rc0 = lin.cost, lin.robust_cost
    cur, cur_c, cur_rc = states, c0, rc0
    history: list[IterationRecord] = []
    message, termination = f"reached max_iter={o.max_iter}", "no_convergence"
    if problem.size == 0:
        message, termination = "no free variables", "convergence"
    lam = o.lambda_initial
    radius = o.radius_initial
    log = _IterationLog(problem, o, t_start, rc0, lin.grad) if show and problem.size else None
    it = 0
    bad_trial: list[np.ndarray] | None = None  # the last trial point with a non-finite cost
    while problem.size and it < o.max_iter:
        it += 1
        solves = 0
        accepted = False
        stop = None
        at_minimum = False  # the first trial's change (or its model's) is within tolerance
        if o.solver == "lm":
            dg = lin.data[problem.diag_pos]  # the undamped diagonal (a copy)
            first_lm: tuple[float, float] | None = None  # the first trial: cost, prediction
            while True:
                # damp in place and restore the diagonal exactly after the solve (no copy of
                # the whole matrix per trial)
                lin.data[problem.diag_pos] = dg + lam * (np.maximum(dg, 1e-12)
                                                         if o.diagonal_damping else 1.0)
                solves += 1
                try:
                    dx = _factor_solve(ls, lin.data, -lin.grad, tm)
                except SingularSystemError:
                    dx = None
                finally:
                    lin.data[problem.diag_pos] = dg
                if dx is not None:
                    # the model's decrease: (H + lam D) dx = -g gives
                    # -(g.dx + dx.H dx / 2) = (lam dx.D dx - g.dx) / 2
                    damp = np.maximum(dg, 1e-12) if o.diagonal_damping else 1.0
                    pred = 0.5 * (lam * _dot(dx, damp * dx) - _dot(lin.grad, dx))
                    keep = solves == 1 and not _final(o, cur_rc, pred)
                    new, new_c, new_rc = _try(problem, cur, dx, tm, keep=keep)
                    if new_rc < cur_rc:
                        accepted = True
                        lam = max(lam / o.lambda_factor, o.lambda_min)
                        break
                    if new_rc == np.inf:
                        bad_trial = new
                    if first_lm is None:
                        first_lm = (new_rc, pred)
                lam *= o.lambda_factor
                if lam > o.lambda_max:
                    stop = f"lambda exceeded {o.lambda_max:g} without decreasing the cost"
                    if first_lm is not None:
                        at_minimum, stop = _at_minimum(o, cur_rc, *first_lm, stop)
                    else:
                        stop += " (the damped system was singular at every lambda)"
                    break
        elif o.solver == "gn":
            solves += 1
            dx = _factor_solve(ls, lin.data, -lin.grad, tm, gn=problem)
            keep = not _final(o, cur_rc, -0.5 * _dot(lin.grad, dx))  # H dx = -g
            new, new_c, new_rc = _try(problem, cur, dx, tm, keep=keep)
            if new_rc < cur_rc:
                accepted = True
            elif _within(o, cur_rc, new_rc):
                at_minimum = True
                stop = "the Gauss-Newton step no longer decreases the cost"
            else:
                if new_rc == np.inf:
                    bad_trial = new
                stop = "the Gauss-Newton step did not decrease the cost"
        else:  # dogleg
            gn_dx = None
            first = True
            g = lin.grad
            H = problem.matrix(lin.data)
            Hg = H @ g
            gHg = _dot(g, Hg)
            sd = -(_dot(g, g) / gHg) * g if gHg > 0 else -g
            while True:
                if gn_dx is None:
                    solves += 1
                    gn_dx = _factor_solve(ls, lin.data, -g, tm, gn=problem)
                dx = _dogleg_step(gn_dx, sd, radius)
                pred = -(_dot(g, dx) + 0.5 * _dot(dx, H @ dx))
                new, new_c, new_rc = _try(problem, cur, dx, tm,
                                          keep=first and not _final(o, cur_rc, pred))
                actual = cur_rc - new_rc
                rho = actual / pred if pred > 0 else -1.0
                step = _norm(dx)
                if rho > 0.75:
                    radius = max(radius, 3.0 * step)
                elif rho < 0.25:
                    radius = 0.5 * step if step > 0 else 0.5 * radius
                if actual > 0:
                    accepted = True
                    break
                if new_rc == np.inf:
                    bad_trial = new
                if first:
                    first_trial = (new_rc, pred)
                first = False
                if radius < 1e-12 * (1.0 + _norm(_vec(cur))):
                    stop = "trust region collapsed without decreasing the cost"
                    at_minimum, stop = _at_minimum(o, cur_rc, *first_trial, stop)
                    break
            lam = radius
        if not accepted:
            message = stop or "no decrease"
            termination = "convergence" if at_minimum else "failure"
            if termination == "failure" and bad_trial is not None:
                where = problem.nonfinite(bad_trial)
                if where:
                    message += f"; trial points had a non-finite cost ({where})"
            history.append(IterationRecord(it, cur_rc, 0.0, lam, time.perf_counter() - t_start,
                                           solves))
            it -= 1
            break
        assert dx is not None
        step_norm = _norm(dx)
        old_rc = cur_rc
        cur, cur_c, cur_rc = new, new_c, new_rc
        history.append(IterationRecord(it, new_rc, step_norm, lam if o.solver != "gn" else 0.0,
                                       time.perf_counter() - t_start, solves))
        if log is not None:
            log.step(it, old_rc, new_rc, lin, dx, lam, solves)
        why = _converged(o, old_rc, new_rc)
        if why is None and step_norm <= o.step_tol:
            why = f"step norm {step_norm:.3g} below step_tol"
        if why is not None:
            message, termination = why, "convergence"
            break
        lin = _linearize(problem, cur, tm, old=lin)
        _require_finite(problem, cur, lin, f"after iteration {it}")
        if log is not None:
            log.emit(lin.grad)
    if log is not None:
        log.emit(None)
    final_c, final_rc = cur_c, cur_rc  # evaluated at the last accepted point already
    total = time.perf_counter() - t_start
    timings = dict(tm.t)
    timings["other"] = total - sum(timings.values())
    vals = Values(problem.variables, cur)
    return Result(vals, c0, final_c, rc0, final_rc, it, termination == "convergence", message,
                  termination, history, total, o.solver, ls.name, timings,
                  list(problem.gauge_fixed))


def _within(o: SolverOptions, old: float, new: float) -> bool:
    """A cost change (either sign) no larger than the tolerances: a minimum to rounding."""
    return abs(new - old) <= max(o.abs_tol, o.rel_tol * old)


def _at_minimum(o: SolverOptions, cost: float, first_cost: float, first_pred: float,
                stop: str) -> tuple[bool, str]:
    """Whether a run that found no decrease from ``cost`` stopped at a minimum (to rounding):
    the first (least damped) trial changed the cost, or its model predicted a decrease, by no
    more than the tolerances. Else it failed: the linearisation does not describe the cost."""
    if _within(o, cost, first_cost) or _final(o, cost, first_pred):
        return True, (f"no step decreases the cost; the first changed it by "
                      f"{first_cost - cost:.3g} with a predicted decrease of {first_pred:.3g}, "
                      f"within abs_tol/rel_tol ({stop})")
    return False, (f"{stop}: the first step changed it by {first_cost - cost:.3g} where its "
                   f"model predicted a decrease of {first_pred:.3g}")


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
    :func:`solve`); a row waits for the gradient at its point (:meth:`emit`)."""

    HEADER = (f"{'iter':>4s} {'cost':>13s} {'cost_change':>12s} {'|gradient|':>10s} "
              f"{'|step|':>9s} {'tr_ratio':>10s} {'tr_radius':>10s} {'ls_iter':>8s} "
              f"{'iter_time':>10s} {'total_time':>11s}")

    def __init__(self, problem: Problem, o: SolverOptions, t_start: float, cost: float,
                 grad: np.ndarray) -> None:
        self.problem, self.solver, self.t_start = problem, o.solver, t_start
        self.t_last = t_start
        self.pending: tuple | None = None
        radius = {"lm": 1.0 / o.lambda_initial if o.lambda_initial > 0 else math.inf,
                  "dogleg": o.radius_initial}.get(o.solver)
        self._print(self.HEADER)
        self.pending = (0, cost, 0.0, 0.0, math.nan, radius, 0)
        self.emit(grad)

    @staticmethod
    def _print(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    def step(self, it: int, old: float, new: float, lin: Any, dx: np.ndarray, lam: float,
             solves: int) -> None:
        """Record an accepted step ``dx`` of the linearisation ``lin`` (its ``H`` undamped)."""
        g = lin.grad
        pred = -(_dot(g, dx) + 0.5 * _dot(dx, self.problem.matrix(lin.data) @ dx))
        radius = {"lm": 1.0 / lam if lam > 0 else math.inf, "dogleg": lam}.get(self.solver)
        self.pending = (it, new, old - new, _norm(dx), (old - new) / pred if pred > 0
                        else math.nan, radius, solves)

    def emit(self, grad: np.ndarray | None) -> None:
        """Print the pending row with the max-norm of ``grad`` (``None``: not evaluated)."""
        if self.pending is None:
            return
        it, cost, change, step, ratio, radius, solves = self.pending
        self.pending = None
        now = time.perf_counter()
        gmax = "-" if grad is None or grad.size == 0 else f"{float(np.abs(grad).max()):.2e}"
        self._print(f"{it:4d} {cost:13.6e} {change:12.2e} {gmax:>10s} {step:9.2e} "
                    f"{_e(ratio, 10)} {_e(radius, 10)} {solves:8d} {now - self.t_last:10.2e} "
                    f"{now - self.t_start:11.2e}")
        self.t_last = now


def _e(v: float | None, w: int) -> str:
    return f"{'-':>{w}s}" if v is None or math.isnan(v) else f"{v:{w}.2e}"


def _dot(a: np.ndarray, b: np.ndarray) -> float:
    """``a . b`` of two vectors without BLAS: a multithreaded BLAS ``ddot`` on a shared machine
    took 7.6 ms for 50k entries (measured, OpenBLAS with its default threads, load 4), this
    loop 18 us."""
    return float(np.einsum("i,i->", a, b))


def _norm(x: np.ndarray) -> float:
    return math.sqrt(_dot(x, x))


def _vec(states: list[np.ndarray]) -> np.ndarray:
    return np.concatenate([s.ravel() for s in states]) if states else np.zeros(0)


def _linearize(problem: Problem, states: list[np.ndarray], tm: _Timer, old: Any = None
               ) -> Any:
    lin = problem.linearize(states, out=old)
    tm.t["linearize"] += lin.times["linearize"] + lin.times["products"] + lin.times["compiled"]
    tm.t["assemble"] += lin.times["assemble"]
    return lin


def _factor_solve(ls: LinearSolver, data: np.ndarray, b: np.ndarray, tm: _Timer,
                  gn: Problem | None = None) -> np.ndarray:
    """Factorise and solve; with ``gn`` (the problem of an undamped system) a singular
    system is an error naming the first variable it involves."""
    t0 = time.perf_counter()
    try:
        ls.factorize(data)
    except SingularSystemError as e:
        if gn is not None:
            at = f", first at {gn.unknown_name(e.unknown)}" if e.unknown is not None else ""
            raise SingularSystemError(
                f"{e}: the Gauss-Newton system is rank deficient (a gauge freedom or an "
                f"unobservable variable{at}); add priors or use solver='lm'",
                unknown=e.unknown) from None
        raise
    finally:
        tm.t["factorize"] += time.perf_counter() - t0
    t1 = time.perf_counter()
    try:
        return ls.solve(b)
    finally:
        tm.t["solve"] += time.perf_counter() - t1


def _try(problem: Problem, cur: list[np.ndarray], dx: np.ndarray, tm: _Timer,
         keep: bool) -> tuple:
    """The trial point ``cur + dx`` and its costs; with ``keep`` (the first trial of an
    iteration, usually accepted, unless the model predicts convergence) the factors whose
    Jacobians come with their residuals keep them for the linearisation at that point."""
    t0 = time.perf_counter()
    new = problem.retract(cur, dx)
    t1 = time.perf_counter()
    c, rc = problem.costs(new, keep=keep)
    t2 = time.perf_counter()
    tm.t["retract"] += t1 - t0
    tm.t["cost"] += t2 - t1
    if not np.isfinite(rc):
        rc = np.inf
    return new, c, rc


def _dogleg_step(gn: np.ndarray, sd: np.ndarray, radius: float) -> np.ndarray:
    ngn = _norm(gn)
    if ngn <= radius:
        return gn
    nsd = _norm(sd)
    if nsd >= radius:
        return sd * (radius / nsd)
    d = gn - sd
    a, b, c = _dot(d, d), 2.0 * _dot(sd, d), nsd * nsd - radius * radius
    tau = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)
    return sd + tau * d
