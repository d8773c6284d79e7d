// Differential evolution: the paper's DE/rand/1/bin (eq. 11-14) and modern variants, on any objective
// that evaluates a whole population at once; parallel, deterministic, steppable and checkpointable.
//
// ---------------------------------------------------------------------------------------------------
// API in one page
// ---------------------------------------------------------------------------------------------------
//   iwr::de::Settings s;                     // what defines a run's trajectory (see below)
//   s.strategy = iwr::de::Strategy::lshade;  s.lower = ...;  s.upper = ...;  s.seed = 42;
//   iwr::de::ObjectiveFunction f(objective, active_mask, x0);   // or any iwr::de::BatchFunction
//   (iwr::de::ReducedObjective<iwr::TrackerObjective> for laser-tracker data)
//   iwr::ThreadPool pool(2);
//
//   iwr::de::State st = iwr::de::init(s, f, pool);   // generation 0: uniform population, evaluated
//   iwr::de::Stop stop;  stop.max_generations = 1000;  stop.target_cost = 1e-4;
//   iwr::de::RunResult r = iwr::de::run(st, f, pool, stop, callback);   // loop of step() + stop tests
//   // or drive it yourself:  while (!done) iwr::de::step(st, f, pool);   // one generation each
//   st.best_x(), st.best_cost(), st.log                                  // the answer and the log
//
//   std::ofstream out(path, std::ios::binary);  st.serialize(out);      // a checkpoint
//   std::ifstream in(path, std::ios::binary);   auto st2 = iwr::de::State::deserialize(in);
//   // step(st2, f, pool) continues exactly as step(st, f, pool) would: bit-identical populations,
//   // costs and log (except the `elapsed` column, which is wall-clock time).
//
// To stop on a signal (SIGINT, SIGTERM), set a std::atomic<bool> in the handler and return its value
// from the callback: run() returns after the current generation with StopReason::callback, and the
// state is complete and serializable.
//
// Everything a run needs to continue lives in `State`: the resolved Settings, the population and its
// costs, every random stream, the strategy's memories (jDE's per-individual F and CR, JADE's means,
// the SHADE family's success-history memories), the archive, the counters, the current population
// size and the per-generation log. `step` is a pure function of (State, objective): no hidden static
// state, no clock in any decision, so init/step/serialize/deserialize/step reproduces a run that was
// never interrupted. Stopping criteria (`Stop`) are not part of the trajectory and are not stored.
//
// Determinism: random stream 0 is the serial stream (archive replacement); stream 1 + i belongs to
// population slot i and is the only source of randomness for slot i's initial point and its trials.
// Trials are generated and evaluated in parallel, everything else (selection, memories, archive,
// population reduction, the log) runs serially in slot order. The same seed and settings therefore give
// bit-identical results whatever the number of threads, provided the objective's value for a row
// depends only on that row (true of iwr::Objective::cost_batch).
//
// Conventions shared by every strategy (and stated once here):
//   * deferred update: all trials of generation G are built from generation G, then selection builds
//     G + 1 (eq. 14 applied to the whole population at once);
//   * selection by `<=` (eq. 14): a trial equal to its target replaces it; the success memories and
//     the archive of the adaptive strategies record only strict improvements (as in Tanabe &
//     Fukunaga's reference code of SHADE/L-SHADE);
//   * a NaN cost is treated as +infinity (never selected over a finite one); a cost of -infinity is
//     an error (std::invalid_argument from init/step/run naming the vector), never a best cost;
//   * binomial crossover with a forced index j_r (eq. 13), `rand < CR`;
//   * out-of-bounds trial components: BoundRule (default `midpoint`, below).
//
// Bound handling (the paper does not say): a trial component u_j outside [l_j, u_j] is replaced by
//   midpoint (default): (x_ij + l_j) / 2 below, (x_ij + u_j) / 2 above, x_i the target (parent) --
//       the rule of JADE (Zhang & Sanderson, "JADE: adaptive differential evolution with optional
//       external archive", IEEE TEC 13(5), 2009) and of the SHADE, L-SHADE and jSO reference codes;
//   reinit: a fresh uniform value in [l_j, u_j] -- what scipy.optimize.differential_evolution does;
//   reflect: mirrored at the violated bound (2 l_j - u_j), then clipped if still outside;
//   clip: the violated bound itself.
// Only mutated components can violate: components copied from the target are inside already.
// ---------------------------------------------------------------------------------------------------
#pragma once

