"""The ``iwr`` command line, run as a user runs it: a subprocess, its exit code and its output."""

from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import iwr

REPO = Path(__file__).resolve().parents[1]


def run(*args: str, cwd: Path | None = None, env: dict[str, str] | None = None):
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    environ.update(env or {})
    # Never the repository root: `python -m iwr` there would import the source folder, which has
    # no compiled module, instead of the installed package.
    return subprocess.run(
        [sys.executable, "-m", "iwr", *args], capture_output=True, text=True,
        cwd=cwd if cwd is not None else tempfile.gettempdir(), env=environ, timeout=600,
    )


def assert_fails(proc, code: int, pattern: str) -> None:
    """Exit code ``code``, exactly one line on stderr, ``iwr: error: ...``, no traceback."""
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr + proc.stdout
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("iwr: error: "), lines[0]
    assert re.search(pattern, lines[0]), lines[0]


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    """A simulated robot, 60 noisy poses and the truth, written by ``iwr simulate``."""
    out = tmp_path_factory.mktemp("sim")
    proc = run("simulate", "--poses", "60", "--seed", "3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "wrote" in proc.stdout
    return out


def csv_lines(path: Path) -> tuple[list[str], int]:
    lines = path.read_text().splitlines()
    return lines, next(i for i, line in enumerate(lines) if line.startswith("q1"))


# -- help and usage ------------------------------------------------------------------------------


@pytest.mark.parametrize("command", ["", "simulate", "calibrate", "analyze", "plan"])
def test_help_everywhere(command):
    proc = run(*([command] if command else []), "--help")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"usage: iwr {command}".rstrip())
    assert "--debug" in proc.stdout


def test_every_command_has_help():
    for command in ("simulate", "calibrate", "analyze", "plan", "compare", "study", "report",
                    "legs"):
        proc = run(command, "--help")
        assert proc.returncode == 0 and proc.stdout.startswith(f"usage: iwr {command}"), command


def test_version():
    proc = run("--version")
    assert proc.returncode == 0 and proc.stdout.startswith(f"iwr {iwr.__version__} (kernel ")


@pytest.mark.parametrize(
    "args, pattern",
    [
        ((), r"required: COMMAND \(see 'iwr --help'\)"),
        (("bogus",), r"invalid choice: 'bogus'"),
        (("calibrate", "--bogus"), r"unrecognized arguments: --bogus"),
        (("calibrate", "robot.toml"), r"give both ROBOT.toml and DATA.csv, or neither"),
        (("calibrate", "--method", "nope"), r"--method 'nope': available methods: .*lm"),
        (("calibrate", "--method", "lm", "--generations", "5"),
         r"--generations is not an option of method 'lm'"),
        # a QA run: DE's named choices exited 1 naming "strategy:", not the option
        (("calibrate", "--method", "de", "--strategy", "foo"),
         r"--strategy 'foo': expected one of rand1bin, .*jso"),
        (("calibrate", "--method", "de", "--preset", "foo"), r"--preset 'foo': expected 'paper'"),
        (("calibrate", "--validation-fraction", "1.5"), r"--validation-fraction: 1.5 must be"),
        (("simulate", "--poses", "0"), r"--poses: 0 must be a positive integer"),
        (("simulate", "--noise", "legs=abc"), r"legs='abc' is not a number"),
        (("simulate", "--noise", "sensor=1"), r"KEY among legs, joint_lengths"),
    ],
)
def test_bad_usage_exits_2_with_one_line(args, pattern):
    assert_fails(run(*args), 2, pattern)


# -- simulate ------------------------------------------------------------------------------------


def test_simulate_writes_consistent_reproducible_files(sim, tmp_path):
    robot = iwr.Robot.from_toml(sim / "robot.toml")
    assert robot == iwr.Robot.default()
    data = iwr.Measurements.from_csv(sim / "measurements.csv", robot=robot)
    truth = json.loads((sim / "true_errors.json").read_text())
    assert len(data) == 60 and truth["seed"] == 3 and truth["parameter_names"] == \
        robot.parameter_names
    # the same seed writes the same data; noise 'none' gives readings the truth explains exactly
    proc = run("simulate", "--poses", "60", "--seed", "3", "--out", str(tmp_path))
    assert proc.returncode == 0
    assert (tmp_path / "measurements.csv").read_bytes() == (sim / "measurements.csv").read_bytes()
    proc = run("simulate", "--poses", "10", "--seed", "4", "--noise", "none",
               "--out", str(tmp_path), "--data-file", "exact.csv", "--truth-file", "t.json")
    assert proc.returncode == 0, proc.stderr
    exact = iwr.Measurements.from_csv(tmp_path / "exact.csv")
    x = np.array(json.loads((tmp_path / "t.json").read_text())["errors"])
    np.testing.assert_allclose(iwr.predict_legs(robot, x, exact.q, exact.poses), exact.legs,
                               atol=1e-9)


