"""Issue 23: the thermal expansion of the carriage's prismatic axes with the machine's temperature
(iwr/effects/carriage_thermal.py, docs/effects.md "The carriage's slides"): the table and its
checks, the objective's and the implicit loop's Jacobians against central differences, the C++
objectives (pose, tracker, ballbar) against the numpy model, the problem file and the engine,
noise-free recovery and compensation on fresh poses at other temperatures (pose and tracker
data), what the data separate, and the refusal of data with the legs' temperatures only."""

from __future__ import annotations

import numpy as np
import pytest
from _ballbar import ballbar_robot, with_offset

import iwr
from iwr import effects
from iwr.effects import api, model
from iwr.effects import tracker as et
from iwr.effects.builtin import LegCompliance, LegThermal
from iwr.effects.carriage import CarriageCompliance
from iwr.effects.carriage_thermal import CarriageThermal
from iwr.effects.problem import EffectProblem
from iwr.measurements import Measurements
from iwr.transforms import pose_matrix

TILTED = 9.80665 * np.array([-0.9, 0.3, 0.3]) / np.linalg.norm([-0.9, 0.3, 0.3])


def _robot(*, per_joint=True, identify=True, others=False, alpha=(11.5, 12.0)):
    robot = iwr.Robot.default()
    ct = CarriageThermal(list(alpha) if per_joint else alpha[0], 20.0, identify=identify,
                         per_joint=per_joint)
    if not others:
        return robot.with_effects(ct)
    return robot.with_effects(LegCompliance(120.0, [0.0, 0.0, 40.0], TILTED, 0.01),
                              LegThermal(11.5, 20.0, identify=True),
                              CarriageCompliance(400.0, [20.0, -10.0, 150.0], 120.0,
                                                 [0.0, 0.0, 40.0], TILTED, None,
                                                 [0.005, 0.005, 0.05, 0.05]), ct)


@pytest.fixture(scope="module")
def robot():
    return _robot(others=True)


@pytest.fixture(scope="module")
def data(robot):
    return api.simulate(robot, 40, seed=3)


def _central(f, x, i, h):
    xp, xm = x.copy(), x.copy()
    xp[i] += h
    xm[i] -= h
    return (f(xp) - f(xm)) / (2 * h)


def test_the_change_is_the_scale_growth():
    """A slide at reading q, at T - T_ref = dT: its true value is q (1 + 1e-6 alpha dT); the
    revolute joints are untouched; simulate draws the machine's temperature (T_C)."""
    robot = _robot(identify=False)
    m, x = api.simulate(robot, 5, seed=1)
    assert m.temperatures.shape == (5, 1)
    dq, _, _ = model.joint_changes(robot, x, np.zeros(0), m.q, pose_matrix(m.poses), m)
    dt = m.temperatures[:, 0] - 20.0
    np.testing.assert_allclose(dq[:, 0], 11.5e-6 * dt * m.q[:, 0], rtol=1e-14, atol=0)
    np.testing.assert_allclose(dq[:, 1], 12.0e-6 * dt * m.q[:, 1], rtol=1e-14, atol=0)
    assert not dq[:, 2:].any()


def test_table_round_trip_and_checks(tmp_path):
    robot = _robot(per_joint=False)
    ct = robot.effects[0]
    assert ct.joints == (1, 2) and ct.parameter_names() == ["carriage.alpha"]
    assert ct.units() == ["ppm/K"] and ct.values() == pytest.approx([11.5])
    path = tmp_path / "robot.toml"
    robot.to_toml(path)
    assert "[effects.carriage_thermal]" in path.read_text()
    assert iwr.Robot.from_toml(path).effects == robot.effects
    d = robot.to_dict()
    table = d["effects"]["carriage_thermal"]
    for key, value, message in [
            ("joints", [1, 3], r"carriage_thermal.joints\[1\]: joint 3 of robot 'IWR' is "
                               "revolute"),
            ("joints", [1, 5], r"carriage_thermal.joints\[1\]: joint 5; robot 'IWR' has 4"),
            ("alpha_ppm_per_K", 40.0, r"alpha_ppm_per_K: 40.0 ppm/K; expected -30 <= value"),
            ("alpha_ppm_per_K", [11.5, 11.5], "2 values; expected one"),
            ("reference_C", "20", "reference_C: expected a number"),
            ("zero_mm", 0.0, "zero_mm: unknown key")]:
        bad = {**d, "effects": {"carriage_thermal": {**table, key: value}}}
        with pytest.raises(ValueError, match=message):
            iwr.Robot.from_dict(bad)
    per = {**table, "per_joint": True, "alpha_ppm_per_K": [11.5, 11.5, 11.5]}
    with pytest.raises(ValueError, match="3 values; expected 2, one per joint"):
        iwr.Robot.from_dict({**d, "effects": {"carriage_thermal": per}})
    with pytest.raises(ValueError, match="not switched on for a robot"):
        CarriageThermal(per_joint=True, identify=True).parameter_names()
    # A robot without slides.
    scara = iwr.Robot.default()
    with pytest.raises(ValueError, match=r"carriage_thermal.joints\[0\]: joint 3 .* revolute"):
        scara.with_effects(CarriageThermal(joints=[3]))
    # Identified values (one beyond the plausible range widens it) are written and read back.
    cal = api.apply(robot, np.r_[np.zeros(robot.n_params), 25.0])
    assert cal.effects[0].values() == pytest.approx([36.5])
    assert api.widened_ranges(robot, np.r_[np.zeros(robot.n_params), 25.0]) == [
        "[effects.carriage_thermal] max_ppm_per_K 30 -> 36.5"]
    cal.to_toml(tmp_path / "cal.toml")
    assert iwr.Robot.from_toml(tmp_path / "cal.toml").effects == cal.effects


