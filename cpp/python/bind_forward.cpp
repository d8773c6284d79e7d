#include <pybind11/gil_safe_call_once.h>

#include "common.hpp"
#include "iwr/forward.hpp"

namespace iwr::python {

void bind_forward(py::module_& m) {
    // iwr.ForwardKinematicsError (a RuntimeError) with the offending pose index in `.pose`.
    PYBIND11_CONSTINIT static py::gil_safe_call_once_and_store<py::object> error_type;
    error_type.call_once_and_store_result([&]() {
        return py::object(
            py::exception<ForwardKinematicsError>(m, "ForwardKinematicsError", PyExc_RuntimeError));
    });
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const ForwardKinematicsError& e) {
            const py::object& type = error_type.get_stored();
            py::object inst = type(e.what());
            inst.attr("pose") = e.pose() >= 0 ? py::object(py::int_(e.pose())) : py::none();
            PyErr_SetObject(type.ptr(), inst.ptr());
        }
    });

    m.def(
        "hexapod_leg_lengths",
        [](const LegMatrix& base, const LegMatrix& platform, const Vector6d& pose) {
            LegJacobian jac;
            const LegVector len = hexapod_leg_lengths(base, platform, pose, &jac);
            return py::make_tuple(len, jac);
        },
        py::arg("base"), py::arg("platform"), py::arg("pose"),
        "Whole leg lengths at a local pose of {5} in {4}, and their Jacobian (6, 6).");
    m.def(
        "forward_kinematics",
        [](const Geometry& g, const VecRef& x, const RowRef& q, const RowRef& legs,
           const RowRef& guess, const Vector6d& home, double tolerance, int max_iterations) {
            ForwardOptions opt;
            opt.tolerance = tolerance;
            opt.max_iterations = max_iterations;
            RowMatrixXd poses;
            Eigen::VectorXi iterations;
            {
                py::gil_scoped_release release;
                poses = forward_kinematics(g, x, q, legs, guess, home, opt, &iterations);
            }
            return py::make_tuple(poses, iterations);
        },
        py::arg("geometry"), py::arg("errors"), py::arg("q"), py::arg("legs"), py::arg("guess"),
        py::arg("home"), py::arg("tolerance") = ForwardOptions().tolerance,
        py::arg("max_iterations") = ForwardOptions().max_iterations,
        "World poses (N, 6) and Newton iterations (N,) from joint and leg readings.");
}

}  // namespace iwr::python
