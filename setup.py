"""Build of microlie's compiled kernels: the C sources of ``src/microlie/_c`` as the extension
modules ``microlie._c.<name>`` (the metadata is in pyproject.toml).

The compiled code is optional. Where no C compiler works (none installed, ``CC`` naming a missing
program, a compiler that rejects the code), each extension that fails is skipped with a warning,
the install succeeds and microlie runs its generic NumPy kernels; ``microlie --version`` says
which kernels are active and why (``src/microlie/_c/_build.json``, written here, records the
outcome).

Flags (portable by default): ``-O3 -fno-math-errno -fno-trapping-math -fopenmp-simd -std=c11``
(``-ffp-contract=off`` for the group kernels) for a baseline ISA,
``-march=x86-64-v2`` on x86-64 (SSE4.2, no AVX), ``-march=armv8-a`` on Linux ARM64, the
compiler's default elsewhere; the hot loops (``LM_HOT``, ``src/microlie/_c/dispatch.h``) are
cloned for x86-64-v3 (AVX2, FMA) and x86-64-v4 (AVX-512) and chosen at load time where the
compiler and the C library support it (GCC/Clang ``target_clones`` and ifunc: glibc). No libmvec.

Environment variables:

- ``MICROLIE_NATIVE=1``: a local build for this CPU only (``-march=native``, ``-mcpu=native`` on
  ARM64; no clones). Not for wheels.
- ``MICROLIE_BUILD_EXT=0``: build no extension (the generic kernels only).
- ``MICROLIE_REQUIRE_EXT=1``: an extension that does not compile is an error (CI, wheels).
- ``MICROLIE_CFLAGS``: replaces the optimisation and ISA flags (``-std=c11`` and the dispatch
  probe stay).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent
C_DIR = Path("src") / "microlie" / "_c"  # relative: setuptools wants relative source paths

# name -> sources (the headers they include lie beside them: vecmath.h, vecmath_coeffs.h,
# array_args.h, dispatch.h, and generated/lie_kernels.h, written at build time by
# microlie._codegen from the component formulas; MANIFEST.in puts the hand-written ones in the
# sdist, the generated one is made again from src/ there)
EXTENSIONS = {
    "_lie": ["_lie.c"],  # the batched group kernels (microlie._kernels registry)
    "_one": ["_one.c"],  # one-element entry points of every group (microlie.groups._single)
    "_graph": ["_graph.c"],  # the pose-graph edge loop (microlie.optim.core.compiled)
    "_factors": ["_factors.c"],  # between and prior rows of small batches (optim.core.factors)
    "_reproj": ["_reproj.c"],  # BAL reprojection factors (microlie.optim.core.compiled)
    "_normal": ["_normal.c"],  # the engine's normal equations (core/problem, schur_solver)
    "_order": ["_order.c"],  # approximate minimum degree (microlie.optim.linalg.ordering)
    "_pattern": ["_pattern.c"],  # the block pattern of H (microlie.optim.core.problem)
    "_symbolic": ["_symbolic.c"],  # the supernodal symbolic analysis (linalg.cholesky)
    "_chol": ["_chol.c"],  # the supernodal Cholesky loop on NumPy's or SciPy's BLAS/LAPACK
    "_incremental": ["_incremental.c"],  # the Bayes tree of optim.online (bayes_tree.py)
    "_online": ["_online.c"],  # IncrementalSmoother's per-update bookkeeping (incremental.py)
    "_text": ["_text.c"],  # the numeric text-table reader (microlie.traj.io)
    "_info": ["_info.c"],  # build and dispatch information (microlie --version)
}
# the group kernels: exactly the operations of the component formulas (no contraction to fused
# multiply-adds), so that one element and a batch give the same bits, equal to the generic
# kernel to the rounding of the elementary functions
EXACT = {"_lie", "_one", "_factors"}
GENERATED = C_DIR / "generated"


def generate_sources(outdir: Path) -> None:
    """Write the generated group kernels (``lie_kernels.h``) into ``outdir``: ``python -m
    microlie._codegen OUTDIR`` on this tree's ``src`` (NumPy only), before compiling."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]), MICROLIE_FAST="0")
    subprocess.run([sys.executable, "-m", "microlie._codegen", str(outdir)], env=env,
                   check=True, cwd=ROOT)


def _machine() -> str:
    return platform.machine().lower()


def baseline_flags() -> list[str]:
    """The ISA flags of a portable build on this platform (see the module docstring)."""
    if os.environ.get("MICROLIE_NATIVE", "0") == "1":
        return ["-mcpu=native"] if _machine() in ("arm64", "aarch64") else ["-march=native"]
    if _machine() in ("x86_64", "amd64"):
        return ["-march=x86-64-v2", "-mtune=generic"]
    if _machine() in ("arm64", "aarch64") and sys.platform.startswith("linux"):
        return ["-march=armv8-a"]
    return []


