"""The iwr-calibrate executable, run as a user runs it: a subprocess on files written by iwr.

Checked: an interrupted (SIGTERM) and resumed run ends exactly where an uninterrupted one does;
damaged, truncated or foreign checkpoints are refused with a one-line message; the result file
loads with iwr.load_result and equals iwr.identify(method="de") with the same seed and settings;
bad arguments and bad files give one-line errors and the documented exit codes.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import iwr


def _default_sigint() -> None:
    # A shell without job control starts background commands with SIGINT ignored, and an ignored
    # signal stays ignored in children: give the executable the default so that it can handle it.
    signal.signal(signal.SIGINT, signal.SIG_DFL)

# Small problems: the whole module runs in well under a minute on two cores.
N_POSES = 12
NP = 24


def _find_exe() -> str:
    exe = shutil.which("iwr-calibrate")
    if exe is None:
        cand = Path(sys.executable).parent / "iwr-calibrate"
        if cand.exists():
            exe = str(cand)
    if exe is None:
        pytest.fail("iwr-calibrate is not installed: `pip install .` puts it next to python")
    return exe


EXE = _find_exe()


def run_exe(*args: object, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [EXE, *map(str, args)], capture_output=True, text=True, timeout=timeout, check=False
    )


def one_line_error(proc: subprocess.CompletedProcess[str]) -> str:
    """The error message, after checking that it is a single 'iwr-calibrate: error: ' line."""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("iwr-calibrate: error: "), proc.stderr
    return lines[0]


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("calib")
    robot = iwr.Robot.default()
    robot.to_toml(d / "robot.toml")
    m, _ = iwr.simulate(robot, N_POSES, seed=3)
    m.to_csv(d / "data.csv")
    # Other data: the same poses, one leg reading moved by one micrometre.
    legs = m.legs.copy()
    legs[0, 0] += 1e-3
    iwr.Measurements(m.q, m.poses, legs, joint_types=m.joint_types).to_csv(d / "other.csv")
    return {"dir": d, "robot": d / "robot.toml", "data": d / "data.csv", "other": d / "other.csv"}


def _same_run(a: iwr.IdentificationResult, b: iwr.IdentificationResult) -> None:
    np.testing.assert_array_equal(a.x, b.x)
    assert a.fun == b.fun
    assert (a.nfev, a.nit) == (b.nfev, b.nit)
    assert set(a.history) == set(b.history)
    for key in a.history:
        if key != "elapsed":  # wall-clock seconds: the only column that may differ
            np.testing.assert_array_equal(a.history[key], b.history[key], err_msg=key)


# --- interruption and resume ---------------------------------------------------------------------


COMMON = ["--population-size", NP, "--seed", 11, "--F", 0.7, "--CR", 0.9]
G = 12000  # about a second or two: long enough to be stopped part way


@pytest.fixture(scope="module")
def reference(files: dict[str, Path]) -> iwr.IdentificationResult:
    """The uninterrupted run."""
    out = files["dir"] / "full.json"
    proc = run_exe(files["robot"], files["data"], *COMMON, "--generations", G, "--threads", 2,
                   "--output", out, "--quiet")
    assert proc.returncode == 0, proc.stderr
    result = iwr.load_result(out)
    assert result.nit == G
    return result


def _start_and_stop(files: dict[str, Path], name: str, sig: int) -> Path:
    """Starts the run, waits for its first checkpoint, sends `sig`; returns the checkpoint."""
    d = files["dir"]
    ckpt = d / f"{name}.ckpt"
    proc = subprocess.Popen(  # noqa: PLW1509 (SIGINT to default: see _default_sigint)
        [EXE, str(files["robot"]), str(files["data"]), *map(str, COMMON), "--generations", str(G),
         "--threads", "1", "--output", str(d / f"{name}.json"), "--checkpoint", str(ckpt),
         "--checkpoint-every", "100", "--log", str(d / f"{name}.csv")],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
    )
    deadline = time.monotonic() + 60
    while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    assert ckpt.exists(), "no checkpoint appeared"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == (128 + sig if sig != signal.SIGKILL else -sig), err
    return ckpt


def test_sigterm_then_resume_equals_uninterrupted_run(
    files: dict[str, Path], reference: iwr.IdentificationResult
) -> None:
    d = files["dir"]
    ckpt = _start_and_stop(files, "term", signal.SIGTERM)
    partial = iwr.load_result(d / "term.json")
    assert 0 < partial.nit < G, "the run was not stopped part way"
    assert not partial.success
    assert "SIGTERM" in partial.message and "--resume" in partial.message
    # The best result so far is consistent with the log written at the same moment.
    log = np.genfromtxt(d / "term.csv", delimiter=",", names=True)
    assert log["generation"][-1] == partial.nit
    assert log["best"][-1] == partial.history["best"][-1] == partial.fun

    # Resumed on another number of threads; the output file, like the other run options, comes
    # from the checkpoint.
    resumed = run_exe(files["robot"], files["data"], "--resume", ckpt, "--threads", 2, "--quiet",
                      "--checkpoint-every", 5000)
    assert resumed.returncode == 0, resumed.stderr
    result = iwr.load_result(d / "term.json")
    _same_run(result, reference)
    assert result.success == reference.success and result.message == reference.message
    assert result.settings["resumed_from"] == str(ckpt)
    log = np.genfromtxt(d / "term.csv", delimiter=",", names=True)
    for key in ("generation", "nfev", "best", "mean", "spread"):
        np.testing.assert_array_equal(log[key], reference.history[key], err_msg=key)


def test_kill_9_loses_only_the_work_since_the_last_checkpoint(
    files: dict[str, Path], reference: iwr.IdentificationResult
) -> None:
    ckpt = _start_and_stop(files, "kill", signal.SIGKILL)
    assert not (files["dir"] / "kill.json").exists()  # no result: the process had no chance
    resumed = run_exe(files["robot"], files["data"], "--resume", ckpt, "--quiet",
                      "--checkpoint-every", 5000)
    assert resumed.returncode == 0, resumed.stderr
    _same_run(iwr.load_result(files["dir"] / "kill.json"), reference)


def test_a_finished_run_extended_equals_the_longer_run(
    files: dict[str, Path], reference: iwr.IdentificationResult
) -> None:
    d = files["dir"]
    short = run_exe(files["robot"], files["data"], *COMMON, "--generations", G // 3,
                    "--output", d / "ext.json", "--quiet")
    assert short.returncode == 0, short.stderr
    assert iwr.load_result(d / "ext.json").nit == G // 3
    longer = run_exe(files["robot"], files["data"], "--resume", d / "ext.json.ckpt",
                     "--generations", G, "--quiet")
    assert longer.returncode == 0, longer.stderr
    _same_run(iwr.load_result(d / "ext.json"), reference)


def test_sigint_and_checkpoint_on_request(files: dict[str, Path]) -> None:
    d = files["dir"]
    ckpt = d / "usr1.ckpt"
    proc = subprocess.Popen(  # noqa: PLW1509 (SIGINT to default: see _default_sigint)
        [EXE, str(files["robot"]), str(files["data"]), "--population-size", str(NP),
         "--generations", "100000000", "--checkpoint-every", "0", "--checkpoint", str(ckpt),
         "--output", str(d / "usr1.json"), "--threads", "1"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
    )
    time.sleep(0.3)
    assert not ckpt.exists()  # no periodic checkpoints
    proc.send_signal(signal.SIGUSR1)
    deadline = time.monotonic() + 30
    while not ckpt.exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert ckpt.exists(), "SIGUSR1 wrote no checkpoint"
    assert proc.poll() is None, "SIGUSR1 must not stop the run"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    res = iwr.load_result(d / "usr1.json")
    assert "SIGINT" in res.message and not res.success

    # Resuming with a smaller generation limit than already done ends at once, untouched.
    again = run_exe(files["robot"], files["data"], "--resume", ckpt, "--generations", 1, "--quiet",
                    "--output", d / "usr1b.json")
    assert again.returncode == 0, again.stderr
    res2 = iwr.load_result(d / "usr1b.json")
    np.testing.assert_array_equal(res2.x, res.x)
    assert res2.nit == res.nit


# --- damaged and foreign checkpoints -----------------------------------------------------------


@pytest.fixture(scope="module")
def checkpoint(files: dict[str, Path]) -> bytes:
    d = files["dir"]
    proc = run_exe(files["robot"], files["data"], "--population-size", NP, "--generations", 30,
                   "--seed", 5, "--output", d / "small.json", "--checkpoint", d / "small.ckpt",
                   "--quiet")
    assert proc.returncode == 0, proc.stderr
    return (d / "small.ckpt").read_bytes()


def _resume_with(files: dict[str, Path], content: bytes | None, *extra: object,
                 data: str = "data") -> subprocess.CompletedProcess[str]:
    path = files["dir"] / "bad.ckpt"
    if content is not None:
        path.write_bytes(content)
    return run_exe(files["robot"], files[data], "--resume", path, "--output",
                   files["dir"] / "bad.json", "--checkpoint", files["dir"] / "bad-out.ckpt",
                   "--quiet", *extra)


@pytest.mark.parametrize("keep", [0, 5, 31, 40, 0.5, -1])
def test_truncated_checkpoint_is_refused(files: dict[str, Path], checkpoint: bytes,
                                         keep: float) -> None:
    n = int(len(checkpoint) * keep) if isinstance(keep, float) else keep % len(checkpoint)
    proc = _resume_with(files, checkpoint[:n])
    assert proc.returncode == 1
    msg = one_line_error(proc)
    assert "bad.ckpt: " in msg
    assert ("truncated" in msg) or ("not an iwr-calibrate checkpoint" in msg and n < 8), msg


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
    assert any(w in msg for w in ("corrupt", "truncated", "not an iwr-calibrate", "version")), msg


def test_checkpoint_for_other_data_or_settings_is_refused(files: dict[str, Path],
                                                          checkpoint: bytes) -> None:
    proc = _resume_with(files, checkpoint, data="other")
    assert proc.returncode == 1
    assert "made for other data" in one_line_error(proc)

    proc = _resume_with(files, checkpoint, "--population-size", NP + 1)
    assert proc.returncode == 1
    msg = one_line_error(proc)
    assert "other settings" in msg and "population_size" in msg

    proc = _resume_with(files, checkpoint, "--seed", 6)
    assert proc.returncode == 1
    assert "seed" in one_line_error(proc)

    robot = iwr.Robot.default()
    moved = robot.with_errors(np.r_[np.zeros(robot.n_params - 1), 0.25])
    moved.to_toml(files["dir"] / "moved.toml")
    proc = run_exe(files["dir"] / "moved.toml", files["data"], "--resume", files["dir"] / "bad.ckpt")
    assert proc.returncode == 1
    assert "made for another robot" in one_line_error(proc)

    proc = _resume_with(files, None, "--seed", 5)  # the same settings again: accepted
    assert proc.returncode == 0, proc.stderr

    (files["dir"] / "missing.ckpt").unlink(missing_ok=True)
    proc = run_exe(files["robot"], files["data"], "--resume", files["dir"] / "missing.ckpt")
    assert proc.returncode == 1
    assert "missing.ckpt: no such file" in one_line_error(proc)

    proc = _resume_with(files, b"# not a checkpoint\n" * 10)
    assert proc.returncode == 1
    assert "not an iwr-calibrate checkpoint" in one_line_error(proc)


# --- the result against the Python package -------------------------------------------------------


def test_result_matches_identify(files: dict[str, Path]) -> None:
    d = files["dir"]
    robot = iwr.Robot.from_toml(files["robot"])
    m = iwr.Measurements.from_csv(files["data"])
    settings = {"population_size": NP, "F": 0.8, "CR": 0.95, "generations": 150, "seed": 9}
    proc = run_exe(files["robot"], files["data"], "--strategy", "rand1bin", "--population-size", NP,
                   "--F", 0.8, "--CR", 0.95, "--generations", 150, "--seed", 9, "--threads", 2,
                   "--output", d / "cmp.json", "--log", d / "cmp.csv", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == ""  # --quiet
    exe = iwr.load_result(d / "cmp.json")
    py = iwr.identify(robot, m, method="de", strategy="rand1bin", workers=1, progress=False,
                      polish=False, **settings)
    # The same engine on the same objective: bit-identical.
    np.testing.assert_array_equal(exe.x, py.x)
    assert exe.fun == py.fun
    assert exe.nfev == py.nfev and exe.nit == py.nit == 150
    for key in ("nfev", "best", "mean"):
        np.testing.assert_array_equal(exe.history[key], py.history[key], err_msg=key)
    assert exe.parameter_names == robot.parameter_names
    assert exe.fun == iwr.Problem(robot, m).cost(exe.x)
    assert exe.settings["population_size"] == NP and exe.settings["seed"] == 9
    raw = json.loads((d / "cmp.json").read_text())
    assert raw["format"] == "iwr-result" and raw["method"] == "de"
    log = np.genfromtxt(d / "cmp.csv", delimiter=",", names=True)
    assert list(log.dtype.names) == ["generation", "nfev", "best", "mean", "spread", "elapsed"]
    np.testing.assert_array_equal(log["best"], exe.history["best"])
    np.testing.assert_array_equal(log["generation"], np.arange(151))


def test_hexapod_robot_and_weighted_data(files: dict[str, Path], tmp_path: Path) -> None:
    """No carriage joints (42 parameters) and a CSV with weights: the same cost as Python's."""
    robot = iwr.Robot.hexapod()
    robot.to_toml(tmp_path / "hexa.toml")
    m, _ = iwr.simulate(robot, 8, seed=4)
    w = np.linspace(0.5, 2.0, m.legs.size).reshape(m.legs.shape)
    iwr.Measurements(m.q, m.poses, m.legs, joint_types="", weights=w).to_csv(tmp_path / "w.csv")
    proc = run_exe(tmp_path / "hexa.toml", tmp_path / "w.csv", "--population-size", 10,
                   "--generations", 5, "--output", tmp_path / "r.json", "--quiet")
    assert proc.returncode == 0, proc.stderr
    res = iwr.load_result(tmp_path / "r.json")
    m2 = iwr.Measurements.from_csv(tmp_path / "w.csv")
    assert len(res.x) == 42
    assert res.fun == iwr.Problem(robot, m2).cost(res.x)


