"""Measurement kinds: what one instrument's data are, and what every calibration step needs of
them, behind one protocol (:class:`MeasurementKind`).

A kind is a type, not a branch. The platform pose measured in the world frame {0} (the paper's
data, :class:`iwr.kinds.pose.PoseKind`), reflector points measured by a laser tracker in its
own frame {T} and a tracker probe's pose in {T} (:mod:`iwr.tracker.kind`) are implementations of
:class:`MeasurementKind`. :func:`of` finds the kind of a data set (its ``kind`` attribute names
it), :func:`for_robot` the kind a robot's description measures; the public functions
(:func:`iwr.simulate`, :func:`iwr.identify`, :func:`iwr.accuracy`, :func:`iwr.identifiability`,
:func:`iwr.uncertainty`, the efficient estimator, :func:`iwr.plan_poses`) call the kind's
methods and never test the type of their data. A new instrument is a new class in its own
module and one :func:`register` line (``register("name", "package.module:Class")``; the module
is imported on first use, so that it may import the modules of the public functions, where the
built-in kinds' implementations still live: docs/kinds.md).

What a kind says of its data: the frame they are given in and whether they fix the robot's world
frame (``frame``, ``determines_world_frame``), the setup parameters identified beside the
robot's (``setup_parameter_names``), its files (``read``), simulation (``simulate``), subsets
(``subset``), the fingerprint that ``iwr-calibrate``'s problem file records (``fingerprint``),
its problem and starting point (``problem``), and the per-kind part of each algorithm.
:func:`split` holds validation poses out by one rule for every kind.
"""

from __future__ import annotations

import abc
import contextlib
import contextvars
import numbers
import os
from typing import Any, ClassVar

import numpy as np

from .._registry import Registry

__all__ = [
    "MeasurementKind",
    "available",
    "for_robot",
    "named",
    "observed",
    "of",
    "register",
    "reuse",
    "split",
    "split_rows",
]


