"""The one module that knows about array backends.

Group mathematics in :mod:`microlie.groups` is written on *components*: a quaternion is four
separate arrays ``(x, y, z, w)`` of the batch shape, a 3x3 matrix is a tuple of three row
tuples. The functions receive an ``ops`` object that supplies the few elementary functions
they need (``sin``, ``sqrt``, ``atan2``, ``where`` ...). Two kinds of ``ops`` exist:

* :class:`ArrayOps` wraps an array namespace (NumPy, PyTorch or JAX through
  ``array-api-compat``); components are arrays and ``where`` is an element-wise selection, so
  the same code vectorises, jits and differentiates.
* :data:`SCALAR` evaluates the same functions on Python floats. A single NumPy element (no
  batch axes) takes this path: it is an order of magnitude faster than NumPy calls on
  length-1 arrays. ``where`` then picks one value, exactly as the array version would.

Nothing here imports PyTorch or JAX: their namespaces are looked up only when a caller's array
is one of theirs.
"""

from __future__ import annotations

import math
import operator
import sys
from typing import Any

import numpy as np

Array = Any  # a NumPy, PyTorch or JAX array


def times(k: Any, v: Any) -> tuple:
    """``(k * v[0], k * v[1], ...)``."""
    return tuple(k * c for c in v)


class _ScalarOps:
    """Elementary functions on Python floats (the single-element NumPy path)."""

    is_scalar = True
    sin = staticmethod(math.sin)
    cos = staticmethod(math.cos)
    tan = staticmethod(math.tan)
    sqrt = staticmethod(math.sqrt)
    atan2 = staticmethod(math.atan2)
    exp = staticmethod(math.exp)
    expm1 = staticmethod(math.expm1)
    log = staticmethod(math.log)
    abs = staticmethod(abs)

    @staticmethod
    def where(cond: bool, a: float, b: float) -> float:
        return a if cond else b

    abs1 = staticmethod(abs)  # |x| (the derivative at 0 matters only to autodiff backends)
    # output components (see ArrayOps.negated): plain arithmetic here
    negated = staticmethod(operator.neg)
    add_out = staticmethod(operator.add)
    sub_out = staticmethod(operator.sub)
    mul_out = staticmethod(operator.mul)

    @staticmethod
    def select(cond: bool, f: Any, g: Any, *args: Any) -> Any:
        return f(*args) if cond else g(*args)

    @staticmethod
    def zeros_like(x: float) -> float:
        return 0.0

    @staticmethod
    def ones_like(x: float) -> float:
        return 1.0

    times = staticmethod(times)


SCALAR = _ScalarOps()


class ArrayOps:
    """Elementary functions of one array namespace."""

    is_scalar = False

    def __init__(self, xp: Any) -> None:
        self.xp = xp
        self.sin = xp.sin
        self.cos = xp.cos
        self.tan = xp.tan
        self.sqrt = xp.sqrt
        self.atan2 = xp.atan2
        self.exp = xp.exp
        self.expm1 = xp.expm1
        self.log = xp.log
        self.abs = xp.abs
        self.where = xp.where

    def abs1(self, x: Array) -> Array:
        """``|x|`` as ``x * (+1 if x >= 0 else -1)``: the derivative at 0 is 1 (torch's ``abs``
        has 0 there, which loses the angle of a rotation by exactly pi in ``Log``)."""
        one = self.xp.ones_like(x)
        return x * self.xp.where(x >= 0, one, -one)

    def select(self, cond: Array, f: Any, g: Any, *args: Any) -> Any:
        """``f(*args)`` where ``cond``, ``g(*args)`` elsewhere (an array or a tuple of arrays).

        Both branches are evaluated on every element and joined with ``where`` (jit- and
        autodiff-friendly): each must stay finite, with finite derivatives, where it is not
        selected (safe substitutes, see :mod:`microlie.groups._math`)."""
        a, b = f(*args), g(*args)
        if isinstance(a, tuple):
            return tuple(self.where(cond, x, y) for x, y in zip(a, b, strict=True))
        return self.where(cond, a, b)

    def zeros_like(self, x: Array) -> Array:
        return self.xp.zeros_like(x)

    def ones_like(self, x: Array) -> Array:
        return self.xp.ones_like(x)

    #: ``times(k, v)``: the components of a common factor ``k`` times a vector ``v``
    times = staticmethod(times)
    #: ``negated(x)``, ``add_out(a, b)``, ``sub_out(a, b)``, ``mul_out(a, b)``: ``-x``,
    #: ``a + b``, ``a - b``, ``a * b`` as an *output* component (plain arithmetic; the names
    #: mark output components in the formulas)
    negated = staticmethod(operator.neg)
    add_out = staticmethod(operator.add)
    sub_out = staticmethod(operator.sub)
    mul_out = staticmethod(operator.mul)
    #: ``id(product) -> (product, k, v_i)`` for the products made by ``times`` (set on a
    #: per-evaluation copy, see :func:`kernel_ops`), or ``None``
    blocks: dict[int, tuple] | None = None