# --- usage and input errors ------------------------------------------------------------------------


def test_help_documents_options_and_exit_codes() -> None:
    proc = run_exe("--help")
    assert proc.returncode == 0
    for word in ("--strategy", "--population-size", "--F", "--CR", "--generations",
                 "--target-cost", "--seed", "--threads", "--preset", "--output", "--log",
                 "--checkpoint", "--checkpoint-every", "--resume", "--quiet", "exit status",
                 "--max-evaluations", "--bounds", "--bound-rule",
                 "130", "143", "USR1", "atomic"):
        assert word in proc.stdout, word


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        ((), "expected ROBOT.toml and DATA.csv"),
        (("{robot}",), "expected ROBOT.toml and DATA.csv"),
        (("{robot}", "{data}", "--bogus"), "unknown option '--bogus'"),
        (("{robot}", "{data}", "--population-size", "many"), "--population-size: 'many'"),
        (("{robot}", "{data}", "--F", "-1"), "F"),
        (("{robot}", "{data}", "--CR", "1.5"), "CR"),
        (("{robot}", "{data}", "--strategy", "rand2exp"), "rand2exp"),
        (("{robot}", "{data}", "--seed", "-3"), "--seed"),
        (("{robot}", "{data}", "--generations"), "--generations: expected a value"),
        (("{robot}", "{data}", "--preset", "fast"), "--preset"),
        (("{robot}", "{data}", "--population-size", "2"), "population"),
        (("{robot}", "{data}", "--population-size", "50", "--max-evaluations", "49"),
         "--max-evaluations: 49; the initial population alone takes population_size (50)"),
    ],
)
def test_usage_errors(files: dict[str, Path], args: tuple[str, ...], needle: str) -> None:
    proc = run_exe(*(a.format(robot=files["robot"], data=files["data"]) for a in args))
    assert proc.returncode == 2, proc.stderr
    assert needle in one_line_error(proc)