class OptionalBuildExt(build_ext):
    """build_ext that probes the compiler's flags, skips (with a warning) each extension that
    fails to compile unless ``MICROLIE_REQUIRE_EXT=1``, and records the outcome in
    ``microlie/_c/_build.json``."""

    def run(self) -> None:
        self.outcome: dict[str, object] = {"built": [], "failed": {}}
        if os.environ.get("MICROLIE_BUILD_EXT", "1") == "0":
            self.outcome["skipped"] = "MICROLIE_BUILD_EXT=0"
            self.extensions = []
        else:
            try:
                generate_sources(ROOT / GENERATED)
            except (OSError, subprocess.CalledProcessError) as exc:
                self._fail_all(f"generating the C sources failed: {exc}")
        try:
            super().run()
        except Exception as exc:  # no compiler at all (set-up of the compiler object failed)
            self._fail_all(f"{type(exc).__name__}: {exc}")
            self.outcome["failed"] = {e.name.rsplit(".", 1)[1]: str(exc)
                                      for e in self.extensions}
        self._write_outcome()

    def _fail_all(self, why: str) -> None:
        if os.environ.get("MICROLIE_REQUIRE_EXT", "0") == "1":
            raise RuntimeError(f"microlie: the compiled extensions cannot be built ({why})")
        self.warn(f"microlie: building no compiled extension ({why}); the generic NumPy "
                  "kernels will run")
        self.outcome["skipped"] = why

    def build_extensions(self) -> None:
        import numpy as np

        flags, defines = self._flags()
        self.outcome.update(flags=flags, defines=[d[0] for d in defines])
        for ext in self.extensions:
            ext.include_dirs = [np.get_include(), str(C_DIR), str(GENERATED)]
            exact = ["-ffp-contract=off"] if ext.name.rsplit(".", 1)[1] in EXACT else []
            ext.extra_compile_args = flags + exact
            # one element: libm's scalar functions (vecmath.h), the bits of Python's math module
            one = [("LM_USE_LIBM", "1")] if ext.name.endswith(("._one", "._factors")) else []
            ext.define_macros = defines + one
            ext.libraries = ["m"] if os.name != "nt" else []
        self._failed: list[Extension] = []
        super().build_extensions()
        # the others are still copied into place (--inplace, editable installs)
        self.extensions = [e for e in self.extensions if e not in self._failed]

    def build_extension(self, ext: Extension) -> None:
        short = ext.name.rsplit(".", 1)[1]
        try:
            super().build_extension(ext)
        except Exception as exc:  # CompileError, LinkError, DistutilsExecError, OSError
            if os.environ.get("MICROLIE_REQUIRE_EXT", "0") == "1":
                raise
            self.warn(f"microlie: the compiled extension {ext.name} was not built ({exc}); "
                      "its generic NumPy kernels will run")
            self.outcome["failed"][short] = str(exc)  # type: ignore[index]
            self._failed.append(ext)
        else:
            self.outcome["built"].append(short)  # type: ignore[union-attr]

    # ---------------------------------------------------------------- compiler probes

    def _compiles(self, code: str, flags: list[str], link: bool = False) -> bool:
        """Whether the compiler accepts ``code`` with ``flags`` (and links it into a shared
        object when ``link``)."""
        with tempfile.TemporaryDirectory() as tmp:
            src = Path(tmp) / "probe.c"
            src.write_text(code)
            try:
                objs = self.compiler.compile([str(src)], output_dir=tmp, extra_postargs=flags)
                if link:
                    self.compiler.link_shared_object(objs, str(Path(tmp) / "probe.so"))
            except Exception:
                return False
        return True

    def _flags(self) -> tuple[list[str], list[tuple[str, str | None]]]:
        if self.compiler.compiler_type == "msvc":
            return ["/O2"], []
        # -fno-trapping-math: the kernels never read floating-point exception flags; without it
        # GCC does not if-convert the selects of the element formulas (both sides computed, the
        # side not taken may hold NaN or inf) on targets without masked vector instructions
        wanted = ["-O3", "-fno-math-errno", "-fno-trapping-math", "-fopenmp-simd",
                  *baseline_flags()]
        if os.environ.get("MICROLIE_CFLAGS"):
            wanted = os.environ["MICROLIE_CFLAGS"].split()
        flags = ["-std=c11"] + [f for f in wanted if self._compiles("int x;\n", [f])]
        baseline = " ".join(f for f in flags if f.startswith(("-march", "-mcpu"))) or "default"
        defines: list[tuple[str, str | None]] = [("LM_BASELINE", json.dumps(baseline))]
        native = os.environ.get("MICROLIE_NATIVE", "0") == "1"
        if not native and _machine() in ("x86_64", "amd64") and self._compiles(
                '#define LM_CLONES 1\n#include "dispatch.h"\n'
                "LM_HOT int f(int x) { return x + 1; }\n"
                "int g(void) { return f(1) + (lm_cpu_level()[0] == 'b'); }\n",
                flags + [f"-I{ROOT / C_DIR}", "-fPIC"], link=True):
            defines.append(("LM_CLONES", "1"))
        return flags, defines

    # ---------------------------------------------------------------- the record

    def _write_outcome(self) -> None:
        """``microlie/_c/_build.json`` beside the built modules: in build_lib, and in the
        source tree for ``--inplace`` and editable installs (which copy the modules there)."""
        bases = [Path(self.build_lib)]
        if self.inplace or getattr(self, "editable_mode", False):
            bases.append(ROOT / "src")
        for base in bases:
            path = base / "microlie" / "_c" / "_build.json"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(self.outcome, indent=1, sort_keys=True) + "\n")

    def get_outputs(self) -> list[str]:  # the record is installed with the modules
        path = Path(self.build_lib) / "microlie" / "_c" / "_build.json"
        return [*super().get_outputs(), str(path)]


setup(
    ext_modules=[Extension(f"microlie._c.{name}", [str(C_DIR / s) for s in sources])
                 for name, sources in EXTENSIONS.items()],
    cmdclass={"build_ext": OptionalBuildExt},
)
