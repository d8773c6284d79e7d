"""iwr.Problem.save / iwr.Problem.load (iwr/problem_file.py, cpp/src/problem_file.cpp), and the
thread pool behind Problem.cost_batch: a thread the system refuses, too many threads, fork()."""

from __future__ import annotations

import math
import os
import resource
import signal
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import iwr
from iwr import _core
from iwr.problem_file import FormatError, read_problem, sha256_of


@pytest.fixture(scope="module")
def problem() -> iwr.Problem:
    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, 9, seed=5)
    w = np.linspace(0.5, 2.0, m.legs.size).reshape(m.legs.shape)
    m = iwr.Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types, weights=w)
    return iwr.Problem(robot, m, bounds="paper")


def test_round_trip_is_exact(kind: Any, tmp_path: Path) -> None:
    """Every kind (the engine takes each): the problem read back is the same problem (its kind,
    rows, measured values, bounds and names; its objective bit for bit), and saving it again
    writes the same bytes; the search start is part of the robot's fingerprint."""
    assert kind.kind.engine
    problem, x0 = kind.kind.problem(kind.robot, kind.data)
    active = np.ones(problem.n_params, dtype=bool)
    active[[5, problem.n_params - 1]] = False
    path = tmp_path / "p.iwrp"
    problem.save(path, x0=x0, active=active)
    back = iwr.Problem.load(path)
    assert type(back) is type(problem) and iwr.kinds.of(back.measurements) is kind.kind
    assert back.measurements.joint_types == kind.data.joint_types == back.robot.joint_types
    for part in (kind.kind.rows, kind.kind.measured):
        np.testing.assert_array_equal(part(back.measurements), part(kind.data))
    np.testing.assert_array_equal(back.lower, problem.lower)
    np.testing.assert_array_equal(back.upper, problem.upper)
    assert back.parameter_names == problem.parameter_names
    d = read_problem(path)
    assert d["kind"] == kind.name and d["bounds_kind"] == "default"
    np.testing.assert_array_equal(d["x0"], x0)
    assert d["active"] == list(active)
    X = np.random.default_rng(1).uniform(problem.lower, problem.upper, size=(6, problem.n_params))
    np.testing.assert_array_equal(back.cost_batch(X, workers=1), problem.cost_batch(X, workers=1))
    back.save(tmp_path / "again.iwrp", x0=x0, active=active)
    assert (tmp_path / "again.iwrp").read_bytes() == path.read_bytes()
    problem.save(tmp_path / "other.iwrp", x0=x0 + 1e-3)
    other = read_problem(tmp_path / "other.iwrp")
    assert other["data_fingerprint"] == d["data_fingerprint"]
    assert other["robot_fingerprint"] != d["robot_fingerprint"]


def test_weights_and_the_papers_bounds_go_through(problem: iwr.Problem, tmp_path: Path) -> None:
    path = tmp_path / "p.iwrp"
    problem.save(path)
    back = iwr.Problem.load(path)
    r, b = problem.robot, back.robot
    assert (b.name, b.joint_types) == (r.name, r.joint_types)
    for attr in ("dh", "joint_limits", "base_joints", "platform_joints", "leg_offsets",
                 "leg_stroke", "home_pose", "workspace"):
        np.testing.assert_array_equal(getattr(b, attr), getattr(r, attr), err_msg=attr)
    np.testing.assert_array_equal(back.measurements.weights, problem.measurements.weights)
    x = np.random.default_rng(1).uniform(problem.lower, problem.upper)
    assert back.cost(x) == problem.cost(x)  # the same objective, bit for bit
    assert read_problem(path)["bounds_kind"] == "paper"
    back.save(tmp_path / "q.iwrp")
    assert (tmp_path / "q.iwrp").read_bytes() == path.read_bytes()


def test_without_weights_and_without_carriage(tmp_path: Path) -> None:
    robot = iwr.Robot.hexapod()
    m, _ = iwr.simulate(robot, 4, seed=1)
    p = iwr.Problem(robot, m, bounds=(-0.1, 0.2))
    p.save(tmp_path / "h.iwrp")
    back = iwr.Problem.load(tmp_path / "h.iwrp")
    assert back.measurements.weights is None and back.robot.n_joints == 0
    assert read_problem(tmp_path / "h.iwrp")["bounds_kind"] == "custom"
    np.testing.assert_array_equal(back.lower, np.full(42, -0.1))


