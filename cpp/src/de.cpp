// Differential evolution engine; see iwr/de.hpp for the API, the strategies and their references.
#include "iwr/de.hpp"

#include "iwr/binary_io.hpp"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <istream>
#include <iterator>
#include <memory>
#include <numeric>
#include <ostream>
#include <sstream>
#include <stdexcept>
#include <utility>

#include "clones.hpp"
#include "inline.hpp"

// The trial loop and the log's column sums are IWR_CLONES (clones.hpp): compiled for AVX-512 and
// AVX2 as well as the baseline, the same values on each. The helpers they call in their loops are
// always inlined, so that each clone compiles them for its own instruction set (the random
// streams' out-of-line methods aside: integer arithmetic).
// IWR_DE_ISA_AVX512F, _AVX2 or _BASELINE (clones.hpp) compile one variant alone, the one a CPU of
// that kind runs: the CPU picks the clone, so only such a build runs the others
// (cpp/tests/test_de_isa.cpp compares their bits).

namespace iwr::de {

// ===== random streams ==================================================================================

namespace {

std::uint64_t splitmix64(std::uint64_t& x) {
    std::uint64_t z = (x += 0x9e3779b97f4a7c15ULL);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

IWR_FORCE_INLINE std::uint64_t rotl(std::uint64_t x, int k) { return (x << k) | (x >> (64 - k)); }

constexpr double kPi = 3.14159265358979323846;

// One step of xoshiro256** on s, inlined where the trials are drawn (Rng::next, an out-of-line
// call there: the target_clones copies of the trial loop did not inline it).
IWR_FORCE_INLINE std::uint64_t xoshiro_next(std::uint64_t* s) {
    const std::uint64_t result = rotl(s[1] * 5, 7) * 9;
    const std::uint64_t t = s[1] << 17;
    s[2] ^= s[0];
    s[3] ^= s[1];
    s[1] ^= s[2];
    s[0] ^= s[3];
    s[2] ^= t;
    s[3] = rotl(s[3], 45);
    return result;
}

// Rng::uniform, inlined.
IWR_FORCE_INLINE double uniform_of(Rng& g) { return static_cast<double>(xoshiro_next(g.s) >> 11) * 0x1.0p-53; }

}  // namespace

Rng Rng::seeded(std::uint64_t seed) {
    Rng r;
    std::uint64_t x = seed;
    for (auto& w : r.s) w = splitmix64(x);
    if ((r.s[0] | r.s[1] | r.s[2] | r.s[3]) == 0) r.s[0] = 1;  // the one forbidden state
    return r;
}

std::uint64_t Rng::next() { return xoshiro_next(s); }

void Rng::jump() {
    static const std::uint64_t kJump[] = {0x180ec6d33cfd0abaULL, 0xd5a61266f0c9392cULL,
                                          0xa9582618e03fc9aaULL, 0x39abdc4529b1661cULL};
    std::uint64_t t[4] = {0, 0, 0, 0};
    for (std::uint64_t word : kJump) {
        for (int b = 0; b < 64; ++b) {
            if (word & (std::uint64_t{1} << b)) {
                for (int k = 0; k < 4; ++k) t[k] ^= s[k];
            }
            next();
        }
    }
    for (int k = 0; k < 4; ++k) s[k] = t[k];
}

double Rng::uniform() { return uniform_of(*this); }

double Rng::uniform(double a, double b) { return a + (b - a) * uniform(); }

std::uint64_t Rng::below(std::uint64_t n) {
    // Rejection of the lowest (2^64 mod n) values makes r % n exactly uniform.
    const std::uint64_t threshold = (0 - n) % n;
    for (;;) {
        const std::uint64_t r = next();
        if (r >= threshold) return r % n;
    }
}

double Rng::normal(double mean, double sd) {
    const double u1 = 1.0 - uniform();  // (0, 1]: log is finite
    const double u2 = uniform();
    return mean + sd * std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
}

double Rng::cauchy(double loc, double scale) { return loc + scale * std::tan(kPi * (uniform() - 0.5)); }

// ===== names =========================================================================================

namespace {
const char* const kStrategyNames[kStrategyCount] = {"rand1bin", "best1bin", "jade", "jde",
                                                    "shade",    "lshade",   "jso"};
const char* const kBoundRuleNames[kBoundRuleCount] = {"midpoint", "reinit", "reflect", "clip"};

template <typename T>
std::string str(const T& v) {
    std::ostringstream o;
    o.precision(17);
    o << v;
    return o.str();
}

[[noreturn]] void bad(const std::string& msg) { throw std::invalid_argument(msg); }
}  // namespace

std::string to_string(Strategy s) {
    const int i = static_cast<int>(s);
    return i >= 0 && i < kStrategyCount ? kStrategyNames[i] : "unknown";
}

std::string to_string(BoundRule b) {
    const int i = static_cast<int>(b);
    return i >= 0 && i < kBoundRuleCount ? kBoundRuleNames[i] : "unknown";
}

Strategy parse_strategy(const std::string& name, const char* what) {
    for (int i = 0; i < kStrategyCount; ++i)
        if (name == kStrategyNames[i]) return static_cast<Strategy>(i);
    std::string all;
    for (int i = 0; i < kStrategyCount; ++i) all += std::string(i ? ", " : "") + kStrategyNames[i];
    bad(std::string(what) + ": unknown strategy '" + name + "'; expected one of " + all);
}

BoundRule parse_bound_rule(const std::string& name, const char* what) {
    for (int i = 0; i < kBoundRuleCount; ++i)
        if (name == kBoundRuleNames[i]) return static_cast<BoundRule>(i);
    bad(std::string(what) + ": unknown rule '" + name +
        "'; expected one of midpoint, reinit, reflect, clip");
}

std::string to_string(StopReason r) {
    switch (r) {
        case StopReason::none: return "none";
        case StopReason::target: return "target";
        case StopReason::converged: return "converged";
        case StopReason::stagnation: return "stagnation";
        case StopReason::generations: return "generations";
        case StopReason::evaluations: return "evaluations";
        case StopReason::time: return "time";
        case StopReason::callback: return "callback";
    }
    return "unknown";
}

// ===== settings ======================================================================================

int min_population_size(Strategy s) { return s == Strategy::best1bin ? 3 : 4; }

namespace {

bool uses_archive(Strategy s) {
    return s == Strategy::jade || s == Strategy::shade || s == Strategy::lshade ||
           s == Strategy::jso;
}
bool uses_memory(Strategy s) {
    return s == Strategy::shade || s == Strategy::lshade || s == Strategy::jso;
}
bool reduces_population(Strategy s) { return s == Strategy::lshade || s == Strategy::jso; }
bool adapts_F(Strategy s) { return s != Strategy::rand1bin && s != Strategy::best1bin; }

// The published default when `value` is NaN (double) or 0 (int); otherwise the value itself.
double pick(double value, double fallback) { return std::isnan(value) ? fallback : value; }
int pick(int value, int fallback) { return value == 0 ? fallback : value; }

void require_range(double v, double lo, double hi, bool lo_open, const std::string& name,
                   const std::string& strategy) {
    const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && v <= hi;
    if (!ok) {
        bad(name + ": " + str(v) + "; strategy '" + strategy + "' needs " +
            (lo_open ? "0 < " : str(lo) + " <= ") + name + " <= " + str(hi));
    }
}

constexpr int kMaxPopulation = 10'000'000;

}  // namespace

Settings resolve(Settings s) {
    const int si = static_cast<int>(s.strategy);
    if (si < 0 || si >= kStrategyCount) bad("strategy: invalid value " + str(si));
    const int bi = static_cast<int>(s.bound_rule);
    if (bi < 0 || bi >= kBoundRuleCount) bad("bound_rule: invalid value " + str(bi));
    const std::string name = to_string(s.strategy);
    const std::size_t d = s.lower.size();
    if (d == 0) bad("bounds: no parameter (lower is empty)");
    if (s.upper.size() != d)
        bad("bounds: upper has " + str(s.upper.size()) + " entries, lower " + str(d));
    for (std::size_t j = 0; j < d; ++j) {
        const double lo = s.lower[j], hi = s.upper[j];
        if (!(std::isfinite(lo) && std::isfinite(hi) && lo < hi)) {
            bad("bounds: parameter " + str(j) + " has lower " + str(lo) + ", upper " + str(hi) +
                "; expected finite bounds with lower < upper");
        }
        if (!std::isfinite(hi - lo)) bad("bounds: parameter " + str(j) + " has an infinite width");
    }
    const double D = static_cast<double>(d);
    const Strategy st = s.strategy;

    // Population size.
    int np_default = 0;
    switch (st) {
        case Strategy::rand1bin:
        case Strategy::best1bin: np_default = static_cast<int>(std::min(10.0 * D, 1e6)); break;
        case Strategy::jade: np_default = d <= 10 ? 30 : (d <= 30 ? 100 : 400); break;
        case Strategy::jde:
        case Strategy::shade: np_default = 100; break;
        case Strategy::lshade: np_default = static_cast<int>(std::lround(std::min(18.0 * D, 1e6))); break;
        case Strategy::jso:
            np_default = static_cast<int>(std::lround(std::min(25.0 * std::log(D) * std::sqrt(D), 1e6)));
            break;
    }
    np_default = std::max(np_default, min_population_size(st));
    if (s.population_size < 0)
        bad("population_size: " + str(s.population_size) + "; expected a positive integer");
    s.population_size = pick(s.population_size, np_default);
    if (s.population_size < min_population_size(st)) {
        bad("population_size: " + str(s.population_size) + "; strategy '" + name +
            "' needs at least " + str(min_population_size(st)) + " individuals");
    }
    if (s.population_size > kMaxPopulation)
        bad("population_size: " + str(s.population_size) + "; at most " + str(kMaxPopulation));

    // F and CR: the fixed values, or the initial values of what the strategy adapts.
    const double F_default = st == Strategy::jso ? 0.3 : 0.5;
    const double CR_default = st == Strategy::jso        ? 0.8
                              : (st == Strategy::jade || st == Strategy::shade ||
                                 st == Strategy::lshade) ? 0.5
                                                         : 0.9;
    s.F = pick(s.F, F_default);
    s.CR = pick(s.CR, CR_default);
    if (!(std::isfinite(s.F) && s.F > 0))
        bad("F: " + str(s.F) + "; expected a finite F > 0");
    if (adapts_F(st) && s.F > 1)
        bad("F: " + str(s.F) + "; strategy '" + name + "' adapts F within (0, 1]");
    if (!(s.CR >= 0 && s.CR <= 1)) bad("CR: " + str(s.CR) + "; expected 0 <= CR <= 1");

    // Strategy parameters: defaults, checks, and zero for those the strategy does not have, so
    // that resolved settings compare equal exactly when their trajectories are the same.
    if (st == Strategy::jade || st == Strategy::shade || st == Strategy::lshade ||
        st == Strategy::jso) {
        const double p_default = st == Strategy::jade    ? 0.05
                                 : st == Strategy::shade ? 0.2
                                 : st == Strategy::lshade ? 0.11
                                                          : 0.25;
        s.p_best = pick(s.p_best, p_default);
        require_range(s.p_best, 0, 1, true, "p_best", name);
        s.archive_rate = pick(s.archive_rate, st == Strategy::lshade ? 2.6 : 1.0);
        require_range(s.archive_rate, 0, 1e3, false, "archive_rate", name);
    } else {
        s.p_best = 0;
        s.archive_rate = 0;
    }
    if (st == Strategy::jade) {
        s.c = pick(s.c, 0.1);
        require_range(s.c, 0, 1, false, "c", name);
    } else {
        s.c = 0;
    }
    if (uses_memory(st)) {
        const int h_default = st == Strategy::shade ? 100 : (st == Strategy::lshade ? 6 : 5);
        if (s.memory_size < 0) bad("memory_size: " + str(s.memory_size) + "; expected >= 1");
        s.memory_size = pick(s.memory_size, h_default);
        const int h_min = st == Strategy::jso ? 2 : 1;
        if (s.memory_size < h_min || s.memory_size > 1'000'000) {
            bad("memory_size: " + str(s.memory_size) + "; strategy '" + name + "' needs " +
                str(h_min) + " <= memory_size <= 1000000");
        }
    } else {
        s.memory_size = 0;
    }
    if (st == Strategy::jde) {
        s.tau1 = pick(s.tau1, 0.1);
        s.tau2 = pick(s.tau2, 0.1);
        s.F_lower = pick(s.F_lower, 0.1);
        s.F_upper = pick(s.F_upper, 0.9);
        require_range(s.tau1, 0, 1, false, "tau1", name);
        require_range(s.tau2, 0, 1, false, "tau2", name);
        require_range(s.F_lower, 0, 2, true, "F_lower", name);
        require_range(s.F_upper, 0, 2, true, "F_upper", name);
    } else {
        s.tau1 = s.tau2 = s.F_lower = s.F_upper = 0;
    }
    if (reduces_population(st)) {
        if (s.min_population_size < 0)
            bad("min_population_size: " + str(s.min_population_size) + "; expected >= 4");
        s.min_population_size = pick(s.min_population_size, 4);
        if (s.min_population_size < 4 || s.min_population_size > s.population_size) {
            bad("min_population_size: " + str(s.min_population_size) + "; strategy '" + name +
                "' needs 4 <= min_population_size <= population_size (" +
                str(s.population_size) + ")");
        }
        if (s.max_evaluations < 0)
            bad("max_evaluations: " + str(s.max_evaluations) + "; expected a positive budget");
        if (s.max_evaluations == 0)
            s.max_evaluations = static_cast<std::int64_t>(std::min(10000.0 * D, 1e15));
        if (s.max_evaluations < s.population_size) {
            bad("max_evaluations: " + str(s.max_evaluations) + "; strategy '" + name +
                "' needs a budget of at least population_size (" + str(s.population_size) +
                ") evaluations");
        }
    } else {
        s.min_population_size = 0;
        s.max_evaluations = 0;
    }
    return s;
}

bool operator==(const Settings& a, const Settings& b) {
    return a.strategy == b.strategy && a.lower == b.lower && a.upper == b.upper &&
           a.seed == b.seed && a.population_size == b.population_size && a.F == b.F &&
           a.CR == b.CR && a.bound_rule == b.bound_rule && a.p_best == b.p_best && a.c == b.c &&
           a.archive_rate == b.archive_rate && a.memory_size == b.memory_size &&
           a.tau1 == b.tau1 && a.tau2 == b.tau2 && a.F_lower == b.F_lower &&
           a.F_upper == b.F_upper && a.min_population_size == b.min_population_size &&
           a.max_evaluations == b.max_evaluations;
}

// ===== objective adapter =============================================================================

namespace detail {

std::vector<int> active_index(int n, std::vector<bool> active, VectorXd& x0) {
    if (active.empty()) active.assign(static_cast<std::size_t>(n), true);
    if (static_cast<int>(active.size()) != n)
        bad("active: " + str(active.size()) + " flags; expected " + str(n));
    if (x0.size() == 0) x0 = VectorXd::Zero(n);
    if (x0.size() != n) bad("x0: " + str(x0.size()) + " values; expected " + str(n));
    require_finite(x0.data(), x0.size(), "x0");
    std::vector<int> index;
    for (int i = 0; i < n; ++i)
        if (active[static_cast<std::size_t>(i)]) index.push_back(i);
    if (index.empty()) bad("active: no parameter is active");
    return index;
}

}  // namespace detail

// ===== the engine ====================================================================================

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point t0) {
    return std::chrono::duration<double>(Clock::now() - t0).count();
}

// The costs c of the n rows of x (d values each) as the engine ranks them: NaN counts as +inf
// (the worst: a point the objective cannot evaluate is never selected). A cost of -inf is no
// point's cost (iwr's are sums of squares; a minimum is finite): std::invalid_argument naming the
// row, its cost and its vector, where it would otherwise be a best cost no trial can improve on,
// "reaching" any target (the default one, -inf, too). `what` names the rows: "population" or
// "trial". Reads the costs only (and writes +inf over NaN): the run's bits are unchanged.
// nan_to_inf: the first half, for rows [b, e) (the generation's pass, each thread its rows);
// whether one of them is -inf.
bool nan_to_inf(double* c, std::size_t b, std::size_t e) {
    bool minus_inf = false;
    for (std::size_t i = b; i < e; ++i) {
        if (std::isnan(c[i])) c[i] = std::numeric_limits<double>::infinity();
        minus_inf |= c[i] == -std::numeric_limits<double>::infinity();
    }
    return minus_inf;
}
void sanitize(const double* x, int d, double* c, std::size_t n, const char* what) {
    if (!nan_to_inf(c, 0, n)) return;
    for (std::size_t i = 0; i < n; ++i) {
        if (c[i] == -std::numeric_limits<double>::infinity()) {
            constexpr int kShown = 12;
            const double* xi = x + i * static_cast<std::size_t>(d);
            std::string v;
            for (int j = 0; j < std::min(d, kShown); ++j) v += (j ? ", " : "") + str(xi[j]);
            if (d > kShown) v += ", ... (" + str(d) + " values)";
            bad("objective: cost -inf at x = [" + v + "] (" + what + " row " + str(i) +
                "); a cost must be a number or +inf (NaN counts as +inf): -inf is no minimum, "
                "check the objective");
        }
    }
}

int initial_np(const State& st) { return static_cast<int>(st.streams.size()) - 1; }

int archive_capacity(const State& st) {
    return static_cast<int>(std::lround(st.settings.archive_rate * st.np));
}

// Adds a parent to the archive; a full archive replaces a random member (serial stream), as JADE
// ("randomly remove solutions") and Tanabe & Fukunaga's code.
void archive_push(State& st, const double* x) {
    const int cap = archive_capacity(st);
    const std::size_t d = static_cast<std::size_t>(st.dim());
    if (cap <= 0) return;
    std::size_t slot;
    if (st.archive_count < cap) {
        slot = static_cast<std::size_t>(st.archive_count++);
        st.archive.resize(static_cast<std::size_t>(st.archive_count) * d);
    } else {
        slot = static_cast<std::size_t>(st.streams[0].below(static_cast<std::uint64_t>(st.archive_count)));
    }
    std::copy(x, x + d, st.archive.begin() + static_cast<std::ptrdiff_t>(slot * d));
}

// Shrinks the archive to its capacity by removing random members.
void archive_trim(State& st) {
    const int cap = std::max(archive_capacity(st), 0);
    const std::size_t d = static_cast<std::size_t>(st.dim());
    while (st.archive_count > cap) {
        const std::size_t r =
            static_cast<std::size_t>(st.streams[0].below(static_cast<std::uint64_t>(st.archive_count)));
        const std::size_t last = static_cast<std::size_t>(st.archive_count - 1);
        if (r != last)
            std::copy(st.archive.begin() + static_cast<std::ptrdiff_t>(last * d),
                      st.archive.begin() + static_cast<std::ptrdiff_t>((last + 1) * d),
                      st.archive.begin() + static_cast<std::ptrdiff_t>(r * d));
        --st.archive_count;
        st.archive.resize(static_cast<std::size_t>(st.archive_count) * d);
    }
}

// The log's spread: sums of squared deviations from the mean of each column of the population,
// in one pass over the rows: with y = x - c, c the column's value in the row `shift` (a member of
// the population: its row 0 after the generation's selection), sum (x - mean)^2 = sum y^2
// - (sum y) (sum y / np) (the shifted-data formula; two passes, the mean first, read the
// population twice from L2: BENCHMARKS.md, fifteenth round). The cancellation loses a factor
// (1 + k^2) of the sums' precision, k the shift's distance from the mean in standard deviations:
// about 1 for a member of the population, and 0 for a converged cluster, where the rounded mean of
// two passes lost everything (a spread of 1e-16 for identical rows); a member that is an outlier
// (k up to sqrt(np)) loses a factor np (3e-12 relative at np = 600,
// emulated). A negative difference (rounding) is 0; NaN stays NaN. The sums are taken over blocks
// of rows (append_log) and added block by block. Within a block the columns are NV vectors of L
// doubles and a last vector of T < L columns, all in the one pass, the counts constants: a pass is
// as long as one column's chain of dependent adds, whatever the count. Written with vectors
// because the compiler, left to group a count such as 10 or 26 itself, turned the last columns
// into scalar adds fed by loads gathered across rows. L is the width of the registers of the
// clone the CPU runs (clone_lanes: 8 AVX-512, 4 AVX2, 2 SSE2) and a pass takes 4 L columns
// (log_window), so that the shift and the two sums of a pass (12 registers) stay in the
// registers: one width for every clone (8, and 32 columns a pass) spilled them to the stack row by
// row in AVX2's and SSE2's 16 registers and moved lanes through general registers; the log was
// 45 % of DE's own work on a Zen 3 (BENCHMARKS.md, twenty-third round). The grouping does not
// change a column's sums: every clone and every number of threads gives the same bits.
inline int log_window() { return 4 * clone_lanes(); }
#if defined(__GNUC__)
template <int L>
struct LanesOf {  // (an alias template drops the attribute)
    typedef double type __attribute__((vector_size(L * sizeof(double))));
};
template <int L>
using Lanes = typename LanesOf<L>::type;
#else
template <int L>
struct Lanes {
    double v[L];
    double& operator[](int k) { return v[k]; }
    double operator[](int k) const { return v[k]; }
    Lanes& operator+=(const Lanes& o) {
        for (int k = 0; k < L; ++k) v[k] += o.v[k];
        return *this;
    }
    Lanes operator-(const Lanes& o) const {
        Lanes r;
        for (int k = 0; k < L; ++k) r.v[k] = v[k] - o.v[k];
        return r;
    }
    Lanes operator*(const Lanes& o) const {
        Lanes r;
        for (int k = 0; k < L; ++k) r.v[k] = v[k] * o.v[k];
        return r;
    }
};
#endif
// The first n <= L doubles at x into r, its other lanes 0. (A reference, not a return value:
// a vector returned by value has another ABI with AVX-512, which GCC warns of.)
template <int L, int n>
IWR_FORCE_INLINE void load_lanes(const double* x, Lanes<L>& r) {
    if (n == L) {
        std::memcpy(&r, x, sizeof r);
    } else {
        r = Lanes<L>{};
        for (int k = 0; k < n; ++k) r[k] = x[k];
    }
}
// Sums over rows [0, nr) of x (row k at x + k * stride) of y and y^2, y = x - shift, for columns
// [j0, j0 + NV L + T), into s1 and s2 (indexed by column).
template <int L, int NV, int T>
IWR_FORCE_INLINE void column_sums(const double* x0, int stride, int nr, const double* shift,
                                  int j0, double* s1o, double* s2o) {
    constexpr int nv = NV + (T > 0 ? 1 : 0);
    Lanes<L> c[nv], s1[nv] = {}, s2[nv] = {}, t = {};
    for (int g = 0; g < NV; ++g) {
        // Through t: in CI's -O0 sanitizer build GCC took a memcpy into c[g] for an overflow.
        load_lanes<L, L>(shift + j0 + g * L, t);
        c[g] = t;
    }
    if (T > 0) {
        load_lanes<L, T>(shift + j0 + NV * L, t);
        c[nv - 1] = t;
    }
    for (int i = 0; i < nr; ++i) {
        const double* x = x0 + static_cast<std::ptrdiff_t>(i) * stride + j0;
        for (int g = 0; g < NV; ++g) {
            load_lanes<L, L>(x + g * L, t);
            t = t - c[g];
            s1[g] += t;
            s2[g] += t * t;
        }
        if (T > 0) {
            load_lanes<L, T>(x + NV * L, t);
            t = t - c[nv - 1];
            s1[nv - 1] += t;
            s2[nv - 1] += t * t;
        }
    }
    // Whole vectors stored (each pass of each of the 16 blocks, every generation). Where the last
    // pass was moved back (append_log), its first columns, which the pass before wrote, are
    // written again with the same bits: each column's arithmetic is the same in any lane.
    if constexpr (NV > 0) {  // (else GCC's -O0 sanitizer build warns of the dead copies)
        for (int g = 0; g < NV; ++g) {
            std::memcpy(s1o + j0 + g * L, &s1[g], sizeof s1[g]);
            std::memcpy(s2o + j0 + g * L, &s2[g], sizeof s2[g]);
        }
    }
    for (int k = 0; k < T; ++k) {
        s1o[j0 + NV * L + k] = s1[nv - 1][k];
        s2o[j0 + NV * L + k] = s2[nv - 1][k];
    }
}

// Columns [j0, j0 + nc) of the sums, 1 <= nc <= 4 L: the counts constants in each case, so
// that the sums of a pass narrower than 4 L stay in vector registers too.
template <int L, int... N>
IWR_FORCE_INLINE void column_cases(std::integer_sequence<int, N...>, const double* x0, int stride,
                                   int nr, const double* shift, int j0, int nc,
                                   double* s1, double* s2) {
    ((nc == N + 1
          ? column_sums<L, (N + 1) / L, (N + 1) % L>(x0, stride, nr, shift, j0, s1, s2)
          : void()),
     ...);
}
IWR_CLONES void column_block(const double* x0, int stride, int nr, const double* shift, int j0,
                             int nc, double* s1, double* s2) {
    switch (clone_lanes()) {
        case 8:
            column_cases<8>(std::make_integer_sequence<int, 32>(), x0, stride, nr, shift, j0, nc,
                            s1, s2);
            break;
        case 4:
            column_cases<4>(std::make_integer_sequence<int, 16>(), x0, stride, nr, shift, j0, nc,
                            s1, s2);
            break;
        default:
            column_cases<2>(std::make_integer_sequence<int, 8>(), x0, stride, nr, shift, j0, nc,
                            s1, s2);
    }
}

// The log's row blocks: a number fixed whatever the threads (so the sums, added block by block in
// order, are the same bits with any number of threads), and enough of them for the pool's
// threads to take each about the blocks of the slots it built the trials of (block k is rows
// [np k / nb, np (k + 1) / nb); parallel_for_dynamic gives thread t first the slots from about
// np t / T on, and parallel_for here the blocks of about those rows: exactly where T divides 16;
// not after L-SHADE's and jSO's reduction, which moves the rows).
constexpr int kLogBlocks = 16;

// A generation's trials not yet in the population, for append_log: either selected already
// (taken[i]: row i of trials replaces the population's, its cost set) or selected in the log's
// pass (taken null; the strategies without an archive: trial i, i < ne, replaces its parent where
// tcost[i] <= costs(i), and jDE's slot takes its F and CR).
struct Pending {
    const RowMatrixXd* trials = nullptr;
    const std::vector<char>* taken = nullptr;
    const double *tcost = nullptr, *tF = nullptr, *tCR = nullptr;
    int ne = 0;
};

// The log row of the current population, and st.elapsed (+= the time since t0, the log
// included), with the generation's pending trials (or none) put into the population. One pass of
// the pool over the rows in kLogBlocks blocks: the thread that takes a block selects or copies its
// trials, then takes the block's smallest cost, the sum of its costs and its rows' sums column by
// column (each in slot order within the block); the blocks' figures are
// then combined in block order. A thread so reads and writes the rows and costs of the slots whose
// trials it built, where they are (its cache), not the other threads'. The deviations are taken
// from row 0 of the population the log describes (a member of it: the shift keeps the sums of
// squares from cancelling), copied before the pass.
void append_log(State& st, ThreadPool& pool, Clock::time_point t0, const Pending* pending = nullptr) {
    LogEntry e;
    e.generation = st.generation;
    e.nfev = st.nfev;
    const int np = st.np;
    const int d = st.dim();
    const int nb = std::min(np, kLogBlocks);
    const auto nd = static_cast<std::size_t>(d);
    // Per block: s1 and s2 (d each), then the smallest cost and the costs' sum; then the shift.
    const std::size_t per = 2 * nd + 2;
    const std::unique_ptr<double[]> part(new double[per * static_cast<std::size_t>(nb) + nd]);
    double* shift = part.get() + per * static_cast<std::size_t>(nb);
    // Row 0 as it is after the pass (a member of the population the log describes: the old row 0,
    // where its trial replaces it, may be far from the rest and ruined the sums' precision).
    bool taken0 = false;
    if (pending && pending->taken) taken0 = (*pending->taken)[0] != 0;
    else if (pending) taken0 = pending->ne > 0 && pending->tcost[0] <= st.costs(0);
    std::memcpy(shift, taken0 ? pending->trials->row(0).data() : st.population.row(0).data(),
                nd * sizeof(double));
    // Passes of `window` columns; where d is not a multiple, the last pass is moved back to end at
    // column d (its first columns computed again with the same arithmetic, the same bits), so that
    // every pass but one of a narrower problem is full width: no lanes loaded one by one.
    const int window = std::min(log_window(), d);
    const int passes = (d + window - 1) / window;
    const bool jde = st.settings.strategy == Strategy::jde;
    pool.parallel_for(static_cast<std::size_t>(nb), [&](std::size_t b, std::size_t end, int) {
        for (std::size_t k = b; k < end; ++k) {
            const auto unp = static_cast<std::size_t>(np), unb = static_cast<std::size_t>(nb);
            const auto r0 = static_cast<Eigen::Index>(unp * k / unb);
            const auto r1 = static_cast<Eigen::Index>(unp * (k + 1) / unb);
            if (pending && pending->taken) {
                for (Eigen::Index i = r0; i < r1; ++i)
                    if ((*pending->taken)[static_cast<std::size_t>(i)])
                        st.population.row(i) = pending->trials->row(i);
            } else if (pending) {
                const auto e1 = std::min<Eigen::Index>(r1, pending->ne);
                for (Eigen::Index i = r0; i < e1; ++i) {
                    // Eq. (14).
                    if (!(pending->tcost[i] <= st.costs(i))) continue;
                    st.population.row(i) = pending->trials->row(i);
                    st.costs(i) = pending->tcost[i];
                    if (jde) {
                        st.ind_F[static_cast<std::size_t>(i)] = pending->tF[i];
                        st.ind_CR[static_cast<std::size_t>(i)] = pending->tCR[i];
                    }
                }
            }
            double* s1 = part.get() + per * k;
            double best = st.costs(r0), sum = 0;
            for (Eigen::Index i = r0; i < r1; ++i) {
                const double c = st.costs(i);
                sum += c;
                best = c < best ? c : best;
            }
            s1[2 * nd] = best;
            s1[2 * nd + 1] = sum;
            for (int p = 0; p < passes; ++p) {
                const int first = p * window;
                const int j0 = std::min(first, d - window);
                column_block(st.population.row(r0).data(), d, static_cast<int>(r1 - r0), shift, j0,
                             window, s1, s1 + nd);
            }
        }
    });
    std::vector<double> s1(part.get(), part.get() + nd), s2(part.get() + nd, part.get() + 2 * nd);
    e.best = part[2 * nd];
    double sum = part[2 * nd + 1];
    for (int k = 1; k < nb; ++k) {
        const double* p = part.get() + per * static_cast<std::size_t>(k);
        for (std::size_t j = 0; j < nd; ++j) s1[j] += p[j], s2[j] += p[nd + j];
        if (p[2 * nd] < e.best) e.best = p[2 * nd];
        sum += p[2 * nd + 1];
    }
    e.mean = sum / np;
    double acc = 0;
    for (std::size_t j = 0; j < nd; ++j) {
        double v = s2[j] - s1[j] * (s1[j] / np);
        v = v < 0 ? 0.0 : v;
        const double w = st.settings.upper[j] - st.settings.lower[j];
        acc += v / np / (w * w);
    }
    e.spread = std::sqrt(acc / d);
    st.elapsed += seconds_since(t0);
    e.elapsed = st.elapsed;
    st.log.push_back(e);
}

// Truncated Cauchy of JADE/SHADE: regenerated while <= 0, cut at 1.
double sample_F(Rng& g, double loc) {
    double F;
    do {
        F = g.cauchy(loc, 0.1);
    } while (!(F > 0));
    return std::min(F, 1.0);
}

double sample_CR(Rng& g, double loc) {
    if (loc < 0) return 0.0;  // the terminal value of L-SHADE's memory
    return std::clamp(g.normal(loc, 0.1), 0.0, 1.0);
}

// Rng::below(n) with its rejection threshold (2^64 mod n, a division) computed once: the same
// draws, for the n every trial uses (NP, D).
struct Below {
    std::uint64_t n = 1, threshold = 0;
    Below() = default;
    explicit Below(std::uint64_t n_) : n(n_), threshold((0 - n_) % n_) {}
    std::uint64_t operator()(Rng& g) const {
        for (;;) {
            const std::uint64_t r = xoshiro_next(g.s);
            if (r >= threshold) return r % n;
        }
    }
};

// Everything a slot's trial needs that is computed once per generation.
struct Generation {
    const State* st;
    Rng* drawn;  // st->drawn: slot i's stream copied to drawn[1 + i], its draws taken there
    std::vector<int> order;  // the best population indices by cost, ties by index
    int pnum = 2;            // size of the p-best set (fixed-p strategies)
    double progress = 0;     // NFE / NFE_max (lshade, jso)
    Below below_np, below_d;  // draws in [0, np) and [0, D)
};

// A trial's component v repaired by the midpoint (Mid) or the clip rule where it is out of the
// bounds, branch-free (a mutant component leaves the bounds at random, so a branch would be
// mispredicted often): the same values as the general loop of build_trial (xi, the parent's
// component, is within the bounds). repair_simple: every component of u.
template <bool Mid>
IWR_FORCE_INLINE double repaired(double v, double xi, double l, double h) {
    const double bound = v < l ? l : h;
    double r = Mid ? 0.5 * (xi + bound) : bound;
    r = r < l ? l : r;  // a no-op but for rounding; r is never NaN
    r = h < r ? h : r;
    const bool inside = (v >= l) & (v <= h);
    return inside ? v : r;
}
template <bool Mid>
IWR_FORCE_INLINE void repair_simple(double* __restrict u, const double* __restrict xi,
                                    const double* __restrict lo, const double* __restrict hi,
                                    int d) {
    for (int j = 0; j < d; ++j) u[j] = repaired<Mid>(u[j], xi[j], lo[j], hi[j]);
}

// The mutant of the rows a trial combines (eq. 12, or the strategy's rule with the
// current-to-pbest term where PBest) into u, each component repaired by the midpoint (Mid) or the
// clip rule where Repair (a trial without crossover): one pass over the components instead of
// two, the same values as the mutant followed by repair_simple (BENCHMARKS.md, sixteenth
// round).
template <bool PBest, bool Repair, bool Mid = false>
IWR_FORCE_INLINE void mutant(double* __restrict u, const double* __restrict xi,
                             const double* __restrict base, const double* __restrict pbest,
                             const double* __restrict d1, const double* __restrict d2, double Fi,
                             double Fw, const double* __restrict lo, const double* __restrict hi,
                             int d) {
    for (int j = 0; j < d; ++j) {
        const double v = PBest ? base[j] + Fw * (pbest[j] - xi[j]) + Fi * (d1[j] - d2[j])
                               : base[j] + Fi * (d1[j] - d2[j]);
        u[j] = Repair ? repaired<Mid>(v, xi[j], lo[j], hi[j]) : v;
    }
}

// What slot i's trial draws before it reads the population: the rows its mutant combines and its
// F and CR. make_trials draws the plans of the next slots ahead of building a trial, so that their
// rows are on their way to the cache (prefetched) when the trial reads them: a trial otherwise
// waited on the three random rows it reads, from L2.
struct Plan {
    const double* base = nullptr;
    const double *d1 = nullptr, *d2 = nullptr;  // difference vector d1 - d2
    const double* pbest = nullptr;
    double Fi = 0, CRi = 0;
    double Fw = 0;  // weight of (pbest - xi)
};

// The first draws of slot i's trial, from its stream, in the order of the strategy's rule.
IWR_FORCE_INLINE void plan_trial(const Generation& gen, int i, Plan& plan) {
    const State& st = *gen.st;
    const Settings& s = st.settings;
    Rng& g = gen.drawn[static_cast<std::size_t>(i) + 1];
    g = st.streams[static_cast<std::size_t>(i) + 1];  // the slot's first draws
    const int np = st.np;
    const int d = st.dim();
    const auto NP = static_cast<std::uint64_t>(np);
    const double* xi = st.population.row(i).data();
    auto row = [&](int k) { return st.population.row(k).data(); };
    const Below& below_np = gen.below_np;
    auto draw_other = [&](int a, int b, int c) {  // uniform in [0, np) \ {a, b, c}
        int r;
        do {
            r = static_cast<int>(below_np(g));
        } while (r == a || r == b || r == c);
        return r;
    };
    const double*& base = plan.base;
    const double*& d1 = plan.d1;
    const double*& d2 = plan.d2;
    const double*& pbest = plan.pbest;
    double& Fi = plan.Fi;
    double& CRi = plan.CRi;
    double& Fw = plan.Fw;
    switch (s.strategy) {
        case Strategy::rand1bin:
        case Strategy::jde: {
            Fi = s.F;
            CRi = s.CR;
            if (s.strategy == Strategy::jde) {
                // Brest et al. 2006, eq. (10)-(11): rand1..rand4 in this order.
                const double r1 = g.uniform(), r2 = g.uniform();
                Fi = r2 < s.tau1 ? s.F_lower + r1 * s.F_upper : st.ind_F[static_cast<std::size_t>(i)];
                const double r3 = g.uniform(), r4 = g.uniform();
                CRi = r4 < s.tau2 ? r3 : st.ind_CR[static_cast<std::size_t>(i)];
            }
            // eq. (12): r1, r2, r3, i all distinct.
            const int r1 = draw_other(i, i, i);
            const int r2 = draw_other(i, r1, r1);
            const int r3 = draw_other(i, r1, r2);
            base = row(r1);
            d1 = row(r2);
            d2 = row(r3);
            break;
        }
        case Strategy::best1bin: {
            Fi = s.F;
            CRi = s.CR;
            const int r1 = draw_other(i, i, i);
            const int r2 = draw_other(i, r1, r1);
            base = row(gen.order[0]);
            d1 = row(r1);
            d2 = row(r2);
            break;
        }
        case Strategy::jade:
        case Strategy::shade:
        case Strategy::lshade:
        case Strategy::jso: {
            int pnum = gen.pnum;
            if (s.strategy == Strategy::jade) {
                CRi = sample_CR(g, st.mu_CR);
                Fi = sample_F(g, st.mu_F);
            } else {
                const int h = s.memory_size;
                const int r = static_cast<int>(g.below(static_cast<std::uint64_t>(h)));
                double mF = st.mem_F[static_cast<std::size_t>(r)];
                double mCR = st.mem_CR[static_cast<std::size_t>(r)];
                if (s.strategy == Strategy::jso && r == h - 1) mF = mCR = 0.9;  // fixed slot
                CRi = sample_CR(g, mCR);
                Fi = sample_F(g, mF);
                if (s.strategy == Strategy::jso) {
                    if (gen.progress < 0.25) CRi = std::max(CRi, 0.7);
                    else if (gen.progress < 0.5) CRi = std::max(CRi, 0.6);
                    if (gen.progress < 0.6) Fi = std::min(Fi, 0.7);
                }
                if (s.strategy == Strategy::shade) {
                    // p_i ~ U[2/NP, p_max] (Tanabe & Fukunaga 2013).
                    const double p = g.uniform(2.0 / np, std::max(s.p_best, 2.0 / np));
                    pnum = std::max(2, static_cast<int>(std::lround(p * np)));
                    pnum = std::min(pnum, np);
                }
            }
            int pb = gen.order[static_cast<std::size_t>(g.below(static_cast<std::uint64_t>(pnum)))];
            if (s.strategy == Strategy::jso) {
                while (gen.progress < 0.5 && pb == i)
                    pb = gen.order[static_cast<std::size_t>(g.below(static_cast<std::uint64_t>(pnum)))];
            }
            Fw = Fi;
            if (s.strategy == Strategy::jso)
                Fw = Fi * (gen.progress < 0.2 ? 0.7 : (gen.progress < 0.4 ? 0.8 : 1.2));
            const int r1 = draw_other(i, i, i);
            // r2 from population + archive, distinct from i and r1.
            const auto total = NP + static_cast<std::uint64_t>(st.archive_count);
            int r2;
            do {
                r2 = static_cast<int>(g.below(total));
            } while (r2 == i || r2 == r1);
            base = xi;
            pbest = row(pb);
            d1 = row(r1);
            d2 = r2 < np ? row(r2)
                         : st.archive.data() + static_cast<std::size_t>(r2 - np) * static_cast<std::size_t>(d);
            break;
        }
    }
}

// The rows a plan reads, prefetched into the cache.
IWR_FORCE_INLINE void prefetch_plan(const Plan& plan, int d) {
#if defined(__GNUC__)
    const std::size_t bytes = static_cast<std::size_t>(d) * sizeof(double);
    for (const double* r : {plan.base, plan.d1, plan.d2, plan.pbest}) {
        if (!r) continue;
        const char* c = reinterpret_cast<const char*>(r);
        __builtin_prefetch(c);
        __builtin_prefetch(c + bytes / 2);
        __builtin_prefetch(c + bytes - 1);
    }
#else
    (void)plan, (void)d;
#endif
}

// Binomial crossover, eq. (13): component j of u (the mutant) is kept where the stream's next
// uniform draw is below CR, or j == jr, and is xi's otherwise. The draws first, then the choice
// in a branch-free loop, kCrossChunk components at a time: a draw is below CR at random, so a
// branch on it was mispredicted most of the time (the adaptive strategies' trials spent 200 ns of
// their 300 in this loop: BENCHMARKS.md, thirty-fourth round). Not inlined: its buffer in
// make_trials' frame slowed the trials without crossover (CR = 1, the paper's) by 1 us a
// generation.
IWR_CLONES IWR_NOINLINE void crossover(Rng& g, double CRi, int jr, const double* __restrict xi,
                                       double* __restrict u, int d) {
    constexpr int kCrossChunk = 64;
    double r[kCrossChunk];
    for (int j0 = 0; j0 < d; j0 += kCrossChunk) {
        const int n = std::min(kCrossChunk, d - j0);
        for (int k = 0; k < n; ++k) r[k] = uniform_of(g);
        double* __restrict uj = u + j0;
        const double* __restrict xj = xi + j0;
        // The choice on the bits (a mask): with `take ? u : x` GCC made the baseline clone's loop
        // a branch again (SSE2 has no blend); the bits' and/or is vectorized in every clone.
        for (int k = 0; k < n; ++k) {
            const bool take = (r[k] < CRi) | (j0 + k == jr);
            std::uint64_t a, b;
            std::memcpy(&a, uj + k, sizeof a);
            std::memcpy(&b, xj + k, sizeof b);
            const std::uint64_t m = 0 - static_cast<std::uint64_t>(take);
            const std::uint64_t c = (a & m) | (b & ~m);
            std::memcpy(uj + k, &c, sizeof c);
        }
    }
}

// Builds the trial of slot i into u from its plan (the rest of its draws from its stream).
IWR_FORCE_INLINE void build_trial(const Generation& gen, int i, const Plan& plan, double* u) {
    const State& st = *gen.st;
    const Settings& s = st.settings;
    Rng& g = gen.drawn[static_cast<std::size_t>(i) + 1];  // after plan_trial's draws
    const int d = st.dim();
    const double* xi = st.population.row(i).data();
    const double* base = plan.base;
    const double *d1 = plan.d1, *d2 = plan.d2;
    const double* pbest = plan.pbest;
    const double Fi = plan.Fi, CRi = plan.CRi, Fw = plan.Fw;
    const bool simple_bounds = s.bound_rule == BoundRule::midpoint || s.bound_rule == BoundRule::clip;
    const bool mid = s.bound_rule == BoundRule::midpoint;
    const double* lower = s.lower.data();
    const double* upper = s.upper.data();
    // The forced index j_r of the binomial crossover (eq. 13), drawn whatever CR.
    const int jr = static_cast<int>(gen.below_d(g));
    if (CRi >= 1 && simple_bounds) {  // no crossover: the mutant repaired in the same pass
        if (mid && pbest) mutant<true, true, true>(u, xi, base, pbest, d1, d2, Fi, Fw, lower, upper, d);
        else if (mid) mutant<false, true, true>(u, xi, base, pbest, d1, d2, Fi, Fw, lower, upper, d);
        else if (pbest) mutant<true, true>(u, xi, base, pbest, d1, d2, Fi, Fw, lower, upper, d);
        else mutant<false, true>(u, xi, base, pbest, d1, d2, Fi, Fw, lower, upper, d);
        return;
    }
    // The mutant (eq. 12 or the strategy's rule) for every component: a branch-free loop.
    if (pbest) {
        mutant<true, false>(u, xi, base, pbest, d1, d2, Fi, Fw, lower, upper, d);
    } else {
        mutant<false, false>(u, xi, base, pbest, d1, d2, Fi, Fw, lower, upper, d);
    }
    // Binomial crossover, eq. (13). With CR = 1 every component comes from the mutant whatever the
    // draws, so none are made (the paper's setting).
    if (CRi < 1) crossover(g, CRi, jr, xi, u, d);
    // Out-of-bounds components (only mutated ones can be) are repaired by the bound rule, in
    // index order. midpoint and clip draw nothing: a branch-free loop (a mutant component leaves
    // the bounds at random, so a branch would be mispredicted often), with the same values as the
    // general loop below.
    if (simple_bounds) {
        if (mid) {
            repair_simple<true>(u, xi, lower, upper, d);
        } else {
            repair_simple<false>(u, xi, lower, upper, d);
        }
        return;
    }
    for (int j = 0; j < d; ++j) {
        const double lo = s.lower[static_cast<std::size_t>(j)];
        const double hi = s.upper[static_cast<std::size_t>(j)];
        double v = u[j];
        if (v >= lo && v <= hi) continue;
        const double bound = v < lo ? lo : hi;
        switch (s.bound_rule) {
            case BoundRule::midpoint: v = 0.5 * (xi[j] + bound); break;
            case BoundRule::reinit: v = g.uniform(lo, hi); break;
            case BoundRule::reflect:
                v = 2 * bound - v;
                v = std::clamp(v, lo, hi);
                break;
            case BoundRule::clip: v = bound; break;
        }
        if (!(v >= lo && v <= hi)) v = std::clamp(std::isnan(v) ? xi[j] : v, lo, hi);
        u[j] = v;
    }
}

// The trials of slots [b, e) into the rows of trials (d each), their F and CR into tF, tCR; each
// slot's plan drawn kAhead slots before its trial is built (slot i's draws come from stream 1 + i
// alone, in the same order: the same trials as drawn one slot at a time).
constexpr int kAhead = 4;
IWR_CLONES void make_trials(const Generation& gen, int b, int e, double* trials, double* tF,
                               double* tCR) {
    const int d = gen.st->dim();
    Plan plans[kAhead];
    for (int k = b; k < std::min(b + kAhead, e); ++k) {
        plan_trial(gen, k, plans[k % kAhead]);
        prefetch_plan(plans[k % kAhead], d);
    }
    for (int i = b; i < e; ++i) {
        const Plan plan = plans[i % kAhead];
        if (i + kAhead < e) {
            Plan& next = plans[(i + kAhead) % kAhead];
            plan_trial(gen, i + kAhead, next);
            prefetch_plan(next, d);
        }
        build_trial(gen, i, plan, trials + static_cast<std::size_t>(i) * static_cast<std::size_t>(d));
        tF[i] = plan.Fi;
        tCR[i] = plan.CRi;
    }
}

// Weighted (Lehmer) means of SHADE: weights |f(u) - f(x)| normalised.
struct Success {
    std::vector<double> F, CR, w;
    void clear() { F.clear(), CR.clear(), w.clear(); }
    std::vector<double> weights() const {
        double sum = 0;
        for (double v : w) sum += v;
        std::vector<double> out(w.size());
        if (std::isfinite(sum) && sum > 0) {
            for (std::size_t k = 0; k < w.size(); ++k) out[k] = w[k] / sum;
        } else {  // infinite improvements (from an infinite cost), or none: equal weights
            std::size_t n = 0;
            for (double v : w) n += std::isinf(v) || !(sum > 0) ? 1 : 0;
            for (std::size_t k = 0; k < w.size(); ++k)
                out[k] = (std::isinf(w[k]) || !(sum > 0)) ? 1.0 / static_cast<double>(n) : 0.0;
        }
        return out;
    }
    static double lehmer(const std::vector<double>& v, const std::vector<double>& wt) {
        double num = 0, den = 0;
        for (std::size_t k = 0; k < v.size(); ++k) num += wt[k] * v[k] * v[k], den += wt[k] * v[k];
        return den > 0 ? num / den : 0.0;
    }
    static double arithmetic(const std::vector<double>& v, const std::vector<double>& wt) {
        double s = 0;
        for (std::size_t k = 0; k < v.size(); ++k) s += wt[k] * v[k];
        return s;
    }
};

void update_memories(State& st, const Success& succ) {
    const Settings& s = st.settings;
    if (succ.F.empty()) return;
    switch (s.strategy) {
        case Strategy::jade: {
            // Zhang & Sanderson 2009, eq. (16)-(18).
            double sum = 0, num = 0, den = 0;
            for (std::size_t k = 0; k < succ.F.size(); ++k) {
                sum += succ.CR[k];
                num += succ.F[k] * succ.F[k];
                den += succ.F[k];
            }
            st.mu_CR = (1 - s.c) * st.mu_CR + s.c * sum / static_cast<double>(succ.CR.size());
            st.mu_F = (1 - s.c) * st.mu_F + s.c * (num / den);
            break;
        }
        case Strategy::shade:
        case Strategy::lshade:
        case Strategy::jso: {
            const std::vector<double> wt = succ.weights();
            const auto k = static_cast<std::size_t>(st.mem_pos);
            const double mF = Success::lehmer(succ.F, wt);
            const double maxCR = *std::max_element(succ.CR.begin(), succ.CR.end());
            if (s.strategy == Strategy::shade) {
                st.mem_CR[k] = Success::arithmetic(succ.CR, wt);
                st.mem_F[k] = mF;
            } else {
                // The terminal value when every successful CR is 0 (Tanabe & Fukunaga's code:
                // the slot leaves it at its next update).
                const bool terminal = maxCR == 0;
                const double mCR = Success::lehmer(succ.CR, wt);
                if (s.strategy == Strategy::lshade) {
                    st.mem_CR[k] = terminal ? -1.0 : mCR;
                    st.mem_F[k] = mF;
                } else {  // jSO (iL-SHADE): the mean of the new and the old value
                    st.mem_CR[k] = terminal ? -1.0 : 0.5 * (mCR + st.mem_CR[k]);
                    st.mem_F[k] = 0.5 * (mF + st.mem_F[k]);
                }
            }
            st.mem_pos = (st.mem_pos + 1) % s.memory_size;
            break;
        }
        default: break;
    }
}

// L-SHADE's linear population size reduction: the worst individuals go (ties: the later slot).
void reduce_population(State& st) {
    const Settings& s = st.settings;
    const double n0 = initial_np(st), nmin = s.min_population_size;
    const double frac = std::min(1.0, static_cast<double>(st.nfev) / static_cast<double>(s.max_evaluations));
    const int plan = std::max(s.min_population_size,
                              static_cast<int>(std::lround((nmin - n0) * frac + n0)));
    if (st.np <= plan) return;
    std::vector<int> idx(static_cast<std::size_t>(st.np));
    std::iota(idx.begin(), idx.end(), 0);
    std::sort(idx.begin(), idx.end(), [&](int a, int b) {
        return st.costs(a) < st.costs(b) || (st.costs(a) == st.costs(b) && a < b);
    });
    std::vector<char> keep(static_cast<std::size_t>(st.np), 0);
    for (int k = 0; k < plan; ++k) keep[static_cast<std::size_t>(idx[static_cast<std::size_t>(k)])] = 1;
    int w = 0;
    for (int i = 0; i < st.np; ++i) {
        if (!keep[static_cast<std::size_t>(i)]) continue;
        if (w != i) {
            st.population.row(w) = st.population.row(i);
            st.costs(w) = st.costs(i);
        }
        ++w;
    }
    st.np = plan;
    st.population.conservativeResize(plan, Eigen::NoChange);
    st.costs.conservativeResize(plan);
    archive_trim(st);
}

void check_dim(const State& st, const BatchFunction& f) {
    if (f.dim() != st.dim()) {
        bad("function: dimension " + str(f.dim()) + "; the settings' bounds have " +
            str(st.dim()) + " parameters");
    }
}

}  // namespace

