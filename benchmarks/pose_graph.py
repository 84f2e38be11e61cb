"""Pose-graph optimisation: microlie.optim against GTSAM 4.3 Levenberg-Marquardt, interleaved.

Run (benchmark environment, one command)::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src /work/bench-venv/bin/python benchmarks/pose_graph.py \
        --repeat 3 --out benchmarks/results/pose_graph-latest.md [--graphs ...]

Two passes, each interleaved with GTSAM: pass 1 in this process (with the compiled kernels
(``microlie._c``) when they were built: the group kernels and the SE(3) edge loop of
``microlie.optim.core.compiled``), every backend; pass 2 in a fresh process with ``MICROLIE_FAST=0``
(the default install: NumPy and SciPy only) on the default-install backends (skip it with
``--no-default-pass``).

For each graph both solvers start from the same poses (the file's vertices; ais2klinik from
microlie's chordal initialisation, kitti_00 from the odometry chain) and hold pose 0 (GTSAM: a
prior with sigma 1e-6, excluded from the reported cost; microlie: pose 0 fixed). GTSAM runs
``LevenbergMarquardtOptimizer(graph, initial, LevenbergMarquardtParams()).optimize()`` with the
default parameters; only ``optimize()`` is timed (the optimizer is constructed outside the timed
region). microlie runs ``FactorGraph.optimize()`` (LM, the same lambda schedule and default
tolerances as GTSAM); neither its graph and pattern (``FactorGraph.problem()``) nor the linear
solver's symbolic analysis (once per problem and backend, ``Problem.analysed``; GTSAM's ordering
runs in its untimed constructor) is timed: both are printed, as "setup" and "analysis". Runs
alternate GTSAM, microlie-backend-1, microlie-backend-2, ... ``--repeat`` times after one
warm-up; the table gives medians, the ratio of medians, and the spread of the per-round ratios.
Every BLAS/LAPACK library is held to one thread (GTSAM's wheel is single-threaded).
Costs are GTSAM's ``0.5 sum r^T Omega r`` over the file's edges, both evaluated by microlie's
``PoseGraph.cost`` on the returned poses.

Backends: ``cholesky`` (our NumPy/LAPACK Cholesky) and ``scipy`` (SuperLU) are what
``pip install microlie`` has; ``pardiso`` needs ``microlie[mkl]``, ``qdldl`` ``microlie[sparse]``.
The summary table gives the ratio of ``linear_solver="auto"``'s pick, once with everything of this
environment installed and once restricted to the default install.

Timed as a user pays it (issue 20), two more sections, each run in fresh subprocesses::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src /work/bench-venv/bin/python benchmarks/pose_graph.py \
        --user-pays --e2e --no-solve-pass --repeat 3 --python /work/main/.venv/bin/python \
        --out benchmarks/results/pose_graph-latest.md

``--user-pays``: the children of ``scaling.py`` on each graph (same start as above, saved as
arrays): GTSAM's optimizer constructor + ``optimize()`` against microlie's graph construction +
pattern + ordering and symbolic analysis + solve, each contender in its own process, with
(``fast:``) and without (``numpy:``, ``MICROLIE_FAST=0``) the compiled extra, every backend
installed in ``--python``'s environment; time per iteration and peak RSS too.
``--e2e``: ``microlie optimize FILE --json -o OUT --init file`` against ``gtsam_optimize.py
FILE OUT`` (the GTSAM script doing the same: read, prior on the first pose, LM from the file's
vertices, write), process start to exit, wall time and the process's peak RSS (``wait4``),
microlie's sources byte-compiled first (``compileall``, as ``pip install`` does);
microlie twice: everything of ``--python``'s environment installed (the compiled extra,
qdldl), and the default install (``--gtsam-python``'s environment, which has no optional
backend, with ``MICROLIE_FAST=0``). Rounds interleave the contenders.
"""

from __future__ import annotations

import os

