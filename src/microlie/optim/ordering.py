"""Fill-reducing orderings of a sparse symmetric pattern, for the supernodal Cholesky.

The orderings work on a graph: the symmetric adjacency (``scipy.sparse`` CSR, no diagonal) of
the block pattern of the normal equations (one vertex per block of unknowns). An ordering is a
permutation ``p`` (new -> old: the matrix is factorised as ``A[p][:, p]``).

- :func:`minimum_degree`: multiple minimum degree (SuperLU's ``MMD_AT_PLUS_A``, run on a
  graph Laplacian of the pattern).
- :func:`nested_dissection`: George's nested dissection. A connected piece larger than
  ``leaf_size`` is split by a vertex separator; both halves are ordered first (recursively),
  the separator last. The separator comes from a level structure (breadth-first levels from a
  pseudo-peripheral vertex, as in George and Liu's automatic nested dissection): for a few
  balanced cuts between consecutive levels ``i`` and ``i + 1`` it is the minimum vertex cover
  of the edges crossing the cut (a maximum bipartite matching and Koenig's theorem), and the
  smallest one wins. Pieces of at most ``leaf_size`` vertices are ordered by minimum degree.
- :func:`symbolic`: the factor's pattern for an ordering, with its column counts, nonzeros,
  flops and elimination-tree height, to compare orderings before any numeric work.
- :func:`fill_order`: the order the supernodal solver uses (``"mmd"``, ``"nd"``, or ``"auto"``:
  the one with the smaller estimated factorisation cost).

Examples
--------
A 2-D grid graph (the 5-point Laplacian's pattern): nested dissection fills less than the
natural order.

>>> import numpy as np
>>> import scipy.sparse as sp
>>> from microlie.optim.ordering import nested_dissection, symbolic
>>> path = sp.diags([np.ones(29), np.ones(29)], [-1, 1], shape=(30, 30))
>>> grid = (sp.kron(path, sp.eye(30)) + sp.kron(sp.eye(30), path)).tocsr()
>>> p = nested_dissection(grid)
>>> bool(np.array_equal(np.sort(p), np.arange(900)))
True
>>> symbolic(grid, p).nnz < symbolic(grid, np.arange(900)).nnz
True
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp  # type: ignore[import-untyped]
from scipy.sparse.csgraph import (  # type: ignore[import-untyped]
    connected_components,
    dijkstra,
    maximum_bipartite_matching,
)
from scipy.sparse.linalg import splu  # type: ignore[import-untyped]

__all__ = ["ORDERINGS", "Symbolic", "fill_order", "graph", "minimum_degree",
           "nested_dissection", "separator", "symbolic"]

ORDERINGS = ("auto", "mmd", "nd")

# pieces of at most this many vertices are ordered by minimum degree
LEAF_SIZE = 256
# a cut between two levels is balanced when each side keeps this fraction of the vertices
_BALANCE = 0.25
# the number of balanced cuts whose exact (matching) separator is computed
_CANDIDATES = 3
# "auto" tries the deep nested dissection when the coarse one saves this fraction of flops
_DEEPER = 0.9


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
    >>> from microlie.optim.ordering import graph
    >>> H = sp.csc_matrix(np.kron(np.array([[1, 1, 0], [1, 1, 1], [0, 1, 1]]), np.ones((2, 2))))
    >>> graph(H.indptr, H.indices, 6, 2).toarray().astype(int).tolist()
    [[0, 1, 0], [1, 0, 1], [0, 1, 0]]
    """
    bs = block_size if block_size > 0 and n % block_size == 0 else 1
    nb = n // bs
    cols = np.repeat(np.arange(n), np.diff(indptr)) // bs
    rows = np.asarray(indices) // bs
    A = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(nb, nb))
    return _clean(A)


def _clean(A: Any) -> Any:
    """The pattern of ``A + A^T`` without diagonal, unit data, sorted CSR."""
    A = sp.csr_matrix(A)
    A = abs(A) + abs(A.T)
    A.setdiag(0)
    A.eliminate_zeros()
    A.data[:] = 1.0
    A.sort_indices()
    return A


