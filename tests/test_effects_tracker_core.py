"""The C++ objective of tracker data with effects (cpp/src/effects_tracker.cpp): checked against
the numpy model (iwr.effects.tracker.TrackerEffectModel), minimised by DE, CRS2 and BOBYQA,
carried by the problem file and run by iwr-engine and iwr-calibrate (issue 23)."""

from __future__ import annotations

import numpy as np
import pytest

import iwr
from iwr import _core, kinds
from iwr.effects import api, tracker_study
from iwr.effects import tracker as et
from iwr.effects.builtin import LegCompliance, LegThermal
from iwr.problem_file import encode_problem, read_problem

PAYLOADS, FRESH_PAYLOADS = tracker_study.PAYLOADS, tracker_study.FRESH_PAYLOADS


def _variant(plain, name):
    comp, _ = api.realistic(plain)
    return plain.with_effects(*{
        "realistic": api.realistic(plain),  # per-leg compliance, one alpha identified
        "shared compliance, alpha per leg": (
            LegCompliance(80.0, [10.0, -5.0, 30.0], comp.gravity, 0.012, per_leg=False),
            LegThermal([11.0, 11.5, 12.0, 12.5, 13.0, 13.5], 18.0, identify=True, per_leg=True)),
        "thermal alone, given": (LegThermal(11.5, 20.0),),
        "compliance alone": (comp,),
    }[name])


@pytest.mark.parametrize("kind", ["points", "probe"])
@pytest.mark.parametrize("name", ["realistic", "shared compliance, alpha per leg",
                                  "thermal alone, given", "compliance alone"])
def test_cpp_objective_agrees_with_the_numpy_model(monkeypatch, measured_with_effects, kind, name):
    """The C++ residuals and costs against the numpy model's (its forward kinematics solved to
    1e-13 mm here) at random points within the bounds; the batch costs the same bits whatever
    the number of threads, and the single costs'."""
    robot = _variant(measured_with_effects(kind).with_effects(), name)
    temps = (np.random.default_rng(2).uniform(15, 28, (12, 6)) if "per leg" in name else None)
    data, truth = et.simulate(robot, 12, seed=7, temperatures=temps,
                              payloads=PAYLOADS if robot.effects[0].name == "compliance" else None,
                              hidden=0.2 if kind == "points" else 0.0)
    problem, start = et.effect_tracker_problem(robot, data)
    monkeypatch.setattr(et, "FK_TOLERANCE_MM", 1e-13)
    rng = np.random.default_rng(3)
    lo, hi = problem.lower, problem.upper
    X = np.vstack([truth, start, lo + (hi - lo) * rng.random((4, problem.n_params))])
    cpp = problem._objective()
    worst = 0.0
    for x in X:
        rn = problem.residuals(x)  # numpy
        rc = cpp.residuals(x)
        assert np.all(np.isfinite(rc)) and not problem.failures(x)
        worst = max(worst, np.abs(rc - rn).max())
        assert problem.cost(x) == pytest.approx(float(rn @ rn), rel=1e-11)
    assert worst < 1e-11, worst  # mm; the residuals are 0.01 to a few mm away from the truth
    assert problem.cost(truth) < 1e-20  # noise-free: the truth fits to round-off
    costs = problem.cost_batch(X, workers=1)
    np.testing.assert_array_equal(costs, problem.cost_batch(X, workers=2))
    np.testing.assert_array_equal(costs, [problem.cost(x) for x in X])
    # The platform poses of the C++ forward kinematics with the effects are numpy's.
    np.testing.assert_allclose(cpp.platform_poses(X[2]), problem.platform_poses(X[2]),
                               rtol=0, atol=1e-11)


