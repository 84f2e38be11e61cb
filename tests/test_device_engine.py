"""The device engine (``microlie.optim.device``, issue 24): graphs on torch and JAX arrays solved
by Levenberg-Marquardt with the NumPy engine's rules. Every solve is checked against the NumPy
engine's solve of the same graph (an independent implementation: sparse Cholesky, its own
linearisation and retraction), problem by problem for batches."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import _jax, require

from microlie import SE2, SE3
from microlie.optim import (
    BetweenFactor,
    CustomFactor,
    Diagonal,
    FactorGraph,
    PriorFactor,
    ReprojectionFactor,
)
from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene


def _torch():
    return require("torch")


def _conv(backend, dtype="float64"):
    if backend == "torch":
        torch = _torch()
        return lambda a: torch.tensor(np.array(a, dtype=dtype))
    _jax(x64=dtype == "float64")  # float32: JAX's default mode, as users run it
    import jax.numpy as jnp

    return lambda a: jnp.asarray(np.array(a, dtype=dtype))


def _chain(conv, seed=0, n=10, group=SE3):
    """A pose chain with a prior, odometry and two loop closures, from a perturbed start."""
    rng = np.random.default_rng(seed)
    d = group.dof
    X0 = group.exp(rng.normal(size=(n, d)) * 0.3)
    Z = group.exp(rng.normal(size=(n - 1, d)) * 0.5)
    Zc = group.exp(rng.normal(size=(2, d)))
    g = FactorGraph()
    x = g.add_variables(group.from_params(conv(X0.params), check=False) if conv else X0)
    g.add(PriorFactor(x, 0, group.identity(), Diagonal([0.1] * d)))
    g.add(BetweenFactor(x, np.arange(n - 1), np.arange(1, n), Z,
                        Diagonal(np.linspace(0.05, 0.2, d))))
    g.add(BetweenFactor(x, [0, 2], [n // 2, n - 1], Zc, Diagonal([0.2] * d)))
    return g, x


def _np(a):
    return a.detach().cpu().numpy() if hasattr(a, "detach") else np.asarray(a)


@pytest.mark.parametrize("backend", ["torch", "jax"])
def test_optimize_on_device_equals_the_numpy_engine(backend):
    from microlie import R

    group = SE3 if backend == "torch" else R(3)   # vectors keep JAX's compile short
    g, x = _chain(_conv(backend), seed=1, group=group)
    gn, xn = _chain(None, seed=1, group=group)
    ref = gn.optimize()
    res = g.optimize()
    assert res.linear_solver == f"{backend}:dense"
    p = res.values[x]
    p = getattr(p, "params", p)
    assert type(p).__module__.split(".")[0] in ("torch", "jaxlib", "jax")
    assert str(p.dtype).endswith("float64")
    assert res.converged and res.iterations == ref.iterations
    pn = ref.values[xn]
    assert np.abs(_np(p) - getattr(pn, "params", pn)).max() < 1e-8
    assert abs(res.final_cost - ref.final_cost) <= 1e-10 * ref.final_cost
    assert abs(res.initial_cost - ref.initial_cost) <= 1e-12 * ref.initial_cost


@pytest.mark.parametrize("backend", ["torch", "jax"])
def test_float32_solve_reaches_the_float64_cost(backend):
    """float32 variables give a float32 solve (on JAX with x64 off, its default) that ends
    at the NumPy engine's float64 cost to float32 accuracy."""
    g, x = _chain(_conv(backend, "float32"), seed=2)
    gn, _ = _chain(None, seed=2)
    ref = gn.optimize()
    res = g.optimize()
    assert str(res.values[x].params.dtype).endswith("float32")
    assert abs(res.final_cost - ref.final_cost) <= 1e-4 * ref.final_cost


