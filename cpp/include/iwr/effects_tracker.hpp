// Laser-tracker data (reflector points or a probe in the tracker frame {T}, iwr/tracker.hpp) for a
// robot with the legs' non-geometric effects (iwr/effects.hpp): the objective DE, CRS2, BOBYQA and
// iwr-engine minimise (issue 23, docs/effects.md, "Tracker data").
//
// The model is Python's (iwr/effects/tracker.py, TrackerEffectModel), which the tests check it
// against. Per pose the platform's local pose (P, R) of {5} in {4} is the one at which the legs
// with the effects give the readings:
//
//     s_kj = D_j(P, R) - l0_j - 1e-3 c_j f_j(P, R) - 1e-6 alpha_j D_j(P, R) (T_kj - T_ref)
//
// (D_j the distance between the joint centres, f_j the leg's axial force from the hexapod's
// statics under the platform's and the pose's payload's weight), solved from the pose solved once
// at the reference by chord steps with the statics' inverse there, each refined towards the
// Newton step of the geometry's leg Jacobian scaled by the thermal growth (the compliance changes
// it by a part in 1e5: the convergence is linear at that rate in the compliance), and by Newton's
// method where the steps do not converge; the points are then T_T0 0T4 (P + R r_i), as
// TrackerObjective's. Gravity is given in {T} and carried into {0} by the identified
// registration, g_0 = R_T0(x)^T g_T: the registration's gauge then moves {0} and gravity together
// (the compliance table's own gravity, in {0}, is for pose data and is not used here).
//
// With the carriage's compliance the carriage's joints change by c_i L_i under their gravity load
// L_i (iwr/effects.hpp) of the hexapod and of the platform's bodies where the solved pose puts them,
// gravity through the registration too: the pose is then solved in {0}, each iteration with
// the joints' change at the current pose and the base joints of the changed carriage (the change's
// own derivative in the pose, a part in 1e5 to 1e3 of the legs', left out as the compliance's).
//
// Parameters: the robot's 4 n + 42, the effects' (their tables' order), then the tracker setup's
// (registration 6, then 3 K reflector offsets or 6 of the probe).
//
// Portable scalar code, one pose after another (no SIMD lanes: every pose runs its own
// iterations); a robot without effects runs TrackerObjective's SIMD kernels, untouched.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "iwr/effects.hpp"
#include "iwr/forward.hpp"
#include "iwr/model.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"
#include "iwr/tracker.hpp"

namespace iwr {

class TrackerEffectObjective {
public:
    /// Residual given to every seen coordinate of a pose whose forward kinematics with the effects
    /// fails (mm): a large finite penalty, never NaN (failures() names the pose).
    static constexpr double kFailedResidual = TrackerObjective::kFailedResidual;

    /// q (N, n_joints), legs (N, 6) the readings, points (N, 3 K) in {T} (a point not seen: its
    /// three entries NaN) as TrackerObjective; gravity (m/s^2) in {T}; payload (N, 4: kg, centre
    /// of mass in {5} mm) or empty; temperatures (N, 1 or N, 6; degrees C) or empty (refused with
    /// the thermal effect on). reference: the robot's geometric errors (4 n + 42) at which each
    /// pose's geometric forward kinematics is solved once from `home` (a local pose of {5} in {4}):
    /// each evaluation's iterations start there (the statics' inverse there is kept for the chord
    /// steps). tolerance (mm): a pose is solved when its largest leg residual is at most this (then
    /// one more step is taken, which costs no evaluation and shrinks the residual further).
    TrackerEffectObjective(Geometry geometry, EffectModel effects, TrackerSetup setup, const Vec3& gravity,
                           const RowMatrixXd& q, const RowMatrixXd& legs, const RowMatrixXd& points,
                           const RowMatrixXd& payload, const RowMatrixXd& temperatures,
                           const VectorXd& reference, const Vector6d& home, double tolerance = 1e-11);

    const Geometry& geometry() const { return geometry_; }
    const EffectModel& effects() const { return effects_; }
    const TrackerSetup& setup() const { return setup_; }
    int n_params() const { return geometry_.n_params() + effects_.n_params + setup_.n_params(); }
    int n_poses() const { return n_; }
    int n_points() const { return setup_.n_points(); }
    int n_residuals() const { return 3 * n_ * setup_.n_points(); }
    int n_seen() const { return n_seen_; }

