"""Spanning-tree preconditioner for PCG steps on pose graphs, solved on the device without a
sparse Cholesky.

The preconditioner ``M`` keeps, of the damped ``H + diag(d)``, every diagonal block and the
off-diagonal blocks of the edges of a spanning tree (forest) of the graph of one variable batch
(the poses): ``M = sum_tree A_e^T A_e + sum_rest blockdiag(A_e^T A_e) + diag(d)``, a sum of
positive semi-definite terms, so ``M`` is positive definite whenever block-Jacobi is. The tree is
the minimum spanning tree with edge weight ``|i - j|`` (the odometry chain where there is one: the
long, weakly anchored chains that make pose graphs ill-conditioned). Other variable batches get
block-Jacobi blocks.

A tree's matrix factors without fill outside the tree when its nodes are eliminated leaves
first. To keep every step a batched block operation, the host plans the elimination once in
*levels* (tree contraction, "rake and compress"): each level eliminates an independent set of
nodes with at most two remaining neighbours (eliminating a node of two neighbours ``a, b``
creates the edge ``a-b``, so the graph stays a tree). A path of ``n`` nodes takes
``log2(n)`` levels (cyclic reduction), not ``n``. Per level, for the eliminated nodes ``v`` with
neighbours ``a <= b``: ``D_a -= E_va^T D_v^-1 E_va``, ``D_b -= ...``, ``E_ab -= E_va^T D_v^-1
E_vb``; a solve is one forward sweep over the levels and one back sweep in reverse. Missing
neighbours point at a dummy node and a zero edge slot, so every index array is static (host
built: ``jax.jit`` and ``torch.compile`` see constants).

Precision. The preconditioners are built and applied in the dtype of the damping they are
given: :func:`~microlie.optim.device.pcg.pcg_step` passes float64 for float32 problems too
(:func:`~microlie.optim.device.schur.step_dtype`), and :func:`coarse_basis`,
:func:`coarse_matrix` and :func:`tree_edges` accumulate in that dtype from the float32
linearisation. The coarse matrix holds the slow modes: on parking-garage its eigenvalues
span 2e-7 to 3e4; factored in float32, with a jitter of a few float32 ``eps`` times its
largest diagonal entry (50 there), it ignores every slow mode, and float32 LM stopped 3.2e-4
above the optimum after 21,000 CG iterations. Where no float64 exists (JAX without
``jax_enable_x64``) the coarse matrix is factored with unit diagonal (Jacobi scaling, the
jitter relative to each diagonal entry): with the jitter relative to the largest entry a
gauge prior of information 1e12 hid every slow mode and float32 LM stopped 1.3e-3 above the
optimum; with the scaling 4.5e-7 (``tests/test_device_precondition.py``). In float64 the
scaling measured worse on sphere2500 (twice to four times the CG iterations) and is not
used.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .pcg import cast
from .problem import DeviceProblem, Linear, add_last, extend, eye_like, transpose
from .schur import step_dtype

__all__ = ["CoarsePlan", "TreePlan", "coarse_basis", "coarse_matrix", "coarse_plan",
           "tree_edges", "tree_plan", "tree_preconditioner", "two_level"]


@dataclass
class _Level:
    v: Any          # (n_l,) eliminated nodes
    a: Any          # (n_l,) first neighbour (dummy when none)
    b: Any          # (n_l,) second neighbour (dummy when none; a <= b)
    sa: Any         # (n_l,) edge slot of v-a (dummy slot when none)
    sb: Any
    fa: Any         # (n_l, 1, 1) bool: the slot stores H[a, v] (v > a): transpose it
    fb: Any
    fill: Any       # (n_l,) slot of the edge a-b (dummy slot unless both exist)


@dataclass
class TreePlan:
    """The host-built plan of a spanning-tree preconditioner (static index arrays).

    Attributes
    ----------
    key : int
        The variable batch of the tree.
    n, dof : int
        Its variable count and dof.
    edges : numpy.ndarray
        ``(T, 2)`` tree edges ``(lo, hi)`` (slots ``0..T-1``; fill slots follow).
    slots : int
        Edge slots, tree and fill (the dummy slot is ``slots``).
    rows : list
        Per factor batch: ``None`` or ``(rows, slots, swap)`` of its factors on tree edges.
    levels : list
        The elimination levels.
    """

    key: int
    n: int
    dof: int
    edges: np.ndarray
    slots: int
    rows: list = field(repr=False)
    levels: list = field(repr=False)

    @property
    def depth(self) -> int:
        """The number of elimination levels."""
        return len(self.levels)


def _candidate_key(problem: DeviceProblem) -> int | None:
    """The variable batch with most between factors inside it (None: none, or landmarks)."""
    if problem.eliminate:
        return None
    count: dict[int, int] = {}
    for t in problem.terms:
        if t.kind == "between" and t.keys[0] == t.keys[1]:
            count[t.keys[0]] = count.get(t.keys[0], 0) + t.m
    if not count:
        return None
    return max(count, key=lambda k: count[k])


def _spanning_tree(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Minimum spanning forest ``(T, 2)`` (lo, hi) with weight ``|i - j|``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import minimum_spanning_tree

    lo, hi = np.minimum(i, j), np.maximum(i, j)
    keep = lo != hi
    lo, hi = lo[keep], hi[keep]
    w = coo_matrix(((hi - lo).astype(np.float64), (lo, hi)), shape=(n, n)).tocsr()
    w.sum_duplicates()
    # duplicates add their weights; restore |i - j| so that parallel edges do not lose out
    r, c = w.nonzero()
    w = coo_matrix(((c - r).astype(np.float64), (r, c)), shape=(n, n)).tocsr()
    t = minimum_spanning_tree(w).tocoo()
    e = np.stack([np.minimum(t.row, t.col), np.maximum(t.row, t.col)], 1).astype(np.int64)
    return e[np.lexsort((e[:, 1], e[:, 0]))]


def _levels(n: int, edges: np.ndarray) -> tuple[list[np.ndarray], int]:
    """Rake-and-compress levels: per level ``(v, a, b, slot_a, slot_b, fill)`` with ``-1``
    for a missing neighbour (and the fill slots numbered after the tree's)."""
    nbr: list[dict[int, int]] = [dict() for _ in range(n)]
    for s, (u, w) in enumerate(edges):
        nbr[int(u)][int(w)] = s
        nbr[int(w)][int(u)] = s
    alive = np.ones(n, dtype=bool)
    remaining = n
    nslot = len(edges)
    out = []
    while remaining:
        taken = np.zeros(n, dtype=bool)
        blocked = np.zeros(n, dtype=bool)
        rows: list[list[int]] = []
        for vv in np.flatnonzero(alive):
            v = int(vv)
            if len(nbr[v]) > 2 or blocked[v]:
                continue
            taken[v] = True
            for u in nbr[v]:
                blocked[u] = True
            ns = sorted(nbr[v].items())
            a, sa = ns[0] if ns else (-1, -1)
            b, sb = ns[1] if len(ns) > 1 else (-1, -1)  # a < b
            rows.append([v, a, b, sa, sb, -1])
        for r in rows:
            v, a, b = r[0], r[1], r[2]
            for u in (a, b):
                if u >= 0:
                    del nbr[u][v]
            if a >= 0 and b >= 0:
                r[5] = nslot
                nbr[a][b] = nslot
                nbr[b][a] = nslot
                nslot += 1
            nbr[v] = {}
            alive[v] = False
        remaining -= len(rows)
        out.append(np.array(rows, dtype=np.int64).reshape(-1, 6))
    return out, nslot


def tree_plan(problem: DeviceProblem) -> TreePlan | None:
    """The spanning-tree plan of a problem's pose batch, built on the host once and cached on
    the problem (``None`` when no variable batch has between factors inside it, or the problem
    has landmarks, whose Schur steps keep their own preconditioner).

    Parameters
    ----------
    problem : DeviceProblem
        The problem.

    Returns
    -------
    TreePlan or None

    Examples
    --------
    >>> import torch
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.precondition import tree_plan
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.from_params(torch.tensor([[0.0, 0, 1, 0]] * 8).double()))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, range(7), range(1, 8), SE2.exp([1.0, 0.0, 0.1])))
    >>> _ = g.add(BetweenFactor(x, [0], [7], SE2.exp([1.0, 0.0, 0.1])))
    >>> plan = tree_plan(DeviceProblem.from_graph(g))
    >>> plan.edges.tolist(), plan.depth   # the odometry chain, eliminated in log2(8) + 1 levels
    ([[0, 1], [1, 2], [2, 3], [3, 4], [4, 5], [5, 6], [6, 7]], 4)
    """
    cache = problem.plans
    if "tree" in cache:
        return cache["tree"]
    key = _candidate_key(problem)
    if key is None:
        cache["tree"] = None
        return None
    be = problem.backend
    blk = problem.blocks[key]
    n = blk.n
    ii, jj = [], []
    for t in problem.terms:
        if t.kind == "between" and t.keys[0] == key and t.keys[1] == key:
            ii.append(np.asarray(t.idx_np[0], dtype=np.int64).reshape(-1))
            jj.append(np.asarray(t.idx_np[1], dtype=np.int64).reshape(-1))
    edges = _spanning_tree(n, np.concatenate(ii), np.concatenate(jj))
    slot_of = {(int(u), int(w)): s for s, (u, w) in enumerate(edges)}
    rows: list = []
    for t in problem.terms:
        if not (t.kind == "between" and t.keys[0] == key and t.keys[1] == key):
            rows.append(None)
            continue
        i = np.asarray(t.idx_np[0], dtype=np.int64).reshape(-1)
        j = np.asarray(t.idx_np[1], dtype=np.int64).reshape(-1)
        s = np.array([slot_of.get((int(min(a, b)), int(max(a, b))), -1)
                      for a, b in zip(i, j, strict=True)], dtype=np.int64)
        on = np.flatnonzero(s >= 0)
        rows.append(None if not len(on) else
                    (be.index(on), be.index(s[on]), be.asarray((i[on] > j[on])[:, None, None]
                                                               .astype(np.float64))))
    lv, slots = _levels(n, edges)
    levels = []
    for r in lv:
        v, a, b, sa, sb, fill = (r[:, c] for c in range(6))
        swap_a = (a >= 0) & (v > a)
        swap_b = (b >= 0) & (v > b)
        a, b = np.where(a < 0, n, a), np.where(b < 0, n, b)
        sa, sb, fill = (np.where(x < 0, slots, x) for x in (sa, sb, fill))
        levels.append(_Level(be.index(v), be.index(a), be.index(b), be.index(sa), be.index(sb),
                             be.asarray(swap_a[:, None, None].astype(np.float64)),
                             be.asarray(swap_b[:, None, None].astype(np.float64)),
                             be.index(fill)))
    plan = TreePlan(key, n, blk.dof, edges, slots, rows, levels)
    cache["tree"] = plan
    return plan


def tree_edges(problem: DeviceProblem, plan: TreePlan, lin: Linear) -> Any:
    """The off-diagonal blocks ``H[lo, hi]`` of the tree edges (zero fill and dummy slots),
    ``(B, slots + 1, dof * dof)``.

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    plan : TreePlan
        From :func:`tree_plan`.
    lin : Linear
        The linearisation.

    Returns
    -------
    array
        Accumulated in :func:`~microlie.optim.device.schur.step_dtype` of the linearisation
        (float64 for float32 problems).

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, BetweenFactor, PriorFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.precondition import tree_plan, tree_edges
    >>> g = FactorGraph()
    >>> x = g.add_variables(torch.zeros((2, 1)).double())
    >>> _ = g.add(PriorFactor(x, 0, [0.0]))
    >>> _ = g.add(BetweenFactor(x, [1], [0], [1.0]))     # r = x0 - x1 - 1: H[0, 1] = -1
    >>> p = DeviceProblem.from_graph(g)
    >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    >>> tree_edges(p, tree_plan(p), p.linearize(th, [a[None] for a in p.initial()])).tolist()
    [[[-1.0], [0.0]]]
    """
    be = problem.backend
    B = lin.e[0].shape[0]
    d = plan.dof
    wide = step_dtype(be, lin.e[0].dtype)
    out = be.zeros((B, plan.slots + 1, d * d), like=cast(be, lin.e[0][:, :1, :1], wide))
    for A, r in zip(lin.A, plan.rows, strict=True):
        if r is None:
            continue
        on, slot, swap = r
        Ai = cast(be, be.take(A[0], on, axis=1), wide)
        Aj = cast(be, be.take(A[1], on, axis=1), wide)
        C = transpose(be, Ai) @ Aj                              # H[i, j]
        C = swap * transpose(be, C) + (1.0 - swap) * C          # H[lo, hi]
        out = be.scatter_add(out, slot, C.reshape(B, -1, d * d))
    return out


def damped_tree_blocks(problem: DeviceProblem, plan: TreePlan, blocks: list[Any],
                       damping: Any) -> Any:
    """``H``'s diagonal blocks of the tree batch plus the damping (an identity block for fixed
    variables, a unit diagonal for held components), padded with an identity dummy node:
    ``(B, n + 1, dof, dof)``."""
    be = problem.backend
    B = damping.shape[0]
    ext = extend(be, damping)
    one = be.zeros((B, problem.size + 1), like=damping)
    one = add_last(be, one, problem._sink, be.full((B, 1), 1.0, dtype=damping.dtype))
    ext = ext + one
    cm = problem._colmap[plan.key]
    dd = be.take(ext, cm.reshape(-1), axis=-1).reshape(B, plan.n, plan.dof)
    blk = blocks[plan.key]
    eye = eye_like(be, blk)
    D = blk + eye * dd[..., None, :]
    pad = be.zeros((B, 1, plan.dof, plan.dof), like=D) + eye
    return be.xp.concatenate([D, pad], axis=1) if be.name == "jax" else be.xp.cat([D, pad], 1)


def _factor(problem: DeviceProblem, plan: TreePlan, D: Any, E: Any) -> list[tuple]:
    be = problem.backend
    B, d = D.shape[0], plan.dof
    D = D.reshape(B, plan.n + 1, d * d)
    out = []
    for lv in plan.levels:
        nl = lv.v.shape[0]
        Dinv = be.inv_spd(be.take(D, lv.v, axis=1).reshape(B, nl, d, d))
        Ea = be.take(E, lv.sa, axis=1).reshape(B, nl, d, d)       # stored H[lo, hi]
        Eb = be.take(E, lv.sb, axis=1).reshape(B, nl, d, d)
        Ea = lv.fa * transpose(be, Ea) + (1.0 - lv.fa) * Ea       # H[v, a]
        Eb = lv.fb * transpose(be, Eb) + (1.0 - lv.fb) * Eb
        Fa = transpose(be, Ea) @ Dinv                              # H[a, v] D_v^-1
        Fb = transpose(be, Eb) @ Dinv
        D = be.scatter_add(D, lv.a, -(Fa @ Ea).reshape(B, nl, d * d))
        D = be.scatter_add(D, lv.b, -(Fb @ Eb).reshape(B, nl, d * d))
        E = be.scatter_add(E, lv.fill, -(Fa @ Eb).reshape(B, nl, d * d))
        out.append((Dinv, Ea, Eb, Fa, Fb))
    return out


def _solve(problem: DeviceProblem, plan: TreePlan, fac: list[tuple], r: Any) -> Any:
    """``M^-1 r`` on the tree batch, ``r`` ``(B, n + 1, dof)`` (dummy row last)."""
    be = problem.backend
    for lv, (_, _, _, Fa, Fb) in zip(plan.levels, fac, strict=True):
        rv = be.take(r, lv.v, axis=1)[..., None]
        r = be.scatter_add(r, lv.a, -(Fa @ rv)[..., 0])
        r = be.scatter_add(r, lv.b, -(Fb @ rv)[..., 0])
    z = r * 0.0
    for lv, (Dinv, Ea, Eb, _, _) in zip(reversed(plan.levels), reversed(fac), strict=True):
        za = be.take(z, lv.a, axis=1)[..., None]
        zb = be.take(z, lv.b, axis=1)[..., None]
        rv = be.take(r, lv.v, axis=1)[..., None]
        z = be.scatter_add(z, lv.v, (Dinv @ (rv - Ea @ za - Eb @ zb))[..., 0])
    return z


def tree_preconditioner(problem: DeviceProblem, plan: TreePlan, blocks: list[Any],
                        edges: Any, damping: Any, others: Any) -> Any:
    """``v -> M^-1 v`` for the damped system: the tree factorised once here (per damping),
    block-Jacobi on the other variable batches.

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    plan : TreePlan
        From :func:`tree_plan`.
    blocks : list of arrays
        :func:`~microlie.optim.device.pcg.block_diagonal` of the linearisation.
    edges : array
        :func:`tree_edges` of the linearisation.
    damping : array
        ``(B, size)``.
    others : callable
        ``v -> `` the block-Jacobi product on the other variable batches (zero on the tree
        batch's columns).

    Returns
    -------
    callable
        ``(B, size) -> (B, size)``, in ``damping``'s dtype (``blocks`` and ``edges`` are
        cast to it).

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, BetweenFactor, PriorFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.pcg import block_diagonal
    >>> from microlie.optim.device.precondition import (tree_plan, tree_edges,
    ...                                                 tree_preconditioner)
    >>> g = FactorGraph()
    >>> x = g.add_variables(torch.zeros((3, 1)).double())
    >>> _ = g.add(PriorFactor(x, 0, [0.0]))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], [[1.0], [1.0]]))  # a chain: M = H
    >>> p = DeviceProblem.from_graph(g)
    >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    >>> lin = p.linearize(th, [a[None] for a in p.initial()])
    >>> plan = tree_plan(p)
    >>> M = tree_preconditioner(p, plan, block_diagonal(p, lin), tree_edges(p, plan, lin),
    ...                         torch.zeros((1, 3)).double(), lambda v: 0.0 * v)
    >>> z = M(torch.tensor([[1.0, 0.0, 0.0]]).double())  # H = [[2,-1,0],[-1,2,-1],[0,-1,1]]
    >>> [round(v, 12) for v in z[0].tolist()]
    [1.0, 1.0, 1.0]
    """
    be = problem.backend
    dt = damping.dtype
    D = damped_tree_blocks(problem, plan, [cast(be, b, dt) for b in blocks], damping)
    fac = _factor(problem, plan, D, cast(be, edges, dt))
    cm = problem._colmap[plan.key].reshape(-1)
    B = damping.shape[0]
    zero = be.zeros((B, 1, plan.dof), like=damping)
    cat = be.xp.concatenate if be.name == "jax" else be.xp.cat

    def apply(v: Any) -> Any:
        ext = extend(be, v)
        r = be.take(ext, cm, axis=-1).reshape(B, plan.n, plan.dof)
        z = _solve(problem, plan, fac, cat([r, zero], 1))[:, :plan.n]
        out = be.zeros((B, problem.size + 1), like=v)
        out = add_last(be, out, cm, z.reshape(B, -1))[..., :problem.size]
        return out + others(v)

    return apply


# ---------------------------------------------------------------------- coarse space
@dataclass
class CoarsePlan:
    """The host-built plan of the coarse correction: aggregates of consecutive variables of
    one batch, each moved as one rigid body.

    Attributes
    ----------
    key : int
        The variable batch.
    size : int
        Variables per aggregate.
    aggregates : int
        Their number (the coarse system has ``aggregates * dof`` unknowns).
    """

    key: int
    size: int
    aggregates: int
    dof: int = 0
    agg: Any = field(default=None, repr=False)      # (n,) aggregate of each variable
    ref: Any = field(default=None, repr=False)      # (n,) its reference variable
    pairs: list = field(default_factory=list, repr=False)


#: The coarse system's size the automatic aggregate size aims at (a dense Cholesky per try).
COARSE_MAX = 1500


def coarse_plan(problem: DeviceProblem, size: int = 0) -> CoarsePlan | None:
    """The coarse-space plan of the pose batch (as :func:`tree_plan` chooses it): aggregates of
    ``size`` consecutive variables (``0``: the smallest size, at least 4, that keeps the
    coarse system within :data:`COARSE_MAX` unknowns), cached on the problem.

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    size : int
        Variables per aggregate (``0``: automatic).

    Returns
    -------
    CoarsePlan or None
        ``None`` where :func:`tree_plan` has no pose batch.

    Examples
    --------
    >>> import torch
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.precondition import coarse_plan
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.from_params(torch.tensor([[0.0, 0, 1, 0]] * 10).double()))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, range(9), range(1, 10), SE2.exp([1.0, 0.0, 0.1])))
    >>> coarse_plan(DeviceProblem.from_graph(g), 4)
    CoarsePlan(key=0, size=4, aggregates=3, dof=3)
    """
    name = f"coarse{size}"
    if name in problem.plans:
        return problem.plans[name]
    key = _candidate_key(problem)
    if key is None:
        problem.plans[name] = None
        return None
    be = problem.backend
    blk = problem.blocks[key]
    n, d = blk.n, blk.dof
    s = size if size > 0 else max(4, -(-n * d // COARSE_MAX))
    agg = np.arange(n) // s
    nag = int(agg[-1]) + 1 if n else 0
    ref = np.arange(n) - np.arange(n) % s
    nc = nag * d
    pairs = []
    for t in problem.terms:
        on = [a for a, k in enumerate(t.keys) if k == key]
        ag = {a: agg[np.asarray(t.idx_np[a], dtype=np.int64).reshape(-1)] for a in on}
        tp = []
        for a in on:
            for b in on:
                pos = ((ag[a][:, None, None] * d + np.arange(d)[:, None]) * nc
                       + ag[b][:, None, None] * d + np.arange(d)[None, :])
                tp.append((a, b, be.index(pos.reshape(-1))))
        pairs.append(tp)
    plan = CoarsePlan(key, s, nag, d, be.index(agg), be.index(ref), pairs)
    problem.plans[name] = plan
    return plan


def coarse_basis(problem: DeviceProblem, plan: CoarsePlan, x: list[Any]) -> Any:
    """The prolongation blocks ``P_i = Ad(X_i^-1 X_ref)`` ``(B, n, dof, dof)``: the right
    tangent step of variable ``i`` when its aggregate moves rigidly by ``c`` in the frame of
    its reference variable (identity for vectors); rows of fixed variables and held
    components zero.

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    plan : CoarsePlan
        From :func:`coarse_plan`.
    x : list of arrays
        ``(B, n_k, param_dim)`` parameters.

    Returns
    -------
    array
        In :func:`~microlie.optim.device.schur.step_dtype` of ``x`` (float64 for float32
        problems).

    Examples
    --------
    >>> import torch
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.precondition import coarse_plan, coarse_basis
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.from_params(torch.tensor([[0.0, 0, 1, 0], [1.0, 0, 1, 0]])
    ...                                     .double()))
    >>> _ = g.add(BetweenFactor(x, [0], [1], SE2.exp([1.0, 0.0, 0.0])))
    >>> p = DeviceProblem.from_graph(g, gauge="none")
    >>> P = coarse_basis(p, coarse_plan(p, 2), [a[None] for a in p.initial()])
    >>> (P[0, 1] + 0.0).tolist()   # a rotation about pose 0 moves pose 1 sideways
    [[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]]
    """
    be = problem.backend
    blk = problem.blocks[plan.key]
    X = cast(be, x[plan.key], step_dtype(be, x[plan.key].dtype))
    ref = be.take(X, plan.ref, axis=-2)
    if blk.vector:
        P = be.zeros((*X.shape[:-1], blk.dof, blk.dof), like=X) + eye_like(
            be, be.zeros((blk.dof, blk.dof), like=X))
    else:
        G = blk.group
        P = G.from_params(X, check=False).inverse().compose(
            G.from_params(ref, check=False)).adjoint()
    mask = be.asarray((blk.cols < problem.size).astype(np.float64)[..., None])
    return P * mask


def coarse_matrix(problem: DeviceProblem, plan: CoarsePlan, lin: Linear, P: Any) -> Any:
    """``P^T J^T J P`` ``(B, nc * nc)`` over the factors' arguments in the plan's batch.

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    plan : CoarsePlan
        From :func:`coarse_plan`.
    lin : Linear
        The linearisation.
    P : array
        :func:`coarse_basis`.

    Returns
    -------
    array
        Accumulated in :func:`~microlie.optim.device.schur.step_dtype` of the linearisation
        (float64 for float32 problems).
    """
    be = problem.backend
    B = lin.e[0].shape[0]
    nc = plan.aggregates * plan.dof
    wide = step_dtype(be, lin.e[0].dtype)
    P = cast(be, P, wide)
    out = be.zeros((B, nc * nc), like=P)
    for t, A, tp in zip(problem.terms, lin.A, plan.pairs, strict=True):
        if not tp:
            continue
        AP = {}
        for a, _, _ in tp:
            if a not in AP:
                AP[a] = cast(be, A[a], wide) @ be.take(P, t.idx[a], axis=1)  # (B, m, dim, dof)
        for a, b, pos in tp:
            C = transpose(be, AP[a]) @ AP[b]
            out = add_last(be, out, pos, C.reshape(B, -1))
    return out


def _coarse_inverse(problem: DeviceProblem, plan: CoarsePlan, Ac: Any, P: Any,
                    damping: Any) -> Any:
    """``(P^T (H + diag(d)) P)^-1`` ``(B, nc, nc)`` (a jitter of a few ``eps`` of its dtype,
    relative to the largest diagonal entry in float64 and to each entry (Jacobi scaling) in
    float32, keeps the Cholesky of a gauge-free problem defined)."""
    be = problem.backend
    B, d = damping.shape[0], plan.dof
    nc = plan.aggregates * d
    cm = problem._colmap[plan.key].reshape(-1)
    dd = be.take(extend(be, damping), cm, axis=-1).reshape(B, -1, d)      # (B, n, dof)
    PtDP = transpose(be, P) @ (dd[..., None] * P)                           # (B, n, dof, dof)
    flat = be.zeros((B, plan.aggregates, d * d), like=damping)
    flat = be.scatter_add(flat, plan.agg, PtDP.reshape(B, -1, d * d))
    eye = eye_like(be, be.zeros((nc, nc), like=damping))
    A = Ac.reshape(B, nc, nc)
    blocks = flat.reshape(B, plan.aggregates, d, d)
    bd = be.zeros((B, nc, nc), like=damping)
    # the aggregate blocks on the diagonal: a scatter into the flat matrix
    idx = ((np.arange(plan.aggregates)[:, None, None] * d + np.arange(d)[:, None]) * nc
           + np.arange(plan.aggregates)[:, None, None] * d + np.arange(d)[None, :])
    bd = add_last(be, bd.reshape(B, -1), be.index(idx.reshape(-1)),
                  blocks.reshape(B, -1)).reshape(B, nc, nc)
    A = A + bd
    diag = A.diagonal(dim1=-2, dim2=-1) if be.name == "torch" else \
        be.xp.diagonal(A, axis1=-2, axis2=-1)
    eps = float(np.finfo(np.float64 if A.dtype.itemsize == 8 else np.float32).eps)
    if A.dtype.itemsize == 8:
        # float64 (the float32 problems' preconditioner too, where float64 exists): a jitter
        # relative to the largest diagonal entry. Measured better than the scaling below on
        # sphere2500 float32 (222 CG iterations on torch and 332 on JAX against 422 and
        # 1479; parking-garage 1067 / 1626 against 591 / 462; benchmarks/device_engine.py)
        scale = diag.max(-1)
        scale = scale.values if be.name == "torch" and hasattr(scale, "values") else scale
        jitter = 10.0 * eps * nc * scale
        A = A + eye * (jitter[:, None, None] + be.where(diag == 0, 1.0, 0.0)[..., None])
        return be.inv_spd(A)
    # float32 only (JAX without jax_enable_x64): factored with unit diagonal (Jacobi scaling
    # A = D S D, D = diag(A)^1/2), the jitter relative to each entry's own scale: relative to
    # the largest, a gauge prior of information 1e12 hid every slow mode and the solve ended
    # 1.3e-3 above the optimum (tests/test_device_precondition.py)
    sc = 1.0 / be.xp.sqrt(be.where(diag > 0, diag, 1.0))
    S = A * sc[..., :, None] * sc[..., None, :]
    S = S + eye * (10.0 * eps * nc + be.where(diag == 0, 1.0, 0.0)[..., None])
    return be.inv_spd(S) * sc[..., :, None] * sc[..., None, :]


def _coarse_apply(problem: DeviceProblem, plan: CoarsePlan, P: Any, Ainv: Any,
                  v: Any) -> Any:
    """``P A_c^-1 P^T v`` ``(B, size)``."""
    be = problem.backend
    B, d = v.shape[0], plan.dof
    cm = problem._colmap[plan.key].reshape(-1)
    vk = be.take(extend(be, v), cm, axis=-1).reshape(B, -1, d, 1)
    w = (transpose(be, P) @ vk)[..., 0]                                   # (B, n, dof)
    u = be.scatter_add(be.zeros((B, plan.aggregates, d), like=v), plan.agg, w)
    y = (Ainv @ u.reshape(B, -1, 1)).reshape(B, plan.aggregates, d)
    z = (P @ be.take(y, plan.agg, axis=1)[..., None])[..., 0]
    out = be.zeros((B, problem.size + 1), like=v)
    return add_last(be, out, cm, z.reshape(B, -1))[..., :problem.size]


def two_level(problem: DeviceProblem, plan: CoarsePlan, P: Any, Ac: Any, damping: Any,
              smoother: Any) -> Any:
    """The additive two-level preconditioner ``v -> S^-1 v + P A_c^-1 P^T v``: a smoother
    (block-Jacobi or the tree) plus the exact solve of the damped system restricted to rigid
    motions of the aggregates (:func:`coarse_basis`), the slow modes of pose graphs (long
    chains bending as wholes) that local preconditioners leave to many CG iterations.

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    plan : CoarsePlan
        From :func:`coarse_plan`.
    P, Ac : array
        :func:`coarse_basis` and :func:`coarse_matrix` at the linearisation point.
    damping : array
        ``(B, size)``.
    smoother : callable
        ``v -> S^-1 v``.

    Returns
    -------
    callable
        In ``damping``'s dtype (``P`` and ``Ac`` are cast to it).

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, BetweenFactor, PriorFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.precondition import (coarse_plan, coarse_basis,
    ...                                                 coarse_matrix, two_level)
    >>> g = FactorGraph()
    >>> x = g.add_variables(torch.zeros((4, 1)).double())
    >>> _ = g.add(PriorFactor(x, 0, [0.0]))
    >>> _ = g.add(BetweenFactor(x, [0, 1, 2], [1, 2, 3], [[1.0]] * 3))
    >>> p = DeviceProblem.from_graph(g)
    >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    >>> xs = [a[None] for a in p.initial()]
    >>> plan = coarse_plan(p, 4)              # one aggregate: the coarse space is x = c
    >>> P = coarse_basis(p, plan, xs)
    >>> Ac = coarse_matrix(p, plan, p.linearize(th, xs), P)   # 1^T H 1 = 1 (the prior)
    >>> M = two_level(p, plan, P, Ac, torch.zeros((1, 4)).double(), lambda v: 0.0 * v)
    >>> [round(v, 9) for v in M(torch.ones((1, 4)).double())[0].tolist()]
    [4.0, 4.0, 4.0, 4.0]
    """
    be = problem.backend
    P, Ac = cast(be, P, damping.dtype), cast(be, Ac, damping.dtype)
    Ainv = _coarse_inverse(problem, plan, Ac, P, damping)

    def apply(v: Any) -> Any:
        return smoother(v) + _coarse_apply(problem, plan, P, Ainv, v)

    return apply
