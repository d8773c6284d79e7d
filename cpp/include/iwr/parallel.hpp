// A small persistent thread pool with static, contiguous partitioning.
//
// Work item i always runs the same code on the same data whatever the number of threads, so results
// that depend only on i are bit-identical for 1 or many threads. Nothing random lives here.
#pragma once

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

    /// Resolves a user's thread count: <= 0 means all hardware threads.
    static int resolve(int threads);

private:
    void worker_loop(int id);

    std::vector<std::thread> workers_;
    std::mutex mutex_;
    std::condition_variable start_cv_, done_cv_;
    const std::function<void(std::size_t, std::size_t, int)>* job_ = nullptr;
    std::size_t n_ = 0;
    unsigned long generation_ = 0;
    int pending_ = 0;
    bool stop_ = false;
    std::exception_ptr error_;
};

}  // namespace iwr
