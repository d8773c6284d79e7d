// iwr-calibrate: long differential-evolution calibration runs, with checkpoints and resume.
//
// Reads the robot TOML and measurement CSV that the Python package writes, runs the DE engine of
// iwr/de.hpp on the objective of eq. (10), and writes a result that iwr.load_result reads. The run's
// whole state (iwr::de::State) goes into checkpoints, so that --resume ends with exactly the result
// of a run that was never interrupted. See `iwr-calibrate --help` and docs/iwr-calibrate.md.
#include <pthread.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstdint>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <iostream>
#include <map>
#include <new>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "checkpoint.hpp"
#include "files.hpp"
#include "inputs.hpp"
#include "iwr/de.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"

#ifndef IWR_VERSION
#define IWR_VERSION "unknown"
#endif

namespace {

using iwr::app::InputError;
namespace de = iwr::de;

const char* const kProgram = "iwr-calibrate";
constexpr int kExitOk = 0;
constexpr int kExitError = 1;
constexpr int kExitUsage = 2;
constexpr std::int64_t kDefaultGenerations = 1000;
// A paper-sized checkpoint (population, streams, the per-generation log) takes 25-75 ms to write;
// 10000 generations take 2-4 s on the development machine (1000 made checkpoints 10-35 % of the run).
constexpr std::int64_t kDefaultCheckpointEvery = 10000;

// --- signals: the handlers only set flags; the generation loop acts on them ------------------------

volatile std::sig_atomic_t g_stop_signal = 0;
volatile std::sig_atomic_t g_checkpoint_request = 0;

extern "C" void on_stop_signal(int sig) { g_stop_signal = sig; }
extern "C" void on_checkpoint_signal(int) { g_checkpoint_request = 1; }

void install(int sig, void (*handler)(int)) {
    struct sigaction old {};
    sigaction(sig, nullptr, &old);
    // A signal that is ignored when we start (nohup, a background job of a non-interactive shell)
    // stays ignored, as the shell intended.
    if (old.sa_handler == SIG_IGN) return;
    struct sigaction sa {};
    sa.sa_handler = handler;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = SA_RESTART;
    sigaction(sig, &sa, nullptr);
}

const char* signal_name(int sig) {
    switch (sig) {
        case SIGINT: return "SIGINT";
        case SIGTERM: return "SIGTERM";
        case SIGHUP: return "SIGHUP";
        default: return "a signal";
    }
}

// --- errors -------------------------------------------------------------------------------------

struct UsageError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// One line on standard error, whatever a message quotes (a key or a file name may hold a newline):
// control characters and Unicode line separators escaped.
std::string one_line(const std::string& msg) {
    std::string out;
    for (size_t i = 0; i < msg.size(); ++i) {
        const unsigned char c = static_cast<unsigned char>(msg[i]);
        const bool separator = (c == 0xE2 && i + 2 < msg.size() && static_cast<unsigned char>(msg[i + 1]) == 0x80 &&
                                (static_cast<unsigned char>(msg[i + 2]) == 0xA8 ||
                                 static_cast<unsigned char>(msg[i + 2]) == 0xA9)) ||
                               (c == 0xC2 && i + 1 < msg.size() && static_cast<unsigned char>(msg[i + 1]) == 0x85);
        if (c < 0x20 || c == 0x7f) {
            char buf[8];
            std::snprintf(buf, sizeof buf, "\\x%02x", c);
            out += c == '\n' ? "\\n" : c == '\r' ? "\\r" : c == '\t' ? "\\t" : buf;
        } else if (separator) {
            out += c == 0xC2 ? "\\x85" : static_cast<unsigned char>(msg[i + 2]) == 0xA8 ? "\\u2028" : "\\u2029";
            i += c == 0xC2 ? 1 : 2;
        } else {
            out += msg[i];
        }
    }
    return out;
}

// --- command line -------------------------------------------------------------------------------

const char* const kHelp = R"(usage: iwr-calibrate ROBOT.toml DATA.csv [options]

Identify the error parameters of a robot by differential evolution (DE), for long runs: progress on
standard error, checkpoints, and resume after an interruption with exactly the result of a run that
was never interrupted. Reads the robot TOML (iwr.Robot.to_toml) and measurement CSV
(iwr.Measurements.to_csv) of the iwr Python package; writes a JSON result that iwr.load_result()
reads. The same seed and settings give the same result as iwr.identify(robot, measurements,
method="de", ...), whatever the number of threads.

positional arguments:
  ROBOT.toml               the nominal robot (lengths in mm, angles in rad)
  DATA.csv                 the measurements: joint readings, measured poses, leg readings

DE settings (they shape the run; a checkpoint remembers them):
  --strategy S             rand1bin (the paper's DE/rand/1/bin, default), best1bin, jade, jde,
                           shade, lshade, jso
  --population-size NP     population size (default: the strategy's published one: rand1bin,
                           best1bin 10 D; jade 30/100/400; jde, shade 100; lshade 18 D;
                           jso 25 ln(D) sqrt(D); D = 58 for the IWR)
  --F F                    scale factor (rand1bin/best1bin) or its initial value/mean (others)
  --CR CR                  crossover rate, in [0, 1] (same remark)
  --bounds B               search bounds: default (+-0.5 mm for lengths, +-0.5 degree for
                           angles) or paper (+-0.5 for every parameter, Table 2 literally)
  --bound-rule R           out-of-bounds trial components: midpoint (default), reinit, reflect,
                           clip
  --seed N                 seed of the random streams (default 0)
  --preset paper           the paper's Table 2 for rand1bin: NP 600, F 0.9, CR 1.0, 60000
                           generations; options given explicitly take precedence. As in
                           iwr.identify, the bounds stay as they are (add --bounds paper for
                           Table 2's literal +-0.5 everywhere)

when to stop (not part of the trajectory, lshade/jso's budget aside: may be changed when
resuming, to extend a run):
  --generations G          stop after G generations (default 1000; 60000 with --preset paper;
                           none for lshade and jso, which stop at their evaluation budget)
  --max-evaluations N      stop after N evaluations. For lshade and jso also the budget that
                           their population-size and parameter schedules run to (default
                           10000 D), hence part of their trajectory
  --target-cost C          stop as soon as the best cost is <= C (mm^2; the paper reached 1e-4)

running:
  --threads T              threads evaluating the population (default 0: all cores); the result
                           does not depend on it
  --output RESULT          the JSON result (default iwr-result.json)
  --log LOG.csv            the per-generation log: generation, nfev, best, mean, spread, elapsed
                           (rewritten at each checkpoint and at the end)
  --checkpoint PATH        where checkpoints go (default RESULT.ckpt; with --resume, the
                           checkpoint resumed from)
  --checkpoint-every G     a checkpoint every G generations (default 10000; 0: only at the end
                           and on a signal). A checkpoint is also written at the end of the run,
                           on SIGINT/SIGTERM/SIGHUP, and on request: kill -USR1 PID.
  --resume PATH            continue the run saved in checkpoint PATH. ROBOT.toml and DATA.csv
                           must be those it was made with. Settings not given take the
                           checkpoint's values (so --resume PATH alone carries on); settings
                           given must agree with it, except the stopping criteria.
  --quiet                  no progress on standard error (errors are still reported)
  -h, --help               this help
  --version                the program's version

Every write (result, log, checkpoint) is atomic: a temporary file in the same folder, flushed to
disk, then renamed. kill -9 loses at most the work since the last checkpoint. Progress goes to
standard error, every 0.5 s on a terminal and every 10 s otherwise.

exit status:
  0    the run ended (generations done or target reached; see "success" in the result)
  1    an error in the input files, a checkpoint (missing, truncated, corrupt, made for other
       data or settings) or while writing; the message names the file
  2    a usage error: unknown option, bad value, missing argument
  129, 130, 143
       stopped by SIGHUP, SIGINT (Ctrl-C) or SIGTERM at the end of a generation, after writing a
       final checkpoint and the best result so far (128 + the signal number). A signal ignored
       when the program starts stays ignored: nohup ignores SIGHUP, and a shell script's
       background job (cmd &) ignores SIGINT, so stop such a job with SIGTERM (kill PID).

example:
  iwr-calibrate robot.toml data.csv --preset paper --seed 1 --output run.json --log run.csv
  # ... Ctrl-C, a reboot, a time limit of the batch system ...
  iwr-calibrate robot.toml data.csv --resume run.json.ckpt
)";

struct Options {
    std::vector<std::string> positional;
    // Trajectory settings: only those given are set.
    std::optional<std::string> strategy, bounds, bound_rule, preset;
    std::optional<int> population_size;
    std::optional<double> F, CR;
    std::optional<std::uint64_t> seed;
    // Stopping criteria.
    std::optional<std::int64_t> generations, max_evaluations;
    std::optional<double> target_cost;
    // Running.
    std::optional<int> threads;
    std::optional<std::string> output, log, checkpoint, resume;
    std::optional<std::int64_t> checkpoint_every;
    bool quiet = false, help = false, version = false;
};

std::int64_t parse_int(const std::string& opt, const std::string& v, std::int64_t lo, std::int64_t hi) {
    errno = 0;
    char* end = nullptr;
    const long long x = std::strtoll(v.c_str(), &end, 10);
    if (v.empty() || end != v.c_str() + v.size() || errno == ERANGE)
        throw UsageError(opt + ": '" + v + "' is not an integer");
    if (x < lo || x > hi)
        throw UsageError(opt + ": " + v + " is out of range [" + std::to_string(lo) + ", " +
                         std::to_string(hi) + "]");
    return x;
}

double parse_real(const std::string& opt, const std::string& v) {
    char* end = nullptr;
    const double x = std::strtod(v.c_str(), &end);
    if (v.empty() || end != v.c_str() + v.size() || v.find_first_of("xX") != std::string::npos)
        throw UsageError(opt + ": '" + v + "' is not a number");
    if (!std::isfinite(x)) throw UsageError(opt + ": " + v + " is not finite");
    return x;
}

Options parse_args(int argc, char** argv) {
    Options o;
    bool only_positional = false;
    for (int i = 1; i < argc; ++i) {
        std::string arg = argv[i];
        if (only_positional || arg.size() < 2 || arg[0] != '-') {
            o.positional.push_back(arg);
            continue;
        }
        if (arg == "--") {
            only_positional = true;
            continue;
        }
        if (arg == "-h" || arg == "--help") {
            o.help = true;
            continue;
        }
        if (arg == "--version") {
            o.version = true;
            continue;
        }
        if (arg == "--quiet" || arg == "-q") {
            o.quiet = true;
            continue;
        }
        std::string name = arg, value;
        bool has_value = false;
        const size_t eq = arg.find('=');
        if (arg.rfind("--", 0) == 0 && eq != std::string::npos) {
            name = arg.substr(0, eq);
            value = arg.substr(eq + 1);
            has_value = true;
        }
        static const char* const kValued[] = {
            "--strategy", "--population-size", "--F", "--CR", "--bounds", "--bound-rule",
            "--seed", "--preset", "--generations", "--max-evaluations", "--target-cost",
            "--threads", "--output",
            "--log", "--checkpoint", "--checkpoint-every", "--resume"};
        bool known = false;
        for (const char* k : kValued) known = known || name == k;
        if (!known) {
            throw UsageError("unknown option '" + name + "'" +
                             (name == "--f" || name == "--cr" ? " (the options are --F and --CR)" : ""));
        }
        if (!has_value) {
            if (i + 1 >= argc) throw UsageError(name + ": expected a value");
            value = argv[++i];
        }
        if (name == "--strategy") o.strategy = value;
        else if (name == "--population-size") o.population_size = static_cast<int>(parse_int(name, value, 1, 100000000));
        else if (name == "--F") o.F = parse_real(name, value);
        else if (name == "--CR") o.CR = parse_real(name, value);
        else if (name == "--bounds") {
            if (value != "default" && value != "paper")
                throw UsageError("--bounds: '" + value + "'; expected default or paper");
            o.bounds = value;
        } else if (name == "--bound-rule") o.bound_rule = value;
        else if (name == "--seed") {
            if (value.empty() || value[0] == '-') throw UsageError("--seed: '" + value + "'; expected an integer >= 0");
            errno = 0;
            char* end = nullptr;
            const unsigned long long s = std::strtoull(value.c_str(), &end, 10);
            if (end != value.c_str() + value.size() || errno == ERANGE)
                throw UsageError("--seed: '" + value + "'; expected an integer in [0, 2^64)");
            o.seed = s;
        } else if (name == "--preset") {
            if (value != "paper") throw UsageError("--preset: '" + value + "'; the only preset is paper");
            o.preset = value;
        } else if (name == "--generations") o.generations = parse_int(name, value, 0, INT64_MAX);
        else if (name == "--max-evaluations") o.max_evaluations = parse_int(name, value, 1, INT64_MAX);
        else if (name == "--target-cost") o.target_cost = parse_real(name, value);
        else if (name == "--threads") o.threads = static_cast<int>(parse_int(name, value, 0, 4096));
        else if (name == "--output") o.output = value;
        else if (name == "--log") o.log = value;
        else if (name == "--checkpoint") o.checkpoint = value;
        else if (name == "--checkpoint-every") o.checkpoint_every = parse_int(name, value, 0, INT64_MAX);
        else if (name == "--resume") o.resume = value;
        if ((name == "--output" || name == "--log" || name == "--checkpoint" || name == "--resume") &&
            value.empty())
            throw UsageError(name + ": expected a file name");
    }
    if (o.help || o.version) return o;
    if (o.positional.size() != 2)
        throw UsageError(o.positional.size() < 2 ? "expected ROBOT.toml and DATA.csv"
                                                 : "unexpected argument '" + o.positional[2] + "'");
    return o;
}

// --- fingerprints ---------------------------------------------------------------------------------

std::uint64_t robot_fingerprint(const iwr::app::RobotFile& r) {
    iwr::app::Hash64 h;
    h.str("robot").str(r.joint_types);
    h.doubles(r.dh.data(), static_cast<std::size_t>(r.dh.size()));
    h.doubles(r.base.data(), 18).doubles(r.platform.data(), 18).doubles(r.leg_offsets.data(), 6);
    return h.value();
}

std::uint64_t data_fingerprint(const iwr::app::MeasurementFile& m) {
    iwr::app::Hash64 h;
    h.str("measurements").str(m.joint_types);
    for (const iwr::RowMatrixXd* a : {&m.q, &m.poses, &m.legs, &m.weights}) {
        h.u64(static_cast<std::uint64_t>(a->rows())).u64(static_cast<std::uint64_t>(a->cols()));
        h.doubles(a->data(), static_cast<std::size_t>(a->size()));
    }
    return h.value();
}

std::string real_text(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

// The resolved settings, readable, in a fixed order (the bounds by their hash).
std::vector<std::pair<std::string, std::string>> settings_pairs(const de::Settings& s) {
    iwr::app::Hash64 b;
    b.doubles(s.lower.data(), s.lower.size()).doubles(s.upper.data(), s.upper.size());
    return {
        {"strategy", de::to_string(s.strategy)},
        {"population_size", std::to_string(s.population_size)},
        {"F", real_text(s.F)},
        {"CR", real_text(s.CR)},
        {"seed", std::to_string(s.seed)},
        {"bound_rule", de::to_string(s.bound_rule)},
        {"bounds", std::to_string(s.lower.size()) + " pairs, hash " + iwr::app::hex64(b.value())},
        {"p_best", real_text(s.p_best)},
        {"c", real_text(s.c)},
        {"archive_rate", real_text(s.archive_rate)},
        {"memory_size", std::to_string(s.memory_size)},
        {"tau1", real_text(s.tau1)},
        {"tau2", real_text(s.tau2)},
        {"F_lower", real_text(s.F_lower)},
        {"F_upper", real_text(s.F_upper)},
        {"min_population_size", std::to_string(s.min_population_size)},
        {"max_evaluations", std::to_string(s.max_evaluations)},
    };
}

std::uint64_t settings_fingerprint(const de::Settings& s) {
    iwr::app::Hash64 h;
    h.str("settings");
    for (const auto& kv : settings_pairs(s)) h.str(kv.first).str(kv.second);
    return h.value();
}

// --- progress on standard error -----------------------------------------------------------------

using Clock = std::chrono::steady_clock;

std::string hms(double seconds) {
    if (!std::isfinite(seconds) || seconds < 0) return "?";
    const long long s = static_cast<long long>(seconds + 0.5);
    char buf[48];
    std::snprintf(buf, sizeof buf, "%lld:%02lld:%02lld", s / 3600, (s / 60) % 60, s % 60);
    return buf;
}

class Progress {
public:
    Progress(bool enabled, std::int64_t max_generations)
        : enabled_(enabled), tty_(enabled && ::isatty(STDERR_FILENO)),
          interval_(tty_ ? 0.5 : 10.0), max_gen_(max_generations) {}

    /// The session starts now, at this generation and evaluation count.
    void start(std::int64_t generation, std::int64_t nfev) {
        start_ = last_ = Clock::now();
        gen0_ = generation;
        nfev0_ = nfev;
    }

    void update(const de::State& st, bool force = false) {
        if (!enabled_) return;
        const auto now = Clock::now();
        if (!force && std::chrono::duration<double>(now - last_).count() < interval_) return;
        last_ = now;
        const double secs = std::chrono::duration<double>(now - start_).count();
        const double rate = secs > 0 ? static_cast<double>(st.nfev - nfev0_) / secs : 0.0;
        std::string left = "?";
        if (max_gen_ >= 0 && st.generation > gen0_ && secs > 0) {
            const double per_gen = secs / static_cast<double>(st.generation - gen0_);
            left = hms(per_gen * static_cast<double>(std::max<std::int64_t>(0, max_gen_ - st.generation)));
        }
        char line[256];
        std::snprintf(line, sizeof line,
                      "%s: generation %lld%s  best %.6e  %.0f evals/s  elapsed %s  left %s", kProgram,
                      static_cast<long long>(st.generation),
                      max_gen_ >= 0 ? ("/" + std::to_string(max_gen_)).c_str() : "", st.best_cost(),
                      rate, hms(st.elapsed).c_str(), left.c_str());
        if (tty_) {
            std::fprintf(stderr, "\r%s\033[K", line);
            dirty_ = true;
        } else {
            std::fprintf(stderr, "%s\n", line);
        }
        std::fflush(stderr);
    }

    // Ends the \r-updated line before another message.
    void finish_line() {
        if (dirty_) std::fputc('\n', stderr);
        dirty_ = false;
    }

    void message(const std::string& text) {
        if (!enabled_) return;
        finish_line();
        std::fprintf(stderr, "%s: %s\n", kProgram, text.c_str());
        std::fflush(stderr);
    }

    double session_seconds() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }
    std::int64_t session_nfev(const de::State& st) const { return st.nfev - nfev0_; }

private:
    bool enabled_, tty_;
    double interval_;
    std::int64_t max_gen_;
    Clock::time_point start_, last_;
    std::int64_t gen0_ = 0, nfev0_ = 0;
    bool dirty_ = false;
};

// --- outputs --------------------------------------------------------------------------------------

// The log as CSV text, formatted incrementally: rows never change once logged, and formatting
// the whole log at every checkpoint would make a long run's checkpoints ever slower.
class LogText {
public:
    const std::string& update(const de::State& st) {
        if (rows_ > st.log.size()) rows_ = 0, text_.clear();
        if (text_.empty()) text_ = "generation,nfev,best,mean,spread,elapsed\n";
        for (; rows_ < st.log.size(); ++rows_) {
            const de::LogEntry& e = st.log[rows_];
            text_ += std::to_string(e.generation) + "," + std::to_string(e.nfev) + "," +
                     iwr::app::csv_number(e.best) + "," + iwr::app::csv_number(e.mean) + "," +
                     iwr::app::csv_number(e.spread) + "," + iwr::app::csv_number(e.elapsed) + "\n";
        }
        return text_;
    }

private:
    std::string text_;
    std::size_t rows_ = 0;
};

struct RunInfo {
    std::string robot_file, data_file;
    std::string bounds_kind;  // "default", "paper" or "checkpoint"
    std::string preset;
    int n_poses = 0;
    int threads = 0;
    std::optional<std::int64_t> generations, max_evaluations;
    std::optional<double> target_cost;
    std::string output, log, checkpoint, resumed_from;
    std::int64_t checkpoint_every = 0;
    std::uint64_t robot_fp = 0, data_fp = 0;
    LogText log_text;
};

std::string json_doubles(const std::vector<double>& v) {
    std::string out = "[";
    for (size_t i = 0; i < v.size(); ++i) out += (i ? ", " : "") + iwr::app::json_number(v[i]);
    return out + "]";
}

std::string result_json(const de::State& st, const iwr::VectorXd& x, double fun,
                        const std::vector<std::string>& names, bool success,
                        const std::string& message, const RunInfo& info) {
    using iwr::app::json_number;
    using iwr::app::json_string;
    const de::Settings& s = st.settings;
    std::ostringstream o;
    o << "{\n";
    o << " \"format\": \"iwr-result\",\n \"version\": 1,\n \"method\": \"de\",\n";
    o << " \"x\": " << json_doubles(std::vector<double>(x.data(), x.data() + x.size())) << ",\n";
    o << " \"parameter_names\": [";
    for (size_t i = 0; i < names.size(); ++i) o << (i ? ", " : "") << json_string(names[i]);
    o << "],\n";
    o << " \"fun\": " << json_number(fun) << ",\n";
    o << " \"nfev\": " << st.nfev << ",\n \"nit\": " << st.generation << ",\n";
    o << " \"success\": " << (success ? "true" : "false") << ",\n";
    o << " \"message\": " << json_string(message) << ",\n";
    o << " \"wall_time\": " << json_number(st.elapsed) << ",\n";
    o << " \"settings\": {\n";
    auto num_or_null = [](double v) { return std::isfinite(v) ? json_number(v) : std::string("null"); };
    std::vector<std::pair<std::string, std::string>> kv = {
        {"strategy", json_string(de::to_string(s.strategy))},
        {"population_size", std::to_string(s.population_size)},
        {"F", num_or_null(s.F)},
        {"CR", num_or_null(s.CR)},
        {"seed", std::to_string(s.seed)},
        {"bound_rule", json_string(de::to_string(s.bound_rule))},
        {"bounds", json_string(info.bounds_kind)},
        {"lower", json_doubles(s.lower)},
        {"upper", json_doubles(s.upper)},
        {"p_best", num_or_null(s.p_best)},
        {"c", num_or_null(s.c)},
        {"archive_rate", num_or_null(s.archive_rate)},
        {"memory_size", std::to_string(s.memory_size)},
        {"tau1", num_or_null(s.tau1)},
        {"tau2", num_or_null(s.tau2)},
        {"F_lower", num_or_null(s.F_lower)},
        {"F_upper", num_or_null(s.F_upper)},
        {"min_population_size", std::to_string(s.min_population_size)},
        {"generations", info.generations ? std::to_string(*info.generations) : "null"},
        {"max_evaluations", info.max_evaluations ? std::to_string(*info.max_evaluations) : "null"},
        {"target_cost", info.target_cost ? json_number(*info.target_cost) : "null"},
        {"preset", info.preset.empty() ? "null" : json_string(info.preset)},
        {"workers", std::to_string(info.threads)},
        {"robot", json_string(info.robot_file)},
        {"data", json_string(info.data_file)},
        {"n_poses", std::to_string(info.n_poses)},
        {"checkpoint", json_string(info.checkpoint)},
        {"checkpoint_every", std::to_string(info.checkpoint_every)},
        {"resumed_from", info.resumed_from.empty() ? "null" : json_string(info.resumed_from)},
        {"robot_fingerprint", json_string(iwr::app::hex64(info.robot_fp))},
        {"data_fingerprint", json_string(iwr::app::hex64(info.data_fp))},
        {"settings_fingerprint", json_string(iwr::app::hex64(settings_fingerprint(s)))},
        {"program", json_string(std::string(kProgram) + " " + IWR_VERSION)},
    };
    for (size_t i = 0; i < kv.size(); ++i)
        o << "  " << json_string(kv[i].first) << ": " << kv[i].second << (i + 1 < kv.size() ? ",\n" : "\n");
    o << " },\n";
    o << " \"history\": {\n";
    std::vector<double> gen, nfev, best, mean, spread, elapsed;
    for (const de::LogEntry& e : st.log) {
        gen.push_back(static_cast<double>(e.generation));
        nfev.push_back(static_cast<double>(e.nfev));
        best.push_back(e.best);
        mean.push_back(e.mean);
        spread.push_back(e.spread);
        elapsed.push_back(e.elapsed);
    }
    auto ints = [](const std::vector<double>& v) {
        std::string out = "[";
        for (size_t i = 0; i < v.size(); ++i) out += (i ? ", " : "") + std::to_string(static_cast<long long>(v[i]));
        return out + "]";
    };
    o << "  \"generation\": " << ints(gen) << ",\n";
    o << "  \"nfev\": " << ints(nfev) << ",\n";
    o << "  \"best\": " << json_doubles(best) << ",\n";
    o << "  \"mean\": " << json_doubles(mean) << ",\n";
    o << "  \"spread\": " << json_doubles(spread) << ",\n";
    o << "  \"elapsed\": " << json_doubles(elapsed) << "\n";
    o << " }\n}\n";
    return o.str();
}

std::string serialize_state(const de::State& st) {
    std::ostringstream out(std::ios::binary);
    st.serialize(out);
    return out.str();
}

std::vector<std::pair<std::string, std::string>> run_options(const RunInfo& info) {
    std::vector<std::pair<std::string, std::string>> o;
    if (info.generations) o.emplace_back("generations", std::to_string(*info.generations));
    if (info.max_evaluations) o.emplace_back("max_evaluations", std::to_string(*info.max_evaluations));
    if (info.target_cost) o.emplace_back("target_cost", real_text(*info.target_cost));
    o.emplace_back("output", info.output);
    if (!info.log.empty()) o.emplace_back("log", info.log);
    o.emplace_back("checkpoint_every", std::to_string(info.checkpoint_every));
    o.emplace_back("bounds", info.bounds_kind);
    if (!info.preset.empty()) o.emplace_back("preset", info.preset);
    return o;
}

void write_checkpoint_file(const de::State& st, const RunInfo& info) {
    iwr::app::Checkpoint c;
    c.program = std::string(kProgram) + " " + IWR_VERSION;
    c.robot_fingerprint = info.robot_fp;
    c.data_fingerprint = info.data_fp;
    c.settings_fingerprint = settings_fingerprint(st.settings);
    c.robot_file = info.robot_file;
    c.data_file = info.data_file;
    c.options = run_options(info);
    c.engine_state = serialize_state(st);
    iwr::app::atomic_write(info.checkpoint, iwr::app::encode_checkpoint(c));
}

// A checkpoint and the log as far as it goes.
void write_checkpoint(const de::State& st, RunInfo& info) {
    write_checkpoint_file(st, info);
    if (!info.log.empty()) iwr::app::atomic_write(info.log, info.log_text.update(st));
}

// --- the run --------------------------------------------------------------------------------------

std::string option_or(const std::vector<std::pair<std::string, std::string>>& kv, const std::string& key,
                      const std::string& fallback) {
    for (const auto& p : kv)
        if (p.first == key) return p.second;
    return fallback;
}

bool has_option(const std::vector<std::pair<std::string, std::string>>& kv, const std::string& key) {
    for (const auto& p : kv)
        if (p.first == key) return true;
    return false;
}

// A number among a checkpoint's saved options (its checksum matched, so a bad one means a file
// written by another program).
template <class T>
T saved_number(const std::vector<std::pair<std::string, std::string>>& kv, const std::string& key,
               const std::string& path) {
    const std::string text = option_or(kv, key, "");
    std::istringstream in(text);
    T v{};
    in >> v;
    if (text.empty() || in.fail() || !in.eof())
        throw InputError(path + ": corrupt: option " + key + " is '" + text + "'");
    return v;
}

// Fails now, not at the end of a long run, if an output file's folder is missing or read-only.
void check_writable(const std::string& path, const char* what) {
    const size_t slash = path.find_last_of('/');
    const std::string dir = slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash));
    if (::access(dir.c_str(), F_OK) != 0)
        throw InputError(path + ": cannot write the " + what + " here: folder " + dir + " does not exist");
    if (::access(dir.c_str(), W_OK) != 0)
        throw InputError(path + ": cannot write the " + what + " here: folder " + dir + " is not writable");
}

