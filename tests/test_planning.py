"""Pose planning (iwr.plan_poses, iwr plan) for every kind of data a robot can be measured by,
written once (the ``plannable`` fixture): the plan is the optimum of an exhaustive search on a
small case, it beats random poses on its criterion and, after a calibration from noisy readings,
on the tool's accuracy at fresh poses; planned poses are measured by the true instrument; the
command line writes a plan of the robot's kind. Then the plan files: what ``iwr plan`` writes is a
plan, read back as one, and refused as measurements."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
from itertools import combinations
from typing import Any

import numpy as np
import pytest

import iwr
from iwr import kinds
from iwr.planning import measure
from iwr.simulation import sample_poses

#: The kinds iwr.plan_poses takes (the ballbar's set-ups are not planned yet: refused, tested).
PLANNABLE = ("pose", "points", "probe")
#: The independent readings a pose gives: a platform pose, three reflector points, one rigid
#: probe pose (whatever number of coordinates the kind's problem writes it with).
INDEPENDENT = {"pose": 6, "points": 9, "probe": 6}


@pytest.fixture(scope="module", params=PLANNABLE)
def plannable(request: pytest.FixtureRequest, kind_case: Any) -> Any:
    return kind_case(request.param)


def _candidates(robot: iwr.Robot, m: int, seed: int = 0) -> iwr.Measurements:
    q, poses, legs = sample_poses(robot, m, np.random.default_rng(seed))
    return iwr.Measurements(q, poses, legs, joint_types=robot.joint_types)


def _o1(jac: np.ndarray, rows: int, subset: list[int] | np.ndarray) -> float:
    """O1 of the poses ``subset`` from the candidates' column-normalised Jacobian, written out:
    the geometric mean of the singular values over the square root of the number of poses."""
    js = (jac / np.linalg.norm(jac, axis=0)).reshape(-1, rows, jac.shape[1])
    s = np.linalg.svd(js[list(subset)].reshape(-1, jac.shape[1]), compute_uv=False)
    return float(np.exp(np.mean(np.log(s))) / math.sqrt(len(subset)))


def test_plan_is_optimal_on_a_small_case(plannable: Any) -> None:
    """Against exhaustive search: three poses more than the fewest that determine the base
    parameters, chosen from four more candidates (every subset tried)."""
    robot = plannable.robot
    kind = kinds.for_robot(robot)
    big = _candidates(robot, 60)
    problem, x, _, rows, _ = kind.design(robot, big, None, None)
    # the base parameters of all 60 (identifiability of the readings of the robot's kind)
    report = iwr.identifiability(robot, measure(robot, np.zeros(x.size), big.q, big.poses))
    base = np.flatnonzero(report.active)
    k = -(-base.size // INDEPENDENT[plannable.name]) + 3
    idx = np.arange(k + 4)
    cand = big.subset(idx)
    jac = problem.jacobian(x)[:, base].reshape(60, rows, -1)[idx].reshape(-1, base.size)
    if plannable.name != "pose":  # a report of pose data does not plan tracker data
        with pytest.raises(ValueError, match="report: the identifiability of 58 parameters"):
            iwr.plan_poses(robot, cand, k, report=iwr.identifiability(robot, big))
    js = (jac / np.linalg.norm(jac, axis=0)).reshape(-1, rows, base.size)

    def o3(sub: Any) -> float:
        return float(np.linalg.svd(js[list(sub)].reshape(-1, base.size), compute_uv=False)[-1])

    plan = iwr.plan_poses(robot, cand, k, "O1", report=report)
    assert plan.data_kind == plannable.name and np.array_equal(plan.base_indices, base)
    best = max(_o1(jac, rows, sub) for sub in combinations(range(k + 4), k))
    assert plan.value == pytest.approx(best, rel=1e-9)
    # O3 (the weakest direction) is not concave: the exchange ends where no single swap of a
    # chosen pose for a free one improves it (checked here), not always at the optimum
    plan = iwr.plan_poses(robot, cand, k, "O3", report=report)
    chosen = list(plan.indices)
    assert plan.value == pytest.approx(o3(chosen), rel=1e-9) and plan.value > 0
    for pos in range(k):
        for c in set(range(k + 4)) - set(chosen):
            assert o3(chosen[:pos] + [c] + chosen[pos + 1:]) <= plan.value * (1 + 1e-9)


def test_planned_poses_beat_random_ones_on_the_criterion(plannable: Any) -> None:
    robot = plannable.robot
    cand = _candidates(robot, 100)
    plan = iwr.plan_poses(robot, cand, 20, criterion="O1", seed=0)
    assert plan.value >= plan.greedy_value > 0 and len(set(plan.indices.tolist())) == 20
    problem, x, base, rows, _ = kinds.for_robot(robot).design(robot, cand, None, None)
    assert np.array_equal(plan.base_indices, base)
    if plannable.name != "pose":  # the setup's parameters are planned for too
        assert any(problem.parameter_names[i].startswith("tracker.") for i in base)
    jac = problem.jacobian(x)[:, base]
    assert _o1(jac, rows, plan.indices) == pytest.approx(plan.value, rel=1e-9)
    rng = np.random.default_rng(1)
    random = [_o1(jac, rows, rng.choice(100, 20, replace=False)) for _ in range(10)]
    assert plan.value > 1.15 * max(random), (plan.value, random)
    k_min = -(-base.size // INDEPENDENT[plannable.name])
    with pytest.raises(ValueError, match=f"n_poses: {k_min - 1}; expected an integer from "
                                         f"{k_min} "):
        iwr.plan_poses(robot, cand, k_min - 1)
    assert iwr.plan_poses(robot, cand, k_min).value > 0  # the fewest poses determine them


def test_planned_poses_calibrate_the_tool_better_than_random_ones(plannable: Any) -> None:
    """With realistic noise, 25 planned poses (O1) of 300 candidates calibrate the tool better
    than 25 random ones: the RMS tool error on 50 fresh poses, per seed (5 seeds: true robot,
    noise and random subset), position and orientation."""
    robot = plannable.robot
    kind = kinds.for_robot(robot)
    noise = kind.experiment_noise(robot, iwr.Noise.realistic())
    cand = _candidates(robot, 300)
    plan = iwr.plan_poses(robot, cand, 25, criterion="O1", seed=0)
    ratios, ori = [], []
    for seed in range(5):
        _, truth = iwr.simulate(robot, 1, seed=seed)
        fresh, _ = iwr.simulate(robot, 50, seed=1000 + seed, x=truth)
        rms, rms_o = [], []
        for idx in (plan.indices, np.random.default_rng(200 + seed).choice(300, 25, replace=False)):
            data = measure(robot, truth, cand.q[idx], cand.poses[idx], noise=noise, seed=seed)
            assert kinds.of(data) is kind
            res = iwr.identify(robot, data, "lm", active="base")
            assert res.success, res.message
            err = kind.tool_accuracy(robot, fresh, res.x, truth).calibrated
            rms.append(math.sqrt(np.mean(err.position**2)))
            rms_o.append(math.sqrt(np.mean(err.orientation**2)))
        ratios.append(rms[1] / rms[0])
        ori.append(rms_o[1] / rms_o[0])
    # random / planned tool RMS after calibration
    assert np.median(ratios) > 1.1 and sum(r > 1 for r in ratios) >= 4, ratios
    assert np.median(ori) > 1.1, ori


def test_measure_gives_the_readings_of_the_true_robot(plannable: Any) -> None:
    """Planned poses measured without noise: the kind's own problem of the true robot (and
    setup) fits them exactly; a truth of the wrong size is refused."""
    robot, truth = plannable.robot, plannable.truth
    cand = _candidates(robot, 10, seed=4)
    m = measure(robot, truth, cand.q, cand.poses)
    problem, _ = kinds.for_robot(robot).problem(robot, m, x0=truth)
    assert problem.cost(truth) < 1e-16
    with pytest.raises(ValueError, match=f"expected \\({truth.size},\\)"
                       if plannable.name != "pose" else "expected 58 finite values|58"):
        measure(robot, truth[:-1], cand.q, cand.poses)


def test_plan_arguments() -> None:
    robot = iwr.Robot.default()
    cand = _candidates(robot, 40)
    with pytest.raises(ValueError, match="criterion"):
        iwr.plan_poses(robot, cand, 15, "O5")
    a = iwr.plan_poses(robot, cand, 12, "O1", seed=1)
    b = iwr.plan_poses(robot, cand, 12, "O1", seed=1)
    np.testing.assert_array_equal(a.indices, b.indices)


def test_ballbar_set_ups_are_not_planned_and_say_so(kind_case: Any) -> None:
    case = kind_case("ballbar", n_poses=12)
    with pytest.raises(ValueError, match="ballbar set-ups"):
        iwr.plan_poses(case.robot, case.data, 10)


@pytest.mark.parametrize("name", PLANNABLE)
def test_iwr_plan_writes_a_plan_of_the_robots_kind(name: str, kind_case: Any, tmp_path) -> None:
    kind_case(name, n_poses=1).robot.to_toml(tmp_path / "robot.toml")
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    proc = subprocess.run([sys.executable, "-m", "iwr", "plan", str(tmp_path / "robot.toml"),
                           "--n-candidates", "100", "--poses", "20", "--out",
                           str(tmp_path / "plan.csv")], capture_output=True, text=True,
                          cwd=tempfile.gettempdir(), env=environ, timeout=600)
    assert proc.returncode == 0, proc.stderr
    text = (tmp_path / "plan.csv").read_text()
    if name == "points":
        assert "reflector points measured by the tracker" in text and "docs/tracker.md" in text
    q, poses = iwr.read_plan(tmp_path / "plan.csv")
    assert q.shape == (20, 4) and poses.shape == (20, 6)


# -- plan files ---------------------------------------------------------------------------------


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
