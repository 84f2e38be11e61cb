"""The interface every sparse symmetric positive definite backend implements
(:class:`LinearSolver`), its error (:class:`SingularSystemError`) and the pivot test they
share (:data:`PIVOT_TOL`). The backends (:mod:`microlie.optim.linalg.linear`,
:mod:`microlie.optim.linalg.cholesky`) import it; the registry ``make_solver`` lives in
:mod:`microlie.optim.linalg.linear`."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # SciPy is imported by the backends that use it
    import scipy.sparse as sp  # type: ignore[import-untyped]

__all__ = ["LinearSolver", "SingularSystemError", "PIVOT_TOL", "expand_blocks", "pattern_csr",
           "split_blocks"]

#: A pivot at most this fraction of its column's diagonal entry counts as zero (the column
#: is, to rounding, a combination of the columns eliminated before it).
PIVOT_TOL = 1e-10


def expand_blocks(bptr: np.ndarray, bidx: np.ndarray, block_size: int
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The scalar CSC pattern (rows sorted) of a block pattern of dense square blocks.

    Parameters
    ----------
    bptr, bidx : numpy.ndarray
        The CSC of the block pattern (``nb`` block columns, rows sorted).
    block_size : int
        The size ``d`` of every block.

    Returns
    -------
    indptr, indices : numpy.ndarray
        The ``nb d x nb d`` pattern: ``indptr`` int32 (int64 beyond 2**31 entries),
        ``indices`` int32; column ``d v + c`` holds the rows ``d u + (0..d-1)`` of each block
        ``(u, v)``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.linalg.base import expand_blocks
    >>> ip, ix = expand_blocks(np.array([0, 2, 3]), np.array([0, 1, 1]), 2)
    >>> ip.tolist(), ix.tolist()
    ([0, 4, 8, 10, 12], [0, 1, 2, 3, 0, 1, 2, 3, 2, 3, 2, 3])
    """
    d = int(block_size)
    nb = len(bptr) - 1
    nnz = int(bptr[-1]) * d * d
    ptype = np.int32 if nnz < 2**31 else np.int64
    bptr = np.asarray(bptr, np.int64)
    # the rows of block column v's scalar columns: each stored block (u, v) gives d u + (0..d-1);
    # the d scalar columns of v repeat that list (NumPy only: no SciPy import on this path)
    rows = (np.asarray(bidx, np.int64)[:, None] * d + np.arange(d)).ravel()
    lens = np.repeat(np.diff(bptr) * d, d)
    indptr = np.zeros(nb * d + 1, ptype)
    np.cumsum(lens, out=indptr[1:])
    starts = np.repeat(bptr[:-1] * d, d)
    pos = np.arange(nnz, dtype=np.int64) - np.repeat(indptr[:-1].astype(np.int64) - starts, lens)
    return indptr, rows[pos].astype(np.int32, copy=False)


