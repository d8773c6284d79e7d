"""Pose planning: choose K of M candidate measurement poses to maximise an observability index.

The information that a set S of poses carries about the base parameters is
``M(S) = sum_{k in S} Js_k^T Js_k``, where ``Js_k`` is the 6-row block of pose k of the Jacobian,
restricted to the base parameters and column-scaled once for all candidates (so that the scaling
does not change with the subset). Its eigenvalues are the squared singular values of the stacked
Jacobian, so each observability index of :mod:`iwr.analysis.identifiability` is a function of them:
O1 (D-optimality: the geometric mean), O2 (inverse condition number), O3 (E-optimality: the
smallest), O4 (noise amplification, ``s_min^2 / s_max``).

The search is greedy (add the pose that raises the index most), then an exchange pass in the
manner of Fedorov (swap a chosen pose for an unchosen one while that raises the index), until no
swap helps. While the chosen poses cannot yet determine every base parameter (fewer than
``rank / 6`` poses), all indices are zero, so the greedy start maximises ``log det(M + eps I)``.
"""

from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import kinds
from ._io import atomic_write_text
from .analysis.identifiability import IdentifiabilityReport, column_scale, identifiability
from .measurements import (
    _PAYLOAD_COLUMNS,
    PLAN_MARKER,
    MeasurementFileError,
    Measurements,
    decode_text,
)
from .problem import Problem, predict_legs
from .robot import Robot
from .simulation import Noise, add_noise

__all__ = ["PosePlan", "plan_poses", "measure", "read_plan"]

CRITERIA = ("O1", "O2", "O3", "O4")


@dataclass
class PosePlan:
    """The poses chosen by :func:`plan_poses`.

    Attributes
    ----------
    indices : ndarray of int
        Rows of the candidates chosen, in the order the greedy pass added them (the exchange pass
        replaces in place).
    criterion : str
    value : float
        The index of the chosen set (with the candidates' fixed column scaling; O1 as the
        geometric mean of the singular values divided by sqrt(k)).
    greedy_value : float
        The index after the greedy pass, before exchanges.
    n_exchanges : int
    base_indices : ndarray of int
        The base parameters the information is computed for.
    measurements : Measurements
        The chosen candidate rows (for a ballbar robot an
        :class:`iwr.ballbar.planning.BallbarCandidates`, whose ``setup`` names the set-up of
        each pose).
    """

    indices: np.ndarray
    criterion: str
    value: float
    greedy_value: float
    n_exchanges: int
    base_indices: np.ndarray
    measurements: Measurements
    #: ``"pose"`` (a pose measured in {0}), the tracker setup's kind (``"points"``,
    #: ``"probe"``) or ``"ballbar"``: what is measured at each pose, for the plan file's
    #: instructions.
    data_kind: str = "pose"
    #: The independent readings a pose gives of the base parameters (6 for a pose in {0} or a
    #: probe, 3 per reflector, 1 for a ballbar): the rank of a pose's rows of the design.
    readings_per_pose: int = 0

    def redundancy(self, validation_fraction: float = kinds.VALIDATION_FRACTION,
                   n_poses: int | None = None) -> int:
        """The readings beyond the base parameters once a calibration job holds out
        ``validation_fraction`` of the ``n_poses`` (default the plan's) for validation
        (:func:`iwr.kinds.split_rows`'s rule): at most 0, the fit has no degree of freedom to be
        tested with (the job then says "not calibrated: no redundancy")."""
        n = len(self.indices) if n_poses is None else int(n_poses)
        n_ident = n - (kinds.split_rows(n, validation_fraction, 0)[1].size if n > 1 else 0)
        return n_ident * self.readings_per_pose - int(self.base_indices.size)

    def poses_for_redundancy(self, validation_fraction: float = kinds.VALIDATION_FRACTION
                             ) -> int:
        """The fewest poses whose readings, once the job holds out ``validation_fraction`` of
        them, exceed the base parameters (:meth:`redundancy` > 0)."""
        n = max(2, len(self.indices))
        while self.redundancy(validation_fraction, n) <= 0:
            n += 1
        return n

    def __str__(self) -> str:
        return (
            f"{len(self.indices)} poses chosen for {self.criterion}: {self.value:.4g} "
            f"(greedy {self.greedy_value:.4g}, {self.n_exchanges} exchange(s))"
        )

    def to_csv(self, path: str | os.PathLike[str], source: str | None = None) -> None:
        """Write the chosen poses to measure (atomically): joint readings and platform poses, in
        the columns of a measurement file but without leg readings, under a first line
        ``# iwr plan: ...`` that :meth:`iwr.Measurements.from_csv` refuses (a plan is not
        measurements); :func:`read_plan` reads it back."""
        m = self.measurements
        cols = m.columns()[: m.n_joints + 6]
        # Issue 23: with payloads planned, the payload to mount at each pose (docs/effects.md).
        pay = [] if m.payload is None else list(_PAYLOAD_COLUMNS)
        # Ballbar data (docs/ballbar.md): the set-up to mount the bar in at each pose.
        setups = getattr(m, "setup", None)
        buf = io.StringIO()
        origin = f" from {source}" if source else ""
        what = {"points": "the reflector points measured by the tracker, in its frame",
                "probe": "the probe pose measured by the tracker, in its frame",
                "ballbar": "the bar's reading, the ballbar mounted in the\n# set-up of the "
                           "pose's setup column (a [ballbar.NAME] of the robot)"}.get(
                    self.data_kind, "the platform pose measured by the tracker")
        doc = {"points": "docs/tracker.md", "probe": "docs/tracker.md",
               "ballbar": "docs/ballbar.md"}.get(self.data_kind, "docs/data.md")
        buf.write(
            f"{PLAN_MARKER} {len(self.indices)} poses chosen for {self.criterion}{origin}.\n"
            "# Not measurements: drive the robot to each pose below, record the joint readings,\n"
            + ("# with the payload of its payload_* columns mounted (mass kg, centre of mass in\n"
               "# {5} mm), " if pay else "# ")
            + f"the six leg readings and {what}, and calibrate\n"
            f"# with that measurement file ({doc}). Lengths in mm, angles in rad; the platform\n"
            "# poses are {5} in the world frame {0} of the nominal robot.\n"
        )
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(cols + pay + ([] if setups is None else ["setup"]))
        for k, row in enumerate(np.hstack([m.q, m.poses] + ([m.payload] if pay else []))):
            writer.writerow([repr(float(v)) for v in row]
                            + ([] if setups is None else [str(setups[k])]))
        atomic_write_text(path, buf.getvalue())


