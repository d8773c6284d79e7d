// Shared include for every binding file: pybind11 with its Eigen and STL casters.
#pragma once

#include <pybind11/eigen.h>
#include <pybind11/functional.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "iwr/model.hpp"

namespace py = pybind11;

namespace iwr::python {
// Row-major on purpose: NumPy's default layout, so C-contiguous float64 arrays pass without a copy.
using RowRef = Eigen::Ref<const RowMatrixXd>;
using VecRef = Eigen::Ref<const VectorXd>;

void bind_model(py::module_& m);
void bind_forward(py::module_& m);
void bind_de(py::module_& m);
void bind_bench(py::module_& m);
void bind_tracker(py::module_& m);
void bind_files(py::module_& m);
void bind_implicit_loop(py::module_& m);
}  // namespace iwr::python
