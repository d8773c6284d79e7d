"""The non-geometric effects on double-ballbar data (issue 23; docs/effects.md, "Ballbar data"):
the distances by forward kinematics with the effects and their exact Jacobian, simulate and the
files' payload and temperature columns, the noise-free recovery on fresh poses under other
loads and temperatures."""

from __future__ import annotations

import numpy as np
import pytest
from _ballbar import NOISE, ballbar_robot

import iwr
from iwr.ballbar import effects as be
from iwr.ballbar import read_ballbar, write_ballbar
from iwr.ballbar.api import gauge_aligned
from iwr.effects import api
from iwr.effects import parameter_names as effect_names
from iwr.effects.builtin import STANDARD_GRAVITY
from iwr.effects.model import predicted_readings
from iwr.effects.tracker_study import FRESH_PAYLOADS, PAYLOADS

#: Gravity tilted against every axis of the IWR's carriage (as tests/test_effects_carriage.py's).
TILTED = STANDARD_GRAVITY * np.array([-0.9, 0.3, 0.3]) / np.linalg.norm([-0.9, 0.3, 0.3])


def _robot(carriage: bool = False) -> iwr.Robot:
    plain = ballbar_robot()
    return plain.with_effects(*api.realistic(plain, carriage=carriage))


@pytest.fixture(scope="module")
def case() -> tuple[iwr.Robot, object, np.ndarray]:
    robot = _robot(carriage=True)
    data, truth = be.simulate(robot, 30, seed=5, payloads=PAYLOADS)
    return robot, data, truth


def test_simulated_readings_are_the_truths_with_its_effects(case):
    """The simulated legs are the truth's readings with the effects at the poses whose distances
    the bar reads: the problem's forward kinematics with the effects returns those poses (the
    residuals vanish at the truth), and the geometry alone misses them by micrometres."""
    robot, data, truth = case
    assert data.payload.shape == (30, 4) and data.temperatures.shape == (30, 1)
    problem, start = be.effect_problem(robot, data)
    assert problem.n_params == robot.n_params + 8 + 14
    assert np.abs(problem.residuals(truth)).max() < 1e-9
    ng, ne = robot.n_params, len(effect_names(robot.effects))
    poses = iwr.transforms.pose_from_matrix(problem.platform_frames(truth))
    legs = predicted_readings(robot, truth[: ng + ne], data.q, poses, data)
    assert np.abs(legs - data.legs).max() < 1e-9
    off = truth.copy()
    off[ng: ng + ne] = -np.concatenate([e.values() for e in robot.effects])  # effects removed
    assert np.abs(problem.residuals(off)).max() > 1e-3
    # The geometric problem of the same data misses by as much: the effects are in the data.
    geometric = iwr.ballbar.BallbarProblem(robot.with_effects(), problem.setup, data)
    assert np.abs(geometric.residuals(np.concatenate([truth[:ng], truth[ng + ne:]]))).max() \
        > 1e-3


def test_jacobian_matches_central_differences(case):
    """The exact Jacobian (implicit differentiation of the loop closure with the effects,
    the carriage's compliance included) against central differences, at the truth and at a
    random point within the bounds: the error falls with the step squared down to the forward
    kinematics' round-off."""
    robot, data, truth = case
    problem, _ = be.effect_problem(robot, data)
    rng = np.random.default_rng(1)
    for x in (truth, problem.lower + (problem.upper - problem.lower) * rng.random(truth.size)):
        _, jac = problem.residuals_and_jacobian(x)
        worst = {}
        for h in (1e-3, 1e-4):
            err = 0.0
            for i in range(problem.n_params):
                e = np.zeros(problem.n_params)
                e[i] = h * (problem.upper[i] - problem.lower[i])
                fd = (problem.residuals(x + e) - problem.residuals(x - e)) / (2 * e[i])
                err = max(err, np.abs(fd - jac[:, i]).max() / np.abs(jac[:, i]).max())
            worst[h] = err
        assert worst[1e-3] < 1e-6, worst
        assert worst[1e-4] < 1e-5, worst


