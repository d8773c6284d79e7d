"""Target lists exported by tracker software (iwr.tracker.sa_export): read through the long
table's join into the same TrackerMeasurements, calibrated to the same bits as the same points in
iwr's CSV, every malformed line named, per-point uncertainties used as the points' noise."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import iwr
from iwr.cli import main
from iwr.tracker import TrackerMeasurements, TrackerNoise, read_tracker_data, write_tracker_long
from iwr.tracker.sa_export import TargetFormat, is_target_export
from iwr.tracker.simulate import axis_whitening

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
COLUMNS = "x y z ux uy uz time rms"


@pytest.fixture(scope="module")
def robot() -> iwr.Robot:
    return iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS)


@pytest.fixture(scope="module")
def data(robot) -> TrackerMeasurements:
    d, _ = iwr.simulate(robot, 40, seed=5, noise=(iwr.Noise(legs=0.002, joint_lengths=0.005,
                                                            joint_angles=5e-6),
                                                  TrackerNoise.leica()))
    pts = d.points.copy()
    pts[3, 1] = np.nan  # a reflector not seen
    return TrackerMeasurements(d.q, d.legs, points=pts, joint_types=d.joint_types)


def sigma_of(k: int, i: int) -> tuple[float, float, float]:
    return (0.008 + 0.001 * (k % 3), 0.009 + 0.001 * i, 0.011)


def write_targets(path, data, *, unit="mm", scale=1.0, sep=None, names="P{pose}_R{reflector}",
                  header=True, drop=()):
    """The points of ``data`` as a target list: comments, both separators (alternating lines
    unless ``sep``), uncertainties, a time stamp and an RMS; returns the lines of the points."""
    lines = ["// SpatialAnalyzer-style export written by the test", "// Working Frame: Tracker"]
    if header:
        lines.append(f"// Units: {unit}")
    where = {}
    for k in range(len(data)):
        for i in range(data.n_reflectors):
            p = data.points[k, i]
            if np.isnan(p).any() or (k, i) in drop:
                continue
            name = names.format(pose=k + 1, reflector=i + 1)
            vals = [repr(float(v) * scale) for v in (*p, *sigma_of(k, i))]
            fields = ["Robot", "Cal", name, *vals, "2026-11-25T10:00:00", "0.0031"]
            s = sep or (", " if len(lines) % 2 else " ")
            lines.append(s.join(fields))
            where[(k, i)] = len(lines)
    path.write_text("\n".join(lines) + "\n")
    return where


def long_pair(robot, data, tmp_path):
    pts, rd = tmp_path / "points_long.csv", tmp_path / "readings.csv"
    write_tracker_long(pts, rd, robot.tracker, data)
    return pts, rd


def test_target_list_reads_the_same_points_and_their_uncertainties(robot, data, tmp_path):
    pts, rd = long_pair(robot, data, tmp_path)
    write_targets(tmp_path / "targets.txt", data)
    assert is_target_export(tmp_path / "targets.txt") and not is_target_export(pts)
    fmt = TargetFormat(columns=tuple(COLUMNS.split()))
    got = read_tracker_data(tmp_path / "targets.txt", robot.tracker, rd, fmt)
    want = read_tracker_data(pts, robot.tracker, rd)
    for a in ("q", "legs", "points", "lines"):
        np.testing.assert_array_equal(getattr(got, a), getattr(want, a))
    assert want.point_sigma is None
    assert got.source.endswith("targets.txt (working frame Tracker)")
    seen = got.seen
    assert np.all(np.isnan(got.point_sigma[~seen]))
    for k, i in zip(*np.nonzero(seen), strict=True):
        assert tuple(got.point_sigma[k, i]) == sigma_of(k, i)


def test_calibrates_bit_for_bit_as_the_csv(robot, data, tmp_path):
    """iwr calibrate on the target list and on the long CSV: the same result, bit for bit (the
    default method, which does not weigh the points)."""
    pts, rd = long_pair(robot, data, tmp_path)
    write_targets(tmp_path / "targets.txt", data)
    toml = tmp_path / "robot.toml"
    robot.to_toml(toml)
    common = ["--readings", str(rd), "--no-plots", "--no-progress"]
    assert main(["calibrate", str(toml), str(tmp_path / "targets.txt"), "--target-columns",
                 COLUMNS, "-o", str(tmp_path / "a"), *common]) == 0
    assert main(["calibrate", str(toml), str(pts), "-o", str(tmp_path / "b"), *common]) == 0
    a, b = (json.loads((tmp_path / d / "result.json").read_text()) for d in "ab")
    assert a["x"] == b["x"] and a["fun"] == b["fun"]
    assert (tmp_path / "a" / "calibrated.toml").read_text().split("[units]")[1] == \
        (tmp_path / "b" / "calibrated.toml").read_text().split("[units]")[1]


def test_units_from_the_comment_or_the_option(robot, data, tmp_path):
    _, rd = long_pair(robot, data, tmp_path)
    write_targets(tmp_path / "m.txt", data, unit="Meters", scale=1e-3, sep=" ")
    fmt = TargetFormat(columns=tuple(COLUMNS.split()))
    got = read_tracker_data(tmp_path / "m.txt", robot.tracker, rd, fmt)
    seen = got.seen
    np.testing.assert_allclose(got.points[seen], data.points[seen], rtol=1e-15, atol=0)
    np.testing.assert_allclose(got.point_sigma[seen][0], sigma_of(0, 0), rtol=1e-14)
    write_targets(tmp_path / "none.txt", data, header=False)
    with pytest.raises(iwr.MeasurementFileError, match="length unit is not stated"):
        read_tracker_data(tmp_path / "none.txt", robot.tracker, rd, fmt)
    got = read_tracker_data(tmp_path / "none.txt", robot.tracker, rd,
                            TargetFormat(columns=fmt.columns, units="mm"))
    np.testing.assert_array_equal(got.points, data.points)
    with pytest.raises(iwr.MeasurementFileError, match=r"m.txt, line 3: units 'Meters' \(m\), "
                       r"but --target-units says mm"):
        read_tracker_data(tmp_path / "m.txt", robot.tracker, rd,
                          TargetFormat(columns=fmt.columns, units="mm"))


def test_group_target_pattern(robot, data, tmp_path):
    _, rd = long_pair(robot, data, tmp_path)
    path = tmp_path / "t.txt"
    write_targets(path, data, names="Pose{pose}_R{reflector}", sep=",")
    # the pose in the group, the reflector in the target name
    text = path.read_text().replace(",Cal,Pose", ",Pose").replace("_R", ",R")
    path.write_text(text)
    got = read_tracker_data(path, robot.tracker, rd, TargetFormat(
        names="Pose{pose}::R{reflector}", columns=tuple(COLUMNS.split())))
    np.testing.assert_array_equal(got.points, data.points)


def test_malformed_lines_are_named_by_line_number(robot, data, tmp_path):
    _, rd = long_pair(robot, data, tmp_path)
    path = tmp_path / "t.txt"
    fmt = TargetFormat(columns=tuple(COLUMNS.split()))
    where = write_targets(path, data, sep=" ")
    lines = path.read_text().splitlines()

    def broken(line_of, edit):
        out = list(lines)
        n = where[line_of]
        out[n - 1] = edit(out[n - 1])
        path.write_text("\n".join(out) + "\n")
        return n

    cases = [
        ((2, 0), lambda s: s.replace(" 2026-11-25T10:00:00", ""), "10 fields; expected 11"),
        ((5, 1), lambda s: s.replace("P6_R2 ", "P6_R2 abc", 1).replace("abc", "1x", 1),
         "column x: '1x.*' is not a number"),
        ((6, 2), lambda s: s.replace("P7_R3", "Q7_R3"), "target 'Q7_R3' does not match the "
         "name pattern 'P{pose}_R{reflector}'"),
        ((7, 0), lambda s: s.replace("P8_R1", "P8_R9"), "reflector '9' is not in the tracker "
         "setup"),
        ((8, 0), lambda s: s.replace("P9_R1", "P99_R1"), "pose '99' is not in"),
        ((9, 1), lambda s: s.replace(" 0.011 ", " -0.011 "), "column uz: '-0.011' is not > 0"),
        ((10, 2), lambda s: s.replace("P11_R3", "P11_R1"), r"reflector '1' at pose '11' again "
         r"\(first at line"),
        ((11, 0), lambda s: s.replace("P12_R1", "P1_R2_R1"), "more than one way"),
    ]
    for line_of, edit, message in cases:
        n = broken(line_of, edit)
        with pytest.raises(iwr.MeasurementFileError, match=rf"t.txt, line {n}[:,] .*{message}"):
            read_tracker_data(path, robot.tracker, rd, fmt)
    # all of them at once: each line named, none dropped
    out = list(lines)
    bad = []
    for line_of, edit, _ in cases:
        n = where[line_of]
        out[n - 1] = edit(out[n - 1])
        bad.append(n)
    path.write_text("\n".join(out) + "\n")
    with pytest.raises(iwr.MeasurementFileError) as err:
        read_tracker_data(path, robot.tracker, rd, fmt)
    assert f"{len(bad)} bad rows in all" in str(err.value)
    assert f"line {min(bad)}:" in str(err.value)
    # and through the command line: one line, exit 1
    toml = tmp_path / "robot.toml"
    robot.to_toml(toml)
    assert main(["calibrate", str(toml), str(path), "--readings", str(rd), "--target-columns",
                 COLUMNS, "-o", str(tmp_path / "o")]) == 1


def test_bad_formats_are_usage_errors(robot, data, tmp_path, capsys):
    for kw, message in [({"names": "P{pose}"}, "{pose} and {reflector} once each"),
                        ({"columns": ("x", "y")}, "x, y and z are required"),
                        ({"columns": ("x", "y", "z", "ux")}, "as u .* or as ux, uy and uz"),
                        ({"columns": ("x", "y", "z", "w")}, "'w' is not a column"),
                        ({"units": "furlong"}, "expected one of")]:
        with pytest.raises(ValueError, match=message):
            TargetFormat(**kw)
    pts, rd = long_pair(robot, data, tmp_path)
    toml = tmp_path / "robot.toml"
    robot.to_toml(toml)
    assert main(["calibrate", str(toml), str(pts), "--readings", str(rd), "--target-names",
                 "X{pose}", "-o", str(tmp_path / "o")]) == 2
    assert "--target-names" in capsys.readouterr().err


def test_axis_whitening():
    rng = np.random.default_rng(3)
    p = rng.normal(size=(20, 3)) * 2000.0
    s = rng.uniform(0.005, 0.02, size=(20, 3))
    w = axis_whitening(p, s)
    np.testing.assert_allclose(np.swapaxes(w, 1, 2) @ w,
                               np.array([np.diag(1.0 / v**2) for v in s]), rtol=1e-10,
                               atol=1e-8)
    # the first row is along the line of sight, scaled by the distance's sigma
    e = p / np.linalg.norm(p, axis=1, keepdims=True)
    np.testing.assert_allclose(np.cross(w[:, 0], e), 0.0, atol=1e-9)
    radial = np.sqrt(np.einsum("ni,ni,ni->n", e, s**2, e))
    np.testing.assert_allclose(np.einsum("ni,ni->n", w[:, 0], e), 1.0 / radial, rtol=1e-12)
    # equal sigmas: the tracker model's whitening with distance = transverse = sigma
    iso = TrackerNoise(distance=0.01, distance_per_m=0.0, transverse=0.01, transverse_per_m=0.0)
    np.testing.assert_allclose(axis_whitening(p, np.full_like(p, 0.01)), iso.whitening(p),
                               rtol=1e-13, atol=1e-9)


def test_point_uncertainties_are_the_estimators_point_noise(robot):
    """Equal per-point uncertainties sigma give the efficient estimator's answer with the tracker
    model TrackerNoise(distance = transverse = sigma): the same weights, another code path."""
    sigma = 0.01
    readings = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
    iso = TrackerNoise(distance=sigma, distance_per_m=0.0, transverse=sigma,
                       transverse_per_m=0.0)
    data, _ = iwr.simulate(robot, 40, seed=6, noise=(readings, iso))
    sig = np.full(data.points.shape, sigma)
    with_sigma = TrackerMeasurements(data.q, data.legs, points=data.points,
                                     joint_types=data.joint_types, point_sigma=sig)
    a = iwr.identify(robot, with_sigma, method="efficient", noise=(readings, TrackerNoise.leica()),
                     active="base")
    b = iwr.identify(robot, data, method="efficient", noise=(readings, iso), active="base")
    assert a.success and b.success, (a.message, b.message)
    std = np.sqrt(np.diag(b["covariance"]))
    act = np.flatnonzero(b["active"])
    # within the solver's convergence tolerance (1e-6 of a standard deviation apart)
    assert np.max(np.abs(a.x[act] - b.x[act]) / std) < 1e-4
    assert a.fun == pytest.approx(b.fun, rel=1e-9)
    # and other uncertainties give another answer (they are used)
    c = iwr.identify(robot, TrackerMeasurements(
        data.q, data.legs, points=data.points, joint_types=data.joint_types,
        point_sigma=np.broadcast_to([0.02, 0.005, 0.01], data.points.shape)),
        method="efficient", noise=(readings, iso), active="base")
    assert np.max(np.abs(c.x[act] - b.x[act]) / std) > 1e-2


def test_point_sigma_is_checked_and_kept_by_subset(data):
    sig = np.where(np.isnan(data.points), np.nan, 0.01)
    m = TrackerMeasurements(data.q, data.legs, points=data.points,
                            joint_types=data.joint_types, point_sigma=sig)
    sub = m.subset([5, 3])
    np.testing.assert_array_equal(sub.point_sigma, sig[[5, 3]])
    bad = sig.copy()
    bad[0, 0, 1] = 0.0
    with pytest.raises(ValueError, match="pose 0, reflector 1, axis y is 0.0"):
        TrackerMeasurements(data.q, data.legs, points=data.points, point_sigma=bad)
    bad = np.full_like(sig, 0.01)
    with pytest.raises(ValueError, match="pose 3, reflector 2 was not seen"):
        TrackerMeasurements(data.q, data.legs, points=data.points, point_sigma=bad)


def test_a_method_that_does_not_weigh_the_points_says_their_uncertainties_are_unused(robot):
    """docs/data.md says iwr calibrate tells that a method other than the efficient estimator
    ignores the points' own uncertainties; it said so of the efficient estimator alone."""
    data, _ = iwr.simulate(robot, 40, seed=6)
    with_sigma = TrackerMeasurements(data.q, data.legs, points=data.points,
                                     joint_types=data.joint_types,
                                     point_sigma=np.full(data.points.shape, 0.01))
    notes = " ".join(iwr.calibrate(robot, with_sigma, "lm").notes)
    assert "uncertainties" in notes and "not used by method lm" in notes
    assert "not used by method" not in " ".join(iwr.calibrate(robot, data, "lm").notes)
