// The efficient estimator of the error parameters: the implicit loop method (Wampler, Hollerbach &
// Arai, IEEE Trans. Robotics and Automation 11(5), 1995), an errors-in-variables least squares.
//
// Every measured quantity of pose k gets a correction: the carriage joint readings q_k (dq), the
// measured platform position (dp) and orientation (a rotation vector w in the platform frame,
// R_true = R_measured exp([w]x), the parametrisation iwr.simulate uses for orientation noise) and
// the leg readings. The loop-closure equation ties them to the error parameters x:
//
//     s_k + ds_k = legs(x, q_k + dq_k, (p_k + dp_k, R_k exp([w_k]x)))          (eq. 8 closed)
//
// so the leg correction ds_k is a function of the others, and the estimator minimises the
// Mahalanobis norm of all the corrections (independent readings, one standard deviation each)
//
//     sum_k  sum_j (legs_kj(x, q_k + dq_k, pose_k + (dp_k, w_k)) - s_kj)^2 / sigma_legs_kj^2
//          + sum_i dq_ki^2 / sigma_q_ki^2 + |dp_k / sigma_p|^2 + |w_k / sigma_o|^2
//
// over x (the active parameters) and the per-pose nuisance corrections y_k = (dq_k, dp_k, w_k).
// A correction whose standard deviation is 0 is an exact reading: it is not an unknown. Eq. (10)
// is the special case with every non-leg reading exact.
//
// The solver is Levenberg-Marquardt on the sparse normal equations: each pose's nuisance block
// (n_joints + 6 unknowns) is eliminated by the Schur complement, so an iteration costs O(N p^2)
// for p active parameters, with the exact derivatives below.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "iwr/model.hpp"
#include "iwr/tracker.hpp"

