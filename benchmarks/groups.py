"""Side-by-side benchmark of microlie's SO3/SE3 against peer libraries.

    python benchmarks/groups.py                      # everything, N = 1,000,000
    python benchmarks/groups.py --quick              # smoke test (small N, few repeats)
    python benchmarks/groups.py --peers scipy gtsam  # a subset of peers
    python benchmarks/groups.py --peers-only         # peers without microlie
    python benchmarks/groups.py --out results.md     # also write the markdown table

Two regimes per op: ``single`` (one element, microseconds per call, many loops, best of
several repeats) and ``batch`` (N elements in one call, nanoseconds per element, best of 3-5
repeats). Peers without batching (GTSAM, spatialmath) run the batch regime as a Python loop over
a smaller N (``--loop-n``), marked in the table.

Before anything is timed, every library's output for every op is compared with scipy on a few
inputs (microlie also on edge cases: zero, tiny and near-pi angles); a library/op that does not
match is not timed, is marked in the table, and the exit status is 1.

Thread counts are pinned (``--threads``, default 1) before NumPy, torch or JAX are imported, so
every library runs on the same single core budget.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from dataclasses import dataclass

DEFAULT_N = 1_000_000


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--n", type=int, default=None, help=f"batch size (default {DEFAULT_N:,})")
    p.add_argument("--quick", action="store_true", help="small N and few repeats (smoke test)")
    p.add_argument(
        "--peers",
        nargs="+",
        default=None,
        metavar="PEER",
        help="peers to run (space or comma separated); default: all of "
        "scipy jaxlie jaxlie-jit pypose spatialmath gtsam",
    )
    p.add_argument("--peers-only", action="store_true", help="do not run microlie")
    p.add_argument("--groups", nargs="+", default=None, help="subset of SO3 SE3")
    p.add_argument("--ops", nargs="+", default=None, help="subset of exp log compose act exp_jac")
    p.add_argument("--regimes", nargs="+", default=None, help="subset of single batch")
    p.add_argument(
        "--loop-n",
        type=int,
        default=None,
        help="elements in the batch regime of non-batched peers (default 10,000)",
    )
    p.add_argument(
        "--repeat", type=int, default=None, help="repeats per measurement (default: auto)"
    )
    p.add_argument("--threads", type=int, default=1, help="threads for BLAS/torch/XLA (default 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=None, help="also write the markdown report to this file")
    p.add_argument("--json", default=None, help="also write the raw numbers to this JSON file")
    args = p.parse_args(argv)
    if args.quick:
        args.n = args.n or 2_000
        args.loop_n = args.loop_n or 200
    args.n = args.n or DEFAULT_N
    args.loop_n = args.loop_n or 10_000
    return args


def pin_threads(threads: int) -> None:
    """Set thread counts through the environment; must run before NumPy/JAX are imported."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = str(threads)
    if threads == 1:
        flags = os.environ.get("XLA_FLAGS", "")
        if "intra_op_parallelism_threads" not in flags:
            extra = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
            os.environ["XLA_FLAGS"] = f"{flags} {extra}".strip()
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


# --------------------------------------------------------------------------------------------


@dataclass
class Cell:
    """One library's result for one (group, op, regime)."""

    value: float | None = None  # µs per call (single) or ns per element (batch)
    n: int = 0
    note: str = ""  # footnote text for a timed value (e.g. Python loop)
    na: str = ""  # why there is no value (unsupported, failed check, error)


def _load_microlie_peer(peers_mod):
    import operator
    from functools import partial

    import numpy as np

    Case, Peer, params_to_matrix = peers_mod.Case, peers_mod.Peer, peers_mod.params_to_matrix

    class MicroliePeer(Peer):
        """microlie itself, through its public API, with NumPy float64 arrays."""

        name = "microlie"

        def setup(self) -> None:
            import microlie

            self.mod = microlie

        def version(self) -> str:
            return getattr(self.mod, "__version__", None) or peers_mod._dist_version("microlie")

        def _elem(self, inp, which):
            R = self.mod.SO3.from_quat(inp.quat(which))
            if inp.group == "SO3":
                return R
            return self.mod.SE3.from_rotation_translation(R, inp.trans(which).copy())

        def case(self, op, inp):
            group = inp.group
            G = getattr(self.mod, group)
            to_m = lambda X: params_to_matrix(group, np.asarray(X.params))
            if op == "exp":
                return Case(partial(G.exp, inp.tau), inp.n, to_m)
            if op == "log":
                return Case(self._elem(inp, "x").log, inp.n, np.asarray)
            if op == "compose":
                a, b = self._elem(inp, "x"), self._elem(inp, "y")
                return Case(partial(operator.matmul, a, b), inp.n, to_m)
            if op == "act":
                return Case(partial(self._elem(inp, "x").act, inp.points), inp.n, np.asarray)
            if op == "exp_jac":
                conv = lambda out: (to_m(out[0]), np.asarray(out[1]))
                return Case(partial(G.exp, inp.tau, jac=True), inp.n, conv)
            raise ValueError(op)

    return MicroliePeer()


