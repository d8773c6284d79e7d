#include "inputs.hpp"

#include <cmath>
#include <cstdlib>
#include <set>
#include <sstream>

namespace iwr::app {

namespace {

std::string num_str(double v) {
    std::ostringstream s;
    s.precision(17);
    s << v;
    return s.str();
}

// --- robot TOML ------------------------------------------------------------------------------

class RobotReader {
public:
    explicit RobotReader(const std::string& file) : file_(file) {}

    [[noreturn]] void fail(const TomlValue& at, const std::string& what) const {
        if (at.line > 0) throw InputError(file_ + ": line " + std::to_string(at.line) + ": " + what);
        throw InputError(file_ + ": " + what);
    }

    const TomlValue& table(const TomlValue& v, const std::string& where) const {
        if (v.kind != TomlValue::Kind::Table)
            fail(v, (where.empty() ? "file" : where) + ": expected a table, got " +
                        TomlValue::kind_name(v.kind));
        return v;
    }

    void check_keys(const TomlValue& t, const std::set<std::string>& allowed,
                    const std::set<std::string>& required, const std::string& where) const {
        table(t, where);
        const std::string prefix = where.empty() ? "" : where + ".";
        for (const auto& e : t.entries) {
            if (!allowed.count(e.first)) {
                std::string list;
                for (const auto& a : allowed) list += (list.empty() ? "" : ", ") + a;
                fail(e.second, prefix + e.first + ": unknown key; allowed: " + list);
            }
        }
        for (const auto& r : required)
            if (!t.find(r)) fail(t, prefix + r + ": missing key");
    }

    double number(const TomlValue& v, const std::string& where) const {
        if (v.kind != TomlValue::Kind::Number)
            fail(v, where + ": expected a number, got " + TomlValue::kind_name(v.kind));
        if (!std::isfinite(v.number)) fail(v, where + ": " + num_str(v.number) + " is not finite");
        return v.number;
    }

    std::vector<double> numbers(const TomlValue& v, size_t n, const std::string& where) const {
        if (v.kind != TomlValue::Kind::Array || v.items.size() != n)
            fail(v, where + ": expected an array of " + std::to_string(n) + " numbers");
        std::vector<double> out;
        for (size_t i = 0; i < n; ++i)
            out.push_back(number(v.items[i], where + "[" + std::to_string(i) + "]"));
        return out;
    }

    std::vector<std::vector<double>> matrix(const TomlValue& v, size_t rows, size_t cols,
                                            const std::string& where) const {
        if (v.kind != TomlValue::Kind::Array || v.items.size() != rows)
            fail(v, where + ": expected " + std::to_string(rows) + " rows of " +
                        std::to_string(cols) + " numbers");
        std::vector<std::vector<double>> out;
        for (size_t i = 0; i < rows; ++i)
            out.push_back(numbers(v.items[i], cols, where + "[" + std::to_string(i) + "]"));
        return out;
    }

    std::string string(const TomlValue& v, const std::string& where) const {
        if (v.kind != TomlValue::Kind::String)
            fail(v, where + ": expected a string, got " + TomlValue::kind_name(v.kind));
        return v.string;
    }