int State::best_index() const {
    int b = 0;
    for (int i = 1; i < np; ++i)
        if (costs(i) < costs(b)) b = i;
    return b;
}

double memory_estimate(const Settings& s) {
    const double np = s.population_size, d = s.dim(), a = std::max(0.0, s.archive_rate);
    // Rows of D doubles per individual: its row, its trial, its archive share; and, while a
    // checkpoint is written, three more copies of the row and archive (the state's payload, the
    // sealed state, the checkpoint's payload and seal overlapping two at a time, plus one).
    // Per individual also: its random stream (32 bytes, copied likewise), cost, trial cost, F/CR.
    const double rows = 2.0 + a + 3.0 * (1.0 + a);
    return np * (rows * d * 8.0 + 4 * 32.0 + 8 * 8.0);
}

void require_memory(const Settings& s, std::uint64_t available) {
    const double need = memory_estimate(s);
    if (available > 0 && need > static_cast<double>(available))
        throw std::invalid_argument("population_size: " + str(s.population_size) + " individuals of " +
                                    str(s.dim()) + " parameters need about " + io::human_bytes(need) +
                                    " of memory (population, trials, archive, checkpoint); " +
                                    io::human_bytes(static_cast<double>(available)) + " are available");
}

State init(const Settings& settings, BatchFunction& f, ThreadPool& pool) {
    const auto t0 = Clock::now();
    State st;
    st.settings = resolve(settings);
    check_dim(st, f);
    const Settings& s = st.settings;
    require_memory(s, io::available_memory());
    const int np = s.population_size;
    const int d = s.dim();
    st.np = np;
    // Streams 2^128 steps apart: 0 serial, 1 + i slot i.
    Rng base = Rng::seeded(s.seed);
    st.streams.resize(static_cast<std::size_t>(np) + 1);
    for (auto& r : st.streams) {
        r = base;
        base.jump();
    }
    // eq. (11): uniform within the bounds.
    st.population.resize(np, d);
    pool.parallel_for(static_cast<std::size_t>(np), [&](std::size_t b, std::size_t e, int) {
        for (std::size_t i = b; i < e; ++i) {
            Rng& g = st.streams[i + 1];
            for (int j = 0; j < d; ++j) {
                const double lo = s.lower[static_cast<std::size_t>(j)];
                const double hi = s.upper[static_cast<std::size_t>(j)];
                st.population(static_cast<Eigen::Index>(i), j) = std::min(lo + g.uniform() * (hi - lo), hi);
            }
        }
    });
    st.costs.resize(np);
    f.evaluate(st.population.data(), static_cast<std::size_t>(np), st.costs.data(), pool);
    sanitize(st.population.data(), d, st.costs.data(), static_cast<std::size_t>(np), "population");
    st.nfev = np;
    st.generation = 0;
    if (s.strategy == Strategy::jde) {
        st.ind_F.assign(static_cast<std::size_t>(np), s.F);
        st.ind_CR.assign(static_cast<std::size_t>(np), s.CR);
    }
    if (s.strategy == Strategy::jade) {
        st.mu_F = s.F;
        st.mu_CR = s.CR;
    }
    if (uses_memory(s.strategy)) {
        st.mem_F.assign(static_cast<std::size_t>(s.memory_size), s.F);
        st.mem_CR.assign(static_cast<std::size_t>(s.memory_size), s.CR);
        if (s.strategy == Strategy::jso) st.mem_F.back() = st.mem_CR.back() = 0.9;
    }
    st.elapsed = 0;
    append_log(st, pool, t0);
    return st;
}

