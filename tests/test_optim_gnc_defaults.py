"""GNC's defaults (``GNC(first="auto", cycle_length=None, moves=None)``) and the command's
flags.

``first="auto"`` is ``"cycles"`` for TLS on a pose graph and ``"values"`` otherwise;
``cycle_length=None`` is 8 on SE3 and 5 on SE2; ``moves=None`` is on for SE3, off for SE2.
Checked: the resolution itself, that the defaults give exactly what the explicit options
give, the checks of bad values, the message when GNC is skipped, and that ``microlie
optimize``'s flags reach the options.
"""

from __future__ import annotations

import numpy as np
import pytest

from microlie import SE2, SE3, SO3
from microlie.optim import BetweenFactor, FactorGraph, Isotropic, PriorFactor
from microlie.optim.core.gnc import GNC


def _grid(G, rows=3, cols=6, n_bad=3, seed=0, sigma=0.01):
    """A snake through a rows x cols grid (odometry) with closures between vertically adjacent
    cells, ``n_bad`` of them replaced by wild measurements. Returns (graph, poses, batch,
    outlier mask, start, i, j, measurements)."""
    rng = np.random.default_rng(seed)
    n = rows * cols
    cell = np.array([(r, c if r % 2 == 0 else cols - 1 - c) for r in range(rows)
                     for c in range(cols)])
    d = 2 if G is SE2 else 3
    tau = np.zeros((n, G.dof))
    tau[:, 0], tau[:, 1] = cell[:, 1], cell[:, 0]
    tau[:, d:] = rng.normal(0, 0.1, (n, G.dof - d))
    X = G.exp(tau)
    at = {tuple(c): k for k, c in enumerate(cell)}
    loops = [(at[(r, c)], at[(r + 1, c)]) for r in range(rows - 1) for c in range(cols)
             if abs(at[(r, c)] - at[(r + 1, c)]) > 1]
    ii = np.r_[np.arange(n - 1), [a for a, _ in loops]]
    jj = np.r_[np.arange(1, n), [b for _, b in loops]]
    Z = X[ii].between(X[jj]).compose(G.exp(rng.normal(0, sigma, (ii.size, G.dof))))
    out = np.zeros(ii.size, dtype=bool)
    out[rng.choice(np.arange(n - 1, ii.size), n_bad, replace=False)] = True
    Zp = np.asarray(Z.params).copy()
    wild = np.concatenate([rng.uniform(-5, 5, (n_bad, d)),
                           rng.uniform(-2, 2, (n_bad, G.dof - d))], axis=1)
    Zp[out] = np.asarray(G.exp(wild).params)
    g = FactorGraph()
    X0 = X[0].compose(X[0].between(X))
    x = g.add_variables(X0, fixed=[0])
    f = g.add(BetweenFactor(x, ii, jj, G.from_params(Zp), Isotropic(G.dof, sigma)))
    return g, x, f, out, X0, ii, jj, Zp


