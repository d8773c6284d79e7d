// The non-geometric effects on the legs (issue 23, docs/effects.md) in the C++ core: the legs'
// axial compliance under the load they carry and their thermal expansion, in the leg objective of
// eq. (10) that DE, CRS2, BOBYQA and iwr-engine minimise.
//
// The model is Python's (iwr/effects/builtin.py, iwr/effects/model.py), which the tests check it
// against: for leg j at pose k the predicted sensor reading is
//
//     s_kj = D_kj - l0_j - 1e-3 c_j f_kj - 1e-6 alpha_j D_kj (T_kj - T_ref)
//
// with D_kj the distance between the joint centres (the geometry, docs/model.md), c_j the leg's
// compliance (um/N), f_kj its axial force (N, tension positive) from the hexapod's statics
// G f = w (column j of G: the leg's unit vector u_j and its moment r_j x u_j about the platform
// origin, r_j = 0R5 b_j; w the gravity wrench of the platform and the pose's payload), alpha_j the
// expansion coefficient (ppm/K) and T_kj the leg's temperature. The unknowns are the robot's
// geometric errors, then the effects' parameters in the order of their tables (corrections to the
// tables' values, as the geometric errors are to the nominal geometry).
//
// A separate objective type (EffectObjective), not a branch inside the SIMD kernels of
// iwr/objective.hpp: a robot without effects runs those kernels exactly as before. This one is
// portable scalar code, the same on every instruction set (BENCHMARKS.md: what it costs).
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "iwr/model.hpp"
#include "iwr/objective.hpp"
#include "iwr/parallel.hpp"

namespace iwr {

/// One value of an effect's table (the robot TOML's [effects.<name>]): true/false, a number, or
/// an array of numbers.
struct EffectValue {
    enum class Type : std::uint8_t { Bool = 0, Number = 1, Numbers = 2 };
    Type type = Type::Number;
    std::vector<double> numbers;  // Bool: one entry, 0 or 1; Number: one; Numbers: any count
};

/// One effect: its registered name ("compliance", "thermal") and its table, key by key, as Python's
/// Effect.to_dict() gives it (the problem file stores it so).
struct EffectTable {
    std::string name;
    std::vector<std::pair<std::string, EffectValue>> entries;
};

/// The effects as the objective evaluates them, read from their tables.
struct EffectModel {
    int n_geometric = 0;  // the robot's 4 n + 42: the effects' parameters come after
    int n_params = 0;     // the effects' parameters
    // [effects.compliance]
    bool compliance = false;
    int compliance_index = -1;          // x[compliance_index + (per_leg ? j : 0)]
    bool compliance_per_leg = true;
    double compliance_values[6] = {};   // um/N, the table's (x holds corrections)
    double platform_mass = 0;           // kg
    Vec3 platform_centre = Vec3::Zero();  // mm in {5}
    Vec3 gravity = Vec3::Zero();        // m/s^2 in {0}
    // [effects.thermal]
    bool thermal = false;
    int thermal_index = -1;             // -1: the coefficient given, not identified
    bool thermal_per_leg = false;
    double alpha_values[6] = {};        // ppm/K
    double reference = 20;              // degrees C
    // [effects.carriage_compliance]: joint carriage_joints[m] (0-based) moves by
    // (carriage_values[m] + x[carriage_index + m]) * (1e-9 rad/(N mm) per urad/(N m) when revolute,
    // 1e-3 mm/N per um/N when prismatic) times its gravity load at the readings.
    bool carriage = false;
    int carriage_index = -1;
    std::vector<int> carriage_joints;
    std::vector<double> carriage_values;
    double hexapod_mass = 0;            // kg
    Vec3 hexapod_centre = Vec3::Zero(); // mm in {4}
    double carriage_platform_mass = 0;  // kg (the compliance effect's, when both are on)
    Vec3 carriage_platform_centre = Vec3::Zero();
    Vec3 carriage_gravity = Vec3::Zero();
    // [effects.carriage_thermal]: prismatic joint ct_joints[m] (0-based) moves by
    // 1e-6 (ct_values[m] + x[ct_index + (ct_per_joint ? m : 0)]) (T - ct_reference) q, its scale's
    // expansion with the machine's temperature T (the data's one column); ct_index -1: given.
    bool carriage_thermal = false;
    int ct_index = -1;
    bool ct_per_joint = false;
    std::vector<int> ct_joints;
    std::vector<double> ct_values;      // ppm/K, one per listed joint
    double ct_reference = 20;           // degrees C

