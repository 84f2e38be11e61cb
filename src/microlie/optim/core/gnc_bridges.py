"""Pieces of a pose graph held by one accepted edge: move them where most edges agree.

After GNC on a pose graph with many wrong loop closures, a piece of the graph can end up
held to the rest by a single accepted edge (a bridge of the accepted edges) while the good
edges that should hold it were rejected: the bridge, wrong or not, fits exactly (residual 0)
and the rejected edges do not fit at all, so no weight update can tell them apart. Measured on
sphere2500 with 30% random loop closures and no known inliers: 14 wrong closures accepted, each
with residual 0, and 64 good edges rejected. :func:`repair_bridges` looks at every accepted
judged edge with a zero residual that is a bridge of the accepted edges: every edge across
its cut (the bridge and the rejected ones) proposes a rigid motion ``D`` of the smaller piece
``P`` (``X_v <- D X_v`` for ``v`` in ``P``) that makes it fit exactly; the motion that the most
cut edges fit within their threshold (whitened squared residual ``<= c^2``) wins, and it is
applied, with those edges accepted and the others across the cut rejected, only when it has
more support than leaving the bridge alone (the TLS objective then falls by ``c^2/2`` per extra
edge). Known inliers keep weight 1 and count as support. Equal support is an exact tie of
the TLS objective (one edge accepted, one rejected, either way): with the whitened squared
residuals at the start values given (``start``), the choice with more edges within ``c^2`` at
the start wins (the start is the user's information; e.g. from an odometry start the odometry
edges fit exactly); otherwise the bridge is left alone. The anchor vertex never moves (when it
lies in the piece, the rest moves by the inverse motion), and with ``components=True`` the
pieces that no accepted edge holds are attached too.

Examples
--------
>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.core.gnc_bridges import repair_bridges
>>> # vertices 0-1-2 (a triangle) and 3-4: the piece {3, 4} hangs on a wrong edge 0-3
>>> # (accepted, weight 1) while the two good edges 2-3 and 1-4 were rejected
>>> Z = SE2.from_xy_theta([1.0, 1.0, 1.0, 5.0, 1.0, 3.0, 2.0],
...                       [0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0], [0.0] * 7)
>>> ii, jj = np.array([0, 1, 3, 0, 2, 1, 0]), np.array([1, 2, 4, 3, 3, 4, 2])
>>> X = SE2.from_xy_theta([0.0, 1.0, 2.0, 5.0, 6.0], [0.0, 0.0, 0.0, 5.0, 5.0], [0.0] * 5)
>>> w = np.array([1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 1.0])
>>> X2, w2 = repair_bridges(SE2, 5, ii, jj, Z, np.tile(np.eye(3) * 100.0, (7, 1, 1)), X, w,
...                         np.ones(7, bool), 11.34)
>>> np.round(X2.translation(), 6).tolist(), w2.tolist()
([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0], [4.0, 0.0]], [1.0, 1.0, 1.0, 0.0, 1.0, 1.0, 1.0])
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...groups import SE2, SE3, LieGroup

__all__ = ["repair_bridges", "repair_stage", "whitened_residuals"]


def whitened_residuals(group: Any, X: np.ndarray, ii: np.ndarray, jj: np.ndarray,
                       Zinv: LieGroup, info: np.ndarray) -> np.ndarray:
    """``r^T Omega r`` of pose-graph edges, ``r = Log(Z^-1 X_i^-1 X_j)`` (right-perturbation
    residual, the group's tangent order), poses as homogeneous matrices.

    Parameters
    ----------
    group : type
        SE2 or SE3.
    X : numpy.ndarray
        ``(..., n, k, k)`` pose matrices (leading axes: several placements at once).
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges.
    Zinv : LieGroup
        ``(E,)`` inverse measurements.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices.

    Returns
    -------
    numpy.ndarray
        ``(..., E)`` whitened squared residuals.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_bridges import whitened_residuals
    >>> X = np.asarray(SE2.from_xy_theta([0.0, 1.0], [0.0, 0.0], [0.0, 0.0]).matrix())
    >>> Z = SE2.from_xy_theta([3.0], [0.0], [0.0])  # measured 3 m, the poses are 1 m apart
    >>> whitened_residuals(SE2, X, np.array([0]), np.array([1]), Z.inverse(),
    ...                    np.eye(3)[None] * 4.0).round(12).tolist()  # (1 - 3)^2 * 4
    [16.0]
    """
    rel = np.linalg.inv(X[..., ii, :, :]) @ X[..., jj, :, :]
    shape = rel.shape[:-2]
    r = np.asarray(Zinv.compose(group.from_matrix(rel.reshape(-1, *rel.shape[-2:]))).log(),
                   dtype=np.float64).reshape(*shape, -1)
    return np.einsum("...a,...ab,...b->...", r, info, r)


def _start_key(s0: np.ndarray, c2: float) -> int:
    """How well a set of edges fits the start values (smaller is better): minus the number
    whose whitened squared residual at the start is within ``c2``. (Comparing the residuals
    themselves when none is within ``c2``, or the distance of the moved vertices to their
    start positions, was measured worse: a start bent by the outliers, e.g. the chordal
    relaxation of the corrupted graph, fits some wrong edges better than the good ones.)"""
    return -int(np.sum(s0 <= c2))


def _cut_motions(group: Any, P: np.ndarray, ii: np.ndarray, jj: np.ndarray, inP: np.ndarray,
                 cut: np.ndarray, M: np.ndarray, Minv: np.ndarray, Zinv: LieGroup,
                 info: np.ndarray, judged: np.ndarray, c2: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The motions ``D_k`` of the piece ``inP`` that make cut edge ``k`` fit exactly, and
    ``fits[k]``: the cut edges within ``c2`` once the piece is moved by ``D_k`` (none for a
    motion that breaks a known inlier)."""
    a, c = ii[cut], jj[cut]
    fwd = inP[c]  # i outside, j in P: D = X_i Z X_j^-1; else D = X_j Z^-1 X_i^-1
    D = np.where(fwd[:, None, None], P[a] @ M[cut] @ np.linalg.inv(P[c]),
                 P[c] @ Minv[cut] @ np.linalg.inv(P[a]))
    K = cut.size
    fits = np.zeros((K, K), dtype=bool)  # fits[k]: the cut edges that D_k fits
    Pa, Pc = P[a], P[c]
    info_c = info[cut]
    for lo in range(0, K, 256):  # all motions at once, in chunks
        Dk = D[lo:lo + 256, None]
        A_ = np.where(~fwd[None, :, None, None], Dk @ Pa[None], Pa[None])
        C_ = np.where(fwd[None, :, None, None], Dk @ Pc[None], Pc[None])
        rel = (np.linalg.inv(A_) @ C_).reshape(-1, *P.shape[1:])
        e = np.tile(cut, Dk.shape[0])
        r = np.asarray(Zinv[e].compose(group.from_matrix(rel)).log(),  # type: ignore[call-overload]
                       dtype=np.float64).reshape(Dk.shape[0], K, -1)
        fits[lo:lo + 256] = np.einsum("kea,eab,keb->ke", r, info_c, r) <= c2
    # a motion that breaks a known inlier: none
    broken = np.any(~judged[cut][None, :] & ~fits, axis=1)
    fits &= ~broken[:, None]
    return D, fits


def _choose(fits: np.ndarray, support: np.ndarray, cut: np.ndarray, s0: np.ndarray | None,
            c2: float) -> int:
    """The motion of most support; among equal support the one whose edges fit the start
    best (:func:`_start_key`), else the first."""
    tied = np.flatnonzero(support == support.max())
    if s0 is None:
        return int(tied[0])
    keys = [_start_key(s0[cut][fits[k]], c2) for k in tied]
    return int(tied[min(range(tied.size), key=keys.__getitem__)])


def _attach_components(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, P: np.ndarray,
                       w: np.ndarray, M: np.ndarray, Minv: np.ndarray, Zinv: LieGroup,
                       info: np.ndarray, judged: np.ndarray, c2: float, s0: np.ndarray | None,
                       anchor: int | None) -> bool:
    """The ``components=True`` pass of :func:`repair_bridges`: attach the components of the
    accepted edges (``w > 0.5``) that no accepted edge joins to the root (the anchor's
    component, else the largest), one at a time, ``P`` and ``w`` updated in place; True when
    one was attached.

    The rule: scan the components other than the root, largest first (equal sizes: the one
    with the lowest vertex first); the first whose cut motions (:func:`_cut_motions`) have any
    support is moved by the motion :func:`_choose` picks, its cut edges re-weighted (those
    within ``c2`` accepted), and the scan starts again on the new components. A component's
    support depends only on its vertices and on the poses at the ends of its cut edges, and an
    attachment moves only the attached component's vertices: so a component found without
    support is not evaluated again until it is merged or a neighbour across its cut moves.
    The decisions are those of rescanning every component after each attachment, with each
    component evaluated about once, not once per attachment (quadratic in the number of
    floating components); the components are kept by union-find, not recomputed. (Known
    inliers, ``judged`` False, are accepted edges, as GNC keeps them; a piece whose chosen
    motion accepts no edge, only a rejected known inlier fitting, is moved once and left,
    where the rescanning rule would move it again forever.)"""
    import heapq

    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    keep = np.flatnonzero(w > 0.5)
    ncomp, lab = connected_components(coo_matrix((np.ones(keep.size), (ii[keep], jj[keep])),
                                                 shape=(n, n)), directed=False)
    if ncomp < 2:
        return False
    order = np.argsort(lab, kind="stable")
    # the vertices of each component, as a list of arrays (merged small into large)
    members = [[m] for m in np.split(order, np.cumsum(np.bincount(lab, minlength=ncomp))[:-1])]
    size = [int(m[0].size) for m in members]
    low = [int(m[0][0]) for m in members]  # the lowest vertex (scipy numbers components by it)
    # edges incident to each vertex (CSR), self-loops once
    loop = ii == jj
    ends = np.concatenate([ii, jj[~loop]])
    eid = np.concatenate([np.arange(ii.size), np.flatnonzero(~loop)])
    by = np.argsort(ends, kind="stable")
    inc_ptr = np.concatenate([[0], np.cumsum(np.bincount(ends, minlength=n))])
    inc = eid[by]
    version = [0] * ncomp
    dead = [False] * ncomp
    alive = [True] * ncomp

    def key(c: int) -> tuple[int, int]:
        return -size[c], low[c]

    root = int(lab[anchor]) if anchor is not None else min(range(ncomp), key=key)
    heap = [(*key(c), c, 0) for c in range(ncomp) if c != root]
    heapq.heapify(heap)
    inP = np.zeros(n, dtype=bool)
    attached = False
    while heap:
        _, _, c, ver = heapq.heappop(heap)
        if not alive[c] or ver != version[c] or dead[c] or c == root:
            continue
        verts = np.sort(np.concatenate(members[c]))
        first, count = inc_ptr[verts], inc_ptr[verts + 1] - inc_ptr[verts]
        e = inc[np.arange(count.sum()) + np.repeat(first - (np.cumsum(count) - count), count)]
        e = e[(lab[ii[e]] == c) != (lab[jj[e]] == c)]
        cut = np.unique(e)
        if not cut.size:
            dead[c] = True
            continue
        inP[verts] = True
        D, fits = _cut_motions(group, P, ii, jj, inP, cut, M, Minv, Zinv, info, judged, c2)
        support = fits.sum(axis=1)
        if support.max() == 0:
            inP[verts] = False
            dead[c] = True
            continue
        best = _choose(fits, support, cut, s0, c2)
        P[inP] = D[best] @ P[inP]
        inP[verts] = False
        w[cut[judged[cut]]] = fits[best][judged[cut]].astype(np.float64)
        attached = True
        # the components across the cut: those joined by a newly accepted edge merge with c,
        # the others have a moved neighbour (their support may change)
        other = np.where(lab[ii[cut]] == c, jj[cut], ii[cut])
        near = set(lab[other].tolist())
        joined = set(lab[other[w[cut] > 0.5]].tolist()) | {c}
        base = max(joined, key=lambda k: size[k])  # relabel the smaller ones into it
        for k in joined - {base}:
            for m in members[k]:
                lab[m] = base
            members[base].extend(members[k])
            alive[k] = False
        size[base] = sum(size[k] for k in joined)
        low[base] = min(low[k] for k in joined)
        if root in joined:
            root = base
        elif anchor is None and key(base) < key(root):
            near.add(root)  # the old root is scanned as any other component now
            root = base
        for k in (near - joined) | {base}:
            version[k] += 1
            dead[k] = False
            if k != root:
                heapq.heappush(heap, (*key(k), k, version[k]))
        if joined == {c}:  # only a rejected known inlier fits: it would move forever
            dead[c] = True
    return attached


def repair_bridges(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                   info: np.ndarray, X: LieGroup, w: np.ndarray, judged: np.ndarray,
                   c2: float, *, zero: float = 1e-6, max_passes: int = 5,
                   start: np.ndarray | None = None, anchor: int | None = None,
                   components: bool = False) -> tuple[LieGroup, np.ndarray]:
    """Move pieces held by one accepted edge where most cut edges agree (module docstring).

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
        ``(n,)`` the poses after GNC.
    w : numpy.ndarray
        ``(E,)`` GNC's weights, 0 or 1 (not modified).
    judged : numpy.ndarray
        ``(E,)`` booleans: False for known inliers (never rejected).
    c2 : float
        The inlier threshold on the whitened squared residual.
    zero : float
        A bridge is a candidate when its whitened squared residual is below ``zero * c2``.
    max_passes : int
        Passes over the bridges at most (each pass recomputes them), >= 1.
    start : numpy.ndarray, optional
        ``(E,)`` whitened squared residuals at the start values (the user's information):
        breaks ties. Among motions of equal support the one with the most fitting edges
        that also fit the start (within ``c2`` there) wins (else the first), and a motion
        whose support only equals the bridge's is applied when more of its edges fit the
        start than of the accepted ones (an exact tie of the TLS objective: one edge
        rejected, one accepted). Without it, or when the start does not separate the
        choices, ties are left alone.
    anchor : int, optional
        A vertex that must not move (the gauge): when it lies in the piece, the rest of the
        graph is moved by the inverse motion instead (the same relative poses).
    components : bool
        Also attach every component of the accepted edges that no accepted edge joins to
        the anchor's (else the largest) component: it is moved by the motion of its cut
        edges with the most support (>= 1: the TLS objective falls by ``c^2/2`` per edge
        accepted; ties broken by ``start``), largest component first, one at a time.

    Returns
    -------
    poses : LieGroup
        ``(n,)`` the poses with the pieces moved (the rest unchanged).
    weights : numpy.ndarray
        ``(E,)`` the new weights.

    Raises
    ------
    ValueError
        A group other than SE2/SE3.

    Examples
    --------
    See the module docstring.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if group not in (SE2, SE3):
        raise ValueError(f"repair_bridges: group must be SE2 or SE3, got {group!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    s0 = None
    if start is not None:
        s0 = np.asarray(start, dtype=np.float64)
        if s0.shape != ii.shape or not np.all(s0 >= 0):
            raise ValueError(f"repair_bridges: start must hold one squared residual >= 0 per "
                             f"edge, shape {ii.shape}, got shape {s0.shape}")
    if anchor is not None and not 0 <= anchor < n:
        raise ValueError(f"repair_bridges: anchor must be a vertex in [0, {n}), got {anchor}")
    w = np.array(w, dtype=np.float64)
    P = np.array(X.matrix(), dtype=np.float64)
    Zinv = Z.inverse()
    M = np.asarray(Z.matrix(), dtype=np.float64)
    Minv = np.asarray(Zinv.matrix(), dtype=np.float64)
    for _ in range(max_passes):
        s = whitened_residuals(group, P, ii, jj, Zinv, info)
        acc = w > 0.5
        cand = np.flatnonzero(acc & judged & (s <= zero * c2))
        changed = False
        for b in cand[np.argsort(s[cand])]:
            keep = np.flatnonzero(acc)
            keep = keep[keep != b]
            _, lab = connected_components(coo_matrix((np.ones(keep.size), (ii[keep], jj[keep])),
                                                     shape=(n, n)), directed=False)
            la, lb = lab[ii[b]], lab[jj[b]]
            if la == lb:
                continue  # not a bridge
            side = lb if np.sum(lab == lb) <= np.sum(lab == la) else la
            inP = lab == side
            cut = np.flatnonzero(inP[ii] != inP[jj])
            if cut.size < 2:
                continue
            D, fits = _cut_motions(group, P, ii, jj, inP, cut, M, Minv, Zinv, info, judged,
                                   c2)
            support = fits.sum(axis=1)
            now = acc[cut] | ~judged[cut]
            top = int(support.max())
            if top < int(now.sum()) or top == 0:
                continue
            best = _choose(fits, support, cut, s0, c2)
            if top == int(now.sum()):  # a tie with leaving the bridge alone
                if s0 is None or np.array_equal(fits[best], now) or \
                        not _start_key(s0[cut][fits[best]], c2) < \
                        _start_key(s0[cut][now], c2):
                    continue
            if anchor is not None and inP[anchor]:  # the anchor stays: move the rest
                P[~inP] = np.linalg.inv(D[best]) @ P[~inP]
            else:
                P[inP] = D[best] @ P[inP]
            w[cut[judged[cut]]] = fits[best][judged[cut]].astype(np.float64)
            acc = w > 0.5
            changed = True
        if components and _attach_components(group, n, ii, jj, P, w, M, Minv, Zinv, info,
                                             judged, c2, s0, anchor):
            changed = True
        if not changed:
            break
    return group.from_matrix(P), w


def repair_stage(states: list[np.ndarray], edges: Any, known: list[np.ndarray],
                 weights: list[np.ndarray], c2: list[float],
                 start: list[np.ndarray] | None = None, components: bool = False
                 ) -> list[np.ndarray] | None:
    """:func:`repair_bridges` on a problem's pose graph after GNC: the new states (the
    BetweenFactor weights updated in place), or ``None`` when nothing moved. The anchor
    vertex never moves; ties are broken by the start values when ``start`` is given.

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
    start : list of numpy.ndarray, optional
        Whitened squared residuals at the start values per factor batch (ties: see
        :func:`repair_bridges`; non-finite values count as not fitting).
    components : bool
        Also attach the components no accepted edge holds (:func:`repair_bridges`).

    Returns
    -------
    list of numpy.ndarray or None

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_bridges import repair_stage
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(2), fixed=[0])
    >>> _ = g.add(BetweenFactor(x, [0], [1], SE2.identity(1)))
    >>> e = pose_graph_edges(g.problem())
    >>> repair_stage([np.asarray(SE2.identity(2).params)], e, [np.zeros(1, bool)],
    ...              [np.ones(1)], [11.34]) is None  # one edge: nothing to decide
    True
    """
    kn = np.concatenate([known[k] for k, _ in edges.rows])
    w = np.concatenate([weights[k] for k, _ in edges.rows])
    c = float(c2[edges.rows[0][0]])
    var = edges.variables
    X = var.group.from_params(np.asarray(states[0], dtype=np.float64))
    s0 = None
    if start is not None:
        s0 = np.concatenate([np.asarray(start[k], dtype=np.float64) for k, _ in edges.rows])
        s0 = np.where(np.isfinite(s0), np.abs(s0), np.inf)
    X2, w2 = repair_bridges(edges.group, edges.n, edges.ii, edges.jj, edges.Z, edges.info, X,
                            w, ~kn, c, start=s0, anchor=edges.anchor, components=components)
    if np.array_equal(w2, w):
        return None
    for k, sl in edges.rows:
        weights[k][:] = w2[sl]
    P = np.array(X2.params, dtype=np.float64)
    P[var.fixed] = np.asarray(states[0], dtype=np.float64)[var.fixed]
    return [P]
