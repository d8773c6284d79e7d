"""The efficient (implicit-loop) estimator on double-ballbar data (iwr.ballbar.estimation,
docs/ballbar.md "The efficient estimator"): its loop model's exact derivatives, noise-free
recovery of what ballbars determine, its predicted accuracy modulo the gauge against the
nonlinear alignment, a Monte Carlo of actual against predicted accuracy, its outlier and
chi-square tests, and its errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _ballbar import NOISE, READINGS, ballbar_robot

import iwr
from iwr import kinds
from iwr.ballbar import BallbarMeasurements, BallbarNoise, ballbar_problem
from iwr.ballbar.estimation import ballbar_loop_model, ballbar_predicted_accuracy
from iwr.estimation import summary
from iwr.result import pose_key
from iwr.transforms import pose_from_matrix


@pytest.fixture(scope="module")
def sim() -> tuple[iwr.Robot, BallbarMeasurements, np.ndarray]:
    robot = ballbar_robot()
    data, truth = iwr.simulate(robot, 160, seed=3)
    return robot, data, truth


def _noisy(robot: iwr.Robot, clean: BallbarMeasurements, seed: int) -> BallbarMeasurements:
    """The same poses with fresh leg, joint and bar noise."""
    rng = np.random.default_rng(seed)
    sigma_q = np.where([c == "P" for c in robot.joint_types], READINGS.joint_lengths,
                       READINGS.joint_angles)
    return BallbarMeasurements(
        clean.q + sigma_q * rng.standard_normal(clean.q.shape),
        clean.legs + READINGS.legs * rng.standard_normal(clean.legs.shape), clean.setup,
        clean.distance + NOISE[1].distance * rng.standard_normal(len(clean)),
        joint_types=clean.joint_types)


def test_loop_model_derivatives_are_exact(sim):
    """The normalised residuals' derivatives in the parameters (robot and set-ups) and in the
    nuisance corrections (joints, platform position, platform rotation vector far from zero)
    against central differences."""
    robot, data, truth = sim
    sub = data.subset(np.arange(10))
    problem, _ = ballbar_problem(robot, sub)
    nj = robot.n_joints
    reference = pose_from_matrix(problem.platform_frames(np.zeros(problem.n_params)))
    sigma = np.empty((10, 7 + nj))
    sigma[:, :6], sigma[:, 6:6 + nj], sigma[:, -1] = 0.002, [0.005, 0.005, 5e-6, 5e-6], 0.001
    model = ballbar_loop_model(robot, problem, reference, sigma)
    rng = np.random.default_rng(0)
    x = truth + 1e-3 * rng.standard_normal(truth.size)
    corr = np.hstack([1e-3 * rng.standard_normal((10, nj)), 0.5 * rng.standard_normal((10, 3)),
                      0.05 * rng.standard_normal((10, 3))])
    r, rx, ry = model(x, corr, True)
    assert r.shape == (10, 7 + nj) and rx.shape == (10, 7 + nj, x.size)
    h = 1e-6
    for jac, arg, size in ((rx, "x", x.size), (ry, "corr", nj + 6)):
        fd = np.zeros_like(jac)
        for i in range(size):
            if arg == "x":
                e = np.zeros_like(x)
                e[i] = h
                plus, minus = model(x + e, corr, False)[0], model(x - e, corr, False)[0]
                fd[:, :, i] = (plus - minus) / (2 * h)
            else:
                e = np.zeros_like(corr)
                e[:, i] = h
                plus, minus = model(x, corr + e, False)[0], model(x, corr - e, False)[0]
                fd[:, :, i] = (plus - minus) / (2 * h)
        # the residuals are ~1e5 over their sigma: central differences carry ~1e-4 of round-off
        assert np.abs(fd - jac).max() < 1e-8 * np.abs(jac).max(), arg
    # the bar row sees the set-up's balls and offset, the leg rows the robot only
    bar_cols = robot.n_params + 7 * problem.bar
    assert np.allclose(rx[np.arange(10), 6 + nj, bar_cols + 6], 1.0 / 0.001)
    assert not np.any(rx[:, :6, robot.n_params:])


def test_noise_free_recovery_to_a_micrometre_of_a_micrometre(sim):
    """Noise-free data, robot errors within the default bounds, unknown balls and offsets: the
    estimator (with a noise model) recovers readings and gauge-aligned tool poses on fresh poses
    to 1e-6 mm, and its fit passes."""
    robot, data, truth = sim
    res = iwr.identify(robot, data, "efficient", noise=NOISE)
    assert res.method == "efficient" and res.success, res.message
    assert res.fit.dof == len(data) - int(res.active.sum())
    fresh, _ = iwr.simulate(robot, 40, seed=11, x=truth)
    readings = iwr.accuracy(robot, fresh, res.x)
    assert readings.calibrated.position.max() < 1e-6 < readings.nominal.position.max()
    tool = iwr.accuracy(robot, fresh, res.x, truth=truth, tool=(50.0, 0.0, 100.0))
    assert tool.calibrated.position.max() < 1e-6 < tool.nominal.position.max()
    assert tool.calibrated.orientation.max() < 1e-7


def test_predicted_accuracy_is_the_gauge_aligned_error_to_first_order(sim):
    """With the covariance ``d d^T`` of one small parameter error ``d``, each pose's predicted
    tool error is ``|E_k d|``: the linearised error after the alignment of {0} and {5}; it
    agrees with iwr.accuracy's nonlinear alignment (iwr.ballbar.gauge_aligned) of the model
    ``x + d`` against ``x`` to 1e-3 of the error (its second order)."""
    robot, data, truth = sim
    fresh, _ = iwr.simulate(robot, 30, seed=12, x=truth)
    mask = iwr.identifiability(robot, data).active
    rng = np.random.default_rng(5)
    d = np.zeros(truth.size)
    d[mask] = 2e-4 * rng.standard_normal(int(mask.sum()))
    tool = np.array([50.0, 0.0, 100.0])
    pred = ballbar_predicted_accuracy(robot, fresh, truth, np.outer(d[mask], d[mask]), mask,
                                      tool=tool)
    acc = iwr.accuracy(robot, fresh, truth + d, truth=truth, tool=tool).calibrated
    linear_pos = np.sqrt(np.trace(pred.position_cov, axis1=1, axis2=2))
    linear_ori = np.degrees(np.sqrt(np.trace(pred.orientation_cov, axis1=1, axis2=2)))
    assert np.allclose(linear_pos, acc.position, rtol=1e-3, atol=1e-9 + 1e-3 * acc.position.max())
    assert np.allclose(linear_ori, acc.orientation, rtol=1e-3,
                       atol=1e-3 * acc.orientation.max())
    # the poses themselves (no alignment) differ by more: the alignment took a part away
    problem, _ = ballbar_problem(robot, fresh)
    raw = np.linalg.norm(problem.platform_frames(truth + d)[:, :3, 3]
                         - problem.platform_frames(truth)[:, :3, 3], axis=1)
    assert np.sqrt(np.mean(raw**2)) > 1.5 * np.sqrt(np.mean(acc.position**2))


def test_a_gross_error_is_found_and_a_wrong_noise_model_fails(sim):
    """A bar reading 50 um off (50 sigma) is removed as an outlier, by pose (one redundant
    reading per pose: every reading of the pose is confounded with the one named); a noise
    model ten times too small fails the chi-square test."""
    robot, clean, _ = sim
    data = _noisy(robot, clean, 7)
    d = data.distance.copy()
    d[17] += 0.05
    bad = BallbarMeasurements(data.q, data.legs, data.setup, d, joint_types=data.joint_types)
    res = iwr.identify(robot, bad, "efficient", noise=NOISE)
    assert [o.pose for o in res.outliers if o.removed] == [17] and res.success, res.outliers
    named = {res.outliers[0].instrument, *res.outliers[0].confounded}
    assert named == set(res.reading_names) and "distance" in named
    assert not res.used[17] and np.isnan(res.residuals[17]).all()
    tiny = (iwr.Noise(legs=2e-4, joint_lengths=5e-4, joint_angles=5e-7), BallbarNoise(1e-4))
    wrong = iwr.identify(robot, data, "efficient", noise=tiny, outliers="off")
    assert not wrong.success and wrong.status == "failed" and "chi" in wrong.message


def test_the_bar_noise_is_estimated_from_the_data(sim):
    """``estimate=("ballbar",)``: the bar's sigma from the data, the others known; the same
    estimate from a start 3x too large or too small (Foerstner's iteration has one fixed point),
    near the truth (3 um) within its wide scatter: a pose's one redundancy is shared with its
    leg and joint readings."""
    robot, _, truth = sim
    data, _ = iwr.simulate(robot, 300, seed=4, x=truth, noise=(READINGS, BallbarNoise(0.003)))
    sigmas = []
    for start in (0.009, 0.001):
        res = iwr.identify(robot, data, "efficient", noise=(READINGS, BallbarNoise(start)),
                           estimate=("ballbar",))
        (c,) = res.variance_components
        assert c.name == "ballbar_distance" and c.identified and res.success
        assert res.noise[1].distance == pytest.approx(c.sigma)
        sigmas.append(c.sigma)
    assert sigmas[0] == pytest.approx(sigmas[1], rel=1e-3)
    assert 0.0015 < sigmas[0] < 0.006


def test_the_estimator_is_the_default_with_a_noise_model_and_checks_it(sim):
    robot, data, _ = sim
    res = iwr.identify(robot, data, noise=NOISE)
    assert res.method == "efficient" and res.reading_names[-1] == "distance"
    # the noise model's prediction (the residuals here are zero: noise-free data)
    assert res.predicted is not None and 1e-4 < res.predicted.position_rms < 0.05
    assert summary(res)["noise"]["ballbar"] == {"distance": 0.001}
    with pytest.raises(ValueError, match="BallbarNoise"):
        iwr.identify(robot, data, "efficient", noise=READINGS)
    with pytest.raises(ValueError, match="weighs every reading"):
        iwr.identify(robot, data, "efficient")
    with pytest.raises(ValueError, match="BallbarNoise.distance: 0"):
        iwr.identify(robot, data, "efficient", noise=(READINGS, BallbarNoise(0.0)))
    with pytest.raises(ValueError, match="noise.legs: 0"):
        iwr.identify(robot, data, "efficient", noise=(iwr.Noise(joint_lengths=0.005),
                                                      BallbarNoise()))
    with pytest.raises(ValueError, match="estimate: unknown component"):
        iwr.identify(robot, data, "efficient", noise=NOISE, estimate=("tracker_distance",))
    with pytest.raises(ValueError, match="weighted=False"):
        iwr.identify(robot, data, "efficient", noise=NOISE, weighted=False)


@pytest.mark.slow
def test_twenty_seed_monte_carlo_within_ten_percent():
    """benchmarks/ballbar_efficient_mc.py, 20 seeds (docs/ballbar.md): actual / predicted tool
    position and bar reading error within 10 % (issue 21)."""
    import importlib.util
    import sys

    here = Path(__file__).resolve().parents[1] / "benchmarks"
    sys.path.insert(0, str(here))
    try:
        spec = importlib.util.spec_from_file_location("ballbar_efficient_mc",
                                                      here / "ballbar_efficient_mc.py")
        assert spec is not None and spec.loader is not None
        mc = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mc)
        out = mc.run(200, 20, "AB")
    finally:
        sys.path.remove(str(here))
    r = out["rows"]
    for a, p in ((0, 1), (4, 5)):
        ratio = np.sqrt(np.mean(r[:, a] ** 2) / np.mean(r[:, p] ** 2))
        assert 0.9 < ratio < 1.1, (a, ratio)
    assert out["success"] == 20
    # The parameters' scatter against their covariance (Mahalanobis distance per base
    # parameter, 1 expected) and the fit test's p-values (uniform: none tiny).
    assert 0.8 < out["maha"].mean() < 1.25, out["maha"]
    assert out["chi2_p"].min() > 1e-3, out["chi2_p"]


def test_iwr_calibrate_with_the_efficient_estimator_on_ballbar_data(sim, tmp_path):
    """`iwr calibrate --method efficient --noise realistic` on ballbar data: the job (the held-out
    poses' gross-error test under the noise model, the ballbar's report with the predicted
    accuracy modulo the gauge); a bar reading 0.2 mm off is found and left out."""
    import json
    import subprocess
    import sys

    robot, clean, truth = sim
    data = _noisy(robot, clean, 9)
    d = data.distance.copy()
    d[40] += 0.2
    BallbarMeasurements(data.q, data.legs, data.setup, d,
                        joint_types=data.joint_types).to_csv(tmp_path / "bar.csv")
    robot.to_toml(tmp_path / "bb.toml")
    cal = subprocess.run([sys.executable, "-m", "iwr", "calibrate", "bb.toml", "bar.csv",
                          "--method", "efficient", "--noise", "realistic", "--out", "c",
                          "--no-plots", "--no-progress"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=900)
    assert cal.returncode == 0, cal.stdout + cal.stderr
    assert "ballbar distance 0.001" in cal.stdout and "tracker" not in cal.stdout
    assert "modulo what a ballbar cannot see" in cal.stdout
    summary = json.loads((tmp_path / "c" / "summary.json").read_text())
    assert summary["method"] == "efficient" and summary["predicted_accuracy"], summary
    result = json.loads((tmp_path / "c" / "result.json").read_text())
    line = kinds.for_robot(robot).read(tmp_path / "bar.csv", robot).lines[40]
    assert [o["line"] for o in result["outliers"] if o["removed"]] == [line], result["outliers"]
    assert (tmp_path / "c" / "report.html").is_file()


def test_compare_runs_the_efficient_estimator_on_a_ballbar_robot():
    """iwr compare (the library's compare_methods) on a ballbar robot: LM and the efficient
    estimator, their validation on the bar readings, the tool pose modulo the gauge and the
    parameter error modulo the null directions, all finite and at the noise's scale."""
    from iwr.experiments.compare import compare_methods

    robot = ballbar_robot()
    out = compare_methods(robot, 120, "realistic", seeds=[0], methods=["lm", "efficient"],
                          start="near", budget=2000, out=None, n_validation=60, progress=False)
    assert {r["method"] for r in out.runs} == {"lm", "efficient"}
    for r in out.runs:
        assert r["success"] and not r.get("notes"), r.get("notes")
        assert 1e-4 < r["val_rms"] < 0.05 and 1e-4 < r["tool_position_rms"] < 0.05
        assert 1e-3 < r["param_error_length"] < 1.0
    assert out.settings["noise"] and "bar" in out.settings["kind"]["readings"]


def test_the_job_screens_ballbar_data_under_a_noise_model(sim):
    """iwr.calibrate with the weighted LM and a noise model: the gross-error screen tests each
    pose's bar residual under the noise propagated from every reading (it stopped: "the
    gross-error test of ballbar data has no noise model"), and leaves the bad pose out."""
    robot, clean, _ = sim
    data = _noisy(robot, clean, 11)
    d = data.distance.copy()
    d[5] -= 0.2
    bad = BallbarMeasurements(data.q, data.legs, data.setup, d, joint_types=data.joint_types)
    job = iwr.calibrate(robot, bad, "lm", noise=NOISE, validation_fraction=0.2, seed=1)
    removed = [o.key for o in job.result.outliers if o.removed]
    assert removed == [pose_key(bad, 5)], job.result.outliers
    assert job.result.fit.fit_ok, job.result.fit.verdict
    m = kinds.of(bad).misclosures(robot, bad, job.result.x, NOISE)
    assert m.r.shape == (len(bad), 1) and m.reading_cov is not None
    # the bar residual's variance: the bar's, plus the legs' and joints' propagated
    var = np.array([m.covariance(k, np.array([True]))[0, 0] for k in range(len(bad))])
    assert np.all(var > NOISE[1].distance ** 2)
