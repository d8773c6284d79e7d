// The leg objective with the non-geometric effects (see iwr/effects.hpp): the effects' tables and
// the per-pose statics and thermal growth, for one parameter vector at a time (cost_batch runs the
// rows of a population across the pool's threads).
#include "iwr/effects.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "effects_kernel.hpp"  // the pieces shared with the tracker objective with effects

namespace iwr {

namespace {

constexpr double kStandardGravity = 9.80665;  // m/s^2, as iwr/effects/builtin.py
using detail::kMaxChainJoints;

[[noreturn]] void bad(const std::string& where, const std::string& what) {
    throw std::invalid_argument(where + ": " + what);
}

std::string number_text(double v) {
    std::ostringstream s;
    s.precision(17);
    s << v;
    return s.str();
}

// The keys of one table, checked: each known, each at most once, the required ones present.
class Keys {
public:
    Keys(const EffectTable& t, std::vector<std::string> known)
        : where_("effects." + t.name), table_(t), known_(std::move(known)) {
        for (std::size_t i = 0; i < t.entries.size(); ++i) {
            const std::string& key = t.entries[i].first;
            if (std::find(known_.begin(), known_.end(), key) == known_.end()) {
                std::string list;
                for (const auto& k : known_) list += (list.empty() ? "" : ", ") + k;
                bad(where_ + "." + key, "unknown key; allowed: " + list);
            }
            for (std::size_t j = 0; j < i; ++j)
                if (t.entries[j].first == key) bad(where_ + "." + key, "given twice");
        }
    }
    bool has(const std::string& key) const {
        for (const auto& e : table_.entries)
            if (e.first == key) return true;
        return false;
    }
    const EffectValue& get(const std::string& key) const {
        for (const auto& e : table_.entries)
            if (e.first == key) return e.second;
        bad(where_ + "." + key, "missing key");
    }
    bool flag(const std::string& key) const {
        const EffectValue& v = get(key);
        if (v.type != EffectValue::Type::Bool || v.numbers.size() != 1 ||
            (v.numbers[0] != 0 && v.numbers[0] != 1))
            bad(where_ + "." + key, "expected true or false");
        return v.numbers[0] != 0;
    }
    // One number within [lo, hi].
    double number(const std::string& key, double lo, double hi, const char* unit) const {
        const EffectValue& v = get(key);
        if (v.type != EffectValue::Type::Number || v.numbers.size() != 1)
            bad(where_ + "." + key, std::string("expected a number (") + unit + ")");
        check(key, v.numbers[0], lo, hi, unit);
        return v.numbers[0];
    }
    // n numbers: an array of n, or (broadcast) one number; each within [lo, hi].
    std::vector<double> numbers(const std::string& key, std::size_t n, double lo, double hi,
                                const char* unit, bool broadcast) const {
        const EffectValue& v = get(key);
        std::vector<double> out;
        if (v.type == EffectValue::Type::Numbers && v.numbers.size() == n) {
            out = v.numbers;
        } else if (broadcast && v.type == EffectValue::Type::Number && v.numbers.size() == 1) {
            out.assign(n, v.numbers[0]);
        } else {
            bad(where_ + "." + key, std::to_string(v.numbers.size()) +
                                        (v.type == EffectValue::Type::Bool ? " boolean" : " number(s)") +
                                        "; expected " + std::to_string(n) + " numbers (" + unit + ")");
        }
        for (std::size_t i = 0; i < out.size(); ++i) check(key + "[" + std::to_string(i) + "]", out[i], lo, hi, unit);
        return out;
    }
    // Distinct joint numbers from 1 to n_joints (an array, or one number), returned from 0; what:
    // the joints expected, for the message ("joint numbers", "prismatic joint numbers").
    std::vector<int> joints(const std::string& key, int n_joints, const char* what) const {
        const EffectValue& v = get(key);
        if (v.type == EffectValue::Type::Bool || v.numbers.empty())
            bad(where_ + "." + key, std::string("expected ") + what + " from 1");
        std::vector<int> out;
        for (std::size_t i = 0; i < v.numbers.size(); ++i) {
            const double j = v.numbers[i];
            if (!(j >= 1 && j <= n_joints && j == std::floor(j)))
                bad(where_ + "." + key + "[" + std::to_string(i) + "]",
                    number_text(j) + "; expected a joint number from 1 to " + std::to_string(n_joints));
            for (std::size_t u = 0; u < i; ++u)
                if (v.numbers[u] == j) bad(where_ + "." + key, "joint " + number_text(j) + " given twice");
            out.push_back(static_cast<int>(j) - 1);
        }
        return out;
    }
    const std::string& where() const { return where_; }

private:
    void check(const std::string& key, double v, double lo, double hi, const char* unit) const {
        if (!(v >= lo && v <= hi))
            bad(where_ + "." + key, number_text(v) + " " + unit + "; expected " + number_text(lo) +
                                        " <= value <= " + number_text(hi));
    }
    std::string where_;
    const EffectTable& table_;
    std::vector<std::string> known_;
};

void require_rows(const RowMatrixXd& m, Eigen::Index rows, std::initializer_list<Eigen::Index> cols,
                  const char* what) {
    bool ok = m.rows() == rows;
    if (ok) ok = std::find(cols.begin(), cols.end(), m.cols()) != cols.end();
    if (!ok) {
        std::ostringstream msg;
        msg << what << ": shape (" << m.rows() << ", " << m.cols() << "); expected (" << rows << ", ";
        bool first = true;
        for (Eigen::Index c : cols) msg << (first ? "" : " or ") << c, first = false;
        msg << ")";
        throw std::invalid_argument(msg.str());
    }
}

}  // namespace

namespace detail {

LegEffects leg_effects(const EffectModel& m, const double* x) {
    LegEffects le;
    for (int j = 0; j < kLegs; ++j) {
        le.c[j] = m.compliance ? (m.compliance_values[j] + x[m.compliance_index + (m.compliance_per_leg ? j : 0)]) * 1e-3
                               : 0.0;
        le.alpha[j] = m.alpha_values[j];
        if (m.thermal_index >= 0) le.alpha[j] += x[m.thermal_index + (m.thermal_per_leg ? j : 0)];
        le.alpha[j] *= 1e-6;
    }
    return le;
}

void check_loads(const EffectModel& m, int n, const RowMatrixXd& payload, const RowMatrixXd& temperatures) {
    if (payload.size() != 0) {
        require_rows(payload, n, {4}, "payload");
        require_finite(payload.data(), payload.size(), "payload");
        for (int k = 0; k < n; ++k)
            if (payload(k, 0) < 0)
                throw std::invalid_argument("payload: pose " + std::to_string(k) + " has mass " +
                                            number_text(payload(k, 0)) + " kg; expected >= 0");
    }
    if (temperatures.size() != 0) {
        require_rows(temperatures, n, {1, kLegs}, "temperatures");
        require_finite(temperatures.data(), temperatures.size(), "temperatures");
    } else if (m.thermal) {
        throw std::invalid_argument(
            "temperatures: the thermal effect (the legs' thermal expansion) needs each pose's "
            "temperature: one per pose or one per leg, degrees C");
    }
    if (m.carriage_thermal && temperatures.cols() != 1)
        throw std::invalid_argument(
            "temperatures: the carriage_thermal effect (the thermal expansion of the carriage's "
            "prismatic axes) needs the machine's temperature at each pose (one column, T_C); the "
            "data have " + std::string(temperatures.size() == 0 ? "none" : "one per leg"));
}

void check_carriage_thermal(const EffectModel& m, const Geometry& g) {
    const int nj = g.n_joints();
    if (nj > kMaxChainJoints)
        throw std::invalid_argument("effects.carriage_thermal: the robot has " + std::to_string(nj) +
                                    " joints; at most " + std::to_string(kMaxChainJoints));
    for (std::size_t u = 0; u < m.ct_joints.size(); ++u) {
        const int jt = m.ct_joints[u];
        const std::string where = "effects.carriage_thermal.joints[" + std::to_string(u) + "]: joint " +
                                  std::to_string(jt + 1);
        if (jt >= nj) throw std::invalid_argument(where + "; the robot has " + std::to_string(nj) + " joints");
        if (!g.is_prismatic(jt))
            throw std::invalid_argument(where + " is revolute; the thermal expansion of a scale applies "
                                                "to prismatic joints only");
    }
}

void carriage_alphas(const EffectModel& m, int n_joints, const double* x, double* out) {
    for (int i = 0; i < n_joints; ++i) out[i] = 0.0;
    for (std::size_t u = 0; u < m.ct_joints.size(); ++u) {
        double a = m.ct_values[u];
        if (m.ct_index >= 0) a += x[m.ct_index + (m.ct_per_joint ? static_cast<int>(u) : 0)];
        out[m.ct_joints[u]] = 1e-6 * a;
    }
}

void carriage_chain(const PoseData& layout, const EvalConsts& ec, const double* d, const double* delta,
                    double* t, double* axes, double* origins) {
    const int nj = layout.n_joints, n_prefix = layout.n_prefix;
    for (int e = 0; e < 9; ++e) t[e] = ec.rc[e];
    for (int e = 0; e < 3; ++e) t[9 + e] = ec.pc[e];
    for (int i = 0; i < n_prefix; ++i) {
        double qi = d[layout.q_off[i]];
        if (delta) qi += delta[i];
        if (axes)  // a prefix joint is prismatic: its axis is all its load needs
            for (int e = 0; e < 3; ++e) axes[3 * i + e] = ec.z[3 * i + e], origins[3 * i + e] = t[9 + e];
        for (int e = 0; e < 3; ++e) t[9 + e] += qi * ec.z[3 * i + e];
    }
    for (int i = n_prefix; i < nj; ++i) {
        const double* jc = ec.joint + 6 * i;
        const double* qd = d + layout.q_off[i];
        double cs, sn, dk = jc[5];
        if (layout.prismatic[i]) {
            cs = jc[2], sn = jc[3], dk = jc[5] + qd[0];
            if (delta) dk += delta[i];
        } else {
            double cq = qd[0], sq = qd[1];
            if (delta && delta[i] != 0.0) {  // cos, sin of q + delta (0: the same bits, skipped)
                const double cd = std::cos(delta[i]), sd = std::sin(delta[i]);
                const double c0 = cq;
                cq = c0 * cd - sq * sd, sq = sq * cd + c0 * sd;
            }
            cs = jc[2] * cq - jc[3] * sq, sn = jc[3] * cq + jc[2] * sq;
        }
        if (axes)
            for (int e = 0; e < 3; ++e) axes[3 * i + e] = t[3 * e + 2], origins[3 * i + e] = t[9 + e];
        for (int r = 0; r < 3; ++r) {
            const double t0 = t[3 * r], t1 = t[3 * r + 1], w = t[3 * r + 2];
            const double u = t0 * cs + t1 * sn, v = t1 * cs - t0 * sn;
            t[3 * r] = u;
            t[3 * r + 1] = jc[0] * v + jc[1] * w;
            t[3 * r + 2] = jc[0] * w - jc[1] * v;
            t[9 + r] += jc[4] * u + dk * w;
        }
    }
}

std::vector<double> carriage_scales(const EffectModel& m, const Geometry& g) {
    const int nj = g.n_joints();
    if (nj > kMaxChainJoints)
        throw std::invalid_argument("effects.carriage_compliance: the robot has " + std::to_string(nj) +
                                    " joints; at most " + std::to_string(kMaxChainJoints));
    std::vector<double> scale(static_cast<std::size_t>(nj), 0.0);
    for (int jt : m.carriage_joints) {
        if (jt >= nj)
            throw std::invalid_argument("effects.carriage_compliance.joints: joint " + std::to_string(jt + 1) +
                                        "; the robot has " + std::to_string(nj) + " joints");
        scale[static_cast<std::size_t>(jt)] = g.is_prismatic(jt) ? 1e-3 : 1e-9;
    }
    return scale;
}

void carriage_compliances(const EffectModel& m, const std::vector<double>& scale, const double* x, double* out) {
    for (std::size_t i = 0; i < scale.size(); ++i) out[i] = 0.0;
    for (std::size_t u = 0; u < m.carriage_joints.size(); ++u) {
        const int i = m.carriage_joints[u];
        out[i] = (m.carriage_values[u] + x[m.carriage_index + static_cast<int>(u)]) * scale[static_cast<std::size_t>(i)];
    }
}

void hexapod_centre(const EffectModel& m, const EvalConsts& ec, double* out) {
    Vec3 a[kLegs], centre = Vec3::Zero(), n = Vec3::Zero();
    for (int j = 0; j < kLegs; ++j) a[j] = Vec3(ec.a[j][0], ec.a[j][1], ec.a[j][2]), centre += a[j];
    centre /= kLegs;
    for (int j = 0; j < kLegs; ++j) n += a[j].cross(a[(j + 1) % kLegs]);
    const Vec3 z = n / n.norm();
    const Vec3 mid = 0.5 * (a[0] + a[1]) - centre;
    const Vec3 xs = mid - mid.dot(z) * z;
    const Vec3 x = xs / xs.norm();
    const Vec3 y = z.cross(x);
    const Vec3& c = m.hexapod_centre;
    const Vec3 p = centre + c(0) * x + c(1) * y + c(2) * z;
    for (int e = 0; e < 3; ++e) out[e] = p(e);
}

void carriage_deflection(const EffectModel& m, const PoseData& layout, const double* axes, const double* origins,
                         const double* t, const double* ch, const double* first, double mass_carried, const Vec3& g,
                         const double* ccomp, double* delta) {
    const double mh = m.hexapod_mass, mass = mh + mass_carried;
    double p[3];
    for (int e = 0; e < 3; ++e)
        p[e] = mh * (t[3 * e] * ch[0] + t[3 * e + 1] * ch[1] + t[3 * e + 2] * ch[2] + t[9 + e]) + first[e];
    for (int i = 0; i < layout.n_joints; ++i) {
        const double* z = axes + 3 * i;
        double load;
        if (layout.prismatic[i]) {
            load = mass * (g(0) * z[0] + g(1) * z[1] + g(2) * z[2]);
        } else {  // (P - M o) . (g x z)
            const double* o = origins + 3 * i;
            const double gz[3] = {g(1) * z[2] - g(2) * z[1], g(2) * z[0] - g(0) * z[2], g(0) * z[1] - g(1) * z[0]};
            load = (p[0] - mass * o[0]) * gz[0] + (p[1] - mass * o[1]) * gz[1] + (p[2] - mass * o[2]) * gz[2];
        }
        delta[i] = ccomp[i] * load;
    }
}

bool statics_factor(const double (&u)[kLegs][3], const double (&r)[kLegs][3], Statics& st) {
    double* a = st.a;
    double radius = 0;  // the largest |r_j| (its square first)
    for (int j = 0; j < kLegs; ++j) {
        a[j] = u[j][0], a[6 + j] = u[j][1], a[12 + j] = u[j][2];
        a[18 + j] = r[j][1] * u[j][2] - r[j][2] * u[j][1];
        a[24 + j] = r[j][2] * u[j][0] - r[j][0] * u[j][2];
        a[30 + j] = r[j][0] * u[j][1] - r[j][1] * u[j][0];
        radius = std::max(radius, r[j][0] * r[j][0] + r[j][1] * r[j][1] + r[j][2] * r[j][2]);
    }
    radius = std::sqrt(radius);
    st.s = radius > 0 ? 1.0 / radius : 1.0;
    for (int e = 18; e < 36; ++e) a[e] *= st.s;
    // Elimination with partial pivoting; a swap moves the columns from the pivot's on (the
    // multipliers of earlier steps stay where they were made: statics_forces replays the steps).
    constexpr double tiny = 1e-12;
    for (int c = 0; c < 6; ++c) {
        int p = c;
        for (int rr = c + 1; rr < 6; ++rr)
            if (std::fabs(a[6 * rr + c]) > std::fabs(a[6 * p + c])) p = rr;
        if (!(std::fabs(a[6 * p + c]) > tiny)) return false;
        st.piv[c] = p;
        if (p != c)
            for (int k = c; k < 6; ++k) std::swap(a[6 * c + k], a[6 * p + k]);
        st.inv[c] = 1.0 / a[6 * c + c];
        for (int rr = c + 1; rr < 6; ++rr) {
            const double m = a[6 * rr + c] * st.inv[c];
            for (int k = c + 1; k < 6; ++k) a[6 * rr + k] -= m * a[6 * c + k];
            a[6 * rr + c] = m;
        }
    }
    return true;
}

void statics_forces(const Statics& st, double (&w)[6]) {
    const double* a = st.a;
    for (int e = 3; e < 6; ++e) w[e] *= st.s;
    for (int c = 0; c < 6; ++c) {
        if (st.piv[c] != c) std::swap(w[c], w[st.piv[c]]);
        for (int rr = c + 1; rr < 6; ++rr) w[rr] -= a[6 * rr + c] * w[c];
    }
    for (int rr = 5; rr >= 0; --rr) {
        double s = w[rr];
        for (int k = rr + 1; k < 6; ++k) s -= a[6 * rr + k] * w[k];
        w[rr] = s * st.inv[rr];
    }
}

void statics_transposed(const Statics& st, double (&b)[6]) {
    // S G = M_0^-1 P_0 ... (the steps) U, so (S G)^T y = b is U^T z = b, then the steps' transposes
    // in reverse; G^T x = b has x = S y (S scales the moment rows).
    const double* a = st.a;
    for (int rr = 0; rr < 6; ++rr) {
        double s = b[rr];
        for (int k = 0; k < rr; ++k) s -= a[6 * k + rr] * b[k];
        b[rr] = s * st.inv[rr];
    }
    for (int c = 5; c >= 0; --c) {
        double s = b[c];
        for (int rr = c + 1; rr < 6; ++rr) s -= a[6 * rr + c] * b[rr];
        b[c] = s;
        if (st.piv[c] != c) std::swap(b[c], b[st.piv[c]]);
    }
    for (int e = 3; e < 6; ++e) b[e] *= st.s;
}

}  // namespace detail

EffectModel EffectModel::parse(const std::vector<EffectTable>& tables, int n_geometric) {
    EffectModel m;
    m.n_geometric = n_geometric;
    int next = n_geometric;
    for (std::size_t t = 0; t < tables.size(); ++t) {
        const EffectTable& table = tables[t];
        for (std::size_t u = 0; u < t; ++u)
            if (tables[u].name == table.name) bad("effects." + table.name, "given twice");
        if (table.name == "compliance") {
            const Keys k(table, {"per_leg", "compliance_um_per_N", "max_um_per_N", "gravity_m_s2",
                                 "platform_mass_kg", "platform_centre_mm"});
            m.compliance = true;
            m.compliance_per_leg = k.flag("per_leg");
            const std::size_t n = m.compliance_per_leg ? 6 : 1;
            const std::vector<double> c = k.numbers("compliance_um_per_N", n, -10, 10, "um/N", true);
            for (int j = 0; j < 6; ++j) m.compliance_values[j] = c[m.compliance_per_leg ? static_cast<std::size_t>(j) : 0];
            (void)k.number("max_um_per_N", 1e-6, 10, "um/N");  // Python's bounds: kept for the round trip
            m.platform_mass = k.number("platform_mass_kg", 0, 1e6, "kg");
            const std::vector<double> pc = k.numbers("platform_centre_mm", 3, -1e5, 1e5, "mm in {5}", false);
            const std::vector<double> g = k.numbers("gravity_m_s2", 3, -20, 20, "m/s^2 in {0}", false);
            m.platform_centre = Vec3(pc[0], pc[1], pc[2]);
            m.gravity = Vec3(g[0], g[1], g[2]);
            if (!(std::fabs(m.gravity.norm() / kStandardGravity - 1.0) <= 0.01))
                bad(k.where() + ".gravity_m_s2", "norm " + number_text(m.gravity.norm()) +
                                                     " m/s^2; expected 9.80665 within 1 %");
            m.compliance_index = next;
            next += static_cast<int>(n);
        } else if (table.name == "thermal") {
            const Keys k(table, {"alpha_ppm_per_K", "reference_C", "identify", "per_leg", "max_ppm_per_K"});
            m.thermal = true;
            m.thermal_per_leg = k.flag("per_leg");
            const bool identify = k.flag("identify");
            const std::size_t n = m.thermal_per_leg ? 6 : 1;
            const std::vector<double> a = k.numbers("alpha_ppm_per_K", n, -1000, 1000, "ppm/K", true);
            for (int j = 0; j < 6; ++j) m.alpha_values[j] = a[m.thermal_per_leg ? static_cast<std::size_t>(j) : 0];
            m.reference = k.number("reference_C", -50, 150, "degrees C");
            (void)k.number("max_ppm_per_K", 1e-3, 1000, "ppm/K");  // as max_um_per_N
            if (identify) {
                m.thermal_index = next;
                next += static_cast<int>(n);
            }
        } else if (table.name == "carriage_compliance") {
            const Keys k(table, {"joints", "compliance", "max_urad_per_Nm", "max_um_per_N", "gravity_m_s2",
                                 "hexapod_mass_kg", "hexapod_centre_mm", "platform_mass_kg",
                                 "platform_centre_mm"});
            m.carriage = true;
            const int nj = (n_geometric - 42) / 4;
            if (k.has("joints")) {
                m.carriage_joints = k.joints("joints", nj, "joint numbers");
            } else {
                for (int j = 0; j < nj; ++j) m.carriage_joints.push_back(j);
            }
            const std::size_t n = m.carriage_joints.size();
            m.carriage_values = k.numbers("compliance", n, -1e3, 1e3, "urad/(N m) or um/N", true);
            (void)k.number("max_urad_per_Nm", 1e-9, 1e3, "urad/(N m)");  // as max_um_per_N above
            (void)k.number("max_um_per_N", 1e-9, 10, "um/N");
            m.hexapod_mass = k.number("hexapod_mass_kg", 0, 1e6, "kg");
            const std::vector<double> hc = k.numbers("hexapod_centre_mm", 3, -1e5, 1e5, "mm in {4}", false);
            m.hexapod_centre = Vec3(hc[0], hc[1], hc[2]);
            m.carriage_platform_mass = k.number("platform_mass_kg", 0, 1e6, "kg");
            const std::vector<double> pc = k.numbers("platform_centre_mm", 3, -1e5, 1e5, "mm in {5}", false);
            m.carriage_platform_centre = Vec3(pc[0], pc[1], pc[2]);
            const std::vector<double> g = k.numbers("gravity_m_s2", 3, -20, 20, "m/s^2 in {0}", false);
            m.carriage_gravity = Vec3(g[0], g[1], g[2]);
            if (!(std::fabs(m.carriage_gravity.norm() / kStandardGravity - 1.0) <= 0.01))
                bad(k.where() + ".gravity_m_s2", "norm " + number_text(m.carriage_gravity.norm()) +
                                                     " m/s^2; expected 9.80665 within 1 %");
            m.carriage_index = next;
            next += static_cast<int>(n);
        } else if (table.name == "carriage_thermal") {
            const Keys k(table, {"joints", "alpha_ppm_per_K", "reference_C", "identify", "per_joint",
                                 "max_ppm_per_K"});
            m.carriage_thermal = true;
            const int nj = (n_geometric - 42) / 4;
            // Python writes the joints it resolved (default: every prismatic joint).
            m.ct_joints = k.joints("joints", nj, "prismatic joint numbers");
            m.ct_per_joint = k.flag("per_joint");
            const bool identify = k.flag("identify");
            const std::size_t n = m.ct_per_joint ? m.ct_joints.size() : 1;
            const std::vector<double> a = k.numbers("alpha_ppm_per_K", n, -1000, 1000, "ppm/K", true);
            for (std::size_t u = 0; u < m.ct_joints.size(); ++u) m.ct_values.push_back(a[m.ct_per_joint ? u : 0]);
            m.ct_reference = k.number("reference_C", -50, 150, "degrees C");
            (void)k.number("max_ppm_per_K", 1e-3, 1000, "ppm/K");  // as the thermal effect's
            if (identify) {
                m.ct_index = next;
                next += static_cast<int>(n);
            }
        } else {
            bad("effects." + table.name,
                "no model of this effect in the C++ core; known: compliance, thermal, carriage_compliance, "
                "carriage_thermal");
        }
    }
    if (m.compliance && m.carriage &&
        (m.gravity != m.carriage_gravity || m.platform_mass != m.carriage_platform_mass ||
         m.platform_centre != m.carriage_platform_centre))
        bad("effects.carriage_compliance",
            "its gravity and platform differ from effects.compliance's: the effects of the load must "
            "describe the same gravity and platform");
    m.n_params = next - n_geometric;
    return m;
}

EffectObjective::EffectObjective(Geometry geometry, EffectModel effects, const RowMatrixXd& q,
                                 const RowMatrixXd& poses, const RowMatrixXd& legs,
                                 const RowMatrixXd& payload, const RowMatrixXd& temperatures,
                                 const RowMatrixXd& weights, const RowMatrixXd& whitening)
    : geometry_(std::move(geometry)), effects_(effects), n_(static_cast<int>(poses.rows())) {
    const int nj = geometry_.n_joints();
    if (effects_.n_geometric != geometry_.n_params())
        throw std::invalid_argument("effects: parsed for " + std::to_string(effects_.n_geometric) +
                                    " geometric parameters; the robot has " +
                                    std::to_string(geometry_.n_params()));
    if (n_ == 0) throw std::invalid_argument("poses: no measurements (0 rows)");
    require_rows(poses, n_, {6}, "poses");
    require_rows(q, n_, {nj}, "q");
    require_rows(legs, n_, {kLegs}, "legs");
    require_finite(q.data(), q.size(), "q");
    require_finite(poses.data(), poses.size(), "poses");
    require_finite(legs.data(), legs.size(), "legs");
    detail::check_loads(effects_, n_, payload, temperatures);
    if (weights.size() != 0) {
        require_rows(weights, n_, {kLegs}, "weights");
        require_finite(weights.data(), weights.size(), "weights");
        for (Eigen::Index i = 0; i < weights.size(); ++i)
            if (weights.data()[i] < 0)
                throw std::invalid_argument("weights: entry " + std::to_string(i) + " is " +
                                            number_text(weights.data()[i]) + "; weights must be >= 0");
    }
    if (whitening.size() != 0) {
        if (weights.size() != 0)
            throw std::invalid_argument(
                "weights, whitening: give one or the other (fold the weights into the whitening)");
        require_rows(whitening, n_, {kLegs * kLegs}, "whitening");
        require_finite(whitening.data(), whitening.size(), "whitening");
        for (int k = 0; k < n_; ++k)
            for (int i = 0; i < kLegs; ++i)
                for (int j = i + 1; j < kLegs; ++j)
                    if (whitening(k, kLegs * i + j) != 0.0)
                        throw std::invalid_argument(
                            "whitening: pose " + std::to_string(k) + ", entry (" + std::to_string(i) +
                            ", " + std::to_string(j) + ") is not 0; the whitening of a pose must be "
                            "lower triangular");
        whitened_ = true;
    }
    int nq = 30;  // 0R5 9, 0P5 3, readings 6, wrench 6, T - T_ref 6
    if (weights.size() != 0) off_w_ = nq, nq += kLegs;
    if (effects_.carriage) {
        off_cc_ = nq, nq += 4;
        cc_scale_ = detail::carriage_scales(effects_, geometry_);
    }
    if (effects_.carriage_thermal) {
        off_ct_ = nq, nq += 1;
        detail::check_carriage_thermal(effects_, geometry_);
    }
    if (whitened_) off_wh_ = nq, nq += kLegs * (kLegs + 1) / 2;
    for (int i = 0; i < nj; ++i) {
        q_off_.push_back(nq);
        prismatic_.push_back(geometry_.is_prismatic(i) ? 1 : 0);
        nq += geometry_.is_prismatic(i) ? 1 : 2;
    }
    stride_ = nq;
    carriage_ = detail::CarriageNominal(geometry_);
    data_.assign(static_cast<std::size_t>(n_) * static_cast<std::size_t>(stride_), 0.0);
    for (int k = 0; k < n_; ++k) {
        double* d = data_.data() + static_cast<std::size_t>(k) * static_cast<std::size_t>(stride_);
        const Mat3 r = euler_zyx(poses(k, 3), poses(k, 4), poses(k, 5));
        for (int e = 0; e < 9; ++e) d[e] = r(e / 3, e % 3);
        for (int e = 0; e < 3; ++e) d[9 + e] = poses(k, e);
        for (int j = 0; j < kLegs; ++j) d[12 + j] = legs(k, j);
        if (effects_.compliance) {
            // The gravity wrench about the platform origin, in {0}: the platform, then the payload
            // (the order of iwr.effects.model.leg_forces).
            const Vec3 g = effects_.gravity;
            Vec3 force = effects_.platform_mass * g;
            Vec3 moment = (r * effects_.platform_centre).cross(Vec3(effects_.platform_mass * g));
            if (payload.size() != 0) {
                const Vec3 wp = payload(k, 0) * g;
                force += wp;
                moment += (r * Vec3(payload(k, 1), payload(k, 2), payload(k, 3))).cross(wp);
            }
            for (int e = 0; e < 3; ++e) d[18 + e] = force(e), d[21 + e] = moment(e);
        }
        if (effects_.carriage) {
            // The first moment (kg mm, in {0}) and the mass of the platform and the payload.
            double mass = effects_.carriage_platform_mass;
            Vec3 first = mass * (r * effects_.carriage_platform_centre + Vec3(poses(k, 0), poses(k, 1), poses(k, 2)));
            if (payload.size() != 0) {
                first += payload(k, 0) * (r * Vec3(payload(k, 1), payload(k, 2), payload(k, 3)) +
                                          Vec3(poses(k, 0), poses(k, 1), poses(k, 2)));
                mass += payload(k, 0);
            }
            for (int e = 0; e < 3; ++e) d[off_cc_ + e] = first(e);
            d[off_cc_ + 3] = mass;
        }
        if (effects_.thermal)
            for (int j = 0; j < kLegs; ++j)
                d[24 + j] = temperatures(k, temperatures.cols() == 1 ? 0 : j) - effects_.reference;
        if (off_ct_ >= 0) d[off_ct_] = temperatures(k, 0) - effects_.ct_reference;
        if (off_w_ >= 0)
            for (int j = 0; j < kLegs; ++j) d[off_w_ + j] = std::sqrt(weights(k, j));
        if (off_wh_ >= 0) {
            int e = off_wh_;
            for (int i = 0; i < kLegs; ++i)
                for (int j = 0; j <= i; ++j) d[e++] = whitening(k, kLegs * i + j);
        }
        for (int i = 0; i < nj; ++i) {
            const int o = q_off_[static_cast<std::size_t>(i)];
            if (prismatic_[static_cast<std::size_t>(i)]) {
                d[o] = q(k, i);
            } else {
                d[o] = std::cos(q(k, i));
                d[o + 1] = std::sin(q(k, i));
            }
        }
    }
}

EffectObjective::Workspace EffectObjective::make_workspace() const {
    Workspace ws;
    ws.buf.assign(static_cast<std::size_t>(15) * static_cast<std::size_t>(geometry_.n_joints()) + 1, 0.0);
    return ws;
}

double EffectObjective::evaluate(const double* x, double* jbuf, double* res, double* forces,
                                 char* singular) const {
    detail::EvalConsts ec;
    carriage_.consts(geometry_, x, ec, jbuf);
    const EffectModel& m = effects_;
    const int nj = geometry_.n_joints();
    const detail::LegEffects le = detail::leg_effects(m, x);
    const double *c = le.c, *alpha = le.alpha;  // mm/N and 1/K
    detail::PoseData layout;  // the carriage chain's
    layout.n_joints = nj, layout.n_prefix = carriage_.n_prefix();
    layout.q_off = q_off_.data(), layout.prismatic = prismatic_.data();
    double ccomp[kMaxChainJoints];  // per joint: its compliance in the model's units (0: rigid)
    double ch[3] = {0, 0, 0};       // the hexapod's centre in {4}
    if (off_cc_ >= 0) {
        detail::hexapod_centre(m, ec, ch);
        detail::carriage_compliances(m, cc_scale_, x, ccomp);
    }
    double calpha[kMaxChainJoints];  // per joint its scale's expansion coefficient (1/K; 0: none)
    if (off_ct_ >= 0) detail::carriage_alphas(m, nj, x, calpha);
    double acc = 0;
    for (int k = 0; k < n_; ++k) {
        const double* d = data_.data() + static_cast<std::size_t>(k) * static_cast<std::size_t>(stride_);
        double t[12];
        if (off_cc_ >= 0) {
            // The carriage compliance: each joint's gravity load at the readings (the chain's
            // frames before it), its change c L, then 0T4 at the changed joint values.
            double axes[3 * kMaxChainJoints], origins[3 * kMaxChainJoints], delta[kMaxChainJoints];
            detail::carriage_chain(layout, ec, d, nullptr, t, axes, origins);
            const double* pl = d + off_cc_;
            detail::carriage_deflection(m, layout, axes, origins, t, ch, pl, pl[3], m.carriage_gravity, ccomp, delta);
            if (off_ct_ >= 0) detail::carriage_growth(layout, d, d[off_ct_], calpha, delta, true);
            detail::carriage_chain(layout, ec, d, delta, t, nullptr, nullptr);
        } else if (off_ct_ >= 0) {  // the scales' growth alone
            double delta[kMaxChainJoints];
            detail::carriage_growth(layout, d, d[off_ct_], calpha, delta, false);
            detail::carriage_chain(layout, ec, d, delta, t, nullptr, nullptr);
        } else {
            detail::carriage_chain(layout, ec, d, nullptr, t, nullptr, nullptr);
        }
        // The legs in {0}: r_j = 0R5 b_j, v_j = 0P5 + r_j - 0P4 - 0R4 a_j.
        double len[kLegs], u[kLegs][3], rj[kLegs][3], w[6];
        for (int j = 0; j < kLegs; ++j) {
            double v[3];
            for (int e = 0; e < 3; ++e) {
                rj[j][e] = d[3 * e] * ec.b[j][0] + d[3 * e + 1] * ec.b[j][1] + d[3 * e + 2] * ec.b[j][2];
                const double aj = t[3 * e] * ec.a[j][0] + t[3 * e + 1] * ec.a[j][1] + t[3 * e + 2] * ec.a[j][2];
                v[e] = (d[9 + e] + rj[j][e]) - (t[9 + e] + aj);
            }
            len[j] = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            if (m.compliance) {
                const double inv = 1.0 / len[j];
                for (int e = 0; e < 3; ++e) u[j][e] = v[e] * inv;
            }
        }
        bool failed = false;
        if (m.compliance) {  // G f = w (the statics, effects_kernel.hpp)
            detail::Statics st;
            failed = !detail::statics_factor(u, rj, st);
            for (int e = 0; e < 3; ++e) w[e] = d[18 + e], w[3 + e] = d[21 + e];
            if (!failed) detail::statics_forces(st, w);
        } else {
            for (double& v : w) v = 0.0;
        }
        if (singular) singular[k] = failed ? 1 : 0;
        if (forces)
            for (int j = 0; j < kLegs; ++j) forces[kLegs * k + j] = failed ? 0.0 : w[j];
        double raw[kLegs];
        for (int j = 0; j < kLegs; ++j) {
            const double pred = detail::predicted_reading(len[j], ec.l0[j], c[j], w[j], alpha[j], d[24 + j]);
            raw[j] = failed ? kFailedResidual : pred - d[12 + j];
            if (off_w_ >= 0 && !failed) raw[j] *= d[off_w_ + j];
        }
        double* out = res ? res + kLegs * k : nullptr;
        if (off_wh_ >= 0 && !failed) {
            const double* wh = d + off_wh_;
            for (int i = 0; i < kLegs; ++i) {
                double r = 0;
                for (int j = 0; j <= i; ++j) r += *wh++ * raw[j];
                if (out) out[i] = r;
                acc += r * r;
            }
        } else {
            for (int j = 0; j < kLegs; ++j) {
                if (out) out[j] = raw[j];
                acc += raw[j] * raw[j];
            }
        }
    }
    return acc;
}

double EffectObjective::cost(const double* x, Workspace& ws) const {
    return evaluate(x, ws.buf.data(), nullptr, nullptr, nullptr);
}

void EffectObjective::check_x(const Eigen::Ref<const VectorXd>& x) const {
    if (x.size() != n_params())
        throw std::invalid_argument("x: " + std::to_string(x.size()) + " values given; expected " +
                                    std::to_string(n_params()) + " (" +
                                    std::to_string(geometry_.n_params()) + " geometric errors, then " +
                                    std::to_string(effects_.n_params) + " effect parameters)");
    require_finite(x.data(), x.size(), "x");
}

double EffectObjective::cost(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    Workspace ws = make_workspace();
    return cost(x.data(), ws);
}

VectorXd EffectObjective::residuals(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    VectorXd r(n_residuals());
    Workspace ws = make_workspace();
    evaluate(x.data(), ws.buf.data(), r.data(), nullptr, nullptr);
    return r;
}

RowMatrixXd EffectObjective::forces(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    RowMatrixXd f(n_, kLegs);
    Workspace ws = make_workspace();
    evaluate(x.data(), ws.buf.data(), nullptr, f.data(), nullptr);
    return f;
}

std::vector<std::pair<int, std::string>> EffectObjective::failures(const Eigen::Ref<const VectorXd>& x) const {
    check_x(x);
    std::vector<char> singular(static_cast<std::size_t>(n_), 0);
    Workspace ws = make_workspace();
    evaluate(x.data(), ws.buf.data(), nullptr, nullptr, singular.data());
    std::vector<std::pair<int, std::string>> out;
    for (int k = 0; k < n_; ++k)
        if (singular[static_cast<std::size_t>(k)])
            out.emplace_back(k, "the hexapod is singular there: its legs cannot hold the load "
                                "(no leg forces)");
    return out;
}

void EffectObjective::cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const {
    batch_costs(*this, X, static_cast<std::size_t>(m), out, pool);
}

}  // namespace iwr
