"""Variables of a factor graph: one batch of elements of one type per handle."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

from ...groups import LieGroup

__all__ = ["Variables", "Values", "element"]


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


class Variables:
    """A handle to one batch of ``n`` variables of one type in a :class:`FactorGraph`
    (returned by :meth:`FactorGraph.add_variables`; not built directly).

    ``group`` is a :class:`~microlie.LieGroup` subclass, or ``None`` for plain vectors of
    dimension ``dof``. Variables are perturbed on the right (``X Exp(delta)``; ``x + delta``
    for vectors), so every Jacobian and every marginal covariance is in the
    right-perturbation frame.

    Parameters
    ----------
    graph : FactorGraph
        The owner.
    key : int
        Position in the graph.
    values : LieGroup or array_like
        A 1-D batch of elements or an ``(n, d)`` array.
    fixed : optional
        Indices, a mask or ``True`` for the constant ones.
    name : str
        The label.

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

    __slots__ = ("graph", "key", "group", "dof", "n", "initial", "fixed", "name")

    def __init__(self, graph: Any, key: int, values: Any, fixed: Any, name: str) -> None:
        self.graph = graph
        self.key = key
        self.name = name
        if isinstance(values, LieGroup):
            if len(values.batch_shape) != 1:
                raise ValueError(f"{name}: variables must be a 1-D batch of elements (n,), got "
                                 f"batch shape {values.batch_shape}")
            self.group: type[LieGroup] | None = type(values)
            self.dof = values.dof
            p = np.asarray(values.params, dtype=np.float64)
        else:
            p = np.asarray(values, dtype=np.float64)
            if p.ndim != 2:
                raise ValueError(f"{name}: vector variables must be an (n, d) array, got shape "
                                 f"{p.shape}")
            if not np.all(np.isfinite(p)):
                raise ValueError(f"{name}: vector variables have non-finite entries")
            self.group = None
            self.dof = int(p.shape[1])
        self.initial = p.copy()
        self.n = int(p.shape[0])
        self.fixed = np.zeros(self.n, dtype=bool)
        if fixed is not None:
            self.fix(fixed)

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
        a = np.asarray(idx)
        if a.dtype == bool:
            if a.shape != (self.n,):
                raise ValueError(f"{self.name}: boolean mask of shape {a.shape}, expected "
                                 f"({self.n},)")
            return np.flatnonzero(a)
        if a.size and not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"{self.name}: {what} must be integers, got {a.dtype}")
        a = a.astype(np.int64).reshape(-1) if a.ndim else a.astype(np.int64).reshape(1)
        if a.size and (a.min() < 0 or a.max() >= self.n):
            bad = a[(a < 0) | (a >= self.n)][0]
            raise ValueError(f"{self.name}: {what} {int(bad)} out of range (the batch has "
                             f"{self.n} variables)")
        return a

    def fix(self, idx: Any = None) -> None:
        """Hold the variables ``idx`` constant.

        Parameters
        ----------
        idx : optional
            Indices or a mask; all if ``None`` or ``True`` (``False`` frees all).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE2
        >>> from microlie.optim import FactorGraph
        >>> g = FactorGraph()
        >>> x = g.add_variables(SE2.identity(4), name="x")
        >>> x.fix([0, 1])
        >>> x.fixed.tolist()
        [True, True, False, False]
        """
        if idx is None or idx is True:
            self.fixed[:] = True
        elif idx is False:
            self.fixed[:] = False
        else:
            self.fixed[self.indices(idx)] = True
        self.graph._changed()

    def unfix(self, idx: Any = None) -> None:
        """Let the variables ``idx`` vary again.

        Parameters
        ----------
        idx : optional
            Indices or a mask; all if ``None``.

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
        if idx is None:
            self.fixed[:] = False
        else:
            self.fixed[self.indices(idx)] = False
        self.graph._changed()

    def wrap(self, params: Any) -> Any:
        """Parameters of this batch as group elements (vectors are returned as they are).

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
        return params if self.group is None else element(self.group, params)

    def retract(self, params: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """The parameters of ``X Exp(delta)`` (``x + delta`` for vectors).

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
        if self.group is None:
            return params + delta
        return np.asarray(element(self.group, params).plus(delta).params)

    def __len__(self) -> int:
        return self.n

    def __repr__(self) -> str:
        kind = self.group.__name__ if self.group is not None else f"R^{self.dof}"
        return f"Variables({self.name!r}, {kind}, n={self.n}, fixed={int(self.fixed.sum())})"


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
        self._params = [np.asarray(p) for p in params]

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
