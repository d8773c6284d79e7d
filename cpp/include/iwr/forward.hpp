// Forward kinematics of the hexapod: the platform pose from the six leg readings (and, for the
// hybrid robot, the carriage joint readings), by Newton-Raphson on the leg-length equations.
//
// The inverse problem is eq. (5)/(8): l_j = || 4P5 + 4R5 b_j - a_j ||, with 4R5 the Z-Y-X Euler
// matrix of eq. (6). Forward kinematics inverts it for the six local pose coordinates
// p = (x, y, z, alpha, beta, gamma) of frame {5} in frame {4}; the world pose is then 0T4 4T5.
//
// Why iterate on the *local* coordinates: the IWR's frame {4} is turned so that at the home pose
// the world Z-Y-X Euler angles of the platform sit at their gimbal lock (beta = -pi/2). Newton on
// world Euler angles would face a singular Jacobian exactly there. In frame {4} the hexapod works
// around beta = 0, so the only singularities left are the hexapod's own (parallel singularities).
#pragma once

#include <stdexcept>
#include <string>

#include "iwr/model.hpp"

namespace iwr {

using Vector6d = Eigen::Matrix<double, 6, 1>;
using LegJacobian = Eigen::Matrix<double, kLegs, 6, Eigen::RowMajor>;

struct ForwardOptions {
    /// Convergence: the largest |predicted - given| leg length (mm).
    double tolerance = 1e-9;
    /// Newton iterations before giving up.
    int max_iterations = 50;
};

/// Raised when Newton-Raphson does not converge or meets a singular Jacobian. `pose()` is the
/// index of the offending pose (row of the input), or -1 for a single solve.
class ForwardKinematicsError : public std::runtime_error {
  public:
    ForwardKinematicsError(const std::string& message, Eigen::Index pose)
        : std::runtime_error(message), pose_(pose) {}
    Eigen::Index pose() const { return pose_; }

  private:
    Eigen::Index pose_;
};

/// Whole leg lengths l_j = || p + R(alpha, beta, gamma) b_j - a_j || at the local pose p
/// (eq. 5-6), and when jac != nullptr their exact Jacobian d l / d p (6 x 6).
LegVector hexapod_leg_lengths(const LegMatrix& base, const LegMatrix& platform,
                              const Vector6d& pose, LegJacobian* jac = nullptr);

struct HexapodSolution {
    Vector6d pose;          ///< local pose of {5} in {4}
    int iterations = 0;     ///< Newton iterations taken
    double residual = 0.0;  ///< largest |l(pose) - lengths| at the solution (mm)
};

/// Newton-Raphson with a backtracking line search: the local pose whose leg lengths are
/// `lengths` (whole lengths, not sensor readings), starting from `guess`. Throws
/// ForwardKinematicsError (pose index `pose_index`) when it does not converge within
/// options.max_iterations or the Jacobian is singular; std::invalid_argument on bad input.
HexapodSolution hexapod_forward(const LegMatrix& base, const LegMatrix& platform,
                                const LegVector& lengths, const Vector6d& guess,
                                const ForwardOptions& options = ForwardOptions(),
                                Eigen::Index pose_index = -1);

/// Z-Y-X Euler angles (alpha, beta, gamma) of a rotation matrix, beta in [-pi/2, pi/2]: the
/// inverse of euler_zyx (eq. 6), also at the gimbal lock beta = +-pi/2 (there alpha = 0).
Vec3 euler_from_matrix(const Mat3& r);

/// World poses (N, 6) of the platform of the robot with errors x, from carriage joint readings
/// q (N, n_joints) and leg sensor readings legs (N, 6) (whole length = reading + l0 + dl0).
/// guess: (N, 6) world poses to start from, or 0 rows for the default, `home` (a local pose of
/// {5} in {4}, the robot's home pose) carried through the carriage. iterations (optional): the
/// Newton iterations per pose.
RowMatrixXd forward_kinematics(const Geometry& g, const Eigen::Ref<const VectorXd>& x,
                               const Eigen::Ref<const RowMatrixXd>& q,
                               const Eigen::Ref<const RowMatrixXd>& legs,
                               const Eigen::Ref<const RowMatrixXd>& guess, const Vector6d& home,
                               const ForwardOptions& options = ForwardOptions(),
                               Eigen::VectorXi* iterations = nullptr);

}  // namespace iwr
