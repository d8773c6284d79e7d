"""The carriage's compliance on laser-tracker data (issue 23, docs/effects.md, "Tracker data"):
the carriage's joints change under the gravity load of what they carry, gravity given in {T}
and carried into {0} by the identified registration; the numpy model and its exact Jacobian,
the C++ objective, the noise-free recovery, what one payload cannot separate, and the job."""

from __future__ import annotations

import numpy as np
import pytest

import iwr
from iwr.effects import api, tracker_study
from iwr.effects import tracker as et
from iwr.effects.carriage import CarriageCompliance
from iwr.effects.model import predicted_readings

PAYLOADS, FRESH_PAYLOADS = tracker_study.PAYLOADS, tracker_study.FRESH_PAYLOADS
#: Gravity in {T} tilted so that every joint of the test IWR's carriage carries a load in {0}
#: (the slides too: a levelled tracker puts gravity along {0}'s -z there).
TILTED = (2.5, -1.5, -9.4)
#: Realistic compliances of the four joints (docs/effects.md, "Realistic magnitudes"), larger for
#: the slides so that their part shows above round-off in a few poses.
CARRIAGE = (0.01, 0.01, 0.02, 0.02)


def carriage_robot(plain, *, legs=True, thermal=True, gravity=TILTED, joints=(1, 2, 3, 4),
                   compliance=CARRIAGE):
    """``plain`` (a tracker robot) with its tracker's gravity ``gravity`` in {T}, the carriage's
    compliance of ``joints`` (400 kg hexapod, 120 kg platform, as api.realistic) and, when asked,
    the legs' realistic compliance and thermal growth."""
    s = plain.tracker
    setup = iwr.tracker.TrackerSetup(s.registration, reflectors=s.reflectors, probe=s.probe,
                                     probe_length=s.probe_length,
                                     names=s.names if s.kind == "points" else None,
                                     gravity=list(gravity))
    plain = plain.with_effects().with_tracker(setup=setup)
    comp, thermal_effect = api.realistic(plain)
    carriage = CarriageCompliance(400.0, [0.0, 0.0, 150.0], 120.0, [0.0, 0.0, 40.0],
                                  comp.gravity, list(joints),
                                  [compliance[j - 1] for j in joints])
    effects = ((comp,) if legs else ()) + ((thermal_effect,) if thermal else ()) + (carriage,)
    return plain.with_effects(*effects)


@pytest.fixture(scope="module", params=["points", "probe"])
def case(request, measured_with_effects):
    robot = carriage_robot(measured_with_effects(request.param))
    data, truth = et.simulate(robot, 6, seed=11, payloads=PAYLOADS)
    return robot, data, truth


def _step(name: str) -> float:
    """A central-difference step per parameter: its unit's scale over 1e6 or so."""
    if name.endswith("compliance"):
        return 1e-4  # um/N, urad/(N m)
    if name == "legs.alpha":
        return 1e-2  # ppm/K
    if name.split(".")[-1] in ("dalpha", "dtheta", "rx", "ry", "rz"):
        return 1e-7  # rad
    return 1e-5  # mm


def test_every_joint_carries_a_load_in_the_tests(case):
    """The premise of the checks below: under the tilted gravity every joint is loaded, so
    every compliance changes the points."""
    from iwr.effects.model import joint_changes, split

    robot, data, truth = case
    model = et.TrackerEffectModel(robot, robot.tracker, data)
    xr, xs = model.split(truth)
    poses = model.forward(truth)[0]
    rg = et.with_gravity(robot, et.registration_gravity(robot.tracker, xs)[0])
    xg, xe = split(robot, xr)
    change = joint_changes(rg, xg, xe, data.q, iwr.transforms.pose_matrix(poses), data)[0]
    assert np.all(np.abs(change).min(axis=0) > 1e-6)  # mm (slides) or rad (revolute joints)


