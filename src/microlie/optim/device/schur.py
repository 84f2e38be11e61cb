"""Exact Schur-complement steps for bundle adjustment on a device (Ceres' ``DENSE_SCHUR``):
the landmarks are eliminated block by block and the reduced camera system

``S = H_cc + D_c - H_cp (H_pp + D_p)^-1 H_pc``

is formed densely over the kept (camera) columns and factored by Cholesky. With few cameras
(``S`` of a few thousand columns at most) this is an exact LM step for the price of one
linearisation, where Schur PCG needs tens to hundreds of matrix-free products per step.

Assembly. The kept arguments of each observation (its camera: rotation, translation,
intrinsics...) form one *super-node* of ``dc`` columns; with ``A_c`` ``(dim, dc)`` and
``A_p`` ``(dim, 3)`` the observation's whitened Jacobians, ``Y = A_c^T A_p`` and
``Z = Y P`` (``P`` the inverse damped landmark block),

* ``H_cc``: ``A_c^T A_c`` summed per super-node (one segment sum), then added to ``S``;
* the elimination: ``-Z_a Y_b^T`` for every ordered pair ``(a, b)`` of observations of one
  landmark, summed per pair of super-nodes (one segment sum), then added to ``S``.

Every index array (pairs, segments, positions in ``S``) is built once on the host from the
problem's structure (:func:`schur_plan`): ``jax.jit`` and ``torch.compile`` see constants.

Precision. A float32 problem keeps float32 residuals, Jacobians, gradient and diagonal blocks
(the linearisation), but its step is computed in float64 (:func:`step_dtype`): the landmark
inverses, the reduced system's accumulation, its Cholesky factorisation, the back-substitution
and the refinement's residual; the step is returned in float32. Done in float32, the
ill-conditioned reduced system (problem-49-7776: 441 x 441) gives steps whose LM ends
5e-4 above the optimum; in float64, 2e-5 (the acceptance is 1e-4). On JAX this needs
``jax_enable_x64`` (without it float64 does not exist and the step stays float32).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .problem import DeviceProblem, Linear, add_last, extend, eye_like, transpose

__all__ = ["SchurPlan", "schur_fits", "schur_plan", "reduced_system", "schur_step",
           "step_dtype", "SCHUR_DENSE_MAX", "SCHUR_PAIRS_MAX"]

#: ``linear="auto"`` takes exact Schur steps up to this many kept (camera) unknowns...
SCHUR_DENSE_MAX = 3000
#: ... and this many observation pairs (the products ``Z_a Y_b^T`` formed per step).
SCHUR_PAIRS_MAX = 4_000_000


@dataclass
class _SuperTerm:
    """One factor batch with kept arguments: its super-nodes and their place in ``S``."""

    term: int
    kept: list[int]          # argument positions of the kept (camera) arguments
    land: int | None         # argument position of the eliminated argument
    dc: int
    nsup: int
    sup_np: np.ndarray       # (m,) super-node of each observation
    cols: np.ndarray         # (nsup, dc) reduced columns
    diag: Any = None         # _Gram of H_cc: the pairs (a, a) per super-node


@dataclass
class _Gram:
    """Segment sums ``sum_{(a, b) in seg} U_a V_b^T`` of observation pairs, computed in
    chunks of ``K`` pairs of one segment each (a batched product with an inner dimension of
    ``K r``, then a segment sum of the chunks); pairs padded with a zero row."""

    t: int                   # index into SchurPlan.terms of U's and V's factor batches
    u: int
    pa: Any                  # backend (nchunk * K,) rows of U (m_t: the zero row)
    pb: Any                  # backend (nchunk * K,) rows of V
    cseg: Any                # backend (nchunk,) segment of each chunk
    nchunk: int
    K: int
    nseg: int
    flat: Any                # backend (nseg * dc_t * dc_u,) positions in the flat S
    count: int               # pairs (without the padding)
    flat_t: Any = None       # symmetric: positions of the transposed blocks (sink: none)


#: Pairs per chunk of a segment Gram product.
CHUNK = 32


def _gram(problem: DeviceProblem, t: int, u: int, pa: np.ndarray, pb: np.ndarray,
          key: np.ndarray, ct_all: np.ndarray, cu_all: np.ndarray, nu: int, ma: int,
          mb: int, n1: int, sym: bool = False) -> _Gram:
    """The chunked segment-sum plan of pairs ``(pa, pb)`` with destination keys
    ``key = row * nu + col`` (super-nodes), padded with the zero rows ``ma``/``mb``. With
    ``sym`` (a symmetric sum: the pair ``(b, a)`` is there for every ``(a, b)``) only the
    pairs with ``row <= col`` are formed, and the blocks with ``row < col`` are added
    transposed too."""
    be = problem.backend
    if sym:
        up = key // nu <= key % nu
        pa, pb, key = pa[up], pb[up], key[up]
    order = np.argsort(key, kind="stable")
    pa, pb, key = pa[order], pb[order], key[order]
    ukey, seg = np.unique(key, return_inverse=True)
    seg = seg.reshape(-1)
    cnt = np.bincount(seg, minlength=len(ukey))
    nch = -(-cnt // CHUNK)                                  # chunks per segment
    slots = np.full(int(nch.sum()) * CHUNK, -1, dtype=np.int64)
    start_slot = np.concatenate([[0], np.cumsum(nch)[:-1]]) * CHUNK
    start_pair = np.concatenate([[0], np.cumsum(cnt)[:-1]])
    pos = start_slot[seg] + (np.arange(len(seg)) - start_pair[seg])
    slots[pos] = np.arange(len(seg))
    A = np.where(slots >= 0, pa[np.maximum(slots, 0)], ma)
    Bv = np.where(slots >= 0, pb[np.maximum(slots, 0)], mb)
    cseg = np.repeat(np.arange(len(ukey)), nch)
    ct, cu = ct_all[ukey // nu], cu_all[ukey % nu]
    flat = (ct[:, :, None] * n1 + cu[:, None, :]).reshape(-1)
    flat_t = None
    if sym:
        ft = cu[:, None, :] * n1 + ct[:, :, None]              # entry (p, q) -> (q, p)
        ft[ukey // nu == ukey % nu] = n1 * n1 - 1              # diagonal blocks: the sink
        flat_t = be.index(ft.reshape(-1))
    return _Gram(t, u, be.index(A), be.index(Bv), be.index(cseg), len(cseg), CHUNK,
                 len(ukey), be.index(flat), len(pa), flat_t)


@dataclass
class SchurPlan:
    """The static structure of the reduced camera system of a problem with landmarks.

    Attributes
    ----------
    kept : array
        Backend ``(nk,)`` global columns of ``S`` (every column not eliminated).
    nk : int
        The order of ``S``.
    terms : list
        Per factor batch with kept arguments: super-nodes and positions in ``S``.
    pairs : list
        Per pair of factor batches seeing one landmark batch: the chunked observation
        pairs.
    pairs_count : int
        The number of observation pairs formed per step (one of ``(a, b)`` and ``(b, a)``).
    """

    kept: Any
    nk: int
    terms: list
    pairs: list
    pairs_count: int


def schur_plan(problem: DeviceProblem) -> SchurPlan:
    """The reduced camera system's structure (built on the host once, then cached on the
    problem).

    Parameters
    ----------
    problem : DeviceProblem
        A problem with landmarks (``problem.eliminate`` not empty).

    Returns
    -------
    SchurPlan

    Raises
    ------
    ValueError
        ``problem`` has no landmarks to eliminate.

    Examples
    --------
    >>> import torch
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.schur import schur_plan
    >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
    >>> _, start = synthetic_scene(3, 10, seed=0)
    >>> g = bundle_graph(start, fix_cameras=[0], fix_points=[0]).graph
    >>> plan = schur_plan(DeviceProblem.from_graph(g, backend="torch"))
    >>> plan.nk, len(plan.terms), plan.pairs_count   # 2 x 6 + 3 x 3 columns; 10 x 6 pairs
    (21, 1, 60)
    """
    cached = getattr(problem, "_schur_plan", None)
    if cached is not None:
        return cached
    elim = problem.eliminate
    if not elim:
        raise ValueError("linear='schur': the problem has no landmarks to eliminate (variable "
                         "batches that share no factor); use linear='dense' or 'pcg'")
    be = problem.backend
    N = problem.size
    land_cols = np.zeros(N + 1, dtype=bool)
    for k in elim:
        land_cols[problem.blocks[k].cols.reshape(-1)] = True
    land_cols[N] = True
    kept = np.nonzero(~land_cols)[0]
    nk = len(kept)
    red = np.full(N + 1, nk, dtype=np.int64)
    red[kept] = np.arange(nk)
    n1 = nk + 1
    terms: list[_SuperTerm] = []
    for ti, t in enumerate(problem.terms):
        kept_args = [a for a, k in enumerate(t.keys) if k not in elim]
        if not kept_args:
            continue
        land = next((a for a, k in enumerate(t.keys) if k in elim), None)
        kidx = np.stack([t.idx_np[a] for a in kept_args], 1)
        uniq, first, sup = np.unique(kidx, axis=0, return_index=True, return_inverse=True)
        sup = sup.reshape(-1)
        cols = np.concatenate([red[t.cols[a][first]] for a in kept_args], 1)  # (nsup, dc)
        st = _SuperTerm(ti, kept_args, land, cols.shape[1], len(uniq), sup, cols)
        a = np.arange(t.m)
        st.diag = _gram(problem, len(terms), len(terms), a, a, sup * st.nsup + sup, cols,
                        cols, st.nsup, t.m, t.m, n1)
        terms.append(st)
    pairs: list[_Gram] = []
    total = 0
    for i, st in enumerate(terms):
        for j, su in enumerate(terms):
            ts, tu = problem.terms[st.term], problem.terms[su.term]
            if st.land is None or su.land is None or ts.keys[st.land] != tu.keys[su.land]:
                continue
            pa, pb = _observation_pairs(ts.idx_np[st.land], tu.idx_np[su.land],
                                        problem.blocks[ts.keys[st.land]].n)
            key = st.sup_np[pa] * su.nsup + su.sup_np[pb]
            gm = _gram(problem, i, j, pa, pb, key, st.cols, su.cols, su.nsup, ts.m, tu.m, n1,
                       sym=i == j)
            pairs.append(gm)
            total += gm.count
    plan = SchurPlan(be.index(kept), nk, terms, pairs, total)
    problem._schur_plan = plan
    return plan


def schur_fits(problem: DeviceProblem) -> bool:
    """Whether exact Schur steps suit ``problem`` (what ``linear="auto"`` asks): it has
    landmarks, at most :data:`SCHUR_DENSE_MAX` kept unknowns and at most
    :data:`SCHUR_PAIRS_MAX` observation pairs (counted without building the plan).

    Parameters
    ----------
    problem : DeviceProblem
        The problem.

    Returns
    -------
    bool

    Examples
    --------
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.schur import schur_fits
    >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
    >>> _, start = synthetic_scene(3, 10, seed=0)
    >>> schur_fits(DeviceProblem.from_graph(bundle_graph(start).graph, gauge="none",
    ...                                     backend="torch"))
    True
    """
    elim = problem.eliminate
    if not elim:
        return False
    land = sum(int((problem.blocks[k].cols < problem.size).sum()) for k in elim)
    if problem.size - land > SCHUR_DENSE_MAX:
        return False
    count = 0
    for k in elim:
        seen = [t.idx_np[t.keys.index(k)] for t in problem.terms
                if k in t.keys and len(t.keys) > 1]
        if seen:
            c = np.bincount(np.concatenate(seen), minlength=problem.blocks[k].n)
            count += int((c.astype(np.int64) ** 2).sum())
    return count <= SCHUR_PAIRS_MAX


def _observation_pairs(la: np.ndarray, lb: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Every ``(a, b)`` with ``la[a] == lb[b]`` (observations of one landmark), grouped by
    landmark."""
    oa = np.argsort(la, kind="stable")
    ob = np.argsort(lb, kind="stable")
    cb = np.bincount(lb, minlength=n)
    sb = np.concatenate([[0], np.cumsum(cb)[:-1]])
    rep = cb[la[oa]]                         # partners of each a
    pa = np.repeat(oa, rep)
    start = np.repeat(sb[la[oa]], rep)
    within = np.arange(len(pa)) - np.repeat(np.cumsum(rep) - rep, rep)
    pb = ob[start + within]
    return pa.astype(np.int64), pb.astype(np.int64)


