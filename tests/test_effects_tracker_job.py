"""The calibration job and its steps on laser-tracker data for a robot with effects (issue 23,
docs/effects.md, "Tracker data"): the noise-weighted point objective with the effects, the
uncertainty, the gross-error screen, the job (`iwr.calibrate`, `iwr calibrate`, `iwr report`),
the written calibrated.toml, and pose planning with payloads."""

from __future__ import annotations

import json

import numpy as np
import pytest

import iwr
from iwr.effects import tracker as et
from iwr.effects import tracker_study

PAYLOADS = tracker_study.PAYLOADS
NOISE = (iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6),
         iwr.tracker.TrackerNoise.leica())


@pytest.fixture(scope="module")
def noisy(measured_with_effects):
    """40 noisy reflector-point poses under three payloads, and the truth."""
    robot = measured_with_effects("points")
    data, truth = et.simulate(robot, 40, seed=1, noise=NOISE, payloads=PAYLOADS)
    return robot, data, truth


@pytest.fixture(scope="module")
def fits(noisy):
    """Weighted LM (the base parameters) and the efficient estimator (no outlier test) on the
    same data."""
    robot, data, _ = noisy
    return (iwr.identify(robot, data, "lm", noise=NOISE, active="base"),
            iwr.identify(robot, data, "efficient", noise=NOISE, outliers="off"))


def test_weighted_lm_statistic_is_the_efficient_estimators(noisy, fits):
    """LM on the noise-weighted point objective with the effects reaches the estimator's
    minimum: its fit statistic (the weighted residuals minimised to first order) is the
    efficient estimator's to 1e-6 (measured 3e-9), with the same degrees of freedom; its
    weighted cost is that statistic (the weights held at the start move it by a few 1e-3)."""
    robot, data, _ = noisy
    lm, eff = fits
    assert lm.success and eff.success, (lm.message, eff.message)
    assert lm.fit.dof == eff.fit.dof
    assert lm.fit.statistic == pytest.approx(eff.fit.statistic, rel=1e-6)
    assert lm.fun == pytest.approx(lm.fit.statistic, rel=1e-2)
    objective = lm.settings["objective"]
    assert objective["weighted"] and objective["cost_eq10"] == pytest.approx(
        et.effect_tracker_problem(robot, data)[0].cost(lm.x))
    # The unweighted LM's minimum is another one: its statistic is larger.
    plain = iwr.identify(robot, data, "lm", noise=NOISE, weighted=False, active="base")
    assert plain.fit.statistic > lm.fit.statistic


def test_weighted_lm_statistic_on_probe_data_is_the_efficient_estimators(noisy):
    """The probe's four points whitened by the pseudo-inverse of their rank-6 covariance (one
    rigid pose): LM's statistic with the effects is the estimator's to 1e-3 with the same
    degrees of freedom (six readings a pose)."""
    robot, _, _ = noisy
    probe = robot.with_tracker(registration=robot.tracker.registration,
                               probe=(10.0, -5.0, 60.0, 0.1, 0.0, 0.2))
    data, _ = et.simulate(probe, 30, seed=1, noise=NOISE, payloads=PAYLOADS)
    lm = iwr.identify(probe, data, "lm", noise=NOISE, active="base")
    eff = iwr.identify(probe, data, "efficient", noise=NOISE, outliers="off")
    assert lm.success and eff.success, (lm.message, eff.message)
    assert lm.settings["objective"]["weighted"]
    assert lm.fit.dof == eff.fit.dof
    assert lm.fit.statistic == pytest.approx(eff.fit.statistic, rel=1e-3)


def test_reading_jacobian_matches_central_differences(noisy,
                                                      reading_jacobian_matches_differences):
    """The points' derivatives in the joint and leg readings through the loop closure with the
    effects against central differences of the forward kinematics with the effects."""
    robot, data, truth = noisy
    reading_jacobian_matches_differences(robot, data.subset(np.arange(6)), truth)


