// DE's trial generation (make_trials), the log's column sums (column_block) and the carriage's
// per-evaluation constants (CarriageNominal::consts) are compiled for AVX-512, AVX2 and the x86-64
// baseline (GCC's target_clones, de.cpp and objective.cpp), and the CPU running the library picks
// one: the others never run on it, so no test compared their bits. This program is built once
// per variant with de.cpp and objective.cpp compiled for that variant alone (IWR_DE_ISA_AVX512F,
// _AVX2, _BASELINE; clones.hpp, CMakeLists.txt), and once with the library's clones. Without
// arguments it prints one line per run: every strategy and bound rule, the default CR and CR = 1
// (the trials without crossover, built in one pass), two dimensions (a remainder of the vector
// width and several log blocks), two threads, each run's whole state after its generations
// (population, costs, archive, memories, random streams, log: State::serialize, the wall-clock
// times zeroed) as a 64-bit FNV-1a digest; and a line of the leg objective's costs at random
// error vectors (the carriage's constants in every one).
// With --compare PROGRAM... it compares its own lines with each program's: exit 0 when all that
// could run agree (and at least one other did), 1 on a difference (the lines named), 77 (skipped)
// when the CPU runs none of the others. A variant the CPU lacks exits 77 and is left out.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <random>
#include <sstream>
#include <string>
#include <sys/wait.h>
#include <vector>

#include "de_fixtures.hpp"
#include "fixtures.hpp"
#include "iwr/de.hpp"
#include "iwr/model.hpp"
#include "iwr/objective.hpp"

