"""Inexact Levenberg-Marquardt steps for large problems on a device, where no sparse
Cholesky is available: preconditioned conjugate gradients on ``(H + diag(d)) dx = -g`` with
matrix-free products ``H v = J^T (J v)`` and a block-Jacobi preconditioner (the inverse
``dof x dof`` diagonal blocks of the damped ``H``, one per variable), or, for bundle adjustment,
on the Schur complement of the landmarks (eliminated exactly, block by block:
``S = H_cc - H_cp H_pp^-1 H_pc``, applied matrix-free, preconditioned by the inverse diagonal
blocks of ``S``). On pose graphs the block-Jacobi preconditioner gets a coarse level, or a
spanning tree (:mod:`microlie.optim.device.precondition`).

Inexact-step rules: CG stops when ``|r_k| <= eta |b|`` (``b`` the right-hand side) with the
forcing term ``eta = min(eta_max, sqrt(|g| / |g_0|))`` (``g_0`` the gradient at the start:
loose steps far from the minimum, exact ones near it, which keeps LM's local convergence
superlinear; Eisenstat and Walker's choice 2 without its safeguards), floored at
``eta_min``, or after ``cg_max_iter`` iterations; a non-finite step is a failed solve
(LM then raises the damping).

Precision. A float32 problem keeps its linearisation in float32 (residuals, Jacobians,
gradient, cost, diagonal blocks) and CG's products ``J^T (J v)`` in float32 (the bulk of the
work); the preconditioner (the damped diagonal blocks' inverses, the coarse level's Gram
matrix and its factorisation, the tree elimination) and CG's vectors and dot products are
float64 (:func:`~microlie.optim.device.schur.step_dtype`), and the step is returned in float32.
Found by promoting one piece at a time on parking-garage (condition number of ``H`` about
``1e11``): a float32 preconditioner (its coarse solve: a float32 Cholesky with a jitter of a
few float32 ``eps`` flattens the slow modes it exists for) leaves the float32 LM 3.2e-4 above
the optimum after 21,000 CG iterations; a float64 one alone reaches 2e-6; float64 products and
vectors without it do not (3.6e-4). On JAX this needs ``jax_enable_x64`` (otherwise every
piece stays float32).
"""

from __future__ import annotations

from typing import Any

from .problem import DeviceProblem, Linear, add_last, extend, eye_like, transpose
from .schur import step_dtype

__all__ = ["block_diagonal", "cast", "diagonal_of", "pcg", "pcg_step"]


def cast(be: Any, a: Any, dtype: Any) -> Any:
    """``a`` in ``dtype`` (no copy when it has it).

    Parameters
    ----------
    be : Backend
        The backend.
    a : array
        A backend array.
    dtype : dtype
        The backend library's dtype.

    Returns
    -------
    array

    Examples
    --------
    >>> import torch
    >>> from microlie.optim.device.backend import Backend
    >>> from microlie.optim.device.pcg import cast
    >>> cast(Backend("torch"), torch.ones(2), torch.float64).dtype
    torch.float64
    """
    if a.dtype == dtype:
        return a
    return a.to(dtype) if be.name == "torch" else a.astype(dtype)


def block_diagonal(problem: DeviceProblem, lin: Linear) -> list[Any]:
    """The ``dof x dof`` diagonal blocks of ``H`` per variable batch, ``(B, n_k, dof, dof)``
    (rows of fixed variables and held components zero).

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    lin : Linear
        Its linearisation.

    Returns
    -------
    list of arrays

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.pcg import block_diagonal
    >>> g = FactorGraph()
    >>> _ = g.add(PriorFactor(g.add_variables(torch.ones((1, 2)).double()), 0, [0.0, 0.0],
    ...                       Isotropic(2, 0.5)))
    >>> p = DeviceProblem.from_graph(g)
    >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    >>> block_diagonal(p, p.linearize(th, [a[None] for a in p.initial()]))[0].tolist()
    [[[[4.0, 0.0], [0.0, 4.0]]]]
    """
    be = problem.backend
    B = lin.e[0].shape[0]
    out = [be.zeros((B, b.n, b.dof * b.dof), like=lin.e[0]) for b in problem.blocks]
    for t, A in zip(problem.terms, lin.A, strict=True):
        for k, Ak, idx in zip(t.keys, A, t.idx, strict=True):
            blk = transpose(be, Ak) @ Ak
            out[k] = be.scatter_add(out[k], idx, blk.reshape(B, t.m, -1))
    return [o.reshape(B, b.n, b.dof, b.dof) for o, b in zip(out, problem.blocks, strict=True)]