def test_uncertainty_of_weighted_lm_is_the_estimators_covariance(noisy, fits):
    """iwr.uncertainty on tracker data with effects: weighted (the whitened Jacobian's
    inverse information) it is the efficient estimator's covariance to 5 % on every active
    parameter's standard deviation (the same information to first order); from the noise
    model (the unweighted estimate's sandwich) no smaller; the default active set is the base
    parameters."""
    robot, data, _ = noisy
    lm, eff = fits
    w = iwr.uncertainty(robot, data, lm.x, NOISE, active=lm.active, weighted=True)
    act = np.flatnonzero(eff.active)
    assert (lm.active == eff.active).all()
    np.testing.assert_allclose(w.std[act], np.sqrt(np.diag(eff.covariance)), rtol=0.05)
    sandwich = iwr.uncertainty(robot, data, lm.x, NOISE, active=lm.active)
    assert sandwich.source == "tracker noise"
    assert np.all(sandwich.std[act] >= 0.95 * w.std[act])
    default = iwr.uncertainty(robot, data, lm.x)
    assert (default.active == et.base_parameters(robot, data, lm.x)).all()


def _written_robot_predicts_the_result(robot, data, x, written):
    """The robot of calibrated.toml (``written``) with the data's payload centres moved into
    its platform frame gives the in-memory model's platform frames and leg commands to 1e-9
    mm; with the payload centres left as they were, not."""
    from iwr.effects import api
    from iwr.tracker.analysis import _moved_platform_frame
    from iwr.transforms import pose_from_matrix, pose_matrix

    ng, ne = robot.n_params, len(iwr.effects.parameter_names(robot.effects))
    _, _, g = _moved_platform_frame(robot, robot.tracker, np.concatenate([x[:ng], x[ng + ne:]]))
    poses, ok = et.TrackerEffectModel(robot, robot.tracker, data).forward(x)
    assert ok.all()
    old = robot.tracker.registration_matrix(x[ng + ne:]) @ pose_matrix(poses)
    expected = old @ np.linalg.inv(g)  # {5} of calibrated.toml in {T}
    pay = data.payload.copy()
    pay[:, 1:] = pay[:, 1:] @ g[:3, :3].T + g[:3, 3]
    n_all = written.n_params + ne + written.tracker.n_params

    def frames(payload):
        moved = iwr.tracker.TrackerMeasurements(data.q, data.legs, points=data.points,
                                                probe=data.probe, joint_types=data.joint_types,
                                                payload=payload,
                                                temperatures=data.temperatures)
        p, ok = et.TrackerEffectModel(written, written.tracker, moved).forward(np.zeros(n_all))
        assert ok.all()
        return written.tracker.registration_matrix(np.zeros(written.tracker.n_params)) \
            @ pose_matrix(p)

    got = frames(pay)
    assert np.abs(got[:, :3, 3] - expected[:, :3, 3]).max() < 1e-9
    assert np.abs(got[:, :3, :3] - expected[:, :3, :3]).max() < 1e-12
    # The compensation (iwr legs' path) of the written robot gives back the readings.
    cmd = api.leg_commands(written, data.q, np.array([pose_from_matrix(t) for t in expected]),
                           payload=pay, temperatures=data.temperatures, frame="T")
    assert np.abs(cmd.legs - data.legs).max() < 1e-9
    # The payloads' centres are in the platform frame: left in the old one, the poses move.
    assert np.abs(frames(data.payload)[:, :3, 3] - expected[:, :3, 3]).max() > 1e-6
    return g


@pytest.mark.parametrize("method", ["efficient", "lm"])
def test_the_job_on_tracker_data_with_effects(tmp_path, noisy, method):
    """iwr.calibrate on reflector points with effects and a noise model: converged, the fit
    (chi-square and the effects' range) passes, a gross error of 1 mm in one reflector is
    found and left out, standard deviations for the effects, the validation poses' accuracy,
    the predicted tool accuracy (the estimator's covariance), and the written calibrated.toml
    (read back by iwr) predicts what the result predicts: {5} moved to the frame the
    reflectors fix and the platform's centre of mass with it."""
    from iwr.reporting.calibration import render

    robot, data, truth = noisy
    bad = data.subset(np.arange(len(data)))
    bad.points[7, 1] += [1.0, 0.0, 0.0]
    cal = iwr.calibrate(robot, bad, method, noise=NOISE, seed=3)
    assert cal.success and cal.fit_ok, cal.result.message
    found = cal.result.outliers
    assert len(found) == 1 and found[0].instrument.startswith("reflector2"), found
    assert found[0].removed
    names = cal.result.parameter_names
    ng = robot.n_params
    assert names[ng: ng + 7] == iwr.effects.parameter_names(robot.effects)
    assert np.all(np.isfinite(cal.uncertainty.std[ng: ng + 7]))
    assert (cal.predicted is not None) == (method == "efficient")
    assert cal.accuracy.calibrated.position.max() < 0.15  # point residuals, mm
    rep = render(cal)
    written = rep.write(tmp_path / "run", plots=False)
    assert {p.name for p in written} >= {"calibrated.toml", "result.json", "report.html"}
    text = rep.text()
    assert "effects on: compliance" in text and "more held" in text
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert [r["name"] for r in summary["effects"]] == names[ng: ng + 7]
    assert [r["correction"] for r in summary["effects"]] == pytest.approx(cal.result.x[ng: ng + 7])
    back = iwr.Robot.from_toml(tmp_path / "run" / "calibrated.toml")
    assert back.effects[0].platform_centre.tolist() != robot.effects[0].platform_centre.tolist()
    _written_robot_predicts_the_result(robot, cal.identification, np.asarray(cal.result.x),
                                       back)


