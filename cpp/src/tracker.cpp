#include "iwr/tracker.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace iwr {

namespace {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

Mat3 skew(const Vec3& v) {
    Mat3 m;
    m << 0, -v(2), v(1), v(2), 0, -v(0), -v(1), v(0), 0;
    return m;
}

// Chord iterations (the reference's inverse Jacobian, not refactorised) before falling back to the
// damped Newton-Raphson of hexapod_forward. From the reference, a parameter change of a millimetre
// moves the pose by about as much and the Jacobian by about 1e-3 relative, so the error shrinks a
// thousandfold per iteration and 4-5 iterations reach 1e-10 mm.
constexpr int kMaxChord = 12;

// The hexapod's leg-length Jacobian in the (dP, omega) parametrisation: d l_j = u_j . dP +
// (w_j x u_j) . omega, with omega a rotation in {4} (R <- Exp(omega) R) and w_j = R b_j.
Matrix6d leg_jacobian(const LegMatrix& a, const LegMatrix& b, const Vec3& p, const Mat3& r,
                      LegVector* len = nullptr) {
    Matrix6d j;
    for (int l = 0; l < kLegs; ++l) {
        const Vec3 w = r * b.row(l).transpose();
        const Vec3 v = p + w - a.row(l).transpose();
        const double n = v.norm();
        if (len) (*len)(l) = n;
        const Vec3 u = v / n;
        j.row(l) << u.transpose(), w.cross(u).transpose();
    }
    return j;
}

void require_rows(const RowMatrixXd& m, Eigen::Index rows, Eigen::Index cols, const char* what) {
    if (m.rows() != rows || m.cols() != cols) {
        std::ostringstream msg;
        msg << what << ": shape (" << m.rows() << ", " << m.cols() << "); expected (" << rows
            << ", " << cols << ")";
        throw std::invalid_argument(msg.str());
    }
}

}  // namespace

