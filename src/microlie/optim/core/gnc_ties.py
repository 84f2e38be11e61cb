"""Exact ties of the truncated-least-squares objective on pose graphs: bridges and swaps.

The TLS objective of GNC is ``0.5 * sum_k min(s_k, c^2)`` over the judged edges, ``s_k`` the
whitened squared residual and ``c^2`` the inlier threshold. Take the true inlier graph (the
good edges only) and a bridge ``b`` of it: removing ``b`` splits it into two sides. When a
wrong edge ``w`` also joins the two sides, the poses obtained by moving one side rigidly so
that ``w`` fits exactly (:func:`swap_witness`) keep every residual inside each side; ``w``
goes from rejected (``c^2/2``) to ``0`` and ``b`` from nearly ``0`` to rejected (``c^2/2``),
so the objective is the same up to ``b``'s own residual, and any other wrong edge across
the cut stays rejected unless it happens to fit. The TLS optimum is then not unique, and the
two minimisers can be metres apart: no TLS solver can be asked to pick the true one without
a prior (known inliers, or the start values). :func:`tie_bridges` lists these bridges
("tie-capable"); :func:`bridges` is the bridge finder it uses (Tarjan's low-link, iterative,
on the multigraph: an edge with a parallel twin is never a bridge).

Conventions: vertices ``0 .. n-1``, edge ``k`` joins ``ii[k]`` and ``jj[k]`` and measures
``X_i^-1 X_j = Z_k``; self-loops are allowed and are never bridges.

Examples
--------
>>> import numpy as np
>>> from microlie.optim.core.gnc_ties import bridges, tie_bridges
>>> # a triangle 0-1-2 with the chain 2-3-4 hanging on it; edge 5 (0-4) is wrong
>>> ii, jj = np.array([0, 1, 2, 2, 3, 0]), np.array([1, 2, 0, 3, 4, 4])
>>> bridges(5, ii[:5], jj[:5]).tolist()
[3, 4]
>>> [(t.edge, t.side.tolist(), t.wrong.tolist())
...  for t in tie_bridges(5, ii, jj, np.arange(6) < 5)]
[(3, [3, 4], [5]), (4, [4], [5])]
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ...groups import LieGroup

__all__ = ["AnswerTie", "TieBridge", "answer_ties", "bridges", "swap_witness", "tie_bridges"]


def _edges(n: int, ii: Any, jj: Any) -> tuple[np.ndarray, np.ndarray]:
    if int(n) != n or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n!r}")
    a = np.asarray(ii)
    b = np.asarray(jj)
    if a.ndim != 1 or a.shape != b.shape:
        raise ValueError(f"ii and jj must be 1-D of one length, got shapes {a.shape} and "
                         f"{b.shape}")
    if a.size and not (np.issubdtype(a.dtype, np.integer) and np.issubdtype(b.dtype,
                                                                             np.integer)):
        raise ValueError("ii and jj must hold integer vertex indices")
    a = a.astype(np.int64)
    b = b.astype(np.int64)
    if a.size and (min(a.min(), b.min()) < 0 or max(a.max(), b.max()) >= n):
        raise ValueError(f"vertex indices must lie in [0, {n}), got [{min(a.min(), b.min())}, "
                         f"{max(a.max(), b.max())}]")
    return a, b


def _dfs(n: int, ii: np.ndarray, jj: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Iterative depth-first search: pre-order number ``tin``, subtree size, parent edge
    (-1 at roots), root of the tree, and the bridge flag per edge and low-link per vertex."""
    E = ii.size
    ends = np.concatenate([ii, jj])
    other = np.concatenate([jj, ii]).tolist()
    eid = np.concatenate([np.arange(E), np.arange(E)])
    order = np.argsort(ends, kind="stable")
    start = np.searchsorted(ends[order], np.arange(n + 1)).tolist()
    oth = [other[k] for k in order.tolist()]
    eids = eid[order].tolist()
    tin = [-1] * n
    low = [0] * n
    size = [1] * n
    pedge = [-1] * n
    par = [-1] * n
    root = [-1] * n
    ptr = list(start[:n])
    t = 0
    for r in range(n):
        if tin[r] >= 0:
            continue
        tin[r] = low[r] = t
        t += 1
        root[r] = r
        stack = [r]
        while stack:
            v = stack[-1]
            k = ptr[v]
            if k < start[v + 1]:
                ptr[v] = k + 1
                e = eids[k]
                if e == pedge[v]:
                    continue  # the tree edge to the parent (its parallel twins do count)
                w = oth[k]
                if tin[w] < 0:
                    tin[w] = low[w] = t
                    t += 1
                    pedge[w] = e
                    par[w] = v
                    root[w] = r
                    stack.append(w)
                elif tin[w] < low[v]:
                    low[v] = tin[w]
            else:
                stack.pop()
                p = par[v]
                if p >= 0:
                    if low[v] < low[p]:
                        low[p] = low[v]
                    size[p] += size[v]
    is_bridge = np.zeros(E, dtype=bool)
    for v in range(n):
        if pedge[v] >= 0 and low[v] > tin[par[v]]:
            is_bridge[pedge[v]] = True
    return (np.array(tin, dtype=np.int64), np.array(size, dtype=np.int64),
            np.array(pedge, dtype=np.int64), np.array(root, dtype=np.int64), is_bridge,
            np.array(low, dtype=np.int64))