def test_auto_resolves_as_documented():
    for G, length, moves in ((SE2, 5, False), (SE3, 8, True)):
        g = _grid(G)[0]
        p = g.problem()
        tls = GNC().resolved(p)
        assert (tls.first, tls.cycle_length, tls.moves) == ("cycles", length, moves)
        # with the cycle marking: the estimated variance factor, its family-wise quantile,
        # the chain
        assert (tls.variance_factor, tls.quantile, tls.chain) == ("estimate", 1 - 1e-6, True)
        gm = GNC("gm").resolved(p)  # the cycle marking is a TLS stage
        assert (gm.first, gm.cycle_length) == ("values", length)
        assert (gm.variance_factor, gm.quantile, gm.chain) == (1.0, 0.99, False)
        given = GNC(quantile=0.95).resolved(p)  # a given quantile stays
        assert (given.variance_factor, given.quantile) == ("estimate", 0.95)
        file_info = GNC(variance_factor=1.0).resolved(p)  # the file's information: 0.99
        assert (file_info.quantile, file_info.chain) == (0.99, True)
        explicit = GNC(first="chordal", cycle_length=6, moves=not moves, quantile=0.99,
                       variance_factor=1.0, chain=False)
        assert explicit.resolved(p) is explicit  # nothing left to decide
        g, x, f = _grid(G)[:3]  # the odometry known: the file's information, per edge 0.99
        odo = GNC(known_inliers=[(f, np.abs(_grid(G)[5] - _grid(G)[6]) == 1)]).resolved(
            g.problem())
        assert (odo.variance_factor, odo.quantile, odo.chain) == (1.0, 0.99, True)
        some = GNC(known_inliers=[(f, [0, 1, 2])]).resolved(g.problem())  # not the whole chain
        assert some.variance_factor == "estimate"
        assert GNC(first="chordal").resolved(p).chain is False  # no cycle marking
        kept = GNC(first="values", moves=not moves).resolved(p)
        assert (kept.first, kept.cycle_length, kept.moves) == ("values", length, not moves)
    # not pose graphs: priors only (no BetweenFactor), and an SO3 batch
    g = FactorGraph()
    x = g.add_variables(SE2.identity(1))
    g.add(PriorFactor(x, [0, 0], SE2.identity(2)))
    r = GNC().resolved(g.problem())
    assert (r.first, r.cycle_length, r.moves) == ("values", 5, False)
    g = FactorGraph()
    y = g.add_variables(SO3.identity(3), fixed=[0])
    g.add(BetweenFactor(y, [0, 1], [1, 2], SO3.identity(2)))
    assert GNC().resolved(g.problem()).first == "values"
    # the options themselves are not changed by resolving
    opts = GNC()
    opts.resolved(_grid(SE3)[0].problem())
    assert (opts.first, opts.cycle_length, opts.moves) == ("auto", None, None)
    assert repr(opts) == "GNC('tls', quantile=None, first='auto', known_inliers=0 batches)"


@pytest.mark.parametrize("G, length, moves", [(SE2, 5, False), (SE3, 8, True)])
def test_defaults_are_the_explicit_options(G, length, moves):
    # GNC("tls") gives exactly GNC("tls", first="cycles", cycle_length=8 or 5, moves=SE3);
    # the wrong closures are found, and the answer is the least-squares optimum without them
    g, x, f, out, X0, ii, jj, Zp = _grid(G)
    res = g.optimize(robust=GNC("tls", quantile=0.9999), verbose=False)
    ref = g.optimize(robust=GNC("tls", quantile=0.9999, first="cycles", cycle_length=length,
                                moves=moves), verbose=False)
    assert np.array_equal(res.inliers[0], ref.inliers[0])
    assert np.array_equal(np.asarray(res.values[x].params), np.asarray(ref.values[x].params))
    assert np.array_equal(res.inliers[0], ~out)
    g2 = FactorGraph()  # built without the wrong closures
    x2 = g2.add_variables(X0, fixed=[0])
    keep = ~out
    g2.add(BetweenFactor(x2, ii[keep], jj[keep], G.from_params(Zp[keep]),
                         Isotropic(G.dof, 0.01)))
    clean = g2.optimize(rel_tol=1e-12, abs_tol=1e-14).values[x2]
    err = np.abs(np.asarray(res.values[x].matrix()) - np.asarray(clean.matrix())).max()
    assert err < 1e-6


def test_bad_options_are_refused():
    for kw, msg in (({"first": "odometry"}, "first must be one of"),
                    ({"first": None}, "first must be one of"),
                    ({"cycle_length": 1}, "cycle_length"), ({"cycle_length": 10}, "cycle_length"),
                    ({"cycle_length": True}, "cycle_length"),
                    ({"cycle_length": 8.0}, "cycle_length"), ({"cycle_length": "8"},
                                                              "cycle_length"),
                    ({"moves": 1}, "moves"), ({"moves": "yes"}, "moves")):
        with pytest.raises(ValueError, match=msg):
            GNC(**kw)
    # first="auto" is a TLS choice on pose graphs; "cycles" with GM is still an error
    g = _grid(SE2)[0]
    with pytest.raises(ValueError, match="is a TLS stage"):
        g.optimize(robust=GNC("gm", first="cycles"), verbose=False)


