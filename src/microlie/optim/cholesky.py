"""A supernodal multifrontal Cholesky on the block pattern, in NumPy and LAPACK only.

Our normal equations have dense ``d x d`` blocks (3 for SE2, 6 for SE3), so the analysis works
on the block graph (36 times smaller than the scalar one): a minimum-degree order of the block
graph (SuperLU's ``MMD_AT_PLUS_A`` on a tiny block matrix), the block elimination tree and
column structures, fundamental supernodes merged by relaxed amalgamation (as CHOLMOD does),
and for every supernode the precomputed gather indices of its frontal matrix. Each numeric
factorisation then runs, per supernode in elimination order: assemble the front (original
entries and the children's update matrices), ``potrf`` on the pivot block, ``trsm`` for the
rows below, ``syrk`` for the update matrix. The solve runs the supernodes forward and back.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp  # type: ignore[import-untyped]
from scipy.linalg import blas, lapack  # type: ignore[import-untyped]

from .linear import LinearSolver, SingularSystemError, block_graph, splu_symmetric

__all__ = ["SupernodalSolver"]

# relaxed amalgamation: (max merged columns, max fraction of explicit zeros)
_RELAX = ((4, 0.8), (16, 0.1), (48, 0.05))


class SupernodalSolver(LinearSolver):
    """Supernodal multifrontal Cholesky (NumPy/LAPACK) on blocks of ``block_size`` unknowns
    (the greatest common divisor of the variables' dimensions)."""

    name = "supernodal"

    def analyse(self, indptr, indices, n, block_size=1):
        super().analyse(indptr, indices, n)
        bs = block_size if block_size > 0 and n % block_size == 0 else 1
        self.bs = bs
        nb = n // bs
        B = block_graph(indptr, indices, n, bs)
        # SuperLU's L is the factor of B[q][:, q] with q = argsort(perm_c), whatever the
        # requested order (it postorders the elimination tree itself)
        lu = splu_symmetric(B, "MMD_AT_PLUS_A")
        perm = np.argsort(lu.perm_c)
        parent = _etree(lu.L.tocsc(), nb)
        perm = perm[_postorder(parent, nb)]
        lu = splu_symmetric(B[perm][:, perm].tocsc(), "NATURAL")
        perm = perm[np.argsort(lu.perm_c)]
        L = _closed(lu.L.tocsc(), nb)
        parent = _etree(L, nb)
        count = np.diff(L.indptr)  # column counts incl. the diagonal
        nchild = np.bincount(parent[parent >= 0], minlength=nb)
        j = np.arange(1, nb)
        cont = (parent[j - 1] == j) & (nchild[j] == 1) & (count[j - 1] == count[j] + 1)
        sn_start = np.r_[0, j[~cont]]
        ends = np.r_[sn_start[1:], nb]
        struct = [L.indices[L.indptr[a]:L.indptr[a + 1]] for a in range(nb)]
        snodes = _amalgamate(list(zip(sn_start.tolist(), ends.tolist(), strict=True)), struct)
        self.perm_blocks = perm
        self.sperm = (perm[:, None] * bs + np.arange(bs)).ravel()  # scalar: new -> old
        self._build(snodes, L, n, nb, bs)

    def _build(self, snodes, L, n, nb, bs):
        ns = len(snodes)
        sn_of = np.empty(nb, np.int64)
        for k, (a, b) in enumerate(snodes):
            sn_of[a:b] = k
        fronts = []
        for a, b in snodes:
            r = np.unique(L.indices[L.indptr[a]:L.indptr[b]])
            blocks = np.concatenate([np.arange(a, b), r[r >= b]])
            idx = (blocks[:, None] * bs + np.arange(bs)).ravel()
            fronts.append((idx, (b - a) * bs))
        sparent = [int(sn_of[f[0][f[1]] // bs]) if f[0].size > f[1] else -1 for f in fronts]
        children: list[list[int]] = [[] for _ in range(ns)]
        for k, p in enumerate(sparent):
            if p >= 0:
                children[p].append(k)
        # original lower-triangle entries of the permuted matrix, grouped by supernode
        inv_s = np.empty(n, np.int64)
        inv_s[self.sperm] = np.arange(n)
        cols_old = np.repeat(np.arange(n), np.diff(self.indptr))
        rnew, cnew = inv_s[self.indices], inv_s[cols_old]
        keep = rnew >= cnew
        src_all = np.flatnonzero(keep)
        r_all, c_all = rnew[keep], cnew[keep]
        csn = sn_of[c_all // bs]
        order = np.argsort(csn, kind="stable")
        src_all, r_all, c_all, csn = src_all[order], r_all[order], c_all[order], csn[order]
        bounds = np.searchsorted(csn, np.arange(ns + 1))
        # update pool: one u x u block (row-major) per supernode with rows below
        usize = [f[0].size - f[1] for f in fronts]
        poff = np.concatenate([[0], np.cumsum([u * u for u in usize])]).astype(np.int64)
        self.pool_size = int(poff[-1])
        pos = np.full(n, -1, np.int64)
        info = []
        for k, (idx, kc) in enumerate(fronts):
            m = idx.size
            pos[idx] = np.arange(m)
            s0, s1 = bounds[k], bounds[k + 1]
            rr = pos[r_all[s0:s1]]
            if rr.size and rr.min() < 0:
                raise AssertionError("supernodal analysis: an entry outside its front")
            dst = rr * m + (c_all[s0:s1] - idx[0])
            adds = []
            for c in children[k]:
                cidx, ckc = fronts[c]
                rel = pos[cidx[ckc:]]
                u = rel.size
                # the child's rows fall into runs of consecutive rows of this front: one
                # slice addition per pair of runs (lower triangle only; at least block_size
                # rows per run), much faster than a fancy-indexed scatter
                cut = (np.flatnonzero(rel[1:] - rel[:-1] != 1) + 1).tolist()
                r0 = rel[[0, *cut]].tolist()
                runs = [(slice(r, r + b - a), slice(a, b))
                        for r, a, b in zip(r0, [0, *cut], [*cut, u], strict=True)]
                pairs = [(fr, fc, cr, cc) for i, (fr, cr) in enumerate(runs)
                         for fc, cc in runs[:i + 1]]
                adds.append((int(poff[c]), u, pairs))
            pos[idx] = -1
            info.append({"idx": idx, "m": m, "k": kc, "src": src_all[s0:s1], "dst": dst,
                         "c0": int(idx[0]), "rows": idx[kc:],
                         "adds": adds,
                         "poff": int(poff[k]), "u": usize[k]})
        # leaves (no children), batched by shape; the other supernodes one by one
        groups: dict[tuple[int, int], list[int]] = {}
        inner = []
        for k, f in enumerate(info):
            if not children[k] and f["u"] > 0:
                groups.setdefault((f["m"], f["k"]), []).append(k)
            else:
                inner.append(k)
        self.leaf_groups = []
        for (m, kc), ks in groups.items():
            G = len(ks)
            u = m - kc
            dst = np.concatenate([g * m * m + info[k]["dst"] for g, k in enumerate(ks)])
            src = np.concatenate([info[k]["src"] for k in ks])
            pidx = (np.array([info[k]["poff"] for k in ks])[:, None] + np.arange(u * u)).ravel()
            cidx = np.stack([info[k]["idx"][:kc] for k in ks])
            ridx = np.stack([info[k]["idx"][kc:] for k in ks])
            self.leaf_groups.append({"G": G, "m": m, "k": kc, "dst": dst, "src": src,
                                     "pidx": pidx, "cidx": cidx, "ridx": ridx})
        self.inner = [info[k] for k in inner]
        self.nsuper = ns

    def factorize(self, data: np.ndarray) -> None:
        pool = np.empty(self.pool_size)
        self.L_leaf = []
        for g in self.leaf_groups:
            G, m, kc = g["G"], g["m"], g["k"]
            F = np.zeros(G * m * m)
            F[g["dst"]] = data[g["src"]]
            F = F.reshape(G, m, m)
            F11 = F[:, :kc, :kc]
            F11 = np.tril(F11) + np.swapaxes(np.tril(F11, -1), 1, 2)
            try:
                L11 = np.linalg.cholesky(F11)
            except np.linalg.LinAlgError:
                raise SingularSystemError("the linear system is not positive definite (a "
                                          "pivot of the Cholesky factorisation is not "
                                          "positive)") from None
            L21 = np.swapaxes(np.linalg.solve(L11, np.swapaxes(F[:, kc:, :kc], 1, 2)), 1, 2)
            U = F[:, kc:, kc:] - L21 @ np.swapaxes(L21, 1, 2)
            pool[g["pidx"]] = U.ravel()
            self.L_leaf.append((np.linalg.inv(L11), L21))
        potrf, trsm, syrk, trtri = lapack.dpotrf, blas.dtrsm, blas.dsyrk, lapack.dtrtri
        self.L_inner = []
        for f in self.inner:
            m, kc = f["m"], f["k"]
            F = np.zeros(m * m)
            F[f["dst"]] = data[f["src"]]
            F = F.reshape(m, m)
            for off, u, pairs in f["adds"]:
                # extend-add of a child's update (only lower triangles are valid and read)
                C = pool[off:off + u * u].reshape(u, u)
                for fr, fc, cr, cc in pairs:
                    F[fr, fc] += C[cr, cc]
            L11, info = potrf(F[:kc, :kc], lower=1, clean=1, overwrite_a=0)
            if info != 0:
                raise SingularSystemError("the linear system is not positive definite (a "
                                          "pivot of the Cholesky factorisation is not positive)")
            if m > kc:
                L21 = trsm(1.0, L11, F[kc:, :kc], side=1, lower=1, trans_a=1)
                # U = F22 - L21 L21^T written in place into the pool (row-major lower
                # triangle = column-major upper of the transpose); only lower triangles are
                # read downstream, so no symmetrisation
                u = m - kc
                V = pool[f["poff"]:f["poff"] + u * u].reshape(u, u)
                V[...] = F[kc:, kc:]
                syrk(-1.0, L21, beta=1.0, c=V.T, trans=0, lower=0, overwrite_c=1)
            else:
                L21 = np.zeros((0, kc))
            Linv, _ = trtri(L11, lower=1)  # the solves become matrix products
            self.L_inner.append((Linv, L21))

    def solve(self, b: np.ndarray) -> np.ndarray:
        b = np.asarray(b, dtype=np.float64)
        vec = b.ndim == 1
        y = (b[:, None] if vec else b)[self.sperm].copy()
        nr = y.shape[1]
        for g, (Li, L21) in zip(self.leaf_groups, self.L_leaf, strict=True):
            yc = Li @ y[g["cidx"]]  # (G, kc, nr)
            y[g["cidx"]] = yc
            upd = L21 @ yc  # (G, u, nr)
            if nr > 1:
                np.subtract.at(y, g["ridx"], upd)
            else:
                y[:, 0] -= np.bincount(g["ridx"].ravel(), weights=upd.ravel(),
                                       minlength=y.shape[0])
        for f, (Li, L21) in zip(self.inner, self.L_inner, strict=True):
            c0, kc = f["c0"], f["k"]
            yc = Li @ y[c0:c0 + kc]
            y[c0:c0 + kc] = yc
            if L21.shape[0]:
                y[f["rows"]] -= L21 @ yc
        for f, (Li, L21) in zip(reversed(self.inner), reversed(self.L_inner), strict=True):
            c0, kc = f["c0"], f["k"]
            rhs = y[c0:c0 + kc]
            if L21.shape[0]:
                rhs = rhs - L21.T @ y[f["rows"]]
            y[c0:c0 + kc] = Li.T @ rhs
        for g, (Li, L21) in zip(self.leaf_groups, self.L_leaf, strict=True):
            rhs = y[g["cidx"]] - np.swapaxes(L21, 1, 2) @ y[g["ridx"]]
            y[g["cidx"]] = np.swapaxes(Li, 1, 2) @ rhs
        x = np.empty_like(y)
        x[self.sperm] = y
        if not np.all(np.isfinite(x)):
            raise SingularSystemError("the linear system is singular (the solution is not "
                                      "finite)")
        return x[:, 0] if vec else x


def _closed(L: Any, nb: int) -> Any:
    """The symbolic Cholesky pattern containing SuperLU's numeric ``L``: SuperLU can drop an
    entry that cancelled exactly, so close the pattern under ``struct(j) - {p} <= struct(p)``
    (``p`` the parent of ``j``). The check is vectorised; the (rare) repair loops."""
    L = sp.tril(L, -1).tocsc()
    L.sort_indices()
    cols = np.repeat(np.arange(nb), np.diff(L.indptr))
    rows = L.indices.astype(np.int64)
    parent = np.full(nb, -1, np.int64)
    has = np.diff(L.indptr) > 0
    parent[has] = rows[L.indptr[:-1][has]]
    keys = cols * nb + rows  # sorted: by column, then row
    p = parent[cols]
    need = rows != p
    want = p[need] * nb + rows[need]
    k = np.searchsorted(keys, want)
    ok = (k < keys.size) & (keys[np.minimum(k, keys.size - 1)] == want)
    if not ok.all():
        struct = [rows[L.indptr[j]:L.indptr[j + 1]] for j in range(nb)]
        for j in range(nb):
            sj = struct[j]
            if sj.size > 1:
                struct[sj[0]] = np.union1d(struct[sj[0]], sj[1:])
        cnt = np.array([x.size for x in struct])
        L = sp.csc_matrix((np.ones(cnt.sum()), np.concatenate(struct),
                           np.concatenate([[0], np.cumsum(cnt)])), shape=(nb, nb))
    return (L + sp.eye(nb)).tocsc()


def _etree(L: Any, nb: int) -> np.ndarray:
    """Parent of each column: the first row below the diagonal in its column of ``L``."""
    parent = np.full(nb, -1, np.int64)
    Lc = sp.tril(L, -1).tocsc()
    Lc.sort_indices()
    has = np.diff(Lc.indptr) > 0
    parent[has] = Lc.indices[Lc.indptr[:-1][has]]
    return parent


def _postorder(parent: np.ndarray, nb: int) -> np.ndarray:
    children: list[list[int]] = [[] for _ in range(nb)]
    roots: list[int] = []
    for j in range(nb):
        p = int(parent[j])
        (children[p] if p >= 0 else roots).append(j)
    out: list[int] = []
    stack = [(r, 0) for r in reversed(roots)]
    while stack:
        node, state = stack.pop()
        if state == 0:
            stack.append((node, 1))
            for c in reversed(children[node]):
                stack.append((c, 0))
        else:
            out.append(node)
    return np.array(out, dtype=np.int64)


def _amalgamate(snodes: list[tuple[int, int]], struct: list[np.ndarray]
                ) -> list[tuple[int, int]]:
    """Merge a supernode into the next one (its parent, contiguous) when the merged one stays
    small or adds few explicit zeros."""
    out: list[list[Any]] = []  # [start, end, rows(set), nnz_true]
    for a, b in snodes:
        rows = set(struct[a][struct[a] >= b].tolist())
        k = b - a
        # true nonzeros of the supernode's columns (dense triangle + rows below)
        true = k * (k + 1) // 2 + k * len(rows)
        cur = [a, b, rows, true]
        while out:
            pa, pb, prow, ptrue = out[-1]
            if pb != a or a not in prow:  # not contiguous or not the parent
                break
            # a supernode with several children: only the last (contiguous) one merges
            merged_rows = (prow - set(range(a, b))) | rows
            k2 = b - pa
            total = k2 * (k2 + 1) // 2 + k2 * len(merged_rows)
            zeros = 1.0 - (ptrue + cur[3]) / total
            ok = any(k2 <= mx and zeros <= z for mx, z in _RELAX)
            if not ok:
                break
            out.pop()
            cur = [pa, b, merged_rows, ptrue + cur[3]]
        out.append(cur)
    return [(a, b) for a, b, _, _ in out]
