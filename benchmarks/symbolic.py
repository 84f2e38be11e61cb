"""Symbolic analysis of the supernodal Cholesky at scale, and the fill of the orderings.

Two parts (one command each):

``scale``: synthetic pose graphs (a random walk on the integer grid, 2-D with SE(2) poses or
3-D with SE(3) poses (``--dim 3``); odometry between consecutive poses and a loop closure to
the previous visit of the same cell) of 1e3 to 1e6 poses. For each size, in a fresh
subprocess per code base, the setup a user pays once is timed: ``g.problem()`` (block
pattern, compiled edge plans or the NumPy path's scatter map) and the supernodal solver's
analysis (minimum-degree order, elimination tree, column counts, supernodes, structures,
assembly and update maps, and without the compiled extra the NumPy loop's plan), then three
Levenberg-Marquardt iterations (the analysis kept) time one iteration; peak resident memory
after the setup and after the solve. ``--old SRC`` runs the same with ``PYTHONPATH=SRC``
(e.g. the code at 1bd9510 unpacked with ``git archive``), interleaved with this one,
``--repeat R`` times below 1e6 poses, each figure the smallest; ``--fast 0`` runs
without the compiled extra::

    OPENBLAS_NUM_THREADS=1 python benchmarks/symbolic.py scale \\
        --sizes 1000 10000 100000 1000000 [--dim 3] [--fast 0] [--old SRC --old-max N]

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


def _walk(n: int, dim: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random walk of ``n`` steps on the integer grid of dimension ``dim`` (the first step
    0): its unit steps, positions, and the edges (odometry, then a closure from each revisit
    of a cell to the previous visit)."""
    rng = np.random.default_rng(seed)
    unit = np.vstack([np.eye(dim, dtype=np.int64), -np.eye(dim, dtype=np.int64)])
    steps = unit[rng.integers(0, 2 * dim, n)]
    steps[0] = 0
    xyz = np.cumsum(steps, axis=0)
    cell = xyz[:, 0].copy()
    for k in range(1, dim):
        cell = cell * 4_000_037 + xyz[:, k]
    o = np.argsort(cell, kind="stable")
    same = cell[o][1:] == cell[o][:-1]
    a = np.r_[np.arange(n - 1), o[:-1][same]]
    b = np.r_[np.arange(1, n), o[1:][same]]
    keep = a != b
    return steps, xyz, np.stack([a[keep], b[keep]])


def pose_graph_2d(n: int, seed: int = 0) -> sp.csr_matrix:
    """The block adjacency of a synthetic 2-D pose graph of ``n`` poses (see the module)."""
    _, _, (a, b) = _walk(n, 2, seed)
    A = sp.csr_matrix((np.ones(a.size), (a, b)), shape=(n, n))
    A = A + A.T
    A.data[:] = 1.0
    return A


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _graph(n: int, dim: int):
    """The factor graph of the synthetic walk: SE(2) (``dim`` 2) or SE(3) poses on it
    (heading along the step), measurements from the truth with noise, the start the truth
    with noise, the first pose fixed."""
    from microlie import SE2, SE3
    from microlie.optim.io.pose_graph import PoseGraph

    steps, xyz, (a, b) = _walk(n, dim)
    A = sp.triu(sp.csr_matrix((np.ones(a.size), (a, b)), shape=(n, n))
                + sp.csr_matrix((np.ones(a.size), (b, a)), shape=(n, n)), 1).tocoo()
    rng = np.random.default_rng(1)
    i, j = A.row.astype(np.int64), A.col.astype(np.int64)
    if dim == 2:
        G, d = SE2, 3
        th = np.arctan2(steps[:, 1], steps[:, 0])
        truth = SE2.from_xy_theta(xyz[:, 0].astype(float), xyz[:, 1].astype(float), th)
    else:
        G, d = SE3, 6
        tau = np.zeros((n, 6))
        tau[:, 3:] = 0.3 * steps  # a rotation along the step
        truth = SE3.exp(tau)
        truth = SE3.from_rotation_translation(truth.rotation(), xyz.astype(float))
    z = truth[i].inverse() @ truth[j]
    z = z @ G.exp(0.01 * rng.standard_normal((i.size, d)))
    start = truth @ G.exp(0.05 * rng.standard_normal((n, d)))
    pg = PoseGraph(G, ids=np.arange(n), poses=start, i=i, j=j, measurements=z,
                   information=np.broadcast_to(np.eye(d) * 1e4, (i.size, d, d)).copy())
    g, _ = pg.to_factor_graph(gauge="fix")
    return g


