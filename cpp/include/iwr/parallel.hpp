// A small persistent thread pool with static, contiguous partitioning (parallel_for) or chunks
// claimed as the threads go (parallel_for_dynamic).
//
// Work item i always runs the same code on the same data whatever the number of threads, so results
// that depend only on i are bit-identical for 1 or many threads. Nothing random lives here.
//
// Hand-over: a thread that finished its chunk (a worker waiting for the next job, the caller
// waiting for the workers) spins for up to kSpinMicroseconds before it sleeps on a condition
// variable. Waking a sleeping thread on another core costs tens of microseconds on some virtual
// machines (32-49 us measured on the development VM, benchmarks/handover.cpp), against 0.1-0.2 us
// for a spinning one, and DE hands work over twice per generation of a third of a millisecond.
// The spin yields the processor between polls, and a pool with more threads than the process may
// use CPUs does not spin at all (a spinning thread would take a core from a working one).
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

namespace iwr {

class ThreadPool {
public:
    /// threads <= 0 means all the CPUs this process may use (resolve()). Throws
    /// std::invalid_argument above max_threads(), and std::runtime_error naming the count when the
    /// system refuses a thread (a process limit): the threads already started are stopped and
    /// joined first, so nothing waits on a thread that does not exist.
    explicit ThreadPool(int threads = 0);
    ~ThreadPool();
    ThreadPool(const ThreadPool&) = delete;
    ThreadPool& operator=(const ThreadPool&) = delete;

    int size() const { return static_cast<int>(workers_.size()) + 1; }

    /// Calls fn(begin, end, worker) on contiguous chunks of [0, n), one chunk per thread; the calling
    /// thread takes chunk 0. Rethrows the first exception thrown by any chunk.
    void parallel_for(std::size_t n, const std::function<void(std::size_t, std::size_t, int)>& fn);

    /// Like parallel_for, but the threads claim chunks of [0, n) as they go, so a thread that
    /// another process slows down takes fewer items instead of holding up the others. Thread t
    /// first claims from its own share, parallel_for's chunk t (each claim half of what is left
    /// of it, at least `grain` items), then from the others' shares (the same claims). A thread
    /// so takes the same items from one call to the next unless another is held up: where a
    /// call writes what the next one reads (DE's trials, its slots' random streams), the data
    /// stays in that thread's cache instead of moving between cores (on two dies, or two CCDs of
    /// one chip, a line costs a round trip of hundreds of ns: BENCHMARKS.md, thirty-third round).
    /// fn may be called several times on one thread (disjoint ranges, each in ascending order)
    /// and the partition differs from run to run: use it only where item i's result depends on i
    /// alone.
    void parallel_for_dynamic(std::size_t n, std::size_t grain,
                              const std::function<void(std::size_t, std::size_t, int)>& fn);

    /// Resolves a user's thread count: <= 0 means all the CPUs this process may run on (its
    /// affinity mask on Linux, else std::thread::hardware_concurrency). CPU quotas (cgroup
    /// cpu.max) are not taken into account.
    static int resolve(int threads);

    /// The most threads a pool takes: max(kMinMaxThreads, kThreadsPerCpu x the CPUs this process
    /// may use). More cannot make a CPU-bound pool faster, and thousands of threads exhaust the
    /// system's process ids.
    static int max_threads();
    static constexpr int kThreadsPerCpu = 4;
    static constexpr int kMinMaxThreads = 16;

    /// A pool belongs to the process that made it: after fork() its threads do not exist in the
    /// child, so parallel_for there throws std::logic_error instead of waiting for them forever
    /// (make a new pool in the child; the Python bindings do).
    bool usable_here() const;

    /// How long a thread spins waiting for work (or for the workers) before it sleeps.
    static constexpr int kSpinMicroseconds = 100;

    /// The smallest chunk of parallel_for_dynamic that the objectives' batches use (rows).
    static constexpr std::size_t kGrain = 8;

private:
    void worker_loop(int id);
    void shutdown();

    struct Sync {
        std::mutex mutex;
        std::condition_variable start_cv, done_cv;
    };
    std::vector<std::thread> workers_;
    std::unique_ptr<Sync> sync_ = std::make_unique<Sync>();
    // Written by the caller before it publishes generation_ (release); read after (acquire).
    const std::function<void(std::size_t, std::size_t, int)>* job_ = nullptr;
    std::size_t n_ = 0;
    std::atomic<unsigned long> generation_{0};
    std::atomic<int> pending_{0};
    std::atomic<bool> stop_{false};
    bool spin_ = true;  // false when oversubscribed
    long owner_pid_ = 0;
    std::exception_ptr error_;  // guarded by sync_->mutex
};

namespace detail {
/// Whether an objective has `cost_rows(const double* const* xs, int m, double* out, Workspace&)`:
/// the costs of m parameter vectors at once, each the same as `cost` of it (an objective that
/// solves several vectors' work together, iwr::TrackerObjective).
template <class T, class = void>
struct has_cost_rows : std::false_type {};
template <class T>
struct has_cost_rows<T, std::void_t<decltype(std::declval<const T&>().cost_rows(
                            std::declval<const double* const*>(), 0, std::declval<double*>(),
                            std::declval<typename T::Workspace&>()))>> : std::true_type {};
template <class T>
inline constexpr bool has_cost_rows_v = has_cost_rows<T>::value;
/// Rows handed to cost_rows at a time.
constexpr std::size_t kCostRows = 16;

/// The costs of rows [b, e) of X (np doubles each) into out[b..e): cost_rows where the objective
/// has it, kCostRows rows at a time, else cost row by row; row(i) gives row i's parameter vector.
template <class Objective, class Row>
void row_costs(const Objective& obj, std::size_t b, std::size_t e, double* out,
               typename Objective::Workspace& ws, Row row) {
    if constexpr (has_cost_rows_v<Objective>) {
        const double* xs[kCostRows];
        for (std::size_t i = b; i < e; i += kCostRows) {
            const std::size_t n = e - i < kCostRows ? e - i : kCostRows;
            for (std::size_t k = 0; k < n; ++k) xs[k] = row(i + k, k);
            obj.cost_rows(xs, static_cast<int>(n), out + i, ws);
        }
    } else {
        for (std::size_t i = b; i < e; ++i) out[i] = obj.cost(row(i, 0), ws);
    }
}
}  // namespace detail

/// The costs of the m rows of X (each obj.n_params() long) into out, across the pool's threads,
/// one workspace per thread: a row's cost never depends on the thread or the other rows. Serves
/// every objective with `make_workspace()` and `cost(const double*, Workspace&)` (and uses its
/// `cost_rows` where it has one).
template <class Objective>
void batch_costs(const Objective& obj, const double* X, std::size_t m, double* out,
                 ThreadPool& pool) {
    std::vector<typename Objective::Workspace> ws(static_cast<std::size_t>(pool.size()));
    for (auto& w : ws) w = obj.make_workspace();
    const std::size_t np = static_cast<std::size_t>(obj.n_params());
    pool.parallel_for_dynamic(m, ThreadPool::kGrain, [&](std::size_t b, std::size_t e, int id) {
        detail::row_costs(obj, b, e, out, ws[static_cast<std::size_t>(id)],
                          [&](std::size_t i, std::size_t) { return X + i * np; });
    });
}

}  // namespace iwr
