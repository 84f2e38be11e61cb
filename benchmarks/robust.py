"""Graduated non-convexity on pose graphs with random loop-closure outliers (issue 22).

For each graph, outlier rate, seed and start: a fraction of the loop closures (edges between
non-consecutive vertices) is replaced by random ones (random endpoints two or more vertices
apart, translation uniform in [-10, 10] m per axis, uniformly random rotation, the replaced
edge's information). The reference is the outlier-free optimum: LM from the chordal start on
the graph without the replaced edges. GNC-TLS (``FactorGraph.optimize(robust=GNC(...))``, with
the library's defaults (``first="auto"``: the cycle marking on these pose graphs, with cycles
up to 8 edges and the moves on SE3, 5 and no moves on SE2) unless ``--first``,
``--cycle-length``, ``--moves`` or ``--search`` say otherwise, and its default data-snooping
re-test unless ``--retest 0``) runs from the odometry or the chordal start of the corrupted
graph, without and with the odometry as known inliers; the table gives the APE (RMS position
difference to the reference, same gauge: the first vertex held at the same pose, no alignment),
the precision and recall of ``result.inliers`` over the loop closures (inlier sense), the outer
and inner iterations and the time. Whether a miss is the solver's fault or the problem's:
``TLS - ref`` is our TLS objective ``0.5 sum min(s, c^2)`` over every edge of the corrupted graph
minus the reference's (its poses on the corrupted graph), in units of ``c^2/2`` (one edge;
above 0: GNC stopped in a local minimum); ``ties`` counts the bridges of the true inlier graph
(not known inliers) that a wrong edge also crosses (largest smaller side in brackets), and the
swap witness (the reference with that side moved so that the wrong edge fits,
``microlie.optim.core.gnc_ties``) gives its ``TLS - ref`` (~0: an exact tie) and APE. A summary
per graph ends the output.
GTSAM's ``GncOptimizer`` (TLS, LM inner solver, the same known inliers and threshold
probability, a prior on the first pose) runs in a child process on the ``--gtsam-cases``
subset with a timeout; its APE and our time over its time are printed. GTSAM's runs are long:
``--gtsam-only FILE`` runs only them (beside a microlie run) and saves each result to FILE as it
finishes, and ``--gtsam-json FILE`` takes them from there.

Run from the worktree root with the benchmark environment::

    PYTHONPATH=src /work/bench-venv/bin/python benchmarks/robust.py --graphs M3500 \\
        --rates 0.1 --seeds 0 --starts odometry --gtsam-cases M3500:0.1:0:odometry:known
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from microlie import SE2, SO2, SO3
from microlie.optim.core.gnc import GNC, inlier_thresholds, squared_norms
from microlie.optim.core.gnc_ties import swap_witness, tie_bridges
from microlie.optim.init import initialize
from microlie.optim.io.g2o import read_g2o, write_g2o

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = {"M3500": "input_M3500_g2o.g2o", "sphere2500": "sphere2500.g2o"}

CHILD = r"""
import json, sys, time
import numpy as np
import gtsam
path, is3d, known, prob, out = sys.argv[1], sys.argv[2] == "1", json.loads(sys.argv[3]), \
    float(sys.argv[4]), sys.argv[5]
graph, initial = gtsam.readG2o(path, is3d)
n_edges = graph.size()
tight = gtsam.noiseModel.Isotropic.Sigma(6 if is3d else 3, 1e-6)
if is3d:
    graph.add(gtsam.PriorFactorPose3(0, initial.atPose3(0), tight))
else:
    graph.add(gtsam.PriorFactorPose2(0, initial.atPose2(0), tight))
params = gtsam.GncLMParams()
params.setLossType(gtsam.GncLossType.TLS)
params.setKnownInliers(known + [n_edges])
t0 = time.perf_counter()
opt = gtsam.GncLMOptimizer(graph, initial, params)
opt.setInlierCostThresholdsAtProbability(prob)
res = opt.optimize()
dt = time.perf_counter() - t0
keys = sorted(res.keys())
P = np.array([(res.atPose3(k).translation() if is3d else
               np.array([res.atPose2(k).x(), res.atPose2(k).y()])) for k in keys])
