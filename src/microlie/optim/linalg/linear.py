"""Sparse symmetric positive definite solvers behind one small interface
(:class:`~microlie.optim.linalg.base.LinearSolver`).

``solver.analyse(indptr, indices, n)`` sees the fixed sparsity pattern once (full symmetric
storage, compressed sparse columns, sorted rows); ``solver.factorize(data)`` refactorises with
new numbers in that pattern; ``solver.solve(b)`` solves ``H x = b``. A matrix that is not
positive definite raises :class:`~microlie.optim.linalg.base.SingularSystemError`, with one
test for every backend but PARDISO: a pivot of the factorisation (``d_k`` of ``LDL^T``,
``L_kk^2`` of Cholesky) at most :data:`~microlie.optim.linalg.base.PIVOT_TOL` times its
column's diagonal entry counts as zero. A rank-deficient system
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

from ..._fast import compiled as compiled_module
from ..core.threads import limit_new_libraries
from .base import LinearSolver, SingularSystemError
from .ordering import graph, minimum_degree_blocks, splu_symmetric

# SciPy is imported where a backend needs it (not by the supernodal Cholesky's path)

__all__ = ["make_solver", "available_solvers", "auto_order", "SOLVERS"]


def _checked(x: np.ndarray) -> np.ndarray:
    if not np.all(np.isfinite(x)):
        raise SingularSystemError("the linear system is singular (the solution is not finite)")
    return x


def block_order(indptr: np.ndarray, indices: np.ndarray, n: int, bs: int,
                block_pattern: Any = None) -> np.ndarray:
    """A fill-reducing order of the unknowns (new -> old) from the minimum-degree order of the
    block graph (``bs`` times smaller than the scalar one; ``block_pattern``: its CSC, else
    read from the scalar pattern; see
    :func:`~microlie.optim.linalg.ordering.minimum_degree_blocks`)."""
    if bs <= 0 or n % bs:
        bs = 1
    if block_pattern is not None and bs > 1:
        q = minimum_degree_blocks(block_pattern[0], block_pattern[1], n // bs)
    else:
        G = graph(indptr, indices, n, bs)
        q = minimum_degree_blocks(G.indptr, G.indices, G.shape[0])
    return (q[:, None] * bs + np.arange(bs)).ravel()


class ScipySolver(LinearSolver):
    """SuperLU (scipy) in symmetric mode (diagonal pivots, no partial pivoting) on the matrix
    permuted once by the minimum-degree order of the block graph (25% faster than SuperLU's
    own ``MMD_AT_PLUS_A`` on the scalar matrix, measured on M3500)."""

    name = "scipy"

    def analyse(self, indptr, indices, n, block_size=1, block_pattern=None):
        import scipy.sparse as sp  # type: ignore[import-untyped]

        super().analyse(indptr, indices, n, block_size, block_pattern)
        indices = self.indices
        p = block_order(indptr, indices, n, block_size, block_pattern)
        tag = sp.csc_matrix((np.arange(1, indices.size + 1, dtype=np.float64), indices,
                             indptr), shape=(n, n))[p][:, p].tocsc()
        tag.sort_indices()
        self._map = tag.data.astype(np.int64) - 1
        self._pindptr, self._pindices = tag.indptr, tag.indices
        self._p = p

    def factorize(self, data: np.ndarray) -> None:
        import scipy.sparse as sp  # type: ignore[import-untyped]

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

    def analyse(self, indptr, indices, n, block_size=1, block_pattern=None):
        super().analyse(indptr, indices, n, block_size, block_pattern)
        self._triangles()
        import qdldl  # type: ignore[import-not-found]

        self._mod = qdldl
        self._solver: Any = None

    def factorize(self, data: np.ndarray) -> None:
        import scipy.sparse as sp  # type: ignore[import-untyped]

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

    def analyse(self, indptr, indices, n, block_size=1, block_pattern=None):
        super().analyse(indptr, indices, n, block_size, block_pattern)
        self._triangles()
        import scipy.sparse as sp  # type: ignore[import-untyped]

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
        from scipy.linalg import lapack  # type: ignore[import-untyped]

        c, info = lapack.dpotrf(self.full(data).toarray(), lower=1, clean=0,
                                    overwrite_a=1)
        if info:
            self._c = None
            i = info - 1 if info > 0 else None
            raise SingularSystemError(f"the linear system is singular or not positive definite: "
                                      f"the pivot of unknown {i} is not positive", unknown=i)
        self._c = (c, True)
        self._check_pivots(data, np.diagonal(c) ** 2, np.arange(self.n))

    def solve(self, b: np.ndarray) -> np.ndarray:
        from scipy.linalg import cho_solve  # type: ignore[import-untyped]

        return _checked(cho_solve(self._c, b, check_finite=False))


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


#: ``"auto"``'s size limits (unknowns), measured as a user pays (graph construction, pattern,
#: ordering and symbolic analysis, solve) by ``benchmarks/scaling.py`` and
#: ``benchmarks/pose_graph.py --user-pays`` (``benchmarks/results/scaling-latest.md``,
#: ``pose_graph-latest.md``; see :func:`auto_order`).
AUTO_DENSE = 300
AUTO_QDLDL_3D = 12_000
AUTO_SCIPY = 5_000


def auto_order(n: int, block_size: int = 1, compiled: bool | None = None) -> tuple[str, ...]:
    """The backends ``"auto"`` tries, best first, for ``n`` unknowns in blocks of ``block_size``.

    The fastest measured per problem kind and size, as a user pays it (analysis included), with
    and without the compiled supernodal loop (``microlie._c._chol``): below :data:`AUTO_DENSE`
    unknowns the dense Cholesky; with the compiled loop, the supernodal Cholesky on every 2-D
    and 3-D size measured (1e3-1e5 poses and the shared graphs, session 8); without it, 2-D
    problems (blocks under 6) qdldl (its scalar LDL^T has almost no analysis to pay, and these
    graphs fill little), 3-D problems (blocks of 6) qdldl below :data:`AUTO_QDLDL_3D` unknowns,
    else the NumPy supernodal loop; without qdldl, SuperLU before the NumPy supernodal loop
    below :data:`AUTO_SCIPY` unknowns. PARDISO, not installed where the tables were measured,
    keeps the place its solve-only measurements gave it: first in 3-D, after the compiled
    supernodal loop and before the NumPy one in 2-D.

    Parameters
    ----------
    n : int
        Number of unknowns.
    block_size : int
        Unknowns per block (the variables' common dimension).
    compiled : bool, optional
        Whether the supernodal Cholesky runs its compiled loop (default: whether
        ``microlie._c._chol`` was built and ``MICROLIE_FAST`` is not ``0``).

    Returns
    -------
    tuple of str
        Backend names, best first, installed or not (``make_solver("auto", ...)`` takes the
        first installed one).

    Examples
    --------
    >>> from microlie.optim.linalg.linear import auto_order
    >>> auto_order(30_000, 3, compiled=True)[0], auto_order(30_000, 3, compiled=False)[0]
    ('cholesky', 'qdldl')
    >>> auto_order(15_000, 6, compiled=False)[:2]
    ('pardiso', 'cholesky')
    """
    if compiled is None:
        compiled = compiled_module("_chol") is not None
    if n < AUTO_DENSE:
        return ("dense", "cholesky", "scipy")
    sup = ("cholesky", "scipy") if compiled or n >= AUTO_SCIPY else ("scipy", "cholesky")
    if block_size >= 6:
        small = not compiled and n < AUTO_QDLDL_3D
        return ("pardiso", "qdldl", *sup) if small else ("pardiso", *sup, "qdldl")
    if compiled:
        return (sup[0], "pardiso", sup[1], "qdldl")
    return ("qdldl", "pardiso", *sup)


def make_solver(name: str | LinearSolver, n: int = 0, block_size: int = 1,
                available: list[str] | None = None) -> LinearSolver:
    """A linear solver by name.

    ``"auto"`` takes the first installed backend of :func:`auto_order` (the fastest measured
    for the problem's kind and size, with or without the compiled loop).

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
        if n < AUTO_DENSE:
            return DenseSolver()
        avail = available_solvers() if available is None else available
        return SOLVERS[next(k for k in auto_order(n, block_size) if k in avail)]()()
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
