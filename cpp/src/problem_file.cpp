#include "iwr/problem_file.hpp"

#include <algorithm>
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
// allow_nan: NaN is a value (a reflector not seen), not an error.
template <class M>
void get(io::Reader& r, const char* field, M& m, Eigen::Index rows, Eigen::Index cols,
         double limit = 1e12, bool allow_nan = false) {
    const std::vector<double> v = r.doubles(field, static_cast<std::size_t>(rows * cols));
    for (std::size_t k = 0; k < v.size(); ++k)
        if (!(std::fabs(v[k]) <= limit) && !(allow_nan && std::isnan(v[k])))
            r.fail(std::string(field) + ": row " + std::to_string(cols ? k / static_cast<std::size_t>(cols) : 0) +
                   ", column " + std::to_string(cols ? k % static_cast<std::size_t>(cols) : 0) + " is " +
                   std::to_string(v[k]) + (std::isfinite(v[k]) ? ", beyond any robot" : ", not finite"));
    m.resize(rows, cols);
    for (Eigen::Index i = 0; i < rows; ++i)
        for (Eigen::Index j = 0; j < cols; ++j) m(i, j) = v[static_cast<std::size_t>(i * cols + j)];
}

// The weighting of a version 3 file (after its flag): what it was made from, then per pose a
// lower-triangular m x m whitening, finite (any scale: 1 / sigma of a sensor far below a micron
// is large, and the cost scales with it).
void read_whitening(io::Reader& r, ProblemData& p) {
    p.weighting = r.text("weighting", kMaxText);
    const Eigen::Index m = p.residuals_per_pose();
    get(r, "whitening", p.whitening, p.n_poses(), m * m, std::numeric_limits<double>::max());
    for (Eigen::Index k = 0; k < p.whitening.rows(); ++k)
        for (Eigen::Index i = 0; i < m; ++i)
            for (Eigen::Index j = i + 1; j < m; ++j)
                if (p.whitening(k, i * m + j) != 0.0)
                    r.fail("whitening: pose " + std::to_string(k) + ", entry (" + std::to_string(i) + ", " +
                           std::to_string(j) + ") is " + std::to_string(p.whitening(k, i * m + j)) +
                           "; the whitening of a pose must be lower triangular");
}

constexpr std::size_t kMaxEffects = 16, kMaxEffectKeys = 64, kMaxEffectNumbers = 64;

void write_effects(io::Writer& w, const ProblemData& p) {
    w.u64(p.effects.size());
    for (const EffectTable& t : p.effects) {
        w.str(t.name);
        w.u64(t.entries.size());
        for (const auto& [key, value] : t.entries) {
            w.str(key);
            w.u8(static_cast<std::uint8_t>(value.type));
            if (value.type == EffectValue::Type::Numbers) {
                w.doubles(value.numbers);
            } else if (value.numbers.size() != 1) {
                throw std::invalid_argument("effects." + t.name + "." + key + ": " +
                                            std::to_string(value.numbers.size()) + " values; expected one");
            } else if (value.type == EffectValue::Type::Bool) {
                w.u8(value.numbers[0] != 0 ? 1 : 0);
            } else {
                w.f64(value.numbers[0]);
            }
        }
    }
    w.u8(p.payload.size() ? 1 : 0);
    put(w, p.payload);
    w.u64(static_cast<std::uint64_t>(p.temperatures.cols()));
    put(w, p.temperatures);
    if (p.tracker() && !p.effects.empty()) put(w, p.tracker_gravity);
}