namespace {

// The indices of the `top` lowest costs in order, ties by index, into order. (cost, index) pairs
// ordered as pairs (no cost is NaN): the top selected, then sorted; a partial sort of the indices
// compared through the costs took 10 % of SHADE's own work (BENCHMARKS.md, thirty-fourth round).
void best_order(const State& st, int top, std::vector<int>& order) {
    const int np = st.np;
    if (top == 1) {  // the first of the best
        int b = 0;
        for (int i = 1; i < np; ++i) b = st.costs(i) < st.costs(b) ? i : b;
        order.assign(1, b);
        return;
    }
    std::vector<std::pair<double, int>> keyed(static_cast<std::size_t>(np));
    for (int i = 0; i < np; ++i) keyed[static_cast<std::size_t>(i)] = {st.costs(i), i};
    if (top < np) std::nth_element(keyed.begin(), keyed.begin() + top, keyed.end());
    std::sort(keyed.begin(), keyed.begin() + top);
    order.resize(static_cast<std::size_t>(top));
    for (int k = 0; k < top; ++k)
        order[static_cast<std::size_t>(k)] = keyed[static_cast<std::size_t>(k)].second;
}

}  // namespace

void step(State& st, BatchFunction& f, ThreadPool& pool, std::int64_t max_trials) {
    const auto t0 = Clock::now();
    check_dim(st, f);
    const Settings& s = st.settings;
    const int np = st.np;
    // The slots whose trials are evaluated: all, or the first max_trials (a budget's last one).
    const int ne = max_trials < 0 ? np
                                  : static_cast<int>(std::clamp<std::int64_t>(max_trials, 1, np));
    const int d = st.dim();

    // Every slot's trial draws from its stream into st.drawn; st.streams take them once the
    // trials are evaluated (an evaluation that throws, such as a Python objective interrupted by
    // Ctrl-C, leaves the state as it was). The scratch stays with the state, so that each slot's
    // stream is written by the thread that builds its trial in every generation (the pool gives
    // a thread the same slots from one pass to the next): a serial copy of the streams before
    // the pass moved half of them between the threads' caches, twice a generation.
    if (st.drawn.size() != st.streams.size()) st.drawn.resize(st.streams.size());
    Generation gen;
    gen.st = &st;
    gen.drawn = st.drawn.data();
    gen.below_np = Below(static_cast<std::uint64_t>(np));
    gen.below_d = Below(static_cast<std::uint64_t>(d));
    if (reduces_population(s.strategy))
        gen.progress = static_cast<double>(st.nfev) / static_cast<double>(s.max_evaluations);
    double p = s.p_best;
    if (s.strategy == Strategy::jso) p = s.p_best * (1.0 - 0.5 * std::min(gen.progress, 1.0));
    gen.pnum = std::min(np, std::max(2, static_cast<int>(std::lround(p * np))));
    if (s.strategy != Strategy::rand1bin && s.strategy != Strategy::jde) {
        // The best `top` individuals in order (all the p-best sets and best1bin's base need).
        best_order(st, s.strategy == Strategy::best1bin ? 1 : gen.pnum, gen.order);
    }

    // Trials: slot i uses stream 1 + i only, so any partition of the slots gives the same trials.
    RowMatrixXd trials(np, d);
    // (Not value-initialized: zeros written by this thread would move the lines the other
    // threads then write between the caches.)
    const std::unique_ptr<double[]> tF(new double[static_cast<std::size_t>(np)]);
    const std::unique_ptr<double[]> tCR(new double[static_cast<std::size_t>(np)]);
    VectorXd tcost(np);
    const auto make_trials_of = [&](std::size_t b, std::size_t e) {
        make_trials(gen, static_cast<int>(b), static_cast<int>(e), trials.data(), tF.get(), tCR.get());
    };
    // What throws here (the objective, sanitize) leaves the state as it was: st.streams are
    // untouched until the swap below.
    std::atomic<bool> unsanitized{false};
    if (f.prepare(pool.size())) {
        // One pass of the pool: each thread builds its slots' trials and evaluates them
        // (while they are in its cache); one hand-over per generation instead of two.
        const auto nev = static_cast<std::size_t>(ne);
        // The chunks claimed as the threads go (a slot's trial and cost depend on the slot
        // alone): a thread that shares its core with another process takes fewer slots.
        pool.parallel_for_dynamic(static_cast<std::size_t>(np), ThreadPool::kGrain,
                                  [&](std::size_t b, std::size_t e, int id) {
            make_trials_of(b, e);
            if (b < std::min(e, nev)) {
                f.evaluate_rows(trials.data(), b, std::min(e, nev), tcost.data(), id);
                if (nan_to_inf(tcost.data(), b, std::min(e, nev)))
                    unsanitized.store(true, std::memory_order_relaxed);
            }
        });
        if (unsanitized.load())  // to name the first row with a -inf
            sanitize(trials.data(), d, tcost.data(), static_cast<std::size_t>(ne), "trial");
    } else {
        pool.parallel_for(static_cast<std::size_t>(np),
                          [&](std::size_t b, std::size_t e, int) { make_trials_of(b, e); });
        f.evaluate(trials.data(), static_cast<std::size_t>(ne), tcost.data(), pool);
        sanitize(trials.data(), d, tcost.data(), static_cast<std::size_t>(ne), "trial");
    }
    // The streams the pass did not draw from (the serial one, and those of slots a reduced
    // population no longer has) carried over, and the drawn ones taken.
    st.drawn[0] = st.streams[0];
    for (std::size_t k = static_cast<std::size_t>(np) + 1; k < st.streams.size(); ++k)
        st.drawn[k] = st.streams[k];
    st.streams.swap(st.drawn);
    st.nfev += ne;

    // Selection, eq. (14). Without an archive or memories (rand1bin, best1bin, jde) each slot's
    // selection depends on the slot alone: the log's pass makes it, each block by the thread that
    // built its trials (append_log). Otherwise serially in slot order (the archive and the
    // memories depend on order), the accepted trials' rows copied into the population by the
    // log's pass, but where the population is reduced (which reads the rows) first.
    Pending pending;
    pending.trials = &trials;
    pending.tcost = tcost.data();
    pending.tF = tF.get();
    pending.tCR = tCR.get();
    pending.ne = ne;
    if (!uses_archive(s.strategy)) {
        ++st.generation;
        append_log(st, pool, t0, &pending);
        return;
    }
    Success succ;
    const bool defer = !reduces_population(s.strategy);
    std::vector<char> taken(static_cast<std::size_t>(np), 0);
    for (int i = 0; i < ne; ++i) {
        if (!(tcost(i) <= st.costs(i))) continue;
        if (tcost(i) < st.costs(i)) {
            succ.F.push_back(tF[static_cast<std::size_t>(i)]);
            succ.CR.push_back(tCR[static_cast<std::size_t>(i)]);
            succ.w.push_back(st.costs(i) - tcost(i));
            archive_push(st, st.population.row(i).data());
        }
        if (defer) {
            taken[static_cast<std::size_t>(i)] = 1;
        } else {
            st.population.row(i) = trials.row(i);
        }
        st.costs(i) = tcost(i);
    }
    update_memories(st, succ);
    if (reduces_population(s.strategy)) reduce_population(st);
    ++st.generation;
    if (defer) {
        pending.taken = &taken;
        append_log(st, pool, t0, &pending);
    } else {
        append_log(st, pool, t0);
    }
}