for _v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from microlie import SE2  # noqa: E402
from microlie.optim import available_solvers, from_pose_graph, make_solver  # noqa: E402
from microlie.optim.core import compiled  # noqa: E402
from microlie.optim.init import initialize  # noqa: E402
from microlie.optim.io.g2o import read_g2o  # noqa: E402

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "pose_graph"
GRAPHS = {  # name: (file, start)
    "sphere2500": ("sphere2500.g2o", "file"),
    "parking-garage": ("parking-garage.g2o", "file"),
    "M3500": ("input_M3500_g2o.g2o", "file"),
    "ais2klinik": ("ais2klinik.g2o", "chordal"),
    "kitti_00": ("kitti_00.g2o", "odometry"),
}


def gtsam_problem(gtsam, path: Path, pg, X0):
    is3d = pg.group is not SE2
    graph, _ = gtsam.readG2o(str(path), is3d)
    init = gtsam.Values()
    p = np.asarray(X0.params)
    for k, key in enumerate(pg.ids.tolist()):
        if is3d:
            x, y, z, qx, qy, qz, qw = p[k]
            init.insert(key, gtsam.Pose3(gtsam.Rot3.Quaternion(qw, qx, qy, qz),
                                         np.array([x, y, z])))
        else:
            init.insert(key, gtsam.Pose2(p[k, 0], p[k, 1], np.arctan2(p[k, 3], p[k, 2])))
    k0 = int(pg.ids[0])
    if is3d:
        graph.add(gtsam.PriorFactorPose3(k0, init.atPose3(k0),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(6, 1e-6))))
    else:
        graph.add(gtsam.PriorFactorPose2(k0, init.atPose2(k0),
                                         gtsam.noiseModel.Diagonal.Sigmas(np.full(3, 1e-6))))
    return graph, init


def gtsam_poses(gtsam, pg, values):
    G = pg.group
    rows = []
    for key in pg.ids.tolist():
        if G is SE2:
            P = values.atPose2(key)
            rows.append([P.x(), P.y(), np.cos(P.theta()), np.sin(P.theta())])
        else:
            P = values.atPose3(key)
            q = P.rotation().toQuaternion()
            t = P.translation()
            rows.append([t[0], t[1], t[2], q.x(), q.y(), q.z(), q.w()])
    return G(np.array(rows), normalize=True)


def run_gtsam(gtsam, graph, init):
    opt = gtsam.LevenbergMarquardtOptimizer(graph, init, gtsam.LevenbergMarquardtParams())
    t0 = time.perf_counter()
    res = opt.optimize()
    return time.perf_counter() - t0, res, opt.iterations()


def measure(args, backends, lines_out: list) -> list[dict]:
    """Interleaved runs of GTSAM and microlie on each graph: one dict per graph."""
    import gtsam

    out = []
    for name in args.graphs:
        fname, start = GRAPHS[name]
        path = DATA / fname
        pg = read_g2o(path)
        X0 = initialize(pg, start)
        fg, handle = from_pose_graph(pg, X0)
        t0 = time.perf_counter()
        prob = fg.problem()  # pattern and summing matrix, once per graph (not timed)
        setup = time.perf_counter() - t0
        analysis = {}
        for b in backends:  # the symbolic analysis, once per problem and backend (not timed)
            t0 = time.perf_counter()
            prob.analysed(b)
            analysis[b] = time.perf_counter() - t0
        ggraph, ginit = gtsam_problem(gtsam, path, pg, X0)
        t_g, t_us = [], {b: [] for b in backends}
        res_us, res_g = {}, None
        for rnd in range(args.repeat + 1):
            tg, gres, git = run_gtsam(gtsam, ggraph, ginit)
            for b in backends:
                r = fg.optimize(linear_solver=b, verbose=False)
                if rnd:
                    t_us[b].append(r.time_s)
                res_us[b] = r
            if rnd:
                t_g.append(tg)
            res_g = (gres, git)
        gcost = pg.cost(gtsam_poses(gtsam, pg, res_g[0]))
        picks = [make_solver("auto", prob.size, prob.block_size).name,
                 make_solver("auto", prob.size, prob.block_size,
                             available=["scipy", "cholesky", "dense"]).name]
        out.append({
            "name": name, "start": start, "setup": setup, "analysis": analysis, "t_g": t_g,
            "git": res_g[1], "gcost": gcost, "t_us": t_us, "picks": picks,
            "costs": {b: (pg.cost(r.values[handle]), r.iterations) for b, r in res_us.items()},
            "timings": {b: (r.timings, r.time_s) for b, r in res_us.items()},
        })
        lines_out.append(f"{name}: done")
        print(f"{name}: done", file=sys.stderr, flush=True)
    return out


