// Checkpoint files of iwr-calibrate.
//
// Layout (all integers little-endian):
//   bytes  0..7   magic "IWRCKPT\x1a"
//   bytes  8..11  format version (kCheckpointVersion)
//   bytes 12..15  zero
//   bytes 16..23  payload size in bytes
//   bytes 24..31  FNV-1a 64 checksum of the payload
//   bytes 32..    payload: the Checkpoint fields below, the DE engine's own state blob last
//                 (iwr::de::State::serialize: population, costs, random streams, memories, log).
// A file shorter than its header says is "truncated"; a checksum mismatch is "corrupt"; both are
// refused before anything in the payload is trusted.
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace iwr::app {

constexpr std::uint32_t kCheckpointVersion = 1;

struct Checkpoint {
    std::string program;                     // "iwr-calibrate 0.1.0", for the record
    std::uint64_t robot_fingerprint = 0;     // the nominal geometry the objective uses
    std::uint64_t data_fingerprint = 0;      // the measurements (and weights)
    std::uint64_t settings_fingerprint = 0;  // every setting that shapes the run's trajectory
    std::string robot_file, data_file;       // where they were read from (for messages)
    /// The run's options that are not part of the trajectory (stopping criteria, output files),
    /// so that `--resume PATH` alone carries on with them.
    std::vector<std::pair<std::string, std::string>> options;
    std::string engine_state;                // iwr::de::State::serialize
};

/// Serialized file contents (header + payload).
std::string encode_checkpoint(const Checkpoint& c);

/// Parses file contents; throws std::runtime_error with the problem (without the file name):
/// "truncated: ...", "corrupt: ...", "not an iwr-calibrate checkpoint", ...
Checkpoint decode_checkpoint(const std::string& bytes);

}  // namespace iwr::app
