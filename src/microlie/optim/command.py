"""The ``microlie optimize`` command: optimise a pose graph (or another problem) from a file.

::

    microlie optimize (IN.g2o | --example) [-o OUT.g2o] [--solver lm|gn|dogleg|trust-region]
                     [--robust huber:1.0|gnc-tls|gnc-gm] [--known-inliers odometry]
                     [--gnc-quantile P]
                     [--gnc-first auto|values|least-squares|chordal|cycles]
                     [--gnc-cycle-length N] [--gnc-moves | --no-gnc-moves]
                     [--gnc-search] [--gnc-assemble] [--gnc-chain]
                     [--gnc-variance-factor V|estimate]
                     [--init auto|file|odometry|chordal|certified]
                     [--certify]
                     [--linear-solver auto|cholesky|schur|...]
                     [--max-iter N] [--abs-tol T] [--rel-tol T]
                     [--gauge check|fix_first|none] [--plot FILE] [--json]
                     [--format auto|g2o|toro|bal] [--force] [-v | -q] [--blas-threads N]
                     [--damping auto|identity|diagonal]
                     [--information strict|nearest-psd|isotropic]

The reported costs are GTSAM's ``0.5 sum r^T Omega r`` over the file's edges (plain, even with
``--robust``, and without the gauge prior); ``time_s`` is the solve alone (reading, initial
guess and graph construction are reported apart). The gauge is the file's ``FIX`` vertices,
or else a prior on the first pose at its start value; a part of the graph that no edge joins
to it is an error unless ``--gauge fix_first`` (hold its first vertex) or ``--gauge none``
(:meth:`~microlie.optim.FactorGraph.optimize`'s ``gauge``). ``--init auto`` takes the file's
vertices, or the odometry chain when the file has none, or chordal when that chain is
incomplete (said on stderr). Before the solve a header line (file, problem size, solver,
start) goes to stderr, flushed, unless ``--quiet``; then Ceres' iteration table, one flushed
line per iteration, with ``--verbose`` or on a terminal (stdout, with ``--json`` too, carries
the report only). ``--damping`` picks LM's damping matrix
(:class:`~microlie.optim.core.strategies.LevenbergMarquardt`; ``auto``, the default, does
not depend on the units); ``--information`` what the reader does with information matrices
that are not positive definite (:mod:`microlie.optim.io.information`; the report's
``repaired_edges`` counts them). ``-o`` or ``--plot`` onto the input file is refused
without ``--force``; every file is written to a temporary file renamed into place, so a
failed write leaves the old file as it was. The whole command runs with one BLAS thread
unless ``--blas-threads`` says otherwise (:mod:`microlie.optim.core.threads`).

``--example`` replaces IN (giving both, or neither, is a usage error): it solves the synthetic
2-D pose graph of :func:`microlie.data.example_pose_graph` (500 poses, 693 edges, made from a
seed, nothing read from disk) from its drifting odometry start, and reports beside the costs
the RMS position error against the ground truth before and after.

``--init certified`` starts from the global minimiser of SE-Sync's isotropic objective, solved
with a certificate (:mod:`microlie.optim.certify`; the report's ``certified_init``, and a
warning when it does not verify). ``--certify`` certifies the answer (report ``certificate``):
whether it is at the global minimum of that objective, after refining its rotations to the
nearest critical point of it (``moved``: the largest rotation change, rad); a local minimum
is reported "NOT certified".

The report's ``termination`` is the solver's (:class:`~microlie.optim.core.solvers.Result`):
``convergence`` and ``no_convergence`` (``--max-iter`` reached; printed "not converged")
exit with status 0, as Ceres calls both usable; ``failure`` (the cost could not be decreased)
prints the reason on stderr, writes no ``-o`` file and exits with status 1.

``--robust gnc-tls`` (or ``gnc-gm``) runs graduated non-convexity
(:mod:`microlie.optim.core.gnc`) instead of a loss: the gauge prior and, with
``--known-inliers odometry``, the edges between consecutive vertex ids keep weight 1.
``--gnc-first`` is ``GNC(first=...)``: by default ``auto``, which for ``gnc-tls`` on a pose
graph is ``cycles`` (GNC-TLS on the chordal relaxation first, with the edges that close a short
cycle within their noise kept as inliers: cycles of up to 8 edges and the rigid moves after GNC
in 3-D, cycles of up to 5 edges and no moves in 2-D) and otherwise ``values`` (``chordal``:
without the cycle marking; ``values``: plain GNC from the start). With the cycle marking the
file's covariances are scaled by the variance factor of the cycle-consistent edges
(``--gnc-variance-factor``, default ``estimate``; a number sets it, 1 keeps the file's), the
inlier threshold is then the ``--gnc-quantile`` chi-square quantile (default 1 - 1e-6 with
the estimate, family-wise; 0.99 otherwise), and the spanning tree of the edges between the
nearest vertex ids (the odometry) breaks exact ties and is tried as known inliers
(``--gnc-chain`` / ``--no-gnc-chain``). ``--gnc-cycle-length N``, ``--gnc-moves`` /
``--no-gnc-moves``, ``--gnc-search`` and ``--gnc-assemble`` set ``GNC(cycle_length=N,
moves=..., search=True, assemble=True)`` (``gnc.options`` in the JSON report: what ``auto``
and the defaults became), and the report lists the edges judged outliers
(``gnc.outlier_edges``, in file order) and the pieces of the answer that another edge could
hold at the same cost (``gnc.ties``).

Formats come from the registry :data:`microlie.optim.io.formats.FORMATS`: its handler is called
as ``handler(args, err) -> dict`` and returns the JSON report; a new format is one entry there.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path
from typing import Any, TextIO

from .core.threads import blas_threads_limit
from .io.formats import FORMATS, detect_format, output_format

__all__ = ["register", "run", "run_pose_graph", "policy_options"]

SOLVERS = ("lm", "gn", "dogleg", "trust-region")  # microlie.optim.core.strategies
INITS = ("auto", "file", "odometry", "chordal", "certified")
GAUGES = ("check", "fix_first", "none")
KNOWN_INLIERS = ("odometry",)


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
        description="Optimise a pose graph read from IN (or, with --example, the synthetic one "
                    "bundled with microlie); report costs (GTSAM's 0.5 sum r^T Omega r over "
                    "the graph's edges), iterations and solve time.",
        epilog="example: microlie optimize --example --plot example.png")
    source = p.add_mutually_exclusive_group(required=True)
    source.add_argument("input", metavar="IN", nargs="?", default=None,
                        help="input file: a g2o or TORO pose graph, or a BAL bundle-adjustment "
                             "problem")
    source.add_argument("--example", action="store_true",
                        help="instead of IN, the synthetic 2-D pose graph bundled with microlie "
                             "(500 poses on a city grid, odometry and loop closures, with its "
                             "ground truth: microlie.data.example_pose_graph)")
    p.add_argument("-o", "--output", metavar="OUT", default=None,
                   help="write the optimised graph to OUT (format from its extension: "
                        ".graph/.toro for TORO, else the input's format)")
    p.add_argument("--format", "-f", choices=("auto", *FORMATS), default="auto",
                   help="input format (default: detected from the first data line)")
    p.add_argument("--solver", choices=SOLVERS, default=None,
                   help="lm (Levenberg-Marquardt with GTSAM's rules, the default for pose "
                        "graphs), gn (Gauss-Newton), dogleg, trust-region (Levenberg-Marquardt "
                        "with Ceres' rules, the default for BAL)")
    p.add_argument("--robust", metavar="LOSS[:SCALE]", default=None,
                   help="robust loss on every edge: huber, cauchy, tukey, geman-mcclure, dcs, "
                        "barron, optionally with a scale, e.g. huber:1.0; or gnc-tls / gnc-gm: "
                        "graduated non-convexity, which judges every edge and reports the "
                        "outliers")
    # graduated non-convexity (microlie.optim.core.gnc): its own options
    p.add_argument("--known-inliers", choices=KNOWN_INLIERS, default=None,
                   help="with --robust gnc-*: edges that keep weight 1 (odometry: the edges "
                        "between consecutive vertex ids)")
    p.add_argument("--gnc-quantile", type=float, default=None, metavar="P",
                   help="with --robust gnc-*: the chi-square quantile of the inlier threshold "
                        "(default 0.99; lower it when the file's information overstates the "
                        "noise)")
    p.add_argument("--gnc-first", choices=("auto", "values", "least-squares", "chordal",
                                           "cycles"),
                   default=None,
                   help="with --robust gnc-*: where GNC's first weights come from (default "
                        "auto: cycles with gnc-tls on a pose graph, else values; values: the "
                        "start; chordal: GNC-TLS on the chordal relaxation first; cycles: "
                        "chordal with the edges on consistent short cycles kept, see "
                        "microlie.optim.core.gnc.GNC)")
    p.add_argument("--gnc-cycle-length", type=int, default=None, metavar="N",
                   help="with the cycle marking (--gnc-first cycles, or auto with gnc-tls): "
                        "the longest cycle, 2-9 edges (default 8 for SE3, 5 for SE2)")
    p.add_argument("--gnc-moves", action=argparse.BooleanOptionalAction, default=None,
                   help="with the cycle marking (--gnc-first cycles, or auto with gnc-tls): "
                        "after GNC, move pieces rigidly where more of their edges fit, kept "
                        "when the TLS objective falls (default: on for SE3, off for SE2)")
    p.add_argument("--gnc-search", action="store_true",
                   help="with the cycle marking: after GNC, the local search on the TLS "
                        "objective (rigid region moves and their chains; slower, off by "
                        "default)")
    p.add_argument("--gnc-assemble", action="store_true",
                   help="with the cycle marking: join the pieces by cycles of pieces before "
                        "the chordal stage (off by default)")
    p.add_argument("--gnc-variance-factor", type=_variance_factor, default=None,
                   metavar="V|estimate",
                   help="with --robust gnc-*: multiply the file's covariances by V before the "
                        "inlier thresholds apply, or estimate it from the cycle-consistent "
                        "edges (default: estimate with the cycle marking, else 1)")
    p.add_argument("--gnc-chain", action=argparse.BooleanOptionalAction, default=None,
                   help="with the cycle marking: the spanning tree of the edges between the "
                        "nearest vertex ids (the odometry) breaks exact ties and is tried as "
                        "known inliers, kept when the TLS objective is no higher (default: on "
                        "with the cycle marking)")
    p.add_argument("--init", choices=INITS, default="auto",
                   help="initial guess: the file's vertices, the odometry chain, chordal, or "
                        "certified (the certified global optimum of SE-Sync's isotropic "
                        "objective) (default auto: the file's vertices, else odometry, else "
                        "chordal)")
    p.add_argument("--certify", action="store_true",
                   help="pose graphs: say whether the answer is the certified global optimum "
                        "of SE-Sync's isotropic objective or a local minimum")
    p.add_argument("--linear-solver", default="auto", metavar="NAME",
                   help="linear solver, auto (default; schur for BAL) or forced: cholesky, "
                        "schur (landmarks eliminated), scipy, qdldl, pardiso, dense")
    p.add_argument("--max-iter", type=_positive_int, default=100, metavar="N",
                   help="maximum number of iterations, at least 1 (default 100)")
    p.add_argument("--abs-tol", type=_tolerance, default=None, metavar="T",
                   help="--solver lm, gn, dogleg: stop when an iteration lowers the cost by "
                        "less than T (GTSAM's absoluteErrorTol; default 1e-5)")
    p.add_argument("--rel-tol", type=_tolerance, default=None, metavar="T",
                   help="--solver lm, gn, dogleg: stop when an iteration lowers the cost by "
                        "less than T times the cost (GTSAM's relativeErrorTol; default 1e-5)")
    p.add_argument("--gauge", choices=GAUGES, default=None,
                   help="pose graphs: parts of the graph not connected to the first vertex or a "
                        "FIX vertex are an error (check, default), or have their first vertex "
                        "held at its start value (fix_first), or are left free (none: LM's "
                        "damping keeps the system solvable, GN fails); FactorGraph.optimize's "
                        "gauge")
    p.add_argument("--plot", metavar="FILE", default=None,
                   help="draw the initial and optimised graph to FILE (PNG)")
    p.add_argument("--blas-threads", type=int, default=1, metavar="N",
                   help="BLAS threads for the whole command (default 1: a multithreaded BLAS "
                        "is several times slower on a busy machine); 0 keeps the BLAS "
                        "library's setting (OPENBLAS_NUM_THREADS or one thread per core)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--force", action="store_true",
                   help="allow -o or --plot to overwrite the input file")
    _add_policy_options(p)
    # issue 23: replay pose by pose through the incremental smoother
    p.add_argument("--incremental", action="store_true",
                   help="pose graphs: replay the file pose by pose (vertices in id order, each "
                        "edge when its later vertex arrives, new poses predicted through their "
                        "odometry edge) through the incremental smoother and report its "
                        "per-update times (microlie.optim.online.replay)")
    talk = p.add_mutually_exclusive_group()
    talk.add_argument("-v", "--verbose", action="store_true",
                      help="print the iteration table on stderr even when it is not a terminal")
    talk.add_argument("-q", "--quiet", action="store_true",
                      help="print neither the header nor the iterations on stderr")
    p.set_defaults(func=run)
    return p


def _add_policy_options(p: argparse.ArgumentParser) -> None:
    """``--damping`` and ``--information`` (pose graphs; issue 22)."""
    from .core.strategies import DAMPINGS
    from .io.information import INFORMATION_POLICIES

    p.add_argument("--damping", choices=DAMPINGS, default=None,
                   help="--solver lm's damping matrix: auto (default: the identity, as GTSAM, "
                        "where it is negligible against every coordinate's curvature, else "
                        "diag(H), and diag(H) for bundle adjustment; the answer does not "
                        "depend on the units), identity, or diagonal (Marquardt's diag(H))")
    p.add_argument("--information", choices=INFORMATION_POLICIES, default=None,
                   help="pose graphs: information matrices that are not positive definite are "
                        "refused with FILE:LINE and their count (strict, default), replaced by "
                        "the nearest positive definite ones (nearest-psd), or every matrix is "
                        "replaced by SE-Sync's isotropic precisions (isotropic)")


def policy_options(args: argparse.Namespace, solver: str) -> tuple[dict, str]:
    """``--damping`` as the optimiser's keywords (refused with a solver other than ``lm``) and
    ``--information`` resolved (default ``strict``).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments.
    solver : str
        The strategy's name.

    Returns
    -------
    options : dict
        ``{"damping": ...}`` or empty.
    information : str
        The reader's ``information=``.

    Examples
    --------
    >>> import argparse
    >>> from microlie.optim.command import policy_options
    >>> policy_options(argparse.Namespace(damping="diagonal", information=None), "lm")
    ({'damping': 'diagonal'}, 'strict')
    """
    damping = getattr(args, "damping", None)
    if damping is not None and solver != "lm":
        raise ValueError(f"--damping applies to --solver lm, not {solver} (drop --damping)")
    return ({} if damping is None else {"damping": damping}), \
        getattr(args, "information", None) or "strict"


def tolerance_options(args: argparse.Namespace, solver: str) -> dict:
    """``--abs-tol`` and ``--rel-tol`` as the optimiser's keywords (only those given), refused
    with ``--solver trust-region``, whose tests are Ceres' (``function_tolerance`` etc.).

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments.
    solver : str
        The strategy's name.

    Returns
    -------
    dict
        ``abs_tol`` and ``rel_tol`` where given.

    Examples
    --------
    >>> import argparse
    >>> from microlie.optim.command import tolerance_options
    >>> tolerance_options(argparse.Namespace(abs_tol=0.0, rel_tol=None), "lm")
    {'abs_tol': 0.0}
    """
    given = {k: v for k in ("abs_tol", "rel_tol")
             if (v := getattr(args, k, None)) is not None}
    if given and solver not in ("lm", "gn", "dogleg"):
        raise ValueError(f"--abs-tol and --rel-tol apply to --solver lm, gn and dogleg, not "
                         f"{solver} (drop them)")
    return given


def _tolerance(text: str) -> float:
    """argparse type of a convergence tolerance: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0.0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text}")
    return value


