"""Throughput of vecmath.h (src/microlie/_c) against glibc's scalar libm and its vector
library libmvec, on arrays of 4096 values in `omp simd` loops, for each ISA level.

    python benchmarks/vecmath.py [--rounds 15]

Builds one C program per ISA level (cc -O3 -fno-math-errno -fno-trapping-math -fopenmp-simd,
-march=x86-64-v2, then with -mavx2 -mfma) in a temporary folder. Three loops per function: ours
(lm_*), libm called per element (no vector version declared), and libmvec (the same loop with
`declare simd` prototypes, so GCC calls glibc's vector variants; left out where -lmvec does not
link). Timed round-robin in one process (CPU time, best of the rounds); prints ns per value and
the ratios ours/libm and ours/libmvec (below 1: ours is faster). Arguments: sin, tan in
[-6, 6]; atan2 on normal pairs; exp, expm1 in [-5, 5]; log in [1e-3, 1e3].
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HEADERS = Path(__file__).resolve().parent.parent / "src" / "microlie" / "_c"
FUNCS = [("sin", 1), ("cos", 1), ("tan", 1), ("atan2", 2), ("exp", 1), ("expm1", 1), ("log", 1)]

PROGRAM = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "vecmath.h"
#define N 4096
double xd[N], yd[N], od[N];
float xf[N], yf[N], of[N];
static double now(void) {
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}
#ifdef MVEC
#define DECL _Pragma("omp declare simd notinbranch")
#else
#define DECL
#endif
#define LOOPS_1(F, T, X, Y, O) LOOPS(F, (T), 1, T, X, Y, O)
#define LOOPS_2(F, T, X, Y, O) LOOPS(F, (T, T), 2, T, X, Y, O)
#define LOOPS(F, A, K, T, X, Y, O)                                                              \
    DECL extern T F A;                                                                        \
    __attribute__((noinline)) static void ours_##F(void) {                                    \
        _Pragma("omp simd") for (int i = 0; i < N; i++) O[i] = lm_##F ARGS_##K(X, Y);          \
    }                                                                                         \
    __attribute__((noinline)) static void libm_##F(void) {                                    \
        _Pragma("GCC novector") for (int i = 0; i < N; i++) O[i] = F ARGS_##K(X, Y);           \
    }                                                                                         \
    __attribute__((noinline)) static void vlib_##F(void) {                                    \
        _Pragma("omp simd") for (int i = 0; i < N; i++) O[i] = F ARGS_##K(X, Y);               \
    }
#define ARGS_1(X, Y) (X[i])
#define ARGS_2(X, Y) (X[i], Y[i])
"""


