"""The C++ leg objective with effects (cpp/src/effects.cpp) behind iwr.Problem: checked against
the numpy model (iwr.effects.problem.EffectProblem), minimised by DE, CRS2 and BOBYQA, carried
by the problem file (version 4) and run by iwr-engine and iwr-calibrate (issue 23, item 2)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr import _core, kinds
from iwr.effects import api
from iwr.effects.builtin import LegCompliance, LegThermal
from iwr.effects.problem import EffectProblem
from iwr.measurements import Measurements
from iwr.problem_file import FormatError, encode_problem, read_problem


@pytest.fixture(scope="module")
def robot():
    return iwr.Robot.default()


@pytest.fixture(scope="module")
def data(with_effects):
    return api.simulate(with_effects, 40, seed=5)


def _variant(robot, name):
    comp, _ = api.realistic(robot)
    shared = LegCompliance(80.0, [10.0, -5.0, 30.0], comp.gravity, 0.02, per_leg=False)
    return robot.with_effects(*{
        "realistic": api.realistic(robot),
        "shared compliance, alpha per leg": (
            shared, LegThermal([11.0, 11.5, 12.0, 12.5, 13.0, 13.5], 18.0, identify=True,
                               per_leg=True)),
        "thermal first, alpha given": (LegThermal(11.5, 20.0), comp),
        "compliance alone": (comp,),
        "thermal alone, identified": (LegThermal(12.0, 21.0, identify=True),),
    }[name])


@pytest.mark.parametrize("name", ["realistic", "shared compliance, alpha per leg",
                                  "thermal first, alpha given", "compliance alone",
                                  "thermal alone, identified"])
@pytest.mark.parametrize("weighted", [False, True])
def test_problem_agrees_with_the_numpy_model(robot, name, weighted):
    """The C++ objective's residuals, cost and batch costs against the numpy model's, at random
    points within the bounds; the batches the same whatever the number of threads; the
    Jacobian the numpy model's (exact, checked against differences in tests/test_effects.py)."""
    rob = _variant(robot, name)
    temps = np.random.default_rng(2).uniform(15, 28, (30, 6)) if "per leg" in name else None
    m, _ = api.simulate(rob, 30, seed=7, temperatures=temps)
    if weighted:
        w = np.random.default_rng(1).uniform(0.2, 2.0, (30, 6))
        m = Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types, weights=w,
                         payload=m.payload, temperatures=m.temperatures)
    problem, numpy_model = iwr.Problem(rob, m), EffectProblem(rob, m)
    assert problem.n_params == numpy_model.n_params > rob.n_params
    assert problem.parameter_names == numpy_model.parameter_names
    np.testing.assert_array_equal(problem.lower, numpy_model.lower)
    np.testing.assert_array_equal(problem.upper, numpy_model.upper)
    rng = np.random.default_rng(3)
    X = problem.lower + (problem.upper - problem.lower) * rng.random((6, problem.n_params))
    for x in X:
        r, rn = problem.residuals(x), numpy_model.residuals(x)
        assert np.abs(r - rn).max() <= 1e-10 * np.abs(rn).max()
        assert problem.cost(x) == pytest.approx(numpy_model.cost(x), rel=1e-10)
    costs = problem.cost_batch(X, workers=1)
    np.testing.assert_array_equal(costs, problem.cost_batch(X, workers=2))
    np.testing.assert_array_equal(costs, [problem.cost(x) for x in X])
    np.testing.assert_allclose(costs, numpy_model.cost_batch(X), rtol=1e-10, atol=0)
    r, jac = problem.residuals_and_jacobian(X[0])
    np.testing.assert_array_equal(r, problem.residuals(X[0]))
    np.testing.assert_allclose(jac, numpy_model.jacobian(X[0]), rtol=0, atol=1e-12)