@pytest.mark.parametrize(
    ("name", "content", "needle"),
    [
        ("robot", None, "no such file"),
        ("robot", 'name = "x"\n[hexapod]\nbase_joints = [1, 2]\n', "line 2: hexapod.leg_offsets: missing key"),
        ("robot", 'name = "x"\nflag = true\n', "line 2, column 8: booleans are not supported"),
        ("robot", "[hexapod\n", "line 1, column 9: expected ']'"),
        # A message stays on one line whatever it quotes (here a key with a newline in it).
        ("robot", '"colo\\nur" = 1\n[hexapod]\n', "line 1: colo\\nur: unknown key"),
        ("robot", 'name = "a\\\nb"\n', "line 1, column 10: a backslash before '\\n' in a string"),
        ("data", None, "no such file"),
        ("data", "# only a comment\n", "empty file"),
        ("data", "q1_mm,x_mm\n1,2\n", "line 1: missing columns"),
    ],
)
def test_bad_input_files(files: dict[str, Path], tmp_path: Path, name: str,
                         content: str | None, needle: str) -> None:
    bad = tmp_path / ("bad.toml" if name == "robot" else "bad.csv")
    if content is not None:
        bad.write_text(content)
    args = [bad, files["data"]] if name == "robot" else [files["robot"], bad]
    proc = run_exe(*args, "--output", tmp_path / "r.json")
    assert proc.returncode == 1
    msg = one_line_error(proc)
    assert (f"{bad}: " in msg or f"{bad}, line" in msg) and needle in msg, msg
    assert not (tmp_path / "r.json").exists()