    RobotFile read(const TomlValue& root) const {
        RobotFile r;
        check_keys(root, {"name", "units", "carriage", "hexapod"}, {"hexapod"}, "");
        if (const TomlValue* units = root.find("units")) {
            check_keys(*units, {"length", "angle"}, {}, "units");
            const TomlValue* len = units->find("length");
            const TomlValue* ang = units->find("angle");
            if ((len && string(*len, "units.length") != "mm") ||
                (ang && string(*ang, "units.angle") != "rad"))
                fail(*units, "units: only length = 'mm', angle = 'rad' are supported");
        }
        r.name = "robot";
        if (const TomlValue* name = root.find("name")) r.name = string(*name, "name");

        std::vector<std::vector<double>> dh, limits;
        if (const TomlValue* carriage = root.find("carriage")) {
            check_keys(*carriage, {"joints"}, {}, "carriage");
            if (const TomlValue* joints = carriage->find("joints")) {
                // [[carriage.joints]] tables, or an array of inline tables (each item checked below).
                if (joints->kind != TomlValue::Kind::TableArray && joints->kind != TomlValue::Kind::Array)
                    fail(*joints, "carriage.joints: expected an array of tables ([[carriage.joints]])");
                for (size_t i = 0; i < joints->items.size(); ++i) {
                    const TomlValue& j = joints->items[i];
                    const std::string where = "carriage.joints[" + std::to_string(i) + "]";
                    const std::set<std::string> keys{"type", "alpha", "a", "d", "theta", "limits"};
                    check_keys(j, keys, keys, where);
                    const std::string type = string(*j.find("type"), where + ".type");
                    if (type != "prismatic" && type != "revolute")
                        fail(*j.find("type"), where + ".type: '" + type +
                                                  "'; expected 'prismatic' or 'revolute'");
                    r.joint_types += type == "prismatic" ? 'P' : 'R';
                    std::vector<double> row;
                    for (const char* c : {"alpha", "a", "d", "theta"})
                        row.push_back(number(*j.find(c), where + "." + c));
                    dh.push_back(row);
                    std::vector<double> lim = numbers(*j.find("limits"), 2, where + ".limits");
                    if (!(lim[0] < lim[1]))
                        fail(*j.find("limits"), where + ".limits: lower " + num_str(lim[0]) +
                                                    " >= upper " + num_str(lim[1]));
                    limits.push_back(lim);
                }
            }
        }
        const Eigen::Index n = static_cast<Eigen::Index>(dh.size());
        r.dh.resize(n, 4);
        r.joint_limits.resize(n, 2);
        for (Eigen::Index i = 0; i < n; ++i) {
            for (int c = 0; c < 4; ++c) r.dh(i, c) = dh[static_cast<size_t>(i)][static_cast<size_t>(c)];
            for (int c = 0; c < 2; ++c)
                r.joint_limits(i, c) = limits[static_cast<size_t>(i)][static_cast<size_t>(c)];
        }

        const TomlValue& hexa = *root.find("hexapod");
        const std::set<std::string> required{"base_joints", "platform_joints", "leg_offsets", "leg_stroke"};
        std::set<std::string> allowed = required;
        allowed.insert("home_pose");
        allowed.insert("workspace");
        check_keys(hexa, allowed, required, "hexapod");
        const auto base = matrix(*hexa.find("base_joints"), 6, 3, "hexapod.base_joints");
        const auto plat = matrix(*hexa.find("platform_joints"), 6, 3, "hexapod.platform_joints");
        const auto l0 = numbers(*hexa.find("leg_offsets"), 6, "hexapod.leg_offsets");
        for (int j = 0; j < 6; ++j) {
            for (int c = 0; c < 3; ++c) {
                r.base(j, c) = base[static_cast<size_t>(j)][static_cast<size_t>(c)];
                r.platform(j, c) = plat[static_cast<size_t>(j)][static_cast<size_t>(c)];
            }
            r.leg_offsets(j) = l0[static_cast<size_t>(j)];
        }
        const TomlValue& stroke = *hexa.find("leg_stroke");
        if (stroke.kind == TomlValue::Kind::Array && stroke.items.size() == 2 &&
            stroke.items[0].kind != TomlValue::Kind::Array) {
            const auto s = numbers(stroke, 2, "hexapod.leg_stroke");
            for (int j = 0; j < 6; ++j) r.leg_stroke.row(j) << s[0], s[1];
        } else {
            const auto s = matrix(stroke, 6, 2, "hexapod.leg_stroke");
            for (int j = 0; j < 6; ++j)
                r.leg_stroke.row(j) << s[static_cast<size_t>(j)][0], s[static_cast<size_t>(j)][1];
        }
        for (int j = 0; j < 6; ++j)
            if (!(r.leg_stroke(j, 0) < r.leg_stroke(j, 1)))
                fail(stroke, "hexapod.leg_stroke: leg " + std::to_string(j + 1) + " has lower " +
                                 num_str(r.leg_stroke(j, 0)) + " >= upper " + num_str(r.leg_stroke(j, 1)));
        r.home_pose << 0.0, 0.0, 600.0, 0.0, 0.0, 0.0;
        r.workspace << 100.0, 100.0, 60.0, 0.15, 0.15, 0.15;
        if (const TomlValue* v = hexa.find("home_pose")) {
            const auto h = numbers(*v, 6, "hexapod.home_pose");
            for (int k = 0; k < 6; ++k) r.home_pose(k) = h[static_cast<size_t>(k)];
        }
        if (const TomlValue* v = hexa.find("workspace")) {
            const auto w = numbers(*v, 6, "hexapod.workspace");
            for (int k = 0; k < 6; ++k) {
                if (w[static_cast<size_t>(k)] < 0)
                    fail(*v, "hexapod.workspace: half-widths must be >= 0, got " +
                                 num_str(w[static_cast<size_t>(k)]));
                r.workspace(k) = w[static_cast<size_t>(k)];
            }
        }
        try {
            (void)r.geometry();
        } catch (const std::invalid_argument& e) {
            throw InputError(file_ + ": " + e.what());
        }
        return r;
    }

private:
    const std::string& file_;
};

// --- measurement CSV -------------------------------------------------------------------------

// One CSV record with the default dialect of Python's csv module (',' and '"', doubled quotes).
std::vector<std::string> split_csv(const std::string& line) {
    std::vector<std::string> out;
    std::string field;
    bool quoted = false;
    for (size_t i = 0; i < line.size(); ++i) {
        const char c = line[i];
        if (quoted) {
            if (c == '"') {
                if (i + 1 < line.size() && line[i + 1] == '"') {
                    field += '"';
                    ++i;
                } else {
                    quoted = false;
                }
            } else {
                field += c;
            }
        } else if (c == '"' && field.empty()) {
            quoted = true;
        } else if (c == ',') {
            out.push_back(field);
            field.clear();
        } else {
            field += c;
        }
    }
    out.push_back(field);
    return out;
}

std::string strip(const std::string& s) {
    const char* ws = " \t\r\n\f\v";
    const size_t b = s.find_first_not_of(ws);
    if (b == std::string::npos) return "";
    const size_t e = s.find_last_not_of(ws);
    return s.substr(b, e - b + 1);
}

// Python's float(): decimal numbers, inf and nan (refused later); no hexadecimal.
bool parse_double(const std::string& s, double& out) {
    if (s.empty() || s.find_first_of("xXpP") != std::string::npos) return false;
    char* end = nullptr;
    out = std::strtod(s.c_str(), &end);
    return end == s.c_str() + s.size();
}

const char* const kPoseCols[] = {"x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad"};

std::string quoted(const std::string& s) { return "'" + s + "'"; }

}  // namespace

Geometry RobotFile::geometry() const {
    return Geometry(joint_types, dh, base, platform, leg_offsets);
}

std::vector<std::string> RobotFile::parameter_names() const {
    std::vector<std::string> names;
    for (size_t i = 0; i < joint_types.size(); ++i)
        for (const char* c : {"alpha", "a", "d", "theta"})
            names.push_back("joint" + std::to_string(i + 1) + ".d" + c);
    for (int j = 1; j <= 6; ++j)
        for (const char* c : {"x", "y", "z"}) names.push_back("leg" + std::to_string(j) + ".da_" + c);
    for (int j = 1; j <= 6; ++j)
        for (const char* c : {"x", "y", "z"}) names.push_back("leg" + std::to_string(j) + ".db_" + c);
    for (int j = 1; j <= 6; ++j) names.push_back("leg" + std::to_string(j) + ".dl0");
    return names;
}

std::vector<bool> RobotFile::angle_parameters() const {
    std::vector<bool> mask;
    for (size_t i = 0; i < joint_types.size(); ++i)
        for (bool angle : {true, false, false, true}) mask.push_back(angle);
    mask.resize(mask.size() + kHexapodParams, false);
    return mask;
}

RobotFile robot_from_toml(const TomlValue& root, const std::string& file) {
    return RobotReader(file).read(root);
}

RobotFile read_robot(const std::string& path) { return robot_from_toml(read_toml(path), path); }

MeasurementFile parse_measurements(const std::string& text, const std::string& file) {
    MeasurementFile m;
    std::vector<std::string> header;
    bool weights = false;
    std::vector<std::vector<double>> rows;
    size_t pos = 0;
    int lineno = 0;
    auto where = [&](int line) { return file + ": line " + std::to_string(line); };
    while (pos < text.size()) {
        size_t end = text.find('\n', pos);
        if (end == std::string::npos) end = text.size();
        const std::string line = text.substr(pos, end - pos);
        pos = end + 1;
        ++lineno;
        const std::string stripped = strip(line);
        if (stripped.empty() || stripped[0] == '#') continue;
        std::vector<std::string> fields = split_csv(line);
        for (auto& f : fields) f = strip(f);
        if (header.empty()) {
            header = fields;
            size_t i = 0;
            while (i < header.size() && !header[i].empty() && header[i][0] == 'q') {
                const std::string want = "q" + std::to_string(i + 1) + "_";
                const std::string& h = header[i];
                if (h == want + "mm") m.joint_types += 'P';
                else if (h == want + "rad") m.joint_types += 'R';
                else
                    throw InputError(where(lineno) + ": column " + std::to_string(i + 1) + " is " +
                                     quoted(h) + "; expected " + quoted(want + "mm") + " or " +
                                     quoted(want + "rad"));
                ++i;
            }
            std::vector<std::string> expected(std::begin(kPoseCols), std::end(kPoseCols));
            for (int j = 1; j <= 6; ++j) expected.push_back("s" + std::to_string(j) + "_mm");
            const size_t rest = header.size() - i;
            weights = rest == expected.size() + 6;
            if (weights)
                for (int j = 1; j <= 6; ++j) expected.push_back("w" + std::to_string(j));
            for (size_t k = 0; k < rest && k < expected.size(); ++k)
                if (header[i + k] != expected[k])
                    throw InputError(where(lineno) + ": column " + std::to_string(i + k + 1) + " is " +
                                     quoted(header[i + k]) + "; expected " + quoted(expected[k]));
            if (rest < expected.size()) {
                std::string missing;
                for (size_t k = rest; k < expected.size(); ++k) missing += (k > rest ? ", " : "") + expected[k];
                throw InputError(where(lineno) + ": missing columns " + missing);
            }
            if (rest > expected.size())
                throw InputError(where(lineno) + ": unknown column " + quoted(header[i + expected.size()]));
            continue;
        }
        if (fields.size() != header.size())
            throw InputError(where(lineno) + ": " + std::to_string(fields.size()) +
                             " fields; the header has " + std::to_string(header.size()));
        std::vector<double> values(fields.size());
        for (size_t k = 0; k < fields.size(); ++k) {
            if (!parse_double(fields[k], values[k]))
                throw InputError(where(lineno) + ", column " + header[k] + ": " + quoted(fields[k]) +
                                 " is not a number");
            if (!std::isfinite(values[k]))
                throw InputError(where(lineno) + ", column " + header[k] + ": " + quoted(fields[k]) +
                                 " is not finite");
            if (weights && k >= fields.size() - 6 && values[k] < 0)
                throw InputError(where(lineno) + ", column " + header[k] + ": " + quoted(fields[k]) +
                                 " is negative; weights must be >= 0");
        }
        rows.push_back(std::move(values));
    }
    if (header.empty()) throw InputError(file + ": empty file (no header line)");
    if (rows.empty()) throw InputError(file + ": no data rows after the header");
    const Eigen::Index n = static_cast<Eigen::Index>(rows.size());
    const Eigen::Index nj = static_cast<Eigen::Index>(m.joint_types.size());
    m.q.resize(n, nj);
    m.poses.resize(n, 6);
    m.legs.resize(n, 6);
    if (weights) m.weights.resize(n, 6);
    for (Eigen::Index r = 0; r < n; ++r) {
        const auto& v = rows[static_cast<size_t>(r)];
        auto at = [&](Eigen::Index c) { return v[static_cast<size_t>(c)]; };
        for (Eigen::Index c = 0; c < nj; ++c) m.q(r, c) = at(c);
        for (Eigen::Index c = 0; c < 6; ++c) {
            m.poses(r, c) = at(nj + c);
            m.legs(r, c) = at(nj + 6 + c);
            if (weights) m.weights(r, c) = at(nj + 12 + c);
        }
    }
    return m;
}

MeasurementFile read_measurements(const std::string& path) {
    return parse_measurements(read_file(path), path);
}

void default_bounds(const RobotFile& robot, const std::string& kind, VectorXd& lower,
                    VectorXd& upper) {
    const std::vector<bool> angle = robot.angle_parameters();
    const Eigen::Index n = static_cast<Eigen::Index>(angle.size());
    upper.resize(n);
    for (Eigen::Index i = 0; i < n; ++i) {
        if (kind == "paper") upper(i) = 0.5;
        else if (kind == "default") upper(i) = angle[static_cast<size_t>(i)] ? 0.5 * (M_PI / 180.0) : 0.5;  // as math.radians
        else throw std::invalid_argument("bounds: unknown preset '" + kind + "'; expected 'default' or 'paper'");
    }
    lower = -upper;
}

}  // namespace iwr::app