def _landmark_inverses(problem: DeviceProblem, blocks: list[Any], damping: Any) -> dict:
    """``(H_pp + D_p)^-1`` per eliminated batch ``(B, n, dof, dof)`` (fixed landmarks: the
    identity)."""
    be = problem.backend
    ext = extend(be, damping)
    N = problem.size
    sink = np.zeros(N + 1)
    sink[N] = 1.0
    ext = ext + be.asarray(sink)
    out = {}
    for k in problem.eliminate:
        b = problem.blocks[k]
        d = be.take(ext, problem._colmap[k].reshape(-1), axis=-1).reshape(-1, b.n, b.dof)
        out[k] = be.inv_spd(blocks[k] + eye_like(be, blocks[k]) * d[..., None, :])
    return out


def _apply_landmarks(problem: DeviceProblem, inv: dict, v: Any) -> Any:
    """``(H_pp + D_p)^-1 v`` on the eliminated columns of ``v`` ``(B, size)``, zero
    elsewhere."""
    be = problem.backend
    ext = extend(be, v)
    B = v.shape[0]
    out = be.zeros((B, problem.size + 1), like=v)
    for k, Mi in inv.items():
        b = problem.blocks[k]
        cm = problem._colmap[k].reshape(-1)
        vk = be.take(ext, cm, axis=-1).reshape(B, b.n, b.dof)
        out = add_last(be, out, cm, (Mi @ vk[..., None])[..., 0].reshape(B, -1))
    return out[..., :problem.size]


