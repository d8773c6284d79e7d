// The double ballbar's objective and its section of the problem file (iwr/ballbar.hpp).
#include "iwr/ballbar.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "iwr/binary_io.hpp"
#include "iwr/problem_file.hpp"

namespace iwr {

namespace {

// The tracker kinematics the distances are computed on: a probe at the origin of {5} (pose zero,
// length 1 mm: its virtual points are {5}'s origin and unit axis tips) in a tracker frame equal
// to {0} (registration zero), measured as zeros (the objective only reads the predicted points).
TrackerObjective kinematics(Geometry geometry, const RowMatrixXd& q, const RowMatrixXd& legs,
                            const VectorXd& reference, const Vector6d& home, double tolerance) {
    return TrackerObjective(std::move(geometry), TrackerSetup::probe(Vector6d::Zero(), Vector6d::Zero(), 1.0),
                            q, legs, RowMatrixXd::Zero(legs.rows(), 12), reference, home, tolerance);
}

}  // namespace

namespace detail {

BarReadings::BarReadings(std::vector<BarSetup> bars, std::vector<int> bar, VectorXd distance, int n)
    : bars_(std::move(bars)), n_(n), bar_(std::move(bar)), distance_(std::move(distance)) {
    if (bars_.empty()) throw std::invalid_argument("ballbar set-ups: none; expected at least one");
    for (const BarSetup& b : bars_) {
        require_finite(b.platform_ball.data(), 3, "ballbar set-up platform ball");
        require_finite(b.fixed_ball.data(), 3, "ballbar set-up fixed ball");
        require_finite(&b.offset, 1, "ballbar set-up offset");
    }
    if (static_cast<Eigen::Index>(bar_.size()) != n_ || distance_.size() != n_) {
        std::ostringstream msg;
        msg << "ballbar data: " << bar_.size() << " set-up indices and " << distance_.size()
            << " distances for " << n_ << " poses; expected one of each per pose";
        throw std::invalid_argument(msg.str());
    }
    require_finite(distance_.data(), distance_.size(), "distance");
    for (int k = 0; k < n_; ++k)
        if (bar_[static_cast<std::size_t>(k)] < 0 || bar_[static_cast<std::size_t>(k)] >= n_setups()) {
            std::ostringstream msg;
            msg << "ballbar data: pose " << k << " has set-up index " << bar_[static_cast<std::size_t>(k)]
                << "; expected 0 to " << n_setups() - 1;
            throw std::invalid_argument(msg.str());
        }
}

void BarReadings::set_whitening(const RowMatrixXd& whitening) {
    if (whitening.size() == 0) {
        weights_.resize(0);
        return;
    }
    if (whitening.rows() != n_ || whitening.cols() != 1) {
        std::ostringstream msg;
        msg << "whitening: shape (" << whitening.rows() << ", " << whitening.cols() << "); expected ("
            << n_ << ", 1): one residual per pose";
        throw std::invalid_argument(msg.str());
    }
    require_finite(whitening.data(), whitening.size(), "whitening");
    weights_ = whitening.col(0);
}

double BarReadings::evaluate(const double* xs_all, const RowMatrixXd& frames, double* res) const {
    double cost = 0;
    for (int k = 0; k < n_; ++k) {
        const int s = bar_[static_cast<std::size_t>(k)];
        const BarSetup& b = bars_[static_cast<std::size_t>(s)];
        const double* xs = xs_all + kBarParams * s;
        const double* pt = frames.row(k).data();  // origin, then the tips of the unit axes
        double r;
        if (std::isnan(pt[0])) {
            r = TrackerObjective::kFailedResidual;
        } else {
            double p[3], v[3];
            for (int c = 0; c < 3; ++c) p[c] = b.platform_ball(c) + xs[c];
            for (int c = 0; c < 3; ++c) {
                // T_05 P = o + sum_j P_j a_j, a_j the axis tip minus the origin (as BallbarProblem).
                const double o = pt[c];
                const double rp = (pt[3 + c] - o) * p[0] + (pt[6 + c] - o) * p[1] + (pt[9 + c] - o) * p[2];
                v[c] = (o + rp) - (b.fixed_ball(c) + xs[3 + c]);
            }
            const double dist = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            r = (dist + (b.offset + xs[6])) - distance_(k);
        }
        if (whitened()) r *= weights_(k);
        if (res) res[k] = r;
        cost += r * r;
    }
    return cost;
}

}  // namespace detail

BallbarObjective::BallbarObjective(Geometry geometry, std::vector<BarSetup> bars, const RowMatrixXd& q,
                                   const RowMatrixXd& legs, std::vector<int> bar, VectorXd distance,
                                   const VectorXd& reference, const Vector6d& home, double tolerance)
    : BallbarOn(kinematics(std::move(geometry), q, legs, reference, home, tolerance), std::move(bars),
                std::move(bar), std::move(distance)) {}

// ----- the problem file's ballbar section (iwr/problem_file.hpp) ---------------------------------

namespace {

constexpr std::size_t kMaxSetups = 10'000;

bool setup_name_ok(const std::string& name) {
    if (name.empty() || name.size() > 40) return false;
    for (char c : name)
        if (!((c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' || c == '-'))
            return false;
    return true;
}

// n finite doubles, each within [-limit, limit].
void finite_doubles(io::Reader& r, const char* field, double* out, std::size_t n, double limit = 1e12) {
    const std::vector<double> v = r.doubles(field, n);
    for (std::size_t i = 0; i < n; ++i) {
        if (!(std::fabs(v[i]) <= limit))
            r.fail(std::string(field) + ": value " + std::to_string(i) + " is " + std::to_string(v[i]) +
                   (std::isfinite(v[i]) ? ", beyond any robot" : ", not finite"));
        out[i] = v[i];
    }
}

}  // namespace

void write_ballbar_section(io::Writer& w, const ProblemData& p) {
    if (p.bar.size() != static_cast<std::size_t>(p.n_poses()))
        throw std::invalid_argument("ballbar set-up indices: " + std::to_string(p.bar.size()) + "; expected " +
                                    std::to_string(p.n_poses()) + ", one per pose");
    w.u64(p.bars.size());
    for (const BarSetup& b : p.bars) {
        w.str(b.name);
        w.doubles(b.platform_ball.data(), 3);
        w.doubles(b.fixed_ball.data(), 3);
        w.f64(b.offset);
        w.u8(b.has_range ? 1 : 0);
        if (b.has_range) {
            const double range[2] = {b.range_min, b.range_max};
            w.doubles(range, 2);
        }
    }
    for (int s : p.bar) w.u64(static_cast<std::uint64_t>(s));
    w.doubles(p.distance.data(), static_cast<std::size_t>(p.distance.size()));
    w.doubles(p.reference.data(), static_cast<std::size_t>(p.reference.size()));
}

void read_ballbar_section(io::Reader& r, ProblemData& p) {
    const std::uint64_t ns = r.u64("number of ballbar set-ups");
    // Each set-up takes at least a name and 7 numbers (9 x 8 bytes with the counts).
    if (ns == 0) r.fail("number of ballbar set-ups: 0; ballbar data need at least one set-up");
    if (ns > kMaxSetups || ns > r.remaining() / (9 * 8))
        r.fail("truncated or corrupt: number of ballbar set-ups " + std::to_string(ns) + " does not fit in the " +
               std::to_string(r.remaining()) + " bytes left");
    p.bars.clear();
    for (std::uint64_t i = 0; i < ns; ++i) {
        BarSetup b;
        b.name = r.str("ballbar set-up name", 40);
        if (!setup_name_ok(b.name))
            r.fail("ballbar set-up name: '" + b.name + "'; expected 1 to 40 letters, digits, '_' or '-'");
        for (const BarSetup& other : p.bars)
            if (other.name == b.name) r.fail("ballbar set-up name: '" + b.name + "' given twice");
        finite_doubles(r, "ballbar platform ball", b.platform_ball.data(), 3);
        finite_doubles(r, "ballbar fixed ball", b.fixed_ball.data(), 3);
        b.offset = r.f64("ballbar offset");
        if (!(std::fabs(b.offset) <= 1e12))
            r.fail("ballbar offset: set-up '" + b.name + "' has " + std::to_string(b.offset) + "; expected a finite length (mm)");
        b.has_range = r.flag("ballbar has range");
        if (b.has_range) {
            double range[2];
            finite_doubles(r, "ballbar range", range, 2);
            if (!(0 <= range[0] && range[0] < range[1]))
                r.fail("ballbar range: set-up '" + b.name + "' has (" + std::to_string(range[0]) + ", " +
                       std::to_string(range[1]) + "); expected 0 <= shortest < longest (mm)");
            b.range_min = range[0], b.range_max = range[1];
        }
        p.bars.push_back(std::move(b));
    }
    const int n = p.n_poses();
    p.bar.assign(static_cast<std::size_t>(n), 0);
    for (int k = 0; k < n; ++k) {
        const std::uint64_t s = r.u64("ballbar set-up index");
        if (s >= ns)
            r.fail("ballbar set-up index: pose " + std::to_string(k) + " has " + std::to_string(s) + "; expected 0 to " +
                   std::to_string(ns - 1));
        p.bar[static_cast<std::size_t>(k)] = static_cast<int>(s);
    }
    p.distance.resize(n);
    finite_doubles(r, "distance", p.distance.data(), static_cast<std::size_t>(n));
    // The limit of iwr.measurements.MAX_LENGTH_MM (100 m), which the Python reader applies too.
    constexpr double kMaxLengthMm = 1e5;
    for (int k = 0; k < n; ++k)
        if (!(p.distance(k) > 0 && p.distance(k) < kMaxLengthMm))
            r.fail("distance: pose " + std::to_string(k) + " is " + std::to_string(p.distance(k)) +
                   "; a bar reading is a length in mm, > 0 and below 1e+05");
    p.reference.resize(p.n_robot_params());
    finite_doubles(r, "reference", p.reference.data(), static_cast<std::size_t>(p.n_robot_params()));
}

void hash_ballbar_setups(io::Hash64& h, const ProblemData& p) {
    h.str("ballbar").u64(p.bars.size());
    for (const BarSetup& b : p.bars) {
        h.str(b.name).doubles(b.platform_ball.data(), 3).doubles(b.fixed_ball.data(), 3).f64(b.offset);
        // The range limits the simulation only: no part of the objective.
    }
    h.doubles(p.reference.data(), static_cast<std::size_t>(p.reference.size()));
}

void hash_ballbar_data(io::Hash64& h, const ProblemData& p) {
    // Each pose's set-up by name (the data file's column): the same data whatever the order of
    // the robot's set-ups.
    h.str("ballbar").u64(p.bar.size());
    for (int s : p.bar) h.str(p.bars.at(static_cast<std::size_t>(s)).name);
    h.doubles(p.distance.data(), static_cast<std::size_t>(p.distance.size()));
}

}  // namespace iwr
