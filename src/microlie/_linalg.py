"""Batched linear algebra over NumPy, PyTorch and JAX arrays.

The small surface the rest of the library needs on matrices of shape ``(*batch, n, k)``:
transposes, identities, solves, factorisations, determinants, diagonals and shape helpers. Every
function keeps the backend of its input (NumPy in, NumPy out; torch autograd intact; JAX
jit-able) and its dtype and device. Together with :mod:`microlie._array` this is the only
module that knows which array library an array belongs to.

Batch axes broadcast the NumPy way. Right-hand sides of :func:`solve` and :func:`cho_solve` are
*matrices* ``(..., n, k)``: solve for a vector ``b`` as ``solve(a, b[..., None])[..., 0]``.

>>> import numpy as np
>>> from microlie import _linalg as L
>>> a = np.array([[4.0, 2.0], [2.0, 3.0]])
>>> bool(np.allclose(L.cho_solve(L.cholesky(a), L.eye(2, a)), np.linalg.inv(a)))
True
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from . import _array as A
from ._array import Array

__all__ = [
    "mT", "eye", "zeros", "solve", "inv", "cholesky", "cho_solve", "solve_triangular", "eigh",
    "eigvalsh", "det", "slogdet", "symmetrize", "diag", "diag_embed", "sqrt_psd",
    "broadcast_to", "broadcast_batch", "numel", "reshape", "concat", "stack", "where", "asarray",
    "same_backend", "copy", "readonly", "concrete", "register_pytree", "activate_pytrees",
]


_NP = (np.ndarray, np.generic)


def _is_np(*arrays: Array) -> bool:
    for a in arrays:
        if not isinstance(a, _NP):
            return False
    return True


def _xp(*arrays: Array) -> Any:
    return A.namespace(*arrays)


def _la(name: str, *arrays: Array) -> Any:
    """``name`` from ``numpy.linalg`` or the arrays' namespace's ``linalg``, applied."""
    mod = np.linalg if _is_np(*arrays) else _xp(*arrays).linalg
    return getattr(mod, name)(*arrays)


# ---------------------------------------------------------------------------- shapes


def mT(a: Array) -> Array:
    """Transpose of the last two axes (``(..., n, k) -> (..., k, n)``; a view where possible)."""
    if isinstance(a, np.ndarray):
        return a.swapaxes(-1, -2)
    if A.is_torch(a):
        return a.transpose(-1, -2)
    return _xp(a).matrix_transpose(a)


def numel(a: Array) -> int:
    """Number of elements of ``a`` (``math.prod(a.shape)``; 1 for a scalar)."""
    return math.prod(tuple(a.shape))


def reshape(a: Array, shape: Sequence[int]) -> Array:
    """``a`` with the shape ``shape`` (a view where possible)."""
    if isinstance(a, np.ndarray):
        return a.reshape(tuple(shape))
    return _xp(a).reshape(a, tuple(shape))


def broadcast_to(a: Array, shape: Sequence[int]) -> Array:
    """``a`` broadcast to ``shape`` (returned unchanged when it already has that shape; NumPy
    gives a read-only view)."""
    shape = tuple(shape)
    if tuple(a.shape) == shape:
        return a
    if _is_np(a):
        return np.broadcast_to(a, shape)
    return _xp(a).broadcast_to(a, shape)


def broadcast_batch(*mats: Array) -> list[Array]:
    """Broadcast the batch axes (all but the last two) of matrices to a common batch shape."""
    batch = np.broadcast_shapes(*(tuple(m.shape[:-2]) for m in mats))
    return [broadcast_to(m, (*batch, *m.shape[-2:])) for m in mats]


def eye(n: int, like: Array, batch_shape: Sequence[int] = ()) -> Array:
    """The ``n x n`` identity in the backend, dtype and device of ``like``, broadcast to
    ``(*batch_shape, n, n)`` (a read-only view for NumPy when ``batch_shape`` is not empty)."""
    if _is_np(like):
        out = np.eye(n, dtype=like.dtype)
    else:
        out = _xp(like).eye(n, dtype=like.dtype, device=A._device(like))
    return broadcast_to(out, (*batch_shape, n, n)) if batch_shape else out


def zeros(shape: Sequence[int], like: Array) -> Array:
    """Zeros of ``shape`` in the backend, dtype and device of ``like``."""
    if _is_np(like):
        return np.zeros(tuple(shape), dtype=like.dtype)
    return _xp(like).zeros(tuple(shape), dtype=like.dtype, device=A._device(like))


def concat(arrays: Sequence[Array], axis: int = -1) -> Array:
    """Join arrays of one backend along an existing axis."""
    arrays = list(arrays)
    if _is_np(*arrays):
        return np.concatenate(arrays, axis=axis)
    return _xp(*arrays).concat(arrays, axis=axis)


def stack(arrays: Sequence[Array], axis: int = 0) -> Array:
    """Join arrays of one backend along a new axis."""
    arrays = list(arrays)
    if _is_np(*arrays):
        return np.stack(arrays, axis=axis)
    return _xp(*arrays).stack(arrays, axis=axis)


def where(cond: Any, a: Any, b: Any) -> Array:
    """Element-wise ``a if cond else b``; ``cond`` may be a NumPy boolean array (it is moved to
    the backend of ``a``/``b``), ``a`` or ``b`` a Python scalar."""
    arrays = [x for x in (a, b) if hasattr(x, "shape")]
    if _is_np(*arrays):
        return np.where(cond, a, b)
    like = arrays[0]
    if isinstance(cond, (np.ndarray, np.generic, bool)):
        cond = _xp(like).asarray(np.asarray(cond), device=A._device(like))
    return _xp(like).where(cond, a, b)


def asarray(x: Any, like: Array) -> Array:
    """``x`` (numbers, lists, NumPy arrays) as an array of the backend, dtype and device of
    ``like``."""
    if _is_np(like):
        return np.asarray(x, dtype=like.dtype)
    return _xp(like).asarray(np.asarray(x), dtype=like.dtype, device=A._device(like))


def same_backend(a: Array, b: Array) -> bool:
    """True when ``a`` and ``b`` belong to the same array library (Python numbers and NumPy
    arrays count as NumPy)."""
    return A.namespace(a) is A.namespace(b)


def diag(a: Array) -> Array:
    """The diagonals ``(..., n)`` of matrices ``(..., n, n)``."""
    if _is_np(a):
        return np.diagonal(a, axis1=-2, axis2=-1)
    return _xp(a).linalg.diagonal(a)


def diag_embed(v: Array) -> Array:
    """Diagonal matrices ``(..., n, n)`` with diagonals ``v`` ``(..., n)``."""
    n = int(v.shape[-1])
    return v[..., :, None] * eye(n, v)


def symmetrize(a: Array) -> Array:
    """``(a + a^T) / 2`` over the last two axes."""
    return 0.5 * (a + mT(a))


def copy(a: Array) -> Array:
    """A copy that does not share memory with ``a`` (NumPy: read-only; torch: ``clone``, so
    gradients still flow; JAX arrays are immutable and returned as they are)."""
    if _is_np(a):
        out = np.array(a, copy=True)
        out.flags.writeable = False
        return out
    if A.is_torch(a):
        return a.clone()
    return a


def readonly(a: Array) -> Array:
    """``a`` itself, or for a writable NumPy array a read-only view of it (for arrays the
    library created and hands out; copy a caller's array with :func:`copy`)."""
    if isinstance(a, np.ndarray) and a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


def concrete(a: Array) -> np.ndarray | None:
    """The values of ``a`` as a NumPy array, or ``None`` when they are not known:
    :func:`microlie._array.host_values` (which it is, for anything but NumPy-like input)."""
    if _is_np(a):
        return np.asarray(a)
    return A.host_values(a)


# ---------------------------------------------------------------------------- solves


def solve(a: Array, b: Array) -> Array:
    """``x`` with ``a x = b``; ``a`` ``(..., n, n)``, ``b`` ``(..., n, k)`` (batch broadcast).

    NumPy and torch raise their ``LinAlgError`` on an exactly singular ``a``; JAX returns
    non-finite values."""
    if _is_np(a, b):
        return np.linalg.solve(a, b)  # broadcasts the batch itself
    return _la("solve", *broadcast_batch(a, b))


def inv(a: Array) -> Array:
    """Inverses of square matrices ``(..., n, n)``."""
    return _la("inv", a)


def cholesky(a: Array) -> Array:
    """Lower Cholesky factors ``L`` with ``L L^T = a`` of symmetric positive definite matrices.

    NumPy and torch raise their ``LinAlgError`` when ``a`` is not positive definite; JAX
    returns NaN. Callers that need a clear error check definiteness first."""
    return _la("cholesky", a)


def solve_triangular(t: Array, b: Array, *, lower: bool = True) -> Array:
    """``x`` with ``t x = b`` for triangular ``t`` ``(..., n, n)`` and ``b`` ``(..., n, k)``."""
    if _is_np(t, b):
        # NumPy has no batched triangular solve: LU of a triangular matrix is backward stable
        return np.linalg.solve(t, b)
    t, b = broadcast_batch(t, b)
    if A.is_torch(t):
        import torch

        return torch.linalg.solve_triangular(t, b, upper=not lower)
    import jax.scipy.linalg as jsl

    return jsl.solve_triangular(t, b, lower=lower)


def cho_solve(chol: Array, b: Array) -> Array:
    """``x`` with ``(L L^T) x = b`` from the lower Cholesky factor ``L = chol``."""
    y = solve_triangular(chol, b, lower=True)
    return solve_triangular(mT(chol), y, lower=False)


# ---------------------------------------------------------------------------- spectra


def eigh(a: Array) -> tuple[Array, Array]:
    """Eigenvalues (ascending, ``(..., n)``) and orthonormal eigenvectors (columns,
    ``(..., n, n)``) of symmetric matrices (only the lower triangle is read)."""
    w, v = _la("eigh", a)
    return w, v


def eigvalsh(a: Array) -> Array:
    """Eigenvalues (ascending, ``(..., n)``) of symmetric matrices."""
    return _la("eigvalsh", a)


def det(a: Array) -> Array:
    """Determinants ``(...)`` of square matrices ``(..., n, n)``."""
    return _la("det", a)


def slogdet(a: Array) -> tuple[Array, Array]:
    """``(sign, log|det a|)`` of square matrices, each of shape ``(...)``."""
    sign, logabs = _la("slogdet", a)
    return sign, logabs


def sqrt_psd(a: Array) -> Array:
    """``S`` with ``S S^T = a`` for symmetric positive semi-definite ``a`` (from :func:`eigh`,
    negative rounding-level eigenvalues clipped to 0; not triangular)."""
    w, v = eigh(a)
    if _is_np(w):
        return v * np.sqrt(np.clip(w, 0.0, None))[..., None, :]
    xp = _xp(w)
    return v * xp.sqrt(xp.clip(w, 0.0, None))[..., None, :]


# ---------------------------------------------------------------------------- JAX pytrees

_PYTREES: list[tuple[type, Callable[..., Any], Callable[..., Any]]] = []
_REGISTERED: set[type] = set()


def register_pytree(cls: type, flatten: Callable[..., Any], unflatten: Callable[..., Any]
                    ) -> None:
    """Make ``cls`` a JAX pytree once JAX is in use (now if it is already imported), without
    importing JAX. ``flatten(obj) -> (children, aux)``, ``unflatten(aux, children) -> obj``."""
    _PYTREES.append((cls, flatten, unflatten))
    activate_pytrees()


def activate_pytrees(like: Array | None = None) -> None:
    """Register the classes given to :func:`register_pytree` with JAX when JAX is imported
    (and ``like``, if given, is a JAX array); a no-op once done."""
    if len(_REGISTERED) == len(_PYTREES) or "jax" not in sys.modules:
        return
    if like is not None:
        if not A.is_jax(like):
            return
        A.namespace(like)  # registers the group classes as well
    import jax

    for cls, flatten, unflatten in _PYTREES:
        if cls not in _REGISTERED:
            jax.tree_util.register_pytree_node(cls, flatten, unflatten)
            _REGISTERED.add(cls)