def test_whitened_problem_with_effects(with_effects, data):
    """A whitening of one's own (the noise model does not propagate through the effects yet):
    the residuals are W_k times the plain ones, and the Jacobian too."""
    m, x = data
    rng = np.random.default_rng(4)
    w = np.tril(rng.uniform(0.5, 1.5, (len(m), 6, 6)))
    plain, whitened = iwr.Problem(with_effects, m), iwr.Problem(with_effects, m, whitening=w)
    x = x + 1e-4
    r0, j0 = plain.residuals_and_jacobian(x)
    r1, j1 = whitened.residuals_and_jacobian(x)
    np.testing.assert_allclose(r1, np.einsum("kij,kj->ki", w, r0.reshape(-1, 6)).ravel(),
                               rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(j1.reshape(len(m), 6, -1),
                               np.einsum("kij,kjp->kip", w, j0.reshape(len(m), 6, -1)),
                               rtol=1e-12, atol=1e-15)
    assert whitened.cost(x) == pytest.approx(r1 @ r1, rel=1e-12)


@pytest.mark.parametrize("method", ["crs2", "bobyqa"])
def test_crs2_and_bobyqa_minimise_the_objective_with_effects(with_effects, data, method):
    m, _ = data
    result = iwr.identify(with_effects, m, method, max_evaluations=400, seed=2)
    problem = iwr.Problem(with_effects, m)
    assert result.parameter_names == problem.parameter_names and len(result.x) == 65
    assert result.fun == problem.cost(result.x) < problem.cost(np.zeros(65))
    assert np.all(result.x >= problem.lower) and np.all(result.x <= problem.upper)


def test_bad_effect_inputs_are_refused(robot, with_effects, data):
    m, _ = data
    with pytest.raises(ValueError, match="thermal effect.*T_C"):
        iwr.Problem(with_effects, Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types,
                                               payload=m.payload))
    geometry = with_effects._geometry
    empty = np.zeros((0, 0))
    for effects, message in [
        ([("compliance", {**with_effects.effects[0].to_dict(), "stiffness": 1.0})],
         "effects.compliance.stiffness: unknown key; allowed: per_leg"),
        ([("backlash", {})], "effects.backlash: no model of this effect in the C\\+\\+ core"),
        ([("thermal", {**with_effects.effects[1].to_dict(), "identify": 1})],
         "effects.thermal.identify: expected true or false"),
        ([("thermal", {**with_effects.effects[1].to_dict(), "alpha_ppm_per_K": "steel"})],
         "effects.thermal.alpha_ppm_per_K: expected true/false, a number or an array of "
         "numbers, got str"),
    ]:
        with pytest.raises(ValueError, match=message):
            _core.EffectObjective(geometry, effects, m.q, m.poses, m.legs, m.payload,
                                  m.temperatures, empty, empty)
    with pytest.raises(ValueError, match=r"payload: shape \(40, 3\); expected \(40, 4\)"):
        _core.EffectObjective(geometry, [("compliance", with_effects.effects[0].to_dict())],
                              m.q, m.poses, m.legs, m.payload[:, :3], empty, empty, empty)


# --- the problem file (version 4) ----------------------------------------------------------------


def test_problem_file_carries_the_effects(tmp_path, robot, with_effects, data):
    m, x_true = data
    problem = iwr.Problem(with_effects, m)
    path = tmp_path / "e.iwrp"
    problem.save(path)
    d = read_problem(path)
    assert d["version"] == 4
    assert d["effects"] == [(e.name, e.to_dict()) for e in with_effects.effects]
    np.testing.assert_array_equal(d["payload"], m.payload)
    np.testing.assert_array_equal(d["temperatures"], m.temperatures)
    assert d["parameter_names"] == problem.parameter_names
    back = iwr.Problem.load(path)
    assert back.robot.effects == with_effects.effects and back.n_params == 65
    np.testing.assert_array_equal(back.measurements.payload, m.payload)
    X = np.vstack([x_true, problem.lower + 0.3 * (problem.upper - problem.lower)])
    np.testing.assert_array_equal(back.cost_batch(X), problem.cost_batch(X))
    # The engine's objective (make_objective) is the same code: the same bits.
    np.testing.assert_array_equal(_core._engine_costs(str(path), X), problem.cost_batch(X))
    # iwr report's fingerprint of the data file covers the loads and temperatures.
    assert kinds.of(m).fingerprint(with_effects, m) == d["data_fingerprint"]
    hotter = Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types, payload=m.payload,
                          temperatures=m.temperatures + 0.1)
    iwr.Problem(with_effects, hotter).save(tmp_path / "hot.iwrp")
    hot = read_problem(tmp_path / "hot.iwrp")
    assert hot["data_fingerprint"] != d["data_fingerprint"]
    assert hot["robot_fingerprint"] == d["robot_fingerprint"]
    stiffer = api.apply(with_effects, np.r_[np.zeros(58), np.full(6, -0.005), 0.0])
    iwr.Problem(stiffer, m).save(tmp_path / "stiff.iwrp")
    stiff = read_problem(tmp_path / "stiff.iwrp")
    assert stiff["robot_fingerprint"] != d["robot_fingerprint"]
    assert stiff["data_fingerprint"] == d["data_fingerprint"]
    # Without effects the file is as before (its fingerprints ignore the absent fields).
    geometric = iwr.Problem(robot, Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types))
    geometric.save(tmp_path / "g.iwrp")
    g = read_problem(tmp_path / "g.iwrp")
    assert g["effects"] == [] and g["payload"] is None and g["temperatures"] is None
    assert g["data_fingerprint"] == kinds.of(m).fingerprint(robot, geometric.measurements)


