"""Fixed-lag smoothing: a sliding window of variables, with what leaves the window
marginalised into a dense Gaussian prior; as Levenberg-Marquardt over the window
(:class:`BatchFixedLagSmoother`, GTSAM's ``BatchFixedLagSmoother``) or as iSAM2 updates of an
:class:`~microlie.optim.IncrementalSmoother` (:class:`IncrementalFixedLagSmoother`).

Marginalisation (both): the factors touching the leaving variables are linearised at the
current estimate, their Gauss-Newton system ``[H_mm H_ms; H_sm H_ss]``, ``[g_m; g_s]`` is
reduced by the Schur complement ``H = H_ss - H_sm H_mm^-1 H_ms``, ``g = g_s - H_sm H_mm^-1 g_m``
onto the separator (the window variables they touch), and replaced by one
:class:`MarginalPrior` ``r(x) = r0 + L (x (-) x0)`` with ``L^T L = H``, ``L^T r0 = g`` and the
linearisation point ``x0`` kept: the prior's Jacobian stays the first estimate's (FEJ), so it
never gains information it did not have when it was made.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from typing import Any

import numpy as np

from ...groups import LieGroup
from ..core.factors import Factor
from ..core.graph import FactorGraph
from ..core.problem import Problem
from ..core.solvers import Result
from ..core.variables import Variables
from .incremental import IncrementalSmoother

__all__ = ["BatchFixedLagSmoother", "IncrementalFixedLagSmoother", "MarginalPrior", "Binding"]

Key = Hashable
FactorFn = Callable[["Binding"], Factor]


class Binding:
    """Where each key of the window lives in the window's :class:`FactorGraph`: what a factor
    function receives to build its factor against the current window graph.

    ``binding[key]`` is the pair ``(handle, index)`` (the ``args`` pair of a :class:`Factor`,
    also ``PriorFactor(*binding[key], Z, noise)``); :meth:`var` and :meth:`idx` give its parts.

    Parameters
    ----------
    where : dict
        ``key -> (Variables, int)``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import FactorGraph
    >>> from microlie.optim.online.fixed_lag import Binding
    >>> g = FactorGraph()
    >>> v = g.add_variables(np.zeros((2, 3)))
    >>> b = Binding({"a": (v, 0), "b": (v, 1)})
    >>> b.var("b") is v, b.idx("b"), b["a"][1]
    (True, 1, 0)
    """

    def __init__(self, where: dict[Key, tuple[Variables, int]]) -> None:
        self._where = where

    def __getitem__(self, key: Key) -> tuple[Variables, int]:
        try:
            return self._where[key]
        except KeyError:
            raise ValueError(f"a factor refers to key {key!r}, which is not in the window "
                             f"(never added, or already marginalised): give its value in "
                             f"new_values, or drop the factor") from None

    def var(self, key: Key) -> Variables:
        """The handle holding ``key``.

        Parameters
        ----------
        key : hashable
            A key of the window.

        Returns
        -------
        Variables

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph
        >>> from microlie.optim.online.fixed_lag import Binding
        >>> v = FactorGraph().add_variables(np.zeros((1, 2)))
        >>> Binding({7: (v, 0)}).var(7) is v
        True
        """
        return self[key][0]

    def idx(self, key: Key) -> int:
        """The index of ``key`` in its handle.

        Parameters
        ----------
        key : hashable
            A key of the window.

        Returns
        -------
        int

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph
        >>> from microlie.optim.online.fixed_lag import Binding
        >>> v = FactorGraph().add_variables(np.zeros((2, 2)))
        >>> Binding({7: (v, 1)}).idx(7)
        1
        """
        return self[key][1]


class MarginalPrior(Factor):
    """The dense Gaussian prior left by marginalisation: ``r(x) = r0 + L (x (-) x0)`` on the
    separator variables, with ``x (-) x0 = Log(x0^-1 x)`` per variable (``x - x0`` for
    vectors) stacked in the order of ``args``; ``L`` and ``x0`` stay those of the first
    estimate (FEJ), only the chart Jacobian ``d(x (-) x0)/dx`` follows ``x``.

    Parameters
    ----------
    args : sequence of (Variables, int)
        The separator variables, one pair each.
    L : array_like
        ``(r, n)`` square-root information (``n`` the sum of their dofs).
    r0 : array_like
        ``(r,)`` residual at ``x0``.
    x0 : sequence of numpy.ndarray
        The parameters of each variable at linearisation.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import FactorGraph
    >>> from microlie.optim.online.fixed_lag import MarginalPrior
    >>> g = FactorGraph()
    >>> v = g.add_variables(np.array([[1.0, 2.0]]))
    >>> f = g.add(MarginalPrior([(v, 0)], 2 * np.eye(2), np.zeros(2), [np.zeros(2)]))
    >>> round(g.cost(), 9)  # 0.5 |2 (x - 0)|^2 = 0.5 * 4 * 5
    10.0
    """

    def __init__(self, args: Sequence[tuple[Variables, int]], L: Any, r0: Any,
                 x0: Sequence[np.ndarray]) -> None:
        L = np.asarray(L, dtype=np.float64)
        r0 = np.asarray(r0, dtype=np.float64)
        dofs = [var.dof for var, _ in args]
        if L.ndim != 2 or L.shape[1] != sum(dofs) or r0.shape != (L.shape[0],):
            raise ValueError(f"MarginalPrior: L must be (r, {sum(dofs)}) and r0 (r,), got "
                             f"{L.shape} and {r0.shape}")
        if len(x0) != len(args):
            raise ValueError(f"MarginalPrior: {len(x0)} linearisation points for "
                             f"{len(args)} variables")
        self.L, self.r0 = L, r0
        self.x0 = [np.asarray(p, dtype=np.float64).reshape(1, -1) for p in x0]
        self._cols = np.concatenate([[0], np.cumsum(dofs)]).astype(int)
        super().__init__([(var, int(i)) for var, i in args], L.shape[0])

    def residual(self, *values: Any, jac: bool = False) -> Any:
        """``r0 + L (x (-) x0)`` and, with ``jac``, its Jacobian blocks
        ``L_k J_r^-1(x_k (-) x0_k)`` (:meth:`Factor.residual`).

        Parameters
        ----------
        *values : LieGroup or numpy.ndarray
            One batch of one value per separator variable.
        jac : bool
            Also return the Jacobians.

        Returns
        -------
        numpy.ndarray or tuple
            ``(1, r)``, or ``(r, [J_1, ...])``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph
        >>> from microlie.optim.online.fixed_lag import MarginalPrior
        >>> v = FactorGraph().add_variables(np.zeros((1, 2)))
        >>> f = MarginalPrior([(v, 0)], np.eye(2), np.ones(2), [np.zeros(2)])
        >>> f.residual(np.array([[1.0, -1.0]])).tolist()
        [[2.0, 0.0]]
        """
        deltas, Js = [], []
        for (var, _), x, x0 in zip(self.args, values, self.x0, strict=True):
            out = var.minus(x, var.wrap(x0), jac=jac)
            deltas.append(out[0] if jac else out)
            if jac:
                Js.append(out[1])
        d = np.concatenate([np.asarray(t).reshape(-1, var.dof)
                            for t, (var, _) in zip(deltas, self.args, strict=True)], axis=1)
        r = self.r0[None] + d @ self.L.T
        if not jac:
            return r
        blocks = [self.L[None, :, self._cols[k]:self._cols[k + 1]] @ np.asarray(J)
                  for k, J in enumerate(Js)]
        return r, blocks


class _Record:
    """A factor function of the window, the keys it touches, and its prior (if it is one)."""

    __slots__ = ("fn", "keys", "prior", "factor")

    def __init__(self, fn: FactorFn, keys: tuple = (), prior: Any = None) -> None:
        self.fn, self.keys, self.prior = fn, keys, prior
        self.factor: Factor | None = None  # the incremental smoother's built factor


def _family(value: Any) -> tuple[Any, np.ndarray]:
    """``(family, params)`` of one value: its group class (vectors: their length)."""
    if isinstance(value, LieGroup):
        if value.batch_shape != ():
            raise ValueError(f"new_values: each value must be one element, got batch shape "
                             f"{value.batch_shape}")
        return type(value), np.array(value.params, dtype=np.float64)
    p = np.array(value, dtype=np.float64)
    if p.ndim != 1 or p.size < 1:
        raise ValueError(f"new_values: a vector value must be 1-D, got shape {p.shape}")
    return p.size, p


def _prior_fn(keys: tuple, L: np.ndarray, r0: np.ndarray, x0: list[np.ndarray]) -> FactorFn:
    """The factor function of a marginal prior."""

    def fn(b: Binding) -> Factor:
        return MarginalPrior([b[k] for k in keys], L, r0, x0)

    return fn


def _stacked(factors: list[Factor]) -> list[Factor]:
    """The factors with those of a class offering ``stack`` (``ImuFactor``, ...) merged into
    few batches: one evaluation for the window's factors of a kind, not one per factor."""
    out: list[Factor] = []
    by: dict[type, list[Factor]] = {}
    for f in factors:
        if len(factors) > 1 and callable(getattr(type(f), "stack", None)):
            by.setdefault(type(f), []).append(f)
        else:
            out.append(f)
    for cls, fs in by.items():
        out.extend(cls.stack(fs) if len(fs) > 1 else fs)  # type: ignore[attr-defined]
    return out