def diagonal_of(problem: DeviceProblem, blocks: list[Any]) -> Any:
    """The diagonal of ``H`` ``(B, size)`` from its diagonal blocks.

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    blocks : list of arrays
        From :func:`block_diagonal`.

    Returns
    -------
    array

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.pcg import block_diagonal, diagonal_of
    >>> g = FactorGraph()
    >>> _ = g.add(PriorFactor(g.add_variables(torch.ones((1, 2)).double()), 0, [0.0, 0.0],
    ...                       Isotropic(2, 0.5)))
    >>> p = DeviceProblem.from_graph(g)
    >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    >>> diagonal_of(p, block_diagonal(p, p.linearize(th, [a[None] for a in p.initial()])))
    tensor([[4., 4.]], dtype=torch.float64)
    """
    be = problem.backend
    B = blocks[0].shape[0]
    out = be.zeros((B, problem.size + 1), like=blocks[0])
    for blk, cm in zip(blocks, problem._colmap, strict=True):
        d = _diag(be, blk)                                   # (B, n, dof)
        out = add_last(be, out, cm.reshape(-1), d.reshape(B, -1))
    return out[..., :problem.size]


def _diag(be: Any, blk: Any) -> Any:
    if be.name == "torch":
        return blk.diagonal(dim1=-2, dim2=-1)
    return be.xp.diagonal(blk, axis1=-2, axis2=-1)


def _gather_blocks(be: Any, problem: DeviceProblem, v_ext: Any, k: int) -> Any:
    b = problem.blocks[k]
    cm = problem._colmap[k]
    return be.take(v_ext, cm.reshape(-1), axis=-1).reshape(*v_ext.shape[:-1], b.n, b.dof)


def _block_inverses(problem: DeviceProblem, blocks: list[Any], damping: Any) -> list[Any]:
    """Inverses of the damped diagonal blocks (sink columns get a unit diagonal)."""
    be = problem.backend
    ext = extend(be, damping)
    B = damping.shape[0]
    one = be.zeros((B, problem.size + 1), like=damping)
    one = add_last(be, one, problem._sink, be.full((B, 1), 1.0, dtype=damping.dtype))
    ext = ext + one
    out = []
    for k, blk in enumerate(blocks):
        d = _gather_blocks(be, problem, ext, k)             # (B, n, dof)
        eye = eye_like(be, blk)
        out.append(be.inv_spd(blk + eye * d[..., None, :]))
    return out


def _apply_blocks(problem: DeviceProblem, inv: list[Any], v: Any, keys: Any = None) -> Any:
    """``blockdiag(inv) v`` over the variable batches ``keys`` (default all); other columns
    zero."""
    be = problem.backend
    ext = extend(be, v)
    B = v.shape[0]
    out = be.zeros((B, problem.size + 1), like=v)
    for k, Mi in enumerate(inv):
        if keys is not None and k not in keys:
            continue
        vk = _gather_blocks(be, problem, ext, k)
        wk = (Mi @ vk[..., None])[..., 0]
        out = add_last(be, out, problem._colmap[k].reshape(-1), wk.reshape(B, -1))
    return out[..., :problem.size]


def _dot(a: Any, b: Any) -> Any:
    return (a * b).sum(-1)


