"""Issue 23: non-geometric effects (leg compliance under load, leg thermal expansion) as plug-ins of
the robot model (iwr/effects, docs/effects.md): the statics against the virtual work, the
objective's Jacobian against finite differences, recovery and compensation on noise-free data,
identifiability with one payload against two, and the refusals of what does not model them."""

from __future__ import annotations

import numpy as np
import pytest

import iwr
from iwr import effects
from iwr.effects import api, model
from iwr.effects.builtin import LegCompliance, LegThermal
from iwr.effects.problem import EffectProblem
from iwr.measurements import Measurements
from iwr.problem import predict_legs
from iwr.transforms import pose_from_matrix, pose_matrix, rotvec_matrix


@pytest.fixture(scope="module")
def robot():
    return iwr.Robot.default()


@pytest.fixture(scope="module")
def data(with_effects):
    return api.simulate(with_effects, 60, seed=3)


def _central(f, x, i, h):
    xp, xm = x.copy(), x.copy()
    xp[i] += h
    xm[i] -= h
    return (f(xp) - f(xm)) / (2 * h)


def test_leg_geometry_matches_the_core_and_its_derivatives_the_differences(robot):
    m, x = iwr.simulate(robot, 15, seed=1)
    v, dv, _ = model.leg_vectors(robot, x, m.q, m.poses)
    s = np.linalg.norm(v, axis=2) - robot.leg_offsets - x[52:58]
    assert np.abs(s - predict_legs(robot, x, m.q, m.poses)).max() < 1e-10
    for i in range(robot.n_params):
        fd = _central(lambda y: model.leg_vectors(robot, y, m.q, m.poses)[0], x, i, 1e-6)
        assert np.abs(fd - dv[..., i]).max() < 1e-5 * max(1.0, np.abs(dv[..., i]).max()), i


def _bodies(k, payload):
    return ((120.0, np.array([0.0, 0.0, 40.0])), (payload[k, 0], payload[k, 1:]))


def test_leg_forces_do_the_virtual_work_of_gravity(robot, with_effects, data):
    """f . dL = w . dX: the legs' forces times their length changes under a small platform
    motion equal the work of gravity on the platform and payload (their potential energy,
    computed from the bodies' centres, and the leg lengths from the C++ core)."""
    m, x = data
    xg = x[: robot.n_params]
    state = model.leg_state(with_effects, xg, m.q, m.poses, m, {"forces"})
    gravity = with_effects.effects[0].gravity
    t = pose_matrix(m.poses)
    rng = np.random.default_rng(7)
    assert np.abs(state.forces).max() > 100.0  # the payload and platform weigh on the legs
    for k in range(0, 60, 7):
        direction = rng.standard_normal(6) * np.array([1, 1, 1, 1e-3, 1e-3, 1e-3])
        errors = []
        for h in (1e-2, 1e-3, 1e-4):
            dx = h * direction
            t2 = t[k].copy()
            t2[:3, 3] += dx[:3]
            t2[:3, :3] = rotvec_matrix(dx[3:]) @ t[k][:3, :3]
            legs = predict_legs(robot, xg, m.q[[k, k]], np.array([m.poses[k],
                                                                    pose_from_matrix(t2)]))
            work = sum(mass * gravity @ ((t2[:3, :3] - t[k][:3, :3]) @ c + dx[:3])
                       for mass, c in _bodies(k, m.payload))
            virtual = state.forces[k] @ (legs[1] - legs[0])
            errors.append(abs(virtual - work) / abs(work))
        # Exact to first order: what is left is the second-order term, so the relative error
        # falls with h (10 times at h / 10).
        assert errors[2] < 1e-5 and errors[2] < errors[1] / 5 < errors[0] / 25, (k, errors)


