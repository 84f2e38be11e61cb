"""The base class: every derived operation and its Jacobians, written once.

A group subclass supplies a handful of primitives on components (see :mod:`microlie._array`):
``_exp``, ``_log``, ``_compose``, ``_inverse``, ``_act`` (with ``_act_jac``), ``_adjoint``,
``_jr``, ``_jr_inv``, ``_matrix``, ``_from_matrix``, and its Lie algebra generators. Everything
else (plus, minus, between, interpolation, left Jacobians, the Lie bracket, hat and vee) is
derived here.

Conventions (``../shared/MATH.md`` section 1): right plus/minus by default, every Jacobian is a
right Jacobian (perturbation on the right of each input and of the output) unless
``side="left"`` is passed, tangent vectors are translation first.
"""

from __future__ import annotations

from math import factorial
from typing import Any, ClassVar

import numpy as np

from .. import _array as A
from .._array import NUMPY, SCALAR, Array, ops_for, pack, pack_matrix

# Large NumPy batches are evaluated in chunks of this many elements, so that the dozens of
# element-wise temporaries of one formula stay in the CPU cache (about twice as fast at 1e6).
CHUNK = 8192


def compute(fn: Any, arrays: tuple, like: Array, matrix: bool = False) -> Array:
    """Evaluate the component function ``fn(ops, *components)`` on ``arrays`` and stack the
    result (a vector, or with ``matrix=True`` a nested tuple of rows) in ``like``'s backend."""
    all_numpy = single = True
    for a in arrays:
        if type(a) is not np.ndarray:
            all_numpy = single = False
            break
        if a.ndim != 1:
            single = False
    if single:  # single NumPy elements: plain Python floats, far faster than tiny arrays
        return np.array(fn(SCALAR, *[a.tolist() for a in arrays]), dtype=like.dtype)
    if all_numpy:
        out = _compute_chunked(fn, arrays, like, matrix)
        if out is not None:
            return out
    foreign = next((a for a in arrays if type(a) is not np.ndarray), None)
    if foreign is not None and any(type(a) is np.ndarray for a in arrays):
        # NumPy constants meet torch/JAX arrays: move them to the caller's backend
        arrays = tuple(A.as_float_array(a, like=foreign) if type(a) is np.ndarray else a
                       for a in arrays)
        like = foreign
    o = ops_for(*arrays)
    if A.is_torch(like) and like.device.type == "cpu":
        out = _compute_chunked_torch(o, fn, arrays, like, matrix)
        if out is not None:
            return out
    r = fn(o, *[A.components(a) for a in arrays])
    return pack_matrix(o, r, like) if matrix else pack(o, r, like)


TORCH_CHUNK = 16384  # torch's per-call overhead is higher than NumPy's: larger chunks


def _compute_chunked_torch(o: Any, fn: Any, arrays: tuple, like: Array, matrix: bool) -> Any:
    """Large CPU tensors in chunks (cache-resident temporaries), joined with ``cat`` so that
    autograd sees ordinary operations."""
    batch = tuple(np.broadcast_shapes(*(tuple(a.shape[:-1]) for a in arrays)))
    n = int(np.prod(batch))
    if n < 2 * TORCH_CHUNK or any(a.ndim > 1 and tuple(a.shape[:-1]) != batch for a in arrays):
        return None
    xp = o.xp
    flats = [xp.reshape(a, (n, a.shape[-1])) if a.ndim > 1 else a for a in arrays]
    parts = []
    for s in range(0, n, TORCH_CHUNK):
        comps = [A.components(f[s:s + TORCH_CHUNK] if f.ndim > 1 else f) for f in flats]
        r = fn(o, *comps)
        parts.append(pack_matrix(o, r, like) if matrix else pack(o, r, like))
    out = xp.concat(parts, axis=0)
    return xp.reshape(out, (*batch, *out.shape[1:]))


def _compute_chunked(fn: Any, arrays: tuple, like: np.ndarray, matrix: bool) -> Any:
    batch = np.broadcast_shapes(*(a.shape[:-1] for a in arrays))
    n = int(np.prod(batch))
    if n < 2 * CHUNK or any(a.ndim > 1 and a.shape[:-1] != batch for a in arrays):
        return None
    flats = [a.reshape(n, a.shape[-1]) if a.ndim > 1 else a.tolist() for a in arrays]
    out = None
    shape = None
    for s in range(0, n, CHUNK):
        e = min(s + CHUNK, n)
        comps = [A.components(f[s:e]) if isinstance(f, np.ndarray) else f for f in flats]
        r = fn(NUMPY, *comps)
        if matrix:
            shape = (len(r), len(r[0]))
            r = [c for row in r for c in row]
        if out is None:
            out = np.empty((n, len(r)), dtype=like.dtype)
        for j, c in enumerate(r):
            out[s:e, j] = c
    return out.reshape(*batch, *shape) if matrix else out.reshape(*batch, out.shape[-1])


