"""Composite states: the vector-space group ``R(n)`` and products of groups.

``Product(SE23, R(3), R(3))`` is the state of an inertial filter (extended pose, gyroscope and
accelerometer biases): a :class:`LieGroup` whose parameters, tangent vectors and points are the
concatenations of its factors', and whose adjoint and Jacobians are block diagonal. Every
operation of the base class (plus/minus, compose, inverse, Jacobians, batching, backends)
works unchanged, so a product is a ``Gaussian`` mean or a solver variable like any group.
Classes are cached: ``Product(SE23, R(3)) is Product(SE23, R(3))``.
"""

from __future__ import annotations

from functools import cache
from typing import Any, ClassVar

import numpy as np

from .. import _array as A
from .._array import Array
from . import _math as M
from .base import LieGroup


class VectorSpace(LieGroup):
    """The additive group ``R^n`` (build it with :func:`R`): ``X Y = x + y``, ``Exp`` and
    ``Log`` are the identity, every Jacobian is ``I``. Matrix ``[[I, x], [0, 1]]``; acting on a
    point adds ``x``."""

    dim: ClassVar[int]

    def __reduce__(self):
        return (_rebuild, (_spec(type(self)), self.params))

    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        return rng.standard_normal((*batch_shape, cls.dim))

    @staticmethod
    def _exp(o, tau):
        return tuple(tau)

    @staticmethod
    def _log(o, p):
        return tuple(p)

    @staticmethod
    def _compose(o, p, q):
        return tuple(a + b for a, b in zip(p, q, strict=True))

    @staticmethod
    def _inverse(o, p):
        return tuple(-a for a in p)

    @staticmethod
    def _act(o, p, v):
        return tuple(a + b for a, b in zip(p, v, strict=True))

    @staticmethod
    def _act_jac(o, p, v):
        n = len(p)
        return M.eye(n, p[0]), M.eye(n, p[0])

    @staticmethod
    def _adjoint(o, p):
        return M.eye(len(p), p[0])

    @staticmethod
    def _matrix(o, p):
        n = len(p)
        z = 0.0 * p[0]
        rows = [tuple(z + (1.0 if i == j else 0.0) for j in range(n)) + (p[i],) for i in range(n)]
        return (*rows, tuple(z for _ in range(n)) + (z + 1.0,))

    @classmethod
    def _jr(cls, o, tau):
        return M.eye(len(tau), tau[0])

    @classmethod
    def _jr_inv(cls, o, tau):
        return M.eye(len(tau), tau[0])


@cache
def R(n: int) -> type[VectorSpace]:
    """The vector-space group ``R^n`` as a class (cached: ``R(3) is R(3)``).

    Parameters
    ----------
    n : int
        The dimension (positive).

    Returns
    -------
    type
        A :class:`VectorSpace` subclass (parameters, tangent and points of size ``n``).

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import R
    >>> b = R(3)(np.array([0.1, 0.2, 0.3]))
    >>> b.plus(np.array([1.0, 0.0, 0.0])).params
    array([1.1, 0.2, 0.3])
    """
    if not isinstance(n, int) or n < 1:
        raise ValueError(f"R(n) needs a positive integer n, got {n!r}")
    gens = np.zeros((n, n + 1, n + 1))
    for i in range(n):
        gens[i, i, n] = 1.0
    return type(f"R{n}", (VectorSpace,), {
        "__doc__": f"The vector-space group R^{n} (see :class:`VectorSpace`).",
        "__module__": __name__, "__slots__": (),
        "dim": n, "dof": n, "param_dim": n, "matrix_dim": n + 1, "point_dim": n,
        "_identity_params": (0.0,) * n, "_generators": gens})


