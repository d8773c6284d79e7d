// The IWR kinematic model: a serial DH carriage carrying a six-legged Stewart hexapod.
//
// Conventions (see docs/model.md and the paper, Wang, Wu & Handroos):
//   * standard DH, A_i = Rot_z(theta_i) Trans_z(d_i) Trans_x(a_i) Rot_x(alpha_i)      eq. (1)
//   * a joint reading adds to the nominal value of its column (d for 'P', theta for 'R')
//   * 4R5 = Rz(alpha) Ry(beta) Rx(gamma), a pose is (x, y, z, alpha, beta, gamma)     eq. (6)
//   * predicted leg sensor reading s_j = || 0P5 + 0R5 b_j - 0P4 - 0R4 a_j || - l0_j    eq. (8)
//   * millimetres and radians everywhere.
//
// Error parameters, in this order (public API):
//   [4 i + 0..3]          joint i: delta alpha, delta a, delta d, delta theta
//   [4 n + 3 j + 0..2]    leg j: delta a_j (x, y, z) in frame {4}
//   [4 n + 18 + 3 j + c]  leg j: delta b_j (x, y, z) in frame {5}
//   [4 n + 36 + j]        leg j: delta l0_j
#pragma once

#include <Eigen/Dense>
#include <string>

namespace iwr {

constexpr int kLegs = 6;
constexpr int kHexapodParams = 42;

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Mat4 = Eigen::Matrix4d;
using VectorXd = Eigen::VectorXd;
using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using LegMatrix = Eigen::Matrix<double, kLegs, 3, Eigen::RowMajor>;
using LegVector = Eigen::Matrix<double, kLegs, 1>;

/// Nominal geometry. Validated on construction; immutable afterwards.
class Geometry {
public:
    /// joint_types: one letter per carriage joint, 'P' (prismatic) or 'R' (revolute); may be empty.
    /// dh: n x 4, columns alpha, a, d, theta. base: a_i in {4}; platform: b_i in {5}.
    Geometry(std::string joint_types, RowMatrixXd dh, LegMatrix base, LegMatrix platform,
             LegVector leg_offsets);

    int n_joints() const { return static_cast<int>(joint_types_.size()); }
    int n_params() const { return 4 * n_joints() + kHexapodParams; }
    const std::string& joint_types() const { return joint_types_; }
    bool is_prismatic(int i) const { return joint_types_[static_cast<size_t>(i)] == 'P'; }
    const RowMatrixXd& dh() const { return dh_; }
    const LegMatrix& base() const { return base_; }
    const LegMatrix& platform() const { return platform_; }
    const LegVector& leg_offsets() const { return leg_offsets_; }

    // Parameter indices (see the header comment).
    int idx_joint(int joint, int column) const { return 4 * joint + column; }
    int idx_base(int leg, int axis) const { return 4 * n_joints() + 3 * leg + axis; }
    int idx_platform(int leg, int axis) const { return 4 * n_joints() + 18 + 3 * leg + axis; }
    int idx_offset(int leg) const { return 4 * n_joints() + 36 + leg; }

    /// Checks that an error vector has n_params() finite entries; throws std::invalid_argument.
    void check_errors(const double* x, Eigen::Index size, const char* what) const;

private:
    std::string joint_types_;
    RowMatrixXd dh_;
    LegMatrix base_, platform_;
    LegVector leg_offsets_;
};

/// Z-Y-X Euler matrix of eq. (6): Rz(alpha) Ry(beta) Rx(gamma).
Mat3 euler_zyx(double alpha, double beta, double gamma);

/// One DH transform, eq. (1).
Mat4 dh_transform(double alpha, double a, double d, double theta);

/// 0T4 of the carriage with errors x (n_params) at joint readings q (n_joints).
/// Returns also the intermediate frames 0T1 .. 0Tn when frames != nullptr (n + 1 entries, 0T0 first).
Mat4 carriage_transform(const Geometry& g, const double* x, const double* q,
                        Mat4* frames = nullptr);

/// Predicted leg sensor readings, (N, 6), for errors x, joint readings q (N, n) and measured poses
/// (N, 6). Throws std::invalid_argument on bad shapes or non-finite input.
RowMatrixXd predict_legs(const Geometry& g, const Eigen::Ref<const VectorXd>& x,
                         const Eigen::Ref<const RowMatrixXd>& q,
                         const Eigen::Ref<const RowMatrixXd>& poses);

/// Throws std::invalid_argument naming `what` unless every entry is finite.
void require_finite(const double* data, Eigen::Index size, const char* what);

/// Throws std::invalid_argument naming the array unless `per_pose` (called `what`: the measured
/// poses or the leg readings) is (N, 6) and the joint readings q are (N, n_joints).
void require_pose_shapes(const Geometry& g, const Eigen::Ref<const RowMatrixXd>& q,
                         const Eigen::Ref<const RowMatrixXd>& per_pose, const char* what);

}  // namespace iwr