def _check_side(side: str) -> None:
    if side not in ("right", "left"):
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")


def _eye(n: int, like: Array, batch_shape: tuple) -> Array:
    if A.is_numpy(like):
        return np.broadcast_to(np.eye(n, dtype=like.dtype), (*batch_shape, n, n))
    xp = A.namespace(like)
    e = xp.eye(n, dtype=like.dtype, device=A._device(like))
    return xp.broadcast_to(e, (*batch_shape, n, n))


def _batch_shape_of(*arrays: Array) -> tuple:
    return tuple(np.broadcast_shapes(*(tuple(a.shape) for a in arrays)))


class LieGroup:
    """A batch of elements of a matrix Lie group, wrapping one parameter array.

    ``X.params`` has shape ``(*batch, param_dim)``; every operation broadcasts over the leading
    batch axes. Elements are immutable.
    """

    dof: ClassVar[int]
    param_dim: ClassVar[int]
    matrix_dim: ClassVar[int]
    point_dim: ClassVar[int]
    _identity_params: ClassVar[tuple[float, ...]]
    _generators: ClassVar[np.ndarray]

    __slots__ = ("params",)
    params: Array

    # ------------------------------------------------------------------ construction
    def __init__(self, params: Any, *, normalize: bool = False) -> None:
        p = A.as_float_array(params)
        A.check_last_dim(p, self.param_dim, f"{type(self).__name__} parameters")
        A.check_finite(p, f"{type(self).__name__} parameters")
        p = type(self)._validate_params(p, normalize)
        _set_params(self, p)

    @classmethod
    def _wrap(cls, params: Array) -> LieGroup:
        obj = object.__new__(cls)
        _set_params(obj, params)
        return obj

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        A.register_pytree_class(cls)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} elements are immutable")

    def __reduce__(self):
        return (type(self)._wrap, (self.params,))

    @classmethod
    def _validate_params(cls, p: Array, normalize: bool) -> Array:
        """Check (or, with ``normalize``, project) raw parameters. Subclasses override."""
        return p

    @classmethod
    def identity(cls, batch_shape: tuple[int, ...] | int = (), dtype: Any = None,
                 like: Array | None = None) -> LieGroup:
        """The identity element, repeated over ``batch_shape``."""
        batch_shape = (batch_shape,) if isinstance(batch_shape, int) else tuple(batch_shape)
        p = np.broadcast_to(np.asarray(cls._identity_params, dtype=dtype or np.float64),
                            (*batch_shape, cls.param_dim)).copy()
        return cls._wrap(A.as_float_array(p, like=like))

    @classmethod
    def random(cls, batch_shape: tuple[int, ...] | int = (), rng: Any = None,
               dtype: Any = None, like: Array | None = None) -> LieGroup:
        """Random elements: uniform rotations, standard normal translations, scales
        ``exp(N(0, 1/4))``. ``rng`` is a seed or ``numpy.random.Generator``; ``like`` puts the
        result in another array's backend, dtype and device."""
        rng = np.random.default_rng(rng)
        batch_shape = (batch_shape,) if isinstance(batch_shape, int) else tuple(batch_shape)
        p = cls._random_params(rng, batch_shape).astype(dtype or np.float64)
        return cls._wrap(p if like is None else A.as_float_array(p, like=like))

    @classmethod
    def _random_params(cls, rng: np.random.Generator, batch_shape: tuple) -> np.ndarray:
        raise NotImplementedError

    def normalize(self) -> LieGroup:
        """Project the parameters back onto the group (e.g. renormalise a quaternion that
        drifted over a long chain of products)."""
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

    def __getitem__(self, index: Any) -> LieGroup:
        if not self.batch_shape:
            raise IndexError(f"a single {type(self).__name__} element cannot be indexed")
        if not isinstance(index, tuple):
            index = (index,)
        return type(self)._wrap(self.params[(*index, slice(None))])

    def __iter__(self):
        for i in range(len(self)):
            yield self[i]

    def __repr__(self) -> str:
        return f"{type(self).__name__}(params={self.params!r})"

    # ------------------------------------------------------------------ primitives to supply
    @staticmethod
    def _exp(o, tau): raise NotImplementedError  # noqa: E704

    @staticmethod
    def _log(o, p): raise NotImplementedError  # noqa: E704

    @staticmethod
    def _compose(o, p, q): raise NotImplementedError  # noqa: E704

    @staticmethod
    def _inverse(o, p): raise NotImplementedError  # noqa: E704

    @staticmethod
    def _act(o, p, v): raise NotImplementedError  # noqa: E704

    @staticmethod
    def _act_jac(o, p, v): raise NotImplementedError  # noqa: E704

    @staticmethod
    def _adjoint(o, p): raise NotImplementedError  # noqa: E704

    @staticmethod
    def _matrix(o, p): raise NotImplementedError  # noqa: E704

    # Groups with closed-form ``_jr``/``_jr_inv`` set this; the others use ``_jr_series``.
    _has_closed_jr: ClassVar[bool] = True

    @classmethod
    def _jr(cls, o, tau): raise NotImplementedError  # noqa: E704

    @classmethod
    def _jr_inv(cls, o, tau): raise NotImplementedError  # noqa: E704

    # ------------------------------------------------------------------ tangent space
    @classmethod
    def _tangent(cls, tau: Any, like: Array | None = None) -> Array:
        t = A.as_float_array(tau, like=like)
        A.check_last_dim(t, cls.dof, f"{cls.__name__} tangent vector")
        A.check_finite(t, f"{cls.__name__} tangent vector")
        return t

    @classmethod
    def _const(cls, value: np.ndarray, like: Array) -> Array:
        if A.is_numpy(like):
            return value.astype(like.dtype, copy=False)
        xp = A.namespace(like)
        return xp.asarray(value, dtype=like.dtype, device=A._device(like))

    @classmethod
    def hat(cls, tau: Any) -> Array:
        """The Lie algebra matrix of ``tau``: shape ``(*batch, n, n)``."""
        t = cls._tangent(tau)
        g = cls._const(cls._generators, t)
        return (t[..., :, None, None] * g).sum(-3) if A.is_numpy(t) else \
            A.namespace(t).sum(t[..., :, None, None] * g, axis=-3)

    @classmethod
    def vee(cls, M: Any) -> Array:
        """The tangent vector of a Lie algebra matrix (inverse of :meth:`hat`)."""
        m = A.as_float_array(M)
        n = cls.matrix_dim
        A.check_last_dim(m, (n, n), f"{cls.__name__} Lie algebra matrix")
        gp = cls._const(np.linalg.pinv(cls._generators.reshape(cls.dof, n * n)), m)
        flat = m.reshape(*m.shape[:-2], n * n) if A.is_numpy(m) else \
            A.namespace(m).reshape(m, (*m.shape[:-2], n * n))
        return flat @ gp

    @classmethod
    def bracket(cls, a: Any, b: Any) -> Array:
        """Lie bracket ``[a, b] = vee(hat(a) hat(b) - hat(b) hat(a)) = ad(a) b``."""
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
        """The small adjoint matrix ``ad_tau`` (``ad(a) @ b == bracket(a, b)``)."""
        t = cls._tangent(tau)
        h = cls.hat(t)
        g = cls._const(cls._generators, t)
        cols = h[..., None, :, :] @ g - g @ h[..., None, :, :]  # (*batch, dof, n, n)
        v = cls.vee(cols)  # (*batch, dof(column), dof(row))
        return _swap_last(v)

    @classmethod
    def jr(cls, tau: Any) -> Array:
        """Right Jacobian ``Jr(tau)``: ``Exp(tau + d) ~= Exp(tau) Exp(Jr(tau) d)``."""
        t = cls._tangent(tau)
        if not cls._has_closed_jr:
            return cls._jr_series(t)
        return compute(cls._jr, (t,), t, matrix=True)

    @classmethod
    def jl(cls, tau: Any) -> Array:
        """Left Jacobian ``Jl(tau) = Jr(-tau)``: ``Exp(tau + d) ~= Exp(Jl(tau) d) Exp(tau)``."""
        return cls.jr(-cls._tangent(tau))

    @classmethod
    def jr_inv(cls, tau: Any) -> Array:
        """Inverse of the right Jacobian."""
        t = cls._tangent(tau)
        if not cls._has_closed_jr:
            return _inv(cls.jr(t))
        return compute(cls._jr_inv, (t,), t, matrix=True)

    @classmethod
    def jl_inv(cls, tau: Any) -> Array:
        """Inverse of the left Jacobian, ``Jl^-1(tau) = Jr^-1(-tau)``."""
        return cls.jr_inv(-cls._tangent(tau))

    @classmethod
    def _jr_series(cls, t: Array, halvings: int = 2, terms: int = 22) -> Array:
        """Generic ``Jr(tau) = int_0^1 Ad_Exp(-s tau) ds`` for groups without a closed form.

        Uses ``Jr(tau) = (I + Ad_Exp(-tau/2)) Jr(tau/2) / 2`` ``halvings`` times, then the
        series ``sum_k (-ad)^k / (k+1)!`` on ``tau / 2**halvings`` (Horner form).
        """
        batch = tuple(t.shape[:-1])
        eye = _eye(cls.dof, t, batch)
        small = t / 2.0**halvings
        neg_ad = -cls.ad(small)
        acc = eye * (1.0 / factorial(terms + 1))
        for k in range(terms, 0, -1):
            acc = eye * (1.0 / factorial(k)) + neg_ad @ acc
        jr = acc
        for level in range(halvings - 1, -1, -1):
            half = t / 2.0 ** (level + 1)
            ad_half = cls.exp(-half).adjoint()
            jr = 0.5 * ((eye + ad_half) @ jr)
        return jr

    # ------------------------------------------------------------------ Exp / Log
    @classmethod
    def exp(cls, tau: Any, jac: bool = False, side: str = "right"):
        """``Exp(tau) = exp(hat(tau))``. With ``jac=True`` also ``d Exp / d tau``
        (``Jr(tau)`` for ``side="right"``, ``Jl(tau)`` for ``side="left"``)."""
        t = cls._tangent(tau)
        X = cls._wrap(compute(cls._exp, (t,), t))
        if not jac:
            return X
        _check_side(side)
        return X, (cls.jr(t) if side == "right" else cls.jl(t))

    def log(self, jac: bool = False, side: str = "right"):
        """``Log(X) = vee(log(X))``. With ``jac=True`` also ``d Log / d X``
        (``Jr^-1(Log X)`` right, ``Jl^-1(Log X)`` left)."""
        tau = compute(self._log, (self.params,), self.params)
        if not jac:
            return tau
        _check_side(side)
        return tau, (self.jr_inv(tau) if side == "right" else self.jl_inv(tau))

    # ------------------------------------------------------------------ group operations
    def inverse(self, jac: bool = False, side: str = "right"):
        """``X^-1``. Jacobian: ``-Ad_X`` (right), ``-Ad_X^-1`` (left)."""
        Xi = self._wrap(compute(self._inverse, (self.params,), self.params))
        if not jac:
            return Xi
        _check_side(side)
        return Xi, -(self.adjoint() if side == "right" else Xi.adjoint())

    def compose(self, other: LieGroup, jac: bool = False, side: str = "right"):
        """``X Y``. Jacobians (right): ``Ad_Y^-1`` and ``I``; (left): ``I`` and ``Ad_X``."""
        if type(other) is not type(self):
            self._same_group(other)
        Z = self._wrap(compute(self._compose, (self.params, other.params), self.params))
        if not jac:
            return Z
        _check_side(side)
        batch = Z.batch_shape
        eye = _eye(self.dof, Z.params, batch)
        if side == "right":
            return Z, _bcast(other.inverse().adjoint(), batch), eye
        return Z, eye, _bcast(self.adjoint(), batch)

    def __matmul__(self, other: LieGroup) -> LieGroup:
        if not isinstance(other, LieGroup):
            return NotImplemented
        return self.compose(other)

    def between(self, other: LieGroup, jac: bool = False, side: str = "right"):
        """``X^-1 Y``. Jacobians (right): ``-Ad_(Y^-1 X)`` and ``I``."""
        self._same_group(other)
        if not jac:
            return self.inverse().compose(other)
        Xi, Ji = self.inverse(jac=True)
        Z, J1, J2 = Xi.compose(other, jac=True)
        return self._left(side, Z, [(J1 @ Ji, self), (J2, other)])

    def act(self, points: Any, jac: bool = False, side: str = "right"):
        """Act on points ``(..., point_dim)``: ``X . p``. Jacobians: ``d/dX`` (right, or left with
        ``side="left"``) and ``d/dp``."""
        v = A.as_float_array(points, like=self.params)
        A.check_last_dim(v, self.point_dim, "points")
        A.check_finite(v, "points")
        args = (self.params, v)
        out = compute(self._act, args, v)
        if not jac:
            return out
        _check_side(side)
        JX = compute(lambda o, p, c: self._act_jac(o, p, c)[0], args, out, matrix=True)
        JV = compute(lambda o, p, c: self._act_jac(o, p, c)[1], args, out, matrix=True)
        batch = tuple(out.shape[:-1])
        JX, JV = _bcast(JX, batch), _bcast(JV, batch)
        if side == "left":
            JX = JX @ _bcast(self.inverse().adjoint(), batch)
        return out, JX, JV

    def adjoint(self) -> Array:
        """The adjoint matrix ``Ad_X``: ``X Exp(tau) = Exp(Ad_X tau) X``."""
        return compute(self._adjoint, (self.params,), self.params, matrix=True)

    def matrix(self) -> Array:
        """The homogeneous matrix of the element, shape ``(*batch, n, n)``."""
        return compute(self._matrix, (self.params,), self.params, matrix=True)

    # ------------------------------------------------------------------ plus / minus
    def plus(self, tau: Any, jac: bool = False, side: str = "right"):
        """Right plus ``X (+) tau = X Exp(tau)``.

        Jacobians (right): ``Ad_Exp(tau)^-1`` and ``Jr(tau)``."""
        t = self._tangent(tau, like=self.params)
        if not jac:
            return self.compose(self.exp(t))
        E, Je = self.exp(t, jac=True)
        Z, J1, J2 = self.compose(E, jac=True)
        return self._left(side, Z, [(J1, self), (J2 @ Je, None)])

    def minus(self, other: LieGroup, jac: bool = False, side: str = "right"):
        """Right minus ``Y (-) X = Log(X^-1 Y)`` for ``Y.minus(X)``. Jacobians (right) with
        respect to ``Y`` and ``X``: ``Jr^-1(tau)``, ``-Jl^-1(tau)``."""
        self._same_group(other)
        if not jac:
            return other.between(self).log()
        D, Jx, Jy = other.between(self, jac=True)
        tau, Jlog = D.log(jac=True)
        return self._left(side, tau, [(Jlog @ Jy, self), (Jlog @ Jx, other)])

    def lplus(self, tau: Any, jac: bool = False, side: str = "right"):
        """Left plus ``tau (+) X = Exp(tau) X``."""
        t = self._tangent(tau, like=self.params)
        if not jac:
            return self.exp(t).compose(self)
        E, Je = self.exp(t, jac=True)
        Z, J1, J2 = E.compose(self, jac=True)
        return self._left(side, Z, [(J2, self), (J1 @ Je, None)])

    def lminus(self, other: LieGroup, jac: bool = False, side: str = "right"):
        """Left minus ``Y (-) X = Log(Y X^-1)`` for ``Y.lminus(X)``."""
        self._same_group(other)
        if not jac:
            return self.compose(other.inverse()).log()
        Xi, Ji = other.inverse(jac=True)
        D, J1, J2 = self.compose(Xi, jac=True)
        tau, Jlog = D.log(jac=True)
        return self._left(side, tau, [(Jlog @ J1, self), (Jlog @ J2 @ Ji, other)])

    def interpolate(self, other: LieGroup, t: Any) -> LieGroup:
        """``X (+) t (Y (-) X)``: ``t = 0`` gives ``X``, ``t = 1`` gives ``Y``; ``t`` broadcasts
        against the batch."""
        d = other.minus(self)
        tt = A.as_float_array(t, like=d)
        return self.plus(tt[..., None] * d)

    # ------------------------------------------------------------------ helpers
    def _same_group(self, other: Any) -> None:
        if type(other) is not type(self):
            raise TypeError(f"expected a {type(self).__name__}, got {type(other).__name__}")

    def _left(self, side: str, out: Any, jacs: list) -> tuple:
        """Return ``(out, J...)``; for ``side="left"`` turn each right Jacobian into a left one:
        ``J_left = Ad_out J_right Ad_in^-1`` (no adjoint for vector spaces)."""
        _check_side(side)
        if side == "right":
            return (out, *(j for j, _ in jacs))
        res = []
        ad_out = out.adjoint() if isinstance(out, LieGroup) else None
        for j, inp in jacs:
            if ad_out is not None:
                j = ad_out @ j
            if inp is not None:
                j = j @ inp.inverse().adjoint()
            res.append(j)
        return (out, *res)


_set_params = LieGroup.__dict__["params"].__set__


def _bcast(m: Array, batch: tuple) -> Array:
    if tuple(m.shape[:-2]) == batch:
        return m
    if A.is_numpy(m):
        return np.broadcast_to(m, (*batch, *m.shape[-2:]))
    return A.namespace(m).broadcast_to(m, (*batch, *m.shape[-2:]))


def _swap_last(m: Array) -> Array:
    if A.is_numpy(m):
        return np.swapaxes(m, -1, -2)
    xp = A.namespace(m)
    return xp.matrix_transpose(m) if hasattr(xp, "matrix_transpose") else m.transpose(-1, -2)


def _inv(m: Array) -> Array:
    if A.is_numpy(m):
        return np.linalg.inv(m)
    return A.namespace(m).linalg.inv(m)
