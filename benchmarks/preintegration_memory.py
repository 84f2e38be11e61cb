"""Peak memory and time of one ``Preintegration.integrate`` call on N samples (issue 19, item 15).

Each measurement runs in a fresh subprocess: the samples are made first, then one
``integrate(accel, gyro, dt)`` call is measured by ``tracemalloc`` (the peak of the memory
allocated during the call: NumPy reports its arrays to it) and by the process's peak resident
set (``ru_maxrss``, which includes the interpreter, NumPy and the 48 MB of input samples at
N = 1e6). With ``--ref COMMIT`` the same measurement runs on that commit's ``src/`` (extracted
with ``git archive`` into a temporary folder), alternating with this tree's, and the table gives
the ratios. Run from the repository root:

    PYTHONPATH=src /work/main/.venv/bin/python benchmarks/preintegration_memory.py \\
        --n 1000000 --ref ec8ad1a

The acceptance figure is "peak under 200 MB at N = 1e6 in one call" (both measures).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(n: int) -> None:
    import resource
    import time
    import tracemalloc

    import numpy as np

    from microlie.imu import Preintegration

    rng = np.random.default_rng(0)
    a = rng.standard_normal((n, 3)) + [0.0, 0.0, 9.81]
    w = 0.5 * rng.standard_normal((n, 3))
    pim = Preintegration(gyro_noise=1.7e-4, accel_noise=2e-3, bias_gyro=[0.01, -0.02, 0.015],
                         bias_accel=[0.1, -0.05, 0.2])
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    tracemalloc.start()
    t = time.perf_counter()
    pim.integrate(a, w, 0.005)
    t = time.perf_counter() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    print(json.dumps({"seconds": t, "traced_mb": peak / 1e6, "rss_mb": rss * 1024 / 1e6,
                      "rss_before_mb": rss0 * 1024 / 1e6,
                      "dp": pim.delta_position.tolist()}))


def measure(src: Path, n: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(src))
    out = subprocess.run([sys.executable, __file__, "--child", str(n)], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=float, default=1e6, help="samples in the call (default 1e6)")
    ap.add_argument("--ref", help="a commit to compare with (its src/, via git archive)")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--child", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        child(args.child)
        return
    n = int(args.n)
    trees = {"this tree": ROOT / "src"}
    with tempfile.TemporaryDirectory() as tmp:
        if args.ref:
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.ref, "src"],
                                     check=True, capture_output=True).stdout
            subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
            trees[args.ref] = Path(tmp) / "src"
        runs: dict[str, list[dict]] = {k: [] for k in trees}
        for _ in range(args.repeat):
            for name, src in trees.items():  # alternating
                runs[name].append(measure(src, n))
    print(f"Preintegration.integrate, one call on N = {n:,} samples "
          f"(median of {args.repeat}; load {os.getloadavg()[0]:.2f})\n")
    print("| tree | time (s) | tracemalloc peak (MB) | peak RSS (MB) | RSS before the call (MB) |")
    print("|---|---|---|---|---|")
    med = {}
    for name, rs in runs.items():
        m = {k: sorted(r[k] for r in rs)[len(rs) // 2]
             for k in ("seconds", "traced_mb", "rss_mb", "rss_before_mb")}
        med[name] = m
        print(f"| {name} | {m['seconds']:.2f} | {m['traced_mb']:.1f} | {m['rss_mb']:.0f} | "
              f"{m['rss_before_mb']:.0f} |")
    if args.ref:
        a, b = med["this tree"], med[args.ref]
        dp = [runs[k][0]["dp"] for k in trees]
        diff = max(abs(x - y) for x, y in zip(*dp, strict=True)) / max(map(abs, dp[0]))
        print(f"\nratios ({args.ref} / this tree): time {b['seconds'] / a['seconds']:.2f}, "
              f"tracemalloc peak {b['traced_mb'] / a['traced_mb']:.1f}, "
              f"peak RSS {b['rss_mb'] / a['rss_mb']:.1f}; delta_position differs by "
              f"{diff:.2g} relative")


if __name__ == "__main__":
    main()
