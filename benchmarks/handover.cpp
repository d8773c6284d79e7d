// How long it takes one thread to hand work to another and get the answer back, on this machine:
// the fixed cost of every parallel_for of a thread pool, paid twice per DE generation.
//
//   condition variable: as iwr::ThreadPool does (mutex + condition variable to start the worker,
//                       another to wait for it), the worker sleeping in between;
//   spinning:           the worker polls an atomic counter and never sleeps.
// Each is measured with the two threads pinned to different CPUs and (condition variable only) to
// the same CPU, where the hand-over is a context switch. Linux only (pthread affinity).
//
//   g++ -O2 -std=c++17 -pthread benchmarks/handover.cpp -o /tmp/handover && /tmp/handover
#include <pthread.h>
#include <sched.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <mutex>
#include <thread>
#include <vector>

using Clock = std::chrono::steady_clock;

namespace {

void pin(int cpu) {
    cpu_set_t set;
    CPU_ZERO(&set);
    CPU_SET(cpu, &set);
    pthread_setaffinity_np(pthread_self(), sizeof set, &set);
}

double us_since(Clock::time_point t0) {
    return std::chrono::duration<double, std::micro>(Clock::now() - t0).count();
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
}

double condvar(int main_cpu, int worker_cpu, int reps) {
    std::mutex m;
    std::condition_variable start, done;
    unsigned long gen = 0;
    int pending = 0;
    bool stop = false;
    pin(main_cpu);
    std::thread w([&] {
        pin(worker_cpu);
        unsigned long seen = 0;
        for (;;) {
            std::unique_lock<std::mutex> l(m);
            start.wait(l, [&] { return stop || gen != seen; });
            if (stop) return;
            seen = gen;
            if (--pending == 0) done.notify_one();
        }
    });
    std::vector<double> t;
    for (int i = 0; i < reps; ++i) {
        const auto t0 = Clock::now();
        {
            std::lock_guard<std::mutex> l(m);
            pending = 1;
            ++gen;
        }
        start.notify_all();
        {
            std::unique_lock<std::mutex> l(m);
            done.wait(l, [&] { return pending == 0; });
        }
        t.push_back(us_since(t0));
    }
    {
        std::lock_guard<std::mutex> l(m);
        stop = true;
    }
    start.notify_all();
    w.join();
    return median(t);
}

double spinning(int main_cpu, int worker_cpu, int reps) {
    std::atomic<unsigned long> go{0}, ack{0};
    std::atomic<bool> stop{false};
    pin(main_cpu);
    std::thread w([&] {
        pin(worker_cpu);
        unsigned long seen = 0;
        while (!stop.load(std::memory_order_acquire)) {
            const unsigned long g = go.load(std::memory_order_acquire);
            if (g != seen) ack.store(seen = g, std::memory_order_release);
        }
    });
    std::vector<double> t;
    for (unsigned long i = 1; i <= static_cast<unsigned long>(reps); ++i) {
        const auto t0 = Clock::now();
        go.store(i, std::memory_order_release);
        while (ack.load(std::memory_order_acquire) != i) {
        }
        t.push_back(us_since(t0));
    }
    stop = true;
    w.join();
    return median(t);
}

}  // namespace

int main() {
    const int reps = 5000;
    if (std::thread::hardware_concurrency() < 2) {
        std::printf("needs 2 CPUs\n");
        return 1;
    }
    std::printf("median round trip over %d hand-overs:\n", reps);
    std::printf("  condition variable, CPUs 0 -> 1: %8.2f us\n", condvar(0, 1, reps));
    std::printf("  condition variable, CPUs 0 -> 0: %8.2f us\n", condvar(0, 0, reps));
    std::printf("  spinning,           CPUs 0 -> 1: %8.2f us\n", spinning(0, 1, reps));
}
