"""The base of every measurement kind's part of the efficient estimator's loop
(:func:`iwr.estimation.efficient`, docs/estimation.md): what the kinds' specs
(``iwr.estimation._PoseSpec``, :class:`iwr.tracker.estimation.TrackerSpec`,
:class:`iwr.ballbar.estimation.BallbarSpec`, and the effects' on top of them) share.

A spec holds the data (``measurements``), the robot, the noise model at the start, the active
parameters (``mask``), the plausible size of the parameters (``limit`` about ``center``) and the
problem of the data; the loop asks it to solve, to name and locate each pose, to test the
parameters' plausibility on the poses in use and for the unweighted cost. A kind implements
``solve``, ``start_sigma``, ``noise_used``, ``predicted`` and :meth:`plausibility_model`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import numpy as np

from .fit_test import Beyond, beyond_plausible
from .result import pose_key, source_line

__all__ = ["EstimatorSpec"]


class EstimatorSpec:
    """What the kinds' estimator specs share: the poses' names and lines, the poses in use, the
    plausibility of the parameters and the unweighted cost."""

    #: The kind's name in the estimator's messages.
    kind = ""
    #: The instrument's own noise in :meth:`noise_dict` (the second of a ``(readings,
    #: instrument)`` pair; None: the noise model is one :class:`iwr.Noise`).
    instrument: str | None = None
    #: The plausible parameters' centre (None: zero, the nominal robot).
    center: np.ndarray | None = None
    #: What makes the model not fit this kind's data, most likely first (None: pose and tracker
    #: data's, :data:`iwr.fit_test.MISFIT_CAUSES`).
    misfit_causes: str | None = None

    measurements: Any
    problem: Any
    limit: np.ndarray
    parameter_names: list[str]

    def where(self, k: int) -> str:
        """Pose ``k`` as a message names it (its file and line, or its index)."""
        return self.measurements.where(k)

    def line(self, k: int) -> int | None:
        return source_line(self.measurements, k)

    def key(self, k: int) -> str:
        return pose_key(self.measurements, k)

    def subset(self, used: np.ndarray) -> Any:
        """The data of the poses in use (``used``, a mask; all of them: the data themselves)."""
        return self.measurements if used.all() else \
            self.measurements.subset(np.flatnonzero(used))

    def plausibility_model(self, used: np.ndarray
                           ) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
        """The readings the data of the poses in use predict at ``x``, with their Jacobian
        (``x -> (r, J)``): what :meth:`implausible` holds fixed."""
        raise NotImplementedError

    def implausible(self, x: np.ndarray, used: np.ndarray, covariance: Any = None,
                    alpha: float = 1e-3) -> list[Beyond]:
        """Each parameter beyond its plausible size in the smallest ``x`` that predicts the same
        readings, tested against the spread ``covariance`` gives it at level ``alpha``
        (:func:`iwr.fit_test.beyond_plausible`)."""
        return beyond_plausible(self.plausibility_model(used), x, self.limit, self.center,
                                self.parameter_names, covariance, alpha)

    def noise_dict(self, noise: Any) -> dict[str, Any]:
        """The noise model as the result's JSON fields."""
        if self.instrument is None:
            return asdict(noise)
        return {"readings": asdict(noise[0]), self.instrument: asdict(noise[1])}

    def cost_eq10(self, x: np.ndarray) -> float:
        """The unweighted objective of the data (eq. (10) or its analogue on the kind's
        readings)."""
        return float(self.problem.cost(x))
