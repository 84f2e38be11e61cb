"""The NumPy loop of the supernodal Cholesky
(:class:`~microlie.optim.linalg.cholesky.SupernodalSolver`
without the compiled ``microlie._c._chol``): the same factor as the compiled loop, organised
so that the Python loop runs a few times per level of the supernodal elimination tree, not once per
supernode.

Plan (made once per pattern by :class:`NumpyLoop`):

- the supernodes of one level (independent of each other) are put in *buckets*; a bucket's
  members are padded to its common ``(K, U)`` (``K`` columns, ``U`` rows below the diagonal
  block): the padded diagonal block is ``blockdiag(A11, I)`` and the padded rows and columns
  are zero, so the padded factor is ``blockdiag(L11, I)`` and ``[L21, 0; 0, 0]``. Which shapes
  share a bucket is chosen by a cost model (a bucket's fixed cost against its padded work);
- the factor lives in one array, bucket after bucket: the ``(G, K, K)`` diagonal blocks
  (``D[g, c, r] = L11[r, c]``) and the ``(G, K, U)`` blocks below (``B[g, c, r] = L21[r, c]``),
  so every member is an F-ordered matrix that LAPACK overwrites in place, and every bucket a
  stack that NumPy's batched ``matmul`` reads directly;
- the update ``W = L21 L21^T`` of every member of a level is written into one buffer, and
  its lower block triangle subtracted from the ancestors' blocks by one ``ufunc.at`` per level
  through precomputed flat maps (``ufunc.at`` sums the contributions of several members to one
  entry; in NumPy 2 it is also faster than a plain indexed subtraction). With even ``bs`` the
  maps move complex128 words (two entries each): the scatters are bound by memory traffic.

Numeric factorisation (:meth:`NumpyLoop.factor`): per bucket either NumPy's stacked
``cholesky`` (small ``K``, many members) or LAPACK's ``potrf`` per member in place; the
diagonal blocks of a bucket of several members are then copied (one gather) into the lower
band of their block-diagonal matrix (bandwidth ``K - 1``), so that one LAPACK band solve
(``tbtrs``) gives ``L21^T = L11^-1 B^T`` for every member at once (``trsm`` per member where
the stacked ``cholesky`` was not used); then ``W`` as a batched product (``syrk`` for a
bucket of one). Solve (:meth:`NumpyLoop.solve`): per level one gather, per bucket one band
solve (``tbsv``/``tbtrs``; ``trsm`` for a bucket of one) and a batched product, and one
scatter, forward then backward. No inverse of a diagonal block is formed: every step is a
triangular solve, backward stable like the compiled loop's (the residual of a solve is the
compiled loop's to a small factor: ``tests/test_optim_cholesky.py`` checks it on the shared
pose graphs)."""

from __future__ import annotations

import functools
from typing import Any

import numpy as np

from .base import SingularSystemError

__all__ = ["NumpyLoop"]

NOT_PD = ("the linear system is not positive definite (a pivot of the Cholesky "
          "factorisation is not positive)")


def _not_pd(supernode: int) -> SingularSystemError:
    """The error of a failed pivot in ``supernode`` (its attribute ``supernode``; the solver
    names the unknown from it, as the C loop's failing supernode)."""
    e = SingularSystemError(NOT_PD)
    e.supernode = supernode  # type: ignore[attr-defined]
    return e

# batched NumPy cholesky and row-by-row substitution for buckets of at least _BATCH_G members
# with K <= _BATCH_K (a substitution step costs a few us whatever G; LAPACK per member 2-3 us)
_BATCH_K, _BATCH_G = 12, 8
# cost model of a bucket (seconds): fixed cost per bucket and per member, per padded flop and
# per padded entry moved (measured on the shared pose graphs, one BLAS thread)
_COST_BUCKET, _COST_MEMBER, _COST_FLOP, _COST_ENTRY = 20e-6, 3e-6, 1.0 / 8e9, 1.5e-9


def _levels(sparent: np.ndarray) -> np.ndarray:
    """Level of each supernode in the supernodal elimination tree (leaves 0; children have
    smaller indices than their parents)."""
    lev = np.zeros(sparent.size, np.int64)
    for s, p in enumerate(sparent.tolist()):
        if p >= 0 and lev[p] <= lev[s]:
            lev[p] = lev[s] + 1
    return lev


