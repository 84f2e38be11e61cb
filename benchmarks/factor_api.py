"""Issue 20: the public factor API (``Factor.residual`` called through the checked
``Factor.evaluate``) must not slow the pose-graph linearisation. Times one linearisation and one
trial cost of sphere2500 and M3500 with two checkouts of ``src`` in alternating subprocesses
(interleaved: a burst of load hits both alike) and prints the ratio of the medians, after /
before.

Run (one command)::

    git archive 7bdf25a src | tar -x -C /tmp/before    # the code before the change
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/factor_api.py \\
        --before /tmp/before/src --after src --rounds 5

Per graph and checkout: ``linearize NumPy`` (the problem built with ``MICROLIE_FAST=0``: every
factor through ``evaluate_into``), ``cost NumPy`` (residuals only, through ``evaluate``) and
``linearize compiled`` (the compiled edge loop for the between factors, the gauge prior through
the NumPy path; skipped without the compiled kernels). Each worker times ``--calls`` calls of each,
interleaved, and reports their median; the table shows the median over rounds.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = {"sphere2500": ("sphere2500.g2o", "file"), "M3500": ("input_M3500_g2o.g2o", "file")}


def worker(calls: int) -> dict:
    """Median seconds per call of each measurement, per graph (run inside one checkout)."""
    from microlie.optim import from_pose_graph
    from microlie.optim.core import compiled
    from microlie.optim.core.problem import Problem
    from microlie.optim.init import initialize
    from microlie.optim.io.g2o import read_g2o

    out: dict = {}
    for name, (fname, start) in GRAPHS.items():
        pg = read_g2o(DATA / fname)
        fg, _ = from_pose_graph(pg, initialize(pg, start))
        os.environ["MICROLIE_FAST"] = "0"
        pn = Problem(fg.variables, fg.factors, "check")
        del os.environ["MICROLIE_FAST"]
        pc = Problem(fg.variables, fg.factors, "check") if compiled.available() else None
        out[name] = _times(pn, pc, [v.initial for v in pn.variables], calls)
    return out


def _times(pn, pc, states: list, calls: int) -> dict[str, float]:
    """Median seconds of each call, interleaved, after one warm-up call each."""
    import gc

    fns = {"linearize NumPy": lambda: pn.linearize(list(states)),
           "cost NumPy": lambda: pn.costs(states)}
    if pc is not None:
        lc = pc.linearize(states)
        fns["linearize compiled"] = lambda: pc.linearize(states, out=lc)
    for fn in fns.values():  # warm-up: work arrays, caches
        fn()
    t: dict[str, list[float]] = {k: [] for k in fns}
    gc.disable()
    try:
        for _ in range(calls):
            for key, fn in fns.items():
                t0 = time.perf_counter()
                fn()
                t[key].append(time.perf_counter() - t0)
    finally:
        gc.enable()
    return {k: statistics.median(v) for k, v in t.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--before", required=True, help="the src folder of the code before")
    ap.add_argument("--after", default="src", help="the src folder of the code after")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--calls", type=int, default=15)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        print(json.dumps(worker(args.calls)))
        return 0
    runs: dict[str, list[dict]] = {"before": [], "after": []}
    for _ in range(args.rounds):
        for which in ("before", "after"):
            src = str(Path(getattr(args, which)).resolve())
            env = dict(os.environ, PYTHONPATH=src, OPENBLAS_NUM_THREADS="1")
            r = subprocess.run([sys.executable, __file__, "--worker", "--before", src,
                                "--calls", str(args.calls)], env=env, capture_output=True,
                               text=True, check=True)
            runs[which].append(json.loads(r.stdout))
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(f"factor_api.py, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"{args.rounds} rounds x {args.calls} calls; `uptime`: {load}\n")
    print("| graph | measurement | before ms | after ms | after / before |")
    print("|---|---|---|---|---|")
    for name in GRAPHS:
        for key in runs["before"][0][name]:
            b = statistics.median(r[name][key] for r in runs["before"])
            a = statistics.median(r[name][key] for r in runs["after"])
            print(f"| {name} | {key} | {b * 1e3:.2f} | {a * 1e3:.2f} | {a / b:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
