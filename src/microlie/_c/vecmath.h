/* Vectorisable elementary functions: lm_sin, lm_cos, lm_tan, lm_sincos, lm_atan2, lm_exp,
 * lm_expm1, lm_log (double) and lm_sinf, lm_cosf, lm_tanf, lm_atan2f, lm_expf, lm_expm1f, lm_logf
 * (float), written with selects instead of branches so that GCC vectorises the loops that call
 * them (`#pragma omp simd`, -O3, from baseline SSE4.2 up; no libmvec, no -ffast-math needed),
 * without errno. Our own kernels: Cody-Waite range reduction (pi/2 and ln 2 in parts whose
 * products with the reduced integer are exact), minimax polynomials computed by fast/gen_coeffs.py
 * (vecmath_coeffs.h), fdlibm-style reconstruction. The float functions evaluate in double with
 * shorter polynomials and round once at the end.
 *
 * Accuracy (tests/test_vecmath.py against mpmath; measured maxima, without / with FMA): double
 * sin 0.72/0.72, cos 0.76/0.74, tan 1.77/1.68, exp 0.79/0.85, expm1 1.36/1.27, log 0.76/0.74,
 * atan2 1.06/1.13 ulp; every float function 0.50-0.51 ulp.
 * Special values follow C99 Annex F: signed zeros kept, NaN propagated, sin/cos/tan(+-inf) = NaN,
 * every +-0/+-inf case of atan2, exp/expm1 overflow to inf and underflow to 0 / -1 (gradual
 * through the subnormals), log(0) = -inf, log(<0) = NaN, log of subnormals exact.
 *
 * Large trigonometric arguments: the reduction is exact for |x| <= LM_TRIG_MAX (2^26, about
 * 6.7e7; pi/2 is carried to 134 bits). Above it lm_sin/cos/tan/sincos (and the f versions)
 * return NaN, never a wrong number; lm_trig_big(x) tells which lanes these are, so that a caller
 * can recompute them with libm in a scalar pass after its vector loop (as tests/test_vecmath.py
 * does): a Payne-Hanek path inside the vector kernel would be paid by every lane. */
#pragma once
#include <math.h>
#include <stdint.h>
#include <string.h>

#ifdef LM_USE_LIBM
/* The one-element entry points (_one.c, built with LM_USE_LIBM): nothing to vectorise there, so
 * the C library's scalar functions, the ones Python's math module calls: a single element in C
 * gives the same bits as the traced Python formula (the exact-lock tests of as_rpy, signed zeros
 * of doctests, the torch single-element path). */
#define LM_VM static inline __attribute__((always_inline, unused))
LM_VM double lm_sin(double x) { return sin(x); }
LM_VM double lm_cos(double x) { return cos(x); }
LM_VM void lm_sincos(double x, double *s, double *c) { *s = sin(x); *c = cos(x); }
LM_VM double lm_tan(double x) { return tan(x); }
LM_VM double lm_atan2(double y, double x) { return atan2(y, x); }
LM_VM double lm_exp(double x) { return exp(x); }
LM_VM double lm_expm1(double x) { return expm1(x); }
LM_VM double lm_log(double x) { return log(x); }
LM_VM float lm_sinf(float x) { return sinf(x); }
LM_VM float lm_cosf(float x) { return cosf(x); }
LM_VM float lm_tanf(float x) { return tanf(x); }
LM_VM float lm_atan2f(float y, float x) { return atan2f(y, x); }
LM_VM float lm_expf(float x) { return expf(x); }
LM_VM float lm_expm1f(float x) { return expm1f(x); }
LM_VM float lm_logf(float x) { return logf(x); }
#else

#include "vecmath_coeffs.h"

#define LM_VM static inline __attribute__((always_inline))
#define LM_TRIG_MAX 0x1p26

LM_VM uint64_t lm__bits(double x) {
    uint64_t u;
    memcpy(&u, &x, sizeof u);
    return u;
}
LM_VM double lm__dbl(uint64_t u) {
    double x;
    memcpy(&x, &u, sizeof x);
    return x;
}

/* c ? a : b as a bit blend: both operands are computed in every lane. A plain ?: lets GCC move
 * an operand's computation into a branch, and with -ftrapping-math (the default) it does not
 * if-convert floating-point operations that could trap: the loop would not vectorise on targets
 * without masked instructions (x86-64-v2, AVX2). */
