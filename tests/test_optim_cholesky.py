"""The supernodal Cholesky (microlie.optim.linalg.cholesky): its factor against LAPACK's dense
Cholesky
of the same permuted matrix, its solves against dense solves and SuperLU, with the compiled
loop (microlie._c._chol) and with the NumPy loop."""

from __future__ import annotations

import os

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from microlie.optim import SingularSystemError, make_solver
from microlie.optim.linalg.cholesky import SupernodalSolver

try:
    import microlie._c._chol  # noqa: F401

    INSTALLED = True
except ImportError:
    INSTALLED = False
# the compiled loop runs unless MICROLIE_FAST=0 (CI also runs without it)
HAVE_C = INSTALLED and os.environ.get("MICROLIE_FAST", "1").strip() != "0"


def _paths():
    """The NumPy loop always; the compiled loop where installed (required in CI)."""
    from conftest import IN_CI

    if IN_CI and not INSTALLED:
        pytest.fail("microlie._c._chol is required in CI but was not built")
    return [False, True] if HAVE_C else [False]


PATHS = _paths()


def _random_spd(bs: int, nb: int, seed: int, extra: int = 2, corner: int = 4):
    """A block-sparse SPD matrix: a chain, random long edges, a dense corner."""
    rng = np.random.default_rng(seed)
    pairs = {(k, k + 1) for k in range(nb - 1)}
    pairs |= {tuple(sorted(rng.choice(nb, 2, replace=False))) for _ in range(nb // extra)}
    pairs |= {(a, b) for a in range(max(nb - corner, 0), nb) for b in range(a + 1, nb)}
    n = nb * bs
    M = np.zeros((n, n))
    for a, b in pairs:
        J = rng.standard_normal((bs + 1, 2 * bs))
        idx = np.r_[a * bs:(a + 1) * bs, b * bs:(b + 1) * bs]
        M[np.ix_(idx, idx)] += J.T @ J
    M += 1e-3 * np.eye(n)
    H = sp.csc_matrix(M)
    H.sort_indices()
    return M, H


def _dense_factor(s: SupernodalSolver) -> np.ndarray:
    """The factor L assembled from the solver's panels (its own numbering)."""
    L = np.zeros((s.n, s.n))
    for j, (c0, k, m, r0) in enumerate(zip(s.c0, s.k, s.m, s.rptr[:-1], strict=True)):
        L[np.ix_(s.rows[r0:r0 + m], np.arange(c0, c0 + k))] = s._panel(j)
    return np.tril(L)


@pytest.mark.parametrize("compiled", PATHS)
@pytest.mark.parametrize("bs, nb, seed", [(6, 40, 1), (3, 120, 2), (2, 7, 3), (1, 50, 4),
                                          (6, 1, 5), (3, 300, 6), (1, 1, 7)])
def test_factor_equals_dense_cholesky_and_solves(compiled, bs, nb, seed):
    M, H = _random_spd(bs, nb, seed)
    s = SupernodalSolver(compiled=compiled)
    s.analyse(H.indptr, H.indices, H.shape[0], bs)
    s.factorize(H.data)
    p = s.sperm
    Ld = np.linalg.cholesky(M[np.ix_(p, p)])
    np.testing.assert_allclose(_dense_factor(s), Ld, rtol=0, atol=1e-10 * np.abs(Ld).max())
    rng = np.random.default_rng(seed)
    b = rng.standard_normal(H.shape[0])
    np.testing.assert_allclose(s.solve(b), np.linalg.solve(M, b), rtol=1e-8, atol=1e-10)
    B = rng.standard_normal((H.shape[0], 5))
    np.testing.assert_allclose(s.solve(B), np.linalg.solve(M, B), rtol=1e-8, atol=1e-10)
    # refactorised with new numbers in the same pattern
    H2 = H.copy()
    H2.data = H.data * 2.0
    s.factorize(H2.data)
    np.testing.assert_allclose(s.solve(b), np.linalg.solve(2.0 * M, b), rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("compiled", PATHS)
def test_symbolic_structure_is_the_exact_fill(compiled):
    """The panels hold every nonzero of the exact factor and no row that is structurally zero
    beyond the relaxed amalgamation's explicit zeros: with amalgamation off the stored
    structure equals the nonzero structure of the dense factor."""
    import microlie.optim.linalg.cholesky as ch

    M, H = _random_spd(1, 200, 11, extra=3, corner=0)
    relax = ch._RELAX
    try:
        ch._RELAX = ((0, 0.0),) * 3
        s = SupernodalSolver(compiled=compiled)
        s.analyse(H.indptr, H.indices, H.shape[0], 1)
    finally:
        ch._RELAX = relax
    s.factorize(H.data)
    p = s.sperm
    Ld = np.linalg.cholesky(M[np.ix_(p, p)])
    stored = np.zeros(Ld.shape, bool)
    for c0, k, m, r0 in zip(s.c0, s.k, s.m, s.rptr[:-1], strict=True):
        stored[np.ix_(s.rows[r0:r0 + m], np.arange(c0, c0 + k))] = True
    stored = np.tril(stored)
    assert not (np.abs(Ld) > 1e-14)[~stored].any()
    # no stored entry is structurally zero (generic random values do not cancel)
    assert (np.abs(Ld[stored]) > 0).all()


@pytest.mark.parametrize("compiled", PATHS)
def test_not_positive_definite_is_an_error(compiled):
    M, H = _random_spd(3, 30, 5)
    s = SupernodalSolver(compiled=compiled)
    s.analyse(H.indptr, H.indices, H.shape[0], 3)
    bad = H.copy()
    bad.data[bad.indices == np.repeat(np.arange(H.shape[0]), np.diff(bad.indptr))] *= -1.0
    with pytest.raises(SingularSystemError, match="not positive definite"):
        s.factorize(bad.data)
    nan = H.copy()
    nan.data[0] = np.nan
    with pytest.raises(SingularSystemError):
        s.factorize(nan.data)
        s.solve(np.ones(H.shape[0]))


@pytest.mark.parametrize("compiled", PATHS)
@pytest.mark.parametrize("name", ["sphere2500", "parking-garage", "input_M3500_g2o"])
def test_real_graph_systems_match_superlu(compiled, name):
    """The Gauss-Newton matrices of shared pose graphs at their initial poses."""
    from conftest import data_file

    from microlie.optim import from_pose_graph
    from microlie.optim.io.g2o import read_g2o

    pg = read_g2o(data_file(f"pose_graph/{name}.g2o"))
    g, _ = from_pose_graph(pg)
    prob = g.problem()
    H = prob.matrix(prob.linearize([v.initial for v in prob.variables]).data)
    b = np.random.default_rng(0).standard_normal(H.shape[0])
    s = SupernodalSolver(compiled=compiled)
    s.analyse(prob.indptr, prob.indices, prob.size, prob.block_size)
    s.factorize(H.data)
    x = s.solve(b)
    ref = spla.splu(H, permc_spec="MMD_AT_PLUS_A").solve(b)
    np.testing.assert_allclose(x, ref, rtol=1e-6, atol=1e-9 * np.abs(ref).max())
    assert np.abs(H @ x - b).max() < 1e-8 * np.abs(b).max() * max(1.0, np.abs(H.data).max())


@pytest.mark.skipif(not HAVE_C, reason="the compiled loop is not installed")
def test_compiled_and_numpy_loops_agree():
    M, H = _random_spd(6, 60, 9)
    a, c = SupernodalSolver(compiled=False), SupernodalSolver(compiled=True)
    for s in (a, c):
        s.analyse(H.indptr, H.indices, H.shape[0], 6)
        s.factorize(H.data)
    for j in range(a.ns):
        np.testing.assert_allclose(a._panel(j), c._panel(j), rtol=0,
                                   atol=1e-12 * np.abs(c.Lx).max())


def test_compiled_switch(monkeypatch):
    monkeypatch.setenv("MICROLIE_FAST", "0")
    assert SupernodalSolver()._c is None
    with pytest.raises(ImportError, match="microlie._c._chol"):
        SupernodalSolver(compiled=True)
    assert make_solver("cholesky").name == "cholesky"


def test_auto_picks_by_installation(monkeypatch):
    """Default install, 2-D and 3-D: the supernodal Cholesky with or without its compiled loop
    (benchmarks/pose_graph.py: the NumPy loop beat SuperLU on all five graphs); SuperLU where
    the supernodal Cholesky is not offered; small problems: dense."""
    default = ["scipy", "cholesky", "dense"]
    assert make_solver("auto", 100, 3, default).name == "dense"
    assert make_solver("auto", 5000, 6, default).name == "cholesky"
    assert make_solver("auto", 5000, 6, ["scipy"]).name == "scipy"
    monkeypatch.setenv("MICROLIE_FAST", "0")
    s = make_solver("auto", 5000, 3, default)
    assert s.name == "cholesky" and s.__dict__["_c"] is None
    if INSTALLED:
        monkeypatch.setenv("MICROLIE_FAST", "1")
        assert make_solver("auto", 5000, 3, default).name == "cholesky"
        assert make_solver("auto", 5000, 3, default).__dict__["_c"] is not None


@pytest.mark.parametrize("bs, nb, seed, extra", [(6, 200, 4, 3), (3, 400, 5, 3)])
def test_numpy_plan_paths_match_dense_cholesky(bs, nb, seed, extra):
    """The NumPy loop's kinds of buckets all occur and give LAPACK's dense factor: members
    padded to a common shape, batched NumPy cholesky/inv, LAPACK per member, buckets of one,
    and the scatters in complex words (even ``bs``) or entries (odd)."""
    M, H = _random_spd(bs, nb, seed, extra=extra)
    s = SupernodalSolver(compiled=False)
    s.analyse(H.indptr, H.indices, H.shape[0], bs)
    p = s._numpy_plan
    buckets = [b for level in p.levels for b in level]
    assert p.size > int((s.k * s.m).sum())  # padding
    assert any(b.batched for b in buckets)
    assert any(not b.batched and b.G > 1 for b in buckets)
    assert any(b.G == 1 for b in buckets)
    assert p.word == (2 if bs % 2 == 0 else 1)
    for scale in (1.0, 3.0):  # twice in the same buffers
        s.factorize(H.data * scale)
        Ld = np.linalg.cholesky(scale * M[np.ix_(s.sperm, s.sperm)])
        np.testing.assert_allclose(_dense_factor(s), Ld, rtol=0,
                                   atol=1e-10 * np.abs(Ld).max())
    b = np.random.default_rng(seed).standard_normal((H.shape[0], 3))
    np.testing.assert_allclose(s.solve(b), np.linalg.solve(3.0 * M, b), rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("compiled", PATHS)
def test_pattern_with_partial_blocks(compiled):
    """Blocks of the pattern that are not dense (entries that cancelled) are assembled entry by
    entry; the factor is still LAPACK's."""
    M, _ = _random_spd(2, 60, 12)
    rng = np.random.default_rng(12)
    i, j = np.nonzero(np.triu(M, 2))
    pick = rng.choice(i.size, i.size // 4, replace=False)
    M[i[pick], j[pick]] = M[j[pick], i[pick]] = 0.0
    M += 50.0 * np.eye(M.shape[0])
    H = sp.csc_matrix(M)
    H.sort_indices()
    s = SupernodalSolver(compiled=compiled)
    s.analyse(H.indptr, H.indices, H.shape[0], 2)
    if not compiled:
        assert s._numpy_plan._aword == 1
    s.factorize(H.data)
    Ld = np.linalg.cholesky(M[np.ix_(s.sperm, s.sperm)])
    np.testing.assert_allclose(_dense_factor(s), Ld, rtol=0, atol=1e-10 * np.abs(Ld).max())


@pytest.mark.parametrize("compiled", PATHS)
def test_solve_after_a_failed_factorisation_is_an_error(compiled):
    M, H = _random_spd(3, 30, 5)
    s = SupernodalSolver(compiled=compiled)
    s.analyse(H.indptr, H.indices, H.shape[0], 3)
    with pytest.raises(SingularSystemError, match="none yet"):
        s.solve(np.ones(H.shape[0]))
    s.factorize(H.data)
    with pytest.raises(SingularSystemError, match="not positive definite"):
        s.factorize(-H.data)
    with pytest.raises(SingularSystemError, match="failed"):
        s.solve(np.ones(H.shape[0]))
    s.factorize(H.data)
    np.testing.assert_allclose(s.solve(np.ones(H.shape[0])),
                               np.linalg.solve(M, np.ones(H.shape[0])), rtol=1e-8)


@pytest.mark.parametrize("compiled", PATHS)
def test_wrong_sizes_are_errors(compiled):
    M, H = _random_spd(3, 20, 8)
    s = SupernodalSolver(compiled=compiled)
    s.analyse(H.indptr, H.indices, H.shape[0], 3)
    with pytest.raises(ValueError, match="pattern has"):
        s.factorize(H.data[:-1])
    s.factorize(H.data)
    with pytest.raises(ValueError, match="right-hand side"):
        s.solve(np.ones(H.shape[0] + 1))
    with pytest.raises(ValueError, match="right-hand side"):
        s.solve(np.ones((2, H.shape[0])))


# the twelve shared pose graphs and their starts (those of tests/test_optim_graphs.py)
POSE_GRAPHS = [("gtsam/pose2example.txt", "file"), ("gtsam/pose3example.txt", "file"),
               ("tinyGrid3D.g2o", "file"), ("smallGrid3D.g2o", "file"), ("MIT.g2o", "chordal"),
               ("CSAIL.g2o", "odometry"), ("manhattan.g2o", "odometry"),
               ("kitti_00.g2o", "odometry"), ("input_M3500_g2o.g2o", "file"),
               ("parking-garage.g2o", "file"), ("sphere2500.g2o", "file"),
               ("ais2klinik.g2o", "chordal")]


@pytest.mark.skipif(not HAVE_C, reason="the compiled loop is not installed (or MICROLIE_FAST=0)")
@pytest.mark.parametrize("name, start", POSE_GRAPHS, ids=[g[0] for g in POSE_GRAPHS])
def test_numpy_loop_residual_within_2x_of_the_compiled_loop(name, start):
    """The NumPy loop (the default install's) is as accurate as the compiled one: on the first
    LM system of every shared pose graph (Gauss-Newton matrix at the start plus LM's initial
    damping ``1e-5 I``, right-hand side minus the gradient), its relative residual
    ``|H x - b| / |b|`` (a sparse product) is at most twice the compiled loop's (floored at
    one rounding unit)."""
    from conftest import data_file

    from microlie.optim.init import initialize
    from microlie.optim.io.g2o import read_g2o

    g = read_g2o(data_file(f"pose_graph/{name}"))
    fg, _ = g.to_factor_graph(initialize(g, start))  # type: ignore[arg-type]
    prob = fg.problem()
    lin = prob.linearize([v.initial for v in prob.variables])
    data = lin.data.copy()
    data[prob.diag_pos] += 1e-5  # SolverOptions().lambda_initial, H + lambda I
    H = prob.matrix(data)
    b = -lin.grad
    res = {}
    for compiled in (False, True):
        # both in the order the NumPy loop runs with in a default install (SciPy's MMD; with
        # the compiled order MIT's ill-conditioned system gives 4.6e-13 against 2.0e-13)
        s = SupernodalSolver(compiled=compiled, ordering="mmd")
        s.analyse(prob.indptr, prob.indices, prob.size, prob.block_size)
        s.factorize(data)
        x = s.solve(b)
        res[compiled] = float(np.linalg.norm(H @ x - b) / np.linalg.norm(b))
    print(f"{name}: relative residual NumPy loop {res[False]:.2e}, compiled loop "
          f"{res[True]:.2e} ({res[False] / res[True]:.2f}x)")
    # a relative residual of a few eps is rounding, where a ratio of two measures noise
    # (manhattan with the portable build: 8.5e-16 against 4.3e-16); the floor is 4 eps
    assert res[False] <= 2.0 * max(res[True], 4 * np.finfo(float).eps)


@pytest.mark.skipif(not HAVE_C, reason="the compiled loop is not installed")
def test_compiled_assembly_map_by_runs():
    """The C analysis maps runs of bs rows (one entry per run; the factor equals the dense
    Cholesky); a map of neither length is refused."""
    M, H = _random_spd(3, 30, 11)
    s = SupernodalSolver(compiled=True)
    s.analyse(H.indptr, H.indices, H.shape[0], 3)
    assert s.amap.size * 3 == H.nnz
    s.factorize(H.data)
    L = _dense_factor(s)
    P = np.eye(s.n)[:, s.sperm]  # new -> old: A[perm][:, perm] = L L^T
    np.testing.assert_allclose(L, np.linalg.cholesky(P.T @ M @ P), rtol=0,
                               atol=1e-10 * np.abs(M).max())
    amap = s.amap
    s.amap = amap[:-1]
    with pytest.raises(ValueError, match="amap must have one entry per entry"):
        s.factorize(H.data)
    s.amap = amap


@pytest.mark.parametrize("seed", range(6))
def test_numpy_buckets_are_the_cheapest_contiguous_partition(seed):
    """The NumPy loop's buckets of one level: every supernode in exactly one bucket, the
    buckets contiguous runs of the distinct shapes sorted by ``(k, u)``, and their summed cost
    (``_bucket_cost`` of the run padded to its largest ``k`` and ``u``) the minimum over every
    partition into contiguous runs, found here by enumerating all ``2**(S - 1)`` of them."""
    from itertools import product

    from microlie.optim.linalg.cholesky_numpy import _bucket_cost, _buckets

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    k = rng.choice([3, 6, 18, 48], n)  # at most 12 shapes: 2048 partitions to enumerate
    u = rng.choice([0, 12, 300], n)
    out = _buckets(k, u)
    members = np.sort(np.concatenate(out))
    np.testing.assert_array_equal(members, np.arange(n))
    shapes = sorted(set(zip(k.tolist(), u.tolist(), strict=True)))
    cnt = [int(np.sum((k == a) & (u == b))) for a, b in shapes]
    run_of = {s: r for r, s in enumerate(shapes)}
    got = 0.0
    prev = -1
    for mem in out:
        idx = sorted({run_of[(int(k[m]), int(u[m]))] for m in mem.tolist()})
        assert idx == list(range(idx[0], idx[-1] + 1)) and idx[0] == prev + 1  # contiguous
        assert sum(cnt[i] for i in idx) == mem.size
        prev = idx[-1]
        got += _bucket_cost(mem.size, int(k[mem].max()), int(u[mem].max()))
    best = np.inf
    S = len(shapes)
    for cuts in product([False, True], repeat=S - 1):
        total, start = 0.0, 0
        for end in [i + 1 for i, c in enumerate(cuts) if c] + [S]:
            run = shapes[start:end]
            total += _bucket_cost(sum(cnt[start:end]), max(a for a, _ in run),
                                  max(b for _, b in run))
            start = end
        best = min(best, total)
    assert got == pytest.approx(best, rel=1e-12)


@pytest.mark.parametrize("K", [1, 2, 6, 13])
def test_numpy_band_maps_hold_the_lower_band(K):
    """``_band_maps(K)``: the band rows of one member hold ``band[c, t] = L11[c + t, c]`` for
    ``t < K - c`` (the layout of LAPACK's lower band storage, transposed), checked against the
    dense matrix entry by entry."""
    from microlie.optim.linalg.cholesky_numpy import _band_maps

    L11 = np.tril(np.random.default_rng(K).standard_normal((K, K)))
    D = L11.T.copy()  # D[c, r] = L11[r, c]
    src, dst = _band_maps(K)
    band = np.zeros((K, K))
    band.ravel()[dst] = D.ravel()[src]
    for c in range(K):
        for t in range(K):
            assert band[c, t] == (L11[c + t, c] if c + t < K else 0.0)