namespace detail {

// Chord iterations for kTrackerLanes poses at once, one pose per lane, written as loops over the
// lanes so that the compiler vectorises them; compiled for AVX-512, AVX2 and the x86-64 baseline
// and chosen at load time (GCC's target_clones). Each lane computes exactly what it would alone:
// a lane that has converged (or must fall back) gets a zero step, which leaves its pose unchanged
// bit for bit, so results never depend on the other poses of the block. No FMA contraction
// (-ffp-contract=off): the same bits for every variant.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
__attribute__((target_clones("avx512f", "avx2", "default")))
#endif
void tracker_chord_block(const double* __restrict blk, const double* __restrict a,
                         const double* __restrict b, const double* __restrict l0, double tol,
                         int max_iter, double* __restrict p, double* __restrict r,
                         int* __restrict status) {
    constexpr int W = kTrackerLanes;
    const double* inv = blk;
    const double* pref = blk + 36 * W;
    const double* rref = blk + 39 * W;
    const double* legs = blk + 48 * W;
    double len[6 * W], len2[6 * W], half_inv[6 * W], f[6 * W], s[6 * W], err[W], prev[W], act[W];
    for (int i = 0; i < 3 * W; ++i) p[i] = pref[i];
    for (int i = 0; i < 9 * W; ++i) r[i] = rref[i];
    for (int j = 0; j < 6; ++j)
        for (int l = 0; l < W; ++l) len[j * W + l] = legs[j * W + l] + l0[j];
    // The residual of leg j is (|v|^2 - L^2) / (2 L) rather than |v| - L: the same root, the same
    // derivative there (u . dv), a difference of (|v| - L)^2 / (2 L), and no square root.
    for (int i = 0; i < 6 * W; ++i) len2[i] = len[i] * len[i], half_inv[i] = 0.5 / len[i];
    for (int l = 0; l < W; ++l) {
        status[l] = 0;
        act[l] = 1.0;
        prev[l] = std::numeric_limits<double>::infinity();
        for (int j = 0; j < 6; ++j) {
            if (!(len[j * W + l] > 0)) status[l] = 2, act[l] = 0.0;
        }
    }
    for (int it = 0;; ++it) {
        for (int l = 0; l < W; ++l) err[l] = 0.0;
        for (int j = 0; j < 6; ++j) {
            const double ax = a[3 * j], ay = a[3 * j + 1], az = a[3 * j + 2];
            const double bx = b[3 * j], by = b[3 * j + 1], bz = b[3 * j + 2];
            for (int l = 0; l < W; ++l) {
                const double vx = p[l] + r[l] * bx + r[W + l] * by + r[2 * W + l] * bz - ax;
                const double vy = p[W + l] + r[3 * W + l] * bx + r[4 * W + l] * by +
                                  r[5 * W + l] * bz - ay;
                const double vz = p[2 * W + l] + r[6 * W + l] * bx + r[7 * W + l] * by +
                                  r[8 * W + l] * bz - az;
                const double fj = (vx * vx + vy * vy + vz * vz - len2[j * W + l]) * half_inv[j * W + l];
                f[j * W + l] = fj;
                err[l] = std::max(err[l], std::abs(fj));
            }
        }
        bool any = false;
        for (int l = 0; l < W; ++l) {
            if (act[l] == 0.0) continue;
            if (err[l] <= tol) {
                act[l] = 0.0;
            } else if (!(err[l] < 0.5 * prev[l]) || it == max_iter) {
                act[l] = 0.0;  // not contracting: the damped Newton fallback
                status[l] = 1;
            } else {
                prev[l] = err[l];
                any = true;
            }
        }
        if (!any) return;
        for (int m = 0; m < 6; ++m) {
            for (int l = 0; l < W; ++l) {
                double acc = 0.0;
                for (int n = 0; n < 6; ++n) acc += inv[(6 * m + n) * W + l] * f[n * W + l];
                s[m * W + l] = -(act[l] * acc);
            }
        }
        for (int l = 0; l < W; ++l) {
            p[l] += s[l];
            p[W + l] += s[W + l];
            p[2 * W + l] += s[2 * W + l];
            // Cayley's rotation of omega = s[3..5]: C = I + 2/(1 + |h|^2) (H + H^2), h = omega/2,
            // H = [h]x, H^2 = h h^T - |h|^2 I; exactly orthogonal, Exp(omega) to second order.
            const double hx = 0.5 * s[3 * W + l], hy = 0.5 * s[4 * W + l], hz = 0.5 * s[5 * W + l];
            const double h2 = hx * hx + hy * hy + hz * hz, k = 2.0 / (1.0 + h2);
            const double c00 = 1.0 + k * (hx * hx - h2), c01 = k * (hx * hy - hz),
                         c02 = k * (hx * hz + hy);
            const double c10 = k * (hx * hy + hz), c11 = 1.0 + k * (hy * hy - h2),
                         c12 = k * (hy * hz - hx);
            const double c20 = k * (hx * hz - hy), c21 = k * (hy * hz + hx),
                         c22 = 1.0 + k * (hz * hz - h2);
            for (int c = 0; c < 3; ++c) {
                const double r0 = r[c * W + l], r1 = r[(3 + c) * W + l], r2 = r[(6 + c) * W + l];
                r[c * W + l] = c00 * r0 + c01 * r1 + c02 * r2;
                r[(3 + c) * W + l] = c10 * r0 + c11 * r1 + c12 * r2;
                r[(6 + c) * W + l] = c20 * r0 + c21 * r1 + c22 * r2;
            }
        }
    }
}

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__)
__attribute__((target_clones("avx512f", "avx2", "default")))
#endif
void tracker_points_block(const double* __restrict qb, int nj, const char* __restrict prismatic,
                          const double* __restrict joint, const double* __restrict rt,
                          const double* __restrict tt, const double* __restrict refl, int kp,
                          const double* __restrict p, const double* __restrict r,
                          double* __restrict t, double* __restrict y) {
    constexpr int W = kTrackerLanes;
    for (int e = 0; e < 12; ++e)
        for (int l = 0; l < W; ++l) t[e * W + l] = (e % 4 == e / 4) ? 1.0 : 0.0;
    double ct[W], st[W], d[W];
    for (int i = 0; i < nj; ++i) {
        const double* jc = joint + 6 * i;
        const double ca = jc[0], sa = jc[1], ct0 = jc[2], st0 = jc[3], a = jc[4], d0 = jc[5];
        const double* q0 = qb + 2 * i * W;
        const double* q1 = q0 + W;
        if (prismatic[i]) {
            for (int l = 0; l < W; ++l) ct[l] = ct0, st[l] = st0, d[l] = d0 + q0[l];
        } else {
            for (int l = 0; l < W; ++l) {
                ct[l] = ct0 * q0[l] - st0 * q1[l];
                st[l] = st0 * q0[l] + ct0 * q1[l];
                d[l] = d0;
            }
        }
        // T <- T A_i, A_i = Rz(theta) Tz(d) Tx(a) Rx(alpha) (eq. 1), row by row.
        for (int row = 0; row < 3; ++row) {
            double* t0 = t + 4 * row * W;
            double* t1 = t0 + W;
            double* t2 = t1 + W;
            double* t3 = t2 + W;
            for (int l = 0; l < W; ++l) {
                const double u = t0[l] * ct[l] + t1[l] * st[l];
                const double v = t1[l] * ct[l] - t0[l] * st[l];
                const double w = t2[l];
                t3[l] += a * u + d[l] * w;
                t0[l] = u;
                t1[l] = ca * v + sa * w;
                t2[l] = ca * w - sa * v;
            }
        }
    }
    // y = m (P + R r_i) + o with m = R_T R4, o = R_T p4 + t_T.
    double m[9 * W], o[3 * W];
    for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) {
            for (int l = 0; l < W; ++l) {
                m[(3 * i + j) * W + l] = rt[3 * i] * t[j * W + l] + rt[3 * i + 1] * t[(4 + j) * W + l] +
                                         rt[3 * i + 2] * t[(8 + j) * W + l];
            }
        }
        for (int l = 0; l < W; ++l) {
            o[i * W + l] = rt[3 * i] * t[3 * W + l] + rt[3 * i + 1] * t[7 * W + l] +
                           rt[3 * i + 2] * t[11 * W + l] + tt[i];
        }
    }
    for (int k = 0; k < kp; ++k) {
        const double rx = refl[3 * k], ry = refl[3 * k + 1], rz = refl[3 * k + 2];
        for (int l = 0; l < W; ++l) {
            const double zx = p[l] + r[l] * rx + r[W + l] * ry + r[2 * W + l] * rz;
            const double zy = p[W + l] + r[3 * W + l] * rx + r[4 * W + l] * ry + r[5 * W + l] * rz;
            const double zz = p[2 * W + l] + r[6 * W + l] * rx + r[7 * W + l] * ry + r[8 * W + l] * rz;
            for (int c = 0; c < 3; ++c) {
                y[(3 * k + c) * W + l] = m[(3 * c) * W + l] * zx + m[(3 * c + 1) * W + l] * zy +
                                         m[(3 * c + 2) * W + l] * zz + o[c * W + l];
            }
        }
    }
}

}  // namespace detail