class _BlockOps(ArrayOps):
    """The ops of one traced JAX evaluation: remembers the products made by ``times``, so that
    the evaluator can assemble them as one broadcast product ``k[..., None] * v`` (XLA then
    computes the common factor once instead of once per output column)."""

    def __init__(self, base: ArrayOps) -> None:
        self.__dict__.update(base.__dict__)
        self.blocks = {}

    def times(self, k: Any, v: Any) -> tuple:  # type: ignore[override]
        out = tuple(k * c for c in v)
        blocks = self.blocks
        assert blocks is not None
        for p, c in zip(out, v, strict=True):
            blocks[id(p)] = (p, k, c)
        return out


#: a traced JAX evaluation with at least this many elements assembles ``times`` blocks
BLOCK_MIN = 64


class _NumpyOps(ArrayOps):
    """NumPy without the ``array-api-compat`` wrappers (fewer Python calls per op)."""

    @staticmethod
    def abs1(x: Array) -> Array:
        return np.abs(x)  # no autodiff: the plain absolute value

    def __init__(self) -> None:
        super().__init__(np)
        self.atan2 = np.arctan2
        self.where = np.where

    def select(self, cond: Array, f: Any, g: Any, *args: Any) -> Any:
        """As :meth:`ArrayOps.select`, but on a 1-D batch each branch is evaluated only where
        it is needed: the branch of the majority on the whole batch, the other one on the
        gathered elements of the minority, scattered into the result (the results are the
        ones ``where`` would give, element by element)."""
        if type(cond) is not np.ndarray or cond.ndim != 1:
            return super().select(cond, f, g, *args)
        n = cond.shape[0]
        m = int(np.count_nonzero(cond))
        if m == 0:
            return g(*args)
        if m == n:
            return f(*args)
        major, minor, idx = (g, f, np.flatnonzero(cond)) if 2 * m <= n else \
            (f, g, np.flatnonzero(~cond))
        out = major(*args)
        sub = minor(*[a[idx] if type(a) is np.ndarray and a.shape == (n,) else a for a in args])
        if not isinstance(out, tuple):
            return _scatter(out, idx, sub, n, args)
        res: list = []  # an array the branch returns twice is patched in two copies
        for o, x in zip(out, sub, strict=True):
            res.append(_scatter(o, idx, x, n, (*args, *res)))
        return tuple(res)


def _scatter(out: Any, idx: np.ndarray, sub: Any, n: int, args: tuple) -> Any:
    """``out`` (a fresh array of ``n`` elements) with ``sub`` written at ``idx``."""
    if type(out) is not np.ndarray or out.shape != (n,) or any(out is a for a in args):
        out = np.array(np.broadcast_to(out, (n,)), dtype=np.result_type(out, sub))
    out[idx] = sub
    return out


