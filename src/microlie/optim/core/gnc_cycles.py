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
walked backwards contributes ``Z^-1`` with covariance ``Ad(Z) Sigma Ad(Z)^T``). The paths are
those of a breadth-first search from ``i`` that does not use ``e`` (one path per vertex, the
first found, and every last step into ``j``), so a consistent cycle can be missed (the edge is
then simply not marked) but a marked edge has closed a cycle: with random wrong edges a false
mark needs a path whose composition agrees with the wrong measurement within its noise.
:func:`~microlie.optim.core.gnc.gnc_solve` with ``GNC(first="cycles")`` takes the marked edges
as known inliers of the chordal GNC stage (:mod:`microlie.optim.core.gnc_chordal`) and of the
nonlinear GNC after it.

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
                     info: np.ndarray, *, max_length: int = 6, quantile: float = 0.99,
                     max_visits: int = 4000) -> np.ndarray:
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
    max_length : int
        Longest cycle tried, in edges (>= 3).
    quantile : float
        Chi-square quantile of the cycle test, ``0 < quantile < 1``.
    max_visits : int
        Vertices visited at most by the search of one edge (bounds the time on dense
        graphs), >= 1.

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
    if isinstance(max_length, bool) or not isinstance(max_length, (int, np.integer)) or \
            max_length < 3:
        raise ValueError(f"consistent_edges: max_length must be an integer >= 3, got "
                         f"{max_length!r}")
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"consistent_edges: quantile must be strictly between 0 and 1, got "
                         f"{quantile!r}")
    if isinstance(max_visits, bool) or not isinstance(max_visits, (int, np.integer)) or \
            max_visits < 1:
        raise ValueError(f"consistent_edges: max_visits must be an integer >= 1, got "
                         f"{max_visits!r}")
    ii = np.asarray(ii, dtype=np.int64)
    jj = np.asarray(jj, dtype=np.int64)
    E = ii.size
    D = int(info.shape[-1])
    M = np.asarray(Z.matrix(), dtype=np.float64)  # (E, d+1, d+1)
    Minv = np.asarray(Z.inverse().matrix(), dtype=np.float64)
    Ad = np.asarray(Z.adjoint(), dtype=np.float64)  # Ad(Z)
    Adinv = np.asarray(Z.inverse().adjoint(), dtype=np.float64)  # Ad(Z^-1)
    cov = np.linalg.inv(info)
    # walking edge e forwards (i -> j): step Z, covariance Sigma; backwards: Z^-1, Ad(Z) S Ad^T
    step = np.concatenate([M, Minv])
    step_cov = np.concatenate([cov, Ad @ cov @ np.swapaxes(Ad, 1, 2)])
    step_adinv = np.concatenate([Adinv, Ad])  # Ad(step^-1)
    heads = np.concatenate([jj, ii])
    tails = np.concatenate([ii, jj])
    order = np.argsort(tails, kind="stable")
    start = np.searchsorted(tails[order], np.arange(n + 1))
    out_nodes = heads[order].tolist()
    out_steps = order.tolist()
    start_l = start.tolist()
    c2 = float(chi2.ppf(quantile, D))
    # candidate cycles, tested together: (edge, composed pose i -> j, its covariance)
    cand_e: list[int] = []
    cand_T: list[np.ndarray] = []
    cand_S: list[np.ndarray] = []
    eye_T = np.eye(M.shape[-1])
    zero_S = np.zeros((D, D))
    for e in range(E):
        i, j = int(ii[e]), int(jj[e])
        if i == j:
            continue
        T = {i: eye_T}
        S = {i: zero_S}
        front = [i]
        visits = 1
        for length in range(1, max_length):
            nxt = []
            last = length == max_length - 1
            for u in front:
                for k in range(start_l[u], start_l[u + 1]):
                    s = out_steps[k]
                    if s % E == e:
                        continue
                    v = out_nodes[k]
                    if v == j:  # a path into j closes a cycle of length + 1 edges
                        cand_e.append(e)
                        cand_T.append(T[u] @ step[s])
                        A = step_adinv[s]
                        cand_S.append(A @ S[u] @ A.T + step_cov[s])
                        continue
                    if last or v in T or visits >= max_visits:
                        continue
                    A = step_adinv[s]
                    T[v] = T[u] @ step[s]
                    S[v] = A @ S[u] @ A.T + step_cov[s]
                    nxt.append(v)
                    visits += 1
            front = nxt
            if not front:
                break
    ok = np.zeros(E, dtype=bool)
    if not cand_e:
        return ok
    ce = np.asarray(cand_e)
    err = Z[ce].inverse().compose(group.from_matrix(np.stack(cand_T)))  # type: ignore[call-overload]
    r = np.asarray(err.log(), dtype=np.float64)
    Sig = np.stack(cand_S) + cov[ce]
    s2 = np.einsum("ca,ca->c", r, np.linalg.solve(Sig, r[:, :, None])[:, :, 0])
    ok[ce[s2 <= c2]] = True
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
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> from microlie.optim.core.gnc_cycles import mark_consistent
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3), fixed=[0])
    >>> Z = SE2.from_xy_theta([1.0, 1.0, 2.0, 5.0], [0.0, 0.0, 0.0, 5.0], [0.0, 0.0, 0.0, 2.0])
    >>> f = g.add(BetweenFactor(x, [0, 1, 0, 0], [1, 2, 2, 2], Z))
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
