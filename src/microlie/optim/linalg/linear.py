"""Sparse symmetric positive definite solvers behind one small interface.

``solver.analyse(indptr, indices, n)`` sees the fixed sparsity pattern once (full symmetric
storage, compressed sparse columns, sorted rows); ``solver.factorize(data)`` refactorises with
new numbers in that pattern; ``solver.solve(b)`` solves ``H x = b``. A matrix that is not
positive definite raises :class:`SingularSystemError`, with one test for every backend but
PARDISO: a pivot of the factorisation (``d_k`` of ``LDL^T``, ``L_kk^2`` of Cholesky) at most
:data:`PIVOT_TOL` times its column's diagonal entry counts as zero. A rank-deficient system
(a gauge freedom, an unobservable variable) then raises whatever the backend and its order
(its computed pivots are rounding noise of either sign, 1e-16 to 1e-9 of their diagonal on
the shared benchmark pose graphs without a gauge; the smallest genuine one there is
2.8e-8, ais2klinik).

Backends (``make_solver(name)``): ``"cholesky"`` (our supernodal multifrontal Cholesky on the
block pattern, NumPy and LAPACK only, :mod:`microlie.optim.linalg.cholesky`), ``"scipy"`` (SuperLU
with
a symmetric minimum-degree order), ``"qdldl"`` (``pip install microlie[sparse]``, Apache-2.0),
``"pardiso"`` (Intel MKL PARDISO through pypardiso, ``pip install microlie[mkl]``), ``"dense"``
(LAPACK Cholesky of the dense matrix, for small problems). ``"auto"`` chooses by problem
and installation (see :func:`make_solver`).
"""

from __future__ import annotations

import importlib.util
from typing import Any

import numpy as np
import scipy.linalg as sla  # type: ignore[import-untyped]
import scipy.sparse as sp  # type: ignore[import-untyped]

from ..core.threads import limit_new_libraries
from .ordering import graph, minimum_degree, splu_symmetric

__all__ = ["LinearSolver", "SingularSystemError", "make_solver", "available_solvers",
           "SOLVERS", "PIVOT_TOL"]

#: A pivot at most this fraction of its column's diagonal entry counts as zero (the column
#: is, to rounding, a combination of the columns eliminated before it).
PIVOT_TOL = 1e-10


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
    >>> from microlie.optim.linalg.linear import SingularSystemError
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

    def analyse(self, indptr: np.ndarray, indices: np.ndarray, n: int,
                block_size: int = 1) -> None:
        """See the pattern (symbolic analysis, ordering).

        Parameters
        ----------
        indptr, indices : numpy.ndarray
            The CSC pattern of the full symmetric matrix.
        n : int
            The matrix size.
        block_size : int
            The unknowns come in dense blocks of that size.

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
        self.indptr, self.indices, self.n = indptr, indices, n
        # the position of each diagonal entry in the CSC data (-1: not in the pattern)
        cols = np.repeat(np.arange(n), np.diff(indptr))
        hit = np.flatnonzero(np.asarray(indices) == cols)
        self._diag_at = np.full(n, -1, dtype=np.int64)
        self._diag_at[cols[hit]] = hit

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


def _checked(x: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(x)):
        raise SingularSystemError("the linear system is singular (the solution is not finite)")
    return x


def block_order(indptr: np.ndarray, indices: np.ndarray, n: int, bs: int) -> np.ndarray:
    """A fill-reducing order of the unknowns (new -> old) from the minimum-degree order of the
    block graph (``bs`` times smaller than the scalar one)."""
    if bs <= 0 or n % bs:
        bs = 1
    q = minimum_degree(graph(indptr, indices, n, bs))
    return (q[:, None] * bs + np.arange(bs)).ravel()


class ScipySolver(LinearSolver):
    """SuperLU (scipy) in symmetric mode (diagonal pivots, no partial pivoting) on the matrix
    permuted once by the minimum-degree order of the block graph (25% faster than SuperLU's
    own ``MMD_AT_PLUS_A`` on the scalar matrix, measured on M3500)."""

    name = "scipy"

    def analyse(self, indptr, indices, n, block_size=1):
        super().analyse(indptr, indices, n)
        p = block_order(indptr, indices, n, block_size)
        tag = sp.csc_matrix((np.arange(1, indices.size + 1, dtype=np.float64), indices,
                             indptr), shape=(n, n))[p][:, p].tocsc()
        tag.sort_indices()
        self._map = tag.data.astype(np.int64) - 1
        self._pindptr, self._pindices = tag.indptr, tag.indices
        self._p = p

    def factorize(self, data: np.ndarray) -> None:
        A = sp.csc_matrix((data[self._map], self._pindices, self._pindptr),
                          shape=(self.n, self.n))
        try:
            self._lu = splu_symmetric(A, "NATURAL")
        except RuntimeError as e:
            raise SingularSystemError(f"the linear system is singular ({e})") from None
        # diagonal pivots: U_kk is the pivot of column perm_c[k] of the permuted matrix
        self._check_pivots(data, self._lu.U.diagonal(), self._p[self._lu.perm_c])

    def solve(self, b: np.ndarray) -> np.ndarray:
        y = self._lu.solve(np.asarray(b, dtype=np.float64)[self._p])
        x = np.empty_like(y)
        x[self._p] = y
        return _checked(x)


class QdldlSolver(LinearSolver):
    """qdldl's LDL^T with its AMD order, analysed once and updated numerically."""

    name = "qdldl"

    def analyse(self, indptr, indices, n, block_size=1):
        super().analyse(indptr, indices, n)
        self._triangles()
        import qdldl  # type: ignore[import-not-found]

        self._mod = qdldl
        self._solver: Any = None

    def factorize(self, data: np.ndarray) -> None:
        U = sp.csc_matrix((data[self._upper], self.upper_indices, self.upper_indptr),
                          shape=(self.n, self.n))
        try:
            if self._solver is None:
                self._solver = self._mod.Solver(U, upper=True)
            else:
                self._solver.update(U, upper=True)
        except Exception as e:  # qdldl raises ValueError on a zero pivot
            self._solver = None
            raise SingularSystemError(f"the linear system is singular ({e})") from None
        # LDL^T takes any nonzero pivot: the test of every backend on D (factors() builds L
        # too: with the test 0.25 ms against 4.35 ms for the factorisation on M3500, measured
        # with one BLAS thread)
        _, d, perm = self._solver.factors()
        self._check_pivots(data, d, perm)

    def solve(self, b: np.ndarray) -> np.ndarray:
        # qdldl solves one vector at a time: a matrix right-hand side column by column
        b = np.asarray(b, dtype=np.float64)
        if b.ndim == 1:
            return _checked(self._solver.solve(b))
        x = np.empty_like(b)
        for k in range(b.shape[1]):
            x[:, k] = self._solver.solve(np.ascontiguousarray(b[:, k]))
        return _checked(x)


