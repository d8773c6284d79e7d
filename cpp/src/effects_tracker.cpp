// Tracker data for a robot with the legs' effects (see iwr/effects_tracker.hpp): forward kinematics
// with the effects pose by pose (chord steps, else Newton's method; the statics shared with the
// leg objective with effects through effects_kernel.hpp), then the points in {T}.
#include "iwr/effects_tracker.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "effects_kernel.hpp"

namespace iwr {

namespace {

// Newton iterations per solve before the fallback (from the damped Newton-Raphson of
// hexapod_forward) and, after it, before the pose is declared failed (the geometry converges
// quadratically, the compliance linearly at a part in 1e5: a few iterations from the reference).
constexpr int kMaxNewton = 25;
// Chord steps (PoseSolver::chord) before Newton's method takes over, and the forces' refinement
// steps in each (each shrinks the forces' error by |I - G_ref^-1 G|, a part in a hundred to a
// thousand within DE's search box).
constexpr int kMaxChord = 12;
constexpr int kMaxForceSteps = 8;
// A leg residual beyond this (mm) is divergence, not a step on the way.
constexpr double kDiverged = 1e3;

constexpr int kOffDt = 6, kOffLoad = 12, kOffRefP = 16, kOffRefR = 19, kOffPoints = 28;

void require_shape(const RowMatrixXd& m, Eigen::Index rows, Eigen::Index cols, const char* what) {
    if (m.rows() != rows || m.cols() != cols) {
        std::ostringstream msg;
        msg << what << ": shape (" << m.rows() << ", " << m.cols() << "); expected (" << rows << ", " << cols << ")";
        throw std::invalid_argument(msg.str());
    }
}

struct Hexapod {
    LegMatrix a, b;
    LegVector l0;
};

Hexapod hexapod_at(const Geometry& g, const double* x) {
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

// The chord's solves: G_ref^-1 (row-major) times x, and its transpose times x.
inline void times(const double* gi, const double (&x)[6], double (&y)[6]) {
    for (int a = 0; a < 6; ++a) {
        double s = 0;
        for (int b = 0; b < 6; ++b) s += gi[6 * a + b] * x[b];
        y[a] = s;
    }
}
inline void times_transposed(const double* gi, const double (&x)[6], double (&y)[6]) {
    for (int a = 0; a < 6; ++a) y[a] = 0;
    for (int b = 0; b < 6; ++b)
        for (int a = 0; a < 6; ++a) y[a] += gi[6 * b + a] * x[b];
}

// One pose's forward kinematics with the effects (solve: Newton's method; chord: chord steps,
// below) on the predicted readings from (p, r) (the platform's pose in the solver's frame; r
// row-major), in place. Before each iteration
// frame(p, r, a, g) gives the base joints a and gravity g in that frame: {4} at the readings without
// the carriage's compliance (a and g fixed), {0} with it (the carriage's joints change with the
// platform's load, so {4} moves with the pose solved). The Jacobian is the geometry's, G^T (the
// statics' matrix transposed: d len_j = u_j . dP + (r_j x u_j) . omega), each row scaled by the leg's
// thermal growth 1 - alpha_j dT_j; the compliances' own derivatives (a part in 1e5 of the legs', 1e3
// for a carriage at its bound) are left out: the convergence is linear at that rate in them.
// Converged when the largest residual is at most tol, after which the step already computed is
// taken too (no further evaluation). False when a leg has no length, the hexapod is singular, the
// residual diverges or kMaxNewton iterations do not converge.
struct PoseSolver {
    const detail::EvalConsts& ec;
    const detail::LegEffects& le;
    bool compliance;
    double tol;

    // The legs at (p, r) with the base joints `base`: each one's platform joint relative to the
    // platform origin rj, unit vector u and length len; false where a leg has no length.
    bool legs(const double (&p)[3], const double (&r)[9], const double (*base)[3], double (&rj)[kLegs][3],
              double (&u)[kLegs][3], double (&len)[kLegs]) const {
        for (int j = 0; j < kLegs; ++j) {
            double v[3];
            for (int e = 0; e < 3; ++e) {
                rj[j][e] = r[3 * e] * ec.b[j][0] + r[3 * e + 1] * ec.b[j][1] + r[3 * e + 2] * ec.b[j][2];
                v[e] = (p[e] + rj[j][e]) - base[j][e];
            }
            len[j] = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            if (!(len[j] > 0)) return false;
            const double inv = 1.0 / len[j];
            for (int e = 0; e < 3; ++e) u[j][e] = v[e] * inv;
        }
        return true;
    }
    // The weight of the platform and payload at rotation r: force M g, moment (R c) x g with c
    // their first moment in {5} (kg mm: N mm), about the platform origin, in the frame of g.
    static void wrench(const double* d, const double (&r)[9], const double* g, double (&w)[6]) {
        const double mass = d[kOffLoad];
        const double* c5 = d + kOffLoad + 1;
        double rc[3];
        for (int e = 0; e < 3; ++e) rc[e] = r[3 * e] * c5[0] + r[3 * e + 1] * c5[1] + r[3 * e + 2] * c5[2];
        for (int e = 0; e < 3; ++e) w[e] = mass * g[e];
        w[3] = rc[1] * g[2] - rc[2] * g[1];
        w[4] = rc[2] * g[0] - rc[0] * g[2];
        w[5] = rc[0] * g[1] - rc[1] * g[0];
    }
    // The legs' residuals at lengths len and forces f: the right-hand side b of the step (-h_j
    // over the thermal growth), and the largest |h_j|; NaN where an h_j is NaN (std::max drops
    // it) or a b_j is not finite (a thermal growth of 0: 0 b_j is then NaN).
    double residuals(const double* d, const double (&len)[kLegs], const double (&f)[6], double (&b)[6]) const {
        double worst = 0, sum = 0;
        for (int j = 0; j < kLegs; ++j) {
            const double dt = d[kOffDt + j];
            const double h = detail::predicted_reading(len[j], ec.l0[j], le.c[j], f[j], le.alpha[j], dt) - d[j];
            worst = std::max(worst, std::fabs(h));
            b[j] = -h / (1.0 - le.alpha[j] * dt);
            sum += h + 0.0 * b[j];
        }
        return std::isnan(sum) ? sum : worst;
    }
    // (p, r) moved by the step (dP, omega): p + dP, Exp(omega) r.
    static void move(const double (&step)[6], double (&p)[3], double (&r)[9]) {
        for (int e = 0; e < 3; ++e) p[e] += step[e];
        const Mat3 turn = rotvec_matrix(Vec3(step[3], step[4], step[5]));
        double nr[9];
        for (int a = 0; a < 3; ++a)
            for (int c = 0; c < 3; ++c)
                nr[3 * a + c] = turn(a, 0) * r[c] + turn(a, 1) * r[3 + c] + turn(a, 2) * r[6 + c];
        for (int e = 0; e < 9; ++e) r[e] = nr[e];
    }

    // The same equations by chord steps: G_ref^-1 (gi: the statics matrix's inverse at the
    // reference geometry and pose in {4}, which the pose and the parameters move by a part in a
    // thousand within DE's search box; rot: 0R4 row-major where the solver's frame is {0}, its
    // G then B G_ref with B = diag(0R4, 0R4), else null) in place of a factorisation of G at
    // every iteration (the statics were 60 % of the objective's time, BENCHMARKS.md, thirtieth
    // round). Each step is refined once towards Newton's: s = s0 + G_ref^-T (b - G^T s0), s0 =
    // G_ref^-T b, with the current G; the legs' forces (with the compliance) are
    // refined from the last iteration's, f += G_ref^-1 (w - G f), to a ten-thousandth of the last
    // step's residual, and to tol / 1000 (no refinement moving a reading more) before the
    // residuals are judged converged. Converged as solve() (the largest residual at most tol, the
    // step computed then taken too), so the pose is solve()'s to within tol. False when a leg has
    // no length, the residual diverges or is NaN, the forces do not settle or kMaxChord steps do
    // not converge: the caller then runs solve() from the start. The current G is not checked for
    // a singularity (solve()'s factorisation refuses one): near one the forces do not settle.
    template <class Frame>
    bool chord(const double* d, const double* gi, const double* rot, Frame&& frame, double (&p)[3],
               double (&r)[9]) const {
        double f[6] = {0, 0, 0, 0, 0, 0};  // the legs' forces (N), refined from step to step
        const double fine = 1e-3 * tol;    // the forces' last refinement moves no reading more
        double last = 1.0;                 // the last step's largest residual (mm), at most 1
        // y = B^T x (into {4}) and x = B y (out of it), B = diag(0R4, 0R4); none without rot.
        const auto into = [rot](double (&x)[6]) {
            if (!rot) return;
            for (int h = 0; h < 6; h += 3) {
                const double a = x[h], b = x[h + 1], c = x[h + 2];
                for (int e = 0; e < 3; ++e) x[h + e] = rot[e] * a + rot[3 + e] * b + rot[6 + e] * c;
            }
        };
        const auto out = [rot](double (&x)[6]) {
            if (!rot) return;
            for (int h = 0; h < 6; h += 3) {
                const double a = x[h], b = x[h + 1], c = x[h + 2];
                for (int e = 0; e < 3; ++e) x[h + e] = rot[3 * e] * a + rot[3 * e + 1] * b + rot[3 * e + 2] * c;
            }
        };
        for (int it = 0; it < kMaxChord; ++it) {
            const double(*base)[3] = nullptr;
            const double* g4 = nullptr;
            frame(p, r, base, g4);
            double u[kLegs][3], rj[kLegs][3], m[kLegs][3], len[kLegs];
            if (!legs(p, r, base, rj, u, len)) return false;
            for (int j = 0; j < kLegs; ++j) {
                m[j][0] = rj[j][1] * u[j][2] - rj[j][2] * u[j][1];
                m[j][1] = rj[j][2] * u[j][0] - rj[j][0] * u[j][2];
                m[j][2] = rj[j][0] * u[j][1] - rj[j][1] * u[j][0];
            }
            double w[6] = {0, 0, 0, 0, 0, 0};
            if (compliance) wrench(d, r, g4, w);
            // The forces refined until a refinement moves no reading by more than `want`; false
            // when kMaxForceSteps do not get there (or a NaN).
            const auto settle = [&](double want) {
                for (int k = 0; k < kMaxForceSteps; ++k) {
                    double res[6], df[6];
                    for (int e = 0; e < 3; ++e) {
                        double sf = w[e], sm = w[3 + e];
                        for (int j = 0; j < kLegs; ++j) sf -= u[j][e] * f[j], sm -= m[j][e] * f[j];
                        res[e] = sf, res[3 + e] = sm;
                    }
                    into(res);
                    times(gi, res, df);
                    double moved = 0, sum = 0;  // (sum: NaN where a change is, which max drops)
                    for (int j = 0; j < kLegs; ++j) {
                        f[j] += df[j];
                        moved = std::max(moved, std::fabs(le.c[j] * df[j]));
                        sum += df[j];
                    }
                    if (std::isnan(sum)) return false;
                    if (moved <= want) return true;
                }
                return false;
            };
            // The forces to a ten-thousandth of the last step's largest residual (they follow the
            // pose: a step takes them on from where they were); once the residuals are within tol,
            // to tol / 1000 and the residuals again (what the convergence is judged on).
            double b[6], worst = 0;
            if (!compliance) {
                worst = residuals(d, len, f, b);
                if (!(worst <= kDiverged)) return false;  // NaN too
            } else {
                double want = std::max(fine, 1e-4 * last);
                for (;;) {
                    if (!settle(want)) return false;
                    worst = residuals(d, len, f, b);
                    if (!(worst <= kDiverged)) return false;  // NaN too
                    if (!(worst <= tol && want > fine)) break;
                    want = fine;
                }
                last = std::min(worst, 1.0);
            }
            double s0[6], t[6], step[6];
            times_transposed(gi, b, s0);
            out(s0);
            for (int j = 0; j < kLegs; ++j)
                t[j] = b[j] - (u[j][0] * s0[0] + u[j][1] * s0[1] + u[j][2] * s0[2] + m[j][0] * s0[3] +
                               m[j][1] * s0[4] + m[j][2] * s0[5]);
            times_transposed(gi, t, step);
            out(step);
            for (int e = 0; e < 6; ++e) step[e] += s0[e];
            move(step, p, r);
            if (worst <= tol) return true;
        }
        return false;
    }

    template <class Frame>
    bool solve(const double* d, Frame&& frame, double (&p)[3], double (&r)[9]) const {
        for (int it = 0; it < kMaxNewton; ++it) {
            const double(*base)[3] = nullptr;
            const double* g4 = nullptr;
            frame(p, r, base, g4);
            double u[kLegs][3], rj[kLegs][3], len[kLegs];
            if (!legs(p, r, base, rj, u, len)) return false;
            detail::Statics st;
            if (!detail::statics_factor(u, rj, st)) return false;
            double f[6] = {0, 0, 0, 0, 0, 0};
            if (compliance) {
                wrench(d, r, g4, f);
                detail::statics_forces(st, f);
            }
            double step[6];
            const double worst = residuals(d, len, f, step);
            if (!(worst <= kDiverged)) return false;  // NaN too
            detail::statics_transposed(st, step);
            move(step, p, r);
            if (worst <= tol) return true;
        }
        return false;
    }
};

// (p, r) <- t (p, r): a pose in the frame t (0T4, rotation row-major then position) into {0}.
void to_world(const double* t, double (&p)[3], double (&r)[9]) {
    double np[3], nr[9];
    for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) nr[3 * a + b] = t[3 * a] * r[b] + t[3 * a + 1] * r[3 + b] + t[3 * a + 2] * r[6 + b];
        np[a] = t[9 + a] + t[3 * a] * p[0] + t[3 * a + 1] * p[1] + t[3 * a + 2] * p[2];
    }
    for (int e = 0; e < 3; ++e) p[e] = np[e];
    for (int e = 0; e < 9; ++e) r[e] = nr[e];
}

}  // namespace