#include <cstddef>
#include <cstdint>
#include <functional>
#include <iosfwd>
#include <limits>
#include <string>
#include <vector>

#include "iwr/measurement_kind.hpp"
#include "iwr/model.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"

namespace iwr::de {

// ----- objectives ------------------------------------------------------------------------------------

/// Any function that evaluates a whole population. Implementations may use the pool (the engine
/// calls evaluate from one thread at a time) and must give each row a value that depends only on it.
class BatchFunction {
public:
    virtual ~BatchFunction() = default;
    /// Number of decision variables D.
    virtual int dim() const = 0;
    /// out[i] = f(row i of X), X row-major (m x dim()).
    virtual void evaluate(const double* X, std::size_t m, double* out, ThreadPool& pool) = 0;
    /// Optional, for functions that are thread-safe row by row (the C++ objectives): prepare(t)
    /// readies t threads; then evaluate_rows(X, b, e, out, id) sets out[i] = f(row i of X) for
    /// b <= i < e on the calling thread, id < t, concurrently for disjoint ranges and ids. The
    /// engine then builds and evaluates each thread's trials in one pass of the pool per
    /// generation instead of two. The default: not supported (prepare returns false).
    virtual bool prepare(int threads) {
        (void)threads;
        return false;
    }
    virtual void evaluate_rows(const double* X, std::size_t b, std::size_t e, double* out, int id) {
        (void)X, (void)b, (void)e, (void)out, (void)id;
    }
};

namespace detail {
/// The indices of the active parameters of an objective with n parameters (active empty: all),
/// and x0 filled (empty: zeros). Throws std::invalid_argument on bad sizes, a non-finite x0 or no
/// active flag.
std::vector<int> active_index(int n, std::vector<bool> active, VectorXd& x0);
}  // namespace detail

/// An objective over its active parameters only; inactive ones are held at x0. Obj is any type
/// meeting the objective requirements of iwr/measurement_kind.hpp (the extension point of the
/// measurement kinds: iwr::Objective for eq. (10), iwr::TrackerObjective for tracker data, ...);
/// the engine never asks which kind it runs on. The objective must outlive this adapter.
template <class Obj>
class ReducedObjective final : public BatchFunction {
    static_assert(is_objective_v<Obj>, "not an objective (see iwr/measurement_kind.hpp)");

public:
    /// active: n_params flags, or empty for all parameters; x0: n_params values (the inactive ones
    /// are used), or empty for zeros. Throws std::invalid_argument on bad sizes or no active flag.
    ReducedObjective(const Obj& objective, std::vector<bool> active = {}, VectorXd x0 = VectorXd())
        : objective_(objective), index_(detail::active_index(objective.n_params(), std::move(active), x0)),
          x0_(std::move(x0)) {}
    int dim() const override { return static_cast<int>(index_.size()); }
    void evaluate(const double* X, std::size_t m, double* out, ThreadPool& pool) override {
        prepare(pool.size());
        pool.parallel_for_dynamic(m, ThreadPool::kGrain, [&](std::size_t b, std::size_t e, int id) {
            evaluate_rows(X, b, e, out, id);
        });
    }
    bool prepare(int threads) override {
        // A thread's full vectors: one, or detail::kCostRows where the objective takes rows at once.
        const Eigen::Index rows = iwr::detail::has_cost_rows_v<Obj> ? iwr::detail::kCostRows : 1;
        while (workspaces_.size() < static_cast<std::size_t>(threads)) {
            workspaces_.push_back(objective_.make_workspace());
            buffers_.push_back(x0_.replicate(rows, 1));
        }
        return true;
    }
    void evaluate_rows(const double* X, std::size_t b, std::size_t e, double* out, int id) override {
        auto& ws = workspaces_[static_cast<std::size_t>(id)];
        double* x = buffers_[static_cast<std::size_t>(id)].data();
        const std::size_t d = index_.size(), n = static_cast<std::size_t>(x0_.size());
        const bool all = static_cast<int>(d) == objective_.n_params();
        // Row i as a full vector: X's row itself, or its active entries over x0 in buffer k.
        iwr::detail::row_costs(objective_, b, e, out, ws, [&](std::size_t i, std::size_t k) {
            const double* z = X + i * d;
            if (all) return z;
            double* xk = x + k * n;
            for (std::size_t j = 0; j < d; ++j) xk[index_[j]] = z[j];
            return static_cast<const double*>(xk);
        });
    }
    /// The full n_params vector for a reduced one (dim() entries).
    VectorXd full(const double* z) const {
        VectorXd x = x0_;
        for (std::size_t k = 0; k < index_.size(); ++k) x(index_[k]) = z[k];
        return x;
    }
    const std::vector<int>& active_index() const { return index_; }
    const Obj& objective() const { return objective_; }

private:
    const Obj& objective_;
    std::vector<int> index_;
    VectorXd x0_;
    std::vector<typename Obj::Workspace> workspaces_;
    std::vector<VectorXd> buffers_;
};

/// The IWR objective of eq. (10) over the active parameters only.
using ObjectiveFunction = ReducedObjective<Objective>;

// ----- settings --------------------------------------------------------------------------------------

/// The strategies. Each one's published rules and defaults are documented at its enumerator.
enum class Strategy : std::uint8_t {
    /// DE/rand/1/bin, the paper's eq. (11)-(14): m = x_r1 + F (x_r2 - x_r3), r1, r2, r3, i
    /// distinct. Storn & Price, "Differential evolution - a simple and efficient heuristic for
    /// global optimization over continuous spaces", J. Global Optim. 11, 1997. Defaults (ibid.):
    /// NP = 10 D, F = 0.5, CR = 0.9. The paper's Table 2: NP = 600, F = 0.9, CR = 1.0.
    rand1bin = 0,
    /// DE/best/1/bin: m = x_best + F (x_r1 - x_r2), r1, r2, i distinct. Storn & Price 1997; same
    /// defaults as rand1bin.
    best1bin = 1,
    /// JADE: DE/current-to-pbest/1/bin with an archive, m = x_i + F_i (x_pbest - x_i) + F_i (x_r1 -
    /// x~_r2), x~_r2 from population + archive; F_i ~ Cauchy(mu_F, 0.1), CR_i ~ N(mu_CR, 0.1);
    /// mu_F <- (1-c) mu_F + c mean_Lehmer(S_F), mu_CR <- (1-c) mu_CR + c mean(S_CR). Zhang &
    /// Sanderson, IEEE TEC 13(5):945-958, 2009. Defaults (ibid.): p = 0.05, c = 0.1, mu_F = mu_CR =
    /// 0.5 (Settings::F and CR set the initial means), archive size NP; NP = 30, 100, 400 for
    /// D <= 10, <= 30, larger (the paper's settings for D = 10, 30, 100).
    jade = 2,
    /// jDE: DE/rand/1/bin with self-adapted F_i and CR_i per individual: with probability tau1
    /// F_i <- F_l + rand F_u, with probability tau2 CR_i <- rand, kept when the trial survives.
    /// Brest, Greiner, Boskovic, Mernik & Zumer, IEEE TEC 10(6):646-657, 2006. Defaults (ibid.):
    /// tau1 = tau2 = 0.1, F_l = 0.1, F_u = 0.9, initial F = 0.5, CR = 0.9, NP = 100.
    jde = 3,
    /// SHADE: JADE's mutation with a success-history memory of H pairs (M_CR, M_F): slot r_i
    /// uniform, CR_i ~ N(M_CR,r, 0.1), F_i ~ Cauchy(M_F,r, 0.1), p_i ~ U[2/NP, 0.2]; memory slot k
    /// <- weighted mean of S_CR, weighted Lehmer mean of S_F (weights |f(u) - f(x)|). Tanabe &
    /// Fukunaga, "Success-history based parameter adaptation for differential evolution", IEEE CEC
    /// 2013, pp. 71-78. Defaults (ibid.): NP = 100, H = 100, memory 0.5, archive size NP.
    shade = 4,
    /// L-SHADE: SHADE with linear population size reduction, NP_{G+1} = round((NP_min - NP_init)
    /// NFE / NFE_max + NP_init), the worst individuals removed, the archive cut to its new size by
    /// random removals; weighted Lehmer mean for M_CR too, with the terminal value (M_CR = ⊥, then
    /// CR = 0) when every successful CR is 0 (until the slot's next update, as in the authors'
    /// code; the paper's text keeps ⊥ for good). Tanabe &
    /// Fukunaga, "Improving the search performance of SHADE using linear population size
    /// reduction", IEEE CEC 2014, pp. 1658-1665. Defaults (ibid.): NP_init = round(18 D), NP_min = 4,
    /// H = 6, p = 0.11, archive rate 2.6, memory 0.5, NFE_max = 10000 D.
    lshade = 5,
    /// jSO: L-SHADE with current-to-pBest-w/1, m = x_i + F_w (x_pbest - x_i) + F (x_r1 - x~_r2),
    /// F_w = 0.7 F, 0.8 F, 1.2 F for NFE < 0.2, < 0.4, >= 0.4 NFE_max; F <= 0.7 while NFE < 0.6
    /// NFE_max; CR >= 0.7 while NFE < 0.25 NFE_max and >= 0.6 while < 0.5 NFE_max; p falls linearly
    /// from 0.25 to 0.125; x_pbest != x_i in the first half; memory M <- (mean_WL(S) + M) / 2, its
    /// last slot fixed at 0.9; the terminal value of M_CR as in lshade (stored as is, where the
    /// authors' code averages it with the old value). Brest, Maucec & Boskovic, "Single objective real-parameter
    /// optimization: algorithm jSO", IEEE CEC 2017, pp. 1311-1318 (p schedule as in the authors'
    /// code). Defaults (ibid.): NP_init = round(25 ln(D) sqrt(D)), NP_min = 4, H = 5, M_F = 0.3,
    /// M_CR = 0.8, archive rate 1, NFE_max = 10000 D.
    jso = 6,
};
constexpr int kStrategyCount = 7;

/// Rule for out-of-bounds trial components; see the header comment.
enum class BoundRule : std::uint8_t { midpoint = 0, reinit = 1, reflect = 2, clip = 3 };
constexpr int kBoundRuleCount = 4;

/// Names as used by the Python API: "rand1bin", "best1bin", "jade", "jde", "shade", "lshade", "jso";
/// "midpoint", "reinit", "reflect", "clip". The parsers throw std::invalid_argument naming `what`.
std::string to_string(Strategy s);
std::string to_string(BoundRule b);
Strategy parse_strategy(const std::string& name, const char* what = "strategy");
BoundRule parse_bound_rule(const std::string& name, const char* what = "bound_rule");

constexpr double kDefault = std::numeric_limits<double>::quiet_NaN();

/// Everything that determines a run's trajectory. A field left at its "default" value (0 for
/// integers, NaN for doubles) takes the strategy's published default in resolve().
struct Settings {
    Strategy strategy = Strategy::rand1bin;
    std::vector<double> lower, upper;  ///< the search box; its size is the dimension D
    std::uint64_t seed = 0;
    int population_size = 0;  ///< NP (the initial NP of lshade/jso)
    /// rand1bin, best1bin: the scale factor F (> 0) and crossover rate CR (in [0, 1]).
    /// jde: the initial F_i and CR_i. jade: the initial mu_F, mu_CR. shade, lshade, jso: the initial
    /// memory values M_F, M_CR.
    double F = kDefault;
    double CR = kDefault;
    BoundRule bound_rule = BoundRule::midpoint;
    // Strategy parameters (ignored by strategies that have no such parameter).
    double p_best = kDefault;        ///< jade 0.05, shade 0.2 (upper end of p_i), lshade 0.11, jso 0.25
    double c = kDefault;             ///< jade: learning rate of mu_F, mu_CR, 0.1
    double archive_rate = kDefault;  ///< archive size / NP: jade, shade 1.0, lshade 2.6, jso 1.0
    int memory_size = 0;             ///< H: shade 100, lshade 6, jso 5
    double tau1 = kDefault, tau2 = kDefault;        ///< jde: 0.1, 0.1
    double F_lower = kDefault, F_upper = kDefault;  ///< jde: F_l = 0.1, F_u = 0.9
    int min_population_size = 0;                    ///< lshade, jso: NP_min = 4
    /// lshade, jso: NFE_max, the evaluation budget their schedules run to (default 10000 D). Part
    /// of the trajectory; Stop::max_evaluations is the separate stopping test.
    std::int64_t max_evaluations = 0;