def test_force_and_objective_jacobians_match_finite_differences(robot, with_effects, data):
    m, x_true = data
    xg = x_true[: robot.n_params]
    state = model.leg_state(with_effects, xg, m.q, m.poses, m, {"forces"})
    for i in range(0, robot.n_params, 3):
        fd = _central(lambda y: model.leg_state(with_effects, y, m.q, m.poses, m,
                                                {"forces"}).forces, xg, i, 1e-6)
        assert np.abs(fd - state.d_forces[..., i]).max() < 1e-6 * np.abs(state.forces).max(), i
    problem = EffectProblem(with_effects, m)
    x = 0.5 * x_true
    _, jac = problem.residuals_and_jacobian(x)
    assert jac.shape == (6 * len(m), robot.n_params + 7)
    for i in range(problem.n_params):
        fd = _central(problem.residuals, x, i, 1e-6)
        assert np.abs(fd - jac[:, i]).max() < 1e-5 * max(1.0, np.abs(jac[:, i]).max()), \
            problem.parameter_names[i]


def _fresh(truth_robot, n, seed):
    """Fresh poses of the true robot with other payloads and temperatures than the data's."""
    zero = np.zeros(truth_robot.n_params + len(effects.parameter_names(truth_robot.effects)))
    rng = np.random.default_rng(seed)
    payload = np.column_stack([rng.uniform(0, 200, n), rng.uniform(-80, 80, (n, 2)),
                               rng.uniform(50, 300, n)])
    return api.simulate(truth_robot, n, seed=seed, x=zero, payloads=payload,
                        temperatures=rng.uniform(10, 35, n))[0]


@pytest.mark.parametrize("method, options", [
    ("lm", {}),
    # DE on the C++ objective with effects (cpp/src/effects.cpp), polished by LM.
    ("de", {"max_evaluations": 20000, "seed": 1}),
])
def test_noise_free_recovery_of_geometry_and_effects(robot, with_effects, data, method, options,
                                                     fresh_tool_error):
    """Issue 23's check: from noise-free data with compliance and temperature drift, LM (and DE
    polished by LM) recovers the geometric and effect parameters so that tool poses and leg
    commands on 50 fresh poses with other loads and temperatures agree with the truth to 1e-6
    mm."""
    m, x_true = data
    result = iwr.identify(with_effects, m, method, **options)
    assert result.success, result.message
    assert result.parameter_names[-7:] == [f"leg{j}.compliance" for j in range(1, 7)] + [
        "legs.alpha"]
    truth = api.apply(with_effects, x_true)
    calibrated = api.apply(with_effects, result.x)
    assert calibrated.effects[1].alpha[0] == pytest.approx(11.5 + x_true[-1], abs=1e-8)
    fresh = _fresh(truth, 50, seed=11)
    # Tool poses: the calibrated model's forward kinematics of the true readings.
    assert fresh_tool_error(calibrated, fresh) < 1e-6
    # Leg commands: the calibrated robot's at the true poses, under their loads and temperatures.
    cmd = api.leg_commands(calibrated, fresh.q, fresh.poses, payload=fresh.payload,
                           temperatures=fresh.temperatures)
    assert np.abs(cmd.legs - fresh.legs).max() < 1e-6
    # Without the effects the commands miss by the compliance and the growth (tens of um).
    plain = iwr.compensation.leg_commands(calibrated.with_effects(), fresh.q, fresh.poses)
    assert np.abs(plain.legs - fresh.legs).max() > 5e-3


def test_compensated_commands_reach_the_target_on_the_true_robot(robot, with_effects, data):
    """The commands with the compensation, run on the simulated true robot (its forward
    kinematics under the move's load and temperature), put the platform at the target."""
    m, x_true = data
    calibrated = api.apply(with_effects, iwr.identify(with_effects, m, "lm").x)
    truth = api.apply(with_effects, x_true)
    targets = _fresh(truth, 20, seed=5)
    cmd = api.leg_commands(calibrated, targets.q, targets.poses, payload=targets.payload,
                           temperatures=targets.temperatures)
    zero = np.zeros(len(x_true))
    reached = api.forward_kinematics(truth, zero, targets.q, cmd.legs, targets,
                                     targets.poses + 1e-3)
    assert np.abs(reached[:, :3] - targets.poses[:, :3]).max() < 1e-6
    assert np.abs(reached[:, 3:] - targets.poses[:, 3:]).max() < 1e-9