Mat3 rotvec_matrix(const Vec3& w) {
    const double t2 = w.squaredNorm();
    double s, c;  // sin(t)/t, (1 - cos t)/t^2
    if (t2 < 1e-8) {
        s = 1 - t2 / 6 + t2 * t2 / 120;
        c = 0.5 - t2 / 24 + t2 * t2 / 720;
    } else {
        const double t = std::sqrt(t2);
        s = std::sin(t) / t;
        c = (1 - std::cos(t)) / t2;
    }
    const Mat3 k = skew(w);
    return Mat3::Identity() + s * k + c * k * k;
}

Mat3 so3_left_jacobian(const Vec3& w) {
    const double t2 = w.squaredNorm();
    double c, d;  // (1 - cos t)/t^2, (t - sin t)/t^3
    if (t2 < 1e-8) {
        c = 0.5 - t2 / 24 + t2 * t2 / 720;
        d = 1.0 / 6 - t2 / 120 + t2 * t2 / 5040;
    } else {
        const double t = std::sqrt(t2);
        c = (1 - std::cos(t)) / t2;
        d = (t - std::sin(t)) / (t2 * t);
    }
    const Mat3 k = skew(w);
    return Mat3::Identity() + c * k + d * k * k;
}

TrackerSetup TrackerSetup::points(const Vector6d& registration, const RowMatrixXd& reflectors) {
    require_finite(registration.data(), 6, "registration");
    if (reflectors.rows() < 1 || reflectors.cols() != 3) {
        std::ostringstream msg;
        msg << "reflectors: shape (" << reflectors.rows() << ", " << reflectors.cols()
            << "); expected (K, 3) with K >= 1";
        throw std::invalid_argument(msg.str());
    }
    require_finite(reflectors.data(), reflectors.size(), "reflectors");
    TrackerSetup s;
    s.kind_ = TrackerKind::Points;
    s.registration_ = registration;
    s.reflectors_ = reflectors;
    s.reg_rot_ = euler_zyx(registration(3), registration(4), registration(5));
    return s;
}

