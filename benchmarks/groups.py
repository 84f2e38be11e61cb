"""Side-by-side benchmark of microlie's SO3/SE3 against peer libraries.

    python benchmarks/groups.py                      # everything, N = 1,000,000
    python benchmarks/groups.py --quick              # smoke test (small N, few repeats)
    python benchmarks/groups.py --peers scipy gtsam  # a subset of peers
    python benchmarks/groups.py --peers-only         # peers without microlie
    python benchmarks/groups.py --backends jax,torch --peers jaxlie-jit pypose \
        --out benchmarks/results/groups-jax-torch-latest.md  # microlie on JAX / torch vs peers
    python benchmarks/groups.py --out results.md     # also write the markdown table
    python benchmarks/groups.py --before-after 93dbac9 --n 100000 \
        --out benchmarks/results/kernels-latest.md   # this checkout against an older commit

microlie runs on each of its array backends (``--backends``, default all that import):
``microlie`` (NumPy), ``microlie-jax-jit`` (``jax.jit`` on float64 JAX arrays) and
``microlie-torch`` (float64 CPU tensors, autograd off). A second table compares the last two with
the peer on the same array library (jaxlie-jit, PyPose).

Two regimes per op: ``single`` (one element, microseconds per call, many loops, median of
several repeats) and ``batch`` (N elements in one call, nanoseconds per element, median of 3-5
repeats). Peers without batching (GTSAM, spatialmath) run the batch regime as a Python loop over
a smaller N (``--loop-n``), marked in the table.

Before anything is timed, every library's output for every op is compared with scipy on a few
inputs (microlie also on edge cases: zero, tiny and near-pi angles); a library/op that does not
match is not timed, is marked in the table, and the exit status is 1. microlie on JAX and PyTorch
must also give the same numbers as microlie on NumPy, on the check inputs and on the very output
of each timed case (N elements).

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
    p.add_argument(
        "--backends",
        nargs="+",
        default=None,
        metavar="BACKEND",
        help="microlie's array backends to run (space or comma separated): numpy (microlie), "
        "jax (microlie-jax-jit), torch (microlie-torch); default: all that import",
    )
    p.add_argument("--peers-only", action="store_true", help="do not run microlie")
    p.add_argument("--groups", nargs="+", default=None,
                   help="subset of SO3 SE3 (with --before-after: of SO3 SE3 Sim3)")
    p.add_argument("--ops", nargs="+", default=None,
                   help="subset of exp log compose act exp_jac (with --before-after: of its "
                   "value and Jacobian operations, e.g. minus minus_jac jr)")
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
    p.add_argument(
        "--before-after",
        default=None,
        metavar="REF",
        help="instead of peers: time microlie at git REF (imported as microlie_before from a "
        "git archive) against this checkout, interleaved, value and Jacobian operations of "
        "SO3, SE3, Sim3 (single element and --n elements); prints ratios",
    )
    args = p.parse_args(argv)
    if args.quick:
        args.n = args.n or 2_000
        args.loop_n = args.loop_n or 200
    args.n = args.n or DEFAULT_N
    args.loop_n = args.loop_n or 10_000
    if args.peers_only:
        args.backends = []
    elif args.backends is None:
        args.backends_explicit, args.backends = False, list(BACKENDS)
    else:
        args.backends = [b for item in args.backends for b in item.split(",") if b]
        for bad in set(args.backends) - set(BACKENDS):
            p.error(f"unknown backend {bad!r}; known: {', '.join(BACKENDS)}")
    args.backends_explicit = getattr(args, "backends_explicit", True)
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

    value: float | None = None  # µs per call (single) or ns per element (batch): the median
    spread: float = 0.0  # interquartile range of the rounds relative to the median
    n: int = 0
    note: str = ""  # footnote text for a timed value (e.g. Python loop)
    na: str = ""  # why there is no value (unsupported, failed check, error)


BACKENDS = ("numpy", "jax", "torch")
# library name of microlie on each backend (the NumPy one keeps the plain name)
BACKEND_LIB = {"numpy": "microlie", "jax": "microlie-jax-jit", "torch": "microlie-torch"}
# the peer each non-NumPy backend is compared with (same array library, same execution model)
BACKEND_PEER = {"jax": "jaxlie-jit", "torch": "pypose"}
# microlie-jax / microlie-torch must equal microlie-numpy to this relative tolerance
BACKEND_TOL = 1e-12
# microlie is checked on this many elements (edge cases first): more than 2 x 8192, so that
# microlie's NumPy path runs in chunks (it does from 16,384 elements on), a last partial one too
CHECK_N_MICROLIE = 20_000


def _microlie_peer(peers_mod, backend: str):
    """microlie through its public API on one array backend, as a peer object.

    numpy: NumPy float64 arrays. torch: CPU float64 tensors, ``torch.set_num_threads(threads)``,
    autograd disabled (like PyPose). jax: float64 (``jax_enable_x64``) arrays, every op wrapped
    in ``jax.jit``, compiled and warmed up while the case is prepared, every call ends in
    ``block_until_ready``. The jitted function takes and returns raw arrays (parameters, tangents,
    points) and builds the elements inside (``G.from_params(p, check=False)``), exactly like the
    jaxlie-jit case (``G(p)`` inside, ``.parameters()`` out): neither side pays for its element
    objects as pytree arguments. numpy/torch elements are built from their parameters
    (``G(params)``) outside the timed region.
    """
    import operator
    from functools import partial

    import numpy as np

    Case, Peer, params_to_matrix = peers_mod.Case, peers_mod.Peer, peers_mod.params_to_matrix

    class MicroliePeer(Peer):
        name = BACKEND_LIB[backend]
        microlie_backend = backend

        def setup(self) -> None:
            if backend == "torch":
                import torch

                torch.set_num_threads(self.threads)
                torch.set_grad_enabled(False)  # as for PyPose: no autograd graph, no_grad
                self.torch = torch
            elif backend == "jax":
                import jax

                jax.config.update("jax_enable_x64", True)
                import jax.numpy as jnp

                self.jax, self.jnp = jax, jnp
            import microlie

            self.mod = microlie

        def version(self) -> str:
            v = getattr(self.mod, "__version__", None) or peers_mod._dist_version("microlie")
            if backend == "numpy":
                return v
            return f"{v} ({backend} {peers_mod._dist_version(backend)})"

        def _arr(self, a):
            """A NumPy input array in this backend (float64, contiguous)."""
            a = np.ascontiguousarray(a, dtype=np.float64)
            if backend == "torch":
                return self.torch.from_numpy(a.copy())
            if backend == "jax":
                return self.jax.device_put(self.jnp.asarray(a))
            return a

        def _elem(self, inp, which):
            return getattr(self.mod, inp.group)(self._arr(getattr(inp, which)))

        def _make(self, f, args, n, to_canonical):
            """Case for ``f(*args)``: called directly, or jitted + blocked on JAX."""
            if backend != "jax":
                return Case(partial(f, *args), n, to_canonical)
            jax = self.jax
            jf = jax.jit(f)
            jax.block_until_ready(jf(*args))  # compile + warm up outside the timed region
            return Case(partial(peers_mod._call_and_block, jax.block_until_ready, jf, args),
                        n, to_canonical)

        def case(self, op, inp):
            group = inp.group
            G = getattr(self.mod, group)
            to_m = lambda X: params_to_matrix(group, np.asarray(X.params))
            if backend == "jax":
                return self._jax_case(G, op, inp)
            if op == "exp":
                return self._make(G.exp, (self._arr(inp.tau),), inp.n, to_m)
            if op == "log":
                return self._make(self._elem(inp, "x").log, (), inp.n, np.asarray)
            if op == "compose":
                a, b = self._elem(inp, "x"), self._elem(inp, "y")
                return self._make(operator.matmul, (a, b), inp.n, to_m)
            if op == "act":
                X, pts = self._elem(inp, "x"), self._arr(inp.points)
                return self._make(X.act, (pts,), inp.n, np.asarray)
            if op == "exp_jac":
                conv = lambda out: (to_m(out[0]), np.asarray(out[1]))
                return self._make(partial(G.exp, jac=True), (self._arr(inp.tau),), inp.n, conv)
            raise ValueError(op)

        def _jax_case(self, G, op, inp):
            """Raw arrays in, raw arrays out of the jitted function (see the class docstring)."""
            to_m = lambda p: params_to_matrix(inp.group, np.asarray(p))
            x, y = self._arr(inp.x), self._arr(inp.y)
            if op == "exp":
                return self._make(_JAX_OPS[G, op], (self._arr(inp.tau),), inp.n, to_m)
            if op == "log":
                return self._make(_JAX_OPS[G, op], (x,), inp.n, np.asarray)
            if op == "compose":
                return self._make(_JAX_OPS[G, op], (x, y), inp.n, to_m)
            if op == "act":
                return self._make(_JAX_OPS[G, op], (x, self._arr(inp.points)), inp.n, np.asarray)
            if op == "exp_jac":
                conv = lambda out: (to_m(out[0]), np.asarray(out[1]))
                return self._make(_JAX_OPS[G, op], (self._arr(inp.tau),), inp.n, conv)
            raise ValueError(op)

    return MicroliePeer()


class _JaxOps(dict):
    """``(G, op) -> function`` for ``jax.jit``: one stable function per group and op, raw arrays
    in and out (the element is built inside, without checks, as jaxlie's ``G(p)``)."""

    def __missing__(self, key):
        G, op = key
        el = lambda p: G.from_params(p, check=False)  # noqa: E731
        f = {"exp": lambda tau: G.exp(tau).params,
             "log": lambda p: el(p).log(),
             "compose": lambda p, q: (el(p) @ el(q)).params,
             "act": lambda p, v: el(p).act(v),
             "exp_jac": lambda tau: (lambda X, J: (X.params, J))(*G.exp(tau, jac=True))}[op]
        self[key] = f
        return f


_JAX_OPS = _JaxOps()


def to_raw(out):
    """A microlie output (element, array or tuple of them, any backend) as NumPy arrays."""
    import numpy as np

    if isinstance(out, tuple):
        return tuple(to_raw(o) for o in out)
    if hasattr(out, "params"):
        return np.asarray(out.params)
    return np.asarray(out)


def raw_mismatch(got, want) -> float:
    """Largest ``|got - want| / (1 + max|want|)`` over the parts of two raw outputs."""
    import numpy as np

    if isinstance(want, tuple):
        return max(raw_mismatch(g, w) for g, w in zip(got, want, strict=True))
    if got.shape != want.shape or got.dtype != want.dtype:
        raise AssertionError(f"{got.dtype}{got.shape} != microlie-numpy {want.dtype}{want.shape}")
    if want.size == 0:
        return 0.0
    return float(np.max(np.abs(got - want)) / (1.0 + np.max(np.abs(want))))


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


def check_all(peers_mod, libs, groups, ops, seed, ref_micro=None) -> dict:
    """Compare every library/op with scipy; returns {(lib, group, op): '' | reason}.

    microlie on JAX / PyTorch must moreover give the same numbers as microlie on NumPy
    (``ref_micro``) on the same inputs, edge cases included (:data:`BACKEND_TOL`).
    """
    status = {}
    for group in groups:
        plain = peers_mod.make_inputs(group, 32, seed + 1)
        edged = edge_inputs(peers_mod, group, CHECK_N_MICROLIE, seed + 1)
        for op in ops:
            for lib in libs:
                backend = getattr(lib, "microlie_backend", None)
                inputs = edged if backend else plain
                why = _check_one(peers_mod, lib, op, inputs)
                if not why and backend not in (None, "numpy"):
                    why = _check_same_as_numpy(lib, ref_micro, op, inputs)
                status[(lib.name, group, op)] = why
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


def _check_same_as_numpy(lib, ref_micro, op, batch_inputs) -> str:
    for inp in (batch_inputs.single(-1), batch_inputs.single(0), batch_inputs):
        regime = "batch" if inp.batched else "single"
        why = compare_with_numpy(lib, ref_micro, op, inp, lib.case(op, inp).fn())
        if why:
            return f"{why} ({regime}, {inp.n} elements)"
    return ""


def compare_with_numpy(lib, ref_micro, op, inp, out) -> str:
    """'' if ``out`` (``lib``'s output of ``op`` on ``inp``) equals microlie-numpy's output."""
    try:
        got = to_raw(out)
        want = to_raw(ref_micro.case(op, inp).fn())
        err = raw_mismatch(got, want)
    except Exception as e:
        return f"ERROR comparing with microlie-numpy: {type(e).__name__}: {e}"
    if not err <= BACKEND_TOL:
        return f"FAILED: differs from microlie-numpy by {err:.2e} > {BACKEND_TOL:.0e}"
    return ""


def time_cases(timing_mod, cases: dict, regime: str, args) -> dict:
    """Time prepared cases of one (group, op, regime) round-robin; name -> (median value,
    relative interquartile range) or Exception.

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
    for name, st in timing_mod.interleaved(fns, plan).items():
        if isinstance(st, Exception):
            out[name] = st
        elif regime == "single":
            out[name] = (st.median * 1e6, st.spread())
        else:
            out[name] = (st.median / cases[name].n * 1e9, st.spread())
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
    """The markdown report: microlie (NumPy) vs every peer, then microlie on JAX / PyTorch vs
    the peer on the same array library (when those backends ran)."""
    names = [lib.name for lib in libs]
    backend_names = [BACKEND_LIB[b] for b in ("jax", "torch") if BACKEND_LIB[b] in names]
    have_micro = "microlie" in names
    peer_names = [n for n in names if n != "microlie" and n not in backend_names]
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
        return fmt_num(c.value) + f" ±{50 * c.spread:.0f}%" + (f" {mark(c.note)}" if c.note else "")

    regime_label = {
        "single": "single (µs/call)",
        "batch": f"batch N={args.n:,} (ns/elem)",
    }

    def table(columns) -> list[str]:
        """columns: ("lib", name) or ("ratio", numerator lib, denominator lib, header)."""
        heads = ["group", "op", "regime"] + [c[1] if c[0] == "lib" else c[3] for c in columns]
        lines = ["| " + " | ".join(heads) + " |", "|" + "|".join("---" for _ in heads) + "|"]
        for group in groups:
            for op in ops:
                for regime in regimes:
                    row = [group, op, regime_label[regime]]
                    for col in columns:
                        if col[0] == "lib":
                            row.append(cell(results.get((col[1], group, op, regime))))
                            continue
                        num = results.get((col[1], group, op, regime))
                        den = results.get((col[2], group, op, regime))
                        ok = num and den and num.value is not None and den.value is not None
                        row.append(f"{num.value / den.value:.2f}" if ok else "")
                    lines.append("| " + " | ".join(row) + " |")
        return lines

    main_cols: list[tuple] = [("lib", "microlie")] if have_micro else []
    for pn in peer_names:
        main_cols.append(("lib", pn))
        if have_micro:
            main_cols.append(("ratio", "microlie", pn, f"µ/{pn}"))

    out = list(header_lines)
    out.append("")
    if main_cols:
        out.append("## microlie (NumPy) vs peers" if have_micro else "## Peers")
        out.append("")
        out.extend(table(main_cols))
        out.append("")
        if have_micro and peer_names:
            out.append("µ/peer = microlie time / peer time: below 1 means microlie is faster.")
            out.append("")
    if backend_names:
        back_cols: list[tuple] = [("lib", "microlie")] if have_micro else []
        ratio_lines = []
        for b in ("jax", "torch"):
            mine, peer = BACKEND_LIB[b], BACKEND_PEER[b]
            if mine not in backend_names:
                continue
            back_cols.append(("lib", mine))
            if peer in names:
                back_cols += [("lib", peer), ("ratio", mine, peer, f"{mine} / {peer}")]
                ratio_lines.append(f"{mine} / {peer}")
        out.append("## microlie on JAX and PyTorch vs the peer on the same array library")
        out.append("")
        out.append(
            "microlie-jax-jit: `jax.jit` of microlie's op on float64 JAX arrays, compiled before "
            "timing, `block_until_ready`; raw arrays in and out of the jitted function on both "
            "sides (elements built inside: `G.from_params(p, check=False)` as jaxlie's `G(p)`); "
            "microlie-torch: microlie's op on float64 CPU tensors, `torch.set_num_threads("
            f"{args.threads})`, autograd disabled (as for PyPose). "
            + ("The microlie column is the NumPy backend, for reference. " if have_micro else "")
            + "Both give the same numbers as microlie on NumPy (relative difference <= "
            f"{BACKEND_TOL:.0e}), checked on the check inputs and on the timed output itself."
        )
        out.append("")
        out.extend(table(back_cols))
        out.append("")
        if ratio_lines:
            out.append(
                ", ".join(ratio_lines) + ": microlie time / peer time on the same array library; "
                "below 1 means microlie is faster."
            )
            out.append("")
    if notes:
        out.append("Notes:")
        out.append("")
        for text, i in notes.items():
            out.append(f"- [{i}] {text}")
        out.append("")
    if skipped:
        out.append("Skipped (not importable here):")
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


def microlie_source() -> str:
    """The git commit of the microlie that is imported, '+ uncommitted changes' if src/ is dirty."""
    import subprocess

    try:
        import microlie

        src = os.path.dirname(os.path.abspath(microlie.__file__))
        git = ["git", "-C", src]
        sha = subprocess.run([*git, "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run([*git, "status", "--porcelain", "--", "."], capture_output=True,
                               text=True, check=True).stdout.strip()
    except Exception:  # not a git checkout (installed wheel) or no git: nothing to report
        return ""
    return f"git {sha}" + (" + uncommitted changes in src/microlie" if dirty else "")


def environment_lines(libs, args, loads: list[float]) -> list[str]:
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
        f"- single: µs per call, median of {args.repeat or (3 if args.quick else 7)} rounds of a "
        "calibrated loop; batch: ns per element for one call on N elements, median of "
        f"{args.repeat or ('2' if args.quick else '3-5')} rounds; libraries alternate "
        "round-robin within each row; ±: half the interquartile range of the rounds, relative "
        "to the median",
        f"- load average (1 min): {loads[0]:.2f} at start, {min(loads):.2f}-{max(loads):.2f} "
        f"while timing (sampled after each row), {_load():.2f} at end; {os.cpu_count()} cores "
        "shared with other processes: compare numbers within one run",
        "- versions: " + ", ".join(f"{lib.name} {lib.version()}" for lib in libs),
    ]
    if getattr(args, "microlie_source", ""):
        lines.append(f"- microlie source (when imported): {args.microlie_source}")
    if args.quick:
        lines.append("- **--quick run: small N, few repeats; numbers are only a smoke test**")
    return lines


# ------------------------------------------------------------------------- before / after

BA_GROUPS = ("SO3", "SE3", "Sim3")
BA_VALUE_OPS = ("exp", "log", "compose", "inverse", "act", "between", "minus", "plus")
BA_JAC_OPS = ("exp_jac", "log_jac", "act_jac", "inverse_jac", "compose_jac", "between_jac",
              "minus_jac", "plus_jac", "jr", "jr_inv")


def _ba_cases(m, group: str, tau, p, q, v) -> dict:
    """The timed callables of one library (module ``m``) on prepared NumPy inputs."""
    G = getattr(m, group)
    X, Y = G(p), G(q)
    return {
        "exp": lambda: G.exp(tau), "log": lambda: X.log(), "compose": lambda: X.compose(Y),
        "inverse": lambda: X.inverse(), "act": lambda: X.act(v),
        "between": lambda: X.between(Y), "minus": lambda: X.minus(Y),
        "plus": lambda: X.plus(tau),
        "exp_jac": lambda: G.exp(tau, jac=True), "log_jac": lambda: X.log(jac=True),
        "act_jac": lambda: X.act(v, jac=True), "compose_jac": lambda: X.compose(Y, jac=True),
        "between_jac": lambda: X.between(Y, jac=True),
        "inverse_jac": lambda: X.inverse(jac=True),
        "minus_jac": lambda: X.minus(Y, jac=True), "plus_jac": lambda: X.plus(tau, jac=True),
        "jr": lambda: G.jr(tau), "jr_inv": lambda: G.jr_inv(tau),
    }


def _ba_flat(out) -> list:
    import numpy as np

    items = out if isinstance(out, tuple) else (out,)
    return [np.asarray(getattr(x, "params", x)) for x in items]


def _import_ref(ref: str):
    """microlie at git ``ref``, extracted with ``git archive`` and imported as microlie_before
    (its modules import each other relatively, so the renamed copy is self-contained)."""
    import importlib
    import io
    import subprocess
    import tarfile
    import tempfile

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    data = subprocess.run(["git", "-C", root, "archive", ref, "src/microlie"],
                          capture_output=True, check=True).stdout
    tmp = tempfile.mkdtemp(prefix="microlie-before-")
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(tmp, filter="data")
    os.rename(os.path.join(tmp, "src", "microlie"), os.path.join(tmp, "microlie_before"))
    sys.path.insert(0, tmp)
    return importlib.import_module("microlie_before")


def before_after(args) -> int:
    """Time this checkout against ``args.before_after`` (see ``--before-after``)."""
    import numpy as np

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import _timing

    import microlie as new

    old = _import_ref(args.before_after)
    n = args.n if args.n != DEFAULT_N else 100_000
    rounds = args.repeat or (3 if args.quick else 9)
    loads = [_load()]
    rng = np.random.default_rng(args.seed)
    rows, bad = [], []
    for group in args.groups or BA_GROUPS:  # --groups / --ops / --regimes: subsets
        G = getattr(new, group)
        inputs = {}
        for regime, shape in (("single", ()), ("batch", (n,))):
            tau = rng.standard_normal((*shape, G.dof)) * 0.5
            p = G.random(shape, rng=rng).params.copy()
            q = G.random(shape, rng=rng).params.copy()
            v = rng.standard_normal((*shape, G.point_dim))
            inputs[regime] = (tau, p, q, v)
        for op in args.ops or BA_VALUE_OPS + BA_JAC_OPS:
            for regime in args.regimes or ("single", "batch"):
                fns = {lib: _ba_cases(m, group, *inputs[regime])[op]
                       for lib, m in (("before", old), ("after", new))}
                a, b = _ba_flat(fns["before"]()), _ba_flat(fns["after"]())
                err = max(float(np.abs(x - y).max() / max(1.0, np.abs(x).max()))
                          for x, y in zip(a, b, strict=True))
                if not err <= 1e-9:  # never time a wrong result
                    bad.append(f"{group}.{op} {regime}: before/after differ by {err:.1e}")
                    log("  !! " + bad[-1])
                    continue
                if regime == "single":
                    number = max(_timing.calibrate(f, 0.005 if args.quick else 0.02)
                                 for f in fns.values())
                else:
                    number = 1
                st = _timing.interleaved(fns, {k: (number, rounds) for k in fns})
                loads.append(_load())
                scale, unit = (1e6, "us") if regime == "single" else (1e9 / n, "ns/elem")
                rows.append((group, op, regime, st["before"], st["after"], scale, unit))
                log(f"  {group:5s} {op:12s} {regime:6s} before {st['before'].median * scale:9.3f}"
                    f"  after {st['after'].median * scale:9.3f} {unit}")
    # the goal ratio measured directly: minus and minus(jac=True) of this checkout alternate in
    # the same rounds (the table's rows are timed minutes apart on a loaded machine)
    # (the same for the older commit, in its own rounds: a third as many, it may be slow)
    goal, goal_before = {}, {}
    for group in args.groups or BA_GROUPS:
        if args.ops and not {"minus", "minus_jac"} <= set(args.ops):
            break
        p, q = (new.__dict__[group].random((n,), rng=rng).params for _ in range(2))
        for lib, m, into, k in (("after", new, goal, 3), ("before", old, goal_before, 1)):
            G = getattr(m, group)
            X, Y = G(p), G(q)
            wall: dict[str, list[float]] = {"minus": [], "jac": []}
            cpu: dict[str, list[float]] = {"minus": [], "jac": []}
            for _ in range(k * rounds):  # wall and CPU (process) time of each call
                for key, jac in (("minus", False), ("jac", True)):
                    w, c = time.perf_counter(), time.process_time()
                    X.minus(Y, jac=jac)
                    cpu[key].append(time.process_time() - c)
                    wall[key].append(time.perf_counter() - w)
            into[group] = tuple(float(np.median(t["jac"]) / np.median(t["minus"]))
                                for t in (wall, cpu))
            loads.append(_load())
            log(f"  {group:5s} {lib:6s} minus_jac / minus alternating: wall "
                f"{into[group][0]:.2f}, cpu {into[group][1]:.2f}")
    report = _ba_render(rows, bad, args, n, rounds, loads, goal, goal_before)
    print(report)
    if args.out:
        with open(args.out, "w") as f:
            f.write(report + "\n")
        log(f"wrote {args.out}")
    return 1 if bad else 0


def _ba_render(rows, bad, args, n, rounds, loads, goal, goal_before) -> str:
    med = {(g, op, r): (b.median * sc, a.median * sc) for g, op, r, b, a, sc, _ in rows}
    lines = [
        f"# microlie before/after: {args.before_after} vs this checkout "
        f"({microlie_source()})", "",
        "Command: `" + "".join(f"{k}={os.environ[k]} " for k in (
            "MICROLIE_FAST", "MICROLIE_CACHE_MB", "OPENBLAS_NUM_THREADS") if k in os.environ)
        + f"python benchmarks/groups.py --before-after {args.before_after} --n {n}"
        + (" --quick" if args.quick else "") + (f" --repeat {args.repeat}" if args.repeat else "")
        + "".join(f" --{k} {' '.join(getattr(args, k))}" for k in ("groups", "ops", "regimes")
                  if getattr(args, k)) + "`", "",
        f"- single: us per call (one element); batch: ns per element at N = {n:,}",
        f"- median of {rounds} interleaved rounds (before/after alternate in each round); "
        "spread = interquartile range / median",
        f"- load average (1 min): {loads[0]:.2f} at start, {min(loads):.2f}-{max(loads):.2f} "
        "during the run", f"- Python {platform.python_version()}, {platform.machine()}", "",
        "| group | op | regime | before | after | speed-up (before/after) | spread b / a |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for g, op, r, b, a, sc, _unit in rows:
        lines.append(f"| {g} | {op} | {r} | {fmt_num(b.median * sc)} | {fmt_num(a.median * sc)} "
                     f"| {b.median / a.median:.2f}x | {b.spread():.0%} / {a.spread():.0%} |")
    lines += ["", "Goals (after):", ""]
    for g in BA_GROUPS:
        if (g, "minus", "batch") in med and (g, "minus_jac", "batch") in med:
            ratio = med[(g, "minus_jac", "batch")][1] / med[(g, "minus", "batch")][1]
            lines.append(f"- {g}: minus(jac=True) / minus() at N = {n:,}: {ratio:.2f} "
                         "(goal <= 2.5)" + (f"; the two alternating in {3 * rounds} rounds: "
                                            f"{goal[g][0]:.2f} wall time, {goal[g][1]:.2f} CPU "
                                            f"time (before, {rounds} rounds: "
                                            f"{goal_before[g][0]:.2f} wall, "
                                            f"{goal_before[g][1]:.2f} CPU)" if g in goal else ""))
    if ("Sim3", "jr", "batch") in med and ("SE3", "jr", "batch") in med:
        ratio = med[("Sim3", "jr", "batch")][1] / med[("SE3", "jr", "batch")][1]
        lines.append(f"- Sim3.jr / SE3.jr at N = {n:,}: {ratio:.2f} (goal <= 2)")
    for op in ("exp", "log", "compose", "act"):
        if ("SE3", op, "single") in med:
            b, a = med[("SE3", op, "single")]
            lines.append(f"- SE3.{op} single element: {b / a:.2f}x faster (goal >= 2)")
    slower = [f"{g}.{op} {b / a:.2f}x" for (g, op, r), (b, a) in med.items()
              if r == "batch" and op in BA_VALUE_OPS and b / a < 1.0]
    lines.append("- batched value operations slower than before: "
                 + (", ".join(slower) if slower else "none"))
    if bad:
        lines += ["", "Not timed (results differ):", ""] + [f"- {x}" for x in bad]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    pin_threads(args.threads)
    if args.before_after:
        return before_after(args)
    loads = [_load()]

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
    ref_micro = None  # microlie on NumPy: timed if selected, the reference for the other backends
    if args.backends:
        ref_micro = _microlie_peer(peers_mod, "numpy")
        try:
            ref_micro.setup()
        except ImportError as e:
            raise SystemExit(
                f"microlie is not importable ({e}); install it (pip install -e .) "
                "or run with --peers-only"
            ) from None
        args.microlie_source = microlie_source()  # now: src/ may change while the run goes on
        if "numpy" in args.backends:
            libs.append(ref_micro)
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
    for backend in args.backends:
        if backend == "numpy":
            continue
        lib = _microlie_peer(peers_mod, backend)
        lib.threads = args.threads
        try:
            lib.setup()
        except ImportError as e:
            if args.backends_explicit:
                raise SystemExit(f"backend {backend} requested but not importable: {e}") from None
            skipped[lib.name] = f"{type(e).__name__}: {e}"
            log(f"skipping backend {backend}: {skipped[lib.name]}")
            continue
        libs.append(lib)
    log("libraries: " + ", ".join(f"{lib.name} {lib.version()}" for lib in libs))

    # 1. sanity check: never time a wrong implementation
    t0 = time.perf_counter()
    status = check_all(peers_mod, libs, groups, ops, args.seed, ref_micro)
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
                        case = lib.case(op, inp)
                    except Exception as e:
                        results[key] = Cell(na=f"ERROR preparing: {type(e).__name__}: {e}")
                        continue
                    if getattr(lib, "microlie_backend", "numpy") != "numpy":
                        # the very output that is about to be timed must equal microlie-numpy's
                        why = compare_with_numpy(lib, ref_micro, op, inp, case.fn())
                        if why:
                            failures[(lib.name, group, op)] = why
                            results[key] = Cell(na=f"{why} (timed inputs, N={inp.n:,})")
                            log(f"  !! {lib.name} {group}.{op} {regime}: {why}")
                            continue
                    cases[lib.name] = case
                timed = time_cases(_timing, cases, regime, args)
                loads.append(_load())
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
                    value, spread = value
                    results[key] = Cell(value=value, spread=spread, n=case.n, note=case.note)
                    log(f"  {lib.name:12s} {group} {op:8s} {regime:6s} {fmt_num(value):>8s} {unit}"
                        f"  (IQR {100 * spread:.0f}%)")
                del cases, timed

    report = render(
        results,
        libs,
        skipped,
        groups,
        ops,
        regimes,
        args,
        environment_lines(libs, args, loads),
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
                "spread": c.spread,
                "n": c.n,
                "note": c.note,
                "na": c.na,
            }
            for k, c in results.items()
        ]
        with open(args.json, "w") as f:
            meta = {"n": args.n, "threads": args.threads, "backends": args.backends, "loads": loads}
            json.dump({**meta, "results": raw}, f, indent=1)
    micro_failed = sorted({k[0] for k in failures if k[0].startswith("microlie")})
    if micro_failed:
        log(f"{', '.join(micro_failed)} FAILED the sanity check for some ops: those were not timed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
