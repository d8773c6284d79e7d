#include <memory>
#include <mutex>

#include "common.hpp"
#include "iwr/objective.hpp"

namespace iwr::python {

namespace {

// The objective together with a persistent thread pool for population batches.
class PyObjective {
public:
    PyObjective(const Geometry& g, const RowMatrixXd& q, const RowMatrixXd& poses,
                const RowMatrixXd& legs, const RowMatrixXd& weights)
        : obj_(std::make_shared<Objective>(g, q, poses, legs, weights)) {}

    ThreadPool& pool(int threads) {
        const int n = ThreadPool::resolve(threads);
        if (pool_ && !pool_->usable_here()) {
            // Made before a fork(): its threads do not exist in this child, and destroying it could
            // wait on them; leave it (a few bytes) and make a new pool here.
            (void)pool_.release();
        }
        if (!pool_ || pool_->size() != n) {
            pool_.reset();
            pool_ = std::make_unique<ThreadPool>(n);
        }
        return *pool_;
    }
    std::shared_ptr<Objective> obj_;
    std::unique_ptr<ThreadPool> pool_;
    std::mutex mutex_;  // one batch at a time per pool: Python threads may share a Problem
};

}  // namespace

void bind_model(py::module_& m) {
    py::class_<Geometry>(m, "Geometry")
        .def(py::init<std::string, RowMatrixXd, LegMatrix, LegMatrix, LegVector>(),
             py::arg("joint_types"), py::arg("dh"), py::arg("base"), py::arg("platform"),
             py::arg("leg_offsets"))
        .def_property_readonly("n_joints", &Geometry::n_joints)
        .def_property_readonly("n_params", &Geometry::n_params)
        .def_property_readonly("joint_types", &Geometry::joint_types);

    // Private: SIMD variant of the cost kernel (tests check that all variants agree bit for bit).
    m.def("_supported_kernels", &supported_kernels);
    m.def("_active_kernel", &active_kernel);
    m.def("_select_kernel", &select_kernel, py::arg("name"));

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
        .def(py::init<const Geometry&, const RowMatrixXd&, const RowMatrixXd&, const RowMatrixXd&,
                      const RowMatrixXd&>(),
             py::arg("geometry"), py::arg("q"), py::arg("poses"), py::arg("legs"),
             py::arg("weights") = RowMatrixXd())
        .def_property_readonly("n_params", [](const PyObjective& o) { return o.obj_->n_params(); })
        .def_property_readonly("n_poses", [](const PyObjective& o) { return o.obj_->n_poses(); })
        .def("cost", [](const PyObjective& o, const VecRef& x) { return o.obj_->cost(x); },
             py::arg("x"))
        .def("residuals",
             [](const PyObjective& o, const VecRef& x) { return o.obj_->residuals(x); }, py::arg("x"))
        .def(
            "jacobian",
            [](const PyObjective& o, const VecRef& x) {
                VectorXd r;
                RowMatrixXd j;
                {
                    py::gil_scoped_release release;
                    o.obj_->jacobian(x, &r, &j);
                }
                return py::make_tuple(r, j);
            },
            py::arg("x"), "Residuals and their exact Jacobian at x.")
        .def(
            "cost_batch",
            [](PyObjective& o, const RowRef& X, int threads) {
                if (X.cols() != o.obj_->n_params())
                    throw std::invalid_argument(
                        "X: shape (" + std::to_string(X.rows()) + ", " + std::to_string(X.cols()) +
                        "); expected (M, " + std::to_string(o.obj_->n_params()) + ")");
                require_finite(X.data(), X.size(), "X");
                VectorXd out(X.rows());
                {
                    py::gil_scoped_release release;
                    std::lock_guard<std::mutex> lock(o.mutex_);
                    o.obj_->cost_batch(X.data(), X.rows(), out.data(), o.pool(threads));
                }
                return out;
            },
            py::arg("X"), py::arg("threads") = 0);
}

}  // namespace iwr::python
