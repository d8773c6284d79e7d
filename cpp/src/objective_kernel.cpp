// The pose loop of eq. (8)-(10): for blocks of 8 poses, the carriage transform 0T4, the platform
// pose in frame {4}, the six leg lengths and the squared residuals. See objective_kernel.hpp.
//
// One body (objective_kernel_body.inl) is compiled for several instruction sets: x86-64's baseline
// SSE2 (any x86-64 CPU), AVX2 and AVX-512 (in target regions, selected at run time from CPUID), or
// portable scalar code elsewhere. Explicit SIMD registers rather than auto-vectorisation: GCC's
// vectoriser picked narrower vectors than the target allows for the leg loop and was ~25% slower.
// The AVX2 and AVX-512 variants are bit-identical: each performs the same IEEE operations, lane by
// lane, in the same order, with fused multiply-adds where the body says so (fma, fms: r_fma, r_fms,
// the FMA instructions; the AVX2 variant therefore requires FMA, which every AVX2 CPU has);
// -ffp-contract=off (CMakeLists.txt) keeps the compiler from fusing anything else. The SSE2 baseline
// (x86-64 CPUs without FMA, before about 2013) runs the same body with each fused operation as a
// multiply and an add: it differs from the other two at the level of rounding (a few units in the
// last place of a leg length; tests/test_objective_kernel.py measures it). sqrt is correctly rounded
// everywhere. The tracker point objective's body (tracker_kernel_body.inl) is compiled alongside.
#include "objective_kernel.hpp"

#include <atomic>
#include <cmath>
#include <limits>
#include <stdexcept>

#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#define IWR_X86_DISPATCH 1
#include <immintrin.h>
#else
#define IWR_X86_DISPATCH 0
#endif

#include "inline.hpp"

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
IWR_FORCE_INLINE R r_div(R a, R b) { return _mm_div_pd(a, b); }
// a * b + c, a * b - c: the baseline has no FMA instruction, so a multiply then an add, rounded
// twice (glibc's correctly rounded fma() lane by lane would be 10-20x slower); the AVX2 and AVX-512
// variants fuse them, so this variant differs from those at the level of rounding.
IWR_FORCE_INLINE R r_fma(R a, R b, R c) { return _mm_add_pd(_mm_mul_pd(a, b), c); }
IWR_FORCE_INLINE R r_fms(R a, R b, R c) { return _mm_sub_pd(_mm_mul_pd(a, b), c); }
constexpr bool kFused = false;
// Lane masks (the tracker kernel): all ones or all zeros per lane.
using M = __m128d;
IWR_FORCE_INLINE M m_le(R a, R b) { return _mm_cmple_pd(a, b); }
IWR_FORCE_INLINE M m_lt(R a, R b) { return _mm_cmplt_pd(a, b); }
IWR_FORCE_INLINE M m_and(M a, M b) { return _mm_and_pd(a, b); }
IWR_FORCE_INLINE M m_andnot(M a, M b) { return _mm_andnot_pd(b, a); }  // a and not b
IWR_FORCE_INLINE M m_or(M a, M b) { return _mm_or_pd(a, b); }
IWR_FORCE_INLINE M m_all(bool on) { return _mm_castsi128_pd(_mm_set1_epi64x(on ? -1 : 0)); }
IWR_FORCE_INLINE int m_bits(M a) { return _mm_movemask_pd(a); }
IWR_FORCE_INLINE R m_select(M m, R a, R b) { return _mm_or_pd(_mm_and_pd(m, a), _mm_andnot_pd(m, b)); }
IWR_FORCE_INLINE R m_keep(M m, R a) { return _mm_and_pd(m, a); }  // a where m, +0 elsewhere
constexpr bool kRereadConsts = false;  // the leg kernel's constants read in every block
constexpr bool kLegPipe = false;  // the leg kernel software-pipelined
#include "objective_kernel_body.inl"
constexpr bool kChordPair = false;  // tracker_chord2: two blocks at once
#include "tracker_kernel_body.inl"
}  // namespace sse2

