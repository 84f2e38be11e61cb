"""Exact Schur steps of the device engine (``microlie.optim.device.schur``, issue 24): the
reduced camera system of bundle adjustment formed densely on torch and JAX. Checked against
the dense solve of the full damped normal equations (NumPy) and against the NumPy engine's LM
with its own sparse Schur solver (an independent implementation)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import _jax, require

from microlie import SO3
from microlie.optim import FactorGraph, PriorFactor, ReprojectionFactor
from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene


def _sparse_scene(seed=3, n_cameras=5, n_points=40, keep=0.6, split=False, priors=False,
                  conv=None):
    """A BAL-model scene where each camera sees a random subset of the points (every point
    at least twice); ``split``: the observations in two factor batches (pairs across
    batches); ``priors``: a prior on a camera translation (a term without landmarks) and one
    on a point (a landmark-only term); ``conv``: the variables' arrays (default NumPy)."""
    conv = conv if conv is not None else (lambda a: a)
    rng = np.random.default_rng(seed)
    _, start = synthetic_scene(n_cameras, n_points, noise=0.5, perturb=0.05, seed=seed)
    ci, pi = start.camera_index, start.point_index
    seen = rng.random(len(ci)) < keep
    for p in range(n_points):           # at least two views per point
        rows = np.nonzero(pi == p)[0]
        if seen[rows].sum() < 2:
            seen[rows[:2]] = True
    ci, pi, uv = ci[seen], pi[seen], start.observations[seen]
    g = FactorGraph()
    R = SO3.from_matrix(start.rotations, normalize=True)
    rot = g.add_variables(SO3.from_params(conv(R.params), check=False))
    tr = g.add_variables(conv(start.translations))
    K = g.add_variables(conv(start.intrinsics))
    X = g.add_variables(conv(start.points))
    g.fix(rot, [0])
    g.fix(tr, [0])
    g.fix(X, [0])
    parts = [np.arange(len(ci))] if not split else [np.arange(0, len(ci), 2),
                                                      np.arange(1, len(ci), 2)]
    for rows in parts:
        c, p = ci[rows], pi[rows]
        g.add(ReprojectionFactor(((rot, c), (tr, c)), (X, p), uv[rows], model="bal",
                                 intrinsics=(K, c)))
    if priors:
        g.add(PriorFactor(tr, 1, start.translations[1] + 0.1))
        g.add(PriorFactor(X, 3, start.points[3] - 0.05))
    return g


def _device(g, backend, dtype="float64"):
    from microlie.optim.device import DeviceProblem

    if backend.startswith("jax"):
        # float32: JAX's default mode, as users run it ("jax+x64": float32 arrays with x64
        # on, the Schur step in float64)
        _jax(x64=dtype == "float64" or backend == "jax+x64")
    else:
        require("torch")
    return DeviceProblem.from_graph(g, gauge="none", backend=backend.partition("+")[0],
                                    dtype=dtype)


def _np(a):
    return a.detach().cpu().numpy() if hasattr(a, "detach") else np.asarray(a)


@pytest.mark.parametrize("backend,split,priors", [("torch", False, False),
                                                   ("torch", True, True), ("jax", True, True)])
def test_schur_step_equals_the_dense_damped_solve(backend, split, priors):
    from microlie.optim.device.dense import normal_equations
    from microlie.optim.device.pcg import block_diagonal
    from microlie.optim.device.schur import schur_plan, schur_step

    g = _sparse_scene(split=split, priors=priors)
    p = _device(g, backend)
    assert p.eliminate == [3]
    plan = schur_plan(p)
    assert len(plan.pairs) == (4 if split else 1)   # cross-batch pairs when split
    th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())

    def both(th, x, d):
        lin = p.linearize(th, x)
        H, grad = normal_equations(p, lin)
        return H, grad, schur_step(p, lin, grad, block_diagonal(p, lin), d)

    if backend == "jax":   # one compiled call (JAX's eager dispatch is slow)
        import jax

        both = jax.jit(both)
    rng = np.random.default_rng(0)
    dn = 10.0 ** rng.uniform(-4, 0, size=p.size)            # any positive damping
    H, grad, (dx, ok) = both(th, [a[None] for a in p.initial()], p.backend.asarray(dn[None]))
    Hn, gn = _np(H)[0], _np(grad)[0]
    ref = np.linalg.solve(Hn + np.diag(dn), -gn)
    assert bool(_np(ok)[0])
    assert np.abs(_np(dx)[0] - ref).max() <= 1e-9 * np.abs(ref).max()


@pytest.mark.parametrize("backend", ["torch"])   # JAX: test_schur_under_jax_jit
def test_schur_lm_reaches_the_numpy_engine(backend):
    from microlie.optim.device import LMOptions, solve

    g = _sparse_scene(split=True, priors=True)
    tight = dict(rel_tol=1e-12, abs_tol=0.0)
    ref = g.optimize(solver="lm", linear_solver="schur", gauge="none", **tight)
    p = _device(g, backend)
    x, info = solve(p, p.theta(), p.initial(), LMOptions(linear="schur", **tight))
    assert int(info.status) == 1 and int(info.cg_iterations) == 0
    assert abs(float(info.cost) - ref.final_cost) <= 1e-8 * ref.final_cost
    for k, v in enumerate(p.variables):
        assert np.abs(_np(x[k]) - ref.values.params(v)).max() < 1e-6


