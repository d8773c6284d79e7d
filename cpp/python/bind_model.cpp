#include <memory>
#include <mutex>

#include "common.hpp"
#include "iwr/objective.hpp"

namespace iwr::python {

namespace {

using PyObjective = Pooled<Objective>;

}  // namespace

void bind_model(py::module_& m) {
    py::class_<Geometry>(m, "Geometry")
        .def(py::init<std::string, RowMatrixXd, LegMatrix, LegMatrix, LegVector>(),
             py::arg("joint_types"), py::arg("dh"), py::arg("base"), py::arg("platform"),
             py::arg("leg_offsets"))
        .def_property_readonly("n_joints", &Geometry::n_joints)
        .def_property_readonly("n_params", &Geometry::n_params)
        .def_property_readonly("joint_types", &Geometry::joint_types);

    // Private: SIMD variant of the cost kernel (tests check that all variants agree bit for bit);
    // IWR_KERNEL applied by iwr's import (iwr/__init__.py) and checked by the commands
    // (iwr._startup.command_kernel).
    m.def("_supported_kernels", &supported_kernels);
    m.def("_active_kernel", &active_kernel);
    m.def("_select_kernel", &select_kernel, py::arg("name"));
    m.def("_select_kernel_from_environment", &select_kernel_from_environment);
    m.def("_kernel_summary", &kernel_summary);
    m.def("_kernel_environment_prefix", &kernel_environment_prefix);

    m.def("euler_zyx", &euler_zyx, py::arg("alpha"), py::arg("beta"), py::arg("gamma"));
    m.def("dh_transform", &dh_transform, py::arg("alpha"), py::arg("a"), py::arg("d"),
          py::arg("theta"));
    m.def(
        "carriage_transform",
        [](const Geometry& g, const VecRef& x, const VecRef& q) {
            g.check_errors(x.data(), x.size(), "errors");
            if (q.size() != g.n_joints())
                throw std::invalid_argument("q: " + std::to_string(q.size()) +
                                            " joint readings given; the carriage has " +
                                            std::to_string(g.n_joints()) + " joints");
            require_finite(q.data(), q.size(), "q");
            return carriage_transform(g, x.data(), q.data());
        },
        py::arg("geometry"), py::arg("errors"), py::arg("q"));
    m.def(
        "predict_legs",
        [](const Geometry& g, const VecRef& x, const RowRef& q, const RowRef& poses) {
            py::gil_scoped_release release;
            return predict_legs(g, x, q, poses);
        },
        py::arg("geometry"), py::arg("errors"), py::arg("q"), py::arg("poses"));

    py::class_<PyObjective>(m, "Objective")
        .def(py::init([](const Geometry& g, const RowMatrixXd& q, const RowMatrixXd& poses,
                         const RowMatrixXd& legs, const RowMatrixXd& weights,
                         const RowMatrixXd& whitening) {
                 return std::make_unique<PyObjective>(
                     std::make_shared<Objective>(g, q, poses, legs, weights, whitening));
             }),
             py::arg("geometry"), py::arg("q"), py::arg("poses"), py::arg("legs"),
             py::arg("weights") = RowMatrixXd(), py::arg("whitening") = RowMatrixXd())
        .def_property_readonly("whitened", [](const PyObjective& o) { return o.obj_->whitened(); })
        .def_property_readonly("n_params", [](const PyObjective& o) { return o.obj_->n_params(); })
        .def_property_readonly("n_poses", [](const PyObjective& o) { return o.obj_->n_poses(); })
        .def("cost", [](const PyObjective& o, const VecRef& x) { return o.obj_->cost(x); },
             py::arg("x"))
        .def("residuals",
             [](const PyObjective& o, const VecRef& x) { return o.obj_->residuals(x); }, py::arg("x"))
        .def("jacobian", &PyObjective::jacobian, py::arg("x"),
             "Residuals and their exact Jacobian at x.")
        .def("cost_batch", &PyObjective::cost_batch,
            py::arg("X"), py::arg("threads") = 0);
}

}  // namespace iwr::python
