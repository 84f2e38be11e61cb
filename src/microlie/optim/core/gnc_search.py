"""A local search on the TLS objective after GNC on a pose graph: rigid moves of regions.

GNC-TLS can stop in a local minimum of ``0.5 * sum min(s_k, c^2)``: on a pose graph with many
wrong loop closures a region of the graph sits at a wrong pose, held there by several accepted
wrong edges, while the good edges that should hold it (odometry among them) are rejected; no
weight update moves it, and :mod:`~microlie.optim.core.gnc_bridges` only moves pieces held by
one edge. Measured on M3500 with 10% random loop closures and no known inliers: the answer's
TLS objective is one edge (``c^2/2``) above the outlier-free optimum's, with 8 wrong closures
accepted and 9 good edges (8 of them odometry) rejected.

:func:`best_region_move` searches rigid moves of *regions*: unions of *pieces* (the
components of edges trusted inside, e.g. the cycle-consistent edges: each taken as rigid). A
rigid move of a region changes only the edges across its boundary, so its effect on the TLS
objective is exact and cheap: ``sum over boundary edges of min(s_new, c^2) - min(s_old, c^2)``
(halved). Each rejected edge ``e = (u, v)`` proposes the motion ``D`` that makes it fit
exactly when the side of ``v`` moves (``X <- D X``; and the mirror with ``u``); the region is
grown from the piece of ``v`` greedily, one adjacent piece at a time, always the one whose
joining lowers the objective change most (the pieces of ``u`` and of the anchor never join),
and the best region along the growth is that proposal's. The best proposal over all rejected
edges is returned when it lowers the objective by more than ``tol * c^2``.
:func:`search_stage` applies moves one at a time (poses and weights), then solves the inliers
and keeps the result only when the TLS objective after the solve is lower than before.

Examples
--------
>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.core.gnc_search import best_region_move
>>> # a chain 0-1-2-3-4-5 whose piece {3, 4, 5} sits 5 m off, held by two wrong edges
>>> # (0-4, 1-5, accepted: they fit) while the good edges 2-3 and 0-3, 1-4, 2-5 are rejected
>>> ii = np.array([0, 1, 3, 4, 2, 0, 1, 2, 0, 1])
>>> jj = np.array([1, 2, 4, 5, 3, 3, 4, 5, 4, 5])
>>> X = SE2.from_xy_theta([0.0, 1, 2, 3, 4, 5], [0.0, 0, 0, 5, 5, 5], [0.0] * 6)
>>> Z = SE2.from_xy_theta([1.0, 1, 1, 1, 1, 3, 3, 3, 4, 4], [0.0] * 8 + [5.0, 5.0], [0.0] * 10)
>>> lab = np.array([0, 0, 0, 1, 1, 1])  # the pieces: the chains {0, 1, 2} and {3, 4, 5}
>>> gain, moved, D = best_region_move(SE2, X, ii, jj, Z, np.tile(np.eye(3) * 100.0,
...                                   (10, 1, 1)), lab, np.ones(10, bool), 11.34, 0)
>>> round(gain / 11.34, 6), np.flatnonzero(moved).tolist()  # 2 wrong out, 4 good in
(-2.0, [3, 4, 5])
>>> np.round(D @ X.matrix()[3], 9)[:2, 2].tolist()  # vertex 3 moved to (3, 0)
[3.0, 0.0]
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from typing import Any

import numpy as np

from ...groups import SE2, SE3, LieGroup

__all__ = ["best_region_move", "chain_moves", "refine_motion", "region_moves",
           "search_stage"]


def _costs(group: Any, P: np.ndarray, ii: np.ndarray, jj: np.ndarray, Zinv: LieGroup,
           info: np.ndarray, c2: float, judged: np.ndarray) -> np.ndarray:
    """``min(s, c^2)`` of the judged edges, ``s`` of the others, poses as matrices."""
    r = group.log_matrix(np.asarray(Zinv.matrix(), dtype=np.float64) @ np.linalg.inv(P[ii]) @ P[jj])
    s = np.einsum("ea,eab,eb->e", r, info, r)
    return np.where(judged, np.minimum(s, c2), s)


def refine_motion(group: Any, P: np.ndarray, ii: np.ndarray, jj: np.ndarray, M: np.ndarray,
                  info: np.ndarray, c2: float, judged: np.ndarray, inR: np.ndarray
                  ) -> tuple[float, np.ndarray]:
    """The best motion of a region among those that make one edge across it fit exactly.

    Parameters
    ----------
    group : type
        SE2 or SE3.
    P : numpy.ndarray
        ``(n, k, k)`` the poses as homogeneous matrices.
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges.
    M : numpy.ndarray
        ``(E, k, k)`` the measurements as matrices.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices.
    c2 : float
        The threshold.
    judged : numpy.ndarray
        ``(E,)`` False for known inliers (cost ``s``).
    inR : numpy.ndarray
        ``(n,)`` booleans: the region.

    Returns
    -------
    gain : float
        The change of ``sum min(s, c^2)`` with the best motion (``inf`` without edges across).
    D : numpy.ndarray
        That motion (``X_v <- D X_v`` on the region).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_search import refine_motion
    >>> P = np.asarray(SE2.from_xy_theta([0.0, 5.0], [0.0, 0.0], [0.0, 0.0]).matrix())
    >>> M = np.asarray(SE2.from_xy_theta([1.0], [0.0], [0.0]).matrix())
    >>> gain, D = refine_motion(SE2, P, np.array([0]), np.array([1]), M,
    ...                         np.eye(3)[None] * 100.0, 11.34, np.ones(1, bool),
    ...                         np.array([False, True]))
    >>> round(gain, 6), np.round(D[:2, 2], 6).tolist()  # vertex 1 pulled 4 m back: fits
    (-11.34, [-4.0, 0.0])
    """
    cut = np.flatnonzero(inR[ii] != inR[jj])
    if not cut.size:
        return float("inf"), np.eye(P.shape[-1])
    a, b = ii[cut], jj[cut]
    fwd = inR[b]  # j in the region: D = X_i Z X_j^-1; else D = X_j Z^-1 X_i^-1
    Minv = np.linalg.inv(M[cut])
    D = np.where(fwd[:, None, None], P[a] @ M[cut] @ np.linalg.inv(P[b]),
                 P[b] @ Minv @ np.linalg.inv(P[a]))
    Pa, Pb = P[a], P[b]
    K = cut.size
    rel0 = np.linalg.inv(Pa) @ Pb
    r0 = group.log_matrix(Minv @ rel0)
    s0 = np.einsum("ea,eab,eb->e", r0, info[cut], r0)
    now = np.where(judged[cut], np.minimum(s0, c2), s0).sum()
    gains = np.empty(K)
    for lo in range(0, K, 64):
        Dk = D[lo:lo + 64, None]
        A_ = np.where(~fwd[None, :, None, None], Dk @ Pa[None], Pa[None])
        B_ = np.where(fwd[None, :, None, None], Dk @ Pb[None], Pb[None])
        rel = (np.linalg.inv(A_) @ B_).reshape(-1, *P.shape[1:])
        r = group.log_matrix(np.tile(Minv, (Dk.shape[0], 1, 1)) @ rel)
        sv = np.einsum("ea,eab,eb->e", r, np.tile(info[cut], (Dk.shape[0], 1, 1)), r)
        cv = np.where(np.tile(judged[cut], Dk.shape[0]), np.minimum(sv, c2), sv)
        gains[lo:lo + 64] = cv.reshape(Dk.shape[0], K).sum(axis=1) - now
    best = int(np.argmin(gains))
    return float(gains[best]), D[best]


def best_region_move(group: Any, X: LieGroup, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                     info: np.ndarray, lab: np.ndarray, judged: np.ndarray, c2: float,
                     anchor: int, *, tol: float = 0.25, margin: float = 6.0,
                     max_steps: int = 500, patience: int = 20
                     ) -> tuple[float, np.ndarray, np.ndarray]:
    """The best rigid region move proposed by the rejected edges (module docstring).

    Parameters
    ----------
    group : type
        SE2 or SE3.
    X : LieGroup
        ``(n,)`` the poses.
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges ``X_i^-1 X_j = Z``.
    Z : LieGroup
        ``(E,)`` measurements.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices.
    lab : numpy.ndarray
        ``(n,)`` piece label of each vertex (integers ``0..m-1``): pieces move as wholes.
    judged : numpy.ndarray
        ``(E,)`` booleans: False for known inliers (cost ``s``, never truncated).
    c2 : float
        The inlier threshold on the whitened squared residual (> 0).
    anchor : int
        The vertex that never moves.
    tol : float
        A move is returned only when it lowers ``sum min(s, c^2)`` by more than ``tol * c2``.
    margin : float
        A region stops growing when its objective change exceeds the best along its growth
        by ``margin * c2``.
    max_steps : int
        Pieces a region grows by at most, >= 1.
    patience : int
        A region stops growing after this many pieces without a new best.

    Returns
    -------
    gain : float
        The change of ``sum min(s, c^2)`` (twice the TLS objective's), < 0; 0 when no move.
    moved : numpy.ndarray
        ``(n,)`` booleans: the vertices of the region (all False when no move).
    D : numpy.ndarray
        The motion (a homogeneous matrix; ``X_v <- D X_v`` for the region).

    Raises
    ------
    ValueError
        A group other than SE2/SE3, or bad shapes.

    Examples
    --------
    See the module docstring.
    """
    moves = region_moves(group, X, ii, jj, Z, info, lab, judged, c2, anchor, tol=tol,
                         margin=margin, max_steps=max_steps, patience=patience)
    n = np.asarray(lab).size
    if not moves:
        return 0.0, np.zeros(n, dtype=bool), np.eye(np.asarray(X.matrix()).shape[-1])
    gain, region, D = moves[0]
    return gain, np.isin(np.asarray(lab), region), D


def region_moves(group: Any, X: LieGroup, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                 info: np.ndarray, lab: np.ndarray, judged: np.ndarray, c2: float,
                 anchor: int, *, tol: float = 0.25, margin: float = 6.0, max_steps: int = 500,
                 patience: int = 20, refine: float = 2.0
                 ) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """Every rejected edge's best region move that lowers the objective, best first.

    Parameters and the search as :func:`best_region_move`; with ``refine > 0`` every region
    whose change with the proposing edge's motion is below ``(refine - tol) * c2`` is tried
    with the motion of each edge across it (:func:`refine_motion`) and the best kept.

    Returns
    -------
    list of tuple
        ``(gain, pieces, D)``: the change of ``sum min(s, c^2)`` (< ``-tol * c2``), the piece
        labels of the region (sorted) and the motion, sorted by gain.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_search import region_moves
    >>> X = SE2.from_xy_theta([0.0, 1.0], [0.0, 0.0], [0.0, 0.0])
    >>> Z = SE2.from_xy_theta([1.0], [0.0], [0.0])
    >>> region_moves(SE2, X, np.array([0]), np.array([1]), Z, np.eye(3)[None] * 100.0,
    ...              np.array([0, 1]), np.ones(1, bool), 11.34, 0)  # it fits: no move
    []
    """
    if group not in (SE2, SE3):
        raise ValueError(f"region_moves: group must be SE2 or SE3, got {group!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    lab = np.asarray(lab, dtype=np.int64)
    judged = np.asarray(judged, dtype=bool)
    E = ii.size
    P = np.array(X.matrix(), dtype=np.float64)
    n = P.shape[0]
    if jj.shape != (E,) or judged.shape != (E,) or info.shape[0] != E or lab.shape != (n,):
        raise ValueError("region_moves: ii, jj, judged, info need one entry per edge and "
                         "lab one per vertex")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or \
            max_steps < 1:
        raise ValueError(f"region_moves: max_steps must be an integer >= 1, got {max_steps!r}")
    Zinv = Z.inverse()
    M = np.asarray(Z.matrix(), dtype=np.float64)
    base = _costs(group, P, ii, jj, Zinv, info, c2, judged)
    la, lb = lab[ii], lab[jj]
    cross = np.flatnonzero(la != lb)
    if not cross.size:
        return []
    m = int(lab.max()) + 1
    # incidence of the pieces: for each piece, its inter-piece edges (positions in ``cross``)
    ends = np.concatenate([la[cross], lb[cross]])
    pos = np.concatenate([np.arange(cross.size), np.arange(cross.size)])
    order = np.argsort(ends, kind="stable")
    start = np.searchsorted(ends[order], np.arange(m + 1)).tolist()
    inc_arr = pos[order]
    inc = inc_arr.tolist()
    ca, cb = la[cross].tolist(), lb[cross].tolist()
    base_c = base[cross]
    a_piece = int(lab[anchor])
    Pi, Pj = P[ii[cross]], P[jj[cross]]
    Pi_inv = np.linalg.inv(Pi)
    judged_c = judged[cross]
    Minv_cc = np.tile(np.linalg.inv(M[cross]), (2, 1, 1))
    info_cc = np.tile(info[cross], (2, 1, 1))
    judged_cc = np.tile(judged_c, 2)
    base_cc = np.tile(base_c, 2)
    out: list[tuple[float, np.ndarray, np.ndarray]] = []
    props = np.flatnonzero(judged_c & (base_c >= c2))  # rejected edges propose motions
    for k in props.tolist():
        e = int(cross[k])
        for side in (0, 1):  # 0: move the piece of j, 1: move the piece of i
            seed = cb[k] if side == 0 else ca[k]
            stay = ca[k] if side == 0 else cb[k]
            if seed == a_piece:
                continue
            if side == 0:
                D = P[ii[e]] @ M[e] @ np.linalg.inv(P[jj[e]])
            else:
                D = P[jj[e]] @ np.linalg.inv(M[e]) @ np.linalg.inv(P[ii[e]])
            # the change of every inter-piece edge with its j end moved (fj) or its i end
            # moved (fi)
            rel = np.concatenate([Pi_inv @ D @ Pj, Pi_inv @ np.linalg.inv(D) @ Pj])
            r = group.log_matrix(Minv_cc @ rel)
            sv = np.einsum("ea,eab,eb->e", r, info_cc, r)
            cv = np.where(judged_cc, np.minimum(sv, c2), sv) - base_cc
            fj, fi = cv[:cross.size].tolist(), cv[cross.size:].tolist()
            gain, region = _grow(seed, stay, a_piece, inc, start, ca, cb, fi, fj,
                                 max_steps, margin * c2, patience)
            if gain < -tol * c2 + refine * c2:
                out.append((gain, np.sort(np.asarray(region, dtype=np.int64)), D))
    if refine > 0:  # each region with the best motion of the edges across it
        done: list[tuple[float, np.ndarray, np.ndarray]] = []
        for g1, reg, D1 in out:
            g2, D2 = refine_motion(group, P, ii, jj, M, info, c2, judged, np.isin(lab, reg))
            done.append((g2, reg, D2) if g2 < g1 else (g1, reg, D1))
        out = [t for t in done if t[0] < -tol * c2]
    out.sort(key=lambda t: t[0])
    return out


def _grow(seed: int, stay: int, a_piece: int, inc: list[int], start: list[int], ca: list[int],
          cb: list[int], fi: list[float], fj: list[float], steps: int, margin: float,
          patience: int) -> tuple[float, list[int]]:
    """Greedy region growth from ``seed``: the best objective change along it and its pieces.

    ``fi[k]`` / ``fj[k]``: the change of inter-piece edge ``k`` when only its i / j end moves.
    """
    inS = {seed}
    region = [seed]
    gains: dict[int, float] = {}

    def edge_change(k: int, p: int) -> float:  # edge k across the boundary, p its end moved
        return fj[k] if cb[k] == p else fi[k]

    def join_gain(q: int) -> float:  # the change of the objective change when q joins
        g = 0.0
        for k in inc[start[q]:start[q + 1]]:
            o = cb[k] if ca[k] == q else ca[k]
            g += -edge_change(k, o) if o in inS else edge_change(k, q)
        return g

    cur = 0.0
    frontier = set()
    for k in inc[start[seed]:start[seed + 1]]:
        q = cb[k] if ca[k] == seed else ca[k]
        cur += edge_change(k, seed)
        if q not in (stay, a_piece):
            frontier.add(q)
    heap: list[tuple[float, int]] = []
    for q in frontier:
        gains[q] = join_gain(q)
        heapq.heappush(heap, (gains[q], q))
    best, best_len = cur, 1
    for _ in range(steps):
        while heap and (heap[0][1] in inS or gains.get(heap[0][1]) != heap[0][0]):
            heapq.heappop(heap)
        if not heap:
            break
        g, q = heapq.heappop(heap)
        inS.add(q)
        region.append(q)
        cur += g
        if cur < best - 1e-12:
            best, best_len = cur, len(region)
        elif cur > best + margin or len(region) - best_len > patience:
            break
        touched: set[int] = set()
        fresh: set[int] = set()
        for k in inc[start[q]:start[q + 1]]:
            o = cb[k] if ca[k] == q else ca[k]
            if o in inS or o == stay or o == a_piece:
                continue
            touched.add(o)
            if o in fresh or o not in gains:
                fresh.add(o)  # first touch: computed below with q in the region
            else:
                # edge k was o's edge to the outside, now to the region
                gains[o] -= edge_change(k, q) + edge_change(k, o)
        for o in fresh:
            gains[o] = join_gain(o)
        for o in touched:
            heapq.heappush(heap, (gains[o], o))
    return best, region[:best_len]


class _Pieces:
    """Rigid pieces of a pose graph under tentative moves: the current poses, the pieces'
    inter-piece edges and their costs ``min(s, c^2)`` (``s`` for known inliers), kept exact
    under :meth:`apply` / :meth:`undo` (only the edges across a moved region change)."""

    def __init__(self, group: Any, P: np.ndarray, ii: np.ndarray, jj: np.ndarray,
                 M: np.ndarray, info: np.ndarray, lab: np.ndarray, judged: np.ndarray,
                 c2: float, anchor: int, hood: int) -> None:
        self.group, self.P, self.c2, self.hood = group, P, c2, hood
        self.ii, self.jj, self.M, self.info, self.judged = ii, jj, M, info, judged
        self.Minv = np.linalg.inv(M)
        la, lb = lab[ii], lab[jj]
        self.cross = np.flatnonzero(la != lb)
        self.ca, self.cb = la[self.cross], lb[self.cross]
        m = int(lab.max()) + 1
        ends = np.concatenate([self.ca, self.cb])
        order = np.argsort(ends, kind="stable")
        self.start = np.searchsorted(ends[order], np.arange(m + 1))
        self.inc = np.concatenate([np.arange(self.cross.size)] * 2)[order]
        self.other = np.concatenate([self.cb, self.ca])[order]  # the far end's piece
        vorder = np.argsort(lab, kind="stable")
        vstart = np.searchsorted(lab[vorder], np.arange(m + 1))
        self.members = [vorder[vstart[p]:vstart[p + 1]] for p in range(m)]
        self.a_piece = int(lab[anchor])
        self.cc = self.costs(np.arange(self.cross.size))

    def costs(self, ks: np.ndarray) -> np.ndarray:
        """The costs of the inter-piece edges ``ks`` at the current poses."""
        e = self.cross[ks]
        r = self.group.log_matrix(self.Minv[e] @ np.linalg.inv(self.P[self.ii[e]]) @
                                  self.P[self.jj[e]])
        s = np.einsum("ea,eab,eb->e", r, self.info[e], r)
        return np.where(self.judged[e], np.minimum(s, self.c2), s)

    def nbrs(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        """The inter-piece edges of piece ``p`` and their far ends' pieces."""
        lo, hi = self.start[p], self.start[p + 1]
        return self.inc[lo:hi], self.other[lo:hi]

    def propose(self, k: int, side: int, locked: set[int]
                ) -> tuple[float, list[int], np.ndarray, int] | None:
        """The region move that makes inter-piece edge ``k`` fit by moving its j end's piece
        (``side`` 0) or its i end's (1), grown greedily within ``hood`` pieces of it (never into
        ``locked``, the anchor's piece or the other end's): ``(gain, pieces, D, k)``."""
        e = int(self.cross[k])
        seed = int(self.cb[k] if side == 0 else self.ca[k])
        stay = int(self.ca[k] if side == 0 else self.cb[k])
        if seed == self.a_piece or seed in locked:
            return None
        P = self.P
        if side == 0:
            D = P[self.ii[e]] @ self.M[e] @ np.linalg.inv(P[self.jj[e]])
        else:
            D = P[self.jj[e]] @ self.Minv[e] @ np.linalg.inv(P[self.ii[e]])
        blocked = locked | {stay, self.a_piece}
        hood, seen = [seed], {seed}
        at = 0
        while at < len(hood) < self.hood:  # breadth first from the seed, up to hood pieces
            for o in self.nbrs(hood[at])[1].tolist():
                if o not in seen and o not in blocked:
                    seen.add(o)
                    hood.append(o)
                    if len(hood) >= self.hood:
                        break
            at += 1
        ks = np.unique(np.concatenate([self.nbrs(p)[0] for p in hood]))
        e2 = self.cross[ks]
        Pi_inv = np.linalg.inv(P[self.ii[e2]])
        Pj = P[self.jj[e2]]
        rel = np.concatenate([Pi_inv @ D @ Pj, Pi_inv @ np.linalg.inv(D) @ Pj])
        r = self.group.log_matrix(np.concatenate([self.Minv[e2]] * 2) @ rel)
        s = np.einsum("ea,eab,eb->e", r, np.concatenate([self.info[e2]] * 2), r)
        jd = np.concatenate([self.judged[e2]] * 2)
        f = np.where(jd, np.minimum(s, self.c2), s) - np.concatenate([self.cc[ks]] * 2)
        fj = dict(zip(ks.tolist(), f[:ks.size].tolist(), strict=True))
        fi = dict(zip(ks.tolist(), f[ks.size:].tolist(), strict=True))
        gain, region = self._grow(seed, seen, fi, fj)
        return gain, region, D, k

    def _grow(self, seed: int, allowed: set[int], fi: dict[int, float], fj: dict[int, float],
              margin: float = 6.0, patience: int = 20) -> tuple[float, list[int]]:
        """Greedy growth from ``seed`` within ``allowed`` (as :func:`_grow`)."""
        cb = self.cb
        inS, region = {seed}, [seed]

        def change(k: int, p: int) -> float:  # edge k across the boundary, p its end moved
            return fj[k] if cb[k] == p else fi[k]

        def join_gain(q: int) -> float:
            ks, os_ = self.nbrs(q)
            return sum(-change(k, o) if o in inS else change(k, q)
                       for k, o in zip(ks.tolist(), os_.tolist(), strict=True))

        ks, os_ = self.nbrs(seed)
        cur = sum(change(k, seed) for k in ks.tolist())
        gains = {q: join_gain(q) for q in set(os_.tolist()) if q in allowed and q != seed}
        heap = [(g, q) for q, g in gains.items()]
        heapq.heapify(heap)
        best, best_len = cur, 1
        while heap:
            g, q = heapq.heappop(heap)
            if q in inS or gains.get(q) != g:
                continue
            inS.add(q)
            region.append(q)
            cur += g
            if cur < best - 1e-12:
                best, best_len = cur, len(region)
            elif cur > best + margin * self.c2 or len(region) - best_len > patience:
                break
            for o in set(self.nbrs(q)[1].tolist()):
                if o not in inS and o in allowed:
                    gains[o] = join_gain(o)
                    heapq.heappush(heap, (gains[o], o))
        return best, region[:best_len]

    def apply(self, region: list[int], D: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
        """Move the region by ``D``; returns what :meth:`undo` needs and the exact change."""
        verts = np.concatenate([self.members[p] for p in region])
        was = self.P[verts]
        self.P[verts] = D @ was
        ks = np.unique(np.concatenate([self.nbrs(p)[0] for p in region]))
        old = self.cc[ks].copy()
        self.cc[ks] = self.costs(ks)
        return verts, was, ks, old, float((self.cc[ks] - old).sum())

    def undo(self, verts: np.ndarray, was: np.ndarray, ks: np.ndarray, old: np.ndarray
             ) -> None:
        self.P[verts] = was
        self.cc[ks] = old

    def chain(self, first: tuple[float, list[int], np.ndarray, int], length: int,
              uphill: float, width: int) -> tuple[float, list[tuple[list[int], np.ndarray]]]:
        """A chain of moves from ``first`` (module docstring); the poses are left unchanged.
        Returns the best prefix's exact change and its moves (empty when no prefix < 0)."""
        hist: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[int],
                         np.ndarray]] = []
        locked: set[int] = set()
        cum, best, best_len = 0.0, 0.0, 0
        move = first
        while True:
            _, region, D, _ = move
            verts, was, ks, old, change = self.apply(region, D)
            hist.append((verts, was, ks, old, region, D))
            cum += change
            locked.update(region)
            if cum < best - 1e-9 * self.c2:
                best, best_len = cum, len(hist)
            if len(hist) >= length:
                break
            nxt = None  # the best move that makes a rejected edge of this region fit
            tried = 0
            for p in region:
                kk, oo = self.nbrs(p)
                for k, o in zip(kk.tolist(), oo.tolist(), strict=True):
                    if o in locked or o == self.a_piece or not self.judged[self.cross[k]] \
                            or self.cc[k] < self.c2 * (1.0 - 1e-12):
                        continue
                    prop = self.propose(k, 0 if self.cb[k] == o else 1, locked)
                    tried += 1
                    if prop is not None and (nxt is None or prop[0] < nxt[0]):
                        nxt = prop
                    if tried >= width:
                        break
                if tried >= width:
                    break
            if nxt is None or nxt[0] > uphill * self.c2 or cum + nxt[0] > 2 * uphill * self.c2:
                break
            move = nxt
        moves = [(h[4], h[5]) for h in hist[:best_len]]
        for h in reversed(hist):
            self.undo(h[0], h[1], h[2], h[3])
        return best, moves