bool budgeted(de::Strategy s) { return s == de::Strategy::lshade || s == de::Strategy::jso; }

// iwr::de::resolve names the Settings field ("population_size: 2; ..."); say the option instead.
std::string as_option_message(const std::string& msg) {
    static const std::map<std::string, std::string> names = {
        {"population_size", "--population-size"}, {"F", "--F"}, {"CR", "--CR"}, {"seed", "--seed"},
        {"bound_rule", "--bound-rule"}, {"strategy", "--strategy"}, {"lower", "--bounds"},
        {"upper", "--bounds"}};
    const size_t colon = msg.find(':');
    if (colon == std::string::npos) return msg;
    const auto it = names.find(msg.substr(0, colon));
    return it == names.end() ? msg : it->second + msg.substr(colon);
}

// Applies the settings given on the command line to `s` (a fresh default, or a checkpoint's).
void apply_settings(const Options& o, const iwr::app::RobotFile& robot, de::Settings& s) {
    const bool paper = o.preset.has_value();
    if (o.strategy) s.strategy = de::parse_strategy(*o.strategy, "--strategy");
    if (paper && s.strategy != de::Strategy::rand1bin)
        throw UsageError("--preset: 'paper' is the paper's DE/rand/1/bin; got strategy '" +
                         de::to_string(s.strategy) + "'");
    if (o.population_size) s.population_size = *o.population_size;
    else if (paper) s.population_size = 600;
    if (o.F) s.F = *o.F;
    else if (paper) s.F = 0.9;
    if (o.CR) s.CR = *o.CR;
    else if (paper) s.CR = 1.0;
    if (o.bound_rule) s.bound_rule = de::parse_bound_rule(*o.bound_rule, "--bound-rule");
    if (o.seed) s.seed = *o.seed;
    // lshade and jso plan their schedules over an evaluation budget: part of the trajectory.
    if (o.max_evaluations && budgeted(s.strategy)) s.max_evaluations = *o.max_evaluations;
    if (o.bounds) {
        iwr::VectorXd lo, hi;
        iwr::app::default_bounds(robot, *o.bounds, lo, hi);
        s.lower.assign(lo.data(), lo.data() + lo.size());
        s.upper.assign(hi.data(), hi.data() + hi.size());
    }
}

