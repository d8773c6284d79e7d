// iwr-engine: long differential-evolution calibration runs, with checkpoints and resume.
//
// Runs from one problem file (iwr.Problem.save; the iwr-calibrate launcher writes it from a robot
// TOML and a measurement CSV), with no Python at run time, so that it can be copied to a compute
// node. Runs the DE engine of iwr/de.hpp on the objective of the problem's measurements: eq. (10)
// for leg data, the tracker-space residuals of iwr/tracker.hpp for laser-tracker points or probe
// poses (one loop, search<Obj>, for both). The run's whole state
// (iwr::de::State) and its result so far go into checkpoints, so that --resume ends with exactly
// the result of a run that was never interrupted; iwr-calibrate (Python) turns the final checkpoint
// into the JSON result. See `iwr-engine --help` and docs/iwr-calibrate.md.
#include <dirent.h>
#include <fcntl.h>
#include <pthread.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <map>
#include <new>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "iwr/binary_io.hpp"
#include "iwr/checkpoint.hpp"
#include "iwr/de.hpp"
#include "iwr/measurement_kind.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"
#include "iwr/problem_file.hpp"
#include "iwr/tracker.hpp"

#ifndef IWR_VERSION
#define IWR_VERSION "unknown"
#endif

namespace {

namespace de = iwr::de;
using iwr::io::FormatError;

// The name messages start with: the one the program was started by (the iwr-calibrate launcher
// starts it as "iwr-calibrate", so that the user reads the command they typed).
const char* kProgram = "iwr-engine";
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
struct InputError : std::runtime_error {
    using std::runtime_error::runtime_error;
};

// A word for a POSIX shell, as Python's shlex.quote: the hint of an interrupted run is pasted.
std::string shell_quote(const std::string& word) {
    const bool plain = !word.empty() && word.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
                                                                "0123456789_@%+=:,./-") == std::string::npos;
    if (plain) return word;
    std::string out = "'";
    for (const char c : word) out += c == '\'' ? std::string("'\"'\"'") : std::string(1, c);
    return out + "'";
}

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

// --- command line ---------------------------------------------------------------------------------

const char* const kHelp = R"(usage: iwr-engine PROBLEM.iwrp [options]

The engine behind iwr-calibrate: identifies the error parameters of a robot by differential
evolution (DE), for long runs, from a problem file alone (no Python at run time: copy the program
and the problem file to a compute node). Progress on standard error, checkpoints, and resume
after an interruption with exactly the result of a run that was never interrupted. The same seed
and settings give the same result as iwr.identify(robot, measurements, method="de", ...),
whatever the number of threads.