def test_gravity_jacobian_with_the_carriage_matches_finite_differences(case):
    """The readings' derivative in gravity (in {0}) now has the carriage's part: its joints'
    loads are linear in gravity, the legs are not linear in the joints (central differences,
    relative 1e-6)."""
    robot, data, truth = case
    model = et.TrackerEffectModel(robot, robot.tracker, data)
    xr, xs = model.split(truth)
    poses = model.forward(truth)[0]
    g0 = et.registration_gravity(robot.tracker, xs)[0]
    jg = et.gravity_jacobian(et.with_gravity(robot, g0), xr, data.q, poses, data)
    plain = robot.with_effects(*robot.effects[:-1])
    n_carriage = len(robot.effects[-1].parameter_names())
    jg_legs = et.gravity_jacobian(et.with_gravity(plain, g0), xr[:-n_carriage], data.q, poses,
                                  data)
    assert np.abs(jg - jg_legs).max() > 1e-5  # mm per m/s^2: the carriage's part
    for c in range(3):
        e = np.zeros(3)
        e[c] = 1e-3
        fd = (predicted_readings(et.with_gravity(robot, g0 + e), xr, data.q, poses, data)
              - predicted_readings(et.with_gravity(robot, g0 - e), xr, data.q, poses, data)) / 2e-3
        np.testing.assert_allclose(jg[..., c], fd, rtol=1e-6, atol=1e-10)


def test_objective_jacobian_with_the_carriage_matches_central_differences(case):
    """The points' (probe's) Jacobian in every parameter, geometric, effects' and setup's (the
    registration's tilts through gravity too), against central differences (relative 1e-5), at
    a point away from the solution; the forward kinematics closes the legs with the carriage's
    change."""
    robot, data, truth = case
    problem, start = et.effect_tracker_problem(robot, data)
    x = 0.5 * (start + truth)
    r, jac = problem.residuals_and_jacobian(x)
    np.testing.assert_array_equal(r, problem.residuals(x))
    names = problem.parameter_names
    assert names[robot.n_params + 7:robot.n_params + 11] == [
        f"joint{j}.compliance" for j in range(1, 5)]
    for i, name in enumerate(names):
        h = _step(name)
        e = np.zeros(problem.n_params)
        e[i] = h
        fd = (problem.residuals(x + e) - problem.residuals(x - e)) / (2 * h)
        scale = max(np.abs(jac[:, i]).max(), 1e-12)
        err = np.abs(fd - jac[:, i]).max()
        assert err <= 1e-5 * scale + 1e-9, (name, err, scale)
    # The carriage's compliances move the points by more than round-off.
    ng = robot.n_params
    assert np.abs(jac[:, ng + 7: ng + 11]).max(axis=0).min() > 1e-4  # mm per unit
    # The legs close: the readings with the carriage's change at the solved poses.
    model = problem.model
    poses, ok = model.forward(x)
    xr, xs = model.split(x)
    rg = et.with_gravity(robot, et.registration_gravity(robot.tracker, xs)[0])
    assert ok.all()
    assert np.abs(predicted_readings(rg, xr, data.q, poses, data) - data.legs).max() < 1e-10


def test_loop_model_jacobians_with_the_carriage(case):
    """The efficient estimator's loop model (legs at corrected readings with the carriage's
    change, points): its derivatives in the parameters (the setup's through gravity) and in
    the corrections against central differences."""
    robot, data, truth = case
    setup = robot.tracker
    problem, start = et.effect_tracker_problem(robot, data)
    x = 0.5 * (start + truth)
    ref = problem.model.forward(x)[0]
    n, nj = len(data), robot.n_joints
    measured = data.tracker_points(setup) if setup.kind == "points" else data.probe
    blocks = setup.n_points if setup.kind == "points" else 2  # 3 x 3 whitening per block
    sigma = np.hstack([np.full((n, 6), 0.002), np.full((n, nj), 1e-3)])
    model = et.loop_model(robot, setup, data, ref, np.ascontiguousarray(measured),
                          np.tile(np.eye(3).ravel() / 0.01, (n, blocks)), sigma)
    corr = np.random.default_rng(4).normal(0, 1e-3, (n, nj + 6))
    r, rx, ry = model(x, corr, True)
    names = problem.parameter_names
    for i in [names.index(k) for k in ("joint4.dtheta", "joint3.compliance", "joint1.compliance",
                                       "leg2.compliance", "tracker.rx", "tracker.ry")]:
        h = _step(names[i])
        e = np.zeros(x.size)
        e[i] = h
        fd = (model(x + e, corr, False)[0] - model(x - e, corr, False)[0]) / (2 * h)
        np.testing.assert_allclose(rx[..., i], fd, rtol=0,
                                   atol=1e-5 * np.abs(rx[..., i]).max() + 1e-7)
    for c in range(nj + 6):
        e = np.zeros_like(corr)
        e[:, c] = 1e-6
        fd = (model(x, corr + e, False)[0] - model(x, corr - e, False)[0]) / 2e-6
        np.testing.assert_allclose(ry[..., c], fd, rtol=0,
                                   atol=1e-5 * np.abs(ry[..., c]).max() + 1e-7)