    int dim() const { return static_cast<int>(lower.size()); }
};

/// Smallest population a strategy can work with (distinct indices it draws): 4 for every strategy
/// but best1bin (3).
int min_population_size(Strategy s);

/// The settings with every default filled in for dimension lower.size(), validated. Throws
/// std::invalid_argument naming the field and its value (for example "F: -1; expected F > 0").
Settings resolve(Settings s);

bool operator==(const Settings& a, const Settings& b);  // field by field, on resolved settings
inline bool operator!=(const Settings& a, const Settings& b) { return !(a == b); }

// ----- random streams --------------------------------------------------------------------------------

/// xoshiro256** (Blackman & Vigna, "Scrambled linear pseudorandom number generators", ACM TOMS 47,
/// 2021), seeded by SplitMix64; streams for different slots are 2^128 steps apart (jump()).
struct Rng {
    std::uint64_t s[4] = {0, 0, 0, 0};

    static Rng seeded(std::uint64_t seed);
    std::uint64_t next();
    void jump();                         ///< advance by 2^128 steps
    double uniform();                    ///< [0, 1), 53 random bits
    double uniform(double a, double b);  ///< [a, b)
    std::uint64_t below(std::uint64_t n);  ///< uniform integer in [0, n), unbiased; n > 0
    double normal(double mean, double sd);  ///< Box-Muller, two uniforms per call
    double cauchy(double loc, double scale);
};

// ----- the run's state -------------------------------------------------------------------------------

/// One row of the per-generation log, written after initialisation (generation 0) and each step.
struct LogEntry {
    std::int64_t generation = 0;
    std::int64_t nfev = 0;  ///< evaluations so far, initial population included
    double best = 0;        ///< lowest cost in the population (selection is elitist: never rises)
    double mean = 0;        ///< mean cost of the population
    /// Root mean square over parameters of the population's standard deviation, each in units of
    /// its bound width (upper - lower): 0 when the population has collapsed to a point.
    double spread = 0;
    double elapsed = 0;  ///< wall-clock seconds spent in init and step so far (not reproducible)
};

struct State {
    Settings settings;  ///< resolved
    int np = 0;         ///< current population size
    RowMatrixXd population;  ///< np x D
    VectorXd costs;          ///< np
    std::vector<Rng> streams;  ///< [0] serial, [1 + i] slot i; size 1 + initial NP
    /// step's scratch, not part of the state (not serialized): the slots' streams after their
    /// trials' draws, which replace `streams` once the trials are evaluated (so that an
    /// evaluation that throws leaves `streams` as they were, without a copy of them made first).
    std::vector<Rng> drawn;
    // Strategy memories.
    std::vector<double> ind_F, ind_CR;  ///< jde: per individual (np)
    double mu_F = 0, mu_CR = 0;         ///< jade
    std::vector<double> mem_F, mem_CR;  ///< shade family, H each; mem_CR < 0 is the terminal value
    int mem_pos = 0;                    ///< shade family: next memory slot to update
    std::vector<double> archive;        ///< archive_count x D, row-major
    int archive_count = 0;
    std::int64_t generation = 0;
    std::int64_t nfev = 0;
    double elapsed = 0;
    std::vector<LogEntry> log;

