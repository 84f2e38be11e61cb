"""One linearisation (residuals, Jacobians, whitening, block products and the scatter into the
fixed pattern) and one trial cost of the shared pose graphs: the compiled edge loop of
``microlie._c._graph`` (``microlie.optim.core.compiled``) against the NumPy path, interleaved in one
process.

Run (one command; needs the compiled kernels: ``python setup.py build_ext --inplace``)::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/pose_graph_linearize.py [--rounds 20]

The NumPy path's problem is built with ``MICROLIE_FAST=0`` set, which turns off the compiled edge
loop only (the group kernels were registered at import, so it still uses the compiled SE(3)
minus/compose kernels); ``benchmarks/pose_graph.py`` times whole solves in both configurations.
Prints min and median ms per call and the ratio of the minima.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from microlie.optim import compiled, from_pose_graph
from microlie.optim.core.problem import Problem
from microlie.optim.init import initialize
from microlie.optim.io.g2o import read_g2o

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = {"sphere2500": ("sphere2500.g2o", "file"),
          "parking-garage": ("parking-garage.g2o", "file"),
          "M3500": ("input_M3500_g2o.g2o", "file"),
          "ais2klinik": ("ais2klinik.g2o", "chordal"),
          "kitti_00": ("kitti_00.g2o", "odometry")}


def rounds(pc: Problem, pn: Problem, states: list, n: int) -> dict[str, list[float]]:
    """Times of compiled linearize / NumPy linearize / compiled cost / NumPy cost, alternating."""
    t: dict[str, list[float]] = {"lc": [], "ln": [], "cc": [], "cn": []}
    lc = pc.linearize(states)
    calls = (("lc", lambda: pc.linearize(states, out=lc)), ("ln", lambda: pn.linearize(states)),
             ("cc", lambda: pc.costs(states)), ("cn", lambda: pn.costs(states)))
    for _ in range(n):
        for key, fn in calls:
            t0 = time.perf_counter()
            fn()
            t[key].append(time.perf_counter() - t0)
    return t


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=20)
    args = ap.parse_args(argv)
    if not compiled.available():
        print("the compiled edge loop was not built (python setup.py build_ext --inplace) "
              "or MICROLIE_FAST=0")
        return 1
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    print(f"pose_graph_linearize.py, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
          f"{args.rounds} rounds; `uptime`: {load}\n")
    print("| graph | edges | linearize compiled ms (min/median) | NumPy path ms | ratio | "
          "trial cost compiled ms | NumPy path ms | ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for name, (fname, start) in GRAPHS.items():
        pg = read_g2o(DATA / fname)
        fg, _ = from_pose_graph(pg, initialize(pg, start))
        pc = Problem(fg.variables, fg.factors, "check")
        saved = os.environ.get("MICROLIE_FAST")
        os.environ["MICROLIE_FAST"] = "0"
        try:
            pn = Problem(fg.variables, fg.factors, "check")
        finally:
            if saved is None:
                del os.environ["MICROLIE_FAST"]
            else:
                os.environ["MICROLIE_FAST"] = saved
        t = rounds(pc, pn, [v.initial for v in pc.variables], args.rounds)

        def cell(k, t=t):
            return f"{min(t[k]) * 1e3:.2f}/{statistics.median(t[k]) * 1e3:.2f}"

        print(f"| {name} | {pc.factors[0].count} | {cell('lc')} | {cell('ln')} | "
              f"{min(t['ln']) / min(t['lc']):.1f}x | {cell('cc')} | {cell('cn')} | "
              f"{min(t['cn']) / min(t['cc']):.1f}x |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
