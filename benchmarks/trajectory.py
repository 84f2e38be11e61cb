"""Trajectory evaluation: microlie vs evo, side by side in one run.

evo is GPL-3 and only *run* here (never imported by microlie). Run in an environment that has
both (from the repository root)::

    python3 -m venv /work/evo-venv && /work/evo-venv/bin/pip install evo==1.38.1 array-api-compat
    /work/evo-venv/bin/pip install .   # microlie with its compiled kernels and file reader
    PYTHONPATH=src /work/evo-venv/bin/python benchmarks/trajectory.py [--n 100000] [--no-write]

Without the compiled kernels (or with ``MICROLIE_FAST=0``) microlie reads files with NumPy's
``loadtxt``; the command table has a row for that default install on the 1e5 pair.

Cases: a synthetic 1e5-pose pair (TUM files written to a temporary directory) and the fr2/desk
files of ../shared/data. For each case both tools compute the same numbers (checked: the
statistics must agree to 1e-9 relative, otherwise the script fails):

* "metric": association + alignment + error + statistics on trajectories already in memory;
* "end to end": the same, starting from reading the two files;
* "command": the whole command as a user runs it, in a fresh process each time
  (``microlie ape FMT GT EST -a`` vs ``evo_ape FMT GT EST -a``, text output discarded), on the
  synthetic pair and on the real TUM, KITTI and EuRoC files: medians of interleaved runs with
  the interquartile range.

Every figure is the median of interleaved rounds (the two tools alternate, one round each,
``benchmarks/_timing.py``) with its spread; a speed-up is the ratio of the medians, with the
range spanned by the rounds (in process: evo's fastest / microlie's slowest to evo's slowest /
microlie's fastest; commands: the interquartile range of the per-round ratios). evo's
in-place alignment gets a fresh copy made before timing. ``--rounds`` / ``--command-runs``
set the rounds (lower them on a slow machine). The tables are written to
``benchmarks/results/trajectory-latest.md``.
"""

from __future__ import annotations

import argparse
import copy
import os
import platform
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import Stats, calibrate, interleaved  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / ".." / "shared" / "data" / "trajectory" / "evo"
SECTION = "## Trajectory evaluation"
RESULTS = REPO / "benchmarks" / "results" / "trajectory-latest.md"
EVO_BIN = Path(sys.executable).parent
# (label, format word, GT, EST): the real files of ../shared/data for the command timing
REAL = [
    ("fr2/desk (TUM)", "tum", "fr2_desk_groundtruth.txt", "fr2_desk_ORB.txt"),
    ("fr1/xyz (TUM)", "tum", "freiburg1_xyz-groundtruth.txt", "freiburg1_xyz-rgbdslam.txt"),
    ("KITTI 00 (KITTI)", "kitti", "KITTI_00_gt.txt", "KITTI_00_ORB.txt"),
    ("V1_02 (EuRoC)", "euroc", "V102_groundtruth.csv", "V102.txt"),
]


def _children_cpu() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def command_times(fmt: str, gt: Path, est: Path, repeat: int,
                  extra_env: dict | None = None) -> list[list[float]]:
    """Wall times of the two whole commands (fresh processes, runs interleaved) and their CPU
    times (user + system of the finished child): ``[wall_ours, wall_evo, cpu_ours, cpu_evo]``.
    ``extra_env`` is added to microlie's environment (e.g. ``MICROLIE_FAST=0``)."""
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
    ours_env = dict(env, **(extra_env or {}))
    ours = [sys.executable, "-m", "microlie.cli", "ape", fmt, str(gt), str(est), "-a"]
    evo = [str(EVO_BIN / "evo_ape"), fmt, str(gt), str(est), "-a", "--no_warnings"]
    out: list[list[float]] = [[], [], [], []]
    for _ in range(repeat):
        for k, cmd in enumerate((ours, evo)):
            c0 = _children_cpu()
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, env=ours_env if k == 0 else env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            out[k].append(time.perf_counter() - t0)
            out[k + 2].append(_children_cpu() - c0)
    return out


def _ms(s: Stats, digits: int = 0) -> str:
    """``median ms [q1-q3]`` with ``digits`` decimals."""
    return f"{s.median * 1e3:.{digits}f} ms [{s.q1 * 1e3:.{digits}f}-{s.q3 * 1e3:.{digits}f}]"


