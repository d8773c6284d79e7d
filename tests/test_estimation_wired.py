"""The efficient estimator wired in: ``identify(noise=...)``, ``"converged"`` only for a sane fit
(eq. 10 too), ``iwr calibrate`` with a noise model, and the comparison with the estimator."""

from __future__ import annotations

import json
import math
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr.transforms import euler_zyx, pose_from_matrix, pose_matrix

ROBOT = iwr.Robot.default()
NOISE = iwr.Noise.realistic()


def run(*args: str, cwd: Path | None = None, env: dict[str, str] | None = None):
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    environ.update(env or {})
    # Outside the repository root, where the source folder would shadow the installed package.
    return subprocess.run(
        [sys.executable, "-m", "iwr", *args], capture_output=True, text=True,
        cwd=cwd if cwd is not None else tempfile.gettempdir(), env=environ, timeout=600,
    )


@pytest.fixture(scope="module")
def data60() -> tuple[iwr.Measurements, np.ndarray]:
    return iwr.simulate(ROBOT, 60, seed=4, noise=NOISE)


def test_noise_selects_the_efficient_estimator(data60) -> None:
    m, _ = data60
    res = iwr.identify(ROBOT, m, noise=NOISE, active="base")
    assert res.method == "efficient" and res.success and res.fit_ok
    # fun is the chi-square statistic, near its dof; eq. (10)'s cost is aside.
    assert 0.5 < res.fun / res.fit.dof < 1.5
    assert res.cost_eq10 == pytest.approx(iwr.Problem(ROBOT, m).cost(res.x))
    lm = iwr.identify(ROBOT, m, active="base")
    assert lm.method == "lm" and lm.success
    assert lm.fit.fit_ok and math.isnan(lm.fit.statistic)  # no noise model: plausibility only
    assert lm.fun == pytest.approx(iwr.Problem(ROBOT, m).cost(lm.x))
    # By its registered name, with the same answer.
    named = iwr.identify(ROBOT, m, "efficient", noise=NOISE, active="base")
    np.testing.assert_array_equal(named.x, res.x)


def test_efficient_needs_a_noise_model(data60) -> None:
    m, _ = data60
    with pytest.raises(ValueError, match="noise"):
        iwr.identify(ROBOT, m, "efficient")
    with pytest.raises(TypeError, match="noise"):
        iwr.identify(ROBOT, m, noise="realistic")


def test_lm_with_a_noise_model_gets_the_chi_square_test(data60) -> None:
    m, _ = data60
    res = iwr.identify(ROBOT, m, "lm", noise=NOISE, active="base")
    assert res.success and res.fit.fit_ok and res.fit.dof == 6 * 60 - int(res.active.sum())
    # The GLS statistic minimised to first order around eq. (10)'s solution: the efficient
    # estimator's minimum, to the linearisation.
    eff = iwr.identify(ROBOT, m, noise=NOISE, active="base")
    assert res.fit.statistic == pytest.approx(eff.fun, rel=0.02)


def test_lm_on_a_shifted_frame_is_not_converged(data60) -> None:
    # Issue 16: a 2 m shift along z0 is absorbed by joint 1's d; LM converges to it, but it is
    # no assembly error.
    m, _ = data60
    moved = iwr.Measurements(m.q, m.poses + [0, 0, 2000.0, 0, 0, 0], m.legs,
                             joint_types=m.joint_types)
    res = iwr.identify(ROBOT, moved, "lm", active="base")
    assert not res.success and res.status == "failed"
    assert "joint1.dd" in res.message and "DOES NOT FIT" in res.message
    named = {n: v for n, v, _ in res.fit.implausible}
    assert abs(named["joint1.dd"] + named["joint2.da"] - 2000) < 1


def test_lm_in_a_local_minimum_fails_the_chi_square_test() -> None:
    # docs/compare.md: LM from the bad start of seed 2 stops converged far above the noise floor;
    # with the scenario's noise model known its success is now False.
    comp = iwr.compare_methods(n_poses=100, seeds=[2], methods=["lm"], start="bad", out=None,
                               progress=False)
    (row,) = comp.runs
    assert not row["at_floor"] and row["cost"] > 1e3 * row["noise_floor"]
    assert not row["success"]
    assert "DOES NOT FIT" in row["message"]


