#include "iwr/objective.hpp"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <sstream>
#include <stdexcept>

#include "clones.hpp"
#include "inline.hpp"
#include "objective_kernel.hpp"

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

// Taylor coefficients (-1)^k / (2k)! of cos and (-1)^k / (2k+1)! of sin, k = 0..9 and 0..8.
struct SinCosSeries {
    double cos[10], sin[9];
};
constexpr SinCosSeries sincos_series() {
    SinCosSeries t{};
    double f = 1;  // 1/n!
    for (int n = 0; n <= 18; ++n) {
        if (n > 0) f /= n;
        const double term = (n / 2) % 2 ? -f : f;
        if (n % 2 == 0) {
            t.cos[n / 2] = term;
        } else {
            t.sin[n / 2] = term;
        }
    }
    return t;
}
constexpr SinCosSeries kSeries = sincos_series();

// cos and sin of nominal_e + delta_e for e < n, from cos and sin of the nominal angles: for the
// deltas of a calibration (|delta| <= 0.8 rad, beyond the +-0.5 rad of the paper's Table 2) by the
// angle-sum identity and the Taylor series of cos delta and sin delta to degree 18 and 17
// (truncation error < 2e-19), else by the C library. Several times cheaper than libm's sin and cos
// (the loops over e vectorise), and no less accurate than cos(fl(nominal + delta)), which rounds the
// angle first. The series by Estrin's scheme (pairs of terms, then pairs of pairs, with d^4, d^8,
// d^16): a critical path of 5 dependent multiplies and an add where Horner's has 18 operations
// (the carriage's constants, this series among them, were about a third of the leg objective's
// fixed cost per evaluation: BENCHMARKS.md, "Thirteenth round"). Not cloned per instruction set:
// GCC has emitted fused operations in a target region despite -ffp-contract=off (BENCHMARKS.md,
// fourth round), and these values must be the same on every CPU.
IWR_FORCE_INLINE void sincos_offset(int n, const double* nominal, const double* cn,
                                    const double* sn, const double* delta, double* c, double* s) {
    const double* kc = kSeries.cos;
    const double* ks = kSeries.sin;
    for (int e = 0; e < n; ++e) {
        const double d = delta[e], y = d * d, y2 = y * y, y4 = y2 * y2, y8 = y4 * y4;
        const double c01 = kc[0] + kc[1] * y, c23 = kc[2] + kc[3] * y, c45 = kc[4] + kc[5] * y,
                     c67 = kc[6] + kc[7] * y, c89 = kc[8] + kc[9] * y;
        const double s01 = ks[0] + ks[1] * y, s23 = ks[2] + ks[3] * y, s45 = ks[4] + ks[5] * y,
                     s67 = ks[6] + ks[7] * y;
        const double cd = ((c01 + c23 * y2) + (c45 + c67 * y2) * y4) + c89 * y8;
        const double sd = (((s01 + s23 * y2) + (s45 + s67 * y2) * y4) + ks[8] * y8) * d;
        c[e] = cn[e] * cd - sn[e] * sd;
        s[e] = sn[e] * cd + cn[e] * sd;
    }
    for (int e = 0; e < n; ++e) {
        if (!(std::abs(delta[e]) <= 0.8)) {
            c[e] = std::cos(nominal[e] + delta[e]);
            s[e] = std::sin(nominal[e] + delta[e]);
        }
    }
}

}  // namespace

