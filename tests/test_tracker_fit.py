"""Issue 13/14: "converged" only when the fit is sane, for laser-tracker data too. The identified
errors of a tracker result are judged against their plausible size (10 times the search bounds,
the setup's from the registration guess) modulo the tracker problem's null directions, by the one
check leg data use (``iwr.estimation.fit_check`` through ``iwr.methods._check_fit``)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr.tracker import TrackerNoise
from iwr.tracker.registration import guess_registration

REPO = Path(__file__).resolve().parents[1]
REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)  # 2 m away, turned 90 degrees
PROBE = (0.0, 0.0, 60.0, 0.0, 0.0, 0.0)
NOISE = (iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6), TrackerNoise.leica())


def setup_kw(kind: str, dz: float = 0.0) -> dict:
    if kind == "points":
        return {"reflectors": [(x, y, z + dz) for x, y, z in REFLECTORS]}
    return {"probe": (0.0, 0.0, 60.0 + dz, 0.0, 0.0, 0.0)}


def robot_for(kind: str, registration=REGISTRATION, dz: float = 0.0) -> iwr.Robot:
    return iwr.Robot.default().with_tracker(registration=registration, **setup_kw(kind, dz))


@pytest.mark.parametrize("kind", ["points", "probe"])
@pytest.mark.parametrize("noise", [None, NOISE], ids=["noise-free", "realistic"])
@pytest.mark.parametrize("active", [None, "base"])
def test_a_clean_calibration_passes_the_fit_check(kind, noise, active):
    robot = robot_for(kind)
    data, _ = iwr.simulate(robot, 40, seed=11, noise=noise)
    res = iwr.identify(robot, data, active=active)
    assert res.success, res.message
    assert res.fit is not None and res.fit.fit_ok and not res.fit.implausible


@pytest.mark.parametrize("kind", ["points", "probe"])
def test_the_registration_is_judged_from_the_guess_whatever_the_start(kind):
    """The data 2 m away and turned 90 degrees, the file's nominal registration the identity,
    started from zeros: LM reaches a zero cost by a 2 m registration correction, which is
    plausible, measured from the data's registration guess (docs/tracker.md), as it is without
    an x0. (It was measured from the nominal registration when an x0 was given, and failed:
    the job's outlier refit gives one, so the verdict of one data set depended on the seed.)
    From zeros, half of the 2 m lands in the rail's joint1.dd: {0} is a null direction of point
    data (a gauge choice), which the size test does not count; from the guess it stays in the
    registration."""
    data, _ = iwr.simulate(robot_for(kind), 40, seed=5)
    wrong = robot_for(kind, registration=(0, 0, 0, 0, 0, 0))
    n = wrong.n_params
    res = iwr.identify(wrong, data, x0=np.zeros(n + wrong.tracker.n_params))
    free = iwr.identify(wrong, data)
    assert res.success and free.success, (res.message, free.message)
    assert res.fit.fit_ok and not res.fit.implausible and res.fun < 1e-12
    found = [wrong.tracker.registration_matrix(r.x[n:])[:3, 3] for r in (res, free)]
    assert np.linalg.norm(found[1] - [2000.0, 0.0, 0.0]) < 10.0  # the guess's start: the 2 m
    assert 500.0 < np.linalg.norm(found[1] - found[0]) < 1500.0  # zeros': half in {0}'s gauge


@pytest.mark.parametrize("bounds", [None, "paper"])
@pytest.mark.parametrize("kind", ["points", "probe"])
def test_the_efficient_estimator_judges_the_registration_from_the_guess_too(kind, bounds):
    """Its own size test was centred on x0's set-up (the file's registration 2 m off: "tracker.x
    = 2004 (limit 100)", failed) while LM's is on the data's guess: now both, from any start
    (18 of 20 seeds converged from zeros; 2 refuse the start itself, their forward kinematics
    failing there)."""
    data, _ = iwr.simulate(robot_for(kind), 60, seed=0, noise=NOISE)
    wrong = robot_for(kind, registration=(0, 0, 0, 0, 0, 0))
    res = iwr.identify(wrong, data, noise=NOISE, bounds=bounds,
                       x0=np.zeros(wrong.n_params + wrong.tracker.n_params))
    assert res.success and res.fit.fit_ok and not res.fit.implausible, res.message


@pytest.mark.parametrize("kind", ["points", "probe"])
def test_offsets_far_from_their_nominal_are_named(kind):
    """The nominal reflectors (probe) 30 mm off the true ones: the guess still starts (its RMS is
    below 20 mm) and LM fits, but through offsets of 30 mm against a plausible 20 mm (10 times
    their 2 mm bounds), even modulo the platform frame's gauge (b_j and the reflectors moved
    together)."""
    data, _ = iwr.simulate(robot_for(kind), 40, seed=5)
    res = iwr.identify(robot_for(kind, dz=30.0), data)
    assert not res.success and "THE MODEL DOES NOT FIT THE DATA" in res.message
    names = {name for name, _, _ in res.fit.implausible}
    expected = {"reflector1.z", "reflector2.z", "reflector3.z"} if kind == "points" else {"probe.z"}
    assert expected <= names, res.fit.implausible


def test_a_reflector_80_mm_off_held_at_nominal_is_named():
    """A reflector 80 mm above its nominal position, its offset held (not identified): the robot's
    spherical joints absorb it; modulo the null directions the offset is what is implausible."""
    robot = robot_for("points")
    _, truth = iwr.simulate(robot, 2, seed=1)
    names = robot.parameter_names + robot.tracker.parameter_names
    bad = truth.copy()
    bad[names.index("reflector1.z")] += 80.0
    data, _ = iwr.simulate(robot, 60, seed=1, x=bad)
    with pytest.raises(iwr.tracker.RegistrationError, match="RMS"):
        iwr.identify(robot, data)  # the guess itself says the model is too poor
    guess = guess_registration(robot, robot.tracker, data, max_rms=1e3)
    x0 = np.concatenate([np.zeros(robot.n_params), guess.x_setup])
    res = iwr.identify(robot, data, x0=x0,
                       active=[not n.startswith("reflector") for n in names])
    assert not res.success and res.status == "failed"
    found = dict((n, v) for n, v, _ in res.fit.implausible)
    assert 60 < found["reflector1.z"] < 90, res.fit.implausible
    assert "reflector1.z = " in res.message


def test_the_check_costs_no_evaluation_and_keeps_the_method_message():
    robot = robot_for("points")
    data, _ = iwr.simulate(robot, 40, seed=5)
    wrong = robot_for("points", dz=30.0)
    res = iwr.identify(wrong, data)
    assert "(the method: " in res.message  # LM's own message kept, not as the outcome
    assert res.fit.dof == 0 and math.isnan(res.fit.statistic)  # no chi-square without noise


def run(*args: str):
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    return subprocess.run([sys.executable, "-m", "iwr", *args], capture_output=True, text=True,
                          cwd=tempfile.gettempdir(), env=environ, timeout=600)


def test_iwr_calibrate_exits_3_on_implausible_tracker_results(tmp_path):
    robot = robot_for("points")
    data, _ = iwr.simulate(robot, 40, seed=5)
    from iwr.tracker.files import write_tracker_wide

    write_tracker_wide(tmp_path / "points.csv", robot.tracker, data)
    robot_for("points", dz=30.0).to_toml(tmp_path / "wrong.toml")
    proc = run("calibrate", str(tmp_path / "wrong.toml"), str(tmp_path / "points.csv"),
               "-o", str(tmp_path / "out"), "--no-plots")
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert "does not fit the data" in proc.stderr
    assert "reflector1.z" in proc.stdout
