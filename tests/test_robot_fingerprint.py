"""The semantic fingerprint of a robot model (iwr.robot_fingerprint): every job records the model
of the robot it was identified for, and ``iwr report`` refuses a robot file of another model,
naming what differs, but takes the same model written otherwise."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr import kinds
from iwr.calibration import _extras
from iwr.cli import main as cli_main
from iwr.effects import api
from iwr.problem_file import engine_result, load_problem
from iwr.robot_fingerprint import differences, fingerprint, record


@pytest.fixture(scope="module")
def robot_measured_by(kind_case):
    """``kind name -> robot``: the default IWR with that kind's instrument."""
    return lambda name: kind_case(name, n_poses=1).robot


@pytest.mark.parametrize("name", ["pose", "points", "probe", "ballbar"])
def test_the_problem_file_holds_the_same_model(name, robot_measured_by, tmp_path):
    """What the engine ran on (the problem file's robot, engine_result's record) is the model
    of the robot file, with and without effects; each kind's set-up makes another model."""
    plain = robot_measured_by(name)
    for robot in (plain, plain.with_effects(*api.realistic(plain))):
        data, _ = iwr.simulate(robot, 8, seed=2)
        problem, x0 = kinds.of(data).problem(robot, data, None)
        problem.save(tmp_path / "p.iwrp", x0=x0 if np.any(x0) else None)
        back = load_problem(tmp_path / "p.iwrp").robot
        assert differences(record(back), robot) == []
        assert fingerprint(back) == fingerprint(robot)
    assert differences(record(plain), robot) != []  # the effects switched on: another model
    others = {fingerprint(robot_measured_by(k)) for k in ("pose", "points", "probe", "ballbar")}
    assert len(others) == 4


def test_a_reformatted_file_is_the_same_model(robot_measured_by, tmp_path):
    """Comments, layout, the robot's name, integers written as integers or exponents, the
    [noise] table and the workspace do not change the numbers: the same model."""
    robot = robot_measured_by("points").with_effects(*api.realistic(iwr.Robot.default()))
    robot.to_toml(tmp_path / "a.toml")
    text = (tmp_path / "a.toml").read_text()
    text = text.replace("leg_offsets = [600.0, 600.0, 600.0, 600.0, 600.0, 600.0]",
                        "# a comment\nleg_offsets = [6e2, 600, 600.0, 600, 600, 600]")
    assert "6e2" in text
    text = text.replace('name = "iwr"', 'name = "renamed"')
    (tmp_path / "b.toml").write_text("# reformatted\n\n" + text)
    other = iwr.Robot.from_toml(tmp_path / "b.toml")
    other.workspace = other.workspace * 2
    assert differences(record(robot), other) == []


def test_round_off_is_the_same_model_and_a_difference_is_shown_apart(robot_measured_by):
    """A file that writes pi/2 with 15 significant digits (another writer) was refused, its
    message showing the same value twice ("alpha = 1.57079632679 rad, the run's robot had
    1.57079632679 rad"). Values apart by round-off are the same model; a real difference in the
    last of the 12 digits shown is shown with the digits that tell the two apart."""
    robot = robot_measured_by("points")
    d = robot.to_dict()
    d["carriage"]["joints"][0]["alpha"] = float(f"{robot.dh[0, 0]:.15g}")
    d["tracker"]["reflectors"][0][0] = float(f"{120.0 * (1 + 3e-16):.17g}")
    assert float(f"{robot.dh[0, 0]:.15g}") != robot.dh[0, 0]
    assert differences(record(robot), iwr.Robot.from_dict(d)) == []
    d["carriage"]["joints"][0]["alpha"] = robot.dh[0, 0] - 4e-12  # 2.5e-12 of it
    assert differences(record(robot), iwr.Robot.from_dict(d)) == [
        "geometry: carriage joint 1 alpha = 1.5707963267908966 rad, the run's robot had "
        "1.5707963267948966 rad"]


def test_differences_name_the_section_and_the_values(robot_measured_by):
    robot = robot_measured_by("points")
    d = robot.to_dict()
    d["carriage"]["joints"][1]["a"] = 1250.0
    d["tracker"]["reflectors"][0][2] = 45.0
    lines = differences(record(robot), iwr.Robot.from_dict(d))
    assert "geometry: carriage joint 2 a = 1250 mm, the run's robot had 0 mm" in lines
    assert "setup: reflectors[1] = [120, 0, 45], the run's robot had [120, 0, 40]" in lines
    on = robot.with_effects(*api.realistic(robot))
    lines = differences(record(robot), on)
    assert "effects: compliance is on, the run's robot had it off" in lines
    assert any(line.startswith("parameters: 80 parameters, the run's robot had 73")
               for line in lines)
    # A record of the fingerprints only names the sections.
    only = {k: v for k, v in record(robot).items() if k != "model"}
    assert differences(only, on) == [
        "parameters: differs (the run recorded only its fingerprint)",
        "effects: differs (the run recorded only its fingerprint)"]


