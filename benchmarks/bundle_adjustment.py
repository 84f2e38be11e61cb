"""Bundle adjustment on BAL problem-49-7776: microlie against Ceres C++, GTSAM and SciPy.

Run (bench venv: gtsam 4.3; Debian's libceres-dev, cmake and g++ for the Ceres reference):

    PYTHONPATH=src /work/bench-venv/bin/python benchmarks/bundle_adjustment.py [--repeat 3]
        [--file ../shared/data/bal/problem-49-7776-pre.txt] [--skip-scipy] [--skip-gtsam]

Every contender starts from the file's values and runs single-threaded; the runs are
interleaved (one of each per round) and the table shows medians (min-max) and the ratio to
microlie. Contenders:

* microlie: ``microlie.optim.sfm.bundle.bundle_adjust`` (BAL model, Ceres' LM rules, dense Schur),
time
  of ``bundle_adjust`` (includes the sparsity analysis, excludes reading the file);
* Ceres 2.1 C++ (``benchmarks/ceres_bal/ceres_bal.cc``, built here with cmake against
  ``libceres-dev``): autodiff BAL cost, LM, SPARSE_SCHUR and DENSE_SCHUR, one thread; time
  ``Summary::total_time_in_seconds`` (excludes reading the file);
* GTSAM 4.3: ``GeneralSFMFactorCal3Bundler`` with unit noise, ``LevenbergMarquardtOptimizer``
  with ``LevenbergMarquardtParams.CeresDefaults()`` (max iterations raised from 50 to 100),
  time of ``optimize()``. GTSAM drops points behind the camera, so its cost is compared with
  microlie's ``behind="drop"`` objective (optimum 13308.4836), not 13344.3184;
* SciPy Cookbook recipe (written here from its formulas): ``least_squares`` with
  ``jac_sparsity``, ``x_scale="jac"``, ``ftol=1e-4``, ``method="trf"`` (2-point finite
  differences as in the recipe).

Also prints microlie's per-iteration breakdown (where the time goes).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # single-threaded like the others
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DEFAULT_FILE = ROOT / ".." / "shared" / "data" / "bal" / "problem-49-7776-pre.txt"


# ---------------------------------------------------------------------------- contenders

def run_microlie(path: Path, behind: str = "evaluate") -> dict:
    from microlie.optim.io.bal import read_bal
    from microlie.optim.sfm.bundle import bundle_adjust

    p = read_bal(path)
    r = bundle_adjust(p, behind=behind)
    return {"time_s": r.time_s, "initial_cost": r.initial_cost, "final_cost": r.final_cost,
            "iterations": r.iterations, "accepted": r.successful_steps - 1,
            "timings": r.timings, "message": r.message}


def run_engine(path: Path) -> dict:
    """The one engine: bundle_graph (FactorGraph with ReprojectionFactor) + TrustRegion +
    linear_solver="schur"; timed as a user pays it (graph construction and solve)."""
    import time

    from microlie.optim import TrustRegion, bundle_graph
    from microlie.optim.io.bal import read_bal

    p = read_bal(path)
    t0 = time.perf_counter()
    bg = bundle_graph(p)
    r = bg.graph.optimize(solver=TrustRegion(), linear_solver="schur", gauge="none")
    t = time.perf_counter() - t0
    return {"time_s": t, "initial_cost": r.initial_cost, "final_cost": r.final_cost,
            "iterations": r.iterations, "accepted": r.accepted_steps,
            "timings": {**r.timings, "build": t - r.time_s}, "message": r.message}


def build_ceres() -> Path | None:
    if shutil.which("cmake") is None:
        print("cmake not found: Ceres C++ skipped", file=sys.stderr)
        return None
    build = HERE / "ceres_bal" / "build"
    exe = build / "ceres_bal"
    src = HERE / "ceres_bal" / "ceres_bal.cc"
    if exe.exists() and exe.stat().st_mtime > src.stat().st_mtime:
        return exe
    build.mkdir(parents=True, exist_ok=True)
    try:
        subprocess.run(["cmake", "-S", str(HERE / "ceres_bal"), "-B", str(build),
                        "-DCMAKE_BUILD_TYPE=Release"], check=True, capture_output=True)
        subprocess.run(["cmake", "--build", str(build)], check=True, capture_output=True)
    except subprocess.CalledProcessError as e:
        print("building the Ceres reference failed (is libceres-dev installed?):\n"
              + e.stderr.decode()[-2000:], file=sys.stderr)
        return None
    return exe


def run_ceres(exe: Path, path: Path, solver: str) -> dict:
    out = subprocess.run([str(exe), str(path), solver, "100"], check=True, capture_output=True,
                         text=True).stdout
    d = json.loads(out.strip().splitlines()[-1])
    return {"time_s": d["solver_time_s"], "initial_cost": d["initial_cost"],
            "final_cost": d["final_cost"], "iterations": d["iterations"],
            "accepted": d["successful_steps"] - 1, "message": d["termination"]}


def run_gtsam(path: Path) -> dict:
    import gtsam
    from gtsam.symbol_shorthand import C, P

    sfm = gtsam.SfmData.FromBalFile(str(path))
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    graph = gtsam.NonlinearFactorGraph()
    for j in range(sfm.numberTracks()):
        track = sfm.track(j)
        for m in range(track.numberMeasurements()):
            i, uv = track.measurement(m)
            graph.add(gtsam.GeneralSFMFactorCal3Bundler(uv, noise, C(i), P(j)))
    initial = gtsam.Values()
    for i in range(sfm.numberCameras()):
        initial.insert(C(i), sfm.camera(i))
    for j in range(sfm.numberTracks()):
        initial.insert(P(j), sfm.track(j).point3())
    params = gtsam.LevenbergMarquardtParams.CeresDefaults()
    params.setMaxIterations(100)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    e0 = graph.error(initial)
    t0 = time.perf_counter()
    result = opt.optimize()
    dt = time.perf_counter() - t0
    return {"time_s": dt, "initial_cost": e0, "final_cost": graph.error(result),
            "iterations": opt.iterations(), "message": "gtsam (iterations)"}


def run_scipy(path: Path) -> dict:
    """The SciPy Cookbook's large-scale bundle adjustment, from its formulas."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    from microlie.optim.io.bal import read_bal

    p = read_bal(path)
    nc, npt = p.n_cameras, p.n_points
    ci, pi, uv = p.camera_index, p.point_index, p.observations

    def rotate(X, w):
        th = np.linalg.norm(w, axis=1)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.nan_to_num(w / th)
        d = np.sum(X * k, axis=1)[:, None]
        c, s = np.cos(th), np.sin(th)
        return c * X + s * np.cross(k, X) + d * (1 - c) * k

    def fun(x):
        cams = x[:9 * nc].reshape(nc, 9)
        X = x[9 * nc:].reshape(npt, 3)
        c = cams[ci]
        P = rotate(X[pi], c[:, :3]) + c[:, 3:6]
        q = -P[:, :2] / P[:, 2, None]
        r2 = np.sum(q * q, axis=1)
        s = c[:, 6] * (1 + c[:, 7] * r2 + c[:, 8] * r2 * r2)
        return (q * s[:, None] - uv).ravel()

    m = 2 * len(ci)
    A = lil_matrix((m, 9 * nc + 3 * npt), dtype=int)
    rows = np.arange(len(ci))
    for k in range(9):
        A[2 * rows, ci * 9 + k] = 1
        A[2 * rows + 1, ci * 9 + k] = 1
    for k in range(3):
        A[2 * rows, 9 * nc + pi * 3 + k] = 1
        A[2 * rows + 1, 9 * nc + pi * 3 + k] = 1
    x0 = np.concatenate([p.cameras.ravel(), p.points.ravel()])
    f0 = fun(x0)
    t0 = time.perf_counter()
    res = least_squares(fun, x0, jac_sparsity=A, x_scale="jac", ftol=1e-4, method="trf")
    dt = time.perf_counter() - t0
    return {"time_s": dt, "initial_cost": 0.5 * float(f0 @ f0), "final_cost": float(res.cost),
            "iterations": int(res.nfev), "message": "scipy (function evaluations)"}