class ProductGroup(LieGroup):
    """A direct product of groups (build it with :func:`Product`). Parameters, tangents and
    points are the factors' concatenated in order; ``X.part(i)`` is the ``i``-th factor."""

    factors: ClassVar[tuple[type[LieGroup], ...]]
    _p: ClassVar[tuple[int, ...]]  # parameter offsets
    _t: ClassVar[tuple[int, ...]]  # tangent offsets
    _v: ClassVar[tuple[int, ...]]  # point offsets

    def __reduce__(self):
        return (_rebuild, (_spec(type(self)), self.params))

    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        return np.concatenate([G._random_params(rng, batch_shape) for G in cls.factors], -1)

    @classmethod
    def _validate_params(cls, p: Array, normalize: bool) -> Array:
        xp = A.namespace(p)
        return xp.concat([G._validate_params(p[..., cls._p[i]:cls._p[i + 1]], normalize)
                          for i, G in enumerate(cls.factors)], axis=-1)

    @classmethod
    def from_parts(cls, *parts: LieGroup) -> ProductGroup:
        """From one element per factor (the batch axes broadcast)."""
        if len(parts) != len(cls.factors):
            raise ValueError(f"{cls.__name__} has {len(cls.factors)} factors, got "
                             f"{len(parts)} parts")
        for i, (G, X) in enumerate(zip(cls.factors, parts, strict=True)):
            if type(X) is not G:
                raise TypeError(f"{cls.__name__}.from_parts: part {i} must be a {G.__name__}, "
                                f"got {type(X).__name__}")
        from ._pose import concat_last

        return cls._wrap(concat_last(*(X.params for X in parts)))  # type: ignore[return-value]

    def part(self, i: int) -> LieGroup:
        """The ``i``-th factor of the element."""
        G = self.factors[i]
        return G._wrap(self.params[..., self._p[i]:self._p[i + 1]])

    def parts(self) -> tuple[LieGroup, ...]:
        return tuple(self.part(i) for i in range(len(self.factors)))


def _prim(kind: str, cls_ref: list) -> Any:
    """A primitive of the product class, delegating to the factors' primitives (``cls_ref``
    holds the class once it exists)."""

    def sl(c: Any, off: tuple[int, ...], i: int) -> tuple:
        return tuple(c[off[i]:off[i + 1]])

    def unary(o: Any, x: Any) -> tuple:  # _exp, _log, _inverse
        cls = cls_ref[0]
        off = cls._t if kind == "_exp" else cls._p
        out: list = []
        for i, G in enumerate(cls.factors):
            out.extend(getattr(G, kind)(o, sl(x, off, i)))
        return tuple(out)

    def binary(o: Any, p: Any, q: Any) -> tuple:  # _compose, _act
        cls = cls_ref[0]
        off = cls._p if kind == "_compose" else cls._v
        out: list = []
        for i, G in enumerate(cls.factors):
            out.extend(getattr(G, kind)(o, sl(p, cls._p, i), sl(q, off, i)))
        return tuple(out)

    def act_jac(o: Any, p: Any, v: Any) -> tuple:
        cls = cls_ref[0]
        JX, JV = [], []
        for i, G in enumerate(cls.factors):
            jx, jv = G._act_jac(o, sl(p, cls._p, i), sl(v, cls._v, i))
            JX.append(jx)
            JV.append(jv)
        return _blockdiag(JX, p[0]), _blockdiag(JV, p[0])

    def matrix(o: Any, x: Any) -> tuple:  # _adjoint, _matrix (params); _jr, _jr_inv (tangent)
        cls = cls_ref[0]
        off = cls._t if kind in ("_jr", "_jr_inv") else cls._p
        return _blockdiag([getattr(G, kind)(o, sl(x, off, i))
                           for i, G in enumerate(cls.factors)], x[0])

    if kind in ("_exp", "_log", "_inverse"):
        return unary
    if kind in ("_compose", "_act"):
        return binary
    if kind == "_act_jac":
        return act_jac
    return matrix


def _as_classmethod(f: Any) -> classmethod:
    return classmethod(lambda cls, o, tau: f(o, tau))


def _blockdiag(blocks: list[tuple], like: Any) -> tuple:
    """Block-diagonal component matrix (rectangular blocks allowed)."""
    z = 0.0 * like
    widths = [len(b[0]) for b in blocks]
    rows = []
    for k, b in enumerate(blocks):
        for r in b:
            row: list = []
            for m, w in enumerate(widths):
                row.extend(r if m == k else (z,) * w)
            rows.append(tuple(row))
    return tuple(rows)