TrackerSetup TrackerSetup::probe(const Vector6d& registration, const Vector6d& probe,
                                 double length) {
    require_finite(registration.data(), 6, "registration");
    require_finite(probe.data(), 6, "probe");
    if (!(std::isfinite(length) && length > 0))
        throw std::invalid_argument("probe_length: " + std::to_string(length) +
                                    "; expected a finite length > 0 (mm)");
    TrackerSetup s;
    s.kind_ = TrackerKind::Probe;
    s.registration_ = registration;
    s.probe_ = probe;
    s.probe_length_ = length;
    s.reg_rot_ = euler_zyx(registration(3), registration(4), registration(5));
    s.probe_rot_ = euler_zyx(probe(3), probe(4), probe(5));
    return s;
}

void TrackerSetup::registration_transform(const double* xt, Mat3& rot, Vec3& trans) const {
    const Vec3 t(xt[0], xt[1], xt[2]), w(xt[3], xt[4], xt[5]);
    rot = reg_rot_ * rotvec_matrix(w);
    trans = reg_rot_ * t + registration_.head<3>();
}

void TrackerSetup::platform_points(const double* xo, Vec3* r, RowMatrixXd* jac) const {
    const int k = n_points(), no = n_offset_params();
    if (jac) jac->setZero(3 * k, no);
    if (kind_ == TrackerKind::Points) {
        for (int i = 0; i < k; ++i) {
            r[i] = reflectors_.row(i).transpose() + Vec3(xo[3 * i], xo[3 * i + 1], xo[3 * i + 2]);
            if (jac) jac->block<3, 3>(3 * i, 3 * i).setIdentity();
        }
        return;
    }
    const Vec3 t = probe_.head<3>() + Vec3(xo[0], xo[1], xo[2]);
    const Vec3 w(xo[3], xo[4], xo[5]);
    const Mat3 rp = rotvec_matrix(w) * probe_rot_;
    const Mat3 jl = jac ? so3_left_jacobian(w) : Mat3::Identity();
    r[0] = t;
    if (jac) jac->block<3, 3>(0, 0).setIdentity();
    for (int c = 0; c < 3; ++c) {
        const Vec3 arm = probe_length_ * rp.col(c);
        r[c + 1] = t + arm;
        if (jac) {
            jac->block<3, 3>(3 * (c + 1), 0).setIdentity();
            jac->block<3, 3>(3 * (c + 1), 3) = -skew(arm) * jl;
        }
    }
}

