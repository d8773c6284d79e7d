"""iwr-calibrate (the Python launcher) and iwr-engine (the C++ engine), run as a user runs them.

Checked: the engine runs from a problem file alone, with an empty environment; an interrupted
(SIGINT, SIGTERM, kill -9) and resumed run ends exactly where an uninterrupted one does, and equals
iwr.identify(method="de") with the same seed and settings; damaged, truncated, foreign or locked
checkpoints are refused with a one-line message; no output may overwrite an input; stale temporary
files are removed; sizes beyond the machine are refused up front; a result that is not finite is
never a success and still loads; the launcher reads ROBOT.toml DATA.csv with the package's checks
and passes signals and exit statuses through.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import resource
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr import _core
from iwr.problem_file import engine_result


def _default_sigint() -> None:
    # A shell without job control starts background commands with SIGINT ignored, and an ignored
    # signal stays ignored in children: give the programs the default so that they can handle it.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _signal_at_checkpoint(proc: subprocess.Popen, ckpt: Path, sig: int) -> str:
    """Waits (60 s at most) for the running program's first checkpoint, sends `sig`, and returns
    its stderr once it has ended."""
    deadline = time.monotonic() + 60
    while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    assert ckpt.exists(), "no checkpoint appeared"
    proc.send_signal(sig)
    return proc.communicate(timeout=60)[1]


# Small problems: the whole module runs in well under a minute on two cores.
N_POSES = 12
NP = 24


def _find(name: str) -> str:
    exe = shutil.which(name)
    cand = Path(sys.executable).parent / name
    if cand.exists():
        exe = str(cand)
    if exe is None:
        pytest.fail(f"{name} is not installed: `pip install .` puts it next to python")
    return exe


ENGINE = _find("iwr-engine")
LAUNCHER = _find("iwr-calibrate")


def run_engine(*args: object, env: dict[str, str] | None = None,
               timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([ENGINE, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, check=False, env=env)


def run_cal(*args: object, timeout: float = 120,
            cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([LAUNCHER, *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, check=False, cwd=cwd)


def one_line_error(proc: subprocess.CompletedProcess[str], prog: str = "iwr-engine") -> str:
    """The error message, after checking that it is a single 'PROG: error: ' line."""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"{prog}: error: "), proc.stderr
    return lines[0]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("calib")
    robot = iwr.Robot.default()
    robot.to_toml(d / "robot.toml")
    m, _ = iwr.simulate(robot, N_POSES, seed=3)
    m.to_csv(d / "data.csv")
    iwr.Problem(robot, m).save(d / "run.iwrp", sources={"robot": d / "robot.toml",
                                                         "data": d / "data.csv"})
    # Other data: the same poses, one leg reading moved by one micrometre.
    legs = m.legs.copy()
    legs[0, 0] += 1e-3
    other = iwr.Measurements(m.q, m.poses, legs, joint_types=m.joint_types)
    other.to_csv(d / "other.csv")
    iwr.Problem(robot, other).save(d / "other.iwrp")
    return {"dir": d, "robot": d / "robot.toml", "data": d / "data.csv", "other": d / "other.csv",
            "problem": d / "run.iwrp", "other_problem": d / "other.iwrp"}


def _same_run(a: iwr.IdentificationResult, b: iwr.IdentificationResult) -> None:
    np.testing.assert_array_equal(a.x, b.x)
    assert a.fun == b.fun
    assert (a.nfev, a.nit) == (b.nfev, b.nit)
    for key in ("generation", "nfev", "best", "mean", "spread"):  # elapsed: wall-clock seconds
        np.testing.assert_array_equal(a.history[key], b.history[key], err_msg=key)


# --- the engine alone: problem file, empty environment, interruption, resume ---------------------


SETTINGS = {"population_size": NP, "seed": 11, "F": 0.7, "CR": 0.9}
COMMON = ["--population-size", NP, "--seed", 11, "--F", 0.7, "--CR", 0.9]
G = 12000  # about a second or two: long enough to be stopped part way


@pytest.fixture(scope="module")
def reference(files: dict[str, Path]) -> iwr.IdentificationResult:
    """The same run by iwr.identify."""
    robot = iwr.Robot.from_toml(files["robot"])
    m = iwr.Measurements.from_csv(files["data"])
    return iwr.identify(robot, m, method="de", strategy="rand1bin", generations=G, workers=2,
                        polish=False, progress=False, **SETTINGS)


def _start_and_stop(files: dict[str, Path], name: str, sig: int,
                    env: dict[str, str] | None = None, problem: Path | None = None,
                    args: list[object] | None = None, every: int = 100
                    ) -> tuple[Path, str]:
    """Starts the engine on the problem file (default: files["problem"] with COMMON and G
    generations), waits for its first checkpoint, sends `sig`; the checkpoint and stderr."""
    d = files["dir"]
    ckpt = d / f"{name}.ckpt"
    if args is None:
        args = [*COMMON, "--generations", G, "--log", d / f"{name}.csv"]
    proc = subprocess.Popen(  # noqa: PLW1509 (SIGINT to default: see _default_sigint)
        [ENGINE, str(problem or files["problem"]), *map(str, args), "--threads", "1",
         "--checkpoint", str(ckpt), "--checkpoint-every", str(every)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
        env=env,
    )
    err = _signal_at_checkpoint(proc, ckpt, sig)
    assert proc.returncode == (128 + sig if sig != signal.SIGKILL else -sig), err
    return ckpt, err


def test_engine_alone_sigint_resume_equals_identify(
    files: dict[str, Path], reference: iwr.IdentificationResult
) -> None:
    """The issue's check: Problem.save, the engine under `env -i`, SIGINT, resume: bit for bit
    iwr.identify(method="de")."""
    d = files["dir"]
    empty: dict[str, str] = {}  # env -i: no PATH, no PYTHONPATH, nothing
    ckpt, _ = _start_and_stop(files, "int", signal.SIGINT, env=empty)
    partial = engine_result(ckpt, files["problem"])
    assert 0 < partial.nit < G, "the run was not stopped part way"
    assert not partial.success and "SIGINT" in partial.message
    # The engine's own resume command: it knows the problem file, the checkpoint and the log.
    assert partial.message.endswith(
        f"; continue with: iwr-engine {shlex.quote(str(files['problem']))} --resume "
        f"{shlex.quote(str(ckpt))} --log {shlex.quote(str(d / 'int.csv'))}"), partial.message
    log = np.genfromtxt(d / "int.csv", delimiter=",", names=True)
    assert log["generation"][-1] == partial.nit
    assert log["best"][-1] == partial.history["best"][-1] == partial.fun

    resumed = run_engine(files["problem"], "--resume", ckpt, "--threads", 2, "--quiet",
                         "--checkpoint-every", 5000, "--log", d / "int.csv", env=empty)
    assert resumed.returncode == 0, resumed.stderr
    result = engine_result(ckpt, files["problem"])
    _same_run(result, reference)
    assert result.success == reference.success and result.message == reference.message
    assert result.parameter_names == reference.parameter_names
    assert result.settings["resumed_from"] == str(ckpt)
    log = np.genfromtxt(d / "int.csv", delimiter=",", names=True)
    for key in ("generation", "nfev", "best", "mean", "spread"):
        np.testing.assert_array_equal(log[key], reference.history[key], err_msg=key)
    # The JSON written from it loads with iwr.load_result, unchanged.
    result.save(d / "int.json")
    _same_run(iwr.load_result(d / "int.json"), reference)


def test_kill_9_loses_only_the_work_since_the_last_checkpoint(
    files: dict[str, Path], reference: iwr.IdentificationResult
) -> None:
    ckpt, _ = _start_and_stop(files, "kill", signal.SIGKILL)
    resumed = run_engine(files["problem"], "--resume", ckpt, "--quiet", "--checkpoint-every", 5000)
    assert resumed.returncode == 0, resumed.stderr
    _same_run(engine_result(ckpt, files["problem"]), reference)


def test_launcher_sigterm_then_resume(files: dict[str, Path],
                                      reference: iwr.IdentificationResult) -> None:
    """iwr-calibrate ROBOT.toml DATA.csv: SIGTERM to the launcher reaches the engine, the exit
    status is the engine's, and the JSON result of the resumed run equals identify's."""
    d = files["dir"]
    out = d / "term.json"
    proc = subprocess.Popen(  # noqa: PLW1509
        [LAUNCHER, str(files["robot"]), str(files["data"]), *map(str, COMMON), "--generations",
         str(G), "--threads", "1", "--output", str(out), "--checkpoint-every", "100"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
    )
    ckpt = d / "term.json.ckpt"
    err = _signal_at_checkpoint(proc, ckpt, signal.SIGTERM)
    assert proc.returncode == 143, err
    assert "iwr-calibrate: interrupted by SIGTERM" in err  # the engine speaks as iwr-calibrate
    partial = iwr.load_result(out)
    assert not partial.success and 0 < partial.nit < G
    assert (d / "term.json.iwrp").is_file()
    # Resume by the checkpoint alone: the result is named after it, never taken from it.
    again = run_cal(files["robot"], files["data"], "--resume", ckpt, "--threads", 2, "--quiet")
    assert again.returncode == 0, again.stderr
    _same_run(iwr.load_result(out), reference)


def test_launcher_sigint_prints_a_resume_command_that_works(files: dict[str, Path],
                                                           tmp_path: Path) -> None:
    """Ctrl-C on iwr-calibrate ROBOT.toml DATA.csv with options the resume needs (paper bounds, a
    checkpoint not named after the result, a log) and names a shell must quote: the command it
    prints, pasted into a shell, finishes the run as if it had never been interrupted."""
    d = tmp_path / "my run"
    d.mkdir()
    shutil.copy(files["robot"], d / "robot 1.toml")
    shutil.copy(files["data"], d / "data's.csv")
    args = ["robot 1.toml", "data's.csv", "--bounds", "paper", *map(str, COMMON),
            "--generations", str(G), "--checkpoint", "state $1.ckpt", "--log", "log file.csv"]
    proc = subprocess.Popen(  # noqa: PLW1509
        [LAUNCHER, *args, "--output", "result.json", "--threads", "1", "--checkpoint-every", "100"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
        cwd=d,
    )
    ckpt = d / "state $1.ckpt"
    err = _signal_at_checkpoint(proc, ckpt, signal.SIGINT)
    assert proc.returncode == 130, err
    hints = [ln.split("; continue with: ", 1)[1] for ln in err.splitlines()
             if "; continue with: " in ln]
    assert len(hints) == 1, err
    command = hints[0]
    assert command.startswith("iwr-calibrate 'robot 1.toml' 'data'\"'\"'s.csv' "), command
    partial = iwr.load_result(d / "result.json")
    assert not partial.success and 0 < partial.nit < G and command in partial.message

    env = {**os.environ, "PATH": f"{Path(LAUNCHER).parent}{os.pathsep}{os.environ['PATH']}"}
    resumed = subprocess.run(command, shell=True, cwd=d, env=env, capture_output=True, text=True,
                             timeout=120, check=False)
    assert resumed.returncode == 0, resumed.stderr
    whole = run_cal(d / "robot 1.toml", d / "data's.csv", "--bounds", "paper", *COMMON,
                    "--generations", G, "--output", d / "whole.json", "--quiet")
    assert whole.returncode == 0, whole.stderr
    result = iwr.load_result(d / "result.json")
    assert result.nit == G
    _same_run(result, iwr.load_result(d / "whole.json"))
    log = np.genfromtxt(d / "log file.csv", delimiter=",", names=True)
    np.testing.assert_array_equal(log["best"], result.history["best"])


def test_a_finished_run_extended_equals_the_longer_run(
    files: dict[str, Path], reference: iwr.IdentificationResult
) -> None:
    d = files["dir"]
    short = run_engine(files["problem"], *COMMON, "--generations", G // 3, "--checkpoint",
                       d / "ext.ckpt", "--quiet")
    assert short.returncode == 0, short.stderr
    assert engine_result(d / "ext.ckpt").nit == G // 3
    longer = run_engine(files["problem"], "--resume", d / "ext.ckpt", "--generations", G,
                        "--quiet")
    assert longer.returncode == 0, longer.stderr
    _same_run(engine_result(d / "ext.ckpt"), reference)


def test_sigusr1_checkpoint_on_request_and_lock(files: dict[str, Path]) -> None:
    d = files["dir"]
    ckpt = d / "usr1.ckpt"
    proc = subprocess.Popen(  # noqa: PLW1509 (SIGINT to default: see _default_sigint)
        [ENGINE, str(files["problem"]), "--population-size", str(NP), "--generations", "100000000",
         "--checkpoint-every", "0", "--checkpoint", str(ckpt), "--threads", "1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
    )
    try:
        time.sleep(0.3)
        assert not ckpt.exists()  # no periodic checkpoints
        proc.send_signal(signal.SIGUSR1)
        deadline = time.monotonic() + 30
        while not ckpt.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert ckpt.exists(), "SIGUSR1 wrote no checkpoint"
        assert proc.poll() is None, "SIGUSR1 must not stop the run"
        # A second process on the same checkpoint, while the first runs: refused, not run.
        second = run_engine(files["problem"], "--resume", ckpt, "--quiet")
        assert second.returncode == 1
        assert "in use by another iwr-engine process" in one_line_error(second)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    res = engine_result(ckpt)
    assert "SIGINT" in res.message and not res.success
    # Free again once the first process ended.
    again = run_engine(files["problem"], "--resume", ckpt, "--generations", 1, "--quiet",
                       "--checkpoint", d / "usr1b.ckpt")
    assert again.returncode == 0, again.stderr
    np.testing.assert_array_equal(engine_result(d / "usr1b.ckpt").x, res.x)


# --- damaged, foreign and crafted checkpoints --------------------------------------------------


@pytest.fixture(scope="module")
def checkpoint(files: dict[str, Path]) -> bytes:
    d = files["dir"]
    proc = run_engine(files["problem"], "--population-size", NP, "--generations", 30, "--seed", 5,
                      "--checkpoint", d / "small.ckpt", "--quiet")
    assert proc.returncode == 0, proc.stderr
    return (d / "small.ckpt").read_bytes()


def _resume_with(files: dict[str, Path], content: bytes | None, *extra: object,
                 problem: str = "problem") -> subprocess.CompletedProcess[str]:
    path = files["dir"] / "bad.ckpt"
    if content is not None:
        path.write_bytes(content)
    return run_engine(files[problem], "--resume", path, "--checkpoint",
                      files["dir"] / "bad-out.ckpt", "--quiet", *extra)


@pytest.mark.parametrize("keep", [0, 5, 31, 40, 0.5, -1])
def test_truncated_checkpoint_is_refused(files: dict[str, Path], checkpoint: bytes,
                                         keep: float) -> None:
    n = int(len(checkpoint) * keep) if isinstance(keep, float) else keep % len(checkpoint)
    proc = _resume_with(files, checkpoint[:n])
    assert proc.returncode == 1
    msg = one_line_error(proc)
    assert "bad.ckpt: " in msg
    assert "truncated" in msg or "empty file" in msg, msg


@pytest.mark.parametrize("where", [0, 9, 17, 25, 40, 0.5, -1])
def test_edited_checkpoint_is_refused(files: dict[str, Path], checkpoint: bytes,
                                      where: float) -> None:
    data = bytearray(checkpoint)
    i = int(len(data) * where) if isinstance(where, float) else where % len(data)
    data[i] ^= 0x10
    proc = _resume_with(files, bytes(data))
    assert proc.returncode == 1
    msg = one_line_error(proc)
    assert "bad.ckpt: " in msg
    assert any(w in msg for w in ("corrupt", "truncated", "not an iwr-engine", "version")), msg


def test_checkpoint_for_other_data_or_settings_is_refused(files: dict[str, Path],
                                                          checkpoint: bytes) -> None:
    proc = _resume_with(files, checkpoint, problem="other_problem")
    assert proc.returncode == 1
    assert "made for other data" in one_line_error(proc)
    proc = _resume_with(files, checkpoint, "--population-size", NP + 1)
    assert proc.returncode == 1
    msg = one_line_error(proc)
    assert "other settings" in msg and "population_size" in msg
    proc = _resume_with(files, checkpoint, "--seed", 6)
    assert proc.returncode == 1 and "seed" in one_line_error(proc)
    for strategy in ("jade", "shade"):  # was "p_best: 0; strategy 'jade' needs 0 < p_best"
        proc = _resume_with(files, checkpoint, "--strategy", strategy)
        assert proc.returncode == 1
        assert one_line_error(proc).endswith(f"made with other settings (strategy {strategy} "
                                             "here, rand1bin in the checkpoint)"), proc.stderr
    proc = _resume_with(files, None, "--seed", 5)  # the same settings again: accepted
    assert proc.returncode == 0, proc.stderr
    proc = run_engine(files["problem"], "--resume", files["dir"] / "missing.ckpt")
    assert proc.returncode == 1
    assert "missing.ckpt: no such file" in one_line_error(proc)
    proc = _resume_with(files, b"# not a checkpoint\n" * 10)
    assert proc.returncode == 1
    assert "not an iwr-engine checkpoint" in one_line_error(proc)


def test_dev_zero_as_checkpoint_fails_at_once(files: dict[str, Path]) -> None:
    proc = run_engine(files["problem"], "--resume", "/dev/zero", "--checkpoint",
                      files["dir"] / "z.ckpt", timeout=20)
    assert proc.returncode == 1
    assert "/dev/zero: not a regular file" in one_line_error(proc)


# --- no lost input, no stale temporary files ---------------------------------------------------


def test_an_output_onto_an_input_is_refused(files: dict[str, Path], tmp_path: Path) -> None:
    before = {k: files[k].read_bytes() for k in ("robot", "data", "problem")}
    link = tmp_path / "link.toml"
    link.symlink_to(files["robot"])
    cases = [
        (run_cal, (files["robot"], files["data"], "--output", files["robot"]), "--output"),
        (run_cal, (files["robot"], files["data"], "--output", link), "--output"),
        (run_cal, (files["robot"], files["data"], "--output", tmp_path / "r.json",
                   "--checkpoint", files["data"]), "--checkpoint"),
        (run_cal, (files["robot"], files["data"], "--output", tmp_path / "r.json",
                   "--log", files["data"]), "--log"),
        (run_cal, (files["robot"], files["data"], "--output", tmp_path / "r.json",
                   "--problem", files["robot"]), "--problem"),
        (run_engine, (files["problem"], "--checkpoint", files["problem"]), "--checkpoint"),
        (run_engine, (files["problem"], "--log", files["problem"]), "--log"),
        # The TOML/CSV a problem was made from are inputs too (recorded in the problem file).
        (run_engine, (files["problem"], "--log", files["data"]), "--log"),
    ]
    for runner, args, opt in cases:
        proc = runner(*args)
        assert proc.returncode == 2, (args, proc.stderr)
        prog = "iwr-calibrate" if runner is run_cal else "iwr-engine"
        msg = one_line_error(proc, prog)
        assert opt in msg and "an output may not overwrite an input" in msg, msg
    assert before == {k: files[k].read_bytes() for k in ("robot", "data", "problem")}


def test_stale_temporary_files_are_removed(files: dict[str, Path], tmp_path: Path) -> None:
    ckpt = tmp_path / "t.ckpt"
    stale = [tmp_path / ".t.ckpt.a1B2c3", tmp_path / ".t.ckpt.XyZ789"]
    keep = [tmp_path / ".t.ckpt.lockx", tmp_path / ".t.ckpt.12345678", tmp_path / "t.ckpt.abcdef"]
    for p in stale + keep:
        p.write_bytes(b"left by a kill")
    proc = run_engine(files["problem"], "--population-size", NP, "--generations", 3,
                      "--checkpoint", ckpt, "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert not any(p.exists() for p in stale)
    assert all(p.exists() for p in keep)


def test_the_file_size_limit_is_an_error_naming_the_file(files: dict[str, Path],
                                                          tmp_path: Path) -> None:
    """Issue 26: at a file-size limit (ulimit -f) the engine died of SIGXFSZ (exit 153) without
    a word, leaving its temporary file; now the write fails with EFBIG, reported by name."""
    ckpt = tmp_path / "t.ckpt"

    def small_files() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))  # a checkpoint is larger

    proc = subprocess.run([ENGINE, str(files["problem"]), "--population-size", str(NP),
                           "--generations", "3", "--checkpoint", str(ckpt), "--quiet"],
                          capture_output=True, text=True, timeout=120, preexec_fn=small_files)
    assert proc.returncode == 1, (proc.returncode, proc.stderr)
    msg = one_line_error(proc)
    assert f"{ckpt}: cannot write (File too large)" in msg, msg
    assert not ckpt.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name != ".t.ckpt.lock"] == []


# --- sizes beyond the machine, threads, results that are not finite -----------------------------


def _address_space_4gb() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))


def test_huge_population_refused_up_front(files: dict[str, Path]) -> None:
    # The memory available is the least of MemAvailable, the cgroup's limit and the process's
    # address-space limit: 4 GB here, whatever the machine has.
    proc = subprocess.run(
        [ENGINE, str(files["problem"]), "--population-size", "10000000", "--checkpoint",
         str(files["dir"] / "huge.ckpt")], capture_output=True, text=True, timeout=30, check=False,
        preexec_fn=_address_space_4gb)  # noqa: PLW1509
    assert proc.returncode == 2, proc.stderr
    msg = one_line_error(proc)
    assert "--population-size: 10000000 individuals of 58 parameters need about" in msg, msg
    assert "GB of memory" in msg and "4.3 GB are available" in msg
    assert not (files["dir"] / "huge.ckpt").exists()


def test_too_many_threads_refused(files: dict[str, Path]) -> None:
    cap = max(16, 4 * len(os.sched_getaffinity(0)))
    proc = run_engine(files["problem"], "--threads", 2000)
    assert proc.returncode == 2
    assert f"--threads: 2000; at most {cap}" in one_line_error(proc)


def test_a_result_that_is_not_finite_is_never_a_success_and_loads(tmp_path: Path) -> None:
    # Written through the one writer directly (no Python check in the way): weights of 1e300 on
    # leg readings 20 m off make every cost overflow to inf.
    robot = iwr.Robot.hexapod()
    m, _ = iwr.simulate(robot, 6, seed=2)
    lo, hi = robot.default_bounds()
    data = _core._encode_problem(dict(
        robot_name="far", joint_types="", dh=np.zeros((0, 4)), joint_limits=np.zeros((0, 2)),
        base_joints=robot.base_joints, platform_joints=robot.platform_joints,
        leg_offsets=robot.leg_offsets, leg_stroke=robot.leg_stroke, home_pose=robot.home_pose,
        workspace=robot.workspace, measurement_joint_types="", kind="pose", q=np.zeros((6, 0)),
        poses=m.poses, legs=m.legs + 2e4, weights=np.full((6, 6), 1e300), lower=list(lo),
        upper=list(hi), bounds_kind="default", x0=[0.0] * 42, active=[True] * 42,
        parameter_names=robot.parameter_names, sources=[], weighting=None))
    (tmp_path / "far.iwrp").write_bytes(data)
    proc = run_engine(tmp_path / "far.iwrp", "--population-size", 10, "--generations", 3,
                      "--target-cost", 1e-3, "--quiet")
    assert proc.returncode == 0, proc.stderr
    res = engine_result(tmp_path / "far.ckpt", tmp_path / "far.iwrp")
    assert not res.success and "not finite" in res.message
    assert not np.isfinite(res.fun)  # written null in strict JSON, read as nan
    res.save(tmp_path / "far.json")
    again = iwr.load_result(tmp_path / "far.json")
    assert not np.isfinite(again.fun) and not again.success


# --- the launcher ------------------------------------------------------------------------------


def test_a_run_at_its_limit_says_how_to_go_on_and_that_works(files: dict[str, Path],
                                                              tmp_path: Path) -> None:
    """DE has no convergence test by default: a run of iwr-calibrate ends at its generation
    limit, "not converged" in the report (its message). The launcher says how far the population
    still moved over the last tenth of the run, and the command that goes on from where it
    stopped with ten times the generations, on standard error and in the result's message; that
    command, run in a shell, gives the run of that many generations made at once."""
    args = [files["robot"], files["data"], *COMMON, "--threads", 1]
    short = run_cal(*args, "--generations", 30, "--output", tmp_path / "short.json", cwd=tmp_path)
    assert short.returncode == 0, short.stderr
    lines = [ln for ln in short.stderr.splitlines() if "run it longer" in ln]
    assert len(lines) == 1, short.stderr
    assert re.search(r"over its last 3 generations the population's mean cost fell [-0-9.e+]+ % "
                     r"and the best [-0-9.e+]+ %; run it longer, from where it stopped: ", lines[0])
    command = lines[0].split("from where it stopped: ", 1)[1]
    assert command.endswith(f"--resume {tmp_path / 'short.json.ckpt'} --generations 300")
    result = iwr.load_result(tmp_path / "short.json")
    assert result.status == "stopped" and result.message.endswith(command)
    env = {**os.environ, "PATH": f"{Path(LAUNCHER).parent}{os.pathsep}{os.environ['PATH']}"}
    longer = subprocess.run(command, shell=True, cwd=tmp_path, env=env, capture_output=True,
                            text=True, timeout=120, check=False)
    assert longer.returncode == 0, longer.stderr
    whole = run_cal(*args, "--generations", 300, "--output", tmp_path / "whole.json", "--quiet")
    assert whole.returncode == 0 and whole.stderr == "", whole.stderr  # --quiet: no hint
    _same_run(iwr.load_result(tmp_path / "short.json"), iwr.load_result(tmp_path / "whole.json"))
    assert "--generations 3000" in iwr.load_result(tmp_path / "whole.json").message
    # A run of --generations 0 was told to go on with --generations 0 (ten times none): now
    # with ten times a hundred (an outside audit).
    none = run_cal(*args, "--generations", 0, "--output", tmp_path / "none.json")
    assert none.returncode == 0, none.stderr
    assert none.stderr.count("--generations 1000\n") == 1, none.stderr
    # A run that converged (its target reached) is told nothing.
    done = run_cal(*args, "--generations", 300, "--target-cost", 1e9, "--output",
                   tmp_path / "done.json")
    assert done.returncode == 0 and "run it longer" not in done.stderr, done.stderr
    assert iwr.load_result(tmp_path / "done.json").success


@pytest.mark.parametrize("strategy, mean_end, want", [
    ("rand1bin", 0.95, "fell 5 % and the best 0.9 %; run it longer, from where it stopped: "
                       "CMD --generations 2000"),
    ("rand1bin", 0.9995, "fell 0.05 % and the best 0.9 % (it has all but settled: more "
                         "generations will change the cost little); run it longer, from where "
                         "it stopped: CMD --generations 400"),
    ("jso", 0.95, "fell 5 % and the best 0.9 %; jso plans its schedules over its budget: run it "
                  "again with a larger one (e.g. --max-evaluations 2000)"),
])
def test_the_advice_follows_the_runs_last_tenth(strategy, mean_end, want) -> None:
    """How far the population still moved over its last tenth sets the advice: ten times the
    generations while it moves (1 % or more), twice once it has settled; lshade and jso get a
    new run with a larger budget. A converged run gets none."""
    from iwr.cli.calibrate_exe import longer_run

    g = np.arange(201.0)
    mean = np.where(g <= 180, 1.0, 1.0 - (1.0 - mean_end) * (g - 180) / 20)
    best = np.where(g <= 180, 0.5, 0.5 * (1.0 - 0.009 * (g - 180) / 20))
    stopped = iwr.IdentificationResult(
        x=np.zeros(2), fun=best[-1], nfev=200, nit=200, success=False, status="stopped",
        message="the maximum number of generations (200) was reached",
        history={"generation": g, "nfev": g, "best": best, "mean": mean},
        settings={"strategy": strategy, "max_evaluations": 200 if strategy == "jso" else None})
    text = longer_run(stopped, "CMD")
    assert text.startswith("over its last 20 generations the population's mean cost ")
    assert text.endswith(want), text
    stopped["status"], stopped["success"] = "converged", True
    assert longer_run(stopped, "CMD") == ""


def test_the_advice_raises_both_limits_of_a_run_that_had_both() -> None:
    """A resumed run keeps the checkpoint's limits: a run stopped at its generations with an
    evaluation cap too is told to raise both, or the continued run would stop at the cap."""
    from iwr.cli.calibrate_exe import longer_run

    g = np.arange(201.0)
    res = iwr.IdentificationResult(
        x=np.zeros(2), fun=0.5, nfev=4000, nit=200, success=False, status="stopped",
        message="the maximum number of generations (200) was reached",
        history={"generation": g, "nfev": 20 * g, "best": 1.0 - 0.001 * g,
                 "mean": 2.0 - 0.001 * g},
        settings={"strategy": "rand1bin", "generations": 200, "max_evaluations": 4100})
    assert longer_run(res, "CMD").endswith("CMD --generations 2000 --max-evaluations 40000")
    res["message"] = "the maximum number of evaluations (4100) was reached"
    assert longer_run(res, "CMD").endswith("CMD --max-evaluations 40000 --generations 2000")


def test_launcher_result_matches_identify(files: dict[str, Path]) -> None:
    d = files["dir"]
    robot = iwr.Robot.from_toml(files["robot"])
    m = iwr.Measurements.from_csv(files["data"])
    proc = run_cal(files["robot"], files["data"], "--strategy", "rand1bin", "--population-size",
                   NP, "--F", 0.8, "--CR", 0.95, "--generations", 150, "--seed", 9, "--threads", 2,
                   "--output", d / "cmp.json", "--log", d / "cmp.csv", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""  # --quiet
    exe = iwr.load_result(d / "cmp.json")
    py = iwr.identify(robot, m, method="de", strategy="rand1bin", workers=1, progress=False,
                      polish=False, population_size=NP, F=0.8, CR=0.95, generations=150, seed=9)
    np.testing.assert_array_equal(exe.x, py.x)
    assert exe.fun == py.fun == iwr.Problem(robot, m).cost(exe.x)
    assert exe.nfev == py.nfev and exe.nit == py.nit == 150
    for key in ("nfev", "best", "mean"):
        np.testing.assert_array_equal(exe.history[key], py.history[key], err_msg=key)
    assert exe.parameter_names == robot.parameter_names
    assert exe.settings["population_size"] == NP and exe.settings["seed"] == 9
    raw = json.loads((d / "cmp.json").read_text())
    assert raw["format"] == "iwr-result" and raw["method"] == "de"
    log = np.genfromtxt(d / "cmp.csv", delimiter=",", names=True)
    assert list(log.dtype.names) == ["generation", "nfev", "best", "mean", "spread", "elapsed"]
    np.testing.assert_array_equal(log["best"], exe.history["best"])
    # The problem file it wrote is the problem, with the files' provenance.
    p = iwr.Problem.load(d / "cmp.json.iwrp")
    assert p.cost(exe.x) == exe.fun
    fields = iwr.problem_file.read_problem(d / "cmp.json.iwrp")
    roles = {role: (path, sha) for role, path, sha in fields["sources"]}
    assert roles["data"][1] == iwr.problem_file.sha256_of(files["data"])
    # --export turns the checkpoint into the same JSON.
    ex = run_cal("--export", d / "cmp.json.ckpt", "--problem", d / "cmp.json.iwrp",
                 "--output", d / "cmp2.json")
    assert ex.returncode == 0, ex.stderr
    _same_run(iwr.load_result(d / "cmp2.json"), exe)


STOP_RULES = [
    {"tol": 0.2},  # SciPy's test: std(costs) <= atol + tol |mean(costs)|
    {"stagnation_generations": 20, "stagnation_tol": 1e-3},
]


@pytest.mark.parametrize("rule", STOP_RULES, ids=["tol", "stagnation"])
def test_the_engine_stops_by_identify_s_convergence_tests(files: dict[str, Path], tmp_path: Path,
                                                          rule: dict) -> None:
    """--tol/--atol and --stagnation-generations/--stagnation-tol are iwr.identify's tests: the
    same run, stopped at the same generation as a success; a resumed run keeps them."""
    robot = iwr.Robot.from_toml(files["robot"])
    m = iwr.Measurements.from_csv(files["data"])
    common = dict(strategy="rand1bin", population_size=NP, F=0.8, CR=0.95, seed=9)
    py = iwr.identify(robot, m, method="de", workers=1, progress=False, polish=False,
                      generations=400, **common, **rule)
    assert py.status == "converged" and 20 < py.nit < 400
    opts = [a for k, v in rule.items() for a in (f"--{k.replace('_', '-')}", v)]
    args = [a for k, v in common.items() for a in (f"--{k.replace('_', '-')}", v)]
    proc = run_cal(files["robot"], files["data"], *args, *opts, "--generations", 400,
                   "--threads", 2, "--output", tmp_path / "s.json", "--quiet")
    assert proc.returncode == 0, proc.stderr
    exe = iwr.load_result(tmp_path / "s.json")
    assert exe.success and exe.status == "converged" and exe.message == py.message
    np.testing.assert_array_equal(exe.x, py.x)
    assert (exe.fun, exe.nit, exe.nfev) == (py.fun, py.nit, py.nfev)
    for k, v in rule.items():
        assert exe.settings[k] == v
    # Stopped short of the test by its generations, then resumed without the options: the
    # checkpoint's tests apply, and the run ends where the whole one did.
    proc = run_cal(files["robot"], files["data"], *args, *opts, "--generations", 15,
                   "--output", tmp_path / "r.json", "--quiet")
    assert proc.returncode == 0, proc.stderr
    part = iwr.load_result(tmp_path / "r.json")
    assert part.status == "stopped" and part.nit == 15
    proc = run_cal(files["robot"], files["data"], "--resume", tmp_path / "r.json.ckpt",
                   "--generations", 400, "--quiet")
    assert proc.returncode == 0, proc.stderr
    _same_run(iwr.load_result(tmp_path / "r.json"), exe)
    # Resumed again with the same test, it stops at once; with the test off, it runs on to the
    # limit, as the same run without the test would.
    off = ["--tol", 0, "--atol", 0] if "tol" in rule else ["--stagnation-generations", 0]
    proc = run_cal(files["robot"], files["data"], "--resume", tmp_path / "r.json.ckpt",
                   "--generations", 60 + exe.nit, *off, "--quiet")
    assert proc.returncode == 0, proc.stderr
    longer = iwr.load_result(tmp_path / "r.json")
    assert longer.status == "stopped" and longer.nit == 60 + exe.nit
    whole = iwr.identify(robot, m, method="de", workers=1, progress=False, polish=False,
                         generations=60 + exe.nit, **common)
    np.testing.assert_array_equal(longer.x, whole.x)


@pytest.mark.parametrize(("option", "value", "expected"), [
    ("--tol", "-0.1", "--tol: -0.1 is negative"),
    ("--atol", "nan", "--atol: nan is not finite"),
    ("--stagnation-generations", "-1", "--stagnation-generations: -1 is out of range"),
    ("--stagnation-tol", "x", "--stagnation-tol: 'x' is not a number"),
])
def test_bad_stop_rules_are_refused_by_name(files: dict[str, Path], tmp_path: Path, option: str,
                                            value: str, expected: str) -> None:
    proc = run_cal(files["problem"], option, value, "--output", tmp_path / "b.json")
    assert proc.returncode == 2
    assert expected in proc.stderr, proc.stderr


def test_launcher_paper_bounds(files: dict[str, Path], tmp_path: Path) -> None:
    proc = run_cal(files["robot"], files["data"], "--bounds", "paper", "--population-size", NP,
                   "--generations", 2, "--output", tmp_path / "p.json", "--quiet")
    assert proc.returncode == 0, proc.stderr
    res = iwr.load_result(tmp_path / "p.json")
    assert res.settings["bounds"] == "paper"
    np.testing.assert_array_equal(res.settings["upper"], np.full(58, 0.5))
    assert iwr.problem_file.read_problem(tmp_path / "p.json.iwrp")["bounds_kind"] == "paper"


def test_hexapod_robot_and_weighted_data(tmp_path: Path) -> None:
    """No carriage joints (42 parameters) and a CSV with weights: the same cost as Python's."""
    robot = iwr.Robot.hexapod()
    robot.to_toml(tmp_path / "hexa.toml")
    m, _ = iwr.simulate(robot, 8, seed=4)
    w = np.linspace(0.5, 2.0, m.legs.size).reshape(m.legs.shape)
    iwr.Measurements(m.q, m.poses, m.legs, joint_types="", weights=w).to_csv(tmp_path / "w.csv")
    proc = run_cal(tmp_path / "hexa.toml", tmp_path / "w.csv", "--population-size", 10,
                   "--generations", 5, "--output", tmp_path / "r.json", "--quiet")
    assert proc.returncode == 0, proc.stderr
    res = iwr.load_result(tmp_path / "r.json")
    m2 = iwr.Measurements.from_csv(tmp_path / "w.csv")
    assert len(res.x) == 42
    assert res.fun == iwr.Problem(robot, m2).cost(res.x)