// The effects of a version 4 file and the payload and temperature columns (checked: the tables by
// EffectModel::parse, as Python's would be).
void read_effects(io::Reader& r, ProblemData& p) {
    const std::size_t ne = r.count("effects", 16);
    if (ne > kMaxEffects) r.fail("effects: " + std::to_string(ne) + "; at most " + std::to_string(kMaxEffects));
    for (std::size_t e = 0; e < ne; ++e) {
        EffectTable t;
        t.name = r.text("effect name", 64, false);
        const std::size_t nk = r.count("effect keys", 10);
        if (nk > kMaxEffectKeys) r.fail("effects." + t.name + ": " + std::to_string(nk) + " keys; at most " +
                                        std::to_string(kMaxEffectKeys));
        for (std::size_t k = 0; k < nk; ++k) {
            std::string key = r.text("effect key", 64, false);
            EffectValue v;
            const std::uint8_t type = r.u8("effect value type");
            if (type == 0) {
                v.type = EffectValue::Type::Bool;
                // One value by count, not `= {x}`: GCC 12 at -O2/-O3 warns on a one-element
                // initializer_list assigned to an empty vector (-Wnonnull, a false positive of
                // vector::_M_assign_aux's memmove; it fails the -DIWR_WERROR=ON Release build).
                v.numbers.assign(1, r.flag("effect flag") ? 1.0 : 0.0);
            } else if (type == 1) {
                v.type = EffectValue::Type::Number;
                v.numbers.assign(1, r.f64("effect number"));
            } else if (type == 2) {
                v.type = EffectValue::Type::Numbers;
                v.numbers = r.doubles("effect numbers");
                if (v.numbers.size() > kMaxEffectNumbers)
                    r.fail("effects." + t.name + "." + key + ": " + std::to_string(v.numbers.size()) +
                           " numbers; at most " + std::to_string(kMaxEffectNumbers));
            } else {
                r.fail("effects." + t.name + "." + key + ": value type " + std::to_string(type) +
                       "; expected 0 (true/false), 1 (a number) or 2 (numbers)");
            }
            t.entries.emplace_back(std::move(key), std::move(v));
        }
        p.effects.push_back(std::move(t));
    }
    try {
        (void)p.effect_model();
    } catch (const std::invalid_argument& e) {
        r.fail(e.what());
    }
    const Eigen::Index rows = p.n_poses();
    if (r.flag("has payload")) {
        get(r, "payload", p.payload, rows, 4);
        for (Eigen::Index k = 0; k < rows; ++k)
            if (!(p.payload(k, 0) >= 0)) r.fail("payload: row " + std::to_string(k) + " has a negative mass");
    } else {
        get(r, "payload", p.payload, 0, 0);
    }
    const std::uint64_t tc = r.u64("temperature columns");
    if (tc != 0 && tc != 1 && tc != 6)
        r.fail("temperature columns: " + std::to_string(tc) + "; expected 0 (none), 1 (per pose) or 6 (per leg)");
    get(r, "temperatures", p.temperatures, tc ? rows : 0, static_cast<Eigen::Index>(tc), 1e4);
    if (p.effect_model().thermal && tc == 0)
        r.fail("temperatures: the thermal effect is on and the file has no temperatures");
    if (p.effect_model().carriage_thermal && tc != 1)
        r.fail("temperatures: the carriage_thermal effect is on and the file has " +
               std::string(tc == 0 ? "no temperatures" : "one per leg") + "; it needs the machine's, one per pose");
    if (p.tracker() && ne) {
        // Tracker data: gravity in {T}, carried into {0} by the identified registration.
        get(r, "tracker gravity", p.tracker_gravity, 3, 1, 20.0);
        const double norm = p.tracker_gravity.norm();
        if (!(std::fabs(norm / 9.80665 - 1.0) <= 0.01))
            r.fail("tracker gravity: norm " + std::to_string(norm) + " m/s^2 in {T}; expected 9.80665 within 1 %");
    }
}

}  // namespace

Geometry ProblemData::geometry() const { return Geometry(joint_types, dh, base, platform, leg_offsets); }