def _positive_int(text: str) -> int:
    """argparse type of an iteration count: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive number of iterations, got {value}")
    return value


def _handler(fmt: str) -> Any:
    entry = FORMATS.get(fmt)
    if entry is None:
        raise ValueError(f"format {fmt!r} is not supported here (known: {', '.join(FORMATS)})")
    return entry.load("handler")


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
    from .._files import check_not_input

    force = getattr(args, "force", False)
    example = getattr(args, "example", False)
    if example == (args.input is not None):
        raise ValueError("give an input file IN or --example, not both" if example else
                         "give an input file IN, or --example for the bundled pose graph")
    if example and args.format not in ("auto", "g2o", "toro"):
        raise ValueError(f"--example is a pose graph: --format {args.format} does not apply "
                         "(drop --format)")
    check_not_input(args.output, [args.input], option="-o", force=force)
    check_not_input(args.plot, [args.input], option="--plot", force=force)
    if example:
        fmt = "g2o" if args.format == "auto" else args.format
    else:
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
    if report.get("termination") == "failure":
        err.write(f"microlie optimize: error: the solver failed ({report['message']}); "
                  f"{'no output written' if args.output else 'the result is not a solution'}\n")
        return 1
    return 0


def _summary(r: dict) -> str:
    head = f"{_label(r.get('file'))}: {r.get('problem', '')}".rstrip()
    if r.get("incremental"):
        return (f"{head}\n  incremental replay: {r['updates']} updates, cost {r['final_cost']:.10g}"
                f", {r['total_s']:.3f} s (update median {r['update_ms_median']:.3f} ms, 99th "
                f"percentile {r['update_ms_p99']:.3f} ms), "
                f"{'converged' if r['converged'] else 'not converged'}")
    text = (f"{head}\n  {r['solver']} ({r['linear_solver']}), start {r.get('init', '-')}: "
            f"cost {r['initial_cost']:.10g} -> {r['final_cost']:.10g} in {r['iterations']} "
            f"iterations, {r['time_s']:.3f} s, "
            f"{'converged' if r['converged'] else 'not converged'} ({r['message']})")
    if r.get("repaired_edges"):
        text += (f"\n  --information {r['information']}: {r['repaired_edges']} of "
                 f"{r['num_edges']} edges had information that is not positive definite")
    if r.get("certified_init"):
        text += _certificate_line("start", r["certified_init"])
    if r.get("certificate"):
        text += _certificate_line("certificate", r["certificate"])
    gnc = r.get("gnc")
    if gnc:
        text += (f"\n  {r['robust']}: {gnc['outliers']} of {r['num_edges']} edges judged "
                 f"outliers ({gnc['outer_iterations']} outer iterations)")
    truth = r.get("ground_truth")
    if truth:
        text += (f"\n  position error against the ground truth (RMS): "
                 f"{truth['initial_rmse']:.4g} m -> {truth['final_rmse']:.4g} m")
    return text


def _label(path: str | None) -> str:
    """How the messages name the input: the file, or the bundled example."""
    return "example (microlie.data.example_pose_graph)" if path is None else str(path)


def _read(path: str, fmt: str, information: str = "strict") -> Any:
    return FORMATS[fmt].load("reader")(path, information=information)


def _write(path: str, graph: Any, poses: Any, fmt: str) -> None:
    output_format(path, fmt).load("writer")(path, graph, poses)


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

    if getattr(args, "incremental", False):
        from .online.replay import run_incremental

        return run_incremental(args, err)
    solver = args.solver or "lm"
    solver_options, information = policy_options(args, solver)
    solver_options.update(tolerance_options(args, solver))
    t0 = time.perf_counter()
    truth = None
    if getattr(args, "example", False):
        from ..data import example_pose_graph

        graph, truth = example_pose_graph()
        if information == "isotropic":  # its matrices are positive definite: nothing else
            from .io.information import apply_information_policy

            graph = graph.replace(information=apply_information_policy(
                graph.information, information, graph.dim)[0])
    else:
        graph = _read(args.input, args.format, information)
    t1 = time.perf_counter()
    init: InitMethod
    if args.init == "auto":
        # the example's vertices are its odometry chain: said so
        init = "file" if graph.poses is not None and truth is None else "odometry"
        try:
            X0 = initialize(graph, init)
        except ValueError as e:  # no vertices and no complete odometry chain
            init = "chordal"
            err.write(f"microlie optimize: {e}; starting from the chordal initialisation\n")
            X0 = initialize(graph, init)
    elif args.init == "certified":
        init = "certified"
        start = _certified_start(graph, err)
        X0 = start.poses
    else:
        init = args.init
        X0 = initialize(graph, init)
    t2 = time.perf_counter()
    gnc = _gnc_options(args)
    fg, poses = graph.to_factor_graph(X0, loss=None if gnc else args.robust)
    robust: Any = None
    if gnc is not None:
        robust = _gnc_for(graph, fg, gnc, args)
    t3 = time.perf_counter()
    problem = (f"{graph.group.__name__} pose graph, {graph.num_vertices} poses, "
               f"{graph.num_edges} edges")
    print_header(args, err, f"{problem}; {solver} (linear solver {args.linear_solver}), "
                 f"start {init}, at most {args.max_iter} iterations; read {t1 - t0:.3f} s, "
                 f"init {t2 - t1:.3f} s, build {t3 - t2:.3f} s")
    from .core.problem import GaugeError, NonFiniteError

    gauge = args.gauge or "check"
    try:
        with solver_output_to(err):
            res = fg.optimize(solver=solver, linear_solver=args.linear_solver,
                              max_iter=args.max_iter, gauge=gauge, **solver_options,
                              # run() holds --blas-threads
                              verbose=show_iterations(err, args), blas_threads=None,
                              robust=robust)
    except NonFiniteError as e:  # batch 0 is the file's edges, in order
        what = f"edge {e.row} of the file" if e.factor == 0 else "the gauge prior"
        on = " -> ".join(str(graph.ids[i]) for _, i in e.variables)
        raise NonFiniteError(f"{e} ({what}, vertices {on})", e.factor, e.row,
                             e.variables) from None
    except GaugeError as e:  # in the command's terms: vertex ids and --gauge
        ids = [str(graph.ids[i]) for _, i in e.unanchored]
        anchor = "a FIX vertex" if graph.fixed.size else \
            f"vertex {graph.ids[0]} (held by the gauge prior)"
        raise GaugeError(
            f"the graph has a gauge freedom: {e.count} vertices in {len(ids)} part(s) that no "
            f"edge joins to {anchor}, the parts starting at vertex {', '.join(ids)}; add "
            f"edges, or pass --gauge fix_first to hold the first vertex of each such part at "
            f"its start value", e.unanchored, e.count) from None
    X = res.values[poses]
    report = {
        "file": None if args.input is None else str(args.input),
        "format": args.format,
        "problem": problem,
        "group": graph.group.__name__,
        "num_vertices": graph.num_vertices,
        "num_edges": graph.num_edges,
        "init": init,
        "robust": args.robust,
        "solver": solver,
        "linear_solver": res.linear_solver,
        "initial_cost": graph.cost(X0),
        "final_cost": graph.cost(X),
        "final_robust_cost": res.final_robust_cost,  # the minimised objective (gauge prior in)
        "iterations": res.iterations,
        "time_s": res.time_s,
        "converged": bool(res.converged),
        "termination": res.termination,
        "message": res.message,
        "read_s": t1 - t0,
        "init_s": t2 - t1,
        "build_s": t3 - t2,
        "timings": {k: float(v) for k, v in res.timings.items()},
        "gauge": gauge,
        "gauge_fixed": [int(graph.ids[i]) for _, i in res.gauge_fixed],
        "information": information,
        "repaired_edges": int(graph.repaired.size),
    }
    if init == "certified":
        report["certified_init"] = _certificate_report(start)
    if getattr(args, "certify", False):
        from .certify import certify_poses

        report["certificate"] = _certificate_report(certify_poses(graph, X, blas_threads=None))
    if res.inliers is not None:  # GNC: the file's edges judged outliers (file order)
        bad = [int(k) for k, ok in enumerate(res.inliers[0]) if not ok]
        report["gnc"] = {"outer_iterations": res.outer_iterations,
                         "known_inliers": args.known_inliers,
                         "quantile": robust.resolved(fg.problem(gauge)).quantile,
                         "outliers": len(bad), "outlier_edges": bad}
        used = robust.resolved(fg.problem(gauge))  # what "auto" / None became (cached problem)
        report["gnc"]["options"] = {
            "first": used.first, "cycle_length": used.cycle_length, "moves": used.moves,
            "search": used.search, "assemble": used.assemble, "retest": used.retest,
            "chain": used.chain, "variance_factor": used.variance_factor}
        if res.ties is not None:  # pieces that another edge could hold at the same cost
            def edge(bk: tuple[int, int]) -> int | str:
                return bk[1] if bk[0] == 0 else "prior"

            report["gnc"]["ties"] = [
                {"held_by": edge(t.held_by), "poses": int(t.poses.size),
                 "alternatives": [edge(a) for a in t.alternatives]} for t in res.ties]
    if truth is not None:  # the example: how far the start and the result are from the truth
        report["ground_truth"] = {
            "cost": graph.cost(truth),
            "initial_rmse": _position_rmse(X0, truth),
            "final_rmse": _position_rmse(X, truth),
        }
    if args.output and res.termination != "failure":
        _write(args.output, graph, X, args.format)
        report["output"] = str(args.output)
    if args.plot:
        from .plot import plot_pose_graph

        title = "microlie optimize --example" if args.input is None else Path(args.input).name
        plot_pose_graph(graph, X0, X, args.plot, title=title)
        report["plot"] = str(args.plot)
    return report


def _certified_start(graph: Any, err: TextIO) -> Any:
    """``--init certified``: the certified solver's result (a warning when not certified)."""
    from .certify import certified_pose_graph

    res = certified_pose_graph(graph, blas_threads=None)  # run() holds --blas-threads
    if not res.certified:
        err.write(f"microlie optimize: warning: the certified initialisation did not verify "
                  f"(smallest eigenvalue {res.min_eigenvalue:.6g} < -{res.tolerance:.3g} at "
                  f"rank {res.rank}); starting from its rounded poses\n")
    return res


