"""Identifiability: which error parameters the leg readings can tell apart, and the error that means
something.

Everything here works on the exact Jacobian ``J`` of the leg residuals of eq. (10)
(:meth:`iwr.Problem.jacobian`, shape (6 N, n_params)), linearised at a parameter vector ``x``.

Column scaling
--------------
Lengths (mm) and angles (rad) share one Jacobian, so its singular values depend on the units
unless the columns are scaled. We divide every column by its Euclidean norm (equilibration, as in
Hollerbach & Wampler's "calibration index"): the scaled Jacobian ``Js = J D^-1`` with
``D = diag(||J[:, j]||)`` is *identical* under any change of units of any parameter (a change of
unit multiplies a column and its norm by the same factor), so the rank, the threshold, the null
space and the choice of base parameters do not depend on units, and every column enters the
selection of base parameters on an equal footing. A parameter with a zero column (no influence at
all) keeps scale 1.

The observability indices are computed from the nonzero singular values of ``Js`` (the
identifiable part; the zero ones would make every index zero). With column-norm scaling they are
unit-free, but they depend on the data set through ``D``; to compare pose sets,
:func:`iwr.plan_poses` holds ``D`` fixed (computed once over all candidate poses).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import kinds
from ..base_parameters import (
    condition_number,
    observability_indices,
    ordered_base,
    preference,
    report_lines,
)
from ..measurements import Measurements
from ..problem import Problem, predict_legs
from ..robot import Robot

__all__ = [
    "IdentifiabilityReport",
    "NullDirection",
    "ParameterError",
    "identifiability",
    "identifiable_count",
    "parameter_error",
    "parameter_error_on",
    "column_scale",
    "grow_active",
]


def column_scale(jacobian: np.ndarray) -> np.ndarray:
    """Column norms of ``jacobian``, with 1 where a column is zero (the scaling ``D`` above)."""
    d = np.linalg.norm(jacobian, axis=0)
    return np.where(d > 0, d, 1.0)


def _x_or_zeros(robot: Robot, x: Any, name: str = "x") -> np.ndarray:
    if x is None:
        return np.zeros(robot.n_params)
    arr = np.array(x, dtype=float)
    if arr.shape != (robot.n_params,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: expected {robot.n_params} finite values, got shape {arr.shape}")
    return arr


def _rank_threshold(
    s: np.ndarray, shape: tuple[int, int], rtol: float | None
) -> tuple[float, float]:
    """Absolute and relative thresholds: numpy.linalg.matrix_rank's default unless ``rtol``."""
    if rtol is None:
        rtol = max(shape) * np.finfo(float).eps
    if not (np.isfinite(rtol) and 0 < rtol < 1):
        raise ValueError(f"rtol: {rtol!r}; expected a number in (0, 1)")
    smax = float(s[0]) if s.size else 0.0
    return rtol * smax, float(rtol)


@dataclass
class NullDirection:
    """One unidentifiable direction of parameter space (in physical units, mm and rad).

    ``vector`` is normalised so that its coefficient on ``parameter`` (a parameter left out of the
    base set) is 1 and its coefficients on the other left-out parameters are 0: moving
    ``parameter`` by t and the base parameters by t times their coefficients leaves every predicted
    leg reading unchanged to first order.

    Attributes
    ----------
    parameter : str
        The left-out parameter this direction is attached to.
    vector : ndarray, shape (n_params,)
    names : list of str
        All parameter names, to print the combination.
    exact : bool
        True if a finite straight-line step along ``vector`` (the largest parameter moving 1e-3 in
        its own unit) leaves the readings unchanged to 1e-9 mm: the model is invariant along the
        whole line (a translation absorbed by translations). False: invariant to first order only
        (a rotation absorbed by moving points, where the exact invariant path is curved).
    second_order : float
        ``max |change of readings| / t^2`` at that step (mm per unit^2): 0 for an exact direction.
    """

    parameter: str
    vector: np.ndarray
    names: list[str]
    exact: bool = False
    second_order: float = 0.0

    def terms(self, rel_tol: float = 1e-9) -> list[tuple[str, float]]:
        """Nonzero ``(name, coefficient)`` pairs, the attached parameter first, then by size."""
        v = self.vector
        big = np.max(np.abs(v)) if v.size else 0.0
        idx = [i for i in np.flatnonzero(np.abs(v) > rel_tol * big)]
        lead = self.names.index(self.parameter)
        idx.sort(key=lambda i: (i != lead, -abs(v[i])))
        return [(self.names[i], float(v[i])) for i in idx]

    def __str__(self) -> str:
        terms = self.terms()
        parts = [f"{c:+.6g} {n}" for n, c in terms]
        kind = "exact (straight line)" if self.exact else "first order only"
        return f"[{kind}] " + " ".join(parts)


