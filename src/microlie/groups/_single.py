"""The single-element fast path: one float64 NumPy element, no Jacobians.

Most calls on one element spend their time around the formula (dispatch, conversions, the output
array and object), not in it. For each group, :func:`build` makes one small function per
operation that handles exactly the common case, an element (or tangent vector, or point) whose
parameters are a one-dimensional float64 NumPy array, and returns ``None`` for everything else
(batches, float32, torch, JAX, another group, values that the formula rejects), so that the
caller falls through to the generic path, which keeps every check and error message.

Each function runs the kernel's traced straight-line float code (:mod:`microlie._trace`, the
same floating-point operations as the generic path), reads its inputs from the tuple of Python
floats that single elements keep beside their read-only ``params`` (``LieGroup._floats``), and
builds the output with one array and one object. The methods of :class:`~microlie.groups.base.
LieGroup` call them as ``cls._one_<op>``; the compiled extra replaces the SO(3)/SE(3) ones with
C functions of the same contract (:mod:`microlie._fast`).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import Any

import numpy as np

from .. import _kernels as K

__all__ = ["OPS", "build"]

# operation -> the kind of each input and of the output: "e" element, "t" tangent vector,
# "v" point
OPS: dict[str, tuple[str, str]] = {
    "exp": ("t", "e"), "log": ("e", "t"), "inverse": ("e", "e"), "compose": ("ee", "e"),
    "between": ("ee", "e"), "act": ("ev", "v"), "plus": ("et", "e"), "minus": ("ee", "t"),
}

_F64 = np.dtype(np.float64)
_ndarray = np.ndarray
_frombuffer = np.frombuffer
_array = np.array
_isfinite = math.isfinite
_new = object.__new__
_FAIL = (ValueError, OverflowError, ZeroDivisionError)


def build(cls: Any) -> dict[str, Callable[..., Any]]:
    """The single-element functions of group ``cls`` (one per entry of :data:`OPS`), in
    Python."""
    from .base import LieGroup

    slots = LieGroup.__dict__
    return {op: _make(cls, op, slots["params"].__set__, slots["_floats"].__set__) for op in OPS}


def _floats_of(x: Any) -> list[float] | tuple[float, ...] | None:
    """The parameters of ``x`` as Python floats, if ``x`` is one float64 NumPy element."""
    p = x.params
    if type(p) is _ndarray and p.ndim == 1 and p.dtype is _F64:
        return p.tolist()  # type: ignore[no-any-return]
    return None


def _make(cls: Any, op: str, set_params: Callable[..., Any], set_floats: Callable[..., Any]
          ) -> Callable[..., Any]:
    kernel = cls._K[op]
    ins, out = OPS[op]
    fn: Callable[..., Any] | None = None  # the traced function, made on first use
    pack = struct.Struct(f"{cls.param_dim}d").pack
    shape = {"t": cls._tshape, "v": cls._vshape}.get(ins[-1])
    check = cls._range_check  # on tangent inputs and outputs (None: no limit)
    finite = kernel.finite
    to_element = out == "e"

    def result(*lists: Any) -> Any:
        """The output of the formula (None: let the generic path report the failure)."""
        nonlocal fn
        if fn is None:
            fn = K.scalar_function(kernel)
        try:
            r = fn(*lists)
        except _FAIL:
            return None
        if finite and not _isfinite(sum(r)):
            return None
        if to_element:
            obj = _new(cls)
            set_params(obj, _frombuffer(pack(*r)))
            set_floats(obj, r)
            return obj
        a = _array(r, _F64)
        if check is not None and out == "t":
            check(a)
        return a

    def vector(v: Any) -> list[float] | None:
        """A tangent vector or point as floats, if it is one finite float64 NumPy vector."""
        if type(v) is not _ndarray or v.dtype is not _F64 or v.shape != shape:
            return None
        vals: list[float] = v.tolist()
        if not _isfinite(sum(vals)):
            return None
        if check is not None and ins[-1] == "t":
            check(v)
        return vals

    def one_t(tau: Any) -> Any:
        t = vector(tau)
        return None if t is None else result(t)

    def one_e(x: Any) -> Any:
        a = x._floats
        if a is None and (a := _floats_of(x)) is None:
            return None
        return result(a)

    def one_ee(x: Any, y: Any) -> Any:
        if type(y) is not cls:
            return None
        a, b = x._floats, y._floats
        if a is None and (a := _floats_of(x)) is None:
            return None
        if b is None and (b := _floats_of(y)) is None:
            return None
        return result(a, b)

    def one_e_vector(x: Any, v: Any) -> Any:  # an element and a tangent vector or a point
        a = x._floats
        if a is None and (a := _floats_of(x)) is None:
            return None
        b = vector(v)
        return None if b is None else result(a, b)

    variants: dict[str, Callable[..., Any]] = {"t": one_t, "e": one_e, "ee": one_ee}
    one = variants.get(ins, one_e_vector)
    one.__name__ = one.__qualname__ = f"{cls.__name__}_one_{op}"
    return one


def use_compiled(one: Any) -> list[str]:
    """Use the one-element C functions of ``one`` (the module ``microlie_fast._one``) for the
    groups and operations it implements; return their names (``"SE3.exp"``, ...). Its functions
    follow the contract of the Python ones above (``None`` for anything they do not handle)."""
    from .. import groups
    from .base import LieGroup

    one.setup(LieGroup.__dict__["params"], LieGroup.__dict__["_floats"], groups.SO3, groups.SE3)
    done = []
    for name, fns in one.OPS.items():
        cls = getattr(groups, name)
        if cls._range_check is not None:  # the C functions do not check tangent ranges
            continue
        for op, fn in fns.items():
            if op in OPS:
                setattr(cls, f"_one_{op}", staticmethod(getattr(one, fn)))
                done.append(f"{name}.{op}")
    return done
