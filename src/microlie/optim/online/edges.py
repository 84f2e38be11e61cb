"""Linearising many pose-graph edges of :class:`IncrementalSmoother` in one compiled call.

An incremental smoother relinearises a few rows of many factor batches at a time (one batch of
one edge per odometry step). :class:`EdgeRows` keeps the measurement and square-root
information of every SE(2) / SE(3) :class:`~microlie.optim.BetweenFactor` row without a robust
loss or a fixed end, and linearises any set of them in one call of the engine's compiled edge
loop (``microlie._c._graph``: residual, right Jacobians, whitening, ``A^T A`` and ``A^T e``),
whatever batch each came from. Other rows, or without the compiled module, take the smoother's
NumPy path (one :meth:`~microlie.optim.Factor.evaluate` per factor batch).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ... import _fast
from ..core.factors import BetweenFactor, Factor

__all__ = ["EdgeRows"]

_NAMES = {"SE2": "se2", "SE3": "se3"}


class _Store:
    """The edge rows of one variable handle."""

    def __init__(self, fn: Any, P: int, D: int) -> None:
        self.fn, self.P, self.D = fn, P, D
        self.n = 0
        self.ii = np.zeros(16, dtype=np.int64)
        self.jj = np.zeros(16, dtype=np.int64)
        self.Z = np.zeros((16, P))
        self.L = np.zeros((16, D, D))
        z = np.zeros((0, 2), dtype=np.int64)
        self._lay: tuple[np.ndarray, np.ndarray, np.ndarray] = (np.zeros((0, 4), np.int64), z, z)

    def layout(self, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where the kernel writes ``m`` rows: row ``q``'s ``(2 D, 2 D)`` block of ``A^T A``
        at ``q (2 D)^2`` (blocks (i, i), (i, j), (j, i), (j, j)) and its ``A^T e`` at
        ``q 2 D`` (kept for the largest ``m`` seen; views of it)."""
        if m > self._lay[0].shape[0]:
            D, W = self.D, 2 * self.D
            k = max(m, 2 * self._lay[0].shape[0])
            base = np.arange(k, dtype=np.int64) * (W * W)
            self._lay = (np.ascontiguousarray(base[:, None] + np.array([0, D * W, D, D * W + D])),
                         np.full((k, 2), W, dtype=np.int64),
                         np.ascontiguousarray((np.arange(k, dtype=np.int64) * W)[:, None]
                                              + np.array([0, D])))
        return self._lay[0][:m], self._lay[1][:m], self._lay[2][:m]

    def add(self, ii: np.ndarray, jj: np.ndarray, Z: np.ndarray, L: np.ndarray) -> int:
        """Append ``m`` rows; return the slot of the first (the others follow)."""
        m = ii.size
        while self.n + m > self.ii.size:
            for name in ("ii", "jj", "Z", "L"):
                a = getattr(self, name)
                setattr(self, name, np.concatenate([a, np.zeros_like(a)]))
        a, b = self.n, self.n + m
        self.ii[a:b], self.jj[a:b], self.Z[a:b], self.L[a:b] = ii, jj, Z, L
        self.n = b
        return a


