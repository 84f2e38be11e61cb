"""The compiled edge loops of ``microlie._c._graph`` for factor batches (built by ``pip install
microlie`` where a C compiler exists; ``microlie --version`` says whether they were).

A batch of SE(3) or SE(2) :class:`~microlie.optim.BetweenFactor` edges is linearised in one pass of
``microlie._c._graph``: residuals, right Jacobians, whitening, the robust correction, the block
products ``A^T A`` and ``A^T e``, added straight into the CSC values of the problem's fixed
pattern. The NumPy path of :class:`~microlie.optim.core.problem.Problem` stays the reference and the
fallback; both give the same linear system to rounding (``tests/test_optim_compiled.py``).
``MICROLIE_FAST=0`` (read when a problem is built) keeps the NumPy path.

>>> from microlie.optim.core.compiled import available
>>> isinstance(available(), bool)
True
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..._fast import compiled as compiled_module
from .factors import BetweenFactor, Factor

__all__ = ["available", "EdgePlan", "plan"]

# the groups with a compiled BetweenFactor loop: class name -> kernel prefix
_KERNELS = {"SE3": "se3", "SE2": "se2"}


def _graph() -> Any:
    """``microlie._c._graph``, or ``None`` (not installed, an older build, or
    ``MICROLIE_FAST=0``)."""
    return compiled_module("_graph")


def available() -> bool:
    """Whether the compiled edge loops are in use for problems built now.

    Returns
    -------
    bool

    Examples
    --------
    >>> from microlie.optim.core.compiled import available
    >>> available() in (True, False)
    True
    """
    return _graph() is not None


class EdgePlan:
    """One factor batch on the compiled path: its arguments as contiguous arrays and its
    destinations in the pattern (built by :func:`plan`).

    Parameters
    ----------
    kernels : tuple
        ``(cost, normal)`` functions of ``microlie._c._graph``.
    key : int
        The position of the variable batch in the problem's states.
    ii, jj : numpy.ndarray
        ``(m,)`` int64 indices of both ends in that batch.
    Z : numpy.ndarray
        ``(m, param_dim)`` measurements.
    L : numpy.ndarray
        ``(1 or m, dim, dim)`` square-root information.
    starts, lens, goff : numpy.ndarray
        ``(m, 4)`` CSC positions of entry (0, 0) of the blocks (i, i), (i, j), (j, i), (j, j)
        (-1: a fixed end), ``(m, 2)`` column lengths of both ends' block columns, ``(m, 2)``
        gradient offsets (-1: fixed).

    Examples
    --------
    >>> from microlie import SE3
    >>> from microlie.optim import FactorGraph, BetweenFactor
    >>> from microlie.optim.core.compiled import plan
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE3.identity(2), fixed=[0])
    >>> _ = g.add(BetweenFactor(x, 0, 1, SE3.exp([1.0, 0, 0, 0, 0, 0.3])))
    >>> p = g.problem()
    >>> pl = plan(p, p.factors[0])
    >>> pl is None or pl.starts.tolist() == [[-1, -1, -1, 0]]
    True
    """

    def __init__(self, kernels: tuple, key: int, ii: np.ndarray, jj: np.ndarray,
                 Z: np.ndarray, L: np.ndarray, starts: np.ndarray, lens: np.ndarray,
                 goff: np.ndarray) -> None:
        self._cost, self._normal = kernels
        self.key = key
        self.ii, self.jj, self.Z, self.L = ii, jj, Z, L
        self.starts, self.lens, self.goff = starts, lens, goff

    def cost(self, states: list[np.ndarray]) -> np.ndarray:
        """``s_k = |L_k r_k|^2`` per factor.

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in problem order.

        Returns
        -------
        numpy.ndarray
            ``(m,)``.

        Examples
        --------
        >>> from microlie import SE3
        >>> from microlie.optim import FactorGraph, BetweenFactor
        >>> from microlie.optim.core.compiled import plan
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE3.identity(2), fixed=[0])
        >>> _ = g.add(BetweenFactor(x, 0, 1, SE3.exp([1.0, 0, 0, 0, 0, 0.0])))
        >>> p = g.problem()
        >>> pl = plan(p, p.factors[0])
        >>> s = pl.cost([v.initial for v in p.variables]) if pl else [1.0]  # |r|^2 = 1
        >>> round(float(s[0]), 12)
        1.0
        """
        s = np.empty(self.ii.size)
        self._cost(_rows(states[self.key]), self.ii, self.jj, self.Z, self.L, s)
        return s

    def normal(self, states: list[np.ndarray], data: np.ndarray, grad: np.ndarray,
               wts: np.ndarray | None) -> np.ndarray:
        """Add the batch's ``A^T A`` into ``data`` and ``A^T e`` into ``grad``; return ``s``.

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in problem order.
        data, grad : numpy.ndarray
            The CSC values ``(nnz,)`` and the gradient ``(size,)``, added to in place.
        wts : numpy.ndarray or None
            ``(m, 3)`` rows ``(sqrt(rho'), residual scale, alpha / s)`` of the robust
            correction, or ``None`` without a loss.

        Returns
        -------
        numpy.ndarray
            ``(m,)`` the squared whitened residuals before the correction.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3
        >>> from microlie.optim import FactorGraph, BetweenFactor
        >>> from microlie.optim.core.compiled import plan
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE3.identity(2), fixed=[0])
        >>> _ = g.add(BetweenFactor(x, 0, 1, SE3.exp([1.0, 0, 0, 0, 0, 0.0])))
        >>> p = g.problem()
        >>> pl = plan(p, p.factors[0])
        >>> data, grad = np.zeros(p.nnz), np.zeros(p.size)
        >>> s = pl.normal([v.initial for v in p.variables], data, grad, None) if pl else [1.0]
        >>> round(float(s[0]), 12), pl is None or bool(data.max() > 0)
        (1.0, True)
        """
        s = np.empty(self.ii.size)
        self._normal(_rows(states[self.key]), self.ii, self.jj, self.Z, self.L, wts,
                     self.starts, self.lens, self.goff, s, data, grad)
        return s


def _rows(p: np.ndarray) -> np.ndarray:
    """Parameters as the C-contiguous float64 rows the compiled loop reads (no copy when they
    are already)."""
    return np.ascontiguousarray(p, dtype=np.float64)


def plan(problem: Any, f: Factor) -> EdgePlan | None:
    """The compiled plan of a factor batch of ``problem``, or ``None`` when it takes the NumPy
    path (no compiled loop for its type, or the extra not in use).

    Parameters
    ----------
    problem : Problem
        The problem (its pattern built).
    f : Factor
        One of its factor batches.

    Returns
    -------
    EdgePlan or None

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> from microlie.optim.core.compiled import plan
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(1))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> p = g.problem()
    >>> plan(p, p.factors[0]) is None  # priors take the NumPy path
    True
    """
    mod = _graph()
    if mod is None or type(f) is not BetweenFactor:
        return None
    (var, ii), (_, jj) = f.args
    name = _KERNELS.get(var.group.__name__)
    if name is None or not hasattr(mod, f"{name}_between_normal"):
        return None
    d = f.dim
    k = problem.key(var)
    ni, nj = (problem.node_of[k][ii], problem.node_of[k][jj])
    starts = np.stack([problem.block_start(a, b) for a in (ni, nj) for b in (ni, nj)], axis=1)
    lens = np.stack([problem.column_length(ni), problem.column_length(nj)], axis=1)
    goff = np.stack([np.where(n >= 0, problem.node_off[np.maximum(n, 0)], -1) for n in (ni, nj)],
                    axis=1)
    L = f.noise.sqrt_info
    L = np.ascontiguousarray(L.reshape(-1, d, d), dtype=np.float64)
    Z = np.ascontiguousarray(f.Z.params, dtype=np.float64)
    kernels = (getattr(mod, f"{name}_between_cost"), getattr(mod, f"{name}_between_normal"))
    return EdgePlan(kernels, k,
                    np.ascontiguousarray(ii, np.int64), np.ascontiguousarray(jj, np.int64), Z, L,
                    np.ascontiguousarray(starts, np.int64), np.ascontiguousarray(lens, np.int64),
                    np.ascontiguousarray(goff, np.int64))
