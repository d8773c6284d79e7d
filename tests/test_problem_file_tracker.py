"""The problem file for laser-tracker data (iwr/problem_file.py, cpp/src/problem_file.cpp): points
(with reflectors not seen) and probe poses in the tracker frame, the nominal setup, the reference,
the search's x0 and active set: what the kind-neutral tests (test_problem_file.py: the round trip,
damaged files) do not see, and every damaged field of the tracker's named."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import iwr
from iwr import _core
from iwr.problem_file import FormatError, encode_problem, read_problem
from iwr.tracker import TrackerProblem
from iwr.tracker.api import tracker_problem, tracker_simulate

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, -150.0, 300.0, math.pi / 2, 0.01, -0.02)


def _problem(kind: str, hidden: float = 0.0) -> tuple[TrackerProblem, np.ndarray]:
    base = iwr.Robot.default()
    robot = (base.with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)
             if kind == "points" else
             base.with_tracker(registration=REGISTRATION, probe=(10.0, -5.0, 60.0, 0.1, 0.0, 0.2)))
    m, _ = tracker_simulate(robot, 12, seed=3, hidden=hidden)
    return tracker_problem(robot, m)


@pytest.fixture(scope="module", params=["points", "probe"])
def tracker(request: Any) -> tuple[TrackerProblem, np.ndarray]:
    return _problem(request.param, hidden=0.25 if request.param == "points" else 0.0)


def test_the_trackers_setup_and_unseen_reflectors_go_through(
        tracker: tuple[TrackerProblem, np.ndarray], tmp_path: Path) -> None:
    """What the kind-neutral round trip (test_problem_file.py) does not see: the setup's own
    fields, and reflectors not seen (NaN) kept as such."""
    problem, x0 = tracker
    path = tmp_path / "t.iwrp"
    problem.save(path, x0=x0)
    back = TrackerProblem.load(path)
    s, b = problem.setup, back.setup
    assert (b.kind, b.names, b.probe_length) == (s.kind, s.names, s.probe_length)
    for attr in ("registration", "reflectors", "probe"):
        np.testing.assert_array_equal(getattr(b, attr), getattr(s, attr), err_msg=attr)
    assert back.robot.tracker is back.setup
    np.testing.assert_array_equal(back.reference, problem.reference)
    m, mb = problem.measurements, back.measurements
    for attr in ("points", "probe"):
        np.testing.assert_array_equal(getattr(mb, attr), getattr(m, attr), err_msg=attr)
    if m.kind == "points":
        assert np.isnan(m.points).any() and np.isnan(mb.points).any()


def test_leg_and_tracker_files_are_told_apart(tracker: tuple[TrackerProblem, np.ndarray],
                                              tmp_path: Path) -> None:
    problem, _ = tracker
    problem.save(tmp_path / "t.iwrp")
    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, 5, seed=1)
    iwr.Problem(robot, m).save(tmp_path / "legs.iwrp")
    with pytest.raises(FormatError, match=r"legs\.iwrp: holds leg data .* not tracker data"):
        TrackerProblem.load(tmp_path / "legs.iwrp")
    assert read_problem(tmp_path / "legs.iwrp")["kind"] == "pose"
    assert read_problem(tmp_path / "legs.iwrp")["active"] == [True] * 58


def _fields(problem: TrackerProblem, x0: np.ndarray) -> dict[str, Any]:
    """The fields the writer takes, as the reader gives them back."""
    d = _core._decode_problem(encode_problem(problem, x0=x0), "")
    return {k: v for k, v in d.items() if not k.endswith("_fingerprint")}


@pytest.mark.parametrize("kind, edit, message", [
    ("points", lambda d: d["points"].__setitem__((2, 4), np.nan),
     "points: row 2, reflector 2 has some coordinates NaN and some not"),
    ("points", lambda d: d["points"].__setitem__((2, 4), np.inf),
     r"points: row 2, column 4 is inf, not finite"),
    ("points", lambda d: d.update(points=np.full_like(d["points"], np.nan)),
     "points: no reflector is seen at any pose"),
    ("points", lambda d: d.update(points=d["points"][:, :6]),
     "points has 72 values; expected 108"),
    ("points", lambda d: d.update(reflector_names=["1", "2", "1"]),
     "reflector name: '1' given twice"),
    ("points", lambda d: d.update(reflector_names=["1", "2"]), "reflector names: 2; expected 3"),
    ("points", lambda d: d["x0"].__setitem__(60, math.nan), "x0: parameter 60 is nan"),
    ("points", lambda d: d.update(active=[False] * len(d["active"])),
     "active: no parameter is active"),
    ("points", lambda d: d.update(active=d["active"][:-1]), "active: 72 flags; expected 73"),
    ("points", lambda d: d.update(reference=d["reference"][:-1]),
     "reference has 57 values; expected 58"),
    ("points", lambda d: d["reference"].__setitem__(3, np.nan),
     "reference: row 3, column 0 is nan"),
    ("points", lambda d: d.update(lower=d["lower"][:-1]),
     "lower bounds has 72 values; expected 73"),
    ("points", lambda d: d["upper"].__setitem__(65, d["lower"][65]), "bounds: parameter 65"),
    ("probe", lambda d: d.update(probe_length=0.0), "probe length: 0"),
    ("probe", lambda d: d.update(probe_length=math.inf), "probe length: inf"),
    ("probe", lambda d: d["probe_poses"].__setitem__((1, 3), np.nan),
     "probe poses: row 1, column 3 is nan, not finite"),
    ("probe", lambda d: d["points"].__setitem__((0, 0), np.nan),
     "points: row 0, column 0 is nan, not finite"),
    ("probe", lambda d: d.update(parameter_names=d["parameter_names"][:-1]),
     "parameter names: 69; expected 70"),
])
def test_every_field_is_checked(kind: str, edit: Any, message: str) -> None:
    problem, x0 = _problem(kind)
    fields = _fields(problem, x0)
    _core._encode_problem(fields)  # as read back: fine
    fields = {k: (v.copy() if isinstance(v, (np.ndarray, list)) else v) for k, v in fields.items()}
    edit(fields)
    with pytest.raises(ValueError, match=message):
        _core._encode_problem(fields)


def test_probe_points_must_be_those_of_the_probe_poses(tmp_path: Path) -> None:
    """The engine runs on the stored virtual points; the loader checks that they are those of the
    stored probe poses (a file written by anything but encode_problem could differ)."""
    problem, x0 = _problem("probe")
    fields = _fields(problem, x0)
    fields["points"] = fields["points"].copy()
    fields["points"][3, 5] += 1e-6
    (tmp_path / "p.iwrp").write_bytes(_core._encode_problem(fields))
    with pytest.raises(FormatError, match=r"p\.iwrp: points: not the virtual points"):
        TrackerProblem.load(tmp_path / "p.iwrp")


def test_bounds_kind_follows_the_robot_part() -> None:
    problem, x0 = _problem("points")
    assert read_problem_bytes(encode_problem(problem, x0=x0))["bounds_kind"] == "default"
    robot, m = problem.robot, problem.measurements
    paper, _ = tracker_problem(robot, m, "paper")
    assert read_problem_bytes(encode_problem(paper))["bounds_kind"] == "paper"
    custom = TrackerProblem(robot, robot.tracker, m, (problem.lower, problem.upper * 2))
    assert read_problem_bytes(encode_problem(custom))["bounds_kind"] == "custom"


def read_problem_bytes(data: bytes) -> dict[str, Any]:
    return _core._decode_problem(data, "")
