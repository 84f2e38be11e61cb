"""IncrementalSmoother against dense linear algebra and the batch solver on the same graph."""

import numpy as np
import pytest
from conftest import data_file

from microlie import SE2, SE3
from microlie.optim import (
    BetweenFactor,
    Diagonal,
    FactorGraph,
    IncrementalSmoother,
    PriorFactor,
)
from microlie.optim.io.g2o import read_g2o
from microlie.optim.io.pose_graph import PoseGraph
from microlie.optim.online.replay import replay_pose_graph

FORCED = {"relinearize_threshold": 1e-8, "relinearize_skip": 1, "wildfire": 0.0}


def _synthetic(group, n, loops, seed):
    """A noisy pose chain with loop closures (random later-to-earlier edges)."""
    rng = np.random.default_rng(seed)
    d = group.dof
    step = np.zeros(d)
    step[0] = 1.0
    step[-1] = 0.3
    truth = [group.identity()]
    for _ in range(n - 1):
        truth.append(truth[-1] @ group.exp(step + 0.2 * rng.standard_normal(d)))
    X = group(np.stack([t.params for t in truth]))
    i = list(range(n - 1))
    j = list(range(1, n))
    for _ in range(loops):
        b = int(rng.integers(5, n))
        a = int(rng.integers(0, b - 2))
        i.append(a)
        j.append(b)
    i, j = np.array(i), np.array(j)
    Z = (X[i].inverse() @ X[j]) @ group.exp(0.05 * rng.standard_normal((i.size, d)))
    A = rng.standard_normal((i.size, d, d)) * 0.1
    info = 50.0 * (np.eye(d) + A @ np.swapaxes(A, 1, 2))  # full, positive definite
    noisy = X @ group.exp(0.3 * rng.standard_normal((n, d)))
    return PoseGraph(group, ids=np.arange(n), poses=noisy, i=i, j=j, measurements=Z,
                     information=info)


def _dense_step(s, x, k):
    """The Gauss-Newton step of the accumulated graph (poses 0..k) at the smoother's
    linearisation point, solved densely, applied to that point."""
    g = s.graph
    saved = x.fixed.copy()
    x.fixed = np.arange(x.n) > k
    try:
        lp = s.linearization_point()
        prob = g.problem("none")
        states = [np.asarray(lp.params(v)) for v in g.variables]
        lin = prob.linearize(states)
        H = prob.matrix(lin.data).toarray()
        dx = np.linalg.solve(H, -lin.grad)
        after = prob.retract(states, dx)
        return after[x.key][: k + 1], H, prob
    finally:
        x.fixed = saved


def _batch(s, x, k):
    g = s.graph
    saved = x.fixed.copy()
    x.fixed = np.arange(x.n) > k
    try:
        res = g.optimize(s.calculate_estimate(), solver="gn", rel_tol=1e-14, abs_tol=1e-14,
                         max_iter=50)
        return res.values.params(x)[: k + 1]
    finally:
        x.fixed = saved


def _close(P, Q, tol):
    return np.max(np.abs(P - Q)) <= tol * max(1.0, np.max(np.abs(Q)))


def _check_replay(graph, points):
    hits = []

    def cb(k, s):
        if k not in points:
            return
        x = s.graph.variables[0]
        # the factorisation after the update: the estimate is the dense Gauss-Newton step
        expect, _, _ = _dense_step(s, x, k)
        got = s.calculate_estimate(x, np.arange(k + 1)).params
        assert _close(got, expect, 1e-8), (k, np.max(np.abs(got - expect)))
        hits.append(k)

    rep = replay_pose_graph(graph, IncrementalSmoother(**FORCED), until=max(points) + 1,
                            callback=cb)
    assert sorted(hits) == sorted(points)
    s, x = rep["smoother"], rep["poses"]
    k = max(points)
    for _ in range(8):  # empty updates with forced relinearisation: Gauss-Newton iterations
        s.update([])
    assert _close(s.calculate_estimate(x, np.arange(k + 1)).params, _batch(s, x, k), 1e-8)
    return rep


@pytest.mark.parametrize("group", [SE2, SE3])
def test_forced_relinearisation_equals_batch_synthetic(group):
    graph = _synthetic(group, 80, 25, seed=3)
    _check_replay(graph, [10, 37, 60, 79])


def test_forced_relinearisation_equals_batch_m3500():
    graph = read_g2o(data_file("pose_graph/input_M3500_g2o.g2o"))
    _check_replay(graph, [40, 150, 260])


