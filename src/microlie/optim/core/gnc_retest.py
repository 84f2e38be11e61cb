"""Each loop closure re-tested after GNC: data snooping with the estimated variance factor.

GNC-TLS judges an edge by its whitened squared residual ``s = r^T Omega r`` at the current
estimate against ``c^2``, the chi-square quantile of its dimension. Two things make that
test miss on real pose graphs (measured on M3500 with the odometry known,
``benchmarks/results/robust-odo-s12.md``):

- the information matrices of the file overstate the noise (on M3500 the a posteriori
  variance factor is 0.025: the inliers' residuals are about 40 times smaller in ``s`` than
  ``Omega`` says), so a wrong closure that bends the graph a little passes: its increase of
  the cost is within ``c^2 / 2``, and TLS prefers it (at 30% seed 2 the answer with one wrong
  closure accepted has a lower TLS objective than the outlier-free optimum);
- an edge between two parts of the graph that are loosely tied has a large ``s`` at an
  estimate that drifted while it was rejected, although accepting it costs almost nothing:
  its residual is within the uncertainty of the prediction ``J P J^T``, which ``s`` ignores.

:func:`retest_edges` gives the statistics of data snooping (Baarda; Pope, "The statistics
of residuals and the detection of outliers", NOAA TR NOS 65, 1976, for the estimated variance
factor): with ``P = H^-1`` the covariance of the inlier solve (``H = sum J^T Omega J`` over
the accepted edges, the anchor held), an accepted edge's standardised residual
``t = r^T (Omega^-1 - J P J^T)^-1 r`` (twice the cost decrease when it is removed, to first
order) and a rejected edge's innovation ``t = r^T (Omega^-1 + J P J^T)^-1 r`` (twice the cost
increase when it is added), and ``v = sum_accepted s / (m - p)``, the a posteriori variance
factor of the accepted edges (``m`` residual rows, ``p`` unknowns).

:func:`retest_stage` keeps GNC's verdict unless the data contradict it, with ``v`` (clipped
to ``[V_MIN, 1]``: it only tightens) as the noise scale:

- an accepted judged edge is rejected when its standardised residual ``t > v b``, ``b`` the
  chi-square bound of the family of the ``m`` accepted judged edges (Bonferroni: the
  quantile ``1 - (1 - q) / m`` for the per-edge quantile ``q``). Only the edges with
  ``s > v c^2`` are tested (``t >= s``; the others keep their verdict: the covariance
  solves are the cost of the pass);
- a rejected judged edge is accepted when its innovation ``t <= v c^2``.

GNC then solves the inliers again (from their chordal relaxation, :func:`inlier_start`) and
repeats with the same ``v`` until nothing flips. Nothing is tested when the accepted edges do
not connect every vertex. The cost is one sparse factorisation and a solve per tested edge
and dimension (``P J^T``, in blocks of right-hand sides). A cheap lower bound of the
innovations, ``s / (1 + l (|L^T J_i|^2 + |L^T J_j|^2))`` with ``l`` the largest eigenvalue of
``P``, screened out none of the 1715 rejected edges of sphere2500 at 70% (``l`` is the loosest
global mode), so every rejected edge is solved for.

Examples
--------
>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.core.gnc_retest import retest_edges
>>> # a square 0-1-2-3 with both diagonals: the diagonal 0-2 is wrong by 0.3 m
>>> ii, jj = np.array([0, 1, 2, 3, 0, 1]), np.array([1, 2, 3, 0, 2, 3])
>>> Z = SE2.from_xy_theta([1.0, 0.0, -1.0, 0.0, 1.3, -1.0], [0.0, 1.0, 0.0, -1.0, 1.0, 1.0],
...                       [0.0] * 6)
>>> X = SE2.from_xy_theta([0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 1.0, 1.0], [0.0] * 4)
>>> s, t, v = retest_edges(SE2, X, ii, jj, Z, np.tile(np.eye(3), (6, 1, 1)),
...                        np.ones(6, bool), np.ones(6, bool), 0)
>>> int(np.argmax(t)), v <= 1.0
(4, True)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...groups import LieGroup
from ..linalg.base import SingularSystemError

__all__ = ["retest_edges", "retest_stage"]

# an accepted edge whose smallest local redundancy number is below this is not tested (no
# other edge checks it: a bridge, or nearly one)
_UNCHECKED = 1e-6
# the variance factor is used to tighten the threshold down to this fraction at most (noise
# -free data would otherwise give a threshold of rounding size)
V_MIN = 1e-4


def _jacobians(X: LieGroup, ii: np.ndarray, jj: np.ndarray, Z: LieGroup
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``r = Log(Z^-1 X_i^-1 X_j)`` and its right Jacobians in ``X_i`` and ``X_j``."""
    rel, Ai, Aj = X[ii].between(X[jj], jac=True)
    r, Jr, _ = rel.minus(Z, jac=True)
    Jr = np.asarray(Jr, dtype=np.float64)
    return (np.asarray(r, dtype=np.float64), Jr @ np.asarray(Ai, dtype=np.float64),
            Jr @ np.asarray(Aj, dtype=np.float64))


