// Checkpoints of iwr-engine: a sealed container (iwr/binary_io.hpp, magic "IWRCKPT\x1a", version
// kCheckpointVersion) whose payload is, in this order:
//   str  program ("iwr-engine 0.1.0", for the record)
//   u64  robot, data and settings fingerprints (of the problem file and of the DE settings)
//   str  problem file (its path when the run started, for messages only)
//   i64  generations (-1: none), max evaluations (-1: none); f64 target cost (NaN: none)
//   f64  tol, atol (0: off); i64 stagnation generations (0: off); f64 stagnation tol (version 4
//        on; a version 3 checkpoint, without them, is read with the tests off)
//   i64  checkpoint every; u8 preset (0 none, 1 paper); u8 had a log
//   u8   success; str message; f64 cost at x; f64s x   (the run's result so far: every parameter)
//   u64  D; D i64s: the increasing positions in x of the engine state's D (active) parameters
//   str  resumed from (for the record)
//   str  the DE engine's state (iwr::de::State::to_bytes, itself sealed and checked)
// A checkpoint is untrusted input: every field is range-checked as if typed by a user, and it
// holds no output path (the run's outputs come from the command line, or from the name of the
// checkpoint itself).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "iwr/de.hpp"

namespace iwr {

constexpr std::uint32_t kCheckpointVersion = 4;  // 4: the convergence and stagnation tests
constexpr std::uint32_t kOldestCheckpointVersion = 3;  // read with the tests off

struct Checkpoint {
    std::string program;
    std::uint64_t robot_fingerprint = 0, data_fingerprint = 0, settings_fingerprint = 0;
    std::string problem_file;
    std::optional<std::int64_t> generations, max_evaluations;
    std::optional<double> target_cost;
    // The convergence test (std of the costs <= atol + tol |mean|; both 0: off) and the
    // stagnation test (the best improved by no more than stagnation_tol |best| over
    // stagnation_generations generations; 0: off): de::Stop's.
    double tol = 0, atol = 0;
    std::int64_t stagnation_generations = 0;
    double stagnation_tol = 0;
    std::int64_t checkpoint_every = 0;
    bool preset_paper = false;
    bool had_log = false;
    bool success = false;
    std::string message;
    double fun = 0;
    std::vector<double> x;
    std::vector<std::int64_t> active;  // positions in x of the state's parameters
    std::string resumed_from;
    de::State state;
};

/// The file's bytes, with `state` as the engine state (c.state is ignored: no copy of a large
/// population is made for writing).
std::string encode_checkpoint(const Checkpoint& c, const de::State& state);

/// Parses and checks file contents; `context` starts every message ("run.ckpt: "). Throws
/// io::FormatError naming the field.
Checkpoint decode_checkpoint(const std::string& bytes, const std::string& context);

/// Reads and decodes a checkpoint file (io::FormatError naming the file).
Checkpoint read_checkpoint(const std::string& path);

}  // namespace iwr