def edge_inputs(peers_mod, group: str, n: int, seed: int):
    """Random check inputs whose first rows are edge cases (zero, tiny, near-pi angles)."""
    import numpy as np

    base = peers_mod.make_inputs(group, n, seed)
    rng = np.random.default_rng(seed + 1000)
    angles = np.array([0.0, 1e-12, 1e-9, 1e-6, 1e-4, 1e-2, np.pi - 1e-3, np.pi - 1e-6])
    axis = rng.normal(size=(len(angles), 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    phi = axis * angles[:, None]
    edge = phi if group == "SO3" else np.concatenate([rng.normal(size=phi.shape), phi], -1)
    k = len(angles)
    tau, x = base.tau.copy(), base.x.copy()
    tau[:k] = edge
    x[:k] = peers_mod._exp_params(group, edge[::-1])  # log inputs: same edges, other order
    return peers_mod.Inputs(group, tau, x, base.y, base.points)


def check_all(peers_mod, libs, groups, ops, seed) -> dict:
    """Compare every library/op with scipy; returns {(lib, group, op): '' | reason}."""
    status = {}
    for group in groups:
        plain = peers_mod.make_inputs(group, 32, seed + 1)
        edged = edge_inputs(peers_mod, group, 32, seed + 1)
        for op in ops:
            for lib in libs:
                inputs = edged if lib.name == "microlie" else plain
                status[(lib.name, group, op)] = _check_one(peers_mod, lib, op, inputs)
    return status


def _check_one(peers_mod, lib, op, batch_inputs) -> str:
    tol = peers_mod.TOLERANCE[op]
    # a generic element for the single regime (edge cases sit in the first rows)
    for inp in (batch_inputs.single(-1), batch_inputs):
        try:
            case = lib.case(op, inp)
            got = case.to_canonical(case.fn())
            want = peers_mod.reference(op, inp.head(case.n) if inp.batched else inp)
            err = peers_mod.max_error(op, got, want)
        except peers_mod.Unsupported as e:
            return f"N/A: {e}"
        except Exception as e:  # any failure: do not time it
            return f"ERROR in check: {type(e).__name__}: {e}"
        if not err <= tol:
            regime = "batch" if inp.batched else "single"
            return f"FAILED check vs scipy ({regime}): max error {err:.2e} > {tol:.0e}"
    return ""


def time_cases(timing_mod, cases: dict, regime: str, args) -> dict:
    """Time prepared cases of one (group, op, regime) round-robin; name -> value or Exception.

    single: loop count calibrated per case to ~50 ms (5 ms with --quick), 7 rounds (3);
    batch: one call per round, 5 rounds, or 3 when the warm-up call took over a second (2).
    Value: µs per call (single) or ns per element (batch).
    """
    plan, out = {}, {}
    for name, case in cases.items():
        try:
            t0 = time.perf_counter()
            case.fn()  # warm-up (caches, allocator, lazy imports; JIT compiled at preparation)
            first = time.perf_counter() - t0
            if regime == "single":
                number = timing_mod.calibrate(case.fn, 0.005 if args.quick else 0.05)
                repeat = args.repeat or (3 if args.quick else 7)
            else:
                number = 1
                repeat = args.repeat or (2 if args.quick else (5 if first < 1.0 else 3))
            plan[name] = (number, repeat)
        except Exception as e:
            out[name] = e
    fns = {name: cases[name].fn for name in plan}
    for name, best in timing_mod.best_interleaved(fns, plan).items():
        if isinstance(best, Exception):
            out[name] = best
        elif regime == "single":
            out[name] = best * 1e6
        else:
            out[name] = best / cases[name].n * 1e9
    return out


# --------------------------------------------------------------------------------------------


def fmt_num(x: float) -> str:
    if x >= 1000:
        return f"{x:,.0f}"
    if x >= 100:
        return f"{x:.0f}"
    if x >= 10:
        return f"{x:.1f}"
    return f"{x:.2f}"


def render(results, libs, skipped, groups, ops, regimes, args, header_lines) -> str:
    names = [lib.name for lib in libs]
    have_micro = "microlie" in names
    peer_names = [n for n in names if n != "microlie"]
    notes: dict[str, int] = {}

    def mark(text: str) -> str:
        if text not in notes:
            notes[text] = len(notes) + 1
        return f"[{notes[text]}]"

    def cell(c: Cell | None) -> str:
        if c is None:
            return "—"
        if c.value is None:
            short = "N/A" if c.na.startswith("N/A") else ("FAILED" if "FAIL" in c.na else "ERROR")
            return f"{short} {mark(c.na)}"
        return fmt_num(c.value) + (f" {mark(c.note)}" if c.note else "")

    cols = ["group", "op", "regime"]
    if have_micro:
        cols.append("microlie")
    for pn in peer_names:
        cols.append(pn)
        if have_micro:
            cols.append(f"µ/{pn}")
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    regime_label = {
        "single": "single (µs/call)",
        "batch": f"batch N={args.n:,} (ns/elem)",
    }
    for group in groups:
        for op in ops:
            for regime in regimes:
                row = [group, op, regime_label[regime]]
                mc = results.get(("microlie", group, op, regime))
                if have_micro:
                    row.append(cell(mc))
                for pn in peer_names:
                    pc = results.get((pn, group, op, regime))
                    row.append(cell(pc))
                    if have_micro:
                        ok = mc and pc and mc.value is not None and pc.value is not None
                        row.append(f"{mc.value / pc.value:.2f}" if ok else "")
                lines.append("| " + " | ".join(row) + " |")

    out = list(header_lines)
    out.append("")
    out.extend(lines)
    out.append("")
    if have_micro:
        out.append("µ/peer = microlie time / peer time: below 1 means microlie is faster.")
        out.append("")
    if notes:
        out.append("Notes:")
        out.append("")
        for text, i in notes.items():
            out.append(f"- [{i}] {text}")
        out.append("")
    if skipped:
        out.append("Skipped peers (not importable here):")
        out.append("")
        for name, why in skipped.items():
            out.append(f"- {name}: {why}")
        out.append("")
    return "\n".join(out)


def _load() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def environment_lines(libs, args, load_start: float) -> list[str]:
    import numpy as np

    cpu = platform.processor() or "?"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    blas = ""
    try:
        import threadpoolctl

        info = threadpoolctl.threadpool_info()
        blas = ", ".join(
            f"{d.get('internal_api')} {d.get('version')} {d.get('architecture', '')} "
            f"x{d.get('num_threads')}"
            for d in info
        )
    except ImportError:
        pass
    coretype = os.environ.get("OPENBLAS_CORETYPE")
    lines = [
        "# microlie vs peers: SO3 / SE3",
        "",
        f"- date: {time.strftime('%Y-%m-%d %H:%M')}, CPU: {cpu} ({os.cpu_count()} cores)",
        f"- Python {platform.python_version()}, NumPy {np.__version__}"
        + (f", BLAS: {blas}" if blas else "")
        + (f", OPENBLAS_CORETYPE={coretype}" if coretype else ""),
        f"- threads: {args.threads} (BLAS/OpenMP env, torch.set_num_threads, XLA flags); "
        "float64 everywhere",
        f"- single: µs per call, best of {args.repeat or (3 if args.quick else 7)} rounds of a "
        "calibrated loop; batch: ns per element for one call on N elements, best of "
        f"{args.repeat or ('2' if args.quick else '3-5')} rounds; libraries alternate "
        "round-robin within each row",
        f"- load average (1 min) at start / end: {load_start:.2f} / {_load():.2f} "
        "(other processes share the cores: compare numbers within one run)",
        "- versions: " + ", ".join(f"{lib.name} {lib.version()}" for lib in libs),
    ]
    if args.quick:
        lines.append("- **--quick run: small N, few repeats; numbers are only a smoke test**")
    return lines


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    pin_threads(args.threads)
    load_start = _load()

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import _timing
    import peers as peers_mod

    groups = args.groups or list(peers_mod.GROUPS)
    ops = args.ops or list(peers_mod.OPS)
    regimes = args.regimes or ["single", "batch"]
    requested = []
    for item in args.peers or list(peers_mod.ALL_PEERS):
        requested.extend(s for s in item.split(",") if s)
    if "scipy" not in requested:
        requested.insert(0, "scipy")  # always: it is the reference
    for bad in set(groups) - set(peers_mod.GROUPS):
        raise SystemExit(f"unknown group {bad!r}")
    for bad in set(ops) - set(peers_mod.OPS):
        raise SystemExit(f"unknown op {bad!r}")

    libs, skipped = [], {}
    if not args.peers_only:
        micro = _load_microlie_peer(peers_mod)
        try:
            micro.setup()
        except ImportError as e:
            raise SystemExit(
                f"microlie is not importable ({e}); install it (pip install -e .) "
                "or run with --peers-only"
            ) from None
        libs.append(micro)
    for name in requested:
        peer = peers_mod.make_peer(name)
        peer.threads, peer.loop_n = args.threads, args.loop_n
        try:
            peer.setup()
        except Exception as e:  # an optional peer may fail in any way
            if name == "scipy":
                raise
            skipped[name] = f"{type(e).__name__}: {e}"
            log(f"skipping peer {name}: {skipped[name]}")
            continue
        libs.append(peer)
    log("libraries: " + ", ".join(f"{lib.name} {lib.version()}" for lib in libs))

    # 1. sanity check: never time a wrong implementation
    t0 = time.perf_counter()
    status = check_all(peers_mod, libs, groups, ops, args.seed)
    log(f"sanity check vs scipy: {len(status)} lib/op pairs in {time.perf_counter() - t0:.1f} s")
    failures = {k: v for k, v in status.items() if v and not v.startswith("N/A")}
    for (lib, group, op), why in failures.items():
        log(f"  !! {lib} {group}.{op}: {why}")

    # 2. timing
    results: dict[tuple, Cell] = {}
    for group in groups:
        inputs = None
        if "batch" in regimes:
            inputs = peers_mod.make_inputs(group, args.n, args.seed)
            single = inputs.single()
        else:
            single = peers_mod.make_inputs(group, 1, args.seed).single()
        for op in ops:
            for regime in regimes:
                inp = single if regime == "single" else inputs
                cases = {}
                for lib in libs:
                    key = (lib.name, group, op, regime)
                    why = status[(lib.name, group, op)]
                    if why:
                        results[key] = Cell(na=why)
                        continue
                    try:
                        cases[lib.name] = lib.case(op, inp)
                    except Exception as e:
                        results[key] = Cell(na=f"ERROR preparing: {type(e).__name__}: {e}")
                timed = time_cases(_timing, cases, regime, args)
                unit = "us/call" if regime == "single" else "ns/elem"
                for lib in libs:
                    if lib.name not in timed:
                        continue
                    key, value = (lib.name, group, op, regime), timed[lib.name]
                    if isinstance(value, Exception):
                        msg = f"ERROR while timing: {type(value).__name__}: {value}"
                        results[key] = Cell(na=msg)
                        log(f"  {lib.name:12s} {group} {op:8s} {regime:6s} {msg}")
                        continue
                    case = cases[lib.name]
                    results[key] = Cell(value=value, n=case.n, note=case.note)
                    log(f"  {lib.name:12s} {group} {op:8s} {regime:6s} {fmt_num(value):>8s} {unit}")
                del cases, timed

    report = render(
        results,
        libs,
        skipped,
        groups,
        ops,
        regimes,
        args,
        environment_lines(libs, args, load_start),
    )
    print(report)
    if args.out:
        with open(args.out, "w") as f:
            f.write(report + "\n")
        log(f"wrote {args.out}")
    if args.json:
        import json

        raw = [
            {
                "lib": k[0],
                "group": k[1],
                "op": k[2],
                "regime": k[3],
                "value": c.value,
                "n": c.n,
                "note": c.note,
                "na": c.na,
            }
            for k, c in results.items()
        ]
        with open(args.json, "w") as f:
            json.dump({"n": args.n, "threads": args.threads, "results": raw}, f, indent=1)
    micro_failed = any(k[0] == "microlie" for k in failures)
    if micro_failed:
        log("microlie FAILED the sanity check for some ops: those were not timed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