LM_VM double lm__sel(int c, double a, double b) {
    uint64_t m = -(uint64_t)(c != 0);
    return lm__dbl((lm__bits(a) & m) | (lm__bits(b) & ~m));
}

/* Horner's scheme, fused where the target has FMA (-mfma, -march=x86-64-v3, AArch64) */
LM_VM double lm__poly(double x, const double *c, int n) {
    double acc = c[n - 1];
#pragma GCC unroll 16
    for (int i = n - 2; i >= 0; i--) {
#if defined(__FMA__) || defined(__ARM_FEATURE_FMA)
        acc = __builtin_fma(acc, x, c[i]);
#else
        acc = acc * x + c[i];
#endif
    }
    return acc;
}

/* round to nearest (even) for |x| < 2^51, inline (GCC calls rint() unless -fno-trapping-math);
 * the low bits of lm__bits(x + LM_SHIFT) are then the integer, mod any small power of 2 */
#define LM_SHIFT 0x1.8p52
LM_VM double lm__round(double x) { return (x + LM_SHIFT) - LM_SHIFT; }

/* x limited to [lo, hi] (NaN stays NaN) */
LM_VM double lm__clamp(double x, double lo, double hi) {
    double a = lm__sel(x > hi, hi, x);
    return lm__sel(a < lo, lo, a);
}

/* 2^n for an integer-valued n in [-1022, 1023] */
LM_VM double lm__pow2(double n) {
    return lm__dbl(lm__bits(n + (1023.0 + 0x1p52)) << 52);
}

/* whether x is outside the exact range of the trigonometric kernels (NaN there) */
LM_VM int lm_trig_big(double x) { return fabs(x) > LM_TRIG_MAX; }

/* ---- sin, cos, tan -------------------------------------------------------------------------- */

/* x = n pi/2 + (y + e), |y + e| <= pi/4 (about), y + e exact to ~2^-105 relative for
 * |x| <= LM_TRIG_MAX; *q = n (integer-valued double). f32: fewer parts (float accuracy). */
LM_VM double lm__reduce(double x, double *e, uint64_t *q, int f32) {
    double kd = x * LM_2_PI + LM_SHIFT, n = kd - LM_SHIFT;
    *q = lm__bits(kd) & 3; /* n mod 4 */
    double r = x - n * LM_PIO2_1; /* exact: n has <= 26 bits, LM_PIO2_1 27 */
    if (f32) {
        *e = 0.0;
        return (r - n * LM_PIO2_2) - n * LM_PIO2_3;
    }
    double w = n * LM_PIO2_2, y = r - w;
    double bv = r - y, err = (r - (y + bv)) + (bv - w); /* two-sum: y + err = r - w exactly */
    double w3 = n * LM_PIO2_3, y3 = y - w3;
    double bv3 = y - y3, err3 = (y - (y3 + bv3)) + (bv3 - w3);
    double lo = (err + err3) - n * LM_PIO2_4;
    double hi = y3 + lo;
    *e = lo - (hi - y3);
    return hi;
}

/* sin and cos of y + e (|y| <= ~pi/4) */
LM_VM void lm__sincos_poly(double y, double e, double *s, double *c, int f32) {
    double t = y * y;
    if (f32) {
        *s = y + y * t * lm__poly(t, C_SINF, N_SINF);
        *c = (1.0 - 0.5 * t) + t * t * lm__poly(t, C_COSF, N_COSF);
        return;
    }
    *s = y + (y * t * lm__poly(t, C_SIN, N_SIN) + e * (1.0 - 0.5 * t));
    double hz = 0.5 * t, w = 1.0 - hz;
    *c = w + (((1.0 - w) - hz) + (t * t * lm__poly(t, C_COS, N_COS) - y * e));
}

/* (sin x, cos x), with the quadrant of the reduction applied */
LM_VM void lm__sincos(double x, double *s, double *c, int f32) {
    double e, ps, pc;
    uint64_t q;
    double y = lm__reduce(x, &e, &q, f32);
    lm__sincos_poly(y, e, &ps, &pc, f32);
    int odd = (q & 1) != 0;
    double ss = lm__sel(odd, pc, ps), cc = lm__sel(odd, ps, pc);
    ss = lm__sel((q & 2) != 0, -ss, ss);       /* quadrants 2, 3: sin < 0 */
    cc = lm__sel(((q + 1) & 2) != 0, -cc, cc); /* quadrants 1, 2: cos < 0 */
    int big = fabs(x) > LM_TRIG_MAX, zero = x == 0.0;
    ss = lm__sel(zero, x, ss); /* sin(-0) = -0 */
    *s = lm__sel(big, NAN, ss);
    *c = lm__sel(big, NAN, cc);
}