def test_a_new_kinds_wording_needs_no_branch():
    """_extras says what a kind's setup parameters belong to by the kind's own words (it said
    "its tracker setup" of every kind not named "ballbar")."""

    class Grid:
        name = "grid"
        setup_words = "its grid's set-ups"

        def setup_parameter_names(self, robot):
            return ["grid.x"]

    assert _extras(iwr.Robot.default(), Grid()) == "with its grid's set-ups "
    assert kinds.named("ballbar").setup_words == "its ballbar set-ups"
    assert kinds.named("probe").setup_words == "its tracker setup"


@pytest.fixture(scope="module")
def run(robot_measured_by, tmp_path_factory):
    """A small iwr calibrate run on ballbar data with effects: its folder, robot and data."""
    out = tmp_path_factory.mktemp("fp")
    plain = robot_measured_by("ballbar")
    robot = plain.with_effects(*api.realistic(plain))
    data, _ = iwr.simulate(robot, 40, seed=4)
    robot.to_toml(out / "robot.toml")
    kinds.of(data).write(robot, data, out / "data.csv")
    code = cli_main(["calibrate", str(out / "robot.toml"), str(out / "data.csv"), "--method",
                     "lm", "-o", str(out / "cal"), "--no-plots"])
    assert code in (0, 3, 5)
    return out


def test_report_refuses_another_robot(run, tmp_path, capsys):
    saved = json.loads((run / "cal" / "result.json").read_text())["settings"]
    robot = iwr.Robot.from_toml(run / "robot.toml")
    assert saved["robot_model"] == json.loads(json.dumps(record(robot)))
    assert json.loads((run / "cal" / "summary.json").read_text())["robot_model"] \
        == fingerprint(robot)
    d = robot.to_dict()
    d["ballbar"]["B"]["fixed_ball"][0] = 950.0
    iwr.Robot.from_dict(d).to_toml(tmp_path / "other.toml")
    capsys.readouterr()
    code = cli_main(["report", str(run / "cal" / "result.json"), str(tmp_path / "other.toml"),
                     str(run / "data.csv"), "--out", str(tmp_path / "r"), "--no-plots"])
    err = capsys.readouterr().err
    assert code == 2
    assert (f"{tmp_path / 'other.toml'} is not the robot {run / 'cal' / 'result.json'} was "
            f"identified for (made from {run / 'robot.toml'}): setup: ballbar.B.fixed_ball = "
            "[950, -200, 2400], the run's robot had [900, -200, 2400]") in err
    assert not (tmp_path / "r").exists()
    # The run's own calibrated.toml given back (a calibration, not the nominal robot): refused,
    # and the message says which file iwr report takes.
    code = cli_main(["report", str(run / "cal" / "result.json"),
                     str(run / "cal" / "calibrated.toml"), str(run / "data.csv"), "--out",
                     str(tmp_path / "r"), "--no-plots"])
    err = capsys.readouterr().err
    assert code == 2 and not (tmp_path / "r").exists()
    assert (f"; {run / 'cal' / 'calibrated.toml'} is a calibrated robot ([provenance] method "
            f"'lm', from {run / 'robot.toml'}): iwr report takes the nominal robot the run "
            f"identified the errors of, {run / 'robot.toml'}") in err


def test_report_warns_of_a_run_without_a_model(run, tmp_path, capsys):
    result = json.loads((run / "cal" / "result.json").read_text())
    del result["settings"]["robot_model"]
    (tmp_path / "old.json").write_text(json.dumps(result))
    capsys.readouterr()
    code = cli_main(["report", str(tmp_path / "old.json"), str(run / "robot.toml"),
                     str(run / "data.csv"), "--out", str(tmp_path / "r"), "--no-plots"])
    err = capsys.readouterr().err
    assert code in (0, 3, 5)
    assert "warning: " + str(tmp_path / "old.json") + " records no model of the robot" in err
    assert "records no model of the robot" in (tmp_path / "r" / "report.md").read_text()
    # The report's settings show the model by its fingerprint, not the whole record.
    assert "'geometry'" not in (tmp_path / "r" / "report.html").read_text()


def test_an_engine_run_records_its_robot(tmp_path):
    launcher = shutil.which("iwr-calibrate", path=str(Path(sys.executable).parent))
    assert launcher is not None
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 12, seed=1)
    robot.to_toml(tmp_path / "robot.toml")
    data.to_csv(tmp_path / "data.csv")
    proc = subprocess.run([launcher, str(tmp_path / "robot.toml"), str(tmp_path / "data.csv"),
                           "--generations", "2", "--output", str(tmp_path / "eng.json"), "-q"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    result = iwr.load_result(tmp_path / "eng.json")
    assert result.settings["robot_model"]["fingerprint"] == fingerprint(robot)
    again = engine_result(tmp_path / "eng.json.ckpt", tmp_path / "eng.json.iwrp")
    assert again.settings["robot_model"] == result.settings["robot_model"]


def test_an_edited_record_is_a_difference_not_a_crash(robot_measured_by):
    robot = robot_measured_by("probe")
    rec = record(robot)
    rec["model"]["setup"] = ["not", "a", "table"]
    rec["model"]["parameters"] = "x0"
    rec["fingerprint"] = "0" * 16
    assert differences(rec, robot) == [
        "parameters: differs (the run's record of it is not a model's)",
        "setup: differs (the run's record of it is not a model's)"]
