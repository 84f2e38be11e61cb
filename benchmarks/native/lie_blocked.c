/* The native loop in the blocked form (benchmarks/native.py): rows copied into
 * structure-of-arrays blocks of S elements, the element formula (the generated lie_kernels.h of
 * the build, microlie._codegen) in an `omp simd` loop over the block (GCC vectorises it; the
 * elementary functions are glibc's libmvec, through the vecmath.h that benchmarks/native.py
 * writes for this reference), copied back; outputs preallocated. This is what a careful C
 * programmer gets on microlie's row layout for the operations whose rows of 6 or 7 do not
 * vectorise as plain loops (lie_native.cpp). Built by benchmarks/native.py: gcc -O3
 * -march=native -fno-math-errno -fopenmp-simd -std=c11 -fno-trapping-math -shared -fPIC
 * -I <its vecmath.h> -I src/microlie/_c/generated -lmvec */
#define S 32
#include "lie_kernels.h"

typedef long ix;

#define LOAD(KW)                                                                               \
    static void load_##KW(const double *restrict x, ix m, double *restrict buf) {             \
        for (ix j = 0; j < m; j++)                                                             \
            for (int c = 0; c < KW; c++) buf[c * S + j] = x[KW * j + c];                      \
    }
#define STORE(KW)                                                                              \
    static void store_##KW(const double *restrict buf, ix m, double *restrict y) {            \
        for (ix j = 0; j < m; j++)                                                             \
            for (int c = 0; c < KW; c++) y[KW * j + c] = buf[c * S + j];                      \
    }
LOAD(6) LOAD(7) STORE(6) STORE(7) STORE(36)

/* two inputs of 7 into one block buffer (rows 0..6 and 7..13) */
static void load_77(const double *a, const double *b, ix m, double *buf) {
    load_7(a, m, buf);
    load_7(b, m, buf + 7 * S);
}

void b_se3_exp(const double *t, double *p, ix n) {
    double ib[6 * S] __attribute__((aligned(64))), ob[7 * S] __attribute__((aligned(64)));
    for (ix i0 = 0; i0 < n; i0 += S) {
        ix m = n - i0 < S ? n - i0 : S;
        load_6(t + 6 * i0, m, ib);
#pragma omp simd
        for (ix j = 0; j < m; j++) se3_exp(ib + j, ib + j, ob + j, S);
        store_7(ob, m, p + 7 * i0);
    }
}

void b_se3_log(const double *p, double *t, ix n) {
    double ib[7 * S] __attribute__((aligned(64))), ob[6 * S] __attribute__((aligned(64)));
    for (ix i0 = 0; i0 < n; i0 += S) {
        ix m = n - i0 < S ? n - i0 : S;
        load_7(p + 7 * i0, m, ib);
#pragma omp simd
        for (ix j = 0; j < m; j++) se3_log(ib + j, ib + j, ob + j, S);
        store_6(ob, m, t + 6 * i0);
    }
}

void b_se3_exp_jac(const double *t, double *p, double *J, ix n) {
    double ib[6 * S] __attribute__((aligned(64))), ob[43 * S] __attribute__((aligned(64)));
    for (ix i0 = 0; i0 < n; i0 += S) {
        ix m = n - i0 < S ? n - i0 : S;
        load_6(t + 6 * i0, m, ib);
#pragma omp simd
        for (ix j = 0; j < m; j++) se3_exp_jac(ib + j, ib + j, ob + j, S);
        store_7(ob, m, p + 7 * i0);
        store_36(ob + 7 * S, m, J + 36 * i0);
    }
}

void b_se3_between_jac(const double *p, const double *q, double *z, double *J, ix n) {
    double ib[14 * S] __attribute__((aligned(64))), ob[43 * S] __attribute__((aligned(64)));
    for (ix i0 = 0; i0 < n; i0 += S) {
        ix m = n - i0 < S ? n - i0 : S;
        load_77(p + 7 * i0, q + 7 * i0, m, ib);
#pragma omp simd
        for (ix j = 0; j < m; j++) se3_between_jac(ib + j, ib + 7 * S + j, ob + j, S);
        store_7(ob, m, z + 7 * i0);
        store_36(ob + 7 * S, m, J + 36 * i0);
    }
}

void b_se3_minus_jac(const double *y, const double *x, double *t, double *Jy, double *Jx, ix n) {
    double ib[14 * S] __attribute__((aligned(64))), ob[78 * S] __attribute__((aligned(64)));
    for (ix i0 = 0; i0 < n; i0 += S) {
        ix m = n - i0 < S ? n - i0 : S;
        load_77(y + 7 * i0, x + 7 * i0, m, ib);
#pragma omp simd
        for (ix j = 0; j < m; j++) se3_minus_jac(ib + j, ib + 7 * S + j, ob + j, S);
        store_6(ob, m, t + 6 * i0);
        store_36(ob + 6 * S, m, Jy + 36 * i0);
        store_36(ob + 42 * S, m, Jx + 36 * i0);
    }
}
