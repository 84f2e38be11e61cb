"""Kernels: the named table of every group computation, and the one evaluator that runs them.

A *kernel* is a component function ``fn(ops, *inputs) -> outputs`` (see :mod:`microlie._array`):
each input is a list of components (one per entry of its last axis), each output is a tuple of
components (a vector) or a tuple of rows of components (a matrix). Every group registers its
kernels under ``"<Group>.<op>"`` when its class is created, e.g. ``"SO3.exp"``, ``"SE3.log"``,
``"SE3.compose"``, ``"SE3.act_jac"`` (value and both Jacobians in one evaluation),
``"SE3.minus_jac"``, ``"Sim3.jr"``. :data:`KERNELS` lists them all.

:func:`run` evaluates a kernel on arrays of shape ``(*batch, k)`` (batch axes broadcast):

* single NumPy elements run on Python floats (far faster than NumPy on length-1 arrays), and so
  do single CPU torch elements when no autograd graph, ``torch.compile``/``torch.jit`` trace or
  ``torch.func`` transform needs tensor operations (the outputs are tensors again);
* large NumPy batches run in chunks of :data:`CHUNK` rows, so that the temporaries of a formula
  stay in the CPU cache; large CPU torch tensors likewise (joined with ``cat``, autograd intact);
* everything else (JAX, torch, small NumPy batches) runs once on whole arrays. Under
  ``jax.jit``, output components that a formula writes as a common factor times a vector
  (``ops.times(k, v)``) are assembled as one broadcast product ``k[..., None] * v``: the same
  multiplications, but XLA then computes ``k`` once instead of once per output column (a
  stack of separately computed columns repeats every shared subexpression per column).

Matrix outputs of more than 8 entries (Jacobians, adjoints) of NumPy batches are views of
component-major arrays: shape ``(*batch, r, c)``, memory order ``(r, c, *batch)``. Each entry is
then one contiguous write (a row-major result costs a transposition that takes as long as the
formula); ``np.ascontiguousarray`` gives a row-major copy where one is needed. Their constant
(Python-number) entries are written once per call, after the last chunk, not in every chunk.

The result dtype is the promotion of the input dtypes (NumPy's rules) on every path. Kernels
flagged ``finite`` (those with tangent-vector inputs, where a huge angle or scale can overflow)
raise ``ValueError`` on a non-finite result, on every path (skipped for traced values).

Replacements (the seam for compiled kernels)
---------------------------------------------
``register(name, impl, backend="numpy")`` replaces the generic kernel ``name`` for NumPy inputs,
without touching the group classes; ``register(name, None)`` restores the generic one. Contract:

* ``impl(*inputs)`` receives one C-contiguous NumPy array per kernel input, of shape
  ``(N, k_i)`` (rows are elements; batch axes already broadcast and flattened, ``N >= 1``), all
  of one dtype, ``float32`` or ``float64`` (the promoted dtype of the caller's inputs). It is
  used for batches: a call whose inputs are all single elements (no batch axes) keeps the
  traced straight-line float code (:mod:`microlie._trace`), which is cheaper than any array
  round trip;
* it returns a tuple with one fresh array per kernel output, of shape ``(N, *shape_j)``
  (``(N, k)`` for a vector, ``(N, r, c)`` for a matrix, see ``KERNELS[name].outs``) and of the
  same dtype; there is no ``out=`` argument;
* it must agree with the generic kernel to rounding at every input, including the hard ones
  (angle 0, 1e-12, near and exactly pi, scale exponent 0): ``tests/test_kernels.py`` checks
  every registered replacement against the generic kernel in float32 and float64.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import numpy as np

from . import _array as A
from ._array import NUMPY, SCALAR, Array
from ._trace import compile_scalar

__all__ = ["Kernel", "KERNELS", "run", "run_floats", "scalar_function", "register",
           "register_single",
           "replacements", "CHUNK", "TORCH_CHUNK"]

# Large NumPy batches are evaluated in chunks of this many elements, so that the dozens of
# element-wise temporaries of one formula stay in the CPU cache (about twice as fast at 1e6).
CHUNK = 8192
TORCH_CHUNK = 16384  # torch's per-call overhead is higher than NumPy's: larger chunks
_WIDE = 8  # matrix outputs with more components than this are stored component-major

Shape = tuple[int, ...]


class Kernel:
    """One named computation.

    ``fn(ops, *inputs)`` works on components; ``ins`` names the kind of each input (``"p"``
    group parameters, ``"t"`` a tangent vector, ``"v"`` a point) and ``outs`` the shape of each
    output (``(k,)`` or ``(r, c)``). ``array_fn``, when given instead of ``fn``, works on whole
    arrays (for computations that are not element-wise formulas). ``impl`` is the registered
    NumPy replacement, if any.
    """

    __slots__ = ("name", "group", "fn", "array_fn", "ins", "outs", "finite", "impl", "one",
                 "_flat", "frozen", "_scalar", "_sizes")

    def __init__(self, name: str, group: Any, fn: Callable[..., Any] | None,
                 ins: Sequence[str], outs: Sequence[Shape], finite: bool = False,
                 array_fn: Callable[..., Any] | None = None, frozen: bool = False) -> None:
        self.name = name
        self.group = group
        self.fn = fn
        self.array_fn = array_fn
        self.ins = tuple(ins)
        self.outs = tuple(tuple(s) for s in outs)
        self.finite = finite
        self.impl: Callable[..., Any] | None = None
        self.one: Callable[..., Any] | None = None
        self._flat = len(self.outs) == 1
        self.frozen = frozen  # the first output becomes an element's parameters: read-only
        self._scalar: Callable[..., Any] | None = None  # the traced single-element function
        self._sizes: tuple[int, ...] = ()

    def __repr__(self) -> str:
        return f"Kernel({self.name!r}, ins={self.ins}, outs={self.outs})"


KERNELS: dict[str, Kernel] = {}


def add(kernel: Kernel) -> Kernel:
    """Put ``kernel`` in the table (a group class does this for each of its kernels)."""
    KERNELS[kernel.name] = kernel
    return kernel


def register(name: str, impl: Callable[..., Any] | None, backend: str = "numpy") -> None:
    """Use ``impl`` instead of the generic kernel ``name`` for NumPy inputs (``None``: back to
    the generic kernel). See the module docstring for the contract."""
    if backend != "numpy":
        raise ValueError(f"only backend='numpy' replacements are supported, got {backend!r}")
    if name not in KERNELS:
        raise KeyError(f"no kernel named {name!r}; known: {', '.join(sorted(KERNELS))}")
    if impl is not None and not callable(impl):
        raise TypeError("impl must be callable (or None)")
    KERNELS[name].impl = impl


def register_single(name: str, one: Callable[..., Any] | None) -> None:
    """Use ``one`` for single float64 NumPy elements of kernel ``name`` (``None``: back to the
    traced Python code). Contract: ``one(*inputs)`` takes one one-dimensional array per input and
    returns the output (one output) or the tuple of outputs as fresh float64 arrays, output 0
    read-only if the kernel is ``frozen``, or ``None`` for any input it does not handle (not a
    contiguous float64 vector of the right length) and for a non-finite result of a ``finite``
    kernel; the caller then evaluates the generic kernel (which raises the errors)."""
    if name not in KERNELS:
        raise KeyError(f"no kernel named {name!r}")
    if one is not None and not callable(one):
        raise TypeError("one must be callable (or None)")
    KERNELS[name].one = one


def replacements() -> list[str]:
    """Names of the kernels that currently have a registered replacement."""
    return [k for k, v in KERNELS.items() if v.impl is not None]


# ---------------------------------------------------------------------------- the evaluator


def run(k: Kernel, *arrays: Array) -> Any:
    """Evaluate kernel ``k`` on ``arrays``: one array per output (a tuple if several)."""
    a = arrays[0]
    if k.one is not None:  # compiled single element (None for anything else)
        r = k.one(*arrays)
        if r is not None:
            return r
    if k.fn is not None and type(a) is np.ndarray and a.ndim == 1:
        # single NumPy elements: plain Python floats, far faster than NumPy on tiny arrays
        if len(arrays) == 1:
            return _single(k, (a.tolist(),), a.dtype)
        b = arrays[1]
        if len(arrays) == 2 and type(b) is np.ndarray and b.ndim == 1 and b.dtype is a.dtype:
            return _single(k, (a.tolist(), b.tolist()), a.dtype)
    return _run(k, arrays)


def run_floats(k: Kernel, lists: tuple, dt: Any) -> Any:
    """:func:`run` on one element given as lists of Python floats (one list per input, of the
    right lengths, finite) and the NumPy dtype of the result: for callers that have already
    read and checked the values."""
    if k.fn is None:
        return run(k, *[np.array(x, dtype=dt) for x in lists])
    return _single(k, lists, dt)


def scalar_function(k: Kernel) -> Callable[..., Any]:
    """The function of Python floats that evaluates ``k`` on one element: ``f(*lists)`` takes
    one list (or tuple) of floats per input and returns a tuple of floats per output (rows of
    tuples for a matrix), as the traced straight-line code of :mod:`microlie._trace`."""
    return k._scalar or _scalar_function(k)


def _single(k: Kernel, lists: tuple, dt: Any) -> Any:
    f = k._scalar or _scalar_function(k)
    try:
        r = f(*lists)
    except (ValueError, OverflowError, ZeroDivisionError) as e:
        for i, (x, n) in enumerate(zip(lists, k._sizes, strict=False)):
            if len(x) != n:
                raise ValueError(f"{k.name}: input {i} has {len(x)} components, expected "
                                 f"{n}") from e
        raise ValueError(_not_finite(k)) from e
    if k._flat:
        if k.finite and not math.isfinite(_fsum(r)):
            raise ValueError(_not_finite(k))
        if k.frozen and dt is _F64:  # read-only without a copy or a flag change
            return _frombuffer(_PACK[len(r)](*r))
        out = np.array(r, dtype=dt)
        if k.frozen:
            _setflags(out, write=False)
        return out
    if k.finite and not math.isfinite(sum(_fsum(x) for x in r)):
        raise ValueError(_not_finite(k))
    outs = [np.array(x, dtype=dt) for x in r]
    if k.frozen:
        _setflags(outs[0], write=False)
    return tuple(outs)


_F64 = np.dtype(np.float64)
_frombuffer = np.frombuffer
_setflags = np.ndarray.setflags
_PACK = {n: struct.Struct(f"{n}d").pack for n in range(1, 33)}


def _scalar_function(k: Kernel) -> Callable[..., Any]:
    """The single-element function of ``k``: traced once (see :mod:`microlie._trace`), or the
    component function on Python floats when it cannot be traced."""
    fn = k.fn
    assert fn is not None
    sizes = _input_sizes(k)
    traced = compile_scalar(fn, sizes) if sizes else None
    k._sizes = sizes
    k._scalar = traced if traced is not None else partial(fn, SCALAR)
    return k._scalar


def _input_sizes(k: Kernel) -> tuple[int, ...]:
    G = k.group
    dims = {"p": "param_dim", "t": "dof", "v": "point_dim"}
    try:
        return tuple(9 if kind == "m" else int(getattr(G, dims[kind])) for kind in k.ins)
    except (KeyError, AttributeError):
        return ()


def _run(k: Kernel, arrays: Sequence[Array]) -> Any:
    single = True
    for a in arrays:
        if type(a) is not np.ndarray:
            return _run_foreign(k, arrays)
        if a.ndim != 1:
            single = False
    if (k.impl is not None and not single) or k.fn is None:
        return _run_arrays(k, arrays)
    dt = arrays[0].dtype
    for a in arrays[1:]:
        if a.dtype is not dt:  # mixed dtypes: evaluate in the promoted one (NumPy's rules)
            dt = np.promote_types(dt, a.dtype)
            arrays = tuple(b.astype(dt, copy=False) for b in arrays)
    if single:
        return _single(k, tuple(a.tolist() for a in arrays), dt)
    batch = np.broadcast_shapes(*(a.shape[:-1] for a in arrays))
    if k.finite:  # overflow is reported once, as a ValueError, not as NumPy warnings
        with np.errstate(over="ignore", invalid="ignore"):
            out = _numpy_batch(k, arrays, batch, dt)
        _check_outputs(k, out)
    else:
        out = _numpy_batch(k, arrays, batch, dt)
    if k.frozen:
        _setflags(out[0], write=False)
    return out[0] if k._flat else tuple(out)


def _numpy_batch(k: Kernel, arrays: Sequence[np.ndarray], batch: Shape, dt: Any) -> list:
    out = _chunked(k, arrays, batch, dt)
    if out is None:
        assert k.fn is not None
        r = k.fn(NUMPY, *[A.components(a) for a in arrays])
        out = [_pack(NUMPY, x, s, dt, batch)
               for x, s in zip([r] if k._flat else r, k.outs, strict=True)]
    return out


def _fsum(r: Any) -> float:
    return sum(sum(x) for x in r) if type(r[0]) is tuple else sum(r)


def _not_finite(k: Kernel) -> str:
    return (f"{k.name}: the result is not finite: an input contains NaN or infinite values, or "
            "is too large (e.g. an angle whose square or a log-scale whose exponential "
            "overflows)")


def _check_outputs(k: Kernel, outs: Sequence[Array]) -> None:
    for o in outs:  # on the device of the outputs; skipped when their values are unknown
        if A.all_finite(o) is False:
            raise ValueError(_not_finite(k))


def _pack(ops: Any, comps: Any, shape: Shape, dt: Any, batch: Shape) -> Array:
    """Stack output components (a vector, or rows of a matrix) into ``(*batch, *shape)``."""
    flat = comps if len(shape) == 1 else [c for row in comps for c in row]
    if ops is NUMPY:
        if len(shape) == 2 and len(flat) > _WIDE:  # component-major, as in _chunked
            out = np.empty((len(flat), *batch), dt)
            for j, c in enumerate(flat):
                out[j] = c
            return np.moveaxis(out, 0, -1).reshape(*batch, *shape)
        out = np.empty((*batch, len(flat)), dt)
        for j, c in enumerate(flat):
            out[..., j] = c
        return out.reshape(*batch, *shape) if len(shape) > 1 else out
    xp = ops.xp
    like = next((c for c in flat if hasattr(c, "dtype")), None)
    arrays = [c if hasattr(c, "shape") else xp.asarray(c, dtype=dt, device=A._device(like))
              for c in flat]
    arrays = [xp.broadcast_to(c, batch) if tuple(c.shape) != batch else c for c in arrays]
    out = _stack_blocks(xp, arrays, ops.blocks) if ops.blocks else xp.stack(arrays, axis=-1)
    return xp.reshape(out, (*batch, *shape)) if len(shape) > 1 else out


def _stack_blocks(xp: Any, arrays: list, blocks: dict) -> Array:
    """``stack(arrays, -1)`` where each run of consecutive ``k * v_i`` products of one factor
    ``k`` (recorded by ``ops.times``) becomes one broadcast product ``k[..., None] * v``: the
    same multiplications, but XLA then computes ``k`` once rather than once per column."""
    parts, i = [], 0
    while i < len(arrays):
        b = blocks.get(id(arrays[i]))
        if b is None or b[0] is not arrays[i] or not hasattr(b[1], "shape"):
            parts.append(arrays[i][..., None])
            i += 1
            continue
        k, vs = b[1], [b[2]]
        i += 1
        while i < len(arrays):
            b = blocks.get(id(arrays[i]))
            if b is None or b[0] is not arrays[i] or b[1] is not k:
                break
            vs.append(b[2])
            i += 1
        shape = tuple(arrays[i - 1].shape)  # the batch shape
        v = xp.stack([xp.broadcast_to(c, shape) for c in vs], axis=-1)
        parts.append(xp.broadcast_to(k, shape)[..., None] * v)
    return parts[0] if len(parts) == 1 else xp.concat(parts, axis=-1)


def _chunked(k: Kernel, arrays: Sequence[np.ndarray], batch: Shape, dt: Any) -> Any:
    n = math.prod(batch)
    fn = k.fn
    if fn is None or n < 2 * CHUNK or any(a.ndim > 1 and a.shape[:-1] != batch for a in arrays):
        return None
    flats = [a.reshape(n, a.shape[-1]) if a.ndim > 1 else a.tolist() for a in arrays]
    # matrix outputs (Jacobians) are stored component-major, ``(r * c, n)``, and returned as
    # ``(*batch, r, c)`` views: each component is one contiguous write, where a row-major
    # result costs a transposition (1-2 ns per value, as much as computing it). Wide vectors
    # (parameters of product groups) stay row-major, filled through a transposed buffer.
    soa = [len(s) == 2 and math.prod(s) > _WIDE for s in k.outs]
    outs = [np.empty((math.prod(s), n) if m else (n, math.prod(s)), dt)
            for s, m in zip(k.outs, soa, strict=True)]
    width = max((s[0] for s, m in zip(k.outs, soa, strict=True) if not m), default=0)
    buf = np.empty((width, CHUNK), dtype=dt) if width > _WIDE else None
    # constant (Python number) components of component-major outputs are written once, after
    # the last chunk, as whole rows (runs of rows: one contiguous fill): ``j -> (value, from)``
    consts: list[dict[int, tuple[float, int]]] = [{} for _ in outs]
    for s in range(0, n, CHUNK):
        e = min(s + CHUNK, n)
        r = fn(NUMPY, *[A.components(f[s:e]) if isinstance(f, np.ndarray) else f
                               for f in flats])
        for res, out, shape, m, pend in zip([r] if k._flat else r, outs, k.outs, soa, consts,
                                            strict=True):
            if m:
                for j, c in enumerate(c for row in res for c in row):
                    tc = type(c)
                    if tc is float or tc is int:
                        p = pend.get(j)
                        if p is None or not _same(p[0], c):
                            if p is not None:
                                out[j, p[1]:s] = p[0]
                            pend[j] = (c, s)
                        continue
                    if pend and j in pend:
                        c0, s0 = pend.pop(j)
                        out[j, s0:s] = c0
                    out[j, s:e] = c
            elif buf is not None and len(res) > _WIDE:
                b = buf[:len(res), :e - s]
                for j, c in enumerate(res):
                    b[j] = c
                out[s:e] = b.T
            else:
                for j, c in enumerate(res if len(shape) == 1 else
                                      [c for row in res for c in row]):
                    out[s:e, j] = c
    for out, pend in zip(outs, consts, strict=True):
        _fill_constants(out, pend)
    return [o.T.reshape(*batch, *shape) if m else o.reshape(*batch, *shape)
            for o, shape, m in zip(outs, k.outs, soa, strict=True)]


def _same(a: float, b: float) -> bool:
    """``a`` and ``b`` are the same constant (``0.0`` and ``-0.0`` are not)."""
    return a == b and (a != 0 or math.copysign(1.0, a) == math.copysign(1.0, b))


def _fill_constants(out: np.ndarray, pend: dict[int, tuple[float, int]]) -> None:
    """Write the pending constant rows ``j -> (value, from)`` of a component-major ``out``;
    consecutive rows of one value that span the whole batch are one contiguous fill."""
    js = sorted(pend)
    i = 0
    while i < len(js):
        j0 = js[i]
        c, s0 = pend[j0]
        i += 1
        if s0:
            out[j0, s0:] = c
            continue
        j1 = j0 + 1
        while i < len(js) and js[i] == j1 and pend[j1][1] == 0 and _same(pend[j1][0], c):
            i += 1
            j1 += 1
        out[j0:j1] = c


def _run_arrays(k: Kernel, arrays: Sequence[np.ndarray]) -> Any:
    """A registered replacement (rows of ``(N, k)`` arrays), or an array-level kernel."""
    if k.impl is None:
        assert k.array_fn is not None
        return k.array_fn(*arrays)
    batch = np.broadcast_shapes(*(a.shape[:-1] for a in arrays))
    dt = np.result_type(*arrays)
    n = math.prod(batch)
    rows = [np.ascontiguousarray(np.broadcast_to(a, (*batch, a.shape[-1])).reshape(
        n, a.shape[-1]), dtype=dt) for a in arrays]
    res = k.impl(*rows)
    if not isinstance(res, tuple) or len(res) != len(k.outs):
        raise RuntimeError(f"replacement kernel {k.name} must return a tuple of "
                           f"{len(k.outs)} arrays")
    out = []
    for r, shape in zip(res, k.outs, strict=True):
        if r.shape != (n, *shape) or r.dtype != dt:
            raise RuntimeError(f"replacement kernel {k.name} returned {r.dtype} {r.shape}, "
                               f"expected {dt} {(n, *shape)}")
        out.append(r.reshape(*batch, *shape))
    if k.finite:
        try:
            _check_outputs(k, out)
        except ValueError:
            if k.fn is None:
                raise
            # the compiled sine and cosine reduce angles up to 2**26 only (NaN beyond, never a
            # wrong number): a non-finite result is decided by the generic kernel, which raises
            # where the inputs themselves overflow
            arrays = tuple(a.astype(dt, copy=False) for a in arrays)
            with np.errstate(over="ignore", invalid="ignore"):
                out = _numpy_batch(k, arrays, batch, dt)
            _check_outputs(k, out)
    if k.frozen:
        _setflags(out[0], write=False)
    return out[0] if k._flat else tuple(out)


def _run_foreign(k: Kernel, arrays: Sequence[Array]) -> Any:
    """torch or JAX arrays (NumPy constants among them move to the caller's backend)."""
    if k.fn is None:
        assert k.array_fn is not None
        return k.array_fn(*arrays)
    foreign = next(a for a in arrays if type(a) is not np.ndarray)
    arrays = [A.as_float_array(a, like=foreign) if type(a) is np.ndarray else a
              for a in arrays]
    batch = () if all(a.ndim == 1 for a in arrays) else \
        tuple(np.broadcast_shapes(*(tuple(a.shape[:-1]) for a in arrays)))
    if not batch:  # one element: on Python floats when no autograd/trace needs tensor ops
        lists = A.element_floats(arrays)
        if lists is not None:
            return _single_like(k, lists, foreign)
    o = A.kernel_ops(arrays, math.prod(batch))
    dt = foreign.dtype
    for a in arrays:
        if a.dtype != dt:  # mixed dtypes: evaluate in the promoted one (0-d operands included)
            dt = o.xp.result_type(dt, a.dtype)
    arrays = [a if a.dtype == dt else o.xp.astype(a, dt) for a in arrays]
    out = None
    if A.is_torch(foreign) and foreign.device.type == "cpu":
        out = _chunked_torch(o, k, arrays, batch, dt)
    if out is None:
        r = k.fn(o, *[A.components(a) for a in arrays])
        out = [_pack(o, x, s, dt, batch)
               for x, s in zip([r] if k._flat else r, k.outs, strict=True)]
    if k.finite:
        _check_outputs(k, out)
    return out[0] if k._flat else tuple(out)


def _single_like(k: Kernel, lists: list, like: Array) -> Any:
    """:func:`_single` with outputs of the array library of ``like`` (a CPU torch tensor)."""
    f = k._scalar or _scalar_function(k)
    try:
        r = f(*lists)
    except (ValueError, OverflowError, ZeroDivisionError) as e:
        raise ValueError(_not_finite(k)) from e
    outs = [r] if k._flat else r
    if k.finite and not math.isfinite(sum(_fsum(x) for x in outs)):
        raise ValueError(_not_finite(k))
    res = [A.floats_like(x, like) for x in outs]
    return res[0] if k._flat else tuple(res)


def _chunked_torch(o: Any, k: Kernel, arrays: Sequence[Array], batch: Shape, dt: Any) -> Any:
    """Large CPU tensors in chunks (cache-resident temporaries), stacked straight into the
    output (``out=``), or, when autograd (or a trace or transform) must see ordinary
    operations, joined with ``cat``."""
    n = math.prod(batch)
    fn = k.fn
    if fn is None or n < 2 * TORCH_CHUNK or \
            any(a.ndim > 1 and tuple(a.shape[:-1]) != batch for a in arrays):
        return None
    xp = o.xp
    flats = [xp.reshape(a, (n, a.shape[-1])) if a.ndim > 1 else a for a in arrays]
    into = A.plain_tensors(arrays)
    outs = [A.empty_like_rows(arrays[0], n, math.prod(s)) for s in k.outs] if into else []
    parts: list[list[Array]] = [[] for _ in k.outs]
    for s in range(0, n, TORCH_CHUNK):
        m = min(s + TORCH_CHUNK, n) - s
        r = fn(o, *[A.components(f[s:s + m] if f.ndim > 1 else f) for f in flats])
        for j, (res, shape) in enumerate(zip([r] if k._flat else r, k.outs, strict=True)):
            if into:
                flat = res if len(shape) == 1 else [c for row in res for c in row]
                A.stack_into(flat, outs[j][s:s + m])
            else:
                parts[j].append(_pack(o, res, shape, dt, (m,)))
    if not into:
        outs = [xp.concat(p, axis=0) for p in parts]
    return [xp.reshape(x, (*batch, *shape)) for x, shape in zip(outs, k.outs, strict=True)]
