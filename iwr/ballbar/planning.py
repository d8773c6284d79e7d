"""Pose planning for double-ballbar data (:func:`iwr.plan_poses`, docs/ballbar.md): the
candidates are (pose, set-up) pairs whose centre distance lies within the set-up's range, each
giving one bar reading; the plan chooses poses and set-ups together.

A candidate pose in {0} alone says nothing a ballbar measures: the bar reads the distance
between the platform ball of one set-up and its fixed ball. So every candidate pose becomes one
candidate per set-up whose bar reaches it (the nominal robot's and set-ups' centre distance
within the set-up's ``range``), and the information of a pair is the distance's (one row of the
:class:`iwr.ballbar.BallbarProblem` Jacobian: the robot's errors and every set-up's balls and
offset). Every set-up of the robot has 7 unknowns of its own, which only its readings see: a
set-up with fewer than 7 candidate pairs is refused by name.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..measurements import Measurements
from ..problem import predict_legs
from ..robot import Robot
from ..tracker.analysis import null_space
from .api import NULL_RTOL, _full_x, ballbar_problem, ballbar_setup
from .data import BallbarMeasurements
from .setup import _FIELDS
from .simulate import measured, true_distances

__all__ = ["BallbarCandidates", "ballbar_candidates", "ballbar_design", "measure_ballbar"]

#: What one candidate gives, for :func:`iwr.plan_poses`' messages.
READING = "distance (the bar's reading)"


class BallbarCandidates(Measurements):
    """Candidate (pose, set-up) pairs: the joint readings, the platform poses in {0} and the
    (nominal or measured) leg readings of :class:`iwr.Measurements`, and ``setup``, the name of
    the set-up (one of the robot's ``[ballbar.NAME]``) each pose would be measured in."""

    def __init__(self, q: Any, poses: Any, legs: Any, setup: Any, *,
                 joint_types: str | None = None, lines: Any = None,
                 source: str | None = None, payload: Any = None,
                 temperatures: Any = None) -> None:
        super().__init__(q, poses, legs, joint_types=joint_types, lines=lines, source=source,
                         payload=payload, temperatures=temperatures)
        if isinstance(setup, str):
            raise ValueError("setup: expected one set-up name per pose, got one string")
        names = np.array([str(s) for s in setup], dtype=object)
        if names.shape != (len(self),):
            raise ValueError(f"setup: {names.size} names; expected {len(self)}, one per pose")
        self.setup = names

    def subset(self, rows: Any) -> BallbarCandidates:
        idx = self._rows(rows)
        return BallbarCandidates(self.q[idx], self.poses[idx], self.legs[idx], self.setup[idx],
                                 joint_types=self.joint_types, lines=self._lines_at(idx),
                                 source=self.source, **_conditions(self, idx))

    def __repr__(self) -> str:
        return (f"BallbarCandidates(n_poses={len(self)}, set-ups="
                f"{sorted(set(self.setup.tolist()))})")


def _centre_distances(robot: Robot, poses: np.ndarray, index: int) -> np.ndarray:
    """The nominal centre distances (mm) of set-up ``index`` at platform poses in {0}."""
    setup = ballbar_setup(robot)
    offset = setup.split(None)[2][index]
    return true_distances(setup, None, np.full(len(poses), index), poses) - offset


def ballbar_candidates(robot: Robot, candidates: Measurements, setup: Any = None
                       ) -> BallbarCandidates:
    """The (pose, set-up) pairs :func:`iwr.plan_poses` chooses from: with ``setup`` (one
    set-up name per candidate, or the candidates' own ``setup``) the pairs as given; without,
    every candidate pose once per set-up whose nominal centre distance at it lies within the
    set-up's ``range`` (any distance without one), a pose's pairs in the set-ups' order. A
    set-up with fewer candidates than its 7 unknowns is refused by name."""
    bars = ballbar_setup(robot)
    m = len(candidates)
    if setup is None:
        setup = getattr(candidates, "setup", None)
    if setup is not None:
        names = setup_names(robot, setup, m)
        rows, given = np.arange(m), True
    else:
        inside = np.zeros((m, bars.n_setups), dtype=bool)
        for i, bar in enumerate(bars.bars):
            lo, hi = (-np.inf, np.inf) if bar.range is None else bar.range
            d = _centre_distances(robot, candidates.poses, i)
            inside[:, i] = (d >= lo) & (d <= hi)
        rows, which = np.nonzero(inside)  # row-major: a pose's pairs together
        names = np.array(bars.names, dtype=object)[which]
        given = False
    need = len(_FIELDS)
    for i, bar in enumerate(bars.bars):
        count = int(np.sum(names == bar.name))
        if count >= need:
            continue
        if given:
            where = f"{count} of the {m} candidate poses are given in it"
        elif bar.range is None:
            where = f"{count} candidate poses (it has no range: every pose is one)"
        else:
            d = _centre_distances(robot, candidates.poses, i)
            where = (f"{count} of the {m} candidate poses put its balls within its range "
                     f"{list(bar.range or ())} mm (centre distances {d.min():.1f} to "
                     f"{d.max():.1f} mm at the candidates)")
        raise ValueError(
            f"candidates: ballbar set-up {bar.name!r}: {where}; its {need} unknowns (the two "
            f"balls' centres and the bar's offset) need at least {need} readings: more or other "
            "candidates, a fixed ball nearer the platform's workspace, or a robot without this "
            "set-up")
    c = candidates
    return BallbarCandidates(c.q[rows], c.poses[rows], c.legs[rows], names,
                             joint_types=robot.joint_types,
                             lines=None if c.lines is None else c.lines[rows], source=c.source,
                             **_conditions(c, rows))


def _conditions(data: Any, rows: np.ndarray) -> dict[str, Any]:
    """The payload and temperatures of ``data`` at ``rows`` (issue 23; None where it has
    none)."""
    return {key: None if getattr(data, key, None) is None else getattr(data, key)[rows]
            for key in ("payload", "temperatures")}


def setup_names(robot: Robot, setup: Any, m: int) -> np.ndarray:
    """``setup`` (one name per pose, ``m`` poses) checked against the robot's set-ups."""
    known = ballbar_setup(robot).names
    if isinstance(setup, str):
        raise ValueError("setup: expected one set-up name per pose, got one string")
    names = np.array([str(s) for s in setup], dtype=object)
    if names.shape != (m,):
        raise ValueError(f"setup: {names.size} names; expected {m}, one per pose")
    bad = [k for k in range(m) if names[k] not in known]
    if bad:
        raise ValueError(f"setup: pose {bad[0]} names {names[bad[0]]!r}, not one of the "
                         f"robot's [ballbar] set-ups ({', '.join(known)})")
    return names


def _nominal_data(robot: Robot, cand: BallbarCandidates) -> BallbarMeasurements:
    """The bar readings the nominal robot and set-ups give at the candidates (their own leg
    readings kept: the problem's forward kinematics at ``x = 0`` gives their poses back)."""
    setup = ballbar_setup(robot)
    index = np.array([setup.index(s) for s in cand.setup], dtype=np.intp)
    distance = true_distances(setup, None, index, cand.poses)
    bad = np.flatnonzero(~(distance > 0))
    if bad.size:
        raise ValueError(f"candidates: pose {int(bad[0])} puts the balls of set-up "
                         f"{cand.setup[bad[0]]!r} at a nominal reading of "
                         f"{float(distance[bad[0]])!r} mm; a bar reading is > 0")
    legs = cand.legs
    if robot.effects:  # issue 23: the nominal robot's legs with its effects under each load
        from ..effects import parameter_names as effect_names
        from ..effects.model import predicted_readings

        legs = predicted_readings(robot, np.zeros(robot.n_params + len(effect_names(
            robot.effects))), cand.q, cand.poses, cand)
    return BallbarMeasurements(cand.q, legs, cand.setup, distance, joint_types=robot.joint_types,
                               payload=cand.payload, temperatures=cand.temperatures)


def ballbar_design(robot: Robot, cand: BallbarCandidates, x: Any, report: Any
                   ) -> tuple[Any, np.ndarray, np.ndarray, int, str]:
    """:func:`iwr.plan_poses`' problem for ballbar data: the distance objective of the pairs
    as the nominal set-ups measure them, ``x`` the robot's then the set-ups' parameters (the
    robot's alone: the nominal set-ups; default zeros), the base parameters of ``report`` (by
    default the null space of the candidates' distances, :func:`iwr.identifiability`'s)."""
    setup = ballbar_setup(robot)
    if robot.effects:  # issue 23: the distances with the effects, under each pair's load
        from .effects import design

        return (*design(robot, _nominal_data(robot, cand), x, report), READING)
    if x is not None and np.shape(x) == (robot.n_params,):
        x = np.concatenate([np.asarray(x, dtype=float), np.zeros(setup.n_params)])
    xf = _full_x(robot, setup, x)
    problem, _ = ballbar_problem(robot, _nominal_data(robot, cand))
    if report is None:
        report = null_space(problem, xf, NULL_RTOL)
    return problem, xf, np.flatnonzero(report.active), 1, READING


def measure_ballbar(robot: Robot, x: np.ndarray, q: np.ndarray, poses: np.ndarray, noise: Any,
                    rng: np.random.Generator, setup: Any = None) -> BallbarMeasurements:
    """:func:`iwr.planning.measure` for a ballbar robot: the actual robot and set-ups ``x``
    (the robot's then the set-ups' parameters) at joint readings ``q`` and platform poses
    ``poses`` in {0}, each measured in the set-up named by ``setup``; the leg and joint reading
    noise, then the bar's, as :func:`iwr.simulate` adds them
    (:func:`iwr.ballbar.simulate.measured`)."""
    bars = ballbar_setup(robot)
    if robot.effects:
        raise ValueError(f"robot {robot.name!r} has effects on: measuring a plan needs each "
                         "pose's payload and temperatures; simulate the plan's poses with "
                         "iwr.ballbar.effects.measure(robot, x, plan.measurements, noise, seed) "
                         "(docs/effects.md)")
    nr, n_all = robot.n_params, robot.n_params + bars.n_params
    if setup is None:
        raise ValueError("setup: a ballbar reads the distance of one set-up's balls; give each "
                         "pose's set-up (setup=plan.measurements.setup, or the names of the "
                         "robot's [ballbar] set-ups)")
    if x.shape != (n_all,):
        raise ValueError(f"x: shape {x.shape}; expected ({n_all},): the robot's {nr} then the "
                         f"ballbar set-ups' {bars.n_params}")
    index = np.array([bars.index(s) for s in setup_names(robot, setup, len(poses))],
                     dtype=np.intp)
    legs = predict_legs(robot, x[:nr], q, poses)
    return measured(robot, bars, x[nr:], index, q, poses, legs, noise, rng)