def test_per_leg_temperatures_are_refused(tmp_path):
    """The slides read the machine's temperature (T_C); data with the legs' only (T1_C .. T6_C)
    are refused naming the effect and the column, in numpy and in the C++ core."""
    robot = _robot(per_joint=False)
    m, _ = api.simulate(robot, 6, seed=2)
    legs_only = Measurements(m.q, m.poses, m.legs, joint_types=robot.joint_types,
                             temperatures=np.repeat(m.temperatures, 6, axis=1))
    message = "carriage_thermal effect .* needs the machine's temperature .* column T_C"
    for call in (lambda: EffectProblem(robot, legs_only),
                 lambda: iwr.identify(robot, legs_only, "lm"),
                 lambda: api.leg_commands(robot, m.q, m.poses, temperatures=legs_only.temperatures),
                 lambda: iwr.identify(robot, Measurements(m.q, m.poses, m.legs,
                                                          joint_types=robot.joint_types), "lm")):
        with pytest.raises(ValueError, match=message):
            call()
    from iwr import _core
    tables = [(e.name, e.to_dict()) for e in robot.effects]
    with pytest.raises(ValueError, match="carriage_thermal effect .* machine's temperature"):
        _core.EffectObjective(robot._geometry, tables, m.q, m.poses, m.legs, np.zeros((0, 0)),
                              legs_only.temperatures)


def test_objective_and_loop_jacobians_match_central_differences(robot, data,
                                                                check_effect_jacobians):
    """With every effect on (the carriage's compliance too: both change the joints), the exact
    Jacobians against central differences, in every parameter and the loop's corrections."""
    m, x_true = data
    assert EffectProblem(robot, m).parameter_names[-2:] == ["joint1.alpha", "joint2.alpha"]
    check_effect_jacobians(robot, m, 0.5 * x_true, list(range(0, robot.n_params, 3))
                           + list(range(robot.n_params, len(x_true))))


def test_cpp_objective_agrees_with_the_numpy_model(robot, data, tmp_path):
    """The C++ leg objective (DE, CRS2, BOBYQA), its problem file and iwr-engine's objective
    against the numpy model; the effect alone (given, not identified) too."""
    from iwr import _core

    m, x_true = data
    numpy_problem, cpp_problem = EffectProblem(robot, m), iwr.Problem(robot, m)
    for x in (np.zeros(numpy_problem.n_params), x_true, 0.3 * x_true):
        r_np, r_cpp = numpy_problem.residuals(x), cpp_problem.residuals(x)
        assert np.abs(r_np - r_cpp).max() < 1e-10 * max(1.0, np.abs(r_np).max())
        c_np = float(r_np @ r_np)
        assert abs(cpp_problem.cost(x) - c_np) <= 1e-10 * c_np + 1e-18
    alone = _robot(identify=False)
    m2, x2 = api.simulate(alone, 15, seed=8)
    assert np.abs(EffectProblem(alone, m2).residuals(0.7 * x2)
                  - iwr.Problem(alone, m2).residuals(0.7 * x2)).max() < 1e-10
    cpp_problem.save(tmp_path / "p.iwrp")
    back = iwr.Problem.load(tmp_path / "p.iwrp")
    assert back.robot.effects == robot.effects
    X = np.vstack([x_true, 0.3 * x_true])
    np.testing.assert_array_equal(_core._engine_costs(str(tmp_path / "p.iwrp"), X),
                                  cpp_problem.cost_batch(X))