void require_budget_for_init(const Settings& resolved, const Stop& stop) {
    if (stop.max_evaluations >= 0 && stop.max_evaluations < resolved.population_size) {
        bad("max_evaluations: " + str(stop.max_evaluations) + "; the initial population alone "
            "takes population_size (" + str(resolved.population_size) + ") evaluations");
    }
}

StopReason check_stop(const State& st, const Stop& stop, double seconds) {
    const double best = st.best_cost();
    // A target is reached by a finite best only, and only when one is set (the default -inf is
    // none): +inf (every cost NaN or +inf) reaches no target.
    if (stop.target_cost > -std::numeric_limits<double>::infinity() && std::isfinite(best) &&
        best <= stop.target_cost)
        return StopReason::target;
    if (stop.tol > 0 || stop.atol > 0) {
        const double mean = st.costs.mean();
        if (std::isfinite(mean)) {
            const double sd = std::sqrt((st.costs.array() - mean).square().mean());
            if (sd <= stop.atol + stop.tol * std::abs(mean)) return StopReason::converged;
        }
    }
    if (stop.stagnation_generations > 0 &&
        static_cast<std::int64_t>(st.log.size()) > stop.stagnation_generations) {
        const double then =
            st.log[st.log.size() - 1 - static_cast<std::size_t>(stop.stagnation_generations)].best;
        if (std::isfinite(then) && then - best <= stop.stagnation_tol * std::abs(best))
            return StopReason::stagnation;
    }
    if (stop.max_generations >= 0 && st.generation >= stop.max_generations)
        return StopReason::generations;
    if (stop.max_evaluations >= 0 && st.nfev >= stop.max_evaluations)
        return StopReason::evaluations;
    if (seconds >= stop.max_seconds) return StopReason::time;
    return StopReason::none;
}

