"""The symbolic Cholesky analysis (microlie.optim.linalg.ordering.symbolic and SupernodalSolver's
supernodes) against two oracles on 240 random block patterns: the elimination game played on
Python sets, and the union of the nonzeros of dense Cholesky factors of the pattern with random
positive weights. On the patterns that have a place for it, a matrix is also built whose
dense factor cancels a block: the analysis, which factorises nothing, keeps it."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from test_optim_cholesky import PATHS

import microlie.optim.linalg.cholesky as ch
from microlie.optim.linalg import ordering as O


def _game(adj: list[set[int]], order: np.ndarray) -> list[set[int]]:
    """The elimination game: the rows below the diagonal of each column of L, in the new
    numbering, eliminating the vertices in ``order`` (new -> old)."""
    n = len(adj)
    pos = np.empty(n, np.int64)
    pos[order] = np.arange(n)
    g = [{int(pos[w]) for w in adj[v]} for v in order.tolist()]
    below = []
    for j in range(n):
        later = {i for i in g[j] if i > j}
        below.append(later)
        for i in later:
            g[i] |= later - {i}
    return below


def _pattern(kind: str, nb: int, rng: np.random.Generator) -> list[set[int]]:
    """A random block graph (adjacency sets) of one of several shapes."""
    edges: set[tuple[int, int]] = set()
    if kind == "random":
        p = rng.uniform(0.05, 0.4)
        edges = {(a, b) for a in range(nb) for b in range(a + 1, nb) if rng.random() < p}
    elif kind == "pose":  # a chain and a few loop closures
        edges = {(a, a + 1) for a in range(nb - 1)}
        edges |= {tuple(sorted(rng.choice(nb, 2, replace=False))) for _ in range(nb // 5)}
    elif kind == "grid":
        w = max(int(np.sqrt(nb)), 1)
        for v in range(nb):
            if v % w + 1 < w and v + 1 < nb:
                edges.add((v, v + 1))
            if v + w < nb:
                edges.add((v, v + w))
    elif kind == "arrow":  # hubs joined to everything, a sparse rest
        hubs = rng.choice(nb, min(nb, int(rng.integers(1, 3))), replace=False)
        edges = {(min(h, v), max(h, v)) for h in hubs.tolist() for v in range(nb) if v != h}
        edges |= {(a, a + 1) for a in range(0, nb - 1, 3)}
    elif kind == "forest":  # disconnected pieces and isolated vertices
        for a in range(1, nb):
            if rng.random() < 0.7:
                edges.add((int(rng.integers(0, a)), a))
    adj: list[set[int]] = [set() for _ in range(nb)]
    for a, b in edges:
        if a != b:
            adj[a].add(b)
            adj[b].add(a)
    return adj


def _matrix(adj: list[set[int]], bs: int, rng: np.random.Generator) -> np.ndarray:
    """An SPD matrix on the pattern: random positive weights on every entry of each edge's
    block, the diagonal dominant."""
    nb = len(adj)
    M = np.zeros((nb * bs, nb * bs))
    for a in range(nb):
        for b in adj[a]:
            if a < b:
                W = rng.uniform(0.1, 1.0, (bs, bs))
                M[a * bs:(a + 1) * bs, b * bs:(b + 1) * bs] = W
                M[b * bs:(b + 1) * bs, a * bs:(a + 1) * bs] = W.T
    M += np.diag(np.abs(M).sum(axis=1) + 1.0)
    return M


def _blocks(L: np.ndarray, bs: int) -> np.ndarray:
    nb = L.shape[0] // bs
    return (np.abs(L) > 1e-13).reshape(nb, bs, nb, bs).any(axis=(1, 3))


def _supernodes(s) -> list[tuple[int, int, set[int]]]:
    """The solver's supernodes: (first block column, block columns, block rows below)."""
    bs, out = s.bs, []
    for c0, k, m, r0 in zip(s.c0, s.k, s.m, s.rptr[:-1], strict=True):
        rows = {int(r) // bs for r in s.rows[r0 + k:r0 + m]}
        out.append((int(c0) // bs, int(k) // bs, rows))
    return out


CASES = [(kind, seed) for kind in ("random", "pose", "grid", "arrow", "forest")
         for seed in range(48)]


def _cancelling(adj: list[set[int]], bs: int, order: np.ndarray, below: list[set[int]],
                rng: np.random.Generator) -> tuple[np.ndarray, int, int] | None:
    """An SPD matrix on the pattern (old numbering) whose block ``(q, p)`` of ``L`` (in
    ``order``) is exactly zero, with ``(q, p)``; ``None`` if the pattern has no such place.
    A leaf column ``j`` of the elimination tree with block rows ``p < q`` below it, ``(p, q)``
    a block of the matrix that no other column before ``p`` updates, and
    ``A_qp = A_qj A_jj^-1 A_jp``: then ``L_qp = (A_qp - L_qj L_pj^T) L_pp^-T = 0``."""
    nb = len(adj)
    for j in range(nb):
        if any(j in below[c] for c in range(j)) or len(below[j]) < 2:
            continue  # not a leaf, or no pair below
        p, q = sorted(below[j])[:2]
        if int(order[q]) not in adj[int(order[p])] or any(
                p in below[c] and q in below[c] for c in range(p) if c != j):
            continue
        M = _matrix(adj, bs, rng)[np.ix_(*(2 * [(order[:, None] * bs + np.arange(bs)).ravel()]))]
        J, P, Q = (slice(v * bs, (v + 1) * bs) for v in (j, p, q))
        M[Q, P] = M[Q, J] @ np.linalg.solve(M[J, J], M[J, P])
        M[P, Q] = M[Q, P].T
        for v in (P, Q):  # diagonally dominant again (L_qp = 0 whatever L_pp is)
            M[v, v] += np.diag(np.abs(M[v]).sum(axis=1))
        old = np.empty(nb * bs, np.int64)
        old[(order[:, None] * bs + np.arange(bs)).ravel()] = np.arange(nb * bs)
        return M[np.ix_(old, old)], p, q
    return None


def _check(kind: str, seed: int, compiled: bool) -> bool:
    """The symbolic factor of one random pattern against both oracles; where the pattern has
    a place for it, also on a matrix whose dense factor cancels a block (returns whether)."""
    rng = np.random.default_rng(seed)
    nb = int(rng.integers(1, 36))
    bs = int(rng.choice([1, 2, 3]))
    adj = _pattern(kind, nb, rng)
    H = sp.csc_matrix(_matrix(adj, bs, rng))
    H.sort_indices()
    relax = ch._RELAX
    try:
        ch._RELAX = ((0, 0.0),) * 3  # fundamental supernodes: the exact pattern
        exact = ch.SupernodalSolver(compiled=compiled)
        exact.analyse(H.indptr, H.indices, H.shape[0], bs)
    finally:
        ch._RELAX = relax
    relaxed = ch.SupernodalSolver(compiled=compiled)
    relaxed.analyse(H.indptr, H.indices, H.shape[0], bs)
    for s in (exact, relaxed):
        order = s.sperm[::bs] // bs
        below = _game(adj, order)
        # oracle 2: dense Cholesky with random positive weights, three draws, the union
        union = np.zeros((nb, nb), bool)
        for _ in range(3):
            M = _matrix(adj, bs, rng)
            union |= _blocks(np.linalg.cholesky(M[np.ix_(s.sperm, s.sperm)]), bs)
        game = np.zeros((nb, nb), bool)
        for j, rows in enumerate(below):
            game[list(rows), j] = True
        np.fill_diagonal(game, True)
        np.testing.assert_array_equal(union, game)  # the two oracles agree
        # each supernode: consecutive columns, rows below = the union of its columns' rows
        # below its last column (fundamental: the columns' own structures nest exactly)
        sn = _supernodes(s)
        assert sum(k for _, k, _ in sn) == nb
        for f, k, rows in sn:
            last = f + k - 1
            want = set().union(*(below[c] for c in range(f, f + k))) - set(range(f, f + k))
            assert rows == want == below[last] - set(range(f, f + k))
        if s is exact:  # no explicit zero: the supernodes are the fundamental ones
            starts = [f for f, _, _ in sn]
            nchild = np.bincount([min(b) for b in below if b], minlength=nb)
            fund = [j for j in range(nb) if j == 0 or not (
                min(below[j - 1], default=-1) == j and nchild[j] == 1
                and below[j - 1] == below[j] | {j})]
            assert starts == fund
    # a numeric cancellation: the dense factor of that matrix loses a block that the
    # analysis (of the pattern alone) keeps; the analysis equals the reference above
    order = relaxed.sperm[::bs] // bs
    below = _game(adj, order)
    made = _cancelling(adj, bs, order, below, rng)
    if made is not None:
        Mc, p, q = made
        sp_ = relaxed.sperm
        Lc = np.linalg.cholesky(Mc[np.ix_(sp_, sp_)])
        assert np.abs(Lc[q * bs:(q + 1) * bs, p * bs:(p + 1) * bs]).max() < 1e-12 * np.abs(Lc).max()
        assert not _blocks(Lc, bs)[q, p]  # the dense factor of this matrix cancelled
        Hc = sp.csc_matrix(Mc)
        Hc.sort_indices()
        np.testing.assert_array_equal(Hc.indices, H.indices)  # the same pattern
        sc = ch.SupernodalSolver(compiled=compiled)
        sc.analyse(Hc.indptr, Hc.indices, Hc.shape[0], bs)
        np.testing.assert_array_equal(sc.sperm, relaxed.sperm)
        stored = np.zeros((nb, nb), bool)
        for f, k, rows in _supernodes(sc):
            stored[f:f + k, f:f + k] = np.tril(np.ones((k, k), bool))
            stored[sorted(rows), f:f + k] = True
        union = np.zeros((nb, nb), bool)
        for _ in range(3):  # the reference: dense factors of random positive weights
            M = _matrix(adj, bs, rng)
            union |= _blocks(np.linalg.cholesky(M[np.ix_(sp_, sp_)]), bs)
        assert stored[q, p] and union[q, p]
        if relaxed.ns == sum(1 for _ in _supernodes(exact)):  # no merge: no explicit zero
            np.testing.assert_array_equal(stored, union)
        else:
            assert (stored >= union).all()
        sc.factorize(Hc.data)
        b = rng.standard_normal(nb * bs)
        np.testing.assert_allclose(sc.solve(b), np.linalg.solve(Mc, b), rtol=1e-9, atol=1e-12)
    # ordering.symbolic on the block graph and the solver's order: tree and counts
    G = sp.csr_matrix((np.ones(sum(map(len, adj))),
                       ([a for a in range(nb) for _ in adj[a]],
                        [b for a in range(nb) for b in sorted(adj[a])])), shape=(nb, nb))
    order = relaxed.sperm[::bs] // bs
    sym = O.symbolic(G, order)
    below = _game(adj, sym.perm)
    np.testing.assert_array_equal(sym.counts, [1 + len(b) for b in below])
    np.testing.assert_array_equal(sym.parent, [min(b) if b else -1 for b in below])
    assert sum(1 + len(b) for b in _game(adj, order)) == sym.nnz  # a postorder: same fill
    return made is not None


@pytest.mark.parametrize("compiled", PATHS)
def test_symbolic_factor_equals_the_elimination_game_and_dense_cholesky(compiled):
    """240 random block patterns (block sizes 1-3); on those with a place for it (74 of
    them: random, pose and arrow shapes), a matrix whose dense factor cancels a block too."""
    cancelled = sum(_check(kind, seed, compiled) for kind, seed in CASES)
    assert cancelled >= 60


@pytest.mark.parametrize("compiled", PATHS)
def test_a_cancelling_factor_keeps_its_symbolic_entries(compiled):
    """Weights chosen so that entry (q, p) of L is exactly zero: a leaf column j of the
    elimination tree with rows p < q below it, (p, q) an entry of the matrix that no other
    column before p updates, and a_qp = a_qj a_pj / a_jj. LAPACK's factor has the zero; the
    analysis (of the pattern alone) keeps the entry, and the solver's factor is LAPACK's."""
    cancelled = 0
    for seed in range(80):
        rng = np.random.default_rng(1000 + seed)
        nb = int(rng.integers(4, 30))
        adj = _pattern(["random", "pose", "grid", "arrow"][seed % 4], nb, rng)
        M0 = _matrix(adj, 1, rng)
        H = sp.csc_matrix(M0)
        H.sort_indices()
        s = ch.SupernodalSolver(compiled=compiled)
        s.analyse(H.indptr, H.indices, nb, 1)
        order = s.sperm
        below = _game(adj, order)
        found = None
        for j in range(nb):
            if any(j in below[c] for c in range(j)) or len(below[j]) < 2:
                continue  # not a leaf, or no pair below
            p, q = sorted(below[j])[:2]
            others = any(p in below[c] and q in below[c] for c in range(p) if c != j)
            if int(order[q]) in adj[int(order[p])] and not others:
                found = (j, p, q)
                break
        if found is None:
            continue
        j, p, q = found
        M = M0[np.ix_(order, order)]
        M[q, p] = M[p, q] = M[q, j] * M[p, j] / M[j, j]
        L = np.linalg.cholesky(M)
        assert abs(L[q, p]) < 1e-14 * np.abs(L).max()  # the numeric factor cancelled
        old = np.empty(nb, np.int64)
        old[order] = np.arange(nb)
        H2 = sp.csc_matrix(M[np.ix_(old, old)])
        H2.sort_indices()
        s2 = ch.SupernodalSolver(compiled=compiled)
        s2.analyse(H2.indptr, H2.indices, nb, 1)
        np.testing.assert_array_equal(s2.sperm, order)
        stored = np.zeros((nb, nb), bool)
        for c0, k, m, r0 in zip(s2.c0, s2.k, s2.m, s2.rptr[:-1], strict=True):
            stored[np.ix_(s2.rows[r0:r0 + m], np.arange(c0, c0 + k))] = True
        assert stored[q, p]  # the symbolic factor keeps it
        for c, rows in enumerate(below):
            assert stored[list(rows), c].all()
        s2.factorize(H2.data)
        b = rng.standard_normal(nb)
        np.testing.assert_allclose(s2.solve(b), np.linalg.solve(H2.toarray(), b), rtol=1e-9)
        cancelled += 1
    assert cancelled >= 20


@pytest.mark.parametrize("bs", [1, 2, 3, 6])
def test_block_assembly_map_is_the_entrywise_one(bs, monkeypatch):
    """The assembly map of a pattern of dense blocks, found once per block (and the order
    from its block pattern), equals the one looked up entry by entry from the scalar pattern's
    block graph (the path of patterns whose blocks are not dense)."""
    real, taken = ch._blocks, []

    def spy(*a):
        taken.append(real(*a))
        return taken[-1]

    for seed in range(6):
        rng = np.random.default_rng(seed)
        nb = int(rng.integers(1, 40))
        adj = _pattern(["random", "pose", "arrow"][seed % 3], nb, rng)
        # dense diagonal blocks (a positive semi-definite addition), as in J^T J
        H = sp.csc_matrix(_matrix(adj, bs, rng) + np.kron(np.eye(nb), np.full((bs, bs), 0.05)))
        H.sort_indices()
        with monkeypatch.context() as mp:
            mp.setattr(ch, "_blocks", spy)
            fast = ch.SupernodalSolver(compiled=False)
            fast.analyse(H.indptr, H.indices, H.shape[0], bs)
        assert taken[-1] is not None  # the pattern is block-dense: the block path ran
        with monkeypatch.context() as mp:
            mp.setattr(ch, "_blocks", lambda *a: None)
            slow = ch.SupernodalSolver(compiled=False)
            slow.analyse(H.indptr, H.indices, H.shape[0], bs)
        np.testing.assert_array_equal(fast.amap, slow.amap)


@pytest.mark.parametrize("compiled", PATHS)
def test_blocks_that_are_not_dense_go_entry_by_entry(compiled):
    """A pattern whose blocks are not all dense (here: one off-diagonal block with a single
    entry, and one scalar column of a block column holding a row its twin lacks) is not read
    as blocks, and the factor still solves the system (against a dense solve)."""
    rng = np.random.default_rng(3)
    bs, nb = 2, 6
    A = np.kron(np.eye(nb), np.ones((bs, bs))) * 0.1
    A[0, 5] = A[5, 0] = 0.05  # block (0, 2): one entry of four
    A[7, 10] = A[10, 7] = 0.03  # block (3, 5): one entry; columns 6 and 7 differ
    A += np.diag(rng.uniform(2.0, 3.0, nb * bs))
    H = sp.csc_matrix(A)
    H.sort_indices()
    assert ch._blocks(H.indptr, H.indices, bs) is None
    s = ch.SupernodalSolver(compiled=compiled)
    s.analyse(H.indptr, H.indices, nb * bs, bs)
    s.factorize(H.data)
    b = rng.standard_normal(nb * bs)
    np.testing.assert_allclose(s.solve(b), np.linalg.solve(A, b), rtol=1e-12, atol=1e-12)


_FIELDS = ("sperm", "c0", "k", "m", "px", "rows", "rptr", "sparent", "amap", "pptr", "pt", "pa",
           "pb", "relptr", "rel", "_ldiag", "_diag_at")


@pytest.mark.skipif(True not in PATHS, reason="the compiled analysis is not installed")
@pytest.mark.parametrize("bs", [1, 2, 3, 6])
def test_compiled_analysis_equals_the_numpy_one(bs):
    """The C analysis (microlie._c._symbolic: elimination tree, postorder, column counts,
    supernodes, structures, update pairs, assembly map) produces every array of the NumPy
    analysis exactly, on 60 random block patterns of every shape (and the factor solves)."""
    for seed in range(60):
        rng = np.random.default_rng(500 + seed)
        nb = int(rng.integers(1, 45))
        adj = _pattern(["random", "pose", "grid", "arrow", "forest"][seed % 5], nb, rng)
        M = _matrix(adj, bs, rng) + np.kron(np.eye(nb), np.full((bs, bs), 0.05))
        H = sp.csc_matrix(M)
        H.sort_indices()
        c = ch.SupernodalSolver(compiled=True)
        c.analyse(H.indptr, H.indices, H.shape[0], bs)
        p = ch.SupernodalSolver(compiled=False)
        p.analyse(H.indptr, H.indices, H.shape[0], bs)
        for name in _FIELDS:
            if name == "amap":  # C: one entry per run of bs rows, the place of its row 0
                last = p.amap[bs - 1::bs].astype(np.int64)  # a run's last row is placed if any
                want = np.where(last < p.nx, last - (bs - 1), p.nx)
                np.testing.assert_array_equal(c.amap, want, err_msg=name)
                e = np.flatnonzero(p.amap < p.nx)  # every placed entry where its run puts it
                np.testing.assert_array_equal(c.amap[e // bs] + e % bs, p.amap[e])
                continue
            np.testing.assert_array_equal(getattr(c, name), getattr(p, name), err_msg=name)
        assert (c.ns, c.nx, c.wsize, c.usize) == (p.ns, p.nx, p.wsize, p.usize)
        c.factorize(H.data)
        b = rng.standard_normal(nb * bs)
        np.testing.assert_allclose(c.solve(b), np.linalg.solve(M, b), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("compiled", PATHS)
@pytest.mark.parametrize("bs", [1, 3])
def test_a_given_block_pattern_is_the_read_back_one(compiled, bs):
    """The block pattern handed to ``analyse`` (as ``Problem`` does) gives the same analysis
    as the one read back from the scalar pattern; a block pattern that does not expand to the
    scalar one is a ValueError."""
    for seed in range(10):
        rng = np.random.default_rng(900 + seed)
        nb = int(rng.integers(2, 40))
        adj = _pattern(["random", "pose", "arrow"][seed % 3], nb, rng)
        M = _matrix(adj, bs, rng) + np.kron(np.eye(nb), np.full((bs, bs), 0.05))
        H = sp.csc_matrix(M)
        H.sort_indices()
        B = sp.csc_matrix(np.abs(M[::bs, ::bs]) > 0)
        B.sort_indices()
        given = ch.SupernodalSolver(compiled=compiled)
        given.analyse(H.indptr, H.indices, H.shape[0], bs, block_pattern=(B.indptr, B.indices))
        read = ch.SupernodalSolver(compiled=compiled)
        read.analyse(H.indptr, H.indices, H.shape[0], bs)
        for name in _FIELDS:
            if hasattr(read, name):
                np.testing.assert_array_equal(getattr(given, name), getattr(read, name))
    with pytest.raises(ValueError, match="block_pattern"):
        ch.SupernodalSolver(compiled=compiled).analyse(
            H.indptr, H.indices, H.shape[0], bs, block_pattern=(B.indptr, B.indices[:-1]))


def test_backends_analyse_from_the_block_pattern_alone():
    """``analyse(indptr, None, ..., block_pattern=...)``: every backend solves the system
    (against a dense solve); those that need the scalar rows expand them (equal to SciPy's
    own CSC of the matrix, via ``expand_blocks``); neither rows nor blocks is a ValueError."""
    from microlie.optim import available_solvers, make_solver
    from microlie.optim.linalg.base import expand_blocks

    rng = np.random.default_rng(7)
    bs, nb = 3, 12
    adj = _pattern("pose", nb, rng)
    M = _matrix(adj, bs, rng) + np.kron(np.eye(nb), np.full((bs, bs), 0.05))
    H = sp.csc_matrix(M)
    H.sort_indices()
    B = sp.csc_matrix(np.abs(M[::bs, ::bs]) > 0)
    B.sort_indices()
    ip, ix = expand_blocks(B.indptr, B.indices, bs)
    np.testing.assert_array_equal(ip, H.indptr)
    np.testing.assert_array_equal(ix, H.indices)
    b = rng.standard_normal(nb * bs)
    for name in available_solvers():
        ls = make_solver(name)
        ls.analyse(H.indptr, None, nb * bs, bs, block_pattern=(B.indptr, B.indices))
        ls.factorize(H.data)
        np.testing.assert_allclose(ls.solve(b), np.linalg.solve(M, b), rtol=1e-9, atol=1e-12,
                                   err_msg=name)
    with pytest.raises(ValueError, match="indices is None"):
        make_solver("dense").analyse(H.indptr, None, nb * bs, bs)


@pytest.mark.parametrize("seed", range(20))
def test_numpy_patterns_equal_scipys(seed):
    """``pattern_csr`` (coordinates with duplicates -> sorted CSR) equals SciPy's
    ``csr_matrix(...).sum_duplicates()``, and ``split_blocks`` equals SciPy's
    ``B[owner][:, owner]`` (what the problem's pattern was built with before: no SciPy on the
    solve path now); bad coordinates are a ValueError."""
    from microlie.optim.linalg.base import pattern_csr, split_blocks

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 30))
    m = int(rng.integers(0, 4 * n))
    r, c = rng.integers(0, n, m), rng.integers(0, n, m)
    r, c = np.r_[r, c, np.arange(n)], np.r_[c, r, np.arange(n)]  # symmetric, with diagonal
    B = sp.csr_matrix((np.ones(r.size, bool), (r, c)), shape=(n, n))
    B.sum_duplicates()
    ip, ix = pattern_csr(r, c, n)
    np.testing.assert_array_equal(ip, B.indptr)
    np.testing.assert_array_equal(ix, B.indices)
    parts = rng.integers(1, 4, n)
    owner = np.repeat(np.arange(n), parts)
    S = B[owner][:, owner]
    S.sort_indices()
    sp_, sx = split_blocks(ip, ix, parts)
    np.testing.assert_array_equal(sp_, S.indptr)
    np.testing.assert_array_equal(sx, S.indices)
    with pytest.raises(ValueError, match=r"rows and cols must be in \[0, "):
        pattern_csr(np.array([0, n]), np.array([0, 0]), n)