class MeasurementKind(abc.ABC):
    """The protocol every kind of measurement implements (one instance per kind).

    ``x`` of every call holds the robot's ``n_params`` error parameters, then the kind's setup
    parameters (:meth:`setup_parameter_names`; none for poses in {0})."""

    #: The kind's name as data, problem files and reports say it (``"pose"``, ``"points"``, ...).
    name: ClassVar[str]
    #: What one pose's reading is, for messages and reports.
    description: ClassVar[str]
    #: The frame the data are given in: ``"{0}"`` (the robot's world frame), ``"{T}"`` (the
    #: tracker's).
    frame: ClassVar[str]
    #: The name of that frame's link in an exported URDF where it is not {0} (``"tracker"``
    #: for {T}), fixed in the world frame's link by the calibrated registration; None:
    #: ``frame_`` and the frame's name.
    frame_link: ClassVar[str | None] = None
    #: Whether the data fix the robot's world frame {0}. Point data do not (the registration and
    #: a rigid motion of {5} are in the null space), so what is said in {0} after such a
    #: calibration is a gauge choice (docs/tracker.md).
    determines_world_frame: ClassVar[bool]
    #: Whether :func:`iwr.estimation.fit_check` can test an eq. (10)-type solution's cost with a
    #: noise model (else only the efficient estimator tests the fit of these data).
    chi2_fit_test: ClassVar[bool] = False
    #: What the setup parameters (:meth:`setup_parameter_names`) belong to, as a result's
    #: parameters are described in messages ("with its effects and {setup_words}").
    setup_words: ClassVar[str] = "its instrument's setup"
    #: Whether :func:`for_robot` chooses this kind only when no other applies (the pose in {0}:
    #: a robot describes no instrument for it).
    fallback: ClassVar[bool] = False
    #: Whether the methods other than the efficient estimator minimise an objective weighted by
    #: a noise model on these data (:func:`iwr.identify` with ``noise=``).
    weighted_objective: ClassVar[bool] = False
    #: The relative rank threshold of the column-scaled Jacobian below which a singular value
    #: is a null direction of these data, or None: NumPy's ``max(shape) * eps``.
    null_rtol: ClassVar[float | None] = None
    #: Whether ``iwr-calibrate`` (the C++ engine) takes these data: their problem has a problem
    #: file (``problem.save``).
    engine: ClassVar[bool] = True
    #: Whether the calibration job (:func:`iwr.calibrate`, ``iwr report``) models a robot's
    #: non-geometric effects on these data (issue 23: every step of it, with the effects).
    models_effects: ClassVar[bool] = False
    #: The report of a calibration on these data, ``"module:Class"`` (a subclass of
    #: :class:`iwr.reporting.calibration.CalibrationReport`), imported by the report layer.
    report: ClassVar[str] = "iwr.reporting.calibration:CalibrationReport"

    # -- the data -----------------------------------------------------------------------------

    @abc.abstractmethod
    def owns(self, data: Any) -> bool:
        """Whether ``data`` (whose ``kind`` attribute names this kind) are of its data type."""

    @abc.abstractmethod
    def applies_to(self, robot: Any) -> bool:
        """Whether ``robot``'s description measures this kind (its setup, if any, says so)."""

    @abc.abstractmethod
    def setup_parameter_names(self, robot: Any) -> list[str]:
        """The setup parameters identified beside the robot's (registration, offsets, ...)."""

    def n_params(self, robot: Any) -> int:
        """Length of a parameter vector on these data: the robot's, then the setup's."""
        return int(robot.n_params) + len(self.setup_parameter_names(robot))

    def check(self, robot: Any, data: Any) -> None:
        """ValueError unless ``data`` can be calibrated with ``robot``: its setup measures this
        kind, and the data's joint and leg readings are the robot's (``check_readings``: joint
        types, ranges, revolute joints in radians)."""
        if not self.applies_to(robot):
            measured = for_robot(robot)
            raise ValueError(
                f"measurements: {self.description} in {self.frame} ({self.name} data), but robot "
                f"{getattr(robot, 'name', '?')!r} measures {measured.description} in "
                f"{measured.frame} ({measured.name} data): " + self._setup_hint())
        # Every kind's data hold the robot's joint and leg readings (RobotReadings): within the
        # robot's ranges, revolute joints in radians.
        check_readings = getattr(data, "check_readings", None)
        if check_readings is not None:
            check_readings(robot)

    def _setup_hint(self) -> str:
        return "describe the instrument in the robot's TOML file (docs/data.md, docs/tracker.md)"

    def read_setup(self, setup: Any, where: str) -> Any:
        """The kind's instrument set-up from the robot TOML's table named after the kind
        (``setup`` a mapping; errors name ``where`` and the key) or a set-up object of the
        kind's own, checked: what ``Robot.instruments`` holds (``Robot.with_instrument``). The
        set-up's ``to_dict()`` is the table written back. The default: the kind is described
        by no table of its own (poses in {0}: none; the tracker: the robot's ``[tracker]``
        table, ``Robot.tracker``)."""
        raise ValueError(f"[{where}]: measurement kind {self.name!r} is not described by a "
                         "table of its own; " + self._setup_hint())

    def subset(self, data: Any, rows: Any) -> Any:
        """The poses at ``rows`` (indices or a boolean mask), lines and source kept."""
        return data.subset(rows)

    @abc.abstractmethod
    def fingerprint(self, robot: Any, data: Any) -> str:
        """16 hex digits: the data's fingerprint as the problem file records it (the C++
        ``ProblemData::data_fingerprint``), computed without building the problem."""

    @abc.abstractmethod
    def read(self, path: str | os.PathLike[str], robot: Any, **options: Any) -> Any:
        """Read a data file of this kind for ``robot``, with every check (errors name the file
        and line); TypeError naming an option the kind's files do not take."""

    def recognises(self, path: str | os.PathLike[str]) -> bool:
        """Whether the file at ``path`` looks like this kind's data (its header, nothing more
        checked; False for a file that cannot be read): how a command that takes either this
        kind's data or poses in {0} (``iwr plan``'s candidates) tells them apart. Default: no
        file of its own."""
        return False

    def write(self, robot: Any, data: Any, path: str | os.PathLike[str]) -> list[str]:
        """Write ``data`` (atomically) as the file(s) :meth:`read` reads back, ``path`` the main
        one; a description of each file written (``iwr simulate``). Default: the data's own
        ``to_csv``."""
        data.to_csv(path)
        return [f"{path} (measurements)"]

    def noise_record(self, noise: Any) -> dict[str, Any]:
        """The noise model a simulation of this kind took (:meth:`reading_noise`'s form), as
        the JSON fields of a truth file (``iwr simulate``). Default: ``{"noise": fields}``."""
        import dataclasses

        return {"noise": dataclasses.asdict(noise)}

    def noise_from_record(self, record: dict[str, Any]) -> Any:
        """The noise model :meth:`noise_record` wrote (a result's weighted objective, a truth
        file), in :meth:`reading_noise`'s form. Default: ``Noise(**record["noise"])``."""
        from ..noise import Noise

        return Noise(**record["noise"])

    def rows(self, data: Any) -> np.ndarray:
        """Each pose's readings and measurements as one row (N, k), NaN where nothing was seen:
        two equal rows are the same pose measured twice
        (:func:`iwr.analysis.identifiability.distinct_poses`). Default: the joint and leg
        readings, then the data's ``measured`` columns."""
        n = len(data)
        return np.hstack([np.asarray(data.q, dtype=float).reshape(n, -1),
                          np.asarray(data.legs, dtype=float).reshape(n, -1),
                          self.measured(data).reshape(n, -1)])

    def measured(self, data: Any) -> np.ndarray:
        """What the instrument measured at each pose, one row per pose (for :meth:`rows`)."""
        raise NotImplementedError(f"{self.name} data: MeasurementKind.measured")

    @abc.abstractmethod
    def simulate(self, robot: Any, n_poses: int, *, seed: int | None, x: Any = None,
                 noise: Any = None) -> tuple[Any, np.ndarray]:
        """``(data, x_true)``: :func:`iwr.simulate` for this kind."""

    # -- the problem and the algorithms' per-kind part ---------------------------------------

    @abc.abstractmethod
    def problem(self, robot: Any, data: Any, bounds: Any = None, x0: Any = None,
                noise: Any = None) -> tuple[Any, np.ndarray]:
        """The least-squares problem of these data (``cost``, ``residuals``, ``jacobian``,
        ``cost_batch``, ``lower``/``upper``, ``parameter_names``) and its default start;
        weighted by ``noise`` (the form :meth:`reading_noise` gives) when given, for a kind
        with a :attr:`weighted_objective` (ValueError for the others)."""

    @abc.abstractmethod
    def identify(self, robot: Any, data: Any, method: str, **options: Any) -> Any:
        """:func:`iwr.identify` for this kind (``method`` already checked)."""

    @abc.abstractmethod
    def accuracy(self, robot: Any, data: Any, x: Any, **options: Any) -> Any:
        """:func:`iwr.accuracy`: what accuracy means for this kind. ``options``: ``tool``,
        ``truth``, ``tolerance``, ``max_iterations`` and ``start`` (:meth:`start` of the
        identification data, or None: what the "before" figure starts from)."""

    @abc.abstractmethod
    def identifiability(self, robot: Any, data: Any, x: Any = None, **options: Any) -> Any:
        """:func:`iwr.identifiability` for this kind."""

    @abc.abstractmethod
    def uncertainty(self, robot: Any, data: Any, x: Any, noise: Any, **options: Any) -> Any:
        """:func:`iwr.uncertainty` for this kind."""

    @abc.abstractmethod
    def estimator(self, robot: Any, data: Any, noise: Any, **options: Any) -> Any:
        """The efficient estimator's model of these data (:func:`iwr.estimation.efficient`):
        the readings, their noise and the nuisance unknowns per pose."""

    @abc.abstractmethod
    def plausibility(self, robot: Any, data: Any, bounds: Any, plausible: float
                     ) -> tuple[list[str], np.ndarray, np.ndarray, Any]:
        """For :func:`iwr.estimation.fit_check`: the parameter names, each parameter's plausible
        size and centre, and the readings model ``x -> (residuals, Jacobian)`` whose null
        directions the size test ignores."""

    def whitened(self, robot: Any, data: Any, x: Any, noise: Any
                 ) -> tuple[np.ndarray, np.ndarray, int]:
        """For the chi-square test of :func:`iwr.estimation.fit_check` (the kinds with
        :attr:`chi2_fit_test`): the residuals at ``x`` and their Jacobian (every parameter's
        column), each pose's whitened by the covariance of its residuals propagated to first
        order from every instrument's ``noise`` at ``x``, and the number of readings that carry
        data (the statistic's degrees of freedom before the fitted parameters). ValueError for a
        noise model whose covariance is singular."""
        raise NotImplementedError(f"{self.name} data: no chi-square test of the fit")

    def misclosures(self, robot: Any, data: Any, x: Any, noise: Any = None) -> Any:
        """For :mod:`iwr.gross_errors`: the linearised readings model at ``x``
        (:class:`iwr.misclosures.Misclosures`). This default: the residuals of :meth:`problem`
        per pose, their Jacobian, each residual its own reading with unit weight; no noise model
        (a kind that has one overrides this, with the derivatives in every reading)."""
        from ..misclosures import Misclosures

        if noise is not None:
            raise ValueError(f"noise: the gross-error test of {self.name} data has no noise "
                             "model; give noise=None (the noise is then estimated from the "
                             "residuals)")
        problem, _ = self.problem(robot, data)
        n = len(data)
        r = np.asarray(problem.residuals(x), dtype=float).reshape(n, -1)
        a = np.asarray(problem.jacobian(x), dtype=float).reshape(n, r.shape[1], -1)
        names = [f"residual{j + 1}" for j in range(r.shape[1])]
        b = np.broadcast_to(-np.eye(r.shape[1]), (n, r.shape[1], r.shape[1])).copy()
        return Misclosures(r, a, b, names, names)

    @abc.abstractmethod
    def candidate_poses(self, robot: Any, data: Any) -> Any:
        """For :func:`iwr.plan_poses`: the candidates as :class:`iwr.Measurements` with their
        platform poses in {0} (measured, or the nominal robot's forward kinematics)."""

    #: Whether each reading belongs to one of the instrument's set-ups (a ballbar's): then
    #: :func:`iwr.plan_poses` chooses (pose, set-up) pairs (:meth:`plan_candidates`) and
    #: :func:`iwr.planning.measure` takes each pose's set-up (``setup=``).
    setups_per_pose = False

    def plan_candidates(self, robot: Any, candidates: Any, setup: Any) -> Any:
        """For :func:`iwr.plan_poses`: the rows to choose from, made of the candidate poses
        (:meth:`candidate_poses`' form) and ``setup``, a set-up name per pose or None. Default:
        the candidates as they are; set-up names refused (this kind has none)."""
        if setup is not None:
            raise ValueError(f"candidates: set-up names given, but robot "
                             f"{getattr(robot, 'name', robot)!r} is measured by "
                             f"{self.description}, whose readings belong to no set-up")
        return candidates

    @abc.abstractmethod
    def design(self, robot: Any, candidates: Any, x: Any, report: Any
               ) -> tuple[Any, np.ndarray, np.ndarray, int, str]:
        """For :func:`iwr.plan_poses`: the problem of the candidate poses (measured by the nominal
        instrument), ``x``, the indices of the base parameters (``report``'s, or computed), the
        readings per pose and what they are called."""

    @abc.abstractmethod
    def measure(self, robot: Any, x: np.ndarray, q: np.ndarray, poses: np.ndarray, noise: Any,
                rng: np.random.Generator) -> Any:
        """For :func:`iwr.planning.measure`: this kind's readings of the actual robot ``x`` at
        joint readings ``q`` and platform poses ``poses`` in {0}, with ``noise`` (a kind with
        :attr:`setups_per_pose` also takes ``setup=``, each pose's set-up)."""

    # -- the calibration job's per-kind part (iwr.calibrate) --------------------------------

    def frame_check(self, robot: Any, data: Any) -> Any:
        """Whether a frame or column mistake puts the data far from the robot, checked before
        anything is identified (:class:`iwr.pose_frame.PoseFrameCheck`: ``ok``, ``diagnosis``,
        ``message``), or None when the kind has no such check."""
        return None

    def calibrated_robot(self, robot: Any, x: Any) -> tuple[Any, dict[str, Any]]:
        """The calibrated robot of ``x``, a result on this kind's data (``robot``'s errors, its
        effects' parameters, then the kind's set-up's), as ``calibrated.toml`` holds it, and
        what that file's ``[provenance]`` says of it beyond the job (the tracker's platform
        frame): the one way a result becomes a robot (:func:`iwr.calibrated_robot`, the
        calibration job's files). Here the robot's own part, its effects' values included; a
        kind with a set-up writes the set-up's calibrated values too."""
        from .._hooks import hook
        from ..effects import parameter_names as effect_names

        n = robot.n_params + len(effect_names(robot.effects))
        x = np.asarray(x, dtype=float)
        if robot.effects:
            return hook("apply_effects")(robot, x[:n]), {}
        return robot.with_errors(x[:n]), {}

    def registration(self, robot: Any, x_setup: Any = None) -> np.ndarray:
        """The frame the data are given in, in {0} (a 4x4 transform): the identity for data in
        {0}; the tracker's registration (at its setup parameters ``x_setup``, default the
        robot's) for data in {T}."""
        return np.eye(4)

    def diagnose(self, robot: Any, data: Any, x: Any, *, active: Any = None,
                 noise: Any = None) -> Any:
        """Whether the residuals of a geometric fit ``x`` correlate with the loads or the
        temperatures the data carry (:class:`iwr.effects.job.Diagnosis`), or None when they carry
        neither. A kind that models no diagnosis says so (ValueError: the job notes it)."""
        if getattr(data, "payload", None) is None and getattr(data, "temperatures", None) is None:
            return None
        raise ValueError(f"{self.name} data: the residuals are tested against the loads and "
                         "temperatures on pose, tracker and ballbar data only (docs/effects.md)")

    def world_gravity(self, robot: Any) -> np.ndarray | None:
        """Gravity in {0} (m/s^2) as the instrument of ``robot``'s description gives it, for the
        effects that load the robot (issue 23), or None when the effects' own ``gravity_m_s2``
        in {0} stands (data in {0}). ValueError for an effect these data do not model."""
        return None

    def reading_noise(self, noise: Any) -> Any:
        """``noise`` (an :class:`iwr.Noise`, ``"estimate"``, or the kind's own form) in the form
        this kind's estimator takes."""
        return noise

    def start(self, robot: Any, data: Any) -> Any:
        """What the identification starts from beyond the nominal robot, for the report (the
        tracker's registration guess), or None."""
        return None

    def job_lines(self, robot: Any, data: Any, n_identification: int, method: str) -> list[str]:
        """What :func:`iwr.calibrate` says before it identifies (its ``log``)."""
        return [f"identifying with {method} ({n_identification} poses; Ctrl-C stops and keeps "
                "the best point so far)"]

    def weighting_note(self, data: Any, method: str, data_name: str) -> str:
        """A note for the report when the data carry their own weights that ``method`` uses in
        place of the noise model, else ``""``."""
        return ""

    def predicted_accuracy(self, robot: Any, data: Any, x: Any, covariance: Any, active: Any,
                           seed: int) -> Any:
        """The tool accuracy the covariance of the active parameters predicts at the poses of
        ``data`` (:class:`iwr.estimation.PredictedAccuracy`)."""
        raise NotImplementedError(f"{self.name} data: no predicted accuracy")

    def improvement(self, accuracy: Any, held_out: bool) -> tuple[float, float, str, str]:
        """``(before, after, sentence, what)``: the error the calibration is judged by
        (:func:`iwr.calibrate` calls a run that makes it worse "not calibrated"), before and
        after, in words, and what it is. The default: the tool position RMS of an
        :class:`iwr.Accuracy`."""
        before = accuracy.nominal.summary()["position_mm"]["rms"]
        after = accuracy.calibrated.summary()["position_mm"]["rms"]
        change = (f"tool position RMS error {before:.4g} mm before, {after:.4g} mm after, on "
                  f"{_where(accuracy.n_poses, held_out)}")
        return before, after, change, "the accuracy"

    #: The components of one per-pose error of :meth:`per_pose_errors` (3: a tool position or
    #: a reflector point; 1: a distance residual): how many validation poses the verdict's
    #: paired test needs (:func:`iwr.calibration.validation_poses_needed`, ``iwr plan``).
    verdict_error_dims: int = 3

    def per_pose_errors(self, accuracy: Any) -> tuple[np.ndarray, np.ndarray] | None:
        """``(before, after)``: the per-pose errors whose RMS are :meth:`improvement`'s
        ``before`` and ``after``, one each per validation pose (NaN where a pose has none), for
        the paired test of whether the calibration made them worse
        (:func:`iwr.calibration.judge`); None when the kind has no such figures (the job then
        judges by the ratio of the two RMS alone). The default: an :class:`iwr.Accuracy`'s
        per-pose ``position`` of the nominal and of the calibrated robot, which the default
        :meth:`improvement` and the tracker's and ballbar's (:func:`position_rms`) take the RMS
        of. A kind that judges by another figure overrides both."""
        try:
            before = np.asarray(accuracy.nominal.position, dtype=float)
            after = np.asarray(accuracy.calibrated.position, dtype=float)
        except AttributeError:
            return None
        if before.ndim != 1 or before.shape != after.shape:
            return None
        return before, after
    # -- the experiments (iwr compare, iwr study) ---------------------------------------------
    # What a simulated calibration needs of the kind beyond the calibration steps: its noise at
    # an experiment's noise level, the actual set-up, and its yardsticks on fresh poses. Each
    # has a default that suits a kind whose readings are exact functions of the truth.

    #: What the experiments' figures measure for this kind, for their tables and captions:
    #: ``cost`` (the unweighted objective, mm^2) and ``cost_label`` (its short name),
    #: ``readings`` (the validation residuals), ``tool`` (the tool pose error against the
    #: truth), ``parameters`` (the parameter error modulo the null directions),
    #: ``noise_level`` (what an experiment's noise level sets; ``noise_panel``, a format of
    #: ``level`` and ``ratio`` to the realistic 0.02, ``noise_axis``, its words in a study's
    #: figures, and ``noise_unit``, after a list of levels), ``gauge`` (what the data leave
    #: free and how the figures treat it; empty when nothing), ``readings_short`` and
    #: ``tool_short`` (a word for the readings, and what qualifies the tool pose error, in the
    #: figures' labels).
    experiment_text: ClassVar[dict[str, str]] = {
        "cost": "the sum of squared residuals of the readings (mm^2)",
        "cost_label": "the unweighted objective",
        "readings_short": "reading",
        "tool_short": "",
        "readings": "readings predicted with the recovered parameters against their exact values "
                    "(mm)",
        "tool": "tool pose error against the truth by forward kinematics of the readings",
        "parameters": "x minus the parameter vector nearest to x that predicts exactly the "
                      "truth's readings at the validation poses, projected onto the identifiable "
                      "directions",
        "noise_level": "the measurement noise scaled from iwr.Noise.realistic() (level 0.02)",
        # A study figure's panel title and axis: a level scales every instrument's noise.
        "noise_panel": "noise level {level:g} ({ratio:g} x realistic)",
        "noise_axis": "noise level (0.02: realistic)",
        "noise_unit": "",
        "gauge": "",
    }

    def experiment_noise(self, robot: Any, noise: Any) -> Any:
        """The noise model that :meth:`simulate` and the efficient estimator take for an
        experiment's ``noise``: an :class:`iwr.Noise` (a noise level's,
        :func:`iwr.experiments.harness.noise_at`, or a user's) or already this kind's model.
        Default: as it is."""
        return noise

    def draw_setup(self, robot: Any, rng: np.random.Generator) -> np.ndarray:
        """The setup parameters of an experiment's actual set-up (registration, offsets, ...),
        drawn from ``rng`` after the robot's errors. Default: the nominal setup (zeros)."""
        return np.zeros(len(self.setup_parameter_names(robot)))

    def angle_parameters(self, robot: Any) -> np.ndarray:
        """Which parameters of ``x`` are angles (rad): the robot's, its effects' (issue 23:
        none), then the setup's (default: none of the setup's)."""
        from ..effects import parameter_names as effect_names

        n = len(effect_names(robot.effects)) + len(self.setup_parameter_names(robot))
        return np.concatenate([np.asarray(robot.angle_parameters, dtype=bool),
                               np.zeros(n, dtype=bool)])

    def readings_per_pose(self, robot: Any, data: Any) -> float:
        """Independent readings one pose gives of the parameters (the fewest poses an
        identification needs is the identifiable parameters divided by this). Default: the
        problem's residuals that carry data, per pose."""
        problem, _ = self.problem(robot, data)
        n = getattr(problem, "n_observations", None)
        return float(problem.n_residuals if n is None else n) / len(data)

    def tool_accuracy(self, robot: Any, data: Any, x: Any, truth: Any, start: Any = None) -> Any:
        """The tool pose errors (:class:`iwr.Accuracy`: nominal and calibrated) of ``x`` on
        ``data``, exact readings of the actual robot ``truth``; "nominal" in ``start``
        (:meth:`start` of the identification data, as :meth:`accuracy`). Default:
        :meth:`accuracy` (measured poses of exact data are the truth's)."""
        return self.accuracy(robot, data, x, start=start)

    def before(self, robot: Any, data: Any, start: Any = None) -> tuple[Any, np.ndarray]:
        """The problem of ``data`` and the vector the "before" figures are at: the nominal robot
        in the identification's ``start`` (:meth:`start` of the identification data, what
        :meth:`accuracy`'s "before" starts from; None: the start of :meth:`problem` on
        ``data``). Default: the start of :meth:`problem` (the nominal robot)."""
        return self.problem(robot, data)

    def validate(self, robot: Any, data: Any, x: Any, truth: Any, start: Any = None, *,
                 nominal: bool = True) -> dict[str, float]:
        """The validation figures of ``x`` on ``data`` (fresh poses of the actual robot ``truth``,
        read without noise): ``val_rms``, ``val_max`` (the readings' residuals at ``x``, mm),
        ``val_rms_nominal`` (at :meth:`before`: the nominal robot in ``start``, the
        identification's :meth:`start`, as :func:`iwr.calibrate`'s "before"; nan when there is
        none); then ``tool_position_rms``, ``tool_orientation_rms`` (degrees) and
        ``tool_position_rms_nominal`` from :meth:`tool_accuracy` with the same ``start`` (nan,
        with ``notes`` saying why, where it fails). ``nominal=False``: no "before" (the
        identification had no start of the kind's own, e.g. no registration guess for a nominal
        robot far from the data): the nominal figures nan, none guessed on ``data`` (which would
        flatter the nominal robot). The residuals do not depend on the gauge: null directions
        leave them unchanged."""
        problem, _ = self.problem(robot, data, x0=x)
        seen = observed(problem)
        err = np.asarray(problem.residuals(x))[seen]
        out: dict[str, Any] = {
            "val_rms": _rms(err), "val_max": float(np.max(np.abs(err))),
            "val_rms_nominal": float("nan"),
            "tool_position_rms": float("nan"), "tool_orientation_rms": float("nan"),
            "tool_position_rms_nominal": float("nan"),
        }
        notes = []
        try:
            if nominal:
                before, x_before = self.before(robot, data, start)
                out["val_rms_nominal"] = _rms(np.asarray(before.residuals(x_before))[seen])
        except _FAILURES as exc:  # e.g. no set-up guess for a nominal robot far from the data
            notes.append(f"nominal: {type(exc).__name__}: {exc}")
        try:
            acc = self.tool_accuracy(robot, data, x, truth, start)
        except _FAILURES as exc:  # e.g. forward kinematics of a poor model diverges
            notes.append(f"accuracy: {type(exc).__name__}: {exc}")
        else:
            out.update(tool_position_rms=_rms(acc.calibrated.position),
                       tool_orientation_rms=_rms(acc.calibrated.orientation),
                       tool_position_rms_nominal=(_rms(acc.nominal.position) if nominal
                                                  else float("nan")))
        if notes:
            out["notes"] = "; ".join(notes)
        return out

    def parameter_error(self, robot: Any, data: Any, x: Any, truth: Any) -> Any:
        """``x - truth`` modulo what ``data`` (exact readings of the actual robot ``truth``)
        cannot see (an :class:`iwr.analysis.identifiability.ParameterError`): the kinds'
        implementations say over which parameters. Default: NotImplementedError (the
        experiments then leave the figure out and say so)."""
        raise NotImplementedError(f"kind {self.name!r} has no parameter error modulo its null "
                                  "directions")

    def __repr__(self) -> str:
        return f"<measurement kind {self.name!r}: {self.description} in {self.frame}>"


