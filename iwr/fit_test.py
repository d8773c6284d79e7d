"""The fit test of an identification (:func:`fit_check`, :class:`FitTest`): is a solution of eq.
(10) sane? The identified errors within their plausible size modulo what the data cannot see
(:func:`_nearest_plausible`, on the kind's readings model), and with a noise model the
chi-square test of the generalised least squares statistic. :func:`iwr.identify` applies it to
every method but the efficient estimator, which tests its own fit with the same verdicts."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np

# The chi-square distribution by scipy.special (chdtrc = sf): importing scipy.stats costs every
# short command 0.5-0.8 s.
from scipy import special

from . import kinds
from ._blas import single_thread
from .implicit_loop import loop_jacobians
from .measurements import Measurements
from .noise import Noise
from .result import FitTest
from .robot import Robot

__all__ = ["FitTest", "fit_check"]


def leg_readings(robot: Robot, measurements: Measurements
                 ) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """``x -> (predicted leg readings, their Jacobian)`` at the measured poses, the readings
    weighted 0 left out: what :func:`_nearest_plausible` keeps fixed for pose data. From the
    estimator's kernel, not Problem's: the check is no evaluation of the method that produced
    ``x`` (its budget counts those)."""
    rows = (np.ones((len(measurements), 6), dtype=bool) if measurements.weights is None
            else measurements.weights > 0).reshape(-1)  # a reading weighted 0 does not count

    def readings(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        legs, jx, _ = loop_jacobians(robot, x, measurements.q, measurements.poses)
        return legs.reshape(-1)[rows], jx.reshape(-1, robot.n_params)[rows]

    return readings


def tracker_readings(problem: Any) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """``x -> (residuals, their Jacobian)`` of a :class:`iwr.tracker.TrackerProblem`: what
    :func:`_nearest_plausible` keeps fixed for laser-tracker data (the measured points are
    constant, so equal residuals are equal predictions)."""
    return lambda x: (problem.residuals(x), problem.jacobian(x))


class Beyond(NamedTuple):
    """A parameter of the smallest equivalent vector beyond its plausible size
    (:func:`beyond_plausible`)."""

    name: str
    value: float  # in the smallest equivalent vector, measured from the centre
    limit: float
    sd: float  # its standard deviation there (nan: not known)
    significant: bool  # beyond by more than the noise explains (always, without an sd)


def beyond_plausible(model: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                     x: np.ndarray, limit: np.ndarray, centre: np.ndarray | None,
                     names: Sequence[str], covariance: Any = None,
                     alpha: float = 1e-3) -> list[Beyond]:
    """Each parameter of ``x`` beyond its plausible size ``limit`` (measured from ``centre``)
    modulo the directions the readings ``model`` cannot see: the entries of its smallest
    equivalent vector (:func:`_nearest_plausible`) beyond their limit. None when ``x`` itself,
    or an equivalent on the way to the smallest, is within every limit: a plausible robot then
    predicts the same readings, and the search stops there (a ballbar's fit took 50 steps of it,
    two thirds of an identification's time, to shrink a vector already at half its limits).

    ``covariance``: the covariance of ``x``'s entries (zero rows and columns for the parameters
    held fixed), or a function giving it (called only when an entry is beyond). The size is
    then tested as a hypothesis, as the effects' range is
    (:func:`iwr.effects.problem.out_of_range`): an entry is ``significant`` when it is beyond
    its limit by more than ``z`` standard deviations of that entry of the smallest equivalent
    vector (the covariance projected off the null directions, to first order), ``z`` the normal
    quantile of ``1 - alpha / k`` over the ``k`` entries with one (Bonferroni: a robot whose
    errors are within their plausible size fails with probability at most ``alpha``). An entry
    beyond by less is what the noise does to a parameter the data determine poorly (a leg's
    offset identified at -5.9 +- 3.4 mm with a 5 mm limit: noise ten times the realistic one on
    60 poses), not a model that absorbed something it does not describe. Without a covariance
    every entry beyond its limit is significant."""
    x_plain = _nearest_plausible(model, x, limit, centre, stop_within=True)
    beyond = [i for i in range(x_plain.size) if abs(x_plain[i]) > limit[i]]
    if not beyond:
        return []
    sd = np.full(x_plain.size, np.nan)
    if covariance is not None:
        cov = covariance() if callable(covariance) else covariance
        sd = _plain_sd(model, x_plain, limit, centre, np.asarray(cov, dtype=float))
    k = int(np.sum(np.isfinite(sd) & (sd > 0)))
    z = float(special.ndtri(1.0 - alpha / max(k, 1)))
    out = []
    for i in beyond:
        v, s = float(x_plain[i]), float(sd[i])
        known = bool(np.isfinite(s) and s > 0)
        out.append(Beyond(names[i], v, float(limit[i]), s if known else math.nan,
                          not known or abs(v) - limit[i] > z * s))
    return out


def _plain_sd(model: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
              x_plain: np.ndarray, limit: np.ndarray, centre: np.ndarray | None,
              covariance: np.ndarray) -> np.ndarray:
    """The standard deviations of the smallest equivalent vector ``x_plain`` (measured from
    ``centre``) given the covariance of the vector it came from: to first order it moves as
    that vector projected off the null directions of the readings' Jacobian at ``x_plain``, in
    units of ``limit`` (the metric in which it is smallest)."""
    c = np.zeros_like(x_plain) if centre is None else np.asarray(centre, dtype=float)
    if covariance.shape != (x_plain.size, x_plain.size):
        raise ValueError(f"covariance: shape {covariance.shape}; expected "
                         f"({x_plain.size}, {x_plain.size})")
    with single_thread():
        null, _ = _null_split(model(c + x_plain)[1] * limit)
        cov = covariance / np.outer(limit, limit)
        proj = np.eye(x_plain.size) - null @ null.T
        var = np.einsum("ij,jk,ik->i", proj, cov, proj)
    return limit * np.sqrt(np.clip(var, 0.0, None))


def _degenerate(robot: Robot, measurements: Any, active: np.ndarray | None = None
                ) -> str | None:
    """Why ``measurements`` cannot identify ``robot``'s errors
    (:func:`iwr.analysis.identifiability.degenerate_data`: the rank of their information matrix
    at the nominal robot, as :func:`iwr.calibrate` judges it; not for a subset of the
    parameters the caller chose, ``active``), else None."""
    from ._hooks import hook

    with single_thread():
        return hook("degenerate_data")(robot, measurements, active)


def _null_split(jac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal bases of the null directions of ``jac`` and of their complement (in the
    units of its columns)."""
    d = np.linalg.norm(jac, axis=0)
    d = np.where(d > 0, d, 1.0)  # the scaled columns: the rank does not depend on units
    _, s, vt = np.linalg.svd(jac / d, full_matrices=jac.shape[0] < jac.shape[1])
    rank = int(np.sum(s > max(jac.shape) * np.finfo(float).eps * (s[0] if s.size else 0.0)))
    basis, _ = np.linalg.qr(vt[rank:].T / d[:, None], mode="complete")
    return basis[:, : jac.shape[1] - rank], basis[:, jac.shape[1] - rank:]


