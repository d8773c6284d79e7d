// The calibration objective of eq. (10): the (optionally weighted) sum over poses and legs of
// (predicted - measured)^2 leg sensor readings, its residual vector and its exact Jacobian.
#pragma once

#include <memory>
#include <vector>

#include "iwr/model.hpp"
#include "iwr/parallel.hpp"

namespace iwr {

class Objective {
public:
    /// q (N, n_joints), poses (N, 6), legs (N, 6) measured sensor readings, weights (N, 6) or empty
    /// (all ones). Residual k*6+j is sqrt(w_kj) * (predicted_kj - legs_kj).
    Objective(Geometry geometry, const RowMatrixXd& q, const RowMatrixXd& poses,
              const RowMatrixXd& legs, const RowMatrixXd& weights = RowMatrixXd());

    const Geometry& geometry() const { return geometry_; }
    int n_params() const { return geometry_.n_params(); }
    int n_poses() const { return n_; }
    int n_residuals() const { return kLegs * n_; }

    /// Scratch memory for one thread's evaluations; makes cost() allocation-free.
    class Workspace {
        friend class Objective;
        std::vector<double> buf;
    };
    Workspace make_workspace() const;

    /// The cost of eq. (10) at x (n_params entries, unchecked: the hot path).
    double cost(const double* x, Workspace& ws) const;
    /// Checked convenience overload.
    double cost(const Eigen::Ref<const VectorXd>& x) const;

    /// Residual vector (N*6, pose-major) at x.
    VectorXd residuals(const Eigen::Ref<const VectorXd>& x) const;

    /// Residuals and their exact, analytic Jacobian (N*6 x n_params) at x.
    void jacobian(const Eigen::Ref<const VectorXd>& x, VectorXd* residuals, RowMatrixXd* jac) const;

    /// Costs of the rows of X (M, n_params) into out (M), across the pool's threads. Unchecked.
    void cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const;

private:
    Geometry geometry_;
    int n_ = 0;
    // Pose data, structure of arrays (one contiguous array of N per quantity) for SIMD loops.
    std::vector<double> r5_[9];        // 0R5 row-major entries
    std::vector<double> p5_[3];        // 0P5
    std::vector<double> legs_[kLegs];  // measured readings
    std::vector<double> sqrtw_[kLegs]; // empty when unweighted
    RowMatrixXd q_;                    // joint readings as given (for the Jacobian)
    std::vector<double> qv_;           // per joint: q (prismatic) or cos q, sin q (revolute)
    std::vector<int> qoff_;            // offset of joint i's arrays in qv_
};

}  // namespace iwr
