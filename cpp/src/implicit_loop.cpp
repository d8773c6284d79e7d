// The implicit loop estimator: see implicit_loop.hpp.
#include "iwr/implicit_loop.hpp"

#include "iwr/measurement_kind.hpp"

#include <algorithm>
#include <functional>
#include <memory>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace iwr {

namespace {

using MatX = Eigen::MatrixXd;
using VecX = Eigen::VectorXd;
using Map3c = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>;

Mat3 skew(const Vec3& v) {
    Mat3 k;
    k << 0, -v(2), v(1), v(2), 0, -v(0), -v(1), v(0), 0;
    return k;
}

// exp([w]x) (Rodrigues) and the right Jacobian J_r(w): exp([w + d]x) = exp([w]x) exp([J_r d]x)
// + O(d^2). Series below 1e-4 rad, where the closed forms lose digits to cancellation.
void so3_exp(const Vec3& w, Mat3* r, Mat3* jr) {
    const double t2 = w.squaredNorm();
    const double t = std::sqrt(t2);
    double s, c, e;  // sin t / t, (1 - cos t) / t^2, (t - sin t) / t^3
    if (t < 1e-4) {
        s = 1 - t2 / 6 + t2 * t2 / 120;
        c = 0.5 - t2 / 24 + t2 * t2 / 720;
        e = 1.0 / 6 - t2 / 120 + t2 * t2 / 5040;
    } else {
        s = std::sin(t) / t;
        c = (1 - std::cos(t)) / t2;
        e = (t - std::sin(t)) / (t2 * t);
    }
    const Mat3 k = skew(w);
    const Mat3 k2 = k * k;
    if (r) *r = Mat3::Identity() + s * k + c * k2;
    if (jr) *jr = Mat3::Identity() - c * k + e * k2;
}

// One pose: predicted legs at (x, q + dq, (p + dp, R exp([w]x))) and, when jx != nullptr, the
// exact derivatives with respect to every parameter (6 x n_params) and to the corrections
// (6 x (n_joints + 6)). `frames` has n_joints + 1 entries.
void pose_legs(const Geometry& g, const double* x, const double* q, const double* pose,
               const double* corr, double* legs, RowMatrixXd* jx, RowMatrixXd* jy, int row0,
               Mat4* frames, double* qt) {
    const int nj = g.n_joints();
    for (int i = 0; i < nj; ++i) qt[i] = q[i] + corr[i];
    const Mat4 t4 = carriage_transform(g, x, qt, frames);
    const Mat3 r4 = t4.topLeftCorner<3, 3>();
    const Vec3 p4 = t4.topRightCorner<3, 1>();
    const Vec3 w(corr[nj + 3], corr[nj + 4], corr[nj + 5]);
    Mat3 ew, jr;
    so3_exp(w, &ew, jx ? &jr : nullptr);
    const Mat3 r5 = euler_zyx(pose[3], pose[4], pose[5]) * ew;
    const Vec3 p5 = Vec3(pose[0], pose[1], pose[2]) + Vec3(corr[nj], corr[nj + 1], corr[nj + 2]);
    const int base = 4 * nj;
    for (int j = 0; j < kLegs; ++j) {
        const Vec3 a = g.base().row(j).transpose() + Eigen::Map<const Vec3>(x + base + 3 * j);
        const Vec3 b = g.platform().row(j).transpose() + Eigen::Map<const Vec3>(x + base + 18 + 3 * j);
        const Vec3 pa = p4 + r4 * a;  // universal joint centre in {0}
        const Vec3 v = p5 + r5 * b - pa;
        const double len = v.norm();
        legs[j] = len - (g.leg_offsets()(j) + x[base + 36 + j]);
        if (!jx) continue;
        const Vec3 u = v / len;  // d len = u . (dB - dA)
        auto rx = jx->row(row0 + j);
        auto ry = jy->row(row0 + j);
        rx.setZero();
        // As Objective::jacobian: theta and d act about/along z_{i-1} through o_{i-1}, a and alpha
        // along/about x_i through o_i. A joint reading adds to d (P) or theta (R).
        for (int i = 0; i < nj; ++i) {
            const Vec3 z_prev = frames[i].block<3, 1>(0, 2);
            const Vec3 o_prev = frames[i].block<3, 1>(0, 3);
            const Vec3 x_i = frames[i + 1].block<3, 1>(0, 0);
            const Vec3 o_i = frames[i + 1].block<3, 1>(0, 3);
            rx(4 * i + 0) = -u.dot(x_i.cross(pa - o_i));
            rx(4 * i + 1) = -u.dot(x_i);
            rx(4 * i + 2) = -u.dot(z_prev);
            rx(4 * i + 3) = -u.dot(z_prev.cross(pa - o_prev));
            ry(i) = g.is_prismatic(i) ? rx(4 * i + 2) : rx(4 * i + 3);
        }
        const Vec3 da = -(r4.transpose() * u);
        const Vec3 c = r5.transpose() * u;
        for (int k = 0; k < 3; ++k) {
            rx(g.idx_base(j, k)) = da(k);
            rx(g.idx_platform(j, k)) = c(k);
        }
        rx(g.idx_offset(j)) = -1.0;
        // d(R exp([w]x) b)/dw = -R exp([w]x) [b]x J_r(w), so d len/dw = (b x c)^T J_r(w).
        const Vec3 dw = jr.transpose() * b.cross(c);
        for (int k = 0; k < 3; ++k) {
            ry(nj + k) = u(k);
            ry(nj + 3 + k) = dw(k);
        }
    }
}

// The rows both residual models share, for pose k at (x, y): the legs, (predicted - measured) /
// sigma (with their derivatives), then y_c / sigma_c for the first n_prior corrections (0 where
// sigma_c = 0, an exact reading). jx, jy (when given) are zeroed first.
void legs_and_priors(const Geometry& g, const VectorXd& x, int k, const double* y,
                     const Eigen::Ref<const RowMatrixXd>& q,
                     const Eigen::Ref<const RowMatrixXd>& poses,
                     const Eigen::Ref<const RowMatrixXd>& legs,
                     const Eigen::Ref<const RowMatrixXd>& sigma, int n_prior, double* r,
                     RowMatrixXd* jx, RowMatrixXd* jy, Mat4* frames, double* qt) {
    double lg[kLegs];
    const RowMatrixXd qk = q.row(k), pk = poses.row(k);
    if (jx) {
        jx->setZero();
        jy->setZero();
    }
    pose_legs(g, x.data(), qk.data(), pk.data(), y, lg, jx, jy, 0, frames, qt);
    for (int j = 0; j < kLegs; ++j) {
        const double is = 1.0 / sigma(k, j);
        r[j] = (lg[j] - legs(k, j)) * is;
        if (jx) {
            jx->row(j) *= is;
            jy->row(j) *= is;
        }
    }
    for (int c = 0; c < n_prior; ++c) {
        const double s = sigma(k, kLegs + c);
        r[kLegs + c] = s > 0 ? y[c] / s : 0.0;
        if (jy && s > 0) (*jy)(kLegs + c, c) = 1.0 / s;
    }
}

void check_shape(const Eigen::Ref<const RowMatrixXd>& m, Eigen::Index rows, Eigen::Index cols,
                 const char* what) {
    if (m.rows() != rows || m.cols() != cols) {
        std::ostringstream msg;
        msg << what << ": shape (" << m.rows() << ", " << m.cols() << "); expected (" << rows
            << ", " << cols << ")";
        throw std::invalid_argument(msg.str());
    }
    require_finite(m.data(), m.size(), what);
}

std::vector<int> checked_active(const std::vector<int>& active, int np) {
    std::vector<char> seen(static_cast<size_t>(np), 0);
    for (int i : active) {
        if (i < 0 || i >= np || seen[static_cast<size_t>(i)]) {
            std::ostringstream msg;
            msg << "active: index " << i << " is out of range [0, " << np << ") or repeated";
            throw std::invalid_argument(msg.str());
        }
        seen[static_cast<size_t>(i)] = 1;
    }
    return active;
}

}  // namespace

