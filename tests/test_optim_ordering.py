"""Fill-reducing orderings (microlie.optim.ordering): permutations, separators that separate,
the symbolic factor against an elimination done by hand, nested dissection against minimum
degree and the natural order on grids, and SupernodalSolver's ``ordering`` option."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from test_optim_cholesky import PATHS, _random_spd

from microlie.optim import ordering as O
from microlie.optim.cholesky import SupernodalSolver


def _path(k: int):
    return sp.diags([np.ones(k - 1), np.ones(k - 1)], [-1, 1], shape=(k, k))


def _grid2(k: int):
    return (sp.kron(_path(k), sp.eye(k)) + sp.kron(sp.eye(k), _path(k))).tocsr()


def _grid3(k: int):
    P, I = _path(k), sp.eye(k)
    return (sp.kron(sp.kron(P, I), I) + sp.kron(sp.kron(I, P), I)
            + sp.kron(sp.kron(I, I), P)).tocsr()


def _random_graph(n: int, m: int, seed: int):
    """A chain plus ``m`` random edges (a pose graph's shape: odometry and loop closures)."""
    rng = np.random.default_rng(seed)
    a = np.r_[np.arange(n - 1), rng.integers(0, n, m)]
    b = np.r_[np.arange(1, n), rng.integers(0, n, m)]
    A = sp.csr_matrix((np.ones(a.size), (a, b)), shape=(n, n))
    return O._clean(A + A.T)


def _eliminate(A, perm):
    """Column counts (with the diagonal) and elimination-tree height of the Cholesky factor
    of ``A[perm][:, perm]``, by eliminating the vertices one by one on explicit sets."""
    n = A.shape[0]
    A = sp.csr_matrix(A)
    pos = np.empty(n, np.int64)
    pos[perm] = np.arange(n)
    adj = [set(pos[A.indices[A.indptr[v]:A.indptr[v + 1]]].tolist()) - {pos[v]}
           for v in perm]  # in the new numbering
    counts = np.zeros(n, np.int64)
    parent = np.full(n, -1)
    for j in range(n):
        later = {i for i in adj[j] if i > j}
        counts[j] = 1 + len(later)
        if later:
            parent[j] = min(later)
        for i in later:
            adj[i] |= later - {i}
    depth = np.zeros(n, np.int64)
    for j in range(n - 1, -1, -1):
        if parent[j] >= 0:
            depth[j] = depth[parent[j]] + 1
    return counts, int(depth.max()) + 1


def _is_perm(p, n):
    return p.dtype.kind == "i" and np.array_equal(np.sort(p), np.arange(n))


GRAPHS = {
    "grid2": lambda: _grid2(9),
    "grid3": lambda: _grid3(5),
    "pose": lambda: _random_graph(300, 40, 1),
    "disconnected": lambda: sp.block_diag([_grid2(6), _random_graph(90, 5, 2),
                                           sp.csr_matrix((3, 3))]).tocsr(),
}


@pytest.mark.parametrize("name", list(GRAPHS))
@pytest.mark.parametrize("leaf", [4, 16, 10_000])
def test_orders_are_permutations_and_symbolic_is_the_elimination(name, leaf):
    A = GRAPHS[name]()
    n = A.shape[0]
    for p in (O.minimum_degree(A), O.nested_dissection(A, leaf), np.arange(n)):
        assert _is_perm(p, n)
        s = O.symbolic(A, p)
        assert _is_perm(s.perm, n)
        counts, height = _eliminate(A, s.perm)
        np.testing.assert_array_equal(s.counts, counts)
        assert s.nnz == counts.sum() and s.height == height
        assert s.flops == float((counts.astype(float) ** 2).sum())
        # the stored order is a postorder of the requested one: the same fill
        assert _eliminate(A, p)[0].sum() == counts.sum()


@pytest.mark.parametrize("A", [_grid2(20), _grid3(7), _random_graph(500, 60, 3)],
                         ids=["grid2", "grid3", "pose"])
def test_separators_separate(A):
    A = O._clean(A)
    sep, side = O.separator(A)
    a, b = ~sep & side, ~sep & ~side
    n = A.shape[0]
    assert a.sum() >= 0.2 * n and b.sum() >= 0.2 * n
    assert sep.sum() < 0.2 * n
    # no edge from A to B
    assert A[np.flatnonzero(a)][:, np.flatnonzero(b)].nnz == 0


def test_separator_of_a_grid_is_one_line():
    # a k x k grid is cut by a line of k vertices (a BFS level from a corner is a diagonal of
    # up to k vertices; its minimum vertex cover may not be larger)
    sep, _ = O.separator(O._clean(_grid2(16)))
    assert sep.sum() <= 16


def test_no_separator_in_a_clique():
    K = O._clean(sp.csr_matrix(np.ones((6, 6))))
    assert O.separator(K) is None
    assert _is_perm(O.nested_dissection(K, 2), 6)


def test_nested_dissection_fills_less_on_grids():
    g2 = _grid2(30)
    nd2 = O.symbolic(g2, O.nested_dissection(g2, 16))
    assert nd2.nnz < 0.5 * O.symbolic(g2, np.arange(900)).nnz
    g3 = _grid3(12)
    nd3 = O.symbolic(g3, O.nested_dissection(g3))
    mmd3 = O.symbolic(g3, O.minimum_degree(g3))
    assert nd3.flops < 0.8 * mmd3.flops and nd3.nnz < mmd3.nnz


def test_auto_takes_the_fewest_flops():
    # minimum degree and the coarse dissection always; the full one when the coarse one
    # saves 10% (the 3-D grid: it does, and the full one is best; the chain with loop
    # closures: minimum degree is best)
    for A, deep_tried in ((_grid3(12), True), (_random_graph(600, 80, 4), False)):
        auto = O.fill_order(A, "auto")
        mmd = O.symbolic(A, O.minimum_degree(A)).flops
        coarse = O.symbolic(A, O.nested_dissection(A, -(-3 * A.shape[0] // 5))).flops
        deep = O.symbolic(A, O.nested_dissection(A)).flops
        assert (coarse < 0.9 * mmd) == deep_tried
        assert auto.flops == min([mmd, coarse] + [deep] * deep_tried)
        assert _eliminate(A, auto.perm)[0].sum() == auto.nnz
    assert O.fill_order(_grid3(12)).flops == O.fill_order(_grid3(12), "nd").flops
    assert O.fill_order(_grid3(12), "nd").flops < O.fill_order(_grid3(12), "mmd").flops


def test_bad_input():
    A = _grid2(4)
    with pytest.raises(ValueError, match="unknown ordering 'amd'"):
        O.fill_order(A, "amd")
    with pytest.raises(ValueError, match="unknown ordering 'metis'"):
        SupernodalSolver(ordering="metis")
    with pytest.raises(ValueError, match="leaf_size must be positive"):
        O.nested_dissection(A, 0)
    with pytest.raises(ValueError, match="perm must be a permutation of 0..15"):
        O.symbolic(A, np.r_[0, np.arange(15)])


def test_graph_is_the_block_pattern():
    _, H = _random_spd(3, 30, 5)
    G = O.graph(H.indptr, H.indices, H.shape[0], 3)
    B = (abs(H) > 0).astype(float).toarray().reshape(30, 3, 30, 3).sum(axis=(1, 3)) > 0
    np.fill_diagonal(B, False)
    np.testing.assert_array_equal(G.toarray() > 0, B)


@pytest.mark.parametrize("compiled", PATHS)
@pytest.mark.parametrize("ordering", ["mmd", "nd", "auto"])
def test_supernodal_solver_orderings_solve(compiled, ordering):
    M, H = _random_spd(3, 150, 6, extra=3)
    s = SupernodalSolver(compiled=compiled, ordering=ordering)
    s.analyse(H.indptr, H.indices, H.shape[0], 3)
    s.factorize(H.data)
    b = np.random.default_rng(7).standard_normal(H.shape[0])
    np.testing.assert_allclose(s.solve(b), np.linalg.solve(M, b), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("compiled", PATHS)
def test_forced_ordering_is_the_one_used(compiled):
    # a 3-D grid of 2x2 blocks: nested dissection's factor is smaller than minimum degree's,
    # and the solver's block order is the ordering's (up to an equivalent postorder)
    A = _grid3(8)
    n = A.shape[0]
    H = (sp.kron(A + sp.diags(np.full(n, 7.0)), np.array([[2.0, 0.5], [0.5, 1.0]]))).tocsc()
    H.sort_indices()
    panels = {}
    for ordering in ("mmd", "nd"):
        s = SupernodalSolver(compiled=compiled, ordering=ordering)
        s.analyse(H.indptr, H.indices, 2 * n, 2)
        blocks = s.sperm[::2] // 2
        fill = O.fill_order(A, ordering).nnz
        assert _eliminate(A, blocks)[0].sum() == fill
        s.factorize(H.data)
        b = np.arange(2 * n, dtype=float)
        np.testing.assert_allclose(H @ s.solve(b), b, rtol=1e-10, atol=1e-9)
        panels[ordering] = fill
    assert panels["nd"] < panels["mmd"]


@pytest.mark.parametrize("n", [0, 1, 2, 3])
@pytest.mark.parametrize("method", ["mmd", "nd", "auto"])
def test_tiny_graphs(n, method):
    A = sp.csr_matrix(np.ones((n, n)))
    s = O.fill_order(A, method)
    assert _is_perm(s.perm, n) and s.nnz == n * (n + 1) // 2 and s.height == n


def test_unbalanced_graphs_fall_back_to_minimum_degree():
    # a star has no balanced cut: no separator, and its order has no fill (the hub last)
    n = 2000
    star = O._clean(sp.csr_matrix((np.ones(n - 1), (np.zeros(n - 1, int), np.arange(1, n))),
                                  shape=(n, n)))
    assert O.separator(star) is None
    assert O.symbolic(star, O.nested_dissection(star, 8)).nnz == 2 * n - 1
    # a broom (a long path ending in a star) and a long path: permutations, no deep recursion
    broom = sp.block_diag([_path(3000), sp.csr_matrix((n, n))]).tolil()
    broom[2999, 3000:] = 1
    for A in (broom, _path(5000)):
        assert _is_perm(O.nested_dissection(A, 64), A.shape[0])