def test_text_beyond_ascii_goes_through(tmp_path: Path) -> None:
    """Names are UTF-8 text: a robot named in another script reads back as it was (the reader
    checks the text is UTF-8 and refuses a stray byte: cpp/tests/test_binary_io.cpp)."""
    robot = iwr.Robot.hexapod()
    robot.name = "Hexapod ü, 六脚"
    m, _ = iwr.simulate(robot, 4, seed=1)
    iwr.Problem(robot, m).save(tmp_path / "u.iwrp")
    assert iwr.Problem.load(tmp_path / "u.iwrp").robot.name == "Hexapod ü, 六脚"


def test_sources_are_recorded_with_their_sha256(problem: iwr.Problem, tmp_path: Path) -> None:
    problem.robot.to_toml(tmp_path / "r.toml")
    problem.save(tmp_path / "p.iwrp", sources={"robot": tmp_path / "r.toml"})
    (role, path, sha), = read_problem(tmp_path / "p.iwrp")["sources"]
    assert role == "robot" and Path(path) == (tmp_path / "r.toml").resolve()
    assert sha == sha256_of(tmp_path / "r.toml") and len(sha) == 64


def test_save_is_atomic_and_leaves_no_temporary(problem: iwr.Problem, tmp_path: Path) -> None:
    path = tmp_path / "p.iwrp"
    path.write_bytes(b"old")
    problem.save(path)
    assert [p.name for p in tmp_path.iterdir()] == ["p.iwrp"]
    with pytest.raises(FileNotFoundError):
        problem.save(tmp_path / "missing" / "p.iwrp")


