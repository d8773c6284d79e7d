"""``iwr report`` checks that DATA.csv is the run's (the result's data fingerprint), and the
reports say which covariance their standard deviations come from (the efficient estimator's own,
or eq. (10)'s first-order one)."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr.analysis.uncertainty import Uncertainty, uncertainty
from iwr.cli.report import data_fingerprint


def run(*args: str, prog: list[str] | None = None) -> subprocess.CompletedProcess[str]:
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    return subprocess.run([*(prog or [sys.executable, "-m", "iwr"]), *args], capture_output=True,
                          text=True, cwd=tempfile.gettempdir(), env=environ, timeout=600)


@pytest.fixture(scope="module")
def sims(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    out = tmp_path_factory.mktemp("rep")
    for seed in (5, 6):
        proc = run("simulate", "--poses", "30", "--seed", str(seed), "--out", str(out / f"s{seed}"))
        assert proc.returncode == 0, proc.stderr
    return out / "s5", out / "s6"


def test_the_fingerprint_is_the_engines(sims, tmp_path):
    """The Python fingerprint is the one the problem file (the engine) records."""
    robot = iwr.Robot.from_toml(sims[0] / "robot.toml")
    data = iwr.Measurements.from_csv(sims[0] / "measurements.csv", robot=robot)
    iwr.Problem(robot, data).save(tmp_path / "p.iwrp")
    from iwr.problem_file import read_problem

    assert read_problem(tmp_path / "p.iwrp")["data_fingerprint"] == data_fingerprint(robot, data)
    other = iwr.Measurements.from_csv(sims[1] / "measurements.csv", robot=robot)
    assert data_fingerprint(robot, other) != data_fingerprint(robot, data)


def test_report_refuses_another_data_file_for_an_engine_result(sims, tmp_path):
    launcher = shutil.which("iwr-calibrate", path=str(Path(sys.executable).parent))
    assert launcher is not None
    good, bad = sims[0] / "measurements.csv", sims[1] / "measurements.csv"
    proc = run(str(sims[0] / "robot.toml"), str(good), "--generations", "3", "--output",
               str(tmp_path / "eng.json"), "-q", prog=[launcher])
    assert proc.returncode == 0, proc.stderr
    proc = run("report", str(tmp_path / "eng.json"), str(sims[0] / "robot.toml"), str(bad),
               "--out", str(tmp_path / "r"), "--no-plots")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    assert f"{bad} is not the data {tmp_path / 'eng.json'} was identified from" in proc.stderr
    assert str(good.resolve()) in proc.stderr  # where the run's data came from
    assert not (tmp_path / "r").exists()  # refused before anything is written
    proc = run("report", str(tmp_path / "eng.json"), str(sims[0] / "robot.toml"), str(good),
               "--out", str(tmp_path / "r"), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    assert "records no fingerprint" not in (tmp_path / "r" / "report.md").read_text()


def test_report_refuses_another_data_file_for_an_iwr_calibrate_result(sims, tmp_path):
    good, bad = sims[0] / "measurements.csv", sims[1] / "measurements.csv"
    proc = run("calibrate", str(sims[0] / "robot.toml"), str(good), "--method", "lm",
               "-o", str(tmp_path / "cal"), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    saved = json.loads((tmp_path / "cal" / "result.json").read_text())
    assert saved["settings"]["data_fingerprint"] and saved["settings"]["data_file"] == str(good)
    proc = run("report", str(tmp_path / "cal" / "result.json"), str(sims[0] / "robot.toml"),
               str(bad), "--out", str(tmp_path / "r"), "--no-plots")
    assert proc.returncode == 2 and "is not the data" in proc.stderr and str(bad) in proc.stderr
    proc = run("report", str(tmp_path / "cal" / "result.json"), str(sims[0] / "robot.toml"),
               str(good), "--out", str(tmp_path / "r"), "--no-plots")
    assert proc.returncode == 0, proc.stderr


def test_a_result_without_fingerprint_is_reported_with_a_note(sims, tmp_path):
    robot = iwr.Robot.from_toml(sims[0] / "robot.toml")
    data = iwr.Measurements.from_csv(sims[0] / "measurements.csv", robot=robot)
    iwr.identify(robot, data, progress=False).save(tmp_path / "api.json")
    proc = run("report", str(tmp_path / "api.json"), str(sims[0] / "robot.toml"),
               str(sims[1] / "measurements.csv"), "--out", str(tmp_path / "r"), "--no-plots")
    # Reported (with the note), and judged: another robot's data are worse after this result
    # than before it, so the verdict "not calibrated" is also the exit status, as iwr calibrate's.
    assert proc.returncode == 5, proc.stderr
    assert "records no fingerprint of its data" in proc.stdout
    assert "not calibrated" in proc.stderr


def test_efficient_estimator_std_come_from_its_covariance(sims, tmp_path):
    robot = iwr.Robot.from_toml(sims[0] / "robot.toml")
    data = iwr.Measurements.from_csv(sims[0] / "measurements.csv", robot=robot)
    res = iwr.identify(robot, data, noise=iwr.Noise.realistic())
    unc = Uncertainty.from_result(res)
    assert unc is not None and unc.source == "estimator"
    np.testing.assert_allclose(unc.std, res["std"], equal_nan=True)
    eq10 = uncertainty(robot, data, res.x, active=res["active"])
    assert not np.allclose(unc.std[res["active"]], eq10.std[res["active"]], rtol=0.05)
    assert Uncertainty.from_result(iwr.identify(robot, data)) is None  # eq. (10): none
    proc = run("calibrate", str(sims[0] / "robot.toml"), str(sims[0] / "measurements.csv"),
               "--noise", "realistic", "-o", str(tmp_path / "cal"), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    md = (tmp_path / "cal" / "report.md").read_text()
    assert "Standard deviations: the efficient estimator's covariance" in md
    rows = json.loads((tmp_path / "cal" / "summary.json").read_text())["parameters"]
    std = np.array([np.nan if r["std"] is None else r["std"] for r in rows])
    # the CLI holds 20 % out: same order of magnitude as the API's on all poses, not eq. (10)'s
    ok = np.isfinite(std)
    assert ok.sum() == res["active"].sum()
    proc = run("report", str(tmp_path / "cal" / "result.json"), str(sims[0] / "robot.toml"),
               str(sims[0] / "measurements.csv"), "--out", str(tmp_path / "r"), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    assert "not the efficient estimator's covariance" in (tmp_path / "r" / "report.md").read_text()


def test_report_on_a_tracker_result(tmp_path):
    """iwr report with a robot that has a [tracker] table: the tracker report, the data checked
    by their fingerprint (the same from the wide file and from the long pair)."""
    repo = Path(__file__).resolve().parents[1]
    robot = repo / "examples" / "iwr_tracker.toml"
    wide = repo / "examples" / "iwr_tracker_points.csv"
    long = [str(repo / "examples" / "iwr_tracker_points_long.csv"), "--readings",
            str(repo / "examples" / "iwr_tracker_readings.csv")]
    proc = run("calibrate", str(robot), str(wide), "-o", str(tmp_path / "cal"), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    res = tmp_path / "cal" / "result.json"
    fp = json.loads(res.read_text())["settings"]["data_fingerprint"]
    assert len(fp) == 16 and not fp.startswith("tracker-")  # the problem file's
    for data in ([str(wide)], long):
        out = tmp_path / f"r{len(data)}"
        proc = run("report", str(res), str(robot), *data, "--out", str(out), "--no-plots")
        assert proc.returncode == 0, proc.stderr
        page = (out / "report.html").read_text()
        assert "<h2>Registration</h2>" in page and "records no fingerprint" not in page
    other = iwr.Robot.from_toml(robot)
    sim, _ = iwr.simulate(other, 20, seed=9)
    from iwr.tracker.files import write_tracker_wide

    write_tracker_wide(tmp_path / "other.csv", other.tracker, sim)
    proc = run("report", str(res), str(robot), str(tmp_path / "other.csv"), "--out",
               str(tmp_path / "bad"), "--no-plots")
    assert proc.returncode == 2 and "is not the data" in proc.stderr, proc.stderr
    plain = tmp_path / "plain.toml"
    iwr.Robot.default().to_toml(plain)
    proc = run("report", str(res), str(plain), str(wide), "--readings", str(wide), "--out",
               str(tmp_path / "bad"))
    assert proc.returncode == 2 and "--readings: only for a robot with a [tracker]" in proc.stderr


def test_a_recalibration_is_unchanged_in_the_run_and_in_its_report(tmp_path):
    """A calibrated robot calibrated again on fresh data of the same robot, 8 poses held out:
    after/before 1.20, which the ratio alone called "not calibrated" (exit 5, and ``iwr legs``
    refused the file); the paired test cannot tell it (p = 0.35). ``iwr calibrate`` and ``iwr
    report`` of its result file both say "Unchanged within what 8 validation poses can tell",
    exit 0."""
    noise = iwr.Noise.realistic()
    robot = iwr.Robot.default()
    data, truth = iwr.simulate(robot, 40, seed=0, noise=noise)
    first = iwr.calibrate(robot, data, noise=noise, seed=0, progress=False)
    robot.with_errors(first.result.x).to_toml(tmp_path / "cal.toml")
    fresh, _ = iwr.simulate(robot, 40, seed=10_000, x=truth, noise=noise)
    fresh.to_csv(tmp_path / "fresh.csv")
    files = [str(tmp_path / "cal.toml"), str(tmp_path / "fresh.csv")]
    proc = run("calibrate", *files, "--noise", "realistic", "--seed", "0", "--no-plots",
               "-o", str(tmp_path / "run"))
    assert proc.returncode == 0, proc.stderr
    head = "**Unchanged within what 8 validation poses can tell: "
    verdict = next(line for line in (tmp_path / "run" / "report.md").read_text().splitlines()
                   if line.startswith("**"))
    assert verdict.startswith(head) and "(after/before 1.20, paired t-test p = 0.35" in verdict
    assert json.loads((tmp_path / "run" / "result.json").read_text())["status"] == "converged"
    proc = run("report", str(tmp_path / "run" / "result.json"), *files, "--no-plots",
               "--out", str(tmp_path / "rep"))
    assert proc.returncode == 0, proc.stderr
    assert verdict in (tmp_path / "rep" / "report.md").read_text().splitlines()


@pytest.fixture(scope="module")
def calibrated(sims: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The result.json of an ``iwr calibrate`` run on the first simulation."""
    out = tmp_path_factory.mktemp("cal") / "cal"
    proc = run("calibrate", str(sims[0] / "robot.toml"), str(sims[0] / "measurements.csv"),
               "--method", "lm", "-o", str(out), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    return out / "result.json"


def _reversed(d: dict) -> None:
    d["parameter_names"].reverse()


def _large(d: dict) -> None:
    d["x"][5] = 1e6


@pytest.mark.parametrize("edit, message", [
    (lambda d: d.update(history=5), r"history: expected an object of lists of numbers, got 5"),
    (lambda d: d.update(settings=[1, 2]), r"settings: expected an object, got \[1, 2\]"),
    (lambda d: d.update(x=[[v] for v in d["x"]]),
     r"x\[0\] \(joint1\.dalpha\): expected a number or null, got \["),
    (lambda d: d.update(success="false"), r"success: expected true or false, got 'false'"),
    (lambda d: d.update(success=True, status="not converged"), r"status: 'not converged'"),
    (lambda d: d["x"].__setitem__(0, float("nan")),
     r"x\[0\] \(joint1\.dalpha\) is nan: a result that is not finite is no robot's errors"),
    (_large, r"x\[5\] \(joint2\.da\) is 1e\+06 mm: the calibrated robot's dh: entry \(1, 1\)"),
    (_reversed, r"its parameters are not those of robot 'IWR': first difference "
                r"parameter_names\[0\] 'leg6\.dl0', the robot's 'joint1\.dalpha'"),
])
@pytest.mark.parametrize("command", ["report", "analyze"])
def test_report_and_analyze_refuse_a_bad_result_file_by_name(sims, calibrated, tmp_path, edit,
                                                              message, command):
    """A QA audit: a result file with one field changed gave internal errors (``history``: an
    AttributeError), messages that named neither the file nor the parameter (``x[5] = 1e6``:
    "dh: entry (1, 1) is 1000000.0 mm", after the report was printed), that contradicted
    themselves ("58 parameters, but robot has 58") or nothing at all: ``iwr analyze --result``
    took reversed ``parameter_names`` (the values on the wrong parameters) and ``x[5] = 1e6``,
    and ``iwr report`` wrote "Calibrated" for ``success: "false"``. Both commands now make one
    check of the file (iwr.load_result) and of the result against the robot
    (iwr.calibration.check_result): one line naming the file and the field, exit 1 (a malformed
    file, docs/cli.md), nothing written."""
    doc = json.loads(calibrated.read_text())
    edit(doc)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    robot, data = str(sims[0] / "robot.toml"), str(sims[0] / "measurements.csv")
    args = (["report", str(bad), robot, data, "--out", str(tmp_path / "r"), "--no-plots"]
            if command == "report" else ["analyze", robot, data, "--result", str(bad)])
    proc = run(*args)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr and not proc.stdout
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"iwr: error: {bad}: "), proc.stderr
    assert re.search(message, lines[0]), lines[0]
    assert not (tmp_path / "r").exists()


def test_analyze_takes_the_result_of_a_robot_with_effects(tmp_path):
    """``iwr analyze --result`` refused the result of a robot with effects ("60 parameters, but
    robot 'IWR' has 58 on pose data"): its ``x`` holds the effects' parameters, which the
    identifiability with effects takes. iwr report's check takes it as the robot's."""
    from iwr.effects import api
    from iwr.effects.carriage_thermal import CarriageThermal

    robot = iwr.Robot.default().with_effects(CarriageThermal([11.5, 12.0], 20.0, identify=True,
                                                             per_joint=True))
    robot.to_toml(tmp_path / "robot.toml")
    data, _ = api.simulate(robot, 40, seed=3)
    data.to_csv(tmp_path / "data.csv")
    files = [str(tmp_path / "robot.toml"), str(tmp_path / "data.csv")]
    proc = run("calibrate", *files, "--method", "lm", "-o", str(tmp_path / "o"), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    proc = run("analyze", *files, "--result", str(tmp_path / "o" / "result.json"))
    assert proc.returncode == 0, proc.stderr
    assert "rank 54 of 60: 6 unidentifiable direction(s)" in proc.stdout