def test_help_documents_options_and_exit_codes() -> None:
    for proc in (run_engine("--help"), run_cal("--help")):
        assert proc.returncode == 0
        for word in ("--strategy", "--population-size", "--F", "--CR", "--generations",
                     "--target-cost", "--seed", "--threads", "--preset", "--log",
                     "--checkpoint", "--checkpoint-every", "--resume", "--quiet", "exit status",
                     "--max-evaluations", "--bound-rule", "130", "143", "USR1", "atomic",
                     "PROBLEM.iwrp"):
            assert word in proc.stdout, word
    cal = run_cal("--help").stdout
    for word in ("ROBOT.toml DATA.csv", "--bounds", "--output", "--problem", "--export"):
        assert word in cal, word


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        ((), "expected PROBLEM.iwrp"),
        (("{problem}", "{problem}"), "unexpected argument"),
        (("{problem}", "--bogus"), "unknown option '--bogus'"),
        (("{problem}", "--output", "x.json"), "an option of iwr-calibrate"),
        (("{problem}", "--population-size", "many"), "--population-size: 'many'"),
        (("{problem}", "--F", "-1"), "F"),
        (("{problem}", "--CR", "1.5"), "CR"),
        (("{problem}", "--strategy", "rand2exp"), "rand2exp"),
        (("{problem}", "--seed", "-3"), "--seed"),
        (("{problem}", "--generations"), "--generations: expected a value"),
        (("{problem}", "--preset", "fast"), "--preset"),
        (("{problem}", "--population-size", "2"), "population"),
        (("{problem}", "--population-size", "50", "--max-evaluations", "49"),
         "--max-evaluations: 49; the initial population alone takes population_size (50)"),
    ],
)
def test_engine_usage_errors(files: dict[str, Path], args: tuple[str, ...], needle: str) -> None:
    proc = run_engine("--checkpoint", files["dir"] / "usage.ckpt",
                      *(a.format(problem=files["problem"]) for a in args))
    assert proc.returncode == 2, proc.stderr
    assert needle in one_line_error(proc)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        ((), "expected ROBOT.toml and DATA.csv, or PROBLEM.iwrp"),
        (("{robot}", "{data}", "--bounds", "wide"), "--bounds: 'wide'"),
        (("{problem}", "--bounds", "paper"), "--bounds: the bounds of a problem file"),
        (("{robot}", "{data}", "--resume", "run.state"), "give --output"),
        (("--export", "x.ckpt"), "--output"),
        (("{robot}", "{data}", "--populaton-size", "50"), "unknown option '--populaton-size'"),
    ],
)
def test_launcher_usage_errors(files: dict[str, Path], args: tuple[str, ...],
                               needle: str) -> None:
    proc = run_cal(*(a.format(**{k: str(v) for k, v in files.items()}) for a in args))
    assert proc.returncode == 2, proc.stderr
    assert needle in one_line_error(proc, "iwr-calibrate")