def _certificate_report(c: Any) -> dict:
    """The JSON fields of a :class:`~microlie.optim.certify.CertifiedResult`."""
    return {"certified": bool(c.certified), "min_eigenvalue": c.min_eigenvalue,
            "tolerance": c.tolerance, "objective": c.objective, "lower_bound": c.lower_bound,
            "cost": c.cost, "rank": c.rank, "moved": c.moved, "time_s": c.time_s}


def _certificate_line(name: str, c: dict) -> str:
    verdict = ("certified global optimum" if c["certified"] else
               "NOT certified (a local minimum)")
    moved = f", rotations refined by at most {c['moved']:.3g} rad" if c["moved"] else ""
    return (f"\n  {name}: {verdict} of SE-Sync's objective F = {c['objective']:.10g} "
            f"(smallest eigenvalue of the certificate matrix {c['min_eigenvalue']:.3g}, "
            f"tolerance {c['tolerance']:.3g}, rank {c['rank']}{moved}, {c['time_s']:.3f} s)")


def _gnc_options(args: argparse.Namespace) -> str | None:
    """The GNC surrogate of ``--robust gnc-*`` (None for a loss); GNC's options without it are
    an error."""
    robust = getattr(args, "robust", None)
    if robust is not None and str(robust).lower().startswith("gnc"):
        return str(robust).lower()
    for flag, value in (("--known-inliers", getattr(args, "known_inliers", None)),
                        ("--gnc-quantile", getattr(args, "gnc_quantile", None)),
                        ("--gnc-first", getattr(args, "gnc_first", None)),
                        ("--gnc-cycle-length", getattr(args, "gnc_cycle_length", None)),
                        ("--gnc-moves", getattr(args, "gnc_moves", None)),
                        ("--gnc-search", getattr(args, "gnc_search", None) or None),
                        ("--gnc-assemble", getattr(args, "gnc_assemble", None) or None),
                        ("--gnc-variance-factor", getattr(args, "gnc_variance_factor", None)),
                        ("--gnc-chain", getattr(args, "gnc_chain", None))):
        if value is not None:
            raise ValueError(f"{flag} applies to --robust gnc-tls or gnc-gm only")
    return None