def reduced_system(problem: DeviceProblem, lin: Linear, inv: dict, damping: Any) -> Any:
    """The damped reduced camera system ``S`` ``(B, nk, nk)`` (columns ``plan.kept``).

    Parameters
    ----------
    problem : DeviceProblem
        A problem with landmarks.
    lin : Linear
        Its linearisation.
    inv : dict
        Inverse damped landmark blocks per eliminated batch ``(B, n, dof, dof)``.
    damping : array
        ``(B, size)`` added to the diagonal of ``H``.

    Returns
    -------
    array
        ``S = H_cc + D_c - H_cp (H_pp + D_p)^-1 H_pc``.
    """
    be = problem.backend
    plan = schur_plan(problem)
    nk, n1 = plan.nk, plan.nk + 1
    B = lin.e[0].shape[0]
    S = be.zeros((B, n1 * n1), like=lin.e[0])
    cat = be.xp.concatenate if be.name == "jax" else be.xp.cat
    Y: list[Any] = []
    Z: list[Any] = []
    for st in plan.terms:
        t = problem.terms[st.term]
        A = lin.A[st.term]
        Ac = cat([A[a] for a in st.kept], -1) if len(st.kept) > 1 else A[st.kept[0]]
        S = add_last(be, S, st.diag.flat, _segment_gram(be, st.diag, Ac, Ac))
        if st.land is None:
            Y.append(None)
            Z.append(None)
            continue
        yt = transpose(be, A[st.land]) @ Ac                          # (B, m, 3, dc): Y^T
        P = be.take(inv[t.keys[st.land]], t.idx[st.land], axis=1)   # (B, m, 3, 3)
        Y.append(yt)
        Z.append(P @ yt)                                             # Z^T = P Y^T
    for pr in plan.pairs:
        c = -_segment_gram(be, pr, Z[pr.t], Y[pr.u])
        S = add_last(be, S, pr.flat, c)
        if pr.flat_t is not None:
            S = add_last(be, S, pr.flat_t, c)
    S = S.reshape(B, n1, n1)[:, :nk, :nk]
    dk = be.take(damping, plan.kept, axis=-1)
    return S + eye_like(be, S) * dk[..., None, :]