def test_the_paths_that_refused_it_model_it(measured_with_effects):
    """The carriage's compliance was refused on tracker data by name (simulate, identify,
    identifiability, accuracy); each now models it: the data simulated with it fit the model
    with it exactly, and without it they do not."""
    plain = measured_with_effects("points")
    robot = plain.with_effects(*api.realistic(plain.with_effects(), carriage=True))
    assert any("joints" in e.changes for e in robot.effects)
    data, truth = et.simulate(robot, 10, seed=1)
    problem, _ = et.effect_tracker_problem(robot, data)
    assert problem.cost(truth) < 1e-20 and float(problem.residuals(truth) @ problem.residuals(
        truth)) < 1e-20
    ns = iwr.identifiability(robot, data, truth)
    assert len(ns.left_out) >= 10
    assert iwr.accuracy(robot, data, truth).calibrated.position.max() < 1e-9
    rigid = truth.copy()
    ng, ne = robot.n_params, len(iwr.effects.parameter_names(robot.effects))
    carriage = [i for i, n in enumerate(problem.parameter_names) if n.startswith("joint")
                and n.endswith(".compliance")]
    assert carriage and carriage[-1] < ng + ne
    rigid[carriage] = -robot.effects[-1].values()
    assert problem.cost(rigid) > 1e-6  # mm^2: the carriage's compliance is in the data


# -- the C++ objective (cpp/src/effects_tracker.cpp) ---------------------------------------------


@pytest.mark.parametrize("kind", ["points", "probe"])
@pytest.mark.parametrize("name", ["with the legs' effects", "the carriage alone",
                                  "the carriage and the thermal effect", "joints 3 and 4"])
def test_cpp_objective_with_the_carriage_agrees_with_the_numpy_model(monkeypatch,
                                                                     measured_with_effects,
                                                                     kind, name):
    """The C++ residuals against the numpy model's (its forward kinematics solved to 1e-13 mm)
    at the truth, the start and random points within the bounds (the carriage's compliances up
    to their bound, 0.5 urad/(N m)): within 1e-11 mm; the costs the residuals' squares, the
    batch the same bits on 1 and 2 threads; the platform poses numpy's; every pose solved by
    chord steps, and far outside the bounds by Newton's method."""
    plain = measured_with_effects(kind)
    robot = carriage_robot(plain, legs=name == "with the legs' effects",
                           thermal=name != "the carriage alone",
                           joints=(3, 4) if name == "joints 3 and 4" else (1, 2, 3, 4))
    data, truth = et.simulate(robot, 8, seed=7, payloads=PAYLOADS,
                              hidden=0.2 if kind == "points" else 0.0)
    problem, start = et.effect_tracker_problem(robot, data)
    monkeypatch.setattr(et, "FK_TOLERANCE_MM", 1e-13)
    rng = np.random.default_rng(3)
    lo, hi = problem.lower, problem.upper
    X = np.vstack([truth, start, lo + (hi - lo) * rng.random((3, problem.n_params)), hi])
    cpp = problem._objective()
    worst = 0.0
    for x in X:
        rn = problem.residuals(x)
        rc = cpp.residuals(x)
        assert np.all(np.isfinite(rc)) and not problem.failures(x)
        worst = max(worst, np.abs(rc - rn).max())
        assert problem.cost(x) == pytest.approx(float(rn @ rn), rel=1e-11)
    assert worst < 1e-11, worst
    assert problem.cost(truth) < 1e-20
    costs = problem.cost_batch(X, workers=1)
    np.testing.assert_array_equal(costs, problem.cost_batch(X, workers=2))
    np.testing.assert_array_equal(costs, [problem.cost(x) for x in X])
    np.testing.assert_allclose(cpp.platform_poses(X[2]), problem.platform_poses(X[2]),
                               rtol=0, atol=1e-11)
    # By chord steps in {0} (the reference's statics carried by the carriage's rotation); three
    # hundred times as far from the bounds' centre they do not converge, and Newton's method from
    # the reference (in {0}) solves the poses, to numpy's residuals too.
    for x in X:
        np.testing.assert_array_equal(cpp.solve_paths(x), 0)
    far = (lo + hi) / 2 + 300 * (X[2] - (lo + hi) / 2)
    np.testing.assert_array_equal(cpp.solve_paths(far), 1)
    assert np.abs(cpp.residuals(far) - problem.residuals(far)).max() < 1e-11