@pytest.mark.parametrize("backend", ["torch", "jax", "jax+x64"])
def test_schur_float32_reaches_the_numpy_cost(backend):
    from microlie.optim.device import LMOptions, solve

    g = _sparse_scene(seed=5)
    ref = g.optimize(solver="lm", linear_solver="schur", gauge="none")
    p = _device(g, backend, "float32")
    f = solve
    if backend.startswith("jax"):
        import jax

        f = jax.jit(solve, static_argnums=(0, 3))
    x, info = f(p, p.theta(), p.initial(), LMOptions(linear="schur"))
    assert _np(x[0]).dtype == np.float32 and _np(info.cost).dtype == np.float32
    from microlie.optim.core.variables import Values

    cost = g.cost(Values(p.variables, [_np(a).astype(np.float64) for a in x]))
    assert abs(cost - ref.final_cost) <= 1e-4 * ref.final_cost


@pytest.mark.parametrize("backend", ["torch", "jax"])
def test_schur_float32_step_is_solved_in_float64(backend):
    """Mixed precision: the step of a float32 linearisation equals the float64 dense solve of
    the same float32 Jacobians and gradient (lightly damped: ill-conditioned) to far below a
    float32 solve's error."""
    from microlie.optim.device.dense import normal_equations
    from microlie.optim.device.pcg import block_diagonal
    from microlie.optim.device.problem import Linear
    from microlie.optim.device.schur import schur_step

    g = _sparse_scene(split=True, priors=True)
    p = _device(g, backend, "float32")
    p64 = _device(g, backend, "float64")  # on JAX: x64 on from here (float64 must exist)
    th = tuple({k: v[None] for k, v in d.items()} for d in p.theta())
    lin = p.linearize(th, [a[None] for a in p.initial()])
    _, grad = normal_equations(p, lin)
    d = np.full(p.size, 1e-6)
    dx, ok = schur_step(p, lin, grad, block_diagonal(p, lin), p.backend.asarray(d[None]))
    assert _np(dx).dtype == np.float32 and bool(_np(ok)[0])
    up = p64.backend.asarray
    lin64 = Linear([up(_np(e)) for e in lin.e], [[up(_np(a)) for a in Ak] for Ak in lin.A],
                   up(_np(lin.cost)))
    H, _ = normal_equations(p64, lin64)
    ref = np.linalg.solve(_np(H)[0] + np.diag(d), -_np(grad)[0].astype(np.float64))
    assert np.abs(_np(dx)[0] - ref).max() <= 1e-6 * np.abs(ref).max()


def test_schur_under_jax_jit():
    jax = _jax()

    from microlie.optim.device import LMOptions, solve

    g = _sparse_scene(split=True, priors=True)
    tight = dict(rel_tol=1e-12, abs_tol=0.0)
    ref = g.optimize(solver="lm", linear_solver="schur", gauge="none", **tight)
    f = jax.jit(solve, static_argnums=(0, 3))
    p = _device(g, "jax")        # float32: test_schur_float32_reaches_the_numpy_cost (torch)
    _, info = f(p, p.theta(), p.initial(), LMOptions(linear="schur", **tight))
    assert abs(float(info.cost) - ref.final_cost) <= 1e-8 * ref.final_cost


def test_optimize_on_torch_variables_takes_schur_steps():
    torch = require("torch")
    g = _sparse_scene(seed=8)
    ref = g.optimize(solver="lm", linear_solver="schur", gauge="none")
    gt = _sparse_scene(seed=8, conv=lambda a: torch.tensor(np.asarray(a)))
    res = gt.optimize(solver="lm", linear_solver="schur", gauge="none")
    assert res.linear_solver == "torch:schur" and res.iterations == ref.iterations
    assert abs(res.final_cost - ref.final_cost) <= 1e-8 * ref.final_cost


def test_auto_picks_schur_for_bundle_adjustment_and_errors():
    from microlie.optim.device import LMOptions
    from microlie.optim.device.lm import linear_kind
    from microlie.optim.device.schur import schur_plan

    torch = require("torch")
    _, start = synthetic_scene(4, 520, seed=1)          # 4 x 9 + 520 x 3 > DENSE_MAX
    p = _device(bundle_graph(start).graph, "torch")
    assert linear_kind(p, "auto") == "schur" and linear_kind(p, "pcg") == "pcg"
    g = FactorGraph()
    g.add(PriorFactor(g.add_variables(torch.ones((3, 2), dtype=torch.float64)), [0, 1, 2],
                      [0.0, 0.0]))
    q = _device(g, "torch")
    with pytest.raises(ValueError, match="linear='schur'.*no landmarks"):
        linear_kind(q, "schur")
    with pytest.raises(ValueError, match="linear='schur'.*no landmarks"):
        schur_plan(q)
    with pytest.raises(ValueError, match="linear must be"):
        LMOptions(linear="sparse")