@pytest.mark.parametrize("payloads,separable", [
    ([[80.0, 50.0, 0.0, 150.0]], False),
    ([[0.0, 0.0, 0.0, 0.0], [80.0, 50.0, 0.0, 150.0]], True),
])
def test_one_payload_leaves_the_compliances_in_the_geometry(robot, payloads, separable,
                                                            carriage_only_poses):
    """With one payload and a constant leg-force pattern the compliances go into the leg
    offsets; a second payload at the same poses separates them. The rank of the analytic
    Jacobian is checked against that of a finite-difference one."""
    comp, thermal = api.realistic(robot, identify_alpha=False)
    rigid = robot.with_effects(comp.with_values(np.zeros(6)), thermal)
    n = 40
    q, poses = carriage_only_poses(robot, n, 2)
    payload = np.asarray(payloads)[np.arange(n) % len(payloads)]
    m = Measurements(q, poses, np.zeros((n, 6)), joint_types=robot.joint_types, payload=payload,
                     temperatures=np.full(n, 20.0))
    report = iwr.identifiability(rigid, m)
    problem = EffectProblem(rigid, m)
    x = np.zeros(problem.n_params)
    fd = np.column_stack([_central(problem.residuals, x, i, 1e-5)
                          for i in range(problem.n_params)])
    scaled = fd / np.where(np.linalg.norm(fd, axis=0) > 0, np.linalg.norm(fd, axis=0), 1)
    s = np.linalg.svd(scaled, compute_uv=False)
    fd_rank = int(np.sum(s > 1e-7 * s[0]))
    assert fd_rank == report.rank
    assert report.rank == report.geometric_rank + (6 if separable else 0)
    names = [name for name, _ in report.inseparable]
    assert names == ([] if separable else [f"leg{j}.compliance" for j in range(1, 7)])
    assert ("NOT separable" in str(report)) != separable
    assert report.active[-6:].all() == separable


def test_realistic_poses_separate_compliances_with_one_payload(robot, with_effects):
    """On the IWR's varied poses (the carriage turns the hexapod in gravity) the leg-force
    pattern varies enough: every effect parameter is identifiable with one payload."""
    m, _ = api.simulate(with_effects, 60, seed=4, payloads=[[0.0, 0.0, 0.0, 0.0]])
    report = iwr.identifiability(with_effects, m)
    assert report.effects_identifiable and report.rank == report.geometric_rank + 7


def test_the_report_with_effects_lists_the_unidentifiable_directions(with_effects, data):
    """``iwr analyze`` of pose data with effects printed the rank and the left-out parameters but
    not the directions (pose data without effects, tracker and ballbar data print them): one
    per left-out parameter, which moves it by 1, the other left-out ones by 0, and the predicted
    readings not at all (the Jacobian times it, against the readings' scale)."""
    m, _ = data
    report = iwr.identifiability(with_effects, m)
    directions = report.null_directions
    assert [name for name, _ in directions] == report.left_out and directions
    jac = EffectProblem(with_effects, m).jacobian(np.zeros(len(report.parameter_names)))
    left = [report.parameter_names.index(n) for n in report.left_out]
    basis = iwr.base_parameters.directions_of(report.null_space, np.array(left))
    np.testing.assert_allclose(basis[left], np.eye(len(left)), atol=1e-12)
    assert np.abs(jac @ basis).max() < 1e-9 * np.abs(jac).max()
    text = str(report)
    assert "unidentifiable directions (coefficients in mm and rad):" in text
    for k, (name, words) in enumerate(directions, 1):
        assert f"    {k}. [{name}] {words}" in text and f"+1 {name}" in words


