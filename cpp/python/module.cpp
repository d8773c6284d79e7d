#include "common.hpp"

PYBIND11_MODULE(_core, m) {
    m.doc() = "iwr's compiled core. Private: use the public API of the iwr package.";
    iwr::python::bind_files(m);
    iwr::python::bind_model(m);
    iwr::python::bind_forward(m);
    iwr::python::bind_de(m);
    iwr::python::bind_bench(m);
    iwr::python::bind_tracker(m);
    iwr::python::bind_implicit_loop(m);
    iwr::python::bind_effects(m);
    iwr::python::bind_ballbar(m);
}
