"""Symbolic analysis of the supernodal Cholesky at scale, and the fill of the orderings.

Two parts (one command each):

``scale``: synthetic 2-D pose graphs (a random walk on the integer grid, one SE(2) pose per
step; odometry between consecutive poses and a loop closure to the previous visit of the same
cell) of 1e3, 1e4, 1e5 (1e6) poses. For each size, in a fresh subprocess per code base, the
problem is built (``FactorGraph``, 3x3 blocks), then ``SupernodalSolver.analyse`` is
timed and the process's peak resident memory read before and after it; the new code also
runs three Levenberg-Marquardt iterations (supernodal solver, the analysis kept) and prints
the time of one. ``--old SRC`` runs the same with ``PYTHONPATH=SRC`` (the code before issue
20, e.g. ``/work/base/src``), interleaved with the new one::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/symbolic.py scale \\
        --sizes 1000 10000 100000 1000000 [--old /work/base/src --old-max 100000]

``flops``: the factorisation flops ``sum(counts**2)`` of the block factor under minimum degree
and under other orderings given as code bases (``--nd SRC``: the nested dissection of the code
before issue 20, ``ordering.nested_dissection`` with its default and its coarse leaf size), on
the shared pose graphs; the counts are this module's exact symbolic ones for every order::

    PYTHONPATH=src python benchmarks/symbolic.py flops --nd /work/base/src
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = {
    "sphere2500": "sphere2500.g2o", "parking-garage": "parking-garage.g2o",
    "M3500": "input_M3500_g2o.g2o", "ais2klinik": "ais2klinik.g2o", "kitti_00": "kitti_00.g2o",
    "sphere-a": "sphere_bignoise_vertex3.g2o", "smallGrid3D": "smallGrid3D.g2o",
    "CSAIL": "CSAIL.g2o", "MIT": "MIT.g2o", "manhattan": "manhattan.g2o",
    "tinyGrid3D": "tinyGrid3D.g2o",
}


def pose_graph_2d(n: int, seed: int = 0) -> sp.csr_matrix:
    """The block adjacency of a synthetic 2-D pose graph of ``n`` poses (see the module)."""
    rng = np.random.default_rng(seed)
    steps = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])[rng.integers(0, 4, n)]
    steps[0] = 0
    xy = np.cumsum(steps, axis=0)
    cell = xy[:, 0] * 4_000_037 + xy[:, 1]
    o = np.argsort(cell, kind="stable")
    same = cell[o][1:] == cell[o][:-1]
    a = np.r_[np.arange(n - 1), o[:-1][same]]
    b = np.r_[np.arange(1, n), o[1:][same]]
    keep = a != b
    A = sp.csr_matrix((np.ones(keep.sum()), (a[keep], b[keep])), shape=(n, n))
    A = A + A.T
    A.data[:] = 1.0
    return A


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _problem(n: int):
    """The problem of the synthetic graph: SE(2) poses on the walk (heading along the step),
    measurements from the truth with noise, the start the truth with noise."""
    from microlie import SE2
    from microlie.optim.io.pose_graph import PoseGraph

    A = sp.triu(pose_graph_2d(n), 1).tocoo()
    rng = np.random.default_rng(1)
    walk = np.random.default_rng(0).integers(0, 4, n)  # the walk of pose_graph_2d
    steps = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])[walk]
    steps[0] = 0
    xy = np.cumsum(steps, axis=0).astype(float)
    th = np.arctan2(steps[:, 1], steps[:, 0])
    truth = SE2.from_xy_theta(xy[:, 0], xy[:, 1], th)
    i, j = A.row.astype(np.int64), A.col.astype(np.int64)
    z = truth[i].inverse() @ truth[j]
    z = z @ SE2.exp(0.01 * rng.standard_normal((i.size, 3)))
    start = truth @ SE2.exp(0.05 * rng.standard_normal((n, 3)))
    pg = PoseGraph(SE2, ids=np.arange(n), poses=start, i=i, j=j, measurements=z,
                   information=np.broadcast_to(np.eye(3) * 1e4, (i.size, 3, 3)).copy())
    g, _ = pg.to_factor_graph(gauge="fix")
    return g.problem()


def _child(n: int, numeric: bool) -> None:
    """Run in the subprocess: print one JSON line."""
    from microlie.optim.linalg.linear import make_solver

    p = _problem(n)
    before = _rss_mb()
    s = make_solver("cholesky")
    t = time.perf_counter()
    s.analyse(p.indptr, p.indices, p.size, p.block_size)
    ana = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    out = {"n": n, "analyse": ana, "rss_before": before, "peak": peak, "ns": int(s.ns)}
    if numeric:  # LM iterations with the analysis done (kept with the problem)
        from microlie.optim.core.solvers import SolverOptions, solve

        p.__dict__.setdefault("_analysed", {})["cholesky"] = s
        res = solve(p, [v.initial for v in p.variables],
                    SolverOptions(solver="lm", linear_solver="cholesky", max_iter=3))
        assert p.analysed("cholesky") is s
        out["iteration"] = res.time_s / max(len(res.history), 1)
    print(json.dumps(out))


def _run(src: str, n: int, numeric: bool) -> dict:
    env = dict(os.environ, PYTHONPATH=src)
    r = subprocess.run([sys.executable, __file__, "_child", str(n), str(int(numeric))],
                       env=env, capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def scale(sizes: list[int], old: str | None, old_max: int) -> None:
    new = str(Path(__file__).resolve().parents[1] / "src")
    print("| poses | code | analysis s | peak RSS MB (before analysis) | supernodes | "
          "LM iteration s | analysis / iteration |")
    print("|---|---|---|---|---|---|---|")
    for n in sizes:
        runs = [("new", new, True)] + ([("old", old, False)] if old and n <= old_max else [])
        res = {}
        for name, src, numeric in runs:
            res[name] = r = _run(src, n, numeric)
            fs = r.get("iteration")
            fs_s = f"{fs:.3f}" if fs is not None else "-"
            ratio = f"{r['analyse'] / fs:.2f}" if fs else "-"
            print(f"| {n} | {name} | {r['analyse']:.3f} | {r['peak']:.0f} "
                  f"({r['rss_before']:.0f}) | {r['ns']} | {fs_s} | {ratio} |", flush=True)
        if "old" in res:
            print(f"|   | old/new | {res['old']['analyse'] / res['new']['analyse']:.1f}x | "
                  f"{res['old']['peak'] / res['new']['peak']:.2f}x | | | |", flush=True)


def flops(nd_src: str | None) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from microlie.optim.io.g2o import read_g2o
    from microlie.optim.linalg.ordering import minimum_degree, symbolic

    nd = None
    if nd_src:  # the old module, loaded under another name
        import importlib.util

        spec = importlib.util.spec_from_file_location(
            "old_ordering", Path(nd_src) / "microlie" / "optim" / "ordering.py")
        nd = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
        sys.modules["old_ordering"] = nd
        spec.loader.exec_module(nd)  # type: ignore[union-attr]
    print("| graph | blocks | mmd flops | nd (leaf 256) / mmd | nd (coarse) / mmd |")
    print("|---|---|---|---|---|")
    for name, fname in GRAPHS.items():
        path = DATA / fname
        if not path.exists():
            continue
        g = read_g2o(path)
        a, b, n = np.asarray(g.i), np.asarray(g.j), len(g.ids)
        keep = a != b
        A = sp.csr_matrix((np.ones(keep.sum()), (a[keep], b[keep])), shape=(n, n))
        A = A + A.T
        f_mmd = symbolic(A, minimum_degree(A)).flops
        cells = [f"{f_mmd:.3e}"]
        if nd is not None:
            for leaf in (256, max(256, -(-3 * n // 5))):
                cells.append(f"{symbolic(A, nd.nested_dissection(A, leaf)).flops / f_mmd:.3f}")
        print(f"| {name} | {n} | " + " | ".join(cells) + " |", flush=True)


def main() -> None:
    if sys.argv[1:2] == ["_child"]:
        _child(int(sys.argv[2]), bool(int(sys.argv[3])))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("scale")
    s.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    s.add_argument("--old", help="src folder of the code to compare with")
    s.add_argument("--old-max", type=int, default=100000, help="largest size for --old")
    f = sub.add_parser("flops")
    f.add_argument("--nd", help="src folder of a code base with ordering.nested_dissection")
    args = ap.parse_args()
    if args.cmd == "scale":
        scale(args.sizes, args.old, args.old_max)
    else:
        flops(args.nd)


if __name__ == "__main__":
    main()
