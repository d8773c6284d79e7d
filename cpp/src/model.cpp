#include "iwr/model.hpp"

#include "clones.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <utility>

namespace iwr {

namespace {
// Whether data[0..n) holds an inf or a NaN: the exponent bits of each value's upper half all ones,
// with no branch per value, a loop the compiler vectorises (on the upper 32 bits: SSE2 has no
// 64-bit comparison), and compiled for AVX2 and AVX-512 too (IWR_CLONES).
IWR_CLONES bool any_not_finite(const double* data, Eigen::Index n) {
    constexpr std::uint32_t kExp = 0x7ff00000u;
    std::uint32_t bad = 0;
    for (Eigen::Index i = 0; i < n; ++i) {
        std::uint64_t u;
        std::memcpy(&u, data + i, sizeof u);
        bad |= (static_cast<std::uint32_t>(u >> 32) & kExp) == kExp ? 1u : 0u;
    }
    return bad != 0;
}
}  // namespace

void require_finite(const double* data, Eigen::Index size, const char* what) {
    // Chunk by chunk without a branch per value (cost_batch checks a whole population, 600 x 58,
    // this way); the first bad value named as before.
    constexpr Eigen::Index kChunk = 512;
    Eigen::Index first = 0;
    while (first < size && !any_not_finite(data + first, std::min(kChunk, size - first)))
        first += kChunk;
    for (Eigen::Index i = first; i < size; ++i) {
        if (!std::isfinite(data[i])) {
            std::ostringstream msg;
            msg << what << ": entry " << i << " is " << data[i] << "; every value must be finite";
            throw std::invalid_argument(msg.str());
        }
    }
}

void require_pose_shapes(const Geometry& g, const Eigen::Ref<const RowMatrixXd>& q,
                         const Eigen::Ref<const RowMatrixXd>& per_pose, const char* what) {
    const Eigen::Index n = per_pose.rows();
    if (per_pose.cols() != 6) {
        std::ostringstream msg;
        msg << what << ": shape (" << per_pose.rows() << ", " << per_pose.cols()
            << "); expected (N, 6)";
        throw std::invalid_argument(msg.str());
    }
    if (q.rows() != n || q.cols() != g.n_joints()) {
        std::ostringstream msg;
        msg << "q: shape (" << q.rows() << ", " << q.cols() << "); expected (" << n << ", "
            << g.n_joints() << ") for " << n << " poses and " << g.n_joints() << " joints";
        throw std::invalid_argument(msg.str());
    }
}

Geometry::Geometry(std::string joint_types, RowMatrixXd dh, LegMatrix base, LegMatrix platform,
                   LegVector leg_offsets)
    : joint_types_(std::move(joint_types)),
      dh_(std::move(dh)),
      base_(base),
      platform_(platform),
      leg_offsets_(leg_offsets) {
    for (size_t i = 0; i < joint_types_.size(); ++i) {
        const char c = joint_types_[i];
        if (c != 'P' && c != 'R') {
            std::ostringstream msg;
            msg << "joint_types: letter " << i << " is '" << c
                << "'; each joint must be 'P' (prismatic) or 'R' (revolute)";
            throw std::invalid_argument(msg.str());
        }
    }
    if (dh_.rows() != n_joints() || dh_.cols() != 4) {
        std::ostringstream msg;
        msg << "dh: shape (" << dh_.rows() << ", " << dh_.cols() << ") but joint_types '"
            << joint_types_ << "' needs (" << n_joints() << ", 4)";
        throw std::invalid_argument(msg.str());
    }
    require_finite(dh_.data(), dh_.size(), "dh");
    require_finite(base_.data(), base_.size(), "base_joints");
    require_finite(platform_.data(), platform_.size(), "platform_joints");
    require_finite(leg_offsets_.data(), leg_offsets_.size(), "leg_offsets");
}

void Geometry::check_errors(const double* x, Eigen::Index size, const char* what) const {
    if (size != n_params()) {
        std::ostringstream msg;
        msg << what << ": " << size << " values given but this robot has " << n_params()
            << " error parameters";
        throw std::invalid_argument(msg.str());
    }
    require_finite(x, size, what);
}

Mat3 euler_zyx(double alpha, double beta, double gamma) {
    const double ca = std::cos(alpha), sa = std::sin(alpha);
    const double cb = std::cos(beta), sb = std::sin(beta);
    const double cg = std::cos(gamma), sg = std::sin(gamma);
    Mat3 r;
    r << ca * cb, ca * sb * sg - sa * cg, ca * sb * cg + sa * sg,  //
        sa * cb, sa * sb * sg + ca * cg, sa * sb * cg - ca * sg,   //
        -sb, cb * sg, cb * cg;
    return r;
}

Mat4 dh_transform(double alpha, double a, double d, double theta) {
    const double ct = std::cos(theta), st = std::sin(theta);
    const double ca = std::cos(alpha), sa = std::sin(alpha);
    Mat4 t;
    t << ct, -ca * st, sa * st, a * ct,  //
        st, ca * ct, -sa * ct, a * st,   //
        0, sa, ca, d,                    //
        0, 0, 0, 1;
    return t;
}

Mat4 carriage_transform(const Geometry& g, const double* x, const double* q, Mat4* frames) {
    Mat4 t = Mat4::Identity();
    if (frames) frames[0] = t;
    for (int i = 0; i < g.n_joints(); ++i) {
        const double alpha = g.dh()(i, 0) + x[4 * i + 0];
        const double a = g.dh()(i, 1) + x[4 * i + 1];
        double d = g.dh()(i, 2) + x[4 * i + 2];
        double theta = g.dh()(i, 3) + x[4 * i + 3];
        if (g.is_prismatic(i)) {
            d += q[i];
        } else {
            theta += q[i];
        }
        t = t * dh_transform(alpha, a, d, theta);
        if (frames) frames[i + 1] = t;
    }
    return t;
}

RowMatrixXd predict_legs(const Geometry& g, const Eigen::Ref<const VectorXd>& x,
                         const Eigen::Ref<const RowMatrixXd>& q,
                         const Eigen::Ref<const RowMatrixXd>& poses) {
    g.check_errors(x.data(), x.size(), "errors");
    require_pose_shapes(g, q, poses, "poses");
    const Eigen::Index n = poses.rows();
    require_finite(q.data(), q.size(), "q");
    require_finite(poses.data(), poses.size(), "poses");
    const int nj = g.n_joints();
    RowMatrixXd out(n, kLegs);
    for (Eigen::Index k = 0; k < n; ++k) {
        const Mat4 t4 = carriage_transform(g, x.data(), q.row(k).data());
        const Mat3 r5 = euler_zyx(poses(k, 3), poses(k, 4), poses(k, 5));
        const Vec3 p5(poses(k, 0), poses(k, 1), poses(k, 2));
        for (int j = 0; j < kLegs; ++j) {
            const Vec3 a = g.base().row(j).transpose() + Eigen::Map<const Vec3>(x.data() + 4 * nj + 3 * j);
            const Vec3 b =
                g.platform().row(j).transpose() + Eigen::Map<const Vec3>(x.data() + 4 * nj + 18 + 3 * j);
            const Vec3 leg = p5 + r5 * b - t4.topRightCorner<3, 1>() - t4.topLeftCorner<3, 3>() * a;
            out(k, j) = leg.norm() - (g.leg_offsets()(j) + x[4 * nj + 36 + j]);
        }
    }
    return out;
}

}  // namespace iwr