w = np.asarray(opt.getWeights())[:n_edges]
np.save(out, P)
print(json.dumps({"time_s": dt, "weights_in": (w > 0.5).tolist()}))
"""


def corrupt(pg, rate: float, seed: int):
    """The graph with ``rate`` of its loop closures replaced by random edges, and the indices
    of the replaced edges."""
    ii, jj = pg.edge_index()
    loops = np.flatnonzero(np.abs(ii - jj) != 1)
    rng = np.random.default_rng(seed)
    k = int(round(rate * loops.size))
    bad = np.sort(rng.choice(loops, k, replace=False))
    V = pg.ids.size
    a = rng.integers(0, V, k)
    b = (a + rng.integers(2, V - 1, k)) % V
    d = 2 if pg.group is SE2 else 3
    rot = (SO2 if pg.group is SE2 else SO3).random(k, rng=rng)
    Z = pg.group.from_rotation_translation(rot, rng.uniform(-10.0, 10.0, (k, d)))
    i2, j2 = pg.i.copy(), pg.j.copy()
    i2[bad], j2[bad] = pg.ids[a], pg.ids[b]
    meas = np.asarray(pg.measurements.params).copy()
    meas[bad] = np.asarray(Z.params)
    return pg.replace(i=i2, j=j2, measurements=pg.group.from_params(meas)), bad


def _reference_result(pg, bad):
    keep = np.setdiff1d(np.arange(pg.i.size), bad)
    clean = pg.replace(i=pg.i[keep], j=pg.j[keep], measurements=pg.measurements[keep],
                       information=pg.information[keep])
    fg, x = clean.to_factor_graph(initialize(clean, "chordal"), gauge="fix")
    return fg.optimize(), x


def reference(pg, bad):
    """The outlier-free optimum: LM from chordal on the graph without the replaced edges
    (positions and cost)."""
    res, x = _reference_result(pg, bad)
    return np.asarray(res.values[x].translation()), res.final_cost


def reference_poses(pg, bad):
    """The outlier-free optimum's poses (see :func:`reference`)."""
    res, x = _reference_result(pg, bad)
    return res.values[x]


def tls_objective(problem, X, c2: float) -> float:
    """``0.5 * sum min(s, c^2)`` over every edge of a pose graph's problem at poses ``X``."""
    s = squared_norms(problem, [np.asarray(X.params, dtype=np.float64)])[0]
    return 0.5 * float(np.minimum(s, c2).sum())


class Ties:
    """Whether a miss can be the problem's: the tie-capable bridges of the true inlier graph
    and the swap witness (module docstring of ``microlie.optim.core.gnc_ties``)."""

    def __init__(self, pg2, bad, Xref, odo: np.ndarray):
        self.fg, _ = pg2.to_factor_graph(Xref, gauge="fix")
        self.problem = self.fg.problem()
        self.Xref = Xref
        ii, jj = pg2.edge_index()
        good = np.ones(ii.size, bool)
        good[bad] = False
        P0 = np.asarray(Xref.translation())
        self.swaps: dict[str, tuple[int, int, object, float] | None] = {}
        for known, judged in (("none", None), ("odometry", ~odo)):
            tb = tie_bridges(pg2.ids.size, ii, jj, good, judged)
            if not tb:
                self.swaps[known] = None
                continue
            W = swap_witness(Xref, ii, jj, pg2.measurements, tb[0].side, int(tb[0].wrong[0]),
                             fixed=0)
            self.swaps[known] = (len(tb), tb[0].side.size, W, ape(W.translation(), P0))

    def delta(self, X, c2: float) -> float:
        """Our TLS objective minus the reference's with the threshold ``c2`` GNC used
        (its quantile times its variance factor), in units of ``c^2/2`` (edges)."""
        ref = tls_objective(self.problem, self.Xref, c2)
        return (tls_objective(self.problem, X, c2) - ref) / (c2 / 2)

    def cell(self, known: str, c2: float) -> tuple[str, bool]:
        """The ``ties``, ``swap TLS - ref`` and ``swap APE`` cells, and whether ties exist."""
        sw = self.swaps[known]
        if sw is None:
            return " 0 | | |", False
        n, side, W, err = sw
        return f" {n} ({side}) | {self.delta(W, c2):.2e} | {err:.2e} |", True


