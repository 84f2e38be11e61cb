"""The array backend of a device solve: which library (PyTorch or JAX), dtype and device, and
the few operations the solver needs that the two spell differently.

Nothing here imports PyTorch or JAX until a caller's array is one of theirs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..._array import is_jax, is_torch, is_traced

__all__ = ["BACKENDS", "backend_of", "Backend", "make_backend", "torch_while"]

#: The backends a device solve runs on.
BACKENDS = ("torch", "jax")


def backend_of(x: Any) -> str:
    """The array library of ``x``: ``"torch"``, ``"jax"`` or ``"numpy"`` (anything else).

    Parameters
    ----------
    x : array_like
        An array, or a group element (its ``params``).

    Returns
    -------
    str

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.device import backend_of
    >>> backend_of(np.zeros(3)), backend_of([1.0])
    ('numpy', 'numpy')
    """
    x = getattr(x, "params", x)
    if is_torch(x):
        return "torch"
    if is_jax(x):
        return "jax"
    return "numpy"


class Backend:
    """One array library with a dtype and a device: converts arrays and supplies the
    operations a solve needs (scatter-add, Cholesky, ``where``...) under one spelling.

    Parameters
    ----------
    name : {"torch", "jax"}
        The library.
    dtype : str
        ``"float64"`` or ``"float32"``.
    device : optional
        A ``torch.device`` (or its string) for torch; a ``jax.Device`` or ``None`` (JAX's
        default) for JAX.

    Raises
    ------
    ValueError
        An unknown library or dtype, or float64 on JAX while ``jax_enable_x64`` is off (JAX
        would silently compute in float32; enable it with ``jax.config.update(
        "jax_enable_x64", True)`` before creating arrays, or pass float32 arrays).

    Examples
    --------
    >>> from microlie.optim.device.backend import Backend
    >>> b = Backend("torch", "float32")
    >>> b.asarray([1.0, 2.0]).dtype
    torch.float32
    """

    xp: Any  # the array namespace (torch, or jax.numpy)

    def __init__(self, name: str, dtype: str = "float64", device: Any = None) -> None:
        if name not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")
        if dtype not in ("float64", "float32"):
            raise ValueError(f"dtype must be 'float64' or 'float32', got {dtype!r}")
        self.name, self.dtype_name = name, dtype
        if name == "torch":
            import torch

            self.xp = torch
            self.dtype = getattr(torch, dtype)
            self.device = torch.device(device) if device is not None else torch.device("cpu")
            self.int = torch.int64
        else:
            import jax
            import jax.numpy as jnp

            if dtype == "float64" and not jax.config.read("jax_enable_x64"):
                raise ValueError(
                    "a float64 JAX solve needs jax_enable_x64 (JAX would compute in float32): "
                    "call jax.config.update('jax_enable_x64', True) at the start of the "
                    "program, or give float32 arrays for a float32 solve")
            self.xp = jnp
            self.dtype = getattr(jnp, dtype)
            self.device = device
            self.int = jnp.int32 if not jax.config.read("jax_enable_x64") else jnp.int64

    @property
    def eps(self) -> float:
        """The machine epsilon of the dtype."""
        return float(np.finfo(self.dtype_name).eps)

    def asarray(self, x: Any) -> Any:
        """``x`` as an array of this backend, dtype and device (a backend array is converted
        without a host copy; a torch tensor keeps its autograd graph)."""
        if self.name == "torch":
            t = self.xp
            if is_torch(x):
                return x.to(device=self.device, dtype=self.dtype)
            return t.as_tensor(np.array(x, dtype=self.dtype_name), device=self.device)
        import jax

        a = self.xp.asarray(x, dtype=self.dtype)
        return jax.device_put(a, self.device) if self.device is not None else a

    def index(self, x: Any) -> Any:
        """Integer indices on this backend's device."""
        a = np.asarray(x, dtype=np.int64)
        if self.name == "torch":
            return self.xp.as_tensor(a, device=self.device)
        return a  # JAX: a NumPy constant (never a tracer, whatever trace builds it)

    def zeros(self, shape: tuple[int, ...], like: Any = None) -> Any:
        """Zeros of this dtype (of ``like``'s dtype when given)."""
        dt = like.dtype if like is not None else self.dtype
        if self.name == "torch":
            return self.xp.zeros(shape, dtype=dt, device=self.device)
        return self.xp.zeros(shape, dtype=dt)

    def full(self, shape: tuple[int, ...], value: Any, dtype: Any = None) -> Any:
        """An array filled with ``value`` (this dtype unless ``dtype``)."""
        dt = self.dtype if dtype is None else dtype
        if self.name == "torch":
            return self.xp.full(shape, value, dtype=dt, device=self.device)
        return self.xp.full(shape, value, dtype=dt)

    def where(self, c: Any, a: Any, b: Any) -> Any:
        """Element-wise ``a if c else b``."""
        return self.xp.where(c, a, b)

    def scatter_add(self, out: Any, idx: Any, src: Any) -> Any:
        """``out`` with ``src`` rows added at ``idx`` along axis ``-2`` of ``out``
        (``out[..., idx[k], :] += src[..., k, :]``), functionally (``out`` unchanged)."""
        if self.name == "torch":
            return out.index_add(out.ndim - 2, idx, src)
        return out.at[..., idx, :].add(src)

    def take(self, x: Any, idx: Any, axis: int) -> Any:
        """``x`` indexed by ``idx`` along ``axis``."""
        if self.name == "torch":
            return x.index_select(axis % x.ndim, idx)
        return self.xp.take(x, idx, axis=axis)

    def cho_solve(self, A: Any, b: Any) -> tuple[Any, Any]:
        """Solve ``A x = b`` by Cholesky for a batch of SPD matrices ``(..., n, n)`` and
        ``b`` ``(..., n)``: ``(x, ok)`` with ``ok`` ``(...)`` bool (False: not positive
        definite; that ``x`` is garbage)."""
        if self.name == "torch":
            t = self.xp
            L, info = t.linalg.cholesky_ex(A)
            x = t.cholesky_solve(b.unsqueeze(-1), L).squeeze(-1)
            ok = (info == 0) & t.isfinite(x).all(-1)
            return x, ok
        import jax

        L = jax.numpy.linalg.cholesky(A)
        x = jax.scipy.linalg.cho_solve((L, True), b[..., None])[..., 0]
        return x, self.xp.isfinite(x).all(-1)

    def inv_spd(self, A: Any) -> Any:
        """Inverses of a batch of small SPD matrices (block-Jacobi blocks, landmark blocks);
        NaN where a matrix is not positive definite (its Cholesky factorisation fails), so that
        the step that needs it fails, as in the NumPy engine, and nothing raises."""
        if self.name == "torch":
            t = self.xp
            L, info = t.linalg.cholesky_ex(A)
            bad = (info != 0)[..., None, None]
            eye = t.eye(A.shape[-1], dtype=A.dtype, device=A.device)
            return t.where(bad, t.nan, t.cholesky_inverse(t.where(bad, eye, L)))
        import jax

        L = jax.numpy.linalg.cholesky(A)
        eye = self.xp.broadcast_to(self.xp.eye(A.shape[-1], dtype=A.dtype), A.shape)
        return jax.scipy.linalg.cho_solve((L, True), eye)

    def to_numpy(self, x: Any) -> np.ndarray:
        """A host NumPy copy (detached)."""
        if self.name == "torch":
            return x.detach().cpu().numpy()
        return np.asarray(x)

    def __repr__(self) -> str:
        return f"Backend({self.name!r}, {self.dtype_name!r}, device={self.device!r})"