def _connected(edges: Any, w: np.ndarray) -> bool:
    """Whether the edges ``w`` connect every vertex."""
    import scipy.sparse as sp  # type: ignore[import-untyped]
    from scipy.sparse.csgraph import connected_components  # type: ignore[import-untyped]

    A = sp.coo_matrix((np.ones(int(w.sum())), (edges.ii[w], edges.jj[w])),
                      shape=(edges.n, edges.n))
    return bool(connected_components(A, directed=False)[0] == 1)


def retest_edges(group: Any, X: LieGroup, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                 info: np.ndarray, accepted: np.ndarray, judged: np.ndarray, anchor: int, *,
                 chunk: int = 100) -> tuple[np.ndarray, np.ndarray, float]:
    """Data-snooping statistics of the judged edges of a pose graph (module docstring).

    Parameters
    ----------
    group : type
        SE2 or SE3.
    X : LieGroup
        ``(n,)`` the poses (the least-squares solve of the accepted edges).
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges ``X_i^-1 X_j = Z``.
    Z : LieGroup
        ``(E,)`` measurements.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices.
    accepted : numpy.ndarray
        ``(E,)`` booleans: the edges in the solve (known inliers included).
    judged : numpy.ndarray
        ``(E,)`` booleans: the edges to test (others get ``t = 0``).
    anchor : int
        The vertex held (the gauge).
    chunk : int
        Edges per block of right-hand sides of the covariance solves (memory
        ``n D * chunk D`` doubles).
    Returns
    -------
    s : numpy.ndarray
        ``(E,)``: the whitened squared residuals ``r^T Omega r`` (``s <= t`` for an accepted
        edge, ``s >= t`` for a rejected one).
    t : numpy.ndarray
        ``(E,)``: the standardised residual of each judged accepted edge (``nan`` for an edge
        no other edge checks), the innovation of each judged rejected edge, in units of
        ``Omega`` (compare with ``v c^2``); 0 for the edges not judged.
    v : float
        The a posteriori variance factor of the accepted edges (``nan`` when they have no
        redundancy).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim.core.gnc_retest import retest_edges
    >>> # a triangle; edge 2 rejected: its innovation against the path 0-1-2
    >>> ii, jj = np.array([0, 1, 0]), np.array([1, 2, 2])
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 3.0], [0.0] * 3, [0.0] * 3)
    >>> X = SE2.from_xy_theta([0.0, 1.0, 2.0], [0.0] * 3, [0.0] * 3)
    >>> s, t, v = retest_edges(SE2, X, ii, jj, Z, np.tile(np.eye(3), (3, 1, 1)),
    ...                        np.array([True, True, False]), np.array([False, False, True]), 0)
    >>> round(float(t[2]), 9)  # 1 m off, prediction variance 2 + measurement 1
    0.333333333
    """
    import scipy.sparse as sp  # type: ignore[import-untyped]

    from ..linalg.linear import make_solver

    n, E, D = len(X), ii.size, info.shape[1]
    r, Ji, Jj = _jacobians(X, ii, jj, Z)
    s = np.einsum("ea,eab,eb->e", r, info, r)
    a = np.flatnonzero(accepted)
    red = a.size * D - (n - 1) * D
    v = float(s[a].sum() / red) if red > 0 else float("nan")
    # H = sum over the accepted edges of J^T Omega J, the anchor's block removed
    keep = np.ones(n, dtype=bool)
    keep[anchor] = False
    col = np.full(n, -1, dtype=np.int64)
    col[keep] = np.arange(n - 1)
    N = (n - 1) * D
    k = np.arange(D)
    rows_l, cols_l, vals_l = [], [], []
    for p, Jp in ((ii, Ji), (jj, Jj)):
        for q, Jq in ((ii, Ji), (jj, Jj)):
            ok = a[(col[p[a]] >= 0) & (col[q[a]] >= 0)]
            B = np.einsum("eba,ebc,ecd->ead", Jp[ok], info[ok], Jq[ok])
            R = col[p[ok]][:, None, None] * D + k[None, :, None]
            C = col[q[ok]][:, None, None] * D + k[None, None, :]
            rows_l.append(np.broadcast_to(R, B.shape).ravel())
            cols_l.append(np.broadcast_to(C, B.shape).ravel())
            vals_l.append(B.ravel())
    H = sp.coo_matrix((np.concatenate(vals_l), (np.concatenate(rows_l),
                                                np.concatenate(cols_l))), shape=(N, N)).tocsc()
    H.sum_duplicates()
    H.sort_indices()
    solver = make_solver("auto", N, D)
    solver.analyse(H.indptr, H.indices, N, D)
    solver.factorize(H.data)
    L = np.linalg.cholesky(info)  # Omega = L L^T: whitened covariances
    test = np.flatnonzero(judged)
    t = np.zeros(E)
    # J P J^T per judged edge: P J^T from one block of right-hand sides per chunk of edges
    S = np.zeros((E, D, D))
    ends = ((ii, Ji), (jj, Jj))
    for c0 in range(0, test.size, chunk):
        e = test[c0:c0 + chunk]
        m = e.size
        rhs = np.zeros((N, m * D))
        cols = (np.arange(m) * D)[:, None] + k[None, :]  # (m, D): this edge's columns
        for p, Jp in ends:
            cp = col[p[e]]
            ok = cp >= 0
            R = cp[ok][:, None] * D + k[None, :]  # (m', D): rows of the vertex's unknowns
            # rhs[row a of vertex, column b of edge] = J[b, a]
            rhs[R[:, :, None], cols[ok][:, None, :]] += np.swapaxes(Jp[e[ok]], 1, 2)
        Y = solver.solve(rhs)
        for p, Jp in ends:
            cp = col[p[e]]
            ok = cp >= 0
            R = cp[ok][:, None] * D + k[None, :]
            G = Y[R[:, :, None], cols[ok][:, None, :]]  # (m', D, D): rows of P J^T
            S[e[ok]] += np.einsum("eab,ebc->eac", Jp[e[ok]], G)
    sign = np.where(accepted, -1.0, 1.0)[test]
    Lt = L[test]
    W = np.eye(D) + sign[:, None, None] * (np.swapaxes(Lt, 1, 2) @ S[test] @ Lt)
    u = np.einsum("eba,eb->ea", Lt, r[test])  # L^T r
    lam = np.linalg.eigvalsh(W)
    good = lam[:, 0] > _UNCHECKED
    tt = np.full(test.size, np.nan)
    tt[good] = np.einsum("ea,ea->e", u[good], np.linalg.solve(W[good], u[good][:, :, None])[
        :, :, 0])
    t[test] = tt
    return s, t, v


