"""The fill-reducing ordering of the supernodal Cholesky on the shared pose graphs and a
synthetic 3-D lattice of poses (``lattice12``): minimum degree (``"mmd"``; nested dissection
was removed in issue 20, see ``benchmarks/symbolic.py flops``), with its structure and
measured factorisation times.

Run (one command, the dev or the benchmark environment)::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/orderings.py --repeat 7 \\
        [--clock cpu] [--graphs sphere2500 ...] [--out benchmarks/results/orderings-latest.md]

For each graph it builds the Gauss-Newton matrix at the start poses (the file's vertices, else
the odometry chain; the pattern is what matters), analyses it once per ordering and loop, then
times ``factorize`` in rounds that alternate the orderings and the loops (the NumPy loop, and
the compiled loop ``microlie._c._chol`` when it was built and ``MICROLIE_FAST`` is not 0),
after one warm-up round. Columns: scalar nonzeros of the factor (the panels' lower
trapezoids), the flops of the updates ``sum_s k_s u_s^2`` (``u_s`` the rows below supernode
``s``), the update entries moved into ancestors, the supernodes, the height of the supernodal
elimination tree, the steps of the NumPy loop, the analysis time of the NumPy solver (once per
problem, not part of a solve), and the median factorisation times with their ratio to
minimum degree's (the spread is the min-max of the per-round ratios). Every solution is checked
(relative residual printed).
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy.sparse as sp  # noqa: E402

from microlie.optim import from_pose_graph  # noqa: E402
from microlie.optim.init import initialize  # noqa: E402
from microlie.optim.io.g2o import read_g2o  # noqa: E402
from microlie.optim.linalg.cholesky import SupernodalSolver  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = {
    "sphere2500": "sphere2500.g2o", "parking-garage": "parking-garage.g2o",
    "M3500": "input_M3500_g2o.g2o", "ais2klinik": "ais2klinik.g2o", "kitti_00": "kitti_00.g2o",
    "sphere-a": "sphere_bignoise_vertex3.g2o", "smallGrid3D": "smallGrid3D.g2o",
    "CSAIL": "CSAIL.g2o", "MIT": "MIT.g2o",
    "lattice12": None,  # synthetic: a 12 x 12 x 12 lattice of SE(3) poses (see lattice())
}
ORDERINGS = ("mmd",)  # nested dissection was removed in issue 20 (benchmarks/symbolic.py)


def structure(s: SupernodalSolver) -> dict:
    """Structure of an analysed solver, from its public symbolic arrays."""
    u = s.m - s.k
    lev = np.zeros(s.ns, np.int64)
    for i, p in enumerate(s.sparent.tolist()):
        if p >= 0 and lev[p] <= lev[i]:
            lev[p] = lev[i] + 1
    ps = np.repeat(np.arange(s.ns), np.diff(s.pptr))
    plan = getattr(s, "_numpy_plan", None)
    return {"nnz": int((s.m * s.k).sum() - (s.k * (s.k - 1) // 2).sum()),
            "flops": float((u.astype(float) ** 2 * s.k).sum()),
            "entries": int(((s.pb - s.pa) * (u[ps] - s.pa)).sum()),
            "ns": int(s.ns), "height": int(lev.max()) + 1 if s.ns else 0,
            "steps": len(plan) if plan is not None else None}


def has_compiled() -> bool:
    try:
        SupernodalSolver(compiled=True)
    except ImportError:
        return False
    return True


def lattice(k: int) -> tuple:
    """A synthetic 3-D lattice of 6-dof poses (each joined to its 6 neighbours): the
    Gauss-Newton matrix's CSC pattern, data, a right-hand side and the matrix."""
    P = sp.diags([np.ones(k - 1), np.ones(k - 1)], [-1, 1], shape=(k, k))
    I = sp.eye(k)
    A = sp.kron(sp.kron(P, I), I) + sp.kron(sp.kron(I, P), I) + sp.kron(sp.kron(I, I), P)
    L = sp.diags(np.asarray(A.sum(axis=1)).ravel() + 0.1) - A
    W = np.random.default_rng(0).standard_normal((6, 6))
    H = sp.kron(L, W @ W.T + 6 * np.eye(6)).tocsc()
    H.sort_indices()
    return H.indptr, H.indices, H.shape[0], 6, H.data, np.ones(H.shape[0]), H


