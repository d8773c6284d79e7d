#include "machine.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <ctime>
#include <limits>
#include <stdexcept>
#include <string>
#include <thread>

#if defined(__linux__)
#include <sched.h>
#endif

#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#define IWR_BENCH_X86 1
#include <immintrin.h>
#else
#define IWR_BENCH_X86 0
#endif

namespace iwr::bench {

namespace {

// CPU time of the calling thread where POSIX has it: other processes sharing the core then do not
// count (they do with wall time).
double now() {
#if defined(CLOCK_THREAD_CPUTIME_ID)
    timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
#else
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
#endif
}

#if IWR_BENCH_X86
// 16 independent chains (8 of multiplies, 8 of adds), or 12 of FMAs, unrolled 8 times: enough in
// flight to hide the latency (3-4 cycles) at two instructions per cycle. GCC/Clang vector operators
// on the intrinsic types compile to single instructions of the enclosing function's target.
// Every chain starts from a different value, or the compiler would merge identical chains.
#define IWR_MUL_ADD_CHAINS(R, one, tiny)                                                       \
    R m0 = one, m1 = m0 + one, m2 = m1 + one, m3 = m2 + one, m4 = m3 + one, m5 = m4 + one;     \
    R m6 = m5 + one, m7 = m6 + one, a0 = m7 + one, a1 = a0 + one, a2 = a1 + one;               \
    R a3 = a2 + one, a4 = a3 + one, a5 = a4 + one, a6 = a5 + one, a7 = a6 + one;               \
    for (long i = 0; i < reps; ++i) {                                                          \
        for (int u = 0; u < 8; ++u) {                                                          \
            m0 *= one, m1 *= one, m2 *= one, m3 *= one, m4 *= one, m5 *= one, m6 *= one;       \
            m7 *= one, a0 += tiny, a1 += tiny, a2 += tiny, a3 += tiny, a4 += tiny, a5 += tiny; \
            a6 += tiny, a7 += tiny;                                                            \
        }                                                                                      \
    }                                                                                          \
    const R s = ((m0 + m1) + (m2 + m3)) + ((m4 + m5) + (m6 + m7)) + ((a0 + a1) + (a2 + a3)) +  \
                ((a4 + a5) + (a6 + a7));                                                       \
    return s[0];

#define IWR_FMA_CHAINS(R, FMA, one, tiny)                                                          \
    R f0 = one, f1 = f0 + one, f2 = f1 + one, f3 = f2 + one, f4 = f3 + one, f5 = f4 + one;         \
    R f6 = f5 + one, f7 = f6 + one, f8 = f7 + one, f9 = f8 + one, f10 = f9 + one, f11 = f10 + one; \
    for (long i = 0; i < reps; ++i) {                                                              \
        for (int u = 0; u < 8; ++u) {                                                              \
            f0 = FMA(f0, one, tiny), f1 = FMA(f1, one, tiny), f2 = FMA(f2, one, tiny);             \
            f3 = FMA(f3, one, tiny), f4 = FMA(f4, one, tiny), f5 = FMA(f5, one, tiny);             \
            f6 = FMA(f6, one, tiny), f7 = FMA(f7, one, tiny), f8 = FMA(f8, one, tiny);             \
            f9 = FMA(f9, one, tiny), f10 = FMA(f10, one, tiny), f11 = FMA(f11, one, tiny);         \
        }                                                                                          \
    }                                                                                              \
    const R s = ((f0 + f1) + (f2 + f3)) + ((f4 + f5) + (f6 + f7)) + ((f8 + f9) + (f10 + f11));     \
    return s[0];

double run_sse2(long reps, bool) {
    const __m128d one = _mm_set1_pd(1.0000001), tiny = _mm_set1_pd(1e-300);
    IWR_MUL_ADD_CHAINS(__m128d, one, tiny)
}
__attribute__((target("avx2,fma"))) double run_avx2(long reps, bool fma) {
    const __m256d one = _mm256_set1_pd(1.0000001), tiny = _mm256_set1_pd(1e-300);
    if (fma) {
        IWR_FMA_CHAINS(__m256d, _mm256_fmadd_pd, one, tiny)
    }
    IWR_MUL_ADD_CHAINS(__m256d, one, tiny)
}
__attribute__((target("avx512f"))) double run_avx512(long reps, bool fma) {
    const __m512d one = _mm512_set1_pd(1.0000001), tiny = _mm512_set1_pd(1e-300);
    if (fma) {
        IWR_FMA_CHAINS(__m512d, _mm512_fmadd_pd, one, tiny)
    }
    IWR_MUL_ADD_CHAINS(__m512d, one, tiny)
}
#endif

}  // namespace

double measure_clock_ghz(double seconds) {
#if IWR_BENCH_X86
    std::uint64_t x = 0;
    long reps = 1 << 16;
    for (;;) {
        const double t0 = now();
        for (long i = 0; i < reps; ++i)
            __asm__ volatile(
                "add $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\t"
                "add $1, %0\n\tadd $1, %0\n\tadd $1, %0\n\tadd $1, %0"
                : "+r"(x));
        const double t = now() - t0;
        if (t >= seconds) return 8.0 * static_cast<double>(reps) / t * 1e-9;
        reps *= 2;
    }
#else
    (void)seconds;
    return 0.0;
#endif
}

double measure_peak_gflops(const std::string& isa, bool fma, double seconds) {
#if IWR_BENCH_X86
    __builtin_cpu_init();
    double (*run)(long, bool) = nullptr;
    int lanes = 0;
    if (isa == "sse2" && !fma) {
        run = run_sse2, lanes = 2;
    } else if (isa == "avx2" && __builtin_cpu_supports("avx2") &&
               (!fma || __builtin_cpu_supports("fma"))) {
        run = run_avx2, lanes = 4;
    } else if (isa == "avx512" && __builtin_cpu_supports("avx512f")) {
        run = run_avx512, lanes = 8;
    }
    if (!run)
        throw std::invalid_argument("isa: '" + isa + (fma ? "' with FMA" : "'") +
                                    " is unknown or not supported by this CPU");
    // flops per rep: 8 unrolled steps of 16 multiplies/adds, or of 12 FMAs of 2 flops each
    const double per_rep = 8.0 * (fma ? 24 : 16) * lanes;
    volatile double sink = 0;
    long reps = 1 << 10;
    for (;;) {
        const double t0 = now();
        sink = sink + run(reps, fma);
        const double t = now() - t0;
        if (t >= seconds) return per_rep * static_cast<double>(reps) / t * 1e-9;
        reps *= 2;
    }
#else
    (void)isa, (void)fma, (void)seconds;
    throw std::invalid_argument("isa: peak probes exist only for x86-64");
#endif
}

namespace {

// The CPUs this thread may run on (its affinity: taskset, a container's cpuset), which
// hardware_concurrency does not see.
int usable_cpus() {
#if defined(__linux__)
    cpu_set_t set;
    CPU_ZERO(&set);
    if (sched_getaffinity(0, sizeof set, &set) == 0) return CPU_COUNT(&set);
#endif
    return static_cast<int>(std::thread::hardware_concurrency());
}

// The probe's two threads on two distinct CPUs of the caller's set, the caller's own set put back
// when it ends: unpinned, a loaded scheduler may run both on one CPU, in turns, and the probe then
// times its time slices (10-12 ms a round trip with four busy processes on two vCPUs), not the
// cache line. Best effort: where affinity cannot be set, the threads stay where they are.
class Pinning {
public:
    Pinning() {
#if defined(__linux__)
        CPU_ZERO(&saved_);
        if (sched_getaffinity(0, sizeof saved_, &saved_) != 0) return;
        // The caller stays on the CPU it is on (if it may), the partner takes the lowest other.
        const int here = sched_getcpu();
        for (int c = 0; c < CPU_SETSIZE && first_ < 0; ++c)
            if (CPU_ISSET(c, &saved_) && (c == here || here < 0 || !CPU_ISSET(here, &saved_)))
                first_ = c;
        for (int c = 0; c < CPU_SETSIZE && second_ < 0; ++c)
            if (CPU_ISSET(c, &saved_) && c != first_) second_ = c;
        if (first_ >= 0 && second_ >= 0) pinned_ = pin(first_);
#endif
    }
    ~Pinning() {
#if defined(__linux__)
        if (pinned_) sched_setaffinity(0, sizeof saved_, &saved_);
#endif
    }
    Pinning(const Pinning&) = delete;
    Pinning& operator=(const Pinning&) = delete;
    /// For the partner thread, on its own start.
    void pin_partner() const {
#if defined(__linux__)
        if (pinned_) pin(second_);
#endif
    }

private:
#if defined(__linux__)
    static bool pin(int cpu) {
        cpu_set_t one;
        CPU_ZERO(&one);
        CPU_SET(cpu, &one);
        return sched_setaffinity(0, sizeof one, &one) == 0;
    }
    cpu_set_t saved_;
    int first_ = -1, second_ = -1;
#endif
    bool pinned_ = false;
};

}  // namespace

double measure_core_round_trip_ns(double seconds) {
    constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
    if (!(seconds >= 0 && seconds <= 3600))
        throw std::invalid_argument("seconds: " + std::to_string(seconds) +
                                    "; expected 0 to 3600");
    if (usable_cpus() < 2) return kNaN;
    using Clock = std::chrono::steady_clock;
    constexpr long kBatch = 256;
    // The counter alone on its cache line: odd values the caller's, even ones the answers
    // (a plain load and store each way, as the pool's hand-overs and DE's rows). The end is a
    // flag on a line of its own (read from L1 until it is set): a partner paused between its
    // load and its store past the caller's give-up then stores an answer nobody reads, and
    // still stops.
    struct alignas(64) Line {
        std::atomic<long> v{0};
    } line;
    struct alignas(64) Flag {
        std::atomic<bool> on{false};
    } stop;
    const Pinning pinning;
    std::thread partner([&line, &stop, &pinning] {
        pinning.pin_partner();
        long seen = 0;
        while (!stop.on.load(std::memory_order_relaxed)) {
            const long v = line.v.load(std::memory_order_acquire);
            if (v != seen && v % 2 == 1) {
                line.v.store(v + 1, std::memory_order_release);
                seen = v + 1;
            }
        }
    });
    double best = kNaN;
    long v = 0;
    bool answered = true;
    bool warm = false;  // the first batch (the partner starting) is not timed
    const auto t_end = Clock::now() + std::chrono::duration<double>(seconds);
    while (answered) {
        const auto t0 = Clock::now();
        for (long i = 0; i < kBatch && answered; ++i) {
            line.v.store(++v, std::memory_order_release);
            ++v;
            // A second without an answer to this round trip: the partner has no core. The clock
            // is read only after 2^20 polls (a millisecond or more), not on the timed path; a
            // loaded machine that answers late, but answers, is waited for.
            long polls = 0;
            Clock::time_point waiting{};
            while (line.v.load(std::memory_order_acquire) != v) {
                if ((++polls & ((1L << 20) - 1)) != 0) continue;
                const auto now = Clock::now();
                if (polls == (1L << 20)) {
                    waiting = now;
                } else if (now - waiting > std::chrono::seconds(1)) {
                    answered = false;
                    break;
                }
            }
        }
        if (!answered) break;
        const auto t1 = Clock::now();
        const double ns = std::chrono::duration<double, std::nano>(t1 - t0).count() / kBatch;
        if (warm) best = std::isnan(best) ? ns : std::min(best, ns);
        if (warm && t1 >= t_end) break;
        warm = true;
    }
    stop.on.store(true, std::memory_order_relaxed);
    partner.join();
    return answered ? best : kNaN;
}

}  // namespace iwr::bench
