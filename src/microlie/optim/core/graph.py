"""The factor graph: variables, factors, cost, optimisation and marginals."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..linalg.linear import LinearSolver
from .factors import Factor
from .problem import Problem
from .solvers import Result, solve
from .strategies import Strategy, make_strategy
from .threads import with_blas_threads
from .variables import Values, Variables, new_variables

__all__ = ["FactorGraph", "from_pose_graph"]


class FactorGraph:
    """Variables stored per type as batches, factors stored and evaluated per type as batches.

    Build one with no arguments, then add variable batches (``add_variables``) and factor
    batches (``add``), and call ``optimize``.

    Examples
    --------
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
        """Add a batch of variables.

        Parameters
        ----------
        values : LieGroup or array_like
            A 1-D batch of group elements (any :class:`~microlie.LieGroup`) or an ``(n, d)`` array
            of vectors: the initial values. Vectors (an array or an ``R(d)`` batch) are
            variables of group ``R(d)`` whose values are plain ``(n, d)`` arrays: what factors
            receive and ``result.values[handle]`` gives.
        fixed : optional
            Variables held constant: indices, a boolean mask, or ``True`` for all.
        name : str, optional
            A label for messages (default ``x0``, ``x1``, ...).

        Returns
        -------
        Variables
            The handle factors refer to.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3
        >>> from microlie.optim import FactorGraph
        >>> g = FactorGraph()
        >>> g.add_variables(SE3.identity(4), fixed=[0], name="poses")
        Variables('poses', SE3, n=4, fixed=1)
        >>> g.add_variables(np.zeros((2, 3)), name="landmarks")
        Variables('landmarks', R3, n=2, fixed=0)
        """
        v = new_variables(self, len(self.variables), values, name or f"x{len(self.variables)}")
        if fixed is not None:
            v.fix(fixed)
        self.variables.append(v)
        self._changed()
        return v

    def add(self, factor: Factor) -> Factor:
        """Add a factor batch (:class:`PriorFactor`, :class:`BetweenFactor`, :class:`CustomFactor`,
        ...).

        Parameters
        ----------
        factor : Factor
            Its variables must belong to this graph.

        Returns
        -------
        Factor
            ``factor`` itself.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
        >>> step = SE2.exp(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.1])))
        >>> g.add(PriorFactor(x, 2, SE2.exp([2.0, 0.0, 0.0]), Diagonal([1.0, 1.0, 1.0])))
        PriorFactor(count=1, dim=3)
        """
        if not isinstance(factor, Factor):
            raise TypeError(f"expected a Factor, got {type(factor).__name__}")
        for var, _ in factor.args:
            if var.graph is not self:
                raise ValueError(f"{factor.name}: {var!r} belongs to another graph")
        self.factors.append(factor)
        self._changed()
        return factor

    def remove(self, factor: Factor) -> None:
        """Remove a factor batch added with :meth:`add`.

        Parameters
        ----------
        factor : Factor
            A batch of this graph (the same object); otherwise a ``ValueError``.

        Examples
        --------
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(1))
        >>> f = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> g.remove(f)
        >>> len(g.factors)
        0
        """
        keep = [f for f in self.factors if f is not factor]
        if len(keep) == len(self.factors):
            raise ValueError(f"factor: {getattr(factor, 'name', factor)!r} is not a factor of "
                             f"this graph")
        self.factors = keep
        self._changed()

    def fix(self, variables: Variables, idx: Any = None, components: Any = None) -> None:
        """Hold ``variables[idx]`` constant, or only their tangent ``components`` (the same as
        ``variables.fix(idx, components)``).

        ``components`` are tangent coordinates (the group's order, translation first) held at
        zero in every step of every solver and linear solver: ``fix(K, components=[1, 2])``
        holds ``k1, k2`` of BAL intrinsics ``(f, k1, k2)``, for every camera or for ``idx``;
        ``fix(T, 0, components=[3, 4, 5])`` holds the rotation of SE3 pose 0. Held components
        have zero marginal variance; a variable with only some components held does not anchor
        the gauge; one with all of them held is fixed.

        Parameters
        ----------
        variables : Variables
            A handle of this graph.
        idx : optional
            Indices or a boolean mask; all if ``None``.
        components : int or sequence of int, optional
            Tangent coordinates to hold, ``0 <= c < dof``, no duplicates (else a
            ``ValueError``); ``None``: the whole variables.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
        >>> step = SE2.exp(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.1])))
        >>> g.fix(x, 0)
        >>> x
        Variables('x', SE2, n=3, fixed=1)
        >>> g.fix(x, [1, 2], components=[2])  # headings of x[1], x[2] stay at their start
        >>> np.round(g.optimize().values[x].log()[:, 2], 12).tolist()
        [0.0, 0.0, 0.0]
        """
        variables.fix(idx, components)

    def _changed(self) -> None:
        self._problem = None

    # ------------------------------------------------------------------ values
    def initial_values(self) -> Values:
        """The current starting point: the values given to :meth:`add_variables` (or
        :meth:`set_values`).

        Returns
        -------
        Values

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
        >>> step = SE2.exp(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.1])))
        >>> g.initial_values()[x].params.shape
        (3, 4)
        """
        return Values(self.variables, [v.initial for v in self.variables])

    def _states(self, values: Values | None) -> list[np.ndarray]:
        if values is None:
            return [v.initial for v in self.variables]
        return [np.asarray(values.params(v), dtype=np.float64) for v in self.variables]

    def set_values(self, values: Values) -> None:
        """Make ``values`` the starting point of the next optimisation.

        Parameters
        ----------
        values : Values
            Values of this graph's variables (for example ``result.values``).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
        >>> step = SE2.exp(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.1])))
        >>> g.set_values(g.optimize().values)
        >>> round(g.cost(), 9)
        0.0
        """
        for v in self.variables:
            v.initial = np.asarray(values.params(v), dtype=np.float64).copy()

    def problem(self, gauge: str = "check") -> Problem:
        """The least-squares :class:`~microlie.optim.core.problem.Problem` of the graph (built once
        and
        cached until variables, factors or fixed flags change).

        Parameters
        ----------
        gauge : {"check", "fix_first", "none"}
            See :meth:`optimize`.

        Returns
        -------
        Problem

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
        >>> step = SE2.exp(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.1])))
        >>> g.problem().size  # free unknowns: 3 poses x 3
        9
        """
        key = (gauge, tuple(v.fixed.tobytes() + v.held.tobytes() for v in self.variables))
        if self._problem is None or self._problem_key != key:
            if not self.factors:
                raise ValueError("the graph has no factors")
            self._problem = Problem(self.variables, self.factors, gauge)
            self._problem_key = key
        return self._problem

    def cost(self, values: Values | None = None) -> float:
        """The cost ``0.5 * sum r^T Omega r`` over all factors, without robust losses (GTSAM's
        error).

        Parameters
        ----------
        values : Values, optional
            Where to evaluate (the initial values if ``None``).

        Returns
        -------
        float

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
        >>> step = SE2.exp(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.1])))
        >>> round(g.cost(), 6)  # two unit odometry residuals with sigma 0.1
        100.0
        """
        return self.problem("none").costs(self._states(values))[0]

    def robust_cost(self, values: Values | None = None) -> float:
        """The minimised cost ``0.5 * sum rho(r^T Omega r)`` (the plain cost for factors without a
        loss).

        Parameters
        ----------
        values : Values, optional
            Where to evaluate (the initial values if ``None``).

        Returns
        -------
        float

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(1))
        >>> f = g.add(PriorFactor(x, 0, SE2.exp([3.0, 0, 0]), Isotropic(3, 1.0), loss="huber:1"))
        >>> g.cost(), g.robust_cost()  # 0.5 * 9 and 0.5 * (2 * 3 - 1)
        (4.5, 2.5)
        """
        return self.problem("none").costs(self._states(values))[1]

    # ------------------------------------------------------------------ solving
    @with_blas_threads
    def optimize(self, values: Values | None = None, *, solver: str | Strategy = "lm",
                 linear_solver: str | LinearSolver = "auto", eliminate: Any = None,
                 max_iter: int = 100, rel_tol: float | None = None, abs_tol: float | None = None,
                 cost_tol: float | None = None, step_tol: float | None = None,
                 gauge: str = "check", verbose: bool | None = None,
                 blas_threads: int | None = 1, robust: Any = None, **options: Any) -> Result:
        """Minimise the robust cost from ``values``.

        Parameters
        ----------
        values : Values, optional
            The starting point (the initial values if ``None``).
        solver : str or Strategy
            The strategy (:mod:`microlie.optim.core.strategies`): ``"lm"`` (default,
            :class:`LevenbergMarquardt`, GTSAM's rules), ``"gn"`` (:class:`GaussNewton`),
            ``"dogleg"`` (:class:`Dogleg`), ``"trust-region"`` (:class:`TrustRegion`,
            Levenberg-Marquardt with Ceres' rules), or an instance with its options.
        linear_solver : str or LinearSolver
            ``"auto"``, ``"cholesky"``, ``"schur"``, ``"scipy"``, ``"qdldl"``, ``"pardiso"``,
            ``"dense"`` or an instance (see :func:`make_solver`). ``"schur"`` eliminates
            variables that share no factor with each other (landmarks) and factorises the
            reduced system (:class:`~microlie.optim.linalg.schur_solver.SchurSolver`).
        eliminate : Variables or sequence of Variables, optional
            With ``linear_solver="schur"``: the batches to eliminate (their free variables may
            share no factor with each other nor with the other named batches); default: the
            landmark-like batches with the most unknowns
            (:func:`~microlie.optim.core.landmarks.landmark_batches`).
        max_iter : int
            Iteration limit (as the strategy counts them, :attr:`Result.iterations`).
        rel_tol, abs_tol, cost_tol, step_tol : float, optional
            GTSAM's convergence tests of ``"lm"``, ``"gn"`` and ``"dogleg"`` (relative and
            absolute cost decrease, cost threshold, step norm; defaults ``1e-5``, ``1e-5``,
            ``0``, ``0``). With a named strategy only.
        gauge : {"check", "fix_first", "none"}
            ``"check"`` raises a :class:`GaugeError` (a ValueError) when variables are not
            anchored by a prior or a fixed variable, ``"fix_first"`` holds the first variable of
            each such component constant (reported in ``result.gauge_fixed``), ``"none"`` skips
            the check.
        verbose : bool, optional
            Print Ceres' iteration table on stderr, one line per iteration (default: when
            stderr is a terminal).
        blas_threads : int or None
            BLAS threads during the call (default 1: a multithreaded BLAS makes the solve
            several times slower on a busy machine; :mod:`microlie.optim.core.threads`); ``None``
            keeps the user's setting (``OPENBLAS_NUM_THREADS``, threadpoolctl) or the library's
            default. The previous setting is restored on return.
        robust : {"gnc-tls", "gnc-gm"} or GNC, optional
            Graduated non-convexity (:mod:`microlie.optim.core.gnc`): truncated least squares
            or Geman-McClure with default options, or a :class:`~microlie.optim.core.gnc.GNC`
            with its options (known inliers, chi-square quantile, ...). Every inner weighted
            solve uses ``solver``, ``linear_solver`` and ``max_iter``; ``result.weights`` and
            ``result.inliers`` give the verdict per factor. The factors may not carry losses.
        **options
            Other constructor parameters of the named strategy: ``lambda_initial``,
            ``lambda_factor``, ``lambda_max``, ``lambda_min``, ``damping``, ``stall_ratio``
            (``"lm"``; ``damping="auto"``, the default, does not depend on the units),
            ``radius_initial`` (``"dogleg"``, ``"trust-region"``), ``function_tolerance``,
            ``gradient_tolerance``, ``parameter_tolerance``, ... (``"trust-region"``). An
            option the strategy does not take is a ``TypeError``.

        Returns
        -------
        Result

        Notes
        -----
        Variables given as torch tensors or JAX arrays are solved on that backend and device
        (:func:`microlie.optim.device.optimize_graph`: Levenberg-Marquardt, ``linear_solver``
        ``"auto"``, ``"dense"`` or ``"pcg"``); ``result.values`` are then arrays of that
        backend, dtype and device. They carry gradients to measurement tensors that require
        grad (or are traced by ``jax.grad``): option ``differentiate="implicit"`` (default) or
        ``"unroll"`` (:mod:`microlie.optim.device.implicit`).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
        >>> step = SE2.exp(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.1])))
        >>> res = g.optimize(solver="gn")
        >>> res.converged, np.round(res.values[x].params[2], 9).tolist()
        (True, [2.0, 0.0, 1.0, 0.0])
        """
        tols = {"rel_tol": rel_tol, "abs_tol": abs_tol, "cost_tol": cost_tol,
                "step_tol": step_tol}
        given = {k: v for k, v in tols.items() if v is not None}
        if any(v.source is not None for v in self.variables):  # torch / JAX variables
            from ..device import optimize_graph

            return optimize_graph(self, values, solver=solver, linear_solver=linear_solver,
                                  max_iter=max_iter, gauge=gauge, robust=robust, **given,
                                  **options)
        strategy = make_strategy(solver, **given, **options)
        if robust is not None:
            from .gnc import gnc_solve, make_gnc

            return gnc_solve(self.problem(gauge), self._states(values), make_gnc(robust),
                             strategy, linear_solver=linear_solver, eliminate=eliminate,
                             max_iter=max_iter, verbose=verbose)
        return solve(self.problem(gauge), self._states(values), strategy,
                     linear_solver=linear_solver, eliminate=eliminate, max_iter=max_iter,
                     verbose=verbose)

    # ------------------------------------------------------------------ marginals
    def _factorized(self, values: Values | None, linear_solver: Any) -> tuple:
        prob = self.problem("check")
        states = self._states(values)
        ls = prob.analysed(linear_solver)
        ls.factorize(prob.linearize(states).data)
        return prob, states, ls

    @with_blas_threads
    def marginal_covariance(self, values: Values | None, items: Sequence[tuple[Variables, int]],
                            linear_solver: str | LinearSolver = "auto", *,
                            blas_threads: int | None = 1) -> np.ndarray:
        """Joint covariance ``H^-1`` of the listed free variables (Gauss-Newton matrix at
        ``values``, robust weights included, no damping), in their order and in the
        right-perturbation frame.

        Parameters
        ----------
        values : Values or None
            Where to linearise (the initial values if ``None``).
        items : sequence of (Variables, int)
            The variables, one ``(handle, index)`` each.
        linear_solver : str or LinearSolver
            ``"auto"``, ``"scipy"``, ``"cholesky"``, ``"qdldl"``, ``"pardiso"``, ``"dense"`` or
            an instance (see :func:`make_solver`).
        blas_threads : int or None
            BLAS threads while factorising and solving (default 1, as :meth:`optimize`;
            ``None`` keeps the process's setting).

        Returns
        -------
        numpy.ndarray
            ``(sum dof, sum dof)``; zero in the rows and columns of held components
            (:meth:`fix` with ``components``).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
        >>> step = SE2.exp(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.1])))
        >>> res = g.optimize()
        >>> S = g.marginal_covariance(res.values, [(x, 0), (x, 1)])
        >>> S.shape, round(float(S[0, 0]), 9)  # the prior's variance
        ((6, 6), 0.01)
        """
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
        X[prob.held] = 0.0  # held components: zero variance (Problem.hold)
        C = X[idx]
        return 0.5 * (C + C.T)

    @with_blas_threads
    def marginals(self, values: Values | None, variables: Variables, idx: Any = None,
                  linear_solver: str | LinearSolver = "auto", *,
                  blas_threads: int | None = 1) -> Any:
        """Marginal Gaussians of ``variables[idx]`` at ``values``.

        Parameters
        ----------
        values : Values or None
            Where to linearise (the initial values if ``None``).
        variables : Variables
            A handle of this graph.
        idx : optional
            Indices or a mask; all if ``None``.
        linear_solver : str or LinearSolver
            ``"auto"``, ``"scipy"``, ``"cholesky"``, ``"qdldl"``, ``"pardiso"``, ``"dense"`` or
            an instance (see :func:`make_solver`).
        blas_threads : int or None
            BLAS threads while factorising and solving (default 1, as :meth:`optimize`;
            ``None`` keeps the process's setting).

        Returns
        -------
        Gaussian or VectorGaussian
            One batched :class:`microlie.Gaussian` with ``frame="right"`` (``X = mean Exp(eps)``)
            for group variables, or a :class:`microlie.VectorGaussian` for vectors
            (``Variables.gaussian``). Held components (:meth:`fix` with ``components``) have
            zero variance and covariance.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor, Diagonal
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.1, 0.1])))
        >>> step = SE2.exp(np.array([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]]))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], step, Diagonal([0.1, 0.1, 0.1])))
        >>> res = g.optimize()
        >>> m = g.marginals(res.values, x)
        >>> m.frame, m.cov.shape, round(float(m.cov[1, 0, 0]), 9)  # prior + one edge
        ('right', (3, 3, 3), 0.02)
        """
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
            X = ls.solve(E)
            X[prob.held] = 0.0  # held components: zero variance (Problem.hold)
            X = X[rows].reshape(sel.size, d, sel.size, d)
            k = np.arange(sel.size)
            blk = X[k, :, k, :]
            covs[s:s + sel.size] = 0.5 * (blk + np.swapaxes(blk, 1, 2))
        return variables.gaussian(states[prob.key(variables)][ix], covs)