def bridges(n: int, ii: Any, jj: Any) -> np.ndarray:
    """The bridges of an undirected multigraph: edges whose removal disconnects their ends.

    Parameters
    ----------
    n : int
        Number of vertices.
    ii, jj : array_like
        ``(E,)`` integer end vertices of the edges, in ``[0, n)``.

    Returns
    -------
    numpy.ndarray
        Sorted indices of the bridge edges. Parallel edges (same two ends) and self-loops
        are never bridges.

    Raises
    ------
    ValueError
        Bad shapes, non-integer or out-of-range indices.

    Examples
    --------
    >>> from microlie.optim.core.gnc_ties import bridges
    >>> bridges(4, [0, 1, 1, 2], [1, 2, 2, 3]).tolist()  # 1-2 doubled: not a bridge
    [0, 3]
    """
    a, b = _edges(n, ii, jj)
    return np.flatnonzero(_dfs(int(n), a, b)[4])


@dataclass(frozen=True)
class TieBridge:
    """A bridge of the good edges whose two sides a wrong edge also joins.

    Attributes
    ----------
    edge : int
        Index of the bridge edge.
    side : numpy.ndarray
        Sorted vertices of its smaller side (within its connected component; the side
        without the DFS root on a draw).
    wrong : numpy.ndarray
        Sorted indices of the wrong edges with one end on each side.
    """

    edge: int
    side: np.ndarray
    wrong: np.ndarray


def tie_bridges(n: int, ii: Any, jj: Any, good: Any, judged: Any = None) -> list[TieBridge]:
    """The tie-capable bridges: bridges of the good edges crossed by a wrong edge.

    Parameters
    ----------
    n : int
        Number of vertices.
    ii, jj : array_like
        ``(E,)`` integer end vertices of every edge (good and wrong).
    good : array_like
        ``(E,)`` booleans: True for the true inliers.
    judged : array_like, optional
        ``(E,)`` booleans: False for known inliers, which TLS never rejects, so a known
        bridge cannot make a tie; default every edge judged.

    Returns
    -------
    list of TieBridge
        Largest smaller side first (then by bridge index).

    Raises
    ------
    ValueError
        Bad shapes or indices.

    Examples
    --------
    >>> from microlie.optim.core.gnc_ties import tie_bridges
    >>> # the path 0-1-2-3 and a wrong edge 0-3: every path edge is a tie-capable bridge
    >>> [(t.edge, t.side.tolist()) for t in tie_bridges(4, [0, 1, 2, 0], [1, 2, 3, 3],
    ...                                                 [True, True, True, False])]
    [(1, [2, 3]), (0, [0]), (2, [3])]
    """
    a, b = _edges(n, ii, jj)
    g = np.asarray(good, dtype=bool)
    if g.shape != a.shape:
        raise ValueError(f"good must have shape {a.shape}, got {g.shape}")
    jd = np.ones(a.size, dtype=bool) if judged is None else np.asarray(judged, dtype=bool)
    if jd.shape != a.shape:
        raise ValueError(f"judged must have shape {a.shape}, got {jd.shape}")
    gi = np.flatnonzero(g)
    tin, size, pedge, root, is_br, _ = _dfs(int(n), a[gi], b[gi])
    child = np.flatnonzero(pedge >= 0)
    child = child[is_br[pedge[child]] & jd[gi[pedge[child]]]]
    wrong = np.flatnonzero(~g & (a != b))
    out: list[TieBridge] = []
    if child.size == 0 or wrong.size == 0:
        return out
    lo = tin[child]
    hi = lo + size[child]
    ta, tb = tin[a[wrong]], tin[b[wrong]]
    # (bridges, wrong edges): both ends in the bridge's component, exactly one in the subtree
    same = (root[a[wrong]][None, :] == root[child][:, None]) & (
        root[b[wrong]][None, :] == root[child][:, None])
    in_a = (ta[None, :] >= lo[:, None]) & (ta[None, :] < hi[:, None])
    in_b = (tb[None, :] >= lo[:, None]) & (tb[None, :] < hi[:, None])
    cross = same & (in_a != in_b)
    csize = size[root[child]]
    for k in np.flatnonzero(cross.any(axis=1)):
        v = child[k]
        in_sub = (root == root[v]) & (tin >= lo[k]) & (tin < hi[k])
        if size[v] > csize[k] - size[v]:
            in_sub = (root == root[v]) & ~in_sub
        out.append(TieBridge(int(gi[pedge[v]]), np.flatnonzero(in_sub),
                             wrong[cross[k]]))
    out.sort(key=lambda t: (-t.side.size, t.edge))
    return out