NUMPY = _NumpyOps()


_OPS_CACHE: dict[int, ArrayOps] = {}


def namespace(*arrays: Array) -> Any:
    """The array namespace shared by ``arrays`` (NumPy for anything that is not torch/JAX)."""
    foreign = [a for a in arrays if not isinstance(a, (np.ndarray, np.generic, float, int))]
    if not foreign:
        return np
    from array_api_compat import array_namespace

    xp = array_namespace(*foreign)
    _register_pytrees(xp)
    return xp


def ops_for(*arrays: Array) -> ArrayOps:
    """The :class:`ArrayOps` for the caller's arrays."""
    xp = namespace(*arrays)
    if xp is np:
        return NUMPY
    ops = _OPS_CACHE.get(id(xp))
    if ops is None:
        ops = _OPS_CACHE[id(xp)] = ArrayOps(xp)
        _register_pytrees(xp)
    return ops


def kernel_ops(arrays: Any, n: int) -> ArrayOps:
    """The :class:`ArrayOps` for evaluating one kernel on ``arrays`` (``n`` elements each)."""
    o = ops_for(*arrays)
    if n >= BLOCK_MIN and is_jax(arrays[0]) and is_traced(arrays[0]):
        return _BlockOps(o)
    return o


def is_numpy(x: Array) -> bool:
    return isinstance(x, np.ndarray)


def is_jax(x: Array) -> bool:
    mod = type(x).__module__
    return mod.startswith("jax") or mod.startswith("jaxlib")


def is_torch(x: Array) -> bool:
    return type(x).__module__.startswith("torch")


def is_device_array(x: Any) -> bool:
    """True for an array the NumPy engine does not own: a torch tensor or a JAX array (the
    device engine, :mod:`microlie.optim.device`, solves with it)."""
    return is_torch(x) or is_jax(x)


def is_host_array(x: Any) -> bool:
    """True for a NumPy array."""
    return isinstance(x, np.ndarray)


def is_traced(x: Array) -> bool:
    """True for a JAX tracer or a torch tensor under ``torch.compile`` or inside a
    ``torch.func`` transform (values unknown: no value checks possible)."""
    if is_torch(x):
        return _torch_compiling(x) or _functorch_wrapped(x)
    if not is_jax(x):
        return False
    import jax

    return isinstance(x, jax.core.Tracer)


def as_float_array(x: Any, like: Array | None = None, dtype: Any = None) -> Array:
    """``x`` as a floating array of the backend of ``like`` (or of ``x`` itself).

    Lists, tuples and integer arrays become float64 (or ``dtype``); floating arrays keep their
    dtype and backend.
    """
    if type(x) is np.ndarray and (like is None or type(like) is np.ndarray) and dtype is None \
            and x.dtype in _NP_FLOATS:
        return x
    if dtype is None and is_torch(x) and x.dtype.is_floating_point:
        return x  # a real floating tensor (complex ones are not floating point)
    if like is not None and not is_numpy(like) and is_numpy_like(x):
        xp = namespace(like)
        return xp.asarray(np.asarray(x, dtype=np.float64), dtype=like.dtype, device=_device(like))
    if is_numpy_like(x):
        arr = np.asarray(x)
        if dtype is not None:
            return arr.astype(dtype, copy=False)
        if arr.dtype.kind != "f" or arr.dtype.itemsize < 4:
            arr = arr.astype(np.float64)
        elif arr.dtype == np.float16 or arr.dtype.itemsize > 8:
            arr = arr.astype(np.float64)
        return arr
    xp = namespace(x)
    if dtype is not None:
        return xp.asarray(x, dtype=dtype)
    if not xp.isdtype(x.dtype, "real floating"):
        return xp.asarray(x, dtype=xp.float64 if _has_f64(xp) else xp.float32)
    return x


_NP_FLOATS = (np.dtype(np.float64), np.dtype(np.float32))


