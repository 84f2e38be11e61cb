"""Sparse Cholesky alone: microlie's supernodal factorisation (compiled loop and NumPy loop)
against PARDISO (pypardiso), qdldl and SuperLU, interleaved, on the Gauss-Newton matrices of the
shared pose graphs.

Run (benchmark environment, one command; build the compiled loop first with
``python setup.py build_ext --inplace`` at the root)::

    PYTHONPATH=src /work/bench-venv/bin/python benchmarks/cholesky.py \
        [--repeat 9] [--graphs sphere2500 ...] [--out benchmarks/results/cholesky-latest.md]

For each graph the matrix is ``H = J^T J`` of microlie's problem at the benchmark's starting
poses (those of ``benchmarks/pose_graph.py``), with pose 0 fixed. Each backend analyses the
pattern once (timed separately: "analysis"), then each round times one numeric factorisation
and one solve of every backend in turn (``--repeat`` rounds after one warm-up). The table gives
medians (ms), the ratio of medians to PARDISO's, the spread of the per-round ratios, and the
relative residual ``|H x - b| / |b|`` of each backend's solution. Every BLAS is held to one
thread (the script sets the variables itself).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from microlie.optim import available_solvers, from_pose_graph, make_solver  # noqa: E402
from microlie.optim.init import initialize  # noqa: E402
from microlie.optim.io.g2o import read_g2o  # noqa: E402
from microlie.optim.linalg.cholesky import SupernodalSolver  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = {  # name: (file, start), as in benchmarks/pose_graph.py
    "sphere2500": ("sphere2500.g2o", "file"),
    "parking-garage": ("parking-garage.g2o", "file"),
    "M3500": ("input_M3500_g2o.g2o", "file"),
    "ais2klinik": ("ais2klinik.g2o", "chordal"),
    "kitti_00": ("kitti_00.g2o", "odometry"),
}


def backends() -> dict[str, object]:
    """Name -> a factory of an un-analysed solver, for what is installed."""
    out: dict[str, object] = {}
    try:
        SupernodalSolver(compiled=True)
        out["supernodal-C"] = lambda: SupernodalSolver(compiled=True)
    except ImportError:
        pass
    out["supernodal-numpy"] = lambda: SupernodalSolver(compiled=False)
    for name in ("pardiso", "qdldl", "scipy"):
        if name in available_solvers():
            out[name] = lambda name=name: make_solver(name)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=9)
    ap.add_argument("--graphs", nargs="*", default=list(GRAPHS), choices=list(GRAPHS))
    ap.add_argument("--out", default=None, help="also write the markdown table to this file")
    args = ap.parse_args(argv)
    makers = backends()
    ref = "pardiso" if "pardiso" in makers else next(iter(makers))
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    lines = [f"cholesky.py, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, repeat "
             f"{args.repeat}, one BLAS thread; `uptime` at the start: {load}", "",
             f"Factorisation and solve ms (median; ratio to {ref}'s median; spread of the "
             "per-round ratios); analysis ms once; residual |Hx - b| / |b|", "",
             "| graph | n | backend | analysis | factorise (ratio, spread) | "
             "solve (ratio, spread) | residual |", "|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for gname in args.graphs:
        fname, start = GRAPHS[gname]
        pg = read_g2o(DATA / fname)
        fg, _ = from_pose_graph(pg, initialize(pg, start))
        prob = fg.problem()
        data = prob.linearize([v.initial for v in prob.variables]).data
        H = prob.matrix(data)
        b = np.random.default_rng(0).standard_normal(prob.size)
        solvers, ana = {}, {}
        for name, make in makers.items():
            s = make()  # type: ignore[operator]
            t0 = time.perf_counter()
            s.analyse(prob.indptr, prob.indices, prob.size, prob.block_size)
            ana[name] = time.perf_counter() - t0
            solvers[name] = s
        tf: dict[str, list[float]] = {k: [] for k in solvers}
        ts: dict[str, list[float]] = {k: [] for k in solvers}
        res = {}
        for rnd in range(args.repeat + 1):
            for name, s in solvers.items():
                t0 = time.perf_counter()
                s.factorize(data)
                t1 = time.perf_counter()
                x = s.solve(b)
                t2 = time.perf_counter()
                if rnd:
                    tf[name].append(t1 - t0)
                    ts[name].append(t2 - t1)
                res[name] = float(np.linalg.norm(H @ x - b) / np.linalg.norm(b))
        for name in solvers:
            cells = []
            for t in (tf, ts):
                med = statistics.median(t[name])
                rat = [a / r for a, r in zip(t[name], t[ref], strict=True)]
                cells.append(f"{med * 1e3:.2f} ({med / statistics.median(t[ref]):.2f}x, "
                             f"{min(rat):.2f}-{max(rat):.2f})")
            row = (f"| {gname} | {prob.size} | {name} | {ana[name] * 1e3:.1f} | {cells[0]} | "
                   f"{cells[1]} | {res[name]:.1e} |")
            print(row, flush=True)
            lines.append(row)
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    lines += ["", f"`uptime` at the end: {load}"]
    print(lines[-1])
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
