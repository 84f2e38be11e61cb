"""IncrementalSmoother.update_rows (rows of a BetweenFactor batch streamed into the smoother)
and the compiled per-update bookkeeping (microlie._c._online) against the NumPy paths, dense
linear algebra and the batch solver."""

import numpy as np
import pytest

from microlie import SE2, SE3, _fast
from microlie.optim import (
    BetweenFactor,
    Diagonal,
    FactorGraph,
    IncrementalSmoother,
    Information,
    PriorFactor,
)
from microlie.optim.core.variables import Values
from microlie.optim.io.pose_graph import PoseGraph
from microlie.optim.online.replay import replay_pose_graph, replay_schedule


def _graph(group, n, loops, seed):
    """A noisy chain with loop closures and full information matrices (a PoseGraph)."""
    rng = np.random.default_rng(seed)
    d = group.dof
    step = np.zeros(d)
    step[0], step[-1] = 1.0, 0.3
    X = [group.identity()]
    for _ in range(n - 1):
        X.append(X[-1] @ group.exp(step + 0.2 * rng.standard_normal(d)))
    X = group(np.stack([x.params for x in X]))
    i, j = list(range(n - 1)), list(range(1, n))
    for _ in range(loops):
        b = int(rng.integers(5, n))
        i.append(int(rng.integers(0, b - 2)))
        j.append(b)
    i, j = np.array(i), np.array(j)
    Z = (X[i].inverse() @ X[j]) @ group.exp(0.05 * rng.standard_normal((i.size, d)))
    A = 0.1 * rng.standard_normal((i.size, d, d))
    info = 40.0 * (np.eye(d) + A @ np.swapaxes(A, 1, 2))
    noisy = X @ group.exp(0.2 * rng.standard_normal((n, d)))
    return PoseGraph(group, ids=np.arange(n), poses=noisy, i=i, j=j, measurements=Z,
                     information=info)


def _replay_with_factors(graph, s):
    """The replay of replay_pose_graph with one BetweenFactor object per pose (update)."""
    ii, jj = graph.edge_index()
    _, edges, odometry = replay_schedule(graph)
    x = s.add_variables(graph.poses)
    Zs, info = graph.measurements, graph.information
    for k in range(graph.num_vertices):
        if k == 0:
            s.update([PriorFactor(x, 0, graph.poses[0:1], Diagonal([1e-6] * graph.group.dof))])
            continue
        e = edges[k]
        o = int(odometry[k])
        prev = s.calculate_estimate(x, k - 1)
        guess = prev @ (Zs[o:o + 1] if ii[o] == k - 1 else Zs[o:o + 1].inverse())
        s.update([BetweenFactor(x, ii[e], jj[e], Zs[e], Information(info[e]))],
                 {(x, k): guess})
    return x


@pytest.mark.parametrize("fast", ["1", "0"])
@pytest.mark.parametrize("group", [SE2, SE3])
def test_update_rows_equals_update_with_factors(monkeypatch, fast, group):
    """Streaming the rows of one batch gives the estimate of one factor object per update
    (forced relinearisation: Gauss-Newton on the accumulated graph), and the smoother's
    graph holds exactly the file's edges: its cost is the PoseGraph's."""
    monkeypatch.setenv("MICROLIE_FAST", fast)
    graph = _graph(group, 40, 12, seed=4)
    forced = {"relinearize_threshold": 0.0, "relinearize_skip": 1, "wildfire": 0.0}
    s1 = IncrementalSmoother(**forced)
    x1 = _replay_with_factors(graph, s1)
    rep = replay_pose_graph(graph, IncrementalSmoother(**forced), prior_sigma=1e-6)
    s2, x2 = rep["smoother"], rep["poses"]
    P1 = s1.calculate_estimate(x1).params
    P2 = s2.calculate_estimate(x2).params
    assert np.max(np.abs(P1 - P2)) <= 1e-9
    assert [r.factors_added for r in s1.records] == [r.factors_added for r in s2.records]
    g = s2.graph
    assert sum(f.count for f in g.factors) == graph.num_edges + 1  # the edges and the prior
    vals = s2.calculate_estimate()
    prior = [f for f in g.factors if isinstance(f, PriorFactor)]
    assert len(prior) == 1
    only_edges = FactorGraph()
    y = only_edges.add_variables(graph.poses)
    for f in g.factors:
        if isinstance(f, BetweenFactor):
            only_edges.add(BetweenFactor(y, f.args[0][1], f.args[1][1], f.Z, f.noise))
    cost = only_edges.cost(Values([y], [np.asarray(vals.params(x2))]))
    assert abs(cost - graph.cost(vals[x2])) <= 1e-10 * max(1.0, graph.cost(vals[x2]))


@pytest.mark.parametrize("fast", ["1", "0"])
def test_update_rows_remove_equals_solve_without(monkeypatch, fast):
    """Loop closures streamed by update_rows, then removed with remove_factors([batch]): the
    estimate is the dense Gauss-Newton solution of the chain alone (a linear chain: the
    prior and odometry determine it exactly)."""
    monkeypatch.setenv("MICROLIE_FAST", fast)
    rng = np.random.default_rng(1)
    n = 12
    s = IncrementalSmoother(relinearize_threshold=0.0, relinearize_skip=1, wildfire=0.0)
    x = s.add_variables(SE2.identity(n))
    sig = Diagonal([0.1, 0.1, 0.05])
    Z = SE2.exp(np.c_[np.ones(n - 1), 0.1 * rng.standard_normal((n - 1, 2))])
    s.update([PriorFactor(x, 0, SE2.identity(), sig),
              BetweenFactor(x, np.arange(n - 1), np.arange(1, n), Z, sig)])
    bad = BetweenFactor(x, [0, 2, 5], [7, 9, 11], SE2.exp(rng.standard_normal((3, 3))), sig)
    s.update_rows(bad, [0, 2])
    s.update_rows(bad, 1)
    assert sum(f.count for f in s.graph.factors) == 1 + (n - 1) + 3
    rec = s.remove_factors([bad])
    assert rec.factors_removed == 3
    for _ in range(6):
        s.update([])
    expect = [SE2.identity()]
    for k in range(n - 1):
        expect.append(expect[-1] @ Z[k])
    E = np.stack([e.params for e in expect])
    assert np.max(np.abs(s.calculate_estimate(x).params - E)) <= 1e-9
    assert sum(f.count for f in s.graph.factors) == 1 + (n - 1)