def _segment_gram(be: Any, gm: _Gram, Ut: Any, Vt: Any) -> Any:
    """``sum_{(a, b) in seg} U_a V_b^T`` per segment, flattened ``(B, nseg * p * q)``, from
    the transposed factors ``Ut`` ``(B, m, r, p)`` and ``Vt`` ``(B, m', r, q)`` (a chunk's
    gathered rows are then one ``(K r, p)`` matrix: no transposing copy)."""
    B, r, p, q = Ut.shape[0], Ut.shape[2], Ut.shape[3], Vt.shape[3]
    if be.name == "torch":
        t = be.xp
        ua = _rows(t, Ut, gm.pa).reshape(B * gm.nchunk, gm.K * r, p)
        vb = _rows(t, Vt, gm.pb).reshape(B * gm.nchunk, gm.K * r, q)
        c = t.bmm(ua.transpose(1, 2), vb).reshape(B, gm.nchunk, p * q)
        out = be.zeros((B, gm.nseg, p * q), like=c).index_add(1, gm.cseg, c)
        return out.reshape(B, -1)
    import jax.numpy as jnp

    Uz = jnp.concatenate([Ut, jnp.zeros((B, 1, r, p), Ut.dtype)], 1)
    Vz = jnp.concatenate([Vt, jnp.zeros((B, 1, r, q), Vt.dtype)], 1)
    ua = jnp.take(Uz, gm.pa, axis=1, mode="clip").reshape(B, gm.nchunk, gm.K * r, p)
    vb = jnp.take(Vz, gm.pb, axis=1, mode="clip").reshape(B, gm.nchunk, gm.K * r, q)
    c = jnp.einsum("bnkp,bnkq->bnpq", ua, vb).reshape(B, gm.nchunk, p * q)
    out = jnp.zeros((B, gm.nseg, p * q), c.dtype).at[:, gm.cseg].add(c)
    return out.reshape(B, -1)


