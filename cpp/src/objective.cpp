#include "iwr/objective.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace iwr {

namespace {

void require_shape(const RowMatrixXd& m, Eigen::Index rows, Eigen::Index cols, const char* what) {
    if (m.rows() != rows || m.cols() != cols) {
        std::ostringstream msg;
        msg << what << ": shape (" << m.rows() << ", " << m.cols() << "); expected (" << rows
            << ", " << cols << ")";
        throw std::invalid_argument(msg.str());
    }
}

// Number of doubles of scratch per pose: 12 for the carriage transform 0T4 (rotation row-major,
// then position), 1 for the per-pose sum of squared residuals.
constexpr int kScratchPerPose = 13;

}  // namespace

Objective::Objective(Geometry geometry, const RowMatrixXd& q, const RowMatrixXd& poses,
                     const RowMatrixXd& legs, const RowMatrixXd& weights)
    : geometry_(std::move(geometry)), n_(static_cast<int>(poses.rows())), q_(q) {
    const int nj = geometry_.n_joints();
    if (n_ == 0) throw std::invalid_argument("poses: no measurements (0 rows)");
    require_shape(poses, n_, 6, "poses");
    require_shape(q, n_, nj, "q");
    require_shape(legs, n_, kLegs, "legs");
    require_finite(q.data(), q.size(), "q");
    require_finite(poses.data(), poses.size(), "poses");
    require_finite(legs.data(), legs.size(), "legs");
    if (weights.size() != 0) {
        require_shape(weights, n_, kLegs, "weights");
        require_finite(weights.data(), weights.size(), "weights");
        for (Eigen::Index i = 0; i < weights.size(); ++i) {
            if (weights.data()[i] < 0) {
                std::ostringstream msg;
                msg << "weights: entry " << i << " is " << weights.data()[i]
                    << "; weights must be >= 0";
                throw std::invalid_argument(msg.str());
            }
        }
    }
    const size_t n = static_cast<size_t>(n_);
    for (auto& v : r5_) v.resize(n);
    for (auto& v : p5_) v.resize(n);
    for (auto& v : legs_) v.resize(n);
    for (int k = 0; k < n_; ++k) {
        const Mat3 r = euler_zyx(poses(k, 3), poses(k, 4), poses(k, 5));
        for (int e = 0; e < 9; ++e) r5_[e][k] = r(e / 3, e % 3);
        for (int e = 0; e < 3; ++e) p5_[e][k] = poses(k, e);
        for (int j = 0; j < kLegs; ++j) legs_[j][k] = legs(k, j);
    }
    if (weights.size() != 0) {
        for (int j = 0; j < kLegs; ++j) {
            sqrtw_[j].resize(n);
            for (int k = 0; k < n_; ++k) sqrtw_[j][k] = std::sqrt(weights(k, j));
        }
    }
    // Joint readings: the sines and cosines of revolute readings are computed once per data set;
    // each evaluation then needs only the angle-sum identity.
    for (int i = 0; i < nj; ++i) {
        qoff_.push_back(static_cast<int>(qv_.size()));
        if (geometry_.is_prismatic(i)) {
            for (int k = 0; k < n_; ++k) qv_.push_back(q(k, i));
        } else {
            for (int k = 0; k < n_; ++k) qv_.push_back(std::cos(q(k, i)));
            for (int k = 0; k < n_; ++k) qv_.push_back(std::sin(q(k, i)));
        }
    }
}

Objective::Workspace Objective::make_workspace() const {
    Workspace ws;
    ws.buf.assign(static_cast<size_t>(kScratchPerPose) * static_cast<size_t>(n_), 0.0);
    return ws;
}

namespace {

// One pass over the poses for one leg; adds each pose's squared residual to acc.
template <bool Weighted>
void leg_pass(int n, const double* const* t, const std::vector<double>* r5,
              const std::vector<double>* p5, const double* s, const double* sw, const double a[3],
              const double b[3], double l0, double* acc) {
    const double *r00 = r5[0].data(), *r01 = r5[1].data(), *r02 = r5[2].data();
    const double *r10 = r5[3].data(), *r11 = r5[4].data(), *r12 = r5[5].data();
    const double *r20 = r5[6].data(), *r21 = r5[7].data(), *r22 = r5[8].data();
    const double *px = p5[0].data(), *py = p5[1].data(), *pz = p5[2].data();
    const double *t00 = t[0], *t01 = t[1], *t02 = t[2], *t10 = t[3], *t11 = t[4], *t12 = t[5];
    const double *t20 = t[6], *t21 = t[7], *t22 = t[8], *tx = t[9], *ty = t[10], *tz = t[11];
    for (int k = 0; k < n; ++k) {
        const double vx = px[k] + r00[k] * b[0] + r01[k] * b[1] + r02[k] * b[2] - tx[k] -
                          (t00[k] * a[0] + t01[k] * a[1] + t02[k] * a[2]);
        const double vy = py[k] + r10[k] * b[0] + r11[k] * b[1] + r12[k] * b[2] - ty[k] -
                          (t10[k] * a[0] + t11[k] * a[1] + t12[k] * a[2]);
        const double vz = pz[k] + r20[k] * b[0] + r21[k] * b[1] + r22[k] * b[2] - tz[k] -
                          (t20[k] * a[0] + t21[k] * a[1] + t22[k] * a[2]);
        double r = std::sqrt(vx * vx + vy * vy + vz * vz) - l0 - s[k];
        if (Weighted) r *= sw[k];
        acc[k] += r * r;
    }
}

}  // namespace