#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx2,fma"))), apply_to = function)
#else
#pragma GCC push_options
#pragma GCC target("avx2,fma")
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
IWR_FORCE_INLINE R r_div(R a, R b) { return _mm256_div_pd(a, b); }
IWR_FORCE_INLINE R r_fma(R a, R b, R c) { return _mm256_fmadd_pd(a, b, c); }
IWR_FORCE_INLINE R r_fms(R a, R b, R c) { return _mm256_fmsub_pd(a, b, c); }
constexpr bool kFused = true;
using M = __m256d;
IWR_FORCE_INLINE M m_le(R a, R b) { return _mm256_cmp_pd(a, b, _CMP_LE_OQ); }
IWR_FORCE_INLINE M m_lt(R a, R b) { return _mm256_cmp_pd(a, b, _CMP_LT_OQ); }
IWR_FORCE_INLINE M m_and(M a, M b) { return _mm256_and_pd(a, b); }
IWR_FORCE_INLINE M m_andnot(M a, M b) { return _mm256_andnot_pd(b, a); }
IWR_FORCE_INLINE M m_or(M a, M b) { return _mm256_or_pd(a, b); }
IWR_FORCE_INLINE M m_all(bool on) { return _mm256_castsi256_pd(_mm256_set1_epi64x(on ? -1 : 0)); }
IWR_FORCE_INLINE int m_bits(M a) { return _mm256_movemask_pd(a); }
IWR_FORCE_INLINE R m_select(M m, R a, R b) { return _mm256_blendv_pd(b, a, m); }
IWR_FORCE_INLINE R m_keep(M m, R a) { return _mm256_and_pd(m, a); }
// Not re-read: 3 % slower with 16 registers (18 % with SSE2; BENCHMARKS.md, "Eleventh round").
constexpr bool kRereadConsts = false;  // the leg kernel's constants read in every block
constexpr bool kLegPipe = false;  // the leg kernel software-pipelined
#include "objective_kernel_body.inl"
// Not two blocks at once: four registers a value spill, 20 % slower (BENCHMARKS.md, "Tenth round").
constexpr bool kChordPair = false;  // tracker_chord2: two blocks at once
#include "tracker_kernel_body.inl"
}  // namespace avx2
#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC pop_options
#endif

#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx512f,avx2,fma"))), apply_to = function)
#else
#pragma GCC push_options
// avx2 and fma too (every AVX-512 CPU has them): half_pass inlines the AVX2 variant's pass.
#pragma GCC target("avx512f,avx2,fma")
#pragma GCC diagnostic push
// GCC 12 warns inside its own _mm512_sqrt_pd and _mm512_cmp_pd_mask (an intentionally undefined
// pass-through operand).
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#pragma GCC diagnostic ignored "-Wuninitialized"
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
IWR_FORCE_INLINE R r_div(R a, R b) { return _mm512_div_pd(a, b); }
IWR_FORCE_INLINE R r_fma(R a, R b, R c) { return _mm512_fmadd_pd(a, b, c); }
IWR_FORCE_INLINE R r_fms(R a, R b, R c) { return _mm512_fmsub_pd(a, b, c); }
constexpr bool kFused = true;
using M = __mmask8;
IWR_FORCE_INLINE M m_le(R a, R b) { return _mm512_cmp_pd_mask(a, b, _CMP_LE_OQ); }
IWR_FORCE_INLINE M m_lt(R a, R b) { return _mm512_cmp_pd_mask(a, b, _CMP_LT_OQ); }
IWR_FORCE_INLINE M m_and(M a, M b) { return static_cast<M>(a & b); }
IWR_FORCE_INLINE M m_andnot(M a, M b) { return static_cast<M>(a & ~b); }
IWR_FORCE_INLINE M m_or(M a, M b) { return static_cast<M>(a | b); }
IWR_FORCE_INLINE M m_all(bool on) { return static_cast<M>(on ? 0xff : 0); }
IWR_FORCE_INLINE int m_bits(M a) { return a; }
IWR_FORCE_INLINE R m_select(M m, R a, R b) { return _mm512_mask_blend_pd(m, b, a); }
IWR_FORCE_INLINE R m_keep(M m, R a) { return _mm512_maskz_mov_pd(m, a); }
// A last block of at most 4 poses runs as the AVX2 variant's 4-lane pass (objective_kernel_body.inl).
#define IWR_HALF_PASS avx2
// Re-read: GCC hoisted them into 40-odd zmm copies on the stack at every call (the weighted
// objective 6-10 % faster without); pipelined: the whitened one 3-5 % faster (BENCHMARKS.md,
// "Eleventh round").
constexpr bool kRereadConsts = true;  // the leg kernel's constants read in every block
constexpr bool kLegPipe = true;  // the leg kernel software-pipelined
#include "objective_kernel_body.inl"
#undef IWR_HALF_PASS
constexpr bool kChordPair = true;  // tracker_chord2: two blocks at once (2-4 % faster)
#include "tracker_kernel_body.inl"
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
inline R r_div(R a, R b) { return a / b; }
inline R r_fma(R a, R b, R c) { return std::fma(a, b, c); }
inline R r_fms(R a, R b, R c) { return std::fma(a, b, -c); }
constexpr bool kFused = true;
using M = bool;
inline M m_le(R a, R b) { return a <= b; }
inline M m_lt(R a, R b) { return a < b; }
inline M m_and(M a, M b) { return a && b; }
inline M m_andnot(M a, M b) { return a && !b; }
inline M m_or(M a, M b) { return a || b; }
inline M m_all(bool on) { return on; }
inline int m_bits(M a) { return a ? 1 : 0; }
inline R m_select(M m, R a, R b) { return m ? a : b; }
inline R m_keep(M m, R a) { return m ? a : 0.0; }
constexpr bool kRereadConsts = false;  // the leg kernel's constants read in every block
constexpr bool kLegPipe = false;  // the leg kernel software-pipelined
#include "objective_kernel_body.inl"
constexpr bool kChordPair = false;  // tracker_chord2: two blocks at once
#include "tracker_kernel_body.inl"
}  // namespace portable