def test_update_rows_bad_input():
    s = IncrementalSmoother()
    x = s.add_variables(SE2.identity(4))
    sig = Diagonal([1.0, 1.0, 1.0])
    f = BetweenFactor(x, [0, 1, 2], [1, 2, 3], SE2.exp(np.zeros((3, 3))), sig)
    s.update([PriorFactor(x, 0, SE2.identity(), sig)])
    with pytest.raises(ValueError, match="rows: indices into the batch must be in 0 .. 2"):
        s.update_rows(f, [3])
    with pytest.raises(ValueError, match="rows: integer indices"):
        s.update_rows(f, [0.5])
    with pytest.raises(ValueError, match="rows: integer indices"):
        s.update_rows(f, [])
    with pytest.raises(ValueError, match="names a row twice"):
        s.update_rows(f, [0, 0])
    s.update_rows(f, 0)
    with pytest.raises(ValueError, match="row 0 of BetweenFactor was already added"):
        s.update_rows(f, [1, 0])
    with pytest.raises(ValueError, match="new_factors: BetweenFactor was already added"):
        s.update([f])
    p = PriorFactor(x, 1, SE2.identity(), sig)
    with pytest.raises(ValueError, match="update_rows takes a BetweenFactor, got PriorFactor"):
        s.update_rows(p, 0)
    whole = BetweenFactor(x, 1, 2, SE2.identity(), sig)
    s.update([whole])
    with pytest.raises(ValueError, match="was given to update"):
        s.update_rows(whole, 0)
    other = FactorGraph().add_variables(SE2.identity(2))
    with pytest.raises(ValueError, match="of another graph"):
        s.update_rows(BetweenFactor(other, 0, 1, SE2.identity(), sig), 0)


def test_online_module_equals_numpy_bookkeeping():
    """microlie._c._online (ordering split, rows to relinearise) against the NumPy fallback
    of incremental.py on a replay with loop closures and relinearisation: the same order, so
    the same estimate to the last bit and the same work per update."""
    if _fast.module("_online") is None:
        pytest.skip("microlie._c._online is not built")
    graph = _graph(SE3, 120, 40, seed=9)
    s1 = IncrementalSmoother()
    s0 = IncrementalSmoother()
    s0._c = None  # the NumPy bookkeeping, the rest compiled
    r1 = replay_pose_graph(graph, s1)
    r0 = replay_pose_graph(graph, s0)
    assert np.array_equal(s1.calculate_estimate(r1["poses"]).params,
                          s0.calculate_estimate(r0["poses"]).params)
    for a, b in zip(s1.records, s0.records, strict=True):
        assert (a.reeliminated, a.backsubstituted, a.relinearized) == \
            (b.reeliminated, b.backsubstituted, b.relinearized)
    assert sum(r.relinearized for r in s1.records) > 0


def test_online_split_order_and_rows_of():
    """The two functions of microlie._c._online against sorting and sets in Python, and their
    argument checks."""
    mod = _fast.module("_online")
    if mod is None:
        pytest.skip("microlie._c._online is not built")
    rng = np.random.default_rng(0)
    for n in (1, 5, 30, 200):
        N = 3 * n + 5
        pos = rng.permutation(10 * N)[:N].astype(np.int64)
        top = rng.permutation(N)[:n].astype(np.int64)
        last = [rng.integers(0, N, 3).astype(np.int64), np.zeros(0, np.int64)]
        mark = np.zeros(N, np.int64)
        keep = pos.copy()
        order, nb = mod.split_order(top, last, pos, mark, 1000)
        inlast = set(np.concatenate(last).tolist())
        head = sorted((t for t in top.tolist() if t not in inlast), key=lambda t: keep[t])
        tail = sorted((t for t in top.tolist() if t in inlast), key=lambda t: keep[t])
        assert order.tolist() == head + tail and nb == len(head)
        assert pos[order].tolist() == list(range(1000, 1000 + n))
        assert not mark.any()
    node_rows = [[0, 2], [2, 3], [1], []]
    rnodes = [np.array([0], np.int64), np.array([2], np.int64), np.array([0, 1], np.int64),
              np.array([1, 3], np.int64)]
    rmark = np.zeros(4, np.int64)
    rows, touched = mod.rows_of(np.array([3], np.int64), np.array([0, 1], np.int64),
                                node_rows, rnodes, rmark)
    assert rows.tolist() == [3, 0, 2] and touched.tolist() == [1, 3, 0, 0, 1]
    assert not rmark.any()
    with pytest.raises(ValueError, match="node id out of range"):
        mod.rows_of(np.zeros(0, np.int64), np.array([4], np.int64), node_rows, rnodes, rmark)
    with pytest.raises(ValueError, match="int64"):
        mod.split_order(np.zeros(2), [], pos, mark, 0)
    with pytest.raises(ValueError, match="top: node id out of range"):
        mod.split_order(np.array([10 ** 6], np.int64), [], pos, mark, 0)