def program(mvec: bool) -> str:
    """The C source: the three loops of every function in both precisions and the timer."""
    names = [f + s for f, _ in FUNCS for s in ("", "f")]
    body = [PROGRAM.replace("#ifdef MVEC", "#if 1" if mvec else "#if 0")]
    arrays = (("double", "", "xd", "yd", "od"), ("float", "f", "xf", "yf", "of"))
    body += [f"LOOPS_{k}({f}{s}, {T}, {X}, {Y}, {O})" for f, k in FUNCS
             for T, s, X, Y, O in arrays]
    table = ", ".join(f'{{"{n}", ours_{n}, libm_{n}, vlib_{n}}}' for n in names)
    body.append(r"""
typedef void (*fn)(void);
struct row { const char *name; fn f[3]; } rows[] = {TABLE};
int main(int argc, char **argv) {
    int rounds = argc > 1 ? atoi(argv[1]) : 15, nr = sizeof rows / sizeof rows[0];
    srand(1);
    for (int i = 0; i < N; i++) {
        double u = rand() / (double)RAND_MAX, v = rand() / (double)RAND_MAX;
        xd[i] = 12.0 * u - 6.0; yd[i] = 4.0 * v - 1.5; xf[i] = (float)xd[i]; yf[i] = (float)yd[i];
    }
    double best[64][3];
    for (int r = 0; r < nr; r++) for (int j = 0; j < 3; j++) best[r][j] = 1e30;
    for (int k = 0; k < rounds; k++)
        for (int r = 0; r < nr; r++) {
            int lg = rows[r].name[0] == 'l', ex = rows[r].name[0] == 'e';
            for (int i = 0; i < N; i++) {  /* the domain of each function */
                double u = (xd[i] + 6.0) / 12.0;
                double a = lg ? 1e-3 * __builtin_pow(1e6, u) : ex ? 10.0 * u - 5.0 : xd[i];
                xd[i] = a; xf[i] = (float)a;
            }
            for (int j = 0; j < 3; j++) {
                double t0 = now();
                for (int rep = 0; rep < 20; rep++) {
                    rows[r].f[j]();
                    __asm__ volatile("" ::: "memory");
                }
                double t = (now() - t0) / (20.0 * N);
                if (t < best[r][j]) best[r][j] = t;
            }
            for (int i = 0; i < N; i++) {  /* back to the shared input */
                double u = rand() / (double)RAND_MAX;
                xd[i] = 12.0 * u - 6.0; xf[i] = (float)xd[i];
            }
        }
    for (int r = 0; r < nr; r++)
        printf("%s %.4f %.4f %.4f\n", rows[r].name, 1e9 * best[r][0], 1e9 * best[r][1],
               1e9 * best[r][2]);
    return 0;
}
""".replace("TABLE", table))
    return "\n".join(body)


def build(cc: str, tmp: Path, isa: list[str], mvec: bool) -> Path | None:
    src = tmp / f"bench{'_mvec' if mvec else ''}.c"
    src.write_text(program(mvec))
    exe = tmp / (src.stem + "_" + "_".join(x.strip("-") for x in isa))
    cmd = [cc, "-O3", "-fno-math-errno", "-fno-trapping-math", "-fopenmp-simd", "-std=c11",
           *isa, f"-I{HEADERS}", str(src), "-o", str(exe), *(["-lmvec"] if mvec else []), "-lm"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        if mvec:
            return None
        raise SystemExit(f"build failed: {' '.join(cmd)}\n{r.stderr}")
    return exe


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=15)
    args = ap.parse_args()
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise SystemExit("no C compiler (cc) on PATH")
    x86 = platform.machine() in ("x86_64", "AMD64")
    isas = ({"x86-64-v2": ["-march=x86-64-v2"],
             "avx2+fma": ["-march=x86-64-v2", "-mavx2", "-mfma"]} if x86 else {"default": []})
    print(f"load: {tuple(round(x, 2) for x in os.getloadavg())}, {cc}, N = 4096 per loop, "
          f"ns per value (best of {args.rounds} rounds)")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for label, isa in isas.items():
            plain = build(cc, tmp, isa, mvec=False)
            mv = build(cc, tmp, isa, mvec=True) if x86 and sys.platform.startswith("linux") \
                else None
            res = {}
            for exe, tag in ((plain, "plain"), (mv, "mvec")):
                if exe is None:
                    continue
                out = subprocess.run([str(exe), str(args.rounds)], capture_output=True,
                                     text=True, check=True).stdout
                for ln in out.splitlines():
                    name, ours, libm, vlib = ln.split()
                    res.setdefault(name, {})[tag] = (float(ours), float(libm), float(vlib))
            print(f"\n{label}:{'' if mv else ' (libmvec does not link: no column)'}")
            print(f"{'function':9s} {'ours':>7s} {'libm':>7s} {'libmvec':>8s} "
                  f"{'ours/libm':>10s} {'ours/libmvec':>13s}")
            for name, r in res.items():
                ours, libm, _ = r["plain"]
                vlib = r["mvec"][2] if "mvec" in r else float("nan")
                print(f"{name:9s} {ours:7.2f} {libm:7.2f} {vlib:8.2f} {ours / libm:10.2f} "
                      f"{ours / vlib:13.2f}")


if __name__ == "__main__":
    main()