# -- calibrate -----------------------------------------------------------------------------------


def test_calibrate_files(sim, tmp_path):
    out = tmp_path / "out"
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"),
               "--method", "lm", "--out", str(out), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""  # no progress bar when stderr is not a terminal
    assert "accuracy on 12 validation poses" in proc.stdout
    assert re.search(r"poses: 48 for identification, 12 held out", proc.stdout)
    for leg in range(1, 7):
        assert f"leg {leg}" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    acc = summary["accuracy"]
    assert acc["n_poses"] == 12
    before, after = (acc[k]["position_mm"]["rms"] for k in ("nominal", "calibrated"))
    assert after < before / 20
    result = iwr.load_result(out / "result.json")
    robot = iwr.Robot.from_toml(sim / "robot.toml")
    data = iwr.Measurements.from_csv(sim / "measurements.csv", robot=robot)
    # The robot's errors, its workspace widened to hold the measured poses (when they need it).
    written = iwr.Robot.from_toml(out / "calibrated.toml")
    assert written == iwr.calibrated_robot(robot, result, data)
    assert written.with_workspace(robot.workspace) == robot.with_errors(result.x)
    assert "## Accuracy" in (out / "report.md").read_text()
    assert not (out / "accuracy.png").exists()


def test_calibrate_with_a_validation_file_and_without_hold_out(sim, tmp_path):
    robot, data = sim / "robot.toml", sim / "measurements.csv"
    # The data file itself as --validation was taken, and called "60 held out" (a QA run).
    proc = run("calibrate", str(robot), str(data), "--validation", str(data), "--method", "lm",
               "--out", str(tmp_path / "a"), "--no-plots")
    assert_fails(proc, 2, r"--validation .*measurements.csv: is the data file .* itself")
    copy = tmp_path / "copy.csv"
    copy.write_bytes(data.read_bytes())
    proc = run("calibrate", str(robot), str(data), "--validation", str(copy), "--method", "lm",
               "--out", str(tmp_path / "a"), "--no-plots")
    assert_fails(proc, 2, r"--validation .*copy.csv: every one of its 60 poses is also in")
    half = tmp_path / "half.csv"
    lines = data.read_text().splitlines(keepends=True)
    head = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if not ln.startswith("#")]
    half.write_text("".join(head + body[:41]))  # the header and the first 40 poses
    proc = run("calibrate", str(robot), str(half), "--validation", str(data), "--method", "lm",
               "--out", str(tmp_path / "a"), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    assert "poses: 40 for identification, 60 held out" in proc.stdout
    assert "note: 40 of the 60 validation poses are also in the data" in proc.stdout
    proc = run("calibrate", str(robot), str(data), "--validation-fraction", "0", "--method",
               "lm", "--out", str(tmp_path / "b"), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    assert "identification poses (optimistic)" in proc.stdout


def test_calibrate_without_arguments_runs_the_example(tmp_path):
    proc = run("calibrate", cwd=tmp_path, env={"IWR_EXAMPLE_QUICK": "1"})
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "iwr-example"
    for name in ("robot.toml", "measurements.csv", "true_errors.json", "calibrated.toml",
                 "result.json", "summary.json", "report.md", "residuals.png", "accuracy.png"):
        assert (out / name).is_file(), name
    assert (out / "accuracy.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "built-in example" in proc.stdout and "realistic noise" in proc.stdout
    assert re.search(r"calibrated robot\s+\d", proc.stdout)
    summary = json.loads((out / "summary.json").read_text())
    acc = summary["accuracy"]
    assert acc["calibrated"]["position_mm"]["rms"] < acc["nominal"]["position_mm"]["rms"] / 20
    # the calibrated robot is as accurate as the truth allows, within a factor of 2
    floor = summary["accuracy_with_true_errors"]["position_mm"]["rms"]
    assert acc["calibrated"]["position_mm"]["rms"] < 2 * floor
    report = (out / "report.md").read_text()
    assert "![Tool pose errors" in report and "| calibrated |" in report


def test_shipped_example_files(tmp_path):
    proc = run("calibrate", str(REPO / "examples" / "iwr.toml"),
               str(REPO / "examples" / "iwr_example.csv"), "--out", str(tmp_path),
               "--method", "lm", "--no-plots")
    assert proc.returncode == 0, proc.stderr
    acc = json.loads((tmp_path / "summary.json").read_text())["accuracy"]
    assert acc["calibrated"]["position_mm"]["rms"] < acc["nominal"]["position_mm"]["rms"] / 20


# -- data and runtime errors: exit 1, one line, no traceback -------------------------------------


def _bad_files(sim: Path, tmp: Path, case: str) -> tuple[Path, Path]:
    robot, data = sim / "robot.toml", sim / "measurements.csv"
    lines, h = csv_lines(data)
    if case == "missing robot":
        return tmp / "nope.toml", data
    if case == "missing data":
        return robot, tmp / "nope.csv"
    if case == "malformed toml":
        bad = tmp / "bad.toml"
        bad.write_text(robot.read_text().replace('name = "IWR"', 'name = "IWR'))
        return bad, data
    if case == "unknown key":
        bad = tmp / "bad.toml"
        bad.write_text(robot.read_text().replace('name = "IWR"', 'name = "IWR"\ncolour = "red"'))
        return bad, data
    out = tmp / "bad.csv"
    if case == "nan row":
        fields = lines[h + 5].split(",")
        fields[12] = "nan"
        lines[h + 5] = ",".join(fields)
    elif case == "metres":
        m = iwr.Measurements.from_csv(data)
        iwr.Measurements(m.q, m.poses, m.legs / 1000.0, joint_types=m.joint_types).to_csv(out)
        return robot, out
    elif case == "duplicated pose":
        lines.append(lines[h + 3])
    elif case == "unreachable pose":
        fields = lines[h + 7].split(",")
        fields[11] = "650.0"
        lines[h + 7] = ",".join(fields)
    out.write_text("\n".join(lines) + "\n")
    return robot, out


@pytest.mark.parametrize(
    "case, pattern",
    [
        ("missing robot", r"nope\.toml: no such file"),
        ("missing data", r"nope\.csv: no such file"),
        ("malformed toml", r"bad\.toml: not valid TOML"),
        ("unknown key", r"bad\.toml: colour: unknown key"),
        # (line numbers in a file of iwr simulate: its "# iwr simulate:" line first)
        ("nan row", r"bad\.csv, line 13, column s3_mm: 'nan' is not finite"),
        ("metres", r"bad\.csv: every one of the leg readings is below 5.*look like metres"),
        ("duplicated pose", r"bad\.csv: 1 repeated pose\(s\): lines 11 and 69"),
        ("unreachable pose", r"bad\.csv: 1 unreachable pose\(s\).*line 15: leg 2 reading 650 mm "
                             r"is outside the stroke"),
    ],
)
def test_data_errors_exit_1_with_one_line(sim, tmp_path, case, pattern):
    robot, data = _bad_files(sim, tmp_path, case)
    proc = run("calibrate", str(robot), str(data), "--out", str(tmp_path / "out"))
    assert_fails(proc, 1, pattern)
    assert not (tmp_path / "out").exists()  # nothing written from bad input


def test_debug_shows_the_traceback(sim, tmp_path):
    robot, data = _bad_files(sim, tmp_path, "nan row")
    proc = run("--debug", "calibrate", str(robot), str(data))
    assert proc.returncode == 1
    assert "Traceback" in proc.stderr and "MeasurementFileError" in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("iwr: error: ")


def test_analyze(sim):
    proc = run("analyze", str(sim / "robot.toml"), str(sim / "measurements.csv"))
    assert proc.returncode == 0, proc.stderr
    assert re.search(r"rank \d+ of 58", proc.stdout)


def test_plan(sim, tmp_path):
    out = tmp_path / "plan.csv"
    proc = run("plan", str(sim / "robot.toml"), "--candidates", str(sim / "measurements.csv"),
               "--poses", "12", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert "12 poses chosen for O1" in proc.stdout
    chosen_q, chosen_poses = iwr.read_plan(out)
    cand = iwr.Measurements.from_csv(sim / "measurements.csv")
    assert len(chosen_q) == 12
    rows = {tuple(r) for r in np.hstack([cand.q, cand.poses])}
    assert all(tuple(r) in rows for r in np.hstack([chosen_q, chosen_poses]))
    # Too few poses to determine the base parameters: a bad option's value, exit 2 (was 1).
    proc = run("plan", str(sim / "robot.toml"), "--n-candidates", "100", "--poses", "2",
               "--out", str(out))
    assert_fails(proc, 2, r"--poses: 2; expected an integer from \d+ .* to 100 \(the number "
                 r"of candidates, of --n-candidates 100\)")
    # Candidates that determine fewer combinations than the robot has: their own rank made the
    # minimum (8 poses: "48 base parameters", a plan written, exit 0: an outside check).
    few = tmp_path / "eight.csv"
    cand.subset(np.arange(8)).to_csv(few)
    proc = run("plan", str(sim / "robot.toml"), "--candidates", str(few), "--poses", "8",
               "--out", str(tmp_path / "eight_plan.csv"))
    assert_fails(proc, 2, r"--candidates .*eight.csv: its 8 poses determine 48 combinations of "
                 r"the parameters, of the 52 that robot 'IWR' has")
    assert not (tmp_path / "eight_plan.csv").exists()


def test_source_folder_without_compiled_module_says_so(tmp_path):
    """Python started in a checkout imports its source folder, which has no compiled module: the
    error says so and what to do, instead of a puzzling circular-import message."""
    import shutil

    shutil.copytree(REPO / "iwr", tmp_path / "iwr",
                    ignore=shutil.ignore_patterns("*.so", "*.pyd", "__pycache__"))
    proc = subprocess.run([sys.executable, "-c", "import iwr"], cwd=tmp_path,
                          capture_output=True, text=True, timeout=120)
    if proc.returncode == 0:
        pytest.skip("an editable install's import hook supplies iwr._core to any iwr folder")
    assert "the compiled module iwr._core is missing" in proc.stderr
    assert "run Python from another folder" in proc.stderr


# -- after calibration: iwr report, iwr legs; Ctrl-C ----------------------------------------------


def test_report_turns_a_result_into_robot_and_report(sim, tmp_path):
    """A result saved by the API (as iwr-calibrate's RUN.json is) becomes the calibrated robot
    and the report, as iwr calibrate writes them."""
    robot = iwr.Robot.from_toml(sim / "robot.toml")
    data = iwr.Measurements.from_csv(sim / "measurements.csv", robot=robot)
    result = iwr.identify(robot, data, method="lm", progress=False)
    result.save(tmp_path / "run.json")
    out = tmp_path / "rep"
    proc = run("report", str(tmp_path / "run.json"), str(sim / "robot.toml"),
               str(sim / "measurements.csv"), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    assert iwr.Robot.from_toml(out / "calibrated.toml") == iwr.calibrated_robot(robot, result, data)
    page = (out / "report.html").read_text(encoding="utf-8")
    assert "Calibration report" in page and "data:image/png;base64," in page
    for f in ("run.json", "robot.toml", "measurements.csv"):
        assert f in page
    digest = hashlib.sha256((sim / "measurements.csv").read_bytes()).hexdigest()
    assert digest in page
    # A result for another robot is refused by name.
    other = tmp_path / "other.json"
    doc = json.loads((tmp_path / "run.json").read_text())
    doc["x"] = doc["x"][:-1]
    doc["parameter_names"] = doc["parameter_names"][:-1]
    if "active" in doc:  # a result of 57 parameters has 57 flags
        doc["active"] = doc["active"][:-1]
    other.write_text(json.dumps(doc))
    proc = run("report", str(other), str(sim / "robot.toml"), str(sim / "measurements.csv"),
               "--out", str(out))
    assert_fails(proc, 1, r"57 parameters, but robot")


def test_legs_round_trip(tmp_path):
    """The legs written for the actual robot and the simulation's poses are the simulated
    (noise-free) readings."""
    robot = iwr.Robot.default()
    data, truth = iwr.simulate(robot, n_poses=30, seed=11, noise=iwr.Noise())
    robot.with_errors(truth).to_toml(tmp_path / "calibrated.toml")
    data.to_csv(tmp_path / "targets.csv")  # q, poses (its leg columns are ignored)
    proc = run("legs", str(tmp_path / "calibrated.toml"), str(tmp_path / "targets.csv"),
               "-o", str(tmp_path / "legs.csv"))
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in (tmp_path / "legs.csv").read_text().splitlines()
             if not ln.startswith("#")]
    head = lines[0].split(",")
    values = np.array([[float(v) for v in ln.split(",")] for ln in lines[1:]])
    legs = values[:, [head.index(f"s{j}_mm") for j in range(1, 7)]]
    assert legs.shape == (30, 6)
    np.testing.assert_allclose(legs, data.legs, rtol=0, atol=1e-9)
    q = values[:, : robot.n_joints]
    np.testing.assert_array_equal(q, data.q)


@pytest.mark.parametrize(
    "content, pattern",
    [
        ("q1_mm,q2_rad\n", r"targets.csv, line 1: missing columns"),
        ("q1_mm;q2_mm;q3_rad;q4_rad;x_mm;y_mm;z_mm;alpha_rad;beta_rad;gamma_rad\n1;2\n",
         r"separated by ';'"),
        ("q1_mm,q2_mm,q3_rad,q4_rad,x_mm,y_mm,z_mm,alpha_rad,beta_rad,gamma_rad\n"
         "1,2,3,4,5,6,7,8,9,x\n", r"line 2, column 'gamma_rad': 'x' is not a number"),
    ],
)
def test_legs_bad_targets(tmp_path, content, pattern):
    iwr.Robot.default().to_toml(tmp_path / "r.toml")
    (tmp_path / "targets.csv").write_text(content)
    proc = run("legs", str(tmp_path / "r.toml"), str(tmp_path / "targets.csv"),
               "-o", str(tmp_path / "legs.csv"))
    assert_fails(proc, 1, pattern)


def test_ctrl_c_writes_the_best_point_so_far_and_exits_130(sim, tmp_path, default_sigint):
    """SIGINT during the identification: exit 130, the files written, success = false."""
    import signal
    import time

    out = tmp_path / "out"
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "iwr", "calibrate", str(sim / "robot.toml"),
         str(sim / "measurements.csv"), "--method", "de", "--generations", "100000",
         "--workers", "1", "--out", str(out), "--no-plots"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environ,
        cwd=tempfile.gettempdir(), preexec_fn=default_sigint,  # noqa: PLW1509
    )
    try:
        for line in proc.stdout:  # wait until the identification runs
            if line.startswith("identifying with de"):
                break
        time.sleep(2.0)
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    assert not re.search(r"(?<!not )converged \(", stdout) and "not converged (" in stdout
    result = iwr.load_result(out / "result.json")
    assert result.success is False and "interrupted" in result.message
    assert np.isfinite(result.fun) and result.nfev > 0
    assert "Interrupted" in (out / "report.html").read_text(encoding="utf-8")


def test_a_method_stopped_before_converging_exits_4(sim, tmp_path):
    """A budget too small to converge: the files are written, but the exit code is not success."""
    out = tmp_path / "out"
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"), "--method",
               "lm", "--budget", "3", "--out", str(out), "--no-plots")
    assert proc.returncode == 4, proc.stderr
    assert "not converged" in proc.stderr
    assert iwr.load_result(out / "result.json").success is False


# -- issue 26: degenerate data, outputs over inputs --------------------------------------------


def test_too_few_distinct_poses_are_not_a_calibration(sim, tmp_path):
    """3 poses (18 leg readings) cannot identify the 50-odd parameters that varied poses
    identify: not success, whatever the method's convergence; exit 5, and the verdict says so."""
    lines, h = csv_lines(sim / "measurements.csv")
    (tmp_path / "few.csv").write_text("\n".join(lines[:h + 4]) + "\n")
    out = tmp_path / "out"
    proc = run("calibrate", str(sim / "robot.toml"), str(tmp_path / "few.csv"), "--method", "lm",
               "--validation-fraction", "0", "--out", str(out), "--no-plots")
    assert proc.returncode == 5, proc.stdout + proc.stderr
    assert "iwr calibrate: not calibrated (exit 5): degenerate data: the 3 distinct" in proc.stderr
    result = json.loads((out / "result.json").read_text())
    assert result["success"] is False
    assert result["message"].startswith("not calibrated: degenerate data: the 3 distinct")
    assert iwr.load_result(out / "result.json").status == "not calibrated"
    assert "**Not calibrated: degenerate data" in (out / "report.md").read_text()


def test_too_few_poses_and_a_method_not_converged_say_the_data_are_the_cause(sim, tmp_path):
    """The same 3 poses with a budget the method exhausts: the verdict said "not converged" (exit
    4), as if a larger budget would do; the data are the cause: exit 5, degenerate data."""
    lines, h = csv_lines(sim / "measurements.csv")
    (tmp_path / "few.csv").write_text("\n".join(lines[:h + 4]) + "\n")
    out = tmp_path / "out"
    proc = run("calibrate", str(sim / "robot.toml"), str(tmp_path / "few.csv"), "--method", "lm",
               "--budget", "3", "--validation-fraction", "0", "--out", str(out), "--no-plots")
    assert proc.returncode == 5, proc.stdout + proc.stderr
    assert "iwr calibrate: not calibrated (exit 5): degenerate data: the 3 distinct" in proc.stderr
    assert iwr.load_result(out / "result.json").success is False
    prov = iwr.Robot.from_toml(out / "calibrated.toml").provenance
    assert prov["status"] == "not calibrated"
    # The SIMD variant that ran is recorded: the widest this CPU runs (run() clears IWR_*).
    assert prov["kernel"] == iwr._core._supported_kernels()[-1]
    assert "**Not calibrated: degenerate data" in (out / "report.md").read_text()
    assert f"| SIMD kernel (IWR_KERNEL) | {prov['kernel']} |" in (out / "report.md").read_text()


def test_recalibration_with_the_default_folder_keeps_its_input(sim, tmp_path):
    """`iwr calibrate iwr-calibration/calibrated.toml DATA.csv` wrote over its own robot; now the
    run goes to iwr-calibration-2/ and its report's SHA-256 names a file that exists."""
    args = ["--method", "lm", "--no-plots"]
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"), *args,
               cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    first = tmp_path / "iwr-calibration" / "calibrated.toml"
    before = first.read_bytes()
    proc = run("calibrate", "iwr-calibration/calibrated.toml", str(sim / "measurements.csv"),
               *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "output folder: iwr-calibration-2/" in proc.stdout
    # Calibrated before: no better, and not worse.
    assert "**Unchanged within 5%" in (tmp_path / "iwr-calibration-2" / "report.md").read_text()
    assert first.read_bytes() == before
    page = (tmp_path / "iwr-calibration-2" / "report.html").read_text(encoding="utf-8")
    assert hashlib.sha256(before).hexdigest() in page
    # Any spelling or link of the folder, given with --out: refused before any work.
    (tmp_path / "link").symlink_to(tmp_path / "iwr-calibration")
    for out in ("./iwr-calibration/", "link", str(tmp_path / "iwr-calibration" / ".")):
        proc = run("calibrate", "iwr-calibration/calibrated.toml", str(sim / "measurements.csv"),
                   *args, "--out", out, cwd=tmp_path)
        assert_fails(proc, 2, r"--out .*: would overwrite iwr-calibration/calibrated.toml, an "
                              r"input of this run .*; give another --out")
        assert "identifying" not in proc.stdout
    assert first.read_bytes() == before


def test_outputs_that_cannot_be_written_are_refused_before_the_work(sim, tmp_path):
    (tmp_path / "file").write_text("x")
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"), "--method",
               "de", "--out", str(tmp_path / "file"))
    assert_fails(proc, 2, r"--out .*file: exists and is not a folder")
    assert "identifying" not in proc.stdout
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    if not os.access(locked, os.W_OK):  # root writes anywhere
        proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"),
                   "--out", str(locked / "new" / "deeper"))
        assert_fails(proc, 2, r"cannot write there: .*locked is not a writable folder")


def test_no_command_writes_over_its_inputs(sim, tmp_path):
    robot, data = sim / "robot.toml", sim / "measurements.csv"
    saved = {p: p.read_bytes() for p in (robot, data)}
    targets = tmp_path / "t.csv"
    targets.write_text("q1_mm,q2_mm,q3_rad,q4_rad,x_mm,y_mm,z_mm,alpha_rad,beta_rad,gamma_rad\n"
                       "100,50,0.1,0.05,0,0,800,0,0,0\n")
    saved[targets] = targets.read_bytes()
    run_json = tmp_path / "rep" / "result.json"
    run_json.parent.mkdir()
    r = iwr.Robot.from_toml(robot)
    iwr.identify(r, iwr.Measurements.from_csv(data, robot=r), method="lm",
                 progress=False).save(run_json)
    saved[run_json] = run_json.read_bytes()
    cases = [
        (["legs", str(robot), str(targets), "-o", str(targets)], r"-o .*t.csv: would overwrite"),
        (["plan", str(robot), "--out", str(robot), "--n-candidates", "50", "--poses", "5"],
         r"--out .*robot.toml: would overwrite"),
        (["report", str(run_json), str(robot), str(data), "--out", str(run_json.parent)],
         r"--out .*rep: would overwrite .*result.json"),
        (["simulate", "--robot", str(robot), "--out", str(sim)],
         r"--out .*: would overwrite .*robot.toml"),
        # Files of another command or of the bench named by mistake (a QA run: `iwr plan --out
        # measurements.csv` replaced the measurements with a plan, exit 0).
        (["plan", str(robot), "--out", str(data), "--n-candidates", "50", "--poses", "5"],
         r"--out .*measurements.csv: exists and is not a file iwr plan wrote"),
        (["legs", str(robot), str(targets), "-o", str(data)],
         r"-o .*measurements.csv: exists and is not a file iwr legs wrote"),
        (["simulate", "--out", str(tmp_path / "s"), "--robot-file", "a.csv", "--data-file",
          "a.csv"], r"--robot-file and --data-file are both 'a.csv'"),
        (["simulate", "--out", str(tmp_path / "s"), "--data-file", "m.csv", "--truth-file",
          "m_long.csv"], r"--truth-file and --data-file's long form are both 'm_long.csv'"),
    ]
    for args, pattern in cases:
        proc = run(*args)
        assert_fails(proc, 2, pattern)
    for p, content in saved.items():
        assert p.read_bytes() == content, p
    assert not (tmp_path / "s").exists()
    # A file the command wrote itself is written over, as before.
    out = tmp_path / "plan.csv"
    for _ in range(2):
        proc = run("plan", str(robot), "--out", str(out), "--n-candidates", "50", "--poses", "10")
        assert proc.returncode == 0, proc.stderr


def test_simulate_writes_over_no_file_it_did_not_write(sim, tmp_path):
    """A QA run: `iwr simulate` in a folder holding the user's measurements.csv replaced it
    (exit 0), as --robot-file and --data-file did any file they named; `--data-file .` and
    `--robot-file ''` failed with exit 1 and no option named. Refused now (exit 2), as `iwr plan
    --out` refuses; the files iwr simulate wrote itself it writes over, as before."""
    out = tmp_path / "ow"
    out.mkdir()
    mine = {out / "measurements.csv": "real data\n", tmp_path / "x.toml": "x = 1\n",
            out / "true_errors.json": "{}\n"}
    for p, text in mine.items():
        p.write_text(text)
    (out / "d.csv").mkdir()
    # Files written by iwr, but not by iwr simulate: a calibrated robot, the library's data.
    iwr.Robot.default().to_toml(out / "calibrated.toml")
    iwr.Measurements.from_csv(sim / "measurements.csv").to_csv(out / "data.csv")
    saved = {p: p.read_bytes() for p in (*mine, out / "calibrated.toml", out / "data.csv")}
    cases = [
        ((), r"--data-file .*measurements.csv: exists and is not a file iwr simulate wrote"),
        (("--robot-file", "../x.toml"), r"--robot-file .*x.toml: exists and is not a file iwr "
                                        r"simulate wrote"),
        (("--data-file", "../x.toml"), r"--data-file .*x.toml: exists and is not a file"),
        (("--data-file", "m.csv"), r"--truth-file .*true_errors.json: exists and is not a "
                                   r"file iwr simulate wrote \(not a true-error file"),
        (("--data-file", "m.csv", "--truth-file", "t.json", "--robot-file",
          "calibrated.toml"), r"--robot-file .*calibrated.toml: exists and is not a file"),
        (("--data-file", "data.csv", "--truth-file", "t.json"),
         r"--data-file .*data.csv: exists and is not a file iwr simulate wrote"),
        (("--data-file", "d.csv"), r"--data-file .*d.csv: is a folder; expected a file name"),
        (("--data-file", "."), r"--data-file '\.': not a file name"),
        (("--robot-file", ""), r"--robot-file '': not a file name"),
        (("--truth-file", "sub/"), r"--truth-file 'sub/': not a file name"),
    ]
    for args, pattern in cases:
        assert_fails(run("simulate", "--poses", "5", *args, cwd=out), 2, pattern)
    assert saved == {p: p.read_bytes() for p in saved}
    assert sorted(p.name for p in out.iterdir()) == ["calibrated.toml", "d.csv", "data.csv",
                                                     "measurements.csv", "true_errors.json"]
    # Its own files, again: written over (the same seed, the same bytes).
    new = tmp_path / "new"
    for _ in range(2):
        proc = run("simulate", "--poses", "5", "--out", str(new), "--robot-file", "../r.toml")
        assert proc.returncode == 0, proc.stderr
    assert (new / "measurements.csv").read_text().startswith("# iwr simulate: ")
    assert iwr.Robot.from_toml(tmp_path / "r.toml") == iwr.Robot.default()
    assert len(iwr.Measurements.from_csv(new / "measurements.csv")) == 5


def test_inputs_that_are_no_regular_file_are_refused_not_read(sim, tmp_path):
    """A named pipe as ``iwr legs``' targets or user frame, or as a result file of ``iwr
    report`` and ``iwr analyze --result``, blocked for ever (a QA run); /dev/zero ran out of
    memory ("internal error: MemoryError"). Refused by name, as data and robot files are."""
    robot, data = sim / "robot.toml", sim / "measurements.csv"
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)
    targets = tmp_path / "t.csv"
    targets.write_text("q1_mm,q2_mm,q3_rad,q4_rad,x_mm,y_mm,z_mm,alpha_rad,beta_rad,gamma_rad\n"
                       "100,50,0.1,0.05,0,0,800,0,0,0\n")
    for bad, what in ((fifo, r"pipe.csv: a named pipe \(FIFO\), not a regular file"),
                      ("/dev/zero", r"/dev/zero: a device, not a regular file")):
        for args in (["legs", str(robot), str(bad), "-o", str(tmp_path / "l.csv")],
                     ["legs", str(robot), str(targets), "--user-frame", str(bad), "-o",
                      str(tmp_path / "l.csv")],
                     ["report", str(bad), str(robot), str(data), "--out", str(tmp_path / "r")],
                     ["analyze", str(robot), str(data), "--result", str(bad)]):
            proc = run(*args)
            assert proc.returncode in (1, 2), (args, proc.stderr)
            assert re.search(what, proc.stderr), (args, proc.stderr)
            assert "Traceback" not in proc.stderr