def _fresh(truth, n, seed):
    zero = np.zeros(truth.n_params + len(effects.parameter_names(truth.effects)))
    rng = np.random.default_rng(seed)
    return api.simulate(truth, n, seed=seed, x=zero,
                        temperatures=rng.uniform(5, 40, n))[0]


@pytest.mark.parametrize("method, options", [
    ("lm", {}),
    # DE on the C++ objective with the slides' growth (cpp/src/effects.cpp), polished by LM.
    ("de", {"max_evaluations": 20000, "seed": 1}),
])
def test_noise_free_recovery_and_compensation(method, options, fresh_tool_error):
    """Issue 23's check: from noise-free pose data at a day's temperatures LM (and DE) recovers
    the geometry and both slides' coefficients so that tool poses and leg commands on 50 fresh
    poses at other temperatures agree with the truth to 1e-6 mm; commands that leave the
    slides' expansion out miss by micrometres."""
    robot = _robot()
    m, x_true = api.simulate(robot, 40, seed=4)
    result = iwr.identify(robot, m, method, **options)
    assert result.success, result.message
    assert np.abs(result.x[-2:] - x_true[-2:]).max() < 1e-6
    truth, calibrated = api.apply(robot, x_true), api.apply(robot, result.x)
    fresh = _fresh(truth, 50, seed=11)
    assert fresh_tool_error(calibrated, fresh) < 1e-6
    cmd = api.leg_commands(calibrated, fresh.q, fresh.poses, temperatures=fresh.temperatures)
    assert np.abs(cmd.legs - fresh.legs).max() < 1e-6
    plain = api.leg_commands(calibrated.with_effects(), fresh.q, fresh.poses)
    assert np.abs(plain.legs - fresh.legs).max() > 1e-3


@pytest.mark.parametrize("kind", ["points", "probe"])
def test_tracker_cpp_and_recovery(kind, measured_with_effects, monkeypatch):
    """On tracker data with the legs' effects on: the C++ objective (its forward kinematics with
    the slides' growth) agrees with the numpy model; noise-free LM recovers the slides'
    coefficient so that tool frames and leg commands on 50 fresh poses at other temperatures
    agree with the truth to 1e-6 mm, and commands without the slides' growth miss."""
    base = measured_with_effects(kind)
    robot = base.with_effects(*base.effects, CarriageThermal(11.5, 20.0, identify=True))
    data, truth = et.simulate(robot, 20, seed=3)
    problem, start = et.effect_tracker_problem(robot, data)
    name = robot.n_params + len(effects.parameter_names(robot.effects)) - 1
    assert problem.parameter_names[name] == "carriage.alpha"
    cpp = problem._objective()
    with monkeypatch.context() as patch:
        patch.setattr(et, "FK_TOLERANCE_MM", 1e-13)
        for x in (truth, start, 0.5 * (start + truth)):
            rn, rc = problem.residuals(x), cpp.residuals(x)
            assert np.abs(rc - rn).max() < 1e-10
            assert problem.cost(x) == pytest.approx(float(rn @ rn), rel=1e-10)
    res = iwr.identify(robot, data, "lm")
    assert res.success, res.message
    assert abs(res.x[name] - truth[name]) < 1e-6
    fresh, _ = et.simulate(robot, 50, seed=99, x=truth, temperatures=np.linspace(5.0, 40.0, 50))
    a = et.tool_frames(robot, res.x, fresh)
    b = et.tool_frames(robot, truth, fresh)
    assert np.abs(a[:, :3, 3] - b[:, :3, 3]).max() < 1e-6
    legs = et.leg_commands(robot, res.x, b, fresh.q, fresh)
    assert np.abs(legs - fresh.legs).max() < 1e-6
    cold = res.x.copy()
    cold[name] = -robot.effects[-1].values()[0]  # a coefficient of 0: no growth
    assert np.abs(et.leg_commands(robot, cold, b, fresh.q, fresh) - fresh.legs).max() > 1e-3


