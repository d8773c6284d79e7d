// C++ tests of the double ballbar's objective (iwr/ballbar.hpp) and its problem-file section:
// the residuals against distances computed independently (platform poses chosen, the leg readings
// from the inverse kinematics of the robot with errors, the distance in closed form), the noise
// weighting, thread-count independence, the penalty of a pose without forward kinematics, and the
// problem file's round trip to the engine's objective (make_objective) with its checks.
#include <cmath>
#include <cstdio>
#include <random>
#include <string>

#include "check.hpp"
#include "fixtures.hpp"
#include "iwr/binary_io.hpp"
#include "iwr/forward.hpp"
#include "iwr/measurement_kind.hpp"
#include "iwr/problem_file.hpp"

namespace {

struct Data {
    iwr::RowMatrixXd q, legs, poses;  // poses: the true world poses of {5}
    std::vector<int> bar;
    iwr::VectorXd distance;
};

std::vector<iwr::BarSetup> two_setups() {
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
double distance_from_pose(const iwr::BarSetup& b, const double* xs, const iwr::Vector6d& pose) {
    const iwr::Mat3 r = iwr::euler_zyx(pose(3), pose(4), pose(5));
    const iwr::Vec3 p = b.platform_ball + iwr::Vec3(xs[0], xs[1], xs[2]);
    const iwr::Vec3 f = b.fixed_ball + iwr::Vec3(xs[3], xs[4], xs[5]);
    return (pose.head<3>() + r * p - f).norm() + b.offset + xs[6];
}

// Random carriage readings and local poses of {5} in {4}; the world poses by the carriage of the
// robot with errors x (its first 4 n + 42 entries), the leg readings by its inverse kinematics,
// the bar readings exact at x (set-ups' part included).
Data make_data(const iwr::Geometry& g, const std::vector<iwr::BarSetup>& bars, const iwr::VectorXd& x, int n,
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

iwr::VectorXd random_x(int n, std::mt19937_64& rng, double scale) {
    std::uniform_real_distribution<double> u(-scale, scale);
    iwr::VectorXd x(n);
    for (int i = 0; i < n; ++i) x(i) = u(rng);
    return x;
}

iwr::Vector6d home() {
    iwr::Vector6d h;
    h << 0, 0, 750, 0, 0, 0;
    return h;
}

}  // namespace

IWR_TEST(ballbar_residuals_are_the_distances) {
    std::mt19937_64 rng(3);
    const iwr::Geometry g = iwr_test::default_iwr();
    const auto bars = two_setups();
    const int np = g.n_params() + 2 * iwr::kBarParams;
    const iwr::VectorXd truth = random_x(np, rng, 0.3);
    const Data d = make_data(g, bars, truth, 30, rng);
    const iwr::BallbarObjective obj(g, bars, d.q, d.legs, d.bar, d.distance, iwr::VectorXd::Zero(g.n_params()),
                                    home());
    CHECK(obj.n_params() == np && obj.n_poses() == 30);
    // At the truth: the forward kinematics recovers the chosen poses (to its tolerance, 1e-10 mm).
    const iwr::VectorXd r0 = obj.residuals(truth);
    std::printf("  largest residual at the truth: %.3g mm\n", r0.cwiseAbs().maxCoeff());
    CHECK(r0.cwiseAbs().maxCoeff() < 1e-8);
    // The set-ups' parameters moved (the robot's kept): each residual is the closed-form distance
    // at the true pose minus the reading.
    iwr::VectorXd x = truth;
    x.tail(2 * iwr::kBarParams) += random_x(2 * iwr::kBarParams, rng, 1.5);
    const iwr::VectorXd r = obj.residuals(x);
    double worst = 0, cost = 0;
    for (int k = 0; k < 30; ++k) {
        const int s = d.bar[static_cast<std::size_t>(k)];
        const double expected = distance_from_pose(bars[static_cast<std::size_t>(s)],
                                                   x.data() + g.n_params() + iwr::kBarParams * s,
                                                   d.poses.row(k).transpose()) - d.distance(k);
        worst = std::max(worst, std::fabs(r(k) - expected));
        cost += r(k) * r(k);
    }
    std::printf("  residuals against the closed form: %.3g mm (largest residual %.3g mm)\n", worst,
                r.cwiseAbs().maxCoeff());
    CHECK(worst < 1e-8 && r.cwiseAbs().maxCoeff() > 0.1);
    CHECK(std::fabs(obj.cost(x) - cost) <= 1e-12 * cost);
    // Weighted: residual k times w_k.
    iwr::BallbarObjective w = obj;
    iwr::RowMatrixXd wh(30, 1);
    for (int k = 0; k < 30; ++k) wh(k, 0) = 0.5 + k;
    w.set_whitening(wh);
    CHECK(w.whitened());
    const iwr::VectorXd rw = w.residuals(x);
    for (int k = 0; k < 30; ++k) CHECK(rw(k) == r(k) * wh(k, 0));
    bool refused = false;
    try {
        w.set_whitening(iwr::RowMatrixXd::Ones(30, 2));
    } catch (const std::invalid_argument& e) {
        refused = std::string(e.what()).find("expected (30, 1)") != std::string::npos;
    }
    CHECK(refused);
}

IWR_TEST(ballbar_batch_and_failures) {
    std::mt19937_64 rng(11);
    const iwr::Geometry g = iwr_test::default_iwr();
    const auto bars = two_setups();
    const int np = g.n_params() + 2 * iwr::kBarParams;
    const Data d = make_data(g, bars, iwr::VectorXd::Zero(np), 41, rng);
    const iwr::BallbarObjective obj(g, bars, d.q, d.legs, d.bar, d.distance, iwr::VectorXd::Zero(g.n_params()),
                                    home());
    const int m = 23;
    iwr::RowMatrixXd X(m, np);
    for (int i = 0; i < m; ++i) X.row(i) = random_x(np, rng, 0.4).transpose();
    iwr::VectorXd one(m), two(m), five(m);
    iwr::ThreadPool p1(1), p2(2), p5(5);
    obj.cost_batch(X.data(), m, one.data(), p1);
    obj.cost_batch(X.data(), m, two.data(), p2);
    obj.cost_batch(X.data(), m, five.data(), p5);
    CHECK(one == two && one == five);
    for (int i = 0; i < m; ++i) {
        const iwr::VectorXd xi = X.row(i).transpose();
        CHECK(one(i) == obj.cost(xi));
        CHECK(one(i) == obj.residuals(xi).squaredNorm() || std::fabs(one(i) - obj.residuals(xi).squaredNorm()) <= 1e-12 * one(i));
    }
    // Leg 1 two metres short: no pose closes; a finite penalty per pose, each named.
    iwr::VectorXd x = iwr::VectorXd::Zero(np);
    x(g.idx_offset(0)) = -2000;
    const auto f = obj.failures(x);
    CHECK(static_cast<int>(f.size()) == obj.n_poses());
    CHECK(!f.empty() && f[0].second.find("pose 0") != std::string::npos);
    const iwr::VectorXd r = obj.residuals(x);
    CHECK((r.array() == iwr::BallbarObjective::kFailedResidual).all());
    bool named = false;
    try {
        (void)obj.cost(iwr::VectorXd::Zero(np - 1));
    } catch (const std::invalid_argument& e) {
        named = std::string(e.what()).find("14 of the 2 ballbar set-up(s)") != std::string::npos;
    }
    CHECK(named);
    std::vector<int> bad = d.bar;
    bad[5] = 2;
    bool index = false;
    try {
        iwr::BallbarObjective(g, bars, d.q, d.legs, bad, d.distance, iwr::VectorXd::Zero(g.n_params()), home());
    } catch (const std::invalid_argument& e) {
        index = std::string(e.what()).find("pose 5 has set-up index 2") != std::string::npos;
    }
    CHECK(index);
}

IWR_TEST(ballbar_problem_file_round_trip) {
    std::mt19937_64 rng(5);
    const iwr::Geometry g = iwr_test::default_iwr();
    const auto bars = two_setups();
    const int np = g.n_params() + 2 * iwr::kBarParams;
    const Data d = make_data(g, bars, random_x(np, rng, 0.2), 12, rng);
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
    p.whitening.resize(12, 1);
    for (int k = 0; k < 12; ++k) p.whitening(k, 0) = 1000.0 / (1 + k);
    p.weighting = "a bar of 1 um";
    p.lower.assign(static_cast<std::size_t>(np), -2);
    p.upper.assign(static_cast<std::size_t>(np), 2);
    p.bounds_kind = "custom";
    p.x0.assign(static_cast<std::size_t>(np), 0);
    p.active.assign(static_cast<std::size_t>(np), true);
    for (int i = 0; i < np; ++i) p.parameter_names.push_back("x" + std::to_string(i));
    const std::string bytes = iwr::encode_problem(p);
    const iwr::ProblemData back = iwr::decode_problem(bytes, "p.iwrp: ");
    CHECK(back.ballbar() && !back.tracker() && back.n_params() == np && back.residuals_per_pose() == 1);
    CHECK(back.bars == bars && back.bar == d.bar && back.distance == d.distance);
    CHECK(back.robot_fingerprint() == p.robot_fingerprint() && back.data_fingerprint() == p.data_fingerprint());
    CHECK(iwr::encode_problem(back) == bytes);
    // The engine's objective is the weighted ballbar objective, bit for bit.
    const iwr::AnyObjective any = iwr::make_objective(back);
    CHECK(std::holds_alternative<iwr::BallbarObjective>(any));
    iwr::BallbarObjective direct(g, bars, d.q, d.legs, d.bar, d.distance, p.reference, home());
    direct.set_whitening(p.whitening);
    for (int i = 0; i < 4; ++i) {
        const iwr::VectorXd x = random_x(np, rng, 1.0);
        CHECK(std::get<iwr::BallbarObjective>(any).cost(x) == direct.cost(x));
    }
    // The set-up order is not data: the data fingerprint names each pose's set-up.
    iwr::ProblemData swapped = back;
    std::swap(swapped.bars[0], swapped.bars[1]);
    for (int& s : swapped.bar) s = 1 - s;
    CHECK(swapped.data_fingerprint() == back.data_fingerprint());
    CHECK(swapped.robot_fingerprint() != back.robot_fingerprint());
    // The reader's checks: an index out of range, a distance <= 0, a name given twice.
    auto refused = [](iwr::ProblemData q, const std::string& needle) {
        try {
            (void)iwr::encode_problem(q);
        } catch (const std::invalid_argument& e) {
            if (std::string(e.what()).find(needle) != std::string::npos) return true;
            std::printf("  unexpected message: %s\n", e.what());
        }
        return false;
    };
    iwr::ProblemData q1 = back;
    q1.bar[3] = 2;
    CHECK(refused(q1, "ballbar set-up index: pose 3 has 2; expected 0 to 1"));
    iwr::ProblemData q2 = back;
    q2.distance(4) = -1;
    CHECK(refused(q2, "distance: pose 4 is -1"));
    q2.distance(4) = 1e11;  // a length beyond 100 m, as iwr.measurements.MAX_LENGTH_MM refuses
    CHECK(refused(q2, "distance: pose 4 is 100000000000"));
    iwr::ProblemData q3 = back;
    q3.bars[1].name = "A";
    CHECK(refused(q3, "ballbar set-up name: 'A' given twice"));
    iwr::ProblemData q4 = back;
    q4.bars[0].name = "a b";
    CHECK(refused(q4, "ballbar set-up name: 'a b'"));
    iwr::ProblemData q5 = back;
    q5.whitening.resize(12, 4);
    q5.whitening.setOnes();
    CHECK(refused(q5, "whitening"));
}

IWR_TEST_MAIN