    bool any() const { return compliance || thermal || carriage || carriage_thermal; }
    /// Reads the tables (the parameters numbered from n_geometric, in the tables' order). Throws
    /// std::invalid_argument naming "effects.<name>.<key>", the value and what was expected.
    static EffectModel parse(const std::vector<EffectTable>& tables, int n_geometric);
};

/// Eq. (10) with the effects: the (weighted or whitened) sum of squared differences between the
/// predicted and measured leg readings, the prediction with the legs' compliance and thermal
/// growth. Meets the objective requirements of iwr/measurement_kind.hpp.
class EffectObjective {
public:
    /// q (N, n_joints), poses (N, 6), legs (N, 6) as Objective; payload (N, 4: kg, then the centre
    /// of mass in {5}, mm) or empty (no payload); temperatures (N, 1: one per pose, or N, 6: one per
    /// leg; degrees C) or empty (refused when the thermal effect is on); weights (N, 6) or empty;
    /// whitening (N, 36) lower-triangular per pose, or empty (not with weights).
    EffectObjective(Geometry geometry, EffectModel effects, const RowMatrixXd& q,
                    const RowMatrixXd& poses, const RowMatrixXd& legs, const RowMatrixXd& payload,
                    const RowMatrixXd& temperatures, const RowMatrixXd& weights = RowMatrixXd(),
                    const RowMatrixXd& whitening = RowMatrixXd());

    /// The residual of each leg at a pose where the legs cannot hold the load (the hexapod is
    /// singular there: the forces do not exist): a large finite penalty, never NaN (failures()).
    static constexpr double kFailedResidual = 1e3;

    const Geometry& geometry() const { return geometry_; }
    const EffectModel& effects() const { return effects_; }
    int n_params() const { return geometry_.n_params() + effects_.n_params; }
    int n_poses() const { return n_; }
    int n_residuals() const { return kLegs * n_; }
    bool whitened() const { return whitened_; }

    class Workspace {
        friend class EffectObjective;
        std::vector<double> buf;
    };
    Workspace make_workspace() const;

    /// The cost at x (n_params entries, unchecked: the hot path, allocation-free).
    double cost(const double* x, Workspace& ws) const;
    /// Checked.
    double cost(const Eigen::Ref<const VectorXd>& x) const;
    /// Residuals (N*6, pose-major) at x.
    VectorXd residuals(const Eigen::Ref<const VectorXd>& x) const;
    /// The leg forces (N, 6; N, tension positive) at x (zeros without the compliance effect).
    RowMatrixXd forces(const Eigen::Ref<const VectorXd>& x) const;
    /// The poses where the hexapod cannot hold the load at x (singular statics), with a message.
    std::vector<std::pair<int, std::string>> failures(const Eigen::Ref<const VectorXd>& x) const;
    /// Costs of the rows of X (M, n_params) into out, across the pool's threads. Unchecked.
    void cost_batch(const double* X, Eigen::Index m, double* out, ThreadPool& pool) const;

private:
    void check_x(const Eigen::Ref<const VectorXd>& x) const;
    // The residuals of every pose into res (or only their squares summed when res is null); the
    // forces into f and a per-pose singular flag into bad when non-null.
    double evaluate(const double* x, double* jbuf, double* res, double* f, char* bad) const;

    Geometry geometry_;
    EffectModel effects_;
    int n_ = 0;
    // Per pose, `stride_` doubles: 0R5 (9, row-major), 0P5 (3), readings (6), the gravity wrench
    // of the platform and payload (6: N, N mm; in {0}), T - T_ref per leg (6), sqrt weights (6,
    // when weighted), the whitening's lower triangle row by row (21, when whitened), then per joint
    // q (prismatic) or cos q, sin q (revolute).
    std::vector<double> data_;
    int stride_ = 0, off_w_ = -1, off_wh_ = -1;
    // The carriage compliance: per pose the first moment (kg mm, in {0}) and the mass (kg) of the
    // bodies the platform carries (4 doubles at off_cc_); per joint its unit scale (0: rigid).
    int off_cc_ = -1;
    // The carriage's thermal expansion: per pose the machine's T - T_ref (1 double at off_ct_).
    int off_ct_ = -1;
    std::vector<double> cc_scale_;
    bool whitened_ = false;
    std::vector<int> q_off_;
    std::vector<char> prismatic_;
    detail::CarriageNominal carriage_;  // the carriage's per-evaluation constants (objective.hpp)
};

}  // namespace iwr
