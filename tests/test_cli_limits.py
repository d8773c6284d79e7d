"""The command line's limits: size options refused for their memory before any work, a method's
too small budget and too few plan poses as usage errors, outputs that are files or under one, and
``iwr legs`` keeping the targets' load and temperature columns (a CLI audit's findings)."""

from __future__ import annotations

import csv
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr.cli import _base
from iwr.cli import main as cli_main

#: The address space of the subprocesses below: a command that allocates beyond it fails with
#: MemoryError instead of taking the shared machine's memory (and the check sees the limit).
_ADDRESS_SPACE = 8 * 1024**3


def _limited() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (_ADDRESS_SPACE, _ADDRESS_SPACE))


def run(*args: str, cwd: Path | None = None, timeout: float = 120):
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    return subprocess.run([sys.executable, "-m", "iwr", *args], capture_output=True, text=True,
                          cwd=cwd if cwd is not None else tempfile.gettempdir(), env=environ,
                          timeout=timeout, preexec_fn=_limited)


def refused(proc, pattern: str) -> str:
    """Exit 2, one line ``iwr: error: ...`` matching ``pattern``, no traceback."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr + proc.stdout
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("iwr: error: "), proc.stderr
    assert re.search(pattern, lines[0]), lines[0]
    return lines[0]


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim")
    proc = run("simulate", "--poses", "40", "--seed", "3", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    return out


# -- 1. sizes whose memory would not fit: exit 2 before any work --------------------------------

BIG = "1000000000000"  # 10^12: petabytes on any machine


@pytest.mark.parametrize("args, option", [
    (("simulate", "--poses", BIG, "--out", "{tmp}/out"), "--poses"),
    (("plan", "{robot}", "--n-candidates", BIG, "--out", "{tmp}/plan.csv"), "--n-candidates"),
    (("calibrate", "--poses", BIG, "--out", "{tmp}/out"), "--poses"),
    (("compare", "--methods", "lm", "--seeds", "0", "--start", "near", "--poses", "1000000000",
      "--out", "{tmp}/out"), "--poses"),
    (("compare", "--methods", "lm", "--seeds", "0", "--start", "near", "--validation-poses", BIG,
      "--out", "{tmp}/out"), "--validation-poses"),
    (("compare", "--methods", "lm", "--seeds", "0.." + BIG + "000", "--start", "near",
      "--out", "{tmp}/out"), "--seeds"),
    (("study", "--methods", "lm", "--poses", "20,1000000000", "--draws", "1", "--seeds", "1",
      "--noise", "0", "--scheduler", "synchronous", "--out", "{tmp}/out"), "--poses"),
    (("study", "--methods", "lm", "--poses", "20", "--draws", "1", "--seeds", "1", "--noise",
      "0", "--validation-poses", BIG, "--scheduler", "synchronous", "--out", "{tmp}/out"),
     "--validation-poses"),
    (("study", "--methods", "lm", "--draws", BIG, "--scheduler", "synchronous",
      "--out", "{tmp}/out"), "--draws"),
    (("study", "--methods", "lm", "--seeds", BIG, "--scheduler", "synchronous",
      "--out", "{tmp}/out"), "--seeds"),
])
def test_a_size_whose_memory_would_not_fit_is_refused_before_any_work(sim, tmp_path, args,
                                                                        option):
    """Every size option: a value whose memory no machine has is a usage error (exit 2) naming
    the option and the value, said at once (the commands allocated until they were killed for
    memory, exit 137, ran for hours, or failed with MemoryError, exit 1), and nothing is
    written."""
    values = {"robot": str(sim / "robot.toml"), "data": str(sim / "measurements.csv"),
              "tmp": str(tmp_path)}
    argv = [a.format(**values) for a in args]
    value = argv[argv.index(option) + 1]
    if option == "--poses" and argv[0] == "study":
        value = value.split(",")[-1]  # the largest of the list is named
    proc = run(*argv, timeout=60)
    line = refused(proc, rf"{re.escape(option)} {re.escape(value)}: .* would need about "
                         r"[\d.]+ [kMGTPEZY]?B of memory, more than the [\d.]+ [kMGTPEZY]?B "
                         rf"available; give a smaller {re.escape(option)}")
    assert "identifying" not in proc.stdout, line
    assert not (tmp_path / "out").exists() and not (tmp_path / "plan.csv").exists()


def test_a_budget_is_a_cap_not_an_allocation(sim, tmp_path):
    """A budget far beyond what a run takes is no memory: LM stops when it converges (an estimate
    of its history from the budget refused this run, on a machine with 24 GB)."""
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"), "--method",
               "lm", "--budget", "100000000", "--out", str(tmp_path / "out"))
    assert proc.returncode == 0, proc.stderr
    assert "converged" in proc.stdout


def test_more_threads_than_the_engine_takes_are_refused_before_any_work(sim, tmp_path):
    """--workers beyond the engine's pool (4 threads per CPU, at least 16): exit 2 naming the
    option before the data are read (it failed with exit 1, "1000000 threads asked for", once DE
    started)."""
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"), "--method",
               "de", "--budget", "600", "--workers", "1000000", "--out", str(tmp_path / "out"))
    refused(proc, r"--workers 1000000: at most \d+ threads \(4 per CPU")
    assert "identifying" not in proc.stdout and not (tmp_path / "out").exists()


def _memory(monkeypatch, available: float) -> None:
    monkeypatch.setattr(_base, "available_memory", lambda: int(available))


def _code(argv: list[str], capsys) -> tuple[int, str]:
    capsys.readouterr()
    code = cli_main(argv)
    return code, capsys.readouterr().err


def test_the_estimate_is_compared_with_the_available_memory(monkeypatch, capsys, tmp_path):
    """The check compares the command's estimate (iwr.cli._base.Footprint: what the simulation
    and its files take a pose) with the memory available: the same --poses is refused with a
    byte less than it needs and runs with a byte more."""
    need = _base.Footprint.of(iwr.Robot.default()).simulate(200)
    _memory(monkeypatch, need - 1)
    code, err = _code(["simulate", "--poses", "200", "--out", str(tmp_path / "a")], capsys)
    assert code == 2 and err.startswith("iwr: error: --poses 200: the simulated poses"), err
    assert not (tmp_path / "a").exists()
    _memory(monkeypatch, need + 1)
    code, err = _code(["simulate", "--poses", "200", "--out", str(tmp_path / "b")], capsys)
    assert code == 0, err
    assert len(iwr.Measurements.from_csv(tmp_path / "b" / "measurements.csv")) == 200


@pytest.mark.parametrize("argv, pattern", [
    (["plan", "{robot}", "--n-candidates", "1000", "--out", "{tmp}/plan.csv"],
     r"--n-candidates 1000: the candidates' Jacobians and information matrices"),
    (["plan", "{robot}", "--candidates", "{data}", "--poses", "12", "--out", "{tmp}/plan.csv"],
     r"--candidates .*measurements.csv: its 40 candidate poses'"),
    (["export", "{robot}", "--nominal", "{robot}", "--grid", "5", "--out", "{tmp}/export"],
     r"--grid 5: the leg-correction table's 15625 poses"),
    (["calibrate", "--poses", "200", "--out", "{tmp}/example"],
     r"--poses 200: the example's simulated poses and their calibration"),
    (["compare", "--methods", "lm", "--budget", "100", "--out", "{tmp}/compare"],
     r"--validation-poses 200: one run \(its poses' Jacobians"),
    (["study", "--methods", "lm", "--scheduler", "synchronous", "--out", "{tmp}/study"],
     r"--poses 100: one cell's run"),
    (["study", "--methods", "lm", "--poses", "20", "--workers", "64", "--out", "{tmp}/study"],
     r"--workers 64: 64 worker processes of about"),
])
def test_each_command_checks_its_sizes_against_the_memory(monkeypatch, capsys, sim, tmp_path,
                                                          argv, pattern):
    """On a machine with little memory left, the commands' sizes (their defaults too) are refused
    by name before any work; nothing is written. (--workers: 64 processes of a study need more
    than the 10 GB left; one does not.)"""
    _memory(monkeypatch, 10e9 if "--workers" in argv else 1e6)
    values = {"robot": str(sim / "robot.toml"), "data": str(sim / "measurements.csv"),
              "tmp": str(tmp_path)}
    code, err = _code([a.format(**values) for a in argv], capsys)
    assert code == 2, err
    assert re.match(r"iwr: error: " + pattern + r".* would need about .* of memory, more than "
                    r"the [\d.]+ [kMG]?B available", err), err
    assert len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, pattern", [
    (["compare", "--methods", "lm", "--scheduler", "local", "--poses", "20",
      "--validation-poses", "1", "--budget", "10", "--seeds", "0", "--out", "{tmp}/compare"],
     r"--scheduler local: a run on each of its 32 worker processes \(one per core\) would need "
     r"about .* run them one after the other \(--scheduler synchronous\) or on a cluster's "
     r"address"),
    (["study", "--methods", "lm", "--poses", "20", "--out", "{tmp}/study"],
     r"--workers 32 \(one per core, the default\): 32 worker processes of about .* give fewer "
     r"--workers \(at most 1\)"),
])
def test_too_many_worker_processes_name_the_processes_not_a_size(monkeypatch, capsys, tmp_path,
                                                                 argv, pattern):
    """One run fits, 32 processes (a local cluster's, one per core) do not: the refusal names
    the processes and how to have fewer (it named the largest size, already small: "give a
    smaller --poses" at --poses 20)."""
    monkeypatch.setattr(os, "cpu_count", lambda: 32)
    _memory(monkeypatch, 300e6)
    code, err = _code([a.format(tmp=str(tmp_path)) for a in argv], capsys)
    assert code == 2 and re.match(r"iwr: error: " + pattern, err), err
    assert sorted(p.name for p in tmp_path.iterdir()) == []


def test_available_memory_honours_the_address_space_limit():
    """The memory the check compares with: the machine's available memory, and no more than an
    address-space limit (ulimit -v) or a control group's limit leaves."""
    here = _base.available_memory()
    assert here is not None and here > 0
    code = ("from iwr.cli._base import available_memory; import sys; "
            "sys.stdout.write(str(available_memory()))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=tempfile.gettempdir(), preexec_fn=_limited, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert 0 < int(proc.stdout) <= _ADDRESS_SPACE


# -- 2. a budget too small for the method, too few poses to plan: exit 2, the option named -------


@pytest.mark.parametrize("method, pattern", [
    ("lm", r"--budget: 1; expected an integer >= 2 \(method lm\)"),
    ("de", r"--budget: 1; the initial population alone takes population_size \(\d+\) "
           r"evaluations \(method de\)"),
], ids=["lm", "de"])
def test_a_budget_too_small_for_the_method_is_a_usage_error(sim, tmp_path, method, pattern):
    """The method refuses the budget as it starts, before any evaluation: a bad option's value
    (exit 2) naming --budget, not "max_evaluations: ..." with exit 1; no output folder."""
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"), "--method",
               method, "--budget", "1", "--out", str(tmp_path / "out"))
    refused(proc, pattern)
    assert not (tmp_path / "out").exists()
    assert "identifying" not in proc.stdout  # before the work (it said so, then refused)
    # The example too: refused before its files are written.
    proc = run("calibrate", "--method", method, "--budget", "1", "--out", str(tmp_path / "ex"))
    refused(proc, pattern)
    assert not (tmp_path / "ex").exists()


def test_more_poses_than_candidates_are_refused_before_they_are_drawn(sim, tmp_path):
    proc = run("plan", str(sim / "robot.toml"), "--n-candidates", "20", "--poses", "30",
               "--out", str(tmp_path / "plan.csv"))
    refused(proc, r"--poses 30: more than the 20 candidates to choose from \(--n-candidates "
                  r"20\); give more candidates or fewer poses")
    proc = run("plan", str(sim / "robot.toml"), "--candidates", str(sim / "measurements.csv"),
               "--poses", "50", "--out", str(tmp_path / "plan.csv"))
    refused(proc, r"--poses: 50; expected an integer from 9 .* to 40 \(the number of "
                  r"candidates, of --candidates .*measurements.csv\)")
    assert not (tmp_path / "plan.csv").exists()


# -- 3. an output folder that is a file, or under one: exit 2, not "[Errno ...]" ----------------


@pytest.fixture(scope="module")
def calibrated(sim, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("cal")
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"), "--method",
               "lm", "--no-plots", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    return out / "calibrated.toml"


def test_an_output_folder_that_is_a_file_or_under_one_is_named(sim, calibrated, tmp_path):
    """`iwr export -o FILE` said "[Errno 17] File exists: 'FILE'" (exit 1), `-o FILE/sub` and
    `iwr study --out FILE` "[Errno 20] Not a directory" (exit 1; `iwr compare --out FILE/sub`
    too): one line naming the option and the path, exit 2, before any work."""
    afile = tmp_path / "afile"
    afile.write_text("mine\n")
    for argv, pattern in (
            (["export", str(calibrated), "-o", str(afile)],
             rf"--out {re.escape(str(afile))}: exists and is not a folder"),
            (["export", str(calibrated), "-o", str(afile / "sub")],
             rf"--out {re.escape(str(afile / 'sub'))}: cannot write there: "
             rf"{re.escape(str(afile))} is a file, not a folder"),
            (["study", "--methods", "lm", "--poses", "20", "--draws", "1", "--seeds", "1",
              "--noise", "0", "--scheduler", "synchronous", "--out", str(afile)],
             rf"--out {re.escape(str(afile))}: exists and is not a folder"),
            (["study", "--methods", "lm", "--poses", "20", "--draws", "1", "--seeds", "1",
              "--noise", "0", "--scheduler", "synchronous", "--out", str(afile / "sub")],
             r"--out .*afile/sub: cannot write there: .*afile is a file, not a folder"),
            (["study", "--report-only", "--out", str(afile)],
             rf"--out {re.escape(str(afile))}: is a file, not a study folder"),
            (["compare", "--methods", "lm", "--seeds", "0", "--start", "near", "--poses", "20",
              "--validation-poses", "10", "--out", str(afile / "sub")],
             r"--out .*afile/sub: cannot write there: .*afile is a file, not a folder")):
        refused(run(*argv), pattern)
        assert afile.read_text() == "mine\n"
    # A folder to be made is made, as before.
    proc = run("export", str(calibrated), "-o", str(tmp_path / "new" / "export"))
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "new" / "export" / "hexapod.json").is_file()


# -- 4. iwr legs with effects keeps the targets' load and temperature ----------------------------


def test_legs_keeps_the_targets_load_and_temperature_and_reads_back(tmp_path, with_effects):
    """`iwr legs` on a robot with effects wrote the commands without the targets' payload_* and
    T_C columns, so its file could not be read back as targets ("the thermal effect ... needs
    each pose's temperature"): they are kept, after the legs as in a measurement file, and the
    file read back gives the same commands."""
    with_effects.to_toml(tmp_path / "robot.toml")
    proc = run("simulate", "--robot", str(tmp_path / "robot.toml"), "--poses", "6", "--seed",
               "2", "--out", str(tmp_path / "sim"))
    assert proc.returncode == 0, proc.stderr
    targets = tmp_path / "sim" / "measurements.csv"
    robot = str(tmp_path / "sim" / "robot.toml")
    data = iwr.Measurements.from_csv(targets, robot=with_effects)
    assert data.payload is not None and data.temperatures is not None

    def read(path: Path) -> tuple[list[str], list[dict[str, str]]]:
        lines = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")]
        rows = list(csv.DictReader(lines))
        return lines[0].split(","), rows

    proc = run("legs", robot, str(targets), "-o", str(tmp_path / "legs.csv"))
    assert proc.returncode in (0, 6), proc.stderr
    head, rows = read(tmp_path / "legs.csv")
    kept = ["payload_kg", "payload_x_mm", "payload_y_mm", "payload_z_mm", "T_C"]
    assert head[-2 - len(kept):] == kept + ["out_of_stroke", "out_of_workspace"]
    assert head.index("s6_mm") < head.index("payload_kg")
    np.testing.assert_array_equal([[float(r[c]) for c in kept[:4]] for r in rows], data.payload)
    np.testing.assert_array_equal([[float(r["T_C"])] for r in rows], data.temperatures)
    # Read back as the targets were: the same commands, the same columns.
    again = run("legs", robot, str(tmp_path / "legs.csv"), "-o", str(tmp_path / "again.csv"))
    assert again.returncode == proc.returncode, again.stderr
    head2, rows2 = read(tmp_path / "again.csv")
    assert head2 == head and rows2 == rows


# -- outputs and counts refused before the work, not after (an outside audit) -------------------


def test_an_output_folder_no_file_can_be_made_in_is_refused_before_the_work(sim):
    """/proc takes no files, whatever the permissions say (root may write anywhere): the job ran
    the whole identification, then failed to make its folder (exit 1)."""
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"), "-o",
               "/proc/iwr-no-such-folder")
    refused(proc, r"--out /proc/iwr-no-such-folder: cannot write there: /proc")
    assert "identifying" not in proc.stdout


def test_a_count_beyond_int64_is_refused_by_the_parser(sim):
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"), "--method",
               "de", "--generations", "99999999999999999999", "-o", "/tmp/iwr-unused")
    refused(proc, r"argument --generations: 99999999999999999999 is beyond 9223372036854775807")
    assert "identifying" not in proc.stdout