# ---------------------------------------------------------------------------- main

def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", type=Path, default=DEFAULT_FILE)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-scipy", action="store_true")
    ap.add_argument("--skip-gtsam", action="store_true")
    args = ap.parse_args(argv)
    path = args.file.resolve()
    contenders: dict[str, object] = {"microlie": lambda: run_microlie(path),
                                     "microlie engine (graph, trust-region, schur)":
                                     lambda: run_engine(path)}
    exe = build_ceres()
    if exe is not None:
        contenders["Ceres C++ SPARSE_SCHUR"] = lambda: run_ceres(exe, path, "SPARSE_SCHUR")
        contenders["Ceres C++ DENSE_SCHUR"] = lambda: run_ceres(exe, path, "DENSE_SCHUR")
    if not args.skip_gtsam:
        try:
            import gtsam  # noqa: F401

            contenders["microlie behind=drop"] = lambda: run_microlie(path, "drop")
            contenders["GTSAM 4.3 LM CeresDefaults"] = lambda: run_gtsam(path)
        except ImportError:
            print("gtsam not installed: skipped", file=sys.stderr)
    if not args.skip_scipy:
        contenders["SciPy least_squares (Cookbook)"] = lambda: run_scipy(path)
    runs: dict[str, list[dict]] = {k: [] for k in contenders}
    for rnd in range(args.repeat):
        for name, fn in contenders.items():
            runs[name].append(fn())  # type: ignore[operator]
            print(f"round {rnd + 1} {name}: {runs[name][-1]['time_s']:.3f} s", file=sys.stderr)
    load = os.getloadavg()
    ref = statistics.median(r["time_s"] for r in runs["microlie"])
    print(f"\n## Bundle adjustment, {path.name} (load average {load[0]:.2f} {load[1]:.2f} "
          f"{load[2]:.2f}, {args.repeat} interleaved rounds)\n")
    print("| solver | time s median (min-max) | time / microlie | accepted steps | initial cost "
          "| final cost |")
    print("|---|---|---|---|---|---|")
    for name, rs in runs.items():
        ts = [r["time_s"] for r in rs]
        med = statistics.median(ts)
        print(f"| {name} | {med:.3f} ({min(ts):.3f}-{max(ts):.3f}) | {med / ref:.2f} | "
              f"{rs[0].get('accepted', rs[0]['iterations'])} | {rs[0]['initial_cost']:.2f} | "
              f"{rs[0]['final_cost']:.4f} |")
    med = {k: statistics.median(r["time_s"] for r in rs) for k, rs in runs.items()}
    print()
    for k in ("Ceres C++ SPARSE_SCHUR", "Ceres C++ DENSE_SCHUR"):
        if k in med:
            print(f"- microlie / {k}: {med['microlie'] / med[k]:.2f} (goal: at most 2)")
    if "GTSAM 4.3 LM CeresDefaults" in med:
        g = med["GTSAM 4.3 LM CeresDefaults"]
        print(f"- GTSAM / microlie behind=drop (same objective): "
              f"{g / med['microlie behind=drop']:.2f}; GTSAM / microlie: "
              f"{g / med['microlie']:.2f} (goal: at least 2)")
    tm = runs["microlie"][-1]["timings"]
    it = max(runs["microlie"][-1]["iterations"], 1)
    print("\nmicrolie time breakdown (last round), ms per iteration "
          f"({it} iterations):\n")
    print("| part | ms / iteration | share |")
    print("|---|---|---|")
    total = tm["total"]
    for k in ("linearize", "schur_form", "reduced_solve", "back_substitution", "evaluate",
              "step", "structure"):
        print(f"| {k} | {1e3 * tm[k] / it:.1f} | {100 * tm[k] / total:.0f}% |")
    eng = runs["microlie engine (graph, trust-region, schur)"][-1]
    it = max(eng["iterations"], 1)
    print(f"\nengine time breakdown (last round), ms per iteration ({it} iterations; "
          f"engine / bundle_adjust {med['microlie engine (graph, trust-region, schur)'] / ref:.2f}"
          f"):\n")
    print("| part | ms / iteration | share |")
    print("|---|---|---|")
    total = sum(v for v in eng["timings"].values() if isinstance(v, float))
    for k, v in eng["timings"].items():
        if isinstance(v, float):
            print(f"| {k} | {1e3 * v / it:.1f} | {100 * v / total:.0f}% |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