def finite_rms(v: Any) -> float:
    """The RMS of the finite values of ``v`` (NaN where there are none)."""
    a = np.asarray(v, dtype=float)
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a**2))) if a.size else float("nan")


def position_rms(accuracy: Any) -> tuple[float, float]:
    """The RMS of an :class:`iwr.Accuracy`'s per-pose ``position`` figures, before and after
    (NaN ignored): what a kind whose accuracy is a residual per pose is judged by."""
    return finite_rms(accuracy.nominal.position), finite_rms(accuracy.calibrated.position)


def _where(n_poses: int, held_out: bool) -> str:
    """The poses an accuracy figure is on, in words."""
    return (f"{n_poses} validation poses" if held_out else
            f"the {n_poses} identification poses (nothing held out: optimistic)")


# -- problems built once per job ---------------------------------------------------------------

_MEMO: contextvars.ContextVar[dict[Any, Any] | None] = contextvars.ContextVar(
    "iwr_kinds_memo", default=None)


@contextlib.contextmanager
def reuse(memo: dict[Any, Any] | None = None) -> Any:
    """Within the block, each data set's problem (and its start, the tracker's registration
    guess) is built once and shared by every call that asks for it (:func:`memo`), so that one
    calibration job builds it once. ``memo`` continues an earlier block's (the report of a
    job); the data and robot objects must not be changed inside. Yields the memo."""
    outer = _MEMO.get()
    if memo is None:
        memo = outer if outer is not None else {}
    token = _MEMO.set(memo)
    try:
        yield memo
    finally:
        _MEMO.reset(token)


