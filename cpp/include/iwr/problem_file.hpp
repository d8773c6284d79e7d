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
//   u8   measurement kind: 0 pose of {5} in {0} (the paper's), 1 points in the tracker frame {T},
//        2 probe pose in {T}, 3 a double ballbar's distances (version 4 files only)
//   u64  poses N; f64s q (N x n), legs (N x 6)
//   kind 0: f64s poses (N x 6); u8 has weights; f64s weights (N x 6)
//   kind 1, 2 (the tracker setup, then the data):
//        f64s registration (6: nominal pose of {0} in {T})
//        kind 1: u64 reflectors K; f64s reflector offsets in {5} (K x 3); K strs reflector names;
//                f64s points (N x 3 K; a reflector not seen at a pose: its three values NaN)
//        kind 2: f64s probe pose in {5} (6); f64 probe length (mm); f64s probe poses (N x 6);
//                f64s the probe's virtual points as the objective takes them (N x 12, computed
//                from the probe poses by the writer)
//        f64s reference (4 n + 42: the robot error vector where forward kinematics is solved once)
//   kind 3 (the ballbar set-ups, then the data; iwr/ballbar.hpp): u64 set-ups S; each: str name,
//        f64s platform ball (3, in {5}), f64s fixed ball (3, in {0}), f64 offset (mm), u8 has
//        range; f64s range (2) when 1; then N u64 set-up indices, f64s distance (N), f64s reference
//   (version 3) u8 weighted; when 1: str what the weighting was made from (a noise model, in
//        words); f64s whitening (N x m^2: per pose a row-major m x m lower-triangular W_k, m the
//        residuals of a pose: 6 legs, 3 K point coordinates, 12 for a probe's four points, or 1
//        for a ballbar's distance).
//        The objective is then sum_k |W_k r_k|^2 (generalised least squares with fixed weights;
//        the leg weights of kind 0, if any, are folded into W_k and not used besides)
//   (version 4) u64 effects E (0: the geometry alone); each: str name
//        ("compliance", "thermal"), u64 keys, each: str key, u8 type (0 true/false, 1 a number,
//        2 numbers), then u8 (type 0), f64 (type 1) or u64 count and f64s (type 2): the effect's
//        table as the robot TOML's [effects.<name>] (iwr/effects.hpp); then u8 has payload;
//        f64s payload (N x 4: kg, centre of mass in {5} mm); u64 temperature columns (0, 1 or
//        6); f64s temperatures (N x that, degrees C); kinds 1, 2 with effects: f64s gravity (3: m/s^2
//        in the tracker frame {T}, carried into {0} by the identified registration, for the
//        legs' statics and the carriage's joint loads alike); kinds 0 and 3 with effects: no
//        gravity field (the effects' own gravity_m_s2, in {0}: ballbar data register no {0}).
//        Kind 3 with effects is read from this release on (iwr/effects_ballbar.hpp); an older
//        reader refuses such a file by name ("ballbar data with effects have no objective")
//   f64s lower, upper (n_params each); str bounds kind ("default", "paper" or "custom")
//   f64s x0 (n_params: where the inactive parameters stay); u64 n_params + that many u8 active
//        flags (at least one 1)
//   u64  parameter names; each a str
//   u64  sources; each: str role ("robot", "data", ...), str path, str SHA-256 (hex, or empty)
// n_params is 4 n + 42, then the effects' parameters (if any), then for tracker data the setup's
// 6 + 3 K (points) or 12 (probe), for ballbar data the set-ups' 7 S. Every
// value is checked as if a user had typed it: sizes against the file, finite numbers (NaN only
// for unseen reflectors), lower < upper, non-negative weights, names of printable ASCII.
// Versions 3 (without the effects: none on) and 2 (without the weighting either: every file
// unweighted) are read; version 1 (leg data only, no kind, x0 or active set) is refused with its
// version named.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "iwr/ballbar.hpp"
#include "iwr/effects.hpp"
#include "iwr/model.hpp"
#include "iwr/tracker.hpp"