def read_plan(path: str | os.PathLike[str], *, payload: bool = False,
              setup: bool = False) -> Any:
    """The poses of a plan written by :meth:`PosePlan.to_csv` (``iwr plan``): ``(q, poses)``,
    joint readings (N, n_joints) and world platform poses (N, 6), a pair that
    :func:`plan_poses` also takes as candidates. ``payload``: ``(q, poses, payload)``, the
    payload planned at each pose ((N, 4): mass kg, centre in {5} mm; None when the plan has no
    ``payload_*`` columns: issue 23). ``setup``: the set-up name of each pose appended
    (an array of str; None when the plan has no ``setup`` column), what a ballbar plan names
    (docs/ballbar.md); the triple ``(q, poses, setup)`` is a ballbar robot's candidates too. A
    plan with payloads read without ``payload``, or with set-ups read without ``setup``, is
    refused (they are part of what to measure).

    Raises
    ------
    MeasurementFileError
        Not a plan file, or a malformed one (naming the line).
    """
    path = Path(path)
    try:
        text = decode_text(path.read_bytes(), path)
    except OSError as exc:
        raise MeasurementFileError(f"{path}: cannot be read ({exc})") from None
    if not text.lstrip().startswith(PLAN_MARKER):
        raise MeasurementFileError(f"{path}: not a pose plan (no first line '{PLAN_MARKER} ...')")
    header: list[str] | None = None
    rows, names = [], []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        fields = [f.strip() for f in next(csv.reader([line]))]
        if header is None:
            header = fields
            n_set = 1 if header[-1:] == ["setup"] else 0
            if n_set and not setup:
                raise MeasurementFileError(
                    f"{path}, line {lineno}: the plan names a ballbar set-up per pose (column "
                    "setup); read it with read_plan(path, setup=True)")
            header = header[: len(header) - n_set]
            n_pay = 4 if tuple(header[-4:]) == _PAYLOAD_COLUMNS else 0
            if n_pay and not payload:
                raise MeasurementFileError(
                    f"{path}, line {lineno}: the plan names a payload per pose (columns "
                    f"{', '.join(_PAYLOAD_COLUMNS)}); read it with read_plan(path, "
                    "payload=True)")
            n_joints = len(header) - 6 - n_pay
            if n_joints < 0 or header[n_joints: n_joints + 6] != [
                    "x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad"]:
                raise MeasurementFileError(f"{path}, line {lineno}: not a plan's header")
            continue
        if n_set:
            if len(fields) != len(header) + 1 or not fields[-1]:
                raise MeasurementFileError(f"{path}, line {lineno}: expected {len(header)} "
                                           "finite numbers and a set-up name")
            names.append(fields[-1])
            fields = fields[:-1]
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise MeasurementFileError(f"{path}, line {lineno}: not numbers") from None
        if len(values) != len(header) or not all(math.isfinite(v) for v in values):
            raise MeasurementFileError(
                f"{path}, line {lineno}: expected {len(header)} finite numbers"
            )
        rows.append(values)
    if header is None or not rows:
        raise MeasurementFileError(f"{path}: no poses")
    data = np.array(rows)
    out: tuple[Any, ...] = (data[:, :n_joints], data[:, n_joints: n_joints + 6])
    if payload:
        out += (data[:, n_joints + 6:] if n_pay else None,)
    if setup:
        out += (np.array(names, dtype=str) if n_set else None,)
    return out