def _nearest_plausible(model: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                       x: np.ndarray, limit: np.ndarray,
                       centre: np.ndarray | None = None, *,
                       stop_within: bool = False) -> np.ndarray:
    """The vector equivalent to ``x`` (the same predictions ``model(x)[0]`` of the readings, with
    their Jacobian ``model(x)[1]``) that is smallest in units of ``limit``, measured from
    ``centre`` (default zero); returned measured from ``centre``. With ``stop_within``, the
    first equivalent within every limit instead, where there is one on the way (``x`` itself
    first): what :func:`beyond_plausible` needs.

    Holding the unidentifiable parameters fixed makes the base parameters absorb their true values
    (joint 4's rotation about its axis moves two base joints by 694 mm per radian), so a plausible
    robot can have base parameters beyond any bound; its smallest equivalent cannot (each entry of
    it is at most the norm of the true vector in these units).

    The set of equivalent vectors is curved (two of the six null directions of the IWR are
    rotations of frame {4}, compensated by moving the base joints on circles), so removing the
    null-space component of ``x`` along straight lines is right only for small errors: with tens
    of degrees along them (the comparison's ``bad`` scenario) the straight step leaves the set by
    tens of millimetres of readings and names a robot at the noise floor implausible. Instead the
    norm is minimised on the set itself, by a feasible-point method: a step along the null
    directions of the Jacobian at the current point (the straight removal), then Gauss-Newton back
    onto the set within the identifiable directions, the step halved until the norm decreases.
    Every accepted point predicts the readings of ``x`` to round-off; at the end the point has no
    component along the null directions (the optimality condition). A ``x`` that is not
    equivalent to a plausible vector stays implausible: no point of its set is small."""
    c = np.zeros_like(x, dtype=float) if centre is None else np.asarray(centre, dtype=float)

    def readings(y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        values, jac = model(c + y * limit)
        return values, jac * limit

    target, jac = readings((np.asarray(x, dtype=float) - c) / limit)
    tol = 1e-10 * (1.0 + float(np.sqrt(np.mean(target**2))))  # mm RMS: round-off of the readings

    def restore(y: np.ndarray, ident: np.ndarray) -> np.ndarray | None:
        """Gauss-Newton onto the readings of ``x`` within the identifiable directions."""
        for _ in range(20):
            legs, jac = readings(y)
            r = target - legs
            if not (np.all(np.isfinite(r)) and np.all(np.isfinite(jac))):
                return None  # a step too far for the model: the caller halves it
            if np.sqrt(np.mean(r**2)) <= tol:
                return y
            y = y + ident @ np.linalg.lstsq(jac @ ident, r, rcond=None)[0]
        return None

    y = (np.asarray(x, dtype=float) - c) / limit
    with single_thread():
        for _ in range(50):
            if stop_within and np.max(np.abs(y), initial=0.0) <= 1.0:
                break
            null, ident = _null_split(jac)
            if null.shape[1] == 0:
                break
            along = -null @ (null.T @ y)  # the straight removal of the null component
            if np.linalg.norm(along) <= 1e-10 * (1.0 + np.linalg.norm(y)):
                break  # no null component left: the smallest equivalent
            for t in 0.5 ** np.arange(12):
                z = restore(y + t * along, ident)
                if z is not None and np.linalg.norm(z) < np.linalg.norm(y):
                    break
            else:
                break  # no progress (round-off): y is as small as it gets
            y = z
            jac = readings(y)[1]
    return y * limit


def _implausible_cause(implausible: list[tuple[str, float, float]], plausible: float) -> str:
    # The farthest beyond its limit first: the likeliest cause.
    worst = sorted(implausible, key=lambda t: -abs(t[1]) / t[2])
    shown = ", ".join(f"{nm} = {v:.4g} (limit {lim:.3g})" for nm, v, lim in worst[:6])
    more = f" and {len(implausible) - 6} more" if len(implausible) > 6 else ""
    return (f"{len(implausible)} identified error(s) beyond {plausible:g} times their plausible "
            f"size (modulo the unidentifiable directions): {shown}{more}. The model has "
            "absorbed something it does not describe: an unregistered measurement frame, a tool "
            "or reflector offset left out, leg or pose columns swapped, a wrong nominal geometry")


def size_test(robot: Any, names: list[str], x: Any, beyond: list[Beyond],
              plausible: float, sd: Any = None, alpha: float = 1e-3
              ) -> tuple[list[tuple[str, float, float]], list[str], list[str], list[str]]:
    """The size test's answer on ``x`` (the fit check's and the efficient estimator's):
    ``(implausible, causes, failed, notes)``. The geometric (and set-up) errors beyond
    ``plausible`` times their size modulo the null directions by more than the noise explains
    (``beyond``, from :func:`beyond_plausible`: the ``significant`` ones are ``implausible``, the
    others ``notes``: poorly determined, not wrong), and a robot's effects' parameters outside
    their own plausible range instead (:func:`iwr.effects.problem.out_of_range`: a compliance
    in 0 .. max; ten times that range would let a negative compliance pass), by more than the
    noise explains at level ``alpha`` when ``sd`` (the standard deviations of ``x``'s entries,
    or a function giving them, called only when an effect is outside its range) is given;
    ``failed`` says what failed, for the verdict."""
    causes: list[str] = []
    failed: list[str] = []
    notes: list[str] = []
    ranges: list[tuple[str, float, float, float]] = []
    if getattr(robot, "effects", ()):
        from .effects import parameter_names as effect_parameter_names
        from .effects.problem import RANGE_FAILED, out_of_range, range_cause

        own = set(effect_parameter_names(robot.effects))
        beyond = [b for b in beyond if b.name not in own]
        ranges = out_of_range(robot, x, names)
        if ranges and sd is not None:  # outside: by more than the noise explains?
            ranges = out_of_range(robot, x, names, sd() if callable(sd) else sd, alpha)
    implausible = [(b.name, b.value, b.limit) for b in beyond if b.significant]
    if implausible:
        causes.append(_implausible_cause(implausible, plausible))
        failed.append("identified errors beyond their plausible size")
    poor = [b for b in beyond if not b.significant]
    if poor:
        notes.append(_poorly_determined(poor, plausible))
    if ranges:
        causes.append(range_cause(robot, ranges))
        failed.append(RANGE_FAILED)
    return implausible + [t[:3] for t in ranges], causes, failed, notes


def _poorly_determined(poor: list[Beyond], plausible: float) -> str:
    worst = sorted(poor, key=lambda b: -abs(b.value) / b.limit)
    shown = ", ".join(f"{b.name} = {b.value:.4g} +- {b.sd:.2g} (limit {b.limit:.3g})"
                      for b in worst[:6])
    more = f" and {len(poor) - 6} more" if len(poor) > 6 else ""
    return (f"{len(poor)} identified error(s) beyond {plausible:g} times their plausible size "
            f"(modulo the unidentifiable directions) but within what the noise explains: "
            f"{shown}{more}. Not a sign of a model that does not fit: these data determine "
            "them poorly (more poses, or poses chosen for them: iwr plan)")


def _chi2_verdict(statistic: float, dof: int, p_value: float, fit_ok: bool,
                  without_dof: str, failed: list[str] | None = None) -> str:
    """The fit test's one-line verdict (``without_dof`` when it failed with no redundancy;
    ``failed``: what failed when the chi-square test itself passed)."""
    if fit_ok:
        return (f"the model fits the data: chi2 = {statistic:.4g} for {dof} degrees of "
                f"freedom (p = {p_value:.3g})")
    chi = f"chi2 = {statistic:.4g} for {dof} degrees of freedom (p = {p_value:.2g})"
    if dof > 0 and failed:  # not the chi-square test: say what, not only its passing p-value
        return (f"THE MODEL DOES NOT FIT THE DATA: {' and '.join(failed)} (the chi-square test "
                f"alone passes: {chi})")
    return "THE MODEL DOES NOT FIT THE DATA: " + (chi if dof > 0 else without_dof)


#: The verdict of data that cannot identify the robot (:func:`_degenerate`): not a misfit.
CANNOT_IDENTIFY = "THE DATA CANNOT IDENTIFY THE ROBOT"


#: What makes a model not fit pose or tracker data, most likely first (a kind whose data have
#: other causes gives its own: :attr:`iwr.estimator_spec.EstimatorSpec.misfit_causes`).
MISFIT_CAUSES = ("the poses are not expressed in the robot's world frame (tracker frame not "
                 "registered), a tool or reflector offset left out of the model, columns "
                 "swapped or in the wrong unit, noise larger than stated, or a local minimum "
                 "(try another method or start)")


#: How the chi-square test's cause (:func:`_chi2_cause`) begins, so that a report whose own
#: diagnosis names the cause can leave the generic list out.
CHI2_CAUSE_HEAD = "the weighted residual sum "


def _chi2_cause(statistic: float, dof: int, p_value: float,
                likely: str | None = None) -> str:
    return (f"{CHI2_CAUSE_HEAD}{statistic:.4g} is {statistic / dof:.3g} times its "
            f"expectation ({dof} degrees of freedom, p = {p_value:.2g}): the model does not fit "
            f"the data. Likely causes: {likely or MISFIT_CAUSES}")


def _plausible_limit(robot: Robot, plausible: float, bounds: Any) -> np.ndarray:
    """``plausible`` times the half-width of ``bounds`` (None: the default bounds)."""
    if bounds is None:
        return plausible * robot.default_bounds("default")[1]
    lower, upper = (np.asarray(b, dtype=float) for b in bounds)
    return plausible * np.maximum(np.abs(lower), np.abs(upper))


def fit_check(robot: Robot, measurements: Measurements, x: Any, *, active: Any,
              noise: Noise | None = None, bounds: Any = None, fit_alpha: float = 1e-3,
              plausible: float = 10.0, weighted: tuple[float, int, int] | None = None
              ) -> FitTest:
    """Is an eq. (10) solution ``x`` sane? The check :func:`iwr.identify` applies to every method
    but the efficient estimator (which tests its own fit).

    Always: no identified error beyond ``plausible`` times the default bounds, modulo the
    unidentifiable directions (as :func:`efficient`; ``bounds``, a pair (lower, upper), sets the
    plausible size instead of the default bounds). With a ``noise`` model also the chi-square
    test of the generalised least squares statistic ``sum_k r_k^T C_k^-1 r_k`` (``r_k`` the six
    leg residuals of pose k, ``C_k`` their covariance propagated to first order from every
    instrument's noise) **minimised to first order around x** over the ``active`` parameters
    (the Gauss-Newton step is computed, not taken), ``dof = 6 N`` minus the rank of the active
    columns: eq. (10)'s
    minimum is not the weighted one, and the statistic at it exceeds its law by the efficiency
    loss (about 100 at N = 100 on ``Noise.realistic()``); the linearised minimum does not, while
    a local minimum far from the solution, an unregistered frame, ... stay far above it. Without
    a noise model the cost cannot be judged (the leg noise is unknown: any cost fits some
    sigma), only the size of the errors; ``statistic``, ``dof`` and ``p_value`` are then nan, 0,
    nan. ``weighted``, instead of ``noise``: a noise-weighted cost minimised elsewhere (a result
    of ``iwr-engine`` on a weighted problem file), ``(its value, the readings, the identifiable
    rank)``, tested as that statistic; ``noise`` beside it, the noise model that cost was
    weighted by, gives the size test the estimate's spread (as the job's, without it the size
    alone; ignored for kinds without :attr:`~iwr.kinds.MeasurementKind.chi2_fit_test`).

    Laser-tracker data (``robot.tracker`` and :class:`iwr.tracker.TrackerMeasurements`, ``x`` the
    robot's then the setup's parameters): the same size test, modulo the null directions of the
    point (probe) objective, each parameter measured from the centre of its bounds (the
    registration guess for the registration's correction) against ``plausible`` times their
    half-width. With a ``noise`` model ``(iwr.Noise or None, TrackerNoise)``: the same
    chi-square test on the point residuals, each pose's whitened by their covariance at ``x``
    (:func:`iwr.tracker.problem.noise_whitening`: the tracker's noise plus the readings'
    propagated through the loop closure), ``dof`` the seen coordinates (a probe's: six a pose,
    its four points one rigid pose) minus the rank. Each kind gives its whitened residuals
    (:meth:`iwr.kinds.MeasurementKind.whitened`).
    """
    x = np.asarray(x, dtype=float)
    mask = np.asarray(active, dtype=bool)
    # The kind's part: each parameter's plausible size about its centre and the readings model
    # whose null directions the test ignores (tracker data, docs/tracker.md: the point (probe)
    # objective, so modulo the registration's and the platform frame's gauge; the setup's
    # parameters judged from the centre of their bounds, the robot's from zero).
    kind = kinds.of(measurements)
    if noise is not None and not kind.chi2_fit_test and weighted is None:
        raise ValueError(f"noise: the chi-square test of {kind.name} data is not implemented "
                         "here (the efficient estimator tests their fit); only the size of the "
                         "identified errors is tested")
    names, limit, centre, readings = kind.plausibility(robot, measurements, bounds, plausible)
    statistic, covariance, jw = math.nan, None, None
    if noise is not None and kind.chi2_fit_test:
        # The kind's whitened residuals and Jacobian at x (iwr.kinds.MeasurementKind.whitened).
        try:
            rw, jw, n_readings = kind.whitened(robot, measurements, x, noise)
        except (ValueError, np.linalg.LinAlgError):
            if weighted is None:
                raise
            rw = jw = None  # the weighted cost's spread unknown: the size alone
    if jw is not None:  # whitened above
        jw = jw[:, mask]
        scale = np.linalg.norm(jw, axis=0)
        scale = np.where(scale > 0, scale, 1.0)
        with single_thread():
            step, _, jrank, _ = np.linalg.lstsq(jw / scale, rw, rcond=None)
        if weighted is None:
            statistic, rank = float(np.sum((rw - (jw / scale) @ step) ** 2)), jrank

        def covariance() -> np.ndarray:
            """The covariance of the weighted (efficient) estimate to first order, for the size
            test: a method less efficient than that spreads more, so the test errs towards
            "implausible" for it."""
            with single_thread():
                _, sv, vt = np.linalg.svd(jw / scale, full_matrices=False)
            v = vt[:jrank].T / sv[:jrank]
            cov = np.zeros((x.size, x.size))
            cov[np.ix_(mask, mask)] = (v @ v.T) / np.outer(scale, scale)
            return cov

    over = beyond_plausible(readings, x, limit, centre, names, covariance, fit_alpha)

    def sd() -> Any:
        """The effects' standard deviations for their range test (with effects only)."""
        from .effects.problem import parameter_sd

        try:
            return parameter_sd(robot, measurements, x, mask, noise, readings=readings)
        except (ValueError, np.linalg.LinAlgError):  # no such Jacobian
            return None  # then the range itself

    implausible, size_causes, size_failed, size_notes = size_test(
        robot, names, x, over, plausible, sd if robot.effects else None, fit_alpha)
    causes: list[str] = []
    dof, p_value, chi_ok = 0, math.nan, True
    if weighted is not None:
        statistic, n_readings, rank = float(weighted[0]), int(weighted[1]), int(weighted[2])
    tested = noise is not None or weighted is not None
    if tested:
        # The identifiable directions among the active parameters (all 58 active: 52 on the IWR).
        dof = int(n_readings) - int(rank)
        p_value = float(special.chdtrc(dof, statistic)) if dof > 0 else math.nan
        chi_ok = bool(dof > 0 and p_value >= fit_alpha)
        if dof <= 0:
            causes.append(f"no redundancy: {int(n_readings)} readings for {int(rank)} "
                          "identifiable parameters, so the data cannot test the model: measure "
                          "more poses")
        elif not chi_ok:
            causes.append(_chi2_cause(statistic, dof, p_value))
    causes += size_causes
    # Data that cannot identify the robot (too few distinct poses, copies): whatever the fit
    # looks like, it says nothing (one pose's six readings fit 58 parameters exactly), as
    # iwr.calibrate's "not calibrated" says.
    degenerate = _degenerate(robot, measurements, mask)
    if degenerate is not None:
        causes.insert(0, degenerate)
    fit_ok = chi_ok and not implausible and degenerate is None
    if degenerate is not None:
        verdict = CANNOT_IDENTIFY  # why: the first cause
    elif not tested:
        beyond = "identified errors beyond their plausible size"  # size_test's wording
        head = ("no noise model: the cost is not tested (give one for the chi-square test); "
                "identified errors " + ("NOT within" if beyond in size_failed else "within")
                + " their plausible size" + "".join(f"; {f}" for f in size_failed if f != beyond))
        verdict = head if fit_ok else "THE MODEL DOES NOT FIT THE DATA: " + head
    else:
        verdict = _chi2_verdict(statistic, dof, p_value, fit_ok, "implausible parameters",
                                size_failed if chi_ok and size_failed else None)
    return FitTest(statistic, dof, p_value, float(fit_alpha), bool(fit_ok), verdict,
                   causes if not fit_ok else size_notes, implausible)
