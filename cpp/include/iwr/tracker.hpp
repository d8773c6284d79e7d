// Laser-tracker data: reflector points (or a 6-DOF probe) measured in the tracker's own frame {T}.
//
// The model of one measured point i at pose k (docs/tracker.md):
//
//     y_ki = T_T0(x_t) 0T4(x_c, q_k) 4T5(x_h, s_k) r_i(x_o)                 (in {T}, mm)
//
//   * T_T0 = T_nom C(x_t): the nominal registration (pose of {0} in {T}) times a correction
//     C = [Exp(w), t] with x_t = (t_x, t_y, t_z, w_x, w_y, w_z): a translation and a rotation vector
//     expressed in {0}, about {0}'s origin. Right-multiplying keeps the correction independent of
//     where the tracker stands (a rotation about the tracker's origin 2 m away would be nearly a
//     translation at the robot), and makes the registration's null directions with the carriage's
//     first joint exact two-parameter combinations (tracker.rz with joint1.dtheta, tracker.z with
//     joint1.dd).
//   * 0T4: the DH carriage (eq. 1-2); 4T5: the hexapod's forward kinematics from the leg readings
//     (Newton-Raphson on eq. 5-8).
//   * r_i: the point in {5}. Reflectors: r_i = r_nom_i + x_o[3i .. 3i+2]. Probe: four virtual
//     points, the probe's origin t_p and t_p + L R_p e_c (c = x, y, z), with t_p = t_nom + x_o[0..2]
//     and R_p = Exp(x_o[3..5]) R_nom, so the residuals of a probe pose are its position error and L
//     times its rotation-matrix error (a chordal metric; L = probe_length, mm).
//
// Parameters: the robot's 4 n + 42, then tracker.x .. tracker.rz (6), then reflector1.x ..
// reflectorK.z (3 K) or probe.x .. probe.rz (6).
//
// Residual 3 (K k + i) + c is y_ki,c - measured_ki,c; a point not seen at a pose (NaN in the data)
// has residuals 0 and zero Jacobian rows. A pose whose forward kinematics fails gets the residual
// kFailedResidual on every seen coordinate (a large finite penalty, zero Jacobian rows), never NaN;
// failures(x) names such poses.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "iwr/forward.hpp"
#include "iwr/model.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"

namespace iwr {

/// Rotation matrix of a rotation vector (Rodrigues' formula).
Mat3 rotvec_matrix(const Vec3& w);
/// Left Jacobian of SO(3): Exp(w + dw) = Exp(J_l(w) dw) Exp(w) to first order, so that
/// d(Exp(w) v)/dw = -[Exp(w) v]x J_l(w).
Mat3 so3_left_jacobian(const Vec3& w);

enum class TrackerKind { Points, Probe };

namespace detail {
struct TrackerConsts;
struct TrackerKernels;
/// The points seen in points (N, 3 K; a point not seen: its three entries NaN); throws
/// std::invalid_argument naming the pose and point of a partial NaN or an infinite coordinate.
int seen_points(const RowMatrixXd& points, int n_points);
/// Checks a per-pose whitening (n, m^2: row-major lower-triangular m x m, finite), throwing
/// std::invalid_argument naming the entry at fault.
void check_whitening(const RowMatrixXd& whitening, Eigen::Index n, Eigen::Index m);
/// sin(t)/t, (1 - cos t)/t^2 and (t - sin t)/t^3 at t^2 = t2 (rotvec_matrix, so3_left_jacobian).
void so3_coefficients(double t2, double& s, double& c, double& d);
}  // namespace detail

/// The nominal measurement setup. Poses are (x, y, z, alpha, beta, gamma), Z-Y-X Euler (eq. 6).
class TrackerSetup {
public:
    /// K >= 1 reflectors with nominal offsets (K, 3) in {5}; registration: nominal pose of {0} in {T}.
    static TrackerSetup points(const Vector6d& registration, const RowMatrixXd& reflectors);
    /// A 6-DOF probe whose frame has the nominal pose `probe` in {5}; `length` (mm) weighs its
    /// orientation error like points that far from its origin.
    static TrackerSetup probe(const Vector6d& registration, const Vector6d& probe, double length);

