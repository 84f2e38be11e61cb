"""Incremental smoothing: iSAM2's algorithm on a variable-level Bayes tree.

:class:`IncrementalSmoother` keeps the square-root information factor of the whole graph as a
Bayes tree with one variable per clique (an elimination tree): node ``j`` stores its conditional
``R_j x_j = c_j - T_j x_S`` on its separator ``S`` (variables eliminated after it) and the
information its whole subtree passes to ``S`` (the Schur complement ``(H_S, b_S)``). An update
(Kaess et al., "iSAM2: Incremental Smoothing and Mapping Using the Bayes Tree", IJRR 2012,
Algorithms 4-6):

1. new variables enter with zero step; every ``relinearize_skip``-th update the variables whose
   step ``|delta_j|_inf`` exceeds ``relinearize_threshold`` are relinearised (their linearisation
   point becomes ``x_j Exp(delta_j)``) and every factor touching them is linearised again;
2. the nodes that consumed a new, removed or relinearised factor and all their ancestors (the
   top of the tree) are detached; the subtrees hanging from them (orphans) keep their cached
   Schur complements;
3. the detached variables are ordered again (approximate minimum degree over them, the variables
   of the new factors constrained last) and eliminated again from their factors and the orphans'
   cached information;
4. the step is back-substituted from the re-eliminated nodes downwards, then into the orphan
   subtrees as GTSAM's wildfire does (partial back-substitution): a node is recomputed when a
   variable of its separator *changed* (re-eliminated, or recomputed and moved by
   ``wildfire`` or more); a recomputed node that moved less keeps its old step.

Why a Bayes tree and not an incremental supernodal Cholesky: re-factoring "the trailing part of
a fixed ordering" re-eliminates everything after the oldest touched variable (on a loop closure
to an early pose: nearly everything), while the tree re-eliminates only the path to the root
and reorders it, which keeps later updates local. The tree (:mod:`.bayes_tree`) stores one
conditional per variable, in flat arrays; a variable whose separator is its parent and the
parent's separator is *nested* in it (the two are one clique of GTSAM's tree): such a chain
is eliminated as one dense front (supernodal) and detached as a whole, so that only clique
roots cache a Schur complement. Detaching, re-eliminating and back-substituting run in C
(``microlie._c._incremental``) with a NumPy fallback.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ... import _fast
from ..core.factors import BetweenFactor, Factor
from ..core.graph import FactorGraph
from ..core.noise import SqrtInformation
from ..core.robust import corrected_weights
from ..core.solvers import Result
from ..core.variables import Values, Variables, VectorVariables, element
from ..linalg.ordering import minimum_degree_blocks
from .bayes_tree import BayesTree, NotDetermined
from .edges import EdgeRows

__all__ = ["IncrementalSmoother", "UpdateRecord"]

_EMPTY = np.zeros(0, dtype=np.int64)


class _Stream:
    """A factor batch whose rows arrive through :meth:`IncrementalSmoother.update_rows`: its
    ends, measurement parameters and square-root information as arrays, which rows were
    added, those not yet made factors of the graph (``pending``) and the factors made."""

    def __init__(self, factor: BetweenFactor, fast: bool) -> None:
        var = factor.args[0][0]
        self.factor = factor  # held: the smoother's maps are keyed by id(factor)
        self.var = var
        self.count = factor.count
        self.ii, self.jj = factor.args[0][1], factor.args[1][1]
        self.Z = np.ascontiguousarray(var.params_of(factor.Z), dtype=np.float64)
        self.L = np.broadcast_to(factor.noise.sqrt_info, (factor.count, var.dof, var.dof))
        self.added = np.zeros(factor.count, dtype=bool)
        self.pending: list[int] = []
        self.parts: list[Factor] = []
        self.fast = fast


@dataclass
class UpdateRecord:
    """What one :meth:`IncrementalSmoother.update` did.

    Attributes
    ----------
    factors_added : int
        Factor rows (residuals) added.
    factors_removed : int
        Factor rows removed.
    variables_added : int
        Variables (elements) that entered.
    relinearized : int
        Variables whose linearisation point moved.
    reeliminated : int
        Variables eliminated again (whole cliques).
    backsubstituted : int
        Variables whose step was recomputed.
    time_s : float
        Wall time of the update.
    times : dict
        Its parts in seconds: ``linearize``, ``detach``, ``order``, ``eliminate``, ``solve``.

    Examples
    --------
    >>> from microlie import SE2
    >>> from microlie.optim import IncrementalSmoother, PriorFactor, Diagonal
    >>> s = IncrementalSmoother()
    >>> x = s.add_variables(SE2.identity(2))
    >>> rec = s.update([PriorFactor(x, [0, 1], SE2.identity(), Diagonal([1, 1, 1]))])
    >>> rec.factors_added, rec.variables_added, rec.reeliminated, s.records[-1] is rec
    (2, 2, 2, True)
    """

    factors_added: int = 0
    factors_removed: int = 0
    variables_added: int = 0
    relinearized: int = 0
    reeliminated: int = 0
    backsubstituted: int = 0
    time_s: float = 0.0
    times: dict[str, float] = field(default_factory=dict)


class IncrementalSmoother:
    """An incremental nonlinear least-squares smoother (GTSAM's ISAM2): add variables and
    factors as they arrive, keep the estimate current at a cost that depends on what changed.

    Create a batch of variables with :meth:`add_variables`, with room for the whole run: an
    element enters at the first :meth:`update` whose factors or ``new_values`` name it (its
    initial value is the batch's, or the one given in ``new_values``). Every factor kind of
    :class:`FactorGraph` works (robust losses included); fixed variables (``fixed=``) are
    constants; variables with only some components held are refused. The cost, steps and
    covariances are those of :class:`FactorGraph` (right perturbation ``X Exp(delta)``,
    tangent translation first).

    Parameters
    ----------
    relinearize_threshold : float
        A variable is relinearised when its step's largest component (tangent units, radians
        and metres) exceeds this (GTSAM's ``relinearizeThreshold``, default 0.1).
    relinearize_skip : int
        Check for relinearisation at every ``relinearize_skip``-th update only (GTSAM's
        ``relinearizeSkip``, default 10; the first update checks).
    wildfire : float
        Partial back-substitution (GTSAM's ``wildfireThreshold``, default 0.001): below the
        re-eliminated nodes, a step is recomputed only where a separator variable changed, and
        kept only when it moved by this or more (0: every step below a change is recomputed).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import IncrementalSmoother, PriorFactor, BetweenFactor, Diagonal
    >>> s = IncrementalSmoother()
    >>> x = s.add_variables(SE2.identity(100))  # room for 100 poses; none has entered yet
    >>> sigma = Diagonal([0.1, 0.1, 0.1])
    >>> rec = s.update([PriorFactor(x, 0, SE2.identity(), sigma)])
    >>> step = SE2.exp([1.0, 0.0, 0.1])
    >>> for k in range(1, 4):  # each new pose predicted from the estimate, then its edge
    ...     guess = s.calculate_estimate(x, [k - 1]) @ step
    ...     rec = s.update([BetweenFactor(x, k - 1, k, step, sigma)], {(x, k): guess})
    >>> rec.variables_added, rec.factors_added, rec.reeliminated  # the root clique and x[3]
    (1, 1, 3)
    >>> (np.round(s.calculate_estimate(x, [3]).log(), 6) + 0.0).tolist()
    [[3.0, 0.0, 0.3]]
    """

    def __init__(self, relinearize_threshold: float = 0.1, relinearize_skip: int = 10,
                 wildfire: float = 0.001) -> None:
        if not (np.isfinite(relinearize_threshold) and relinearize_threshold >= 0):
            raise ValueError(f"relinearize_threshold must be a finite number >= 0, got "
                             f"{relinearize_threshold!r}")
        if int(relinearize_skip) != relinearize_skip or relinearize_skip < 1:
            raise ValueError(f"relinearize_skip must be a positive integer, got "
                             f"{relinearize_skip!r}")
        if not (np.isfinite(wildfire) and wildfire >= 0):
            raise ValueError(f"wildfire must be a finite number >= 0, got {wildfire!r}")
        self.relinearize_threshold = float(relinearize_threshold)
        self.relinearize_skip = int(relinearize_skip)
        self.wildfire = float(wildfire)
        self._graph = FactorGraph()
        #: One record per :meth:`update`.
        self.records: list[UpdateRecord] = []
        self._lin: list[np.ndarray] = []        # linearisation points per handle
        self._node_of: list[np.ndarray] = []    # node id per element (-1: fixed or pending)
        self._seen: list[np.ndarray] = []       # per handle: elements that have entered
        self._factors: list[Factor | None] = []
        self._rows: list[list[int]] = []        # row ids per factor batch
        self._row_fid: list[int] = []           # per row: its factor batch and row in it
        self._row_k: list[int] = []
        self._key: list[int] = []               # per node: handle key and element index
        self._idx: list[int] = []
        self._fids: dict[int, int] = {}         # id(factor) -> its index in self._factors
        self._streams: dict[int, _Stream] = {}  # id(factor) -> rows given by update_rows
        self._tree = BayesTree()
        self._edges = EdgeRows()
        self._c: Any = _fast.module("_online")  # the bookkeeping in C (None: NumPy below)
        self._rmark = np.zeros(64, dtype=np.int64)  # scratch per row: 0 between calls
        self._dxbuf = np.zeros(64)
        self._dx = self._dxbuf[:0]
        self._size = 0
        self._next_pos = 0
        self._updates = 0

    # ------------------------------------------------------------------ building
    def add_variables(self, values: Any, fixed: Any = None, name: str | None = None
                      ) -> Variables:
        """Add a batch of variables; an element enters the estimate at the first :meth:`update`
        whose factors or ``new_values`` name it.

        Parameters
        ----------
        values : LieGroup or array_like
            Initial values, as :meth:`FactorGraph.add_variables`.
        fixed : optional
            Variables held constant (indices, a mask or ``True``).
        name : str, optional
            A label for messages.

        Returns
        -------
        Variables
            The handle factors refer to.

        Examples
        --------
        >>> from microlie import SE3
        >>> from microlie.optim import IncrementalSmoother
        >>> IncrementalSmoother().add_variables(SE3.identity(2), name="x")
        Variables('x', SE3, n=2, fixed=0)
        """
        return self._graph.add_variables(values, fixed=fixed, name=name)

    # ------------------------------------------------------------------ update
    def update(self, new_factors: Iterable[Factor] = (),
               new_values: Mapping[Any, Any] | None = None,
               remove: Iterable[Factor] = ()) -> UpdateRecord:
        """Add factors (and the variables created since the last update), optionally remove
        factors, relinearise where needed and update the estimate.

        Parameters
        ----------
        new_factors : iterable of Factor
            Factor batches over this smoother's variables.
        new_values : mapping, optional
            Initial values of elements that have not entered yet (GTSAM's ``newTheta``), keyed
            by ``(handle, index)`` (``index`` an int or a tuple of ints; the value one element
            or a batch) or by a handle (all its elements). They replace the values given to
            :meth:`add_variables` and make the elements enter.
        remove : iterable of Factor
            Factor batches added earlier, removed now (:meth:`remove_factors`).

        Returns
        -------
        UpdateRecord
            Also appended to :attr:`records`. The estimate: :meth:`calculate_estimate`.

        Raises
        ------
        ValueError
            A factor of another graph or added twice, a value for a variable that has already
            entered, held components, or a variable the factors leave undetermined (no prior
            and no fixed variable anchors it).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import IncrementalSmoother, PriorFactor, Diagonal
        >>> s = IncrementalSmoother()
        >>> x = s.add_variables(SE2.identity(2))
        >>> rec = s.update([PriorFactor(x, [0, 1], SE2.exp([[1.0, 0, 0], [2.0, 0, 0]]),
        ...                             Diagonal([0.1, 0.1, 0.1]))])
        >>> np.round(s.calculate_estimate(x).translation()[:, 0], 9).tolist()
        [1.0, 2.0]
        """
        t0 = time.perf_counter()
        new_factors = list(new_factors)
        remove = list(remove)
        rec = UpdateRecord()
        for f in new_factors:
            if not isinstance(f, Factor):
                raise TypeError(f"new_factors: expected Factor objects, got {type(f).__name__}")
            if id(f) in self._fids or id(f) in self._streams:
                raise ValueError(f"new_factors: {f.name} was already added")
        self._sync()
        for f in new_factors:
            for var, _ in f.args:
                if var.graph is not self._graph:
                    raise ValueError(f"new_factors: {f.name} refers to {var!r} of another "
                                     f"graph")
        first = len(self._key)
        self._set_values(new_values)
        for f in new_factors:
            for var, idx in f.args:
                self._enter(var, idx)
        for f in new_factors:
            self._graph.add(f)
        ta = time.perf_counter()
        marked: list[np.ndarray] = []
        for f in remove:
            rec.factors_removed += self._remove(f, marked)
        new_rows: list[int] = []
        for f in new_factors:
            new_rows.extend(self._add_factor(f))
        return self._step(rec, t0, ta, first, new_rows, marked)

    def update_rows(self, factor: BetweenFactor, rows: Any,
                    new_values: Mapping[Any, Any] | None = None) -> UpdateRecord:
        """Add some rows (edges) of a :class:`~microlie.optim.BetweenFactor` batch built once
        for a stream of measurements (every edge of a file, say): the same as
        ``update([BetweenFactor(...)], new_values)`` with those rows' ends, measurements and
        noise, without building a factor per update (the rows go to the compiled edge kernel
        directly when it is built).

        Parameters
        ----------
        factor : BetweenFactor
            The batch over this smoother's variables; it is not added whole: each row enters
            when named here, once. The accumulated :attr:`graph` holds the rows added so far
            (as batches of them); ``remove_factors([factor])`` removes every row added.
        rows : int or array_like of int
            Indices into the batch (``0 <= row < factor.count``), none added before.
        new_values : mapping, optional
            As :meth:`update`.

        Returns
        -------
        UpdateRecord

        Raises
        ------
        ValueError
            Not a BetweenFactor of this smoother's graph, the factor already given to
            :meth:`update`, rows out of range or added before.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import IncrementalSmoother, BetweenFactor, PriorFactor, Diagonal
        >>> s = IncrementalSmoother()
        >>> x = s.add_variables(SE2.identity(3))
        >>> sig = Diagonal([0.1, 0.1, 0.1])
        >>> edges = BetweenFactor(x, [0, 1], [1, 2], SE2.exp([[1.0, 0, 0], [2.0, 0, 0]]), sig)
        >>> _ = s.update([PriorFactor(x, 0, SE2.identity(), sig)])
        >>> _ = s.update_rows(edges, 0, {(x, 1): SE2.exp([0.9, 0, 0])})
        >>> rec = s.update_rows(edges, [1], {(x, 2): SE2.exp([3.2, 0, 0])})
        >>> np.round(s.calculate_estimate(x).translation()[:, 0], 9).tolist()
        [0.0, 1.0, 3.0]
        >>> sum(f.count for f in s.graph.factors), rec.factors_added  # the prior and 2 edges
        (3, 1)
        """
        t0 = time.perf_counter()
        st = self._streams.get(id(factor))
        if st is None:
            st = self._stream(factor)
        ix, lst = self._stream_rows(st, rows, factor)
        var = st.var
        sel = slice(lst[0], lst[0] + 1) if len(lst) == 1 else ix
        ii, jj = st.ii[sel], st.jj[sel]
        iil, jjl = ii.tolist(), jj.tolist()
        fixed = var.fixed
        if not st.fast or any(fixed[a] or fixed[b] for a, b in zip(iil, jjl, strict=True)):
            # the general path: a factor of these rows
            part = BetweenFactor(var, ii, jj, element(var.group, st.Z[ix]),
                                 SqrtInformation(st.L[ix]), factor.loss)
            rec = self.update([part], new_values)
            st.added[ix] = True
            st.parts.append(part)
            return rec
        rec = UpdateRecord()
        self._sync()
        first = len(self._key)
        self._set_values(new_values)
        self._enter(var, ii)
        self._enter(var, jj)
        st.added[ix] = True
        ta = time.perf_counter()
        nodes = self._node_of[var.key]
        tree = self._tree
        rows_out = [tree.add_row((nodes[a], nodes[b])) for a, b in zip(iil, jjl, strict=True)]
        self._row_fid.extend([-1] * len(lst))  # set when the rows become a factor (_flush)
        self._row_k.extend(lst)
        self._edges.add_raw(var, rows_out, ii, jj, st.Z[sel], st.L[sel])
        st.pending.extend(rows_out)
        return self._step(rec, t0, ta, first, rows_out, [])

    @staticmethod
    def _stream_rows(st: _Stream, rows: Any, factor: Any) -> tuple[np.ndarray, list[int]]:
        """``rows`` of ``st`` validated (in range, distinct, not added), as an int64 array and
        a list."""
        ix = np.asarray(rows)
        if ix.ndim > 1 or ix.size == 0 or ix.dtype.kind not in "iu":
            raise ValueError(f"rows: integer indices into the batch (0 .. {st.count - 1}) "
                             f"expected, got {rows!r}")
        lst = ix.reshape(-1).tolist()
        if min(lst) < 0 or max(lst) >= st.count:
            raise ValueError(f"rows: indices into the batch must be in 0 .. {st.count - 1}, "
                             f"got {rows!r}")
        if len(set(lst)) != len(lst):
            raise ValueError(f"rows: {rows!r} names a row twice")
        added = st.added
        for r in lst:
            if added[r]:
                raise ValueError(f"rows: row {r} of {factor.name} was already added")
        return np.asarray(lst, dtype=np.int64), lst

    def _stream(self, factor: Any) -> _Stream:
        if type(factor) is not BetweenFactor:
            raise ValueError(f"factor: update_rows takes a BetweenFactor, got "
                             f"{type(factor).__name__} (give other factors to update)")
        var = factor.args[0][0]
        if var.graph is not self._graph:
            raise ValueError(f"factor: {factor.name} refers to {var!r} of another graph")
        if id(factor) in self._fids:
            raise ValueError(f"factor: {factor.name} was given to update (whole) already")
        self._sync()
        st = _Stream(factor, self._edges.accepts(factor))
        self._streams[id(factor)] = st
        return st

    @property
    def graph(self) -> FactorGraph:
        """The accumulated graph: every variable and factor added (the rows given to
        :meth:`update_rows` as batches of them), none removed."""
        self._flush()
        return self._graph

    def _flush(self) -> None:
        """Make the rows of :meth:`update_rows` added since the last call factors (one batch
        per stream) of the graph and of the bookkeeping."""
        for st in self._streams.values():
            self._flush_one(st)

    def _flush_one(self, st: _Stream) -> None:
        if st.pending:
            rows = st.pending
            ks = np.asarray([self._row_k[r] for r in rows], dtype=np.int64)
            part = BetweenFactor(st.var, st.ii[ks], st.jj[ks], element(st.var.group, st.Z[ks]),
                                 SqrtInformation(st.L[ks]))
            fid = len(self._factors)
            self._factors.append(part)
            self._fids[id(part)] = fid
            self._rows.append(rows)
            for k, r in enumerate(rows):
                self._row_fid[r] = fid
                self._row_k[r] = k
            self._graph.add(part)
            st.parts.append(part)
            st.pending = []

    def _step(self, rec: UpdateRecord, t0: float, ta: float, first: int, new_rows: list[int],
              marked: list[np.ndarray]) -> UpdateRecord:
        """The rest of an update once the new rows are in the tree: relinearise, linearise,
        detach, order, eliminate, back-substitute; fill and keep ``rec``."""
        rec.variables_added = len(self._key) - first
        rec.factors_added = len(new_rows)
        times = rec.times
        relin: np.ndarray = _EMPTY
        if self._updates % self.relinearize_skip == 0 and self._size:
            relin = self._relinearize()
        rec.relinearized = int(relin.size)
        new = np.arange(first, len(self._key), dtype=np.int64)
        redo, touched = self._rows_of(new_rows, relin)
        marked.append(new)
        marked.append(touched)
        marked.append(relin)
        self._linearize(redo)
        # a row's nodes are its first node and that node's ancestors: marking them all
        # detaches what marking the first would
        tb = time.perf_counter()
        times["linearize"] = tb - ta
        top, orphans, pool = self._tree.detach(np.concatenate(marked))
        tc = time.perf_counter()
        times["detach"] = tc - tb
        order = self._order(top, pool, orphans, [new, touched] if not relin.size else
                            [new] + [self._tree.rnodes[r] for r in new_rows])
        td = time.perf_counter()
        times["order"] = td - tc
        self._eliminate(order, pool, orphans)
        te = time.perf_counter()
        times["eliminate"] = te - td
        rec.reeliminated = int(order.size)
        rec.backsubstituted = self._tree.backsubstitute(order, orphans, self._dx, self.wildfire)
        times["solve"] = time.perf_counter() - te
        self._updates += 1
        rec.time_s = time.perf_counter() - t0
        self.records.append(rec)
        return rec

    def remove_factors(self, factors: Iterable[Factor]) -> UpdateRecord:
        """Remove factor batches added earlier (outlier rejection after the fact) and update
        the estimate: ``update(remove=factors)``.

        Parameters
        ----------
        factors : iterable of Factor
            Batches given to :meth:`update` before.

        Returns
        -------
        UpdateRecord

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import IncrementalSmoother, PriorFactor, Diagonal
        >>> s = IncrementalSmoother()
        >>> x = s.add_variables(SE2.identity(1))
        >>> sig = Diagonal([0.1, 0.1, 0.1])
        >>> good = PriorFactor(x, 0, SE2.exp([1.0, 0, 0]), sig)
        >>> bad = PriorFactor(x, 0, SE2.exp([5.0, 0, 0]), sig)
        >>> _ = s.update([good, bad])
        >>> _ = s.remove_factors([bad])
        >>> round(float(s.calculate_estimate(x).translation()[0, 0]), 9)
        1.0
        """
        return self.update(remove=factors)

    # ------------------------------------------------------------------ results
    def calculate_estimate(self, variables: Variables | None = None, idx: Any = None) -> Any:
        """The current estimate ``x_j Exp(delta_j)`` (GTSAM's ``calculateEstimate``).

        Parameters
        ----------
        variables : Variables, optional
            One handle: its values only (a group batch or an array); ``None``: all.
        idx : optional
            Indices into ``variables`` (all if ``None``).

        Returns
        -------
        Values or LieGroup or numpy.ndarray
            Variables that have not entered yet have their initial values.

        Examples
        --------
        >>> from microlie import SE2
        >>> from microlie.optim import IncrementalSmoother
        >>> s = IncrementalSmoother()
        >>> x = s.add_variables(SE2.identity(2))
        >>> s.calculate_estimate()[x].batch_shape
        (2,)
        """
        if variables is None:
            vs = self._graph.variables
            return Values(vs, [self._params(v, np.arange(v.n)) for v in vs])
        self._check_handle(variables, "variables")
        one = self._one(variables, idx)
        if one is not None:
            return one
        ix = np.arange(variables.n) if idx is None else variables.indices(idx)
        return variables.wrap(self._params(variables, ix))

    def _one(self, var: Variables, idx: Any) -> Any:
        """The estimate of one element of a group batch (``idx`` an int or a list of one)
        through the single-element group operations, or ``None`` (the general path)."""
        if type(idx) is list and len(idx) == 1:
            idx = idx[0]
        if type(idx) is not int or isinstance(var, VectorVariables) or \
                var.key >= len(self._seen) or not -var.n <= idx < var.n:
            return None
        i = idx % var.n
        node = int(self._node_of[var.key][i])
        if node < 0:
            return None
        o = int(self._tree.off[node])
        e = element(var.group, self._lin[var.key][i]).plus(self._dx[o:o + var.dof])
        return element(var.group, np.asarray(e.params)[None])

    def calculate_best_estimate(self) -> Values:
        """The estimate with the complete step of the current factorisation, by a full
        back-substitution (GTSAM's ``calculateBestEstimate``): :meth:`calculate_estimate`
        without the wildfire's stale steps (each below the ``wildfire`` threshold, but they
        add up down the tree). The stored step is not changed (the relinearisation decisions
        stay those of the partial back-substitution, as in GTSAM).

        Returns
        -------
        Values
            Variables that have not entered yet have their initial values.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import IncrementalSmoother, PriorFactor, BetweenFactor, Diagonal
        >>> s = IncrementalSmoother(wildfire=0.5)  # a coarse partial back-substitution
        >>> x = s.add_variables(SE2.identity(3))
        >>> sig = Diagonal([0.1, 0.1, 0.1])
        >>> _ = s.update([PriorFactor(x, 0, SE2.identity(), sig),
        ...               BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0, 0]), sig)])
        >>> _ = s.update([PriorFactor(x, 2, SE2.exp([2.3, 0, 0]), sig)])
        >>> (np.round(s.calculate_estimate(x).translation()[:, 0], 6) + 0.0).tolist()  # stale
        [0.0, 1.15, 2.225]
        >>> np.round(s.calculate_best_estimate()[x].translation()[:, 0], 6).tolist()
        [0.075, 1.15, 2.225]
        """
        t = self._tree
        order = np.argsort(t.pos[:t.n], kind="stable").astype(np.int64)
        dx = self._dx.copy()
        t.backsubstitute(order, np.zeros(0, dtype=np.int64), dx, 0.0)
        vs = self._graph.variables
        return Values(vs, [self._params(v, np.arange(v.n), dx) for v in vs])

    def _params(self, var: Variables, ix: np.ndarray, dx: np.ndarray | None = None
                ) -> np.ndarray:
        if dx is None:
            dx = self._dx
        if var.key >= len(self._seen):
            return var.initial[ix].copy()
        nodes = self._node_of[var.key][ix]
        P = np.where(self._seen[var.key][ix][:, None], self._lin[var.key][ix], var.initial[ix])
        live = nodes >= 0
        if live.any():
            cols = (self._tree.off[nodes[live]][:, None] + np.arange(var.dof))
            P[live] = var.retract(P[live], dx[cols])
        return P

    def linearization_point(self) -> Values:
        """The linearisation points of the factorisation (GTSAM's ``getLinearizationPoint``;
        the estimate is ``x_j Exp(delta_j)`` from them); elements that have not entered have
        their initial values.

        Returns
        -------
        Values

        Examples
        --------
        >>> from microlie import SE2
        >>> from microlie.optim import IncrementalSmoother, PriorFactor, Diagonal
        >>> s = IncrementalSmoother(relinearize_skip=100)
        >>> x = s.add_variables(SE2.identity(1))
        >>> _ = s.update([PriorFactor(x, 0, SE2.exp([0.5, 0, 0]), Diagonal([1, 1, 1]))])
        >>> s.linearization_point()[x].log().tolist()  # the step is not applied yet
        [[0.0, 0.0, 0.0]]
        """
        self._sync()
        vs = self._graph.variables
        return Values(vs, [np.where(seen[:, None], lin, v.initial)
                           for v, lin, seen in zip(vs, self._lin, self._seen, strict=True)])

    def max_step(self) -> float:
        """The largest component of any variable's step from its linearisation point (what
        the relinearisation threshold is compared with; 0 with no variables).

        Returns
        -------
        float

        Examples
        --------
        >>> from microlie import SE2
        >>> from microlie.optim import IncrementalSmoother, PriorFactor, Diagonal
        >>> s = IncrementalSmoother()
        >>> x = s.add_variables(SE2.identity(1))
        >>> _ = s.update([PriorFactor(x, 0, SE2.exp([0.5, 0, 0]), Diagonal([1, 1, 1]))])
        >>> round(s.max_step(), 12)
        0.5
        """
        return float(np.max(np.abs(self._dx))) if self._dx.size else 0.0

    def marginal_covariance(self, variables: Variables, idx: int) -> np.ndarray:
        """The marginal covariance of one variable from the current factorisation (the
        Gauss-Newton information at the linearisation points, as GTSAM's
        ``marginalCovariance``), in the right-perturbation frame.

        Parameters
        ----------
        variables : Variables
            A handle of this smoother.
        idx : int
            The variable's index in the batch.

        Returns
        -------
        numpy.ndarray
            ``(dof, dof)``.

        Examples
        --------
        >>> from microlie import SE2
        >>> from microlie.optim import IncrementalSmoother, PriorFactor, Diagonal
        >>> s = IncrementalSmoother()
        >>> x = s.add_variables(SE2.identity(1))
        >>> _ = s.update([PriorFactor(x, 0, SE2.identity(), Diagonal([0.1, 0.2, 0.3]))])
        >>> s.marginal_covariance(x, 0).diagonal().round(9).tolist()
        [0.01, 0.04, 0.09]
        """
        self._check_handle(variables, "variables")
        i = int(variables.indices(idx)[0])
        if variables.key >= len(self._seen) or not self._seen[variables.key][i]:
            raise ValueError(f"variables: {variables.name}[{i}] has not entered yet (call "
                             f"update first)")
        j = int(self._node_of[variables.key][i])
        if j < 0:
            raise ValueError(f"variables: {variables.name}[{i}] is fixed: it has no marginal "
                             f"covariance")
        t = self._tree
        path = [j]
        while t.parent[path[-1]] >= 0:
            path.append(int(t.parent[path[-1]]))
        d = int(t.dof[j])
        # forward: R^T y = e_j over the path (pos order), then back: R x = y
        y: dict[int, np.ndarray] = {}
        acc: dict[int, np.ndarray] = {j: np.eye(d)}
        for k in path:
            rhs = acc.pop(k, None)  # R_k^T y_k = rhs, R_k^-T = Rinv_k^T
            yk = t.Rinv[k].T @ rhs if rhs is not None else np.zeros((int(t.dof[k]), d))
            y[k] = yk
            o = 0
            for s in t.sep[k].tolist():
                ds = int(t.dof[s])
                contrib = -t.T[k][:, o:o + ds].T @ yk
                acc[s] = acc[s] + contrib if s in acc else contrib
                o += ds
        x: dict[int, np.ndarray] = {}
        for k in reversed(path):
            v = y[k].copy()
            o = 0
            for s in t.sep[k].tolist():
                ds = int(t.dof[s])
                v -= t.T[k][:, o:o + ds] @ x[s]
                o += ds
            x[k] = t.Rinv[k] @ v
        C = x[j]
        return 0.5 * (C + C.T)

    def optimize(self, **options: Any) -> Result:
        """Solve the accumulated graph in batch (:meth:`FactorGraph.optimize` from the current
        estimate, the same answer) and restart the factorisation at its solution.

        Parameters
        ----------
        **options
            Passed to :meth:`FactorGraph.optimize` (``solver``, ``max_iter``, ...).

        Returns
        -------
        Result

        Examples
        --------
        >>> from microlie import SE2
        >>> from microlie.optim import IncrementalSmoother, PriorFactor, Diagonal
        >>> s = IncrementalSmoother()
        >>> x = s.add_variables(SE2.identity(1))
        >>> _ = s.update([PriorFactor(x, 0, SE2.exp([1.0, 2.0, 3.0]), Diagonal([1, 1, 1]))])
        >>> s.optimize().final_cost < 1e-20
        True
        """
        self._sync()
        graph = self.graph  # with the rows of update_rows as factors
        saved = [v.fixed.copy() for v in graph.variables]
        try:  # elements that have not entered are not part of the accumulated graph
            for v, seen in zip(self._graph.variables, self._seen, strict=True):
                v.fixed = v.fixed | ~seen
            res = graph.optimize(self.calculate_estimate(), **options)
        finally:
            for v, fx in zip(self._graph.variables, saved, strict=True):
                v.fixed = fx
        for v in self._graph.variables:
            self._lin[v.key] = np.asarray(res.values.params(v), dtype=np.float64).copy()
        self._dx[:] = 0.0
        self._linearize({r for rs in self._rows for r in rs})
        top, orphans, pool = self._tree.detach(np.arange(len(self._key), dtype=np.int64))
        order = self._order(top, pool, orphans, [])
        self._eliminate(order, pool, orphans)
        self._tree.backsubstitute(order, orphans, self._dx, self.wildfire)
        return res

    # ------------------------------------------------------------------ internals
    def _check_handle(self, var: Any, what: str) -> None:
        if not isinstance(var, Variables) or var.graph is not self._graph:
            raise ValueError(f"{what}: expected a Variables handle of this smoother "
                             f"(IncrementalSmoother.add_variables), got {var!r}")

    def _sync(self) -> None:
        """Register the handles added to the graph since the last call."""
        for v in self._graph.variables[len(self._seen):]:
            self._lin.append(np.asarray(v.initial, dtype=np.float64).copy())
            self._node_of.append(np.full(v.n, -1, dtype=np.int64))
            self._seen.append(np.zeros(v.n, dtype=bool))

    def _set_values(self, new_values: Mapping[Any, Any] | None) -> None:
        if new_values is None:
            return
        if not isinstance(new_values, Mapping):
            raise ValueError("new_values: expected a mapping {Variables or (Variables, index): "
                             "values}")
        for what, val in new_values.items():
            var, idx = what if isinstance(what, tuple) else (what, None)
            self._check_handle(var, "new_values")
            row = var.initial.shape[1:]
            if type(idx) is int and -var.n <= idx < var.n:  # one element: no NumPy pass
                i = idx % var.n
                if self._seen[var.key][i]:
                    raise ValueError(f"new_values: {var.name}[{i}] has already entered; its "
                                     f"value is the estimate's")
                p = np.asarray(var.params_of(val), dtype=np.float64)
                if p.size != var.initial[i].size:
                    raise ValueError(f"new_values: {var.name} takes values of shape "
                                     f"{(1,) + row}, got {p.shape}")
                var.initial[i] = p.reshape(row)
                self._enter_one(var, i)
                continue
            ix = np.arange(var.n) if idx is None else var.indices(idx, "new_values index")
            if self._seen[var.key][ix].any():
                bad = int(ix[np.flatnonzero(self._seen[var.key][ix])[0]])
                raise ValueError(f"new_values: {var.name}[{bad}] has already entered; its "
                                 f"value is the estimate's")
            p = np.asarray(var.params_of(val), dtype=np.float64)
            shape = (ix.size,) + row
            if p.size % max(1, var.initial[0].size) or \
                    p.reshape((-1,) + row).shape != shape:
                raise ValueError(f"new_values: {var.name} takes values of shape {shape}, "
                                 f"got {p.shape}")
            var.initial[ix] = p.reshape(shape)
            self._enter(var, ix)

    def _enter(self, var: Variables, idx: np.ndarray) -> None:
        """Make elements ``idx`` of ``var`` enter (once): a node each unless fixed."""
        seen = self._seen[var.key]
        if idx.size <= 8:  # Python ints: cheaper than NumPy calls on a few elements
            fresh = sorted({i for i in idx.tolist() if not seen[i]})
            held = var.held
            for i in fresh:  # all checked before any enters
                if held[i].any() and not held[i].all():
                    self._enter_one(var, i)  # raises
            for i in fresh:
                self._enter_one(var, i, False)
            return
        new = np.unique(idx[~seen[idx]])
        if new.size == 0:
            return
        part = var.held[new].any(1) & ~var.held[new].all(1)
        if part.any():
            self._enter_one(var, int(new[np.flatnonzero(part)[0]]))  # raises
        for i in new.tolist():
            self._enter_one(var, i, False)

    def _enter_one(self, var: Variables, i: int, check: bool = True) -> None:
        """Make element ``i`` of ``var`` enter (not entered yet): a node unless fixed."""
        if check:
            h = var.held[i]
            if h.any() and not h.all():
                raise ValueError(f"{var.name}[{i}]: held components are not supported by "
                                 f"IncrementalSmoother; fix whole variables instead")
        self._seen[var.key][i] = True
        self._lin[var.key][i] = var.initial[i]
        if var.fixed[i]:
            return
        self._node_of[var.key][i] = len(self._key)
        self._key.append(var.key)
        self._idx.append(i)
        tree = self._tree
        j = tree.add_node(var.dof, self._size)
        tree.pos[j] = self._next_pos
        self._next_pos += 1
        self._size += var.dof
        if self._size > self._dx.size:  # the step: a view of a buffer grown by doubling
            if self._size > self._dxbuf.size:
                buf = np.zeros(max(self._size, 2 * self._dxbuf.size))
                buf[:self._dx.size] = self._dx
                self._dxbuf = buf
            self._dx = self._dxbuf[:self._size]

    def _add_factor(self, f: Factor) -> list[int]:
        fid = len(self._factors)
        self._factors.append(f)
        self._fids[id(f)] = fid
        nodes = [self._node_of[var.key][idx] for var, idx in f.args]
        rows = []
        tree = self._tree
        for k in range(f.count):
            nk = [int(n[k]) for n in nodes if n[k] >= 0]
            if len(set(nk)) != len(nk):
                raise ValueError(f"new_factors: {f.name} row {k} takes the same variable twice")
            rows.append(tree.add_row(nk))
            self._row_fid.append(fid)
            self._row_k.append(k)
        self._rows.append(rows)
        self._edges.add(f, np.asarray(rows, dtype=np.int64))
        return rows

    def _remove(self, f: Factor, marked: list[np.ndarray]) -> int:
        st = self._streams.pop(id(f), None)
        if st is not None:  # every row given by update_rows, now factors of their own
            self._flush_one(st)
            return sum(self._remove(part, marked) for part in st.parts)
        fid = self._fids.pop(id(f), None)
        if fid is None:
            raise ValueError(f"remove: {getattr(f, 'name', f)!r} is not a factor of this "
                             f"smoother")
        rows = self._rows[fid]
        for r in rows:
            marked.append(self._tree.rnodes[r])
            self._tree.remove_row(r)
        self._factors[fid] = None
        self._rows[fid] = []
        self._graph.remove(f)
        return len(rows)

    def _relinearize(self) -> np.ndarray:
        n = len(self._key)
        off = self._tree.off[:n]
        big = np.maximum.reduceat(np.abs(self._dx), off) if n else off
        nodes = np.flatnonzero(big > self.relinearize_threshold)
        if nodes.size == 0:
            return nodes
        nl = nodes.tolist()  # O(relinearised), not O(nodes)
        keys = np.array([self._key[q] for q in nl], dtype=np.int64)
        idx = np.array([self._idx[q] for q in nl], dtype=np.int64)
        for key in np.unique(keys).tolist():
            one = keys == key
            sel = nodes[one]
            var = self._graph.variables[key]
            ix = idx[one]
            cols = off[sel][:, None] + np.arange(var.dof)
            self._lin[key][ix] = var.retract(self._lin[key][ix], self._dx[cols])
            self._dx[cols] = 0.0
        return nodes

    def _rows_of(self, new_rows: list[int], relin: np.ndarray) -> tuple[list[int], np.ndarray]:
        """The rows to linearise: ``new_rows`` and every row of the nodes ``relin``, distinct
        (first-seen order), and the concatenation of their nodes."""
        tree = self._tree
        if self._c is not None:
            if len(tree.rnodes) > self._rmark.size:
                self._rmark = np.zeros(max(len(tree.rnodes), 2 * self._rmark.size),
                                       dtype=np.int64)
            rows, touched = self._c.rows_of(np.asarray(new_rows, dtype=np.int64), relin,
                                            tree.node_rows, tree.rnodes, self._rmark)
            return rows.tolist(), touched
        redo = dict.fromkeys(new_rows)
        for n in relin.tolist():
            redo.update(dict.fromkeys(tree.node_rows[n]))
        out = list(redo)
        rn = tree.rnodes
        return out, (np.concatenate([rn[r] for r in out]) if out else _EMPTY)

    def _linearize(self, rows: Iterable[int]) -> None:
        """Linearise ``rows`` (distinct) at the linearisation points: the pose-graph edges in
        one compiled call (:class:`EdgeRows`), the others one evaluation per factor batch."""
        tree = self._tree
        rest: Iterable[int] = rows
        if rows:
            rl = rows if type(rows) is list else list(rows)
            left = self._edges.linearize(rl, self._lin, tree.rH, tree.rb)
            if not left:
                return
            rest = [rl[q] for q in left]
        by: dict[int, list[int]] = {}
        fids = self._row_fid
        for r in rest:
            by.setdefault(fids[r], []).append(r)
        for fid, rs in by.items():
            f = self._factors[fid]
            assert f is not None
            vals = [var.wrap(np.take(self._lin[var.key], idx, axis=0)) for var, idx in f.args]
            r, J = f.evaluate(vals, True)
            sc = f.noise.scales
            if sc is not None:
                e = r * sc
                A = [j * sc[..., :, None] for j in J]
            else:
                L = f.noise.sqrt_info
                if L.ndim == 3:
                    L = np.broadcast_to(L, (f.count,) + L.shape[1:])
                    e = np.einsum("mij,mj->mi", L, r)
                else:
                    e = r @ L.T
                A = [np.matmul(L, j) for j in J]
            if f.loss is not None:
                s = np.einsum("mi,mi->m", e, e)
                _, scale, aos = corrected_weights(f.loss, s)
                sq = np.sqrt(np.maximum(f.loss.evaluate(s)[1], 0.0))
                A = [sq[:, None, None] * (a - (aos[:, None] * e)[:, :, None]
                                          * np.einsum("mi,mij->mj", e, a)[:, None, :])
                     for a in A]
                e = e * scale[:, None]
            if all(not var.fixed[idx].any() for var, idx in f.args):
                Aall = np.concatenate(A, axis=2) if len(A) > 1 else A[0]
                ks = np.asarray([self._row_k[q] for q in rs])
                Ak = Aall[ks]
                H = np.matmul(np.swapaxes(Ak, 1, 2), Ak)
                b = -np.einsum("mij,mi->mj", Ak, e[ks])
                for q, row in enumerate(rs):
                    tree.rH[row] = H[q]
                    tree.rb[row] = b[q]
                continue
            for row in rs:
                k = self._row_k[row]
                blocks = [A[a][k] for a, (var, idx) in enumerate(f.args)
                          if self._node_of[var.key][idx[k]] >= 0]
                Ak = np.concatenate(blocks, axis=1) if blocks else np.zeros((f.dim, 0))
                tree.rH[row] = Ak.T @ Ak
                tree.rb[row] = -(Ak.T @ e[k])

    def _order(self, top: np.ndarray, pool: np.ndarray, orphans: np.ndarray,
               last: list[np.ndarray]) -> np.ndarray:
        """Order ``top``: approximate minimum degree on the others, then the nodes of
        ``last`` (the new variables and those of the new factors, in arrival order); set the
        positions."""
        tree = self._tree
        pos = tree.pos
        n = int(top.size)
        start = self._next_pos
        self._next_pos += n
        if self._c is not None:
            order, nb = self._c.split_order(top, last, pos, tree.mark, start)
        else:
            flag = tree.mark  # scratch, 0 between calls
            for a in last:
                flag[a] = 1
            is_last = flag[top] == 1
            for a in last:
                flag[a] = 0
            tail = top[is_last]
            tail = tail[np.argsort(pos[tail], kind="stable")]
            head = top[~is_last]
            head = head[np.argsort(pos[head], kind="stable")]
            nb = head.size
            order = np.concatenate([head, tail]).astype(np.int64, copy=False)
            pos[order] = np.arange(start, start + n)
        if nb > 2:
            head = order[:nb]
            indptr, indices = tree.adjacency(pool, orphans, head)
            order[:nb] = head[np.asarray(minimum_degree_blocks(indptr, indices, nb),
                                         dtype=np.int64)]
            pos[order[:nb]] = np.arange(start, start + nb)
        return order

    def _eliminate(self, order: np.ndarray, pool: np.ndarray, orphans: np.ndarray) -> None:
        try:
            self._tree.eliminate(order, pool, orphans)
        except NotDetermined as e:
            var = self._graph.variables[self._key[e.node]]
            raise ValueError(f"{var.name}[{self._idx[e.node]}] is not determined by the factors "
                             f"(no prior or fixed variable anchors it, or a direction is "
                             f"unobserved): add a prior or fix a variable") from None
