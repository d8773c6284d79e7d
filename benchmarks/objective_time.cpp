// The C++ objective of problem files per evaluation, alternated: Objective::cost_batch of 600
// vectors drawn uniformly within each problem's bounds (std::rand, seed 0), one thread, thread
// CPU time divided by 600, the minimum over ROUNDS rounds of 20 calls of each file in turn (the
// files alternated, so that a clock change or a neighbour hits them alike). One kernel variant,
// forced (iwr::select_kernel: baseline, avx2 or avx512). The "check" is the sum of the first
// call's costs of every file (hex): the same in two builds means the same bits. What the rounds of
// BENCHMARKS.md call `trk_time` (the tracker problems of bench_regression.py --objectives, saved
// with TrackerProblem.save; the leg problem with Problem.save).
//
//   cmake -S . -B build/rel -G Ninja -DIWR_BUILD_PYTHON=OFF && cmake --build build/rel
//   g++ -O2 -std=c++17 -Icpp/include -isystem EIGEN_INCLUDE benchmarks/objective_time.cpp
//       build/rel/libiwr_core.a -pthread -o /tmp/objective_time
//   /tmp/objective_time VARIANT ROUNDS PROBLEM.iwrp [PROBLEM.iwrp ...]
#include <time.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <variant>
#include <vector>

#include "iwr/measurement_kind.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"
#include "iwr/problem_file.hpp"

namespace {
double thread_cpu_seconds() {
    timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}
}  // namespace

int main(int argc, char** argv) {
    if (argc < 4) {
        std::fprintf(stderr, "usage: %s VARIANT ROUNDS PROBLEM.iwrp [PROBLEM.iwrp ...]\n", argv[0]);
        return 2;
    }
    iwr::select_kernel(argv[1]);
    const int rounds = std::max(1, std::atoi(argv[2]));
    constexpr int kVectors = 600;
    std::vector<iwr::ProblemData> problems;
    for (int a = 3; a < argc; ++a) problems.push_back(iwr::read_problem(argv[a]));
    std::vector<iwr::AnyObjective> objectives;
    std::vector<std::vector<double>> X;
    for (const auto& p : problems) {
        objectives.push_back(iwr::make_objective(p));
        const std::size_t d = p.lower.size();
        std::vector<double> x(kVectors * d);
        std::srand(0);
        for (std::size_t i = 0; i < kVectors; ++i)
            for (std::size_t j = 0; j < d; ++j)
                x[i * d + j] = p.lower[j] + (p.upper[j] - p.lower[j]) * (std::rand() / (RAND_MAX + 1.0));
        X.push_back(std::move(x));
    }
    iwr::ThreadPool pool(1);
    std::vector<double> out(kVectors), best(problems.size(), 1e300);
    double check = 0;
    for (int r = 0; r < rounds; ++r)
        for (std::size_t k = 0; k < objectives.size(); ++k)
            for (int rep = 0; rep < 20; ++rep) {
                const double t0 = thread_cpu_seconds();
                std::visit([&](auto& o) { o.cost_batch(X[k].data(), kVectors, out.data(), pool); },
                           objectives[k]);
                best[k] = std::min(best[k], (thread_cpu_seconds() - t0) / kVectors * 1e6);
                if (r == 0 && rep == 0)
                    for (double v : out) check += v;
            }
    std::printf("%s", iwr::active_kernel().c_str());
    for (double b : best) std::printf(" %.4f", b);
    std::printf(" us  check %a\n", check);
}
