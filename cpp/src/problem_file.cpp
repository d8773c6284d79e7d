#include "iwr/problem_file.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>

#include "iwr/binary_io.hpp"

namespace iwr {

namespace {

const char kMagic[8] = {'I', 'W', 'R', 'P', 'R', 'O', 'B', '\x1a'};
constexpr std::uint64_t kMaxFile = std::uint64_t(64) << 30;  // 64 GiB: 10^8 poses fit
constexpr std::size_t kMaxText = 4096;
constexpr std::size_t kMaxSources = 64;

template <class M>
void put(io::Writer& w, const M& m) {
    w.doubles(m.data(), static_cast<std::size_t>(m.size()));
}

// Exactly rows x cols finite values (any value outside [-limit, limit] refused: no coordinate,
// length or angle of a robot comes near 1e12, and larger ones would overflow the cost).
template <class M>
void get(io::Reader& r, const char* field, M& m, Eigen::Index rows, Eigen::Index cols,
         double limit = 1e12) {
    const std::vector<double> v = r.doubles(field, static_cast<std::size_t>(rows * cols));
    for (std::size_t k = 0; k < v.size(); ++k)
        if (!(std::fabs(v[k]) <= limit))
            r.fail(std::string(field) + ": row " + std::to_string(cols ? k / static_cast<std::size_t>(cols) : 0) +
                   ", column " + std::to_string(cols ? k % static_cast<std::size_t>(cols) : 0) + " is " +
                   std::to_string(v[k]) + (std::isfinite(v[k]) ? ", beyond any robot" : ", not finite"));
    m.resize(rows, cols);
    for (Eigen::Index i = 0; i < rows; ++i)
        for (Eigen::Index j = 0; j < cols; ++j) m(i, j) = v[static_cast<std::size_t>(i * cols + j)];
}

}  // namespace

Geometry ProblemData::geometry() const { return Geometry(joint_types, dh, base, platform, leg_offsets); }

std::uint64_t ProblemData::robot_fingerprint() const {
    io::Hash64 h;
    h.str("robot").str(joint_types);
    h.doubles(dh.data(), static_cast<std::size_t>(dh.size()));
    h.doubles(base.data(), 18).doubles(platform.data(), 18).doubles(leg_offsets.data(), 6);
    return h.value();
}

std::uint64_t ProblemData::data_fingerprint() const {
    io::Hash64 h;
    h.str("measurements").str(has_measurement_joint_types ? measurement_joint_types : joint_types);
    for (const RowMatrixXd* a : {&q, &poses, &legs, &weights}) {
        h.u64(static_cast<std::uint64_t>(a->rows())).u64(static_cast<std::uint64_t>(a->cols()));
        h.doubles(a->data(), static_cast<std::size_t>(a->size()));
    }
    return h.value();
}

std::string encode_problem(const ProblemData& p) {
    io::Writer w;
    w.str(p.robot_name);
    w.str(p.joint_types);
    put(w, p.dh);
    put(w, p.joint_limits);
    put(w, p.base);
    put(w, p.platform);
    put(w, p.leg_offsets);
    put(w, p.leg_stroke);
    put(w, p.home_pose);
    put(w, p.workspace);
    w.u8(p.has_measurement_joint_types ? 1 : 0);
    w.str(p.measurement_joint_types);
    w.u64(static_cast<std::uint64_t>(p.poses.rows()));
    put(w, p.q);
    put(w, p.poses);
    put(w, p.legs);
    w.u8(p.weights.size() ? 1 : 0);
    put(w, p.weights);
    w.doubles(p.lower);
    w.doubles(p.upper);
    w.str(p.bounds_kind);
    w.u64(p.parameter_names.size());
    for (const auto& n : p.parameter_names) w.str(n);
    w.u64(p.sources.size());
    for (const auto& s : p.sources) {
        w.str(s.role);
        w.str(s.path);
        w.str(s.sha256);
    }
    std::string bytes = io::seal(kMagic, kProblemVersion, w.data());
    // The writer never writes what the reader would refuse: the reader's checks are the checks.
    try {
        decode_problem(bytes, "");
    } catch (const io::FormatError& e) {
        throw std::invalid_argument(e.what());
    }
    return bytes;
}

ProblemData decode_problem(const std::string& bytes, const std::string& context) {
    const std::string payload = io::unseal(bytes, kMagic, kProblemVersion, context, "an iwr problem file");
    io::Reader r(payload.data(), payload.size(), context);
    ProblemData p;
    p.robot_name = r.text("robot name", kMaxText);
    p.joint_types = r.str("joint types", kMaxJoints);
    for (char c : p.joint_types)
        if (c != 'P' && c != 'R') r.fail("joint types: '" + std::string(1, c) + "'; expected P or R");
    const Eigen::Index n = static_cast<Eigen::Index>(p.joint_types.size());
    get(r, "dh", p.dh, n, 4);
    get(r, "joint limits", p.joint_limits, n, 2);
    for (Eigen::Index i = 0; i < n; ++i)
        if (!(p.joint_limits(i, 0) < p.joint_limits(i, 1)))
            r.fail("joint limits: joint " + std::to_string(i + 1) + " has lower >= upper");
    get(r, "base joints", p.base, 6, 3);
    get(r, "platform joints", p.platform, 6, 3);
    get(r, "leg offsets", p.leg_offsets, 6, 1);
    get(r, "leg stroke", p.leg_stroke, 6, 2);
    for (int i = 0; i < 6; ++i)
        if (!(p.leg_stroke(i, 0) < p.leg_stroke(i, 1)))
            r.fail("leg stroke: leg " + std::to_string(i + 1) + " has lower >= upper");
    get(r, "home pose", p.home_pose, 6, 1);
    get(r, "workspace", p.workspace, 6, 1);
    for (int i = 0; i < 6; ++i)
        if (p.workspace(i) < 0) r.fail("workspace: half-width " + std::to_string(i) + " is negative");
    p.has_measurement_joint_types = r.flag("has measurement joint types");
    p.measurement_joint_types = r.str("measurement joint types", kMaxJoints);
    if (p.has_measurement_joint_types && p.measurement_joint_types != p.joint_types)
        r.fail("measurement joint types '" + p.measurement_joint_types + "' do not match the robot's '" +
               p.joint_types + "'");
    if (!p.has_measurement_joint_types && !p.measurement_joint_types.empty())
        r.fail("measurement joint types: set without its flag");
    const std::uint64_t N = r.u64("number of poses");
    // Each pose takes at least 8 (6 + 6) doubles below: a count the file cannot hold is refused
    // before anything is allocated.
    if (N == 0) r.fail("number of poses: 0; a problem needs measurements");
    if (N > kMaxPoses || N > r.remaining() / (12 * 8))
        r.fail("truncated or corrupt: number of poses " + std::to_string(N) + " does not fit in the " +
               std::to_string(r.remaining()) + " bytes left");
    const Eigen::Index rows = static_cast<Eigen::Index>(N);
    get(r, "q", p.q, rows, n);
    get(r, "poses", p.poses, rows, 6);
    get(r, "legs", p.legs, rows, 6);
    if (r.flag("has weights")) {
        // Any finite weight: their scale is the user's (the cost scales with it).
        get(r, "weights", p.weights, rows, 6, std::numeric_limits<double>::max());
        for (Eigen::Index k = 0; k < p.weights.size(); ++k)
            if (p.weights.data()[k] < 0)
                r.fail("weights: row " + std::to_string(k / 6) + ", column " + std::to_string(k % 6) +
                       " is negative");
    } else {
        get(r, "weights", p.weights, 0, 0);
    }
    const std::size_t np = static_cast<std::size_t>(p.n_params());
    p.lower = r.doubles("lower bounds", np);
    p.upper = r.doubles("upper bounds", np);
    for (std::size_t j = 0; j < np; ++j)
        if (!(std::isfinite(p.lower[j]) && std::isfinite(p.upper[j]) && p.lower[j] < p.upper[j] &&
              std::isfinite(p.upper[j] - p.lower[j])))
            r.fail("bounds: parameter " + std::to_string(j) + " has lower " + std::to_string(p.lower[j]) +
                   ", upper " + std::to_string(p.upper[j]) + "; expected finite bounds, lower < upper");
    p.bounds_kind = r.str("bounds kind", 16);
    if (p.bounds_kind != "default" && p.bounds_kind != "paper" && p.bounds_kind != "custom")
        r.fail("bounds kind: '" + p.bounds_kind + "'; expected default, paper or custom");
    const std::size_t nn = r.count("parameter names", 8);
    if (nn != np)
        r.fail("parameter names: " + std::to_string(nn) + "; expected " + std::to_string(np));
    p.parameter_names.reserve(nn);
    for (std::size_t k = 0; k < nn; ++k)
        p.parameter_names.push_back(r.text("parameter name", kMaxText, false));
    const std::size_t ns = r.count("sources", 24);
    if (ns > kMaxSources) r.fail("sources: " + std::to_string(ns) + "; at most " + std::to_string(kMaxSources));
    for (std::size_t k = 0; k < ns; ++k) {
        ProblemSource s;
        s.role = r.text("source role", kMaxText, false);
        s.path = r.text("source path", kMaxText);
        s.sha256 = r.str("source sha256", 64);
        for (char c : s.sha256)
            if (!((c >= '0' && c <= '9') || (c >= 'a' && c <= 'f'))) r.fail("source sha256: not hexadecimal");
        if (!s.sha256.empty() && s.sha256.size() != 64) r.fail("source sha256: not 64 hex digits");
        p.sources.push_back(std::move(s));
    }
    r.finish();
    try {
        (void)p.geometry();  // its own checks (joint types, sizes)
    } catch (const std::invalid_argument& e) {
        r.fail(std::string("robot: ") + e.what());
    }
    return p;
}

ProblemData read_problem(const std::string& path) {
    return decode_problem(io::read_file(path, "an iwr problem file", kMaxFile), path + ": ");
}

}  // namespace iwr
