"""Symbolic analysis of the supernodal Cholesky at scale, and the fill of the orderings.

Two parts (one command each):

``scale``: synthetic pose graphs (:func:`synthetic_pose_graph`: a random walk on the integer
grid, 2-D with SE(2) poses or 3-D with SE(3) poses (``--dim 3``); odometry between consecutive
poses and a loop closure to the previous visit of the same cell) of 1e3 to 1e6 poses. For each
size, in a fresh subprocess per code base, the setup a user pays once is timed: ``g.problem()``
(block pattern, compiled edge plans or the NumPy path's scatter map) and the supernodal solver's
analysis (minimum-degree order, elimination tree, column counts, supernodes, structures,
assembly and update maps, and without the compiled extra the NumPy loop's plan), then three
Levenberg-Marquardt iterations (the analysis kept) time one iteration; peak resident memory
after the setup and after the solve. ``--old SRC`` runs the same with ``PYTHONPATH=SRC`` (e.g.
the code at 1bd9510 unpacked with ``git archive``), interleaved with this one, ``--repeat R``
times below 1e6 poses, each figure the smallest; ``--fast 0`` runs without the compiled extra::

    OPENBLAS_NUM_THREADS=1 python benchmarks/symbolic.py scale \\
        --sizes 1000 10000 100000 1000000 [--dim 3] [--fast 0] [--old SRC --old-max N] \\
        [--graphs sphere2500 parking-garage]

``flops``: the factorisation flops ``sum(counts**2)`` of the block factor under minimum degree
and under other orderings given as code bases (``--nd SRC``: the nested dissection of the code
before issue 20, ``ordering.nested_dissection`` with its default and its coarse leaf size), on
the shared pose graphs; the counts are this module's exact symbolic ones for every order::

    PYTHONPATH=src python benchmarks/symbolic.py flops --nd /work/base/src

``order``: the orderings of the block graph compared on the shared pose graphs and on synthetic
ones (``--sizes``, 2-D and 3-D): our approximate minimum degree (``microlie._c._order``,
what :func:`~microlie.optim.linalg.ordering.minimum_degree_blocks` runs with the compiled code)
against SciPy's SuperLU multiple minimum degree (``MMD_AT_PLUS_A``, the order without the
compiled code) and COLAMD (on the same symmetric pattern). For each: the nonzero blocks of
``L`` and the factorisation flops ``sum(counts**2)`` (exact symbolic counts), and the ordering
time (the smallest of ``--repeat`` runs)::

    PYTHONPATH=src:fast/src python benchmarks/symbolic.py order --sizes 10000 100000
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


def synthetic_pose_graph(n: int, dim: int = 2, seed: int = 0):
    """A synthetic pose graph of ``n`` poses in ``dim`` = 2 (SE(2)) or 3 (SE(3)) dimensions.

    A random walk on the integer grid (unit steps along +-x, +-y(, +-z), drawn from
    ``default_rng(seed)``), one pose per step heading along its step; odometry edges between
    consecutive poses and a loop closure from each visit of a cell to the previous visit of
    the same cell; edges sorted by ``(i, j)``. Measurements are the true relative poses with
    noise on the right (``Exp(0.01 n)``), information ``1e4 I``; the graph's poses (the start)
    are the truth with noise ``Exp(0.05 n)`` (``default_rng(seed + 1)``).
    ``benchmarks/scaling.py`` reuses it.
    """
    from microlie import SE2, SE3
    from microlie.optim.io.pose_graph import PoseGraph

    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    eye = np.eye(dim, dtype=np.int64)
    moves = np.stack([eye, -eye], axis=1).reshape(2 * dim, dim)  # +e0, -e0, +e1, -e1, ...
    walk = np.random.default_rng(seed).integers(0, 2 * dim, n)
    steps = moves[walk]
    steps[0] = 0
    pos = np.cumsum(steps, axis=0)
    o = np.lexsort(pos.T[::-1])  # by x, then y (then z), stable: visits in time order
    same = np.all(pos[o][1:] == pos[o][:-1], axis=1)
    a = np.r_[np.arange(n - 1), o[:-1][same]]
    b = np.r_[np.arange(1, n), o[1:][same]]
    e = np.lexsort((b, a))
    i, j = a[e].astype(np.int64), b[e].astype(np.int64)
    rng = np.random.default_rng(seed + 1)
    xyz = pos.astype(np.float64)
    if dim == 2:
        G = SE2
        truth = SE2.from_xy_theta(xyz[:, 0], xyz[:, 1],
                                  np.arctan2(steps[:, 1], steps[:, 0]).astype(np.float64))
    else:  # the rotation taking +x to the step's direction (the first pose: the identity)
        G = SE3
        half = np.array([[0, 0, 0], [0, 0, np.pi], [0, 0, np.pi / 2], [0, 0, -np.pi / 2],
                         [0, -np.pi / 2, 0], [0, np.pi / 2, 0]])[walk] / 2
        half[0] = 0
        ang = np.linalg.norm(half, axis=1, keepdims=True)
        axis = np.divide(half, ang, out=np.zeros_like(half), where=ang > 0)
        truth = SE3(np.concatenate([xyz, axis * np.sin(ang), np.cos(ang)], axis=1))
    d = G.dof
    z = truth[i].inverse() @ truth[j]
    z = z @ G.exp(0.01 * rng.standard_normal((i.size, d)))
    start = truth @ G.exp(0.05 * rng.standard_normal((n, d)))
    return PoseGraph(G, ids=np.arange(n), poses=start, i=i, j=j, measurements=z,
                     information=np.broadcast_to(np.eye(d) * 1e4, (i.size, d, d)).copy())


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _graph(n: int | str, dim: int):
    """The factor graph of :func:`synthetic_pose_graph` (or of the shared graph named ``n``)
    with the first pose fixed."""
    if isinstance(n, str):
        from microlie.optim.io.g2o import read_g2o

        g, _ = read_g2o(DATA / GRAPHS[n]).to_factor_graph(gauge="fix")
        return g
    g, _ = synthetic_pose_graph(n, dim).to_factor_graph(gauge="fix")
    return g


def _problem(n: int, dim: int = 2):
    """The problem of the synthetic graph (see :func:`_graph`)."""
    return _graph(n, dim).problem()


def _child(n: int | str, dim: int) -> None:
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


def _run(src: str, n: int | str, dim: int, fast: str) -> dict:
    # that tree's own in-place build of the compiled code lies in src/microlie/_c
    env = dict(os.environ, PYTHONPATH=src, MICROLIE_FAST=fast)
    r = subprocess.run([sys.executable, __file__, "_child", str(n), str(dim)],
                       env=env, capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def scale(sizes: list[int | str], dim: int, old: str | None, old_max: int, fast: str,
          repeat: int) -> None:
    new = str(Path(__file__).resolve().parents[1] / "src")
    print("| poses | code | problem() s | analysis s | setup s | LM iteration s | "
          "setup / iteration | peak RSS MB: setup (before) / solve | supernodes |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in sizes:
        big = isinstance(n, int) and n >= 1_000_000
        runs = [("new", new)] + ([("old", old)] if old and (
            isinstance(n, str) or n <= old_max) else [])
        res: dict[str, dict] = {}
        for _ in range(1 if big else repeat):  # interleaved; the fastest of each
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


def _adjacency(name: str | int, dim: int):
    """The symmetric block adjacency (CSR, no diagonal) of a shared graph or a synthetic one."""
    if isinstance(name, str):
        from microlie.optim.io.g2o import read_g2o

        g = read_g2o(DATA / GRAPHS[name])
        a, b, n = np.asarray(g.i), np.asarray(g.j), len(g.ids)
    else:
        g = synthetic_pose_graph(name, dim)
        a, b, n = np.asarray(g.i), np.asarray(g.j), name
    keep = a != b
    A = sp.csr_matrix((np.ones(keep.sum()), (a[keep], b[keep])), shape=(n, n))
    A = A + A.T
    A.data[:] = 1.0
    A.sort_indices()
    return A


def order(sizes: list[int], repeat: int) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from scipy.sparse.linalg import spilu

    from microlie._fast import compiled
    from microlie.optim.linalg.ordering import minimum_degree, symbolic

    amd = compiled("_order")
    if amd is None:
        raise SystemExit("order: the compiled microlie._c._order is needed (build fast/)")

    def superlu(spec: str):
        def run(A):
            B = (sp.diags(np.diff(A.indptr) + 1.0) - A).tocsc()
            lu = spilu(B, drop_tol=1e300, fill_factor=1, permc_spec=spec,
                       diag_pivot_thresh=0.0, options={"SymmetricMode": True})
            return np.argsort(lu.perm_c)
        return run

    methods = {"amd": lambda A: amd.order(A.indptr.astype(np.intp),
                                          A.indices.astype(np.intp), A.shape[0]),
               "mmd": minimum_degree, "colamd": superlu("COLAMD")}
    print("| graph | blocks | amd nnz(L) | amd flops | mmd nnz/amd | mmd flops/amd | "
          "colamd nnz/amd | colamd flops/amd | amd s | mmd s | colamd s | mmd s / amd s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    cases: list[tuple[str | int, int, str]] = [(g, 0, g) for g in GRAPHS
                                              if (DATA / GRAPHS[g]).exists()]
    cases += [(n, d, f"synthetic {d}-D {n}") for d in (2, 3) for n in sizes]
    for name, dim, label in cases:
        A = _adjacency(name, dim)
        res = {}
        for m, fn in methods.items():
            best = np.inf
            for _ in range(repeat):
                t = time.perf_counter()
                p = fn(A)
                best = min(best, time.perf_counter() - t)
            s = symbolic(A, p)
            res[m] = (s.nnz, s.flops, best)
        a = res["amd"]
        print(f"| {label} | {A.shape[0]} | {a[0]} | {a[1]:.3e} | "
              f"{res['mmd'][0] / a[0]:.3f} | {res['mmd'][1] / a[1]:.3f} | "
              f"{res['colamd'][0] / a[0]:.3f} | {res['colamd'][1] / a[1]:.3f} | "
              f"{a[2]:.4f} | {res['mmd'][2]:.4f} | {res['colamd'][2]:.4f} | "
              f"{res['mmd'][2] / a[2]:.1f} |", flush=True)


def main() -> None:
    if sys.argv[1:2] == ["_child"]:
        a = sys.argv[2]
        _child(a if a in GRAPHS else int(a), int(sys.argv[3]))
        return
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("scale")
    s.add_argument("--sizes", type=int, nargs="+", default=[1000, 10000, 100000])
    s.add_argument("--graphs", nargs="*", default=[], choices=list(GRAPHS),
                   help="shared pose graphs to time after the synthetic sizes")
    s.add_argument("--old", help="src folder of the code to compare with")
    s.add_argument("--old-max", type=int, default=100000, help="largest size for --old")
    s.add_argument("--dim", type=int, choices=(2, 3), default=2, help="2-D (SE2) or 3-D (SE3)")
    s.add_argument("--fast", choices=("0", "1"), default="1",
                   help="MICROLIE_FAST for the runs (0: the NumPy paths)")
    s.add_argument("--repeat", type=int, default=1,
                   help="runs per size below 1e6 (interleaved; each figure the smallest)")
    f = sub.add_parser("flops")
    f.add_argument("--nd", help="src folder of a code base with ordering.nested_dissection")
    o = sub.add_parser("order")
    o.add_argument("--sizes", type=int, nargs="*", default=[10000, 100000])
    o.add_argument("--repeat", type=int, default=3, help="runs per ordering (the fastest)")
    args = ap.parse_args()
    if args.cmd == "order":
        order(args.sizes, args.repeat)
    elif args.cmd == "scale":
        scale([*args.sizes, *args.graphs], args.dim, args.old, args.old_max, args.fast,
              args.repeat)
    else:
        flops(args.nd)


if __name__ == "__main__":
    main()
