#include "inputs.hpp"

#include "files.hpp"

#include <algorithm>
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

using u32 = std::u32string;

u32 ascii(const std::string& s) { return u32(s.begin(), s.end()); }

// One CSV record with the default dialect of Python's csv module (',' and '"', doubled quotes,
// not strict: a quote inside an unquoted field is kept, text after a closing quote appended).
std::vector<u32> split_csv(const u32& line) {
    std::vector<u32> out;
    u32 field;
    bool quoted = false;
    for (size_t i = 0; i < line.size(); ++i) {
        const char32_t c = line[i];
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

// The lines of a text as Python's str.splitlines() cuts them (\n, \r\n, \r, \v, \f, \x1c-\x1e,
// \x85, U+2028, U+2029).
std::vector<u32> split_lines(const u32& text) {
    std::vector<u32> lines;
    size_t start = 0;
    for (size_t i = 0; i < text.size(); ++i) {
        if (!py_line_break(text[i])) continue;
        lines.push_back(text.substr(start, i - start));
        if (text[i] == '\r' && i + 1 < text.size() && text[i + 1] == '\n') ++i;
        start = i + 1;
    }
    if (start < text.size()) lines.push_back(text.substr(start));
    return lines;
}

// "a, b and c", at most `limit` items then "... (N more)", as iwr.measurements._enumerate.
std::string enumerate(std::vector<std::string> items, size_t limit = 10) {
    if (items.size() > limit) {
        const size_t more = items.size() - limit;
        items.resize(limit);
        items.push_back("... (" + std::to_string(more) + " more)");
    }
    if (items.size() == 1) return items[0];
    std::string out;
    for (size_t k = 0; k + 1 < items.size(); ++k) out += (k ? ", " : "") + items[k];
    return out + " and " + items.back();
}

// "line 12" or "lines 12, 15 and 40", as Measurements._lines_of.
std::string lines_of(const MeasurementFile& m, const std::vector<Eigen::Index>& rows) {
    std::vector<std::string> items;
    for (const Eigen::Index k : rows) items.push_back(std::to_string(m.lines[static_cast<size_t>(k)]));
    return (rows.size() > 1 ? "lines " : "line ") + enumerate(items);
}

// A Python list of str, as repr() shows it.
std::string py_list(const std::vector<std::string>& items) {
    std::string out = "[";
    for (size_t k = 0; k < items.size(); ++k) out += (k ? ", " : "") + py_repr(items[k]);
    return out + "]";
}

const char* const kPoseCols[] = {"x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad"};
// Lengths all below this (in what should be millimetres) look like metres (METRE_SUSPICION).
constexpr double kMetreSuspicion = 5.0;

// The header's q columns: q<i>_mm or q<i>_rad with i = 1, 2, ... (Python's \d+ and int(): any
// Unicode decimal digits, leading zeros allowed). Returns 'P', 'R', or 0.
char joint_column(const u32& h, size_t i) {
    if (h.size() < 2 || h[0] != 'q') return 0;
    size_t k = 1;
    unsigned long long n = 0;
    bool big = false;
    while (k < h.size() && py_decimal(h[k]) >= 0) {
        n = n * 10 + static_cast<unsigned>(py_decimal(h[k]));
        big = big || n > 1000000;
        ++k;
    }
    if (k == 1 || big || n != i + 1) return 0;
    const u32 unit = h.substr(k);
    if (unit == ascii("_mm")) return 'P';
    if (unit == ascii("_rad")) return 'R';
    return 0;
}

// Measurements._check_alone: repeated poses, angles in degrees, lengths in metres.
void check_alone(const MeasurementFile& m, const std::string& file) {
    const Eigen::Index n = m.poses.rows(), nj = m.q.cols();
    // Exactly repeated joint readings and pose: a copied row.
    auto key_less = [&](Eigen::Index a, Eigen::Index b) {
        for (Eigen::Index c = 0; c < nj + 6; ++c) {
            const double x = c < nj ? m.q(a, c) : m.poses(a, c - nj);
            const double y = c < nj ? m.q(b, c) : m.poses(b, c - nj);
            if (x < y) return true;
            if (y < x) return false;
        }
        return false;
    };
    std::vector<Eigen::Index> order(static_cast<size_t>(n));
    for (Eigen::Index k = 0; k < n; ++k) order[static_cast<size_t>(k)] = k;
    std::stable_sort(order.begin(), order.end(), key_less);
    std::vector<std::vector<Eigen::Index>> groups;
    for (size_t s = 0; s < order.size();) {
        size_t e = s + 1;
        while (e < order.size() && !key_less(order[s], order[e])) ++e;
        if (e - s > 1) groups.emplace_back(order.begin() + static_cast<std::ptrdiff_t>(s),
                                           order.begin() + static_cast<std::ptrdiff_t>(e));
        s = e;
    }
    if (!groups.empty()) {
        std::sort(groups.begin(), groups.end());  // each group is ascending: by its first row
        std::string desc;
        for (size_t g = 0; g < groups.size() && g < 5; ++g) desc += (g ? "; " : "") + lines_of(m, groups[g]);
        const std::string more = groups.size() > 5
                                     ? " (and " + std::to_string(groups.size() - 5) + " more groups)"
                                     : "";
        throw InputError(file + ": " + std::to_string(groups.size()) + " repeated pose(s): " + desc + more +
                         " have exactly the same joint readings and measured pose; remove the copies "
                         "(or average repeated measurements)");
    }
    std::vector<Eigen::Index> degrees;
    for (Eigen::Index k = 0; k < n; ++k)
        if (m.poses.row(k).tail<3>().cwiseAbs().maxCoeff() > 2 * M_PI) degrees.push_back(k);
    if (!degrees.empty())
        throw InputError(file + ": pose angles larger than 2 pi at " + lines_of(m, degrees) +
                         ": angles must be in radians, not degrees");
    double pos = 0, leg = 0;
    for (Eigen::Index k = 0; k < n; ++k) {
        const double x = m.poses(k, 0), y = m.poses(k, 1), z = m.poses(k, 2);
        pos = std::max(pos, std::sqrt(x * x + y * y + z * z));
        leg = std::max(leg, m.legs.row(k).cwiseAbs().maxCoeff());
    }
    if (pos < kMetreSuspicion && leg < kMetreSuspicion)
        throw InputError(file + ": every position and leg reading is below 5.0 (largest position " +
                         py_g(pos, 4) + ", largest leg reading " + py_g(leg, 4) +
                         "): these look like metres; iwr expects millimetres (multiply the lengths by 1000)");
}

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

MeasurementFile parse_measurements(const std::string& bytes, const std::string& file) {
    u32 text;
    const size_t bad = decode_utf8(bytes, text);
    if (bad != std::string::npos)
        throw InputError(file + ", " + utf8_error_at(bytes, bad) + " (iwr reads CSV files as UTF-8)");
    MeasurementFile m;
    std::vector<u32> header;
    bool have_header = false, weights = false;
    std::vector<std::vector<double>> rows;
    std::vector<std::pair<int, std::string>> problems;  // (line, message): every bad row
    const std::vector<u32> lines = split_lines(text);
    for (size_t index = 0; index < lines.size(); ++index) {
        const int lineno = static_cast<int>(index) + 1;
        const std::string at = "line " + std::to_string(lineno);
        const u32 stripped = py_strip(lines[index]);
        if (stripped.empty() || stripped[0] == '#') continue;
        std::vector<u32> fields = split_csv(lines[index]);
        for (auto& f : fields) f = py_strip(f);
        if (!have_header) {
            have_header = true;
            header = fields;
            const std::string where = file + ", " + at + ": ";
            size_t i = 0;
            while (i < header.size() && !header[i].empty() && header[i][0] == 'q') {
                const char type = joint_column(header[i], i);
                if (!type) {
                    const std::string q = "q" + std::to_string(i + 1);
                    throw InputError(where + "column " + std::to_string(i + 1) + " is " + py_repr(header[i]) +
                                     "; expected '" + q + "_mm' or '" + q + "_rad'");
                }
                m.joint_types += type;
                ++i;
            }
            std::vector<std::string> expected(std::begin(kPoseCols), std::end(kPoseCols));
            for (int j = 1; j <= 6; ++j) expected.push_back("s" + std::to_string(j) + "_mm");
            const size_t rest = header.size() - i;
            weights = rest == expected.size() + 6;
            if (weights)
                for (int j = 1; j <= 6; ++j) expected.push_back("w" + std::to_string(j));
            for (size_t k = 0; k < rest && k < expected.size(); ++k)
                if (header[i + k] != ascii(expected[k]))
                    throw InputError(where + "column " + std::to_string(i + k + 1) + " is " +
                                     py_repr(header[i + k]) + "; expected " + py_repr(expected[k]));
            if (rest < expected.size())
                throw InputError(where + "missing columns " +
                                 py_list(std::vector<std::string>(expected.begin() + static_cast<std::ptrdiff_t>(rest),
                                                                  expected.end())));
            if (rest > expected.size()) {
                std::vector<std::string> extra;
                for (size_t k = i + expected.size(); k < header.size(); ++k) extra.push_back(to_utf8(header[k]));
                throw InputError(where + "unknown columns " + py_list(extra));
            }
            continue;
        }
        if (fields.size() != header.size()) {
            problems.emplace_back(lineno, at + ": " + std::to_string(fields.size()) + " fields; the header has " +
                                              std::to_string(header.size()));
            continue;
        }
        std::vector<double> values(fields.size());
        bool ok = true;
        for (size_t k = 0; k < fields.size() && ok; ++k) {
            const std::string cell = at + ", column " + to_utf8(header[k]) + ": " + py_repr(fields[k]);
            if (!py_float(fields[k], values[k])) {
                problems.emplace_back(lineno, cell + (fields[k].empty() ? " is empty" : " is not a number"));
                ok = false;
            } else if (!std::isfinite(values[k])) {
                problems.emplace_back(lineno, cell + " is not finite");
                ok = false;
            } else if (weights && k >= fields.size() - 6 && values[k] < 0) {
                problems.emplace_back(lineno, cell + " is negative; weights must be >= 0");
                ok = false;
            }
        }
        if (ok) {
            rows.push_back(std::move(values));
            m.lines.push_back(lineno);
        }
    }
    if (!have_header) throw InputError(file + ": empty file (no header line)");
    if (!problems.empty()) {
        // One line: the first problem in full, then the lines of all of them (_summarise).
        std::vector<std::string> bad_lines;
        for (const auto& p : problems)
            if (bad_lines.empty() || bad_lines.back() != std::to_string(p.first))
                bad_lines.push_back(std::to_string(p.first));
        std::string msg = file + ", " + problems.front().second;
        if (bad_lines.size() > 1)
            msg += " (" + std::to_string(bad_lines.size()) + " bad rows in all, none dropped: lines " +
                   enumerate(bad_lines) + ")";
        throw InputError(msg);
    }
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
    check_alone(m, file);
    return m;
}

MeasurementFile read_measurements(const std::string& path) {
    return parse_measurements(read_file(path, "a CSV file"), path);
}

void check_measurements(const MeasurementFile& m, const RobotFile& robot, const std::string& file) {
    const std::string& types = robot.joint_types;
    if (m.joint_types != types)
        throw InputError(file + ": joint types " + py_repr(m.joint_types) +
                         " (from the units of the q columns: _mm prismatic, _rad revolute) do not match "
                         "robot " + py_repr(robot.name) + ", " + py_repr(types));
    const Eigen::Index n = m.poses.rows(), nj = static_cast<Eigen::Index>(types.size());
    // -- scale: metres where millimetres are expected --------------------------------------
    const Geometry g = robot.geometry();
    const VectorXd zero = VectorXd::Zero(g.n_params());
    VectorXd mid(nj);
    for (Eigen::Index i = 0; i < nj; ++i) mid(i) = (robot.joint_limits(i, 0) + robot.joint_limits(i, 1)) / 2;
    const Mat4 t4 = carriage_transform(g, zero.data(), mid.data());
    const Eigen::Vector3d home =
        t4.block<3, 1>(0, 3) + t4.block<3, 3>(0, 0) * robot.home_pose.head<3>();
    struct Scale {
        const char* what;
        double largest, robot;
    };
    std::vector<Scale> scales;
    double pos = 0, leg = 0, prismatic = 0, prismatic_range = 0;
    for (Eigen::Index k = 0; k < n; ++k) {
        const double x = m.poses(k, 0), y = m.poses(k, 1), z = m.poses(k, 2);
        pos = std::max(pos, std::sqrt(x * x + y * y + z * z));
        leg = std::max(leg, m.legs.row(k).cwiseAbs().maxCoeff());
    }
    scales.push_back({"positions", pos, std::sqrt(home.squaredNorm())});
    scales.push_back({"leg readings", leg, robot.leg_stroke.maxCoeff() - robot.leg_stroke.minCoeff()});
    bool any_prismatic = false;
    for (Eigen::Index i = 0; i < nj; ++i) {
        if (types[static_cast<size_t>(i)] != 'P') continue;
        const double range = robot.joint_limits(i, 1) - robot.joint_limits(i, 0);
        prismatic_range = any_prismatic ? std::max(prismatic_range, range) : range;
        any_prismatic = true;
        for (Eigen::Index k = 0; k < n; ++k) prismatic = std::max(prismatic, std::abs(m.q(k, i)));
    }
    if (any_prismatic) scales.push_back({"prismatic joint readings", prismatic, prismatic_range});
    for (const Scale& s : scales)
        if (s.robot > 10 * kMetreSuspicion && s.largest < kMetreSuspicion)
            throw InputError(file + ": every one of the " + s.what + " is below 5.0 (largest " + py_g(s.largest, 4) +
                             ") while robot " + py_repr(robot.name) + " is " + py_g(s.robot, 4) +
                             " mm in size: these look like metres; iwr expects millimetres");
    // -- reachability, with 1 % of each range for noise ---------------------------------------
    const double tolerance = 0.01;
    std::vector<std::pair<Eigen::Index, std::string>> problems;
    for (Eigen::Index i = 0; i < nj; ++i) {
        const double lo = robot.joint_limits(i, 0), hi = robot.joint_limits(i, 1);
        const double slack = tolerance * (hi - lo);
        const char* unit = types[static_cast<size_t>(i)] == 'P' ? "mm" : "rad";
        for (Eigen::Index k = 0; k < n; ++k)
            if (m.q(k, i) < lo - slack || m.q(k, i) > hi + slack)
                problems.emplace_back(k, "line " + std::to_string(m.lines[static_cast<size_t>(k)]) + ": joint " +
                                             std::to_string(i + 1) + " reading " + py_g(m.q(k, i), 6) + " " +
                                             unit + " is outside the joint limits [" + py_g(lo, 6) + ", " +
                                             py_g(hi, 6) + "]");
    }
    for (int j = 0; j < 6; ++j) {
        const double lo = robot.leg_stroke(j, 0), hi = robot.leg_stroke(j, 1);
        const double slack = tolerance * (hi - lo);
        for (Eigen::Index k = 0; k < n; ++k)
            if (m.legs(k, j) < lo - slack || m.legs(k, j) > hi + slack)
                problems.emplace_back(k, "line " + std::to_string(m.lines[static_cast<size_t>(k)]) + ": leg " +
                                             std::to_string(j + 1) + " reading " + py_g(m.legs(k, j), 6) +
                                             " mm is outside the stroke [" + py_g(lo, 6) + ", " + py_g(hi, 6) + "]");
    }
    if (!problems.empty()) {
        std::stable_sort(problems.begin(), problems.end(),
                         [](const auto& a, const auto& b) { return a.first < b.first; });
        std::vector<Eigen::Index> rows;
        for (const auto& p : problems)
            if (rows.empty() || rows.back() != p.first) rows.push_back(p.first);
        throw InputError(file + ": " + std::to_string(rows.size()) + " unreachable pose(s) for robot " +
                         py_repr(robot.name) + " (" + lines_of(m, rows) + "; nothing dropped); first: " +
                         problems.front().second);
    }
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