@dataclass
class IdentifiabilityReport:
    """What leg readings at a set of poses can identify; see :func:`identifiability`.

    Attributes
    ----------
    parameter_names : list of str
    singular_values : ndarray
        Of the column-scaled Jacobian, descending (all n_params of them).
    scale : ndarray
        The column scaling ``D`` (column norms of the unscaled Jacobian, mm per unit of each
        parameter).
    rank : int
    threshold : float
        Singular values above it count (absolute, in the scaled Jacobian); ``rtol`` is the relative
        threshold used, ``threshold = rtol * singular_values[0]``.
    condition_number : float
        ``s_1 / s_r`` over the identifiable part (the nonzero singular values).
    O1, O2, O3, O4 : float
        Observability indices, see :func:`observability_indices`.
    null_space : ndarray, shape (n_params, n_params - rank)
        A basis of the unidentifiable directions in physical units (the columns of
        ``null_directions``).
    null_directions : list of NullDirection
    base_parameters : list of str
        An identifiable subset (QR with column pivoting of the scaled Jacobian); its Jacobian has
        full column rank.
    base_indices : ndarray of int
    left_out : list of str
        The parameters outside the base set; hold them fixed (``active=report.active``) for a
        unique answer.
    n_poses : int
    x : ndarray
        Where the Jacobian was taken.
    """

    parameter_names: list[str]
    singular_values: np.ndarray
    scale: np.ndarray
    rank: int
    threshold: float
    rtol: float
    condition_number: float
    O1: float
    O2: float
    O3: float
    O4: float
    null_space: np.ndarray
    null_directions: list[NullDirection]
    base_parameters: list[str]
    base_indices: np.ndarray
    left_out: list[str]
    n_poses: int
    x: np.ndarray
    robot_name: str = ""
    angle_parameters: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    @property
    def n_params(self) -> int:
        return len(self.parameter_names)

    @property
    def base_parameters_mask(self) -> np.ndarray:
        """Boolean mask of the base parameters (True: identified, False: held fixed)."""
        mask = np.zeros(self.n_params, dtype=bool)
        mask[self.base_indices] = True
        return mask

    @property
    def active(self) -> np.ndarray:
        """Same as :attr:`base_parameters_mask`, named for ``iwr.identify(..., active=...)``."""
        return self.base_parameters_mask

    @property
    def n_unidentifiable(self) -> int:
        return self.n_params - self.rank

    def __str__(self) -> str:
        lines = [
            f"Identifiability of {self.robot_name or 'the robot'} from {self.n_poses} poses "
            f"({6 * self.n_poses} leg readings), {self.n_params} error parameters",
            *report_lines(self.singular_values, self.rank, self.threshold, self.n_poses,
                          self.rtol),
        ]
        if self.left_out:
            lines.append(
                f"  base parameters: {len(self.base_parameters)}; left out (hold fixed): "
                + ", ".join(self.left_out)
            )
            lines.append("  unidentifiable directions (coefficients in mm and rad):")
            for k, nd in enumerate(self.null_directions, 1):
                lines.append(f"    {k}. {nd}")
        else:
            lines.append("  every parameter is identifiable")
        return "\n".join(lines)


