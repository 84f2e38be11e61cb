"""Cycle consistency on pose graphs: edges that close a short cycle within its noise.

Without known inliers GNC on a pose graph with many wrong loop closures starts from an estimate
bent by all of them and can reject good edges early (measured on M3500 with random wrong loop
closures: 38-47 m from the outlier-free optimum). A wrong edge, however, almost never closes a
short cycle of the graph consistently: the measurements around a cycle compose to the identity
only up to their noise, and a random measurement does not. :func:`consistent_edges` marks every
edge ``e = (i, j)`` that lies on a cycle of at most ``max_length`` edges whose other edges
compose, from ``i`` to ``j``, to a pose ``T`` with

``r = Log(Z_e^-1 T)``, ``r^T (Sigma_path + Sigma_e)^-1 r <= chi2.ppf(quantile, dof)``,

``Sigma_path`` the first-order covariance of the composed path (right perturbations: along a
path ``T_v = T_u Z_uv``, ``Sigma_v = Ad(Z_uv^-1) Sigma_u Ad(Z_uv^-1)^T + Sigma_uv``; an edge
walked backwards contributes ``Z^-1`` with covariance ``Ad(Z) Sigma Ad(Z)^T``). Every path
from ``i`` to ``j`` of up to four steps that walks no edge twice and not ``e`` is tried (two
half-paths of one or two steps joined at a common vertex; cycles of 3-5 edges), vectorised
in chunks of edges. A marked edge has closed a cycle: with random wrong edges a false mark
needs a path whose composition agrees with the wrong measurement within its noise; an edge on
no short cycle (a long chain, or cycles broken by wrong edges) is simply not marked.
:func:`~microlie.optim.core.gnc.gnc_solve` with ``GNC(first="cycles")`` takes the marked edges
as known inliers of the chordal GNC stage (:mod:`microlie.optim.core.gnc_chordal`) and of the
nonlinear GNC after it. Measured in ``benchmarks/results/robust-s11.md`` (0 wrong edges marked
on M3500 and sphere2500 with 30% random loop closures; about half of M3500's inliers and 79%
of sphere2500's marked).

Examples
--------
>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.core.gnc_cycles import consistent_edges
>>> Z = SE2.from_xy_theta([1.0, 1.0, 2.0, 5.0], [0.0, 0.0, 0.0, 5.0], [0.0, 0.0, 0.0, 2.0])
>>> consistent_edges(SE2, 3, np.array([0, 1, 0, 0]), np.array([1, 2, 2, 2]), Z,
...                  np.tile(np.eye(3) * 100.0, (4, 1, 1))).tolist()  # the last edge is wrong
[True, True, True, False]
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...groups import SE2, SE3, LieGroup

__all__ = ["consistent_edges", "mark_consistent"]


def consistent_edges(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                     info: np.ndarray, *, max_length: int = 5, quantile: float = 0.99,
                     chunk: int = 256) -> np.ndarray:
    """Edges that lie on a short cycle that closes within its noise (module docstring).

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
    max_length : {3, 4, 5}
        Longest cycle tried, in edges.
    quantile : float
        Chi-square quantile of the cycle test, ``0 < quantile < 1``.
    chunk : int
        Edges tested together (bounds the memory), >= 1.

    Returns
    -------
    numpy.ndarray
        ``(E,)`` booleans: True for an edge on a consistent cycle.

    Raises
    ------
    ValueError
        A group other than SE2/SE3, or an option out of range.

    Examples
    --------
    See the module docstring.
    """
    from scipy.stats import chi2  # type: ignore[import-untyped]

    if group not in (SE2, SE3):
        raise ValueError(f"consistent_edges: group must be SE2 or SE3, got {group!r}")
    if max_length not in (3, 4, 5) or isinstance(max_length, bool):
        raise ValueError(f"consistent_edges: max_length must be 3, 4 or 5, got {max_length!r}")
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"consistent_edges: quantile must be strictly between 0 and 1, got "
                         f"{quantile!r}")
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValueError(f"consistent_edges: chunk must be an integer >= 1, got {chunk!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    E = ii.size
    cov = np.linalg.inv(info)
    # directed steps: s < E walks edge s forwards (Z, Sigma), s >= E backwards (Z^-1,
    # Ad(Z) Sigma Ad(Z)^T); Ad(step^-1) transports a path's covariance past the step
    M = np.asarray(Z.matrix(), dtype=np.float64)
    Ad = np.asarray(Z.adjoint(), dtype=np.float64)
    Adinv = np.asarray(Z.inverse().adjoint(), dtype=np.float64)
    tail, head = np.concatenate([ii, jj]), np.concatenate([jj, ii])
    edge = np.concatenate([np.arange(E), np.arange(E)])
    T1 = np.concatenate([M, np.asarray(Z.inverse().matrix(), dtype=np.float64)])
    S1 = np.concatenate([cov, Ad @ cov @ np.swapaxes(Ad, 1, 2)])
    A1 = np.concatenate([Adinv, Ad])
    # two-step paths a -> v -> b (b != a, two different edges)
    order = np.argsort(tail, kind="stable")
    first = np.searchsorted(tail[order], np.arange(n + 1))
    cnt = first[head + 1] - first[head]
    p1 = np.repeat(np.arange(2 * E), cnt)
    p2 = order[np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt) +
               np.repeat(first[head], cnt)]
    keep = (edge[p1] != edge[p2]) & (head[p2] != tail[p1])
    if max_length == 3:  # triangles: one-step half-paths only
        keep[:] = False
    p1, p2 = p1[keep], p2[keep]
    # half-paths: one or two steps; first edge, last edge, pose, covariance, Ad(pose^-1)
    h_tail = np.concatenate([tail, tail[p1]])
    h_head = np.concatenate([head, head[p2]])
    h_len = np.concatenate([np.ones(2 * E, np.int64), np.full(p1.size, 2)])
    h_e1 = np.concatenate([edge, edge[p1]])
    h_e2 = np.concatenate([edge, edge[p2]])
    h_T = np.concatenate([T1, T1[p1] @ T1[p2]])
    h_S = np.concatenate([S1, A1[p2] @ S1[p1] @ np.swapaxes(A1[p2], 1, 2) + S1[p2]])
    h_A = np.concatenate([A1, A1[p2] @ A1[p1]])
    by_tail = np.argsort(h_tail, kind="stable")
    t_first = np.searchsorted(h_tail[by_tail], np.arange(n + 1))
    key = h_tail * n + h_head
    by_key = np.argsort(key, kind="stable")
    skey = key[by_key]
    c2 = float(chi2.ppf(quantile, info.shape[-1]))
    ok = np.zeros(E, dtype=bool)
    for lo in range(0, E, chunk):
        es = np.arange(lo, min(E, lo + chunk))
        # A: half-paths from i; B: half-paths from A's end to j
        na = t_first[ii[es] + 1] - t_first[ii[es]]
        ea = np.repeat(es, na)
        a = by_tail[np.arange(na.sum()) - np.repeat(np.cumsum(na) - na, na) +
                    np.repeat(t_first[ii[es]], na)]
        use = (h_e1[a] != ea) & (h_e2[a] != ea) & (h_head[a] != jj[ea])
        ea, a = ea[use], a[use]
        q = h_head[a] * n + jj[ea]
        b_lo = np.searchsorted(skey, q, "left")
        nb = np.searchsorted(skey, q, "right") - b_lo
        ec = np.repeat(ea, nb)
        ac = np.repeat(a, nb)
        bc = by_key[np.arange(nb.sum()) - np.repeat(np.cumsum(nb) - nb, nb) +
                    np.repeat(b_lo, nb)]
        use = (h_len[ac] >= h_len[bc]) & (h_len[ac] + h_len[bc] < max_length) & \
            (h_e1[bc] != ec) & (h_e2[bc] != ec) & (h_e1[bc] != h_e2[ac]) & \
            (h_e2[bc] != h_e1[ac]) & (h_e2[bc] != h_e2[ac])  # no edge walked twice
        ec, ac, bc = ec[use], ac[use], bc[use]
        if not ec.size:
            continue
        T = h_T[ac] @ h_T[bc]
        S = h_A[bc] @ h_S[ac] @ np.swapaxes(h_A[bc], 1, 2) + h_S[bc] + cov[ec]
        r = np.asarray(Z[ec].inverse().compose(group.from_matrix(T)).log(),  # type: ignore[call-overload]
                       dtype=np.float64)
        s2 = np.einsum("ca,ca->c", r, np.linalg.solve(S, r[:, :, None])[:, :, 0])
        ok[ec[s2 <= c2]] = True
    return ok


def mark_consistent(edges: Any, known: list[np.ndarray], quantile: float) -> list[np.ndarray]:
    """The known-inlier masks with every edge of :func:`consistent_edges` added.

    Parameters
    ----------
    edges : PoseGraphEdges
        The problem's edges (:func:`~microlie.optim.core.gnc_chordal.pose_graph_edges`).
    known : list of numpy.ndarray
        ``(count,)`` booleans per factor batch (graph order); not modified.
    quantile : float
        Chi-square quantile of the cycle test.

    Returns
    -------
    list of numpy.ndarray
        New masks: ``known`` or, on the BetweenFactor rows, on a consistent cycle.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor, Isotropic
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_cycles import mark_consistent
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3), fixed=[0])
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 2.0, 5.0], [0.0, 0.0, 0.0, 5.0], [0.0, 0.0, 0.0, 2.0])
    >>> f = g.add(BetweenFactor(x, [0, 1, 0, 0], [1, 2, 2, 2], Z, Isotropic(3, 0.1)))
    >>> [m.tolist() for m in mark_consistent(pose_graph_edges(g.problem()),
    ...                                      [np.zeros(4, bool)], 0.99)]
    [[True, True, True, False]]
    """
    ok = consistent_edges(edges.group, edges.n, edges.ii, edges.jj, edges.Z, edges.info,
                          quantile=quantile)
    out = [np.array(k, dtype=bool) for k in known]
    for k, sl in edges.rows:
        out[k] |= ok[sl]
    return out