def from_pose_graph(pose_graph: Any, poses: Any = None, loss: Any = None
                    ) -> tuple[FactorGraph, Variables]:
    r"""A :class:`FactorGraph` of a :class:`~microlie.optim.io.pose_graph.PoseGraph` with the first
    vertex held fixed (or the file's ``FIX`` vertices): ``pose_graph.to_factor_graph(poses,
    loss=loss, gauge="fix")``, so the cost is the file's edges only.

    Parameters
    ----------
    pose_graph : PoseGraph
        From :func:`~microlie.optim.io.g2o.read_g2o` or :func:`~microlie.optim.io.toro.read_toro`.
    poses : LieGroup, optional
        Initial poses in ``pose_graph.ids`` order (default: the file's).
    loss : str or RobustLoss, optional
        A robust loss on every edge.

    Returns
    -------
    graph : FactorGraph
    handle : Variables
        ``result.values[handle]`` are the poses in ``ids`` order.

    Examples
    --------
    >>> import os, tempfile
    >>> from microlie.optim import from_pose_graph
    >>> from microlie.optim.io.g2o import read_g2o
    >>> path = os.path.join(tempfile.mkdtemp(), "tiny.g2o")
    >>> _ = open(path, "w").write(
    ...     "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\n"
    ...     "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    >>> graph, poses = from_pose_graph(read_g2o(path))
    >>> res = graph.optimize()
    >>> [round(float(v), 6) for v in res.values[poses].params[1]]
    [1.0, 0.0, 1.0, 0.0]
    """
    return pose_graph.to_factor_graph(poses, loss=loss, gauge="fix")
