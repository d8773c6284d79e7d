// Shared include for every binding file: pybind11 with its Eigen and STL casters.
#pragma once

#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include <unistd.h>

#include "iwr/ballbar.hpp"
#include "iwr/effects.hpp"
#include "iwr/model.hpp"
#include "iwr/parallel.hpp"
#include "iwr/tracker.hpp"

namespace py = pybind11;

namespace iwr::python {
// Row-major on purpose: NumPy's default layout, so C-contiguous float64 arrays pass without a copy.
using RowRef = Eigen::Ref<const RowMatrixXd>;
using VecRef = Eigen::Ref<const VectorXd>;

// An objective (Objective, TrackerObjective) with the persistent thread pool its population
// batches run on.
template <class T>
struct Pooled {
    explicit Pooled(std::shared_ptr<T> obj) : obj_(std::move(obj)) {}

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

    /// The residuals at x and their exact Jacobian, without the GIL.
    py::tuple jacobian(const VecRef& x) const {
        VectorXd r;
        RowMatrixXd j;
        {
            py::gil_scoped_release release;
            obj_->jacobian(x, &r, &j);
        }
        return py::make_tuple(r, j);
    }

    /// The costs of the rows of X (M, n_params), on `threads` threads without the GIL.
    VectorXd cost_batch(const RowRef& X, int threads) {
        if (X.cols() != obj_->n_params())
            throw std::invalid_argument("X: shape (" + std::to_string(X.rows()) + ", " +
                                        std::to_string(X.cols()) + "); expected (M, " +
                                        std::to_string(obj_->n_params()) + ")");
        require_finite(X.data(), X.size(), "X");
        VectorXd out(X.rows());
        std::mutex& mutex = mutex_here();  // with the GIL held: one caller at a time
        {
            py::gil_scoped_release release;
            std::lock_guard<std::mutex> lock(mutex);
            obj_->cost_batch(X.data(), X.rows(), out.data(), pool(threads));
        }
        return out;
    }

    /// The mutex of this process. After a fork() the child's copy of the parent's may be locked
    /// for good (a parent thread was inside cost_batch, and does not exist in the child): checked
    /// by the process id before it is taken, and the copy left (a few bytes) for a new one.
    std::mutex& mutex_here() {
        const long pid = static_cast<long>(::getpid());
        if (mutex_pid_ != pid) {
            (void)mutex_.release();
            mutex_ = std::make_unique<std::mutex>();
            mutex_pid_ = pid;
        }
        return *mutex_;
    }

    std::shared_ptr<T> obj_;
    std::unique_ptr<ThreadPool> pool_;
    // One batch at a time per pool: Python threads may share a Problem. Taken through mutex_here().
    std::unique_ptr<std::mutex> mutex_ = std::make_unique<std::mutex>();
    long mutex_pid_ = static_cast<long>(::getpid());
};

void bind_model(py::module_& m);
void bind_forward(py::module_& m);
void bind_de(py::module_& m);
void bind_bench(py::module_& m);
void bind_tracker(py::module_& m);
void bind_files(py::module_& m);
void bind_implicit_loop(py::module_& m);
void bind_effects(py::module_& m);
// The effects' tables from Python's [(name, Effect.to_dict()), ...] (None: none), and back
// (bind_effects.cpp).
std::vector<EffectTable> effect_tables(const py::object& effects);
py::list effect_tables_py(const std::vector<EffectTable>& tables);
void bind_ballbar(py::module_& m);
// The ballbar set-ups from a dict's bar_names, platform_balls, fixed_balls, offsets and ranges
// (NaN: none), and into one (bind_ballbar.cpp).
std::vector<BarSetup> bar_setups(const py::dict& d);
void bar_setups_py(py::dict& d, const std::vector<BarSetup>& bars);
// The nominal tracker setup of kind "points" or "probe" (bind_tracker.cpp).
TrackerSetup make_setup(const std::string& kind, const Vector6d& registration,
                        const RowMatrixXd& reflectors, const Vector6d& probe, double length);
}  // namespace iwr::python