LM_VM double lm__tan(double x, int f32) {
    double e, ps, pc;
    uint64_t q;
    double y = lm__reduce(x, &e, &q, f32);
    lm__sincos_poly(y, e, &ps, &pc, f32);
    int odd = (q & 1) != 0;
    double num = lm__sel(odd, -pc, ps), den = lm__sel(odd, ps, pc);
    double t = num / den;
    int big = fabs(x) > LM_TRIG_MAX, zero = x == 0.0;
    t = lm__sel(zero, x, t);
    return lm__sel(big, NAN, t);
}

LM_VM void lm_sincos(double x, double *s, double *c) { lm__sincos(x, s, c, 0); }
LM_VM double lm_sin(double x) {
    double s, c;
    lm__sincos(x, &s, &c, 0);
    return s;
}
LM_VM double lm_cos(double x) {
    double s, c;
    lm__sincos(x, &s, &c, 0);
    return c;
}
LM_VM double lm_tan(double x) { return lm__tan(x, 0); }
LM_VM float lm_sinf(float x) {
    double s, c;
    lm__sincos((double)x, &s, &c, 1);
    return (float)s;
}
LM_VM float lm_cosf(float x) {
    double s, c;
    lm__sincos((double)x, &s, &c, 1);
    return (float)c;
}
LM_VM float lm_tanf(float x) { return (float)lm__tan((double)x, 1); }

/* ---- atan2 ---------------------------------------------------------------------------------- */

/* atan2 from z = min(|x|,|y|)/max(|x|,|y|) in [0, 1]: atan z = b + atan u with (b, u) =
 * (0, z) below 7/16, (atan 1/2, (2z - 1)/(2 + z)) below 11/16, (pi/4, (z - 1)/(z + 1)) above
 * (|u| <= 7/16; u from the unrounded operands); then the octant (m pi/4 +- ...) and the sign. */
LM_VM double lm__atan2(double y, double x, int f32) {
    double ax = fabs(x), ay = fabs(y);
    int swap = ay > ax;
    double num = lm__sel(swap, ax, ay), den = lm__sel(swap, ay, ax); /* num <= den */
    int same = num == den; /* also both infinite */
    /* the range from exact comparisons (16 num exact; 7 den, 11 den rounded only at overflow) */
    int zero = den == 0.0, r1 = (16.0 * num >= 7.0 * den) & !zero;
    int r2 = (16.0 * num >= 11.0 * den) & !zero;
    double sc = lm__sel(den > 0x1p1020, 0.25, 1.0), ns = num * sc, ds = den * sc;
    double ua = lm__sel(r2, ns - ds, 2.0 * ns - ds), ub = lm__sel(r2, ns + ds, 2.0 * ds + ns);
    ua = lm__sel(r1, ua, num);
    ub = lm__sel(r1, ub, den);
    double u = ua / ub;                   /* one division */
    u = lm__sel(same | zero, 0.0, u); /* atan2(+-0, +-0), atan2(+-inf, +-inf) */
    double t = u * u;
    double p = u + u * t * (f32 ? lm__poly(t, C_ATANF, N_ATANF) : lm__poly(t, C_ATAN, N_ATAN));
    double bh = lm__sel(r2, LM_PIO4_HI, lm__sel(r1, LM_ATAN_HALF_HI, 0.0));
    double bl = lm__sel(r2, LM_PIO4_LO, lm__sel(r1, LM_ATAN_HALF_LO, 0.0));
    /* result = m pi/4 + sg (bh + bl + p), m in 0..4 */
    double m = 0.0, sg = 1.0;
    m = lm__sel(swap, 2.0, m);
    sg = lm__sel(swap, -1.0, sg);
    int neg = copysign(1.0, x) < 0.0;
    m = lm__sel(neg, 4.0 - m, m);
    sg = lm__sel(neg, -sg, sg);
    double A = m * LM_PIO4_HI, B = sg * bh, h = A + B; /* A exact: LM_PIO4_HI ends in 3 zeros */
    double bv = h - A, err = (A - (h - bv)) + (B - bv);
    double r = h + (err + (m * LM_PIO4_LO + sg * (bl + p)));
    r = copysign(r, y);
    int nan = (x != x) | (y != y);
    return lm__sel(nan, x + y, r);
}

