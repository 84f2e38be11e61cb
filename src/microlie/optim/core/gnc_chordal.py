"""The first stage of GNC on pose graphs: graduated non-convexity on the chordal relaxation.

GNC needs an inner solver that finds the global optimum of each weighted problem (Yang et
al., RA-L 2020). Local least squares on a pose graph with many wrong loop closures does not:
while ``mu`` is small its weighted estimates bend towards the outliers, and the weights then
follow the bent estimate (measured on M3500: 12-47 m from the outlier-free optimum). Here
each weighted problem is solved by the chordal relaxation (:func:`microlie.optim.init.chordal`
with the GNC weights): rotations by weighted linear least squares on the entries of the
rotation matrices (the anchor's held, each edge's weight times its rotation precision,
``rho / trace(Sigma_R)``), projected to SO(n) by SVD; then translations by weighted linear
least squares with those rotations held (whitened by the marginal translation information).
Both are one sparse Cholesky factorisation on a pattern analysed once; no start is needed,
so no start can be bent. Each outer iteration judges every edge on the whitened squared
residual of the nonlinear factor, ``s = r^T Omega r`` with ``r = Log(Z^-1 X_i^-1 X_j)``,
against ``c^2 = chi2.ppf(quantile, dof)``, with the closed-form TLS weights; ``mu`` starts by
the paper's Remark 5 at the unweighted relaxation, grows by ``mu_step`` per outer iteration,
and the stage stops when every weight is within ``weights_tol`` of 0 or 1.
:func:`~microlie.optim.core.gnc.gnc_solve` then solves least squares on the inliers found here
and continues GNC-TLS on the nonlinear problem from that estimate at the last ``mu``
(``GNC(first="chordal")``, what ``first="auto"`` picks for pose graphs). Known inliers keep
weight 1.

Examples
--------
>>> import numpy as np
>>> from microlie import SE2
>>> from microlie.optim.core.gnc_chordal import chordal_gnc
>>> Z = SE2.from_xy_theta([1.0, 1.0, 2.0, 5.0], [0.0, 0.0, 0.0, 5.0], [0.0, 0.0, 0.0, 2.0])
>>> X, w, _ = chordal_gnc(SE2, 3, np.array([0, 1, 0, 0]), np.array([1, 2, 2, 2]), Z,
...                       np.tile(np.eye(3) * 100.0, (4, 1, 1)), 0, SE2.identity(),
...                       np.array([True, True, False, False]))
>>> np.round(X.translation(), 6).tolist(), w.tolist()  # the last edge is wrong
([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], [1.0, 1.0, 1.0, 0.0])
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...groups import SE2, SE3, SO2, SO3, LieGroup
from .factors import BetweenFactor, PriorFactor
from .gnc_weights import initial_mu, tls_weights
from .problem import Problem

__all__ = ["chordal_gnc", "pose_graph_edges", "PoseGraphEdges"]

# a weight-0 edge keeps this fraction of its weight in the linear solves, so that a vertex
# whose every edge is judged an outlier keeps a defined (if meaningless) estimate
_FLOOR = 1e-9


class PoseGraphEdges:
    """The edges of a problem that is a pose graph, for :func:`chordal_gnc`.

    Attributes
    ----------
    group : type
        SE2 or SE3.
    variables : Variables
        The one pose batch.
    n : int
        Its size.
    ii, jj : numpy.ndarray
        ``(E,)`` vertex indices of the edges (every BetweenFactor row, in factor order).
    Z : LieGroup
        ``(E,)`` measurements.
    info : numpy.ndarray
        ``(E, D, D)`` information matrices.
    rows : list of tuple
        ``(factor index, slice of the E edges)`` per BetweenFactor batch.
    anchor : int
        The vertex held: the first fixed one, else the first with a prior.
    """

    def __init__(self, group: Any, variables: Any, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                 info: np.ndarray, rows: list[tuple[int, slice]], anchor: int) -> None:
        self.group, self.variables, self.n = group, variables, int(variables.n)
        self.ii, self.jj, self.Z, self.info = ii, jj, Z, info
        self.rows, self.anchor = rows, anchor


def pose_graph_edges(problem: Problem) -> PoseGraphEdges | None:
    """The problem's edges when it is a pose graph: one SE2 or SE3 variable batch, only
    BetweenFactor and PriorFactor batches on it, a fixed vertex or a prior; else ``None``.

    Parameters
    ----------
    problem : Problem
        The problem.

    Returns
    -------
    PoseGraphEdges or None

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.gnc_chordal import pose_graph_edges
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3), fixed=[0])
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.identity(2)))
    >>> e = pose_graph_edges(g.problem())
    >>> e.ii.tolist(), e.jj.tolist(), e.anchor
    ([0, 1], [1, 2], 0)
    """
    if len(problem.variables) != 1:
        return None
    var = problem.variables[0]
    if var.group not in (SE2, SE3):
        return None
    ii, jj, Zs, infos, rows = [], [], [], [], []
    anchor = int(np.flatnonzero(var.fixed)[0]) if var.fixed.any() else -1
    for var_g, k in problem.gauge_fixed:
        if var_g is var and anchor < 0:
            anchor = int(k)
    start = 0
    for k, f in enumerate(problem.factors):
        if isinstance(f, PriorFactor):
            if anchor < 0:
                anchor = int(f.args[0][1][0])
            continue
        if not isinstance(f, BetweenFactor):
            return None
        ii.append(np.asarray(f.args[0][1], dtype=np.int64))
        jj.append(np.asarray(f.args[1][1], dtype=np.int64))
        Zs.append(np.asarray(var.params_of(f.Z), dtype=np.float64).reshape(f.count, -1))
        infos.append(np.broadcast_to(f.noise.information, (f.count, f.dim, f.dim)))
        rows.append((k, slice(start, start + f.count)))
        start += f.count
    if anchor < 0 or not ii:
        return None
    return PoseGraphEdges(var.group, var, np.concatenate(ii), np.concatenate(jj),
                          var.group.from_params(np.concatenate(Zs)), np.concatenate(infos),
                          rows, anchor)


class _WeightedLS:
    """``min_x sum_e w_e |Ai_e x_ii[e] + Aj_e x_jj[e] - rhs_e|^2`` over the vertices but the
    anchor, held at ``fixed``; blocks of ``p`` unknowns, ``rhs`` with ``k`` columns. The
    normal equations are gathered into one analysed pattern (one symbolic analysis for all
    the weighted solves)."""

    def __init__(self, ii: np.ndarray, jj: np.ndarray, Ai: np.ndarray, Aj: np.ndarray,
                 rhs: np.ndarray, n: int, anchor: int, fixed: np.ndarray) -> None:
        from ..linalg.linear import make_solver

        E, m, p = Ai.shape
        pos = np.arange(n) - (np.arange(n) > anchor)
        pos[anchor] = -1
        cols = np.concatenate([pos[ii, None] * p + np.arange(p), pos[jj, None] * p +
                               np.arange(p)], axis=1)  # (E, 2p), < 0 on the anchor
        cols[np.concatenate([np.repeat(ii[:, None] == anchor, p, 1),
                             np.repeat(jj[:, None] == anchor, p, 1)], axis=1)] = -1
        free = cols >= 0
        self.fixed = fixed
        self.cols, self.free = cols, free
        self.set_blocks(Ai, Aj, rhs)
        N = (n - 1) * p
        rr = np.broadcast_to(cols[:, :, None], self.G.shape)
        cc = np.broadcast_to(cols[:, None, :], self.G.shape)
        ok = (rr >= 0) & (cc >= 0)
        keys = (cc * N + rr)[ok]
        uniq, inv = np.unique(keys, return_inverse=True)
        self.ok, self.inv, self.nnz = ok, inv, uniq.size
        self.indices = (uniq % N).astype(np.int64)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(uniq // N, minlength=N))])
        self.N = N
        self.ls = make_solver("dense" if N < 300 else "cholesky", N)
        self.ls.analyse(self.indptr, self.indices, N, block_size=p)

    def set_blocks(self, Ai: np.ndarray, Aj: np.ndarray, rhs: np.ndarray) -> None:
        """New coefficient blocks and right-hand sides on the same edges (same pattern)."""
        A = np.concatenate([Ai, Aj], axis=2)
        Afix = np.where(self.free[:, None, :], 0.0, A)  # the anchor's part moves to the rhs
        fix_val = np.concatenate([self.fixed, self.fixed], axis=0)  # (2p, k): either end
        self.r = rhs - Afix @ fix_val
        self.A = np.where(self.free[:, None, :], A, 0.0)
        self.G = np.swapaxes(self.A, 1, 2) @ self.A  # (E, 2p, 2p)

    def __call__(self, w: np.ndarray) -> np.ndarray:
        w = np.maximum(w, _FLOOR * max(float(w.max()), 1.0))
        data = np.bincount(self.inv, (w[:, None, None] * self.G)[self.ok], minlength=self.nnz)
        self.ls.factorize(data)
        g = w[:, None, None] * (np.swapaxes(self.A, 1, 2) @ self.r)  # (E, 2p, k)
        k = self.r.shape[-1]
        b = np.zeros((self.N, k))
        for c in range(k):
            b[:, c] = np.bincount(self.cols[self.free], g[..., c][self.free], minlength=self.N)
        return np.asarray(self.ls.solve(b)).reshape(self.N, k)


def _graduate(solve_fn: Any, resid_fn: Any, w: np.ndarray, judged: np.ndarray, c2: float,
              mu_step: float, max_iter: int, weights_tol: float) -> tuple[Any, float, int]:
    """GNC-TLS with a linear inner solve: ``solve_fn(w)`` gives an estimate, ``resid_fn`` its
    squared residuals; ``w`` (updated in place) holds the fixed weights of the rows not judged.
    Returns the last estimate, the last ``mu`` and the outer iterations."""
    est = solve_fn(w)
    s = resid_fn(est)
    mu = initial_mu("tls", s[judged], np.full(int(judged.sum()), c2)) if judged.any() else None
    if mu is None:
        return est, 1.0, 0
    it = 0
    while it < max_iter:
        it += 1
        w[judged] = tls_weights(s[judged], c2, mu)
        est = solve_fn(w)
        s = resid_fn(est)
        wj = w[judged]
        if np.all(np.abs(wj - np.round(wj)) <= weights_tol):
            break
        mu *= mu_step
    w[judged] = np.round(w[judged])
    return est, mu, it


def chordal_gnc(group: Any, n: int, ii: np.ndarray, jj: np.ndarray, Z: LieGroup,
                info: np.ndarray, anchor: int, anchor_pose: LieGroup, known: np.ndarray, *,
                quantile: float = 0.99, mu_step: float = 1.4, max_iter: int = 100,
                weights_tol: float = 1e-4, rejected: np.ndarray | None = None
                ) -> tuple[LieGroup, np.ndarray, float]:
    """GNC-TLS with the chordal relaxation as the inner solver (see the module docstring).

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
        ``(E, D, D)`` information matrices (tangent order: translation, then rotation).
    anchor : int
        The vertex held at ``anchor_pose``.
    anchor_pose : LieGroup
        Its pose (one element).
    known : numpy.ndarray
        ``(E,)`` booleans: edges that keep weight 1.
    quantile : float
        Chi-square quantile of the thresholds, ``0 < quantile < 1``.
    mu_step : float
        Factor of ``mu`` per outer iteration, > 1.
    max_iter : int
        Outer iterations at most.
    weights_tol : float
        Stop when every weight is within this of 0 or 1.
    rejected : numpy.ndarray, optional
        ``(E,)`` booleans: edges held at weight 0 (not judged; ``known`` wins where both are
        set). With every edge known or rejected this is one relaxation of the known edges.

    Returns
    -------
    poses : LieGroup
        ``(n,)`` the last relaxation's estimate.
    weights : numpy.ndarray
        ``(E,)`` 0 or 1 (rounded): 0 for an edge judged an outlier.
    mu : float
        The last ``mu`` (where the nonlinear GNC continues).

    Examples
    --------
    See the module docstring.
    """
    from scipy.stats import chi2  # type: ignore[import-untyped]

    if group not in (SE2, SE3):
        raise ValueError(f"chordal_gnc: group must be SE2 or SE3, got {group!r}")
    d = 2 if group is SE2 else 3
    rot = SO2 if d == 2 else SO3  # from_matrix(normalize=True): the nearest rotation
    E = ii.size
    cov = np.linalg.inv(info)
    info_t = np.linalg.inv(cov[:, :d, :d])  # marginal information of the translation
    D = info.shape[-1]
    rho = D - d
    omega = rho / np.trace(cov[:, d:, d:], axis1=1, axis2=2)  # the chordal rotation weight
    assert isinstance(Z, (SE2, SE3))
    Rz = np.asarray(Z.rotation().matrix(), dtype=np.float64)
    tz = np.asarray(Z.translation(), dtype=np.float64)
    keep = np.delete(np.arange(n), anchor)
    eye = np.broadcast_to(np.eye(d), (E, d, d))

    # rotations: residual Z^T x_i - x_j, x = R^T (columns decouple: d right-hand sides)
    rot_ls = _WeightedLS(ii, jj, np.swapaxes(Rz, 1, 2), -eye, np.zeros((E, d, d)), n, anchor,
                         np.eye(d))
    # translations with R held: whitened residual L R_i^T (t_j - t_i) - L t_ij
    L = np.swapaxes(np.linalg.cholesky(info_t), 1, 2)  # info_t = L^T L
    rhs = np.einsum("eab,eb->ea", L, tz)[:, :, None]
    tr_ls = _WeightedLS(ii, jj, -L, L, rhs, n, anchor, np.zeros((d, 1)))

    def relax(w: np.ndarray) -> LieGroup:
        x = rot_ls(w * omega)
        xs = np.empty((n, d, d))
        xs[anchor] = np.eye(d)
        xs[keep] = x.reshape(-1, d, d)
        R = np.asarray(rot.from_matrix(np.swapaxes(xs, 1, 2), normalize=True).matrix())
        B = L @ np.swapaxes(R[ii], 1, 2)
        tr_ls.set_blocks(-B, B, rhs)
        t = np.zeros((n, d))
        t[keep] = tr_ls(w).reshape(-1, d)
        T = np.zeros((n, d + 1, d + 1))
        T[:, :d, :d] = R
        T[:, :d, d] = t
        T[:, d, d] = 1.0
        return group.from_matrix(T)

    def resid(X: LieGroup) -> np.ndarray:
        rel = X[ii].inverse().compose(X[jj])  # type: ignore[call-overload]
        r = np.asarray(Zinv.compose(rel).log(), dtype=np.float64)  # type: ignore[call-overload]
        return np.einsum("ea,eab,eb->e", r, info, r)

    Zinv = Z.inverse()
    w = np.ones(E)
    judged = ~np.asarray(known, dtype=bool)
    if rejected is not None:
        out = judged & np.asarray(rejected, dtype=bool)
        w[out] = 0.0
        judged &= ~out
    X, mu, _ = _graduate(relax, resid, w, judged, float(chi2.ppf(quantile, D)),
                         mu_step, max_iter, weights_tol)
    return anchor_pose.compose(X), w, mu
