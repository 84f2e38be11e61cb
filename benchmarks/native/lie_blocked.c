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

/* rows of kw components <-> a structure-of-arrays block of m <= S elements */
static inline void load(const double *restrict x, ix m, int kw, double *restrict buf) {
    for (ix j = 0; j < m; j++)
        for (int c = 0; c < kw; c++) buf[c * S + j] = x[kw * j + c];
}
static inline void store(const double *restrict buf, ix m, int kw, double *restrict y) {
    for (ix j = 0; j < m; j++)
        for (int c = 0; c < kw; c++) y[kw * j + c] = buf[c * S + j];
}

/* b_<group>_<op>: the generated element function G_OP over blocks; A, B the input widths (B = 0:
 * one input), O the outputs' widths (value, then Jacobians), written to the output pointers */
#define BLOCKS(FN, A, B, NO, ...)                                                              \
    {                                                                                          \
        const int ow[3] = {__VA_ARGS__};                                                       \
        int tot = 0;                                                                           \
        for (int k = 0; k < NO; k++) tot += ow[k];                                             \
        double ib[(A + B) * S] __attribute__((aligned(64)));                                   \
        double ob[tot * S] __attribute__((aligned(64)));                                       \
        for (ix i0 = 0; i0 < n; i0 += S) {                                                     \
            ix m = n - i0 < S ? n - i0 : S;                                                    \
            load(x + A * i0, m, A, ib);                                                        \
            if (B) load(y + B * i0, m, B, ib + A * S);                                         \
            _Pragma("omp simd") for (ix j = 0; j < m; j++)                                     \
                FN(ib + j, ib + A * S + j, ob + j, S);                                         \
            int off = 0;                                                                       \
            for (int k = 0; k < NO; k++) {                                                     \
                store(ob + off * S, m, ow[k], outs[k] + ow[k] * i0);                           \
                off += ow[k];                                                                  \
            }                                                                                  \
        }                                                                                      \
    }

#define B1(FN, A, O)                                                                           \
    void b_##FN(const double *x, double *o, ix n) {                                            \
        const double *y = x;                                                                   \
        double *outs[1] = {o};                                                                 \
        BLOCKS(FN, A, 0, 1, O)                                                                 \
    }
#define B1J(FN, A, O, J)                                                                       \
    void b_##FN(const double *x, double *o, double *jac, ix n) {                               \
        const double *y = x;                                                                   \
        double *outs[2] = {o, jac};                                                            \
        BLOCKS(FN, A, 0, 2, O, J)                                                              \
    }
#define B2J(FN, A, O, J)                                                                       \
    void b_##FN(const double *x, const double *y, double *o, double *jac, ix n) {              \
        double *outs[2] = {o, jac};                                                            \
        BLOCKS(FN, A, A, 2, O, J)                                                              \
    }
#define B2JJ(FN, A, O, J)                                                                      \
    void b_##FN(const double *x, const double *y, double *o, double *j1, double *j2, ix n) {    \
        double *outs[3] = {o, j1, j2};                                                         \
        BLOCKS(FN, A, A, 3, O, J, J)                                                           \
    }

/* rows of 6 or more with elementary functions (the plain loops do not vectorise them well) */
B1(se3_exp, 6, 7) B1(se3_log, 7, 6) B1J(se3_exp_jac, 6, 7, 36) B2J(se3_between_jac, 7, 7, 36)
B2JJ(se3_minus_jac, 7, 6, 36)
B1(sim3_exp, 7, 8) B1(sim3_log, 8, 7) B1J(sim3_exp_jac, 7, 8, 49) B2J(sim3_between_jac, 8, 8, 49)
B2JJ(sim3_minus_jac, 8, 7, 49)
B1(se23_exp, 9, 10) B1(se23_log, 10, 9) B1J(se23_exp_jac, 9, 10, 81)
B2J(se23_between_jac, 10, 10, 81) B2JJ(se23_minus_jac, 10, 9, 81)