def test_missing_output_folder_is_refused_before_the_run(files: dict[str, Path],
                                                         tmp_path: Path) -> None:
    proc = run_exe(files["robot"], files["data"], "--output", tmp_path / "no" / "r.json")
    assert proc.returncode == 1
    assert "folder" in one_line_error(proc) and "does not exist" in proc.stderr
    proc = run_exe(files["robot"], files["data"], "--output", tmp_path / "r.json",
                   "--log", tmp_path / "no" / "log.csv")
    assert proc.returncode == 1
    assert "log.csv: cannot write the log here" in one_line_error(proc)


def test_data_that_does_not_fit_the_robot(files: dict[str, Path], tmp_path: Path) -> None:
    m, _ = iwr.simulate(iwr.Robot.hexapod(), 5, seed=1)
    m.to_csv(tmp_path / "hexa.csv")
    proc = run_exe(files["robot"], tmp_path / "hexa.csv")
    assert proc.returncode == 1
    assert "do not match robot" in one_line_error(proc)


def test_csv_errors_name_line_and_column(files: dict[str, Path], tmp_path: Path) -> None:
    lines = files["data"].read_text().splitlines()
    header_at = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    row = lines[header_at + 2].split(",")
    row[5] = "abc"
    lines[header_at + 2] = ",".join(row)
    (tmp_path / "d.csv").write_text("\n".join(lines) + "\n")
    proc = run_exe(files["robot"], tmp_path / "d.csv")
    assert proc.returncode == 1
    msg = one_line_error(proc)
    assert f"line {header_at + 3}, column y_mm: 'abc' is not a number" in msg, msg