def swap_witness(X: LieGroup, ii: Any, jj: Any, Z: LieGroup, side: Any, edge: int,
                 fixed: int | None = None) -> LieGroup:
    """Move one side of a cut rigidly so that an edge across it fits exactly.

    With ``X_i^-1 X_j = Z`` the edge's measurement and ``j`` on the moving side, every pose
    ``X_v`` of that side becomes ``D X_v`` with ``D = X_i Z X_j^-1`` (``i`` on it:
    ``D = X_j Z^-1 X_i^-1``); residuals of edges within either side are unchanged.

    Parameters
    ----------
    X : LieGroup
        ``(n,)`` poses.
    ii, jj : array_like
        ``(E,)`` end vertices of the edges.
    Z : LieGroup
        ``(E,)`` measurements.
    side : array_like
        Vertex indices of the side to move.
    edge : int
        The edge to make fit; exactly one of its ends must be in ``side``.
    fixed : int, optional
        A vertex that must keep its pose (the gauge): when it is in ``side``, the other
        side moves instead (the same relative poses, so the same residuals).

    Returns
    -------
    LieGroup
        ``(n,)`` the new poses.

    Raises
    ------
    ValueError
        An edge index out of range, or an edge not across the cut.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_ties import swap_witness
    >>> X = SE2.from_xy_theta([0.0, 1.0, 2.0], 0.0, 0.0)
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 5.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.5])
    >>> Y = swap_witness(X, [0, 1, 0], [1, 2, 2], Z, [2], 2)  # make 0 -> 2 fit
    >>> np.round(Y[0].between(Y[2]).log() - Z[2].log(), 12).tolist()
    [0.0, 0.0, 0.0]
    """
    n = X.batch_shape[0]
    a, b = _edges(n, ii, jj)
    if not 0 <= edge < a.size:
        raise ValueError(f"edge {edge} out of range for {a.size} edges")
    mask = np.zeros(n, dtype=bool)
    mask[np.asarray(side, dtype=np.int64)] = True
    if fixed is not None and mask[fixed]:
        mask = ~mask
    i, j = int(a[edge]), int(b[edge])
    if mask[i] == mask[j]:
        raise ValueError(f"edge {edge} ({i}-{j}) does not cross the cut")
    z = Z[edge]
    if mask[j]:
        D = X[i].compose(z).compose(X[j].inverse())
    else:
        D = X[j].compose(z.inverse()).compose(X[i].inverse())
    idx = np.flatnonzero(mask)
    P = np.array(X.params, dtype=np.float64)
    P[idx] = np.asarray(D.compose(X[idx]).params, dtype=np.float64)
    return type(X).from_params(P, check=False)


