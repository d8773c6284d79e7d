// Double-ballbar data (iwr/ballbar.hpp) for a robot with the non-geometric effects (iwr/effects.hpp):
// the objective DE, CRS2, BOBYQA and iwr-engine minimise (issue 23; docs/effects.md, "Ballbar data").
//
// Residual k, pose k measured in set-up s, as BallbarObjective's:
//
//     r_k = w_k ( |T_05,k(x) P_s - F_s| + o_s - d_k )                                    (mm)
//
// with T_05,k the platform pose by forward kinematics *with the effects* under pose k's load and
// temperature: TrackerEffectObjective's kinematics (iwr/effects_tracker.hpp: chord or Newton steps on
// the legs with their compliance and thermal growth, the carriage's joints changed by their compliance
// under the load) on a probe at the origin of {5} in a tracker frame equal to {0} (registration
// zero: gravity in {T} is gravity in {0}, the effects' own gravity_m_s2, as Python's
// iwr.ballbar.effects.BallbarEffectProblem takes it), whose four virtual points give the origin and
// axes of {5}; then the distances of BallbarObjective (detail::BarReadings).
//
// Parameters: the robot's 4 n + 42, the effects' (their tables' order), then the set-ups' 7 S
// (BallbarObjective's: platform ball, fixed ball, length offset), the order of BallbarEffectProblem.
//
// A pose whose forward kinematics with the effects fails gets r_k = w_k kFailedResidual; failures(x)
// names such poses. The cost is summed in pose order: a row's cost never depends on the thread.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "iwr/ballbar.hpp"
#include "iwr/effects.hpp"
#include "iwr/effects_tracker.hpp"
#include "iwr/model.hpp"
#include "iwr/parallel.hpp"

namespace iwr {

class BallbarEffectObjective : public detail::BallbarOn<TrackerEffectObjective> {
public:
    /// bars, q, legs, bar, distance as BallbarObjective; effects: at least one on (the geometry
    /// alone runs on BallbarObjective); payload (N, 4) or empty, temperatures (N, 1 or 6) or empty
    /// as TrackerEffectObjective; reference (4 n + 42), home and tolerance (mm) as
    /// TrackerEffectObjective (the geometric forward kinematics solved once per pose at the
    /// reference, ForwardKinematicsError naming the pose when it fails there). Gravity is the
    /// effects' own, in {0}. Throws std::invalid_argument on bad sizes, an index out of range or a
    /// value not finite.
    BallbarEffectObjective(Geometry geometry, EffectModel effects, std::vector<BarSetup> bars,
                           const RowMatrixXd& q, const RowMatrixXd& legs, std::vector<int> bar,
                           VectorXd distance, const RowMatrixXd& payload, const RowMatrixXd& temperatures,
                           const VectorXd& reference, const Vector6d& home, double tolerance = 1e-11);

    const EffectModel& effects() const { return kin().effects(); }
};

}  // namespace iwr
