"""BLAS threads in the solver on a busy machine (issue 19, item 13).

Run from the repository root (any Python with microlie's dependencies)::

    PYTHONPATH=src python benchmarks/blas_threads.py [--rounds 7] [--graph sphere2500.g2o]

A busy-loop process (``while True: pass``) keeps one core busy for the whole run; then each
round runs, in one subprocess each and in turn (interleaved, so that a burst of other load hits
every condition alike), ``python -m microlie.cli optimize GRAPH --json`` as:

* ``new default``: this checkout, no thread setting anywhere (one BLAS thread in the solver);
* ``one thread (env)``: this checkout with ``OPENBLAS_NUM_THREADS=1`` etc. (the one-thread time);
* ``opt-out``: this checkout with ``--blas-threads 0``, no thread variable (the BLAS library's
  default threads: the old behaviour);
* ``old main``: ``--base`` (default ``/work/base/src``) on ``PYTHONPATH``, no thread variable.

The thread variables (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``) are
removed from the children's environment except in ``one thread (env)``; anything else
(``OPENBLAS_CORETYPE``, ``OPENBLAS_L2_SIZE``, ``MICROLIE_FAST``) is passed on and printed. Two
times are reported, labelled: ``process`` (wall clock from the start of the subprocess to its
exit: imports, reading, initialisation, solve) and ``solve`` (the report's ``time_s``, the
solve alone, measured inside the process). Medians with the interquartile range and min-max,
and the ratios of medians to ``new default``. The load average is printed before and after.

``--overhead`` instead times, in this process, the limit's own cost: ``optimize()`` against
``optimize(blas_threads=None)`` on a 4-pose SE(2) chain (about a millisecond), alternating.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data" / "pose_graph"
THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
SHOWN_VARS = ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE", "MICROLIE_FAST", "GOTO_NUM_THREADS")


def _conditions(base: str) -> dict[str, tuple[str, dict[str, str], list[str]]]:
    """label -> (PYTHONPATH, extra environment, extra command-line arguments)."""
    src = str(ROOT / "src")
    one = {v: "1" for v in THREAD_VARS}
    return {"new default": (src, {}, []),
            "one thread (env)": (src, one, []),
            "opt-out (--blas-threads 0)": (src, {}, ["--blas-threads", "0"]),
            "old main": (base, {}, [])}


def _run(graph: Path, pythonpath: str, extra_env: dict[str, str], args: list[str]
         ) -> tuple[float, float, float]:
    env = {k: v for k, v in os.environ.items() if k not in THREAD_VARS}
    env.update(extra_env)
    # the caller's PYTHONPATH (e.g. where threadpoolctl lives) after ours, without this src
    rest = [q for q in os.environ.get("PYTHONPATH", "").split(os.pathsep)
            if q and Path(q).resolve() != ROOT / "src"]
    env["PYTHONPATH"] = os.pathsep.join([pythonpath, *rest])
    cmd = [sys.executable, "-m", "microlie.cli", "optimize", str(graph), "--json", *args]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{p.stderr}")
    report = json.loads(p.stdout)
    return wall, float(report["time_s"]), float(report["final_cost"])


def _stats(xs: list[float]) -> str:
    q = statistics.quantiles(xs, n=4) if len(xs) > 1 else [xs[0]] * 3
    return (f"{statistics.median(xs):7.3f} (IQR {q[0]:.3f}-{q[2]:.3f}, "
            f"{min(xs):.3f}-{max(xs):.3f})")


def _per_round(xs: list[float], refs: list[float]) -> str:
    r = [x / y for x, y in zip(xs, refs, strict=True)]
    return f"{statistics.median(r):.2f} ({min(r):.2f}-{max(r):.2f})"


def overhead(rounds: int) -> None:
    """Per-call cost of the limit on a tiny graph (in process, alternating)."""
    import numpy as np

    from microlie import SE2
    from microlie.optim import BetweenFactor, Diagonal, FactorGraph, PriorFactor

    g = FactorGraph()
    x = g.add_variables(SE2.identity(4))
    g.add(PriorFactor(x, 0, SE2.identity(), Diagonal([0.1] * 3)))
    g.add(BetweenFactor(x, [0, 1, 2], [1, 2, 3], SE2.exp(np.tile([1.0, 0, 0.1], (3, 1))),
                        Diagonal([0.1] * 3)))
    times: dict[str | None, list[float]] = {"1": [], None: []}
    for r in range(rounds + 1):
        for k in times:
            t = time.perf_counter()
            g.optimize(blas_threads=None if k is None else int(k))
            if r:  # the first round warms up
                times[k].append(time.perf_counter() - t)
    one, none = (statistics.median(times[k]) * 1e3 for k in ("1", None))
    print(f"4-pose SE(2) chain, {rounds} alternating rounds, load "
          f"{os.getloadavg()[0]:.2f}: optimize() {one:.3f} ms, optimize(blas_threads=None) "
          f"{none:.3f} ms, ratio {one / none:.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--graph", default="sphere2500.g2o", help="a file of ../shared/data/pose_graph")
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--base", default="/work/base/src",
                    help="PYTHONPATH of the old main (before the change)")
    ap.add_argument("--no-busy", action="store_true", help="do not start the busy-loop process")
    ap.add_argument("--only", nargs="+", default=None, metavar="LABEL",
                    choices=("new", "env", "opt-out", "old"),
                    help="run only these conditions (new default and one thread (env) are "
                         "always kept: the acceptance ratio needs both)")
    ap.add_argument("--overhead", action="store_true",
                    help="only the limit's own cost on a tiny graph (in process)")
    a = ap.parse_args()
    if a.overhead:
        overhead(max(a.rounds, 50))
        return
    graph = (DATA / a.graph).resolve()
    if not graph.exists():
        sys.exit(f"{graph}: missing (the shared data sets)")
    conds = _conditions(a.base)
    if a.only:
        keep = {"new", "env", *a.only}
        short = dict(zip(conds, ("new", "env", "opt-out", "old"), strict=True))
        conds = {k: v for k, v in conds.items() if short[k] in keep}
    if "old main" in conds and not Path(a.base).is_dir():
        del conds["old main"]
        print(f"{a.base}: missing, old main skipped", file=sys.stderr)
    env_shown = ", ".join(f"{k}={os.environ[k]}" for k in SHOWN_VARS if k in os.environ)
    print(f"# BLAS threads: `microlie optimize {a.graph} --json`, {a.rounds} interleaved rounds")
    print(f"\nload average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; "
          f"cores: {os.cpu_count()}; busy loop: {'no' if a.no_busy else 'one process'}; "
          f"environment: {env_shown or 'no BLAS variables'}; python {sys.version.split()[0]}; "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(1))  # the busy loop ends with us
    busy = None if a.no_busy else subprocess.Popen([sys.executable, "-c", "while True: pass"])
    walls: dict[str, list[float]] = {k: [] for k in conds}
    solves: dict[str, list[float]] = {k: [] for k in conds}
    costs: dict[str, float] = {}
    try:
        for k in conds:  # warm-up round: file cache, .pyc
            _run(graph, *conds[k])
        for r in range(a.rounds):
            for k, (pp, env, args) in conds.items():
                w, s, c = _run(graph, pp, env, args)
                walls[k].append(w)
                solves[k].append(s)
                costs[k] = c
            print(f"round {r + 1}/{a.rounds}: " + ", ".join(
                f"{k} {walls[k][-1]:.2f}/{solves[k][-1]:.2f} s" for k in conds), file=sys.stderr)
    finally:
        if busy is not None:
            busy.kill()
            busy.wait()
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}\n")
    ref_w = statistics.median(walls["new default"])
    ref_s = statistics.median(solves["new default"])
    print("| condition | process s, median (IQR, min-max) | ratio | per-round ratio | solve s, "
          "median (IQR, min-max) | ratio | per-round ratio | final cost |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for k in conds:
        print(f"| {k} | {_stats(walls[k])} | {statistics.median(walls[k]) / ref_w:.2f} | "
              f"{_per_round(walls[k], walls['new default'])} | {_stats(solves[k])} | "
              f"{statistics.median(solves[k]) / ref_s:.2f} | "
              f"{_per_round(solves[k], solves['new default'])} | {costs[k]:.10g} |")
    one = "one thread (env)"
    print("\nratios: median of the conditions' medians over `new default`'s, and the median "
          "(min-max) of the ratios within each round")
    print(f"\nacceptance, new default / one thread: solve "
          f"{ref_s / statistics.median(solves[one]):.2f} (per round "
          f"{_per_round(solves['new default'], solves[one])}), process "
          f"{ref_w / statistics.median(walls[one]):.2f} (per round "
          f"{_per_round(walls['new default'], walls[one])}); goal <= 1.2")


if __name__ == "__main__":
    main()
