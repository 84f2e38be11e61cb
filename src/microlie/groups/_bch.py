"""The Baker-Campbell-Hausdorff series ``Log(Exp(a) Exp(b))`` on any group (MATH.md section 10).

    Log(Exp(a) Exp(b)) = a + b + 1/2 [a, b] + 1/12 [a, [a, b]] - 1/12 [b, [a, b]]
                         - 1/24 [b, [a, [a, b]]] + O(|a, b|^5)

The first bracket term is ``1/2 [a, b]`` (the source notes' ``1/12`` is an erratum).
"""

from __future__ import annotations

from typing import Any

from .._array import Array

ORDERS = (1, 2, 3, 4)


def bch(G: Any, a: Any, b: Any, order: int) -> Array:
    """The BCH series of ``Log(Exp(a) Exp(b))`` truncated after the terms of degree ``order``
    in ``(a, b)`` (1 to 4); the error is ``O(|a, b|^(order + 1))``."""
    if order not in ORDERS:
        raise ValueError(f"BCH order must be one of {ORDERS}, got {order!r}")
    a = G._tangent(a)
    b = G._tangent(b, like=a)
    z = a + b
    if order == 1:
        return z
    ab = G.bracket(a, b)
    z = z + 0.5 * ab
    if order == 2:
        return z
    a_ab = G.bracket(a, ab)
    z = z + (1.0 / 12.0) * (a_ab - G.bracket(b, ab))
    if order == 3:
        return z
    return z - (1.0 / 24.0) * G.bracket(b, a_ab)


def bch_first_order(G: Any, a: Any, b: Any, small: str) -> Array:
    """``Log(Exp(a) Exp(b))`` to first order in the small argument: ``Jl(b)^-1 a + b`` for
    ``small="a"``, ``a + Jr(a)^-1 b`` for ``small="b"`` (the other argument may be large)."""
    if small not in ("a", "b"):
        raise ValueError(f"small must be 'a' or 'b', got {small!r}")
    a = G._tangent(a)
    b = G._tangent(b, like=a)
    if small == "a":
        return (G.jl_inv(b) @ a[..., :, None])[..., 0] + b
    return a + (G.jr_inv(a) @ b[..., :, None])[..., 0]