TrackerObjective::TrackerObjective(Geometry geometry, TrackerSetup setup, const RowMatrixXd& q,
                                   const RowMatrixXd& legs, const RowMatrixXd& points,
                                   const VectorXd& reference, const Vector6d& home,
                                   double tolerance)
    : geometry_(std::move(geometry)),
      setup_(std::move(setup)),
      n_(static_cast<int>(legs.rows())),
      tolerance_(tolerance),
      q_(q),
      legs_(legs),
      points_(points) {
    const int nj = geometry_.n_joints(), k = setup_.n_points();
    if (n_ == 0) throw std::invalid_argument("legs: no measurements (0 rows)");
    require_rows(legs, n_, kLegs, "legs");
    require_rows(q, n_, nj, "q");
    require_rows(points, n_, 3 * k, "points");
    require_finite(q.data(), q.size(), "q");
    require_finite(legs.data(), legs.size(), "legs");
    if (!(std::isfinite(tolerance) && tolerance > 0))
        throw std::invalid_argument("tolerance: " + std::to_string(tolerance) +
                                    "; expected a finite number > 0 (mm)");
    geometry_.check_errors(reference.data(), reference.size(), "reference");
    require_finite(home.data(), 6, "home");
    for (int p = 0; p < n_; ++p) {
        for (int i = 0; i < k; ++i) {
            const int nan = std::isnan(points(p, 3 * i)) + std::isnan(points(p, 3 * i + 1)) +
                            std::isnan(points(p, 3 * i + 2));
            bool finite = true;
            for (int c = 0; c < 3; ++c) finite = finite && !std::isinf(points(p, 3 * i + c));
            if ((nan != 0 && nan != 3) || !finite) {
                std::ostringstream msg;
                msg << "points: pose " << p << ", point " << i + 1
                    << " has a non-finite coordinate; a point not seen has all three NaN";
                throw std::invalid_argument(msg.str());
            }
            if (nan == 0) ++n_seen_;
        }
    }
    cq_.resize(n_, nj);
    sq_.resize(n_, nj);
    for (int p = 0; p < n_; ++p)
        for (int i = 0; i < nj; ++i) cq_(p, i) = std::cos(q(p, i)), sq_(p, i) = std::sin(q(p, i));

    // The reference solves: damped Newton from the home pose, once.
    VectorXd xref(n_params());
    xref.setZero();
    xref.head(geometry_.n_params()) = reference;
    const Hexapod h = hexapod(xref.data());
    ForwardOptions opt;
    opt.tolerance = tolerance_;
    ref_euler_.resize(static_cast<size_t>(n_));
    const int n_blocks = (n_ + kLanes - 1) / kLanes;
    stride_ = (kChordQuantities + 2 * nj) * kLanes;
    blocks_.assign(static_cast<size_t>(n_blocks) * static_cast<size_t>(stride_), 0.0);
    for (int i = 0; i < nj; ++i) prismatic_.push_back(geometry_.is_prismatic(i) ? 1 : 0);
    for (int kk = 0; kk < n_blocks * kLanes; ++kk) {
        const int p = std::min(kk, n_ - 1);
        const size_t s = static_cast<size_t>(p);
        if (kk < n_) {
            const LegVector len = legs_.row(p).transpose() + h.l0;
            ref_euler_[s] = hexapod_forward(h.a, h.b, len, home, opt, p).pose;
        }
        const Vec3 pr = ref_euler_[s].head<3>();
        const Mat3 rr = euler_zyx(ref_euler_[s](3), ref_euler_[s](4), ref_euler_[s](5));
        const Matrix6d inv = leg_jacobian(h.a, h.b, pr, rr).inverse();
        double* blk = blocks_.data() + static_cast<size_t>(kk / kLanes) * static_cast<size_t>(stride_);
        auto put = [&](int e, double v) { blk[e * kLanes + kk % kLanes] = v; };
        for (int e = 0; e < 36; ++e) put(e, inv(e / 6, e % 6));
        for (int e = 0; e < 3; ++e) put(36 + e, pr(e));
        for (int e = 0; e < 9; ++e) put(39 + e, rr(e / 3, e % 3));
        for (int e = 0; e < 6; ++e) put(48 + e, legs_(p, e));
        for (int i = 0; i < nj; ++i) {  // q (and 0) for a prismatic joint, cos q and sin q else
            put(kChordQuantities + 2 * i, geometry_.is_prismatic(i) ? q(p, i) : cq_(p, i));
            put(kChordQuantities + 2 * i + 1, geometry_.is_prismatic(i) ? 0.0 : sq_(p, i));
        }
    }
}

TrackerObjective::Hexapod TrackerObjective::hexapod(const double* x) const {
    const Geometry& g = geometry_;
    Hexapod h;
    for (int j = 0; j < kLegs; ++j) {
        for (int c = 0; c < 3; ++c) {
            h.a(j, c) = g.base()(j, c) + x[g.idx_base(j, c)];
            h.b(j, c) = g.platform()(j, c) + x[g.idx_platform(j, c)];
        }
        h.l0(j) = g.leg_offsets()(j) + x[g.idx_offset(j)];
    }
    return h;
}

TrackerObjective::Workspace TrackerObjective::make_workspace() const {
    Workspace ws;
    ws.joint.resize(static_cast<size_t>(6 * geometry_.n_joints()));
    ws.r.resize(static_cast<size_t>(setup_.n_points()));
    ws.refl.resize(static_cast<size_t>(3 * setup_.n_points()));
    ws.y.resize(static_cast<size_t>(3 * setup_.n_points() * kLanes));
    return ws;
}

void TrackerObjective::prepare(const double* x, Workspace& ws, Mat3& rt, Vec3& tt) const {
    const Geometry& g = geometry_;
    for (int i = 0; i < g.n_joints(); ++i) {
        double* jc = ws.joint.data() + 6 * i;
        const double alpha = g.dh()(i, 0) + x[4 * i], theta = g.dh()(i, 3) + x[4 * i + 3];
        jc[0] = std::cos(alpha), jc[1] = std::sin(alpha);
        jc[2] = std::cos(theta), jc[3] = std::sin(theta);
        jc[4] = g.dh()(i, 1) + x[4 * i + 1];
        jc[5] = g.dh()(i, 2) + x[4 * i + 2];
    }
    setup_.registration_transform(x + g.n_params(), rt, tt);
    setup_.platform_points(x + g.n_params() + 6, ws.r.data());
}

