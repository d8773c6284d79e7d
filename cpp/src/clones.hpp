// Internal: IWR_CLONES, a function compiled for AVX-512 and AVX2 as well as the x86-64 baseline
// (DE's trial loop and log sums and the carriage's per-evaluation constants, tested for equal bits
// by cpp/tests/test_de_isa.cpp; the integer finiteness check of model.cpp),
// the widest the CPU runs picked when the library loads (GCC's target_clones). Separate multiplies
// and adds in every clone (-ffp-contract=off, CMakeLists.txt) and no reassociation: the same values
// whatever the instruction set, in wider registers. GCC on x86-64 glibc only (target_clones needs
// ifunc, which musl does not have); elsewhere an ordinary function.
#pragma once

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && \
    defined(__GLIBC__)
#define IWR_CLONES __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define IWR_CLONES
#endif

// One variant alone, the one a CPU of that kind runs (the test programs iwr_de_isa_*, which
// compile de.cpp and objective.cpp so: CMakeLists.txt).
#if defined(IWR_DE_ISA_AVX512F)
#undef IWR_CLONES
#define IWR_CLONES __attribute__((target("avx512f")))
#elif defined(IWR_DE_ISA_AVX2)
#undef IWR_CLONES
#define IWR_CLONES __attribute__((target("avx2")))
#elif defined(IWR_DE_ISA_BASELINE)
#undef IWR_CLONES
#define IWR_CLONES
#endif

namespace iwr {

// The vector width in doubles of the IWR_CLONES variant this CPU runs (8 AVX-512, 4 AVX2, 2 the
// baseline's SSE2): for work split into register-sized groups outside a clone (DE's log columns),
// where a group sized for the widest registers spills in narrower ones.
inline int clone_lanes() {
#if defined(IWR_DE_ISA_AVX512F)
    return 8;
#elif defined(IWR_DE_ISA_AVX2)
    return 4;
#elif defined(IWR_DE_ISA_BASELINE)
    return 2;
#elif defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__) && \
    defined(__GLIBC__)
    // The test target_clones' resolver makes (GCC's ifunc picks the clone by the same builtin).
    static const int lanes = __builtin_cpu_supports("avx512f") ? 8
                             : __builtin_cpu_supports("avx2") ? 4
                                                               : 2;
    return lanes;
#elif defined(__AVX512F__)
    return 8;
#elif defined(__AVX2__) || defined(__AVX__)
    return 4;
#else
    return 2;
#endif
}

}  // namespace iwr
