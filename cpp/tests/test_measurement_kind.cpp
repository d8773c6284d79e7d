// The extension point of iwr/measurement_kind.hpp exercised by a kind that is not built in: a
// straight line v = a + b u measured with errors in both readings (u_k, v_k). Its objective (the
// sum of squared v residuals) runs through the DE engine as any objective does, and its residual
// model (the v residual and the correction of u, each over its standard deviation) through the
// one implicit-loop solver; both are checked against closed forms (ordinary least squares, and
// Deming's errors-in-variables regression), independent of the code under test.
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "check.hpp"
#include "iwr/de.hpp"
#include "iwr/measurement_kind.hpp"

namespace test_measurement_kind {

namespace {

struct LineData {
    std::vector<double> u, v;
};

LineData line_data(int n, double a, double b, double su, double sv, std::uint64_t seed) {
    std::mt19937_64 rng(seed);
    std::normal_distribution<double> g(0, 1);
    std::uniform_real_distribution<double> t(-10, 10);
    LineData d;
    for (int k = 0; k < n; ++k) {
        const double u = t(rng);
        d.u.push_back(u + su * g(rng));
        d.v.push_back(a + b * u + sv * g(rng));
    }
    return d;
}

// The new kind's objective: parameters (a, b), cost sum_k (a + b u_k - v_k)^2.
class LineObjective {
public:
    explicit LineObjective(LineData d) : d_(std::move(d)) {}
    int n_params() const { return 2; }
    int n_poses() const { return static_cast<int>(d_.u.size()); }
    struct Workspace {};
    Workspace make_workspace() const { return {}; }
    double cost(const double* x, Workspace&) const {
        double s = 0;
        for (std::size_t k = 0; k < d_.u.size(); ++k) {
            const double r = x[0] + x[1] * d_.u[k] - d_.v[k];
            s += r * r;
        }
        return s;
    }
    double cost(const iwr::VectorXd& x) const {
        Workspace ws;
        return cost(x.data(), ws);
    }

private:
    LineData d_;
};

// Sums of the centred readings: (mean u, mean v, s_uu, s_vv, s_uv).
struct Moments {
    double mu, mv, suu, svv, suv;
};
Moments moments(const LineData& d) {
    const double n = static_cast<double>(d.u.size());
    Moments m{0, 0, 0, 0, 0};
    for (std::size_t k = 0; k < d.u.size(); ++k) m.mu += d.u[k] / n, m.mv += d.v[k] / n;
    for (std::size_t k = 0; k < d.u.size(); ++k) {
        const double du = d.u[k] - m.mu, dv = d.v[k] - m.mv;
        m.suu += du * du, m.svv += dv * dv, m.suv += du * dv;
    }
    return m;
}

}  // namespace

IWR_TEST(new_objective_runs_through_the_de_engine) {
    static_assert(iwr::is_objective_v<LineObjective>, "the line meets the objective requirements");
    const LineData d = line_data(40, 1.5, -0.7, 0.05, 0.1, 5);
    const LineObjective obj(d);
    CHECK(iwr::objective_failures(obj, iwr::VectorXd::Zero(2)).empty());  // it has no failures()
    iwr::de::ReducedObjective<LineObjective> f(obj);
    iwr::de::Settings s;
    s.strategy = iwr::de::Strategy::rand1bin;
    s.lower = {-5, -5};
    s.upper = {5, 5};
    s.population_size = 20;
    s.seed = 3;
    iwr::ThreadPool pool(2);
    auto st = iwr::de::init(s, f, pool);
    iwr::de::Stop stop;
    stop.max_generations = 400;
    iwr::de::run(st, f, pool, stop, [](const iwr::de::State&) { return false; });
    // Ordinary least squares in closed form.
    const Moments m = moments(d);
    const double b = m.suv / m.suu, a = m.mv - b * m.mu;
    const iwr::VectorXd x = f.full(st.best_x().data());
    std::printf("  DE on the line: (%.12f, %.12f), least squares (%.12f, %.12f)\n", x(0), x(1), a, b);
    CHECK(std::fabs(x(0) - a) < 1e-7 && std::fabs(x(1) - b) < 1e-7);
}

IWR_TEST(new_residual_model_runs_through_the_implicit_loop) {
    const double su = 0.2, sv = 0.1;
    const LineData d = line_data(50, 1.5, -0.7, su, sv, 8);
    const int n = static_cast<int>(d.u.size());
    iwr::LoopModel model;
    model.n = n, model.ny = 1, model.nr = 2, model.np = 2;
    model.free.assign(static_cast<std::size_t>(n), {0});
    model.rows.assign(static_cast<std::size_t>(n), {0, 1});
    model.eval = [&d, su, sv](const iwr::VectorXd& x, int k, const double* y, double* r, iwr::RowMatrixXd* jx,
                              iwr::RowMatrixXd* jy) {
        const double u = d.u[static_cast<std::size_t>(k)] + y[0];
        r[0] = (x(0) + x(1) * u - d.v[static_cast<std::size_t>(k)]) / sv;
        r[1] = y[0] / su;
        if (!jx) return;
        jx->setZero();
        jy->setZero();
        (*jx)(0, 0) = 1 / sv, (*jx)(0, 1) = u / sv;
        (*jy)(0, 0) = x(1) / sv, (*jy)(1, 0) = 1 / su;
    };
    const iwr::ImplicitLoopResult r = iwr::solve_loop(model, iwr::VectorXd::Zero(2), {0, 1},
                                                      iwr::RowMatrixXd::Zero(n, 1));
    // Deming regression (errors in both variables, variance ratio delta = sv^2 / su^2).
    const Moments m = moments(d);
    const double delta = sv * sv / (su * su);
    const double b = (m.svv - delta * m.suu + std::sqrt(std::pow(m.svv - delta * m.suu, 2) + 4 * delta * m.suv * m.suv)) /
                     (2 * m.suv);
    const double a = m.mv - b * m.mu;
    std::printf("  implicit loop on the line: status %d, (%.12f, %.12f), Deming (%.12f, %.12f), dof %d\n", r.status,
                r.x(0), r.x(1), a, b, r.dof);
    CHECK(r.status > 0);
    CHECK(std::fabs(r.x(0) - a) < 1e-9 && std::fabs(r.x(1) - b) < 1e-9);
    CHECK(r.dof == 2 * n - n - 2);
}

}  // namespace test_measurement_kind