LoopJacobians loop_jacobians(const Geometry& g, const Eigen::Ref<const VectorXd>& x,
                             const Eigen::Ref<const RowMatrixXd>& q,
                             const Eigen::Ref<const RowMatrixXd>& poses,
                             const Eigen::Ref<const RowMatrixXd>& corrections) {
    g.check_errors(x.data(), x.size(), "x");
    require_pose_shapes(g, q, poses, "poses");
    require_finite(q.data(), q.size(), "q");
    require_finite(poses.data(), poses.size(), "poses");
    const Eigen::Index n = poses.rows();
    const int nj = g.n_joints(), ny = nj + 6;
    RowMatrixXd corr = RowMatrixXd::Zero(n, ny);
    if (corrections.size() != 0) {
        check_shape(corrections, n, ny, "corrections");
        corr = corrections;
    }
    LoopJacobians out;
    out.legs.resize(n, kLegs);
    out.jac_x.resize(kLegs * n, g.n_params());
    out.jac_y.resize(kLegs * n, ny);
    std::vector<Mat4> frames(static_cast<size_t>(nj) + 1);
    std::vector<double> qt(static_cast<size_t>(nj) + 1);
    for (Eigen::Index k = 0; k < n; ++k) {
        const RowMatrixXd qk = q.row(k), pk = poses.row(k);
        pose_legs(g, x.data(), qk.data(), pk.data(), corr.row(k).data(), out.legs.row(k).data(),
                  &out.jac_x, &out.jac_y, static_cast<int>(kLegs * k), frames.data(), qt.data());
    }
    return out;
}

LoopModel pose_loop_model(const Geometry& g, const Eigen::Ref<const RowMatrixXd>& q,
                          const Eigen::Ref<const RowMatrixXd>& poses,
                          const Eigen::Ref<const RowMatrixXd>& legs,
                          const Eigen::Ref<const RowMatrixXd>& sigma) {
    const int n = static_cast<int>(poses.rows());
    const int nj = g.n_joints(), ny = nj + 6;
    LoopModel model;
    model.n = n;
    model.ny = ny;
    model.nr = kLegs + ny;
    model.np = g.n_params();
    model.free.resize(static_cast<size_t>(n));
    model.rows.resize(static_cast<size_t>(n));
    for (int k = 0; k < n; ++k) {
        auto& rows = model.rows[static_cast<size_t>(k)];
        for (int j = 0; j < kLegs; ++j) rows.push_back(j);
        for (int c = 0; c < ny; ++c) {
            if (sigma(k, kLegs + c) > 0) {
                model.free[static_cast<size_t>(k)].push_back(c);
                rows.push_back(kLegs + c);
            }
        }
    }
    auto frames = std::make_shared<std::vector<Mat4>>(static_cast<size_t>(nj) + 1);
    auto qt = std::make_shared<std::vector<double>>(static_cast<size_t>(nj) + 1);
    // The inputs by value: Refs onto the caller's arrays, which outlive the model.
    model.eval = [&g, q, poses, legs, sigma, frames, qt, ny](const VectorXd& x, int k, const double* y,
                                                              double* r, RowMatrixXd* jx, RowMatrixXd* jy) {
        legs_and_priors(g, x, k, y, q, poses, legs, sigma, ny, r, jx, jy, frames->data(), qt->data());
    };
    return model;
}