def retest_stage(states: list[np.ndarray], edges: Any, known: list[np.ndarray],
                 weights: list[np.ndarray], c2: list[float], v: float | None = None
                 ) -> tuple[int, float]:
    """:func:`retest_edges` on a problem's pose graph after GNC: flip the judged edges whose
    verdict changes (the BetweenFactor weights updated in place).

    Parameters
    ----------
    states : list of numpy.ndarray
        The parameters of the one pose batch (a list of one array): the inlier solve.
    edges : PoseGraphEdges
        :func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` of the problem.
    known : list of numpy.ndarray
        Known-inlier masks per factor batch (never tested).
    weights : list of numpy.ndarray
        GNC's weights per factor batch (0 or 1), updated in place.
    c2 : list of float
        Thresholds per factor batch.
    v : float, optional
        The variance factor to use (the first pass's, so that later passes test against the
        same threshold); default: estimated here.

    Returns
    -------
    flipped : int
        How many edges changed verdict.
    v : float
        The variance factor used, clipped to ``[V_MIN, 1]`` (1 when it cannot be estimated).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_retest import retest_stage
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(2), fixed=[0])
    >>> _ = g.add(BetweenFactor(x, [0, 0], [1, 1], SE2.identity(2)))
    >>> e = pose_graph_edges(g.problem())
    >>> w = [np.array([1.0, 0.0])]  # the second, exact, copy was rejected
    >>> retest_stage([np.asarray(SE2.identity(2).params)], e, [np.zeros(2, bool)], w, [11.34])
    (1, 1.0)
    >>> w[0].tolist()
    [1.0, 1.0]
    """
    from scipy.stats import chi2  # type: ignore[import-untyped]

    kn = np.concatenate([known[k] for k, _ in edges.rows])
    w = np.concatenate([weights[k] for k, _ in edges.rows])
    cc = np.concatenate([np.full(sl.stop - sl.start, c2[k]) for k, sl in edges.rows])
    judged = ~kn
    if not judged.any():
        return 0, 1.0 if v is None else v
    X = edges.group.from_params(np.asarray(states[0], dtype=np.float64))
    acc = w >= 0.5
    if not _connected(edges, acc):  # no covariance across the pieces: nothing to test
        return 0, 1.0 if v is None else v
    r, _, _ = _jacobians(X, edges.ii, edges.jj, edges.Z)
    s = np.einsum("ea,eab,eb->e", r, edges.info, r)
    if v is None:
        red = int(acc.sum()) * edges.info.shape[1] - (edges.n - 1) * edges.info.shape[1]
        v_hat = float(s[acc].sum() / red) if red > 0 else float("nan")
        v = min(1.0, max(V_MIN, v_hat)) if np.isfinite(v_hat) else 1.0
    # removal candidates: accepted edges beyond their own quantile (t >= s)
    cand = judged & acc & (s > v * cc)
    rejected = judged & ~acc
    try:
        _, t, _ = retest_edges(edges.group, X, edges.ii, edges.jj, edges.Z, edges.info, acc,
                               rejected | cand, edges.anchor)
    except SingularSystemError:  # the accepted edges leave a direction free
        return 0, v
    m = int((judged & acc).sum())
    D = edges.info.shape[1]
    q = 1.0 - chi2.sf(cc, D)  # each edge's quantile, from its threshold
    bound = chi2.ppf(1.0 - (1.0 - q) / max(m, 1), D)
    drop = cand & np.isfinite(t) & (t > v * bound)
    add = rejected & (t <= v * cc)
    flip = drop | add
    if flip.any():
        w2 = np.where(drop, 0.0, np.where(add, 1.0, w))
        for k, sl in edges.rows:
            weights[k][:] = w2[sl]
    return int(flip.sum()), v


