/* Runtime dispatch of the hot loops to wider vector units (issue 21).
 *
 * The extensions are compiled for a baseline ISA (x86-64-v2 on x86-64: SSE4.2, no AVX; armv8-a
 * on ARM64; see setup.py), so that one wheel runs on every CPU of its platform. LM_HOT marks a
 * hot loop: on x86-64 with GCC/Clang and an ifunc-capable C library (glibc; setup.py probes it
 * and defines LM_CLONES), the compiler emits three versions of the function (the baseline one,
 * one for x86-64-v3: AVX2 + FMA, one for x86-64-v4: AVX-512) and the dynamic loader picks the
 * widest one the CPU supports, once, when the module is loaded. Elsewhere (musl, macOS,
 * ARM64, a local -march=native build with MICROLIE_NATIVE=1) LM_HOT is empty and the baseline
 * (or native) code runs. Inline helpers called from an LM_HOT function are compiled into each
 * version. tools/check_isa.py checks that no AVX/AVX-512 instruction lies outside the clones.
 *
 * lm_cpu_level(): the version the loader chose on this CPU ("x86-64-v4", "x86-64-v3" or
 * "baseline"), by the same tests as GCC's resolver. */
#pragma once

#if defined(LM_CLONES) && defined(__x86_64__)
#define LM_HOT __attribute__((target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")))
#else
#define LM_HOT
#endif

static inline const char *lm_cpu_level(void) {
#if defined(LM_CLONES) && defined(__x86_64__)
    __builtin_cpu_init();
    if (__builtin_cpu_supports("x86-64-v4")) return "x86-64-v4";
    if (__builtin_cpu_supports("x86-64-v3")) return "x86-64-v3";
#endif
    return "baseline";
}
