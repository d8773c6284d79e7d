// Double-ballbar data (docs/ballbar.md): one distance per pose between a ball on the platform and a
// ball fixed in the world frame, in one of several bar set-ups. The kind iwr.ballbar in the C++
// core: its objective (for DE, CRS2, BOBYQA and iwr-engine, through make_objective of
// iwr/measurement_kind.hpp) and its section of the problem file (iwr/problem_file.hpp).
//
// Residual k, pose k measured in set-up s = bar[k]:
//
//     r_k = w_k ( |T_05,k(x) P_s - F_s| + o_s - d_k )                                    (mm)
//
//   * T_05,k: the platform pose by the robot's forward kinematics from the pose's joint and leg
//     readings (the carriage, then the hexapod's forward solve from a reference solution): the
//     kinematics of the tracker objective (iwr/tracker.hpp), a probe at the origin of {5} in a
//     tracker frame equal to {0}, whose four virtual points (the origin and the tips of {5}'s unit
//     axes) give the origin o_k and the axes a_kj of {5} in {0}, so T_05,k P = o_k + sum_j P_j a_kj.
//     iwr.ballbar.BallbarProblem does the same in NumPy on the same kernel.
//   * P_s = P_nom,s + x[nr + 7 s .. +2] (the platform ball in {5}), F_s = F_nom,s + x[nr + 7 s + 3
//     .. +5] (the fixed ball in {0}), o_s = o_nom,s + x[nr + 7 s + 6] (the bar's length offset),
//     nr = 4 n + 42 the robot's parameters; d_k the bar's reading.
//   * w_k: 1, or the noise weighting's 1 / sigma_k (set_whitening: the whitening of the other
//     kinds with one residual per pose, a 1 x 1 lower-triangular W_k).
//
// A pose whose forward kinematics fails gets r_k = w_k kFailedResidual (a large finite penalty);
// failures(x) names such poses. The cost is sum_k r_k^2, summed in pose order: a row's cost never
// depends on the thread that evaluates it.
#pragma once

#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "iwr/model.hpp"
#include "iwr/parallel.hpp"
#include "iwr/tracker.hpp"

namespace iwr {

/// One placement of the bar (iwr.ballbar.BarSetup): its name, the nominal centres of the platform
/// ball (in {5}) and of the fixed ball (in {0}), the nominal length offset (reading minus centre
/// distance, mm) and, when given, the bar's range of centre distances (mm; simulation only).
struct BarSetup {
    std::string name;
    Vec3 platform_ball = Vec3::Zero(), fixed_ball = Vec3::Zero();
    double offset = 0;
    bool has_range = false;
    double range_min = 0, range_max = 0;
    bool operator==(const BarSetup& o) const {
        return name == o.name && platform_ball == o.platform_ball && fixed_ball == o.fixed_ball &&
               offset == o.offset && has_range == o.has_range && range_min == o.range_min &&
               range_max == o.range_max;
    }
};

/// The parameters of one set-up after the robot's: px, py, pz, fx, fy, fz, offset.
constexpr int kBarParams = 7;

namespace detail {

/// The bar's side of the ballbar objectives: the set-ups, each pose's set-up and reading, the
/// weights, and the residuals r_k = w_k (|T_05,k P_s - F_s| + o_s - d_k) from the frames of {5}
/// in {0}.
class BarReadings {
public:
    /// Checks (std::invalid_argument): at least one set-up, finite balls and offsets, one set-up
    /// index (in range) and one finite distance per pose of n.
    BarReadings(std::vector<BarSetup> bars, std::vector<int> bar, VectorXd distance, int n);

    const std::vector<BarSetup>& bars() const { return bars_; }
    int n_setups() const { return static_cast<int>(bars_.size()); }
    /// BallbarObjective::set_whitening.
    void set_whitening(const RowMatrixXd& whitening);
    bool whitened() const { return weights_.size() != 0; }

