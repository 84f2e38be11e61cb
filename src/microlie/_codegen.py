"""The compiled group kernels, generated from the component formulas (run at build time).

Every element-wise kernel of :data:`microlie._kernels.KERNELS` (values and fused Jacobians of
every group) is traced once (:func:`microlie._trace.trace`: the same record that becomes the
single-element Python code) and written as one C function of doubles::

    static inline void se3_exp_jac(const double *a0, const double *a1, double *o, ptrdiff_t s)

Component ``j`` of input ``i`` is read at ``ai[j * s]``; the outputs are written one after the
other, component ``j`` (matrices row by row) at ``o[j * s]``. With ``s = 1`` that is one element
in rows; with ``s`` the block length it is a structure-of-arrays block, the form that GCC
vectorises inside ``#pragma omp simd`` loops. A value selection of the formula
(``ops.where``/``ops.select``: the small-angle branches) becomes a C conditional on two values
that are both computed: the side not taken may hold NaN or an infinity (no floating-point trap
is enabled), never the selected result. The operations are those of the component function in
the same order (no reassociation; the build compiles without contraction to fused
multiply-adds), so a compiled kernel agrees with the generic one to rounding of the elementary
functions. Elementary functions are called as ``lm_sin``, ``lm_cos``, ``lm_tan``, ``lm_atan2``,
``lm_exp``, ``lm_expm1``, ``lm_log`` from ``vecmath.h`` (microlie's own vectorisable kernels).

:func:`generate` writes ``lie_kernels.h``: the functions, and the table ``LK_KERNELS(X)``
(one ``X(fn, "Group.op", nin, k0, k1, nout, r0, r1, r2, c0, c1, c2, finite, frozen, plain)`` per
kernel: ``rj, cj`` the shape of output ``j`` (``cj = 0`` for a vector), ``plain`` 1 where a row
loop is cheaper than structure-of-arrays blocks), ``LK_GROUPS(X)`` (one ``X(G_SE3, "SE3",
param_dim)`` per group), ``LK_ONE(X)`` (the one-element operations of
:data:`microlie.groups._single.OPS`) and ``LK_JAC(X)`` (the same with ``jac=True``).
``python -m microlie._codegen OUTDIR`` does the same from a build script.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Sequence
from typing import Any

from ._trace import BINARY, COMPARE, Trace, flatten, trace

__all__ = ["generate", "kernel_c", "c_name"]

_FUNC = {"sin": "lm_sin", "cos": "lm_cos", "tan": "lm_tan", "atan2": "lm_atan2",
         "exp": "lm_exp", "expm1": "lm_expm1", "log": "lm_log", "sqrt": "sqrt", "abs": "fabs"}
_CALLS = ("sin", "cos", "tan", "atan2", "exp", "expm1", "log")


def _plain(k: Any, rec: Trace) -> bool:
    """Whether the batched kernel runs as a loop over rows rather than over structure-of-arrays
    blocks. Measured at N = 1e6 (x86-64-v2, v3 and v4 builds): rows win for one output without
    elementary functions (products, actions: the block copies would double their time) and for
    rows of at most 2 components (SO2); with elementary functions and rows of 3 or 4 components
    the row loop vectorises through shuffles that cost more than the copies (SO3.log 9.5 ns per
    element as rows, 5.0 as blocks with AVX-512; SO3.exp 33 against 13 at x86-64-v2), and rows
    of 6 or more vectorise only as blocks."""
    if len(k.outs) != 1:
        return False
    calls = any(op in _CALLS for op, _ in rec.nodes)
    return not calls or max(*rec.sizes, math.prod(k.outs[0])) <= 2


def c_name(name: str) -> str:
    """The C name of kernel ``name``: ``"SE3.exp_jac"`` -> ``"se3_exp_jac"``."""
    return name.replace(".", "_").lower()


def _const(x: Any) -> str:
    if isinstance(x, bool):
        return "1" if x else "0"
    x = float(x)
    if math.isnan(x):
        return "NAN"
    if math.isinf(x):
        return "INFINITY" if x > 0 else "(-INFINITY)"
    text = repr(x)
    return f"({text})" if text.startswith("-") else text


def kernel_c(fn_name: str, rec: Trace, doc: str = "") -> str:
    """The C function ``fn_name`` of the traced kernel ``rec`` (see the module docstring)."""
    bools: set[str] = set()
    lines = [f"/* {doc} */"] if doc else []
    lines.append(f"LK_FN void {fn_name}(const double *restrict a0, const double *restrict a1, "
                 "double *restrict o, ptrdiff_t s) {")
    live = _live(rec)
    for i in range(2):
        n = rec.sizes[i] if i < len(rec.sizes) else 0
        used = [j for j in range(n) if f"a{i}_{j}" in live]
        if not used:
            lines.append(f"    (void)a{i};")
        for j in used:
            lines.append(f"    const double a{i}_{j} = a{i}[{j} * s];")

    def ref(x: Any) -> str:
        return x if type(x) is str else _const(x)

    for k, (op, args) in enumerate(rec.nodes):
        name = f"v{k}"
        if name not in live:
            continue
        a = [ref(x) for x in args]
        ctype = "double"
        if op in BINARY:
            expr = f"{a[0]} {op} {a[1]}"
        elif op in COMPARE:
            expr, ctype = f"{a[0]} {op} {a[1]}", "int"
        elif op == "neg":
            expr = f"-{a[0]}"
        elif op == "where":
            if args[1] in bools and args[2] in bools:
                ctype = "int"
            expr = f"{a[0]} ? {a[1]} : {a[2]}"
        else:
            expr = f"{_FUNC[op]}({', '.join(a)})"
        if ctype == "int":
            bools.add(name)
        lines.append(f"    const {ctype} {name} = {expr};")
    for j, x in enumerate(flatten(rec.outputs)):
        lines.append(f"    o[{j} * s] = {ref(x)};")
    lines.append("}")
    return "\n".join(lines) + "\n"


def _live(rec: Trace) -> set[str]:
    """The names that the outputs depend on (the record keeps dead values: a component
    function may compute what only another output of its family uses)."""
    live = {x for x in flatten(rec.outputs) if type(x) is str}
    for k in range(len(rec.nodes) - 1, -1, -1):
        if f"v{k}" in live:
            live.update(x for x in rec.nodes[k][1] if type(x) is str)
    return live


_HEAD = """/* GENERATED by microlie._codegen from the component formulas of microlie's groups: do
 * not edit (see src/microlie/_codegen.py). */
