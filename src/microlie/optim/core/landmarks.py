"""Which variables are landmarks: the variable batches of a
:class:`~microlie.optim.core.problem.Problem` whose free variables share no factor with each
other, the set of them that ``linear_solver="schur"`` eliminates by default
(:func:`landmark_batches`), and those of a bundle adjustment (:func:`bundle_landmarks`), which
``LevenbergMarquardt(damping="auto")`` and the device engine's Schur step use. NumPy only: a
pose graph's solve imports this module, not the SciPy-backed
:mod:`~microlie.optim.core.elimination`."""

from __future__ import annotations

from collections.abc import Sequence
from itertools import combinations
from typing import Any

import numpy as np

from .variables import Variables

# a Problem is passed in, not imported: problem.py calls this module (no import cycle)
Problem = Any

__all__ = ["batch_conflicts", "bundle_landmarks", "landmark_batches"]


def batch_conflicts(problem: Problem) -> tuple[np.ndarray, list[list[str]]]:
    """Which variable batches share a factor (both arguments free in some row).

    Parameters
    ----------
    problem : Problem
        The problem.

    Returns
    -------
    conflict : numpy.ndarray
        ``(B, B)`` booleans over the problem's variable batches (the diagonal: two variables
        of one batch share a factor).
    why : list of list of str
        The first factor batch responsible for each entry, for messages.

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor, PriorFactor
    >>> from microlie.optim.core.landmarks import batch_conflicts
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3), fixed=[0])
    >>> y = g.add_variables(SE2.identity(1))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.identity(2)))
    >>> _ = g.add(PriorFactor(y, 0, SE2.identity()))
    >>> conflict, why = batch_conflicts(g.problem())
    >>> conflict.tolist(), why[0][0]
    ([[True, False], [False, False]], 'factor batch 0 (BetweenFactor)')
    """
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
    >>> from microlie.optim.core.landmarks import landmark_batches
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
    conflict, _ = batch_conflicts(problem)
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
    >>> from microlie.optim.core.landmarks import bundle_landmarks
    >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
    >>> _, start = synthetic_scene(n_cameras=3, n_points=20, seed=0)
    >>> bg = bundle_graph(start)
    >>> [v.name for v in bundle_landmarks(bg.graph.problem("none"))]
    ['points']
    """
    if not any(type(f).__name__ == "ReprojectionFactor" for f in problem.factors):
        return []  # no import of sfm here: sfm builds on core
    return landmark_batches(problem)
