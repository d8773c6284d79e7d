// Bindings of the double ballbar's objectives (iwr/ballbar.hpp, and with the effects
// iwr/effects_ballbar.hpp). Private: iwr.ballbar is the public API (BallbarProblem's and
// BallbarEffectProblem's cost and batch costs run on them). The set-ups travel as a dict of arrays
// (bar_names, platform_balls (S, 3), fixed_balls (S, 3), offsets (S,), ranges (S, 2), NaN: none),
// as the problem file's fields do.
#include <cmath>
#include <memory>

#include "common.hpp"
#include "iwr/ballbar.hpp"
#include "iwr/effects_ballbar.hpp"

namespace iwr::python {

std::vector<BarSetup> bar_setups(const py::dict& d) {
    const auto names = d["bar_names"].cast<std::vector<std::string>>();
    const auto p = d["platform_balls"].cast<RowMatrixXd>(), f = d["fixed_balls"].cast<RowMatrixXd>();
    const auto o = d["offsets"].cast<VectorXd>();
    const auto r = d["ranges"].cast<RowMatrixXd>();
    const Eigen::Index s = static_cast<Eigen::Index>(names.size());
    if (p.rows() != s || p.cols() != 3 || f.rows() != s || f.cols() != 3 || o.size() != s || r.rows() != s ||
        r.cols() != 2)
        throw std::invalid_argument("ballbar set-ups: expected " + std::to_string(s) +
                                    " names, platform_balls and fixed_balls (S, 3), offsets (S,), ranges (S, 2)");
    std::vector<BarSetup> out;
    for (Eigen::Index i = 0; i < s; ++i) {
        BarSetup b;
        b.name = names[static_cast<std::size_t>(i)];
        b.platform_ball = p.row(i).transpose();
        b.fixed_ball = f.row(i).transpose();
        b.offset = o(i);
        b.has_range = !std::isnan(r(i, 0));  // NaN: no range
        if (b.has_range) b.range_min = r(i, 0), b.range_max = r(i, 1);
        out.push_back(std::move(b));
    }
    return out;
}

void bar_setups_py(py::dict& d, const std::vector<BarSetup>& bars) {
    const Eigen::Index s = static_cast<Eigen::Index>(bars.size());
    std::vector<std::string> names;
    RowMatrixXd p(s, 3), f(s, 3), r(s, 2);
    VectorXd o(s);
    for (Eigen::Index i = 0; i < s; ++i) {
        const BarSetup& b = bars[static_cast<std::size_t>(i)];
        names.push_back(b.name);
        p.row(i) = b.platform_ball.transpose();
        f.row(i) = b.fixed_ball.transpose();
        o(i) = b.offset;
        r.row(i) << (b.has_range ? b.range_min : NAN), (b.has_range ? b.range_max : NAN);
    }
    d["bar_names"] = names;
    d["platform_balls"] = p;
    d["fixed_balls"] = f;
    d["offsets"] = o;
    d["ranges"] = r;
}

namespace {

// What the two ballbar objectives share in Python: sizes, cost, residuals, failures, batch costs.
template <class P>
void ballbar_methods(py::class_<P>& c) {
    c.def_property_readonly("n_params", [](const P& o) { return o.obj_->n_params(); })
        .def_property_readonly("n_poses", [](const P& o) { return o.obj_->n_poses(); })
        .def_property_readonly("whitened", [](const P& o) { return o.obj_->whitened(); })
        .def("cost",
             [](const P& o, const VecRef& x) {
                 py::gil_scoped_release release;
                 return o.obj_->cost(x);
             },
             py::arg("x"))
        .def("residuals",
             [](const P& o, const VecRef& x) {
                 py::gil_scoped_release release;
                 return o.obj_->residuals(x);
             },
             py::arg("x"))
        .def("failures", [](const P& o, const VecRef& x) { return o.obj_->failures(x); }, py::arg("x"),
             "Poses whose forward kinematics fails at x: [(index, message)].")
        .def("cost_batch", &P::cost_batch, py::arg("X"), py::arg("threads") = 0);
}

}  // namespace

void bind_ballbar(py::module_& m) {
    using PyBallbarObjective = Pooled<BallbarObjective>;
    py::class_<PyBallbarObjective> plain(m, "BallbarObjective");
    plain.def(py::init([](const Geometry& g, const py::dict& bars, const RowMatrixXd& q, const RowMatrixXd& legs,
                          const std::vector<int>& bar, const VectorXd& distance, const VectorXd& reference,
                          const Vector6d& home, const RowMatrixXd& whitening, double tolerance) {
                  std::vector<BarSetup> setups = bar_setups(bars);
                  std::shared_ptr<BallbarObjective> obj;
                  {
                      py::gil_scoped_release release;
                      obj = std::make_shared<BallbarObjective>(g, std::move(setups), q, legs, bar, distance,
                                                               reference, home, tolerance);
                      obj->set_whitening(whitening);
                  }
                  return std::make_unique<PyBallbarObjective>(std::move(obj));
              }),
              py::arg("geometry"), py::arg("bars"), py::arg("q"), py::arg("legs"), py::arg("bar"),
              py::arg("distance"), py::arg("reference"), py::arg("home"), py::arg("whitening") = RowMatrixXd(),
              py::arg("tolerance") = 1e-10);
    ballbar_methods(plain);

    // With the effects (iwr/effects_ballbar.hpp), for iwr.ballbar.effects.BallbarEffectProblem.
    using PyBallbarEffectObjective = Pooled<BallbarEffectObjective>;
    py::class_<PyBallbarEffectObjective> effects(m, "BallbarEffectObjective");
    effects.def(py::init([](const Geometry& g, const py::object& tables, const py::dict& bars, const RowMatrixXd& q,
                            const RowMatrixXd& legs, const std::vector<int>& bar, const VectorXd& distance,
                            const RowMatrixXd& payload, const RowMatrixXd& temperatures, const VectorXd& reference,
                            const Vector6d& home, const RowMatrixXd& whitening, double tolerance) {
                    EffectModel model = EffectModel::parse(effect_tables(tables), g.n_params());
                    std::vector<BarSetup> setups = bar_setups(bars);
                    std::shared_ptr<BallbarEffectObjective> obj;
                    {
                        py::gil_scoped_release release;
                        obj = std::make_shared<BallbarEffectObjective>(g, std::move(model), std::move(setups), q,
                                                                       legs, bar, distance, payload, temperatures,
                                                                       reference, home, tolerance);
                        obj->set_whitening(whitening);
                    }
                    return std::make_unique<PyBallbarEffectObjective>(std::move(obj));
                }),
                py::arg("geometry"), py::arg("effects"), py::arg("bars"), py::arg("q"), py::arg("legs"),
                py::arg("bar"), py::arg("distance"), py::arg("payload"), py::arg("temperatures"),
                py::arg("reference"), py::arg("home"), py::arg("whitening") = RowMatrixXd(),
                py::arg("tolerance") = 1e-11);
    ballbar_methods(effects);
}

}  // namespace iwr::python