@pytest.mark.parametrize("carriage", [False, True])
def test_the_cheaper_cost_solves_the_same_forward_kinematics(carriage):
    """The residuals (what DE, CRS2, BOBYQA and LM's trial steps evaluate) solve the forward
    kinematics with the geometry's pose Jacobian, at the joints the carriage's compliance
    changed when it is on: the same poses as the exact Newton's method of the Jacobian's
    evaluation, to its tolerance, at the truth, at a random point within the bounds and at the
    upper bounds (where the effects change the pose Jacobian most)."""
    robot = _robot(carriage=carriage)
    data, truth = be.simulate(robot, 12, seed=8, payloads=PAYLOADS)
    problem, _ = be.effect_problem(robot, data)
    rng = np.random.default_rng(2)
    for x in (truth, problem.lower + (problem.upper - problem.lower) * rng.random(truth.size),
              problem.upper):
        cheap = problem.residuals(x)
        exact = problem.residuals_and_jacobian(x)[0]
        assert np.all(np.isfinite(cheap)) and np.all(np.isfinite(exact))
        assert np.abs(cheap - exact).max() < 1e-9
        assert problem.cost_batch(x[None])[0] == pytest.approx(float(exact @ exact), rel=1e-9)


def test_files_carry_the_payload_and_temperature_columns(tmp_path, case):
    robot, data, _ = case
    path = tmp_path / "bar.csv"
    write_ballbar(path, data)
    header = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")][0]
    assert header.endswith("setup,distance_mm,payload_kg,payload_x_mm,payload_y_mm,"
                           "payload_z_mm,T_C")
    back = read_ballbar(path, robot.joint_types, robot.instruments["ballbar"])
    np.testing.assert_array_equal(back.payload, data.payload)
    np.testing.assert_array_equal(back.temperatures, data.temperatures)
    np.testing.assert_array_equal(back.distance, data.distance)
    sub = back.subset([3, 1])
    np.testing.assert_array_equal(sub.payload, data.payload[[3, 1]])
    # A bad temperature is named by its line and column.
    text = path.read_text().splitlines()
    first = next(i for i, ln in enumerate(text) if not ln.startswith("#")) + 1
    text[first] = text[first].rsplit(",", 1)[0] + ",hot"
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(iwr.measurements.MeasurementFileError, match=r"line \d+, column T_C"):
        read_ballbar(path, robot.joint_types, robot.instruments["ballbar"])


def test_the_thermal_effect_needs_temperatures(case):
    robot, data, _ = case
    bare = iwr.ballbar.BallbarMeasurements(data.q, data.legs, data.setup, data.distance,
                                           joint_types=data.joint_types, payload=data.payload)
    with pytest.raises(ValueError, match="needs each pose's temperature"):
        be.effect_problem(robot, bare)


def test_noise_free_recovery_on_fresh_poses_with_other_loads():
    """Issue 23's first check on ballbar data: from noise-free data (three payloads, a day's
    temperatures; the legs' compliance and expansion and the carriage's compliance) LM recovers
    the parameters so that tool poses (modulo the ballbar's gauge, as without effects) and leg
    commands on 50 fresh poses with other loads and temperatures agree with the truth to 1e-6
    mm; the geometry alone misses by micrometres."""
    robot = _robot(carriage=True)
    data, truth = be.simulate(robot, 80, seed=3, payloads=PAYLOADS)
    res = iwr.identify(robot, data, "lm")  # every parameter free (LM's default)
    assert res.success, res.message
    ng, ne = robot.n_params, len(effect_names(robot.effects))
    np.testing.assert_allclose(res.x[ng: ng + ne], truth[ng: ng + ne], rtol=0, atol=1e-6)
    fresh, _ = be.simulate(robot, 50, seed=99, x=truth, payloads=FRESH_PAYLOADS,
                           temperatures=np.linspace(14.0, 30.0, 50))
    acc = iwr.accuracy(robot, fresh, res.x, truth=truth)
    assert acc.calibrated.position.max() < 1e-6 < acc.nominal.position.min()
    assert acc.calibrated.orientation.max() < 1e-6
    readings = iwr.accuracy(robot, fresh, res.x)  # the bar's readings, no truth needed
    assert readings.calibrated.position.max() < 1e-6 < readings.nominal.position.max()
    # Leg commands for the true platform frames (in the calibration's gauge) under the fresh
    # poses' loads and temperatures: the truth's readings.
    problem, _ = be.effect_problem(robot, fresh)
    model, true = problem.platform_frames(res.x), problem.platform_frames(truth)
    targets = gauge_aligned(true, model)
    legs = be.leg_commands(robot, res.x, targets, fresh.q, fresh)
    assert np.abs(legs - fresh.legs).max() < 1e-6
    geometric = res.x.copy()
    geometric[ng: ng + ne] = -np.concatenate([e.values() for e in robot.effects])
    assert np.abs(be.leg_commands(robot, geometric, targets, fresh.q, fresh)
                  - fresh.legs).max() > 1e-3


