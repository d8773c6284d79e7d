// C++ tests of the double ballbar's objective (iwr/ballbar.hpp) and its problem-file section:
// the residuals against distances computed independently (platform poses chosen, the leg readings
// from the inverse kinematics of the robot with errors, the distance in closed form), the noise
// weighting, thread-count independence, the penalty of a pose without forward kinematics, and the
// problem file's round trip to the engine's objective (make_objective) with its checks.
#include <cmath>
#include <cstdio>
#include <random>
#include <string>

#include "ballbar_fixtures.hpp"
#include "check.hpp"
#include "fixtures.hpp"
#include "iwr/binary_io.hpp"
#include "iwr/forward.hpp"
#include "iwr/measurement_kind.hpp"
#include "iwr/problem_file.hpp"

namespace test_ballbar {

namespace {

using iwr_test::Data;
using iwr_test::distance_from_pose;
using iwr_test::home;
using iwr_test::make_data;
using iwr_test::random_x;
using iwr_test::two_setups;

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
    CHECK(iwr_test::batch_is_thread_independent(obj, X));
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
    iwr::ProblemData p = iwr_test::ballbar_problem(g, bars, d);
    iwr_test::set_search(p);
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

}  // namespace test_ballbar
