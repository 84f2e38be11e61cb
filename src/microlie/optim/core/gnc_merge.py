"""Pieces of a pose graph: merge them by a rigid-motion vote over the edges between them.

Without known inliers GNC on a pose graph with many wrong loop closures can reject good edges
(odometry among them): the accepted edges then fall into connected components, each well
estimated inside, that sit at wrong poses relative to each other. Every edge ``e``
between two components ``A`` and ``B`` (oriented from ``a`` in ``A`` to ``b`` in ``B``,
measurement ``Z_e``) predicts the rigid motion that brings ``B`` onto ``A``:

``D_e = X_a Z_e X_b^-1`` (``X_v <- D_e X_v`` for ``v`` in ``B`` makes ``e`` fit exactly).

Two good edges across the same cut predict the same motion up to their noise: edges ``k`` and
``l`` *agree* when ``r = Log(Z_l^-1 X_a_l^-1 D_k X_b_l)`` (the residual of ``l`` once ``B`` is
moved by ``D_k``: the cycle ``a_l -> a_k`` inside ``A``, ``k``, ``b_k -> b_l`` inside ``B``,
``l`` backwards) passes ``r^T (Sigma_l + Ad(P^-1) Sigma_k Ad(P^-1)^T)^-1 r <= c^2`` with
``P = X_b_k^-1 X_b_l`` (first-order covariance of the cycle, the paths inside the components
taken as exact), ``c^2`` the chi-square quantile of the edge dimension (GNC's threshold), in both
directions. Random edges agree with nothing. :func:`merge_components` finds, on every cut, the
largest set of mutually agreeing edges (a clique of the agreement graph, greedily: the edge with
most agreeing partners and those partners, then the member with the fewest agreements inside
dropped until all agree). Each round (:func:`merge_components`) accepts every such set of at
least ``min_support`` = 2 edges (a single edge across a cut cannot be told from a random one),
joins a component that has only one or two cut edges in all (and no anchor) to its neighbour of
higher degree across one of them (nothing can confirm or contradict such an edge yet: joining
lets later rounds vote with the larger piece; the edge itself is left to GNC's judgement; with
the start values given, an edge that fits them within its threshold, else the first), and
moves the components rigidly so that a spanning forest of those edges fits exactly (the
anchor's component, else the largest, stays). Rounds repeat on the larger components until no
cut has support; a component never merged stays where it was, and the count is returned.
Everything uses only the edges' measurements, information and the current poses: no edge
order, no trusted odometry.

:func:`~microlie.optim.core.gnc.gnc_solve` with ``GNC(first="cycles")`` runs the vote twice:
before the chordal stage between the pieces of the cycle-consistent edges, each posed by
composing its measurements along a spanning tree (:func:`merge_known`: the agreeing edges
become known inliers), and after GNC between the components of the accepted edges
(:func:`merge_stage`: merged edges known, GNC-TLS re-run from ``mu = 1``). Measured in
``benchmarks/results/robust-s12.md``. The agreement test takes the paths inside a component as
exact: with the large rotation noise of M3500 (0.15 rad per edge) long pieces bend more than
that, so good edges across a cut can disagree (they are then left apart, not merged wrongly).

Examples
--------
>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.core.gnc_merge import merge_components
>>> # a chain 0-1-2 | 3-4-5 whose middle edge (2-3) was rejected, with two good loop edges
>>> # (0-3, 2-5: also rejected) and one random edge (1-4); the piece {3, 4, 5} sits 5 m off
>>> ii, jj = np.array([0, 1, 2, 3, 4, 0, 2, 1]), np.array([1, 2, 3, 4, 5, 3, 5, 4])
>>> Z = SE2.from_xy_theta([1.0, 1, 1, 1, 1, 3, 3, -7], [0.0, 0, 0, 0, 0, 0, 0, 4], [0.0] * 8)
>>> X = SE2.from_xy_theta([0.0, 1, 2, 3, 4, 5], [0.0, 0, 0, 5, 5, 5], [0.0] * 6)
>>> inside = np.array([True, True, False, True, True, False, False, False])
>>> X2, merged, left = merge_components(SE2, 6, ii, jj, Z, np.tile(np.eye(3) * 100.0,
...                                     (8, 1, 1)), X, inside, 11.34, 0)
>>> np.round(X2.translation(), 9).tolist()
[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0.0], [5.0, 0.0]]
>>> np.flatnonzero(merged).tolist(), left  # the three good cut edges; no piece left
([2, 5, 6], 0)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from ...groups import SE2, SE3, LieGroup
from .gnc_weights import tls_weights

__all__ = ["agreeing_set", "merge_components", "merge_known", "merge_stage"]


def agreeing_set(agree: np.ndarray) -> np.ndarray:
    """A large set of mutually agreeing edges (greedy clique of a symmetric agreement matrix).

    Parameters
    ----------
    agree : numpy.ndarray
        ``(m, m)`` booleans, symmetric, True on the diagonal: edges ``k`` and ``l`` agree.

    Returns
    -------
    numpy.ndarray
        Indices of the set, sorted: the edge with the most agreeing partners together with
        them, then, while two members disagree, the member with the fewest agreements inside
        the set removed (ties: the later index).

    Raises
    ------
    ValueError
        ``agree`` not square.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.core.gnc_merge import agreeing_set
    >>> A = np.eye(4, dtype=bool)
    >>> A[0, 1] = A[1, 0] = A[0, 2] = A[2, 0] = A[1, 2] = A[2, 1] = A[2, 3] = A[3, 2] = True
    >>> agreeing_set(A).tolist()
    [0, 1, 2]
    """
    agree = np.asarray(agree, dtype=bool)
    if agree.ndim != 2 or agree.shape[0] != agree.shape[1]:
        raise ValueError(f"agreeing_set: agree must be a square matrix, got shape {agree.shape}")
    if agree.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    deg = agree.sum(axis=1)
    S = np.flatnonzero(agree[int(np.argmax(deg))])
    while S.size > 1:
        inner = agree[np.ix_(S, S)].sum(axis=1)
        if inner.min() == S.size:
            break
        worst = np.flatnonzero(inner == inner.min())[-1]
        S = np.delete(S, worst)
    return S


def _oriented(group: Any, M: np.ndarray, cov: np.ndarray, Z: LieGroup, flip: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Measurements (as matrices) and covariances with the flipped edges walked backwards."""
    Mo = np.where(flip[:, None, None], np.linalg.inv(M), M)
    Ad = np.asarray(Z.adjoint(), dtype=np.float64)
    back = Ad @ cov @ np.swapaxes(Ad, 1, 2)
    return Mo, np.where(flip[:, None, None], back, cov)


