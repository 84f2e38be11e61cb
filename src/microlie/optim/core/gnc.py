"""Graduated non-convexity (GNC): robust estimation that finds the outliers itself.

Yang, Antonante, Tzoumas and Carlone, "Graduated Non-Convexity for Robust Spatial Perception:
From Non-Minimal Solvers to Global Outlier Rejection", RA-L 2020. GNC minimises
``0.5 * sum rho(s_k)`` with ``s_k = |e_k|^2`` the whitened squared residual of factor ``k`` and
``rho`` truncated least squares (TLS, ``rho(s) = min(s, c^2)``) or Geman-McClure (GM,
``rho(s) = c^2 s / (c^2 + s)``), by a sequence of surrogates ``rho_mu`` that starts convex and
ends at ``rho``. Each outer iteration alternates

1. the weights in closed form at the current residuals (:func:`tls_weights`,
   :func:`gm_weights`: the minimisers of the surrogate's Black-Rangarajan duality), then
2. the weighted least-squares problem ``min 0.5 * sum w_k s_k`` solved on the one engine
   (:func:`~microlie.optim.core.solvers.solve`, warm-started from the previous estimate; the
   pattern does not change, so the symbolic analysis of a named linear solver is reused),
3. ``mu`` updated: ``mu <- mu_step * mu`` for TLS (non-convexity grows as ``mu -> inf``),
   ``mu <- max(1, mu / mu_step)`` for GM (``mu = 1`` is GM itself).

The threshold ``c^2`` of each factor is the ``quantile`` of the chi-square distribution with the
factor's dimension degrees of freedom (:func:`inlier_thresholds`): an inlier's ``s_k`` is below
it with that probability when the information matrices match the noise; with the cycle marking
(the default on pose graphs) the covariances are first scaled by their variance factor
estimated from the cycle-consistent edges and the quantile is family-wise
(``variance_factor``, ``quantile``). The first weights come
from the start values (``first="values"``), as in the paper from the plain least-squares
estimate (``first="least-squares"``), or, on pose graphs, from GNC-TLS run first on the
chordal relaxation (``first="chordal"``, :mod:`microlie.optim.core.gnc_chordal`; ``"cycles"``
with a cycle-consistency marking first); the default ``first="auto"`` is ``"cycles"`` for TLS on
a pose graph and ``"values"`` otherwise (:meth:`GNC.resolved`);
``mu`` starts as the paper's Remark 5 (:func:`initial_mu`) from the largest residual there (or
where the chordal stage left it). The outer
loop stops when every TLS weight is within ``weights_tol`` of 0 or 1 (they are then rounded and
the inliers solved once more: the result is the least-squares optimum of the factors judged
inliers), when the relative change of the weighted cost is below ``cost_tol`` (for GM once
``mu`` has reached 1: the reweighting continues to Geman-McClure's fixed point), or after
``max_iter`` outer iterations. Known inliers (odometry, priors) keep weight 1 throughout.

Examples
--------
>>> import numpy as np
>>> from microlie.optim.core.gnc import tls_weights
>>> np.round(tls_weights(np.array([0.5, 4.0, 100.0]), 4.0, 1.0), 6).tolist()  # c^2 4, mu 1
[1.0, 0.414214, 0.0]
"""

from __future__ import annotations

import copy
import dataclasses
import math
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...groups import SE3
from .factors import Factor
from .gnc_weights import gm_weights, initial_mu, tls_weights
from .problem import Problem
from .robust import RobustLoss
from .solvers import Result, solve
from .strategies import Strategy
from .variables import Values

__all__ = ["GNC", "SURROGATES", "make_gnc", "tls_weights", "gm_weights", "initial_mu",
           "inlier_thresholds", "squared_norms", "gnc_solve"]

SURROGATES = ("tls", "gm")
FIRST = ("auto", "values", "least-squares", "chordal", "cycles")
# quantile=None with an estimated variance factor: 1% over 10,000 edges (Bonferroni)
FAMILY_QUANTILE = 1.0 - 1e-6
# search=True: rounds of the region search (each one solve when it moves something)
_SEARCH_ROUNDS = 3