def _ms_range(s: Stats, digits: int) -> str:
    """``median ms [min-max]`` with ``digits`` decimals."""
    return f"{s.median * 1e3:.{digits}f} ms [{s.lo * 1e3:.{digits}f}-{s.hi * 1e3:.{digits}f}]"


def _speedup(ours: Stats, evo: Stats) -> tuple[float, float, float]:
    """Ratio of the medians evo / microlie and the range the rounds allow."""
    return evo.median / ours.median, evo.lo / ours.hi, evo.hi / ours.lo


def command_rows(cases: list[tuple[str, str, Path, Path]], repeat: int,
                 extra_env: dict | None = None) -> list[dict]:
    rows = []
    for label, fmt, gt, est in cases:
        a, b, cpu_a, cpu_b = command_times(fmt, gt, est, repeat, extra_env)
        ratio = Stats.of([y / x for x, y in zip(a, b, strict=True)], 1)
        cpu_ratio = Stats.of([y / x for x, y in zip(cpu_a, cpu_b, strict=True)], 1)
        rows.append(dict(case=label, ours=_ms(Stats.of(a, 1)), evo=_ms(Stats.of(b, 1)),
                         ratio=ratio.median, lo=ratio.q1, hi=ratio.q3, runs=repeat,
                         cpu_ours=Stats.of(cpu_a, 1).median, cpu_evo=Stats.of(cpu_b, 1).median,
                         cpu_ratio=cpu_ratio.median, cpu_lo=cpu_ratio.q1,
                         cpu_hi=cpu_ratio.q3))
        print(f"command {label:22s} microlie {rows[-1]['ours']:>22s}  evo {rows[-1]['evo']:>22s}"
              f"  x{rows[-1]['ratio']:.1f}", flush=True)
    return rows


def command_table(rows: list[dict]) -> str:
    lines = [
        "### The command, end to end",
        "",
        "`microlie ape FMT GT EST -a` against `evo_ape FMT GT EST -a --no_warnings`, each run in "
        "a fresh process (interpreter start, imports, reading, association, SE(3) alignment, "
        "APE, text output), the two commands alternating; median wall time with the "
        "interquartile range, and the median of the per-round ratios evo / microlie with its "
        "interquartile range. CPU: user + system seconds of each finished process (the "
        "operating system's accounting; less sensitive to other jobs than wall time), medians "
        "and the median per-round ratio with its interquartile range.",
        "",
        "| files | runs | microlie wall | evo wall | wall speed-up (IQR) | microlie CPU | "
        "evo CPU | CPU speed-up (IQR) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['case']} | {r['runs']} | {r['ours']} | {r['evo']} | "
                     f"**{r['ratio']:.1f}x** ({r['lo']:.1f}-{r['hi']:.1f}) | "
                     f"{r['cpu_ours'] * 1e3:.0f} ms | {r['cpu_evo'] * 1e3:.0f} ms | "
                     f"**{r['cpu_ratio']:.1f}x** ({r['cpu_lo']:.1f}-{r['cpu_hi']:.1f}) |")
    return "\n".join(lines) + "\n"


def median_times(ours, evo, rounds: int, evo_fresh=None) -> tuple[Stats, Stats]:
    """Interleaved medians of ``ours()`` and ``evo()`` over ``rounds`` rounds each.

    microlie's calls are batched to ~50 ms per round when fast (``_timing.calibrate``); evo's
    run once per round. With ``evo_fresh`` (a factory of fresh inputs), evo's callable takes
    one of them, all made before timing (evo aligns in place).
    """
    number = calibrate(ours)
    if evo_fresh is not None:
        inputs = iter([evo_fresh() for _ in range(rounds)])
        fn, evo = evo, lambda: fn(*next(inputs))
    res = interleaved({"ours": ours, "evo": evo}, {"ours": (number, rounds), "evo": (1, rounds)})
    for v in res.values():
        if isinstance(v, Exception):
            raise v
    return res["ours"], res["evo"]  # type: ignore[return-value]


