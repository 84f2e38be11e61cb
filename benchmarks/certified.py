"""The certified pose-graph solver (microlie.optim.certify) on the shared graphs, against
SE-Sync's published optima and against Levenberg-Marquardt from the chordal start.

Run::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src /work/main/.venv/bin/python benchmarks/certified.py \
        --repeat 3 --out benchmarks/results/certified-s9.md [--graphs NAME ...]

For each graph, interleaved ``--repeat`` times after one warm-up (medians printed):

- ``certified_pose_graph(graph)``: SE-Sync's objective ``F`` (isotropic weights from each edge's
  information, no 1/2), whether the certificate verified, the smallest eigenvalue of the
  certificate matrix and its tolerance, the staircase's rank, the time (chordal rotations,
  staircase, certificate, rounding, translations: everything after reading the file);
- LM (``FactorGraph.optimize``, GTSAM's rules, ``rel_tol=1e-10``, ``abs_tol=1e-12``, at most
  500 iterations, as the data README's GTSAM reference) from ``microlie.optim.init.chordal``:
  GTSAM's error ``0.5 sum r^T Omega r`` with the file's full information, and its time
  (chordal + LM);
- LM from the certified poses (the polish of ``microlie optimize --init certified``): its error
  and time, and whether it is no higher than LM from chordal (relative 1e-9).

SE-Sync's published optimal ``F`` (Rosen, Carlone, Bandeira, Leonard, IJRR 2019, Table 2, via
``../shared/data/README.md``) is printed where the files agree, and a second table sets our
certified times beside SE-Sync's published ones (Tables 1 and 2; another machine). Then, on
``sphere_bignoise_vertex3.g2o``, the command itself: ``microlie optimize FILE --init file
--certify`` (LM from the file's vertices, then the certificate of its answer) and
``--init certified --certify``.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"

#: file -> SE-Sync's published optimal F (None: not in the paper's table)
GRAPHS = {
    "tinyGrid3D": ("tinyGrid3D.g2o", None),
    "smallGrid3D": ("smallGrid3D.g2o", None),
    "sphere2500": ("sphere2500.g2o", 1.687e3),
    "parking-garage": ("parking-garage.g2o", 1.263e0),
    "sphere_bignoise_vertex3": ("sphere_bignoise_vertex3.g2o", None),
    "CSAIL": ("CSAIL.g2o", 3.170e1),
    "manhattan": ("manhattan.g2o", 6.432e3),
    "ais2klinik": ("ais2klinik.g2o", 1.885e2),
}

#: SE-Sync's published times in seconds (Rosen, Carlone, Bandeira, Leonard, IJRR 38(2-3) 2019,
#: Tables 1 and 2: their C++ SE-Sync and GTSAM's Powell dogleg, "PDL-GN", both from the chordal
#: initialisation, on an Intel Xeon E3-1505M 2.80 GHz laptop): (SE-Sync, PDL-GN)
PUBLISHED_TIMES = {
    "sphere2500": (0.580, 0.704),
    "parking-garage": (0.468, 0.415),
    "CSAIL": (0.010, 0.029),
    "manhattan": (0.080, 0.268),
    "ais2klinik": (1.981, 12.472),
}


def _lm(graph, X0):
    fg, poses = graph.to_factor_graph(X0)
    t = time.perf_counter()
    # as the data README's GTSAM reference, and no absolute stop (parking-garage's cost is 0.63:
    # the default abs_tol 1e-5 stops LM from the certified start at 0.63421)
    res = fg.optimize(max_iter=500, rel_tol=1e-10, abs_tol=1e-12)
    return graph.cost(res.values[poses]), time.perf_counter() - t, res.iterations


def run_graph(name: str, repeat: int) -> dict:
    from microlie.optim.certify import certified_pose_graph
    from microlie.optim.init import chordal
    from microlie.optim.io.g2o import read_g2o

    fname, published = GRAPHS[name]
    g = read_g2o(DATA / fname)
    rows: dict[str, list] = {"cert_t": [], "lm_t": [], "polish_t": []}
    for k in range(repeat + 1):  # round 0 is the warm-up
        t = time.perf_counter()
        c = certified_pose_graph(g)
        cert_t = time.perf_counter() - t
        t = time.perf_counter()
        X0 = chordal(g)
        ch_t = time.perf_counter() - t
        lm_cost, lm_t, lm_it = _lm(g, X0)
        pol_cost, pol_t, pol_it = _lm(g, c.poses)
        if k:
            rows["cert_t"].append(cert_t)
            rows["lm_t"].append(ch_t + lm_t)
            rows["polish_t"].append(pol_t)
    out = {
        "graph": name, "poses": g.num_vertices, "edges": g.num_edges, "F": c.objective,
        "published_F": published, "certified": c.certified,
        "min_eigenvalue": c.min_eigenvalue, "tolerance": c.tolerance, "rank": c.rank,
        "iterations": c.iterations, "cert_cost": c.cost,
        "cert_s": statistics.median(rows["cert_t"]),
        "lm_chordal_cost": lm_cost, "lm_chordal_iterations": lm_it,
        "lm_chordal_s": statistics.median(rows["lm_t"]),
        "polished_cost": pol_cost, "polish_iterations": pol_it,
        "polish_s": statistics.median(rows["polish_t"]),
    }
    out["no_higher"] = pol_cost <= lm_cost * (1 + 1e-9)
    return out


def command(*extra: str) -> dict:
    from microlie.optim.command import register

    parser = argparse.ArgumentParser(prog="microlie")
    register(parser.add_subparsers())
    path = DATA / "sphere_bignoise_vertex3.g2o"
    args = parser.parse_args(["optimize", str(path), "--json", "-q", *extra])
    out = io.StringIO()
    t = time.perf_counter()
    args.func(args, out, io.StringIO())
    rep = json.loads(out.getvalue())
    rep["wall_s"] = time.perf_counter() - t
    return rep


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--graphs", nargs="+", default=list(GRAPHS), choices=list(GRAPHS))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--no-command", action="store_true", help="skip the command section")
    ap.add_argument("--out", default=None, help="write the markdown here too")
    a = ap.parse_args()
    load = os.getloadavg()
    lines = ["# Certified pose graphs (microlie.optim.certify)\n",
             f"`OPENBLAS_NUM_THREADS=1 PYTHONPATH=src {sys.executable} benchmarks/certified.py "
             f"--repeat {a.repeat}" + (f" --graphs {' '.join(a.graphs)}"
                                       if a.graphs != list(GRAPHS) else "") + "`",
             f"commit {_commit()}, load at start {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} "
             f"(2 cores), medians of {a.repeat} interleaved rounds after a warm-up.\n",
             "F: SE-Sync's objective (no 1/2). cost: GTSAM's error 0.5 sum r^T Omega r with the "
             "file's information. Times in seconds, after reading the file.\n",
             "| graph | poses / edges | F certified (ours) | SE-Sync published F | certified | "
             "lambda_min(S) / tolerance | rank | time certified | LM from chordal: cost, "
             "time | LM from certified: cost, time | <= chordal LM |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    results = []
    for name in a.graphs:
        r = run_graph(name, a.repeat)
        results.append(r)
        pub = "-" if r["published_F"] is None else f"{r['published_F']:.4g}"
        row = (f"| {name} | {r['poses']} / {r['edges']} | {r['F']:.10g} | {pub} | "
               f"{'yes' if r['certified'] else 'NO'} | {r['min_eigenvalue']:.2g} / "
               f"{r['tolerance']:.2g} | {r['rank']} | {r['cert_s']:.3f} | "
               f"{r['lm_chordal_cost']:.10g}, {r['lm_chordal_s']:.3f} | "
               f"{r['polished_cost']:.10g}, {r['polish_s']:.3f} | "
               f"{'yes' if r['no_higher'] else 'NO'} |")
        lines.append(row)
        print(row, flush=True)
    timed = [r for r in results if r["graph"] in PUBLISHED_TIMES]
    if timed:
        lines += ["", "## Against SE-Sync's published times", "",
                  "SE-Sync's and GTSAM's (Powell's dogleg) times as published (IJRR 2019, Tables 1 "
                  "and 2; C++, Intel Xeon E3-1505M 2.80 GHz laptop, 2016): a different machine, "
                  "so the ratios are indicative only. Ours: `certified_pose_graph` on this "
                  "machine, median above.", "",
                  "| graph | SE-Sync published F | ours F | SE-Sync s (published) | GTSAM PDL s "
                  "(published) | ours certified s | ours / SE-Sync |",
                  "|---|---|---|---|---|---|---|"]
        for r in timed:
            ss, pdl = PUBLISHED_TIMES[r["graph"]]
            row = (f"| {r['graph']} | {r['published_F']:.4g} | {r['F']:.6g} | {ss:.3f} | "
                   f"{pdl:.3f} | {r['cert_s']:.3f} | {r['cert_s'] / ss:.2f} |")
            lines.append(row)
            print(row, flush=True)
    if not a.no_command:
        lines += ["", "## `microlie optimize sphere_bignoise_vertex3.g2o` (in process)", "",
                  "| options | LM start cost -> final cost | iterations | certificate of the "
                  "answer | F (refined) | lambda_min(S) | wall s |",
                  "|---|---|---|---|---|---|---|"]
        for extra in (("--init", "file", "--certify"), ("--init", "chordal", "--certify"),
                      ("--init", "certified", "--certify")):
            rep = command(*extra)
            c = rep["certificate"]
            row = (f"| `{' '.join(extra)}` | {rep['initial_cost']:.10g} -> "
                   f"{rep['final_cost']:.10g} | {rep['iterations']} | "
                   f"{'certified' if c['certified'] else 'NOT certified'} "
                   f"(moved {c['moved']:.3g} rad) | {c['objective']:.10g} | "
                   f"{c['min_eigenvalue']:.3g} | {rep['wall_s']:.2f} |")
            lines.append(row)
            print(row, flush=True)
    load = os.getloadavg()
    lines.append(f"\nload at end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    print(lines[-1])
    if a.out:
        Path(a.out).write_text("\n".join(lines) + "\n")


def _commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "?"


if __name__ == "__main__":
    main()