class PardisoSolver(LinearSolver):
    """Intel MKL PARDISO (real symmetric positive definite, ``mtype=2``): symbolic analysis
    (phase 11) once, numeric factorisation (22) and solve (33) per call."""

    name = "pardiso"

    def analyse(self, indptr, indices, n, block_size=1):
        super().analyse(indptr, indices, n)
        self._triangles()
        self._ps = _pardiso_instance()
        self._A = sp.csr_matrix((np.zeros(self._lower.size), self.lower_indices,
                                 self.lower_indptr), shape=(n, n))
        self._analysed = False

    def _call(self, phase: int, b: np.ndarray) -> np.ndarray:
        self._ps.set_phase(phase)
        return self._ps._call_pardiso(self._A, b)

    def factorize(self, data: np.ndarray) -> None:
        self._A.data[:] = data[self._lower]
        b = np.zeros((self.n, 1))
        try:
            if not self._analysed:
                self._call(11, b)
                self._analysed = True
            self._call(22, b)
        except Exception as e:  # PyPardisoError: -4 zero pivot, ...
            raise SingularSystemError(f"the linear system is not positive definite "
                                      f"(PARDISO: {e})") from None

    def solve(self, b: np.ndarray) -> np.ndarray:
        x = self._call(33, np.asfortranarray(b.reshape(self.n, -1)))
        return _checked(x.reshape(b.shape))


_PARDISO_TEMPLATE: Any = None


def _pardiso_instance() -> Any:
    """A fresh PyPardisoSolver (``mtype=2``) without searching for and loading MKL again
    (about half a second per construction): copies of one template with new handles."""
    global _PARDISO_TEMPLATE
    import copy

    import pypardiso  # type: ignore[import-not-found]

    if _PARDISO_TEMPLATE is None:
        _PARDISO_TEMPLATE = pypardiso.PyPardisoSolver(mtype=2)
        limit_new_libraries()  # MKL was loaded just now: hold it to the solve's BLAS threads
    ps = copy.copy(_PARDISO_TEMPLATE)
    ps.pt = np.zeros_like(_PARDISO_TEMPLATE.pt)
    # our own parameters instead of MKL's defaults (iparm[0] = 1): the minimum-degree order
    # (iparm[1] = 0) and no iterative refinement (iparm[7] = 0: a Cholesky solve is exact to
    # rounding). Measured on sphere2500 (one thread) against the defaults (METIS, refinement):
    # analysis 30 ms instead of 85, factorisation 12 ms instead of 18, solve 1.5 ms instead of 4.3
    ps.iparm = np.zeros_like(_PARDISO_TEMPLATE.iparm)
    ps.iparm[0] = 1
    ps.iparm[1] = 0
    ps.perm = np.zeros(0, dtype=np.int32)
    return ps


