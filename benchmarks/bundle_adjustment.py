"""Bundle adjustment on BAL problem-49-7776 and synthetic street scenes: microlie against Ceres
C++, GTSAM and SciPy.

Run (bench venv: gtsam 4.3; Debian's libceres-dev, cmake and g++ for the Ceres reference):

    PYTHONPATH=src /work/bench-venv/bin/python benchmarks/bundle_adjustment.py [--repeat 3]
        [--file ../shared/data/bal/problem-49-7776-pre.txt] [--skip-scipy] [--skip-gtsam]
        [--street 300 1000] [--skip-file] [--seed 0]

``--street N ...`` adds one seeded synthetic street scene per camera count (:func:`street_scene`:
a forward-looking camera every metre along a 2-D street, landmarks on the two facades and the
ground, each seen from the cameras 3-45 m behind it: a banded camera graph, unlike
``synthetic_scene``'s every-camera-sees-every-point cloud), written as a BAL file in a
temporary directory and run like the file (microlie's ``bundle_adjust`` and Ceres
SPARSE_SCHUR; GTSAM, SciPy and Ceres DENSE_SCHUR only for ``--file``); ``--skip-file`` runs only
the street scenes.

Every contender starts from the file's values and runs single-threaded; the runs are
interleaved (one of each per round) and the table shows medians (min-max) and the ratio to
microlie. Contenders:

* microlie: ``microlie.optim.sfm.bundle.bundle_adjust``, the one engine (``bundle_graph`` +
  ``FactorGraph.optimize`` with ``TrustRegion``, Ceres' LM rules, and ``linear_solver="schur"``;
  BAL model), timed as a user pays it: the whole ``bundle_adjust`` call (graph construction,
  symbolic analysis and solve; excludes reading the file);
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
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
DEFAULT_FILE = ROOT / ".." / "shared" / "data" / "bal" / "problem-49-7776-pre.txt"


# ---------------------------------------------------------------------------- contenders

def run_microlie(path: Path, behind: str = "evaluate") -> dict:
    """``bundle_adjust`` (the engine: bundle_graph + TrustRegion + linear_solver="schur"), timed
    as a user pays it (graph construction and solve, not reading the file)."""
    from microlie.optim.io.bal import read_bal
    from microlie.optim.sfm.bundle import bundle_adjust

    p = read_bal(path)
    t0 = time.perf_counter()
    r = bundle_adjust(p, behind=behind)
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


# ---------------------------------------------------------------------------- street scenes

def street_scene(n_cameras: int, seed: int = 0, points_per_camera: float = 20.0,
                 noise_px: float = 0.5):
    """A seeded synthetic street as a BAL problem (BAL camera model, start perturbed).

    Cameras every metre along the x axis (lateral wiggle 0.3 m, height 1.6 m, yaw noise 3
    degrees), looking forward (down their -z axis, BAL's convention); ``points_per_camera``
    landmarks per metre of street on the facades (``|y|`` in 6-9 m, height 0-10 m) and the
    ground; an observation when the point is 3-45 m in front, inside a 800 x 600 image (f =
    500) and a coin (probability 0.5) says it is not occluded; landmarks seen fewer than 3
    times are dropped. Pixel noise ``noise_px``. Start: rotations perturbed by 2e-3 rad,
    camera centres by 0.05 m, focal lengths by 0.5%, points by 0.1 m.
    """
    from scipy.spatial.transform import Rotation

    from microlie.optim.io.bal import BALProblem

    rng = np.random.default_rng(seed)
    xs = np.arange(n_cameras, dtype=float)
    centres = np.stack([xs, 0.3 * np.sin(xs / 7.0), np.full(n_cameras, 1.6)], 1)
    yaw = np.deg2rad(3.0) * rng.standard_normal(n_cameras)
    fwd = np.stack([np.cos(yaw), np.sin(yaw), np.zeros(n_cameras)], 1)
    zc = -fwd
    up = np.array([0.0, 0.0, 1.0])
    yc = up - (zc @ up)[:, None] * zc
    yc /= np.linalg.norm(yc, axis=1, keepdims=True)
    xc = np.cross(yc, zc)
    R = np.stack([xc, yc, zc], 1)                     # rows: camera axes in the world
    t = -np.einsum("nij,nj->ni", R, centres)
    n_pts = int(points_per_camera * (n_cameras + 45))
    kind = rng.uniform(size=n_pts)
    side = np.where(rng.uniform(size=n_pts) < 0.5, -1.0, 1.0)
    X = np.empty((n_pts, 3))
    X[:, 0] = rng.uniform(0.0, n_cameras + 45.0, n_pts)
    facade = kind < 0.8
    X[:, 1] = np.where(facade, side * rng.uniform(6.0, 9.0, n_pts), rng.uniform(-6, 6, n_pts))
    X[:, 2] = np.where(facade, rng.uniform(0.0, 10.0, n_pts), 0.0)
    K = np.tile([500.0, 1e-2, -1e-3], (n_cameras, 1))
    cams, pts = [], []
    for i in range(n_cameras):
        near = np.flatnonzero((X[:, 0] > xs[i] + 2.0) & (X[:, 0] < xs[i] + 46.0))
        P = X[near] @ R[i].T + t[i]
        depth = -P[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = 500.0 * P[:, 0] / depth, 500.0 * P[:, 1] / depth
        ok = ((depth > 3.0) & (depth < 45.0) & (np.abs(u) < 400.0) & (np.abs(v) < 300.0)
              & (rng.uniform(size=near.size) < 0.5))
        cams.append(np.full(int(ok.sum()), i))
        pts.append(near[ok])
    ci, pi = np.concatenate(cams), np.concatenate(pts)
    keep = np.bincount(pi, minlength=n_pts) >= 3
    renum = np.cumsum(keep) - 1
    sel = keep[pi]
    ci, pi, X = ci[sel], renum[pi[sel]], X[keep]
    cameras = np.concatenate([Rotation.from_matrix(R).as_rotvec(), t, K], 1)
    clean = BALProblem(cameras, X, ci, pi, np.zeros((ci.size, 2))).residuals()
    uv = clean + noise_px * rng.standard_normal(clean.shape)
    start = cameras.copy()
    Rs = Rotation.from_rotvec(2e-3 * rng.standard_normal((n_cameras, 3))) * Rotation.from_matrix(R)
    cs = centres + 0.05 * rng.standard_normal((n_cameras, 3))     # perturb the centres
    start[:, :3] = Rs.as_rotvec()
    start[:, 3:6] = -np.einsum("nij,nj->ni", Rs.as_matrix(), cs)
    start[:, 6] *= 1.0 + 5e-3 * rng.standard_normal(n_cameras)
    Xs = X + 0.1 * rng.standard_normal(X.shape)
    return BALProblem(start, Xs, ci, pi, uv)


# ---------------------------------------------------------------------------- main

def bench(label: str, contenders: dict, repeat: int) -> None:
    """Interleaved rounds of ``contenders`` (name -> callable), a markdown table, the ratios."""
    runs: dict[str, list[dict]] = {k: [] for k in contenders}
    for rnd in range(repeat):
        for name, fn in contenders.items():
            runs[name].append(fn())
            print(f"{label} round {rnd + 1} {name}: {runs[name][-1]['time_s']:.3f} s",
                  file=sys.stderr)
    load = os.getloadavg()
    ref = statistics.median(r["time_s"] for r in runs["microlie"])
    print(f"\n## Bundle adjustment, {label} (load average {load[0]:.2f} {load[1]:.2f} "
          f"{load[2]:.2f}, {repeat} interleaved rounds)\n")
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
            for m in (n for n in med if n.startswith("microlie")):
                print(f"- {m} / {k}: {med[m] / med[k]:.2f}"
                      + (" (goal, issue 20: at most 1.0)" if k.endswith("SPARSE_SCHUR") else ""))
    if "GTSAM 4.3 LM CeresDefaults" in med:
        g = med["GTSAM 4.3 LM CeresDefaults"]
        print(f"- GTSAM / microlie behind=drop (same objective): "
              f"{g / med['microlie behind=drop']:.2f}; GTSAM / microlie: "
              f"{g / med['microlie']:.2f} (goal: at least 2)")
    eng = runs["microlie"][-1]
    it = max(eng["iterations"], 1)
    print(f"\nmicrolie time breakdown (last round), ms per iteration ({it} iterations):\n")
    print("| part | ms / iteration | share |")
    print("|---|---|---|")
    total = sum(v for v in eng["timings"].values() if isinstance(v, float))
    for k, v in eng["timings"].items():
        if isinstance(v, float):
            print(f"| {k} | {1e3 * v / it:.1f} | {100 * v / total:.0f}% |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", type=Path, default=DEFAULT_FILE)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-scipy", action="store_true")
    ap.add_argument("--skip-gtsam", action="store_true")
    ap.add_argument("--skip-file", action="store_true", help="only the street scenes")
    ap.add_argument("--street", type=int, nargs="*", default=[],
                    help="camera counts of synthetic street scenes (e.g. 300 1000)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the street scenes")
    args = ap.parse_args(argv)
    if any(n < 10 for n in args.street):
        ap.error("--street: camera counts must be at least 10")
    exe = build_ceres()
    if not args.skip_file:
        path = args.file.resolve()
        contenders: dict[str, Any] = {"microlie": lambda: run_microlie(path)}
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
        bench(path.name, contenders, args.repeat)
    if args.street:
        from microlie.optim.io.bal import write_bal

        with tempfile.TemporaryDirectory() as tmp:
            for n in args.street:
                p = street_scene(n, seed=args.seed)
                f = Path(tmp) / f"street-{n}-{args.seed}.txt"
                write_bal(f, p)
                label = (f"synthetic street, {n} cameras, {p.n_points} points, "
                         f"{p.n_observations} observations (seed {args.seed})")
                street: dict[str, Any] = {"microlie": lambda f=f: run_microlie(f)}
                if exe is not None:
                    street["Ceres C++ SPARSE_SCHUR"] = (
                        lambda f=f: run_ceres(exe, f, "SPARSE_SCHUR"))
                bench(label, street, args.repeat)
    return 0


if __name__ == "__main__":
    sys.exit(main())