def _rows(t: Any, X: Any, idx: Any) -> Any:
    """Rows ``idx`` of ``X`` ``(B, m, ...)`` along axis 1, index ``m`` a zero row (torch:
    one gather along the leading axis of a 2-D view, the fast path)."""
    B, m = X.shape[0], X.shape[1]
    flat = t.cat([X.reshape(B, m, -1), X.new_zeros((B, 1, X[0, 0].numel()))], 1)
    flat = flat.reshape(B * (m + 1), -1)
    if B > 1:
        idx = (t.arange(B, device=idx.device)[:, None] * (m + 1) + idx[None]).reshape(-1)
    return flat.index_select(0, idx)


def _cholesky(be: Any, S: Any) -> tuple[Any, Any]:
    """The lower Cholesky factor of a batch of SPD matrices and ``ok`` ``(B,)`` (False: not
    positive definite)."""
    if be.name == "torch":
        L, info = be.xp.linalg.cholesky_ex(S)
        return L, info == 0
    L = be.xp.linalg.cholesky(S)
    return L, be.xp.isfinite(L).all((-1, -2))


def _cho_solve(be: Any, L: Any, b: Any) -> Any:
    if be.name == "torch":
        return be.xp.cholesky_solve(b[..., None], L)[..., 0]
    import jax

    return jax.scipy.linalg.cho_solve((L, True), b[..., None])[..., 0]


def step_dtype(be: Any, dtype: Any) -> Any:
    """The dtype the Schur step of a problem of ``dtype`` is computed in: float64 (for
    float32 problems too; on JAX float32 when ``jax_enable_x64`` is off).

    Parameters
    ----------
    be : Backend
        The problem's backend.
    dtype : dtype
        The linearisation's dtype (the backend library's float32 or float64).

    Returns
    -------
    dtype
        The backend library's float64, or ``dtype`` when float64 is unavailable.

    Examples
    --------
    >>> import torch
    >>> from microlie.optim.device.backend import Backend
    >>> from microlie.optim.device.schur import step_dtype
    >>> step_dtype(Backend("torch", "float32"), torch.float32)
    torch.float64
    """
    if be.name == "torch":
        return be.xp.float64
    import jax

    return be.xp.float64 if jax.config.read("jax_enable_x64") else dtype