def _problem(n: int, dim: int = 2):
    """The problem of the synthetic graph (see :func:`_graph`)."""
    return _graph(n, dim).problem()


def _child(n: int, dim: int) -> None:
    """Run in the subprocess: print one JSON line. The setup (``g.problem()``: pattern,
    compiled plans or scatter map; then the supernodal solver's analysis: ordering, symbolic
    factor, its maps) is timed and the process's peak resident memory read before and after
    it, then three Levenberg-Marquardt iterations (the analysis kept) time one iteration. A
    10-pose problem is analysed first: the import of the modules is not counted (it is
    the end-to-end benchmarks' subject)."""
    from microlie.optim.linalg.linear import make_solver

    try:  # the supernodal Cholesky's name ("supernodal" before issue 20)
        ls = make_solver("cholesky").name
    except ValueError:
        ls = "supernodal"
    _graph(10, dim).problem().analysed(ls)  # the modules imported, not timed
    g = _graph(n, dim)
    before = _rss_mb()
    t = time.perf_counter()
    p = g.problem()
    t_problem = time.perf_counter() - t
    t = time.perf_counter()
    s = p.analysed(ls)
    t_analyse = time.perf_counter() - t
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    res = g.optimize(linear_solver=ls, max_iter=3)  # the cached problem and analysis
    assert g.problem() is p and p.analysed(ls) is s
    print(json.dumps({"n": n, "problem": t_problem, "analyse": t_analyse, "rss_before": before,
                      "peak": peak, "ns": int(s.ns),
                      "peak_solve": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                      "iteration": res.time_s / max(len(res.history), 1)}))


def _run(src: str, n: int, dim: int, fast: str) -> dict:
    env = dict(os.environ, PYTHONPATH=src, MICROLIE_FAST=fast)
    r = subprocess.run([sys.executable, __file__, "_child", str(n), str(dim)],
                       env=env, capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def scale(sizes: list[int], dim: int, old: str | None, old_max: int, fast: str,
          repeat: int) -> None:
    new = str(Path(__file__).resolve().parents[1] / "src")
    print("| poses | code | problem() s | analysis s | setup s | LM iteration s | "
          "setup / iteration | peak RSS MB: setup (before) / solve | supernodes |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in sizes:
        runs = [("new", new)] + ([("old", old)] if old and n <= old_max else [])
        res: dict[str, dict] = {}
        for _ in range(repeat if n < 1_000_000 else 1):  # interleaved; the fastest of each
            for name, src in runs:
                r = _run(src, n, dim, fast)
                res[name] = r if name not in res else {
                    k: min(v, r[k]) if isinstance(v, float) else v
                    for k, v in res[name].items()}
        for name, _src in runs:
            r = res[name]
            setup = r["problem"] + r["analyse"]
            print(f"| {n} | {name} | {r['problem']:.3f} | {r['analyse']:.3f} | {setup:.3f} | "
                  f"{r['iteration']:.3f} | {setup / r['iteration']:.2f} | {r['peak']:.0f} "
                  f"({r['rss_before']:.0f}) / {r['peak_solve']:.0f} | {r['ns']} |", flush=True)
        if "old" in res:
            o, w = res["old"], res["new"]
            print(f"|   | old/new | {o['problem'] / w['problem']:.2f}x | "
                  f"{o['analyse'] / w['analyse']:.2f}x | "
                  f"{(o['problem'] + o['analyse']) / (w['problem'] + w['analyse']):.2f}x | "
                  f"{o['iteration'] / w['iteration']:.2f}x | | "
                  f"{o['peak'] / w['peak']:.2f}x / {o['peak_solve'] / w['peak_solve']:.2f}x | |",
                  flush=True)


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
        _child(int(sys.argv[2]), int(sys.argv[3]))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("scale")
    s.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    s.add_argument("--old", help="src folder of the code to compare with")
    s.add_argument("--old-max", type=int, default=100000, help="largest size for --old")
    s.add_argument("--dim", type=int, choices=(2, 3), default=2, help="2-D (SE2) or 3-D (SE3)")
    s.add_argument("--fast", choices=("0", "1"), default="1",
                   help="MICROLIE_FAST for the runs (0: the NumPy paths)")
    s.add_argument("--repeat", type=int, default=1,
                   help="runs per size below 1e6 (interleaved; each figure the smallest)")
    f = sub.add_parser("flops")
    f.add_argument("--nd", help="src folder of a code base with ordering.nested_dissection")
    args = ap.parse_args()
    if args.cmd == "scale":
        scale(args.sizes, args.dim, args.old, args.old_max, args.fast, args.repeat)
    else:
        flops(args.nd)


if __name__ == "__main__":
    main()
