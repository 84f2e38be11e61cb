"""The least-squares problem of a :class:`~microlie.optim.FactorGraph` on torch or JAX arrays:
its static structure (:class:`DeviceProblem`), its data ``theta`` (measurements and noise
arrays of every factor batch) and its variables ``x``, kept apart so that a solve is a pure
function of ``(theta, x0)``.

Layout. Every free variable gets ``dof`` columns, in the order of the NumPy engine's
:class:`~microlie.optim.core.problem.Problem` (so the gauge checks and the fixed and held
variables are the same); column ``size`` is a sink for fixed variables and held components
(their Jacobian columns are zeroed). Arrays carry one leading batch axis ``B`` (a problem
batch; ``B = 1`` for one problem): ``x[k]`` is ``(B, n_k, param_dim)``.

Linearisation. Each factor batch evaluates its whitened residuals ``e = L r`` ``(B, m, dim)``
and whitened right Jacobians ``A_k = L J_k`` ``(B, m, dim, dof_k)`` from the group kernels
(analytic Jacobians, the same formulas as the NumPy factors), on the backend's arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ...groups import SO3
from ..core.factors import BetweenFactor, Factor, PriorFactor
from ..core.landmarks import bundle_landmarks
from ..core.variables import VectorVariables
from .backend import Backend, make_backend

__all__ = ["DeviceProblem", "Theta", "Linear"]

#: Problems up to this many unknowns take dense Cholesky steps with ``linear="auto"``.
DENSE_MAX = 1500

#: ``theta``: one dict of arrays per factor batch, in graph order (a JAX pytree).
Theta = tuple


@dataclass
class _Block:
    """One variable batch: its group, shape and columns."""

    group: Any
    n: int
    dof: int
    vector: bool
    cols: np.ndarray        # (n, dof) column of each tangent coordinate (size: fixed or held)
    free: np.ndarray        # (n,) bool


@dataclass
class _Term:
    """One factor batch: how to evaluate it, its arguments and columns."""

    kind: str               # "prior", "between", "reprojection"
    keys: list[int]         # variable batch of each argument
    idx: list[Any]          # backend int indices of each argument (m,)
    idx_np: list[np.ndarray]
    cols: list[np.ndarray]  # (m, dof_k) columns of each argument
    flat: list[Any]         # backend (m * dof_k,) columns of each argument
    mask: list[Any]         # backend (m, 1, dof_k) 0/1: the columns that are unknowns
    dim: int
    m: int
    info: dict


@dataclass
class _Stack:
    """Factor batches evaluated as one (:meth:`DeviceProblem._stack_terms`)."""

    ids: list[int]          # the factor batches, in order
    kind: str               # how the stack evaluates
    keys: list[int]         # variable batch of each argument
    idx: list[Any]          # backend joined indices of each argument
    mask: list[Any]         # backend (M, 1, dof_k) 0/1 columns that are unknowns
    prior: Any              # backend (M, 1) 1.0 on prior rows (between from the identity)
    one: Any                # backend identity parameters (with prior rows)


class Linear(NamedTuple):
    """A linearisation: whitened residuals and Jacobian blocks per factor batch (a pytree).

    Attributes
    ----------
    e : list of arrays
        ``(B, m, dim)`` whitened residuals per factor batch.
    A : list of list of arrays
        ``(B, m, dim, dof_k)`` whitened Jacobians per batch and argument (zero columns for
        fixed variables and held components).
    cost : array
        ``(B,)``: ``0.5 * sum |e|^2``.
    """

    e: list
    A: list
    cost: Any


class DeviceProblem:
    """The static structure of a graph's least-squares problem on torch or JAX: the variable
    layout, which factor batch touches which variables, and how each evaluates.

    Build it with :meth:`from_graph`; :meth:`theta` and :meth:`initial` give the arrays a solve
    (:func:`~microlie.optim.device.solve`) takes. Supported factors: :class:`PriorFactor`,
    :class:`BetweenFactor` (any group, and vectors) and
    :class:`~microlie.optim.ReprojectionFactor` (``"bal"`` and ``"pinhole"`` models, SE3 or
    SO3 x R(3) world-to-camera poses, variable or constant intrinsics); no robust losses.

    Attributes
    ----------
    backend : Backend
        The library, dtype and device.
    size : int
        The number of unknowns (free tangent coordinates).
    blocks : list
        Per variable batch: group, count, dof, columns.
    terms : list
        Per factor batch: kind, arguments, columns.
    eliminate : list of int
        The variable batches a Schur step eliminates (landmarks,
        :func:`~microlie.optim.core.landmarks.bundle_landmarks`; empty when none): a bundle
        adjustment, which ``damping="auto"`` damps by ``diag(H)``.

    Examples
    --------
    >>> import jax.numpy as jnp  # float32: JAX's default, no jax_enable_x64 needed
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.from_params(jnp.array([[0.0, 0, 1, 0]] * 3, dtype=jnp.float32)))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.0])))
    >>> p = DeviceProblem.from_graph(g)
    >>> p.size, p.backend.name, [t.kind for t in p.terms]
    (9, 'jax', ['prior', 'between'])
    """

    def __init__(self, graph: Any, backend: Backend, gauge: str = "check") -> None:
        prob = graph.problem(gauge)
        self.graph = graph
        self.backend = be = backend
        self.size = N = int(prob.size)
        self.variables = list(prob.variables)
        self.factors = list(prob.factors)
        self.gauge_fixed = list(prob.gauge_fixed)
        held = np.zeros(N + 1, dtype=bool)
        held[prob.held] = True
        self.blocks: list[_Block] = []
        for v, nodes in zip(prob.variables, prob.node_of, strict=True):
            free = nodes >= 0
            cols = np.full((v.n, v.dof), N, dtype=np.int64)
            cols[free] = prob.node_off[nodes[free]][:, None] + np.arange(v.dof)
            cols[held[cols]] = N
            self.blocks.append(_Block(v.group, v.n, v.dof, isinstance(v, VectorVariables), cols,
                                      free))
        self._colmap = [be.index(b.cols) for b in self.blocks]
        self._any_free = [bool(b.free.any()) for b in self.blocks]
        self._sink = be.index(np.array([N]))
        self.terms = [self._term(prob, f) for f in prob.factors]
        self._stacks = self._stack_terms()
        self.rows = int(sum(t.m * t.dim for t in self.terms))
        self.eliminate = self._landmarks(prob)
        cm = np.ones(N)        # 1 on the columns a Schur step keeps (cameras), 0 on landmarks
        for k in self.eliminate:
            c = self.blocks[k].cols.reshape(-1)
            cm[c[c < N]] = 0.0
        self._keep_mask = be.asarray(cm)
        self._dense: Any = None
        self._schur_plan: Any = None   # schur.schur_plan, built on first use
        #: host-built plans of the step solvers (static index arrays), cached by name
        self.plans: dict = {}
        if N <= DENSE_MAX:
            self.dense_index()  # built here, not inside a traced solve

    # ------------------------------------------------------------------ building
    @classmethod
    def from_graph(cls, graph: Any, *, gauge: str = "check", backend: str | None = None,
                   dtype: str | None = None, device: Any = None) -> DeviceProblem:
        """The problem of ``graph``, on the backend of its variables (or the one named).

        Parameters
        ----------
        graph : FactorGraph
            Variables given as torch tensors or JAX arrays (any array with ``backend``).
        gauge : {"check", "fix_first", "none"}
            As :meth:`FactorGraph.optimize`.
        backend : {"torch", "jax"}, optional
            Default: the library of the variables (a ``ValueError`` when they mix torch and
            JAX, naming both).
        dtype : {"float64", "float32"}, optional
            Default: the variables' dtype.
        device : optional
            Default: the variables' device.

        Returns
        -------
        DeviceProblem

        Raises
        ------
        ValueError
            Mixed backends, a factor type or robust loss the device engine does not support
            (the message names it), float64 on JAX without ``jax_enable_x64``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.device import DeviceProblem
        >>> g = FactorGraph()
        >>> _ = g.add(PriorFactor(g.add_variables(SE2.identity(2)), [0, 1], SE2.identity()))
        >>> DeviceProblem.from_graph(g, backend="jax", dtype="float32").backend
        Backend('jax', 'float32', device=None)
        """
        if backend is None:
            be = make_backend([v.source if v.source is not None else v.initial
                               for v in graph.variables], dtype, device)
        else:
            be = Backend(backend, dtype or "float64", device)
        return cls(graph, be, gauge)

    def _term(self, prob: Any, f: Factor) -> _Term:
        be = self.backend
        if f.loss is not None:
            raise ValueError(f"{f.name}: the device engine does not apply robust losses yet "
                             f"(loss {type(f.loss).__name__}); use the NumPy engine")
        keys = [prob.key(v) for v, _ in f.args]
        cols = [self.blocks[k].cols[i] for k, (_, i) in zip(keys, f.args, strict=True)]
        info: dict = {}
        if type(f) is PriorFactor:
            kind = "prior"
        elif type(f) is BetweenFactor:
            kind = "between"
        elif type(f).__name__ == "ReprojectionFactor":
            kind = "reprojection"
            rf: Any = f
            model = getattr(rf.model, "name", "")
            if model not in ("bal", "pinhole") or getattr(rf.model, "distortion", False):
                raise ValueError(f"ReprojectionFactor: the device engine supports the 'bal' and "
                                 f"'pinhole' models, got {model!r}")
            if rf.camera_to_world:
                raise ValueError("ReprojectionFactor: the device engine supports "
                                 "world-to-camera poses (camera_to_world=False)")
            info = {"model": model, "pose": rf.pose_form, "behind": rf.behind,
                    "const_K": rf.intrinsics is not None}
        else:
            raise ValueError(f"{f.name}: the device engine evaluates PriorFactor, BetweenFactor "
                             f"and ReprojectionFactor; solve graphs with {f.name} with the "
                             f"NumPy engine (NumPy variables)")
        mask = [be.asarray((c != self.size).astype(np.float64)[:, None, :]) for c in cols]
        return _Term(kind, keys, [be.index(i) for _, i in f.args], [i for _, i in f.args], cols,
                     [be.index(c.reshape(-1)) for c in cols], mask, f.dim, f.count, info)

    def _stack_terms(self) -> list[_Stack]:
        """Factor batches evaluated together, in graph order: reprojections of one model and
        variable batches; priors and betweens of one variable batch, a prior being a between
        from the identity (``Log(Z^-1 X) = Log((I Z)^-1 X)``). One residual/Jacobian evaluation
        per stack: fewer, larger array operations (what a compiled graph pays for)."""
        groups: dict[tuple, list[int]] = {}
        for i, t in enumerate(self.terms):
            if t.kind == "reprojection":
                key: tuple = (t.kind, tuple(t.keys), t.dim, tuple(sorted(t.info.items())))
            else:
                ks = t.keys if t.kind == "between" else [t.keys[0], t.keys[0]]
                key = ("relative", tuple(ks), t.dim)
            groups.setdefault(key, []).append(i)
        be = self.backend
        out = []
        for ids in groups.values():
            ts = [self.terms[i] for i in ids]
            if len({t.kind for t in ts}) == 1:  # one kind: its own evaluation
                nargs = len(ts[0].keys)
                idx = [be.index(np.concatenate([t.idx_np[a] for t in ts])) for a in range(nargs)]
                cols = [np.concatenate([t.cols[a] for t in ts]) for a in range(nargs)]
                out.append(_Stack(ids, ts[0].kind, list(ts[0].keys), idx,
                                  [self._mask(c) for c in cols], None, None))
                continue
            k = ts[0].keys[-1]
            dof = self.blocks[k].dof
            first, cols0, prior = [], [], []
            for t in ts:   # a prior's first argument: the identity, no columns
                p = t.kind == "prior"
                first.append(np.zeros(t.m, np.int64) if p else t.idx_np[0])
                cols0.append(np.full((t.m, dof), self.size) if p else t.cols[0])
                prior.append(np.full(t.m, p))
            idx = [be.index(np.concatenate(first)),
                   be.index(np.concatenate([t.idx_np[-1] for t in ts]))]
            mask = [self._mask(np.concatenate(cols0)),
                    self._mask(np.concatenate([t.cols[-1] for t in ts]))]
            b = self.blocks[k]
            one = np.zeros(b.dof) if b.vector else np.asarray(b.group.identity().params)
            out.append(_Stack(ids, "between", [k, k], idx, mask,
                              be.asarray(np.concatenate(prior)[:, None].astype(np.float64)),
                              be.asarray(one.astype(np.float64))))
        return out

    def _mask(self, cols: np.ndarray) -> Any:
        """``(m, 1, dof)`` 0/1: the columns that are unknowns."""
        return self.backend.asarray((cols != self.size).astype(np.float64)[:, None, :])

    def _whitened(self, theta: Theta, x: list[Any], jac: bool) -> list[Any]:
        """Per factor batch ``e`` ``(B, m, dim)`` or, with ``jac``, ``(e, [A_k])``: each stack
        of batches (:meth:`_stack_terms`) evaluated once, then split."""
        be = self.backend
        out: list[Any] = [None] * len(self.terms)
        for st in self._stacks:
            ids = st.ids
            args = [be.take(x[k], i, axis=-2) for k, i in zip(st.keys, st.idx, strict=True)]
            if st.prior is not None:  # priors start from the identity
                args[0] = args[0] * (1.0 - st.prior) + st.one * st.prior
            th = theta[ids[0]] if len(ids) == 1 else \
                {k: _join(be, k, [theta[i][k] for i in ids]) for k in theta[ids[0]]}
            t = _Term(st.kind, st.keys, [], [], [], [], [], 0, 0, self.terms[ids[0]].info)
            res = self._evaluate(t, args, th, jac)
            r, Js = res if jac else (res, [])
            L = th["L"]
            e = _whiten(L, r)
            A = [(L @ J) * mk for J, mk in zip(Js, st.mask, strict=True)] if jac else None
            sizes = [self.terms[i].m for i in ids]
            es = _split(be, e, sizes) if len(ids) > 1 else [e]
            As = [_split(be, a, sizes) if len(ids) > 1 else [a] for a in A] \
                if A is not None else None
            for j, i in enumerate(ids):
                if As is None:
                    out[i] = es[j]
                    continue
                Ai = [a[j] for a in As]
                out[i] = (es[j], Ai[1:] if self.terms[i].kind == "prior" and
                          st.prior is not None else Ai)
        return out

    def _landmarks(self, prob: Any) -> list[int]:
        return [prob.key(v) for v in bundle_landmarks(prob)]

    # ------------------------------------------------------------------ arrays
    def theta(self) -> Theta:
        """The data of every factor batch as backend arrays (no batch axis): per batch a dict
        with ``"L"`` (``(m, dim, dim)`` square-root information) and ``"Z"`` (prior and
        between: ``(m, param_dim)`` measurement parameters) or ``"obs"`` (``(m, 2)`` pixels)
        and ``"K"`` (constant intrinsics ``(m, k)``).

        Returns
        -------
        tuple of dict
            A pytree; stack along a new leading axis for a problem batch
            (:func:`~microlie.optim.device.stack`).

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.device import DeviceProblem
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.from_params(jnp.array([[0.0, 0, 1, 0]], dtype=jnp.float32)))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> th = DeviceProblem.from_graph(g).theta()
        >>> sorted(th[0]), tuple(th[0]["L"].shape)
        (['L', 'Z'], (1, 3, 3))
        """
        be = self.backend
        out = []
        for t, f in zip(self.terms, self.factors, strict=True):
            L = np.broadcast_to(np.asarray(f.noise.sqrt_info, dtype=np.float64),
                                (t.m, t.dim, t.dim))
            d = {"L": be.asarray(np.ascontiguousarray(L))}
            if t.kind in ("prior", "between"):
                var = f.args[0][0]
                d["Z"] = be.asarray(np.asarray(var.params_of(f.Z), dtype=np.float64))
                src = getattr(f, "Z_source", None)  # the caller's tensors: gradients reach them
                if src is not None:
                    d["Z"] = be.asarray(src) + 0.0 * d["Z"]  # broadcast to (m, param_dim)
            else:
                d["obs"] = be.asarray(f.observations)
                if t.info["const_K"]:
                    d["K"] = be.asarray(f.intrinsics)
            out.append(d)
        return tuple(out)

    def initial(self, values: Any = None) -> list[Any]:
        """The starting parameters of every variable batch as backend arrays (no batch
        axis): ``values`` (a :class:`~microlie.optim.Values`) or the graph's initial values
        (the arrays given to ``add_variables``, converted to this backend, dtype and device).

        Parameters
        ----------
        values : Values, optional
            The starting point.

        Returns
        -------
        list of arrays
            ``(n_k, param_dim)`` each.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.device import DeviceProblem
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.from_params(jnp.array([[0.0, 0, 1, 0]], dtype=jnp.float32)))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> DeviceProblem.from_graph(g).initial()[0]
        Array([[0., 0., 1., 0.]], dtype=float32)
        """
        be = self.backend
        out = []
        for v in self.variables:
            if values is not None:
                p = values.params(v)
            else:
                p = v.source if v.source is not None else v.initial
            out.append(be.asarray(p))
        return out

    # ------------------------------------------------------------------ evaluation
    def _evaluate(self, t: _Term, args: list[Any], th: dict, jac: bool) -> Any:
        """Residuals ``(B, m, dim)`` and, with ``jac``, the Jacobians ``(B, m, dim, dof_k)``
        (unwhitened)."""
        if t.kind == "prior":
            return _prior(self.blocks[t.keys[0]], args[0], th["Z"], jac)
        if t.kind == "between":
            return _between(self.blocks[t.keys[0]], args[0], args[1], th["Z"], jac)
        return _reprojection(self.backend, t.info, args, th, jac)

    def residuals(self, theta: Theta, x: list[Any]) -> list[Any]:
        """Whitened residuals ``e = L r`` per factor batch.

        Parameters
        ----------
        theta : tuple of dict
            From :meth:`theta` (with the batch axis of ``x``).
        x : list of arrays
            ``(B, n_k, param_dim)`` parameters.

        Returns
        -------
        list of arrays
            ``(B, m, dim)`` each.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
        >>> from microlie.optim.device import DeviceProblem
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.from_params(jnp.array([[1.0, 0, 1, 0]], dtype=jnp.float32)))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Isotropic(3, 0.5)))
        >>> p = DeviceProblem.from_graph(g)
        >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
        >>> p.residuals(th, [a[None] for a in p.initial()])[0].tolist()
        [[[2.0, 0.0, 0.0]]]
        """
        return self._whitened(theta, x, False)

    def cost(self, theta: Theta, x: list[Any]) -> Any:
        """``0.5 * sum r^T Omega r`` per problem, ``(B,)``.

        Parameters
        ----------
        theta : tuple of dict
            From :meth:`theta` (with the batch axis of ``x``).
        x : list of arrays
            ``(B, n_k, param_dim)`` parameters.

        Returns
        -------
        array
            ``(B,)``.

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
        >>> from microlie.optim.device import DeviceProblem
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.from_params(jnp.array([[1.0, 0, 1, 0]], dtype=jnp.float32)))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity(), Isotropic(3, 0.5)))
        >>> p = DeviceProblem.from_graph(g)
        >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
        >>> p.cost(th, [a[None] for a in p.initial()]).tolist()  # 0.5 * (1 / 0.5)^2
        [2.0]
        """
        total = 0.0
        for e in self.residuals(theta, x):
            total = total + 0.5 * _sum2(e)
        return total

    def linearize(self, theta: Theta, x: list[Any]) -> Linear:
        """Whitened residuals and Jacobians of every factor batch at ``x``.

        Parameters
        ----------
        theta : tuple of dict
            From :meth:`theta` (with the batch axis of ``x``).
        x : list of arrays
            ``(B, n_k, param_dim)`` parameters.

        Returns
        -------
        Linear

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.device import DeviceProblem
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.from_params(jnp.array([[1.0, 0, 1, 0]], dtype=jnp.float32)))
        >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
        >>> p = DeviceProblem.from_graph(g)
        >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
        >>> lin = p.linearize(th, [a[None] for a in p.initial()])
        >>> lin.A[0][0].shape, lin.cost.tolist()
        ((1, 1, 3, 3), [0.5])
        """
        es, As = [], []
        cost = 0.0
        for e, A in self._whitened(theta, x, True):
            es.append(e)
            As.append(A)
            cost = cost + 0.5 * _sum2(e)
        return Linear(es, As, cost)

    def retract(self, x: list[Any], dx: Any) -> list[Any]:
        """``X Exp(dx)`` for every free variable (``x + dx`` for vectors); fixed variables and
        held components do not move.

        Parameters
        ----------
        x : list of arrays
            ``(B, n_k, param_dim)``.
        dx : array
            ``(B, size)`` step.

        Returns
        -------
        list of arrays

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.device import DeviceProblem
        >>> g = FactorGraph()
        >>> X = SE2.from_params(jnp.array([[0.0, 0, 1, 0]] * 2, dtype=jnp.float32))
        >>> x = g.add_variables(X, fixed=[0])
        >>> _ = g.add(PriorFactor(x, 1, SE2.identity()))
        >>> p = DeviceProblem.from_graph(g)
        >>> dx = jnp.array([[1.0, 2.0, 0.0]], dtype=jnp.float32)
        >>> x1 = p.retract([a[None] for a in p.initial()], dx)
        >>> x1[0][0].tolist()
        [[0.0, 0.0, 1.0, 0.0], [1.0, 2.0, 1.0, 0.0]]
        """
        be = self.backend
        ext = extend(be, dx)
        out = []
        for b, cm, p, free in zip(self.blocks, self._colmap, x, self._any_free, strict=True):
            if not free:
                out.append(p)
                continue
            d = be.take(ext, cm.reshape(-1), axis=-1).reshape(*ext.shape[:-1], b.n, b.dof)
            if b.vector:
                out.append(p + d)
            else:
                out.append(b.group.from_params(p, check=False).plus(d).params)
        return out

    def dense_index(self) -> Any:
        """The flat positions in the ``(size + 1)^2`` dense matrix of every factor's
        ``J^T J``, ``J = [A_1 ... A_k]`` its Jacobian blocks side by side (``(m, D, D)`` per
        factor batch, raveled, the factor batches one after the other; built once; fixed
        columns land in the extra last row and column).

        Returns
        -------
        index array

        Examples
        --------
        >>> import jax.numpy as jnp
        >>> from microlie.optim import FactorGraph, PriorFactor
        >>> from microlie.optim.device import DeviceProblem
        >>> g = FactorGraph()
        >>> x = g.add_variables(jnp.ones((1, 2), dtype=jnp.float32))
        >>> _ = g.add(PriorFactor(x, 0, [0.0, 0.0]))
        >>> DeviceProblem.from_graph(g).dense_index().tolist()  # (0,0), (0,1), ...
        [0, 1, 3, 4]
        """
        if self._dense is None:
            n1 = self.size + 1
            cols = [np.concatenate(t.cols, axis=1) for t in self.terms]
            self._dense = self.backend.index(np.concatenate(
                [(c[:, :, None] * n1 + c[:, None, :]).reshape(-1) for c in cols]))
        return self._dense

    # ------------------------------------------------------------------ products
    def jvp(self, lin: Linear, v: Any) -> list[Any]:
        """``J v`` per factor batch (whitened), ``(B, m, dim)`` each, for a step ``v``
        ``(B, size)``."""
        be = self.backend
        ext = extend(be, v)
        out = []
        for t, A in zip(self.terms, lin.A, strict=True):
            acc = 0.0
            for Ak, c in zip(A, t.flat, strict=True):
                vk = be.take(ext, c, axis=-1).reshape(*ext.shape[:-1], t.m, Ak.shape[-1])
                acc = acc + (Ak @ vk[..., None])[..., 0]
            out.append(acc)
        return out

    def vjp(self, lin: Linear, u: list[Any]) -> Any:
        """``J^T u`` ``(B, size)`` for per-batch ``u`` ``(B, m, dim)``."""
        be = self.backend
        B = u[0].shape[0] if u else 1
        out = be.zeros((B, self.size + 1), like=u[0] if u else None)
        for t, A, ut in zip(self.terms, lin.A, u, strict=True):
            for Ak, c in zip(A, t.flat, strict=True):
                w = (ut[..., None, :] @ Ak)[..., 0, :]          # (B, m, dof)
                out = add_last(be, out, c, w.reshape(B, -1))
        return out[..., :self.size]


# ---------------------------------------------------------------------- helpers
def _sum2(e: Any) -> Any:
    return (e * e).reshape(e.shape[0], -1).sum(-1)


def _whiten(L: Any, r: Any) -> Any:
    return (L @ r[..., None])[..., 0]


def _cat(be: Backend, xs: list[Any], axis: int) -> Any:
    return be.xp.concatenate(xs, axis=axis) if be.name == "jax" else be.xp.cat(xs, axis)


#: ``theta`` arrays' dimensions without a batch axis.
_BASE_NDIM = {"L": 3, "Z": 2, "obs": 2, "K": 2}


def _join(be: Backend, key: str, xs: list[Any]) -> Any:
    """``theta[key]`` arrays of stacked factor batches joined along the factor axis, each with
    the batch axis (shared arrays broadcast to the batch)."""
    xs = [a[None] if a.ndim == _BASE_NDIM[key] else a for a in xs]
    B = max(int(a.shape[0]) for a in xs)
    if be.name == "torch":
        xs = [a.expand(B, *a.shape[1:]) if a.shape[0] != B else a for a in xs]
    else:
        xs = [be.xp.broadcast_to(a, (B, *a.shape[1:])) if a.shape[0] != B else a for a in xs]
    return _cat(be, xs, 1)


def _split(be: Backend, a: Any, sizes: list[int]) -> list[Any]:
    """``a`` cut along axis 1 into pieces of ``sizes``."""
    if be.name == "torch":
        return list(a.split(sizes, 1))
    cuts = np.cumsum(sizes)[:-1].tolist()
    return list(be.xp.split(a, cuts, axis=1))


def extend(be: Backend, dx: Any) -> Any:
    """``dx`` with a zero column appended (the sink of fixed and held columns)."""
    z = be.zeros((*dx.shape[:-1], 1), like=dx)
    return be.xp.concatenate([dx, z], axis=-1) if be.name == "jax" else be.xp.cat([dx, z], -1)


def add_last(be: Backend, out: Any, idx: Any, src: Any) -> Any:
    """``out[:, idx] += src`` along the last axis, functionally."""
    if be.name == "torch":
        return out.index_add(out.ndim - 1, idx, src)
    return out.at[..., idx].add(src)


def transpose(be: Backend, A: Any) -> Any:
    """``A`` with its last two axes swapped."""
    return A.transpose(-1, -2) if be.name == "torch" else be.xp.swapaxes(A, -1, -2)


def eye_like(be: Backend, A: Any) -> Any:
    """The identity of the size of the last axis of ``A``, its dtype (and device)."""
    n = A.shape[-1]
    if be.name == "torch":
        return be.xp.eye(n, dtype=A.dtype, device=A.device)
    return be.xp.eye(n, dtype=A.dtype)


def _eye(like: Any, d: int, shape: tuple) -> Any:
    import sys

    if "torch" in type(like).__module__:
        t = sys.modules["torch"]
        return t.eye(d, dtype=like.dtype, device=like.device).expand(*shape, d, d)
    import jax.numpy as jnp

    return jnp.broadcast_to(jnp.eye(d, dtype=like.dtype), (*shape, d, d))


def _prior(b: _Block, X: Any, Z: Any, jac: bool) -> Any:
    if b.vector:
        r = X - Z
        return (r, [_eye(r, b.dof, r.shape[:-1])]) if jac else r
    g = b.group
    E = g.from_params(Z, check=False).inverse().compose(g.from_params(X, check=False))
    if not jac:
        return E.log()
    r, J = E.log(jac=True)
    return r, [J]


def _between(b: _Block, Xi: Any, Xj: Any, Z: Any, jac: bool) -> Any:
    if b.vector:
        r = Xj - Xi - Z
        if not jac:
            return r
        eye = _eye(r, b.dof, r.shape[:-1])
        return r, [-eye, eye]
    g = b.group
    Zg = g.from_params(Z, check=False)
    XiZ = g.from_params(Xi, check=False).compose(Zg)
    Yj = g.from_params(Xj, check=False)
    if not jac:
        return Yj.minus(XiZ)
    r, Jj, Jc = Yj.minus(XiZ, jac=True)
    return r, [Jc @ Zg.inverse().adjoint(), Jj]


def _skew_rows(R: Any, X: Any) -> Any:
    """``R [X]_x`` for ``(..., 3, 3)`` R and ``(..., 3)`` X: column j of ``R [X]_x`` is
    ``R (X x e_j)``... built from the columns of R: ``[X]_x`` columns are ``(0, X2, -X1)``,
    ``(-X2, 0, X0)``, ``(X1, -X0, 0)``."""
    x0, x1, x2 = X[..., 0:1], X[..., 1:2], X[..., 2:3]
    c0, c1, c2 = R[..., :, 0], R[..., :, 1], R[..., :, 2]
    col0 = c1 * x2 - c2 * x1
    col1 = c2 * x0 - c0 * x2
    col2 = c0 * x1 - c1 * x0
    return _stack([col0, col1, col2])


def _stack(xs: list[Any], axis: int = -1) -> Any:
    """``xs`` stacked along a new ``axis`` (torch or JAX, by the type of ``xs[0]``)."""
    import sys

    if "torch" in type(xs[0]).__module__:
        return sys.modules["torch"].stack(xs, axis)
    import jax.numpy as jnp

    return jnp.stack(xs, axis)


def _project(model: str, P: Any, K: Any, jac: bool) -> Any:
    """Pixels ``(..., 2)`` and, with ``jac``, ``d uv / d P`` ``(..., 2, 3)`` and
    ``d uv / d K`` ``(..., 2, k)`` (the formulas of :mod:`microlie.optim.sfm.camera`)."""
    if model == "bal":
        f, k1, k2 = K[..., 0], K[..., 1], K[..., 2]
        iz = -1.0 / P[..., 2]
        px, py = P[..., 0] * iz, P[..., 1] * iz
        r2 = px * px + py * py
        d = 1.0 + r2 * (k1 + k2 * r2)
        fd = f * d
        uv = _stack([fd * px, fd * py])
        if not jac:
            return uv
        g = 2.0 * f * (k1 + 2.0 * k2 * r2)
        a00, a01, a11 = fd + g * px * px, g * px * py, fd + g * py * py
        row0 = _stack([a00 * iz, a01 * iz, (a00 * px + a01 * py) * iz])
        row1 = _stack([a01 * iz, a11 * iz, (a01 * px + a11 * py) * iz])
        fr2 = f * r2
        k0 = _stack([d * px, fr2 * px, fr2 * r2 * px])
        k1r = _stack([d * py, fr2 * py, fr2 * r2 * py])
        return uv, _stack([row0, row1], -2), _stack([k0, k1r], -2)
    fx, fy, cx, cy = K[..., 0], K[..., 1], K[..., 2], K[..., 3]
    iz = 1.0 / P[..., 2]
    x, y = P[..., 0] * iz, P[..., 1] * iz
    uv = _stack([fx * x + cx, fy * y + cy])
    if not jac:
        return uv
    z0 = 0.0 * x
    row0 = _stack([fx * iz, z0, -fx * x * iz])
    row1 = _stack([z0, fy * iz, -fy * y * iz])
    one = z0 + 1.0
    k0 = _stack([x, z0, one, z0])
    k1r = _stack([z0, y, z0, one])
    return uv, _stack([row0, row1], -2), _stack([k0, k1r], -2)


def _reprojection(be: Backend, info: dict, args: list[Any], th: dict, jac: bool) -> Any:
    """``r = project(R X + t, K) - obs`` and its right Jacobians (pose, point, intrinsics)."""
    if info["pose"] == "SE3":
        p = args[0]
        R = SO3.from_params(p[..., 3:], check=False).matrix()
        t = p[..., :3]
        n = 1
    else:
        R = SO3.from_params(args[0], check=False).matrix()
        t = args[1]
        n = 2
    X = args[n]
    K = th["K"] if info["const_K"] else args[n + 1]
    P = (R @ X[..., None])[..., 0] + t
    out = _project(info["model"], P, K, jac)
    uv = out[0] if jac else out
    r = uv - th["obs"]
    keep = None
    if info["behind"] == "drop":
        front = P[..., 2] < 0.0 if info["model"] == "bal" else P[..., 2] > 0.0
        keep = be.where(front, 1.0, 0.0)[..., None]
        r = r * keep
    if not jac:
        return r
    _, A, JK = out
    AR = A @ R                                   # d r / d X, and d r / d rho (SE3)
    Aphi = -(A @ _skew_rows(R, X))               # d r / d phi
    if info["pose"] == "SE3":
        cat = be.xp.concatenate if be.name == "jax" else be.xp.cat
        Js = [cat([AR, Aphi], -1)]
    else:
        Js = [Aphi, A]
    Js.append(AR)
    if not info["const_K"]:
        Js.append(JK)
    if keep is not None:
        Js = [J * keep[..., None] for J in Js]
    return r, Js
