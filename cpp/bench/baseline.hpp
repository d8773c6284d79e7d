// Benchmark-only: the straightforward Eigen implementation of the cost of eq. (10), the yardstick
// against which benchmarks/bench_objective.py measures the optimised kernel. Not used by iwr.
//
// "Straightforward" means what one would write first from the paper: per pose, the carriage
// transform as a product of 4x4 DH matrices (eq. 1-2, a sine and a cosine per joint and pose), then
// each leg vector 0P5 + 0R5 b_j - 0P4 - 0R4 a_j (eq. 8) with Eigen's fixed-size types, its norm and
// the squared residual. The measured poses' rotation matrices (eq. 6) are data and are computed
// once.
#pragma once

#include <vector>

#include "iwr/model.hpp"

namespace iwr::bench {

class EigenBaseline {
  public:
    EigenBaseline(Geometry geometry, const RowMatrixXd& q, const RowMatrixXd& poses,
                  const RowMatrixXd& legs, const RowMatrixXd& weights);
    double cost(const double* x) const;

  private:
    Geometry g_;
    RowMatrixXd q_, legs_, w_;
    std::vector<Mat3> r5_;
    std::vector<Vec3> p5_;
};

}  // namespace iwr::bench