int ProblemData::n_params() const {
    switch (kind) {
        case MeasurementKind::Points: return n_robot_params() + n_effect_params() + 6 + 3 * static_cast<int>(reflectors.rows());
        case MeasurementKind::Probe: return n_robot_params() + n_effect_params() + 12;
        case MeasurementKind::Ballbar: return n_robot_params() + n_effect_params() + kBarParams * static_cast<int>(bars.size());
        default: return n_robot_params() + n_effect_params();
    }
}

int ProblemData::residuals_per_pose() const {
    switch (kind) {
        case MeasurementKind::Points: return 3 * static_cast<int>(reflectors.rows());
        case MeasurementKind::Probe: return 12;
        case MeasurementKind::Ballbar: return 1;
        default: return kLegs;
    }
}

int ProblemData::n_active() const {
    return static_cast<int>(std::count(active.begin(), active.end(), true));
}

TrackerSetup ProblemData::tracker_setup() const {
    if (kind == MeasurementKind::Points) return TrackerSetup::points(registration, reflectors);
    if (kind == MeasurementKind::Probe) return TrackerSetup::probe(registration, probe, probe_length);
    throw std::invalid_argument("tracker setup: the measurements are poses in {0}, not tracker data");
}

std::uint64_t ProblemData::robot_fingerprint() const {
    io::Hash64 h;
    h.str("robot").str(joint_types);
    h.doubles(dh.data(), static_cast<std::size_t>(dh.size()));
    h.doubles(base.data(), 18).doubles(platform.data(), 18).doubles(leg_offsets.data(), 6);
    // Leg data searched over every parameter from zeros hash as version 1 did: their checkpoints
    // stay valid.
    if (tracker()) {
        h.str("tracker").u64(static_cast<std::uint64_t>(kind)).doubles(registration.data(), 6);
        h.doubles(reflectors.data(), static_cast<std::size_t>(reflectors.size()));
        h.doubles(probe.data(), 6).f64(probe_length);
        h.doubles(reference.data(), static_cast<std::size_t>(reference.size()));
    }
    if (ballbar()) hash_ballbar_setups(h, *this);
    // The weighting makes another objective of the same data (unweighted: hashed as before).
    if (weighted()) {
        h.str("whitening").u64(static_cast<std::uint64_t>(whitening.rows()))
            .u64(static_cast<std::uint64_t>(whitening.cols()));
        h.doubles(whitening.data(), static_cast<std::size_t>(whitening.size()));
    }
    // The effects make another objective of the same data (none: hashed as before).
    if (!effects.empty()) {
        h.str("effects").u64(effects.size());
        for (const EffectTable& t : effects) {
            h.str(t.name).u64(t.entries.size());
            for (const auto& [key, value] : t.entries)
                h.str(key).u64(static_cast<std::uint64_t>(value.type)).u64(value.numbers.size())
                    .doubles(value.numbers.data(), value.numbers.size());
        }
        if (tracker()) h.str("tracker gravity").doubles(tracker_gravity.data(), 3);
    }
    const bool plain = std::all_of(x0.begin(), x0.end(), [](double v) { return v == 0; }) &&
                       std::all_of(active.begin(), active.end(), [](bool a) { return a; });
    if (!plain) {
        h.str("search").doubles(x0.data(), x0.size()).u64(active.size());
        for (bool a : active) h.u64(a ? 1 : 0);
    }
    return h.value();
}

std::uint64_t ProblemData::data_fingerprint() const {
    io::Hash64 h;
    h.str("measurements").str(has_measurement_joint_types ? measurement_joint_types : joint_types);
    if (tracker()) h.str("tracker").u64(static_cast<std::uint64_t>(kind));
    for (const RowMatrixXd* a : {&q, &poses, &legs, &weights}) {
        h.u64(static_cast<std::uint64_t>(a->rows())).u64(static_cast<std::uint64_t>(a->cols()));
        h.doubles(a->data(), static_cast<std::size_t>(a->size()));
    }
    if (tracker())
        for (const RowMatrixXd* a : {&probe_poses, &points}) {
            h.u64(static_cast<std::uint64_t>(a->rows())).u64(static_cast<std::uint64_t>(a->cols()));
            h.doubles(a->data(), static_cast<std::size_t>(a->size()));
        }
    if (ballbar()) hash_ballbar_data(h, *this);
    // The loads and temperatures the effects read are data (none: hashed as before).
    if (payload.size() || temperatures.size())
        for (const RowMatrixXd* a : {&payload, &temperatures}) {
            h.str("loads").u64(static_cast<std::uint64_t>(a->rows())).u64(static_cast<std::uint64_t>(a->cols()));
            h.doubles(a->data(), static_cast<std::size_t>(a->size()));
        }
    return h.value();
}

