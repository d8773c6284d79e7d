// The C++ DE tests' objective (test_de.cpp, test_de_isa.cpp).
#pragma once

#include <cstddef>

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

}  // namespace iwr_test
