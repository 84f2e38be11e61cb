"""Which variables ``linear_solver="schur"`` eliminates: the landmark-like batches of a
:class:`~microlie.optim.core.problem.Problem` (variables that share no factor with each other),
checked or chosen, and the :class:`~microlie.optim.linalg.schur_solver.SchurSolver` that
eliminates them (the solver itself knows only the node numbering)."""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations
from typing import Any

import numpy as np

from ..linalg.schur_solver import SchurSolver
from .variables import Variables

# a Problem is passed in, not imported: problem.py calls this module (no import cycle)
Problem = Any

__all__ = ["schur_solver", "landmark_batches", "bundle_landmarks"]


def schur_solver(problem: Problem, eliminate: Any = None, reduced: str = "auto") -> SchurSolver:
    """The solver of a :class:`~microlie.optim.core.problem.Problem` that eliminates the free
    variables of the batches ``eliminate`` (default: :func:`landmark_batches`).

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


def _conflicts(problem: Problem) -> tuple[np.ndarray, list[list[str]]]:
    """Which variable batches share a factor (both arguments free in some row): a boolean
    matrix over the problem's batches (the diagonal: two variables of one batch), and the
    first factor batch responsible for each entry, for messages."""
    nb = len(problem.variables)
    conflict = np.zeros((nb, nb), dtype=bool)
    why: list[list[str]] = [[""] * nb for _ in range(nb)]
    for fi, (f, nodes) in enumerate(zip(problem.factors, problem.fargs, strict=True)):
        keys = [problem.key(var) for var, _ in f.args]
        for k, l in combinations(range(len(keys)), 2):
            if np.any((nodes[k] >= 0) & (nodes[l] >= 0)):
                a, b = keys[k], keys[l]
                if not conflict[a, b]:
                    why[a][b] = why[b][a] = f"factor batch {fi} ({f.name})"
                conflict[a, b] = conflict[b, a] = True
    return conflict, why


def landmark_batches(problem: Problem) -> list[Variables]:
    """The default elimination set of ``linear_solver="schur"``: among the variable batches
    whose free variables share no factor with each other (landmark-like), the set of batches
    that share no factor with one another with the most unknowns, leaving at least one free
    variable outside it.

    Parameters
    ----------
    problem : Problem
        The problem.

    Returns
    -------
    list of Variables
        In graph order; empty when no batch qualifies.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import BetweenFactor, CustomFactor, FactorGraph, PriorFactor
    >>> from microlie.optim.core.elimination import landmark_batches
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(2), name="x")
    >>> p = g.add_variables(np.zeros((3, 2)), name="p")
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, 0, 1, SE2.identity()))
    >>> _ = g.add(CustomFactor(lambda a, b: b - a.translation(), [(x, [0, 1, 1]),
    ...                        (p, [0, 1, 2])], 2))
    >>> [v.name for v in landmark_batches(g.problem())]
    ['p']
    """
    conflict, _ = _conflicts(problem)
    nvar = len(problem.variables)
    unknowns = np.array([int((problem.node_of[k] >= 0).sum()) * problem.variables[k].dof
                         for k in range(nvar)])
    cand = [k for k in range(nvar) if unknowns[k] and not conflict[k, k]]
    best: tuple[int, ...] = ()
    best_size = 0

    def ok(sub: Sequence[int]) -> bool:
        return not any(conflict[a, b] for a, b in combinations(sub, 2))

    if len(cand) <= 12:
        for r in range(1, len(cand) + 1):
            for sub in combinations(cand, r):
                size = int(unknowns[list(sub)].sum())
                if best_size < size < problem.size and ok(sub):
                    best, best_size = sub, size
    else:  # greedily by size
        chosen: list[int] = []
        for k in sorted(cand, key=lambda k: -unknowns[k]):
            size = int(unknowns[[*chosen, k]].sum())
            if size < problem.size and ok([*chosen, k]):
                chosen.append(k)
        best = tuple(sorted(chosen))
    return [problem.variables[k] for k in best]


def bundle_landmarks(problem: Problem) -> list[Variables]:
    """The landmarks of a bundle adjustment: :func:`landmark_batches` of a problem with
    reprojection factors (:class:`~microlie.optim.sfm.reprojection.ReprojectionFactor`), else
    none. ``LevenbergMarquardt(damping="auto")`` and the device engine damp such a problem with
    ``diag(H)``; the device engine eliminates them in its Schur step.

    Parameters
    ----------
    problem : Problem
        The problem.

    Returns
    -------
    list of Variables
        In graph order; empty without reprojection factors or landmark-like batches.

    Examples
    --------
    >>> from microlie.optim.core.elimination import bundle_landmarks
    >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
    >>> _, start = synthetic_scene(n_cameras=3, n_points=20, seed=0)
    >>> bg = bundle_graph(start)
    >>> [v.name for v in bundle_landmarks(bg.graph.problem("none"))]
    ['points']
    """
    if not any(type(f).__name__ == "ReprojectionFactor" for f in problem.factors):
        return []  # no import of sfm here: sfm builds on core
    return landmark_batches(problem)


def _chosen(problem: Problem, eliminate: Any) -> list[Variables]:
    """The batches to eliminate: ``eliminate`` checked, or :func:`landmark_batches`."""
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
    conflict, why = _conflicts(problem)
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