def _gnc_for(graph: Any, fg: Any, spec: str, args: argparse.Namespace) -> Any:
    """GNC options for the command: the gauge prior (when there is one) and, with
    ``--known-inliers odometry``, the edges between consecutive vertices are known inliers."""
    from .core.gnc import GNC, SURROGATES

    name = spec[4:] if spec.startswith("gnc-") else ""
    if name not in SURROGATES:
        raise ValueError(f"--robust {spec}: graduated non-convexity is gnc-tls or gnc-gm")
    known: list[Any] = list(fg.factors[1:])  # the gauge prior
    if args.known_inliers == "odometry":
        ii, jj = graph.edge_index()
        known.append((fg.factors[0], abs(jj - ii) == 1))
    quantile = args.gnc_quantile  # None: GNC's (0.99, or 1 - 1e-6 with the estimate)
    first = getattr(args, "gnc_first", None) or "auto"
    length = getattr(args, "gnc_cycle_length", None)
    moves = getattr(args, "gnc_moves", None)
    search = bool(getattr(args, "gnc_search", False))
    assemble = bool(getattr(args, "gnc_assemble", False))
    chain = getattr(args, "gnc_chain", None)
    variance = getattr(args, "gnc_variance_factor", None)
    cycles = first == "cycles" or (first == "auto" and name == "tls")
    if (length is not None or moves is not None or search or assemble or chain is not None or
            variance == "estimate") and not cycles:
        raise ValueError("--gnc-cycle-length, --gnc-moves, --gnc-search, --gnc-assemble, "
                         "--gnc-chain and --gnc-variance-factor estimate apply to the cycle "
                         "marking only (--gnc-first cycles, or auto with gnc-tls)")
    opts: dict[str, Any] = {} if moves is None else {"moves": bool(moves)}
    return GNC(name, known_inliers=known, quantile=quantile, first=first, cycle_length=length,
               search=search, assemble=assemble, chain=chain, variance_factor=variance, **opts)