namespace {
std::string stop_message(StopReason r, const State& st, const Stop& stop) {
    switch (r) {
        case StopReason::target:
            return "the best cost " + str(st.best_cost()) + " reached the target " +
                   str(stop.target_cost);
        case StopReason::converged:
            return "the population's costs converged (std <= atol + tol * |mean|)";
        case StopReason::stagnation:
            return "the best cost improved by no more than stagnation_tol in the last " +
                   str(stop.stagnation_generations) + " generations";
        case StopReason::generations:
            return "the maximum number of generations (" + str(stop.max_generations) +
                   ") was reached";
        case StopReason::evaluations:
            return "the maximum number of evaluations (" + str(stop.max_evaluations) +
                   ") was reached";
        case StopReason::time:
            return "the time limit (" + str(stop.max_seconds) + " s) was reached";
        case StopReason::callback: return "stopped by the callback";
        case StopReason::none: break;
    }
    return "not stopped";
}
}  // namespace

RunResult run(State& st, BatchFunction& f, ThreadPool& pool, const Stop& stop,
              const Callback& callback) {
    if (stop.max_generations < 0 && stop.max_evaluations < 0 && !std::isfinite(stop.max_seconds) &&
        !callback) {
        bad("stop: no stopping criterion (max_generations, max_evaluations, max_seconds or a "
            "callback)");
    }
    if (std::isnan(stop.max_seconds)) bad("max_seconds: nan");
    check_dim(st, f);
    const auto t0 = Clock::now();
    StopReason reason = check_stop(st, stop, 0.0);
    while (reason == StopReason::none) {
        // Never past the evaluation budget: the last generation may evaluate only part of the
        // population.
        step(st, f, pool, stop.max_evaluations >= 0 ? stop.max_evaluations - st.nfev : -1);
        const bool asked = callback && callback(st);
        reason = check_stop(st, stop, seconds_since(t0));
        if (reason == StopReason::none && asked) reason = StopReason::callback;
    }
    RunResult r;
    r.reason = reason;
    r.success = reason == StopReason::target || reason == StopReason::converged ||
                reason == StopReason::stagnation;
    r.message = stop_message(reason, st, stop);
    if (!std::isfinite(st.best_cost()))
        r.message += "; no finite cost was found (the objective returned NaN or +inf for every "
                     "point evaluated)";
    return r;
}

