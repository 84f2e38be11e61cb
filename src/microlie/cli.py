"""The ``microlie`` command: trajectory evaluation from the shell.

Subcommands::

    microlie ape GT EST [--format tum|kitti|euroc] [--align none|se3|sim3|scale|origin]
                        [--relation trans|rot|full|se3|...] [--plot FILE] [--json]
    microlie rpe GT EST ... --delta N --unit frames|m [--all-pairs]
    microlie kitti GT EST [--format kitti|tum|euroc] [--json]
    microlie plot FILES... -o FILE [--format ...] [--align se3|sim3|...]

``--example`` replaces GT and EST by the small pair bundled with the package
(``microlie.data.example_paths()``). ``--format euroc`` reads GT as a EuRoC CSV and the estimate
as TUM (as estimates for EuRoC are usually written); ``--est-format`` overrides it.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterable, Iterator, Sequence
from typing import TypeVar

__all__ = ["main", "build_parser"]

T = TypeVar("T")

_RELATIONS = ("trans", "rot", "full", "se3", "angle_deg", "angle_rad", "rot_part",
              "point_distance")


def _progress(items: Sequence[T], label: str, stream=None) -> Iterator[T]:
    """Yield ``items``, drawing a text progress bar on a terminal (silent otherwise)."""
    stream = stream or sys.stderr
    show = len(items) > 1 and hasattr(stream, "isatty") and stream.isatty()
    n = len(items)
    for k, item in enumerate(items):
        if show:
            done = int(30 * k / n)
            stream.write(f"\r{label} [{'#' * done}{'.' * (30 - done)}] {k}/{n}")
            stream.flush()
        yield item
    if show:
        stream.write(f"\r{label} [{'#' * 30}] {n}/{n}\n")
        stream.flush()


def _read(path: str, fmt: str, times: str | None):
    from .traj import read_trajectory

    return read_trajectory(path, fmt, timestamps=times)


def _load_pair(args: argparse.Namespace):
    if args.example:
        from .data import example_paths

        gt_path, est_path = (str(p) for p in example_paths())
        gt_fmt = est_fmt = "tum"
    else:
        if args.gt is None or args.est is None:
            raise SystemExit("microlie: give GT and EST files, or --example")
        gt_path, est_path = args.gt, args.est
        gt_fmt = args.format
        est_fmt = args.est_format or ("tum" if args.format == "euroc" else args.format)
    jobs = [(gt_path, gt_fmt, args.gt_times), (est_path, est_fmt, args.est_times)]
    ref, est = (_read(*job) for job in _progress(jobs, "reading"))
    return ref, est


def _add_common(p: argparse.ArgumentParser, metric: bool = True) -> None:
    p.add_argument("gt", nargs="?", help="reference (ground-truth) trajectory file")
    p.add_argument("est", nargs="?", help="estimated trajectory file")
    p.add_argument("--example", action="store_true",
                   help="use the example pair bundled with microlie instead of GT and EST")
    p.add_argument("--format", "-f", choices=("tum", "kitti", "euroc"), default="tum",
                   help="file format of GT (and EST unless --est-format); default tum")
    p.add_argument("--est-format", choices=("tum", "kitti", "euroc"), default=None,
                   help="file format of EST (default: as --format; tum for euroc)")
    p.add_argument("--gt-times", default=None, help="timestamps file for KITTI GT poses")
    p.add_argument("--est-times", default=None, help="timestamps file for KITTI EST poses")
    p.add_argument("--max-diff", type=float, default=0.01,
                   help="max. timestamp difference for association, s (default 0.01)")
    p.add_argument("--offset", type=float, default=0.0,
                   help="time offset added to EST timestamps for association, s")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    if metric:
        p.add_argument("--align", "-a", choices=("none", "se3", "sim3", "scale", "origin"),
                       default="none", help="alignment of EST to GT (default none)")
        p.add_argument("--n-align", type=int, default=None,
                       help="align on the first N pose pairs only")
        p.add_argument("--relation", "-r", choices=_RELATIONS, default="trans",
                       help="pose relation (default trans); rot = rotation angle")
        p.add_argument("--angle-unit", choices=("deg", "rad"), default="deg",
                       help="unit of --relation rot (default deg)")
        p.add_argument("--plot", default=None, metavar="FILE",
                       help="write an error plot (PNG, 1200x800 px) to FILE")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``microlie`` command."""
    parser = argparse.ArgumentParser(
        prog="microlie",
        description="Trajectory evaluation with microlie (APE, RPE, KITTI metric, plots).",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("ape", help="absolute pose error")
    _add_common(p)

    p = sub.add_parser("rpe", help="relative pose error")
    _add_common(p)
    p.add_argument("--delta", "-d", type=float, default=1.0,
                   help="pair separation (default 1)")
    p.add_argument("--unit", "-u", choices=("frames", "m"), default="frames",
                   help="unit of --delta (default frames)")
    p.add_argument("--all-pairs", action="store_true",
                   help="all pairs separated by delta instead of consecutive ones")
    p.add_argument("--delta-tol", type=float, default=0.1,
                   help="relative tolerance on delta in all-pairs metre mode (default 0.1)")
    p.add_argument("--pairs-from", choices=("est", "ref"), default="est",
                   help="trajectory on which pairs are chosen (default est, as evo)")

    p = sub.add_parser("kitti", help="KITTI odometry metric (100-800 m segments)")
    _add_common(p, metric=False)
    p.set_defaults(format="kitti")
    p.add_argument("--step", type=int, default=10, help="start every STEP frames (default 10)")

    p = sub.add_parser("plot", help="plot trajectories (top, 3-D, xyz and rpy over time)")
    p.add_argument("files", nargs="*", help="trajectory files; the first is the reference")
    p.add_argument("--example", action="store_true", help="plot the bundled example pair")
    p.add_argument("-o", "--output", required=True, help="output image file (PNG)")
    p.add_argument("--format", "-f", choices=("tum", "kitti", "euroc"), default="tum",
                   help="format of all files (default tum)")
    p.add_argument("--align", "-a", choices=("none", "se3", "sim3", "scale", "origin"),
                   default="none", help="align every other file to the first one")
    p.add_argument("--max-diff", type=float, default=0.01,
                   help="max. timestamp difference when aligning, s (default 0.01)")

    from .optim.command import register as register_optimize  # argparse only, no solver yet

    register_optimize(sub)
    return parser


def _print_stats(title: str, stats: dict, out) -> None:
    out.write(title + "\n\n")
    for key in ("rmse", "mean", "median", "std", "min", "max", "sse"):
        out.write(f"{key:>10s}  {stats[key]:.6f}\n")


def _title(res) -> str:
    unit = f" ({res.unit})" if res.unit else ""
    head = f"{res.metric.upper()} w.r.t. {res.relation}{unit}"
    info = res.info
    parts = []
    if res.metric == "rpe":
        parts.append(f"delta {info['delta']:g} {info['delta_unit']}"
                     f"{', all pairs' if info['all_pairs'] else ''}")
    parts.append(f"alignment {info.get('alignment', 'none')}")
    if "pairs" in info:
        parts.append(f"{info['pairs']} of max. {info['max_pairs']} pose pairs associated")
    parts.append(f"{res.errors.size} errors")
    return head + "\n" + ", ".join(parts)


def _warn_duplicates(res, err) -> None:
    dup = res.info.get("duplicate_timestamps")
    if dup:
        err.write(
            f"warning: repeated timestamps (GT {dup[0]}, EST {dup[1]}); each estimate pose is "
            "paired with the nearest GT pose (the last of equal stamps)\n"
        )


def _run_metric(args: argparse.Namespace, out, err) -> int:
    from .traj import evaluate_ape, evaluate_rpe

    ref, est = _load_pair(args)
    common = dict(relation=args.relation, align=args.align, n_align=args.n_align,
                  max_diff=args.max_diff, offset=args.offset, angle_unit=args.angle_unit)
    if args.command == "ape":
        res = evaluate_ape(ref, est, **common)
    else:
        res = evaluate_rpe(ref, est, delta=args.delta, unit=args.unit, all_pairs=args.all_pairs,
                           rel_tol=args.delta_tol, pairs_from=args.pairs_from, **common)
    _warn_duplicates(res, err)
    if args.json:
        d = res.to_dict()
        d["gt"], d["est"] = ref.name, est.name
        out.write(json.dumps(d, indent=2) + "\n")
    else:
        _print_stats(_title(res), res.stats, out)
    if args.plot:
        from .traj import plot as tplot

        tplot.save(tplot.plot_error(res), args.plot)
        err.write(f"plot written to {args.plot}\n")
    return 0


def _run_kitti(args: argparse.Namespace, out, err) -> int:
    from .traj import evaluate_kitti

    ref, est = _load_pair(args)
    res = evaluate_kitti(ref, est, step=args.step, max_diff=args.max_diff, offset=args.offset)
    if args.json:
        out.write(json.dumps(res.to_dict(), indent=2) + "\n")
        return 0
    out.write("KITTI odometry metric (segments of 100-800 m)\n\n")
    out.write(f"{'length':>8s} {'segments':>9s} {'t_err %':>9s} {'r_err deg/100m':>15s}\n")
    for length, (t, r, k) in res.per_length.items():
        out.write(f"{length:8g} {k:9d} {t:9.4f} {100 * r:15.4f}\n")
    out.write(f"\n{'average':>8s} {res.segments.shape[0]:9d} {res.t_err:9.4f} "
              f"{100 * res.r_err:15.4f}\n")
    out.write(f"\nt_err {res.t_err:.6f} %   r_err {res.r_err:.8f} deg/m\n")
    return 0


def _run_plot(args: argparse.Namespace, out, err) -> int:
    from .traj import align as talign
    from .traj import plot as tplot
    from .traj import prepare, read_trajectory

    files: Iterable[str] = args.files
    fmt = args.format
    if args.example:
        from .data import example_paths

        files = [str(p) for p in example_paths()]
        fmt = "tum"
    files = list(files)
    if not files:
        raise SystemExit("microlie plot: give at least one file (or --example)")
    trajs = [read_trajectory(f, fmt) for f in _progress(files, "reading")]
    if args.align != "none" and len(trajs) > 1:
        ref = trajs[0]
        aligned = [ref]
        for t in trajs[1:]:
            r, e, _ = prepare(ref, t, max_diff=args.max_diff)
            _, g = talign(e, r, args.align)
            aligned.append(t.transform(g))
        trajs = aligned
    tplot.save(tplot.plot_trajectories(trajs, labels=files), args.output)
    err.write(f"plot written to {args.output}\n")
    return 0


def main(argv: Sequence[str] | None = None, out=None, err=None) -> int:
    """Entry point of the ``microlie`` console script; returns the exit status."""
    out = out or sys.stdout
    err = err or sys.stderr
    args = build_parser().parse_args(argv)
    try:
        if getattr(args, "run", None) is not None:  # subcommands registered by other modules
            return args.run(args, out, err)
        if args.command in ("ape", "rpe"):
            return _run_metric(args, out, err)
        if args.command == "kitti":
            return _run_kitti(args, out, err)
        return _run_plot(args, out, err)
    except (ValueError, OSError, ImportError) as exc:
        err.write(f"microlie {args.command}: error: {exc}\n")
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