def test_what_does_not_model_the_effects_refuses(with_effects, data):
    m, x = data
    # iwr.Problem(noise=), the global methods with a noise model and predict_legs(data=) model
    # them (tests/test_effects_noise.py); predict_legs needs the loads.
    with pytest.raises(ValueError, match="data: robot 'IWR' has effects on"):
        predict_legs(with_effects, None, m.q, m.poses)
    with pytest.raises(ValueError, match="thermal effect.*T_C"):
        EffectProblem(with_effects, Measurements(m.q, m.poses, m.legs,
                                                 joint_types=m.joint_types, payload=m.payload))
    # iwr.accuracy models them (tests/test_effects_job.py): the effects' parameters are needed.
    with pytest.raises(ValueError, match="x: shape.*effect parameters"):
        iwr.accuracy(with_effects, m, x[:with_effects.n_params])
    # Tracker data model them (tests/test_effects_tracker.py): data without the temperatures
    # are refused by the thermal effect; the C++ point objective refuses the effects.
    tracked = with_effects.with_tracker(registration=(2000.0, 0.0, 300.0, 1.5708, 0.0, 0.0),
                                        reflectors=[(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0),
                                                    (-60.0, -104.0, 40.0)])
    tm, _ = iwr.simulate(tracked.with_effects(), 20, seed=1)
    for call in (lambda: iwr.identify(tracked, tm, "lm"),
                 lambda: iwr.identifiability(tracked, tm)):
        with pytest.raises(ValueError, match="thermal effect.*T_C"):
            call()
    with pytest.raises(ValueError, match="effects on.*tracker data"):
        iwr.tracker.TrackerProblem(tracked, tracked.tracker, tm)


def test_robot_file_round_trip_and_checks(tmp_path, robot, with_effects):
    path = tmp_path / "robot.toml"
    with_effects.to_toml(path)
    text = path.read_text()
    assert "[effects.compliance]" in text and "[effects.thermal]" in text
    back = iwr.Robot.from_toml(path)
    assert back == with_effects and back.effects == with_effects.effects
    # With none on, nothing of it is written.
    robot.to_toml(tmp_path / "plain.toml")
    assert "effects" not in (tmp_path / "plain.toml").read_text()
    assert robot.effects == () and "effects" not in robot.to_dict()
    bad = text.replace("platform_mass_kg", "platform_mass")
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(iwr.RobotFileError, match="effects.compliance.platform_mass: unknown"):
        iwr.Robot.from_toml(tmp_path / "bad.toml")
    d = with_effects.to_dict()
    d["effects"]["compliance"]["gravity_m_s2"] = [0.0, 0.0, -9.81e-3]
    with pytest.raises(ValueError, match="gravity_m_s2.*norm"):
        iwr.Robot.from_dict(d)
    d["effects"] = {"backlash": {}}
    with pytest.raises(ValueError, match="effects.backlash: unknown effect"):
        iwr.Robot.from_dict(d)
    # Identified values are kept by a calibrated robot and its geometry by with_errors.
    x = np.zeros(robot.n_params + 7)
    x[-7:] = [0.001] * 6 + [0.5]
    cal = api.apply(with_effects, x)
    assert np.allclose(cal.effects[0].compliance, 0.011) and cal.effects[1].alpha[0] == 12.0
    assert cal.with_errors(np.zeros(robot.n_params)).effects == cal.effects


