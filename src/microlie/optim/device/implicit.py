"""Gradients through a device solve: implicit differentiation of the optimum, or unrolling.

A solve maps the factors' data ``theta`` (measurements, square-root informations) and a start
``x0`` to an optimum ``x*``. At the optimum the gradient of the cost in the tangent chart of
``x*`` is zero:

``g(0, theta) = 0``,  ``g(delta, theta) = d/d delta F(x* (+) delta, theta)``,

with ``F = 0.5 sum_k r_k^T Omega_k r_k`` (:meth:`DeviceProblem.cost`). Differentiating this
identity (the implicit function theorem) gives the derivative of the optimum, ``d delta /
d theta = -H^-1 d g / d theta``, with ``H = d g / d delta`` the Hessian of the cost in the
tangent chart. The vector-Jacobian product of the solve is then one linear solve with ``H`` at
the optimum, however many iterations the solve took:

``u = R^T xbar`` (``R = d params(x* (+) delta) / d delta``),  ``H w = u``,
``thetabar = -(d g / d theta)^T w``.

**Which Hessian.** ``H`` is the *full* Hessian of the cost, ``J^T Omega J + sum_k (Omega_k r_k)
. d^2 r_k``, computed by the backend's automatic differentiation (forward over reverse on JAX,
double backward on torch), not the Gauss-Newton matrix ``J^T Omega J`` the solve steps with.
The two agree only where every residual is zero at the optimum; with noisy measurements the
second-order term changes the gradient at the level of the residuals (a relative error of
4.7e-2 in the tests, where the full Hessian meets central finite differences to 1e-9). At a
strict minimum ``H`` is positive definite. One dense ``(size, size)`` Hessian per problem is
built (``size`` HVPs, batched over problems), so implicit gradients are for problems of up to a
few thousand unknowns.

**What receives gradients.** ``theta`` (every array: measurement parameters, ``"L"``,
observations, constant intrinsics) and ``x0``. The optimum does not depend (locally) on where
the solve starts: the gradient with respect to the starting values of free variables is zero.
Fixed variables are data of the problem: their values receive the gradient through the cost and
through the output, where they are returned as given. (Held tangent components of otherwise
free variables are treated as free variables' starts: no gradient.) Measurement parameters of a
group (a unit quaternion) are differentiated as the formulas are written; the component that
leaves the group (the quaternion's norm) is not meaningful: project gradients on the group
(perturb ``Z (+) eps``) to use them.

**Accuracy.** The gradient is exact at an exact optimum. A solve stopped by loose tolerances
(GTSAM's ``rel_tol = 1e-5``) leaves a gradient of the cost of that order, and the implicit
gradient is then that far from the derivative of the returned values; solve with tight
tolerances (``rel_tol=abs_tol=0``: until no decrease) when the gradient matters.

**Unrolling** (``differentiate="unroll"``) differentiates the iterations themselves: on torch the
ordinary autograd graph of the loop, on JAX the loop run as a fixed number of masked tries
(``LMOptions(loop="fixed")``, a ``lax.fori_loop``: a ``while_loop`` cannot be reverse
differentiated). Its cost grows with the iterations (every try is kept for the backward pass).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

__all__ = ["DIFFERENTIATE", "ImplicitSpec", "implicit_jax", "implicit_torch",
           "solve_differentiable", "spec_of", "traced_result"]

#: the ways gradients go through a solve
DIFFERENTIATE = ("implicit", "unroll")


@dataclass(frozen=True)
class ImplicitSpec:
    """What implicit differentiation needs of a solve (arrays with a leading problem axis).

    Parameters
    ----------
    solve : callable
        ``solve(theta, x0) -> (x, aux)``: the optimum from ``x0`` (a list of ``(B, n_k,
        P_k)`` parameter arrays, one per batch of variables) and a pytree of arrays passed
        through without gradients (the solve's report). Its own derivatives are not used.
    cost : callable
        ``cost(theta, x) -> (B,)``: the cost the solve minimises, twice differentiable by the
        backend.
    retract : callable
        ``retract(x, dx) -> x'``: ``x (+) dx`` with ``dx`` ``(B, size)`` (the chart the
        Hessian is taken in; any smooth retraction gives the same gradient at an optimum).
    size : int
        The number of unknowns of one problem.
    fixed : sequence of (bool array or None)
        Per batch of variables, ``(n_k,)`` True where the variable is held constant (its
        output is its value in ``x0``); ``None``: all free.

    Examples
    --------
    >>> import numpy as np
    >>> spec = ImplicitSpec(solve=None, cost=None, retract=None, size=-1, fixed=[None])
    Traceback (most recent call last):
    ...
    ValueError: ImplicitSpec: size must be an integer >= 0, got -1
    """

    solve: Any
    cost: Any
    retract: Any
    size: int
    fixed: Sequence[Any]

    def __post_init__(self) -> None:
        if isinstance(self.size, bool) or not isinstance(self.size, int | np.integer) \
                or self.size < 0:
            raise ValueError(f"ImplicitSpec: size must be an integer >= 0, got {self.size!r}")


def spec_of(problem: Any, options: Any = None) -> ImplicitSpec:
    """The :class:`ImplicitSpec` of a :class:`~microlie.optim.device.DeviceProblem` solved by
    :func:`~microlie.optim.device.solve` with ``options``.

    Parameters
    ----------
    problem : DeviceProblem
        The structure.
    options : LMOptions, optional
        The solve's options.

    Returns
    -------
    ImplicitSpec

    Examples
    --------
    >>> import torch
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.from_params(torch.tensor([[0.0, 0, 1, 0]] * 2).double()),
    ...                     fixed=[0])
    >>> _ = g.add(PriorFactor(x, 1, SE2.identity()))
    >>> s = spec_of(DeviceProblem.from_graph(g))
    >>> s.size, s.fixed[0].tolist()
    (3, [True, False])
    """
    from .lm import solve

    def run(theta: Any, x0: list) -> tuple[list, Any]:
        x, info = solve(problem, theta, list(x0), options)
        return list(x), info

    return ImplicitSpec(run, problem.cost, problem.retract, int(problem.size),
                        [~np.asarray(b.free, bool) for b in problem.blocks])


def _where_fixed(xp: Any, fixed: Sequence[Any], xs: Sequence[Any], x0: Sequence[Any]) -> list:
    """``x0`` at fixed variables, ``xs`` elsewhere (differentiable in both)."""
    out = []
    for xk, x0k, fk in zip(xs, x0, fixed, strict=True):
        if fk is None or not np.any(fk):
            out.append(xk)
        else:
            m = xp.asarray(np.asarray(fk)[:, None]) if xp.__name__.startswith("jax") else \
                xp.as_tensor(np.asarray(fk)[:, None], device=xk.device)
            out.append(xp.where(m, x0k, xk))
    return out


# ---------------------------------------------------------------------------------------- JAX


def implicit_jax(spec: ImplicitSpec) -> Callable[[Any, list], tuple[list, Any]]:
    """``spec.solve`` with a ``jax.custom_vjp``: reverse-mode gradients by implicit
    differentiation (module docstring).

    Parameters
    ----------
    spec : ImplicitSpec
        The solve, its cost, retraction and layout.

    Returns
    -------
    callable
        ``f(theta, x0) -> (x, aux)`` with the values of ``spec.solve``; ``theta`` any pytree
        of JAX arrays, ``x0`` a list of ``(B, n_k, P_k)`` arrays. Traceable by ``jax.jit``.

    Examples
    --------
    >>> import jax, jax.numpy as jnp
    >>> # minimise 0.5 |x - a|^2 + 0.5 |x - b|^2 per problem: x* = (a + b) / 2
    >>> spec = ImplicitSpec(
    ...     solve=lambda th, x0: ([(th[0] + th[1]) / 2], None),
    ...     cost=lambda th, x: 0.5 * ((x[0] - th[0]) ** 2 + (x[0] - th[1]) ** 2).sum((1, 2)),
    ...     retract=lambda x, dx: [x[0] + dx[:, :, None]], size=1, fixed=[None])
    >>> f = implicit_jax(spec)
    >>> a, b = jnp.array([[[1.0]]]), jnp.array([[[3.0]]])
    >>> float(jax.grad(lambda a: f((a, b), [jnp.zeros((1, 1, 1))])[0][0].sum())(a)[0, 0, 0])
    0.5
    """
    import jax

    @jax.custom_vjp
    def f(theta: Any, x0: list) -> tuple[list, Any]:
        x, aux = spec.solve(theta, list(x0))
        return list(x), aux

    def fwd(theta: Any, x0: list) -> tuple[tuple[list, Any], tuple]:
        x, aux = f(theta, x0)
        return (x, aux), (x, theta, list(x0))

    def bwd(res: tuple, cot: tuple) -> tuple:
        x, theta, x0 = res
        return _jax_vjp(spec, x, theta, x0, list(cot[0]))

    f.defvjp(fwd, bwd)
    return f  # type: ignore[return-value]


def _jax_vjp(spec: ImplicitSpec, x: list, theta: Any, x0: list, xbar: list) -> tuple:
    import jax
    import jax.numpy as jnp

    B, n = int(x[0].shape[0]), int(spec.size)
    dtype = x[0].dtype

    def evaluate(dx: Any, x0_: list) -> list:
        return _where_fixed(jnp, spec.fixed, spec.retract(x, dx), x0_)

    def grad_dx(dx: Any, th: Any, x0_: list) -> Any:
        return jax.grad(lambda d: jnp.sum(spec.cost(th, evaluate(d, x0_))))(dx)

    d0 = jnp.zeros((B, n), dtype)
    _, ev = jax.vjp(evaluate, d0, x0)
    u, x0_through = ev(xbar)
    _, gv = jax.vjp(lambda th, x0_: grad_dx(d0, th, x0_), theta, x0)
    if n == 0:
        theta_bar, x0_bar = gv(d0)
    else:
        eye = jnp.eye(n, dtype=dtype)
        # H[b] by forward over reverse: one tangent direction for all problems at once
        H = jax.vmap(lambda e: jax.jvp(lambda d: grad_dx(d, theta, x0), (d0,),
                                       (jnp.broadcast_to(e, (B, n)),))[1], out_axes=2)(eye)
        w = jnp.linalg.solve(H, u[..., None])[..., 0]
        theta_bar, x0_bar = gv(-w)
    return theta_bar, [a + b for a, b in zip(x0_bar, x0_through, strict=True)]


# -------------------------------------------------------------------------------------- torch


def implicit_torch(spec: ImplicitSpec) -> Callable[[Any, list], tuple[list, Any]]:
    """``spec.solve`` as a ``torch.autograd.Function``: backward by implicit differentiation
    (module docstring).

    Parameters
    ----------
    spec : ImplicitSpec
        The solve, its cost, retraction and layout.

    Returns
    -------
    callable
        ``f(theta, x0) -> (x, aux)`` with the values of ``spec.solve``; ``theta`` a pytree
        (tuples, lists, dicts) of tensors, ``x0`` a list of ``(B, n_k, P_k)`` tensors. When
        tensors of ``theta`` or ``x0`` require grad, ``x`` carries the gradient of the optimum
        (``aux``, a pytree of tensors, none).

    Examples
    --------
    >>> import torch
    >>> spec = ImplicitSpec(
    ...     solve=lambda th, x0: ([(th[0] + th[1]) / 2], None),
    ...     cost=lambda th, x: 0.5 * ((x[0] - th[0]) ** 2 + (x[0] - th[1]) ** 2).sum((1, 2)),
    ...     retract=lambda x, dx: [x[0] + dx[:, :, None]], size=1, fixed=[None])
    >>> a = torch.tensor([[[1.0]]], dtype=torch.float64, requires_grad=True)
    >>> b = torch.tensor([[[3.0]]], dtype=torch.float64)
    >>> (x,), _ = implicit_torch(spec)((a, b), [torch.zeros(1, 1, 1, dtype=torch.float64)])
    >>> x.sum().backward(); float(a.grad.flatten()[0])
    0.5
    """
    import torch
    from torch.utils import _pytree as pytree

    class _Solve(torch.autograd.Function):
        @staticmethod
        def forward(ctx: Any, trees: Any, n_x0: int, *tensors: Any) -> Any:  # type: ignore[override]
            leaves = list(tensors[:len(tensors) - n_x0])
            x0 = list(tensors[len(tensors) - n_x0:])
            theta = pytree.tree_unflatten(leaves, trees[0])
            with torch.no_grad():
                x, aux = spec.solve(theta, x0)
            x = [t.detach() for t in x]
            aux_leaves, aux_tree = pytree.tree_flatten(aux)
            trees[1] = aux_tree
            ctx.theta_tree, ctx.n_x0, ctx.n_x = trees[0], n_x0, len(x)
            ctx.save_for_backward(*tensors, *x)
            ctx.mark_non_differentiable(*[a for a in aux_leaves if isinstance(a, torch.Tensor)])
            return (*x, *aux_leaves)

        @staticmethod
        def backward(ctx: Any, *cot: Any) -> Any:  # type: ignore[override]
            saved = ctx.saved_tensors
            nx, n_x0 = ctx.n_x, ctx.n_x0
            x = list(saved[len(saved) - nx:])
            inputs = saved[:len(saved) - nx]
            leaves = list(inputs[:len(inputs) - n_x0])
            x0 = list(inputs[len(inputs) - n_x0:])
            needs = ctx.needs_input_grad[2:]
            grads = _torch_vjp(spec, ctx.theta_tree, x, leaves, x0, list(cot[:nx]), needs)
            return (None, None, *grads)

    def f(theta: Any, x0: list) -> tuple[list, Any]:
        leaves, tree = pytree.tree_flatten(theta)
        trees: list[Any] = [tree, None]
        out = _Solve.apply(trees, len(x0), *leaves, *x0)
        return list(out[:len(x0)]), pytree.tree_unflatten(list(out[len(x0):]), trees[1])

    return f


def _torch_vjp(spec: ImplicitSpec, tree: Any, x: list, leaves: list, x0: list, xbar: list,
               needs: Sequence[bool]) -> list:
    import torch
    from torch.utils import _pytree as pytree

    B, n = int(x[0].shape[0]), int(spec.size)
    dtype, device = x[0].dtype, x[0].device
    xbar = [torch.zeros_like(a) if g is None else g for a, g in zip(x, xbar, strict=True)]
    nt = len(leaves)
    with torch.enable_grad():
        th = [t.detach().requires_grad_(bool(r) and t.is_floating_point())
              for t, r in zip(leaves, needs[:nt], strict=True)]
        x0d = [t.detach().requires_grad_(bool(r)) for t, r in zip(x0, needs[nt:], strict=True)]
        d = torch.zeros((B, n), dtype=dtype, device=device, requires_grad=True)
        xe = _where_fixed(torch, spec.fixed, spec.retract(x, d), x0d)
        c = spec.cost(pytree.tree_unflatten(th, tree), xe).sum()
        wants = [t for t in th + x0d if t.requires_grad]
        (g,) = torch.autograd.grad(c, d, create_graph=True)
        grads_u = torch.autograd.grad(xe, [d, *[t for t in x0d if t.requires_grad]],
                                      grad_outputs=xbar, retain_graph=True, allow_unused=True,
                                      materialize_grads=True)
        u = grads_u[0]
        back: Sequence[Any] = ()
        if wants and g.requires_grad and n > 0:
            eye = torch.eye(n, dtype=dtype, device=device)
            H = torch.autograd.grad(g, d, grad_outputs=eye[:, None, :].expand(n, B, n),
                                    retain_graph=True, is_grads_batched=True,
                                    materialize_grads=True)[0].permute(1, 2, 0)
            w = torch.linalg.solve(H, u[..., None])[..., 0]
            back = torch.autograd.grad(g, wants, grad_outputs=-w, allow_unused=True,
                                       materialize_grads=True)
        elif wants:
            back = [torch.zeros_like(t) for t in wants]
    out: list = []
    it = iter(back)
    for t in th:
        out.append(next(it) if t.requires_grad else None)
    through = iter(grads_u[1:])
    for t in x0d:
        out.append(next(it) + next(through) if t.requires_grad else None)
    return out


# ---------------------------------------------------------------------------- the entry point


def solve_differentiable(problem: Any, theta: Any, x0: list, options: Any = None,
                         differentiate: str = "implicit") -> tuple[list, Any]:
    """:func:`~microlie.optim.device.solve` with gradients of the optimum to ``theta`` and
    ``x0``: implicit (default) or unrolled (module docstring).

    Parameters
    ----------
    problem : DeviceProblem
        The structure.
    theta : tuple of dict
        The factors' data (:meth:`DeviceProblem.theta`; arrays may require grad on torch,
        be traced by ``jax.grad`` on JAX), optionally with a leading problem axis.
    x0 : list of arrays
        ``(n_k, param_dim)`` per variable batch, or ``(B, n_k, param_dim)``.
    options : LMOptions, optional
        The solve's rules.
    differentiate : {"implicit", "unroll"}
        Implicit differentiation of the optimum (one linear solve with the full Hessian at
        the optimum), or differentiation of the iterations (on JAX with ``loop="fixed"``).

    Returns
    -------
    x : list of arrays
        The optimum, shaped as ``x0``, carrying gradients.
    info : SolveInfo
        As :func:`~microlie.optim.device.solve` (no gradients).

    Raises
    ------
    ValueError
        ``differentiate`` not one of :data:`DIFFERENTIATE`.

    Examples
    --------
    >>> import torch
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.device import DeviceProblem, LMOptions
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.from_params(torch.tensor([[0.0, 0, 1, 0]] * 2).double()))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, 0, 1, SE2.exp([1.0, 0.0, 0.0])))
    >>> p = DeviceProblem.from_graph(g)
    >>> theta = p.theta()
    >>> theta[1]["Z"].requires_grad_()  # the odometry measurement
    tensor([[1., 0., 1., 0.]], dtype=torch.float64, requires_grad=True)
    >>> xs, info = solve_differentiable(p, theta, p.initial(), LMOptions(rel_tol=0, abs_tol=0))
    >>> xs[0][1, 0].backward()  # x of the second pose moves with the measured x
    >>> theta[1]["Z"].grad[0, 0].item()
    1.0
    """
    if differentiate not in DIFFERENTIATE:
        raise ValueError(f"differentiate must be one of {DIFFERENTIATE}, got {differentiate!r}")
    from .lm import LMOptions, solve

    opts = options if options is not None else LMOptions()
    be = problem.backend
    if differentiate == "unroll":
        if be.name == "jax" and opts.loop != "fixed":
            opts = replace(opts, loop="fixed")
        return solve(problem, theta, x0, opts)
    batched = x0[0].ndim == 3 if x0 else False
    spec = spec_of(problem, opts)
    f = implicit_jax(spec) if be.name == "jax" else implicit_torch(spec)
    # theta arrays without the problem axis broadcast against it (their gradients summed)
    x, info = f(theta, list(x0) if batched else [be.asarray(a)[None] for a in x0])
    if not batched:
        x = [a[0] for a in x]
        info = type(info)(*(v[0] for v in info))
    return x, info


def traced_result(problem: Any, x: list, info: Any, options: Any) -> Any:
    """The :class:`~microlie.optim.Result` of a solve traced by ``jax.jit`` or ``jax.grad``
    (a graph built inside the traced function): its numbers stay arrays of the trace.

    Parameters
    ----------
    problem : DeviceProblem
        The structure.
    x : list of arrays
        The solve's values.
    info : SolveInfo
        The solve's report (traced arrays).
    options : LMOptions
        The solve's options.

    Returns
    -------
    Result
        ``initial_cost``, ``final_cost``, ``iterations`` and ``accepted_steps`` are 0-d
        arrays, ``converged`` a 0-d bool array, ``termination`` ``"traced"`` and ``message``
        says where the codes are (:data:`~microlie.optim.device.lm.STATUS` in ``status``
        of :func:`~microlie.optim.device.solve`); ``time_s`` is 0 (the solve runs later).

    Examples
    --------
    >>> import jax, jax.numpy as jnp
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> def final(z):  # a graph made inside a jitted function
    ...     g = FactorGraph()
    ...     x = g.add_variables(jnp.zeros((1, 2), dtype=z.dtype))
    ...     _ = g.add(PriorFactor(x, 0, z))
    ...     res = g.optimize()
    ...     return res.values[x][0, 0], res.converged
    >>> v, ok = jax.jit(final)(jnp.array([[2.0, 3.0]]))
    >>> round(float(v), 6), bool(ok)  # float32 or float64, as jax_enable_x64 says
    (2.0, True)
    """
    from ..core.solvers import Result
    from ..core.variables import Values
    from .problem import DENSE_MAX

    dense = options.linear == "dense" or (options.linear == "auto" and problem.size <= DENSE_MAX)
    return Result(Values(problem.variables, x), info.initial_cost, info.cost, info.initial_cost,
                  info.cost, info.iterations, info.status == 1,
                  "traced by JAX: the solve's status is an array (1 converged, 2 max_iter, "
                  "3 failure)", "traced", [], 0.0, "lm",
                  f"{problem.backend.name}:{'dense' if dense else 'pcg'}", {},
                  list(problem.gauge_fixed), info.iterations, None)