    TrackerKind kind() const { return kind_; }
    /// Points per pose: K reflectors, or the probe's 4 virtual points.
    int n_points() const { return kind_ == TrackerKind::Points ? static_cast<int>(reflectors_.rows()) : 4; }
    /// Parameters of the setup: 6 (registration) + 3 K or + 6.
    int n_params() const { return 6 + n_offset_params(); }
    int n_offset_params() const { return kind_ == TrackerKind::Points ? 3 * n_points() : 6; }
    const Vector6d& registration() const { return registration_; }
    const RowMatrixXd& reflectors() const { return reflectors_; }
    const Vector6d& probe_pose() const { return probe_; }
    double probe_length() const { return probe_length_; }

    /// The registration T_T0 = T_nom C(xt): rotation and translation, xt 6 entries.
    void registration_transform(const double* xt, Mat3& rot, Vec3& trans) const;
    /// The measured points in {5} for offset parameters xo (n_offset_params() entries); when jac is
    /// given, also d r_i / d xo, one 3 x n_offset_params() block per point, stacked.
    void platform_points(const double* xo, Vec3* r, RowMatrixXd* jac = nullptr) const;

private:
    TrackerKind kind_ = TrackerKind::Points;
    Vector6d registration_ = Vector6d::Zero();
    RowMatrixXd reflectors_;
    Vector6d probe_ = Vector6d::Zero();
    double probe_length_ = 100.0;
    Mat3 reg_rot_ = Mat3::Identity(), probe_rot_ = Mat3::Identity();
};

class TrackerObjective {
public:
    /// Residual given to every seen coordinate of a pose whose forward kinematics fails (mm).
    static constexpr double kFailedResidual = 1e3;

    /// q (N, n_joints) joint readings, legs (N, 6) leg sensor readings, points (N, 3 K) measured
    /// points in {T} (a reflector not seen: its 3 entries NaN). reference: robot error vector
    /// (4 n + 42) where the forward kinematics of every pose is solved once (from `home`, a local
    /// pose of {5} in {4}) to start each evaluation's solve. tolerance (mm): an evaluation's solve
    /// stops when the 2-norm of the six leg-length residuals is at most this; the reference solve
    /// and the damped Newton fallback, when the largest residual is.
    TrackerObjective(Geometry geometry, TrackerSetup setup, const RowMatrixXd& q,
                     const RowMatrixXd& legs, const RowMatrixXd& points,
                     const VectorXd& reference, const Vector6d& home, double tolerance = 1e-10);

    const Geometry& geometry() const { return geometry_; }
    const TrackerSetup& setup() const { return setup_; }
    int n_params() const { return geometry_.n_params() + setup_.n_params(); }
    int n_poses() const { return n_; }
    int n_points() const { return setup_.n_points(); }
    int n_residuals() const { return 3 * n_ * setup_.n_points(); }
    /// Seen points (3 residuals each).
    int n_seen() const { return n_seen_; }

    /// Weighs the residuals by the instruments' noise (generalised least squares with fixed
    /// weights): whitening (N, m^2), m = 3 n_points(), per pose a row-major lower-triangular
    /// m x m matrix W_k; from then on residual block k is W_k r_k (r_k as above: unseen
    /// coordinates 0, a failed pose's kFailedResidual) and the cost sum_k |W_k r_k|^2, for
    /// example W_k = L_k^-1 with L_k L_k^T the covariance of pose k's point residuals. Empty:
    /// unweighted. Throws std::invalid_argument on a bad shape, a value not finite or a non-zero
    /// entry above the diagonal.
    void set_whitening(const RowMatrixXd& whitening);
    /// Whether the residuals are whitened.
    bool whitened() const { return whitening_.size() != 0; }

    /// The most parameter vectors cost_rows solves together (a group's blocks share the cache).
    static constexpr int kMaxGroup = 8;

    class Workspace {
        friend class TrackerObjective;
        struct Slot {                 // one parameter vector's (cost_rows: kMaxGroup at once)
            std::vector<double> jbuf;  // the carriage's per-joint constants (CarriageNominal)
            std::vector<Vec3> r;       // points in {5}
            std::vector<double> refl;  // the same as B^-1 r_i, flat (TrackerConsts::refl)
        };
        Slot slot[kMaxGroup];
        std::vector<double, detail::AlignedAllocator<double>> y;  // a block's points (3 K x lanes)
        std::vector<double, detail::AlignedAllocator<double>> v;  // a block's residuals (whitened)
    };
    Workspace make_workspace() const;