def _scaled_svd(jac: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    d = column_scale(jac)
    js = jac / d
    # Economic SVD unless there are fewer readings than parameters (then V must be square).
    _, s, vt = np.linalg.svd(js, full_matrices=js.shape[0] < js.shape[1])
    if s.size < js.shape[1]:  # fewer readings than parameters: pad with zeros
        s = np.concatenate([s, np.zeros(js.shape[1] - s.size)])
    return d, s, vt


def grow_active(jac: np.ndarray, mask: np.ndarray, columns: Any, rtol: float) -> np.ndarray:
    """``mask`` with each of ``columns`` (in order) added where its column of ``jac`` raises the
    rank of the active columns (column-scaled, at the relative threshold ``rtol``): the
    parameters the data separate from those already active (the effects' from the geometry's
    base parameters, issue 23)."""
    def rank(m: np.ndarray) -> int:
        _, s, _ = _scaled_svd(jac[:, m])
        return int(np.sum(s > _rank_threshold(s, (jac.shape[0], int(m.sum())), rtol)[0]))

    mask = np.array(mask, dtype=bool)
    current = rank(mask)
    for i in columns:
        trial = mask.copy()
        trial[i] = True
        r = rank(trial)
        if r > current:
            mask, current = trial, r
    return mask


def identifiability(
    robot: Robot,
    measurements: Measurements,
    x: Any = None,
    *,
    rtol: float | None = None,
    selection: str = "ordered",
) -> IdentifiabilityReport:
    """Which error parameters the leg readings at these poses can identify.

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    measurements : Measurements
        The poses (joint readings and measured platform poses); the leg readings themselves do not
        enter the Jacobian.
    x : array_like, optional
        Error vector at which to linearise (default zeros, the nominal robot).
    rtol : float, optional
        Relative rank threshold on the scaled singular values; default
        ``max(6 N, n_params) * machine epsilon`` (as ``numpy.linalg.matrix_rank``). The structural
        null directions of the IWR give singular values ~1e-16 while the weakest identifiable
        ones are ~1e-3, so the choice is not delicate.
    selection : {"ordered", "pivoted"}
        How to choose the base parameters among equivalent ones. ``"pivoted"``: the first
        ``rank`` pivots of QR with column pivoting of the scaled Jacobian
        (``scipy.linalg.qr(pivoting=True)``), the best-conditioned subset; but where columns are
        exactly dependent (joint1.da and joint3.dd are opposite) the choice among them falls to
        round-off or to a 1e-3 difference of the geometry, so it can change from one data set or
        one ``x`` to the next. ``"ordered"`` (default): go through the parameters in a fixed order
        of preference (the hexapod's a_i, b_i, l0_i, then the carriage's joints 1, 2, ...) and keep
        each one that is independent of those kept so far, so the same structural dependencies
        always leave out the same parameters (for the IWR: joint2.da, joint3.dd and joint 4's
        four). Falls back to ``"pivoted"`` if the ordered pass does not find ``rank`` columns.

    Returns
    -------
    IdentifiabilityReport
        Printable; ``report.active`` is the mask to pass to :func:`iwr.identify`. For tracker
        data (:class:`iwr.tracker.TrackerMeasurements`): an :class:`iwr.tracker.NullSpace` of
        the point objective, with ``active`` too (docs/tracker.md).
    """
    return kinds.of(measurements).identifiability(robot, measurements, x, rtol=rtol,
                                                  selection=selection)


def pose_identifiability(robot: Robot, measurements: Measurements, x: Any = None, *,
                         rtol: float | None = None, selection: str = "ordered"
                         ) -> IdentifiabilityReport:
    """:func:`identifiability` on pose data (the platform pose measured in {0})."""
    problem = Problem(robot, measurements)
    x = _x_or_zeros(robot, x)
    jac = problem.jacobian(x)
    d, s, vt = _scaled_svd(jac)
    thr, rtol = _rank_threshold(s, jac.shape, rtol)
    rank = int(np.sum(s > thr))
    names = robot.parameter_names

    base, out = _base_parameters(jac / d, s, thr, rank, names, selection)

    # Null space in scaled coordinates, then back to physical units; then the "echelon" basis:
    # one direction per left-out parameter, coefficient 1 there and 0 on the other left-out ones.
    ns = vt[rank:].T / d[:, None]
    if out.size:
        ns = ns @ np.linalg.solve(ns[out], np.eye(out.size))
        ns[out] = np.eye(out.size)  # exact zeros and ones, not 1 +- eps
    nulls = []
    for k, j in enumerate(out):
        v = ns[:, k].copy()
        exact, curv = _line_invariance(robot, measurements, x, v, d)
        nulls.append(NullDirection(names[j], v, names, exact, curv))
    ind = observability_indices(s[:rank], len(measurements))
    return IdentifiabilityReport(
        parameter_names=names,
        singular_values=s,
        scale=d,
        rank=rank,
        threshold=thr,
        rtol=rtol,
        condition_number=condition_number(s, rank),
        null_space=ns,
        null_directions=nulls,
        base_parameters=[names[i] for i in base],
        base_indices=base,
        left_out=[names[i] for i in out],
        n_poses=len(measurements),
        x=x,
        robot_name=robot.name,
        angle_parameters=robot.angle_parameters,
        **ind,
    )


#: Poses of the varied pose set of :func:`identifiable_count` (the data's seed is fixed).
GENERIC_POSES = 60


#: identifiable_count's answers, per robot model (its fingerprint) and sampled workspace.
_COUNTS: dict[tuple, int] = {}  # key: also what the sampled poses depend on


def identifiable_count(robot: Robot) -> int:
    """How many error parameters (with a tracker: robot and setup) varied poses identify for
    ``robot``: the rank of the information matrix on :data:`GENERIC_POSES` random poses of its
    workspace (:func:`iwr.simulate`, a fixed seed, no noise). Data of a lower rank cannot
    identify the robot's errors, whatever the method (too few distinct poses, copies).
    Remembered per robot model (every identification's fit check asks); raises
    :class:`iwr.simulation.UnreachableError` where the workspace yields no poses to sample."""
    from ..robot_fingerprint import fingerprint
    from ..simulation import simulate

    key = (fingerprint(robot), *(np.asarray(v, dtype=float).tobytes() for v in (
        robot.joint_limits, robot.home_pose, robot.workspace, robot.leg_stroke)))
    if key not in _COUNTS:
        data, _ = simulate(robot, GENERIC_POSES, seed=0)
        _COUNTS[key] = int(identifiability(robot, data).rank)
    return _COUNTS[key]


def degenerate(robot: Any, identification: Any, report: Any) -> str | None:
    """Why ``identification`` cannot identify the robot's errors, else None: their information
    matrix (``report``, :func:`iwr.identifiability`) has a lower rank than varied poses give
    this robot (too few distinct poses, copies, poses that do not move some joint)."""
    if report is None:
        return None
    # With effects: the geometry's rank (effect parameters the data cannot separate from the
    # geometry are named by the report and held at the robot file's values, not a degeneracy).
    rank = getattr(report, "geometric_rank", report.rank)
    from ..simulation import UnreachableError

    try:
        need = identifiable_count(robot.with_effects() if robot.effects else robot)
    except UnreachableError:
        # A workspace the robot file describes too narrowly to sample (its home pose out of
        # reach): the measured poses are what they are; nothing to compare their rank with.
        return None
    if rank >= need:
        return None
    distinct = distinct_poses(identification)
    n = len(identification)
    copies = f" ({n} poses, {n - distinct} of them copies)" if distinct < n else ""
    return (f"degenerate data: the {distinct} distinct identification poses{copies} "
            f"identify {rank} of the {need} parameters that varied poses identify "
            f"for this robot; the other {need - rank} would be left at nominal: "
            "measure more, and more varied, poses")


def degenerate_data(robot: Any, data: Any, active: Any = None) -> str | None:
    """:func:`degenerate` of ``data`` with their identifiability at the nominal robot (what
    :func:`iwr.calibrate` judges), for the fit check of every method. ``active``: the parameters
    the method identified; a subset of fewer than varied poses identify, other than the data's
    own base parameters, is the caller's choice (six leg offsets from six poses) and is not
    judged so (the data's base parameters are the default of the efficient estimator: 30
    copies of one pose give six, and are judged). None too where the rank cannot be had
    (tracker data too far from the nominal robot for a registration guess, a nominal pose out
    of reach: ValueError, RuntimeError)."""
    try:
        report = identifiability(robot, data)
        if active is not None:
            mask = np.asarray(active, dtype=bool)
            own = np.asarray(report.active, dtype=bool)
            if not (mask.shape == own.shape and np.array_equal(mask, own)):
                need = identifiable_count(robot.with_effects() if robot.effects else robot)
                if int(mask.sum()) < need:
                    return None
        return degenerate(robot, data, report)
    except (ValueError, RuntimeError):
        return None


def distinct_poses(data: Any) -> int:
    """The number of distinct poses (rows of readings and measurements,
    :meth:`iwr.kinds.MeasurementKind.rows`) in ``data``."""
    key = kinds.of(data).rows(data)
    return len(np.unique(np.where(np.isnan(key), np.inf, key), axis=0))


def _base_parameters(
    js: np.ndarray, s: np.ndarray, thr: float, rank: int, names: list[str], selection: str
) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the base parameters and of those left out (both sorted); ``names``: the
    parameters of the columns of ``js``."""
    if selection not in ("ordered", "pivoted"):
        raise ValueError(f"selection: {selection!r}; expected 'ordered' or 'pivoted'")
    if selection == "ordered":
        # The hexapod's parameters first, the carriage's joints 1..n last: the order every
        # kind's null directions break their ties by (iwr.base_parameters.preference).
        chosen = ordered_base(js, s, thr, rank, preference(names))
        if chosen is not None:
            return chosen
    import scipy.linalg  # here, not at the top: scipy.linalg costs every short command

    _, _, piv = scipy.linalg.qr(js, mode="economic", pivoting=True)
    return np.sort(piv[:rank]), np.sort(piv[rank:])


def _line_invariance(
    robot: Robot, m: Measurements, x: np.ndarray, v: np.ndarray, d: np.ndarray
) -> tuple[bool, float]:
    """Is the model invariant along the straight line x + t v, not just to first order?

    The step t is the size at which the parameter of ``v`` with the largest scaled coefficient
    would, on its own, change the readings by 1 mm RMS (``|D_i t v_i| = sqrt(6 N)`` mm): large
    enough that a second-order term shows (a rotation by ~1 mm / lever arm gives a change of
    ~1e-3 mm), small enough to stay in the linear regime of everything else. Exact directions
    change the readings by round-off only (~1e-12 mm); the threshold is 1e-9 mm.
    """
    t = np.sqrt(6 * len(m)) / np.max(np.abs(d * v))
    base = predict_legs(robot, x, m.q, m.poses)
    change = np.max(np.abs(predict_legs(robot, x + t * v, m.q, m.poses) - base))
    return bool(change < 1e-9), float(change / t**2)


# -- parameter error modulo the unidentifiable directions ----------------------------------------


@dataclass
class ParameterError:
    """An identified error vector compared with the truth, modulo the unidentifiable directions.

    Attributes
    ----------
    projected : ndarray, shape (n_params,)
        ``x - truth`` with its unidentifiable component removed: the orthogonal projection (in the
        column-scaled metric) onto the row space of the Jacobian. Two vectors that differ only
        along null directions have (to first order) the same projected error. A robot with
        effects: the geometric errors then the effects' parameters (:meth:`named`); the RMS and
        maxima below are the geometric errors'.
    raw : ndarray
        ``x - truth`` as it is.
    null_component : ndarray
        ``raw - projected``: the part no data set of this kind could see.
    rms_length, rms_angle : float
        RMS of the projected error over the length parameters (mm) and the angle parameters (rad;
        nan if there are none).
    max_abs_length, max_abs_angle : float
        Largest absolute projected error among lengths (mm) and among angles (rad).
    raw_rms_length, raw_rms_angle : float
        The same RMS values for the raw error.
    reading_rms : float
        RMS of ``J (x - truth)`` over the readings (mm): the first-order change of the predicted
        leg readings that the error causes at these poses.
    rank : int
        Rank of the Jacobian used.
    converged : bool
        ``method="nonlinear"``: whether the search for the nearest equivalent of the truth reached
        the truth's readings to 1e-9 mm (always True for ``"linear"``).
    """

    projected: np.ndarray
    raw: np.ndarray
    null_component: np.ndarray
    rms_length: float
    rms_angle: float
    max_abs_length: float
    max_abs_angle: float
    raw_rms_length: float
    raw_rms_angle: float
    reading_rms: float
    rank: int
    parameter_names: list[str]
    converged: bool = True

    def named(self) -> dict[str, float]:
        """The projected error by parameter name."""
        return dict(zip(self.parameter_names, map(float, self.projected), strict=True))

    def __str__(self) -> str:
        return (
            f"parameter error modulo {len(self.raw) - self.rank} unidentifiable direction(s): "
            f"RMS {self.rms_length:.4g} mm (max {self.max_abs_length:.4g} mm), "
            f"{self.rms_angle:.4g} rad (max {self.max_abs_angle:.4g} rad); raw RMS "
            f"{self.raw_rms_length:.4g} mm, {self.raw_rms_angle:.4g} rad; readings RMS "
            f"{self.reading_rms:.4g} mm"
        )


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")


def _maxabs(v: np.ndarray) -> float:
    return float(np.max(np.abs(v))) if v.size else float("nan")


def _readings_problem(robot: Robot, measurements: Measurements, truth: np.ndarray) -> Problem:
    """A problem whose residuals are ``predict_legs(y) - predict_legs(truth)``, unweighted
    (with effects: under each pose's load and temperature)."""
    m = measurements
    if robot.effects:
        legs = predict_legs(robot, truth, m.q, m.poses, data=m)
        return Problem(robot, Measurements(m.q, m.poses, legs, joint_types=robot.joint_types,
                                           payload=m.payload, temperatures=m.temperatures))
    legs = predict_legs(robot, truth, m.q, m.poses)
    return Problem(robot, Measurements(m.q, m.poses, legs, joint_types=robot.joint_types))


def _row_space(
    jac: np.ndarray, rtol: float | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    d, s, vt = _scaled_svd(jac)
    thr, _ = _rank_threshold(s, jac.shape, rtol)
    rank = int(np.sum(s > thr))
    return d, s, vt, rank


def parameter_error(
    robot: Robot,
    measurements: Measurements,
    x: Any,
    truth: Any,
    *,
    method: str = "nonlinear",
    rtol: float | None = None,
) -> ParameterError:
    """Compare an identified error vector with the truth modulo the unidentifiable directions.

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    measurements : Measurements
        The poses that define what is identifiable (normally the calibration data set; only its
        joint readings and platform poses are used).
    x : array_like, shape (n_params,)
        The identified error parameters.
    truth : array_like, shape (n_params,)
        The true error parameters (simulation).
    method : {"nonlinear", "linear"}
        ``"linear"``: project ``x - truth`` onto the row space of the column-scaled Jacobian at the
        truth, ``D^-1 V_r V_r^T D (x - truth)`` with ``J D^-1 = U S V^T`` (exact to first order).
        ``"nonlinear"`` (default): first find ``y``, the parameter vector nearest to ``x`` that
        predicts exactly the truth's readings at these poses (Gauss-Newton from ``x`` with
        minimum-norm steps in the scaled metric), then project ``x - y`` onto the row space at
        ``y``. The two agree to first order; the nonlinear one also removes the second-order
        part of the null component. This matters: a rotation of frame {4} by 0.5 degree,
        absorbed by the base joints, leaves a linear-projection residue of ~1e-3 mm, more than
        the error of a converged noise-free identification.
    rtol : float, optional
        Rank threshold, as in :func:`identifiability`.

    Returns
    -------
    ParameterError

    Notes
    -----
    The projected error is the smallest error, in the scaled norm ``||D e||``, between ``x`` and
    the set of parameter vectors indistinguishable from the truth at these poses: the part of the
    error that the readings can see.
    """
    if robot.effects:  # issue 23: the effects' parameters after the geometric errors
        from ..effects import parameter_names as effect_names

        n_all = robot.n_params + len(effect_names(robot.effects))
        for name, v in (("x", x), ("truth", truth)):
            if np.shape(v) != (n_all,):
                raise ValueError(f"{name}: shape {np.shape(v)}; expected ({n_all},): "
                                 f"{robot.n_params} geometric errors, then "
                                 + ", ".join(effect_names(robot.effects)))
        x, truth = np.array(x, dtype=float), np.array(truth, dtype=float)
    else:
        x = _x_or_zeros(robot, x, "x")
        truth = _x_or_zeros(robot, truth, "truth")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(truth))):
        raise ValueError("x, truth: expected finite values")
    if method not in ("nonlinear", "linear"):
        raise ValueError(f"method: {method!r}; expected 'nonlinear' or 'linear'")
    problem = _readings_problem(robot, measurements, truth)
    raw = x - truth
    converged = True
    if method == "linear":
        jac = problem.jacobian(truth)
        d, _, vt, rank = _row_space(jac, rtol)
        vr = vt[:rank].T
        projected = (vr @ (vr.T @ (d * raw))) / d
    else:
        y = _nearest_equivalent(problem, x, rtol)
        converged = bool(np.max(np.abs(problem.residuals(y)), initial=0.0) < 1e-9)
        jac = problem.jacobian(y)
        d, _, vt, rank = _row_space(jac, rtol)
        vr = vt[:rank].T
        projected = (vr @ (vr.T @ (d * (x - y)))) / d
    # The geometric errors' lengths and angles (the effects' parameters have units of their own:
    # by name in the result).
    ang = robot.angle_parameters
    n = robot.n_params
    lengths, angles = projected[:n][~ang], projected[:n][ang]
    return ParameterError(
        projected=projected,
        raw=raw,
        null_component=raw - projected,
        rms_length=_rms(lengths),
        rms_angle=_rms(angles),
        max_abs_length=_maxabs(lengths),
        max_abs_angle=_maxabs(angles),
        raw_rms_length=_rms(raw[:n][~ang]),
        raw_rms_angle=_rms(raw[:n][ang]),
        reading_rms=_rms(problem.residuals(x)),
        rank=rank,
        parameter_names=problem.parameter_names,
        converged=converged,
    )


def _nearest_equivalent(problem: Problem, x: np.ndarray, rtol: float | None) -> np.ndarray:
    """Gauss-Newton from ``x`` to the set where the residuals vanish, with minimum-norm steps
    (in the column-scaled metric) so the path leaves the null directions alone."""
    y = x.copy()
    prev = np.inf
    for _ in range(50):
        r, jac = problem.residuals_and_jacobian(y)
        size = float(np.max(np.abs(r))) if r.size else 0.0
        # Converged at round-off (readings are ~1e3 mm: 1e-12 mm is a few ulps) or stalled.
        if size < 1e-12 or size >= prev:
            break
        prev = size
        d, s, vt, rank = _row_space(jac, rtol)
        u = (jac / d) @ vt[:rank].T / s[:rank]  # U_r, without a second SVD
        y -= (vt[:rank].T @ ((u.T @ r) / s[:rank])) / d
    return y


def parameter_error_on(problem: Any, x: Any, truth: Any, angles: Any,
                       rtol: float | None = None) -> ParameterError:
    """``x - truth`` modulo the null directions of ``problem`` (:func:`iwr.parameter_error`'s
    nonlinear method on any problem whose residuals vanish at ``truth``: exact readings of the
    truth): ``y``, the vector nearest to ``x`` (column-scaled metric) with the truth's readings,
    by Gauss-Newton with minimum-norm steps, then ``x - y`` projected onto the row space of the
    Jacobian at ``y``. ``angles`` marks the angle parameters (rad); ``rtol`` the relative rank
    threshold (default NumPy's). ValueError when the
    residuals do not vanish at ``truth`` (noisy data: no vector predicts them)."""
    x = np.asarray(x, dtype=float)
    truth = np.asarray(truth, dtype=float)
    ang = np.asarray(angles, dtype=bool)
    r_truth = np.max(np.abs(problem.residuals(truth)), initial=0.0)
    if not r_truth < 1e-6:
        raise ValueError(f"data: residuals up to {r_truth:.3g} mm at the truth; the parameter "
                         "error needs exact readings of the truth (noise-free poses)")
    y = _nearest_equivalent(problem, x, rtol)
    converged = bool(np.max(np.abs(problem.residuals(y)), initial=0.0) < 1e-9)
    d, _, vt, rank = _row_space(problem.jacobian(y), rtol)
    vr = vt[:rank].T
    projected = (vr @ (vr.T @ (d * (x - y)))) / d
    raw = x - truth

    def rms(v: np.ndarray) -> float:
        return float(np.sqrt(np.mean(v**2))) if v.size else float("nan")

    def maxabs(v: np.ndarray) -> float:
        return float(np.max(np.abs(v))) if v.size else float("nan")

    return ParameterError(
        projected=projected, raw=raw, null_component=raw - projected,
        rms_length=rms(projected[~ang]), rms_angle=rms(projected[ang]),
        max_abs_length=maxabs(projected[~ang]), max_abs_angle=maxabs(projected[ang]),
        raw_rms_length=rms(raw[~ang]), raw_rms_angle=rms(raw[ang]),
        reading_rms=rms(problem.residuals(x)), rank=rank,
        parameter_names=list(problem.parameter_names), converged=converged)



def kind_parameter_error(kind: Any, robot: Robot, data: Any, x: Any, truth: Any) -> ParameterError:
    """``x - truth`` over the robot's and the setup's parameters modulo the null directions of
    ``kind``'s problem on ``data`` (exact readings of the truth; the gauge among them; the rank
    threshold the kind's :attr:`~iwr.kinds.MeasurementKind.null_rtol`): what the experiments
    report for a kind with setup parameters. ValueError when no vector with the truth's readings
    is reached from ``x``."""
    problem, _ = kind.problem(robot, data, x0=truth)
    error = parameter_error_on(problem, x, truth, kind.angle_parameters(robot), kind.null_rtol)
    if not error.converged:
        raise ValueError("no parameter vector with the truth's readings was reached from x "
                         f"(readings RMS {error.reading_rms:.3g} mm off at x): x is too far from "
                         "the truth for its error to be split into seen and unseen parts")
    return error
