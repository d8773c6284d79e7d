// C++ tests of iwr-calibrate's file handling, run by ctest (and under AddressSanitizer/UBSan):
// the strict TOML subset reader, the measurement CSV reader, and the checkpoint format, which must
// refuse every truncation and every single-byte change without reading out of bounds.
#include <cmath>
#include <cstdio>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "check.hpp"
#include "checkpoint.hpp"
#include "files.hpp"
#include "inputs.hpp"
#include "iwr/de.hpp"
#include "toml.hpp"

namespace {

using iwr::app::InputError;

// What iwr.Robot.hexapod().to_toml() writes (tomli-w layout: multi-line arrays, trailing commas),
// with a few of the other forms TOML allows in the subset.
const char* const kRobot = R"(# comment line
name = "hexa\u0070od"  # a \u escape

[units]
length = 'mm'
angle = "rad"

[carriage]
joints = []

[hexapod]
base_joints = [
    [
        393.9231012048832,
        -69.45927106677213,
        0.0,
    ],
    [393.9231012048832, 69.45927106677213, 0.0],
    [-136.80805733026747, 375.8770483143634, 0],
    [-257.11504387461576, 306.41777724759123, 0.0],
    [-257.11504387461576, -306.4177772475912, 0.0],
    [-136.80805733026742, -375.8770483143634, 0.0],  # comment inside an array
]
platform_joints = [[160.69690242163483, 191.5111107797445, 0.0], [85.5050358314172, 234.92315519647707, 0.0], [-246.201938253052, 43.41204441673257, 0.0], [-246.201938253052, -43.41204441673262, 0.0], [85.50503583141725, -234.92315519647707, 0.0], [160.6969024216348, -191.51111077974454, 0.0]]
leg_offsets = [600.0, 600.0, 6e2, 6_00.0, +600.0, 600]
leg_stroke = [0.0, 400.0]
home_pose = [0.0, 0.0, 750.0, 0.0, 0.0, 0.0]
)";

