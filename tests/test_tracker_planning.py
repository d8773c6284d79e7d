"""iwr.plan_poses and iwr plan for a robot with a laser tracker: the tracker problem's information
(registration and offsets included, null directions left out); planned poses beat random ones on
the criterion and on the tool accuracy after calibration."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile

import numpy as np
import pytest

import iwr
from iwr.analysis.identifiability import column_scale
from iwr.planning import _criterion, _tracker_problem, measure
from iwr.simulation import sample_poses
from iwr.tracker import TrackerMeasurements, TrackerNoise

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
NOISE = (iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6), TrackerNoise.leica())


def robot_for(kind: str) -> iwr.Robot:
    kw = {"reflectors": REFLECTORS} if kind == "points" else {"probe": (0, 0, 60, 0, 0, 0)}
    return iwr.Robot.default().with_tracker(registration=REGISTRATION, **kw)


def candidates(robot: iwr.Robot, m: int) -> iwr.Measurements:
    q, poses, legs = sample_poses(robot, m, np.random.default_rng(0))
    return iwr.Measurements(q, poses, legs, joint_types=robot.joint_types)


@pytest.mark.parametrize("kind", ["points", "probe"])
def test_planned_poses_beat_random_ones_on_the_criterion(kind):
    robot = robot_for(kind)
    cand = candidates(robot, 100)
    plan = iwr.plan_poses(robot, cand, 20, criterion="O1", seed=0)
    assert plan.data_kind == kind and len(set(plan.indices.tolist())) == 20
    problem, x = _tracker_problem(robot, cand, None)
    ns = iwr.identifiability(robot, problem.measurements)
    # the setup's parameters are planned for; one per null direction is left out
    assert plan.base_indices.size == ns.rank == problem.n_params - 16
    assert any(problem.parameter_names[i].startswith("tracker.") for i in plan.base_indices)
    jac = problem.jacobian(x)[:, plan.base_indices]
    js = (jac / column_scale(jac)).reshape(100, 3 * robot.tracker.n_points, -1)

    def value(idx):
        info = np.einsum("kij,kil->jl", js[idx], js[idx])
        return float(_criterion(np.linalg.eigvalsh(info), "O1", len(idx)))

    assert value(plan.indices) == pytest.approx(plan.value)
    rng = np.random.default_rng(1)
    random = [value(rng.choice(100, 20, replace=False)) for _ in range(10)]
    assert plan.value > 1.15 * max(random), (plan.value, random)
    with pytest.raises(ValueError, match="probe coordinates" if kind == "probe"
                       else "point coordinates"):
        iwr.plan_poses(robot, cand, 2)


def test_planned_poses_calibrate_the_tool_better_than_random_ones():
    robot = robot_for("points")
    cand = candidates(robot, 300)
    plan = iwr.plan_poses(robot, cand, 25, criterion="O1", seed=0)
    ratios, ori = [], []
    for seed in range(5):
        _, truth = iwr.simulate(robot, 1, seed=seed)
        fresh, _ = iwr.simulate(robot, 50, seed=1000 + seed, x=truth)
        rms, rms_o = [], []
        for idx in (plan.indices, np.random.default_rng(200 + seed).choice(300, 25, replace=False)):
            data = measure(robot, truth, cand.q[idx], cand.poses[idx], noise=NOISE, seed=seed)
            assert isinstance(data, TrackerMeasurements)
            res = iwr.identify(robot, data, active="base")
            assert res.success, res.message
            err = iwr.accuracy(robot, fresh, res.x, truth=truth).calibrated
            rms.append(math.sqrt(np.mean(err.position**2)))
            rms_o.append(math.sqrt(np.mean(err.orientation**2)))
        ratios.append(rms[1] / rms[0])
        ori.append(rms_o[1] / rms_o[0])
    # random / planned tool RMS after calibration, position and orientation, per seed
    assert np.median(ratios) > 1.1 and sum(r > 1 for r in ratios) >= 4, ratios
    assert np.median(ori) > 1.1, ori


def test_measure_gives_the_points_of_the_true_setup():
    robot = robot_for("probe")
    data, truth = iwr.simulate(robot, 10, seed=4)
    cand = candidates(robot, 10)
    m = measure(robot, truth, cand.q, cand.poses)  # noise-free
    problem, _ = _tracker_problem(robot, cand, None)
    assert iwr.tracker.TrackerProblem(robot, robot.tracker, m).cost(truth) < 1e-16
    with pytest.raises(ValueError, match="expected \\(70,\\)"):
        measure(robot, truth[:58], cand.q, cand.poses)


def test_iwr_plan_with_a_tracker_robot(tmp_path):
    robot_for("points").to_toml(tmp_path / "robot.toml")
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    proc = subprocess.run([sys.executable, "-m", "iwr", "plan", str(tmp_path / "robot.toml"),
                           "--n-candidates", "100", "--poses", "20", "--out",
                           str(tmp_path / "plan.csv")], capture_output=True, text=True,
                          cwd=tempfile.gettempdir(), env=environ, timeout=600)
    assert proc.returncode == 0, proc.stderr
    text = (tmp_path / "plan.csv").read_text()
    assert "reflector points measured by the tracker" in text and "docs/tracker.md" in text
    q, poses = iwr.read_plan(tmp_path / "plan.csv")
    assert q.shape == (20, 4) and poses.shape == (20, 6)
