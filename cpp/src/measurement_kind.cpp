// The one dispatch from a problem file's measurement kind to its objective type (see
// iwr/measurement_kind.hpp).
#include "iwr/measurement_kind.hpp"

namespace iwr {

AnyObjective make_objective(const ProblemData& problem) {
    switch (problem.kind) {
        case MeasurementKind::Pose:
            if (!problem.effects.empty())  // the legs' compliance and temperature (issue 23)
                return AnyObjective(std::in_place_type<EffectObjective>, problem.geometry(),
                                    problem.effect_model(), problem.q, problem.poses, problem.legs,
                                    problem.payload, problem.temperatures,
                                    problem.weighted() ? RowMatrixXd() : problem.weights, problem.whitening);
            // Whitened: the leg weights are folded into the whitening (the writer's Problem did).
            return AnyObjective(std::in_place_type<Objective>, problem.geometry(), problem.q, problem.poses,
                                problem.legs, problem.weighted() ? RowMatrixXd() : problem.weights,
                                problem.whitening);
        case MeasurementKind::Points:
        case MeasurementKind::Probe: {
            if (!problem.effects.empty()) {  // the legs' compliance and temperature (issue 23)
                AnyObjective out(std::in_place_type<TrackerEffectObjective>, problem.geometry(),
                                 problem.effect_model(), problem.tracker_setup(), problem.tracker_gravity,
                                 problem.q, problem.legs, problem.points, problem.payload,
                                 problem.temperatures, problem.reference, problem.home_pose);
                std::get<TrackerEffectObjective>(out).set_whitening(problem.whitening);
                return out;
            }
            AnyObjective out(std::in_place_type<TrackerObjective>, problem.geometry(), problem.tracker_setup(),
                             problem.q, problem.legs, problem.points, problem.reference, problem.home_pose);
            std::get<TrackerObjective>(out).set_whitening(problem.whitening);
            return out;
        }
        case MeasurementKind::Ballbar: {  // the double ballbar's distances (iwr/ballbar.hpp)
            if (!problem.effects.empty()) {  // with the effects, gravity theirs in {0} (issue 23)
                AnyObjective out(std::in_place_type<BallbarEffectObjective>, problem.geometry(),
                                 problem.effect_model(), problem.bars, problem.q, problem.legs, problem.bar,
                                 problem.distance, problem.payload, problem.temperatures, problem.reference,
                                 problem.home_pose);
                std::get<BallbarEffectObjective>(out).set_whitening(problem.whitening);
                return out;
            }
            AnyObjective out(std::in_place_type<BallbarObjective>, problem.geometry(), problem.bars, problem.q,
                             problem.legs, problem.bar, problem.distance, problem.reference, problem.home_pose);
            std::get<BallbarObjective>(out).set_whitening(problem.whitening);
            return out;
        }
    }
    throw std::invalid_argument("measurement kind: " + std::to_string(static_cast<int>(problem.kind)) +
                                " has no objective");
}

}  // namespace iwr