def make_backend(arrays: list[Any], dtype: str | None = None, device: Any = None) -> Backend:
    """The backend of ``arrays`` (variable parameters): every array must be of one library;
    dtype and device are taken from the first unless given.

    Parameters
    ----------
    arrays : list
        torch tensors or JAX arrays (NumPy arrays among them are converted).
    dtype : {"float64", "float32"}, optional
        The solve's dtype (default: the first device array's).
    device : optional
        The device (default: the first device array's).

    Returns
    -------
    Backend

    Raises
    ------
    ValueError
        Both torch and JAX arrays (the message names both), or none of either.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie.optim.device.backend import make_backend
    >>> try:
    ...     make_backend([np.zeros(2)])
    ... except ValueError as e:
    ...     print(str(e)[:40])
    no torch tensor or JAX array among the v
    """
    kinds = {backend_of(a) for a in arrays} - {"numpy"}
    if len(kinds) > 1:
        raise ValueError("variables mix torch tensors and JAX arrays: give every variable "
                         "(and measurement) as arrays of one library, torch or jax")
    if not kinds:
        raise ValueError("no torch tensor or JAX array among the variables: the NumPy engine "
                         "(FactorGraph.optimize) solves NumPy problems")
    name = kinds.pop()
    first = next(getattr(a, "params", a) for a in arrays if backend_of(a) == name)
    if dtype is None:
        dtype = str(first.dtype).replace("torch.", "")
        if dtype not in ("float64", "float32"):
            raise ValueError(f"variables must be float32 or float64 arrays, got {dtype}")
    if device is None:
        if name == "torch":
            device = first.device
        else:
            devs = [] if is_traced(first) else list(getattr(first, "devices", lambda: [])())
            device = devs[0] if len(devs) == 1 else None
    return Backend(name, dtype, device)


def torch_while(cond: Any, body: Any, st: Any) -> Any:
    """``while cond(st): st = body(st)`` as torch's ``while_loop`` operator (what
    ``torch.compile(fullgraph=True)`` traces into one graph), on the flattened state (a pytree
    of tensors whose shapes and dtypes the body keeps).

    Parameters
    ----------
    cond : callable
        ``state -> bool tensor``.
    body : callable
        ``state -> state``.
    st : pytree
        The initial state.

    Returns
    -------
    pytree
        The final state.

    Examples
    --------
    >>> import torch
    >>> from microlie.optim.device.backend import torch_while
    >>> torch_while(lambda s: s["i"] < 3, lambda s: {"i": s["i"] + 1}, {"i": torch.tensor(0)})
    {'i': tensor(3)}
    """
    from torch._higher_order_ops import while_loop
    from torch.utils._pytree import tree_flatten, tree_unflatten

    leaves, spec = tree_flatten(st)

    def c(*flat: Any) -> Any:
        return cond(tree_unflatten(list(flat), spec))

    def b(*flat: Any) -> tuple:
        out = tree_flatten(body(tree_unflatten(list(flat), spec)))[0]
        ids = {id(a) for a in flat}  # the operator allows no output aliasing an input
        res = []
        for o in out:                # ... nor another output
            res.append(o.clone() if id(o) in ids else o.contiguous())
            ids.add(id(o))
        return tuple(res)

    seen: set[int] = set()
    fresh = []
    for a in leaves:  # no two carried tensors may alias; outputs keep the inputs' strides
        fresh.append(a.clone() if id(a) in seen else a.contiguous())
        seen.add(id(a))
    leaves = fresh
    return tree_unflatten(list(while_loop(c, b, tuple(leaves))), spec)