positional arguments:
  PROBLEM.iwrp             the problem: robot, measurements (leg data, laser-tracker points
                           or probe poses with the nominal tracker setup, or ballbar
                           distances with the bar's set-ups), weights or the
                           noise weighting (the objective is then whitened), search
                           bounds, x0 and active set, as iwr.Problem.save or
                           iwr.tracker.TrackerProblem.save writes it (iwr-calibrate ROBOT.toml
                           DATA.csv writes it for you)

DE settings (they shape the run; a checkpoint remembers them):
  --strategy S             rand1bin (the paper's DE/rand/1/bin, default), best1bin, jade, jde,
                           shade, lshade, jso
  --population-size NP     population size (default: the strategy's published one: rand1bin,
                           best1bin 10 D; jade 30/100/400; jde, shade 100; lshade 18 D;
                           jso 25 ln(D) sqrt(D); D = 58 for the IWR, 73 with a tracker and
                           3 reflectors: the active parameters). A population whose memory
                           exceeds what the machine has available is refused with the estimate
  --F F                    scale factor (rand1bin/best1bin) or its initial value/mean (others)
  --CR CR                  crossover rate, in [0, 1] (same remark)
  --bound-rule R           out-of-bounds trial components: midpoint (default), reinit, reflect,
                           clip
  --seed N                 seed of the random streams (default 0)
  --preset paper           the paper's Table 2 for rand1bin: NP 600, F 0.9, CR 1.0, 60000
                           generations; options given explicitly take precedence. The search
                           bounds are the problem file's (iwr-calibrate --bounds paper writes
                           Table 2's literal +-0.5 everywhere)

when to stop (not part of the trajectory, lshade/jso's budget aside: may be changed when
resuming, to extend a run):
  --generations G          stop after G generations (default 1000; 60000 with --preset paper;
                           none for lshade and jso, which stop at their evaluation budget)
  --max-evaluations N      stop after N evaluations. For lshade and jso also the budget that
                           their population-size and parameter schedules run to (default
                           10000 D), hence part of their trajectory
  --target-cost C          stop as soon as the best cost is <= C (mm^2; the paper reached 1e-4;
                           a problem weighted by a noise model: the dimensionless chi-square)
  --tol T, --atol A        stop when the population's costs have converged: their standard
                           deviation <= A + T |mean| (SciPy's test; default 0 and 0: off)
  --stagnation-generations G
                           stop when the best cost improved by no more than R |best| over the
                           last G generations (default 0: off)
  --stagnation-tol R       R of the stagnation test (default 0: no improvement at all); without
                           --stagnation-generations it does nothing
                           --target-cost, --tol/--atol and the stagnation test end a run as a
                           success ("converged"); they are iwr.identify(method="de")'s options of
                           the same names. A run one of them stopped stops again at once when
                           resumed with it: to extend such a run, resume it with the test off
                           (--tol 0 --atol 0, --stagnation-generations 0) or changed

running:
  --threads T              threads evaluating the population (default 0: all the CPUs this
                           process may use; at most 4 per CPU, and at least 16 allowed); the
                           result does not depend on it
  --checkpoint PATH        where checkpoints, and the result, go (default: PROBLEM without .iwrp,
                           plus .ckpt; with --resume, the checkpoint resumed from)
  --log LOG.csv            the per-generation log: generation, nfev, best, mean, spread, elapsed
                           (rewritten at each checkpoint and at the end; give it again when
                           resuming)
  --checkpoint-every G     a checkpoint every G generations (default 10000; 0: only at the end
                           and on a signal). A checkpoint is also written at the end of the run,
                           on SIGINT/SIGTERM/SIGHUP, and on request: kill -USR1 PID.
  --resume PATH            continue the run saved in checkpoint PATH. PROBLEM.iwrp must hold the
                           robot and data it was made with. Settings not given take the
                           checkpoint's values (so --resume PATH alone carries on); settings
                           given must agree with it, except the stopping criteria. A checkpoint
                           in use is locked: a second process resuming it is refused.
  --resume-command CMD     the command that the message of an interrupted run gives to resume it
                           (default: this program, PROBLEM.iwrp, --resume and the checkpoint,
                           and --log if given; iwr-calibrate passes its own)
  --quiet                  no progress on standard error (errors are still reported)
  -h, --help               this help
  --version                the program's version

The result is the final checkpoint: its best point, cost, counters, log, success and message;
iwr-calibrate turns it into the JSON that iwr.load_result reads (iwr-calibrate --export CKPT).
No output may be an input of the same run (the problem file, the checkpoint resumed, or the
TOML/CSV files the problem was made from). Every write is atomic: a temporary file .NAME.XXXXXX
in the same folder, flushed to disk, then renamed; those a kill left behind are removed at the
next start. kill -9 loses at most the work since the last checkpoint. Progress goes to standard
error, every 0.5 s on a terminal and every 10 s otherwise.

environment:
  IWR_KERNEL               the objective's SIMD variant: baseline, avx2, avx512 (those this CPU
                           runs; --version lists them) or auto, the widest (the default). avx2
                           and avx512 give the same bits; baseline differs to rounding, so a run
                           with the same seed follows another path. The checkpoint does not
                           record it: resume with the same IWR_KERNEL (an interrupted run's
                           resume command sets it)

exit status:
  0    the run ended (its limit reached, or a test: --target-cost, --tol, the stagnation test;
       see "success" in the result)
  1    an error in the problem file, a checkpoint (missing, truncated, corrupt, locked, made for
       other data or settings), while writing, or when the system refuses a thread; the message
       names the file or the number of threads
  2    a usage error: unknown option, bad value, missing argument, an output that is an input,
       a population too large for the memory available, a bad IWR_KERNEL
  129, 130, 143
       stopped by SIGHUP, SIGINT (Ctrl-C) or SIGTERM at the end of a generation, after writing a
       final checkpoint with the best result so far (128 + the signal number). A signal ignored
       when the program starts stays ignored: nohup ignores SIGHUP, and a shell script's
       background job (cmd &) ignores SIGINT, so stop such a job with SIGTERM (kill PID).

example:
  iwr-engine run.iwrp --preset paper --seed 1 --log run.csv      # writes run.ckpt
  # ... Ctrl-C, a reboot, a time limit of the batch system ...
  iwr-engine run.iwrp --resume run.ckpt --log run.csv
)";

struct Options {
    std::vector<std::string> positional;
    // Trajectory settings: only those given are set.
    std::optional<std::string> strategy, bound_rule, preset;
    std::optional<int> population_size;
    std::optional<double> F, CR;
    std::optional<std::uint64_t> seed;
    // Stopping criteria.
    std::optional<std::int64_t> generations, max_evaluations;
    std::optional<double> target_cost;
    std::optional<double> tol, atol, stagnation_tol;
    std::optional<std::int64_t> stagnation_generations;
    // Running.
    std::optional<int> threads;
    std::optional<std::string> log, checkpoint, resume, resume_command;
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

double parse_tolerance(const std::string& opt, const std::string& v) {
    const double x = parse_real(opt, v);
    if (x < 0) throw UsageError(opt + ": " + v + " is negative; expected a number >= 0");
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
            "--strategy", "--population-size", "--F", "--CR", "--bound-rule", "--seed", "--preset",
            "--generations", "--max-evaluations", "--target-cost", "--tol", "--atol",
            "--stagnation-generations", "--stagnation-tol", "--threads", "--log",
            "--checkpoint", "--checkpoint-every", "--resume", "--resume-command"};
        bool known = false;
        for (const char* k : kValued) known = known || name == k;
        if (!known) {
            const bool launcher = name == "--output" || name == "--bounds" || name == "--problem";
            throw UsageError("unknown option '" + name + "'" +
                             (name == "--f" || name == "--cr" ? " (the options are --F and --CR)" : "") +
                             (launcher ? " (an option of iwr-calibrate, which writes the problem file "
                                         "and the JSON result)"
                                       : ""));
        }
        if (!has_value) {
            if (i + 1 >= argc) throw UsageError(name + ": expected a value");
            value = argv[++i];
        }
        if (name == "--strategy") o.strategy = value;
        else if (name == "--population-size") o.population_size = static_cast<int>(parse_int(name, value, 1, 100000000));
        else if (name == "--F") o.F = parse_real(name, value);
        else if (name == "--CR") o.CR = parse_real(name, value);
        else if (name == "--bound-rule") o.bound_rule = value;
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
        else if (name == "--tol") o.tol = parse_tolerance(name, value);
        else if (name == "--atol") o.atol = parse_tolerance(name, value);
        else if (name == "--stagnation-generations")
            o.stagnation_generations = parse_int(name, value, 0, INT64_MAX);
        else if (name == "--stagnation-tol") o.stagnation_tol = parse_tolerance(name, value);
        else if (name == "--threads") {
            const int cap = iwr::ThreadPool::max_threads();
            const std::int64_t t = parse_int(name, value, 0, INT32_MAX);
            if (t > cap)
                throw UsageError("--threads: " + value + "; at most " + std::to_string(cap) + " (" +
                                 std::to_string(iwr::ThreadPool::kThreadsPerCpu) +
                                 " per CPU this process may use, at least " +
                                 std::to_string(iwr::ThreadPool::kMinMaxThreads) + ")");
            o.threads = static_cast<int>(t);
        } else if (name == "--log") o.log = value;
        else if (name == "--checkpoint") o.checkpoint = value;
        else if (name == "--checkpoint-every") o.checkpoint_every = parse_int(name, value, 0, INT64_MAX);
        else if (name == "--resume") o.resume = value;
        else if (name == "--resume-command") o.resume_command = value;
        if ((name == "--log" || name == "--checkpoint" || name == "--resume") && value.empty())
            throw UsageError(name + ": expected a file name");
    }
    if (o.help || o.version) return o;
    if (o.positional.size() != 1)
        throw UsageError(o.positional.empty() ? "expected PROBLEM.iwrp (write one with iwr.Problem.save, or run "
                                                "iwr-calibrate ROBOT.toml DATA.csv)"
                                              : "unexpected argument '" + o.positional[1] +
                                                    "' (iwr-engine reads one problem file; iwr-calibrate "
                                                    "reads ROBOT.toml DATA.csv)");
    return o;
}

