"""The C++ objective of tracker data for a robot with effects (``cpp/src/effects_tracker.cpp``,
``_core.TrackerEffectObjective``): the cost DE, CRS2, BOBYQA and ``iwr-engine`` minimise on
points or a probe in {T} with the legs' compliance and thermal growth (docs/effects.md,
"Tracker data"). The numpy model (:class:`iwr.effects.tracker.TrackerEffectModel`) is the
independent one it is checked against; :class:`iwr.effects.tracker.TrackerEffectProblem` holds
one of each."""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _core
from ..problem_base import reference_error

__all__ = ["cpp_objective"]


def _matrix(a: Any) -> np.ndarray:
    return np.zeros((0, 0)) if a is None else np.ascontiguousarray(a, dtype=float)


def cpp_objective(robot: Any, setup: Any, measurements: Any, reference: np.ndarray,
                  whitening: Any = None) -> Any:
    """``_core.TrackerEffectObjective`` of ``measurements`` (an
    :class:`iwr.tracker.TrackerMeasurements` with the loads and temperatures ``robot``'s effects
    read) with ``setup`` (its gravity in {T} carried into {0} by the identified registration):
    parameters ``(geometric, effects, setup)``; each pose's forward kinematics with the effects
    starts from the geometric one at ``reference`` (the robot's geometric errors). ``whitening``
    (N, m, m) or None: the residuals ``W_k r_k`` per pose. The reference solve's failure names
    the data row (:class:`iwr.ForwardKinematicsError`)."""
    from ..problem import effect_inputs

    wh = (None if whitening is None
          else np.asarray(whitening, dtype=float).reshape(len(measurements), -1))
    try:
        return _core.TrackerEffectObjective(
            robot._geometry, kind=setup.kind, registration=setup.registration,
            reflectors=setup.reflectors if setup.reflectors is not None else np.zeros((1, 3)),
            probe=setup.probe if setup.probe is not None else np.zeros(6),
            probe_length=setup.probe_length, gravity=np.asarray(setup.gravity, dtype=float),
            q=np.ascontiguousarray(measurements.q, dtype=float),
            legs=np.ascontiguousarray(measurements.legs, dtype=float),
            points=np.ascontiguousarray(measurements.tracker_points(setup), dtype=float),
            reference=np.ascontiguousarray(reference, dtype=float), home=robot.home_pose,
            whitening=_matrix(wh), **effect_inputs(robot, measurements))
    except _core.ForwardKinematicsError as exc:
        raise reference_error(exc, measurements) from None

