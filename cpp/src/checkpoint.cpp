#include "iwr/checkpoint.hpp"

#include <cmath>
#include <limits>

#include "iwr/binary_io.hpp"

namespace iwr {

namespace {

const char kMagic[8] = {'I', 'W', 'R', 'C', 'K', 'P', 'T', '\x1a'};
constexpr std::uint64_t kMaxFile = std::uint64_t(64) << 30;
constexpr std::int64_t kInt64Max = std::numeric_limits<std::int64_t>::max();

}  // namespace

std::string encode_checkpoint(const Checkpoint& c, const de::State& state) {
    io::Writer w;
    w.str(c.program);
    w.u64(c.robot_fingerprint);
    w.u64(c.data_fingerprint);
    w.u64(c.settings_fingerprint);
    w.str(c.problem_file);
    w.i64(c.generations ? *c.generations : -1);
    w.i64(c.max_evaluations ? *c.max_evaluations : -1);
    w.f64(c.target_cost ? *c.target_cost : std::numeric_limits<double>::quiet_NaN());
    w.f64(c.tol);
    w.f64(c.atol);
    w.i64(c.stagnation_generations);
    w.f64(c.stagnation_tol);
    w.i64(c.checkpoint_every);
    w.u8(c.preset_paper ? 1 : 0);
    w.u8(c.had_log ? 1 : 0);
    w.u8(c.success ? 1 : 0);
    w.str(c.message);
    w.f64(c.fun);
    w.doubles(c.x);
    w.u64(c.active.size());
    for (std::int64_t i : c.active) w.i64(i);
    w.str(c.resumed_from);
    {
        const std::string blob = state.to_bytes();
        w.data().reserve(w.data().size() + 8 + blob.size());
        w.str(blob);
    }
    return io::seal(kMagic, kCheckpointVersion, w.data());
}

Checkpoint decode_checkpoint(const std::string& bytes, const std::string& context) {
    std::uint32_t version = 0;
    const std::string payload = io::unseal(bytes, kMagic, kOldestCheckpointVersion, kCheckpointVersion,
                                           &version, context, "an iwr-engine checkpoint");
    io::Reader r(payload.data(), payload.size(), context);
    Checkpoint c;
    c.program = r.text("program", 256);
    c.robot_fingerprint = r.u64("robot fingerprint");
    c.data_fingerprint = r.u64("data fingerprint");
    c.settings_fingerprint = r.u64("settings fingerprint");
    c.problem_file = r.text("problem file", 4096);
    const std::int64_t g = r.i64_in("generations", -1, kInt64Max);
    if (g >= 0) c.generations = g;
    const std::int64_t m = r.i64_in("max evaluations", -1, kInt64Max);
    if (m == 0) r.fail("max evaluations is 0, outside [1, 2^63)");
    if (m > 0) c.max_evaluations = m;
    const double t = r.f64("target cost");
    if (std::isinf(t)) r.fail("target cost is not finite");
    if (!std::isnan(t)) c.target_cost = t;
    auto tolerance = [&](const char* what) {
        const double v = r.f64(what);
        if (!(v >= 0 && std::isfinite(v))) r.fail(std::string(what) + " is not a finite number >= 0");
        return v;
    };
    if (version >= 4) {  // version 3 had no convergence tests: off
        c.tol = tolerance("tol");
        c.atol = tolerance("atol");
        c.stagnation_generations = r.i64_in("stagnation generations", 0, kInt64Max);
        c.stagnation_tol = tolerance("stagnation tol");
    }
    c.checkpoint_every = r.i64_in("checkpoint every", 0, kInt64Max);
    c.preset_paper = r.flag("preset");
    c.had_log = r.flag("had a log");
    c.success = r.flag("success");
    c.message = r.str("message", 4096);
    c.fun = r.f64("cost");
    if (c.success && !std::isfinite(c.fun)) r.fail("success with a cost that is not finite");
    c.x = r.doubles("x");
    const std::size_t na = r.count("active", 8);
    for (std::size_t k = 0; k < na; ++k) {
        const std::int64_t lo = c.active.empty() ? 0 : c.active.back() + 1;
        if (c.x.empty()) r.fail("active: indices into an empty x");
        // Increasing indices into x: the positions of the engine state's parameters.
        c.active.push_back(r.i64_in("active", lo, static_cast<std::int64_t>(c.x.size()) - 1));
    }
    c.resumed_from = r.text("resumed from", 4096);
    const std::string state = r.str("engine state", payload.size());
    r.finish();
    try {
        c.state = de::State::from_bytes(state);
    } catch (const io::FormatError& e) {
        r.fail(std::string("corrupt engine state (") + e.what() + ")");
    }
    if (c.active.size() != static_cast<std::size_t>(c.state.dim()))
        r.fail("active: " + std::to_string(c.active.size()) + " parameters; the engine state has " +
               std::to_string(c.state.dim()));
    for (std::size_t j = 0; j < c.x.size(); ++j)
        if (!(std::fabs(c.x[j]) <= 1e12)) r.fail("x: parameter " + std::to_string(j) + " is not finite");
    for (std::size_t k = 0; k < c.active.size(); ++k) {
        const double v = c.x[static_cast<std::size_t>(c.active[k])];
        if (!(v >= c.state.settings.lower[k] && v <= c.state.settings.upper[k]))
            r.fail("x: parameter " + std::to_string(c.active[k]) + " is outside the bounds");
    }
    return c;
}

Checkpoint read_checkpoint(const std::string& path) {
    return decode_checkpoint(io::read_file(path, "an iwr-engine checkpoint", kMaxFile), path + ": ");
}

}  // namespace iwr
