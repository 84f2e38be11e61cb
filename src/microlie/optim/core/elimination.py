"""Which variables ``linear_solver="schur"`` eliminates: the landmark-like batches of a
:class:`~microlie.optim.core.problem.Problem` (variables that share no factor with each other),
checked or chosen (the default: :func:`~microlie.optim.core.landmarks.landmark_batches`), and
the :class:`~microlie.optim.linalg.schur_solver.SchurSolver` that eliminates them (the solver
itself knows only the node numbering)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..linalg.schur_solver import SchurSolver
from .landmarks import batch_conflicts, landmark_batches
from .variables import Variables

# a Problem is passed in, not imported: problem.py calls this module (no import cycle)
Problem = Any

__all__ = ["schur_solver"]


def schur_solver(problem: Problem, eliminate: Any = None, reduced: str = "auto") -> SchurSolver:
    """The solver of a :class:`~microlie.optim.core.problem.Problem` that eliminates the free
    variables of the batches ``eliminate`` (default:
    :func:`~microlie.optim.core.landmarks.landmark_batches`).

    Parameters
    ----------
    problem : Problem
        The problem (its node numbering and factors).
    eliminate : Variables or sequence of Variables, optional
        Batches to eliminate; no two of their variables may share a factor.
    reduced : str
        The backend of the reduced system (see :class:`SchurSolver`).

    Returns
    -------
    SchurSolver
        Not analysed yet.

    Raises
    ------
    ValueError
        ``eliminate`` names a batch not in the problem, without free variables, or whose
        variables share a factor (with each other or another named batch), or leaves
        nothing to reduce to; or (default) no batch qualifies.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import CustomFactor, FactorGraph, PriorFactor
    >>> from microlie.optim.core.elimination import schur_solver
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1), name="x")
    >>> p = g.add_variables(np.zeros((4, 2)), name="p")
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(CustomFactor(lambda a, b: b - a.translation(), [(x, [0] * 4),
    ...                        (p, range(4))], 2))
    >>> s = schur_solver(g.problem())
    >>> s.eliminated.tolist()  # the four points (node 0 is x[0])
    [1, 2, 3, 4]
    """
    batches = _chosen(problem, eliminate)
    nodes = np.concatenate([problem.node_of[problem.key(v)] for v in batches])
    return SchurSolver(problem.node_off, nodes[nodes >= 0], reduced)


def _chosen(problem: Problem, eliminate: Any) -> list[Variables]:
    """The batches to eliminate: ``eliminate`` checked, or
    :func:`~microlie.optim.core.landmarks.landmark_batches`."""
    if eliminate is None:
        batches = landmark_batches(problem)
        if not batches:
            raise ValueError(
                "linear_solver='schur' found no variables to eliminate: no variable batch has "
                "free variables that share no factor with each other (landmarks), or "
                "eliminating them would leave nothing; pass eliminate=[handles] or use "
                "linear_solver='cholesky'")
        return batches
    items = [eliminate] if isinstance(eliminate, Variables) else list(eliminate)
    if not items:
        raise ValueError("eliminate is empty: pass variable handles, or None for the default")
    conflict, why = batch_conflicts(problem)
    keys: list[int] = []
    for i, v in enumerate(items):
        if not isinstance(v, Variables) or id(v) not in {id(u) for u in problem.variables}:
            raise ValueError(f"eliminate[{i}] is not a variable handle of this graph: pass "
                             f"handles returned by add_variables")
        k = problem.key(v)
        if k in keys:
            raise ValueError(f"eliminate names {v.name!r} twice")
        if not (problem.node_of[k] >= 0).any():
            raise ValueError(f"eliminate: every variable of {v.name!r} is fixed; nothing to "
                             f"eliminate")
        if conflict[k, k]:
            raise ValueError(f"eliminate: variables of {v.name!r} share a factor with each "
                             f"other ({why[k][k]}); only variables that share no factor can be "
                             f"eliminated")
        for j in keys:
            if conflict[j, k]:
                raise ValueError(f"eliminate: {problem.variables[j].name!r} and {v.name!r} "
                                 f"share a factor ({why[j][k]}); only variables that share no "
                                 f"factor can be eliminated together")
        keys.append(k)
    size = sum(int((problem.node_of[k] >= 0).sum()) * problem.variables[k].dof for k in keys)
    if size >= problem.size:
        raise ValueError("eliminate names every free variable: leave some to reduce to")
    return [problem.variables[k] for k in sorted(keys)]
