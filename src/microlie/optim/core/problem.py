"""The least-squares problem of a graph: linearisation, and assembly into a fixed pattern.

Built once per optimisation: every free variable gets a block of columns (fixed ones get
none), the block sparsity of ``H = J^T J`` (whitened) is analysed once into a compressed
sparse column pattern (full symmetric storage, diagonal blocks always present), and every
factor batch gets a precomputed place for each of its products. Each iteration then only
refills the numbers, in work arrays kept by the problem: the whitened Jacobians and residuals
``[A e] = L [J_1 ... J_K r]`` in one product, ``[A e]^T [A e]`` in another, and one sparse
0/1 matrix product that sums them into the CSC values of ``H`` and the gradient.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..._fast import compiled as compiled_module
from ..linalg.base import expand_blocks, pattern_csr, split_blocks
from ..linalg.ordering import connected_components
from . import compiled
from .factors import Factor
from .robust import corrected_weights
from .variables import Variables

__all__ = ["Problem", "Linearization", "GaugeError", "NonFiniteError"]

# factors per chunk of the NumPy path's products (their operands stay in the 4 MB L2 cache)
_CHUNK = 512


class GaugeError(ValueError):
    """The graph leaves some variables unconstrained up to a common transformation.

    Attributes
    ----------
    message : str
        The error text (``str(error)``).
    unanchored : list of (Variables, int)
        The first variable of each connected component that no prior or fixed variable
        anchors.
    count : int
        The number of variables in those components.

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import BetweenFactor, FactorGraph, GaugeError
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(2), name="x")
    >>> _ = g.add(BetweenFactor(x, 0, 1, SE2.identity()))
    >>> try:
    ...     g.optimize()
    ... except GaugeError as e:
    ...     print(e.count, [f"{v.name}[{i}]" for v, i in e.unanchored])
    2 ['x[0]']
    """

    def __init__(self, message: str, unanchored: list | None = None, count: int = 0) -> None:
        super().__init__(message)
        self.unanchored: list[tuple[Variables, int]] = list(unanchored or [])
        self.count = count


class NonFiniteError(ValueError):
    """The cost or the linearisation of a factor is not finite.

    Attributes
    ----------
    message : str
        The error text (``str(error)``).
    factor : int
        The factor batch (its position in the graph's factors).
    row : int
        The factor within the batch.
    variables : list of (Variables, int)
        Its arguments.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import CustomFactor, FactorGraph
    >>> from microlie.optim import NonFiniteError
    >>> g = FactorGraph()
    >>> x = g.add_variables(np.array([[1.0]]), name="x")
    >>> _ = g.add(CustomFactor(lambda v: np.full_like(v, np.nan), [(x, 0)], 1))
    >>> try:
    ...     g.optimize()
    ... except NonFiniteError as e:
    ...     print(e.factor, e.row, [f"{v.name}[{i}]" for v, i in e.variables])
    0 0 ['x[0]']
    """

    def __init__(self, message: str, factor: int, row: int,
                 variables: list[tuple[Variables, int]]) -> None:
        super().__init__(message)
        self.factor, self.row, self.variables = factor, row, variables


@dataclass
class Linearization:
    """One linearisation of a :class:`Problem` (returned by :meth:`Problem.linearize`).

    Attributes
    ----------
    data : numpy.ndarray
        ``H = J^T J`` (whitened, robust weights applied) as CSC data in the problem's pattern
        (the rows and columns of held components replaced, see :meth:`Problem.hold`).
    grad : numpy.ndarray
        ``g = J^T e``.
    cost, robust_cost : float
        The plain and the robust cost at the linearisation point.
    times : dict
        Timings of the parts, seconds.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
    >>> p = g.problem()
    >>> lin = p.linearize([v.initial for v in p.variables])
    >>> lin.data.shape == p.indices.shape, lin.cost
    (True, 1.0)
    """

    data: np.ndarray
    grad: np.ndarray
    cost: float
    robust_cost: float
    times: dict = field(default_factory=dict)


class Problem:
    """The least-squares problem of a graph: unknown numbering, the block pattern of
    ``H = J^T J``, and evaluation into it (built by :meth:`FactorGraph.problem`).

    Parameters
    ----------
    variables : list of Variables
        The graph's variable batches.
    factors : list of Factor
        The graph's factor batches.
    gauge : {"check", "fix_first", "none"}
        See :meth:`FactorGraph.optimize`.

    Raises
    ------
    GaugeError
        ``gauge="check"`` and some variables are not anchored.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(3))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
    >>> p = g.problem()
    >>> states = [v.initial for v in p.variables]
    >>> p.size, p.block_size, p.num_nodes
    (9, 3, 3)
    """
    def __init__(self, variables: list[Variables], factors: list[Factor],
                 gauge: str = "check") -> None:
        self.variables = variables
        self.factors = factors
        self.has_loss = any(f.loss is not None for f in factors)
        self._key = {id(v): k for k, v in enumerate(variables)}
        self.gauge_fixed: list[tuple[Variables, int]] = []
        if gauge not in ("check", "fix_first", "none"):
            raise ValueError(f"gauge must be 'check', 'fix_first' or 'none', got {gauge!r}")
        self._number()
        self._build_pattern()
        if gauge != "none":
            self._check_gauge(gauge)  # on the block pattern (its graph is the factors')
            if self.gauge_fixed:
                self._number()
                self._build_pattern()
        self._held_pos = self._held_positions()
        # the compiled edge loop of each factor batch (None: the NumPy path)
        self.plans = [compiled.plan(self, f) for f in factors]
        self._build_scatter()

    def _number(self) -> None:
        """One node per free variable, in graph order (gauge-fixed ones count as fixed)."""
        extra: dict[int, list[int]] = {}
        for var, i in self.gauge_fixed:
            extra.setdefault(id(var), []).append(i)
        node_of, dofs, nn = [], [], 0
        for v in self.variables:
            nodes = np.full(v.n, -1, dtype=np.int64)
            fixed = v.fixed | v.held.all(axis=1)  # every component held: fixed
            fixed[extra.get(id(v), [])] = True
            free = np.flatnonzero(~fixed)
            nodes[free] = nn + np.arange(free.size)
            nn += free.size
            node_of.append(nodes)
            dofs.append(np.full(free.size, v.dof, dtype=np.int64))
        self.node_of = node_of
        self.num_nodes = nn
        self.node_dof = np.concatenate(dofs) if dofs else np.zeros(0, np.int64)
        self.node_off = np.concatenate([[0], np.cumsum(self.node_dof)]).astype(np.int64)
        self.size = int(self.node_off[-1])
        self.block_size = int(np.gcd.reduce(self.node_dof)) if nn else 1
        self.fargs = [[node_of[self._key[id(var)]][idx] for var, idx in f.args]
                      for f in self.factors]
        # per variable batch: its free rows (None: all) and their entries of a step dx; the
        # unknowns of held components (Variables.fix(..., components))
        self._steps = []
        held = [np.zeros(0, np.int64)]
        for v, nodes in zip(self.variables, node_of, strict=True):
            free = np.flatnonzero(nodes >= 0)
            idx = self.node_off[nodes[free]][:, None] + np.arange(v.dof)
            self._steps.append((None if free.size == v.n else free, idx))
            held.append(idx[v.held[free]])
        self.held = np.concatenate(held)

    def key(self, var: Variables) -> int:
        """The position of a variable batch in the problem.

        Parameters
        ----------
        var : Variables
            A handle of the graph.

        Returns
        -------
        int

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> states = [v.initial for v in p.variables]
        >>> p.key(x)
        0
        """
        return self._key[id(var)]

    # ------------------------------------------------------------------ gauge
    def _check_gauge(self, gauge: str) -> None:
        """Anchor each connected component of the pattern's graph (two free nodes are joined
        when a factor holds both) by a prior-like factor or a fixed variable, or raise
        :class:`GaugeError` (``"check"``) or hold the first variable of each unanchored
        component (``"fix_first"``, :attr:`gauge_fixed`)."""
        nn = self.num_nodes
        if nn == 0:
            return
        anchored = np.zeros(nn, dtype=bool)
        for nodes in self.fargs:
            stack = np.stack(nodes)  # (K, m)
            free = stack >= 0
            nfree = free.sum(0)
            absolute = (len(nodes) == 1) | (nfree < len(nodes))
            for k in range(len(nodes)):
                anchored[stack[k][free[k] & absolute]] = True
        bptr, brow = self._bptr, self._brow
        mod = compiled_module("_pattern")
        if mod is not None:
            ncomp, label = mod.components(bptr, brow)
        else:
            ncomp, label = connected_components(
                nn, np.repeat(np.arange(nn, dtype=np.int64), np.diff(bptr)), brow)
        ok = np.zeros(ncomp, dtype=bool)
        ok[label[anchored]] = True
        if ok.all():
            return
        bad = ~ok[label]
        firsts = [self._node_var(int(np.flatnonzero(label == comp)[0]))
                  for comp in np.flatnonzero(~ok)]
        if gauge == "check":
            first = int(np.flatnonzero(bad)[0])
            name = self._node_name(first)
            raise GaugeError(
                f"the graph has a gauge freedom: {int(bad.sum())} variables (in "
                f"{int((~ok).sum())} connected component(s), the first containing {name}) are "
                f"not connected to a prior or a fixed variable; add a PriorFactor, fix a "
                f"variable, or pass gauge='fix_first' to hold the first variable of each such "
                f"component constant", firsts, int(bad.sum()))
        self.gauge_fixed.extend(firsts)

    def _node_var(self, node: int) -> tuple[Variables, int]:
        for v, nodes in zip(self.variables, self.node_of, strict=False):
            hit = np.flatnonzero(nodes == node)
            if hit.size:
                return v, int(hit[0])
        raise KeyError(node)

    def _node_name(self, node: int) -> str:
        v, i = self._node_var(node)
        return f"{v.name}[{i}]"

    def unknown_name(self, unknown: int) -> str:
        """The variable that unknown (row of ``H``) ``unknown`` belongs to, as ``name[index]``.

        Parameters
        ----------
        unknown : int
            A row of ``H``, ``0 <= unknown < size``.

        Returns
        -------
        str

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3), name="x")
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> g.problem().unknown_name(4)  # unknowns 3..5 are x[1]
        'x[1]'
        """
        if not 0 <= unknown < self.size:
            raise ValueError(f"unknown must be in [0, {self.size}), got {unknown}")
        return self._node_name(int(np.searchsorted(self.node_off, unknown, side="right")) - 1)

    # ------------------------------------------------------------------ pattern
    def _pairs(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The node pairs ``(a, b)`` (intp, -1: fixed) of every two arguments of each factor."""
        out = []
        for nodes in self.fargs:
            for k in range(len(nodes)):
                for l in range(k + 1, len(nodes)):
                    out.append((np.ascontiguousarray(nodes[k], np.intp),
                                np.ascontiguousarray(nodes[l], np.intp)))
        return out

    def _build_pattern(self) -> None:
        """The pattern of ``H``: the block pattern (one block per pair of nodes that share a
        factor, and the diagonal) as a symmetric block CSC with sorted rows, in C
        (``microlie._c._pattern``) or NumPy; the scalar CSC column pointers (``indptr``; the row
        indices expanded on first use). Entry ``(r, c)`` of block ``(u, v)`` is at
        ``bstart_uv + c * collen_v + r`` (every scalar column of block column ``v`` holds the
        same ``collen_v`` rows); kept per block, not per entry."""
        nn, dof, bs = self.num_nodes, self.node_dof, self.block_size
        mod = compiled_module("_pattern")
        self._bkey_: np.ndarray | None = None  # block keys v * nn + u, for the NumPy lookup
        if mod is not None:
            bptr, brow, bstart, collen = mod.block_pattern(nn, self._pairs(), dof)
            nnz = int(np.dot(dof, collen))
        else:
            itype = np.int32 if nn < 2**31 else np.int64
            rows, cols = [], []
            for a, b in self._pairs():
                both = (a >= 0) & (b >= 0)
                a, b = a[both].astype(itype), b[both].astype(itype)
                rows += [a, b]
                cols += [b, a]
            diag = np.arange(nn, dtype=itype)
            # symmetric: its CSR is its CSC (column v holds the rows u, sorted, no duplicates)
            bptr, brow = pattern_csr(np.concatenate(rows + [diag]),
                                     np.concatenate(cols + [diag]), nn)
            del rows, cols
            bcol = np.repeat(np.arange(nn, dtype=np.int64), np.diff(bptr))
            cs = np.r_[0, np.cumsum(dof[brow])]
            collen = cs[bptr[1:]] - cs[bptr[:-1]]  # rows of each scalar column of column v
            base = np.r_[0, np.cumsum(dof * collen)]
            bstart = base[bcol] + cs[:-1] - cs[bptr[bcol]]  # CSC position of its (0, 0)
            nnz = int(base[-1])
            del bcol, cs, base
        self._bptr, self._brow, self._bstart, self._collen = bptr, brow, bstart, collen
        # the pattern of bs x bs sub-blocks (a node of dimension d is d / bs sub-blocks)
        if nn and (dof != bs).any():
            bptr, brow = split_blocks(bptr, brow, dof // bs)
        # the pattern of bs x bs blocks, for the analyses that work on blocks
        self.block_pattern = (bptr, brow)
        if int(bptr[-1]) * bs * bs != nnz:
            raise AssertionError("pattern: the scalar pattern disagrees with the block one")
        self.nnz = nnz
        ptype = np.int32 if nnz < 2**31 else np.int64
        # the scalar pattern's column pointers (each scalar column of a sub-block column holds
        # its blocks' bs rows each); its row indices are expanded on first use (indices)
        self.indptr = np.r_[0, np.cumsum(np.repeat(np.diff(bptr) * bs, bs))].astype(ptype)
        self._indices: np.ndarray | None = None
        # diagonal positions (for damping): entry (c, c) of each diagonal block
        diag = self.block_start(np.arange(nn), np.arange(nn))
        node = np.repeat(np.arange(nn), dof)
        cc = np.arange(self.size) - self.node_off[node]
        self.diag_pos = diag[node] + cc * (collen[node] + 1)

    @property
    def indices(self) -> np.ndarray:
        """The row indices of the scalar CSC pattern of ``H`` (int32, rows sorted; with
        :attr:`indptr`), expanded from :attr:`block_pattern` on first use: the supernodal
        Cholesky works on the blocks and never needs them.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(2))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0], [1], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> p.indices[:6].tolist(), p.indices.size == p.nnz == 36
        ([0, 1, 2, 3, 4, 5], True)
        """
        if self._indices is None:
            self._indices = expand_blocks(*self.block_pattern, self.block_size)[1]
        return self._indices

    def _held_positions(self) -> np.ndarray:
        """CSC positions of the rows and columns of the held unknowns (``self.held``)."""
        if not self.held.size:
            return self.held
        mask = np.zeros(self.size, bool)
        mask[self.held] = True
        col = np.repeat(mask, np.diff(self.indptr))
        return np.flatnonzero(mask[self.indices] | col)

    def hold(self, data: np.ndarray, grad: np.ndarray) -> None:
        """Hold the unknowns ``self.held`` (tangent components fixed with
        ``Variables.fix(..., components)``) at a zero step, in place: their rows and columns
        of ``H`` zero, unit diagonal, zero gradient. Every solve of ``H dx = -g`` (damped or
        not, any backend, Schur or not) then gives exactly ``dx = 0`` there, and the inverse
        has zero off-diagonal entries in those rows (a marginal zeroes its unit diagonal).
        Done by :meth:`linearize`; the block pattern and the numbering stay those of the whole
        variables.

        Parameters
        ----------
        data, grad : numpy.ndarray
            ``Linearization.data`` and ``grad``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.zeros((1, 2)))
        >>> _ = g.add(PriorFactor(x, 0, [1.0, 2.0]))
        >>> g.fix(x, components=[1])
        >>> p = g.problem()
        >>> lin = p.linearize([x.initial])
        >>> p.matrix(lin.data).toarray().tolist(), lin.grad.tolist()
        ([[1.0, 0.0], [0.0, 1.0]], [-1.0, 0.0])
        """
        if self.held.size:
            data[self._held_pos] = 0.0
            data[self.diag_pos[self.held]] = 1.0
            grad[self.held] = 0.0

    def _build_scatter(self) -> None:
        """Where the NumPy-path factors' contributions go in ``[data, grad]``: per factor,
        ``w`` holds the products ``[A e]^T [A e]`` (``(m, D + 1, D + 1)``, row-major; ``D`` =
        the sum of the arguments' dofs), whose ``D x D`` block is ``A^T A`` and whose last row
        holds ``e^T A``; ``_dest`` holds one position per entry of ``w`` (intp: with int32,
        ``np.bincount`` copies, measured 1.5x slower): the CSC values of ``H``, then the
        gradient, then one dump slot for entries of fixed variables and the unused ``e^T e``.
        ``np.bincount`` sums ``w`` into place (as fast as the sparse 0/1 sum matrix it
        replaces, which cost 9x this to build and 1.5x its memory)."""
        dump = self.nnz + self.size
        dests, start = [], 0
        self._spans: dict[int, tuple[int, list[int]]] = {}
        for fi, (f, nodes, pl) in enumerate(zip(self.factors, self.fargs, self.plans,
                                                strict=True)):
            if pl is not None:
                continue
            dofs = [var.dof for var, _ in f.args]
            offs = np.concatenate([[0], np.cumsum(dofs)]).astype(np.int64)
            D = int(offs[-1])
            m = f.count
            # each product is symmetric: entry (a, b) is read from (b, a), so that the rows of
            # a CSC block column (consecutive a) come from consecutive memory
            big = np.full((m, D + 1, D + 1), dump, np.intp)
            for k in range(len(nodes)):
                for l in range(len(nodes)):
                    st = self.block_start(nodes[k], nodes[l])
                    cl = self.column_length(nodes[l])[:, None, None]
                    at = st[:, None, None] + np.arange(dofs[l])[:, None] * cl + np.arange(dofs[k])
                    big[:, offs[l]:offs[l + 1], offs[k]:offs[k + 1]] = np.where(
                        st[:, None, None] >= 0, at, dump)
                big[:, D, offs[k]:offs[k + 1]] = np.where(
                    nodes[k][:, None] >= 0,
                    self.nnz + self.node_off[np.maximum(nodes[k], 0)][:, None]
                    + np.arange(dofs[k]), dump)
            dests.append(big.ravel())
            self._spans[fi] = (start, offs.tolist())
            start += big.size
        self._dest = np.concatenate(dests) if dests else np.zeros(0, np.intp)
        self._work: dict[int, tuple[np.ndarray, ...]] = {}
        self._held: list[np.ndarray] | None = None  # the states whose [A e] the work arrays hold

    def block_start(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """CSC positions of entry (0, 0) of the blocks ``(a[k], b[k])`` of ``H``.

        Every scalar column of a block column holds the same rows, so entry ``(r, c)`` of a block
        is at ``block_start + c * column_length(b) + r``.

        Parameters
        ----------
        a, b : numpy.ndarray
            Node numbers (``-1``: a fixed variable), the same shape.

        Returns
        -------
        numpy.ndarray
            int64 positions in ``Linearization.data``, ``-1`` where ``a`` or ``b`` is fixed.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> p.block_start(np.array([0, 1, -1]), np.array([0, 0, 1])).tolist()
        [0, 3, -1]
        """
        a, b = np.asarray(a, np.intp), np.asarray(b, np.intp)
        nn = self.num_nodes
        if a.shape != b.shape:
            raise ValueError(f"a and b must have one shape, got {a.shape} and {b.shape}")
        mod = compiled_module("_pattern")
        if mod is not None:  # a binary search in the block column
            try:
                pos = mod.positions(self._bptr, self._brow, self._bstart, a.ravel(), b.ravel())
            except ValueError as e:
                raise KeyError(str(e)) from None
            return pos.reshape(a.shape)
        ok = (a >= 0) & (b >= 0)
        q = b.astype(np.int64) * nn + a  # the block key: column-major
        if self._bkey_ is None:
            self._bkey_ = np.repeat(np.arange(nn, dtype=np.int64) * max(nn, 1),
                                    np.diff(self._bptr)) + self._brow
        bkey = self._bkey_
        if not bkey.size:  # no free variable
            if ok.any():
                raise KeyError("block not in the pattern")
            return np.full(a.shape, -1, np.int64)
        k = np.searchsorted(bkey, np.where(ok, q, 0))
        k = np.minimum(k, bkey.size - 1)
        found = ok & (bkey[k] == q)
        if np.any(ok & ~found):
            raise KeyError("block not in the pattern")
        return np.where(found, self._bstart[k], -1)

    def scatter_positions(self, nodes: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where a batch of factors adds into ``H`` and ``g``: what a compiled factor loop
        (:mod:`microlie.optim.core.compiled`) reads.

        Parameters
        ----------
        nodes : numpy.ndarray
            ``(m, K)`` node numbers of the ``K`` arguments of each factor (``-1``: fixed).

        Returns
        -------
        starts : numpy.ndarray
            ``(m, K * K)`` int64: at ``k * K + l`` the :meth:`block_start` of the block
            ``(nodes[:, k], nodes[:, l])`` (``-1`` when either is fixed).
        lens : numpy.ndarray
            ``(m, K)`` int64 :meth:`column_length` of each argument.
        goff : numpy.ndarray
            ``(m, K)`` int64 first unknown of each argument (``-1``: fixed).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> st, ln, go = g.problem().scatter_positions(np.array([[1, 2], [2, -1]]))
        >>> st.tolist(), ln.tolist(), go.tolist()
        ([[21, 45, 24, 48], [48, -1, -1, -1]], [[9, 6], [6, 0]], [[3, 6], [6, -1]])
        """
        nodes = np.ascontiguousarray(nodes, np.intp)
        if nodes.ndim != 2:
            raise ValueError(f"nodes must be (m, K), got shape {nodes.shape}")
        mod = compiled_module("_pattern")
        if mod is not None:
            try:
                return mod.plan(self._bptr, self._brow, self._bstart, self._collen,
                                self.node_off, nodes)
            except ValueError as e:
                raise KeyError(str(e)) from None
        cols = nodes.T
        starts = np.stack([self.block_start(a, b) for a in cols for b in cols], axis=1)
        lens = np.stack([self.column_length(n) for n in cols], axis=1)
        goff = np.stack([np.where(n >= 0, self.node_off[np.maximum(n, 0)], -1) for n in cols],
                        axis=1)
        return (starts.reshape(nodes.shape[0], -1).astype(np.int64),
                lens.reshape(nodes.shape[0], -1).astype(np.int64), goff.astype(np.int64))

    def column_length(self, nodes: np.ndarray) -> np.ndarray:
        """The number of stored rows in each scalar column of the block columns ``nodes``.

        Parameters
        ----------
        nodes : numpy.ndarray
            Node numbers (``-1``: fixed, length 0).

        Returns
        -------
        numpy.ndarray
            int64 lengths.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> g.problem().column_length(np.array([0, 1, -1])).tolist()  # node 1 meets 0 and 2
        [6, 9, 0]
        """
        nodes = np.asarray(nodes, np.int64)
        collen = np.r_[self._collen, 0]  # then the length of a fixed one
        return collen[np.where(nodes >= 0, nodes, -1)]

    def analysed(self, linear_solver: Any, eliminate: Any = None) -> Any:
        """A linear solver that has analysed this problem's pattern (for a backend given by
        name, analysed once per problem and reused).

        Parameters
        ----------
        linear_solver : str or LinearSolver
            A name (see :func:`~microlie.optim.make_solver`; ``"schur"``: a
            :class:`~microlie.optim.linalg.schur_solver.SchurSolver`) or an instance.
        eliminate : Variables or sequence of Variables, optional
            With ``"schur"``: the batches to eliminate (default: the landmark-like ones).

        Returns
        -------
        LinearSolver

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> states = [v.initial for v in p.variables]
        >>> p.analysed("scipy").n
        9
        """
        from ..linalg.linear import make_solver

        if linear_solver == "schur":
            from .elimination import schur_solver

            ls: Any = schur_solver(self, eliminate)
        elif eliminate is not None:
            raise ValueError(f"eliminate applies to linear_solver='schur' only, got "
                             f"linear_solver={linear_solver!r}")
        else:
            ls = make_solver(linear_solver, self.size, self.block_size)
        key = getattr(ls, "key", ls.name)
        if isinstance(linear_solver, str):
            # the symbolic analysis runs once per problem and backend (as GTSAM orders once,
            # in its optimizer's constructor); later solves refactorise the cached solver
            cache = self.__dict__.setdefault("_analysed", {})
            if key in cache:
                return cache[key]
        # the row indices only if expanded already (else the backend expands them if it
        # needs them: the supernodal Cholesky and the Schur elimination work on the blocks)
        ls.analyse(self.indptr, self._indices, self.size, self.block_size,
                   block_pattern=self.block_pattern)
        if isinstance(linear_solver, str):
            cache[key] = ls
        return ls

    def matrix(self, data: np.ndarray) -> Any:
        """The sparse ``H`` of CSC ``data`` in the problem's pattern.

        Parameters
        ----------
        data : numpy.ndarray
            Values in the pattern's order (``Linearization.data``).

        Returns
        -------
        scipy.sparse.csc_matrix
            ``(size, size)``, full symmetric storage.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> states = [v.initial for v in p.variables]
        >>> H = p.matrix(p.linearize(states).data)
        >>> H.shape, bool(abs(H - H.T).max() == 0)
        ((9, 9), True)
        """
        import scipy.sparse as sp  # type: ignore[import-untyped]

        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    # ------------------------------------------------------------------ evaluation
    def gather(self, f: Factor, states: list[np.ndarray]) -> list[Any]:
        """The argument values of a factor batch.

        Parameters
        ----------
        f : Factor
            One of the problem's factors.
        states : list of numpy.ndarray
            The parameters of each variable batch, in graph order.

        Returns
        -------
        list
            One batch of elements (or ``(m, d)`` array) per argument of ``f``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> states = [v.initial for v in p.variables]
        >>> [a.batch_shape for a in p.gather(p.factors[1], states)]
        [(2,), (2,)]
        """
        # take: 4x faster than fancy indexing for rows this short (measured, NumPy 2.4)
        return [var.wrap(np.take(states[self.key(var)], idx, axis=0)) for var, idx in f.args]

    def whiten(self, f: Factor, r: np.ndarray) -> np.ndarray:
        """Whitened residuals ``e = L r`` with the factor's square-root information ``L``.

        Parameters
        ----------
        f : Factor
            The factor batch.
        r : numpy.ndarray
            ``(m, dim)`` residuals.

        Returns
        -------
        numpy.ndarray
            ``(m, dim)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> states = [v.initial for v in p.variables]
        >>> p.whiten(p.factors[0], np.ones((1, 3))).tolist()  # unit noise
        [[1.0, 1.0, 1.0]]
        """
        sc = f.noise.scales
        if sc is not None:  # diagonal noise: a scale
            return r * sc
        L = f.noise.sqrt_info
        if L.ndim == 2:
            return r @ L.T
        return np.einsum("mij,mj->mi", L, r)

    def costs(self, states: list[np.ndarray], keep: bool = False) -> tuple[float, float]:
        """The plain cost ``0.5 sum |e|^2`` and the robust cost ``0.5 sum rho(|e|^2)``.

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in graph order.
        keep : bool
            Also evaluate the whitened Jacobians of the factors whose Jacobians come with
            their residuals (:attr:`Factor.jacobians_with_residuals`) and keep them for the
            next :meth:`linearize` of this same list (which must not be changed in between):
            what a solver does at a trial point it expects to accept.

        Returns
        -------
        cost, robust_cost : float

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> states = [v.initial for v in p.variables]
        >>> p.costs(states), p.costs(states, keep=True)
        ((1.0, 1.0), (1.0, 1.0))
        """
        c = rc = 0.0
        if keep:
            self._held = None
        for fi, (f, pl) in enumerate(zip(self.factors, self.plans, strict=True)):
            if pl is not None:
                s = pl.cost(states)
            elif keep and f.jacobians_with_residuals:
                s = self._whitened_system(fi, states)
            else:
                e = self.whiten(f, np.asarray(f.evaluate(self.gather(f, states), False)))
                s = np.einsum("mi,mi->m", e, e)
            c += 0.5 * float(s.sum())
            rc += 0.5 * float((f.loss.rho(s) if f.loss is not None else s).sum())
        if keep:
            self._held = states
        return c, rc

    def nonfinite(self, states: list[np.ndarray], jacobians: bool = False) -> str | None:
        """The first factor whose whitened residual (or, with ``jacobians``, Jacobian) is not
        finite at ``states``, described by its batch, type, row and arguments; ``None`` when
        every one is finite.

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in graph order.
        jacobians : bool
            Also check the Jacobians.

        Returns
        -------
        str or None

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import CustomFactor, FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(np.array([[4.0], [1.0]]), name="x")
        >>> _ = g.add(CustomFactor(lambda v: np.log(v - 2.0), [(x, [0, 1])], 1))
        >>> p = g.problem()
        >>> with np.errstate(invalid="ignore"):
        ...     p.nonfinite([v.initial for v in p.variables])
        'factor batch 0 (CustomFactor) row 1 on x[1]: whitened residual [nan]'
        """
        found = self._nonfinite(states, jacobians)
        return None if found is None else found[0]

    def _nonfinite(self, states: list[np.ndarray], jacobians: bool
                   ) -> tuple[str, int, int, list[tuple[Variables, int]]] | None:
        """:meth:`nonfinite` with the factor batch, row and arguments."""
        for fi, f in enumerate(self.factors):
            vals = self.gather(f, states)
            out = f.evaluate(vals, jacobians)
            r, Js = (out[0], out[1]) if jacobians else (out, [])
            e = self.whiten(f, np.asarray(r, dtype=np.float64))
            with np.errstate(over="ignore", invalid="ignore"):
                big = ~np.isfinite(np.einsum("mi,mi->m", e, e))
            bad = ~np.isfinite(e).all(axis=1) | big
            what = "whitened residual"
            if not bad.any():
                for J in Js:
                    bad |= ~np.isfinite(np.asarray(J)).reshape(f.count, -1).all(axis=1)
                what = "Jacobian"
            if not bad.any():
                continue
            k = int(np.flatnonzero(bad)[0])
            names = ", ".join(f"{var.name}[{int(idx[k])}]" for var, idx in f.args)
            unset = [f"{var.name}[{int(idx[k])}]" for var, idx in f.args
                     if not np.isfinite(states[self.key(var)][idx[k]]).all()]
            note = f" (the value of {', '.join(unset)} is not finite)" if unset else ""
            shown = "not finite" if what == "Jacobian" else (
                f"{e[k].tolist()}" + (" (its squared norm overflows)"
                                      if np.isfinite(e[k]).all() else ""))
            return (f"factor batch {fi} ({f.name}) row {k} on {names}: {what} {shown}{note}",
                    fi, k, [(var, int(idx[k])) for var, idx in f.args])
        return None

    def _whitened_system(self, fi: int, states: list[np.ndarray]) -> np.ndarray:
        """Fill factor ``fi``'s work arrays at ``states``: ``K = [J_1 ... J_K r]``
        ``(m, dim, D + 1)``, in one product ``A = L K = [A e]``, and ``s = |e|^2`` (returned),
        chunk by chunk (``A`` is still in cache for ``s``)."""
        f = self.factors[fi]
        K, A, _, s, _ = self._buffers(fi)
        D = K.shape[2] - 1
        K[:, :, D] = f.evaluate_into(self.gather(f, states), K[:, :, :D])
        sc = f.noise.scales
        L = f.noise.sqrt_info if sc is None else sc[..., :, None]
        per = L.ndim == 3 and L.shape[0] == f.count
        for a in range(0, f.count, _CHUNK):
            b = min(a + _CHUNK, f.count)
            La = L[a:b] if per else L
            if sc is None:
                np.matmul(La, K[a:b], out=A[a:b])
            else:  # diagonal noise: a scale of the rows
                np.multiply(K[a:b], La, out=A[a:b])
            e = A[a:b, :, D]
            np.einsum("mi,mi->m", e, e, out=s[a:b])
        return s

    def linearize(self, states: list[np.ndarray], out: Linearization | None = None
                  ) -> Linearization:
        """Linearise every factor at ``states`` and assemble ``H = J^T J`` and ``g = J^T e``
        (whitened, robust weights with Triggs' correction where it applies).

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in graph order.
        out : Linearization, optional
            A linearisation of this problem that is no longer needed: when every factor
            runs in the compiled edge loop its arrays are overwritten and reused (saves
            allocating and faulting in fresh memory); otherwise it is not used (the NumPy
            path's sum is a fresh array, its work arrays are the problem's own).

        Returns
        -------
        Linearization
            ``data`` (CSC values of ``H``), ``grad``, ``cost``, ``robust_cost`` and timings.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> states = [v.initial for v in p.variables]
        >>> lin = p.linearize(states)
        >>> lin.grad.shape, lin.cost
        ((9,), 1.0)
        """
        t0 = time.perf_counter()
        cost = rcost = 0.0
        t_lin = t_prod = t_fused = 0.0
        numpy_any = False
        held, self._held = self._held is states, None
        # the compiled products add straight into y; else every product is kept for bincount
        normal = compiled_module("_normal") if self._spans else None
        y: np.ndarray | None = None
        if normal is not None:
            y = np.zeros(self.nnz + self.size + 1)
        for fi, (f, pl) in enumerate(zip(self.factors, self.plans, strict=True)):
            if pl is not None:
                continue
            numpy_any = True
            ta = time.perf_counter()
            K, A, M, s, At = self._buffers(fi)
            D = K.shape[2] - 1
            if not (held and f.jacobians_with_residuals):  # else kept by costs(keep=True)
                s = self._whitened_system(fi, states)
            e = A[:, :, D]
            cost += 0.5 * float(s.sum())
            if f.loss is not None:
                rho, scale, aos = corrected_weights(f.loss, s)
                rcost += 0.5 * float(rho.sum())
                sq = np.sqrt(np.maximum(f.loss.evaluate(s)[1], 0.0))
                Aw = A[:, :, :D]  # Triggs' correction in place: sqrt(rho') (I - a e e^T) A
                eA = np.einsum("mi,mij->mj", e, Aw)
                Aw -= (aos[:, None] * e)[:, :, None] * eA[:, None, :]
                Aw *= sq[:, None, None]
                e *= scale[:, None]
            else:
                rcost += 0.5 * float(s.sum())
            tb = time.perf_counter()
            t_lin += tb - ta
            if y is not None and normal is not None:
                start, offs = self._spans[fi]
                normal.products(A, self._dest[start:start + f.count * (D + 1) ** 2], y)
                t_prod += time.perf_counter() - tb
                continue
            # A^T A and A^T e (and e^T e, unused), chunk by chunk with [A e]^T made contiguous
            # in a small cache-resident buffer: batched matmul on a transposed view is 3x
            # slower than on contiguous operands (measured, NumPy 2.4)
            for a in range(0, f.count, _CHUNK):
                b = min(a + _CHUNK, f.count)
                at = At[:b - a]
                np.copyto(at, np.swapaxes(A[a:b], 1, 2))
                np.matmul(at, A[a:b], out=M[a:b])
            t_prod += time.perf_counter() - tb
        tc = time.perf_counter()
        if numpy_any:  # every contribution summed into its place (one bincount)
            if y is None:
                y = np.bincount(self._dest, weights=self._contrib,
                                minlength=self.nnz + self.size + 1)
            data, grad = y[: self.nnz], y[self.nnz:-1]
        elif out is not None:
            data, grad = out.data, out.grad
            data.fill(0.0)
            grad.fill(0.0)
        else:
            data, grad = np.zeros(self.nnz), np.zeros(self.size)
        t_asm = time.perf_counter() - tc
        for f, pl in zip(self.factors, self.plans, strict=True):
            if pl is None:
                continue
            ta = time.perf_counter()
            # the compiled edge loop: evaluation, products and scatter (added into the pattern)
            wts = None
            if f.loss is not None:
                s = pl.cost(states)
                rho, scale, aos = corrected_weights(f.loss, s)
                sq = np.sqrt(np.maximum(f.loss.evaluate(s)[1], 0.0))
                wts = np.ascontiguousarray(np.stack([sq, scale, aos], axis=1))
            s = pl.normal(states, data, grad, wts)
            cost += 0.5 * float(s.sum())
            rcost += 0.5 * float((rho if f.loss is not None else s).sum())
            t_fused += time.perf_counter() - ta
        self.hold(data, grad)
        t_end = time.perf_counter()
        return Linearization(data, grad, cost, rcost,
                             {"linearize": t_lin, "products": t_prod, "compiled": t_fused,
                              "assemble": t_asm, "total": t_end - t0})

    def _buffers(self, fi: int) -> tuple[np.ndarray, ...]:
        """The work arrays of NumPy-path factor ``fi`` (allocated on first use, reused by every
        linearisation): ``K`` and ``A`` ``(m, dim, D + 1)``, its products
        ``(m, D + 1, D + 1)`` (a view of the contribution vector that ``S`` sums), ``s``
        ``(m,)``, and a chunk of ``[A e]^T`` ``(chunk, D + 1, dim)``."""
        if not self._work:
            self._contrib = np.empty(self._dest.size)
            for k, (start, offs) in self._spans.items():
                f = self.factors[k]
                m, d, D = f.count, f.dim, offs[-1]
                M = self._contrib[start:start + m * (D + 1) ** 2].reshape(m, D + 1, D + 1)
                self._work[k] = (np.empty((m, d, D + 1)), np.empty((m, d, D + 1)), M,
                                 np.empty(m), np.empty((min(m, _CHUNK), D + 1, d)))
        return self._work[fi]

    def retract(self, states: list[np.ndarray], dx: np.ndarray) -> list[np.ndarray]:
        """The states after a step ``dx`` on the free variables (``X Exp(dx_block)``; fixed
        variables unchanged).

        Parameters
        ----------
        states : list of numpy.ndarray
            The parameters of each variable batch, in graph order.
        dx : numpy.ndarray
            ``(size,)`` step in the problem's unknown order.

        Returns
        -------
        list of numpy.ndarray
            The new states.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(3))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
        >>> p = g.problem()
        >>> states = [v.initial for v in p.variables]
        >>> lin = p.linearize(states)
        >>> dx = np.linalg.solve(p.matrix(lin.data).toarray(), -lin.grad)
        >>> p.costs(p.retract(states, dx))[0] < 1e-20
        True
        """
        out = []
        for v, p, (free, idx) in zip(self.variables, states, self._steps, strict=False):
            if free is None:  # every variable free: no gather or scatter
                q = v.retract(p, dx[idx])
                out.append(q if q.flags.writeable else q.copy())
            elif free.size == 0:
                out.append(p)
            else:
                q = p.copy()
                q[free] = v.retract(p[free], dx[idx])
                out.append(q)
        return out


