"""The public API on double-ballbar data: what :func:`iwr.identify`, :func:`iwr.accuracy`,
:func:`iwr.identifiability` and :func:`iwr.uncertainty` do when the robot describes ballbar
set-ups (a ``[ballbar]`` table, ``Robot.with_instrument("ballbar", ...)``) and the data are
:class:`BallbarMeasurements` (docs/ballbar.md)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy import special
from scipy.optimize import least_squares

from .. import kinds
from ..analysis.accuracy import Accuracy, PoseErrors, pose_errors
from ..analysis.uncertainty import Uncertainty
from ..fit_test import _chi2_cause, _chi2_verdict
from ..robot import Robot
from ..tracker.analysis import NullSpace, null_space
from ..transforms import pose_from_matrix, rotvec_matrix
from .data import BallbarMeasurements
from .problem import BallbarProblem
from .setup import MISFIT_CAUSES, BallbarSetup
from .simulate import split_noise

__all__ = ["ballbar_setup", "ballbar_problem", "reading_sensitivities", "reading_sigmas",
           "ballbar_misclosures", "ballbar_reading_names", "ballbar_identify",
           "ballbar_accuracy", "ballbar_identifiability", "ballbar_uncertainty",
           "gauge_aligned", "reading_std"]


#: The relative rank threshold of the null-space analysis: the structural null directions of
#: ballbar problems give scaled singular values of ~5e-14 (round-off, above NumPy's default
#: ``max(shape) * eps`` at a few hundred poses), the weakest identifiable ones ~1e-4.
NULL_RTOL = 1e-10


def ballbar_setup(robot: Robot) -> BallbarSetup:
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
    setup = robot.instruments.get("ballbar")
    if setup is None:
        raise ValueError(f"robot {robot.name!r}: no ballbar set-ups; describe them with a "
                         "[ballbar] table in the robot's TOML file or robot.with_instrument("
                         "'ballbar', iwr.ballbar.BallbarSetup(...)) (docs/ballbar.md)")
    return setup


def _full_x(robot: Robot, setup: BallbarSetup, x: Any, name: str = "x") -> np.ndarray:
    n = robot.n_params + setup.n_params
    arr = np.zeros(n) if x is None else np.array(x, dtype=float)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: expected {n} finite values (the robot's {robot.n_params}, "
                         f"then the ballbar set-ups' {setup.n_params}), got shape {arr.shape}")
    return arr


def ballbar_problem(robot: Robot, measurements: BallbarMeasurements, bounds: Any = None,
                    x0: Any = None) -> tuple[BallbarProblem, np.ndarray]:
    """The problem for these data and its start (``x0``, default zeros: the nominal robot and
    the nominal set-ups). ``bounds``: None or "default", "paper" (the robot's Table 2 bounds,
    the set-ups' default ones) or a pair (lower, upper)."""
    setup = ballbar_setup(robot)
    if isinstance(bounds, str):
        if bounds not in ("default", "paper"):
            raise ValueError(f"bounds: {bounds!r}; expected None, 'default', 'paper' or "
                             "(lower, upper)")
        lo_r, hi_r = robot.default_bounds(bounds)
        lo_s, hi_s = setup.default_bounds()
        bounds = (np.concatenate([lo_r, lo_s]), np.concatenate([hi_r, hi_s]))
    problem = BallbarProblem(robot, setup, measurements, bounds)
    return problem, _full_x(robot, setup, x0, "x0")


def reading_sensitivities(problem: BallbarProblem, jac: np.ndarray) -> np.ndarray:
    """Each pose's residual's derivatives (N, 6 + n_joints) in its leg readings, then its joint
    readings, from the unweighted Jacobian ``jac``: a leg reading adds to the leg length as the
    leg offset ``dl0`` does, a joint reading to ``d`` (prismatic) or ``theta`` (revolute) as the
    joint's error does, so they are those columns (exact, no finite differences)."""
    names = problem.robot.parameter_names
    cols = [names.index(f"leg{j + 1}.dl0") for j in range(6)]
    cols += [names.index(f"joint{i + 1}.{'dd' if t == 'P' else 'dtheta'}")
             for i, t in enumerate(problem.robot.joint_types)]
    return jac[:, cols]


def ballbar_reading_names(robot: Robot) -> list[str]:
    """Names of the readings of one pose: ``leg1 .. leg6``, ``q1 .. qn``, ``distance`` (the
    bar)."""
    return ([f"leg{j + 1}" for j in range(6)] + [f"q{i + 1}" for i in range(robot.n_joints)]
            + ["distance"])


def _reading_variances(robot: Robot, noise: Any) -> np.ndarray:
    """The variances (6 + n_joints + 1,) of a pose's leg, joint and bar readings under
    ``noise`` (:func:`split_noise`; a part not given: 0)."""
    readings, bar = split_noise(noise)
    var = np.zeros(7 + robot.n_joints)
    if readings is not None:
        var[:6] = readings.legs**2
        var[6:-1] = [(readings.joint_lengths if t == "P" else readings.joint_angles) ** 2
                     for t in robot.joint_types]
    var[-1] = 0.0 if bar is None else bar.distance**2
    return var


def reading_sigmas(problem: BallbarProblem, x: Any, noise: Any) -> np.ndarray:
    """Each pose's residual standard deviation (mm) at ``x``, to first order: the bar's sigma
    and the leg and joint readings' propagated through the model
    (:func:`reading_sensitivities`)."""
    unweighted = problem.with_weights(None) if np.any(problem.weights != 1) else problem
    var_readings = _reading_variances(problem.robot, noise)
    sens = reading_sensitivities(problem, unweighted.jacobian(x))
    var = var_readings[-1] + sens**2 @ var_readings[:-1]
    if not np.all(var > 0):
        raise ValueError(f"noise: {noise!r} gives a reading of zero variance; the bar's noise "
                         "must be > 0 (iwr.ballbar.BallbarNoise(distance=...))")
    return np.sqrt(var)


def ballbar_misclosures(robot: Robot, measurements: BallbarMeasurements, x: Any,
                        noise: Any = None) -> Any:
    """:class:`iwr.misclosures.Misclosures` of ballbar data at ``x`` (robot then set-ups), for
    the gross-error test: one component per pose, the predicted minus measured bar reading (NaN
    where the forward kinematics fails), its derivatives in the parameters and in every reading
    (the legs and joints, :func:`reading_sensitivities`; the bar's, -1); with ``noise``
    (:func:`split_noise`) the readings' covariance, without it the unit metric (the noise then
    estimated from the residuals)."""
    problem, x = ballbar_problem(robot, measurements, x0=x)
    return misclosures_on(problem, x, noise)


def misclosures_on(problem: Any, x: np.ndarray, noise: Any) -> Any:
    """:func:`ballbar_misclosures` of ``problem`` (a :class:`BallbarProblem`, or the objective
    with the effects, :class:`iwr.ballbar.effects.BallbarEffectProblem`) at ``x``."""
    from ..misclosures import Misclosures

    robot, measurements = problem.robot, problem.measurements
    r, jac = problem.residuals_and_jacobian(x)
    failed = np.zeros(len(measurements), dtype=bool)
    failed[[k for k, _ in problem.failures(x)]] = True
    r = np.where(failed, np.nan, r)
    b = np.concatenate([reading_sensitivities(problem, jac),
                        -np.ones((len(measurements), 1))], axis=1)[:, None, :]
    names = ballbar_reading_names(robot)
    if noise is None:
        return Misclosures(r[:, None], jac[:, None, :], b, names, ["distance"])
    var = _reading_variances(robot, noise)
    if not var[-1] > 0 and not var[:-1].any():
        raise ValueError(f"noise: {noise!r}; every reading's variance is 0")
    cov = np.broadcast_to(np.diag(var), (len(measurements), var.size, var.size))
    return Misclosures(r[:, None], jac[:, None, :], b, names, ["distance"], reading_cov=cov)


def plausible_limits(problem: BallbarProblem, plausible: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Each parameter's plausible size and centre for the plausibility test of a fit:
    ``plausible`` times the half-width of the problem's bounds, about their middle."""
    centre = 0.5 * (problem.lower + problem.upper)
    return plausible * 0.5 * (problem.upper - problem.lower), centre


def weighted_problem(problem: BallbarProblem, x0: np.ndarray, noise: Any) -> BallbarProblem:
    """``problem`` weighted by ``noise``: each distance by its standard deviation at ``x0``."""
    return problem.with_weights(1.0 / reading_sigmas(problem, x0, noise), noise=noise)


def ballbar_identify(robot: Robot, measurements: BallbarMeasurements, method: str, *,
                     noise: Any = None, weighted: bool | None = None, bounds: Any = None,
                     x0: Any = None, active: Any = None, max_evaluations: int | None = None,
                     seed: int | None = None, callback: Callable[..., Any] | None = None,
                     progress: bool | None = None, **options: Any) -> Any:
    """:func:`iwr.identify` on ballbar data: ``"efficient"``, the implicit-loop estimator
    (:mod:`iwr.ballbar.estimation`, through :func:`iwr.estimation.efficient`; ``noise`` the
    pair or ``"estimate"``), or another method on the distance objective, from the nominal robot
    and set-ups (default ``x0``). With a noise model (``(iwr.Noise, BallbarNoise)``, or either
    alone) the residuals are weighted by their
    first-order standard deviations at ``x0`` (:func:`reading_sigmas`; ``weighted=False``: not),
    and the fit gets a chi-square test of the weighted cost. ``active="base"``: one parameter
    per null direction held at ``x0`` (:func:`ballbar_identifiability`). DE runs on the
    problem's C++ objective (:attr:`BallbarProblem.objective`, the engine's) and is polished by
    LM."""
    return ballbar_identify_with(
        robot, measurements, method, lambda: ballbar_problem(robot, measurements, bounds, x0),
        lambda problem, start: null_space(problem, start, NULL_RTOL).active, noise=noise,
        weighted=weighted, bounds=bounds, x0=x0, active=active,
        max_evaluations=max_evaluations, seed=seed, callback=callback, progress=progress,
        **options)


def ballbar_identify_with(robot: Robot, measurements: BallbarMeasurements, method: str,
                          make: Callable[[], Any], base: Callable[[Any, np.ndarray], np.ndarray],
                          *, noise: Any, weighted: bool | None, bounds: Any, x0: Any,
                          active: Any, max_evaluations: int | None, seed: int | None,
                          callback: Callable[..., Any] | None, progress: bool | None,
                          **options: Any) -> Any:
    """:func:`ballbar_identify` on the distance objective that ``make()`` gives with its start
    (:func:`ballbar_problem`, or the objective with the effects,
    :func:`iwr.ballbar.effects.effect_problem`); ``active="base"``: ``base(problem, start)``,
    the base parameters' mask."""
    from ..methods import run_method, settle
    from ..methods.reduced import active_mask

    if method == "efficient":
        # Every reading weighted by its noise, the platform poses and true joint readings as
        # nuisance unknowns (docs/ballbar.md, "The efficient estimator"): its own start (the
        # weighted LM), base parameters and fit test.
        from ..methods.efficient import efficient_on

        return efficient_on(robot, measurements, noise, lambda: make()[0],
                            noise_hint="(iwr.Noise(...), iwr.ballbar.BallbarNoise(...))",
                            x0=x0, active=active, bounds=bounds, callback=callback,
                            weighted=weighted, max_evaluations=max_evaluations, **options)
    if isinstance(noise, str):
        raise ValueError(f"noise: {noise!r}; ballbar data take no estimated noise model: give "
                         "(iwr.Noise(...), iwr.ballbar.BallbarNoise(...))")
    split_noise(noise)  # checked here, before any work
    if weighted is None:
        weighted = noise is not None
    elif weighted and noise is None:
        raise ValueError("weighted=True needs a noise model: noise=(iwr.Noise(...), "
                         "iwr.ballbar.BallbarNoise(...))")
    problem, start = make()
    if weighted:
        problem = weighted_problem(problem, start, noise)
    if isinstance(active, str) and active == "base":
        active = base(problem, start)
    mask = active_mask(problem, active)
    result = run_method(problem, method, mask, start, max_evaluations=max_evaluations,
                        seed=seed, callback=callback, progress=progress,
                        **options)
    if weighted:
        result["settings"] = {**dict(result.settings),
                              "objective": {"weighted": True,
                                            **kinds.of(measurements).noise_record(noise)}}
    settle(result, problem, None, mask)
    if weighted and result.status != "interrupted" and np.all(np.isfinite(result.x)):
        _chi2(result, problem, mask)
    return result


def _chi2(result: Any, problem: BallbarProblem, mask: np.ndarray,
          alpha: float = 1e-3) -> None:
    """The chi-square test of the weighted cost (the residuals are whitened by their
    first-order sigmas): ``dof = N`` minus the rank of the active columns."""
    fit = result["fit"]
    jac = problem.jacobian(result.x)[:, mask]
    d = np.linalg.norm(jac, axis=0)
    s = np.linalg.svd(jac / np.where(d > 0, d, 1.0), compute_uv=False)
    # the ballbar's rank threshold (NULL_RTOL): NumPy's counts its null directions at ~2e-14
    # (at 120 poses one more parameter, one degree of freedom less than the estimator's)
    rtol = max(NULL_RTOL, max(jac.shape) * np.finfo(float).eps)
    rank = int(np.sum(s > s[0] * rtol)) if s.size else 0
    dof = problem.n_residuals - rank
    stat = float(result["fun"])
    p_value = float(special.chdtrc(dof, stat)) if dof > 0 else math.nan
    ok = bool(dof > 0 and p_value >= alpha)
    # a passing fit's causes are notes (FitTest.causes): kept only while it passes
    causes = list(fit.causes) if (fit.fit_ok is False or ok) else []
    without_dof = (f"no redundancy: {problem.n_residuals} readings for {rank} identifiable "
                   "parameters")
    if not ok:
        causes.append(_chi2_cause(stat, dof, p_value, MISFIT_CAUSES) if dof > 0 else without_dof)
    fit_ok = bool(fit.fit_ok and ok)
    # the fit check's own verdict when only it failed (the size of the errors)
    verdict = _chi2_verdict(stat, dof, p_value, fit_ok, without_dof) if ok == fit_ok else (
        fit.verdict)
    result["fit"] = type(fit)(stat, dof, p_value, alpha, fit_ok, verdict, causes,
                              fit.implausible)
    if result.success and not fit_ok:
        result.update(success=False, status="failed",
                      message=f"{verdict} (the method: {str(result.message).strip()})")


# -- accuracy ---------------------------------------------------------------------------------
def _transform(v: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3], t[:3, 3] = rotvec_matrix(v[3:6][None])[0], v[:3]
    return t


def gauge_aligned(a: np.ndarray, b: np.ndarray, length: float = 100.0) -> np.ndarray:
    """The frames ``a`` (N, 4, 4) moved by the rigid motions ``G`` of the world frame and ``H``
    of the platform frame that best align ``G a_k H`` with ``b_k`` over all poses (least squares
    on the frames' origins and the tips of their axes ``length`` mm long): what a ballbar
    cannot see removed (docs/ballbar.md)."""
    def aligned(v: np.ndarray) -> np.ndarray:
        return _transform(v[:6]) @ a @ _transform(v[6:])

    tips = np.vstack([np.zeros(3), length * np.eye(3)]).T  # (3, 4): origin and the axis tips

    def residuals(v: np.ndarray) -> np.ndarray:
        m = aligned(v)
        return (m[:, :3, :3] @ tips + m[:, :3, 3:] - b[:, :3, :3] @ tips - b[:, :3, 3:]).ravel()

    fit = least_squares(residuals, np.zeros(12), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return aligned(fit.x)


def ballbar_accuracy(robot: Robot, measurements: BallbarMeasurements, x: Any, *,
                     truth: Any = None, tool: Any = None, **_: Any) -> Accuracy:
    """:func:`iwr.accuracy` on ballbar data, before (the nominal robot and set-ups) and after
    (``x``). Without ``truth``: per pose, ``position`` is the absolute reading residual
    ``|predicted - measured|`` (mm) and ``orientation`` NaN (a bar measures no orientation).
    With ``truth`` (a simulation's): tool pose errors against the true robot at the same
    readings, after the best rigid motion of the world frame and of the platform frame
    (:func:`gauge_aligned`), which ballbar data cannot determine."""
    setup = ballbar_setup(robot)
    x = _full_x(robot, setup, x)
    truth = None if truth is None else _full_x(robot, setup, truth, "truth")
    return accuracy_on(BallbarProblem(robot, setup, measurements), x, truth, tool)


def accuracy_on(problem: Any, x: Any, truth: Any, tool: Any) -> Accuracy:
    """:func:`ballbar_accuracy` on ``problem`` (a :class:`BallbarProblem`, or the objective with
    the effects, :class:`iwr.ballbar.effects.BallbarEffectProblem`: its ``residuals`` and
    ``platform_frames``), from its start (zeros) to ``x``; ``x`` and ``truth`` (or None)
    checked."""
    start = np.zeros(problem.n_params)
    if truth is None:
        def errors(xe: np.ndarray) -> PoseErrors:
            res = np.abs(problem.residuals(xe))
            return PoseErrors(res, np.full(res.size, np.nan),
                              pose_from_matrix(problem.platform_frames(xe)))

        return Accuracy(errors(start), errors(x))
    true = problem.platform_frames(truth)
    out = []
    for xe in (start, x):
        model = gauge_aligned(problem.platform_frames(xe), true)
        pos, ori = pose_errors(pose_from_matrix(model), pose_from_matrix(true), tool)
        out.append(PoseErrors(pos, ori, pose_from_matrix(model)))
    return Accuracy(*out)


def ballbar_identifiability(robot: Robot, measurements: BallbarMeasurements, x: Any = None, *,
                            rtol: float | None = None, **_: Any) -> NullSpace:
    """:func:`iwr.identifiability` on ballbar data: the null directions of the distance
    objective's column-scaled Jacobian at ``x`` (default: the nominal robot and set-ups), one
    per left-out parameter (:class:`iwr.tracker.NullSpace`); ``rtol`` default
    :data:`NULL_RTOL`."""
    problem, start = ballbar_problem(robot, measurements, x0=x)
    return null_space(problem, start, NULL_RTOL if rtol is None else rtol)


def ballbar_uncertainty(robot: Robot, measurements: BallbarMeasurements, x: Any, noise: Any,
                        *, active: Any = None, weighted: bool = False, **_: Any
                        ) -> Uncertainty:
    """:func:`iwr.uncertainty` on ballbar data: the covariance of the least-squares estimate of
    the active parameters, ``A Cov(r) A^T`` with ``A = (J^T J)^-1 J^T`` (eq. (10)-style, from the
    exact Jacobian at ``x``). ``noise``: None (the reading sigma estimated from the residuals),
    or a noise model (:func:`reading_sigmas` per pose); ``weighted=True``: ``x`` minimises the
    noise-weighted objective, whose covariance is ``(J_w^T J_w)^-1``. ``active``: a mask, a
    NullSpace, or None (one parameter per null direction held)."""
    problem, x = ballbar_problem(robot, measurements, x0=x)
    return uncertainty_on(problem, x, noise, active=active, weighted=weighted,
                          base=lambda p, xx: null_space(p, xx, NULL_RTOL).active)


def uncertainty_on(problem: Any, x: np.ndarray, noise: Any, *, active: Any, weighted: bool,
                   base: Callable[[Any, np.ndarray], np.ndarray]) -> Uncertainty:
    """:func:`ballbar_uncertainty` of ``problem`` (a :class:`BallbarProblem`, or the objective
    with the effects, :class:`iwr.ballbar.effects.BallbarEffectProblem`) at ``x``; ``active``
    None: ``base(problem, x)``, the base parameters' mask."""
    if weighted and noise is None:
        raise ValueError("weighted=True needs a noise model")
    if weighted:
        problem = weighted_problem(problem, np.zeros(problem.n_params), noise)
    n = problem.n_params
    if active is None:
        mask = base(problem, x)
    elif isinstance(active, NullSpace):
        mask = active.active
    else:
        mask = np.asarray(active, dtype=bool)
        if mask.shape != (n,):
            raise ValueError(f"active: boolean mask of shape {mask.shape}; expected ({n},)")
    r, jac = problem.residuals_and_jacobian(x)
    jb = jac[:, mask]
    m, p = jb.shape
    d = np.linalg.norm(jb, axis=0)
    d = np.where(d > 0, d, 1.0)
    u, s, vt = np.linalg.svd(jb / d, full_matrices=False)
    if s.size < p or s[-1] <= s[0] * max(m, p) * np.finfo(float).eps:
        raise ValueError("active: the ballbar problem's Jacobian of the active parameters is "
                         "rank deficient; hold one parameter per null direction "
                         "(active=iwr.identifiability(robot, data).active)")
    a = (vt.T / s) @ u.T / d[:, None]
    dof = m - p
    if weighted:
        cov, sigma, source = a @ a.T, float("nan"), "weighted"
    elif noise is None:
        if dof <= 0:
            raise ValueError(f"measurements: {m} readings for {p} parameters; cannot estimate "
                             "the noise from the residuals (pass noise=)")
        sigma = float(np.sqrt(r @ r / dof))
        cov, source = sigma**2 * (a @ a.T), "residuals"
    else:
        sig = reading_sigmas(problem, x, noise)
        cov, sigma, source = (a * sig**2) @ a.T, float("nan"), "noise"
    std = np.full(n, np.nan)
    std[mask] = np.sqrt(np.diag(cov))
    return Uncertainty(problem.parameter_names, mask, cov, std, sigma, source, dof)


def reading_std(robot: Robot, measurements: BallbarMeasurements, x: Any,
                unc: Uncertainty) -> np.ndarray:
    """The predicted standard deviation (mm) of each pose's predicted reading at ``x``, from the
    covariance of the identified parameters (first order): the accuracy the noise leaves."""
    problem, x = ballbar_problem(robot, measurements, x0=x)
    g = problem.jacobian(x)[:, unc.active]
    return np.sqrt(np.einsum("ki,ij,kj->k", g, unc.covariance, g))