def test_problem_file_refuses_bad_effects(tmp_path, with_effects, data):
    m, _ = data
    problem = iwr.Problem(with_effects, m)
    from iwr.problem_file import encode_problem as encode

    good = encode(problem)
    fields = _core._decode_problem(good, "x: ")
    base = {k: v for k, v in fields.items() if k not in (
        "version", "robot_fingerprint", "data_fingerprint")}
    for change, message in [
        ({"effects": [("compliance", {**fields["effects"][0][1], "gravity_m_s2": [0.0, 0.0, -5.0]}),
                      fields["effects"][1]]},
         "effects.compliance.gravity_m_s2: norm 5 m/s\\^2; expected 9.80665 within 1 %"),
        ({"temperatures": None}, "temperatures: the thermal effect is on"),
        ({"temperatures": np.full((40, 2), 20.0)}, "temperature columns: 2; expected 0"),
        ({"payload": np.full((40, 4), -1.0)}, "payload: row 0 has a negative mass"),
    ]:
        with pytest.raises(ValueError, match=message):
            _core._encode_problem({**base, **change})
    # A file whose table C++ reads but Python's effect refuses: a FormatError naming the file.
    table = {**fields["effects"][0][1], "compliance_um_per_N": [0.2] * 6}  # above max_um_per_N
    path = tmp_path / "odd.iwrp"
    path.write_bytes(_core._encode_problem({**base, "effects": [("compliance", table),
                                                               fields["effects"][1]]}))
    with pytest.raises(FormatError, match=r"odd.iwrp: effects.compliance.compliance_um_per_N"):
        iwr.Problem.load(path)


# --- iwr-engine and iwr-calibrate ------------------------------------------------------------


def _find(name: str) -> str:
    cand = Path(sys.executable).parent / name
    exe = str(cand) if cand.exists() else shutil.which(name)
    if exe is None:
        pytest.fail(f"{name} is not installed: `pip install .` puts it next to python")
    return exe


def test_engine_and_launcher_run_with_effects(tmp_path, with_effects):
    """iwr-calibrate on a robot TOML with [effects] and data with payload and temperature
    columns: the engine's run is iwr.identify's DE run on the same problem, bit for bit, and
    iwr report refuses the result clearly (the job does not model the effects yet)."""
    m, _ = api.simulate(with_effects, 15, seed=8)
    with_effects.to_toml(tmp_path / "robot.toml")
    m.to_csv(tmp_path / "data.csv")
    settings = ["--population-size", 30, "--generations", 40, "--seed", 4, "--F", 0.7,
                "--CR", 0.9, "--threads", 2, "--quiet"]
    proc = subprocess.run([_find("iwr-calibrate"), tmp_path / "robot.toml",
                           tmp_path / "data.csv", "--output", tmp_path / "run.json",
                           *map(str, settings)], capture_output=True, text=True, timeout=300,
                          check=False)
    assert proc.returncode == 0, proc.stderr
    result = iwr.load_result(tmp_path / "run.json")
    robot = iwr.Robot.from_toml(tmp_path / "robot.toml")
    data = Measurements.from_csv(tmp_path / "data.csv", robot=robot)
    assert result.parameter_names[-7:] == [f"leg{j}.compliance" for j in range(1, 7)] + [
        "legs.alpha"]
    problem = iwr.Problem.load(tmp_path / "run.json.iwrp")
    assert result.fun == problem.cost(result.x) == iwr.Problem(robot, data).cost(result.x)
    reference = iwr.identify(robot, data, "de", strategy="rand1bin", population_size=30,
                             generations=40, seed=4, F=0.7, CR=0.9, workers=2, polish=False,
                             progress=False)
    np.testing.assert_array_equal(result.x, reference.x)
    report = subprocess.run([_find("iwr"), "report", tmp_path / "run.json",
                             tmp_path / "robot.toml", tmp_path / "data.csv", "--out",
                             tmp_path / "report"], capture_output=True, text=True, timeout=300,
                            check=False)
    # iwr report renders it with the effects (the job models them on pose data).
    assert report.returncode == 0, report.stdout + report.stderr
    text = (tmp_path / "report" / "report.md").read_text()
    assert "legs.alpha" in text and "Effects" in text
    # The same problem file through encode_problem is the file the launcher wrote (no drift).
    assert read_problem(tmp_path / "run.json.iwrp")["robot_fingerprint"] == \
        _core._decode_problem(encode_problem(problem), "")["robot_fingerprint"]
