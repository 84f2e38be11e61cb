"""``linear_solver="schur"`` against ``"cholesky"`` on a bundle-adjustment graph, interleaved,
printing ratios (``bundle_adjust`` itself runs this engine since issue 20).

The graph is a BAL problem (default problem-49-7776) as factors of the one engine: per camera
an SO3 rotation, an R(3) translation and R(3) intrinsics ``(f, k1, k2)``, per point an R(3)
variable, and one analytic :class:`~microlie.optim.CustomFactor` whose values and Jacobians
come from :func:`microlie.optim.sfm.camera.reproject` (the bundle adjuster's own projection).

Printed, per repetition (each round runs every contender once, in turn):

- ``linear``: one damped factorisation and solve of the same ``H`` (the linearisation at the
  start, ``lambda = 1e-4`` on the diagonal; one BLAS thread, as ``optimize`` runs): median of
  ``--inner`` calls, ms. Schur includes
  forming and factorising the reduced system and the back-substitution.
- ``iteration``: a Levenberg-Marquardt run of ``--iters`` iterations on the graph, time per
  iteration (linearisation, solve, trial cost). ``in-run solve``: the linear-solve part of
  those runs per linear solve (factorisation and solve).
- ``analysis``: the one-off symbolic analysis of each solver, ms.

Usage::

    PYTHONPATH=src python benchmarks/schur.py [--bal FILE] [--repeat 3] [--iters 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from microlie import SO3
from microlie.optim import CustomFactor, FactorGraph, read_bal
from microlie.optim.core.threads import blas_threads_limit
from microlie.optim.sfm.camera import BALCamera, reproject

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "bal"


def bal_graph(bal) -> FactorGraph:
    """The BAL problem as an engine graph (no gauge prior: LM's damping holds the gauge)."""
    model = BALCamera()
    g = FactorGraph()
    rot = g.add_variables(SO3.exp(bal.cameras[:, :3]), name="rotations")
    tr = g.add_variables(bal.cameras[:, 3:6].copy(), name="translations")
    K = g.add_variables(bal.cameras[:, 6:9].copy(), name="intrinsics")
    X = g.add_variables(bal.points.copy(), name="points")

    def fn(R, t, k, x, z):
        m = len(t)
        i = np.arange(m)
        rep = reproject(model, R.matrix(), t, k, x, i, i, z)
        Jc = rep.J_cam
        return rep.residuals, [Jc[:, :, 3:6], Jc[:, :, 0:3], Jc[:, :, 6:9], rep.J_point]

    c, p = bal.camera_index, bal.point_index
    g.add(CustomFactor(fn, [(rot, c), (tr, c), (K, c), (X, p)], 2, data=[bal.observations],
                       jac="analytic"))
    return g


def linear_time(ls, data, diag, grad, inner):
    d = data.copy()
    d[diag] += 1e-4
    times = []
    with blas_threads_limit(1):  # as optimize runs
        for _ in range(inner):
            t0 = time.perf_counter()
            ls.factorize(d)
            x = ls.solve(-grad)
            times.append(time.perf_counter() - t0)
    return statistics.median(times), x


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bal", default=str(DATA / "problem-49-7776-pre.txt"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--iters", type=int, default=5)
    ap.add_argument("--inner", type=int, default=5)
    args = ap.parse_args()
    bal = read_bal(args.bal)
    g = bal_graph(bal)
    p = g.problem("none")
    lin = p.linearize([v.initial for v in p.variables])
    print(f"{Path(args.bal).name}: {p.num_nodes} nodes, {p.size} unknowns, H nnz {p.nnz}")
    ana = {}
    solvers = {}
    for name in ("schur", "cholesky"):
        t0 = time.perf_counter()
        solvers[name] = p.analysed(name)
        ana[name] = time.perf_counter() - t0
    s = solvers["schur"]
    print(f"schur: reduced system {s.n_reduced} unknowns ({s.reduced_solver.name}); analysis "
          f"schur {1e3 * ana['schur']:.1f} ms, cholesky {1e3 * ana['cholesky']:.1f} ms")
    _, xs = linear_time(solvers["schur"], lin.data, p.diag_pos, lin.grad, 1)
    _, xc = linear_time(solvers["cholesky"], lin.data, p.diag_pos, lin.grad, 1)
    print(f"steps agree: max |x_schur - x_cholesky| / max |x| = "
          f"{np.abs(xs - xc).max() / np.abs(xc).max():.1e}")
    rows: dict[str, list[float]] = {}
    for r in range(args.repeat):
        for name in ("schur", "cholesky"):
            t, _ = linear_time(solvers[name], lin.data, p.diag_pos, lin.grad, args.inner)
            rows.setdefault(f"linear {name}", []).append(t)
        for name in ("schur", "cholesky"):
            res = g.optimize(linear_solver=name, max_iter=args.iters, gauge="none",
                             rel_tol=0.0, abs_tol=0.0, verbose=False)
            solves = sum(h.solves for h in res.history)
            rows.setdefault(f"iteration {name}", []).append(res.time_s / res.iterations)
            rows.setdefault(f"in-run solve {name}", []).append(
                (res.timings["factorize"] + res.timings["solve"]) / solves)
        print(f"round {r + 1} (ms): " + ", ".join(f"{k} {1e3 * v[-1]:.1f}"
                                               for k, v in rows.items()), flush=True)
    med = {k: statistics.median(v) for k, v in rows.items()}
    print(f"\nmedians over {args.repeat} rounds (ms):")
    for k, v in med.items():
        print(f"  {k:30s} {1e3 * v:9.2f}")
    for what in ("linear", "in-run solve", "iteration"):
        print(f"  {what + ' schur / cholesky:':38s} "
              f"{med[f'{what} schur'] / med[f'{what} cholesky']:.2f}x")


if __name__ == "__main__":
    main()
