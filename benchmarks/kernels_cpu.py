"""CPU-time cross-check of the kernel layer's before/after table (for loaded machines).

    MICROLIE_FAST=0 OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/kernels_cpu.py \\
        --ref 93dbac9 --ops exp log compose minus minus_jac --rounds 11

On a machine shared with other processes the wall-clock medians of ``groups.py
--before-after`` include the time spent waiting for a CPU. Here the older commit (extracted with
``git archive``, as ``groups.py`` does) and this checkout alternate call by call in each round
and are timed with the process clock. Prints ns per element at N = 1e5 and the speed-up, and
``minus(jac=True) / minus()`` of this checkout.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from groups import BA_GROUPS, _ba_cases, _import_ref  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--ref", default="93dbac9", help="the older commit (default 93dbac9)")
    p.add_argument("--ops", nargs="+", default=["exp", "log", "compose", "inverse", "act",
                                                  "between", "minus", "plus", "minus_jac"])
    p.add_argument("--groups", nargs="+", default=list(BA_GROUPS))
    p.add_argument("--n", type=int, default=100_000)
    p.add_argument("--rounds", type=int, default=11)
    args = p.parse_args()
    import microlie as new

    old = _import_ref(args.ref)
    n, rng = args.n, np.random.default_rng(0)
    print(f"load {os.getloadavg()[0]:.2f}; ns per element (CPU time), median of {args.rounds}")
    for g in args.groups:
        G = getattr(new, g)
        tau = rng.standard_normal((n, G.dof)) * 0.5
        ps, qs = (G.random((n,), rng=rng).params.copy() for _ in range(2))
        v = rng.standard_normal((n, 3))
        before, after = _ba_cases(old, g, tau, ps, qs, v), _ba_cases(new, g, tau, ps, qs, v)
        res = {}
        for op in args.ops:
            tb, ta = [], []
            for _ in range(args.rounds):
                for f, acc in ((before[op], tb), (after[op], ta)):
                    t = time.process_time()
                    f()
                    acc.append(time.process_time() - t)
            res[op] = (float(np.median(tb)) * 1e9 / n, float(np.median(ta)) * 1e9 / n)
        print(g, "  ".join(f"{op} {b:.0f} -> {a:.0f} ({b / a:.2f}x)" for op, (b, a) in res.items()))
        if "minus" in res and "minus_jac" in res:
            ratio = res["minus_jac"][1] / res["minus"][1]
            print(f"  {g} minus(jac=True) / minus() after: {ratio:.2f}")


if __name__ == "__main__":
    main()