class EdgeRows:
    """The compiled linearisation of pose-graph edge rows (see the module docstring).

    Parameters
    ----------
    compiled : bool, optional
        Use ``microlie._c._graph`` (default: when it is built and ``MICROLIE_FAST`` is not 0);
        ``False``: every row takes the NumPy path.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, BetweenFactor, Diagonal
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3))
    >>> f = BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0, 0]), Diagonal([0.5, 0.5, 0.5]))
    >>> e = EdgeRows()
    >>> e.add(f, np.array([10, 11]))
    >>> H, b = [None] * 12, [None] * 12
    >>> left = e.linearize([11, 3], [x.initial], H, b)
    >>> compiled = e.module is not None
    >>> left == ([1] if compiled else [0, 1]), (H[11] is not None) == compiled
    (True, True)
    """

    def __init__(self, compiled: bool | None = None) -> None:
        mod = _fast.module("_graph")
        self.module: Any = mod if (compiled is None or compiled) else None
        self._stores: dict[int, _Store] = {}
        self._key = np.full(16, -1, dtype=np.int64)   # per row id: the handle, -1: NumPy path
        self._slot = np.zeros(16, dtype=np.int64)

    def add(self, f: Factor, rows: np.ndarray) -> None:
        """Register the rows ``rows`` (ids, one per factor of ``f``) of the batch ``f``: kept
        when ``f`` is an SE(2) / SE(3) BetweenFactor without a loss or a fixed end."""
        rows = np.asarray(rows, dtype=np.int64)
        self._grow(rows)
        if not self.accepts(f) or not isinstance(f, BetweenFactor):
            return
        (var, ii), (_, jj) = f.args
        if var.fixed[ii].any() or var.fixed[jj].any():
            return
        L = np.broadcast_to(f.noise.sqrt_info, (f.count, var.dof, var.dof))
        Z = np.asarray(var.params_of(f.Z), dtype=np.float64).reshape(f.count, -1)
        self.add_raw(var, rows.tolist(), ii, jj, Z, L)

    def accepts(self, f: Factor) -> bool:
        """Whether rows of ``f`` can be kept (the compiled module is there, ``f`` is an SE(2) /
        SE(3) BetweenFactor without a loss; fixed ends are the caller's to check)."""
        return (self.module is not None and type(f) is BetweenFactor and f.loss is None
                and f.args[0][0].group.__name__ in _NAMES)

    def _grow(self, rows: np.ndarray) -> None:
        if rows.size and rows.max() >= self._key.size:
            grow = max(int(rows.max()) + 1, 2 * self._key.size)
            self._key = np.concatenate([self._key, np.full(grow - self._key.size, -1,
                                                           dtype=np.int64)])
            self._slot = np.concatenate([self._slot, np.zeros(grow - self._slot.size,
                                                              dtype=np.int64)])

    def add_raw(self, var: Any, rows: list[int], ii: np.ndarray, jj: np.ndarray,
                Z: np.ndarray, L: np.ndarray) -> None:
        """Keep rows ``rows`` (increasing ids) of edges ``ii -> jj`` of ``var`` (neither end
        fixed; the caller checked :meth:`accepts`) with measurement parameters ``Z``
        ``(m, P)`` and square-root information ``L`` ``(m, D, D)``."""
        if rows[-1] >= self._key.size:
            self._grow(np.asarray(rows, dtype=np.int64))
        store = self._stores.get(var.key)
        if store is None:
            fn = getattr(self.module, f"{_NAMES[var.group.__name__]}_between_normal")
            store = self._stores[var.key] = _Store(fn, var.initial.shape[-1], var.dof)
        q = store.add(ii, jj, Z, L)
        if len(rows) == 1:
            self._slot[rows[0]] = q
            self._key[rows[0]] = var.key
        else:
            self._slot[rows] = np.arange(q, q + len(rows))
            self._key[rows] = var.key

    def linearize(self, rows: list[int], lin: list[np.ndarray], H: list[Any], b: list[Any]
                  ) -> list[int]:
        """Linearise the kept rows among ``rows`` (distinct row ids) at the parameters ``lin``
        (per handle key): ``H[r] = A^T A`` ``(2 D, 2 D)`` and ``b[r] = -A^T e`` ``(2 D,)`` over
        the row's two ends (first, second), for each kept row ``r``.

        Returns
        -------
        list of int
            The positions in ``rows`` of the rows not kept (for the NumPy path).
        """
        if len(rows) <= 8:  # the new edges of one update: Python ints, slices if contiguous
            K, S = self._key, self._slot
            key = int(K[rows[0]])
            q = int(S[rows[0]])
            m = len(rows)
            if key >= 0 and all(int(K[r]) == key and int(S[r]) == q + k
                                for k, r in enumerate(rows)):
                self._run(self._stores[key], rows, slice(q, q + m), lin[key], H, b)
                return []
        ra = np.asarray(rows, dtype=np.int64)
        keys = self._key[ra]
        left: list[int] = []
        for key, store in self._stores.items():
            sel = np.flatnonzero(keys == key)
            if sel.size == len(rows):
                self._run(store, rows, self._slot[ra], lin[key], H, b)
                return left
            if sel.size:
                self._run(store, ra[sel].tolist(), self._slot[ra[sel]], lin[key], H, b)
        return np.flatnonzero(keys < 0).tolist()

    def _run(self, store: _Store, rows: list[int], sl: Any, X: np.ndarray, H: list[Any],
             b: list[Any]) -> None:
        """The kernel over ``rows`` (all of ``store``'s handle, at its slots ``sl``) into ``H``
        and ``b``, at ``X`` (C-contiguous float64, as the smoother keeps its points)."""
        m = len(rows)
        W = 2 * store.D
        starts, lens, goff = store.layout(m)
        data = np.zeros((m, W, W))
        grad = np.zeros((m, W))
        s = np.empty(m)
        store.fn(X, store.ii[sl], store.jj[sl], store.Z[sl], store.L[sl], None, starts, lens,
                 goff, s, data.reshape(-1), grad.reshape(-1))
        np.negative(grad, out=grad)
        for r, Hr, br in zip(rows, data, grad, strict=True):
            H[r] = Hr
            b[r] = br
