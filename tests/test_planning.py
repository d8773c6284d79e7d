"""Plan files: what ``iwr plan`` writes is a plan, read back as one, and refused as measurements."""

from __future__ import annotations

import numpy as np
import pytest

import iwr
from iwr.simulation import sample_poses


@pytest.fixture(scope="module")
def plan():
    robot = iwr.Robot.default()
    q, poses, _ = sample_poses(robot, 120, np.random.default_rng(3))
    return iwr.plan_poses(robot, (q, poses), 12, "O1", seed=0), q, poses


def test_plan_file_round_trip(tmp_path, plan):
    p, q, poses = plan
    path = tmp_path / "plan.csv"
    p.to_csv(path, source="120 random poses")
    first = path.read_text().splitlines()[0]
    assert first.startswith("# iwr plan: 12 poses chosen for O1 from 120 random poses")
    q_back, poses_back = iwr.read_plan(path)
    np.testing.assert_array_equal(q_back, q[p.indices])
    np.testing.assert_array_equal(poses_back, poses[p.indices])
    # a plan is also a set of candidates
    again = iwr.plan_poses(iwr.Robot.default(), (q_back, poses_back), 12, "O1", seed=0)
    assert len(again.indices) == 12


def test_plan_file_is_refused_as_measurements_with_what_to_do(tmp_path, plan):
    p, _, _ = plan
    path = tmp_path / "plan.csv"
    p.to_csv(path)
    with pytest.raises(iwr.MeasurementFileError) as info:
        iwr.Measurements.from_csv(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: a pose plan written by 'iwr plan'")
    assert "drive the robot to each of its poses" in msg and "calibrate with that file" in msg


def test_measurements_are_not_a_plan(tmp_path):
    m, _ = iwr.simulate(iwr.Robot.default(), 5, seed=0)
    m.to_csv(tmp_path / "m.csv")
    with pytest.raises(iwr.MeasurementFileError, match="not a pose plan"):
        iwr.read_plan(tmp_path / "m.csv")
