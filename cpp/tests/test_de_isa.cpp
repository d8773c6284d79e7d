// DE's trial generation (make_trials) and the log's column sums (column_block) are compiled for
// AVX-512, AVX2 and the x86-64 baseline (GCC's target_clones, de.cpp), and the CPU running the
// library picks one: the others never run on it, so no test compared their bits. This program is
// built once per variant with de.cpp compiled for that variant alone (IWR_DE_ISA_AVX512F, _AVX2,
// _BASELINE; CMakeLists.txt), and once with the library's clones. Without arguments it prints one
// line per run: every strategy and bound rule, the default CR and CR = 1 (the trials without
// crossover, built in one pass), two dimensions (a remainder of the vector width
// and several log blocks), two threads, each run's whole state after its generations (population,
// costs, archive, memories, random streams, log: State::serialize, the wall-clock times
// zeroed) as a 64-bit FNV-1a digest.
// With --compare PROGRAM... it compares its own lines with each program's: exit 0 when all that
// could run agree (and at least one other did), 1 on a difference (the lines named), 77 (skipped)
// when the CPU runs none of the others. A variant the CPU lacks exits 77 and is left out.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <sstream>
#include <string>
#include <sys/wait.h>

#include "de_fixtures.hpp"
#include "iwr/de.hpp"

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