double Objective::cost(const double* x, Workspace& ws) const {
    const int n = n_;
    double* buf = ws.buf.data();
    double* t[12];
    for (int e = 0; e < 12; ++e) t[e] = buf + static_cast<size_t>(e) * static_cast<size_t>(n);
    double* acc = buf + static_cast<size_t>(12) * static_cast<size_t>(n);

    // Carriage chain 0T4, all poses at once, one joint at a time (eq. 1-2).
    const int nj = geometry_.n_joints();
    if (nj == 0) {
        for (int e = 0; e < 12; ++e) {
            const double v = (e == 0 || e == 4 || e == 8) ? 1.0 : 0.0;
            for (int k = 0; k < n; ++k) t[e][k] = v;
        }
    }
    for (int i = 0; i < nj; ++i) {
        const double alpha = geometry_.dh()(i, 0) + x[4 * i + 0];
        const double a = geometry_.dh()(i, 1) + x[4 * i + 1];
        const double d = geometry_.dh()(i, 2) + x[4 * i + 2];
        const double theta = geometry_.dh()(i, 3) + x[4 * i + 3];
        const double ca = std::cos(alpha), sa = std::sin(alpha);
        const double ct = std::cos(theta), st = std::sin(theta);
        const bool prismatic = geometry_.is_prismatic(i);
        const double* q0 = qv_.data() + qoff_[static_cast<size_t>(i)];  // q, or cos q
        const double* q1 = q0 + n;                                         // sin q (revolute)
        if (i == 0) {
            // 0T1 = A_1 itself.
            for (int k = 0; k < n; ++k) {
                const double c = prismatic ? ct : ct * q0[k] - st * q1[k];
                const double s = prismatic ? st : st * q0[k] + ct * q1[k];
                const double dk = prismatic ? d + q0[k] : d;
                t[0][k] = c, t[1][k] = -s * ca, t[2][k] = s * sa;
                t[3][k] = s, t[4][k] = c * ca, t[5][k] = -c * sa;
                t[6][k] = 0, t[7][k] = sa, t[8][k] = ca;
                t[9][k] = a * c, t[10][k] = a * s, t[11][k] = dk;
            }
            continue;
        }
        // T <- T A_i, row by row: with u = T0 c + T1 s and v = T1 c - T0 s the new rotation row is
        // (u, ca v + sa T2, -sa v + ca T2) and the position gains a u + d_k T2.
        for (int k = 0; k < n; ++k) {
            const double c = prismatic ? ct : ct * q0[k] - st * q1[k];
            const double s = prismatic ? st : st * q0[k] + ct * q1[k];
            const double dk = prismatic ? d + q0[k] : d;
            for (int r = 0; r < 3; ++r) {
                double* row0 = t[3 * r];
                double* row1 = t[3 * r + 1];
                double* row2 = t[3 * r + 2];
                const double u = row0[k] * c + row1[k] * s;
                const double v = row1[k] * c - row0[k] * s;
                const double w = row2[k];
                row0[k] = u;
                row1[k] = ca * v + sa * w;
                row2[k] = ca * w - sa * v;
                t[9 + r][k] += a * u + dk * w;
            }
        }
    }

    // Legs (eq. 8): sum over legs per pose, then over poses in a fixed order.
    for (int k = 0; k < n; ++k) acc[k] = 0.0;
    const double* tc[12];
    for (int e = 0; e < 12; ++e) tc[e] = t[e];
    for (int j = 0; j < kLegs; ++j) {
        double a[3], b[3];
        for (int c = 0; c < 3; ++c) {
            a[c] = geometry_.base()(j, c) + x[geometry_.idx_base(j, c)];
            b[c] = geometry_.platform()(j, c) + x[geometry_.idx_platform(j, c)];
        }
        const double l0 = geometry_.leg_offsets()(j) + x[geometry_.idx_offset(j)];
        if (sqrtw_[0].empty()) {
            leg_pass<false>(n, tc, r5_, p5_, legs_[j].data(), nullptr, a, b, l0, acc);
        } else {
            leg_pass<true>(n, tc, r5_, p5_, legs_[j].data(), sqrtw_[j].data(), a, b, l0, acc);
        }
    }
    // Eight fixed lanes: vectorisable, and the summation order never depends on the machine.
    double lane[8] = {0, 0, 0, 0, 0, 0, 0, 0};
    int k = 0;
    for (; k + 8 <= n; k += 8)
        for (int l = 0; l < 8; ++l) lane[l] += acc[k + l];
    for (int l = 0; k < n; ++k, ++l) lane[l] += acc[k];
    return ((lane[0] + lane[4]) + (lane[1] + lane[5])) + ((lane[2] + lane[6]) + (lane[3] + lane[7]));
}

