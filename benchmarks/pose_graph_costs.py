"""Final costs on the shared pose graphs against GTSAM 4.3 LM's (the issue-9 acceptance table).

Run from the repository root (any environment with microlie's dependencies)::

    PYTHONPATH=src python benchmarks/pose_graph_costs.py \
        > benchmarks/results/pose_graph_costs-latest.md

Each graph is read with ``microlie.optim.io.g2o.read_g2o``, started as ``../shared/data/README.md``
states (the file's vertices; the odometry chain for files without vertices; chordal for MIT and
ais2klinik), solved by ``PoseGraph.to_factor_graph(X0)`` (prior on pose 0, left out of the
cost) and ``FactorGraph.optimize`` (LM, relative tolerance 1e-10, at most 200 iterations), and
its cost ``0.5 sum r^T Omega r`` over the file's edges is compared with GTSAM 4.3 LM's value
from the README (ais2klinik: "at or below 86.4067"). The same check is
``tests/test_optim_graphs.py``. BLAS is held to one thread (set before NumPy loads).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # a second BLAS thread on a busy machine: up to 40x slower

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from microlie.optim.init import initialize  # noqa: E402
from microlie.optim.io.g2o import read_g2o  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
# (file, start, GTSAM 4.3 LM error from ../shared/data/README.md)
CASES = [
    ("gtsam/pose2example.txt", "file", 0.5494864475),
    ("gtsam/pose3example.txt", "file", 18853.02073),
    ("tinyGrid3D.g2o", "file", 9.313909434),
    ("smallGrid3D.g2o", "file", 517.9253324),
    ("MIT.g2o", "chordal", 20.60347352),
    ("CSAIL.g2o", "odometry", 20.27544167),
    ("manhattan.g2o", "odometry", 1774.520535),
    ("kitti_00.g2o", "odometry", 49.16106912),
    ("input_M3500_g2o.g2o", "file", 68.95743912),
    ("parking-garage.g2o", "file", 0.6341923996),
    ("sphere2500.g2o", "file", 675.7009629),
    ("ais2klinik.g2o", "chordal", 86.4067),
]


def main() -> None:
    print("| graph | start | microlie final cost | GTSAM 4.3 LM | relative difference | "
          "iterations | solve s |")
    print("|---|---|---|---|---|---|---|")
    for name, start, ref in CASES:
        g = read_g2o(DATA / name)
        X0 = initialize(g, start)  # type: ignore[arg-type]
        fg, poses = g.to_factor_graph(X0)
        t = time.perf_counter()
        res = fg.optimize(rel_tol=1e-10, abs_tol=0.0, max_iter=200)
        t = time.perf_counter() - t
        c = g.cost(res.values[poses])
        print(f"| {name} | {start} | {c:.10g} | {ref:.10g} | {(c - ref) / ref:+.1e} | "
              f"{res.iterations} | {t:.2f} |", flush=True)
    load = os.getloadavg()
    print(f"\n`{' '.join(sys.argv)}`; load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} "
          "(times are whole solves with default linear solver, for orientation only; the "
          "timing comparison is benchmarks/pose_graph.py).")


if __name__ == "__main__":
    main()
