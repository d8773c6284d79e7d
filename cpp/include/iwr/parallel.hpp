// A small persistent thread pool with static, contiguous partitioning.
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
#include <mutex>
#include <thread>
#include <vector>

namespace iwr {

class ThreadPool {
public:
    /// threads <= 0 means std::thread::hardware_concurrency().
    explicit ThreadPool(int threads = 0);
    ~ThreadPool();
    ThreadPool(const ThreadPool&) = delete;
    ThreadPool& operator=(const ThreadPool&) = delete;

    int size() const { return static_cast<int>(workers_.size()) + 1; }

    /// Calls fn(begin, end, worker) on contiguous chunks of [0, n), one chunk per thread; the calling
    /// thread takes chunk 0. Rethrows the first exception thrown by any chunk.
    void parallel_for(std::size_t n, const std::function<void(std::size_t, std::size_t, int)>& fn);

    /// Resolves a user's thread count: <= 0 means all the CPUs this process may run on (its
    /// affinity mask on Linux, else std::thread::hardware_concurrency). CPU quotas (cgroup
    /// cpu.max) are not taken into account.
    static int resolve(int threads);

    /// How long a thread spins waiting for work (or for the workers) before it sleeps.
    static constexpr int kSpinMicroseconds = 100;

private:
    void worker_loop(int id);

    std::vector<std::thread> workers_;
    std::mutex mutex_;
    std::condition_variable start_cv_, done_cv_;
    // Written by the caller before it publishes generation_ (release); read after (acquire).
    const std::function<void(std::size_t, std::size_t, int)>* job_ = nullptr;
    std::size_t n_ = 0;
    std::atomic<unsigned long> generation_{0};
    std::atomic<int> pending_{0};
    std::atomic<bool> stop_{false};
    bool spin_ = true;  // false when oversubscribed
    std::exception_ptr error_;  // guarded by mutex_
};

}  // namespace iwr