void TrackerObjective::chord(const Hexapod& h, int block, double* pp, double* rr,
                             int* status) const {
    static_assert(kLanes == detail::kTrackerLanes, "one block width");
    double a[18], b[18], l0[6];
    for (int j = 0; j < kLegs; ++j) {
        for (int c = 0; c < 3; ++c) a[3 * j + c] = h.a(j, c), b[3 * j + c] = h.b(j, c);
        l0[j] = h.l0(j);
    }
    detail::tracker_chord_block(blocks_.data() + static_cast<size_t>(block) * static_cast<size_t>(stride_),
                                a, b, l0, tolerance_, kMaxChord, pp, rr, status);
}

void TrackerObjective::solve_block(const Hexapod& h, int block, Vec3* p, Mat3* r,
                                   int* status) const {
    constexpr int W = kLanes;
    double pp[3 * W], rr[9 * W];
    chord(h, block, pp, rr, status);
    for (int l = 0; l < W; ++l) {
        p[l] = Vec3(pp[l], pp[W + l], pp[2 * W + l]);
        for (int e = 0; e < 9; ++e) r[l](e / 3, e % 3) = rr[e * W + l];
    }
}

void TrackerObjective::finish(const Hexapod& h, int k, int status, Vec3& p, Mat3& r) const {
    if (status == 0) return;
    const LegVector len = legs_.row(k).transpose() + h.l0;
    if (status == 2) {
        for (int j = 0; j < kLegs; ++j) {
            if (!(len(j) > 0)) {
                std::ostringstream msg;
                msg << "forward kinematics: pose " << k << ": leg " << j + 1 << " has length "
                    << len(j) << " mm (reading + offset + error); a leg length must be > 0";
                throw ForwardKinematicsError(msg.str(), k);
            }
        }
    }
    ForwardOptions opt;
    opt.tolerance = tolerance_;
    const HexapodSolution sol =
        hexapod_forward(h.a, h.b, len, ref_euler_[static_cast<size_t>(k)], opt, k);
    p = sol.pose.head<3>();
    r = euler_zyx(sol.pose(3), sol.pose(4), sol.pose(5));
}

void TrackerObjective::solve(const Hexapod& h, int k, Vec3& p, Mat3& r) const {
    Vec3 pb[kLanes];
    Mat3 rb[kLanes];
    int status[kLanes];
    solve_block(h, k / kLanes, pb, rb, status);
    p = pb[k % kLanes];
    r = rb[k % kLanes];
    finish(h, k, status[k % kLanes], p, r);
}

double TrackerObjective::evaluate(const double* x, Workspace& ws, double* res,
                                  std::vector<int>* failed, RowMatrixXd* poses,
                                  RowMatrixXd* predicted) const {
    constexpr int W = kLanes;
    Mat3 rt_m;
    Vec3 tt;
    prepare(x, ws, rt_m, tt);
    double rt[9];
    for (int e = 0; e < 9; ++e) rt[e] = rt_m(e / 3, e % 3);
    const int kp = setup_.n_points();
    double* refl = ws.refl.data();
    double* y = ws.y.data();
    for (int i = 0; i < kp; ++i)
        for (int c = 0; c < 3; ++c) refl[3 * i + c] = ws.r[static_cast<size_t>(i)](c);
    const Hexapod h = hexapod(x);
    double pp[3 * W], rr[9 * W], t[12 * W];
    int status[W];
    bool bad[W];
    double cost = 0;
    for (int blk = 0; blk * W < n_; ++blk) {
        chord(h, blk, pp, rr, status);
        for (int l = 0; l < W; ++l) {
            const int k = blk * W + l;
            bad[l] = false;
            if (status[l] == 0 || k >= n_) continue;
            Vec3 p;
            Mat3 r;
            try {
                finish(h, k, status[l], p, r);
                for (int c = 0; c < 3; ++c) pp[c * W + l] = p(c);
                for (int e = 0; e < 9; ++e) rr[e * W + l] = r(e / 3, e % 3);
            } catch (const ForwardKinematicsError&) {
                bad[l] = true;
            }
        }
        detail::tracker_points_block(
            blocks_.data() + static_cast<size_t>(blk) * static_cast<size_t>(stride_) +
                kChordQuantities * W,
            geometry_.n_joints(), prismatic_.data(), ws.joint.data(), rt, tt.data(), refl, kp, pp,
            rr, t, y);
        for (int l = 0; l < W && blk * W + l < n_; ++l) {
            const int k = blk * W + l;
            if (bad[l]) {
                if (failed) failed->push_back(k);
                if (poses) poses->row(k).setConstant(std::numeric_limits<double>::quiet_NaN());
                if (predicted)
                    predicted->row(k).setConstant(std::numeric_limits<double>::quiet_NaN());
            } else {
                if (poses) {
                    Mat3 r4, r;
                    Vec3 p4, p;
                    for (int e = 0; e < 9; ++e) {
                        r4(e / 3, e % 3) = t[(4 * (e / 3) + e % 3) * W + l];
                        r(e / 3, e % 3) = rr[e * W + l];
                    }
                    for (int c = 0; c < 3; ++c) p4(c) = t[(4 * c + 3) * W + l], p(c) = pp[c * W + l];
                    poses->block<1, 3>(k, 0) = (p4 + r4 * p).transpose();
                    poses->block<1, 3>(k, 3) = euler_from_matrix(r4 * r).transpose();
                }
                if (predicted)
                    for (int e = 0; e < 3 * kp; ++e) (*predicted)(k, e) = y[e * W + l];
            }
            for (int i = 0; i < kp; ++i) {
                const bool seen = !std::isnan(points_(k, 3 * i));
                for (int c = 0; c < 3; ++c) {
                    const double v = !seen ? 0.0
                                     : bad[l] ? kFailedResidual
                                              : y[(3 * i + c) * W + l] - points_(k, 3 * i + c);
                    if (res) res[3 * (kp * k + i) + c] = v;
                    cost += v * v;
                }
            }
        }
    }
    return cost;
}