class GNC:
    """Options of graduated non-convexity (:meth:`FactorGraph.optimize`'s ``robust``).

    Parameters
    ----------
    surrogate : {"tls", "gm"}
        Truncated least squares (the paper's GNC-TLS, the default) or Geman-McClure.
    quantile : float or None
        ``0 < quantile < 1``: the inlier threshold of a factor of dimension ``d`` is
        ``c^2 = chi2.ppf(quantile, d)`` on its whitened squared residual (times the variance
        factor). ``None`` (default): 0.99, as GTSAM's ``GncOptimizer``, with the information
        as given; ``1 - 1e-6`` with an estimated variance factor (``FAMILY_QUANTILE``: with the
        noise estimated the test is family-wise, 1% over up to 10,000 good edges, Bonferroni;
        0.99 per edge rejects a few dozen good edges of M3500 and moves its answer 0.04-0.17 m).
    known_inliers : sequence, optional
        Factors that keep weight 1 (never judged): each item a factor batch of the graph (all
        its rows) or ``(factor, rows)`` with row indices or a boolean mask of that batch.
    mu_step : float
        The factor ``mu`` is multiplied (TLS) or divided (GM) by each outer iteration, > 1
        (default 1.4, the paper's and GTSAM's).
    max_iter : int
        Outer iterations at most, >= 1 (default 100).
    cost_tol : float
        Stop when the weighted cost changes by less than this relative amount between outer
        iterations, >= 0 (default 1e-5).
    weights_tol : float
        TLS: stop when every weight is within this of 0 or 1, ``0 <= weights_tol < 0.5``
        (default 1e-4).
    first : {"auto", "values", "least-squares", "chordal", "cycles"}
        Where the first weights and ``mu`` come from. ``"auto"`` (default): ``"cycles"`` for
        TLS on a pose graph (:func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` is not
        None), else ``"values"`` (:meth:`resolved`): the best measured on the pose graphs of
        ``benchmarks/robust.py`` (``benchmarks/results/robust-defaults-s14.md``). Otherwise:
        the residuals at the start values (``"values"``, the default until session 14);
        as in the paper and GTSAM, at the plain least-squares estimate from the
        start (one more solve; the outliers pull it); or, for TLS on a pose graph (one SE2/SE3
        batch, only BetweenFactor and PriorFactor, a fixed vertex or a prior), GNC-TLS first
        on the chordal relaxation (:mod:`microlie.optim.core.gnc_chordal`: linear inner
        solves that no start can bend), then least squares on its inliers and GNC-TLS on the
        nonlinear problem from there at its last ``mu``. Measured (``benchmarks/robust.py``):
        with the odometry known, ``"chordal"`` reaches M3500 and sphere2500 with 10-70% wrong
        loop closures in most cases where ``"values"`` ends 0.5-47 m off; on small graphs
        with calibrated information and no known inliers it misjudges more edges than
        ``"values"`` (the relaxation is not the maximum-likelihood estimate).
        ``"cycles"``: as ``"chordal"``, with every edge that closes a short cycle within its
        noise (:func:`~microlie.optim.core.gnc_cycles.consistent_edges`) added to the known
        inliers first, and after GNC the pieces held by one accepted edge moved where most
        edges across it agree (:func:`~microlie.optim.core.gnc_bridges.repair_bridges`),
        then the inliers solved once more (for graphs without known odometry); pieces are
        also merged by a rigid-motion vote over the edges between them
        (:mod:`microlie.optim.core.gnc_merge`), before the chordal stage and after GNC,
        then the pieces no accepted edge holds attached by their best-supported edge.
        Exact ties of the TLS objective (a piece that either of two edges can hold alone:
        one rejected, the other accepted, the same ``0.5 * sum min(s, c^2)``) are broken by
        the chain's poses (``chain``, the default) or, with ``chain=False``, by the start
        values, the user's information: the choice with more edges that fit
        the start (whitened squared residual within ``c^2`` there) is kept; when neither
        fits the start the tie is left as GNC found it. Such answers therefore depend on
        the start; where the support differs it does not.
    retest : int
        With ``first="chordal"`` or ``"cycles"``: passes of data snooping after GNC, >= 0
        (default 3; 0: off; :mod:`microlie.optim.core.gnc_retest`). With ``v`` the a
        posteriori variance factor of the accepted edges (at most 1), each pass accepts the
        rejected judged edges whose innovation is within ``v c^2`` and rejects the accepted
        ones whose standardised residual exceeds ``v`` times the Bonferroni bound of the
        family; after flips the inliers are solved again from their chordal relaxation,
        until nothing flips. Measured: fixes the three M3500 cases GNC-TLS missed with the
        odometry known (a wrong closure within the file's overstated noise; a good closure
        rejected at a drifted estimate).
    search : bool
        With ``first="cycles"``: after the repair and the vote, a local search on the TLS
        objective (default False; :mod:`microlie.optim.core.gnc_search`): rigid moves of
        unions of pieces (components of the cycle-consistent and voted edges) proposed by the
        rejected edges, then chains of such moves
        (:func:`~microlie.optim.core.gnc_search.chain_moves`: moves that are exact ties
        accepted tentatively until a later move lowers the objective), kept only when the
        objective falls after the inlier solve. Only ``known_inliers`` are never rejected by
        it. Measured on M3500 without known inliers (docs/optim.md): the excess of the
        objective over the outlier-free optimum's at 30% from the chordal start falls from
        26-31 to 15-21 edges, at 50% from 86-105 to 67-92 (APE unchanged, 38-48 m); nothing
        changes at 10% or with the odometry known; GNC takes 3-10 times as long on M3500
        30-50%.
    cycle_length : int or None
        With ``first="cycles"``: the longest cycle of the consistency marking, 2 to 9 edges;
        ``None`` (default): 8 on an SE3 pose graph, 5 otherwise (SE2). 5:
        :func:`~microlie.optim.core.gnc_cycles.consistent_edges` and the vote of
        :func:`~microlie.optim.core.gnc_merge.merge_known`. Any other value uses
        :func:`~microlie.optim.core.gnc_loops.mark_loops`: cycles up to that length (in 2-D
        an edge needs two consistent cycles longer than five edges) and the vote between the
        pieces posed by their chordal relaxation. Measured on sphere2500 without known
        inliers (``benchmarks/results/robust-sph-s13.md``): 8 marks 3140 of the 3724 good
        edges at 50% (seed 0, with the vote; 5: 2255) and no wrong one; on M3500 (2-D) it
        made 70% seed 0 with the odometry known worse (1.91 m instead of 5.6e-13 m).
    moves : bool or None
        With ``first="cycles"``: after GNC (and the vote), move pieces of the graph rigidly
        where more of their edges fit (:func:`~microlie.optim.core.gnc_loops.move_stage`:
        pieces of the known edges, of the accepted edges, small regions outside the largest
        known piece, the sides of accepted bridges), solve the accepted edges, and keep the
        result only when the TLS objective fell. ``None`` (default): on for an SE3 pose
        graph, off otherwise (SE2). Measured (``benchmarks/results/robust-defaults-s14.md``,
        no known inliers): on sphere2500 (SE3) it brings the chordal start's answers at 30%
        seed 2 and 50% (all seeds) to the outlier-free optimum (0.96-9.7 m without), at 2.0
        times GNC's time over the 18 rows and up to 7 times on one (50% seed 0, chordal
        start); on M3500 (SE2) it changed no verdict at 1.5 times the time.
    assemble : bool
        With ``first="cycles"``: before the chordal stage, join the pieces of the known edges
        where cycles of pieces close (:mod:`microlie.optim.core.gnc_assemble`: chains of
        pieces composed into one link, the cycle test and the vote with the covariances
        scaled by the variance factor of the known edges); the joined edges become known
        inliers (default False). Measured on M3500 without known inliers: the chordal stage
        rejects 11-12 odometry edges at 10% instead of 51; the excess of the objective over
        the outlier-free optimum's at 30% from the chordal start falls from 26-31 to -0.7-5
        edges, at 50% from 86-105 to -0.9-52; two rows got worse (by 1-3 edges); GNC time
        0.8-1.3 times.
    variance_factor : float, "estimate" or None
        The factor the factors' covariances are multiplied by before the thresholds apply
        (every ``c^2`` becomes ``v c^2``; the least-squares solves do not change). ``None``
        (default): ``"estimate"`` with ``first="cycles"`` unless the known inliers hold every
        edge of the chain (``chain``; e.g. the odometry known), else 1 (the information as
        given: there the re-test's variance factor catches what the file's noise lets in, and
        the estimate measured worse, 22 of 24 M3500 rows within 0.01 m instead of 24).
        ``"estimate"`` (a pose graph with ``first="cycles"``): the a posteriori variance
        factor of the edges the cycle test marks
        (:func:`~microlie.optim.core.gnc_assemble.known_variance`, clipped to ``[1e-3, 1]``),
        then the marking is done again with the scaled covariances; the value is in the
        result's message. For files whose information overstates the noise, where wrong edges
        then pass as inliers: M3500's covariances are about 40 times the scatter of its edges
        (``v = 0.024``). Measured in ``benchmarks/results/robust-s15.md``.
    chain : bool or None
        With ``first="cycles"``: the spanning tree of the edges between the nearest vertex
        indices (:func:`~microlie.optim.core.gnc_chain.chain_edges`; the odometry of a file
        whose vertices are numbered in time order) is GNC's hypothesis where the data cannot
        decide. ``None`` (default): True with ``first="cycles"``, else False. Exact ties of
        the TLS objective (see ``first``) are broken by the poses composed along the tree
        instead of the start values, so the answer does not depend on the start; and, unless
        its answer already accepts every tree edge, GNC solves a second time with the tree's
        edges held as inliers (from those poses) and keeps that answer when its TLS
        objective over every edge, the tree's included, is no higher and every tree edge fits
        there within its threshold (a wrong odometry edge makes it lose). Measured on M3500
        without known inliers (``benchmarks/results/robust-s15.md``): 18 of 18 rows within
        0.01 m at 10-50% wrong loop closures, with the estimated variance factor (2 of 18
        before).

    Examples
    --------
    >>> from microlie.optim.core.gnc import GNC
    >>> GNC("gm", quantile=0.95)
    GNC('gm', quantile=0.95, first='auto', known_inliers=0 batches)
    >>> GNC()
    GNC('tls', quantile=None, first='auto', known_inliers=0 batches)
    """

    def __init__(self, surrogate: str = "tls", *, quantile: float | None = None,
                 known_inliers: Sequence[Any] | None = None, mu_step: float = 1.4,
                 max_iter: int = 100, cost_tol: float = 1e-5, weights_tol: float = 1e-4,
                 first: str = "auto", retest: int = 3, cycle_length: int | None = None,
                 moves: bool | None = None, search: bool = False,
                 assemble: bool = False, variance_factor: float | str | None = None,
                 chain: bool | None = None) -> None:
        if surrogate not in SURROGATES:
            raise ValueError(f"GNC surrogate must be one of {', '.join(SURROGATES)}, got "
                             f"{surrogate!r}")
        if quantile is not None and not (isinstance(quantile, (float, int)) and
                                         not isinstance(quantile, bool) and
                                         0.0 < quantile < 1.0):
            raise ValueError(f"GNC quantile must be a probability strictly between 0 and 1 or "
                             f"None, got {quantile!r}")
        if not (isinstance(mu_step, (float, int)) and math.isfinite(mu_step) and mu_step > 1.0):
            raise ValueError(f"GNC mu_step must be a finite number > 1, got {mu_step!r}")
        if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or \
                max_iter < 1:
            raise ValueError(f"GNC max_iter must be an integer >= 1, got {max_iter!r}")
        if not (isinstance(cost_tol, (float, int)) and math.isfinite(cost_tol) and cost_tol >= 0):
            raise ValueError(f"GNC cost_tol must be a finite number >= 0, got {cost_tol!r}")
        if not (isinstance(weights_tol, (float, int)) and 0.0 <= weights_tol < 0.5):
            raise ValueError(f"GNC weights_tol must be in [0, 0.5), got {weights_tol!r}")
        if first not in FIRST:
            raise ValueError(f"GNC first must be one of {', '.join(FIRST)}, got {first!r}")
        if known_inliers is not None and (isinstance(known_inliers, (Factor, str)) or
                                          not isinstance(known_inliers, Sequence)):
            raise ValueError("GNC known_inliers must be a sequence of factor batches or "
                             "(factor, rows) pairs, e.g. [odometry]")
        self.surrogate = surrogate
        self.quantile = None if quantile is None else float(quantile)
        self.known_inliers = list(known_inliers or [])
        self.mu_step = float(mu_step)
        self.max_iter = int(max_iter)
        self.cost_tol = float(cost_tol)
        self.weights_tol = float(weights_tol)
        self.first = first
        if isinstance(retest, bool) or not isinstance(retest, (int, np.integer)) or retest < 0:
            raise ValueError(f"GNC retest must be an integer >= 0 (passes; 0: off), got "
                             f"{retest!r}")
        self.retest = int(retest)
        if not isinstance(search, bool):
            raise ValueError(f"GNC search must be True or False, got {search!r}")
        self.search = search
        if cycle_length is not None and (
                isinstance(cycle_length, bool) or
                not isinstance(cycle_length, (int, np.integer)) or not 2 <= cycle_length <= 9):
            raise ValueError(f"GNC cycle_length must be an integer from 2 to 9 or None (8 for "
                             f"SE3, 5 for SE2), got {cycle_length!r}")
        self.cycle_length = None if cycle_length is None else int(cycle_length)
        if moves is not None and not isinstance(moves, bool):
            raise ValueError(f"GNC moves must be True, False or None (on for SE3, off for "
                             f"SE2), got {moves!r}")
        self.moves = moves
        if not isinstance(assemble, bool):
            raise ValueError(f"GNC assemble must be True or False, got {assemble!r}")
        self.assemble = assemble
        if not (variance_factor is None or variance_factor == "estimate" or (
                isinstance(variance_factor, (float, int)) and
                not isinstance(variance_factor, bool) and math.isfinite(variance_factor) and
                variance_factor > 0)):
            raise ValueError(f"GNC variance_factor must be a finite number > 0, 'estimate' or "
                             f"None, got {variance_factor!r}")
        self.variance_factor = variance_factor if variance_factor in (None, "estimate") \
            else float(variance_factor)  # type: ignore[arg-type]
        if chain is not None and not isinstance(chain, bool):
            raise ValueError(f"GNC chain must be True, False or None (with first='cycles'), "
                             f"got {chain!r}")
        self.chain = chain
        self._hypothesis = False  # set on the copies that chain=True solves with
        self._variance_note = ""  # how those copies' variance factor was estimated

    def __repr__(self) -> str:
        return (f"GNC({self.surrogate!r}, quantile={self.quantile}, first={self.first!r}, "
                f"known_inliers={len(self.known_inliers)} batches)")

    def resolved(self, problem: Problem) -> GNC:
        """These options with ``first="auto"`` and every ``None`` decided for ``problem``.

        ``first="auto"``: ``"cycles"`` for TLS on a pose graph
        (:func:`~microlie.optim.core.gnc_chordal.pose_graph_edges` is not None), else
        ``"values"``. ``cycle_length=None``: 8 on an SE3 pose graph, 5 otherwise (SE2).
        ``moves=None``: True on an SE3 pose graph, False otherwise. ``variance_factor=None``:
        ``"estimate"`` with ``first="cycles"`` unless the known inliers hold the chain, else
        1.0; ``chain=None``: whether
        ``first="cycles"``; ``quantile=None``: ``FAMILY_QUANTILE`` with ``"estimate"``, else
        0.99.

        Parameters
        ----------
        problem : Problem
            The problem GNC will solve.

        Returns
        -------
        GNC
            A copy with those options set (``self`` when nothing was left to decide).

        Examples
        --------
        >>> from microlie import SE2, SE3
        >>> from microlie.optim import FactorGraph, BetweenFactor
        >>> from microlie.optim.core.gnc import GNC
        >>> def chain(group):
        ...     g = FactorGraph()
        ...     x = g.add_variables(group.identity(3), fixed=[0])
        ...     _ = g.add(BetweenFactor(x, [0, 1], [1, 2], group.identity(2)))
        ...     return g.problem()
        >>> [(o.first, o.cycle_length, o.moves) for o in (GNC().resolved(chain(SE2)),
        ...                                               GNC().resolved(chain(SE3)),
        ...                                               GNC("gm").resolved(chain(SE3)))]
        [('cycles', 5, False), ('cycles', 8, True), ('values', 8, True)]
        >>> [(o.variance_factor, o.chain, o.quantile) for o in (GNC().resolved(chain(SE2)),
        ...                                                     GNC("gm").resolved(chain(SE2)))]
        [('estimate', True, 0.999999), (1.0, False, 0.99)]
        """
        if self.first != "auto" and self.cycle_length is not None and self.moves is not None \
                and self.variance_factor is not None and self.chain is not None and \
                self.quantile is not None:
            return self
        from .gnc_chordal import pose_graph_edges

        edges = pose_graph_edges(problem)
        out = copy.copy(self)
        out.known_inliers = list(self.known_inliers)
        if self.first == "auto":
            out.first = "cycles" if edges is not None and self.surrogate == "tls" else "values"
        se3 = edges is not None and edges.group is SE3
        if self.cycle_length is None:
            out.cycle_length = 8 if se3 else 5
        if self.moves is None:
            out.moves = se3
        cycles = out.first == "cycles"
        if self.variance_factor is None:
            out.variance_factor = "estimate" if cycles and edges is not None and \
                not self._chain_known(problem, edges) else 1.0
        if self.chain is None:
            out.chain = cycles and edges is not None
        if self.quantile is None:
            out.quantile = FAMILY_QUANTILE if out.variance_factor == "estimate" else 0.99
        return out

    def _chain_known(self, problem: Problem, edges: Any) -> bool:
        """Whether the known inliers hold every edge of the chain (e.g. the odometry)."""
        from .gnc_chain import chain_edges

        return _on_tree(self.known_masks(problem.factors), chain_edges(edges), edges)

    def known_masks(self, factors: Sequence[Factor]) -> list[np.ndarray]:
        """Boolean masks of the known inliers, one per factor batch of ``factors``.

        Parameters
        ----------
        factors : sequence of Factor
            The graph's factor batches, in order.

        Returns
        -------
        list of numpy.ndarray
            ``(count,)`` booleans per batch.

        Raises
        ------
        ValueError
            An item that is not a batch of ``factors`` or rows out of range.

        Examples
        --------
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> from microlie.optim.core.gnc import GNC
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> p = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> b = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.identity(2)))
        >>> [m.tolist() for m in GNC(known_inliers=[p, (b, [1])]).known_masks(g.factors)]
        [[True], [False, True]]
        """
        masks = [np.zeros(f.count, dtype=bool) for f in factors]
        where = {id(f): k for k, f in enumerate(factors)}
        for item in self.known_inliers:
            f, rows = (item, None) if isinstance(item, Factor) else _pair(item)
            k = where.get(id(f))
            if k is None:
                raise ValueError(f"GNC known_inliers: {f!r} is not a factor batch of this graph")
            if rows is None:
                masks[k][:] = True
                continue
            r = np.asarray(rows)
            if r.dtype == bool:
                if r.shape != (f.count,):
                    raise ValueError(f"GNC known_inliers: the mask of {f!r} must have shape "
                                     f"({f.count},), got {r.shape}")
                masks[k] |= r
                continue
            if r.size and (r.dtype.kind not in "iu" or r.min() < -f.count or
                           r.max() >= f.count):
                raise ValueError(f"GNC known_inliers: rows of {f!r} must be integers in "
                                 f"[0, {f.count}), got {rows!r}")
            masks[k][r.astype(np.int64)] = True
        return masks


