"""Fill-reducing ordering and symbolic Cholesky analysis of a sparse symmetric pattern.

The functions work on a graph: the symmetric adjacency (``scipy.sparse`` CSR, no diagonal) of
the block pattern of the normal equations (one vertex per block of unknowns). An ordering is a
permutation ``p`` (new -> old: the matrix is factorised as ``A[p][:, p]``).

- :func:`minimum_degree_blocks`: the default order of a block (node) graph given as CSR arrays:
  our approximate minimum degree (Amestoy, Davis and Duff 1996; compiled,
  ``microlie._c._order``), or without the compiled code SciPy's :func:`minimum_degree`.
- :func:`minimum_degree`: multiple minimum degree (SuperLU's ``MMD_AT_PLUS_A``; SuperLU only
  orders: its incomplete factorisation with every off-diagonal entry dropped follows).
- :func:`symbolic`: the symbolic factor for an ordering, computed from the pattern alone, as
  every sparse Cholesky does: the elimination tree (Liu's algorithm with path compression),
  a postorder of it (an equivalent order: the same fill), and the column counts (Gilbert, Ng
  and Peyton: row subtrees counted through the least common ancestors of consecutive entries,
  found here by binary lifting). Nothing numeric is factorised, so no entry can cancel.
- :func:`fill_order`: the order of the supernodal solver with its symbolic factor.

Examples
--------
A star: minimum degree eliminates the leaves before the hub, so there is no fill (``L`` has
the 5 diagonal entries and the 4 edges).

>>> import numpy as np
>>> import scipy.sparse as sp
>>> from microlie.optim.linalg.ordering import fill_order
>>> star = sp.csr_matrix((np.ones(8), ([0, 0, 0, 0, 1, 2, 3, 4], [1, 2, 3, 4, 0, 0, 0, 0])))
>>> s = fill_order(star)
>>> int(s.perm[0]) != 0, s.counts.tolist(), s.nnz
(True, [2, 2, 2, 2, 1], 9)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..._fast import compiled

__all__ = ["ORDERINGS", "Symbolic", "connected_components", "fill_order", "graph",
           "minimum_degree", "minimum_degree_blocks", "symbolic"]

# "auto": minimum_degree_blocks (our AMD when compiled); "mmd": SciPy's SuperLU MMD (nested
# dissection was measured and removed: issue 20)
ORDERINGS = ("auto", "mmd")


def graph(indptr: np.ndarray, indices: np.ndarray, n: int, block_size: int = 1) -> Any:
    """The graph of a block pattern: the symmetric adjacency of its blocks.

    Parameters
    ----------
    indptr, indices : numpy.ndarray
        The CSC pattern of an ``n x n`` matrix.
    n : int
        The matrix size.
    block_size : int
        The unknowns come in dense blocks of that size (1 when it does not divide ``n``).

    Returns
    -------
    scipy.sparse.csr_matrix
        ``(n // block_size, n // block_size)``, unit entries where two blocks meet, no
        diagonal.

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.linalg.ordering import graph
    >>> H = sp.csc_matrix(np.kron(np.array([[1, 1, 0], [1, 1, 1], [0, 1, 1]]), np.ones((2, 2))))
    >>> graph(H.indptr, H.indices, 6, 2).toarray().astype(int).tolist()
    [[0, 1, 0], [1, 0, 1], [0, 1, 0]]
    """
    import scipy.sparse as sp  # type: ignore[import-untyped]

    bs = block_size if block_size > 0 and n % block_size == 0 else 1
    nb = n // bs
    itype = np.int32 if n < 2**31 else np.int64
    rows = np.asarray(indices).astype(itype, copy=False) // bs
    cols = np.repeat(np.arange(n, dtype=itype) // bs, np.diff(indptr))
    if bs > 1 and rows.size:  # a run of rows of one block in a column counts once
        new = np.empty(rows.size, bool)
        new[0] = True
        np.not_equal(rows[1:], rows[:-1], out=new[1:])
        new[1:] |= cols[1:] != cols[:-1]
        rows, cols = rows[new], cols[new]
    A = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(nb, nb))
    return _clean(A)


def _clean(A: Any) -> Any:
    """The pattern of ``A + A^T`` without diagonal, unit data, sorted CSR."""
    import scipy.sparse as sp  # type: ignore[import-untyped]

    A = sp.csr_matrix(A)
    A = abs(A) + abs(A.T)
    A.setdiag(0)
    A.eliminate_zeros()
    A.data[:] = 1.0
    A.sort_indices()
    return A


def splu_symmetric(B: Any, spec: str) -> Any:
    """SuperLU in symmetric mode (diagonal pivots only) with the column order ``spec``."""
    from scipy.sparse.linalg import splu  # type: ignore[import-untyped]

    return splu(B, permc_spec=spec, diag_pivot_thresh=0.0, options={"SymmetricMode": True})


def minimum_degree(A: Any) -> np.ndarray:
    """Multiple minimum degree order of a graph (SuperLU's ``MMD_AT_PLUS_A``).

    SuperLU has no ordering-only entry point; its incomplete factorisation with a drop
    tolerance that drops every off-diagonal entry computes the same column order as the full
    factorisation at the cost of the ordering (the matrix: the pattern with a dominant
    diagonal, so no pivot is small).

    Parameters
    ----------
    A : scipy.sparse matrix
        The adjacency (of the pattern of ``A + A^T``; the diagonal and values are ignored).

    Returns
    -------
    numpy.ndarray
        The order, new -> old (int64).

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.linalg.ordering import minimum_degree
    >>> star = sp.csr_matrix((np.ones(8), ([0, 0, 0, 0, 1, 2, 3, 4], [1, 2, 3, 4, 0, 0, 0, 0])))
    >>> int(minimum_degree(star)[-1])  # the hub last: no fill
    0
    """
    return _mmd(_clean(A))


def _mmd(A: Any) -> np.ndarray:
    """:func:`minimum_degree` of a clean graph (:func:`_clean`)."""
    import scipy.sparse as sp  # type: ignore[import-untyped]
    from scipy.sparse.linalg import spilu  # type: ignore[import-untyped]

    n = A.shape[0]
    if n == 0:
        return np.zeros(0, np.int64)
    B = (sp.diags(np.diff(A.indptr) + 1.0) - A).tocsc()
    lu = spilu(B, drop_tol=1e300, fill_factor=1, permc_spec="MMD_AT_PLUS_A",
               diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    return np.argsort(lu.perm_c).astype(np.int64)


def minimum_degree_blocks(indptr: np.ndarray, indices: np.ndarray, nb: int,
                          method: str = "auto") -> np.ndarray:
    """The fill-reducing order of a block (node) graph: approximate minimum degree.

    With the compiled code, our approximate minimum degree (Amestoy, Davis and Duff 1996:
    quotient graph, element absorption, approximate external degrees, supervariables and mass
    elimination, aggressive absorption; nodes of degree above ``max(16, 10 sqrt(nb))`` last);
    without it (or ``MICROLIE_FAST=0``), :func:`minimum_degree` (SciPy's SuperLU). Both are
    deterministic.

    Parameters
    ----------
    indptr : numpy.ndarray
        ``nb + 1`` row pointers (int32 or int64) of the symmetric CSR pattern.
    indices : numpy.ndarray
        The column of each entry (int32 or int64), in ``[0, nb)``. A diagonal and repeated
        entries are ignored; the order within a row does not matter.
    nb : int
        The number of nodes.
    method : {"auto", "mmd"}
        ``"auto"`` as above; ``"mmd"`` always SciPy's SuperLU minimum degree (the order a
        default install without the compiled code uses).

    Returns
    -------
    numpy.ndarray
        The order, new -> old (int64): node ``perm[k]`` is eliminated ``k``-th.

    Raises
    ------
    ValueError
        ``method`` is not one of :data:`ORDERINGS`, ``indptr`` is not ``nb + 1``
        non-decreasing pointers from 0, an index is outside ``[0, nb)``, or the pattern is
        not symmetric (``(i, j)`` without ``(j, i)``).

    Examples
    --------
    A path 0 - 1 - 2 - 3: an end first (degree 1), never an inner node (no fill).

    >>> import numpy as np
    >>> from microlie.optim.linalg.ordering import minimum_degree_blocks
    >>> indptr = np.array([0, 1, 3, 5, 6])
    >>> indices = np.array([1, 0, 2, 1, 3, 2])
    >>> p = minimum_degree_blocks(indptr, indices, 4)
    >>> sorted(p.tolist()), int(p[0]) in (0, 3)
    ([0, 1, 2, 3], True)
    """
    nb = int(nb)
    if nb < 0:
        raise ValueError(f"nb must be >= 0, got {nb}")
    if method not in ORDERINGS:
        raise ValueError(f"unknown ordering {method!r}: expected one of {ORDERINGS}")
    indptr = np.asarray(indptr)
    indices = np.asarray(indices)
    for name, a in (("indptr", indptr), ("indices", indices)):
        if a.ndim != 1 or a.dtype.kind not in "iu":
            raise ValueError(f"{name} must be a 1-D integer array, got {a.dtype} {a.shape}")
    if indptr.size != nb + 1:
        raise ValueError(f"indptr must have nb + 1 = {nb + 1} entries, got {indptr.size}")
    mod = compiled("_order") if method == "auto" else None
    if mod is not None:
        return mod.order(np.ascontiguousarray(indptr, np.intp),
                         np.ascontiguousarray(indices, np.intp), nb).astype(np.int64, copy=False)
    import scipy.sparse as sp  # type: ignore[import-untyped]

    if indptr[0] != 0 or (np.diff(indptr) < 0).any() or indptr[-1] > indices.size:
        raise ValueError("indptr must start at 0, be non-decreasing and end at most at "
                         "len(indices)")
    idx = indices[:indptr[-1]]
    if idx.size and (idx.min() < 0 or idx.max() >= nb):
        raise ValueError(f"indices must be in [0, {nb})")
    # copies: the clean-up below works in place, and must not change the caller's arrays
    A = sp.csr_matrix((np.ones(idx.size), idx.copy(), indptr.copy()), shape=(nb, nb))
    A.sum_duplicates()
    A.setdiag(0)
    A.eliminate_zeros()
    A.data[:] = 1.0
    if (A != A.T).nnz:
        raise ValueError("the pattern must be symmetric: (i, j) present iff (j, i) present")
    A.sort_indices()
    return _mmd(A)


@dataclass(frozen=True)
class Symbolic:
    """The symbolic Cholesky factor of a graph under an order (returned by :func:`symbolic`
    and :func:`fill_order`), in the postorder ``perm`` of its elimination tree.

    Attributes
    ----------
    perm : numpy.ndarray
        The order (new -> old) in which ``L`` is stored: a postorder of the elimination tree
        of the requested order (the same fill; subtrees are contiguous).
    parent : numpy.ndarray
        The elimination tree in that order: the parent of each column (-1 for a root), the
        first row below the diagonal of its column of ``L``; ``parent[j] > j``.
    lower : scipy.sparse.csr_matrix
        The strictly lower pattern of ``A[perm][:, perm]`` (row ``i``: the columns ``k < i``).
    counts : numpy.ndarray
        The column counts of ``L``, diagonal included.
    nnz : int
        Their sum.
    flops : float
        ``sum(counts**2)``: the multiply-adds of the factorisation up to lower-order terms.
    height : int
        The height of the elimination tree (the longest chain of dependent columns).

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.linalg.ordering import symbolic
    >>> path = sp.diags([np.ones(3), np.ones(3)], [-1, 1], shape=(4, 4))
    >>> s = symbolic(path, np.arange(4))
    >>> s.counts.tolist(), s.nnz, s.flops, s.height, s.parent.tolist()
    ([2, 2, 2, 1], 7, 13.0, 4, [1, 2, 3, -1])
    """

    perm: np.ndarray
    parent: np.ndarray
    lower: Any
    counts: np.ndarray
    nnz: int
    flops: float
    height: int


def symbolic(A: Any, perm: np.ndarray) -> Symbolic:
    """The symbolic Cholesky factor of a graph under an order, from the pattern alone
    (elimination tree, postorder, column counts; see the module).

    Parameters
    ----------
    A : scipy.sparse matrix
        The adjacency (of the pattern of ``A + A^T``; the diagonal and values are ignored).
    perm : array_like of int
        The order, new -> old.

    Returns
    -------
    Symbolic

    Raises
    ------
    ValueError
        ``perm`` is not a permutation of the vertices.

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.linalg.ordering import symbolic
    >>> star = sp.csr_matrix((np.ones(6), ([0, 0, 0, 1, 2, 3], [1, 2, 3, 0, 0, 0])))
    >>> symbolic(star, [0, 1, 2, 3]).nnz, symbolic(star, [1, 2, 3, 0]).nnz  # hub first fills
    (10, 7)
    """
    perm = np.asarray(perm, dtype=np.int64)
    A = _clean(A)
    n = A.shape[0]
    if perm.shape != (n,) or not np.array_equal(np.sort(perm), np.arange(n)):
        raise ValueError(f"perm must be a permutation of 0..{n - 1}")
    return _symbolic(A, perm)


def _symbolic(A: Any, perm: np.ndarray) -> Symbolic:
    """:func:`symbolic` of a clean graph and a valid order."""
    n = A.shape[0]
    parent = _etree(_lower(A, perm))
    po = _postorder(parent)
    perm = perm[po]
    inv = np.empty(n, np.int64)
    inv[po] = np.arange(n)
    parent = np.where(parent[po] < 0, -1, inv[np.maximum(parent[po], 0)])
    lower = _lower(A, perm)
    up = _lifting(parent)
    counts = _counts(lower, parent, up)
    depth = np.zeros(n, np.int64)
    x = np.arange(n)
    for k in range(len(up) - 1, -1, -1):  # the number of ancestors, by binary lifting
        y = up[k][x]
        step = y < n
        depth[step] += 1 << k
        x[step] = y[step]
    return Symbolic(perm, parent, lower, counts, int(counts.sum()),
                    float((counts.astype(float) ** 2).sum()), int(depth.max()) + 1 if n else 0)


def _lower(A: Any, perm: np.ndarray) -> Any:
    """The strictly lower pattern of ``A[perm][:, perm]`` (CSR, sorted, int64 indices)."""
    import scipy.sparse as sp  # type: ignore[import-untyped]

    L = sp.tril(A[perm][:, perm], -1, format="csr")
    L.sort_indices()
    return L


def _etree(lower: Any) -> np.ndarray:
    """Liu's elimination tree with path compression: for each row ``i``, each column ``k < i``
    of it climbs from ``k`` through the (compressed) ancestors to the root of its current
    subtree, which becomes a child of ``i``."""
    n = lower.shape[0]
    indptr, indices = lower.indptr.tolist(), lower.indices.tolist()
    parent = [-1] * n
    anc = [-1] * n
    for i in range(n):
        for k in indices[indptr[i]:indptr[i + 1]]:
            while True:
                a = anc[k]
                if a == i:
                    break
                anc[k] = i
                if a < 0:
                    parent[k] = i
                    break
                k = a
    return np.array(parent, dtype=np.int64)


def _postorder(parent: np.ndarray) -> np.ndarray:
    """A postorder of the forest ``parent`` (children before parents, subtrees contiguous,
    children in ascending order): the reversed preorder of SciPy's compiled depth-first search
    from a virtual root, with the nodes relabelled ``n - 1 - j``."""
    mod = compiled("_order")
    if mod is not None:  # the same order, without SciPy
        return mod.postorder(np.ascontiguousarray(parent, np.intp)).astype(np.int64, copy=False)
    import scipy.sparse as sp  # type: ignore[import-untyped]
    from scipy.sparse.csgraph import depth_first_order  # type: ignore[import-untyped]

    n = parent.size
    p = np.where(parent < 0, n, n - 1 - parent)
    tree = sp.csr_matrix((np.ones(n), (p, n - 1 - np.arange(n))), shape=(n + 1, n + 1))
    pre = depth_first_order(tree, n, directed=True, return_predecessors=False)
    return (n - 1 - pre[1:])[::-1].astype(np.int64)


def connected_components(n: int, rows: np.ndarray, cols: np.ndarray) -> tuple[int, np.ndarray]:
    """The connected components of an undirected graph given by its edges (NumPy only).

    Hooking of roots to the smaller root of each edge and pointer jumping (Shiloach-Vishkin
    style), repeated until every edge joins two nodes of one label.

    Parameters
    ----------
    n : int
        The number of nodes.
    rows, cols : numpy.ndarray
        The edges ``rows[k] - cols[k]`` (integers in ``[0, n)``; either direction, repeats and
        loops allowed).

    Returns
    -------
    ncomp : int
        The number of components (isolated nodes included).
    label : numpy.ndarray
        The component of each node (int64), ``0 .. ncomp - 1`` in the order of each
        component's smallest node.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.linalg.ordering import connected_components
    >>> ncomp, label = connected_components(6, np.array([0, 4, 2]), np.array([1, 5, 1]))
    >>> ncomp, label.tolist()
    (3, [0, 0, 0, 1, 2, 2])
    """
    L = np.arange(n, dtype=np.int64)
    r = np.asarray(rows, dtype=np.int64).ravel()
    c = np.asarray(cols, dtype=np.int64).ravel()
    while r.size:
        lr, lc = L[r], L[c]
        diff = lr != lc
        if not diff.any():
            break
        r, c, lr, lc = r[diff], c[diff], lr[diff], lc[diff]  # the edges still to join
        m = np.minimum(lr, lc)
        np.minimum.at(L, lr, m)  # each root hooks under the smallest root it meets
        np.minimum.at(L, lc, m)
        while True:  # pointer jumping to the roots
            LL = L[L]
            if np.array_equal(LL, L):
                break
            L = LL
    _, label = np.unique(L, return_inverse=True)
    return int(label.max()) + 1 if n else 0, label.astype(np.int64).ravel()


def _lifting(parent: np.ndarray) -> list[np.ndarray]:
    """Binary lifting table of a postordered forest: ``up[k][j]`` is the ``2**k``-th ancestor
    of ``j`` (``n`` above a root; ``up[k][n] = n``), up to the height."""
    n = parent.size
    up = [np.r_[np.where(parent < 0, n, parent), n]]
    while (up[-1][:n] < n).any():
        up.append(up[-1][up[-1]])
    return up


def _lca(a: np.ndarray, b: np.ndarray, up: list[np.ndarray]) -> np.ndarray:
    """Least common ancestors of ``a < b`` in a postordered tree: the lowest ancestor of
    ``a`` that is ``>= b`` (in a postorder the ancestors of ``a`` ascend, and an ancestor
    ``x >= b`` of ``a < b`` has ``b`` in its subtree)."""
    x = a.copy()
    for k in range(len(up) - 1, -1, -1):
        y = up[k][x]
        go = y < b
        x[go] = y[go]
    return up[0][x]


def _counts(lower: Any, parent: np.ndarray, up: list[np.ndarray]) -> np.ndarray:
    """Column counts of ``L`` (Gilbert, Ng and Peyton): row ``i`` of ``L`` is the union of the
    tree paths from its columns ``k`` (and ``i``) up to ``i``; sorted in postorder, that
    union's indicator is the subtree sum of ``+1`` at each, ``-1`` at the least common ancestor
    of consecutive ones and ``-1`` at the parent of ``i``."""
    n = parent.size
    rows = np.repeat(np.arange(n), np.diff(lower.indptr))
    # each row's columns then the row itself (the diagonal), in postorder
    r = np.r_[rows, np.arange(n)]
    c = np.r_[lower.indices.astype(np.int64), np.arange(n)]
    o = np.lexsort((c, r))
    r, c = r[o], c[o]
    same = r[1:] == r[:-1]
    delta = np.bincount(c, minlength=n + 1).astype(np.int64)
    delta -= np.bincount(_lca(c[:-1][same], c[1:][same], up), minlength=n + 1)
    delta -= np.bincount(up[0][:n], minlength=n + 1)
    cs = np.r_[0, np.cumsum(delta[:n])]
    # the first descendant of each node: follow the smallest child down (pointer jumping)
    first = np.arange(n)
    has = parent >= 0
    np.minimum.at(first, parent[has], np.flatnonzero(has))
    while True:
        nxt = first[first]
        if np.array_equal(nxt, first):
            break
        first = nxt
    return (cs[1:] - cs[first]).astype(np.int64)


def fill_order(A: Any, method: str = "auto") -> Symbolic:
    """The fill-reducing order of the supernodal Cholesky, with its symbolic factor.

    ``"auto"``: :func:`minimum_degree_blocks` (our approximate minimum degree with the
    compiled code, else SciPy's multiple minimum degree); ``"mmd"``: :func:`minimum_degree`
    (SciPy's). George's nested dissection as it was here cost 1.0-1.7x the flops of minimum
    degree on the shared pose graphs and was removed; see ``benchmarks/symbolic.py``.

    Parameters
    ----------
    A : scipy.sparse matrix
        The adjacency (of the pattern of ``A + A^T``; the diagonal and values are ignored).
    method : str
        ``"auto"`` or ``"mmd"``.

    Returns
    -------
    Symbolic

    Raises
    ------
    ValueError
        Unknown ``method``.

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.linalg.ordering import fill_order
    >>> P = sp.diags([np.ones(5), np.ones(5)], [-1, 1], shape=(6, 6))
    >>> s = fill_order(P)
    >>> s.nnz, s.height <= 6
    (11, True)
    """
    if method not in ORDERINGS:
        raise ValueError(f"unknown ordering {method!r}: expected one of {ORDERINGS}")
    A = _clean(A)
    if method == "mmd":
        return _symbolic(A, _mmd(A))
    return _symbolic(A, minimum_degree_blocks(A.indptr, A.indices, A.shape[0]))