def _laplacian(A: Any) -> Any:
    """A graph Laplacian of ``A`` plus ``0.1 I`` with random positive weights (CSC): SuperLU's
    numeric factor of it has the symbolic pattern (an M-matrix's Schur complements keep
    non-positive off-diagonals, so no entry cancels, and fill decays slowly enough not to
    underflow)."""
    n = A.shape[0]
    rows = np.repeat(np.arange(n), np.diff(A.indptr))
    lo, hi = np.minimum(rows, A.indices), np.maximum(rows, A.indices)
    # symmetric pseudo-random weights in [0.5, 1): a hash of the edge (golden-ratio steps)
    w = 0.5 + 0.5 * np.modf((lo * 0.7548776662 + hi * 0.5698402910) % 1.0 + 0.1)[0]
    off = sp.csr_matrix((-w, A.indices, A.indptr), shape=A.shape)
    deg = np.bincount(rows, weights=w, minlength=n)
    return (off + sp.diags(deg + 0.1, format="csr")).tocsc()


def splu_symmetric(B: Any, spec: str) -> Any:
    """SuperLU in symmetric mode (diagonal pivots only) with the column order ``spec``."""
    return splu(B, permc_spec=spec, diag_pivot_thresh=0.0, options={"SymmetricMode": True})


def minimum_degree(A: Any) -> np.ndarray:
    """Multiple minimum degree order of a graph (SuperLU's ``MMD_AT_PLUS_A`` on a Laplacian of
    it).

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
    >>> from microlie.optim.ordering import minimum_degree
    >>> star = sp.csr_matrix((np.ones(8), ([0, 0, 0, 0, 1, 2, 3, 4], [1, 2, 3, 4, 0, 0, 0, 0])))
    >>> int(minimum_degree(star)[-1])  # the hub last: no fill
    0
    """
    lu = splu_symmetric(_laplacian(_clean(A)), "MMD_AT_PLUS_A")
    return np.argsort(lu.perm_c).astype(np.int64)


def _distances(A: Any, v: int) -> np.ndarray:
    return dijkstra(A, directed=False, indices=v, unweighted=True).astype(np.int64)


def _peripheral(A: Any, deg: np.ndarray) -> np.ndarray:
    """Breadth-first levels from a pseudo-peripheral vertex of the connected graph ``A``
    (George and Liu: restart from a vertex of least degree in the last level while the
    eccentricity grows)."""
    v = int(np.argmin(deg))
    d = _distances(A, v)
    for _ in range(8):
        last = np.flatnonzero(d == d.max())
        u = int(last[np.argmin(deg[last])])
        du = _distances(A, u)
        if du.max() <= d.max():
            break
        d = du
    return d