def test_skip_message_says_where_the_residuals_were_small():
    # every residual within half its threshold: no GNC, plain least squares, and the message
    # says at which estimate that was judged
    g = FactorGraph()
    x = g.add_variables(SE2.exp(np.array([[0.001, 0.0, 0.0]])))
    g.add(PriorFactor(x, [0, 0], SE2.exp(np.array([[0.0, 0.0, 0.0], [0.002, 0.0, 0.0]])),
                      Isotropic(3, 0.01)))
    for first, where in (("auto", "at the start values"), ("values", "at the start values"),
                         ("least-squares", "at the least-squares estimate")):
        res = g.optimize(robust=GNC("tls", first=first), verbose=False)
        assert "GNC skipped" in res.message and where in res.message, res.message
        assert res.outer_iterations == 0 and np.all(res.weights[0] == 1.0)
        # the plain least-squares optimum of two priors: their mean
        assert np.allclose(np.asarray(res.values[x].log()), [[0.001, 0.0, 0.0]], atol=1e-9)


def test_command_flags_reach_the_options(tmp_path, monkeypatch):
    import argparse
    import io
    import json

    from microlie.optim.command import register, run
    from microlie.optim.core import gnc as gnc_module

    g, x, f, out, X0, ii, jj, Zp = _grid(SE2)
    P = np.asarray(X0.params)
    th = np.arctan2(P[:, 3], P[:, 2]).tolist()
    tz = np.arctan2(Zp[:, 3], Zp[:, 2]).tolist()
    p, z = P.tolist(), Zp.tolist()
    lines = [f"VERTEX_SE2 {k} {p[k][0]!r} {p[k][1]!r} {th[k]!r}" for k in range(len(p))]
    lines += [f"EDGE_SE2 {a} {b} {z[e][0]!r} {z[e][1]!r} {tz[e]!r} 10000 0 0 10000 0 10000"
              for e, (a, b) in enumerate(zip(ii.tolist(), jj.tolist(), strict=True))]
    path = tmp_path / "grid.g2o"
    path.write_text("\n".join(lines) + "\n")
    seen: list[tuple[str, int, bool]] = []
    orig = gnc_module.GNC.resolved

    def spy(self, problem):
        r = orig(self, problem)
        seen.append((r.first, r.cycle_length, r.moves))
        return r

    monkeypatch.setattr(gnc_module.GNC, "resolved", spy)
    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    for extra, want in (([], ("cycles", 5, False)),
                        (["--gnc-first", "auto"], ("cycles", 5, False)),
                        (["--gnc-first", "values"], ("values", 5, False)),
                        (["--gnc-cycle-length", "7", "--gnc-moves"], ("cycles", 7, True)),
                        (["--gnc-first", "cycles", "--no-gnc-moves"], ("cycles", 5, False))):
        seen.clear()
        args = parser.parse_args(["optimize", str(path), "--robust", "gnc-tls", "--json",
                                  *extra])
        out = io.StringIO()
        assert run(args, out, io.StringIO()) == 0
        assert seen[0] == want, extra  # gnc_solve's, then the report's
        opts = json.loads(out.getvalue())["gnc"]["options"]
        assert (opts["first"], opts["cycle_length"], opts["moves"]) == want, extra
        assert (opts["search"], opts["assemble"]) == (False, False)
    seen.clear()
    args = parser.parse_args(["optimize", str(path), "--robust", "gnc-gm", "--json"])
    assert run(args, io.StringIO(), io.StringIO()) == 0
    assert seen and seen[0][0] == "values"
