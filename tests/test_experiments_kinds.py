"""iwr compare and iwr study on every kind of data (issue 21, item 3): the experiment harness asks
the robot's kind for its noise, its actual set-up and its yardsticks; the figures on tracker data
are gauge-invariant; the noise-weighted objective on tracker points."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import iwr
from iwr import kinds
from iwr.analysis.identifiability import parameter_error_on
from iwr.cli import main as cli_main
from iwr.experiments.harness import (
    Cell,
    Scenario,
    canonical,
    evaluate,
    min_poses,
    noise_at,
    robot_hash,
)
from iwr.tracker import TrackerNoise
from iwr.tracker.analysis import null_space
from iwr.tracker.data import TrackerMeasurements
from iwr.tracker.problem import TrackerProblem, point_covariances

REPO = Path(__file__).resolve().parents[1]
TRACKER_TOML = REPO / "examples" / "iwr_tracker.toml"
REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, -150.0, 300.0, math.pi / 2, 0.01, -0.02)
READINGS = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)


@pytest.fixture(scope="module")
def robots(kind_case: Any) -> Any:
    """The robot of a kind by name (conftest's KindCase robots)."""
    return lambda name: kind_case(name, n_poses=1).robot


def _cell(robot: iwr.Robot, method: str, n_poses: int, noise: Any) -> Cell:
    return Cell(method, canonical({}), None, n_poses, noise, 0, 0, 0, 12, robot_hash(robot))


def test_a_scenario_simulates_the_robots_kind(kind):
    robot = kind.robot
    k = kinds.for_robot(robot)
    n_poses = max(14, min_poses(robot))
    sc = Scenario(n_poses, iwr.Noise(), draw=1, validation_poses=5).build(robot)
    assert kinds.of(sc.data) is k and kinds.of(sc.validation) is k
    n = k.n_params(robot)
    assert sc.truth.shape == sc.x0.shape == (n,)
    # The actual set-up is drawn within the set-up's default bounds, not the nominal one.
    extra = sc.truth[robot.n_params:]
    assert extra.size == len(k.setup_parameter_names(robot))
    if extra.size:
        setup = robot.tracker or next(iter(robot.instruments.values()))  # the ballbar's
        lo, hi = setup.default_bounds()
        assert np.all((lo <= extra) & (extra <= hi)) and np.any(extra != 0)
    # The same scenario twice: the same data.
    again = Scenario(n_poses, iwr.Noise(), draw=1, validation_poses=5).build(robot)
    assert np.array_equal(again.truth, sc.truth) and np.array_equal(again.data.q, sc.data.q)


def test_min_poses_counts_the_kinds_readings(kind):
    """Six independent readings a pose for the platform pose or a probe, three per reflector,
    one for a ballbar's distance."""
    name, robot = kind.name, kind.robot
    need = min_poses(robot)
    per_pose = {"pose": 6, "points": 9, "probe": 6, "ballbar": 1}[name]
    data, x = iwr.simulate(robot, 80, seed=3)
    problem, _ = kinds.of(data).problem(robot, data, x0=x)
    jac = problem.jacobian(x)
    s = np.linalg.svd(jac / np.linalg.norm(jac, axis=0), compute_uv=False)
    # the rank across the gap of the scaled singular values (the null directions of a ballbar's
    # data sit at ~1e-14, the weakest identifiable direction at ~1e-4: NumPy's default
    # threshold, 80 x eps, counted two of them)
    rank = int(np.sum(s > 1e-9 * s[0]))
    assert need == math.ceil(rank / per_pose)


def test_noise_free_lm_recovers_what_the_data_see(kind):
    """Noise-free data, LM from the kind's start: the validation readings, the tool pose (modulo
    the gauge for tracker data) and the parameter error modulo the null directions all vanish."""
    robot = kind.robot
    row = evaluate(_cell(robot, "lm", max(30, min_poses(robot) + 10), 0.0), robot,
                   details=True)
    assert row["status"] == "ok", row["message"]
    assert row["at_floor"] and row["success"]
    assert row["val_rms"] < 1e-6 and row["val_rms_nominal"] > 0.1
    assert row["tool_position_rms"] < 1e-5 and row["tool_position_rms_nominal"] > 0.1
    # the tool's pose, orientation included (a ballbar's "tool" figure was its distance residual)
    assert row["tool_orientation_rms"] < 1e-8
    assert row["param_error_length"] < 1e-5 and row["param_error_angle"] < 1e-8
    n = kinds.for_robot(robot).n_params(robot)
    assert len(row["x"]) == len(row["truth"]) == len(row["unidentifiable"]) == n


def test_the_experiments_before_on_tracker_data_is_the_jobs(robots):
    """compare's and study's nominal figures on tracker points are iwr.calibrate's "before": the
    nominal robot in the registration guess the identification started from, not a guess fitted
    to the validation poses (which flattered it: tool 4.86 mm against 5.11 on 100 poses)."""
    from iwr.tracker.analysis import tool_pose_errors
    from iwr.tracker.start import registration_guess

    robot = robots("points")
    cell = _cell(robot, "lm", 30, 0.02)
    row = evaluate(cell, robot)
    assert row["status"] == "ok", row["message"]
    sc = cell.scenario_problem().build(robot)
    val = sc.validation
    before = np.concatenate([np.zeros(robot.n_params), registration_guess(robot, sc.data).x_setup])
    residuals = TrackerProblem(robot, robot.tracker, val).residuals(before)
    assert row["val_rms_nominal"] == pytest.approx(np.sqrt(np.mean(residuals**2)), rel=1e-9)
    tool = tool_pose_errors(robot, robot.tracker, before, sc.truth, val.q, val.legs).position
    assert row["tool_position_rms_nominal"] == pytest.approx(np.sqrt(np.mean(tool**2)), rel=1e-9)
    # The job's own "before" on the same poses (iwr.calibrate: accuracy with the kind's start).
    kind = kinds.for_robot(robot)
    job = iwr.accuracy(robot, val, row["x"], truth=sc.truth, start=kind.start(robot, sc.data))
    assert row["tool_position_rms_nominal"] == pytest.approx(
        np.sqrt(np.mean(job.nominal.position**2)), rel=1e-9)


def test_the_parameter_error_on_tracker_data_ignores_the_gauge(robots):
    """Moving x along a null direction of the point objective (the registration and {5} absorb
    a rigid motion) leaves its parameter error unchanged; an identifiable change does not."""
    robot = robots("points")
    m, truth = iwr.simulate(robot, 20, seed=5)
    problem = TrackerProblem(robot, robot.tracker, m)
    ns = null_space(problem, truth)
    assert ns.vectors.shape[1] >= 6
    ang = kinds.for_robot(robot).angle_parameters(robot)
    rng = np.random.default_rng(0)
    visible = 1e-3 * rng.standard_normal(truth.size) * np.where(ang, 1e-3, 1.0)
    x = truth + visible
    base = parameter_error_on(problem, x, truth, ang)
    along = ns.vectors @ rng.standard_normal(ns.vectors.shape[1])
    moved = parameter_error_on(problem, x + 1e-2 * along / np.sqrt(np.mean(along**2)), truth,
                               ang)
    assert base.converged and moved.converged
    assert base.rms_length > 1e-4
    # The raw error grows tenfold; the error the points see stays (to second order).
    assert moved.raw_rms_length > 10 * base.raw_rms_length
    assert moved.rms_length == pytest.approx(base.rms_length, rel=1e-3)
    assert moved.rms_angle == pytest.approx(base.rms_angle, rel=1e-3)


def test_compare_writes_the_report_for_every_kind(kind, tmp_path):
    name, robot = kind.name, kind.robot
    comp = iwr.compare_methods(robot, n_poses=max(12, min_poses(robot) + 6), seeds=[0],
                               methods=["lm", "efficient"],
                               budget=200, start="near", out=tmp_path, n_validation=6,
                               progress=False)
    assert {r["status"] for r in comp.runs} == {"ok"}
    k = kinds.for_robot(robot)
    assert comp.settings["kind"]["name"] == name
    assert comp.settings["n_params"] == k.n_params(robot)
    md = (tmp_path / "report.md").read_text()
    assert f"measured in {k.frame} ({name} data)" in md
    assert k.experiment_text["readings"] in md
    assert "tool position RMS (mm)" in md
    # The noise in words, each instrument's once (a tracker's said {'legs': ..., 'readings':
    # {'legs': ...}, ...}: an outside check).
    said = md.split("poses per identification, noise ", 1)[1].split(" (mm, rad)", 1)[0]
    assert "{" not in said and said.count("legs ") == 1, said
    data = json.loads((tmp_path / "results.json").read_text())
    assert len(data["parameter_names"]) == k.n_params(robot)
    assert all((tmp_path / f).is_file() for f in ("report.html", "runs.csv", "summary.csv"))


def test_the_bad_start_on_tracker_data_is_a_failed_run_not_an_abort(tmp_path):
    """From the 'bad' start no pose of the tracker robot has forward kinematics: the efficient
    estimator cannot start there (a failed run in the report), LM runs (and fails to converge)."""
    robot = iwr.Robot.from_toml(TRACKER_TOML)
    comp = iwr.compare_methods(robot, n_poses=12, seeds=[0], methods=["lm", "efficient"],
                               budget=100, start="both", out=None, n_validation=6, progress=False)
    by = {(r["scenario"], r["method"]): r for r in comp.runs}
    assert by["near", "efficient"]["status"] == "ok"
    bad = by["bad", "efficient"]
    assert bad["status"] == "failed" and not bad["success"] and math.isnan(bad["cost"])
    assert "forward kinematics" in bad["message"]
    summary = {(s["scenario"], s["method"]): s for s in comp.summary}
    assert summary["bad", "efficient"]["failed"] == 1
    with pytest.raises(ValueError, match="method 'efficient', scenario bad"):
        iwr.compare_methods(robot, n_poses=12, seeds=[0], methods=["efficient"], budget=100,
                            start="bad", out=None, n_validation=6, progress=False)


def test_a_run_from_the_bad_start_that_reaches_the_floor_is_a_success_without_a_before():
    """The 'bad' scenario's nominal robot is hundreds of mm from its truth: no registration guess
    (the kind's start) exists on its data, so there is no "before". A run that reaches the floor
    from the bad start (LM, seed 1: cost 0.213 against a floor of 0.233) is a success with its
    calibrated figures, its nominal ones nan and a note saying why; the cell failed on the missing
    guess (a RegistrationError from the validation), however good the identification."""
    robot = iwr.Robot.from_toml(TRACKER_TOML)
    comp = iwr.compare_methods(robot, seeds=[1], methods=["lm"], start="bad", out=None,
                               n_validation=20, progress=False)
    (run,) = comp.runs
    assert run["status"] == "ok" and run["success"] and run["cost"] < run["noise_floor"]
    assert run["val_rms"] < 0.01 and run["tool_position_rms"] < 0.01  # mm: at the noise
    assert math.isnan(run["val_rms_nominal"]) and math.isnan(run["tool_position_rms_nominal"])
    assert "nominal: no start of the kind's own: RegistrationError" in run["notes"]


def test_study_on_tracker_data_says_what_it_measures(tmp_path):
    robot = iwr.Robot.from_toml(TRACKER_TOML)
    res = iwr.study(methods="lm", poses=[10], noise=[0.0, 0.02], draws=1, seeds=1,
                    out=tmp_path, robot=robot, validation_poses=6, scheduler="synchronous",
                    progress=False)
    assert res.failed == 0 and len(res.rows) == 2
    noisy = next(r for r in res.rows if r["noise"] == 0.02)
    clean = next(r for r in res.rows if r["noise"] == 0.0)
    assert clean["tool_position_rms"] < 1e-5 < noisy["tool_position_rms"] < 1.0
    meta = json.loads((tmp_path / "study.json").read_text())
    assert meta["kind"]["name"] == "points"
    summary = (tmp_path / "summary.md").read_text()
    assert "Validation point ({T}) RMS error (mm)" in summary
    assert "Tool position RMS error modulo the gauge (mm)" in summary
    assert "TrackerNoise.leica()" in summary
    # A level scales every instrument's noise: no millimetres (they read as the tracker's sd).
    assert "noise levels [0.0, 0.02]," in summary and "0.02] mm" not in summary


def test_a_noise_level_scales_the_instruments_noise(robots):
    k = kinds.for_robot(robots("points"))
    readings, tracker = k.experiment_noise(robots("points"), noise_at(0.01))
    assert readings.position == readings.orientation == 0 and readings.legs == pytest.approx(0.001)
    leica = TrackerNoise.leica()
    assert tracker.transverse_per_m == pytest.approx(0.5 * leica.transverse_per_m)
    pair = (READINGS, leica)
    assert k.experiment_noise(robots("points"), pair) is pair
    pose = kinds.for_robot(robots("pose"))
    assert pose.experiment_noise(robots("pose"), READINGS) is READINGS
    # the ballbar's: its 1 um at the realistic level (every noisy study run was refused before)
    bar = kinds.for_robot(robots("ballbar"))
    readings, reading = bar.experiment_noise(robots("ballbar"), noise_at(0.01))
    assert readings.position == readings.orientation == 0 and readings.legs == pytest.approx(0.001)
    assert reading.distance == pytest.approx(0.0005)
    data, _ = bar.simulate(robots("ballbar"), 10, seed=1, noise=(readings, reading))
    assert len(data) == 10


@pytest.mark.parametrize("name, instrument", [("ballbar", "the bar"),
                                              ("points", "the tracker")])
def test_noisy_readings_without_a_level_do_not_make_the_instrument_exact(
        robots, tmp_path, capsys, name, instrument):
    """``iwr compare --noise legs=...`` on ballbar data made the bar exact (no bar noise) without
    a word, on tracker data the tracker: ``position`` is the instrument's noise level there, so
    the experiments refuse noisy readings without it, naming the key and the instrument; the
    command line's --noise gives the instrument its realistic noise then (as iwr simulate and
    iwr calibrate, tests/test_noise_option.py); with it the instrument has its noise, named after
    it in the settings."""
    robot = robots(name)
    k = kinds.for_robot(robot)
    with pytest.raises(ValueError, match=f"without position.*{instrument} exact"):
        k.experiment_noise(robot, iwr.Noise(legs=0.002, joint_lengths=0.005))
    assert k.experiment_noise(robot, iwr.Noise())[1].is_zero  # noise-free: both exact
    robot.to_toml(tmp_path / "robot.toml")
    args = ["compare", "--robot", str(tmp_path / "robot.toml"), "--poses", "70", "--seeds", "0",
            "--methods", "lm", "--budget", "60", "--start", "near", "--validation-poses", "5",
            "--no-progress", "-o", str(tmp_path / "c")]
    assert cli_main([*args, "--noise", "legs=0.002,position=0.01"]) == 0, capsys.readouterr().err
    noise = json.loads((tmp_path / "c" / "results.json").read_text())["settings"]["noise"]
    model = noise["ballbar" if name == "ballbar" else "tracker"]
    if name == "ballbar":
        assert model == {"distance": pytest.approx(0.0005)}
    else:
        assert model["transverse"] == pytest.approx(0.5 * TrackerNoise.leica().transverse)
    assert noise["readings"]["legs"] == 0.002


def test_cli_compare_and_study_on_the_tracker_example(tmp_path, capsys):
    code = cli_main(["compare", "--robot", str(TRACKER_TOML), "--poses", "10", "--seeds", "0",
                     "--methods", "lm,bobyqa", "--budget", "60", "--start", "near",
                     "--validation-poses", "5", "--no-progress", "-o", str(tmp_path / "c")])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "tool position RMS (mm)" in out.out and (tmp_path / "c" / "report.html").is_file()
    code = cli_main(["study", "--robot", str(TRACKER_TOML), "--poses", "10", "--noise", "0.02",
                     "--draws", "1", "--seeds", "1", "--validation-poses", "5",
                     "--scheduler", "synchronous", "--out", str(tmp_path / "s"), "--no-progress"])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert (tmp_path / "s" / "report.html").is_file()


# -- the noise-weighted objective on tracker data --------------------------------------------


def test_point_covariances_match_finite_differences(robots):
    """The readings' noise propagated into the predicted points: the exact derivative (loop
    closure) against central differences of forward kinematics with perturbed readings."""
    robot = robots("points")
    m, _ = iwr.simulate(robot, 6, seed=1, noise=(READINGS, TrackerNoise.leica()))
    problem = TrackerProblem(robot, robot.tracker, m)
    x = np.zeros(problem.n_params)
    cov = point_covariances(problem, x, READINGS, None)
    nj, h = robot.n_joints, 1e-5
    sigma = np.concatenate([np.where([c == "P" for c in robot.joint_types], READINGS.joint_lengths,
                                     READINGS.joint_angles), np.full(6, READINGS.legs)])
    g = np.zeros((len(m), cov.shape[1], nj + 6))
    for j in range(nj + 6):
        pts = []
        for s in (1.0, -1.0):
            q, legs = m.q.copy(), m.legs.copy()
            if j < nj:
                q[:, j] += s * h
            else:
                legs[:, j - nj] += s * h
            moved = TrackerMeasurements(q, legs, points=m.points, joint_types=robot.joint_types)
            pts.append(TrackerProblem(robot, robot.tracker, moved).predicted_points(x)
                       .reshape(len(m), -1))
        g[:, :, j] = (pts[0] - pts[1]) / (2 * h)
    expected = np.einsum("kip,p,kjp->kij", g, sigma**2, g)
    assert np.max(np.abs(cov - expected)) < 1e-6 * np.max(np.abs(expected))
    # The tracker's part: its covariance at each measured point, block by block.
    both = point_covariances(problem, x, None, TrackerNoise.leica())
    assert np.allclose(both[:, :3, :3], TrackerNoise.leica().covariance(m.points[:, 0]))


def test_weighted_lm_on_points_is_generalised_least_squares(robots):
    robot = robots("points")
    noise = (READINGS, TrackerNoise.leica())
    m, truth = iwr.simulate(robot, 30, seed=2, noise=noise)
    res = iwr.identify(robot, m, "lm", noise=noise)
    plain = iwr.identify(robot, m, "lm")
    assert res.success and res.settings["objective"]["weighted"]
    # fun is the chi-square statistic, about the number of readings less the parameters seen.
    problem, _ = kinds.of(m).problem(robot, m, x0=truth)
    dof = problem.n_observations - null_space(problem, truth).rank
    assert 0.5 * dof < res.fun < 1.5 * dof
    assert res.cost_eq10 == pytest.approx(problem.cost(res.x))
    assert res.cost_eq10 >= plain.fun * (1 - 1e-9)  # the unweighted optimum is unweighted LM's
    # Unweighted LM with the noise model: the same minimum as without, now with a fit test.
    tested = iwr.identify(robot, m, "lm", noise=noise, weighted=False)
    assert tested.fun == pytest.approx(plain.fun, rel=1e-9)
    assert tested.fit.dof == res.fit.dof > 0
    assert plain.fit.dof == 0 and np.isnan(plain.fit.statistic)


def test_a_weighted_tracker_problem_round_trips_or_refuses(tmp_path, robots):
    noise = (READINGS, TrackerNoise.leica())
    robot = robots("points")
    m, _ = iwr.simulate(robot, 12, seed=1, noise=noise)
    problem, _ = kinds.of(m).problem(robot, m)
    weighted = TrackerProblem(robot, robot.tracker, m, noise=noise)
    assert weighted.weighted and not problem.weighted
    # The problem file carries the weighting (issue 21): saved, it loads back weighted.
    weighted.save(tmp_path / "p.iwrp")
    back = TrackerProblem.load(tmp_path / "p.iwrp")
    assert back.weighted
    np.testing.assert_array_equal(back.whitening, weighted.whitening)
    with pytest.raises(ValueError, match="needs the tracker's noise"):
        iwr.identify(robot, m, "lm", noise=READINGS)