Objective::Objective(Geometry geometry, const RowMatrixXd& q, const RowMatrixXd& poses,
                     const RowMatrixXd& legs, const RowMatrixXd& weights,
                     const RowMatrixXd& whitening)
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
    if (whitening.size() != 0) {
        if (weights.size() != 0)
            throw std::invalid_argument(
                "weights, whitening: give one or the other (fold the weights into the whitening)");
        require_shape(whitening, n_, kLegs * kLegs, "whitening");
        require_finite(whitening.data(), whitening.size(), "whitening");
        for (int k = 0; k < n_; ++k) {
            for (int i = 0; i < kLegs; ++i) {
                for (int j = i + 1; j < kLegs; ++j) {
                    if (whitening(k, kLegs * i + j) != 0.0) {
                        std::ostringstream msg;
                        msg << "whitening: pose " << k << ", entry (" << i << ", " << j << ") is "
                            << whitening(k, kLegs * i + j)
                            << "; the whitening of a pose must be lower triangular";
                        throw std::invalid_argument(msg.str());
                    }
                }
            }
        }
        whitening_ = whitening;
    }
    // Blocked layout (see objective_kernel.hpp). Joint readings: the sines and cosines of revolute
    // readings are computed once per data set; each evaluation then needs only the angle-sum
    // identity.
    static_assert(kBlock == detail::kBlock, "one block size");
    int nq = 18;
    if (weights.size() != 0) off_w_ = nq, nq += kLegs;
    if (whitening.size() != 0) off_wh_ = nq, nq += kLegs * (kLegs + 1) / 2;
    for (int i = 0; i < nj; ++i) {
        q_off_.push_back(nq);
        prismatic_.push_back(geometry_.is_prismatic(i) ? 1 : 0);
        nq += geometry_.is_prismatic(i) ? 1 : 2;
    }
    carriage_ = detail::CarriageNominal(geometry_);
    n_blocks_ = (n_ + kBlock - 1) / kBlock;
    stride_ = nq * kBlock;
    blocks_.assign(static_cast<size_t>(n_blocks_) * static_cast<size_t>(stride_), 0.0);
    for (int kk = 0; kk < n_blocks_ * kBlock; ++kk) {
        const int k = std::min(kk, n_ - 1);  // padding: copies of the last pose (finite values)
        double* blk = blocks_.data() + static_cast<size_t>(kk / kBlock) * static_cast<size_t>(stride_);
        auto put = [&](int e, double v) { blk[e * kBlock + kk % kBlock] = v; };
        const Mat3 r = euler_zyx(poses(k, 3), poses(k, 4), poses(k, 5));
        for (int e = 0; e < 9; ++e) put(e, r(e / 3, e % 3));
        for (int e = 0; e < 3; ++e) put(9 + e, poses(k, e));
        for (int j = 0; j < kLegs; ++j) put(12 + j, legs(k, j));
        if (off_w_ >= 0)
            for (int j = 0; j < kLegs; ++j) put(off_w_ + j, std::sqrt(weights(k, j)));
        if (off_wh_ >= 0) {
            int e = off_wh_;
            for (int i = 0; i < kLegs; ++i)
                for (int j = 0; j <= i; ++j) put(e++, whitening(k, kLegs * i + j));
        }
        for (int i = 0; i < nj; ++i) {
            const int o = q_off_[static_cast<size_t>(i)];
            if (prismatic_[static_cast<size_t>(i)]) {
                put(o, q(k, i));
            } else {
                put(o, std::cos(q(k, i)));
                put(o + 1, std::sin(q(k, i)));
            }
        }
    }
}

Objective::Workspace Objective::make_workspace() const {
    Workspace ws;
    ws.buf.assign(static_cast<size_t>(15) * static_cast<size_t>(geometry_.n_joints()) + 1, 0.0);
    return ws;
}

detail::CarriageNominal::CarriageNominal(const Geometry& g) {
    const int nj = g.n_joints();
    while (n_prefix_ < nj && g.is_prismatic(n_prefix_)) ++n_prefix_;
    nominal_.resize(static_cast<size_t>(6 * nj));  // angles, their cosines, their sines
    for (int e = 0; e < 2 * nj; ++e) {
        const double angle = g.dh()(e / 2, e % 2 ? 3 : 0);
        nominal_[static_cast<size_t>(e)] = angle;
        nominal_[static_cast<size_t>(2 * nj + e)] = std::cos(angle);
        nominal_[static_cast<size_t>(4 * nj + e)] = std::sin(angle);
    }
}

