"""The ``microlie optimize`` command: optimise a pose graph (or another problem) from a file.

::

    microlie optimize IN.g2o [-o OUT.g2o] [--solver lm|gn|dogleg] [--robust huber:1.0]
                     [--init auto|file|odometry|chordal] [--linear-solver auto|supernodal|...]
                     [--max-iter N] [--plot FILE] [--json] [--format auto|g2o|toro|bal]
                     [--blas-threads N]

The reported costs are GTSAM's ``0.5 sum r^T Omega r`` over the file's edges (plain, even with
``--robust``, and without the gauge prior); ``time_s`` is the solve alone (reading, initial
guess and graph construction are reported apart). The gauge is the file's ``FIX`` vertices,
or else a prior on the first pose at its start value. ``--init auto`` takes the file's vertices,
or the odometry chain when the file has none, or chordal when that chain is incomplete (said on
stderr). A progress line per iteration goes to stderr on a terminal. The whole command runs
with one BLAS thread unless ``--blas-threads`` says otherwise (:mod:`microlie.optim.threads`).

Formats are handled by the functions in :data:`FORMATS` (format name -> ``"module:function"``,
imported on use), each called as ``run(args, err) -> dict`` and returning the JSON report: a
new format is one entry there.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from .threads import blas_threads_limit

__all__ = ["register", "run", "run_pose_graph", "FORMATS", "detect_format"]

FORMATS: dict[str, str] = {
    "g2o": "microlie.optim.command:run_pose_graph",
    "toro": "microlie.optim.command:run_pose_graph",
    "bal": "microlie.optim.command_bal:run_bal",
}
SOLVERS = ("lm", "gn", "dogleg")
INITS = ("auto", "file", "odometry", "chordal")


def register(subparsers: Any) -> argparse.ArgumentParser:
    r"""Add the ``optimize`` subcommand to ``subparsers``; its arguments carry ``func``
    (:func:`run`), called with ``(args, out, err)``.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``ArgumentParser.add_subparsers()``.

    Returns
    -------
    argparse.ArgumentParser
        The subcommand's parser.

    Examples
    --------
    >>> import argparse, io, json, os, tempfile
    >>> from microlie.optim.command import register
    >>> path = os.path.join(tempfile.mkdtemp(), "tiny.g2o")
    >>> _ = open(path, "w").write(
    ...     "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    >>> parser = argparse.ArgumentParser(prog="microlie")
    >>> _ = register(parser.add_subparsers())
    >>> args = parser.parse_args(["optimize", path, "--json"])
    >>> args.func(args, io.StringIO(), io.StringIO())
    0
    """
    p = subparsers.add_parser(
        "optimize", help="optimise a pose graph (g2o, TORO) or a bundle adjustment (BAL)",
        description="Optimise a pose graph read from IN; report costs (GTSAM's "
                    "0.5 sum r^T Omega r over the file's edges), iterations and solve time.")
    p.add_argument("input", metavar="IN",
                   help="input file: a g2o or TORO pose graph, or a BAL bundle-adjustment problem")
    p.add_argument("-o", "--output", metavar="OUT", default=None,
                   help="write the optimised graph to OUT (format from its extension: "
                        ".graph/.toro for TORO, else the input's format)")
    p.add_argument("--format", "-f", choices=("auto", *FORMATS), default="auto",
                   help="input format (default: detected from the first data line)")
    p.add_argument("--solver", choices=SOLVERS, default="lm",
                   help="lm (Levenberg-Marquardt, default), gn (Gauss-Newton), dogleg")
    p.add_argument("--robust", metavar="LOSS[:SCALE]", default=None,
                   help="robust loss on every edge: huber, cauchy, tukey, geman-mcclure, dcs, "
                        "barron, optionally with a scale, e.g. huber:1.0")
    p.add_argument("--init", choices=INITS, default="auto",
                   help="initial guess: the file's vertices, the odometry chain, or chordal "
                        "(default auto: the file's vertices, else odometry, else chordal)")
    p.add_argument("--linear-solver", default="auto", metavar="NAME",
                   help="linear solver, auto (default) or forced: for pose graphs supernodal, "
                        "scipy, qdldl, pardiso, dense; for BAL dense, sparse, full")
    p.add_argument("--max-iter", type=int, default=100, metavar="N",
                   help="maximum number of iterations (default 100)")
    p.add_argument("--plot", metavar="FILE", default=None,
                   help="draw the initial and optimised graph to FILE (PNG)")
    p.add_argument("--blas-threads", type=int, default=1, metavar="N",
                   help="BLAS threads for the whole command (default 1: a multithreaded BLAS "
                        "is several times slower on a busy machine); 0 keeps the BLAS "
                        "library's setting (OPENBLAS_NUM_THREADS or one thread per core)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)
    return p


def detect_format(path: str | Path) -> str:
    r"""The format of a file from its first data line.

    Parameters
    ----------
    path : str or pathlib.Path
        The file.

    Returns
    -------
    str
        ``"g2o"``, ``"toro"`` or ``"bal"``.

    Raises
    ------
    ValueError
        No known format.

    Examples
    --------
    >>> import argparse, io, json, os, tempfile
    >>> from microlie.optim.command import register
    >>> path = os.path.join(tempfile.mkdtemp(), "tiny.g2o")
    >>> _ = open(path, "w").write(
    ...     "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    >>> parser = argparse.ArgumentParser(prog="microlie")
    >>> _ = register(parser.add_subparsers())
    >>> from microlie.optim.command import detect_format
    >>> detect_format(path)
    'g2o'
    """
    with open(path, encoding="utf-8") as f:
        for line in f:
            toks = line.split()
            if not toks or toks[0].startswith("#"):
                continue
            tag = toks[0]
            if tag in ("VERTEX2", "EDGE2", "VERTEX3", "EDGE3"):
                return "toro"
            if tag.startswith(("VERTEX_", "EDGE_")) or tag == "FIX":
                return "g2o"
            if len(toks) == 3 and all(t.isdigit() for t in toks):
                return "bal"
            raise ValueError(f"{path}:1: cannot tell the file format from {tag!r}; "
                             "give --format")
    raise ValueError(f"{path}: the file has no data lines")


def _handler(fmt: str) -> Any:
    target = FORMATS.get(fmt)
    if target is None:
        raise ValueError(f"format {fmt!r} is not supported here (known: {', '.join(FORMATS)})")
    module, _, name = target.partition(":")
    return getattr(importlib.import_module(module), name)


def run(args: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None) -> int:
    r"""Run ``microlie optimize`` with parsed ``args``.

    Parameters
    ----------
    args : argparse.Namespace
        From the parser of :func:`register`.
    out, err : text streams, optional
        Where the report and the messages go (default stdout and stderr).

    Returns
    -------
    int
        The exit status (0 on success).

    Examples
    --------
    >>> import argparse, io, json, os, tempfile
    >>> from microlie.optim.command import register
    >>> path = os.path.join(tempfile.mkdtemp(), "tiny.g2o")
    >>> _ = open(path, "w").write(
    ...     "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    >>> parser = argparse.ArgumentParser(prog="microlie")
    >>> _ = register(parser.add_subparsers())
    >>> from microlie.optim.command import run
    >>> out = io.StringIO()
    >>> run(parser.parse_args(["optimize", path, "--json"]), out, io.StringIO())
    0
    >>> round(json.loads(out.getvalue())["final_cost"], 12)
    0.0
    """
    out = out or sys.stdout
    err = err or sys.stderr
    fmt = detect_format(args.input) if args.format == "auto" else args.format
    args.format = fmt
    threads = getattr(args, "blas_threads", 1)
    if threads < 0:
        raise ValueError(f"--blas-threads must be >= 0 (0: the BLAS library's setting), "
                         f"not {threads}")
    with blas_threads_limit(threads or None):  # the solvers below keep it (blas_threads=None)
        report = _handler(fmt)(args, err)
    if args.json:
        out.write(json.dumps(report) + "\n")
    else:
        out.write(_summary(report) + "\n")
    return 0


def _summary(r: dict) -> str:
    head = f"{r['file']}: {r.get('problem', '')}".rstrip()
    return (f"{head}\n  {r['solver']} ({r['linear_solver']}), start {r.get('init', '-')}: "
            f"cost {r['initial_cost']:.10g} -> {r['final_cost']:.10g} in {r['iterations']} "
            f"iterations, {r['time_s']:.3f} s, "
            f"{'converged' if r['converged'] else 'not converged'} ({r['message']})")


def _read(path: str, fmt: str) -> Any:
    if fmt == "toro":
        from .toro import read_toro

        return read_toro(path)
    from .g2o import read_g2o

    return read_g2o(path)


def _write(path: str, graph: Any, poses: Any, fmt: str) -> None:
    suffix = Path(path).suffix.lower()
    if suffix in (".graph", ".toro") or (fmt == "toro" and suffix != ".g2o"):
        from .toro import write_toro

        write_toro(path, graph, poses)
    else:
        from .g2o import write_g2o

        write_g2o(path, graph, poses)


def run_pose_graph(args: argparse.Namespace, err: TextIO) -> dict:
    r"""Read, initialise, optimise, write and plot one pose graph.

    Parameters
    ----------
    args : argparse.Namespace
        From the parser of :func:`register` (with ``format`` resolved).
    err : text stream
        Where messages go.

    Returns
    -------
    dict
        The JSON report.

    Examples
    --------
    >>> import argparse, io, json, os, tempfile
    >>> from microlie.optim.command import register
    >>> path = os.path.join(tempfile.mkdtemp(), "tiny.g2o")
    >>> _ = open(path, "w").write(
    ...     "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0.9 0 0\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n")
    >>> parser = argparse.ArgumentParser(prog="microlie")
    >>> _ = register(parser.add_subparsers())
    >>> from microlie.optim.command import run_pose_graph
    >>> args = parser.parse_args(["optimize", path, "--format", "g2o"])
    >>> report = run_pose_graph(args, io.StringIO())
    >>> report["initial_cost"] > report["final_cost"]
    True
    """
    from .init import InitMethod, initialize

    t0 = time.perf_counter()
    graph = _read(args.input, args.format)
    t1 = time.perf_counter()
    init: InitMethod
    if args.init == "auto":
        init = "file" if graph.poses is not None else "odometry"
        try:
            X0 = initialize(graph, init)
        except ValueError as e:  # no vertices and no complete odometry chain
            init = "chordal"
            err.write(f"microlie optimize: {e}; starting from the chordal initialisation\n")
            X0 = initialize(graph, init)
    else:
        init = args.init
        X0 = initialize(graph, init)
    t2 = time.perf_counter()
    fg, poses = graph.to_factor_graph(X0, loss=args.robust)
    t3 = time.perf_counter()
    res = fg.optimize(solver=args.solver, linear_solver=args.linear_solver,
                      max_iter=args.max_iter, verbose=_progress(err), blas_threads=None)
    X = res.values[poses]
    report = {
        "file": str(args.input),
        "format": args.format,
        "problem": f"{graph.group.__name__} pose graph, {graph.num_vertices} poses, "
                   f"{graph.num_edges} edges",
        "group": graph.group.__name__,
        "num_vertices": graph.num_vertices,
        "num_edges": graph.num_edges,
        "init": init,
        "robust": args.robust,
        "solver": args.solver,
        "linear_solver": res.linear_solver,
        "initial_cost": graph.cost(X0),
        "final_cost": graph.cost(X),
        "final_robust_cost": res.final_robust_cost,  # the minimised objective (gauge prior in)
        "iterations": res.iterations,
        "time_s": res.time_s,
        "converged": bool(res.converged),
        "message": res.message,
        "read_s": t1 - t0,
        "init_s": t2 - t1,
        "build_s": t3 - t2,
        "timings": {k: float(v) for k, v in res.timings.items()},
    }
    if args.output:
        _write(args.output, graph, X, args.format)
        report["output"] = str(args.output)
    if args.plot:
        from .plot import plot_pose_graph

        plot_pose_graph(graph, X0, X, args.plot, title=Path(args.input).name)
        report["plot"] = str(args.plot)
    return report


def _progress(err: TextIO) -> bool:
    return bool(getattr(err, "isatty", None) and err.isatty())
