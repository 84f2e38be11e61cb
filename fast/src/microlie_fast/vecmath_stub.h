/* Stand-in for vecmath.h (microlie's own vectorisable elementary functions): lm_sin, lm_cos,
 * lm_tan, lm_atan2, lm_exp, lm_expm1, lm_log (double) and their f-suffixed float versions, here
 * mapped to libm. Selected by -DLM_VECMATH_STUB (setup.py does so while vecmath.h is absent).
 * With LM_LIBMVEC (Linux x86-64, glibc >= 2.35, linked with -lmvec) the libm functions are
 * declared `omp declare simd`, so that GCC vectorises loops calling them (IEEE semantics kept). */
#pragma once
#include <math.h>

#ifdef LM_LIBMVEC
#pragma omp declare simd notinbranch
extern double sin(double);
#pragma omp declare simd notinbranch
extern double cos(double);
#pragma omp declare simd notinbranch
extern double tan(double);
#pragma omp declare simd notinbranch
extern double atan2(double, double);
#pragma omp declare simd notinbranch
extern double exp(double);
#pragma omp declare simd notinbranch
extern double expm1(double);
#pragma omp declare simd notinbranch
extern double log(double);
#endif

#define LM_STUB_FN static inline __attribute__((always_inline, unused))
LM_STUB_FN double lm_sin(double x) { return sin(x); }
/* cos(x + 0.0) = cos(x) for every x (cos is even): a value other than sin's argument, so that GCC
 * does not merge sin(x) and cos(x) into one sincos call, which it cannot vectorise */
LM_STUB_FN double lm_cos(double x) { return cos(x + 0.0); }
LM_STUB_FN double lm_tan(double x) { return tan(x); }
LM_STUB_FN double lm_atan2(double y, double x) { return atan2(y, x); }
LM_STUB_FN double lm_exp(double x) { return exp(x); }
LM_STUB_FN double lm_expm1(double x) { return expm1(x); }
LM_STUB_FN double lm_log(double x) { return log(x); }
LM_STUB_FN float lm_sinf(float x) { return sinf(x); }
LM_STUB_FN float lm_cosf(float x) { return cosf(x); }
LM_STUB_FN float lm_tanf(float x) { return tanf(x); }
LM_STUB_FN float lm_atan2f(float y, float x) { return atan2f(y, x); }
LM_STUB_FN float lm_expf(float x) { return expf(x); }
LM_STUB_FN float lm_expm1f(float x) { return expm1f(x); }
LM_STUB_FN float lm_logf(float x) { return logf(x); }