def memo(key: tuple[Any, ...], objects: tuple[Any, ...], build: Any) -> Any:
    """``build()``, kept for ``key`` and the identity of ``objects`` inside a :func:`reuse`
    block (the objects are held so that their identities stay theirs); outside, built afresh.
    ``build=None`` only looks: the kept value, or None."""
    cache = _MEMO.get()
    if cache is None:
        return None if build is None else build()
    full = (*key, *(id(o) for o in objects))
    hit = cache.get(full)
    if hit is None:
        if build is None:
            return None
        hit = cache[full] = (build(), objects)
    return hit[0]
# What a figure's computation raises deterministically (recorded, not retried).
_FAILURES = (ValueError, ArithmeticError, RuntimeError, np.linalg.LinAlgError)


def _rms(v: Any) -> float:
    a = np.asarray(v, dtype=float)
    return float(np.sqrt(np.mean(np.square(a)))) if a.size else float("nan")


def observed(problem: Any) -> np.ndarray:
    """The residuals of ``problem`` that carry data (a tracker problem's unseen points are
    zeros): all of them unless the problem says which it holds (``seen``)."""
    mask = getattr(problem, "seen", None)
    return np.ones(problem.n_residuals, dtype=bool) if mask is None else np.asarray(mask, bool)


def data_fingerprint(kind: str, robot: Any, data: Any, *, poses: Any = None, weights: Any = None,
                     probe_poses: Any = None, points: Any = None, **own: Any) -> str:
    """The problem file's data fingerprint of these arrays (C++ ``ProblemData::data_fingerprint``
    through ``iwr._core._data_fingerprint``), for the kinds' :meth:`MeasurementKind.fingerprint`;
    ``own``: a kind's own fields of the file, as ``_data_fingerprint`` names them (ballbar data:
    ``bar_names``, ``bar``, ``distance``)."""
    from .. import _core

    empty = np.zeros((0, 0))

    def arr(a: Any) -> np.ndarray:
        return empty if a is None else np.ascontiguousarray(a, dtype=float)

    return str(_core._data_fingerprint(
        kind, str(robot.joint_types), data.joint_types, arr(data.q), arr(data.legs), arr(poses),
        None if weights is None else arr(weights), arr(probe_poses), arr(points),
        # the loads and temperatures of the effects (issue 23), when the data carry them
        arr(getattr(data, "payload", None)), arr(getattr(data, "temperatures", None)), **own))


