// C++ tests of the leg objective with the non-geometric effects (iwr/effects.hpp): the statics
// against the virtual work of gravity, the thermal growth and the geometry against the objective
// of the geometry alone, the tables' checks, the thread independence of the batches, singular
// poses, and the problem file's effects (version 4).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "check.hpp"
#include "effect_fixtures.hpp"
#include "fixtures.hpp"
#include "iwr/binary_io.hpp"
#include "iwr/effects.hpp"
#include "iwr/measurement_kind.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"
#include "iwr/problem_file.hpp"

namespace test_effects {

namespace {

using iwr::EffectTable;
using iwr::EffectValue;
using iwr::RowMatrixXd;
using iwr::VectorXd;

using iwr_test::compliance_table;
using iwr_test::contains;
using iwr_test::flag;
using iwr_test::num;
using iwr_test::nums;
using iwr_test::refusal;
using iwr_test::thermal_table;

// Poses of the platform about its home (the hexapod alone, or the IWR at random carriage readings
// with the platform 700 mm out along the carriage's z), a payload at every other pose, and
// temperatures per leg.
struct Data {
    RowMatrixXd q, poses, legs, payload, temperatures;
};
Data sample(const iwr::Geometry& g, int n, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(-1, 1);
    Data d;
    d.q.resize(n, g.n_joints());
    d.poses.resize(n, 6);
    d.legs.resize(n, 6);
    d.payload.resize(n, 4);
    d.temperatures.resize(n, 6);
    const VectorXd zero = VectorXd::Zero(g.n_params());
    for (int k = 0; k < n; ++k) {
        for (int i = 0; i < g.n_joints(); ++i) d.q(k, i) = g.is_prismatic(i) ? 200 * u(rng) : 0.3 * u(rng);
        const iwr::Mat4 t4 = iwr::carriage_transform(g, zero.data(), d.q.row(k).data());
        const iwr::Vec3 p = t4.topRightCorner<3, 1>() +
                            t4.topLeftCorner<3, 3>() * iwr::Vec3(30 * u(rng), 30 * u(rng), 700 + 30 * u(rng));
        const iwr::Mat3 r4 = t4.topLeftCorner<3, 3>();
        // Euler angles of 4R5 ~ small rotation, composed with 0R4.
        const iwr::Mat3 r = r4 * iwr::euler_zyx(0.1 * u(rng), 0.1 * u(rng), 0.1 * u(rng));
        const double beta = -std::asin(r(2, 0)), alpha = std::atan2(r(1, 0), r(0, 0)),
                     gamma = std::atan2(r(2, 1), r(2, 2));
        d.poses.row(k) << p(0), p(1), p(2), alpha, beta, gamma;
        for (int j = 0; j < 6; ++j) d.legs(k, j) = 100 + 10 * u(rng), d.temperatures(k, j) = 22 + 4 * u(rng);
        if (k % 2) d.payload.row(k) << 80, 50, 0, 150;
        else d.payload.row(k) << 0, 0, 0, 0;
    }
    return d;
}

}  // namespace

// The forces against an independent computation: the virtual work of the leg forces over a small
// platform motion (the leg lengths from predict_legs, central differences) equals that of gravity
// on the platform and the payload (their centres' displacement), to second order in the step.
IWR_TEST(statics_match_the_virtual_work_of_gravity) {
    const iwr::Geometry g = iwr_test::default_iwr(false);
    const iwr::Vec3 gravity(0.3, -0.2, -9.8);
    const iwr::EffectModel model = iwr::EffectModel::parse({compliance_table(true, 0.01, gravity)}, g.n_params());
    Data d = sample(g, 6, 1);
    const iwr::EffectObjective obj(g, model, d.q, d.poses, d.legs, d.payload, RowMatrixXd());
    const VectorXd x = VectorXd::Constant(obj.n_params(), 0.0);
    const RowMatrixXd f = obj.forces(x);
    const VectorXd xg = VectorXd::Zero(g.n_params());
    double worst = 0, scale = 0;
    for (int k = 0; k < d.poses.rows(); ++k) {
        const iwr::Mat3 r = iwr::euler_zyx(d.poses(k, 3), d.poses(k, 4), d.poses(k, 5));
        for (int axis = 0; axis < 6; ++axis) {
            const double h = axis < 3 ? 1e-3 : 1e-6;  // mm, rad
            iwr::RowMatrixXd moved(2, 6), q2(2, 0);
            for (int s = 0; s < 2; ++s) {
                const double step = s ? -h : h;
                iwr::Vec3 p(d.poses(k, 0), d.poses(k, 1), d.poses(k, 2));
                iwr::Mat3 rr = r;
                if (axis < 3) p(axis) += step;
                else rr = Eigen::AngleAxisd(step, iwr::Vec3::Unit(axis - 3)).toRotationMatrix() * r;
                const double beta = -std::asin(rr(2, 0)), alpha = std::atan2(rr(1, 0), rr(0, 0)),
                             gamma = std::atan2(rr(2, 1), rr(2, 2));
                moved.row(s) << p(0), p(1), p(2), alpha, beta, gamma;
            }
            const RowMatrixXd lengths = iwr::predict_legs(g, xg, q2, moved);
            double legs_work = 0;
            for (int j = 0; j < 6; ++j) legs_work += f(k, j) * (lengths(0, j) - lengths(1, j)) / (2 * h);
            // Gravity: sum of m g . d(centre)/dX, centre = p + R c; d/dphi (R c) = e x (R c).
            double gravity_work = 0;
            const iwr::Vec3 centres[2] = {iwr::Vec3(5, -3, 40),
                                          iwr::Vec3(d.payload(k, 1), d.payload(k, 2), d.payload(k, 3))};
            const double masses[2] = {120, d.payload(k, 0)};
            for (int b = 0; b < 2; ++b) {
                const iwr::Vec3 arm = r * centres[b];
                const iwr::Vec3 dc = axis < 3 ? iwr::Vec3::Unit(axis) : iwr::Vec3(iwr::Vec3::Unit(axis - 3).cross(arm));
                gravity_work += masses[b] * gravity.dot(dc);
            }
            worst = std::max(worst, std::fabs(legs_work - gravity_work));
            scale = std::max(scale, std::fabs(gravity_work));
        }
    }
    std::printf("virtual work: worst difference %.3g of %.3g\n", worst, scale);
    CHECK(scale > 100 && worst < 1e-6 * scale);
}

// With every effect at zero the residuals are the geometry's (the SIMD objective's, to
// round-off); the thermal growth is alpha D (T - T_ref) exactly; the compliance is c f.
IWR_TEST(effects_change_the_readings_as_modelled) {
    const iwr::Geometry g = iwr_test::default_iwr(true);
    Data d = sample(g, 13, 2);
    const iwr::Vec3 gravity(-9.80665, 0, 0);
    const iwr::EffectModel model = iwr::EffectModel::parse(
        {thermal_table(true, false, 0.0), compliance_table(false, 0.0, gravity)}, g.n_params());
    CHECK(model.thermal_index == g.n_params() && model.compliance_index == g.n_params() + 1 && model.n_params == 2);
    const iwr::EffectObjective obj(g, model, d.q, d.poses, d.legs, d.payload, d.temperatures);
    const iwr::Objective plain(g, d.q, d.poses, d.legs);
    std::mt19937_64 rng(3);
    std::uniform_real_distribution<double> u(-1e-3, 1e-3);
    VectorXd xg(g.n_params());
    for (auto& v : xg) v = u(rng);
    VectorXd x(obj.n_params());
    x << xg, 0.0, 0.0;
    const VectorXd r0 = obj.residuals(x), rg = plain.residuals(xg);
    CHECK((r0 - rg).cwiseAbs().maxCoeff() < 1e-9);
    // Thermal: -alpha D dT with D = predicted reading + l0.
    const RowMatrixXd s = iwr::predict_legs(g, xg, d.q, d.poses);
    x(g.n_params()) = 11.5;
    const VectorXd rt = obj.residuals(x);
    double worst = 0;
    for (int k = 0; k < d.q.rows(); ++k)
        for (int j = 0; j < 6; ++j) {
            const double length = s(k, j) + g.leg_offsets()(j) + xg(g.idx_offset(j));
            const double expected = -11.5e-6 * length * (d.temperatures(k, j) - 20);
            worst = std::max(worst, std::fabs((rt(6 * k + j) - r0(6 * k + j)) - expected));
        }
    CHECK(worst < 1e-10);
    // Compliance: -c f (f from forces(), at the same x).
    x(g.n_params()) = 0, x(g.n_params() + 1) = 0.01;
    const VectorXd rc = obj.residuals(x);
    const RowMatrixXd f = obj.forces(x);
    worst = 0;
    double biggest = 0;
    for (int k = 0; k < d.q.rows(); ++k)
        for (int j = 0; j < 6; ++j) {
            worst = std::max(worst, std::fabs((rc(6 * k + j) - r0(6 * k + j)) + 1e-5 * f(k, j)));
            biggest = std::max(biggest, std::fabs(f(k, j)));
        }
    CHECK(worst < 1e-10 && biggest > 100);
    // The cost is the sum of the squared residuals.
    CHECK(std::fabs(obj.cost(x) - rc.squaredNorm()) <= 1e-12 * rc.squaredNorm());
}

IWR_TEST(batches_are_thread_independent) {
    const iwr::Geometry g = iwr_test::default_iwr(true);
    Data d = sample(g, 37, 4);
    const iwr::EffectModel model = iwr::EffectModel::parse(
        {compliance_table(true, 0.01, iwr::Vec3(0, 0, -9.81)), thermal_table(true, true, 11.5)}, g.n_params());
    RowMatrixXd w = RowMatrixXd::Constant(37, 6, 2.0);
    const iwr::EffectObjective obj(g, model, d.q, d.poses, d.legs, d.payload, d.temperatures.col(0), w);
    const int m = 23;
    RowMatrixXd X = 1e-3 * RowMatrixXd::Random(m, obj.n_params());
    std::vector<double> one(m), four(m);
    iwr::ThreadPool p1(1), p4(4);
    obj.cost_batch(X.data(), m, one.data(), p1);
    obj.cost_batch(X.data(), m, four.data(), p4);
    for (int i = 0; i < m; ++i) {
        CHECK(one[static_cast<std::size_t>(i)] == four[static_cast<std::size_t>(i)]);
        CHECK(one[static_cast<std::size_t>(i)] == obj.cost(VectorXd(X.row(i).transpose())));
    }
}

IWR_TEST(singular_hexapod_is_a_failure_not_nan) {
    // Every joint on one axis: G has rank 2 at most.
    iwr::LegMatrix base = iwr::LegMatrix::Zero(), platform = iwr::LegMatrix::Zero();
    for (int j = 0; j < 6; ++j) base(j, 0) = 100.0 * j, platform(j, 0) = 100.0 * j;
    const iwr::Geometry g("", RowMatrixXd(0, 4), base, platform, iwr::LegVector::Constant(600));
    const iwr::EffectModel model =
        iwr::EffectModel::parse({compliance_table(false, 0.01, iwr::Vec3(0, 0, -9.80665))}, g.n_params());
    RowMatrixXd q(2, 0), poses(2, 6), legs = RowMatrixXd::Constant(2, 6, 100);
    poses << 0, 0, 700, 0, 0, 0, 0, 10, 700, 0.1, 0, 0;
    const iwr::EffectObjective obj(g, model, q, poses, legs, RowMatrixXd(), RowMatrixXd());
    const VectorXd x = VectorXd::Zero(obj.n_params());
    const double c = obj.cost(x);
    CHECK(std::isfinite(c) && c >= 12 * iwr::EffectObjective::kFailedResidual * iwr::EffectObjective::kFailedResidual);
    const auto bad = obj.failures(x);
    CHECK(bad.size() == 2 && contains(bad[0].second, "singular"));
}

IWR_TEST(tables_and_inputs_are_checked) {
    const iwr::Geometry g = iwr_test::default_iwr(false);
    const int n = g.n_params();
    const auto parse = [&](std::vector<EffectTable> t) { return refusal([&] { (void)iwr::EffectModel::parse(t, n); }); };
    EffectTable c = compliance_table(true, 0.01, iwr::Vec3(0, 0, -9.80665));
    CHECK(parse({c, c}) == "effects.compliance: given twice");
    EffectTable t = c;
    t.entries.push_back({"stiffness", num(1)});
    CHECK(contains(parse({t}), "effects.compliance.stiffness: unknown key; allowed: per_leg"));
    t = c;
    t.entries.erase(t.entries.begin() + 4);  // platform_mass_kg
    CHECK(parse({t}) == "effects.compliance.platform_mass_kg: missing key");
    t = c;
    t.entries[3].second = nums({0, 0, -5});
    CHECK(contains(parse({t}), "effects.compliance.gravity_m_s2: norm 5 m/s^2; expected 9.80665 within 1 %"));
    t = c;
    t.entries[1].second = nums({0.01, 0.01});
    CHECK(contains(parse({t}), "effects.compliance.compliance_um_per_N: 2 number(s); expected 6 numbers"));
    t = c;
    t.entries[0].second = num(1);
    CHECK(contains(parse({t}), "effects.compliance.per_leg: expected true or false"));
    CHECK(contains(parse({{"backlash", {}}}), "effects.backlash: no model of this effect in the C++ core"));
    // The data: the thermal effect needs temperatures; shapes and masses are checked.
    Data d = sample(g, 3, 5);
    const iwr::EffectModel th = iwr::EffectModel::parse({thermal_table(false, false, 11.5)}, n);
    CHECK(contains(refusal([&] { iwr::EffectObjective(g, th, d.q, d.poses, d.legs, d.payload, RowMatrixXd()); }),
                   "temperatures: the thermal effect"));
    CHECK(contains(refusal([&] {
                       iwr::EffectObjective(g, th, d.q, d.poses, d.legs, d.payload, RowMatrixXd::Zero(3, 2));
                   }),
                   "temperatures: shape (3, 2); expected (3, 1 or 6)"));
    d.payload(1, 0) = -1;
    CHECK(contains(refusal([&] { iwr::EffectObjective(g, th, d.q, d.poses, d.legs, d.payload, d.temperatures); }),
                   "payload: pose 1 has mass -1 kg"));
    const iwr::EffectObjective ok(g, th, d.q, d.poses, d.legs, RowMatrixXd(), d.temperatures);
    CHECK(ok.n_params() == n);  // alpha given: no parameter
    CHECK(contains(refusal([&] { (void)ok.cost(VectorXd::Zero(n + 1)); }), "x: " + std::to_string(n + 1)));
}

// A problem file with effects: written, read back (version 4), its objective the EffectObjective,
// the fingerprints covering the tables and the loads; refused on tracker data and with bad tables.
IWR_TEST(problem_file_with_effects) {
    const iwr::Geometry g = iwr_test::default_iwr(true);
    Data d = sample(g, 9, 6);
    iwr::ProblemData p;
    p.robot_name = "iwr";
    p.joint_types = g.joint_types();
    p.dh = g.dh();
    p.joint_limits = RowMatrixXd(4, 2);
    p.joint_limits << -1000, 1000, -1000, 1000, -3, 3, -3, 3;
    p.base = g.base();
    p.platform = g.platform();
    p.leg_offsets = g.leg_offsets();
    for (int j = 0; j < 6; ++j) p.leg_stroke(j, 0) = 0, p.leg_stroke(j, 1) = 400;
    p.home_pose << 0, 0, 700, 0, 0, 0;
    p.workspace << 100, 100, 100, 0.2, 0.2, 0.2;
    p.q = d.q;
    p.legs = d.legs;
    p.poses = d.poses;
    p.effects = {compliance_table(true, 0.01, iwr::Vec3(-9.80665, 0, 0)), thermal_table(true, false, 11.5)};
    p.payload = d.payload;
    p.temperatures = d.temperatures.col(2);
    const int np = g.n_params() + 7;
    CHECK(p.n_params() == np);
    p.lower.assign(np, -0.5);
    p.upper.assign(np, 0.5);
    p.bounds_kind = "custom";
    p.x0.assign(np, 0.0);
    p.active.assign(np, true);
    for (int i = 0; i < np; ++i) p.parameter_names.push_back("p" + std::to_string(i));
    const std::string bytes = iwr::encode_problem(p);
    const iwr::ProblemData r = iwr::decode_problem(bytes, "e.iwrp: ");
    CHECK(r.version == 4 && r.effects.size() == 2 && r.effects[0].name == "compliance" &&
          r.effects[1].entries[2].second.type == EffectValue::Type::Bool && r.payload == p.payload &&
          r.temperatures == p.temperatures && r.n_params() == np);
    CHECK(r.robot_fingerprint() == p.robot_fingerprint() && r.data_fingerprint() == p.data_fingerprint());
    const iwr::AnyObjective any = iwr::make_objective(r);
    CHECK(std::holds_alternative<iwr::EffectObjective>(any));
    const iwr::EffectObjective direct(g, p.effect_model(), d.q, d.poses, d.legs, d.payload, p.temperatures);
    const VectorXd x = VectorXd::Constant(np, 1e-4);
    CHECK(std::get<iwr::EffectObjective>(any).cost(x) == direct.cost(x));
    // The fingerprints see the effects and the loads.
    iwr::ProblemData other = p;
    other.temperatures(3, 0) += 0.5;
    CHECK(other.data_fingerprint() != p.data_fingerprint() && other.robot_fingerprint() == p.robot_fingerprint());
    other = p;
    other.effects[0].entries[1].second.numbers[2] = 0.02;
    CHECK(other.robot_fingerprint() != p.robot_fingerprint() && other.data_fingerprint() == p.data_fingerprint());
    // Without effects, the fingerprints are those of a file without the fields (as version 3).
    other = p;
    other.effects.clear(), other.payload.resize(0, 0), other.temperatures.resize(0, 0);
    other.lower.resize(static_cast<std::size_t>(g.n_params())), other.upper.resize(other.lower.size());
    other.x0.resize(other.lower.size()), other.active.resize(other.lower.size());
    other.parameter_names.resize(other.lower.size());
    const iwr::ProblemData plain = iwr::decode_problem(iwr::encode_problem(other), "");
    CHECK(std::holds_alternative<iwr::Objective>(iwr::make_objective(plain)));
    // Bad tables and data are refused naming the field.
    other = p;
    other.effects[1].entries[1].second = num(500);
    CHECK(contains(refusal([&] { (void)iwr::encode_problem(other); }),
                   "effects.thermal.reference_C: 500 degrees C; expected -50 <= value <= 150"));
    other = p;
    other.temperatures.resize(0, 0);
    CHECK(contains(refusal([&] { (void)iwr::encode_problem(other); }), "temperatures: the thermal effect is on"));
    other = p;
    other.temperatures = RowMatrixXd::Constant(9, 3, 20.0);
    CHECK(contains(refusal([&] { (void)iwr::encode_problem(other); }), "temperature columns: 3"));
    // Damaged files: refused with a FormatError, never a crash (a short fuzz of the effects' bytes).
    std::mt19937_64 rng(7);
    const int refused = iwr_test::fuzz_refusals(bytes, 300, rng);
    std::printf("effects fuzz: %d of 300 refused, the rest read\n", refused);
    CHECK(refused > 0);
}

// The carriage's compliance against an independent computation: each joint's load is the work of
// gravity on the hexapod, platform and payload per unit of that joint's motion (the bodies moved
// rigidly with carriage_transform; central differences), its change c L, and the objective's
// residuals are then the geometry's at the changed joints (predict_legs). The default IWR's base
// joints are centred on {4}'s origin in its xy plane, joints 1 and 2 about +x: their frame is {4}.
IWR_TEST(carriage_compliance_matches_the_virtual_work_of_gravity) {
    const iwr::Geometry g = iwr_test::default_iwr(true);
    const iwr::Vec3 gravity = 9.80665 * iwr::Vec3(-0.9, 0.3, 0.3).normalized();
    const double c[4] = {0.005, 0.004, 0.05, 0.04};  // um/N (slides), urad/(N m) (revolute)
    const iwr::Vec3 hexapod(20, -10, 150), platform(5, -3, 40);
    const EffectTable table{"carriage_compliance",
                            {{"joints", nums({1, 2, 3, 4})},
                             {"compliance", nums({c[0], c[1], c[2], c[3]})},
                             {"max_urad_per_Nm", num(0.5)},
                             {"max_um_per_N", num(0.05)},
                             {"gravity_m_s2", nums({gravity(0), gravity(1), gravity(2)})},
                             {"hexapod_mass_kg", num(400)},
                             {"hexapod_centre_mm", nums({hexapod(0), hexapod(1), hexapod(2)})},
                             {"platform_mass_kg", num(120)},
                             {"platform_centre_mm", nums({platform(0), platform(1), platform(2)})}}};
    const iwr::EffectModel model = iwr::EffectModel::parse({table}, g.n_params());
    CHECK(model.n_params == 4 && model.carriage_index == g.n_params());
    const Data d = sample(g, 8, 3);
    const iwr::EffectObjective obj(g, model, d.q, d.poses, d.legs, d.payload, RowMatrixXd());
    const VectorXd x = VectorXd::Zero(obj.n_params()), xg = VectorXd::Zero(g.n_params());
    const VectorXd res = obj.residuals(x);
    double worst = 0, moved = 0;
    for (int k = 0; k < d.poses.rows(); ++k) {
        const double* qk = d.q.row(k).data();
        const iwr::Mat4 t4 = iwr::carriage_transform(g, xg.data(), qk);
        const iwr::Mat3 r5 = iwr::euler_zyx(d.poses(k, 3), d.poses(k, 4), d.poses(k, 5));
        const iwr::Vec3 p5(d.poses(k, 0), d.poses(k, 1), d.poses(k, 2));
        const iwr::Vec3 centres[3] = {
            t4.topLeftCorner<3, 3>() * hexapod + t4.topRightCorner<3, 1>(), r5 * platform + p5,
            r5 * iwr::Vec3(d.payload(k, 1), d.payload(k, 2), d.payload(k, 3)) + p5};
        const double masses[3] = {400, 120, d.payload(k, 0)};
        const auto work = [&](const std::vector<double>& q) {
            const iwr::Mat4 m = iwr::carriage_transform(g, xg.data(), q.data()) * t4.inverse();
            double w = 0;
            for (int b = 0; b < 3; ++b)
                w += masses[b] * gravity.dot(m.topLeftCorner<3, 3>() * centres[b] + m.topRightCorner<3, 1>());
            return w;
        };
        RowMatrixXd changed(1, 4);
        for (int i = 0; i < 4; ++i) {
            const double h = g.is_prismatic(i) ? 0.1 : 1e-4;
            std::vector<double> plus(qk, qk + 4), minus(qk, qk + 4);
            plus[static_cast<std::size_t>(i)] += h, minus[static_cast<std::size_t>(i)] -= h;
            const double load = (work(plus) - work(minus)) / (2 * h);  // N, or N mm per rad
            changed(0, i) = qk[i] + c[i] * (g.is_prismatic(i) ? 1e-3 : 1e-9) * load;
            moved = std::max(moved, std::fabs(changed(0, i) - qk[i]));
        }
        const RowMatrixXd legs = iwr::predict_legs(g, xg, changed, d.poses.row(k));
        for (int j = 0; j < 6; ++j) worst = std::max(worst, std::fabs(legs(0, j) - d.legs(k, j) - res(6 * k + j)));
    }
    std::printf("carriage compliance: joints moved up to %.3g, residuals within %.3g mm\n", moved, worst);
    CHECK(moved > 1e-3);  // mm on a slide: the effect is there
    CHECK(worst < 1e-9);
    // With the compliances at 0 the objective is the geometry's, the same bits.
    EffectTable rigid = table;
    rigid.entries[1].second = nums({0, 0, 0, 0});
    const iwr::EffectObjective zero(g, iwr::EffectModel::parse({rigid}, g.n_params()), d.q, d.poses, d.legs,
                                    d.payload, RowMatrixXd());
    const iwr::EffectObjective none(g, iwr::EffectModel::parse({}, g.n_params()), d.q, d.poses, d.legs,
                                    d.payload, RowMatrixXd());
    CHECK(zero.cost(x) == none.cost(VectorXd::Zero(none.n_params())));
    // The table's checks.
    const auto parse = [&](EffectTable t, std::vector<EffectTable> more = {}) {
        more.push_back(std::move(t));
        return refusal([&] { (void)iwr::EffectModel::parse(more, g.n_params()); });
    };
    EffectTable bad = table;
    bad.entries[0].second = nums({1, 5});
    CHECK(contains(parse(bad), "effects.carriage_compliance.joints[1]: 5; expected a joint number from 1 to 4"));
    bad = table;
    bad.entries[1].second = nums({0.01, 0.01});
    CHECK(contains(parse(bad), "effects.carriage_compliance.compliance: 2 number(s); expected 4 numbers"));
    CHECK(contains(parse(table, {compliance_table(true, 0.01, iwr::Vec3(0, 0, -9.80665))}),
                   "its gravity and platform differ from effects.compliance's"));
}

// The carriage's slides' thermal expansion: the objective's residuals are the geometry's at the
// readings grown by 1e-6 alpha (T - T_ref) q on the listed slides (predict_legs); a coefficient of
// 0 gives the geometry's cost, the same bits; a revolute joint, per-leg temperatures only and no
// temperatures are refused by name.
IWR_TEST(carriage_thermal_is_the_scales_growth) {
    const iwr::Geometry g = iwr_test::default_iwr(true);
    const double alpha[2] = {11.5, 13.0};
    const EffectTable table{"carriage_thermal",
                            {{"joints", nums({1, 2})},
                             {"alpha_ppm_per_K", nums({alpha[0], alpha[1]})},
                             {"reference_C", num(20)},
                             {"identify", flag(true)},
                             {"per_joint", flag(true)},
                             {"max_ppm_per_K", num(30)}}};
    const iwr::EffectModel model = iwr::EffectModel::parse({table}, g.n_params());
    CHECK(model.n_params == 2 && model.ct_index == g.n_params() && model.any());
    const Data d = sample(g, 8, 4);
    const RowMatrixXd machine = d.temperatures.col(0);
    const iwr::EffectObjective obj(g, model, d.q, d.poses, d.legs, RowMatrixXd(), machine);
    VectorXd x = VectorXd::Zero(obj.n_params());
    x(g.n_params() + 1) = 1.5;  // joint 2's coefficient corrected to 14.5 ppm/K
    const VectorXd res = obj.residuals(x);
    const VectorXd xg = VectorXd::Zero(g.n_params());
    double worst = 0, moved = 0;
    for (int k = 0; k < d.poses.rows(); ++k) {
        RowMatrixXd changed = d.q.row(k);
        const double dt = machine(k, 0) - 20;
        changed(0, 0) += 1e-6 * alpha[0] * dt * d.q(k, 0);
        changed(0, 1) += 1e-6 * (alpha[1] + 1.5) * dt * d.q(k, 1);
        moved = std::max(moved, std::fabs(changed(0, 0) - d.q(k, 0)));
        const RowMatrixXd legs = iwr::predict_legs(g, xg, changed, d.poses.row(k));
        for (int j = 0; j < 6; ++j) worst = std::max(worst, std::fabs(legs(0, j) - d.legs(k, j) - res(6 * k + j)));
    }
    std::printf("carriage thermal: slides moved up to %.3g mm, residuals within %.3g mm\n", moved, worst);
    CHECK(moved > 1e-4);
    CHECK(worst < 1e-9);
    // A coefficient of 0: the geometry's cost, the same bits.
    EffectTable cold = table;
    cold.entries[1].second = nums({0, 0});
    cold.entries[3].second = flag(false);
    const iwr::EffectObjective zero(g, iwr::EffectModel::parse({cold}, g.n_params()), d.q, d.poses, d.legs,
                                    RowMatrixXd(), machine);
    const iwr::EffectObjective none(g, iwr::EffectModel::parse({}, g.n_params()), d.q, d.poses, d.legs,
                                    RowMatrixXd(), RowMatrixXd());
    CHECK(zero.cost(VectorXd::Zero(zero.n_params())) == none.cost(VectorXd::Zero(none.n_params())));
    // Refusals, by name.
    const auto build = [&](const EffectTable& t, const RowMatrixXd& temps) {
        return refusal([&] {
            (void)iwr::EffectObjective(g, iwr::EffectModel::parse({t}, g.n_params()), d.q, d.poses, d.legs,
                                       RowMatrixXd(), temps);
        });
    };
    EffectTable bad = table;
    bad.entries[0].second = nums({1, 3});
    CHECK(contains(build(bad, machine), "effects.carriage_thermal.joints[1]: joint 3 is revolute"));
    bad.entries[0].second = nums({1, 5});  // the joints' checks, shared with carriage_compliance
    CHECK(contains(build(bad, machine), "effects.carriage_thermal.joints[1]: 5; expected a joint number from 1 to 4"));
    bad.entries[0].second = nums({2, 2});
    CHECK(contains(build(bad, machine), "effects.carriage_thermal.joints: joint 2 given twice"));
    bad.entries[0].second = flag(true);
    CHECK(contains(build(bad, machine), "effects.carriage_thermal.joints: expected prismatic joint numbers from 1"));
    CHECK(contains(build(table, d.temperatures), "the carriage_thermal effect"));
    CHECK(contains(build(table, d.temperatures), "the data have one per leg"));
    CHECK(contains(build(table, RowMatrixXd()), "the data have none"));
    bad = table;
    bad.entries[1].second = nums({11.5, 11.5, 11.5});
    CHECK(contains(refusal([&] { (void)iwr::EffectModel::parse({bad}, g.n_params()); }),
                   "effects.carriage_thermal.alpha_ppm_per_K: 3 number(s); expected 2 numbers"));
}

}  // namespace test_effects