def test_a_value_identified_beyond_its_plausible_range_reads_back(tmp_path, robot):
    """A calibration can identify an effect a little beyond its plausible range (the fit's range
    test weighs the departure by its standard deviation and passes it): the calibrated robot
    widens that range to hold the value, so that calibrated.toml reads back (it was written
    with the old range, and iwr refused to read it). The other ranges stay as they were."""
    with_all = robot.with_effects(*api.realistic(robot, carriage=True))
    names = effects.parameter_names(with_all.effects)
    x = np.zeros(robot.n_params + len(names))
    # leg 3 at 1.5 times max_um_per_N (0.05), the shared alpha at 40 ppm/K (max 30), joint 4
    # (revolute) at twice its max; the slides stay within theirs
    x[robot.n_params + names.index("leg3.compliance")] = 0.075 - 0.01
    x[robot.n_params + names.index("legs.alpha")] = 40.0 - 11.5
    carriage = with_all.effects[2]
    j4 = names.index("joint4.compliance")
    x[robot.n_params + j4] = 2 * carriage.max_revolute - carriage.values()[-1]
    widened = api.widened_ranges(with_all, x)
    assert widened == [
        "[effects.compliance] max_um_per_N 0.05 -> 0.075",
        "[effects.thermal] max_ppm_per_K 30 -> 40",
        f"[effects.carriage_compliance] max_urad_per_Nm {carriage.max_revolute:g} -> "
        f"{2 * carriage.max_revolute:.4g}"], widened
    cal = api.apply(with_all, x)
    cal.to_toml(tmp_path / "calibrated.toml")
    back = iwr.Robot.from_toml(tmp_path / "calibrated.toml")
    assert back.effects == cal.effects
    assert back.effects[0].compliance[2] == pytest.approx(0.075)
    assert back.effects[2].max_prismatic == carriage.max_prismatic
    # Within the ranges nothing is widened.
    assert api.widened_ranges(with_all, np.zeros_like(x)) == []
    # A negative value (within its standard deviation of 0) moves the range's lower end, not
    # max_um_per_N, and the note says so.
    below = np.zeros_like(x)
    below[robot.n_params + names.index("leg1.compliance")] = -0.03 - 0.01
    assert api.widened_ranges(with_all, below) == [
        "[effects.compliance] leg1.compliance -0.03 um/N, below the plausible range's lower "
        "end 0: the range starts at it"]
    low = api.apply(with_all, below).effects[0]
    assert low.max_compliance == with_all.effects[0].max_compliance
    assert (low.values() + low.bounds()[0])[0] == pytest.approx(-0.03)
    # A negative value beyond -max_* (the robot file holds values within +-max_*): the range
    # widens to hold it, both notes, and the calibrated robot file reads back with the values
    # (it was written with -0.07 under max_um_per_N 0.05 and refused by the reader).
    deep = np.zeros_like(x)
    deep[robot.n_params + names.index("leg1.compliance")] = -0.07 - 0.01
    deep[robot.n_params + names.index("legs.alpha")] = -35.0 - 11.5
    deep[robot.n_params + j4] = -2 * carriage.max_revolute - carriage.values()[-1]
    notes = api.widened_ranges(with_all, deep)
    assert "[effects.compliance] max_um_per_N 0.05 -> 0.07" in notes, notes
    assert "[effects.thermal] max_ppm_per_K 30 -> 35" in notes, notes
    assert any(n.startswith("[effects.compliance] leg1.compliance -0.07 um/N, below")
               for n in notes)
    cal = api.apply(with_all, deep)
    cal.to_toml(tmp_path / "negative.toml")
    back = iwr.Robot.from_toml(tmp_path / "negative.toml")
    assert back.effects == cal.effects
    assert back.effects[0].compliance[0] == pytest.approx(-0.07)
    assert back.effects[1].alpha[0] == pytest.approx(-35.0)
    assert back.effects[2].values()[-1] == pytest.approx(-2 * carriage.max_revolute)
    # A slide's compliance: widened up to the robot file's cap (10 um/N), refused beyond it by
    # name (the file could not hold it).
    from iwr.effects.carriage import CarriageCompliance

    leg, thermal = with_all.effects[:2]
    slides = with_all.with_effects(leg, thermal, CarriageCompliance(
        400.0, (0.0, 0.0, 150.0), leg.platform_mass, leg.platform_centre, leg.gravity,
        joints=[2], compliance=0.005))
    x = np.zeros(robot.n_params + 8)
    x[-1] = 5.0
    assert api.widened_ranges(slides, x) == [
        "[effects.carriage_compliance] max_um_per_N 0.05 -> 5.005"]
    api.apply(slides, x).to_toml(tmp_path / "slides.toml")
    assert iwr.Robot.from_toml(tmp_path / "slides.toml").effects[2].max_prismatic == 5.005
    x[-1] = 15.0
    with pytest.raises(ValueError, match=r"joint2.compliance 15.005 um/N; expected -10 <= value "
                                         r"<= 10"):
        api.apply(slides, x)


def test_measurement_columns_round_trip_and_checks(tmp_path, data):
    m, _ = data
    path = tmp_path / "m.csv"
    m.to_csv(path)
    header = [line for line in path.read_text().splitlines() if not line.startswith("#")][0]
    assert header.endswith("s6_mm,payload_kg,payload_x_mm,payload_y_mm,payload_z_mm,T_C")
    back = Measurements.from_csv(path)
    assert np.array_equal(back.payload, m.payload)
    assert np.array_equal(back.temperatures, m.temperatures)
    per_leg = Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types,
                           weights=np.ones((len(m), 6)), temperatures=np.full((len(m), 6), 21.0))
    per_leg.to_csv(path)
    back = Measurements.from_csv(path)
    assert back.temperatures.shape == (len(m), 6) and back.payload is None
    assert back.weights is not None
    assert back.subset([0, 2]).temperatures.shape == (2, 6)
    with pytest.raises(ValueError, match="temperatures: row 0, column 0 is 293.15"):
        Measurements(m.q, m.poses, m.legs, temperatures=np.full(len(m), 293.15))
    with pytest.raises(ValueError, match="payload: row 0, mass -1.0 kg"):
        Measurements(m.q, m.poses, m.legs, payload=np.tile([-1.0, 0, 0, 0], (len(m), 1)))


