// The leg objective with the non-geometric effects (iwr/effects.hpp) for iwr.Problem, and the
// effects' tables between Python (a list of (name, table): Effect.to_dict()) and C++.
#include "common.hpp"
#include "iwr/effects.hpp"
#include "iwr/effects_tracker.hpp"
#include "iwr/tracker.hpp"

namespace iwr::python {

namespace {
using PyEffectObjective = Pooled<EffectObjective>;
using PyTrackerEffectObjective = Pooled<TrackerEffectObjective>;
}  // namespace

std::vector<EffectTable> effect_tables(const py::object& effects) {
    std::vector<EffectTable> out;
    if (effects.is_none()) return out;
    for (const py::handle item : effects) {
        const auto pair = item.cast<py::tuple>();
        if (pair.size() != 2) throw std::invalid_argument("effects: expected (name, table) pairs");
        EffectTable t;
        t.name = pair[0].cast<std::string>();
        for (const auto& [k, v] : pair[1].cast<py::dict>()) {
            const std::string key = k.cast<std::string>();
            EffectValue value;
            if (py::isinstance<py::bool_>(v)) {
                value.type = EffectValue::Type::Bool;
                value.numbers = {v.cast<bool>() ? 1.0 : 0.0};
            } else if (py::isinstance<py::int_>(v) || py::isinstance<py::float_>(v)) {
                value.type = EffectValue::Type::Number;
                value.numbers = {v.cast<double>()};
            } else if (py::isinstance<py::list>(v) || py::isinstance<py::tuple>(v)) {
                value.type = EffectValue::Type::Numbers;
                for (const py::handle e : v) {
                    if (py::isinstance<py::bool_>(e) ||
                        !(py::isinstance<py::int_>(e) || py::isinstance<py::float_>(e)))
                        throw std::invalid_argument("effects." + t.name + "." + key +
                                                    ": expected an array of numbers");
                    value.numbers.push_back(e.cast<double>());
                }
            } else {
                throw std::invalid_argument("effects." + t.name + "." + key +
                                            ": expected true/false, a number or an array of numbers, got " +
                                            std::string(py::str(py::type::of(v).attr("__name__"))));
            }
            t.entries.emplace_back(key, std::move(value));
        }
        out.push_back(std::move(t));
    }
    return out;
}

py::list effect_tables_py(const std::vector<EffectTable>& tables) {
    py::list out;
    for (const EffectTable& t : tables) {
        py::dict d;
        for (const auto& [key, value] : t.entries) {
            if (value.type == EffectValue::Type::Bool) {
                d[py::str(key)] = py::bool_(value.numbers.at(0) != 0);
            } else if (value.type == EffectValue::Type::Number) {
                d[py::str(key)] = py::float_(value.numbers.at(0));
            } else {
                py::list l;
                for (double v : value.numbers) l.append(py::float_(v));
                d[py::str(key)] = l;
            }
        }
        out.append(py::make_tuple(t.name, d));
    }
    return out;
}

void bind_effects(py::module_& m) {
    py::class_<PyEffectObjective>(m, "EffectObjective")
        .def(py::init([](const Geometry& g, const py::object& effects, const RowMatrixXd& q,
                         const RowMatrixXd& poses, const RowMatrixXd& legs, const RowMatrixXd& payload,
                         const RowMatrixXd& temperatures, const RowMatrixXd& weights,
                         const RowMatrixXd& whitening) {
                 EffectModel model = EffectModel::parse(effect_tables(effects), g.n_params());
                 return std::make_unique<PyEffectObjective>(std::make_shared<EffectObjective>(
                     g, model, q, poses, legs, payload, temperatures, weights, whitening));
             }),
             py::arg("geometry"), py::arg("effects"), py::arg("q"), py::arg("poses"), py::arg("legs"),
             py::arg("payload") = RowMatrixXd(), py::arg("temperatures") = RowMatrixXd(),
             py::arg("weights") = RowMatrixXd(), py::arg("whitening") = RowMatrixXd())
        .def_property_readonly("whitened", [](const PyEffectObjective& o) { return o.obj_->whitened(); })
        .def_property_readonly("n_params", [](const PyEffectObjective& o) { return o.obj_->n_params(); })
        .def_property_readonly("n_poses", [](const PyEffectObjective& o) { return o.obj_->n_poses(); })
        .def("cost", [](const PyEffectObjective& o, const VecRef& x) { return o.obj_->cost(x); }, py::arg("x"))
        .def("residuals", [](const PyEffectObjective& o, const VecRef& x) { return o.obj_->residuals(x); },
             py::arg("x"))
        .def("forces", [](const PyEffectObjective& o, const VecRef& x) { return o.obj_->forces(x); },
             py::arg("x"), "The leg forces (N, 6), N, tension positive.")
        .def("failures", [](const PyEffectObjective& o, const VecRef& x) { return o.obj_->failures(x); },
             py::arg("x"))
        .def("cost_batch", &PyEffectObjective::cost_batch, py::arg("X"), py::arg("threads") = 0);

    // Tracker data with the effects (iwr/effects_tracker.hpp), for iwr.effects.tracker's problem.
    using T = PyTrackerEffectObjective;
    py::class_<T>(m, "TrackerEffectObjective")
        .def(py::init([](const Geometry& g, const py::object& effects, const std::string& kind,
                         const Vector6d& registration, const RowMatrixXd& reflectors, const Vector6d& probe,
                         double probe_length, const Vec3& gravity, const RowMatrixXd& q, const RowMatrixXd& legs,
                         const RowMatrixXd& points, const RowMatrixXd& payload, const RowMatrixXd& temperatures,
                         const VectorXd& reference, const Vector6d& home, const RowMatrixXd& whitening,
                         double tolerance) {
                 EffectModel model = EffectModel::parse(effect_tables(effects), g.n_params());
                 TrackerSetup s = make_setup(kind, registration, reflectors, probe, probe_length);
                 std::shared_ptr<TrackerEffectObjective> obj;
                 {
                     py::gil_scoped_release release;
                     obj = std::make_shared<TrackerEffectObjective>(g, model, s, gravity, q, legs, points, payload,
                                                                    temperatures, reference, home, tolerance);
                     obj->set_whitening(whitening);
                 }
                 return std::make_unique<T>(std::move(obj));
             }),
             py::arg("geometry"), py::arg("effects"), py::arg("kind"), py::arg("registration"),
             py::arg("reflectors"), py::arg("probe"), py::arg("probe_length"), py::arg("gravity"), py::arg("q"),
             py::arg("legs"), py::arg("points"), py::arg("payload"), py::arg("temperatures"),
             py::arg("reference"), py::arg("home"), py::arg("whitening") = RowMatrixXd(),
             py::arg("tolerance") = 1e-11)
        .def_property_readonly("n_params", [](const T& o) { return o.obj_->n_params(); })
        .def_property_readonly("n_poses", [](const T& o) { return o.obj_->n_poses(); })
        .def_property_readonly("n_residuals", [](const T& o) { return o.obj_->n_residuals(); })
        .def_property_readonly("n_seen", [](const T& o) { return o.obj_->n_seen(); })
        .def_property_readonly("whitened", [](const T& o) { return o.obj_->whitened(); })
        .def("cost",
             [](const T& o, const VecRef& x) {
                 py::gil_scoped_release release;
                 return o.obj_->cost(x);
             },
             py::arg("x"))
        .def("residuals",
             [](const T& o, const VecRef& x) {
                 py::gil_scoped_release release;
                 return o.obj_->residuals(x);
             },
             py::arg("x"))
        .def("failures", [](const T& o, const VecRef& x) { return o.obj_->failures(x); }, py::arg("x"))
        .def("platform_poses", [](const T& o, const VecRef& x) { return o.obj_->platform_poses(x); },
             py::arg("x"))
        .def("predicted_points", [](const T& o, const VecRef& x) { return o.obj_->predicted_points(x); },
             py::arg("x"))
        .def("solve_paths", [](const T& o, const VecRef& x) { return o.obj_->solve_paths(x); },
             py::arg("x"),
             "Per pose how its forward kinematics with the effects was solved at x: 0 chord steps, 1 "
             "Newton from the reference, 2 Newton from the geometry's forward kinematics, 3 failed.")
        .def("cost_batch", &T::cost_batch, py::arg("X"), py::arg("threads") = 0);
}

}  // namespace iwr::python
