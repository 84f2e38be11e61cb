"""A kernel traced once into straight-line code: Python for single elements, C for the build.

A single NumPy element is evaluated on Python floats (see :mod:`microlie._kernels`). Running the
component function itself costs mostly Python overhead: helper calls, tuple building, generator
expressions. :func:`trace` runs the component function once on symbols instead and records every
arithmetic operation, comparison, selection and elementary function in order (a
:class:`Trace`). :func:`compile_scalar` compiles the record into one Python function of local
float variables: exactly the floating-point operations of the component function on
:data:`microlie._array.SCALAR`, in the same order (bit-identical results), two to three times
faster. :mod:`microlie._codegen` writes the same record as C (the compiled kernels).

A kernel whose code takes a Python branch on a value (``if x > 0``, ``and``) cannot be traced:
:func:`trace` and :func:`compile_scalar` return ``None`` and the caller keeps the component
function.
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Sequence
from typing import Any

from ._array import times

__all__ = ["Trace", "trace", "compile_scalar"]

# node operations: binary operators, comparisons, unary and elementary functions, selection
BINARY = ("+", "-", "*", "/")
COMPARE = ("<", "<=", ">", ">=")
FUNCTIONS = ("sin", "cos", "tan", "sqrt", "atan2", "exp", "expm1", "log", "abs")


class Trace:
    """The record of one trace: ``nodes[i] = (op, args)`` defines the value ``v<i>``; an
    argument is a name (``"v3"``, an input ``"a0_2"``) or a Python number (or bool);
    ``outputs`` holds the returned structure (a tuple of components, or of rows of them) with
    names or numbers as leaves; ``sizes`` the length of each input."""

    def __init__(self, sizes: Sequence[int]) -> None:
        self.nodes: list[tuple[str, tuple[Any, ...]]] = []
        self.sizes = tuple(sizes)
        self.outputs: Any = None

    def new(self, op: str, *args: Any) -> _Sym:
        self.nodes.append((op, tuple(_arg(a) for a in args)))
        return _Sym(self, f"v{len(self.nodes) - 1}")

    def uses(self) -> dict[str, int]:
        """How often each name is read (an output counts twice)."""
        n: dict[str, int] = {}
        for _, args in self.nodes:
            for a in args:
                if type(a) is str:
                    n[a] = n.get(a, 0) + 1
        for a in flatten(self.outputs):
            if type(a) is str:
                n[a] = n.get(a, 0) + 2
        return n

    def python(self) -> list[str]:
        """The body of the Python function: a value used once is written into its single use
        (fewer loads and stores, and inside ``a if c else b`` only the branch taken is
        evaluated); the others are assigned to local variables."""
        uses = self.uses()
        text: dict[str, str] = {}
        lines = []
        for i, (op, args) in enumerate(self.nodes):
            name = f"v{i}"
            a = [text.get(x, x) if type(x) is str else _py_const(x) for x in args]
            if op in BINARY or op in COMPARE:
                expr = f"{a[0]} {op} {a[1]}"
            elif op == "neg":
                expr = f"-{a[0]}"
            elif op == "where":
                expr = f"{a[1]} if {a[0]} else {a[2]}"
            elif op == "abs":
                expr = f"abs({a[0]})"
            else:
                expr = f"_{op}({', '.join(a)})"
            if uses.get(name, 0) == 1 and len(expr) < 400:
                text[name] = f"({expr})"
            elif uses.get(name, 0):
                lines.append(f"    {name} = {expr}")

        def structure(x: Any) -> str:
            if isinstance(x, tuple | list):
                return "(" + "".join(f"{structure(c)}, " for c in x) + ")"
            return text.get(x, x) if type(x) is str else _py_const(x)

        return [*lines, f"    return {structure(self.outputs)}"]


def flatten(x: Any) -> list[Any]:
    """The leaves of an output structure, in order (matrices row by row)."""
    if isinstance(x, tuple | list):
        return [c for y in x for c in flatten(y)]
    return [x]


def _arg(x: Any) -> Any:
    if isinstance(x, _Sym):
        return x.name
    if isinstance(x, bool | int | float):
        return x
    raise TypeError(f"cannot trace a {type(x).__name__}")


def _py_const(x: Any) -> str:
    if isinstance(x, bool):
        return "True" if x else "False"
    if isinstance(x, float) and not math.isfinite(x):
        return f"float({str(x)!r})"
    return repr(x)


class _Sym:
    """A traced float (or bool) value: every operation appends one node to the record."""

    __slots__ = ("rec", "name")

    def __init__(self, rec: Trace, name: str) -> None:
        self.rec = rec
        self.name = name

    def _bin(self, op: str, other: Any, reverse: bool = False) -> _Sym:
        return self.rec.new(op, other, self) if reverse else self.rec.new(op, self, other)

    def __add__(self, o: Any) -> _Sym: return self._bin("+", o)  # noqa: E704
    def __radd__(self, o: Any) -> _Sym: return self._bin("+", o, True)  # noqa: E704
    def __sub__(self, o: Any) -> _Sym: return self._bin("-", o)  # noqa: E704
    def __rsub__(self, o: Any) -> _Sym: return self._bin("-", o, True)  # noqa: E704
    def __mul__(self, o: Any) -> _Sym: return self._bin("*", o)  # noqa: E704
    def __rmul__(self, o: Any) -> _Sym: return self._bin("*", o, True)  # noqa: E704
    def __truediv__(self, o: Any) -> _Sym: return self._bin("/", o)  # noqa: E704
    def __rtruediv__(self, o: Any) -> _Sym: return self._bin("/", o, True)  # noqa: E704
    def __lt__(self, o: Any) -> _Sym: return self._bin("<", o)  # noqa: E704
    def __le__(self, o: Any) -> _Sym: return self._bin("<=", o)  # noqa: E704
    def __gt__(self, o: Any) -> _Sym: return self._bin(">", o)  # noqa: E704
    def __ge__(self, o: Any) -> _Sym: return self._bin(">=", o)  # noqa: E704
    def __neg__(self) -> _Sym: return self.rec.new("neg", self)  # noqa: E704
    def __abs__(self) -> _Sym: return self.rec.new("abs", self)  # noqa: E704

    def __bool__(self) -> bool:
        raise TypeError("a Python branch on a traced value")


class _Ops:
    """The ``ops`` object of a trace: the functions of :data:`microlie._array.SCALAR`."""

    is_scalar = True

    def __init__(self, rec: Trace) -> None:
        self.rec = rec

    def sin(self, x: Any) -> _Sym: return self.rec.new("sin", x)  # noqa: E704
    def cos(self, x: Any) -> _Sym: return self.rec.new("cos", x)  # noqa: E704
    def tan(self, x: Any) -> _Sym: return self.rec.new("tan", x)  # noqa: E704
    def sqrt(self, x: Any) -> _Sym: return self.rec.new("sqrt", x)  # noqa: E704
    def atan2(self, y: Any, x: Any) -> _Sym: return self.rec.new("atan2", y, x)  # noqa: E704
    def exp(self, x: Any) -> _Sym: return self.rec.new("exp", x)  # noqa: E704
    def expm1(self, x: Any) -> _Sym: return self.rec.new("expm1", x)  # noqa: E704
    def log(self, x: Any) -> _Sym: return self.rec.new("log", x)  # noqa: E704
    def abs(self, x: Any) -> _Sym: return self.rec.new("abs", x)  # noqa: E704
    def abs1(self, x: Any) -> _Sym: return self.rec.new("abs", x)  # noqa: E704

    def where(self, cond: Any, a: Any, b: Any) -> Any:
        return self.rec.new("where", cond, a, b)

    times = staticmethod(times)

    # output components (see microlie._array.ArrayOps.negated): plain arithmetic here
    negated = staticmethod(operator.neg)
    add_out = staticmethod(operator.add)
    sub_out = staticmethod(operator.sub)
    mul_out = staticmethod(operator.mul)

    def select(self, cond: Any, f: Any, g: Any, *args: Any) -> Any:
        a, b = f(*args), g(*args)  # both recorded; only the branch taken runs (see python())
        if isinstance(a, tuple):
            return tuple(self.where(cond, x, y) for x, y in zip(a, b, strict=True))
        return self.where(cond, a, b)

    @staticmethod
    def zeros_like(x: Any) -> float:
        return 0.0

    @staticmethod
    def ones_like(x: Any) -> float:
        return 1.0


_NAMESPACE = {"_sin": math.sin, "_cos": math.cos, "_tan": math.tan, "_sqrt": math.sqrt,
              "_atan2": math.atan2, "_exp": math.exp, "_expm1": math.expm1, "_log": math.log}


def trace(fn: Callable[..., Any], sizes: Sequence[int]) -> Trace | None:
    """The record of ``fn(ops, *inputs)`` on inputs of lengths ``sizes`` (input ``i``'s
    component ``j`` is named ``a<i>_<j>``), or ``None`` if ``fn`` branches on a value."""
    rec = Trace(sizes)
    ins = [[_Sym(rec, f"a{i}_{j}") for j in range(n)] for i, n in enumerate(sizes)]
    try:
        out = fn(_Ops(rec), *ins)
        rec.outputs = _leaves(out)
    except TypeError:
        return None
    return rec


def _leaves(x: Any) -> Any:
    if isinstance(x, tuple | list):
        return tuple(_leaves(c) for c in x)
    return _arg(x)


_INPUT = re.compile(r"^a(\d+)_(\d+)$")


def compile_scalar(fn: Callable[..., Any], sizes: Sequence[int]) -> Callable[..., Any] | None:
    """``fn(ops, *inputs)`` as a function of lists of floats (one per input, of lengths
    ``sizes``) that returns what ``fn`` returns on :data:`microlie._array.SCALAR`; ``None`` if
    ``fn`` cannot be traced."""
    rec = trace(fn, sizes)
    if rec is None:
        return None
    args = ", ".join(f"a{i}" for i in range(len(sizes)))
    unpack = [f"    {', '.join(f'a{i}_{j}' for j in range(n))}, = a{i}"
              for i, n in enumerate(sizes)]
    src = "\n".join([f"def kernel({args}):", *unpack, *rec.python()])
    ns: dict[str, Any] = dict(_NAMESPACE)
    exec(compile(src, f"<traced {getattr(fn, '__qualname__', fn)}>", "exec"), ns)
    kernel: Callable[..., Any] = ns["kernel"]
    return kernel
