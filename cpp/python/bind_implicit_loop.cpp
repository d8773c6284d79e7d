#include "common.hpp"
#include "iwr/implicit_loop.hpp"

namespace iwr::python {

namespace {

ImplicitLoopOptions loop_options(int max_iterations, double ftol, double xtol, double gtol) {
    if (max_iterations < 0) throw std::invalid_argument("max_iterations: must be >= 0");
    ImplicitLoopOptions opt;
    opt.max_iterations = max_iterations;
    opt.ftol = ftol;
    opt.xtol = xtol;
    opt.gtol = gtol;
    return opt;
}

LoopCallback loop_callback(const py::object& callback) {
    if (callback.is_none()) return LoopCallback();
    return [&callback](int it, const VectorXd& x, double cost) {
        py::gil_scoped_acquire acquire;
        return py::bool_(callback(it, x, cost)).cast<bool>();
    };
}

py::dict result_dict(const ImplicitLoopResult& r) {
    py::dict out;
    out["x"] = r.x;
    out["corrections"] = r.corrections;
    out["cost"] = r.cost;
    out["iterations"] = r.iterations;
    out["nfev"] = r.nfev;
    out["status"] = r.status;
    out["message"] = r.message;
    out["residuals"] = r.residuals;
    out["redundancy"] = r.redundancy;
    out["pose_statistic"] = r.pose_statistic;
    out["pose_dof"] = r.pose_dof;
    out["covariance"] = r.covariance;
    out["reciprocal_condition"] = r.reciprocal_condition;
    out["dof"] = r.dof;
    return out;
}

TrackerLoopData tracker_data(const std::string& kind, const Vector6d& registration,
                             const RowMatrixXd& reflectors, const Vector6d& probe, double length,
                             const RowRef& measured, const RowRef& whitening,
                             const RowRef& reference) {
    TrackerLoopData d;
    if (kind == "points") d.setup = TrackerSetup::points(registration, reflectors);
    else if (kind == "probe") d.setup = TrackerSetup::probe(registration, probe, length);
    else throw std::invalid_argument("kind: '" + kind + "'; expected 'points' or 'probe'");
    d.measured = measured;
    d.whitening = whitening;
    d.reference = reference;
    return d;
}

}  // namespace

void bind_implicit_loop(py::module_& m) {
    m.def(
        "loop_jacobians",
        [](const Geometry& g, const VecRef& x, const RowRef& q, const RowRef& poses,
           const RowRef& corrections) {
            LoopJacobians j = loop_jacobians(g, x, q, poses, corrections);
            return py::make_tuple(j.legs, j.jac_x, j.jac_y);
        },
        py::arg("geometry"), py::arg("x"), py::arg("q"), py::arg("poses"),
        py::arg("corrections"),
        "Predicted legs (N, 6) at corrected readings and their exact derivatives: (6 N, n_params) "
        "with respect to x and (6 N, n_joints + 6) with respect to the corrections (dq, dp, w).");
    m.def(
        "implicit_loop",
        [](const Geometry& g, const VecRef& x0, const std::vector<int>& active, const RowRef& q,
           const RowRef& poses, const RowRef& legs, const RowRef& sigma, const RowRef& corrections0,
           int max_iterations, double ftol, double xtol, double gtol, const py::object& callback) {
            const ImplicitLoopOptions opt = loop_options(max_iterations, ftol, xtol, gtol);
            const LoopCallback cb = loop_callback(callback);
            ImplicitLoopResult r;
            {
                py::gil_scoped_release release;
                r = implicit_loop(g, x0, active, q, poses, legs, sigma, corrections0, opt, cb);
            }
            return result_dict(r);
        },
        py::arg("geometry"), py::arg("x0"), py::arg("active"), py::arg("q"), py::arg("poses"),
        py::arg("legs"), py::arg("sigma"), py::arg("corrections0"),
        py::arg("max_iterations") = ImplicitLoopOptions().max_iterations,
        py::arg("ftol") = ImplicitLoopOptions().ftol, py::arg("xtol") = ImplicitLoopOptions().xtol,
        py::arg("gtol") = ImplicitLoopOptions().gtol, py::arg("callback") = py::none(),
        "The implicit loop (errors-in-variables) estimator; see cpp/include/iwr/implicit_loop.hpp.");
    m.def(
        "tracker_loop_jacobians",
        [](const Geometry& g, const std::string& kind, const Vector6d& registration,
           const RowMatrixXd& reflectors, const Vector6d& probe, double length,
           const RowRef& measured, const RowRef& whitening, const RowRef& reference,
           const VecRef& x, const RowRef& q, const RowRef& legs, const RowRef& sigma,
           const RowRef& corrections) {
            const TrackerLoopData d = tracker_data(kind, registration, reflectors, probe, length,
                                                   measured, whitening, reference);
            LoopJacobians j = tracker_loop_jacobians(g, d, x, q, legs, sigma, corrections);
            return py::make_tuple(j.legs, j.jac_x, j.jac_y);
        },
        py::arg("geometry"), py::arg("kind"), py::arg("registration"), py::arg("reflectors"),
        py::arg("probe"), py::arg("probe_length"), py::arg("measured"), py::arg("whitening"),
        py::arg("reference"), py::arg("x"), py::arg("q"), py::arg("legs"), py::arg("sigma"),
        py::arg("corrections"),
        "The tracker estimator's normalised residuals (N, nr) and their exact derivatives "
        "(N nr, n_params), (N nr, n_joints + 6); see implicit_loop.hpp.");
    m.def(
        "implicit_loop_tracker",
        [](const Geometry& g, const std::string& kind, const Vector6d& registration,
           const RowMatrixXd& reflectors, const Vector6d& probe, double length,
           const RowRef& measured, const RowRef& whitening, const RowRef& reference,
           const VecRef& x0, const std::vector<int>& active, const RowRef& q, const RowRef& legs,
           const RowRef& sigma, const RowRef& corrections0, int max_iterations, double ftol,
           double xtol, double gtol, const py::object& callback) {
            const TrackerLoopData d = tracker_data(kind, registration, reflectors, probe, length,
                                                   measured, whitening, reference);
            const ImplicitLoopOptions opt = loop_options(max_iterations, ftol, xtol, gtol);
            const LoopCallback cb = loop_callback(callback);
            ImplicitLoopResult r;
            {
                py::gil_scoped_release release;
                r = implicit_loop_tracker(g, d, x0, active, q, legs, sigma, corrections0, opt, cb);
            }
            return result_dict(r);
        },
        py::arg("geometry"), py::arg("kind"), py::arg("registration"), py::arg("reflectors"),
        py::arg("probe"), py::arg("probe_length"), py::arg("measured"), py::arg("whitening"),
        py::arg("reference"), py::arg("x0"), py::arg("active"), py::arg("q"), py::arg("legs"),
        py::arg("sigma"), py::arg("corrections0"),
        py::arg("max_iterations") = ImplicitLoopOptions().max_iterations,
        py::arg("ftol") = ImplicitLoopOptions().ftol, py::arg("xtol") = ImplicitLoopOptions().xtol,
        py::arg("gtol") = ImplicitLoopOptions().gtol, py::arg("callback") = py::none(),
        "The efficient estimator on laser-tracker data; see cpp/include/iwr/implicit_loop.hpp.");
}

}  // namespace iwr::python
