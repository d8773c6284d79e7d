#include "baseline.hpp"

#include <cmath>

namespace iwr::bench {

EigenBaseline::EigenBaseline(Geometry geometry, const RowMatrixXd& q, const RowMatrixXd& poses,
                             const RowMatrixXd& legs, const RowMatrixXd& weights)
    : g_(std::move(geometry)), q_(q), legs_(legs), w_(weights) {
    for (Eigen::Index k = 0; k < poses.rows(); ++k) {
        r5_.push_back(euler_zyx(poses(k, 3), poses(k, 4), poses(k, 5)));
        p5_.emplace_back(poses(k, 0), poses(k, 1), poses(k, 2));
    }
}

double EigenBaseline::cost(const double* x) const {
    const int nj = g_.n_joints();
    double sum = 0;
    for (Eigen::Index k = 0; k < q_.rows(); ++k) {
        Mat4 t = Mat4::Identity();
        for (int i = 0; i < nj; ++i) {
            double d = g_.dh()(i, 2) + x[4 * i + 2], theta = g_.dh()(i, 3) + x[4 * i + 3];
            (g_.is_prismatic(i) ? d : theta) += q_(k, i);
            t = t * dh_transform(g_.dh()(i, 0) + x[4 * i], g_.dh()(i, 1) + x[4 * i + 1], d, theta);
        }
        for (int j = 0; j < kLegs; ++j) {
            const Vec3 a =
                g_.base().row(j).transpose() + Eigen::Map<const Vec3>(x + g_.idx_base(j, 0));
            const Vec3 b = g_.platform().row(j).transpose() +
                           Eigen::Map<const Vec3>(x + g_.idx_platform(j, 0));
            const Vec3 leg = p5_[static_cast<size_t>(k)] + r5_[static_cast<size_t>(k)] * b -
                             t.topRightCorner<3, 1>() - t.topLeftCorner<3, 3>() * a;
            const double r = leg.norm() - (g_.leg_offsets()(j) + x[g_.idx_offset(j)]) - legs_(k, j);
            sum += (w_.size() ? w_(k, j) : 1.0) * r * r;
        }
    }
    return sum;
}

}  // namespace iwr::bench