    /// The residuals into res (N; may be null) and their cost, summed in pose order; xs the
    /// set-ups' parameters (kBarParams per set-up), frames (N x 12) per pose the origin of {5}
    /// and the tips of its unit axes in {0}, a NaN first entry where the forward kinematics
    /// failed (the residual is then w_k TrackerObjective::kFailedResidual).
    double evaluate(const double* xs, const RowMatrixXd& frames, double* res) const;

private:
    std::vector<BarSetup> bars_;
    int n_ = 0;
    std::vector<int> bar_;
    VectorXd distance_;
    VectorXd weights_;  // N or empty
};

/// A ballbar objective on the kinematics Kin of a tracker objective (TrackerObjective, or
/// TrackerEffectObjective with the effects, iwr/effects_ballbar.hpp) made with a probe at the
/// origin of {5} (pose zero, length 1 mm) in a tracker frame equal to {0} (registration zero), whose
/// four predicted points are {5}'s origin and unit axis tips: its parameters are the
/// kinematics' but the probe setup's 12 (which stay zero), then the set-ups' 7 S. Kin provides
/// geometry(), setup(), n_params(), n_poses(), make_workspace(), failures(x) and the hot path
/// predicted_points(x, ws, out).
template <class Kin>
class BallbarOn {
public:
    /// The residual of a pose whose forward kinematics fails (mm, times its weight).
    static constexpr double kFailedResidual = TrackerObjective::kFailedResidual;

    const Geometry& geometry() const { return kin_.geometry(); }
    const std::vector<BarSetup>& bars() const { return bars_.bars(); }
    int n_setups() const { return bars_.n_setups(); }
    /// The robot's parameters (and the effects', if any): the kinematics' first ones.
    int n_model_params() const { return n_model_; }
    int n_params() const { return n_model_ + kBarParams * n_setups(); }
    int n_poses() const { return n_; }
    int n_residuals() const { return n_; }

    /// Weighs residual k by whitening(k, 0) (N x 1: the whitening of one residual per pose, e.g.
    /// 1 / sigma_k); empty: unweighted. Throws std::invalid_argument on a bad shape or a value not
    /// finite.
    void set_whitening(const RowMatrixXd& whitening) { bars_.set_whitening(whitening); }
    bool whitened() const { return bars_.whitened(); }

    struct Workspace {
        typename Kin::Workspace kin;  // the kinematics' scratch memory
        std::vector<double> kx;       // the kinematics' parameters: the model's, then 12 zeros
        RowMatrixXd frames;           // N x 12: the origin and axis tips of {5} in {0}
    };
    Workspace make_workspace() const {
        Workspace ws{kin_.make_workspace(), std::vector<double>(static_cast<std::size_t>(kin_.n_params()), 0.0),
                     RowMatrixXd(n_, 12)};
        return ws;
    }