def test_default_replay_near_batch_optimum():
    """GTSAM's defaults (threshold 0.1, skip 10, wildfire 0.001): the final cost near the batch
    optimum of the same graph (steps below the threshold are left unapplied to the
    linearisation, so not equal), and equal to it after one batch optimize()."""
    graph = _synthetic(SE2, 150, 40, seed=5)
    rep = replay_pose_graph(graph)
    fg, _ = graph.to_factor_graph()  # GTSAM's gauge prior (sigma 1e-6) on the first pose
    best = fg.optimize(rel_tol=1e-12, abs_tol=1e-12).final_cost
    assert best - 1e-9 * best <= rep["final_cost"] <= 1.02 * best
    res = rep["smoother"].optimize(rel_tol=1e-12, abs_tol=1e-12)
    assert abs(res.final_cost - best) <= 1e-6 * best


def test_marginals_equal_dense_inverse():
    graph = _synthetic(SE3, 40, 12, seed=7)
    rep = replay_pose_graph(graph, IncrementalSmoother(relinearize_threshold=0.05))
    s, x = rep["smoother"], rep["poses"]
    _, H, prob = _dense_step(s, x, 39)
    C = np.linalg.inv(H)
    for i in (0, 7, 23, 39):
        node = prob.node_of[prob.key(x)][i]
        o = prob.node_off[node]
        ref = C[o:o + 6, o:o + 6]
        got = s.marginal_covariance(x, i)
        assert np.max(np.abs(got - ref)) <= 1e-9 * np.max(np.abs(ref))


def test_remove_factor_equals_batch_without_it():
    graph = _synthetic(SE2, 60, 15, seed=11)
    rep = replay_pose_graph(graph, IncrementalSmoother(**FORCED))
    s, x = rep["smoother"], rep["poses"]
    bad = BetweenFactor(x, 3, 50, SE2.exp([1.0, -1.0, 0.3]), Diagonal([0.1, 0.1, 0.05]))
    s.update([bad])
    s.update([])
    with_bad = s.calculate_estimate(x).params.copy()
    rec = s.remove_factors([bad])
    assert rec.factors_removed == 1
    assert bad not in s.graph.factors
    for _ in range(20):  # Gauss-Newton on a problem with residuals: linear convergence
        s.update([])
    # the batch solve of the graph without the outlier, from the estimate that had it
    ref = FactorGraph()
    y = ref.add_variables(SE2(with_bad))
    for f in s.graph.factors:
        if isinstance(f, BetweenFactor):
            ref.add(BetweenFactor(y, f.args[0][1], f.args[1][1], f.Z, f.noise))
        else:
            ref.add(PriorFactor(y, f.args[0][1], f.Z, f.noise))
    best = ref.optimize(rel_tol=1e-15, abs_tol=1e-15, max_iter=200).values.params(y)
    got = s.calculate_estimate(x).params
    assert _close(got, best, 1e-8)
    assert np.max(np.abs(with_bad - best)) > 1e-2  # the outlier had moved the estimate