def run(name: str, repeat: int, clock=time.perf_counter) -> list[dict]:
    if name == "lattice12":
        indptr, indices, n, bs, data, grad, H = lattice(12)
    else:
        pg = read_g2o(DATA / GRAPHS[name])
        try:
            X0 = initialize(pg, "file")
        except ValueError:
            X0 = initialize(pg, "odometry")
        fg, _ = from_pose_graph(pg, X0)
        prob = fg.problem()
        lin = prob.linearize([v.initial for v in prob.variables])
        indptr, indices, n, bs = prob.indptr, prob.indices, prob.size, prob.block_size
        data, grad, H = lin.data, lin.grad, prob.matrix(lin.data)
    loops = [False] + ([True] if has_compiled() else [])
    solvers, rows = {}, []
    for o in ORDERINGS:
        for c in loops:
            s = SupernodalSolver(compiled=c, ordering=o)
            t0 = time.perf_counter()
            s.analyse(indptr, indices, n, bs)
            solvers[o, c] = (s, time.perf_counter() - t0)
    times: dict = {k: [] for k in solvers}
    for r in range(repeat + 1):
        for k, (s, _) in solvers.items():
            t0 = clock()
            s.factorize(data)
            if r:
                times[k].append(clock() - t0)
    for o in ORDERINGS:
        s, ta = solvers[o, False]
        x = s.solve(grad)
        row = {"graph": name, "ordering": o, "analysis": ta, **structure(s),
               "residual": float(np.linalg.norm(H @ x - grad) / np.linalg.norm(grad))}
        for c in loops:
            t, t_mmd = times[o, c], times["mmd", c]
            ratios = [a / b for a, b in zip(t, t_mmd, strict=True)]
            row["C" if c else "numpy"] = (statistics.median(t), statistics.median(t)
                                          / statistics.median(t_mmd), min(ratios), max(ratios))
        rows.append(row)
    return rows


def table(rows: list[dict]) -> str:
    out = ["| graph | ordering | factor nnz | update flops | update entries | supernodes | "
           "height | NumPy steps | analysis (ms) | NumPy factorize (ms) | C factorize (ms) | "
           "residual |", "|" + " --- |" * 12]
    for r in rows:
        cells = []
        for c in ("numpy", "C"):
            if c in r:
                t, q, lo, hi = r[c]
                cells.append(f"{t * 1e3:.2f} ({q:.3f}, {lo:.2f}-{hi:.2f})")
            else:
                cells.append("n/a")
        steps = "n/a" if r["steps"] is None else str(r["steps"])
        out.append(f"| {r['graph']} | {r['ordering']} | {r['nnz'] / 1e6:.3f}M | "
                   f"{r['flops'] / 1e6:.1f}M | {r['entries'] / 1e6:.3f}M | {r['ns']} | "
                   f"{r['height']} | {steps} | {r['analysis'] * 1e3:.0f} | {cells[0]} | "
                   f"{cells[1]} | {r['residual']:.0e} |")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--graphs", nargs="*", default=list(GRAPHS), choices=list(GRAPHS))
    ap.add_argument("--clock", choices=["wall", "cpu"], default="wall",
                    help="time factorisations by the wall clock or by this process's CPU time "
                         "(steadier on a shared machine; one BLAS thread)")
    ap.add_argument("--out", default=None, help="also write the markdown table to this file")
    args = ap.parse_args()
    clock = time.perf_counter if args.clock == "wall" else time.process_time
    load0 = os.getloadavg()[0]
    rows = []
    for g in args.graphs:
        rows += run(g, args.repeat, clock)
        print(table(rows[-len(ORDERINGS):]).split("\n", 2)[2], flush=True)
    text = (f"load average before/after: {load0:.2f}/{os.getloadavg()[0]:.2f}; "
            f"factorisation times ({args.clock} clock): median ms (ratio of medians to mmd, "
            "min-max of the per-round ratios)\n\n"
            + table(rows))
    print("\n" + text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
