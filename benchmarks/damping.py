"""Issue 22: LM damping and units.

Part 1, units: M3500 (``input_M3500_g2o.g2o``) with its translations scaled by 1e-6, 1, 1e3
and 1e6 (1e6: micrometres; positions and measured translations times the scale, the
information's translation rows and columns divided by it: the cost is the same function),
solved by the
default ``microlie optimize FILE --json`` (``--damping auto``), by ``--damping identity`` and
``--damping diagonal``, each in a fresh process, and by GTSAM 4.3's LM
(``gtsam_optimize.py``) when the running interpreter imports gtsam. The optimum is 68.95743913
in every unit.

Part 2, speed: the twelve shared pose graphs (the starts of ``tests/test_optim_graphs.py``, the
file's vertices for ais2klinik and sphere_bignoise_vertex3), solved in-process with the default
tolerances by ``damping="auto"``, ``"identity"`` (the previous default, GTSAM's) and
``"diagonal"``, interleaved; iterations, linear solves, final cost, median solve time and the
ratio auto / identity.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src /work/bench-venv/bin/python benchmarks/damping.py \\
        --repeat 3 --python /work/main/.venv/bin/python
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "pose_graph"
M3500 = "input_M3500_g2o.g2o"
SCALES = (1e-6, 1.0, 1e3, 1e6)
GRAPHS = [("gtsam/pose2example.txt", "file"), ("gtsam/pose3example.txt", "file"),
          ("tinyGrid3D.g2o", "file"), ("smallGrid3D.g2o", "file"), ("MIT.g2o", "chordal"),
          ("CSAIL.g2o", "odometry"), ("manhattan.g2o", "odometry"),
          ("kitti_00.g2o", "odometry"), (M3500, "file"), ("parking-garage.g2o", "file"),
          ("sphere2500.g2o", "file"), ("ais2klinik.g2o", "file"),
          ("sphere_bignoise_vertex3.g2o", "file")]


def scaled_file(scale: float, folder: Path) -> Path:
    """M3500 with translations times ``scale``, written as g2o."""
    from microlie.optim.io.g2o import read_g2o, write_g2o

    g = read_g2o(DATA / M3500)
    s = scale
    P, Z = np.array(g.poses.params), np.array(g.measurements.params)
    P[:, :2] *= s
    Z[:, :2] *= s
    w = np.array([1.0 / s, 1.0 / s, 1.0])
    g = g.replace(poses=g.group(P), measurements=g.group(Z),
                  information=g.information * w[:, None] * w[None, :])
    path = folder / f"M3500-scale{scale:g}.g2o"
    write_g2o(path, g)
    return path


def run_command(python: str, path: Path, damping: str | None) -> dict:
    argv = [python, "-c", "import sys; from microlie.cli import main; sys.exit(main())",
            "optimize", str(path), "--json", "-q"]
    if damping:
        argv += ["--damping", damping]
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    out = subprocess.run(argv, capture_output=True, text=True, env=env, check=True).stdout
    return json.loads(out)


def run_gtsam(path: Path, folder: Path) -> dict:
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "gtsam_optimize.py"),
                          str(path), str(folder / "gtsam-out.g2o")],
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out)


def part_units(python: str) -> list[str]:
    rows = ["| translations times | solver | final cost | iterations | solve s | message |",
            "|---|---|---|---|---|---|"]
    have_gtsam = importlib.util.find_spec("gtsam") is not None
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for unit in SCALES:
            path = scaled_file(unit, folder)
            for damping in (None, "identity", "diagonal"):
                r = run_command(python, path, damping)
                name = f"microlie --damping {damping or 'auto (default)'}"
                rows.append(f"| {unit:g} | {name} | {r['final_cost']:.10g} | "
                            f"{r['iterations']} | {r['time_s']:.3f} | {r['message']} |")
                print(rows[-1], flush=True)
            if have_gtsam:
                r = run_gtsam(path, folder)
                rows.append(f"| {unit:g} | GTSAM 4.3 LM (defaults) | {r['final_cost']:.10g} | "
                            f"{r['iterations']} | {r['time_s']:.3f} | |")
                print(rows[-1], flush=True)
    return rows


def part_graphs(repeat: int, only: list[str] | None) -> list[str]:
    from microlie.optim.core.strategies import LevenbergMarquardt
    from microlie.optim.init import initialize
    from microlie.optim.io.g2o import read_g2o

    rows = ["| graph | damping | iterations | solves | final cost | median solve s | "
            "auto / identity |", "|---|---|---|---|---|---|---|"]
    for name, start in GRAPHS:
        if only and not any(o in name for o in only):
            continue
        g = read_g2o(DATA / name)
        fg, poses = g.to_factor_graph(initialize(g, start))  # type: ignore[arg-type]
        fg.optimize(max_iter=1)  # warm the pattern, analysis and imports
        times: dict[str, list[float]] = {d: [] for d in ("auto", "identity", "diagonal")}
        last = {}
        for _ in range(repeat):
            for d in times:
                t = time.perf_counter()
                res = fg.optimize(solver=LevenbergMarquardt(damping=d))
                times[d].append(time.perf_counter() - t)
                last[d] = res
        med = {d: statistics.median(v) for d, v in times.items()}
        for d, res in last.items():
            ratio = f"{med['auto'] / med['identity']:.2f}" if d == "auto" else ""
            rows.append(f"| {name} ({start}) | {d} | {res.iterations} | "
                        f"{sum(h.solves for h in res.history)} | "
                        f"{g.cost(res.values[poses]):.10g} | {med[d]:.3f} | {ratio} |")
            print(rows[-1], flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--python", default=sys.executable,
                    help="the interpreter of the microlie command (part 1)")
    ap.add_argument("--graphs", nargs="*", default=None, help="part 2: names containing these")
    ap.add_argument("--skip-units", action="store_true")
    ap.add_argument("--skip-graphs", action="store_true")
    ap.add_argument("--out", default=None, help="also write the markdown here")
    args = ap.parse_args()
    text = [f"# LM damping and units ({time.strftime('%Y-%m-%d %H:%M')}, load "
            f"{os.getloadavg()[0]:.1f})", ""]
    if not args.skip_units:
        text += ["## M3500 scaled (fresh process each)", "", *part_units(args.python), ""]
    if not args.skip_graphs:
        text += [f"## The shared pose graphs (in-process, median of {args.repeat})", "",
                 *part_graphs(args.repeat, args.graphs), ""]
    if args.out:
        Path(args.out).write_text("\n".join(text) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