// ===== serialization =================================================================================

namespace {

constexpr char kMagic[8] = {'I', 'W', 'R', 'D', 'E', 'S', 'T', '\n'};

using io::Reader;
using io::Writer;

[[noreturn]] void corrupt(const std::string& what) {
    throw io::FormatError("DE state: " + what);
}

int i32(Reader& r, const char* what) {
    return static_cast<int>(r.i64_in(what, std::numeric_limits<int>::min(), std::numeric_limits<int>::max()));
}

void write_settings(Writer& w, const Settings& s) {
    w.u8(static_cast<std::uint8_t>(s.strategy));
    w.doubles(s.lower);
    w.doubles(s.upper);
    w.u64(s.seed);
    w.i64(s.population_size);
    w.f64(s.F);
    w.f64(s.CR);
    w.u8(static_cast<std::uint8_t>(s.bound_rule));
    w.f64(s.p_best);
    w.f64(s.c);
    w.f64(s.archive_rate);
    w.i64(s.memory_size);
    w.f64(s.tau1);
    w.f64(s.tau2);
    w.f64(s.F_lower);
    w.f64(s.F_upper);
    w.i64(s.min_population_size);
    w.i64(s.max_evaluations);
}

Settings read_settings(Reader& r) {
    Settings s;
    const std::uint8_t st = r.u8("strategy");
    if (st >= kStrategyCount) corrupt("unknown strategy code " + str(int(st)));
    s.strategy = static_cast<Strategy>(st);
    s.lower = r.doubles("lower bounds");
    s.upper = r.doubles("upper bounds");
    s.seed = r.u64("seed");
    s.population_size = i32(r, "population size");
    s.F = r.f64("F");
    s.CR = r.f64("CR");
    const std::uint8_t br = r.u8("bound rule");
    if (br >= kBoundRuleCount) corrupt("unknown bound rule code " + str(int(br)));
    s.bound_rule = static_cast<BoundRule>(br);
    s.p_best = r.f64("p_best");
    s.c = r.f64("c");
    s.archive_rate = r.f64("archive_rate");
    s.memory_size = i32(r, "memory_size");
    s.tau1 = r.f64("tau1");
    s.tau2 = r.f64("tau2");
    s.F_lower = r.f64("F_lower");
    s.F_upper = r.f64("F_upper");
    s.min_population_size = i32(r, "min_population_size");
    s.max_evaluations = r.i64("max_evaluations");
    return s;
}

}  // namespace