def _pair(item: Any) -> tuple[Factor, Any]:
    if isinstance(item, tuple) and len(item) == 2 and isinstance(item[0], Factor):
        return item[0], item[1]
    raise ValueError(f"GNC known_inliers: each item must be a factor batch or (factor, rows), "
                     f"got {item!r}")


def make_gnc(spec: str | GNC) -> GNC:
    """GNC options from ``"gnc-tls"``, ``"gnc-gm"`` or a :class:`GNC`.

    Parameters
    ----------
    spec : str or GNC
        ``"gnc-tls"`` / ``"gnc-gm"`` (default options) or an instance.

    Returns
    -------
    GNC

    Examples
    --------
    >>> from microlie.optim.core.gnc import make_gnc
    >>> make_gnc("gnc-gm").surrogate
    'gm'
    """
    if isinstance(spec, GNC):
        return spec
    if isinstance(spec, str) and spec.lower().startswith("gnc-"):
        return GNC(spec.lower()[4:]) if spec.lower()[4:] in SURROGATES else GNC(spec[4:])
    raise ValueError(f"robust must be 'gnc-tls', 'gnc-gm' or a GNC instance, got {spec!r} (a "
                     f"robust loss goes on the factors: loss='huber:1')")


def inlier_thresholds(factors: Sequence[Factor], quantile: float) -> list[float]:
    """``c^2`` of each factor batch: the chi-square quantile with the factor's dimension.

    Parameters
    ----------
    factors : sequence of Factor
        Factor batches.
    quantile : float
        Probability, ``0 < quantile < 1``.

    Returns
    -------
    list of float
        ``scipy.stats.chi2.ppf(quantile, f.dim)`` per batch.

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> from microlie.optim.core.gnc import inlier_thresholds
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> f = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> [round(c, 4) for c in inlier_thresholds([f], 0.99)]  # chi2(3) at 0.99
    [11.3449]
    """
    if not 0.0 < quantile < 1.0:
        raise ValueError(f"quantile must be strictly between 0 and 1, got {quantile!r}")
    from scipy.stats import chi2  # type: ignore[import-untyped]

    return [float(chi2.ppf(quantile, f.dim)) for f in factors]