def pcg(be: Any, matvec: Any, precond: Any, b: Any, eta: Any, max_iter: int,
        fixed: bool = False) -> tuple[Any, Any]:
    """Preconditioned conjugate gradients for a batch of SPD systems ``M x = b``, each
    stopping when ``|r| <= eta |b|`` (then its iterate no longer changes).

    Parameters
    ----------
    be : Backend
        The backend.
    matvec, precond : callable
        ``v (B, n) -> (B, n)``.
    b : array
        ``(B, n)``.
    eta : array
        ``(B,)`` relative tolerances.
    max_iter : int
        Iteration limit.
    fixed : bool
        No data-dependent Python loop: torch's ``while_loop`` operator while
        ``torch.compile`` traces, else exactly ``max_iter`` masked iterations.

    Returns
    -------
    x : array
        ``(B, n)``.
    iterations : array
        ``(B,)`` iterations each system took.

    Examples
    --------
    >>> import torch
    >>> from microlie.optim.device.backend import Backend
    >>> from microlie.optim.device.pcg import pcg
    >>> A = torch.tensor([[[4.0, 1.0], [1.0, 3.0]]], dtype=torch.float64)
    >>> b = torch.tensor([[1.0, 2.0]], dtype=torch.float64)
    >>> x, it = pcg(Backend("torch"), lambda v: (A @ v[..., None])[..., 0], lambda v: v, b,
    ...             torch.tensor([1e-12]), 10)
    >>> [round(v, 12) for v in x[0].tolist()], it.tolist()  # 1/11 * (1, 7)
    ([0.090909090909, 0.636363636364], [2.0])
    """
    x = b * 0.0
    r = b
    z = precond(r)
    p = z
    rz = _dot(r, z)
    bn = _dot(b, b) ** 0.5
    tol = eta * bn
    B = b.shape[0]
    it = be.zeros((B,), like=b)

    def body(state: tuple) -> tuple:
        x, r, z, p, rz, it, active = state
        q = matvec(p)
        pq = _dot(p, q)
        alpha = be.where(active & (pq > 0), rz / be.where(pq > 0, pq, 1.0), 0.0)
        x = x + alpha[:, None] * p
        r = r - alpha[:, None] * q
        z = precond(r)
        rz_new = _dot(r, z)
        beta = be.where(active & (rz != 0), rz_new / be.where(rz != 0, rz, 1.0), 0.0)
        p = be.where(active[:, None], z + beta[:, None] * p, p)
        it = it + be.where(active, 1.0, 0.0)
        rn = _dot(r, r) ** 0.5
        active = active & (rn > tol) & (pq > 0)
        rz = be.where(active, rz_new, rz)
        return x, r, z, p, rz, it, active

    active = (bn > 0) & (max_iter > 0)
    state = (x, r, z, p, rz, it, active)
    if be.name == "jax":
        from jax import lax

        def cond(s: tuple) -> Any:
            return s[6].any() & (s[5].max() < max_iter)

        state = lax.while_loop(cond, body, state)
    elif fixed and be.xp.compiler.is_compiling():  # one while_loop op in the graph
        from .backend import torch_while

        state = torch_while(lambda s: s[6].any() & (s[5].max() < max_iter), body, state)
    elif fixed:
        for _ in range(max_iter):
            state = body(state)
    else:
        k = 0
        while k < max_iter and bool(state[6].any()):
            state = body(state)
            k += 1
    return state[0], state[5]


