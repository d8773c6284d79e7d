#include "common.hpp"
#include "iwr/implicit_loop.hpp"

namespace iwr::python {

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
            ImplicitLoopOptions opt;
            opt.max_iterations = max_iterations;
            opt.ftol = ftol;
            opt.xtol = xtol;
            opt.gtol = gtol;
            if (max_iterations < 0) throw std::invalid_argument("max_iterations: must be >= 0");
            LoopCallback cb;
            if (!callback.is_none()) {
                cb = [&callback](int it, const VectorXd& x, double cost) {
                    py::gil_scoped_acquire acquire;
                    return py::bool_(callback(it, x, cost)).cast<bool>();
                };
            }
            ImplicitLoopResult r;
            {
                py::gil_scoped_release release;
                r = implicit_loop(g, x0, active, q, poses, legs, sigma, corrections0, opt, cb);
            }
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
            return out;
        },
        py::arg("geometry"), py::arg("x0"), py::arg("active"), py::arg("q"), py::arg("poses"),
        py::arg("legs"), py::arg("sigma"), py::arg("corrections0"),
        py::arg("max_iterations") = ImplicitLoopOptions().max_iterations,
        py::arg("ftol") = ImplicitLoopOptions().ftol, py::arg("xtol") = ImplicitLoopOptions().xtol,
        py::arg("gtol") = ImplicitLoopOptions().gtol, py::arg("callback") = py::none(),
        "The implicit loop (errors-in-variables) estimator; see cpp/include/iwr/implicit_loop.hpp.");
}

}  // namespace iwr::python