def _criterion(eig: np.ndarray, name: str, k: int) -> np.ndarray:
    """Index values from eigenvalues (..., r) of information matrices, ascending."""
    ev = np.clip(eig, 0.0, None)
    s = np.sqrt(ev)
    smin, smax = s[..., 0], s[..., -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        if name == "O1":
            out = np.exp(np.mean(np.log(np.where(s > 0, s, 1e-300)), axis=-1)) / np.sqrt(k)
        elif name == "O2":
            out = smin / smax
        elif name == "O3":
            out = smin
        else:
            out = smin**2 / smax
    return np.nan_to_num(out)


def _as_candidates(robot: Robot, candidates: Any) -> tuple[Measurements, Any]:
    """``(candidate poses, set-up names or None)``: the set-ups of a triple ``(q, poses,
    setup)`` (a ballbar plan read back, :func:`read_plan`)."""
    if isinstance(getattr(candidates, "kind", None), str):
        # Data of any kind: their platform poses in {0} (tracker data hold none: the nominal
        # robot's forward kinematics gives them).
        return kinds.of(candidates).candidate_poses(robot, candidates), None
    try:
        q, poses, *rest = candidates
        if len(rest) > 1:
            raise ValueError
    except (TypeError, ValueError):
        raise TypeError(
            "candidates: expected an iwr.Measurements, a pair (q, poses) or, for a ballbar "
            "robot, a triple (q, poses, setup)"
        ) from None
    poses = np.asarray(poses, dtype=float)
    q = np.asarray(q, dtype=float).reshape(len(poses), robot.n_joints)
    legs = predict_legs(robot.with_effects(), np.zeros(robot.n_params), q, poses)
    return Measurements(q, poses, legs, joint_types=robot.joint_types), (rest or [None])[0]


def _with_conditions(robot: Robot, cand: Measurements, payloads: Any, temperatures: Any
                     ) -> Measurements:
    """Issue 23: the candidates under each of ``payloads`` in turn (every pose once per
    payload, the first payload's copies first), with ``temperatures`` (one per pose or per leg)
    when given."""
    temps = cand.temperatures
    if temperatures is not None:
        temps = np.asarray(temperatures, dtype=float)
        if temps.ndim == 0:
            temps = np.full(len(cand), float(temps))
    pay = cand.payload
    if payloads is not None:
        if not any(e.needs & {"forces", "loads"} for e in robot.effects):
            raise ValueError(f"payloads: robot {robot.name!r} has no effect of the load "
                             "([effects.compliance] or [effects.carriage_compliance]); the "
                             "payloads change nothing it models")
        p = np.asarray(payloads, dtype=float)
        if p.ndim != 2 or p.shape[1] != 4 or len(p) == 0:
            raise ValueError(f"payloads: shape {p.shape}; expected (P, 4): mass kg, centre of "
                             "mass in {5} mm")
        rows = np.tile(np.arange(len(cand)), len(p))
        pay = np.repeat(p, len(cand), axis=0)
        if temps is not None:
            temps = np.asarray(temps)[rows]
        base = cand.subset(rows)
        return Measurements(base.q, base.poses, base.legs, joint_types=robot.joint_types,
                            payload=pay, temperatures=temps)
    return Measurements(cand.q, cand.poses, cand.legs, joint_types=robot.joint_types,
                        payload=pay, temperatures=temps)


def plan_poses(
    robot: Robot,
    candidates: Any,
    n_poses: int,
    criterion: str = "O1",
    seed: int | None = None,
    *,
    x: Any = None,
    exchange: bool = True,
    max_passes: int = 20,
    report: IdentifiabilityReport | None = None,
    payloads: Any = None,
    temperatures: Any = None,
) -> PosePlan:
    """Choose ``n_poses`` of the candidate poses that maximise an observability index.

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    candidates : Measurements or (q, poses) or (q, poses, setup)
        M candidate poses: joint readings (M, n_joints) and platform poses in the world frame
        (M, 6). Leg readings, if any, are not used. For a robot with a tracker
        (``robot.tracker``) the information is the tracker problem's (docs/tracker.md: points or
        probe poses in {T} as the nominal setup measures them at these poses; the registration
        and offsets among the parameters, one parameter per null direction left out), and
        :class:`iwr.tracker.TrackerMeasurements` are candidates too (their poses by forward
        kinematics of the nominal robot). For a robot measured by a double ballbar
        (docs/ballbar.md) the candidates are (pose, set-up) pairs: each candidate pose once per
        set-up whose bar reaches it (the nominal centre distance within the set-up's
        ``range``), or the pairs given (``setup``, one set-up name per pose, as
        ``read_plan(path, setup=True)`` gives them; :class:`iwr.ballbar.BallbarMeasurements`
        in their own set-ups); the information is the distance's, the balls and offsets of
        every set-up included, and ``plan.measurements.setup`` says where to mount the bar. A
        set-up with fewer candidates than its 7 unknowns is refused by name.
    n_poses : int
        Number of poses to choose, at least ``ceil(rank / r)`` so the base parameters can be
        determined, ``r`` the independent readings of one pose (the rank of one pose's
        information: 6 for a pose in {0} or a probe's, 3 per reflector, 1 for a ballbar's
        distance).
    criterion : {"O1", "O2", "O3", "O4"}
        The index to maximise (see :func:`iwr.identifiability`). O1 (D-optimal) is the usual
        choice; O3 and O4 guard the weakest direction.
    seed : int, optional
        Breaks ties between equally good candidates at random (reproducibly); ``None``: ties go
        to the lowest index.
    x : array_like, optional
        Where to linearise (default: the nominal robot; with a tracker, the robot's then the
        setup's parameters, or the robot's alone with the nominal setup).
    exchange : bool
        Follow the greedy pass with exchange passes.
    max_passes : int
        At most this many exchange passes over the chosen poses.
    report : IdentifiabilityReport or NullSpace, optional
        Identifiability of all candidates, if already computed (defines the base parameters;
        with a tracker, :func:`iwr.identifiability`'s NullSpace, whose ``active`` are kept).
    payloads : array_like (P, 4), optional
        A robot with the compliance effect (issue 23, docs/effects.md): the payloads that can
        be mounted (mass kg, centre of mass in {5} mm; include ``(0, 0, 0, 0)`` for none).
        Every candidate pose is a candidate once per payload, and the plan chooses poses and
        payloads together (``plan.measurements.payload``; the plan file's ``payload_*``
        columns), so that the compliances are separated from the geometry where one payload
        cannot. Default: the candidates' own payload column (none if they have none).
    temperatures : float or array_like, optional
        The legs' temperatures expected at the candidate poses (degrees C; one per pose, or
        per pose and leg), which the thermal effect needs; default the candidates' own.

    Returns
    -------
    PosePlan
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion: {criterion!r}; expected one of {', '.join(CRITERIA)}")
    cand, setup = _as_candidates(robot, candidates)
    if robot.effects:  # issue 23: the loads (and temperatures) are part of each candidate
        cand = _with_conditions(robot, cand, payloads, temperatures)
    elif payloads is not None or temperatures is not None:
        raise ValueError(f"payloads, temperatures: robot {robot.name!r} has no effect on; they "
                         "change nothing its geometry models (docs/effects.md)")
    # The information of the kind of data the robot measures (laser-tracker data,
    # docs/tracker.md: the tracker problem's, the registration and the offsets included; ballbar
    # data, docs/ballbar.md: (pose, set-up) pairs within the bar's range).
    kind = kinds.for_robot(robot)
    cand = kind.plan_candidates(robot, cand, setup)
    n_cand = len(cand)
    problem, x, base, rows, what = kind.design(robot, cand, x, report)
    n_all = len(problem.parameter_names)
    if report is not None and np.shape(report.active) != (n_all,):
        raise ValueError(
            f"report: the identifiability of {np.size(report.active)} parameters, but robot "
            f"{robot.name!r} measured by {kind.description} has {n_all} (the report of data of "
            "another kind? iwr.identifiability of data of the robot's kind gives the right one)")
    r = base.size
    jac = problem.jacobian(x)[:, base]
    js = (jac / column_scale(jac)).reshape(n_cand, rows, r)
    # The readings of a pose that carry independent information: a probe's points are one rigid
    # pose (6 of its 12 coordinates), so counting its rows would plan too few poses (singular).
    per_pose = int(np.max(np.linalg.matrix_rank(js)))
    k_min = -(-r // max(per_pose, 1))
    if (isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer))
            or not k_min <= n_poses <= n_cand):
        independent = f"{per_pose} independent of the {rows}" if per_pose < rows else f"{rows}"
        raise ValueError(
            f"n_poses: {n_poses!r}; expected an integer from {k_min} (to determine {r} base "
            f"parameters from {independent} {what} per pose) to {n_cand} (the number of "
            "candidates)"
        )
    k = int(n_poses)
    info = np.einsum("kij,kil->kjl", js, js)  # per-pose information, (M, r, r)
    rng = np.random.default_rng(seed) if seed is not None else None
    eps = 1e-9 * float(np.trace(info.sum(axis=0))) / r

    def pick(values: np.ndarray, allowed: np.ndarray) -> int:
        vals = np.where(allowed, values, -np.inf)
        best = np.max(vals)
        ties = np.flatnonzero(vals >= best - 1e-12 * abs(best))
        return int(ties[0] if rng is None else rng.choice(ties))

    def logdets(base_info: np.ndarray) -> np.ndarray:
        """``log det(base_info + eps I + info[c])`` for every c, by the determinant lemma
        ``det(A + J^T J) = det(A) det(I + J A^-1 J^T)``: one Cholesky factor and one triangular
        solve for all candidates instead of M eigen-decompositions."""
        a = base_info + eps * np.eye(r)
        low = np.linalg.cholesky(a)
        b = np.linalg.solve(low, js.transpose(2, 1, 0).reshape(r, rows * n_cand))  # L^-1 J^T
        b = b.reshape(r, rows, n_cand)
        g = np.einsum("ijc,ilc->cjl", b, b) + np.eye(rows)
        return 2.0 * np.sum(np.log(np.diag(low))) + np.linalg.slogdet(g)[1]

    def scores(base_info: np.ndarray, size: int, name: str | None) -> np.ndarray:
        """Index of base_info + info[c] for every candidate c (name None: regularised logdet).
        O1 is a monotone function of log det at a fixed number of poses, so it is ranked by
        log det too."""
        if name is None or name == "O1":
            return logdets(base_info)
        out = np.empty(n_cand)
        for lo in range(0, n_cand, 256):  # chunks bound the memory (256 x r x r)
            ev = np.linalg.eigvalsh(base_info + info[lo : lo + 256])
            if name is None:
                out[lo : lo + 256] = np.sum(np.log(ev + eps), axis=-1)
            else:
                out[lo : lo + 256] = _criterion(ev, name, size)
        return out

    def value(mat: np.ndarray, size: int) -> float:
        return float(_criterion(np.linalg.eigvalsh(mat), criterion, size))

    chosen: list[int] = []
    total = np.zeros((r, r))
    free = np.ones(n_cand, dtype=bool)
    for step in range(k):
        name = criterion if step + 1 >= k_min else None
        sc = scores(total, step + 1, name)
        if name is not None and np.max(sc[free]) <= 0:  # still singular: keep filling by logdet
            sc = scores(total, step + 1, None)
        c = pick(sc, free)
        chosen.append(c)
        free[c] = False
        total = total + info[c]
    greedy_value = value(total, k)

    n_exchanges = 0
    if exchange:
        for _ in range(max_passes):
            improved = False
            for pos in range(k):
                without = total - info[chosen[pos]]
                sc = scores(without, k, criterion)
                c = pick(sc, free)
                now = sc[chosen[pos]]  # the current set's score on the same scale
                if sc[c] > now + 1e-9 * abs(now) + 1e-300:
                    free[chosen[pos]] = True
                    free[c] = False
                    chosen[pos] = c
                    total = without + info[c]
                    n_exchanges += 1
                    improved = True
            if not improved:
                break
    idx = np.array(chosen, dtype=int)
    return PosePlan(
        indices=idx,
        criterion=criterion,
        value=value(total, k),
        greedy_value=greedy_value,
        n_exchanges=n_exchanges,
        base_indices=base,
        measurements=cand.subset(idx),
        data_kind=kind.name,
        readings_per_pose=per_pose,
    )


def pose_design(robot: Robot, cand: Measurements, x: Any, report: Any
                ) -> tuple[Problem, np.ndarray, np.ndarray, int, str]:
    """:func:`plan_poses`'s problem for pose data: ``(problem, x, base indices, readings per
    pose, what they are)``."""
    if robot.effects:  # issue 23: the geometry's and the effects' parameters together
        from .effects.api import identifiability as effect_identifiability
        from .effects.problem import EffectProblem

        eproblem = EffectProblem(robot, cand)
        x = np.zeros(eproblem.n_params) if x is None else np.asarray(x, dtype=float)
        if report is None:
            report = effect_identifiability(robot, cand, x)
        return eproblem, x, np.flatnonzero(report.active), 6, "readings"
    problem = Problem(robot, cand)
    x = np.zeros(robot.n_params) if x is None else np.asarray(x, dtype=float)
    if report is None:
        report = identifiability(robot, cand, x)
    return problem, x, report.base_indices, 6, "readings"


def tracker_design(robot: Robot, cand: Measurements, x: Any, report: Any
                   ) -> tuple[Any, np.ndarray, np.ndarray, int, str]:
    """:func:`plan_poses`'s problem for laser-tracker data: the tracker problem's information,
    the registration and the offsets included, one null direction per held parameter."""
    from .tracker.analysis import null_space

    problem, x = _tracker_problem(robot, cand, x)
    if report is None:
        report = null_space(problem, x)
    what = "point coordinates" if robot.tracker.kind == "points" else "probe coordinates"
    return problem, x, np.flatnonzero(report.active), 3 * robot.tracker.n_points, what


def _tracker_problem(robot: Robot, cand: Measurements, x: Any) -> tuple[Any, np.ndarray]:
    """The tracker problem of candidate poses measured by the nominal setup: the points (probe
    poses) the nominal robot and setup give at them, and ``x`` (robot's then setup's; default
    zeros; the robot's alone: the nominal setup)."""
    from .tracker.data import TrackerMeasurements
    from .tracker.problem import TrackerProblem
    from .tracker.simulate import true_points
    from .transforms import pose_from_matrix

    setup = robot.tracker
    n_all = robot.n_params + setup.n_params
    xf = np.zeros(n_all) if x is None else np.asarray(x, dtype=float)
    if xf.shape == (robot.n_params,):
        xf = np.concatenate([xf, np.zeros(setup.n_params)])
    if xf.shape != (n_all,) or not np.all(np.isfinite(xf)):
        raise ValueError(f"x: expected {n_all} finite values (the robot's {robot.n_params} then "
                         f"the tracker setup's {setup.n_params}), got shape {xf.shape}")
    pts = true_points(robot, setup, np.zeros(n_all), cand.poses)
    if setup.kind == "points":
        m = TrackerMeasurements(cand.q, cand.legs, points=pts, joint_types=robot.joint_types)
    else:
        t = np.tile(np.eye(4), (len(cand), 1, 1))
        t[:, :3, 3] = pts[:, 0]
        t[:, :3, :3] = np.swapaxes((pts[:, 1:] - pts[:, :1]) / setup.probe_length, 1, 2)
        probe = np.array([pose_from_matrix(mat) for mat in t])
        m = TrackerMeasurements(cand.q, cand.legs, probe=probe, joint_types=robot.joint_types)
    return TrackerProblem(robot, setup, m), xf


def measure(
    robot: Robot,
    x: Any,
    q: Any,
    poses: Any,
    noise: Noise | None = None,
    seed: int | np.random.Generator | None = None,
    *,
    setup: Any = None,
) -> Measurements:
    """Simulated readings at given poses: the actual robot (nominal + ``x``) at joint readings
    ``q`` and world platform poses ``poses``, with the noise model of :func:`iwr.simulate`.

    This is how a planned set of poses is measured in a simulation: the leg readings are those of
    the actual robot, then the joint readings, legs, position and orientation get their noise.
    For a robot with a tracker (``robot.tracker``), ``x`` holds the robot's then the setup's true
    parameters and the result is :class:`iwr.tracker.TrackerMeasurements` (the points or probe
    poses in {T}); ``noise`` is then None, an iwr.Noise (readings), an
    :class:`iwr.tracker.TrackerNoise` or a pair of both. For a ballbar robot (docs/ballbar.md),
    ``setup`` names the set-up each pose is measured in (``plan.measurements.setup``), ``x``
    holds the robot's then the set-ups' true parameters, and the result is
    :class:`iwr.ballbar.BallbarMeasurements` (``noise``: None, an iwr.Noise, a
    :class:`iwr.ballbar.BallbarNoise` or a pair).
    """
    poses = np.asarray(poses, dtype=float)
    q = np.asarray(q, dtype=float).reshape(len(poses), robot.n_joints)
    x = np.asarray(x, dtype=float)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    kind = kinds.for_robot(robot)
    if kind.setups_per_pose:
        return kind.measure(robot, x, q, poses, noise, rng, setup=setup)
    if setup is not None:
        raise ValueError(f"setup: robot {robot.name!r} is measured by {kind.description}, whose "
                         "readings belong to no set-up; give setup=None")
    return kind.measure(robot, x, q, poses, noise, rng)


def measure_poses(robot: Robot, x: np.ndarray, q: np.ndarray, poses: np.ndarray, noise: Any,
                  rng: np.random.Generator) -> Measurements:
    """:func:`measure` for pose data."""
    legs = predict_legs(robot, x, q, poses)
    noise = noise if noise is not None else Noise()
    return add_noise(robot, q, poses, legs, noise, rng)


def measure_tracker(robot: Robot, x: np.ndarray, q: np.ndarray, poses: np.ndarray, noise: Any,
                     rng: np.random.Generator) -> Any:
    """:func:`measure` for a robot with a tracker: ``x`` the robot's then the setup's true
    parameters; the points (or probe poses) in {T} the true setup measures, with the reading
    noise then the tracker noise of :func:`iwr.simulate` (``noise``: None, an iwr.Noise, a
    TrackerNoise, or a pair)."""
    from .noise import split_noise
    from .tracker.data import TrackerMeasurements
    from .tracker.simulate import true_points
    from .transforms import pose_from_matrix

    setup = robot.tracker
    nr = robot.n_params
    if x.shape != (nr + setup.n_params,):
        raise ValueError(f"x: shape {x.shape}; expected ({nr + setup.n_params},): the robot's "
                         f"{nr} then the tracker setup's {setup.n_params}")
    readings, tracker = split_noise(noise)
    legs = predict_legs(robot, x[:nr], q, poses)
    pts = true_points(robot, setup, x, poses)
    if readings is not None and not readings.is_zero:
        sq = np.where([c == "P" for c in robot.joint_types], readings.joint_lengths,
                      readings.joint_angles)
        q = q + sq * rng.standard_normal(q.shape)
        legs = legs + readings.legs * rng.standard_normal(legs.shape)
    if setup.kind == "points":
        if tracker is not None:
            pts = tracker.perturb(pts, rng)
        return TrackerMeasurements(q, legs, points=pts, joint_types=robot.joint_types)
    t = np.tile(np.eye(4), (len(poses), 1, 1))
    t[:, :3, 3] = pts[:, 0]
    t[:, :3, :3] = np.swapaxes((pts[:, 1:] - pts[:, :1]) / setup.probe_length, 1, 2)
    if tracker is not None:
        from scipy.spatial.transform import Rotation

        t[:, :3, 3] = tracker.perturb(t[:, :3, 3], rng)
        turn = Rotation.from_rotvec(tracker.orientation * rng.standard_normal((len(poses), 3)))
        t[:, :3, :3] = turn.as_matrix() @ t[:, :3, :3]
    probe = np.array([pose_from_matrix(m) for m in t])
    return TrackerMeasurements(q, legs, probe=probe, joint_types=robot.joint_types)