def _dense_system(variables: list[Variables], factors: list[Factor], states: list[np.ndarray],
                  items: list[tuple[Variables, int]]) -> tuple[np.ndarray, np.ndarray]:
    """The Gauss-Newton ``H = J^T J`` and gradient ``g = J^T r`` of ``factors`` at ``states``
    over the unknowns of ``items`` (in that order), dense."""
    prob = Problem(variables, _stacked(factors), "none")
    lin = prob.linearize(states)
    ix = np.concatenate([prob.node_off[prob.node_of[prob.key(h)][i]] + np.arange(h.dof)
                         for h, i in items]) if items else np.zeros(0, np.int64)
    H = prob.matrix(lin.data)[ix][:, ix].toarray()
    return H, np.asarray(lin.grad)[ix]


def _schur_prior(H: np.ndarray, g: np.ndarray, nm: int, what: Any
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """Marginalise the first ``nm`` unknowns of ``(H, g)``: ``(L, r0)`` with ``L^T L`` the
    Schur complement on the others and ``L^T r0`` its gradient (``None``: nothing left)."""
    try:
        C = np.linalg.cholesky(H[:nm, :nm])
    except np.linalg.LinAlgError:
        raise ValueError(f"marginalising {what}: their information is singular (a variable "
                         f"not determined by its factors)") from None
    if H.shape[0] == nm:
        return None
    A = np.linalg.solve(C, H[:nm, nm:])  # C^-1 H_ms
    b = np.linalg.solve(C, g[:nm])
    Hs = H[nm:, nm:] - A.T @ A
    gs = g[nm:] - A.T @ b
    Hs = 0.5 * (Hs + Hs.T)
    lam, U = np.linalg.eigh(Hs)
    keep = lam > 1e-12 * max(float(lam.max()), 0.0)
    if not keep.any():
        return None
    sq = np.sqrt(lam[keep])
    return sq[:, None] * U[:, keep].T, (U[:, keep].T @ gs) / sq


class _FixedLagSmoother:
    """What both fixed-lag smoothers share: the window rule (by time or by count), the keys'
    timestamps, the checks of new keys, and the public queries (each smoother gives
    ``_estimate``, ``_covariance``, ``_priors`` and ``_marginalize``)."""

    _records: list[_Record]  # the window's factor functions (each smoother sets it)

    def __init__(self, lag: float | None, window: int | None) -> None:
        name = type(self).__name__
        if (lag is None) == (window is None):
            raise ValueError(f"{name}: give exactly one of lag (seconds) and window (a count "
                             f"of timestamps)")
        if lag is not None and not (math.isfinite(lag) and lag >= 0):
            raise ValueError(f"{name}: lag must be finite and >= 0, got {lag!r}")
        if window is not None and (int(window) != window or window < 1):
            raise ValueError(f"{name}: window must be an integer >= 1, got {window!r}")
        self.lag = None if lag is None else float(lag)
        self.window = None if window is None else int(window)
        self.time = -math.inf
        self.marginalized: list[Key] = []
        self._stamp: dict[Key, float] = {}

    def _check_new(self, known: Any, fns: list, new_values: Mapping[Key, Any] | None,
                   timestamps: Mapping[Key, float] | None
                   ) -> tuple[dict[Key, tuple[Any, np.ndarray]], dict[Key, float]]:
        """Check the factor functions and the new keys; their ``(family, params)`` and times."""
        for fn in fns:
            if not callable(fn):
                raise TypeError(f"new_factors: expected functions binding -> Factor, got "
                                f"{type(fn).__name__}")
        new_values = dict(new_values or {})
        timestamps = dict(timestamps or {})
        added: dict[Key, tuple[Any, np.ndarray]] = {}
        for k, v in new_values.items():
            if k in known:
                raise ValueError(f"new_values: key {k!r} is already in the window")
            added[k] = _family(v)
        stamps: dict[Key, float] = {}
        for k in added:
            if k in timestamps:
                t = float(timestamps[k])
            elif self.lag is not None:
                raise ValueError(f"timestamps: key {k!r} has none (a window by time needs "
                                 f"one per new key)")
            else:
                t = float(max(self.time, 0.0) + 1.0) if self._stamp else 0.0
            if not math.isfinite(t):
                raise ValueError(f"timestamps: key {k!r} has a non-finite time {t!r}")
            stamps[k] = t
        extra = set(timestamps) - set(added)
        if extra:
            raise ValueError(f"timestamps: keys {sorted(map(repr, extra))} are not new values")
        return added, stamps

    def _removable(self, drop: list[FactorFn]) -> dict[int, int]:
        """``id(fn) -> index`` in ``_records`` of the window's factor functions (not its
        priors); raises when one of ``drop`` is not among them."""
        ids = {id(rec.fn): n for n, rec in enumerate(self._records) if rec.prior is None}
        missing = [fn for fn in drop if id(fn) not in ids]
        if missing:
            raise ValueError(f"remove: {len(missing)} factor function(s) are not in the window "
                             f"(never added, or marginalised with their variables)")
        return ids

    def _slide(self, stamps: dict[Key, float]) -> None:
        """Move the time to the newest of ``stamps`` and marginalise what left the window."""
        if stamps:
            self.time = max(self.time, max(stamps.values()))
        self.marginalized = self._leaving()
        if self.marginalized:
            self._marginalize(self.marginalized)

    def _leaving(self) -> list[Key]:
        if self.lag is not None:
            cut = self.time - self.lag
            return [k for k, t in self._stamp.items() if t < cut]
        times = sorted(set(self._stamp.values()))
        if len(times) <= (self.window or 0):
            return []
        cut = times[-(self.window or 0)]
        return [k for k, t in self._stamp.items() if t < cut]

    def timestamps(self) -> dict[Key, float]:
        """The timestamp of every key in the window.

        Returns
        -------
        dict

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import PriorFactor, Isotropic
        >>> from microlie.optim.online import BatchFixedLagSmoother
        >>> s = BatchFixedLagSmoother(lag=1.0)
        >>> _ = s.update([lambda b: PriorFactor(*b["p"], np.zeros(1), Isotropic(1, 1.0))],
        ...              {"p": np.zeros(1)}, {"p": 2.5})
        >>> s.timestamps()
        {'p': 2.5}
        """
        return dict(self._stamp)

    def calculate_estimate(self) -> dict[Key, Any]:
        """The current estimate of every key in the window.

        Returns
        -------
        dict
            ``key -> value`` (a group element, or a 1-D array).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import PriorFactor, Isotropic
        >>> from microlie.optim.online import BatchFixedLagSmoother
        >>> s = BatchFixedLagSmoother(lag=1.0)
        >>> _ = s.update([lambda b: PriorFactor(*b["p"], np.array([3.0]), Isotropic(1, 1.0))],
        ...              {"p": np.zeros(1)}, {"p": 0.0})
        >>> np.round(s.calculate_estimate()["p"], 6).tolist()
        [3.0]
        """
        return self._estimate()

    def marginal_covariance(self, key: Key) -> np.ndarray:
        """The covariance of ``key`` given everything fused so far (the window's factors and
        marginal priors): the Gauss-Newton information at the current estimate, in the
        right-perturbation frame (dense over the window for the incremental smoother).

        Parameters
        ----------
        key : hashable
            A key of the window.

        Returns
        -------
        numpy.ndarray
            ``(dof, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import PriorFactor, Isotropic
        >>> from microlie.optim.online import BatchFixedLagSmoother
        >>> s = BatchFixedLagSmoother(window=2)
        >>> _ = s.update([lambda b: PriorFactor(*b["p"], np.zeros(2), Isotropic(2, 0.5))],
        ...              {"p": np.zeros(2)}, {"p": 0.0})
        >>> s.marginal_covariance("p").tolist()
        [[0.25, 0.0], [0.0, 0.25]]
        """
        return self.joint_covariance([key])

    def joint_covariance(self, keys: Sequence[Key]) -> np.ndarray:
        """The joint covariance of several keys of the window (as :meth:`marginal_covariance`).

        Parameters
        ----------
        keys : sequence of hashable
            Keys of the window.

        Returns
        -------
        numpy.ndarray
            ``(sum dof, sum dof)`` in the order of ``keys``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import PriorFactor, Isotropic
        >>> from microlie.optim.online import BatchFixedLagSmoother
        >>> s = BatchFixedLagSmoother(window=2)
        >>> _ = s.update([lambda b: PriorFactor(b.var("p"), [b.idx("p"), b.idx("q")],
        ...                                     np.zeros((2, 1)), Isotropic(1, 1.0))],
        ...              {"p": np.zeros(1), "q": np.zeros(1)}, {"p": 0.0, "q": 0.0})
        >>> s.joint_covariance(["p", "q"]).tolist()
        [[1.0, 0.0], [0.0, 1.0]]
        """
        return self._covariance(keys)

    @property
    def priors(self) -> list[MarginalPrior]:
        """The marginal priors in the window (what marginalisation left), as built on the
        current window.

        Returns
        -------
        list of MarginalPrior

        Examples
        --------
        >>> from microlie.optim.online import BatchFixedLagSmoother
        >>> BatchFixedLagSmoother(window=1).priors
        []
        """
        return self._priors()

    def _estimate(self) -> dict[Key, Any]:
        raise NotImplementedError  # each smoother gives its own

    def _covariance(self, keys: Sequence[Key]) -> np.ndarray:
        raise NotImplementedError  # each smoother gives its own

    def _priors(self) -> list[MarginalPrior]:
        raise NotImplementedError  # each smoother gives its own

    def _marginalize(self, leaving: list[Key]) -> None:
        raise NotImplementedError  # each smoother gives its own


class BatchFixedLagSmoother(_FixedLagSmoother):
    """A fixed-lag smoother: Levenberg-Marquardt over the variables of a window, the older
    ones marginalised into a :class:`MarginalPrior` with first-estimate Jacobians.

    Named after GTSAM's ``BatchFixedLagSmoother`` (the same algorithm and the same
    ``update``/``calculate_estimate``/``marginal_covariance`` calls); the incremental one is
    ``IncrementalFixedLagSmoother``. Keys are any hashable; each holds one group element or one
    1-D vector. Factors are given as functions ``fn(binding) -> Factor`` (a :class:`Binding`
    maps keys to the window graph), because the window graph is rebuilt as the window slides.

    Parameters
    ----------
    lag : float, optional
        Window by time: after an update, the keys whose timestamp is older than the newest
        timestamp minus ``lag`` are marginalised (GTSAM's rule).
    window : int, optional
        Window by count: keep the keys of the ``window`` newest distinct timestamps. Exactly one
        of ``lag`` and ``window``.
    max_iter : int
        Levenberg-Marquardt iterations per update.
    **options
        Other keywords of :meth:`FactorGraph.optimize` (``solver``, ``linear_solver``,
        ``rel_tol``, ...). ``gauge`` defaults to ``"none"``: a window is usually anchored by
        its marginal prior, a factor over several keys that the graph's topological gauge
        check does not count as an anchor; an unanchored window shows as a singular system.

    Attributes
    ----------
    time : float
        The newest timestamp seen.
    marginalized : list
        The keys marginalised by the last update.

    Examples
    --------
    A random walk on the line, one position a second, a window of 2 s:

    >>> import numpy as np
    >>> from microlie.optim import BetweenFactor, PriorFactor, Isotropic
    >>> from microlie.optim.online import BatchFixedLagSmoother
    >>> s = BatchFixedLagSmoother(lag=2.0)
    >>> _ = s.update([lambda b: PriorFactor(*b[0], np.zeros(1), Isotropic(1, 1.0))],
    ...              {0: np.zeros(1)}, {0: 0.0})
    >>> for k in range(1, 6):
    ...     _ = s.update([lambda b, k=k: BetweenFactor(b.var(k - 1), b.idx(k - 1), b.idx(k),
    ...                                                np.ones(1), Isotropic(1, 1.0))],
    ...                  {k: np.zeros(1)}, {k: float(k)})
    >>> sorted(s.calculate_estimate()), s.marginalized
    ([3, 4, 5], [2])
    >>> est, var = s.calculate_estimate()[5], s.marginal_covariance(5)
    >>> round(float(est[0]), 6), round(float(var[0, 0]), 6)  # 5 steps, variance 1 + 5
    (5.0, 6.0)
    """

    def __init__(self, lag: float | None = None, window: int | None = None, *,
                 max_iter: int = 100, **options: Any) -> None:
        super().__init__(lag, window)
        self.max_iter = int(max_iter)
        self.options = {"gauge": "none", **options}
        self._values: dict[Key, tuple[Any, np.ndarray]] = {}
        self._records: list[_Record] = []
        self._graph: tuple | None = None

    # ------------------------------------------------------------------ window graph
    def _build(self) -> tuple[FactorGraph, dict, list[Factor]]:
        """The window graph: every key some factor touches (a key without factors, given
        before its factors or left alone by a removal, waits outside it), every factor."""
        if self._graph is not None:
            return self._graph
        if any(not rec.keys for rec in self._records):  # learn the keys of new factors
            self._graph = self._assemble(list(self._values))
        used = {k for rec in self._records for k in rec.keys}
        keys = [k for k in self._values if k in used]
        if self._graph is None or len(keys) != len(self._values):
            self._graph = self._assemble(keys)
        return self._graph

    def _assemble(self, keys: list[Key]) -> tuple[FactorGraph, dict, list[Factor]]:
        fams: dict[Any, list[Key]] = {}
        for k in keys:
            fams.setdefault(self._values[k][0], []).append(k)
        g = FactorGraph()
        where: dict[Key, tuple[Variables, int]] = {}
        for fam, ks in fams.items():
            P = np.stack([self._values[k][1] for k in ks])
            h = g.add_variables(P if isinstance(fam, int) else fam(P), name=str(ks[0]))
            for i, k in enumerate(ks):
                where[k] = (h, i)
        bind = Binding(where)
        owner = {(id(h), i): k for k, (h, i) in where.items()}
        factors = []
        for rec in self._records:
            f = rec.fn(bind)
            if not isinstance(f, Factor):
                raise TypeError(f"a factor function must return a Factor, got "
                                f"{type(f).__name__}")
            if not rec.keys:
                rec.keys = tuple(dict.fromkeys(owner[(id(v), int(i))] for v, ix in f.args
                                               for i in ix))
            factors.append(f)
        for f in _stacked(factors):
            g.add(f)
        return g, where, factors

    # ------------------------------------------------------------------ the public calls
    def update(self, new_factors: Iterable[FactorFn] = (),
               new_values: Mapping[Key, Any] | None = None,
               timestamps: Mapping[Key, float] | None = None,
               remove: Iterable[FactorFn] = ()) -> Result | None:
        """Add variables and factors (and remove factors), solve the window, marginalise what
        left it.

        Parameters
        ----------
        new_factors : iterable of callable
            Functions ``fn(binding) -> Factor`` (see :class:`Binding`); each may refer to any
            key of the window, new or old.
        new_values : mapping, optional
            ``key -> value`` of new variables: one group element, or a 1-D vector; the initial
            estimate.
        timestamps : mapping, optional
            ``key -> time`` (seconds) of the new keys; required for every new key with
            ``lag``; with ``window`` a missing one gets the update's number.
        remove : iterable of callable
            Factor functions given to an earlier update (the same objects) to take out, for
            example measurements found to be outliers. A key left without factors (or given
            before its factors) stays in the window, outside the solve, with its given value,
            and is dropped without marginalisation when it leaves (GTSAM issues #2478, #2479).

        Returns
        -------
        Result or None
            The engine's result on the window (before marginalisation); ``None`` when the
            window has no factor.

        Raises
        ------
        ValueError
            A key already in the window, a missing or non-finite timestamp, a factor referring
            to a key outside the window, a factor to remove that is not in the window; nothing
            is changed then.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import PriorFactor, Isotropic
        >>> from microlie.optim.online import BatchFixedLagSmoother
        >>> s = BatchFixedLagSmoother(window=3)
        >>> res = s.update([lambda b: PriorFactor(*b["x0"], SE2.exp([1.0, 0, 0]),
        ...                                       Isotropic(3, 0.1))],
        ...                {"x0": SE2.identity()}, {"x0": 0.0})
        >>> res.converged, np.round(s.calculate_estimate()["x0"].log(), 9).tolist()
        (True, [1.0, 0.0, 0.0])
        """
        fns = list(new_factors)
        added, stamps = self._check_new(self._values, fns, new_values, timestamps)
        drop = list(remove)
        ids = self._removable(drop)
        gone = {ids[id(fn)] for fn in drop}
        saved = (dict(self._values), dict(self._stamp), list(self._records), self._graph)
        res = None
        try:
            self._values.update(added)
            self._stamp.update(stamps)
            self._records = [r for n, r in enumerate(self._records) if n not in gone]
            self._records.extend(_Record(fn) for fn in fns)
            self._graph = None
            if self._records:
                g, where, _ = self._build()
                res = g.optimize(max_iter=self.max_iter, **self.options)
        except Exception:
            self._values, self._stamp, self._records, self._graph = saved
            raise
        if res is not None:
            self._store(g, where, res)
        self._slide(stamps)
        return res

    def _store(self, g: FactorGraph, where: dict, res: Result) -> None:
        for h in g.variables:
            P = np.asarray(res.values.params(h))
            for k, (hk, i) in where.items():
                if hk is h:
                    self._values[k] = (self._values[k][0], P[i].copy())
        g.set_values(res.values)

    def _marginalize(self, leaving: list[Key]) -> None:
        M = set(leaving)
        g, where, factors = self._build()
        touch = [n for n, rec in enumerate(self._records) if M.intersection(rec.keys)]
        sep = list(dict.fromkeys(k for n in touch for k in self._records[n].keys
                                 if k not in M))
        prior = None
        if touch:
            mk = [k for k in where if k in M]
            H, grad = _dense_system(g.variables, [factors[n] for n in touch],
                                    [v.initial for v in g.variables],
                                    [where[k] for k in mk + sep])
            nm = sum(where[k][0].dof for k in mk)
            out = _schur_prior(H, grad, nm, sorted(map(repr, M)))
            if out is not None:
                prior = (tuple(sep), out[0], out[1], [self._values[k][1].copy() for k in sep])
        for n in sorted(touch, reverse=True):
            del self._records[n]
        for k in M:
            del self._values[k], self._stamp[k]
        if prior is not None:
            self._records.append(_Record(_prior_fn(*prior), prior[0], prior))
        self._graph = None

    def _estimate(self) -> dict[Key, Any]:
        out: dict[Key, Any] = {}
        for k, (fam, p) in self._values.items():
            out[k] = p.copy() if isinstance(fam, int) else fam(p.copy())
        return out

    def _covariance(self, keys: Sequence[Key]) -> np.ndarray:
        missing = [k for k in keys if k not in self._values]
        if missing:
            raise ValueError(f"covariance: keys {missing!r} are not in the window")
        if not self._records:
            raise ValueError("covariance: the window has no factor")
        g, where, _ = self._build()
        free = [k for k in keys if k not in where]
        if free:
            raise ValueError(f"covariance: keys {free!r} have no factor (no information)")
        # the window's anchor may be a marginal prior over several keys, which the graph's
        # topological gauge check does not count as one: factorise without it
        prob = g.problem("none")
        ls = prob.analysed(self.options.get("linear_solver", "auto"))
        ls.factorize(prob.linearize([v.initial for v in g.variables]).data)
        idx = np.concatenate([prob.node_off[prob.node_of[prob.key(h)][i]] + np.arange(h.dof)
                              for h, i in (where[k] for k in keys)])
        E = np.zeros((prob.size, idx.size))
        E[idx, np.arange(idx.size)] = 1.0
        C = ls.solve(E)[idx]
        return 0.5 * (C + C.T)

    def _priors(self) -> list[MarginalPrior]:
        if not any(rec.prior is not None for rec in self._records):
            return []
        _, _, factors = self._build()
        return [f for f, rec in zip(factors, self._records, strict=True)
                if rec.prior is not None and isinstance(f, MarginalPrior)]


_SLOTS = 128  # the smallest variable batch of the incremental smoother (one per family)


class IncrementalFixedLagSmoother(_FixedLagSmoother):
    """A fixed-lag smoother on the incremental smoother: each update is one iSAM2 update of
    :class:`IncrementalSmoother` over the window, and what leaves the window is marginalised
    into a :class:`MarginalPrior` with first-estimate Jacobians, as in
    :class:`BatchFixedLagSmoother` (GTSAM's ``IncrementalFixedLagSmoother``).

    The same calls as :class:`BatchFixedLagSmoother` (``update``, ``calculate_estimate``,
    ``marginal_covariance``, ``joint_covariance``, ``priors``, ``timestamps``), the same keys,
    factor functions (``fn(binding) -> Factor``, called once per factor) and window rule.
    Marginalisation: after an update the factors touching the leaving keys are linearised at
    the current estimate and reduced by the Schur complement onto the keys they share with the
    window; the next update hands the smoother the prior and takes those factors out, and each
    leaving key keeps a unit prior at its last estimate, alone in its own component, so it no
    longer influences the window. The keys of one family (group, or vector length) live in one
    variable batch of the smoother, in the order they were added (as in the batch smoother's
    window graph: a factor may take several keys of a batch by index); when a batch is full
    (``max(128, 4 x`` the family's keys in the window ``)``), the smoother is rebuilt from the
    window (its factors at the current estimate) into fresh batches, which drops the left
    variables: memory stays bounded.

    Parameters
    ----------
    lag : float, optional
        Window by time (as :class:`BatchFixedLagSmoother`).
    window : int, optional
        Window by count of timestamps. Exactly one of ``lag`` and ``window``.
    relinearize_threshold : float
        :class:`IncrementalSmoother`'s (GTSAM's ``relinearizeThreshold``, 0.1).
    relinearize_skip : int
        :class:`IncrementalSmoother`'s (GTSAM's ``relinearizeSkip``, 10); 1 with a threshold of
        0 relinearises every variable at every update (Gauss-Newton over the window).
    wildfire : float
        :class:`IncrementalSmoother`'s partial back-substitution threshold (0.001).
    iterations : int
        Smoother updates per :meth:`update` (the extra ones without new factors, as GTSAM
        users call ``update()`` again); 1 is iSAM2's one Gauss-Newton step per measurement.

    Attributes
    ----------
    smoother : IncrementalSmoother
        The smoother of the window (replaced when the window is rebuilt).
    time : float
        The newest timestamp seen.
    marginalized : list
        The keys marginalised by the last update.

    Examples
    --------
    The random walk of :class:`BatchFixedLagSmoother`'s example:

    >>> import numpy as np
    >>> from microlie.optim import BetweenFactor, PriorFactor, Isotropic
    >>> from microlie.optim.online import IncrementalFixedLagSmoother
    >>> s = IncrementalFixedLagSmoother(lag=2.0)
    >>> _ = s.update([lambda b: PriorFactor(*b[0], np.zeros(1), Isotropic(1, 1.0))],
    ...              {0: np.zeros(1)}, {0: 0.0})
    >>> for k in range(1, 6):
    ...     _ = s.update([lambda b, k=k: BetweenFactor(b.var(k - 1), b.idx(k - 1), b.idx(k),
    ...                                                np.ones(1), Isotropic(1, 1.0))],
    ...                  {k: np.zeros(1)}, {k: float(k)})
    >>> sorted(s.calculate_estimate()), s.marginalized
    ([3, 4, 5], [2])
    >>> est, var = s.calculate_estimate()[5], s.marginal_covariance(5)
    >>> round(float(est[0]), 6), round(float(var[0, 0]), 6)  # 5 steps, variance 1 + 5
    (5.0, 6.0)
    """

    def __init__(self, lag: float | None = None, window: int | None = None, *,
                 relinearize_threshold: float = 0.1, relinearize_skip: int = 10,
                 wildfire: float = 0.001, iterations: int = 1) -> None:
        super().__init__(lag, window)
        if int(iterations) != iterations or iterations < 1:
            raise ValueError(f"IncrementalFixedLagSmoother: iterations must be an integer >= 1, "
                             f"got {iterations!r}")
        self.iterations = int(iterations)
        self._options: dict[str, Any] = {"relinearize_threshold": relinearize_threshold,
                         "relinearize_skip": relinearize_skip, "wildfire": wildfire}
        self._fam: dict[Key, Any] = {}            # key -> its family (group class or length)
        self._where: dict[Key, tuple[Variables, int]] = {}
        self._pending: dict[Key, np.ndarray] = {}  # keys not in the smoother yet: their value
        self._parked: dict[Key, Factor] = {}       # keys in the smoother without factors
        self._count: dict[Key, int] = {}           # factors (records) per key
        self._records: list[_Record] = []
        self._to_add: list[_Record] = []           # records the smoother has not got yet
        self._extra: list[Factor] = []             # unit priors of left keys, not given yet
        self._to_remove: list[Factor] = []         # factors of left keys, still in the smoother
        self._need: dict[Any, int] = {}            # new keys per family in this update
        self._reset()

    def _reset(self) -> None:
        self.smoother = IncrementalSmoother(**self._options)
        self._slots: dict[Any, tuple[Variables, int]] = {}  # family -> (batch, next free)

    def _room(self) -> bool:
        """Whether every family's batch has room for the new keys (``self._need``)."""
        return all(self._slots[fam][1] + n <= self._slots[fam][0].n
                   for fam, n in self._need.items() if fam in self._slots)

    def _slot(self, fam: Any) -> tuple[Variables, int]:
        if fam not in self._slots:  # room for 4 x the family's keys, new ones included
            live = sum(f == fam for f in self._fam.values()) + self._need.get(fam, 0)
            size = max(_SLOTS, 4 * live)
            h = self.smoother.add_variables(np.zeros((size, fam)) if isinstance(fam, int)
                                            else fam.identity(size))
            self._slots[fam] = (h, 0)
        h, n = self._slots[fam]
        self._slots[fam] = (h, n + 1)
        return h, n

    def _value(self, key: Key, p: np.ndarray) -> Any:
        fam = self._fam[key]
        return p.copy() if isinstance(fam, int) else fam(p.copy())

    def _params(self) -> dict[Key, np.ndarray]:
        """The current parameters of every key of the window."""
        vals = self.smoother.calculate_estimate()
        P: dict[int, np.ndarray] = {}
        out = {}
        for k, (h, i) in self._where.items():
            if k in self._pending:
                out[k] = self._pending[k]
            else:
                if id(h) not in P:
                    P[id(h)] = np.asarray(vals.params(h))
                out[k] = P[id(h)][i]
        return out

    def _park(self, key: Key, p: np.ndarray) -> None:
        """Hold ``key``, left without factors, by a unit prior at ``p`` (its own component)."""
        from ..core.factors import PriorFactor
        from ..core.noise import Isotropic

        h, i = self._where[key]
        f = PriorFactor(h, i, self._value(key, p), Isotropic(h.dof, 1.0))
        self._parked[key] = f
        self._extra.append(f)

    def _rebuild(self) -> None:
        """A new smoother holding only the window (its factors at the current estimate)."""
        est = self._params()
        self._reset()
        self._where = {k: self._slot(self._fam[k]) for k in self._where}
        self._pending = {k: est[k].copy() for k in self._where}
        self._parked = {}
        bind = Binding(self._where)
        for rec in self._records:
            rec.factor = rec.fn(bind)
        self._to_add = list(self._records)
        self._extra, self._to_remove = [], []

    def update(self, new_factors: Iterable[FactorFn] = (),
               new_values: Mapping[Key, Any] | None = None,
               timestamps: Mapping[Key, float] | None = None,
               remove: Iterable[FactorFn] = ()) -> Any:
        """Add variables and factors (and remove factors), update the estimate incrementally,
        marginalise what left the window.

        Parameters
        ----------
        new_factors : iterable of callable
            Functions ``fn(binding) -> Factor`` (see :class:`Binding`), called once.
        new_values : mapping, optional
            ``key -> value`` of new variables (one group element or a 1-D vector).
        timestamps : mapping, optional
            ``key -> time`` of the new keys (as :meth:`BatchFixedLagSmoother.update`).
        remove : iterable of callable
            Factor functions given to an earlier update, to take out. A key left without
            factors (or given before its factors) keeps its value outside the estimate and
            is dropped without marginalisation when it leaves (GTSAM issues #2478, #2479).

        Returns
        -------
        UpdateRecord
            The record of the smoother's (first) update.

        Raises
        ------
        ValueError
            As :meth:`BatchFixedLagSmoother.update` (nothing is changed then); from the
            smoother, a variable its factors leave undetermined (the smoother is then left
            as the error found it).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import PriorFactor, Isotropic
        >>> from microlie.optim.online import IncrementalFixedLagSmoother
        >>> s = IncrementalFixedLagSmoother(window=3)
        >>> rec = s.update([lambda b: PriorFactor(*b["x0"], SE2.exp([1.0, 0, 0]),
        ...                                       Isotropic(3, 0.1))],
        ...                {"x0": SE2.identity()}, {"x0": 0.0})
        >>> rec.variables_added, np.round(s.calculate_estimate()["x0"].log(), 9).tolist()
        (1, [1.0, 0.0, 0.0])
        """
        fns = list(new_factors)
        added, stamps = self._check_new(self._fam, fns, new_values, timestamps)
        drop = list(remove)
        ids = self._removable(drop)
        self._need = {}
        for fam, _ in added.values():
            self._need[fam] = self._need.get(fam, 0) + 1
        if not self._room():
            self._rebuild()
        saved = (dict(self._where), dict(self._slots))
        try:
            for k, (fam, _) in added.items():
                self._where[k] = self._slot(fam)
            bind = Binding(self._where)
            owner = {(id(h), i): k for k, (h, i) in self._where.items()}
            new: list[_Record] = []
            for fn in fns:
                f = fn(bind)
                if not isinstance(f, Factor):
                    raise TypeError(f"a factor function must return a Factor, got "
                                    f"{type(f).__name__}")
                try:
                    keys = tuple(dict.fromkeys(owner[(id(v), int(i))] for v, ix in f.args
                                               for i in ix))
                except KeyError:
                    raise ValueError("a factor refers to a variable that is not a key of the "
                                     "window: build factors from the binding") from None
                rec = _Record(fn, keys)
                rec.factor = f
                new.append(rec)
        except Exception:
            self._where, self._slots = saved
            raise
        old = self._params() if drop else {}
        for k, (fam, p) in added.items():
            self._fam[k] = fam
            self._pending[k] = p
            self._count[k] = 0
        self._stamp.update(stamps)
        removing, self._to_remove = self._to_remove, []
        gone = [self._records[ids[id(fn)]] for fn in drop]
        for rec in gone:
            self._records.remove(rec)
            if any(r is rec for r in self._to_add):
                self._to_add = [r for r in self._to_add if r is not rec]
            else:
                assert rec.factor is not None
                removing.append(rec.factor)
            for k in rec.keys:
                self._count[k] -= 1
        for rec in new:
            self._records.append(rec)
            for k in rec.keys:
                self._count[k] += 1
        adding = self._to_add + new
        self._to_add = []
        values: dict[Any, Any] = {}
        for rec in adding:
            for k in rec.keys:
                if k in self._pending:
                    values[self._where[k]] = self._value(k, self._pending.pop(k))
                elif k in self._parked:
                    removing.append(self._parked.pop(k))
        for rec in gone:
            for k in rec.keys:
                if self._count[k] == 0 and k in old and k not in self._pending \
                        and k not in self._parked:
                    self._park(k, old[k])
        factors = [f for f in (rec.factor for rec in adding) if f is not None] + self._extra
        self._extra = []
        record = self.smoother.update(factors, values, removing)
        for _ in range(self.iterations - 1):
            self.smoother.update()
        self._slide(stamps)
        return record

    def _marginalize(self, leaving: list[Key]) -> None:
        M = set(leaving)
        est = self._params()
        active = [k for k in leaving if k not in self._pending and k not in self._parked]
        touch = [rec for rec in self._records if M.intersection(rec.keys)]
        sep = list(dict.fromkeys(k for rec in touch for k in rec.keys if k not in M))
        prior = None
        if touch:
            g = self.smoother.graph
            vals = self.smoother.calculate_estimate()
            factors = [f for f in (rec.factor for rec in touch) if f is not None]
            H, grad = _dense_system(g.variables, factors,
                                    [np.asarray(vals.params(v)) for v in g.variables],
                                    [self._where[k] for k in active + sep])
            nm = sum(self._where[k][0].dof for k in active)
            out = _schur_prior(H, grad, nm, sorted(map(repr, M)))
            if out is not None:
                prior = (tuple(sep), out[0], out[1], [est[k].copy() for k in sep])
        for rec in touch:
            self._records.remove(rec)
            assert rec.factor is not None
            self._to_remove.append(rec.factor)
            for k in rec.keys:
                self._count[k] -= 1
        for k in active:
            self._park(k, est[k])
        for k in M:
            self._parked.pop(k, None)
            self._pending.pop(k, None)
            del self._where[k], self._fam[k], self._stamp[k], self._count[k]
        if prior is not None:
            rec = _Record(_prior_fn(*prior), prior[0], prior)
            rec.factor = rec.fn(Binding(self._where))
            self._records.append(rec)
            self._to_add.append(rec)
            for k in sep:
                self._count[k] += 1
        for k in sep:
            if self._count[k] == 0:
                self._park(k, est[k])

    def _estimate(self) -> dict[Key, Any]:
        return {k: self._value(k, p) for k, p in self._params().items()}

    def _covariance(self, keys: Sequence[Key]) -> np.ndarray:
        missing = [k for k in keys if k not in self._where]
        if missing:
            raise ValueError(f"covariance: keys {missing!r} are not in the window")
        free = [k for k in keys if k in self._pending or k in self._parked]
        if free:
            raise ValueError(f"covariance: keys {free!r} have no factor (no information)")
        live = [k for k in self._where if k not in self._pending and k not in self._parked]
        g = self.smoother.graph
        vals = self.smoother.calculate_estimate()
        H, _ = _dense_system(g.variables,
                             [f for f in (rec.factor for rec in self._records) if f is not None],
                             [np.asarray(vals.params(v)) for v in g.variables],
                             [self._where[k] for k in live])
        off = np.concatenate([[0], np.cumsum([self._where[k][0].dof for k in live])])
        pos = {k: n for n, k in enumerate(live)}
        idx = np.concatenate([np.arange(off[pos[k]], off[pos[k] + 1]) for k in keys])
        from scipy.linalg import cho_factor, cho_solve  # type: ignore[import-untyped]

        E = np.zeros((H.shape[0], idx.size))
        E[idx, np.arange(idx.size)] = 1.0
        try:
            C = cho_solve(cho_factor(H, lower=True), E)[idx]
        except np.linalg.LinAlgError:
            raise ValueError("covariance: the window's information is singular (a direction "
                             "no factor or prior determines)") from None
        return 0.5 * (C + C.T)

    def _priors(self) -> list[MarginalPrior]:
        return [rec.factor for rec in self._records
                if rec.prior is not None and isinstance(rec.factor, MarginalPrior)]