def test_effects_off_leave_ballbar_files_as_they_were(tmp_path, case):
    """Data without loads or temperatures (a robot without effects) are written without their
    columns, and read back without them."""
    robot, _, _ = case
    plain = robot.with_effects()
    data, _ = iwr.simulate(plain, 12, seed=4)
    assert data.payload is None and data.temperatures is None
    path = tmp_path / "plain.csv"
    write_ballbar(path, data)
    header = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")][0]
    assert header.endswith(",s6_mm,setup,distance_mm")
    back = read_ballbar(path, plain.joint_types, plain.instruments["ballbar"])
    assert back.payload is None and back.temperatures is None


@pytest.mark.parametrize("payloads, inseparable", [
    ([[80.0, 50.0, 0.0, 150.0]], ["joint1.compliance", "joint2.compliance"]),
    ([[0.0, 0.0, 0.0, 0.0], [80.0, 50.0, 0.0, 150.0]], []),
])
def test_one_payload_leaves_the_slides_in_the_geometry(payloads, inseparable):
    """Issue 23's third check on ballbar data: gravity tilted so that every carriage joint is
    loaded (tests/test_effects_carriage.py), a slide keeps its load at every pose under one
    payload, and its compliance is a constant shift of the robot, which ballbar data cannot see
    (a translation of {0}, docs/ballbar.md): the report names the slides' compliances; a second
    payload separates them. The rank of the analytic Jacobian is that of a finite-difference
    one, over every parameter and over the active ones."""
    from iwr.effects.carriage import CarriageCompliance

    plain = ballbar_robot()
    # At the file's compliances 0 (as the pose data's test): the rank then has no directions
    # that only the loads fix.
    robot = plain.with_effects(CarriageCompliance(400.0, [20.0, -10.0, 150.0], 120.0,
                                                  [0.0, 0.0, 40.0], TILTED, None, [0.0] * 4))
    data, _ = be.simulate(robot, 60, seed=6, payloads=np.asarray(payloads))
    report = iwr.identifiability(robot, data)
    assert [name for name, _ in report.inseparable] == inseparable
    assert report.effects_identifiable == (not inseparable)
    assert ("NOT separable" in str(report)) == bool(inseparable)
    assert report.rank == 56 + 4 - len(inseparable)  # the geometry's 42 + 7 S, S = 2
    # Its size, for the observability's O1 (it was 0: the report built positionally), and the
    # report every kind prints (it printed the rank alone).
    assert (report.n_poses, report.n_readings) == (60, 60)
    assert f"condition number (identifiable part) {report.condition_number:.4g}" in str(report)
    problem, x = be.effect_problem(robot, data)
    steps = np.full(x.size, 1e-5)
    steps[robot.n_params: robot.n_params + 4] = 1e-3  # the compliances
    fd = np.column_stack([(problem.residuals(x + h * e) - problem.residuals(x - h * e)) / (2 * h)
                          for h, e in zip(steps, np.eye(x.size), strict=True)])
    scaled = fd / np.where(np.linalg.norm(fd, axis=0) > 0, np.linalg.norm(fd, axis=0), 1)
    for cols in (np.ones(x.size, dtype=bool), report.active):
        s = np.linalg.svd(scaled[:, cols], compute_uv=False)
        assert int(np.sum(s > 1e-7 * s[0])) == (report.rank if cols.all() else cols.sum())
    assert not [n for n in inseparable if report.active[problem.parameter_names.index(n)]]


