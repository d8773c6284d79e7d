// The C++ extension point: what a measurement kind implements (docs/internals.md, "Adding a
// measurement kind in C++").
//
// A measurement kind (the platform pose in {0}, reflector points or a probe in the tracker frame
// {T}, ...) enters the C++ core through two models of its readings, and nowhere else:
//
//   1. Its objective, for the global methods and the iwr-engine: a type meeting the `Objective`
//      requirements below (iwr::Objective for poses in {0}, iwr::TrackerObjective for tracker
//      data). Everything that searches (the DE engine of iwr/de.hpp through
//      de::ReducedObjective<Obj>, batch_costs of iwr/parallel.hpp, the engine's run loop) is a
//      template over that type and never asks which kind it runs on.
//   2. Its residual model for the efficient estimator: a LoopModel (below), the per-pose
//      normalised residuals with their nuisance corrections and exact derivatives; solve_loop
//      runs the one Levenberg-Marquardt/Schur solver on any LoopModel.
//
// The one place that maps a problem file's kind to a type is make_objective (and, for the file
// itself, iwr/problem_file.hpp): a new kind is a new type, one alternative of AnyObjective and one
// case there, not a branch at every call site. The SIMD kernels of the built-in kinds keep their
// own run-time instruction-set dispatch (supported_kernels() in iwr/objective.hpp), inside their
// objective types.
#pragma once

#include <functional>
#include <string>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

#include "iwr/ballbar.hpp"
#include "iwr/effects.hpp"
#include "iwr/effects_ballbar.hpp"
#include "iwr/effects_tracker.hpp"
#include "iwr/implicit_loop.hpp"
#include "iwr/model.hpp"
#include "iwr/objective.hpp"
#include "iwr/problem_file.hpp"
#include "iwr/tracker.hpp"