void TrackerObjective::check_x(const Eigen::Ref<const VectorXd>& x) const {
    if (x.size() != n_params()) {
        std::ostringstream msg;
        msg << "x: " << x.size() << " values given but this problem has " << n_params()
            << " parameters (" << geometry_.n_params() << " of the robot, "
            << setup_.n_params() << " of the tracker setup)";
        throw std::invalid_argument(msg.str());
    }
    require_finite(x.data(), x.size(), "x");
}

double TrackerObjective::cost(const double* x, Workspace& ws) const {
    return evaluate(x, ws, nullptr, nullptr, nullptr, nullptr);
}

double TrackerObjective::cost(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    Workspace ws = make_workspace();
    return cost(x.data(), ws);
}

VectorXd TrackerObjective::residuals(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    VectorXd r(n_residuals());
    Workspace ws = make_workspace();
    evaluate(x.data(), ws, r.data(), nullptr, nullptr, nullptr);
    return r;
}

std::vector<std::pair<int, std::string>> TrackerObjective::failures(
    const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    const Hexapod h = hexapod(x.data());
    std::vector<std::pair<int, std::string>> out;
    for (int k = 0; k < n_; ++k) {
        Vec3 p;
        Mat3 r;
        try {
            solve(h, k, p, r);
        } catch (const ForwardKinematicsError& e) {
            out.emplace_back(k, e.what());
        }
    }
    return out;
}

RowMatrixXd TrackerObjective::platform_poses(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    RowMatrixXd poses(n_, 6);
    Workspace ws = make_workspace();
    evaluate(x.data(), ws, nullptr, nullptr, &poses, nullptr);
    return poses;
}

RowMatrixXd TrackerObjective::predicted_points(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    RowMatrixXd pred(n_, 3 * setup_.n_points());
    Workspace ws = make_workspace();
    evaluate(x.data(), ws, nullptr, nullptr, nullptr, &pred);
    return pred;
}