TrackerEffectObjective::TrackerEffectObjective(Geometry geometry, EffectModel effects, TrackerSetup setup,
                                               const Vec3& gravity, const RowMatrixXd& q, const RowMatrixXd& legs,
                                               const RowMatrixXd& points, const RowMatrixXd& payload,
                                               const RowMatrixXd& temperatures, const VectorXd& reference,
                                               const Vector6d& home, double tolerance)
    : geometry_(std::move(geometry)),
      effects_(std::move(effects)),
      setup_(std::move(setup)),
      gravity_(gravity),
      n_(static_cast<int>(legs.rows())),
      tolerance_(tolerance) {
    const int nj = geometry_.n_joints(), kp = setup_.n_points();
    if (effects_.n_geometric != geometry_.n_params())
        throw std::invalid_argument("effects: parsed for " + std::to_string(effects_.n_geometric) +
                                    " geometric parameters; the robot has " + std::to_string(geometry_.n_params()));
    if (!effects_.any())
        throw std::invalid_argument("effects: none on; tracker data without effects run on TrackerObjective");
    if (n_ == 0) throw std::invalid_argument("legs: no measurements (0 rows)");
    require_shape(legs, n_, kLegs, "legs");
    require_shape(q, n_, nj, "q");
    require_shape(points, n_, 3 * kp, "points");
    require_finite(q.data(), q.size(), "q");
    require_finite(legs.data(), legs.size(), "legs");
    detail::check_loads(effects_, n_, payload, temperatures);
    require_finite(gravity_.data(), 3, "gravity");
    if (!(std::fabs(gravity_.norm() / 9.80665 - 1.0) <= 0.01)) {
        std::ostringstream msg;
        msg.precision(17);
        msg << "gravity: norm " << gravity_.norm() << " m/s^2 in the tracker frame {T}; expected 9.80665 within 1 %";
        throw std::invalid_argument(msg.str());
    }
    if (!(std::isfinite(tolerance) && tolerance > 0))
        throw std::invalid_argument("tolerance: " + std::to_string(tolerance) + "; expected a finite number > 0 (mm)");
    geometry_.check_errors(reference.data(), reference.size(), "reference");
    require_finite(home.data(), 6, "home");
    n_seen_ = detail::seen_points(points, kp);

    int nq = kOffPoints + 4 * kp;
    if (effects_.carriage_thermal) {
        off_ct_ = nq++;
        detail::check_carriage_thermal(effects_, geometry_);
    }
    for (int i = 0; i < nj; ++i) {
        q_off_.push_back(nq);
        prismatic_.push_back(geometry_.is_prismatic(i) ? 1 : 0);
        nq += geometry_.is_prismatic(i) ? 1 : 2;
    }
    off_chord_ = nq;
    nq += 36;
    stride_ = nq;
    off_pts_ = kOffPoints;
    carriage_ = detail::CarriageNominal(geometry_);
    if (effects_.carriage) cc_scale_ = detail::carriage_scales(effects_, geometry_);
    data_.assign(static_cast<std::size_t>(n_) * static_cast<std::size_t>(stride_), 0.0);
    const Hexapod h = hexapod_at(geometry_, reference.data());
    ForwardOptions opt;
    opt.tolerance = tolerance_;
    ref_euler_.resize(static_cast<std::size_t>(n_));
    // The platform's mass and centre: the leg compliance's, else the carriage compliance's (the
    // same when both are on: EffectModel::parse).
    const bool loaded = effects_.compliance || effects_.carriage;
    const double platform_mass = effects_.compliance ? effects_.platform_mass
                                 : effects_.carriage ? effects_.carriage_platform_mass
                                                     : 0.0;
    const Vec3 platform_centre = effects_.compliance ? effects_.platform_centre : effects_.carriage_platform_centre;
    for (int k = 0; k < n_; ++k) {
        double* d = data_.data() + static_cast<std::size_t>(k) * static_cast<std::size_t>(stride_);
        for (int j = 0; j < kLegs; ++j) d[j] = legs(k, j);
        if (effects_.thermal)
            for (int j = 0; j < kLegs; ++j)
                d[kOffDt + j] = temperatures(k, temperatures.cols() == 1 ? 0 : j) - effects_.reference;
        if (off_ct_ >= 0) d[off_ct_] = temperatures(k, 0) - effects_.ct_reference;
        if (loaded) {
            Vec3 first = platform_mass * platform_centre;
            double mass = platform_mass;
            if (payload.size() != 0) {
                first += payload(k, 0) * Vec3(payload(k, 1), payload(k, 2), payload(k, 3));
                mass += payload(k, 0);
            }
            d[kOffLoad] = mass;
            for (int e = 0; e < 3; ++e) d[kOffLoad + 1 + e] = first(e);
        }
        const LegVector len = legs.row(k).transpose() + h.l0;
        ref_euler_[static_cast<std::size_t>(k)] = hexapod_forward(h.a, h.b, len, home, opt, k).pose;
        const Vector6d& ref = ref_euler_[static_cast<std::size_t>(k)];
        const Mat3 rr = euler_zyx(ref(3), ref(4), ref(5));
        for (int e = 0; e < 3; ++e) d[kOffRefP + e] = ref(e);
        for (int e = 0; e < 9; ++e) d[kOffRefR + e] = rr(e / 3, e % 3);
        {  // G_ref^-1 for the chord steps: G's column j is (u_j, w_j x u_j), w_j = R b_j; none
           // (NaN) where the statics refuse G_ref as solve() would (a pivot below 1e-12)
            Eigen::Matrix<double, 6, 6> gm;
            double uj[kLegs][3], wj[kLegs][3];
            for (int j = 0; j < kLegs; ++j) {
                const Vec3 w = rr * h.b.row(j).transpose();
                const Vec3 u = (ref.head<3>() + w - h.a.row(j).transpose()).normalized();
                gm.col(j) << u, w.cross(u);
                for (int e = 0; e < 3; ++e) uj[j][e] = u(e), wj[j][e] = w(e);
            }
            detail::Statics st;
            const bool regular = detail::statics_factor(uj, wj, st);
            Eigen::Map<Eigen::Matrix<double, 6, 6, Eigen::RowMajor>> gi(d + off_chord_);
            if (regular) gi = gm.fullPivLu().inverse();
            if (!regular || !gi.allFinite()) gi(0, 0) = std::numeric_limits<double>::quiet_NaN();
        }
        for (int i = 0; i < kp; ++i) {
            const bool seen = !std::isnan(points(k, 3 * i));
            for (int c = 0; c < 3; ++c) d[kOffPoints + 3 * i + c] = seen ? points(k, 3 * i + c) : 0.0;
            d[kOffPoints + 3 * kp + i] = seen ? 1.0 : 0.0;
        }
        for (int i = 0; i < nj; ++i) {
            const int o = q_off_[static_cast<std::size_t>(i)];
            if (prismatic_[static_cast<std::size_t>(i)]) {
                d[o] = q(k, i);
            } else {
                d[o] = std::cos(q(k, i));
                d[o + 1] = std::sin(q(k, i));
            }
        }
    }
}