#pragma once
#include <math.h>
#include <stddef.h>
#include "vecmath.h"
#ifndef LK_FN
#define LK_FN static inline __attribute__((always_inline, unused))
#endif
"""


def _sizes(k: Any) -> tuple[int, ...]:
    G = k.group
    dims = {"p": "param_dim", "t": "dof", "v": "point_dim"}
    try:
        return tuple(int(getattr(G, dims[kind])) for kind in k.ins)
    except (KeyError, AttributeError):
        return ()


#: the groups whose kernels are compiled (products of groups and user groups are not)
BUILT_IN = ("SO2", "SE2", "SO3", "SE3", "Sim3", "SE23")


def _kernels() -> list[tuple[Any, Trace]]:
    from . import groups  # noqa: F401  (defines every group's kernels)
    from ._kernels import KERNELS

    out = []
    for name in sorted(KERNELS):
        k = KERNELS[name]
        if getattr(k.group, "__name__", "") not in BUILT_IN:
            continue  # microlie's groups only (a program or a Product may define more)
        sizes = _sizes(k)
        if k.fn is None or not sizes or len(sizes) > 2 or len(k.outs) > 3:
            continue
        rec = trace(k.fn, sizes)
        if rec is not None:
            out.append((k, rec))
    return out


def source() -> str:
    """The text of ``lie_kernels.h``."""
    from .groups._single import OPS

    parts = [_HEAD]
    table: list[str] = []
    one: list[str] = []
    jac: list[str] = []
    groups: dict[str, int] = {}
    for k, rec in _kernels():
        fn = c_name(k.name)
        parts.append(kernel_c(fn, rec, f"{k.name}: inputs {k.ins}, outputs {k.outs}"))
        nin = len(rec.sizes)
        ks = [*rec.sizes, 0][:2]
        outs = [*k.outs, *[()] * (3 - len(k.outs))]
        rows = [s[0] if s else 0 for s in outs]
        cols = [s[1] if len(s) == 2 else 0 for s in outs]
        plain = int(_plain(k, rec))
        table.append(f"    X({fn}, \"{k.name}\", {nin}, {ks[0]}, {ks[1]}, {len(k.outs)}, "
                     f"{', '.join(map(str, rows))}, {', '.join(map(str, cols))}, "
                     f"{int(k.finite)}, {int(k.frozen)}, {plain})")
        gname, op = k.name.split(".")
        groups.setdefault(gname, k.group.param_dim)
        base = op.removesuffix("_jac")
        check = getattr(k.group, "_range_check", None)
        bound = getattr(k.group, "_range_bound", None)
        if base in OPS and (check is None or bound is not None):
            ins, res = OPS[base]
            kin = rec.sizes[-1] if ins[-1] in "tv" else 0
            kout = math.prod(k.outs[0])
            # the range check as data: the component of the tangent input (last input) and of
            # the tangent output whose magnitude must not exceed the bound (-1: none)
            b_in = bound[0] if bound and ins[-1] == "t" else -1
            b_out = bound[0] if bound and res == "t" else -1
            row = (f"{fn}, G_{gname.upper()}, \"{ins}\", {kin}, {int(res == 'e')}, {kout}, "
                   f"{int(k.finite)}, {b_in}, {b_out}, {_const(bound[1] if bound else 0.0)}")
            if op == base:
                one.append(f"    X({row})")
            else:  # the Jacobians (1 or 2 matrices), and an identity for compose and between
                eye = k.group.dof if base in ("compose", "between") else 0
                mats = [*k.outs[1:], (0, 0)][:2]
                jac.append(f"    X({row}, {len(k.outs) - 1}, {mats[0][0]}, {mats[0][1]}, "
                           f"{mats[1][0]}, {mats[1][1]}, {eye})")
    parts.append("/* X(fn, name, nin, k0, k1, nout, r0, r1, r2, c0, c1, c2, finite, frozen, "
                 "plain) */\n#define LK_KERNELS(X) \\\n" + " \\\n".join(table) + "\n")
    gl = [f"    X(G_{g.upper()}, \"{g}\", {d})" for g, d in groups.items()]
    parts.append("/* X(id, name, param_dim) */\n#define LK_GROUPS(X) \\\n" + " \\\n".join(gl)
                 + "\n")
    parts.append("/* X(fn, group, inputs, vector width, element output, output width, finite, "
                 "range: component of the tangent input, of the tangent output (-1: none), "
                 "largest magnitude) */\n#define LK_ONE(X) \\\n" + " \\\n".join(one) + "\n")
    parts.append("/* X(fn, group, inputs, vector width, element output, output width, finite, "
                 "range (3 entries as in LK_ONE), number of Jacobians, their shapes (r1, c1, r2, "
                 "c2), identity size) */\n"
                 "#define LK_JAC(X) \\\n" + " \\\n".join(jac) + "\n")
    return "\n".join(parts)


def generate(outdir: str) -> list[str]:
    """Write the generated C (``lie_kernels.h``) into ``outdir`` (created if missing); a file
    whose text is unchanged is not rewritten (no needless rebuild). Returns the paths.

    Examples
    --------
    >>> import tempfile, os
    >>> d = tempfile.mkdtemp()
    >>> [os.path.basename(p) for p in generate(d)]
    ['lie_kernels.h']
    >>> "se3_exp_jac" in open(os.path.join(d, "lie_kernels.h")).read()
    True
    """
    os.makedirs(outdir, exist_ok=True)
    path = os.path.join(outdir, "lie_kernels.h")
    text = source()
    try:
        with open(path) as f:
            same = f.read() == text
    except OSError:
        same = False
    if not same:
        with open(path, "w") as f:
            f.write(text)
    return [path]


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m microlie._codegen OUTDIR``."""
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1:
        print("usage: python -m microlie._codegen OUTDIR", file=sys.stderr)
        return 2
    for p in generate(args[0]):
        print(p)
    return 0


if __name__ == "__main__":
    sys.exit(main())
