// The bar set-ups and closed-form distances shared by the C++ tests of the ballbar objectives
// (test_ballbar.cpp, test_effects_ballbar.cpp).
#pragma once

#include <cmath>
#include <random>
#include <vector>

#include "iwr/ballbar.hpp"
#include "iwr/forward.hpp"
#include "iwr/model.hpp"
#include "iwr/parallel.hpp"
#include "iwr/problem_file.hpp"

namespace iwr_test {

inline std::vector<iwr::BarSetup> two_setups() {
    iwr::BarSetup a, b;
    a.name = "A";
    a.platform_ball << 0, 0, -60;
    a.fixed_ball << 800, -800, 1500;
    b.name = "B-2";
    b.platform_ball << 100, 50, -60;
    b.fixed_ball << 900, -200, 2400;
    b.offset = 0.25;
    b.has_range = true;
    b.range_min = 300, b.range_max = 700;
    return {a, b};
}

// |T_05 P - F| + o for set-up s at x, from the true world pose (Z-Y-X Euler) of {5}.
inline double distance_from_pose(const iwr::BarSetup& b, const double* xs, const iwr::Vector6d& pose) {
    const iwr::Mat3 r = iwr::euler_zyx(pose(3), pose(4), pose(5));
    const iwr::Vec3 p = b.platform_ball + iwr::Vec3(xs[0], xs[1], xs[2]);
    const iwr::Vec3 f = b.fixed_ball + iwr::Vec3(xs[3], xs[4], xs[5]);
    return (pose.head<3>() + r * p - f).norm() + b.offset + xs[6];
}

struct Data {
    iwr::RowMatrixXd q, legs, poses;  // poses: the true world poses of {5}
    std::vector<int> bar;
    iwr::VectorXd distance;
};

// Random carriage readings and local poses of {5} in {4}; the world poses by the carriage of the
// robot with errors x (its first 4 n + 42 entries), the leg readings by its inverse kinematics,
// the bar readings exact at x (set-ups' part included).
inline Data make_data(const iwr::Geometry& g, const std::vector<iwr::BarSetup>& bars, const iwr::VectorXd& x, int n,
               std::mt19937_64& rng) {
    std::uniform_real_distribution<double> u(-1, 1);
    Data d;
    d.q.resize(n, g.n_joints());
    d.poses.resize(n, 6);
    d.distance.resize(n);
    for (int k = 0; k < n; ++k) {
        d.q.row(k) << 1000 * (1 + u(rng)), 500 * (1 + u(rng)), 1.5 * u(rng), 1.0 * u(rng);
        iwr::Mat4 local = iwr::Mat4::Identity();
        local.topLeftCorner<3, 3>() = iwr::euler_zyx(0.15 * u(rng), 0.15 * u(rng), 0.15 * u(rng));
        local.topRightCorner<3, 1>() = iwr::Vec3(100 * u(rng), 100 * u(rng), 750 + 60 * u(rng));
        const iwr::Mat4 world = iwr::carriage_transform(g, x.data(), d.q.row(k).data()) * local;
        d.poses.block<1, 3>(k, 0) = world.topRightCorner<3, 1>().transpose();
        d.poses.block<1, 3>(k, 3) = iwr::euler_from_matrix(world.topLeftCorner<3, 3>()).transpose();
        d.bar.push_back(k % static_cast<int>(bars.size()));
        const int s = d.bar.back();
        d.distance(k) = distance_from_pose(bars[static_cast<std::size_t>(s)],
                                           x.data() + g.n_params() + iwr::kBarParams * s, d.poses.row(k).transpose());
    }
    d.legs = iwr::predict_legs(g, x.head(g.n_params()), d.q, d.poses);
    return d;
}

inline iwr::VectorXd random_x(int n, std::mt19937_64& rng, double scale) {
    std::uniform_real_distribution<double> u(-scale, scale);
    iwr::VectorXd x(n);
    for (int i = 0; i < n; ++i) x(i) = u(rng);
    return x;
}

inline iwr::Vector6d home() {
    iwr::Vector6d h;
    h << 0, 0, 750, 0, 0, 0;
    return h;
}

// Whether obj's batch costs of the rows of X are the same bits from 1, 2 and 5 threads, each its
// row's cost(x), and within 1e-12 of its residuals' squared norm.
template <class Obj>
bool batch_is_thread_independent(const Obj& obj, const iwr::RowMatrixXd& X) {
    const Eigen::Index m = X.rows();
    iwr::VectorXd one(m), two(m), five(m);
    iwr::ThreadPool p1(1), p2(2), p5(5);
    obj.cost_batch(X.data(), m, one.data(), p1);
    obj.cost_batch(X.data(), m, two.data(), p2);
    obj.cost_batch(X.data(), m, five.data(), p5);
    bool ok = one == two && one == five;
    for (Eigen::Index i = 0; i < m; ++i) {
        const iwr::VectorXd xi = X.row(i).transpose();
        ok = ok && one(i) == obj.cost(xi) && std::fabs(one(i) - obj.residuals(xi).squaredNorm()) <= 1e-12 * one(i);
    }
    return ok;
}

// The problem file's fields of ballbar data d of the robot g (the reference zero, weighted: pose k
// by 1000 / (1 + k)); then set_search gives its search (bounds +-2, x0 zeros, every parameter
// active, names x0, x1, ...) sized by p.n_params() (after any effects are added).
inline iwr::ProblemData ballbar_problem(const iwr::Geometry& g, const std::vector<iwr::BarSetup>& bars,
                                        const Data& d) {
    iwr::ProblemData p;
    p.robot_name = "test";
    p.joint_types = g.joint_types();
    p.dh = g.dh();
    p.joint_limits.resize(4, 2);
    p.joint_limits << 0, 2000, 0, 1000, -3, 3, -3, 3;
    p.base = g.base();
    p.platform = g.platform();
    p.leg_offsets = g.leg_offsets();
    for (int j = 0; j < 6; ++j) p.leg_stroke.row(j) << 0, 400;
    p.home_pose = home();
    p.workspace << 100, 100, 60, 0.2, 0.2, 0.2;
    p.kind = iwr::MeasurementKind::Ballbar;
    p.q = d.q;
    p.legs = d.legs;
    p.poses.resize(0, 6);  // as the reader leaves them (and iwr._core._data_fingerprint)
    p.bars = bars;
    p.bar = d.bar;
    p.distance = d.distance;
    p.reference = iwr::VectorXd::Zero(g.n_params());
    const Eigen::Index n = d.legs.rows();
    p.whitening.resize(n, 1);
    for (Eigen::Index k = 0; k < n; ++k) p.whitening(k, 0) = 1000.0 / static_cast<double>(1 + k);
    p.weighting = "a bar of 1 um";
    return p;
}
inline void set_search(iwr::ProblemData& p) {
    const std::size_t np = static_cast<std::size_t>(p.n_params());
    p.lower.assign(np, -2);
    p.upper.assign(np, 2);
    p.bounds_kind = "custom";
    p.x0.assign(np, 0);
    p.active.assign(np, true);
    p.parameter_names.clear();
    for (std::size_t i = 0; i < np; ++i) p.parameter_names.push_back("x" + std::to_string(i));
}

}  // namespace iwr_test
