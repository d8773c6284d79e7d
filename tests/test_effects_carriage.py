"""Issue 23: the compliance of the carriage's joints under the gravity load of what they carry
(iwr/effects/carriage.py, docs/effects.md "The carriage's joints"): the loads against the virtual
work of gravity, the objective's and the implicit loop's Jacobians against central differences,
the C++ objective against the numpy model, noise-free recovery and compensation on fresh poses
with other loads, what one payload cannot separate, and the table's checks."""

from __future__ import annotations

import numpy as np
import pytest

import iwr
from iwr import effects
from iwr.effects import api, model
from iwr.effects.builtin import STANDARD_GRAVITY, LegCompliance, LegThermal
from iwr.effects.carriage import CarriageCompliance
from iwr.effects.problem import EffectProblem
from iwr.measurements import Measurements
from iwr.transforms import pose_matrix

#: Gravity tilted against every axis of the IWR's carriage, so that every joint carries a load
#: (the IWR's own, along -x of {0}, loads joint 4 only: test_the_iwr_loads_joint_4_only).
TILTED = STANDARD_GRAVITY * np.array([-0.9, 0.3, 0.3]) / np.linalg.norm([-0.9, 0.3, 0.3])
HEXAPOD = (400.0, [20.0, -10.0, 150.0])
PLATFORM = (120.0, [0.0, 0.0, 40.0])


def _robot(gravity=TILTED, *, joints=None, legs=True, compliance=None):
    robot = iwr.Robot.default()
    c = compliance if compliance is not None else [
        0.005 if t == "P" else 0.05 for t in
        (robot.joint_types if joints is None else [robot.joint_types[j - 1] for j in joints])]
    carriage = CarriageCompliance(*HEXAPOD, *PLATFORM, gravity, joints, c)
    if not legs:
        return robot.with_effects(carriage)
    return robot.with_effects(LegCompliance(*PLATFORM, gravity, 0.01),
                              LegThermal(11.5, 20.0, identify=True), carriage)


@pytest.fixture(scope="module")
def robot():
    return _robot()


@pytest.fixture(scope="module")
def data(robot):
    return api.simulate(robot, 60, seed=3)


def _central(f, x, i, h):
    xp, xm = x.copy(), x.copy()
    xp[i] += h
    xm[i] -= h
    return (f(xp) - f(xm)) / (2 * h)


def _loads(robot, xg, q, poses, m):
    carriage = robot.effects[-1]
    moment, mass, _ = model.platform_moment(carriage, m, pose_matrix(poses))
    return model.joint_loads(robot, xg, q, moment, mass, carriage)