def inlier_start(states: list[np.ndarray], edges: Any, weights: list[np.ndarray]
                 ) -> list[np.ndarray]:
    """The chordal relaxation of the accepted edges: where the inlier solve restarts after
    :func:`retest_stage` flipped edges (the estimate that held a wrong edge is bent by it;
    on flat graphs such as M3500 with 70% of its closures rejected, least squares from there
    stops within its tolerance centimetres from the optimum that the chordal start reaches).

    Parameters
    ----------
    states : list of numpy.ndarray
        The parameters of the one pose batch (a list of one array); the anchor and the fixed
        vertices keep theirs.
    edges : PoseGraphEdges
        :func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` of the problem.
    weights : list of numpy.ndarray
        GNC's weights per factor batch (0 or 1): the edges with weight 1 are used.

    Returns
    -------
    list of numpy.ndarray
        The relaxation's poses, or ``states`` unchanged when the accepted edges do not
        connect every vertex.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_retest import inlier_start
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(2), fixed=[0])
    >>> _ = g.add(BetweenFactor(x, [0, 0], [1, 1], SE2.from_xy_theta([1.0, 5.0], [0.0] * 2,
    ...                                                             [0.0] * 2)))
    >>> e = pose_graph_edges(g.problem())
    >>> P = inlier_start([np.asarray(SE2.identity(2).params)], e, [np.array([1.0, 0.0])])
    >>> np.round(SE2.from_params(P[0]).translation(), 9).tolist()  # the second edge ignored
    [[0.0, 0.0], [1.0, 0.0]]
    """
    from .gnc_chordal import chordal_gnc

    w = np.concatenate([weights[k] for k, _ in edges.rows]) >= 0.5
    if not _connected(edges, w):
        return [np.asarray(states[0], dtype=np.float64)]  # no relaxation of every vertex
    var = edges.variables
    P0 = np.asarray(states[0], dtype=np.float64)
    X0 = var.group.from_params(P0[edges.anchor])
    X, _, _ = chordal_gnc(edges.group, edges.n, edges.ii[w], edges.jj[w], edges.Z[w],
                          edges.info[w], edges.anchor, X0, np.ones(int(w.sum()), dtype=bool))
    P = np.array(X.params, dtype=np.float64)
    held = np.asarray(var.fixed, dtype=bool)
    P[held] = P0[held]
    return [P]