def test_failures_and_bad_inputs(measured_with_effects):
    robot = _variant(measured_with_effects("points").with_effects(), "realistic")
    data, truth = et.simulate(robot, 6, seed=1, payloads=PAYLOADS)
    problem, _ = et.effect_tracker_problem(robot, data)
    cpp = problem._objective()
    # Legs 10 m longer at pose 2 have no forward kinematics: a finite penalty there, named.
    legs = data.legs.copy()
    legs[2] += 1e4
    far = iwr.tracker.TrackerMeasurements(data.q, legs, points=data.points,
                                          joint_types=data.joint_types, payload=data.payload,
                                          temperatures=data.temperatures)
    with pytest.raises(iwr.ForwardKinematicsError, match="no forward kinematics for the robot "
                                                         "at the reference"):
        et.TrackerEffectProblem(robot, robot.tracker, far).cost(truth)
    geometry, tables = robot._geometry, [(e.name, e.to_dict()) for e in robot.effects]
    args = dict(kind="points", registration=robot.tracker.registration,
                reflectors=robot.tracker.reflectors, probe=np.zeros(6), probe_length=100.0,
                gravity=np.array([0.0, 0.0, -9.80665]), q=data.q, legs=data.legs,
                points=data.tracker_points(robot.tracker), payload=data.payload,
                temperatures=data.temperatures, reference=np.zeros(58), home=robot.home_pose)
    for change, message in [
        ({"temperatures": np.zeros((0, 0))}, "temperatures: the thermal effect"),
        ({"payload": data.payload[:, :3]}, r"payload: shape \(6, 3\); expected \(6, 4\)"),
        ({"gravity": np.array([0.0, 0.0, -5.0])}, "gravity: norm 5 m/s\\^2 in the tracker frame"),
        ({"effects": [(e.name, {**e.to_dict(), "joints": [5]} if "joints" in e.changes
                       else e.to_dict()) for e in api.realistic(robot, carriage=True)]},
         r"effects.carriage_compliance.joints\[0\]: 5; expected a joint number from 1 to 4"),
    ]:
        with pytest.raises(ValueError, match=message):
            _core.TrackerEffectObjective(geometry, **{"effects": tables, **args, **change})
    with pytest.raises(ValueError, match=r"x: 10 values given but this problem has 80 "
                                         r"parameters \(58 of the robot, 7 of the effects, 15"):
        cpp.cost(np.zeros(10))
    x = truth.copy()
    x[58] = np.nan
    with pytest.raises(ValueError, match="x"):
        cpp.cost(x)
    assert cpp.failures(truth) == []
    # Leg 1 shorter than nothing at every pose: no forward kinematics, the finite penalty on
    # every seen coordinate (1000 mm), each pose named; never NaN.
    x = truth.copy()
    x[problem.parameter_names.index("leg1.dl0")] -= 5000.0
    assert [k for k, _ in cpp.failures(x)] == list(range(6))
    np.testing.assert_array_equal(cpp.residuals(x), np.full(6 * 9, 1e3))
    assert problem.cost_batch(x[None])[0] == cpp.cost(x) == 6 * 9 * 1e6


# --- the problem file --------------------------------------------------------------------------


def test_problem_file_carries_tracker_data_with_effects(tmp_path, measured_with_effects):
    for kind in ("points", "probe"):
        plain = measured_with_effects(kind).with_effects()
        robot = _variant(plain, "realistic")
        data, truth = et.simulate(robot, 10, seed=4, payloads=PAYLOADS,
                                  hidden=0.2 if kind == "points" else 0.0)
        problem, start = et.effect_tracker_problem(robot, data)
        path = tmp_path / f"{kind}.iwrp"
        problem.save(path, x0=start)
        d = read_problem(path)
        assert d["kind"] == kind and d["version"] == 4
        assert d["effects"] == [(e.name, e.to_dict()) for e in robot.effects]
        np.testing.assert_array_equal(d["payload"], data.payload)
        np.testing.assert_array_equal(d["temperatures"], data.temperatures)
        np.testing.assert_array_equal(d["tracker_gravity"], robot.tracker.gravity)
        assert d["parameter_names"] == problem.parameter_names and d["bounds_kind"] == "default"
        back = iwr.Problem.load(path)
        assert isinstance(back, et.TrackerEffectProblem)
        assert back.robot.effects == robot.effects and back.n_params == problem.n_params
        # The round trip is bit for bit: the same file again, the same costs, the engine's too.
        assert encode_problem(back, x0=start) == encode_problem(problem, x0=start)
        X = np.vstack([truth, start, problem.lower + 0.3 * (problem.upper - problem.lower)])
        costs = problem.cost_batch(X)
        np.testing.assert_array_equal(back.cost_batch(X), costs)
        np.testing.assert_array_equal(_core._engine_costs(str(path), X), costs)
        # The fingerprints: the data's covers the loads and temperatures, the robot's gravity.
        assert kinds.of(data).fingerprint(robot, data) == d["data_fingerprint"]
        hotter = iwr.tracker.TrackerMeasurements(
            data.q, data.legs, points=data.points, probe=data.probe,
            joint_types=data.joint_types, payload=data.payload,
            temperatures=data.temperatures + 0.1)
        et.TrackerEffectProblem(robot, robot.tracker, hotter, (problem.lower, problem.upper)
                                ).save(tmp_path / "hot.iwrp", x0=start)
        hot = read_problem(tmp_path / "hot.iwrp")
        assert hot["data_fingerprint"] != d["data_fingerprint"]
        assert hot["robot_fingerprint"] == d["robot_fingerprint"]
        s = robot.tracker
        tilted_setup = iwr.tracker.TrackerSetup(
            s.registration, reflectors=s.reflectors, probe=s.probe, probe_length=s.probe_length,
            names=s.names if kind == "points" else None, gravity=[0.2, 0.0, -9.80])
        tilted = robot.with_tracker(setup=tilted_setup)
        et.TrackerEffectProblem(tilted, tilted_setup, data, (problem.lower, problem.upper)
                                ).save(tmp_path / "tilted.iwrp", x0=start)
        tilt = read_problem(tmp_path / "tilted.iwrp")
        assert tilt["robot_fingerprint"] != d["robot_fingerprint"]
        assert tilt["data_fingerprint"] == d["data_fingerprint"]
        np.testing.assert_array_equal(iwr.Problem.load(tmp_path / "tilted.iwrp").setup.gravity,
                                      [0.2, 0.0, -9.80])


