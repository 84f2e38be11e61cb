"""Build of the compiled kernels. Flags: -O3 with the host's vector ISA (this is a local build
from source; a distributed wheel would target a fixed ISA level), math without errno so that
GCC may vectorise calls, and glibc's libmvec for the vector versions of tan/sin/cos/atan2.
Set MICROLIE_FAST_CFLAGS to override the flags (for example on a compiler without -march)."""

import os
import platform
import sys

import numpy as np
from setuptools import Extension, setup

flags = ["-O3", "-fno-math-errno", "-fopenmp-simd", "-std=c11"]
libs = ["m"]
if sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64"):
    flags.append("-march=native")
    libs.insert(0, "mvec")  # glibc's vector math library
    flags.append("-DLM_LIBMVEC")
elif platform.machine() in ("arm64", "aarch64"):
    flags.append("-mcpu=native")
if os.environ.get("MICROLIE_FAST_CFLAGS"):
    flags = os.environ["MICROLIE_FAST_CFLAGS"].split()

setup(
    ext_modules=[
        Extension(
            "microlie_fast._lie",
            sources=["src/microlie_fast/_lie.c"],
            include_dirs=[np.get_include(), "src/microlie_fast"],
            extra_compile_args=flags,
            libraries=libs,
        ),
        Extension(
            "microlie_fast._graph",
            sources=["src/microlie_fast/_graph.c"],
            include_dirs=[np.get_include(), "src/microlie_fast"],
            extra_compile_args=flags,
            libraries=libs,
        ),
        Extension(  # one-element entry points (microlie.groups._single)
            "microlie_fast._one",
            sources=["src/microlie_fast/_one.c"],
            include_dirs=[np.get_include(), "src/microlie_fast"],
            extra_compile_args=flags,
            libraries=libs,
        ),
        Extension(  # the Schur complement of bundle adjustment (microlie.optim.linalg.schur)
            "microlie_fast._schur",
            sources=["src/microlie_fast/_schur.c"],
            include_dirs=[np.get_include()],
            extra_compile_args=flags,
        ),
        Extension(  # the engine's normal equations: core/problem.py, linalg/schur_solver.py
            "microlie_fast._normal",
            sources=["src/microlie_fast/_normal.c"],
            include_dirs=[np.get_include()],
            extra_compile_args=flags,
            libraries=["m"],  # fma() where the target has no fused multiply-add instruction
        ),
        Extension(  # the reader of numeric text tables (microlie.traj.io)
            "microlie_fast._text",
            sources=["src/microlie_fast/_text.c"],
            include_dirs=[np.get_include()],
            extra_compile_args=flags,
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