def test_fixed_variables_held_components_and_vectors():
    torch = _torch()
    rng = np.random.default_rng(3)

    def build(conv):
        g = FactorGraph()
        X0 = SE3.exp(rng_a.normal(size=(6, 6)) * 0.3)
        x = g.add_variables(SE3.from_params(conv(X0.params)) if conv else X0, fixed=[0])
        v = g.add_variables(conv(rng_a.normal(size=(4, 3))) if conv else
                            rng_a.normal(size=(4, 3)))
        g.fix(x, [2, 3], components=[3, 4])
        g.add(BetweenFactor(x, [0, 1, 2, 3, 4], [1, 2, 3, 4, 5],
                            SE3.exp(rng_a.normal(size=(5, 6)) * 0.4), Diagonal([0.1] * 6)))
        g.add(PriorFactor(v, [0, 1], rng_a.normal(size=(2, 3)), Diagonal([0.5] * 3)))
        g.add(BetweenFactor(v, [0, 1, 2], [1, 2, 3], rng_a.normal(size=(3, 3))))
        return g, x, v

    seed = int(rng.integers(1 << 30))
    rng_a = np.random.default_rng(seed)
    gn, xn, vn = build(None)
    rng_a = np.random.default_rng(seed)
    g, x, v = build(lambda a: torch.tensor(np.array(a)))
    ref, res = gn.optimize(), g.optimize()
    P = _np(res.values[x].params)
    assert np.abs(P - ref.values[xn].params).max() < 1e-8
    assert np.abs(_np(res.values[v]) - ref.values[vn]).max() < 1e-8
    assert np.array_equal(P[0], np.asarray(SE3.from_params(gn.variables[0].initial).params[0]))
    # the held rotation components (tangent 3, 4) did not move: rotation of x[2] differs from
    # its start by a rotation about z only
    R0 = SE3.from_params(gn.variables[0].initial[2]).rotation()
    R1 = SE3.from_params(P[2]).rotation()
    w = (R0.inverse().compose(R1)).log()
    assert abs(w[0]) < 1e-12 and abs(w[1]) < 1e-12 and abs(w[2]) > 1e-6


def test_batch_of_pose_graphs_each_equal_to_its_numpy_solve():
    torch = _torch()
    from microlie.optim.device import DeviceProblem, LMOptions, solve, stack

    B = 12
    graphs = [_chain(lambda a: torch.tensor(np.array(a)), seed=100 + b)[0] for b in range(B)]
    probs = [DeviceProblem.from_graph(gb) for gb in graphs]
    theta = stack([pb.theta() for pb in probs])
    x0 = stack([pb.initial() for pb in probs])
    xs, info = solve(probs[0], theta, x0, LMOptions())
    assert xs[0].shape == (B, 10, 7) and info.cost.shape == (B,)
    for b in range(B):
        gn, xn = _chain(None, seed=100 + b)
        ref = gn.optimize()
        assert int(info.iterations[b]) == ref.iterations
        assert int(info.status[b]) == 1
        assert np.abs(_np(xs[0][b]) - ref.values[xn].params).max() < 1e-8
        assert abs(float(info.cost[b]) - ref.final_cost) <= 1e-10 * ref.final_cost


def _pnp(seed, conv=None, n=12):
    """Perspective-n-point: one SE3 pose (world-to-camera) from fixed 3-D points and pixels."""
    rng = np.random.default_rng(seed)
    T = SE3.exp(np.r_[0.1 * rng.normal(size=3), 0.1 * rng.normal(size=3)])
    X = rng.uniform(-1, 1, (n, 3)) + [0.0, 0.0, 5.0]
    P = T.act(X)
    K = np.array([500.0, 480.0, 320.0, 240.0])
    uv = K[:2] * P[:, :2] / P[:, 2:] + K[2:] + rng.normal(size=(n, 2))
    T0 = T.compose(SE3.exp(0.05 * rng.normal(size=6)))
    g = FactorGraph()
    pose = g.add_variables(SE3.from_params(conv(T0.params[None]) if conv else
                                           T0.params[None]), name="T")
    pts = g.add_variables(conv(X) if conv else X, fixed=True, name="X")
    g.add(ReprojectionFactor((pose, np.zeros(n, int)), (pts, np.arange(n)), uv,
                             model="pinhole", intrinsics=K, noise=Diagonal([1.0, 1.0])))
    return g, pose


def test_batch_of_pnp_problems_each_equal_to_its_numpy_solve():
    torch = _torch()
    from microlie.optim.device import DeviceProblem, solve, stack

    B = 10
    conv = lambda a: torch.tensor(np.array(a))  # noqa: E731
    probs = [DeviceProblem.from_graph(_pnp(s, conv)[0]) for s in range(B)]
    xs, info = solve(probs[0], stack([p.theta() for p in probs]),
                     stack([p.initial() for p in probs]))
    for b in range(B):
        gn, pn = _pnp(b)
        ref = gn.optimize()
        assert int(info.iterations[b]) == ref.iterations
        assert np.abs(_np(xs[0][b]) - ref.values[pn].params).max() < 1e-8


