// C++ tests of the ballbar objective with the non-geometric effects (iwr/effects_ballbar.hpp): the
// residuals against distances computed independently (platform poses in {0} chosen, the leg readings
// with the effects from the leg objective with effects, EffectObjective, which predicts the readings
// of given poses: the inverse of the objective's forward kinematics; the distance in closed form),
// the weights, thread-count independence, the penalty of a pose without forward kinematics, the
// checks, and the problem file's round trip to the engine's objective (make_objective).
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "ballbar_fixtures.hpp"
#include "check.hpp"
#include "effect_fixtures.hpp"
#include "fixtures.hpp"
#include "iwr/binary_io.hpp"
#include "iwr/effects.hpp"
#include "iwr/effects_ballbar.hpp"
#include "iwr/measurement_kind.hpp"
#include "iwr/problem_file.hpp"

namespace test_effects_ballbar {

namespace {

using iwr::EffectTable;
using iwr::RowMatrixXd;
using iwr::VectorXd;
using iwr_test::contains;
using iwr_test::nums;
using iwr_test::refusal;

const iwr::Vec3 kTilted = 9.80665 * iwr::Vec3(-0.9, 0.3, 0.3).normalized();  // against every axis

// Python's CarriageCompliance(...).to_dict(): the four joints of the IWR's carriage, the same gravity
// and platform as compliance_table's.
EffectTable carriage_table(const iwr::Vec3& gravity) {
    using iwr_test::num;
    return {"carriage_compliance",
            {{"joints", nums({1, 2, 3, 4})},
             {"compliance", nums({0.005, 0.004, 0.05, 0.04})},
             {"max_urad_per_Nm", num(0.5)},
             {"max_um_per_N", num(0.05)},
             {"gravity_m_s2", nums({gravity(0), gravity(1), gravity(2)})},
             {"hexapod_mass_kg", num(400)},
             {"hexapod_centre_mm", nums({20, -10, 150})},
             {"platform_mass_kg", num(120)},
             {"platform_centre_mm", nums({5, -3, 40})}}};
}

// Ballbar data of the robot with effects x = (geometric, effects, set-ups): the poses and distances
// of make_data (exact at x's geometric and set-up parts), a payload at every other pose, a
// temperature per pose, and the leg readings with the effects at those poses: the residuals of the
// leg objective with effects against zero readings (its predicted readings).
struct EffectData {
    iwr_test::Data d;
    RowMatrixXd payload, temperatures;
};
EffectData effect_data(const iwr::Geometry& g, const iwr::EffectModel& model, const std::vector<iwr::BarSetup>& bars,
                       const VectorXd& x, int n, std::mt19937_64& rng) {
    const int ng = g.n_params(), ne = model.n_params, ns = iwr::kBarParams * static_cast<int>(bars.size());
    VectorXd geometric_and_setups(ng + ns);
    geometric_and_setups << x.head(ng), x.tail(ns);
    EffectData e{iwr_test::make_data(g, bars, geometric_and_setups, n, rng), RowMatrixXd::Zero(n, 4),
                 RowMatrixXd(n, 1)};
    std::uniform_real_distribution<double> u(-1, 1);
    for (int k = 0; k < n; ++k) {
        if (k % 2) e.payload.row(k) << 80 + 20 * u(rng), 50, 0, 150;
        e.temperatures(k, 0) = 22 + 6 * u(rng);
    }
    const iwr::EffectObjective legs(g, model, e.d.q, e.d.poses, RowMatrixXd::Zero(n, 6), e.payload, e.temperatures);
    const VectorXd readings = legs.residuals(x.head(ng + ne));
    e.d.legs = Eigen::Map<const RowMatrixXd>(readings.data(), n, 6);
    return e;
}

iwr::BallbarEffectObjective objective(const iwr::Geometry& g, const iwr::EffectModel& model,
                                      const std::vector<iwr::BarSetup>& bars, const EffectData& e) {
    return iwr::BallbarEffectObjective(g, model, bars, e.d.q, e.d.legs, e.d.bar, e.d.distance, e.payload,
                                       e.temperatures, VectorXd::Zero(g.n_params()), iwr_test::home());
}

// x: the geometric errors and set-up parameters at `scale`, the effects' corrections small against
// their tables' values.
VectorXd truth(const iwr::Geometry& g, int ne, int ns, std::mt19937_64& rng, double scale) {
    VectorXd x = iwr_test::random_x(g.n_params() + ne + ns, rng, scale);
    x.segment(g.n_params(), ne) *= 1e-3;
    return x;
}

}  // namespace

// At the truth the forward kinematics with the effects finds the chosen poses (the residuals
// vanish to its tolerance), with the set-ups moved each residual is the closed-form distance at the
// chosen pose, and the geometry alone (BallbarObjective) misses by the effects: for the legs'
// compliance and temperature, with and without the carriage's compliance, and the thermal effect
// alone (no load read).
IWR_TEST(ballbar_effects_residuals_are_the_distances) {
    const iwr::Geometry g = iwr_test::default_iwr();
    const auto bars = iwr_test::two_setups();
    const std::vector<std::vector<EffectTable>> cases = {
        {iwr_test::compliance_table(true, 0.01, kTilted), iwr_test::thermal_table(true, false, 11.5)},
        {iwr_test::compliance_table(true, 0.01, kTilted), iwr_test::thermal_table(true, false, 11.5),
         carriage_table(kTilted)},
        {iwr_test::thermal_table(true, true, 11.5)}};
    for (std::size_t c = 0; c < cases.size(); ++c) {
        std::mt19937_64 rng(3 + c);
        const iwr::EffectModel model = iwr::EffectModel::parse(cases[c], g.n_params());
        const int ns = 2 * iwr::kBarParams, n = 24;
        const VectorXd x0 = truth(g, model.n_params, ns, rng, 0.1);
        const EffectData e = effect_data(g, model, bars, x0, n, rng);
        const iwr::BallbarEffectObjective obj = objective(g, model, bars, e);
        CHECK(obj.n_params() == g.n_params() + model.n_params + ns && obj.n_poses() == n);
        const VectorXd r0 = obj.residuals(x0);
        // The set-ups' parameters moved (the robot's and the effects' kept): the closed form.
        VectorXd x = x0;
        x.tail(ns) += iwr_test::random_x(ns, rng, 1.5);
        const VectorXd r = obj.residuals(x);
        double worst = 0, cost = 0;
        for (int k = 0; k < n; ++k) {
            const int s = e.d.bar[static_cast<std::size_t>(k)];
            const double expected = iwr_test::distance_from_pose(bars[static_cast<std::size_t>(s)],
                                                                 x.data() + obj.n_model_params() + iwr::kBarParams * s,
                                                                 e.d.poses.row(k).transpose()) -
                                    e.d.distance(k);
            worst = std::max(worst, std::fabs(r(k) - expected));
            cost += r(k) * r(k);
        }
        // The geometry alone on the same data: the effects are in the readings.
        const iwr::BallbarObjective plain(g, bars, e.d.q, e.d.legs, e.d.bar, e.d.distance, VectorXd::Zero(g.n_params()),
                                          iwr_test::home());
        VectorXd xp(plain.n_params());
        xp << x0.head(g.n_params()), x0.tail(ns);
        const double missed = plain.residuals(xp).cwiseAbs().maxCoeff();
        std::printf("  case %zu: at the truth %.3g mm, against the closed form %.3g mm (residuals up to %.3g mm); "
                    "the geometry alone misses by %.3g mm\n",
                    c, r0.cwiseAbs().maxCoeff(), worst, r.cwiseAbs().maxCoeff(), missed);
        // (measured: 1e-11 to 2.5e-11 mm, the Newton tolerance of 1e-11 mm in the legs)
        CHECK(r0.cwiseAbs().maxCoeff() < 1e-9);
        CHECK(worst < 1e-9 && r.cwiseAbs().maxCoeff() > 0.1);
        CHECK(missed > 1e-3);
        CHECK(std::fabs(obj.cost(x) - cost) <= 1e-12 * cost);
        // Weighted: residual k times w_k, the same bits.
        iwr::BallbarEffectObjective w = obj;
        RowMatrixXd wh(n, 1);
        for (int k = 0; k < n; ++k) wh(k, 0) = 0.5 + k;
        w.set_whitening(wh);
        CHECK(w.whitened() && !obj.whitened());
        const VectorXd rw = w.residuals(x);
        for (int k = 0; k < n; ++k) CHECK(rw(k) == r(k) * wh(k, 0));
    }
}

IWR_TEST(ballbar_effects_batch_failures_and_checks) {
    std::mt19937_64 rng(11);
    const iwr::Geometry g = iwr_test::default_iwr();
    const auto bars = iwr_test::two_setups();
    const iwr::EffectModel model = iwr::EffectModel::parse(
        {iwr_test::compliance_table(false, 0.01, kTilted), carriage_table(kTilted)}, g.n_params());
    const int ns = 2 * iwr::kBarParams, np = g.n_params() + model.n_params + ns;
    const EffectData e = effect_data(g, model, bars, VectorXd::Zero(np), 13, rng);
    iwr::BallbarEffectObjective obj = objective(g, model, bars, e);
    RowMatrixXd wh(13, 1);
    for (int k = 0; k < 13; ++k) wh(k, 0) = 1.0 / (1 + k);
    for (bool weighted : {false, true}) {
        obj.set_whitening(weighted ? wh : RowMatrixXd());
        const int m = 9;
        RowMatrixXd X(m, np);
        for (int i = 0; i < m; ++i) X.row(i) = truth(g, model.n_params, ns, rng, 0.3).transpose();
        CHECK(iwr_test::batch_is_thread_independent(obj, X));
    }
    // Leg 1 two metres short: no pose closes; a finite penalty per pose (times its weight), each named.
    VectorXd x = VectorXd::Zero(np);
    x(g.idx_offset(0)) = -2000;
    const auto f = obj.failures(x);
    CHECK(static_cast<int>(f.size()) == obj.n_poses());
    CHECK(!f.empty() && contains(f[0].second, "pose 0") && contains(f[0].second, "with the effects"));
    const VectorXd r = obj.residuals(x);
    for (int k = 0; k < 13; ++k) CHECK(r(k) == iwr::BallbarEffectObjective::kFailedResidual * wh(k, 0));
    // The checks name what is wrong.
    CHECK(contains(refusal([&] { (void)obj.cost(VectorXd::Zero(np - 1)); }),
                   "(58 of the robot, 5 of the effects, 14 of the 2 ballbar set-up(s))"));
    CHECK(contains(refusal([&] { obj.set_whitening(RowMatrixXd::Ones(13, 2)); }), "expected (13, 1)"));
    const iwr::EffectModel none = iwr::EffectModel::parse({}, g.n_params());
    CHECK(contains(refusal([&] { (void)objective(g, none, bars, e); }), "effects: none on"));
    const iwr::EffectModel thermal =
        iwr::EffectModel::parse({iwr_test::thermal_table(false, false, 11.5)}, g.n_params());
    EffectData cold = e;
    cold.temperatures.resize(0, 0);
    CHECK(contains(refusal([&] { (void)objective(g, thermal, bars, cold); }), "temperatures"));
    EffectData bad = e;
    bad.d.bar[5] = 2;
    CHECK(contains(refusal([&] { (void)objective(g, model, bars, bad); }), "pose 5 has set-up index 2"));
}

// A problem file of ballbar data with effects: written, read back, its objective the
// BallbarEffectObjective bit for bit; the fingerprints see the effects and the loads; a truncated or
// damaged file is refused naming it, never a crash.
IWR_TEST(ballbar_effects_problem_file) {
    std::mt19937_64 rng(5);
    const iwr::Geometry g = iwr_test::default_iwr();
    const auto bars = iwr_test::two_setups();
    const std::vector<EffectTable> tables = {iwr_test::compliance_table(true, 0.01, kTilted),
                                             iwr_test::thermal_table(true, false, 11.5)};
    const iwr::EffectModel model = iwr::EffectModel::parse(tables, g.n_params());
    const int ns = 2 * iwr::kBarParams, np = g.n_params() + model.n_params + ns;
    const EffectData e = effect_data(g, model, bars, truth(g, model.n_params, ns, rng, 0.1), 10, rng);
    iwr::ProblemData p = iwr_test::ballbar_problem(g, bars, e.d);
    p.effects = tables;
    p.payload = e.payload;
    p.temperatures = e.temperatures;
    CHECK(p.n_params() == np);
    iwr_test::set_search(p);
    const std::string bytes = iwr::encode_problem(p);
    const iwr::ProblemData back = iwr::decode_problem(bytes, "bb.iwrp: ");
    CHECK(back.ballbar() && back.version == 4 && back.n_params() == np && back.effects.size() == 2);
    CHECK(back.payload == p.payload && back.temperatures == p.temperatures && back.bars == bars);
    CHECK(back.robot_fingerprint() == p.robot_fingerprint() && back.data_fingerprint() == p.data_fingerprint());
    CHECK(iwr::encode_problem(back) == bytes);
    const iwr::AnyObjective any = iwr::make_objective(back);
    CHECK(std::holds_alternative<iwr::BallbarEffectObjective>(any));
    iwr::BallbarEffectObjective direct = objective(g, model, bars, e);
    direct.set_whitening(p.whitening);
    for (int i = 0; i < 3; ++i) {
        const VectorXd x = truth(g, model.n_params, ns, rng, 1.0);
        CHECK(std::get<iwr::BallbarEffectObjective>(any).cost(x) == direct.cost(x));
    }
    // The fingerprints: the effects' tables are the robot's, the loads the data's.
    iwr::ProblemData other = p;
    other.effects[0].entries[1].second.numbers[2] = 0.02;
    CHECK(other.robot_fingerprint() != p.robot_fingerprint() && other.data_fingerprint() == p.data_fingerprint());
    other = p;
    other.temperatures(3, 0) += 0.5;
    CHECK(other.data_fingerprint() != p.data_fingerprint() && other.robot_fingerprint() == p.robot_fingerprint());
    // What the reader refuses, naming the file and the field.
    other = p;
    other.temperatures.resize(0, 0);
    CHECK(contains(refusal([&] { (void)iwr::encode_problem(other); }), "temperatures: the thermal effect is on"));
    other = p;
    other.lower.pop_back();
    CHECK(contains(refusal([&] { (void)iwr::encode_problem(other); }), "lower bounds"));
    CHECK(contains(refusal([&] { (void)iwr::decode_problem(bytes.substr(0, bytes.size() - 9), "bb.iwrp: "); }),
                   "bb.iwrp: "));
    // Damaged effects' bytes (the second half of the payload): refused with a FormatError or read.
    const int refused = iwr_test::fuzz_refusals(bytes, 200, rng);
    std::printf("  ballbar effects fuzz: %d of 200 refused, the rest read\n", refused);
    CHECK(refused > 0);
}

}  // namespace test_effects_ballbar