std::string error_of(const std::string& toml) {
    try {
        iwr::app::robot_from_toml(iwr::app::parse_toml(toml, "r.toml"), "r.toml");
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

bool contains(const std::string& s, const std::string& part) {
    const bool ok = s.find(part) != std::string::npos;
    if (!ok) std::fprintf(stderr, "  '%s' does not contain '%s'\n", s.c_str(), part.c_str());
    return ok;
}

void test_toml_robot() {
    const auto r = iwr::app::robot_from_toml(iwr::app::parse_toml(kRobot, "r.toml"), "r.toml");
    CHECK(r.name == "hexapod");
    CHECK(r.joint_types.empty());
    CHECK(r.base(0, 0) == 393.9231012048832 && r.base(0, 1) == -69.45927106677213);
    CHECK(r.base(2, 2) == 0.0);
    CHECK(r.platform(5, 1) == -191.51111077974454);
    for (int j = 0; j < 6; ++j) CHECK(r.leg_offsets(j) == 600.0);
    CHECK(r.leg_stroke(3, 0) == 0.0 && r.leg_stroke(3, 1) == 400.0);
    CHECK(r.home_pose(2) == 750.0);
    CHECK(r.workspace(0) == 100.0);  // the default, as iwr.Robot's
    CHECK(r.parameter_names().size() == 42 && r.parameter_names().front() == "leg1.da_x");

    const std::string carriage = std::string(kRobot).replace(
        std::string(kRobot).find("[carriage]\njoints = []\n"), 22,
        "[[carriage.joints]]\ntype = \"prismatic\"\nalpha = 1.5707963267948966\na = 0.0\nd = 500.0\n"
        "theta = 0.0\nlimits = [0.0, 2000.0]\n\n[[carriage.joints]]\ntype = \"revolute\"\nalpha = -1.0\n"
        "a = 300.0\nd = 0.0\ntheta = 0.5\nlimits = [-1.0, 1.0]\n");
    const auto c = iwr::app::robot_from_toml(iwr::app::parse_toml(carriage, "c.toml"), "c.toml");
    CHECK(c.joint_types == "PR");
    CHECK(c.dh(0, 0) == 1.5707963267948966 && c.dh(1, 3) == 0.5 && c.joint_limits(1, 0) == -1.0);
    CHECK(c.parameter_names().size() == 50 && c.parameter_names()[7] == "joint2.dtheta");
    CHECK(c.angle_parameters()[0] && !c.angle_parameters()[1] && c.angle_parameters()[7]);

    // The other forms of TOML 1.0 that Python's tomllib reads (so that iwr and iwr-calibrate take
    // the same files): inline tables, arrays of them, dotted keys, multi-line strings, integers in
    // hexadecimal, octal and binary; the same robot as the [[carriage.joints]] form.
    std::string other = carriage;
    other.replace(other.find("name = \"hexa\\u0070od\""), 21, "name = \"\"\"\\\n   hexapod\"\"\"");
    other.replace(other.find("[units]\nlength = 'mm'\nangle = \"rad\"\n"), 35,
                  "units = {length = '''mm''', angle = \"rad\"}\n");
    const size_t j0 = other.find("[[carriage.joints]]"), j1 = other.find("[hexapod]");
    other.replace(j0, j1 - j0,
                  "carriage.joints = [{type = \"prismatic\", alpha = 1.5707963267948966, a = 0x0, d = 500.0, "
                  "theta = 0o0, limits = [0b0, 2000.0]},\n  {type = \"revolute\", alpha = -1.0, a = 0x12c, "
                  "d = 0.0, theta = 0.5, limits = [-1.0, 1.0]},\n]\n");
    const auto o = iwr::app::robot_from_toml(iwr::app::parse_toml(other, "o.toml"), "o.toml");
    CHECK(o.name == "hexapod" && o.joint_types == "PR" && o.dh == c.dh && o.joint_limits == c.joint_limits);
    CHECK(o.base == c.base && o.leg_stroke == c.leg_stroke && o.home_pose == c.home_pose);
    const auto dotted = iwr::app::parse_toml("a.b.c = 1\na.b.d = 0xff_ff\n[x]\ny.z = '''it's'''\n", "d.toml");
    CHECK(dotted.find("a")->find("b")->find("d")->number == 65535.0);
    CHECK(dotted.find("x")->find("y")->find("z")->string == "it's");
    CHECK(iwr::app::parse_toml("s = \"\"\"\r\na\r\nb\"\"\"\"\n", "s.toml").find("s")->string == "a\nb\"");

    // Refusals, each naming the line, and the column of a syntax error.
    CHECK(contains(error_of("flag = true\n"), "r.toml: line 1, column 8: booleans are not supported"));
    CHECK(contains(error_of("\n\nt = 1979-05-27T07:32:00Z\n"), "line 3, column 5: '1979-05-27T07:32:00Z': dates"));
    CHECK(contains(error_of("x = {a = 1}\n"), "line 1: x: unknown key"));
    CHECK(contains(error_of("x = {a = 1,}\n"), "line 1, column 12: a trailing comma is not allowed"));
    CHECK(contains(error_of("x = {a = 1,\nb = 2}\n"), "line 1, column 12: expected a key"));
    CHECK(contains(error_of("x = {a = 1}\n[x]\n"), "line 2: [x]: already defined on line 1"));
    CHECK(contains(error_of("x = {a = 1}\n[x.b]\n"), "line 2: x: an inline table (line 1) cannot be extended"));
    CHECK(contains(error_of("a.b = 1\n[a]\n"), "line 2: [a]: already defined"));
    CHECK(contains(error_of("[a]\nb.c = 1\n[x]\n[a.b]\n"), "line 4: [a.b]: already defined"));
    CHECK(contains(error_of("[a.b]\nc = 1\n[a]\nb.d = 1\n"), "line 4: key 'b' is already defined"));
    CHECK(contains(error_of("s = \"\"\"x\n"), "line 1: unterminated multi-line string"));
    CHECK(contains(error_of("x = -0x10\n"), "column 5: '-0x10' is not a number"));
    CHECK(contains(error_of("x = 0x\n"), "'0x' is not a number"));
    CHECK(contains(error_of("x = 1\ry = 2\n"), "line 1, column 6: unexpected '\\r' after the value"));
    CHECK(contains(error_of("x = [1, 2\ny = 3\n"), "line 2, column 1: unexpected 'y' in an array"));
    CHECK(contains(error_of("x = [1, 2,\n"), "line 1: unterminated array"));
    CHECK(contains(error_of("x = 1\nx = 2\n"), "line 2: key 'x' is defined twice (first on line 1)"));
    CHECK(contains(error_of("[hexapod]\n[hexapod]\n"), "line 2: [hexapod]: already defined on line 1"));
    CHECK(contains(error_of("x = 1 2\n"), "line 1, column 7: unexpected '2' after the value"));
    CHECK(contains(error_of("x = 007\n"), "leading zeros"));
    CHECK(contains(error_of("x = 1__0\n"), "'1__0' is not a number"));
    CHECK(contains(error_of("x = .5\n"), "'.5' is not a number"));
    CHECK(contains(error_of("x = \"abc\n"), "line 1, column 9: unterminated string"));
    CHECK(contains(error_of("x = \"a\\qb\"\n"), "unknown escape '\\q'"));
    CHECK(contains(error_of("x = \"a\\\nb\"\n"), "line 1, column 7: a backslash before '\\n' in a string"));
    CHECK(contains(error_of("x = \"a\x01\"\n"), "line 1, column 7: control character '\\x01' in a string"));
    CHECK(contains(error_of("x =\n"), "line 1, column 4: missing value"));
    CHECK(contains(error_of("= 1\n"), "line 1, column 1: unexpected '='; expected a key"));
    CHECK(contains(error_of("[a\n"), "line 1, column 3: expected ']'"));
    // UTF-8 only (as tomllib), without a byte order mark (tomllib refuses one).
    CHECK(contains(error_of("# caf\xe9\nname = \"x\"\n"), "r.toml: line 1, column 6: byte 0xe9 is not valid UTF-8"));
    CHECK(contains(error_of("name = \"\xc3\xa9\xed\xa0\x80\"\n"), "line 1, column 10: byte 0xed is not valid UTF-8"));
    CHECK(contains(error_of("\xef\xbb\xbfname = \"x\"\n"), "line 1, column 1: the file starts with a byte order mark"));
    CHECK(contains(error_of("name = \"caf\xc3\xa9\"\nx = \xc3\xa9\n"), "line 2, column 5: '\xc3\xa9' is not a number"));
    // Robot-level checks (the rules of iwr.Robot.from_dict).
    CHECK(contains(error_of("name = \"x\"\n"), "r.toml: line 1: hexapod: missing key"));
    std::string bad = kRobot;
    bad.replace(bad.find("leg_stroke = [0.0, 400.0]"), 25, "leg_stroke = [400.0, 0.0]");
    CHECK(contains(error_of(bad), "hexapod.leg_stroke: leg 1 has lower 400 >= upper 0"));
    bad = kRobot;
    bad.replace(bad.find("6_00.0"), 6, "inf");
    CHECK(contains(error_of(bad), "line 25: hexapod.leg_offsets[3]: inf is not finite"));
    bad = kRobot;
    bad.replace(bad.find("length = 'mm'"), 13, "length = 'm'");
    CHECK(contains(error_of(bad), "units: only length = 'mm'"));
    bad = kRobot;
    bad.replace(bad.find("home_pose"), 9, "home_posE");
    CHECK(contains(error_of(bad), "hexapod.home_posE: unknown key"));
    bad = kRobot;
    bad.replace(bad.find("    [393.9231012048832, 69.45927106677213, 0.0],\n"), 48, "");
    CHECK(contains(error_of(bad), "line 12: hexapod.base_joints: expected 6 rows of 3 numbers"));

    try {
        iwr::app::read_toml("/nonexistent/robot.toml");
        CHECK(false);
    } catch (const InputError& e) {
        CHECK(contains(e.what(), "/nonexistent/robot.toml: no such file"));
    }
    try {
        iwr::app::read_toml("/");
        CHECK(false);
    } catch (const InputError& e) {
        CHECK(contains(e.what(), "/: is a folder, not a TOML file"));
    }
}

std::string csv_error(const std::string& text) {
    try {
        iwr::app::parse_measurements(text, "d.csv");
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

void test_csv() {
    const std::string header =
        "q1_mm,q2_rad,x_mm,y_mm,z_mm,alpha_rad,beta_rad,gamma_rad,s1_mm,s2_mm,s3_mm,s4_mm,s5_mm,s6_mm";
    const std::string row = "1.5,-0.25,100,200,700,0.1,0.2,0.3,10,11,12,13,14,1e-3";
    const std::string row2 = "2.5,-0.25,100,200,700,0.1,0.2,0.3,10,11,12,13,14,1e-3";
    const auto m = iwr::app::parse_measurements("# comment\n\n" + header + "\r\n" + row + "\n" + row2 + "\n", "d.csv");
    CHECK(m.joint_types == "PR" && m.n_poses() == 2 && m.weights.size() == 0);
    CHECK(m.q(1, 0) == 2.5 && m.q(1, 1) == -0.25 && m.poses(0, 5) == 0.3 && m.legs(0, 5) == 1e-3);
    CHECK(m.lines == std::vector<int>({4, 5}));
    const auto w = iwr::app::parse_measurements(header + ",w1,w2,w3,w4,w5,w6\n" + row + ",1,2,3,4,5,\"6\"\n", "w.csv");
    CHECK(w.weights.rows() == 1 && w.weights(0, 5) == 6.0);
    // Python's str.splitlines() (\r, \v, \f, U+2028, ... end lines), str.strip() and float()
    // (underscores, any Unicode decimal digits, inf/nan spelt in any case).
    const auto p = iwr::app::parse_measurements(
        header + "\r" + row + "\x0b\xe2\x80\xa8 \xc2\xa0 \n1_0.5, -0.25 ,1e2,\xef\xbc\x92\xd9\xa0\xd9\xa0\xc2\xa0,700,0.1,0.2,0.3,10,11,12,13,14,1\n",
        "p.csv");
    CHECK(p.lines == std::vector<int>({2, 5}) && p.q(1, 0) == 10.5 && p.poses(1, 1) == 200.0);

    CHECK(contains(csv_error(""), "d.csv: empty file"));
    CHECK(contains(csv_error(header + "\n"), "d.csv: no data rows"));
    CHECK(contains(csv_error("q1_m," + header.substr(6) + "\n"), "d.csv, line 1: column 1 is 'q1_m'"));
    CHECK(contains(csv_error(header + ",extra\n"), "line 1: unknown columns ['extra']"));
    CHECK(contains(csv_error(header.substr(0, header.size() - 6) + "\n"), "line 1: missing columns ['s6_mm']"));
    CHECK(contains(csv_error("\xef\xbb\xbf" + header + "\n"), "column 1 is '\\ufeffq1_mm'; expected 'x_mm'"));
    CHECK(contains(csv_error(header + "\n" + row + ",7\n"), "d.csv, line 2: 15 fields; the header has 14"));
    CHECK(contains(csv_error(header + "\n#\n1.5,x,1,2,3,0.1,0.2,0.3,10,11,12,13,14,1\n"),
                   "d.csv, line 3, column q2_rad: 'x' is not a number"));
    CHECK(contains(csv_error(header + "\n1.5,nan,1,2,3,0.1,0.2,0.3,10,11,12,13,14,1\n"), "'nan' is not finite"));
    CHECK(contains(csv_error(header + "\n1.5,0x10,1,2,3,0.1,0.2,0.3,10,11,12,13,14,1\n"), "is not a number"));
    CHECK(contains(csv_error(header + "\n1.5,,1,2,3,0.1,0.2,0.3,10,11,12,13,14,1\n"), "column q2_rad: '' is empty"));
    CHECK(contains(csv_error(header + "\n1.5,1\x01" "5,1,2,3,0.1,0.2,0.3,10,11,12,13,14,1\n"), "'1\\x015' is not a number"));
    CHECK(contains(csv_error(header + ",w1,w2,w3,w4,w5,w6\n" + row + ",1,2,3,4,5,-6\n"),
                   "line 2, column w6: '-6' is negative"));
    // Every bad row is named, none dropped (iwr.measurements._summarise).
    std::string many = header + "\n";
    for (int k = 0; k < 12; ++k) many += "1.5,nan,1,2,3,0.1,0.2,0.3,10,11,12,13,14,1\n";
    CHECK(contains(csv_error(many), "d.csv, line 2, column q2_rad: 'nan' is not finite (12 bad rows in all, none "
                                    "dropped: lines 2, 3, 4, 5, 6, 7, 8, 9, 10, 11 and ... (2 more))"));
    // Not UTF-8: named by line and column.
    CHECK(contains(csv_error("# caf\xe9\n" + header + "\n" + row + "\n"), "d.csv, line 1, column 6: byte 0xe9 is not valid UTF-8"));
    // The checks that need no robot (Measurements._check_alone).
    CHECK(contains(csv_error(header + "\n" + row + "\n" + row2 + "\n" + row + "\n"),
                   "d.csv: 1 repeated pose(s): lines 2 and 4 have exactly the same joint readings and measured pose"));
    CHECK(contains(csv_error(header + "\n1.5,-0.25,100,200,700,0.1,20,0.3,10,11,12,13,14,1\n"),
                   "d.csv: pose angles larger than 2 pi at line 2: angles must be in radians"));
    CHECK(contains(csv_error(header + "\n1.5,-0.25,0.1,0.2,0.7,0.1,0.2,0.3,0.01,0.011,0.012,0.013,0.014,0.001\n"),
                   "d.csv: every position and leg reading is below 5.0 (largest position 0.7348, largest leg "
                   "reading 0.014): these look like metres"));
}

std::string robot_check_error(const iwr::app::RobotFile& robot, const std::string& csv) {
    try {
        iwr::app::check_measurements(iwr::app::parse_measurements(csv, "d.csv"), robot, "d.csv");
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

// The checks against the robot (Measurements.check), as `iwr calibrate` and iwr-calibrate make them.
void test_csv_against_robot() {
    std::string text = kRobot;
    text.replace(text.find("[carriage]\njoints = []\n"), 22,
                 "[[carriage.joints]]\ntype = \"prismatic\"\nalpha = 0.0\na = 0.0\nd = 500.0\n"
                 "theta = 0.0\nlimits = [0.0, 2000.0]\n\n[[carriage.joints]]\ntype = \"revolute\"\nalpha = 0.0\n"
                 "a = 0.0\nd = 0.0\ntheta = 0.0\nlimits = [-1.0, 1.0]\n");
    const auto robot = iwr::app::robot_from_toml(iwr::app::parse_toml(text, "r.toml"), "r.toml");
    const std::string header =
        "q1_mm,q2_rad,x_mm,y_mm,z_mm,alpha_rad,beta_rad,gamma_rad,s1_mm,s2_mm,s3_mm,s4_mm,s5_mm,s6_mm\n";
    const std::string ok = header + "1000,0.5,10,20,1250,0.1,0.2,0.3,100,110,120,130,140,150\n" +
                           "1000,0.6,10,20,1250,0.1,0.2,0.3,100,110,120,130,140,404\n";
    CHECK(robot_check_error(robot, ok).empty());  // 404 is within 1 % of the stroke [0, 400]
    CHECK(contains(robot_check_error(robot, ok + "1000,0.7,10,20,1250,0.1,0.2,0.3,100,110,120,130,650,150\n"
                                                 "2100,1.7,10,20,1250,0.1,0.2,0.3,100,110,120,130,140,150\n"),
                   "d.csv: 2 unreachable pose(s) for robot 'hexapod' (lines 4 and 5; nothing dropped); first: line "
                   "4: leg 5 reading 650 mm is outside the stroke [0, 400]"));
    CHECK(contains(robot_check_error(robot, header + "2100,0.5,10,20,1250,0.1,0.2,0.3,100,110,120,130,140,150\n"),
                   "first: line 2: joint 1 reading 2100 mm is outside the joint limits [0, 2000]"));
    CHECK(contains(robot_check_error(robot, header + "1000,0.5,10,20,1250,0.1,0.2,0.3,0.1,0.11,0.12,0.13,0.14,0.15\n"),
                   "d.csv: every one of the leg readings is below 5.0 (largest 0.15) while robot 'hexapod' is 400 mm "
                   "in size: these look like metres; iwr expects millimetres"));
    CHECK(contains(robot_check_error(robot, header + "1,0.5,10,20,1250,0.1,0.2,0.3,100,110,120,130,140,150\n"),
                   "every one of the prismatic joint readings is below 5.0 (largest 1) while robot 'hexapod' is 2000 mm"));
    CHECK(contains(robot_check_error(robot, header + "1000,0.5,0.01,0.02,1.25,0.1,0.2,0.3,100,110,120,130,140,150\n"),
                   "every one of the positions is below 5.0 (largest 1.25) while robot 'hexapod' is 2250 mm"));
    CHECK(contains(robot_check_error(robot, "q1_mm,q2_mm" + header.substr(12) + "1,2,10,20,1250,0.1,0.2,0.3,100,110,120,130,140,150\n"),
                   "d.csv: joint types 'PP' (from the units of the q columns: _mm prismatic, _rad revolute) do not "
                   "match robot 'hexapod', 'PR'"));
}

// A small but complete DE state, as the executable checkpoints it.
class Sphere : public iwr::de::BatchFunction {
public:
    int dim() const override { return 5; }
    void evaluate(const double* X, std::size_t m, double* out, iwr::ThreadPool&) override {
        for (std::size_t i = 0; i < m; ++i) {
            double s = 0;
            for (int j = 0; j < 5; ++j) s += X[i * 5 + static_cast<std::size_t>(j)] * X[i * 5 + static_cast<std::size_t>(j)];
            out[i] = s;
        }
    }
};

void test_checkpoint_refuses_damage() {
    iwr::de::Settings s;
    s.strategy = iwr::de::Strategy::shade;
    s.lower.assign(5, -1.0);
    s.upper.assign(5, 1.0);
    s.population_size = 8;
    s.memory_size = 3;
    Sphere f;
    iwr::ThreadPool pool(1);
    iwr::de::State st = iwr::de::init(s, f, pool);
    for (int g = 0; g < 3; ++g) iwr::de::step(st, f, pool);
    std::ostringstream blob(std::ios::binary);
    st.serialize(blob);

    iwr::app::Checkpoint c;
    c.program = "test";
    c.robot_fingerprint = 1;
    c.data_fingerprint = 2;
    c.settings_fingerprint = 3;
    c.robot_file = "r.toml";
    c.data_file = "d.csv";
    c.options = {{"generations", "10"}, {"output", "x.json"}};
    c.engine_state = blob.str();
    const std::string bytes = iwr::app::encode_checkpoint(c);

    const iwr::app::Checkpoint back = iwr::app::decode_checkpoint(bytes);
    CHECK(back.robot_fingerprint == 1 && back.data_fingerprint == 2 && back.settings_fingerprint == 3);
    CHECK(back.options == c.options && back.engine_state == c.engine_state && back.data_file == "d.csv");
    std::istringstream in(back.engine_state, std::ios::binary);
    const iwr::de::State st2 = iwr::de::State::deserialize(in);
    CHECK(st2.generation == 3 && st2.population == st.population && st2.costs == st.costs);

    // Every truncation, and a change of every bit of every byte, is refused with an exception.
    int refused = 0, total = 0;
    for (std::size_t n = 0; n < bytes.size(); ++n) {
        ++total;
        try {
            iwr::app::decode_checkpoint(bytes.substr(0, n));
        } catch (const std::runtime_error& e) {
            const std::string what = e.what();
            refused += what.find("truncated") != std::string::npos || what.find("empty") != std::string::npos;
        }
    }
    CHECK(refused == total);
    refused = total = 0;
    for (std::size_t i = 0; i < bytes.size(); ++i) {
        for (int bit = 0; bit < 8; ++bit) {
            std::string edited = bytes;
            edited[i] = static_cast<char>(edited[i] ^ (1 << bit));
            ++total;
            try {
                iwr::app::decode_checkpoint(edited);
            } catch (const std::runtime_error&) {
                ++refused;
            }
        }
    }
    CHECK(refused == total);
    // Trailing bytes, and a payload whose checksum matches but whose contents are garbage.
    try {
        iwr::app::decode_checkpoint(bytes + "x");
        CHECK(false);
    } catch (const std::runtime_error& e) {
        CHECK(contains(e.what(), "corrupt"));
    }
    std::string garbage = bytes.substr(0, 32) + std::string(bytes.size() - 32, '\xff');
    const std::uint64_t h = iwr::app::hash64(garbage.substr(32));
    for (int k = 0; k < 8; ++k) garbage[24 + static_cast<std::size_t>(k)] = static_cast<char>((h >> (8 * k)) & 0xff);
    try {
        iwr::app::decode_checkpoint(garbage);
        CHECK(false);
    } catch (const std::runtime_error& e) {
        CHECK(contains(e.what(), "corrupt: malformed payload"));
    }
}

void test_json_and_hash() {
    CHECK(iwr::app::json_number(0.1) == "0.10000000000000001");
    CHECK(std::stod(iwr::app::json_number(1.0 / 3.0)) == 1.0 / 3.0);
    CHECK(iwr::app::json_number(std::nan("")) == "null");
    CHECK(iwr::app::json_number(1.0) == "1.0" && iwr::app::json_number(-2e300) == "-2.0000000000000001e+300");
    CHECK(iwr::app::json_string("a\"b\\c\n\x01") == "\"a\\\"b\\\\c\\n\\u0001\"");
    CHECK(iwr::app::hash64("") == 0xcbf29ce484222325ULL);
    CHECK(iwr::app::hash64("a") == 0xaf63dc4c8601ec8cULL);  // the published FNV-1a 64 test vector
    CHECK(iwr::app::hex64(255) == "00000000000000ff");
}

}  // namespace

int main() {
    test_toml_robot();
    test_csv();
    test_csv_against_robot();
    test_checkpoint_refuses_damage();
    test_json_and_hash();
    return iwr_test::finish("all iwr-calibrate file checks passed");
}