def _cover(rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A minimum vertex cover of the bipartite graph with edges ``rows[e] - cols[e]``
    (Koenig's theorem on a maximum matching): the rows and the columns of the cover."""
    ur, ri = np.unique(rows, return_inverse=True)
    uc, ci = np.unique(cols, return_inverse=True)
    M = sp.csr_matrix((np.ones(ri.size), (ri, ci)), shape=(ur.size, uc.size))
    match = maximum_bipartite_matching(M, perm_type="column")  # row -> column or -1
    rmatch = np.full(uc.size, -1, np.int64)
    has = match >= 0
    rmatch[match[has]] = np.flatnonzero(has)
    # Z: the vertices reachable from unmatched rows by alternating paths
    zr = ~has
    zc = np.zeros(uc.size, bool)
    front = zr.copy()
    MT = M.T.tocsr()
    while front.any():
        reach = (MT @ front.astype(np.float64)) > 0
        newc = reach & ~zc
        zc |= newc
        front = np.zeros(ur.size, bool)
        front[rmatch[newc]] = True
        front &= ~zr
        zr |= front
    return ur[~zr], uc[zc]


def separator(A: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """A vertex separator of a connected graph, from a level structure (see the module).

    Parameters
    ----------
    A : scipy.sparse.csr_matrix
        The symmetric adjacency, no diagonal, sorted indices (as :func:`graph` returns).

    Returns
    -------
    tuple of numpy.ndarray or None
        ``(sep, side)``, boolean masks: no edge joins ``~sep & side`` and ``~sep & ~side``,
        and each side holds at least a quarter of the vertices less the separator; ``None``
        when the level structure has no such cut (for example a star or a clique).

    Raises
    ------
    ValueError
        ``A`` is not connected.

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.ordering import separator
    >>> path = sp.diags([np.ones(8), np.ones(8)], [-1, 1], shape=(9, 9)).tocsr()
    >>> sep, side = separator(path)
    >>> np.flatnonzero(sep).tolist()  # one vertex near the middle cuts a path
    [4]
    """
    n = A.shape[0]
    if connected_components(A, directed=False)[0] > 1:
        raise ValueError("separator needs a connected graph (order the components apart)")
    deg = np.diff(A.indptr)
    d = _peripheral(A, deg)
    nlev = int(d.max()) + 1
    if nlev < 3:
        return None
    below = np.cumsum(np.bincount(d, minlength=nlev))  # vertices in levels 0..i
    coo = A.tocoo()
    up = d[coo.col] == d[coo.row] + 1  # edges from level i to level i + 1 (each once)
    er, ec = coo.row[up], coo.col[up]
    lev = d[er]
    # an upper bound on each cut's separator: the smaller side of its crossing edges
    nr = np.bincount(d[np.unique(er)], minlength=nlev)
    nc = np.bincount(d[np.unique(ec)] - 1, minlength=nlev)
    bound = np.minimum(nr, nc)[: nlev - 1]
    cut = np.arange(nlev - 1)
    ok = (below[cut] >= _BALANCE * n) & (n - below[cut] >= _BALANCE * n)
    if not ok.any():  # no balanced cut (a star, a clique): minimum degree does better
        return None
    est = bound / np.maximum(np.minimum(below[cut], n - below[cut]), 1)
    cand = cut[ok][np.argsort(est[ok], kind="stable")[:_CANDIDATES]]
    best: tuple[float, int, np.ndarray] | None = None
    for i in cand.tolist():
        e = lev == i
        r, c = _cover(er[e], ec[e])
        s = np.r_[r, c]
        a = below[i] - r.size
        b = n - below[i] - c.size
        if a <= 0 or b <= 0:
            continue
        score = s.size / min(a, b)
        if best is None or score < best[0]:
            best = (score, i, s)
    if best is None:
        return None
    sep = np.zeros(n, bool)
    sep[best[2]] = True
    return sep, d <= best[1]


def nested_dissection(A: Any, leaf_size: int = LEAF_SIZE) -> np.ndarray:
    """Nested-dissection order of a graph: each connected component apart; in a piece larger
    than ``leaf_size``, both sides of a vertex separator (:func:`separator`) first,
    recursively, the separator last; a piece of at most ``leaf_size`` vertices by minimum
    degree, with its neighbours outside it (all ordered later) joined into a clique and then
    dropped, which keeps the piece's boundary late, as a constrained minimum degree would.

    Parameters
    ----------
    A : scipy.sparse matrix
        The adjacency (of the pattern of ``A + A^T``; the diagonal and values are ignored).
    leaf_size : int
        Pieces of at most this many vertices are not split (``leaf_size >= n``: minimum
        degree).

    Returns
    -------
    numpy.ndarray
        The order, new -> old (int64).

    Raises
    ------
    ValueError
        ``leaf_size`` is not positive.

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim.ordering import nested_dissection
    >>> path = sp.diags([np.ones(8), np.ones(8)], [-1, 1], shape=(9, 9))
    >>> p = nested_dissection(path, leaf_size=3)
    >>> int(p[-1]), sorted(p[:4].tolist())  # the middle vertex last, after a half
    (4, [0, 1, 2, 3])
    """
    if leaf_size < 1:
        raise ValueError(f"leaf_size must be positive, got {leaf_size}")
    A = _clean(A)
    out: list[np.ndarray] = []
    _dissect(A, np.arange(A.shape[0], dtype=np.int64), leaf_size, out)
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def _dissect(A: Any, ids: np.ndarray, leaf: int, out: list[np.ndarray]) -> None:
    """Append the order of the vertices ``ids`` of ``A`` to ``out``."""
    if ids.size <= leaf:
        out.append(_leaf(A, ids))
        return
    S = A[ids][:, ids]
    ncomp, lab = connected_components(S, directed=False)
    if ncomp > 1:
        size = np.bincount(lab)
        small = size[lab] <= leaf
        if small.any():  # the small components together (minimum degree keeps them apart)
            out.append(_leaf(A, ids[small]))
        for c in np.flatnonzero(size > leaf).tolist():
            _dissect(A, ids[lab == c], leaf, out)
        return
    cut = separator(S)
    if cut is None:
        out.append(_leaf(A, ids))
        return
    sep, side = cut
    _dissect(A, ids[~sep & side], leaf, out)
    _dissect(A, ids[~sep & ~side], leaf, out)
    out.append(ids[sep])


def _leaf(A: Any, ids: np.ndarray) -> np.ndarray:
    """Minimum-degree order of the vertices ``ids`` of ``A``, their halo (neighbours outside
    ``ids``) joined into a clique so that the boundary is eliminated late."""
    if ids.size <= 2:
        return ids
    inside = np.zeros(A.shape[0], bool)
    inside[ids] = True
    nbr = A[ids].indices
    halo = np.unique(nbr[~inside[nbr]])
    allv = np.r_[ids, halo]
    G = A[allv][:, allv]
    if halo.size > 1:
        h = np.arange(ids.size, allv.size)
        G = G + sp.csr_matrix((np.ones(h.size * h.size), (np.repeat(h, h.size),
                                                          np.tile(h, h.size))), shape=G.shape)
    q = minimum_degree(_clean(G))
    return allv[q[q < ids.size]]


@dataclass(frozen=True)
class Symbolic:
    """The symbolic Cholesky factor of a graph under an order (returned by :func:`symbolic`
    and :func:`fill_order`).

    Attributes
    ----------
    perm : numpy.ndarray
        The order (new -> old) in which ``L`` is stored: the requested one, or an equivalent
        postorder of it (the same fill).
    L : scipy.sparse.csc_matrix
        The lower-triangular pattern with the diagonal, sorted (SuperLU's numeric factor of
        a Laplacian: an entry that cancelled exactly may be missing; the supernodal solver
        closes the pattern).
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
    >>> from microlie.optim.ordering import symbolic
    >>> path = sp.diags([np.ones(3), np.ones(3)], [-1, 1], shape=(4, 4))
    >>> s = symbolic(path, np.arange(4))
    >>> s.counts.tolist(), s.nnz, s.flops, s.height
    ([2, 2, 2, 1], 7, 13.0, 4)
    """

    perm: np.ndarray
    L: Any
    counts: np.ndarray
    nnz: int
    flops: float
    height: int


def symbolic(A: Any, perm: np.ndarray) -> Symbolic:
    """The symbolic Cholesky factor of a graph under an order, from SuperLU's factorisation
    of a Laplacian of ``A[perm][:, perm]`` in its natural order.

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
    >>> from microlie.optim.ordering import symbolic
    >>> star = sp.csr_matrix((np.ones(6), ([0, 0, 0, 1, 2, 3], [1, 2, 3, 0, 0, 0])))
    >>> symbolic(star, [0, 1, 2, 3]).nnz, symbolic(star, [1, 2, 3, 0]).nnz  # hub first fills
    (10, 7)
    """
    perm = np.asarray(perm, dtype=np.int64)
    n = A.shape[0]
    if perm.shape != (n,) or not np.array_equal(np.sort(perm), np.arange(n)):
        raise ValueError(f"perm must be a permutation of 0..{n - 1}")
    return _factor(_clean(A)[perm][:, perm], perm, "NATURAL")


def _factor(Ap: Any, base: np.ndarray, spec: str) -> Symbolic:
    """The symbolic factor of ``Ap`` (the graph ``A[base][:, base]``) with SuperLU ordering
    it by ``spec``: its ``L`` is the factor of ``Ap[q][:, q]``, ``q = argsort(perm_c)``
    (SuperLU postorders the elimination tree whatever ``spec`` asks)."""
    n = Ap.shape[0]
    lu = splu_symmetric(_laplacian(Ap), spec)
    p = base[np.argsort(lu.perm_c)]
    L = lu.L.tocsc()
    L.sort_indices()
    counts = np.diff(L.indptr).astype(np.int64)
    # elimination tree: parent = first row below the diagonal of each column
    parent = np.full(n, -1, np.int64)
    has = counts > 1
    parent[has] = L.indices[L.indptr[:-1][has] + 1]
    depth = np.zeros(n, np.int64)
    for j in range(n - 1, -1, -1):  # parents come after their children
        if parent[j] >= 0:
            depth[j] = depth[parent[j]] + 1
    return Symbolic(p, L, counts, int(counts.sum()), float((counts.astype(float) ** 2).sum()),
                    int(depth.max()) + 1 if n else 0)


def fill_order(A: Any, method: str = "auto") -> Symbolic:
    """The fill-reducing order of the supernodal Cholesky, with its symbolic factor.

    ``"mmd"``: :func:`minimum_degree`; ``"nd"``: :func:`nested_dissection`; ``"auto"``: the
    order with the fewest factorisation flops (:attr:`Symbolic.flops`; minimum degree on
    ties) of minimum degree, a coarse nested dissection (leaves of 60% of the vertices: one
    or two levels of separators) and, only when the coarse one has at least 10% fewer flops
    than minimum degree, the full one (leaves of ``LEAF_SIZE``, 256). On the pose graphs of
    ``benchmarks/orderings.py`` minimum degree has the fewest flops but on sphere2500 (3%
    more than the coarse dissection); on 3-D meshes nested dissection has half as many.

    Parameters
    ----------
    A : scipy.sparse matrix
        The adjacency (of the pattern of ``A + A^T``; the diagonal and values are ignored).
    method : str
        ``"auto"``, ``"mmd"`` or ``"nd"``.

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
    >>> from microlie.optim.ordering import fill_order
    >>> P = sp.diags([np.ones(11), np.ones(11)], [-1, 1], shape=(12, 12))
    >>> I = sp.eye(12)
    >>> cube = sp.kron(sp.kron(P, I), I) + sp.kron(sp.kron(I, P), I) + sp.kron(sp.kron(I, I), P)
    >>> nd, mmd = fill_order(cube, "nd"), fill_order(cube, "mmd")
    >>> bool(nd.flops < 0.8 * mmd.flops), fill_order(cube).flops == nd.flops
    (True, True)
    """
    if method not in ORDERINGS:
        raise ValueError(f"unknown ordering {method!r}: expected one of {ORDERINGS}")
    A = _clean(A)
    if method == "nd":
        return symbolic(A, nested_dissection(A))
    n = A.shape[0]
    # minimum degree's factor from the same SuperLU call that orders
    mmd = _factor(A, np.arange(n), "MMD_AT_PLUS_A")
    if method == "mmd":
        return mmd
    coarse = max(LEAF_SIZE, -(-3 * n // 5))
    if n <= coarse:
        return mmd
    one = symbolic(A, nested_dissection(A, coarse))
    best = one if one.flops < mmd.flops else mmd
    if one.flops < _DEEPER * mmd.flops:  # separators pay: see whether more levels pay more
        deep = symbolic(A, nested_dissection(A, LEAF_SIZE))
        best = deep if deep.flops < best.flops else best
    return best