def test_pcg_steps_reach_the_numpy_cost():
    torch = _torch()
    g, x = _chain(lambda a: torch.tensor(np.array(a)), seed=5, n=16)
    gn, _ = _chain(None, seed=5, n=16)
    tight = dict(rel_tol=1e-12, abs_tol=0.0)
    ref = gn.optimize(**tight)
    res = g.optimize(linear_solver="pcg", **tight)
    assert res.linear_solver == "torch:pcg"
    assert abs(res.final_cost - ref.final_cost) <= 1e-8 * ref.final_cost


def test_schur_pcg_bundle_adjustment_reaches_the_numpy_cost():
    from microlie.optim.device import DeviceProblem, LMOptions, solve

    _torch()
    _, start = synthetic_scene(4, 30, noise=0.5, perturb=0.05, seed=4)
    bg = bundle_graph(start, fix_cameras=[0], fix_points=[0])
    tight = dict(rel_tol=1e-12, abs_tol=0.0)
    ref = bg.graph.optimize(solver="lm", linear_solver="schur", **tight)
    p = DeviceProblem.from_graph(bg.graph, backend="torch")
    assert p.eliminate == [3]      # the points
    _, info = solve(p, p.theta(), p.initial(), LMOptions(linear="pcg", **tight))
    assert int(info.cg_iterations) > 0
    assert abs(float(info.cost) - ref.final_cost) <= 1e-8 * ref.final_cost
    _, dense = solve(p, p.theta(), p.initial(), LMOptions(linear="dense", **tight))
    assert abs(float(dense.cost) - ref.final_cost) <= 1e-10 * ref.final_cost


def test_errors_name_what_is_wrong():
    torch = _torch()
    _jax()
    import jax.numpy as jnp

    from microlie.optim.device import LMOptions

    g = FactorGraph()
    g.add_variables(SE2.from_params(torch.tensor([[0.0, 0, 1, 0]], dtype=torch.float64)))
    x2 = g.add_variables(SE2.from_params(jnp.asarray([[0.0, 0, 1, 0]])))
    g.add(PriorFactor(x2, 0, SE2.identity()))
    with pytest.raises(ValueError, match="torch.*JAX"):
        g.optimize(gauge="none")
    g = FactorGraph()
    x = g.add_variables(SE2.from_params(torch.tensor([[0.0, 0, 1, 0]], dtype=torch.float64)))
    f = g.add(PriorFactor(x, 0, SE2.identity(), loss="huber:1"))
    with pytest.raises(ValueError, match="PriorFactor.*robust"):
        g.optimize()
    g.remove(f)
    g.add(CustomFactor(lambda X: X.params[..., :2], [(x, 0)], 2))
    with pytest.raises(ValueError, match="CustomFactor"):
        g.optimize()
    with pytest.raises(ValueError, match="solver"):
        g.optimize(solver="gn")
    with pytest.raises(ValueError, match="linear_solver"):
        g.optimize(linear_solver="cholesky")
    with pytest.raises(ValueError, match="max_iter"):
        LMOptions(max_iter=-1)
    with pytest.raises(ValueError, match="linear"):
        LMOptions(linear="qr")


def test_jax_jit_batch_each_equal_to_its_numpy_solve():
    jax = _jax()
    import jax.numpy as jnp

    from microlie.optim.device import DeviceProblem, LMOptions, solve, stack

    B = 4
    probs = [DeviceProblem.from_graph(_chain(jnp.asarray, seed=200 + b, n=6, group=SE2)[0])
             for b in range(B)]
    p, opts = probs[0], LMOptions()
    fn = jax.jit(lambda th, x: solve(p, th, x, opts))
    xs, info = fn(stack([q.theta() for q in probs]), stack([q.initial() for q in probs]))
    for b in range(B):
        gn, xn = _chain(None, seed=200 + b, n=6, group=SE2)
        ref = gn.optimize()
        assert int(info.iterations[b]) == ref.iterations and int(info.status[b]) == 1
        assert np.abs(np.asarray(xs[0][b]) - ref.values[xn].params).max() < 1e-8