LM_VM double lm_atan2(double y, double x) { return lm__atan2(y, x, 0); }
LM_VM float lm_atan2f(float y, float x) { return (float)lm__atan2((double)y, (double)x, 1); }

/* ---- exp, expm1 ----------------------------------------------------------------------------- */

/* x = k ln2 + (hi - lo) with |hi - lo| <= ~ln2/2; returns k */
LM_VM double lm__reduce_ln2(double x, double *hi, double *lo) {
    double k = lm__round(x * LM_INV_LN2);
    *hi = x - k * LM_LN2_HI; /* exact: |k| <= 2^11, LM_LN2_HI has 42 bits */
    *lo = k * LM_LN2_LO;
    return k;
}

LM_VM double lm__exp(double x, int f32) {
    double xc = lm__clamp(x, -746.0, 710.0);
    double hi, lo, k = lm__reduce_ln2(xc, &hi, &lo);
    double r = hi - lo;
    double q = r * r * (0.5 + r * (f32 ? lm__poly(r, C_EXPM1F, N_EXPM1F)
                                         : lm__poly(r, C_EXPM1, N_EXPM1)));
    double p = 1.0 + (hi + (q - lo)); /* e^r */
    double k1 = lm__round(0.5 * k);         /* 2^k = 2^k1 2^(k - k1), each factor normal */
    return (p * lm__pow2(k1)) * lm__pow2(k - k1);
}

LM_VM double lm__expm1(double x, int f32) {
    double xc = lm__clamp(x, -40.0, 710.0);
    double hi, lo, k = lm__reduce_ln2(xc, &hi, &lo);
    double r = hi - lo;
    double q = r * r * (0.5 + r * (f32 ? lm__poly(r, C_EXPM1F, N_EXPM1F)
                                         : lm__poly(r, C_EXPM1, N_EXPM1)));
    double pm = hi + (q - lo); /* e^r - 1 */
    double kk = lm__sel(k > 60.0, 60.0, k), s = lm__pow2(kk);
    double mid = (s - 1.0) + s * pm; /* 2^k (1 + pm) - 1 */
    double k1 = lm__round(0.5 * k);
    double far = ((1.0 + pm) * lm__pow2(k1)) * lm__pow2(k - k1);
    int k0 = k == 0.0, kfar = k > 60.0, zero = x == 0.0;
    double res = lm__sel(kfar, far, mid);
    res = lm__sel(k0, pm, res);
    return lm__sel(zero, x, res); /* expm1(-0) = -0; NaN propagates */
}

LM_VM double lm_exp(double x) { return lm__exp(x, 0); }
LM_VM double lm_expm1(double x) { return lm__expm1(x, 0); }
LM_VM float lm_expf(float x) { return (float)lm__exp((double)x, 1); }
LM_VM float lm_expm1f(float x) { return (float)lm__expm1((double)x, 1); }

/* ---- log ------------------------------------------------------------------------------------ */

LM_VM double lm__log(double x, int f32) {
    int sub = x < 0x1p-1022;
    double xs = x * lm__sel(sub, 0x1p54, 1.0);
    uint64_t u = lm__bits(xs);
    double ex = lm__dbl(0x4330000000000000ULL | ((u >> 52) & 0x7ff)) - 0x1p52;
    double k = ex - lm__sel(sub, 1023.0 + 54.0, 1023.0);
    double m = lm__dbl((u & 0x000fffffffffffffULL) | 0x3ff0000000000000ULL); /* [1, 2) */
    int hi = m > LM_SQRT2;
    m = m * lm__sel(hi, 0.5, 1.0);
    k = k + lm__sel(hi, 1.0, 0.0);
    double f = m - 1.0, s = f / (2.0 + f), z = s * s, hfsq = 0.5 * f * f;
    double R = z * (f32 ? lm__poly(z, C_LOGF, N_LOGF) : lm__poly(z, C_LOG, N_LOG));
    double v = k * LM_LN2_HI - ((hfsq - (s * (hfsq + R) + k * LM_LN2_LO)) - f);
    int zero = x == 0.0, neg = x < 0.0, fin = (x > 0.0) & (x < INFINITY);
    double special = lm__sel(neg, NAN, x); /* inf, NaN: x */
    special = lm__sel(zero, -INFINITY, special);
    return lm__sel(fin, v, special);
}

LM_VM double lm_log(double x) { return lm__log(x, 0); }
LM_VM float lm_logf(float x) { return (float)lm__log((double)x, 1); }

#endif /* LM_USE_LIBM */