namespace iwr {

/// Predicted leg readings and their exact derivatives at corrected readings.
struct LoopJacobians {
    RowMatrixXd legs;   ///< (N, 6) predicted leg sensor readings
    RowMatrixXd jac_x;  ///< (6 N, n_params) d legs / d x, pose-major rows
    RowMatrixXd jac_y;  ///< (6 N, n_joints + 6) d legs / d (dq, dp, w)
};

/// Predicted legs at joint readings q + dq and platform poses (p + dp, R(pose) exp([w]x)), and
/// their exact derivatives, with corrections (N, n_joints + 6) = (dq, dp, w) (empty: zeros).
LoopJacobians loop_jacobians(const Geometry& g, const Eigen::Ref<const VectorXd>& x,
                             const Eigen::Ref<const RowMatrixXd>& q,
                             const Eigen::Ref<const RowMatrixXd>& poses,
                             const Eigen::Ref<const RowMatrixXd>& corrections);

struct ImplicitLoopOptions {
    int max_iterations = 200;  ///< LM iterations per stage (each one Jacobian evaluation)
    /// Converged when an accepted step lowers the cost by at most ftol * cost, or the scaled step
    /// is below xtol, or the scaled gradient below gtol.
    double ftol = 1e-12;
    double xtol = 1e-12;
    double gtol = 1e-12;
    /// LM damping relative to the diagonal of the reduced normal matrix. Small: that matrix has a
    /// condition number near 1e6 after Jacobi scaling, so 1e-4 would already damp its weakest
    /// directions a hundredfold; a step that fails raises it.
    double initial_lambda = 1e-8;
    /// From a cold start (no corrections given), first solve with every non-leg reading exact
    /// (the weighted eq. 10, no nuisance unknowns) to ftol 1e-8, then the full problem from there.
    /// Far from the solution (a frame 2 m off) the full problem's first steps would otherwise put
    /// radians into the orientation corrections, where the model is far from linear, and crawl.
    bool two_stage = true;
    /// Compute the statistics at the solution (redundancy numbers, pose tests, covariance).
    bool statistics = true;
};

/// Called after every accepted iteration with (iteration, x, cost); true stops the solve.
using LoopCallback = std::function<bool(int, const VectorXd&, double)>;

struct ImplicitLoopResult {
    VectorXd x;               ///< all n_params error parameters (inactive ones as given)
    RowMatrixXd corrections;  ///< (N, n_joints + 6): dq, dp, w at the solution
    double cost = 0;          ///< sum of squared normalised corrections (the chi-square statistic)
    int iterations = 0;       ///< accepted + rejected LM iterations
    int nfev = 0;             ///< residual evaluations (a Jacobian counts as one more)
    /// 1: cost change below ftol; 2: step below xtol; 3: gradient below gtol; 4: zero cost;
    /// 0: iteration limit; -1: stopped by the callback; -2: no step could lower the cost.
    int status = 0;
    std::string message;
    /// Normalised residuals (N, 6 + n_joints + 6): legs (predicted - measured) / sigma, then
    /// dq / sigma_q, dp / sigma_p, w / sigma_o (0 where the reading is exact).
    RowMatrixXd residuals;
    /// Redundancy numbers r_i = 1 - h_ii of every reading (same layout; 0 for exact readings).
    /// They sum to 6 N - p.
    RowMatrixXd redundancy;
    /// Per pose: T_k = v_k^T Q_vv,kk^+ v_k, chi-square with pose_dof(k) degrees of freedom under
    /// the noise model (v_k the pose's normalised residuals, Q_vv,kk their cofactor block).
    VectorXd pose_statistic;
    Eigen::VectorXi pose_dof;
    /// Covariance of the active parameters (p x p), the inverse of the reduced normal matrix at
    /// the solution (in the units of the parameters, for normalised residuals of unit variance).
    Eigen::MatrixXd covariance;
    /// Smallest eigenvalue of the Jacobi-scaled reduced normal matrix over its largest: near
    /// machine precision when the active parameters are not all identifiable.
    double reciprocal_condition = 0;
    /// Degrees of freedom of the chi-square law of `cost`: live residuals - free corrections - p.
    int dof = 0;
};

/// The efficient estimator. x0 (n_params) is the starting point and the value of inactive
/// parameters; active lists the indices of the parameters estimated. q (N, n_joints), poses
/// (N, 6), legs (N, 6) are the readings; sigma (N, 6 + n_joints + 6) the standard deviation of
/// every reading in the layout of `residuals` (legs > 0; others >= 0, 0 = exact). corrections0
/// (N, n_joints + 6) starts the nuisance corrections (empty: zeros). Throws std::invalid_argument
/// on bad shapes or values.
ImplicitLoopResult implicit_loop(const Geometry& g, const Eigen::Ref<const VectorXd>& x0,
                                 const std::vector<int>& active,
                                 const Eigen::Ref<const RowMatrixXd>& q,
                                 const Eigen::Ref<const RowMatrixXd>& poses,
                                 const Eigen::Ref<const RowMatrixXd>& legs,
                                 const Eigen::Ref<const RowMatrixXd>& sigma,
                                 const Eigen::Ref<const RowMatrixXd>& corrections0,
                                 const ImplicitLoopOptions& options = ImplicitLoopOptions(),
                                 const LoopCallback& callback = LoopCallback());

// --- Laser-tracker data (docs/estimation.md, "Tracker data") ---------------------------------
//
// The same estimator when the platform is measured by a laser tracker in its own frame {T}:
// reflector points (K per pose, some possibly unseen) or a 6-DOF probe pose. The parameters are
// the robot's n_params then the setup's (registration correction, reflector or probe offsets:
// iwr/tracker.hpp). Per pose the nuisance unknowns are the true joint readings q + dq and the true
// platform pose in {0}, (p_ref + dp, R_ref exp([w]x)) about a reference pose (forward kinematics
// at the starting point); the normalised residuals (the layout of `residuals`, nr = 6 + n_joints +
// 3 n_blocks columns) are
//
//   legs:    (legs(x, q + dq, pose) - s) / sigma_legs                    (6; eq. 8 closed)
//   joints:  dq / sigma_q                                                 (n_joints; 0 if exact)
//   points:  W_ki (T_T0(x) pose r_i(x) - m_ki)                           (3 per reflector; 0 unseen)
//   probe:   W_k0 (T_T0(x) pose t_p(x) - m_k),  W_k1 vee(asym(R_pred R_m^T))     (3 + 3)
//
// with W a 3x3 whitening matrix per point (W^T W = the point's inverse covariance: the tracker's
// anisotropic noise) and n_blocks = K for points, 2 for a probe (position, orientation).

/// Inputs of the tracker estimator besides the robot and its readings.
struct TrackerLoopData {
    TrackerSetup setup;      ///< the nominal setup (iwr/tracker.hpp)
    RowMatrixXd measured;    ///< (N, 3 K) points in {T}, NaN where unseen; probe: (N, 6) poses
    RowMatrixXd whitening;   ///< (N, 9 n_blocks): per block a row-major 3x3 W
    RowMatrixXd reference;   ///< (N, 6) reference platform poses in {0}
};

/// Normalised residuals (N, nr) at (x, corrections) and their exact derivatives (N nr, n_params)
/// and (N nr, n_joints + 6), pose-major rows (for tests); sigma (N, 6 + n_joints) the leg and
/// joint standard deviations.
LoopJacobians tracker_loop_jacobians(const Geometry& g, const TrackerLoopData& data,
                                     const Eigen::Ref<const VectorXd>& x,
                                     const Eigen::Ref<const RowMatrixXd>& q,
                                     const Eigen::Ref<const RowMatrixXd>& legs,
                                     const Eigen::Ref<const RowMatrixXd>& sigma,
                                     const Eigen::Ref<const RowMatrixXd>& corrections);

/// The efficient estimator on tracker data; arguments as implicit_loop (sigma: (N, 6 + n_joints),
/// legs > 0, joints >= 0), corrections (N, n_joints + 6) = (dq, dp, w) about data.reference.
ImplicitLoopResult implicit_loop_tracker(const Geometry& g, const TrackerLoopData& data,
                                         const Eigen::Ref<const VectorXd>& x0,
                                         const std::vector<int>& active,
                                         const Eigen::Ref<const RowMatrixXd>& q,
                                         const Eigen::Ref<const RowMatrixXd>& legs,
                                         const Eigen::Ref<const RowMatrixXd>& sigma,
                                         const Eigen::Ref<const RowMatrixXd>& corrections0,
                                         const ImplicitLoopOptions& options = ImplicitLoopOptions(),
                                         const LoopCallback& callback = LoopCallback());

}  // namespace iwr