def test_calibrated_robot_moves_the_loads_with_the_platform_frame(measured_with_effects):
    """iwr.tracker.calibrated_robot (what calibrated.toml holds) on the probe: the probe's
    frame fixes {5}; the written robot predicts the noise-free truth's frames and leg commands
    (payload centres moved with {5}), and without moving the platform's centre of mass it
    would not."""
    from iwr.tracker import calibrated_robot

    robot = measured_with_effects("probe")
    data, truth = et.simulate(robot, 15, seed=4, payloads=PAYLOADS)
    written, frame = calibrated_robot(robot, truth)
    assert frame == "probe"
    _written_robot_predicts_the_result(robot, data, truth, written)
    same_centre = written.with_effects(*(
        type(e).from_dict({**e.to_dict(), "platform_centre_mm": [0.0, 0.0, 40.0]}, "e")
        if e.name == "compliance" else e for e in written.effects))
    with pytest.raises(AssertionError):
        _written_robot_predicts_the_result(robot, data, truth, same_centre)


def test_plan_poses_with_payloads_on_tracker_data(measured_with_effects):
    """iwr.plan_poses on tracker data with effects: every candidate once per payload, the
    information of the point objective with the effects under each pose's load over the base
    parameters; the plan identifies them all (full rank)."""
    robot = measured_with_effects("points")
    cand, _ = et.simulate(robot, 40, seed=2, payloads=PAYLOADS[:1])
    plan = iwr.plan_poses(robot, cand, 24, payloads=PAYLOADS, seed=0)
    m = plan.measurements
    assert m.payload is not None and len(m) == 24
    assert len({tuple(p) for p in m.payload}) >= 2  # more than one payload chosen
    problem, x, base, _, _ = et.design(robot, m, None, None)
    jac = problem.jacobian(x)[:, base]
    assert np.linalg.matrix_rank(jac / np.linalg.norm(jac, axis=0)) == base.size
    assert plan.value >= plan.greedy_value > 0


@pytest.mark.slow
def test_iwr_calibrate_and_iwr_report_on_tracker_data_with_effects(tmp_path,
                                                                   measured_with_effects):
    """The commands: `iwr calibrate` with a noise model on reflector points with effects exits
    0 with the effects' values in its summary and writes calibrated.toml that iwr reads back;
    `iwr report` of that run reproduces the verdict; `iwr plan` with payloads writes a plan
    with the payload columns."""
    import os
    import subprocess
    import sys

    robot = measured_with_effects("points")
    robot.to_toml(tmp_path / "robot.toml")

    def run(*args):
        env = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
        return subprocess.run([sys.executable, "-m", "iwr", *args], capture_output=True,
                              text=True, cwd=tmp_path, env=env, timeout=900)

    proc = run("simulate", "--robot", "robot.toml", "--poses", "40", "--seed", "3", "--noise",
               "realistic", "--out", "sim")
    assert proc.returncode == 0, proc.stderr
    proc = run("calibrate", "sim/robot.toml", "sim/measurements.csv", "--noise",
               "legs=0.002,joint_lengths=0.005,joint_angles=5e-6", "--out", "out",
               "--no-plots")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "the model fits the data" in proc.stdout and "leg1.compliance" in proc.stdout
    back = iwr.Robot.from_toml(tmp_path / "out" / "calibrated.toml")
    assert back.effects and back.tracker is not None
    proc = run("report", "out/result.json", "sim/robot.toml", "sim/measurements.csv", "--out",
               "rep", "--no-plots")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "the model fits the data" in proc.stdout
    proc = run("plan", "sim/robot.toml", "--candidates", "sim/measurements.csv", "--poses",
               "25", "--payload", "0,0,0,0", "--payload", "80,50,0,150", "--out", "plan.csv")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "payload_kg" in (tmp_path / "plan.csv").read_text()
