// The C++ DE tests' objective (test_de.cpp, test_de_isa.cpp).
#pragma once

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <stdexcept>

#include "iwr/de.hpp"

namespace iwr_test {

// Shifted Rosenbrock-like sum with a cost that depends only on its row.
class TestFunction : public iwr::de::BatchFunction {
public:
    explicit TestFunction(int d, bool flat = false) : d_(d), flat_(flat) {}
    int dim() const override { return d_; }
    void evaluate(const double* X, std::size_t m, double* out, iwr::ThreadPool& pool) override {
        pool.parallel_for(m, [&](std::size_t b, std::size_t e, int) {
            for (std::size_t i = b; i < e; ++i) {
                const double* x = X + i * static_cast<std::size_t>(d_);
                double s = 0;
                for (int j = 0; j < d_; ++j) s += (x[j] - 0.3) * (x[j] - 0.3) * (1 + j);
                out[i] = flat_ ? 1.0 : s;
            }
        });
        calls += 1;
    }
    int calls = 0;

private:
    int d_;
    bool flat_;
};

// The same kind of cost, evaluated row by row on the generation's own pass (prepare true: the
// path of the C++ objectives) or through evaluate (prepare false). `throw_at`: the evaluation
// with that count (from 0) throws Boom; `jitter`: thread 1 waits 20 us at every 7th evaluation
// (another process on its core), so that the other threads take slots of its share.
struct Boom : std::runtime_error {
    using std::runtime_error::runtime_error;
};
class RowFunction : public iwr::de::BatchFunction {
public:
    RowFunction(int d, bool rows) : d_(d), rows_(rows) {}
    int dim() const override { return d_; }
    bool prepare(int) override { return rows_; }
    void evaluate_rows(const double* X, std::size_t b, std::size_t e, double* out, int id) override {
        for (std::size_t i = b; i < e; ++i) out[i] = row(X + i * static_cast<std::size_t>(d_), id);
    }
    void evaluate(const double* X, std::size_t m, double* out, iwr::ThreadPool& pool) override {
        pool.parallel_for(m, [&](std::size_t b, std::size_t e, int id) { evaluate_rows(X, b, e, out, id); });
    }
    long throw_at = -1;
    bool jitter = false;
    // The cost of the rows whose first component is above `special_above`.
    double special = 0, special_above = INFINITY;
    std::atomic<long> count{0};

private:
    double row(const double* x, int id) {
        const long c = count.fetch_add(1);
        if (c == throw_at) throw Boom("boom");
        if (jitter && id == 1 && c % 7 == 0) {
            const auto until = std::chrono::steady_clock::now() + std::chrono::microseconds(20);
            while (std::chrono::steady_clock::now() < until) {
            }
        }
        if (x[0] > special_above) return special;
        double s = 0;
        for (int j = 0; j < d_; ++j) s += (x[j] - 0.3) * (x[j] - 0.3) * (1 + j) + 0.1 * std::sin(7 * x[j]);
        return s;
    }
    int d_;
    bool rows_;
};

}  // namespace iwr_test
