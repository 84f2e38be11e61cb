"""The ``microlie`` command: trajectory evaluation from the shell.

Subcommands (``microlie COMMAND -h`` shows every option with an example)::

    microlie ape [tum|kitti|euroc] GT EST [-a [se3|sim3|scale|origin]] [-s] [-r RELATION] ...
    microlie rpe [tum|kitti|euroc] GT EST [-d DELTA] [-u f|m|d|r] [--all_pairs] ...
    microlie kitti GT EST                      # KITTI 100-800 m segment metric
    microlie traj FILES... [--ref FILE] [-a ...] [--merge] [--plot FILE] [--save-as FMT DIR]
    microlie res RESULTS.json... [--plot FILE] [--json]
    microlie plot FILES... -o FILE [--plot-mode xy|xz|yz|zy|xyz]
    microlie optimize (IN.g2o | --example) [-o OUT.g2o] [--plot FILE] ...  # microlie.optim.command

evo's spellings are accepted as aliases (``-a``, ``-s``, ``-as``, ``--align_origin``,
``-r trans_part``, ``-r point_distance_error_ratio``, ``-u f``, ``--t_max_diff``,
``--t_offset``, ``--n_to_align``, ``--all_pairs``, ``--save_results``, ``--change_unit``,
``-p`` / a bare ``--plot`` (show a window), ``--save_plot FILE``, ``--plot_mode``,
``--plot_x_dimension``, ``--silent``, ``--logfile``, evo_res's ``--use_rel_time``,
``--save_table``, and the leading format word ``microlie ape tum GT EST``; ``bag BAGFILE
REF_TOPIC EST_TOPIC`` for a ROS bag). ``microlie res`` reads our JSON results and evo's result
archives (``.zip``).

Exit status: 0 success; 1 a data or runtime error (unreadable or malformed file, no matching
timestamps, degenerate alignment); 2 a usage error (unknown option, missing or conflicting
arguments; argparse's meaning); 3 a missing optional dependency (matplotlib, rosbags).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import warnings
import zipfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TextIO, TypeVar

from .traj.formats import FORMATS, WRITABLE

__all__ = ["main", "build_parser", "EXIT_OK", "EXIT_ERROR", "EXIT_USAGE", "EXIT_DEPENDENCY"]

T = TypeVar("T")

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_DEPENDENCY = 0, 1, 2, 3

BAG_WORDS = ("bag", "bag2")
ALIGNMENTS = ("none", "se3", "sim3", "scale", "origin")
# native names and evo's; -r rot is the rotation angle in --angle-unit
RELATIONS = ("trans", "rot", "full", "se3", "angle_deg", "angle_rad", "rot_part",
             "point_distance", "trans_part", "point_distance_error_ratio")
UNITS = ("mm", "cm", "m", "km", "deg", "rad")  # --change_unit (evo's)
X_DIMENSIONS = ("seconds", "index", "distances")  # --plot_x_dimension (evo's)
RES_PLOTS = ("summary", "raw", "stats", "histogram", "box", "violin", "all")
# evo_res's names of its figures (FILE_NAME.png when several are written)
RES_PLOT_NAMES = {"summary": "summary", "raw": "raw", "stats": "stats",
                  "histogram": "histogram", "box": "box_plot", "violin": "violin_histogram"}
DELTA_UNITS = ("frames", "m", "deg", "rad", "f", "d", "r")
PLOT_MODES = ("xy", "xz", "yx", "yz", "zx", "zy", "xyz")
PLANES = ("xy", "xz", "yz")


class UsageError(Exception):
    """Wrong or conflicting arguments found after parsing (exit status 2)."""


# ----------------------------------------------------------------------------- helpers
def _progress(items: Sequence[T], label: str, stream: TextIO | None = None) -> Iterator[T]:
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


class _PlotAction(argparse.Action):
    """``--plot FILE`` writes the plot to FILE; a bare ``--plot`` (evo's flag) shows it."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        if values is None:
            namespace.show_plot = True
        else:
            namespace.plot = values


class _Tee(io.TextIOBase):
    """Writes to every stream given (``None`` entries are skipped)."""

    def __init__(self, *streams: TextIO | None) -> None:
        self.streams = [s for s in streams if s is not None]

    def write(self, text: str) -> int:  # type: ignore[override]
        for s in self.streams:
            s.write(text)
        return len(text)

    def flush(self) -> None:
        for s in self.streams:
            s.flush()

    def isatty(self) -> bool:
        return bool(self.streams) and all(getattr(s, "isatty", lambda: False)()
                                           for s in self.streams)


def _note(args: argparse.Namespace, text: str) -> None:
    """An informational line (``plot written to ...``): on stderr unless ``--silent``, and in
    the ``--logfile``."""
    args.note_stream.write(text + "\n")


def _plot_files(path: str, names: Sequence[str]) -> list[str]:
    """Files of several figures for ``--save_plot FILE`` (evo's naming): ``FILE`` itself for
    one figure or a PDF (one page per figure), else ``STEM_NAME.SUFFIX`` per figure."""
    if len(names) == 1 or path.lower().endswith(".pdf"):
        return [path]
    base, ext = os.path.splitext(path)
    return [f"{base}_{n}{ext}" for n in names]


def _emit_plots(args: argparse.Namespace, figs: Sequence[tuple[str, Any]]) -> None:
    """Write the figures to ``--plot/--save_plot FILE`` and/or show them (``-p``)."""
    from .traj import plot as tplot

    if args.plot:
        targets = _plot_files(args.plot, [n for n, _ in figs])
        if len(targets) == 1 and len(figs) > 1:  # several figures: pages of one PDF
            from matplotlib.backends.backend_pdf import PdfPages

            with PdfPages(args.plot) as pdf:
                for _, fig in figs:
                    fig.set_size_inches(*tplot.FIGSIZE)
                    pdf.savefig(fig)
        else:
            for target, (_, fig) in zip(targets, figs, strict=True):
                tplot.save(fig, target)
        for target in targets:
            _note(args, f"plot written to {target}")
    if getattr(args, "show_plot", False):
        _show(args, [f for _, f in figs])


def _show(args: argparse.Namespace, figs: Sequence[Any]) -> None:
    """Show the figures in windows (``-p``), or say on stderr that there is no display."""
    import matplotlib
    import matplotlib.pyplot as plt
    from matplotlib import _pylab_helpers
    from matplotlib.backends import BackendFilter, backend_registry

    backend = matplotlib.get_backend().lower()
    if backend not in backend_registry.list_builtin(BackendFilter.INTERACTIVE):
        args.warn_stream.write(
            f"warning: -p/--plot: no window can be shown (matplotlib backend {backend!r} is "
            "not interactive, e.g. no display); write the plot with --save_plot FILE\n")
        return
    canvas: Any = plt._get_backend_mod().FigureCanvas
    for k, fig in enumerate(figs, start=1):
        manager = canvas.new_manager(fig, k)
        _pylab_helpers.Gcf._set_new_active_manager(manager)  # type: ignore[no-untyped-call]
    plt.show()


def _normalize_argv(argv: list[str]) -> list[str]:
    """evo's flag forms of the alignment options, rewritten to ``--align METHOD``.

    Combined flags are split (``-as`` is ``-a -s``, i.e. sim3; ``-va`` is ``-v -a``);
    ``-a`` / ``--align`` not followed by a method is
    ``--align se3`` (evo's ``-a`` is a flag, ours takes an optional method, so that
    ``microlie ape -a gt.txt est.txt`` keeps its positional arguments); the same for a bare
    ``--interpolate`` (``se3``).
    """
    expanded: list[str] = []
    for tok in argv:  # evo's combined flags: -as, -va, -vas, ...
        if len(tok) > 2 and tok[0] == "-" and tok[1] != "-" and set(tok[1:]) <= set("asv"):
            expanded += [f"-{c}" for c in tok[1:]]
        else:
            expanded.append(tok)
    argv = expanded
    out: list[str] = []
    it = iter(range(len(argv)))
    for i in it:
        tok = argv[i]
        if tok in ("-a", "--align", "--interpolate"):
            name, values = ("--interpolate", ("se3", "split")) if tok == "--interpolate" else \
                ("--align", ALIGNMENTS)
            nxt = argv[i + 1] if i + 1 < len(argv) else None
            if nxt is not None and nxt in values:
                out += [name, nxt]
                next(it, None)
            else:
                out += [name, values[0] if name == "--interpolate" else "se3"]
        else:
            out.append(tok)
    return out


def _is_bag(path: str) -> bool:
    from .traj.rosbag import is_bag

    return is_bag(path)


class _Source:
    """One trajectory to read: a file in a format, or a bag topic."""

    def __init__(self, path: str, fmt: str, times: str | None = None,
                 topic: str | None = None) -> None:
        self.path, self.fmt, self.times, self.topic = path, fmt, times, topic

    def read(self) -> Any:
        from .traj import read_trajectory

        if self.fmt == "bag" or _is_bag(self.path):
            if not self.topic:
                raise UsageError(f"{self.path} is a ROS bag: give its topic with --topic")
            return read_trajectory(self.path, "bag", topic=self.topic)
        return read_trajectory(self.path, self.fmt, timestamps=self.times)


def _format_word(args: argparse.Namespace, n_files: int | None) -> None:
    """Take evo's leading format word (``ape tum GT EST``) off the positional arguments."""
    files = args.files
    if files and files[0] in (*WRITABLE, *BAG_WORDS) and not os.path.exists(files[0]) and (
        n_files is None or len(files) == n_files + 1 or files[0] in BAG_WORDS
    ):
        word = files.pop(0)
        word = "bag" if word in BAG_WORDS else word
        if args.format is not None and args.format != word:
            raise UsageError(f"format word {word!r} conflicts with --format {args.format}")
        args.format = word


def _two_sources(args: argparse.Namespace) -> tuple[_Source, _Source]:
    """GT and EST sources of ape / rpe / kitti (files, format words, bag topics)."""
    if args.example:
        from .data import example_paths

        if args.files:
            raise UsageError("--example replaces GT and EST: give no files with it")
        gt_path, est_path = (str(p) for p in example_paths())
        return _Source(gt_path, "tum"), _Source(est_path, "tum")
    _format_word(args, 2)
    fmt = args.format or args.default_format
    if fmt == "bag" and len(args.files) == 3:  # evo: bag BAGFILE REF_TOPIC EST_TOPIC
        bag, ref_topic, est_topic = args.files
        return _Source(bag, "bag", topic=ref_topic), _Source(bag, "bag", topic=est_topic)
    if len(args.files) != 2:
        raise UsageError(f"give GT and EST files (got {len(args.files)} arguments), or --example")
    gt_path, est_path = args.files
    ref_fmt = args.ref_format or fmt
    est_fmt = args.est_format or ("tum" if fmt == "euroc" else fmt)
    ref_topic = args.ref_topic or args.topic
    return (_Source(gt_path, ref_fmt, args.gt_times, ref_topic),
            _Source(est_path, est_fmt, args.est_times, args.topic))


def _resolve_align(args: argparse.Namespace) -> str:
    """One alignment method from ``--align``, ``-s/--correct_scale`` and ``--align_origin``."""
    method = args.align
    if args.align_origin:
        if method not in (None, "origin") or args.correct_scale:
            raise UsageError("--align_origin cannot be combined with -a/--align or -s")
        return "origin"
    if args.correct_scale:
        if method in (None, "scale"):
            return "scale"
        if method in ("se3", "sim3"):
            return "sim3"
        raise UsageError(f"-s/--correct_scale cannot be combined with --align {method}")
    return method or "none"


def _interpolation(args: argparse.Namespace) -> str | None:
    if args.sync_method == "interpolation":
        if args.interpolate not in (None, "split"):
            raise UsageError("--sync_method interpolation is --interpolate split")
        return "split"
    return args.interpolate


def _relation(args: argparse.Namespace) -> str:
    return "trans" if args.relation == "trans_part" else args.relation


def _plot_mode(args: argparse.Namespace, fmt: str) -> str:
    from .traj.plot import default_plot_mode

    return args.plot_mode or default_plot_mode(fmt)


# ----------------------------------------------------------------------------- parser
def _add_files(p: argparse.ArgumentParser) -> None:
    p.add_argument("files", nargs="*", metavar="[FORMAT] GT EST",
                   help="reference (ground truth) and estimate files, optionally after a "
                        "format word (tum, kitti, euroc; or bag BAGFILE REF_TOPIC EST_TOPIC)")
    p.add_argument("--example", action="store_true",
                   help="use the example pair bundled with microlie instead of GT and EST")
    _add_formats(p)
    p.add_argument("--gt-times", "--ref-times", dest="gt_times", default=None,
                   help="timestamps file for KITTI GT poses")
    p.add_argument("--est-times", default=None, help="timestamps file for KITTI EST poses")


def _add_formats(p: argparse.ArgumentParser) -> None:
    p.add_argument("--format", "-f", choices=tuple(FORMATS), default=None,
                   help="file format (default tum; the leading format word sets it too)")
    p.add_argument("--ref-format", choices=tuple(FORMATS), default=None,
                   help="format of the reference (default: --format)")
    p.add_argument("--est-format", choices=tuple(FORMATS), default=None,
                   help="format of the estimate(s) (default: --format; tum for euroc)")
    p.add_argument("--topic", default=None,
                   help="ROS bag topic of the estimate (and of the reference unless "
                        "--ref-topic); /tf:PARENT.CHILD for tf frames")
    p.add_argument("--ref-topic", default=None, help="ROS bag topic of the reference")


def _add_sync(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("time association and preprocessing")
    g.add_argument("--max-diff", "--t_max_diff", dest="max_diff", type=float, default=0.01,
                   help="max. timestamp difference for association, s (default 0.01)")
    g.add_argument("--offset", "--t_offset", dest="offset", type=float, default=0.0,
                   help="time offset added to EST timestamps for association, s")
    g.add_argument("--t-start", "--t_start", dest="t_start", type=float, default=None,
                   help="only use reference poses at or after this time (absolute, s)")
    g.add_argument("--t-end", "--t_end", dest="t_end", type=float, default=None,
                   help="only use reference poses at or before this time (absolute, s)")
    g.add_argument("--downsample", type=int, default=None, metavar="N",
                   help="keep at most N poses of each trajectory (evenly spaced), before "
                        "association")
    g.add_argument("--interpolate", nargs="?", const="se3", choices=("se3", "split"),
                   default=None,
                   help="interpolate the denser trajectory at the matched stamps of the "
                        "other: se3 geodesic (default) or split (linear + slerp, evo's)")
    g.add_argument("--sync_method", choices=("nearest_time", "interpolation"),
                   default="nearest_time", help="evo's spelling: interpolation = "
                   "--interpolate split")


def _add_align(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("alignment")
    g.add_argument("--align", "-a", choices=ALIGNMENTS, default=None, metavar="METHOD",
                   help="align EST to GT: se3 (default of a bare -a), sim3, scale, origin, none")
    g.add_argument("--correct_scale", "-s", action="store_true",
                   help="evo: correct the scale (with -a: sim3; alone: scale only)")
    g.add_argument("--align_origin", action="store_true",
                   help="evo: make the first poses coincide (= --align origin)")
    g.add_argument("--n-align", "--n_to_align", dest="n_align", type=int, default=None,
                   metavar="N", help="align on the first N pose pairs only")


def _add_console(g: Any) -> None:
    g.add_argument("--no_warnings", action="store_true",
                   help="accepted for evo compatibility (microlie never asks to confirm)")
    g.add_argument("--silent", action="store_true",
                   help="print nothing but warnings and errors (evo's --silent)")
    g.add_argument("--logfile", default=None, metavar="FILE",
                   help="also append everything printed (even with --silent) to FILE")


def _add_plot_files(g: Any) -> None:
    g.add_argument("--plot", nargs="?", action=_PlotAction, default=None, metavar="FILE",
                   help="write the plot to FILE (PNG, 1200x800 px; the format from the "
                        "suffix); without FILE (evo's flag) show it in a window")
    g.add_argument("--save_plot", dest="plot", metavar="FILE", help="evo: --plot FILE")
    g.add_argument("-p", dest="show_plot", action="store_true",
                   help="evo: show the plot in a window (needs a display)")


def _add_output(p: argparse.ArgumentParser, plot: bool = True) -> None:
    g = p.add_argument_group("output")
    g.add_argument("--json", action="store_true", help="print the result as JSON")
    g.add_argument("-v", "--verbose", action="store_true",
                   help="also print the alignment transform and scale, and file details")
    _add_console(g)
    if plot:
        _add_plot_files(g)
        g.add_argument("--force", action="store_true", help=_FORCE_HELP)
        g.add_argument("--plot-mode", "--plot_mode", dest="plot_mode", choices=PLOT_MODES,
                       default=None,
                       help="plane of the path plot (horizontal, vertical axis) or xyz for "
                            "3-D; default xz for KITTI, xy otherwise")


_FORCE_HELP = "allow the files written (plots, results, --save-as) to overwrite an input file"


def _check_outputs(args: argparse.Namespace, inputs: Sequence[Any],
                   outputs: dict[str, Any]) -> None:
    """Refuse, before anything is written, an output (option -> path) that is an input file
    (unless ``--force``)."""
    from ._files import check_not_input

    for option, path in outputs.items():
        try:
            check_not_input(path, inputs, option=option, force=getattr(args, "force", False))
        except ValueError as e:
            raise UsageError(str(e)) from None


def _add_metric(p: argparse.ArgumentParser) -> None:
    _add_files(p)
    _add_sync(p)
    _add_align(p)
    g = p.add_argument_group("metric")
    g.add_argument("--relation", "-r", "--pose_relation", dest="relation", choices=RELATIONS,
                   default="trans", help="pose relation (default trans = evo's trans_part); "
                   "rot = rotation angle in --angle-unit; point_distance_error_ratio (RPE "
                   "only): length error of each displacement in %% of the reference's")
    g.add_argument("--angle-unit", choices=("deg", "rad"), default="deg",
                   help="unit of --relation rot (default deg)")
    g.add_argument("--project-to-plane", "--project_to_plane", dest="project", choices=PLANES,
                   default=None, help="project both trajectories onto a plane after the "
                   "alignment (2-D evaluation)")
    g.add_argument("--change-unit", "--change_unit", dest="change_unit", choices=UNITS,
                   default=None, help="express the errors in another unit: mm, cm, m, km "
                   "(lengths) or deg, rad (angles)")
    _add_output(p)
    p.add_argument("--plot-x-dimension", "--plot_x_dimension", dest="plot_x_dimension",
                   choices=X_DIMENSIONS, default=None,
                   help="abscissa of the error plot: seconds (default; the index without "
                        "timestamps), index, or distances (m travelled along the reference)")
    p.add_argument("--save-results", "--save_results", dest="save_results", default=None,
                   metavar="FILE", help="save options, statistics, timestamps and per-pose "
                   "errors as JSON (read by microlie res)")


EXAMPLES = {
    "ape": """examples:
  microlie ape groundtruth.txt estimate.txt -a se3
  microlie ape tum groundtruth.txt estimate.txt -a             (evo spelling)
  microlie ape kitti 00.txt 00_est.txt -as -r angle_deg --plot ape.png
  microlie ape euroc data.csv estimate.txt -a --save-results ape.json
  microlie ape bag run.bag /ground_truth /odom -a""",
    "rpe": """examples:
  microlie rpe groundtruth.txt estimate.txt --delta 1 --unit m -r rot
  microlie rpe tum groundtruth.txt estimate.txt -d 10 -u f --all_pairs
  microlie rpe tum groundtruth.txt estimate.txt -d 30 -u d -r angle_deg""",
    "kitti": """example:
  microlie kitti 00.txt 00_est.txt --json""",
    "traj": """examples:
  microlie traj a.txt b.txt                          (poses, duration, length, rate)
  microlie traj est.txt --ref gt.txt -a se3 --plot traj.png
  microlie traj kitti 00.txt --save-as tum out/      (convert)
  microlie traj part1.txt part2.txt --merge --save-as tum out/""",
    "res": """examples:
  microlie ape gt.txt a.txt -a --save-results a.json
  microlie ape gt.txt b.txt -a --save-results b.json
  microlie res a.json b.json --plot res.png
  microlie res a.zip b.zip --save_plot res.png --plot-kind all   (evo archives; evo_res's
      five figures: res_raw.png res_stats.png res_histogram.png res_box_plot.png
      res_violin_histogram.png)
  microlie res a.json b.zip --plot-kind box,violin --save_plot res.pdf --save_table res.csv""",
    "plot": """example:
  microlie plot gt.txt est.txt -o traj.png -a se3 --plot-mode xz""",
}


def _sub(sub: Any, name: str, help_text: str) -> argparse.ArgumentParser:
    return sub.add_parser(name, help=help_text, description=help_text, epilog=EXAMPLES[name],
                          formatter_class=argparse.RawDescriptionHelpFormatter)


def _register_ape(sub: Any) -> None:
    p = _sub(sub, "ape", "absolute pose error (APE)")
    _add_metric(p)
    p.set_defaults(func=_run_metric, default_format="tum")


def _register_rpe(sub: Any) -> None:
    p = _sub(sub, "rpe", "relative pose error (RPE)")
    _add_metric(p)
    g = p.add_argument_group("pairs")
    g.add_argument("--delta", "-d", type=float, default=1.0, help="pair separation (default 1)")
    g.add_argument("--unit", "-u", "--delta_unit", dest="unit", choices=DELTA_UNITS,
                   default="frames", help="unit of --delta: frames (f), m, deg (d), rad (r)")
    g.add_argument("--all-pairs", "--all_pairs", dest="all_pairs", action="store_true",
                   help="all pairs separated by delta instead of consecutive ones")
    g.add_argument("--delta-tol", "--delta_tol", dest="delta_tol", type=float, default=0.1,
                   help="relative tolerance on delta in all-pairs m/deg/rad mode (default 0.1)")
    g.add_argument("--pairs-from", choices=("est", "ref"), default="est",
                   help="trajectory on which pairs are chosen (default est, as evo)")
    g.add_argument("--pairs_from_reference", dest="pairs_from", action="store_const",
                   const="ref", help="evo: --pairs-from ref")
    p.set_defaults(func=_run_metric, default_format="tum")


def _register_kitti(sub: Any) -> None:
    p = _sub(sub, "kitti", "KITTI odometry metric (100-800 m segments)")
    _add_files(p)
    g = p.add_argument_group("time association")
    g.add_argument("--max-diff", "--t_max_diff", dest="max_diff", type=float, default=0.01,
                   help="max. timestamp difference for association, s (default 0.01)")
    g.add_argument("--offset", "--t_offset", dest="offset", type=float, default=0.0,
                   help="time offset added to EST timestamps for association, s")
    p.add_argument("--step", type=int, default=10, help="start every STEP frames (default 10)")
    _add_output(p, plot=False)
    p.set_defaults(func=_run_kitti, default_format="kitti")


def _register_traj(sub: Any) -> None:
    p = _sub(sub, "traj", "inspect, align, merge, convert and plot trajectory files")
    p.add_argument("files", nargs="*", metavar="[FORMAT] FILE",
                   help="trajectory files, optionally after a format word (tum, kitti, "
                        "euroc; or bag BAGFILE TOPIC...)")
    _add_formats(p)
    p.add_argument("--ref", default=None, help="reference file (aligned to with --align)")
    _add_sync(p)
    _add_align(p)
    p.add_argument("--merge", action="store_true",
                   help="merge the files into one trajectory, sorted by time")
    p.add_argument("--project-to-plane", "--project_to_plane", dest="project", choices=PLANES,
                   default=None, help="project the trajectories onto a plane")
    p.add_argument("--save-as", nargs=2, metavar=("FORMAT", "DIR"), default=None,
                   help="write every trajectory (after processing) in FORMAT (tum, kitti, "
                        "euroc) to DIR")
    _add_output(p)
    p.set_defaults(func=_run_traj, default_format="tum", example=False)


def _register_res(sub: Any) -> None:
    p = _sub(sub, "res", "tabulate and plot results saved with --save-results (or evo's "
             "--save_results archives)")
    p.add_argument("files", nargs="+", help="result files: JSON written by microlie ape/rpe, "
                   "or evo result archives (.zip)")
    g = p.add_argument_group("output")
    g.add_argument("--json", action="store_true", help="print the table as JSON")
    g.add_argument("-v", "--verbose", action="store_true", help="accepted (evo)")
    _add_console(g)
    _add_plot_files(g)
    g.add_argument("--plot-kind", "--plot_kind", dest="plot_kind", default=None,
                   metavar="KIND[,KIND...]",
                   help="figure(s) to plot: summary (default: errors and statistics side by "
                        "side), raw, stats, histogram, box, violin, or all (evo_res's five: "
                        "raw, stats, histogram, box, violin); several figures go to "
                        "FILE_raw.png, FILE_box_plot.png, ... (evo's names) or to the pages "
                        "of one PDF")
    g.add_argument("--use-rel-time", "--use_rel_time", dest="rel_time", action="store_true",
                   help="time axis of each result from its own first error (evo_res)")
    g.add_argument("--save-table", "--save_table", dest="save_table", default=None,
                   metavar="FILE", help="write the statistics table as CSV (evo_res's format: "
                   "one row per result file)")
    g.add_argument("--use_filenames", action="store_true",
                   help="accepted (evo_res): microlie always labels results by file name")
    g.add_argument("--ignore_title", action="store_true",
                   help="do not warn when the results measure different things")
    g.add_argument("--force", action="store_true", help=_FORCE_HELP)
    p.set_defaults(func=_run_res, show_plot=False)


def _register_plot(sub: Any) -> None:
    p = _sub(sub, "plot", "plot trajectories (path, xyz and rpy over time)")
    p.add_argument("files", nargs="*", help="trajectory files; the first is the reference")
    p.add_argument("--example", action="store_true", help="plot the bundled example pair")
    p.add_argument("-o", "--output", required=True, help="output image file (PNG)")
    p.add_argument("--force", action="store_true", help=_FORCE_HELP)
    _add_formats(p)
    _add_align(p)
    p.add_argument("--max-diff", "--t_max_diff", dest="max_diff", type=float, default=0.01,
                   help="max. timestamp difference when aligning, s (default 0.01)")
    p.add_argument("--plot-mode", "--plot_mode", dest="plot_mode", choices=PLOT_MODES,
                   default=None, help="plane of the path plot; default xz for KITTI, xy "
                   "otherwise")
    p.set_defaults(func=_run_plot, default_format="tum")


# Subcommands in the order ``microlie -h`` lists them; each entry adds one subparser whose
# ``func(args, out, err)`` runs it. Another package's command is one more entry here.
def _register_optimize(sub: Any) -> None:
    from .optim.command import register  # argparse only: the solver is imported on use

    register(sub)


COMMANDS: list[Callable[[Any], None]] = [
    _register_ape, _register_rpe, _register_kitti, _register_traj, _register_res,
    _register_plot, _register_optimize,
]


class _VersionAction(argparse.Action):
    """``--version``: one line, the version and which kernels are active (compiled, with the ISA
    of the build and the version of the hot loops running on this CPU, or generic and why;
    :func:`microlie._fast.describe`), computed only when asked."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        from . import __version__, _fast

        sys.stdout.write(f"microlie {__version__}; {_fast.describe()}\n")
        parser.exit()


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser of the ``microlie`` command (with ``command``, e.g. ``"ape"``: only
    that subcommand, which is all :func:`main` needs to run it)."""
    parser = argparse.ArgumentParser(
        prog="microlie",
        description="microlie from the shell: trajectory evaluation (APE, RPE, KITTI metric, "
                    "trajectory files, saved results, plots) and the other subcommands below.",
        epilog="exit status: 0 ok, 1 data or runtime error, 2 usage error, 3 missing optional "
               "dependency.\nexample: microlie ape tum groundtruth.txt estimate.txt -a",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action=_VersionAction, nargs=0,
                        help="print the version and which kernels are active, then exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for register in COMMANDS:
        if command is None or register.__name__ == f"_register_{command}":
            register(sub)
    return parser


# ----------------------------------------------------------------------------- ape / rpe
STAT_KEYS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def _print_stats(title: str, stats: dict, out: TextIO) -> None:
    out.write(title + "\n\n")
    for key in STAT_KEYS:
        out.write(f"{key:>10s}  {stats[key]:.6f}\n")


_ALIGN_NAMES = {"se3": "SE(3) Umeyama", "sim3": "Sim(3) Umeyama", "scale": "scale only",
                "origin": "origin", "none": "none"}


def _alignment_line(info: dict) -> str:
    method = info.get("alignment", "none")
    line = f"alignment: {_ALIGN_NAMES[method]}"
    if "aligned_poses" in info:
        line += f" on the first {info['aligned_poses']} pose pairs"
    if method in ("sim3", "scale"):
        line += f", scale {info['alignment_scale']:.6f}"
    return line


def _title(res: Any) -> str:
    info = res.info
    lines = [res.label]
    if res.metric == "rpe":
        lines.append(f"for delta = {info['delta']:g} {info['delta_unit']}"
                     f"{' (all pairs)' if info['all_pairs'] else ''}")
    lines.append(_alignment_line(info))
    if info.get("project"):
        lines.append(f"projected to the {info['project']} plane")
    parts = []
    if "pairs" in info:
        parts.append(f"{info['pairs']} of max. {info['max_pairs']} pose pairs associated"
                     + (f" ({info['interpolate']} interpolation)" if info.get("interpolate")
                        else ""))
    parts.append(f"{res.errors.size} errors")
    lines.append(", ".join(parts))
    return "\n".join(lines)


def _verbose_alignment(info: dict, out: TextIO) -> None:
    tf = info.get("alignment_transform")
    if not tf:
        out.write("alignment transform: none\n\n")
        return
    out.write("alignment transform (applied to the estimate: p -> s R p + t, R_i -> R R_i)\n")
    out.write("  rotation qx qy qz qw  " + " ".join(f"{v:.9f}" for v in
                                                     tf["rotation_quat_xyzw"]) + "\n")
    out.write("  translation           " + " ".join(f"{v:.9f}" for v in tf["translation"])
              + "\n")
    out.write(f"  scale                 {tf['scale']:.9f}\n  matrix\n")
    for row in tf["matrix"]:
        out.write("    " + " ".join(f"{v:13.9f}" for v in row) + "\n")
    out.write("\n")


def _warn_duplicates(res: Any, err: TextIO) -> None:
    dup = res.info.get("duplicate_timestamps")
    if dup:
        err.write(
            f"warning: repeated timestamps (GT {dup[0]}, EST {dup[1]}); each estimate pose is "
            "paired with the nearest GT pose (the last of equal stamps)\n"
        )


def _options(args: argparse.Namespace, keys: Sequence[str]) -> dict:
    return {k: getattr(args, k) for k in keys if getattr(args, k, None) is not None}


def _run_metric(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    from .traj import evaluate_ape, evaluate_rpe

    ref_src, est_src = _two_sources(args)
    if args.command == "ape" and args.relation == "point_distance_error_ratio":
        raise UsageError("-r point_distance_error_ratio is an RPE relation (evo_rpe's): use "
                         "microlie rpe ... -r point_distance_error_ratio")
    _check_outputs(args, [ref_src.path, est_src.path, ref_src.times, est_src.times],
                   {"--save-results": args.save_results, "--plot": args.plot})
    if args.plot_x_dimension is not None and not (args.plot or args.show_plot):
        raise UsageError("--plot_x_dimension sets the error plot's abscissa: give --plot FILE "
                         "/ --save_plot FILE or -p as well")
    common = dict(relation=_relation(args), align=_resolve_align(args), n_align=args.n_align,
                  max_diff=args.max_diff, offset=args.offset, angle_unit=args.angle_unit,
                  t_start=args.t_start, t_end=args.t_end, downsample=args.downsample,
                  interpolate=_interpolation(args), project=args.project)
    ref, est = (s.read() for s in _progress([ref_src, est_src], "reading"))
    if args.command == "ape":
        res = evaluate_ape(ref, est, **common)
    else:
        common.update(delta=args.delta, unit=args.unit, all_pairs=args.all_pairs,
                      rel_tol=args.delta_tol, pairs_from=args.pairs_from)
        res = evaluate_rpe(ref, est, **common)
    if args.change_unit:
        try:
            res = res.change_unit(args.change_unit)
        except ValueError as exc:
            raise UsageError(f"--change_unit {args.change_unit}: "
                             f"{str(exc).split(': ', 1)[-1]}") from None
        common["change_unit"] = args.change_unit
    _warn_duplicates(res, err)
    if args.json:
        d = res.to_dict()
        d["gt"], d["est"] = ref.name, est.name
        out.write(json.dumps(d, indent=2) + "\n")
    else:
        if args.verbose:
            out.write(f"reference {ref.name}: {len(ref)} poses\nestimate  {est.name}: "
                      f"{len(est)} poses\n")
            _verbose_alignment(res.info, out)
        _print_stats(_title(res), res.stats, out)
    if args.save_results:
        from .traj import save_result

        save_result(res, args.save_results, {"command": args.command, **common})
        _note(args, f"results written to {args.save_results}")
    if args.plot or args.show_plot:
        from .traj import plot as tplot

        mode = _plot_mode(args, ref_src.fmt)
        _emit_plots(args, [("error", tplot.plot_error(res, plot_mode=mode,
                                                      x_dimension=args.plot_x_dimension
                                                      or "seconds"))])
    return EXIT_OK


# ----------------------------------------------------------------------------- kitti
def _run_kitti(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    from .traj import evaluate_kitti

    ref_src, est_src = _two_sources(args)
    ref, est = ref_src.read(), est_src.read()
    res = evaluate_kitti(ref, est, step=args.step, max_diff=args.max_diff, offset=args.offset)
    if args.json:
        out.write(json.dumps(res.to_dict(), indent=2) + "\n")
        return EXIT_OK
    out.write("KITTI odometry metric (segments of 100-800 m)\n\n")
    out.write(f"{'length':>8s} {'segments':>9s} {'t_err %':>9s} {'r_err deg/100m':>15s}\n")
    for length, (t, r, k) in res.per_length.items():
        out.write(f"{length:8g} {k:9d} {t:9.4f} {100 * r:15.4f}\n")
    out.write(f"\n{'average':>8s} {res.segments.shape[0]:9d} {res.t_err:9.4f} "
              f"{100 * res.r_err:15.4f}\n")
    out.write(f"\nt_err {res.t_err:.6f} %   r_err {res.r_err:.8f} deg/m\n")
    return EXIT_OK


# ----------------------------------------------------------------------------- traj
def _sources(args: argparse.Namespace) -> list[_Source]:
    _format_word(args, None)
    fmt = args.est_format or args.format or args.default_format
    if fmt == "bag" and args.files and _is_bag(args.files[0]) and len(args.files) > 1 and \
            not _is_bag(args.files[1]):  # evo: bag BAGFILE TOPIC...
        return [_Source(args.files[0], "bag", topic=t) for t in args.files[1:]]
    return [_Source(f, fmt, topic=args.topic) for f in args.files]


def _info(t: Any) -> dict:
    d: dict[str, Any] = {"name": t.name, "poses": len(t), "path_length_m": t.path_length}
    if t.timestamps is not None:
        dur = float(t.timestamps[-1] - t.timestamps[0])
        d.update(t_start=float(t.timestamps[0]), t_end=float(t.timestamps[-1]),
                 duration_s=dur, rate_hz=(len(t) - 1) / dur if dur > 0 else None)
    d["timestamp_problems"] = t.check()
    return d


def _align_to(ref: Any, t: Any, args: argparse.Namespace, method: str) -> tuple[Any, Any]:
    """``t`` moved by the transform that aligns its paired poses onto ``ref``."""
    from .traj import align, prepare

    r, e, _ = prepare(ref, t, max_diff=args.max_diff, offset=args.offset,
                      interpolate=_interpolation(args))
    _, g = align(r, e, method, args.n_align)
    return (t if g is None else t.transform(g)), g


def _file_stem(name: str | None) -> str:
    """Output file stem for a trajectory name: the file's stem; for a bag topic
    ``run.bag:/tf:map.base`` the bag's stem and the topic (``run_tf_map_base``)."""
    if not name:
        return "trajectory"
    path, _, topic = str(name).partition(":")
    stem = Path(path).stem
    if topic:
        stem += "_" + "".join(c if c.isalnum() else "_" for c in topic.strip("/"))
    return stem


def _run_traj(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    from .traj import describe_alignment, merge, read_trajectory, write_trajectory

    sources = _sources(args)
    if not sources:
        raise UsageError("give at least one trajectory file")
    method = _resolve_align(args)
    if method != "none" and not args.ref:
        raise UsageError("--align needs --ref")
    if args.save_as and args.save_as[0] not in WRITABLE:
        raise UsageError(f"--save-as format must be one of {WRITABLE}, got "
                         f"{args.save_as[0]!r}")
    _check_outputs(args, [s.path for s in sources] + [args.ref], {"--plot": args.plot})
    trajs = [s.read() for s in _progress(sources, "reading")]
    ref = None
    if args.ref:
        ref_fmt = args.ref_format or args.format or args.default_format
        ref = read_trajectory(args.ref, "bag" if _is_bag(args.ref) else ref_fmt,
                              topic=args.ref_topic or args.topic)
    if args.merge:
        trajs = [merge(trajs)]
    pre = []
    for t in trajs:
        if args.t_start is not None or args.t_end is not None:
            t = t.crop(args.t_start, args.t_end)
        if args.downsample:
            t = t.downsample(args.downsample)
        pre.append(t)
    trajs = pre
    alignments = []
    if ref is not None and method != "none":
        moved = []
        for t in trajs:
            t2, g = _align_to(ref, t, args, method)
            moved.append(t2)
            alignments.append(describe_alignment(g))
        trajs = moved
    if args.project:
        trajs = [t.project(args.project) for t in trajs]
        ref = ref.project(args.project) if ref is not None else None
    infos = [_info(t) for t in trajs]
    for d, a in zip(infos, alignments, strict=False):
        d["alignment"] = {"method": method, **a}
    if args.json:
        doc: dict[str, Any] = {"trajectories": infos}
        if ref is not None:
            doc["reference"] = _info(ref)
        out.write(json.dumps(doc, indent=2) + "\n")
    else:
        rows = ([("reference", _info(ref))] if ref is not None else []) + \
            [("", d) for d in infos]
        for role, d in rows:
            name = f"{d['name']}{' (reference)' if role else ''}"
            line = f"{name}\n  poses {d['poses']}, path length {d['path_length_m']:.3f} m"
            if "duration_s" in d:
                rate = f"{d['rate_hz']:.3f} Hz" if d["rate_hz"] else "-"
                line += (f", duration {d['duration_s']:.3f} s, rate {rate}, "
                         f"t {d['t_start']:.6f} .. {d['t_end']:.6f}")
            out.write(line + "\n")
            if "alignment" in d:
                a = d["alignment"]
                out.write(f"  aligned to the reference: {_ALIGN_NAMES[a['method']]}"
                          + (f", scale {a['scale']:.6f}" if "scale" in a else "") + "\n")
                if args.verbose and "matrix" in a:
                    for row in a["matrix"]:
                        out.write("    " + " ".join(f"{v:13.9f}" for v in row) + "\n")
            for problem in d["timestamp_problems"]:
                out.write(f"  warning: {problem}\n")
    if args.save_as:
        fmt, folder = args.save_as
        Path(folder).mkdir(parents=True, exist_ok=True)
        ext = FORMATS[fmt].suffix
        targets = [Path(folder) / (_file_stem(t.name) + ext) for t in trajs]
        for target in targets:
            _check_outputs(args, [s.path for s in sources] + [args.ref], {"--save-as": target})
        for t, target in zip(trajs, targets, strict=True):
            write_trajectory(target, t, fmt)
            _note(args, f"wrote {target}")
    if args.plot or args.show_plot:
        from .traj import plot as tplot

        shown = ([ref] if ref is not None else []) + trajs
        fmt0 = args.ref_format if ref is not None and args.ref_format else sources[0].fmt
        _emit_plots(args, [("trajectories", tplot.plot_trajectories(
            shown, plot_mode=_plot_mode(args, fmt0)))])
    return EXIT_OK


# ----------------------------------------------------------------------------- res
def _res_kinds(text: str) -> list[str]:
    kinds: list[str] = []
    for k in text.split(","):
        k = k.strip()
        if k not in RES_PLOTS:
            raise UsageError(f"--plot-kind: unknown kind {k!r}; expected a comma-separated list "
                             f"of {', '.join(RES_PLOTS)}")
        kinds += ["raw", "stats", "histogram", "box", "violin"] if k == "all" else [k]
    return list(dict.fromkeys(kinds))


def _load_any_result(path: str) -> Any:
    """Our JSON result, or an evo result archive (a zip)."""
    from .traj import load_evo_result, load_result

    if os.path.isfile(path) and zipfile.is_zipfile(path):
        return load_evo_result(path)
    return load_result(path)


def _run_res(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    if args.plot_kind is not None and not (args.plot or args.show_plot):
        raise UsageError("--plot-kind chooses figures of --plot FILE / --save_plot FILE / -p: "
                         "give one of them")
    kinds = _res_kinds(args.plot_kind or "summary")
    outputs = [args.save_table] + (_plot_files(args.plot, [RES_PLOT_NAMES[k] for k in kinds])
                                   if args.plot else [])
    _check_outputs(args, args.files, {"--save_table": args.save_table})
    for f in outputs[1:]:
        _check_outputs(args, args.files, {"--plot": f})
    results = [_load_any_result(f) for f in args.files]
    names = [Path(f).name for f in args.files]
    labels = {r.label for r in results}
    if len(labels) > 1 and not args.ignore_title:
        err.write("warning: the results measure different things: " + "; ".join(sorted(labels))
                  + "\n")
    if args.json:
        rows = [{"file": f, "label": r.label, "est": r.est_name, "num_errors": int(r.errors.size),
                 "stats": r.stats, "options": r.options} for f, r in zip(args.files, results,
                                                                         strict=True)]
        out.write(json.dumps({"results": rows}, indent=2) + "\n")
    else:
        width = max(len(n) for n in names)
        out.write(f"{' / '.join(sorted(labels))}\n\n")
        out.write(f"{'result':<{width}s} {'errors':>7s} "
                  + " ".join(f"{k:>12s}" for k in STAT_KEYS) + "\n")
        for n, r in zip(names, results, strict=True):
            out.write(f"{n:<{width}s} {r.errors.size:7d} "
                      + " ".join(f"{r.stats[k]:12.6f}" for k in STAT_KEYS) + "\n")
    if args.save_table:
        lines = ["," + ",".join(STAT_KEYS)] + [
            n + "," + ",".join(repr(float(r.stats[k])) for k in STAT_KEYS)
            for n, r in zip(names, results, strict=True)]
        Path(args.save_table).write_text("\n".join(lines) + "\n", encoding="utf-8")
        _note(args, f"table written to {args.save_table}")
    if args.plot or args.show_plot:
        from .traj import plot as tplot

        _emit_plots(args, [(RES_PLOT_NAMES[k], tplot.plot_results(
            results, names, kind=k, rel_time=args.rel_time)) for k in kinds])
    return EXIT_OK


# ----------------------------------------------------------------------------- plot
def _run_plot(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    from .traj import plot as tplot

    if args.example:
        from .data import example_paths

        sources = [_Source(str(p), "tum") for p in example_paths()]
    else:
        args.default_format = "tum"
        _format_word(args, None)
        if not args.files:
            raise UsageError("give at least one file (or --example)")
        fmt = args.format or "tum"
        ref_fmt = args.ref_format or fmt
        est_fmt = args.est_format or ("tum" if fmt == "euroc" else fmt)
        sources = [_Source(f, ref_fmt if i == 0 else est_fmt,
                           topic=(args.ref_topic or args.topic) if i == 0 else args.topic)
                   for i, f in enumerate(args.files)]
    _check_outputs(args, [s.path for s in sources], {"-o": args.output})
    trajs = [s.read() for s in _progress(sources, "reading")]
    method = _resolve_align(args)
    if method != "none" and len(trajs) > 1:
        args.offset, args.interpolate, args.sync_method = 0.0, None, "nearest_time"
        trajs = [trajs[0]] + [_align_to(trajs[0], t, args, method)[0] for t in trajs[1:]]
    fig = tplot.plot_trajectories(trajs, labels=[s.path for s in sources],
                                  plot_mode=_plot_mode(args, sources[0].fmt))
    tplot.save(fig, args.output)
    _note(args, f"plot written to {args.output}")
    return EXIT_OK


# ----------------------------------------------------------------------------- main
def main(argv: Sequence[str] | None = None, out: TextIO | None = None,
         err: TextIO | None = None) -> int:
    """Entry point of the ``microlie`` console script; returns the exit status (module
    docstring)."""
    out = out or sys.stdout
    err = err or sys.stderr
    argv = _normalize_argv(list(sys.argv[1:] if argv is None else argv))
    # the subcommand's parser only (``microlie -h``, ``--version`` and errors: all of them)
    names = {r.__name__.removeprefix("_register_") for r in COMMANDS}
    parser = build_parser(argv[0] if argv and argv[0] in names else None)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: 0 for --help / --version, 2 for usage errors
        return int(exc.code or 0)
    if getattr(args, "silent", False) and getattr(args, "json", False):
        err.write(f"microlie {args.command}: error: --silent and --json contradict each other "
                  "(--silent prints nothing): drop one\n")
        return EXIT_USAGE
    with contextlib.ExitStack() as stack:
        log = None
        if getattr(args, "logfile", None):
            try:
                log = stack.enter_context(open(args.logfile, "a", encoding="utf-8"))
            except OSError as exc:
                err.write(f"microlie {args.command}: error: --logfile: {exc}\n")
                return EXIT_ERROR
        silent = getattr(args, "silent", False)
        all_err = _Tee(err, log)
        args.note_stream = _Tee(None if silent else err, log)
        args.warn_stream = all_err
        return _run(args, _Tee(None if silent else out, log), all_err)  # type: ignore[arg-type]


def _run(args: argparse.Namespace, out: TextIO, err: TextIO) -> int:
    """Run the parsed command; exceptions become messages and exit statuses."""
    from .traj import TimestampWarning

    try:
        with warnings.catch_warnings():
            # reported by the command itself (with the counts), not as a Python warning
            warnings.simplefilter("ignore", TimestampWarning)
            return int(args.func(args, out, err))
    except UsageError as exc:
        err.write(f"microlie {args.command}: error: {exc}\n")
        return EXIT_USAGE
    except ImportError as exc:
        err.write(f"microlie {args.command}: error: {exc}\n")
        return EXIT_DEPENDENCY
    except (ValueError, OSError) as exc:
        err.write(f"microlie {args.command}: error: {exc}\n")
        return EXIT_ERROR


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
