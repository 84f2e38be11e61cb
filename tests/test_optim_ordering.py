"""Fill-reducing orderings (microlie.optim.linalg.ordering): permutations, minimum degree as
SuperLU's
full factorisation orders, the symbolic factor against an elimination done by hand, and
SupernodalSolver's ``ordering`` option (more symbolic checks: test_optim_symbolic.py)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from test_optim_cholesky import PATHS, _random_spd

from microlie.optim.linalg import ordering as O
from microlie.optim.linalg.cholesky import SupernodalSolver


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
def test_orders_are_permutations_and_symbolic_is_the_elimination(name):
    A = GRAPHS[name]()
    n = A.shape[0]
    rng = np.random.default_rng(0)
    for p in (O.minimum_degree(A), np.arange(n), rng.permutation(n)):
        assert _is_perm(p, n)
        s = O.symbolic(A, p)
        assert _is_perm(s.perm, n)
        counts, height = _eliminate(A, s.perm)
        np.testing.assert_array_equal(s.counts, counts)
        assert s.nnz == counts.sum() and s.height == height
        assert s.flops == float((counts.astype(float) ** 2).sum())
        # the stored order is a postorder of the requested one: the same fill
        assert _eliminate(A, p)[0].sum() == counts.sum()


@pytest.mark.parametrize("name", list(GRAPHS))
def test_minimum_degree_is_superlus_order(name):
    # the order SuperLU's full factorisation uses (of a diagonally dominant matrix on the
    # pattern), which minimum_degree takes from a factorisation that drops everything
    A = O._clean(GRAPHS[name]())
    B = (sp.diags(np.diff(A.indptr) + 2.0) - 0.5 * A).tocsc()
    lu = O.splu_symmetric(B, "MMD_AT_PLUS_A")
    np.testing.assert_array_equal(O.minimum_degree(A), np.argsort(lu.perm_c))


def test_bad_input():
    A = _grid2(4)
    with pytest.raises(ValueError, match="unknown ordering 'nd'"):
        O.fill_order(A, "nd")
    with pytest.raises(ValueError, match="unknown ordering 'metis'"):
        SupernodalSolver(ordering="metis")
    with pytest.raises(ValueError, match="perm must be a permutation of 0..15"):
        O.symbolic(A, np.r_[0, np.arange(15)])


def test_graph_is_the_block_pattern():
    _, H = _random_spd(3, 30, 5)
    G = O.graph(H.indptr, H.indices, H.shape[0], 3)
    B = (abs(H) > 0).astype(float).toarray().reshape(30, 3, 30, 3).sum(axis=(1, 3)) > 0
    np.fill_diagonal(B, False)
    np.testing.assert_array_equal(G.toarray() > 0, B)


@pytest.mark.parametrize("compiled", PATHS)
@pytest.mark.parametrize("ordering", ["mmd", "auto"])
def test_supernodal_solver_orderings_solve(compiled, ordering):
    M, H = _random_spd(3, 150, 6, extra=3)
    s = SupernodalSolver(compiled=compiled, ordering=ordering)
    s.analyse(H.indptr, H.indices, H.shape[0], 3)
    s.factorize(H.data)
    b = np.random.default_rng(7).standard_normal(H.shape[0])
    np.testing.assert_allclose(s.solve(b), np.linalg.solve(M, b), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("compiled", PATHS)
def test_the_ordering_is_the_one_used(compiled):
    # a 3-D grid of 2x2 blocks: the solver's block order has minimum degree's fill (it is a
    # postorder of it)
    A = _grid3(8)
    n = A.shape[0]
    H = (sp.kron(A + sp.diags(np.full(n, 7.0)), np.array([[2.0, 0.5], [0.5, 1.0]]))).tocsc()
    H.sort_indices()
    s = SupernodalSolver(compiled=compiled, ordering="mmd")
    s.analyse(H.indptr, H.indices, 2 * n, 2)
    blocks = s.sperm[::2] // 2
    assert _eliminate(A, blocks)[0].sum() == _eliminate(A, O.minimum_degree(A))[0].sum()
    s.factorize(H.data)
    b = np.arange(2 * n, dtype=float)
    np.testing.assert_allclose(H @ s.solve(b), b, rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("n", [0, 1, 2, 3])
@pytest.mark.parametrize("method", ["mmd", "auto"])
def test_tiny_graphs(n, method):
    A = sp.csr_matrix(np.ones((n, n)))
    s = O.fill_order(A, method)
    assert _is_perm(s.perm, n) and s.nnz == n * (n + 1) // 2 and s.height == n