# -- the registry -----------------------------------------------------------------------------

#: The kinds by name, one instance each, made on first use (docs/kinds.md).
_KINDS: Registry[MeasurementKind] = Registry(
    "kind", lambda obj: isinstance(obj, MeasurementKind), "a MeasurementKind",
    make=lambda cls: cls())


def register(name: str, kind: str | MeasurementKind) -> None:
    """Make kind ``name`` known: ``kind`` is an instance, or ``"package.module:Class"`` imported
    (and instantiated) on first use. Data of the kind carry ``kind == name``."""
    _KINDS.register(name, kind)


register("pose", "iwr.kinds.pose:PoseKind")
register("points", "iwr.tracker.kind:PointsKind")
register("probe", "iwr.tracker.kind:ProbeKind")
register("ballbar", "iwr.ballbar.kind:BallbarKind")


def named(name: str) -> MeasurementKind:
    """The registered kind named ``name``; ValueError naming the registered ones otherwise."""
    return _KINDS.get(name)


def available() -> list[str]:
    """The registered kinds' names."""
    return _KINDS.names()


def of(data: Any) -> MeasurementKind:
    """The kind of ``data`` (its ``kind`` attribute); TypeError naming the type otherwise."""
    name = getattr(data, "kind", None)
    kind = _KINDS.get(name) if name in _KINDS else None
    if kind is None or not kind.owns(data):
        raise TypeError(f"measurements: expected an iwr.Measurements or another registered kind "
                        f"of data ({', '.join(_KINDS.names())}), got {type(data).__name__}"
                        + (f" of unregistered kind {name!r}" if isinstance(name, str)
                           and kind is None else ""))
    return kind


