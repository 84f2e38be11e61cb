"""Jacobian outputs above the block cache: SE3 ``log(jac=True)`` per element against N, before and
after (issue 19, item 17).

Run from the repository root (with the compiled extra of each side importable)::

    python benchmarks/output_cache.py [--rounds 7] [--sizes 1e4 1e5 1e6 2e6] \\
        [--before /work/base/src] [--after src[:DIR_WITH_ITS_BUILT_microlie]] [--generic]

Each side is a ``PYTHONPATH``: the compiled kernels are a C extension, so the two sides cannot
be imported into one process (``groups.py --before-after`` imports the older Python package next
to the new one, with its own built ``microlie._c``) and run in subprocesses instead: in each
round, for each N, one process of each side, in turn (interleaved, so that a burst of load hits
both). A process makes N random SE3 elements, calls ``X.log(jac=True)`` once untimed (the first call
allocates the output), then ``--calls`` times, freeing each result before the next call (a loop
over batches); it reports the median per call of wall time, CPU time (``process_time``) and
minor page faults (``ru_minflt``). The table gives, per N and side, the median over the rounds
of those per-process medians in ns per element (wall: with the IQR and min-max of the rounds),
the faults per call, the after/before ratio and, per side, the ratio of the per-element time at
each N to that at 1e5. ``--generic`` sets ``MICROLIE_FAST=0`` on both sides (the NumPy kernels
and their own pool); ``OPENBLAS_NUM_THREADS=1``. The load average is printed before and after.
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

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, resource, sys, time
import numpy as np
import microlie as ml
from microlie._fast import installed
n, calls = int(sys.argv[1]), int(sys.argv[2])
X = ml.SE3(ml.SE3.random((n,), rng=np.random.default_rng(0)).params.copy())
r = X.log(jac=True)
del r
wall, cpu, faults = [], [], []
for _ in range(calls):
    f = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    c, t = time.process_time(), time.perf_counter()
    r = X.log(jac=True)
    wall.append(time.perf_counter() - t)
    cpu.append(time.process_time() - c)
    faults.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f)
    del r
med = lambda xs: sorted(xs)[len(xs) // 2]
print(json.dumps({"wall": med(wall) / n * 1e9, "cpu": med(cpu) / n * 1e9,
                  "faults": med(faults), "compiled": "SE3.log_jac" in installed(),
                  "microlie": ml.__file__}))
"""


def _run(pythonpath: str, n: int, calls: int, generic: bool) -> dict:
    env = dict(os.environ, PYTHONPATH=pythonpath, OPENBLAS_NUM_THREADS="1")
    if generic:
        env["MICROLIE_FAST"] = "0"
    p = subprocess.run([sys.executable, "-c", CHILD, str(n), str(calls)], env=env,
                       capture_output=True, text=True, check=False)
    if p.returncode != 0:
        raise RuntimeError(f"PYTHONPATH={pythonpath} N={n}: {p.stderr}")
    return json.loads(p.stdout)


def _q(xs: list[float]) -> tuple[float, float, float]:
    q = statistics.quantiles(xs, n=4) if len(xs) > 1 else [xs[0]] * 3
    return q[0], statistics.median(xs), q[2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", nargs="+", type=float, default=[1e4, 1e5, 1e6, 2e6])
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--calls", type=int, default=5, help="timed calls per process")
    ap.add_argument("--before", default="/work/base/src", help="PYTHONPATH of the old side")
    ap.add_argument("--after", default=str(ROOT / "src"), help="PYTHONPATH of the new side")
    ap.add_argument("--generic", action="store_true", help="MICROLIE_FAST=0 on both sides")
    a = ap.parse_args()
    sizes = [int(s) for s in a.sizes]
    sides = {"before": a.before, "after": a.after}
    print(f"# SE3 log(jac=True) per element against N: before ({a.before}) vs after "
          f"({a.after}){', generic kernels (MICROLIE_FAST=0)' if a.generic else ''}")
    print(f"\nCommand: `python benchmarks/output_cache.py --rounds {a.rounds} --calls {a.calls} "
          f"--sizes {' '.join(f'{s:g}' for s in a.sizes)} --before {a.before} --after {a.after}"
          f"{' --generic' if a.generic else ''}`\n")
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; cores {os.cpu_count()}; "
          f"cache limits: MICROLIE_CACHE_MB={os.environ.get('MICROLIE_CACHE_MB', '256')}, "
          f"MICROLIE_FAST_CACHE_MB={os.environ.get('MICROLIE_FAST_CACHE_MB', '256')}")
    res: dict[tuple[str, int], list[dict]] = {(s, n): [] for s in sides for n in sizes}
    for r in range(a.rounds):
        for n in sizes:
            for side, pp in sides.items():
                res[side, n].append(_run(pp, n, a.calls, a.generic))
        print(f"round {r + 1}/{a.rounds} done", file=sys.stderr)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for side in sides:
        one = res[side, sizes[0]][0]
        print(f"- {side}: {one['microlie']}, compiled SE3.log_jac: {one['compiled']}")
    print("\n| N | side | wall ns/elem, median (IQR; min-max) | CPU ns/elem | faults/call "
          "| wall after/before | wall vs 1e5 | CPU vs 1e5 |")
    print("| ---: | --- | --- | ---: | ---: | ---: | ---: | ---: |")
    med = {k: (statistics.median([x["wall"] for x in v]), statistics.median([x["cpu"] for x in v]))
           for k, v in res.items()}
    for n in sizes:
        for side in sides:
            w = [x["wall"] for x in res[side, n]]
            q1, m, q3 = _q(w)
            ref = med.get((side, 100_000))
            vs = (f"{m / ref[0]:.2f} | {med[side, n][1] / ref[1]:.2f}" if ref else "- | -")
            ratio = f"{m / med['before', n][0]:.2f}" if side == "after" else ""
            faults = statistics.median([x["faults"] for x in res[side, n]])
            print(f"| {n:.0e} | {side} | {m:.1f} ({q1:.1f}-{q3:.1f}; {min(w):.1f}-{max(w):.1f})"
                  f" | {med[side, n][1]:.1f} | {faults:.0f} | {ratio} | {vs} |")


if __name__ == "__main__":
    main()
