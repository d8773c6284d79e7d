"""Shared fixtures."""

from __future__ import annotations

import signal
from typing import Any

import pytest


@pytest.fixture
def sigint_handler():
    """Make SIGINT raise KeyboardInterrupt in this process for the test's duration.

    A shell without job control starts background commands with SIGINT ignored, and Python then
    keeps it ignored: a test that sends itself SIGINT would wait forever (CI may run so).
    """
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)



@pytest.fixture(scope="session")
def default_sigint() -> Any:
    """A ``preexec_fn`` for a child that is sent SIGINT: the signal's default action. A shell
    without job control starts background commands with SIGINT ignored, an ignored signal stays
    ignored in children, and Python then installs no KeyboardInterrupt handler."""
    def preexec() -> None:
        signal.signal(signal.SIGINT, signal.SIG_DFL)

    return preexec


# -- the measurement kinds (issue 21: tests parametrised over the kinds, not twin files) ---------

#: Every registered kind of data a robot can be measured by, as the ``kind`` fixture gives them.
KINDS = ("pose", "points", "probe", "ballbar")
_REGISTRATION = (2000.0, -150.0, 300.0, 1.5, 0.01, -0.02)


def robot_measured_by(name: str) -> Any:
    """The default IWR robot with the instrument of kind ``name``."""
    import iwr

    robot = iwr.Robot.default()
    if name == "points":
        return robot.with_tracker(registration=_REGISTRATION, reflectors=[
            (120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)])
    if name == "probe":
        return robot.with_tracker(registration=_REGISTRATION,
                                  probe=(10.0, -5.0, 60.0, 0.1, 0.0, 0.2))
    if name == "ballbar":
        from _ballbar import ballbar_robot  # the ballbar tests' set-ups A and B

        return ballbar_robot(base=robot)
    assert name == "pose", name
    return robot


class KindCase:
    """One kind's robot and noise-free simulated data (``name``, ``robot``, ``data``, ``truth``,
    ``kind``: the :class:`iwr.kinds.MeasurementKind`)."""

    def __init__(self, name: str, n_poses: int = 30, seed: int = 7) -> None:
        import iwr
        from iwr import kinds

        self.name = name
        self.robot = robot_measured_by(name)
        self.data, self.truth = iwr.simulate(self.robot, n_poses, seed=seed)
        self.kind = kinds.of(self.data)
        assert self.kind.name == name and kinds.for_robot(self.robot) is self.kind

    def __repr__(self) -> str:
        return f"KindCase({self.name!r})"


@pytest.fixture(scope="module", params=KINDS)
def kind(request: pytest.FixtureRequest) -> KindCase:
    """Each kind of data in turn: a test written once for every kind."""
    return KindCase(request.param)


@pytest.fixture(scope="session")
def kind_case() -> type[KindCase]:
    """:class:`KindCase` itself, for a test that chooses its kinds (``kind_case("points")``:
    the robot of that kind and its data)."""
    return KindCase


@pytest.fixture(scope="module")
def with_effects() -> Any:
    """The default IWR robot with the realistic effects (docs/effects.md: the legs' compliance
    under load and their thermal expansion), for the effects' test files."""
    import iwr
    from iwr.effects import api

    robot = iwr.Robot.default()
    return robot.with_effects(*api.realistic(robot))


@pytest.fixture(scope="session")
def carriage_only_poses() -> Any:
    """``(robot, n, seed) -> (q, poses)``: poses that move only the carriage's slides (the
    hexapod at its home pose in one orientation to gravity), so that each leg's force is the
    same at every pose under one payload: where one payload cannot separate the compliances."""
    import numpy as np

    from iwr.transforms import pose_from_matrix, pose_matrix

    def poses(robot: Any, n: int, seed: int) -> tuple[Any, Any]:
        rng = np.random.default_rng(seed)
        q = np.zeros((n, robot.n_joints))
        q[:, 0] = rng.uniform(0, 2000, n)
        q[:, 1] = rng.uniform(0, 1000, n)
        local = pose_matrix(robot.home_pose)
        return q, np.array([pose_from_matrix(robot.carriage_transform(qk) @ local)
                            for qk in q])

    return poses


@pytest.fixture(scope="session")
def measured_with_effects() -> Any:
    """``kind name -> robot``: the default IWR with that instrument (:func:`robot_measured_by`)
    and the realistic effects (tracker data with effects, tests/test_effects_tracker.py)."""
    from iwr.effects import api

    def robot(name: str) -> Any:
        plain = robot_measured_by(name)
        return plain.with_effects(*api.realistic(plain))

    return robot


