"""The efficient estimator: every instrument weighted by its noise (implicit loop method).

Eq. (10) puts all the error in the leg readings and weighs every reading alike. Here every measured
quantity of a pose (carriage joint readings, measured platform position and orientation, leg
readings) gets a correction with its own standard deviation, and the estimator minimises the
Mahalanobis norm of all corrections subject to the loop-closure equations (the legs predicted at
the corrected joint readings and pose equal the corrected leg readings): the implicit loop method of
Wampler, Hollerbach & Arai (IEEE Trans. Robotics and Automation 11(5), 1995), an errors-in-variables
least squares. The unknowns are the (base) error parameters and, per pose, the corrections of the
joint readings and of the platform pose (the nuisance unknowns: the true joint readings and the
true pose); the solver, in C++ (``cpp/src/implicit_loop.cpp``), is a Levenberg-Marquardt method
whose per-pose blocks are eliminated by the Schur complement, with exact derivatives.

On top of the solve this module tests the fit (chi-square, with the verdicts of
:mod:`iwr.fit_test`), finds outliers (a per-pose chi-square test on the normalised residuals, and
Baarda's w-test to name the instrument), estimates variance components (Foerstner's iteration
with redundancy numbers) and predicts the tool accuracy from the covariance
(:mod:`iwr.accuracy_prediction`). The readings model is :mod:`iwr.implicit_loop`. See
``docs/estimation.md``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

# The chi-square distribution by scipy.special (chdtrc = sf, chdtr = cdf, chdtri = isf: the
# functions scipy.stats.chi2 evaluates): importing scipy.stats costs every short command 0.5-0.8 s.
from scipy import special
from scipy.optimize import OptimizeResult

from . import _core, kinds
from ._blas import single_thread
from ._io import jsonable
from .accuracy_prediction import PredictedAccuracy, predicted_accuracy
from .estimator_spec import EstimatorSpec
from .fit_test import (
    CANNOT_IDENTIFY,
    FitTest,
    _chi2_cause,
    _chi2_verdict,
    _degenerate,
    _plausible_limit,
    fit_check,
    leg_readings,
    size_test,
)
from .implicit_loop import (
    _check_noise,
    _component_columns,
    loop_jacobians,
    reading_names,
    sigma_matrix,
)
from .measurements import Measurements, tool_point
from .noise import Noise
from .problem import Problem, _check_joint_types
from .result import IdentificationResult, Outlier
from .robot import Robot

__all__ = [
    "COMPONENTS",
    "FitTest",
    "Outlier",
    "PredictedAccuracy",
    "VarianceComponent",
    "efficient",
    "fit_check",
    "loop_jacobians",
    "predicted_accuracy",
    "reading_names",
    "sigma_matrix",
    "summary",
]

#: The variance components, named as the fields of :class:`iwr.Noise`.
COMPONENTS = ("legs", "joint_lengths", "joint_angles", "position", "orientation")


@dataclass(frozen=True)
class VarianceComponent:
    """One estimated variance component.

    Attributes
    ----------
    name : str
        A field of :class:`iwr.Noise`.
    sigma : float
        The estimate (mm or rad).
    start : float
        The starting value.
    redundancy : float
        The share of the redundancy carried by its readings (sum of their redundancy numbers).
    std : float
        Approximate standard deviation of ``sigma`` (``sigma / sqrt(2 redundancy)``; ignores the
        correlation between components).
    identified : bool
        False when its readings carry (almost) no redundancy, or the estimate collapsed to zero: the
        data do not separate it from the other components; it is then held at ``start``.
    """

    name: str
    sigma: float
    start: float
    redundancy: float
    std: float
    identified: bool


def pose_misclosures(robot: Robot, measurements: Measurements, x: Any, noise: Any = None) -> Any:
    """:class:`iwr.misclosures.Misclosures` of pose data at ``x``: the six leg residuals of eq.
    (10) per pose (a leg weighted 0 left out), their derivatives in the parameters and in every
    reading (:func:`reading_names`: the leg readings, the joints, the measured position and
    orientation, from :func:`loop_jacobians`), the readings' covariance under ``noise``
    (:func:`sigma_matrix`), or, without one, eq. (10)'s metric ``1 / w`` per leg."""
    from .misclosures import Misclosures

    legs, jx, jy = loop_jacobians(robot, x, measurements.q, measurements.poses,
                                  data=measurements)
    n = len(measurements)
    r = legs - measurements.legs
    b = np.concatenate([np.broadcast_to(-np.eye(6), (n, 6, 6)), jy], axis=2)
    w = measurements.weights
    if w is not None:
        r = np.where(w > 0, r, np.nan)
    names = reading_names(robot)
    if noise is not None:
        if not isinstance(noise, Noise):
            raise TypeError(f"noise: expected an iwr.Noise or None, got {type(noise).__name__}")
        _check_noise(noise)
        sig = sigma_matrix(robot, measurements, noise)
        return Misclosures(r, jx, b, names, names[:6], reading_cov=np.einsum(
            "ki,ij->kij", sig**2, np.eye(sig.shape[1])))
    metric = None
    if w is not None:
        metric = np.einsum("ki,ij->kij", 1.0 / np.where(w > 0, w, 1.0), np.eye(6))
    return Misclosures(r, jx, b, names, names[:6], metric=metric)