def _agreement(group: Any, P: np.ndarray, a: np.ndarray, b: np.ndarray, Mo: np.ndarray,
               So: np.ndarray, c2: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairwise agreement (both directions) and statistic of ``m`` oriented cut edges."""
    m = a.size
    k = np.repeat(np.arange(m), m)
    l_ = np.tile(np.arange(m), m)
    inv = np.linalg.inv
    Pb = inv(P[b[k]]) @ P[b[l_]]
    T = inv(P[a[l_]]) @ P[a[k]] @ Mo[k] @ Pb
    r = np.asarray(group.from_matrix(inv(Mo[l_]) @ T).log(), dtype=np.float64)
    Adi = np.asarray(group.from_matrix(inv(Pb)).adjoint(), dtype=np.float64)
    S = Adi @ So[k] @ np.swapaxes(Adi, 1, 2) + So[l_]
    s2 = np.einsum("ca,ca->c", r, np.linalg.solve(S, r[:, :, None])[:, :, 0]).reshape(m, m)
    ok = s2 <= c2
    return ok & ok.T, s2 + s2.T


def merge_components(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                     info: np.ndarray, X: LieGroup, base: np.ndarray, c2: float, anchor: int,
                     *, min_support: int = 2, max_rounds: int = 100,
                     start: np.ndarray | None = None) -> tuple[LieGroup, np.ndarray, int]:
    """Merge the components of the ``base`` edges by a rigid-motion vote (module docstring).

    The agreeing set of each cut comes from :func:`agreeing_set` on the pairwise agreement;
    components are moved rigidly, never deformed.

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
        ``(E, D, D)`` information matrices (positive definite).
    X : LieGroup
        ``(n,)`` the poses; each component of the ``base`` edges is taken as rigid.
    base : numpy.ndarray
        ``(E,)`` booleans: the edges trusted inside the components (known inliers).
    c2 : float
        The inlier threshold on the whitened squared residual (> 0).
    anchor : int
        A vertex that never moves (the gauge); its component stays put.
    min_support : int
        Fewest agreeing edges that merge a cut by the vote, >= 2.
    max_rounds : int
        Rounds at most, >= 1.
    start : numpy.ndarray, optional
        ``(E,)`` whitened squared residuals at the start values: a component with one or two
        cut edges is joined along one that fits the start (within ``c2``) when there is one,
        else along the first in edge order (a tie: each edge alone has support 1).

    Returns
    -------
    poses : LieGroup
        ``(n,)`` the poses, merged components moved rigidly.
    merged : numpy.ndarray
        ``(E,)`` booleans: the edges of the agreeing sets (not the edges components with one
        or two cut edges were joined along).
    left : int
        Components that remain besides the anchor's.

    Raises
    ------
    ValueError
        A group other than SE2/SE3, bad shapes or options.

    Examples
    --------
    See the module docstring.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if group not in (SE2, SE3):
        raise ValueError(f"merge_components: group must be SE2 or SE3, got {group!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    E = ii.size
    if jj.shape != (E,) or np.shape(base) != (E,) or \
            info.shape[0] != E:
        raise ValueError("merge_components: ii, jj, base and info must have one "
                         "entry per edge")
    if isinstance(min_support, bool) or not isinstance(min_support, (int, np.integer)) or \
            min_support < 2:
        raise ValueError(f"merge_components: min_support must be an integer >= 2, got "
                         f"{min_support!r}")
    if not 0 <= anchor < n:
        raise ValueError(f"merge_components: anchor must be a vertex in [0, {n}), got {anchor}")
    if isinstance(max_rounds, bool) or not isinstance(max_rounds, (int, np.integer)) or \
            max_rounds < 1:
        raise ValueError(f"merge_components: max_rounds must be an integer >= 1, got "
                         f"{max_rounds!r}")
    if start is not None:
        start = np.asarray(start, dtype=np.float64)
        if start.shape != (E,) or not np.all(start >= 0):
            raise ValueError(f"merge_components: start must hold one squared residual >= 0 "
                             f"per edge, shape ({E},), got shape {start.shape}")
    base = np.asarray(base, dtype=bool)
    merged = np.zeros(E, dtype=bool)  # accepted by a vote
    joined = np.zeros(E, dtype=bool)  # components joined along their only cut edges
    P = np.array(X.matrix(), dtype=np.float64)
    M = np.asarray(Z.matrix(), dtype=np.float64)
    cov = np.linalg.inv(info)
    ncomp = n
    for _ in range(max_rounds):
        inside = base | merged | joined
        ncomp, lab = connected_components(
            coo_matrix((np.ones(int(inside.sum())), (ii[inside], jj[inside])), shape=(n, n)),
            directed=False)
        cross = np.flatnonzero(lab[ii] != lab[jj])
        if ncomp == 1 or not cross.size:
            break
        vote = _pair_votes(group, P, M, cov, ii, jj, Z, lab, ncomp, cross, c2, min_support)
        # a component with one or two cut edges (no anchor) joins the neighbour of higher
        # degree across one of them: nothing can confirm or contradict that edge yet
        a, b = lab[ii[cross]], lab[jj[cross]]
        deg = np.bincount(a, minlength=ncomp) + np.bincount(b, minlength=ncomp)
        series = np.zeros(ncomp, dtype=bool)
        series[lab[anchor]] = True
        join = np.zeros(E, dtype=bool)
        by = np.argsort(start[cross] > c2, kind="stable") if start is not None else \
            np.arange(cross.size)  # the edges that fit the start are tried first
        for e, la, lb in zip(cross[by], a[by], b[by], strict=True):
            for me, other in ((la, lb), (lb, la)):
                if deg[me] <= 2 and not series[me] and not vote[e] and \
                        (deg[other] > deg[me] or (deg[other] == deg[me] and other < me)):
                    series[me] = True
                    join[e] = True
        if not (vote | join).any():
            break
        P = _place(P, M, ii, jj, lab, ncomp, np.flatnonzero(vote | join), int(lab[anchor]))
        merged |= vote
        joined |= join
    return group.from_matrix(P), merged, int(ncomp) - 1


def _pair_votes(group: Any, P: np.ndarray, M: np.ndarray, cov: np.ndarray, ii: np.ndarray,
                jj: np.ndarray, Z: LieGroup, lab: np.ndarray, ncomp: int, cross: np.ndarray,
                c2: float, min_support: int) -> np.ndarray:
    """The agreeing sets (at least ``min_support`` edges) of every cut between two components."""
    mark = np.zeros(ii.size, dtype=bool)
    la, lb = lab[ii[cross]], lab[jj[cross]]
    lo, hi = np.minimum(la, lb), np.maximum(la, lb)
    key = lo * ncomp + hi
    order = np.argsort(key, kind="stable")
    cross, key, lo = cross[order], key[order], lo[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    counts = np.diff(np.r_[starts, key.size])
    for s0, cnt in zip(starts[counts >= min_support], counts[counts >= min_support],
                       strict=True):
        e = cross[s0:s0 + cnt]
        flip = lab[ii[e]] != lo[s0]  # walk the edge from the lower component
        a = np.where(flip, jj[e], ii[e])
        b = np.where(flip, ii[e], jj[e])
        Mo, So = _oriented(group, M[e], cov[e], Z[e], flip)  # type: ignore[call-overload]
        ok, _ = _agreement(group, P, a, b, Mo, So, c2)
        S = agreeing_set(ok)
        if S.size >= min_support:
            mark[e[S]] = True
    return mark


def _place(P: np.ndarray, M: np.ndarray, ii: np.ndarray, jj: np.ndarray, lab: np.ndarray,
           ncomp: int, edges: np.ndarray, root: int) -> np.ndarray:
    """Move the components rigidly so that a spanning forest of ``edges`` fits exactly; the
    root of each tree (the anchor's component, else the one with most vertices) stays."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    a, b = lab[ii[edges]], lab[jj[edges]]
    _, first = np.unique(np.minimum(a, b) * ncomp + np.maximum(a, b), return_index=True)
    edges, a, b = edges[first], a[first], b[first]  # one edge per pair of components
    adj = coo_matrix((np.arange(1, edges.size + 1, dtype=np.float64), (a, b)),
                     shape=(ncomp, ncomp)).tocsr()
    adj = adj.maximum(adj.T)
    adj.sum_duplicates()
    _, tree = connected_components(adj, directed=False)
    size = np.bincount(lab, minlength=ncomp)
    P = P.copy()
    motion = np.tile(np.eye(P.shape[-1]), (ncomp, 1, 1))
    done = np.zeros(ncomp, dtype=bool)
    for t in np.unique(tree[np.r_[a, b]]):
        members = np.flatnonzero(tree == t)
        start = root if root in members else int(members[np.argmax(size[members])])
        order, pred = breadth_first_order(adj, start, directed=False)
        for c in order[1:]:
            p = pred[c]
            e = edges[int(round(adj[p, c])) - 1]
            # the edge joins components p and c: make it fit with p already placed
            i, j = ii[e], jj[e]
            if lab[i] == p:
                D = motion[p] @ P[i] @ M[e] @ np.linalg.inv(P[j])
            else:
                D = motion[p] @ P[j] @ np.linalg.inv(M[e]) @ np.linalg.inv(P[i])
            motion[c] = D
            done[c] = True
    moved = done[lab]
    P[moved] = motion[lab[moved]] @ P[moved]
    return P


def merge_stage(states: list[np.ndarray], edges: Any, known: list[np.ndarray],
                weights: list[np.ndarray], c2: list[float],
                solve: Callable[[list[np.ndarray]], list[np.ndarray]],
                norms: Callable[[list[np.ndarray]], list[np.ndarray]], *,
                max_rounds: int = 10, max_reweight: int = 100, mu_step: float = 1.4,
                weights_tol: float = 1e-4, start: list[np.ndarray] | None = None
                ) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """:func:`merge_components` on a problem's pose graph after GNC, then GNC-TLS once more.

    Each round merges the components of the accepted and known edges (the agreeing edges
    become known inliers, weight 1), solves the weighted problem from the merged poses, then
    runs GNC-TLS again on every judged factor from ``mu = 1`` (weight 1 for ``s <= c^2/2``, 0
    for ``s >= 2 c^2``: the merged pieces settle before the threshold hardens), ``mu``
    multiplied by ``mu_step`` each iteration until every weight is within ``weights_tol`` of
    0 or 1 (then rounded and solved once more); rounds repeat while a merge happens.

    Parameters
    ----------
    states : list of numpy.ndarray
        The parameters of each variable batch (the pose batch first and only).
    edges : PoseGraphEdges
        :func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` of the problem.
    known : list of numpy.ndarray
        Known-inlier masks per factor batch; not modified.
    weights : list of numpy.ndarray
        GNC's weights per factor batch (0 or 1), updated in place.
    c2 : list of float
        Thresholds per factor batch.
    solve : callable
        ``solve(states) -> states``: the weighted least-squares solve (reads ``weights``).
    norms : callable
        ``norms(states) -> s``: whitened squared residuals per factor batch.
    max_rounds : int
        Merge rounds at most, >= 1.
    max_reweight : int
        GNC iterations at most per round, >= 1.
    mu_step : float
        Factor ``mu`` grows by per GNC iteration, > 1.
    weights_tol : float
        GNC stops when every weight is within this of 0 or 1.
    start : list of numpy.ndarray, optional
        Whitened squared residuals at the start values per factor batch: ties of
        :func:`merge_components` (``start``) are broken by them.

    Returns
    -------
    states : list of numpy.ndarray
        The final parameters (``states`` itself when nothing merged).
    known : list of numpy.ndarray
        ``known`` with the merged edges added.
    left : int
        Components of the accepted edges besides the anchor's after the last round.

    Raises
    ------
    ValueError
        An option out of range.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_merge import merge_stage
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(2), fixed=[0])
    >>> _ = g.add(BetweenFactor(x, [0], [1], SE2.identity(1)))
    >>> e = pose_graph_edges(g.problem())
    >>> st = [np.asarray(SE2.identity(2).params)]
    >>> merge_stage(st, e, [np.zeros(1, bool)], [np.ones(1)], [11.34], lambda s: s,
    ...             lambda s: [np.zeros(1)])[2]  # one component: nothing to merge
    0
    """
    for name, val in (("max_rounds", max_rounds), ("max_reweight", max_reweight)):
        if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < 1:
            raise ValueError(f"merge_stage: {name} must be an integer >= 1, got {val!r}")
    if not (isinstance(mu_step, (float, int)) and np.isfinite(mu_step) and mu_step > 1.0):
        raise ValueError(f"merge_stage: mu_step must be a finite number > 1, got {mu_step!r}")
    if not (isinstance(weights_tol, (float, int)) and 0.0 <= weights_tol < 0.5):
        raise ValueError(f"merge_stage: weights_tol must be in [0, 0.5), got {weights_tol!r}")
    var = edges.variables
    known = [np.array(k, dtype=bool) for k in known]
    s0 = _edge_start(edges, start)
    left = 0
    for _ in range(max_rounds):
        kn = np.concatenate([known[k] for k, _ in edges.rows])
        w = np.concatenate([weights[k] for k, _ in edges.rows])
        c = float(c2[edges.rows[0][0]])
        X = var.group.from_params(np.asarray(states[0], dtype=np.float64))
        X2, merged, left = merge_components(edges.group, edges.n, edges.ii, edges.jj, edges.Z,
                                            edges.info, X, kn | (w >= 0.5), c, edges.anchor,
                                            start=s0)
        if not (merged & ~kn).any():
            break
        for k, sl in edges.rows:
            weights[k][merged[sl]] = 1.0
            known[k] |= merged[sl]
        P = np.array(X2.params, dtype=np.float64)
        P[var.fixed] = np.asarray(states[0], dtype=np.float64)[var.fixed]
        states = solve([P] + list(states[1:]))
        mu = 1.0  # GNC-TLS again from mu = 1 (weight 1 below c^2/2, 0 above 2 c^2)
        for _ in range(max_reweight):
            s = norms(states)
            new = [np.where(kk, 1.0, tls_weights(sk, ck, mu))
                   for sk, ck, kk in zip(s, c2, known, strict=True)]
            binary = all(np.all(np.abs(nk - np.round(nk)) <= weights_tol) for nk in new)
            for wk, nk in zip(weights, new, strict=True):
                wk[:] = np.round(nk) if binary else nk
            states = solve(states)
            if binary:
                break
            mu *= mu_step
    return states, known, left


def _edge_start(edges: Any, start: list[np.ndarray] | None) -> np.ndarray | None:
    """The start residuals of the pose graph's edges (non-finite: +inf), or ``None``."""
    if start is None:
        return None
    s0 = np.concatenate([np.asarray(start[k], dtype=np.float64) for k, _ in edges.rows])
    return np.where(np.isfinite(s0), np.abs(s0), np.inf)


def merge_known(edges: Any, known: list[np.ndarray], quantile: float,
                start: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """The known-inlier masks with the edges of a vote between their pieces added.

    The pieces are the components of the known edges, each posed by composing the
    measurements along a spanning tree of its known edges (no start values needed);
    :func:`merge_components` then merges them (no lone edges: nothing is accepted yet).

    Parameters
    ----------
    edges : PoseGraphEdges
        :func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` of the problem.
    known : list of numpy.ndarray
        Known-inlier masks per factor batch (e.g. with the cycle-consistent edges marked);
        not modified.
    quantile : float
        Chi-square quantile of the agreement test, ``0 < quantile < 1``.
    start : list of numpy.ndarray, optional
        Whitened squared residuals at the start values per factor batch (see
        :func:`merge_components`).

    Returns
    -------
    list of numpy.ndarray
        New masks: ``known`` or, on the BetweenFactor rows, merged by the vote.

    Raises
    ------
    ValueError
        ``quantile`` out of range.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor, Isotropic
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_merge import merge_known
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(4), fixed=[0])
    >>> # pieces {0, 1} and {2, 3} (known), joined by two agreeing edges and a random one
    >>> Z = SE2.from_xy_theta([1.0, 1, 2, 4, 9], [0.0, 0, 0, 0, 4], [0.0] * 5)
    >>> f = g.add(BetweenFactor(x, [0, 2, 1, 0, 1], [1, 3, 2, 3, 3], Z, Isotropic(3, 0.1)))
    >>> kn = [np.array([True, True, False, False, False])]
    >>> merge_known(pose_graph_edges(g.problem()), kn, 0.99)[0].tolist()
    [True, True, True, True, False]
    """
    from scipy.stats import chi2  # type: ignore[import-untyped]

    if not 0.0 < quantile < 1.0:
        raise ValueError(f"merge_known: quantile must be strictly between 0 and 1, got "
                         f"{quantile!r}")
    kn = np.concatenate([known[k] for k, _ in edges.rows])
    n, ii, jj = edges.n, edges.ii, edges.jj
    M = np.asarray(edges.Z.matrix(), dtype=np.float64)
    P = _place(np.tile(np.eye(M.shape[-1]), (n, 1, 1)), M, ii, jj, np.arange(n), n,
               np.flatnonzero(kn), edges.anchor)
    c2 = float(chi2.ppf(quantile, edges.info.shape[-1]))
    _, merged, _ = merge_components(edges.group, n, ii, jj, edges.Z, edges.info,
                                    edges.group.from_matrix(P), kn, c2, edges.anchor,
                                    start=_edge_start(edges, start))
    out = [np.array(k, dtype=bool) for k in known]
    for k, sl in edges.rows:
        out[k] |= merged[sl]
    return out