def test_ballbar_cpp_agrees_with_the_numpy_model():
    """Ballbar data (the legs' effects and the slides' growth): the C++ residuals are the numpy
    ones, and LM on noise-free data recovers the slides' coefficient."""
    from iwr.ballbar import effects as be

    plain = ballbar_robot(with_offset(0.3))
    robot = plain.with_effects(LegThermal(11.5, 20.0),
                               CarriageThermal(11.5, 20.0, identify=True, per_joint=True))
    data, truth = be.simulate(robot, 14, seed=3)
    problem, start = be.effect_problem(robot, data)
    for x in (truth, start, 0.5 * (start + truth), problem.lower):
        py = problem.residuals(x)
        np.testing.assert_allclose(problem.objective.residuals(x), py, rtol=0, atol=1e-9)
    assert problem.parameter_names[robot.n_params: robot.n_params + 2] == [
        "joint1.alpha", "joint2.alpha"]


def test_a_coefficient_of_zero_changes_no_bit(measured_with_effects):
    """The slides' expansion at a coefficient of 0 beside the other effects: the readings, their
    Jacobian (numpy) and the C++ costs (pose and tracker data) are those without it, bit for
    bit (the effects' sum adds zeros)."""
    robot = _robot(others=True, identify=False, alpha=(0.0, 0.0))
    without = robot.with_effects(*robot.effects[:-1])
    m, x = api.simulate(without, 12, seed=5)
    a = model.predicted_readings(robot, 0.5 * x, m.q, m.poses, m, derivatives=True)
    b = model.predicted_readings(without, 0.5 * x, m.q, m.poses, m, derivatives=True)
    for u, v in zip(a, b, strict=True):
        np.testing.assert_array_equal(u, v)
    X = np.vstack([x, 0.5 * x])
    np.testing.assert_array_equal(iwr.Problem(robot, m).cost_batch(X),
                                  iwr.Problem(without, m).cost_batch(X))
    base = measured_with_effects("points")
    with_ct = base.with_effects(*base.effects, CarriageThermal(0.0, 20.0))
    data, truth = et.simulate(base, 6, seed=2)
    p1, _ = et.effect_tracker_problem(with_ct, data)
    p0, _ = et.effect_tracker_problem(base, data)
    np.testing.assert_array_equal(p1._objective().residuals(truth),
                                  p0._objective().residuals(truth))


@pytest.mark.parametrize("temperatures, inseparable", [
    ("drawn", []),                                    # a day's drift: identified
    (25.0, []),                                       # one temperature, not the reference
    (20.0, ["joint1.alpha", "joint2.alpha"]),         # every pose at the reference: no growth
])
def test_what_the_temperatures_identify(temperatures, inseparable):
    """The geometry has no scale error of a slide, so the growth alpha dT q is separable from it
    whenever some pose is away from the reference temperature, one temperature throughout
    included (it is then a scale error of the slide at that temperature); at the reference
    there is nothing to see. The rank against a central-difference Jacobian's."""
    robot = _robot()
    m0, _ = api.simulate(robot, 25, seed=6, x=np.zeros(robot.n_params + 2))
    t = m0.temperatures if temperatures == "drawn" else np.full(25, temperatures)
    m = Measurements(m0.q, m0.poses, m0.legs, joint_types=robot.joint_types, temperatures=t)
    with np.errstate(all="raise"):  # a zero column at the reference: no 0/0 on the way
        report = iwr.identifiability(robot, m)
    assert report.rank == report.geometric_rank + 2 - len(inseparable)
    assert [name for name, _ in report.inseparable] == inseparable
    problem = EffectProblem(robot, m)
    x = np.zeros(problem.n_params)
    steps = np.where(np.arange(len(x)) < robot.n_params, 1e-5, 1e-2)
    fd = np.column_stack([_central(problem.residuals, x, i, steps[i])
                          for i in range(problem.n_params)])
    norms = np.linalg.norm(fd, axis=0)
    s = np.linalg.svd(fd / np.where(norms > 0, norms, 1), compute_uv=False)
    assert int(np.sum(s > 1e-7 * s[0])) == report.rank