# --- the methods ---------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["crs2", "bobyqa"])
def test_crs2_and_bobyqa_on_tracker_data_with_effects(measured_with_effects, method):
    robot = _variant(measured_with_effects("points").with_effects(), "realistic")
    data, _ = et.simulate(robot, 10, seed=6, payloads=PAYLOADS)
    problem, start = et.effect_tracker_problem(robot, data)
    result = iwr.identify(robot, data, method, max_evaluations=300, seed=2)
    assert result.parameter_names == problem.parameter_names
    assert result.fun == problem.cost(result.x) <= problem.cost(start)
    if method == "bobyqa":  # a local method from the start; CRS2's 300 are its first population
        assert result.fun < 0.5 * problem.cost(start)
    assert np.all(result.x >= problem.lower) and np.all(result.x <= problem.upper)


@pytest.mark.parametrize("kind", ["points", "probe"])
def test_de_and_lm_recover_tool_poses_and_leg_commands(measured_with_effects, kind):
    """Issue 23's check through DE: DE on the C++ objective with the effects, polished by LM,
    from noise-free tracker data with three payloads; tool poses and leg commands on fresh poses
    with other loads and temperatures agree with the truth to 1e-6 mm."""
    robot = _variant(measured_with_effects(kind).with_effects(), "realistic")
    data, truth = et.simulate(robot, 30, seed=3, payloads=PAYLOADS)
    res = iwr.identify(robot, data, "de", population_size=20, generations=15, seed=1,
                       workers=2, progress=False)
    assert res.settings["polish"] and res.success, res.message
    fresh, _ = et.simulate(robot, 20, seed=99, x=truth, payloads=FRESH_PAYLOADS,
                           temperatures=np.linspace(14.0, 30.0, 20))
    a = et.tool_frames(robot, res.x, fresh)
    b = et.tool_frames(robot, truth, fresh)
    assert np.abs(a[:, :3, 3] - b[:, :3, 3]).max() < 1e-6
    legs = et.leg_commands(robot, res.x, b, fresh.q, fresh)
    assert np.abs(legs - fresh.legs).max() < 1e-6


# --- iwr-engine and iwr-calibrate ----------------------------------------------------------------


def test_launcher_on_tracker_data_with_effects_equals_identify(tmp_path, measured_with_effects,
                                                              engine_equals_identify):
    """iwr-calibrate ROBOT.toml DATA.csv on point data with effects (payload and temperature
    columns): the engine's DE run is iwr.identify's, bit for bit, and its cost the problem's."""
    robot = _variant(measured_with_effects("points").with_effects(), "realistic")
    data, _ = et.simulate(robot, 10, seed=8, payloads=PAYLOADS)
    exe, py, problem = engine_equals_identify(robot, data, tmp_path, 20, 12)
    assert isinstance(problem, et.TrackerEffectProblem)
    assert exe.parameter_names == problem.parameter_names == py.parameter_names
    assert exe.parameter_names[58:65] == [f"leg{j}.compliance" for j in range(1, 7)] + [
        "legs.alpha"]


@pytest.mark.parametrize("kind", ["points", "probe"])
@pytest.mark.parametrize("name", ["realistic", "thermal alone, given"])
def test_chord_steps_solve_the_box_and_newton_takes_over_far_outside(monkeypatch,
                                                                     measured_with_effects,
                                                                     kind, name):
    """The forward kinematics with the effects by chord steps (the statics' inverse at the
    reference geometry and pose, refined with the current statics: cpp/src/effects_tracker.cpp)
    solve every pose at random points within the bounds and ten times as far from the bounds'
    centre; a hundred times as far Newton's method from the reference takes over for some. The
    residuals are the numpy model's (solved to 1e-13 mm) within 1e-11 mm on either path. With a
    leg 2 m short no pose closes: every one failed, the same as `failures` names."""
    robot = _variant(measured_with_effects(kind).with_effects(), name)
    compliance = robot.effects[0].name == "compliance"
    data, _ = et.simulate(robot, 12, seed=8, payloads=PAYLOADS if compliance else None)
    problem, _ = et.effect_tracker_problem(robot, data)
    monkeypatch.setattr(et, "FK_TOLERANCE_MM", 1e-13)
    cpp = problem._objective()
    lo, hi = problem.lower, problem.upper
    X = lo + (hi - lo) * np.random.default_rng(11).random((20, problem.n_params))
    for x in X:
        np.testing.assert_array_equal(cpp.solve_paths(x), 0)
    centre = (lo + hi) / 2
    ten, hundred = (centre + k * (X[0] - centre) for k in (10, 100))
    np.testing.assert_array_equal(cpp.solve_paths(ten), 0)
    paths = cpp.solve_paths(hundred)
    assert 1 in paths and set(paths) <= {0, 1}, paths
    for x in (X[1], ten, hundred):
        assert np.abs(cpp.residuals(x) - problem.residuals(x)).max() < 1e-11
    short = X[1].copy()
    short[4 * robot.n_joints + 36] = -2000.0  # leg 1's offset (mm)
    np.testing.assert_array_equal(cpp.solve_paths(short), 3)
    assert [k for k, _ in cpp.failures(short)] == list(range(12))