def pcg_step(problem: DeviceProblem, lin: Linear, g: Any, blocks: list[Any], damping: Any,
             eta: Any, max_iter: int, schur: bool = True, fixed: bool = False,
             precond: Any = None) -> tuple[Any, Any, Any]:
    """The inexact step of ``(H + diag(damping)) dx = -g`` by PCG (Schur-complement PCG over
    the non-eliminated variables when the problem has landmarks and ``schur``).

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    lin : Linear
        Its linearisation.
    g : array
        ``(B, size)`` gradient.
    blocks : list of arrays
        :func:`block_diagonal` of ``lin``.
    damping : array
        ``(B, size)``.
    eta : array
        ``(B,)`` forcing terms (CG's relative residual tolerance).
    max_iter : int
        CG iteration limit.
    schur : bool
        Eliminate the landmarks (``problem.eliminate``) when there are some.
    fixed : bool
        Fixed-length loops (see :func:`pcg`).
    precond : callable, optional
        ``(damping, jacobi) -> (v -> M^-1 v)`` given the damping and the block-Jacobi
        product: a preconditioner built on block-Jacobi
        (:mod:`~microlie.optim.device.precondition`) for steps without landmarks.

    Returns
    -------
    dx : array
        ``(B, size)``, of ``g``'s dtype (the preconditioner and CG's vectors in float64 for
        float32 problems too: see the module docstring).
    ok : array
        ``(B,)`` bool, a finite step.
    iterations : array
        ``(B,)`` CG iterations.

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, PriorFactor, Isotropic
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.dense import gradient
    >>> from microlie.optim.device.pcg import block_diagonal, pcg_step
    >>> g = FactorGraph()
    >>> _ = g.add(PriorFactor(g.add_variables(torch.ones((1, 2)).double()), 0, [0.0, 0.0],
    ...                       Isotropic(2, 0.5)))
    >>> p = DeviceProblem.from_graph(g)
    >>> th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    >>> lin = p.linearize(th, [a[None] for a in p.initial()])
    >>> dx, ok, it = pcg_step(p, lin, gradient(p, lin), block_diagonal(p, lin),
    ...                       torch.zeros((1, 2), dtype=torch.float64), torch.tensor([1e-10]), 5)
    >>> dx.tolist(), ok.tolist()
    ([[-1.0, -1.0]], [True])
    """
    be = problem.backend
    dt = g.dtype
    wide = step_dtype(be, dt)   # float64 for float32 problems too (module docstring)
    blocks = [cast(be, b, wide) for b in blocks]
    damp = cast(be, damping, wide)
    inv = _block_inverses(problem, blocks, damp)

    def H(v: Any) -> Any:       # J^T (J v) in the linearisation's dtype
        u = cast(be, v, dt)
        return cast(be, problem.vjp(lin, problem.jvp(lin, u)), wide) + damp * v

    elim = problem.eliminate if schur else []
    b = cast(be, -g, wide)
    eta = cast(be, eta, wide)
    if not elim and precond is not None:
        M = precond(damp, lambda v, keys=None: _apply_blocks(problem, inv, v, keys))
        dx, it = pcg(be, H, M, b, eta, max_iter, fixed)
    elif not elim:
        dx, it = pcg(be, H, lambda v: _apply_blocks(problem, inv, v), b, eta, max_iter, fixed)
    else:
        mc = problem._keep_mask           # 1 on the reduced (camera) columns
        mp = 1.0 - mc
        keep = [k for k in range(len(problem.blocks)) if k not in elim]

        def Hpp_inv(v: Any) -> Any:
            return _apply_blocks(problem, inv, v, elim)

        def S(v: Any) -> Any:
            w = H(v * mc)
            y = Hpp_inv(w * mp)
            return (w - H(y)) * mc

        s_inv = _schur_block_inverses(problem, lin, blocks, damp, inv, elim)

        rhs = (b - H(Hpp_inv(b * mp))) * mc
        dc, it = pcg(be, S, lambda v: _apply_blocks(problem, s_inv, v, keep), rhs, eta,
                     max_iter, fixed)
        dp = Hpp_inv((b - H(dc)) * mp)
        dx = dc * mc + dp
    ok = (dx == dx).all(-1) & (dx.abs() < float("inf")).all(-1) if be.name == "torch" \
        else be.xp.isfinite(dx).all(-1)
    return cast(be, dx, dt), ok, cast(be, it, dt)


def _schur_block_inverses(problem: DeviceProblem, lin: Linear, blocks: list[Any],
                          damping: Any, inv: list[Any], elim: list[int]) -> list[Any]:
    """Inverses of the damped diagonal blocks of the Schur complement ``S`` (per kept
    variable: ``H_vv - sum_obs W H_pp^-1 W^T``, ``W = A_v^T A_p``)."""
    be = problem.backend
    B = damping.shape[0]
    sblocks = list(blocks)
    for t, A in zip(problem.terms, lin.A, strict=True):
        pos = [a for a, k in enumerate(t.keys) if k in elim]
        if not pos:
            continue
        a = pos[0]
        Pi = be.take(inv[t.keys[a]], t.idx[a], axis=1)        # (B, m, 3, 3)
        for k, Ak, idx in zip(t.keys, A, t.idx, strict=True):
            if k in elim:
                continue
            W = cast(be, transpose(be, Ak) @ A[a], Pi.dtype)    # (B, m, dof, 3)
            c = W @ Pi @ transpose(be, W)
            b = problem.blocks[k]
            flat = sblocks[k].reshape(B, b.n, -1)
            flat = be.scatter_add(flat, idx, -c.reshape(B, t.m, -1))
            sblocks[k] = flat.reshape(B, b.n, b.dof, b.dof)
    return _block_inverses(problem, sblocks, damping)