def scores(pred_in, bad, loops):
    truth = np.ones(pred_in.size, bool)
    truth[bad] = False
    p, t = pred_in[loops], truth[loops]
    tp = int(np.sum(p & t))
    return tp / max(1, int(p.sum())), tp / max(1, int(t.sum()))


def ape(P, P0) -> float:
    return float(np.sqrt(np.mean(np.sum((np.asarray(P) - P0) ** 2, axis=1))))


def run_gtsam(pg2, X0, known, quantile, timeout, python):
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "g.g2o")
        write_g2o(path, pg2, X0)
        out = os.path.join(tmp, "p.npy")
        cmd = [python, "-c", CHILD, path, "1" if pg2.group is not SE2 else "0",
               json.dumps([int(k) for k in known]), str(quantile), out]
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return None
        if proc.returncode != 0:
            raise RuntimeError(proc.stderr[-2000:])
        info = json.loads(proc.stdout.strip().splitlines()[-1])
        return info["time_s"], np.load(out), np.array(info["weights_in"])


def gtsam_record(got, bad, loops, P0, timeout) -> dict:
    """GTSAM's result as a JSON-able record: time (None: timed out), APE, precision, recall."""
    if got is None:
        return {"time_s": None, "timeout": timeout}
    gt, gP, gin = got
    gp, gr = scores(gin, bad, loops)
    return {"time_s": gt, "ape": ape(gP, P0), "precision": gp, "recall": gr}


def gtsam_cells(rec, dt: float) -> str:
    if rec["time_s"] is None:
        return f" - | - | > {rec['timeout']:.0f} (timeout) | < {dt / rec['timeout']:.3f} |"
    return (f" {rec['ape']:.2e} | {rec['precision']:.4f} / {rec['recall']:.4f} | "
            f"{rec['time_s']:.2f} | {dt / rec['time_s']:.3f} |")


def run_gtsam_only(args, gcases) -> None:
    """GTSAM's GncOptimizer alone on ``gcases``, each result printed and saved to JSON as it
    finishes."""
    out: dict[str, object] = {}
    path = Path(args.gtsam_only)
    if path.exists():
        out = json.loads(path.read_text())
    for gname, rate, seed, start, known in sorted(gcases):
        key = ":".join((gname, rate, seed, start, known))
        if key in out:
            continue
        pg = read_g2o(DATA / GRAPHS[gname])
        ii, jj = pg.edge_index()
        loops = np.flatnonzero(np.abs(ii - jj) != 1)
        pg2, bad = corrupt(pg, float(rate), int(seed))
        P0, _ = reference(pg2, bad)
        X0 = initialize(pg2, start)
        kidx = np.flatnonzero(np.abs(ii - jj) == 1) if known == "known" else []
        got = run_gtsam(pg2, X0, kidx, args.quantile or 0.99, args.gtsam_timeout, args.python)
        out[key] = gtsam_record(got, bad, loops, P0, args.gtsam_timeout)
        print(key, out[key], flush=True)
        path.write_text(json.dumps(out, indent=1))


def used_variance(message: str) -> float:
    """The variance factor GNC used, from its result's message (1 when not given)."""
    m = re.search(r"variance factor ([0-9.eE+-]+)", message)
    return float(m.group(1)) if m else 1.0


