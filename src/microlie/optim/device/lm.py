"""Levenberg-Marquardt on torch or JAX arrays with the NumPy engine's rules (GTSAM's, as
:class:`~microlie.optim.LevenbergMarquardt`), for one problem or a batch of problems of the
same structure, each with its own damping and convergence state.

The loop runs one *try* per pass: solve ``(H + lambda D) dx = -g`` at the current point, evaluate
the cost at ``X Exp(dx)``; a decrease is accepted (``lambda /= lambda_factor``, GTSAM's tests,
then the new point is linearised), anything else raises ``lambda`` (``*= lambda_factor``) and
tries again from the same point, until ``lambda > lambda_max``. The damping matrix ``D`` follows
``damping="auto"`` as the NumPy engine (bundle adjustment: ``diag(H)``; else the identity where
negligible, else ``diag(H)``, with its switch). A problem that has stopped (converged,
``max_iter`` reached or failed) keeps its values while the others go on. On JAX the loop is a
``lax.while_loop`` (``jax.jit`` and ``jax.vmap`` compile it); on torch a Python loop, torch's
``while_loop`` operator while ``torch.compile`` traces (one graph with ``fullgraph=True``: its
body holds one linearisation, of the candidate, and the first pass linearises the start), or
with ``loop="fixed"`` a fixed number of masked tries.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, NamedTuple

from ..core.strategies import BUNDLE_LAMBDA
from .backend import torch_while
from .dense import dense_step, normal_equations
from .pcg import block_diagonal, diagonal_of, pcg_step
from .precondition import (
    coarse_basis,
    coarse_matrix,
    coarse_plan,
    tree_edges,
    tree_plan,
    tree_preconditioner,
    two_level,
)
from .problem import DENSE_MAX, DeviceProblem, Linear, Theta
from .schur import schur_fits, schur_plan, schur_step

__all__ = ["LMOptions", "SolveInfo", "linear_kind", "solve", "STATUS"]

#: ``SolveInfo.status`` codes: running, converged, max_iter reached, failure.
STATUS = {0: "running", 1: "convergence", 2: "no_convergence", 3: "failure"}


@dataclass(frozen=True)
class LMOptions:
    """Options of a device solve (hashable: a static argument of ``jax.jit``).

    Parameters
    ----------
    max_iter : int
        Accepted iterations allowed per problem (as :meth:`FactorGraph.optimize`).
    lambda_initial : float, optional
        Initial damping (default ``1e-5`` with the identity, ``1e-12`` with ``diag(H)``,
        ``1e-4`` with ``"auto"`` on a bundle adjustment, as the NumPy engine).
    lambda_factor, lambda_max, lambda_min : float
        As :class:`~microlie.optim.LevenbergMarquardt`.
    damping : {"auto", "identity", "diagonal"}
        The damping matrix (as :class:`~microlie.optim.LevenbergMarquardt`).
    stall_ratio : float
        ``"auto"``'s bound on ``lambda / H_kk`` for the identity.
    rel_tol, abs_tol, cost_tol, step_tol : float
        GTSAM's convergence tests.
    linear : {"auto", "dense", "schur", "pcg"}
        The step solve: dense Cholesky (batched); ``"schur"``: landmarks eliminated exactly
        and the reduced camera system factored densely (:mod:`microlie.optim.device.schur`,
        Ceres' ``DENSE_SCHUR``; needs landmarks); or preconditioned conjugate gradients
        (:mod:`microlie.optim.device.pcg`; Schur elimination of landmarks for bundle
        adjustment). ``"auto"``: dense up to :data:`DENSE_MAX` unknowns, else ``"schur"``
        when there are landmarks and the reduced system is small
        (:func:`~microlie.optim.device.schur.schur_fits`), else ``"pcg"``.
    schur : bool
        PCG eliminates landmarks (variables that share no factor) when there are some.
    precondition : {"auto", "jacobi", "tree"}
        PCG's local preconditioner on problems without landmarks: ``"jacobi"`` the
        diagonal blocks, ``"tree"`` also the off-diagonal blocks of a spanning tree of the
        pose graph, solved by tree elimination (:mod:`microlie.optim.device.precondition`).
        ``"auto"``: ``"jacobi"``.
    coarse : int
        The coarse level added to it (pose graphs: a variable batch with between factors,
        no landmarks): aggregates of ``coarse`` consecutive variables moved rigidly, solved
        exactly (dense). ``-1``: automatic size; ``0``: none.
    cg_max_iter : int
        CG iterations per step at most.
    eta_max, eta_min : float
        Bounds of the forcing term (CG stops at ``|r| <= eta |b|``, ``eta = min(eta_max,
        sqrt(|g| / |g_0|))``, at least ``eta_min``).
    loop : {"auto", "while", "fixed"}
        On torch: ``"while"`` is a Python loop in eager mode and torch's ``while_loop``
        operator while ``torch.compile`` traces (one graph with ``fullgraph=True``);
        ``"fixed"`` runs exactly ``max_tries`` masked tries (and ``cg_max_iter`` masked CG
        iterations), unrolled. ``"auto"`` is ``"while"``. JAX always uses
        ``lax.while_loop``.
    max_tries : int, optional
        Total tries (linear solves) per call (default ``max_iter * 10``; with ``"fixed"``
        exactly this many).

    Examples
    --------
    >>> from microlie.optim.device import LMOptions
    >>> LMOptions(max_iter=20, linear="dense").tries()
    200
    """

    max_iter: int = 100
    lambda_initial: float | None = None
    lambda_factor: float = 10.0
    lambda_max: float = 1e5
    lambda_min: float = 0.0
    damping: str = "auto"
    stall_ratio: float = 1e-3
    rel_tol: float = 1e-5
    abs_tol: float = 1e-5
    cost_tol: float = 0.0
    step_tol: float = 0.0
    linear: str = "auto"
    schur: bool = True
    precondition: str = "auto"
    coarse: int = -1
    cg_max_iter: int = 3000
    eta_max: float = 1e-4
    eta_min: float = 1e-10
    loop: str = "auto"
    max_tries: int | None = None

    def __post_init__(self) -> None:
        if isinstance(self.max_iter, bool) or not isinstance(self.max_iter, int) or \
                self.max_iter < 0:
            raise ValueError(f"max_iter must be an integer >= 0, got {self.max_iter!r}")
        if self.damping not in ("auto", "identity", "diagonal"):
            raise ValueError(f"damping must be 'auto', 'identity' or 'diagonal', got "
                             f"{self.damping!r}")
        if self.linear not in ("auto", "dense", "schur", "pcg"):
            raise ValueError(f"linear must be 'auto', 'dense', 'schur' or 'pcg', got "
                             f"{self.linear!r}")
        if self.precondition not in ("auto", "tree", "jacobi"):
            raise ValueError(f"precondition must be 'auto', 'tree' or 'jacobi', got "
                             f"{self.precondition!r}")
        if isinstance(self.coarse, bool) or not isinstance(self.coarse, int) or \
                self.coarse < -1:
            raise ValueError(f"coarse must be an integer >= -1 (-1 automatic, 0 none), got "
                             f"{self.coarse!r}")
        if self.loop not in ("auto", "while", "fixed"):
            raise ValueError(f"loop must be 'auto', 'while' or 'fixed', got {self.loop!r}")
        if not self.lambda_factor > 1.0:
            raise ValueError(f"lambda_factor must be > 1, got {self.lambda_factor!r}")
        if not 0.0 < self.stall_ratio < 1.0:
            raise ValueError(f"stall_ratio must be in (0, 1), got {self.stall_ratio!r}")
        if not (isinstance(self.cg_max_iter, int) and self.cg_max_iter >= 1):
            raise ValueError(f"cg_max_iter must be an integer >= 1, got {self.cg_max_iter!r}")
        for name in ("lambda_max", "eta_max", "eta_min"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        for name in ("lambda_min", "rel_tol", "abs_tol", "cost_tol", "step_tol"):
            v = getattr(self, name)
            if not v >= 0 or math.isnan(v):
                raise ValueError(f"{name} must be >= 0, got {v!r}")
        if self.lambda_initial is not None and not self.lambda_initial >= 0:
            raise ValueError(f"lambda_initial must be >= 0, got {self.lambda_initial!r}")
        if self.max_tries is not None and not (isinstance(self.max_tries, int)
                                               and self.max_tries >= 0):
            raise ValueError(f"max_tries must be an integer >= 0, got {self.max_tries!r}")

    def tries(self) -> int:
        """The try limit (``max_tries``, default ``10 * max_iter``).

        Returns
        -------
        int
        """
        return self.max_tries if self.max_tries is not None else 10 * self.max_iter


class SolveInfo(NamedTuple):
    """The state of a device solve, per problem (arrays of shape ``(B,)``; a pytree).

    Attributes
    ----------
    initial_cost, cost : array
        ``0.5 * sum r^T Omega r`` at the start and at the returned values.
    iterations : array
        Accepted steps (what ``max_iter`` limits).
    tries : array
        Linear solves.
    lam : array
        The damping ``lambda`` at the end.
    status : array
        :data:`STATUS` codes: 1 converged, 2 ``max_iter`` (or the try limit) reached,
        3 failure (no decrease at ``lambda_max``); 0 only when the loop was cut by
        ``max_tries``.
    cg_iterations : array
        CG iterations summed over the tries (0 with dense steps).
    """

    initial_cost: Any
    cost: Any
    iterations: Any
    tries: Any
    lam: Any
    status: Any
    cg_iterations: Any


def _first_lambda(opts: LMOptions, diagonal: Any) -> Any:
    if opts.lambda_initial is not None:
        return diagonal * 0.0 + opts.lambda_initial
    return diagonal * 1e-12 + (1.0 - diagonal) * 1e-5


def _smallest_positive(be: Any, d: Any) -> Any:
    big = float("inf")
    m = be.where(d > 0, d, big).min(-1)
    m = m.values if be.name == "torch" and hasattr(m, "values") else m
    return be.where(m < big, m, 1.0)


class _Engine:
    """The linear algebra of one solve: dense or PCG, for one problem (batch) layout."""

    def __init__(self, problem: DeviceProblem, opts: LMOptions, fixed: bool) -> None:
        self.p, self.opts, self.fixed = problem, opts, fixed
        self.kind = lin = linear_kind(problem, opts.linear)
        self.dense = lin == "dense"
        if lin == "schur":
            schur_plan(problem)  # built here (host), not inside a traced solve
        self.tree = self.coarse = None
        if lin == "pcg" and opts.precondition == "tree":
            self.tree = tree_plan(problem)
            if self.tree is None:
                raise ValueError("precondition='tree' needs a variable batch with between "
                                 "factors and no landmarks; use 'jacobi' or 'auto'")
        if lin == "pcg" and opts.coarse != 0:
            self.coarse = coarse_plan(problem, max(opts.coarse, 0))
        # torch without data-dependent branches linearises every candidate (masked): the
        # cost test reads that linearisation (one evaluation per try, not two)
        self.fused = fixed and problem.backend.name == "torch"
        self.start_in_loop = False  # the loop's first pass linearises the start (solve sets)

    def system(self, theta: Theta, x: list[Any]) -> dict:
        lin = self.p.linearize(theta, x)
        if self.dense:
            H, g = normal_equations(self.p, lin)
            be = self.p.backend
            dg = H.diagonal(dim1=-2, dim2=-1) if be.name == "torch" else \
                be.xp.diagonal(H, axis1=-2, axis2=-1)
            return {"H": H, "g": g, "dg": dg, "cost": lin.cost}
        blocks = block_diagonal(self.p, lin)
        g = self.p.vjp(lin, lin.e)
        out = {"e": lin.e, "A": lin.A, "blocks": blocks, "g": g,
               "dg": diagonal_of(self.p, blocks), "cost": lin.cost}
        if self.tree is not None:
            out["tree"] = tree_edges(self.p, self.tree, lin)
        if self.coarse is not None:
            out["P"] = coarse_basis(self.p, self.coarse, x)
            out["Ac"] = coarse_matrix(self.p, self.coarse, lin, out["P"])
        return out

    def preconditioner(self, s: dict, blocks: list[Any]) -> Any:
        """``(damping, jacobi) -> M^-1`` for :func:`pcg_step` (``None``: block-Jacobi)."""
        if self.tree is None and self.coarse is None:
            return None
        p, tree, coarse = self.p, self.tree, self.coarse

        def build(damping: Any, jacobi: Any) -> Any:
            M = jacobi
            if tree is not None:
                rest = [k for k in range(len(p.blocks)) if k != tree.key]
                M = tree_preconditioner(p, tree, blocks, s["tree"], damping,
                                        lambda v: jacobi(v, rest))
            if coarse is not None:
                M = two_level(p, coarse, s["P"], s["Ac"], damping, M)
            return M

        return build

    def step(self, s: dict, damping: Any, eta: Any) -> tuple[Any, Any, Any, Any, Any]:
        """``dx``, ``ok``, the model decrease ``-(g.dx + dx.H dx / 2)``, CG iterations and
        whether the step met its tolerance (CG did not stop at ``cg_max_iter``)."""
        g = s["g"]
        if self.dense:
            dx, ok = dense_step(self.p, s["H"], g, damping)
            Hdx = (s["H"] @ dx[..., None])[..., 0]
            pred = -((g * dx).sum(-1) + 0.5 * (dx * Hdx).sum(-1))
            return dx, ok, pred, g[..., 0] * 0.0, ok | True
        lin = Linear(s["e"], s["A"], s["cost"])
        if self.kind == "schur":
            dx, ok = schur_step(self.p, lin, g, s["blocks"], damping)
            it = g[..., 0] * 0.0
        else:
            dx, ok, it = pcg_step(self.p, lin, g, s["blocks"], damping, eta,
                                  self.opts.cg_max_iter, self.opts.schur, self.fixed,
                                  self.preconditioner(s, s["blocks"]))
        Jdx = self.p.jvp(lin, dx)
        quad = 0.0
        for u in Jdx:
            quad = quad + (u * u).reshape(u.shape[0], -1).sum(-1)
        pred = -((g * dx).sum(-1) + 0.5 * quad)
        return dx, ok, pred, it, it < self.opts.cg_max_iter


def linear_kind(problem: DeviceProblem, linear: str) -> str:
    """The step solve ``linear`` (an :class:`LMOptions` value) resolves to for ``problem``:
    ``"dense"``, ``"schur"`` or ``"pcg"``.

    Parameters
    ----------
    problem : DeviceProblem
        The problem.
    linear : {"auto", "dense", "schur", "pcg"}
        The requested step solve.

    Returns
    -------
    str

    Raises
    ------
    ValueError
        ``"schur"`` on a problem without landmarks.

    Examples
    --------
    >>> import torch
    >>> from microlie.optim import FactorGraph, PriorFactor
    >>> from microlie.optim.device import DeviceProblem
    >>> from microlie.optim.device.lm import linear_kind
    >>> g = FactorGraph()
    >>> _ = g.add(PriorFactor(g.add_variables(torch.ones((1, 2)).double()), 0, [0.0, 0.0]))
    >>> linear_kind(DeviceProblem.from_graph(g), "auto")
    'dense'
    """
    if linear == "auto":
        if problem.size <= DENSE_MAX:
            return "dense"
        return "schur" if problem.eliminate and schur_fits(problem) else "pcg"
    if linear == "schur" and not problem.eliminate:
        raise ValueError("linear='schur': the problem has no landmarks to eliminate (variable "
                         "batches that share no factor); use linear='dense' or 'pcg'")
    return linear


def _select(be: Any, mask: Any, a: Any, b: Any) -> Any:
    """``a`` where ``mask`` ``(B,)`` else ``b``, leaf by leaf (pytrees of ``(B, ...)``)."""
    if isinstance(a, dict):
        return {k: _select(be, mask, a[k], b[k]) for k in a}
    if isinstance(a, list | tuple):
        return type(a)(_select(be, mask, u, v) for u, v in zip(a, b, strict=True))
    m = mask.reshape(mask.shape + (1,) * (a.ndim - 1))
    return be.where(m, a, b)


def _norm(v: Any) -> Any:
    return ((v * v).sum(-1)) ** 0.5


def solve(problem: DeviceProblem, theta: Theta, x0: list[Any],
          options: LMOptions | None = None) -> tuple[list[Any], SolveInfo]:
    """Minimise ``0.5 * sum r^T Omega r`` from ``x0``: a pure function of ``(theta, x0)``.

    Parameters
    ----------
    problem : DeviceProblem
        The structure (:meth:`DeviceProblem.from_graph`).
    theta : tuple of dict
        The factors' data (:meth:`DeviceProblem.theta`), optionally with a leading batch
        axis ``B`` on every array (arrays without it are shared by the batch).
    x0 : list of arrays
        Starting parameters per variable batch: ``(n_k, param_dim)``, or ``(B, n_k,
        param_dim)`` for a batch of problems.
    options : LMOptions, optional
        The rules and the step solve.

    Returns
    -------
    x : list of arrays
        The optimised parameters (shaped as ``x0``).
    info : SolveInfo
        Per-problem costs, iterations and status (scalars' arrays of shape ``()`` for one
        problem, ``(B,)`` for a batch).

    Examples
    --------
    >>> import torch
    >>> from microlie import SE2
    >>> from microlie.optim import FactorGraph, PriorFactor, BetweenFactor
    >>> from microlie.optim.device import DeviceProblem, LMOptions, solve
    >>> g = FactorGraph()
    >>> x = g.add_variables(SE2.from_params(torch.tensor([[0.0, 0, 1, 0]] * 3).double()))
    >>> _ = g.add(PriorFactor(x, 0, SE2.identity()))
    >>> _ = g.add(BetweenFactor(x, [0, 1], [1, 2], SE2.exp([1.0, 0.0, 0.5])))
    >>> p = DeviceProblem.from_graph(g)
    >>> xs, info = solve(p, p.theta(), p.initial(), LMOptions(abs_tol=0.0, rel_tol=0.0))
    >>> int(info.status), float(info.cost) < 1e-20
    (1, True)
    """
    opts = options if options is not None else LMOptions()
    be = problem.backend
    batched = x0[0].ndim == 3 if x0 else False
    xs = [be.asarray(a) if not batched else be.asarray(a) for a in x0]
    if not batched:
        xs = [a[None] for a in xs]
    B = xs[0].shape[0]
    th = _batch_theta(problem, theta, B)
    fixed = opts.loop == "fixed" or _compiling(be)  # no data-dependent Python branches
    eng = _Engine(problem, opts, fixed)
    status = be.zeros((B,), like=xs[0])
    if problem.size == 0:
        status = status + 1.0
    elif opts.max_iter == 0:
        status = status + 2.0
    # Traced by torch.compile: the first pass of the loop linearises the start (its try is
    # skipped), so the graph holds one linearisation, in the loop body.
    eng.start_in_loop = in_loop = (be.name == "torch" and fixed and opts.loop != "fixed"
                                   and eng.dense and problem.size > 0 and opts.max_iter > 0)
    if in_loop:
        N = problem.size
        z = be.zeros((B, N), like=xs[0])
        sys0 = {"H": be.zeros((B, N, N), like=xs[0]), "g": z, "dg": z, "cost": status}
        st = _start(be, opts, xs, sys0, status, bool(problem.eliminate))
        st["started"] = status
    else:
        st = _start(be, opts, xs, eng.system(th, xs), status, bool(problem.eliminate))
    cost0 = st["cost"]

    def body(st: dict) -> dict:
        return _try(problem, eng, opts, th, st)

    n_tries = opts.tries()

    def cond(st: dict) -> Any:
        return (st["status"] == 0).any() & (st["tries"].max() < n_tries)

    if be.name == "jax" and fixed:  # a static trip count: reverse-differentiable (unrolling)
        from jax import lax

        st = lax.fori_loop(0, n_tries, lambda _, s: body(s), st)
    elif be.name == "jax":
        from jax import lax

        st = lax.while_loop(cond, body, st)
    elif fixed and opts.loop != "fixed":  # traced by torch.compile: one while_loop op
        st = torch_while(cond, body, st)
    elif fixed:
        for _ in range(n_tries):
            st = body(st)
    else:
        k = 0
        while k < n_tries and bool((st["status"] == 0).any()):
            st = body(st)
            k += 1
    if in_loop:
        cost0 = st["cost0"]
    info = SolveInfo(cost0, st["cost"], st["iters"], st["tries"], st["lam"], st["status"],
                     st["cg"])
    x = st["x"]
    if not batched:
        x = [a[0] for a in x]
        info = SolveInfo(*(v[0] for v in info))
    return x, info


def _start(be: Any, opts: LMOptions, xs: list[Any], sys0: dict, status: Any,
           landmarks: bool) -> dict:
    """The loop state at ``xs`` linearised as ``sys0``: damping chosen, nothing tried
    (``"auto"`` with ``landmarks``, a bundle adjustment: ``diag(H)``, as the NumPy engine)."""
    cost0 = sys0["cost"]
    zero = cost0 * 0.0
    dg = sys0["dg"]
    first = None
    if opts.damping == "auto" and landmarks:
        diag = zero + 1.0
        first = zero + (BUNDLE_LAMBDA if opts.lambda_initial is None else opts.lambda_initial)
    elif opts.damping == "auto":
        lam_id = opts.lambda_initial if opts.lambda_initial is not None else 1e-5
        diag = be.where(lam_id < opts.stall_ratio * _smallest_positive(be, dg), 0.0, 1.0) \
            + zero
    else:
        diag = zero + (1.0 if opts.damping == "diagonal" else 0.0)
    lam = _first_lambda(opts, diag) if first is None else first
    g0n = _norm(sys0["g"])
    return {"x": xs, "sys": sys0, "cost": cost0, "cost0": cost0, "lam": lam, "diag": diag,
            "stalled": zero, "lam0": lam, "first_set": zero, "first_cost": zero,
            "first_pred": zero, "status": status, "iters": zero, "tries": zero, "cg": zero,
            "g0": be.where(g0n > 0, g0n, 1.0)}


def _compiling(be: Any) -> bool:
    if be.name != "torch":
        return False
    return bool(be.xp.compiler.is_compiling())


def _batch_theta(problem: DeviceProblem, theta: Theta, B: int) -> Theta:
    """Every theta array with the leading batch axis (shared ones broadcast)."""
    be = problem.backend
    base = {"L": 3, "Z": 2, "obs": 2, "K": 2}
    out = []
    for d in theta:
        e = {}
        for k, v in d.items():
            v = be.asarray(v)
            if v.ndim == base[k]:
                v = v[None]
            if v.shape[0] != B:
                if be.name == "torch":
                    v = v.expand(B, *v.shape[1:])
                else:
                    v = be.xp.broadcast_to(v, (B, *v.shape[1:]))
            e[k] = v
        out.append(e)
    return tuple(out)


def _try(problem: DeviceProblem, eng: _Engine, o: LMOptions, th: Theta, st: dict) -> dict:
    """One try for every running problem (stopped ones keep their state)."""
    be = problem.backend
    s = st["sys"]
    active = st["status"] == 0
    started = st["started"] > 0.5 if eng.start_in_loop else None
    if started is not None:
        active = active & started
    dg = s["dg"]
    diag = st["diag"] > 0.5
    lam = st["lam"]
    cur = st["cost"]
    damp = be.where(diag[:, None], be.where(dg > 0, dg, 1.0), 1.0 + 0.0 * dg)
    gn = _norm(s["g"])
    eta = (gn / st["g0"]) ** 0.5
    eta = be.where(eta < o.eta_max, eta, o.eta_max)
    eta = be.where(eta > o.eta_min, eta, o.eta_min)
    dx, ok, pred, cg_it, _ = eng.step(s, lam[:, None] * damp, eta)
    dx = be.where(ok[:, None], dx, 0.0)  # a failed step (NaN where a factorisation failed): none
    xn = problem.retract(st["x"], dx)
    if started is not None:  # not started: linearise the start itself
        xn = _select(be, started, xn, st["x"])
    if eng.fused:  # the candidate's linearisation is made anyway: its cost is the test's
        sys_n = eng.system(th, xn)
        cn = sys_n["cost"]
    else:
        cn = problem.cost(th, xn)
    cn = be.where(ok & (cn == cn) & (cn < float("inf")), cn, float("inf"))
    accept = active & (cn < cur)
    # ---- accepted: GTSAM's tests, then the "auto" switch
    watch = (1.0 - st["diag"]) > 0.5 if o.damping == "auto" else active & ~active
    bound = o.stall_ratio * _smallest_positive(be, dg)
    stalled_a = watch & ~(lam < bound)
    lam_a = lam / o.lambda_factor
    lam_a = be.where(lam_a > o.lambda_min, lam_a, o.lambda_min)
    dec = cur - cn
    why = (cn <= o.cost_tol) | ((dec >= 0) & (dec < o.abs_tol)) | \
        ((dec >= 0) & (cur > 0) & (dec < o.rel_tol * cur)) | (_norm(dx) <= o.step_tol)
    switch_a = why & stalled_a if o.damping == "auto" else why & ~why
    conv_a = why & ~switch_a
    iters_a = st["iters"] + 1.0
    diag_a = be.where(switch_a, 1.0, st["diag"])
    lam_a = be.where(switch_a, _first_lambda(o, diag_a), lam_a)
    stalled_a = stalled_a & ~switch_a
    status_a = be.where(conv_a, 1.0, be.where(iters_a >= o.max_iter, 2.0, 0.0))
    # ---- rejected: raise lambda; past lambda_max stop (or switch to diag(H))
    first_set_r = (st["first_set"] > 0.5) | ok
    first_cost = be.where(st["first_set"] > 0.5, st["first_cost"], cn)
    first_pred = be.where(st["first_set"] > 0.5, st["first_pred"], pred)
    lam_r = lam * o.lambda_factor
    over = lam_r > o.lambda_max
    stalled_r = watch & ~(st["lam0"] < bound)
    switch_r = over & stalled_r if o.damping == "auto" else over & ~over
    end_r = over & ~switch_r
    within = ((first_cost - cur).abs() if be.name == "torch" else be.xp.abs(first_cost - cur))
    tol = be.where(o.abs_tol > o.rel_tol * cur, o.abs_tol + 0.0 * cur, o.rel_tol * cur)
    fc = cur - first_pred
    fdec = cur - fc
    final = (fc <= o.cost_tol) | ((fdec >= 0) & (fdec < o.abs_tol)) | \
        ((fdec >= 0) & (cur > 0) & (fdec < o.rel_tol * cur))
    at_min = first_set_r & ((within <= tol) | final)
    status_r = be.where(end_r, be.where(at_min, 1.0, 3.0), 0.0)
    diag_r = be.where(switch_r, 1.0, st["diag"])
    lam_r = be.where(switch_r, _first_lambda(o, diag_r), lam_r)
    # ---- merge
    x_new = _select(be, accept, xn, st["x"])
    out = dict(st)
    out["x"] = x_new
    out["cost"] = be.where(accept, cn, cur)
    rej = active & ~accept
    out["lam"] = be.where(accept, lam_a, be.where(rej, lam_r, lam))
    out["diag"] = be.where(accept, diag_a, be.where(rej, diag_r, st["diag"]))
    out["stalled"] = be.where(accept, stalled_a * 1.0, be.where(rej & switch_r, 0.0,
                                                                 st["stalled"]))
    new_iter = accept | (rej & switch_r)
    out["lam0"] = be.where(new_iter, out["lam"], st["lam0"])
    out["first_set"] = be.where(new_iter, 0.0, be.where(rej, first_set_r * 1.0,
                                                         st["first_set"]))
    out["first_cost"] = be.where(rej, first_cost, st["first_cost"])
    out["first_pred"] = be.where(rej, first_pred, st["first_pred"])
    out["status"] = be.where(accept, status_a, be.where(rej, status_r, st["status"]))
    out["iters"] = be.where(accept, iters_a, st["iters"])
    out["tries"] = st["tries"] + be.where(active, 1.0, 0.0)
    out["cg"] = st["cg"] + be.where(active, cg_it, 0.0)
    # the linearisation at accepted points (where none was accepted, the old one)
    relin = accept & (out["status"] == 0)
    if be.name == "jax":
        from jax import lax

        out["sys"] = lax.cond(relin.any(), lambda: _select(be, accept, eng.system(th, x_new), s),
                              lambda: s)
    elif eng.fused:
        out["sys"] = _select(be, accept, sys_n, s)
    elif bool(relin.any()):  # eager: no select (a copy of every H) when all accepted
        sys_a = eng.system(th, x_new)
        out["sys"] = sys_a if bool(accept.all()) else _select(be, accept, sys_a, s)
    if started is not None:
        init = _start(be, o, st["x"], sys_n, st["status"], bool(problem.eliminate))
        init["started"] = st["started"] * 0.0 + 1.0
        out["started"] = init["started"]
        out = _select(be, ~started, init, out)
    return out
