#include "iwr/parallel.hpp"

#include <algorithm>
#include <chrono>

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

ThreadPool::ThreadPool(int threads) {
    const int n = resolve(threads);
    spin_ = n <= resolve(0);
    for (int i = 1; i < n; ++i) workers_.emplace_back([this, i] { worker_loop(i); });
}

ThreadPool::~ThreadPool() {
    {
        std::lock_guard<std::mutex> lock(mutex_);
        stop_.store(true, std::memory_order_release);
    }
    start_cv_.notify_all();
    for (auto& w : workers_) w.join();
}

void ThreadPool::worker_loop(int id) {
    unsigned long seen = 0;
    for (;;) {
        const auto posted = [&] {
            return stop_.load(std::memory_order_acquire) ||
                   generation_.load(std::memory_order_acquire) != seen;
        };
        if (!spin_until(spin_, posted)) {
            std::unique_lock<std::mutex> lock(mutex_);
            start_cv_.wait(lock, posted);
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
            std::lock_guard<std::mutex> lock(mutex_);
            if (!error_) error_ = std::current_exception();
        }
        if (pending_.fetch_sub(1, std::memory_order_acq_rel) == 1) {
            // The caller may be asleep on done_cv_: the lock orders this notify after its check.
            std::lock_guard<std::mutex> lock(mutex_);
            done_cv_.notify_one();
        }
    }
}

void ThreadPool::parallel_for(std::size_t n,
                              const std::function<void(std::size_t, std::size_t, int)>& fn) {
    if (workers_.empty() || n < 2) {
        if (n > 0) fn(0, n, 0);
        return;
    }
    {
        std::lock_guard<std::mutex> lock(mutex_);
        job_ = &fn;
        n_ = n;
        error_ = nullptr;
        pending_.store(static_cast<int>(workers_.size()), std::memory_order_relaxed);
        generation_.fetch_add(1, std::memory_order_release);  // publishes job_, n_, pending_
    }
    start_cv_.notify_all();  // for workers that stopped spinning
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
        std::unique_lock<std::mutex> lock(mutex_);
        done_cv_.wait(lock, done);
    }
    {
        std::lock_guard<std::mutex> lock(mutex_);
        theirs = error_;
        job_ = nullptr;
    }
    if (mine) std::rethrow_exception(mine);
    if (theirs) std::rethrow_exception(theirs);
}

}  // namespace iwr
