"""The factor graph: variables, factors, cost, optimisation and marginals."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .factors import Factor
from .linear import LinearSolver
from .problem import Problem
from .solvers import Result, SolverOptions, solve
from .variables import Values, Variables

__all__ = ["FactorGraph", "from_pose_graph"]


class FactorGraph:
    """Variables stored per type as batches, factors stored and evaluated per type as batches.

    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
    >>> g = FactorGraph()
    >>> poses = g.add_variables(SE2.identity(3))
    >>> _ = g.add(PriorFactor(poses, 0, SE2.identity(), Diagonal([1e-3, 1e-3, 1e-3])))
    >>> step = SE2.exp(np.array([[1.0, 0.0, 0.1], [1.0, 0.0, 0.1]]))
    >>> _ = g.add(BetweenFactor(poses, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.01])))
    >>> result = g.optimize()
    >>> result.converged, result.final_cost < 1e-12
    (True, True)
    >>> np.round(result.values[poses][2].log(), 6).tolist()  # two steps of Exp(1, 0, 0.1)
    [2.0, 0.0, 0.2]
    """

    def __init__(self) -> None:
        self.variables: list[Variables] = []
        self.factors: list[Factor] = []
        self._problem: Problem | None = None
        self._problem_key: Any = None

    # ------------------------------------------------------------------ building
    def add_variables(self, values: Any, fixed: Any = None, name: str | None = None
                      ) -> Variables:
        """Add a batch of variables: a 1-D batch of group elements (any LieGroup) or an
        ``(n, d)`` array of vectors. ``fixed`` holds some constant (indices, a boolean mask,
        or ``True`` for all). Returns the handle factors refer to."""
        v = Variables(self, len(self.variables), values, None,
                      name or f"x{len(self.variables)}")
        if fixed is not None:
            v.fix(fixed)
        self.variables.append(v)
        self._changed()
        return v

    def add(self, factor: Factor) -> Factor:
        """Add a factor batch (PriorFactor, BetweenFactor, CustomFactor, ...)."""
        if not isinstance(factor, Factor):
            raise TypeError(f"expected a Factor, got {type(factor).__name__}")
        for var, _ in factor.args:
            if var.graph is not self:
                raise ValueError(f"{factor.name}: {var!r} belongs to another graph")
        self.factors.append(factor)
        self._changed()
        return factor

    def fix(self, variables: Variables, idx: Any = None) -> None:
        """Hold ``variables[idx]`` (all if None) constant."""
        variables.fix(idx)

    def _changed(self) -> None:
        self._problem = None

    # ------------------------------------------------------------------ values
    def initial_values(self) -> Values:
        return Values(self.variables, [v.initial for v in self.variables])

    def _states(self, values: Values | None) -> list[np.ndarray]:
        if values is None:
            return [v.initial for v in self.variables]
        return [np.asarray(values.params(v), dtype=np.float64) for v in self.variables]

    def set_values(self, values: Values) -> None:
        """Make ``values`` the starting point of the next optimisation."""
        for v in self.variables:
            v.initial = np.asarray(values.params(v), dtype=np.float64).copy()

    def problem(self, gauge: str = "check") -> Problem:
        key = (gauge, tuple(v.fixed.tobytes() for v in self.variables))
        if self._problem is None or self._problem_key != key:
            if not self.factors:
                raise ValueError("the graph has no factors")
            self._problem = Problem(self.variables, self.factors, gauge)
            self._problem_key = key
        return self._problem

    def cost(self, values: Values | None = None) -> float:
        """``0.5 * sum r^T Omega r`` over all factors (no robust loss), at ``values`` (the
        initial values if None)."""
        return self.problem("none").costs(self._states(values))[0]

    def robust_cost(self, values: Values | None = None) -> float:
        """``0.5 * sum rho(r^T Omega r)`` (the plain cost for factors without a loss)."""
        return self.problem("none").costs(self._states(values))[1]

    # ------------------------------------------------------------------ solving
    def optimize(self, values: Values | None = None, *, solver: str = "lm",
                 linear_solver: str | LinearSolver = "auto", max_iter: int = 100,
                 rel_tol: float = 1e-5, abs_tol: float = 1e-5, cost_tol: float = 0.0,
                 step_tol: float = 0.0, gauge: str = "check", verbose: bool | None = None,
                 **options: Any) -> Result:
        """Minimise the robust cost from ``values`` (the initial values if None).

        ``solver``: ``"lm"`` (Levenberg-Marquardt, default), ``"gn"`` (Gauss-Newton) or
        ``"dogleg"`` (Powell's dogleg). ``linear_solver``: ``"auto"``, ``"scipy"``,
        ``"qdldl"``, ``"pardiso"``, ``"dense"`` or a :class:`LinearSolver`. ``gauge``:
        ``"check"`` raises a ValueError when variables are not anchored by a prior or a fixed
        variable, ``"fix_first"`` holds the first variable of each such component constant
        (reported in ``result.gauge_fixed``), ``"none"`` skips the check. ``verbose`` prints
        one line per iteration on stderr (default: when stderr is a terminal). Further
        options: ``lambda_initial``, ``lambda_factor``, ``lambda_max``, ``diagonal_damping``,
        ``radius_initial``.
        """
        o = SolverOptions(solver=solver, linear_solver=linear_solver, max_iter=max_iter,
                          rel_tol=rel_tol, abs_tol=abs_tol, cost_tol=cost_tol,
                          step_tol=step_tol, verbose=verbose)
        for k, val in options.items():
            if not hasattr(o, k):
                raise TypeError(f"optimize() got an unknown option {k!r}")
            setattr(o, k, val)
        return solve(self.problem(gauge), self._states(values), o)

    # ------------------------------------------------------------------ marginals
    def _factorized(self, values: Values | None, linear_solver: Any) -> tuple:
        prob = self.problem("check")
        states = self._states(values)
        ls = prob.analysed(linear_solver)
        ls.factorize(prob.linearize(states).data)
        return prob, states, ls

    def marginal_covariance(self, values: Values | None, items: Sequence[tuple[Variables, int]],
                            linear_solver: str | LinearSolver = "auto") -> np.ndarray:
        """Joint covariance ``H^-1`` (Gauss-Newton matrix at ``values``, robust weights
        included, no damping) of the listed free variables, in their order and the
        right-perturbation frame: an ``(sum dof, sum dof)`` array."""
        prob, states, ls = self._factorized(values, linear_solver)
        cols = []
        for var, i in items:
            i = int(var.indices(i)[0])
            node = prob.node_of[prob.key(var)][i]
            if node < 0:
                raise ValueError(f"{var.name}[{i}] is fixed: it has no marginal covariance")
            cols.append(prob.node_off[node] + np.arange(var.dof))
        idx = np.concatenate(cols)
        E = np.zeros((prob.size, idx.size))
        E[idx, np.arange(idx.size)] = 1.0
        X = ls.solve(E)
        C = X[idx]
        return 0.5 * (C + C.T)

    def marginals(self, values: Values | None, variables: Variables, idx: Any = None,
                  linear_solver: str | LinearSolver = "auto") -> Any:
        """Marginal Gaussians of ``variables[idx]`` (all if None) at ``values``, as one
        batched :class:`microlie.Gaussian` with ``frame="right"`` (``X = mean Exp(eps)``) for
        group variables, or a :class:`microlie.VectorGaussian` for vectors."""
        from ..uncertainty import Gaussian, VectorGaussian

        ix = np.arange(variables.n) if idx is None else variables.indices(idx)
        prob, states, ls = self._factorized(values, linear_solver)
        nodes = prob.node_of[prob.key(variables)][ix]
        if np.any(nodes < 0):
            bad = int(ix[np.flatnonzero(nodes < 0)[0]])
            raise ValueError(f"{variables.name}[{bad}] is fixed: it has no marginal covariance")
        d = variables.dof
        covs = np.empty((ix.size, d, d))
        chunk = max(1, 2048 // d)
        for s in range(0, ix.size, chunk):
            sel = nodes[s:s + chunk]
            rows = (prob.node_off[sel][:, None] + np.arange(d)).ravel()
            E = np.zeros((prob.size, rows.size))
            E[rows, np.arange(rows.size)] = 1.0
            X = ls.solve(E)[rows].reshape(sel.size, d, sel.size, d)
            k = np.arange(sel.size)
            blk = X[k, :, k, :]
            covs[s:s + sel.size] = 0.5 * (blk + np.swapaxes(blk, 1, 2))
        params = states[prob.key(variables)][ix]
        if variables.group is None:
            return VectorGaussian(params, covs)
        return Gaussian(variables.wrap(params), covs, frame="right")


def from_pose_graph(pose_graph: Any, poses: Any = None, loss: Any = None
                    ) -> tuple[FactorGraph, Variables]:
    """A :class:`FactorGraph` of a :class:`~microlie.optim.pose_graph.PoseGraph` with the
    first vertex held fixed (or the file's ``FIX`` vertices): ``pose_graph.to_factor_graph(
    poses, loss=loss, gauge="fix")``, so the cost is the file's edges only.

    Returns ``(graph, handle)``; ``result.values[handle]`` are the poses in ``ids`` order.
    """
    return pose_graph.to_factor_graph(poses, loss=loss, gauge="fix")