# --- the same inputs accepted and refused as by the Python package ------------------------------
#
# iwr-calibrate must take exactly the files that `iwr calibrate` takes (iwr.Robot.from_toml, then
# iwr.Measurements.from_csv(path, robot=robot)), and refuse the others with the same one-line
# message. Each case edits the module's files the way a user's file goes wrong.


def _data_case(files: dict[str, Path], case: str, out: Path) -> None:
    text = files["data"].read_text()
    lines = text.splitlines()
    h = next(i for i, line in enumerate(lines) if line.startswith("q1"))

    def cell(row: int, col: int, value: str) -> str:
        edited = list(lines)
        fields = edited[h + row].split(",")
        fields[col] = value
        edited[h + row] = ",".join(fields)
        return "\n".join(edited) + "\n"

    m = iwr.Measurements.from_csv(files["data"])
    scaled = {"legs in metres": (1, 1, 1e-3), "positions in metres": (1, 1e-3, 1),
              "everything in metres": (1, 1e-3, 1e-3), "joints in metres": (1e-3, 1, 1)}
    if case in scaled:
        fq, fp, fl = scaled[case]
        q, poses = m.q.copy(), m.poses.copy()
        q[:, :2] *= fq  # the prismatic joints
        poses[:, :3] *= fp
        iwr.Measurements(q, poses, m.legs * fl, joint_types=m.joint_types).to_csv(out)
        return
    if case == "angles in degrees":
        poses = m.poses.copy()
        poses[4, 3:] = np.degrees(poses[4, 3:]) + 360.0
        iwr.Measurements(m.q, poses, m.legs, joint_types=m.joint_types).to_csv(out)
        return
    if case.startswith("weights"):
        w = np.ones_like(m.legs)
        iwr.Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types, weights=w).to_csv(out)
        wl = out.read_text().splitlines()
        wh = next(i for i, line in enumerate(wl) if line.startswith("q1"))
        fields = wl[wh + 3].split(",")
        fields[-2] = {"weights nan": "nan", "weights text": "heavy", "weights empty": ""}[case]
        wl[wh + 3] = ",".join(fields)
        out.write_text("\n".join(wl) + "\n")
        return
    content: str | bytes = {
        "nan cell": lambda: cell(3, 12, "nan"),
        "nan in three rows": lambda: cell(3, 12, "nan").replace(
            lines[h + 5], lines[h + 5].replace(",", ";", 1)).replace(
            lines[h + 9], lines[h + 9] + ",1"),
        "missing column": lambda: text.replace(",s6_mm", ""),
        "unknown columns": lambda: text.replace("s6_mm", "s6_mm,w1,w2"),
        "duplicated pose": lambda: "\n".join([*lines, lines[h + 3]]) + "\n",
        "unreachable leg": lambda: cell(7, 11, "650.0"),
        "unreachable joint": lambda: cell(2, 0, "99999.0"),
        "empty file": lambda: "",
        "header only": lambda: "# a comment\n" + lines[h] + "\n",
        "not UTF-8": lambda: ("# café\n" + text).encode("latin-1"),
        "byte order mark": lambda: b"\xef\xbb\xbf" + text.encode(),
        "control character": lambda: cell(3, 5, "1\x0b5"),
        "NUL byte": lambda: cell(3, 5, "1\x005"),
    }[case]()
    if isinstance(content, bytes):
        out.write_bytes(content)
    else:
        out.write_text(content)