    /// Sum of squared residuals at x (n_params entries, unchecked: the hot path).
    double cost(const double* x, Workspace& ws) const { return evaluate(x, ws, nullptr); }
    double cost(const Eigen::Ref<const VectorXd>& x) const {
        check_x(x);
        Workspace ws = make_workspace();
        return evaluate(x.data(), ws, nullptr);
    }
    /// The residuals r_k (N) at x, checked.
    VectorXd residuals(const Eigen::Ref<const VectorXd>& x) const {
        check_x(x);
        Workspace ws = make_workspace();
        VectorXd r(n_);
        evaluate(x.data(), ws, r.data());
        return r;
    }
    /// Costs of the rows of X (M, n_params) across the pool's threads; thread-count independent.
    void cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const {
        batch_costs(*this, X, static_cast<std::size_t>(m), out, pool);
    }
    /// Poses whose forward kinematics fails at x, with the solver's message.
    std::vector<std::pair<int, std::string>> failures(const Eigen::Ref<const VectorXd>& x) const {
        check_x(x);
        VectorXd kx = VectorXd::Zero(kin_.n_params());
        kx.head(n_model_) = x.head(n_model_);
        return kin_.failures(kx);
    }

protected:
    BallbarOn(Kin kin, std::vector<BarSetup> bars, std::vector<int> bar, VectorXd distance)
        : kin_(std::move(kin)),
          bars_(std::move(bars), std::move(bar), std::move(distance), kin_.n_poses()),
          n_(kin_.n_poses()),
          n_model_(kin_.n_params() - kin_.setup().n_params()) {}
    const Kin& kin() const { return kin_; }

private:
    // x: n_params() values given, naming the parts (the effects' when any).
    void check_x(const Eigen::Ref<const VectorXd>& x) const {
        if (x.size() != n_params()) throw std::invalid_argument(size_message(x.size()));
        require_finite(x.data(), x.size(), "x");
    }
    std::string size_message(Eigen::Index given) const {
        const int ng = geometry().n_params();
        return "x: " + std::to_string(given) + " values given but this problem has " + std::to_string(n_params()) +
               " parameters (" + std::to_string(ng) + " of the robot, " +
               (n_model_ > ng ? std::to_string(n_model_ - ng) + " of the effects, " : std::string()) +
               std::to_string(kBarParams * n_setups()) + " of the " + std::to_string(n_setups()) +
               " ballbar set-up(s))";
    }
    // The residuals into res (N; may be null), returns the cost.
    double evaluate(const double* x, Workspace& ws, double* res) const {
        for (int i = 0; i < n_model_; ++i) ws.kx[static_cast<std::size_t>(i)] = x[i];
        kin_.predicted_points(ws.kx.data(), ws.kin, ws.frames);
        return bars_.evaluate(x + n_model_, ws.frames, res);
    }

    Kin kin_;
    BarReadings bars_;
    int n_ = 0, n_model_ = 0;
};

}  // namespace detail

class BallbarObjective : public detail::BallbarOn<TrackerObjective> {
public:
    /// bars: the set-ups (at least one); q (N, n_joints), legs (N, 6): the readings; bar (N): each
    /// pose's set-up, an index into bars; distance (N): the bar's readings (mm). reference (4 n +
    /// 42) and home, tolerance: as TrackerObjective (forward kinematics solved once per pose at the
    /// reference; ForwardKinematicsError naming the pose when it fails there). Throws
    /// std::invalid_argument on bad sizes, an index out of range or a value not finite.
    BallbarObjective(Geometry geometry, std::vector<BarSetup> bars, const RowMatrixXd& q,
                     const RowMatrixXd& legs, std::vector<int> bar, VectorXd distance,
                     const VectorXd& reference, const Vector6d& home, double tolerance = 1e-10);
};

// ----- the problem file's ballbar section (measurement kind 3; iwr/problem_file.hpp) ------------
struct ProblemData;
namespace io {
class Writer;
class Reader;
class Hash64;
}  // namespace io

/// After the legs: u64 set-ups S (>= 1); each: str name (1 to 40 letters, digits, '_', '-'),
/// f64s platform ball (3, in {5}), f64s fixed ball (3, in {0}), f64 offset (mm), u8 has range,
/// f64s range (2: shortest, longest centre distance, mm) when 1; then N u64 set-up indices (< S),
/// f64s distance (N, > 0, mm), f64s reference (4 n + 42).
void write_ballbar_section(io::Writer& w, const ProblemData& p);
/// Reads and checks the section (io::FormatError naming the field).
void read_ballbar_section(io::Reader& r, ProblemData& p);
/// The set-ups and the reference (the robot fingerprint's part: they make the objective).
void hash_ballbar_setups(io::Hash64& h, const ProblemData& p);
/// Each pose's set-up by name and the distances (the data fingerprint's part).
void hash_ballbar_data(io::Hash64& h, const ProblemData& p);

}  // namespace iwr
