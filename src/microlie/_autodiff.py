"""Jacobians of batched residual functions by JAX or PyTorch automatic differentiation.

With :mod:`microlie._array` and :mod:`microlie._linalg`, this is the only module that imports an
array library other than NumPy (lazily, on first use). The solver's ``CustomFactor(jac="jax")``
and ``jac="torch"`` call :func:`residual_jacobians`; everything they exchange is NumPy.

The residual function ``f(deltas, params, data)`` receives backend arrays: ``deltas[k]`` (the
right perturbations of argument ``k``, zero), ``params[k]`` and ``data[j]``. Its residuals are
differentiated with respect to the deltas at zero:

* ``"jax"``: ``f`` sees the rows of one residual (it is ``jax.vmap``-ed over the batch and
  ``jax.jit``-ted once); it returns ``dim`` values. Needs float64 in JAX (the solver works in
  float64): :func:`check_backend` raises ``ValueError`` when ``jax_enable_x64`` is off.
  microlie never changes that process-wide setting; the program enables it, at its start:
  ``jax.config.update("jax_enable_x64", True)``.
* ``"torch"``: ``f`` sees the whole batch (float64 CPU tensors) and returns ``(count, dim)``
  residuals; row ``m`` must depend on row ``m`` of the inputs only (one backward pass per
  residual component then gives every row's Jacobian).

>>> import numpy as np
>>> from microlie import _autodiff
>>> run = _autodiff.residual_jacobians(
...     "torch", lambda d, p, data: (p[0] + d[0]) ** 2, dofs=[2], count=3, dim=2)
>>> r, (J,) = run([np.ones((3, 2))], [], True)
>>> r.shape, J[0].tolist()
((3, 2), [[2.0, 0.0], [0.0, 2.0]])
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

__all__ = ["residual_jacobians", "check_backend", "BACKENDS"]

BACKENDS = ("jax", "torch")

Run = Callable[[Sequence[np.ndarray], Sequence[np.ndarray], bool], Any]


def residual_jacobians(backend: str, f: Callable[..., Any], dofs: Sequence[int], count: int,
                       dim: int) -> Run:
    """``run(params, data, jac)``: the residuals ``(count, dim)`` of ``f`` (NumPy), and with
    ``jac`` also one Jacobian ``(count, dim, dofs[k])`` per argument.

    Parameters
    ----------
    backend : {"jax", "torch"}
        The automatic differentiation to use (see the module docstring).
    f : callable
        ``f(deltas, params, data)``.
    dofs : sequence of int
        Tangent dimension of each argument (the size of its delta).
    count, dim : int
        Number of residuals and their dimension.

    Returns
    -------
    callable
        ``run(params, data, jac)`` with NumPy ``params`` (one ``(count, ...)`` array per
        argument) and ``data``; returns ``r`` or ``(r, [J_1, ...])``.

    Examples
    --------
    >>> import numpy as np
    >>> from microlie._autodiff import residual_jacobians
    >>> run = residual_jacobians("torch", lambda d, p, data: p[0] + 3 * d[0], [1], 2, 1)
    >>> run([np.zeros((2, 1))], [], True)[1][0].ravel().tolist()
    [3.0, 3.0]
    """
    if backend == "jax":
        return _jax(f, dofs, count, dim)
    if backend == "torch":
        return _torch(f, dofs, count, dim)
    raise ValueError(f"automatic differentiation backend must be one of {BACKENDS}, "
                     f"got {backend!r}")


def check_backend(backend: str, what: str) -> None:
    """Raise ``ValueError`` when ``backend`` cannot give the solver float64 Jacobians: JAX with
    ``jax_enable_x64`` off (its arrays are then float32, and Jacobians would keep about 7
    digits). microlie does not switch that process-wide flag: the program does, at its start.

    Parameters
    ----------
    backend : {"jax", "torch"}
        The automatic differentiation backend.
    what : str
        Who needs it, for the message.

    Examples
    --------
    >>> from microlie._autodiff import check_backend
    >>> check_backend("torch", "CustomFactor(jac='torch')")  # float64 tensors: always
    """
    if backend != "jax":
        return
    import jax

    if not jax.config.read("jax_enable_x64"):
        raise ValueError(
            f"{what} needs JAX in float64, and jax_enable_x64 is off: enable it at the start "
            "of the program, jax.config.update('jax_enable_x64', True) (microlie does not "
            "change this process-wide setting)")


def _jax(f: Callable[..., Any], dofs: Sequence[int], count: int, dim: int) -> Run:
    import jax
    import jax.numpy as jnp

    check_backend("jax", "automatic differentiation by JAX")

    def single(deltas, params, data):
        return jnp.asarray(f(deltas, params, data)).reshape(dim)

    def both(deltas, params, data):
        return single(deltas, params, data), jax.jacfwd(single)(deltas, params, data)

    batched = jax.jit(jax.vmap(both))
    forward = jax.jit(jax.vmap(single))

    def run(params, data, jac):
        ps = [jnp.asarray(p) for p in params]
        ds = [jnp.zeros((count, n)) for n in dofs]
        dd = [jnp.asarray(d) for d in data]
        if not jac:
            return np.asarray(forward(ds, ps, dd))
        r, Js = batched(ds, ps, dd)
        return np.asarray(r), [np.asarray(J) for J in Js]

    return run


def _torch(f: Callable[..., Any], dofs: Sequence[int], count: int, dim: int) -> Run:
    import torch

    def run(params, data, jac):
        ps = [torch.as_tensor(np.array(p, dtype=np.float64)) for p in params]
        ds = [torch.zeros((count, n), dtype=torch.float64, requires_grad=jac) for n in dofs]
        r = torch.as_tensor(f(ds, ps, [torch.as_tensor(d) for d in data]))
        r = r.reshape(count, dim)
        if not jac:
            return r.detach().numpy()
        # row m of r depends on row m of each delta only: one backward pass per residual
        # component gives every row's Jacobian at once
        Js = [np.zeros((count, dim, n)) for n in dofs]
        for a in range(dim):
            gs = torch.autograd.grad(r[:, a].sum(), ds, retain_graph=True, allow_unused=True)
            for J, g in zip(Js, gs, strict=True):
                if g is not None:
                    J[:, a, :] = g.detach().numpy()
        return r.detach().numpy(), Js

    return run
