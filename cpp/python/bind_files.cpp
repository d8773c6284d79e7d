// The problem file for Python: iwr.Problem.save encodes through encode_problem (whose checks are
// the reader's), iwr.Problem.load reads through read_problem. One writer and one reader, in C++,
// for both languages; the bytes are written by Python's atomic writer.
#include "common.hpp"
#include "iwr/binary_io.hpp"
#include "iwr/problem_file.hpp"

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

    m.def(
        "_encode_problem",
        [](const std::string& robot_name, const std::string& joint_types, const RowMatrixXd& dh,
           const RowMatrixXd& joint_limits, const LegMatrix& base, const LegMatrix& platform,
           const LegVector& leg_offsets, const RowMatrixXd& leg_stroke, const VectorXd& home_pose,
           const VectorXd& workspace, const py::object& measurement_joint_types, const RowMatrixXd& q,
           const RowMatrixXd& poses, const RowMatrixXd& legs, const py::object& weights,
           const std::vector<double>& lower, const std::vector<double>& upper, const std::string& bounds_kind,
           const std::vector<std::string>& parameter_names,
           const std::vector<std::tuple<std::string, std::string, std::string>>& sources) {
            ProblemData p;
            p.robot_name = robot_name;
            p.joint_types = joint_types;
            p.dh = dh.rows() ? dh : RowMatrixXd(0, 4);
            p.joint_limits = joint_limits.rows() ? joint_limits : RowMatrixXd(0, 2);
            p.base = base;
            p.platform = platform;
            p.leg_offsets = leg_offsets;
            if (leg_stroke.rows() != 6 || leg_stroke.cols() != 2)
                throw std::invalid_argument("leg_stroke: expected 6 x 2");
            if (home_pose.size() != 6 || workspace.size() != 6)
                throw std::invalid_argument("home_pose, workspace: expected 6 values each");
            p.leg_stroke = leg_stroke;
            p.home_pose = home_pose;
            p.workspace = workspace;
            p.has_measurement_joint_types = !measurement_joint_types.is_none();
            if (p.has_measurement_joint_types) p.measurement_joint_types = measurement_joint_types.cast<std::string>();
            p.q = q.cols() == static_cast<Eigen::Index>(joint_types.size()) ? q : RowMatrixXd(poses.rows(), 0);
            p.poses = poses;
            p.legs = legs;
            if (!weights.is_none()) p.weights = weights.cast<RowMatrixXd>();
            p.lower = lower;
            p.upper = upper;
            p.bounds_kind = bounds_kind;
            p.parameter_names = parameter_names;
            for (const auto& s : sources) p.sources.push_back({std::get<0>(s), std::get<1>(s), std::get<2>(s)});
            return py::bytes(encode_problem(p));
        },
        py::arg("robot_name"), py::arg("joint_types"), py::arg("dh"), py::arg("joint_limits"), py::arg("base"),
        py::arg("platform"), py::arg("leg_offsets"), py::arg("leg_stroke"), py::arg("home_pose"),
        py::arg("workspace"), py::arg("measurement_joint_types"), py::arg("q"), py::arg("poses"), py::arg("legs"),
        py::arg("weights"), py::arg("lower"), py::arg("upper"), py::arg("bounds_kind"),
        py::arg("parameter_names"), py::arg("sources"));

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
    d["q"] = p.q;
    d["poses"] = p.poses;
    d["legs"] = p.legs;
    d["weights"] = p.weights.size() ? py::cast(p.weights) : py::none();
    d["lower"] = p.lower;
    d["upper"] = p.upper;
    d["bounds_kind"] = p.bounds_kind;
    d["parameter_names"] = p.parameter_names;
    py::list sources;
    for (const auto& s : p.sources) sources.append(py::make_tuple(s.role, s.path, s.sha256));
    d["sources"] = sources;
    d["robot_fingerprint"] = io::hex64(p.robot_fingerprint());
    d["data_fingerprint"] = io::hex64(p.data_fingerprint());
    return d;
}

}  // namespace iwr::python