def test_joint_loads_do_the_virtual_work_of_gravity(robot, data):
    """L_i = d W / d q_i: each joint's load is the work of gravity on the bodies it carries (the
    hexapod, the platform, the payload, moved rigidly with the carriage's end: the C++ core's
    carriage transform) per unit of its motion, by central differences of their potential
    energy; the error falls with the step squared."""
    m, x = data
    xg = x[: robot.n_params]
    geometric = robot.with_effects().with_errors(xg)
    loads, _, _ = _loads(robot, xg, m.q, m.poses, m)
    assert np.abs(loads[:, :2]).min() > 1000.0  # N along both slides
    assert np.abs(loads[:, 2:]).max() > 1e5  # N mm about the revolute axes
    mh, ch = HEXAPOD
    mp, cp = PLATFORM
    t5 = pose_matrix(m.poses)
    for k in range(0, 60, 9):
        t4 = geometric.carriage_transform(m.q[k])
        # The hexapod's centre is given in the frame of its base joints (docs/effects.md: their
        # centre, the normal of their polygon, x towards joints 1 and 2).
        a = geometric.base_joints
        o = a.mean(axis=0)
        normal = sum(np.cross(a[j], a[(j + 1) % 6]) for j in range(6))
        normal /= np.linalg.norm(normal)
        x_axis = (a[0] + a[1]) / 2 - o
        x_axis -= (x_axis @ normal) * normal
        x_axis /= np.linalg.norm(x_axis)
        centre = o + np.column_stack([x_axis, np.cross(normal, x_axis), normal]) @ ch
        bodies = [(mh, t4[:3, :3] @ centre + t4[:3, 3]), (mp, t5[k, :3, :3] @ cp + t5[k, :3, 3]),
                  (m.payload[k, 0], t5[k, :3, :3] @ m.payload[k, 1:] + t5[k, :3, 3])]

        def work(qk, t4=t4, bodies=bodies):
            moved = geometric.carriage_transform(qk) @ np.linalg.inv(t4)
            return sum(mass * TILTED @ (moved[:3, :3] @ p + moved[:3, 3]) for mass, p in bodies)

        for i, kind in enumerate(robot.joint_types):
            errors = []
            for h in ((1.0, 0.1) if kind == "P" else (1e-2, 1e-4)):
                virtual = _central(work, m.q[k], i, h)
                errors.append(abs(virtual - loads[k, i]) / abs(loads[k, i]))
            # Prismatic: work linear in the motion (exact); revolute: second order in h (h^2 / 6
            # of a sine's central difference).
            assert errors[1] < 1e-8 and (kind == "P" or errors[1] < errors[0] / 1000), \
                (k, i, errors)


def test_the_iwr_loads_joint_4_only():
    """With the IWR's gravity (along -x of {0}) the slides are horizontal and joint 3's axis is
    vertical: only joint 4 carries a load, and realistic() switches only it on."""
    robot = iwr.Robot.default()
    full = _robot(api.realistic(robot)[0].gravity)
    m, x = api.simulate(full, 30, seed=2)
    loads, _, _ = _loads(full, np.zeros(robot.n_params), m.q, m.poses, m)
    assert np.abs(loads[:, :3]).max() < 1e-6 and np.abs(loads[:, 3]).max() > 1e6
    # The geometric errors tilt the axes by up to milliradians: loads of a thousandth.
    tilted, _, _ = _loads(full, x[: robot.n_params], m.q, m.poses, m)
    assert 0 < np.abs(tilted[:, :3]).max(axis=0).max() < 1e-1 * np.abs(loads[:, 3]).max()
    carriage = api.realistic(robot, carriage=True)[2]
    assert carriage.parameter_names() == ["joint4.compliance"]
    assert carriage.units() == ["urad/(N m)"] and carriage.values() == pytest.approx([0.02])


def test_objective_and_loop_jacobians_match_central_differences(robot, data,
                                                                check_effect_jacobians):
    """Eq. (10)'s Jacobian in every parameter; the implicit loop's in every other parameter and
    every correction of the readings; the loop at zero corrections is eq. (10)'s prediction."""
    m, x_true = data
    names = EffectProblem(robot, m).parameter_names
    assert names[-4:] == [f"joint{i}.compliance" for i in range(1, 5)]
    check_effect_jacobians(robot, m, 0.5 * x_true, range(0, len(names), 2))


def test_cpp_objective_agrees_with_the_numpy_model(robot, data):
    m, x_true = data
    numpy_problem = EffectProblem(robot, m)
    cpp_problem = iwr.Problem(robot, m)
    for x in (np.zeros(numpy_problem.n_params), x_true, 0.3 * x_true):
        r_np, r_cpp = numpy_problem.residuals(x), cpp_problem.residuals(x)
        assert np.abs(r_np - r_cpp).max() < 1e-10 * max(1.0, np.abs(r_np).max())
    # The carriage alone, some joints listed.
    alone = _robot(joints=[2, 4], legs=False)
    m2, x2 = api.simulate(alone, 20, seed=8)
    assert np.abs(EffectProblem(alone, m2).residuals(x2 * 0.7)
                  - iwr.Problem(alone, m2).residuals(x2 * 0.7)).max() < 1e-10