def test_weighted_poses_all_held_out_are_named_as_such(sim, tmp_path):
    """Issue 26: "every weight is zero" when the only weighted poses all fell in the validation
    split. The poses of weight 0 are now out before the split, so a split leaves weighted poses
    on both sides or is refused: one weighted pose cannot be split, and the message says why."""
    robot = iwr.Robot.from_toml(sim / "robot.toml")
    data = iwr.Measurements.from_csv(sim / "measurements.csv", robot=robot).subset(range(20))
    # One weighted pose: with 50 % held out, some seed puts it among them.
    seed = next(s for s in range(100)
                if 0 in np.random.default_rng(s).permutation(20)[:10])
    w = np.zeros((20, 6))
    w[0] = 1.0
    weighted = iwr.Measurements(data.q, data.poses, data.legs, joint_types=data.joint_types,
                                weights=w)
    weighted.to_csv(tmp_path / "w.csv")
    proc = run("calibrate", str(sim / "robot.toml"), str(tmp_path / "w.csv"), "--method", "lm",
               "--validation-fraction", "0.5", "--seed", str(seed), "--out", str(tmp_path / "o"))
    assert_fails(proc, 1, r"--validation-fraction 0.5: leaves no pose for identification out of "
                          r"1 \(the poses with a weight > 0; 19 more have weight 0 for every "
                          r"reading")


