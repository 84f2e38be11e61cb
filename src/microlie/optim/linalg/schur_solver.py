"""Schur-complement elimination as a linear solver of the engine (``linear_solver="schur"``).

The unknowns of ``H x = b`` come in blocks (nodes: one variable each). A set ``E`` of nodes
whose diagonal blocks are the only blocks they share with one another (no two of them in one
factor: landmarks) is eliminated:

    [ A    B ] [x_r]   [b_r]
    [ B^T  C ] [x_e] = [b_e],   C = blockdiag(C_1, ..., C_m),

    S = A - B C^-1 B^T,   S x_r = b_r - B C^-1 b_e,   x_e = C^-1 (b_e - B^T x_r).

With ``C_e = L_e L_e^T`` (batched Cholesky of the ``d x d`` blocks) and ``V_e = L_e^-1 B_e^T``
(``B_e^T`` the ``d x k_e`` rows of node ``e`` against the ``k_e`` unknowns of its neighbours),
node ``e`` adds ``-V_e^T V_e`` to ``S``: one batched matrix product per group of eliminated
nodes of the same size ``(d, k_e)``, summed into ``S``'s compressed columns by one ``bincount``
over scatter positions computed once. The nodes that stay are grouped in supernodes (nodes
with the same neighbours, such as the rotation, translation and intrinsics of one bundle
adjustment camera), so that ``S`` is stored and formed in their larger dense blocks. The
reduced system is factorised by one of the
backends of :func:`~microlie.optim.linalg.linear.make_solver` (dense LAPACK Cholesky when it
is small or dense, the sparse supernodal Cholesky otherwise), analysed once as well: every
symbolic step (the pattern of ``S``, fixed by ``H``'s, its ordering and the scatter maps)
happens in :meth:`SchurSolver.analyse`, and each factorisation is numeric work only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp  # type: ignore[import-untyped]

from ..._fast import compiled as compiled_module
from .linear import LinearSolver, SingularSystemError, make_solver

__all__ = ["SchurSolver", "REDUCED_SOLVERS", "reduced_choice"]

#: The backends that can factorise the reduced system (``"auto"``: :func:`reduced_choice`).
REDUCED_SOLVERS = ("auto", "dense", "cholesky", "scipy", "qdldl", "pardiso")
#: ``"auto"`` factorises the reduced system densely up to ``DENSE_ALWAYS`` unknowns, and, when
#: the supernodal Cholesky runs its NumPy loop, up to ``DENSE_MAX`` unknowns when at least
#: ``DENSE_FILL`` of it is nonzero (see :func:`reduced_choice`).
DENSE_ALWAYS = 100
DENSE_FILL = 0.8
DENSE_MAX = 600


def reduced_choice(n: int, nnz: int, compiled: bool | None = None) -> str:
    """The backend ``"auto"`` chooses for a reduced system of ``n`` unknowns and ``nnz`` stored
    entries (full symmetric storage): ``"dense"`` (LAPACK) up to :data:`DENSE_ALWAYS` unknowns,
    or, without the compiled supernode loop, up to :data:`DENSE_MAX` when at least
    :data:`DENSE_FILL` of the matrix is nonzero; else ``"cholesky"``.

    Measured (factorisation and solve, one BLAS thread; blocks of 9, banded and random
    patterns): the supernodal Cholesky's compiled loop beat LAPACK's dense one at every size
    and fill tried, 450 unknowns full included (1.4 against 2.8 ms); its NumPy loop lost to
    the dense one only on small full matrices (450 full: 6.5 against 2.8 ms; 900 at fill 0.52:
    17 against 25 ms; 2700 at fill 0.56: 263 against 451 ms).

    Parameters
    ----------
    n : int
        Unknowns of the reduced system.
    nnz : int
        Its stored entries.
    compiled : bool, optional
        Whether the supernodal Cholesky runs its compiled loop (default: whether it is
        installed and enabled).

    Returns
    -------
    str

    Examples
    --------
    >>> from microlie.optim.linalg.schur_solver import reduced_choice
    >>> reduced_choice(60, 3600), reduced_choice(441, 441 ** 2, compiled=False)
    ('dense', 'dense')
    >>> reduced_choice(441, 441 ** 2, compiled=True), reduced_choice(30000, 30000 * 60)
    ('cholesky', 'cholesky')
    """
    if compiled is None:
        compiled = compiled_module("_chol") is not None
    if n <= DENSE_ALWAYS or (not compiled and n <= DENSE_MAX and nnz >= DENSE_FILL * n * n):
        return "dense"
    return "cholesky"


@dataclass
class _Group:
    """Eliminated nodes of one size: ``d`` unknowns each, ``k`` neighbouring unknowns."""

    cols: np.ndarray  # (m, d) their unknowns
    cidx: np.ndarray  # (m, d, d) positions of C_e in the extended data
    bidx: np.ndarray  # (m, k, d) positions of B_e
    rows: np.ndarray  # (m, k) neighbouring unknowns, reduced numbering
    span: tuple[int, int]  # their products' slice of the contribution buffer
    p0: np.ndarray  # (m, dg, dg) position in S of entry (0, 0) of each pair of neighbours
    nd: np.ndarray  # (m, dg) unknowns of each neighbour
    cl: np.ndarray  # (m, dg) length of the scalar columns of each neighbour in S


class SchurSolver(LinearSolver):
    """Solve ``H x = b`` by eliminating a set of nodes whose blocks of ``H`` are block
    diagonal, then factorising the reduced system ``S = A - B C^-1 B^T`` with a backend.

    Built by ``FactorGraph.optimize(linear_solver="schur", eliminate=...)`` through
    :func:`microlie.optim.core.elimination.schur_solver`; directly, on any CSC pattern whose
    unknowns are grouped in nodes.

    Parameters
    ----------
    node_off : array_like of int
        ``(nodes + 1,)`` the first unknown of each node, then the number of unknowns.
    eliminate : array_like of int
        The nodes to eliminate: no two of them may share an off-diagonal block of ``H``
        (checked by :meth:`analyse`), and at least one node must remain.
    reduced : str
        The backend of the reduced system: ``"auto"`` (:func:`reduced_choice`, by its size and
        fill), ``"dense"``, ``"cholesky"``, ``"scipy"``, ``"qdldl"`` or ``"pardiso"``.

    Raises
    ------
    ValueError
        Bad ``node_off``, ``eliminate`` or ``reduced``.

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.linalg.schur_solver import SchurSolver
    >>> H = np.array([[4.0, 1.0, 1.0], [1.0, 3.0, 0.0], [1.0, 0.0, 2.0]])
    >>> A = sp.csc_matrix(H)
    >>> s = SchurSolver([0, 1, 2, 3], eliminate=[1, 2])  # nodes 1 and 2 share no block
    >>> s.analyse(A.indptr, A.indices, 3)
    >>> s.factorize(A.data)
    >>> x = s.solve(np.array([6.0, 4.0, 3.0]))
    >>> np.allclose(x, np.linalg.solve(H, [6.0, 4.0, 3.0])), s.reduced_solver.name
    (True, 'dense')
    >>> s.n_reduced  # node 0 is left
    1
    """

    name = "schur"

    def __init__(self, node_off: Any, eliminate: Any, reduced: str = "auto") -> None:
        off = np.asarray(node_off, dtype=np.int64)
        if off.ndim != 1 or off.size < 2 or off[0] != 0 or np.any(np.diff(off) <= 0):
            raise ValueError("node_off must be increasing node offsets starting at 0, "
                             f"got {np.asarray(node_off).tolist()[:8]}")
        elim = np.asarray(eliminate, dtype=np.int64).ravel()
        nn = off.size - 1
        if elim.size == 0:
            raise ValueError("eliminate is empty: name at least one node to eliminate")
        if elim.min() < 0 or elim.max() >= nn:
            raise ValueError(f"eliminate must hold node numbers in [0, {nn}), got "
                             f"{int(elim.min())}..{int(elim.max())}")
        if np.unique(elim).size != elim.size:
            raise ValueError("eliminate names a node twice")
        if elim.size == nn:
            raise ValueError("eliminate names every node: nothing is left to reduce to")
        if reduced not in REDUCED_SOLVERS:
            raise ValueError(f"reduced must be one of {REDUCED_SOLVERS}, got {reduced!r}")
        self.node_off = off
        self.eliminated = np.sort(elim)
        self.reduced = reduced
        #: what :meth:`Problem.analysed` caches the analysed solver under
        self.key: tuple = ("schur", reduced, self.eliminated.tobytes())
        self.reduced_solver: LinearSolver | None = None

    # ---------------------------------------------------------------- analysis
    def analyse(self, indptr: np.ndarray, indices: np.ndarray | None, n: int,
                block_size: int = 1, block_pattern: Any = None) -> None:
        """The symbolic work, once per pattern: the eliminated blocks' positions, the pattern
        of the reduced system (its blocks: ``A``'s and every pair of neighbours of an
        eliminated node), the scatter of every product into it, and the reduced system's own
        analysis by its backend.

        Parameters
        ----------
        indptr, indices : numpy.ndarray
            The CSC pattern of the full symmetric matrix (rows sorted in each column).
        n : int
            The matrix size (``node_off[-1]``).
        block_size : int
            The unknowns come in blocks of that size (each node holds whole blocks).
        block_pattern : (numpy.ndarray, numpy.ndarray), optional
            The CSC of the ``block_size`` blocks (see
            :meth:`~microlie.optim.linalg.base.LinearSolver.analyse`): when given, ``H``'s
            blocks of nodes are read off it, never off the scalar pattern (``indices`` may then
            be ``None``).

        Raises
        ------
        ValueError
            Two eliminated nodes share a block, or the pattern does not fit ``node_off``.

        Examples
        --------
        >>> import numpy as np
        >>> import scipy.sparse as sp
        >>> from microlie.optim.linalg.schur_solver import SchurSolver
        >>> A = sp.csc_matrix(np.array([[4.0, 1.0, 1.0], [1.0, 3.0, 0.0], [1.0, 0.0, 2.0]]))
        >>> s = SchurSolver([0, 1, 2, 3], eliminate=[1, 2])
        >>> s.analyse(A.indptr, A.indices, 3)
        >>> s.n_reduced, s.reduced_solver.name
        (1, 'dense')
        """
        super().analyse(indptr, indices, n, block_size, block_pattern)
        off = self.node_off
        if off[-1] != n:
            raise ValueError(f"node_off ends at {int(off[-1])}, the matrix has {n} unknowns")
        nn = off.size - 1
        dof = np.diff(off)
        # H by blocks of nodes: every step below works on these (a few per pair of nodes that
        # share a factor), never on H's scalar entries; entry (a, b) of block (u, v) is at
        # hpos[block] + b * hlen[v] + a of H's data (padded when H does not store it)
        bu, bv = self._node_blocks(block_size, block_pattern)
        hpos, hlen = _block_offsets(bu, bv, dof)
        hkey = bv * nn + bu  # ascending
        is_e = np.zeros(nn, dtype=bool)
        is_e[self.eliminated] = True
        eu_, ev_ = is_e[bu], is_e[bv]
        clash = np.flatnonzero(eu_ & ev_ & (bu != bv))
        if clash.size:
            a, b = int(bu[clash[0]]), int(bv[clash[0]])
            raise ValueError(f"eliminated nodes {a} and {b} share a block of the matrix: only "
                             f"nodes that share no factor can be eliminated together")
        # the reduced numbering: the nodes that stay, grouped in supernodes (nodes with the
        # same closed neighbourhood in H's block graph, e.g. the rotation, translation and
        # intrinsics of one camera: their blocks of S are dense together, so one block of
        # their summed size loses no sparsity), unknowns supernode by supernode
        rnode = _supernodes(bv, bu, is_e)  # node -> supernode, -1: eliminated
        ns = int(rnode.max()) + 1
        kept = np.flatnonzero(~is_e)
        kept = kept[np.argsort(rnode[kept], kind="stable")]  # the nodes in reduced order
        rdof = np.bincount(rnode[kept], weights=dof[kept], minlength=ns).astype(np.int64)
        roff = np.concatenate([[0], np.cumsum(rdof)]).astype(np.int64)
        nR = int(roff[-1])
        kd = dof[kept]
        self._r_unk = (np.repeat(off[kept], kd)
                       + np.arange(nR) - np.repeat(np.cumsum(kd) - kd, kd))  # reduced -> H
        node = np.repeat(np.arange(nn, dtype=np.int64), dof)  # node of each unknown
        # each reduced unknown's place in its supernode
        lin = np.full(n, -1, np.int64)
        lin[self._r_unk] = np.arange(nR) - roff[rnode[node[self._r_unk]]]
        self.supernodes = ns

        def at_e(row: np.ndarray, es: np.ndarray, d: int) -> np.ndarray:
            """The positions of ``H[row, off[es] + arange(d)]``: ``(m, r, d)`` (the blocks
            are stored: the rows are the node's own and its neighbours')."""
            rn = node[row]
            k = np.searchsorted(hkey, es[:, None] * nn + rn)
            p0 = hpos[k] + row - off[rn]
            return p0[:, :, None] + np.arange(d) * hlen[es][:, None, None]

        # the blocks (e, u) of eliminated nodes against the supernodes that stay, by e then u
        sel = ev_ & ~eu_
        eu = _unique_keys([bv[sel] * ns + rnode[bu[sel]]], nn * ns)
        pe, pu = eu // ns, eu % ns  # eliminated node, neighbouring supernode
        # the pattern of S, by blocks of the reduced nodes: A's blocks and, for every
        # eliminated node, all pairs of its neighbours
        ra = np.flatnonzero(~eu_ & ~ev_)
        keys = [rnode[bv[ra]] * ns + rnode[bu[ra]], np.arange(ns) * (ns + 1)]
        # eliminated nodes grouped by (dof, degree, neighbouring unknowns)
        deg = np.bincount(pe, minlength=nn)
        kun = np.bincount(pe, weights=rdof[pu], minlength=nn).astype(np.int64)
        pstart = np.concatenate([[0], np.cumsum(deg)])  # node e's pairs: pstart[e]..
        sig = np.stack([dof[self.eliminated], deg[self.eliminated], kun[self.eliminated]], 1)
        sigs, inv = np.unique(sig, axis=0, return_inverse=True)
        inv = inv.ravel()
        plan = []
        for g, (d, dg, k) in enumerate(sigs.tolist()):
            es = self.eliminated[inv == g]
            if dg:
                nb = pu[pstart[es][:, None] + np.arange(dg)]  # (m, dg) neighbours
                # nodes with the same neighbours one after the other: they update the same
                # blocks of S while these are in cache
                o = np.lexsort(nb.T[::-1])
                es, nb = es[o], nb[o]
                keys.append((nb[:, None, :] * ns + nb[:, :, None]).ravel())
            else:
                nb = np.zeros((es.size, 0), np.int64)
            plan.append((es, nb, d, dg, k))
        bkey = _unique_keys(keys, ns * ns)  # col * ns + row, ascending
        su, sv = bkey % ns, bkey // ns
        pos0, collen = _block_offsets(su, sv, rdof)
        sptr = np.searchsorted(sv, np.arange(ns + 1))
        self._s_nnz = int(np.sum(rdof * collen))

        # the blocks' positions by key: a table when it is small (a street scene asks for tens
        # of millions of neighbour pairs: a gather instead of as many binary searches)
        table = None
        if ns * ns <= DENSE_TABLE:
            table = np.zeros(ns * ns, np.int64)
            table[bkey] = pos0

        def s_at(u: np.ndarray, v: np.ndarray) -> np.ndarray:
            """The position in S of entry (0, 0) of block (u, v) (supernodes)."""
            if table is not None:
                return table[v * ns + u]
            return pos0[np.searchsorted(bkey, v * ns + u)]

        # A's entries: H position -> S position, block by block
        du, dv = dof[bu[ra]], dof[bv[ra]]
        cnt = du * dv
        rep = np.repeat(np.arange(ra.size), cnt)
        within = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        bb, aa = within // du[rep], within % du[rep]
        u, v = bu[ra][rep], bv[ra][rep]
        self._a_src = hpos[ra][rep] + bb * hlen[v] + aa
        self._a_dst = (s_at(rnode[u], rnode[v]) + lin[off[v] + bb] * collen[rnode[v]]
                       + lin[off[u] + aa])
        del du, dv, cnt, rep, within, bb, aa, u, v
        # per group: the index arrays of C_e, B_e^T, the rows and the scatter into S
        # the compiled loop writes straight into S from the blocks' positions; the NumPy one
        # scatters every product through one bincount over all their destinations
        self._elim = compiled_module("_normal")
        groups, dests, total = [], [], 0
        rowsall, at_rows = [], []
        for es, nb, d, dg, k in plan:
            m = es.size
            ecols = off[es][:, None] + np.arange(d)  # (m, d)
            cidx = at_e(ecols, es, d)  # C[a, b] = H[col_a, col_b]
            nd = rdof[nb]  # (m, dg)
            rb = nb
            P0 = s_at(rb[:, :, None], rb[:, None, :])  # (m, dg, dg): block (row j1, col j2)
            if dg:
                # the neighbouring unknowns of each node, in order: (m, k), and for each the
                # position of its neighbour in the list and its offset in that node
                first = np.cumsum(nd, axis=1) - nd
                jt = np.zeros((m, k), np.int64)
                np.put_along_axis(jt, first, 1, axis=1)
                jt = np.cumsum(jt, axis=1) - 1
                loc = np.arange(k) - np.take_along_axis(first, jt, axis=1)
                un = np.take_along_axis(nb, jt, axis=1)  # supernode of each row
                rr = roff[un] + loc  # (m, k) reduced unknowns
                rows = self._r_unk[rr]  # and in H
                bidx = at_e(rows, es, d)  # B[t, a] = H[row_t, col_a]
                if self._elim is None and np.all(nd == nd[0, 0]):  # one size: broadcasting
                    dl = int(nd[0, 0])
                    la = np.arange(dl)
                    acl = collen[rb][:, :, None] * la  # (m, dg, dl): a2 * collen
                    dests.append((P0[:, :, None, :, None] + la[:, None, None]
                                  + acl[:, None, None, :, :]).ravel())
                elif self._elim is None:
                    ii = np.arange(m)[:, None, None]
                    j1, j2 = jt[:, :, None], jt[:, None, :]
                    cl = collen[un]  # (m, k)
                    dests.append((P0[ii, j1, j2] + loc[:, None, :] * cl[:, None, :]
                                  + loc[:, :, None]).ravel())
                rowsall.append(rr.ravel())
            else:
                bidx = np.zeros((m, 0, d), np.int64)
                rr = np.zeros((m, 0), np.int64)
            at_rows.append(total)
            span = (0, 0) if self._elim is not None else (total, total + m * k * k)
            groups.append(_Group(ecols, cidx, bidx, rr, span, P0, nd,
                                 np.ascontiguousarray(collen[rb])))
            total += span[1] - span[0]
        self._groups = groups
        if self._elim is not None:
            # the compiled loop writes S's upper block triangle only: the positions of the
            # lower blocks' entries and of their transposes, copied after it
            lb = np.flatnonzero(su > sv)
            du, dv = rdof[su[lb]], rdof[sv[lb]]
            cnt = du * dv
            rep = np.repeat(np.arange(lb.size), cnt)
            within = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
            bb, aa = within // du[rep], within % du[rep]
            u, v = su[lb][rep], sv[lb][rep]
            self._low = pos0[lb][rep] + bb * collen[v] + aa
            self._up = s_at(v, u) + aa * collen[u] + bb
        # int64: bincount converts anything else to it, a copy per factorisation
        self._dest = np.concatenate(dests) if dests else np.zeros(0, np.int64)
        self._w = np.empty(total)  # the products V_e^T V_e of every group
        # the rhs scatter of the NumPy solve (t (sum m k) -> reduced rows, one sparse 0/1
        # product): built on its first use (the compiled solve of one right-hand side has none)
        self._rhs_rows = rowsall
        self._rhs_sum: Any = None
        # H's data then one zero, for the entries of C_e and B_e not stored (an H whose
        # blocks are dense has none: then the data is read in place, not copied)
        self._pad = self._spread is not None
        self._dz = np.zeros(int(np.sum(dof[bu] * dof[bv])) + 1) if self._pad else np.zeros(0)
        self.n_reduced = nR
        choice = reduced_choice(nR, self._s_nnz) if self.reduced == "auto" else self.reduced
        bs = int(np.gcd.reduce(rdof))
        inner = make_solver(choice, nR, bs)
        if np.all(rdof == bs):  # S's blocks are its supernodes': the backend expands them
            inner.analyse(_scalar_ptr(sptr, bs), None, nR, bs, block_pattern=(sptr, su))
        else:
            s_ip, s_ix = _block_csc(su, sv, rdof, roff, pos0, collen)
            inner.analyse(s_ip, s_ix, nR, bs)
        self.reduced_solver = inner
        self._factored = False

    def _node_blocks(self, bs: int, block_pattern: Any) -> tuple[np.ndarray, np.ndarray]:
        """H's blocks of nodes ``(rows, columns)`` (sorted by column, then row), read off the
        pattern of ``bs x bs`` blocks when given (the first sub-block of every node block),
        else off the scalar pattern. When H does not store its node blocks in full (a scalar
        pattern with holes), sets ``_spread``: the position of each stored entry in the data
        of the full blocks (:meth:`factorize` spreads the data into it, zeros elsewhere)."""
        off, n = self.node_off, self.n
        nn = off.size - 1
        dof = np.diff(off)
        self._spread: np.ndarray | None = None
        if block_pattern is not None and bs > 0 and not np.any(off % bs):
            bptr, bidx = (np.asarray(a, dtype=np.int64) for a in block_pattern)
            first = off[:-1] // bs  # first sub-block of each node
            sbnode = np.repeat(np.arange(nn, dtype=np.int64), dof // bs)
            lens = bptr[first + 1] - bptr[first]
            pos = (np.repeat(bptr[first] - np.cumsum(lens) + lens, lens)
                   + np.arange(int(lens.sum())))
            rows = bidx[pos]
            keep = rows * bs == off[sbnode[rows]]
            bu = sbnode[rows[keep]]
            bv = np.repeat(np.arange(nn, dtype=np.int64), lens)[keep]
            if int(np.sum(dof[bu] * dof[bv])) == self.nnz:  # every node block in full
                return bu, bv
        ip = np.asarray(self.indptr, dtype=np.int64)
        ix = np.asarray(self.indices, dtype=np.int64)
        cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(ip))
        if ix.size > 1 and np.any(np.diff(cols * n + ix) <= 0):
            raise ValueError("indices must be sorted within each column (canonical CSC)")
        node = np.repeat(np.arange(nn, dtype=np.int64), dof)
        cn = node[cols]
        key = _unique_keys([cn * nn + node[ix]], nn * nn)
        bu, bv = key % nn, key // nn
        if int(np.sum(dof[bu] * dof[bv])) != ix.size:
            pos0, collen = _block_offsets(bu, bv, dof)
            rn = node[ix]
            k = np.searchsorted(key, cn * nn + rn)
            self._spread = pos0[k] + (cols - off[cn]) * collen[cn] + ix - off[rn]
        return bu, bv

    # ---------------------------------------------------------------- numeric
    def factorize(self, data: np.ndarray) -> None:
        """Factorise: the eliminated blocks ``C_e = L_e L_e^T``, the reduced system
        ``S = A - B C^-1 B^T`` and its factorisation (numeric work only).

        Parameters
        ----------
        data : numpy.ndarray
            Values of ``H`` in the analysed pattern's order.

        Raises
        ------
        SingularSystemError
            A block ``C_e`` or the reduced system is not positive definite (``unknown``:
            the failing unknown of ``H``).

        Examples
        --------
        >>> import numpy as np
        >>> import scipy.sparse as sp
        >>> from microlie.optim.linalg.schur_solver import SchurSolver
        >>> A = sp.csc_matrix(np.array([[4.0, 1.0, 1.0], [1.0, 3.0, 0.0], [1.0, 0.0, 2.0]]))
        >>> s = SchurSolver([0, 1, 2, 3], eliminate=[1, 2])
        >>> s.analyse(A.indptr, A.indices, 3)
        >>> s.factorize(A.data)
        """
        data = np.ascontiguousarray(data, dtype=np.float64)
        if data.shape != (self.nnz,):
            raise ValueError(f"data has shape {data.shape}; the analysed pattern has "
                             f"{self.nnz} entries")
        self._factored = False
        if self._pad:
            dz = self._dz
            dz[self._spread] = data
        else:
            dz = data
        S = np.zeros(self._s_nnz)
        S[self._a_dst] = dz[self._a_src]
        self._li: list[np.ndarray] = []
        self._vt: list[tuple[np.ndarray, np.ndarray | None] | None] = []
        w = self._w
        for g in self._groups:
            if self._elim is not None:
                self._form_compiled(g, dz, data, S)
                continue
            C = dz[g.cidx]
            try:
                L = np.linalg.cholesky(C)
            except np.linalg.LinAlgError:
                L = np.full_like(C, np.nan)
            piv = np.diagonal(L, axis1=1, axis2=2) ** 2
            if not np.all(np.isfinite(piv)):
                bad = int(np.flatnonzero(~np.isfinite(piv).all(1)
                                         | ~(np.linalg.eigvalsh(C)[:, 0] > 0))[0])
                raise SingularSystemError(
                    "the linear system is singular or not positive definite: the block of an "
                    "eliminated variable is not positive definite", unknown=int(g.cols[bad, 0]))
            self._check_pivots(data, piv.ravel(), g.cols.ravel())
            Li = np.linalg.inv(L)  # lower triangular, d x d
            self._li.append(Li)
            if g.rows.shape[1]:
                # V = B L^-T (m, k, d) and its transpose, both contiguous: a batched matmul
                # with a transposed (strided) operand leaves BLAS and is 10-30x slower
                # (measured, NumPy 2.4)
                V = dz[g.bidx] @ np.ascontiguousarray(np.swapaxes(Li, 1, 2))
                VT = np.ascontiguousarray(np.swapaxes(V, 1, 2))
                a, b = g.span
                m, k = g.rows.shape
                np.matmul(V, VT, out=w[a:b].reshape(m, k, k))  # B C^-1 B^T per node
                self._vt.append((V, VT))
            else:
                self._vt.append(None)
        if self._elim is not None:
            S[self._low] = S[self._up]
        elif self._dest.size:
            S -= np.bincount(self._dest, weights=w, minlength=self._s_nnz)
        assert self.reduced_solver is not None
        try:
            self.reduced_solver.factorize(S)
        except SingularSystemError as e:
            u = None if e.unknown is None else int(self._r_unk[e.unknown])
            raise SingularSystemError(str(e).replace(f"unknown {e.unknown} ",
                                                     f"unknown {u} ") if u is not None
                                      else str(e), unknown=u) from None
        self._factored = True

    def _form_compiled(self, g: _Group, dz: np.ndarray, data: np.ndarray, S: np.ndarray
                       ) -> None:
        """Group ``g``'s part of :meth:`factorize` by the compiled loop (``_normal.form``)."""
        m, d = g.cols.shape
        k = g.rows.shape[1]
        Li, V, piv = np.empty((m, d, d)), np.empty((m, k, d)), np.empty((m, d))
        bad = self._elim.form(dz, g.cidx, g.bidx, g.p0, g.nd, g.cl, S, Li, V, piv)
        if bad >= 0:
            raise SingularSystemError(
                "the linear system is singular or not positive definite: the block of an "
                "eliminated variable is not positive definite", unknown=int(g.cols[bad, 0]))
        self._check_pivots(data, piv.ravel(), g.cols.ravel())
        self._li.append(Li)
        self._vt.append((V, None))  # V^T: formed by solve only for several right-hand sides

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve ``H x = b`` with the last factorisation: the reduced right-hand side
        ``b_r - B C^-1 b_e``, the reduced solve, then ``x_e = C^-1 (b_e - B^T x_r)``.

        Parameters
        ----------
        b : numpy.ndarray
            ``(n,)``, or ``(n, k)`` for ``k`` right-hand sides.

        Returns
        -------
        numpy.ndarray
            The solution, shaped as ``b``.

        Raises
        ------
        SingularSystemError
            No factorisation, or the solution is not finite.

        Examples
        --------
        >>> import numpy as np
        >>> import scipy.sparse as sp
        >>> from microlie.optim.linalg.schur_solver import SchurSolver
        >>> H = np.array([[4.0, 1.0, 1.0], [1.0, 3.0, 0.0], [1.0, 0.0, 2.0]])
        >>> A = sp.csc_matrix(H)
        >>> s = SchurSolver([0, 1, 2, 3], eliminate=[1, 2])
        >>> s.analyse(A.indptr, A.indices, 3)
        >>> s.factorize(A.data)
        >>> np.round(s.solve(H @ [1.0, 2.0, 3.0]), 12).tolist()
        [1.0, 2.0, 3.0]
        """
        b = np.asarray(b, dtype=np.float64)
        if b.ndim not in (1, 2) or b.shape[0] != self.n:
            raise ValueError(f"the right-hand side has shape {b.shape}; expected ({self.n},) "
                             f"or ({self.n}, k)")
        if not self._factored:
            raise SingularSystemError("no factorisation to solve with (none yet, or the last "
                                      "one failed)")
        B = b.reshape(self.n, -1)
        j = B.shape[1]
        if self._elim is not None and j == 1:
            return self._solve_compiled(b)
        ys, ts = [], []
        for g, Li, VT in zip(self._groups, self._li, self._vt, strict=True):
            y = Li @ B[g.cols]  # (m, d, j) = L^-1 b_e
            ys.append(y)
            if VT is not None:
                ts.append((VT[0] @ y).reshape(-1, j))  # (m k, j) B C^-1 b_e
        rhs = B[self._r_unk]
        if ts:
            if self._rhs_sum is None:
                rr = (np.concatenate(self._rhs_rows) if self._rhs_rows
                      else np.zeros(0, np.int64))
                self._rhs_sum = sp.csr_matrix((np.ones(rr.size), (rr, np.arange(rr.size))),
                                              shape=(self.n_reduced, rr.size))
            rhs = rhs - self._rhs_sum @ np.concatenate(ts)
        assert self.reduced_solver is not None
        xr = self.reduced_solver.solve(rhs if b.ndim == 2 else rhs[:, 0])
        xr = xr.reshape(-1, j)
        x = np.empty((self.n, j))
        x[self._r_unk] = xr
        for g, Li, VT, y in zip(self._groups, self._li, self._vt, ys, strict=True):
            if VT is not None:
                Vt = VT[1] if VT[1] is not None else np.ascontiguousarray(np.swapaxes(VT[0], 1, 2))
            z = y if VT is None else y - Vt @ xr[g.rows]  # L^-1 (b_e - B^T x_r)
            x[g.cols] = np.swapaxes(Li, 1, 2) @ z
        if not np.all(np.isfinite(x)):
            raise SingularSystemError("the linear system is singular (the solution is not "
                                      "finite)")
        return x[:, 0] if b.ndim == 1 else x

    def _solve_compiled(self, b: np.ndarray) -> np.ndarray:
        """:meth:`solve` for one right-hand side by the compiled loops (``_normal.rhs`` and
        ``_normal.back``)."""
        B = b.reshape(self.n)
        rhs = B[self._r_unk]
        ys = []
        for g, Li, VT in zip(self._groups, self._li, self._vt, strict=True):
            assert VT is not None
            y = np.empty(g.cols.shape)
            self._elim.rhs(Li, VT[0], g.rows, B[g.cols], y, rhs)
            ys.append(y)
        assert self.reduced_solver is not None
        xr = np.ascontiguousarray(self.reduced_solver.solve(rhs), dtype=np.float64).reshape(-1)
        x = np.empty(self.n)
        x[self._r_unk] = xr
        for g, Li, VT, y in zip(self._groups, self._li, self._vt, ys, strict=True):
            assert VT is not None
            xe = np.empty(g.cols.shape)
            self._elim.back(Li, VT[0], g.rows, y, xr, xe)
            x[g.cols] = xe
        if not np.all(np.isfinite(x)):
            raise SingularSystemError("the linear system is singular (the solution is not "
                                      "finite)")
        return x.reshape(b.shape)


#: :func:`_unique_keys` marks keys in a dense table up to this many possible keys (bytes)
DENSE_KEYS = 1 << 26
#: :meth:`SchurSolver.analyse` looks the reduced blocks up in a dense table of their positions
#: up to this many possible blocks (8 bytes each), by binary search above
DENSE_TABLE = 1 << 23


def _unique_keys(keys: list[np.ndarray], size: int) -> np.ndarray:
    """The sorted distinct values of ``keys`` (in ``[0, size)``): by marking a table of
    ``size`` flags when it is at most :data:`DENSE_KEYS` (linear time; a sort of the tens of
    millions of neighbour pairs of a street scene takes seconds), else by ``numpy.unique``."""
    if size <= DENSE_KEYS:
        seen = np.zeros(size, dtype=bool)
        for k in keys:
            seen[k] = True
        return np.flatnonzero(seen)
    return np.unique(np.concatenate(keys))


def _supernodes(u: np.ndarray, w: np.ndarray, is_e: np.ndarray) -> np.ndarray:
    """The supernode of each node that stays (-1 for the eliminated ones), numbered by their
    first node: nodes with the same closed neighbourhood in the block graph of ``H`` (the
    blocks ``(w, u)``, sorted by ``u`` then ``w``, diagonal included) form one supernode. Such
    nodes are adjacent and have the same blocks in ``S`` too, so storing them as one dense
    block loses no sparsity; the neighbourhoods are compared by their size and a 64-bit sum of
    fixed per-node keys (two different ones with the same keys would only make one denser
    block: the solve stays exact)."""
    nn = is_e.size
    # splitmix64 of the node numbers: fixed pseudo-random keys, summed with wrap-around
    z = (np.arange(nn, dtype=np.uint64) + np.uint64(1)) * np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z ^= z >> np.uint64(31)
    cs = np.concatenate([np.zeros(1, np.uint64), np.cumsum(z[w], dtype=np.uint64)])
    end = np.searchsorted(u, np.arange(nn), side="right")
    start = np.concatenate([[0], end[:-1]])
    h = cs[end] - cs[start]
    deg = (end - start).astype(np.uint64)
    kept = np.flatnonzero(~is_e)
    _, grp = np.unique(np.stack([deg[kept], h[kept]], 1), axis=0, return_inverse=True)
    grp = grp.ravel()
    # number the groups by their first node (kept is ascending)
    firsts = np.full(int(grp.max()) + 1 if grp.size else 0, nn, np.int64)
    np.minimum.at(firsts, grp, kept)
    rank = np.empty(firsts.size, np.int64)
    rank[np.argsort(firsts)] = np.arange(firsts.size)
    out = np.full(nn, -1, np.int64)
    out[kept] = rank[grp]
    return out


def _block_offsets(bu: np.ndarray, bv: np.ndarray, dof: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Where the dense blocks ``(bu, bv)`` (sorted by column ``bv``, then row ``bu``; nodes of
    ``dof`` unknowns) sit in their CSC data (full storage, rows sorted): every scalar column of
    block column ``v`` holds the same ``collen[v]`` rows, so entry ``(a, b)`` of block
    ``(u, v)`` is at ``pos0 + b * collen[v] + a``. Returns ``pos0`` (per block) and ``collen``
    (per node)."""
    nb = dof.size
    du = dof[bu]
    cs = np.cumsum(du) - du
    rowoff = cs - cs[np.searchsorted(bv, bv)]
    collen = np.bincount(bv, weights=du, minlength=nb).astype(np.int64)
    base = np.concatenate([[0], np.cumsum(dof * collen)]).astype(np.int64)
    return base[bv] + rowoff, collen


