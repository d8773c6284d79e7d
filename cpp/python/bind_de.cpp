// Bindings of the differential evolution engine (iwr/de.hpp). Private: iwr.de is the public API.
// Two entries: de_kernel runs the engine on a bound C++ objective of any measurement kind (what
// iwr.identify(method="de") runs, as iwr-engine does: no Python in the loop), de_function on a
// Python function of the population (iwr.differential_evolution, and a problem with no C++
// objective).
//
// The engine runs with the GIL released. The GIL is taken back only (a) to call a Python objective,
// once per generation with the whole population, (b) to call the Python monitor, every generation
// when asked or at most every `interval` seconds otherwise, and (c) at that same point to run
// PyErr_CheckSignals(), so that Ctrl-C stops the run within `interval` seconds (plus one
// generation) and the best result so far is returned, marked as interrupted.
#include <chrono>
#include <cmath>
#include <cstring>
#include <memory>
#include <sstream>
#include <string>
#include <variant>

#include "common.hpp"
#include "iwr/binary_io.hpp"
#include "iwr/checkpoint.hpp"
#include "iwr/de.hpp"
#include "iwr/measurement_kind.hpp"

namespace iwr::python {

namespace {

namespace de = iwr::de;
using Clock = std::chrono::steady_clock;

// Thrown through the engine when a Python error is pending in `Session::pending`.
struct PythonError {};

// What one run shares between the engine's callbacks and the binding.
struct Session {
    std::unique_ptr<py::error_already_set> pending;  // a Python exception to re-raise, or Ctrl-C
    bool interrupted = false;                        // KeyboardInterrupt seen
};

// A Python callable f(X: (M, D) float64) -> M costs, as a BatchFunction.
class PyFunction final : public de::BatchFunction {
public:
    PyFunction(py::function f, int dim, Session& session)
        : f_(std::move(f)), dim_(dim), session_(session) {}
    int dim() const override { return dim_; }
    void evaluate(const double* X, std::size_t m, double* out, ThreadPool&) override {
        py::gil_scoped_acquire gil;
        try {
            py::array_t<double> arr({static_cast<py::ssize_t>(m), static_cast<py::ssize_t>(dim_)});
            std::memcpy(arr.mutable_data(), X, m * static_cast<std::size_t>(dim_) * sizeof(double));
            py::object res = f_(arr);
            auto costs = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(res);
            if (!costs) {
                throw std::invalid_argument("func: returned " +
                                            std::string(py::str(py::type::of(res).attr("__name__"))) +
                                            "; expected an array of " + std::to_string(m) + " costs");
            }
            const bool ok = (costs.ndim() == 1 && costs.shape(0) == static_cast<py::ssize_t>(m)) ||
                            (costs.ndim() == 2 && costs.shape(0) == static_cast<py::ssize_t>(m) &&
                             costs.shape(1) == 1);
            if (!ok) {
                std::ostringstream msg;
                msg << "func: returned an array of shape (";
                for (py::ssize_t k = 0; k < costs.ndim(); ++k) msg << (k ? ", " : "") << costs.shape(k);
                msg << (costs.ndim() == 1 ? ",)" : ")") << " for a population of " << m
                    << "; expected (" << m << ",)";
                throw std::invalid_argument(msg.str());
            }
            std::memcpy(out, costs.data(), m * sizeof(double));
        } catch (py::error_already_set& e) {
            session_.pending = std::make_unique<py::error_already_set>(std::move(e));
            throw PythonError{};
        }
    }

private:
    py::function f_;
    int dim_;
    Session& session_;
};

py::dict settings_dict(const de::Settings& s) {
    py::dict d;
    d["strategy"] = de::to_string(s.strategy);
    d["population_size"] = s.population_size;
    d["F"] = s.F;
    d["CR"] = s.CR;
    d["seed"] = s.seed;
    d["bound_rule"] = de::to_string(s.bound_rule);
    d["p_best"] = s.p_best;
    d["c"] = s.c;
    d["archive_rate"] = s.archive_rate;
    d["memory_size"] = s.memory_size;
    d["tau1"] = s.tau1;
    d["tau2"] = s.tau2;
    d["F_lower"] = s.F_lower;
    d["F_upper"] = s.F_upper;
    d["min_population_size"] = s.min_population_size;
    d["max_evaluations"] = s.max_evaluations;
    return d;
}

py::dict state_summary(const de::State& st) {
    const int b = st.best_index();
    py::dict d;
    d["generation"] = st.generation;
    d["nfev"] = st.nfev;
    d["best"] = st.costs(b);
    d["x"] = VectorXd(st.population.row(b).transpose());
    const de::LogEntry& e = st.log.back();
    d["mean"] = e.mean;
    d["spread"] = e.spread;
    d["elapsed"] = e.elapsed;
    d["population_size"] = st.np;
    return d;
}

py::dict result_dict(const de::State& st, const de::RunResult& r, const Session& session,
                     bool with_state) {
    py::dict d = state_summary(st);
    d["fun"] = d["best"];
    d["nit"] = st.generation;
    d["reason"] = session.interrupted ? "interrupted" : de::to_string(r.reason);
    d["success"] = session.interrupted ? false : r.success;
    d["message"] = session.interrupted ? std::string("interrupted by KeyboardInterrupt (Ctrl-C)")
                                       : r.message;
    d["interrupted"] = session.interrupted;
    const std::size_t n = st.log.size();
    py::array_t<std::int64_t> gen(static_cast<py::ssize_t>(n)), nfev(static_cast<py::ssize_t>(n));
    py::array_t<double> best(static_cast<py::ssize_t>(n)), mean(static_cast<py::ssize_t>(n)),
        spread(static_cast<py::ssize_t>(n)), elapsed(static_cast<py::ssize_t>(n));
    for (std::size_t k = 0; k < n; ++k) {
        const de::LogEntry& e = st.log[k];
        gen.mutable_at(k) = e.generation;
        nfev.mutable_at(k) = e.nfev;
        best.mutable_at(k) = e.best;
        mean.mutable_at(k) = e.mean;
        spread.mutable_at(k) = e.spread;
        elapsed.mutable_at(k) = e.elapsed;
    }
    py::dict h;
    h["generation"] = gen;
    h["nfev"] = nfev;
    h["best"] = best;
    h["mean"] = mean;
    h["spread"] = spread;
    h["elapsed"] = elapsed;
    d["history"] = h;
    d["population"] = st.population;
    d["population_costs"] = st.costs;
    d["settings"] = settings_dict(st.settings);
    if (with_state) {
        std::ostringstream out;
        st.serialize(out);
        d["state"] = py::bytes(out.str());
    }
    return d;
}

// Runs (or resumes) a DE on f. Called with the GIL held; releases it around the engine.
py::dict run_de(de::BatchFunction& f, Session& session, const de::Settings& settings,
                const de::Stop& stop, int threads, const py::object& monitor, bool every_generation,
                double interval, const py::object& resume, bool return_state) {
    if (!(interval > 0 && interval <= 1))
        throw std::invalid_argument("interval: " + std::to_string(interval) + "; expected (0, 1] s");
    // Too many threads for this machine: the pool's refusal, named by the Python argument.
    std::unique_ptr<ThreadPool> owned;
    try {
        owned = std::make_unique<ThreadPool>(threads);
    } catch (const std::invalid_argument& e) {
        throw std::invalid_argument("workers: " + std::to_string(threads) + "; " + e.what());
    }
    ThreadPool& pool = *owned;
    de::State st;
    if (!resume.is_none()) {
        std::istringstream in(std::string(resume.cast<py::bytes>()));
        st = de::State::deserialize(in);
        if (st.settings != de::resolve(settings))
            throw std::invalid_argument("state: made with other settings than the ones given");
    } else {
        de::require_budget_for_init(de::resolve(settings), stop);
    }
    auto last = Clock::now();
    const bool has_monitor = !monitor.is_none();
    de::Callback cb = [&](const de::State& s) -> bool {
        const auto now = Clock::now();
        const bool due = std::chrono::duration<double>(now - last).count() >= interval;
        if (!(due || (has_monitor && every_generation))) return false;
        last = now;
        py::gil_scoped_acquire gil;
        if (PyErr_CheckSignals() != 0) {
            session.pending = std::make_unique<py::error_already_set>();
            return true;
        }
        if (!has_monitor) return false;
        try {
            return py::cast<bool>(monitor(state_summary(s)));
        } catch (py::error_already_set& e) {
            session.pending = std::make_unique<py::error_already_set>(std::move(e));
            return true;
        }
    };
    de::RunResult r;
    try {
        py::gil_scoped_release release;
        if (resume.is_none()) st = de::init(settings, f, pool);
        r = de::run(st, f, pool, stop, cb);
    } catch (const PythonError&) {
        // the Python objective raised; handled below
    }
    if (session.pending) {
        if (session.pending->matches(PyExc_KeyboardInterrupt) && st.np > 0) {
            session.interrupted = true;
        } else {
            py::error_already_set e = *session.pending;
            session.pending.reset();
            throw e;
        }
    }
    py::dict d = result_dict(st, r, session, return_state);
    d["threads"] = pool.size();  // the engine's threads, the calling one included
    return d;
}

// The bound C++ objectives DE runs on: Pooled<T> for each objective type T of AnyObjective (the
// one list of the kinds' objectives, iwr/measurement_kind.hpp), so a new kind's objective is run
// here once it is an alternative there and bound.
template <class Variant>
struct BoundObjectives;
template <class... T>
struct BoundObjectives<std::variant<T...>> {
    /// Calls f(std::shared_ptr<const U>) for the type U of `kernel`; false when it is none of them.
    template <class F>
    static bool visit(const py::handle& kernel, F&& f) {
        return (visit_one<T>(kernel, f) || ...);
    }
    /// "iwr._core.Objective, iwr._core.TrackerObjective, ...": the types accepted, for messages.
    static std::string names() {
        std::string out;
        ((out += (out.empty() ? "" : ", ") + type_name<T>()), ...);
        return out;
    }

private:
    template <class U, class F>
    static bool visit_one(const py::handle& kernel, F& f) {
        if (!py::isinstance<Pooled<U>>(kernel)) return false;
        f(std::shared_ptr<const U>(kernel.cast<Pooled<U>&>().obj_));
        return true;
    }
    template <class U>
    static std::string type_name() {
        const py::type t = py::type::of<Pooled<U>>();
        return py::cast<std::string>(t.attr("__module__")) + "." +
               py::cast<std::string>(t.attr("__qualname__"));
    }
};
using KernelTypes = BoundObjectives<AnyObjective>;

de::Settings make_settings(const std::string& strategy, const VectorXd& lower, const VectorXd& upper,
                           std::uint64_t seed, int population_size, double F, double CR,
                           const std::string& bound_rule, const py::dict& extra) {
    de::Settings s;
    s.strategy = de::parse_strategy(strategy);
    s.lower.assign(lower.data(), lower.data() + lower.size());
    s.upper.assign(upper.data(), upper.data() + upper.size());
    s.seed = seed;
    s.population_size = population_size;
    s.F = F;
    s.CR = CR;
    s.bound_rule = de::parse_bound_rule(bound_rule);
    for (auto item : extra) {
        const std::string key = py::cast<std::string>(item.first);
        py::handle v = item.second;
        if (v.is_none()) continue;
        if (key == "p_best") s.p_best = v.cast<double>();
        else if (key == "c") s.c = v.cast<double>();
        else if (key == "archive_rate") s.archive_rate = v.cast<double>();
        else if (key == "memory_size") s.memory_size = v.cast<int>();
        else if (key == "tau1") s.tau1 = v.cast<double>();
        else if (key == "tau2") s.tau2 = v.cast<double>();
        else if (key == "F_lower") s.F_lower = v.cast<double>();
        else if (key == "F_upper") s.F_upper = v.cast<double>();
        else if (key == "min_population_size") s.min_population_size = v.cast<int>();
        else if (key == "max_evaluations") s.max_evaluations = v.cast<std::int64_t>();
        else throw std::invalid_argument("options: unknown strategy parameter '" + key + "'");
    }
    return s;
}

de::Stop make_stop(std::int64_t max_generations, std::int64_t max_evaluations, double target_cost,
                   double tol, double atol, std::int64_t stagnation_generations,
                   double stagnation_tol, double max_seconds) {
    de::Stop s;
    s.max_generations = max_generations;
    s.max_evaluations = max_evaluations;
    s.target_cost = target_cost;
    s.tol = tol;
    s.atol = atol;
    s.stagnation_generations = stagnation_generations;
    s.stagnation_tol = stagnation_tol;
    s.max_seconds = max_seconds;
    if (std::isnan(target_cost)) throw std::invalid_argument("target_cost: nan");
    if (!(tol >= 0)) throw std::invalid_argument("tol: " + std::to_string(tol) + "; expected >= 0");
    if (!(atol >= 0)) throw std::invalid_argument("atol: " + std::to_string(atol) + "; expected >= 0");
    if (!(stagnation_tol >= 0))
        throw std::invalid_argument("stagnation_tol: " + std::to_string(stagnation_tol) +
                                    "; expected >= 0");
    if (!(max_seconds > 0))
        throw std::invalid_argument("max_seconds: " + std::to_string(max_seconds) + "; expected > 0");
    return s;
}

}  // namespace

void bind_de(py::module_& m) {
    m.def("max_threads", &ThreadPool::max_threads,
          "The most threads a pool takes (``workers``): 4 per CPU this process may use, at least "
          "16; more are refused.");

    m.def(
        "de_resolve",
        [](const std::string& strategy, const VectorXd& lower, const VectorXd& upper,
           std::uint64_t seed, int population_size, double F, double CR,
           const std::string& bound_rule, const py::dict& extra) {
            return settings_dict(de::resolve(make_settings(strategy, lower, upper, seed,
                                                           population_size, F, CR, bound_rule,
                                                           extra)));
        },
        py::arg("strategy"), py::arg("lower"), py::arg("upper"), py::arg("seed"),
        py::arg("population_size"), py::arg("F"), py::arg("CR"), py::arg("bound_rule"),
        py::arg("extra"), "The settings with the strategy's defaults filled in, validated.");

    m.def(
        "de_function",
        [](py::function func, const std::string& strategy, const VectorXd& lower,
           const VectorXd& upper, std::uint64_t seed, int population_size, double F, double CR,
           const std::string& bound_rule, const py::dict& extra, std::int64_t max_generations,
           std::int64_t max_evaluations, double target_cost, double tol, double atol,
           std::int64_t stagnation_generations, double stagnation_tol, double max_seconds,
           int threads, py::object monitor, bool every_generation, double interval,
           py::object resume, bool return_state) {
            const de::Settings s = make_settings(strategy, lower, upper, seed, population_size, F,
                                                 CR, bound_rule, extra);
            const de::Stop stop = make_stop(max_generations, max_evaluations, target_cost, tol,
                                            atol, stagnation_generations, stagnation_tol,
                                            max_seconds);
            Session session;
            PyFunction f(std::move(func), static_cast<int>(lower.size()), session);
            return run_de(f, session, s, stop, threads, monitor, every_generation, interval,
                          resume, return_state);
        },
        py::arg("func"), py::arg("strategy"), py::arg("lower"), py::arg("upper"), py::arg("seed"),
        py::arg("population_size"), py::arg("F"), py::arg("CR"), py::arg("bound_rule"),
        py::arg("extra"), py::arg("max_generations"), py::arg("max_evaluations"),
        py::arg("target_cost"), py::arg("tol"), py::arg("atol"), py::arg("stagnation_generations"),
        py::arg("stagnation_tol"), py::arg("max_seconds"), py::arg("threads"), py::arg("monitor"),
        py::arg("every_generation"), py::arg("interval"), py::arg("resume"),
        py::arg("return_state"));

    m.def(
        "de_kernel",
        [](const py::object& kernel, const std::vector<bool>& active, const VectorXd& x0,
           const std::string& strategy, const VectorXd& lower, const VectorXd& upper,
           std::uint64_t seed, int population_size, double F, double CR,
           const std::string& bound_rule, const py::dict& extra, std::int64_t max_generations,
           std::int64_t max_evaluations, double target_cost, double tol, double atol,
           std::int64_t stagnation_generations, double stagnation_tol, double max_seconds,
           int threads, py::object monitor, bool every_generation, double interval,
           py::object resume, bool return_state) {
            const de::Settings s = make_settings(strategy, lower, upper, seed, population_size, F,
                                                 CR, bound_rule, extra);
            const de::Stop stop = make_stop(max_generations, max_evaluations, target_cost, tol,
                                            atol, stagnation_generations, stagnation_tol,
                                            max_seconds);
            Session session;
            py::dict out;
            // The objective is shared with the Python object while the engine runs without the
            // GIL (kept alive by the shared pointer; its cost is const, each thread has its own
            // workspace), and evaluated as iwr-engine evaluates it: de::ReducedObjective<T>, the
            // trials built and evaluated in one pass of the pool.
            const bool known = KernelTypes::visit(kernel, [&](auto obj) {
                using Obj = typename decltype(obj)::element_type;
                de::ReducedObjective<Obj> f(*obj, active, x0);
                out = run_de(f, session, s, stop, threads, monitor, every_generation, interval,
                             resume, return_state);
            });
            if (!known)
                throw py::type_error("kernel: " +
                                     py::cast<std::string>(py::type::of(kernel).attr("__name__")) +
                                     " is not a C++ objective; expected one of " +
                                     KernelTypes::names());
            return out;
        },
        py::arg("kernel"), py::arg("active"), py::arg("x0"), py::arg("strategy"), py::arg("lower"),
        py::arg("upper"), py::arg("seed"), py::arg("population_size"), py::arg("F"),
        py::arg("CR"), py::arg("bound_rule"), py::arg("extra"), py::arg("max_generations"),
        py::arg("max_evaluations"), py::arg("target_cost"), py::arg("tol"), py::arg("atol"),
        py::arg("stagnation_generations"), py::arg("stagnation_tol"), py::arg("max_seconds"),
        py::arg("threads"), py::arg("monitor"), py::arg("every_generation"), py::arg("interval"),
        py::arg("resume"), py::arg("return_state"),
        "DE on a bound C++ objective (any kind's: iwr._core.Objective, TrackerObjective, ...) over "
        "its active parameters, the others held at x0: the engine of iwr-engine, no Python in the "
        "loop. TypeError for any other object.");

    // The engine's checkpoint (and result) for iwr.problem_file.engine_result: the one reader of
    // iwr/checkpoint.hpp, so Python refuses exactly what the engine refuses.
    m.def(
        "_read_checkpoint",
        [](const std::string& path) {
            Checkpoint c;
            {
                py::gil_scoped_release release;
                c = read_checkpoint(path);
            }
            de::RunResult r;
            r.success = c.success;
            r.message = c.message;
            Session session;
            py::dict d = result_dict(c.state, r, session, false);
            d["x"] = VectorXd(Eigen::Map<const VectorXd>(c.x.data(), static_cast<Eigen::Index>(c.x.size())));
            d["fun"] = c.fun;
            d["success"] = c.success;
            d["message"] = c.message;
            d["reason"] = py::none();
            d["program"] = c.program;
            d["robot_fingerprint"] = io::hex64(c.robot_fingerprint);
            d["data_fingerprint"] = io::hex64(c.data_fingerprint);
            d["settings_fingerprint"] = io::hex64(c.settings_fingerprint);
            d["problem_file"] = c.problem_file;
            d["generations"] = c.generations ? py::cast(*c.generations) : py::none();
            d["max_evaluations"] = c.max_evaluations ? py::cast(*c.max_evaluations) : py::none();
            d["target_cost"] = c.target_cost ? py::cast(*c.target_cost) : py::none();
            d["tol"] = c.tol;
            d["atol"] = c.atol;
            d["stagnation_generations"] =
                c.stagnation_generations > 0 ? py::cast(c.stagnation_generations) : py::none();
            d["stagnation_tol"] = c.stagnation_tol;
            d["checkpoint_every"] = c.checkpoint_every;
            d["preset"] = c.preset_paper ? py::cast("paper") : py::none();
            d["resumed_from"] = c.resumed_from.empty() ? py::none() : py::cast(c.resumed_from);
            d["lower"] = VectorXd(Eigen::Map<const VectorXd>(c.state.settings.lower.data(),
                                                             static_cast<Eigen::Index>(c.state.settings.lower.size())));
            d["upper"] = VectorXd(Eigen::Map<const VectorXd>(c.state.settings.upper.data(),
                                                             static_cast<Eigen::Index>(c.state.settings.upper.size())));
            d["wall_time"] = c.state.elapsed;
            return d;
        },
        py::arg("path"));
}

}  // namespace iwr::python