def _as_noise(noise: Any) -> tuple[Noise, tuple[str, ...]]:
    """The starting noise model and the components to estimate."""
    if isinstance(noise, str):
        if noise != "estimate":
            raise ValueError(f"noise: {noise!r}; expected an iwr.Noise or 'estimate'")
        return Noise.realistic(), COMPONENTS
    if not isinstance(noise, Noise):
        raise TypeError(f"noise: expected an iwr.Noise or 'estimate', got {type(noise).__name__}")
    return noise, ()


def efficient(
    robot: Robot,
    measurements: Any,
    noise: Any,
    *,
    x0: Any = None,
    active: Any = None,
    callback: Callable[[OptimizeResult], Any] | None = None,
    estimate: Sequence[str] | None = None,
    outliers: str = "remove",
    outlier_alpha: float = 1e-3,
    max_outlier_fraction: float = 0.2,
    fit_alpha: float = 1e-3,
    plausible: float = 10.0,
    max_iterations: int = 200,
    max_variance_iterations: int = 50,
    tool: Any = None,
    bounds: Any = None,
) -> IdentificationResult:
    """Identify the error parameters with every instrument weighted by its noise.

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    measurements : Measurements or iwr.tracker.TrackerMeasurements
        Pose data in {0}; or laser-tracker data (points or probe poses in {T}) for a robot with a
        tracker setup (docs/estimation.md, "Tracker data": the parameters then cover the setup's,
        the start is LM on the points from the registration guess, and ``x0``, ``active`` are
        of the full length).
    noise : Noise, (Noise, TrackerNoise) or "estimate"
        The standard deviation of each instrument (legs > 0; a 0 elsewhere makes that reading
        exact). ``"estimate"``: every component estimated from the data, starting from
        :meth:`iwr.Noise.realistic` (and ``TrackerNoise.leica()``). Tracker data take the pair,
        as :func:`iwr.simulate` does on such a robot.
    x0 : array_like, optional
        Starting point and value of the inactive parameters; default zeros (the nominal robot).
    active : array_like of bool, optional
        The parameters to identify; default the base parameters of :func:`iwr.identifiability`
        at ``x0`` (the unidentifiable ones are held at ``x0``, so the answer is unique and its
        covariance finite). They must be identifiable.
    callback : callable, optional
        SciPy's convention: ``callback(intermediate_result)`` after every accepted iteration, with
        an ``OptimizeResult`` holding ``x`` (all parameters), ``fun`` (the weighted cost), ``nfev``
        and ``nit``; a truthy return or ``StopIteration`` stops the solve, which then returns its
        current point with ``success=False``.
    estimate : sequence of str, optional
        Noise components to estimate from the data (names of :class:`iwr.Noise` fields), the
        others being held at ``noise``: e.g. ``("position", "orientation")`` when only the leg and
        joint noise is known. Default: none (all when ``noise="estimate"``). Tracker data:
        ``legs``, ``joint_lengths``, ``joint_angles``, ``tracker_distance``,
        ``tracker_transverse``, ``tracker_orientation`` (probe), or ``"tracker"`` for all of the
        tracker's.
    outliers : {"remove", "report", "off"}
        ``"remove"``: data snooping, one pose at a time: while the worst pose fails its test
        (``outlier_alpha``), it is reported and left out, and the solve is repeated. ``"report"``:
        every failing pose is reported, none is removed. ``"off"``: no test.
    outlier_alpha : float
        Significance level of each pose's chi-square test (default 0.001: 0.1 % of clean poses
        flagged).
    max_outlier_fraction : float
        More failing poses than this fraction is no longer a few gross errors but a model that
        does not fit: the removal stops and the fit is reported as bad.
    fit_alpha : float
        Significance level of the global chi-square test.
    plausible : float
        Identified errors beyond ``plausible`` times the default bounds (+-0.5 mm, +-0.5 degree)
        are reported as implausible (a model that does not fit).
    max_iterations : int
        Levenberg-Marquardt iterations per solve.
    max_variance_iterations : int
        Iterations of the variance component estimation.
    tool : array_like, shape (3,), optional
        Tool point in {5} for the predicted accuracy.
    bounds : (lower, upper), optional
        The parameters' expected range, for the plausibility test (``plausible`` times their
        half-width); default the default bounds. No bound is imposed on the solution.

    Returns
    -------
    IdentificationResult
        ``x``, ``fun`` (the weighted cost: sum of squared normalised corrections), ``nfev``,
        ``nit``, ``success`` (converged *and* the fit is sane), ``status`` (``"converged"``,
        ``"stopped"`` at the iteration limit, ``"callback"``, ``"failed"``: no step lowered the
        cost, or the model does not fit), ``solver_status`` (the C++ solver's code, see
        ``implicit_loop.hpp``), ``message``, and:
        ``fit`` (:class:`FitTest`), ``fit_ok``, ``verdict``, ``outliers`` (list of
        :class:`Outlier`), ``used`` (mask of the poses in the final solution), ``active``,
        ``covariance`` (active parameters), ``std`` (all parameters, nan where fixed),
        ``noise`` (the noise model used, estimated where asked), ``variance_components``,
        ``corrections`` (N, n_joints + 6; nan for removed poses), ``residuals`` and
        ``redundancy`` (N, 12 + n_joints, columns :func:`reading_names`), ``pose_statistic``,
        ``predicted`` (:class:`PredictedAccuracy` on the calibration poses), ``cost_eq10``.
    """
    start_time = time.perf_counter()
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
    kind = kinds.of(measurements)
    if outliers not in ("remove", "report", "off"):
        raise ValueError(f"outliers: {outliers!r}; expected 'remove', 'report' or 'off'")
    for name, v, lo, hi in (("outlier_alpha", outlier_alpha, 0, 1), ("fit_alpha", fit_alpha, 0, 1),
                            ("max_outlier_fraction", max_outlier_fraction, 0, 1)):
        if not (isinstance(v, (int, float)) and lo < v < hi) and not (
                name == "max_outlier_fraction" and v == 0):
            raise ValueError(f"{name}: {v!r}; expected a number in ({lo}, {hi})")
    if not (isinstance(plausible, (int, float)) and plausible > 0):
        raise ValueError(f"plausible: {plausible!r}; expected a number > 0")
    for name, v in (("max_iterations", max_iterations),
                    ("max_variance_iterations", max_variance_iterations)):
        # At most the C++ int they are passed as (pybind11 refuses a larger one with a dump
        # of the signature, not naming it).
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v < 2**31:
            raise ValueError(f"{name}: {v!r}; expected an integer from 1 to {2**31 - 1}")
    if tool is not None:  # checked before the solve, which a bad one would only end
        tool = tool_point(tool)
    # The kind's model of its readings, their noise and the nuisance unknowns per pose.
    spec = kind.estimator(robot, measurements, noise, x0=x0, active=active, estimate=estimate,
                          bounds=bounds, plausible=plausible)
    return _estimate(spec, start_time, callback=callback, outliers=outliers,
                     outlier_alpha=outlier_alpha, max_outlier_fraction=max_outlier_fraction,
                     fit_alpha=fit_alpha, plausible=plausible, max_iterations=max_iterations,
                     max_variance_iterations=max_variance_iterations, tool=tool)


