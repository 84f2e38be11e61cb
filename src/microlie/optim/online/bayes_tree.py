"""The Bayes tree of :class:`~microlie.optim.online.incremental.IncrementalSmoother` in flat
arrays, and its three operations: detaching the top, re-eliminating it, back-substituting.

Node ``j`` is one variable (``dof[j]`` columns at ``off[j]`` of the step). Its conditional is
``R_j x_j = c_j - T_j x_S`` on its separator ``S = sep[j]`` (nodes eliminated after it, the
first its parent); the tree stores ``Rinv[j] = R_j^-1``, ``T[j]`` and ``c[j]`` (so that
``x_j = Rinv[j] (c[j] - T[j] x_S)``) and the information its subtree passes to ``S`` (the
Schur complement ``Hs[j], bs[j]``: kept for every node, as any can become the root of an
orphan subtree).

Links: ``parent``, and the children as lists threaded through ``child`` (first child) and
``sib`` (next sibling). Rows (linearised factor residuals) have their nodes ``rnodes[r]``
(argument order) and ``H = A^T A``, ``b = -A^T e`` over them; ``node_rows[j]`` lists the rows
of node ``j``.

The operations run in one call each of the compiled module ``microlie._c._incremental`` when
it is built, else in the NumPy functions of this module (the same arithmetic: tested equal).
The compiled elimination factors one dense front per clique (the chain of nodes each nested in
the next) with SciPy's BLAS and LAPACK (``dpotrf``, ``dtrsm``, ``dsyrk``; plain loops for small
fronts) and keeps only the row-major upper triangle of a clique root's ``Hs`` (the lower is 0);
the NumPy one eliminates one node per front and keeps ``Hs`` whole.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg.lapack import dpotrf as _potrf  # type: ignore[import-untyped]
from scipy.linalg.lapack import dtrtri as _trtri  # type: ignore[import-untyped]

from ... import _fast

__all__ = ["BayesTree", "NotDetermined"]

_BLAS: list[bool] = []  # the compiled module has SciPy's BLAS and LAPACK


class NotDetermined(ValueError):
    """Elimination met a variable whose information block is not positive definite.

    Attributes
    ----------
    node : int
        The node.

    Examples
    --------
    >>> NotDetermined(3).node
    3
    """

    def __init__(self, node: int) -> None:
        super().__init__(f"node {node} is not determined")
        self.node = node


class BayesTree:
    """The flat Bayes tree (see the module docstring).

    Parameters
    ----------
    compiled : bool, optional
        Use ``microlie._c._incremental`` (default: when it is built and ``MICROLIE_FAST`` is
        not 0); ``False`` runs the NumPy functions.

    Examples
    --------
    >>> import numpy as np
    >>> t = BayesTree()
    >>> a, b = t.add_node(1, 0), t.add_node(1, 1)
    >>> r0 = t.add_row([a], np.array([[4.0]]), np.array([4.0]))      # 4 x_a = 4
    >>> r1 = t.add_row([a, b], np.array([[1.0, -1.0], [-1.0, 1.0]]), np.zeros(2))  # x_b = x_a
    >>> top, orphans, rows = t.detach(np.array([a, b]))
    >>> t.pos[[a, b]] = [0, 1]
    >>> t.eliminate(np.array([a, b]), rows, orphans)
    >>> dx = np.zeros(2)
    >>> t.backsubstitute(np.array([a, b]), orphans, dx, 0.0), dx.round(12).tolist()
    (2, [1.0, 1.0])
    """

    def __init__(self, compiled: bool | None = None) -> None:
        mod = _fast.module("_incremental")
        self.module: Any = mod if (compiled is None or compiled) else None
        if compiled and mod is None:
            raise ValueError("compiled=True: microlie._c._incremental is not available (not "
                             "built, or MICROLIE_FAST=0)")
        if self.module is not None and not _BLAS:  # SciPy's BLAS/LAPACK for wide fronts, once
            from scipy.linalg import cython_blas, cython_lapack  # type: ignore[import-untyped]

            self.module.set_blas(cython_blas.__pyx_capi__, cython_lapack.__pyx_capi__)
            _BLAS.append(True)
        self.n = 0
        cap = 16
        self.parent = np.full(cap, -1, dtype=np.int64)
        self.child = np.full(cap, -1, dtype=np.int64)
        self.sib = np.full(cap, -1, dtype=np.int64)
        self.dof = np.zeros(cap, dtype=np.int64)
        self.off = np.zeros(cap, dtype=np.int64)
        self.pos = np.zeros(cap, dtype=np.int64)
        self.chain = np.zeros(cap, dtype=np.int64)   # 1: nested in its parent (one clique)
        self.mark = np.zeros(cap, dtype=np.int64)    # scratch: 0 between calls
        self.loc = np.full(cap, -1, dtype=np.int64)  # scratch: -1 between calls
        self.chg = np.zeros(cap, dtype=np.float64)   # scratch: 0 between calls
        self.sep: list[np.ndarray] = []
        self.Rinv: list[np.ndarray] = []
        self.T: list[np.ndarray] = []
        self.c: list[np.ndarray] = []
        self.Hs: list[Any] = []
        self.bs: list[Any] = []
        self.node_rows: list[list[int]] = []
        self.rnodes: list[Any] = []
        self.rH: list[Any] = []
        self.rb: list[Any] = []
        self.rseen = np.zeros(cap, dtype=np.int64)   # scratch per row: 0 between calls

    # ------------------------------------------------------------------ building
    def add_node(self, dof: int, off: int) -> int:
        """Add a node of ``dof`` columns at step offset ``off``; return its id.

        Examples
        --------
        >>> t = BayesTree()
        >>> t.add_node(3, 0), t.add_node(3, 3), int(t.off[1])
        (0, 1, 3)
        """
        j = self.n
        if j == self.parent.size:
            grow = self.parent.size
            for name in ("parent", "child", "sib", "loc"):
                setattr(self, name, np.concatenate([getattr(self, name),
                                                    np.full(grow, -1, dtype=np.int64)]))
            for name in ("dof", "off", "pos", "chain", "mark"):
                setattr(self, name, np.concatenate([getattr(self, name),
                                                    np.zeros(grow, dtype=np.int64)]))
            self.chg = np.concatenate([self.chg, np.zeros(grow)])
        self.dof[j] = dof
        self.off[j] = off
        self.n = j + 1
        empty = np.zeros(0, dtype=np.int64)
        self.sep.append(empty)
        self.Rinv.append(np.zeros((0, 0)))
        self.T.append(np.zeros((0, 0)))
        self.c.append(np.zeros(0))
        self.Hs.append(None)
        self.bs.append(None)
        self.node_rows.append([])
        return j

    def add_row(self, nodes: Any, H: np.ndarray | None = None, b: np.ndarray | None = None
                ) -> int:
        """Add a row over ``nodes`` with its ``H`` and ``b`` (``None``: set before the row is
        eliminated); return its id.

        Examples
        --------
        >>> t = BayesTree()
        >>> a, b = t.add_node(1, 0), t.add_node(1, 1)
        >>> t.add_row([a, b]), t.node_rows[b]
        (0, [0])
        """
        r = len(self.rnodes)
        if r == self.rseen.size:
            self.rseen = np.concatenate([self.rseen, np.zeros_like(self.rseen)])
        nd = np.asarray(nodes, dtype=np.int64)
        self.rnodes.append(nd)
        self.rH.append(H)
        self.rb.append(b)
        for n in nd.tolist():
            self.node_rows[n].append(r)
        return r

    def remove_row(self, r: int) -> None:
        """Drop row ``r`` (its nodes keep their place in the tree).

        Examples
        --------
        >>> t = BayesTree()
        >>> a = t.add_node(1, 0)
        >>> t.remove_row(t.add_row([a]))
        >>> t.node_rows[a], t.rnodes[0] is None
        ([], True)
        """
        for n in self.rnodes[r].tolist():
            self.node_rows[n].remove(r)
        self.rnodes[r] = None
        self.rH[r] = None
        self.rb[r] = None

    # ------------------------------------------------------------------ operations
    def detach(self, marked: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Detach the top: ``marked`` nodes and their ancestors. Return ``(top, orphans,
        rows)``: the detached nodes, the roots of the subtrees left hanging (their cached
        ``Hs, bs`` join the elimination) and the rows whose nodes are all detached. The links
        of the top are cleared."""
        marked = np.ascontiguousarray(marked, dtype=np.int64)
        if self.module is not None:
            return self.module.detach(marked, self.parent, self.child, self.sib, self.mark,
                                      self.rseen, self.node_rows, self.rnodes, self.chain)
        parent, child, sib = self.parent, self.child, self.sib
        intop: set[int] = set()
        top: list[int] = []
        for n in marked.tolist():
            while n >= 0 and n not in intop:
                intop.add(n)
                top.append(n)
                n = int(parent[n])
        k = 0
        while k < len(top):  # whole cliques: the nested children of the top too
            ch = int(child[top[k]])
            while ch >= 0:
                if self.chain[ch] and ch not in intop:
                    intop.add(ch)
                    top.append(ch)
                ch = int(sib[ch])
            k += 1
        orphans: list[int] = []
        rows: list[int] = []
        seen: set[int] = set()
        for n in top:
            ch = int(child[n])
            while ch >= 0:
                if ch not in intop:
                    orphans.append(ch)
                    parent[ch] = -1
                ch = int(sib[ch])
            child[n] = -1
            parent[n] = -1
            for r in self.node_rows[n]:
                if r not in seen:
                    seen.add(r)
                    if all(m in intop for m in self.rnodes[r].tolist()):
                        rows.append(r)
        return (np.asarray(top, dtype=np.int64), np.asarray(orphans, dtype=np.int64),
                np.asarray(rows, dtype=np.int64))

    def eliminate(self, order: np.ndarray, rows: np.ndarray, orphans: np.ndarray) -> None:
        """Eliminate the detached nodes in ``order`` (``pos`` increasing along it) from
        ``rows`` and the orphans' cached information: multifrontal (NumPy: one variable per
        front; compiled: one front per clique, the same numbers up to rounding); a node nested
        in the next of the order is marked ``chain`` and keeps no Schur complement.

        Raises
        ------
        NotDetermined
            A front whose own block is not positive definite (``node`` names it).
        """
        order = np.ascontiguousarray(order, dtype=np.int64)
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        orphans = np.ascontiguousarray(orphans, dtype=np.int64)
        if self.module is not None:
            bad = self.module.eliminate(order, rows, orphans, self.rnodes, self.rH, self.rb,
                                        self.sep, self.Rinv, self.T, self.c, self.Hs, self.bs,
                                        self.parent, self.child, self.sib, self.dof, self.pos,
                                        self.loc, self.chain)
            if bad >= 0:
                raise NotDetermined(int(bad))
            return
        pos, dof = self.pos, self.dof
        waiting: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray, int]]] = {}

        def put(nodes: np.ndarray, H: np.ndarray, b: np.ndarray, who: int) -> None:
            first = int(nodes[np.argmin(pos[nodes])])
            waiting.setdefault(first, []).append((nodes, H, b, who))

        for r in rows.tolist():
            put(self.rnodes[r], self.rH[r], self.rb[r], -1)
        for o in orphans.tolist():
            put(self.sep[o], self.Hs[o], self.bs[o], o)
        for q, j in enumerate(order.tolist()):
            items = waiting.pop(j, [])
            nodes = {j}
            for it in items:
                nodes.update(it[0].tolist())
            nodes.discard(j)
            sep = np.array(sorted(nodes, key=lambda n: pos[n]), dtype=np.int64)
            allv = np.concatenate([[j], sep]).astype(np.int64)
            dofs = dof[allv]
            starts = np.concatenate([[0], np.cumsum(dofs)])
            w = int(starts[-1])
            loc = dict(zip(allv.tolist(), starts[:-1].tolist(), strict=True))
            F = np.zeros((w, w))
            g = np.zeros(w)
            for vs, H, b, who in items:
                if who >= 0:  # a subtree hangs from j
                    self.parent[who] = j
                    self.sib[who] = self.child[j]
                    self.child[j] = who
                ix = np.concatenate([np.arange(loc[n], loc[n] + dof[n]) for n in vs.tolist()])
                F[ix[:, None], ix] += H
                g[ix] += b
            d = int(dof[j])
            L, info = _potrf(F[:d, :d], lower=1, clean=1)
            if info != 0:
                raise NotDetermined(j)
            Linv = _trtri(L, lower=1)[0]
            T = Linv @ F[:d, d:]
            c = Linv @ g[:d]
            self.Rinv[j] = np.ascontiguousarray(Linv.T)
            self.T[j] = T
            self.c[j] = c
            self.sep[j] = sep
            Hs = F[d:, d:] - T.T @ T
            bs = g[d:] - T.T @ c
            self.Hs[j] = Hs
            self.bs[j] = bs
            self.parent[j] = -1
            self.chain[j] = 0
            if q > 0:  # the previous node nested in j (one clique): it keeps no Schur complement
                prev = int(order[q - 1])
                ps = self.sep[prev]
                if ps.size == sep.size + 1 and ps[0] == j and (ps[1:] == sep).all():
                    self.chain[prev] = 1
                    self.Hs[prev] = None
                    self.bs[prev] = None
            if sep.size:
                put(sep, Hs, bs, j)

    def adjacency(self, rows: np.ndarray, orphans: np.ndarray, head: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """The graph of the nodes ``head`` (local numbers ``0 .. len(head) - 1``) that the
        elimination of ``rows`` and the orphans' information creates: an edge between two
        nodes of one row or one orphan's separator. Returns CSR ``(indptr, indices)``
        (repeated entries kept; for the ordering).

        Examples
        --------
        >>> import numpy as np
        >>> t = BayesTree()
        >>> a, b, c = (t.add_node(1, k) for k in range(3))
        >>> r = t.add_row([a, b, c])
        >>> indptr, indices = t.adjacency(np.array([r]), np.zeros(0, np.int64),
        ...                               np.array([a, c]))
        >>> indptr.tolist(), indices.tolist()  # a and c (local 0 and 1) share the row
        ([0, 1, 2], [1, 0])
        """
        nb = int(head.size)
        loc = self.loc
        loc[head] = np.arange(nb)
        try:
            if self.module is not None:
                return self.module.adjacency(np.ascontiguousarray(rows, dtype=np.int64),
                                             np.ascontiguousarray(orphans, dtype=np.int64),
                                             self.rnodes, self.sep, loc, nb)
            pa: list[np.ndarray] = []
            pb: list[np.ndarray] = []
            groups = [self.rnodes[r] for r in rows.tolist()]
            groups += [self.sep[o] for o in orphans.tolist()]
            for g in groups:
                ix = loc[g]
                ix = ix[ix >= 0]
                if ix.size > 1:
                    pa.append(np.repeat(ix, ix.size))
                    pb.append(np.tile(ix, ix.size))
        finally:
            loc[head] = -1
        if pa:
            a_arr, b_arr = np.concatenate(pa), np.concatenate(pb)
            keep = a_arr != b_arr
            a_arr, b_arr = a_arr[keep], b_arr[keep]
        else:
            a_arr = b_arr = np.zeros(0, dtype=np.int64)
        o = np.argsort(a_arr, kind="stable")
        indptr = np.concatenate([[0], np.cumsum(np.bincount(a_arr, minlength=nb))])
        return indptr.astype(np.int64), b_arr[o].astype(np.int64)

    def backsubstitute(self, order: np.ndarray, orphans: np.ndarray, dx: np.ndarray,
                       wildfire: float) -> int:
        """Back-substitution with GTSAM's wildfire: the step of the nodes of ``order`` (from
        the root down; all *changed*), then, down the orphan subtrees, of every node with a
        changed separator variable: it is *changed* (and keeps its new step) when a component
        moved by ``wildfire`` or more, else it keeps its old step. Return how many nodes were
        computed."""
        order = np.ascontiguousarray(order, dtype=np.int64)
        orphans = np.ascontiguousarray(orphans, dtype=np.int64)
        if self.module is not None:
            return int(self.module.backsubstitute(order, orphans, dx, self.off, self.dof,
                                                  self.sep, self.Rinv, self.T, self.c,
                                                  self.child, self.sib, float(wildfire),
                                                  self.chg))
        off, dof = self.off, self.dof
        changed: set[int] = set()

        def back(k: int, keep: bool) -> None:
            o0 = int(off[k])
            o1 = o0 + int(dof[k])
            sep = self.sep[k]
            if sep.size:
                cols = np.concatenate([np.arange(off[s], off[s] + dof[s]) for s in sep.tolist()])
                v = self.c[k] - self.T[k] @ dx[cols]
            else:
                v = self.c[k]
            new = self.Rinv[k] @ v
            if keep or not np.abs(new - dx[o0:o1]).max() < wildfire:
                dx[o0:o1] = new
                changed.add(k)

        for k in order[::-1].tolist():
            back(k, True)
        count = order.size
        stack = orphans.tolist()
        while stack:
            k = stack.pop()
            if not changed.intersection(self.sep[k].tolist()):
                continue
            back(k, False)
            count += 1
            ch = int(self.child[k])
            while ch >= 0:
                stack.append(ch)
                ch = int(self.sib[ch])
        return int(count)
