#include "iwr/parallel.hpp"

#include <algorithm>
#include <chrono>
#include <memory>
#include <stdexcept>
#include <string>
#include <system_error>

#include <unistd.h>

#if defined(__linux__)
#include <sched.h>
#endif

namespace iwr {

namespace {

inline void cpu_relax() {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#else
    std::this_thread::yield();
#endif
}

// Polls done() for up to kSpinMicroseconds, reading the clock and yielding the processor every 256
// polls (a few microseconds, by the CPU's PAUSE latency); true if it became true. `spin` false: a
// single poll.
template <class Done>
bool spin_until(bool spin, Done done) {
    if (!spin) return done();
    using Clock = std::chrono::steady_clock;
    const auto limit = Clock::now() + std::chrono::microseconds(ThreadPool::kSpinMicroseconds);
    for (;;) {
        for (int k = 0; k < 256; ++k) {
            if (done()) return true;
            cpu_relax();
        }
        if (Clock::now() >= limit) return done();
        std::this_thread::yield();
    }
}

void chunk(std::size_t n, int parts, int id, std::size_t& begin, std::size_t& end) {
    const std::size_t p = static_cast<std::size_t>(parts);
    const std::size_t base = n / p, extra = n % p, i = static_cast<std::size_t>(id);
    begin = i * base + std::min(i, extra);
    end = begin + base + (i < extra ? 1 : 0);
}

}  // namespace

int ThreadPool::resolve(int threads) {
    if (threads > 0) return threads;
#if defined(__linux__)
    // The CPUs this process may run on (a container's or taskset's cpuset), not the machine's.
    cpu_set_t set;
    if (sched_getaffinity(0, sizeof set, &set) == 0) {
        const int n = CPU_COUNT(&set);
        if (n > 0) return n;
    }
#endif
    const unsigned hw = std::thread::hardware_concurrency();
    return hw == 0 ? 1 : static_cast<int>(hw);
}

int ThreadPool::max_threads() { return std::max(kMinMaxThreads, kThreadsPerCpu * resolve(0)); }

bool ThreadPool::usable_here() const { return owner_pid_ == static_cast<long>(::getpid()); }

ThreadPool::ThreadPool(int threads) : owner_pid_(static_cast<long>(::getpid())) {
    const int n = resolve(threads);
    if (n > max_threads())
        throw std::invalid_argument(std::to_string(n) + " threads asked for; at most " +
                                    std::to_string(max_threads()) + " (" + std::to_string(kThreadsPerCpu) +
                                    " per CPU this process may use, at least " +
                                    std::to_string(kMinMaxThreads) + ")");
    spin_ = n <= resolve(0);
    workers_.reserve(static_cast<std::size_t>(n - 1));
    for (int i = 1; i < n; ++i) {
        try {
            workers_.emplace_back([this, i] { worker_loop(i); });
        } catch (const std::system_error& e) {
            // The constructor fails: the destructor will not run, so stop what did start here.
            const std::size_t started = workers_.size();
            shutdown();
            throw std::runtime_error("threads: cannot start " + std::to_string(n) + " threads (" +
                                     std::to_string(started + 1) + " running when the system refused one: " +
                                     e.what() + "); use fewer threads or raise the process limit");
        }
    }
}

void ThreadPool::shutdown() {
    {
        std::lock_guard<std::mutex> lock(sync_->mutex);
        stop_.store(true, std::memory_order_release);
    }
    sync_->start_cv.notify_all();
    for (auto& w : workers_) w.join();
    workers_.clear();
}

ThreadPool::~ThreadPool() {
    if (!usable_here()) {
        // A forked child's copy: its threads do not exist here. Joining them, or destroying a
        // condition variable they were waiting on in the parent, would wait forever: leak both.
        new std::vector<std::thread>(std::move(workers_));
        (void)sync_.release();
        return;
    }
    shutdown();
}

void ThreadPool::worker_loop(int id) {
    unsigned long seen = 0;
    for (;;) {
        const auto posted = [&] {
            return stop_.load(std::memory_order_acquire) ||
                   generation_.load(std::memory_order_acquire) != seen;
        };
        if (!spin_until(spin_, posted)) {
            std::unique_lock<std::mutex> lock(sync_->mutex);
            sync_->start_cv.wait(lock, posted);
        }
        if (stop_.load(std::memory_order_acquire)) return;
        seen = generation_.load(std::memory_order_acquire);
        const auto* job = job_;
        const std::size_t n = n_;
        std::size_t b, e;
        chunk(n, size(), id, b, e);
        try {
            if (b < e) (*job)(b, e, id);
        } catch (...) {
            std::lock_guard<std::mutex> lock(sync_->mutex);
            if (!error_) error_ = std::current_exception();
        }
        if (pending_.fetch_sub(1, std::memory_order_acq_rel) == 1) {
            // The caller may be asleep on sync_->done_cv: the lock orders this notify after its check.
            std::lock_guard<std::mutex> lock(sync_->mutex);
            sync_->done_cv.notify_one();
        }
    }
}

void ThreadPool::parallel_for(std::size_t n,
                              const std::function<void(std::size_t, std::size_t, int)>& fn) {
    if (!usable_here())
        throw std::logic_error("thread pool: made in process " + std::to_string(owner_pid_) +
                               ", used in process " + std::to_string(::getpid()) +
                               " (a fork): its threads do not exist here; make a new pool");
    if (workers_.empty() || n < 2) {
        if (n > 0) fn(0, n, 0);
        return;
    }
    {
        std::lock_guard<std::mutex> lock(sync_->mutex);
        job_ = &fn;
        n_ = n;
        error_ = nullptr;
        pending_.store(static_cast<int>(workers_.size()), std::memory_order_relaxed);
        generation_.fetch_add(1, std::memory_order_release);  // publishes job_, n_, pending_
    }
    sync_->start_cv.notify_all();  // for workers that stopped spinning
    std::exception_ptr mine;
    std::size_t b, e;
    chunk(n, size(), 0, b, e);
    try {
        if (b < e) fn(b, e, 0);
    } catch (...) {
        mine = std::current_exception();
    }
    const auto done = [&] { return pending_.load(std::memory_order_acquire) == 0; };
    std::exception_ptr theirs;
    if (!spin_until(spin_, done)) {
        std::unique_lock<std::mutex> lock(sync_->mutex);
        sync_->done_cv.wait(lock, done);
    }
    {
        std::lock_guard<std::mutex> lock(sync_->mutex);
        theirs = error_;
        job_ = nullptr;
    }
    if (mine) std::rethrow_exception(mine);
    if (theirs) std::rethrow_exception(theirs);
}

void ThreadPool::parallel_for_dynamic(
    std::size_t n, std::size_t grain, const std::function<void(std::size_t, std::size_t, int)>& fn) {
    const int t = size();
    if (t == 1 || n < 2 || !usable_here()) return parallel_for(n, fn);  // serial, or its error
    // At most n: a claim adds it to a share's counter, which a grain near SIZE_MAX wrapped (a
    // range claimed twice).
    grain = std::clamp<std::size_t>(grain, 1, n);
    // Each share's counter alone on its cache line (its thread's claims write it); on the stack
    // for the pools people make (a generation calls this once, a cost_batch once).
    struct alignas(64) Range {
        std::atomic<std::size_t> next{0};
        std::size_t end = 0;
    };
    constexpr int kOnStack = 16;
    Range local[kOnStack];
    std::unique_ptr<Range[]> heap;
    if (t > kOnStack) heap.reset(new Range[static_cast<std::size_t>(t)]);
    Range* const ranges = heap ? heap.get() : local;
    for (int k = 0; k < t; ++k) {
        std::size_t b, e;
        chunk(n, t, k, b, e);
        ranges[static_cast<std::size_t>(k)].next.store(b, std::memory_order_relaxed);
        ranges[static_cast<std::size_t>(k)].end = e;
    }
    parallel_for(static_cast<std::size_t>(t), [&](std::size_t, std::size_t, int id) {
        for (int k = 0; k < t; ++k) {
            Range& r = ranges[static_cast<std::size_t>((id + k) % t)];
            for (;;) {
                const std::size_t seen = r.next.load(std::memory_order_relaxed);
                if (seen >= r.end) break;
                const std::size_t want = std::max(grain, (r.end - seen) / 2);
                const std::size_t b = r.next.fetch_add(want, std::memory_order_relaxed);
                if (b >= r.end) break;
                fn(b, std::min(r.end, b + want), id);
            }
        }
    });
}

}  // namespace iwr