ImplicitLoopResult implicit_loop(const Geometry& g, const Eigen::Ref<const VectorXd>& x0,
                                 const std::vector<int>& active,
                                 const Eigen::Ref<const RowMatrixXd>& q,
                                 const Eigen::Ref<const RowMatrixXd>& poses,
                                 const Eigen::Ref<const RowMatrixXd>& legs,
                                 const Eigen::Ref<const RowMatrixXd>& sigma,
                                 const Eigen::Ref<const RowMatrixXd>& corrections0,
                                 const ImplicitLoopOptions& options,
                                 const LoopCallback& callback) {
    // --- checks ---------------------------------------------------------------------------------
    g.check_errors(x0.data(), x0.size(), "x0");
    require_pose_shapes(g, q, poses, "poses");
    require_pose_shapes(g, q, legs, "legs");
    require_finite(q.data(), q.size(), "q");
    require_finite(poses.data(), poses.size(), "poses");
    require_finite(legs.data(), legs.size(), "legs");
    const int n = static_cast<int>(poses.rows());
    const int nj = g.n_joints(), ny = nj + 6, nr = kLegs + ny, np = g.n_params();
    if (n < 1) throw std::invalid_argument("poses: no pose given");
    check_shape(sigma, n, nr, "sigma");
    for (int k = 0; k < n; ++k) {
        for (int c = 0; c < nr; ++c) {
            const double s = sigma(k, c);
            if (c < kLegs ? !(s > 0) : !(s >= 0)) {
                std::ostringstream msg;
                msg << "sigma: entry (" << k << ", " << c << ") is " << s << "; the leg readings"
                    << " need a standard deviation > 0, the other readings >= 0 (0: exact)";
                throw std::invalid_argument(msg.str());
            }
        }
    }
    RowMatrixXd corr = RowMatrixXd::Zero(n, ny);
    if (corrections0.size() != 0) {
        check_shape(corrections0, n, ny, "corrections0");
        corr = corrections0;
    }
    checked_active(active, np);
    if (options.two_stage && corr.isZero(0.0) && !sigma.rightCols(ny).isZero(0.0)) {
        RowMatrixXd s1 = sigma;
        s1.rightCols(ny).setZero();
        ImplicitLoopOptions o1 = options;
        o1.two_stage = false;
        o1.statistics = false;
        o1.ftol = std::max(options.ftol, 1e-8);
        const ImplicitLoopResult r1 =
            implicit_loop(g, x0, active, q, poses, legs, s1, RowMatrixXd(), o1, callback);
        ImplicitLoopOptions o2 = options;
        o2.two_stage = false;
        ImplicitLoopResult r2 = r1.status == -1 ? r1 : implicit_loop(g, r1.x, active, q, poses, legs,
                                                                      sigma, RowMatrixXd(), o2, callback);
        if (r1.status == -1) {  // stopped by the callback: statistics of the full problem anyway
            o2.max_iterations = 0;
            r2 = implicit_loop(g, r1.x, active, q, poses, legs, sigma, RowMatrixXd(), o2, LoopCallback());
            r2.status = -1;
            r2.message = r1.message;
        }
        r2.iterations += r1.iterations;
        r2.nfev += r1.nfev;
        return r2;
    }
    // The pose model: legs (predicted - measured) / sigma, then each free correction / sigma.
    const LoopModel model = pose_loop_model(g, q, poses, legs, sigma);
    for (int k = 0; k < n; ++k)
        for (int c = 0; c < ny; ++c)
            if (!(sigma(k, kLegs + c) > 0)) corr(k, c) = 0;  // an exact reading has no correction
    return solve_loop(model, x0, active, corr, options, callback);
}

