// Ballbar data for a robot with the effects (see iwr/effects_ballbar.hpp): the frames of {5} by
// TrackerEffectObjective's forward kinematics with the effects, the distances by BallbarObjective's
// (detail::BarReadings).
#include "iwr/effects_ballbar.hpp"

namespace iwr {

namespace {

// The kinematics the distances are computed on, as BallbarObjective's (iwr/ballbar.cpp): a probe at
// the origin of {5} (pose zero, length 1 mm: its virtual points are {5}'s origin and unit axis tips)
// in a tracker frame equal to {0} (registration zero, so gravity in {T} is gravity in {0}), measured
// as zeros (only the predicted points are read). Gravity: the effects' own, in {0} (compliance's
// and the carriage's are the same when both are on, EffectModel::parse); with the thermal effect
// alone no load is read, and standard gravity stands in.
TrackerEffectObjective kinematics(Geometry geometry, EffectModel effects, const RowMatrixXd& q,
                                  const RowMatrixXd& legs, const RowMatrixXd& payload,
                                  const RowMatrixXd& temperatures, const VectorXd& reference,
                                  const Vector6d& home, double tolerance) {
    const Vec3 gravity = effects.compliance ? effects.gravity
                         : effects.carriage ? effects.carriage_gravity
                                            : Vec3(0, 0, -9.80665);
    return TrackerEffectObjective(std::move(geometry), std::move(effects),
                                  TrackerSetup::probe(Vector6d::Zero(), Vector6d::Zero(), 1.0), gravity, q, legs,
                                  RowMatrixXd::Zero(legs.rows(), 12), payload, temperatures, reference, home,
                                  tolerance);
}

}  // namespace

BallbarEffectObjective::BallbarEffectObjective(Geometry geometry, EffectModel effects, std::vector<BarSetup> bars,
                                               const RowMatrixXd& q, const RowMatrixXd& legs, std::vector<int> bar,
                                               VectorXd distance, const RowMatrixXd& payload,
                                               const RowMatrixXd& temperatures, const VectorXd& reference,
                                               const Vector6d& home, double tolerance)
    : BallbarOn(kinematics(std::move(geometry), std::move(effects), q, legs, payload, temperatures, reference, home,
                           tolerance),
                std::move(bars), std::move(bar), std::move(distance)) {}

}  // namespace iwr
