"""The default fill-reducing order of a block graph (ordering.minimum_degree_blocks): our
approximate minimum degree (compiled, microlie._c._order) and, with MICROLIE_FAST=0, SciPy's
multiple minimum degree. Checked against an exact greedy minimum degree and a brute-force
minimum fill written here on explicit sets, and against the known optimal fill of trees and
cycles."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

from microlie._fast import compiled
from microlie.optim.linalg.cholesky import SupernodalSolver
from microlie.optim.linalg.ordering import minimum_degree_blocks, symbolic

HAVE_C = compiled("_order") is not None
#: the compiled order and the SciPy fallback (MICROLIE_FAST=0)
PATHS = [pytest.param("1", marks=pytest.mark.skipif(not HAVE_C, reason="microlie._c._order "
                                                    "not built (pip install .)")),
         "0"]


@pytest.fixture(params=PATHS)
def fast(request, monkeypatch):
    monkeypatch.setenv("MICROLIE_FAST", request.param)
    return request.param


def _csr(n, a, b):
    """The symmetric pattern of the edges (a, b) (no diagonal), sorted CSR."""
    a, b = np.asarray(a, np.int64), np.asarray(b, np.int64)
    keep = a != b
    A = sp.csr_matrix((np.ones(keep.sum()), (a[keep], b[keep])), shape=(n, n))
    A = ((A + A.T) != 0).astype(float).tocsr()
    A.sort_indices()
    return A


@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_the_callers_arrays_are_left_unchanged(fast, dtype):
    """The order reads its arrays and never changes them (the SciPy path used to clean the
    caller's own arrays in place: diagonal entries dropped from its indptr)."""
    A = _csr(5, [0, 1, 2, 3], [1, 2, 3, 4]) + sp.eye(5, format="csr")  # with the diagonal
    A.sort_indices()
    indptr, indices = A.indptr.astype(dtype), A.indices.astype(dtype)
    keep = indptr.copy(), indices.copy()
    p = minimum_degree_blocks(indptr, indices, 5)
    assert sorted(p.tolist()) == list(range(5))
    np.testing.assert_array_equal(indptr, keep[0])
    np.testing.assert_array_equal(indices, keep[1])


def _order(A, dtype=np.int64):
    return minimum_degree_blocks(A.indptr.astype(dtype), A.indices.astype(dtype), A.shape[0])


def _fill(A, perm):
    """Fill edges of eliminating the vertices of A in the order perm, on explicit sets."""
    n = A.shape[0]
    adj = [set(A.indices[A.indptr[v]:A.indptr[v + 1]].tolist()) - {v} for v in range(n)]
    fill = 0
    for v in perm:
        nb = adj[v]
        for i in nb:
            adj[i].discard(v)
        for i, j in itertools.combinations(sorted(nb), 2):
            if j not in adj[i]:
                adj[i].add(j)
                adj[j].add(i)
                fill += 1
    return fill


def _exact_minimum_degree(A):
    """Greedy minimum degree on the eliminated graph itself (exact degrees, smallest index
    first among ties)."""
    n = A.shape[0]
    adj = [set(A.indices[A.indptr[v]:A.indptr[v + 1]].tolist()) - {v} for v in range(n)]
    alive, order = set(range(n)), []
    for _ in range(n):
        v = min(alive, key=lambda u: (len(adj[u]), u))
        alive.remove(v)
        order.append(v)
        for i in adj[v]:
            adj[i].discard(v)
            adj[i] |= adj[v] - {i}
    return np.array(order, np.int64)


def _is_perm(p, n):
    return p.shape == (n,) and np.array_equal(np.sort(p), np.arange(n))


def _random(rng, n, density):
    A = sp.random(n, n, density, random_state=rng, format="coo")
    return _csr(n, A.row, A.col)


def test_valid_on_random_graphs_int32_and_int64(fast):
    rng = np.random.default_rng(0)
    for _ in range(60):
        n = int(rng.integers(1, 80))
        A = _random(rng, n, rng.uniform(0.0, 0.3))
        p64 = _order(A)
        assert _is_perm(p64, n) and p64.dtype == np.int64
        np.testing.assert_array_equal(_order(A, np.int32), p64)


@pytest.mark.skipif(not HAVE_C, reason="microlie._c._order not built (or MICROLIE_FAST=0)")
def test_fill_against_an_exact_minimum_degree():
    # our approximate degrees and tie rules against exact minimum degree on the eliminated
    # graph: never much worse on one graph, and no worse in total
    rng = np.random.default_rng(1)
    ours = exact = 0
    for _ in range(150):
        n = int(rng.integers(2, 40))
        A = _random(rng, n, rng.uniform(0.02, 0.3))
        f, e = _fill(A, _order(A)), _fill(A, _exact_minimum_degree(A))
        assert f <= 1.05 * e + 1
        ours, exact = ours + f, exact + e
    assert ours <= exact


def test_fill_against_brute_force_on_tiny_graphs(fast):
    # never below the true minimum fill (a check of the fill count), and at it on most
    rng = np.random.default_rng(2)
    at_optimum = 0
    for _ in range(40):
        n = int(rng.integers(3, 7))
        A = _random(rng, n, 0.5)
        best = min(_fill(A, p) for p in itertools.permutations(range(n)))
        f = _fill(A, _order(A))
        assert f >= best
        at_optimum += f == best
    assert at_optimum >= 36


def test_trees_paths_and_stars_have_no_fill(fast):
    rng = np.random.default_rng(3)
    for n in (1, 2, 5, 50, 400):
        path = _csr(n, np.arange(n - 1), np.arange(1, n))
        star = _csr(n, np.zeros(n - 1, int), np.arange(1, n))
        parent = [int(rng.integers(0, k)) for k in range(1, n)]  # a random tree
        tree = _csr(n, parent, np.arange(1, n))
        for A in (path, star, tree):
            assert _fill(A, _order(A)) == 0
            assert symbolic(A, _order(A)).nnz == n + A.nnz // 2  # L = lower triangle of A


def test_cycles_have_the_minimum_fill(fast):
    # a cycle of n vertices is made chordal by n - 3 edges at least, and minimum degree does it
    for n in (4, 5, 9, 100):
        A = _csr(n, np.arange(n), (np.arange(n) + 1) % n)
        assert _fill(A, _order(A)) == n - 3


def test_disconnected_empty_and_isolated(fast):
    assert _order(sp.csr_matrix((0, 0))).shape == (0,)
    for n in (1, 7):
        np.testing.assert_array_equal(np.sort(_order(sp.csr_matrix((n, n)))), np.arange(n))
    # two paths, an isolated node and a cycle: no fill but the cycle's n - 3
    a = np.r_[0, 1, 2, 4, 5, 7, 8, 9, 10]
    b = np.r_[1, 2, 3, 5, 6, 8, 9, 10, 7]
    A = _csr(11, a, b)  # paths 0-3 and 4-6, the 4-cycle 7-10
    A = sp.block_diag([A, sp.csr_matrix((2, 2))]).tocsr()  # two isolated nodes
    p = _order(A)
    assert _is_perm(p, 13) and _fill(A, p) == 1


def test_dense_rows_go_last():
    # a hub joined to every node of a 30 x 30 grid (degree 900 > 10 sqrt(901)) is ordered
    # last, its row of L full, and the grid ordered about as well as without it
    if not HAVE_C:
        pytest.skip("microlie._c._order not built")
    k = 30
    idx = np.arange(k * k).reshape(k, k)
    a = np.r_[idx[:, :-1].ravel(), idx[:-1, :].ravel()]
    b = np.r_[idx[:, 1:].ravel(), idx[1:, :].ravel()]
    G = _csr(k * k, a, b)
    hub = k * k
    A = _csr(k * k + 1, np.r_[a, np.full(k * k, hub)], np.r_[b, np.arange(k * k)])
    p = _order(A)
    assert _is_perm(p, k * k + 1) and p[-1] == hub
    assert symbolic(A, p).nnz == symbolic(G, p[:-1]).nnz + k * k + 1
    assert symbolic(G, p[:-1]).nnz <= 1.05 * symbolic(G, _order(G)).nnz


def test_fill_close_to_superlus_mmd_on_pose_graph_shapes(fast):
    # a chain with loop closures (a pose graph's shape), and a 2-D grid
    rng = np.random.default_rng(4)
    n = 3000
    a = np.r_[np.arange(n - 1), rng.integers(0, n, 300)]
    b = np.r_[np.arange(1, n), rng.integers(0, n, 300)]
    k = 40
    idx = np.arange(k * k).reshape(k, k)
    grid = _csr(k * k, np.r_[idx[:, :-1].ravel(), idx[:-1, :].ravel()],
                np.r_[idx[:, 1:].ravel(), idx[1:, :].ravel()])
    from microlie.optim.linalg.ordering import minimum_degree

    for A in (_csr(n, a, b), grid):
        ours, mmd = symbolic(A, _order(A)), symbolic(A, minimum_degree(A))
        assert ours.nnz <= 1.05 * mmd.nnz and ours.flops <= 1.10 * mmd.flops


@pytest.mark.parametrize("bad, match", [
    ((np.array([0, 1, 1]), np.array([1]), 2), "symmetric"),
    ((np.array([0, 1, 2]), np.array([1, 2]), 2), r"indices must be in \[0, 2\)"),
    ((np.array([0, 1, 2]), np.array([1, -1]), 2), r"indices must be in \[0, 2\)"),
    ((np.array([0, 1]), np.array([1]), 2), "indptr must have nb \\+ 1 = 3 entries"),
    ((np.array([0, 2, 1]), np.array([1, 0]), 2), "indptr must"),
    ((np.array([0, 1, 2]), np.array([1.0, 0.0]), 2), "indices must be a 1-D integer array"),
    ((np.array([0]), np.array([], int), -1), "nb must be >= 0"),
])
def test_bad_input(fast, bad, match):
    with pytest.raises(ValueError, match=match):
        minimum_degree_blocks(*bad)


def test_supernodal_solver_uses_it(fast):
    # the solver's block order has the fill of minimum_degree_blocks (a postorder of it)
    k = 12
    idx = np.arange(k * k).reshape(k, k)
    A = _csr(k * k, np.r_[idx[:, :-1].ravel(), idx[:-1, :].ravel()],
             np.r_[idx[:, 1:].ravel(), idx[1:, :].ravel()])
    n = A.shape[0]
    H = sp.kron(A + sp.diags(np.full(n, 5.0)), np.array([[2.0, 0.5], [0.5, 1.0]])).tocsc()
    H.sort_indices()
    s = SupernodalSolver()
    s.analyse(H.indptr, H.indices, 2 * n, 2)
    assert _fill(A, s.sperm[::2] // 2) == _fill(A, _order(A))
    s.factorize(H.data)
    b = np.arange(2 * n, dtype=float)
    np.testing.assert_allclose(H @ s.solve(b), b, rtol=1e-10, atol=1e-9)


def test_connected_components_is_scipys():
    from scipy.sparse.csgraph import connected_components as scipy_components

    from microlie.optim.linalg.ordering import connected_components

    rng = np.random.default_rng(5)
    for _ in range(100):
        n = int(rng.integers(0, 300))
        m = int(rng.integers(0, 2 * n + 1))
        r, c = rng.integers(0, max(n, 1), m), rng.integers(0, max(n, 1), m)
        k, label = connected_components(n, r, c)
        A = sp.coo_matrix((np.ones(m), (r, c)), shape=(n, n))
        k2, label2 = scipy_components(A, directed=False) if n else (0, np.zeros(0))
        assert k == k2
        np.testing.assert_array_equal(label, label2)
    # a long chain: one component
    n = 100_000
    assert connected_components(n, np.arange(n - 1), np.arange(1, n))[0] == 1


def test_compiled_postorder_is_the_depth_first_one(monkeypatch):
    # the elimination tree's postorder (children ascending) with and without the compiled code
    from microlie.optim.linalg import ordering as O

    if not HAVE_C:
        pytest.skip("microlie._c._order not built")
    rng = np.random.default_rng(6)
    for _ in range(50):
        n = int(rng.integers(1, 300))
        parent = np.array([int(rng.integers(j + 1, n)) if j < n - 1 and rng.random() < 0.9
                           else -1 for j in range(n)])
        ours = O._postorder(parent)
        monkeypatch.setenv("MICROLIE_FAST", "0")
        ref = O._postorder(parent)
        monkeypatch.delenv("MICROLIE_FAST")
        np.testing.assert_array_equal(ours, ref)
    with pytest.raises(ValueError, match="cycle"):
        compiled("_order").postorder(np.array([1, 0], np.intp))
