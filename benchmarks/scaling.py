"""Scaling: synthetic 2-D and 3-D pose graphs of 1e3-1e6 poses, microlie against GTSAM 4.3.

The graphs are ``symbolic.synthetic_pose_graph`` (a random walk on the integer grid, odometry
and a loop closure at every revisit of a cell, the start the truth with noise); pose 0 is held
(microlie: fixed; GTSAM: a prior with sigma 1e-6). Every contender runs in its own fresh
subprocess, one at a time, interleaved round by round, one BLAS thread:

- ``gtsam``: GTSAM 4.3 (``--gtsam-python``, the benchmark environment) builds the
  ``NonlinearFactorGraph`` (``BetweenFactorPose2/3``) and ``Values`` in a Python loop, then
  ``LevenbergMarquardtOptimizer(graph, initial, LevenbergMarquardtParams())`` (constructor,
  which orders) and ``optimize()``;
- ``fast:NAME`` / ``numpy:NAME``: microlie (``--python``) with and without the compiled extra
  (``MICROLIE_FAST=0``), linear solver NAME: ``from_pose_graph`` (graph construction),
  ``FactorGraph.problem()`` (pattern, "setup"), ``Problem.analysed(NAME)`` (ordering and
  symbolic analysis) and ``FactorGraph.optimize(linear_solver=NAME)`` (LM, GTSAM's rules and
  tolerances).

"Setup + analysis / iteration" (the goal: at most 1) counts everything between graph
construction and the first linearisation: ``FactorGraph.problem()`` (the block pattern, the
gauge check, the compiled loops' scatter positions) and ``Problem.analysed`` (ordering and
symbolic analysis), over the per-iteration time; ``optimize`` reuses both.

"User pays" = microlie construction + setup + analysis + solve; GTSAM constructor +
``optimize()`` (GTSAM's Python graph building is printed apart). Per-iteration time = solve
time / iterations (GTSAM: ``optimize()`` / ``optimizer.iterations()``). Peak memory = the
subprocess's own peak RSS (``VmHWM``: interpreter, imports and the loaded graph included; not
``ru_maxrss``, which on Linux carries the parent's peak into a child), also read after each
phase. Final costs (GTSAM's ``0.5 sum r^T Omega r`` over the edges) are evaluated
by ``PoseGraph.cost`` in the parent on the poses each child returns. One command::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src /work/main/.venv/bin/python benchmarks/scaling.py \\
        --cases 2d:1000 2d:10000 2d:100000 3d:100000 --repeat 3 \\
        --out benchmarks/results/scaling-latest.md
    ... benchmarks/scaling.py --cases 2d:1000000 --repeat 1 --contenders gtsam fast:cholesky

``pose_graph.py --user-pays`` runs the same children on the shared pose-graph files.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import resource  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
GTSAM_PYTHON = "/work/bench-venv/bin/python"


def _peak_mb() -> float:
    """This process's peak resident memory, MB: ``VmHWM`` (reset by ``exec``; ``ru_maxrss``
    is not on Linux: a child started by a large parent inherits the parent's peak)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


# ---------------------------------------------------------------- the graph file of a case
def save_graph(pg, path: Path) -> None:
    """The arrays of a PoseGraph (poses = the start) for the children (no pickle)."""
    np.savez(path, dim=2 if pg.group.dof == 3 else 3, ids=np.asarray(pg.ids),
             i=np.asarray(pg.i), j=np.asarray(pg.j), z=np.asarray(pg.measurements.params),
             info=np.asarray(pg.information), x0=np.asarray(pg.poses.params))


def _arrays(path: str) -> dict:
    with np.load(path) as f:
        return {k: f[k] for k in f.files}