def test_weighted_cpp_objective_with_the_carriage(measured_with_effects):
    """The noise-weighted point objective with the carriage's compliance: the C++ cost is the
    sum of the numpy model's whitened residuals (the readings' noise propagated through the loop
    closure with the carriage's change), the same bits on 1 and 2 threads."""
    robot = carriage_robot(measured_with_effects("points"))
    noise = (iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6),
             iwr.tracker.TrackerNoise.leica())
    data, truth = et.simulate(robot, 8, seed=5, payloads=PAYLOADS, noise=noise)
    problem, start = et.effect_tracker_problem(robot, data, noise=noise)
    assert problem.whitening is not None
    X = np.vstack([truth, start, 0.5 * (start + truth)])
    for x in X:
        r = problem.residuals(x)
        assert problem.cost(x) == pytest.approx(float(r @ r), rel=1e-10)
        assert problem.cost_unweighted(x) != pytest.approx(problem.cost(x), rel=1e-3)
    np.testing.assert_array_equal(problem.cost_batch(X, workers=1),
                                  problem.cost_batch(X, workers=2))


def test_reading_jacobian_with_the_carriage(case, reading_jacobian_matches_differences):
    """The points' derivatives in the joint and leg readings through the loop closure with the
    carriage's change (it depends on the joint readings: the loads are taken there), what the
    weights, the uncertainty and the gross-error screen propagate the readings' noise by,
    against central differences of the forward kinematics with the effects."""
    robot, data, truth = case
    reading_jacobian_matches_differences(robot, data, truth)


def test_problem_file_and_engine_with_the_carriage(tmp_path, measured_with_effects):
    """The problem file carries the carriage's table on tracker data (the reader refused it);
    the round trip is bit for bit and iwr-engine's objective gives the same costs."""
    from iwr import _core
    from iwr.problem_file import encode_problem, read_problem

    for kind in ("points", "probe"):
        robot = carriage_robot(measured_with_effects(kind))
        data, truth = et.simulate(robot, 8, seed=4, payloads=PAYLOADS)
        problem, start = et.effect_tracker_problem(robot, data)
        path = tmp_path / f"{kind}.iwrp"
        problem.save(path, x0=start)
        d = read_problem(path)
        assert [name for name, _ in d["effects"]] == ["compliance", "thermal",
                                                      "carriage_compliance"]
        np.testing.assert_array_equal(d["tracker_gravity"], TILTED)
        back = iwr.Problem.load(path)
        assert isinstance(back, et.TrackerEffectProblem) and back.robot.effects == robot.effects
        assert encode_problem(back, x0=start) == encode_problem(problem, x0=start)
        X = np.vstack([truth, start, problem.lower + 0.3 * (problem.upper - problem.lower)])
        costs = problem.cost_batch(X)
        np.testing.assert_array_equal(back.cost_batch(X), costs)
        np.testing.assert_array_equal(_core._engine_costs(str(path), X), costs)


# -- what the data recover and what they separate ------------------------------------------------