def owned_array(x: Any) -> Array:
    """``x`` as an array that aliases no caller's NumPy array: NumPy input (and lists) as a
    floating array, copied if it is the caller's own; torch and JAX arrays as they are (JAX's
    are immutable, torch's keep their autograd graph)."""
    if not is_numpy_like(x):
        return x
    p = as_float_array(x)
    return p.copy() if p is x else p


def is_numpy_like(x: Any) -> bool:
    return isinstance(x, (np.ndarray, np.generic, list, tuple, float, int))


def _has_f64(xp: Any) -> bool:
    if "jax" in getattr(xp, "__name__", ""):
        import jax

        return bool(jax.config.read("jax_enable_x64"))
    return True


def _device(x: Array) -> Any:
    from array_api_compat import device

    return device(x)


def components(x: Array) -> list[Array]:
    """Split the last axis of ``x`` into a list of arrays (views where the backend allows)."""
    return [x[..., i] for i in range(x.shape[-1])]


_UNKNOWN, _HOST, _DEVICE = 0, 1, 2


def _where(x: Array) -> int:
    """Where the values of a torch or JAX array ``x`` can be read: ``_UNKNOWN`` (see
    :func:`values_known`), ``_HOST`` (CPU memory that NumPy can view without a copy; not inside
    a ``torch.func`` transform, where ``detach`` wraps even a tensor it does not) or
    ``_DEVICE`` (another device, or inside a transform: reduce in the array's namespace)."""
    torch = sys.modules.get("torch")
    if torch is not None and isinstance(x, torch.Tensor):
        fc = torch._C._functorch
        if torch.compiler.is_compiling() or fc.is_functorch_wrapped_tensor(x):
            return _UNKNOWN
        dev = x.device.type
        if dev == "cpu" and x.layout is torch.strided and fc.maybe_current_level() is None:
            return _HOST
        return _UNKNOWN if dev == "meta" else _DEVICE
    if is_jax(x):
        if is_traced(x):
            return _UNKNOWN
        try:
            return _HOST if all(d.platform == "cpu" for d in x.devices()) else _DEVICE
        except AttributeError:
            return _HOST
    return _HOST


def values_known(x: Array) -> bool:
    """Whether the values of ``x`` can be read for a check (the rule of :func:`check_finite`):
    not for a JAX tracer, a tensor while ``torch.compile`` traces, a tensor that a
    ``torch.func`` transform wraps (its inputs and what is computed from them), nor a tensor on
    the ``meta`` device (it has no values)."""
    return type(x) is np.ndarray or _where(x) != _UNKNOWN


def host_values(x: Array) -> np.ndarray | None:
    """The values of ``x`` as a NumPy array, or ``None`` when they are unknown (see
    :func:`values_known`, and inside a ``torch.func`` transform, where a tensor's memory cannot
    be read). Never forces a traced value: a concrete JAX array closed over by a jitted
    function is read on the host, not through a (traced) JAX operation. Arrays in CPU memory
    are viewed, not copied; arrays on another device (a GPU) are copied to the host, so the
    checks of every operation use :func:`all_finite` and :func:`max_abs` instead, which reduce
    on the device. For value checks only."""
    if type(x) is np.ndarray:
        return x
    w = _where(x)
    if w == _HOST:
        return _view(x)
    if w == _UNKNOWN or (is_torch(x) and _in_functorch()):
        return None  # inside a transform detach() would wrap it: no memory to read
    return x.detach().cpu().to_dense().numpy() if is_torch(x) else np.asarray(x)


def _view(x: Array) -> np.ndarray:
    """The NumPy view of an array in CPU memory (``_where(x) == _HOST``)."""
    return x.detach().numpy() if is_torch(x) else np.asarray(x)


