"""What tracker data cannot see (docs/tracker.md, "What tracker data determine"): the null
directions of a tracker problem (:func:`null_space`), and the rigid transform that aligns two
sets of frames modulo that gauge (:func:`_align`); with the forward kinematics they start from."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import _core
from ..base_parameters import (
    condition_number,
    direction_text,
    left_out_directions,
    observability_indices,
    report_lines,
)
from ..robot import Robot
from .problem import TrackerProblem

__all__ = ["NullSpace", "null_space"]


def _fk(robot: Robot, xr: np.ndarray, q: np.ndarray, legs: np.ndarray) -> np.ndarray:
    return _core.forward_kinematics(robot._geometry, np.ascontiguousarray(xr, dtype=float),
                                    np.ascontiguousarray(q, dtype=float),
                                    np.ascontiguousarray(legs, dtype=float), np.zeros((0, 6)),
                                    robot.home_pose)[0]


def _align(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The one rigid transform D (4x4) that best maps the frames ``a @ D`` onto ``b`` (N, 4, 4):
    the chordal mean of the rotations ``a_k^-1 b_k`` projected on SO(3), then the translation
    that minimises the squared position differences of the frames' origins."""
    rel = np.linalg.solve(a, b)
    u, _, vt = np.linalg.svd(rel[:, :3, :3].mean(axis=0))
    r = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt)) or 1.0]) @ vt
    # origin of a_k D: pa_k + Ra_k t = pb_k  ->  least squares in t
    ra = a[:, :3, :3]
    t, *_ = np.linalg.lstsq(ra.reshape(-1, 3), (b[:, :3, 3] - a[:, :3, 3]).reshape(-1),
                            rcond=None)
    d = np.eye(4)
    d[:3, :3], d[:3, 3] = r, t
    return d


@dataclass(frozen=True)
class NullSpace:
    """The null directions of a tracker problem's column-scaled Jacobian.

    ``vectors[:, k]`` (physical units) has coefficient 1 on ``left_out[k]`` and 0 on the other
    left-out parameters; moving ``x`` along it leaves every residual unchanged to first order.
    """

    singular_values: np.ndarray
    rank: int
    threshold: float
    parameter_names: list[str]
    left_out: list[str]
    vectors: np.ndarray
    scale: np.ndarray = field(repr=False)
    #: The poses and readings of the Jacobian (the report's first line, and O1's N).
    n_poses: int = 0
    n_readings: int = 0

    @property
    def active(self) -> np.ndarray:
        """The parameters kept (not left out): the mask to pass to ``iwr.identify(active=)``."""
        out = set(self.left_out)
        return np.array([n not in out for n in self.parameter_names], dtype=bool)

    def describe(self, k: int, tol: float = 1e-6) -> str:
        """``"+1 joint1.dtheta -1 tracker.rz"``-style text of null direction k (as the pose
        data's :class:`iwr.analysis.identifiability.NullDirection`): its nonzero components,
        largest scaled first."""
        return direction_text(self.vectors[:, k], self.scale, self.parameter_names, tol)

    @property
    def condition_number(self) -> float:
        """``s_1 / s_r`` over the identifiable part, as :class:`iwr.IdentifiabilityReport`."""
        return condition_number(self.singular_values, self.rank)

    @property
    def observability(self) -> dict[str, float]:
        """O1..O4 of the identifiable part (:func:`iwr.base_parameters.observability_indices`)."""
        return observability_indices(self.singular_values[: self.rank], self.n_poses)

    def __str__(self) -> str:
        """The report of pose data's :class:`iwr.IdentifiabilityReport`, line for line (it gave
        the rank and the directions alone: an outside check)."""
        lines = [
            f"Identifiability from {self.n_poses} poses ({self.n_readings} readings), "
            f"{len(self.parameter_names)} parameters (the robot's errors and the set-up's)",
            *report_lines(self.singular_values, self.rank, self.threshold, self.n_poses),
        ]
        held = list(getattr(self, "held", []))  # with effects: what only the loads fix
        if not self.left_out and not held:
            return "\n".join([*lines, "  every parameter is identifiable"])
        lines.append(f"  base parameters: {int(self.active.sum())}; left out (hold fixed): "
                     + ", ".join(self.left_out))
        if held:
            lines.append(f"  held too ({len(held)}, counted in the rank: directions only the "
                         "loads fix, too weakly to identify with noise): " + ", ".join(held))
        lines.append("  unidentifiable directions (coefficients in mm and rad):")
        lines += [f"    {k + 1}. [{name}] {self.describe(k)}"
                  for k, name in enumerate(self.left_out)]
        return "\n".join(lines)


def null_space(problem: TrackerProblem, x: Any = None, rtol: float | None = None) -> NullSpace:
    """SVD of the column-scaled exact Jacobian (each column divided by its norm, as
    :func:`iwr.identifiability`) at ``x`` (default zeros); the rank threshold is ``rtol`` times
    the largest singular value, default ``max(shape) * eps``."""
    x = np.zeros(problem.n_params) if x is None else np.asarray(x, dtype=float)
    jac = problem.jacobian(x)
    d = np.linalg.norm(jac, axis=0)
    d = np.where(d > 0, d, 1.0)
    # U is not needed: full matrices only when there are fewer rows than parameters (for V).
    _, s, vt = np.linalg.svd(jac / d, full_matrices=jac.shape[0] < jac.shape[1])
    rtol = max(jac.shape) * np.finfo(float).eps if rtol is None else float(rtol)
    thr = rtol * s[0]
    rank = int(np.sum(s > thr))
    ns = vt[rank:].T / d[:, None]  # physical units
    names = problem.parameter_names
    size = {"n_poses": len(problem.measurements), "n_readings": int(jac.shape[0])}
    if ns.shape[1] == 0:
        return NullSpace(s, rank, thr, names, [], ns, d, **size)
    # One direction per left-out parameter: the best-conditioned rows of the scaled null basis
    # (QR with column pivoting), ties between exactly dependent parameters broken by a fixed
    # preference (the carriage's left out before the set-up's, the hexapod's last), not by
    # round-off: the same gauge whatever the instruction set or the objective's last bits.
    out, basis = left_out_directions(vt[rank:], ns, names)
    return NullSpace(s, rank, thr, names, [names[i] for i in out], basis, d, **size)
