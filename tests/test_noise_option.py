"""``--noise`` reads the same in every command (``iwr simulate``, ``iwr calibrate``, ``iwr
compare``, ``iwr-calibrate``: :func:`iwr.cli.robot_noise.option_noise`). On tracker and ballbar
data ``position`` is the instrument's noise level (its realistic noise x position / 0.02), and
without it the instrument keeps its own noise (the robot file's, else the realistic one): simulate
and calibrate dropped ``position`` there (the instrument always the realistic one), and compare
refused noisy readings without ``position``."""

from __future__ import annotations

import dataclasses
import json

import pytest

import iwr
from iwr import kinds
from iwr.ballbar import BallbarNoise
from iwr.cli import main as cli_main
from iwr.cli._base import noise_spec
from iwr.cli.robot_noise import option_noise
from iwr.tracker import TrackerNoise

READINGS = iwr.Noise(legs=0.002, joint_lengths=0.005)
REALISTIC = {"points": TrackerNoise.leica(), "probe": TrackerNoise.leica(),
             "ballbar": BallbarNoise()}


def _scaled(model, factor):
    return type(model)(**{k: v * factor for k, v in dataclasses.asdict(model).items()})


@pytest.fixture(scope="module")
def robots(kind_case):
    return {name: kind_case(name, n_poses=1).robot for name in ("pose", "points", "ballbar")}


@pytest.mark.parametrize("name", ["points", "ballbar"])
def test_the_option_on_an_instrument_that_measures_no_pose(robots, name):
    robot = robots[name]
    realistic = REALISTIC[name]
    # realistic and none: the same as before, in every reading
    model = option_noise(noise_spec("realistic"), robot)
    assert model == kinds.for_robot(robot).reading_noise(iwr.Noise.realistic())
    assert model[1] == realistic
    assert option_noise(noise_spec("none"), robot)[1].is_zero
    # the readings' noise alone: the instrument keeps its realistic noise (compare refused it)
    readings, instrument = option_noise(noise_spec("legs=0.002,joint_lengths=0.005"), robot)
    assert readings == READINGS and instrument == realistic
    # position: the instrument's level (simulate and calibrate dropped it)
    readings, instrument = option_noise(noise_spec("legs=0.002,joint_lengths=0.005,"
                                                   "position=0.04,orientation=1e-5"), robot)
    assert readings == READINGS  # no position nor orientation reading on these data
    assert dataclasses.asdict(instrument) == pytest.approx(dataclasses.asdict(
        _scaled(realistic, 2.0)))


def test_the_option_on_pose_data_is_each_readings_sd(robots):
    noise = noise_spec("legs=0.002,position=0.04")
    assert option_noise(noise, robots["pose"]) == noise
    assert option_noise(noise_spec("legs=0.002"), robots["pose"]) == iwr.Noise(legs=0.002)


def test_without_position_the_tracker_keeps_the_robot_files_noise(robots):
    own = TrackerNoise(distance=0.004, distance_per_m=0.0002, transverse=0.006,
                       transverse_per_m=0.0025, orientation=1e-4)
    robot = robots["points"].with_noise(READINGS, own)
    assert option_noise(noise_spec("legs=0.003"), robot) == (iwr.Noise(legs=0.003), own)
    assert option_noise(noise_spec("legs=0.003,position=0.02"), robot)[1] == \
        TrackerNoise.leica()  # a level given: the level's


def test_simulate_uses_position_as_the_trackers_level(robots, tmp_path, capsys):
    robots["points"].to_toml(tmp_path / "robot.toml")
    assert cli_main(["simulate", "--robot", str(tmp_path / "robot.toml"), "--poses", "12",
                     "--noise", "legs=0.002,position=0.04", "-o", str(tmp_path / "s")]) == 0
    record = json.loads((tmp_path / "s" / "true_errors.json").read_text())
    assert record["tracker_noise"] == pytest.approx(
        dataclasses.asdict(_scaled(TrackerNoise.leica(), 2)))
    assert record["noise"]["legs"] == 0.002 and record["noise"]["position"] == 0


def test_compare_takes_the_readings_noise_alone(robots, tmp_path, capsys):
    robots["ballbar"].to_toml(tmp_path / "robot.toml")
    code = cli_main(["compare", "--robot", str(tmp_path / "robot.toml"), "--poses", "70",
                     "--seeds", "0", "--methods", "lm", "--budget", "60", "--start", "near",
                     "--validation-poses", "5", "--no-progress", "-o", str(tmp_path / "c"),
                     "--noise", "legs=0.002"])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "noise model: legs 0.002" in out.out
    assert "ballbar distance 0.001 (from --noise)" in out.out
    noise = json.loads((tmp_path / "c" / "results.json").read_text())["settings"]["noise"]
    assert noise["ballbar"] == {"distance": pytest.approx(0.001)}
    assert noise["readings"]["legs"] == 0.002


def test_iwr_calibrate_exe_reads_the_option_alike(robots, tmp_path):
    from iwr.cli.calibrate_exe import _noise

    robot = robots["points"]
    for spec in ("realistic", "legs=0.002", "legs=0.002,position=0.01"):
        assert _noise(spec, robot, "robot.toml") == option_noise(noise_spec(spec), robot)


@pytest.mark.parametrize("spec", ["legs=1e9", "position=1e6", "orientation=500"])
def test_an_absurd_noise_is_a_usage_error_naming_the_option(tmp_path, capsys, spec):
    # Before, legs=1e9 ran the simulation and failed with "legs: row 0, column 0: 134622092.8 mm
    # is beyond any robot or instrument", exit 1, --noise not named.
    assert cli_main(["simulate", "--noise", spec, "--poses", "10", "-o", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert "argument --noise: Noise." in err and "is beyond any instrument's noise" in err
    with pytest.raises(ValueError, match=r"Noise.legs: 1000.0 is beyond any instrument's noise"):
        iwr.Noise(legs=1e3)
