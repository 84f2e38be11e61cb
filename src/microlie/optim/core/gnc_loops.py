"""Longer cycles: edges that close a cycle of up to seven edges within its noise.

:func:`~microlie.optim.core.gnc_cycles.consistent_edges` tries cycles of 3-5 edges. On
sphere2500 with half of the loop closures replaced by random ones most good edges lie on no
such cycle any more (the ring-to-ring closures that remain are about two poses apart, so the
shortest cycles through them have six edges): 1662 of its 3724 good edges are left unmarked
at 50% (seed 0). :func:`cycle_consistent_edges` tries every cycle of at most ``max_length``
edges (default 7) with the same test: an edge ``e = (i, j)`` is marked when some path from
``i`` to ``j`` that does not use ``e``, walks no edge twice and visits no vertex twice within
each half, composes to a pose ``T`` with

``r = Log(Z_e^-1 T)``, ``r^T (Sigma_path + Sigma_e)^-1 r <= chi2.ppf(quantile, dof)``,

``Sigma_path`` the first-order covariance of the composed path (right perturbations, as in
:mod:`microlie.optim.core.gnc_cycles`). Paths are two half-paths of 0-3 steps (built by
extending paths one step at a time: every simple path from every vertex) joined at a common
vertex, the first at least as long as the second; the parallel edges of ``e`` are cycles of
two edges. The marked edges become known inliers of GNC (``GNC(first="cycles",
cycle_length=...)``).

Examples
--------
>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.core.gnc_loops import cycle_consistent_edges
>>> # a hexagon of unit steps turning 60 degrees and one random chord 0-3
>>> a = np.pi / 3
>>> Z = SE2.from_xy_theta([1.0] * 6 + [4.0], [0.0] * 6 + [1.0], [a] * 6 + [0.5])
>>> ii, jj = np.array([0, 1, 2, 3, 4, 5, 0]), np.array([1, 2, 3, 4, 5, 0, 3])
>>> info = np.tile(np.eye(3) * 100.0, (7, 1, 1))
>>> cycle_consistent_edges(SE2, 6, ii, jj, Z, info).tolist()  # the 6-cycle closes
[True, True, True, True, True, True, False]
>>> cycle_consistent_edges(SE2, 6, ii, jj, Z, info, max_length=5).tolist()
[False, False, False, False, False, False, False]
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...groups import SE2, SE3, LieGroup
from .gnc_bridges import whitened_residuals

__all__ = ["cycle_consistent_edges", "mark_loops", "move_pieces", "move_regions",
           "move_stage"]


def _ranges(first: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For sorted groups with starts ``first``: (owner index, position) of every member of the
    groups ``keys`` (``first[k]`` to ``first[k + 1]``)."""
    cnt = first[keys + 1] - first[keys]
    own = np.repeat(np.arange(keys.size), cnt)
    pos = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt) + \
        np.repeat(first[keys], cnt)
    return own, pos