namespace {

using iwr::de::BoundRule;
using iwr::de::Strategy;

using iwr_test::TestFunction;

std::uint64_t fnv1a(const std::string& bytes) {
    std::uint64_t h = 0xcbf29ce484222325ULL;
    for (unsigned char c : bytes) {
        h ^= c;
        h *= 0x100000001b3ULL;
    }
    return h;
}

// The leg objective's costs near two error vectors (the kernel variant the CPU picks, the same in
// every program): each goes through CarriageNominal::consts, whose sines and cosines of the joint
// angles take a series within 0.8 rad of the nominal and libm beyond (the second vector's).
// The legs are predicted at the vector, so that the costs are small and each moves with the
// last bits of the constants.
std::string carriage_digest() {
    const iwr::Geometry g = iwr_test::default_iwr();
    const int n = 21, m = 32, d = g.n_params();
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(-1.0, 1.0);
    iwr::RowMatrixXd q(n, 4), poses(n, 6);
    for (int k = 0; k < n; ++k) {
        q.row(k) << 100 * u(rng), 100 * u(rng), 0.5 * u(rng), 0.5 * u(rng);
        poses.row(k) << 400 + 50 * u(rng), 300 + 50 * u(rng), 900 + 50 * u(rng), 0.1 * u(rng),
            0.1 * u(rng), 0.1 * u(rng);
    }
    std::string out;
    for (double scale : {0.01, 2.0}) {
        iwr::VectorXd x0(d);
        for (int e = 0; e < d; ++e) x0(e) = scale * u(rng);
        const iwr::Objective obj(g, q, poses, iwr::predict_legs(g, x0, q, poses));
        std::vector<double> x(static_cast<std::size_t>(m * d)), cost(static_cast<std::size_t>(m));
        for (int i = 0; i < m; ++i)
            for (int e = 0; e < d; ++e)
                x[static_cast<std::size_t>(i * d + e)] = x0(e) + (i == 0 ? 0.0 : 1e-6 * u(rng));
        iwr::ThreadPool pool(1);
        obj.cost_batch(x.data(), m, cost.data(), pool);
        const std::string bytes(reinterpret_cast<const char*>(cost.data()),
                                cost.size() * sizeof(double));
        char line[160];
        std::snprintf(line, sizeof line,
                      "leg objective near errors of %g: %d costs, the first %.17g, %016llx\n", scale,
                      m, cost[0], static_cast<unsigned long long>(fnv1a(bytes)));
        out += line;
    }
    return out;
}

std::string digests() {
    constexpr Strategy kAll[] = {Strategy::rand1bin, Strategy::best1bin, Strategy::jade,
                                 Strategy::jde,      Strategy::shade,    Strategy::lshade,
                                 Strategy::jso};
    constexpr BoundRule kRules[] = {BoundRule::midpoint, BoundRule::reinit, BoundRule::reflect,
                                    BoundRule::clip};
    std::ostringstream out;
    iwr::ThreadPool pool(2);
    for (Strategy s : kAll)
        for (BoundRule rule : kRules)
            for (bool no_crossover : {false, true})  // the strategy's default CR, or CR = 1
            for (int d : {13, 37}) {
                TestFunction f(d);
                iwr::de::Settings set;
                set.strategy = s;
                set.bound_rule = rule;
                set.lower.assign(static_cast<std::size_t>(d), -1.0);
                set.upper.assign(static_cast<std::size_t>(d), 2.0);
                set.seed = 2026;
                set.population_size = 24;
                set.max_evaluations = 24 * 40;
                if (no_crossover) set.CR = 1.0;
                auto st = iwr::de::init(set, f, pool);
                for (int g = 0; g < 30; ++g) iwr::de::step(st, f, pool);
                st.elapsed = 0;  // the wall clock: the one part of a state that is not reproducible
                for (auto& e : st.log) e.elapsed = 0;
                std::ostringstream bytes;
                st.serialize(bytes);
                char line[160];
                std::snprintf(line, sizeof line, "%s %s CR %g D=%d generation %d best %.17g %016llx\n",
                              iwr::de::to_string(s).c_str(), iwr::de::to_string(rule).c_str(),
                              set.CR, d,
                              static_cast<int>(st.generation), st.log.back().best,
                              static_cast<unsigned long long>(fnv1a(bytes.str())));
                out << line;
            }
    out << carriage_digest();
    return out.str();
}

const char* variant() {
#if defined(IWR_DE_ISA_AVX512F)
    return "avx512f";
#elif defined(IWR_DE_ISA_AVX2)
    return "avx2";
#elif defined(IWR_DE_ISA_BASELINE)
    return "baseline";
#else
    return "the clones the CPU picks";
#endif
}

bool runs_here() {
#if defined(IWR_DE_ISA_AVX512F)
    return __builtin_cpu_supports("avx512f");
#elif defined(IWR_DE_ISA_AVX2)
    return __builtin_cpu_supports("avx2");
#else
    return true;
#endif
}

// The other program's output and exit status.
int run(const char* program, std::string& text) {
    FILE* p = popen((std::string("'") + program + "'").c_str(), "r");
    if (!p) return -1;
    char buf[4096];
    std::size_t n;
    while ((n = std::fread(buf, 1, sizeof buf, p)) > 0) text.append(buf, n);
    const int status = pclose(p);
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace

int main(int argc, char** argv) {
    if (!runs_here()) {
        std::printf("%s: not run by this CPU\n", variant());
        return 77;
    }
    const std::string mine = digests();
    if (argc < 2) {
        std::fputs(mine.c_str(), stdout);
        return 0;
    }
    if (std::strcmp(argv[1], "--compare") != 0) {
        std::fprintf(stderr, "usage: %s [--compare PROGRAM...]\n", argv[0]);
        return 2;
    }
    int compared = 0, failed = 0;
    for (int k = 2; k < argc; ++k) {
        std::string theirs;
        const int code = run(argv[k], theirs);
        if (code == 77) {
            std::printf("%s: skipped (%s)", argv[k], theirs.c_str());
            continue;
        }
        if (code != 0 || theirs != mine) {
            std::printf("%s (exit %d) differs from %s:\n--- %s\n%s--- %s\n%s", argv[k], code,
                        variant(), variant(), mine.c_str(), argv[k], theirs.c_str());
            ++failed;
        } else {
            std::printf("%s: the same bits as %s (%zu runs)\n", argv[k], variant(),
                        static_cast<std::size_t>(std::count(mine.begin(), mine.end(), '\n')));
        }
        ++compared;
    }
    if (failed) return 1;
    return compared ? 0 : 77;
}
