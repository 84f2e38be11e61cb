"""Sim(3) closed forms against SE(3): ``jr``, ``jr_inv``, ``exp``, ``log`` at N = 1e5 and on one
element, timed interleaved (one round times every operation once, in turn) and reported as the
median over the rounds with the interquartile spread, and the Sim3 / SE3 ratio of the medians.

Run from the repository root::

    PYTHONPATH=src python benchmarks/sim3.py [--n 100000] [--rounds 15]

``--generic`` also times ``Sim3._jr_series`` (the generic series the closed form replaced).
Both columns use the generic NumPy kernels (``MICROLIE_FAST=0``) unless ``--fast`` is given.
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import time

import numpy as np

# the generic NumPy kernels on both sides: SE3's compiled replacements (microlie._c, when
# installed) are a different comparison; pass --fast to keep them
if "--fast" not in sys.argv:
    os.environ["MICROLIE_FAST"] = "0"

from microlie import SE3, Sim3  # noqa: E402


def _per_call(fn, number: int) -> float:
    gc.disable()
    try:
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        return (time.perf_counter() - t0) / number
    finally:
        gc.enable()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--rounds", type=int, default=15)
    ap.add_argument("--generic", action="store_true")
    ap.add_argument("--fast", action="store_true", help="keep compiled kernels if installed")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    n = args.n
    z7, z6 = rng.standard_normal((n, 7)), rng.standard_normal((n, 6))
    S, T = Sim3.exp(z7), SE3.exp(z6)
    s7, s6 = z7[0], z6[0]
    S1, T1 = S[0], T[0]
    ops = {  # name: (Sim3 call, SE3 call, elements per call)
        "jr": (lambda: Sim3.jr(z7), lambda: SE3.jr(z6), n),
        "jr_inv": (lambda: Sim3.jr_inv(z7), lambda: SE3.jr_inv(z6), n),
        "exp": (lambda: Sim3.exp(z7), lambda: SE3.exp(z6), n),
        "log": (lambda: S.log(), lambda: T.log(), n),
        "jr (1 element)": (lambda: Sim3.jr(s7), lambda: SE3.jr(s6), 1),
        "jr_inv (1 element)": (lambda: Sim3.jr_inv(s7), lambda: SE3.jr_inv(s6), 1),
        "exp (1 element)": (lambda: Sim3.exp(s7), lambda: SE3.exp(s6), 1),
        "log (1 element)": (lambda: S1.log(), lambda: T1.log(), 1),
    }
    if args.generic:
        ops["jr, generic series (old)"] = (lambda: Sim3._jr_series(z7), lambda: SE3.jr(z6), n)
    calls = {}
    for name, (fs, ft, _) in ops.items():  # warm up; ~20 ms per timed call
        fs(), ft()
        t = _per_call(fs, 1)
        calls[name] = max(1, int(0.02 / max(t, 1e-9)))
    times = {name: ([], []) for name in ops}
    for _ in range(args.rounds):
        for name, (fs, ft, m) in ops.items():
            times[name][0].append(_per_call(fs, calls[name]) / m)
            times[name][1].append(_per_call(ft, calls[name]) / m)
    print(f"N = {n}, {args.rounds} interleaved rounds, load {os.getloadavg()[0]:.2f}; "
          "per element, median [25%, 75%]")
    print("| operation | Sim3 (us) | SE3 (us) | Sim3 / SE3 |")
    print("|---|---|---|---|")
    for name, (a, b) in times.items():
        qa, qb = np.percentile(a, [25, 50, 75]) * 1e6, np.percentile(b, [25, 50, 75]) * 1e6
        print(f"| {name} | {qa[1]:.3f} [{qa[0]:.3f}, {qa[2]:.3f}] | "
              f"{qb[1]:.3f} [{qb[0]:.3f}, {qb[2]:.3f}] | {qa[1] / qb[1]:.2f} |")


if __name__ == "__main__":
    main()