def _scalar_ptr(bptr: np.ndarray, bs: int) -> np.ndarray:
    """The scalar CSC column pointers of the pattern of ``bs x bs`` blocks ``bptr``."""
    return np.concatenate([[0], np.cumsum(np.repeat(np.diff(bptr) * bs, bs))]).astype(np.int64)


def _block_csc(bu: np.ndarray, bv: np.ndarray, dof: np.ndarray, off: np.ndarray,
               pos0: np.ndarray, collen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The scalar CSC pattern (``indptr``, ``indices``) of the dense blocks ``(bu, bv)`` laid
    out by :func:`_block_offsets` (``pos0``, ``collen``; nodes of ``dof`` unknowns at
    ``off``)."""
    nb = dof.size
    n = int(off[-1])
    du = dof[bu]
    cs = np.cumsum(du) - du
    base = np.concatenate([[0], np.cumsum(dof * collen)]).astype(np.int64)
    cnode = np.repeat(np.arange(nb), dof)  # node of each scalar column
    cin = np.arange(n) - off[cnode]  # column within its node
    indptr = np.concatenate([base[cnode] + cin * collen[cnode], [base[-1]]]).astype(np.int64)
    # the rows of each block column, once: blocks in order, each expanded to its unknowns
    rstart = np.concatenate([[0], np.cumsum(collen)])
    rowlist = np.repeat(off[bu], du) + (np.arange(int(du.sum())) - np.repeat(cs, du))
    lens = collen[cnode]
    within = np.arange(int(base[-1])) - np.repeat(indptr[:-1], lens)
    indices = rowlist[np.repeat(rstart[cnode], lens) + within]
    return indptr, indices.astype(np.int32)
