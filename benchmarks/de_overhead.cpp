// DE's own work per generation, in C++: a generation of de::step on a problem file's leg
// objective against one Objective::cost_batch of 600 vectors on the same threads, and a
// generation on an objective that costs nothing (x0^2), which is DE's own work alone (trials,
// selection, the log). DE/rand/1/bin, NP 600, F 0.9, CR 1, seed 1; per generation the minimum
// over `runs` runs, then the median over generations 50..; cost_batch the minimum of 2000, and
// like for like, the median over groups of `runs` of each group's minimum. The
// "check" line prints the 60th generation's best and a sum of the log's best and mean costs
// (hex): the same in two builds means the same run (the log's spread, printed beside them, is
// not in it: its last digits changed with the one-pass log of BENCHMARKS.md's fifteenth round).
// The kernel variant is the machine's widest.
//
//   cmake -S . -B build/rel -G Ninja -DIWR_BUILD_PYTHON=OFF && cmake --build build/rel
//   g++ -O3 -std=c++17 -DNDEBUG -Icpp/include -isystem EIGEN_INCLUDE (Eigen's folder)
//       benchmarks/de_overhead.cpp build/rel/libiwr_core.a -pthread -o /tmp/de_overhead
//   python -c "import iwr; r = iwr.Robot.default(); d, _ = iwr.simulate(r, n_poses=100, seed=1);
//       iwr.Problem(r, d).save('/tmp/leg.iwrp')"     (one line)
//   /tmp/de_overhead /tmp/leg.iwrp THREADS GENERATIONS [both|real|trivial] [RUNS] [STRATEGY]
// (STRATEGY: another strategy than rand1bin, with its defaults but NP 600 and, for rand1bin, jde
// and best1bin, F 0.9 and CR 1. lshade and jso shrink the population during the timed generations,
// so their median mixes population sizes.)
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <algorithm>
#include <string>
#include <vector>
#include "iwr/de.hpp"
#include "iwr/measurement_kind.hpp"
#include "iwr/problem_file.hpp"
#include "iwr/objective.hpp"

using Clock = std::chrono::steady_clock;
namespace de = iwr::de;

// A trivial objective: cost = x[0]^2 (the DE's own work alone).
struct Trivial final : de::BatchFunction {
    int d;
    explicit Trivial(int d_) : d(d_) {}
    int dim() const override { return d; }
    void evaluate(const double* X, std::size_t m, double* out, iwr::ThreadPool&) override {
        for (std::size_t i = 0; i < m; ++i) out[i] = X[i * d] * X[i * d];
    }
    bool prepare(int) override { return true; }
    void evaluate_rows(const double* X, std::size_t b, std::size_t e, double* out, int) override {
        for (std::size_t i = b; i < e; ++i) out[i] = X[i * d] * X[i * d];
    }
};

template <class F>
double median_gen_ms(F& f, const de::Settings& s, iwr::ThreadPool& pool, int gens, int runs) {
    std::vector<std::vector<double>> all(runs);
    for (int r = 0; r < runs; ++r) {
        de::State st = de::init(s, f, pool);
        for (int g = 0; g < gens; ++g) {
            auto t0 = Clock::now();
            de::step(st, f, pool);
            all[r].push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
        }
    }
    {
        double h = 0;
        de::State st = de::init(s, f, pool);
        for (int g = 0; g < 60; ++g) de::step(st, f, pool);
        for (const auto& e : st.log) h += e.best + e.mean;
        std::printf("check: best %a sum %a (spread %.17g)\n", st.log.back().best, h,
                    st.log.back().spread);
    }
    std::vector<double> mins;
    for (int g = 50; g < gens; ++g) {
        double m = 1e9;
        for (int r = 0; r < runs; ++r) m = std::min(m, all[r][g]);
        mins.push_back(m);
    }
    std::sort(mins.begin(), mins.end());
    return mins[mins.size() / 2];
}

int main(int argc, char** argv) {
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s PROBLEM.iwrp [THREADS [GENERATIONS > 50 [MODE [RUNS [STRATEGY]]]]]\n", argv[0]);
        return 2;
    }
    const std::string path = argv[1];
    const int threads = argc > 2 ? std::atoi(argv[2]) : 1;
    const int gens = argc > 3 ? std::atoi(argv[3]) : 400;
    if (gens <= 50) {
        std::fprintf(stderr, "GENERATIONS: %d; more than 50 (the median is over generations 50..)\n", gens);
        return 2;
    }
    const std::string mode = argc > 4 ? argv[4] : "both";
    const int runs = argc > 5 ? std::atoi(argv[5]) : 5;
    if (runs < 1 || runs > 2000) {
        std::fprintf(stderr, "RUNS: %d; 1 to 2000\n", runs);
        return 2;
    }
    const iwr::ProblemData p = iwr::read_problem(path);
    iwr::AnyObjective any = iwr::make_objective(p);
    const auto& obj = std::get<iwr::Objective>(any);
    de::Settings s;
    try {
        s.strategy = de::parse_strategy(argc > 6 ? argv[6] : "rand1bin", "STRATEGY");
    } catch (const std::exception& e) {
        std::fprintf(stderr, "%s\n", e.what());
        return 2;
    }
    s.lower = p.lower;
    s.upper = p.upper;
    s.seed = 1;
    s.population_size = 600;
    if (s.strategy == de::Strategy::rand1bin || s.strategy == de::Strategy::jde ||
        s.strategy == de::Strategy::best1bin) {
        s.F = 0.9;
        s.CR = 1.0;
    }
    iwr::ThreadPool pool(threads);
    const int d = obj.n_params();
    std::printf("kernel %s threads %d D %d\n", iwr::active_kernel().c_str(), threads, d);
    if (mode == "both" || mode == "real") {
        de::ObjectiveFunction f(obj);
        // cost_batch of 600 random vectors within the bounds
        std::vector<double> X(600 * d), out(600);
        std::srand(0);
        for (int i = 0; i < 600; ++i)
            for (int j = 0; j < d; ++j)
                X[i * d + j] = s.lower[j] + (s.upper[j] - s.lower[j]) * (std::rand() / (RAND_MAX + 1.0));
        // The minimum of 2000, and the generation's statistic: the median over groups of `runs`
        // of each group's minimum (like for like: the minimum of 2000 is lower).
        double best = 1e9;
        std::vector<double> groups;
        for (int k = 0; k < 2000 / runs; ++k) {
            double m = 1e9;
            for (int r = 0; r < runs; ++r) {
                auto t0 = Clock::now();
                obj.cost_batch(X.data(), 600, out.data(), pool);
                m = std::min(m, std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
            }
            groups.push_back(m);
            best = std::min(best, m);
        }
        std::sort(groups.begin(), groups.end());
        const double like = groups[groups.size() / 2];
        const double g = median_gen_ms(f, s, pool, gens, runs);
        std::printf("cost_batch %.4f ms (like for like %.4f ms), generation %.4f ms, ratio %.3fx "
                    "(like for like %.3fx), own %.4f ms (%.4f ms)\n",
                    best, like, g, g / best, g / like, g - best, g - like);
    }
    if (mode == "both" || mode == "trivial") {
        Trivial f(d);
        const double g = median_gen_ms(f, s, pool, gens, runs);
        std::printf("trivial objective: generation %.4f ms\n", g);
    }
}