    /// Sum of squared residuals at x (n_params entries, unchecked: the hot path).
    double cost(const double* x, Workspace& ws) const;
    double cost(const Eigen::Ref<const VectorXd>& x) const;
    VectorXd residuals(const Eigen::Ref<const VectorXd>& x) const;
    /// Residuals and their exact Jacobian (n_residuals x n_params): implicit differentiation of
    /// the forward kinematics, d(pose)/dx = -(dg/dpose)^-1 dg/dx with g the leg-length equations.
    void jacobian(const Eigen::Ref<const VectorXd>& x, VectorXd* residuals, RowMatrixXd* jac) const;
    /// Costs of the rows of X (M, n_params) across the pool's threads; thread-count independent.
    void cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const;
    /// Costs of the m parameter vectors xs[0..m) (n_params entries each, unchecked) into out[0..m):
    /// cost() of each, bit for bit. The vectors are taken in groups of up to kMaxGroup. Where the
    /// last block of poses is solved alone (it is not the second of a pair), the group's last
    /// blocks are solved together: each lane computes what it would in its own vector's block, and
    /// half-filled blocks (N mod 8 in 1..4) share a block two vectors at once (batch_costs and the
    /// DE engine call it). A group's other blocks are run a block (AVX-512: a pair) at a time,
    /// vector after vector: each block's data read by the group while it is cached.
    void cost_rows(const double* const* xs, int m, double* out, Workspace& ws) const;

    /// Poses whose forward kinematics fails at x, with the solver's message.
    std::vector<std::pair<int, std::string>> failures(const Eigen::Ref<const VectorXd>& x) const;
    /// How the kernel's own iterations ended for each pose at x (N): 0 solved by them, 1 not
    /// contracting (the damped Newton solver finishes the pose), 2 a leg length <= 0. A
    /// diagnostic: what the cost and the points use is the same either way, to the tolerance.
    Eigen::VectorXi chord_status(const Eigen::Ref<const VectorXd>& x) const;
    /// World poses of {5} (N, 6) at x, and the predicted points in {T} (N, 3 K); rows of failed
    /// poses are NaN.
    RowMatrixXd platform_poses(const Eigen::Ref<const VectorXd>& x) const;
    RowMatrixXd predicted_points(const Eigen::Ref<const VectorXd>& x) const;
    /// The same into `out` (N x 3 n_points, sized by the caller) at x (n_params entries,
    /// unchecked): the hot path of an objective built on these kinematics (iwr/ballbar.hpp).
    void predicted_points(const double* x, Workspace& ws, RowMatrixXd& out) const;

private:
    struct Hexapod {
        LegMatrix a, b;
        LegVector l0;
    };
    Hexapod hexapod(const double* x) const;
    // The kernel's constants at x.
    void prepare(const double* x, Workspace& ws, detail::TrackerConsts& tc, int slot = 0) const;
    // The forward kinematics' constants beyond the hexapod's a, b, l0 (already in tc).
    void fk_consts(detail::TrackerConsts& tc) const;
    // Whether the last block of poses is at most half full: then its padding lanes kLanes / 2..
    // repeat its first half (the constructor) and cost_rows puts two vectors' poses in it.
    bool last_block_half_full() const {
        return n_ - (n_ - 1) / kLanes * kLanes <= kLanes / 2;  // its poses: 1..kLanes
    }
    const double* block_data(int block) const {
        return blocks_.data() + static_cast<size_t>(block) * static_cast<size_t>(stride_);
    }
    // Chord iterations for the kLanes poses of block `block`: local poses (P, R) of {5} in {4}
    // and a status per lane (0 solved, 1 needs the damped Newton fallback, 2 a leg length <= 0).
    void solve_block(const Hexapod& h, int block, Vec3* p, Mat3* r, int* status) const;
    // Finishes pose k after its block's chord iterations ended with `status`: nothing, the
    // damped Newton fallback, or ForwardKinematicsError when it fails.
    void finish(const Hexapod& h, int k, int status, Vec3& p, Mat3& r) const;
    // Local pose of pose k alone (its block solved, the lane taken): as in evaluate().
    void solve(const Hexapod& h, int k, Vec3& p, Mat3& r) const;
    void check_x(const Eigen::Ref<const VectorXd>& x) const;
    // Residuals into res (n_residuals, may be null; not whitened); returns the cost (whitened when
    // whitened()); failed poses into failed.
    double evaluate(const double* x, Workspace& ws, double* res, std::vector<int>* failed,
                    RowMatrixXd* poses, RowMatrixXd* predicted) const;
    // Block blk of the vector x (constants tc) after its chord (pp, ff, status: a lane that
    // fell back is finished here, its pose written into pp and ff; h, have_h: the hexapod at x,
    // made at the first such lane; a padding lane that did not finish gets the block's reference
    // pose): the points and their squared residuals added to acc (W), the failed lanes 1 in bad
    // (W); t and y as the kernels' points (may be null). Inline: defined in tracker.cpp, its only
    // user (evaluate and cost_rows).
    inline void block_points(const double* x, const detail::TrackerConsts& tc,
                      const detail::TrackerKernels& kernel, Workspace& ws, int blk, double* pp,
                      double* ff, const int* status, Hexapod& h, bool& have_h, double* bad,
                      double* t, double* y, double* acc) const;
    // evaluate() at x with its constants tc (prepare) and the kernels of one variant.
    double evaluate(const double* x, const detail::TrackerConsts& tc,
                    const detail::TrackerKernels& kernel, Workspace& ws, double* res,
                    std::vector<int>* failed, RowMatrixXd* poses, RowMatrixXd* predicted) const;

