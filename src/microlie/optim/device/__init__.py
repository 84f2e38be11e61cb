"""The estimator on PyTorch and JAX arrays (issue 24): Levenberg-Marquardt with the NumPy
engine's rules, dense Cholesky, exact Schur (bundle adjustment) or preconditioned-CG steps,
and a batch axis over whole problems.

Two ways in:

* ``FactorGraph.optimize()`` on a graph whose variables are torch tensors or JAX arrays runs
  here (:func:`optimize_graph`) and returns a :class:`~microlie.optim.Result` whose values are
  arrays of that backend, dtype and device.
* The pure functional core: ``problem = DeviceProblem.from_graph(g)``, ``theta =
  problem.theta()`` (the factors' measurements and noise), ``x0 = problem.initial()``, then
  ``x, info = solve(problem, theta, x0, LMOptions(...))``. Give ``theta`` and ``x0`` a leading
  batch axis (:func:`stack`) to solve a batch of problems of the same structure in one call;
  ``jax.jit``/``jax.vmap`` compile it, ``torch.compile(fullgraph=True)`` traces it with
  ``LMOptions(loop="fixed")``.

Nothing here imports torch or JAX before a caller's arrays are theirs.
"""

from .backend import BACKENDS, Backend, backend_of
from .lm import LMOptions, SolveInfo, solve
from .optimize import optimize_graph, stack
from .problem import DeviceProblem

__all__ = ["BACKENDS", "Backend", "DeviceProblem", "LMOptions", "SolveInfo", "backend_of",
           "optimize_graph", "solve", "stack"]
