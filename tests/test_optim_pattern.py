"""The block pattern of ``H`` (``Problem``): the compiled build (``microlie._c._pattern``) equals
the NumPy one, and both equal an independent reference (the node pairs that share a factor,
listed in plain Python, and the scalar CSC positions read from SciPy's CSC of the pattern), on
random graphs with mixed variable sizes, fixed variables, priors, three-argument factors and
reprojection factors."""

from __future__ import annotations

import numpy as np
import pytest

from microlie import SE2, SE3
from microlie._fast import module
from microlie.optim import BetweenFactor, CustomFactor, FactorGraph, GaugeError, PriorFactor

needs_c = pytest.mark.skipif(module("_pattern") is None,
                             reason="microlie._c._pattern not built (or MICROLIE_FAST=0)")


def _resid(*vals):
    """A residual of any arguments (only the pattern matters here)."""
    return np.concatenate([np.asarray(v.params if hasattr(v, "params") else v)[:, :1]
                           for v in vals], axis=1)


def random_graph(seed: int) -> FactorGraph:
    """SE2 (dof 3), SE3 (6) and vector (2 or 3) batches, some fixed, joined by priors,
    between factors, repeated pairs and factors of three arguments."""
    rng = np.random.default_rng(seed)
    g = FactorGraph()
    n2, n3, nv = rng.integers(2, 30, size=3)
    dv = int(rng.choice([2, 3]))
    fix = lambda n: rng.choice(n, size=rng.integers(0, n // 3 + 1), replace=False)  # noqa: E731
    a = g.add_variables(SE2.exp(rng.normal(size=(n2, 3))), fixed=fix(n2), name="a")
    b = g.add_variables(SE3.exp(rng.normal(size=(n3, 6))), fixed=fix(n3), name="b")
    c = g.add_variables(rng.normal(size=(nv, dv)), fixed=fix(nv), name="c")
    g.add(PriorFactor(a, 0, SE2.identity()))
    g.add(PriorFactor(b, [0, 1], SE3.identity(2)))
    i = rng.integers(0, n2, size=3 * n2)
    j = (i + rng.integers(1, n2, size=i.size)) % n2
    g.add(BetweenFactor(a, i, j, SE2.exp(rng.normal(size=(i.size, 3)))))
    i = rng.integers(0, n3, size=2 * n3)
    j = (i + rng.integers(1, n3, size=i.size)) % n3
    g.add(BetweenFactor(b, i, j, SE3.exp(rng.normal(size=(i.size, 6)))))
    m = int(rng.integers(1, 40))
    g.add(CustomFactor(_resid, [(a, rng.integers(0, n2, m)), (b, rng.integers(0, n3, m)),
                                (c, rng.integers(0, nv, m))], 3))
    m = int(rng.integers(1, 20))
    g.add(CustomFactor(_resid, [(c, rng.integers(0, nv, m)), (b, rng.integers(0, n3, m))], 2))
    return g


def bundle(seed: int) -> FactorGraph:
    from microlie.optim.sfm.bundle import bundle_graph, synthetic_scene

    _, start = synthetic_scene(4, 25, seed=seed)
    return bundle_graph(start, fix_cameras=[0], fix_points=[0, 3]).graph


ARRAYS = ("_bptr", "_brow", "_bstart", "_collen", "indptr", "diag_pos")


def reference_blocks(p) -> set[tuple[int, int]]:
    """The node pairs (u, v) that share a factor, and the diagonal, in plain Python."""
    out = {(u, u) for u in range(p.num_nodes)}
    for nodes in p.fargs:
        for row in zip(*[n.tolist() for n in nodes], strict=True):
            for u in row:
                for v in row:
                    if u >= 0 and v >= 0:
                        out.add((u, v))
    return out


def check_reference(p) -> None:
    import scipy.sparse as sp

    bptr, brow = p._bptr, p._brow
    got = {(int(brow[k]), v) for v in range(p.num_nodes) for k in range(bptr[v], bptr[v + 1])}
    assert got == reference_blocks(p)
    for v in range(p.num_nodes):
        assert np.all(np.diff(brow[bptr[v]:bptr[v + 1]]) > 0)  # sorted, no repeats
    # every entry (r, c) of every block is where SciPy's CSC of the scalar pattern puts it
    H = sp.csc_matrix((np.arange(p.nnz, dtype=float), p.indices, p.indptr),
                      shape=(p.size, p.size))
    H.has_sorted_indices = False
    H.sort_indices()
    assert np.array_equal(H.data, np.arange(p.nnz))  # the pattern's rows are sorted
    off = p.node_off
    for (u, v) in sorted(got):
        st = int(p.block_start(np.array([u]), np.array([v]))[0])
        cl = int(p.column_length(np.array([v]))[0])
        for r in range(p.node_dof[u]):
            for c in range(p.node_dof[v]):
                assert H[off[u] + r, off[v] + c] == st + c * cl + r
    assert np.array_equal(H.diagonal(), p.diag_pos)


def build(g: FactorGraph, fast: bool, monkeypatch, gauge: str = "check"):
    monkeypatch.setenv("MICROLIE_FAST", "1" if fast else "0")
    g._problem = None
    return g.problem(gauge)


@needs_c
@pytest.mark.parametrize("seed", range(12))
def test_pattern_c_equals_numpy_and_reference(seed, monkeypatch):
    g = random_graph(seed)
    pc = build(g, True, monkeypatch, "fix_first")  # some vectors are left unanchored
    pn = build(g, False, monkeypatch, "fix_first")
    assert pc.gauge_fixed == pn.gauge_fixed
    for name in ARRAYS:
        x, y = getattr(pc, name), getattr(pn, name)
        assert np.array_equal(x, y), name
    assert pc.nnz == pn.nnz
    for x, y in zip(pc.block_pattern, pn.block_pattern, strict=True):
        assert np.array_equal(x, y)
    check_reference(pn)
    # the scatter positions of a three-argument batch, both ways, against block_start
    nodes = np.stack(pn.fargs[4], axis=1)
    monkeypatch.setenv("MICROLIE_FAST", "1")
    sc = pc.scatter_positions(nodes)
    monkeypatch.setenv("MICROLIE_FAST", "0")
    sn = pn.scatter_positions(nodes)
    for x, y in zip(sc, sn, strict=True):
        assert np.array_equal(x, y)
    K = nodes.shape[1]
    for k in range(K):
        assert np.array_equal(sc[2][:, k], np.where(nodes[:, k] >= 0,
                                                    pn.node_off[np.maximum(nodes[:, k], 0)], -1))
        for l in range(K):
            assert np.array_equal(sc[0][:, k * K + l], pn.block_start(nodes[:, k], nodes[:, l]))
    # the same linear system from both patterns (the compiled edge loops on one side)
    states = [v.initial for v in g.variables]
    monkeypatch.setenv("MICROLIE_FAST", "1")
    Hc = pc.matrix(pc.linearize(states).data).toarray()
    monkeypatch.setenv("MICROLIE_FAST", "0")
    Hn = pn.matrix(pn.linearize(states).data).toarray()
    np.testing.assert_allclose(Hc, Hn, rtol=1e-12, atol=1e-9 * abs(Hn).max())


@needs_c
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_pattern_bundle(seed, monkeypatch):
    g = bundle(seed)
    pc = build(g, True, monkeypatch)
    pn = build(g, False, monkeypatch)
    for name in ARRAYS:
        assert np.array_equal(getattr(pc, name), getattr(pn, name)), name
    check_reference(pc)
    # the compiled reprojection plan's positions equal the NumPy lookup
    from microlie.optim.core.compiled import plan

    monkeypatch.setenv("MICROLIE_FAST", "1")
    pl = plan(pc, pc.factors[0])
    if pl is not None:
        monkeypatch.setenv("MICROLIE_FAST", "0")
        nodes = [pn.node_of[pn.key(var)][np.asarray(i)] for var, i in pn.factors[0].args]
        for k, a in enumerate(nodes):
            for l, b in enumerate(nodes):
                assert np.array_equal(pl.starts[:, 4 * k + l], pn.block_start(a, b))


@needs_c
@pytest.mark.parametrize("fast", [True, False])
def test_gauge_on_pattern(fast, monkeypatch):
    """Two unanchored components (a chain and a lone pair), one anchored: check names the
    first, fix_first holds the first node of each, both paths alike."""
    g = FactorGraph()
    x = g.add_variables(SE2.identity(7), name="x")
    g.add(PriorFactor(x, 0, SE2.identity()))
    g.add(BetweenFactor(x, [0, 2, 3, 5], [1, 3, 4, 6], SE2.exp(np.full((4, 3), 0.1))))
    monkeypatch.setenv("MICROLIE_FAST", "1" if fast else "0")
    with pytest.raises(GaugeError) as e:
        g.problem("check")
    assert e.value.count == 5
    assert [i for _, i in e.value.unanchored] == [2, 5]
    g._problem = None
    p = g.problem("fix_first")
    assert [i for _, i in p.gauge_fixed] == [2, 5]
    assert p.num_nodes == 5 and p.size == 15
    check_reference(p)


@needs_c
def test_compiled_bad_input():
    P = module("_pattern")
    a = np.array([0, 5], np.intp)
    with pytest.raises(ValueError, match="outside"):
        P.block_pattern(3, [(a, np.array([1, 2], np.intp))], np.full(3, 2, np.int64))
    with pytest.raises(ValueError, match="intp"):
        P.block_pattern(3, [(a.astype(np.int32), a)], np.full(3, 2, np.int64))
    bp, br, bs, cl = P.block_pattern(3, [(np.array([0]), np.array([1]))], np.full(3, 2, np.int64))
    with pytest.raises(ValueError, match=r"block \(2, 0\) is not in the pattern"):
        P.positions(bp, br, bs, np.array([2]), np.array([0]))
    assert P.components(bp, br)[1].tolist() == [0, 0, 1]


def test_problem_bad_gauge():
    g = FactorGraph()
    x = g.add_variables(SE2.identity(1))
    g.add(PriorFactor(x, 0, SE2.identity()))
    with pytest.raises(ValueError, match="gauge must be"):
        g.problem("first")