def test_launcher_bad_input_files_use_the_package_messages(files: dict[str, Path],
                                                           tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[hexapod\n")
    proc = run_cal(bad, files["data"], "--output", tmp_path / "r.json")
    assert proc.returncode == 1
    msg = one_line_error(proc, "iwr-calibrate")
    with pytest.raises(ValueError) as info:
        iwr.Robot.from_toml(bad)
    assert msg == "iwr-calibrate: error: " + " ".join(str(info.value).split())
    assert not (tmp_path / "r.json").exists() and not (tmp_path / "r.json.iwrp").exists()
    m, _ = iwr.simulate(iwr.Robot.hexapod(), 5, seed=1)
    m.to_csv(tmp_path / "hexa.csv")
    proc = run_cal(files["robot"], tmp_path / "hexa.csv", "--output", tmp_path / "r.json")
    assert proc.returncode == 1
    assert "do not match robot" in one_line_error(proc, "iwr-calibrate")
    proc = run_cal(files["robot"], files["data"], "--output", tmp_path / "no" / "r.json")
    assert proc.returncode == 1
    assert "folder" in one_line_error(proc, "iwr-calibrate") and "does not exist" in proc.stderr


def test_bad_problem_files_are_refused(files: dict[str, Path], tmp_path: Path) -> None:
    good = files["problem"].read_bytes()
    cases = {
        "cut.iwrp": (good[: len(good) // 2], "truncated"),
        "flip.iwrp": (good[:100] + bytes([good[100] ^ 1]) + good[101:], "checksum mismatch"),
        "text.iwrp": (b"q1_mm,q2_mm\n1,2\n", "not an iwr problem file"),
    }
    for name, (content, needle) in cases.items():
        (tmp_path / name).write_bytes(content)
        proc = run_engine(tmp_path / name)
        assert proc.returncode == 1
        msg = one_line_error(proc)
        assert f"{tmp_path / name}: " in msg and needle in msg, msg
    proc = run_engine(tmp_path / "missing.iwrp")
    assert proc.returncode == 1 and "missing.iwrp: no such file" in one_line_error(proc)


def test_launcher_lock_is_visible_to_flock(files: dict[str, Path], tmp_path: Path) -> None:
    """The lock a run holds is a plain flock on .NAME.lock: another tool can see it."""
    ckpt = tmp_path / "l.ckpt"
    lock = tmp_path / ".l.ckpt.lock"
    with open(lock, "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        proc = run_engine(files["problem"], "--checkpoint", ckpt, "--generations", 2, "--quiet")
    assert proc.returncode == 1 and "in use by another iwr-engine process" in proc.stderr
    proc = run_engine(files["problem"], "--checkpoint", ckpt, "--generations", 2, "--quiet")
    assert proc.returncode == 0, proc.stderr


def test_a_second_launcher_leaves_the_running_jobs_record(files: dict[str, Path],
                                                          tmp_path: Path) -> None:
    """Issue 26: a second iwr-calibrate on the same --output wrote its problem file (the running
    job's record) before the engine's lock refused it; the first run then ended "made for another
    problem". The launcher now takes the lock first and writes nothing."""
    out = tmp_path / "r.json"
    problem = tmp_path / "r.json.iwrp"
    # The running job's record, a problem file (another file there is refused before the lock).
    record = files["other_problem"].read_bytes()
    problem.write_bytes(record)
    with open(tmp_path / ".r.json.ckpt.lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)  # as the running engine holds it
        proc = run_cal(files["robot"], files["other"], "--output", out, "--generations", 2)
    assert proc.returncode == 1, proc.stderr
    msg = one_line_error(proc, "iwr-calibrate")
    assert "r.json.ckpt: in use by another iwr-engine process" in msg
    assert "nothing was written" in msg
    assert problem.read_bytes() == record and not out.exists()


def test_export_onto_the_problem_read_is_refused(files: dict[str, Path], tmp_path: Path) -> None:
    problem = tmp_path / "r.iwrp"
    problem.write_bytes(files["problem"].read_bytes())
    proc = run_cal("--export", tmp_path / "r.ckpt", "--problem", problem, "--output", problem)
    assert proc.returncode == 2
    assert "is the problem file read; an output may not overwrite an input" in one_line_error(
        proc, "iwr-calibrate")
    assert problem.read_bytes() == files["problem"].read_bytes()


def test_no_output_over_the_run_s_files_a_folder_or_a_file_iwr_did_not_write(
        files: dict[str, Path], tmp_path: Path) -> None:
    """A QA run: `--export CKPT --output robot.toml`, `PROBLEM.iwrp --resume CKPT --output
    data.csv` and `--log` onto a CSV of the user's exited 0 with the file replaced, and
    `--output DIR` failed only after the whole run ("Is a directory"). Refused now, exit 2,
    before any work; iwr's own files (a result, a checkpoint, a log) are written over as before."""
    robot, data = tmp_path / "robot.toml", tmp_path / "data.csv"
    robot.write_bytes(files["robot"].read_bytes())
    data.write_bytes(files["data"].read_bytes())
    run = run_cal(robot, data, "--population-size", 10, "--generations", 2, "--output", "r.json",
                  "--log", "r.log", "--quiet", cwd=tmp_path)
    assert run.returncode == 0, run.stderr
    mine = tmp_path / "mine.csv"
    mine.write_text("the user's own file\n")
    (tmp_path / "d").mkdir()
    saved = {p: p.read_bytes() for p in (robot, data, mine)}
    cases = [
        (("--export", "r.json.ckpt", "--output", "robot.toml"),
         "--output: robot.toml exists and is not a file iwr wrote (not an iwr result)"),
        (("--export", "r.json.ckpt", "--problem", "r.json.iwrp", "--output", "data.csv"),
         "--output: data.csv is the data file the problem was made from"),
        (("r.json.iwrp", "--resume", "r.json.ckpt", "--generations", 4, "--output", "data.csv"),
         "--output: data.csv is the data file the problem was made from"),
        (("r.json.iwrp", "--generations", 4, "--output", "r2.json", "--log", "robot.toml"),
         "--log: robot.toml is the robot file the problem was made from"),
        ((robot, data, "--generations", 2, "--output", "r2.json", "--log", "mine.csv"),
         "--log: mine.csv exists and is not a file iwr wrote (not an iwr-engine log)"),
        ((robot, data, "--generations", 2, "--output", "r2.json", "--problem", "mine.csv"),
         "--problem: mine.csv exists and is not a file iwr wrote"),
        ((robot, data, "--generations", 2, "--output", "r2.json", "--checkpoint", "mine.csv"),
         "--checkpoint: mine.csv exists and is not a file iwr wrote"),
        ((robot, data, "--generations", 2, "--output", "mine.csv"),
         "--output: mine.csv exists and is not a file iwr wrote"),
        ((robot, data, "--generations", 2, "--output", "d"), "--output: d is a folder"),
        ((robot, data, "--generations", 2, "--output", "."), "--output: . is a folder"),
        ((robot, data, "--generations", 2, "--output", "r2.json", "--checkpoint", "d"),
         "--checkpoint: d is a folder"),
        (("--export", "r.json.ckpt", "--output", "d"), "--output: d is a folder"),
    ]
    for args, needle in cases:
        proc = run_cal(*args, cwd=tmp_path)
        assert proc.returncode == 2, (args, proc.stderr)
        assert needle in one_line_error(proc, "iwr-calibrate"), (args, proc.stderr)
    assert saved == {p: p.read_bytes() for p in saved}
    assert not any(p.name.startswith(("r2.json", "..", ".d.")) for p in tmp_path.iterdir())
    # iwr's own files are written over: the result, problem file, checkpoint and log of a run.
    for args in ((robot, data, "--population-size", 10, "--generations", 2, "--output",
                  "r.json", "--log", "r.log", "--quiet"),
                 ("r.json.iwrp", "--resume", "r.json.ckpt", "--generations", 3, "--output",
                  "r.json", "--log", "r.log", "--quiet"),
                 ("--export", "r.json.ckpt", "--problem", "r.json.iwrp", "--output", "r.json")):
        proc = run_cal(*args, cwd=tmp_path)
        assert proc.returncode == 0, (args, proc.stderr)
    assert iwr.load_result(tmp_path / "r.json").nit == 3


def test_launcher_resume_keeps_the_run_problem(files: dict[str, Path], tmp_path: Path) -> None:
    """Resuming with other data is refused before the run's problem file is replaced."""
    run = run_cal(files["robot"], files["data"], "--population-size", NP, "--generations", 3,
                  "--output", tmp_path / "k.json", "--quiet")
    assert run.returncode == 0, run.stderr
    before = (tmp_path / "k.json.iwrp").read_bytes()
    proc = run_cal(files["robot"], files["other"], "--resume", tmp_path / "k.json.ckpt")
    assert proc.returncode == 1
    msg = one_line_error(proc, "iwr-calibrate")
    assert "k.json.iwrp: the problem of the run being resumed" in msg and "legs" in msg, msg
    assert (tmp_path / "k.json.iwrp").read_bytes() == before
    # The same files again: accepted (the problem file rewritten identically).
    proc = run_cal(files["robot"], files["data"], "--resume", tmp_path / "k.json.ckpt",
                   "--generations", 5, "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert iwr.load_result(tmp_path / "k.json").nit == 5


def test_one_version_everywhere() -> None:
    """The version is written once (pyproject.toml): the package and the engine report it."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    version = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]["version"]
    assert iwr.__version__ == version
    proc = run_engine("--version")
    assert proc.returncode == 0 and proc.stdout.split()[1] == version, proc.stdout


# --- laser-tracker data: points and probe poses in the tracker frame ---------------------------

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TRACKER_NP = 20
TRACKER_G = 4000  # long enough to be stopped part way
REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, 1.5707963267948966, 0.0, 0.0)


@pytest.fixture(scope="module")
def tracker_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Point data (one reflector in five hidden) and probe data of 10 poses, their TOML and CSV
    files, and the point problem's file as iwr-calibrate writes it."""
    from iwr.tracker.api import tracker_problem, tracker_simulate
    from iwr.tracker.files import write_tracker_wide

    d = tmp_path_factory.mktemp("tracker")
    out: dict[str, Path] = {"dir": d}
    base = iwr.Robot.default()
    for kind, robot in (
        ("points", base.with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)),
        ("probe", base.with_tracker(registration=REGISTRATION,
                                    probe=(5.0, 0.0, 60.0, 0.0, 0.1, 0.0))),
    ):
        m, _ = tracker_simulate(robot, 10, seed=4, hidden=0.2 if kind == "points" else 0.0)
        robot.to_toml(d / f"{kind}.toml")
        write_tracker_wide(d / f"{kind}.csv", robot.tracker, m)
        out[kind + "_robot"], out[kind + "_data"] = d / f"{kind}.toml", d / f"{kind}.csv"
    robot = iwr.Robot.from_toml(out["points_robot"])
    from iwr.tracker.files import read_tracker_data

    problem, x0 = tracker_problem(robot, read_tracker_data(out["points_data"], robot.tracker))
    problem.save(d / "points.iwrp", x0=x0, sources={"robot": out["points_robot"],
                                                     "data": out["points_data"]})
    out["points_problem"] = d / "points.iwrp"
    return out


def _tracker_identify(robot_path: Path, data_path: Path, **settings: object
                      ) -> iwr.IdentificationResult:
    """iwr.identify(method="de") on the files, DE alone (iwr-calibrate does not polish)."""
    from iwr.tracker.files import read_tracker_data

    robot = iwr.Robot.from_toml(robot_path)
    data = read_tracker_data(data_path, robot.tracker)
    return iwr.identify(robot, data, method="de", polish=False, progress=False, **settings)


def test_tracker_engine_sigint_resume_equals_uninterrupted_and_identify(
        tracker_files: dict[str, Path]) -> None:
    """Point data with hidden reflectors through the engine: SIGINT part way, resume, and the
    result equals an uninterrupted engine run and iwr.identify(method="de"), bit for bit."""
    d, problem = tracker_files["dir"], tracker_files["points_problem"]
    common = ["--population-size", TRACKER_NP, "--seed", 5, "--strategy", "jade",
              "--generations", TRACKER_G]
    ckpt, err = _start_and_stop(tracker_files, "int", signal.SIGINT, problem=problem,
                                args=common, every=50)
    assert "73 parameters, 15 of them the tracker setup's, 10 poses (points in the tracker " \
           "frame)" in err
    partial = engine_result(ckpt, problem)
    assert 0 < partial.nit < TRACKER_G and not partial.success and "SIGINT" in partial.message
    resumed = run_engine(problem, "--resume", ckpt, "--threads", 2, "--quiet")
    assert resumed.returncode == 0, resumed.stderr
    result = engine_result(ckpt, problem)

    straight = run_engine(problem, *common, "--threads", 2, "--checkpoint", d / "straight.ckpt",
                          "--quiet")
    assert straight.returncode == 0, straight.stderr
    _same_run(result, engine_result(d / "straight.ckpt", problem))

    py = _tracker_identify(tracker_files["points_robot"], tracker_files["points_data"],
                           strategy="jade", population_size=TRACKER_NP, seed=5,
                           generations=TRACKER_G, workers=2)
    _same_run(result, py)
    assert result.parameter_names == py.parameter_names
    assert result.parameter_names[-3:] == ["reflector3.x", "reflector3.y", "reflector3.z"]
    assert result.settings["measurements"] == "points"


@pytest.mark.parametrize("kind", ["points", "probe"])
def test_tracker_launcher_equals_identify(tracker_files: dict[str, Path], kind: str) -> None:
    """iwr-calibrate ROBOT.toml DATA.csv on point and probe data: the result JSON equals
    iwr.identify(method="de") with the same settings, and its cost the problem's."""
    d = tracker_files["dir"]
    out = d / f"launch-{kind}.json"
    proc = run_cal(tracker_files[kind + "_robot"], tracker_files[kind + "_data"], "--strategy",
                   "rand1bin", "--population-size", TRACKER_NP, "--F", 0.8, "--CR", 0.95,
                   "--generations", 40, "--seed", 9, "--threads", 2, "--output", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    exe = iwr.load_result(out)
    py = _tracker_identify(tracker_files[kind + "_robot"], tracker_files[kind + "_data"],
                           strategy="rand1bin", population_size=TRACKER_NP, F=0.8, CR=0.95,
                           generations=40, seed=9, workers=1)
    _same_run(exe, py)
    problem = iwr.Problem.load(out.with_suffix(".json.iwrp"))
    assert problem.setup.kind == kind
    assert exe.fun == problem.cost(exe.x)
    assert exe.parameter_names == problem.parameter_names
    assert len(exe.x) == 58 + (15 if kind == "points" else 12)


def test_tracker_active_set_and_x0_reach_the_engine(tracker_files: dict[str, Path]) -> None:
    """A problem file with parameters held fixed (at x0): the engine searches the others only,
    as iwr.identify(active=..., x0=...) does."""
    from iwr.tracker.api import tracker_problem

    d = tracker_files["dir"]
    loaded = iwr.Problem.load(tracker_files["points_problem"])
    x0 = np.asarray(iwr.problem_file.read_problem(tracker_files["points_problem"])["x0"])
    x0[:58] = np.random.default_rng(2).uniform(-0.01, 0.01, 58)
    active = np.zeros(loaded.n_params, dtype=bool)
    active[40:] = True  # the hexapod's offsets, the registration and the reflectors
    problem, _ = tracker_problem(loaded.robot, loaded.measurements, x0=x0)
    problem.save(d / "active.iwrp", x0=x0, active=active)
    proc = run_engine(d / "active.iwrp", "--population-size", TRACKER_NP, "--generations", 30,
                      "--seed", 3, "--threads", 1, "--checkpoint", d / "active.ckpt", "--quiet")
    assert proc.returncode == 0, proc.stderr
    exe = engine_result(d / "active.ckpt", d / "active.iwrp")
    py = iwr.identify(loaded.robot, loaded.measurements, method="de", polish=False,
                      progress=False, population_size=TRACKER_NP, generations=30, seed=3,
                      workers=1, x0=x0, active=active)
    _same_run(exe, py)
    np.testing.assert_array_equal(exe.x[:40], x0[:40])
    np.testing.assert_array_equal(exe.active, active)
    # Another active set is another problem: its checkpoint is refused.
    proc = run_engine(tracker_files["points_problem"], "--resume", d / "active.ckpt",
                      "--checkpoint", d / "other.ckpt")
    assert proc.returncode == 1 and "made for another robot" in one_line_error(proc)


def test_tracker_result_without_forward_kinematics_is_a_failure(
        tracker_files: dict[str, Path]) -> None:
    """Held leg offsets 1 m short (negative leg lengths): no pose has forward kinematics at any
    point searched, so every cost is the penalty, and even a run that reaches its target cost is
    no success; the message names a pose."""
    d = tracker_files["dir"]
    loaded = iwr.Problem.load(tracker_files["points_problem"])
    x0 = np.zeros(loaded.n_params)
    x0[52:58] = -1000.0  # leg1.dl0 .. leg6.dl0
    active = np.zeros(loaded.n_params, dtype=bool)
    active[58:64] = True  # the registration only
    loaded.save(d / "nofk.iwrp", x0=x0, active=active)
    proc = run_engine(d / "nofk.iwrp", "--population-size", 8, "--generations", 2,
                      "--target-cost", 1e300, "--checkpoint", d / "nofk.ckpt", "--quiet")
    assert proc.returncode == 0, proc.stderr
    res = engine_result(d / "nofk.ckpt", d / "nofk.iwrp")
    assert not res.success
    assert "10 of 10 poses have no forward kinematics at the result (pose 0:" in res.message
    # The penalty, 1000 mm on each seen coordinate.
    assert res.fun == loaded.cost(res.x) == 1e6 * loaded.n_observations


def test_tracker_launcher_resume_keeps_the_run_problem(tracker_files: dict[str, Path],
                                                       tmp_path: Path) -> None:
    """Resuming tracker data: the same files are accepted (NaN mask and guess rewritten
    identically); other data are refused before the run's problem file is replaced."""
    robot, data = tracker_files["points_robot"], tracker_files["points_data"]
    run = run_cal(robot, data, "--population-size", TRACKER_NP, "--generations", 3,
                  "--output", tmp_path / "k.json", "--quiet")
    assert run.returncode == 0, run.stderr
    before = (tmp_path / "k.json.iwrp").read_bytes()
    proc = run_cal(robot, data, "--resume", tmp_path / "k.json.ckpt", "--generations", 6,
                   "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert iwr.load_result(tmp_path / "k.json").nit == 6
    assert (tmp_path / "k.json.iwrp").read_bytes() == before
    lines = data.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("3,"))
    cells = lines[k].split(",")
    cells[5] = repr(float(cells[5]) + 1e-3)  # s1_mm of pose 3, one micrometre longer
    lines[k] = ",".join(cells)
    (tmp_path / "other.csv").write_text("\n".join(lines) + "\n")
    proc = run_cal(robot, tmp_path / "other.csv", "--resume", tmp_path / "k.json.ckpt")
    assert proc.returncode == 1
    msg = one_line_error(proc, "iwr-calibrate")
    assert "k.json.iwrp: the problem of the run being resumed" in msg and "legs" in msg, msg
    assert (tmp_path / "k.json.iwrp").read_bytes() == before


def test_a_second_launcher_is_refused_before_the_first_ones_engine_runs(
        files: dict[str, Path], tmp_path: Path) -> None:
    """Issue 26's campaign: the first launcher releases the checkpoint's lock just before its
    engine takes it; a second launcher in between took the lock, wrote its problem file over the
    first's and ran, the first ending with exit 1. The first launcher's engine is made slow to
    start here (a wrapper that waits 3 s), so the second always comes in that gap."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    shutil.copy(LAUNCHER, bin_dir / "iwr-calibrate")
    slow = bin_dir / "iwr-engine"
    slow.write_text(f'#!/bin/sh\nsleep 3\nexec "{ENGINE}" "$@"\n')
    slow.chmod(0o755)
    out = tmp_path / "r.json"
    first = subprocess.Popen(  # noqa: PLW1509 (SIGINT to default: see _default_sigint)
        [str(bin_dir / "iwr-calibrate"), str(files["robot"]), str(files["data"]), "--output",
         str(out), "--generations", "100000", "--population-size", str(NP), "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    try:
        problem = Path(str(out) + ".iwrp")
        deadline = time.monotonic() + 60
        while not problem.exists() and time.monotonic() < deadline and first.poll() is None:
            time.sleep(0.01)
        assert problem.exists(), first.stderr.read() if first.poll() is not None else "no file"
        record = problem.read_bytes()
        second = run_cal(files["robot"], files["other"], "--output", out, "--generations", 2)
        assert second.returncode == 1, second.stderr
        assert "r.json.ckpt: in use by another iwr-calibrate process" in one_line_error(
            second, "iwr-calibrate")
        assert problem.read_bytes() == record
    finally:
        first.send_signal(signal.SIGINT)
        _, err = first.communicate(timeout=120)
    assert first.returncode == 130, err  # stopped in its wrapper's wait: nothing to export


def test_a_weighted_run_s_fit_is_tested_before_it_is_written(tmp_path: Path) -> None:
    """``--noise``: the cost is the fit's chi-square statistic. A run that its stagnation test
    stopped far above the noise floor was written "converged", success true, until ``iwr
    report`` refused it; the result now says failed, with the fit test's verdict, and the
    launcher says so."""
    robot = iwr.Robot.default()
    robot.to_toml(tmp_path / "robot.toml")
    m, _ = iwr.simulate(robot, 30, seed=4, noise=iwr.Noise.realistic())
    m.to_csv(tmp_path / "data.csv")
    proc = run_cal(tmp_path / "robot.toml", tmp_path / "data.csv", "--noise", "realistic",
                   "--population-size", 30, "--generations", 400, "--stagnation-generations", 5,
                   "--stagnation-tol", 0.5, "--seed", 1, "--output", tmp_path / "r.json")
    assert proc.returncode == 0, proc.stderr
    res = iwr.load_result(tmp_path / "r.json")
    assert res.fit is not None and res.fit.p_value < 1e-3 and res.fun > 1e3
    assert not res.success and res.status == "failed", res.message
    assert "THE MODEL DOES NOT FIT THE DATA" in proc.stderr
