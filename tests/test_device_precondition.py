"""PCG preconditioners of the device engine for pose graphs (issue 24): the spanning-tree
and two-level preconditioners against dense NumPy linear algebra, and PCG solves of an
ill-conditioned chain (a long odometry chain, a weak prior, few loop closures) against the
NumPy engine's sparse-Cholesky solve, on torch and JAX, float64 and float32."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import _jax, require

from microlie import SE2, SE3
from microlie.optim import BetweenFactor, Diagonal, FactorGraph, PriorFactor


def _chain(G, n, conv=None, seed=0, closures=3):
    """A long chain with a weak prior, anisotropic odometry noise and ``closures`` loop
    closures between its first half and its last third, started off the optimum."""
    rng = np.random.default_rng(seed)
    d = G.dof
    steps = rng.normal(size=(n - 1, d)) * 0.05
    steps[:, 0] += 1.0                                  # forward motion
    Z = G.exp(steps)
    X = [G.identity()]
    for k in range(n - 1):
        X.append(X[-1].compose(Z[k]))
    Xt = G.from_params(np.stack([x.params for x in X]))
    X0 = Xt.plus(rng.normal(size=(n, d)) * 0.05)
    g = FactorGraph()
    x = g.add_variables(G.from_params(conv(X0.params), check=False) if conv else X0)
    half = d // 2 if G is SE3 else 2
    g.add(PriorFactor(x, 0, G.identity(), Diagonal([1e-3] * d)))
    g.add(BetweenFactor(x, np.arange(n - 1), np.arange(1, n),
                        Z.compose(G.exp(rng.normal(size=(n - 1, d)) * 0.01)),
                        Diagonal([0.01] * half + [0.001] * (d - half))))
    i = rng.choice(n // 2, closures, replace=False)
    j = n - 1 - rng.choice(n // 3, closures, replace=False)
    Zc = Xt[i].inverse().compose(Xt[j]).compose(G.exp(rng.normal(size=(closures, d)) * 0.01))
    g.add(BetweenFactor(x, i, j, Zc, Diagonal([0.05] * d)))
    return g, x


def _linearised(G, n, seed=0):
    torch = require("torch")
    from microlie.optim.device import DeviceProblem
    from microlie.optim.device.dense import normal_equations

    g, _ = _chain(G, n, torch.tensor, seed, closures=6)
    p = DeviceProblem.from_graph(g)
    th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    xs = [a[None] for a in p.initial()]
    lin = p.linearize(th, xs)
    H, _ = normal_equations(p, lin)
    return torch, p, xs, lin, H[0].numpy()


def test_tree_preconditioner_solves_the_tree_system():
    """``M`` = the diagonal blocks and the tree's off-diagonal blocks of ``H + diag(d)``,
    solved by dense NumPy, equals the level-order tree elimination."""
    from microlie.optim.device.pcg import block_diagonal
    from microlie.optim.device.precondition import tree_edges, tree_plan, tree_preconditioner

    torch, p, _, lin, H = _linearised(SE3, 45)
    d = 6
    plan = tree_plan(p)
    assert len(plan.edges) == 44 and plan.depth <= 8       # log-depth, not 45 levels
    M = np.zeros_like(H)
    for i in range(45):
        M[i * d:(i + 1) * d, i * d:(i + 1) * d] = H[i * d:(i + 1) * d, i * d:(i + 1) * d]
    for u, w in plan.edges:
        M[u * d:(u + 1) * d, w * d:(w + 1) * d] = H[u * d:(u + 1) * d, w * d:(w + 1) * d]
        M[w * d:(w + 1) * d, u * d:(u + 1) * d] = H[w * d:(w + 1) * d, u * d:(u + 1) * d]
    rng = np.random.default_rng(1)
    damp = rng.uniform(1e-3, 1.0, size=H.shape[0])
    apply = tree_preconditioner(p, plan, block_diagonal(p, lin), tree_edges(p, plan, lin),
                                torch.tensor(damp)[None], lambda v: 0.0 * v)
    v = rng.normal(size=(1, H.shape[0]))
    ref = np.linalg.solve(M + np.diag(damp), v[0])
    got = apply(torch.tensor(v))[0].numpy()
    assert np.abs(got - ref).max() <= 1e-9 * np.abs(ref).max()


def test_two_level_preconditioner_equals_the_dense_formula():
    """``S^-1 v + P (P^T (H + D) P)^-1 P^T v`` with ``P_i = Ad(X_i^-1 X_ref)`` from the NumPy
    group, by dense NumPy."""
    from microlie.optim.device.precondition import (
        coarse_basis,
        coarse_matrix,
        coarse_plan,
        two_level,
    )

    torch, p, xs, lin, H = _linearised(SE2, 30)
    d, s = 3, 4
    plan = coarse_plan(p, s)
    assert plan.aggregates == 8
    X = SE2.from_params(xs[0][0].numpy())
    n = 30
    P = np.zeros((n * d, plan.aggregates * d))
    for i in range(n):
        r = i - i % s
        P[i * d:(i + 1) * d, (i // s) * d:(i // s + 1) * d] = \
            X[i].inverse().compose(X[r]).adjoint()
    rng = np.random.default_rng(2)
    damp = rng.uniform(1e-6, 1e-3, size=n * d)
    A = H + np.diag(damp)
    S = np.diag(rng.uniform(0.5, 2.0, size=n * d))
    Pd = coarse_basis(p, plan, xs)
    apply = two_level(p, plan, Pd, coarse_matrix(p, plan, lin, Pd), torch.tensor(damp)[None],
                      lambda v: v * torch.tensor(np.diag(S))[None])
    v = rng.normal(size=(1, n * d))
    ref = S @ v[0] + P @ np.linalg.solve(P.T @ A @ P, P.T @ v[0])
    got = apply(torch.tensor(v))[0].numpy()
    assert np.abs(got - ref).max() <= 1e-8 * np.abs(ref).max()


def _conv(backend, dtype):
    if backend == "torch":
        torch = require("torch")
        return lambda a: torch.tensor(np.array(a, dtype=dtype))
    # float32: JAX's default mode, as users run it ("jax+x64": float32 arrays with x64 on, the
    # preconditioner in float64)
    _jax(x64=dtype == "float64" or backend == "jax+x64")
    import jax.numpy as jnp

    return lambda a: jnp.asarray(np.array(a, dtype=dtype))


@pytest.mark.parametrize("backend", ["torch", "jax"])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_pcg_on_an_ill_conditioned_chain_reaches_the_numpy_cost(backend, dtype):
    from microlie.optim.core.variables import Values
    from microlie.optim.device import DeviceProblem, LMOptions, solve

    gn, _ = _chain(SE2, 160)
    tight = dict(rel_tol=1e-12, abs_tol=0.0)
    ref = gn.optimize(**tight)
    g, _ = _chain(SE2, 160, _conv(backend, dtype))
    p = DeviceProblem.from_graph(g)
    opts = LMOptions(linear="pcg", max_iter=30, **tight)
    if backend == "jax":
        import jax

        x, info = jax.jit(lambda th, x0: solve(p, th, x0, opts))(p.theta(), p.initial())
    else:
        x, info = solve(p, p.theta(), p.initial(), opts)
    vals = Values(p.variables, [np.asarray(p.backend.to_numpy(a), dtype=np.float64) for a in x])
    rel = (g.cost(vals) - ref.final_cost) / ref.final_cost     # evaluated by NumPy
    assert abs(rel) <= (1e-8 if dtype == "float64" else 1e-4)
    # the coarse level does the work: tens of CG iterations per step (block-Jacobi alone: ~430)
    assert int(info.cg_iterations) <= 100 * int(info.tries)


def test_preconditioner_options_are_checked():
    torch = require("torch")
    from microlie.optim.device import DeviceProblem, LMOptions, solve

    with pytest.raises(ValueError, match="precondition"):
        LMOptions(precondition="ilu")
    with pytest.raises(ValueError, match="coarse"):
        LMOptions(coarse=-2)
    g = FactorGraph()
    x = g.add_variables(torch.zeros((3, 2)).double())
    g.add(PriorFactor(x, [0, 1, 2], [[1.0, 2.0]] * 3))
    p = DeviceProblem.from_graph(g)
    with pytest.raises(ValueError, match="precondition='tree' needs"):
        solve(p, p.theta(), p.initial(), LMOptions(linear="pcg", precondition="tree"))
    _, info = solve(p, p.theta(), p.initial(), LMOptions(linear="pcg"))   # no pose batch
    assert float(info.cost) < 1e-20


def test_batched_pcg_with_the_coarse_level_equals_the_dense_solves():
    """Two starts of one chain in one batch: each PCG solve equals the batched dense-Cholesky
    solve of the same problem (each problem its own coarse matrix and damping)."""
    torch = require("torch")
    from microlie.optim.device import DeviceProblem, LMOptions, solve, stack

    g, _ = _chain(SE2, 60, torch.tensor)
    p = DeviceProblem.from_graph(g)
    x0 = p.initial()
    kick = torch.tensor(np.random.default_rng(3).normal(size=(60, 3)) * 0.05)
    x1 = [SE2.from_params(x0[0]).plus(kick).params]
    th, xs = stack([p.theta(), p.theta()]), stack([x0, x1])
    tight = dict(max_iter=30, rel_tol=1e-12, abs_tol=0.0)
    _, info = solve(p, th, xs, LMOptions(linear="pcg", **tight))
    _, ref = solve(p, th, xs, LMOptions(linear="dense", **tight))
    assert (info.status == 1).all()
    assert ((info.cost - ref.cost).abs() <= 1e-10 * ref.cost).all()


def _garage(n, conv=None, seed=0):
    """A parking-garage-like SE3 graph: a two-turn helix of ``n`` poses (0.5 m steps,
    climbing), closures between the turns, unit-information edges whose measurements agree to
    1% of their noise (a small optimal cost), and GTSAM's gauge prior on the first pose at the
    identity with standard deviation 1e-6 (information 1e12)."""
    rng = np.random.default_rng(seed)
    steps = np.zeros((n - 1, 6))
    steps[:, 0], steps[:, 2], steps[:, 5] = 0.5, 0.0125, 4 * np.pi / n
    steps += rng.normal(size=steps.shape) * 0.01
    Z = SE3.exp(steps)
    X = [SE3.identity()]
    for k in range(n - 1):
        X.append(X[-1].compose(Z[k]))
    Xt = SE3.from_params(np.stack([x.params for x in X]))
    X0 = Xt.plus(rng.normal(size=(n, 6)) * 0.02)
    g = FactorGraph()
    x = g.add_variables(SE3.from_params(conv(X0.params), check=False) if conv else X0)
    g.add(PriorFactor(x, 0, Xt[0], Diagonal([1e-6] * 6)))
    g.add(BetweenFactor(x, np.arange(n - 1), np.arange(1, n),
                        Z.compose(SE3.exp(rng.normal(size=(n - 1, 6)) * 0.01))))
    i = np.arange(8) * 3 + 1
    j = i + n // 2
    Zc = Xt[i].inverse().compose(Xt[j]).compose(SE3.exp(rng.normal(size=(8, 6)) * 0.01))
    g.add(BetweenFactor(x, i, j, Zc))
    return g


@pytest.mark.parametrize("backend", ["torch", "jax", "jax+x64"])
def test_float32_pcg_with_a_strong_prior_reaches_the_numpy_cost(backend):
    """float32 PCG on a pose graph whose gauge prior has information 1e12 (GTSAM's, as
    ``PoseGraph.to_factor_graph`` adds it to files without FIX lines): the float32 LM reaches
    the NumPy engine's float64 cost to 1e-4. On torch the preconditioner's coarse level is
    accumulated and factored in float64; on JAX the test runs as users do by default, without
    ``jax_enable_x64``, so everything is float32, and it is the Jacobi-scaled coarse factor
    that makes it (with a jitter of a few float32 ``eps`` times the largest diagonal entry it
    ignored every slow mode: that solve ended 1.3e-3 above the optimum)."""
    from microlie.optim.core.variables import Values
    from microlie.optim.device import DeviceProblem, LMOptions, solve

    ref = _garage(200).optimize(rel_tol=1e-12, abs_tol=0.0)
    g = _garage(200, _conv(backend, "float32"))
    p = DeviceProblem.from_graph(g)
    assert p.backend.dtype_name == "float32"
    opts = LMOptions(linear="pcg", max_iter=30, cg_max_iter=500)
    if backend.startswith("jax"):
        import jax

        x, info = jax.jit(lambda th, x0: solve(p, th, x0, opts))(p.theta(), p.initial())
    else:
        x, info = solve(p, p.theta(), p.initial(), opts)
    assert all(str(a.dtype).endswith("float32") for a in x)
    vals = Values(p.variables, [np.asarray(p.backend.to_numpy(a), dtype=np.float64) for a in x])
    rel = (g.cost(vals) - ref.final_cost) / ref.final_cost     # evaluated by NumPy
    assert int(info.status) == 1
    assert abs(rel) <= 1e-4