def for_robot(robot: Any) -> MeasurementKind:
    """The kind of data ``robot``'s description measures (its ``[tracker]`` table, if any); a
    fallback kind (the pose in {0}) only when no other applies."""
    loaded = [_KINDS.get(name) for name in _KINDS.names()]
    for kind in sorted(loaded, key=lambda k: k.fallback):
        if kind.applies_to(robot):
            return kind
    raise ValueError(f"robot {getattr(robot, 'name', robot)!r}: no registered kind of data "
                     "applies to it")


def without_weightless(data: Any, name: str = "data") -> tuple[Any, int]:
    """``data`` without the poses whose every reading has weight 0 (docs/data.md: how a file
    leaves a pose out and keeps its row visible), and how many there were; ``data`` itself
    when none (or when the kind has no weights). Such a pose counts in no fit, so it counts in
    no figure either: the calibration job and ``iwr report`` take them out before anything
    else. ValueError when no pose is left (``name`` the data set)."""
    w = getattr(data, "weights", None)
    if w is None or len(data) == 0:
        return data, 0
    keep = (np.asarray(w, dtype=float).reshape(len(data), -1) > 0).any(axis=1)
    if keep.all():
        return data, 0
    if not keep.any():
        raise ValueError(f"{name}: every pose has weight 0 for every reading, so none counts")
    return of(data).subset(data, np.flatnonzero(keep)), int(np.count_nonzero(~keep))