ImplicitLoopResult solve_loop(const LoopModel& model, const Eigen::Ref<const VectorXd>& x0,
                              const std::vector<int>& active,
                              const Eigen::Ref<const RowMatrixXd>& corrections0,
                              const ImplicitLoopOptions& options, const LoopCallback& callback) {
    const int n = model.n, ny = model.ny, nr = model.nr, np = model.np;
    const int p = static_cast<int>(active.size());
    RowMatrixXd corr = corrections0;
    RowMatrixXd jx(nr, np), jy(nr, ny);

    // Normalised residuals of pose k into rk (nr).
    auto residuals_of = [&](const VectorXd& x, const RowMatrixXd& cr, int k, double* rk,
                            bool jac) {
        model.eval(x, k, cr.row(k).data(), rk, jac ? &jx : nullptr, jac ? &jy : nullptr);
    };
    auto total_cost = [&](const VectorXd& x, const RowMatrixXd& cr) {
        double cost = 0;
        std::vector<double> rk(static_cast<size_t>(nr));
        for (int k = 0; k < n; ++k) {
            residuals_of(x, cr, k, rk.data(), false);
            for (int c : model.rows[static_cast<size_t>(k)]) cost += rk[static_cast<size_t>(c)] *
                                                                     rk[static_cast<size_t>(c)];
        }
        return cost;
    };

    // Normal equations, per pose over its live rows: A = d r / d x_active, B = d r / d y_free.
    // U = sum A^T A, W_k = A^T B, V_k = B^T B, gradients gx = sum A^T r, gy_k = B^T r. (A
    // correction's own row, y / sigma, is one of the rows: V_k is positive definite through it.)
    MatX U(p, p);
    VecX gx(p);
    std::vector<MatX> W(static_cast<size_t>(n)), V(static_cast<size_t>(n)),
        A(static_cast<size_t>(n)), B(static_cast<size_t>(n));
    std::vector<VecX> gy(static_cast<size_t>(n)), rr(static_cast<size_t>(n));
    auto build = [&](const VectorXd& x, const RowMatrixXd& cr) {
        U.setZero();
        gx.setZero();
        double cost = 0;
        std::vector<double> rk(static_cast<size_t>(nr));
        for (int k = 0; k < n; ++k) {
            const auto& fr = model.free[static_cast<size_t>(k)];
            const auto& rows = model.rows[static_cast<size_t>(k)];
            const int m = static_cast<int>(fr.size()), nrow = static_cast<int>(rows.size());
            residuals_of(x, cr, k, rk.data(), true);
            MatX& a = A[static_cast<size_t>(k)];
            MatX& b = B[static_cast<size_t>(k)];
            a.resize(nrow, p);
            b.resize(nrow, m);
            VecX rl(nrow);
            for (int j = 0; j < nrow; ++j) {
                const int c = rows[static_cast<size_t>(j)];
                for (int i = 0; i < p; ++i) a(j, i) = jx(c, active[static_cast<size_t>(i)]);
                for (int i = 0; i < m; ++i) b(j, i) = jy(c, fr[static_cast<size_t>(i)]);
                rl(j) = rk[static_cast<size_t>(c)];
                cost += rl(j) * rl(j);
            }
            rr[static_cast<size_t>(k)] = rl;
            U.noalias() += a.transpose() * a;
            gx.noalias() += a.transpose() * rl;
            W[static_cast<size_t>(k)].noalias() = a.transpose() * b;
            V[static_cast<size_t>(k)].noalias() = b.transpose() * b;
            gy[static_cast<size_t>(k)].noalias() = b.transpose() * rl;
        }
        return cost;
    };

    ImplicitLoopResult res;
    VectorXd x = x0;
    int nfev = 0, iter = 0;
    double cost = build(x, corr);
    nfev += 2;
    double lambda = options.initial_lambda, nu = 2.0;
    int status = 0;
    std::string message;
    std::vector<VecX> dy(static_cast<size_t>(n));
    std::vector<Eigen::LDLT<MatX>> vfac(static_cast<size_t>(n));
    std::vector<MatX> vwt(static_cast<size_t>(n));
    std::vector<VecX> vg(static_cast<size_t>(n));
    MatX S0;
    VecX rhs0, du;
    bool schur_ready = false;
    const double tiny = std::numeric_limits<double>::min();
    bool fresh = true;  // normal equations built at the current point
    while (true) {
        if (cost <= tiny) {
            status = 4;
            message = "the residuals are zero";
            break;
        }
        if (iter >= options.max_iterations) {
            status = 0;
            message = "iteration limit reached (max_iterations=" +
                      std::to_string(options.max_iterations) + ")";
            break;
        }
        if (!fresh) {
            cost = build(x, corr);
            nfev += 2;
            fresh = true;
            schur_ready = false;
        }
        // Gradient test, scaled by the diagonal of the normal matrix (a cosine, as MINPACK's).
        double gmax = 0;
        for (int i = 0; i < p; ++i)
            gmax = std::max(gmax, std::abs(gx(i)) / std::sqrt(std::max(U(i, i), tiny) * cost));
        if (gmax <= options.gtol) {
            status = 3;
            message = "the gradient is below gtol";
            break;
        }
        ++iter;
        // The reduced normal matrix S = U - sum W V^-1 W^T, once per point (rejected steps reuse
        // it). Damping lambda diag(S) on the parameters only: the nuisance blocks V are positive
        // definite through their priors, and damping U's diagonal instead would over-damp the
        // weak directions, where S is much smaller than U (seen: 13 iterations instead of 4).
        if (!schur_ready) {
            S0 = U;
            rhs0 = -gx;
            for (int k = 0; k < n; ++k) {
                const size_t kk = static_cast<size_t>(k);
                vfac[kk].compute(V[kk]);
                vwt[kk] = vfac[kk].solve(W[kk].transpose());  // m x p
                vg[kk] = vfac[kk].solve(gy[kk]);
                S0.noalias() -= W[kk] * vwt[kk];
                rhs0.noalias() += W[kk] * vg[kk];
            }
            double dmax = 0;
            for (int i = 0; i < p; ++i) dmax = std::max(dmax, S0(i, i));
            du.resize(p);
            for (int i = 0; i < p; ++i) du(i) = std::max(S0(i, i), 1e-12 * dmax);
            schur_ready = true;
        }
        MatX S = S0;
        S.diagonal() += lambda * du;
        // Jacobi scaling before the factorisation: mm and rad columns differ by orders of
        // magnitude.
        VecX d = S.diagonal().cwiseMax(tiny).cwiseSqrt().cwiseInverse();
        const MatX Ss = d.asDiagonal() * S * d.asDiagonal();
        Eigen::LDLT<MatX> sfac(Ss);
        const VecX dx = d.asDiagonal() * sfac.solve(d.asDiagonal() * rhs0);
        double gd = gx.dot(dx), ddd = (dx.array().square() * du.array()).sum();
        double step2 = ddd, xn2 = 0;
        for (int i = 0; i < p; ++i) {
            const double xi = x(active[static_cast<size_t>(i)]);
            xn2 += xi * xi * du(i);
        }
        for (int k = 0; k < n; ++k) {
            const size_t kk = static_cast<size_t>(k);
            dy[kk] = -vg[kk] - vwt[kk] * dx;
            const VecX& sy = dy[kk];
            const auto vd = V[kk].diagonal();
            gd += gy[kk].dot(sy);
            step2 += (sy.array().square() * vd.array()).sum();
            const auto& fr = model.free[kk];
            for (size_t i = 0; i < fr.size(); ++i) {
                const double c = corr(k, fr[i]);
                xn2 += c * c * vd(static_cast<Eigen::Index>(i));
            }
        }
        // Predicted reduction of the cost sum r^2 by the linear model: -2 g.d - d^T J^T J d
        // = -g.d + lambda d^T D d (from (J^T J + lambda D) d = -g).
        const double predicted = -gd + lambda * ddd;
        VectorXd xt = x;
        for (int i = 0; i < p; ++i) xt(active[static_cast<size_t>(i)]) += dx(i);
        RowMatrixXd ct = corr;
        for (int k = 0; k < n; ++k) {
            const auto& fr = model.free[static_cast<size_t>(k)];
            for (size_t i = 0; i < fr.size(); ++i)
                ct(k, fr[i]) += dy[static_cast<size_t>(k)](static_cast<Eigen::Index>(i));
        }
        const double ct_cost = xt.allFinite() && ct.allFinite()
                                   ? total_cost(xt, ct)
                                   : std::numeric_limits<double>::infinity();
        ++nfev;
        const double actual = cost - ct_cost;
        const bool small_step = std::sqrt(step2) <= options.xtol * (std::sqrt(xn2) + options.xtol);
        if (actual > 0 && std::isfinite(ct_cost)) {
            const double rho = predicted > 0 ? actual / predicted : 0;
            x = xt;
            corr = ct;
            const double old = cost;
            cost = ct_cost;
            fresh = false;
            lambda *= std::max(1.0 / 3.0, 1.0 - std::pow(2.0 * rho - 1.0, 3));
            nu = 2.0;
            if (callback && callback(iter, x, cost)) {
                status = -1;
                message = "stopped by the callback";
                break;
            }
            if (actual <= options.ftol * old) {
                status = 1;
                message = "the cost changes by less than ftol";
                break;
            }
            if (small_step) {
                status = 2;
                message = "the step is below xtol";
                break;
            }
        } else {
            // At rounding level the model predicts no gain and no step helps: converged.
            // (Only while the damping is mild: a heavily damped step predicts little anyway.)
            if (lambda <= 1.0 && (predicted <= options.ftol * cost || small_step)) {
                status = predicted <= options.ftol * cost ? 1 : 2;
                message = status == 1 ? "the cost changes by less than ftol"
                                      : "the step is below xtol";
                break;
            }
            lambda *= nu;
            nu *= 2.0;
            if (lambda > 1e16) {
                status = -2;
                message = "no step lowers the cost (damping exhausted)";
                break;
            }
        }
    }

    // --- statistics at the solution ----------------------------------------------------------
    if (!fresh) {
        cost = build(x, corr);
        nfev += 2;
    }
    res.x = x;
    if (!options.statistics) {
        res.corrections = corr;
        res.cost = cost;
        res.iterations = iter;
        res.nfev = nfev;
        res.status = status;
        res.message = message;
        return res;
    }
    res.corrections = corr;
    res.cost = cost;
    res.iterations = iter;
    res.nfev = nfev;
    res.status = status;
    res.message = message;
    res.residuals = RowMatrixXd::Zero(n, nr);
    res.redundancy = RowMatrixXd::Zero(n, nr);
    res.pose_statistic = VecX::Zero(n);
    res.pose_dof = Eigen::VectorXi::Zero(n);
    // Undamped reduced normal matrix S = U - sum W V^-1 W^T and its inverse, the covariance.
    MatX S = U;
    for (int k = 0; k < n; ++k) {
        vfac[static_cast<size_t>(k)].compute(V[static_cast<size_t>(k)]);
        const MatX& w = W[static_cast<size_t>(k)];
        S.noalias() -= w * vfac[static_cast<size_t>(k)].solve(w.transpose());
    }
    MatX C = MatX::Zero(p, p);
    if (p > 0) {
        VecX d = S.diagonal().cwiseMax(tiny).cwiseSqrt().cwiseInverse();
        const MatX Ss = d.asDiagonal() * S * d.asDiagonal();
        Eigen::SelfAdjointEigenSolver<MatX> es(Ss);
        const VecX ev = es.eigenvalues();
        res.reciprocal_condition = ev(p - 1) > 0 ? std::max(ev(0), 0.0) / ev(p - 1) : 0.0;
        // Pseudo-inverse: directions at rounding level get no variance (the caller is told by
        // reciprocal_condition that the active set is not identifiable).
        const double cut = ev(p - 1) * p * std::numeric_limits<double>::epsilon();
        VecX inv(p);
        for (int i = 0; i < p; ++i) inv(i) = ev(i) > cut ? 1.0 / ev(i) : 0.0;
        C = d.asDiagonal() * (es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose()) *
            d.asDiagonal();
    } else {
        res.reciprocal_condition = 1.0;
    }
    res.covariance = C;
    // Per pose: H_kk = B V^-1 B^T + E C E^T with E = A - B V^-1 W^T over the pose's live rows,
    // Q_vv,kk = I - H_kk.
    std::vector<double> rk(static_cast<size_t>(nr));
    int n_rows = 0, n_free = 0;
    for (int k = 0; k < n; ++k) {
        const auto& rows_k = model.rows[static_cast<size_t>(k)];
        const int rows = static_cast<int>(rows_k.size());
        n_rows += rows;
        n_free += static_cast<int>(model.free[static_cast<size_t>(k)].size());
        const MatX& Ja = A[static_cast<size_t>(k)];
        const MatX& Jb = B[static_cast<size_t>(k)];
        const VecX& v = rr[static_cast<size_t>(k)];
        residuals_of(x, corr, k, rk.data(), false);
        for (int c = 0; c < nr; ++c) res.residuals(k, c) = rk[static_cast<size_t>(c)];
        const auto& vf = vfac[static_cast<size_t>(k)];
        const MatX E = Ja - Jb * vf.solve(W[static_cast<size_t>(k)].transpose());
        MatX H = Jb * vf.solve(Jb.transpose()) + E * C * E.transpose();
        const MatX Q = MatX::Identity(rows, rows) - H;
        for (int j = 0; j < rows; ++j) res.redundancy(k, rows_k[static_cast<size_t>(j)]) = Q(j, j);
        Eigen::SelfAdjointEigenSolver<MatX> es(Q);
        const VecX proj = es.eigenvectors().transpose() * v;
        double t = 0;
        int dof = 0;
        for (int i = 0; i < rows; ++i) {
            if (es.eigenvalues()(i) > 1e-8) {
                t += proj(i) * proj(i) / es.eigenvalues()(i);
                ++dof;
            }
        }
        res.pose_statistic(k) = t;
        res.pose_dof(k) = dof;
    }
    res.dof = n_rows - n_free - p;
    return res;
}