def test_damaged_files_are_refused_naming_file_and_field(kind: Any, tmp_path: Path) -> None:
    """Every kind: a truncated file, a flipped bit anywhere, an unknown format version, not a
    file, no file: each refused naming the file and the fault."""
    problem, x0 = kind.kind.problem(kind.robot, kind.data)
    path = tmp_path / "p.iwrp"
    problem.save(path, x0=x0)
    good = path.read_bytes()
    bad = tmp_path / "bad.iwrp"
    for n in (0, 7, 31, 32, 100, 200, len(good) // 2, len(good) - 1):
        bad.write_bytes(good[:n])
        with pytest.raises(FormatError, match=r"bad\.iwrp: (truncated|empty file)"):
            iwr.Problem.load(bad)
    for at in (0, 9, 20, 40, len(good) // 3, len(good) // 2, len(good) - 9, len(good) - 1):
        edited = bytearray(good)
        edited[at] ^= 0x04
        bad.write_bytes(bytes(edited))
        with pytest.raises(FormatError, match=r"bad\.iwrp: "):
            iwr.Problem.load(bad)
    for at in (40, len(good) // 3, len(good) - 9):  # in the body: the checksum sees it
        edited = bytearray(good)
        edited[at] ^= 0x10
        bad.write_bytes(bytes(edited))
        with pytest.raises(FormatError, match=r"bad\.iwrp: corrupt: checksum mismatch"):
            iwr.Problem.load(bad)
    for version in (1, 99):  # 1: leg data only, before tracker data
        edited = bytearray(good)
        edited[8] = version
        bad.write_bytes(bytes(edited))
        with pytest.raises(FormatError, match=f"format version {version}; this program reads "
                                              "versions 2 to 4"):
            iwr.Problem.load(bad)
    with pytest.raises(ValueError, match="/dev/zero: not a regular file"):
        iwr.Problem.load("/dev/zero")
    with pytest.raises(ValueError, match="nope.iwrp: no such file"):
        iwr.Problem.load(tmp_path / "nope.iwrp")
    # A problem file is also a RuntimeError's kind of error for old callers of the DE state.
    assert issubclass(FormatError, ValueError) and issubclass(FormatError, RuntimeError)


def test_the_writer_refuses_what_the_reader_would(problem: iwr.Problem) -> None:
    robot, m = problem.robot, problem.measurements
    lo, hi = problem.lower, problem.upper
    args: dict[str, Any] = dict(
        robot_name="r", joint_types=robot.joint_types, dh=robot.dh,
        joint_limits=robot.joint_limits, base_joints=robot.base_joints,
        platform_joints=robot.platform_joints, leg_offsets=robot.leg_offsets,
        leg_stroke=robot.leg_stroke, home_pose=robot.home_pose, workspace=robot.workspace,
        measurement_joint_types=m.joint_types, kind="pose", q=m.q, poses=m.poses, legs=m.legs,
        weights=None, lower=list(lo), upper=list(hi), bounds_kind="paper", x0=[0.0] * 58,
        active=[True] * 58, parameter_names=problem.parameter_names, sources=[], weighting=None)
    _core._encode_problem(args)  # as given: fine
    legs = m.legs.copy()
    legs[2, 4] = 1e300
    with pytest.raises(ValueError, match="legs: row 2, column 4 is .*beyond any robot"):
        _core._encode_problem({**args, "legs": legs})
    with pytest.raises(ValueError, match="parameter names: 57; expected 58"):
        _core._encode_problem({**args, "parameter_names": problem.parameter_names[:-1]})
    with pytest.raises(ValueError, match="kind: 'legs'; expected pose, points, probe or ballbar"):
        _core._encode_problem({**args, "kind": "legs"})
    with pytest.raises(ValueError, match="x0: missing"):
        _core._encode_problem({k: v for k, v in args.items() if k != "x0"})
    with pytest.raises(ValueError, match="x0: parameter 3 is inf, not finite"):
        _core._encode_problem({**args, "x0": [0.0] * 3 + [math.inf] + [0.0] * 54})


# --- the thread pool: no hang, a cap, fork -----------------------------------------------------


def _in_child(body: Any, timeout: float = 60) -> int:
    """Runs body() in a forked child (fork is what is tested); its exit status, or -1 on a hang."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # "multi-threaded process forked"
        pid = os.fork()
    if pid == 0:  # pragma: no cover (the child)
        code = 1
        try:
            code = int(body())
        finally:
            os._exit(code)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(status)
        time.sleep(0.02)
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    return -1


def test_pool_works_in_a_forked_child(problem: iwr.Problem) -> None:
    X = np.random.default_rng(2).uniform(problem.lower, problem.upper, size=(40, 58))
    expected = problem.cost_batch(X, workers=2)  # the pool now runs in this process

    def child() -> int:
        return 0 if np.array_equal(problem.cost_batch(X, workers=2), expected) else 3

    assert _in_child(child) == 0  # not -1: no hang
    np.testing.assert_array_equal(problem.cost_batch(X, workers=2), expected)  # parent unharmed


def test_fork_while_another_thread_is_inside_the_same_problems_batch(problem) -> None:
    """Issue 26: the child of a fork() taken while another thread held the problem's batch lock
    hung on that lock (17 of 20 children); the lock is now checked by process id first."""
    import threading

    X = np.random.default_rng(3).uniform(problem.lower, problem.upper, size=(3000, 58))
    small = X[:5]
    expected = problem.cost_batch(small, workers=1)
    stop, busy = threading.Event(), threading.Event()

    def load() -> None:
        while not stop.is_set():
            busy.set()
            problem.cost_batch(X, workers=2)  # the lock is held almost all the time

    thread = threading.Thread(target=load, daemon=True)
    thread.start()
    try:
        assert busy.wait(60)
        time.sleep(0.05)

        def child() -> int:
            return 0 if np.allclose(problem.cost_batch(small, workers=2), expected,
                                    rtol=1e-12, atol=0) else 3

        codes = [_in_child(child, timeout=30) for _ in range(8)]
    finally:
        stop.set()
        thread.join(60)
    assert codes == [0] * 8  # -1: a child hung


def test_a_thread_the_system_refuses_is_an_error_not_a_hang(problem: iwr.Problem) -> None:
    X = np.zeros((8, 58))

    def child() -> int:
        # No new thread for this user: RLIMIT_NPROC 0 (root ignores it, so drop to nobody).
        if os.getuid() == 0:
            os.setuid(65534)
        resource.setrlimit(resource.RLIMIT_NPROC, (0, 0))
        fresh = iwr.Problem(problem.robot, problem.measurements)
        try:
            fresh.cost_batch(X, workers=4)
        except RuntimeError as exc:
            return 0 if "cannot start 4 threads" in str(exc) else 4
        return 5

    assert _in_child(child) == 0


def test_worker_counts_are_capped(problem: iwr.Problem) -> None:
    """No hang and no exhaustion of process ids: thousands of threads are refused up front, in
    cost_batch as in identify (the same pool)."""
    cap = max(16, 4 * len(os.sched_getaffinity(0)))
    with pytest.raises(ValueError, match=f"2000 threads asked for; at most {cap}"):
        problem.cost_batch(np.zeros((4, 58)), workers=2000)
    assert problem.cost_batch(np.zeros((4, 58)), workers=cap).shape == (4,)
    with pytest.raises(ValueError, match="2000 threads asked for"):
        iwr.identify(problem.robot, problem.measurements, method="de", workers=2000,
                     generations=2, population_size=20, seed=1, progress=False)
