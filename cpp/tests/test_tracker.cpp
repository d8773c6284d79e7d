// C++ tests of the laser-tracker objective: exact Jacobian against central differences (points,
// probe, a hidden reflector), cost = sum of squared residuals, thread-count independence, and the
// finite penalty of a pose whose forward kinematics fails.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <string>

#include "check.hpp"
#include "fixtures.hpp"
#include "iwr/tracker.hpp"

namespace test_tracker {

namespace {

struct Data {
    iwr::RowMatrixXd q, legs, points;
};

// Readings of the robot with errors x at random local poses; points from `truth` (the setup's
// parameters appended to x) through the objective's own prediction, plus an offset so that the
// residuals are not zero.
Data make_data(const iwr::Geometry& g, const iwr::TrackerSetup& s, int n, std::mt19937_64& rng) {
    std::uniform_real_distribution<double> u(-1, 1);
    Data d;
    d.q.resize(n, 4);
    d.legs.resize(n, 6);
    d.points.resize(n, 3 * s.n_points());
    for (int k = 0; k < n; ++k) {
        d.q.row(k) << 1000 * (1 + u(rng)), 500 * (1 + u(rng)), 1.5 * u(rng), 1.0 * u(rng);
        iwr::Vector6d local;
        local << 100 * u(rng), 100 * u(rng), 750 + 60 * u(rng), 0.15 * u(rng), 0.15 * u(rng),
            0.15 * u(rng);
        const iwr::LegVector len = iwr::hexapod_leg_lengths(g.base(), g.platform(), local);
        d.legs.row(k) = (len - g.leg_offsets()).transpose();
        for (int c = 0; c < d.points.cols(); ++c) d.points(k, c) = 2000 * u(rng);
    }
    return d;
}

iwr::VectorXd random_x(int n, std::mt19937_64& rng, double scale) {
    std::uniform_real_distribution<double> u(-scale, scale);
    iwr::VectorXd x(n);
    for (int i = 0; i < n; ++i) x(i) = u(rng);
    return x;
}

// Largest |analytic - central difference| over the Jacobian, relative to its largest entry.
double jacobian_error(const iwr::TrackerObjective& obj, const iwr::VectorXd& x) {
    iwr::VectorXd r;
    iwr::RowMatrixXd jac;
    obj.jacobian(x, &r, &jac);
    double worst = 0, scale = jac.cwiseAbs().maxCoeff();
    for (int i = 0; i < x.size(); ++i) {
        const double h = 1e-6;
        iwr::VectorXd xp = x, xm = x;
        xp(i) += h;
        xm(i) -= h;
        const iwr::VectorXd fd = (obj.residuals(xp) - obj.residuals(xm)) / (2 * h);
        worst = std::max(worst, (fd - jac.col(i)).cwiseAbs().maxCoeff());
    }
    return worst / scale;
}

// SO(3)'s exponential and left Jacobian against their power series summed in long double
// (Exp(w) = sum K^n / n!, J_l(w) = sum K^n / (n + 1)!, K = [w]x, 40 terms): rotvec_matrix and
// so3_left_jacobian take Taylor series of their coefficients below t = |w| = 0.1 and libm's sin and
// cos above; both sides of that bound, and 1e-9 to 3 rad, within a few ulps.
IWR_TEST(so3_exponential_and_left_jacobian_against_their_power_series) {
    std::mt19937_64 rng(11);
    std::normal_distribution<double> n01;
    using Mat3L = Eigen::Matrix<long double, 3, 3>;
    double worst_exp = 0, worst_jac = 0;
    for (int i = 0; i < 3000; ++i) {
        iwr::Vec3 a(n01(rng), n01(rng), n01(rng));
        a.normalize();
        const double t = i < 1000 ? std::pow(10.0, -9.0 + 9.5 * (i / 999.0))  // 1e-9 .. 3
                                  : 0.1 * (1 + 1e-3 * (i - 2000) / 1000.0);   // 0.1 +- 1e-4
        const iwr::Vec3 w = t * a;
        Mat3L k;
        k << 0, -w(2), w(1), w(2), 0, -w(0), -w(1), w(0), 0;
        Mat3L term = Mat3L::Identity(), e = Mat3L::Identity(), j = Mat3L::Identity();
        for (int m = 1; m <= 40; ++m) {
            term = (term * k) / static_cast<long double>(m);   // K^m / m!
            e += term;
            j += term / static_cast<long double>(m + 1);      // K^m / (m + 1)!
        }
        const iwr::Mat3 de = iwr::rotvec_matrix(w) - e.cast<double>();
        const iwr::Mat3 dj = iwr::so3_left_jacobian(w) - j.cast<double>();
        worst_exp = std::max(worst_exp, de.cwiseAbs().maxCoeff());
        worst_jac = std::max(worst_jac, dj.cwiseAbs().maxCoeff());
    }
    std::printf("SO(3): Exp within %.2e, J_l within %.2e of the power series\n", worst_exp,
                worst_jac);
    CHECK(worst_exp < 1e-15);
    CHECK(worst_jac < 1e-15);
}

// The coefficients themselves below t = 0.1, where they are series: within an ulp of the same
// series summed to t^40 in long double (their last terms' coefficients checked too).
IWR_TEST(so3_coefficients_within_an_ulp_below_the_bound) {
    double worst[3] = {0, 0, 0};
    for (int i = 0; i <= 4000; ++i) {
        const double t = i == 0 ? 0.0 : 0.1 * std::pow(1e-6, (4000 - i) / 4000.0) * (1 - 1e-12);
        const double t2 = t * t;
        double got[3];
        iwr::detail::so3_coefficients(t2, got[0], got[1], got[2]);
        // sum (-t2)^k / (2k + 1)!, / (2k + 2)!, / (2k + 3)!
        long double want[3] = {0, 0, 0}, p = 1;
        for (int k = 0; k < 20; ++k) {
            long double f1 = 1;  // (2k + 1)!
            for (int m = 2; m <= 2 * k + 1; ++m) f1 *= m;
            want[0] += p / f1;
            want[1] += p / (f1 * (2 * k + 2));
            want[2] += p / (f1 * (2 * k + 2) * (2 * k + 3));
            p *= -static_cast<long double>(t2);
        }
        for (int q = 0; q < 3; ++q) {
            const double w = static_cast<double>(want[q]);
            const double ulp = std::nextafter(w, HUGE_VAL) - w;
            worst[q] = std::max(worst[q], std::abs(static_cast<double>(got[q] - want[q])) /
                                              std::abs(ulp));
        }
    }
    std::printf("so3_coefficients below t = 0.1: within %.2f, %.2f, %.2f ulp\n", worst[0],
                worst[1], worst[2]);
    CHECK(worst[0] <= 1 && worst[1] <= 1 && worst[2] <= 1);
}

IWR_TEST(points_jacobian) {
    std::mt19937_64 rng(7);
    const iwr::Geometry g = iwr_test::default_iwr();
    iwr::Vector6d reg;
    reg << 2000, -500, 300, M_PI / 2, 0.1, -0.2;  // 2 m away, turned 90 degrees
    iwr::RowMatrixXd refl(3, 3);
    refl << 100, 0, 30, -50, 90, 30, -50, -90, 30;
    const iwr::TrackerSetup s = iwr::TrackerSetup::points(reg, refl);
    Data d = make_data(g, s, 12, rng);
    d.points.block<1, 3>(3, 3).setConstant(std::numeric_limits<double>::quiet_NaN());  // hidden
    iwr::Vector6d home;
    home << 0, 0, 750, 0, 0, 0;
    const iwr::TrackerObjective obj(g, s, d.q, d.legs, d.points, iwr::VectorXd::Zero(g.n_params()),
                                    home);
    CHECK(obj.n_params() == 58 + 6 + 9);
    CHECK(obj.n_seen() == 12 * 3 - 1);
    iwr::VectorXd x = random_x(obj.n_params(), rng, 0.3);
    x.segment(58 + 3, 3) *= 0.1;  // the registration's rotation vector (rad)
    const double err = jacobian_error(obj, x);
    std::printf("points: Jacobian vs central differences, relative error %.2e\n", err);
    CHECK(err < 1e-6);
    // A large registration correction (45 degrees) exercises the left Jacobian of SO(3).
    iwr::VectorXd x2 = x;
    x2.segment(58 + 3, 3) << 0.5, -0.4, 0.3;
    CHECK(jacobian_error(obj, x2) < 1e-6);
    // cost == sum of squared residuals; a hidden reflector has zero residuals.
    const iwr::VectorXd r = obj.residuals(x);
    CHECK(std::abs(obj.cost(x) - r.squaredNorm()) <= 1e-12 * r.squaredNorm());
    CHECK(r.segment(3 * (3 * 3 + 1), 3).isZero(0));
}

IWR_TEST(probe_jacobian) {
    std::mt19937_64 rng(8);
    const iwr::Geometry g = iwr_test::default_iwr();
    iwr::Vector6d reg, probe;
    reg << -1500, 2000, 100, -M_PI / 2, 0.05, 0.1;
    probe << 20, -10, 80, 0.3, -0.2, 0.1;
    const iwr::TrackerSetup s = iwr::TrackerSetup::probe(reg, probe, 100.0);
    const Data d = make_data(g, s, 8, rng);
    iwr::Vector6d home;
    home << 0, 0, 750, 0, 0, 0;
    const iwr::TrackerObjective obj(g, s, d.q, d.legs, d.points, iwr::VectorXd::Zero(g.n_params()),
                                    home);
    CHECK(obj.n_params() == 58 + 12);
    iwr::VectorXd x = random_x(obj.n_params(), rng, 0.3);
    x.segment(58 + 9, 3) << 0.4, 0.2, -0.3;  // a large probe rotation correction
    const double err = jacobian_error(obj, x);
    std::printf("probe: Jacobian vs central differences, relative error %.2e\n", err);
    CHECK(err < 1e-6);
}

IWR_TEST(batch_and_failures) {
    std::mt19937_64 rng(9);
    const iwr::Geometry g = iwr_test::default_iwr();
    iwr::Vector6d reg;
    reg << 2000, 0, 0, M_PI / 2, 0, 0;
    iwr::RowMatrixXd refl(2, 3);
    refl << 100, 0, 30, -50, 90, 30;
    const iwr::TrackerSetup s = iwr::TrackerSetup::points(reg, refl);
    Data d = make_data(g, s, 40, rng);
    iwr::Vector6d home;
    home << 0, 0, 750, 0, 0, 0;
    const iwr::TrackerObjective obj(g, s, d.q, d.legs, d.points, iwr::VectorXd::Zero(g.n_params()),
                                    home);
    const int m = 37;
    iwr::RowMatrixXd X(m, obj.n_params());
    for (int i = 0; i < m; ++i) X.row(i) = random_x(obj.n_params(), rng, 0.4).transpose();
    iwr::VectorXd one(m), two(m), five(m);
    iwr::ThreadPool p1(1), p2(2), p5(5);
    obj.cost_batch(X.data(), m, one.data(), p1);
    obj.cost_batch(X.data(), m, two.data(), p2);
    obj.cost_batch(X.data(), m, five.data(), p5);
    CHECK(one == two);
    CHECK(one == five);
    for (int i = 0; i < m; ++i) CHECK(one(i) == obj.cost(iwr::VectorXd(X.row(i).transpose())));
    // Leg 1 made 2 m shorter: no pose can close (a negative length): a finite penalty per pose,
    // named by failures().
    const iwr::TrackerObjective& obj2 = obj;
    iwr::VectorXd x = iwr::VectorXd::Zero(obj2.n_params());
    x(g.idx_offset(0)) = -2000;
    const auto f = obj2.failures(x);
    CHECK(static_cast<int>(f.size()) == obj2.n_poses());
    const double c = obj2.cost(x);
    CHECK(std::isfinite(c));
    CHECK(c >= f.size() * 2 * 3 * iwr::TrackerObjective::kFailedResidual *
                   iwr::TrackerObjective::kFailedResidual);
    if (!f.empty()) CHECK(f[0].second.find("pose " + std::to_string(f[0].first)) != std::string::npos);
    iwr::VectorXd r;
    iwr::RowMatrixXd jac;
    obj2.jacobian(x, &r, &jac);
    CHECK(r.allFinite() && jac.allFinite());
    CHECK(jac.middleRows(3 * 2 * f[0].first, 6).isZero(0));
}

IWR_TEST(tracker_validation) {
    const iwr::Geometry g = iwr_test::default_iwr();
    iwr::Vector6d reg = iwr::Vector6d::Zero(), home;
    home << 0, 0, 750, 0, 0, 0;
    bool thrown = false;
    try {
        iwr::TrackerSetup::points(reg, iwr::RowMatrixXd(0, 3));
    } catch (const std::invalid_argument& e) {
        thrown = std::string(e.what()).find("reflectors") != std::string::npos;
    }
    CHECK(thrown);
    const iwr::TrackerSetup s = iwr::TrackerSetup::points(reg, iwr::RowMatrixXd::Zero(1, 3));
    iwr::RowMatrixXd q = iwr::RowMatrixXd::Constant(2, 4, 100), legs = iwr::RowMatrixXd::Constant(2, 6, 150);
    iwr::RowMatrixXd pts = iwr::RowMatrixXd::Zero(2, 3);
    pts(1, 1) = std::numeric_limits<double>::quiet_NaN();  // one NaN of three
    thrown = false;
    try {
        iwr::TrackerObjective(g, s, q, legs, pts, iwr::VectorXd::Zero(g.n_params()), home);
    } catch (const std::invalid_argument& e) {
        thrown = std::string(e.what()).find("pose 1, point 1") != std::string::npos;
    }
    CHECK(thrown);
    // Platform joints on one line through the origin of {5}: the kernel could not recover the
    // platform's rotation from them; refused by name before any solve.
    iwr::LegMatrix line = g.platform();
    for (int j = 0; j < 6; ++j) line.row(j) << 100.0 * (j - 2.5), 0, 0;
    const iwr::Geometry bad("PPRR", g.dh(), g.base(), line, g.leg_offsets());
    const iwr::RowMatrixXd pts2 = iwr::RowMatrixXd::Zero(2, 3);
    thrown = false;
    try {
        iwr::TrackerObjective(bad, s, q, legs, pts2, iwr::VectorXd::Zero(bad.n_params()), home);
    } catch (const std::invalid_argument& e) {
        thrown = std::string(e.what()).find("platform joints: all on one line") != std::string::npos;
    }
    CHECK(thrown);
}

}  // namespace

}  // namespace test_tracker