// The tracker model of implicit_loop_tracker (see the header), on checked inputs.
LoopModel tracker_loop_model(const Geometry& g, const TrackerLoopData& data,
                        const Eigen::Ref<const RowMatrixXd>& q,
                        const Eigen::Ref<const RowMatrixXd>& legs,
                        const Eigen::Ref<const RowMatrixXd>& sigma) {
    const TrackerSetup& setup = data.setup;
    const bool probe = setup.kind() == TrackerKind::Probe;
    const int n = static_cast<int>(legs.rows()), nj = g.n_joints(), npr = g.n_params();
    const int nb = probe ? 2 : setup.n_points();
    LoopModel model;
    model.n = n;
    model.ny = nj + 6;
    model.nr = kLegs + nj + 3 * nb;
    model.np = npr + setup.n_params();
    model.free.resize(static_cast<size_t>(n));
    model.rows.resize(static_cast<size_t>(n));
    for (int k = 0; k < n; ++k) {
        auto& fr = model.free[static_cast<size_t>(k)];
        auto& rows = model.rows[static_cast<size_t>(k)];
        for (int j = 0; j < kLegs; ++j) rows.push_back(j);
        for (int c = 0; c < nj; ++c) {
            if (sigma(k, kLegs + c) > 0) {
                fr.push_back(c);
                rows.push_back(kLegs + c);
            }
        }
        for (int c = nj; c < nj + 6; ++c) fr.push_back(c);  // the true pose: always unknown
        for (int b = 0; b < nb; ++b) {
            if (!probe && std::isnan(data.measured(k, 3 * b))) continue;  // not seen
            for (int c = 0; c < 3; ++c) rows.push_back(kLegs + nj + 3 * b + c);
        }
    }
    const Mat3 r_nom = euler_zyx(setup.registration()(3), setup.registration()(4),
                                 setup.registration()(5));
    struct Scratch {
        std::vector<Mat4> frames;
        std::vector<double> qt;
        std::vector<Vec3> pts;
    };
    auto sc = std::make_shared<Scratch>();
    sc->frames.resize(static_cast<size_t>(nj) + 1);
    sc->qt.resize(static_cast<size_t>(nj) + 1);
    sc->pts.resize(static_cast<size_t>(setup.n_points()));
    model.eval = [&g, &data, &setup, q, legs, sigma, sc, r_nom, probe, nb, nj, npr](
                     const VectorXd& x, int k, const double* y, double* r, RowMatrixXd* jx,
                     RowMatrixXd* jy) {
        const int nr = kLegs + nj + 3 * nb;
        for (int c = 0; c < nr; ++c) r[c] = 0.0;
        legs_and_priors(g, x, k, y, q, data.reference, legs, sigma, nj, r, jx, jy,
                        sc->frames.data(), sc->qt.data());
        const RowMatrixXd pk = data.reference.row(k);
        // The true platform pose in {0} and the setup's transforms at x.
        const double* xs = x.data() + npr;
        const Vec3 w(y[nj + 3], y[nj + 4], y[nj + 5]), rr(xs[3], xs[4], xs[5]);
        Mat3 ew, jrw, jrr;
        so3_exp(w, &ew, &jrw);
        so3_exp(rr, nullptr, &jrr);
        const Mat3 r5 = euler_zyx(pk(0, 3), pk(0, 4), pk(0, 5)) * ew;
        const Vec3 p5 = Vec3(pk(0, 0), pk(0, 1), pk(0, 2)) + Vec3(y[nj], y[nj + 1], y[nj + 2]);
        Mat3 rreg;
        Vec3 treg;
        setup.registration_transform(xs, rreg, treg);
        setup.platform_points(xs + 6, sc->pts.data());
        const Mat3 rreg5 = rreg * r5;
        const int row0 = kLegs + nj, col_t = npr, col_o = npr + 6;
        // One point o (in {5}) measured at m with whitening wm: residual rows row, derivatives
        // with respect to the registration, the pose and (offset_col >= 0) its offset.
        auto point = [&](const Vec3& o, const double* m, const double* wm, int row,
                         int offset_col) {
            const Map3c wmat(wm);
            const Vec3 p0 = p5 + r5 * o;
            const Vec3 e = rreg * p0 + treg - Vec3(m[0], m[1], m[2]);
            const Vec3 we = wmat * e;
            for (int c = 0; c < 3; ++c) r[row + c] = we(c);
            if (!jx) return;
            jx->block<3, 3>(row, col_t) = wmat * r_nom;
            jx->block<3, 3>(row, col_t + 3) = -wmat * rreg * skew(p0) * jrr;
            if (offset_col >= 0) jx->block<3, 3>(row, offset_col) = wmat * rreg5;
            jy->block<3, 3>(row, nj) = wmat * rreg;
            jy->block<3, 3>(row, nj + 3) = -wmat * rreg5 * skew(o) * jrw;
        };
        if (!probe) {
            for (int i = 0; i < nb; ++i) {
                const double* m = data.measured.row(k).data() + 3 * i;
                if (std::isnan(m[0])) continue;
                point(sc->pts[static_cast<size_t>(i)], m, data.whitening.row(k).data() + 9 * i,
                      row0 + 3 * i, col_o + 3 * i);
            }
            return;
        }
        // Probe: its origin as a point, then its orientation residual e = vee(asym(R_pred R_m^T)),
        // whose derivative for a left perturbation phi of R_pred (in {T}) is (tr(R_e) I - R_e)/2.
        const double* m = data.measured.row(k).data();
        point(sc->pts[0], m, data.whitening.row(k).data(), row0, col_o);
        const double len = setup.probe_length();
        Mat3 rp;
        for (int c = 0; c < 3; ++c) rp.col(c) = (sc->pts[static_cast<size_t>(c) + 1] - sc->pts[0]) / len;
        const Mat3 re = rreg5 * rp * euler_zyx(m[3], m[4], m[5]).transpose();
        const Vec3 e(0.5 * (re(2, 1) - re(1, 2)), 0.5 * (re(0, 2) - re(2, 0)),
                     0.5 * (re(1, 0) - re(0, 1)));
        const Map3c wo(data.whitening.row(k).data() + 9);
        const Vec3 we = wo * e;
        for (int c = 0; c < 3; ++c) r[row0 + 3 + c] = we(c);
        if (!jx) return;
        const Mat3 dm = wo * (0.5 * (re.trace() * Mat3::Identity() - re));
        const Vec3 rho(xs[9], xs[10], xs[11]);
        Mat3 erho, jrho;
        so3_exp(rho, &erho, &jrho);
        jx->block<3, 3>(row0 + 3, col_t + 3) = dm * rreg * jrr;
        jx->block<3, 3>(row0 + 3, col_o + 3) = dm * rreg5 * jrho.transpose();  // J_l = J_r^T
        jy->block<3, 3>(row0 + 3, nj + 3) = dm * rreg5 * jrw;
    };
    return model;
}