@pytest.fixture(scope="module")
def noisy() -> tuple[iwr.Robot, object, np.ndarray]:
    robot = _robot()
    data, truth = be.simulate(robot, 100, seed=7, payloads=PAYLOADS, noise=NOISE)
    return robot, data, truth


def test_efficient_estimator_with_effects_on_noisy_distances(noisy):
    """The efficient estimator on ballbar data with effects: converges, its fit test passes,
    its base parameters hold the ballbar's null directions and the directions only the loads
    fix (the report's), the effects are identified; the weighted LM on the same base parameters
    reaches the same tool accuracy on fresh poses under other loads (within 10 %), and the
    estimator's covariance predicts it there (within the scatter of one seed: a factor 1.6)."""
    robot, data, truth = noisy
    res = iwr.identify(robot, data, "efficient", noise=NOISE)
    assert res.success, res.message
    report = iwr.identifiability(robot, data)
    np.testing.assert_array_equal(res.active, report.active)
    ng, ne = robot.n_params, len(effect_names(robot.effects))
    assert res.active[ng: ng + ne].all()
    lm = iwr.identify(robot, data, "lm", noise=NOISE, active="base")
    assert lm.success, lm.message
    assert lm.fit.p_value > 1e-3
    fresh, _ = be.simulate(robot, 50, seed=98, x=truth, payloads=FRESH_PAYLOADS,
                           temperatures=np.linspace(14.0, 30.0, 50))
    errors = [float(np.sqrt(np.mean(iwr.accuracy(robot, fresh, r.x, truth=truth)
                                    .calibrated.position ** 2))) for r in (res, lm)]
    assert abs(errors[1] / errors[0] - 1) < 0.1
    predicted = be.predicted_accuracy(robot, fresh, res.x, res.covariance, res.active)
    assert 1 / 1.6 < errors[0] / predicted.position_rms < 1.6
    # The predicted accuracy is the RMS of models drawn from the covariance (first order).
    rng = np.random.default_rng(0)
    chol = np.linalg.cholesky(res.covariance)
    drawn = []
    for _ in range(30):
        x = res.x.copy()
        x[res.active] += chol @ rng.standard_normal(chol.shape[0])
        drawn.append(iwr.accuracy(robot, fresh, x, truth=res.x).calibrated.position)
    assert abs(float(np.sqrt(np.mean(np.square(drawn)))) / predicted.position_rms - 1) < 0.15


def test_uncertainty_and_misclosures_with_effects(noisy):
    robot, data, truth = noisy
    unc = iwr.uncertainty(robot, data, truth, NOISE)
    ng, ne = robot.n_params, len(effect_names(robot.effects))
    assert unc.parameter_names[ng: ng + ne] == effect_names(robot.effects)
    assert np.all(np.isfinite(unc.std[ng: ng + ne]))
    # The misclosures' reading derivatives are exact with the effects: a leg reading moved by
    # h moves the residual by the leg column times h (the residual's central difference).
    m = iwr.ballbar.effects.misclosures(robot, data, truth, NOISE)
    problem, _ = be.effect_problem(robot, data)
    h = 1e-4
    for j in (0, 5):
        up, down = (iwr.ballbar.BallbarMeasurements(
            data.q, data.legs + s * h * np.eye(6)[j], data.setup, data.distance,
            joint_types=data.joint_types, payload=data.payload,
            temperatures=data.temperatures) for s in (1, -1))
        fd = (be.effect_problem(robot, up)[0].residuals(truth)
              - be.effect_problem(robot, down)[0].residuals(truth)) / (2 * h)
        np.testing.assert_allclose(m.b[:, 0, j], fd, rtol=1e-5, atol=1e-8)
    assert problem.n_params == truth.size