class DenseSolver(LinearSolver):
    """LAPACK Cholesky of the dense matrix (small problems)."""

    name = "dense"

    def factorize(self, data: np.ndarray) -> None:
        c, info = sla.lapack.dpotrf(self.full(data).toarray(), lower=1, clean=0,
                                    overwrite_a=1)
        if info:
            self._c = None
            i = info - 1 if info > 0 else None
            raise SingularSystemError(f"the linear system is singular or not positive definite: "
                                      f"the pivot of unknown {i} is not positive", unknown=i)
        self._c = (c, True)
        self._check_pivots(data, np.diagonal(c) ** 2, np.arange(self.n))

    def solve(self, b: np.ndarray) -> np.ndarray:
        return _checked(sla.cho_solve(self._c, b, check_finite=False))


def _supernodal() -> type[LinearSolver]:
    from .cholesky import SupernodalSolver

    return SupernodalSolver


SOLVERS: dict[str, Any] = {"cholesky": _supernodal, "scipy": lambda: ScipySolver,
                           "qdldl": lambda: QdldlSolver, "pardiso": lambda: PardisoSolver,
                           "dense": lambda: DenseSolver}
_MODULES = {"qdldl": "qdldl", "pardiso": "pypardiso"}
_EXTRAS = {"qdldl": "microlie[sparse]", "pardiso": "microlie[mkl]"}


def available_solvers() -> list[str]:
    """The linear-solver backends importable here (``scipy`` and ``dense`` always are).

    Returns
    -------
    list of str

    Examples
    --------
    >>> from microlie.optim import available_solvers
    >>> {"scipy", "dense"} <= set(available_solvers())
    True
    """
    return [k for k in SOLVERS
            if k not in _MODULES or importlib.util.find_spec(_MODULES[k]) is not None]


def make_solver(name: str | LinearSolver, n: int = 0, block_size: int = 1,
                available: list[str] | None = None) -> LinearSolver:
    """A linear solver by name.

    ``"auto"`` chooses by what is installed and by the measurements of
    ``benchmarks/pose_graph.py`` and ``benchmarks/cholesky.py``: below 300 unknowns the dense
    Cholesky; for 3-D problems (blocks of 6 or more) PARDISO, else the supernodal Cholesky; for
    2-D problems qdldl, else PARDISO, else the supernodal Cholesky, else SuperLU (on the five
    pose graphs of the benchmark the supernodal Cholesky beat SuperLU in the default install,
    NumPy loop and all: its factorisations took 0.28-0.56x SuperLU's).

    Parameters
    ----------
    name : str or LinearSolver
        ``"auto"``, a backend name (see :func:`available_solvers`) or an instance (returned
        as is).
    n : int
        The number of unknowns (for ``"auto"``).
    block_size : int
        The block size of the unknowns (for ``"auto"``).
    available : list of str, optional
        Restrict ``"auto"``'s choice (for example to ``["scipy", "cholesky", "dense"]``,
        what ``pip install microlie`` has).

    Returns
    -------
    LinearSolver

    Raises
    ------
    ValueError
        Unknown name.
    ImportError
        The backend's package is not installed (the message names the extra).

    Examples
    --------
    >>> from microlie.optim import make_solver
    >>> make_solver("auto", n=100).name, make_solver("auto", 5000, 3, ["scipy"]).name
    ('dense', 'scipy')
    """
    if isinstance(name, LinearSolver):
        return name
    if name == "auto":
        if n < 300:
            return DenseSolver()
        avail = available_solvers() if available is None else available
        if block_size >= 6:
            prefs: tuple[str, ...] = ("pardiso", "cholesky", "scipy")
        else:
            prefs = ("qdldl", "pardiso", "cholesky", "scipy")
        return SOLVERS[next(k for k in prefs if k in avail)]()()
    make = SOLVERS.get(name)
    if name == "schur":
        raise ValueError("linear_solver='schur' needs the problem's variables: pass it to "
                         "FactorGraph.optimize or Problem.analysed, or build a "
                         "microlie.optim.linalg.schur_solver.SchurSolver(node_off, eliminate)")
    if make is None:
        raise ValueError(f"unknown linear solver {name!r}; known: auto, "
                         f"{', '.join(SOLVERS)}, schur")
    if name in _MODULES and importlib.util.find_spec(_MODULES[name]) is None:
        raise ImportError(f"linear_solver={name!r} needs the package {_MODULES[name]!r} "
                          f"(pip install {_EXTRAS[name]!r})")
    return make()()