namespace {

void check_tracker_inputs(const Geometry& g, const TrackerLoopData& data,
                          const Eigen::Ref<const RowMatrixXd>& q,
                          const Eigen::Ref<const RowMatrixXd>& legs,
                          const Eigen::Ref<const RowMatrixXd>& sigma) {
    require_pose_shapes(g, q, legs, "legs");
    require_finite(q.data(), q.size(), "q");
    require_finite(legs.data(), legs.size(), "legs");
    const int n = static_cast<int>(legs.rows()), nj = g.n_joints();
    if (n < 1) throw std::invalid_argument("legs: no pose given");
    const bool probe = data.setup.kind() == TrackerKind::Probe;
    const int nb = probe ? 2 : data.setup.n_points();
    check_shape(data.reference, n, 6, "reference");
    check_shape(data.whitening, n, 9 * nb, "whitening");
    check_shape(sigma, n, kLegs + nj, "sigma");
    if (data.measured.rows() != n || data.measured.cols() != (probe ? 6 : 3 * nb)) {
        std::ostringstream msg;
        msg << "measured: shape (" << data.measured.rows() << ", " << data.measured.cols()
            << "); expected (" << n << ", " << (probe ? 6 : 3 * nb) << ")";
        throw std::invalid_argument(msg.str());
    }
    for (int k = 0; k < n; ++k) {
        for (int c = 0; c < kLegs + nj; ++c) {
            const double s = sigma(k, c);
            if (c < kLegs ? !(s > 0) : !(s >= 0)) {
                std::ostringstream msg;
                msg << "sigma: entry (" << k << ", " << c << ") is " << s << "; the leg readings"
                    << " need a standard deviation > 0, the joint readings >= 0 (0: exact)";
                throw std::invalid_argument(msg.str());
            }
        }
        for (int b = 0; b < (probe ? 1 : nb); ++b) {
            const int w = probe ? 6 : 3;
            int nan = 0;
            for (int c = 0; c < w; ++c) nan += std::isnan(data.measured(k, w * b + c)) ? 1 : 0;
            const bool bad_inf = !probe && nan == 0 && !data.measured.row(k).segment(3 * b, 3).allFinite();
            if ((nan != 0 && (probe || nan != 3)) || bad_inf ||
                (probe && !data.measured.row(k).allFinite())) {
                std::ostringstream msg;
                msg << "measured: pose " << k << (probe ? "" : ", reflector " + std::to_string(b + 1))
                    << " is not finite" << (probe ? "" : " (an unseen point has all three NaN)");
                throw std::invalid_argument(msg.str());
            }
        }
    }
}

}  // namespace

