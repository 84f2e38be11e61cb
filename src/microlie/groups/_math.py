"""Small shared pieces of component-wise mathematics.

Everything here works on *components* (Python floats, or arrays of one batch shape) with an
``ops`` object from :mod:`microlie._array`. Branches on values are ``ops.where`` selections, and
the branch not taken is always evaluated on a safe substitute input, so neither a value nor a
gradient can become NaN.
"""

from __future__ import annotations

from fractions import Fraction
from functools import reduce as _reduce
from math import comb, factorial
from operator import add as _add
from operator import mul as _mul
from operator import sub as _sub
from typing import Any

# Below this squared angle the closed forms that do not cancel (sin t / t, cos t) switch to a
# short Taylor polynomial: only the division by t (and sqrt's infinite slope at 0) matter.
TINY2 = 1e-8
# Below this squared angle, coefficients whose closed form cancels catastrophically
# ((t - sin t) / t^3 and friends) use a long Taylor polynomial (enough terms for ~1e-17).
SMALL2 = 1.0


def horner(x: Any, coeffs: tuple[float, ...]) -> Any:
    """``sum(coeffs[k] * x**k)``."""
    acc = coeffs[-1]
    for c in coeffs[-2::-1]:
        acc = acc * x + c
    return acc


def _series(term, n: int) -> tuple[float, ...]:
    return tuple(float(term(k)) for k in range(n))


# Taylor coefficients in t^2 (k = 0, 1, ...), generated from the exact series.
# sin(t/2)/t and cos(t/2): only used below TINY2.
HALF_SINC = _series(lambda k: Fraction((-1) ** k, 2 ** (2 * k + 1) * factorial(2 * k + 1)), 3)
HALF_COS = _series(lambda k: Fraction((-1) ** k, 4**k * factorial(2 * k)), 3)
SINC = _series(lambda k: Fraction((-1) ** k, factorial(2 * k + 1)), 3)
# (t - sin t) / t^3
C_T_SIN = _series(lambda k: Fraction((-1) ** k, factorial(2 * k + 3)), 11)
# (t^2 + 2 cos t - 2) / (2 t^4)
C_COS4 = _series(lambda k: Fraction((-1) ** k, factorial(2 * k + 4)), 11)
# (2 t - 3 sin t + t cos t) / (2 t^5)
C_SIN5 = _series(lambda k: Fraction((-1) ** k * (k + 1), factorial(2 * k + 5)), 11)


def _bernoulli(n: int) -> list[Fraction]:
    """Bernoulli numbers B_0..B_n (B_1 = -1/2), from sum_k C(m+1, k) B_k = 0."""
    b = [Fraction(1)]
    for m in range(1, n + 1):
        b.append(-sum((comb(m + 1, k) * b[k] for k in range(m)), Fraction(0)) / (m + 1))
    return b


_B = _bernoulli(24)
# (1 - (t/2) cot(t/2)) / t^2 = sum_{n>=1} |B_2n| t^(2n-2) / (2n)!
C_COT = _series(lambda k: abs(_B[2 * k + 2]) / factorial(2 * k + 2), 12)
# (h cot h) in powers of h^2: 1 - h^2/3 - h^4/45 ...  (x cot x = sum (-4)^n B_2n x^2n/(2n)!)
X_COT = _series(lambda k: (-4) ** k * _B[2 * k] / factorial(2 * k), 3)


def norm2(*c: Any) -> Any:
    acc = c[0] * c[0]
    for x in c[1:]:
        acc = acc + x * x
    return acc


def cross(a: tuple, b: tuple) -> tuple:
    return (
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    )


def dot(a: tuple, b: tuple) -> Any:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def hat3(v: tuple) -> tuple:
    z = 0.0 * v[0]
    return ((z, -v[2], v[1]), (v[2], z, -v[0]), (-v[1], v[0], z))


def poly_matrix(p: tuple, w: tuple, t2: Any, o: Any = None) -> tuple:
    """``p0 I + p1 hat(w) + p2 hat(w)^2`` written out (``t2 = |w|^2``); with ``ops`` ``o``
    its entries are output components (``o.add_out``/``o.sub_out``, see
    :mod:`microlie._array`), never to be used in further arithmetic."""
    p0, p1, p2 = p
    x, y, z = w
    bx, by, bz = p2 * x, p2 * y, p2 * z
    d = p0 - p2 * t2
    ax, ay, az = p1 * x, p1 * y, p1 * z
    xy, xz, yz = bx * y, bx * z, by * z
    add, sub = (_add, _sub) if o is None else (o.add_out, o.sub_out)
    return ((add(d, bx * x), sub(xy, az), add(xz, ay)),
            (add(xy, az), add(d, by * y), sub(yz, ax)),
            (sub(xz, ay), add(yz, ax), add(d, bz * z)))


def matmul(a: tuple, b: tuple) -> tuple:
    if len(b) == 3:  # the common case, written out
        b0, b1, b2 = b
        return tuple(tuple(r0 * x + r1 * y + r2 * z for x, y, z in zip(b0, b1, b2, strict=True))
                     for r0, r1, r2 in a)
    cols = tuple(zip(*b, strict=True))
    return tuple(tuple(_reduce(_add, map(_mul, row, col)) for col in cols) for row in a)


def matvec(a: tuple, v: tuple) -> tuple:
    return tuple(_reduce(_add, map(_mul, row, v)) for row in a)


def transpose(a: tuple) -> tuple:
    return tuple(tuple(a[i][j] for i in range(len(a))) for j in range(len(a[0])))


def scale(a: tuple, s: Any) -> tuple:
    return tuple(tuple(x * s for x in row) for row in a)


def add(*ms: tuple) -> tuple:
    return tuple(
        tuple(_sum(m[i][j] for m in ms) for j in range(len(ms[0][0]))) for i in range(len(ms[0]))
    )


def neg(a: tuple) -> tuple:
    return tuple(tuple(-x for x in row) for row in a)


def neg_out(o: Any, a: tuple) -> tuple:
    """``-a`` as output components (``o.negated``, see :mod:`microlie._array`)."""
    return tuple(tuple(o.negated(x) for x in row) for row in a)


def blocks(rows: list[list[tuple]]) -> tuple:
    """Assemble a block matrix from a grid of component matrices."""
    out = []
    for brow in rows:
        for r in range(len(brow[0])):
            out.append(tuple(x for blk in brow for x in blk[r]))
    return tuple(out)


def zeros(n: int, m: int, like: Any) -> tuple:
    z = 0.0 * like
    return tuple(tuple(z for _ in range(m)) for _ in range(n))


def eye(n: int, like: Any) -> tuple:
    z = 0.0 * like
    o = z + 1.0
    return tuple(tuple(o if i == j else z for j in range(n)) for i in range(n))


def _sum(it) -> Any:
    return _reduce(_add, it)


def det3(m: tuple) -> Any:
    return (
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    )


def adjugate3(m: tuple) -> tuple:
    return (
        (
            m[1][1] * m[2][2] - m[1][2] * m[2][1],
            m[0][2] * m[2][1] - m[0][1] * m[2][2],
            m[0][1] * m[1][2] - m[0][2] * m[1][1],
        ),
        (
            m[1][2] * m[2][0] - m[1][0] * m[2][2],
            m[0][0] * m[2][2] - m[0][2] * m[2][0],
            m[0][2] * m[1][0] - m[0][0] * m[1][2],
        ),
        (
            m[1][0] * m[2][1] - m[1][1] * m[2][0],
            m[0][1] * m[2][0] - m[0][0] * m[2][1],
            m[0][0] * m[1][1] - m[0][1] * m[1][0],
        ),
    )