def reduce_values(x: Array, fn: Any) -> float | None:
    """``fn(xp, v)``, a reduction of the values ``v`` of ``x`` to one number in the namespace
    ``xp``, as a Python float; ``None`` when the values are unknown (see
    :func:`values_known`). Arrays in CPU memory (NumPy, and torch and JAX arrays there) are
    viewed as NumPy, not copied; arrays on another device are reduced there, with one
    synchronisation (torch without autograd; JAX eagerly, also inside ``jax.jit`` for a
    concrete array it closes over: never a traced value)."""
    if type(x) is np.ndarray:
        return float(fn(np, x))
    w = _where(x)
    if w == _HOST:
        return float(fn(np, _view(x)))
    if w == _UNKNOWN:
        return None
    xp = namespace(x)
    if is_torch(x):
        import torch

        with torch.no_grad():
            return float(fn(xp, x))
    import jax

    with jax.ensure_compile_time_eval():
        return float(fn(xp, x))


def all_finite(x: Array) -> bool | None:
    """Whether every value of ``x`` is finite; ``None`` when the values are unknown. As
    :func:`reduce_values`: on the host for arrays in CPU memory, else one sum on the device
    (the exact test runs only when the sum is not finite)."""
    if type(x) is not np.ndarray:
        w = _where(x)
        if w == _UNKNOWN:
            return None
        if w == _DEVICE:
            if math.prod(x.shape) == 0:
                return True
            s = reduce_values(x, _sum)
            return True if s is None or math.isfinite(s) else reduce_values(x, _all_finite) == 1
        x = _view(x)
    return _np_finite(x)


def _sum(xp: Any, v: Array) -> Array:
    return xp.sum(v)


def _all_finite(xp: Any, v: Array) -> Array:
    return xp.all(xp.isfinite(v))


def _np_finite(v: np.ndarray) -> bool:
    # one sum: NaN/inf make it non-finite (so can overflow of huge values, in which case the
    # exact test decides). Not a BLAS call: no thread wake-up, no copy of a slice.
    if v.ndim == 1 and v.size <= 16:  # one element: a Python sum is the cheapest test
        return math.isfinite(sum(v.tolist())) or bool(np.isfinite(v).all())
    return not v.size or math.isfinite(np.add.reduce(v, axis=None)) \
        or bool(np.isfinite(v).all())


def max_abs(x: Array) -> float | None:
    """``max |x|`` over every value (0.0 for an empty array; NaN if a value is NaN), or
    ``None`` when the values are unknown; computed as :func:`reduce_values` says."""
    if math.prod(x.shape) == 0:
        return 0.0
    return reduce_values(x, _max_abs)


def _max_abs(xp: Any, v: Array) -> Array:
    return xp.max(xp.abs(v))


def check_finite(x: Array, what: str) -> None:
    """Raise ``ValueError`` if ``x`` holds NaN or inf (skipped when its values are unknown:
    see :func:`values_known`; on the array's device, see :func:`all_finite`)."""
    if not (_np_finite(x) if type(x) is np.ndarray else all_finite(x) is not False):
        raise ValueError(f"{what} contains NaN or infinite values")


def plain_tensors(arrays: Any) -> bool:
    """True if ``arrays`` are CPU torch tensors of one dtype whose results need no tensor
    operations: no autograd graph to record, no ``torch.compile``/``torch.jit`` trace, no
    ``torch.func`` transform, no tensor subclass (``False`` for anything that is not torch)."""
    torch = sys.modules.get("torch")
    if torch is None:
        return False
    grad = torch.is_grad_enabled()
    dt = arrays[0].dtype
    for a in arrays:
        if type(a) is not torch.Tensor or a.dtype != dt or not a.is_cpu \
                or (grad and a.requires_grad) or _functorch_wrapped(a):
            return False
    return not (torch.compiler.is_compiling() or torch.jit.is_tracing())


def element_floats(arrays: Any) -> list[list[float]] | None:
    """The values of single elements (1-D float32/float64 :func:`plain_tensors`) as lists of
    Python floats, or ``None``."""
    if all(a.ndim == 1 for a in arrays) and plain_tensors(arrays) \
            and str(arrays[0].dtype) in _TORCH_FLOATS:
        return [a.tolist() for a in arrays]
    return None