def _variance(text: str) -> float | str:
    return text if text == "estimate" else float(text)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--graphs", nargs="+", default=list(GRAPHS), choices=list(GRAPHS))
    ap.add_argument("--rates", nargs="+", type=float, default=[0.1, 0.3, 0.5, 0.7])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--starts", nargs="+", default=["odometry", "chordal"],
                    choices=["odometry", "chordal"])
    ap.add_argument("--known", nargs="+", default=["none", "odometry"],
                    choices=["none", "odometry"], help="runs without / with known inliers")
    ap.add_argument("--quantile", type=float, default=None,
                    help="chi-square quantile of the inlier threshold (default: GNC's, 0.99 "
                         "or 1 - 1e-6 with the estimated variance factor; GTSAM: 0.99)")
    ap.add_argument("--first", default=None, choices=["auto", "chordal", "cycles", "values",
                                                      "least-squares"],
                    help="GNC(first=...): where the first weights come from (default: GNC's, "
                         "auto: cycles on these pose graphs)")
    ap.add_argument("--retest", type=int, default=None,
                    help="GNC(retest=...): data-snooping passes after GNC (0: off; default: "
                         "GNC's, 3)")
    ap.add_argument("--cycle-length", type=int, default=None,
                    help="GNC(cycle_length=...): longest cycle of the first='cycles' marking "
                         "(default: GNC's, 8 on SE3 and 5 on SE2)")
    ap.add_argument("--moves", action=argparse.BooleanOptionalAction, default=None,
                    help="GNC(moves=...): pieces moved where their cut edges fit best (default: "
                         "GNC's, on for SE3 and off for SE2)")
    ap.add_argument("--search", action=argparse.BooleanOptionalAction, default=None,
                    help="GNC(search=...): the local search of core/gnc_search.py after GNC, "
                         "region moves and their chains (default: GNC's, off)")
    ap.add_argument("--assemble", action=argparse.BooleanOptionalAction, default=None,
                    help="GNC(assemble=True): pieces joined by cycles of pieces before the "
                         "chordal stage (core/gnc_assemble.py; default: GNC's, off)")
    ap.add_argument("--variance-factor", default=None, type=_variance,
                    help="GNC(variance_factor=): a number or 'estimate' (default: GNC's, 1)")
    ap.add_argument("--chain", action=argparse.BooleanOptionalAction, default=None,
                    help="GNC(chain=True): the nearest-index spanning tree decides ties and is "
                         "tried as known inliers (default: GNC's, off)")
    ap.add_argument("--gtsam-cases", nargs="*", default=[],
                    help="GRAPH:RATE:SEED:START:KNOWN cases GTSAM's GncOptimizer also runs "
                         "(KNOWN: none or known)")
    ap.add_argument("--gtsam-timeout", type=float, default=600.0)
    ap.add_argument("--python", default=sys.executable, help="Python with gtsam")
    ap.add_argument("--gtsam-only", metavar="JSON", default=None,
                    help="run only GTSAM on --gtsam-cases and save its results to JSON (a long "
                         "run that can go beside microlie's)")
    ap.add_argument("--gtsam-json", metavar="JSON", default=None,
                    help="take GTSAM's results from a --gtsam-only file instead of running it")
    args = ap.parse_args(argv)
    gcases = {tuple(c.split(":")) for c in args.gtsam_cases}
    saved: dict[str, object] = {}
    if args.gtsam_json:
        saved = json.loads(Path(args.gtsam_json).read_text())
        gcases |= {tuple(k.split(":")) for k in saved}
    if args.gtsam_only:
        run_gtsam_only(args, gcases)
        return
    opts = {k: v for k, v in (("quantile", args.quantile), ("first", args.first),
                              ("retest", args.retest), ("cycle_length", args.cycle_length),
                              ("moves", args.moves), ("search", args.search),
                              ("assemble", args.assemble),
                              ("variance_factor", args.variance_factor),
                              ("chain", args.chain)) if v is not None}
    shown = GNC("tls", **opts)  # type: ignore[arg-type]
    print(f"quantile {shown.quantile} (None: 1 - 1e-6 with the estimated variance factor, "
          f"else 0.99), first weights from {shown.first}, retest {shown.retest}, cycle_length "
          f"{shown.cycle_length} (None: 8 on SE3, 5 on SE2), moves {shown.moves} (None: on for "
          f"SE3, off for SE2), search {shown.search}, assemble {shown.assemble}, variance "
          f"factor {shown.variance_factor} (None: estimate with the cycle marking), chain "
          f"{shown.chain} (None: on with the cycle marking) (GNC's defaults unless given: "
          f"{opts or 'none given'}); "
          f"APE in m against the outlier-free optimum; P/R: precision/recall of result.inliers "
          f"over loop closures")
    print("TLS - ref: our TLS objective 0.5 sum min(s, c^2) over every edge of the corrupted "
          "graph minus the outlier-free optimum's, in units of c^2/2 (1 = one edge); ties: "
          "bridges of the true inlier graph (not known inliers) crossed by a wrong edge "
          "(largest smaller side); swap: the reference with that side moved so that a wrong "
          "edge across fits exactly, its TLS - ref (edges) and APE to the reference (m); "
          "answer ties: len(result.ties), the pieces of OUR answer that a rejected edge could "
          "hold at the same TLS objective (GNC says 'not unique')")
    print("| graph | outliers | seed | start | known inliers | APE (m) | P | R | outer | "
          "inner | time (s) | GTSAM APE (m) | GTSAM P / R | GTSAM time (s) | ratio | "
          "TLS - ref (edges) | ties (side) | swap TLS - ref (edges) | swap APE (m) | "
          "answer ties |")
    print("|" + " --- |" * 20)
    summary: dict[tuple[str, str], list[int]] = {}
    for gname in args.graphs:
        pg = read_g2o(DATA / GRAPHS[gname])
        ii, jj = pg.edge_index()
        loops = np.flatnonzero(np.abs(ii - jj) != 1)
        odo = np.abs(ii - jj) == 1
        for rate in args.rates:
            for seed in args.seeds:
                pg2, bad = corrupt(pg, rate, seed)
                Xref = reference_poses(pg2, bad)
                P0 = np.asarray(Xref.translation())
                ties = Ties(pg2, bad, Xref, odo)
                for start in args.starts:
                    X0 = initialize(pg2, start)
                    for known in args.known:
                        fg, x = pg2.to_factor_graph(X0, gauge="fix")
                        ki = [(fg.factors[0], odo)] if known == "odometry" else None
                        gnc = GNC("tls", known_inliers=ki, **opts)  # type: ignore[arg-type]
                        t0 = time.perf_counter()
                        res = fg.optimize(robust=gnc, verbose=False)
                        dt = time.perf_counter() - t0
                        p, r = scores(res.inliers[0], bad, loops)
                        err = ape(res.values[x].translation(), P0)
                        used = gnc.resolved(fg.problem())
                        c2 = inlier_thresholds(fg.problem().factors, used.quantile)[0] * \
                            used_variance(res.message)
                        dtls = ties.delta(res.values[x], c2)
                        tcell, tied = ties.cell(known, c2)
                        tally = summary.setdefault((gname, known), [0, 0, 0, 0, 0, 0, 0])
                        tally[0] += 1
                        tally[1] += err <= 0.01
                        tally[2] += dtls <= 1e-3
                        tally[3] += tied
                        flagged = len(res.ties or [])
                        tally[4] += flagged > 0
                        tally[5] += err > 0.01 and not flagged
                        tally[6] += "kept the answer that held the chain" in res.message
                        row = (f"| {gname} | {rate:.0%} | {seed} | {start} | {known} | "
                               f"{err:.2e} | {p:.4f} | "
                               f"{r:.4f} | {res.outer_iterations} | {res.iterations} | "
                               f"{dt:.2f} |")
                        key = (gname, f"{rate:g}", str(seed), start,
                               "known" if known == "odometry" else "none")
                        if ":".join(key) in saved:
                            row += gtsam_cells(saved[":".join(key)], dt)
                        elif key in gcases:
                            kidx = np.flatnonzero(odo) if known == "odometry" else []
                            got = run_gtsam(pg2, X0, kidx, args.quantile or 0.99,
                                            args.gtsam_timeout, args.python)
                            row += gtsam_cells(gtsam_record(got, bad, loops, P0,
                                                            args.gtsam_timeout), dt)
                        else:
                            row += " | | | |"
                        print(row + f" {dtls:.3g} |" + tcell + f" {flagged} |", flush=True)
    print()
    for (gname, known), (n, met, opt, tied, flag, silent, held) in summary.items():
        print(f"{gname}, known inliers {known}: {n} cases; within 0.01 m: {met}; TLS-optimal "
              f"(TLS - ref <= 1e-3 edges): {opt}; with ties: {tied}; answers flagged not "
              f"unique: {flag}; misses not flagged: {silent}"
              + f"; chain hypothesis kept: {held}")


if __name__ == "__main__":
    main()