    int dim() const { return settings.dim(); }
    int best_index() const;  ///< lowest cost, the first one on ties
    double best_cost() const { return costs(best_index()); }
    VectorXd best_x() const { return population.row(best_index()).transpose(); }

    /// The sealed container of iwr/binary_io.hpp (magic "IWRDEST\n", format version, size,
    /// FNV-1a 64 checksum) around the fields.
    std::string to_bytes() const;
    void serialize(std::ostream& out) const;
    /// Reads what serialize wrote. Throws std::runtime_error (never crashes, never allocates more
    /// than the input's size justifies) on a wrong magic, an unknown version, a truncated or
    /// corrupted stream, or inconsistent contents.
    static State deserialize(std::istream& in);
    static State from_bytes(const std::string& bytes);
    static constexpr std::uint32_t kFormatVersion = 2;
};

// ----- the engine ------------------------------------------------------------------------------------

/// Generation 0: resolves and validates the settings (std::invalid_argument), draws the population
/// uniformly within the bounds (eq. 11) from each slot's stream, evaluates it, writes log row 0.
/// Throws std::invalid_argument if f.dim() != settings.lower.size().
/// Also refuses (std::invalid_argument naming population_size) a population whose memory,
/// estimated by memory_estimate, exceeds what the machine has available.
State init(const Settings& settings, BatchFunction& f, ThreadPool& pool);

/// Bytes a run of these resolved settings holds at once (population, trials, archive, random
/// streams, per-individual memories, and the serialized copy a checkpoint makes), per-generation
/// log aside.
double memory_estimate(const Settings& resolved);
/// Throws std::invalid_argument ("population_size: ... need about X of memory; Y are available")
/// when memory_estimate exceeds `available` bytes (0: unknown, no check).
void require_memory(const Settings& resolved, std::uint64_t available);

/// One generation: trials for every slot (in parallel, slot i from stream i), their evaluation,
/// selection (eq. 14), the strategy's serial bookkeeping, then a log row.
/// max_trials >= 0 evaluates only the trials of the first max_trials slots (at least 1), the
/// others keep their parents: run() uses it so that a generation never takes the evaluation count
/// past Stop::max_evaluations. Every slot's trial is still drawn, so the random streams advance as
/// in a full generation. < 0 (the default): the whole population.
void step(State& state, BatchFunction& f, ThreadPool& pool, std::int64_t max_trials = -1);

/// When to stop. Not stored in the state: a resumed run may use other criteria.
struct Stop {
    std::int64_t max_generations = -1;  ///< stop when generation >= this; < 0: no limit
    std::int64_t max_evaluations = -1;  ///< stop when nfev >= this; < 0: no limit
    /// stop when a finite best <= this; the default -inf: no target
    double target_cost = -std::numeric_limits<double>::infinity();
    /// Population convergence, as scipy: std(costs) <= atol + tol |mean(costs)|; off when both 0.
    double tol = 0, atol = 0;
    /// Stagnation: the best cost improved by no more than stagnation_tol |best| over the last
    /// stagnation_generations generations; off when stagnation_generations <= 0.
    std::int64_t stagnation_generations = 0;
    double stagnation_tol = 0;
    double max_seconds = std::numeric_limits<double>::infinity();  ///< wall clock of this run() call
};

enum class StopReason : std::uint8_t {
    none = 0,     ///< not stopped
    target,       ///< best <= target_cost (success)
    converged,    ///< tol/atol test (success)
    stagnation,   ///< no progress (success)
    generations,  ///< max_generations reached
    evaluations,  ///< max_evaluations reached
    time,         ///< max_seconds reached
    callback,     ///< the callback asked to stop
};
std::string to_string(StopReason r);

/// Throws std::invalid_argument (naming max_evaluations) when a fresh run cannot respect the
/// budget: init() evaluates the whole initial population, population_size evaluations, so
/// stop.max_evaluations (when set) must be at least that. `resolved`: settings after resolve().
void require_budget_for_init(const Settings& resolved, const Stop& stop);

/// The reason, if any, to stop now (callback aside). `seconds` is the wall time of the current run.
StopReason check_stop(const State& state, const Stop& stop, double seconds);

/// Called after every generation with the state; return true to stop.
using Callback = std::function<bool(const State&)>;

struct RunResult {
    StopReason reason = StopReason::none;
    bool success = false;  ///< target, converged or stagnation
    std::string message;
};

/// Steps until a stopping criterion holds or the callback returns true (checked in that order
/// after each generation; the criteria are also checked once before the first step, so a state
/// that already satisfies them is returned untouched). At least one of max_generations,
/// max_evaluations, max_seconds or a callback must be given (std::invalid_argument otherwise).
RunResult run(State& state, BatchFunction& f, ThreadPool& pool, const Stop& stop,
              const Callback& callback = Callback());

}  // namespace iwr::de