def test_efficient_estimator_uncertainty_and_plan():
    """With realistic instrument noise the efficient estimator converges, passes its fit test
    and finds the slides' coefficient within 4 of its standard deviations (which
    iwr.uncertainty states alike); iwr.plan_poses plans with the machine's temperatures."""
    robot = _robot(per_joint=False)
    noise = iwr.Noise.realistic()
    noisy, x_true = api.simulate(robot, 40, seed=5, noise=noise)
    result = iwr.identify(robot, noisy, "efficient", noise=noise)
    assert result.success, result.message
    assert result.parameter_names[-1] == "carriage.alpha"
    assert abs(result.x[-1] - x_true[-1]) < 4 * result.std[-1]
    assert result.std[-1] < 10.0  # ppm/K over a day's 8 K at 40 poses
    weighted = iwr.uncertainty(robot, noisy, result.x, noise, weighted=True)
    assert weighted.parameter_names[-1] == "carriage.alpha"
    assert weighted.std[-1] == pytest.approx(result.std[-1], rel=0.3)
    cand, _ = api.simulate(robot, 40, seed=9)
    plan = iwr.plan_poses(robot, cand, 20, seed=1)
    assert len(plan.indices) == 20
    with pytest.raises(ValueError, match="carriage_thermal effect .* column T_C"):
        iwr.plan_poses(robot, Measurements(cand.q, cand.poses, cand.legs,
                                           joint_types=robot.joint_types), 20, seed=1)


def test_tracker_jacobian_with_the_carriage_compliance(measured_with_effects):
    """Tracker points with the legs' effects, the carriage's compliance (gravity through the
    registration: its joint change is linear in gravity, the slides' growth is not) and the
    slides' growth per joint: the Jacobian in every parameter against central differences."""
    plain = measured_with_effects("points").with_effects()
    robot = plain.with_effects(*api.realistic(plain, carriage=True),
                               CarriageThermal([11.5, 12.5], 20.0, identify=True,
                                               per_joint=True))
    data, truth = et.simulate(robot, 5, seed=11)
    problem, start = et.effect_tracker_problem(robot, data)
    x = 0.5 * (start + truth)
    _, jac = problem.residuals_and_jacobian(x)
    names = problem.parameter_names
    ng = robot.n_params + len(effects.parameter_names(robot.effects))
    assert names[ng - 2: ng] == ["joint1.alpha", "joint2.alpha"]
    for i, name in enumerate(names):
        h = (1e-2 if name.endswith(".alpha") else 1e-4 if name.endswith("compliance")
             else 1e-7 if name.split(".")[-1] in ("dalpha", "dtheta", "rx", "ry", "rz")
             else 1e-5)
        e = np.zeros(problem.n_params)
        e[i] = h
        fd = (problem.residuals(x + e) - problem.residuals(x - e)) / (2 * h)
        scale = max(np.abs(jac[:, i]).max(), 1e-12)
        assert np.abs(fd - jac[:, i]).max() <= 1e-5 * scale + 1e-9, name
    assert np.abs(jac[:, ng - 2: ng]).max(axis=0).min() > 1e-3  # mm per ppm/K


def test_cli_legs_and_plan(tmp_path):
    """`iwr legs` compensates the slides' growth at each target's T_C (the library's commands)
    and refuses targets with the legs' temperatures only, naming the file and the column;
    `iwr plan` draws the machine's temperatures for it. Subprocesses: the command line end to
    end (about 1 s each)."""
    import os
    import subprocess
    import sys

    robot = _robot(per_joint=False, identify=False)
    robot.to_toml(tmp_path / "robot.toml")
    m, _ = api.simulate(robot, 4, seed=7, x=np.zeros(robot.n_params))  # the file's robot
    cols = [f"q{i + 1}_{'mm' if t == 'P' else 'rad'}" for i, t in enumerate(robot.joint_types)]
    head = cols + ["x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad", "gamma_rad"]
    rows = np.hstack([m.q, m.poses])
    for name, extra, values in (("targets.csv", ["T_C"], m.temperatures),
                                ("per_leg.csv", [f"T{j}_C" for j in range(1, 7)],
                                 np.repeat(m.temperatures, 6, axis=1))):
        lines = [",".join(head + extra)] + [",".join(repr(float(v)) for v in row)
                                            for row in np.hstack([rows, values])]
        (tmp_path / name).write_text("\n".join(lines) + "\n")

    def run(*args):
        env = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
        return subprocess.run([sys.executable, "-m", "iwr", *args], capture_output=True,
                              text=True, cwd=tmp_path, env=env, timeout=600)

    proc = run("legs", "robot.toml", "targets.csv", "-o", "legs.csv")
    assert proc.returncode == 0, proc.stderr
    text = [line.split(",") for line in (tmp_path / "legs.csv").read_text().splitlines()
            if not line.startswith("#")]
    at = [text[0].index(f"s{j}_mm") for j in range(1, 7)]
    legs = np.array([[float(row[c]) for c in at] for row in text[1:]])
    expected = api.leg_commands(robot, m.q, m.poses, temperatures=m.temperatures).legs
    np.testing.assert_allclose(legs, expected, rtol=0, atol=1e-9)
    assert np.abs(legs - m.legs).max() < 1e-9  # the simulated robot's own readings
    plain = api.leg_commands(robot.with_effects(), m.q, m.poses).legs
    assert np.abs(legs - plain).max() > 1e-3  # the slides' growth is in the commands
    proc = run("legs", "robot.toml", "per_leg.csv", "-o", "bad.csv")
    assert proc.returncode != 0 and "per_leg.csv: the carriage_thermal effect" in proc.stderr
    assert "column T_C" in proc.stderr and "Traceback" not in proc.stderr
    proc = run("plan", "robot.toml", "--n-candidates", "30", "--poses", "15", "--out",
               "plan.csv")
    assert proc.returncode == 0, proc.stderr
    assert "temperatures: the carriage_thermal effect needs them" in proc.stdout