def _python_error(robot: Path, data: Path) -> str | None:
    """What iwr.Robot.from_toml and iwr.Measurements.from_csv say about the files (None: fine)."""
    try:
        iwr.Measurements.from_csv(data, robot=iwr.Robot.from_toml(robot))
    except ValueError as exc:
        return str(exc)
    return None


# The message, word for word as the Python package's.
# (Not "missing column", "unknown columns" and "byte order mark": Python now names the column
# order expected and accepts a byte order mark; the C++ copy of the reader does not, and goes.)
SAME_MESSAGE = [
    "nan cell", "nan in three rows", "duplicated pose",
    "unreachable leg", "unreachable joint", "legs in metres", "positions in metres",
    "everything in metres", "joints in metres", "angles in degrees", "weights nan",
    "weights text", "weights empty", "empty file", "header only",
    "control character", "NUL byte",
]


@pytest.mark.parametrize("case", SAME_MESSAGE)
def test_bad_data_refused_with_the_python_message(files: dict[str, Path], tmp_path: Path,
                                                   case: str) -> None:
    bad = tmp_path / "bad.csv"
    _data_case(files, case, bad)
    expected = _python_error(files["robot"], bad)
    assert expected is not None, f"the Python package accepts case {case!r}"
    proc = run_exe(files["robot"], bad, "--output", tmp_path / "r.json")
    assert proc.returncode == 1, proc.stderr
    assert one_line_error(proc) == f"iwr-calibrate: error: {expected}"
    assert not (tmp_path / "r.json").exists()


