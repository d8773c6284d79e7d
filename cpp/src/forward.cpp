#include "iwr/forward.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

namespace iwr {

namespace {

using Matrix6d = Eigen::Matrix<double, 6, 6>;

// Below this inverse condition number (of the Jacobian with its angle columns scaled by the
// platform radius, so that every column is in mm) a Newton step is meaningless.
constexpr double kMinRcond = 1e-12;
// Halvings of the Newton step before the line search gives up.
constexpr int kMaxHalvings = 40;

std::string format_pose(const Vector6d& p) {
    std::ostringstream s;
    s.precision(6);
    s << "(" << p(0) << ", " << p(1) << ", " << p(2) << ", " << p(3) << ", " << p(4) << ", " << p(5)
      << ")";
    return s.str();
}

std::string where(Eigen::Index pose_index) {
    if (pose_index < 0) return "forward kinematics: ";
    return "forward kinematics: pose " + std::to_string(pose_index) + ": ";
}

}  // namespace

LegVector hexapod_leg_lengths(const LegMatrix& base, const LegMatrix& platform,
                              const Vector6d& pose, LegJacobian* jac) {
    const double ca = std::cos(pose(3)), sa = std::sin(pose(3));
    const double cb = std::cos(pose(4)), sb = std::sin(pose(4));
    const Mat3 r = euler_zyx(pose(3), pose(4), pose(5));
    const Vec3 p = pose.head<3>();
    // With R = Rz(alpha) Ry(beta) Rx(gamma) (eq. 6) and w = R b:
    //   dR/dalpha b = ez x w,   dR/dbeta b = (Rz ey) x w,   dR/dgamma b = (R ex) x w,
    // so d l / d angle_k = u . (k x w) = (w x u) . k for the axes k below (u the unit leg vector).
    const Vec3 kz(0.0, 0.0, 1.0);
    const Vec3 ky(-sa, ca, 0.0);
    const Vec3 kx(ca * cb, sa * cb, -sb);
    LegVector len;
    for (int j = 0; j < kLegs; ++j) {
        const Vec3 w = r * platform.row(j).transpose();
        const Vec3 v = p + w - base.row(j).transpose();
        len(j) = v.norm();
        if (jac) {
            const Vec3 u = v / len(j);
            const Vec3 m = w.cross(u);
            jac->row(j) << u(0), u(1), u(2), m.dot(kz), m.dot(ky), m.dot(kx);
        }
    }
    return len;
}

HexapodSolution hexapod_forward(const LegMatrix& base, const LegMatrix& platform,
                                const LegVector& lengths, const Vector6d& guess,
                                const ForwardOptions& options, Eigen::Index pose_index) {
    if (!(std::isfinite(options.tolerance) && options.tolerance > 0)) {
        std::ostringstream msg;
        msg << "tolerance: " << options.tolerance << "; expected a finite number > 0 (mm)";
        throw std::invalid_argument(msg.str());
    }
    if (options.max_iterations < 1) {
        throw std::invalid_argument("max_iterations: " + std::to_string(options.max_iterations) +
                                    "; expected a positive integer");
    }
    require_finite(guess.data(), guess.size(), "guess");
    for (int j = 0; j < kLegs; ++j) {
        if (!(std::isfinite(lengths(j)) && lengths(j) > 0)) {
            std::ostringstream msg;
            msg << where(pose_index) << "leg " << j + 1 << " has length " << lengths(j)
                << " mm (reading + offset); a leg length must be finite and > 0";
            throw std::invalid_argument(msg.str());
        }
    }
    double scale = 1.0;  // platform radius (mm): converts the angle columns to mm
    for (int j = 0; j < kLegs; ++j) scale = std::max(scale, platform.row(j).norm());

    HexapodSolution sol;
    sol.pose = guess;
    LegJacobian jac;
    LegVector f = hexapod_leg_lengths(base, platform, sol.pose, &jac) - lengths;
    double err = f.cwiseAbs().maxCoeff();
    for (int it = 0;; ++it) {
        if (err <= options.tolerance) {
            sol.iterations = it;
            sol.residual = err;
            return sol;
        }
        if (it == options.max_iterations) break;
        Matrix6d scaled = jac;
        scaled.rightCols<3>() /= scale;
        const Eigen::JacobiSVD<Matrix6d> svd(scaled);
        const auto& sv = svd.singularValues();
        const double rcond = sv(0) > 0 ? sv(5) / sv(0) : 0.0;
        if (!(rcond > kMinRcond)) {
            std::ostringstream msg;
            msg << where(pose_index) << "the Jacobian of the leg lengths is singular (inverse "
                << "condition number " << rcond << ") at local pose " << format_pose(sol.pose)
                << " after " << it << " iterations: a singular configuration of the hexapod; "
                << "try another initial guess";
            throw ForwardKinematicsError(msg.str(), pose_index);
        }
        const Vector6d step = jac.partialPivLu().solve(-f);
        // Backtracking: halve the Newton step until the squared leg residual decreases, which
        // keeps a poor initial guess from jumping to another assembly mode.
        double t = 1.0;
        bool accepted = false;
        LegJacobian jac_new;
        for (int h = 0; h <= kMaxHalvings; ++h, t *= 0.5) {
            const Vector6d trial = sol.pose + t * step;
            const LegVector f_new = hexapod_leg_lengths(base, platform, trial, &jac_new) - lengths;
            if (f_new.allFinite() && f_new.squaredNorm() < f.squaredNorm()) {
                sol.pose = trial;
                f = f_new;
                jac = jac_new;
                accepted = true;
                break;
            }
        }
        if (!accepted) {
            std::ostringstream msg;
            msg << where(pose_index) << "Newton-Raphson stalled after " << it
                << " iterations with a largest leg-length residual of " << err << " mm > tolerance "
                << options.tolerance
                << " mm (no step decreases it): the leg readings may be unreachable for this "
                   "robot, or the tolerance below what double precision can reach";
            throw ForwardKinematicsError(msg.str(), pose_index);
        }
        err = f.cwiseAbs().maxCoeff();
    }
    std::ostringstream msg;
    msg << where(pose_index) << "no convergence in " << options.max_iterations
        << " Newton-Raphson iterations (largest leg-length residual " << err << " mm > tolerance "
        << options.tolerance << " mm): the leg readings may be unreachable for this robot, or "
        << "the initial guess too far from the solution";
    throw ForwardKinematicsError(msg.str(), pose_index);
}

Vec3 euler_from_matrix(const Mat3& r) {
    // As iwr.transforms.euler_from_matrix: exact at and near the gimbal lock (beta = +-pi/2),
    // gamma read from Rz(-alpha) R = Ry(beta) Rx(gamma), whose second row is (0, cg, -sg).
    const double alpha = std::atan2(r(1, 0), r(0, 0));  // 0 where cos(beta) = 0
    const double ca = std::cos(alpha), sa = std::sin(alpha);
    return Vec3(alpha, std::atan2(-r(2, 0), std::hypot(r(0, 0), r(1, 0))),
                std::atan2(sa * r(0, 2) - ca * r(1, 2), ca * r(1, 1) - sa * r(0, 1)));
}

RowMatrixXd forward_kinematics(const Geometry& g, const Eigen::Ref<const VectorXd>& x,
                               const Eigen::Ref<const RowMatrixXd>& q,
                               const Eigen::Ref<const RowMatrixXd>& legs,
                               const Eigen::Ref<const RowMatrixXd>& guess, const Vector6d& home,
                               const ForwardOptions& options, Eigen::VectorXi* iterations) {
    g.check_errors(x.data(), x.size(), "errors");
    require_pose_shapes(g, q, legs, "legs");
    const Eigen::Index n = legs.rows();
    if (guess.rows() != 0 && (guess.rows() != n || guess.cols() != 6)) {
        std::ostringstream msg;
        msg << "guess: shape (" << guess.rows() << ", " << guess.cols() << "); expected (" << n
            << ", 6) or no rows (the home pose)";
        throw std::invalid_argument(msg.str());
    }
    require_finite(q.data(), q.size(), "q");
    require_finite(legs.data(), legs.size(), "legs");
    require_finite(guess.data(), guess.size(), "guess");
    require_finite(home.data(), home.size(), "home");

    const int nj = g.n_joints();
    LegMatrix a = g.base(), b = g.platform();
    LegVector l0 = g.leg_offsets();
    for (int j = 0; j < kLegs; ++j) {
        a.row(j) += Eigen::Map<const Vec3>(x.data() + g.idx_base(j, 0)).transpose();
        b.row(j) += Eigen::Map<const Vec3>(x.data() + g.idx_platform(j, 0)).transpose();
        l0(j) += x[g.idx_offset(j)];
    }
    RowMatrixXd out(n, 6);
    if (iterations) iterations->resize(n);
    for (Eigen::Index k = 0; k < n; ++k) {
        const Mat4 t4 = carriage_transform(g, x.data(), nj ? q.row(k).data() : nullptr);
        const Mat3 r4 = t4.topLeftCorner<3, 3>();
        const Vec3 p4 = t4.topRightCorner<3, 1>();
        Vector6d start = home;
        if (guess.rows()) {
            // 4T5 = (0T4)^-1 0T5 of the world guess.
            const Mat3 r5 = euler_zyx(guess(k, 3), guess(k, 4), guess(k, 5));
            const Vec3 p5(guess(k, 0), guess(k, 1), guess(k, 2));
            start.head<3>() = r4.transpose() * (p5 - p4);
            start.tail<3>() = euler_from_matrix(r4.transpose() * r5);
        }
        const LegVector lengths = legs.row(k).transpose() + l0;
        const HexapodSolution sol = hexapod_forward(a, b, lengths, start, options, k);
        if (iterations) (*iterations)(k) = sol.iterations;
        // 0T5 = 0T4 4T5 (eq. 7).
        const Mat3 r5 = r4 * euler_zyx(sol.pose(3), sol.pose(4), sol.pose(5));
        out.block<1, 3>(k, 0) = (p4 + r4 * sol.pose.head<3>()).transpose();
        out.block<1, 3>(k, 3) = euler_from_matrix(r5).transpose();
    }
    return out;
}

}  // namespace iwr