void TrackerEffectObjective::set_whitening(const RowMatrixXd& whitening) {
    if (whitening.size() == 0) {
        whitening_.resize(0, 0);
        return;
    }
    const Eigen::Index m = 3 * setup_.n_points();
    detail::check_whitening(whitening, n_, m);
    whitening_ = whitening;
}

TrackerEffectObjective::Workspace TrackerEffectObjective::make_workspace() const {
    Workspace ws;
    ws.jbuf.assign(static_cast<std::size_t>(15 * geometry_.n_joints() + 1), 0.0);
    ws.r.resize(static_cast<std::size_t>(setup_.n_points()));
    ws.res.resize(static_cast<std::size_t>(3 * setup_.n_points()));
    return ws;
}

double TrackerEffectObjective::evaluate(const double* x, Workspace& ws, double* res, RowMatrixXd* poses,
                                        RowMatrixXd* predicted,
                                        std::vector<std::pair<int, std::string>>* failed, int* paths) const {
    const Geometry& g = geometry_;
    const int nj = g.n_joints(), kp = setup_.n_points(), m = 3 * kp;
    detail::EvalConsts ec;
    carriage_.consts(g, x, ec, ws.jbuf.data());
    const detail::LegEffects le = detail::leg_effects(effects_, x);
    const double* xs = x + g.n_params() + effects_.n_params;
    Mat3 rt;
    Vec3 tt;
    setup_.registration_transform(xs, rt, tt);
    setup_.platform_points(xs + 6, ws.r.data());
    const Vec3 g0 = rt.transpose() * gravity_;  // gravity in {0} through the registration
    detail::PoseData layout;
    layout.n_joints = nj, layout.n_prefix = carriage_.n_prefix();
    layout.q_off = q_off_.data(), layout.prismatic = prismatic_.data();
    const PoseSolver solver{ec, le, effects_.compliance, tolerance_};
    const bool whiten = whitened();
    // The carriage's compliance: per joint its compliance at x, the hexapod's centre in {4}.
    const bool cc = effects_.carriage;
    double ccomp[detail::kMaxChainJoints], ch[3] = {0, 0, 0};
    if (cc) {
        detail::hexapod_centre(effects_, ec, ch);
        detail::carriage_compliances(effects_, cc_scale_, x, ccomp);
    }
    // The carriage's thermal expansion: per joint its scale's coefficient at x (1/K; 0: none).
    const bool ct = off_ct_ >= 0;
    double calpha[detail::kMaxChainJoints], growth[detail::kMaxChainJoints];
    if (ct) detail::carriage_alphas(effects_, nj, x, calpha);
    double* out = ws.res.data();
    double acc = 0;
    for (int k = 0; k < n_; ++k) {
        const double* d = data_.data() + static_cast<std::size_t>(k) * static_cast<std::size_t>(stride_);
        double t[12];  // 0T4 at the readings (with the scales' growth when the compliance is off)
        double axes[3 * detail::kMaxChainJoints], origins[3 * detail::kMaxChainJoints];
        if (ct) detail::carriage_growth(layout, d, d[off_ct_], calpha, growth, false);
        detail::carriage_chain(layout, ec, d, ct && !cc ? growth : nullptr, t, cc ? axes : nullptr,
                               cc ? origins : nullptr);
        double g4[3];  // gravity in {4}: 0R4^T g_0
        for (int e = 0; e < 3; ++e) g4[e] = t[e] * g0(0) + t[3 + e] * g0(1) + t[6 + e] * g0(2);
        // Without the carriage's compliance the pose is solved in {4} at the readings (its base
        // joints and gravity fixed); with it in {0}: each iteration the joints' change under the
        // load of the hexapod and of the platform's bodies where the pose puts them (the loads at
        // the readings' axes, iwr.effects.model.joint_loads), then the base joints of the changed
        // carriage.
        const auto fixed = [&](const double(&)[3], const double(&)[9], const double(*&base)[3], const double*& g) {
            base = ec.a, g = g4;
        };
        double changed[12], base_world[kLegs][3];
        const auto moving = [&](const double(&pw)[3], const double(&rw)[9], const double(*&base)[3], const double*& g) {
            const double* c5 = d + kOffLoad + 1;
            double first[3], delta[detail::kMaxChainJoints];
            for (int e = 0; e < 3; ++e)
                first[e] = d[kOffLoad] * pw[e] + (rw[3 * e] * c5[0] + rw[3 * e + 1] * c5[1] + rw[3 * e + 2] * c5[2]);
            detail::carriage_deflection(effects_, layout, axes, origins, t, ch, first, d[kOffLoad], g0, ccomp, delta);
            if (ct)
                for (int i = 0; i < nj; ++i) delta[i] += growth[i];
            detail::carriage_chain(layout, ec, d, delta, changed, nullptr, nullptr);
            for (int j = 0; j < kLegs; ++j)
                for (int e = 0; e < 3; ++e)
                    base_world[j][e] = changed[9 + e] + changed[3 * e] * ec.a[j][0] + changed[3 * e + 1] * ec.a[j][1] +
                                       changed[3 * e + 2] * ec.a[j][2];
            base = base_world, g = g0.data();
        };
        const auto solve = [&](double(&pp)[3], double(&rr)[9]) {
            if (!cc) return solver.solve(d, fixed, pp, rr);
            to_world(t, pp, rr);
            return solver.solve(d, moving, pp, rr);
        };
        double p[3], r[9];
        const auto start = [&] {
            for (int e = 0; e < 3; ++e) p[e] = d[kOffRefP + e];
            for (int e = 0; e < 9; ++e) r[e] = d[kOffRefR + e];
        };
        start();
        // Chord steps (in {0} with the carriage's compliance: its G_ref carried by 0R4 at the
        // readings), else (where they do not converge) Newton's method from the reference.
        const double* gi = d + off_chord_;
        bool ok = false;
        if (!std::isnan(gi[0])) {
            if (!cc) {
                ok = solver.chord(d, gi, nullptr, fixed, p, r);
            } else {
                to_world(t, p, r);
                ok = solver.chord(d, gi, t, moving, p, r);
            }
        }
        int path = 0;
        if (!ok) {
            start();
            ok = solve(p, r);
            path = 1;
        }
        if (!ok) {
            // From the geometry's own forward kinematics at x (damped Newton-Raphson from the
            // reference pose), then Newton with the effects again.
            LegVector len;
            bool positive = true;  // hexapod_forward refuses a leg length <= 0 (none exists)
            for (int j = 0; j < kLegs; ++j) len(j) = d[j] + ec.l0[j], positive = positive && len(j) > 0 && std::isfinite(len(j));
            if (positive) try {
                LegMatrix a, b;
                for (int j = 0; j < kLegs; ++j)
                    for (int c = 0; c < 3; ++c) a(j, c) = ec.a[j][c], b(j, c) = ec.b[j][c];
                ForwardOptions opt;
                opt.tolerance = tolerance_;
                const Vector6d sol = hexapod_forward(a, b, len, ref_euler_[static_cast<std::size_t>(k)], opt, k).pose;
                const Mat3 rs = euler_zyx(sol(3), sol(4), sol(5));
                for (int e = 0; e < 3; ++e) p[e] = sol(e);
                for (int e = 0; e < 9; ++e) r[e] = rs(e / 3, e % 3);
                ok = solve(p, r);
                path = 2;
            } catch (const ForwardKinematicsError&) {
                ok = false;
            }
            if (!ok) path = 3;
            if (!ok && failed)
                failed->emplace_back(k, "forward kinematics with the effects: pose " + std::to_string(k) +
                                            ": the legs do not close at these readings under the pose's load "
                                            "and temperature (no Newton convergence)");
        }
        if (paths) paths[k] = path;
        // The point y = T_T0 0T4 (P + R r_i) (with the carriage's compliance (P, R) is 0T5
        // already), and its residual.
        double w0[12];  // 0T5
        if (cc) {
            for (int e = 0; e < 9; ++e) w0[e] = r[e];
            for (int e = 0; e < 3; ++e) w0[9 + e] = p[e];
        } else {
            for (int a = 0; a < 3; ++a) {
                for (int b = 0; b < 3; ++b)
                    w0[3 * a + b] = t[3 * a] * r[b] + t[3 * a + 1] * r[3 + b] + t[3 * a + 2] * r[6 + b];
                w0[9 + a] = t[9 + a] + t[3 * a] * p[0] + t[3 * a + 1] * p[1] + t[3 * a + 2] * p[2];
            }
        }
        const double* meas = d + kOffPoints;
        const double* seen = meas + m;
        for (int i = 0; i < kp; ++i) {
            const Vec3& ri = ws.r[static_cast<std::size_t>(i)];
            double z[3], y[3];
            for (int a = 0; a < 3; ++a) z[a] = w0[9 + a] + w0[3 * a] * ri(0) + w0[3 * a + 1] * ri(1) + w0[3 * a + 2] * ri(2);
            for (int a = 0; a < 3; ++a) y[a] = tt(a) + rt(a, 0) * z[0] + rt(a, 1) * z[1] + rt(a, 2) * z[2];
            for (int c = 0; c < 3; ++c) {
                out[3 * i + c] = seen[i] == 0.0 ? 0.0 : !ok ? kFailedResidual : y[c] - meas[3 * i + c];
                if (predicted) (*predicted)(k, 3 * i + c) = ok ? y[c] : std::numeric_limits<double>::quiet_NaN();
            }
        }
        if (poses) {
            if (ok) {
                const Mat3 rw = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(w0);
                for (int e = 0; e < 3; ++e) (*poses)(k, e) = w0[9 + e];
                poses->block<1, 3>(k, 3) = euler_from_matrix(rw).transpose();
            } else {
                poses->row(k).setConstant(std::numeric_limits<double>::quiet_NaN());
            }
        }
        if (whiten) {
            const double* wk = whitening_.row(k).data();
            for (int i = 0; i < m; ++i) {
                double s = 0;
                for (int j = 0; j <= i; ++j) s += wk[i * m + j] * out[j];
                if (res) res[static_cast<std::ptrdiff_t>(m) * k + i] = s;
                acc += s * s;
            }
        } else {
            for (int i = 0; i < m; ++i) {
                if (res) res[static_cast<std::ptrdiff_t>(m) * k + i] = out[i];
                acc += out[i] * out[i];
            }
        }
    }
    return acc;
}