def _check_estimate(estimate: Sequence[str] | None, est: tuple[str, ...],
                    components: Sequence[str], aliases: dict[str, tuple[str, ...]] | None = None
                    ) -> tuple[str, ...]:
    if estimate is None:
        return est
    if isinstance(estimate, str):
        raise TypeError(f"estimate: {estimate!r}; expected a sequence of component names, e.g. "
                        f"({estimate!r},)")
    aliases = aliases or {}
    bad = [c for c in estimate if c not in components and c not in aliases]
    if bad:
        raise ValueError(f"estimate: unknown component(s) {bad}; expected names among "
                         f"{', '.join(list(components) + list(aliases))}")
    out: list[str] = []
    for c in estimate:
        out += list(aliases.get(c, (c,)))
    return tuple(dict.fromkeys(out))


class _PoseSpec(EstimatorSpec):
    """What the estimation loop (:func:`_estimate`) needs to know of pose-in-{0} data: the
    solve, the readings' names and variance components, the plausibility test, the predicted
    accuracy (:class:`iwr.estimator_spec.EstimatorSpec` holds what every kind's spec shares;
    the tracker kinds have theirs in :mod:`iwr.tracker.estimation`)."""

    kind = "pose"

    def __init__(self, robot: Robot, measurements: Measurements, noise: Any, x0: Any,
                 active: Any, estimate: Any, bounds: Any, plausible: float) -> None:
        _check_joint_types(robot, measurements)
        noise0, est = _as_noise(noise)
        est = _check_estimate(estimate, est, COMPONENTS)
        _check_noise(noise0)
        self.robot, self.measurements, self.noise0 = robot, measurements, noise0
        self.n = len(measurements)
        x0_arr = np.zeros(robot.n_params) if x0 is None else np.array(x0, dtype=float)
        if x0_arr.shape != (robot.n_params,) or not np.all(np.isfinite(x0_arr)):
            raise ValueError(f"x0: expected {robot.n_params} finite values, got shape "
                             f"{x0_arr.shape}")
        self.x_start = x0_arr
        self.mask = _active_mask(active, robot.n_params, lambda: kinds.of(
            measurements).identifiability(robot, measurements, x0_arr).active)
        self.cols = _component_columns(robot)
        self.sigma_all = sigma_matrix(robot, measurements, noise0)
        # Which components to estimate: only those with readings (and not exact).
        self.est = tuple(c for c in est if self.cols[c].size and getattr(noise0, c) > 0)
        self.names = reading_names(robot)
        self.parameter_names = robot.parameter_names
        self.ny = robot.n_joints + 6
        self.limit = _plausible_limit(robot, plausible, bounds)

    def start_sigma(self, c: str) -> float:
        return float(getattr(self.noise0, c))

    def solve(self, x: np.ndarray, idx: list[int], used: np.ndarray, scale: dict[str, float],
              corr: np.ndarray, max_iterations: int, cb: Any) -> dict[str, Any]:
        s = self.sigma_all.copy()
        for c, f in scale.items():
            s[:, self.cols[c]] *= f
        m = self.subset(used)
        return _core.implicit_loop(
            self.robot._geometry, x, idx, m.q, m.poses, m.legs, np.ascontiguousarray(s[used]),
            np.ascontiguousarray(corr), max_iterations=int(max_iterations), callback=cb)

    def plausibility_model(self, used: np.ndarray) -> Any:
        return leg_readings(self.robot, self.subset(used))

    def noise_used(self, sigmas: dict[str, float]) -> Any:
        return replace(self.noise0, **sigmas)

    def predicted(self, x: np.ndarray, cov: np.ndarray, used: np.ndarray,
                  tool: Any) -> PredictedAccuracy:
        return predicted_accuracy(self.robot, self.subset(used), x, cov, active=self.mask,
                                  tool=tool)

    def cost_eq10(self, x: np.ndarray) -> float:
        return Problem(self.robot, self.measurements).cost(x)


