// C++ tests of the implicit loop estimator: exact derivatives against central differences, exact
// recovery from noise-free data, the redundancy numbers' sum, and argument checks.
#include <cmath>
#include <cstdio>
#include <random>
#include <stdexcept>
#include <vector>

#include "check.hpp"
#include "fixtures.hpp"
#include "iwr/implicit_loop.hpp"
#include "iwr/model.hpp"

namespace test_implicit_loop {

namespace {

// World poses: 0T4(x, q) times a local pose around 750 mm above the base plate.
struct Data {
    iwr::RowMatrixXd q, poses, legs;
};

Data make_data(const iwr::Geometry& g, const iwr::VectorXd& x, int n, std::mt19937_64& rng) {
    std::uniform_real_distribution<double> u(-1, 1);
    Data d;
    d.q.resize(n, g.n_joints());
    d.poses.resize(n, 6);
    for (int k = 0; k < n; ++k) {
        for (int i = 0; i < g.n_joints(); ++i) d.q(k, i) = g.is_prismatic(i) ? 500 * (1 + u(rng)) : u(rng);
        const iwr::Mat4 t4 = iwr::carriage_transform(g, x.data(), d.q.row(k).data());
        iwr::Mat4 local = iwr::Mat4::Identity();
        local.topLeftCorner<3, 3>() = iwr::euler_zyx(0.17 * u(rng), 0.17 * u(rng), 0.17 * u(rng));
        local.topRightCorner<3, 1>() = iwr::Vec3(120 * u(rng), 120 * u(rng), 750 + 80 * u(rng));
        const iwr::Mat4 t = t4 * local;
        const iwr::Mat3 r = t.topLeftCorner<3, 3>();
        // Z-Y-X Euler angles of r (beta away from +-pi/2 for these poses is not needed: the
        // round trip through euler_zyx is checked below).
        const double beta = std::atan2(-r(2, 0), std::hypot(r(0, 0), r(1, 0)));
        d.poses.row(k) << t(0, 3), t(1, 3), t(2, 3), std::atan2(r(1, 0), r(0, 0)), beta,
            std::atan2(r(2, 1), r(2, 2));
        CHECK((iwr::euler_zyx(d.poses(k, 3), d.poses(k, 4), d.poses(k, 5)) - r).norm() < 1e-9);
    }
    d.legs = iwr::predict_legs(g, x, d.q, d.poses);
    return d;
}

iwr::VectorXd random_errors(const iwr::Geometry& g, std::mt19937_64& rng) {
    std::uniform_real_distribution<double> u(-0.5, 0.5);
    iwr::VectorXd x(g.n_params());
    for (int i = 0; i < x.size(); ++i) x(i) = u(rng);
    for (int i = 0; i < g.n_joints(); ++i) {  // angles: +-0.5 degree
        x(4 * i) *= M_PI / 180;
        x(4 * i + 3) *= M_PI / 180;
    }
    return x;
}

IWR_TEST(derivatives) {
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> u(-1, 1);
    for (bool carriage : {true, false}) {
        const iwr::Geometry g = iwr_test::default_iwr(carriage);
        const iwr::VectorXd x = random_errors(g, rng);
        const Data d = make_data(g, x, 5, rng);
        const int ny = g.n_joints() + 6;
        iwr::RowMatrixXd corr(5, ny);
        for (int k = 0; k < 5; ++k) {
            for (int c = 0; c < ny; ++c) corr(k, c) = (c >= ny - 3 ? 0.3 : 0.5) * u(rng);
        }
        const iwr::LoopJacobians j = iwr::loop_jacobians(g, x, d.q, d.poses, corr);
        // Central differences: step 1e-5 (mm or rad), truncation ~1e-10 * 1e3 lever, round-off
        // ~1e-13 / 1e-5: both far below the 1e-6 tolerance.
        const double h = 1e-5;
        double worst = 0;
        for (int i = 0; i < g.n_params(); ++i) {
            iwr::VectorXd xp = x, xm = x;
            xp(i) += h;
            xm(i) -= h;
            const iwr::RowMatrixXd lp = iwr::loop_jacobians(g, xp, d.q, d.poses, corr).legs;
            const iwr::RowMatrixXd lm = iwr::loop_jacobians(g, xm, d.q, d.poses, corr).legs;
            for (int k = 0; k < 5; ++k)
                for (int l = 0; l < 6; ++l)
                    worst = std::max(worst, std::abs((lp(k, l) - lm(k, l)) / (2 * h) - j.jac_x(6 * k + l, i)));
        }
        for (int c = 0; c < ny; ++c) {
            iwr::RowMatrixXd cp = corr, cm = corr;
            cp.col(c).array() += h;
            cm.col(c).array() -= h;
            const iwr::RowMatrixXd lp = iwr::loop_jacobians(g, x, d.q, d.poses, cp).legs;
            const iwr::RowMatrixXd lm = iwr::loop_jacobians(g, x, d.q, d.poses, cm).legs;
            for (int k = 0; k < 5; ++k)
                for (int l = 0; l < 6; ++l)
                    worst = std::max(worst, std::abs((lp(k, l) - lm(k, l)) / (2 * h) - j.jac_y(6 * k + l, c)));
        }
        std::printf("  derivatives (%s): worst |analytic - central difference| %.2e\n",
                    carriage ? "hybrid" : "hexapod", worst);
        CHECK(worst < 1e-6);
        // Zero corrections reproduce predict_legs.
        const iwr::RowMatrixXd l0 = iwr::loop_jacobians(g, x, d.q, d.poses, iwr::RowMatrixXd()).legs;
        CHECK((l0 - d.legs).cwiseAbs().maxCoeff() < 1e-9);
    }
}

iwr::RowMatrixXd sigma_matrix(int n, int nj, double legs, double q, double pos, double ori) {
    iwr::RowMatrixXd s(n, 6 + nj + 6);
    s.leftCols(6).setConstant(legs);
    s.middleCols(6, nj).setConstant(q);
    s.middleCols(6 + nj, 3).setConstant(pos);
    s.rightCols(3).setConstant(ori);
    return s;
}

// The standalone hexapod: all 42 parameters are identifiable (docs/identifiability.md).
IWR_TEST(noise_free_recovery) {
    std::mt19937_64 rng(11);
    const iwr::Geometry g = iwr_test::default_iwr(false);
    const iwr::VectorXd truth = random_errors(g, rng);
    const Data d = make_data(g, truth, 30, rng);
    std::vector<int> active(42);
    for (int i = 0; i < 42; ++i) active[static_cast<size_t>(i)] = i;
    const iwr::RowMatrixXd sigma = sigma_matrix(30, 0, 0.002, 0, 0.02, 2e-5);
    const iwr::ImplicitLoopResult r = iwr::implicit_loop(
        g, iwr::VectorXd::Zero(42), active, d.q, d.poses, d.legs, sigma, iwr::RowMatrixXd());
    std::printf("  noise-free: status %d (%s), %d iterations, cost %.2e, max |x - truth| %.2e\n",
                r.status, r.message.c_str(), r.iterations, r.cost, (r.x - truth).cwiseAbs().maxCoeff());
    CHECK(r.status > 0);
    CHECK((r.x - truth).cwiseAbs().maxCoeff() < 1e-9);
    CHECK(r.corrections.cwiseAbs().maxCoeff() < 1e-9);
    CHECK(r.reciprocal_condition > 1e-12);
}

IWR_TEST(noisy_statistics) {
    std::mt19937_64 rng(12);
    std::normal_distribution<double> gauss;
    const iwr::Geometry g = iwr_test::default_iwr(true);
    const int n = 40, nj = 4;
    const iwr::VectorXd truth = random_errors(g, rng);
    Data d = make_data(g, truth, n, rng);
    for (int k = 0; k < n; ++k) {
        for (int j = 0; j < 6; ++j) d.legs(k, j) += 0.002 * gauss(rng);
        for (int c = 0; c < 3; ++c) d.poses(k, c) += 0.02 * gauss(rng);
        for (int i = 0; i < nj; ++i) d.q(k, i) += (g.is_prismatic(i) ? 0.005 : 5e-6) * gauss(rng);
    }
    // The hybrid robot's six unidentifiable parameters held fixed (docs/identifiability.md):
    // joint2.da (5), joint3.dd (10), joint4.dalpha, da, dd, dtheta (12..15).
    std::vector<int> active;
    for (int i = 0; i < g.n_params(); ++i)
        if (i != 5 && i != 10 && (i < 12 || i > 15)) active.push_back(i);
    iwr::RowMatrixXd sigma = sigma_matrix(n, nj, 0.002, 0, 0.02, 0);
    for (int i = 0; i < nj; ++i) sigma.col(6 + i).setConstant(g.is_prismatic(i) ? 0.005 : 5e-6);
    const iwr::ImplicitLoopResult r = iwr::implicit_loop(
        g, iwr::VectorXd::Zero(g.n_params()), active, d.q, d.poses, d.legs, sigma,
        iwr::RowMatrixXd());
    const double dof = 6.0 * n - static_cast<double>(active.size());
    std::printf("  noisy: status %d, cost %.1f for %g degrees of freedom, redundancy sum %.9f\n",
                r.status, r.cost, dof, r.redundancy.sum());
    CHECK(r.status > 0);
    CHECK(std::abs(r.redundancy.sum() - dof) < 1e-6);
    // Exact readings (orientation, sigma 0) keep a zero correction and no redundancy.
    CHECK(r.corrections.rightCols(3).cwiseAbs().maxCoeff() == 0.0);
    CHECK(r.redundancy.rightCols(3).cwiseAbs().maxCoeff() == 0.0);
    CHECK(r.redundancy.minCoeff() >= -1e-12 && r.redundancy.maxCoeff() <= 1 + 1e-12);
    // Each pose's statistic has 6 degrees of freedom (6 closure equations).
    CHECK(r.pose_dof.minCoeff() == 6 && r.pose_dof.maxCoeff() == 6);
    // The cost is the sum of the squared normalised residuals.
    CHECK(std::abs(r.residuals.squaredNorm() - r.cost) < 1e-9 * r.cost);
    CHECK((r.covariance - r.covariance.transpose()).cwiseAbs().maxCoeff() <=
          1e-9 * r.covariance.cwiseAbs().maxCoeff());
    CHECK(r.covariance.diagonal().minCoeff() > 0);
    CHECK(r.reciprocal_condition > 1e-14);
}

// The tracker model: residuals of reflector points (one unseen) and of a probe pose, their exact
// derivatives against central differences in every parameter (robot and setup) and correction.
IWR_TEST(tracker_derivatives) {
    std::mt19937_64 rng(21);
    std::uniform_real_distribution<double> u(-1, 1);
    const iwr::Geometry g = iwr_test::default_iwr(true);
    const int n = 4, nj = g.n_joints(), ny = nj + 6;
    const iwr::VectorXd xr = random_errors(g, rng);
    const Data d = make_data(g, xr, n, rng);
    iwr::Vector6d reg;
    reg << 2000, 10, -20, M_PI / 2, 0.1, -0.05;
    iwr::RowMatrixXd refl(3, 3);
    refl << 120, 0, 40, -60, 104, 40, -60, -104, 40;
    iwr::Vector6d probe;
    probe << 30, -20, 60, 0.3, -0.2, 0.1;
    for (bool is_probe : {false, true}) {
        iwr::TrackerLoopData data;
        data.setup = is_probe ? iwr::TrackerSetup::probe(reg, probe, 100.0)
                              : iwr::TrackerSetup::points(reg, refl);
        const int nb = is_probe ? 2 : 3, ns = data.setup.n_params();
        data.reference = d.poses;
        data.measured.resize(n, is_probe ? 6 : 9);
        data.whitening.resize(n, 9 * nb);
        for (int k = 0; k < n; ++k) {
            for (int c = 0; c < data.measured.cols(); ++c)
                data.measured(k, c) = (is_probe && c >= 3) ? 0.2 * u(rng) : 2000 * u(rng);
            for (int c = 0; c < 9 * nb; ++c) data.whitening(k, c) = u(rng);
        }
        if (!is_probe) data.measured.block(1, 3, 1, 3).setConstant(std::nan(""));  // unseen
        iwr::VectorXd x(g.n_params() + ns);
        x.head(g.n_params()) = xr;
        for (int i = 0; i < ns; ++i) x(g.n_params() + i) = (i % 6 >= 3 ? 0.02 : 1.0) * u(rng);
        iwr::RowMatrixXd sigma(n, 6 + nj), corr(n, ny);
        sigma.leftCols(6).setConstant(0.002);
        for (int i = 0; i < nj; ++i) sigma.col(6 + i).setConstant(i == 1 ? 0.0 : 0.005);
        for (int k = 0; k < n; ++k)
            for (int c = 0; c < ny; ++c) corr(k, c) = (c >= ny - 3 ? 0.01 : 0.3) * u(rng);
        const iwr::LoopJacobians j = iwr::tracker_loop_jacobians(g, data, x, d.q, d.legs, sigma, corr);
        const double h = 1e-6;
        double worst = 0, scale = std::max(j.jac_x.cwiseAbs().maxCoeff(), j.jac_y.cwiseAbs().maxCoeff());
        auto res = [&](const iwr::VectorXd& xx, const iwr::RowMatrixXd& cc) {
            return iwr::tracker_loop_jacobians(g, data, xx, d.q, d.legs, sigma, cc).legs;
        };
        const int nr = static_cast<int>(j.legs.cols());
        for (int i = 0; i < x.size(); ++i) {
            iwr::VectorXd xp = x, xm = x;
            xp(i) += h;
            xm(i) -= h;
            const iwr::RowMatrixXd diff = (res(xp, corr) - res(xm, corr)) / (2 * h);
            for (int k = 0; k < n; ++k)
                for (int r = 0; r < nr; ++r)
                    worst = std::max(worst, std::abs(diff(k, r) - j.jac_x(nr * k + r, i)));
        }
        for (int c = 0; c < ny; ++c) {
            iwr::RowMatrixXd cp = corr, cm = corr;
            cp.col(c).array() += h;
            cm.col(c).array() -= h;
            const iwr::RowMatrixXd diff = (res(x, cp) - res(x, cm)) / (2 * h);
            for (int k = 0; k < n; ++k)
                for (int r = 0; r < nr; ++r)
                    worst = std::max(worst, std::abs(diff(k, r) - j.jac_y(nr * k + r, c)));
        }
        std::printf("  tracker derivatives (%s): worst |analytic - central difference| %.2e of %.2e\n",
                    is_probe ? "probe" : "points", worst, scale);
        // Round-off: residuals up to ~1e6 (random whitening of metre-size misfits) times 1e-16 / h.
        CHECK(worst < 1e-8 * scale);
        if (!is_probe) CHECK(j.legs.row(1).segment(6 + nj + 3, 3).isZero(0.0));
    }
}

IWR_TEST(argument_checks) {
    const iwr::Geometry g = iwr_test::default_iwr(false);
    std::mt19937_64 rng(3);
    const Data d = make_data(g, iwr::VectorXd::Zero(42), 3, rng);
    std::vector<int> active = {0, 1, 2};
    auto throws = [&](const iwr::RowMatrixXd& sigma, const std::vector<int>& act) {
        try {
            iwr::implicit_loop(g, iwr::VectorXd::Zero(42), act, d.q, d.poses, d.legs, sigma,
                               iwr::RowMatrixXd());
        } catch (const std::invalid_argument&) {
            return true;
        }
        return false;
    };
    CHECK(throws(sigma_matrix(3, 0, 0.0, 0, 0.02, 0), active));    // leg sigma 0
    CHECK(throws(sigma_matrix(3, 0, 0.002, 0, -1, 0), active));    // negative sigma
    CHECK(throws(sigma_matrix(2, 0, 0.002, 0, 0.02, 0), active));  // wrong shape
    CHECK(throws(sigma_matrix(3, 0, 0.002, 0, 0.02, 0), {0, 0}));  // repeated index
    CHECK(throws(sigma_matrix(3, 0, 0.002, 0, 0.02, 0), {42}));    // out of range
    CHECK(!throws(sigma_matrix(3, 0, 0.002, 0, 0.02, 0), active));
}

}  // namespace

}  // namespace test_implicit_loop
