"""Build of the compiled kernels. The group kernels (_lie, _one, and the edge loop of _graph) are
generated first from microlie's component formulas (microlie._codegen -> generated/). Flags: -O3
with the host's vector ISA (this is a local build from source; a distributed wheel would target a
fixed ISA level), math without errno or traps. The elementary functions of the group kernels come
from vecmath.h (our own vectorisable kernels), so no vector math library is linked.
Set MICROLIE_FAST_CFLAGS to override the flags (for example on a compiler without -march)."""

import os
import platform
import sys

import numpy as np
from setuptools import Extension, setup

HERE = os.path.dirname(os.path.abspath(__file__))
SRC = os.path.join(HERE, "src", "microlie_fast")
GENERATED = os.path.join(SRC, "generated")


def generate_kernels(outdir: str) -> None:
    """Write the generated group kernels (lie_kernels.h) from microlie's component formulas
    (microlie._codegen.generate; the microlie sources beside this folder, or an installed
    microlie)."""
    root = os.path.join(os.path.dirname(HERE), "src")
    if os.path.isdir(os.path.join(root, "microlie")):
        sys.path.insert(0, root)
    os.environ["MICROLIE_FAST"] = "0"  # the generic kernels only, whatever is installed
    from microlie._codegen import generate

    generate(outdir)


generate_kernels(GENERATED)

# -fno-trapping-math: the kernels never read floating-point exception flags, and without it GCC
# does not if-convert the selects of the element formulas (their operands could trap) on targets
# without masked vector instructions, so the element loops stay scalar
flags = ["-O3", "-fno-math-errno", "-fno-trapping-math", "-fopenmp-simd", "-std=c11"]
libs = ["m"]
if sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64"):
    flags.append("-march=native")
elif platform.machine() in ("arm64", "aarch64"):
    flags.append("-mcpu=native")
if os.environ.get("MICROLIE_FAST_CFLAGS"):
    flags = os.environ["MICROLIE_FAST_CFLAGS"].split()
# the group kernels: exactly the operations of the component formulas (no fused multiply-add
# contraction), so that one element and a batch give the same bits, equal to the generic kernel
# to the rounding of the elementary functions; both sides of a small-angle selection are
# computed (-fno-trapping-math above: GCC may evaluate the side not taken and vectorise the loop)
kernel_flags = [*flags, "-ffp-contract=off"]

setup(
    ext_modules=[
        Extension(
            "microlie_fast._lie",
            sources=["src/microlie_fast/_lie.c"],
            include_dirs=[np.get_include(), "src/microlie_fast", "src/microlie_fast/generated"],
            extra_compile_args=kernel_flags,
            libraries=libs,
        ),
        Extension(
            "microlie_fast._graph",
            sources=["src/microlie_fast/_graph.c"],
            include_dirs=[np.get_include(), "src/microlie_fast", "src/microlie_fast/generated"],
            extra_compile_args=[*flags, "-fno-trapping-math"],
            libraries=libs,
        ),
        Extension(  # one-element entry points (microlie.groups._single)
            "microlie_fast._one",
            sources=["src/microlie_fast/_one.c"],
            include_dirs=[np.get_include(), "src/microlie_fast", "src/microlie_fast/generated"],
            extra_compile_args=kernel_flags,
            libraries=libs,
        ),
        Extension(  # the engine's normal equations: core/problem.py, linalg/schur_solver.py
            "microlie_fast._normal",
            sources=["src/microlie_fast/_normal.c"],
            include_dirs=[np.get_include()],
            extra_compile_args=flags,
            libraries=["m"],  # fma() where the target has no fused multiply-add instruction
        ),
        Extension(  # BAL reprojection factors (microlie.optim.core.compiled.ReprojectionPlan)
            "microlie_fast._reproj",
            sources=["src/microlie_fast/_reproj.c"],
            include_dirs=[np.get_include()],
            extra_compile_args=flags,
        ),
        Extension(  # the reader of numeric text tables (microlie.traj.io)
            "microlie_fast._text",
            sources=["src/microlie_fast/_text.c"],
            include_dirs=[np.get_include()],
            extra_compile_args=flags,
        ),
        Extension(  # approximate minimum degree ordering (microlie.optim.linalg.ordering)
            "microlie_fast._order",
            sources=["src/microlie_fast/_order.c"],
            include_dirs=[np.get_include(), "src/microlie_fast"],
            extra_compile_args=flags,
            libraries=["m"],
        ),
        Extension(  # the symbolic supernodal analysis (microlie.optim.linalg.cholesky)
            "microlie_fast._symbolic",
            sources=["src/microlie_fast/_symbolic.c"],
            include_dirs=[np.get_include(), "src/microlie_fast"],
            extra_compile_args=flags,
        ),
        # the numeric supernodal Cholesky loop on SciPy's BLAS/LAPACK (capsules, no BLAS link)
        Extension(
            "microlie_fast._chol",
            sources=["src/microlie_fast/_chol.c"],
            include_dirs=[np.get_include()],
            extra_compile_args=flags,
        ),
    ]
)