def test_data_without_the_machines_temperature_refused_by_file_before_the_work(tmp_path,
                                                                              capsys):
    """Data (or a validation file, or plan candidates) without the column the slides need were
    refused as "measurements: ..." (no file named) and only once the work had run: a validation
    file's after the whole identification. Now by its file, before any identification."""
    from iwr.cli import main as cli_main

    robot = _robot(per_joint=False)
    robot.to_toml(tmp_path / "robot.toml")
    m, _ = api.simulate(robot, 12, seed=3)
    m.to_csv(tmp_path / "data.csv")
    Measurements(m.q, m.poses, m.legs, joint_types=robot.joint_types).to_csv(
        tmp_path / "none.csv")
    Measurements(m.q, m.poses, m.legs, joint_types=robot.joint_types,
                 temperatures=np.repeat(m.temperatures, 6, axis=1)).to_csv(
        tmp_path / "per_leg.csv")
    robot_file, data = str(tmp_path / "robot.toml"), str(tmp_path / "data.csv")
    none, per_leg = str(tmp_path / "none.csv"), str(tmp_path / "per_leg.csv")
    for argv, bad in (
            (["calibrate", robot_file, none], none),
            (["calibrate", robot_file, data, "--validation", per_leg], per_leg),
            (["analyze", robot_file, per_leg], per_leg),
            (["plan", robot_file, "--candidates", per_leg, "--poses", "5"], per_leg)):
        capsys.readouterr()
        code = cli_main([*argv, "--method", "lm", "-o", str(tmp_path / "out")]
                        if argv[0] == "calibrate" else
                        argv + (["--out", str(tmp_path / "plan.csv")] if argv[0] == "plan"
                                else []))
        out, err = capsys.readouterr()
        assert code == 1, (argv, err)
        assert f"iwr: error: {bad}: the carriage_thermal effect" in err, (argv, err)
        assert "column T_C" in err and "identifying" not in out, (argv, out)
    assert not (tmp_path / "out").exists() and not (tmp_path / "plan.csv").exists()
    # iwr report: a run of the robot without the effect, given the robot with it, is told the
    # robot differs (not that its data lack T_C); given the right robot and data without T_C,
    # the data file is named.
    robot.with_effects().to_toml(tmp_path / "plain.toml")
    cli_main(["calibrate", str(tmp_path / "plain.toml"), none, "--method", "lm", "-o",
              str(tmp_path / "plain"), "--no-plots", "--validation-fraction", "0"])
    capsys.readouterr()
    run = str(tmp_path / "plain" / "result.json")
    assert cli_main(["report", run, robot_file, none, "--out", str(tmp_path / "r")]) == 2
    assert "effects: carriage_thermal is on, the run's robot had it off" in \
        capsys.readouterr().err
    cli_main(["calibrate", robot_file, data, "--method", "lm", "-o", str(tmp_path / "own"),
              "--no-plots", "--validation-fraction", "0"])
    capsys.readouterr()
    assert cli_main(["report", str(tmp_path / "own" / "result.json"), robot_file, data,
                     "--validation", per_leg, "--out", str(tmp_path / "r")]) == 1
    assert f"iwr: error: {per_leg}: the carriage_thermal effect" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
    # The library's job names the data set, before the identification.
    legs_only = Measurements.from_csv(per_leg, robot=robot)

    def never(*args, **kwargs):
        raise AssertionError("identified before the data were checked")

    import iwr.calibration as job

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(job, "identify", never)
        with pytest.raises(ValueError, match="^validation: the carriage_thermal effect"):
            iwr.calibrate(robot, m, validation=legs_only)