std::string State::to_bytes() const {
    Writer w;
    w.data().reserve(256 + 8 * static_cast<std::size_t>(population.size() + archive.size() + 8 * np) +
                     48 * log.size());
    write_settings(w, settings);
    w.i64(np);
    w.doubles(population.data(), static_cast<std::size_t>(population.size()));
    w.doubles(costs.data(), static_cast<std::size_t>(costs.size()));
    w.u64(streams.size());
    for (const Rng& r : streams)
        for (std::uint64_t v : r.s) w.u64(v);
    w.doubles(ind_F);
    w.doubles(ind_CR);
    w.f64(mu_F);
    w.f64(mu_CR);
    w.doubles(mem_F);
    w.doubles(mem_CR);
    w.i64(mem_pos);
    w.i64(archive_count);
    w.doubles(archive);
    w.i64(generation);
    w.i64(nfev);
    w.f64(elapsed);
    w.u64(log.size());
    for (const LogEntry& e : log) {
        w.i64(e.generation);
        w.i64(e.nfev);
        w.f64(e.best);
        w.f64(e.mean);
        w.f64(e.spread);
        w.f64(e.elapsed);
    }
    return io::seal(kMagic, kFormatVersion, w.data());
}

void State::serialize(std::ostream& out) const {
    const std::string bytes = to_bytes();
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    if (!out) throw std::runtime_error("DE state: write failed");
}

