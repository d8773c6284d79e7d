"""The double ballbar as a measurement kind (iwr.ballbar, docs/ballbar.md): one registration line
and its own package; its problem's exact Jacobian, noise-free recovery of what ballbar data
determine, the null space (what a bar cannot see) and the number of set-ups it needs."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from _ballbar import BAR_C, NOISE, ballbar_robot
from _ballbar import BARS as AB
from scipy.spatial.transform import Rotation

import iwr
from iwr import kinds
from iwr.ballbar import (
    BallbarMeasurements,
    BallbarNoise,
    BallbarProblem,
    BallbarSetup,
    ballbar_problem,
    read_ballbar,
    reading_std,
    write_ballbar,
)
from iwr.measurements import MeasurementFileError
from iwr.robot import RobotFileError

BARS = {**AB, "C": BAR_C}


def _robot(names: str = "AB", base: iwr.Robot | None = None) -> iwr.Robot:
    return ballbar_robot({n: BARS[n] for n in names}, base)


@pytest.fixture(scope="module")
def sim() -> tuple[iwr.Robot, BallbarMeasurements, np.ndarray]:
    robot = _robot()
    data, truth = iwr.simulate(robot, 160, seed=3)
    return robot, data, truth


def test_one_registration_line_reaches_the_kind(sim):
    robot, data, truth = sim
    assert "ballbar" in kinds.available()
    assert kinds.of(data).name == "ballbar" and kinds.for_robot(robot) is kinds.of(data)
    assert kinds.for_robot(iwr.Robot.default()).name == "pose"
    k = kinds.of(data)
    assert not k.determines_world_frame
    assert k.n_params(robot) == 58 + 14 == truth.size
    assert k.setup_parameter_names(robot)[:7] == [
        f"ballbar.A.{f}" for f in ("px", "py", "pz", "fx", "fy", "fz", "offset")]
    # the data of a pose robot are refused by name
    with pytest.raises(ValueError, match="ballbar data.*measures the platform pose"):
        k.check(iwr.Robot.default(), data)


def test_robot_toml_round_trip_and_errors(tmp_path):
    robot = _robot("ABC")
    robot.to_toml(tmp_path / "r.toml")
    text = (tmp_path / "r.toml").read_text()
    assert "[ballbar.A]" in text and "[ballbar.C]" in text
    back = iwr.Robot.from_toml(tmp_path / "r.toml")
    assert back == robot and back.instruments["ballbar"].names == ["A", "B", "C"]
    assert back.with_errors(np.zeros(58)).instruments == back.instruments
    assert kinds.for_robot(robot.with_instrument("ballbar", None)).name == "pose"

    def bad(extra: str, match: str) -> None:
        (tmp_path / "b.toml").write_text((tmp_path / "base.toml").read_text() + extra)
        with pytest.raises(RobotFileError, match=match):
            iwr.Robot.from_toml(tmp_path / "b.toml")

    iwr.Robot.default().to_toml(tmp_path / "base.toml")
    bad("\n[ballbar.A]\nplatform_ball = [0, 0, 1]\n", r"ballbar\.A\.fixed_ball: missing")
    bad("\n[ballbar.A]\nplatform_ball = [0, 0, 1]\nfixed_ball = [1, 2]\n",
        r"ballbar\.A\.fixed_ball: \[1, 2\]; expected 3 numbers")
    bad("\n[ballbar.A]\nplatform_ball = [0, 0, 1]\nfixed_ball = [1, 2, 3]\nlength = 2\n",
        r"ballbar\.A\.length: unknown key")
    bad("\n[ballbar.A]\nplatform_ball = [0, 0, 1]\nfixed_ball = [1, 2, 3]\nrange = [5, 1]\n",
        r"ballbar\.A\.range: \[5.0, 1.0\]; expected 0 <= shortest < longest")
    bad("\n[ballbar]\nplatform_ball = [0, 0, 1]\n", r"ballbar\.platform_ball: expected a set-up")
    bad("\n[points]\nx = 1\n", r"measurement kind 'points' is not described by a table")
    bad("\n[bar]\nx = 1\n", r"bar: unknown key")
    tracker = iwr.Robot.default().with_tracker((0, 0, 0, 0, 0, 0), reflectors=[(0, 0, 0)])
    with pytest.raises(ValueError, match="tracker and ballbar: a robot is measured by one"):
        tracker.with_instrument("ballbar", BARS)
    with pytest.raises(ValueError, match="tracker and ballbar: a robot is measured by one"):
        robot.with_tracker((0, 0, 0, 0, 0, 0), reflectors=[(0, 0, 0)])


def test_simulation_and_problem_agree(sim):
    """The simulation computes the readings from the sampled poses in NumPy, the problem by
    forward kinematics of the readings in C++: at the truth they agree."""
    robot, data, truth = sim
    problem, _ = ballbar_problem(robot, data)
    assert np.abs(problem.residuals(truth)).max() < 1e-8
    centre = problem.ball_vectors(truth)[1]
    assert np.all((centre >= 300) & (centre <= 700))  # within the bar's range
    assert sorted(set(data.setup)) == ["A", "B"] and (data.setup == "A").sum() == 80


@pytest.mark.parametrize("weighted", [False, True])
def test_jacobian_is_exact(sim, weighted):
    """The Jacobian against central differences of the residuals, column by column (steps of
    1e-2 mm and 1e-5 rad: the forward kinematics' convergence tolerance makes smaller ones
    noisy; the agreement is ~4e-8 of each column's size)."""
    robot, data, truth = sim
    problem, _ = ballbar_problem(robot, data.subset(range(40)))
    if weighted:
        problem = problem.with_weights(np.linspace(0.5, 2.0, problem.n_poses))
    x = truth + 1e-3 * np.random.default_rng(0).standard_normal(truth.size)
    r, jac = problem.residuals_and_jacobian(x)
    np.testing.assert_allclose(r, problem.residuals(x), atol=1e-12)
    for i in range(x.size):
        h = 1e-5 if problem.angle_parameters[i] else 1e-2
        e = np.zeros(x.size)
        e[i] = h
        fd = (problem.residuals(x + e) - problem.residuals(x - e)) / (2 * h)
        scale = max(np.abs(jac[:, i]).max(), 1e-3)
        assert np.abs(fd - jac[:, i]).max() < 1e-6 * scale, problem.parameter_names[i]
    # cost and cost_batch are the residuals' sum of squares
    costs = problem.cost_batch(np.stack([x, truth]))
    np.testing.assert_allclose(costs, [r @ r, problem.cost(truth)], rtol=1e-12)


def test_noise_free_recovery_to_a_micrometre_of_a_micrometre(sim):
    """Noise-free data, robot errors within the default bounds, unknown balls and offsets: the
    predicted readings and tool poses (modulo the gauge of docs/ballbar.md) on fresh poses agree
    with the truth to 1e-6 mm, from all parameters or from the base ones."""
    robot, data, truth = sim
    lo, hi = robot.default_bounds()
    assert np.all((truth[:58] >= lo) & (truth[:58] <= hi))
    fresh, _ = iwr.simulate(robot, 40, seed=11, x=truth)
    for active in (None, "base"):
        res = iwr.identify(robot, data, active=active)
        assert res.success, res.message
        readings = iwr.accuracy(robot, fresh, res.x)
        assert readings.calibrated.position.max() < 1e-6 < readings.nominal.position.max()
        tool = iwr.accuracy(robot, fresh, res.x, truth=truth, tool=(50.0, 0.0, 100.0))
        assert tool.calibrated.position.max() < 1e-6 < tool.nominal.position.max()
        assert tool.calibrated.orientation.max() < 1e-7
    # without the gauge removed the poses in {0} differ: what ballbars cannot see
    problem, _ = ballbar_problem(robot, fresh)
    raw = problem.platform_frames(res.x)[:, :3, 3] - problem.platform_frames(truth)[:, :3, 3]
    assert np.abs(raw).max() > 1e-3


def _nullity(robot: iwr.Robot, n_poses: int = 160, seed: int = 1) -> int:
    data, truth = iwr.simulate(robot, n_poses, seed=seed)
    ns = iwr.identifiability(robot, data, truth)
    return len(ns.left_out)


@pytest.mark.parametrize("names", ["A", "AB", "ABC"])
def test_one_set_up_makes_the_identifiable_part_full_rank(names):
    """What ballbar data cannot see, whatever the number of set-ups S >= 1: the pose data's own
    null directions (6 on the IWR), the rigid motions of the world frame the robot's model can
    make (3 translations and the turn about the first joint's axis: 4) and the rigid motions of
    the platform frame {5} (6); rank = 58 + 7 S - 16. One set-up suffices."""
    pose_nullity = 58 - iwr.identifiability(iwr.Robot.default(),
                                            iwr.simulate(iwr.Robot.default(), 80, seed=1)[0]).rank
    assert pose_nullity == 6
    robot = _robot(names)
    assert _nullity(robot) == pose_nullity + 4 + 6 == 16


def test_hexapod_needs_one_set_up_too():
    """A hexapod alone (no carriage; every pose-data parameter identifiable): the world frame's
    six rigid motions (its base joints move with it) and the platform frame's six."""
    hexa = iwr.Robot.hexapod()
    fixed = {"O": {"platform_ball": [0.0, 0.0, 0.0], "fixed_ball": [0.0, 0.0, 300.0],
                   "range": [100.0, 600.0]}}
    assert _nullity(hexa.with_instrument("ballbar", fixed), 120) == 12


def test_too_few_poses_lose_rank():
    """One reading per pose: fewer poses than identifiable parameters (49 for one set-up on the
    IWR) cannot give the full rank."""
    assert _nullity(_robot("A"), 40) == 65 - 40
    assert _nullity(_robot("A"), 60) == 16


def test_the_gauge_changes_no_reading(sim):
    """The documented null directions, as finite moves: a rigid motion of the platform frame
    (the platform joints and balls moved back), a turn of the world about the first joint's
    axis and a shift along it (joint1.dtheta, joint1.dd, the fixed balls moved with them)."""
    robot, data, truth = sim
    problem, _ = ballbar_problem(robot, data)
    before = problem.residuals(truth)
    setup = robot.instruments["ballbar"]
    x = truth.copy()
    h = Rotation.from_rotvec([0.01, -0.02, 0.015]).as_matrix()
    shift = np.array([1.0, -2.0, 0.5])
    joints = slice(16 + 18, 16 + 36)
    b = robot.platform_joints + x[joints].reshape(6, 3)
    x[joints] = (b @ h + shift - robot.platform_joints).ravel()  # b' = h^T b + shift...
    # ... and the balls alike: T' = T h_inv with h_inv(p) = h^T p + shift
    xs = x[58:].reshape(2, 7)
    p = np.array([BARS[n]["platform_ball"] for n in "AB"]) + xs[:, :3]
    xs[:, :3] = p @ h + shift - np.array([BARS[n]["platform_ball"] for n in "AB"])
    np.testing.assert_allclose(problem.residuals(x), before, atol=1e-8)
    x = truth.copy()
    phi, dz = 0.003, 0.7
    x[3] += phi  # joint1.dtheta
    x[2] += dz  # joint1.dd
    xs = x[58:].reshape(2, 7)
    f = np.array([BARS[n]["fixed_ball"] for n in "AB"]) + xs[:, 3:6]
    rz = Rotation.from_rotvec([0, 0, phi]).as_matrix()
    xs[:, 3:6] = f @ rz.T + [0, 0, dz] - np.array([BARS[n]["fixed_ball"] for n in "AB"])
    np.testing.assert_allclose(problem.residuals(x), before, atol=1e-8)
    assert setup.n_setups == 2


def test_noise_weighted_fit_and_its_uncertainty(sim):
    """With noise: the weighted LM's chi-square test passes, and the predicted standard
    deviation of a fresh reading is of the size of the actual error (the Monte-Carlo over 20
    seeds is benchmarks/ballbar_mc.py)."""
    robot, _, truth = sim
    data, _ = iwr.simulate(robot, 160, seed=21, x=truth, noise=NOISE)
    res = iwr.identify(robot, data, "lm", noise=NOISE, active="base")
    assert res.success and res.fit.fit_ok and res.fit.dof == 160 - int(res.active.sum())
    unc = iwr.uncertainty(robot, data, res.x, NOISE, active=res.active, weighted=True)
    assert unc.source == "weighted" and np.all(np.isfinite(unc.std[res.active]))
    fresh, _ = iwr.simulate(robot, 60, seed=22, x=truth)
    actual = np.sqrt(np.mean(ballbar_problem(robot, fresh)[0].residuals(res.x) ** 2))
    predicted = np.sqrt(np.mean(reading_std(robot, fresh, res.x, unc) ** 2))
    assert 0.5 < actual / predicted < 2.0
    # a wrong noise model (ten times too small) fails the fit test
    small = (NOISE[0], BallbarNoise(1e-4))
    tiny = (iwr.Noise(legs=2e-4, joint_lengths=5e-4, joint_angles=5e-7), small[1])
    bad = iwr.identify(robot, data, "lm", noise=tiny, active="base")
    assert not bad.success and "chi2 = " in bad.message


def test_every_method_takes_the_problem(sim):
    """DE (on cost_batch), CRS2 and BOBYQA reach the ballbar problem through iwr.identify."""
    robot, data, truth = sim
    for method, opts in (("de", {"generations": 3, "population_size": 20, "seed": 1}),
                         ("crs2", {"max_evaluations": 300, "seed": 1}),
                         ("bobyqa", {"max_evaluations": 300})):
        res = iwr.identify(robot, data, method, **opts)
        assert res.method == method and np.isfinite(res.fun) and res.x.size == truth.size
        assert res.fun <= ballbar_problem(robot, data)[0].cost(np.zeros(truth.size)) + 1e-9
    # the efficient estimator: tests/test_ballbar_estimator.py


def test_file_round_trip_and_errors(sim, tmp_path):
    robot, data, _ = sim
    path = tmp_path / "bar.csv"
    write_ballbar(path, data)
    back = kinds.for_robot(robot).read(path, robot)
    np.testing.assert_array_equal(back.distance, data.distance)
    np.testing.assert_array_equal(back.q, data.q)
    assert list(back.setup) == list(data.setup) and back.where(2).endswith("line 8")
    k = kinds.of(back)
    assert k.fingerprint(robot, back) == k.fingerprint(robot, data)
    assert k.fingerprint(robot, k.subset(back, range(1, len(back)))) != k.fingerprint(robot, back)
    lines = path.read_text().splitlines()
    header = lines[4]

    def refused(rows: list[str], match: str) -> None:
        bad = tmp_path / "bad.csv"
        bad.write_text("\n".join(rows) + "\n")
        with pytest.raises(MeasurementFileError, match=match):
            read_ballbar(bad, robot.joint_types, robot.instruments["ballbar"])

    row = lines[5].split(",")
    refused([header, ",".join(row[:-2] + ["Z", row[-1]])],
            r"bad.csv, .*line 2, column setup: 'Z' is not one of the robot's \[ballbar\] "
            r"set-ups \(A, B\)")
    refused([header, ",".join(row[:-1] + ["x"])], r"line 2, column distance_mm: 'x' is not a "
            "number")
    refused([header, ",".join(row[:-1] + ["-3"])], r"line 2, column distance_mm: -3.0; a bar")
    refused([header, ",".join(row[:3] + ["1e9"] + row[4:])], r"line 2, column q4_rad")
    refused([header.replace("q3_rad", "q3_mm"), lines[5]], r"line 1, column 3: 'q3_mm'")
    refused([header + ",extra", lines[5] + ",1"], r"unknown column\(s\) extra")
    with pytest.raises(TypeError, match="--readings: not an option of ballbar data"):
        kinds.of(data).read(path, robot, readings="x.csv")


@pytest.mark.parametrize("factor, units", [(1e-3, "metres"), (1 / 25.4, "inches"),
                                           (10.0, None)])
def test_readings_in_other_units_are_refused_by_name(sim, tmp_path, factor, units):
    """A bar's readings 1000 times too small (a file in metres) reached the identification,
    which reported the leg readings as having no forward kinematics; the kind's check compares
    them with the distances the nominal robot predicts and names the column and the likely
    unit. The right file passes the same check."""
    robot, data, _ = sim
    kind = kinds.for_robot(robot)
    path = tmp_path / "bar.csv"
    write_ballbar(path, data)
    kind.check(robot, kind.read(path, robot))  # mm: accepted
    scaled = BallbarMeasurements(data.q, data.legs, data.setup, data.distance * factor,
                                 joint_types=robot.joint_types)
    write_ballbar(path, scaled)
    hint = f"a file in {units}\\? " if units else r"mm\): the readings are in mm"
    with pytest.raises(ValueError, match=r"bar.csv: column distance_mm: the bar's readings are "
                       rf"{factor:.3g} times the distances the nominal robot predicts.*{hint}"):
        kind.check(robot, kind.read(path, robot))
    with pytest.raises(ValueError, match="column distance_mm"):
        iwr.calibrate(robot, kind.read(path, robot), method="lm", progress=False)


def test_data_type_checks():
    with pytest.raises(ValueError, match="distance: pose 1 is 0.0"):
        BallbarMeasurements(np.zeros((2, 4)), np.zeros((2, 6)), ["A", "A"], [1.0, 0.0])
    with pytest.raises(ValueError, match="setup: 1 names; expected 2"):
        BallbarMeasurements(np.zeros((2, 4)), np.zeros((2, 6)), ["A"], [1.0, 2.0])
    m = BallbarMeasurements(np.zeros((2, 4)), np.zeros((2, 6)), ["A", "Q"], [1.0, 2.0])
    with pytest.raises(ValueError, match="pose 1: set-up 'Q' is not one of"):
        BallbarProblem(iwr.Robot.default(), BallbarSetup(BARS), m)
    with pytest.raises(ValueError, match="no measurements"):
        m.subset([])
    assert math.isnan(iwr.accuracy(_robot(), iwr.simulate(_robot(), 4, seed=0)[0],
                                   np.zeros(72)).nominal.orientation[0])


def test_docs_list_the_kind():
    text = (Path(__file__).resolve().parents[1] / "docs" / "ballbar.md").read_text()
    assert "[ballbar.A]" in text and "distance_mm" in text


@pytest.mark.slow
def test_monte_carlo_actual_accuracy_is_the_predicted_one():
    """benchmarks/ballbar_mc.py, 20 seeds: the actual RMS error of fresh readings within 10 % of
    the predicted one (docs/ballbar.md: 1.025 measured), every fit passing its chi-square test."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "ballbar_mc.py"
    spec = importlib.util.spec_from_file_location("ballbar_mc", path)
    assert spec is not None and spec.loader is not None
    mc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mc)
    out = mc.run(200, 20, "AB")
    assert 0.9 < out["ratio"] < 1.1, out["ratio"]
    assert 0.8 < out["maha"].mean() < 1.25
    assert out["chi2_p"].min() > 1e-3


def test_iwr_simulate_then_calibrate_a_ballbar_robot(tmp_path):
    """`iwr simulate --robot` with a ballbar robot and the default (realistic) noise: the leg
    and joint readings' noise with the bar's default (it refused the pose noise of
    Noise.realistic()); its data go through `iwr calibrate`."""
    import subprocess
    import sys

    robot = iwr.Robot.default().with_instrument("ballbar", {
        "A": {"platform_ball": [0, 0, -60], "fixed_ball": [800, -800, 1500], "range": [300, 700]},
        "B": {"platform_ball": [100, 50, -60], "fixed_ball": [900, -200, 2400],
              "range": [300, 700]}})
    robot.to_toml(tmp_path / "bb.toml")

    def run(*args):
        return subprocess.run([sys.executable, "-m", "iwr", *args], cwd=tmp_path,
                              capture_output=True, text=True, timeout=900)

    sim = run("simulate", "--robot", "bb.toml", "--poses", "120", "--seed", "3", "--out", "s")
    assert sim.returncode == 0, sim.stdout + sim.stderr
    assert "legs 0.002, joint_lengths 0.005, joint_angles 5e-06, ballbar distance 0.001" \
        in sim.stdout, sim.stdout
    cal = run("calibrate", "s/robot.toml", "s/measurements.csv", "--method", "lm", "--out", "c",
              "--no-plots", "--no-progress")
    assert cal.returncode == 0, cal.stdout + cal.stderr
    assert (tmp_path / "c" / "report.html").is_file()