@pytest.mark.parametrize("kind", ["points", "probe"])
def test_noise_free_recovery_with_the_carriage(kind, measured_with_effects):
    """Issue 23's check on tracker data with the carriage's compliance, the legs' compliance and
    thermal growth: from noise-free data under three payloads (every parameter free), tool poses
    and leg commands on 50 fresh poses with other loads and temperatures agree with the truth
    to 1e-6 mm (the tool frames modulo nothing: the registration is identified with the rest,
    as tests/test_effects_tracker.py's); commands that leave the carriage's compliance out miss
    by micrometres."""
    robot = carriage_robot(measured_with_effects(kind))
    data, truth = et.simulate(robot, 30, seed=3, payloads=PAYLOADS)
    res = iwr.identify(robot, data, "lm")
    assert res.success, res.message
    ng = robot.n_params
    np.testing.assert_allclose(res.x[ng: ng + 11], truth[ng: ng + 11], atol=1e-7)
    fresh, _ = et.simulate(robot, 50, seed=99, x=truth, payloads=FRESH_PAYLOADS,
                           temperatures=np.linspace(14.0, 30.0, 50))
    a = et.tool_frames(robot, res.x, fresh)
    b = et.tool_frames(robot, truth, fresh)
    assert np.abs(a[:, :3, 3] - b[:, :3, 3]).max() < 1e-6
    assert np.abs(a[:, :3, :3] - b[:, :3, :3]).max() < 1e-9
    legs = et.leg_commands(robot, res.x, b, fresh.q, fresh)
    assert np.abs(legs - fresh.legs).max() < 1e-6
    rigid = res.x.copy()
    rigid[ng + 7: ng + 11] = -robot.effects[-1].values()
    assert np.abs(et.leg_commands(robot, rigid, b, fresh.q, fresh) - fresh.legs).max() > 1e-3
    assert iwr.accuracy(robot, fresh, res.x, truth=truth).calibrated.position.max() < 1e-6


@pytest.mark.parametrize("payloads, inseparable", [
    (PAYLOADS[1:2], ["joint1.compliance", "joint2.compliance"]),  # the 80 kg head throughout
    (PAYLOADS[:2], []),                                            # none and the head
])
def test_one_payload_leaves_the_slides_in_the_geometry_on_tracker_data(
        measured_with_effects, payloads, inseparable):
    """The design rule on tracker data: a slide whose axis keeps its direction to gravity
    carries the same force at every pose under one payload, so its change is a translation of
    everything after it, which the geometry and the registration absorb (iwr.identifiability
    names it among the left-out parameters; the default parameters leave it out); a second
    payload separates it. The revolute joints' torques vary with the pose: one payload
    separates them. The rank of the analytic Jacobian (over the base parameters and the four
    compliances) is that of a central-difference one: a rank gap of 2 (one payload) or 0 (two)
    at 1e-7 of the largest singular value, where the gap is below 1e-16 (analytic) and 1e-8
    (differences) and the base parameters' weakest is 3e-4."""
    # At the file's compliances 0 (as the pose data's test, tests/test_effects_carriage.py).
    robot = carriage_robot(measured_with_effects("points"), legs=False, thermal=False,
                           compliance=(0.0, 0.0, 0.0, 0.0))
    x = np.zeros(robot.n_params + 4 + robot.tracker.n_params)
    data, _ = et.simulate(robot, 30, seed=6, x=x, payloads=payloads)
    report = iwr.identifiability(robot, data, x)
    assert [n for n in report.left_out if n.endswith(".compliance")] == inseparable
    problem, _ = et.effect_tracker_problem(robot, data)
    names = problem.parameter_names
    base = et.base_parameters(robot, data, x)
    compliances = np.array([n.endswith(".compliance") for n in names])
    assert [n for n, b in zip(names, base & compliances, strict=True) if b] == [
        f"joint{j}.compliance" for j in range(1, 5) if f"joint{j}.compliance" not in inseparable]
    cols = np.flatnonzero(base | compliances)
    steps = np.where(compliances, 1e-3, 1e-5)
    fd = np.column_stack([(problem.residuals(x + steps[i] * np.eye(x.size)[i])
                           - problem.residuals(x - steps[i] * np.eye(x.size)[i])) / (2 * steps[i])
                          for i in cols])

    def rank(m):
        s = np.linalg.svd(m / np.linalg.norm(m, axis=0), compute_uv=False)
        return int(np.sum(s > 1e-7 * s[0]))

    assert rank(problem.jacobian(x)[:, cols]) == rank(fd) == cols.size - len(inseparable)
    assert report.rank == len(names) - len(report.left_out)