def pattern_csr(rows: np.ndarray, cols: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The CSR pattern (columns sorted, duplicates merged) of the ``n x n`` entries
    ``(rows[k], cols[k])``, in NumPy (no SciPy import).

    Parameters
    ----------
    rows, cols : numpy.ndarray
        Integer coordinates in ``[0, n)``, same length, duplicates allowed.
    n : int
        The matrix size.

    Returns
    -------
    indptr, indices : numpy.ndarray
        int64; row ``i`` holds the columns ``indices[indptr[i]:indptr[i + 1]]``, increasing.
        (For a symmetric pattern this is also its CSC.)

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.linalg.base import pattern_csr
    >>> ip, ix = pattern_csr(np.array([1, 0, 1, 1]), np.array([0, 2, 0, 1]), 3)
    >>> ip.tolist(), ix.tolist()
    ([0, 1, 3, 3], [2, 0, 1])
    """
    n = int(n)
    rows = np.asarray(rows)
    cols = np.asarray(cols)
    if rows.shape != cols.shape or rows.ndim != 1:
        raise ValueError(f"rows and cols must be 1-D of one length, got {rows.shape} and "
                         f"{cols.shape}")
    if rows.size and (min(rows.min(), cols.min()) < 0 or max(rows.max(), cols.max()) >= n):
        raise ValueError(f"rows and cols must be in [0, {n})")
    key = rows.astype(np.int64) * max(n, 1) + cols
    key.sort()  # row-major; then merged (np.unique hashes first: 10x slower here, NumPy 2.4)
    if key.size:
        key = key[np.r_[True, key[1:] != key[:-1]]]
    indptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(key // max(n, 1), minlength=n), out=indptr[1:])
    return indptr, key % max(n, 1)


def split_blocks(bptr: np.ndarray, bidx: np.ndarray, parts: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The pattern of a block pattern whose block ``u`` is split into ``parts[u]`` sub-blocks
    (every sub-block of a stored block stored), in NumPy.

    Parameters
    ----------
    bptr, bidx : numpy.ndarray
        A CSR (or symmetric CSC) block pattern, indices sorted within each row.
    parts : numpy.ndarray
        Sub-blocks per block (``>= 1``).

    Returns
    -------
    indptr, indices : numpy.ndarray
        int64, the pattern of the ``parts.sum()`` sub-blocks (indices sorted), what
        ``B[owner][:, owner]`` gives for ``owner = np.repeat(np.arange(nb), parts)``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.linalg.base import split_blocks
    >>> ip, ix = split_blocks(np.array([0, 2, 3]), np.array([0, 1, 1]), np.array([1, 2]))
    >>> ip.tolist(), ix.tolist()
    ([0, 3, 5, 7], [0, 1, 2, 1, 2, 1, 2])
    """
    bptr = np.asarray(bptr, np.int64)
    bidx = np.asarray(bidx, np.int64)
    parts = np.asarray(parts, np.int64)
    nb = bptr.size - 1
    soff = np.zeros(nb + 1, np.int64)
    np.cumsum(parts, out=soff[1:])
    ecnt = parts[bidx]  # the sub-columns of each stored block
    scol = _ranges(soff[bidx], ecnt)  # each block row's sub-columns, concatenated
    eoff = np.zeros(bidx.size + 1, np.int64)
    np.cumsum(ecnt, out=eoff[1:])
    seg, lrow = eoff[bptr[:-1]], eoff[bptr[1:]] - eoff[bptr[:-1]]
    owner = np.repeat(np.arange(nb), parts)  # every sub-row repeats its block row's list
    indptr = np.zeros(owner.size + 1, np.int64)
    np.cumsum(lrow[owner], out=indptr[1:])
    return indptr, scol[_ranges(seg[owner], lrow[owner])]


def _ranges(starts: np.ndarray, lens: np.ndarray) -> np.ndarray:
    """``concatenate([arange(s, s + l) for s, l in zip(starts, lens)])``, vectorised."""
    ends = np.cumsum(lens)
    return np.arange(int(ends[-1]) if ends.size else 0, dtype=np.int64) - \
        np.repeat(ends - lens - starts, lens)


class SingularSystemError(ValueError):
    """The linear system is singular or not positive definite.

    Attributes
    ----------
    message : str
        The error text (``str(error)``).
    unknown : int or None
        The unknown (row of the matrix) whose pivot failed, when known.

    Examples
    --------
    >>> from microlie.optim.linalg.base import SingularSystemError
    >>> SingularSystemError("singular", unknown=4).unknown
    4
    """

    def __init__(self, message: str, unknown: int | None = None) -> None:
        super().__init__(message)
        self.unknown = unknown


class LinearSolver:
    """A sparse symmetric positive definite solver: analyse the pattern once, refactorise many
    times, solve. The matrix is given as the CSC data of the full symmetric pattern passed
    to :meth:`analyse`. Backends: ``make_solver(name)`` (see :func:`available_solvers`).

    Examples
    --------
    >>> import numpy as np
    >>> import scipy.sparse as sp
    >>> from microlie.optim import make_solver
    >>> A = sp.csc_matrix(np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.0], [0.0, 0.0, 2.0]]))
    >>> ls = make_solver("scipy")
    >>> ls.analyse(A.indptr, A.indices, 3)
    >>> ls.factorize(A.data)
    >>> np.round(ls.solve(np.array([5.0, 4.0, 2.0])), 12).tolist()
    [1.0, 1.0, 1.0]
    """

    name = "base"

    def analyse(self, indptr: np.ndarray, indices: np.ndarray | None, n: int,
                block_size: int = 1, block_pattern: tuple[np.ndarray, np.ndarray] | None = None
                ) -> None:
        """See the pattern (symbolic analysis, ordering).

        Parameters
        ----------
        indptr, indices : numpy.ndarray
            The CSC pattern of the full symmetric matrix. ``indices`` may be ``None`` when
            ``block_pattern`` is given: it is then expanded from the blocks on first use
            (:attr:`indices`), and backends that work on blocks never expand it.
        n : int
            The matrix size.
        block_size : int
            The unknowns come in dense blocks of that size.
        block_pattern : (numpy.ndarray, numpy.ndarray), optional
            ``(bptr, bidx)``: the CSC (rows sorted, diagonal included) of the
            ``n / block_size`` square block pattern whose dense expansion into
            ``block_size x block_size`` blocks is exactly ``(indptr, indices)``, when the caller
            has it (:class:`~microlie.optim.core.problem.Problem` does); backends that work on
            blocks then need not read them back from the scalar pattern. Others ignore it.

        Examples
        --------
        >>> import numpy as np
        >>> import scipy.sparse as sp
        >>> from microlie.optim import make_solver
        >>> A = sp.csc_matrix(np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.0], [0.0, 0.0, 2.0]]))
        >>> ls = make_solver("scipy")
        >>> ls.analyse(A.indptr, A.indices, 3)
        >>> ls.n
        3
        """
        if indices is None and block_pattern is None:
            raise ValueError("indices is None: pass the pattern's indices or its block_pattern")
        self.indptr, self._indices, self.n = indptr, indices, n
        self.nnz = int(indptr[-1]) if len(indptr) else 0
        self._given_blocks = None
        if block_pattern is not None:
            bptr, bidx = (np.ascontiguousarray(a, dtype=np.int64) for a in block_pattern)
            nb = bptr.size - 1
            bs = n // nb if nb and n % nb == 0 else 0
            if bs < 1 or bptr[-1] != bidx.size or bidx.size * bs * bs != self.nnz:
                raise ValueError(
                    f"block_pattern must be the block CSC of dense square blocks whose "
                    f"expansion is the {n} x {n} pattern of {self.nnz} entries; got "
                    f"{nb} block columns and {bidx.size} blocks")
            self._given_blocks = (bptr, bidx, bs)
        # the position of each diagonal entry in the CSC data (-1: not in the pattern)
        diag = self._block_diagonal()
        if diag is None:
            ix = self.indices
            cols = np.repeat(np.arange(n), np.diff(indptr))
            hit = np.flatnonzero(np.asarray(ix) == cols)
            diag = np.full(n, -1, dtype=np.int64)
            diag[cols[hit]] = hit
        self._diag_at = diag

    @property
    def indices(self) -> np.ndarray:
        """The row indices of the analysed CSC pattern (expanded from the block pattern on
        first use when :meth:`analyse` was given ``indices=None``)."""
        if self._indices is None:
            bptr, bidx, bs = self._given_blocks  # type: ignore[misc]
            self._indices = expand_blocks(bptr, bidx, bs)[1]
        return self._indices

    @indices.setter
    def indices(self, value: np.ndarray) -> None:
        self._indices = value

    def _block_diagonal(self) -> np.ndarray | None:
        """The CSC positions of the diagonal entries from the given block pattern (``None``
        without one, or when a diagonal block is missing)."""
        if self._given_blocks is None:
            return None
        bptr, bidx, bs = self._given_blocks
        nb = bptr.size - 1
        nblk = np.diff(bptr)
        d = np.flatnonzero(bidx == np.repeat(np.arange(nb, dtype=np.int64), nblk))
        if d.size != nb:
            return None
        pos = (bs * bs * bptr[:-1] + bs * (d - bptr[:-1]))[:, None] + \
            np.arange(bs) * (bs * nblk[:, None] + 1)
        return pos.ravel()

    def _check_pivots(self, data: np.ndarray, pivots: np.ndarray, order: np.ndarray) -> None:
        """Raise :class:`SingularSystemError` unless every pivot exceeds :data:`PIVOT_TOL`
        times its diagonal entry (``pivots[k]`` is that of unknown ``order[k]``, in elimination
        order); the message names the first failing unknown."""
        at = self._diag_at[order]
        diag = np.where(at >= 0, data[np.maximum(at, 0)], 0.0)
        bad = np.flatnonzero(~(pivots > PIVOT_TOL * diag))  # NaN fails too
        if bad.size:
            k = int(bad[0])
            i = int(order[k])
            ratio = pivots[k] / diag[k] if diag[k] > 0 else float("nan")
            raise SingularSystemError(
                f"the linear system is singular or not positive definite: the pivot of "
                f"unknown {i} is {ratio:.2g} times its diagonal entry {diag[k]:.3g} "
                f"({bad.size} of {self.n} pivots at most {PIVOT_TOL:g} times theirs)",
                unknown=i)

    def _triangles(self) -> None:
        """CSC upper and lower triangles of the pattern (for the triangular-input backends)."""
        indptr, indices, n = self.indptr, self.indices, self.n
        cols = np.repeat(np.arange(n), np.diff(indptr))
        self._upper = np.flatnonzero(indices <= cols)  # CSC upper triangle (= CSR lower)
        self._lower = np.flatnonzero(indices >= cols)  # CSC lower triangle (= CSR upper)
        up_cols = cols[self._upper]
        self.upper_indptr = np.concatenate([[0], np.cumsum(np.bincount(up_cols, minlength=n))]
                                           ).astype(np.int32)
        self.upper_indices = indices[self._upper].astype(np.int32)
        lo_cols = cols[self._lower]
        self.lower_indptr = np.concatenate([[0], np.cumsum(np.bincount(lo_cols, minlength=n))]
                                           ).astype(np.int32)
        self.lower_indices = indices[self._lower].astype(np.int32)

    def full(self, data: np.ndarray) -> sp.csc_matrix:
        """The matrix of CSC ``data`` in the analysed pattern.

        Parameters
        ----------
        data : numpy.ndarray
            Values in the pattern's order.

        Returns
        -------
        scipy.sparse.csc_matrix

        Examples
        --------
        >>> import numpy as np
        >>> import scipy.sparse as sp
        >>> from microlie.optim import make_solver
        >>> A = sp.csc_matrix(np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.0], [0.0, 0.0, 2.0]]))
        >>> ls = make_solver("scipy")
        >>> ls.analyse(A.indptr, A.indices, 3)
        >>> ls.full(A.data).toarray()[0].tolist()
        [4.0, 1.0, 0.0]
        """
        import scipy.sparse as sp  # type: ignore[import-untyped]

        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))

    def factorize(self, data: np.ndarray) -> None:
        """Factorise the matrix with values ``data`` in the analysed pattern.

        Parameters
        ----------
        data : numpy.ndarray
            Values in the pattern's order.

        Raises
        ------
        SingularSystemError
            The matrix is singular or not positive definite.

        Examples
        --------
        >>> import numpy as np
        >>> import scipy.sparse as sp
        >>> from microlie.optim import make_solver
        >>> A = sp.csc_matrix(np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.0], [0.0, 0.0, 2.0]]))
        >>> ls = make_solver("scipy")
        >>> ls.analyse(A.indptr, A.indices, 3)
        >>> ls.factorize(A.data)
        """
        raise NotImplementedError

    def solve(self, b: np.ndarray) -> np.ndarray:
        """Solve with the last factorisation.

        Parameters
        ----------
        b : numpy.ndarray
            ``(n,)`` right-hand side, or ``(n, k)`` for ``k`` of them (every backend).

        Returns
        -------
        numpy.ndarray
            The solution, shaped as ``b``.

        Raises
        ------
        SingularSystemError
            The solution is not finite.

        Examples
        --------
        >>> import numpy as np
        >>> import scipy.sparse as sp
        >>> from microlie.optim import make_solver
        >>> A = sp.csc_matrix(np.array([[4.0, 1.0, 0.0], [1.0, 3.0, 0.0], [0.0, 0.0, 2.0]]))
        >>> ls = make_solver("scipy")
        >>> ls.analyse(A.indptr, A.indices, 3)
        >>> ls.factorize(A.data)
        >>> np.round(ls.solve(np.array([4.0, 1.0, 0.0])), 12).tolist()
        [1.0, 0.0, 0.0]
        """
        raise NotImplementedError
