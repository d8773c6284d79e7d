#include "iwr/tracker.hpp"

#include "inline.hpp"
#include "objective_kernel.hpp"

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

// B = [b_i, b_k, b_i x b_k] of the kernel's pair (i, k) of platform joints (TrackerConsts::binv
// its inverse): the kernels give a platform rotation R as F = R B (TrackerKernels).
Mat3 joint_frame(const detail::TrackerConsts& tc) {
    const Vec3 bi(tc.ec.b[tc.pair[0]][0], tc.ec.b[tc.pair[0]][1], tc.ec.b[tc.pair[0]][2]);
    const Vec3 bk(tc.ec.b[tc.pair[1]][0], tc.ec.b[tc.pair[1]][1], tc.ec.b[tc.pair[1]][2]);
    Mat3 bm;
    bm << bi, bk, bi.cross(bk);
    return bm;
}

// R = F B^-1 of lane l of a block's F (9 x W, row-major).
Mat3 rotation_of(const double* f, int l, const detail::TrackerConsts& tc) {
    Mat3 fm;
    for (int e = 0; e < 9; ++e) fm(e / 3, e % 3) = f[e * detail::kBlock + l];
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> binv(tc.binv);
    return fm * binv;
}

// Steps of the kernel's forward kinematics (tracker_kernel_body.inl: chord steps with the
// reference's inverse Jacobian, refined while the residual is large) before falling back to the
// damped Newton-Raphson of hexapod_forward. Three steps reach 1e-10 mm from the reference across
// DE's search box.
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

// A vector's cost from its 8 lanes' sums (evaluate, cost_rows), in a fixed order: the same bits
// whatever the thread, the instruction set or the path that summed the lanes.
double lane_sum(const double* acc) {
    static_assert(detail::kBlock == 8, "eight lanes");
    return ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
}

}  // namespace

// sin(t)/t, (1 - cos t)/t^2 and (t - sin t)/t^3 at t^2 = t2 (SO(3)'s exponential and its left
// Jacobian). Below t = 0.1 (a registration's or a probe's correction within the default bounds:
// |r| < 0.061) their Taylor series to t^8: the first term left out is at most t^10 / 11! < 2.6e-18,
// a tenth of an ulp of the smallest (1/6), and no libm call. Within 0.52, 0.50 and 0.83 ulp of
// the exact values there (mpmath, 22,000 t), where libm's (1 - cos t) / t^2 in doubles cancels to
// 1e-8 relative at t = 1e-4 (which put so3_left_jacobian 4e-13 off).
void detail::so3_coefficients(double t2, double& s, double& c, double& d) {
    if (t2 < 1e-2) {
        s = 1 + t2 * (-1.0 / 6 + t2 * (1.0 / 120 + t2 * (-1.0 / 5040 + t2 * (1.0 / 362880))));
        c = 0.5 + t2 * (-1.0 / 24 + t2 * (1.0 / 720 + t2 * (-1.0 / 40320 + t2 * (1.0 / 3628800))));
        d = 1.0 / 6 + t2 * (-1.0 / 120 + t2 * (1.0 / 5040 + t2 * (-1.0 / 362880 +
                                                               t2 * (1.0 / 39916800))));
    } else {
        const double t = std::sqrt(t2), sn = std::sin(t);
        s = sn / t;
        c = (1 - std::cos(t)) / t2;
        d = (t - sn) / (t2 * t);
    }
}

Mat3 rotvec_matrix(const Vec3& w) {
    const double x = w(0), y = w(1), z = w(2), xx = x * x, yy = y * y, zz = z * z;
    double s, c, d;  // sin(t)/t, (1 - cos t)/t^2 (d unused)
    detail::so3_coefficients(xx + yy + zz, s, c, d);
    // I + s K + c K^2 with K = [w]x, K^2 = w w^T - |w|^2 I, written out.
    const double cxy = c * (x * y), cxz = c * (x * z), cyz = c * (y * z);
    const double sx = s * x, sy = s * y, sz = s * z;
    Mat3 r;
    r << 1 - c * (yy + zz), cxy - sz, cxz + sy,
         cxy + sz, 1 - c * (xx + zz), cyz - sx,
         cxz - sy, cyz + sx, 1 - c * (xx + yy);
    return r;
}