namespace {

// CarriageNominal::consts for NJ joints, NP of them a prismatic prefix, the counts constants (the
// loops unrolled, the angles' offsets and their sines and cosines on the stack: for the IWR's
// PPRR carriage 35 ns a call where the counts at run time took 43, BENCHMARKS.md, fifteenth
// round), or NJ = 0: the counts nj_rt, np_rt at run time. The same operations in the same order
// either way: the same bits.
template <int NJ, int NP>
IWR_FORCE_INLINE void carriage_consts(const Geometry& g, const double* nominal, int nj_rt,
                                      int np_rt, const double* x, detail::EvalConsts& ec,
                                      double* jbuf) {
    const int nj = NJ > 0 ? NJ : nj_rt;
    const int n_prefix = NJ > 0 ? NP : np_rt;
    double* z = jbuf;               // 3 per prefix joint
    double* joint = jbuf + 3 * nj;  // 6 per joint: cos/sin alpha, cos/sin theta, a, d
    // The errors of alpha and theta, then c, s (2 per joint): on the stack for constant counts
    // (no stores that the compiler must assume reach ec or x), else in jbuf.
    double local[NJ > 0 ? 6 * NJ : 1];
    double* delta = NJ > 0 ? local : jbuf + 9 * nj;
    double* c = delta + 2 * nj;
    double* s = c + 2 * nj;
    for (int i = 0; i < nj; ++i) delta[2 * i] = x[4 * i], delta[2 * i + 1] = x[4 * i + 3];
    sincos_offset(2 * nj, nominal, nominal + 2 * nj, nominal + 4 * nj, delta, c, s);
    for (int i = 0; i < nj; ++i) {
        double* jc = joint + 6 * i;
        jc[0] = c[2 * i], jc[1] = s[2 * i], jc[2] = c[2 * i + 1], jc[3] = s[2 * i + 1];
        jc[4] = g.dh()(i, 1) + x[4 * i + 1];
        jc[5] = g.dh()(i, 2) + x[4 * i + 2];
    }
    // The prismatic prefix: with rotations independent of the readings, 0T_m has the same rotation
    // at every pose and a position affine in the readings, p = pc + sum_i q_i z_i. Each joint
    // multiplies by Rz(theta) Trans_z(d + q) Trans_x(a) Rx(alpha) (eq. 1).
    // Written in place: a local copy, copied by GCC in 16-byte moves, made loads wait on the
    // 8-byte stores they straddle (store-forwarding stalls: BENCHMARKS.md, thirteenth round).
    double* r = ec.rc;
    double* p = ec.pc;
    for (int e = 0; e < 9; ++e) r[e] = e % 4 == 0 ? 1.0 : 0.0;
    for (int k = 0; k < 3; ++k) p[k] = 0.0;
    for (int i = 0; i < n_prefix; ++i) {
        const double* jc = joint + 6 * i;
        const double ca = jc[0], sa = jc[1], ct = jc[2], st = jc[3], a = jc[4], d = jc[5];
        for (int row = 0; row < 3; ++row) {
            double* t = r + 3 * row;
            z[3 * i + row] = t[2];  // d grows along z_{i-1}
            const double u = t[0] * ct + t[1] * st;
            const double v = t[1] * ct - t[0] * st;
            const double w = t[2];
            p[row] += a * u + d * w;
            t[0] = u;
            t[1] = ca * v + sa * w;
            t[2] = ca * w - sa * v;
        }
    }
    const int base = 4 * nj;
    for (int j = 0; j < kLegs; ++j) {
        for (int k = 0; k < 3; ++k) {
            ec.a[j][k] = g.base()(j, k) + x[base + 3 * j + k];
            ec.b[j][k] = g.platform()(j, k) + x[base + 18 + 3 * j + k];
        }
        ec.l0[j] = g.leg_offsets()(j) + x[base + 36 + j];
    }
    ec.z = z;
    ec.joint = joint;
}

}  // namespace

IWR_CLONES void detail::CarriageNominal::consts(const Geometry& g, const double* x,
                                                EvalConsts& ec, double* jbuf) const {
    const int nj = g.n_joints();
    if (nj == 4 && n_prefix_ == 2)
        carriage_consts<4, 2>(g, nominal_.data(), nj, n_prefix_, x, ec, jbuf);
    else
        carriage_consts<0, 0>(g, nominal_.data(), nj, n_prefix_, x, ec, jbuf);
}