class _Weighted(RobustLoss):
    """Fixed per-row weights: ``rho(s) = w s`` (a weighted least-squares factor batch)."""

    def __init__(self, weights: np.ndarray) -> None:
        super().__init__(1.0)
        self.w = weights

    def evaluate(self, s):
        if s.shape != self.w.shape:  # the engine evaluates whole batches only
            raise ValueError(f"GNC weights of shape {self.w.shape} for residuals {s.shape}")
        return self.w * s, self.w, np.zeros_like(s)


def squared_norms(problem: Problem, states: list[np.ndarray]) -> list[np.ndarray]:
    """Whitened squared residual norms ``s = |e|^2`` of every factor row at ``states``.

    Parameters
    ----------
    problem : Problem
        The problem.
    states : list of numpy.ndarray
        The parameters of each variable batch, in graph order.

    Returns
    -------
    list of numpy.ndarray
        ``(count,)`` per factor batch.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
    >>> from microlie.optim.core.gnc import squared_norms
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> _ = g.add(PriorFactor(x, 0, SE2.exp([3.0, 0, 0]), Isotropic(3, 0.5)))
    >>> p = g.problem()
    >>> [s.round(9).tolist() for s in squared_norms(p, [v.initial for v in p.variables])]
    [[36.0]]
    """
    out = []
    for f, pl in zip(problem.factors, problem.plans, strict=True):
        if pl is not None:
            s = np.array(pl.cost(states), dtype=np.float64)
        else:
            e = problem.whiten(f, np.asarray(f.evaluate(problem.gather(f, states), False),
                                             dtype=np.float64))
            s = np.einsum("mi,mi->m", e, e)
        out.append(s)
    return out