def _active_mask(active: Any, n_params: int, default: Callable[[], np.ndarray]) -> np.ndarray:
    if active is None:
        with single_thread():
            return np.asarray(default(), dtype=bool)
    mask = np.asarray(active)
    if mask.dtype != bool or mask.shape != (n_params,):
        raise ValueError(f"active: expected a boolean mask of shape ({n_params},), got "
                         f"{mask.dtype} of shape {mask.shape}")
    if not mask.any():
        raise ValueError("active: no parameter is active")
    return mask


def _estimate(spec: Any, start_time: float, *, callback: Any, outliers: str,
              outlier_alpha: float, max_outlier_fraction: float, fit_alpha: float,
              plausible: float, max_iterations: int, max_variance_iterations: int,
              tool: Any) -> IdentificationResult:
    """The estimation loop shared by every measurement kind: solves, variance components,
    data snooping, the fit test and the result."""
    n = spec.n
    mask = spec.mask
    idx = [int(i) for i in np.flatnonzero(mask)]
    p = len(idx)
    cols = spec.cols
    est = spec.est
    scale = {c: 1.0 for c in est}
    used = np.ones(n, dtype=bool)
    corr = np.zeros((n, spec.ny))
    x = spec.x_start.copy()
    stopped = {"flag": False}
    totals = {"nfev": 0, "nit": 0}

    def cb(it: int, xx: np.ndarray, cost: float) -> bool:
        if callback is None:
            return False
        inter = OptimizeResult(x=np.array(xx), fun=float(cost), nfev=totals["nfev"] + it,
                               nit=totals["nit"] + it)
        try:
            stop = bool(callback(inter))
        except StopIteration:
            stop = True
        stopped["flag"] = stopped["flag"] or stop
        return stop

    last: dict[str, Any] = {}  # the state of the last completed solve (for Ctrl-C)

    def solve() -> dict[str, Any]:
        nonlocal x, corr
        out = spec.solve(x, idx, used, scale, corr[used], max_iterations,
                         cb if callback is not None else None)
        totals["nfev"] += int(out["nfev"])
        totals["nit"] += int(out["iterations"])
        x = np.array(out["x"])
        corr[used] = out["corrections"]
        last.update(out=out, used=used.copy(), x=x.copy(), corr=corr.copy(), scale=dict(scale))
        return out

    components: list[VarianceComponent] = []

    def solve_with_variances() -> dict[str, Any]:
        out = solve()
        if not est or stopped["flag"]:
            return out
        frozen: set[str] = set()
        for _ in range(int(max_variance_iterations)):
            change = 0.0
            for c in est:
                if c in frozen:
                    continue
                red = float(np.sum(out["redundancy"][:, cols[c]]))
                omega = float(np.sum(out["residuals"][:, cols[c]] ** 2))
                f = math.sqrt(omega / red) if red > 0 else 0.0
                # (Almost) no redundancy, or collapsed towards zero: the data do not separate it
                # from the others; hold it at its starting value (and solve again with it).
                if red < 1.0 or f < 1e-6:
                    frozen.add(c)
                    if scale[c] != 1.0:
                        scale[c] = 1.0
                        change = max(change, 1.0)
                    continue
                # Foerstner: sigma^2 <- sigma^2 Omega_c / r_c.
                scale[c] *= f
                change = max(change, abs(f - 1.0))
            out = solve()
            if change < 1e-4 or stopped["flag"]:
                break
        components.clear()
        for c in est:
            red = float(np.sum(out["redundancy"][:, cols[c]]))
            s = spec.start_sigma(c) * scale[c]
            components.append(VarianceComponent(
                c, s, spec.start_sigma(c), red, s / math.sqrt(2 * red) if red > 0 else math.inf,
                c not in frozen))
        return out

    crit_dof: dict[int, float] = {}

    def test_poses(o: dict[str, Any]) -> list[tuple[Any, ...]]:
        rows = np.flatnonzero(used)
        names = spec.names
        bad = []
        for r_i, k in enumerate(rows):
            t, d = float(o["pose_statistic"][r_i]), int(o["pose_dof"][r_i])
            if d < 1:
                continue
            if d not in crit_dof:
                crit_dof[d] = float(special.chdtri(d, outlier_alpha))
            if t > crit_dof[d]:
                red = o["redundancy"][r_i]
                w = np.where(red > 1e-10,
                             o["residuals"][r_i] / np.sqrt(np.maximum(red, 1e-300)), 0.0)
                j = int(np.argmax(np.abs(w)))
                alt = tuple(names[i] for i in np.flatnonzero(np.abs(w) >= 0.99 * abs(w[j]))
                            if i != j)
                bad.append((int(k), t, d, float(special.chdtrc(d, t)), names[j], float(w[j]), alt))
        return bad

    found: list[Outlier] = []
    too_many = False
    interrupted = False
    try:
        out = solve_with_variances()
        if outliers != "off" and not stopped["flag"]:
            cap = int(math.floor(max_outlier_fraction * n))
            while True:
                bad = test_poses(out)
                if not bad:
                    break
                if outliers == "report":
                    found = [Outlier(k, spec.where(k), t, d, pv, ins, w, False, alt,
                                       line=spec.line(k), key=spec.key(k))
                             for k, t, d, pv, ins, w, alt in bad]
                    too_many = len(bad) > cap
                    break
                if len(found) >= cap:
                    # More failing poses than gross errors can explain: report them, stop
                    # removing. (Not decided on the first round's count: a few 1 mm errors among
                    # 2 um readings distort the first solution so much that most clean poses fail
                    # with them.)
                    too_many = True
                    found += [Outlier(k, spec.where(k), t, d, pv, ins, w, False, alt,
                                       line=spec.line(k), key=spec.key(k))
                              for k, t, d, pv, ins, w, alt in bad]
                    break
                k, t, d, pv, ins, w, alt = max(bad, key=lambda b: b[1] / crit_dof[b[2]])
                found.append(Outlier(k, spec.where(k), t, d, pv, ins, w, True, alt,
                                       line=spec.line(k), key=spec.key(k)))
                used[k] = False
                corr[k] = 0.0
                if int(out["dof"]) - int(out["pose_dof"][int(np.sum(used[:k]))]) <= 0:
                    too_many = True
                    break
                out = solve_with_variances()
                if stopped["flag"]:
                    break

    except KeyboardInterrupt:
        # Ctrl-C: the result of the last completed solve, marked interrupted (nothing to return
        # before the first one has finished).
        if "out" not in last:
            raise
        interrupted = True
        out, x = last["out"], last["x"]
        used[:] = last["used"]
        corr[:] = last["corr"]
        scale.update(last["scale"])
        found = [replace(o, removed=False) if o.removed and used[o.pose] else o for o in found]
        components[:] = [VarianceComponent(c, spec.start_sigma(c) * scale[c], spec.start_sigma(c),
                                           math.nan, math.nan, False) for c in est]

    # --- the verdict ---------------------------------------------------------------------------
    dof = int(out["dof"])
    statistic = float(out["cost"])
    p_value = float(special.chdtrc(dof, statistic)) if dof > 0 else math.nan
    converged = int(out["status"]) > 0 and not stopped["flag"] and not interrupted
    causes: list[str] = []
    names = spec.parameter_names
    # the size test weighs departures from the plausible size by the estimate's spread
    covariance = np.zeros((mask.size, mask.size))
    covariance[np.ix_(mask, mask)] = np.asarray(out["covariance"], dtype=float)
    sd = np.sqrt(np.clip(np.diag(covariance), 0, None))
    sd[~mask] = np.nan
    implausible, size_causes, size_failed, size_notes = size_test(
        getattr(spec, "robot", None), names, x,
        spec.implausible(x, used, covariance, fit_alpha), plausible, sd, fit_alpha)
    rank_ok = float(out["reciprocal_condition"]) > 1e-13
    if not rank_ok:
        causes.append(
            f"the active parameters are not all identifiable (reciprocal condition "
            f"{out['reciprocal_condition']:.1e}): hold the unidentifiable ones fixed "
            "(active=iwr.identifiability(...).active, the default)")
    chi_ok = bool(dof > 0 and p_value >= fit_alpha)
    if dof <= 0:
        causes.append(f"no redundancy: {dof + p} independent readings for {p} parameters; "
                      "measure more poses")
    elif not chi_ok:
        causes.append(_chi2_cause(statistic, dof, p_value, spec.misfit_causes))
    causes += size_causes
    if too_many:
        causes.append(
            f"{len(found)} poses fail the outlier test (more than {max_outlier_fraction:.0%} of "
            f"{n}): not a few gross errors but a model or noise model that does not fit")
    for c in components:
        if c.identified and c.sigma > 10 * c.start:
            causes.append(f"the noise of {c.name} is estimated at {c.sigma:.3g}, "
                          f"{c.sigma / c.start:.0f} times the stated {c.start:.3g}: the model may "
                          "not fit, or that instrument is much worse than stated")
    # Data that cannot identify the robot (copies of a few poses): no fit says anything.
    degenerate = (_degenerate(spec.robot, spec.subset(used), mask)
                  if hasattr(spec, "robot") else None)
    if degenerate is not None:
        causes.insert(0, degenerate)
    fit_ok = chi_ok and rank_ok and not implausible and not too_many and degenerate is None
    notes: list[str] = []
    if dof > 0 and chi_ok and special.chdtr(dof, statistic) < fit_alpha:
        notes.append(f"the weighted residual sum {statistic:.4g} is far below its expectation "
                     f"{dof}: the noise model is pessimistic (the data are better than stated)")
    if est:
        notes.append("noise estimated for " + ", ".join(est) + ": the chi-square test checks "
                     "only what the estimate leaves free")
    notes += size_notes
    failed = [what for what, bad in (
        ("the active parameters are not all identifiable", not rank_ok),
        *((what, True) for what in size_failed),
        ("too many poses fail the outlier test", bool(too_many))) if bad] if chi_ok else None
    verdict = (CANNOT_IDENTIFY if degenerate is not None else
               _chi2_verdict(statistic, dof, p_value, fit_ok, "no degrees of freedom", failed))
    fit = FitTest(statistic, dof, p_value, float(fit_alpha), bool(fit_ok), verdict,
                  causes if not fit_ok else notes, implausible)

    # The statuses of iwr's results: "converged" only when the solver converged *and* the fit is
    # sane; a model that does not fit is "failed" whatever the solver said.
    solver_status = int(out["status"])
    if interrupted:
        status = "interrupted"
        message = "interrupted (Ctrl-C): the result of the last completed solve"
    elif stopped["flag"]:
        status, message = "callback", "stopped by the callback"
    elif not converged:
        status = "stopped" if solver_status == 0 else "failed"
        message = str(out["message"])
        if status == "stopped":  # the iteration limit: the test is of the point it stopped at
            fit = fit.stopped()
            verdict = fit.verdict
        if not fit_ok:
            message += "; the model does not fit the data" + (
                f": chi2 = {statistic:.4g} for {dof} degrees of freedom (p = {p_value:.2g})"
                if dof > 0 else "")
    elif degenerate is not None:
        status, message = "failed", f"solved, but the data cannot identify the robot: {degenerate}"
    elif not fit_ok:
        status, message = "failed", "solved, but the model does not fit the data" + (
            f": chi2 = {statistic:.4g} for {dof} degrees of freedom (p = {p_value:.2g})"
            if dof > 0 else "") + ("; implausible parameters" if implausible else "")
    else:
        status, message = "converged", str(out["message"])
    success = bool(converged and fit_ok)

    cov = np.array(out["covariance"])
    std = np.full(mask.size, np.nan)
    std[mask] = np.sqrt(np.clip(np.diag(cov), 0, None))
    nr = len(spec.names)
    residuals = np.full((n, nr), np.nan)
    redundancy = np.full((n, nr), np.nan)
    pose_stat = np.full(n, np.nan)
    residuals[used] = out["residuals"]
    redundancy[used] = out["redundancy"]
    pose_stat[used] = out["pose_statistic"]
    corrections = corr.copy()
    corrections[~used] = np.nan
    noise_used = spec.noise_used({c.name: c.sigma for c in components})
    try:
        predicted = spec.predicted(x, cov, used, tool)
    except np.linalg.LinAlgError as exc:
        # A singular leg Jacobian (a hexapod singularity) at some pose.
        predicted = None
        fit.causes.append(f"predicted accuracy unavailable: {exc}")
    return IdentificationResult(
        x=x,
        fun=statistic,
        nfev=totals["nfev"],
        nit=totals["nit"],
        success=success,
        status=status,
        solver_status=solver_status,
        message=message,
        method="efficient",
        fit=fit,
        verdict=verdict,
        outliers=found,
        used=used,
        active=mask,
        covariance=cov,
        std=std,
        noise=noise_used,
        variance_components=components,
        corrections=corrections,
        residuals=residuals,
        redundancy=redundancy,
        reading_names=list(spec.names),
        pose_statistic=pose_stat,
        predicted=predicted,
        cost_eq10=spec.cost_eq10(x),
        parameter_names=names,
        history={"nfev": np.array([totals["nfev"]]), "best": np.array([statistic])},
        wall_time=time.perf_counter() - start_time,
        settings={"noise": spec.noise_dict(spec.noise0), "estimate": list(est),
                  "outliers": outliers,
                  "outlier_alpha": outlier_alpha, "max_outlier_fraction": max_outlier_fraction,
                  "fit_alpha": fit_alpha, "plausible": plausible,
                  "max_iterations": max_iterations,
                  "max_variance_iterations": max_variance_iterations},
    )


