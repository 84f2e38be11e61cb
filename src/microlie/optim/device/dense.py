"""Dense normal equations and the damped dense Cholesky step (small problems, and batches of
them): ``H = sum A_k^T A_l`` and ``g = sum A_k^T e`` summed block by block into
``(B, size, size)`` and ``(B, size)``, then ``(H + diag(d)) dx = -g`` by a batched Cholesky
factorisation."""

from __future__ import annotations

from typing import Any

from .problem import DeviceProblem, Linear, add_last, eye_like, transpose

__all__ = ["normal_equations", "dense_step", "gradient"]


def gradient(problem: DeviceProblem, lin: Linear) -> Any:
    """``g = J^T e`` ``(B, size)`` (whitened, the gradient of the cost).

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    lin : Linear
        Its linearisation.

    Returns
    -------
    array

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.dense import gradient
    >>> g = FactorGraph()
    >>> _ = g.add(PriorFactor(g.add_variables(torch.ones((1, 2)).double()), 0, [0.0, 0.0]))
    >>> p = DeviceProblem.from_graph(g)
    >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    >>> gradient(p, p.linearize(th, [a[None] for a in p.initial()])).tolist()
    [[1.0, 1.0]]
    """
    return problem.vjp(lin, lin.e)


def normal_equations(problem: DeviceProblem, lin: Linear) -> tuple[Any, Any]:
    """The dense ``H`` ``(B, size, size)`` and ``g`` ``(B, size)`` of a linearisation.

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    lin : Linear
        Its linearisation.

    Returns
    -------
    H, g : arrays

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.dense import normal_equations
    >>> g = FactorGraph()
    >>> x = g.add_variables(torch.ones((1, 2)).double())
    >>> _ = g.add(PriorFactor(x, 0, [0.0, 0.0], Isotropic(2, 0.5)))
    >>> p = DeviceProblem.from_graph(g)
    >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    >>> H, grad = normal_equations(p, p.linearize(th, [a[None] for a in p.initial()]))
    >>> H.tolist(), grad.tolist()
    ([[[4.0, 0.0], [0.0, 4.0]]], [[4.0, 4.0]])
    """
    be = problem.backend
    n1 = problem.size + 1
    B = lin.e[0].shape[0]
    # one product J^T J per factor batch (J: its blocks side by side) and one scatter of them
    # all: on torch eager a product per argument pair costs a batched matmul call per small
    # block, and an out-of-place scatter per pair copies all of H each time (together 3-4x)
    src = []
    for A in lin.A:
        J = A[0] if len(A) == 1 else be.xp.concatenate(A, axis=-1)
        src.append((transpose(be, J) @ J).reshape(B, -1))
    H = be.zeros((B, n1 * n1), like=lin.e[0])
    src = src[0] if len(src) == 1 else be.xp.concatenate(src, axis=-1)
    if be.name == "torch":   # into the fresh zeros in place (no copy of H; compile-safe)
        H = H.index_add_(1, problem.dense_index(), src)
    else:
        H = add_last(be, H, problem.dense_index(), src)
    H = H.reshape(B, n1, n1)[:, :-1, :-1]
    return H, gradient(problem, lin)


def dense_step(problem: DeviceProblem, H: Any, g: Any, damping: Any) -> tuple[Any, Any]:
    """The step of ``(H + diag(damping)) dx = -g`` by Cholesky, per problem of the batch.

    Parameters
    ----------
    problem : DeviceProblem
        The problem (its backend).
    H : array
        ``(B, size, size)``.
    g : array
        ``(B, size)``.
    damping : array
        ``(B, size)`` added to the diagonal.

    Returns
    -------
    dx : array
        ``(B, size)``.
    ok : array
        ``(B,)`` bool: the damped matrix was positive definite.

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.dense import dense_step
    >>> g = FactorGraph()
    >>> _ = g.add(PriorFactor(g.add_variables(torch.ones((1, 2)).double()), 0, [0.0, 0.0]))
    >>> p = DeviceProblem.from_graph(g)
    >>> H = torch.eye(2, dtype=torch.float64)[None]
    >>> grad = torch.ones((1, 2)).double()
    >>> dx, ok = dense_step(p, H, grad, torch.full((1, 2), 3.0))  # (1 + 3) dx = -1
    >>> dx.tolist(), ok.tolist()
    ([[-0.25, -0.25]], [True])
    """
    be = problem.backend
    if be.name == "torch":  # one new (B, n, n) array, not an identity product and a sum
        t = be.xp
        A = t.diagonal_scatter(H, H.diagonal(dim1=-2, dim2=-1) + damping.to(H.dtype),
                               dim1=-2, dim2=-1)
        return be.cho_solve(A, -g)
    return be.cho_solve(H + eye_like(be, H) * damping[..., None, :], -g)