def test_compare_shows_the_estimator_beside_eq10() -> None:
    comp = iwr.compare_methods(n_poses=60, seeds=[0, 1], methods=["lm", "efficient"],
                               start="near", out=None, progress=False)
    rows = {(r["method"], r["seed"]): r for r in comp.runs}
    for s in (0, 1):
        eff, lm = rows[("efficient", s)], rows[("lm", s)]
        assert eff["status"] == "ok" and eff["success"], eff["message"]
        # Its cost is eq. (10)'s at its x: at the floor but not below eq. (10)'s minimum.
        assert eff["at_floor"] and eff["cost"] >= lm["cost"] * (1 - 1e-9)
        assert np.isfinite(eff["tool_position_rms"])


def _write_moved(sim: Path, out: Path, how: str) -> Path:
    m = iwr.Measurements.from_csv(sim / "measurements.csv", ROBOT)
    t = pose_matrix(m.poses)
    if how == "frame":  # an unregistered tracker frame, 2 m and 30 degrees off
        f = np.eye(4)
        f[:3, :3] = euler_zyx(math.radians(30), 0.0, 0.0)
        f[:3, 3] = [2000.0, 0.0, 0.0]
        t = f @ t
    else:  # an 80 mm tool offset above {5} left out of the model
        t[:, :3, 3] += t[:, :3, 2] * 80.0
    moved = iwr.Measurements(m.q, pose_from_matrix(t), m.legs, joint_types=m.joint_types)
    path = out / f"{how}.csv"
    moved.to_csv(path)
    return path


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sim")
    proc = run("simulate", "--poses", "80", "--seed", "5", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    return out


@pytest.mark.parametrize("how", ["frame", "tool"])
@pytest.mark.parametrize("noise", ["realistic", None])
def test_calibrate_reports_a_model_that_does_not_fit(sim, tmp_path, how, noise) -> None:
    data = _write_moved(sim, tmp_path, how)
    out = tmp_path / "out"
    args = ["calibrate", str(sim / "robot.toml"), str(data), "--out", str(out), "--no-plots"]
    if noise:
        args += ["--noise", noise]
    proc = run(*args)
    assert "Traceback" not in proc.stderr
    if how == "frame":
        # Named before anything is identified (iwr.pose_frame), as bad data: exit 1.
        assert proc.returncode == 1, (proc.returncode, proc.stdout, proc.stderr)
        assert "another frame than the robot's world frame {0}" in proc.stderr
        assert re.search(r"one rigid transform, (199\d|20\d\d) mm and (29|30)\.\d+ deg",
                         proc.stderr), proc.stderr
        return
    assert proc.returncode == 3, (proc.returncode, proc.stdout, proc.stderr)
    text = proc.stdout
    assert "THE MODEL DOES NOT FIT THE DATA" in text
    assert "converged" not in text.replace("not converged", "").replace("(converged;", "")
    assert "likely causes" in text.lower() or "absorbed something" in text
    assert ("efficient" if noise else "lm") in text
    report = (out / "report.md").read_text()
    assert "The model does not fit the data" in report and "## Fit test and outliers" in report
    html = (out / "report.html").read_text()
    assert "The model does not fit the data" in html
    summary = json.loads((out / "summary.json").read_text())
    assert summary["fit"]["fit_ok"] is False
    if how == "tool":  # the six b_z absorb the 80 mm: named
        assert "db_z" in text


def test_calibrate_with_a_noise_model_reports_fit_outliers_prediction(sim, tmp_path) -> None:
    out = tmp_path / "out"
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"),
               "--noise", "legs=0.002,joint_lengths=0.005,joint_angles=5e-6,position=0.02,"
               "orientation=2e-5", "--out", str(out), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    assert "efficient estimator" in proc.stdout
    assert "fit test: the model fits the data" in proc.stdout
    # the statistic, its degrees of freedom and p-value, said once
    assert proc.stdout.count("degrees of freedom (p = ") == 1 and "[statistic" not in proc.stdout
    assert "outliers:" in proc.stdout and "predicted" in proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["fit"]["fit_ok"] and summary["method"] == "efficient"
    assert summary["predicted_accuracy"]["position_rms_mm"] > 0
    # eq. (10) is still there by its name.
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"),
               "--noise", "realistic", "--method", "lm", "--out", str(tmp_path / "lm"),
               "--no-plots")
    assert proc.returncode == 0, proc.stderr
    assert "identifying with lm" in proc.stdout and "fit test: the model fits" in proc.stdout