# ---------------------------------------------------------------- the children
def child_gtsam(path: str, out: str) -> dict:
    import gtsam

    peaks = {"import": _peak_mb()}
    a = _arrays(path)
    peaks["load"] = _peak_mb()
    is3d = int(a["dim"]) == 3
    t0 = time.perf_counter()
    graph, init = gtsam.NonlinearFactorGraph(), gtsam.Values()
    info = a["info"]
    if is3d:  # our tangent order (rho, phi) -> GTSAM's (rot, trans)
        perm = [3, 4, 5, 0, 1, 2]
        info = info[:, perm][:, :, perm]
    same = bool(np.all(info == info[0]))
    one = gtsam.noiseModel.Gaussian.Information(info[0]) if same else None

    def pose(p):
        if is3d:
            x, y, z, qx, qy, qz, qw = p
            return gtsam.Pose3(gtsam.Rot3.Quaternion(qw, qx, qy, qz), np.array([x, y, z]))
        return gtsam.Pose2(p[0], p[1], np.arctan2(p[3], p[2]))

    Between = gtsam.BetweenFactorPose3 if is3d else gtsam.BetweenFactorPose2
    for key, p in zip(a["ids"].tolist(), a["x0"], strict=True):
        init.insert(key, pose(p))
    for e, (i, j, z) in enumerate(zip(a["i"].tolist(), a["j"].tolist(), a["z"],
                                      strict=True)):
        model = one if same else gtsam.noiseModel.Gaussian.Information(info[e])
        graph.add(Between(int(a["ids"][i]), int(a["ids"][j]), pose(z), model))
    k0 = int(a["ids"][0])
    d = 6 if is3d else 3
    prior = gtsam.PriorFactorPose3 if is3d else gtsam.PriorFactorPose2
    graph.add(prior(k0, init.atPose3(k0) if is3d else init.atPose2(k0),
                    gtsam.noiseModel.Diagonal.Sigmas(np.full(d, 1e-6))))
    t1 = time.perf_counter()
    peaks["build"] = _peak_mb()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, init, gtsam.LevenbergMarquardtParams())
    t2 = time.perf_counter()
    peaks["constructor"] = _peak_mb()
    res = opt.optimize()
    t3 = time.perf_counter()
    peaks["solve"] = _peak_mb()
    it = int(opt.iterations())
    poses = (gtsam.utilities.extractPose3 if is3d else gtsam.utilities.extractPose2)(res)
    np.save(out, poses)
    return {"build": t1 - t0, "setup": 0.0, "analysis": t2 - t1, "solve": t3 - t2,
            "iterations": it, "user": t3 - t1, "peaks": peaks, "peak": peaks["solve"]}


def child_microlie(path: str, out: str, backend: str) -> dict:
    from microlie import SE2, SE3
    from microlie.optim import from_pose_graph
    from microlie.optim.core import compiled
    from microlie.optim.io.pose_graph import PoseGraph

    peaks = {"import": _peak_mb()}
    a = _arrays(path)
    peaks["load"] = _peak_mb()
    G = SE3 if int(a["dim"]) == 3 else SE2
    # imports are not timed (GTSAM's are not either; benchmarks/pose_graph.py --e2e times them):
    # a 3-pose solve with the same backend loads what this path imports on first use
    tiny = PoseGraph(G, ids=np.arange(3), poses=G.identity(3), i=np.array([0, 1]),
                     j=np.array([1, 2]), measurements=G.exp(np.full((2, G.dof), 0.1)),
                     information=np.broadcast_to(np.eye(G.dof), (2, G.dof, G.dof)))
    from_pose_graph(tiny)[0].optimize(linear_solver=backend, verbose=False)
    pg = PoseGraph(G, ids=a["ids"], poses=G(a["x0"]), i=a["i"], j=a["j"],
                   measurements=G(a["z"]), information=a["info"])
    t0 = time.perf_counter()
    fg, handle = from_pose_graph(pg)
    t1 = time.perf_counter()
    peaks["build"] = _peak_mb()
    prob = fg.problem()
    t2 = time.perf_counter()
    peaks["setup"] = _peak_mb()
    prob.analysed(backend)
    t3 = time.perf_counter()
    peaks["analysis"] = _peak_mb()
    r = fg.optimize(linear_solver=backend, verbose=False)
    t4 = time.perf_counter()
    peaks["solve"] = _peak_mb()
    np.save(out, np.asarray(r.values[handle].params))
    return {"build": t1 - t0, "setup": t2 - t1, "analysis": t3 - t2, "solve": t4 - t3,
            "iterations": r.iterations, "user": t4 - t0, "peaks": peaks, "peak": peaks["solve"],
            "timings": r.timings, "fast": compiled.available(), "linear": r.linear_solver}