def synthetic_pair(n: int, folder: Path) -> tuple[Path, Path]:
    """A smooth random 3-D path at 30 Hz and a drifting, noisy estimate at shifted stamps."""
    from microlie import SE3
    from microlie.traj import Trajectory

    rng = np.random.default_rng(42)
    stamps = 1.6e9 + np.arange(n) / 30.0
    vel = np.cumsum(rng.normal(scale=0.01, size=(n, 3)), axis=0)
    vel -= vel.mean(axis=0)
    pos = np.cumsum(vel, axis=0) * 0.05
    omega = np.cumsum(rng.normal(scale=0.002, size=(n, 3)), axis=0)
    rot = SE3.exp(np.concatenate([np.zeros((n, 3)), np.cumsum(omega, axis=0) * 0.01], axis=1))
    gt = Trajectory(SE3.from_rotation_translation(rot.rotation(), pos), stamps)
    drift = SE3.exp(np.cumsum(rng.normal(scale=[2e-4] * 3 + [5e-5] * 3, size=(n, 6)), axis=0))
    noise = SE3.exp(rng.normal(scale=[3e-3] * 3 + [1e-3] * 3, size=(n, 6)))
    est = Trajectory(gt.poses @ drift @ noise, stamps + 0.002)
    a, b = folder / "synthetic_gt.tum", folder / "synthetic_est.tum"
    # the precision SLAM systems write (e.g. ORB-SLAM: 6-decimal stamps, 9-decimal values)
    fmt = ["%.6f"] + ["%.9f"] * 7
    for path, t in ((a, gt), (b, est)):
        np.savetxt(path, np.column_stack([t.timestamps, t.positions, t.quat_xyzw]), fmt=fmt,
                   header="timestamp tx ty tz qx qy qz qw")
    return a, b


# ----------------------------------------------------------------------------- the two tools
def ours_read(path: Path):
    from microlie.traj import read_tum

    return read_tum(path)


def ours_metric(kind: str, ref, est):
    from microlie.traj import evaluate_ape, evaluate_rpe

    if kind == "ape":
        return evaluate_ape(ref, est, align="se3")
    if kind == "rpe":
        return evaluate_rpe(ref, est, delta=1, unit="frames")
    return evaluate_rpe(ref, est, relation="angle_deg", delta=1.0, unit="m")


def evo_read(path: Path):
    from evo.tools import file_interface

    t = file_interface.read_tum_trajectory_file(str(path))
    return t


def evo_metric(kind: str, ref, est) -> dict:
    from evo.core import metrics, sync

    ref, est = sync.associate_trajectories(ref, est, max_diff=0.01)
    if kind == "ape":
        est.align(ref)
        m = metrics.APE(metrics.PoseRelation.translation_part)
    elif kind == "rpe":
        m = metrics.RPE(metrics.PoseRelation.translation_part, 1, metrics.Unit.frames)
    else:
        m = metrics.RPE(metrics.PoseRelation.rotation_angle_deg, 1.0, metrics.Unit.meters)
    m.process_data((ref, est))
    return m.get_all_statistics()


def check_same(a: dict, b: dict, what: str) -> float:
    worst = 0.0
    for k, v in b.items():
        err = abs(a[k] - v) / max(abs(v), 1e-300)
        if abs(a[k] - v) > 1e-9 * abs(v) + 1e-12:
            raise SystemExit(f"{what}: {k} differs: microlie {a[k]!r} vs evo {v!r}")
        worst = max(worst, err)
    return worst


KINDS = {
    "ape": "APE trans, SE(3) Umeyama",
    "rpe": "RPE trans, delta 1 frame",
    "rpe_m": "RPE angle (deg), delta 1 m",
}