def _objective(surrogate: str, s: list[np.ndarray], c2: list[float],
               known: list[np.ndarray]) -> float:
    """``0.5 * sum rho(s)`` with TLS or GM (mu at its final value) on the judged rows, plain
    least squares on the known inliers."""
    total = 0.0
    for sk, ck, kk in zip(s, c2, known, strict=True):
        r = np.minimum(sk, ck) if surrogate == "tls" else ck * sk / (ck + sk)
        total += 0.5 * float(np.where(kk, sk, r).sum())
    return total


def _q(gnc: GNC) -> float:
    """The quantile of resolved options (:meth:`GNC.resolved` decides ``None``)."""
    if gnc.quantile is None:
        raise ValueError("GNC options not resolved: call GNC.resolved(problem) first")
    return gnc.quantile


def _count(masks: list[np.ndarray]) -> int:
    return sum(int(m.sum()) for m in masks)


def _mark_cycles(edges: Any, known: list[np.ndarray], gnc: GNC, s_start: list[np.ndarray]
                 ) -> list[np.ndarray]:
    """``first="cycles"``: the known-inlier masks with the edges of consistent cycles (and,
    with ``assemble``, of consistent cycles of pieces) added."""
    if gnc.cycle_length != 5:
        from .gnc_loops import mark_loops

        known = mark_loops(edges, known, _q(gnc), gnc.cycle_length or 5)
    else:
        from .gnc_cycles import mark_consistent
        from .gnc_merge import merge_known

        known = mark_consistent(edges, known, _q(gnc))
        known = merge_known(edges, known, _q(gnc), s_start)  # joined by a vote
    if gnc.assemble:
        from .gnc_assemble import assemble_known

        known = assemble_known(edges, known, _q(gnc))  # cycles of pieces
    return known


def _on_tree(masks: list[np.ndarray], tree: np.ndarray, edges: Any) -> bool:
    """Whether per-batch boolean ``masks`` hold every edge of ``tree`` (an edge mask)."""
    return all(bool(np.all(masks[k][tree[sl]])) for k, sl in edges.rows)


def _estimate_variance(edges: Any, known: list[np.ndarray], gnc: GNC,
                       s_start: list[np.ndarray]) -> tuple[float, str]:
    """``variance_factor="estimate"``: the factor of the cycle-consistent edges and the note
    for the result's message."""
    from .gnc_assemble import known_variance

    marked = _mark_cycles(edges, known, gnc, s_start)
    v = known_variance(edges, marked, _q(gnc))
    return v, f"; variance factor {v:.6g} (estimated from {_count(marked):d} cycle-consistent " \
              f"edges)"


def _chain_states(edges: Any, states: list[np.ndarray]) -> list[np.ndarray]:
    """The start values with the poses composed along the chain from the anchor's."""
    from .gnc_chain import chain_poses

    P = np.array(states[0], dtype=np.float64)
    P[:] = np.asarray(chain_poses(edges, edges.group.from_params(P[edges.anchor])).params,
                      dtype=np.float64)
    return [P]