@pytest.mark.parametrize(
    ("case", "content", "needle"),
    [
        # Python: "cannot be read ('utf-8' codec can't decode byte 0xe9 in position 7 ...)".
        ("data", b"# caf\xe9\n", "bad.csv, line 1, column 6: byte 0xe9 is not valid UTF-8"),
        # Python: "weights: row 3, column 4 is negative" (no line).
        ("data", "weights", "bad.csv, line {line}, column w5: '-1' is negative; weights must be >= 0"),
        ("data", "folder", "bad.csv: is a folder, not a CSV file"),
        # Python lets UnicodeDecodeError through here.
        ("robot", b'name = "caf\xe9"\n', "bad.toml: line 1, column 12: byte 0xe9 is not valid UTF-8"),
        ("robot", b"\xef\xbb\xbf", "bad.toml: line 1, column 1: the file starts with a byte order mark"),
        ("robot", "folder", "bad.toml: is a folder, not a TOML file"),
    ],
)
def test_bad_files_refused_where_python_refuses_them(files: dict[str, Path], tmp_path: Path,
                                                      case: str, content: bytes | str,
                                                      needle: str) -> None:
    """Refused by both; the executable says more precisely where (line and column)."""
    bad = tmp_path / ("bad.csv" if case == "data" else "bad.toml")
    source = files["data"] if case == "data" else files["robot"]
    if content == "folder":
        bad.mkdir()
    elif content == "weights":
        m = iwr.Measurements.from_csv(files["data"])
        w = np.ones_like(m.legs)
        w[3, 4] = -1.0
        # Python's Measurements refuses negative weights too: write the file by hand.
        iwr.Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types,
                         weights=np.abs(w)).to_csv(bad)
        lines = bad.read_text().splitlines()
        h = next(i for i, line in enumerate(lines) if line.startswith("q1"))
        fields = lines[h + 4].split(",")
        fields[-2] = "-1"
        lines[h + 4] = ",".join(fields)
        bad.write_text("\n".join(lines) + "\n")
        needle = needle.format(line=h + 5)
    else:
        assert isinstance(content, bytes)
        bad.write_bytes(content + source.read_bytes())
    args = (files["robot"], bad) if case == "data" else (bad, files["data"])
    try:
        refused_by_python = _python_error(*args) is not None
    except (OSError, UnicodeDecodeError):
        refused_by_python = True
    assert refused_by_python
    proc = run_exe(*args, "--output", tmp_path / "r.json")
    assert proc.returncode == 1, proc.stderr
    msg = one_line_error(proc)
    assert needle in msg, msg


def _robot_toml_other_forms(robot: iwr.Robot) -> str:
    """The robot in the TOML forms that tomli-w does not write but tomllib reads."""
    d = robot.to_dict()

    def arr(v: object) -> str:
        if isinstance(v, list):
            return "[" + ", ".join(arr(x) for x in v) + "]"
        return repr(float(v))  # type: ignore[arg-type]

    joints = ",\n  ".join(
        f"{{type = '{j['type']}', alpha = {arr(j['alpha'])}, a = {arr(j['a'])}, d = {arr(j['d'])}, "
        f"theta = {arr(j['theta'])}, limits = {arr(j['limits'])}}}"
        for j in d["carriage"]["joints"]
    ).replace("a = 0.0,", "a = 0x0,")
    hexa = "\n".join(f"hexapod.{k} = {arr(v)}" for k, v in d["hexapod"].items())
    return (f'name = """\\\n    {d["name"]}"""\nunits = {{length = "mm", angle = \'\'\'rad\'\'\'}}\n'
            f"carriage.joints = [\n  {joints},\n]\n{hexa}\n")


def test_files_python_accepts_are_accepted(files: dict[str, Path], tmp_path: Path) -> None:
    """Other spellings of the same files: the same robot and data (by their fingerprints)."""
    def fingerprints(robot: Path, data: Path) -> tuple[str, str]:
        assert _python_error(robot, data) is None
        out = tmp_path / "fp.json"
        proc = run_exe(robot, data, "--population-size", 10, "--generations", 1, "--output", out,
                       "--quiet")
        assert proc.returncode == 0, proc.stderr
        s = iwr.load_result(out).settings
        return s["robot_fingerprint"], s["data_fingerprint"]

    reference = fingerprints(files["robot"], files["data"])
    # The robot: inline tables, an array of them, dotted keys, multi-line strings, a hex integer.
    other = tmp_path / "other.toml"
    other.write_text(_robot_toml_other_forms(iwr.Robot.default()))
    assert fingerprints(other, files["data"]) == reference
    # The data: old Mac line ends, a value with underscores, Unicode digits and a no-break space,
    # a line of Unicode whitespace.
    text = files["data"].read_text()
    lines = text.splitlines()
    h = next(i for i, line in enumerate(lines) if line.startswith("q1"))
    fields = lines[h + 2].split(",")
    digits = f"{float(fields[2])!r}"
    fields[2] = digits[:2] + "_" + digits[2:] if digits[1].isdigit() and digits[2].isdigit() else digits
    fields[6] = f"{float(fields[6])!r}".translate(str.maketrans("0123456789", "０１２３４５６７８９")) + "\xa0"
    lines[h + 2] = ",".join(fields)
    lines.insert(h + 1, "\u3000\xa0")
    data = tmp_path / "other.csv"
    data.write_bytes("\r".join(lines).encode() + b"\r")
    assert fingerprints(files["robot"], data) == reference
