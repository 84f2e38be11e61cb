"""Assemble the pieces of a pose graph by cycle consistency between them, before GNC judges.

After the cycle marking (:mod:`microlie.optim.core.gnc_cycles`) and the vote of
:func:`~microlie.optim.core.gnc_merge.merge_known`, the known edges of ``GNC(first="cycles")``
form *pieces* (connected components), each correct inside. Without known inliers on M3500 the
pieces are many (1094 at 10% random loop closures, seed 0, 997 of them single poses) and
linked by single edges; the chordal GNC stage then judges every link at once and rejects 51-134
good odometry edges, breaking the chain into misplaced segments. :func:`assemble_edges` joins
pieces first where cycles *of pieces* close, and defers every ambiguous choice:

1. Each piece is posed by the least squares of its known edges (:func:`pose_pieces`, from one
   chordal relaxation, then from the last round's poses with the joined pieces moved along
   the new edges, :func:`join_pieces`) and taken as rigid, with its frame at its lowest vertex
   ``r``. An edge ``e = (a, b)`` between pieces ``A`` and ``B`` is then a relative pose of
   their frames, ``D_e = Q_a Z_e Q_b^-1`` with ``Q_v = X_r^-1 X_v``, of covariance
   ``Ad(Q_b) Sigma_e Ad(Q_b)^T`` (right perturbations).
2. Series reduction (:func:`reduce_series`): a piece with one link is set aside (no cycle
   passes through it), a piece with exactly two links to two different pieces is replaced by
   the composed link (``D_1 D_2``, covariance ``Ad(D_2^-1) S_1 Ad(D_2^-1)^T + S_2``), until
   neither applies. A chain of poses between two closures becomes one link, so a cycle of a
   few links can stand for a cycle of dozens of edges.
3. A link that is the only one between its two pieces is tested on the cycles of links of
   :func:`~microlie.optim.core.gnc_loops.cycle_consistent_edges` (up to ``max_length`` = 5
   links; one consistent cycle is enough); several links between the same two pieces vote
   (:func:`parallel_links`: the largest set of links that agree with each other, kept when
   it has two links or more and more than any other set; one against one waits). Every edge
   of a kept link becomes known.

Rounds repeat on the joined pieces until no edge becomes known: a pair that was one link
against one often has a second agreeing link once its pieces have grown, and a wrong link
agrees with nothing. Edges never joined are left to GNC. The tests use the covariances scaled
by the a posteriori variance factor of the known edges (:func:`variance_factor` at the first
poses, clipped to ``[1e-3, 1]``): the information of M3500 overstates its noise about 35
times (``v = 0.028``), and with the file's covariance cycles of a few dozen edges close around
random edges by chance (60 wrong edges marked at 10%, seed 0); with the measured noise none.
Measured on M3500 (``benchmarks/results/robust-assemble-s14.md``): 10% seed 0, 3465 known edges
before, 4871 after (of 5258 good), none wrong; 30% seeds 0/1: 1947/2032 before, 4524/4549 after,
none wrong; 50% seed 0: 1090 before, 3441 after, 2 wrong (asking two cycles of every link
longer than four: 3013, none wrong, but the answers at 50% were 15-50 edges worse). A rigid
piece ignores the uncertainty of its own shape, so good links between a large piece and a small
one can disagree under the measured noise; they are then left to GNC, not joined wrongly.

Examples
--------
>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.core.gnc_assemble import assemble_edges
>>> # a ring of 8 unit steps turning 45 degrees (a regular octagon) and one random chord 0-4;
>>> # no short cycle: nothing was known before
>>> a = np.pi / 4
>>> Z = SE2.from_xy_theta([1.0] * 8 + [3.0], [0.0] * 8 + [2.0], [a] * 8 + [1.0])
>>> ii, jj = np.array([0, 1, 2, 3, 4, 5, 6, 7, 0]), np.array([1, 2, 3, 4, 5, 6, 7, 0, 4])
>>> info = np.tile(np.eye(3) * 100.0, (9, 1, 1))
>>> assemble_edges(SE2, 8, ii, jj, Z, info, np.zeros(9, bool), 0).tolist()
[True, True, True, True, True, True, True, True, False]
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...groups import SE2, SE3, LieGroup

__all__ = ["reduce_series", "parallel_links", "assemble_edges", "assemble_known",
           "variance_factor", "known_variance", "pose_pieces", "join_pieces"]

_V_MIN = 1e-3  # the variance factor is clipped to [_V_MIN, 1]


def _adjoint(group: Any, M: np.ndarray) -> np.ndarray:
    """``Ad(M)`` of SE2/SE3 homogeneous matrices ``(..., k, k)`` (tangent order: translation,
    then rotation), in plain numpy (the group's constructor checks cost ~1 ms a call)."""
    M = np.asarray(M, dtype=np.float64)
    R, t = M[..., :-1, :-1], M[..., :-1, -1]
    if M.shape[-1] == 3:
        A = np.zeros(M.shape[:-2] + (3, 3))
        A[..., :2, :2] = R
        A[..., 0, 2] = t[..., 1]
        A[..., 1, 2] = -t[..., 0]
        A[..., 2, 2] = 1.0
        return A
    tx = np.zeros(M.shape[:-2] + (3, 3))
    tx[..., 0, 1], tx[..., 0, 2], tx[..., 1, 2] = -t[..., 2], t[..., 1], -t[..., 0]
    tx = tx - np.swapaxes(tx, -1, -2)
    A = np.zeros(M.shape[:-2] + (6, 6))
    A[..., :3, :3] = R
    A[..., :3, 3:] = tx @ R
    A[..., 3:, 3:] = R
    return A


def reduce_series(group: Any, n: int, a: np.ndarray, b: np.ndarray, D: np.ndarray,
                  S: np.ndarray, keep: int | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """Series reduction of a multigraph of relative poses ``X_a^-1 X_b = D`` (module step 2).

    Repeatedly: a vertex with one incident link is removed with it; a vertex with exactly two
    incident links to two different vertices ``u``, ``w`` is removed and the two replaced by
    their composition ``u -> w`` (first-order covariance, right perturbations).

    Parameters
    ----------
    group : type
        SE2 or SE3.
    n : int
        Number of vertices.
    a, b : numpy.ndarray
        ``(L,)`` vertex indices of the links.
    D : numpy.ndarray
        ``(L, k, k)`` homogeneous matrices of the links.
    S : numpy.ndarray
        ``(L, d, d)`` their covariances (the group's tangent order).
    keep : int, optional
        A vertex never removed.

    Returns
    -------
    a, b : numpy.ndarray
        ``(R,)`` the links that remain, composed or not.
    D, S : numpy.ndarray
        Their relative poses and covariances.
    members : list of numpy.ndarray
        For each remaining link the indices of the input links composed into it.

    Raises
    ------
    ValueError
        Inconsistent shapes or vertices out of range.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_assemble import reduce_series
    >>> M = np.asarray(SE2.from_xy_theta([1.0] * 3, [0.0] * 3, [0.0] * 3).matrix())
    >>> S = np.tile(np.eye(3) * 0.01, (3, 1, 1))
    >>> a, b, D, S2, mem = reduce_series(SE2, 4, np.array([0, 1, 2]), np.array([1, 2, 3]), M, S,
    ...                                  keep=0)  # the path 0-1-2-3: everything goes
    >>> a.size
    0
    >>> a, b, D, S2, mem = reduce_series(SE2, 3, np.array([0, 1, 0]), np.array([1, 2, 2]),
    ...                                  M, S, keep=0)  # a triangle: vertex 2 goes first
    >>> a.tolist(), b.tolist(), [m.tolist() for m in mem]  # 0 -> 1 and 1 -> 2 -> 0 remain
    ([0, 1], [1, 0], [[0], [1, 2]])
    >>> np.round(D[1], 9).tolist()  # 1 m forwards, then 2 m back: the identity
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    """
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    L = a.size
    if b.shape != (L,) or np.shape(D)[0] != L or np.shape(S)[0] != L or \
            (L and (min(a.min(), b.min()) < 0 or max(a.max(), b.max()) >= n)):
        raise ValueError("reduce_series: a, b, D and S must have one entry per link, with "
                         "vertices in [0, n)")
    links: dict[int, list[Any]] = {k: [int(a[k]), int(b[k]), D[k], S[k], [k]]
                                   for k in range(L)}
    inc: list[set[int]] = [set() for _ in range(n)]
    for k in range(L):
        inc[int(a[k])].add(k)
        inc[int(b[k])].add(k)
    nxt = L
    todo = [v for v in range(n) if len(inc[v]) in (1, 2) and v != keep]
    while todo:
        v = todo.pop()
        if len(inc[v]) == 1:
            (k,) = inc[v]
            u, w = links[k][0], links[k][1]
            o = w if u == v else u
            if o == v:
                continue
            del links[k]
            inc[v].clear()
            inc[o].discard(k)
            if o != keep:
                todo.append(o)
            continue
        if len(inc[v]) != 2:
            continue
        k1, k2 = sorted(inc[v])
        l1, l2 = links[k1], links[k2]
        o1 = l1[1] if l1[0] == v else l1[0]
        o2 = l2[1] if l2[0] == v else l2[0]
        if o1 == v or o2 == v or o1 == o2:
            continue  # a self-loop or two links to one vertex: not a series
        D1, S1 = (l1[2], l1[3]) if l1[1] == v else _reverse(group, l1[2], l1[3])
        D2, S2 = (l2[2], l2[3]) if l2[0] == v else _reverse(group, l2[2], l2[3])
        A = _adjoint(group, np.linalg.inv(D2))
        del links[k1], links[k2]
        inc[v].clear()
        inc[o1].discard(k1)
        inc[o2].discard(k2)
        links[nxt] = [o1, o2, D1 @ D2, A @ S1 @ A.T + S2, l1[4] + l2[4]]
        inc[o1].add(nxt)
        inc[o2].add(nxt)
        nxt += 1
        for o in (o1, o2):
            if o != keep and len(inc[o]) in (1, 2):
                todo.append(o)
    rest = list(links.values())
    k_ = np.shape(D)[-1]
    d_ = np.shape(S)[-1]
    return (np.array([r[0] for r in rest], dtype=np.int64),
            np.array([r[1] for r in rest], dtype=np.int64),
            np.array([r[2] for r in rest]).reshape(-1, k_, k_),
            np.array([r[3] for r in rest]).reshape(-1, d_, d_),
            [np.array(r[4], dtype=np.int64) for r in rest])


def parallel_links(group: Any, a: np.ndarray, b: np.ndarray, D: np.ndarray, S: np.ndarray,
                   c2: float) -> np.ndarray:
    """The links of every pair of vertices joined by several links that agree, with a margin.

    Links ``k`` and ``l`` between the same two vertices (both walked from the lower one)
    agree when ``r = Log(D_k^-1 D_l)`` passes ``r^T (Ad(R^-1) S_k Ad(R^-1)^T + S_l)^-1 r <=
    c2`` (``R = D_k^-1 D_l``) both ways. The largest set of mutually agreeing links
    (:func:`~microlie.optim.core.gnc_merge.agreeing_set`) is kept when it has at least two
    links and more than the largest agreeing set of the other links; otherwise (one link
    against one, two against two) the pair is left for later rounds.

    Parameters
    ----------
    group : type
        SE2 or SE3.
    a, b : numpy.ndarray
        ``(L,)`` vertex indices of the links.
    D : numpy.ndarray
        ``(L, k, k)`` homogeneous matrices of the links ``X_a^-1 X_b``.
    S : numpy.ndarray
        ``(L, d, d)`` their covariances.
    c2 : float
        The threshold of the agreement statistic.

    Returns
    -------
    numpy.ndarray
        Indices of the kept links, sorted.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_assemble import parallel_links
    >>> D = np.asarray(SE2.from_xy_theta([2.0, 2.01, 5.0], [0.0, 0.0, 1.0], [0.0] * 3).matrix())
    >>> parallel_links(SE2, np.array([0, 0, 1]), np.array([1, 1, 0]), D,
    ...                np.tile(np.eye(3) * 0.01, (3, 1, 1)), 11.34).tolist()
    [0, 1]
    """
    from .gnc_merge import agreeing_set

    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    flip = a > b
    Do = D.copy()
    So = S.copy()
    if flip.any():
        Do[flip], So[flip] = _reverse(group, D[flip], S[flip])
    key = np.where(flip, b, a) * (int(max(a.max(), b.max())) + 1) + np.where(flip, a, b)
    order = np.argsort(key, kind="stable")
    starts = np.flatnonzero(np.r_[True, key[order][1:] != key[order][:-1]])
    sizes = np.diff(np.r_[starts, order.size])
    groups = [order[s0:s0 + m] for s0, m in zip(starts, sizes, strict=True) if m >= 2]
    out: list[int] = []
    if not groups:
        return np.zeros(0, dtype=np.int64)
    # every ordered pair of links of every group at once (one Log call)
    k = np.concatenate([np.repeat(e, e.size) for e in groups])
    l_ = np.concatenate([np.tile(e, e.size) for e in groups])
    R = np.linalg.inv(Do[k]) @ Do[l_]
    r = np.asarray(group.from_matrix(R).log(), dtype=np.float64)
    Ai = _adjoint(group, np.linalg.inv(R))
    C = Ai @ So[k] @ np.swapaxes(Ai, 1, 2) + So[l_]
    s2 = np.einsum("ca,ca->c", r, np.linalg.solve(C, r[:, :, None])[:, :, 0])
    pos = 0
    for e in groups:
        m = e.size
        ok = (s2[pos:pos + m * m] <= c2).reshape(m, m)
        pos += m * m
        ok = ok & ok.T
        best = agreeing_set(ok)
        if best.size < 2:
            continue
        rest = np.setdiff1d(np.arange(m), best)
        second = agreeing_set(ok[np.ix_(rest, rest)]).size if rest.size else 0
        if best.size > second:
            out.extend(int(x) for x in e[best])
    return np.array(sorted(out), dtype=np.int64)


def _reverse(group: Any, D: np.ndarray, S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A link walked backwards: ``D^-1`` with covariance ``Ad(D) S Ad(D)^T``."""
    A = _adjoint(group, D)
    return np.linalg.inv(D), A @ S @ np.swapaxes(A, -1, -2)


def join_pieces(P: np.ndarray, M: np.ndarray, ii: np.ndarray, jj: np.ndarray,
                inside: np.ndarray, joins: np.ndarray, root: int) -> np.ndarray:
    """Move the components of the ``inside`` edges rigidly so that a spanning forest of the
    ``joins`` edges fits exactly (the component of vertex ``root``, else the lowest vertex's
    of each tree, stays).

    Parameters
    ----------
    P : numpy.ndarray
        ``(n, k, k)`` pose matrices.
    M : numpy.ndarray
        ``(E, k, k)`` measurement matrices (``X_i^-1 X_j = M``).
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges.
    inside : numpy.ndarray
        ``(E,)`` booleans: the edges that hold the components together (kept as they are).
    joins : numpy.ndarray
        ``(E,)`` booleans: the edges the components are joined along.
    root : int
        A vertex whose component never moves.

    Returns
    -------
    numpy.ndarray
        ``(n, k, k)`` the moved poses (a copy).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_assemble import join_pieces
    >>> P = np.asarray(SE2.from_xy_theta([0.0, 1.0, 7.0, 8.0], [0.0] * 4, [0.0] * 4).matrix())
    >>> M = np.asarray(SE2.from_xy_theta([1.0] * 3, [0.0] * 3, [0.0] * 3).matrix())
    >>> ii, jj = np.array([0, 1, 2]), np.array([1, 2, 3])
    >>> Q = join_pieces(P, M, ii, jj, np.array([True, False, True]),
    ...                 np.array([False, True, False]), 0)
    >>> np.round(Q[:, 0, 2], 9).tolist()  # the piece {2, 3} moved 5 m back
    [0.0, 1.0, 2.0, 3.0]
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import breadth_first_order, connected_components

    n = P.shape[0]
    inside = np.asarray(inside, dtype=bool)
    _, lab = connected_components(
        coo_matrix((np.ones(int(inside.sum())), (ii[inside], jj[inside])), shape=(n, n)),
        directed=False)
    e = np.flatnonzero(np.asarray(joins, dtype=bool) & (lab[ii] != lab[jj]))
    P = P.copy()
    if not e.size:
        return P
    nc = int(lab.max()) + 1
    a, b = lab[ii[e]], lab[jj[e]]
    adj = coo_matrix((np.arange(1, e.size + 1, dtype=np.float64), (a, b)), shape=(nc, nc))
    adj = adj.tocsr()  # duplicates summed: the entry is looked up by the pair below
    first = {}
    for k in range(e.size - 1, -1, -1):
        first[(int(a[k]), int(b[k]))] = int(e[k])
        first[(int(b[k]), int(a[k]))] = int(e[k])
    ntree, tree = connected_components(adj, directed=False)
    motion = np.tile(np.eye(P.shape[-1]), (nc, 1, 1))
    moved = np.zeros(nc, dtype=bool)
    for t in range(ntree):
        members = np.flatnonzero(tree == t)
        if members.size < 2:
            continue
        start = int(lab[root]) if lab[root] in members else int(members.min())
        order, pred = breadth_first_order(adj, start, directed=False)
        for c in order[1:]:
            q = int(pred[c])
            k = first[(q, int(c))]
            i, j = ii[k], jj[k]
            if lab[i] == q:  # place c so that edge k fits, with q already placed
                motion[c] = motion[q] @ P[i] @ M[k] @ np.linalg.inv(P[j])
            else:
                motion[c] = motion[q] @ P[j] @ np.linalg.inv(M[k]) @ np.linalg.inv(P[i])
            moved[c] = True
    m = moved[lab]
    P[m] = motion[lab[m]] @ P[m]
    return P


def pose_pieces(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                info: np.ndarray, known: np.ndarray, X: LieGroup, *, max_iter: int = 20
                ) -> np.ndarray:
    """Each piece (component of the ``known`` edges) at the least-squares optimum of its known
    edges, from ``X`` (Levenberg-Marquardt, the lowest vertex of each piece held).

    The chordal relaxation is not the maximum-likelihood estimate: on M3500 its pieces are
    bent by more than the measured noise, so that good edges between two pieces disagree
    when the tests use that noise.

    Parameters
    ----------
    group : type
        SE2 or SE3.
    n : int
        Number of vertices.
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges.
    Z : LieGroup
        ``(E,)`` measurements.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices.
    known : numpy.ndarray
        ``(E,)`` booleans.
    X : LieGroup
        ``(n,)`` the start (e.g. the chordal relaxation of the known edges).
    max_iter : int
        Iterations at most.

    Returns
    -------
    numpy.ndarray
        ``(n, k, k)`` pose matrices.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_assemble import pose_pieces
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 2.0], [0.0] * 3, [0.0] * 3)
    >>> X = SE2.from_xy_theta([0.0, 0.5, 3.0], [0.0] * 3, [0.0] * 3)
    >>> P = pose_pieces(SE2, 3, np.array([0, 1, 0]), np.array([1, 2, 2]), Z,
    ...                 np.tile(np.eye(3), (3, 1, 1)), np.ones(3, bool), X)
    >>> np.round(P[:, 0, 2], 9).tolist()
    [0.0, 1.0, 2.0]
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from .factors import BetweenFactor
    from .noise import Information
    from .problem import Problem
    from .solvers import solve
    from .variables import new_variables

    known = np.asarray(known, dtype=bool)
    if not known.any():
        return np.asarray(X.matrix(), dtype=np.float64)
    nc, lab = connected_components(
        coo_matrix((np.ones(int(known.sum())), (ii[known], jj[known])), shape=(n, n)),
        directed=False)
    rep = np.zeros(nc, dtype=np.int64)
    rep[lab[::-1]] = np.arange(n)[::-1]
    x = new_variables(None, 0, X, "pieces")  # a problem of its own (no graph: no cycle)
    x.fix(rep)
    f = BetweenFactor(x, ii[known], jj[known], Z[known],  # type: ignore[call-overload]
                      Information(info[known]))
    res = solve(Problem([x], [f]), [np.asarray(X.params, dtype=np.float64)], "lm",
                max_iter=max_iter, verbose=False)
    return np.asarray(res.values[x].matrix(), dtype=np.float64)


def variance_factor(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                    info: np.ndarray, X: np.ndarray, known: np.ndarray) -> float:
    """A posteriori variance factor of the known edges at poses ``X``: ``sum s / r`` with
    ``s`` their whitened squared residuals and ``r = dof * (edges - (vertices - pieces))``
    their redundancy (1.0 without redundancy).

    Parameters
    ----------
    group : type
        SE2 or SE3.
    n : int
        Number of vertices.
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges.
    Z : LieGroup
        ``(E,)`` measurements.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices.
    X : numpy.ndarray
        ``(n, k, k)`` pose matrices (e.g. the relaxation of the known edges).
    known : numpy.ndarray
        ``(E,)`` booleans.

    Returns
    -------
    float
        ``v`` (about 1 when the information is calibrated and ``X`` is their optimum).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_assemble import variance_factor
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 2.2], [0.0] * 3, [0.0] * 3)  # 2.2 m against 2 m
    >>> X = np.asarray(SE2.from_xy_theta([0.0, 1.07, 2.13], [0.0] * 3, [0.0] * 3).matrix())
    >>> v = variance_factor(SE2, 3, np.array([0, 1, 0]), np.array([1, 2, 2]), Z,
    ...                     np.tile(np.eye(3), (3, 1, 1)), X, np.ones(3, bool))
    >>> round(v, 6)  # (0.07^2 + 0.06^2 + 0.07^2) / (3 * (3 - 2)): one cycle, three dof
    0.004467
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from .gnc_bridges import whitened_residuals

    known = np.asarray(known, dtype=bool)
    if not known.any():
        return 1.0
    ncomp, _ = connected_components(
        coo_matrix((np.ones(int(known.sum())), (ii[known], jj[known])), shape=(n, n)),
        directed=False)
    red = info.shape[-1] * (int(known.sum()) - (n - ncomp))
    if red <= 0:
        return 1.0
    s = whitened_residuals(group, X, ii[known], jj[known], Z[known].inverse(),  # type: ignore[call-overload]
                           info[known])
    return float(s.sum()) / red


def _pose_known(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                info: np.ndarray, known: np.ndarray, anchor: int) -> np.ndarray:
    """``(n, k, k)`` poses with each piece of the known edges at its own least-squares optimum
    (one chordal relaxation of the known edges, then :func:`pose_pieces`)."""
    from ..linalg.base import SingularSystemError
    from .gnc_chordal import chordal_gnc

    try:
        X, _, _ = chordal_gnc(group, n, ii, jj, Z, info, anchor, group.identity(), known,
                              rejected=~known)
        P = np.asarray(X.matrix(), dtype=np.float64)
    except SingularSystemError:  # pieces held by the floor weights only: walk their edges
        M = np.asarray(Z.matrix(), dtype=np.float64)
        P = join_pieces(np.tile(np.eye(M.shape[-1]), (n, 1, 1)), M, ii, jj,
                        np.zeros(ii.size, dtype=bool), known, anchor)
    return pose_pieces(group, n, ii, jj, Z, info, known, group.from_matrix(P))


def known_variance(edges: Any, known: list[np.ndarray], quantile: float) -> float:
    """The a posteriori variance factor of a pose graph's known edges, each piece at its
    least-squares optimum, trimmed of the edges it makes outliers; clipped to ``[1e-3, 1]``:
    what ``GNC(variance_factor="estimate")`` scales the thresholds by.

    :func:`variance_factor` of the kept edges with the pieces posed on them, then the known
    edges with ``s > v chi2.ppf(quantile, dof)`` there dropped, until nothing changes (10
    rounds at most): one wrong edge among the known ones (a wrong closure within the file's
    overstated noise closes its cycles) would otherwise inflate ``v`` several times on a
    small graph.

    Parameters
    ----------
    edges : PoseGraphEdges
        :func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` of the problem.
    known : list of numpy.ndarray
        Known-inlier masks per factor batch (e.g. the cycle-consistent edges).
    quantile : float
        Chi-square quantile of the trimming test, ``0 < quantile < 1``.

    Returns
    -------
    float
        ``1.0`` when the known edges have no redundancy.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor, Isotropic
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_assemble import known_variance
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3), fixed=[0])
    >>> # a triangle 0.3 m short of closing in x; noise sigma 1 m: s = 0.3^2 / 3, one cycle
    >>> Z = SE2.from_xy_theta([1.0, 1.0, -2.3], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    >>> _ = g.add(BetweenFactor(x, [0, 1, 2], [1, 2, 0], Z, Isotropic(3, 1.0)))
    >>> round(known_variance(pose_graph_edges(g.problem()), [np.ones(3, bool)], 0.99), 6)
    0.01
    """
    from scipy.stats import chi2  # type: ignore[import-untyped]

    from .gnc_bridges import whitened_residuals

    kn = np.concatenate([known[k] for k, _ in edges.rows])
    if not kn.any():
        return 1.0
    c2 = float(chi2.ppf(quantile, edges.info.shape[-1]))
    keep = kn.copy()
    v = 1.0
    for _ in range(10):
        P = _pose_known(edges.group, edges.n, edges.ii, edges.jj, edges.Z, edges.info, keep,
                        edges.anchor)
        v = variance_factor(edges.group, edges.n, edges.ii, edges.jj, edges.Z, edges.info, P,
                            keep)
        s = whitened_residuals(edges.group, P, edges.ii, edges.jj, edges.Z.inverse(),
                               edges.info)
        new = kn & (s <= c2 * v)  # a dropped edge that fits the poses without it comes back
        if np.array_equal(new, keep):
            break
        keep = new
    return min(1.0, max(_V_MIN, v))


def assemble_edges(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                   info: np.ndarray, known: np.ndarray, anchor: int, *,
                   quantile: float = 0.99, max_length: int = 5, max_rounds: int = 10,
                   support: int = 1, single: int = 5, variance: float | None = None
                   ) -> np.ndarray:
    """The known edges with those of consistent cycles of pieces and of the vote added
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
        ``(E, D, D)`` information matrices (positive definite).
    known : numpy.ndarray
        ``(E,)`` booleans: the edges trusted so far (their components are the pieces).
    anchor : int
        The vertex held by the relaxations (the gauge).
    quantile : float
        Chi-square quantile of the cycle and agreement tests, ``0 < quantile < 1``.
    max_length : int
        Longest cycle of pieces tested, 3 to 9 links.
    max_rounds : int
        Rounds at most, >= 1.
    support, single : int
        A link marks its edges on one consistent cycle of at most ``single`` links, else on
        at least ``support`` of them (up to ``max_length`` links; see
        :func:`~microlie.optim.core.gnc_loops.cycle_consistent_edges`).
    variance : float, optional
        The variance factor the covariances are scaled by; default: :func:`variance_factor`
        of the known edges at their first relaxation, clipped to ``[1e-3, 1]``.

    Returns
    -------
    numpy.ndarray
        ``(E,)`` booleans: ``known`` and the edges joined to it.

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
    from scipy.stats import chi2  # type: ignore[import-untyped]

    from .gnc_loops import cycle_consistent_edges

    if group not in (SE2, SE3):
        raise ValueError(f"assemble_edges: group must be SE2 or SE3, got {group!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    E = ii.size
    known = np.asarray(known, dtype=bool)
    if jj.shape != (E,) or known.shape != (E,) or np.shape(info)[0] != E or \
            (E and (min(ii.min(), jj.min()) < 0 or max(ii.max(), jj.max()) >= n)):
        raise ValueError("assemble_edges: ii, jj, known and info must have one entry per edge, "
                         "with vertices in [0, n)")
    if not 0 <= anchor < n:
        raise ValueError(f"assemble_edges: anchor must be a vertex in [0, {n}), got {anchor}")
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"assemble_edges: quantile must be strictly between 0 and 1, got "
                         f"{quantile!r}")
    for name, val, lo, hi in (("max_length", max_length, 3, 9),
                              ("max_rounds", max_rounds, 1, 10 ** 6),
                              ("support", support, 1, 10 ** 6), ("single", single, 3, 9)):
        if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or \
                not lo <= val <= hi:
            raise ValueError(f"assemble_edges: {name} must be an integer in [{lo}, {hi}], got "
                             f"{val!r}")
    if variance is not None and not (isinstance(variance, (float, int)) and
                                     np.isfinite(variance) and variance > 0):
        raise ValueError(f"assemble_edges: variance must be a finite number > 0, got "
                         f"{variance!r}")
    kn = known.copy()
    if E == 0:
        return kn
    M = np.asarray(Z.matrix(), dtype=np.float64)
    c2 = float(chi2.ppf(quantile, info.shape[-1]))

    def relax(P: np.ndarray, old: np.ndarray, mask: np.ndarray) -> np.ndarray:
        P = join_pieces(P, M, ii, jj, old, mask & ~old, anchor)
        return pose_pieces(group, n, ii, jj, Z, info, mask, group.from_matrix(P))

    ncomp, _ = connected_components(
        coo_matrix((np.ones(int(kn.sum())), (ii[kn], jj[kn])), shape=(n, n)), directed=False)
    if ncomp == 1:
        return kn  # one piece: nothing to join
    P = _pose_known(group, n, ii, jj, Z, info, kn, anchor)
    if variance is None:
        variance = min(1.0, max(_V_MIN, variance_factor(group, n, ii, jj, Z, info, P, kn)))
    info_v = info / variance
    cov_v = np.linalg.inv(info_v)
    was = kn.copy()  # the known edges P is posed for
    for _ in range(max_rounds):
        before = int(kn.sum())
        nc, lab = connected_components(
            coo_matrix((np.ones(before), (ii[kn], jj[kn])), shape=(n, n)), directed=False)
        rep = np.zeros(nc, dtype=np.int64)
        rep[lab[::-1]] = np.arange(n)[::-1]  # the lowest vertex of each piece: its frame
        Q = np.linalg.inv(P[rep[lab]]) @ P
        cross = np.flatnonzero(lab[ii] != lab[jj])
        if not cross.size:
            break
        Qb = Q[jj[cross]]
        D = Q[ii[cross]] @ M[cross] @ np.linalg.inv(Qb)
        A = _adjoint(group, Qb)
        S = A @ cov_v[cross] @ np.swapaxes(A, 1, 2)
        ca, cb, cD, cS, members = reduce_series(group, nc, lab[ii[cross]], lab[jj[cross]], D, S,
                                                keep=int(lab[anchor]))
        if ca.size:
            key = np.minimum(ca, cb) * nc + np.maximum(ca, cb)
            _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
            sel = np.flatnonzero(cnt[inv] == 1)  # one link between two pieces: cycles
            ok = cycle_consistent_edges(group, nc, ca[sel], cb[sel], group.from_matrix(cD[sel]),
                                        np.linalg.inv(cS[sel]), max_length=int(max_length),
                                        quantile=quantile, support=int(support),
                                        single=int(single))
            for k in sel[ok]:
                kn[cross[members[k]]] = True
            for k in parallel_links(group, ca, cb, cD, cS, c2):
                kn[cross[members[k]]] = True
        if int(kn.sum()) == before:
            break
        P = relax(P, was, kn)
        was = kn.copy()
    return kn


def assemble_known(edges: Any, known: list[np.ndarray], quantile: float
                   ) -> list[np.ndarray]:
    """:func:`assemble_edges` on a problem's pose graph: the known-inlier masks with the joined
    edges added (what ``GNC(first="cycles", assemble=True)`` runs after the vote of
    :func:`~microlie.optim.core.gnc_merge.merge_known`).

    Parameters
    ----------
    edges : PoseGraphEdges
        :func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` of the problem.
    known : list of numpy.ndarray
        Known-inlier masks per factor batch; not modified.
    quantile : float
        Chi-square quantile of the tests, ``0 < quantile < 1``.

    Returns
    -------
    list of numpy.ndarray
        New masks.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor, Isotropic
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_assemble import assemble_known
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(8), fixed=[0])
    >>> a = np.pi / 4  # the octagon of the module docstring and its random chord
    >>> Z = SE2.from_xy_theta([1.0] * 8 + [3.0], [0.0] * 8 + [2.0], [a] * 8 + [1.0])
    >>> f = g.add(BetweenFactor(x, [0, 1, 2, 3, 4, 5, 6, 7, 0], [1, 2, 3, 4, 5, 6, 7, 0, 4], Z,
    ...                         Isotropic(3, 0.1)))
    >>> assemble_known(pose_graph_edges(g.problem()), [np.zeros(9, bool)], 0.99)[0].tolist()
    [True, True, True, True, True, True, True, True, False]
    """
    kn = np.concatenate([known[k] for k, _ in edges.rows])
    new = assemble_edges(edges.group, edges.n, edges.ii, edges.jj, edges.Z, edges.info, kn,
                         edges.anchor, quantile=quantile)
    out = [np.array(k, dtype=bool) for k in known]
    for k, sl in edges.rows:
        out[k] |= new[sl]
    return out