int run(const Options& o) {
    const std::string& robot_path = o.positional[0];
    const std::string& data_path = o.positional[1];
    const iwr::app::RobotFile robot = iwr::app::read_robot(robot_path);
    const iwr::app::MeasurementFile data = iwr::app::read_measurements(data_path);
    iwr::app::check_measurements(data, robot, data_path);  // as `iwr calibrate` checks them
    std::optional<iwr::Objective> objective;
    try {
        objective.emplace(robot.geometry(), data.q, data.poses, data.legs, data.weights);
    } catch (const std::invalid_argument& e) {
        throw InputError(data_path + ": " + e.what());
    }

    RunInfo info;
    info.robot_file = robot_path;
    info.data_file = data_path;
    info.n_poses = data.n_poses();
    info.robot_fp = robot_fingerprint(robot);
    info.data_fp = data_fingerprint(data);
    info.threads = iwr::ThreadPool::resolve(o.threads.value_or(0));

    std::optional<de::State> state;
    std::vector<std::pair<std::string, std::string>> saved;  // the checkpoint's run options
    if (o.resume) {
        const std::string& path = *o.resume;
        iwr::app::Checkpoint c;
        try {
            c = iwr::app::decode_checkpoint(iwr::app::read_file(path, "a checkpoint"));
        } catch (const InputError&) {
            throw;
        } catch (const std::runtime_error& e) {
            throw InputError(path + ": " + e.what());
        }
        if (c.robot_fingerprint != info.robot_fp)
            throw InputError(path + ": made for another robot (" + c.robot_file +
                             "); the geometry in " + robot_path + " differs");
        if (c.data_fingerprint != info.data_fp)
            throw InputError(path + ": made for other data (" + c.data_file + "); the measurements in " +
                             data_path + " differ");
        try {
            std::istringstream in(c.engine_state, std::ios::binary);
            state = de::State::deserialize(in);
        } catch (const std::exception& e) {
            throw InputError(path + ": corrupt engine state (" + e.what() + ")");
        }
        if (settings_fingerprint(state->settings) != c.settings_fingerprint)
            throw InputError(path + ": corrupt: the settings fingerprint does not match the engine state");
        if (state->dim() != robot.geometry().n_params())
            throw InputError(path + ": made for " + std::to_string(state->dim()) + " parameters; " +
                             robot_path + " has " + std::to_string(robot.geometry().n_params()));
        saved = c.options;
        de::Settings wanted = state->settings;
        try {
            apply_settings(o, robot, wanted);
            wanted = de::resolve(wanted);
        } catch (const std::invalid_argument& e) {
            throw UsageError(as_option_message(e.what()));
        }
        if (wanted != state->settings) {
            std::string diff;
            const auto a = settings_pairs(wanted), b = settings_pairs(state->settings);
            for (size_t i = 0; i < a.size(); ++i)
                if (a[i].second != b[i].second)
                    diff += (diff.empty() ? "" : "; ") + a[i].first + " " + a[i].second + " here, " +
                            b[i].second + " in the checkpoint";
            throw InputError(path + ": made with other settings (" + diff + ")");
        }
        info.resumed_from = path;
        info.bounds_kind = option_or(saved, "bounds", "default");
        info.preset = option_or(saved, "preset", "");
    } else {
        de::Settings s;
        iwr::VectorXd lo, hi;
        iwr::app::default_bounds(robot, "default", lo, hi);
        s.lower.assign(lo.data(), lo.data() + lo.size());
        s.upper.assign(hi.data(), hi.data() + hi.size());
        try {
            apply_settings(o, robot, s);
            s = de::resolve(s);
        } catch (const std::invalid_argument& e) {
            throw UsageError(as_option_message(e.what()));
        }
        info.bounds_kind = o.bounds.value_or("default");
        info.preset = o.preset.value_or("");
        state.emplace();
        state->settings = s;  // init() below replaces the whole state
    }

    // Stopping criteria and outputs: the command line, else the checkpoint's, else the defaults.
    if (o.generations) info.generations = *o.generations;
    else if (has_option(saved, "generations"))
        info.generations = saved_number<std::int64_t>(saved, "generations", *o.resume);
    if (o.max_evaluations) info.max_evaluations = *o.max_evaluations;
    else if (has_option(saved, "max_evaluations"))
        info.max_evaluations = saved_number<std::int64_t>(saved, "max_evaluations", *o.resume);
    if (o.target_cost) info.target_cost = *o.target_cost;
    else if (has_option(saved, "target_cost"))
        info.target_cost = saved_number<double>(saved, "target_cost", *o.resume);
    // The defaults of iwr.identify(method="de"): the paper's 60000 generations with its preset;
    // lshade and jso run to their evaluation budget (10000 D unless given); others 1000 generations.
    const bool budget = budgeted(state->settings.strategy);
    if (!o.resume) {
        if (!info.generations && o.preset) info.generations = 60000;
        if (budget && !info.max_evaluations) info.max_evaluations = state->settings.max_evaluations;
        if (!info.generations && !info.max_evaluations) info.generations = kDefaultGenerations;
    }
    info.output = o.output ? *o.output : option_or(saved, "output", "iwr-result.json");
    info.log = o.log ? *o.log : option_or(saved, "log", "");
    info.checkpoint = o.checkpoint ? *o.checkpoint : (o.resume ? *o.resume : info.output + ".ckpt");
    info.checkpoint_every = kDefaultCheckpointEvery;
    if (o.checkpoint_every) info.checkpoint_every = *o.checkpoint_every;
    else if (has_option(saved, "checkpoint_every"))
        info.checkpoint_every = saved_number<std::int64_t>(saved, "checkpoint_every", *o.resume);
    check_writable(info.output, "result");
    check_writable(info.checkpoint, "checkpoint");
    if (!info.log.empty()) check_writable(info.log, "log");

    de::Stop stop;
    if (info.generations) stop.max_generations = *info.generations;
    if (info.max_evaluations) stop.max_evaluations = *info.max_evaluations;
    if (info.target_cost) stop.target_cost = *info.target_cost;
    if (!o.resume) {
        try {
            de::require_budget_for_init(state->settings, stop);
        } catch (const std::invalid_argument& e) {
            const std::string msg = e.what();  // "max_evaluations: ..." -> "--max-evaluations: ..."
            const std::size_t colon = msg.find(':');
            throw UsageError(colon == std::string::npos ? "--max-evaluations: " + msg
                                                        : "--max-evaluations" + msg.substr(colon));
        }
    }

    de::ObjectiveFunction f(*objective);
    // The pool's threads start with our signals blocked, so the handlers always run on this thread,
    // the one that reads the flags (a sig_atomic_t is only safe within one thread).
    sigset_t ours, previous;
    sigemptyset(&ours);
    for (int sig : {SIGINT, SIGTERM, SIGHUP, SIGUSR1}) sigaddset(&ours, sig);
    pthread_sigmask(SIG_BLOCK, &ours, &previous);
    iwr::ThreadPool pool(info.threads);
    install(SIGINT, on_stop_signal);
    install(SIGTERM, on_stop_signal);
    install(SIGHUP, on_stop_signal);
    install(SIGUSR1, on_checkpoint_signal);
    pthread_sigmask(SIG_SETMASK, &previous, nullptr);
    Progress progress(!o.quiet, stop.max_generations);

    if (o.resume) {
        progress.message("resuming " + info.resumed_from + " at generation " +
                         std::to_string(state->generation) + " (best cost " + real_text(state->best_cost()) + ")");
    } else {
        progress.message(std::to_string(robot.geometry().n_params()) + " parameters, " +
                         std::to_string(info.n_poses) + " poses; " + de::to_string(state->settings.strategy) +
                         ", NP " + std::to_string(state->settings.population_size) + ", seed " +
                         std::to_string(state->settings.seed) + ", " + std::to_string(info.threads) +
                         " thread(s)");
        progress.start(0, 0);
        *state = de::init(state->settings, f, pool);
    }
    if (o.resume) progress.start(state->generation, state->nfev);

    auto callback = [&](const de::State& st) {
        progress.update(st);
        if (g_stop_signal) return true;
        const bool due = info.checkpoint_every > 0 && st.generation % info.checkpoint_every == 0;
        if (due || g_checkpoint_request) {
            g_checkpoint_request = 0;
            write_checkpoint(st, info);
        }
        return false;
    };
    de::RunResult rr;
    if (!g_stop_signal) rr = de::run(*state, f, pool, stop, callback);
    const int sig = g_stop_signal;
    const bool interrupted = sig != 0 && (rr.reason == de::StopReason::callback || rr.reason == de::StopReason::none);
    progress.update(*state, true);

    std::string message = rr.message;
    bool success = rr.success;
    if (interrupted) {
        message = std::string("interrupted by ") + signal_name(sig) + " at generation " +
                  std::to_string(state->generation) + "; continue with --resume " + info.checkpoint;
        success = false;
    }
    // The checkpoint first (what a resume needs), then the result, then the log.
    write_checkpoint_file(*state, info);
    const iwr::VectorXd x = f.full(state->best_x().data());
    const double fun = objective->cost(x);
    iwr::app::atomic_write(info.output, result_json(*state, x, fun, robot.parameter_names(), success,
                                                    message, info));
    if (!info.log.empty()) iwr::app::atomic_write(info.log, info.log_text.update(*state));
    const double secs = progress.session_seconds();
    const long long ev = static_cast<long long>(progress.session_nfev(*state));
    char summary[512];
    std::snprintf(summary, sizeof summary,
                  "best cost %.6e at generation %lld, %lld evaluations (%lld in this session: %.1f s, "
                  "%.0f/s); result in %s, checkpoint in %s",
                  fun, static_cast<long long>(state->generation), static_cast<long long>(state->nfev),
                  ev, secs, secs > 0 ? static_cast<double>(ev) / secs : 0.0, info.output.c_str(),
                  info.checkpoint.c_str());
    progress.message(message);
    progress.message(summary);
    return interrupted ? 128 + sig : kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
    try {
        const Options o = parse_args(argc, argv);
        if (o.help) {
            std::fputs(kHelp, stdout);
            return kExitOk;
        }
        if (o.version) {
            std::printf("%s %s\n", kProgram, IWR_VERSION);
            return kExitOk;
        }
        return run(o);
    } catch (const UsageError& e) {
        std::fprintf(stderr, "%s: error: %s (see %s --help)\n", kProgram, one_line(e.what()).c_str(), kProgram);
        return kExitUsage;
    } catch (const std::bad_alloc&) {
        std::fprintf(stderr, "%s: error: out of memory\n", kProgram);
        return kExitError;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "%s: error: %s\n", kProgram, one_line(e.what()).c_str());
        return kExitError;
    } catch (...) {
        std::fprintf(stderr, "%s: error: unexpected internal error\n", kProgram);
        return kExitError;
    }
}
