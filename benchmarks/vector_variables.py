"""Issue 20: vector variables became ``R(d)`` variables (no ``group is None`` branch); their
retraction must stay a plain addition and a solve with them no slower. Times, on a problem of
20,000 ``R(3)`` variables (an analytic ``CustomFactor`` ``x^3 + x - z`` per variable, a chain
of vector ``BetweenFactor`` s, one prior): ``Problem.retract`` of the whole batch, one
linearisation, and an 8-iteration LM solve (scipy's solver), with two checkouts of ``src`` in
alternating subprocesses (interleaved: a burst of load hits both alike), and prints the ratio
of the medians, after / before.

Run (one command)::

    git archive 1bd9510 src | tar -x -C /tmp/before    # the code before the change
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/vector_variables.py \\
        --before /tmp/before/src --after src --rounds 5
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time


def _build(n: int = 20000):
    import numpy as np

    from microlie.optim import BetweenFactor, CustomFactor, FactorGraph, Isotropic, PriorFactor

    rng = np.random.default_rng(0)
    truth = rng.standard_normal((n, 3))
    g = FactorGraph()
    x = g.add_variables(truth + 0.3 * rng.standard_normal((n, 3)))

    def fn(v, z):
        J = np.zeros((v.shape[0], 3, 3))
        J[:, [0, 1, 2], [0, 1, 2]] = 3 * v ** 2 + 1
        return v ** 3 + v - z, [J]

    g.add(CustomFactor(fn, [(x, np.arange(n))], 3, Isotropic(3, 0.1),
                       data=[truth ** 3 + truth], jac="analytic"))
    g.add(BetweenFactor(x, np.arange(n - 1), np.arange(1, n), truth[1:] - truth[:-1],
                        Isotropic(3, 1.0)))
    g.add(PriorFactor(x, 0, truth[0], Isotropic(3, 0.01)))
    return g


def worker(calls: int) -> dict:
    """Median seconds per call of each measurement (run inside one checkout)."""
    import numpy as np

    g = _build()
    p = g.problem()
    states = [v.initial for v in p.variables]
    dx = np.random.default_rng(1).standard_normal(p.size) * 1e-3
    out: dict[str, list[float]] = {"retract": [], "linearize": [], "solve (8 LM iterations)": []}
    for _ in range(calls):
        t = time.perf_counter()
        p.retract(states, dx)
        out["retract"].append(time.perf_counter() - t)
        t = time.perf_counter()
        p.linearize(states)
        out["linearize"].append(time.perf_counter() - t)
    for _ in range(max(1, calls // 20)):
        h = _build()
        t = time.perf_counter()
        h.optimize(max_iter=8, linear_solver="scipy")
        out["solve (8 LM iterations)"].append(time.perf_counter() - t)
    return {k: statistics.median(v) for k, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True, help="src folder of the code before")
    ap.add_argument("--after", required=True, help="src folder of the code after")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--calls", type=int, default=40)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        print(json.dumps(worker(a.calls)))
        return
    res: dict[str, list[dict]] = {"before": [], "after": []}
    for _ in range(a.rounds):
        for side in ("before", "after"):
            env = dict(os.environ, PYTHONPATH=getattr(a, side))
            r = subprocess.run([sys.executable, __file__, "--worker", "--before", a.before,
                                "--after", a.after, "--calls", str(a.calls)], env=env,
                               capture_output=True, text=True, check=True)
            res[side].append(json.loads(r.stdout))
    print(f"{'measurement':28s} {'before':>12s} {'after':>12s} {'after/before':>13s}")
    for k in res["before"][0]:
        b = statistics.median(r[k] for r in res["before"])
        f = statistics.median(r[k] for r in res["after"])
        unit, s = ("us", 1e6) if b < 1e-3 else ("ms", 1e3)
        print(f"{k:28s} {b * s:9.1f} {unit} {f * s:9.1f} {unit} {f / b:13.2f}")


if __name__ == "__main__":
    main()