def schur_step(problem: DeviceProblem, lin: Linear, g: Any, blocks: list[Any],
               damping: Any) -> tuple[Any, Any]:
    """The exact step of ``(H + diag(damping)) dx = -g`` by Schur elimination of the
    landmarks and a dense Cholesky factorisation of the reduced camera system.

    Parameters
    ----------
    problem : DeviceProblem
        A problem with landmarks.
    lin : Linear
        Its linearisation.
    g : array
        ``(B, size)`` gradient.
    blocks : list of arrays
        The diagonal blocks of ``H`` (:func:`~microlie.optim.device.pcg.block_diagonal`).
    damping : array
        ``(B, size)``.

    Returns
    -------
    dx : array
        ``(B, size)``, of ``g``'s dtype (computed in :func:`step_dtype`: float64 for float32
        problems too).
    ok : array
        ``(B,)`` bool: ``S`` was positive definite and the step finite.

    Examples
    --------
    >>> import torch
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.dense import normal_equations
    >>> from microlie.optim.device.pcg import block_diagonal
    >>> from microlie.optim.device.schur import schur_step
    >>> from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene
    >>> _, start = synthetic_scene(3, 10, noise=0.5, perturb=0.05, seed=0)
    >>> g = bundle_graph(start, fix_cameras=[0], fix_points=[0]).graph
    >>> p = DeviceProblem.from_graph(g, backend="torch")
    >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    >>> lin = p.linearize(th, [a[None] for a in p.initial()])
    >>> H, grad = normal_equations(p, lin)
    >>> d = torch.full_like(grad, 1e-3)
    >>> dx, ok = schur_step(p, lin, grad, block_diagonal(p, lin), d)
    >>> ref = torch.linalg.solve(H + torch.diag_embed(d), -grad)   # dense, all columns
    >>> bool(ok), float((dx - ref).abs().max() / ref.abs().max()) < 1e-9
    (True, True)
    """
    be = problem.backend
    dt = g.dtype
    wide = step_dtype(be, dt)
    if wide != dt:              # float32 linearisation, float64 linear algebra

        def up(a: Any) -> Any:
            return a.to(wide) if be.name == "torch" else a.astype(wide)

        lin = Linear([up(e) for e in lin.e], [[up(a) for a in A] for A in lin.A],
                     up(lin.cost))
        g, blocks, damping = up(g), [up(b) for b in blocks], up(damping)
    plan = schur_plan(problem)
    inv = _landmark_inverses(problem, blocks, damping)

    def H(v: Any) -> Any:
        return problem.vjp(lin, problem.jvp(lin, v)) + damping * v

    mc = problem._keep_mask
    mp = 1.0 - mc
    L, ok = _cholesky(be, reduced_system(problem, lin, inv, damping))
    B = g.shape[0]

    def solve(b: Any) -> Any:
        rhs = b - H(_apply_landmarks(problem, inv, b * mp))       # camera rows: reduced rhs
        dck = _cho_solve(be, L, be.take(rhs, plan.kept, axis=-1))
        dc = add_last(be, be.zeros((B, problem.size + 1), like=g), plan.kept, dck)[..., :-1]
        return dc + _apply_landmarks(problem, inv, (b - H(dc)) * mp)

    dx = solve(-g)
    dx = dx + solve(-g - H(dx))      # one step of iterative refinement (residual 30x lower)
    fin = (dx == dx).all(-1) & (dx.abs() < float("inf")).all(-1) if be.name == "torch" \
        else be.xp.isfinite(dx).all(-1)
    dx = dx.to(dt) if be.name == "torch" else dx.astype(dt)
    return dx, ok & fin