def _bucket_cost(G: int, K: int, U: int) -> float:
    flops = G * (K ** 3 / 3.0 + K * K * U + K * U * U)
    return (_COST_BUCKET + G * _COST_MEMBER + flops * _COST_FLOP
            + G * (K * K + K * U + U * U) * _COST_ENTRY)


def _buckets(k: np.ndarray, u: np.ndarray) -> list[np.ndarray]:
    """Partition the supernodes of one level (shapes ``k``, ``u``) into buckets: distinct
    shapes sorted by ``(k, u)``, cut into contiguous runs by dynamic programming on
    :func:`_bucket_cost` (a run is padded to its largest ``k`` and ``u``)."""
    wide = int(u.max(initial=0)) + 1
    shapes, inv, cnt_a = np.unique(k * wide + u, return_inverse=True, return_counts=True)
    cnt = cnt_a.tolist()
    ks, us = (shapes // wide).tolist(), (shapes % wide).tolist()
    S = len(ks)
    best = [0.0] + [np.inf] * S
    cut = [0] * (S + 1)
    cb, cm, cf, ce = _COST_BUCKET, _COST_MEMBER, _COST_FLOP, _COST_ENTRY
    for j in range(1, S + 1):  # runs i..j-1 (_bucket_cost inlined: the plan's hot loop)
        G, U, K = 0, 0, ks[j - 1]
        bj, cj = best[j], cut[j]
        for i in range(j - 1, -1, -1):
            G += cnt[i]
            if us[i] > U:
                U = us[i]
            c = best[i] + cb + G * (cm + (K ** 3 / 3.0 + K * K * U + K * U * U) * cf
                                     + (K * K + K * U + U * U) * ce)
            if c < bj:
                bj, cj = c, i
        best[j], cut[j] = bj, cj
    runs = []
    j = S
    while j > 0:
        runs.append((cut[j], j))
        j = cut[j]
    order = np.argsort(inv.ravel(), kind="stable")
    start = np.r_[0, np.cumsum(cnt_a)]
    return [order[start[i]:start[j]] for i, j in reversed(runs)]


@functools.lru_cache(maxsize=64)
def _band_maps(K: int) -> tuple[np.ndarray, np.ndarray]:
    """The entries of one member's ``(K, K)`` diagonal block ``D`` (``D[c, r] = L11[r, c]``)
    that its band rows hold, as flat positions in ``D`` and in the ``(K, K)`` band rows
    (``band[c, t] = D[c, c + t]``, ``t < K - c``)."""
    length = K - np.arange(K)
    c = np.repeat(np.arange(K), length)
    t = np.arange(c.size) - np.repeat(np.cumsum(length) - length, length)
    return c * K + c + t, c * K + t


class _Bucket:
    """Members of one level padded to ``(K, U)``, with views into the factor buffers."""

    def __init__(self, members: np.ndarray, K: int, U: int, batched: bool) -> None:
        self.members, self.G, self.K, self.U, self.batched = members, members.size, K, U, \
            batched
        self.D: Any = None  # (G, K, K) views, set by NumpyLoop._views
        self.B: Any = None  # (G, K, U)
        self.BT: Any = None  # (G, U, K), L21
        self.W: Any = None  # (G, U, U)
        # buckets of more than one member: the diagonal blocks again, as the lower band
        # (bandwidth K - 1) of their block-diagonal matrix, for one LAPACK band solve
        # (``tbtrs``) per bucket in :meth:`NumpyLoop.solve`; row ``g K + c`` of ``band`` is
        # column ``c`` of member ``g`` from its diagonal down, zero-padded
        self.band: Any = None  # (G K, K)
        self.bsrc: Any = None  # positions in D of the band's entries ...
        self.bdst: Any = None  # ... and in band
        self.c: tuple[int, int] = (0, 0)  # its columns in the level's gathered columns
        self.r: tuple[int, int] = (0, 0)  # its rows in the level's gathered rows


class NumpyLoop:
    """The NumPy plan of a :class:`~microlie.optim.linalg.cholesky.SupernodalSolver` whose symbolic
    analysis is done (its panels, row structures, assembly map and update pairs); the solver
    makes and uses it itself when the compiled loop is off.

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.linalg.cholesky import SupernodalSolver
    >>> from microlie.optim.linalg.cholesky_numpy import NumpyLoop
    >>> A = sp.csc_matrix(np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.0], [0.0, 0.0, 2.0]]))
    >>> s = SupernodalSolver(compiled=False)
    >>> s.analyse(A.indptr, A.indices, 3)
    >>> plan = NumpyLoop(s)
    >>> plan.factor(A.data)
    >>> y = np.zeros((3 + 2, 1))  # the right-hand side permuted, a zero row, a dump row
    >>> y[:3, 0] = np.array([5.0, 4.0, 2.0])[s.sperm]
    >>> plan.solve(y)
    >>> x = np.empty(3)
    >>> x[s.sperm] = y[:3, 0]
    >>> np.round(x, 12).tolist()
    [1.0, 1.0, 1.0]
    """

    def __init__(self, s: Any) -> None:
        bs, ns = s.bs, s.ns
        k, m = s.k, s.m
        u = m - k
        self.n, self.bs, self.ns = s.n, bs, ns
        self.k, self.u = k, u
        lev = _levels(s.sparent)
        nlev = int(lev.max()) + 1 if ns else 0
        # buckets, level by level; the padded shape of every supernode
        K = k.copy()
        U = u.copy()
        self.levels: list[list[_Bucket]] = []
        for level in range(nlev):
            sel = np.flatnonzero(lev == level)
            bl = []
            for idx in _buckets(k[sel], u[sel]):
                mem = sel[idx]
                Kb, Ub = int(k[mem].max()), int(u[mem].max())
                K[mem], U[mem] = Kb, Ub
                bl.append(_Bucket(mem, Kb, Ub, bool(Kb <= _BATCH_K and mem.size >= _BATCH_G)))
            self.levels.append(bl)
        # layout: bucket after bucket, D then B; W in its own buffer
        dpos = np.zeros(ns, np.int64)
        bpos = np.zeros(ns, np.int64)
        wpos = np.zeros(ns, np.int64)
        off = wmax = 0
        self._wlen: list[int] = []
        for bl in self.levels:
            woff = 0
            for b in bl:
                G, Kb, Ub = b.G, b.K, b.U
                g = np.arange(G)
                dpos[b.members] = off + g * Kb * Kb
                off += G * Kb * Kb
                bpos[b.members] = off + g * Kb * Ub
                off += G * Kb * Ub
                wpos[b.members] = woff + g * Ub * Ub
                woff += G * Ub * Ub
            self._wlen.append(woff)
            wmax = max(wmax, woff)
        self.size = off
        self.L = np.zeros(off + bs)  # the factor, then one dump run of bs entries
        self._Wbuf = np.zeros(wmax)
        self.K, self.U, self.dpos, self.bpos = K, U, dpos, bpos
        # padded diagonal: ones
        pad = k < K
        cnt = (K - k)[pad]
        sid = np.repeat(np.flatnonzero(pad), cnt)
        c = np.arange(int(cnt.sum())) - np.repeat(np.r_[0, np.cumsum(cnt)][:-1], cnt) + k[sid]
        self._ones = dpos[sid] + c * K[sid] + c
        # runs of bs entries move as complex128 words of two entries when bs is even (half
        # the indices: the scatters are bound by memory traffic)
        self.word = 2 if bs % 2 == 0 else 1
        self._assembly(s)
        self._updates(s, lev, wpos, nlev)
        self._solve_maps(s)
        self._views()

    def __len__(self) -> int:
        """The number of buckets (steps of the loop)."""
        return sum(len(level) for level in self.levels)

    # ---- plan ------------------------------------------------------------------------------

    def _at(self, sid: np.ndarray, col: np.ndarray, row: np.ndarray) -> np.ndarray:
        """Position in :attr:`L` of entry ``(row, col)`` (local) of supernode ``sid``."""
        k = self.k[sid]
        return np.where(row < k, self.dpos[sid] + col * self.K[sid] + row,
                        self.bpos[sid] + col * self.U[sid] + row - k)

    def _from_panel(self, s: Any, p: np.ndarray) -> np.ndarray:
        """Positions in :attr:`L` of the panel offsets ``p`` (the compiled loop's layout)."""
        sid = np.searchsorted(s.px, p, side="right") - 1
        rem = p - s.px[sid]
        return self._at(sid, rem // s.m[sid], rem % s.m[sid])

    def _assembly(self, s: Any) -> None:
        """The map of the pattern's entries into :attr:`L`, the strict upper triangle to the
        dump run: by runs of ``bs`` rows when the pattern is made of dense ``bs x bs`` blocks
        (a run of the diagonal block also writes the unused upper part of ``L11``), in words
        of :attr:`word` entries; else entry by entry."""
        bs, nx, w = self.bs, s.nx, self.word
        runs = s.dense_blocks  # else look for runs of bs rows in the scalar pattern
        if not runs:
            ip, ix = np.asarray(s.indptr), np.asarray(s.indices)
            runs = ix.size % bs == 0 and bool(np.all(ip % bs == 0))
        if not s.dense_blocks and runs and ix.size:
            r = ix.reshape(-1, bs)
            runs = bool(np.all(r[:, 0] % bs == 0) and np.all(r - r[:, :1] == np.arange(bs)))
        amap = s.amap
        if runs:
            last = amap[bs - 1::bs]  # the run's last row is in the lower triangle if any is
            low = last < nx
            start = np.full(last.size, self.size, np.int64)
            start[low] = self._from_panel(s, last[low]) - (bs - 1)
            self._amap, self._aword = (start[:, None] // w + np.arange(bs // w)).ravel(), w
        else:
            low = amap < nx
            pos = np.full(amap.size, self.size, np.int64)
            pos[low] = self._from_panel(s, amap[low])
            self._amap, self._aword = pos, 1

    def _updates(self, s: Any, lev: np.ndarray, wpos: np.ndarray, nlev: int) -> None:
        """Per level: the runs of ``bs`` entries of the members' ``W`` (lower block triangle)
        and their destinations in the ancestors, as two index arrays (destinations and
        sources, for one ``ufunc.at`` per level)."""
        bs, ns = self.bs, self.ns
        u = self.u
        ps = np.repeat(np.arange(ns), np.diff(s.pptr))
        a, b = s.pa, s.pb
        # every quantity is a multiple of bs (shapes, offsets, rows), so each is computed in
        # runs of bs: per pair and column jj of W in [a, b) first, then per run r of rows
        # a + r bs of that column in the lower block triangle (r >= (jj - a) // bs)
        ncol = b - a
        pc = np.repeat(np.arange(ps.size), ncol)  # (pair, column)
        jj = a[pc] + np.arange(int(ncol.sum())) - np.repeat(np.cumsum(ncol) - ncol, ncol)
        sc, tc = ps[pc], s.pt[pc]
        # by level of the source (stable: pairs, then columns, in order within a level); the
        # runs expanded below keep this order
        so = np.argsort(lev[sc], kind="stable")
        pc, jj, sc, tc = pc[so], jj[so], sc[so], tc[so]
        bounds = np.searchsorted(lev[sc], np.arange(nlev + 1))
        r0 = (jj - a[pc]) // bs
        nrun = (u[sc] - a[pc]) // bs - r0
        col = s.rows[s.rptr[sc] + s.k[sc] + jj] - s.c0[tc]
        kt1 = self.k[tc] // bs
        dia1 = (self.dpos[tc] + col * self.K[tc]) // bs
        bel1 = (self.bpos[tc] + col * self.U[tc]) // bs - kt1
        # run r of (pair, column) x: source word src1 + r, block row rowb = rel[rel1 + r]
        first = np.cumsum(nrun) - nrun
        src1 = (wpos[sc] + jj * self.U[sc] + a[pc]) // bs + r0 - first
        rel1 = s.relptr[pc] + r0 - first
        bounds = np.r_[first, int(nrun.sum())][bounds]  # the levels' bounds in runs
        del sc, tc, col, jj, pc
        x = np.repeat(np.arange(nrun.size), nrun)
        r = np.arange(x.size)
        src = src1[x] + r
        rowb = s.rel[rel1[x] + r]
        dst = np.where(rowb < kt1[x], dia1[x], bel1[x]) + rowb
        del x, r, rowb
        w = self.word
        run = np.arange(bs // w)
        # kept for every factorisation: int32 when the words of L and W allow (half the
        # memory; ufunc.at and take are as fast with them)
        small = max(self.size + bs, self._Wbuf.size) // w < 2**31
        it = np.int32 if small else np.intp
        self._scatter: list[tuple[np.ndarray, np.ndarray]] = []
        for level in range(nlev):  # in words
            sl = slice(bounds[level], bounds[level + 1])
            self._scatter.append(((dst[sl, None] * (bs // w) + run).astype(it).ravel(),
                                  (src[sl, None] * (bs // w) + run).astype(it).ravel()))

    def _solve_maps(self, s: Any) -> None:
        """Per level, the gathered columns and rows of its buckets (padded ones: the zero row
        ``n`` to read, the dump row ``n + 1`` to write)."""
        n = self.n
        self._cols: list[tuple[np.ndarray, np.ndarray]] = []
        self._rows: list[tuple[np.ndarray, np.ndarray]] = []
        for bl in self.levels:
            cr, cw, rr, rw = [], [], [], []
            nc = nr = 0
            for b in bl:
                G, Kb, Ub = b.G, b.K, b.U
                kk, uu = self.k[b.members][:, None], self.u[b.members][:, None]
                c = s.c0[b.members][:, None] + np.arange(Kb)
                real = np.arange(Kb) < kk
                cr.append(np.where(real, c, n).ravel())
                cw.append(np.where(real, c, n + 1).ravel())
                ri = np.minimum(np.arange(Ub), np.maximum(uu - 1, 0))
                # a member without rows below (a root) reads a real row, masked below; the
                # last supernode's would be past the end
                rr_ = s.rows[np.minimum(s.rptr[b.members][:, None] + s.k[b.members][:, None]
                                        + ri, s.rows.size - 1)]
                real = np.arange(Ub) < uu
                rr.append(np.where(real, rr_, n).ravel())
                rw.append(np.where(real, rr_, n + 1).ravel())
                b.c, b.r = (nc, nc + G * Kb), (nr, nr + G * Ub)
                nc, nr = nc + G * Kb, nr + G * Ub
            self._cols.append((np.concatenate(cr), np.concatenate(cw)))
            self._rows.append((np.concatenate(rr), np.concatenate(rw)))

    def _views(self) -> None:
        L = self.L
        for bl in self.levels:
            for b in bl:
                G, Kb, Ub = b.G, b.K, b.U
                d0 = int(self.dpos[b.members[0]])
                b.D = L[d0:d0 + G * Kb * Kb].reshape(G, Kb, Kb)
                b.B = L[d0 + G * Kb * Kb:d0 + G * Kb * (Kb + Ub)].reshape(G, Kb, Ub)
                b.BT = np.swapaxes(b.B, 1, 2)
                if G > 1:  # band[g K + c, t] = D[g, c, c + t] = L11[c + t, c], t < K - c
                    b.bsrc, b.bdst = _band_maps(Kb)
                    b.band = np.zeros((G * Kb, Kb))
        for bl in self.levels:
            w = 0
            for b in bl:
                b.W = self._Wbuf[w:w + b.G * b.U * b.U].reshape(b.G, b.U, b.U)
                w += b.G * b.U * b.U

    # ---- numeric ---------------------------------------------------------------------------

    def factor(self, data: np.ndarray) -> None:
        """Factorise the matrix with CSC values ``data`` (in the analysed pattern)."""
        L = self.L
        L.fill(0.0)
        L[self._ones] = 1.0
        if self._aword == 2:
            L.view(np.complex128)[self._amap] = data.view(np.complex128)
        else:
            L[self._amap] = data
        Lw, Wf = (L.view(np.complex128), self._Wbuf.view(np.complex128)) if self.word == 2 \
            else (L, self._Wbuf)
        from scipy.linalg import blas, lapack  # type: ignore[import-untyped]  # (this loop only)

        potrf, trsm, syrk, tbtrs = lapack.dpotrf, blas.dtrsm, blas.dsyrk, lapack.dtbtrs
        for bl, (dst, src) in zip(self.levels, self._scatter, strict=True):
            for b in bl:
                D, B = b.D, b.B
                if b.batched:
                    try:
                        L11 = np.linalg.cholesky(np.swapaxes(D, 1, 2))
                    except np.linalg.LinAlgError:
                        bad = next(g for g in range(b.G) if potrf(D[g].T.copy(), lower=1)[1])
                        raise _not_pd(int(b.members[bad])) from None
                    D[...] = np.swapaxes(L11, 1, 2)
                    b.band.reshape(b.G, -1)[:, b.bdst] = D.reshape(b.G, -1)[:, b.bsrc]
                    if b.U:  # B = L21^T = L11^-1 B: one band solve for the bucket
                        BU = B.reshape(-1, b.U)
                        BU[...] = tbtrs(b.band.T, BU, uplo="L")[0]
                else:  # per member in place: L11 = potrf, L21 = L21 L11^-T (F views)
                    for g in range(b.G):
                        DF = D[g].T
                        if potrf(DF, lower=1, clean=1, overwrite_a=1)[1]:
                            raise _not_pd(int(b.members[g]))
                        if b.U:
                            trsm(1.0, DF, B[g].T, side=1, lower=1, trans_a=1, overwrite_b=1)
                    if b.G > 1:
                        b.band.reshape(b.G, -1)[:, b.bdst] = D.reshape(b.G, -1)[:, b.bsrc]
                if b.U:
                    if b.G == 1:
                        syrk(1.0, B[0].T, beta=0.0, c=b.W[0].T, lower=1, overwrite_c=1)
                    else:
                        np.matmul(b.BT, B, out=b.W)
            if dst.size:  # ufunc.at sums the contributions of several members to one entry
                np.subtract.at(Lw, dst, Wf.take(src))

    def solve(self, y: np.ndarray) -> None:
        """Solve in place: ``y`` is ``(n + 2, nrhs)`` (the right-hand side in the factor's
        order, then the zero row and the dump row)."""
        from scipy.linalg import blas, lapack  # type: ignore[import-untyped]

        trsm, tbsv, tbtrs, mm = blas.dtrsm, blas.dtbsv, lapack.dtbtrs, np.matmul
        nr = y.shape[1]
        plan = list(zip(self.levels, self._cols, self._rows, strict=True))
        for bl, (cr, cw), (_, rw) in plan:
            X = y[cr]  # a copy, solved in place
            Ur = np.empty((rw.size, nr))
            for b in bl:
                (c0, c1), (r0, r1), sh = b.c, b.r, (b.G, -1, nr)
                Xb = X[c0:c1].reshape(sh)
                if b.G == 1:  # L11 X = Y
                    Xb[0] = trsm(1.0, b.D[0].T, Xb[0], lower=1)
                elif nr == 1:  # one band solve for the bucket, in place
                    tbsv(b.K - 1, b.band.T, X[c0:c1, 0], lower=1, overwrite_x=1)
                else:
                    X[c0:c1] = tbtrs(b.band.T, X[c0:c1], uplo="L")[0]
                if b.U:  # L21 X, to subtract from the rows below
                    mm(b.BT, Xb, out=Ur[r0:r1].reshape(sh))
            y[cw] = X
            if rw.size:
                if nr == 1:
                    np.subtract.at(y.ravel(), rw, Ur.ravel())
                else:
                    np.subtract.at(y, rw, Ur)
        for bl, (cr, cw), (rr, _) in reversed(plan):
            X = y[cr]
            Yr = y[rr]
            for b in bl:
                (c0, c1), (r0, r1), sh = b.c, b.r, (b.G, -1, nr)
                Xb = X[c0:c1].reshape(sh)
                if b.U:  # Y - L21^T Yr
                    Xb -= mm(b.B, Yr[r0:r1].reshape(sh))
                if b.G == 1:  # L11^T X = Y
                    Xb[0] = trsm(1.0, b.D[0].T, Xb[0], lower=1, trans_a=1)
                elif nr == 1:
                    tbsv(b.K - 1, b.band.T, X[c0:c1, 0], lower=1, trans=1, overwrite_x=1)
                else:
                    X[c0:c1] = tbtrs(b.band.T, X[c0:c1], uplo="L", trans="T")[0]
            y[cw] = X

    def diagonal(self) -> np.ndarray:
        """The diagonal of the last factor, in the factor's column order."""
        if not hasattr(self, "_ldiag"):
            sid = np.repeat(np.arange(self.ns), self.k)
            col = np.arange(self.n) - np.repeat(np.r_[0, np.cumsum(self.k)][:-1], self.k)
            self._ldiag = self.dpos[sid] + col * (self.K[sid] + 1)
        return self.L[self._ldiag]

    def panel(self, j: int) -> np.ndarray:
        """The dense ``(k + u) x k`` panel of supernode ``j`` (diagonal block, then the rows
        below), as the compiled loop stores it."""
        k, u, K, U = int(self.k[j]), int(self.u[j]), int(self.K[j]), int(self.U[j])
        d0, b0 = int(self.dpos[j]), int(self.bpos[j])
        D = self.L[d0:d0 + K * K].reshape(K, K).T[:k, :k]
        B = self.L[b0:b0 + K * U].reshape(K, U).T[:u, :k]
        return np.vstack([D, B])