std::string encode_problem(const ProblemData& p) {
    // What the reader could not tell from a misaligned file: counts the payload does not store.
    if (p.kind == MeasurementKind::Points && p.reflector_names.size() != static_cast<std::size_t>(p.reflectors.rows()))
        throw std::invalid_argument("reflector names: " + std::to_string(p.reflector_names.size()) + "; expected " +
                                    std::to_string(p.reflectors.rows()));
    if (p.active.size() != p.x0.size())
        throw std::invalid_argument("active: " + std::to_string(p.active.size()) + " flags; expected " +
                                    std::to_string(p.x0.size()));
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
    w.u8(static_cast<std::uint8_t>(p.kind));
    w.u64(static_cast<std::uint64_t>(p.legs.rows()));
    put(w, p.q);
    put(w, p.legs);
    if (p.ballbar()) {
        write_ballbar_section(w, p);
    } else if (!p.tracker()) {
        put(w, p.poses);
        w.u8(p.weights.size() ? 1 : 0);
        put(w, p.weights);
    } else {
        put(w, p.registration);
        if (p.kind == MeasurementKind::Points) {
            w.u64(static_cast<std::uint64_t>(p.reflectors.rows()));
            put(w, p.reflectors);
            for (const auto& n : p.reflector_names) w.str(n);
        } else {
            put(w, p.probe);
            w.f64(p.probe_length);
            put(w, p.probe_poses);
        }
        put(w, p.points);
        put(w, p.reference);
    }
    w.u8(p.weighted() ? 1 : 0);
    if (p.weighted()) {
        w.str(p.weighting);
        put(w, p.whitening);
    }
    write_effects(w, p);
    w.doubles(p.lower);
    w.doubles(p.upper);
    w.str(p.bounds_kind);
    w.doubles(p.x0);
    w.u64(p.active.size());
    for (bool a : p.active) w.u8(a ? 1 : 0);
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
    ProblemData p;
    const std::string payload = io::unseal(bytes, kMagic, kOldestProblemVersion, kProblemVersion, &p.version,
                                           context, "an iwr problem file");
    io::Reader r(payload.data(), payload.size(), context);
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
    const std::uint8_t kind = r.u8("measurement kind");
    if (kind > 3 || (kind == 3 && p.version < 4))
        r.fail("measurement kind: " + std::to_string(kind) + "; expected 0 (pose in {0}), 1 (points in {T}), 2 (probe pose in {T}) or, from version 4, 3 (ballbar distances)");
    p.kind = static_cast<MeasurementKind>(kind);
    const std::uint64_t N = r.u64("number of poses");
    // Each pose takes at least 12 (6 + 6) doubles below (8 for ballbar data: 6 legs, a set-up
    // index and a distance): a count the file cannot hold is refused before anything is allocated.
    if (N == 0) r.fail("number of poses: 0; a problem needs measurements");
    if (N > kMaxPoses || N > r.remaining() / ((p.ballbar() ? 8 : 12) * 8))
        r.fail("truncated or corrupt: number of poses " + std::to_string(N) + " does not fit in the " +
               std::to_string(r.remaining()) + " bytes left");
    const Eigen::Index rows = static_cast<Eigen::Index>(N);
    get(r, "q", p.q, rows, n);
    get(r, "legs", p.legs, rows, 6);
    if (p.ballbar()) {
        p.poses.resize(0, 6);
        read_ballbar_section(r, p);
    } else if (!p.tracker()) {
        get(r, "poses", p.poses, rows, 6);
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
    } else {
        p.poses.resize(0, 6);
        get(r, "registration", p.registration, 6, 1);
        Eigen::Index cols = 12;
        if (p.kind == MeasurementKind::Points) {
            const std::uint64_t k = r.u64("number of reflectors");
            // Each reflector takes 3 doubles and a name (8 bytes at least).
            if (k == 0) r.fail("number of reflectors: 0; point data need at least one reflector");
            if (k > r.remaining() / (4 * 8))
                r.fail("truncated or corrupt: number of reflectors " + std::to_string(k) +
                       " does not fit in the " + std::to_string(r.remaining()) + " bytes left");
            get(r, "reflectors", p.reflectors, static_cast<Eigen::Index>(k), 3);
            for (std::uint64_t i = 0; i < k; ++i) {
                p.reflector_names.push_back(r.text("reflector name", kMaxText, false));
                for (std::uint64_t j = 0; j < i; ++j)
                    if (p.reflector_names[j] == p.reflector_names.back())
                        r.fail("reflector name: '" + p.reflector_names.back() + "' given twice");
            }
            cols = 3 * static_cast<Eigen::Index>(k);
            get(r, "points", p.points, rows, cols, 1e12, true);
            bool any = false;
            for (Eigen::Index i = 0; i < rows; ++i)
                for (Eigen::Index c = 0; c < cols; c += 3) {
                    const int nan = std::isnan(p.points(i, c)) + std::isnan(p.points(i, c + 1)) +
                                    std::isnan(p.points(i, c + 2));
                    if (nan != 0 && nan != 3)
                        r.fail("points: row " + std::to_string(i) + ", reflector " + std::to_string(c / 3 + 1) +
                               " has some coordinates NaN and some not; a reflector not seen has all three NaN");
                    any = any || nan == 0;
                }
            if (!any) r.fail("points: no reflector is seen at any pose");
        } else {
            get(r, "probe", p.probe, 6, 1);
            p.probe_length = r.f64("probe length");
            if (!(std::isfinite(p.probe_length) && p.probe_length > 0 && p.probe_length <= 1e12))
                r.fail("probe length: " + std::to_string(p.probe_length) + "; expected a finite length > 0 (mm)");
            get(r, "probe poses", p.probe_poses, rows, 6);
            get(r, "points", p.points, rows, cols);
        }
        get(r, "reference", p.reference, p.n_robot_params(), 1);
    }
    if (p.version >= 3 && r.flag("weighted")) read_whitening(r, p);
    if (p.version >= 4) read_effects(r, p);
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
    p.x0 = r.doubles("x0", np);
    for (std::size_t j = 0; j < np; ++j)
        if (!(std::fabs(p.x0[j]) <= 1e12))
            r.fail("x0: parameter " + std::to_string(j) + " is " + std::to_string(p.x0[j]) +
                   (std::isfinite(p.x0[j]) ? ", beyond any robot" : ", not finite"));
    const std::uint64_t na = r.u64("number of active flags");
    if (na != np) r.fail("active: " + std::to_string(na) + " flags; expected " + std::to_string(np));
    for (std::size_t j = 0; j < np; ++j) p.active.push_back(r.flag("active flag"));
    if (p.n_active() == 0) r.fail("active: no parameter is active");
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
    if (p.tracker()) {
        try {
            (void)p.tracker_setup();
        } catch (const std::invalid_argument& e) {
            r.fail(std::string("tracker setup: ") + e.what());
        }
    }
    return p;
}

ProblemData read_problem(const std::string& path) {
    return decode_problem(io::read_file(path, "an iwr problem file", kMaxFile), path + ": ");
}

}  // namespace iwr