    /// Weighs the residuals as TrackerObjective::set_whitening: (N, m^2), m = 3 n_points(), per
    /// pose a row-major lower-triangular W_k; the cost is then sum_k |W_k r_k|^2. Empty: none.
    void set_whitening(const RowMatrixXd& whitening);
    bool whitened() const { return whitening_.size() != 0; }

    class Workspace {
        friend class TrackerEffectObjective;
        std::vector<double> jbuf;  // the carriage's per-joint constants (CarriageNominal)
        std::vector<Vec3> r;       // the points in {5}
        std::vector<double> res;   // one pose's residuals
    };
    Workspace make_workspace() const;

    /// The cost at x (n_params entries, unchecked: the hot path, allocation-free once warm).
    double cost(const double* x, Workspace& ws) const;
    double cost(const Eigen::Ref<const VectorXd>& x) const;
    /// Residuals (n_residuals, pose-major; whitened when a whitening is set).
    VectorXd residuals(const Eigen::Ref<const VectorXd>& x) const;
    /// Costs of the rows of X (M, n_params) across the pool's threads; thread-count independent.
    void cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const;
    /// Poses whose forward kinematics with the effects fails at x, with a message.
    std::vector<std::pair<int, std::string>> failures(const Eigen::Ref<const VectorXd>& x) const;
    /// World poses of {5} (N, 6) at x, and the predicted points in {T} (N, 3 K); rows of failed
    /// poses are NaN.
    RowMatrixXd platform_poses(const Eigen::Ref<const VectorXd>& x) const;
    RowMatrixXd predicted_points(const Eigen::Ref<const VectorXd>& x) const;
    /// How each pose's forward kinematics with the effects was solved at x: 0 by chord steps (the
    /// statics' inverse at the reference geometry and pose), 1 by Newton's method from the
    /// reference, 2 by Newton's method from the geometry's forward kinematics at x, 3 not at all
    /// (a failure). A diagnostic: the same poses whichever path solved them, to within the
    /// tolerance.
    Eigen::VectorXi solve_paths(const Eigen::Ref<const VectorXd>& x) const;
    /// The same into out (n_poses() x 3 n_points(), sized by the caller) at x (unchecked, as
    /// cost(x, ws)): the hot path of the objectives built on these kinematics
    /// (BallbarEffectObjective, iwr/effects_ballbar.hpp).
    void predicted_points(const double* x, Workspace& ws, RowMatrixXd& out) const;

private:
    void check_x(const Eigen::Ref<const VectorXd>& x) const;
    // The cost; per pose its residuals into res (n_residuals, unwhitened; may be null), its world
    // pose and predicted points into poses/predicted (may be null), a failure message into
    // failed (may be null), the path that solved it into paths (solve_paths; may be null).
    double evaluate(const double* x, Workspace& ws, double* res, RowMatrixXd* poses,
                    RowMatrixXd* predicted, std::vector<std::pair<int, std::string>>* failed,
                    int* paths = nullptr) const;

    Geometry geometry_;
    EffectModel effects_;
    TrackerSetup setup_;
    Vec3 gravity_;  // in {T}
    int n_ = 0, n_seen_ = 0;
    double tolerance_;
    // Per pose, stride_ doubles: the readings (6), T - T_ref per leg (6), the mass (kg) and first
    // moment in {5} (kg mm) of the platform and payload (4; with the leg or the carriage compliance), the reference's local pose P (3) and
    // R (9, row-major), the measured points (3 K; 0 where not seen) and a flag per point (1 seen),
    // then per joint q (prismatic) or cos q, sin q (revolute), then (at off_chord_) G_ref^-1, the
    // inverse of the hexapod's statics matrix at the reference geometry and pose (36, row-major;
    // NaN first where it has none: the chord steps are skipped).
    std::vector<double> data_;
    int stride_ = 0, off_pts_ = 0, off_chord_ = 0;
    std::vector<int> q_off_;
    std::vector<char> prismatic_;
    std::vector<Vector6d> ref_euler_;  // the reference local poses (the fallback's start)
    detail::CarriageNominal carriage_;
    std::vector<double> cc_scale_;  // the carriage compliance's unit scale per joint (0: rigid)
    int off_ct_ = -1;  // the carriage's thermal expansion: the machine's T - T_ref per pose
    RowMatrixXd whitening_;
};

}  // namespace iwr