def test_bad_input():
    s = IncrementalSmoother()
    x = s.add_variables(SE2.identity(3))
    sig = Diagonal([0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match="relinearize_threshold"):
        IncrementalSmoother(relinearize_threshold=-1.0)
    with pytest.raises(ValueError, match="relinearize_skip"):
        IncrementalSmoother(relinearize_skip=0)
    with pytest.raises(ValueError, match="wildfire"):
        IncrementalSmoother(wildfire=float("nan"))
    with pytest.raises(ValueError, match="has not entered"):
        s.marginal_covariance(x, 0)
    other = FactorGraph().add_variables(SE2.identity(1))
    with pytest.raises(ValueError, match="another graph"):
        s.update([PriorFactor(other, 0, SE2.identity(), sig)])
    with pytest.raises(TypeError, match="Factor"):
        s.update(["not a factor"])
    prior = PriorFactor(x, 0, SE2.identity(), sig)
    s.update([prior])
    with pytest.raises(ValueError, match="already added"):
        s.update([prior])
    with pytest.raises(ValueError, match="already entered"):
        s.update([], {(x, 0): SE2.identity()})
    with pytest.raises(ValueError, match="not a factor of this smoother"):
        s.remove_factors([PriorFactor(x, 1, SE2.identity(), sig)])
    with pytest.raises(ValueError, match=r"x0\[2\] is not determined"):
        s.update([], {(x, 2): SE2.identity()})
    with pytest.raises(ValueError, match="new_values"):
        IncrementalSmoother().update([], [1, 2])


def _run_command(argv):
    import argparse
    import io
    import json

    from microlie.optim.command import register, run

    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    out = io.StringIO()
    code = run(parser.parse_args(["optimize", *argv]), out, io.StringIO())
    return code, json.loads(out.getvalue())


def test_command_incremental_json(tmp_path):
    from microlie.optim import write_g2o

    graph = _synthetic(SE2, 120, 30, seed=13)
    path = tmp_path / "syn.g2o"
    write_g2o(path, graph)
    code, r = _run_command([str(path), "--incremental", "--json"])
    assert code == 0
    for key in ("final_cost", "updates", "update_ms_median", "update_ms_p99", "total_s",
                "converged"):
        assert key in r
    assert r["updates"] == 120 and isinstance(r["converged"], bool)
    assert r["update_ms_p99"] >= r["update_ms_median"] > 0 and r["total_s"] > 0
    # GTSAM's error over the file's edges: the file graph's cost at the batch optimum is a
    # lower bound, and the replay lands near it
    fg, _ = read_g2o(path).to_factor_graph()
    best = fg.optimize(rel_tol=1e-12, abs_tol=1e-12).final_cost
    assert best * (1 - 1e-9) <= r["final_cost"] <= 1.02 * best


def test_command_incremental_refuses_batch_options(tmp_path):
    from microlie.optim import write_g2o

    path = tmp_path / "syn.g2o"
    write_g2o(path, _synthetic(SE2, 10, 2, seed=1))
    with pytest.raises(ValueError, match="--solver do not apply"):
        _run_command([str(path), "--incremental", "--solver", "gn"])


def test_held_components_refused():
    s = IncrementalSmoother()
    x = s.add_variables(SE3.identity(2))
    x.fix(1, components=[3])
    with pytest.raises(ValueError, match=r"x0\[1\]: held components"):
        s.update([PriorFactor(x, [0, 1], SE3.identity(), Diagonal([0.1] * 6))])


def _mixed_run(seed, compiled=None):
    """SE3 poses and R^2 landmarks (two block sizes) with a robust odometry loss, a fixed
    landmark and a custom pose-landmark factor: every branch of the tree code."""
    from microlie.optim import CustomFactor, Isotropic
    from microlie.optim.online.bayes_tree import BayesTree

    rng = np.random.default_rng(seed)
    s = IncrementalSmoother(relinearize_threshold=0.01, relinearize_skip=2, wildfire=1e-4)
    if compiled is not None:
        s._tree = BayesTree(compiled=compiled)
    n, m = 40, 8
    x = s.add_variables(SE3.exp(0.1 * rng.standard_normal((n, 6))))
    p = s.add_variables(rng.standard_normal((m, 2)), fixed=[0])
    sig = Diagonal([0.1] * 6)

    def sees(X, q):  # the landmark's offset from the pose's (x, y)
        return X.params[..., :2] - q

    s.update([PriorFactor(x, 0, SE3.identity(), sig)])
    for k in range(1, n):
        fs = [BetweenFactor(x, k - 1, k, SE3.exp([1.0, 0, 0, 0, 0, 0.2]), sig, loss="huber:1.0")]
        if k % 3 == 0:
            fs.append(BetweenFactor(x, int(rng.integers(0, k - 1)), k,
                                    SE3.exp(0.3 * rng.standard_normal(6)), sig))
        if k % 2 == 0:
            fs.append(CustomFactor(sees, [(x, k), (p, int(rng.integers(0, m)))], 2,
                                   Isotropic(2, 0.5)))
        s.update(fs)
    return s, x, p


def test_compiled_tree_equals_numpy():
    """The compiled Bayes tree (microlie._c._incremental) against the NumPy one (the same
    ordering code): the same estimate to rounding and the same nodes re-eliminated and
    back-substituted."""
    from microlie import _fast

    if _fast.module("_incremental") is None:
        pytest.skip("microlie._c._incremental is not built")
    s1, x1, p1 = _mixed_run(4, compiled=True)
    s0, x0, p0 = _mixed_run(4, compiled=False)
    assert s1._tree.module is not None and s0._tree.module is None
    assert _close(s1.calculate_estimate(x1).params, s0.calculate_estimate(x0).params, 1e-10)
    assert _close(s1.calculate_estimate(p1), s0.calculate_estimate(p0), 1e-10)
    for a, b in zip(s1.records, s0.records, strict=True):
        assert (a.reeliminated, a.backsubstituted, a.relinearized) == \
            (b.reeliminated, b.backsubstituted, b.relinearized)
    C1, C0 = s1.marginal_covariance(p1, 3), s0.marginal_covariance(p0, 3)
    assert _close(C1, C0, 1e-10)


@pytest.mark.parametrize("fast", ["1", "0"])
def test_mixed_blocks_equal_dense_step(monkeypatch, fast):
    """Two block sizes, a robust loss, a fixed variable, forced relinearisation: the estimate
    after the last update is the dense Gauss-Newton step from the linearisation point."""
    monkeypatch.setenv("MICROLIE_FAST", fast)
    s, x, p = _mixed_run(9)
    s.relinearize_threshold, s.relinearize_skip, s.wildfire = 0.0, 1, 0.0
    s.update([])
    g = s.graph
    lp = s.linearization_point()
    saved = p.fixed.copy()
    p.fixed = p.fixed | ~s._seen[p.key]  # landmarks never observed are not in the estimate
    try:
        prob = g.problem("none")
        states = [np.asarray(lp.params(v)) for v in g.variables]
        lin = prob.linearize(states)
        H = prob.matrix(lin.data).toarray()
        dx = np.linalg.solve(H, -lin.grad)
        after = prob.retract(states, dx)
    finally:
        p.fixed = saved
    assert _close(s.calculate_estimate(x).params, after[x.key], 1e-8)
    assert _close(s.calculate_estimate(p), after[p.key], 1e-8)


@pytest.mark.parametrize("group", [SE2, SE3])
def test_edge_rows_equal_factor_jacobians(group):
    """The compiled edge linearisation (online.edges.EdgeRows) against A = L [J_i J_j] from
    BetweenFactor.evaluate, full information matrices, rows of two batches."""
    from microlie.optim import SqrtInformation
    from microlie.optim.online.edges import EdgeRows

    e = EdgeRows()
    if e.module is None:
        pytest.skip("microlie._c._graph is not built")
    rng = np.random.default_rng(2)
    d = group.dof
    g = FactorGraph()
    x = g.add_variables(group.exp(rng.standard_normal((6, d))))
    L = np.tril(rng.standard_normal((4, d, d))) + 3 * np.eye(d)
    f1 = BetweenFactor(x, [0, 1, 2], [3, 4, 5], group.exp(rng.standard_normal((3, d))),
                       SqrtInformation(L[:3]))
    f2 = BetweenFactor(x, 5, 0, group.exp(rng.standard_normal(d)), SqrtInformation(L[3]))
    e.add(f1, np.array([0, 1, 2]))
    e.add(f2, np.array([3]))
    H: list = [None] * 4
    b: list = [None] * 4
    assert e.linearize([3, 1], [x.initial], H, b) == []
    assert H[0] is None and H[2] is None
    for r in (1, 3):
        Hr, br = H[r], b[r]
        f, k = (f1, r) if r < 3 else (f2, 0)
        vals = [x.initial[f.args[0][1]], x.initial[f.args[1][1]]]
        res, (Ji, Jj) = f.evaluate([x.wrap(v) for v in vals], True)
        Lk = f.noise.sqrt_info.reshape(-1, d, d)[min(k, f.count - 1) if f.count > 1 else 0]
        A = Lk @ np.concatenate([Ji[k], Jj[k]], axis=1)
        assert np.allclose(Hr, A.T @ A, rtol=1e-10, atol=1e-10)
        assert np.allclose(br, -A.T @ (Lk @ res[k]), rtol=1e-10, atol=1e-10)


def test_best_estimate_is_the_complete_step():
    """calculate_best_estimate: the dense Gauss-Newton step of the current factorisation
    (the partial back-substitution of a coarse wildfire leaves calculate_estimate off it)."""
    graph = _synthetic(SE2, 60, 15, seed=13)
    rep = replay_pose_graph(graph, IncrementalSmoother(wildfire=0.05), until=60)
    s, x = rep["smoother"], rep["poses"]
    expect, _, _ = _dense_step(s, x, 59)
    best = s.calculate_best_estimate()[x].params
    assert _close(best, expect, 1e-9)
    assert not _close(s.calculate_estimate(x).params, expect, 1e-6)  # stale steps


def test_wide_fronts_equal_dense_step():
    """Many loop closures: separators above 48 columns (the compiled path's BLAS/LAPACK
    fronts); forced relinearisation, so the estimate is the dense Gauss-Newton step."""
    graph = _synthetic(SE3, 80, 60, seed=21)
    rep = replay_pose_graph(graph, IncrementalSmoother(**FORCED))
    s, x = rep["smoother"], rep["poses"]
    t = s._tree
    assert max(int(t.dof[sp].sum()) for sp in t.sep[:t.n]) >= 48
    expect, _, _ = _dense_step(s, x, 79)
    assert _close(s.calculate_estimate(x).params, expect, 1e-10)
