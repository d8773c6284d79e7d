"""Gravity for the effects on data that fix no direction in {0} (laser-tracker data): given in
the instrument's frame and carried into {0} by the identified registration (docs/effects.md,
"Tracker data"). Below :mod:`iwr.effects.tracker` and
:mod:`iwr.effects.api`, which both use it."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from .. import kinds
from .loop import _skew, right_jacobian

__all__ = ["in_world_gravity", "registration_gravity", "with_gravity"]


def registration_gravity(setup: Any, x_setup: Any) -> tuple[np.ndarray, np.ndarray]:
    """Gravity in {0} (3,) (m/s^2) at the setup's parameters ``x_setup``, ``R_T0^T g_T``, and its
    derivative in them (3, setup.n_params): with ``R_T0 = R_nom Exp(r)``,
    ``d g_0 / d r = [g_0]x J_r(r)`` (only the registration's rotation moves it)."""
    xs = np.asarray(x_setup, dtype=float)
    rot = setup.registration_matrix(xs)[:3, :3]
    g0 = rot.T @ setup.gravity
    d = np.zeros((3, setup.n_params))
    d[:, 3:6] = _skew(g0) @ right_jacobian(xs[3:6])
    return g0, d


def with_gravity(robot: Any, gravity: np.ndarray) -> Any:
    """``robot`` whose effects of the load (the legs' and the carriage's compliance) take
    ``gravity`` (in {0})."""
    effects = []
    for e in robot.effects:
        if hasattr(e, "gravity"):
            e = copy.copy(e)
            e.gravity = np.array(gravity, dtype=float)
        effects.append(e)
    return robot.with_effects(*effects)


def in_world_gravity(robot: Any) -> Any:
    """``robot`` whose effects take gravity as its data give it
    (:meth:`iwr.kinds.MeasurementKind.world_gravity` of the kind ``robot`` measures: for a
    robot with a tracker, the tracker's gravity in {T} carried into {0} by the robot file's
    registration); ``robot`` itself when its effects' own gravity in {0} stands."""
    if not robot.effects:
        return robot
    gravity = kinds.for_robot(robot).world_gravity(robot)
    return robot if gravity is None else with_gravity(robot, gravity)