def _variance_factor(text: str) -> float | str:
    """``--gnc-variance-factor``: ``estimate`` or a number > 0."""
    if text == "estimate":
        return text
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not v > 0 or v == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0 or 'estimate', got "
                                         f"{text!r}")
    return v


def _position_rmse(X: Any, truth: Any) -> float:
    """RMS distance between the positions of two aligned pose batches (same gauge)."""
    import numpy as np

    d = np.asarray(X.translation()) - np.asarray(truth.translation())
    return float(np.sqrt(np.mean(np.sum(d * d, axis=-1))))


def show_iterations(err: TextIO, args: argparse.Namespace | None = None) -> bool:
    """Whether to print the iteration table: ``--verbose``, or a terminal without
    ``--quiet``."""
    if getattr(args, "verbose", False):
        return True
    if getattr(args, "quiet", False):
        return False
    return bool(getattr(err, "isatty", None) and err.isatty())


def print_header(args: argparse.Namespace, err: TextIO, text: str) -> None:
    """The line printed before the iterations (not with ``--quiet``), flushed."""
    if not getattr(args, "quiet", False):
        err.write(f"microlie optimize: {_label(args.input)}: {text}\n")
        err.flush()


def solver_output_to(err: TextIO) -> contextlib.AbstractContextManager:
    """The solvers print on ``sys.stderr``: send that to ``err``."""
    return contextlib.nullcontext() if err is sys.stderr else contextlib.redirect_stderr(err)