namespace iwr {

// ----- 1. the objective ------------------------------------------------------------------------
//
// An objective type Obj provides (const methods are called concurrently from several threads,
// each with its own Workspace):
//
//   int n_params() const;                        // parameters: the robot's 4 n + 42, then the
//                                                // kind's own (registration, offsets, ...)
//   int n_poses() const;
//   class Workspace;                             // one thread's scratch memory
//   Workspace make_workspace() const;
//   double cost(const double* x, Workspace&) const;            // the hot path: no allocation
//                                                              // once warm, no check of x
//   double cost(const Eigen::Ref<const VectorXd>& x) const;    // checked
//
// and, optionally, `std::vector<std::pair<int, std::string>> failures(const Eigen::Ref<const
// VectorXd>& x) const`: the poses whose model cannot be evaluated at x (their residuals carry a
// finite penalty); a result with failures is never reported as a success (objective_failures),
// and `void cost_rows(const double* const* xs, int m, double* out, Workspace&) const`: the costs
// of m vectors at once, each bit for bit its cost (detail::row_costs in iwr/parallel.hpp hands
// batch_costs' and ReducedObjective's rows to it, up to kCostRows at a time).
// A row's cost must depend on that row only (not on the thread or the other rows), which makes
// every search reproducible whatever the number of threads. Weighting by the instruments' noise
// lives inside the objective (a whitening per pose, fixed): the searches see one cost.

namespace detail {
template <class T, class = void>
struct is_objective : std::false_type {};
template <class T>
struct is_objective<
    T, std::void_t<typename T::Workspace,
                   decltype(std::declval<const T&>().n_params()),
                   decltype(std::declval<const T&>().n_poses()),
                   decltype(std::declval<const T&>().make_workspace()),
                   decltype(double(std::declval<const T&>().cost(
                       std::declval<const double*>(), std::declval<typename T::Workspace&>()))),
                   decltype(double(std::declval<const T&>().cost(std::declval<const VectorXd&>())))>>
    : std::true_type {};

template <class T, class = void>
struct has_failures : std::false_type {};
template <class T>
struct has_failures<T, std::void_t<decltype(std::declval<const T&>().failures(
                           std::declval<const VectorXd&>()))>> : std::true_type {};
}  // namespace detail

/// Whether Obj meets the objective requirements above (checked by de::ReducedObjective).
template <class Obj>
constexpr bool is_objective_v = detail::is_objective<Obj>::value;

/// The poses whose model cannot be evaluated at x, with a message each; none for a kind whose
/// objective has no failures() (the leg residuals of eq. (10) need no forward kinematics).
template <class Obj>
std::vector<std::pair<int, std::string>> objective_failures(const Obj& objective, const VectorXd& x) {
    static_assert(is_objective_v<Obj>, "not an objective (see iwr/measurement_kind.hpp)");
    if constexpr (detail::has_failures<Obj>::value) {
        return objective.failures(x);
    } else {
        (void)objective, (void)x;
        return {};
    }
}

/// The objective of each kind a problem file holds, one alternative per objective type: leg data,
/// tracker data and ballbar data with non-geometric effects on (iwr/effects.hpp,
/// iwr/effects_tracker.hpp, iwr/effects_ballbar.hpp) have their own, so that the SIMD kernels of the
/// geometry alone run unchanged without them.
using AnyObjective = std::variant<Objective, TrackerObjective, EffectObjective, TrackerEffectObjective,
                                  BallbarObjective, BallbarEffectObjective>;

/// The objective of a problem file's measurements, as iwr-engine runs it (and the Python
/// bindings, to check it against iwr.Problem): eq. (10) on leg readings or the tracker residuals,
/// whitened when the file carries a noise weighting. The one dispatch on the measurement kind.
/// Throws std::invalid_argument on inconsistent data, ForwardKinematicsError (naming the pose)
/// when a tracker pose has no forward kinematics at the reference.
AnyObjective make_objective(const ProblemData& problem);

// ----- 2. the residual model of the efficient estimator ------------------------------------------

/// The per-pose residual model the implicit-loop solver works on: pose k has ny nuisance
/// corrections y_k, of which `free[k]` are unknowns (the rest held), and nr normalised residual
/// columns, of which `rows[k]` are live (the others are 0: an exact reading, an unseen point). np
/// is the number of parameters (the robot's, then the kind's own).
struct LoopModel {
    int n = 0, ny = 0, nr = 0, np = 0;
    std::vector<std::vector<int>> free, rows;
    /// Normalised residuals r (nr) of pose k at (x, y_k); with jx, jy non-null also their exact
    /// derivatives (nr x np, nr x ny, zero where a residual does not depend on the variable).
    /// Called from one thread.
    std::function<void(const VectorXd& x, int k, const double* y, double* r, RowMatrixXd* jx,
                       RowMatrixXd* jy)>
        eval;
};

/// The efficient estimator on any residual model: Levenberg-Marquardt over the active parameters
/// (indices into x0, checked by the caller) and the free corrections, each pose's nuisance block
/// eliminated by its Schur complement; statistics at the solution when options.statistics.
/// corrections0 (n, ny) starts the corrections (a held one stays as given).
ImplicitLoopResult solve_loop(const LoopModel& model, const Eigen::Ref<const VectorXd>& x0,
                              const std::vector<int>& active,
                              const Eigen::Ref<const RowMatrixXd>& corrections0,
                              const ImplicitLoopOptions& options = ImplicitLoopOptions(),
                              const LoopCallback& callback = LoopCallback());

/// The residual models of the built-in kinds (implicit_loop and implicit_loop_tracker solve
/// them after their checks; the inputs must outlive the model). The pose in {0}: legs, then each
/// reading with sigma > 0 as an unknown correction (sigma (N, 6 + n_joints + 6), as
/// implicit_loop). Tracker data: as implicit_loop_tracker (sigma (N, 6 + n_joints)).
LoopModel pose_loop_model(const Geometry& g, const Eigen::Ref<const RowMatrixXd>& q,
                          const Eigen::Ref<const RowMatrixXd>& poses,
                          const Eigen::Ref<const RowMatrixXd>& legs,
                          const Eigen::Ref<const RowMatrixXd>& sigma);
LoopModel tracker_loop_model(const Geometry& g, const TrackerLoopData& data,
                             const Eigen::Ref<const RowMatrixXd>& q,
                             const Eigen::Ref<const RowMatrixXd>& legs,
                             const Eigen::Ref<const RowMatrixXd>& sigma);

}  // namespace iwr