def _chain_hypothesis(problem: Problem, states: list[np.ndarray], gnc: GNC, strategy: Any,
                      **kw: Any) -> Result:
    """``GNC(chain=True)``: GNC with ties broken by the chain, then, unless that answer accepts
    every chain edge (or the known inliers hold them), GNC with the chain's edges held as
    inliers; the answer of lower TLS objective over every edge (the second on a tie, when
    every chain edge fits there)."""
    from .gnc_chain import chain_edges
    from .gnc_chordal import pose_graph_edges

    t0 = time.perf_counter()
    edges = pose_graph_edges(problem)
    if edges is None:
        raise ValueError("GNC chain=True needs a pose graph: one SE2 or SE3 variable batch "
                         "with only BetweenFactor and PriorFactor batches and a fixed vertex "
                         "or a prior")
    user_known = gnc.known_masks(problem.factors)
    base = copy.copy(gnc)
    base._hypothesis = True
    if gnc.variance_factor == "estimate":  # one estimate for both answers (one objective)
        base.variance_factor, base._variance_note = _estimate_variance(
            edges, user_known, gnc, squared_norms(problem, states))
    vf = base.variance_factor if isinstance(base.variance_factor, float) else 1.0
    a = gnc_solve(problem, states, base, strategy, **kw)
    tree = chain_edges(edges)
    if _on_tree(user_known, tree, edges):
        # the tree's edges are known inliers already: nothing to try
        return dataclasses.replace(a, time_s=time.perf_counter() - t0)
    if a.inliers is not None and _on_tree(a.inliers, tree, edges):
        # GNC's answer accepts every tree edge already: the second pass, which holds them,
        # is skipped (measured: the same answers on benchmarks/robust.py's rows)
        return dataclasses.replace(a, message=f"{a.message}; chain hypothesis: every edge of "
                                              f"the chain accepted, no second pass",
                                   time_s=time.perf_counter() - t0)
    held = copy.copy(base)
    held.known_inliers = list(gnc.known_inliers) + [
        (problem.factors[k], tree[sl]) for k, sl in edges.rows]
    b = gnc_solve(problem, _chain_states(edges, states), held, strategy, **kw)
    c2 = inlier_thresholds(problem.factors, _q(gnc))

    def norms(r: Result) -> list[np.ndarray]:
        return [sk / vf for sk in squared_norms(problem, [np.asarray(
            r.values.params(v), dtype=np.float64) for v in problem.variables])]

    sa, sb = norms(a), norms(b)
    oa, ob = _objective("tls", sa, c2, user_known), _objective("tls", sb, c2, user_known)
    fits = _on_tree([sk <= ck for sk, ck in zip(sb, c2, strict=True)], tree, edges)
    pick = b if ob <= oa and fits else a
    what = "held the chain's edges" if pick is b else "broke ties by the chain"
    ties = _ties(problem, edges, gnc, pick.inliers or [], [~kk for kk in user_known])
    return dataclasses.replace(
        pick, message=f"{pick.message}; chain hypothesis: kept the answer that {what} (TLS "
                      f"objective {vf * min(oa, ob):.6g} against {vf * max(oa, ob):.6g})",
        iterations=a.iterations + b.iterations, time_s=time.perf_counter() - t0,
        ties=ties, outer_iterations=(a.outer_iterations or 0) + (b.outer_iterations or 0))


def _chordal_stage(problem: Problem, states: list[np.ndarray], gnc: GNC, edges: Any,
                   known: list[np.ndarray], weights: list[np.ndarray]
                   ) -> tuple[list[np.ndarray], float]:
    """GNC-TLS on the chordal relaxation (:func:`~microlie.optim.core.gnc_chordal.chordal_gnc`):
    the poses and ``mu`` where the nonlinear GNC continues; sets the BetweenFactor weights."""
    from .gnc_chordal import chordal_gnc

    var = edges.variables
    kn = np.concatenate([known[k] for k, _ in edges.rows])
    X0 = var.group.from_params(np.asarray(states[0][edges.anchor]))
    X, w, mu = chordal_gnc(edges.group, edges.n, edges.ii, edges.jj, edges.Z, edges.info,
                           edges.anchor, X0, kn, quantile=_q(gnc),
                           mu_step=gnc.mu_step, max_iter=gnc.max_iter,
                           weights_tol=gnc.weights_tol)
    for k, sl in edges.rows:
        weights[k][~known[k]] = w[sl][~known[k]]
    P = np.array(X.params, dtype=np.float64)
    held = var.fixed
    P[held] = np.asarray(states[0], dtype=np.float64)[held]  # fixed vertices stay put
    return [P], mu


