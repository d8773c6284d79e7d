// The pose loop of eq. (8)-(10): for blocks of 8 poses, the carriage transform 0T4, the platform
// pose in frame {4}, the six leg lengths and the squared residuals. See objective_kernel.hpp.
//
// One body (objective_kernel_body.inl) is compiled for several instruction sets: x86-64's baseline
// SSE2 (any x86-64 CPU), AVX2 and AVX-512 (in target regions, selected at run time from CPUID), or
// portable scalar code elsewhere. Explicit SIMD registers rather than auto-vectorisation: GCC's
// vectoriser picked narrower vectors than the target allows for the leg loop and was ~25% slower.
// The variants are bit-identical: each performs the same IEEE operations, lane by lane, in the same
// order; -ffp-contract=off (CMakeLists.txt) keeps the compiler from fusing a*b+c into FMAs (which
// would round differently from the non-FMA baseline); sqrt is correctly rounded everywhere.
#include "objective_kernel.hpp"

#include <atomic>
#include <cmath>
#include <stdexcept>

#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#define IWR_X86_DISPATCH 1
#include <immintrin.h>
#else
#define IWR_X86_DISPATCH 0
#endif

#if defined(__GNUC__) || defined(__clang__)
#define IWR_FORCE_INLINE __attribute__((always_inline)) inline
#else
#define IWR_FORCE_INLINE inline
#endif

namespace iwr::detail {

namespace {

#if IWR_X86_DISPATCH

namespace sse2 {  // the x86-64 baseline: every x86-64 CPU has SSE2
using R = __m128d;
constexpr int K = 4;
IWR_FORCE_INLINE R r_splat(double x) { return _mm_set1_pd(x); }
IWR_FORCE_INLINE R r_load(const double* p) { return _mm_load_pd(p); }
IWR_FORCE_INLINE void r_store(double* p, R a) { _mm_store_pd(p, a); }
IWR_FORCE_INLINE R r_add(R a, R b) { return _mm_add_pd(a, b); }
IWR_FORCE_INLINE R r_sub(R a, R b) { return _mm_sub_pd(a, b); }
IWR_FORCE_INLINE R r_mul(R a, R b) { return _mm_mul_pd(a, b); }
IWR_FORCE_INLINE R r_sqrt(R a) { return _mm_sqrt_pd(a); }
#include "objective_kernel_body.inl"
}  // namespace sse2

#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx2"))), apply_to = function)
#else
#pragma GCC push_options
#pragma GCC target("avx2")
#endif
namespace avx2 {
using R = __m256d;
constexpr int K = 2;
IWR_FORCE_INLINE R r_splat(double x) { return _mm256_set1_pd(x); }
IWR_FORCE_INLINE R r_load(const double* p) { return _mm256_load_pd(p); }
IWR_FORCE_INLINE void r_store(double* p, R a) { _mm256_store_pd(p, a); }
IWR_FORCE_INLINE R r_add(R a, R b) { return _mm256_add_pd(a, b); }
IWR_FORCE_INLINE R r_sub(R a, R b) { return _mm256_sub_pd(a, b); }
IWR_FORCE_INLINE R r_mul(R a, R b) { return _mm256_mul_pd(a, b); }
IWR_FORCE_INLINE R r_sqrt(R a) { return _mm256_sqrt_pd(a); }
#include "objective_kernel_body.inl"
}  // namespace avx2
#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC pop_options
#endif

#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx512f"))), apply_to = function)
#else
#pragma GCC push_options
#pragma GCC target("avx512f")
#pragma GCC diagnostic push
// GCC 12 warns inside its own _mm512_sqrt_pd (an intentionally undefined pass-through operand).
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif
namespace avx512 {
using R = __m512d;
constexpr int K = 1;
IWR_FORCE_INLINE R r_splat(double x) { return _mm512_set1_pd(x); }
IWR_FORCE_INLINE R r_load(const double* p) { return _mm512_load_pd(p); }
IWR_FORCE_INLINE void r_store(double* p, R a) { _mm512_store_pd(p, a); }
IWR_FORCE_INLINE R r_add(R a, R b) { return _mm512_add_pd(a, b); }
IWR_FORCE_INLINE R r_sub(R a, R b) { return _mm512_sub_pd(a, b); }
IWR_FORCE_INLINE R r_mul(R a, R b) { return _mm512_mul_pd(a, b); }
IWR_FORCE_INLINE R r_sqrt(R a) { return _mm512_sqrt_pd(a); }
#include "objective_kernel_body.inl"
}  // namespace avx512
#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC diagnostic pop
#pragma GCC pop_options
#endif

#else  // portable scalar code; the compiler may vectorise it for its default target

namespace portable {
using R = double;
constexpr int K = 8;
inline R r_splat(double x) { return x; }
inline R r_load(const double* p) { return *p; }
inline void r_store(double* p, R a) { *p = a; }
inline R r_add(R a, R b) { return a + b; }
inline R r_sub(R a, R b) { return a - b; }
inline R r_mul(R a, R b) { return a * b; }
inline R r_sqrt(R a) { return std::sqrt(a); }
#include "objective_kernel_body.inl"
}  // namespace portable

#endif

struct Variant {
    const char* name;
    KernelFn fn;
    bool (*supported)();
};

bool always() { return true; }
#if IWR_X86_DISPATCH
bool has_avx2() {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2");
}
bool has_avx512() {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f");
}
#endif

const Variant kVariants[] = {
#if IWR_X86_DISPATCH
    {"baseline", sse2::kernel, always},
    {"avx2", avx2::kernel, has_avx2},
    {"avx512", avx512::kernel, has_avx512},
#else
    {"baseline", portable::kernel, always},
#endif
};
constexpr int kNumVariants = static_cast<int>(sizeof(kVariants) / sizeof(kVariants[0]));

int best_variant() {
    for (int i = kNumVariants - 1; i > 0; --i)
        if (kVariants[i].supported()) return i;
    return 0;
}

std::atomic<int>& active_index() {
    static std::atomic<int> index{best_variant()};
    return index;
}

}  // namespace

KernelFn active_kernel() { return kVariants[active_index().load(std::memory_order_relaxed)].fn; }

const char* active_kernel_name() {
    return kVariants[active_index().load(std::memory_order_relaxed)].name;
}

std::vector<std::string> supported_kernels() {
    std::vector<std::string> out;
    for (const Variant& v : kVariants)
        if (v.supported()) out.emplace_back(v.name);
    return out;
}

void select_kernel(const std::string& name) {
    for (int i = 0; i < kNumVariants; ++i) {
        if (name == kVariants[i].name) {
            if (!kVariants[i].supported())
                throw std::invalid_argument("kernel: '" + name + "' is not supported by this CPU");
            active_index().store(i, std::memory_order_relaxed);
            return;
        }
    }
    std::string known;
    for (const Variant& v : kVariants) known += std::string(known.empty() ? "" : ", ") + v.name;
    throw std::invalid_argument("kernel: '" + name + "' is unknown; compiled variants: " + known);
}

}  // namespace iwr::detail