@pytest.fixture(scope="session")
def installed_command() -> Any:
    """``name -> path`` of a command ``pip install .`` puts next to this Python (``iwr``,
    ``iwr-calibrate``, ``iwr-engine``); the test fails naming it when it is not installed."""
    import shutil
    import sys
    from pathlib import Path

    def find(name: str) -> str:
        cand = Path(sys.executable).parent / name
        exe = str(cand) if cand.exists() else shutil.which(name)
        if exe is None:
            pytest.fail(f"{name} is not installed: `pip install .` puts it next to python")
        return exe

    return find


@pytest.fixture(scope="session")
def engine_equals_identify(installed_command: Any) -> Any:
    """``(robot, data, folder, population, generations) -> (engine result, iwr.identify's, the
    run's problem)``: ``iwr-calibrate`` on the robot and its tracker data written to ``folder``
    (DE/rand/1/bin, 2 threads) and ``iwr.identify``'s DE with the same settings on the data read
    back (1 thread), checked equal bit for bit (x, the best cost's history, the cost)."""
    import subprocess

    import numpy as np

    import iwr
    from iwr.tracker.files import read_tracker_data, write_tracker_wide

    def run(robot: Any, data: Any, folder: Any, population: int, generations: int) -> Any:
        robot.to_toml(folder / "robot.toml")
        write_tracker_wide(folder / "data.csv", robot.tracker, data)
        settings = ["--population-size", population, "--generations", generations, "--seed", 4,
                    "--F", 0.7, "--CR", 0.9, "--threads", 2, "--quiet"]
        proc = subprocess.run([installed_command("iwr-calibrate"), folder / "robot.toml",
                               folder / "data.csv", "--output", folder / "run.json",
                               *map(str, settings)], capture_output=True, text=True,
                              timeout=300, check=False)
        assert proc.returncode == 0, proc.stderr
        exe = iwr.load_result(folder / "run.json")
        robot = iwr.Robot.from_toml(folder / "robot.toml")
        back = read_tracker_data(folder / "data.csv", robot.tracker)
        py = iwr.identify(robot, back, "de", strategy="rand1bin", population_size=population,
                          generations=generations, seed=4, F=0.7, CR=0.9, workers=1,
                          polish=False, progress=False)
        np.testing.assert_array_equal(exe.x, py.x)
        np.testing.assert_array_equal(exe.history["best"], py.history["best"])
        problem = iwr.Problem.load(folder / "run.json.iwrp")
        assert exe.fun == problem.cost(exe.x) == py.fun
        return exe, py, problem

    return run


@pytest.fixture(scope="session")
def reading_jacobian_matches_differences() -> Any:
    """``(robot, data, truth) -> None``: the derivatives of tracker data's predicted points with
    effects in the joint and leg readings (:func:`iwr.tracker.problem.reading_jacobian`, what
    the weights, the uncertainty and the gross-error screen propagate the readings' noise by)
    checked against central differences of the forward kinematics with the effects."""
    import numpy as np

    import iwr
    from iwr.effects import tracker as et
    from iwr.tracker.problem import reading_jacobian

    def check(robot: Any, data: Any, truth: Any) -> None:
        problem, _ = et.effect_tracker_problem(robot, data, x0=truth)
        g = reading_jacobian(problem, truth)
        nj = robot.n_joints
        for j in range(nj + 6):
            h = 1e-6 if j < nj and robot.joint_types[j] == "R" else 1e-4
            pts = []
            for sign in (1.0, -1.0):
                q, legs = data.q.copy(), data.legs.copy()
                if j < nj:
                    q[:, j] += sign * h
                else:
                    legs[:, j - nj] += sign * h
                moved = iwr.tracker.TrackerMeasurements(
                    q, legs, points=data.points, probe=data.probe, joint_types=data.joint_types,
                    payload=data.payload, temperatures=data.temperatures)
                pts.append(et.TrackerEffectModel(robot, robot.tracker, moved).points(truth)[0])
            fd = ((pts[0] - pts[1]) / (2 * h)).reshape(len(data), -1)
            np.testing.assert_allclose(g[:, :, j], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())

    return check