namespace iwr {

constexpr std::uint32_t kProblemVersion = 4;
/// The oldest version read (files of version 2 are unweighted problems).
constexpr std::uint32_t kOldestProblemVersion = 2;
/// Limits that no real problem comes near; they bound what a damaged file can make us allocate.
constexpr int kMaxJoints = 64;
constexpr std::uint64_t kMaxPoses = 100'000'000;

/// What the measurements are (the problem file's "measurement kind").
enum class MeasurementKind : std::uint8_t { Pose = 0, Points = 1, Probe = 2, Ballbar = 3 };

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
    MeasurementKind kind = MeasurementKind::Pose;
    RowMatrixXd q, legs;                   // N x n, N x 6
    RowMatrixXd poses, weights;            // Pose: N x 6 and N x 6 or empty (none); else empty
    // Points and Probe: the nominal tracker setup and the data.
    Vector6d registration = Vector6d::Zero();
    RowMatrixXd reflectors;                // Points: K x 3
    std::vector<std::string> reflector_names;
    Vector6d probe = Vector6d::Zero();     // Probe
    double probe_length = 0;
    RowMatrixXd probe_poses;               // Probe: N x 6 as measured
    RowMatrixXd points;                    // N x 3 K (Points) or N x 12 (Probe): the objective's
    VectorXd reference;                    // 4 n + 42 (tracker and ballbar data)
    // Ballbar: the set-ups, each pose's set-up (an index into bars) and the bar's reading (mm).
    std::vector<BarSetup> bars;
    std::vector<int> bar;
    VectorXd distance;
    // The noise weighting (version 3; empty: unweighted, eq. (10) or the plain point residuals).
    std::string weighting;                 // what it was made from, in words
    RowMatrixXd whitening;                 // N x m^2 (m = residuals_per_pose()) or empty
    // The non-geometric effects (version 4; none: the geometry alone) and the per-pose data they
    // read: the payload (N x 4 or empty: none) and the temperatures (N x 1, N x 6 or empty).
    std::vector<EffectTable> effects;
    RowMatrixXd payload, temperatures;
    Vec3 tracker_gravity = Vec3(0, 0, -9.80665);  // tracker data with effects: gravity in {T}
    std::uint32_t version = kProblemVersion;  // the version of the file read
    std::vector<double> lower, upper;
    std::string bounds_kind;
    std::vector<double> x0;                // n_params
    std::vector<bool> active;              // n_params
    std::vector<std::string> parameter_names;
    std::vector<ProblemSource> sources;

    bool tracker() const { return kind == MeasurementKind::Points || kind == MeasurementKind::Probe; }
    bool ballbar() const { return kind == MeasurementKind::Ballbar; }
    int n_robot_params() const { return 4 * static_cast<int>(joint_types.size()) + 42; }
    /// The effects' model (their parameters after the robot's); throws std::invalid_argument.
    EffectModel effect_model() const { return EffectModel::parse(effects, n_robot_params()); }
    int n_effect_params() const { return effects.empty() ? 0 : effect_model().n_params; }
    /// The robot's, the effects', then the tracker setup's (6 + 3 K or 12) or the ballbar
    /// set-ups' (7 S).
    int n_params() const;
    int n_active() const;
    int n_poses() const { return static_cast<int>(legs.rows()); }
    /// Residuals of one pose: 6 legs, 3 K point coordinates, 12 (a probe's four points), 1 (a
    /// ballbar's distance).
    int residuals_per_pose() const;
    bool weighted() const { return whitening.size() != 0; }
    Geometry geometry() const;
    /// The nominal tracker setup (Points or Probe only).
    TrackerSetup tracker_setup() const;
    /// 64-bit fingerprints of what the objective is made of (the geometry, and for tracker data
    /// the setup and the reference; the noise weighting when weighted; the search's x0 and active
    /// set when not all zeros and all active; the effects' tables when any), and of the
    /// measurements + weights (+ payload and temperatures when any: the data file's alone; the
    /// same data weighted by another noise model keep their data fingerprint).
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
