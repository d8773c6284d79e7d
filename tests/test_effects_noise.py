"""Issue 23 with a noise model: the noise-weighted objective with effects in every method
(iwr.Problem(noise=), DE, BOBYQA), the calibration job and its command line with a noise model
and effects (the gross-error screen's chi-square test, the fit test, the uncertainty, the
predicted accuracy, the report), iwr.parameter_error and iwr.predict_legs with effects, the
effects' range check inside every method's fit check, and `iwr report` of an `iwr-calibrate`
run weighted by a noise model (docs/effects.md)."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr.effects import api
from iwr.effects.problem import EffectProblem
from iwr.measurements import Measurements

NOISE = iwr.Noise.realistic()


def _run(*args, timeout=900):
    env = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    return subprocess.run([*map(str, args)], capture_output=True, text=True,
                          cwd=tempfile.gettempdir(), env=env, timeout=timeout)


def _iwr(*args):
    return _run(sys.executable, "-m", "iwr", *args)


def _launcher() -> str:
    exe = Path(sys.executable).parent / "iwr-calibrate"
    if not exe.is_file():
        pytest.fail("iwr-calibrate is not installed next to python: `pip install .`")
    return str(exe)


@pytest.fixture(scope="module")
def noisy(with_effects):
    """60 poses of the realistic effects with every instrument's realistic noise."""
    return api.simulate(with_effects, 60, seed=3, noise=NOISE)


