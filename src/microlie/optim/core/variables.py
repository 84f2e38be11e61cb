"""Variables of a factor graph: one batch of elements of one type per handle."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from ..._array import host_values, is_device_array
from ...groups import LieGroup, R, VectorSpace

__all__ = ["Variables", "VectorVariables", "Values", "element", "host_params",
           "new_variables"]


def element(group: type[LieGroup], params: Any) -> LieGroup:
    """Wrap trusted parameters without checks (``group.from_params(params, check=False)``; the
    only place in ``optim`` that builds elements that way).

    Parameters
    ----------
    group : type
        The :class:`~microlie.LieGroup` subclass.
    params : array_like
        ``(..., param_dim)`` valid parameters.

    Returns
    -------
    LieGroup

    Examples
    --------
    >>> from microlie import SO2
    >>> from microlie.optim.core.variables import element
    >>> element(SO2, [[1.0, 0.0]]).batch_shape
    (1,)
    """
    return group.from_params(params, check=False)


def new_variables(graph: Any, key: int, values: Any, name: str) -> Variables:
    """The handle of a new batch (what :meth:`FactorGraph.add_variables` calls): a
    :class:`VectorVariables` for an ``(n, d)`` array or an ``R(d)`` batch, a
    :class:`Variables` for any other group.

    Parameters
    ----------
    graph : FactorGraph
        The owner.
    key : int
        Position in the graph.
    values : LieGroup or array_like
        A 1-D batch of elements or an ``(n, d)`` array.
    name : str
        The label.

    Returns
    -------
    Variables

    Raises
    ------
    ValueError
        Not a 1-D batch or an ``(n, d)`` array, or non-finite vectors.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import R
    >>> from microlie.optim.core.variables import new_variables
    >>> a = new_variables(None, 0, np.zeros((2, 3)), "a")
    >>> b = new_variables(None, 1, R(3)(np.zeros((2, 3))), "b")
    >>> a.group is b.group is R(3), type(a).__name__
    (True, 'VectorVariables')
    """
    source = _device_params(values)  # torch / JAX parameters: the device engine's start
    if isinstance(values, LieGroup):
        if len(values.batch_shape) != 1:
            raise ValueError(f"{name}: variables must be a 1-D batch of elements (n,), got "
                             f"batch shape {values.batch_shape}")
        group: type[LieGroup] = type(values)
        p = np.array(host_params(values.params, group), dtype=np.float64)
    else:
        p = np.array(host_params(values), dtype=np.float64)
        if p.ndim != 2 or p.shape[1] < 1:
            raise ValueError(f"{name}: vector variables must be an (n, d) array with d >= 1, "
                             f"got shape {p.shape}")
        group = R(int(p.shape[1]))
    cls = VectorVariables if issubclass(group, VectorSpace) else Variables
    v = cls(graph, key, group, p, name)
    v.source = source
    return v


def _device_params(values: Any) -> Any:
    """The torch or JAX parameter array of ``values`` (``None`` for anything else)."""
    p = values.params if isinstance(values, LieGroup) else values
    return p if is_device_array(p) else None


def host_params(x: Any, group: Any = None) -> Any:
    """The NumPy-convertible values of parameters ``x`` (a torch tensor detached and on the
    host). Values unknown while a function is traced (a JAX tracer under ``jax.jit``/``grad``,
    a tensor under ``torch.compile``) are stood in for by the identity of ``group`` (zeros for
    vectors): the graph's NumPy copy then only carries its structure, and the solve runs on
    the traced arrays (:mod:`microlie.optim.device`).

    Parameters
    ----------
    x : array_like
        ``(..., param_dim)`` parameters.
    group : type, optional
        Their group (``None``: vectors).

    Returns
    -------
    array_like

    Examples
    --------
    >>> import torch
    >>> from microlie import SE2
    >>> host_params(torch.ones(1, 4, requires_grad=True), SE2).tolist()
    [[1.0, 1.0, 1.0, 1.0]]
    """
    if not is_device_array(x):
        return x
    v = host_values(x)
    if v is not None:
        return v
    one = np.zeros(x.shape[-1]) if group is None or issubclass(group, VectorSpace) else \
        np.asarray(group.identity().params, dtype=np.float64)
    return np.broadcast_to(one, tuple(x.shape))


class Variables:
    """A handle to one batch of ``n`` variables of one group in a :class:`FactorGraph`
    (returned by :meth:`FactorGraph.add_variables`; not built directly).

    ``group`` is a :class:`~microlie.LieGroup` subclass: ``R(d)`` for vectors (given as an
    ``(n, d)`` array or an ``R(d)`` batch; their handle is a :class:`VectorVariables`, whose
    values are plain ``(n, d)`` arrays). Variables are perturbed on the right
    (``X Exp(delta)``, ``x + delta`` for vectors), so every Jacobian and every marginal
    covariance is in the right-perturbation frame. The methods ``wrap``, ``params_of``,
    ``retract``, ``plus``, ``inverse``, ``compose``, ``log``, ``minus`` and ``gaussian`` work on
    this batch's values (group elements here, arrays for vectors).

    Parameters
    ----------
    graph : FactorGraph
        The owner.
    key : int
        Position in the graph.
    group : type
        The group.
    params : numpy.ndarray
        ``(n, param_dim)`` float64 initial parameters (this array is kept).
    name : str
        The label.

    Attributes
    ----------
    fixed : numpy.ndarray
        ``(n,)`` bool: variables held constant.
    held : numpy.ndarray
        ``(n, dof)`` bool: tangent components held at zero in every step
        (:meth:`fix` with ``components``).
    source : array or None
        The torch tensor or JAX array the variables were given as (their parameters), kept
        for the device engine (:mod:`microlie.optim.device`); ``None`` for NumPy input.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(4), name="x")
    >>> x.group.__name__, x.dof, len(x)
    ('SE2', 3, 4)
    """

    __slots__ = ("graph", "key", "group", "dof", "n", "initial", "fixed", "held", "name",
                 "source")

    def __init__(self, graph: Any, key: int, group: type[LieGroup], params: np.ndarray,
                 name: str) -> None:
        if not np.all(np.isfinite(params)):
            raise ValueError(f"{name}: initial values have non-finite entries")
        self.graph = graph
        self.key = key
        self.name = name
        self.group = group
        self.dof = int(group.dof)
        self.initial = params
        self.n = int(params.shape[0])
        self.fixed = np.zeros(self.n, dtype=bool)
        self.held = np.zeros((self.n, self.dof), dtype=bool)
        self.source: Any = None  # torch / JAX initial parameters (the device engine's start)

    def indices(self, idx: Any, what: str = "index") -> np.ndarray:
        """Validated integer indices into this batch.

        Parameters
        ----------
        idx : int, array_like or boolean mask
            The selection.
        what : str
            What the indices are, for the error message.

        Returns
        -------
        numpy.ndarray
            1-D int64 indices.

        Raises
        ------
        ValueError
            Non-integer, out-of-range indices or a mask of the wrong shape.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(4), name="x")
        >>> x.indices([True, False, True, False]).tolist(), x.indices(3).tolist()
        ([0, 2], [3])
        """
        if type(idx) is int or type(idx) is np.int64:  # one index: no NumPy reductions
            if 0 <= idx < self.n:
                return np.array((idx,), dtype=np.int64)
            raise ValueError(f"{self.name}: {what} {int(idx)} out of range (the batch has "
                             f"{self.n} variables)")
        a = np.asarray(idx)
        if a.dtype == bool:
            if a.shape != (self.n,):
                raise ValueError(f"{self.name}: boolean mask of shape {a.shape}, expected "
                                 f"({self.n},)")
            return np.flatnonzero(a)
        if a.size and not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"{self.name}: {what} must be integers, got {a.dtype}")
        a = a.astype(np.int64).reshape(-1) if a.ndim else a.astype(np.int64).reshape(1)
        # a few indices: Python's min and max cost less than NumPy's reductions
        v = a.tolist() if a.size <= 16 else None
        if a.size and ((min(v) < 0 or max(v) >= self.n) if v is not None
                       else (a.min() < 0 or a.max() >= self.n)):
            bad = a[(a < 0) | (a >= self.n)][0]
            raise ValueError(f"{self.name}: {what} {int(bad)} out of range (the batch has "
                             f"{self.n} variables)")
        return a

    def components(self, components: Any) -> np.ndarray:
        """Validated tangent coordinates of this group.

        Parameters
        ----------
        components : int or sequence of int
            Tangent coordinates, ``0 <= c < dof``, no duplicates (the group's tangent order,
            translation first: SE3 ``(rho, phi)``).

        Returns
        -------
        numpy.ndarray
            1-D int64.

        Raises
        ------
        ValueError
            Not integers, out of range or repeated (the message names ``components``).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph
        >>> k = FactorGraph().add_variables(np.zeros((2, 3)), name="K")
        >>> k.components([1, 2]).tolist()
        [1, 2]
        """
        a = np.asarray(components)
        if a.ndim > 1 or (a.size and not np.issubdtype(a.dtype, np.integer)) or a.dtype == bool:
            raise ValueError(f"{self.name}: components must be an int or a 1-D sequence of "
                             f"ints (tangent coordinates), got {components!r}")
        a = a.astype(np.int64).reshape(-1)
        bad = a[(a < 0) | (a >= self.dof)]
        if bad.size:
            raise ValueError(f"{self.name}: components: {int(bad[0])} out of range (a "
                             f"{self.group.__name__} variable has tangent coordinates 0 to "
                             f"{self.dof - 1})")
        u, c = np.unique(a, return_counts=True)
        if np.any(c > 1):
            raise ValueError(f"{self.name}: components: {int(u[c > 1][0])} given twice")
        return a

    def fix(self, idx: Any = None, components: Any = None) -> None:
        """Hold the variables ``idx`` constant, or only their tangent ``components``.

        With ``components``, those tangent coordinates of ``delta`` are zero in every step
        (``X Exp(delta)``; ``x + delta`` for vectors): for BAL intrinsics ``(f, k1, k2)``,
        ``components=[1, 2]`` holds ``k1, k2``; for an SE3 pose ``[3, 4, 5]`` holds its
        rotation. A variable with every component held is fixed. The marginal covariance of a
        held component is zero. A variable with only some components held does not anchor
        the gauge.

        Parameters
        ----------
        idx : optional
            Indices or a mask; all if ``None`` or ``True`` (``False`` frees all).
        components : int or sequence of int, optional
            Tangent coordinates to hold (see :meth:`components`); ``None``: the whole variables.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(4), name="x")
        >>> x.fix([0, 1])
        >>> x.fix(3, components=[2])  # the heading of x[3]
        >>> x.fixed.tolist(), x.held[3].tolist()
        ([True, True, False, False], [False, False, True])
        """
        if components is not None:
            rows = np.arange(self.n) if idx is None or idx is True else self.indices(idx)
            self.held[np.ix_(rows, self.components(components))] = True
        elif idx is None or idx is True:
            self.fixed[:] = True
        elif idx is False:
            self.fixed[:] = False
            self.held[:] = False
        else:
            self.fixed[self.indices(idx)] = True
        self._changed()

    def unfix(self, idx: Any = None, components: Any = None) -> None:
        """Let the variables ``idx`` vary again (all their components), or only their
        tangent ``components``.

        Parameters
        ----------
        idx : optional
            Indices or a mask; all if ``None``.
        components : int or sequence of int, optional
            Tangent coordinates to release; ``None``: the whole variables (every component).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(4), name="x")
        >>> x.fix()
        >>> x.unfix(0)
        >>> x.fixed.tolist()
        [False, True, True, True]
        """
        sel = np.arange(self.n) if idx is None else self.indices(idx)
        if components is not None:
            self.held[np.ix_(sel, self.components(components))] = False
        else:
            self.fixed[sel] = False
            self.held[sel] = False
        self._changed()

    def _changed(self) -> None:
        if self.graph is not None:
            self.graph._changed()

    @property
    def value_type(self) -> str:
        """What the values of this batch are, for messages: ``"a SE2"``, ``"an array"``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph
        >>> FactorGraph().add_variables(np.zeros((1, 2))).value_type
        'an array'
        """
        return f"a {self.group.__name__}"

    def wrap(self, params: Any) -> Any:
        """Parameters of this batch as the values that factors receive: group elements
        (:class:`VectorVariables`: the arrays themselves).

        Parameters
        ----------
        params : numpy.ndarray
            ``(k, params_dim)`` trusted parameters (not checked).

        Returns
        -------
        LieGroup or numpy.ndarray

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(4), name="x")
        >>> type(x.wrap(np.tile([0.0, 0, 1, 0], (2, 1)))).__name__
        'SE2'
        """
        return element(self.group, params)

    def params_of(self, value: Any) -> Any:
        """The parameter array of a value of this batch (the inverse of :meth:`wrap`).

        Parameters
        ----------
        value : LieGroup
            Elements of ``group`` (:class:`VectorVariables`: an array or an ``R(d)`` batch).

        Returns
        -------
        array
            ``value.params`` (any backend, dtype kept).

        Raises
        ------
        TypeError
            ``value`` is not of this batch's kind.

        Examples
        --------
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph
        >>> x = FactorGraph().add_variables(SE2.identity(4))
        >>> x.params_of(SE2.identity(2)).shape
        (2, 4)
        """
        if not isinstance(value, self.group):
            raise TypeError(f"{self.name}: expected a {self.group.__name__} batch, got "
                            f"{type(value).__name__}")
        return value.params

    def retract(self, params: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """The parameters of ``X Exp(delta)`` (``x + delta`` for vectors), NumPy in and out.

        Parameters
        ----------
        params : numpy.ndarray
            ``(k, params_dim)`` parameters.
        delta : numpy.ndarray
            ``(k, dof)`` tangent steps.

        Returns
        -------
        numpy.ndarray
            The new parameters.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(4), name="x")
        >>> x.retract(np.array([[0.0, 0, 1, 0]]), np.array([[1.0, 2.0, 0.0]])).tolist()
        [[1.0, 2.0, 1.0, 0.0]]
        """
        return np.asarray(element(self.group, params).plus(delta).params)

    def plus(self, params: Any, delta: Any) -> Any:
        """The value ``X Exp(delta)`` (``x + delta`` for vectors) of parameters of any array
        backend (NumPy, PyTorch, JAX: what automatic differentiation perturbs).

        Parameters
        ----------
        params : array
            ``(k, params_dim)`` parameters.
        delta : array
            ``(k, dof)`` tangent steps, the same backend.

        Returns
        -------
        LieGroup or array
            A value of this batch (see :meth:`wrap`).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO2
        >>> from microlie.optim import FactorGraph
        >>> x = FactorGraph().add_variables(SO2.identity(1))
        >>> np.round(x.plus(np.array([[1.0, 0.0]]), np.array([[0.5]])).log(), 12).tolist()
        [[0.5]]
        """
        return element(self.group, params).plus(delta)

    def inverse(self, X: Any) -> Any:
        """``X^-1`` of a value of this batch (``-x`` for vectors).

        Parameters
        ----------
        X : LieGroup or numpy.ndarray
            A value (see :meth:`wrap`).

        Returns
        -------
        LieGroup or numpy.ndarray

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO2
        >>> from microlie.optim import FactorGraph
        >>> x = FactorGraph().add_variables(SO2.identity(1))
        >>> np.round(x.inverse(SO2.exp([[0.5]])).log(), 12).tolist()
        [[-0.5]]
        """
        return X.inverse()

    def compose(self, X: Any, Y: Any) -> Any:
        """``X Y`` of two values of this batch (``x + y`` for vectors).

        Parameters
        ----------
        X, Y : LieGroup or numpy.ndarray
            Values (see :meth:`wrap`).

        Returns
        -------
        LieGroup or numpy.ndarray

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO2
        >>> from microlie.optim import FactorGraph
        >>> x = FactorGraph().add_variables(SO2.identity(1))
        >>> np.round(x.compose(SO2.exp([[0.5]]), SO2.exp([[0.25]])).log(), 12).tolist()
        [[0.75]]
        """
        return X.compose(Y)

    def log(self, X: Any, jac: bool = False) -> Any:
        """``Log(X)`` of a value of this batch and, with ``jac``, ``Jr^-1(Log X)`` (the
        identity for vectors).

        Parameters
        ----------
        X : LieGroup or numpy.ndarray
            A value (see :meth:`wrap`).
        jac : bool
            Also return the Jacobian.

        Returns
        -------
        numpy.ndarray or tuple
            ``(k, dof)``, or with ``jac`` ``(tau, J)``, ``J`` of shape ``(k, dof, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO2
        >>> from microlie.optim import FactorGraph
        >>> x = FactorGraph().add_variables(SO2.identity(1))
        >>> tau, J = x.log(SO2.exp([[0.5]]), jac=True)
        >>> np.round(tau, 12).tolist(), J.shape
        ([[0.5]], (1, 1, 1))
        """
        return X.log(jac=jac)

    def minus(self, Y: Any, X: Any, jac: bool = False) -> Any:
        """``Y (-) X = Log(X^-1 Y)`` of two values of this batch (``y - x`` for vectors)
        and, with ``jac``, its right Jacobians with respect to ``Y`` and ``X``.

        Parameters
        ----------
        Y, X : LieGroup or numpy.ndarray
            Values (see :meth:`wrap`).
        jac : bool
            Also return the Jacobians.

        Returns
        -------
        numpy.ndarray or tuple
            ``(k, dof)``, or with ``jac`` ``(tau, J_Y, J_X)`` (``I``, ``-I`` for vectors,
            read-only views).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie.optim import FactorGraph
        >>> x = FactorGraph().add_variables(np.zeros((1, 2)))
        >>> r, Jy, Jx = x.minus(np.array([[3.0, 1.0]]), np.array([[1.0, 1.0]]), jac=True)
        >>> r.tolist(), Jy[0].tolist(), Jx[0].tolist()
        ([[2.0, 0.0]], [[1.0, 0.0], [0.0, 1.0]], [[-1.0, -0.0], [-0.0, -1.0]])
        """
        return Y.minus(X, jac=jac)

    def gaussian(self, params: np.ndarray, cov: np.ndarray) -> Any:
        """The Gaussian of this batch with mean ``params`` and tangent covariances ``cov``: a
        :class:`~microlie.Gaussian` in the right frame (``X = mean Exp(eps)``), a
        :class:`~microlie.VectorGaussian` for vectors.

        Parameters
        ----------
        params : numpy.ndarray
            ``(k, params_dim)`` parameters of the means.
        cov : numpy.ndarray
            ``(k, dof, dof)`` covariances.

        Returns
        -------
        Gaussian or VectorGaussian

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO2
        >>> from microlie.optim import FactorGraph
        >>> x = FactorGraph().add_variables(SO2.identity(1))
        >>> x.gaussian(x.initial, np.ones((1, 1, 1))).frame
        'right'
        """
        from ...uncertainty import Gaussian

        return Gaussian(self.wrap(params), cov, frame="right")

    def __len__(self) -> int:
        return self.n

    def __repr__(self) -> str:
        held = int(self.held.any(axis=1).sum())
        part = f", held={held}" if held else ""
        return (f"Variables({self.name!r}, {self.group.__name__}, n={self.n}, "
                f"fixed={int(self.fixed.sum())}{part})")


class VectorVariables(Variables):
    """The handle of a batch of vector variables, group ``R(d)`` (from an ``(n, d)`` array
    or an ``R(d)`` batch): its values are plain ``(n, d)`` arrays (what factors receive and
    ``result.values[handle]`` gives), ``x + delta`` is a plain addition.

    Parameters
    ----------
    graph : FactorGraph
        The owner.
    key : int
        Position in the graph.
    group : type
        ``R(d)``.
    params : numpy.ndarray
        ``(n, d)`` float64 initial values (this array is kept).
    name : str
        The label.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim import FactorGraph
    >>> g = FactorGraph()
    >>> p = g.add_variables(np.zeros((2, 3)), name="p")
    >>> p, type(g.initial_values()[p]).__name__
    (Variables('p', R3, n=2, fixed=0), 'ndarray')
    """

    __slots__ = ()

    @property
    def value_type(self) -> str:
        return "an array"

    def wrap(self, params: Any) -> Any:
        return params

    def params_of(self, value: Any) -> Any:
        if isinstance(value, LieGroup):
            return super().params_of(value)
        if not hasattr(value, "shape"):
            value = np.asarray(value, dtype=np.float64)
        return value

    def retract(self, params: np.ndarray, delta: np.ndarray) -> np.ndarray:
        return params + delta

    def plus(self, params: Any, delta: Any) -> Any:
        return params + delta

    def inverse(self, X: Any) -> Any:
        return -X

    def compose(self, X: Any, Y: Any) -> Any:
        return X + Y

    def log(self, X: Any, jac: bool = False) -> Any:
        if not jac:
            return X
        return X, _eye(X.shape[0], self.dof)

    def minus(self, Y: Any, X: Any, jac: bool = False) -> Any:
        if not jac:
            return Y - X
        k = max(Y.shape[0], X.shape[0])
        return Y - X, _eye(k, self.dof), _eye(k, self.dof, -1.0)

    def gaussian(self, params: np.ndarray, cov: np.ndarray) -> Any:
        from ...uncertainty import VectorGaussian

        return VectorGaussian(params, cov)


def _eye(k: int, d: int, scale: float = 1.0) -> np.ndarray:
    """``scale * I_d`` repeated ``k`` times, a read-only view."""
    return np.broadcast_to(scale * np.eye(d), (k, d, d))


class Values:
    """Values of a graph's variables: ``values[handle]`` is the batch of that handle (a group
    element batch, or an ``(n, d)`` array for vectors). Iterating gives the handles.

    Parameters
    ----------
    handles : list of Variables
        The graph's handles.
    params : list of numpy.ndarray
        One parameter array per handle.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.identity(4), name="x")
    >>> v = g.initial_values()
    >>> len(v), v[x].batch_shape
    (1, (4,))
    """

    def __init__(self, handles: list[Variables], params: list[np.ndarray]) -> None:
        self._handles = list(handles)
        # torch / JAX arrays (device solves) are kept as they are
        self._params = [p if is_device_array(p) else np.asarray(p) for p in params]

    def __getitem__(self, var: Variables) -> Any:
        return var.wrap(self._params[self._index(var)])

    def params(self, var: Variables) -> np.ndarray:
        """The raw parameter array of a handle.

        Parameters
        ----------
        var : Variables
            A handle of the graph.

        Returns
        -------
        numpy.ndarray
            ``(n, params_dim)`` (SE2: ``x, y, cos, sin``), or ``(n, d)`` for vectors.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(4), name="x")
        >>> g.initial_values().params(x)[0].tolist()
        [0.0, 0.0, 1.0, 0.0]
        """
        return self._params[self._index(var)]

    def _index(self, var: Variables) -> int:
        for k, h in enumerate(self._handles):
            if h is var:
                return k
        raise KeyError(f"{var!r} does not belong to this graph")

    def __iter__(self) -> Iterator[Variables]:
        return iter(self._handles)

    def __len__(self) -> int:
        return len(self._handles)

    def items(self) -> Iterator[tuple[Variables, Any]]:
        """The ``(handle, value)`` pairs, in graph order.

        Yields
        ------
        tuple of (Variables, LieGroup or numpy.ndarray)

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(4), name="x")
        >>> [(h.name, type(v).__name__) for h, v in g.initial_values().items()]
        [('x', 'SE2')]
        """
        for h in self._handles:
            yield h, self[h]

    def __repr__(self) -> str:
        return f"Values({', '.join(repr(h.name) for h in self._handles)})"
