// Bindings of the laser-tracker objective (iwr/tracker.hpp). Private: iwr.tracker is the public API.
#include <memory>
#include <mutex>

#include "common.hpp"
#include "iwr/tracker.hpp"

namespace iwr::python {

namespace {

using PyTrackerObjective = Pooled<TrackerObjective>;

}  // namespace

TrackerSetup make_setup(const std::string& kind, const Vector6d& registration,
                        const RowMatrixXd& reflectors, const Vector6d& probe, double length) {
    if (kind == "points") return TrackerSetup::points(registration, reflectors);
    if (kind == "probe") return TrackerSetup::probe(registration, probe, length);
    throw std::invalid_argument("kind: '" + kind + "'; expected 'points' or 'probe'");
}

void bind_tracker(py::module_& m) {
    m.def("rotvec_matrix", &rotvec_matrix, py::arg("w"));
    m.def("so3_left_jacobian", &so3_left_jacobian, py::arg("w"));
    py::class_<PyTrackerObjective>(m, "TrackerObjective")
        .def(py::init([](const Geometry& g, const std::string& kind, const Vector6d& registration,
                         const RowMatrixXd& reflectors, const Vector6d& probe, double probe_length,
                         const RowMatrixXd& q, const RowMatrixXd& legs, const RowMatrixXd& points,
                         const VectorXd& reference, const Vector6d& home, double tolerance) {
                 TrackerSetup s = make_setup(kind, registration, reflectors, probe, probe_length);
                 std::shared_ptr<TrackerObjective> obj;
                 {
                     py::gil_scoped_release release;
                     obj = std::make_shared<TrackerObjective>(g, s, q, legs, points, reference,
                                                              home, tolerance);
                 }
                 return std::make_unique<PyTrackerObjective>(std::move(obj));
             }),
             py::arg("geometry"), py::arg("kind"), py::arg("registration"), py::arg("reflectors"),
             py::arg("probe"), py::arg("probe_length"), py::arg("q"), py::arg("legs"),
             py::arg("points"), py::arg("reference"), py::arg("home"),
             py::arg("tolerance") = 1e-10)
        .def_property_readonly("n_params",
                               [](const PyTrackerObjective& o) { return o.obj_->n_params(); })
        .def_property_readonly("n_poses", [](const PyTrackerObjective& o) { return o.obj_->n_poses(); })
        .def_property_readonly("n_points",
                               [](const PyTrackerObjective& o) { return o.obj_->n_points(); })
        .def_property_readonly("n_residuals",
                               [](const PyTrackerObjective& o) { return o.obj_->n_residuals(); })
        .def_property_readonly("n_seen", [](const PyTrackerObjective& o) { return o.obj_->n_seen(); })
        .def("cost",
             [](const PyTrackerObjective& o, const VecRef& x) {
                 py::gil_scoped_release release;
                 return o.obj_->cost(x);
             },
             py::arg("x"))
        .def("residuals",
             [](const PyTrackerObjective& o, const VecRef& x) {
                 py::gil_scoped_release release;
                 return o.obj_->residuals(x);
             },
             py::arg("x"))
        .def("jacobian", &PyTrackerObjective::jacobian, py::arg("x"),
             "Residuals and their exact Jacobian at x.")
        .def("failures", [](const PyTrackerObjective& o, const VecRef& x) { return o.obj_->failures(x); },
             py::arg("x"), "Poses whose forward kinematics fails at x: [(index, message)].")
        .def("platform_poses",
             [](const PyTrackerObjective& o, const VecRef& x) { return o.obj_->platform_poses(x); },
             py::arg("x"))
        .def("chord_status",
             [](const PyTrackerObjective& o, const VecRef& x) { return o.obj_->chord_status(x); },
             py::arg("x"),
             "Per pose, how the kernel's iterations ended at x: 0 solved, 1 finished by the\n"
             "damped Newton solver, 2 a leg length <= 0.")
        .def("predicted_points",
             [](const PyTrackerObjective& o, const VecRef& x) { return o.obj_->predicted_points(x); },
             py::arg("x"))
        .def("cost_batch", &PyTrackerObjective::cost_batch,
            py::arg("X"), py::arg("threads") = 0)
        .def("set_whitening",
             [](PyTrackerObjective& o, const RowMatrixXd& whitening) {
                 // Copy on write: a DE run (iwr._core.de_kernel, the GIL released) may be reading
                 // the current object through its own shared_ptr; it keeps that one.
                 auto next = std::make_shared<TrackerObjective>(*o.obj_);
                 next->set_whitening(whitening);
                 o.obj_ = std::move(next);
             },
             py::arg("whitening"),
             "Whiten the residuals (and the cost, the Jacobian) per pose: (N, m^2), each row a\n"
             "row-major lower-triangular m x m matrix, m = 3 n_points; an empty array: unweighted.");
}

}  // namespace iwr::python
