"""The single-element fast path: one float64 NumPy element (Jacobians: compiled only).

Most calls on one element spend their time around the formula (dispatch, conversions, the output
array and object), not in it. For each group, :func:`build` makes one small function per
operation that handles exactly the common case, an element (or tangent vector, or point) whose
parameters are a one-dimensional float64 NumPy array, and returns ``None`` for everything else
(batches, float32, torch, JAX, another group, values that the formula rejects), so that the
caller falls through to the generic path, which keeps every check and error message.

Each function runs the kernel's traced straight-line float code (:mod:`microlie._trace`, the
same floating-point operations as the generic path) on the Python floats that single elements
keep beside their read-only ``params`` (``LieGroup._floats``). An output element is one object
holding the result's floats; its ``params`` array is made when first read (so a chain of
compositions builds no arrays). A tangent or point output is one fresh writable array. The
methods of :class:`~microlie.groups.base.LieGroup` call them as ``cls._one_<op>``; the compiled
extra replaces them with C functions of the same contract (:mod:`microlie._fast`), and adds
``_one_<op>_jac``: the operation with ``jac=True`` and right Jacobians, returning the tuple of
the public method (``None`` here: the generic path).
"""

from __future__ import annotations

import math
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
_array = np.array
_isfinite = math.isfinite
_new = object.__new__
_FAIL = (ValueError, OverflowError, ZeroDivisionError)


def build(cls: Any) -> dict[str, Callable[..., Any]]:
    """The single-element functions of group ``cls`` (one per entry of :data:`OPS`), in
    Python."""
    from .base import LieGroup

    slots = LieGroup.__dict__
    fns = {op: _make(cls, op, slots["_params"].__set__, slots["_floats"].__set__) for op in OPS}
    for op in OPS:  # with jac=True: only compiled (use_compiled); None sends to the generic path
        fns[f"{op}_jac"] = _none
    return fns


def _none(*args: Any) -> None:
    return None


def _floats_of(x: Any) -> list[float] | tuple[float, ...] | None:
    """The parameters of ``x`` as Python floats, if ``x`` is one float64 NumPy element."""
    p = x.params
    if type(p) is _ndarray and p.ndim == 1 and p.dtype is _F64:
        return p.tolist()  # type: ignore[no-any-return]
    return None


def _make(cls: Any, op: str, set_params: Callable[..., Any], set_floats: Callable[..., Any]
          ) -> Callable[..., Any]:
    """The function of ``cls.op``, written out as straight-line code (one Python frame around
    the traced formula: these functions are all overhead but the formula)."""
    kernel = cls._K[op]
    ins, out = OPS[op]
    ns: dict[str, Any] = {
        "cls": cls, "ndarray": _ndarray, "F64": _F64, "isfinite": _isfinite, "FAIL": _FAIL,
        "floats_of": _floats_of, "new": _new, "set_params": set_params, "set_floats": set_floats,
        "array": _array, "check": cls._range_check,
        "shape": {"t": cls._tshape, "v": cls._vshape}.get(ins[-1]),
    }

    def first_call(*lists: Any) -> Any:  # trace the formula on first use (not at import)
        ns["fn"] = K.scalar_function(kernel)
        return ns["fn"](*lists)

    ns["fn"] = first_call
    names = {"t": ["v"], "e": ["x"], "ee": ["x", "y"]}.get(ins, ["x", "v"])
    body = []
    for i, (kind, name) in enumerate(zip(ins, names, strict=True)):
        floats = "ab"[i]
        if kind == "e":
            if i:
                body.append(f"if type({name}) is not cls: return None")
            body += [f"{floats} = {name}._floats",
                     f"if {floats} is None and ({floats} := floats_of({name})) is None: "
                     "return None"]
        else:
            body += [f"if type({name}) is not ndarray or {name}.dtype is not F64 "
                     f"or {name}.shape != shape: return None",
                     f"{floats} = {name}.tolist()",
                     f"if not isfinite(sum({floats})): return None"]
            if kind == "t" and cls._range_check is not None:
                body.append(f"check({name})")
    body += ["try:", f"    r = fn({', '.join('ab'[:len(ins)])})", "except FAIL: return None"]
    if kernel.finite:
        body.append("if not isfinite(sum(r)): return None")
    if out == "e":
        body += ["obj = new(cls)", "set_params(obj, None)", "set_floats(obj, r)", "return obj"]
    else:
        body.append("out = array(r, F64)")
        if out == "t" and cls._range_check is not None:
            body.append("check(out)")
        body.append("return out")
    src = f"def one({', '.join(names)}):\n" + "".join(f"    {line}\n" for line in body)
    exec(compile(src, f"<single-element {cls.__name__}.{op}>", "exec"), ns)
    fn: Callable[..., Any] = ns["one"]
    fn.__name__ = fn.__qualname__ = f"{cls.__name__}._one_{op}"
    return fn


def use_compiled(one: Any) -> list[str]:
    """Use the one-element C functions of ``one`` (the module ``microlie._c._one``, generated
    from the same kernels) for the groups and operations it implements; return their names
    (``"SE3.exp"``, ...). Its functions follow the contract of the Python ones above (``None``
    for anything they do not handle)."""
    from .. import groups
    from .base import LieGroup

    classes = [getattr(groups, name) for name in one.GROUPS]
    one.setup(LieGroup.__dict__["_params"], LieGroup.__dict__["_floats"], *classes)
    done = []
    for name, fns in one.OPS.items():
        cls = getattr(groups, name)
        if cls._range_check is not None and cls._range_bound is None:
            continue  # a range check that the C functions cannot apply
        for op, fn in fns.items():
            if op in OPS:
                setattr(cls, f"_one_{op}", staticmethod(getattr(one, fn)))
                done.append(f"{name}.{op}")
        for op, fn in getattr(one, "JAC", {}).get(name, {}).items():
            if op in OPS:
                setattr(cls, f"_one_{op}_jac", staticmethod(getattr(one, fn)))
                done.append(f"{name}.{op}_jac")
    return done
