"""The ``components=True`` pass of ``repair_bridges`` (microlie.optim.core.gnc_bridges): the
pieces no accepted edge holds are attached one at a time, largest first. The pass keeps the
components by union-find and evaluates a piece again only when it merged or a neighbour moved;
its decisions must be those of the plain rule, written out here as the session-13 loop did it
(recompute the components after every attachment and rescan them all, largest first), on random
graphs with many floating pieces, ties of size and of support, pieces without cut edges and
pieces that only a known inlier could hold."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from microlie import SE2, SE3
from microlie.optim.core import gnc_bridges as B

C2 = 9.0


def _rescanning_pass(group, n, ii, jj, P, w, M, Minv, Zinv, info, judged, c2, s0, anchor):
    """The rule, plainly: after each attachment recompute the components of the accepted edges
    and scan them all again, largest first (ties: lowest label, i.e. lowest vertex), skipping
    the root (the anchor's, else the largest); the first with a supported cut motion moves."""
    changed = False
    while True:
        keep = np.flatnonzero(w > 0.5)
        ncomp, lab = connected_components(coo_matrix((np.ones(keep.size), (ii[keep], jj[keep])),
                                                     shape=(n, n)), directed=False)
        size = np.bincount(lab, minlength=ncomp)
        root = lab[anchor] if anchor is not None else int(np.argmax(size))
        for comp in np.argsort(-size, kind="stable"):
            inP = lab == comp
            cut = np.flatnonzero(inP[ii] != inP[jj])
            if comp == root or not cut.size:
                continue
            D, fits = B._cut_motions(group, P, ii, jj, inP, cut, M, Minv, Zinv, info, judged,
                                     c2)
            support = fits.sum(axis=1)
            if support.max() == 0:
                continue
            best = B._choose(fits, support, cut, s0, c2)
            P[inP] = D[best] @ P[inP]
            w[cut[judged[cut]]] = fits[best][judged[cut]].astype(np.float64)
            changed = True
            break
        else:
            return changed


def _random_case(group, seed):
    """Pieces of a true graph, each moved by its own rigid motion, held together only by
    rejected edges: good ones (true relative poses) and wrong ones (random, and pairs that agree
    on a wrong placement of a piece, for ties of support). Known inliers are accepted (GNC
    keeps their weight 1), except two that disagree, between pieces 0 and 1: every motion of a
    piece with both in its cut breaks one, so it is never attached."""
    rng = np.random.default_rng(seed)
    d = group.dof
    sizes = rng.choice([1, 1, 2, 2, 3, 4, 6], size=int(rng.integers(8, 30)))
    sizes[0] = int(rng.integers(1, 12))
    n = int(sizes.sum())
    piece = np.repeat(np.arange(sizes.size), sizes)
    rng.shuffle(piece)                     # pieces are not runs of vertex numbers
    truth = group.exp(rng.standard_normal((n, d)) * 2.0)
    Tm = np.asarray(truth.matrix())
    move = np.asarray(group.exp(rng.standard_normal((sizes.size, d)) * 3.0).matrix())
    P = move[piece] @ Tm
    ii, jj, Zm, w, judged = [], [], [], [], []

    def edge(a, b, Zab, wt, jd=True):
        ii.append(a), jj.append(b), Zm.append(Zab), w.append(wt), judged.append(jd)

    for p in range(sizes.size):           # accepted chains inside the pieces
        v = np.flatnonzero(piece == p)
        for a, b in zip(v[:-1], v[1:], strict=True):
            edge(a, b, np.linalg.inv(P[a]) @ P[b], 1.0, bool(rng.random() < 0.8))
    lonely = set(rng.choice(np.arange(2, sizes.size), size=2, replace=False).tolist())
    others = [v for v in range(n) if piece[v] not in lonely]
    for _ in range(int(rng.integers(n, 3 * n))):
        a, b = rng.choice(others, size=2, replace=False)
        if piece[a] == piece[b]:
            continue
        kind = rng.random()
        if kind < 0.45:                   # good: the true relative pose, a little noise
            Zab = np.linalg.inv(Tm[a]) @ Tm[b] @ np.asarray(
                group.exp(0.01 * rng.standard_normal(d)).matrix())
        elif kind < 0.75:                 # wrong, random
            Zab = np.asarray(group.exp(rng.standard_normal(d) * 2.0).matrix())
        else:                             # wrong, but two of them agree: b's piece elsewhere
            alt = np.asarray(group.exp(rng.standard_normal(d)).matrix())
            b2 = rng.choice(np.flatnonzero(piece == piece[b]))
            edge(a, b2, np.linalg.inv(Tm[a]) @ alt @ Tm[b2], float(rng.choice([0.0, 0.2])))
            Zab = np.linalg.inv(Tm[a]) @ alt @ Tm[b]
        edge(a, b, Zab, float(rng.choice([0.0, 0.3])))
    for _ in range(2):                     # the two rejected known inliers that disagree
        a, b = rng.choice(np.flatnonzero(piece == 0)), rng.choice(np.flatnonzero(piece == 1))
        edge(a, b, np.asarray(group.exp(rng.standard_normal(d) * 2.0).matrix()), 0.0, False)
    ii, jj = np.array(ii), np.array(jj)
    Z = group.from_matrix(np.array(Zm), normalize=True)
    A = rng.standard_normal((ii.size, d, d)) * 0.3
    info = 40.0 * (A @ np.swapaxes(A, 1, 2) + np.eye(d))
    start = B.whitened_residuals(group, Tm, ii, jj, Z.inverse(), info)
    start *= rng.uniform(0.5, 2.0, ii.size)  # some good edges off at the start, some wrong on
    return n, ii, jj, Z, info, P, np.array(w), np.array(judged), start


@pytest.mark.parametrize("group", [SE2, SE3], ids=["SE2", "SE3"])
@pytest.mark.parametrize("seed", range(12))
def test_components_pass_decides_as_the_rescanning_rule(group, seed):
    n, ii, jj, Z, info, P0, w0, judged, start = _random_case(group, 100 * seed + group.dof)
    Zinv = Z.inverse()
    M, Minv = np.asarray(Z.matrix()), np.asarray(Zinv.matrix())
    rng = np.random.default_rng(seed)
    stats = []
    for anchor in (None, int(rng.integers(n))):
        for s0 in (None, start):
            ref_P, ref_w = P0.copy(), w0.copy()
            ref = _rescanning_pass(group, n, ii, jj, ref_P, ref_w, M, Minv, Zinv, info, judged,
                                   C2, s0, anchor)
            got_P, got_w = P0.copy(), w0.copy()
            got = B._attach_components(group, n, ii, jj, got_P, got_w, M, Minv, Zinv, info,
                                       judged, C2, s0, anchor)
            assert got == ref
            assert np.array_equal(got_w, ref_w)
            assert np.array_equal(got_P, ref_P)
            if anchor is not None:         # the anchor never moves
                assert np.array_equal(got_P[anchor], P0[anchor])
            stats.append(int(np.sum((got_w > 0.5) & (w0 <= 0.5))))
    assert max(stats) > 0                  # the pass attached pieces: not a vacuous check


def test_components_pass_on_repair_bridges():
    """End to end (``repair_bridges(..., components=True)``): every floating piece whose cut
    holds a good edge ends at its true pose relative to the anchor's piece when the good edges
    outnumber the wrong ones across each cut; the pieces without cut edges stay where they
    were."""
    rng = np.random.default_rng(5)
    n, k = 40, 8                           # 8 pieces of 5 vertices, vertex 0 the anchor
    piece = np.repeat(np.arange(k), n // k)
    truth = SE2.exp(rng.standard_normal((n, 3)))
    Tm = np.asarray(truth.matrix())
    move = np.asarray(SE2.exp(rng.standard_normal((k, 3)) * 3.0).matrix())
    move[0] = np.eye(3)
    P = move[piece] @ Tm
    ii, jj, Zm, w = [], [], [], []
    for a in range(n - 1):                  # the chain: accepted inside pieces, rejected across
        ii.append(a), jj.append(a + 1), Zm.append(np.linalg.inv(Tm[a]) @ Tm[a + 1])
        w.append(1.0 if piece[a] == piece[a + 1] else 0.0)
    for p in range(1, k - 1):              # two more good edges and one wrong across each cut
        for a, b in ((5 * p - 2, 5 * p + 3), (5 * p - 3, 5 * p + 1)):
            ii.append(a), jj.append(b), Zm.append(np.linalg.inv(Tm[a]) @ Tm[b]), w.append(0.0)
        ii.append(5 * p - 1), jj.append(5 * p + 2), w.append(0.0)
        Zm.append(np.asarray(SE2.exp(rng.standard_normal(3) * 2).matrix()))
    keep = np.flatnonzero(~((np.array(ii) >= 34) | (np.array(jj) >= 35)))  # last piece: alone
    ii, jj = np.array(ii)[keep], np.array(jj)[keep]
    Z = SE2.from_matrix(np.array(Zm)[keep], normalize=True)
    w = np.array(w)[keep]
    info = np.tile(np.eye(3) * 100.0, (ii.size, 1, 1))
    X2, w2 = B.repair_bridges(SE2, n, ii, jj, Z, info, SE2.from_matrix(P), w,
                              np.ones(ii.size, bool), C2, anchor=0, components=True)
    got = np.asarray(X2.matrix())
    assert np.allclose(got[:35], Tm[:35], atol=1e-9)
    assert np.allclose(got[35:], P[35:], atol=1e-12)  # unchanged (a round trip)
    good = np.array([np.allclose(np.linalg.inv(Tm[a]) @ Tm[b], z) for a, b, z in
                     zip(ii, jj, np.asarray(Z.matrix()), strict=True)])
    assert np.array_equal(w2 > 0.5, good)
