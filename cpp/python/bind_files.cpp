// The problem file for Python: iwr.Problem.save encodes through encode_problem (whose checks are
// the reader's), iwr.Problem.load reads through read_problem. One writer and one reader, in C++,
// for both languages; the bytes are written by Python's atomic writer.
#include "common.hpp"
#include "iwr/binary_io.hpp"
#include "iwr/measurement_kind.hpp"
#include "iwr/problem_file.hpp"

#include <tuple>
#include <variant>

namespace iwr::python {

py::dict problem_dict(const ProblemData& p);

void bind_files(py::module_& m) {
    // A malformed file: a ValueError (bad input), and a RuntimeError as before for the DE state.
    static py::object format_error = py::reinterpret_steal<py::object>(PyErr_NewExceptionWithDoc(
        "iwr._core.FormatError", "A malformed, truncated or foreign binary file (problem, checkpoint, DE state).",
        py::make_tuple(py::handle(PyExc_ValueError), py::handle(PyExc_RuntimeError)).ptr(), nullptr));
    m.attr("FormatError") = format_error;
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const io::FormatError& e) {
            PyErr_SetString(format_error.ptr(), e.what());
        }
    });

    // Every field by name (problem_dict's keys): iwr/problem_file.py builds the dict for both
    // kinds of problem, and a field missing or of the wrong type is a KeyError/TypeError there.
    m.def(
        "_encode_problem",
        [](const py::dict& d) {
            auto get = [&](const char* key) -> py::object {
                if (!d.contains(key)) throw std::invalid_argument(std::string(key) + ": missing");
                return d[key];
            };
            ProblemData p;
            p.robot_name = get("robot_name").cast<std::string>();
            p.joint_types = get("joint_types").cast<std::string>();
            const auto dh = get("dh").cast<RowMatrixXd>();
            const auto joint_limits = get("joint_limits").cast<RowMatrixXd>();
            p.dh = dh.rows() ? dh : RowMatrixXd(0, 4);
            p.joint_limits = joint_limits.rows() ? joint_limits : RowMatrixXd(0, 2);
            p.base = get("base_joints").cast<LegMatrix>();
            p.platform = get("platform_joints").cast<LegMatrix>();
            p.leg_offsets = get("leg_offsets").cast<LegVector>();
            const auto leg_stroke = get("leg_stroke").cast<RowMatrixXd>();
            const auto home_pose = get("home_pose").cast<VectorXd>();
            const auto workspace = get("workspace").cast<VectorXd>();
            if (leg_stroke.rows() != 6 || leg_stroke.cols() != 2)
                throw std::invalid_argument("leg_stroke: expected 6 x 2");
            if (home_pose.size() != 6 || workspace.size() != 6)
                throw std::invalid_argument("home_pose, workspace: expected 6 values each");
            p.leg_stroke = leg_stroke;
            p.home_pose = home_pose;
            p.workspace = workspace;
            const py::object mjt = get("measurement_joint_types");
            p.has_measurement_joint_types = !mjt.is_none();
            if (p.has_measurement_joint_types) p.measurement_joint_types = mjt.cast<std::string>();
            const auto kind = get("kind").cast<std::string>();
            if (kind == "pose") p.kind = MeasurementKind::Pose;
            else if (kind == "points") p.kind = MeasurementKind::Points;
            else if (kind == "probe") p.kind = MeasurementKind::Probe;
            else if (kind == "ballbar") p.kind = MeasurementKind::Ballbar;
            else throw std::invalid_argument("kind: '" + kind + "'; expected pose, points, probe or ballbar");
            p.legs = get("legs").cast<RowMatrixXd>();
            const auto q = get("q").cast<RowMatrixXd>();
            p.q = q.cols() == static_cast<Eigen::Index>(p.joint_types.size()) ? q : RowMatrixXd(p.legs.rows(), 0);
            if (p.ballbar()) {  // the set-ups, each pose's set-up and the bar's readings
                p.bars = bar_setups(d);
                p.bar = get("bar").cast<std::vector<int>>();
                p.distance = get("distance").cast<VectorXd>();
                p.reference = get("reference").cast<VectorXd>();
            } else if (!p.tracker()) {
                p.poses = get("poses").cast<RowMatrixXd>();
                const py::object weights = get("weights");
                if (!weights.is_none()) p.weights = weights.cast<RowMatrixXd>();
            } else {
                const auto reg = get("registration").cast<VectorXd>();
                if (reg.size() != 6) throw std::invalid_argument("registration: expected 6 values");
                p.registration = reg;
                if (p.kind == MeasurementKind::Points) {
                    p.reflectors = get("reflectors").cast<RowMatrixXd>();
                    p.reflector_names = get("reflector_names").cast<std::vector<std::string>>();
                } else {
                    const auto probe = get("probe").cast<VectorXd>();
                    if (probe.size() != 6) throw std::invalid_argument("probe: expected 6 values");
                    p.probe = probe;
                    p.probe_length = get("probe_length").cast<double>();
                    p.probe_poses = get("probe_poses").cast<RowMatrixXd>();
                }
                p.points = get("points").cast<RowMatrixXd>();
                p.reference = get("reference").cast<VectorXd>();
            }
            // The noise weighting: None (unweighted), or (what it was made from, (N, m^2) whitening).
            const py::object weighting = get("weighting");
            if (!weighting.is_none()) {
                const auto pair = weighting.cast<std::tuple<std::string, RowMatrixXd>>();
                p.weighting = std::get<0>(pair);
                p.whitening = std::get<1>(pair);
                if (p.whitening.size() == 0)
                    throw std::invalid_argument("whitening: empty; give None for an unweighted problem");
                const Eigen::Index m = p.residuals_per_pose();
                if (p.whitening.rows() != p.legs.rows() || p.whitening.cols() != m * m)
                    throw std::invalid_argument("whitening: shape (" + std::to_string(p.whitening.rows()) + ", " +
                                                std::to_string(p.whitening.cols()) + "); expected (" +
                                                std::to_string(p.legs.rows()) + ", " + std::to_string(m * m) + ")");
            }
            // The effects (issue 23): [(name, table)], and the loads and temperatures they read.
            if (d.contains("effects")) {
                p.effects = effect_tables(d["effects"]);
                const py::object payload = get("payload"), temperatures = get("temperatures");
                if (!payload.is_none()) p.payload = payload.cast<RowMatrixXd>();
                if (!temperatures.is_none()) p.temperatures = temperatures.cast<RowMatrixXd>();
                // Tracker data with effects: gravity in {T} (the tracker setup's).
                if (p.tracker() && !p.effects.empty()) {
                    const auto gravity = get("tracker_gravity").cast<VectorXd>();
                    if (gravity.size() != 3) throw std::invalid_argument("tracker_gravity: expected 3 values");
                    p.tracker_gravity = gravity;
                }
            }
            p.lower = get("lower").cast<std::vector<double>>();
            p.upper = get("upper").cast<std::vector<double>>();
            p.bounds_kind = get("bounds_kind").cast<std::string>();
            p.x0 = get("x0").cast<std::vector<double>>();
            p.active = get("active").cast<std::vector<bool>>();
            p.parameter_names = get("parameter_names").cast<std::vector<std::string>>();
            for (const auto& s : get("sources").cast<std::vector<std::tuple<std::string, std::string, std::string>>>())
                p.sources.push_back({std::get<0>(s), std::get<1>(s), std::get<2>(s)});
            return py::bytes(encode_problem(p));
        },
        py::arg("fields"));

    // The fingerprint of a data set alone, as the problem file records it (ProblemData's
    // data_fingerprint): what `iwr report` checks a DATA file against, for every kind, without
    // building the problem (no forward kinematics, no registration guess).
    m.def(
        "_data_fingerprint",
        [](const std::string& kind, const std::string& joint_types, const py::object& measurement_joint_types,
           const RowMatrixXd& q, const RowMatrixXd& legs, const RowMatrixXd& poses, const py::object& weights,
           const RowMatrixXd& probe_poses, const RowMatrixXd& points, const RowMatrixXd& payload,
           const RowMatrixXd& temperatures, const std::vector<std::string>& bar_names, const std::vector<int>& bar,
           const VectorXd& distance) {
            ProblemData p;
            if (kind == "pose") p.kind = MeasurementKind::Pose;
            else if (kind == "points") p.kind = MeasurementKind::Points;
            else if (kind == "probe") p.kind = MeasurementKind::Probe;
            else if (kind == "ballbar") p.kind = MeasurementKind::Ballbar;
            else throw std::invalid_argument("kind: '" + kind + "'; expected pose, points, probe or ballbar");
            p.joint_types = joint_types;
            p.has_measurement_joint_types = !measurement_joint_types.is_none();
            if (p.has_measurement_joint_types) p.measurement_joint_types = measurement_joint_types.cast<std::string>();
            p.legs = legs;
            // As _encode_problem stores it: no joint columns when the robot has no joints.
            p.q = q.cols() == static_cast<Eigen::Index>(joint_types.size()) ? q : RowMatrixXd(legs.rows(), 0);
            if (p.ballbar()) {  // as decode_problem leaves them; the set-ups by name only
                p.poses.resize(0, 6);
                for (const std::string& name : bar_names) {
                    BarSetup b;
                    b.name = name;
                    p.bars.push_back(std::move(b));
                }
                p.bar = bar;
                p.distance = distance;
                for (int s : bar)
                    if (s < 0 || s >= static_cast<int>(bar_names.size()))
                        throw std::invalid_argument("bar: set-up index " + std::to_string(s) + " out of range");
            } else if (!p.tracker()) {
                p.poses = poses;
                if (!weights.is_none()) p.weights = weights.cast<RowMatrixXd>();
            } else {
                p.poses.resize(0, 6);  // as decode_problem leaves them for tracker data
                if (p.kind == MeasurementKind::Probe) p.probe_poses = probe_poses;
                p.points = points;
            }
            p.payload = payload;  // the loads and temperatures, of every kind (issue 23)
            p.temperatures = temperatures;
            return io::hex64(p.data_fingerprint());
        },
        py::arg("kind"), py::arg("joint_types"), py::arg("measurement_joint_types"), py::arg("q"),
        py::arg("legs"), py::arg("poses"), py::arg("weights"), py::arg("probe_poses"), py::arg("points"),
        py::arg("payload") = RowMatrixXd(), py::arg("temperatures") = RowMatrixXd(),
        py::arg("bar_names") = std::vector<std::string>(), py::arg("bar") = std::vector<int>(),
        py::arg("distance") = VectorXd());
    m.def(
        "_read_problem",
        [](const std::string& path) {
            ProblemData p;
            {
                py::gil_scoped_release release;
                p = read_problem(path);
            }
            return problem_dict(p);
        },
        py::arg("path"));
    m.def(
        "_decode_problem",
        [](const py::bytes& data, const std::string& context) {
            return problem_dict(decode_problem(std::string(data), context));
        },
        py::arg("data"), py::arg("context"));
    // The costs of the rows of X (M, n_params) on the objective iwr-engine builds from a problem
    // file (make_objective): how the tests check the engine against iwr.Problem.
    m.def(
        "_engine_costs",
        [](const std::string& path, const RowMatrixXd& X) {
            const ProblemData p = read_problem(path);
            if (X.cols() != p.n_params())
                throw std::invalid_argument("X: " + std::to_string(X.cols()) + " columns; expected " +
                                            std::to_string(p.n_params()));
            const AnyObjective objective = make_objective(p);
            VectorXd out(X.rows());
            std::visit(
                [&](const auto& obj) {
                    for (Eigen::Index i = 0; i < X.rows(); ++i) out(i) = obj.cost(VectorXd(X.row(i).transpose()));
                },
                objective);
            return out;
        },
        py::arg("path"), py::arg("X"));
}

