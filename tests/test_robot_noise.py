"""The instruments' noise model in the robot TOML ([noise], [tracker.noise]): read back exactly,
every bad value named, and used by ``iwr calibrate`` and ``iwr simulate`` when ``--noise`` is not
given (``--noise`` overrides it); run as a user runs them."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

import iwr
from iwr.tracker import TrackerNoise

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
READINGS = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
TRACKER = TrackerNoise(distance=0.004, distance_per_m=0.0002, transverse=0.006,
                       transverse_per_m=0.0025, orientation=1e-4)


def run(*args: str):
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    return subprocess.run([sys.executable, "-m", "iwr", *args], capture_output=True, text=True,
                          cwd=tempfile.gettempdir(), env=environ, timeout=600)


def tracker_robot() -> iwr.Robot:
    return iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)


def test_without_noise_tables_there_is_no_noise_model(tmp_path):
    iwr.Robot.default().to_toml(tmp_path / "r.toml")
    assert "[noise]" not in (tmp_path / "r.toml").read_text()
    back = iwr.Robot.from_toml(tmp_path / "r.toml")
    assert back.noise is None and back.tracker_noise is None and back.noise_model is None


def test_noise_round_trip(tmp_path):
    noise = iwr.Noise(legs=0.0021, joint_lengths=0.0049, joint_angles=4.9e-6, position=0.0199,
                      orientation=2.1e-5)
    robot = iwr.Robot.default().with_noise(noise)
    robot.to_toml(tmp_path / "r.toml")
    text = (tmp_path / "r.toml").read_text()
    assert "\n[noise]" in text and "legs = 0.0021" in text.splitlines()
    back = iwr.Robot.from_toml(tmp_path / "r.toml")
    assert back.noise == noise and back.noise_model == noise and back == robot
    assert back != iwr.Robot.default()  # the noise model is part of the description
    # A calibrated robot keeps the bench's noise model.
    assert robot.with_errors([0.0] * robot.n_params).noise == noise


def test_tracker_noise_round_trip(tmp_path):
    robot = tracker_robot().with_noise(READINGS, TRACKER)
    robot.to_toml(tmp_path / "r.toml")
    text = (tmp_path / "r.toml").read_text()
    assert "\n[tracker.noise]" in text and "transverse_per_m = 0.0025" in text.splitlines()
    back = iwr.Robot.from_toml(tmp_path / "r.toml")
    assert back.noise == READINGS and back.tracker_noise == TRACKER
    assert back.noise_model == (READINGS, TRACKER) and back == robot
    assert back.tracker == robot.tracker
    # The tracker's noise goes with the tracker.
    assert back.with_tracker(None).tracker_noise is None
    assert back.with_tracker(None).noise_model == READINGS


@pytest.mark.parametrize("table, message", [
    ("[noise]\nleg = 0.002", "noise.leg: unknown key; known: legs, joint_lengths, joint_angles"),
    ("[noise]\nlegs = -0.002", "noise.legs: -0.002 is negative"),
    ("[noise]\njoint_angles = -1e-6", "noise.joint_angles: -1e-06 is negative; a standard "
     "deviation (rad)"),
    ('[noise]\nlegs = "0.002"', "noise.legs: expected a number, got str '0.002'"),
    ("[noise]\nlegs = true", "noise.legs: expected a number, got bool"),
    ("[noise]\nposition = nan", "noise.position: nan is not a finite double"),
    ("[noise]\norientation = 2e9", "noise.orientation: 2000000000.0 rad is beyond any robot"),
    ("noise = 0.002", "noise: expected a table of standard deviations"),
    # Issue 26: 1e-200 ended with chi2 = inf (1 / sigma^2 overflows).
    ("[noise]\nlegs = 1e-200", "noise.legs: 1e-200 mm is below any instrument's noise; a "
     "standard deviation is 0 (none) or at least 1e-09"),
])
def test_bad_noise_values_are_named(tmp_path, table, message):
    iwr.Robot.default().to_toml(tmp_path / "r.toml")
    path = tmp_path / "r.toml"
    text = path.read_text()
    # A table goes at the end; a bare key before the first table.
    path.write_text(text + "\n" + table + "\n" if table.startswith("[")
                    else text.replace("[units]", table + "\n\n[units]", 1))
    with pytest.raises(iwr.RobotFileError) as info:
        iwr.Robot.from_toml(path)
    assert str(info.value).startswith(f"{path}: ")
    assert message in str(info.value)


@pytest.mark.parametrize("table, message", [
    ("[tracker.noise]\ndistance = -0.005", "tracker.noise.distance: -0.005 is negative"),
    ("[tracker.noise]\ndistance_per_metre = 0.0002",
     "tracker.noise.distance_per_metre: unknown key; known: distance, distance_per_m, "
     "transverse, transverse_per_m, orientation"),
    ("[tracker.noise]\ntransverse = 'x'", "tracker.noise.transverse: expected a number"),
    # Issue 26: 5e-324 gave "whitening: entry 0 is inf".
    ("[tracker.noise]\ndistance = 5e-324", "tracker.noise.distance: 5e-324 mm is below any "
     "instrument's noise"),
    ("[noise]\nlegs = 0.002\nposition = 0.02", "noise: position 0.02 mm, orientation 0.0 rad"),
])
def test_bad_tracker_noise_values_are_named(tmp_path, table, message):
    path = tmp_path / "r.toml"
    tracker_robot().with_noise(READINGS, TRACKER).to_toml(path)
    text = path.read_text()
    head = table.split("\n")[0]
    start = text.index(head)
    end = text.find("\n\n", start)
    # Replace the written table by the bad one.
    path.write_text(text[:start] + table + ("\n" + text[end:] if end >= 0 else "\n"))
    with pytest.raises(iwr.RobotFileError) as info:
        iwr.Robot.from_toml(path)
    assert str(info.value).startswith(f"{path}: ") and message in str(info.value)


@pytest.mark.parametrize("drop", ["[noise]", "[tracker.noise]"])
def test_a_tracker_robot_needs_both_noise_tables(tmp_path, drop):
    path = tmp_path / "r.toml"
    tracker_robot().with_noise(READINGS, TRACKER).to_toml(path)
    text = path.read_text()
    start = text.index("\n" + drop)
    end = text.find("\n\n", start + 1)
    path.write_text(text[:start] + (text[end:] if end >= 0 else "\n"))
    with pytest.raises(iwr.RobotFileError, match=r"\[tracker.noise\]|\[noise\]") as info:
        iwr.Robot.from_toml(path)
    assert f"{drop}: missing" in str(info.value)


def test_noise_arguments_are_checked():
    with pytest.raises(TypeError, match="noise: expected an iwr.Noise"):
        iwr.Robot.default().with_noise(0.002)
    with pytest.raises(ValueError, match="tracker_noise: only for a robot with a tracker"):
        iwr.Robot.default().with_noise(READINGS, TRACKER)
    with pytest.raises(ValueError, match="position = orientation = 0"):
        tracker_robot().with_noise(iwr.Noise.realistic(), TRACKER)
    with pytest.raises(ValueError, match="position = orientation = 0"):
        iwr.Robot.default().with_noise(iwr.Noise.realistic()).with_tracker(
            registration=REGISTRATION, reflectors=REFLECTORS)


# -- the command line ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def leg_files(tmp_path_factory) -> Path:
    """Pose data simulated with the noise model of the robot file (no --noise)."""
    out = tmp_path_factory.mktemp("legs")
    iwr.Robot.default().with_noise(iwr.Noise.realistic()).to_toml(out / "bench.toml")
    proc = run("simulate", "--robot", str(out / "bench.toml"), "--poses", "40", "--seed", "5",
               "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    assert f"from {out / 'bench.toml'} [noise]" in proc.stdout
    return out


def test_simulate_uses_the_file_noise_and_noise_overrides_it(leg_files, tmp_path):
    truth = json.loads((leg_files / "true_errors.json").read_text())
    assert truth["noise"] == dataclasses.asdict(iwr.Noise.realistic())
    assert iwr.Robot.from_toml(leg_files / "robot.toml").noise == iwr.Noise.realistic()
    proc = run("simulate", "--robot", str(leg_files / "bench.toml"), "--poses", "5",
               "--noise", "none", "-o", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "true_errors.json").read_text())["noise"] == \
        dataclasses.asdict(iwr.Noise())


def test_calibrate_uses_the_file_noise(leg_files, tmp_path):
    proc = run("calibrate", str(leg_files / "robot.toml"), str(leg_files / "measurements.csv"),
               "-o", str(tmp_path), "--no-plots", "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    source = f"{leg_files / 'robot.toml'} [noise]"
    assert f"(from {source}; --noise overrides it)" in proc.stdout
    assert "method: the efficient estimator" in proc.stdout
    result = iwr.load_result(tmp_path / "result.json")
    assert result["method"] == "efficient"
    assert source in (tmp_path / "report.html").read_text()  # its settings table


@pytest.mark.parametrize("spec, method", [("none", "lm"), ("legs=0.004,position=0.03",
                                                           "efficient")])
def test_noise_on_the_command_line_overrides_the_file(leg_files, tmp_path, spec, method):
    proc = run("calibrate", str(leg_files / "robot.toml"), str(leg_files / "measurements.csv"),
               "--noise", spec, "-o", str(tmp_path), "--no-plots", "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "[noise]" not in proc.stdout
    assert iwr.load_result(tmp_path / "result.json")["method"] == method
    if method == "efficient":
        assert "legs 0.004, joint_lengths 0, joint_angles 0, position 0.03" in proc.stdout
        assert "(from --noise)" in proc.stdout


def test_calibrate_refuses_a_file_with_no_leg_noise(leg_files, tmp_path):
    path = tmp_path / "r.toml"
    iwr.Robot.default().with_noise(iwr.Noise(position=0.02)).to_toml(path)
    proc = run("calibrate", str(path), str(leg_files / "measurements.csv"), "-o", str(tmp_path))
    assert proc.returncode != 0
    assert f"{path}: [noise] legs = 0.0" in proc.stderr and "Traceback" not in proc.stderr


def test_tracker_noise_reaches_the_estimator(tmp_path):
    robot = tracker_robot().with_noise(READINGS, TRACKER)
    robot.to_toml(tmp_path / "bench.toml")
    proc = run("simulate", "--robot", str(tmp_path / "bench.toml"), "--poses", "30", "--seed",
               "4", "-o", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    truth = json.loads((tmp_path / "true_errors.json").read_text())
    assert truth["noise"] == dataclasses.asdict(READINGS)
    assert truth["tracker_noise"] == dataclasses.asdict(TRACKER)
    proc = run("calibrate", str(tmp_path / "robot.toml"), str(tmp_path / "measurements.csv"),
               "-o", str(tmp_path / "cal"), "--no-plots", "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "with efficient" in proc.stdout
    assert f"from {tmp_path / 'robot.toml'} [noise] and [tracker.noise]" in proc.stdout
    result = iwr.load_result(tmp_path / "cal" / "result.json")
    assert result["method"] == "efficient"
    # The calibrated robot keeps the bench's noise model.
    assert iwr.Robot.from_toml(tmp_path / "cal" / "calibrated.toml").noise_model == \
        (READINGS, TRACKER)


def test_another_method_on_tracker_points_is_weighted_by_the_file_noise(tmp_path):
    robot = tracker_robot().with_noise(READINGS, TRACKER)
    robot.to_toml(tmp_path / "bench.toml")
    proc = run("simulate", "--robot", str(tmp_path / "bench.toml"), "--poses", "20", "--seed",
               "2", "-o", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", str(tmp_path / "robot.toml"), str(tmp_path / "measurements.csv"),
               "--method", "lm", "-o", str(tmp_path / "cal"), "--no-plots", "--no-progress")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "method: lm on the objective weighted by the noise model" in proc.stdout
    assert iwr.load_result(tmp_path / "cal" / "result.json")["method"] == "lm"


def test_tiny_sigmas_are_refused_in_python_too():
    with pytest.raises(ValueError, match=r"Noise.legs: 1e-200 is below any instrument's noise"):
        iwr.Noise(legs=1e-200)
    from iwr.tracker import TrackerNoise

    with pytest.raises(ValueError, match=r"TrackerNoise.orientation: 5e-324 is below"):
        TrackerNoise(orientation=5e-324)
    assert iwr.Noise(legs=1e-9).legs == 1e-9 and iwr.Noise(legs=0.0).is_zero