def test_the_calibration_job_and_its_report(tmp_path, noisy):
    """iwr calibrate on a ballbar robot with effects: the job runs every step with the effects
    (identifiability, the estimator, the fit test, the gross-error screen, the uncertainty, the
    predicted accuracy), writes calibrated.toml with the identified effect values, and the
    report has its Effects section and the directions only the loads fix."""
    from iwr.cli import main

    robot, data, _ = noisy
    robot.to_toml(tmp_path / "robot.toml")
    write_ballbar(tmp_path / "bar.csv", data)
    out = tmp_path / "run"
    code = main(["calibrate", str(tmp_path / "robot.toml"), str(tmp_path / "bar.csv"),
                 "--noise", "legs=0.002,joint_lengths=0.005,joint_angles=5e-6", "-o", str(out)])
    assert code in (0, 4), code  # 4: calibrated, the fit test failed (none expected here)
    summary = __import__("json").loads((out / "summary.json").read_text())
    assert [r["name"] for r in summary["effects"]] == effect_names(robot.effects)
    md = (out / "report.md").read_text()
    assert "## Effects" in md and "fixed by the loads alone" in md
    import tomllib

    # (Read as TOML, not as a robot: an identified compliance beyond the plausible maximum by
    # less than the noise explains passes the range test, but the robot reader refuses it.)
    table = tomllib.loads((out / "calibrated.toml").read_text())["effects"]
    identified = [r["value"] for r in summary["effects"]]
    np.testing.assert_allclose(table["compliance"]["compliance_um_per_N"], identified[:6])
    assert table["thermal"]["alpha_ppm_per_K"] == pytest.approx(identified[6])
    assert "ballbar" in tomllib.loads((out / "calibrated.toml").read_text())


def test_plan_poses_and_payloads_with_effects():
    """iwr.plan_poses on a ballbar robot with effects chooses (pose, set-up, payload) triples
    over the base parameters of the distances with the effects; the plan measured in a
    simulation (iwr.ballbar.effects.measure) is calibrated data of that robot."""
    robot = _robot()
    rng = np.random.default_rng(2)
    q, poses, _ = iwr.simulation.sample_poses(robot.with_effects(), 150, rng)
    plan = iwr.plan_poses(robot, (q, poses), 80, payloads=PAYLOADS[:2], temperatures=20.0,
                          seed=1)
    m = plan.measurements
    assert len(m) == 80 and set(np.unique(m.payload[:, 0])) == {0.0, 80.0}
    assert set(m.setup) == {"A", "B"}
    _, truth = be.simulate(robot, 2, seed=3)
    data = be.measure(robot, truth, m, NOISE, seed=4)
    assert data.payload is not None and len(data) == 80
    problem, _ = be.effect_problem(robot, data)
    assert np.abs(problem.residuals(truth)).max() < 0.05  # the noise's size, not the errors'
    with pytest.raises(ValueError, match="iwr.ballbar.effects.measure"):
        iwr.planning.measure(robot, truth, m.q, m.poses, NOISE, setup=m.setup)


def test_leg_commands_of_the_calibrated_robot(case):
    """The library's compensation (iwr.effects.api.leg_commands, what iwr legs runs) on the
    robot file a ballbar calibration with effects writes (iwr.effects.api.apply), targets in
    {0} (frame "0": a ballbar registers no frame), gives the readings of the truth under each
    pose's load and temperature; the ballbar module's leg commands agree."""
    robot, data, truth = case
    problem, _ = be.effect_problem(robot, data)
    frames = problem.platform_frames(truth)
    n_re = problem.n_params - problem.setup.n_params
    calibrated = api.apply(robot, truth[:n_re])
    cmd = api.leg_commands(calibrated, data.q, iwr.transforms.pose_from_matrix(frames),
                           payload=data.payload, temperatures=data.temperatures[:, 0],
                           frame="0")
    assert np.abs(cmd.legs - data.legs).max() < 1e-9
    assert np.abs(be.leg_commands(robot, truth, frames, data.q, data) - data.legs).max() < 1e-9


def test_a_run_read_again_tests_the_range_as_the_run_did(noisy):
    """iwr report re-checks an effect's range on a run read back
    (iwr.calibration.effects_in_range) with the standard deviations the run's fit check used:
    an effect outside its range by less than the noise explains passes both (on data other
    than poses in {0} the re-check took none, and failed it)."""
    from iwr.calibration import effects_in_range
    from iwr.effects.problem import out_of_range

    robot, data, _ = noisy
    res = iwr.identify(robot, data, "lm", active="base")
    assert out_of_range(robot, res.x, res.parameter_names)  # outside its range: not vacuous
    assert res.fit.fit_ok, res.fit.causes
    again = effects_in_range(robot, data, res)
    assert again.fit.fit_ok and again.success == res.success