def split(data: Any, fraction: float, seed: int) -> tuple[Any, Any]:
    """``(identification, validation)``: ``round(fraction * N)`` poses (at least one) drawn by
    ``seed`` for validation, each part in file order (:func:`split_rows`); the same rule for
    every kind. ValueError when no pose would be left to identify from."""
    kind = of(data)
    ident, val = split_rows(len(data), fraction, seed)
    return kind.subset(data, ident), kind.subset(data, val)


#: The fraction of a data set ``iwr calibrate`` holds out for validation unless told otherwise
#: (:func:`iwr.calibrate`'s and ``--validation-fraction``'s default; ``iwr plan`` warns by it).
VALIDATION_FRACTION = 0.2


def split_rows(n: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The rows of :func:`split`: ``(identification, validation)`` indices of ``n`` poses."""
    if not (isinstance(fraction, numbers.Real) and not isinstance(fraction, bool)
            and 0 < float(fraction) < 1):
        raise ValueError(f"fraction: {fraction!r}; expected 0 < fraction < 1")
    n_val = max(1, int(round(float(fraction) * n)))
    if n - n_val < 1:
        raise ValueError(f"fraction {fraction}: leaves no pose for identification out of {n}")
    order = np.random.default_rng(seed).permutation(n)
    return np.sort(order[n_val:]), np.sort(order[:n_val])
