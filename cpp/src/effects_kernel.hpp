// Internal (not installed, not API): the pieces of the legs' effects that the leg objective with
// effects (effects.cpp, poses in {0}) and the tracker objective with effects (effects_tracker.cpp,
// forward kinematics with the effects) share: the carriage chain at the joint readings, the legs'
// effect coefficients at x, the hexapod's statics (G f = w, factorised once and solved for the
// forces and, transposed, for a Newton step of the legs) and the predicted reading.
#pragma once

#include <vector>

#include "iwr/effects.hpp"
#include "objective_kernel.hpp"  // detail::EvalConsts, PoseData

namespace iwr::detail {

/// The legs' compliance (mm/N, 0 without the compliance effect) and expansion coefficient (1/K)
/// at x: the tables' values plus x's corrections.
struct LegEffects {
    double c[kLegs], alpha[kLegs];
};
LegEffects leg_effects(const EffectModel& m, const double* x);

/// Checks the per-pose loads and temperatures the effects read (std::invalid_argument naming the
/// field): payload (n, 4: kg >= 0, centre of mass in {5}) or empty, temperatures (n, 1 or 6) or
/// empty (refused when the thermal effect is on).
void check_loads(const EffectModel& m, int n, const RowMatrixXd& payload, const RowMatrixXd& temperatures);

/// The predicted leg reading: the joint centres' distance `len` less the leg offset, the
/// compliance's change (c f) and the thermal growth (alpha len dT), in that order.
inline double predicted_reading(double len, double l0, double c, double f, double alpha, double dt) {
    return ((len - l0) - c * f) - (alpha * len) * dt;
}

/// 0T4 by the DH chain (as the SIMD kernel's carriage(), one pose): rotation row-major t[0..8],
/// position t[9..11]. d: the pose's readings at layout.q_off (q prismatic, cos q and sin q
/// revolute); delta (per joint, may be null) added to them; axes, origins (3 per joint, may be
/// null): each joint's axis and a point of it in {0}, the frame before it.
void carriage_chain(const PoseData& layout, const EvalConsts& ec, const double* d, const double* delta,
                    double* t, double* axes, double* origins);

/// The carriage's compliance (EffectModel::carriage): at most this many joints (its per-joint
/// buffers live on the stack).
constexpr int kMaxChainJoints = 64;

/// Per joint of the carriage its compliance's unit scale: 1e-9 rad/(N mm) per urad/(N m) for a
/// revolute joint, 1e-3 mm/N per um/N for a prismatic one, 0 for a joint not listed (rigid).
/// Throws std::invalid_argument naming effects.carriage_compliance.joints for a joint the robot
/// does not have or a chain longer than kMaxChainJoints.
std::vector<double> carriage_scales(const EffectModel& m, const Geometry& g);
/// Per joint its compliance at x in the model's units (0: rigid): the table's value plus x's
/// correction, times scale (carriage_scales).
void carriage_compliances(const EffectModel& m, const std::vector<double>& scale, const double* x, double* out);
/// The hexapod's centre of mass in {4} at the base joints of ec: m.hexapod_centre is given in the
/// frame they define (iwr.effects.model.base_frame: origin their centre, z the normal of their
/// polygon, x towards the midpoint of joints 1 and 2).
void hexapod_centre(const EffectModel& m, const EvalConsts& ec, double* out);
/// The carriage compliance's change of the joints, delta_i = ccomp_i L_i, with L_i joint i's
/// gravity load (iwr.effects.model.joint_loads) at the readings: the torque (P - M o_i) . (g x z_i)
/// about a revolute axis, the force M g . z_i along a prismatic one (axes z_i and points o_i of
/// them, 3 per joint, in {0}: carriage_chain's at the readings). The bodies: the hexapod (mass
/// m.hexapod_mass, centre ch in {4}, t = 0T4 at the readings) and those the platform carries
/// (first moment `first` in {0}, kg mm, and mass `mass`, kg); g (m/s^2) in {0}.
void carriage_deflection(const EffectModel& m, const PoseData& layout, const double* axes, const double* origins,
                         const double* t, const double* ch, const double* first, double mass, const Vec3& g,
                         const double* ccomp, double* delta);

/// The carriage's thermal expansion (EffectModel::carriage_thermal): throws std::invalid_argument
/// naming effects.carriage_thermal.joints for a joint the robot does not have or a revolute one.
void check_carriage_thermal(const EffectModel& m, const Geometry& g);
/// Per joint of the carriage its scale's expansion coefficient at x (1/K; 0 for a joint not
/// listed): the table's value plus x's correction when identified, times 1e-6.
void carriage_alphas(const EffectModel& m, int n_joints, const double* x, double* out);
/// The scales' growth: delta_i (+)= alpha_i dt q_i for the prismatic joints (q_i the reading at
/// layout.q_off[i], dt the machine's T - T_ref at the pose); revolute joints untouched.
inline void carriage_growth(const PoseData& layout, const double* d, double dt, const double* alpha,
                            double* delta, bool add) {
    for (int i = 0; i < layout.n_joints; ++i) {
        const double g = layout.prismatic[i] ? alpha[i] * dt * d[layout.q_off[i]] : 0.0;
        delta[i] = add ? delta[i] + g : g;
    }
}

/// The hexapod's statics at one pose: G (column j the leg's unit vector u_j and its moment
/// r_j x u_j about the platform origin) with the moment rows scaled by 1 / the platform's radius
/// (entries of order 1: the pivot test is then a test of the hexapod's singularity, whatever its
/// size), factorised by Gaussian elimination with partial pivoting.
struct Statics {
    double a[36];     // the elimination (row-major): U on and above the diagonal, the multipliers below
    double inv[6];    // 1 / U's diagonal
    int piv[6];       // the row swapped with row c at step c
    double s = 1;     // the moment rows' scale
};
/// Builds and factorises G from the six legs' unit vectors u and platform joints r (about the
/// platform origin, the same frame); false when a pivot falls below 1e-12 (a singular hexapod:
/// no leg forces).
bool statics_factor(const double (&u)[kLegs][3], const double (&r)[kLegs][3], Statics& st);
/// The leg forces f (N, tension positive) holding the wrench w (force N, moment N mm about the
/// platform origin, unscaled), in place: G f = w.
void statics_forces(const Statics& st, double (&w)[6]);
/// G^-T b in place: the platform motion (dP, omega: a rotation about the platform origin) that
/// changes the legs' lengths by b (d len = G^T (dP, omega)).
void statics_transposed(const Statics& st, double (&b)[6]);

}  // namespace iwr::detail