def test_effect_registry():
    assert effects.available()[:2] == ["compliance", "thermal"]
    assert effects.named("compliance") is LegCompliance
    assert effects.named("thermal") is LegThermal
    with pytest.raises(ValueError, match="already registered"):
        effects.register("thermal", LegThermal)
    with pytest.raises(ValueError, match="not registered"):
        effects.named("backlash")
    given = LegThermal(11.5, 20.0)
    assert given.parameter_names() == [] and LegThermal(identify=True, per_leg=True
                                                        ).parameter_names()[5] == "leg6.alpha"


def test_iwr_legs_compensates_with_the_targets_load_and_temperature(tmp_path, with_effects, data):
    """``iwr legs`` on a robot with effects reads each target's payload and temperature from
    its columns and writes the compensated commands (the true robot's readings there)."""
    import csv
    import subprocess
    import sys

    _, x_true = data
    truth = api.apply(with_effects, x_true)
    truth.to_toml(tmp_path / "robot.toml")
    targets = _fresh(truth, 5, seed=8)
    targets.to_csv(tmp_path / "targets.csv")
    run = [sys.executable, "-m", "iwr", "legs", str(tmp_path / "robot.toml"),
           str(tmp_path / "targets.csv"), "-o", str(tmp_path / "legs.csv"), "--allow-unverified"]
    done = subprocess.run(run, capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode in (0, 6), done.stderr
    rows = list(csv.DictReader(line for line in (tmp_path / "legs.csv").read_text().splitlines()
                               if not line.startswith("#")))
    legs = np.array([[float(r[f"s{j}_mm"]) for j in range(1, 7)] for r in rows])
    assert np.abs(legs - targets.legs).max() < 1e-9
    # Without the temperature column the thermal effect has nothing to work with: refused.
    text = (tmp_path / "targets.csv").read_text().replace(",T_C\n", "\n")
    lines = [line.rsplit(",", 1)[0] if line[:1].isdigit() else line
             for line in text.splitlines()]
    (tmp_path / "targets.csv").write_text("\n".join(lines) + "\n")
    done = subprocess.run(run, capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode != 0 and "T_C" in done.stderr and "Traceback" not in done.stderr
    assert f"{tmp_path / 'targets.csv'}: the thermal effect" in done.stderr, done.stderr


@pytest.mark.parametrize("variant", ["thermal given", "shared compliance"])
def test_one_effect_alone(robot, variant):
    """Each effect on its own: a given coefficient (no parameter) and one shared compliance;
    the data carry only the columns the effect needs, and LM fits them exactly."""
    comp, _ = api.realistic(robot)
    if variant == "thermal given":
        effect = LegThermal(11.5, 20.0)
    else:
        effect = LegCompliance(comp.platform_mass, comp.platform_centre, comp.gravity, 0.01,
                               per_leg=False)
    rob = robot.with_effects(effect)
    m, x_true = api.simulate(rob, 50, seed=9)
    assert (m.payload is None) == (variant == "thermal given")
    assert (m.temperatures is None) == (variant != "thermal given")
    assert len(x_true) == robot.n_params + (0 if variant == "thermal given" else 1)
    result = iwr.identify(rob, m, "lm")
    assert result.success and result.fun < 1e-16
    truth, calibrated = api.apply(rob, x_true), api.apply(rob, result.x)
    fresh = _fresh(truth, 10, seed=4)
    options = {"payload": fresh.payload, "temperatures": fresh.temperatures}
    assert np.abs(api.leg_commands(calibrated, fresh.q, fresh.poses, **options).legs
                  - api.leg_commands(truth, fresh.q, fresh.poses, **options).legs).max() < 1e-6