#endif

struct Variant {
    const char* name;
    KernelFn fn;
    TrackerKernels tracker;
    bool (*supported)();
};

bool always() { return true; }
#if IWR_X86_DISPATCH
bool has_avx2() {  // and FMA, which every AVX2 CPU has (Intel Haswell, AMD Excavator and later)
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}
bool has_avx512() {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") && has_avx2();
}
#endif

const Variant kVariants[] = {
#if IWR_X86_DISPATCH
    {"baseline", sse2::kernel, {sse2::tracker_chord, sse2::chord_pair, sse2::tracker_chord_lanes, sse2::tracker_points}, always},
    {"avx2", avx2::kernel, {avx2::tracker_chord, avx2::chord_pair, avx2::tracker_chord_lanes, avx2::tracker_points}, has_avx2},
    {"avx512", avx512::kernel, {avx512::tracker_chord, avx512::chord_pair, avx512::tracker_chord_lanes, avx512::tracker_points}, has_avx512},
#else
    {"baseline", portable::kernel, {portable::tracker_chord, portable::chord_pair, portable::tracker_chord_lanes, portable::tracker_points}, always},
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

TrackerKernels active_tracker_kernels() {
    return kVariants[active_index().load(std::memory_order_relaxed)].tracker;
}

const char* active_kernel_name() {
    return kVariants[active_index().load(std::memory_order_relaxed)].name;
}

std::vector<std::string> compiled_kernels() {
    std::vector<std::string> out;
    for (const Variant& v : kVariants) out.emplace_back(v.name);
    return out;
}

std::vector<std::string> supported_kernels() {
    std::vector<std::string> out;
    for (const Variant& v : kVariants)
        if (v.supported()) out.emplace_back(v.name);
    return out;
}

namespace {
template <int N>  // lanes l0..l0 + N (a fixed count: each quantity one broadcast and a store)
void set_lanes(LaneConsts& lc, const TrackerConsts& tc, int l0) {
    auto put = [&](int q, double x) {
        double* o = lc.v + q * kBlock + l0;
        for (int l = 0; l < N; ++l) o[l] = x;
    };
    for (int j = 0; j < 6; ++j) {
        for (int c = 0; c < 3; ++c)
            put(LaneConsts::kA + 3 * j + c, tc.ec.a[j][c]), put(LaneConsts::kB + 3 * j + c, tc.ec.b[j][c]);
        put(LaneConsts::kL0 + j, tc.ec.l0[j]);
    }
}
}  // namespace

void LaneConsts::set(const TrackerConsts& tc, int l0, int l1) {
    if (l1 - l0 == kBlock)
        set_lanes<kBlock>(*this, tc, l0);
    else if (l1 - l0 == kBlock / 2)
        set_lanes<kBlock / 2>(*this, tc, l0);
    else
        for (int l = l0; l < l1; ++l) set_lanes<1>(*this, tc, l);
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
