"""A supernodal Cholesky on the block pattern, in NumPy and LAPACK (and one C call with the
optional compiled extension).

Our normal equations have dense ``d x d`` blocks (3 for SE2, 6 for SE3), so the symbolic
analysis works on the block graph (36 times smaller than the scalar one): a minimum-degree
order of the block graph, its elimination tree and column counts computed from the pattern
(:func:`microlie.optim.linalg.ordering.symbolic`), fundamental supernodes merged by relaxed
amalgamation (as CHOLMOD does), the supernodes' row structures (each the union of its columns'
rows and its children's), and, vectorised over all supernodes, the scatter maps of the numeric
phase.
It runs once per pattern (:meth:`SupernodalSolver.analyse`), on the block pattern the caller
hands over (``block_pattern``: :class:`~microlie.optim.core.problem.Problem` does, so the
scalar pattern is never read back, nor even expanded); with the compiled extra the
elimination tree, column counts, supernodes, structures, update pairs and assembly map are
C loops (``microlie._c._symbolic``), else the vectorised NumPy twin above (the same arrays,
tested equal).

The factor is stored as one array of dense panels: supernode ``s`` owns the ``m_s x k_s``
column-major panel of its ``k_s`` columns and their ``m_s`` rows (the ``k_s x k_s`` diagonal
block first). The numeric factorisation is right-looking: scatter the matrix into the panels
(one indexed assignment), then for each supernode in elimination order ``potrf`` on its
diagonal block, ``trsm`` for the rows below, ``syrk`` for the update ``W = L21 L21^T``, and
subtract ``W`` from the panels of its ancestors through precomputed relative row indices.
With the compiled kernels (built by ``pip install microlie`` where a C compiler exists) the
whole loop is one C call on SciPy's own BLAS/LAPACK (``microlie._c._chol``); without it (or
with ``MICROLIE_FAST=0``) the NumPy loop of :mod:`microlie.optim.linalg.cholesky_numpy` runs a
few batched steps per level of the supernodal elimination tree (its own layout of the same
factor). Both compute the same factor (to rounding)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..._fast import compiled as compiled_module
from .base import LinearSolver, SingularSystemError
from .cholesky_numpy import NOT_PD, NumpyLoop
from .ordering import ORDERINGS, graph, minimum_degree_blocks, symbolic

__all__ = ["SupernodalSolver"]

# relaxed amalgamation: (max merged columns, max fraction of explicit zeros)
_RELAX = ((4, 0.8), (16, 0.1), (48, 0.05))



def _compiled() -> Any:
    """The compiled supernode loop (``microlie._c._chol``) or ``None``."""
    return compiled_module("_chol")


def _compiled_symbolic() -> Any:
    """The compiled symbolic analysis (``microlie._c._symbolic``) or ``None``."""
    return compiled_module("_symbolic")


def _supernodes(aptr: np.ndarray, aidx: np.ndarray, nb: int, order: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The NumPy twin of ``microlie._c._symbolic.supernodes``: the postordered order, the
    first block column of each (amalgamated) supernode and the block row structures
    (``brow[brptr[s]:brptr[s + 1]]``, sorted, its own columns first) of the block graph
    ``(aptr, aidx)`` (CSR) under ``order``."""
    import scipy.sparse as sp  # type: ignore[import-untyped]  # the fallback only

    adj = sp.csr_matrix((np.ones(aidx.size), aidx, aptr), shape=(nb, nb))
    sym = symbolic(adj, order)
    parent, count = sym.parent, sym.counts
    nchild = np.bincount(parent[parent >= 0], minlength=nb)
    j = np.arange(1, nb)
    cont = (parent[j - 1] == j) & (nchild[j] == 1) & (count[j - 1] == count[j] + 1)
    sn_start = np.r_[0, j[~cont]].astype(np.int64) if nb else np.zeros(0, np.int64)
    bstart = _amalgamate(sn_start, count, parent, nb)
    key = _structure(bstart, parent, count, sym.lower)
    brptr = np.r_[0, np.cumsum(np.bincount(key // max(nb, 1), minlength=bstart.size))]
    return sym.perm, bstart, brptr.astype(np.int64), key % max(nb, 1)


class SupernodalSolver(LinearSolver):
    """Supernodal Cholesky (NumPy/LAPACK, or one C call with the compiled kernels) on blocks of
    ``block_size`` unknowns (the greatest common divisor of the variables' dimensions).

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.linalg.cholesky import SupernodalSolver
    >>> A = sp.csc_matrix(np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.0], [0.0, 0.0, 2.0]]))
    >>> s = SupernodalSolver()
    >>> s.analyse(A.indptr, A.indices, 3)
    >>> s.factorize(A.data)
    >>> np.round(s.solve(np.array([5.0, 4.0, 2.0])), 12).tolist()
    [1.0, 1.0, 1.0]
    """

    name = "cholesky"

    def __init__(self, compiled: bool | None = None, ordering: str = "auto") -> None:
        """``compiled``: use the C loop (``True``: it must be installed), the NumPy loop
        (``False``), or the C loop when installed (``None``, the default). ``ordering``: the
        fill-reducing order of the block graph, ``"mmd"`` (minimum degree) or ``"auto"`` (the
        same; see :func:`microlie.optim.linalg.ordering.fill_order`)."""
        if ordering not in ORDERINGS:
            raise ValueError(f"unknown ordering {ordering!r}: expected one of {ORDERINGS}")
        self.ordering = ordering
        mod = _compiled() if compiled is not False else None
        if compiled and mod is None:
            raise ImportError("the compiled supernode loop needs microlie._c._chol, built by pip "
                              "install with a C compiler (microlie --version says whether "
                              "it was), and MICROLIE_FAST != 0")
        self._c: Any = mod

    def analyse(self, indptr, indices, n, block_size=1, block_pattern=None):
        self._factored = False
        bs = block_size if block_size > 0 and n % block_size == 0 else 1
        nb = n // bs
        if block_pattern is not None and len(block_pattern[0]) != nb + 1:
            raise ValueError(f"block_pattern must have {nb + 1} block column pointers for "
                             f"blocks of {bs}, got {len(block_pattern[0])}")
        super().analyse(indptr, indices, n, bs, block_pattern)
        # the block pattern: the caller's (nothing is read back), else read from the scalar one
        blocks = self._given_blocks[:2] if self._given_blocks is not None else \
            _blocks(indptr, self.indices, bs)
        self.dense_blocks = blocks is not None
        if blocks is None:  # the block graph of a pattern whose blocks are not dense
            adj = graph(indptr, indices, n, bs)
            aptr, aidx = adj.indptr.astype(np.int64), adj.indices.astype(np.int64)
        else:
            aptr, aidx = blocks
        order = minimum_degree_blocks(aptr, aidx, nb, self.ordering).astype(np.int64)
        sym_c = _compiled_symbolic() if self._c is not None else None
        if sym_c is not None:  # elimination tree, counts, supernodes, structures in C
            perm, _, _, bstart, brptr, brow = sym_c.supernodes(aptr, aidx, order, sum(_RELAX, ()))
        else:
            perm, bstart, brptr, brow = _supernodes(aptr, aidx, nb, order)
        self.sperm = (perm[:, None] * bs + np.arange(bs)).ravel()  # scalar: new -> old
        self._symbolic(perm, bstart, brptr, brow, n, nb, bs, blocks, sym_c)
        self._numpy_plan = None if self._c is not None else NumpyLoop(self)

    def _symbolic(self, perm: np.ndarray, bstart: np.ndarray, brptr: np.ndarray,
                  brow: np.ndarray, n: int, nb: int, bs: int,
                  blocks: tuple[np.ndarray, np.ndarray] | None, sym_c: Any) -> None:
        """Panels, row structures, the assembly map and the update pairs from the block row
        structures of the supernodes (``brow[brptr[s]:brptr[s + 1]]``, sorted: its columns
        first) and, when the pattern is made of dense blocks, its block CSC ``blocks``; the
        maps in C with ``sym_c`` (``microlie._c._symbolic``), else vectorised."""
        ns = bstart.size
        bend = np.r_[bstart[1:], nb]
        sn_of_b = np.repeat(np.arange(ns), bend - bstart)
        bm = np.diff(brptr)
        bk = bend - bstart
        k, m = bk * bs, bm * bs
        c0 = bstart * bs
        px = np.r_[0, np.cumsum(m * k)]
        rows = (brow[:, None] * bs + np.arange(bs)).ravel()
        rptr = brptr * bs
        # supernodal parent: the owner of the first row below the diagonal block
        has = bm > bk
        sparent = np.full(ns, -1, np.int64)
        sparent[has] = sn_of_b[brow[brptr[:-1][has] + bk[has]]]
        self.ns, self.bs, self.nx = ns, bs, int(px[-1])
        self.c0, self.k, self.m, self.px = c0, k, m, px[:-1].copy()
        self.rows, self.rptr, self.sparent = rows, rptr, sparent
        key = None if sym_c is not None else np.repeat(np.arange(ns), bm) * nb + brow
        # assembly: pattern entry e (old numbering) -> its place in the panels, or the dump
        # slot nx for the strict upper triangle
        inv_b = np.empty(nb, np.int64)
        inv_b[perm] = np.arange(nb)
        if blocks is not None and sym_c is not None:
            amap = sym_c.amap(blocks[0], blocks[1], inv_b, sn_of_b, brptr, brow, bstart,
                              self.px, bs, self.nx)
        elif blocks is not None:
            assert key is not None
            amap = _dense_amap(blocks, bs, nb, inv_b, sn_of_b, key, brptr, px, c0, m,
                               self.nx)
        else:  # blocks that are not dense: entry by entry
            inv_s = np.empty(n, np.int64)
            inv_s[self.sperm] = np.arange(n)
            cols_old = np.repeat(np.arange(n), np.diff(self.indptr))
            rn, cn = inv_s[self.indices], inv_s[cols_old]
            low = rn >= cn
            s = sn_of_b[cn[low] // bs]
            gkey = np.repeat(np.arange(ns), m) * n + rows
            pos = np.searchsorted(gkey, s * n + rn[low])
            if pos.size and not np.array_equal(gkey[np.minimum(pos, gkey.size - 1)],
                                               s * n + rn[low]):
                raise AssertionError("supernodal analysis: an entry outside its supernode")
            amap = np.full(self.nnz, self.nx, np.int64)
            amap[low] = px[s] + (cn[low] - c0[s]) * m[s] + pos - rptr[s]
        # int32 when it fits (half the memory; the compiled loop takes either)
        self.amap = amap.astype(np.int32, copy=False) if self.nx < 2**31 - 1 else amap
        u = (m - k)
        self.wsize = int((u * u).max()) if ns else 0
        self.usize = int(u.max()) if ns else 0
        # the diagonal of L in the compiled layout (column c of supernode s at px + c m + c)
        sid = np.repeat(np.arange(ns), k)
        col = np.arange(n) - np.repeat(c0, k)
        self._ldiag = px[:-1][sid] + col * (m[sid] + 1)
        if sym_c is not None:
            pptr, pt, pa, pb, relptr, relb = sym_c.updates(brptr, brow, bstart, nb)
            self.rel, self.relptr, self.pptr = relb, relptr, pptr
            self.pt, self.pa, self.pb = pt, pa * bs, pb * bs
            return
        assert key is not None
        # update pairs (s, t): the rows below s's diagonal block owned by ancestor t form the
        # run [a, b) of s's below rows; rel are the local rows in t of s's below rows a..u-1
        bu = bm - bk
        blocal = np.arange(brow.size) - np.repeat(brptr[:-1], bm)  # index within s
        isb = blocal >= np.repeat(bk, bm)
        b_s = np.repeat(np.arange(ns), bm)[isb]
        b_row = brow[isb]
        b_t = sn_of_b[b_row]
        b_i = blocal[isb] - np.repeat(bk, bm)[isb]  # index among s's below rows
        new = np.r_[True, (b_s[1:] != b_s[:-1]) | (b_t[1:] != b_t[:-1])] if b_s.size else \
            np.zeros(0, bool)
        first = np.flatnonzero(new)
        ps, pt, pa = b_s[first], b_t[first], b_i[first]
        pb = np.r_[pa[1:], 0] if pa.size else pa.copy()
        last = np.r_[ps[1:] != ps[:-1], True] if ps.size else np.zeros(0, bool)
        pb[last] = bu[ps[last]]
        lens = bu[ps] - pa  # block rows a..u-1 of each pair
        tot = int(lens.sum())
        start = np.r_[0, np.cumsum(lens)]
        # the block rows of s's below part, from a on, looked up in t's structure
        sbelow0 = np.r_[0, np.cumsum(bu)]  # offsets of each s's below rows in b_row
        idx = np.repeat(sbelow0[ps] + pa - start[:-1], lens) + np.arange(tot)
        t_rep = np.repeat(pt, lens)
        q = b_row[idx] + t_rep * nb
        bpos = np.searchsorted(key, q)
        if bpos.size and not np.array_equal(key[np.minimum(bpos, key.size - 1)], q):
            raise AssertionError("supernodal analysis: an update outside its target")
        self.rel = bpos - brptr[t_rep]
        self.relptr = start
        self.pptr = np.searchsorted(ps, np.arange(ns + 1)).astype(np.int64)
        self.pt, self.pa, self.pb = pt, pa * bs, pb * bs

    # ---- numeric factorisation -------------------------------------------------------------

    def factorize(self, data: np.ndarray) -> None:
        data = np.ascontiguousarray(data, dtype=np.float64)
        if data.shape != (self.nnz,):
            raise ValueError(f"data has shape {data.shape}; the analysed pattern has "
                             f"{self.nnz} entries")
        # a failed factorisation leaves no factor to solve with (the NumPy loop overwrites
        # the last one in place; the C loop's would be stale)
        self._factored = False
        if self._numpy_plan is not None:
            try:
                self._numpy_plan.factor(data)
            except SingularSystemError as e:  # name the failing supernode's first unknown
                j = getattr(e, "supernode", None)
                raise SingularSystemError(
                    NOT_PD, unknown=None if j is None else int(self.sperm[self.c0[j]])) from None
        else:
            # the panels, then a dump block (zeroed in C); the last factor's buffer is reused
            # (a failed factorisation leaves none to solve with anyway): a fresh one would
            # hold two factors at the peak
            Lx = self.__dict__.get("Lx")
            if Lx is None or Lx.size != self.nx + self.bs:
                Lx = np.empty(self.nx + self.bs)
            info = self._c.factor(Lx, data, self.amap, self.c0, self.k, self.m, self.px,
                                  self.rows, self.rptr, self.pptr, self.pt, self.pa, self.pb,
                                  self.relptr, self.rel, self.wsize, self.bs)
            if info:  # the failing supernode + 1: name its first unknown
                i = int(self.sperm[self.c0[info - 1]]) if 0 < info <= self.ns else None
                raise SingularSystemError(NOT_PD, unknown=i)
            self.Lx = Lx
        # every backend's pivot test (L_kk^2 against the diagonal entry; base.PIVOT_TOL)
        ld = self._numpy_plan.diagonal() if self._numpy_plan is not None else \
            self.Lx[self._ldiag]
        self._check_pivots(data, ld * ld, self.sperm)
        self._factored = True

    def _panel(self, j: int) -> np.ndarray:
        """The dense ``m_j x k_j`` panel of supernode ``j`` of the last factorisation (its
        diagonal block, then the rows below; for tests)."""
        if self._numpy_plan is not None:
            return self._numpy_plan.panel(j)
        p0, k, m = int(self.px[j]), int(self.k[j]), int(self.m[j])
        P = self.Lx[p0:p0 + m * k].reshape(k, m).T.copy()
        P[:k][np.triu_indices(k, 1)] = 0.0  # the assembly leaves H there, never read
        return P

    # ---- solve -----------------------------------------------------------------------------

    def solve(self, b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=np.float64)
        if b.ndim not in (1, 2) or b.shape[0] != self.n:
            raise ValueError(f"the right-hand side has shape {b.shape}; expected ({self.n},) "
                             f"or ({self.n}, k)")
        vec = b.ndim == 1
        if not self._factored:
            raise SingularSystemError("no factorisation to solve with (none yet, or the last "
                                      "one failed)")
        rhs = (b[:, None] if vec else b)[self.sperm]
        if self._numpy_plan is not None:
            y = np.zeros((self.n + 2, rhs.shape[1]))  # then a zero row and a dump row
            y[:self.n] = rhs
            self._numpy_plan.solve(y)
            y = y[:self.n]
        else:
            y = np.asfortranarray(rhs)
            self._c.solve(self.Lx, y, self.c0, self.k, self.m, self.px, self.rows,
                          self.rptr, self.usize)
        x = np.empty_like(y)
        x[self.sperm] = y
        if not np.all(np.isfinite(x)):
            raise SingularSystemError("the linear system is singular (the solution is not "
                                      "finite)")
        return x[:, 0] if vec else x


def _blocks(indptr: np.ndarray, indices: np.ndarray, bs: int
            ) -> tuple[np.ndarray, np.ndarray] | None:
    """The block CSC ``(bptr, bidx)`` (int64) of a scalar CSC pattern made of dense ``bs x
    bs`` blocks (``None`` when it is not: then the analysis works entry by entry)."""
    n = indptr.size - 1
    if bs < 1 or n % bs:
        return None
    nb = n // bs
    ip = np.asarray(indptr, dtype=np.int64)
    lens = np.diff(ip).reshape(nb, bs)
    l0 = lens[:, 0]
    if not (lens == l0[:, None]).all() or (l0 % bs).any():
        return None
    # every column's entries come in runs of bs rows, bs-aligned
    ix = np.asarray(indices).reshape(-1, bs)
    r = ix[:, 0]
    if (r % bs).any() or not (ix == r[:, None] + np.arange(bs, dtype=ix.dtype)).all():
        return None
    G = r // bs  # each group's block row
    nblk = l0 // bs
    bptr = np.r_[0, np.cumsum(nblk)].astype(np.int64)
    cc, _ = _groups(bptr, bs)
    # the scalar columns of a block column hold the same block rows
    if not np.array_equal(G[np.arange(G.size) - cc * np.repeat(nblk, bs * nblk)], G):
        return None
    return bptr, G[cc == 0].astype(np.int64)


def _groups(bptr: np.ndarray, bs: int) -> tuple[np.ndarray, np.ndarray]:
    """The groups of ``bs`` consecutive entries of the scalar CSC of a dense-block pattern
    (block CSC ``bptr``), in order: each one's column within its block (``cc``) and its
    block (index into the block CSC)."""
    nblk = np.diff(bptr)
    ng = bs * int(bptr[-1])
    gcol = np.repeat(np.arange(nblk.size, dtype=np.int64), bs * nblk)
    o = np.arange(ng, dtype=np.int64) - np.repeat(bs * bptr[:-1], bs * nblk)
    cc, k = np.divmod(o, nblk[gcol]) if ng else (o, o)
    return cc, bptr[:-1][gcol] + k


def _dense_amap(blocks: tuple[np.ndarray, np.ndarray], bs: int, nb: int, inv_b: np.ndarray,
                sn_of_b: np.ndarray, key: np.ndarray, brptr: np.ndarray, px: np.ndarray,
                c0: np.ndarray, m: np.ndarray, nx: int) -> np.ndarray:
    """The assembly map of a pattern of dense blocks (block CSC ``blocks``), from one
    lookup per block: entry ``(rr, cc)`` of a block of the lower triangle goes to its block's
    place in its panel plus ``cc * m + rr``; the upper triangle (blocks above the diagonal,
    and ``rr < cc`` in the diagonal blocks) to the dump slot ``nx``."""
    bptr, bidx = blocks
    Cb = inv_b[np.repeat(np.arange(nb, dtype=np.int64), np.diff(bptr))]
    Rb = inv_b[bidx]
    low = Rb >= Cb
    s = sn_of_b[Cb]
    q = s[low] * nb + Rb[low]
    bpos = np.searchsorted(key, q)
    if bpos.size and not np.array_equal(key[np.minimum(bpos, key.size - 1)], q):
        raise AssertionError("supernodal analysis: an entry outside its supernode")
    sl = s[low]
    base = np.zeros(Cb.size, np.int64)
    base[low] = px[sl] + (Cb[low] * bs - c0[sl]) * m[sl] + (bpos - brptr[sl]) * bs
    cc, b = _groups(bptr, bs)
    amap = (base[b] + cc * m[s][b])[:, None] + np.arange(bs, dtype=np.int64)
    amap[~low[b]] = nx
    d = np.flatnonzero((Rb == Cb)[b])  # groups of the diagonal blocks: rows rr < cc dumped
    if d.size and bs > 1:
        amap[d] = np.where(np.arange(bs) < cc[d, None], nx, amap[d])
    return amap.ravel()


def _structure(bstart: np.ndarray, parent: np.ndarray, count: np.ndarray,
               lower: Any) -> np.ndarray:
    """The block row structure of each supernode, ``s * nb + row`` sorted: its columns, then
    the rows below, ``struct(s) = (its columns' rows of A) | (its children's rows below)``
    beyond its last column, computed one level of the supernodal tree at a time (leaves
    first), vectorised within a level. The rows below must number ``count[last] - 1``."""
    nb, ns = parent.size, bstart.size
    if ns == 0:
        return np.zeros(0, np.int64)
    bend = np.r_[bstart[1:], nb]
    last = bend - 1
    sn_of = np.repeat(np.arange(ns), bend - bstart)
    sparent = np.where(parent[last] < 0, -1, sn_of[np.maximum(parent[last], 0)])
    level = np.zeros(ns, np.int64)  # height above the leaves (children precede parents)
    lv = level.tolist()
    for c, t in enumerate(sparent.tolist()):
        if t >= 0 and lv[t] <= lv[c]:
            lv[t] = lv[c] + 1
    level = np.array(lv, np.int64)
    nlev = int(level.max()) + 1
    # the entries of A below each supernode's last column, bucketed by the supernode's level
    rows = np.repeat(np.arange(nb), np.diff(lower.indptr))
    s_e = sn_of[lower.indices]
    keep = rows > last[s_e]
    own = s_e[keep] * nb + rows[keep]
    pending: list[list[np.ndarray]] = [[] for _ in range(nlev)]
    _bucket(own, level[own // nb], pending)
    out = []
    for h in range(nlev):
        if not pending[h]:
            continue
        key = np.unique(np.concatenate(pending[h]))
        pending[h] = []
        out.append(key)
        t, r = sparent[key // nb], key % nb
        up = (t >= 0) & (r > last[np.maximum(t, 0)])
        _bucket(t[up] * nb + r[up], level[t[up]], pending)
    below = np.concatenate(out) if out else np.zeros(0, np.int64)
    if not np.array_equal(np.bincount(below // nb, minlength=ns), count[last] - 1):
        raise AssertionError("supernodal analysis: structures disagree with the column counts")
    diag = np.repeat(np.arange(ns), bend - bstart) * nb + np.arange(nb)
    return np.sort(np.r_[below, diag])


def _bucket(keys: np.ndarray, level: np.ndarray, pending: list[list[np.ndarray]]) -> None:
    """Append ``keys`` to ``pending[level]``, grouped by level."""
    if not keys.size:
        return
    o = np.argsort(level, kind="stable")
    lv = level[o]
    cut = np.flatnonzero(np.r_[True, lv[1:] != lv[:-1]])
    for a, b in zip(cut.tolist(), np.r_[cut[1:], lv.size].tolist(), strict=True):
        pending[int(lv[a])].append(keys[o[a:b]])


def _amalgamate(sn_start: np.ndarray, count: np.ndarray, parent: np.ndarray,
                nb: int) -> np.ndarray:
    """Relaxed amalgamation: merge a supernode into the next one (its parent, contiguous)
    when the merged one stays small or adds few explicit zeros (CHOLMOD's rule with its
    default limits). Returns the first block column of each merged supernode."""
    ends = np.r_[sn_start[1:], nb]
    # the rows below a fundamental supernode are those of its last column
    below = (count[ends - 1] - 1).tolist()  # rows strictly below the supernode's last column
    first_below = parent[ends - 1].tolist()
    (r0, z0), (r1, z1), (r2, z2) = _RELAX
    # the stack of merged supernodes, as parallel lists: start, end, true nonzeros, the
    # parent of the last column
    st: list[int] = []
    en: list[int] = []
    tr: list[int] = []
    fbs: list[int] = []
    for a, b, nbel, fb in zip(sn_start.tolist(), ends.tolist(), below, first_below,
                              strict=True):
        k = b - a
        ctrue = k * (k + 1) // 2 + k * nbel
        start = a
        while st and en[-1] == a and fbs[-1] == a:  # contiguous, and a is its parent
            # the child's rows below (minus a's columns) are in the parent's structure, so
            # the merged supernode has the parent's rows below
            k2 = b - st[-1]
            total = k2 * (k2 + 1) // 2 + k2 * nbel
            zeros = 1.0 - (tr[-1] + ctrue) / total
            if not ((k2 <= r0 and zeros <= z0) or (k2 <= r1 and zeros <= z1)
                    or (k2 <= r2 and zeros <= z2)):
                break
            start = st.pop()
            ctrue += tr.pop()
            en.pop()
            fbs.pop()
        st.append(start)
        en.append(b)
        tr.append(ctrue)
        fbs.append(fb)
    return np.array(st, dtype=np.int64)