def gnc_solve(problem: Problem, states: list[np.ndarray], gnc: GNC,
              strategy: str | Strategy = "lm", *, linear_solver: Any = "auto",
              eliminate: Any = None, max_iter: int = 100, verbose: bool | None = None
              ) -> Result:
    """Graduated non-convexity on a problem (what ``FactorGraph.optimize(robust=...)`` calls).

    Parameters
    ----------
    problem : Problem
        The problem; its factor batches may not carry robust losses (GNC is the loss).
    states : list of numpy.ndarray
        The starting parameters of each variable batch.
    gnc : GNC
        The options.
    strategy : str or Strategy
        The strategy of every weighted inner solve (:func:`~microlie.optim.core.solvers.solve`).
    linear_solver : str or LinearSolver
        See :func:`~microlie.optim.make_solver`; a name is analysed once and reused by every
        inner solve.
    eliminate : Variables or sequence of Variables, optional
        With ``linear_solver="schur"``.
    max_iter : int
        Iteration limit of each inner solve.
    verbose : bool, optional
        One line per outer iteration on stderr (``mu``, weighted cost, inliers, inner
        iterations); default: when stderr is a terminal.

    Returns
    -------
    Result
        ``weights`` and ``inliers`` hold one array per factor batch (graph order): the last
        weights and the verdict (known inliers, also those the vote of ``first="cycles"``
        merged: always True). With TLS the verdict is the last weight rounded (``w >= 0.5``;
        the re-test decides by the weights and flips them): once the weights converged to 0
        or 1 the estimate is the least-squares optimum of the factors judged inliers, also
        where a rejected factor's final ``s`` is within ``c^2`` or an accepted one's beyond
        it. With GM (weights never 0 or 1) it is whether the factor's final ``s`` is within
        its threshold ``c^2``. ``outer_iterations`` counts the weight updates (each followed
        by a weighted solve); ``iterations`` and ``history`` are the inner solves'
        together; ``initial_robust_cost`` / ``final_robust_cost`` are ``0.5 * sum rho(s)``
        with TLS ``min(s, c^2)`` or GM ``c^2 s / (c^2 + s)`` (plain on known inliers);
        ``converged`` is True when a stopping rule of the outer loop was met; ``weights`` are
        all 1 when no residual exceeded half its threshold at the first estimate.

    Raises
    ------
    ValueError
        A factor batch with a robust loss, or bad known inliers.

    Notes
    -----
    The weights reach the engine as a fixed-weight loss set on the judged factor batches for
    the duration of the call (``rho(s) = w s``, no curvature correction) and removed on return,
    also on an error: do not share the graph's factors with another thread meanwhile.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
    >>> from microlie.optim.core.gnc import GNC, gnc_solve
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> z = SE2.exp(np.array([[0.0, 0, 0]] * 5 + [[9.0, 0, 0]]))  # one wild prior
    >>> _ = g.add(PriorFactor(x, [0] * 6, z, Isotropic(3, 0.1)))
    >>> p = g.problem()
    >>> res = gnc_solve(p, [v.initial for v in p.variables], GNC("tls"))
    >>> res.inliers[0].tolist(), np.round(res.values[x].log(), 9).tolist()
    ([True, True, True, True, True, False], [[0.0, 0.0, 0.0]])
    """
    t0 = time.perf_counter()
    factors = problem.factors
    for k, f in enumerate(factors):
        if f.loss is not None:
            raise ValueError(f"GNC replaces robust losses: factor batch {k} ({f.name}) has "
                             f"loss {f.loss!r}; build it without a loss")
    explicit_chain = gnc.chain
    gnc = gnc.resolved(problem)  # first="auto", cycle_length=None: decided for this problem
    if explicit_chain and gnc.first != "cycles":
        raise ValueError(f"GNC chain=True needs first='cycles' (or 'auto' with TLS on a pose "
                         f"graph), not {gnc.first!r}")
    if gnc.chain and gnc.first == "cycles" and not gnc._hypothesis:
        return _chain_hypothesis(problem, states, gnc, strategy, linear_solver=linear_solver,
                                 eliminate=eliminate, max_iter=max_iter, verbose=verbose)
    known = gnc.known_masks(factors)
    user_known = known  # the caller's (the stages below add their own known inliers)
    c2 = inlier_thresholds(factors, _q(gnc))
    s_start = squared_norms(problem, states)  # also what breaks exact ties (first="cycles")
    edges = None
    if gnc.first in ("chordal", "cycles") and gnc.surrogate != "tls":
        raise ValueError(f"GNC first={gnc.first!r} is a TLS stage; use surrogate='tls' or "
                         f"another first")
    if gnc.variance_factor == "estimate" and gnc.first != "cycles":
        raise ValueError(f"GNC variance_factor='estimate' comes from the cycle-consistent "
                         f"edges of a pose graph: use first='cycles' (or 'auto' on a pose "
                         f"graph), not {gnc.first!r}, or give the factor as a number")
    vf = gnc.variance_factor if isinstance(gnc.variance_factor, float) else 1.0
    note_v = gnc._variance_note or (f"; variance factor {vf:.6g} (given)" if vf != 1.0 else "")
    if gnc.first in ("chordal", "cycles"):
        from .gnc_chordal import pose_graph_edges

        edges = pose_graph_edges(problem)
        if edges is None:
            raise ValueError(f"GNC first={gnc.first!r} needs a pose graph: one SE2 or SE3 "
                             f"variable batch with only BetweenFactor and PriorFactor batches "
                             f"and a fixed vertex or a prior; use first='values'")
        if gnc.first == "cycles" and gnc.variance_factor == "estimate":
            vf, note_v = _estimate_variance(edges, known, gnc, s_start)
    # the covariances scaled by vf: every squared norm below is s / vf (in the stages' edge
    # information too), the thresholds stay c^2; the least-squares solves do not change
    s_start = [sk / vf for sk in s_start]
    s_tie = s_start  # the squared norms that break exact ties
    if edges is not None:
        edges.info = edges.info / vf
        if gnc.first == "cycles" and gnc.chain:
            s_tie = [sk / vf for sk in squared_norms(problem, _chain_states(edges, states))]
        if gnc.first == "cycles":
            known = _mark_cycles(edges, known, gnc, s_tie)

    def norms(st: list[np.ndarray]) -> list[np.ndarray]:
        return [sk / vf for sk in squared_norms(problem, st)]

    pieces = known
    show = bool(verbose) if verbose is not None else sys.stderr.isatty()
    weights = [np.ones(f.count) for f in factors]
    judged = [~kk for kk in known]
    runs: list[Result] = []

    def inner(st: list[np.ndarray]) -> list[np.ndarray]:
        res = solve(problem, st, strategy, linear_solver=linear_solver, eliminate=eliminate,
                    max_iter=max_iter, verbose=False)
        runs.append(res)
        return [np.asarray(res.values.params(v), dtype=np.float64) for v in problem.variables]

    saved = [f.loss for f in factors]
    try:
        for f, w, jk in zip(factors, weights, judged, strict=True):
            if jk.any():
                f.loss = _Weighted(w)  # weighted least squares, weights updated in place
        mu: float | None
        if edges is not None:
            cur, mu = _chordal_stage(problem, states, gnc, edges, known, weights)
            cur = inner(cur)  # least squares on the inliers of the chordal stage
            s = norms(cur)
        elif gnc.first == "values":
            cur = [np.asarray(st, dtype=np.float64) for st in states]
            s = s_start
        else:
            cur = inner(states)
            s = norms(cur)
        sj = np.concatenate([sk[jk] for sk, jk in zip(s, judged, strict=True)])
        cj = np.concatenate([np.full(int(jk.sum()), ck) for ck, jk in zip(c2, judged,
                                                                           strict=True)])
        if edges is None:
            mu = initial_mu(gnc.surrogate, sj, cj) if sj.size else None
        outer = 0
        message, termination = "", "convergence"
        if mu is None:
            where = ("at the start values" if gnc.first == "values" else
                     "at the least-squares estimate from the start values")
            message = (f"GNC skipped: no residual {where} exceeds half its threshold; "
                       f"solved by plain least squares (every weight 1)"
                       if sj.size else "every factor is a known inlier")
        else:
            prev = 0.5 * sum(float(sk.sum()) for sk in s)
            weight_fn = tls_weights if gnc.surrogate == "tls" else gm_weights
            message, termination = f"reached max_iter={gnc.max_iter} outer iterations", \
                "no_convergence"
            if show:
                print(f"{'outer':>5s} {'mu':>10s} {'weighted_cost':>14s} {'inliers':>8s} "
                      f"{'iters':>6s} {'time':>8s}", file=sys.stderr, flush=True)
            while outer < gnc.max_iter:
                outer += 1
                for w, sk, ck, jk in zip(weights, s, c2, judged, strict=True):
                    w[jk] = weight_fn(sk[jk], ck, mu)
                cur = inner(cur)
                s = norms(cur)
                cost = 0.5 * sum(float((w * sk).sum()) for w, sk in zip(weights, s,
                                                                         strict=True))
                if show:
                    n_in = sum(int((w >= 0.5).sum()) for w in weights)
                    print(f"{outer:5d} {mu:10.3e} {cost:14.6e} {n_in:8d} "
                          f"{runs[-1].iterations:6d} {time.perf_counter() - t0:8.3f}",
                          file=sys.stderr, flush=True)
                wj = np.concatenate([w[jk] for w, jk in zip(weights, judged, strict=True)])
                if gnc.surrogate == "tls" and \
                        np.all(np.abs(wj - np.round(wj)) <= gnc.weights_tol):
                    message, termination = "GNC weights converged to 0 or 1", "convergence"
                    snapped = [np.round(w) for w in weights]
                    if any(np.any(a != w) for a, w in zip(snapped, weights, strict=True)):
                        for a, w in zip(snapped, weights, strict=True):
                            w[:] = a  # the TLS solution: least squares on the inliers
                        cur = inner(cur)
                        s = norms(cur)
                    break
                if abs(cost - prev) / max(prev, 1e-7) < gnc.cost_tol and \
                        (gnc.surrogate == "tls" or mu == 1.0):
                    message, termination = "GNC weighted cost converged", "convergence"
                    break
                prev = cost
                mu = mu * gnc.mu_step if gnc.surrogate == "tls" else max(1.0, mu / gnc.mu_step)
        if edges is not None and gnc.first == "cycles" and runs:
            from .gnc_bridges import repair_stage
            from .gnc_merge import merge_stage

            moved = repair_stage(cur, edges, known, weights, c2, s_tie)
            if moved is not None:  # pieces held by one wrong edge moved: solve the inliers
                cur = inner(moved)
            cur, known, _ = merge_stage(cur, edges, known, weights, c2, inner,
                                        lambda st: norms(st),
                                        mu_step=gnc.mu_step, weights_tol=gnc.weights_tol,
                                        start=s_tie)
            moved = repair_stage(cur, edges, known, weights, c2, s_tie, components=True)
            cur = inner(moved) if moved is not None else cur  # pieces the merge left
            s = norms(cur)
        if edges is not None and gnc.first == "cycles" and gnc.search and runs:
            from .gnc_search import search_stage

            for _ in range(_SEARCH_ROUNDS):
                cur, moves = search_stage(
                    cur, edges, pieces, user_known, weights, c2, inner,
                    lambda st: _objective("tls", norms(st), c2, user_known),
                    chain=True)
                if not moves:
                    break
            s = norms(cur)
        if edges is not None and gnc.first == "cycles" and gnc.moves and runs:
            from .gnc_loops import move_stage

            for _ in range(5):  # pieces moved where their cut edges fit best, then solved
                before = _objective("tls", norms(cur), c2, known)
                saved_w = [w.copy() for w in weights]
                moved = move_stage(cur, edges, known, weights, c2)
                if moved is None:
                    break
                new = inner(moved)
                for w, sk, ck, kk in zip(weights, norms(new), c2, known,
                                         strict=True):
                    w[~kk] = (sk[~kk] <= ck).astype(np.float64)
                new = inner(new)
                if _objective("tls", norms(new), c2, known) >= before:
                    for w, a in zip(weights, saved_w, strict=True):
                        w[:] = a  # no better: keep the answer before the moves
                    break
                cur = new
            s = norms(cur)
        if edges is not None and gnc.retest and runs:
            from .gnc_retest import inlier_start, retest_stage

            v = None  # every pass tests against the first pass's variance factor
            for _ in range(gnc.retest):
                flipped, v = retest_stage(cur, edges, known, weights, c2, v)
                if not flipped:
                    break
                cur = inner(inlier_start(cur, edges, weights))  # the inliers after the flips
                s = norms(cur)
        if not runs:  # least squares is the answer: every weight 1
            cur = inner(cur)
            s = norms(cur)
    finally:
        for f, loss in zip(factors, saved, strict=True):
            f.loss = loss
    # the verdict: TLS the final weights rounded (after the re-test, which decides by them);
    # GM's weights are never 0 or 1, so its verdict is the final s within c^2
    inliers = [kk | (w >= 0.5) for kk, w in zip(known, weights, strict=True)] \
        if gnc.surrogate == "tls" else \
        [kk | (sk <= ck) for kk, sk, ck in zip(known, s, c2, strict=True)]
    ties = _ties(problem, edges, gnc, inliers, [~kk for kk in user_known])
    note = ""
    if ties:
        note = (f"; not unique: {len(ties)} piece(s) of the answer (the largest "
                f"{ties[0].poses.size} poses) held by one accepted edge that a rejected edge "
                f"could replace at the same TLS cost (result.ties): the data cannot decide, "
                f"{'the chain of nearest-index edges' if gnc.chain else 'the start values'} "
                f"did; known inliers decide otherwise")
    history: list[Any] = []
    offset = 0.0
    for r in runs:
        for rec in r.history:
            history.append(dataclasses.replace(rec, iteration=len(history) + 1,
                                               time_s=offset + rec.time_s))
        offset += r.time_s
    timings: dict[str, float] = {}
    for r in runs:
        for key, val in r.timings.items():
            timings[key] = timings.get(key, 0.0) + val
    total = time.perf_counter() - t0
    timings["other"] = timings.get("other", 0.0) + total - sum(r.time_s for r in runs)
    last = runs[-1]
    name = f"GNC-{gnc.surrogate.upper()}"
    return Result(Values(problem.variables, cur),  # costs in the problem's units (times vf)
                  0.5 * vf * sum(float(v.sum()) for v in s_start),
                  0.5 * vf * sum(float(v.sum()) for v in s),
                  vf * _objective(gnc.surrogate, s_start, c2, known),
                  vf * _objective(gnc.surrogate, s, c2, known),
                  sum(r.iterations for r in runs), termination == "convergence",
                  f"{name}: {message} after {outer} outer iterations ({len(runs)} "
                  f"solves){note_v}{note}",
                  termination, history, total, f"{name} + {last.solver}", last.linear_solver,
                  timings, list(problem.gauge_fixed), sum(r.accepted_steps for r in runs),
                  last.strategy, weights=weights, inliers=inliers, outer_iterations=outer,
                  ties=ties)


def _ties(problem: Problem, edges: Any, gnc: GNC, inliers: list[np.ndarray],
          judged: list[np.ndarray]) -> list[Any] | None:
    """GNC-TLS on a pose graph: :func:`~microlie.optim.core.gnc_ties.answer_ties`; else None."""
    if gnc.surrogate != "tls":
        return None
    if edges is None:
        from .gnc_chordal import pose_graph_edges

        edges = pose_graph_edges(problem)
        if edges is None:
            return None
    from .gnc_ties import answer_ties

    return answer_ties(problem, edges, inliers, judged)