@pytest.fixture
def singular_at(monkeypatch):
    """``singular_at(n, pose)``: the statics of the forward kinematics with the effects
    (``iwr.effects.model.leg_forces`` as the tracker's and the loop's code call it) raise
    ``SingularPoseError`` at ``pose`` whenever all ``n`` poses are in the call: a robot whose
    hexapod is singular at that pose, as a search from a bad start can try."""
    from iwr.effects import loop, model, tracker

    real = model.leg_forces

    def patch(n: int, pose: int) -> None:
        def leg_forces(v, *args, **kwargs):
            if len(v) == n:
                raise model.SingularPoseError(f"pose {pose}: singular (a test)", pose)
            return real(v, *args, **kwargs)

        for module in (loop, tracker):
            monkeypatch.setattr(module, "leg_forces", leg_forces)

    return patch


@pytest.fixture(scope="session")
def fresh_tool_error() -> Any:
    """``(calibrated, fresh) -> mm``: issue 23's check of a calibration with effects on fresh
    poses. The largest distance between the tool point 200 mm along z of {5} where
    ``calibrated``'s forward kinematics with its effects puts it from ``fresh``'s true readings
    under their loads and temperatures (:func:`iwr.effects.api.forward_kinematics` at the file's
    values, started 0.5 mm and 1 mrad off) and where ``fresh``'s true poses have it."""
    import numpy as np

    from iwr.effects import api
    from iwr.effects import parameter_names as effect_names
    from iwr.transforms import pose_matrix

    tool = np.array([0.0, 0.0, 200.0])

    def points(poses: Any) -> Any:
        t = pose_matrix(poses)
        return t[:, :3, 3] + t[:, :3, :3] @ tool

    def error(calibrated: Any, fresh: Any) -> float:
        zero = np.zeros(calibrated.n_params + len(effect_names(calibrated.effects)))
        guess = fresh.poses + np.array([0.5, -0.5, 0.5, 1e-3, -1e-3, 1e-3])
        poses = api.forward_kinematics(calibrated, zero, fresh.q, fresh.legs, fresh, guess)
        return float(np.abs(points(poses) - points(fresh.poses)).max())

    return error


@pytest.fixture(scope="session")
def check_effect_jacobians() -> Any:
    """``(robot, data, x, loop_columns)``: the exact Jacobians of a robot with effects against
    central differences (relative 1e-5): eq. (10)'s (:class:`iwr.effects.problem.EffectProblem`)
    in every parameter, the implicit loop's (:func:`iwr.implicit_loop.loop_jacobians`, at random
    corrections) in the parameters ``loop_columns`` and in every correction of pose 3's
    readings; the loop at zero corrections is eq. (10)'s prediction (1e-9 mm). Steps: 1e-6 for a
    geometric error, 1e-4 of its range for an effect's parameter."""
    import numpy as np

    from iwr.effects import model
    from iwr.effects.problem import EffectProblem
    from iwr.implicit_loop import loop_jacobians

    def central(f: Any, x: Any, i: int, h: float) -> Any:
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        return (f(xp) - f(xm)) / (2 * h)

    def close(fd: Any, exact: Any, what: Any) -> None:
        assert np.abs(fd - exact).max() < 1e-5 * max(1.0, np.abs(exact).max()), what

    def check(robot: Any, m: Any, x: Any, loop_columns: Any) -> None:
        problem = EffectProblem(robot, m)
        names = problem.parameter_names
        _, jac = problem.residuals_and_jacobian(x)
        steps = np.where(np.arange(len(x)) < robot.n_params, 1e-6,
                         1e-4 * (problem.upper - problem.lower))
        for i in range(problem.n_params):
            close(central(problem.residuals, x, i, steps[i]), jac[:, i], names[i])
        rng = np.random.default_rng(5)
        corr = rng.normal(0, 1, (len(m), robot.n_joints + 6)) * ([1e-2] * 2 + [1e-5] * 2
                                                                 + [1e-2] * 3 + [1e-5] * 3)
        legs, jx, jy = loop_jacobians(robot, x, m.q, m.poses, corr, data=m)
        for i in loop_columns:
            fd = central(lambda y: loop_jacobians(robot, y, m.q, m.poses, corr, data=m)[0], x,
                         i, steps[i])
            close(fd, jx[..., i], names[i])
        for c in range(robot.n_joints + 6):
            h = 1e-4 if c in (0, 1, 4, 5, 6) else 1e-7
            fd = central(lambda y: loop_jacobians(robot, x, m.q, m.poses, y.reshape(corr.shape),
                                                  data=m)[0].ravel(), corr.ravel().copy(),
                         np.ravel_multi_index((3, c), corr.shape), h).reshape(legs.shape)
            close(fd[3], jy[3, :, c], c)
        s = model.predicted_readings(robot, x, m.q, m.poses, m)
        assert np.abs(loop_jacobians(robot, x, m.q, m.poses, data=m)[0] - s).max() < 1e-9

    return check