def chain_moves(group: Any, X: LieGroup, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                info: np.ndarray, lab: np.ndarray, judged: np.ndarray, c2: float,
                anchor: int, *, length: int = 6, first: float = 0.3, uphill: float = 1.0,
                tol: float = 0.25, hood: int = 30, width: int = 40, max_scans: int = 5
                ) -> tuple[float, LieGroup, np.ndarray, int]:
    """Chained rigid region moves (Kernighan-Lin style) that lower ``sum min(s, c^2)``.

    A single rigid move of a region (:func:`region_moves`) can be an exact tie: it makes one
    rejected edge fit and breaks one accepted edge, and only a *further* move of another region
    lowers the objective. A chain starts with every move whose change is at most ``first *
    c2`` (ties and improvements), proposed by a rejected inter-piece edge for either of its
    ends' pieces and grown greedily within ``hood`` pieces of it. It applies the move
    tentatively, locks the moved pieces, and continues with the best move that makes a
    rejected edge of the region just moved fit (its other end's region moves; ``width``
    such edges tried), while each step's change is at most ``uphill * c2`` and the running
    sum at most ``2 * uphill * c2``, for at most ``length`` moves. The running change is exact
    (pieces are rigid: only the edges across a moved region change). The best prefix is kept
    when it lowers the objective by more than ``tol * c2``; the chains of a scan are applied in
    turn, each recomputed from its first move at the poses the earlier ones left; scans repeat
    until one keeps nothing (``max_scans`` at most).

    Parameters
    ----------
    group, X, ii, jj, Z, info, lab, judged, c2, anchor
        As :func:`best_region_move`.
    length : int
        Moves in a chain at most, >= 1 (1: single moves).
    first, uphill, tol : float
        In units of ``c2``: the largest change of a chain's first move, of a later move, and
        the least decrease kept.
    hood : int
        Pieces a move's region may be grown from, >= 1 (the nearest by breadth-first order).
    width : int
        Rejected edges tried for the next move of a chain, >= 1.
    max_scans : int
        Scans at most, >= 1.

    Returns
    -------
    gain : float
        The change of ``sum min(s, c^2)`` (<= 0; 0 when nothing kept).
    X : LieGroup
        The poses after the kept chains.
    moved : numpy.ndarray
        ``(n,)`` booleans: the vertices moved.
    chains : int
        Chains kept.

    Raises
    ------
    ValueError
        A group other than SE2/SE3, bad shapes or bad options.

    Examples
    --------
    A line of nine poses, truth ``x_v = (v, 0)``; the pieces ``{0, 1, 2}`` (anchor),
    ``{3, 4, 5}`` and ``{6, 7, 8}``; the second sits 5 m off, held by the wrong edge 0-4, and
    the third 4 m off the other way, held by the wrong edge 0-8, while the good edges 2-3, 5-6
    and 1-7 are rejected. Moving either piece alone is a tie (one good edge in, one wrong
    out); moving the third to 1-7 and then the second to 5-6 (which brings 2-3 in too) lowers
    the objective by one edge:

    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_search import chain_moves, region_moves
    >>> ii = np.array([0, 1, 3, 4, 6, 7, 2, 5, 1, 0, 0])
    >>> jj = np.array([1, 2, 4, 5, 7, 8, 3, 6, 7, 4, 8])
    >>> Z = SE2.from_xy_theta([1.0] * 8 + [6.0, 4.0, 11.0], [0.0] * 9 + [5.0, -4.0], [0.0] * 11)
    >>> X = SE2.from_xy_theta([0.0, 1, 2, 3, 4, 5, 9, 10, 11], [0.0] * 3 + [5.0] * 3 +
    ...                       [-4.0] * 3, [0.0] * 9)
    >>> lab = np.array([0, 0, 0, 1, 1, 1, 2, 2, 2])
    >>> info = np.tile(np.eye(3) * 100.0, (11, 1, 1))
    >>> region_moves(SE2, X, ii, jj, Z, info, lab, np.ones(11, bool), 11.34, 0)
    []
    >>> gain, X2, moved, chains = chain_moves(SE2, X, ii, jj, Z, info, lab,
    ...                                       np.ones(11, bool), 11.34, 0)
    >>> round(gain / 11.34, 6), chains, np.round(X2.translation()[:, 1], 9).tolist()
    (-1.0, 1, [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    """
    if group not in (SE2, SE3):
        raise ValueError(f"chain_moves: group must be SE2 or SE3, got {group!r}")
    for name, val in (("length", length), ("hood", hood), ("width", width),
                      ("max_scans", max_scans)):
        if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < 1:
            raise ValueError(f"chain_moves: {name} must be an integer >= 1, got {val!r}")
    for name, x in (("first", first), ("uphill", uphill), ("tol", tol)):
        if isinstance(x, bool) or not isinstance(x, (float, int)) or not np.isfinite(x) \
                or x < 0:
            raise ValueError(f"chain_moves: {name} must be a finite number >= 0, got {x!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    lab = np.asarray(lab, dtype=np.int64)
    judged = np.asarray(judged, dtype=bool)
    info = np.asarray(info, dtype=np.float64)
    E = ii.size
    P = np.array(X.matrix(), dtype=np.float64)
    n = P.shape[0]
    if jj.shape != (E,) or judged.shape != (E,) or info.shape[0] != E or lab.shape != (n,):
        raise ValueError("chain_moves: ii, jj, judged, info need one entry per edge and lab "
                         "one per vertex")
    P0 = P.copy()
    if not np.any(lab[ii] != lab[jj]):
        return 0.0, X, np.zeros(n, dtype=bool), 0
    pcs = _Pieces(group, P, ii, jj, np.asarray(Z.matrix(), dtype=np.float64), info, lab,
                  judged, c2, anchor, int(hood))
    total, kept = 0.0, 0
    for _ in range(max_scans):
        rej = np.flatnonzero(judged[pcs.cross] & (pcs.cc >= c2 * (1.0 - 1e-12)))
        starts = []
        for k in rej.tolist():
            for side in (0, 1):
                prop = pcs.propose(k, side, set())
                if prop is not None and prop[0] <= first * c2:
                    starts.append((prop[0], k, side))
        starts.sort()
        applied = 0
        for _g, k, side in starts:
            if pcs.cc[k] < c2 * (1.0 - 1e-12):
                continue  # an earlier chain made it fit
            prop = pcs.propose(k, side, set())  # again, at the current poses
            if prop is None or prop[0] > first * c2:
                continue
            gain, moves = pcs.chain(prop, int(length), uphill, int(width))
            if gain < -tol * c2:
                for region, D in moves:
                    pcs.apply(region, D)
                total += gain
                applied += 1
        kept += applied
        if not applied:
            break
    moved = np.any(np.abs(pcs.P - P0) > 0.0, axis=(1, 2))
    return total, group.from_matrix(pcs.P), moved, kept


def search_stage(states: list[np.ndarray], edges: Any, known: list[np.ndarray],
                 user_known: list[np.ndarray], weights: list[np.ndarray], c2: list[float],
                 solve: Callable[[list[np.ndarray]], list[np.ndarray]],
                 objective: Callable[[list[np.ndarray]], float], *, max_moves: int = 200,
                 max_scans: int = 5, tol: float = 0.25, chain: bool = False
                 ) -> tuple[list[np.ndarray], int]:
    """Region moves (:func:`best_region_move`) after GNC, kept when the TLS objective falls.

    The pieces are the components of the ``known`` edges (e.g. the cycle-consistent ones);
    only ``user_known`` edges count as never rejected. Each scan collects every rejected
    edge's best move (:func:`region_moves`) and applies them in order of gain, each only when
    it still lowers the objective at the poses left by the ones before; scans repeat until
    one applies nothing. The edges across the moved regions are then judged again (weight 1
    when ``s < c^2``, else 0; the other weights stay GNC's), the inliers solved, and the
    result kept only when ``objective`` is lower than at ``states`` (else ``states`` and the
    weights are restored).

    Parameters
    ----------
    states : list of numpy.ndarray
        The parameters of the one pose batch (a list of one array).
    edges : PoseGraphEdges
        :func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` of the problem.
    known : list of numpy.ndarray
        Masks per factor batch of the edges trusted inside pieces.
    user_known : list of numpy.ndarray
        Masks per factor batch of the known inliers given by the user.
    weights : list of numpy.ndarray
        GNC's weights per factor batch (0 or 1), updated in place when kept.
    c2 : list of float
        Thresholds per factor batch.
    solve : callable
        ``solve(states) -> states``: the weighted least-squares solve (reads ``weights``).
    objective : callable
        ``objective(states) -> float``: the TLS objective.
    max_moves : int
        Moves at most, >= 1.
    max_scans : int
        Scans of all proposals at most (each applies every move still lowering the objective
        at the poses it finds), >= 1.
    tol : float
        A move must lower ``sum min(s, c^2)`` by more than ``tol * c^2``.
    chain : bool
        After the scans, chained moves (:func:`chain_moves`, its defaults) from the poses they
        left, before the one solve.

    Returns
    -------
    states : list of numpy.ndarray
        The new states (``states`` when nothing was kept).
    moves : int
        Moves and chains kept (0 when none or when the solve did not lower the objective).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_search import search_stage
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(2), fixed=[0])
    >>> _ = g.add(BetweenFactor(x, [0], [1], SE2.identity(1)))
    >>> e = pose_graph_edges(g.problem())
    >>> st = [np.asarray(SE2.identity(2).params)]
    >>> search_stage(st, e, [np.zeros(1, bool)], [np.zeros(1, bool)], [np.ones(1)], [11.34],
    ...              lambda s: s, lambda s: 0.0)[1]  # nothing rejected: no move
    0
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    for name, val in (("max_moves", max_moves), ("max_scans", max_scans)):
        if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < 1:
            raise ValueError(f"search_stage: {name} must be an integer >= 1, got {val!r}")
    if not (isinstance(tol, (float, int)) and np.isfinite(tol) and tol >= 0):
        raise ValueError(f"search_stage: tol must be a finite number >= 0, got {tol!r}")
    if not isinstance(chain, bool):
        raise ValueError(f"search_stage: chain must be True or False, got {chain!r}")
    var = edges.variables
    kn = np.concatenate([known[k] for k, _ in edges.rows])
    uk = np.concatenate([user_known[k] for k, _ in edges.rows])
    c = float(c2[edges.rows[0][0]])
    n, ii, jj = edges.n, edges.ii, edges.jj
    _, lab = connected_components(coo_matrix((np.ones(int(kn.sum())), (ii[kn], jj[kn])),
                                             shape=(n, n)), directed=False)
    X = var.group.from_params(np.asarray(states[0], dtype=np.float64))
    P = np.array(X.matrix(), dtype=np.float64)
    G = edges.group
    Zinv = edges.Z.inverse()
    moves = 0
    touched = np.zeros(ii.size, dtype=bool)  # the edges across the moved regions
    for _ in range(max_scans):
        found = region_moves(G, G.from_matrix(P), ii, jj, edges.Z, edges.info, lab, ~uk, c,
                             edges.anchor)
        applied = 0
        for _gain, region, D in found:
            if moves >= max_moves:
                break
            inR = np.isin(lab, region)
            cut = np.flatnonzero(inR[ii] != inR[jj])
            # the exact change at the current poses (earlier moves may have changed it)
            P2 = P.copy()
            P2[inR] = D @ P[inR]
            now = _costs(G, P, ii[cut], jj[cut], Zinv[cut], edges.info[cut], c, ~uk[cut])
            after = _costs(G, P2, ii[cut], jj[cut], Zinv[cut], edges.info[cut], c, ~uk[cut])
            if float((after - now).sum()) < -tol * c:
                P = P2
                touched[cut] = True
                moves += 1
                applied += 1
        if not applied or moves >= max_moves:
            break
    if chain:
        _, Xc, moved, kept = chain_moves(G, G.from_matrix(P), ii, jj, edges.Z, edges.info, lab,
                                         ~uk, c, edges.anchor, tol=tol)
        if kept:
            Pc = np.array(Xc.matrix(), dtype=np.float64)
            e = np.flatnonzero(moved[ii] | moved[jj])  # the edges whose relative pose changed
            rel0 = np.linalg.inv(P[ii[e]]) @ P[jj[e]]
            rel1 = np.linalg.inv(Pc[ii[e]]) @ Pc[jj[e]]
            touched[e[np.abs(rel1 - rel0).max(axis=(1, 2)) > 1e-9]] = True
            P = Pc
            moves += kept
    if not moves:
        return states, 0
    before = objective(states)
    saved = [w.copy() for w in weights]
    Xn = var.group.from_matrix(P)
    s = _costs(G, P, ii, jj, Zinv, edges.info, c, np.ones(ii.size, dtype=bool))
    for k, sl in edges.rows:  # the edges across the moves judged again; the others as GNC
        redo = touched[sl] & ~user_known[k]
        weights[k][redo] = (s[sl][redo] < c).astype(np.float64)
    Pp = np.array(Xn.params, dtype=np.float64)
    Pp[var.fixed] = np.asarray(states[0], dtype=np.float64)[var.fixed]
    new = solve([Pp] + list(states[1:]))
    if objective(new) < before:
        return new, moves
    for w, sv in zip(weights, saved, strict=True):
        w[:] = sv
    return states, 0