LoopJacobians tracker_loop_jacobians(const Geometry& g, const TrackerLoopData& data,
                                     const Eigen::Ref<const VectorXd>& x,
                                     const Eigen::Ref<const RowMatrixXd>& q,
                                     const Eigen::Ref<const RowMatrixXd>& legs,
                                     const Eigen::Ref<const RowMatrixXd>& sigma,
                                     const Eigen::Ref<const RowMatrixXd>& corrections) {
    check_tracker_inputs(g, data, q, legs, sigma);
    const LoopModel model = tracker_loop_model(g, data, q, legs, sigma);
    if (x.size() != model.np) {
        throw std::invalid_argument("x: " + std::to_string(x.size()) + " values; expected " +
                                    std::to_string(model.np));
    }
    require_finite(x.data(), x.size(), "x");
    RowMatrixXd corr = RowMatrixXd::Zero(model.n, model.ny);
    if (corrections.size() != 0) {
        check_shape(corrections, model.n, model.ny, "corrections");
        corr = corrections;
    }
    LoopJacobians out;
    out.legs.resize(model.n, model.nr);
    out.jac_x.resize(static_cast<Eigen::Index>(model.nr) * model.n, model.np);
    out.jac_y.resize(static_cast<Eigen::Index>(model.nr) * model.n, model.ny);
    RowMatrixXd jx(model.nr, model.np), jy(model.nr, model.ny);
    const VectorXd xv = x;
    for (int k = 0; k < model.n; ++k) {
        model.eval(xv, k, corr.row(k).data(), out.legs.row(k).data(), &jx, &jy);
        out.jac_x.middleRows(static_cast<Eigen::Index>(model.nr) * k, model.nr) = jx;
        out.jac_y.middleRows(static_cast<Eigen::Index>(model.nr) * k, model.nr) = jy;
    }
    return out;
}