# -- the estimator and the job ---------------------------------------------------------------------

NOISE = (iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6),
         iwr.tracker.TrackerNoise.leica())


def test_efficient_estimator_with_the_carriage_on_noisy_points(measured_with_effects):
    """The efficient estimator on noisy reflector points with the carriage's, the legs'
    compliance and thermal growth (three payloads): it converges, the chi-square fit test and
    the effects' range pass, and the carriage's compliances are within 4 standard deviations of
    the truth (the revolute joints' to a small fraction of their size)."""
    robot = carriage_robot(measured_with_effects("points"))
    data, truth = et.simulate(robot, 40, seed=2, noise=NOISE, payloads=PAYLOADS)
    res = iwr.identify(robot, data, "efficient", noise=NOISE, outliers="off")
    assert res.success and res.fit.fit_ok, (res.message, res.fit.verdict)
    ng = robot.n_params
    names = res.parameter_names[ng + 7: ng + 11]
    assert names == [f"joint{j}.compliance" for j in range(1, 5)]
    err = np.asarray(res.x[ng + 7: ng + 11]) - truth[ng + 7: ng + 11]
    sd = np.asarray(res.std)[ng + 7: ng + 11]
    assert np.all(np.isfinite(sd)) and np.all(np.abs(err) < 4 * sd), (err, sd)
    assert np.all(sd[2:] < 0.1 * (truth[ng + 9: ng + 11] + robot.effects[-1].values()[2:]))


def test_iwr_calibrate_on_a_tracker_robot_with_the_carriage(tmp_path, measured_with_effects):
    """`iwr calibrate` (the efficient estimator with a noise model) on reflector points of a
    tracker robot whose file switches on the carriage's compliance: exit 0, the fit passes, the
    carriage's compliances in the summary and in calibrated.toml (read back by iwr), and the
    report says what the tracker objective models."""
    import json
    import os
    import subprocess
    import sys

    from iwr.tracker.files import write_tracker_wide

    robot = carriage_robot(measured_with_effects("points"), joints=(3, 4))
    robot.to_toml(tmp_path / "robot.toml")
    assert "[effects.carriage_compliance]" in (tmp_path / "robot.toml").read_text()

    def run(*args):
        env = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
        return subprocess.run([sys.executable, "-m", "iwr", *args], capture_output=True,
                              text=True, cwd=tmp_path, env=env, timeout=900, check=False)

    # A true machine with the file's (realistic) effects: a value drawn near its plausible bound
    # may be identified just beyond it, and the robot file refuses such a value when read back
    # (effects.thermal.alpha_ppm_per_K: 30.28 of 30 on `iwr simulate --seed 3`'s machine).
    _, truth = et.simulate(robot, 1, seed=3)
    ng, ne = robot.n_params, len(iwr.effects.parameter_names(robot.effects))
    truth[ng: ng + ne] = 0.0
    data, _ = et.simulate(robot, 30, seed=3, x=truth, noise=NOISE, payloads=PAYLOADS)
    write_tracker_wide(tmp_path / "data.csv", robot.tracker, data)
    proc = run("calibrate", "robot.toml", "data.csv", "--noise",
               "legs=0.002,joint_lengths=0.005,joint_angles=5e-6", "--out", "out",
               "--no-plots")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "the model fits the data" in proc.stdout and "joint4.compliance" in proc.stdout
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert "joint3.compliance" in json.dumps(summary["parameters"])
    assert "joint4.compliance" in json.dumps(summary["parameters"])
    back = iwr.Robot.from_toml(tmp_path / "out" / "calibrated.toml")
    assert [e.name for e in back.effects] == ["compliance", "thermal", "carriage_compliance"]
    assert not np.array_equal(back.effects[-1].values(), robot.effects[-1].values())
    assert back.tracker is not None
    html = (tmp_path / "out" / "report.html").read_text()
    assert "the carriage&#x27;s joints changed first" in html or \
        "the carriage's joints changed first" in html


