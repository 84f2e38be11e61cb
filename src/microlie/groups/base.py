"""The base class: every derived operation and its Jacobians, written once.

A concrete group supplies a handful of primitives on components (see :mod:`microlie._array`):
``_exp``, ``_log``, ``_compose``, ``_inverse``, ``_act`` and ``_act_jac``, ``_adjoint``,
``_matrix``, ``_jr`` and ``_jr_inv`` (unless ``_has_closed_jr = False``; optionally a hand-fused
``_minus_jac(o, y, x) -> (tau, Jr^-1(tau), -Jl^-1(tau))``), ``_random_params``,
and the class facts ``dof``, ``param_dim``, ``matrix_dim``, ``point_dim``, ``_identity_params``,
``_generators``. :meth:`LieGroup.__init_subclass__` checks that they are all there and builds the
group's kernels (:mod:`microlie._kernels`) from them: the primitives, and the derived operations
fused with their closed-form right Jacobians, each evaluated in one pass.

Conventions (Sola, Deray, Atchuthan, "A micro Lie theory for state estimation in robotics",
arXiv:1812.01537): right plus/minus by default (``X (+) tau = X Exp(tau)``,
``Y (-) X = Log(X^-1 Y)``, eqs. 25-26; left ones are ``lplus``/``lminus``, eqs. 27-28); every
Jacobian is a right Jacobian (perturbation on the right of each input and of the output) unless
``side="left"`` is passed, which transports it with ``J_left = Ad_out J_right Ad_in^-1``
(``Ad`` of eq. 29); tangent vectors are translation first. The closed-form Jacobians of the
elementary operations are the paper's (its section on the Jacobians of inverse, composition,
Exp/Log, plus/minus and the group action), as in manif.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Iterator, Sequence
from math import factorial
from typing import TYPE_CHECKING, Any, ClassVar, Literal, overload

import numpy as np

from .. import _array as A
from .. import _kernels as K
from .. import _linalg as L
from .._array import Array
from .._kernels import Kernel, run
from . import _math as M
from . import _single

if TYPE_CHECKING:
    from typing_extensions import Self

Side = Literal["right", "left"]

# What a concrete group must supply (checked when the class is created).
PRIMITIVES = ("_exp", "_log", "_compose", "_inverse", "_act", "_act_jac", "_adjoint", "_matrix",
              "_random_params")
CLOSED_JR = ("_jr", "_jr_inv")
FACTS = ("dof", "param_dim", "matrix_dim", "point_dim", "_identity_params", "_generators")


def _check_side(side: str) -> None:
    if side != "right" and side != "left":
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")


def _neg(v: Sequence[Any]) -> tuple:
    return tuple(-c for c in v)


def _build_kernels(cls: Any) -> dict[str, Kernel]:
    """The group's kernels: its primitives, and every derived operation fused with its
    closed-form right Jacobians (the paper's Jacobians of the elementary operations)."""
    exp, log, comp, inv = cls._exp, cls._log, cls._compose, cls._inverse
    act, act_jac, adj, mat = cls._act, cls._act_jac, cls._adjoint, cls._matrix
    d, pd, vd, n = cls.dof, cls.param_dim, cls.point_dim, cls.matrix_dim
    sq = (d, d)
    defs: dict[str, tuple] = {
        "exp": (exp, "t", [(pd,)], True),
        "log": (log, "p", [(d,)]),
        "compose": (comp, "pp", [(pd,)]),
        "inverse": (inv, "p", [(pd,)]),
        "act": (act, "pv", [(vd,)]),
        "adjoint": (adj, "p", [sq]),
        "matrix": (mat, "p", [(n, n)]),
        "adjoint_inv": (lambda o, p: adj(o, inv(o, p)), "p", [sq]),
        "between": (lambda o, p, q: comp(o, inv(o, p), q), "pp", [(pd,)]),
        "minus": (lambda o, y, x: log(o, comp(o, inv(o, x), y)), "pp", [(d,)]),
        "lminus": (lambda o, y, x: log(o, comp(o, y, inv(o, x))), "pp", [(d,)]),
        "plus": (lambda o, p, t: comp(o, p, exp(o, t)), "pt", [(pd,)], True),
        "lplus": (lambda o, p, t: comp(o, exp(o, t), p), "pt", [(pd,)], True),
        # fused value + right Jacobians
        "act_jac": (lambda o, p, v: (act(o, p, v), *act_jac(o, p, v)), "pv",
                    [(vd,), (vd, d), (vd, vd)]),
        "inverse_jac": (lambda o, p: (inv(o, p), M.neg_out(o, adj(o, p))), "p", [(pd,), sq]),
        "compose_jac": (lambda o, p, q: (comp(o, p, q), adj(o, inv(o, q))), "pp", [(pd,), sq]),
        "between_jac": (_between_jac(comp, inv, adj), "pp", [(pd,), sq]),
    }
    out = {name: K.add(Kernel(f"{cls.__name__}.{name}", cls, d_[0], d_[1], d_[2],
                              finite=len(d_) > 3 and d_[3], frozen=name in _ELEMENT_OUT))
           for name, d_ in defs.items()}
    jac_outs = {"exp_jac": ("t", [(pd,), sq]), "log_jac": ("p", [(d,), sq]),
                "minus_jac": ("pp", [(d,), sq, sq]), "lminus_jac": ("pp", [(d,), sq, sq]),
                "plus_jac": ("pt", [(pd,), sq, sq]), "lplus_jac": ("pt", [(pd,), sq]),
                "jr": ("t", [sq]), "jr_inv": ("t", [sq])}
    fns = _jr_kernels(cls) if cls._has_closed_jr else _jr_array_kernels(cls, out)
    for name, (ins, outs) in jac_outs.items():
        fn = fns[name]
        finite = ins[-1] == "t"
        out[name] = K.add(Kernel(f"{cls.__name__}.{name}", cls, fn if cls._has_closed_jr else None,
                                 ins, outs, finite=finite, frozen=name in _ELEMENT_OUT,
                                 array_fn=None if cls._has_closed_jr else fn))
    return out


# kernels whose first output becomes an element's parameters (returned read-only)
_ELEMENT_OUT = {"exp", "compose", "inverse", "between", "plus", "lplus", "exp_jac",
                "inverse_jac", "compose_jac", "between_jac", "plus_jac", "lplus_jac"}


def _between_jac(comp: Any, inv: Any, adj: Any) -> Any:
    def between_jac(o: Any, p: Any, q: Any) -> tuple:
        z = comp(o, inv(o, p), q)
        return z, M.neg_out(o, adj(o, inv(o, z)))  # d(X^-1 Y)/dX = -Ad_(Y^-1 X)
    return between_jac


def _jr_kernels(cls: Any) -> dict[str, Any]:
    """Component kernels of the operations whose Jacobians involve ``Jr`` (closed forms)."""
    exp, log, comp, inv, adj = cls._exp, cls._log, cls._compose, cls._inverse, cls._adjoint
    jr, jri, pair = cls._jr, cls._jr_inv, cls._jr_inv_pair

    def log_jac(o: Any, p: Any) -> tuple:
        tau = log(o, p)
        return tau, jri(o, tau)

    def minus_jac(o: Any, y: Any, x: Any) -> tuple:
        tau = log(o, comp(o, inv(o, x), y))
        a, b = pair(o, tau)  # Jr^-1(tau), Jl^-1(tau)
        return tau, a, M.neg_out(o, b)

    def lminus_jac(o: Any, y: Any, x: Any) -> tuple:
        tau = log(o, comp(o, y, inv(o, x)))
        j = M.matmul(jri(o, tau), adj(o, x))  # Jr^-1(tau) Ad_X
        return tau, j, M.neg_out(o, j)

    def plus_jac(o: Any, p: Any, t: Any) -> tuple:
        e = exp(o, t)
        return comp(o, p, e), adj(o, inv(o, e)), jr(o, t)

    def lplus_jac(o: Any, p: Any, t: Any) -> tuple:
        return comp(o, exp(o, t), p), M.matmul(adj(o, inv(o, p)), jr(o, t))

    return {"exp_jac": lambda o, t: (exp(o, t), jr(o, t)), "log_jac": log_jac,
            "minus_jac": getattr(cls, "_minus_jac", None) or minus_jac,
            "lminus_jac": lminus_jac, "plus_jac": plus_jac,
            "lplus_jac": lplus_jac, "jr": jr, "jr_inv": jri}


def _jr_array_kernels(cls: Any, k: dict[str, Kernel]) -> dict[str, Any]:
    """The same operations for a group without closed-form ``Jr``: on whole arrays, with
    :meth:`LieGroup._jr_series` and its inverse."""
    jr = cls._jr_series

    def jr_inv(t: Array) -> Array:
        return L.inv(jr(t))

    def log_jac(p: Array) -> tuple:
        tau = run(k["log"], p)
        return tau, jr_inv(tau)

    def minus_jac(y: Array, x: Array) -> tuple:
        tau = run(k["minus"], y, x)
        return tau, jr_inv(tau), -jr_inv(-tau)

    def lminus_jac(y: Array, x: Array) -> tuple:
        tau = run(k["lminus"], y, x)
        j = jr_inv(tau) @ run(k["adjoint"], x)
        return tau, j, -j

    def plus_jac(p: Array, t: Array) -> tuple:
        return run(k["plus"], p, t), run(k["adjoint_inv"], run(k["exp"], t)), jr(t)

    def lplus_jac(p: Array, t: Array) -> tuple:
        return run(k["lplus"], p, t), run(k["adjoint_inv"], p) @ jr(t)

    return {"exp_jac": lambda t: (run(k["exp"], t), jr(t)), "log_jac": log_jac,
            "minus_jac": minus_jac, "lminus_jac": lminus_jac, "plus_jac": plus_jac,
            "lplus_jac": lplus_jac, "jr": jr, "jr_inv": jr_inv}


class LieGroup:
    """A batch of elements of a matrix Lie group, wrapping one parameter array.

    ``X.params`` has shape ``(*batch, param_dim)``; every operation broadcasts over the leading
    batch axes. Elements are immutable (NumPy parameters are read-only arrays). Conventions:
    tangent vectors translation first, right ``plus``/``minus`` (``X Exp(tau)``,
    ``Log(X^-1 Y)``), right Jacobians unless ``side="left"``, quaternions ``(x, y, z, w)``.

    Parameters
    ----------
    params : array_like
        ``(*batch, param_dim)`` parameters (NumPy, PyTorch or JAX), checked.
    normalize : bool
        Project slightly-off parameters onto the group instead of raising ``ValueError``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie import SO3
    >>> R = SO3([0.0, 0.0, np.sin(0.25), np.cos(0.25)])  # (x, y, z, w): 0.5 rad about z
    >>> R.batch_shape, np.round(R.log(), 12).tolist()
    ((), [0.0, 0.0, 0.5])
    """

    dof: ClassVar[int]
    param_dim: ClassVar[int]
    matrix_dim: ClassVar[int]
    point_dim: ClassVar[int]
    _identity_params: ClassVar[tuple[float, ...]]
    _generators: ClassVar[np.ndarray]
    _vee_matrix: ClassVar[np.ndarray]
    _K: ClassVar[dict[str, Kernel]]
    _tshape: ClassVar[tuple[int]]
    _vshape: ClassVar[tuple[int]]
    # the primitives a concrete group supplies (component functions, see the module docstring)
    _exp: ClassVar[Callable[..., Any]]
    _log: ClassVar[Callable[..., Any]]
    _compose: ClassVar[Callable[..., Any]]
    _inverse: ClassVar[Callable[..., Any]]
    _act: ClassVar[Callable[..., Any]]
    _act_jac: ClassVar[Callable[..., Any]]
    _adjoint: ClassVar[Callable[..., Any]]
    _matrix: ClassVar[Callable[..., Any]]
    _jr: ClassVar[Callable[..., Any]]
    _jr_inv: ClassVar[Callable[..., Any]]
    # Groups with closed-form ``_jr``/``_jr_inv`` set this; the others use ``_jr_series``.
    _has_closed_jr: ClassVar[bool] = True
    # A group's range check of tangent vectors (``ValueError`` outside the range where its
    # formulas are verified), applied to every tangent input and output; None: no limit.
    _range_check: ClassVar[Any] = None  # or a staticmethod f(tau) -> None
    # The same check as data, for the compiled single elements (microlie._c._one): (component,
    # largest magnitude) of every tangent input and output; None: the check is Python-only.
    _range_bound: ClassVar[tuple[int, float] | None] = None

    # the single-element fast path (see :mod:`microlie.groups._single`): one function per
    # operation that returns None unless its inputs are single float64 NumPy values
    _one_exp: ClassVar[Callable[..., Any]]
    _one_log: ClassVar[Callable[..., Any]]
    _one_inverse: ClassVar[Callable[..., Any]]
    _one_compose: ClassVar[Callable[..., Any]]
    _one_between: ClassVar[Callable[..., Any]]
    _one_act: ClassVar[Callable[..., Any]]
    _one_plus: ClassVar[Callable[..., Any]]
    _one_minus: ClassVar[Callable[..., Any]]
    _one_exp_jac: ClassVar[Callable[..., Any]]
    _one_log_jac: ClassVar[Callable[..., Any]]
    _one_inverse_jac: ClassVar[Callable[..., Any]]
    _one_compose_jac: ClassVar[Callable[..., Any]]
    _one_between_jac: ClassVar[Callable[..., Any]]
    _one_act_jac: ClassVar[Callable[..., Any]]
    _one_plus_jac: ClassVar[Callable[..., Any]]
    _one_minus_jac: ClassVar[Callable[..., Any]]

    __slots__ = ("_params", "_floats")
    _params: Array | None  # None: made from _floats on first use
    _floats: list[float] | tuple[float, ...] | None  # a single float64 element's params

    @property
    def params(self) -> Array:
        """The parameters, ``(*batch, param_dim)`` (read-only for NumPy)."""
        p = self._params
        if p is None:  # a single element of the fast path: its array made on first use
            f = self._floats
            assert f is not None
            p = _frombuffer(_PACK[len(f)](*f))
            _set_params(self, p)
        return p

    # ------------------------------------------------------------------ construction
    def __init__(self, params: Any, *, normalize: bool = False) -> None:
        p = A.as_float_array(params)
        A.check_last_dim(p, self.param_dim, f"{type(self).__name__} parameters")
        A.check_finite(p, f"{type(self).__name__} parameters")
        q = type(self)._validate_params(p, normalize)
        if type(q) is np.ndarray:
            q = q.copy() if q is params else q
            _setflags(q, write=False)
        object.__setattr__(self, "_params", q)
        object.__setattr__(self, "_floats", _owned_floats(q))

    @classmethod
    def from_params(cls, params: Any, check: bool = True) -> Self:
        """An element from raw parameters ``(..., param_dim)``.

        Parameters
        ----------
        params : array_like
            The parameters (NumPy input is copied: the element never aliases the caller's
            array, and its ``params`` are read-only).
        check : bool
            ``True``: validated (``ValueError``) exactly like the constructor. ``False``: taken
            as they are, for solvers and readers whose parameters are valid by construction.

        Returns
        -------
        LieGroup
            An element of the class it is called on.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> SO3.from_params(np.array([0.0, 0.0, 0.6, 0.8]), check=False).log().round(6)
        array([0.      , 0.      , 1.287002])
        """
        if check:
            return cls(params)
        return cls._new(A.owned_array(params))

    @classmethod
    def _new(cls, params: Array) -> Self:
        """Wrap a fresh parameter array (made read-only in place)."""
        obj = object.__new__(cls)
        if type(params) is np.ndarray:
            _setflags(params, write=False)
        object.__setattr__(obj, "_params", params)
        object.__setattr__(obj, "_floats", _owned_floats(params))
        return obj

    @classmethod
    def _adopt(cls, params: Array) -> Self:
        """Wrap a kernel's output (already read-only)."""
        obj = object.__new__(cls)
        object.__setattr__(obj, "_params", params)
        object.__setattr__(obj, "_floats", _owned_floats(params))
        return obj

    @classmethod
    def _wrap(cls, params: Array) -> Self:
        """Wrap parameters without checks (a read-only view of a NumPy array; the array itself
        is left as it is)."""
        obj = object.__new__(cls)
        if type(params) is np.ndarray and params.flags.writeable:
            params = params.view()
            _setflags(params, write=False)
        object.__setattr__(obj, "_params", params)
        object.__setattr__(obj, "_floats", None)
        return obj

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        A.register_pytree_class(cls, cls._adopt)
        if not hasattr(cls, "dof"):  # an abstract intermediate class (e.g. Pose)
            return
        needed = FACTS + PRIMITIVES + (CLOSED_JR if cls._has_closed_jr else ())
        missing = [name for name in needed if getattr(cls, name, None) is None]
        if missing:
            raise TypeError(f"{cls.__name__} does not supply {', '.join(missing)}")
        d, n = cls.dof, cls.matrix_dim
        cls._tshape, cls._vshape = (d,), (cls.point_dim,)
        cls._vee_matrix = np.linalg.pinv(cls._generators.reshape(d, n * n))
        cls._K = _build_kernels(cls)
        for op, fn in _single.build(cls).items():
            setattr(cls, f"_one_{op}", staticmethod(fn))

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} elements are immutable")

    def __reduce__(self) -> tuple:
        return (_unpickle, (type(self), self.params))

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        raise TypeError(
            f"a {type(self).__name__} is not an array: use .params for its parameters or "
            ".matrix() for its homogeneous matrices")

    @classmethod
    def _validate_params(cls, p: Array, normalize: bool) -> Array:
        """Check (or, with ``normalize``, project) raw parameters. Subclasses override."""
        return p

    @classmethod
    def identity(cls, batch_shape: tuple[int, ...] | int = (), dtype: Any = None,
                 like: Array | None = None) -> Self:
        """The identity element, repeated over ``batch_shape``.

        Parameters
        ----------
        batch_shape : int or tuple of int
            The batch shape.
        dtype : dtype, optional
            Float type (default float64).
        like : array, optional
            Put the result in this array's backend, dtype and device.

        Returns
        -------
        LieGroup

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> SE3.identity(3).params[0].tolist()
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]
        """
        batch_shape = (batch_shape,) if isinstance(batch_shape, int) else tuple(batch_shape)
        p = np.broadcast_to(np.asarray(cls._identity_params, dtype=dtype or np.float64),
                            (*batch_shape, cls.param_dim)).copy()
        return cls._new(A.as_float_array(p, like=like))

    @classmethod
    def random(cls, batch_shape: tuple[int, ...] | int = (), rng: Any = None,
               dtype: Any = None, like: Array | None = None) -> Self:
        """Random elements: uniform rotations, standard normal translations, scales
        ``exp(N(0, 1/4))``.

        Parameters
        ----------
        batch_shape : int or tuple of int
            The batch shape.
        rng : int or numpy.random.Generator, optional
            A seed or a generator.
        dtype : dtype, optional
            Float type (default float64).
        like : array, optional
            Put the result in this array's backend, dtype and device.

        Returns
        -------
        LieGroup

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> R = SO3.random((2, 5), rng=0)
        >>> R.batch_shape, bool(np.allclose(np.linalg.norm(R.params, axis=-1), 1.0))
        ((2, 5), True)
        """
        rng = np.random.default_rng(rng)
        batch_shape = (batch_shape,) if isinstance(batch_shape, int) else tuple(batch_shape)
        p = cls._random_params(rng, batch_shape).astype(dtype or np.float64)
        return cls._new(p if like is None else A.as_float_array(p, like=like))

    def normalize(self) -> Self:
        """Project the parameters back onto the group (e.g. renormalise a quaternion that drifted
        over a long chain of products).

        Returns
        -------
        LieGroup

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> R = SO3([0.0, 0.0, 0.0, 1.0 + 1e-9], normalize=True).normalize()
        >>> float(np.linalg.norm(R.params))
        1.0
        """
        return type(self)(self.params, normalize=True)

    # ------------------------------------------------------------------ container protocol
    @property
    def batch_shape(self) -> tuple[int, ...]:
        return tuple(self.params.shape[:-1])

    @property
    def dtype(self) -> Any:
        return self.params.dtype

    def __len__(self) -> int:
        if not self.batch_shape:
            raise TypeError(f"a single {type(self).__name__} element has no length")
        return self.batch_shape[0]

    def __getitem__(self, index: Any) -> Self:
        if not self.batch_shape:
            raise IndexError(f"a single {type(self).__name__} element cannot be indexed")
        if not isinstance(index, tuple):
            index = (index,)
        return type(self)._wrap(self.params[index + (slice(None),)])

    def __iter__(self) -> Iterator[Self]:
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        return f"{type(self).__name__}(params={self.params!r})"

    @classmethod
    def stack(cls, elements: Sequence[LieGroup], axis: int = 0) -> Self:
        """Join elements of equal batch shape along a new batch axis.

        Parameters
        ----------
        elements : sequence of LieGroup
            Elements of this group, all of one batch shape and backend.
        axis : int
            The new batch axis (negative values count from the last batch axis).

        Returns
        -------
        LieGroup
            Batch shape ``(len(elements), *batch)`` for ``axis=0``.

        Examples
        --------
        >>> from microlie import SE3
        >>> SE3.stack([SE3.identity(), SE3.random(rng=0)]).batch_shape
        (2,)
        """
        ps = cls._params_of(elements)
        nb = len(ps[0].shape) - 1
        ax = _batch_axis(axis, nb + 1, "stack")
        xp = A.namespace(*ps)
        return cls._new(np.stack(ps, axis=ax) if xp is np else xp.stack(ps, axis=ax))

    @classmethod
    def concatenate(cls, elements: Sequence[LieGroup], axis: int = 0) -> Self:
        """Join batches along an existing batch axis.

        Parameters
        ----------
        elements : sequence of LieGroup
            Batches of this group (their other batch axes equal).
        axis : int
            The batch axis to join along.

        Returns
        -------
        LieGroup
            The joined batch.

        Examples
        --------
        >>> from microlie import SO3
        >>> SO3.concatenate([SO3.random(2, rng=0), SO3.random(3, rng=1)]).batch_shape
        (5,)
        """
        ps = cls._params_of(elements)
        nb = len(ps[0].shape) - 1
        if nb == 0:
            raise ValueError("concatenate needs batches (single elements: use stack)")
        ax = _batch_axis(axis, nb, "concatenate")
        xp = A.namespace(*ps)
        return cls._new(np.concatenate(ps, axis=ax) if xp is np else xp.concat(ps, axis=ax))

    @classmethod
    def _params_of(cls, elements: Sequence[LieGroup]) -> list[Array]:
        elements = list(elements)
        if not elements:
            raise ValueError(f"need at least one {cls.__name__}")
        for e in elements:
            if type(e) is not cls:
                raise TypeError(f"expected {cls.__name__} elements, got {type(e).__name__}")
        return [e.params for e in elements]

    # ------------------------------------------------------------------ primitives to supply
    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        raise NotImplementedError

    @classmethod
    def _jr_inv_pair(cls, o: Any, tau: Any) -> tuple:
        """``(Jr^-1(tau), Jl^-1(tau))`` in one evaluation (groups share their coefficients)."""
        return cls._jr_inv(o, tau), cls._jr_inv(o, _neg(tau))

    # ------------------------------------------------------------------ tangent space
    @classmethod
    def _tangent(cls, tau: Any, like: Array | None = None, kernel_checks: bool = False) -> Array:
        """``tau`` validated as tangent vectors. ``kernel_checks``: the caller evaluates a
        kernel that checks its result for NaN/inf (those with tangent inputs), which then
        replaces the input's finiteness check on NumPy batches (one pass over the data)."""
        if type(tau) is np.ndarray and tau.shape == cls._tshape and tau.dtype in _FLOATS \
                and (like is None or type(like) is np.ndarray) \
                and math.isfinite(sum(tau.tolist())):
            t = tau  # one valid NumPy tangent vector: the common case, checked once
        else:
            t = A.as_float_array(tau, like=like)
            A.check_last_dim(t, cls.dof, f"{cls.__name__} tangent vector")
            if not (kernel_checks and type(t) is np.ndarray and t.ndim > 1):
                A.check_finite(t, f"{cls.__name__} tangent vector")
        if cls._range_check is not None:
            cls._range_check(t)
        return t

    def _tangent_out(self, tau: Array) -> Array:
        if self._range_check is not None:
            self._range_check(tau)
        return tau

    @classmethod
    def _const(cls, value: np.ndarray, like: Array) -> Array:
        return L.asarray(value, like)

    @classmethod
    def hat(cls, tau: Any) -> Array:
        """The Lie algebra matrix of ``tau``.

        Parameters
        ----------
        tau : array_like
            ``(*batch, dof)`` tangent vectors (translation first).

        Returns
        -------
        array
            ``(*batch, n, n)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> SO3.hat([1.0, 2.0, 3.0]).tolist()
        [[0.0, -3.0, 2.0], [3.0, 0.0, -1.0], [-2.0, 1.0, 0.0]]
        """
        t = cls._tangent(tau)
        g = cls._const(cls._generators, t)
        return A.namespace(t).sum(t[..., :, None, None] * g, axis=-3)

    @classmethod
    def vee(cls, M: Any) -> Array:
        """The tangent vector of a Lie algebra matrix (inverse of :meth:`hat`).

        Parameters
        ----------
        M : array_like
            ``(*batch, n, n)`` Lie algebra matrices.

        Returns
        -------
        array
            ``(*batch, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> tau = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        >>> bool(np.allclose(SE3.vee(SE3.hat(tau)), tau))
        True
        """
        m = A.as_float_array(M)
        n = cls.matrix_dim
        A.check_last_dim(m, (n, n), f"{cls.__name__} Lie algebra matrix")
        gp = cls._const(cls._vee_matrix, m)
        return L.reshape(m, (*m.shape[:-2], n * n)) @ gp

    @classmethod
    def bracket(cls, a: Any, b: Any) -> Array:
        """Lie bracket ``[a, b] = vee(hat(a) hat(b) - hat(b) hat(a)) = ad(a) b``.

        Parameters
        ----------
        a, b : array_like
            ``(*batch, dof)`` tangent vectors.

        Returns
        -------
        array
            ``(*batch, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> SO3.bracket([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]).tolist()  # so(3): the cross product
        [0.0, 0.0, 1.0]
        """
        ha, hb = cls.hat(a), cls.hat(b)
        return cls.vee(ha @ hb - hb @ ha)

    @classmethod
    def bch(cls, a: Any, b: Any, order: int = 2) -> Array:
        """``Log(Exp(a) Exp(b))`` by the Baker-Campbell-Hausdorff series up to the terms of
        degree ``order``: ``a + b + [a, b]/2 + ([a, [a, b]] - [b, [a, b]])/12
        - [b, [a, [a, b]]]/24`` (the first bracket term is 1/2; see :mod:`microlie.groups._bch`).

        Parameters
        ----------
        a, b : array_like
            Tangent vectors ``(..., dof)`` (batches broadcast).
        order : int
            1 to 4; the error is ``O(|a, b|^(order + 1))``.

        Returns
        -------
        array
            ``(..., dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> a, b = np.array([0.01, 0.0, 0.0]), np.array([0.0, 0.02, 0.0])
        >>> exact = (SO3.exp(a) @ SO3.exp(b)).log()
        >>> bool(np.abs(SO3.bch(a, b, order=3) - exact).max() < 1e-8)
        True
        """
        from ._bch import bch

        return bch(cls, a, b, order)

    @classmethod
    def bch_first_order(cls, a: Any, b: Any, small: str = "a") -> Array:
        """``Log(Exp(a) Exp(b))`` to first order in the small argument (the other may be large).

        Parameters
        ----------
        a, b : array_like
            Tangent vectors ``(..., dof)``.
        small : {"a", "b"}
            ``"a"``: ``Jl(b)^-1 a + b``; ``"b"``: ``a + Jr(a)^-1 b``.

        Returns
        -------
        array
            ``(..., dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> a, b = np.array([1e-3, 0.0, 0.0]), np.array([0.0, 1.5, 0.3])
        >>> exact = (SO3.exp(a) @ SO3.exp(b)).log()
        >>> bool(np.abs(SO3.bch_first_order(a, b, small="a") - exact).max() < 1e-6)
        True
        """
        from ._bch import bch_first_order

        return bch_first_order(cls, a, b, small)

    @classmethod
    def ad(cls, tau: Any) -> Array:
        """The small adjoint matrix ``ad_tau`` (``ad(a) @ b == bracket(a, b)``).

        Parameters
        ----------
        tau : array_like
            ``(*batch, dof)`` tangent vectors (translation first).

        Returns
        -------
        array
            ``(*batch, dof, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> a, b = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6]), np.array([1.0, 0, 0, 0, 1.0, 0])
        >>> bool(np.allclose(SE3.ad(a) @ b, SE3.bracket(a, b)))
        True
        """
        t = cls._tangent(tau)
        h = cls.hat(t)
        g = cls._const(cls._generators, t)
        cols = h[..., None, :, :] @ g - g @ h[..., None, :, :]  # (*batch, dof, n, n)
        v = cls.vee(cols)  # (*batch, dof(column), dof(row))
        return L.mT(v)

    @classmethod
    def jr(cls, tau: Any) -> Array:
        """Right Jacobian ``Jr(tau)``: ``Exp(tau + d) ~= Exp(tau) Exp(Jr(tau) d)``.

        Parameters
        ----------
        tau : array_like
            ``(*batch, dof)`` tangent vectors (translation first).

        Returns
        -------
        array
            ``(*batch, dof, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> tau, d = np.array([0.3, -0.2, 0.5]), 1e-7 * np.array([1.0, 2.0, -1.0])
        >>> lhs = SO3.exp(tau + d).minus(SO3.exp(tau))
        >>> bool(np.allclose(lhs, SO3.jr(tau) @ d, atol=1e-13))
        True
        """
        return run(cls._K["jr"], cls._tangent(tau, kernel_checks=True))

    @classmethod
    def jl(cls, tau: Any) -> Array:
        """Left Jacobian ``Jl(tau) = Jr(-tau)``: ``Exp(tau + d) ~= Exp(Jl(tau) d) Exp(tau)``.

        Parameters
        ----------
        tau : array_like
            ``(*batch, dof)`` tangent vectors (translation first).

        Returns
        -------
        array
            ``(*batch, dof, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> tau = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        >>> bool(np.allclose(SE3.jl(tau), SE3.jr(-tau)))
        True
        """
        return cls.jr(-cls._tangent(tau))

    @classmethod
    def jr_inv(cls, tau: Any) -> Array:
        """Inverse of the right Jacobian.

        Parameters
        ----------
        tau : array_like
            ``(*batch, dof)`` tangent vectors (translation first).

        Returns
        -------
        array
            ``(*batch, dof, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> tau = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        >>> bool(np.allclose(SE3.jr_inv(tau) @ SE3.jr(tau), np.eye(6)))
        True
        """
        return run(cls._K["jr_inv"], cls._tangent(tau, kernel_checks=True))

    @classmethod
    def jl_inv(cls, tau: Any) -> Array:
        """Inverse of the left Jacobian, ``Jl^-1(tau) = Jr^-1(-tau)``.

        Parameters
        ----------
        tau : array_like
            ``(*batch, dof)`` tangent vectors (translation first).

        Returns
        -------
        array
            ``(*batch, dof, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> tau = np.array([0.3, -0.2, 0.5])
        >>> bool(np.allclose(SO3.jl_inv(tau) @ SO3.jl(tau), np.eye(3)))
        True
        """
        return cls.jr_inv(-cls._tangent(tau))

    @classmethod
    def _jr_series(cls, t: Array, halvings: int = 2, terms: int = 22) -> Array:
        """Generic ``Jr(tau) = int_0^1 Ad_Exp(-s tau) ds`` for groups without a closed form.

        Uses ``Jr(tau) = (I + Ad_Exp(-tau/2)) Jr(tau/2) / 2`` ``halvings`` times, then the
        series ``sum_k (-ad)^k / (k+1)!`` on ``tau / 2**halvings`` (Horner form).
        """
        batch = tuple(t.shape[:-1])
        eye = L.eye(cls.dof, t, batch)
        small = t / 2.0**halvings
        neg_ad = -cls.ad(small)
        acc = eye * (1.0 / factorial(terms + 1))
        for k in range(terms, 0, -1):
            acc = eye * (1.0 / factorial(k)) + neg_ad @ acc
        jr = acc
        for level in range(halvings - 1, -1, -1):
            half = t / 2.0 ** (level + 1)
            ad_half = run(cls._K["adjoint_inv"], run(cls._K["exp"], half))
            jr = 0.5 * ((eye + ad_half) @ jr)
        return jr

    # ------------------------------------------------------------------ Exp / Log
    @overload
    @classmethod
    def exp(cls, tau: Any, jac: Literal[False] = ..., side: Side = ...) -> Self: ...
    @overload
    @classmethod
    def exp(cls, tau: Any, jac: Literal[True], side: Side = ...) -> tuple[Self, Array]: ...
    @overload
    @classmethod
    def exp(cls, tau: Any, jac: bool, side: Side = ...) -> Self | tuple[Self, Array]: ...

    @classmethod
    def exp(cls, tau: Any, jac: bool = False, side: Side = "right") -> Any:
        """``Exp(tau) = exp(hat(tau))`` (eq. 23).

        Parameters
        ----------
        tau : array_like
            ``(*batch, dof)`` tangent vectors (translation first).
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        X : LieGroup
        J : array
            With ``jac=True``: ``d Exp / d tau``, ``Jr(tau)`` (right) or ``Jl(tau)`` (left).

        Examples
        --------
        >>> import numpy as np
        >>> from scipy.linalg import expm
        >>> from microlie import SE3
        >>> tau = np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])  # (rho, phi)
        >>> X, J = SE3.exp(tau, jac=True)
        >>> bool(np.allclose(X.matrix(), expm(SE3.hat(tau)))), bool(np.allclose(J, SE3.jr(tau)))
        (True, True)
        """
        if not jac:
            X = cls._one_exp(tau)
            if X is not None:
                return X
        elif side == "right":
            r = cls._one_exp_jac(tau)
            if r is not None:
                return r
        t = cls._tangent(tau, kernel_checks=True)
        if not jac:
            return cls._adopt(run(cls._K["exp"], t))
        p, J = run(cls._K["exp_jac"], t)
        return cls._adopt(p)._left(side, [(J, None)])

    @overload
    def log(self, jac: Literal[False] = ..., side: Side = ...) -> Array: ...
    @overload
    def log(self, jac: Literal[True], side: Side = ...) -> tuple[Array, Array]: ...
    @overload
    def log(self, jac: bool, side: Side = ...) -> Array | tuple[Array, Array]: ...

    def log(self, jac: bool = False, side: Side = "right") -> Any:
        """``Log(X) = vee(log(X))`` (eq. 24), the inverse of :meth:`exp`.

        Parameters
        ----------
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        tau : array
            ``(*batch, dof)``.
        J : array
            With ``jac=True``: ``d Log / d X``, ``Jr^-1(Log X)`` (right) or ``Jl^-1(Log X)`` (left).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> tau = np.array([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
        >>> t, J = SE3.exp(tau).log(jac=True)
        >>> bool(np.allclose(t, tau)), bool(np.allclose(J, SE3.jr_inv(tau)))
        (True, True)
        """
        if not jac:
            t = self._one_log(self)
            if t is not None:
                return t
            return self._tangent_out(run(self._K["log"], self.params))
        elif side == "right":
            r = self._one_log_jac(self)
            if r is not None:
                return r
        tau, J = run(self._K["log_jac"], self.params)
        return _left_vec(side, self._tangent_out(tau), [(J, self)])

    # ------------------------------------------------------------------ group operations
    @overload
    def inverse(self, jac: Literal[False] = ..., side: Side = ...) -> Self: ...
    @overload
    def inverse(self, jac: Literal[True], side: Side = ...) -> tuple[Self, Array]: ...
    @overload
    def inverse(self, jac: bool, side: Side = ...) -> Self | tuple[Self, Array]: ...

    def inverse(self, jac: bool = False, side: Side = "right") -> Any:
        """``X^-1``.

        Parameters
        ----------
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        Y : LieGroup
        J : array
            With ``jac=True``: ``-Ad_X`` (right), ``-Ad_X^-1`` (left).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X = SE3.random(rng=0)
        >>> Y, J = X.inverse(jac=True)
        >>> bool(np.allclose((X @ Y).matrix(), np.eye(4))), bool(np.allclose(J, -X.adjoint()))
        (True, True)
        """
        if not jac:
            Y = self._one_inverse(self)
            if Y is not None:
                return Y
            return self._adopt(run(self._K["inverse"], self.params))
        elif side == "right":
            r = self._one_inverse_jac(self)
            if r is not None:
                return r
        p, J = run(self._K["inverse_jac"], self.params)
        return self._adopt(p)._left(side, [(J, self)])

    @overload
    def compose(self, other: Self, jac: Literal[False] = ..., side: Side = ...) -> Self: ...
    @overload
    def compose(self, other: Self, jac: Literal[True],
                side: Side = ...) -> tuple[Self, Array, Array]: ...
    @overload
    def compose(self, other: Self, jac: bool,
                side: Side = ...) -> Self | tuple[Self, Array, Array]: ...

    def compose(self, other: Self, jac: bool = False, side: Side = "right") -> Any:
        """``X Y`` (also ``X @ Y``).

        Parameters
        ----------
        other : LieGroup
            ``Y``, of the same group (batches broadcast).
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        Z : LieGroup
        J_X, J_Y : array
            With ``jac=True``: ``Ad_Y^-1`` and ``I`` (right); ``I`` and ``Ad_X`` (left).

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X, Y = SE3.random(2, rng=0)
        >>> Z, JX, JY = X.compose(Y, jac=True)
        >>> bool(np.allclose(Z.matrix(), X.matrix() @ Y.matrix()))
        True
        >>> bool(np.allclose(JX, Y.inverse().adjoint())), bool(np.allclose(JY, np.eye(6)))
        (True, True)
        """
        if not jac:
            Z = self._one_compose(self, other)
            if Z is not None:
                return Z
        elif side == "right":
            r = self._one_compose_jac(self, other)
            if r is not None:
                return r
        if type(other) is not type(self):
            self._same_group(other)
        if not jac:
            return self._adopt(run(self._K["compose"], self.params, other.params))
        p, J1 = run(self._K["compose_jac"], self.params, other.params)
        Z = self._adopt(p)
        return Z._left(side, [(J1, self), (L.eye(self.dof, p, Z.batch_shape), other)])

    def __matmul__(self, other: Self) -> Self:
        Z = self._one_compose(self, other)
        if Z is not None:
            return Z
        if not isinstance(other, LieGroup):
            return NotImplemented
        return self.compose(other)

    @overload
    def between(self, other: Self, jac: Literal[False] = ..., side: Side = ...) -> Self: ...
    @overload
    def between(self, other: Self, jac: Literal[True],
                side: Side = ...) -> tuple[Self, Array, Array]: ...
    @overload
    def between(self, other: Self, jac: bool,
                side: Side = ...) -> Self | tuple[Self, Array, Array]: ...

    def between(self, other: Self, jac: bool = False, side: Side = "right") -> Any:
        """``X^-1 Y``.

        Parameters
        ----------
        other : LieGroup
            ``Y``.
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        Z : LieGroup
        J_X, J_Y : array
            With ``jac=True`` (right): ``-Ad_(Y^-1 X)`` and ``I``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X, Y = SE3.random(2, rng=1)
        >>> bool(np.allclose(X.between(Y).matrix(), np.linalg.inv(X.matrix()) @ Y.matrix()))
        True
        """
        if not jac:
            Z = self._one_between(self, other)
            if Z is not None:
                return Z
        elif side == "right":
            r = self._one_between_jac(self, other)
            if r is not None:
                return r
        self._same_group(other)
        if not jac:
            return self._adopt(run(self._K["between"], self.params, other.params))
        p, J1 = run(self._K["between_jac"], self.params, other.params)
        Z = self._adopt(p)
        return Z._left(side, [(J1, self), (L.eye(self.dof, p, Z.batch_shape), other)])

    @overload
    def act(self, points: Any, jac: Literal[False] = ..., side: Side = ...) -> Array: ...
    @overload
    def act(self, points: Any, jac: Literal[True],
            side: Side = ...) -> tuple[Array, Array, Array]: ...
    @overload
    def act(self, points: Any, jac: bool,
            side: Side = ...) -> Array | tuple[Array, Array, Array]: ...

    def act(self, points: Any, jac: bool = False, side: Side = "right") -> Any:
        """Act on points: ``X . p`` (``R p + t`` for SE(3), ``s R p + t`` for Sim(3)). The result
        dtype is the promotion of the element's and the points' dtypes.

        Parameters
        ----------
        points : array_like
            ``(*batch, point_dim)``.
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        q : array
            ``(*batch, point_dim)``.
        J_X, J_p : array
            With ``jac=True``: ``d q / d X`` (right, or left with ``side="left"``) and
            ``d q / d p``, with the value in one evaluation.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X, p = SE3.random(rng=2), np.array([1.0, 2.0, 3.0])
        >>> q, JX, Jp = X.act(p, jac=True)
        >>> bool(np.allclose(q, X.matrix()[:3, :3] @ p + X.translation()))
        True
        >>> bool(np.allclose(Jp, X.rotation().matrix())), JX.shape
        (True, (3, 6))
        """
        if not jac:
            q = self._one_act(self, points)
            if q is not None:
                return q
        elif side == "right":
            r = self._one_act_jac(self, points)
            if r is not None:
                return r
        p = self.params
        v = A.as_float_array(points, like=p)
        A.check_last_dim(v, self.point_dim, "points")
        A.check_finite(v, "points")
        if not jac:
            return run(self._K["act"], p, v)
        out, JX, JV = run(self._K["act_jac"], self.params, v)
        return _left_vec(side, out, [(JX, self), (JV, None)])

    def adjoint(self) -> Array:
        """The adjoint matrix ``Ad_X`` (eqs. 29-30): ``X Exp(tau) = Exp(Ad_X tau) X``.

        Returns
        -------
        array
            ``(*batch, dof, dof)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X, tau = SE3.random(rng=3), np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        >>> bool(np.allclose(X.plus(tau).matrix(), X.lplus(X.adjoint() @ tau).matrix()))
        True
        """
        return run(self._K["adjoint"], self.params)

    def matrix(self) -> Array:
        """The homogeneous matrix of the element (the rotation matrix for SO(2), SO(3)).

        Returns
        -------
        array
            ``(*batch, n, n)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> SE3.exp([1.0, 2.0, 3.0, 0.0, 0.0, 0.0]).matrix()[:3, 3].tolist()
        [1.0, 2.0, 3.0]
        """
        return run(self._K["matrix"], self.params)

    # ------------------------------------------------------------------ plus / minus
    @overload
    def plus(self, tau: Any, jac: Literal[False] = ..., side: Side = ...) -> Self: ...
    @overload
    def plus(self, tau: Any, jac: Literal[True],
             side: Side = ...) -> tuple[Self, Array, Array]: ...
    @overload
    def plus(self, tau: Any, jac: bool,
             side: Side = ...) -> Self | tuple[Self, Array, Array]: ...

    def plus(self, tau: Any, jac: bool = False, side: Side = "right") -> Any:
        """Right plus ``X (+) tau = X Exp(tau)`` (eq. 25).

        Parameters
        ----------
        tau : array_like
            ``(*batch, dof)`` tangent vectors (translation first).
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        Y : LieGroup
        J_X, J_tau : array
            With ``jac=True`` (right): ``Ad_Exp(tau)^-1`` and ``Jr(tau)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X, tau = SE3.random(rng=4), np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        >>> bool(np.allclose(X.plus(tau).matrix(), (X @ SE3.exp(tau)).matrix()))
        True
        """
        if not jac:
            Y = self._one_plus(self, tau)
            if Y is not None:
                return Y
        elif side == "right":
            r = self._one_plus_jac(self, tau)
            if r is not None:
                return r
        t = self._tangent(tau, like=self.params, kernel_checks=True)
        if not jac:
            return self._adopt(run(self._K["plus"], self.params, t))
        p, J1, J2 = run(self._K["plus_jac"], self.params, t)
        return self._adopt(p)._left(side, [(J1, self), (J2, None)])

    @overload
    def minus(self, other: Self, jac: Literal[False] = ..., side: Side = ...) -> Array: ...
    @overload
    def minus(self, other: Self, jac: Literal[True],
              side: Side = ...) -> tuple[Array, Array, Array]: ...
    @overload
    def minus(self, other: Self, jac: bool,
              side: Side = ...) -> Array | tuple[Array, Array, Array]: ...

    def minus(self, other: Self, jac: bool = False, side: Side = "right") -> Any:
        """Right minus ``Y (-) X = Log(X^-1 Y)`` for ``Y.minus(X)`` (eq. 26); inverse of
        :meth:`plus`.

        Parameters
        ----------
        other : LieGroup
            ``X``.
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        tau : array
            ``(*batch, dof)``.
        J_Y, J_X : array
            With ``jac=True`` (right): ``Jr^-1(tau)`` and ``-Jl^-1(tau)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X, tau = SE3.random(rng=5), np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        >>> t, JY, JX = X.plus(tau).minus(X, jac=True)
        >>> bool(np.allclose(t, tau)), bool(np.allclose(JX, -SE3.jl_inv(tau)))
        (True, True)
        """
        if not jac:
            t = self._one_minus(self, other)
            if t is not None:
                return t
        elif side == "right":
            r = self._one_minus_jac(self, other)
            if r is not None:
                return r
        self._same_group(other)
        if not jac:
            return self._tangent_out(run(self._K["minus"], self.params, other.params))
        tau, JY, JX = run(self._K["minus_jac"], self.params, other.params)
        return _left_vec(side, self._tangent_out(tau), [(JY, self), (JX, other)])

    @overload
    def lplus(self, tau: Any, jac: Literal[False] = ..., side: Side = ...) -> Self: ...
    @overload
    def lplus(self, tau: Any, jac: Literal[True],
              side: Side = ...) -> tuple[Self, Array, Array]: ...
    @overload
    def lplus(self, tau: Any, jac: bool,
              side: Side = ...) -> Self | tuple[Self, Array, Array]: ...

    def lplus(self, tau: Any, jac: bool = False, side: Side = "right") -> Any:
        """Left plus ``tau (+) X = Exp(tau) X`` (eq. 27).

        Parameters
        ----------
        tau : array_like
            ``(*batch, dof)`` tangent vectors (translation first).
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        Y : LieGroup
        J_X, J_tau : array
            With ``jac=True`` (right): ``I`` and ``Ad_X^-1 Jr(tau)``.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X, tau = SE3.random(rng=6), np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        >>> bool(np.allclose(X.lplus(tau).matrix(), (SE3.exp(tau) @ X).matrix()))
        True
        """
        t = self._tangent(tau, like=self.params, kernel_checks=True)
        if not jac:
            return self._adopt(run(self._K["lplus"], self.params, t))
        p, J2 = run(self._K["lplus_jac"], self.params, t)
        Z = self._adopt(p)
        return Z._left(side, [(L.eye(self.dof, p, Z.batch_shape), self), (J2, None)])

    @overload
    def lminus(self, other: Self, jac: Literal[False] = ..., side: Side = ...) -> Array: ...
    @overload
    def lminus(self, other: Self, jac: Literal[True],
               side: Side = ...) -> tuple[Array, Array, Array]: ...
    @overload
    def lminus(self, other: Self, jac: bool,
               side: Side = ...) -> Array | tuple[Array, Array, Array]: ...

    def lminus(self, other: Self, jac: bool = False, side: Side = "right") -> Any:
        """Left minus ``Y (-) X = Log(Y X^-1)`` for ``Y.lminus(X)`` (eq. 28); inverse of
        :meth:`lplus`.

        Parameters
        ----------
        other : LieGroup
            ``X``.
        jac : bool
            Also return the Jacobians, in argument order.
        side : {"right", "left"}
            Which Jacobians: right (perturbation ``X Exp(d)``, default) or left (``Exp(d) X``).

        Returns
        -------
        tau : array
            ``(*batch, dof)``.
        J_Y, J_X : array
            With ``jac=True`` (right): ``Jr^-1(tau) Ad_X`` and its negative.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X, tau = SE3.random(rng=7), np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
        >>> bool(np.allclose(X.lplus(tau).lminus(X), tau))
        True
        """
        self._same_group(other)
        if not jac:
            return self._tangent_out(run(self._K["lminus"], self.params, other.params))
        tau, JY, JX = run(self._K["lminus_jac"], self.params, other.params)
        return _left_vec(side, self._tangent_out(tau), [(JY, self), (JX, other)])

    def interpolate(self, other: Self, t: Any) -> Self:
        """The geodesic ``X (+) t (Y (-) X)``: ``t = 0`` gives ``X``, ``t = 1`` gives ``Y``.

        Parameters
        ----------
        other : LieGroup
            ``Y``.
        t : float or array_like
            Fractions; broadcast against the batch.

        Returns
        -------
        LieGroup

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SE3, SO3
        >>> X, Y = SO3.identity(), SO3.exp([0.0, 0.0, 1.0])
        >>> np.round(X.interpolate(Y, np.array([0.25, 0.5])).log(), 12).tolist()
        [[0.0, 0.0, 0.25], [0.0, 0.0, 0.5]]
        """
        d = other.minus(self)
        tt = A.as_float_array(t, like=d)
        return self.plus(tt[..., None] * d)

    # ------------------------------------------------------------------ comparisons, means
    def allclose(self, other: Self, atol: float = 1e-8, rtol: float = 1e-5) -> bool:
        """Whether every pair of elements agrees on the group.

        The rule: ``d = Y (-) X`` (right minus, a tangent vector) satisfies
        ``|d| <= atol + rtol * |Log(X)|`` entry by entry (for ``X.allclose(Y)``; the batch axes
        broadcast). Unlike comparing parameters, ``q`` and ``-q`` are equal and angles compare
        across pi.

        Parameters
        ----------
        other : LieGroup
            Elements of the same group.
        atol, rtol : float
            Absolute and relative tolerances (tangent units).

        Returns
        -------
        bool
            ``True`` when all pairs agree.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> R = SO3.exp(np.array([0.0, 0.0, 1.0]))
        >>> R.allclose(SO3(-R.params))
        True
        """
        self._same_group(other)
        d = other.minus(self)
        ref = self.log()
        xp = A.namespace(d)
        return bool(xp.all(xp.abs(d) <= atol + rtol * xp.abs(ref)))

    @classmethod
    def mean(cls, X: Self, weights: Any = None, axis: int = 0, tol: float | None = None,
             max_iter: int = 100) -> Self:
        """The (weighted) Karcher mean along a batch axis.

        The mean is the ``M`` with ``sum_i w_i Log(M^-1 X_i) = 0`` (right minus), found by the
        fixed-point iteration ``M <- M (+) sum_i w_i (X_i (-) M)`` from the first element.
        Needs concrete values (not inside ``jax.jit``).

        Parameters
        ----------
        X : LieGroup
            The elements, a batch of this group.
        weights : array_like, optional
            ``(n,)`` non-negative weights with a positive sum (normalised here); equal
            weights by default.
        axis : int
            The batch axis to average over.
        tol : float, optional
            Stop when the update is below ``tol`` in tangent units (default ``1e-12`` for
            float64, ``1e-6`` for float32).
        max_iter : int
            ``ValueError`` after this many iterations (the elements are too spread for a
            unique mean).

        Returns
        -------
        LieGroup
            The mean, with the batch axis ``axis`` removed.

        Examples
        --------
        >>> import numpy as np
        >>> from microlie import SO3
        >>> X = SO3.exp(np.array([[0.0, 0.0, 0.2], [0.0, 0.0, 0.6]]))
        >>> SO3.mean(X).log().round(12)
        array([0. , 0. , 0.4])
        """
        if not isinstance(X, cls):
            raise TypeError(f"expected a {cls.__name__}, got {type(X).__name__}")
        nb = len(X.batch_shape)
        if nb == 0:
            return X
        ax = _batch_axis(axis, nb, "mean")
        p = X.params
        xp = A.namespace(p)
        n = int(p.shape[ax])
        if weights is None:
            w = A.as_float_array(np.full(n, 1.0 / n), like=p)
        else:
            w = A.as_float_array(weights, like=p)
            wv = A.host_values(w)
            if tuple(w.shape) != (n,):
                raise ValueError(f"weights must have shape ({n},), got {tuple(w.shape)}")
            if wv is not None and (not np.isfinite(wv).all() or (wv < 0).any()
                                   or wv.sum() <= 0):
                raise ValueError("weights must be finite, non-negative, with a positive sum")
            w = w / xp.sum(w)
        if w.dtype != p.dtype:
            w = xp.astype(w, p.dtype)
        shape = [1] * (nb + 1)
        shape[ax] = n
        w = xp.reshape(w, tuple(shape))
        if tol is None:
            tol = 1e-12 if np.dtype(str(p.dtype).replace("torch.", "")).itemsize >= 8 else 1e-6
        index: list[Any] = [slice(None)] * (nb + 1)
        index[ax] = slice(0, 1)
        M = cls._wrap(p[tuple(index)])  # keeps the axis (length 1) to broadcast against X
        for _ in range(max_iter):
            delta = xp.sum(X.minus(M) * w, axis=ax, keepdims=True)
            M = M.plus(delta)
            step = A.host_values(delta)
            if step is not None and float(np.abs(step).max(initial=0.0)) <= tol:
                index[ax] = 0
                return cls._wrap(M.params[tuple(index)])
        raise ValueError(f"{cls.__name__}.mean did not converge in {max_iter} iterations "
                         f"(tolerance {tol:g}): the elements are too spread for a unique mean")

    # ------------------------------------------------------------------ helpers
    def _same_group(self, other: Any) -> None:
        if type(other) is not type(self):
            raise TypeError(f"expected a {type(self).__name__}, got {type(other).__name__}")

    def _left(self, side: str, jacs: list) -> tuple:
        """``(self, J...)`` for an operation whose output is the element ``self``; for
        ``side="left"`` each right Jacobian becomes ``Ad_out J Ad_in^-1`` (no adjoint for a
        tangent-vector input, marked ``None``)."""
        if side == "right":
            return (self, *(j for j, _ in jacs))
        _check_side(side)
        ad_out = run(self._K["adjoint"], self.params)
        return (self, *_to_left(ad_out, jacs))