ImplicitLoopResult implicit_loop_tracker(const Geometry& g, const TrackerLoopData& data,
                                         const Eigen::Ref<const VectorXd>& x0,
                                         const std::vector<int>& active,
                                         const Eigen::Ref<const RowMatrixXd>& q,
                                         const Eigen::Ref<const RowMatrixXd>& legs,
                                         const Eigen::Ref<const RowMatrixXd>& sigma,
                                         const Eigen::Ref<const RowMatrixXd>& corrections0,
                                         const ImplicitLoopOptions& options,
                                         const LoopCallback& callback) {
    check_tracker_inputs(g, data, q, legs, sigma);
    const LoopModel model = tracker_loop_model(g, data, q, legs, sigma);
    if (x0.size() != model.np) {
        throw std::invalid_argument("x0: " + std::to_string(x0.size()) + " values; expected " +
                                    std::to_string(model.np) + " (the robot's, then the setup's)");
    }
    require_finite(x0.data(), x0.size(), "x0");
    checked_active(active, model.np);
    RowMatrixXd corr = RowMatrixXd::Zero(model.n, model.ny);
    if (corrections0.size() != 0) {
        check_shape(corrections0, model.n, model.ny, "corrections0");
        corr = corrections0;
    }
    for (int k = 0; k < model.n; ++k)
        for (int c = 0; c < g.n_joints(); ++c)
            if (!(sigma(k, kLegs + c) > 0)) corr(k, c) = 0;  // an exact reading: no correction
    return solve_loop(model, x0, active, corr, options, callback);
}

}  // namespace iwr