// --- fingerprints ---------------------------------------------------------------------------------

std::string real_text(double v) {
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

// The resolved settings, readable, in a fixed order (the bounds by their hash).
std::vector<std::pair<std::string, std::string>> settings_pairs(const de::Settings& s) {
    iwr::io::Hash64 b;
    b.doubles(s.lower.data(), s.lower.size()).doubles(s.upper.data(), s.upper.size());
    return {
        {"strategy", de::to_string(s.strategy)},
        {"population_size", std::to_string(s.population_size)},
        {"F", real_text(s.F)},
        {"CR", real_text(s.CR)},
        {"seed", std::to_string(s.seed)},
        {"bound_rule", de::to_string(s.bound_rule)},
        {"bounds", std::to_string(s.lower.size()) + " pairs, hash " + iwr::io::hex64(b.value())},
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
    iwr::io::Hash64 h;
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

// A CSV number: 17 significant digits, "inf"/"nan" as Python writes them.
std::string csv_number(double v) {
    if (std::isnan(v)) return "nan";
    if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
    char buf[32];
    std::snprintf(buf, sizeof buf, "%.17g", v);
    return buf;
}

// The log as CSV text, formatted incrementally: rows never change once logged, and formatting
// the whole log at every checkpoint would make a long run's checkpoints ever slower.
class LogText {
public:
    const std::string& update(const de::State& st) {
        if (rows_ > st.log.size()) rows_ = 0, text_.clear();
        if (text_.empty()) text_ = "generation,nfev,best,mean,spread,elapsed\n";
        for (; rows_ < st.log.size(); ++rows_) {
            const de::LogEntry& e = st.log[rows_];
            text_ += std::to_string(e.generation) + "," + std::to_string(e.nfev) + "," + csv_number(e.best) +
                     "," + csv_number(e.mean) + "," + csv_number(e.spread) + "," + csv_number(e.elapsed) + "\n";
        }
        return text_;
    }

private:
    std::string text_;
    std::size_t rows_ = 0;
};

struct RunInfo {
    std::string problem_file;
    bool preset_paper = false;
    int threads = 0;
    std::optional<std::int64_t> generations, max_evaluations;
    std::optional<double> target_cost;
    double tol = 0, atol = 0, stagnation_tol = 0;
    std::int64_t stagnation_generations = 0;
    std::string log, checkpoint, resumed_from;
    std::int64_t checkpoint_every = 0;
    std::uint64_t robot_fp = 0, data_fp = 0;
    std::vector<std::int64_t> active;  // positions of the searched parameters in x
    LogText log_text;
};

// The result so far: the best point, its cost evaluated afresh, and whether the run succeeded.
struct Outcome {
    bool success = false;
    std::string message;
    double fun = 0;
    iwr::VectorXd x;
};

// A setting that a resumed run may change: the command line's, else the checkpoint's (else `to`
// is left as it is).
template <class T, class V>
void take(T& to, const std::optional<V>& given, const std::optional<iwr::Checkpoint>& saved,
          T iwr::Checkpoint::*field) {
    if (given) to = *given;
    else if (saved) to = (*saved).*field;
}

void write_checkpoint_file(const de::State& st, const RunInfo& info, const Outcome& out) {
    iwr::Checkpoint c;
    c.program = std::string(kProgram) + " " + IWR_VERSION;
    c.robot_fingerprint = info.robot_fp;
    c.data_fingerprint = info.data_fp;
    c.settings_fingerprint = settings_fingerprint(st.settings);
    c.problem_file = one_line(info.problem_file);
    c.generations = info.generations;
    c.max_evaluations = info.max_evaluations;
    c.target_cost = info.target_cost;
    c.tol = info.tol;
    c.atol = info.atol;
    c.stagnation_generations = info.stagnation_generations;
    c.stagnation_tol = info.stagnation_tol;
    c.checkpoint_every = info.checkpoint_every;
    c.preset_paper = info.preset_paper;
    c.had_log = !info.log.empty();
    c.success = out.success;
    c.message = out.message;
    c.fun = out.fun;
    c.x.assign(out.x.data(), out.x.data() + out.x.size());
    c.active = info.active;
    c.resumed_from = one_line(info.resumed_from);
    iwr::io::atomic_write(info.checkpoint, iwr::encode_checkpoint(c, st));
}

// --- files: no output onto an input, one process per checkpoint, no stale temporary files ---------

std::string folder_of(const std::string& path) {
    const size_t slash = path.find_last_of('/');
    return slash == std::string::npos ? "." : (slash == 0 ? "/" : path.substr(0, slash));
}

std::string base_of(const std::string& path) {
    const size_t slash = path.find_last_of('/');
    return slash == std::string::npos ? path : path.substr(slash + 1);
}

// The same file (st_dev and st_ino, so after every link is resolved); false if either is missing.
bool same_file(const std::string& a, const std::string& b) {
    struct stat sa {}, sb {};
    if (::stat(a.c_str(), &sa) != 0 || ::stat(b.c_str(), &sb) != 0) return false;
    return sa.st_dev == sb.st_dev && sa.st_ino == sb.st_ino;
}

// Fails now, not at the end of a long run, if an output file's folder is missing or read-only.
void check_writable(const std::string& path, const char* what) {
    const std::string dir = folder_of(path);
    if (base_of(path).empty()) throw UsageError(path + ": not a file name for the " + what);
    if (::access(dir.c_str(), F_OK) != 0)
        throw InputError(path + ": cannot write the " + what + " here: folder " + dir + " does not exist");
    if (::access(dir.c_str(), W_OK) != 0)
        throw InputError(path + ": cannot write the " + what + " here: folder " + dir + " is not writable");
    struct stat st {};
    if (::stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode))
        throw InputError(path + ": is a folder; cannot write the " + what + " there");
}

// Holds an exclusive flock on a lock file next to a checkpoint (".NAME.lock"): the checkpoint
// itself is replaced by a rename at every write, so a lock on it would not outlive the first write.
class CheckpointLock {
public:
    explicit CheckpointLock(const std::string& checkpoint) {
        const std::string dir = folder_of(checkpoint);
        path_ = (checkpoint.find('/') == std::string::npos ? "" : dir + "/") + "." + base_of(checkpoint) + ".lock";
        fd_ = ::open(path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
        if (fd_ < 0)
            throw InputError(checkpoint + ": cannot create its lock file " + path_ + " (" + std::strerror(errno) + ")");
        if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
            const int err = errno;
            ::close(fd_);
            if (err == EWOULDBLOCK)
                throw InputError(checkpoint + ": in use by another iwr-engine process (locked: " + path_ +
                                 "); wait for it to end or stop it");
            throw InputError(checkpoint + ": cannot lock " + path_ + " (" + std::strerror(err) + ")");
        }
    }
    ~CheckpointLock() { ::close(fd_); }  // the lock file stays: removing it would race a new locker
    CheckpointLock(const CheckpointLock&) = delete;
    CheckpointLock& operator=(const CheckpointLock&) = delete;

private:
    std::string path_;
    int fd_ = -1;
};

// Removes the temporary files ".NAME.XXXXXX" that an atomic write of `path` killed part way left
// (mkstemp's six letters or digits; nothing else matches). Called with the checkpoint locked, so
// no live writer of these names exists.
int remove_stale_temporaries(const std::string& path) {
    const std::string dir = folder_of(path), prefix = "." + base_of(path) + ".";
    DIR* d = ::opendir(dir.c_str());
    if (!d) return 0;
    int removed = 0;
    while (const dirent* e = ::readdir(d)) {
        const std::string name = e->d_name;
        if (name.size() != prefix.size() + 6 || name.compare(0, prefix.size(), prefix) != 0) continue;
        bool random = true;
        for (size_t k = prefix.size(); k < name.size(); ++k)
            random = random && std::isalnum(static_cast<unsigned char>(name[k]));
        if (random && ::unlink((dir + "/" + name).c_str()) == 0) ++removed;
    }
    ::closedir(d);
    return removed;
}

// --- the run --------------------------------------------------------------------------------------

bool budgeted(de::Strategy s) { return s == de::Strategy::lshade || s == de::Strategy::jso; }

// iwr::de::resolve names the Settings field ("population_size: 2; ..."); say the option instead.
std::string as_option_message(const std::string& msg) {
    static const std::map<std::string, std::string> names = {
        {"population_size", "--population-size"}, {"F", "--F"}, {"CR", "--CR"}, {"seed", "--seed"},
        {"bound_rule", "--bound-rule"}, {"strategy", "--strategy"}, {"threads", "--threads"}};
    const size_t colon = msg.find(':');
    if (colon == std::string::npos) return msg;
    const auto it = names.find(msg.substr(0, colon));
    return it == names.end() ? msg : it->second + msg.substr(colon);
}

// Applies the settings given on the command line to `s` (a fresh default, or a checkpoint's).
void apply_settings(const Options& o, de::Settings& s) {
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
}

// The default checkpoint of a problem file: its name without ".iwrp", plus ".ckpt".
std::string default_checkpoint(const std::string& problem) {
    const std::string ext = ".iwrp";
    if (problem.size() > ext.size() && problem.compare(problem.size() - ext.size(), ext.size(), ext) == 0)
        return problem.substr(0, problem.size() - ext.size()) + ".ckpt";
    return problem + ".ckpt";
}

// The poses whose model fails at x carry a penalty (tracker data: no forward kinematics): never a
// success.
template <class Obj>
std::string unsolved(const Obj& objective, const iwr::VectorXd& x) {
    const auto bad = iwr::objective_failures(objective, x);
    if (bad.empty()) return "";
    return std::to_string(bad.size()) + " of " + std::to_string(objective.n_poses()) +
           " poses have no forward kinematics at the result (pose " + std::to_string(bad.front().first) + ": " +
           bad.front().second + ")";
}

const char* kind_text(iwr::MeasurementKind k) {
    switch (k) {
        case iwr::MeasurementKind::Points: return " (points in the tracker frame)";
        case iwr::MeasurementKind::Probe: return " (probe poses in the tracker frame)";
        case iwr::MeasurementKind::Ballbar: return " (ballbar distances)";
        default: return "";
    }
}

// The active entries of a full-length vector.
std::vector<double> active_part(const std::vector<double>& v, const std::vector<bool>& active) {
    std::vector<double> out;
    for (std::size_t i = 0; i < v.size(); ++i)
        if (active[i]) out.push_back(v[i]);
    return out;
}

template <class Obj>
int search(const Options& o, const iwr::ProblemData& problem, const Obj& objective);

int run(const Options& o) {
    const std::string& problem_path = o.positional[0];
    iwr::ProblemData problem;
    try {
        problem = iwr::read_problem(problem_path);
    } catch (const FormatError& e) {
        throw InputError(e.what());
    }
    // The objective of the measurement kind (iwr/measurement_kind.hpp): eq. (10) on leg readings,
    // or the tracker residuals, whitened when the problem is weighted by a noise model.
    std::optional<iwr::AnyObjective> objective;
    try {
        objective.emplace(iwr::make_objective(problem));
    } catch (const iwr::ForwardKinematicsError& e) {
        throw InputError(problem_path + ": pose " + std::to_string(e.pose()) +
                         ": the leg readings have no forward kinematics for the robot at the reference "
                         "parameters (" + e.what() + ")");
    } catch (const std::invalid_argument& e) {
        throw InputError(problem_path + ": " + e.what());
    }
    return std::visit([&](const auto& obj) { return search(o, problem, obj); }, *objective);
}

// The run on either objective: one engine loop, checkpoints and resume for every kind of data.
template <class Obj>
int search(const Options& o, const iwr::ProblemData& problem, const Obj& objective) {
    const std::string& problem_path = o.positional[0];
    const std::vector<double> lower = active_part(problem.lower, problem.active);
    const std::vector<double> upper = active_part(problem.upper, problem.active);
    RunInfo info;
    info.problem_file = problem_path;
    info.robot_fp = problem.robot_fingerprint();
    info.data_fp = problem.data_fingerprint();
    info.threads = iwr::ThreadPool::resolve(o.threads.value_or(0));
    if (info.threads > iwr::ThreadPool::max_threads())  // all the CPUs is always allowed
        info.threads = iwr::ThreadPool::max_threads();

    // The files: outputs named now, checked against the inputs before anything is read or written.
    info.checkpoint = o.checkpoint ? *o.checkpoint : (o.resume ? *o.resume : default_checkpoint(problem_path));
    info.log = o.log.value_or("");
    std::vector<std::pair<std::string, std::string>> inputs = {{problem_path, "the problem file"}};
    const bool resume_elsewhere = o.resume && *o.resume != info.checkpoint && !same_file(*o.resume, info.checkpoint);
    if (o.resume) {
        struct stat st {};
        if (::stat(o.resume->c_str(), &st) != 0) throw InputError(*o.resume + ": no such file");
    }
    if (resume_elsewhere) inputs.emplace_back(*o.resume, "the checkpoint resumed");
    for (const auto& src : problem.sources)
        if (!src.path.empty()) inputs.emplace_back(src.path, "the " + src.role + " file the problem was made from");
    std::vector<std::pair<std::string, std::string>> outputs = {{info.checkpoint, "--checkpoint"}};
    if (!info.log.empty()) outputs.emplace_back(info.log, "--log");
    for (const auto& out : outputs) {
        for (const auto& in : inputs)
            if (out.first == in.first || same_file(out.first, in.first))
                throw UsageError(out.second + ": " + out.first + " is " + in.second +
                                 "; an output may not overwrite an input");
    }
    if (!info.log.empty() && (info.log == info.checkpoint || same_file(info.log, info.checkpoint)))
        throw UsageError("--log: " + info.log + " is also the checkpoint");
    if (!info.log.empty() && o.resume && same_file(info.log, *o.resume))
        throw UsageError("--log: " + info.log + " is the checkpoint resumed");
    check_writable(info.checkpoint, "checkpoint");
    if (!info.log.empty()) check_writable(info.log, "log");

    // One process per checkpoint: the one written, and the one resumed if it is another file.
    std::optional<CheckpointLock> lock_out, lock_in;
    lock_out.emplace(info.checkpoint);
    if (resume_elsewhere) lock_in.emplace(*o.resume);
    remove_stale_temporaries(info.checkpoint);
    if (!info.log.empty()) remove_stale_temporaries(info.log);

    std::optional<de::State> state;
    std::optional<iwr::Checkpoint> saved;
    if (o.resume) {
        const std::string& path = *o.resume;
        try {
            saved = iwr::read_checkpoint(path);
        } catch (const FormatError& e) {
            throw InputError(e.what());
        }
        const iwr::Checkpoint& c = *saved;
        if (c.robot_fingerprint != info.robot_fp)
            throw InputError(path + ": made for another robot (problem " + c.problem_file + "); the geometry" +
                             (problem.tracker() ? ", the tracker setup" : problem.ballbar() ? ", the ballbar set-ups" : "") +
                             (problem.weighted() ? ", the noise weighting" : "") + " or the search's x0 and active set in " +
                             problem_path + " differ");
        if (c.data_fingerprint != info.data_fp) {
            std::string from;
            for (const auto& src : problem.sources)
                if (src.role == "data") from = " (from " + src.path + ")";
            throw InputError(path + ": made for other data (problem " + c.problem_file + "); the measurements in " +
                             problem_path + from + " differ");
        }
        if (settings_fingerprint(c.state.settings) != c.settings_fingerprint)
            throw InputError(path + ": corrupt: the settings fingerprint does not match the engine state");
        if (c.state.dim() != problem.n_active())
            throw InputError(path + ": made for " + std::to_string(c.state.dim()) + " parameters; " +
                             problem_path + " has " + std::to_string(problem.n_active()) + " active");
        state = c.state;
        de::Settings wanted = state->settings;
        wanted.lower = lower;
        wanted.upper = upper;
        try {
            apply_settings(o, wanted);
        } catch (const std::invalid_argument& e) {
            throw UsageError(as_option_message(e.what()));
        }
        // Another strategy than the checkpoint's: said as such (resolved with the checkpoint's
        // own settings, jade's p_best of 0 from rand1bin was refused as an option never given).
        if (wanted.strategy != state->settings.strategy)
            throw InputError(path + ": made with other settings (strategy " + de::to_string(wanted.strategy) +
                             " here, " + de::to_string(state->settings.strategy) + " in the checkpoint)");
        try {
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
        info.preset_paper = c.preset_paper;
        if (c.had_log && info.log.empty() && !o.quiet)
            std::fprintf(stderr, "%s: note: the run had a log; give --log again to keep writing it (the "
                                 "result holds the whole history anyway)\n", kProgram);
    } else {
        de::Settings s;
        s.lower = lower;
        s.upper = upper;
        try {
            apply_settings(o, s);
            s = de::resolve(s);
        } catch (const std::invalid_argument& e) {
            throw UsageError(as_option_message(e.what()));
        }
        info.preset_paper = o.preset.has_value();
        state.emplace();
        state->settings = s;  // init() below replaces the whole state
    }
    // Memory: refused up front, with the estimate, rather than killed part way.
    try {
        de::require_memory(state->settings, iwr::io::available_memory());
    } catch (const std::invalid_argument& e) {
        throw UsageError(as_option_message(e.what()));
    }

    // Stopping criteria: the command line, else the checkpoint's, else the defaults.
    take(info.generations, o.generations, saved, &iwr::Checkpoint::generations);
    take(info.max_evaluations, o.max_evaluations, saved, &iwr::Checkpoint::max_evaluations);
    take(info.target_cost, o.target_cost, saved, &iwr::Checkpoint::target_cost);
    take(info.tol, o.tol, saved, &iwr::Checkpoint::tol);
    take(info.atol, o.atol, saved, &iwr::Checkpoint::atol);
    take(info.stagnation_generations, o.stagnation_generations, saved,
         &iwr::Checkpoint::stagnation_generations);
    take(info.stagnation_tol, o.stagnation_tol, saved, &iwr::Checkpoint::stagnation_tol);
    // The defaults of iwr.identify(method="de"): the paper's 60000 generations with its preset;
    // lshade and jso run to their evaluation budget (10000 D unless given); others 1000 generations.
    const bool budget = budgeted(state->settings.strategy);
    if (!o.resume) {
        if (!info.generations && o.preset) info.generations = 60000;
        if (budget && !info.max_evaluations) info.max_evaluations = state->settings.max_evaluations;
        if (!info.generations && !info.max_evaluations) info.generations = kDefaultGenerations;
    }
    info.checkpoint_every = kDefaultCheckpointEvery;
    take(info.checkpoint_every, o.checkpoint_every, saved, &iwr::Checkpoint::checkpoint_every);

    de::Stop stop;
    if (info.generations) stop.max_generations = *info.generations;
    if (info.max_evaluations) stop.max_evaluations = *info.max_evaluations;
    if (info.target_cost) stop.target_cost = *info.target_cost;
    stop.tol = info.tol;
    stop.atol = info.atol;
    stop.stagnation_generations = info.stagnation_generations;
    stop.stagnation_tol = info.stagnation_tol;
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

    de::ReducedObjective<Obj> f(objective, problem.active,
                                Eigen::Map<const iwr::VectorXd>(problem.x0.data(), problem.n_params()));
    info.active.assign(f.active_index().begin(), f.active_index().end());
    // The pool's threads start with our signals blocked, so the handlers always run on this thread,
    // the one that reads the flags (a sig_atomic_t is only safe within one thread).
    sigset_t ours, previous;
    sigemptyset(&ours);
    for (int sig : {SIGINT, SIGTERM, SIGHUP, SIGUSR1}) sigaddset(&ours, sig);
    pthread_sigmask(SIG_BLOCK, &ours, &previous);
    std::optional<iwr::ThreadPool> pool;
    try {
        pool.emplace(info.threads);
    } catch (...) {
        pthread_sigmask(SIG_SETMASK, &previous, nullptr);
        throw;
    }
    install(SIGINT, on_stop_signal);
    install(SIGTERM, on_stop_signal);
    install(SIGHUP, on_stop_signal);
    install(SIGUSR1, on_checkpoint_signal);
    pthread_sigmask(SIG_SETMASK, &previous, nullptr);
    Progress progress(!o.quiet, stop.max_generations);

    if (o.resume) {
        progress.message("resuming " + info.resumed_from + " at generation " + std::to_string(state->generation) +
                         " (best cost " + real_text(state->best_cost()) + ")");
    } else {
        const std::string active = problem.n_active() == problem.n_params()
                                       ? ""
                                       : " (" + std::to_string(problem.n_active()) + " active)";
        const int n_effects = problem.n_effect_params();
        std::string setup = n_effects ? ", " + std::to_string(n_effects) + " of them the effects'" : "";
        if (problem.tracker() || problem.ballbar())
            setup += ", " + std::to_string(problem.n_params() - problem.n_robot_params() - n_effects) +
                     (n_effects ? "" : " of them") +
                     (problem.ballbar() ? " the ballbar set-ups'" : " the tracker setup's");
        progress.message(std::to_string(problem.n_params()) + " parameters" + setup + active + ", " +
                         std::to_string(problem.n_poses()) + " poses" + kind_text(problem.kind) +
                         (problem.weighted() ? ", weighted by the noise (" + problem.weighting + ")" : "") + "; " + de::to_string(state->settings.strategy) + ", NP " +
                         std::to_string(state->settings.population_size) + ", seed " +
                         std::to_string(state->settings.seed) + ", " + std::to_string(info.threads) + " thread(s)");
        progress.start(0, 0);
        *state = de::init(state->settings, f, *pool);
    }
    if (o.resume) progress.start(state->generation, state->nfev);

    auto outcome = [&](bool success, const std::string& message) {
        Outcome out;
        out.x = f.full(state->best_x().data());
        out.fun = objective.cost(out.x);
        out.success = success;
        out.message = message;
        const std::string failed = unsolved(objective, out.x);
        if (!failed.empty()) {
            out.success = false;
            out.message += "; " + failed;
        }
        // A cost that is not finite is never a success (and the result still loads: the JSON
        // writer of iwr-calibrate writes it as Infinity/NaN, which iwr.load_result reads).
        if (!std::isfinite(out.fun)) {
            out.success = false;
            out.message += "; the best cost is not finite (" + real_text(out.fun) +
                           "): the data are far outside what the robot model can fit";
        }
        return out;
    };
    auto callback = [&](const de::State& st) {
        progress.update(st);
        if (g_stop_signal) return true;
        const bool due = info.checkpoint_every > 0 && st.generation % info.checkpoint_every == 0;
        if (due || g_checkpoint_request) {
            g_checkpoint_request = 0;
            write_checkpoint_file(st, info, outcome(false, "checkpoint at generation " +
                                                               std::to_string(st.generation) +
                                                               "; the run was still going"));
            if (!info.log.empty()) iwr::io::atomic_write(info.log, info.log_text.update(st));
        }
        return false;
    };
    de::RunResult rr;
    if (!g_stop_signal) rr = de::run(*state, f, *pool, stop, callback);
    const int sig = g_stop_signal;
    const bool interrupted = sig != 0 && (rr.reason == de::StopReason::callback || rr.reason == de::StopReason::none);
    progress.update(*state, true);

    std::string message = rr.message;
    bool success = rr.success;
    if (interrupted) {
        const std::string command =
            o.resume_command ? *o.resume_command
                             : iwr::kernel_environment_prefix() + kProgram + " " +
                                   shell_quote(problem_path) + " --resume " +
                                   shell_quote(info.checkpoint) +
                                   (info.log.empty() ? "" : " --log " + shell_quote(info.log));
        message = std::string("interrupted by ") + signal_name(sig) + " at generation " +
                  std::to_string(state->generation) + "; continue with: " + command;
        success = false;
    }
    const Outcome out = outcome(success, message);
    // The checkpoint (what a resume needs, and the result), then the log.
    write_checkpoint_file(*state, info, out);
    if (!info.log.empty()) iwr::io::atomic_write(info.log, info.log_text.update(*state));
    const double secs = progress.session_seconds();
    const long long ev = static_cast<long long>(progress.session_nfev(*state));
    char summary[512];
    std::snprintf(summary, sizeof summary,
                  "best cost %.6e at generation %lld, %lld evaluations (%lld in this session: %.1f s, "
                  "%.0f/s); checkpoint and result in %s",
                  out.fun, static_cast<long long>(state->generation), static_cast<long long>(state->nfev), ev, secs,
                  secs > 0 ? static_cast<double>(ev) / secs : 0.0, info.checkpoint.c_str());
    progress.message(out.message);
    progress.message(summary);
    return interrupted ? 128 + sig : kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
    if (argc > 0 && argv[0] && *argv[0]) {
        const char* slash = std::strrchr(argv[0], '/');
        kProgram = slash ? slash + 1 : argv[0];
        if (!*kProgram) kProgram = "iwr-engine";
    }
    // At a file-size limit (ulimit -f) a write then fails with EFBIG, which the writers report
    // naming the file and clean up after, instead of SIGXFSZ killing the engine silently with a
    // temporary file left behind (as Python does).
    std::signal(SIGXFSZ, SIG_IGN);
    try {
        const Options o = parse_args(argc, argv);
        if (o.help) {
            std::fputs(kHelp, stdout);
            return kExitOk;
        }
        try {
            iwr::select_kernel_from_environment();
        } catch (const std::invalid_argument& e) {
            throw UsageError(e.what());
        }
        if (o.version) {
            std::printf("%s %s (%s)\n", kProgram, IWR_VERSION, iwr::kernel_summary().c_str());
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