def _fresh(truth, n, seed):
    """Fresh poses of the true robot with other payloads and temperatures than the data's."""
    zero = np.zeros(truth.n_params + len(effects.parameter_names(truth.effects)))
    rng = np.random.default_rng(seed)
    payload = np.column_stack([rng.uniform(0, 200, n), rng.uniform(-80, 80, (n, 2)),
                               rng.uniform(50, 300, n)])
    return api.simulate(truth, n, seed=seed, x=zero, payloads=payload,
                        temperatures=rng.uniform(10, 35, n))[0]


@pytest.mark.parametrize("method, options", [
    ("lm", {}),
    # DE on the C++ objective with the carriage's compliance (cpp/src/effects.cpp), polished by LM.
    ("de", {"max_evaluations": 20000, "seed": 1}),
])
def test_noise_free_recovery_and_compensation(robot, data, method, options,
                                               fresh_tool_error):
    """Issue 23's check with the carriage's compliance: from noise-free data (two payloads) LM
    (and DE polished by LM) recovers the geometric and every effect parameter so that tool poses
    and leg commands on 50 fresh poses with other loads and temperatures agree with the truth to
    1e-6 mm; commands that leave out the carriage's compliance miss by tens of micrometres."""
    m, x_true = data
    result = iwr.identify(robot, m, method, **options)
    assert result.success, result.message
    assert np.abs(result.x[-4:] - x_true[-4:]).max() < 1e-8
    truth, calibrated = api.apply(robot, x_true), api.apply(robot, result.x)
    fresh = _fresh(truth, 50, seed=11)
    assert fresh_tool_error(calibrated, fresh) < 1e-6
    zero = np.zeros(len(x_true))
    cmd = api.leg_commands(calibrated, fresh.q, fresh.poses, payload=fresh.payload,
                           temperatures=fresh.temperatures)
    assert np.abs(cmd.legs - fresh.legs).max() < 1e-6
    # The commands run on the true robot reach the targets.
    reached = api.forward_kinematics(truth, zero, fresh.q, cmd.legs, fresh, fresh.poses + 1e-3)
    assert np.abs(reached[:, :3] - fresh.poses[:, :3]).max() < 1e-6
    # Without the carriage's compliance the commands miss.
    no_carriage = calibrated.with_effects(*calibrated.effects[:2])
    plain = api.leg_commands(no_carriage, fresh.q, fresh.poses, payload=fresh.payload,
                             temperatures=fresh.temperatures)
    assert np.abs(plain.legs - fresh.legs).max() > 1e-2


@pytest.mark.parametrize("payloads, inseparable", [
    ([[80.0, 50.0, 0.0, 150.0]], ["joint1.compliance", "joint2.compliance"]),
    ([[0.0, 0.0, 0.0, 0.0], [80.0, 50.0, 0.0, 150.0]], []),
])
def test_one_payload_leaves_the_slides_in_the_geometry(payloads, inseparable):
    """A slide whose axis keeps its direction to gravity (no revolute joint before it) carries
    the same force at every pose under one payload: its compliance goes into its offset d. A
    second payload separates it; the revolute joints' loads vary with the pose and one payload
    separates them. The rank of the analytic Jacobian is that of a finite-difference one."""
    # At the file's compliances 0 (as the leg compliances' test): with compliances on, a joint
    # offset also moves the other joints' loads (the platform stays where it was measured), a
    # second-order difference (5e-7 of the largest singular value) a rank cannot weigh.
    robot = _robot(legs=False, compliance=[0.0] * 4)
    n = 40
    m0, _ = api.simulate(robot, n, seed=6, x=np.zeros(robot.n_params + 4))
    payload = np.asarray(payloads)[np.arange(n) % len(payloads)]
    m = Measurements(m0.q, m0.poses, m0.legs, joint_types=robot.joint_types, payload=payload)
    report = iwr.identifiability(robot, m)
    problem = EffectProblem(robot, m)
    x = np.zeros(problem.n_params)
    steps = np.where(np.arange(len(x)) < robot.n_params, 1e-5, 1e-3)
    fd = np.column_stack([_central(problem.residuals, x, i, steps[i])
                          for i in range(problem.n_params)])
    scaled = fd / np.where(np.linalg.norm(fd, axis=0) > 0, np.linalg.norm(fd, axis=0), 1)
    s = np.linalg.svd(scaled, compute_uv=False)
    assert int(np.sum(s > 1e-7 * s[0])) == report.rank
    assert report.rank == report.geometric_rank + 4 - len(inseparable)
    assert [name for name, _ in report.inseparable] == inseparable


