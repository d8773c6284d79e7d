"""Laser-tracker data (issue 13): the setup, the objective and its exact Jacobian, the registration
guess, the noise model, the null directions, and recovery of the robot from point data."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import iwr
from iwr.methods import METHODS, ReducedProblem
from iwr.methods.lm import levenberg_marquardt
from iwr.simulation import sample_poses
from iwr.tracker import (
    FAILED_RESIDUAL,
    RegistrationError,
    TrackerMeasurements,
    TrackerNoise,
    TrackerProblem,
    TrackerSetup,
    guess_registration,
    kabsch,
    null_space,
    simulate_tracker,
    tool_pose_errors,
    true_points,
)
from iwr.transforms import pose_matrix, rotation_angle

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
# 2 m from the robot's origin and turned 90 degrees.
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)


def truth_vector(robot: iwr.Robot, setup: TrackerSetup, seed: int) -> np.ndarray:
    """Robot errors drawn as iwr.simulate draws them; the registration 5 mm and 1 degree off the
    nominal; each reflector 1 mm off (or the probe 1 mm and 1 degree)."""
    rng = np.random.default_rng(seed)
    lo, hi = robot.default_bounds()
    xr = lo + (hi - lo) * rng.random(robot.n_params)

    def unit(n: int) -> np.ndarray:
        v = rng.standard_normal((n, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    reg = np.concatenate([5.0 * unit(1)[0], math.radians(1.0) * unit(1)[0]])
    if setup.kind == "points":
        offsets = unit(setup.n_reflectors).ravel()
    else:
        offsets = np.concatenate([unit(1)[0], math.radians(1.0) * unit(1)[0]])
    return np.concatenate([xr, reg, offsets])


@pytest.fixture(scope="module")
def robot() -> iwr.Robot:
    return iwr.Robot.default()


def points_setup(k: int = 3) -> TrackerSetup:
    return TrackerSetup(REGISTRATION, reflectors=REFLECTORS[:k])


# -- setup ----------------------------------------------------------------------------------------

def test_setup_names_order_and_toml_round_trip(robot):
    s = points_setup()
    assert s.n_params == 15
    assert s.parameter_names[:6] == ["tracker.x", "tracker.y", "tracker.z", "tracker.rx",
                                     "tracker.ry", "tracker.rz"]
    assert s.parameter_names[6:9] == ["reflector1.x", "reflector1.y", "reflector1.z"]
    assert s.parameter_names[-1] == "reflector3.z"
    back = TrackerSetup.from_dict(json.loads(json.dumps(s.to_dict())))
    assert back == s
    p = TrackerSetup(REGISTRATION, probe=(10, 0, 50, 0.1, 0, 0), probe_length=80)
    assert p.parameter_names[6:] == ["probe.x", "probe.y", "probe.z", "probe.rx", "probe.ry",
                                     "probe.rz"]
    assert TrackerSetup.from_dict(p.to_dict()) == p
    data = simulate_tracker(robot, s, 3, seed=0)[0]
    names = TrackerProblem(robot, s, data).parameter_names
    assert names == robot.parameter_names + s.parameter_names


def test_setup_rejects_bad_input():
    with pytest.raises(ValueError, match="either reflectors"):
        TrackerSetup(REGISTRATION)
    with pytest.raises(ValueError, match=r"reflectors: reflector 1: 1; expected 3 numbers"):
        TrackerSetup(REGISTRATION, reflectors=[1, 2, 3])
    with pytest.raises(ValueError, match=r"tracker: unknown key\(s\) reflector"):
        TrackerSetup.from_dict({"registration": list(REGISTRATION), "reflector": [[0, 0, 0]]})
    with pytest.raises(ValueError, match="tracker.registration: missing"):
        TrackerSetup.from_dict({"reflectors": [[0, 0, 0]]})
    with pytest.raises(ValueError, match="registration: entry 2 is not finite"):
        TrackerSetup((0, 0, math.nan, 0, 0, 0), reflectors=[(0, 0, 0)])


def test_setup_refuses_angles_in_degrees():
    """An angle beyond 2 pi is degrees written for radians: refused, naming the field and axis,
    through TrackerSetup, Robot.with_tracker and from_dict alike (the TOML: test_tracker_api)."""
    with pytest.raises(ValueError, match=r"^registration gamma \(entry 5\) = 90: angles are in "
                                         r"radians \(90 deg = 1\.5708 rad\); expected \|angle\| "
                                         r"<= 2 pi$"):
        TrackerSetup((2000, 0, 0, 0, 0, 90), reflectors=REFLECTORS)
    with pytest.raises(ValueError, match=r"^probe beta \(entry 4\) = -180: angles are in radians "
                                         r"\(-180 deg = -3\.1416 rad\)"):
        TrackerSetup(REGISTRATION, probe=(0, 0, 60, 0, -180, 0))
    with pytest.raises(ValueError, match=r"^registration alpha \(entry 3\) = 6\.3: "):
        iwr.Robot.default().with_tracker(registration=(0, 0, 0, 6.3, 0, 0), reflectors=REFLECTORS)
    with pytest.raises(ValueError, match=r"^tracker: registration beta \(entry 4\) = 45: "):
        TrackerSetup.from_dict({"registration": [0, 0, 0, 0, 45, 0], "reflectors": REFLECTORS})
    # Lengths are millimetres, whatever their size; every angle up to 2 pi is taken as it is.
    edge = (2000, -3000, 10, 2 * math.pi, -2 * math.pi, -6.28)
    np.testing.assert_array_equal(TrackerSetup(edge, reflectors=REFLECTORS).registration, edge)
    np.testing.assert_array_equal(TrackerSetup(edge, probe=edge).probe, edge)


@pytest.mark.parametrize(("reflectors", "message"), [
    ([(120, 0, 40), (-60, 104)],
     r"reflectors: reflector 2: \(-60, 104\); expected 3 numbers \(x, y, z in mm\)"),
    ([(120, 0, 40), (-60, 104, 40, 1)], r"reflector 2: \(-60, 104, 40, 1\); expected 3 numbers"),
    ([(120, 0, 40), (-60, "104", 40)],
     r"reflector 2: entry 1 is '104'; expected a number \(x, y, z in mm\)"),
    ([(120, 0, 40), (True, 0, 40)], r"reflector 2: entry 0 is True; expected a number"),
    ([(120, 0, 40), (-60, math.inf, 40)], r"reflector 2: entry 1 is not finite"),
    ([], r"reflectors: empty; expected at least one reflector, 3 numbers \(x, y, z in mm\)"),
    ("abc", r"reflectors: 'abc'; expected a list of reflectors, 3 numbers each"),
    (5, r"reflectors: 5; expected a list of reflectors"),
    (np.zeros((2, 3, 1)), r"reflector 1: \[\[0\.0\], \[0\.0\], \[0\.0\]\]; expected 3 numbers"),
])
def test_setup_names_a_bad_reflector(reflectors, message):
    with pytest.raises(ValueError, match=message):
        TrackerSetup(REGISTRATION, reflectors=reflectors)


def test_setup_takes_reflectors_as_any_array_of_numbers():
    expected = np.array(REFLECTORS)
    for given in (REFLECTORS, expected, expected.astype(np.float32), [list(r) for r in REFLECTORS],
                  np.array(REFLECTORS, dtype=int)):
        np.testing.assert_array_equal(TrackerSetup(REGISTRATION, reflectors=given).reflectors,
                                      np.asarray(given, dtype=float))


def test_correction_is_right_multiplied_in_world_frame():
    s = points_setup()
    xs = np.zeros(s.n_params)
    xs[:3] = (1.0, 2.0, 3.0)
    xs[5] = 0.01  # about z of {0}
    t = s.registration_matrix(xs)
    c = np.eye(4)
    c[:3, :3] = iwr.transforms.rotvec_matrix(np.array([0, 0, 0.01]))
    c[:3, 3] = (1.0, 2.0, 3.0)
    np.testing.assert_allclose(t, pose_matrix(np.array(REGISTRATION)) @ c, atol=1e-12)
    np.testing.assert_allclose(s.correction_for(t)[:6], xs[:6], atol=1e-12)


# -- the objective --------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["points", "probe"])
def test_residuals_match_a_numpy_prediction_and_the_jacobian_central_differences(robot, kind):
    if kind == "points":
        setup = points_setup()
    else:
        setup = TrackerSetup((-1500, 2000, 100, -math.pi / 2, 0.05, 0.1),
                             probe=(20, -10, 80, 0.3, -0.2, 0.1), probe_length=100)
    truth = truth_vector(robot, setup, 3)
    data, _ = simulate_tracker(robot, setup, 8, seed=3, x=truth, hidden=0.0)
    problem = TrackerProblem(robot, setup, data)
    # Noise-free data: zero residuals at the truth, to rounding.
    assert np.max(np.abs(problem.residuals(truth))) < 1e-9
    # The C++ prediction against NumPy's (true_points) at another x, through the true poses.
    rng = np.random.default_rng(5)
    x = truth + 0.2 * rng.uniform(-1, 1, truth.size) * np.where(problem.angle_parameters, 0.01, 1)
    poses = problem.platform_poses(x)
    np.testing.assert_allclose(problem.predicted_points(x), true_points(robot, setup, x, poses),
                               atol=1e-9)
    r, jac = problem.residuals_and_jacobian(x)
    fd = np.empty_like(jac)
    for i in range(x.size):
        h = 1e-6
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        fd[:, i] = (problem.residuals(xp) - problem.residuals(xm)) / (2 * h)
    assert np.max(np.abs(fd - jac)) < 1e-6 * np.max(np.abs(jac))
    assert problem.cost(x) == pytest.approx(float(r @ r), rel=1e-12)


@pytest.mark.parametrize("which", [0, 2])
def test_predicted_points_match_numpy_where_the_kernel_falls_back(robot, which):
    # Far outside the search box the chord stops contracting in some lanes and the damped Newton
    # solver finishes them (TrackerObjective::finish), whose rotation the kernel's points take as
    # F = R B: the points predicted there, and the platform poses, against NumPy's points through
    # Newton's poses (iwr.forward_kinematics, an independent solver). (A fallback that entered R
    # for F put 83 % of these points off, by up to 128 mm.)
    setup = _setups()[which]
    data, _ = simulate_tracker(robot, setup, 30, seed=12, hidden=0.0)
    problem = TrackerProblem(robot, setup, data)
    rng = np.random.default_rng(4)
    far = problem.lower + (problem.upper - problem.lower) * rng.random(problem.n_params)
    far[: robot.n_params] *= np.where(robot.angle_parameters, 1.0, 80.0)
    assert not problem.failures(far)
    # The premise: most poses here are finished by the fallback, some by the kernel alone.
    status = problem._objective.chord_status(far)
    assert 15 <= np.count_nonzero(status == 1) < 30 and np.all(status != 2)
    assert not problem._objective.chord_status(np.zeros(problem.n_params)).any()
    newton = iwr.forward_kinematics(robot, far[: robot.n_params], data.q, data.legs)
    np.testing.assert_allclose(problem.predicted_points(far),
                               true_points(robot, setup, far, newton), atol=1e-8)
    poses = problem.platform_poses(far)
    assert np.max(np.abs(poses[:, :3] - newton[:, :3])) < 1e-8
    assert np.max(np.abs(poses[:, 3:] - newton[:, 3:])) < 1e-10


def test_hidden_reflectors_have_zero_residuals(robot):
    setup = points_setup()
    data, truth = simulate_tracker(robot, setup, 30, seed=4, hidden=0.5)
    seen = data.seen
    assert 5 < np.count_nonzero(~seen) < 25 and np.all(seen.sum(axis=1) >= 2)
    problem = TrackerProblem(robot, setup, data)
    r = problem.residuals(np.zeros(problem.n_params)).reshape(30, 3, 3)
    assert np.all(r[~seen] == 0) and np.all(np.abs(r[seen]).sum(axis=1) > 0)
    assert problem.n_observations == 3 * int(seen.sum())


def test_cost_batch_is_thread_independent_and_equals_cost(robot):
    setup = points_setup()
    data, truth = simulate_tracker(robot, setup, 40, seed=6)
    problem = TrackerProblem(robot, setup, data)
    rng = np.random.default_rng(1)
    lo, hi = problem.lower, problem.upper
    X = lo + (hi - lo) * rng.random((23, problem.n_params))
    one = problem.cost_batch(X, workers=1)
    assert np.array_equal(one, problem.cost_batch(X, workers=2))
    assert np.array_equal(one, problem.cost_batch(X, workers=5))
    assert np.array_equal(one, [problem.cost(x) for x in X])


def test_failed_forward_kinematics_is_a_finite_penalty_and_named(robot):
    setup = points_setup()
    data, _ = simulate_tracker(robot, setup, 5, seed=7)
    problem = TrackerProblem(robot, setup, data)
    x = np.zeros(problem.n_params)
    x[problem.parameter_names.index("leg1.dl0")] = -2000.0  # no leg can be that short
    assert [k for k, _ in problem.failures(x)] == list(range(5))
    assert problem.cost(x) == pytest.approx(5 * 9 * FAILED_RESIDUAL**2)
    r, jac = problem.residuals_and_jacobian(x)
    assert np.all(np.isfinite(r)) and not jac.any()
    with pytest.raises(iwr.ForwardKinematicsError, match="pose 0") as info:
        problem.check(x)
    assert info.value.pose == 0
    problem.check(np.zeros(problem.n_params))  # nothing fails there
    # Readings no pose can produce, at the reference solve: named at construction.
    legs = data.legs.copy()
    legs[3, 0] -= 500.0
    bad = TrackerMeasurements(data.q, legs, points=data.points, source="run.csv", lines=range(2, 7))
    with pytest.raises(iwr.ForwardKinematicsError, match="run.csv, line 5: the leg") as info:
        TrackerProblem(robot, setup, bad)
    assert info.value.pose == 3


def test_problem_rejects_mismatched_data(robot):
    setup = points_setup()
    data, _ = simulate_tracker(robot, points_setup(2), 3, seed=0)
    with pytest.raises(ValueError, match="2 reflectors per pose, but the tracker setup has 3"):
        TrackerProblem(robot, setup, data)
    with pytest.raises(ValueError, match="pose 1, reflector 2 has some coordinates NaN"):
        pts = np.zeros((2, 3, 3))
        pts[1, 1, 0] = np.nan
        TrackerMeasurements(np.zeros((2, 4)), np.zeros((2, 6)), points=pts)
    with pytest.raises(ValueError, match="x: shape"):
        data3 = simulate_tracker(robot, setup, 3, seed=0)[0]
        TrackerProblem(robot, setup, data3).cost(np.zeros(58))


# -- the registration guess -----------------------------------------------------------------------

def test_kabsch_recovers_a_rotation_and_never_a_reflection():
    rng = np.random.default_rng(0)
    a = rng.normal(size=(10, 3)) * 100
    r = iwr.transforms.rotvec_matrix(np.array([0.3, -1.2, 2.0]))
    rr, t = kabsch(a, a @ r.T + (5, 6, 7))
    np.testing.assert_allclose(rr, r, atol=1e-12)
    np.testing.assert_allclose(t, (5, 6, 7), atol=1e-9)
    mirrored = a * (1, 1, -1)  # the best orthogonal map is a reflection: still a rotation back
    rr, _ = kabsch(a, mirrored)
    assert np.linalg.det(rr) == pytest.approx(1.0)


def test_registration_guess_from_the_nominal_model(robot):
    setup = points_setup()
    truth = truth_vector(robot, setup, 2)
    data, _ = simulate_tracker(robot, setup, 50, seed=2, x=truth)
    g = guess_registration(robot, setup, data)
    t_true = setup.registration_matrix(truth[robot.n_params:])
    # The nominal robot's poses are millimetres off, so is the guess (and part of the difference
    # is the gauge: a shift of the robot's base that the registration absorbs), but it fits the
    # data far better than the nominal registration, 5 mm and 1 degree off at 2 m.
    assert 0.01 < g.rms < 20.0
    np.testing.assert_allclose(setup.registration_matrix(g.x_setup), g.matrix, atol=1e-9)
    problem = TrackerProblem(robot, setup, data)
    at_guess = np.concatenate([np.zeros(robot.n_params), g.x_setup])
    assert problem.cost(at_guess) < 0.05 * problem.cost(np.zeros(problem.n_params))
    assert problem.cost(at_guess) == pytest.approx(g.rms**2 * g.n_points, rel=1e-9)
    # With the true robot and offsets the guess is exact.
    exact = guess_registration(robot, TrackerSetup(REGISTRATION, reflectors=np.array(REFLECTORS)
                                                   + truth[-9:].reshape(3, 3)),
                               data, truth[: robot.n_params])
    assert exact.rms < 1e-9
    np.testing.assert_allclose(exact.matrix, t_true, atol=1e-8)


def test_registration_guess_refuses_a_model_too_poor(robot):
    setup = points_setup()
    data, _ = simulate_tracker(robot, setup, 20, seed=3)
    # Reflectors 2 and 3 swapped in the description: no rigid motion fits.
    swapped = TrackerSetup(REGISTRATION, reflectors=[REFLECTORS[0], REFLECTORS[2], REFLECTORS[1]])
    with pytest.raises(RegistrationError, match=r"RMS of .* mm .* > max_rms = 20 mm"):
        guess_registration(robot, swapped, data)
    assert guess_registration(robot, swapped, data, max_rms=1e3).rms > 20.0
    one = TrackerSetup(REGISTRATION, reflectors=[(0.0, 0.0, 40.0)])
    data1, _ = simulate_tracker(robot, one, 2, seed=3)
    with pytest.raises(RegistrationError, match="2 usable points"):
        guess_registration(robot, one, data1)


# -- noise ----------------------------------------------------------------------------------------

def test_tracker_noise_is_long_across_the_line_of_sight():
    noise = TrackerNoise.leica()
    p = np.tile([0.0, 3000.0, 0.0], (20000, 1))  # 3 m along y
    e = noise.perturb(p, np.random.default_rng(0)) - p
    sr, st = noise.sigmas(3000.0)
    assert sr == pytest.approx(0.005 + 0.00045) and st == pytest.approx(0.0075 + 0.009)
    assert np.std(e[:, 1]) == pytest.approx(sr, rel=0.03)
    assert np.std(e[:, 0]) == pytest.approx(st, rel=0.03)
    assert np.std(e[:, 2]) == pytest.approx(st, rel=0.03)


# -- recovery of the robot from point data --------------------------------------------------------

@pytest.mark.parametrize("hidden", [0.0, 0.2])
def test_lm_from_the_nominal_model_and_the_registration_guess_recovers_the_tool_pose(robot, hidden):
    setup = points_setup()
    truth = truth_vector(robot, setup, 1)
    data, _ = simulate_tracker(robot, setup, 100, seed=1, x=truth, hidden=hidden)
    if hidden:
        assert 10 < np.count_nonzero(~data.seen) < 30
    g = guess_registration(robot, setup, data)
    problem = TrackerProblem(robot, setup, data, center=g.x_setup)
    x0 = problem.x0(g)
    np.testing.assert_array_equal(x0[robot.n_params:], g.x_setup)
    res = levenberg_marquardt(ReducedProblem(problem, np.ones(problem.n_params, dtype=bool), x0),
                              progress=False)
    assert res["success"], res["message"]
    problem.check(res["x"])
    q, _, legs = sample_poses(robot, 50, np.random.default_rng(99), truth[: robot.n_params])
    before = tool_pose_errors(robot, setup, x0, truth, q, legs)
    after = tool_pose_errors(robot, setup, res["x"], truth, q, legs)
    assert before.position.max() > 0.1  # the nominal model is millimetres off
    assert after.position.max() < 1e-6
    assert math.radians(after.orientation.max()) < 1e-9
    # The gauge is real: {5} in {0} by forward kinematics differs by what the data cannot see.
    joints = tool_pose_errors(robot, setup, res["x"], truth, q, legs, gauge="joints")
    assert joints.position.max() < 1e-6 and math.radians(joints.orientation.max()) < 1e-9
    raw = tool_pose_errors(robot, setup, res["x"], truth, q, legs, gauge=None)
    assert raw.position.max() > 1e-3


def test_every_method_runs_on_the_tracker_problem(robot):
    setup = points_setup(2)
    data, truth = simulate_tracker(robot, setup, 20, seed=8)
    problem = TrackerProblem(robot, setup, data)
    active = np.ones(problem.n_params, dtype=bool)
    x0 = np.zeros(problem.n_params)
    c0 = problem.cost(x0)
    for method in ("crs2", "bobyqa"):
        res = METHODS[method](ReducedProblem(problem, active, x0), seed=1, callback=None,
                              progress=False, max_evaluations=300)
        assert res["fun"] < c0 and res["nfev"] <= 300
    reduced = ReducedProblem(problem, active, x0)
    box = np.column_stack([reduced.lower, reduced.upper])
    de = iwr.differential_evolution(reduced.cost_batch, box, population_size=20, generations=5,
                                    seed=1, workers=2)
    assert np.isfinite(de["fun"]) and de["fun"] == pytest.approx(reduced.cost(de["x"]))


# -- identifiability ------------------------------------------------------------------------------

def test_null_directions_of_point_data(robot):
    setup = points_setup()
    data, truth = simulate_tracker(robot, setup, 60, seed=5)
    ns = null_space(TrackerProblem(robot, setup, data))  # at x = 0: an exact correction
    legs_only = iwr.identifiability(robot, iwr.simulate(robot, 60, seed=5)[0])
    # The leg data's 6, the registration's 4 (every translation: joint 1 and 2 slide, and
    # joint 1's a; a turn about joint 1's axis),
    # and the platform frame's 6 (a rigid motion of {5} with the joints b_j and the reflectors).
    assert len(legs_only.null_directions) == 6
    assert ns.rank == ns.vectors.shape[0] - 16
    assert ns.singular_values[ns.rank - 1] > 1e6 * ns.singular_values[ns.rank]
    names = ns.parameter_names
    v = np.zeros(len(names))
    v[names.index("tracker.rz")], v[names.index("joint1.dtheta")] = 1.0, -1.0
    w = np.zeros(len(names))
    w[names.index("tracker.z")], w[names.index("joint1.dd")] = 1.0, -1.0
    for u in (v, w):  # in the null space: its projection on the basis reproduces it
        coef, *_ = np.linalg.lstsq(ns.vectors, u, rcond=None)
        np.testing.assert_allclose(ns.vectors @ coef, u, atol=1e-6)


def test_a_pose_gives_the_same_bits_whatever_its_neighbours_in_a_block(robot):
    # The chord iterations run 8 poses at a time; a converged lane takes zero steps, so a pose's
    # residuals must not depend on which poses share its block.
    setup = points_setup()
    data, truth = simulate_tracker(robot, setup, 21, seed=9)
    order = np.random.default_rng(0).permutation(21)
    shuffled = TrackerMeasurements(data.q[order], data.legs[order], points=data.points[order])
    x = truth + np.concatenate([0.3 * np.ones(robot.n_params), np.zeros(setup.n_params)]) * \
        np.where(np.concatenate([robot.angle_parameters, setup.angle_parameters]), 0.01, 1.0)
    a = TrackerProblem(robot, setup, data).residuals(x).reshape(21, -1)
    b = TrackerProblem(robot, setup, shuffled).residuals(x).reshape(21, -1)
    assert np.array_equal(a[order], b)


def test_a_pose_alone_gives_the_same_bits_as_beside_poses_that_fall_back_or_fail(robot):
    # Each pose solved alone (N = 1: its block is its own copies) against the same pose in blocks
    # of 8 whose other lanes converge later, take the damped Newton fallback or fail, at vectors
    # across and far beyond the search box: the per-lane masks must leave a lane's bits alone.
    setup = points_setup()
    data, _ = simulate_tracker(robot, setup, 13, seed=21, hidden=0.3)
    full = TrackerProblem(robot, setup, data)
    half = (full.upper - full.lower) / 2
    rng = np.random.default_rng(5)
    xs = []
    for scale in (1.0, 200.0):
        x = (2 * rng.random(full.n_params) - 1) * half
        x[: robot.n_params] *= scale
        xs.append(x)
    x = np.zeros(full.n_params)
    x[full.parameter_names.index("leg2.dl0")] = 300.0  # some poses cannot close
    xs.append(x)
    assert 0 < len(full.failures(x)) < 13
    alone = [TrackerProblem(robot, setup, TrackerMeasurements(
        data.q[k:k + 1], data.legs[k:k + 1], points=data.points[k:k + 1])) for k in range(13)]
    for x in xs:
        rows = full.residuals(x).reshape(13, -1)
        for k in range(13):
            assert np.array_equal(alone[k].residuals(x), rows[k]), k

def test_lm_recovers_the_tool_pose_from_noise_free_probe_poses(robot):
    setup = TrackerSetup(REGISTRATION, probe=(10.0, -20.0, 60.0, 0.2, -0.1, 0.3))
    truth = truth_vector(robot, setup, 4)
    data, _ = simulate_tracker(robot, setup, 60, seed=4, x=truth)
    g = guess_registration(robot, setup, data)
    problem = TrackerProblem(robot, setup, data, center=g.x_setup)
    x0 = np.concatenate([np.zeros(robot.n_params), g.x_setup])
    res = levenberg_marquardt(ReducedProblem(problem, np.ones(problem.n_params, dtype=bool), x0),
                              progress=False)
    assert res["success"], res["message"]
    q, _, legs = sample_poses(robot, 50, np.random.default_rng(98), truth[: robot.n_params])
    after = tool_pose_errors(robot, setup, res["x"], truth, q, legs)
    assert after.position.max() < 1e-6
    assert math.radians(after.orientation.max()) < 1e-9


# -- the SIMD kernel -------------------------------------------------------------------------------

@pytest.fixture
def restore_kernel():
    from iwr import _core

    before = _core._active_kernel()
    yield _core
    _core._select_kernel(before)


def _setups():
    probe = TrackerSetup((-1500, 2000, 100, -math.pi / 2, 0.05, 0.1),
                         probe=(20, -10, 80, 0.3, -0.2, 0.1), probe_length=100)
    return [points_setup(), points_setup(1), probe]


@pytest.mark.parametrize("which", [0, 1, 2])
def test_the_fma_variants_give_the_same_tracker_bits_and_the_baseline_the_same_to_rounding(
    robot, which, restore_kernel
):
    # The point objective's kernel is compiled for the baseline, AVX2 and AVX-512 with explicit
    # fused multiply-adds: AVX2 and AVX-512 give the same bits; the baseline (no FMA) rounds each
    # twice, which moved the costs by at most 8.0e-15 relative, the residuals and the platform
    # poses by at most 1.8e-12 (mm, rad) here. 21 poses: a padded last block; a fifth of the
    # reflectors hidden; vectors across the search box, one far outside it (the damped Newton
    # fallback) and one where every pose fails.
    _core = restore_kernel
    setup = _setups()[which]
    data, truth = simulate_tracker(robot, setup, 21, seed=11,
                                   hidden=0.2 if setup.kind == "points" else 0.0)
    problem = TrackerProblem(robot, setup, data)
    rng = np.random.default_rng(3)
    X = problem.lower + (problem.upper - problem.lower) * rng.random((12, problem.n_params))
    far = truth.copy()
    far[: robot.n_params] += np.where(robot.angle_parameters, 0.05, 40.0)
    dead = np.zeros(problem.n_params)
    dead[problem.parameter_names.index("leg1.dl0")] = -2000.0
    X = np.vstack([X, far, dead])
    results = {}
    for v in _core._supported_kernels():
        _core._select_kernel(v)
        results[v] = (problem.cost_batch(X, workers=1), problem.cost_batch(X, workers=2),
                      problem.residuals(X[0]), problem.residuals(far),
                      problem.platform_poses(X[1]))
    base = results["baseline"]
    fused = [v for v in results if v != "baseline"]
    for v in fused[1:]:
        for a, b in zip(results[v], results[fused[0]], strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"variant {v}")
    for v in fused:
        got = results[v]
        for a, b in zip(got[:2], base[:2], strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-13, atol=0, err_msg=f"variant {v}")
        for a, b in zip(got[2:], base[2:], strict=True):
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-10, err_msg=f"variant {v}")
    for got in results.values():
        assert np.array_equal(got[0], got[1])
    # every pose failed: the penalty on every seen coordinate, none on the hidden ones
    r = problem.residuals(dead)
    assert set(np.unique(r)) <= {0.0, FAILED_RESIDUAL}
    assert np.count_nonzero(r) == (3 * int(data.seen.sum()) if setup.kind == "points" else 12 * 21)
    assert base[0][-1] == pytest.approx(np.count_nonzero(r) * FAILED_RESIDUAL**2)


def test_a_pose_turned_past_the_series_gives_the_same_bits_alone(robot, restore_kernel):
    # The chord's Cayley factor 2 / (1 + |h|^2) is a series where a lane's step turns the platform
    # by less than 0.02 rad (|h|^2 < 1e-4) and a division elsewhere, lane by lane; pairs of blocks
    # (AVX-512) turn the joints in the residuals' pass. A block of 8 whose first steps turn some
    # poses by more than 0.02 rad and others by less (hexapod errors only: the first step turns
    # each pose by about its angle from the reference solve) must give each pose the bits it has
    # alone (a block of its own copies), and the damped Newton solver's pose.
    _core = restore_kernel
    setup = points_setup()
    data, _ = simulate_tracker(robot, setup, 16, seed=31)
    full = TrackerProblem(robot, setup, data)
    names = full.parameter_names
    home = full.platform_poses(np.zeros(full.n_params))
    pattern = np.array([1.0, -0.8, 0.6, -0.4, 0.9, -0.2])
    found = None
    for scale in np.linspace(1.5, 3.5, 81):
        x = np.zeros(full.n_params)
        for j in range(6):
            x[names.index(f"leg{j + 1}.dl0")] = scale * pattern[j]
        ra, rb = pose_matrix(home)[:8, :3, :3], pose_matrix(full.platform_poses(x))[:8, :3, :3]
        turn = rotation_angle(np.swapaxes(ra, -1, -2) @ rb)
        # 2 % clear of the bound on either side (the first step's turn is within a few 1e-3 of
        # the solution's)
        if (turn > 0.0204).any() and (turn < 0.0196).any() and \
                not ((turn > 0.0196) & (turn < 0.0204)).any():
            found = x
            break
    assert found is not None, "no block with poses on both sides of the series' bound"
    alone = [TrackerProblem(robot, setup, TrackerMeasurements(
        data.q[k:k + 1], data.legs[k:k + 1], points=data.points[k:k + 1])) for k in range(16)]
    newton = iwr.forward_kinematics(robot, found[: robot.n_params], data.q, data.legs)
    for v in _core._supported_kernels():
        _core._select_kernel(v)
        rows = full.residuals(found).reshape(16, -1)
        for k in range(16):
            assert np.array_equal(alone[k].residuals(found), rows[k]), (v, k)
        kernel = full.platform_poses(found)
        assert np.max(np.abs(kernel[:, :3] - newton[:, :3])) < 1e-8, v
        assert np.max(np.abs(kernel[:, 3:] - newton[:, 3:])) < 1e-10, v


def test_kernel_forward_kinematics_agrees_with_the_damped_newton_solver(robot):
    # The kernel's chord-and-refinement solve against iwr.forward_kinematics (forward.cpp's damped
    # Newton-Raphson, an independent implementation), across DE's search box and 40 mm beyond it.
    setup = points_setup()
    data, _ = simulate_tracker(robot, setup, 30, seed=12)
    problem = TrackerProblem(robot, setup, data)
    rng = np.random.default_rng(4)
    for scale in (1.0, 1.0, 1.0, 80.0):
        x = problem.lower + (problem.upper - problem.lower) * rng.random(problem.n_params)
        x[: robot.n_params] *= np.where(robot.angle_parameters, 1.0, scale)
        kernel = problem.platform_poses(x)
        newton = iwr.forward_kinematics(robot, x[: robot.n_params], data.q, data.legs)
        assert np.max(np.abs(kernel[:, :3] - newton[:, :3])) < 1e-8
        assert np.max(np.abs(kernel[:, 3:] - newton[:, 3:])) < 1e-10


def test_the_cost_is_never_nan_where_a_prediction_overflows(robot, restore_kernel):
    # A finite but absurd x whose carriage position overflows to inf: a failed pose still costs
    # the finite penalty on its seen coordinates and a hidden point nothing, as residuals() says
    # (the kernel once multiplied the prediction by 0 there: inf * 0 = NaN), in every variant.
    _core = restore_kernel
    setup = points_setup()
    data, _ = simulate_tracker(robot, setup, 11, seed=5, hidden=0.5)
    assert not data.seen.all()
    problem = TrackerProblem(robot, setup, data)
    names = problem.parameter_names
    x = np.zeros(problem.n_params)
    for name in ("joint2.dd", "joint3.da", "joint3.dd", "joint4.da"):
        x[names.index(name)] = 1e308
    dead = x.copy()
    dead[names.index("leg1.dl0")] = -2000.0  # no pose closes: the penalty alone
    for v in _core._supported_kernels():
        _core._select_kernel(v)
        r = problem.residuals(x)
        assert np.isinf(r).any() and not np.isnan(r).any()
        assert problem.cost(x) == np.inf, v  # every pose solved: inf residuals, inf cost
        r = problem.residuals(dead)
        assert len(problem.failures(dead)) == 11 and np.isfinite(r).all()
        assert problem.cost(dead) == pytest.approx(r @ r, rel=1e-15), v
        assert problem.cost_batch(dead[None], workers=1)[0] == problem.cost(dead)
