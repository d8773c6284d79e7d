#include "iwr/parallel.hpp"

#include <algorithm>

namespace iwr {

int ThreadPool::resolve(int threads) {
    if (threads > 0) return threads;
    const unsigned hw = std::thread::hardware_concurrency();
    return hw == 0 ? 1 : static_cast<int>(hw);
}

ThreadPool::ThreadPool(int threads) {
    const int n = resolve(threads);
    for (int i = 1; i < n; ++i) workers_.emplace_back([this, i] { worker_loop(i); });
}

ThreadPool::~ThreadPool() {
    {
        std::lock_guard<std::mutex> lock(mutex_);
        stop_ = true;
    }
    start_cv_.notify_all();
    for (auto& w : workers_) w.join();
}

static void chunk(std::size_t n, int parts, int id, std::size_t& begin, std::size_t& end) {
    const std::size_t p = static_cast<std::size_t>(parts);
    const std::size_t base = n / p, extra = n % p, i = static_cast<std::size_t>(id);
    begin = i * base + std::min(i, extra);
    end = begin + base + (i < extra ? 1 : 0);
}

void ThreadPool::worker_loop(int id) {
    unsigned long seen = 0;
    for (;;) {
        const std::function<void(std::size_t, std::size_t, int)>* job;
        std::size_t n;
        {
            std::unique_lock<std::mutex> lock(mutex_);
            start_cv_.wait(lock, [&] { return stop_ || generation_ != seen; });
            if (stop_) return;
            seen = generation_;
            job = job_;
            n = n_;
        }
        std::size_t b, e;
        chunk(n, size(), id, b, e);
        try {
            if (b < e) (*job)(b, e, id);
        } catch (...) {
            std::lock_guard<std::mutex> lock(mutex_);
            if (!error_) error_ = std::current_exception();
        }
        {
            std::lock_guard<std::mutex> lock(mutex_);
            if (--pending_ == 0) done_cv_.notify_one();
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
        pending_ = static_cast<int>(workers_.size());
        error_ = nullptr;
        ++generation_;
    }
    start_cv_.notify_all();
    std::exception_ptr mine;
    std::size_t b, e;
    chunk(n, size(), 0, b, e);
    try {
        if (b < e) fn(b, e, 0);
    } catch (...) {
        mine = std::current_exception();
    }
    std::exception_ptr theirs;
    {
        std::unique_lock<std::mutex> lock(mutex_);
        done_cv_.wait(lock, [&] { return pending_ == 0; });
        theirs = error_;
        job_ = nullptr;
    }
    if (mine) std::rethrow_exception(mine);
    if (theirs) std::rethrow_exception(theirs);
}

}  // namespace iwr