def summary(result: IdentificationResult) -> dict[str, Any]:
    """What :func:`efficient` adds to an identification result, JSON-able (for a result file or a
    report): the fit test, the outliers, the noise used, the variance components, the predicted
    accuracy and the standard deviations of the parameters (null for those held fixed).
    ValueError for another result, or one read back from a file (which keeps only the fit test
    and the outliers)."""
    if result.method != "efficient" or result.used is None or result.fit is None:
        raise ValueError("summary: not a result of the efficient estimator held in memory (a "
                         "result file keeps its fit test and outliers only: result.fit, "
                         "result.outliers)")
    fit: FitTest = result.fit
    pred: PredictedAccuracy | None = result.predicted
    noise = result.noise
    return jsonable({
        "fit": fit.to_dict(),
        "outliers": [asdict(o) for o in result.outliers or []],
        "n_poses_used": int(np.sum(result.used)),
        "noise": (asdict(noise) if isinstance(noise, Noise) else
                  # the instrument's own noise by its name: "tracker", "ballbar"
                  {"readings": asdict(noise[0]),
                   type(noise[1]).__name__.removesuffix("Noise").lower(): asdict(noise[1])}),
        "variance_components": [asdict(c) for c in result.variance_components or []],
        "predicted": None if pred is None else {
            "position_rms_mm": pred.position_rms, "position_95_mm": pred.position_95,
            "orientation_rms_deg": pred.orientation_rms,
            "orientation_95_deg": pred.orientation_95},
        "std": result.std,
        "cost_eq10": result.cost_eq10,
    }, finite_only=True)