def test_problem_with_a_noise_model_is_the_weighted_objective_with_effects(with_effects, noisy,
                                                                          tmp_path):
    """iwr.Problem(noise=) with effects: the C++ objective with effects whitened by
    gls_whitening equals the numpy model's (EffectProblem(noise=)) in cost, residuals and
    cost_batch; its Jacobian matches central differences of the C++ residuals; the problem
    file keeps the weighting."""
    m, x = noisy
    p = iwr.Problem(with_effects, m, noise=NOISE)
    e = EffectProblem(with_effects, m, noise=NOISE)
    rng = np.random.default_rng(1)
    xs = x + 1e-3 * rng.standard_normal((3, x.size)) * np.maximum(np.abs(x), 1e-3)
    for xi in xs:
        assert p.cost(xi) == pytest.approx(e.cost(xi), rel=1e-9)
        np.testing.assert_allclose(p.residuals(xi), e.residuals(xi), rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(p.cost_batch(xs), e.cost_batch(xs), rtol=1e-9)
    # Weighted against unweighted: a different objective (the whitening is used).
    assert abs(p.cost(x) - iwr.Problem(with_effects, m).cost(x)) > 0.5 * p.cost(x)
    jac = p.jacobian(x)
    for i in list(range(0, with_effects.n_params, 7)) + list(range(with_effects.n_params,
                                                                   x.size)):
        h = 1e-6 * max(1.0, abs(x[i]))
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        fd = (p.residuals(xp) - p.residuals(xm)) / (2 * h)
        np.testing.assert_allclose(jac[:, i], fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())
    path = tmp_path / "weighted.iwrp"
    e.save(path)
    back = iwr.Problem.load(path)
    assert back.robot.effects == with_effects.effects
    assert back.cost(x) == pytest.approx(p.cost(x), rel=1e-12)


def test_global_methods_minimise_the_weighted_objective_with_effects(with_effects, noisy):
    """DE (polished by LM) with a noise model on a robot with effects minimises the
    noise-weighted objective with effects: its fun is that objective's value at x, and its
    minimum the one weighted LM reaches (the same objective, another method); the fit gets its
    chi-square test. CRS2 and BOBYQA run on the same weighted objective."""
    m, _ = noisy
    report = iwr.identifiability(with_effects, m)
    weighted = iwr.Problem(with_effects, m, noise=NOISE)
    lm = iwr.identify(with_effects, m, "lm", noise=NOISE, active=report.active)
    assert lm.success, lm.message
    result = iwr.identify(with_effects, m, "de", noise=NOISE, active=report.active,
                          max_evaluations=6000, seed=1)
    assert result.settings["objective"]["weighted"] is True
    assert result.fun == pytest.approx(weighted.cost(result.x), rel=1e-12)
    assert result.fun == pytest.approx(lm.fun, rel=1e-6)
    assert result.cost_eq10 == pytest.approx(iwr.Problem(with_effects, m).cost(result.x),
                                             rel=1e-12)
    assert result.fit.dof == 6 * len(m) - report.rank
    # The fit test's statistic: whitened at x (fun: at the nominal robot), minimised to first
    # order: the same size.
    assert result.fit.statistic == pytest.approx(result.fun, rel=0.05)
    assert result.fit.p_value > 1e-3 and result.success, result.message
    for method in ("crs2", "bobyqa"):
        short = iwr.identify(with_effects, m, method, noise=NOISE, active=report.active,
                             max_evaluations=300, seed=1)
        assert short.settings["objective"]["weighted"] is True
        assert short.fun == pytest.approx(weighted.cost(short.x), rel=1e-12)
        assert short.fit.dof == 6 * len(m) - report.rank


def test_predict_legs_with_effects(with_effects):
    """iwr.predict_legs(..., data=) of a robot with effects: the readings under each pose's
    load and temperature (the simulation's, noise-free); refused without the loads, and a
    robot without effects takes none."""
    m, x = api.simulate(with_effects, 12, seed=4)
    np.testing.assert_allclose(iwr.predict_legs(with_effects, x, m.q, m.poses, data=m), m.legs,
                               atol=1e-9)
    plain = iwr.predict_legs(with_effects.with_effects(), x[: with_effects.n_params], m.q,
                             m.poses)
    assert np.abs(plain - m.legs).max() > 1e-3  # the effects are in the readings
    with pytest.raises(ValueError, match="data: robot 'IWR' has effects on"):
        iwr.predict_legs(with_effects, x, m.q, m.poses)
    with pytest.raises(ValueError, match="data: 12 poses, but poses has 3 rows"):
        iwr.predict_legs(with_effects, x, m.q[:3], m.poses[:3], data=m)
    with pytest.raises(ValueError, match="has no effect on"):
        iwr.predict_legs(with_effects.with_effects(), None, m.q, m.poses, data=m)


def test_parameter_error_with_effects(with_effects):
    """iwr.parameter_error with effects: modulo what the data cannot see (the geometric null
    directions), an identification from noise-free data has no error even though its raw
    vector differs from the truth's; an error in a compliance is seen as it is, by name, by
    the nonlinear and the linear projection alike."""
    m, x = api.simulate(with_effects, 40, seed=6)
    fit = iwr.identify(with_effects, m, "lm", active="base")
    assert fit.success, fit.message
    perr = iwr.parameter_error(with_effects, m, fit.x, x)
    assert np.abs(perr.raw).max() > 1e-3  # the unidentifiable ones are held at zero
    assert perr.rms_length < 1e-8 and perr.rms_angle < 1e-10
    assert np.abs(perr.projected[with_effects.n_params:]).max() < 1e-9
    assert perr.parameter_names[-1] == "legs.alpha" and perr.converged
    off = x.copy()
    k = perr.parameter_names.index("leg3.compliance")
    off[k] += 2e-3
    for method in ("nonlinear", "linear"):
        e = iwr.parameter_error(with_effects, m, off, x, method=method)
        assert e.named()["leg3.compliance"] == pytest.approx(2e-3, rel=1e-6)
        assert e.rms_length < 1e-9
    with pytest.raises(ValueError, match="truth: shape"):
        iwr.parameter_error(with_effects, m, x, x[: with_effects.n_params])


@pytest.fixture(scope="module")
def negative(with_effects):
    """Data of a machine whose legs are 'compliant' by -0.02 um/N (no machine: outside the
    plausible 0 .. 0.05 of the file), 1 um leg noise."""
    n_eff = 7
    x = np.zeros(with_effects.n_params + n_eff)
    x[with_effects.n_params: with_effects.n_params + 6] = -0.03  # 0.01 in the file
    return api.simulate(with_effects, 60, seed=8, x=x, noise=iwr.Noise(legs=0.001))


def _range_cause(fit):
    causes = [c for c in fit.causes if "outside their plausible range" in c]
    assert len(causes) == 1, fit.causes
    return causes[0]


def test_an_effect_outside_its_range_fails_every_method_and_the_job(with_effects, negative):
    """The range check is the fit check's own: LM (unbounded), weighted LM, the efficient
    estimator and the calibration job each fail a compliance of -0.02 um/N by name, in one
    wording; the geometric size test does not judge the effects with a limit of its own."""
    m, _ = negative
    want = re.compile(r"leg1\.compliance = -0\.0(19|2)\d* um/N, outside its plausible range "
                      r"0 \.\. 0\.05 um/N")
    results = {
        "lm": iwr.identify(with_effects, m, "lm"),
        "weighted lm": iwr.identify(with_effects, m, "lm", noise=iwr.Noise(legs=0.001)),
        "efficient": iwr.identify(with_effects, m, "efficient", noise=iwr.Noise(legs=0.001)),
    }
    for name, r in results.items():
        assert not r.success and r.status == "failed", name
        cause = _range_cause(r.fit)
        assert want.search(cause) and cause.startswith("6 effect parameter(s)"), (name, cause)
        assert "an effect's identified value outside its plausible range" in r.fit.verdict, name
        named = [t[0] for t in r.fit.implausible]
        assert sorted(named) == [f"leg{j}.compliance" for j in range(1, 7)], (name, named)
        assert "limit" not in cause
    cal = iwr.calibrate(with_effects, m, validation_fraction=0)
    assert not cal.success and cal.fit_ok is False
    assert want.search(_range_cause(cal.result.fit))
    assert want.search(cal.result.message)


def test_a_machine_at_the_bound_of_an_effects_range_passes(with_effects):
    """The range is tested as a hypothesis: legs with no compliance (the bound of 0 .. 0.05),
    realistic noise; the compliances identified below 0 by the noise (some are) are within
    what the noise explains, and LM, the efficient estimator and the job pass."""
    n = with_effects.n_params
    x = np.zeros(n + 7)
    x[n: n + 6] = -0.01  # 0.01 in the file: no compliance
    m, _ = api.simulate(with_effects, 60, seed=12, x=x, noise=NOISE)
    lm = iwr.identify(with_effects, m, "lm")
    eff = iwr.identify(with_effects, m, "efficient", noise=NOISE)
    for r in (lm, eff):
        assert np.any(r.x[n: n + 6] < -0.01), r.x[n: n + 6]  # below the range: the noise
        assert r.success, r.message
        assert not any("outside their plausible range" in c for c in r.fit.causes)
    cal = iwr.calibrate(with_effects, m, noise=NOISE, validation_fraction=0)
    assert cal.success, cal.result.message


def test_job_with_a_noise_model_and_effects(with_effects):
    """iwr.calibrate(noise=) on a robot with effects: the efficient estimator by default (its
    outlier test names a 0.3 mm leg typo), or weighted LM with the gross-error screen's
    chi-square test under the noise model; either way the chi-square fit test, the standard
    deviations of the effects, the predicted accuracy, the parameter error and the report."""
    from iwr.reporting.calibration import render

    m, x = api.simulate(with_effects, 80, seed=7, noise=NOISE)
    legs = m.legs.copy()
    legs[17, 3] += 0.3
    bad = Measurements(m.q, m.poses, legs, joint_types=m.joint_types, payload=m.payload,
                       temperatures=m.temperatures)
    n = with_effects.n_params
    for method in (None, "lm"):
        cal = iwr.calibrate(with_effects, bad, method, noise=NOISE, seed=1, truth=x,
                            validation_fraction=0.2)
        r = cal.result
        assert cal.success, (method, r.message)
        assert r.method == (method or "efficient")
        assert r.fit.dof > 0 and r.fit.p_value > 1e-3 and cal.fit_ok
        # The typo's pose, identification or held out (the split's seed decides), by its leg.
        gone = [o for o in r.outliers if o.removed]
        assert [(o.instrument, o.test) for o in gone] == [("leg4", "chi2")], [
            str(o) for o in r.outliers]
        assert "chi-square test under the noise model" in r.gross_errors
        assert cal.uncertainty is not None and np.all(np.isfinite(cal.uncertainty.std[n:]))
        if method is None:  # the estimator's covariance (LM's result has none, as without effects)
            assert cal.predicted is not None and cal.predicted.position_rms > 0
        # The effects recovered within a few standard deviations.
        err = (r.x[n:] - x[n:]) / cal.uncertainty.std[n:]
        assert np.abs(err).max() < 5, err
        pe = cal.parameter_error  # against the truth (its accuracy: test_parameter_error_...)
        assert pe is not None and pe.converged and np.isfinite(pe.rms_length)
        assert pe.parameter_names == list(r.parameter_names)
        text = render(cal).text()
        assert "chi2 =" in text and "leg1.compliance" in text
        assert "Pope" not in r.gross_errors


def _cli_files(robot, data, tmp_path, noise=NOISE):
    robot_file, data_file = tmp_path / "robot.toml", tmp_path / "data.csv"
    robot.with_noise(noise).to_toml(robot_file)
    data.to_csv(data_file)
    return robot_file, data_file


def test_cli_calibrate_with_the_robot_files_noise_and_effects(with_effects, noisy, tmp_path):
    """`iwr calibrate ROBOT.toml DATA.csv` on a robot with effects and a [noise] table: the
    noise model is used (the efficient estimator, its chi-square test in the report, exit 0);
    --method lm weighs by it too; --noise 10 times too small fails the fit test (exit 3)."""
    m, _ = noisy
    robot_file, data_file = _cli_files(with_effects, m, tmp_path)
    out = tmp_path / "eff"
    proc = _iwr("calibrate", robot_file, data_file, "--out", out, "--no-plots")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "[noise]" in proc.stdout and "not used" not in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "efficient"
    md = (out / "report.md").read_text()
    assert "chi2 =" in md and "## Effects" in md
    assert "calibrated.toml" in {p.name for p in out.iterdir()}
    lm = tmp_path / "lm"
    proc = _iwr("calibrate", robot_file, data_file, "--method", "lm", "--out", lm,
                "--no-plots")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "chi-square test under the noise model" in (lm / "report.md").read_text()
    small = ",".join(f"{k}={v / 10}" for k, v in vars(NOISE).items())
    proc = _iwr("calibrate", robot_file, data_file, "--noise", small, "--out",
                tmp_path / "small", "--no-plots")
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert "THE MODEL DOES NOT FIT THE DATA" in proc.stdout
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("weighted", [True, False], ids=["noise", "unweighted"])
def test_report_of_an_iwr_calibrate_run_with_effects(with_effects, noisy, tmp_path, weighted):
    """`iwr-calibrate` (DE on the C++ objective with effects; with `--noise robot` whitened)
    then `iwr report`: a weighted run records its noise model, and the report tests the fit
    (chi-square), the gross errors (each pose's chi-square test under that model, not Pope's)
    and gives the effects; an unweighted run is reported with Pope's test and the effects."""
    m, _ = noisy
    robot_file, data_file = _cli_files(with_effects, m, tmp_path)
    run = tmp_path / "run.json"
    proc = _run(_launcher(), robot_file, data_file, *(["--noise", "robot"] if weighted else []),
                "--output", run, "--population-size", 40, "--generations", 150, "--seed", 2,
                "--quiet")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    saved = iwr.load_result(run)
    assert saved.parameter_names[-1] == "legs.alpha"
    rep = tmp_path / "rep"
    proc = _iwr("report", run, robot_file, data_file, "--out", rep, "--no-plots")
    assert "Traceback" not in proc.stderr, proc.stderr
    md = (rep / "report.md").read_text()
    assert "## Effects" in md
    if not weighted:
        assert "objective" not in saved.settings and "Pope's tau test" in md
        assert proc.returncode in (0, 3, 5), proc.stdout + proc.stderr
        return
    assert saved.settings["objective"]["weighted"] is True
    assert saved.settings["objective"]["noise"] == vars(NOISE)
    assert "chi-square test under the noise model" in md and "Pope" not in md
    assert "chi2 =" in md
    # A short DE run need not fit; the exit status is the verdict's (0 fits, 3 does not).
    summary = json.loads((rep / "summary.json").read_text())
    assert summary["fit"]["statistic"] == pytest.approx(saved.fun, rel=1e-9)
    assert proc.returncode == (0 if summary["fit"]["fit_ok"] else 3), proc.stdout + proc.stderr


def test_report_of_a_weighted_tracker_run_tests_gross_errors_under_its_noise(tmp_path):
    """Laser-tracker points: `iwr-calibrate --noise realistic` records its noise model (the
    readings' and the tracker's), and `iwr report` tests each pose under it (the chi-square
    test, as `iwr calibrate --noise` does), not by Pope's test with the noise estimated from
    the residuals; its standard deviations are the weighted objective's."""
    robot = iwr.Robot.default().with_tracker(
        registration=(2000.0, 0.0, 0.0, np.pi / 2, 0.0, 0.0),
        reflectors=[(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)])
    nominal = tmp_path / "nominal.toml"
    robot.to_toml(nominal)
    sim = tmp_path / "sim"
    proc = _iwr("simulate", "--robot", nominal, "--poses", "40", "--seed", "3", "-o", sim)
    assert proc.returncode == 0, proc.stderr
    run = tmp_path / "run.json"
    proc = _run(_launcher(), sim / "robot.toml", sim / "measurements.csv", "--noise",
                "realistic", "--output", run, "--population-size", 40, "--generations", 100,
                "--seed", 2, "--quiet")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    saved = iwr.load_result(run)
    objective = saved.settings["objective"]
    assert objective["weighted"] is True and objective["tracker_noise"] is not None
    rep = tmp_path / "rep"
    proc = _iwr("report", run, sim / "robot.toml", sim / "measurements.csv", "--out", rep,
                "--no-plots")
    assert "Traceback" not in proc.stderr, proc.stderr
    md = (rep / "report.md").read_text()
    assert "chi-square test under the noise model" in md and "Pope" not in md, md
    summary = json.loads((rep / "summary.json").read_text())
    assert summary["fit"]["statistic"] == pytest.approx(saved.fun, rel=1e-9)
    assert proc.returncode == (0 if summary["fit"]["fit_ok"] else 3), proc.stdout