def run_case(label: str, gt: Path, est: Path, rounds: int) -> list[dict]:
    rows = []
    o_ref, o_est = ours_read(gt), ours_read(est)
    e_ref, e_est = evo_read(gt), evo_read(est)
    # evo computes poses lazily from quaternions on first use: do it once before timing the
    # in-memory metric (it is counted in the end-to-end column)
    _ = e_ref.poses_se3, e_est.poses_se3
    for kind, title in KINDS.items():
        res = ours_metric(kind, o_ref, o_est)
        s_ours = res.stats
        s_evo = evo_metric(kind, copy.deepcopy(e_ref), copy.deepcopy(e_est))
        worst = check_same(s_ours, s_evo, f"{label} {kind}")
        t_ours, t_evo = median_times(
            lambda k=kind: ours_metric(k, o_ref, o_est),
            lambda a, b, k=kind: evo_metric(k, a, b), rounds,
            evo_fresh=lambda: (copy.deepcopy(e_ref), copy.deepcopy(e_est)))
        t_ours_e2e, t_evo_e2e = median_times(
            lambda k=kind: ours_metric(k, ours_read(gt), ours_read(est)),
            lambda k=kind: evo_metric(k, evo_read(gt), evo_read(est)), rounds)
        row = dict(
            case=label,
            metric=title,
            poses=f"{len(o_ref)} / {len(o_est)}",
            pairs=res.info["pairs"],
            errors=res.errors.size,
            rel=worst,
            ours=t_ours,
            evo=t_evo,
            ours_e2e=t_ours_e2e,
            evo_e2e=t_evo_e2e,
            rounds=rounds,
        )
        rows.append(row)
        print(
            f"{label:22s} {title:28s} metric: microlie {t_ours.median * 1e3:8.2f} ms  evo "
            f"{t_evo.median * 1e3:9.2f} ms  x{_speedup(t_ours, t_evo)[0]:6.1f} | end to end: "
            f"microlie {t_ours_e2e.median * 1e3:8.2f} ms  evo {t_evo_e2e.median * 1e3:9.2f} ms"
            f"  x{_speedup(t_ours_e2e, t_evo_e2e)[0]:6.1f} | max rel. diff {worst:.1e}",
            flush=True,
        )
    return rows


IMPORTS = {
    "numpy": "import numpy",
    "microlie": "import microlie.traj",
    "evo": "from evo.tools import file_interface; from evo.core import metrics, sync",
}


def import_times(repeat: int = 5) -> dict[str, float]:
    """Median import time (s) of each tool's modules in a fresh interpreter, interleaved.

    Not part of the end-to-end columns (there both tools are already imported, as in a
    library call): reported separately because a command-line run pays it once.
    """
    times: dict[str, list[float]] = {key: [] for key in IMPORTS}
    for _ in range(repeat):
        for key, stmt in IMPORTS.items():
            code = f"import time; t = time.perf_counter(); {stmt}; print(time.perf_counter() - t)"
            out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                                 check=True).stdout
            times[key].append(float(out))
    return {key: Stats.of(v, 1).median for key, v in times.items()}


