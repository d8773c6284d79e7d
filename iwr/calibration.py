"""The calibration job as one library call.

:func:`calibrate` does what ``iwr calibrate`` does, for every kind of data
(:mod:`iwr.kinds`), and computes each thing once: the validation split, the start (the
tracker's registration guess), the identifiability and the parameters identified, the
identification, the fit test and outliers (the method's), the standard deviations, the accuracy
on the validation poses and the accuracy the covariance predicts. It returns a
:class:`Calibration` that holds them; the commands and the reports only render it
(:func:`iwr.reporting.calibration.render`). :func:`from_result` makes the same object from a
result identified elsewhere (``iwr report`` on a run of ``iwr-calibrate``).

Inside the job each data set's problem is built once (:func:`iwr.kinds.reuse`); the
:class:`Calibration` keeps that memo so that its report shares it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from . import kinds
from .analysis.accuracy import Accuracy, accuracy
from .analysis.identifiability import degenerate, identifiability
from .analysis.uncertainty import Uncertainty, uncertainty
from .effects import parameter_names as effect_parameter_names
from .fit_test import CANNOT_IDENTIFY
from .gross_errors import LeftOutError, cut_to_used, fitted_poses, without_left_out
from .gross_errors import check_result as check_gross_errors
from .gross_errors import screen as screen_gross_errors
from .methods import IdentificationResult, identify
from .problem_base import recorded_bounds
from .robot_fingerprint import record as robot_model_record

__all__ = ["LEVEL", "NOT_CALIBRATED", "WORSE", "Calibration", "Judgement", "LeftOutError",
           "NotHeldOutError", "calibrate", "from_result", "judge", "paired_test"]

#: The status (and message prefix) of a run whose method converged but whose data cannot
#: identify the errors, or whose calibrated robot is worse than the nominal one.
NOT_CALIBRATED = "not calibrated"
#: A calibration whose error after is more than this times the error before, and whose
#: validation poses show it worse (:data:`LEVEL`), did not improve (:func:`judge`).
WORSE = 1.05
#: The level of the one-sided paired test by which the validation poses must show the error
#: after larger than before for a calibration to be "not calibrated" (:func:`judge`). 5 %, not
#: 1 %: a bad calibration let through is worse than a good one refused, and at 1 % 16 of 182
#: calibrations 1.5-3 times worse passed on 8 validation poses, at 5 % 2 of them, for 7 of 120
#: correct re-calibrations refused instead of 1 (docs/kinds.md, "The verdict").
LEVEL = 0.05
#: What the validation poses should be able to tell (``iwr plan`` warns when a plan holds out
#: fewer poses than :func:`validation_poses_needed`): a calibration this many times worse at
#: every pose refused with at least :data:`POWER` probability by the paired test at LEVEL.
DETECT_RATIO = 2.0
POWER = 0.8


@dataclass(frozen=True)
class Judgement:
    """Whether a calibration made the error it is judged by worse (:func:`judge`).

    Attributes
    ----------
    before, after, change, what
        The kind's :meth:`~iwr.kinds.MeasurementKind.improvement`: the error (RMS) before and
        after, in words, and what it is.
    n : int
        The poses the paired test compared (those with a finite error > 0 before and
        after); 0 when the kind has no per-pose errors.
    p : float
        The test's one-sided p-value (after larger than before); NaN when there was no test
        (no per-pose errors, or fewer than 2 poses).
    worse : bool
        "Did not improve": the error after or before is not finite, or it is more than
        :data:`WORSE` times larger after and the test finds it larger at :data:`LEVEL` (no
        test: the ratio alone).
    """

    before: float
    after: float
    change: str
    what: str
    n: int
    p: float
    worse: bool

    @property
    def ratio(self) -> float:
        """after / before (inf when only before is 0)."""
        if self.before > 0:
            return self.after / self.before
        return math.inf if self.after > 0 else 1.0

    @property
    def tested(self) -> bool:
        return math.isfinite(self.p)

    @property
    def beyond_ratio(self) -> bool:
        """Finite and more than :data:`WORSE` times larger after (the test may not tell)."""
        return (math.isfinite(self.after) and math.isfinite(self.before)
                and self.after > WORSE * self.before)

    def evidence(self) -> str:
        """The ratio and the test in words: ``after/before 1.12, paired t-test p = 0.3``."""
        r = self.ratio
        ratio = f"after/before {r:.2f}" if r < 1000 else f"after/before {r:.3g}"
        if self.tested:
            return f"{ratio}, paired t-test p = {self.p:.2g}"
        if self.n:
            return f"{ratio}; {self.n} pose(s): too few for a paired test"
        return f"{ratio}; no per-pose errors for a paired test"


def paired_test(before: Any, after: Any) -> tuple[int, float]:
    """``(n, p)``: the one-sided paired t-test of whether the per-pose errors ``after`` are
    larger than ``before``: of the mean of ``log(after / before)`` > 0 (the error after larger
    at the typical pose, by a factor), over the ``n`` poses where both are finite and > 0;
    ``p`` NaN when fewer than 2. The p-value of Student's t with n - 1 degrees of freedom (as
    ``scipy.stats.ttest_1samp(d, 0, alternative="greater")``, without importing scipy.stats).

    On the log ratios, not on the differences of the squared errors (whose mean > 0 is the RMS
    after > the RMS before): one pose's large error dominates those, and a calibration 5 times
    worse on 8 validation poses had p = 0.09 (benchmarks/recalibration_verdict.py); the log
    ratios of errors are near normal, and the test has the power to refuse it."""
    from scipy import special

    b = np.asarray(before, dtype=float).ravel()
    a = np.asarray(after, dtype=float).ravel()
    ok = np.isfinite(a) & np.isfinite(b) & (a > 0) & (b > 0)
    d = np.log(a[ok]) - np.log(b[ok])
    n = int(d.size)
    if n < 2:
        return n, math.nan
    mean, sd = float(np.mean(d)), float(np.std(d, ddof=1))
    if not sd > 0:  # every pose changed by the same factor: certain
        return n, 0.0 if mean > 0 else 1.0
    t = mean / (sd / math.sqrt(n))
    return n, float(special.stdtr(n - 1, -t))


def validation_poses_needed(error_dims: int = 3, ratio: float = DETECT_RATIO,
                            power: float = POWER, level: float = LEVEL) -> int:
    """The fewest validation poses with which :func:`paired_test` at ``level`` finds a
    calibration ``ratio`` times worse at every pose with probability ``power``.

    Each per-pose error is taken as the length of an error of ``error_dims`` independent
    Gaussian components of one standard deviation (3: a tool position, a reflector point; 1: a
    ballbar's distance residual), before and after independent: ``log(after / before)`` then
    has mean ``log(ratio)`` and standard deviation ``sqrt(trigamma(error_dims / 2) / 2)``
    (0.68 for 3 components, 1.57 for 1), and the power at n poses is the noncentral t's,
    ``1 - F(t_crit; n - 1, sqrt(n) log(ratio) / sd)``. With the defaults: 8 poses for 3
    components (power 0.82; 7 give 0.76), 34 for 1 (docs/kinds.md, "The verdict")."""
    from scipy import special

    sd = math.sqrt(float(special.polygamma(1, error_dims / 2)) / 2)
    effect = math.log(ratio) / sd
    n = 2
    while 1 - special.nctdtr(n - 1, math.sqrt(n) * effect,
                             special.stdtrit(n - 1, 1 - level)) < power:
        n += 1
    return n


def judge(kind: Any, accuracy: Any, held_out: bool) -> Judgement:
    """Whether the calibration whose accuracy on the validation poses is ``accuracy`` made the
    error its ``kind`` judges by worse: the one rule of the job's "not calibrated"
    (:meth:`Calibration._settle`) and of the report's verdict.

    Worse when the error after or before is not finite, or when it is more than :data:`WORSE`
    times larger after AND the paired test of its per-pose errors
    (:meth:`~iwr.kinds.MeasurementKind.per_pose_errors`, :func:`paired_test`) finds it larger
    at :data:`LEVEL`. A robot calibrated before, re-calibrated on fresh data, is at the noise
    level before and after, and the ratio of two such errors on a few validation poses is
    random (up to 1.6 on 8 poses): the ratio alone refused such calibrations. A kind without
    per-pose errors, or fewer than 2 poses, has no test: the ratio alone decides, as before."""
    before, after, change, what = kind.improvement(accuracy, held_out)
    errors = kind.per_pose_errors(accuracy)
    # A kind without per-pose errors (None), or fewer than 2 poses: no test (p NaN), and the
    # ratio alone decides, the rule before the test.
    n, p = (0, math.nan) if errors is None else paired_test(*errors)
    finite = math.isfinite(after) and math.isfinite(before)
    worse = not finite or (after > WORSE * before and (not math.isfinite(p) or p < LEVEL))
    return Judgement(before, after, change, what, n, p, worse)


@dataclass
class Calibration:
    """Everything a calibration job produced (:func:`calibrate`, :func:`from_result`).

    Attributes
    ----------
    robot : Robot
        The nominal robot.
    identification, validation
        The poses used for identification, and the held-out ones (``validation`` is the
        identification set itself when nothing was held out: ``held_out`` is then False).
    held_out : bool
    result : IdentificationResult
        Its ``status`` and ``success`` say what the job is: ``"not calibrated"``
        (:data:`NOT_CALIBRATED`) when the method converged on data that cannot identify the
        errors, or to a robot no better than the nominal one.
    accuracy : Accuracy
        On the validation poses (what accuracy means for the kind: :func:`iwr.accuracy`).
    data_name, robot_name : str
        How the inputs are named in the report.
    identifiability
        At the start, on the identification poses (:func:`iwr.identifiability`): what the
        parameters identified were chosen by.
    uncertainty : Uncertainty or None
        Standard deviations of the identified parameters (None if they could not be computed;
        ``notes`` says why).
    parameter_error : ParameterError or None
        Against the truth, modulo the unidentifiable directions (simulations only).
    truth_accuracy : Accuracy or None
        The accuracy of the true errors (simulations only): the noise floor.
    notes : list of str
        For the summary and the report.
    settings : dict
        How the job was run (method, options, bounds, ...), for the report.
    provenance : dict or None
        :func:`iwr.reporting.html.provenance`: version, command line, date, inputs' SHA-256.
    predicted : PredictedAccuracy or None
        The tool accuracy the covariance predicts on the validation poses.
    start
        What the identification started from beyond the nominal robot (the tracker's
        registration guess), or None.
    sources : dict
        Other inputs named in the report (``{"readings": path}``).
    kind : MeasurementKind
        The kind of the data (:func:`iwr.kinds.of`).
    diagnosis : iwr.effects.job.Diagnosis or None
        A robot without effects on data with payload or temperature columns: whether the
        residuals correlate with the leg forces or the temperatures, and the effect to switch
        on (:func:`iwr.effects.job.diagnose`; issue 23).
    weightless : int
        The poses of the data left out before anything else because every reading of theirs
        has weight 0 (:func:`iwr.kinds.without_weightless`): in no set, no figure.
    """

    robot: Any
    identification: Any
    validation: Any
    held_out: bool
    result: IdentificationResult
    accuracy: Accuracy
    data_name: str = ""
    robot_name: str = ""
    identifiability: Any = None
    uncertainty: Any = None
    parameter_error: Any = None
    truth_accuracy: Accuracy | None = None
    notes: list[str] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] | None = None
    predicted: Any = None
    start: Any = None
    sources: dict[str, str] = field(default_factory=dict)
    kind: Any = None
    diagnosis: Any = None
    weightless: int = 0
    problems: dict[Any, Any] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.kind is None:
            self.kind = kinds.of(self.identification)

    # -- what the job is ----------------------------------------------------------------------
    @property
    def success(self) -> bool:
        """Whether the job calibrated the robot: converged, fits, and improved it."""
        return bool(self.result.success)

    @property
    def status(self) -> str:
        return str(self.result.status)

    @property
    def interrupted(self) -> bool:
        return bool(self.result.interrupted)

    @property
    def fit_ok(self) -> bool | None:
        """The fit test's answer, or None when there was none (no noise model)."""
        return self.result.fit_ok

    def calibrated_robot(self) -> Any:
        """The calibrated robot, as the job's ``calibrated.toml`` holds it
        (:meth:`iwr.kinds.MeasurementKind.calibrated_robot`: with the kind's calibrated set-up,
        and for tracker data {5} moved to the frame the measured points fix; its workspace
        widened to hold the poses measured, :func:`iwr.compensation.with_measured_workspace`).
        Check :attr:`success` before acting on it."""
        return self.calibrated_file()[0]

    def calibrated_file(self) -> tuple[Any, dict[str, Any]]:
        """:meth:`calibrated_robot`, and what ``calibrated.toml``'s ``[provenance]`` says of it
        beyond the job (the kind's: the tracker's platform frame)."""
        from .compensation import with_measured_workspace

        robot, extra = self.kind.calibrated_robot(self.robot, self.result.x)
        sets = [self.identification] + ([self.validation] if self.held_out else [])
        return with_measured_workspace(robot, *sets), extra

    def improvement(self) -> tuple[float, float, str, str]:
        """``(before, after, sentence, what)``: the error the job is judged by
        (:meth:`iwr.kinds.MeasurementKind.improvement`)."""
        return self.kind.improvement(self.accuracy, self.held_out)

    def judgement(self) -> Judgement:
        """Whether the calibration made that error worse (:func:`judge`)."""
        return judge(self.kind, self.accuracy, self.held_out)

    def degenerate(self) -> str | None:
        """Why the identification data cannot identify the robot's errors, else None
        (:func:`degenerate`)."""
        return degenerate(self.robot, self.identification, self.identifiability)

    def _settle(self) -> None:
        """success, the verdict and the exit code agree: a converged method is not yet a
        calibration (issue 26: 2 poses copied 30 times, or 3 tracker poses, were
        "calibrated")."""
        r = self.result
        if r.interrupted:
            return
        # Degenerate data whether or not the method converged or its fit passed: more budget
        # would not help, and a fit test of too few readings says nothing.
        reason = self.degenerate()
        if reason is None and r.fit is not None:
            # An exact fit (the chi-square test found no redundancy): as many readings as
            # identified parameters fit the noise too, and nothing is left to test the model.
            reason = next((c for c in r.fit.causes if c.startswith("no redundancy")), None)
        if reason is None and (not r.success or self.fit_ok is False):
            return
        if reason is None:
            j = self.judgement()
            if j.worse:
                reason = f"the calibration did not improve {j.what}: {j.change} ({j.evidence()})"
        if reason is not None:
            r["success"] = False
            r["status"] = NOT_CALIBRATED
            # The prefix keeps the status in a result file (iwr.result.status_from_message).
            r["message"] = f"{NOT_CALIBRATED}: {reason}"


class _Best:
    """A method's callback (SciPy's convention, ``callback(intermediate_result)``) that keeps the
    best point seen, then calls the caller's: what is left if Ctrl-C escapes a method before it
    returns its own result."""

    def __init__(self, then: Callable[..., Any] | None) -> None:
        self.best = math.inf
        self.x: np.ndarray | None = None
        self.calls = 0
        self.then = then

    def __call__(self, res: Any) -> Any:
        self.calls = max(int(getattr(res, "nfev", self.calls + 1)), self.calls)
        if float(res.fun) < self.best:
            self.best, self.x = float(res.fun), np.array(res.x, dtype=float, copy=True)
        return None if self.then is None else self.then(res)


def _quiet(_line: str) -> None:
    pass


def calibrate(
    robot: Any,
    data: Any,
    method: str | None = None,
    *,
    noise: Any = None,
    validation: Any = None,
    validation_fraction: float = kinds.VALIDATION_FRACTION,
    seed: int = 0,
    parameters: str = "base",
    bounds: Any = None,
    truth: Any = None,
    progress: bool | None = None,
    callback: Callable[..., Any] | None = None,
    log: Callable[[str], None] | None = None,
    data_name: str = "",
    robot_name: str = "",
    sources: dict[str, str] | None = None,
    settings: dict[str, Any] | None = None,
    provenance: dict[str, Any] | None = None,
    **options: Any,
) -> Calibration:
    """Calibrate ``robot`` from ``data`` of any kind: the whole job of ``iwr calibrate``.

    Parameters
    ----------
    robot : Robot
        The nominal robot (with its instrument's setup, e.g. a ``[tracker]`` table, for data
        measured by one).
    data
        The measurements (:class:`iwr.Measurements`, tracker data, or any registered kind).
    method : str, optional
        As :func:`iwr.identify`; default ``"efficient"`` with a noise model, else ``"lm"``.
    noise : optional
        The instruments' noise (:class:`iwr.Noise`, the kind's own form, or ``"estimate"``):
        the efficient estimator weighs every reading by it and tests the fit; other methods
        minimise the objective weighted by it where the kind has one.
    validation : optional
        Held-out poses of the same kind; else ``validation_fraction`` of ``data`` is held out at
        random (seed ``seed``; 0: none, and the accuracy is then optimistic).
    parameters : {"base", "all"}
        Identify the base parameters only (the unidentifiable ones held at nominal: a unique
        answer), or all of them.
    bounds, seed, progress, options
        As :func:`iwr.identify` (``max_evaluations``, ``generations``, ``polish``, ...).
    truth : array_like, optional
        The true parameters of a simulation: the parameter error and the noise floor.
    callback : callable, optional
        Called with each intermediate result, as by :func:`iwr.identify`.
    log : callable, optional
        Called with each line the job says as it goes (``print`` for a command line).
    data_name, robot_name, sources, settings, provenance
        What the report names and records.

    Returns
    -------
    Calibration
        Ctrl-C during the identification ends the job with the best point so far
        (``status == "interrupted"``, ``success`` false).
    """
    if robot.effects:  # issue 23: pose data; the methods say which of them model the effects
        from .effects.job import check_job
        from .effects.model import check_inputs

        check_job(robot, data)
        # The columns the effects need (temperatures), in both data sets before any work: the
        # validation set's were found only after the identification, as "measurements".
        check_inputs(robot, data, "data")
        if validation is not None:
            check_inputs(robot, validation, "validation")
    kind = kinds.of(data)
    kind.check(robot, data)
    if parameters not in ("base", "all"):
        raise ValueError(f"parameters: {parameters!r}; expected 'base' or 'all'")
    say = log or _quiet
    notes: list[str] = []
    # Poses with weight 0 for every reading count in no figure, before the split.
    given = data
    data, weightless = kinds.without_weightless(data)
    if validation is not None:
        if kinds.of(validation) is not kind:
            raise TypeError(f"validation: {kinds.of(validation).name} data, but data are "
                            f"{kind.name} data")
        validation = _validation_weighted(validation, notes)
        _check_held_out(data, validation, notes)
        ident, val, held_out = data, validation, True
    elif validation_fraction:
        # (Every pose left has a weight > 0: both parts count.)
        ident, val = kinds.split(data, validation_fraction, seed)
        held_out = True
    else:
        ident = val = data
        held_out = False
    if noise is not None:
        noise = kind.reading_noise(noise)
    if method is None:
        method = "efficient" if noise is not None else "lm"
    problems: dict[Any, Any] = {}
    with kinds.reuse(problems):
        for line in kind.job_lines(robot, data, len(ident), method):
            say(line)
        start = kind.start(robot, ident)
        if start is not None:
            say(str(start))
        # At the start: what identify holds at nominal, so that the report's "held" and "null
        # direction" agree with what was done.
        report = identifiability(robot, ident)
        if parameters == "base":
            options["active"] = report.active
        best = _Best(callback)
        try:
            result = identify(robot, ident, method, noise=noise, bounds=bounds, seed=seed,
                              progress=progress, callback=best, **options)
        except KeyboardInterrupt:
            result = _best_so_far(robot, ident, kind, method, best, options.get("active"),
                                  bounds)
        # Gross errors in every pose, held-out ones too, with or without a noise model (issue 22):
        # named, and left out of the identification (re-fitted) and of the accuracy. Not on
        # degenerate data: those are "not calibrated" (below), whatever their residuals say (the
        # poses the efficient estimator left out of its fit leave the set all the same).
        before = len(ident)
        if degenerate(robot, ident, report) is not None:
            result["gross_errors"] = "gross errors: not tested (degenerate data)"
            ident = fitted_poses(result, ident)
            if not held_out:
                val = ident
        else:
            result, ident, val = screen_gross_errors(robot, ident, val, result, noise,
                                                     held_out=held_out, bounds=bounds)
        if len(ident) != before:
            # The report describes the poses the result was identified from.
            report = identifiability(robot, ident)
        # What `iwr report` checks its data against: the whole data set's fingerprint, as the
        # engine's problem file records it.
        # And its robot file against the model of the robot identified for (the fingerprint
        # of what determines the numbers: geometry, parameters, effects, set-up).
        # And the validation split, which `iwr report` makes again for the same figures.
        split = ({"from": "validation data"} if validation is not None else
                 {"from": "data", "fraction": float(validation_fraction),
                  "seed": None if seed is None else int(seed)}
                 if validation_fraction else {"from": "none"})
        result["settings"] = {**dict(result.settings), "data_file": data_name,
                              "validation_split": split,
                              "data_fingerprint": kind.fingerprint(robot, given),
                              **({"robot_file": robot_name} if robot_name else {}),
                              "robot_model": robot_model_record(robot)}
        note = kind.weighting_note(given, method, data_name)
        if note:
            notes.append(note)
        _note_widened(robot, result, notes)
        unc = _uncertainty(robot, ident, result, report if parameters == "all" else None,
                           noise, notes)
        acc = accuracy(robot, val, result.x, start=start)
        truth_acc = perr = None
        if truth is not None:
            truth_acc = accuracy(robot, val, truth, start=start)
            try:  # the kind's: tracker data need exact readings of the truth
                perr = kind.parameter_error(robot, ident, result.x, truth)
            except ValueError as exc:
                notes.append(f"note: no parameter error against the truth: {_one_line(exc)}")
        predicted = None
        if result.covariance is not None and not result.interrupted:
            try:
                predicted = kind.predicted_accuracy(robot, val, result.x, result["covariance"],
                                                    result["active"], seed)
            except (ValueError, NotImplementedError, np.linalg.LinAlgError) as exc:
                notes.append(f"note: no predicted accuracy: {_one_line(exc)}")
        cal = Calibration(
            robot=robot, identification=ident, validation=val, held_out=held_out,
            result=result, accuracy=acc, data_name=data_name, robot_name=robot_name,
            identifiability=report, uncertainty=unc, parameter_error=perr,
            truth_accuracy=truth_acc, notes=notes, settings=dict(settings or {"method": method}),
            provenance=provenance, predicted=predicted, start=start,
            sources=dict(sources or {}), kind=kind, problems=problems, weightless=weightless,
            diagnosis=_diagnosis(robot, ident, result, noise, notes))
        cal._settle()
    return cal


def _recorded_split(data: Any, result: IdentificationResult, notes: list[str]
                    ) -> tuple[Any, Any]:
    """``(identification, validation)`` of ``data`` as the job that identified ``result`` split
    them (its settings' ``validation_split``: the fraction and seed of :func:`iwr.kinds.split`),
    so that ``iwr report`` of the run gives the job's figures; ``(data, None)`` when the job
    held out nothing or recorded no split (a note when it held out a separate file)."""
    split = dict(result.settings).get("validation_split")
    if not isinstance(split, dict):
        return data, None
    if split.get("from") == "validation data":
        notes.append("note: the run held out the poses of a separate validation file; give it "
                     "(--validation) for the run's accuracy figures: these are on the "
                     "identification poses (optimistic)")
        return data, None
    if split.get("from") != "data":
        return data, None
    fraction, seed = split.get("fraction"), split.get("seed")
    if seed is None and isinstance(fraction, float):
        notes.append("note: the run split its data without a seed (seed=None), so its "
                     "validation poses cannot be found again: these figures are on every pose "
                     "(optimistic)")
        return data, None
    if not (isinstance(fraction, float) and 0 < fraction < 1 and isinstance(seed, int)
            and not isinstance(seed, bool) and seed >= 0):
        raise ValueError(f"result: its settings' validation_split {split!r}: expected a "
                         "fraction in (0, 1) and a seed >= 0")
    return kinds.split(data, fraction, seed)


class NotHeldOutError(ValueError):
    """A validation set whose every pose is also in the data (``shared`` of them)."""

    def __init__(self, shared: int) -> None:
        self.shared = shared
        super().__init__("validation: every one of its poses is also in the data (the same "
                         "measurements given twice?): accuracy on held-out poses needs poses the "
                         "identification did not use; give other poses, or none to hold out a "
                         "fraction of the data")


def _check_held_out(data: Any, validation: Any, notes: list[str]) -> None:
    """A validation set given apart from the data holds no pose of theirs:
    :class:`NotHeldOutError` when every one of its poses is also in the data (the data file
    given twice), a note naming how many when some are (their accuracy is not a held-out one).
    Poses are compared by content (:func:`iwr.result.pose_keys`)."""
    from .result import pose_keys

    mine = set(pose_keys(data))
    shared = sum(1 for k in pose_keys(validation) if k in mine)
    if shared and shared == len(validation):
        raise NotHeldOutError(shared)
    if shared:
        notes.append(f"note: {shared} of the {len(validation)} validation poses are also in the "
                     "data: their accuracy is not a held-out one")


def _validation_weighted(validation: Any, notes: list[str]) -> Any:
    """``validation`` without its poses of weight 0 for every reading, with a note naming how
    many (:func:`iwr.kinds.without_weightless`)."""
    validation, k = kinds.without_weightless(validation, "validation")
    if k:
        notes.append(f"note: {k} pose(s) of the validation data have weight 0 for every reading: "
                     "left out of the accuracy figures")
    return validation


def _note_widened(robot: Any, result: IdentificationResult, notes: list[str]) -> None:
    """A note naming the effects' plausible ranges calibrated.toml widens to hold a value
    identified beyond them (:func:`iwr.effects.api.widened_ranges`)."""
    x = np.asarray(result.x, dtype=float)[:robot.n_params + len(
        effect_parameter_names(robot.effects))]
    if not robot.effects or not np.all(np.isfinite(x)):
        return
    from .effects.api import widened_ranges

    widened = widened_ranges(robot, x)
    if widened:
        notes.append("note: calibrated.toml widens the plausible range of an effect to hold the "
                     "value identified beyond it (the fit's range test weighs the departure by "
                     "its standard deviation): " + "; ".join(widened))


def effects_in_range(robot: Any, data: Any, result: IdentificationResult
                     ) -> IdentificationResult:
    """``result``, its fit failed when an effect's identified value is outside its plausible
    range and its fit test did not say so: a result identified elsewhere (``iwr-calibrate``'s
    engine, whose DE bounds its search but whose result file may be edited or come from
    another robot file). Every method's own fit check tests the range
    (:func:`iwr.fit_test.size_test`, :func:`iwr.effects.problem.out_of_range`), with the same
    cause."""
    from dataclasses import replace

    from .effects.problem import RANGE_FAILED, out_of_range, range_cause
    from .result import FitTest

    x = np.asarray(result.x, dtype=float)
    if not robot.effects or result.interrupted or not np.all(np.isfinite(x)):
        return result
    fit = result.fit
    seen = set() if fit is None else {t[0] for t in fit.implausible}
    bad = [t for t in out_of_range(robot, x, list(result.parameter_names) or None)
           if t[0] not in seen]
    if bad:  # by more than the noise explains (the leg noise estimated from the residuals)?
        from .effects.problem import parameter_sd

        active = (np.ones(x.size, dtype=bool) if result.active is None
                  else np.asarray(result.active, dtype=bool))
        try:
            # Data of another kind than poses in {0} need their residuals and Jacobian (as the
            # fit check gives them): without them the range was tested without the noise.
            readings = kinds.of(data).plausibility(robot, data, None, 1.0)[3]
            sd = parameter_sd(robot, data, x, active, readings=readings)
        except (ValueError, np.linalg.LinAlgError):
            sd = None
        bad = [t for t in out_of_range(robot, x, list(result.parameter_names) or None, sd)
               if t[0] not in seen]
    if not bad:
        return result
    cause = range_cause(robot, bad)
    verdict = f"THE MODEL DOES NOT FIT THE DATA: {RANGE_FAILED}"
    fit = fit or FitTest(math.nan, 0, math.nan, 1e-3, True, "", [], [])
    out = IdentificationResult(**dict(result))
    # a passing fit's causes are notes (FitTest.causes): not among a failure's causes
    out["fit"] = replace(fit, fit_ok=False, verdict=verdict if fit.fit_ok else fit.verdict,
                         causes=([] if fit.fit_ok else list(fit.causes)) + [cause],
                         implausible=list(fit.implausible) + [t[:3] for t in bad])
    if out.success or out.status == "converged":
        out.update(success=False, status="failed", message=f"{verdict}: {cause}")
    return out


def _diagnosis(robot: Any, data: Any, result: Any, noise: Any, notes: list[str]) -> Any:
    """The kind's :meth:`~iwr.kinds.MeasurementKind.diagnose` of a geometric-only result on
    data with payload or temperature columns (issue 23), with the noise the fit was weighted
    by; None otherwise (a note when it cannot be computed)."""
    from .noise import Noise, TrackerNoise

    if robot.effects or result.interrupted:
        return None
    if result.method == "efficient" and result.noise is not None:
        noise = result.noise
    if not isinstance(noise, (Noise, TrackerNoise, tuple)):
        noise = None  # "estimate" and the like: not a model to whiten by
    try:
        return kinds.of(data).diagnose(robot, data, result.x, active=result.active, noise=noise)
    except (ValueError, np.linalg.LinAlgError) as exc:
        notes.append(f"note: no diagnosis of the residuals against the loads and temperatures: "
                     f"{_one_line(exc)}")
        return None


def from_result(
    robot: Any,
    data: Any,
    result: IdentificationResult,
    *,
    validation: Any = None,
    data_name: str = "",
    robot_name: str = "",
    sources: dict[str, str] | None = None,
    settings: dict[str, Any] | None = None,
    provenance: dict[str, Any] | None = None,
    polish: bool = False,
) -> Calibration:
    """The :class:`Calibration` of a result identified elsewhere (``iwr-calibrate``'s run, a
    saved result) from ``data``: everything :func:`calibrate` computes after the
    identification, on ``validation`` (default: the split the job recorded
    (``settings["validation_split"]``) made again, so the job's sets and figures; a result that
    records none, the data themselves: an optimistic accuracy).
    ValueError when the result's parameters are not those of ``robot`` and the data's kind.
    ``polish``: the result refined first by :func:`polish` on the identification poses
    (``iwr report --polish``)."""
    kind = kinds.of(data)
    kind.check(robot, data)
    if robot.effects:
        from .effects.job import check_job

        check_job(robot, data)  # the data it models; the method ran elsewhere
    x = check_result(robot, kind, result)
    if validation is not None and kinds.of(validation) is not kind:
        raise TypeError(f"validation: {kinds.of(validation).name} data, but data are "
                        f"{kind.name} data")
    notes: list[str] = []
    # As the job: poses of weight 0 for every reading count in no figure.
    data, weightless = kinds.without_weightless(data)
    if validation is not None:
        validation = _validation_weighted(validation, notes)
        _check_held_out(data, validation, notes)
    else:
        data, validation = _recorded_split(data, result, notes)
    # The poses the run's gross-error screen left out (recorded with their lines) are left out
    # here too: the result was not fitted to them, and its accuracy figures are without them.
    # A pose is found by its content: a held-out pose of a separate validation file is never one
    # of DATA's, and a file with other line numbers (comments, another layout) is the same data.
    # Held-out poses may have come from a separate file: not required to be in DATA.
    n_given = len(data)
    screened = data  # the identification poses before the screen, as the job's start saw them
    data, gone = without_left_out(data, result, ("identification",))
    used = result.get("used")
    if (used is not None and len(data) < n_given and np.size(used) == n_given
            and np.count_nonzero(used) == len(data)):
        # The efficient estimator's result on DATA (iwr.identify, not a job's): its per-pose
        # arrays cut to the poses left, as the job's screen cuts them (its check of them refused
        # the longer `used`).
        result = IdentificationResult(**dict(result))
        cut_to_used(result)
    if validation is None:
        data, gone_val = without_left_out(data, result, ("validation",), required=False)
    else:
        validation, gone_val = without_left_out(validation, result, ("validation",),
                                                required=False)
    gone = None if gone is None or gone_val is None else gone + gone_val
    settings_in = dict(result.settings)
    job = "data_file" in settings_in and "program" not in settings_in
    if gone is None or (job and result.gross_errors is None and not result.interrupted):
        notes.append("note: the poses the run left out as gross errors are in these figures: "
                     "its result file does not record them (written by an older iwr; calibrate "
                     "again to have them left out)")
    elif gone:
        notes.append(f"note: {len(gone)} pose(s) the run left out as gross errors are left out "
                     f"here too ({'; '.join(gone)})")
    val = data if validation is None else validation
    if polish:  # on the poses the run identified from: none held out, none its screen left out
        result = _polish(robot, data, result)
        x = np.asarray(result.x, dtype=float)
    problems: dict[Any, Any] = {}
    with kinds.reuse(problems):
        try:  # as the job: from the identification poses before its screen
            start = kind.start(robot, screened)
        except ValueError:  # too few points for a registration guess of their own
            start = None
        report = identifiability(robot, data)
        result = effects_in_range(robot, data, _weighted_fit(robot, data, result, report))
        if (result.gross_errors is None and not job
                and degenerate(robot, data, report) is None):
            # Never screened (iwr-calibrate's engine, iwr.identify): tested here, not re-fitted
            # (issue 22). A job's result was screened by its run (an older one: not recorded).
            # Under the noise model a weighted run recorded (iwr-calibrate --noise), as the job
            # tests a weighted fit's poses; else Pope's test.
            result, val = check_gross_errors(robot, data, val, result,
                                             noise=_recorded_noise(kind, result),
                                             held_out=validation is not None)
        result = _stopped_first(result)
        unc = _uncertainty(robot, data, result, report if result.active is None else None,
                           None, notes, own_covariance=False)
        if unc is not None and result.method == "efficient":
            # A result file does not keep the estimator's covariance: say whose these are.
            notes.append("note: the standard deviations are eq. (10)'s first-order ones at the "
                         "result, not the efficient estimator's covariance (which `iwr "
                         "calibrate` reports; a result file does not keep it): they differ from "
                         "them, several-fold for some parameters (3.3x on the built-in example)")
        _note_widened(robot, result, notes)
        cal = Calibration(
            robot=robot, identification=data, validation=val, held_out=validation is not None,
            result=result, accuracy=accuracy(robot, val, x, start=start), data_name=data_name,
            robot_name=robot_name, identifiability=report, uncertainty=unc, notes=notes,
            settings=dict(settings or {"method": result.method}),
            provenance=provenance, start=start, sources=dict(sources or {}), kind=kind,
            problems=problems, weightless=weightless,
            diagnosis=_diagnosis(robot, data, result, None, notes))
        cal._settle()
    return cal


#: The first cause of a failed fit test of a result a limit stopped before it converged.
STOPPED_CAUSE = (
    "the method stopped before it converged (status stopped): the residuals of its best point "
    "so far hold what it has not fitted yet, which the fit test and the outlier test blame on "
    "the model and on the poses; run it to convergence (more generations, or a polish) before "
    "changing the model or the data")


def _stopped_first(result: IdentificationResult) -> IdentificationResult:
    """``result``, its failed fit test's causes led by :data:`STOPPED_CAUSE` when a limit
    stopped the method before it converged (a DE run of ``iwr-calibrate`` reaching its last
    generation far from the solution: the test says the result does not fit, and the outlier
    test names clean poses; the engineer should first run longer)."""
    from dataclasses import replace

    fit = result.fit
    # Data that cannot identify the robot: no run, however long, would (the verdict's reason
    # stays the first cause).
    if (result.status != "stopped" or fit is None or fit.fit_ok or STOPPED_CAUSE in fit.causes
            or fit.verdict == CANNOT_IDENTIFY):
        return result
    out = IdentificationResult(**dict(result))
    out["fit"] = replace(fit, causes=[STOPPED_CAUSE, *fit.causes])
    return out


#: The methods whose result :func:`polish` refines: the global searches, which end at a limit
#: (``iwr.identify`` polishes DE by default; ``iwr-calibrate``'s engine never does).
GLOBAL_METHODS = ("de", "crs2")


def polish_refusal(result: IdentificationResult) -> str | None:
    """Why :func:`polish` refuses ``result``, or None: not a global search's, polished already,
    or ended by Ctrl-C or a callback (whose job skipped its gross-error screen: resume it)."""
    if result.method not in GLOBAL_METHODS:
        return (f"a result of {result.method!r}: only a global search's ("
                f"{', '.join(GLOBAL_METHODS)}) is polished, which ends at its limit")
    if dict(result.settings).get("polish"):
        return f"the result of {result.method} is polished already"
    if result.interrupted or result.status == "callback":
        return (f"the run was {'interrupted' if result.interrupted else 'stopped by its callback'}"
                " (its gross-error screen did not run): resume it, then polish")
    return None


def polish(robot: Any, data: Any, result: IdentificationResult) -> IdentificationResult:
    """``result``, a global search's identified elsewhere and not polished (``iwr-calibrate``'s
    DE run, which stops at its generation limit: status "stopped", which ``iwr legs`` and ``iwr
    export`` refuse), refined by Levenberg-Marquardt from its ``x`` as
    ``iwr.identify(method="de")`` polishes: on the same objective (weighted by the noise model
    the run recorded, else eq. (10)), bounds and active parameters, on ``data`` (the poses the
    run identified from: :func:`from_result` with ``polish=True`` gives it those, without the
    held-out ones and those its screen left out), then tested as every method's result. The
    polish's result, with the run's record (its method, history, settings, stop reason and
    checkpoint; its cost before in ``settings["polish_result"]``). ValueError for a result
    :func:`polish_refusal` names."""
    kind = kinds.of(data)
    x = check_result(robot, kind, result)
    settings = dict(result.settings)
    refusal = polish_refusal(result)
    if refusal:
        raise ValueError(refusal)
    lm = identify(robot, data, "lm", x0=x, active=result.get("active"),
                  noise=_recorded_noise(kind, result), progress=False,
                  **recorded_bounds(settings, x.size))
    record = {"fun_before": float(result.fun), "fun": float(lm.fun), "nfev": int(lm.nfev),
              "nit": int(lm.nit), "success": bool(lm.success), "message": str(lm.message)}
    head = str(result.message).strip().rstrip(".")
    if not lm.fun <= result.fun:  # never from its own start, but then the run's point stays
        out = IdentificationResult(**dict(result))
        out.update(settings={**settings, "polish": True, "polish_result": record},
                   nfev=int(result.nfev) + int(lm.nfev),
                   message=f"{head}; Levenberg-Marquardt did not lower its cost: {lm.message}")
        return out
    out = IdentificationResult(**{**dict(result), **dict(lm)})
    objective = dict(lm.settings).get("objective")
    out.update(method=result.method, nit=int(result.nit), history=result.history,
               nfev=int(result.nfev) + int(lm.nfev),
               wall_time=float(result.wall_time) + float(lm.wall_time),
               message=f"{head}; polished by Levenberg-Marquardt: {lm.message}",
               settings={**settings, **({"objective": objective} if objective else {}),
                         "polish": True, "polish_result": record})
    return out


_polish = polish  # for from_result, whose argument of that name shadows it


def _recorded_noise(kind: Any, result: IdentificationResult) -> Any:
    """The noise model a weighted result recorded (its settings' ``objective``, written by
    :func:`iwr.identify` and ``iwr-calibrate --noise``), in the kind's form; None without one."""
    objective = dict(result.settings).get("objective")
    if isinstance(objective, dict) and objective.get("weighted"):
        return kind.noise_from_record(objective)
    return None


def calibrated_robot(robot: Any, result: Any, data: Any = None) -> Any:
    """The calibrated robot of an identification: ``robot`` (the nominal one it started from)
    corrected by ``result`` (an :class:`iwr.IdentificationResult`, or its ``x``), as a
    calibration job's ``calibrated.toml`` holds it. For every kind of data: its effects'
    identified values written in; a tracker's registration and reflectors (or probe) and a
    ballbar's set-ups at their calibrated values; and for tracker data {5} moved to the frame
    the measured points fix (the data do not fix {5}), so that a target pose in {T} means
    what a user measures (:func:`iwr.compensation.leg_commands`).

    ``data``: the data identified, all of them (their kind decides what ``result.x`` holds; the
    robot's workspace is widened to hold their poses but those of weight 0 and those the run's
    gross-error screen left out, as the job's is:
    :func:`iwr.compensation.with_measured_workspace`); default the kind ``robot``'s description
    measures (its ``[tracker]`` or ``[ballbar]`` table, else poses in {0}), and the workspace as
    it is. ValueError naming the entry at fault when ``result.x`` is not a result of ``robot``
    on that kind (:func:`check_result`). ``Robot.with_errors`` takes the geometric
    errors alone, and a tracker result's first ones with it keep the nominal registration and
    {5}: commands from that robot are off by the registration's error."""
    kind = kinds.of(data) if data is not None else kinds.for_robot(robot)
    if not hasattr(result, "x"):
        result = SimpleNamespace(x=result, parameter_names=[])
    calibrated = kind.calibrated_robot(robot, check_result(robot, kind, result))[0]
    if data is None:
        return calibrated
    from .compensation import with_measured_workspace

    # The poses the job's sets hold: none of weight 0, none its gross-error screen left out.
    data, _ = kinds.without_weightless(data)
    if getattr(result, "left_out", None):
        data, _ = without_left_out(data, result, required=False)
    return with_measured_workspace(calibrated, data)


def check_result(robot: Any, kind: Any, result: Any) -> np.ndarray:
    """``result.x``, checked to be a vector of errors of ``robot`` on ``kind``'s data (its
    geometric errors, its effects' parameters, then the kind's set-up's): one finite value per
    parameter, the parameters the result names (``parameter_names``, when it names them) these,
    in this order, and a calibrated geometry within the physical limits (what a corrupted or
    hand-edited result file breaks). ValueError naming the entry at fault (``x[5]
    (joint2.da)``); what :func:`from_result`, ``iwr report`` and ``iwr analyze --result`` check
    a result with."""
    names = (robot.parameter_names + effect_parameter_names(robot.effects)
             + kind.setup_parameter_names(robot))
    x = np.asarray(result.x, dtype=float)
    if x.ndim != 1:
        raise ValueError(f"x: expected a list of numbers, one per parameter, got an array of "
                         f"shape {x.shape}")
    if x.shape != (len(names),):
        raise ValueError(f"{x.size} parameters, but robot {robot.name!r} "
                         + _extras(robot, kind) + f"has {len(names)}")
    saved = list(result.parameter_names)
    if saved and saved != names:
        head = (f"its parameters are not those of robot {robot.name!r}"
                + f" {_extras(robot, kind)}".rstrip())
        if len(saved) != len(names):
            raise ValueError(f"{head}: parameter_names has {len(saved)} names for the "
                             f"{len(names)} values of x")
        k = next(i for i, (a, b) in enumerate(zip(saved, names, strict=True)) if a != b)
        raise ValueError(f"{head}: first difference parameter_names[{k}] {saved[k]!r}, the "
                         f"robot's {names[k]!r}")
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        k = int(bad[0])
        more = f" (and {bad.size - 1} more)" if bad.size > 1 else ""
        raise ValueError(f"x[{k}] ({names[k]}) is {x[k]}{more}: a result that is not finite "
                         "is no robot's errors")
    n = robot.n_params
    try:
        robot.with_errors(x[:n])
    except ValueError as exc:  # the calibrated geometry beyond any robot: the entry at fault
        k = next((j for j in np.argsort(-np.abs(x[:n]), kind="stable")
                  if not _within_limits(robot, j, x[j])), None)
        if k is None:
            raise
        unit = "rad" if robot.angle_parameters[k] else "mm"
        raise ValueError(f"x[{k}] ({names[k]}) is {x[k]:g} {unit}: the calibrated robot's "
                         f"{exc}") from None
    return x


def _within_limits(robot: Any, k: int, value: float) -> bool:
    """Whether the robot with the error ``value`` on its parameter ``k`` alone is one."""
    e = np.zeros(robot.n_params)
    e[k] = value
    try:
        robot.with_errors(e)
    except ValueError:
        return False
    return True


def _extras(robot: Any, kind: Any) -> str:
    """What a result's parameters hold beyond the robot's geometric errors, for messages."""
    parts = (["its effects"] if robot.effects else []) + (
        [kind.setup_words] if kind.setup_parameter_names(robot) else [])
    return f"with {' and '.join(parts)} " if parts else ""


def _weighted_fit(robot: Any, data: Any, result: IdentificationResult, report: Any
                  ) -> IdentificationResult:
    """A result identified elsewhere on a noise-weighted objective (``iwr-calibrate --noise``:
    its settings name the ``weighting``) and not tested: its cost is the chi-square statistic
    of the fit (the whitened residuals' sum of squares), tested by
    :func:`iwr.fit_test.fit_check` (``weighted``) against chi2 with the readings less the
    identifiable parameters (``report``'s rank) as degrees of freedom, beside the size check.
    A copy of ``result``, ``failed`` when it fails; ``result`` itself when there is nothing to
    test."""
    from .fit_test import fit_check

    settings = dict(result.settings)
    x = np.asarray(result.x, dtype=float)
    if (not settings.get("weighting") or result.fit is not None or result.interrupted
            or not (np.all(np.isfinite(x)) and math.isfinite(float(result.fun)))):
        return result
    # The readings the weighted objective has: a probe's whitening has six rows a pose that
    # carry data, not its four points' twelve coordinates (the unweighted problem's).
    kind = kinds.of(data)
    noise = _recorded_noise(kind, result)
    problem, _ = kind.problem(robot, data, noise=noise)
    active = result.active
    mask = np.ones(x.size, dtype=bool) if active is None else np.asarray(active, dtype=bool)
    # The recorded noise model gives the size test the estimate's spread, as the job's fit
    # check has it: a poorly determined parameter beyond its size is a note, not a misfit.
    fit = fit_check(robot, data, x, active=mask, noise=noise,
                    weighted=(float(result.fun), problem.n_observations, int(report.rank)))
    out = IdentificationResult(**dict(result))
    # A weighted engine run stopped by its generation limit: a passing test is of that point.
    out["fit"] = fit.stopped() if result.status == "stopped" else fit
    if out.success and not fit.fit_ok:
        out.update(success=False, status="failed", message=f"{fit.verdict} (the method: "
                   f"{str(result.message).strip().rstrip('.')})")
    return out


def _uncertainty(robot: Any, data: Any, result: Any, report: Any, noise: Any, notes: list[str],
                 *, own_covariance: bool = True) -> Uncertainty | None:
    """The standard deviations of the identified parameters: the efficient estimator's own
    covariance when it has one (eq. (10)'s first-order covariance differs from it, several-fold
    for some parameters),
    else the objective's the method minimised (weighted by ``noise`` when it was) over the
    result's active parameters, or ``report``'s identifiable ones. None, with a note, where
    they do not exist."""
    try:
        unc = Uncertainty.from_result(result) if own_covariance else None
        if unc is None:
            active = result.active if report is None else report
            recorded = _recorded_noise(kinds.of(data), result)
            if recorded is not None:
                # The weighted objective: the noise model given (the job), else the one the
                # result recorded (a result read back).
                unc = uncertainty(robot, data, result.x, recorded if noise is None else noise,
                                  active=active, weighted=True)
            else:
                unc = uncertainty(robot, data, result.x, active=active)
    except (ValueError, TypeError, KeyError) as exc:
        notes.append(f"note: no standard deviations: {_one_line(exc)}")
        return None
    return unc


def _best_so_far(robot: Any, data: Any, kind: Any, method: str, best: _Best, active: Any,
                 bounds: Any) -> IdentificationResult:
    """The result of an identification that Ctrl-C cut short without a result: the best point
    the callback saw (else the start), its cost evaluated afresh."""
    problem, start = kind.problem(robot, data, bounds)
    x = best.x
    if x is None or x.shape != (problem.n_params,):
        x = np.asarray(start, dtype=float)
    return IdentificationResult(
        x=x, fun=problem.cost(x), nfev=best.calls, nit=0, success=False, status="interrupted",
        message="interrupted (Ctrl-C)", method=method,
        parameter_names=list(problem.parameter_names), active=active, settings={}, history={},
    )


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())