Mat3 so3_left_jacobian(const Vec3& w) {
    double s, c, d;  // (1 - cos t)/t^2, (t - sin t)/t^3 (s unused)
    detail::so3_coefficients(w.squaredNorm(), s, c, d);
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
    n_seen_ = detail::seen_points(points, k);
    cq_.resize(n_, nj);
    sq_.resize(n_, nj);
    for (int p = 0; p < n_; ++p)
        for (int i = 0; i < nj; ++i) cq_(p, i) = std::cos(q(p, i)), sq_(p, i) = std::sin(q(p, i));

    // The reference solves: damped Newton from the home pose, once.
    VectorXd xref(n_params());
    xref.setZero();
    xref.head(geometry_.n_params()) = reference;
    // The two platform joints whose cross product is largest: the kernel's forward kinematics
    // recovers the platform's rotation from them.
    double best = -1;
    for (int i = 0; i < kLegs; ++i) {
        for (int j = i + 1; j < kLegs; ++j) {
            const double c = geometry_.platform().row(i).cross(geometry_.platform().row(j)).norm();
            if (c > best) best = c, pair_[0] = i, pair_[1] = j;
        }
    }
    if (!(best > 1e-6 * geometry_.platform().squaredNorm()))
        throw std::invalid_argument("platform joints: all on one line through the origin of {5}; "
                                    "the forward kinematics needs two that span a plane with it");
    const Hexapod h = hexapod(xref.data());
    ForwardOptions opt;
    opt.tolerance = tolerance_;
    ref_euler_.resize(static_cast<size_t>(n_));
    const int n_blocks = (n_ + kLanes - 1) / kLanes;
    stride_ = (kChordQuantities + 2 * nj + 4 * k) * kLanes;
    blocks_.assign(static_cast<size_t>(n_blocks) * static_cast<size_t>(stride_), 0.0);
    for (int i = 0; i < nj; ++i) {
        prismatic_.push_back(geometry_.is_prismatic(i) ? 1 : 0);
        q_off_.push_back(kChordQuantities + 2 * i);
    }
    carriage_ = detail::CarriageNominal(geometry_);
    // A padding lane (kk >= n_) copies a pose of its block: when the last block is at most half
    // full, lane l copies lane l mod kLanes / 2 (the last pose if that is padding too), so that its
    // lanes kLanes / 2.. repeat its first half (cost_rows solves two vectors' last poses in one
    // such block); else the last pose.
    const int last_first = (n_blocks - 1) * kLanes;
    const bool half_full = last_block_half_full();
    for (int kk = 0; kk < n_blocks * kLanes; ++kk) {
        const int p = kk < n_ ? kk
                      : half_full ? std::min(last_first + kk % (kLanes / 2), n_ - 1)
                                  : n_ - 1;
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
        for (int e = 0; e < 6; ++e) put(54 + e, 0.5 / (legs_(p, e) + h.l0(e)));
        for (int i = 0; i < nj; ++i) {  // q (and 0) for a prismatic joint, cos q and sin q else
            put(kChordQuantities + 2 * i, geometry_.is_prismatic(i) ? q(p, i) : cq_(p, i));
            put(kChordQuantities + 2 * i + 1, geometry_.is_prismatic(i) ? 0.0 : sq_(p, i));
        }
        // The measured points (0 where not seen) and 1 or 0 for seen; a padding lane sees nothing.
        const int e0 = kChordQuantities + 2 * nj;
        if (kk % kLanes == 0) all_seen_.push_back(1);
        for (int i = 0; i < k; ++i) {
            const bool seen = kk < n_ && !std::isnan(points(p, 3 * i));
            for (int c = 0; c < 3; ++c) put(e0 + 3 * i + c, seen ? points(p, 3 * i + c) : 0.0);
            put(e0 + 3 * k + i, seen ? 1.0 : 0.0);
            if (!seen) all_seen_.back() = 0;
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
    for (auto& sl : ws.slot) {
        sl.jbuf.assign(static_cast<size_t>(15 * geometry_.n_joints() + 1), 0.0);
        sl.r.resize(static_cast<size_t>(setup_.n_points()));
        sl.refl.resize(static_cast<size_t>(3 * setup_.n_points()));
    }
    ws.y.resize(static_cast<size_t>(3 * setup_.n_points() * kLanes));
    ws.v.resize(static_cast<size_t>(3 * setup_.n_points() * kLanes));
    return ws;
}

void TrackerObjective::fk_consts(detail::TrackerConsts& tc) const {
    // The rotation from the platform joints (tracker_chord): B^-1 with B = [b_i, b_k, b_i x b_k].
    tc.pair[0] = pair_[0], tc.pair[1] = pair_[1];
    const Mat3 binv = joint_frame(tc).inverse();
    for (int e = 0; e < 9; ++e) tc.binv[e] = binv(e / 3, e % 3);
    tc.tol = tolerance_;
    tc.max_iter = kMaxChord;
}

void TrackerObjective::prepare(const double* x, Workspace& ws, detail::TrackerConsts& tc,
                               int slot) const {
    const Geometry& g = geometry_;
    Workspace::Slot& sl = ws.slot[slot];
    carriage_.consts(g, x, tc.ec, sl.jbuf.data());
    fk_consts(tc);
    tc.pd.n_joints = g.n_joints();
    tc.pd.n_prefix = carriage_.n_prefix();
    tc.pd.q_off = q_off_.data();
    tc.pd.prismatic = prismatic_.data();
    Mat3 rt;
    Vec3 tt;
    setup_.registration_transform(x + g.n_params(), rt, tt);
    setup_.platform_points(x + g.n_params() + 6, sl.r.data());
    for (int e = 0; e < 9; ++e) tc.rt[e] = rt(e / 3, e % 3);
    for (int c = 0; c < 3; ++c) tc.tt[c] = tt(c);
    // The registration folded into the carriage: the kernel's chain starts from T_T0 and ends at
    // T_T4. ec.z points into the slot's jbuf (one direction per prismatic prefix joint).
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> rc(tc.ec.rc);
    Eigen::Map<Vec3> pc(tc.ec.pc);
    rc = (rt * rc).eval();
    pc = rt * pc + tt;
    for (int i = 0; i < tc.pd.n_prefix; ++i) {
        Eigen::Map<Vec3> z(sl.jbuf.data() + 3 * i);
        z = (rt * z).eval();
    }
    // The points in the joints' frame: c_i = B^-1 r_i (the kernel's R r_i is F c_i).
    tc.n_points = setup_.n_points();
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> binv(tc.binv);
    for (int i = 0; i < tc.n_points; ++i)
        Eigen::Map<Vec3>(sl.refl.data() + 3 * i) = binv * sl.r[static_cast<size_t>(i)];
    tc.refl = sl.refl.data();
    tc.failed_residual = kFailedResidual;
    tc.wh_rows = wh_rows_.data();
    tc.wh_first = wh_first_;
}

void TrackerObjective::solve_block(const Hexapod& h, int block, Vec3* p, Mat3* r,
                                   int* status) const {
    constexpr int W = kLanes;
    static_assert(kLanes == detail::kBlock, "one block width");
    detail::TrackerConsts tc;
    for (int j = 0; j < kLegs; ++j) {
        for (int c = 0; c < 3; ++c) tc.ec.a[j][c] = h.a(j, c), tc.ec.b[j][c] = h.b(j, c);
        tc.ec.l0[j] = h.l0(j);
    }
    fk_consts(tc);
    alignas(64) double pp[3 * W], ff[9 * W];
    detail::active_tracker_kernels().chord(block_data(block), tc, pp, ff, status);
    for (int l = 0; l < W; ++l) {
        p[l] = Vec3(pp[l], pp[W + l], pp[2 * W + l]);
        r[l] = rotation_of(ff, l, tc);
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
    detail::TrackerConsts tc;
    prepare(x, ws, tc);
    return evaluate(x, tc, detail::active_tracker_kernels(), ws, res, failed, poses, predicted);
}

void TrackerObjective::cost_rows(const double* const* xs, int m, double* out,
                                 Workspace& ws) const {
    constexpr int W = kLanes;
    const detail::TrackerKernels kernel = detail::active_tracker_kernels();
    const int nb = (n_ + W - 1) / W;
    // The vectors go in groups of up to kMaxGroup; every block (or pair of blocks, where the
    // variant solves pairs) is run for the whole group, vector after vector (below). The last
    // block is solved alone unless it is the second of a pair (evaluate). The group's such blocks
    // are solved together: two vectors in a block when it is at most half full (its lanes W / 2..
    // repeat its first half: the constructor's padding), and two blocks in a call where the
    // variant solves pairs.
    const bool alone = !kernel.chord2 || nb % 2 == 1;
    const int share = alone && last_block_half_full() ? 2 : 1, part = W / share;
    static_assert(kMaxGroup >= 4, "two vectors to a block, two blocks to a call");
    const double* data = block_data(nb - 1);
    const double* const blk[2] = {data, data};
    int i = 0;
    while (i < m) {
        const int group = std::min(kMaxGroup, m - i) / share * share;  // whole blocks only
        if (group <= 1) {
            out[i] = evaluate(xs[i], ws, nullptr, nullptr, nullptr, nullptr);
            ++i;
            continue;
        }
        detail::TrackerConsts tc[kMaxGroup];
        for (int g = 0; g < group; ++g) prepare(xs[i + g], ws, tc[g], g);
        alignas(64) double pp[2 * 3 * W], ff[2 * 9 * W];
        int st[2 * W];
        alignas(64) double lp[kMaxGroup][3 * W], lf[kMaxGroup][9 * W];
        int ls[kMaxGroup][W];
        // The group's last blocks, two (of `share` vectors each) a call. Each vector's: lanes of
        // the call's block (g - g0) / share, from lane (g % share) part, copied (the other
        // blocks' chords below reuse pp, ff and st; block_points may write a padding lane's
        // pose). With two vectors to a block they move to lanes 0..part, and its lanes part..
        // (padding: they see no point, so their pose does not matter) take the block's reference
        // P and R for P and F.
        for (int g0 = 0; alone && g0 < group; g0 += 2 * share) {
            const int calls = std::min(2 * share, group - g0) / share;
            detail::LaneConsts lc[2];
            for (int g = g0; g < g0 + calls * share; ++g)
                lc[(g - g0) / share].set(tc[g], (g % share) * part, (g % share + 1) * part);
            kernel.chord_lanes(blk, lc, calls, tc[g0], pp, ff, st);
            for (int g = g0; g < g0 + calls * share; ++g) {
                const int b = (g - g0) / share, o = (g % share) * part;
                for (int q = 0; q < 12; ++q) {
                    double* to = q < 3 ? lp[g] + q * W : lf[g] + (q - 3) * W;
                    const double* from = q < 3 ? pp + 3 * W * b + q * W : ff + 9 * W * b + (q - 3) * W;
                    for (int l = 0; l < W; ++l)
                        to[l] = l < part ? from[o + l] : data[(36 + q) * W + l];
                }
                for (int l = 0; l < W; ++l) ls[g][l] = l < part ? st[W * b + o + l] : 0;
            }
        }
        Hexapod h[kMaxGroup];
        bool have_h[kMaxGroup] = {};
        alignas(64) double acc[kMaxGroup][W] = {}, bad[W];
        if (!kernel.chord2) {
            // The other blocks one at a time, vector after vector: a block's data (its poses,
            // the measurements, the whitening: 8.3 KB with 3 reflectors) read by the whole group
            // while it is in L1, instead of each vector streaming every block's (108 KB at
            // N = 100, beyond a Zen 3's 32 KB L1). On a Zen 3 (BENCHMARKS.md, twenty-seventh
            // round), medians over 12 arrangements of the code, two runs: AVX2 tracker 2-3 %
            // faster, weighted 5-6 % (groups of 4: 2.5 % and 4 %); the baseline about 1 %.
            // (Groups of 2 ran AVX2 0.5-0.8 % slower on a Zen 5, twentieth round.) Each vector's
            // blocks in evaluate's order: the same sums.
            for (int b = 0; b + 1 < nb; ++b)
                for (int g = 0; g < group; ++g) {
                    kernel.chord(block_data(b), tc[g], pp, ff, st);
                    block_points(xs[i + g], tc[g], kernel, ws, b, pp, ff, st, h[g], have_h[g],
                                 bad, nullptr, nullptr, acc[g]);
                }
        } else {
            // The other blocks a pair at a time (all of them when there is no last block alone),
            // vector after vector: each pair's data (its poses, the whitening) read by every
            // vector of the group while it is in the cache (groups of 4 against none: AVX-512
            // 2-3 % faster, weighted or not; of 8 against 4 on a Zen 5, 1 %: BENCHMARKS.md,
            // twenty-ninth round). Each vector's blocks in the same order as evaluate's, so the
            // same sums.
            for (int b = 0; b + 1 < nb; b += 2) {
                for (int g = 0; g < group; ++g) {
                    kernel.chord2(block_data(b), block_data(b + 1), tc[g], pp, ff, st);
                    for (int k = 0; k < 2; ++k)
                        block_points(xs[i + g], tc[g], kernel, ws, b + k, pp + 3 * W * k,
                                     ff + 9 * W * k, st + W * k, h[g], have_h[g], bad, nullptr,
                                     nullptr, acc[g]);
                }
            }
        }
        for (int g = 0; g < group; ++g) {  // each vector's last block, then its sum
            if (alone)
                block_points(xs[i + g], tc[g], kernel, ws, nb - 1, lp[g], lf[g], ls[g], h[g],
                             have_h[g], bad, nullptr, nullptr, acc[g]);
            out[i + g] = lane_sum(acc[g]);
        }
        i += group;
    }
}

IWR_FORCE_INLINE void TrackerObjective::block_points(const double* x, const detail::TrackerConsts& tc,
                                    const detail::TrackerKernels& kernel, Workspace& ws, int blk,
                                    double* pp, double* ff, const int* status, Hexapod& h,
                                    bool& have_h, double* bad, double* t, double* y,
                                    double* acc) const {
    constexpr int W = kLanes;
    const int kp = setup_.n_points(), nj = geometry_.n_joints();
    const double* data = block_data(blk);
    int unsolved = 0;  // some lane's status not 0 (rare: look at the lanes only then)
    bool any_bad = false;
    for (int l = 0; l < W; ++l) unsolved |= status[l], bad[l] = 0.0;
    for (int l = 0; l < W && unsolved != 0; ++l) {
        const int k = blk * W + l;
        if (status[l] == 0) continue;
        Vec3 p;
        Mat3 r;
        bool solved = false;
        if (k < n_) {
            if (!have_h) h = hexapod(x), have_h = true;
            try {
                finish(h, k, status[l], p, r);
                solved = true;
            } catch (const ForwardKinematicsError&) {
                bad[l] = 1.0, any_bad = true;
            }
        }
        if (!solved) {  // a failed pose or a padding lane: the reference pose, finite
            for (int c = 0; c < 3; ++c) p(c) = data[(36 + c) * W + l];
            for (int e = 0; e < 9; ++e) r(e / 3, e % 3) = data[(39 + e) * W + l];
        }
        const Mat3 f = r * joint_frame(tc);  // the kernels' F = R B
        for (int c = 0; c < 3; ++c) pp[c * W + l] = p(c);
        for (int e = 0; e < 9; ++e) ff[e * W + l] = f(e / 3, e % 3);
    }
    const double* meas = data + (kChordQuantities + 2 * nj) * W;
    const double* wh = whitened()
        ? wh_blocks_.data() + static_cast<size_t>(blk) * static_cast<size_t>(wh_stride_)
        : nullptr;
    kernel.points(data, tc, pp, ff, meas, meas + 3 * kp * W, bad,
                  all_seen_[static_cast<size_t>(blk)] != 0 && !any_bad, wh, ws.v.data(), t, y,
                  acc);
}

double TrackerObjective::evaluate(const double* x, const detail::TrackerConsts& tc,
                                  const detail::TrackerKernels& kernel, Workspace& ws, double* res,
                                  std::vector<int>* failed, RowMatrixXd* poses,
                                  RowMatrixXd* predicted) const {
    constexpr int W = kLanes;
    const int kp = setup_.n_points();
    const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> rt(tc.rt);
    const Eigen::Map<const Vec3> tt(tc.tt);
    Hexapod h;
    bool have_h = false;
    double* y = ws.y.data();
    // The forward kinematics of two blocks at once where the variant does so (chord2), else
    // block by block; then each block's points.
    alignas(64) double pp2[2 * 3 * W], ff2[2 * 9 * W], t[12 * W], bad[W], acc[W] = {};
    int status2[2 * W];
    const bool scalar = res || failed || poses || predicted;
    for (int blk = 0; blk * W < n_; ++blk) {
        const double* data = block_data(blk);
        const int half = kernel.chord2 ? blk % 2 : 0;
        if (!kernel.chord2)
            kernel.chord(data, tc, pp2, ff2, status2);
        else if (half == 0 && (blk + 1) * W < n_)
            kernel.chord2(data, block_data(blk + 1), tc, pp2, ff2, status2);
        else if (half == 0)
            kernel.chord(data, tc, pp2, ff2, status2);
        double* pp = pp2 + half * 3 * W;
        double* ff = ff2 + half * 9 * W;
        const int* status = status2 + half * W;
        block_points(x, tc, kernel, ws, blk, pp, ff, status, h, have_h, bad, scalar ? t : nullptr,
                     scalar ? y : nullptr, acc);
        if (!scalar) continue;
        for (int l = 0; l < W && blk * W + l < n_; ++l) {
            const int k = blk * W + l;
            if (bad[l] != 0.0) {
                if (failed) failed->push_back(k);
                if (poses) poses->row(k).setConstant(std::numeric_limits<double>::quiet_NaN());
                if (predicted)
                    predicted->row(k).setConstant(std::numeric_limits<double>::quiet_NaN());
            } else {
                if (poses) {
                    Mat3 r4, r;
                    Vec3 p4, p;
                    for (int e = 0; e < 9; ++e) r4(e / 3, e % 3) = t[e * W + l];
                    r = rotation_of(ff, l, tc);
                    for (int c = 0; c < 3; ++c) p4(c) = t[(9 + c) * W + l], p(c) = pp[c * W + l];
                    // t is T_T4: back to {0}.
                    r4 = (rt.transpose() * r4).eval();
                    p4 = rt.transpose() * (p4 - tt);
                    poses->block<1, 3>(k, 0) = (p4 + r4 * p).transpose();
                    poses->block<1, 3>(k, 3) = euler_from_matrix(r4 * r).transpose();
                }
                if (predicted)
                    for (int e = 0; e < 3 * kp; ++e) (*predicted)(k, e) = y[e * W + l];
            }
            if (!res) continue;
            for (int i = 0; i < kp; ++i) {
                const bool seen = !std::isnan(points_(k, 3 * i));
                for (int c = 0; c < 3; ++c) {
                    res[3 * (kp * k + i) + c] = !seen          ? 0.0
                                                : bad[l] != 0.0 ? kFailedResidual
                                                                : y[(3 * i + c) * W + l] - points_(k, 3 * i + c);
                }
            }
        }
    }
    return lane_sum(acc);
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

namespace detail {

int seen_points(const RowMatrixXd& points, int n_points) {
    int seen = 0;
    for (Eigen::Index p = 0; p < points.rows(); ++p) {
        for (int i = 0; i < n_points; ++i) {
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
            if (nan == 0) ++seen;
        }
    }
    return seen;
}

void check_whitening(const RowMatrixXd& whitening, Eigen::Index n, Eigen::Index m) {
    require_rows(whitening, n, m * m, "whitening");
    require_finite(whitening.data(), whitening.size(), "whitening");
    for (Eigen::Index k = 0; k < n; ++k)
        for (Eigen::Index i = 0; i < m; ++i)
            for (Eigen::Index j = i + 1; j < m; ++j)
                if (whitening(k, i * m + j) != 0.0) {
                    std::ostringstream msg;
                    msg << "whitening: pose " << k << ", entry (" << i << ", " << j << ") is "
                        << whitening(k, i * m + j) << "; the whitening of a pose must be lower triangular";
                    throw std::invalid_argument(msg.str());
                }
}

}  // namespace detail

void TrackerObjective::set_whitening(const RowMatrixXd& whitening) {
    const int m = 3 * setup_.n_points();
    if (whitening.size() == 0) {
        whitening_.resize(0, 0);
        wh_blocks_.clear();
        wh_rows_.clear();
        wh_stride_ = 0;
        wh_first_ = -1;
        return;
    }
    detail::check_whitening(whitening, n_, m);
    whitening_ = whitening;
    // The kernel's copy (tracker_kernel_body.inl, points_chain): the rows not zero at every pose.
    wh_rows_.assign(static_cast<size_t>(m), 0);
    int entries = 0;
    for (int i = 0; i < m; ++i) {
        for (int k = 0; k < n_ && !wh_rows_[static_cast<size_t>(i)]; ++k)
            for (int j = 0; j <= i; ++j)
                if (whitening(k, i * m + j) != 0.0) wh_rows_[static_cast<size_t>(i)] = 1;
        if (wh_rows_[static_cast<size_t>(i)]) entries += i + 1;
    }
    const auto first = std::find(wh_rows_.begin(), wh_rows_.end(), 1);
    wh_first_ = static_cast<int>(first - wh_rows_.begin());
    if (std::find(first, wh_rows_.end(), 0) != wh_rows_.end()) wh_first_ = -1;
    const size_t n_blocks = static_cast<size_t>((n_ + kLanes - 1) / kLanes);
    wh_stride_ = entries * kLanes;
    // At least one double: a whitening zero at every pose still passes a whitening (cost 0).
    wh_blocks_.assign(std::max<size_t>(n_blocks * static_cast<size_t>(wh_stride_), 1), 0.0);
    for (int k = 0; k < n_; ++k) {
        double* blk = wh_blocks_.data() +
                      static_cast<size_t>(k / kLanes) * static_cast<size_t>(wh_stride_);
        int e = 0;
        for (int i = 0; i < m; ++i) {
            if (!wh_rows_[static_cast<size_t>(i)]) continue;
            for (int j = 0; j <= i; ++j, ++e)
                blk[e * kLanes + k % kLanes] = whitening(k, i * m + j);
        }
    }
}

void TrackerObjective::whiten_rows(double* rows, Eigen::Index cols) const {
    const Eigen::Index m = 3 * setup_.n_points();
    using Rows = Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>;
    using Block = Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>;
    for (Eigen::Index k = 0; k < n_; ++k) {
        Rows b(rows + k * m * cols, m, cols);
        const Block w(whitening_.row(k).data(), m, m);
        b = (w.triangularView<Eigen::Lower>() * b).eval();
    }
}

double TrackerObjective::cost(const double* x, Workspace& ws) const {
    // Whitened or not: the kernel's sums (points_chain whitens each lane's residuals).
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
    if (whitened()) whiten_rows(r.data(), 1);
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

Eigen::VectorXi TrackerObjective::chord_status(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    const Hexapod h = hexapod(x.data());
    Eigen::VectorXi out(n_);
    Vec3 p[kLanes];
    Mat3 r[kLanes];
    int status[kLanes];
    for (int blk = 0; blk * kLanes < n_; ++blk) {
        solve_block(h, blk, p, r, status);
        for (int l = 0; l < kLanes && blk * kLanes + l < n_; ++l) out(blk * kLanes + l) = status[l];
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

void TrackerObjective::predicted_points(const double* x, Workspace& ws, RowMatrixXd& out) const {
    evaluate(x, ws, nullptr, nullptr, nullptr, &out);
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
    if (residuals) {
        *residuals = res;
        if (whitened()) whiten_rows(residuals->data(), 1);
    }
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
    setup_.platform_points(xt + 6, ws.slot[0].r.data(), &djo);
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
            const Vec3 ri = r * ws.slot[0].r[static_cast<size_t>(i)];  // R r_i
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
    if (whitened()) whiten_rows(jac->data(), jac->cols());
}

void TrackerObjective::cost_batch(const double* X, Eigen::Index m, double* out,
                                  ThreadPool& pool) const {
    batch_costs(*this, X, static_cast<std::size_t>(m), out, pool);
}
// batch_costs and de::ReducedObjective hand their rows to cost_rows (detail::row_costs).
static_assert(detail::has_cost_rows_v<TrackerObjective>, "TrackerObjective::cost_rows not seen");

}  // namespace iwr