void TrackerObjective::jacobian(const Eigen::Ref<const VectorXd>& x, VectorXd* residuals,
                                RowMatrixXd* jac) const {
    check_x(x);
    const Geometry& g = geometry_;
    const int nj = g.n_joints(), nr = g.n_params(), kp = setup_.n_points();
    const int no = setup_.n_offset_params();
    Workspace ws = make_workspace();
    std::vector<int> failed;
    VectorXd res(n_residuals());
    evaluate(x.data(), ws, res.data(), &failed, nullptr, nullptr);
    if (residuals) *residuals = res;
    if (!jac) return;
    jac->setZero(n_residuals(), n_params());

    const Hexapod h = hexapod(x.data());
    const double* xt = x.data() + nr;
    Mat3 rt;
    Vec3 tt;
    setup_.registration_transform(xt, rt, tt);
    const Mat3 rnom = euler_zyx(setup_.registration()(3), setup_.registration()(4),
                                setup_.registration()(5));
    const Vec3 wc(xt[3], xt[4], xt[5]);
    const Mat3 rc = rotvec_matrix(wc), jl = so3_left_jacobian(wc);
    RowMatrixXd djo;  // d r_i / d offsets
    setup_.platform_points(xt + 6, ws.r.data(), &djo);
    std::vector<Mat4> frames(static_cast<size_t>(nj) + 1);
    size_t next_failed = 0;
    for (int k = 0; k < n_; ++k) {
        if (next_failed < failed.size() && failed[next_failed] == k) {
            ++next_failed;
            continue;  // zero rows: the penalty does not depend on x
        }
        Vec3 p;
        Mat3 r;
        solve(h, k, p, r);
        const Mat4 t4 = carriage_transform(g, x.data(), q_.row(k).data(), frames.data());
        const Mat3 r4 = t4.topLeftCorner<3, 3>();
        const Vec3 p4 = t4.topRightCorner<3, 1>();
        // Implicit differentiation of the leg-length equations g(P, R, x) = 0:
        // d(P, omega)/dx_h = -Jh^-1 dg/dx_h, over the 42 hexapod parameters (a, b, l0).
        const Matrix6d jh = leg_jacobian(h.a, h.b, p, r);
        Eigen::Matrix<double, 6, kHexapodParams> gx;
        gx.setZero();
        for (int j = 0; j < kLegs; ++j) {
            const Vec3 v = p + r * h.b.row(j).transpose() - h.a.row(j).transpose();
            const Vec3 u = v.normalized();
            const Vec3 ub = r.transpose() * u;
            for (int c = 0; c < 3; ++c) {
                gx(j, 3 * j + c) = -u(c);        // a_j
                gx(j, 18 + 3 * j + c) = ub(c);  // b_j
            }
            gx(j, 36 + j) = -1.0;  // l0_j
        }
        const Eigen::Matrix<double, 6, kHexapodParams> dpose = -(jh.partialPivLu().solve(gx));
        const Mat3 m = rt * r4;
        for (int i = 0; i < kp; ++i) {
            if (std::isnan(points_(k, 3 * i))) continue;
            const Vec3 ri = r * ws.r[static_cast<size_t>(i)];  // R r_i
            const Vec3 z = p + ri;                             // point in {4}
            const Vec3 w = p4 + r4 * z;                        // point in {0}
            auto rows = jac->middleRows(3 * (kp * k + i), 3);
            // Hexapod: dz = dP + omega x (R r_i) = [I, -[R r_i]x] d(P, omega).
            Eigen::Matrix<double, 3, 6> dz;
            dz.leftCols<3>().setIdentity();
            dz.rightCols<3>() = -skew(ri);
            rows.middleCols(g.idx_base(0, 0), kHexapodParams) = m * dz * dpose;
            // Carriage: theta and d act about/along z_{i-1} through o_{i-1}; alpha and a
            // about/along x_i through o_i (as in the leg objective).
            for (int jn = 0; jn < nj; ++jn) {
                const Vec3 z_prev = frames[static_cast<size_t>(jn)].block<3, 1>(0, 2);
                const Vec3 o_prev = frames[static_cast<size_t>(jn)].block<3, 1>(0, 3);
                const Vec3 x_i = frames[static_cast<size_t>(jn) + 1].block<3, 1>(0, 0);
                const Vec3 o_i = frames[static_cast<size_t>(jn) + 1].block<3, 1>(0, 3);
                rows.col(4 * jn + 0) = rt * x_i.cross(w - o_i);
                rows.col(4 * jn + 1) = rt * x_i;
                rows.col(4 * jn + 2) = rt * z_prev;
                rows.col(4 * jn + 3) = rt * z_prev.cross(w - o_prev);
            }
            // Registration: y = R_nom (Exp(wc) w + t) + t_nom.
            rows.middleCols(nr, 3) = rnom;
            rows.middleCols(nr + 3, 3) = -rnom * skew(rc * w) * jl;
            // Offsets: y = m (P + R r_i(x_o)) + ...
            rows.middleCols(nr + 6, no) = m * r * djo.middleRows(3 * i, 3);
        }
    }
}

void TrackerObjective::cost_batch(const double* X, Eigen::Index m, double* out,
                                  ThreadPool& pool) const {
    batch_costs(*this, X, static_cast<std::size_t>(m), out, pool);
}

}  // namespace iwr