    Geometry geometry_;
    TrackerSetup setup_;
    int n_ = 0, n_seen_ = 0;
    double tolerance_;
    RowMatrixXd q_, legs_, points_;
    RowMatrixXd cq_, sq_;  // cos and sin of the revolute readings
    // Per pose, in blocks of kLanes poses, structure of arrays (quantity e of lane l at
    // e * kLanes + l): the inverse leg Jacobian at the reference (36, row-major), the reference
    // position (3) and rotation (9, row-major), the leg readings (6), 1 / (2 L) with L the leg
    // lengths at the reference (6), then per joint q and 0
    // (prismatic) or cos q and sin q (revolute), then the measured points (3 K, 0 where not seen)
    // and a flag per point (1 seen, 0 not). The last block is padded with copies of its poses
    // (the constructor says which), which see no point.
    static constexpr int kLanes = 8;
    static constexpr int kChordQuantities = 60;
    int stride_ = 0;  // doubles per block
    std::vector<double, detail::AlignedAllocator<double>> blocks_;  // 64-byte aligned
    std::vector<char> prismatic_;
    std::vector<int> q_off_;  // per joint: its first quantity in a block
    std::vector<char> all_seen_;  // per block: every point of its (real) poses seen
    detail::CarriageNominal carriage_;
    int pair_[2] = {0, 1};  // the platform joints the kernel recovers the rotation from
    std::vector<Vector6d> ref_euler_;  // the reference as a local pose (the fallback's start)
    RowMatrixXd whitening_;  // (N, m^2) or empty: see set_whitening
    // The whitening for the kernel, in blocks of kLanes poses as blocks_ (quantity e of lane l at
    // e * kLanes + l): row after row of the rows not zero at every pose (wh_rows_ 1), entries
    // j = 0..i of row i; the padding lanes 0. wh_stride_ doubles a block.
    std::vector<double, detail::AlignedAllocator<double>> wh_blocks_;
    std::vector<char> wh_rows_;  // per row of a pose's whitening: 1 stored, 0 zero at every pose
    int wh_stride_ = 0;
    int wh_first_ = -1;  // the rows stored are wh_first_.. (every one), or -1 (TrackerConsts)
    // W_k times the m rows of pose k, for every pose, of a (n_residuals x cols) row-major array.
    void whiten_rows(double* rows, Eigen::Index cols) const;
};

}  // namespace iwr