def cycle_consistent_edges(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                           info: np.ndarray, *, max_length: int = 7, quantile: float = 0.99,
                           chunk: int = 128, support: int = 1, single: int = 5
                           ) -> np.ndarray:
    """Edges that lie on a cycle of at most ``max_length`` edges that closes within its noise
    (module docstring).

    Parameters
    ----------
    group : type
        SE2 or SE3.
    n : int
        Number of vertices.
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges ``X_i^-1 X_j = Z``.
    Z : LieGroup
        ``(E,)`` measurements.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices (positive definite, the group's tangent order).
    max_length : int
        Longest cycle tried, in edges, 2 to 7.
    quantile : float
        Chi-square quantile of the cycle test, ``0 < quantile < 1``.
    chunk : int
        Edges tested together (bounds the memory), >= 1.
    support : int
        An edge whose consistent cycles are all longer than ``single`` edges needs at least
        this many of them, >= 1.
    single : int
        Cycles of at most this many edges mark an edge alone.

    Returns
    -------
    numpy.ndarray
        ``(E,)`` booleans: True for an edge on a consistent cycle.

    Raises
    ------
    ValueError
        A group other than SE2/SE3, bad shapes or an option out of range.

    Examples
    --------
    See the module docstring.
    """
    from scipy.stats import chi2  # type: ignore[import-untyped]

    if group not in (SE2, SE3):
        raise ValueError(f"cycle_consistent_edges: group must be SE2 or SE3, got {group!r}")
    if isinstance(max_length, bool) or not isinstance(max_length, (int, np.integer)) or \
            not 2 <= max_length <= 9:
        raise ValueError(f"cycle_consistent_edges: max_length must be an integer from 2 to 7, "
                         f"got {max_length!r}")
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"cycle_consistent_edges: quantile must be strictly between 0 and 1, "
                         f"got {quantile!r}")
    for name, val in (("chunk", chunk), ("support", support), ("single", single)):
        if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < 1:
            raise ValueError(f"cycle_consistent_edges: {name} must be an integer >= 1, got "
                             f"{val!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    E = ii.size
    if jj.shape != (E,) or np.shape(info)[0] != E or \
            (E and (min(ii.min(), jj.min()) < 0 or max(ii.max(), jj.max()) >= n)):
        raise ValueError("cycle_consistent_edges: ii, jj and info must have one entry per "
                         "edge, with vertices in [0, n)")
    ok = np.zeros(E, dtype=bool)
    if E == 0:
        return ok
    cov = np.linalg.inv(info)
    M = np.asarray(Z.matrix(), dtype=np.float64)
    Ad = np.asarray(Z.adjoint(), dtype=np.float64)
    Adinv = np.asarray(Z.inverse().adjoint(), dtype=np.float64)
    # directed steps: s < E walks edge s forwards (Z, Sigma), s >= E backwards (Z^-1,
    # Ad(Z) Sigma Ad(Z)^T); Ad(step^-1) transports a path's covariance past the step
    s_tail, s_head = np.concatenate([ii, jj]), np.concatenate([jj, ii])
    s_edge = np.concatenate([np.arange(E), np.arange(E)])
    s_T = np.concatenate([M, np.linalg.inv(M)])
    s_S = np.concatenate([cov, Ad @ cov @ np.swapaxes(Ad, 1, 2)])
    s_A = np.concatenate([Adinv, Ad])
    loops = s_tail == s_head
    s_order = np.argsort(s_tail, kind="stable")
    s_first = np.searchsorted(s_tail[s_order], np.arange(n + 1))
    half = (max_length - 1 + 1) // 2  # the longer half has at most this many steps
    m, D = M.shape[-1], info.shape[-1]
    # half-paths by length: 0 steps (every vertex), then extended by one step at a time
    L = half + 1
    h_tail = [np.arange(n)]
    h_head = [np.arange(n)]
    h_edges = [np.full((n, L), -1, np.int64)]
    h_verts = [np.concatenate([np.arange(n)[:, None], np.full((n, L), -1, np.int64)], 1)]
    h_T = [np.broadcast_to(np.eye(m), (n, m, m))]
    h_S = [np.zeros((n, D, D))]
    h_A = [np.broadcast_to(np.eye(D), (n, D, D))]
    for k in range(1, half + 1):
        own, pos = _ranges(s_first, h_head[-1])
        q = s_order[pos]
        ed, ve = h_edges[-1][own], h_verts[-1][own]
        use = ~loops[q] & ~np.any(ed == s_edge[q][:, None], 1) & \
            ~np.any(ve == s_head[q][:, None], 1)
        own, q = own[use], q[use]
        ed, ve = ed[use].copy(), ve[use].copy()
        ed[:, k - 1] = s_edge[q]
        ve[:, k] = s_head[q]
        Aq = s_A[q]
        h_tail.append(h_tail[-1][own])
        h_head.append(s_head[q])
        h_edges.append(ed)
        h_verts.append(ve)
        h_T.append(h_T[-1][own] @ s_T[q])
        h_S.append(Aq @ h_S[-1][own] @ np.swapaxes(Aq, 1, 2) + s_S[q])
        h_A.append(Aq @ h_A[-1][own])
    lens = np.concatenate([np.full(t.size, k, np.int64) for k, t in enumerate(h_tail)])
    tail, head = np.concatenate(h_tail), np.concatenate(h_head)
    edges, T = np.concatenate(h_edges), np.concatenate(h_T)
    S, A = np.concatenate(h_S), np.concatenate(h_A)
    by_tail = np.argsort(tail, kind="stable")
    t_first = np.searchsorted(tail[by_tail], np.arange(n + 1))
    key = tail * n + head
    by_key = np.argsort(key, kind="stable")
    skey = key[by_key]
    c2 = float(chi2.ppf(quantile, D))
    for lo in range(0, E, chunk):
        es = np.arange(lo, min(E, lo + chunk))
        own, pos = _ranges(t_first, ii[es])
        ea, a = es[own], by_tail[pos]
        use = (lens[a] >= 1) & ~np.any(edges[a] == ea[:, None], 1)
        ea, a = ea[use], a[use]
        q = head[a] * n + jj[ea]
        b_lo = np.searchsorted(skey, q, "left")
        nb = np.searchsorted(skey, q, "right") - b_lo
        own = np.repeat(np.arange(ea.size), nb)
        pos = np.arange(int(nb.sum())) - np.repeat(np.cumsum(nb) - nb, nb) + \
            np.repeat(b_lo, nb)
        ec, ac, bc = ea[own], a[own], by_key[pos]
        eb = edges[bc]
        use = ((lens[ac] == lens[bc]) | (lens[ac] == lens[bc] + 1)) & \
            (lens[ac] + lens[bc] <= max_length - 1) & \
            ~np.any(eb == ec[:, None], 1) & \
            ~np.any((eb[:, :, None] == edges[ac][:, None, :]) & (eb[:, :, None] >= 0), (1, 2))
        use &= ~ok[ec]
        ec, ac, bc = ec[use], ac[use], bc[use]
        if not ec.size:
            continue
        Tc = T[ac] @ T[bc]
        Sc = A[bc] @ S[ac] @ np.swapaxes(A[bc], 1, 2) + S[bc] + cov[ec]
        r = np.asarray(Z[ec].inverse().compose(group.from_matrix(Tc)).log(),  # type: ignore[call-overload]
                       dtype=np.float64)
        s2 = np.einsum("ca,ca->c", r, np.linalg.solve(Sc, r[:, :, None])[:, :, 0])
        good = s2 <= c2
        short = good & (lens[ac] + lens[bc] <= single - 1)  # one short cycle: enough
        ok[ec[short]] = True
        cnt = np.bincount(ec[good] - lo, minlength=es.size)
        ok[es[cnt >= support]] = True
    return ok


def mark_loops(edges: Any, known: list[np.ndarray], quantile: float, max_length: int = 8
               ) -> list[np.ndarray]:
    """The known-inlier masks with the edges on consistent cycles and the edges of a vote
    between the pieces they form added.

    The edges of :func:`cycle_consistent_edges` (cycles of at most ``max_length`` edges)
    join the known ones; the pieces (components of the known edges) are each posed by one
    chordal relaxation of their known edges
    (:func:`~microlie.optim.core.gnc_chordal.chordal_gnc` with every other edge rejected:
    each piece is solved as a whole, so a long piece does not drift as the composition along
    a spanning tree does), and :func:`~microlie.optim.core.gnc_merge.merge_components` merges
    them by the rigid-motion vote; the edges of its agreeing sets become known too.

    Parameters
    ----------
    edges : PoseGraphEdges
        :func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` of the problem.
    known : list of numpy.ndarray
        Known-inlier masks per factor batch; not modified.
    quantile : float
        Chi-square quantile of the cycle and agreement tests, ``0 < quantile < 1``.
    max_length : int
        Longest cycle tried, 2 to 9 edges.

    Returns
    -------
    list of numpy.ndarray
        New masks: ``known`` or, on the BetweenFactor rows, on a consistent cycle or merged.

    Raises
    ------
    ValueError
        ``quantile`` or ``max_length`` out of range.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor, Isotropic
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_loops import mark_loops
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(6), fixed=[0])
    >>> # a ladder of two unit squares (rails 0-1-2 and 3-4-5) and a random chord 0-5
    >>> ii, jj = [0, 1, 3, 4, 0, 1, 2, 0], [1, 2, 4, 5, 3, 4, 5, 5]
    >>> Z = SE2.from_xy_theta([1.0] * 4 + [0.0] * 3 + [4.0], [0.0] * 4 + [1.0] * 3 + [3.0],
    ...                       [0.0] * 7 + [1.0])
    >>> f = g.add(BetweenFactor(x, ii, jj, Z, Isotropic(3, 0.1)))
    >>> mark_loops(pose_graph_edges(g.problem()), [np.zeros(8, bool)], 0.99)[0].tolist()
    [True, True, True, True, True, True, True, False]
    """
    from scipy.stats import chi2  # type: ignore[import-untyped]

    from .gnc_chordal import chordal_gnc
    from .gnc_merge import merge_components

    if not 0.0 < quantile < 1.0:
        raise ValueError(f"mark_loops: quantile must be strictly between 0 and 1, got "
                         f"{quantile!r}")
    single = 6 if edges.info.shape[-1] >= 6 else 5  # longer cycles: two needed (module doc)
    ok = cycle_consistent_edges(edges.group, edges.n, edges.ii, edges.jj, edges.Z, edges.info,
                                max_length=max_length, quantile=quantile, support=2,
                                single=single)
    kn = np.concatenate([known[k] for k, _ in edges.rows]) | ok
    X, _, _ = chordal_gnc(edges.group, edges.n, edges.ii, edges.jj, edges.Z, edges.info,
                          edges.anchor, edges.group.identity(), kn, rejected=~kn)
    c2 = float(chi2.ppf(quantile, edges.info.shape[-1]))
    _, merged, _ = merge_components(edges.group, edges.n, edges.ii, edges.jj, edges.Z,
                                    edges.info, X, kn, c2, edges.anchor)
    out = [np.array(k, dtype=bool) for k in known]
    for k, sl in edges.rows:
        out[k] |= (ok | merged)[sl]
    return out


def _misfit(s: np.ndarray, c2: float, slack: float) -> np.ndarray:
    """``c^2 / 2`` per edge that does not fit within ``slack c^2``, else 0: the TLS cost
    of a rigid placement, whose residuals the least-squares solve after it shares out."""
    return np.where(s <= slack * c2, 0.0, 0.5 * c2)


def _motions(group: Any, P: np.ndarray, ii: np.ndarray, jj: np.ndarray, M: np.ndarray,
             Minv: np.ndarray, Zinv: LieGroup, info: np.ndarray, cut: np.ndarray,
             inP: np.ndarray, c2: float, slack: float) -> tuple[np.ndarray, np.ndarray]:
    """The rigid motions ``D_k`` of the vertices ``inP`` that make each cut edge ``k`` fit
    exactly, and the cost (:func:`_misfit`) of the cut edges after each."""
    fwd = inP[jj[cut]]  # i outside, j in P: D = X_i Z X_j^-1; else D = X_j Z^-1 X_i^-1
    a, b = ii[cut], jj[cut]
    D = np.where(fwd[:, None, None], P[a] @ M[cut] @ np.linalg.inv(P[b]),
                 P[b] @ Minv[cut] @ np.linalg.inv(P[a]))
    Pa, Pb = P[a], P[b]
    K = cut.size
    cost = np.empty(K)
    for lo in range(0, K, 256):
        Dk = D[lo:lo + 256, None]
        A_ = np.where(~fwd[None, :, None, None], Dk @ Pa[None], Pa[None])
        B_ = np.where(fwd[None, :, None, None], Dk @ Pb[None], Pb[None])
        rel = np.linalg.inv(A_) @ B_
        e = np.tile(cut, Dk.shape[0])
        r = np.asarray(Zinv[e].compose(group.from_matrix(  # type: ignore[call-overload]
            rel.reshape(-1, *P.shape[1:]))).log(), dtype=np.float64)
        s = np.einsum("ea,eab,eb->e", r, info[e], r).reshape(Dk.shape[0], K)
        cost[lo:lo + 256] = _misfit(s, c2, slack).sum(axis=1)
    return D, cost


def move_regions(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                 info: np.ndarray, X: LieGroup, known: np.ndarray, accepted: np.ndarray,
                 c2: float, anchor: int, *, max_size: int = 50, slack: float = 4.0,
                 grow: int = 12) -> tuple[LieGroup, bool]:
    """Local search on the TLS objective: re-pose each small region outside the core.

    The core is the largest component of the ``known`` edges; the regions are the
    components of all edges between the other vertices (a chain of vertices each held by
    its own wrong edge is one region, although no edge of it is accepted). Each region of
    at most ``max_size`` vertices without the anchor is posed inside by composing the
    measurements along a spanning tree of its edges (known edges first, then accepted, then
    rejected ones), then moved rigidly by each of the motions that make one of its cut edges
    fit exactly; so is each part of the region that one of its edges alone holds to the rest
    of it (a wrong edge inside a region, for one, gets its own chance to be cut). The best
    move replaces the current poses when more of the set's edges (inside and cut) fit then
    than now, an edge fitting when its whitened squared residual is within
    ``slack c^2`` (a rigid placement puts the noise of a chain into its last edge; the
    least-squares solve after the move shares it out).

    Parameters
    ----------
    group : type
        SE2 or SE3.
    n : int
        Number of vertices.
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges ``X_i^-1 X_j = Z``.
    Z : LieGroup
        ``(E,)`` measurements.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices.
    X : LieGroup
        ``(n,)`` the poses.
    known : numpy.ndarray
        ``(E,)`` booleans: the known inliers.
    accepted : numpy.ndarray
        ``(E,)`` booleans: the judged edges accepted now (preferred in the trees).
    c2 : float
        The inlier threshold on the whitened squared residual (> 0).
    anchor : int
        The vertex held: its region never moves.
    max_size : int
        Largest region tried whole (and split at each edge), in vertices.
    slack : float
        An edge fits a rigid placement within ``slack c^2``.
    grow : int
        When neither the region nor a part of it moves (or the region is larger than
        ``max_size``): sets grown from each unit of the region (a component of its known
        and accepted edges, accepted bridges cut) that touches an edge beyond ``c^2``, one
        neighbouring unit at a time (the one whose addition gains most), at most this many
        steps; the best set met moves (0: off).

    Returns
    -------
    poses : LieGroup
        ``(n,)`` the poses, regions moved.
    moved : bool
        Whether a region moved.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_loops import move_regions
    >>> # a known square 0-1-2-3 (the core) and the chain 1-4-5-2 of unit steps; 4 and 5
    >>> # each sit where a wrong edge from 0 puts them (8, 9): the chain's edges do not fit
    >>> ii = np.array([0, 1, 2, 3, 1, 4, 5, 0, 0])
    >>> jj = np.array([1, 2, 3, 0, 4, 5, 2, 4, 5])
    >>> Z = SE2.from_xy_theta([1.0, 0.0, -1.0, 0.0, 1.0, 0.0, -1.0, 5.0, 6.0],
    ...                       [0.0, 1.0, 0.0, -1.0, 0.0, 1.0, 0.0, 5.0, 5.0], [0.0] * 9)
    >>> X = SE2.from_xy_theta([0.0, 1.0, 1.0, 0.0, 5.0, 6.0], [0.0, 0.0, 1.0, 1.0, 5.0, 5.0],
    ...                       [0.0] * 6)
    >>> kn = np.array([True] * 4 + [False] * 5)
    >>> X2, moved = move_regions(SE2, 6, ii, jj, Z, np.tile(np.eye(3) * 100.0, (9, 1, 1)),
    ...                            X, kn, ~kn & np.array([0, 0, 0, 0, 0, 0, 0, 1, 1], bool),
    ...                            11.34, 0)
    >>> moved, np.round(X2.translation()[4:], 9).tolist()
    (True, [[2.0, 0.0], [2.0, 1.0]])
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import (
        breadth_first_order,
        connected_components,
        minimum_spanning_tree,
    )

    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    known = np.asarray(known, dtype=bool)
    P = np.array(X.matrix(), dtype=np.float64)
    M = np.asarray(Z.matrix(), dtype=np.float64)
    Zinv = Z.inverse()
    Minv = np.asarray(Zinv.matrix(), dtype=np.float64)
    _, lab = connected_components(
        coo_matrix((np.ones(int(known.sum())), (ii[known], jj[known])), shape=(n, n)),
        directed=False)
    core = lab == np.argmax(np.bincount(lab))
    inner = ~core[ii] & ~core[jj]
    _, reg = connected_components(
        coo_matrix((np.ones(int(inner.sum())), (ii[inner], jj[inner])), shape=(n, n)),
        directed=False)
    reg = np.where(core, -1, reg)
    size = np.bincount(reg[~core], minlength=n)
    prio = np.where(known, 1.0, np.where(accepted, 2.0, 3.0))
    moved = False
    def attempt(inR: np.ndarray) -> tuple[float, np.ndarray | None]:
        """The gain of the best rigid move of the vertices ``inR`` and their new poses."""
        touch = np.flatnonzero(inR[ii] | inR[jj])
        cut = touch[inR[ii[touch]] != inR[jj[touch]]]
        if not cut.size:
            return 0.0, None
        verts = np.flatnonzero(inR)
        local = np.full(n, -1)
        local[verts] = np.arange(verts.size)
        ins = touch[inR[ii[touch]] & inR[jj[touch]] & (ii[touch] != jj[touch])]
        Q = P.copy()
        if ins.size:  # pose the set along a spanning tree of its edges, by priority
            order = ins[np.argsort(prio[ins], kind="stable")]
            a, b = local[ii[order]], local[jj[order]]
            _, first = np.unique(np.minimum(a, b) * verts.size + np.maximum(a, b),
                                 return_index=True)
            order = order[first]
            W = coo_matrix((prio[order], (local[ii[order]], local[jj[order]])),
                           shape=(verts.size, verts.size)).tocsr()
            T = minimum_spanning_tree(W)
            T = (T + T.T).tocsr()
            ncomp, sub = connected_components(T, directed=False)
            pick = {(int(min(local[ii[k]], local[jj[k]])),
                     int(max(local[ii[k]], local[jj[k]]))): k for k in order}
            for c in range(ncomp):
                root = int(np.flatnonzero(sub == c)[0])
                seq, pred = breadth_first_order(T, root, directed=False)
                for v in seq[1:]:
                    u = int(pred[v])
                    k = pick[(min(u, int(v)), max(u, int(v)))]
                    if local[ii[k]] == u:
                        Q[verts[v]] = Q[verts[u]] @ M[k]
                    else:
                        Q[verts[v]] = Q[verts[u]] @ Minv[k]
        s_in = whitened_residuals(group, Q, ii[ins], jj[ins], Zinv[ins], info[ins]) if ins.size \
            else np.zeros(0)
        new_in = float(_misfit(s_in, c2, slack).sum())
        D, cost = _motions(group, Q, ii, jj, M, Minv, Zinv, info, cut, inR, c2, slack)
        now = float(_misfit(whitened_residuals(group, P, ii[touch], jj[touch], Zinv[touch],
                                     info[touch]), c2, slack).sum())
        best = int(np.argmin(cost))
        return now - new_in - float(cost[best]), D[best] @ Q[inR]

    for r in np.flatnonzero(size > 0):
        inR = reg == r
        if inR[anchor]:
            continue
        # the region, and each part of it that one of its edges alone holds to the rest
        small = size[r] <= max_size
        sets = [inR] if small else []
        ins = np.flatnonzero(inR[ii] & inR[jj] & (ii != jj))
        verts = np.flatnonzero(inR)
        local = np.full(n, -1)
        local[verts] = np.arange(verts.size)
        for k in ins if small else ():
            keep = ins[ins != k]
            parts, lab_r = connected_components(
                coo_matrix((np.ones(keep.size), (local[ii[keep]], local[jj[keep]])),
                           shape=(verts.size, verts.size)), directed=False)
            if parts > 1:
                for q in range(parts):
                    part = np.zeros(n, dtype=bool)
                    part[verts[lab_r == q]] = True
                    if not part[anchor]:
                        sets.append(part)
        best_gain, best_set, best_pose = 0.25 * c2, None, None
        for cand in sets:
            gain, pose = attempt(cand)
            if gain > best_gain:
                best_gain, best_set, best_pose = gain, cand, pose
        if best_set is None and grow:
            best_gain, best_set, best_pose = _grow(attempt, n, ii, jj, known, accepted, inR,
                                                   ins, verts, local, P, Zinv, info, c2,
                                                   anchor, grow, group)
        if best_set is not None:
            P[best_set] = best_pose
            moved = True
    return group.from_matrix(P), moved


def _grow(attempt: Any, n: int, ii: np.ndarray, jj: np.ndarray, known: np.ndarray,
          accepted: np.ndarray, inR: np.ndarray, ins: np.ndarray, verts: np.ndarray,
          local: np.ndarray, P: np.ndarray, Zinv: LieGroup, info: np.ndarray, c2: float,
          anchor: int, steps: int, group: Any) -> tuple[float, Any, Any]:
    """Sets of units of a region grown greedily (:func:`move_regions`' ``grow``): the best
    gain, set and poses met (set ``None`` when nothing gains more than ``c^2 / 4``)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = verts.size

    def comps(edges: np.ndarray) -> tuple[int, np.ndarray]:
        c, lab = connected_components(coo_matrix((np.ones(edges.size), (local[ii[edges]],
                                                 local[jj[edges]])), shape=(m, m)),
                                      directed=False)
        return int(c), lab

    held = ins[known[ins] | accepted[ins]]
    base, _ = comps(held)
    unit_edges = [k for k in held if known[k] or comps(held[held != k])[0] == base]
    _, unit = comps(np.array(unit_edges, dtype=np.int64))
    touch = np.flatnonzero(inR[ii] | inR[jj])
    s = np.zeros(touch.size) if not touch.size else \
        whitened_residuals(group, P, ii[touch], jj[touch], Zinv[touch], info[touch])
    bad_v = np.concatenate([ii[touch][s > c2], jj[touch][s > c2]])
    seeds = np.unique(unit[local[bad_v[inR[bad_v]]]])
    adj_a, adj_b = unit[local[ii[ins]]], unit[local[jj[ins]]]
    best_gain, best_set, best_pose = 0.25 * c2, None, None
    for seed in seeds:
        have = {int(seed)}
        for _ in range(steps):
            nbr = set(adj_b[np.isin(adj_a, list(have))].tolist()) | \
                set(adj_a[np.isin(adj_b, list(have))].tolist())
            nbr -= have
            if not nbr:
                break
            step_best = None
            for u in sorted(nbr):
                cand = np.zeros(n, dtype=bool)
                cand[verts[np.isin(unit, list(have | {u}))]] = True
                if cand[anchor]:
                    continue
                gain, pose = attempt(cand)
                if step_best is None or gain > step_best[0]:
                    step_best = (gain, u, cand, pose)
            if step_best is None:
                break
            have.add(step_best[1])
            if step_best[0] > best_gain:
                best_gain, best_set, best_pose = step_best[0], step_best[2], step_best[3]
    return best_gain, best_set, best_pose


def move_pieces(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                info: np.ndarray, X: LieGroup, known: np.ndarray, c2: float, anchor: int, *,
                max_passes: int = 5, slack: float = 4.0) -> tuple[LieGroup, bool]:
    """Local search on the TLS objective: move each piece of the known edges rigidly where
    its edges to the rest fit best.

    The pieces are the components of the ``known`` edges (rigid: their edges are never
    rejected). For each piece ``P`` without the anchor, smallest first, every edge ``k``
    across its cut proposes the rigid motion ``D_k`` of ``P`` (``X_v <- D_k X_v`` for ``v`` in
    ``P``) that makes ``k`` fit exactly; the motion that makes the most cut edges fit
    (whitened squared residual within ``slack c^2``: a rigid placement puts the noise of a
    chain into its last edge; the least-squares solve after the move shares it out) replaces
    the current pose when more cut edges fit then than now (the rest of the objective does
    not change: only ``P`` moves). Passes repeat until no piece moves. GNC ends where no
    weight update can leave: a piece held by a wrong edge fits it, its good edges do not fit
    and are rejected; one move here replaces that configuration with a better one.

    Parameters
    ----------
    group : type
        SE2 or SE3.
    n : int
        Number of vertices.
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges ``X_i^-1 X_j = Z``.
    Z : LieGroup
        ``(E,)`` measurements.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices.
    X : LieGroup
        ``(n,)`` the poses.
    known : numpy.ndarray
        ``(E,)`` booleans: the known inliers (the pieces' edges).
    c2 : float
        The inlier threshold on the whitened squared residual (> 0).
    anchor : int
        The vertex held: its piece never moves.
    max_passes : int
        Passes over the pieces at most, >= 1.
    slack : float
        An edge fits a rigid placement within ``slack c^2``.

    Returns
    -------
    poses : LieGroup
        ``(n,)`` the poses, pieces moved.
    moved : bool
        Whether a piece moved.

    Raises
    ------
    ValueError
        A group other than SE2/SE3 or bad options.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_loops import move_pieces
    >>> # vertices 0-1-2 known; vertex 3 sits where the wrong edge 0-3 puts it, while the
    >>> # good edges 2-3 and 1-3 (unit steps along x) do not fit
    >>> ii, jj = np.array([0, 1, 0, 2, 1]), np.array([1, 2, 3, 3, 3])
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 5.0, 1.0, 2.0], [0.0, 0.0, 5.0, 0.0, 0.0], [0.0] * 5)
    >>> X = SE2.from_xy_theta([0.0, 1.0, 2.0, 5.0], [0.0, 0.0, 0.0, 5.0], [0.0] * 4)
    >>> X2, moved = move_pieces(SE2, 4, ii, jj, Z, np.tile(np.eye(3) * 100.0, (5, 1, 1)), X,
    ...                           np.array([True, True, False, False, False]), 11.34, 0)
    >>> moved, np.round(X2.translation()[3], 9).tolist()
    (True, [3.0, 0.0])
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if group not in (SE2, SE3):
        raise ValueError(f"move_pieces: group must be SE2 or SE3, got {group!r}")
    if not (np.isfinite(c2) and c2 > 0):
        raise ValueError(f"move_pieces: c2 must be a positive number, got {c2!r}")
    if not 0 <= anchor < n:
        raise ValueError(f"move_pieces: anchor must be a vertex in [0, {n}), got {anchor}")
    if isinstance(max_passes, bool) or not isinstance(max_passes, (int, np.integer)) or \
            max_passes < 1:
        raise ValueError(f"move_pieces: max_passes must be an integer >= 1, got "
                         f"{max_passes!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    known = np.asarray(known, dtype=bool)
    P = np.array(X.matrix(), dtype=np.float64)
    M = np.asarray(Z.matrix(), dtype=np.float64)
    Zinv = Z.inverse()
    Minv = np.asarray(Zinv.matrix(), dtype=np.float64)
    ncomp, lab = connected_components(
        coo_matrix((np.ones(int(known.sum())), (ii[known], jj[known])), shape=(n, n)),
        directed=False)
    size = np.bincount(lab, minlength=ncomp)
    la, lb = lab[ii], lab[jj]
    cross = np.flatnonzero(la != lb)
    # the cut edges of every piece, grouped
    owner = np.concatenate([la[cross], lb[cross]])
    cut_of = np.concatenate([cross, cross])
    order = np.argsort(owner, kind="stable")
    first = np.searchsorted(owner[order], np.arange(ncomp + 1))
    moved = False
    for _ in range(max_passes):
        changed = False
        for c in np.argsort(size, kind="stable"):
            if c == lab[anchor] or first[c + 1] == first[c]:
                continue
            cut = cut_of[order[first[c]:first[c + 1]]]
            inP = lab == c
            D, cost = _motions(group, P, ii, jj, M, Minv, Zinv, info, cut, inP, c2, slack)
            s_cut = whitened_residuals(group, P, ii[cut], jj[cut], Zinv[cut], info[cut])
            now = float(_misfit(s_cut, c2, slack).sum())
            best = int(np.argmin(cost))
            if cost[best] < now - 0.25 * c2:
                P[inP] = D[best] @ P[inP]
                changed = moved = True
        if not changed:
            break
    return group.from_matrix(P), moved


def move_stage(states: list[np.ndarray], edges: Any, known: list[np.ndarray],
               weights: list[np.ndarray], c2: list[float], *, max_passes: int = 5,
               slack: float = 4.0) -> list[np.ndarray] | None:
    """Pieces moved after GNC on a problem's pose graph: the new states with the
    BetweenFactor weights set to ``s <= slack c^2`` there (judged rows; updated in place), or
    ``None`` when nothing moved.

    Each pass runs :func:`move_pieces` on the pieces of the known edges, then on the pieces
    of the accepted edges (weights >= 0.5 and the known ones: a pair of vertices whose
    edge is accepted moves together), then
    :func:`~microlie.optim.core.gnc_bridges.repair_bridges` (the smaller side of every
    accepted judged bridge moved where most cut edges fit), with the weights set to
    ``s <= slack c^2`` after every move; passes repeat until nothing moves. Every move makes
    more edges fit the rigidly moved poses; :func:`~microlie.optim.core.gnc.gnc_solve` keeps
    the result only when the TLS objective after the least-squares solve of the accepted
    edges is lower than before.

    Parameters
    ----------
    states : list of numpy.ndarray
        The parameters of the one pose batch (a list of one array).
    edges : PoseGraphEdges
        :func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` of the problem.
    known : list of numpy.ndarray
        Known-inlier masks per factor batch.
    weights : list of numpy.ndarray
        GNC's weights per factor batch (0 or 1), updated in place.
    c2 : list of float
        Thresholds per factor batch.
    max_passes : int
        Passes at most, >= 1.
    slack : float
        An edge fits a rigid placement within ``slack c^2`` (:func:`move_pieces`).

    Returns
    -------
    list of numpy.ndarray or None

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_loops import move_stage
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(2), fixed=[0])
    >>> _ = g.add(BetweenFactor(x, [0], [1], SE2.identity(1)))
    >>> e = pose_graph_edges(g.problem())
    >>> move_stage([np.asarray(SE2.identity(2).params)], e, [np.zeros(1, bool)],
    ...              [np.ones(1)], [11.34]) is None  # it fits: nothing moves
    True
    """
    from .gnc_bridges import repair_bridges

    kn = np.concatenate([known[k] for k, _ in edges.rows])
    w = np.concatenate([weights[k] for k, _ in edges.rows])
    c = float(c2[edges.rows[0][0]])
    var, group = edges.variables, edges.group
    X = group.from_params(np.asarray(states[0], dtype=np.float64))
    Zinv = edges.Z.inverse()
    args = (group, edges.n, edges.ii, edges.jj, edges.Z, edges.info)
    moved = False

    def fits(X: LieGroup) -> np.ndarray:
        s = whitened_residuals(group, np.asarray(X.matrix(), dtype=np.float64), edges.ii, edges.jj,
                     Zinv, edges.info)
        return kn | (s <= slack * c)

    for _ in range(max_passes):
        X, m1 = move_pieces(*args, X, kn, c, edges.anchor, slack=slack)
        acc = fits(X) if m1 else kn | (w >= 0.5)
        X, m2 = move_pieces(*args, X, acc, c, edges.anchor, slack=slack)
        acc = fits(X) if m2 else acc
        X, m4 = move_regions(*args, X, kn, acc & ~kn, c, edges.anchor, slack=slack)
        acc = fits(X) if m4 else acc
        X, w2 = repair_bridges(*args, X, acc.astype(np.float64), ~kn, c)
        m3 = not np.array_equal(w2 >= 0.5, acc)
        w = w2 if m3 else acc.astype(np.float64)
        if not (m1 or m2 or m3 or m4):
            break
        moved = True
    if not moved:
        return None
    for k, sl in edges.rows:
        weights[k][~known[k]] = w[sl][~known[k]]
    P = np.array(X.params, dtype=np.float64)
    P[var.fixed] = np.asarray(states[0], dtype=np.float64)[var.fixed]
    return [P]