void detail::fold_carriage(EvalConsts& ec, int n_prefix, int n_joints, const char* prismatic) {
    ec.folded = false;
    // The chain the kernel has compiled in (kernel(): chain_is(pd, 2, 2)): the IWR's PPRR.
    if (n_prefix != 2 || n_joints != 4 || prismatic[2] || prismatic[3]) return;
    FoldedCarriage& f = ec.fold;
    const double* j1 = ec.joint + 6 * n_prefix;  // cos/sin alpha, cos/sin theta, a, d
    const double* j2 = j1 + 6;
    // G = Rc Rz(theta1) and H = Rx(alpha1) Rz(theta2). With Rz(q) = E0 + c E1 + s E2 (E0 = e_z
    // e_z^T, E1 = e_x e_x^T + e_y e_y^T, E2 = e_y e_x^T - e_x e_y^T), S = G Rz(q) H is s0 + c s1 +
    // s s2: s0 = G_col2 H_row2, s1 = G_col0 H_row0 + G_col1 H_row1, s2 = G_col1 H_row0 - G_col0
    // H_row1. Scalars, not arrays: copies of small arrays became 16-byte loads of 8-byte stores
    // (store-forwarding stalls).
    const double ct1 = j1[2], st1 = j1[3], ca1 = j1[0], sa1 = j1[1], ct2 = j2[2], st2 = j2[3];
    const double a1 = j1[4], d1 = j1[5], d2 = j2[5];
    const double h00 = ct2, h01 = -st2, h10 = ca1 * st2, h11 = ca1 * ct2, h12 = -sa1,
                 h20 = sa1 * st2, h21 = sa1 * ct2, h22 = ca1;
    for (int r = 0; r < 3; ++r) {
        const double* rc = ec.rc + 3 * r;
        const double g0 = rc[0] * ct1 + rc[1] * st1, g1 = rc[1] * ct1 - rc[0] * st1, g2 = rc[2];
        double* s0 = f.s0 + 3 * r;
        double* s1 = f.s1 + 3 * r;
        double* s2 = f.s2 + 3 * r;
        s0[0] = g2 * h20, s0[1] = g2 * h21, s0[2] = g2 * h22;
        s1[0] = g0 * h00 + g1 * h10, s1[1] = g0 * h01 + g1 * h11, s1[2] = g1 * h12;
        s2[0] = g1 * h00 - g0 * h10, s2[1] = g1 * h01 - g0 * h11, s2[2] = -(g0 * h12);
        // p4 = pc + sum q_i z_i + d1 Rc e_z + a1 (c G_col0 + s G_col1) + d2 S e_z + a2 R' e_x.
        f.p0[r] = (ec.pc[r] + d1 * g2) + d2 * s0[2];
        f.pc[r] = a1 * g0 + d2 * s1[2];
        f.ps[r] = a1 * g1 + d2 * s2[2];
    }
    // The legs in {4'} = {4} Rx(alpha2)^T: a_j' = Rx(alpha2) a_j. And a2 R' e_x, the last term of
    // p4, is a2 e_x in {4'} (R'^T R' = I): moved onto a_j' too.
    const double a2 = j2[4], ca2 = j2[0], sa2 = j2[1];
    for (int j = 0; j < 6; ++j) {
        f.a[j][0] = ec.a[j][0] + a2;
        f.a[j][1] = ca2 * ec.a[j][1] - sa2 * ec.a[j][2];
        f.a[j][2] = sa2 * ec.a[j][1] + ca2 * ec.a[j][2];
    }
    ec.folded = true;
}

void Objective::prepare(const double* x, detail::EvalConsts& ec, double* jbuf) const {
    carriage_.consts(geometry_, x, ec, jbuf);
    detail::fold_carriage(ec, carriage_.n_prefix(), geometry_.n_joints(), prismatic_.data());
}

double Objective::evaluate(const double* x, double* jbuf, double* res) const {
    detail::EvalConsts ec;
    prepare(x, ec, jbuf);
    detail::PoseData pd;
    pd.data = blocks_.data();
    pd.n = n_;
    pd.n_blocks = n_blocks_;
    pd.stride = stride_;
    pd.off_r5 = 0;
    pd.off_p5 = 9;
    pd.off_s = 12;
    pd.off_w = off_w_;
    pd.off_wh = off_wh_;
    pd.n_joints = geometry_.n_joints();
    pd.n_prefix = carriage_.n_prefix();
    pd.q_off = q_off_.data();
    pd.prismatic = prismatic_.data();
    return detail::active_kernel()(pd, ec, res);
}

double Objective::cost(const double* x, Workspace& ws) const {
    return evaluate(x, ws.buf.data(), nullptr);
}

double Objective::cost(const Eigen::Ref<const VectorXd>& x) const {
    geometry_.check_errors(x.data(), x.size(), "x");
    Workspace ws = make_workspace();
    return cost(x.data(), ws);
}

VectorXd Objective::residuals(const Eigen::Ref<const VectorXd>& x) const {
    geometry_.check_errors(x.data(), x.size(), "x");
    VectorXd r(n_residuals());
    Workspace ws = make_workspace();
    evaluate(x.data(), ws.buf.data(), r.data());
    return r;
}

