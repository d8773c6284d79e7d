// The pose loop of eq. (8)-(10): for a block of kBlock poses, the carriage transform 0T4, the platform
// pose in frame {4}, the six leg lengths and the squared residuals. See objective_kernel.hpp.
//
// Compiled with -fno-math-errno (so that sqrt vectorises) and -ffp-contract=off (so that no variant
// fuses a*b+c into an FMA: the variants then round identically, lane by lane). The loops over the
// kBlock lanes of a block have a fixed trip count and no branches; GCC and Clang vectorise them for
// whatever vector width the enclosing function's target allows.
#include "objective_kernel.hpp"

#include <atomic>
#include <cmath>
#include <stdexcept>

#if (defined(__GNUC__) || defined(__clang__)) && (defined(__x86_64__) || defined(__i386__))
#define IWR_X86_DISPATCH 1
#define IWR_FORCE_INLINE __attribute__((always_inline)) inline
#define IWR_TARGET(t) __attribute__((target(t)))
#else
#define IWR_X86_DISPATCH 0
#define IWR_FORCE_INLINE inline
#define IWR_TARGET(t)
#endif

namespace iwr::detail {

namespace {

constexpr int B = kBlock;
static_assert(B == 8, "the final reduction below sums eight lanes");

// One block: 0T4 by the DH chain (eq. 1-2), then M = 4R0 0R5 and w = 4R0 (0P5 - 0P4), i.e. the
// platform pose in frame {4}; leg j is then v = M b_j + w - a_j (eq. 8 expressed in {4}), its length
// |v|, and the residual sqrt(w_kj) (|v| - l0_j - s_kj). Returns the per-lane sums of squares in acc.
template <bool Weighted, bool Residuals>
IWR_FORCE_INLINE void block(const PoseData& pd, const EvalConsts& ec, const double* blk,
                            double (&acc)[B], double (&res)[6][B]) {
    // --- carriage: the prismatic prefix (same rotation at every pose), then joint by joint --------
    double t[12][B];  // 0T4: rotation row-major (0..8), position (9..11)
    for (int e = 0; e < 9; ++e)
        for (int l = 0; l < B; ++l) t[e][l] = ec.rc[e];
    for (int r = 0; r < 3; ++r)
        for (int l = 0; l < B; ++l) t[9 + r][l] = ec.pc[r];
    for (int i = 0; i < pd.n_prefix; ++i) {
        const double* q = blk + pd.q_off[i] * B;
        const double* z = ec.z + 3 * i;
        for (int r = 0; r < 3; ++r)
            for (int l = 0; l < B; ++l) t[9 + r][l] += q[l] * z[r];
    }
    for (int i = pd.n_prefix; i < pd.n_joints; ++i) {
        const double* jc = ec.joint + 6 * i;
        const double ca = jc[0], sa = jc[1], ct = jc[2], st = jc[3], a = jc[4], d = jc[5];
        const double* q = blk + pd.q_off[i] * B;
        double c[B], s[B], dk[B];
        if (pd.prismatic[i]) {
            for (int l = 0; l < B; ++l) c[l] = ct, s[l] = st, dk[l] = d + q[l];
        } else {
            // angle-sum identity on the per-data-set cos q, sin q
            for (int l = 0; l < B; ++l) {
                c[l] = ct * q[l] - st * q[B + l];
                s[l] = st * q[l] + ct * q[B + l];
                dk[l] = d;
            }
        }
        // T <- T A_i row by row: u = T0 c + T1 s, v = T1 c - T0 s; new row (u, ca v + sa T2,
        // ca T2 - sa v); the position gains a u + d_k T2.
        for (int r = 0; r < 3; ++r) {
            double* row0 = t[3 * r];
            double* row1 = t[3 * r + 1];
            double* row2 = t[3 * r + 2];
            double* pos = t[9 + r];
            for (int l = 0; l < B; ++l) {
                const double u = row0[l] * c[l] + row1[l] * s[l];
                const double v = row1[l] * c[l] - row0[l] * s[l];
                const double w = row2[l];
                row0[l] = u;
                row1[l] = ca * v + sa * w;
                row2[l] = ca * w - sa * v;
                pos[l] += a * u + dk[l] * w;
            }
        }
    }

    // --- platform pose in {4}: M = R4^T R5, w = R4^T (p5 - p4) -------------------------------------
    const double* r5 = blk + pd.off_r5 * B;
    const double* p5 = blk + pd.off_p5 * B;
    double m[12][B];
    for (int l = 0; l < B; ++l) {
        const double d0 = p5[l] - t[9][l], d1 = p5[B + l] - t[10][l], d2 = p5[2 * B + l] - t[11][l];
        for (int r = 0; r < 3; ++r) {
            const double c0 = t[r][l], c1 = t[3 + r][l], c2 = t[6 + r][l];  // column r of R4
            m[3 * r + 0][l] = c0 * r5[l] + c1 * r5[3 * B + l] + c2 * r5[6 * B + l];
            m[3 * r + 1][l] = c0 * r5[B + l] + c1 * r5[4 * B + l] + c2 * r5[7 * B + l];
            m[3 * r + 2][l] = c0 * r5[2 * B + l] + c1 * r5[5 * B + l] + c2 * r5[8 * B + l];
            m[9 + r][l] = c0 * d0 + c1 * d1 + c2 * d2;
        }
    }

    // --- the six legs --------------------------------------------------------------------------------
    for (int l = 0; l < B; ++l) acc[l] = 0.0;
    for (int j = 0; j < 6; ++j) {
        const double b0 = ec.b[j][0], b1 = ec.b[j][1], b2 = ec.b[j][2];
        const double a0 = ec.a[j][0], a1 = ec.a[j][1], a2 = ec.a[j][2];
        const double l0 = ec.l0[j];
        const double* s = blk + (pd.off_s + j) * B;
        const double* sw = blk + (Weighted ? pd.off_w + j : 0) * B;
        for (int l = 0; l < B; ++l) {
            const double vx = (m[0][l] * b0 + m[1][l] * b1 + m[2][l] * b2) + (m[9][l] - a0);
            const double vy = (m[3][l] * b0 + m[4][l] * b1 + m[5][l] * b2) + (m[10][l] - a1);
            const double vz = (m[6][l] * b0 + m[7][l] * b1 + m[8][l] * b2) + (m[11][l] - a2);
            double r = (std::sqrt(vx * vx + vy * vy + vz * vz) - l0) - s[l];
            if (Weighted) r *= sw[l];
            if (Residuals) res[j][l] = r;
            acc[l] += r * r;
        }
    }
}

template <bool Weighted, bool Residuals>
IWR_FORCE_INLINE double run(const PoseData& pd, const EvalConsts& ec, double* out) {
    // Per-lane partial sums: pose k goes to lane k mod 8 whatever the SIMD width, so the summation
    // order (and the result) is the same for every variant.
    double lanes[B] = {0, 0, 0, 0, 0, 0, 0, 0};
    double acc[B], res[6][B];
    for (int b = 0; b < pd.n_blocks; ++b) {
        const double* blk = pd.data + static_cast<long>(b) * pd.stride;
        block<Weighted, Residuals>(pd, ec, blk, acc, res);
        const int valid = pd.n - b * B < B ? pd.n - b * B : B;  // the last block is padded
        for (int l = 0; l < B; ++l) lanes[l] += l < valid ? acc[l] : 0.0;
        if (Residuals) {
            for (int l = 0; l < valid; ++l)
                for (int j = 0; j < 6; ++j) out[(static_cast<long>(b) * B + l) * 6 + j] = res[j][l];
        }
    }
    return ((lanes[0] + lanes[4]) + (lanes[1] + lanes[5])) +
           ((lanes[2] + lanes[6]) + (lanes[3] + lanes[7]));
}

IWR_FORCE_INLINE double run_any(const PoseData& pd, const EvalConsts& ec, double* out) {
    if (pd.off_w >= 0) return out ? run<true, true>(pd, ec, out) : run<true, false>(pd, ec, out);
    return out ? run<false, true>(pd, ec, out) : run<false, false>(pd, ec, out);
}

double kernel_baseline(const PoseData& pd, const EvalConsts& ec, double* out) {
    return run_any(pd, ec, out);
}

#if IWR_X86_DISPATCH
IWR_TARGET("avx2")
double kernel_avx2(const PoseData& pd, const EvalConsts& ec, double* out) {
    return run_any(pd, ec, out);
}

IWR_TARGET("avx512f,avx512dq,avx512vl,avx512bw,prefer-vector-width=512")
double kernel_avx512(const PoseData& pd, const EvalConsts& ec, double* out) {
    return run_any(pd, ec, out);
}
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
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
           __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512bw");
}
#endif

const Variant kVariants[] = {
    {"baseline", kernel_baseline, always},
#if IWR_X86_DISPATCH
    {"avx2", kernel_avx2, has_avx2},
    {"avx512", kernel_avx512, has_avx512},
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