def test_iwr_calibrate_launcher_with_the_carriage_equals_identify(tmp_path, measured_with_effects,
                                                                 engine_equals_identify):
    """iwr-calibrate ROBOT.toml DATA.csv on point data of a robot with the carriage's compliance:
    the engine's DE run is iwr.identify's, bit for bit (2 threads against 1), and its cost the
    problem's."""
    robot = carriage_robot(measured_with_effects("points"))
    data, _ = et.simulate(robot, 8, seed=8, payloads=PAYLOADS)
    exe, _, _ = engine_equals_identify(robot, data, tmp_path, 16, 8)
    assert exe.parameter_names[65:69] == [f"joint{j}.compliance" for j in range(1, 5)]


def test_the_job_steps_with_the_carriage(measured_with_effects):
    """iwr.calibrate (noise-weighted LM) on reflector points with the carriage's compliance and
    a 1 mm gross error in one reflector: the screen (the misclosures' derivatives in every
    reading through the loop closure with the carriage's change) finds it, the fit passes, the
    uncertainty has the carriage's compliances; iwr.plan_poses chooses poses and payloads with
    it; iwr legs' commands (targets in {T}) are the model's."""
    from iwr.transforms import pose_from_matrix

    robot = carriage_robot(measured_with_effects("points"))
    ng, ne = robot.n_params, 11
    _, truth = et.simulate(robot, 1, seed=3)
    truth[ng: ng + ne] = 0.0  # the file's (realistic) effects: see the test above
    data, _ = et.simulate(robot, 30, seed=1, x=truth, noise=NOISE, payloads=PAYLOADS)
    bad = data.subset(np.arange(len(data)))
    bad.points[7, 1] += [1.0, 0.0, 0.0]
    cal = iwr.calibrate(robot, bad, "lm", noise=NOISE, seed=3)
    assert cal.success and cal.fit_ok, cal.result.message
    found = cal.result.outliers
    assert len(found) == 1 and found[0].instrument.startswith("reflector2"), found
    assert np.all(np.isfinite(np.asarray(cal.uncertainty.std)[ng + 7: ng + 11]))
    plan = iwr.plan_poses(robot, data, 12, payloads=PAYLOADS, seed=0)
    assert len(plan.measurements) == 12 and plan.value > 0
    frames = et.tool_frames(robot, truth, data)
    nominal = np.zeros_like(truth)
    cmd = api.leg_commands(robot, data.q, np.array([pose_from_matrix(f) for f in
                                                    et.tool_frames(robot, nominal, data)]),
                           payload=data.payload, temperatures=data.temperatures, frame="T")
    model = et.leg_commands(robot, nominal, et.tool_frames(robot, nominal, data), data.q, data)
    np.testing.assert_allclose(cmd.legs, model, rtol=0, atol=1e-9)
    # The commands invert the forward kinematics with the carriage's change.
    np.testing.assert_allclose(et.leg_commands(robot, truth, frames, data.q, data), data.legs,
                               rtol=0, atol=1e-9)


def test_realistic_lists_the_joints_the_trackers_gravity_loads(measured_with_effects):
    """api.realistic(carriage=True) chooses the joints that carry a load under gravity as the
    data give it: on tracker data the tracker's through the registration. The tests' levelled
    tracker puts gravity along {0}'s -z, where the first slide carries the whole weight; the
    effect's own gravity in {0} (-x, pose data's) loads joint 4 only."""
    plain = measured_with_effects("points").with_effects()
    g0 = iwr.kinds.for_robot(plain).world_gravity(plain)
    assert g0[2] < -9.7
    assert api.realistic(plain, carriage=True)[-1].joints[0] == 1
    assert api.realistic(iwr.Robot.default(), carriage=True)[-1].joints == (4,)
