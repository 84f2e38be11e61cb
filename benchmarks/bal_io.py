"""Reading BAL files: ``read_bal`` against a plain NumPy parse of the same file, and against
the ``read_bal`` of another checkout (``--ref``, e.g. today's main), time and peak memory.

Run (from the repository root; the shared data lives in ``../shared/data``)::

    PYTHONPATH=src python benchmarks/bal_io.py --ref /work/base/src [--repeat 5]
        [--synthetic 800000]

The plain NumPy parse is ``np.fromstring(Path(f).read_bytes(), sep=" ")``: the file's bytes
and every number as float64, no checks, the least a reader has to do. Each measurement runs in
a fresh interpreter (so no reader profits from another's caches or heap), the three readers
alternate round by round, and the table gives medians with the per-round ratios' spread.
Peak memory is ``tracemalloc``'s (NumPy reports its allocations to it), that is what the
reading itself allocates, without the interpreter. ``--synthetic N`` also writes a BAL file of
N observations (BAL's own ``%e`` layout, in a temporary folder) to measure a large problem.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / ".." / "shared" / "data" / "bal"

CHILD = r"""
import json, sys, time, tracemalloc
from pathlib import Path
which, path = sys.argv[1], sys.argv[2]
if which == "numpy":
    import numpy as np
    def run():
        return np.fromstring(Path(path).read_bytes(), sep=" ")
else:
    from microlie.optim.io.bal import read_bal
    def run():
        return read_bal(path)
tracemalloc.start()
t = time.perf_counter()
out = run()
dt = time.perf_counter() - t
peak = tracemalloc.get_traced_memory()[1]
tracemalloc.stop()
n = out.n_observations if hasattr(out, "n_observations") else 0
print(json.dumps({"seconds": dt, "peak": peak, "n": n}))
"""


def _measure(which: str, path: Path, src: str) -> dict[str, float]:
    env = dict(os.environ, PYTHONPATH=src, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD, which, str(path)], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _synthetic(n_obs: int, folder: Path) -> Path:
    """A BAL file shaped like the Ladybug problems (about 5 observations per point)."""
    import numpy as np

    rng = np.random.default_rng(0)
    nc, npt = max(2, n_obs // 650), max(2, n_obs // 5)
    ci, pi = rng.integers(0, nc, n_obs), rng.integers(0, npt, n_obs)
    uv = rng.normal(scale=300.0, size=(n_obs, 2))
    path = folder / f"synthetic-{nc}-{npt}-{n_obs}.txt"
    with open(path, "w") as f:
        f.write(f"{nc} {npt} {n_obs}\n")
        for c, p, (u, v) in zip(ci.tolist(), pi.tolist(), uv.tolist(), strict=True):
            f.write(f"{c} {p}     {u:e} {v:e}\n")
        vals = np.concatenate([rng.normal(size=9 * nc), rng.normal(size=3 * npt)])
        f.write("\n".join(f"{x:.16e}" for x in vals.tolist()) + "\n")
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ref", default=None, help="src folder of the read_bal to compare with")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--synthetic", type=int, default=0, help="also a file of N observations")
    args = ap.parse_args()
    src = str(ROOT / "src")
    readers = [("read_bal", "microlie", src), ("numpy", "numpy", src)]
    if args.ref:
        readers.append(("read_bal --ref", "microlie", args.ref))
    with tempfile.TemporaryDirectory() as tmp:
        files = sorted(DATA.glob("*.txt"), key=lambda p: p.stat().st_size)[-1:]
        if args.synthetic:
            files.append(_synthetic(args.synthetic, Path(tmp)))
        print("| file | MB | observations | reader | median s | peak MB | bytes/obs | "
              "time / NumPy (spread) | peak / NumPy |")
        print("|---|---|---|---|---|---|---|---|---|")
        for path in files:
            runs: dict[str, list[dict[str, float]]] = {name: [] for name, _, _ in readers}
            for _ in range(args.repeat):
                for name, which, where in readers:
                    runs[name].append(_measure(which, path, where))
            n = runs["read_bal"][0]["n"]
            base = runs["numpy"]
            for name, _, _ in readers:
                r = runs[name]
                ratios = [a["seconds"] / b["seconds"] for a, b in zip(r, base, strict=True)]
                t = statistics.median(x["seconds"] for x in r)
                peak = max(x["peak"] for x in r)
                print(f"| {path.name} | {path.stat().st_size / 1e6:.1f} | {int(n)} | {name} | "
                      f"{t:.3f} | {peak / 1e6:.1f} | {peak / n:.0f} | "
                      f"{statistics.median(ratios):.2f} ({min(ratios):.2f}-{max(ratios):.2f})"
                      f" | {peak / max(x['peak'] for x in base):.2f} |", flush=True)
    load = os.getloadavg()
    print(f"\nload average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}, {args.repeat} rounds")


if __name__ == "__main__":
    main()
