"""GTSAM's wildfire by cliques: the partial back-substitution of
:class:`~microlie.optim.online.incremental.IncrementalSmoother` (ISAM2's ``optimizeWildfire``).

After an update the re-eliminated nodes get their step from the root down (all *changed*).
Below them, the orphan subtrees are visited clique by clique (a clique: a node that is not
nested in its parent, ``chain == 0``, and the chain of nested children below it, eliminated as
one front): a clique is recomputed when a variable of its separator changed; it keeps its new
steps, all marked changed, when one of its frontal components moved by ``wildfire`` or more,
and its old steps otherwise; the cliques below a recomputed clique are visited. Deciding per
clique rather than per variable (the tree's own
:meth:`~microlie.optim.online.bayes_tree.BayesTree.backsubstitute`) is GTSAM's rule: a clique
whose first variable moves takes all its variables along, which leaves fewer stale steps.

One compiled call (``microlie._c._online.backsubstitute_cliques``) when it is built, else the
NumPy function below (the same arithmetic).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .bayes_tree import BayesTree

__all__ = ["backsubstitute_cliques"]

_MAX_FRONT = 64  # a longer chain is taken as cliques of this many (as the compiled code does)


def backsubstitute_cliques(tree: BayesTree, order: np.ndarray, orphans: np.ndarray,
                           dx: np.ndarray, wildfire: float, module: Any = None,
                           scratch: np.ndarray | None = None) -> int:
    """The wildfire back-substitution by cliques (see the module docstring) into ``dx``.

    Parameters
    ----------
    tree : BayesTree
        The factorisation, ``order`` just re-eliminated and ``orphans`` the roots of the
        subtrees left below it.
    order : numpy.ndarray
        The re-eliminated nodes (int64), in elimination order.
    orphans : numpy.ndarray
        The orphan roots (int64).
    dx : numpy.ndarray
        The step (float64), updated in place.
    wildfire : float
        The threshold (tangent units; 0: every clique below a change is recomputed and kept).
    module : module, optional
        ``microlie._c._online`` (``None``: the NumPy path).
    scratch : numpy.ndarray, optional
        float64 zeros, one per node at least (the compiled path's changed flags; returned to
        zero).

    Returns
    -------
    int
        The number of nodes computed.

    Examples
    --------
    >>> import numpy as np
    >>> t = BayesTree(compiled=False)
    >>> a, b = t.add_node(1, 0), t.add_node(1, 1)
    >>> _ = t.add_row([a], np.array([[4.0]]), np.array([4.0]))           # 4 x_a = 4
    >>> _ = t.add_row([a, b], np.array([[1.0, -1.0], [-1.0, 1.0]]), np.zeros(2))
    >>> top, orphans, rows = t.detach(np.array([a, b]))
    >>> t.pos[[a, b]] = [0, 1]
    >>> t.eliminate(np.array([a, b]), rows, orphans)
    >>> dx = np.zeros(2)
    >>> backsubstitute_cliques(t, np.array([a, b]), orphans, dx, 0.001), dx.round(12).tolist()
    (2, [1.0, 1.0])
    """
    order = np.ascontiguousarray(order, dtype=np.int64)
    orphans = np.ascontiguousarray(orphans, dtype=np.int64)
    if module is not None:
        if scratch is None or scratch.size < tree.n:
            scratch = np.zeros(max(tree.n, 1))
        return int(module.backsubstitute_cliques(order, orphans, dx, tree.off, tree.dof,
                                                 tree.sep, tree.Rinv, tree.T, tree.c,
                                                 tree.child, tree.sib, tree.chain,
                                                 float(wildfire), scratch))
    off, dof = tree.off, tree.dof

    def solve(k: int) -> float:
        sep = tree.sep[k]
        if sep.size:
            cols = np.concatenate([np.arange(off[s], off[s] + dof[s]) for s in sep.tolist()])
            v = tree.c[k] - tree.T[k] @ dx[cols]
        else:
            v = tree.c[k]
        o0, o1 = int(off[k]), int(off[k] + dof[k])
        new = tree.Rinv[k] @ v
        moved = float(np.max(np.abs(new - dx[o0:o1]))) if new.size else 0.0
        dx[o0:o1] = new
        return moved

    changed: set[int] = set()
    for k in order[::-1].tolist():
        solve(k)
        changed.add(k)
    count = int(order.size)
    stack = orphans.tolist()
    while stack:
        r = stack.pop()
        if not changed.intersection(tree.sep[r].tolist()):
            continue
        front = [r]
        while len(front) < _MAX_FRONT:  # the chain of nested children
            ch, nxt = int(tree.child[front[-1]]), -1
            while ch >= 0:
                if tree.chain[ch]:
                    nxt = ch
                ch = int(tree.sib[ch])
            if nxt < 0:
                break
            front.append(nxt)
        old = [dx[off[j]:off[j] + dof[j]].copy() for j in front]
        moved = max(solve(j) for j in front)  # in order: each uses the ones above it
        count += len(front)
        if not moved < wildfire:
            changed.update(front)
        else:
            for j, x in zip(front, old, strict=True):
                dx[off[j]:off[j] + dof[j]] = x
        for a, j in enumerate(front):
            ch = int(tree.child[j])
            while ch >= 0:
                if not (a + 1 < len(front) and ch == front[a + 1]):
                    stack.append(ch)
                ch = int(tree.sib[ch])
    return count
