"""Fixtures of the method tests: the default IWR, noise-free data and fresh validation poses."""

from __future__ import annotations

import numpy as np
import pytest

import iwr


@pytest.fixture(scope="package")
def robot() -> iwr.Robot:
    return iwr.Robot.default()


@pytest.fixture(scope="package")
def data(robot):
    """Noise-free data of 30 poses and the true errors."""
    return iwr.simulate(robot, n_poses=30, seed=5)


@pytest.fixture(scope="package")
def validation(robot, data):
    """Fresh poses of the same actual robot, exact readings."""
    _, truth = data
    m, _ = iwr.simulate(robot, n_poses=40, seed=77, x=truth)
    return m


@pytest.fixture(scope="package")
def subset(robot, data):
    """12 parameters (leg offsets and the z of the base joints), the others held at the truth:
    identifiable, and small enough for the derivative-free methods to converge in a test."""
    _, truth = data
    names = robot.parameter_names
    active = np.array([n.endswith(".dl0") or n.endswith(".da_z") for n in names])
    x0 = truth.copy()
    x0[active] = 0.0
    return active, x0


def validation_rms(robot, x, m) -> float:
    return float(np.sqrt(np.mean((iwr.predict_legs(robot, x, m.q, m.poses) - m.legs) ** 2)))