# ---------------------------------------------------------------- the parent
def run(contender: str, graph: Path, python: str, gtsam_python: str) -> dict:
    """One fresh subprocess; its JSON line plus the process's wall time and the poses."""
    env = dict(os.environ)
    src = str(HERE.parent / "src")
    env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    if contender == "gtsam":
        exe = gtsam_python
    else:
        exe = python
        if contender.split(":")[0] == "numpy":
            env["MICROLIE_FAST"] = "0"
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "poses.npy")
        t0 = time.perf_counter()
        r = subprocess.run([exe, __file__, "_child", contender, str(graph), out], env=env,
                           capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if r.returncode:
            return {"error": (r.stderr.strip().splitlines() or ["?"])[-1], "wall": wall}
        res = json.loads(r.stdout.strip().splitlines()[-1])
        res["wall"] = wall
        res["poses"] = np.load(out)
    return res


def cost_of(pg, res: dict, contender: str) -> float:
    from microlie import SE2, SE3

    P = res["poses"]
    if contender != "gtsam":
        return float(pg.cost(pg.group(P)))
    if pg.group is SE2:
        return float(pg.cost(SE2.from_xy_theta(P[:, 0], P[:, 1], P[:, 2])))
    M = np.zeros((len(P), 4, 4))
    M[:, :3, :3] = P[:, :9].reshape(-1, 3, 3)
    M[:, :3, 3] = P[:, 9:12]
    M[:, 3, 3] = 1.0
    return float(pg.cost(SE3.from_matrix(M, normalize=True)))


def measure(pg, graph: Path, contenders: list[str], repeat: int, python: str,
            gtsam_python: str, log=print) -> dict:
    """``repeat`` interleaved rounds of every contender on one graph (no warm-up: each run is a
    fresh process, as a user's)."""
    runs: dict[str, list[dict]] = {c: [] for c in contenders}
    for rnd in range(repeat):
        for c in contenders:
            r = run(c, graph, python, gtsam_python)
            if "error" not in r:
                r["cost"] = cost_of(pg, r, c)
                del r["poses"]
            runs[c].append(r)
            log(f"  round {rnd + 1} {c}: " + (r["error"] if "error" in r else
                f"user {r['user']:.3f} s, {r['iterations']} it, peak {r['peak']:.0f} MB, "
                f"cost {r['cost']:.10g}"))
    return runs


def _med(runs: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def summary(runs: dict[str, list[dict]]) -> dict[str, dict]:
    """Medians per contender; per-round ratios to GTSAM of user time, per iteration, peak."""
    out = {}
    g = [r for r in runs.get("gtsam", []) if "error" not in r]
    for c, rs in runs.items():
        ok = [r for r in rs if "error" not in r]
        if not ok:
            out[c] = {"error": rs[0]["error"]}
            continue
        s = {k: _med(ok, k) for k in ("build", "setup", "analysis", "solve", "user", "wall",
                                      "peak")}
        s["iterations"] = ok[-1]["iterations"]
        s["cost"] = ok[-1]["cost"]
        s["per_it"] = statistics.median(r["solve"] / max(r["iterations"], 1) for r in ok)
        s["peaks"] = ok[-1]["peaks"]
        s["timings"] = ok[-1].get("timings")
        if g and len(g) == len(ok):
            s["ratio_user"] = [u["user"] / v["user"] for u, v in zip(ok, g, strict=True)]
            s["ratio_it"] = [(u["solve"] / max(u["iterations"], 1))
                             / (v["solve"] / max(v["iterations"], 1))
                             for u, v in zip(ok, g, strict=True)]
        out[c] = s
    return out


def _ratio(s: dict, key: str) -> str:
    r = s.get(key)
    if not r:
        return "-"
    return f"{statistics.median(r):.2f}x" + (f" ({min(r):.2f}-{max(r):.2f})" if len(r) > 1
                                             else "")


def table(label: str, summ: dict[str, dict], gtsam_cost: float | None) -> list[str]:
    lines = [f"### {label}", "",
             "| contender | user pays s | vs GTSAM | build s | setup s | analysis s | "
             "solve s (it) | per iteration s | vs GTSAM | setup + analysis / iteration | peak MB | "
             "peak vs GTSAM | process s | final cost (rel. to GTSAM) |",
             "|" + "---|" * 14]
    gpeak = summ.get("gtsam", {}).get("peak")
    for c, s in summ.items():
        if "error" in s:
            lines.append(f"| {c} | failed: {s['error']} |" + " |" * 12)
            continue
        rel = f" ({s['cost'] / gtsam_cost - 1:+.1e})" if gtsam_cost and c != "gtsam" else ""
        ana = "-" if c == "gtsam" else f"{(s['setup'] + s['analysis']) / s['per_it']:.2f}"
        pk = f"{s['peak'] / gpeak:.2f}x" if gpeak and c != "gtsam" else "-"
        lines.append(
            f"| {c} | {s['user']:.3f} | {_ratio(s, 'ratio_user')} | {s['build']:.3f} | "
            f"{s['setup']:.3f} | {s['analysis']:.3f} | {s['solve']:.3f} ({s['iterations']}) | "
            f"{s['per_it']:.4f} | {_ratio(s, 'ratio_it')} | {ana} | {s['peak']:.0f} | {pk} | "
            f"{s['wall']:.2f} | {s['cost']:.10g}{rel} |")
    return lines


def breakdown(label: str, summ: dict[str, dict]) -> list[str]:
    lines = [f"{label}: where the time and memory go (last round; seconds; peak RSS MB after "
             "each phase)", "",
             "| contender | linearize | assemble | factorize | solve | cost+retract | other | "
             "peak after import / load / build / setup / analysis (GTSAM: constructor) / solve |",
             "|---|---|---|---|---|---|---|---|"]
    for c, s in summ.items():
        if "error" in s:
            continue
        t = s.get("timings")
        pk = " / ".join(f"{v:.0f}" for v in s["peaks"].values())
        if t:
            lines.append(f"| {c} | {t['linearize']:.3f} | {t['assemble']:.3f} | "
                         f"{t['factorize']:.3f} | {t['solve']:.3f} | "
                         f"{t['cost'] + t['retract']:.3f} | {t['other']:.3f} | {pk} |")
        else:
            lines.append(f"| {c} | | | | | | | {pk} |")
    return lines


def auto_table(rows: list[tuple[str, int, int, dict]], avail: list[str] | None = None
               ) -> list[str]:
    """Which backend ``auto`` picks (with ``avail`` installed, default: this environment's)
    against the fastest measured one (with the compiled extra and without it), by user-pays
    time."""
    from microlie.optim import available_solvers, make_solver

    avail = available_solvers() if avail is None else avail
    lines = ["| case | unknowns (block) | fastest, compiled extra | fastest, MICROLIE_FAST=0 "
             "| auto, all installed | auto, default install |", "|---|---|---|---|---|---|"]
    for case, n, bs, summ in rows:
        cells = []
        for pre in ("fast", "numpy"):
            ok = {c.split(":")[1]: s["user"] for c, s in summ.items()
                  if c.startswith(pre + ":") and "error" not in s}
            cells.append(", ".join(f"{k} {v:.2f} s" for k, v in sorted(ok.items(),
                                                                     key=lambda x: x[1]))
                         or "-")
        picks = [make_solver("auto", n, bs, avail).name,
                 make_solver("auto", n, bs, ["scipy", "cholesky", "dense"]).name]
        lines.append(f"| {case} | {n} ({bs}) | {cells[0]} | {cells[1]} | {picks[0]} | "
                     f"{picks[1]} |")
    return lines


def main(argv=None) -> int:
    if sys.argv[1:2] == ["_child"]:
        c, path, out = sys.argv[2:5]
        res = child_gtsam(path, out) if c == "gtsam" else child_microlie(
            path, out, c.split(":")[1])
        print(json.dumps(res))
        return 0
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", nargs="+", default=["2d:1000", "2d:10000", "2d:100000",
                                                   "3d:100000"],
                    help="DIMd:POSES, e.g. 2d:100000 3d:100000")
    ap.add_argument("--contenders", nargs="+", default=None,
                    help="gtsam, fast:NAME, numpy:NAME (default: gtsam and every installed "
                         "backend of cholesky, qdldl, scipy, pardiso, with and without the "
                         "compiled extra)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--python", default=sys.executable, help="interpreter for microlie")
    ap.add_argument("--gtsam-python", default=GTSAM_PYTHON, help="interpreter with gtsam")
    ap.add_argument("--out", default=None, help="append the markdown to this file")
    args = ap.parse_args(argv)

    sys.path.insert(0, str(HERE))
    from symbolic import synthetic_pose_graph

    from microlie.optim import available_solvers

    avail = available_solvers()
    back = [b for b in ("cholesky", "qdldl", "scipy", "pardiso") if b in avail]
    contenders = args.contenders or (["gtsam"] + [f"fast:{b}" for b in back]
                                     + [f"numpy:{b}" for b in back])
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    head = [f"scaling.py, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
            f"cases {' '.join(args.cases)}, repeat {args.repeat} (interleaved, fresh process "
            f"per run, medians; ratios: median of the per-round ratios (range)), one BLAS "
            f"thread; `uptime` at the start: {load}", "",
            "Command: `" + " ".join(["OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python",
                                     "benchmarks/scaling.py", *sys.argv[1:]]) + "`", ""]
    print("\n".join(head), flush=True)
    lines = list(head)
    autos = []
    with tempfile.TemporaryDirectory() as tmp:
        for case in args.cases:
            dim, n = int(case.split("d:")[0]), int(float(case.split(":")[1]))
            pg = synthetic_pose_graph(n, dim)
            path = Path(tmp) / f"{case.replace(':', '_')}.npz"
            save_graph(pg, path)
            print(f"{case}: {pg.num_vertices} poses, {pg.num_edges} edges", file=sys.stderr,
                  flush=True)
            runs = measure(pg, path, contenders, args.repeat, args.python, args.gtsam_python,
                           log=lambda s: print(s, file=sys.stderr, flush=True))
            summ = summary(runs)
            gc = summ.get("gtsam", {}).get("cost")
            label = (f"{dim}-D, {n} poses, {pg.num_edges} edges, start cost "
                     f"{pg.cost():.6g}")
            block = table(label, summ, gc) + [""] + breakdown(label, summ) + [""]
            print("\n".join(block), flush=True)
            lines += block
            bs = pg.group.dof
            autos.append((f"{dim}-D {n}", (n - 1) * bs, bs, summ))
            path.unlink()
    end = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    block = ["`auto` against the fastest backend (user-pays medians):", ""] + auto_table(
        autos) + ["", f"`uptime` at the end: {end}", ""]
    print("\n".join(block), flush=True)
    lines += block
    if args.out:
        with open(args.out, "a") as f:
            f.write("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