double Objective::cost(const Eigen::Ref<const VectorXd>& x) const {
    geometry_.check_errors(x.data(), x.size(), "x");
    Workspace ws = make_workspace();
    return cost(x.data(), ws);
}

VectorXd Objective::residuals(const Eigen::Ref<const VectorXd>& x) const {
    VectorXd r;
    jacobian(x, &r, nullptr);
    return r;
}

void Objective::jacobian(const Eigen::Ref<const VectorXd>& x, VectorXd* residuals,
                         RowMatrixXd* jac) const {
    geometry_.check_errors(x.data(), x.size(), "x");
    const Geometry& g = geometry_;
    const int nj = g.n_joints(), np = g.n_params();
    if (residuals) residuals->resize(n_residuals());
    if (jac) jac->setZero(n_residuals(), np);
    std::vector<Mat4> frames(static_cast<size_t>(nj) + 1);
    LegMatrix a, b;
    LegVector l0;
    for (int j = 0; j < kLegs; ++j) {
        for (int c = 0; c < 3; ++c) {
            a(j, c) = g.base()(j, c) + x[g.idx_base(j, c)];
            b(j, c) = g.platform()(j, c) + x[g.idx_platform(j, c)];
        }
        l0(j) = g.leg_offsets()(j) + x[g.idx_offset(j)];
    }
    for (int k = 0; k < n_; ++k) {
        const Mat4 t4 = carriage_transform(g, x.data(), q_.row(k).data(), frames.data());
        const Mat3 r4 = t4.topLeftCorner<3, 3>();
        const Vec3 p4 = t4.topRightCorner<3, 1>();
        Mat3 r5;
        for (int e = 0; e < 9; ++e) r5(e / 3, e % 3) = r5_[e][k];
        const Vec3 p5(p5_[0][k], p5_[1][k], p5_[2][k]);
        for (int j = 0; j < kLegs; ++j) {
            const Vec3 pa = p4 + r4 * a.row(j).transpose();  // U-joint centre in {0}
            const Vec3 v = p5 + r5 * b.row(j).transpose() - pa;
            const double len = v.norm();
            const double sw = sqrtw_[0].empty() ? 1.0 : sqrtw_[j][k];
            const int row = kLegs * k + j;
            if (residuals) (*residuals)(row) = sw * (len - l0(j) - legs_[j][k]);
            if (!jac) continue;
            const Vec3 u = v / len;  // d len = u . (dB - dA)
            auto jr = jac->row(row);
            // Carriage joint i moves everything beyond frame i-1: theta and d act about/along
            // z_{i-1} through o_{i-1}; a and alpha along/about x_i through o_i.
            for (int i = 0; i < nj; ++i) {
                const Vec3 z_prev = frames[static_cast<size_t>(i)].block<3, 1>(0, 2);
                const Vec3 o_prev = frames[static_cast<size_t>(i)].block<3, 1>(0, 3);
                const Vec3 x_i = frames[static_cast<size_t>(i) + 1].block<3, 1>(0, 0);
                const Vec3 o_i = frames[static_cast<size_t>(i) + 1].block<3, 1>(0, 3);
                jr(4 * i + 0) = -sw * u.dot(x_i.cross(pa - o_i));
                jr(4 * i + 1) = -sw * u.dot(x_i);
                jr(4 * i + 2) = -sw * u.dot(z_prev);
                jr(4 * i + 3) = -sw * u.dot(z_prev.cross(pa - o_prev));
            }
            const Vec3 da = -sw * (r4.transpose() * u);
            const Vec3 db = sw * (r5.transpose() * u);
            for (int c = 0; c < 3; ++c) {
                jr(g.idx_base(j, c)) = da(c);
                jr(g.idx_platform(j, c)) = db(c);
            }
            jr(g.idx_offset(j)) = -sw;
        }
    }
}

void Objective::cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const {
    std::vector<Workspace> ws(static_cast<size_t>(pool.size()));
    for (auto& w : ws) w = make_workspace();
    const size_t np = static_cast<size_t>(n_params());
    pool.parallel_for(static_cast<size_t>(m), [&](size_t b, size_t e, int id) {
        Workspace& w = ws[static_cast<size_t>(id)];
        for (size_t i = b; i < e; ++i) out[i] = cost(X + i * np, w);
    });
}

}  // namespace iwr
