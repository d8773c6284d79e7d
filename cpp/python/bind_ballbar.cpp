// Bindings of the double ballbar's objective (iwr/ballbar.hpp). Private: iwr.ballbar is the public
// API (BallbarProblem's cost and batch costs run on it).
#include <memory>

#include "common.hpp"
#include "iwr/ballbar.hpp"

namespace iwr::python {

std::vector<BarSetup> bar_setups(const py::object& bars) {
    std::vector<BarSetup> out;
    for (const py::handle item : bars) {
        const auto t = item.cast<py::tuple>();
        if (t.size() != 5)
            throw std::invalid_argument("bars: expected (name, platform_ball, fixed_ball, offset, range or None)");
        BarSetup b;
        b.name = t[0].cast<std::string>();
        const auto p = t[1].cast<VectorXd>(), f = t[2].cast<VectorXd>();
        if (p.size() != 3 || f.size() != 3)
            throw std::invalid_argument("bars: set-up '" + b.name + "': expected 3 coordinates per ball");
        b.platform_ball = p;
        b.fixed_ball = f;
        b.offset = t[3].cast<double>();
        if (!t[4].is_none()) {
            const auto r = t[4].cast<std::vector<double>>();
            if (r.size() != 2) throw std::invalid_argument("bars: set-up '" + b.name + "': range: expected 2 values");
            b.has_range = true;
            b.range_min = r[0], b.range_max = r[1];
        }
        out.push_back(std::move(b));
    }
    return out;
}

py::list bar_setups_py(const std::vector<BarSetup>& bars) {
    py::list out;
    for (const BarSetup& b : bars)
        out.append(py::make_tuple(b.name, VectorXd(b.platform_ball), VectorXd(b.fixed_ball), b.offset,
                                  b.has_range ? py::object(py::make_tuple(b.range_min, b.range_max))
                                              : py::object(py::none())));
    return out;
}

void bind_ballbar(py::module_& m) {
    using PyBallbarObjective = Pooled<BallbarObjective>;
    py::class_<PyBallbarObjective>(m, "BallbarObjective")
        .def(py::init([](const Geometry& g, const py::object& bars, const RowMatrixXd& q, const RowMatrixXd& legs,
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
             py::arg("tolerance") = 1e-10)
        .def_property_readonly("n_params", [](const PyBallbarObjective& o) { return o.obj_->n_params(); })
        .def_property_readonly("n_poses", [](const PyBallbarObjective& o) { return o.obj_->n_poses(); })
        .def("cost",
             [](const PyBallbarObjective& o, const VecRef& x) {
                 py::gil_scoped_release release;
                 return o.obj_->cost(x);
             },
             py::arg("x"))
        .def("residuals",
             [](const PyBallbarObjective& o, const VecRef& x) {
                 py::gil_scoped_release release;
                 return o.obj_->residuals(x);
             },
             py::arg("x"))
        .def("failures", [](const PyBallbarObjective& o, const VecRef& x) { return o.obj_->failures(x); },
             py::arg("x"), "Poses whose forward kinematics fails at x: [(index, message)].")
        .def("cost_batch", &PyBallbarObjective::cost_batch, py::arg("X"), py::arg("threads") = 0);
}

}  // namespace iwr::python