def test_report_md_carries_no_raw_html_from_names(sim, tmp_path):
    text = (sim / "robot.toml").read_text()
    name = "<img src=x onerror=alert(1)>"
    robot = tmp_path / "r<b>.toml"
    robot.write_text(re.sub(r"(?m)^name = .*$", lambda m: f"name = {json.dumps(name)}", text,
                            count=1))
    assert name in iwr.Robot.from_toml(robot).name
    proc = run("calibrate", str(robot), str(sim / "measurements.csv"), "--method", "lm",
               "--no-plots", "--out", str(tmp_path / "o"))
    assert proc.returncode == 0, proc.stderr
    md = (tmp_path / "o" / "report.md").read_text()
    # Outside fenced code blocks (verbatim text to a Markdown viewer) no tag is left.
    outside = re.sub(r"(?ms)^```.*?^```", "", md)
    assert "<img" not in outside and "<b>" not in outside
    assert "&lt;img src=x onerror=alert(1)&gt;" in md and "r&lt;b&gt;.toml" in md


def test_a_usage_error_points_to_the_help_of_the_command_that_ran(sim):
    """A usage error raised without naming its command ended "(see 'iwr calibrate --help')"
    whatever the command (iwr analyze --target-units furlong: an outside check)."""
    proc = run("analyze", str(sim / "robot.toml"), str(sim / "measurements.csv"),
               "--target-units", "furlong")
    assert proc.returncode == 2
    assert proc.stderr.strip().endswith("(see 'iwr analyze --help')"), proc.stderr


def test_one_reader_of_whole_numbers_for_every_command():
    """``iwr compare --budget 1e4`` was refused where ``iwr study --budget 1e5`` was taken (an
    outside check): every count, budget and seed is read by iwr.cli._base.whole_number, exactly
    (no float in between), and its range checked where it is used."""
    from iwr.cli._base import whole_number
    from iwr.cli.compare import add_compare_parser
    from iwr.cli.study import _parse_budgets

    for text, want in (("10000", 10000), ("1e4", 10000), ("1.5e3", 1500), ("1_000", 1000),
                       (" 7 ", 7), ("9007199254740993", 9007199254740993),
                       ("9.007199254740993e15", 9007199254740993)):
        assert whole_number(text) == want
    for text in ("1e4.5", "abc", "1.5", "nan", "inf", ""):
        with pytest.raises(ValueError, match="not an integer|not a whole number"):
            whole_number(text)
    import argparse

    parser = argparse.ArgumentParser()
    add_compare_parser(parser.add_subparsers(dest="command"))
    assert parser.parse_args(["compare", "--budget", "1e4"]).budget == 10000
    assert _parse_budgets(["de=1e2,3e2", "lm=1e4"]) == {"de": [100, 300], "lm": [10000]}
