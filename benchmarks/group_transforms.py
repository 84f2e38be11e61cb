"""Group operations under torch.compile, and the per-call cost of the value checks.

Two measurements (issue 24, the group-level blockers):

* ``--compile``: the first call of ``torch.compile(f, fullgraph=True)`` (inductor, a fresh
  empty cache directory, a fresh process) for ``f = lambda x, p: SE3.exp(x).act(p)`` on a batch
  of 1000 float64 tensors, and its graph count and graph breaks (``torch._dynamo.explain``).
  Goal: no graph break, under 30 s.
* ``--eager``: the per-call time of group operations on NumPy (single elements and a batch)
  and torch (a batch and one element), for each source tree given with ``--src`` (e.g. this
  checkout and an older one), in child processes run in interleaved rounds; reports the median
  per call and the ratio to the first tree. Checks must not make NumPy slower.

Usage::

    PYTHONPATH=src python benchmarks/group_transforms.py --compile
    python benchmarks/group_transforms.py --eager --src src --src /path/to/old/src --rounds 5
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

COMPILE = r"""
import json, sys, time
import torch
import microlie
from microlie import SE3
torch.manual_seed(0)
x = torch.randn(1000, 6, dtype=torch.float64) * 0.5
p = torch.randn(1000, 3, dtype=torch.float64)
f = lambda x, p: SE3.exp(x).act(p)
t0 = time.perf_counter()
g = torch.compile(f, fullgraph=True)
out = g(x, p)
first = time.perf_counter() - t0
err = float((out - f(x, p)).abs().max())
import torch._dynamo as dynamo
dynamo.reset()
ex = dynamo.explain(f)(x, p)
t0 = time.perf_counter()
for _ in range(100):
    g(x, p)
compiled = (time.perf_counter() - t0) / 100
t0 = time.perf_counter()
for _ in range(100):
    f(x, p)
eager = (time.perf_counter() - t0) / 100
print(json.dumps({"first_call_s": first, "graphs": ex.graph_count,
                  "graph_breaks": ex.graph_break_count, "max_abs_diff": err,
                  "compiled_call_us": compiled * 1e6, "eager_call_us": eager * 1e6}))
"""

EAGER = r"""
import json, sys, timeit
import numpy as np
import torch
from microlie import SE3
rng = np.random.default_rng(0)
t = rng.standard_normal(6) * 0.5
X, Y, p = SE3.exp(t), SE3.exp(-t), rng.standard_normal(3)
tb = rng.standard_normal((100, 6)) * 0.5
Xb, Yb, pb = SE3.exp(tb), SE3.exp(-tb), rng.standard_normal((100, 3))
T = lambda a: torch.tensor(a, dtype=torch.float64)
tt, pt = T(tb), T(pb)
Xt, Yt = SE3.exp(tt), SE3.exp(-tt)
t1, p1 = T(t), T(p)
X1 = SE3.exp(t1)
qt = Xt.params
cases = {
    "numpy 1 exp": lambda: SE3.exp(t), "numpy 1 act": lambda: X.act(p),
    "numpy 1 compose": lambda: X @ Y, "numpy 1 log": lambda: X.log(),
    "numpy 1 plus": lambda: X.plus(t), "numpy 1 from_params": lambda: SE3.from_params(X.params),
    "numpy 100 exp": lambda: SE3.exp(tb), "numpy 100 act": lambda: Xb.act(pb),
    "numpy 100 from_params": lambda: SE3.from_params(Xb.params),
    "torch 100 exp": lambda: SE3.exp(tt), "torch 100 act": lambda: Xt.act(pt),
    "torch 100 compose": lambda: Xt @ Yt, "torch 100 log": lambda: Xt.log(),
    "torch 100 plus": lambda: Xt.plus(tt), "torch 100 minus": lambda: Xt.minus(Yt),
    "torch 100 from_params": lambda: SE3.from_params(qt),
    "torch 1 exp": lambda: SE3.exp(t1), "torch 1 act": lambda: X1.act(p1),
}
out = {}
for name, f in cases.items():
    n = 2000 if name.startswith("numpy 1 ") else 300
    out[name] = min(timeit.repeat(f, number=n, repeat=3)) / n * 1e6
print(json.dumps(out))
"""


def _child(code: str, src: str | None, python: str, env_extra: dict | None = None) -> dict:
    env = dict(os.environ, **(env_extra or {}))
    if src is not None:
        env["PYTHONPATH"] = os.path.abspath(src)
    out = subprocess.run([python, "-W", "ignore", "-c", code], env=env, capture_output=True,
                         text=True, check=True, timeout=1800)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--compile", action="store_true", help="first call of torch.compile")
    ap.add_argument("--eager", action="store_true", help="per-call times, per --src tree")
    ap.add_argument("--src", action="append", help="a source tree to import (repeatable)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds (--eager)")
    ap.add_argument("--python", default=sys.executable, help="the interpreter of the children")
    a = ap.parse_args()
    print(f"load (1, 5, 15 min): {os.getloadavg()}")
    if a.compile:
        with tempfile.TemporaryDirectory() as cache:
            r = _child(COMPILE, (a.src or [None])[0], a.python,
                       {"TORCHINDUCTOR_CACHE_DIR": cache})
        print("torch.compile(fullgraph=True) of SE3.exp(x).act(p), batch 1000, float64, "
              "fresh cache:")
        for k, v in r.items():
            print(f"  {k}: {v:.4g}" if isinstance(v, float) else f"  {k}: {v}")
    if a.eager:
        srcs = a.src or ["src"]
        runs: dict[str, list[dict]] = {s: [] for s in srcs}
        for _ in range(a.rounds):
            for s in srcs:
                runs[s].append(_child(EAGER, s, a.python))
        names = list(runs[srcs[0]][0])
        head = " | ".join(f"{s} (us)" for s in srcs)
        ratios = " | ".join(f"ratio {s}" for s in srcs[1:])
        print(f"| case | {head} | {ratios} |")
        print("|---" * (1 + 2 * len(srcs) - 1) + "|")
        for n in names:
            med = [statistics.median(r[n] for r in runs[s]) for s in srcs]
            rat = [statistics.median(runs[srcs[0]][i][n] / runs[s][i][n]
                                     for i in range(a.rounds)) for s in srcs[1:]]
            print(f"| {n} | " + " | ".join(f"{m:.3f}" for m in med) + " | "
                  + " | ".join(f"{x:.2f}" for x in rat) + " |")
        print(f"ratio = time of {srcs[0]} / time of the other tree (median of the per-round "
              "ratios; < 1: the first tree is faster)")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"total {time.perf_counter() - t0:.0f} s")