def _to_left(ad_out: Array | None, jacs: list) -> list:
    """``J_left = Ad_out J_right Ad_in^-1`` for each ``(J, input)``."""
    res = []
    for j, inp in jacs:
        if ad_out is not None:
            j = ad_out @ j
        if inp is not None:
            j = j @ run(inp._K["adjoint_inv"], inp.params)
        res.append(j)
    return res


def _left_vec(side: str, out: Array, jacs: list) -> tuple:
    """As :meth:`LieGroup._left`, for an operation whose output is a vector."""
    if side == "right":
        return (out, *(j for j, _ in jacs))
    _check_side(side)
    return (out, *_to_left(None, jacs))


def _batch_axis(axis: int, ndim: int, what: str) -> int:
    """A batch axis in ``[-ndim, ndim)`` as an axis of the parameter array."""
    if not -ndim <= axis < ndim:
        raise ValueError(f"{what}: axis {axis} is out of range for {ndim} batch axes")
    return axis if axis >= 0 else axis - 1


def _owned_floats(p: Array) -> list[float] | None:
    """The Python floats of the parameters of a single float64 NumPy element, kept beside its
    ``params`` for the single-element fast path (only for arrays the element owns: they never
    change); None for anything else."""
    if type(p) is np.ndarray and p.ndim == 1 and p.dtype is _F64:
        return p.tolist()  # type: ignore[no-any-return]
    return None


def _unpickle(cls: type[LieGroup], params: Array) -> LieGroup:
    return cls.from_params(params, check=False)


# the constructors write the slots with ``object.__setattr__`` spelled out (``__setattr__``
# raises: elements are immutable), which torch.compile traces (not a slot descriptor's
# ``__set__``, nor ``object.__setattr__`` under another name); the descriptor's ``__set__`` is
# kept for the lazily made ``params`` of single NumPy elements (never traced)
_set_params = LieGroup.__dict__["_params"].__set__
_frombuffer = np.frombuffer
_PACK = {n: struct.Struct(f"{n}d").pack for n in range(1, 33)}
_F64 = np.dtype(np.float64)
_FLOATS = (np.dtype(np.float64), np.dtype(np.float32))
_setflags = np.ndarray.setflags