py::dict problem_dict(const ProblemData& p) {
    py::dict d;
    d["robot_name"] = p.robot_name;
    d["joint_types"] = p.joint_types;
    d["dh"] = p.dh;
    d["joint_limits"] = p.joint_limits;
    d["base_joints"] = RowMatrixXd(p.base);
    d["platform_joints"] = RowMatrixXd(p.platform);
    d["leg_offsets"] = VectorXd(p.leg_offsets);
    d["leg_stroke"] = RowMatrixXd(p.leg_stroke);
    d["home_pose"] = VectorXd(p.home_pose);
    d["workspace"] = VectorXd(p.workspace);
    d["measurement_joint_types"] =
        p.has_measurement_joint_types ? py::cast(p.measurement_joint_types) : py::none();
    d["kind"] = p.kind == MeasurementKind::Points    ? "points"
                : p.kind == MeasurementKind::Probe   ? "probe"
                : p.kind == MeasurementKind::Ballbar ? "ballbar"
                                                     : "pose";
    d["q"] = p.q;
    d["legs"] = p.legs;
    if (p.ballbar()) {
        bar_setups_py(d, p.bars);
        d["bar"] = p.bar;
        d["distance"] = p.distance;
        d["reference"] = p.reference;
    } else if (!p.tracker()) {
        d["poses"] = p.poses;
        d["weights"] = p.weights.size() ? py::cast(p.weights) : py::none();
    } else {
        d["registration"] = VectorXd(p.registration);
        if (p.kind == MeasurementKind::Points) {
            d["reflectors"] = p.reflectors;
            d["reflector_names"] = p.reflector_names;
        } else {
            d["probe"] = VectorXd(p.probe);
            d["probe_length"] = p.probe_length;
            d["probe_poses"] = p.probe_poses;
        }
        d["points"] = p.points;
        d["reference"] = p.reference;
    }
    d["version"] = p.version;
    d["weighting"] = p.weighted() ? py::object(py::make_tuple(p.weighting, p.whitening)) : py::object(py::none());
    d["effects"] = effect_tables_py(p.effects);
    d["payload"] = p.payload.size() ? py::cast(p.payload) : py::none();
    d["temperatures"] = p.temperatures.size() ? py::cast(p.temperatures) : py::none();
    d["tracker_gravity"] = p.tracker() && !p.effects.empty() ? py::cast(VectorXd(p.tracker_gravity)) : py::none();
    d["lower"] = p.lower;
    d["upper"] = p.upper;
    d["bounds_kind"] = p.bounds_kind;
    d["x0"] = p.x0;
    d["active"] = p.active;
    d["parameter_names"] = p.parameter_names;
    py::list sources;
    for (const auto& s : p.sources) sources.append(py::make_tuple(s.role, s.path, s.sha256));
    d["sources"] = sources;
    d["robot_fingerprint"] = io::hex64(p.robot_fingerprint());
    d["data_fingerprint"] = io::hex64(p.data_fingerprint());
    return d;
}

}  // namespace iwr::python