def test_table_round_trip_and_checks(tmp_path, robot):
    path = tmp_path / "robot.toml"
    robot.to_toml(path)
    assert "[effects.carriage_compliance]" in path.read_text()
    back = iwr.Robot.from_toml(path)
    assert back.effects == robot.effects
    assert back.effects[-1].units() == ["um/N", "um/N", "urad/(N m)", "urad/(N m)"]
    d = robot.to_dict()
    table = d["effects"]["carriage_compliance"]
    for key, value, message in [
            ("joints", [1, 5], r"carriage_compliance.joints\[1\]: joint 5; robot 'IWR' has 4"),
            ("joints", [2, 2], "distinct joint numbers"),
            ("compliance", [0.01, 0.01], "compliance: 2 values; expected 4"),
            ("compliance", [0.01, 0.01, 0.7, 0.01], r"compliance\[2\]: 0.7 urad/\(N m\)"),
            ("platform_mass_kg", 100.0, "platform_mass_kg: 100.0.*compliance.platform_mass_kg "
                                        "says 120.0")]:
        bad = {**d, "effects": {**d["effects"], "carriage_compliance": {**table, key: value}}}
        with pytest.raises(ValueError, match=message):
            iwr.Robot.from_dict(bad)
    with pytest.raises(ValueError, match="not switched on for a robot"):
        CarriageCompliance(*HEXAPOD, *PLATFORM, TILTED).parameter_names()
    # Identified values are kept by the calibrated robot and written.
    x = np.zeros(robot.n_params + 11)
    x[-4:] = [0.001, 0.002, 0.01, 0.02]
    cal = api.apply(robot, x)
    assert cal.effects[-1].values() == pytest.approx([0.006, 0.007, 0.06, 0.07])
    cal.to_toml(tmp_path / "cal.toml")
    assert iwr.Robot.from_toml(tmp_path / "cal.toml").effects == cal.effects
    # The problem file carries the table; the engine's objective is the same.
    m, _ = api.simulate(robot, 10, seed=1)
    iwr.Problem(robot, m).save(tmp_path / "p.iwrp")
    loaded = iwr.Problem.load(tmp_path / "p.iwrp")
    assert loaded.robot.effects == robot.effects
    assert loaded.cost(x) == pytest.approx(iwr.Problem(robot, m).cost(x), rel=1e-12)


def test_efficient_estimator_with_the_carriage_compliance():
    """The efficient estimator (implicit loop with the joints' change) on the IWR with realistic
    effects and instrument noise: it converges, its fit test passes and joint 4's compliance is
    within 4 of its standard deviations of the truth."""
    robot = iwr.Robot.default()
    r = robot.with_effects(*api.realistic(robot, carriage=True))
    noisy, x_true = api.simulate(r, 80, seed=5, noise=iwr.Noise.realistic())
    report = iwr.identifiability(r, noisy)
    assert report.rank == report.geometric_rank + 8 and report.effects_identifiable
    result = iwr.identify(r, noisy, "efficient", noise=iwr.Noise.realistic())
    assert result.success, result.message
    assert result.parameter_names[-1] == "joint4.compliance"
    assert abs(result.x[-1] - x_true[-1]) < 4 * result.std[-1]
    assert result.std[-1] < 0.1 * r.effects[-1].max_revolute