State State::deserialize(std::istream& in) {
    std::string buf((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    if (in.bad()) corrupt("read failed");
    return from_bytes(buf);
}

State State::from_bytes(const std::string& bytes) {
    const std::string payload = io::unseal(bytes, kMagic, kFormatVersion, "DE state: ", "a DE state");
    Reader r(payload.data(), payload.size(), "DE state: ");
    State st;
    const Settings raw = read_settings(r);
    try {
        st.settings = resolve(raw);
    } catch (const std::invalid_argument& e) {
        corrupt(std::string("invalid settings: ") + e.what());
    }
    if (st.settings != raw) corrupt("settings are not in resolved form");
    const Settings& s = st.settings;
    const std::size_t d = static_cast<std::size_t>(s.dim());
    st.np = i32(r, "population size");
    if (st.np < min_population_size(s.strategy) || st.np > s.population_size)
        corrupt("current population size " + str(st.np) + " out of range");
    const std::size_t np = static_cast<std::size_t>(st.np);
    const std::vector<double> pop = r.doubles("population");
    if (pop.size() != np * d) corrupt("population has the wrong size");
    st.population = Eigen::Map<const RowMatrixXd>(pop.data(), st.np, static_cast<Eigen::Index>(d));
    for (std::size_t i = 0; i < np; ++i)
        for (std::size_t j = 0; j < d; ++j) {
            const double v = pop[i * d + j];
            if (!(v >= s.lower[j] && v <= s.upper[j])) corrupt("population outside the bounds");
        }
    const std::vector<double> c = r.doubles("costs");
    if (c.size() != np) corrupt("costs have the wrong size");
    for (double v : c) {
        if (std::isnan(v)) corrupt("NaN cost");
        if (v == -std::numeric_limits<double>::infinity()) corrupt("-inf cost");  // never kept
    }
    st.costs = Eigen::Map<const VectorXd>(c.data(), st.np);
    const std::uint64_t ns = r.u64("stream count");
    if (ns != static_cast<std::uint64_t>(s.population_size) + 1) corrupt("wrong number of random streams");
    if (ns > r.remaining() / 32) corrupt("truncated while reading the random streams");
    st.streams.resize(static_cast<std::size_t>(ns));
    for (Rng& g : st.streams) {
        for (std::uint64_t& v : g.s) v = r.u64("random stream");
        if ((g.s[0] | g.s[1] | g.s[2] | g.s[3]) == 0) corrupt("zero random stream state");
    }
    st.ind_F = r.doubles("jDE F");
    st.ind_CR = r.doubles("jDE CR");
    const std::size_t n_ind = s.strategy == Strategy::jde ? np : 0;
    if (st.ind_F.size() != n_ind || st.ind_CR.size() != n_ind) corrupt("jDE parameters have the wrong size");
    for (std::size_t i = 0; i < n_ind; ++i)
        if (!(st.ind_F[i] > 0 && std::isfinite(st.ind_F[i]) && st.ind_CR[i] >= 0 && st.ind_CR[i] <= 1))
            corrupt("jDE parameters out of range");
    st.mu_F = r.f64("mu_F");
    st.mu_CR = r.f64("mu_CR");
    if (s.strategy == Strategy::jade && !(st.mu_F > 0 && st.mu_F <= 1 && st.mu_CR >= 0 && st.mu_CR <= 1))
        corrupt("JADE means out of range");
    st.mem_F = r.doubles("memory F");
    st.mem_CR = r.doubles("memory CR");
    const std::size_t h = static_cast<std::size_t>(s.memory_size);
    if (st.mem_F.size() != h || st.mem_CR.size() != h) corrupt("memories have the wrong size");
    for (std::size_t k = 0; k < h; ++k)
        if (!(st.mem_F[k] >= 0 && st.mem_F[k] <= 1 && st.mem_CR[k] <= 1 && (st.mem_CR[k] >= 0 || st.mem_CR[k] == -1)))
            corrupt("memory values out of range");
    st.mem_pos = i32(r, "memory position");
    if (st.mem_pos < 0 || (h > 0 ? st.mem_pos >= s.memory_size : st.mem_pos != 0))
        corrupt("memory position out of range");
    st.archive_count = i32(r, "archive count");
    st.archive = r.doubles("archive");
    if (st.archive_count < 0 || st.archive.size() != static_cast<std::size_t>(st.archive_count) * d ||
        st.archive_count > archive_capacity(st))
        corrupt("archive has the wrong size");
    for (double v : st.archive)
        if (!std::isfinite(v)) corrupt("non-finite archive entry");
    st.generation = r.i64("generation");
    st.nfev = r.i64("evaluation count");
    st.elapsed = r.f64("elapsed");
    if (st.generation < 0 || st.nfev < static_cast<std::int64_t>(np) || !(st.elapsed >= 0))
        corrupt("counters out of range");
    const std::uint64_t nlog = r.u64("log length");
    if (nlog != static_cast<std::uint64_t>(st.generation) + 1)
        corrupt("log length does not match the generation");
    if (nlog > r.remaining() / 48) corrupt("truncated while reading the log");
    st.log.resize(static_cast<std::size_t>(nlog));
    for (LogEntry& e : st.log) {
        e.generation = r.i64("log");
        e.nfev = r.i64("log");
        e.best = r.f64("log");
        e.mean = r.f64("log");
        e.spread = r.f64("log");
        e.elapsed = r.f64("log");
    }
    if (r.remaining() != 0) corrupt("unexpected bytes after the log");
    return st;
}

}  // namespace iwr::de