def table(rows: list[dict], imports: dict[str, float],
          load: tuple[tuple[float, ...], tuple[float, ...]]) -> str:
    import evo

    import microlie

    lines = [
        SECTION,
        "",
        f"`benchmarks/trajectory.py`, microlie {microlie.__version__} vs evo "
        f"{evo.__version__.lstrip('v')}, measured in the same run on {platform.machine()} "
        f"({os.cpu_count()} CPUs), Python {platform.python_version()}, NumPy {np.__version__}. "
        f"Medians of {rows[0]['rounds']} interleaved rounds per tool (runs of the two tools "
        "alternating; a fast microlie call is repeated to ~50 ms per round) with [min-max] of "
        "the rounds; speed-up = ratio of the medians evo / microlie, in parentheses the range "
        "the rounds span (evo's fastest / microlie's slowest to evo's slowest / microlie's "
        'fastest). "Metric": association + '
        'alignment + errors + statistics on trajectories in memory; "end to end": the same '
        "starting from the two TUM files "
        "(synthetic files written with 6-decimal stamps and 9-decimal values, as SLAM "
        "systems write them): read both files, associate, align, errors, statistics, "
        "no printing or plotting; both tools are imported before timing (import times, "
        "fresh interpreter, median of 5: numpy "
        f"{imports['numpy'] * 1e3:.0f} ms, `microlie.traj` {imports['microlie'] * 1e3:.0f} ms, "
        f"evo's file_interface + metrics + sync {imports['evo'] * 1e3:.0f} ms, each "
        "including numpy). microlie reads the files with its compiled reader "
        "(`microlie._c._text`) when it is installed, otherwise with "
        "`numpy.loadtxt` (the MICROLIE_FAST=0 row of the command table); both give the values "
        "of Python's `float`, and a malformed file falls back to a line-by-line parser that "
        "names the bad line. "
        "Both tools' statistics agree to the stated relative difference in every row "
        "(the 2e-9 row: its smallest error is 1.5e-4 m on coordinates up to 4e3 m, where both "
        "tools carry ~1e-13 m of rounding). "
        "Load average (`uptime`, 1 / 5 / 15 min) at the start of the run "
        f"{' / '.join(f'{x:.2f}' for x in load[0])}, at the end "
        f"{' / '.join(f'{x:.2f}' for x in load[1])} "
        "(other jobs shared the machine; both tools were timed under the same conditions, "
        "interleaved).",
        "",
        "| trajectory | metric | poses GT / est | pairs | microlie metric | evo metric | "
        "speed-up | microlie end to end | evo end to end | speed-up | max rel. diff |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        m, m_lo, m_hi = _speedup(r["ours"], r["evo"])
        e, e_lo, e_hi = _speedup(r["ours_e2e"], r["evo_e2e"])
        lines.append(
            f"| {r['case']} | {r['metric']} | {r['poses']} | {r['pairs']} | "
            f"{_ms_range(r['ours'], 2)} | {_ms_range(r['evo'], 0)} | "
            f"**{m:.0f}x** ({m_lo:.0f}-{m_hi:.0f}) | "
            f"{_ms_range(r['ours_e2e'], 1)} | {_ms_range(r['evo_e2e'], 0)} | "
            f"**{e:.1f}x** ({e_lo:.1f}-{e_hi:.1f}) | {r['rel']:.0e} |"
        )
    lines += [
        "",
        "Regenerate: `PYTHONPATH=src /work/evo-venv/bin/python benchmarks/trajectory.py` "
        "(evo 1.38.1 and microlie's dependencies in one environment; see the script's "
        "docstring).",
        "",
    ]
    return "\n".join(lines)


def write_results(text: str) -> None:
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(f"wrote {RESULTS}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000, help="synthetic trajectory length")
    ap.add_argument("--no-write", action="store_true",
                    help="do not write benchmarks/results/trajectory-latest.md")
    ap.add_argument("--rounds", type=int, default=5,
                    help="interleaved in-process rounds per tool and metric (default 5)")
    ap.add_argument("--command-runs", type=int, default=7,
                    help="fresh-process runs of each command per file pair (default 7)")
    args = ap.parse_args()
    try:
        import evo  # noqa: F401
    except ImportError:
        sys.exit("evo is not installed in this environment (see the module docstring)")
    from microlie.traj import TimestampWarning

    # fr2/desk's ground truth has one repeated stamp: expected, warned once per read
    warnings.simplefilter("ignore", TimestampWarning)
    from microlie import _fast

    fast_reader = _fast.text_parser() is not None
    print(f"compiled file reader (microlie._c._text): {'yes' if fast_reader else 'no'}")
    load_start = os.getloadavg()
    imports = import_times()
    print("import times: " + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in imports.items()))
    rows = []
    synth = f"synthetic {args.n:.0e}".replace("e+0", "e")
    fr2_gt, fr2_est = DATA / "fr2_desk_groundtruth.txt", DATA / "fr2_desk_ORB.txt"
    if not fr2_gt.exists():
        sys.exit(f"{fr2_gt} not found: the benchmark needs ../shared/data")
    with tempfile.TemporaryDirectory() as tmp:
        gt, est = synthetic_pair(args.n, Path(tmp))
        rows += run_case(synth, gt, est, args.rounds)
        cmd_rows = command_rows([(synth + " (TUM)", "tum", gt, est)],
                                max(3, args.command_runs - 2))
        if fast_reader:  # the default install (no compiled kernels): NumPy's loadtxt reads
            cmd_rows += command_rows([(synth + " (TUM), MICROLIE_FAST=0", "tum", gt, est)],
                                     max(3, args.command_runs - 2), {"MICROLIE_FAST": "0"})
    rows += run_case("fr2/desk (TUM)", fr2_gt, fr2_est, args.rounds)
    cmd_rows += command_rows([(lab, fmt, DATA / g, DATA / e) for lab, fmt, g, e in REAL],
                             args.command_runs)
    load = (load_start, os.getloadavg())
    text = (table(rows, imports, load) + "\n" + command_table(cmd_rows)
            + f"\nmicrolie's compiled file reader (microlie._c._text): "
            f"{'installed' if fast_reader else 'not installed'}.\n")
    print()
    print(text)
    if not args.no_write:
        write_results(text)


if __name__ == "__main__":
    main()