def _spec(G: type[LieGroup]) -> Any:
    """A picklable description of a (possibly generated) group class."""
    if issubclass(G, VectorSpace):
        return ("R", G.dim)
    if issubclass(G, ProductGroup):
        return ("Product", tuple(_spec(F) for F in G.factors))
    return G


def _group(spec: Any) -> type[LieGroup]:
    if isinstance(spec, tuple) and spec[0] == "R":
        return R(spec[1])
    if isinstance(spec, tuple) and spec[0] == "Product":
        return Product(*(_group(f) for f in spec[1]))
    return spec


def _rebuild(spec: Any, params: Any) -> LieGroup:
    """Unpickle an element of a generated group (classes made by R(n) and Product)."""
    return _group(spec)._wrap(params)


def _offsets(sizes: list[int]) -> tuple[int, ...]:
    return tuple(int(x) for x in np.concatenate([[0], np.cumsum(sizes)]))


@cache
def _product(factors: tuple[type[LieGroup], ...]) -> type[ProductGroup]:
    ref: list = []
    dofs = [G.dof for G in factors]
    mats = [G.matrix_dim for G in factors]
    gens = np.zeros((sum(dofs), sum(mats), sum(mats)))
    t0 = m0 = 0
    for G in factors:
        gens[t0:t0 + G.dof, m0:m0 + G.matrix_dim, m0:m0 + G.matrix_dim] = G._generators
        t0 += G.dof
        m0 += G.matrix_dim
    ns: dict[str, Any] = {
        "__doc__": f"The product group {' x '.join(G.__name__ for G in factors)} "
                   "(see :class:`ProductGroup`).",
        "__module__": __name__, "__slots__": (), "factors": factors,
        "dof": sum(dofs), "param_dim": sum(G.param_dim for G in factors),
        "matrix_dim": sum(mats), "point_dim": sum(G.point_dim for G in factors),
        "_identity_params": sum((tuple(G._identity_params) for G in factors), ()),
        "_generators": gens,
        "_p": _offsets([G.param_dim for G in factors]), "_t": _offsets(dofs),
        "_v": _offsets([G.point_dim for G in factors]),
        "_has_closed_jr": all(G._has_closed_jr for G in factors),
    }
    for kind in ("_exp", "_log", "_compose", "_inverse", "_act", "_act_jac", "_adjoint",
                 "_matrix"):
        ns[kind] = staticmethod(_prim(kind, ref))
    for kind in ("_jr", "_jr_inv"):
        ns[kind] = _as_classmethod(_prim(kind, ref))
    name = "Product[" + ", ".join(G.__name__ for G in factors) + "]"
    cls = type(name, (ProductGroup,), ns)
    ref.append(cls)
    return cls


def Product(*factors: type[LieGroup]) -> type[ProductGroup]:
    """The direct product of groups, e.g. ``Product(SE23, R(3), R(3))`` (cached).

    Parameters, tangent vectors and points concatenate the factors' in order; the adjoint and
    the Jacobians are block diagonal. Right plus on the product is right plus on each factor.

    Parameters
    ----------
    *factors : type
        ``LieGroup`` classes (including ``R(n)`` and other products).

    Returns
    -------
    type
        A :class:`ProductGroup` subclass.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SE23, Product, R
    >>> State = Product(SE23, R(3), R(3))
    >>> State.dof, State.param_dim
    (15, 16)
    >>> X = State.identity().plus(np.arange(15) * 0.01)
    >>> np.round(X.part(2).params, 2)
    array([0.12, 0.13, 0.14])
    """
    if not factors:
        raise ValueError("Product needs at least one group")
    for G in factors:
        if not (isinstance(G, type) and issubclass(G, LieGroup)) or G is LieGroup:
            raise TypeError(f"Product factors must be LieGroup classes, got {G!r}")
    return _product(tuple(factors))