def table(results: list[dict], backends: list[str], label: str) -> list[str]:
    cols = " | ".join(f"{b} ms (ratio, spread)" for b in backends)
    lines = [f"| graph | start | GTSAM LM ms (it) | {cols} | GTSAM cost | "
             + " | ".join(f"{b} cost (it)" for b in backends) + " |",
             "|" + "---|" * (4 + 2 * len(backends))]
    for g in results:
        mg = statistics.median(g["t_g"])
        cells, costs = [], []
        for b in backends:
            mu = statistics.median(g["t_us"][b])
            ratios = [u / t for u, t in zip(g["t_us"][b], g["t_g"], strict=True)]
            cells.append(f"{mu * 1e3:.0f} ({mu / mg:.2f}x, {min(ratios):.2f}-{max(ratios):.2f})")
            c, it = g["costs"][b]
            costs.append(f"{c:.10g} ({it})")
        lines.append(f"| {g['name']} | {g['start']} | {mg * 1e3:.0f} ({g['git']}) | "
                     + " | ".join(cells) + f" | {g['gcost']:.10g} | " + " | ".join(costs) + " |")
    return [f"{label}:", ""] + lines


def breakdown(results: list[dict], label: str) -> list[str]:
    lines = [f"{label}:", "",
             "| graph | backend | linearize | assemble | factorize | solve | cost+retract | "
             "other | total | setup (not timed) | analysis (not timed) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for g in results:
        for b, (t, tot) in g["timings"].items():
            lines.append(
                f"| {g['name']} | {b} | {t['linearize'] * 1e3:.1f} | {t['assemble'] * 1e3:.1f}"
                f" | {t['factorize'] * 1e3:.1f} | {t['solve'] * 1e3:.1f} | "
                f"{(t['cost'] + t['retract']) * 1e3:.1f} | {t['other'] * 1e3:.1f} | "
                f"{tot * 1e3:.1f} | {g['setup'] * 1e3:.1f} | "
                f"{g['analysis'][b] * 1e3:.1f} |")
    return lines


def ratio(g: dict, backend: str) -> str:
    if backend not in g["t_us"]:
        return f"{backend} (not run)"
    return f"{backend} {statistics.median(g['t_us'][backend]) / statistics.median(g['t_g']):.2f}x"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--graphs", nargs="*", default=list(GRAPHS), choices=list(GRAPHS))
    ap.add_argument("--backends", nargs="*", default=None,
                    help="microlie linear solvers (default: cholesky, pardiso, qdldl, scipy "
                         "where installed)")
    ap.add_argument("--no-default-pass", action="store_true",
                    help="skip the second pass without the compiled extra (MICROLIE_FAST=0)")
    ap.add_argument("--child-json", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--user-pays", action="store_true",
                    help="also time construction + analysis + solve, one process per run")
    ap.add_argument("--e2e", action="store_true",
                    help="also time `microlie optimize FILE --json` against a GTSAM script")
    ap.add_argument("--no-solve-pass", action="store_true",
                    help="skip the in-process solve-only passes")
    ap.add_argument("--python", default=sys.executable,
                    help="interpreter for microlie's subprocesses (--user-pays, --e2e)")
    ap.add_argument("--gtsam-python", default=sys.executable,
                    help="interpreter with gtsam and no optional microlie backend")
    ap.add_argument("--out", default=None, help="also write the markdown table to this file")
    args = ap.parse_args(argv)

    avail = available_solvers()
    backends = args.backends or [b for b in ("cholesky", "pardiso", "qdldl", "scipy")
                                 if b in avail]
    if args.child_json:  # the MICROLIE_FAST=0 pass, run by the parent in a fresh process
        res = measure(args, backends, [])
        Path(args.child_json).write_text(json.dumps(res))
        return 0
    if args.no_solve_pass:
        load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
        lines = [f"pose_graph.py, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
                 f"repeat {args.repeat}, one BLAS thread; `uptime` at the start: {load}", "",
                 "Command: `OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python benchmarks/"
                 "pose_graph.py " + " ".join(sys.argv[1:]) + "`"]
        print("\n".join(lines), flush=True)
    else:
        lines = solve_passes(args, backends)
    if args.user_pays:
        lines += [""] + user_pays(args)
    if args.e2e:
        lines += [""] + end_to_end(args)
    if args.user_pays or args.e2e:
        load_end = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
        lines += ["", f"`uptime` at the end: {load_end}"]
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


def solve_passes(args, backends: list[str]) -> list[str]:
    """The in-process passes (solve timed alone)."""
    fast = compiled.available()
    load = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    head = (f"pose_graph.py, {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, "
            f"repeat {args.repeat}, one BLAS thread; compiled kernels (microlie._c): "
            f"{'on' if fast else 'OFF'}; `uptime` at the start: {load}")
    print(head, flush=True)
    res = measure(args, backends, [])
    lines = [head, ""]
    lines += table(res, backends, f"Pass 1, {'with' if fast else 'without'} the compiled "
                                  "extra, every backend of this environment")
    default_res = None
    default_backends = [b for b in ("cholesky", "scipy") if b in backends]
    if not args.no_default_pass and fast and default_backends:
        with tempfile.TemporaryDirectory() as tmp:
            js = Path(tmp) / "default.json"
            env = dict(os.environ, MICROLIE_FAST="0")
            cmd = [sys.executable, __file__, "--repeat", str(args.repeat), "--graphs",
                   *args.graphs, "--backends", *default_backends, "--child-json", str(js)]
            subprocess.run(cmd, env=env, check=True)
            default_res = json.loads(js.read_text())
        lines += [""] + table(default_res, default_backends,
                              "Pass 2, MICROLIE_FAST=0 (the default install: NumPy and SciPy "
                              "only), in a fresh process, again interleaved with GTSAM")
    load_end = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    lines += ["", f"`uptime` at the end: {load_end}", "",
              "Ratio to GTSAM (median time) of linear_solver='auto': with everything of this "
              "environment installed, the compiled extra included (goal <= 0.5x); the default "
              "install, NumPy and SciPy only, without the extra (goal <= 1.0x); the default "
              "install's backend with the compiled extra (issue 11: <= 0.5x):", "",
              "| graph | auto, all installed | auto, default install | default backend + extra |",
              "|---|---|---|---|"]
    for k, g in enumerate(res):
        best, dflt = g["picks"]
        # auto's default-install pick without the extra (MICROLIE_FAST=0) can differ
        d = ratio(default_res[k], default_res[k]["picks"][1]) if default_res else (
            ratio(g, dflt) + (" (extra on)" if fast else ""))
        lines.append(f"| {g['name']} | {ratio(g, best)} | {d} | "
                     f"{ratio(g, dflt) if fast else '(extra not installed)'} |")
    note = ("Breakdown of microlie's last run (ms): linearise (residuals, Jacobians and block "
            "products; with the compiled extra the SE(3) edges' scatter into the pattern is "
            "inside it) / assemble (the sum of the NumPy-path factors into the pattern) / "
            "factorise / solve / cost (trial points; on the NumPy path also the whitened "
            "Jacobians kept at the first trial of each iteration for the next linearisation) / "
            "other (damping, bookkeeping); 'setup' is the graph's pattern and summing matrix, "
            "built once per graph, and 'analysis' the linear solver's symbolic analysis, once "
            "per problem and backend, both before the timed solve (like GTSAM's optimizer "
            "constructor, which is not timed either)")
    lines += [""] + breakdown(res, f"{note}; pass 1")
    if default_res:
        lines += [""] + breakdown(default_res, "Pass 2 (MICROLIE_FAST=0)")
    print("\n".join(lines[2:]))
    return lines


def user_pays(args) -> list[str]:
    """Construction + analysis + solve against GTSAM's constructor + optimize(), one fresh
    process per run (``scaling.py``'s children)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import scaling

    probe = subprocess.run([args.python, "-c", "from microlie.optim import available_solvers;"
                            "print(' '.join(available_solvers()))"], capture_output=True,
                           text=True, check=True, env=dict(os.environ, PYTHONPATH=str(
                               Path(__file__).resolve().parents[1] / "src")))
    avail = probe.stdout.split()
    back = [b for b in ("cholesky", "qdldl", "scipy", "pardiso") if b in avail]
    if args.backends:  # --backends limits this pass too (it was ignored here)
        missing = [b for b in args.backends if b not in avail]
        if missing:
            raise SystemExit(f"--backends: {missing} not installed for {args.python}")
        back = [b for b in back if b in args.backends]
    contenders = (["gtsam"] + [f"fast:{b}" for b in back] + [f"numpy:{b}" for b in back])
    lines = ["## Timed as a user pays it (graph construction, pattern, ordering, symbolic "
             "analysis, solve; GTSAM: optimizer constructor + optimize())", "",
             f"Fresh process per run, {args.repeat} interleaved rounds, medians; ratios: median "
             "of the per-round ratios (range). 'build' (microlie: `from_pose_graph`; GTSAM: its "
             "Python loop building the graph, not counted) / 'setup' (`FactorGraph.problem()`) "
             "/ 'analysis' (`Problem.analysed`: ordering + symbolic; GTSAM: the optimizer "
             "constructor) / 'solve'. Peak = the process's own peak RSS (VmHWM).", ""]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.graphs:
            fname, start = GRAPHS[name]
            pg = read_g2o(DATA / fname)
            pg0 = pg.replace(poses=initialize(pg, start))
            npz = Path(tmp) / f"{name}.npz"
            scaling.save_graph(pg0, npz)
            print(f"{name}: user pays", file=sys.stderr, flush=True)
            runs = scaling.measure(pg, npz, contenders, args.repeat, args.python,
                                   args.gtsam_python,
                                   log=lambda s: print(s, file=sys.stderr, flush=True))
            summ = scaling.summary(runs)
            label = f"{name} ({start} start, {pg.num_vertices} poses, {pg.num_edges} edges)"
            block = (scaling.table(label, summ, summ.get("gtsam", {}).get("cost")) + [""]
                     + scaling.breakdown(label, summ) + [""])
            print("\n".join(block), flush=True)
            lines += block
            bs = pg.group.dof
            rows.append((name, (pg.num_vertices - 1) * bs, bs, summ))
    lines += ["`auto` against the fastest backend (user-pays medians; the picks are this "
              "checkout's rule with everything of --python's environment, and restricted to the "
              "default install):", ""] + scaling.auto_table(rows, avail)
    return lines


#: Started by _timed_process: spawns the command, waits for it, writes [wall s, peak RSS MB,
#: exit code] to argv[1]. A small process in between because Linux's ru_maxrss of a child is at
#: least its parent's peak RSS (kept over fork and exec): this one's is a few MB.
_SPAWN = ("import json, os, sys, time\n"
          "t = time.perf_counter()\n"
          "pid = os.posix_spawn(sys.argv[2], sys.argv[2:], os.environ)\n"
          "_, st, ru = os.wait4(pid, 0)\n"
          "w = time.perf_counter() - t\n"
          "open(sys.argv[1], 'w').write(json.dumps([w, ru.ru_maxrss / 1024, "
          "os.waitstatus_to_exitcode(st)]))\n")


def _timed_process(cmd: list[str], env: dict) -> tuple[float, float, str]:
    """Wall time from start to exit, the process's peak RSS (MB), its stdout."""
    with tempfile.TemporaryDirectory() as tmp:
        rep = Path(tmp) / "rusage.json"
        r = subprocess.run([sys.executable, "-S", "-c", _SPAWN, str(rep), *cmd], env=env,
                           capture_output=True, text=True)
        wall, peak, code = json.loads(rep.read_text())
        if code or r.returncode:
            raise RuntimeError(f"{cmd} exited with {code}: {r.stderr[-500:]}")
        return wall, peak, r.stdout


def end_to_end(args) -> list[str]:
    """``microlie optimize FILE --json`` against the GTSAM script, process start to exit."""
    src = str(Path(__file__).resolve().parents[1] / "src")
    script = str(Path(__file__).resolve().parent / "gtsam_optimize.py")
    env = dict(os.environ, PYTHONPATH=src)
    env.pop("MICROLIE_FAST", None)
    # the bytecode of microlie's sources, as ``pip install`` writes it for every package (GTSAM,
    # NumPy and SciPy have theirs): without it, and with PYTHONDONTWRITEBYTECODE set, each
    # process would compile microlie's modules again (some 0.18 s of CPU)
    for exe in {args.python, args.gtsam_python}:
        subprocess.run([exe, "-m", "compileall", "-q", src], check=True, env=env,
                       stdout=subprocess.DEVNULL)
    # with PYTHONPATH=src, this checkout's compiled code is the one built in place (pip
    # install -e . or python setup.py build_ext --inplace put it in src/microlie/_c)
    env_all = env
    contenders = {
        "GTSAM script": (args.gtsam_python, env, "gtsam"),
        "microlie (pip install: compiled code)": (args.python, env_all, "cli"),
        "microlie, no compiled code": (args.gtsam_python, dict(env, MICROLIE_FAST="0"), "cli"),
    }
    lines = ["## End to end: `microlie optimize FILE --json -o OUT --init file` against "
             "`gtsam_optimize.py FILE OUT`", "",
             f"Process start to exit (import, read, solve, write), {args.repeat} interleaved "
             "rounds after one warm-up round (file cache), medians; ratio: median of the "
             "per-round ratios to the GTSAM script (range); peak = the process's ru_maxrss "
             "(wait4 in a small launcher process, so no parent's peak is inherited); "
             "microlie's sources byte-compiled first, as pip install does. 'pip "
             "install': --python's environment with the compiled code that pip install builds "
             "(and qdldl); 'no compiled code': numpy + scipy only, MICROLIE_FAST=0 (an install "
             "without a C compiler). Both start from the file's vertices.", "",
             "| graph | contender | wall s | vs GTSAM | peak MB | vs GTSAM | final cost (it) |",
             "|---|---|---|---|---|---|---|"]
    with tempfile.TemporaryDirectory() as tmp:
        out = str(Path(tmp) / "out.g2o")
        for name in args.graphs:
            if GRAPHS[name][1] == "odometry":  # no vertices in the file: no common start
                lines.append(f"| {name} | (no vertices in the file: not run) | | | | | |")
                continue
            path = str(DATA / GRAPHS[name][0])
            res: dict[str, list] = {c: [] for c in contenders}
            for rnd in range(args.repeat + 1):
                for c, (exe, e, kind) in contenders.items():
                    cmd = ([exe, script, path, out] if kind == "gtsam" else
                           [exe, "-m", "microlie.cli", "optimize", path, "--json", "-o", out,
                            "--init", "file", "-q"])
                    wall, peak, text = _timed_process(cmd, e)
                    rep = json.loads(text.strip().splitlines()[-1])
                    if rnd:
                        res[c].append((wall, peak, rep["final_cost"], rep["iterations"]))
                    print(f"  {name} e2e round {rnd} {c}: {wall:.3f} s {peak:.0f} MB",
                          file=sys.stderr, flush=True)
            g = res["GTSAM script"]
            for c, rs in res.items():
                w = statistics.median(r[0] for r in rs)
                pk = statistics.median(r[1] for r in rs)
                if c == "GTSAM script":
                    rw = rp = "-"
                else:
                    qw = [a[0] / b[0] for a, b in zip(rs, g, strict=True)]
                    qp = [a[1] / b[1] for a, b in zip(rs, g, strict=True)]
                    rw = f"{statistics.median(qw):.2f}x ({min(qw):.2f}-{max(qw):.2f})"
                    rp = f"{statistics.median(qp):.2f}x ({min(qp):.2f}-{max(qp):.2f})"
                lines.append(f"| {name} | {c} | {w:.3f} | {rw} | {pk:.0f} | {rp} | "
                             f"{rs[-1][2]:.10g} ({rs[-1][3]}) |")
            print("\n".join(lines[-3:]), flush=True)
    return lines


if __name__ == "__main__":
    sys.exit(main())
