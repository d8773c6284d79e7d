"""The linearised readings model of a data set at given parameters, per pose, that the
gross-error test (:mod:`iwr.gross_errors`) works on; each kind of data gives its own
(:meth:`iwr.kinds.MeasurementKind.misclosures`). A module of its own, below the kinds and the
estimators that build it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Misclosures"]


@dataclass(frozen=True)
class Misclosures:
    """A kind's linearised model of its readings at ``x`` (:meth:`MeasurementKind.misclosures`).

    Attributes
    ----------
    r : ndarray, shape (N, m)
        Misclosures, predicted minus measured; NaN for a component that carries no data (a point
        not seen, a leg weighted 0, a pose whose forward kinematics fails).
    a : ndarray, shape (N, m, n_params)
        Their derivatives in the parameters.
    b : ndarray, shape (N, m, n_readings)
        Their derivatives in each reading's error: a gross error ``e`` in reading ``i`` of pose
        ``k`` changes ``r[k]`` by ``b[k, :, i] e``.
    names : list of str
        The readings' names (``leg3``, ``q2``, ``position.x``, ``reflector2.z``, ...).
    components : list of str
        The names of the misclosures' components (``leg1`` .. ``leg6``, ``reflector1.x``, ...).
    reading_cov : ndarray, shape (N, n_readings, n_readings), or None
        The readings' covariance under the noise model; None without one.
    metric : ndarray, shape (N, m, m), or None
        Without a noise model: the misclosures' covariance up to the unknown factor ``sigma^2``
        (the objective's weighting; None: the identity).
    groups : ndarray of int, shape (m,), or None
        Without a noise model: the components that share one unknown sigma (estimated from
        their residuals), by group number; None: one sigma for all. Tracker points: the
        distance along the line of sight and the two directions across it, whose noise differs
        by a factor of 2 to 3 (the components are then along and across it).
    """

    r: np.ndarray
    a: np.ndarray
    b: np.ndarray
    names: list[str]
    components: list[str]
    reading_cov: np.ndarray | None = None
    metric: np.ndarray | None = None
    groups: np.ndarray | None = None

    def covariance(self, k: int, rows: np.ndarray) -> np.ndarray:
        """The covariance (noise model) or metric (without) of pose ``k``'s components ``rows``."""
        if self.reading_cov is not None:
            bk = self.b[k][rows]
            return bk @ self.reading_cov[k] @ bk.T
        if self.metric is None:
            return np.eye(int(np.sum(rows)))
        return self.metric[k][np.ix_(rows, rows)]
