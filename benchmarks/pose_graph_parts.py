"""The default install's pose-graph solve part by part, at a git revision against this checkout.

Run (one command, from the project root)::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/pose_graph_parts.py \
        --before-after d1eded8 [--rounds 4] [--graphs sphere2500 parking-garage]

Both versions run ``FactorGraph.optimize(linear_solver="cholesky")`` with
``MICROLIE_FAST=0`` (NumPy and SciPy only) on the same graphs from the file's vertices (pose 0
held fixed, as ``benchmarks/pose_graph.py`` does), each in fresh processes that alternate
before, after, before, ... for ``--rounds`` rounds of three solves each after one warm-up solve
(the graph, its pattern and the symbolic analysis are built before, untimed). The revision's
``src`` is extracted with ``git archive``. The table gives the median over all solves of each
part of ``Result.timings`` (linearise / assemble / trial costs / retract / other / factorise /
solve, ms), of the whole solve, and of its process CPU time, and the ratio after/before. The
figures are whole-solve parts: GTSAM is not run here (``benchmarks/pose_graph.py`` times us
against it); use this to see which part moved between two commits.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data" / "pose_graph"
GRAPHS = {"sphere2500": "sphere2500.g2o", "parking-garage": "parking-garage.g2o"}
PARTS = ("linearize", "assemble", "cost", "retract", "other", "factorize", "solve")


def child(src: str, graphs: list[str], solves: int) -> None:
    """Solve each graph ``solves`` times with the microlie found in ``src``; print JSON."""
    sys.path.insert(0, src)
    from microlie.optim import from_pose_graph
    from microlie.optim.init import initialize
    from microlie.optim.io.g2o import read_g2o

    out = {}
    for name in graphs:
        pg = read_g2o(DATA / GRAPHS[name])
        fg, poses = from_pose_graph(pg, initialize(pg, "file"))
        fg.problem().analysed("cholesky")
        fg.optimize(linear_solver="cholesky", verbose=False)  # warm-up
        rows = []
        for _ in range(solves):
            c = time.process_time()
            r = fg.optimize(linear_solver="cholesky", verbose=False)
            rows.append(dict(r.timings, total=r.time_s, cpu=time.process_time() - c,
                             cost_final=r.final_cost, iterations=r.iterations))
        out[name] = rows
    print(json.dumps(out))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before-after", required=True, metavar="REV",
                    help="the git revision to compare this checkout with")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--graphs", nargs="*", default=list(GRAPHS), choices=list(GRAPHS))
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args.child, args.graphs, 3)
        return 0
    env = dict(os.environ, MICROLIE_FAST="0")
    for v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
        env.setdefault(v, "1")
    start = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        tar = subprocess.run(["git", "-C", str(ROOT), "archive", args.before_after, "src"],
                             check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=tar, check=True)
        srcs = {"before": str(Path(tmp) / "src"), "after": str(ROOT / "src")}
        acc: dict[str, dict[str, list[dict]]] = {k: {} for k in srcs}
        for _ in range(args.rounds):
            for k, src in srcs.items():
                res = subprocess.run([sys.executable, __file__, "--before-after",
                                      args.before_after, "--child", src, "--graphs",
                                      *args.graphs], env=env, check=True, capture_output=True,
                                     text=True)
                for g, rows in json.loads(res.stdout).items():
                    acc[k].setdefault(g, []).extend(rows)
    end = os.getloadavg()
    keys = (*PARTS, "total", "cpu")
    print(f"pose_graph_parts.py --before-after {args.before_after} --rounds {args.rounds}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, MICROLIE_FAST=0, one BLAS "
          f"thread; load average at the start {start[0]:.2f}, at the end {end[0]:.2f}")
    for g in args.graphs:
        b, a = acc["before"][g], acc["after"][g]
        if {round(r["cost_final"], 9) for r in a} != {round(r["cost_final"], 9) for r in b}:
            print(f"WARNING {g}: final costs differ", file=sys.stderr)
        print(f"\n{g} ({len(a)} solves each, {a[0]['iterations']} iterations), median ms:\n")
        print("| version | " + " | ".join(keys) + " | linearize+assemble+cost |")
        print("|---" * (len(keys) + 2) + "|")
        med = {}
        for k, rows in (("before", b), ("after", a)):
            med[k] = {q: statistics.median(r[q] for r in rows) * 1e3 for q in keys}
            med[k]["mine"] = statistics.median(r["linearize"] + r["assemble"] + r["cost"]
                                               for r in rows) * 1e3
            print(f"| {k} ({args.before_after if k == 'before' else 'this checkout'}) | "
                  + " | ".join(f"{med[k][q]:.1f}" for q in keys) + f" | {med[k]['mine']:.1f} |")
        print("| after/before | " + " | ".join(
            f"{med['after'][q] / med['before'][q]:.2f}" if med["before"][q] > 0 else "-"
            for q in (*keys, "mine")) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
