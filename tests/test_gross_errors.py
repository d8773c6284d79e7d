"""Gross errors in every pose, with or without a noise model (iwr.gross_errors; issue 22, item 3):
the kinds' linearised readings model against finite differences, a swapped-digit typo in a leg
reading and in a point (pose data: the measured position) named by line and reading in the
identification and in the validation set, with and without a noise model, and the command line
(docs/cli.md: exit 0 with the pose named and left out; never "outliers: none")."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr import kinds
from iwr.gross_errors import find_gross_errors, screen
from iwr.reporting.calibration import render
from iwr.result import IdentificationResult, pose_key
from iwr.tracker import TrackerNoise
from iwr.tracker.data import TrackerMeasurements

REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
PROBE = (30.0, -20.0, 60.0, 0.3, -0.2, 0.1)
REAL = iwr.Noise.realistic()
READINGS = iwr.Noise(legs=REAL.legs, joint_lengths=REAL.joint_lengths,
                     joint_angles=REAL.joint_angles)
TRACKER_NOISE = (READINGS, TrackerNoise.leica())


def _robot(kind: str) -> iwr.Robot:
    robot = iwr.Robot.default()
    if kind == "points":
        return robot.with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)
    if kind == "probe":
        return robot.with_tracker(registration=REGISTRATION, probe=PROBE)
    return robot


def _noise(kind: str) -> object:
    return REAL if kind == "pose" else TRACKER_NOISE


def _rebuild(data: object, *, legs: np.ndarray | None = None, q: np.ndarray | None = None,
             readings: np.ndarray | None = None) -> object:
    """``data`` with new legs, joints or tracker (pose) readings, lines and source kept."""
    lines = getattr(data, "lines", None)
    kw = {"joint_types": data.joint_types, "lines": lines, "source": data.source}
    legs = data.legs if legs is None else legs
    q = data.q if q is None else q
    if isinstance(data, TrackerMeasurements):
        key = "points" if data.points is not None else "probe"
        kw[key] = getattr(data, key) if readings is None else readings
        return TrackerMeasurements(q, legs, **kw)
    return iwr.Measurements(q, data.poses if readings is None else readings, legs, **kw)


@pytest.mark.parametrize("kind", ["points", "probe"])
def test_tracker_misclosures_match_finite_differences(kind):
    """The derivatives of the predicted-minus-measured points (along and across the line of
    sight) in every reading (legs and joints through the forward kinematics, the tracker's own
    readings) against central differences of the misclosures recomputed from perturbed data."""
    robot = _robot(kind)
    # Noise-free: the residuals vanish at the truth, so that the change of the line of sight
    # with a perturbed point (the misclosures are along and across it) is second order.
    data, truth = iwr.simulate(robot, 6, seed=1)
    kind_ = kinds.of(data)
    mis = kind_.misclosures(robot, data, truth, None)
    h = 1e-5
    nj = robot.n_joints
    raw = data.points.reshape(len(data), -1) if data.points is not None else data.probe

    def at(**kw: np.ndarray) -> np.ndarray:
        return kind_.misclosures(robot, _rebuild(data, **kw), truth, None).r

    for j in range(len(mis.names)):
        if j < 6:
            arrays = [data.legs.copy(), data.legs.copy()]
            key = "legs"
        elif j < 6 + nj:
            arrays, key = [data.q.copy(), data.q.copy()], "q"
        else:
            arrays, key = [raw.copy(), raw.copy()], "readings"
        col = j if j < 6 else j - 6 if j < 6 + nj else j - 6 - nj
        if key == "readings" and kind == "probe" and col >= 3:
            continue  # the probe's rotation about {T}'s axes: checked below, not an Euler column
        arrays[0][:, col] += h
        arrays[1][:, col] -= h
        if key == "readings" and data.points is not None:
            arrays = [a.reshape(data.points.shape) for a in arrays]
        fd = (at(**{key: arrays[0]}) - at(**{key: arrays[1]})) / (2 * h)
        scale = max(1.0, float(np.max(np.abs(mis.b[:, :, j]))))
        assert np.max(np.abs(fd - mis.b[:, :, j])) < 1e-6 * scale, mis.names[j]
    if kind == "probe":
        # Rotating the measured probe by a small rotation vector w about its origin, in {T}.
        from scipy.spatial.transform import Rotation

        from iwr.transforms import euler_zyx, pose_from_matrix
        for c in range(3):
            w = np.zeros(3)
            w[c] = h
            out = []
            for sign in (1, -1):
                probe = data.probe.copy()
                for k in range(len(data)):
                    t = np.eye(4)
                    t[:3, :3] = Rotation.from_rotvec(sign * w).as_matrix() @ euler_zyx(
                        *probe[k, 3:])
                    t[:3, 3] = probe[k, :3]
                    probe[k] = pose_from_matrix(t)
                out.append(at(readings=probe))
            fd = (out[0] - out[1]) / (2 * h)
            assert np.max(np.abs(fd - mis.b[:, :, 6 + nj + 3 + c])) < 1e-5


def test_default_misclosures_are_the_problems_residuals():
    """The protocol's default (a kind without its own): the problem's residuals per pose, each
    its own reading; no noise model."""
    robot = _robot("pose")
    data, truth = iwr.simulate(robot, 5, seed=2, noise=REAL)
    mis = kinds.MeasurementKind.misclosures(kinds.of(data), robot, data, truth)
    own = kinds.of(data).misclosures(robot, data, truth)
    assert np.allclose(mis.r, own.r, atol=1e-9)
    assert np.allclose(mis.a, own.a, atol=1e-6)
    with pytest.raises(ValueError, match="no noise model"):
        kinds.MeasurementKind.misclosures(kinds.of(data), robot, data, truth, REAL)


def _swap_digits(value: float, place: int) -> float:
    """``value`` with two adjacent differing digits swapped: those of ``10^place`` and
    ``10^(place - 1)`` (``place`` 1: tens and units, -1: the first two decimals), or, where they
    are equal, the next pair down, else the next pair up (so that the typo is not a few um)."""
    text = f"{abs(value):.6f}"
    point = text.index(".")
    for p in (place, place - 1 if place != 1 else 2, place + 2 if place != -2 else 1):
        i = point - 1 - p if p > 0 else point - p
        s = list(text)
        if i >= 0 and s[i] != s[i + 1]:
            s[i], s[i + 1] = s[i + 1], s[i]
            return math.copysign(float("".join(s)), value)
    raise AssertionError(f"no digits to swap in {text}")


def _typo(data: object, row: int, reading: str) -> tuple[object, str]:
    """A swapped-digit typo in pose ``row``: in leg 3's reading (its first decimals: tenths of a
    mm), or in the first coordinate of the measured point (reflector 1's x; the probe's x; the
    platform's x for poses in {0}; its tens and units: up to 81 mm). Returns the data and the
    reading the test must blame."""
    if reading == "leg":
        legs = data.legs.copy()
        legs[row, 2] = _swap_digits(legs[row, 2], -1)
        return _rebuild(data, legs=legs), "leg3"
    if isinstance(data, TrackerMeasurements) and data.points is not None:
        pts = data.points.copy()
        pts[row, 0, 0] = _swap_digits(pts[row, 0, 0], 1)
        return _rebuild(data, readings=pts), "reflector1.x"
    raw = (data.probe if isinstance(data, TrackerMeasurements) else data.poses).copy()
    raw[row, 0] = _swap_digits(raw[row, 0], 1)
    return _rebuild(data, readings=raw), ("probe.x" if isinstance(data, TrackerMeasurements)
                                          else "position.x")


def _with_lines(data: object) -> object:
    """As if read from ``data.csv`` with a comment line and a header before the rows."""
    n = len(data)
    kw = {"joint_types": data.joint_types, "lines": np.arange(n) + 3, "source": "data.csv"}
    if isinstance(data, TrackerMeasurements):
        key = "points" if data.points is not None else "probe"
        return TrackerMeasurements(data.q, data.legs, **{key: getattr(data, key)}, **kw)
    return iwr.Measurements(data.q, data.poses, data.legs, **kw)


@pytest.mark.parametrize("noisy", [False, True], ids=["no-noise-model", "noise-model"])
@pytest.mark.parametrize("where", ["identification", "validation"])
@pytest.mark.parametrize("reading", ["leg", "point"])
@pytest.mark.parametrize("kind", ["pose", "points"])
def test_swapped_digit_named_by_line_and_reading(kind, reading, where, noisy):
    """One swapped-digit typo among clean poses with realistic noise is named by its file line
    and the reading at fault, in either set, whether or not a noise model is given; the pose is
    left out (of the solution, or of the accuracy figures), the fit passes, and the clean poses
    are not named."""
    robot = _robot(kind)
    data, _ = iwr.simulate(robot, 40, seed=11, noise=_noise(kind))
    data = _with_lines(data)
    ident_rows, val_rows = kinds.split_rows(len(data), 0.2, 0)
    row = int((ident_rows if where == "identification" else val_rows)[3])
    bad, blame = _typo(data, row, reading)
    kind_ = kinds.of(bad)
    ident, val = kind_.subset(bad, ident_rows), kind_.subset(bad, val_rows)
    noise = _noise(kind) if noisy else None
    method = "efficient" if noisy else "lm"
    kw = {"noise": noise} if noisy else {}
    result = iwr.identify(robot, ident, method, active="base", **kw)
    result, ident2, val2 = screen(robot, ident, val, result, noise, held_out=True)
    named = [o for o in result["outliers"] if o.where == f"data.csv, line {row + 3}"]
    assert len(named) == 1, [str(o) for o in result["outliers"]]
    o = named[0]
    assert o.data_set == where and o.removed
    # The estimator names a point's reading along its line of sight (radial) and across it.
    names = {o.instrument, *o.confounded}
    assert blame in names or (blame == "reflector1.x" and "reflector1.radial" in names), str(o)
    assert o.test == ("chi2" if noisy else "tau")
    assert len(result["outliers"]) <= 2, [str(o) for o in result["outliers"]]  # <= 1 false alarm
    assert result["fit"].fit_ok, result["fit"].verdict
    lines = [int(v) for v in (ident2.lines if where == "identification" else val2.lines)]
    # Out of the returned set, or (the estimator's own snooping) out of the poses it used.
    assert row + 3 not in lines or not result["used"][lines.index(row + 3)]
    assert "false alarms" in result["gross_errors"]


def test_clean_data_without_noise_model_pass_and_say_the_rate():
    robot = _robot("pose")
    data, _ = iwr.simulate(robot, 40, seed=12, noise=REAL)
    ident, val = kinds.split(data, 0.2, 0)
    result = iwr.identify(robot, ident, "lm", active="base")
    found = find_gross_errors(robot, ident, result.x, None, validation=val,
                              active=result["active"])
    # At 0.001 per pose, 40 clean poses give a false alarm in 4 % of such data sets (this one
    # has one, at p = 0.0008): the rates are measured in benchmarks/bench_gross_errors.py.
    assert found.test == "tau" and len(found.outliers) <= 1
    assert found.n_tested == {"identification": len(ident), "validation": len(val)}
    # The noise estimated from the residuals: the legs' share of realistic noise, tens of um.
    assert 0.005 < found.sigma < 0.05
    assert "0.001 per pose" in found.describe()


def test_a_wrong_model_is_not_blamed_on_readings():
    """A tool offset left out (80 mm along z of {5}, times 0.5 .. 1.5 over the poses), no noise
    model: every pose misfits alike, so no pose stands out from the noise estimated from the
    residuals (none is removed), and the fit fails on the implausible errors: the model, not a
    reading."""
    robot = _robot("pose")
    data, _ = iwr.simulate(robot, 30, seed=13, noise=REAL)
    from iwr.transforms import euler_zyx

    r = euler_zyx(data.poses[:, 3], data.poses[:, 4], data.poses[:, 5])
    poses = data.poses.copy()
    poses[:, :3] += 80.0 * r[:, :, 2] * np.linspace(0.5, 1.5, len(data))[:, None]
    bad = _rebuild(data, readings=poses)
    result = iwr.identify(robot, bad, "lm", active="base")
    result, ident, _ = screen(robot, bad, bad, result, None, held_out=False)
    assert not result["fit"].fit_ok and not result.success
    assert len(ident) >= 0.8 * len(bad)
    assert not any(o.removed for o in result["outliers"])


# -- the command line ---------------------------------------------------------------------------

def _run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    return subprocess.run([sys.executable, "-m", "iwr", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=900)


def _file_typo(path: Path, row: int, column: str, place: int) -> int:
    """Swap two digits of ``column`` in data row ``row`` of a CSV file; its line number."""
    lines = path.read_text().splitlines()
    head = next(i for i, line in enumerate(lines) if not line.startswith("#"))
    j = lines[head].split(",").index(column)
    i = head + 1 + row
    fields = lines[i].split(",")
    fields[j] = repr(_swap_digits(float(fields[j]), place))
    lines[i] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    return i + 1


@pytest.mark.parametrize("noise", ["none", "realistic"])
def test_cli_held_out_typo_named_and_left_out(tmp_path, noise):
    """The issue's case: a swapped digit in a held-out pose. Named by file and line, left out of
    the accuracy figures, exit 0 (docs/cli.md), and never "outliers: none"."""
    sim = _run("simulate", "--out", "sim", "--poses", "40", "--seed", "5", cwd=tmp_path)
    assert sim.returncode == 0, sim.stderr
    _, val_rows = kinds.split_rows(40, 0.2, 0)
    data = tmp_path / "sim" / "measurements.csv"
    line = _file_typo(data, int(val_rows[1]), "s3_mm", -1)
    out = _run("calibrate", "sim/robot.toml", "sim/measurements.csv", "--noise", noise,
               "--out", "cal", "--no-plots", "--no-progress", cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    assert f"measurements.csv, line {line} (held-out pose)" in out.stdout, out.stdout
    assert "outliers: none" not in out.stdout
    summary = json.loads((tmp_path / "cal" / "summary.json").read_text())
    held = [o for o in summary["outliers"] if o["data_set"] == "validation"]
    assert [o["instrument"] for o in held] == ["leg3"]
    assert summary["n_validation"] == len(val_rows) - 1
    report = (tmp_path / "cal" / "report.html").read_text()
    assert f"line {line} (held-out pose)" in report


@pytest.mark.parametrize("noise", ["none", "realistic"])
def test_cli_tracker_typos_in_both_sets(tmp_path, noise):
    """Tracker data (the shipped example's setup): a swapped digit in a held-out pose's point and
    in an identification pose's leg reading, with and without a noise model: both named by line
    and reading, the first left out of the accuracy figures, the second of the solution; exit 0
    and the fit passes (one reading is wrong, not the model)."""
    robot = Path(__file__).resolve().parents[1] / "examples" / "iwr_tracker.toml"
    sim = _run("simulate", "--robot", str(robot), "--out", "sim", "--poses", "40", "--seed", "5",
               cwd=tmp_path)
    assert sim.returncode == 0, sim.stderr
    ident_rows, val_rows = kinds.split_rows(40, 0.2, 0)
    data = tmp_path / "sim" / "measurements.csv"
    point_line = _file_typo(data, int(val_rows[2]), "reflector2_y_mm", 1)
    leg_line = _file_typo(data, int(ident_rows[5]), "s2_mm", -1)
    out = _run("calibrate", "sim/robot.toml", "sim/measurements.csv", "--noise", noise,
               "--out", "cal", "--no-plots", "--no-progress", cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "the model fits the data" in out.stdout or "within their plausible size" in out.stdout
    assert f"measurements.csv, line {point_line} (held-out pose)" in out.stdout, out.stdout
    assert f"measurements.csv, line {leg_line}:" in out.stdout, out.stdout
    summary = json.loads((tmp_path / "cal" / "summary.json").read_text())
    named = {o["where"].rsplit("line ", 1)[1]: o for o in summary["outliers"]}
    assert set(named) == {str(point_line), str(leg_line)}
    assert named[str(point_line)]["instrument"] in ("reflector2.y", "reflector2.across1",
                                                     "reflector2.across2")
    assert named[str(leg_line)]["instrument"] == "leg2"
    assert named[str(point_line)]["data_set"] == "validation"


@pytest.mark.parametrize("noisy", [False, True], ids=["tau", "chi2"])
def test_pose_statistics_match_the_stacked_problem(noisy):
    """Each identification pose's test value against the same statistic computed on the whole
    stacked, whitened problem in plain NumPy (hat matrix of all 6 N residuals, not per pose
    blocks): Pope's largest |tau| per pose, or the chi-square of the pose's block of Q^+."""
    robot = _robot("pose")
    data, _ = iwr.simulate(robot, 25, seed=21, noise=REAL)
    result = iwr.identify(robot, data, "lm", active="base")
    active = result["active"]
    noise = REAL if noisy else None
    found = find_gross_errors(robot, data, result.x, noise, active=active, alpha=1 - 1e-12)
    assert sorted(o.pose for o in found.outliers) == list(range(len(data)))  # all "fail"
    mis = kinds.of(data).misclosures(robot, data, result.x, noise)
    n = len(data)
    if noisy:
        cov = np.einsum("kij,kjl,kml->kim", mis.b, mis.reading_cov, mis.b)
        white = np.linalg.inv(np.linalg.cholesky(cov))
    else:
        white = np.broadcast_to(np.eye(6), (n, 6, 6))
    r = np.einsum("kij,kj->ki", white, mis.r).reshape(-1)
    a = np.einsum("kij,kjp->kip", white, mis.a[:, :, active]).reshape(6 * n, -1)
    h = a @ np.linalg.pinv(a.T @ a) @ a.T
    q = np.eye(6 * n) - h
    f = 6 * n - np.linalg.matrix_rank(a)
    s = math.sqrt(r @ r / f)
    for o in found.outliers:
        rows = slice(6 * o.pose, 6 * o.pose + 6)
        if noisy:
            want = r[rows] @ np.linalg.pinv(q[rows, rows]) @ r[rows]
        else:
            want = np.max(np.abs(r[rows] / (s * np.sqrt(np.diag(q)[rows]))))
        assert o.statistic == pytest.approx(want, rel=1e-6), o


def test_a_pose_left_out_far_from_the_solution_is_put_back_when_it_passes_there():
    """A global method's "converged" at a point far from the solution (here the nominal robot):
    at that point a clean pose fails its test and is left out; after the re-fit it passes, so
    it is put back (the review's crs2/bobyqa runs named clean lines as outliers)."""
    robot = iwr.Robot.default()
    noise = iwr.Noise.realistic()
    data, _ = iwr.simulate(robot, 40, seed=11, noise=noise)
    ident_rows, val_rows = kinds.split_rows(len(data), 0.2, 0)
    ident, val = data.subset(ident_rows), data.subset(val_rows)
    far = IdentificationResult(x=np.zeros(robot.n_params), fun=1.0, nfev=1, success=True,
                               message="converged", method="crs2")
    result, ident2, val2 = screen(robot, ident, val, far, noise, held_out=True)
    assert [str(o) for o in result["outliers"]] == []
    assert len(ident2) == len(ident) and len(val2) == len(val)
    assert result["fit"].fit_ok and result.success, result.message
    assert "with every pose" in result.message


def test_cli_report_leaves_out_what_the_run_left_out(tmp_path):
    """The review's case: `iwr calibrate` leaves an identification pose with a typo out; its
    result.json records the line, and `iwr report` of that run on the same file leaves it out
    too (exit 0, the line named), where it used to test the typo again and say "does not fit".
    The same result without the record (as `iwr-calibrate`'s engine writes it) is tested in
    the report, not re-fitted: the typo's line is named and the fit fails (exit 3)."""
    sim = _run("simulate", "--out", "sim", "--poses", "40", "--seed", "5", cwd=tmp_path)
    assert sim.returncode == 0, sim.stderr
    ident_rows, _ = kinds.split_rows(40, 0.2, 0)
    data = tmp_path / "sim" / "measurements.csv"
    line = _file_typo(data, int(ident_rows[2]), "s3_mm", 1)  # 205.0 -> 250.0 mm
    out = _run("calibrate", "sim/robot.toml", "sim/measurements.csv", "--method", "lm",
               "--out", "cal", "--no-plots", "--no-progress", cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    run = iwr.load_result(tmp_path / "cal" / "result.json")
    assert [o.line for o in run.left_out] == [line] and run.gross_errors
    rep = _run("report", "cal/result.json", "sim/robot.toml", "sim/measurements.csv",
               "--out", "rep", "--no-plots", cwd=tmp_path)
    assert rep.returncode == 0, rep.stdout + rep.stderr
    assert f"left out here too (sim/measurements.csv, line {line})" in rep.stdout, rep.stdout
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert summary["n_identification"] == 31  # the run's split: 8 of 40 held out, 1 typo
    assert "poses: 31 for identification (1 more left out as gross error), 8 held out" in \
        out.stdout and "poses: 31 for identification" in rep.stdout
    # As the engine writes it: no record of a screen; the report tests and names the line.
    bare = iwr.result.IdentificationResult(
        x=run.x, fun=run.fun, nfev=run.nfev, success=True, message="converged", method="de",
        parameter_names=run.parameter_names, settings={"program": "iwr-engine"})
    bare.save(tmp_path / "engine.json")
    rep = _run("report", "engine.json", "sim/robot.toml", "sim/measurements.csv",
               "--out", "rep2", "--no-plots", cwd=tmp_path)
    assert rep.returncode == 3, rep.stdout + rep.stderr
    assert f"measurements.csv, line {line}" in rep.stdout and "identify again" in rep.stdout


def test_the_job_on_probe_data_with_a_noise_model_finds_a_gross_error():
    """A probe's twelve point misclosures have a covariance of rank 6 (they move as one rigid
    pose): the screen whitens them in the directions the noise reaches (a Cholesky factor
    failed, and the job stopped with numpy's "Matrix is not positive definite"). A probe pose
    1 mm off is found and left out; the clean poses pass, and the chi-square test with them.
    (The efficient estimator: a probe's weighted point objective is refused, for the same
    singular covariance.)"""
    robot = _robot("probe")
    data, _ = iwr.simulate(robot, 40, seed=5, noise=TRACKER_NOISE)
    probe = np.array(data.probe, dtype=float)
    probe[9, 0] += 1.0
    bad = _rebuild(data, readings=probe)
    cal = iwr.calibrate(robot, bad, "efficient", noise=TRACKER_NOISE, seed=3)
    assert cal.success and cal.fit_ok, cal.result.message
    found = [o for o in cal.result.outliers if o.removed]
    assert [o.key for o in found] == [pose_key(bad, 9)], found
    # Out of the identification set, as every method's (the estimator's per-pose arrays cut to
    # the set), and the summary's cost over the set says nothing of a pose it includes.
    assert len(cal.identification) == 40 - len(cal.validation) - 1
    assert cal.result.used.all() and cal.result.used.size == len(cal.identification)
    assert "did not use included" not in render(cal).summary()


def _leg_typo():
    """The robot and 40 poses of pose data with realistic noise, leg 3 of pose 5 1 mm off."""
    robot = _robot("pose")
    data, _ = iwr.simulate(robot, 40, seed=11, noise=REAL)
    legs = np.array(data.legs, dtype=float)
    legs[5, 2] += 1.0
    return robot, _rebuild(data, legs=legs)


@pytest.mark.parametrize("held_out", [True, False])
@pytest.mark.parametrize("method", ["efficient", "lm"])
def test_every_method_leaves_its_outlier_out_of_the_figures(method, held_out):
    """Pose data with one leg reading 1 mm off: whatever the method, the job's identification
    set, its cost and residual figures and (nothing held out) its accuracy figures are over the
    poses the result was fitted to. The efficient estimator leaves the pose out of its own fit
    (``result["used"]``); the job once kept it in the set, so that with nothing held out the
    accuracy it reported was over the typo (max 1.07 mm where LM's was 0.06 mm, 60 poses), and
    ``iwr report`` of the same run (which drops the recorded outliers) said otherwise."""
    robot, bad = _leg_typo()
    cal = iwr.calibrate(robot, bad, method, noise=REAL if method == "efficient" else None,
                        seed=3, validation_fraction=0.2 if held_out else 0.0)
    removed = [o for o in cal.result.outliers if o.removed]
    assert [o.key for o in removed] == [pose_key(bad, 5)], [str(o) for o in removed]
    assert cal.held_out is held_out
    assert len(cal.identification) == 40 - (len(cal.validation) if held_out else 0) - 1
    keys = set(iwr.result.pose_keys(cal.identification))
    assert pose_key(bad, 5) not in keys
    if method == "efficient":
        used = cal.result.used
        assert used.all() and used.size == len(cal.identification)
        for name in ("corrections", "residuals", "redundancy", "pose_statistic"):
            assert len(cal.result[name]) == len(cal.identification), name
        assert np.isfinite(cal.result.pose_statistic).all()
    text = "did not use included"
    rep = render(cal)
    assert text not in rep.summary() and text not in rep.markdown([])
    # The counts say where the 40th pose went.
    said = "for identification (1 more left out as gross error), "
    assert said in rep.summary() and said in rep.markdown([]) and said in rep.html().render()
    if not held_out:
        # The accuracy is over the identification poses: the typo is not among them.
        assert cal.validation is cal.identification
        assert cal.accuracy.calibrated.summary()["position_mm"]["max"] < 0.2
        # And the report of the run from its result says the same.
        again = iwr.calibration.from_result(robot, bad, cal.result)
        assert len(again.identification) == len(cal.identification)
        a = cal.accuracy.calibrated.summary()["position_mm"]
        b = again.accuracy.calibrated.summary()["position_mm"]
        assert a == pytest.approx(b, rel=1e-9, abs=1e-12), (a, b)


def test_a_typo_names_no_effect_in_the_diagnosis():
    """Pose data without any effect, with payload and temperature columns and one leg reading
    1 mm off: the diagnosis of the geometric fit regresses the poses the fit used, so the typo,
    left out by the screen, names no effect. (Regressed over every identification pose, this
    data set named the legs' compliance, and so did 6 of 30 such data sets, against 0 of 30.)"""
    from iwr.effects import api
    from iwr.measurements import Measurements

    robot = _robot("pose")
    data, _ = iwr.simulate(robot, 60, seed=109, noise=REAL)
    rng = np.random.default_rng(9)
    legs = np.array(data.legs, dtype=float)
    legs[9, 3] += 1.0
    bad = Measurements(data.q, data.poses, legs, joint_types=data.joint_types,
                       payload=api.DEFAULT_PAYLOADS[np.arange(60) % 2],
                       temperatures=17 + 8 * rng.random(60))
    cal = iwr.calibrate(robot, bad, "lm", noise=REAL, seed=3, validation_fraction=0.0)
    assert [o.key for o in cal.result.left_out] == [pose_key(bad, 9)]
    assert cal.fit_ok and cal.diagnosis is not None
    assert cal.diagnosis.suggested == [], cal.diagnosis.sentence()
    # The premise: over every pose (the typo in) the same regression names one.
    from iwr.calibration import _diagnosis

    everything = _diagnosis(robot, bad, cal.result, REAL, [])
    assert everything.suggested == ["compliance"]


def test_the_report_of_an_estimators_result_on_its_data():
    """``from_result`` of the efficient estimator's result on the data it identified (not a
    job's): the recorded outlier is dropped from the data and the result's per-pose arrays are
    cut alike (it refused the result: ``used: shape (40,); expected (39,)``)."""
    robot, bad = _leg_typo()
    res = iwr.identify(robot, bad, "efficient", noise=REAL, progress=False)
    assert not res.used[5] and res.used.size == 40
    cal = iwr.calibration.from_result(robot, bad, res)
    assert len(cal.identification) == 39 and cal.result.used.size == 39
    assert pose_key(bad, 5) not in set(iwr.result.pose_keys(cal.identification))
    assert res.used.size == 40  # the caller's result is not changed
    assert cal.accuracy.calibrated.summary()["position_mm"]["max"] < 0.2


def test_degenerate_data_lose_the_estimators_outlier_too():
    """Data that cannot identify the robot (8 distinct poses, each measured 5 times with its own
    leg noise) are not screened ("not calibrated"), but the pose the efficient estimator left
    out of its own fit leaves the identification set all the same, and the identifiability
    report is over the poses left."""
    from iwr.measurements import Measurements

    robot = _robot("pose")
    d8, _ = iwr.simulate(robot, 8, seed=3, noise=REAL)
    rows = np.repeat(np.arange(8), 5)
    legs = np.array(d8.legs, dtype=float)[rows]
    legs += np.random.default_rng(1).normal(0, 0.002, legs.shape)
    legs[7, 1] += 1.0
    bad = Measurements(np.array(d8.q)[rows], np.array(d8.poses)[rows], legs,
                       joint_types=robot.joint_types)
    cal = iwr.calibrate(robot, bad, "efficient", noise=REAL, validation_fraction=0.0, seed=1)
    assert cal.degenerate() is not None and cal.result.status == "not calibrated"
    assert [o.pose for o in cal.result.left_out] == [7]
    assert len(cal.identification) == 39 and cal.result.used.size == 39
    assert cal.validation is cal.identification and cal.identifiability.n_poses == 39


def test_an_interrupted_efficient_run_leaves_out_what_its_last_solve_left_out():
    """screen on an interrupted result of the efficient estimator (Ctrl-C after a solve that
    left a pose out): nothing re-tested, but the identification set and the per-pose arrays
    are those of the poses the last completed solve used, as a finished run's."""
    robot, bad = _leg_typo()
    res = iwr.identify(robot, bad, "efficient", noise=REAL, progress=False)
    assert not res.used[5] and res.used.sum() == 39
    res["status"] = "interrupted"
    out, ident, val = screen(robot, bad, bad, res, REAL, held_out=False)
    assert out is res and len(ident) == 39 and val is ident
    assert pose_key(bad, 5) not in set(iwr.result.pose_keys(ident))
    assert res.used.all() and len(res.residuals) == 39


def test_a_clean_probe_pose_is_tested_in_six_directions():
    """The probe's twelve misclosures move with the probe reading and with the robot's readings
    as rigid motions of the same four points: six directions, whatever the misclosure. (Their
    columns once took the arms of the measured and of the predicted points: the covariance had a
    seventh direction at 1e-10 of the largest, kept on about 1 pose in 100, whose chi-square
    statistic then averaged 17.6 for 7 degrees of freedom.) Held out, the statistics follow
    chi2(6)."""
    from scipy import stats

    from iwr.gross_errors import _Whitened

    robot = _robot("probe")
    data, truth = iwr.simulate(robot, 60, seed=5, noise=TRACKER_NOISE)
    val, _ = iwr.simulate(robot, 200, seed=105, noise=TRACKER_NOISE, x=truth)
    eff = iwr.identify(robot, data, "efficient", noise=TRACKER_NOISE, outliers="off")
    mis = kinds.of(val).misclosures(robot, val, eff.x, TRACKER_NOISE)
    assert {_Whitened(mis, k, eff.active).r.size for k in range(len(val))} == {6}
    found = find_gross_errors(robot, data, eff.x, TRACKER_NOISE, validation=val,
                              active=eff.active, alpha=1 - 1e-12, test_identification=False)
    chi2 = [o.statistic for o in found.outliers]
    assert len(chi2) == len(val) and {o.dof for o in found.outliers} == {6}
    assert stats.kstest(chi2, stats.chi2(6).cdf).pvalue > 1e-3


def test_a_removed_outlier_leaves_no_stale_misfit_verdict_in_the_message(tmp_path):
    """One leg reading 10 mm off, no noise model: the method's point fitted to it fails the
    plausibility test (leg4.dl0 beyond its limit), the screen removes the pose and the refit
    fits. The result's message (a calibration file's status_detail) read "THE MODEL DOES NOT FIT
    THE DATA: ..." beside status "success"; it now says the method's point failed with the pose
    in, and what the refit gave (found by an outside audit, on the shipped example)."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 125, seed=1, noise=iwr.Noise.realistic())
    legs = data.legs.copy()
    legs[30, 3] += 10.0
    bad = iwr.Measurements(data.q, data.poses, legs, joint_types=data.joint_types)
    cal = iwr.calibrate(robot, bad, "lm", seed=1)
    assert cal.success and any(o.removed for o in cal.result.outliers)
    message = str(cal.result.message)
    assert "DOES NOT FIT" not in message, message
    assert message.startswith("lm: its point, fitted to every pose, failed the fit test"), message
    render(cal).write(tmp_path, plots=False)
    provenance = iwr.Robot.from_toml(tmp_path / "calibrated.toml").provenance
    assert provenance["status"] == "success" and "DOES NOT FIT" not in provenance["status_detail"]
