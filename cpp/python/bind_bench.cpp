// iwr._core._bench: benchmark-only helpers (private; used by benchmarks/, not by iwr): the
// straightforward Eigen baseline of the cost, and probes of the machine's clock and peak.
//
// They live in the extension, rather than in a separate benchmark executable, so that the
// benchmark compares the kernel and the baseline in one process, on the same data, with one timing
// harness, and the wheel needs no second binary; the cost is a few kilobytes of code.
#include "../bench/baseline.hpp"
#include "../bench/machine.hpp"
#include "common.hpp"

namespace iwr::python {

void bind_bench(py::module_& m) {
    py::module_ b = m.def_submodule("_bench", "Benchmark-only helpers (private).");
    py::class_<bench::EigenBaseline>(b, "EigenBaseline")
        .def(py::init<Geometry, const RowMatrixXd&, const RowMatrixXd&, const RowMatrixXd&,
                      const RowMatrixXd&>(),
             py::arg("geometry"), py::arg("q"), py::arg("poses"), py::arg("legs"),
             py::arg("weights") = RowMatrixXd())
        .def(
            "cost_batch",
            [](const bench::EigenBaseline& e, const RowRef& X) {
                VectorXd out(X.rows());
                py::gil_scoped_release release;
                for (Eigen::Index i = 0; i < X.rows(); ++i) out(i) = e.cost(X.row(i).data());
                return out;
            },
            py::arg("X"), "Costs of the rows of X, one after the other on the calling thread.");
    // The probes run without the GIL (pybind11's call guard releases it around the call).
    using NoGil = py::call_guard<py::gil_scoped_release>;
    b.def("measure_clock_ghz", &bench::measure_clock_ghz, py::arg("seconds") = 0.2, NoGil());
    b.def("measure_peak_gflops", &bench::measure_peak_gflops, py::arg("isa"), py::arg("fma") = false,
          py::arg("seconds") = 0.2, NoGil());
    b.def("measure_core_round_trip_ns", &bench::measure_core_round_trip_ns, py::arg("seconds") = 0.05,
          NoGil());
}

}  // namespace iwr::python
