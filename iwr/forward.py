"""Forward kinematics: the platform pose from the carriage joint and leg sensor readings."""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _core, kinds
from .measurements import as_matrix
from .robot import Robot
from .transforms import pose_from_matrix, pose_matrix

__all__ = ["forward_kinematics", "ForwardKinematicsError"]

#: Raised when Newton-Raphson does not converge or meets a singular Jacobian; a ``RuntimeError``
#: whose ``pose`` attribute is the index of the offending pose.
ForwardKinematicsError = _core.ForwardKinematicsError


def forward_kinematics(
    robot: Robot,
    x: Any,
    q: Any,
    legs: Any,
    guess: Any = None,
    *,
    tolerance: float = 1e-9,
    max_iterations: int = 50,
) -> np.ndarray:
    """World poses of the platform from joint and leg readings (the forward kinematics).

    The inverse model (eq. 5-8) gives the six leg lengths from a pose; this inverts it by
    Newton-Raphson on the six leg-length equations, with their exact Jacobian with respect to the
    pose of frame {5} in frame {4} and a backtracking line search, in C++. The world pose is then
    ``0T5 = 0T4(q) 4T5`` (eq. 7).

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    x : array_like, shape (n_params,), or None
        Error parameters added to the nominal geometry (None or zeros: the nominal robot; an
        identified vector: the calibrated robot).
    q : array_like, shape (N, n_joints)
        Carriage joint readings (mm, rad).
    legs : array_like, shape (N, 6)
        Leg sensor readings (mm); a leg's whole length is its reading plus ``l0 + dl0``.
    guess : array_like, shape (6,) or (N, 6), optional
        World poses to start from. Default: ``robot.home_pose`` carried through the carriage at
        each ``q``. Newton-Raphson converges to the assembly mode nearest the guess.
    tolerance : float
        Convergence: the largest leg-length residual (mm).
    max_iterations : int
        Newton iterations per pose before giving up.

    Returns
    -------
    ndarray, shape (N, 6)
        Rows ``(x, y, z, alpha, beta, gamma)`` in the world frame (mm, rad; Z-Y-X Euler angles of
        eq. 6, beta in [-pi/2, pi/2]).

    Raises
    ------
    ForwardKinematicsError
        (a ``RuntimeError``) when a pose does not converge within ``max_iterations`` (leg readings
        that no pose of this robot produces, or a guess too far away) or the Jacobian is singular;
        its ``pose`` attribute is the index of the pose.
    ValueError
        On bad shapes or non-finite values.

    Notes
    -----
    Newton-Raphson iterates on the local coordinates of frame {5} in {4}, not on the world Euler
    angles: the IWR's world Euler angles sit at their gimbal lock (beta = -pi/2) at the home pose,
    where a Jacobian with respect to them is singular.
    """
    if not isinstance(robot, Robot):
        raise TypeError(f"robot: expected an iwr.Robot, got {type(robot).__name__}")
    if x is not None and np.size(x) != robot.n_params:
        # An x identified with an instrument's setup parameters (tracker data): the poses in
        # the frame the data are given in (docs/tracker.md).
        return in_data_frame(robot, x, q, legs)
    legs = as_matrix(legs, 6, "legs")
    n = legs.shape[0]
    q = as_matrix(q, robot.n_joints, "q", rows=n)
    x = np.zeros(robot.n_params) if x is None else np.ascontiguousarray(x, dtype=float)
    if x.shape != (robot.n_params,):
        raise ValueError(f"x: shape {x.shape}; expected ({robot.n_params},)")
    if guess is None:
        g = np.zeros((0, 6))
    else:
        g = np.asarray(guess, dtype=float)
        if g.shape == (6,):
            g = np.tile(g, (n, 1))
        g = as_matrix(g, 6, "guess", rows=n)
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer)):
        raise ValueError(f"max_iterations: {max_iterations!r}; expected a positive integer")
    poses, _ = _core.forward_kinematics(
        robot._geometry, x, q, legs, g, robot.home_pose, float(tolerance), int(max_iterations)
    )
    return poses


def in_data_frame(robot: Robot, x: Any, q: Any, legs: Any) -> np.ndarray:
    """:func:`forward_kinematics` with an ``x`` identified from the robot's instrument's data
    (the robot's parameters, then the setup's: :func:`iwr.kinds.for_robot`): the platform poses
    in the frame the data are given in (the tracker's {T}: its identified registration), ``(N,
    6)``. (Modulo the gauge of docs/tracker.md: what tracker data determine.)"""
    kind = kinds.for_robot(robot)
    x = np.asarray(x, dtype=float)
    nr = robot.n_params
    n = kind.n_params(robot)
    if x.shape != (n,):
        with_setup = (f"({n},) for robot {robot.name!r} with its {kind.name} setup, or "
                      if n != nr else "")
        raise ValueError(f"x: shape {x.shape}; expected {with_setup}({nr},) for poses in {{0}}")
    poses = forward_kinematics(robot, x[:nr], q, legs)
    reg = kind.registration(robot, x[nr:])
    return np.array([pose_from_matrix(reg @ pose_matrix(p)) for p in poses])