@dataclass(frozen=True)
class AnswerTie:
    """A piece of GNC's answer that another edge could hold at the same TLS objective.

    Attributes
    ----------
    held_by : tuple of int
        ``(factor batch, row)`` of the accepted edge that alone joins the piece to the rest.
    poses : numpy.ndarray
        Sorted vertex indices of the piece (the smaller side of the cut).
    alternatives : list of tuple of int
        ``(factor batch, row)`` of the rejected edges across the same cut: moving the piece
        rigidly until one of them fits and rejecting ``held_by`` gives the same objective.
    """

    held_by: tuple[int, int]
    poses: np.ndarray
    alternatives: list[tuple[int, int]]


def answer_ties(problem: Any, edges: Any, inliers: list[np.ndarray],
                judged: list[np.ndarray]) -> list[AnswerTie]:
    """The exact ties of a GNC-TLS answer on a pose graph: accepted judged edges that are
    bridges of the accepted edges while a rejected judged edge joins the same two sides.

    At a least-squares optimum of the accepted edges such a bridge has residual 0 (nothing
    else holds its piece); swapping it for a rejected edge across its cut (the piece moved
    rigidly until that edge fits, :func:`swap_witness`) changes no other residual, so the TLS
    objective stays the same (or falls, if more rejected edges then fit): the answer is one of
    several optima, which the data alone cannot tell apart. Priors count as edges to the
    anchor, fixed vertices as known edges to it.

    Parameters
    ----------
    problem : Problem
        The pose-graph problem.
    edges : PoseGraphEdges
        Its edges (:func:`~microlie.optim.core.gnc_chordal.pose_graph_edges`).
    inliers : list of numpy.ndarray
        GNC's verdict per factor batch.
    judged : list of numpy.ndarray
        Per factor batch, False for the caller's known inliers.

    Returns
    -------
    list of AnswerTie
        Largest piece first.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_ties import answer_ties
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(4), fixed=[0])
    >>> # a triangle 0-1-2, vertex 3 held by edge 3 (2-3); edge 4 (0-3) was rejected
    >>> _ = g.add(BetweenFactor(x, [0, 1, 2, 2, 0], [1, 2, 0, 3, 3], SE2.identity(5)))
    >>> p = g.problem()
    >>> t = answer_ties(p, pose_graph_edges(p), [np.array([1, 1, 1, 1, 0], bool)],
    ...                 [np.ones(5, bool)])
    >>> [(a.held_by, a.poses.tolist(), a.alternatives) for a in t]
    [((0, 3), [3], [(0, 4)])]
    """
    from .factors import PriorFactor

    where = np.empty((edges.ii.size, 2), dtype=np.int64)
    for k, sl in edges.rows:
        where[sl, 0] = k
        where[sl, 1] = np.arange(sl.stop - sl.start)
    ii, jj = [edges.ii], [edges.jj]
    acc = [np.concatenate([inliers[k] for k, _ in edges.rows])]
    jud = [np.concatenate([judged[k] for k, _ in edges.rows])]
    wh = [where]
    var, a = edges.variables, edges.anchor
    for k, f in enumerate(problem.factors):
        if isinstance(f, PriorFactor):
            v = np.asarray(f.args[0][1], dtype=np.int64).reshape(-1)
            ii.append(np.full(v.size, a))
            jj.append(v)
            acc.append(np.asarray(inliers[k], dtype=bool))
            jud.append(np.asarray(judged[k], dtype=bool))
            wh.append(np.stack([np.full(v.size, k), np.arange(v.size)], axis=1))
    held = np.flatnonzero(np.asarray(var.fixed, dtype=bool))
    ii.append(np.full(held.size, a))
    jj.append(held)
    acc.append(np.ones(held.size, dtype=bool))
    jud.append(np.zeros(held.size, dtype=bool))
    wh.append(np.full((held.size, 2), -1, dtype=np.int64))
    W = np.concatenate(wh)
    # a rejected edge is judged (known inliers are always accepted): each one across the cut
    # of an accepted judged bridge is an alternative
    return [AnswerTie((int(W[t.edge, 0]), int(W[t.edge, 1])), t.side,
                      [(int(W[e, 0]), int(W[e, 1])) for e in t.wrong])
            for t in tie_bridges(edges.n, np.concatenate(ii), np.concatenate(jj),
                                 np.concatenate(acc), np.concatenate(jud))]
