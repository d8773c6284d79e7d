// The problem file: everything the engine needs to identify a robot, written by Python after all
// of its checks (iwr.Problem.save) and read here, by the engine and (through the bindings) by
// iwr.Problem.load. One reader for both languages.
//
// A sealed container (iwr/binary_io.hpp) with magic "IWRPROB\x1a" and version kProblemVersion; the
// payload, every count before its items, all little-endian:
//   str  robot name
//   str  joint types, n letters P/R
//   f64s dh (n x 4, alpha a d theta), joint limits (n x 2), base joints (6 x 3), platform joints
//        (6 x 3), leg offsets (6), leg stroke (6 x 2), home pose (6), workspace (6)
//   u8   has measurement joint types; str measurement joint types
//   u64  poses N; f64s q (N x n), poses (N x 6), legs (N x 6)
//   u8   has weights; f64s weights (N x 6)
//   f64s lower, upper (4 n + 42 each); str bounds kind ("default", "paper" or "custom")
//   u64  parameter names; each a str
//   u64  sources; each: str role ("robot", "data", ...), str path, str SHA-256 (hex, or empty)
// Every value is checked as if a user had typed it: sizes against the file, finite numbers,
// lower < upper, non-negative weights, names of printable ASCII.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "iwr/model.hpp"

namespace iwr {

constexpr std::uint32_t kProblemVersion = 1;
/// Limits that no real problem comes near; they bound what a damaged file can make us allocate.
constexpr int kMaxJoints = 64;
constexpr std::uint64_t kMaxPoses = 100'000'000;

struct ProblemSource {
    std::string role, path, sha256;
};

struct ProblemData {
    std::string robot_name;
    std::string joint_types;
    RowMatrixXd dh, joint_limits;          // n x 4, n x 2
    LegMatrix base, platform;              // 6 x 3
    LegVector leg_offsets;                 // 6
    Eigen::Matrix<double, 6, 2, Eigen::RowMajor> leg_stroke;
    Eigen::Matrix<double, 6, 1> home_pose, workspace;
    bool has_measurement_joint_types = false;
    std::string measurement_joint_types;
    RowMatrixXd q, poses, legs, weights;   // weights empty when none
    std::vector<double> lower, upper;
    std::string bounds_kind;
    std::vector<std::string> parameter_names;
    std::vector<ProblemSource> sources;

    int n_params() const { return 4 * static_cast<int>(joint_types.size()) + 42; }
    int n_poses() const { return static_cast<int>(poses.rows()); }
    Geometry geometry() const;
    /// 64-bit fingerprints of the geometry the objective uses, and of the measurements + weights.
    std::uint64_t robot_fingerprint() const;
    std::uint64_t data_fingerprint() const;
};

/// Checks every field (std::invalid_argument "field: problem") and returns the file's bytes.
std::string encode_problem(const ProblemData& p);

/// Parses file contents; `context` starts every message ("run.iwrp: "). Throws io::FormatError
/// naming the field on anything malformed, truncated or out of range.
ProblemData decode_problem(const std::string& bytes, const std::string& context);

/// Reads and decodes a problem file (io::FormatError naming the file).
ProblemData read_problem(const std::string& path);

}  // namespace iwr