def test_calibrate_efficient_without_noise_is_a_usage_error(sim, tmp_path) -> None:
    proc = run("calibrate", str(sim / "robot.toml"), str(sim / "measurements.csv"),
               "--method", "efficient", "--out", str(tmp_path))
    assert proc.returncode == 2 and "noise" in proc.stderr and "Traceback" not in proc.stderr


def test_the_example_knows_its_noise_and_uses_the_estimator(tmp_path) -> None:
    proc = run("calibrate", "--no-plots", cwd=tmp_path, env={"IWR_EXAMPLE_QUICK": "1"})
    assert proc.returncode == 0, proc.stderr
    assert "the built-in example knows its noise" in proc.stdout
    assert "identifying with efficient" in proc.stdout
    assert "fit test: the model fits the data" in proc.stdout
    summary = json.loads((tmp_path / "iwr-example" / "summary.json").read_text())
    pred = summary["predicted_accuracy"]["position_rms_mm"]
    truth = summary["accuracy_with_true_errors"]["position_mm"]["rms"]
    # Predicted against the truth (parameter uncertainty only): below the measured noise floor.
    assert 0 < pred < truth
    report = (tmp_path / "iwr-example" / "report.md").read_text()
    assert "Predicted by the estimator's covariance" in report and "## Fit test" in report


def test_study_runs_the_estimator_beside_eq10(tmp_path) -> None:
    out = tmp_path / "st"
    proc = run("study", "--methods", "lm,efficient", "--poses", "40", "--noise", "0.02",
               "--draws", "2", "--seeds", "1", "--out", str(out), "--no-progress",
               "--scheduler", "synchronous")  # the estimator beside eq. (10), not Dask (test_study)
    assert proc.returncode == 0, proc.stderr
    summary = (out / "summary.md").read_text()
    assert "| efficient | 0.02 |" in summary and "| lm | 0.02 |" in summary
    assert "0 failed" in summary


def test_calibrate_lists_an_outlier_by_line_and_instrument(sim, tmp_path) -> None:
    m = iwr.Measurements.from_csv(sim / "measurements.csv", ROBOT)
    legs = m.legs.copy()
    legs[7, 2] += 1.0  # a misread leg 3 at the 8th pose
    data = tmp_path / "gross.csv"
    iwr.Measurements(m.q, m.poses, legs, joint_types=m.joint_types).to_csv(data)
    line = int(iwr.Measurements.from_csv(data, ROBOT).lines[7])
    out = tmp_path / "out"
    proc = run("calibrate", str(sim / "robot.toml"), str(data), "--noise", "realistic",
               "--validation-fraction", "0", "--out", str(out), "--no-plots")
    assert proc.returncode == 0, proc.stderr
    expected = f"gross.csv, line {line}: chi2"
    assert expected in proc.stdout and "leg3" in proc.stdout and "removed" in proc.stdout
    assert expected in (out / "report.md").read_text()
    summary = json.loads((out / "summary.json").read_text())
    assert [(o["pose"], o["instrument"], o["removed"]) for o in summary["outliers"]] == [
        (7, "leg3", True)]


def test_no_redundancy_is_not_a_fit() -> None:
    """Five poses (30 readings) for the 52 identifiable parameters leave no degree of freedom: the
    chi-square test cannot pass, and the result is not a success."""
    m, _ = iwr.simulate(ROBOT, 5, seed=3, noise=iwr.Noise.realistic())
    r = iwr.identify(ROBOT, m, "lm", noise=iwr.Noise.realistic(), progress=False)
    assert not r.success and r.status == "failed"
    assert not r.fit.fit_ok and "no redundancy" in r.message


def test_a_noise_model_the_test_cannot_use_leaves_the_plausibility_check(data60) -> None:
    """A pose weighted 0 (eq. (10)'s way to leave it out) cannot enter the chi-square test: LM's
    result keeps the plausibility check and says why there is no chi-square test."""
    m, _ = data60
    w = np.ones((len(m), 6))
    w[3] = 0.0
    m0 = iwr.Measurements(m.q, m.poses, m.legs, weights=w, joint_types=ROBOT.joint_types)
    r = iwr.identify(ROBOT, m0, "lm", noise=iwr.Noise.realistic(), progress=False)
    assert r.fit is not None and r.fit.fit_ok and "no chi-square test: weights" in r.message