_TORCH_FLOATS: dict[str, Any] = {"torch.float64": np.dtype(np.float64),
                                 "torch.float32": np.dtype(np.float32)}


def empty_like_rows(like: Array, n: int, k: int) -> Array:
    """An uninitialised ``(n, k)`` torch tensor of ``like``'s dtype and device."""
    import torch

    return torch.empty((n, k), dtype=like.dtype, device=like.device)


def stack_into(columns: list, out: Array) -> None:
    """Write the ``(m,)`` tensors (or Python floats) ``columns`` into the columns of the
    ``(m, k)`` torch tensor ``out`` (one ``stack`` with ``out=``; no autograd)."""
    import torch

    if all(type(c) is torch.Tensor and c.shape == out.shape[:1] for c in columns):
        torch.stack(columns, dim=1, out=out)
        return
    for j, c in enumerate(columns):
        out[:, j] = c


def _functorch_wrapped(x: Array) -> bool:
    import torch

    return bool(torch._C._functorch.is_functorch_wrapped_tensor(x))


def _in_functorch() -> bool:
    """True inside a ``torch.func`` transform (even a tensor it does not wrap cannot then be
    viewed as NumPy: ``detach`` wraps it)."""
    import torch

    return torch._C._functorch.maybe_current_level() is not None


def floats_like(values: Any, like: Array) -> Array:
    """Python floats (a tuple, or a tuple of rows) as a fresh CPU tensor of ``like``'s dtype
    (float32 or float64)."""
    import torch

    return torch.from_numpy(np.array(values, dtype=_TORCH_FLOATS[str(like.dtype)]))


def _torch_compiling(x: Array) -> bool:
    """True while ``torch.compile`` traces (values unknown, and a check would break the graph)."""
    if not is_torch(x):
        return False
    import torch

    return bool(torch.compiler.is_compiling())


def check_last_dim(x: Array, n: int | tuple[int, ...], what: str) -> None:
    if type(n) is int and x.shape[-1:] == (n,):
        return
    shape = tuple(x.shape)
    want = (n,) if isinstance(n, int) else n
    if len(shape) < len(want) or shape[len(shape) - len(want):] != want:
        dims = "x".join(str(d) for d in want)
        raise ValueError(f"{what} must have shape (..., {dims.replace('x', ', ')}), got {shape}")


_PYTREE_CLASSES: list[tuple[type, Any]] = []
_PYTREES_DONE = False


def register_pytree_class(cls: type, adopt: Any) -> None:
    """Remember ``cls`` so that it becomes a JAX pytree once JAX is in use. Its one leaf is
    ``params``; ``adopt(params)`` rebuilds an element without checks (NumPy leaves, e.g. from
    ``jax.device_get``, go through ``cls.from_params(p, check=False)``, which makes them
    read-only)."""
    _PYTREE_CLASSES.append((cls, adopt))
    if "jax" in sys.modules:
        _register_one(cls, adopt)


def _register_pytrees(xp: Any) -> None:
    global _PYTREES_DONE
    if _PYTREES_DONE or "jax" not in getattr(xp, "__name__", ""):
        return
    _PYTREES_DONE = True
    for cls, adopt in _PYTREE_CLASSES:
        _register_one(cls, adopt)


_REGISTERED: set[type] = set()


def _register_one(cls: type, adopt: Any) -> None:
    if cls in _REGISTERED:
        return
    import jax

    from_params = cls.from_params  # type: ignore[attr-defined]

    def unflatten(_: Any, children: Any) -> Any:
        # called on every jitted call that returns elements: kept to one type test
        p = children[0]
        return from_params(p, check=False) if type(p) is np.ndarray else adopt(p)

    jax.tree_util.register_pytree_node(cls, lambda x: ((x.params,), None), unflatten)
    _REGISTERED.add(cls)
