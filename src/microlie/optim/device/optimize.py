"""``FactorGraph.optimize`` for graphs on torch or JAX arrays, and batches of graphs."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..._array import is_traced
from ..core.solvers import Result
from ..core.strategies import LevenbergMarquardt
from ..core.variables import Values
from .implicit import solve_differentiable, traced_result
from .lm import STATUS, LMOptions, linear_kind
from .problem import DeviceProblem

__all__ = ["optimize_graph", "stack", "lm_options"]

_LM_FIELDS = ("lambda_initial", "lambda_factor", "lambda_max", "lambda_min", "damping",
              "stall_ratio", "rel_tol", "abs_tol", "cost_tol", "step_tol")


def lm_options(solver: Any = "lm", linear_solver: Any = "auto", max_iter: int = 100,
               **options: Any) -> LMOptions:
    """The :class:`LMOptions` of ``FactorGraph.optimize``'s arguments on a device graph.

    Parameters
    ----------
    solver : "lm" or LevenbergMarquardt
        The strategy (only Levenberg-Marquardt runs on devices).
    linear_solver : {"auto", "dense", "schur", "pcg"}
        The step solve (:class:`LMOptions` ``linear``).
    max_iter : int
        Iteration limit.
    **options
        :class:`LMOptions` fields (``rel_tol``, ``lambda_initial``, ``cg_max_iter``, ...).

    Returns
    -------
    LMOptions

    Raises
    ------
    ValueError
        Another strategy or linear solver (the message says what runs on devices).

    Examples
    --------
    >>> from microlie.optim.device.optimize import lm_options
    >>> lm_options("lm", "pcg", 20, rel_tol=1e-8).rel_tol
    1e-08
    """
    fields: dict[str, Any] = {}
    if isinstance(solver, LevenbergMarquardt):
        fields = {k: getattr(solver, k) for k in _LM_FIELDS}
    elif solver != "lm":
        raise ValueError(f"solver: graphs on torch or JAX arrays are solved by Levenberg-"
                         f"Marquardt ('lm' or a LevenbergMarquardt), got {solver!r}; use NumPy "
                         f"variables for the other strategies")
    if linear_solver not in ("auto", "dense", "schur", "pcg"):
        raise ValueError(f"linear_solver: graphs on torch or JAX arrays take 'auto', 'dense', "
                         f"'schur' (landmarks eliminated, dense reduced system) or 'pcg' "
                         f"(preconditioned conjugate gradients), got {linear_solver!r}")
    fields.update({k: v for k, v in options.items() if v is not None})
    return LMOptions(max_iter=max_iter, linear=linear_solver, **fields)


def optimize_graph(graph: Any, values: Values | None = None, *, solver: Any = "lm",
                   linear_solver: Any = "auto", max_iter: int = 100, gauge: str = "check",
                   robust: Any = None, **options: Any) -> Result:
    """Optimise a graph whose variables are torch tensors or JAX arrays on that backend and
    device (what :meth:`FactorGraph.optimize` calls for them).

    Parameters
    ----------
    graph : FactorGraph
        Variables given as torch tensors or JAX arrays (one library; NumPy measurements are
        converted to it).
    values : Values, optional
        The starting point (default: the variables' initial arrays).
    solver : "lm" or LevenbergMarquardt
        Levenberg-Marquardt with GTSAM's rules.
    linear_solver : {"auto", "dense", "schur", "pcg"}
        Dense Cholesky, exact Schur elimination of landmarks with a dense reduced camera
        system, or preconditioned conjugate gradients (Schur for bundle adjustment).
    max_iter : int
        Iteration limit.
    gauge : {"check", "fix_first", "none"}
        As :meth:`FactorGraph.optimize`.
    robust : None
        Graduated non-convexity is not available on devices (a ``ValueError``).
    **options
        :class:`LMOptions` fields: the tolerances, damping options, ``cg_max_iter``,
        ``eta_max``, ``eta_min``, ``schur``; and ``differentiate``: how gradients reach the
        measurements and initial values given as tensors (``"implicit"``, default, or
        ``"unroll"``, :mod:`microlie.optim.device.implicit`).

    Returns
    -------
    Result
        ``values[handle].params`` are arrays of the variables' backend, dtype and device;
        costs are Python floats; ``history`` is empty (the loop runs on the device).

    Examples
    --------
    >>> import torch
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.from_params(torch.tensor([[0.0, 0, 1, 0]] * 3).double()))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.5])))
    >>> res = g.optimize()
    >>> res.converged, type(res.values[x].params).__name__, res.linear_solver
    (True, 'Tensor', 'torch:dense')
    """
    if robust is not None:
        raise ValueError("robust: graduated non-convexity runs on the NumPy engine only; give "
                         "NumPy variables")
    for k in ("verbose", "blas_threads", "eliminate"):
        options.pop(k, None)
    differentiate = options.pop("differentiate", "implicit")
    opts = lm_options(solver, linear_solver, max_iter, **options)
    t0 = time.perf_counter()
    prob = DeviceProblem.from_graph(graph, gauge=gauge)
    x, info = solve_differentiable(prob, prob.theta(), prob.initial(values), opts, differentiate)
    be = prob.backend
    if is_traced(info.status):  # inside jax.jit / jax.grad: no values on the host
        return traced_result(prob, x, info, opts)
    total = time.perf_counter() - t0
    status = int(be.to_numpy(info.status))
    term = STATUS[status] if status else "no_convergence"
    msg = {1: "converged (GTSAM's tests, or no decrease within the tolerances)",
           2: f"reached max_iter={max_iter}",
           3: f"lambda exceeded {opts.lambda_max:g} without decreasing the cost",
           0: f"reached max_tries={opts.tries()}"}[status]
    c0, c1 = float(be.to_numpy(info.initial_cost)), float(be.to_numpy(info.cost))
    name = f"{be.name}:{linear_kind(prob, opts.linear)}"
    return Result(Values(prob.variables, x), c0, c1, c0, c1,
                  int(be.to_numpy(info.iterations)), term == "convergence", msg, term, [],
                  total, "lm", name, {}, list(prob.gauge_fixed),
                  int(be.to_numpy(info.iterations)), None)


def stack(items: list[Any]) -> Any:
    """Stack pytrees (``theta`` of :meth:`DeviceProblem.theta`, ``x0`` lists) of problems of
    the same structure along a new leading batch axis.

    Parameters
    ----------
    items : list
        Same-structure pytrees (tuples of dicts, lists) of torch or JAX arrays.

    Returns
    -------
    pytree
        The same structure with every array stacked.

    Raises
    ------
    ValueError
        Structures or shapes differ (the message names the leaf).

    Examples
    --------
    >>> import torch
    >>> from microlie.optim.device import stack
    >>> s = stack([[torch.zeros(2, 3)], [torch.ones(2, 3)]])
    >>> s[0].shape
    torch.Size([2, 2, 3])
    """
    if not items:
        raise ValueError("stack: no problems given")
    first = items[0]
    if isinstance(first, dict):
        if any(not isinstance(i, dict) or set(i) != set(first) for i in items):
            raise ValueError("stack: the problems' theta differ in structure (factor data keys)")
        return {k: stack([i[k] for i in items]) for k in first}
    if isinstance(first, list | tuple):
        if any(len(i) != len(first) for i in items):
            raise ValueError("stack: the problems differ in structure (number of factor or "
                             "variable batches)")
        return type(first)(stack([i[j] for i in items]) for j in range(len(first)))
    shapes = {tuple(i.shape) for i in items}
    if len(shapes) != 1:
        raise ValueError(f"stack: arrays of different shapes {sorted(shapes)}: the problems "
                         f"must have the same structure")
    mod = type(first).__module__
    if mod.startswith("torch"):
        import torch

        return torch.stack(list(items))
    if "jax" in mod:
        import jax.numpy as jnp

        return jnp.stack(list(items))
    return np.stack([np.asarray(i) for i in items])