void Objective::jacobian(const Eigen::Ref<const VectorXd>& x, VectorXd* residuals,
                         RowMatrixXd* jac) const {
    geometry_.check_errors(x.data(), x.size(), "x");
    const Geometry& g = geometry_;
    const int nj = g.n_joints(), np = g.n_params();
    if (residuals) {
        // The residuals come from the same kernel as cost(), so that cost == sum of their squares
        // (up to the order of summation) even where the residuals are at rounding level.
        residuals->resize(n_residuals());
        Workspace ws = make_workspace();
        evaluate(x.data(), ws.buf.data(), residuals->data());
    }
    if (!jac) return;
    jac->setZero(n_residuals(), np);
    std::vector<Mat4> frames(static_cast<size_t>(nj) + 1);
    LegMatrix a, b;
    for (int j = 0; j < kLegs; ++j) {
        for (int c = 0; c < 3; ++c) {
            a(j, c) = g.base()(j, c) + x[g.idx_base(j, c)];
            b(j, c) = g.platform()(j, c) + x[g.idx_platform(j, c)];
        }
    }
    for (int k = 0; k < n_; ++k) {
        const Mat4 t4 = carriage_transform(g, x.data(), q_.row(k).data(), frames.data());
        const Mat3 r4 = t4.topLeftCorner<3, 3>();
        const Vec3 p4 = t4.topRightCorner<3, 1>();
        Mat3 r5;
        for (int e = 0; e < 9; ++e) r5(e / 3, e % 3) = pose_value(e, k);
        const Vec3 p5(pose_value(9, k), pose_value(10, k), pose_value(11, k));
        for (int j = 0; j < kLegs; ++j) {
            const Vec3 pa = p4 + r4 * a.row(j).transpose();  // U-joint centre in {0}
            const Vec3 v = p5 + r5 * b.row(j).transpose() - pa;
            const double len = v.norm();
            const double sw = off_w_ < 0 ? 1.0 : pose_value(off_w_ + j, k);
            const int row = kLegs * k + j;
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
        if (off_wh_ >= 0) {  // the whitened rows: W_k times the six rows of pose k
            const Eigen::Map<const Eigen::Matrix<double, kLegs, kLegs, Eigen::RowMajor>> w(
                whitening_.row(k).data());
            jac->middleRows(kLegs * k, kLegs) =
                (w.triangularView<Eigen::Lower>() * jac->middleRows(kLegs * k, kLegs)).eval();
        }
    }
}

std::vector<std::string> supported_kernels() { return detail::supported_kernels(); }
std::string active_kernel() { return detail::active_kernel_name(); }
void select_kernel(const std::string& name) { detail::select_kernel(name); }

namespace {

std::string joined(const std::vector<std::string>& names) {
    std::string out;
    for (const std::string& k : names) out += (out.empty() ? "" : ", ") + k;
    return out;
}

// A value as the message shows it: printable ASCII as is, any other byte as \xHH (a message must
// stay one line of valid UTF-8 whatever the environment holds).
std::string shown(const std::string& value) {
    std::string out;
    for (const unsigned char c : value) {
        if (c >= 0x20 && c < 0x7f && c != '\\') {
            out += static_cast<char>(c);
        } else {
            static const char* hex = "0123456789abcdef";
            out += "\\x";
            out += hex[c >> 4];
            out += hex[c & 15];
        }
    }
    return out;
}

// The variant IWR_KERNEL names; "" when it names none (unset, empty or auto: the widest).
std::string kernel_variable() {
    const char* value = std::getenv("IWR_KERNEL");
    const std::string name = value ? value : "";
    return name == "auto" ? "" : name;
}

}  // namespace

void select_kernel_from_environment() {
    const std::string name = kernel_variable();
    const std::vector<std::string> runs = supported_kernels();
    if (name.empty()) {
        detail::select_kernel(runs.back());
        return;
    }
    if (std::find(runs.begin(), runs.end(), name) != runs.end()) {
        detail::select_kernel(name);
        return;
    }
    const std::vector<std::string> built = detail::compiled_kernels();
    const bool known = std::find(built.begin(), built.end(), name) != built.end();
    throw std::invalid_argument("environment variable IWR_KERNEL='" + shown(name) + "': " +
                                (known ? "this CPU cannot run that kernel variant"
                                       : "not a kernel variant") +
                                "; expected one this CPU runs (" + joined(runs) + ") or auto");
}

std::string kernel_summary() {
    return "kernel " + active_kernel() + "; this CPU runs " + joined(supported_kernels());
}

std::string kernel_environment_prefix() {
    const std::string name = kernel_variable();
    return name.empty() ? "" : "IWR_KERNEL=" + name + " ";
}

void Objective::cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const {
    batch_costs(*this, X, static_cast<std::size_t>(m), out, pool);
}

}  // namespace iwr