double TrackerEffectObjective::cost(const double* x, Workspace& ws) const {
    return evaluate(x, ws, nullptr, nullptr, nullptr, nullptr);
}

void TrackerEffectObjective::check_x(const Eigen::Ref<const VectorXd>& x) const {
    if (x.size() != n_params()) {
        std::ostringstream msg;
        msg << "x: " << x.size() << " values given but this problem has " << n_params() << " parameters ("
            << geometry_.n_params() << " of the robot, " << effects_.n_params << " of the effects, "
            << setup_.n_params() << " of the tracker setup)";
        throw std::invalid_argument(msg.str());
    }
    require_finite(x.data(), x.size(), "x");
}

double TrackerEffectObjective::cost(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    Workspace ws = make_workspace();
    return cost(x.data(), ws);
}

VectorXd TrackerEffectObjective::residuals(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    VectorXd r(n_residuals());
    Workspace ws = make_workspace();
    evaluate(x.data(), ws, r.data(), nullptr, nullptr, nullptr);
    return r;
}

std::vector<std::pair<int, std::string>> TrackerEffectObjective::failures(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    std::vector<std::pair<int, std::string>> out;
    Workspace ws = make_workspace();
    evaluate(x.data(), ws, nullptr, nullptr, nullptr, &out);
    return out;
}

Eigen::VectorXi TrackerEffectObjective::solve_paths(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    Eigen::VectorXi out(n_);
    Workspace ws = make_workspace();
    evaluate(x.data(), ws, nullptr, nullptr, nullptr, nullptr, out.data());
    return out;
}

RowMatrixXd TrackerEffectObjective::platform_poses(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    RowMatrixXd poses(n_, 6);
    Workspace ws = make_workspace();
    evaluate(x.data(), ws, nullptr, &poses, nullptr, nullptr);
    return poses;
}

RowMatrixXd TrackerEffectObjective::predicted_points(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    RowMatrixXd pred(n_, 3 * setup_.n_points());
    Workspace ws = make_workspace();
    evaluate(x.data(), ws, nullptr, nullptr, &pred, nullptr);
    return pred;
}

void TrackerEffectObjective::predicted_points(const double* x, Workspace& ws, RowMatrixXd& out) const {
    evaluate(x, ws, nullptr, nullptr, &out, nullptr);
}

void TrackerEffectObjective::cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const {
    batch_costs(*this, X, static_cast<std::size_t>(m), out, pool);
}

}  // namespace iwr
