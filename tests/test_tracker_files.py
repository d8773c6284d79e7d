"""Tracker data files: the wide CSV and the long table of points with the log of readings; round
trips, units checked, every bad row named."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

import iwr
from iwr.tracker import (
    TrackerMeasurements,
    read_tracker_data,
    write_tracker_long,
    write_tracker_wide,
)

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)


@pytest.fixture(scope="module")
def robot() -> iwr.Robot:
    return iwr.Robot.default().with_tracker(registration=REGISTRATION, reflectors=REFLECTORS,
                                            names=["A", "B", "C"])


@pytest.fixture(scope="module")
def data(robot) -> TrackerMeasurements:
    d, _ = iwr.simulate(robot, 12, seed=2)
    pts = d.points.copy()
    pts[3, 1] = np.nan  # reflector B not seen at pose 4
    pts[7, 2] = np.nan
    return TrackerMeasurements(d.q, d.legs, points=pts, joint_types=d.joint_types)


def same(a: TrackerMeasurements, b: TrackerMeasurements) -> None:
    np.testing.assert_array_equal(a.q, b.q)
    np.testing.assert_array_equal(a.legs, b.legs)
    np.testing.assert_array_equal(a.points, b.points)  # NaN where unseen, in both


def test_wide_round_trip(robot, data, tmp_path):
    path = tmp_path / "points.csv"
    write_tracker_wide(path, robot.tracker, data)
    header = [ln for ln in path.read_text().splitlines() if not ln.startswith("#")][0]
    assert header.startswith("pose,q1_mm,q2_mm,q3_rad,q4_rad,s1_mm")
    assert header.endswith("reflectorC_x_mm,reflectorC_y_mm,reflectorC_z_mm")
    back = read_tracker_data(path, robot.tracker)
    same(back, data)
    assert back.joint_types == robot.joint_types and back.source == str(path)


def test_long_round_trip(robot, data, tmp_path):
    pts, rd = tmp_path / "points.csv", tmp_path / "readings.csv"
    write_tracker_long(pts, rd, robot.tracker, data)
    rows = [ln for ln in pts.read_text().splitlines() if not ln.startswith("#")]
    assert rows[0] == "pose,reflector,x_mm,y_mm,z_mm" and len(rows) == 1 + 12 * 3 - 2
    same(read_tracker_data(pts, robot.tracker, readings=rd), data)
    # The points in another order (as a tracker exports them, by reflector): the same data.
    shuffled = tmp_path / "shuffled.csv"
    body = rows[1:]
    shuffled.write_text("\n".join([rows[0], *sorted(body, key=lambda r: r.split(",")[1])]) + "\n")
    same(read_tracker_data(shuffled, robot.tracker, readings=rd), data)


def test_probe_wide_round_trip(tmp_path):
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, probe=(0, 0, 60, 0, 0, 0))
    d, _ = iwr.simulate(robot, 5, seed=1)
    path = tmp_path / "probe.csv"
    write_tracker_wide(path, robot.tracker, d)
    back = read_tracker_data(path, robot.tracker)
    np.testing.assert_array_equal(back.probe, d.probe)


def test_bad_rows_are_all_named_with_file_and_line(robot, data, tmp_path):
    path = tmp_path / "points.csv"
    write_tracker_wide(path, robot.tracker, data)
    lines = path.read_text().splitlines()
    first = next(i for i, ln in enumerate(lines) if not ln.startswith("#")) + 1  # data row 1
    f = lines[first].split(",")
    f[2] = "abc"
    lines[first] = ",".join(f)
    f = lines[first + 2].split(",")
    f[-2] = ""  # one coordinate of reflector C missing
    lines[first + 2] = ",".join(f)
    f = lines[first + 4].split(",")
    f[8] = "1e300"
    lines[first + 4] = ",".join(f)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(iwr.MeasurementFileError) as exc:
        read_tracker_data(bad, robot.tracker)
    msg = str(exc.value)
    n1, n3, n5 = first + 1, first + 3, first + 5
    assert msg.startswith(f"{bad}, line {n1}, column q2_mm: 'abc' is not a number")
    assert f"3 bad rows in all, none dropped: lines {n1}, {n3} and {n5}" in msg


def test_units_and_columns_are_checked(robot, data, tmp_path):
    path = tmp_path / "points.csv"
    write_tracker_wide(path, robot.tracker, data)
    text = path.read_text()
    bad = tmp_path / "m.csv"
    bad.write_text(text.replace("reflectorA_x_mm", "reflectorA_x_m"))
    with pytest.raises(iwr.MeasurementFileError, match=r"m\.csv, line \d+: column 12 is "
                       r"'reflectorA_x_m', in m; iwr reads mm"):
        read_tracker_data(bad, robot.tracker)
    bad.write_text(text.replace("reflectorB_", "reflectorX_"))
    with pytest.raises(iwr.MeasurementFileError, match="expected 'reflectorB_x_mm'"):
        read_tracker_data(bad, robot.tracker)


def test_long_table_errors_name_the_file_and_line(robot, data, tmp_path):
    pts, rd = tmp_path / "points.csv", tmp_path / "readings.csv"
    write_tracker_long(pts, rd, robot.tracker, data)
    lines = pts.read_text().splitlines()
    lines.append("99,A,1,2,3")          # a pose not in the readings
    lines.append("1,D,1,2,3")           # a reflector not in the setup
    lines.append(lines[2])              # a point given twice
    pts.write_text("\n".join(lines) + "\n")
    n = len(lines)
    with pytest.raises(iwr.MeasurementFileError) as exc:
        read_tracker_data(pts, robot.tracker, readings=rd)
    msg = str(exc.value)
    assert msg.startswith(f"{pts}, line {n - 2}: pose '99' is not in {rd}")
    assert f"lines {n - 2}, {n - 1} and {n}" in msg
    with pytest.raises(iwr.MeasurementFileError, match="give the robot's log of joint and leg"):
        read_tracker_data(pts, robot.tracker)
    bad = tmp_path / "mm.csv"
    bad.write_text("pose,reflector,x_m,y_m,z_m\n1,A,1,2,3\n")
    with pytest.raises(iwr.MeasurementFileError, match="'x_m', in m; iwr reads mm"):
        read_tracker_data(bad, robot.tracker, readings=rd)


def _with_copies(path, copies):
    """Append to a wide file a copy of data row ``k`` under a new pose id, for each k."""
    lines = path.read_text().splitlines()
    first = next(i for i, ln in enumerate(lines) if not ln.startswith("#")) + 1
    for n, k in enumerate(copies):
        f = lines[first + k].split(",")
        lines.append(",".join([f"copy{n}"] + f[1:]))
    path.write_text("\n".join(lines) + "\n")
    return first + 1  # the line of data row 0


def test_repeated_poses_under_other_ids_are_refused(robot, data, tmp_path):
    # The same pose measured twice never gives identical readings and points: a copy counts
    # one pose twice (issue 26: 2 poses copied 30 times were "calibrated").
    path = tmp_path / "points.csv"
    write_tracker_wide(path, robot.tracker, data)
    row0 = _with_copies(path, [0, 3, 0])  # row 3 has reflector B unseen (NaN): still a copy
    n = len(data)
    with pytest.raises(iwr.MeasurementFileError,
                       match=rf"points.csv: 2 repeated pose\(s\): lines {row0} \(pose '1'\), "
                       rf"{row0 + n} \(pose 'copy0'\), {row0 + n + 2} \(pose 'copy2'\); "
                       rf"lines {row0 + 3} \(pose '4'\), {row0 + n + 1} \(pose 'copy1'\) have "
                       "exactly the same"):
        read_tracker_data(path, robot.tracker)
    # The long pair: the copy is in the readings and the points under a new id.
    pts, rd = tmp_path / "long.csv", tmp_path / "readings.csv"
    write_tracker_long(pts, rd, robot.tracker, data)
    r_lines = rd.read_text().splitlines()
    r_first = next(i for i, ln in enumerate(r_lines) if not ln.startswith("#")) + 1
    rd.write_text("\n".join(r_lines + ["copy," + r_lines[r_first + 1].split(",", 1)[1]]) + "\n")
    p_lines = pts.read_text().splitlines()
    p_lines += ["copy," + ln.split(",", 1)[1] for ln in p_lines if ln.startswith("2,")]
    pts.write_text("\n".join(p_lines) + "\n")
    with pytest.raises(iwr.MeasurementFileError, match=rf"readings.csv \+ .*long.csv: 1 repeated "
                       rf"pose\(s\): lines {r_first + 2} \(pose '2'\), {r_first + n + 1} "):
        read_tracker_data(pts, robot.tracker, readings=rd)
    # Distinct points at the same readings are two measurements, not a copy.
    lines = path.read_text().splitlines()[:row0 + n - 1]
    f = lines[row0 - 1].split(",")
    f[0], f[-1] = "again", repr(float(f[-1]) + 0.001)
    path.write_text("\n".join(lines + [",".join(f)]) + "\n")
    assert len(read_tracker_data(path, robot.tracker)) == n + 1


def test_repeated_probe_poses_are_refused(tmp_path):
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, probe=(0, 0, 60, 0, 0, 0))
    d, _ = iwr.simulate(robot, 5, seed=1)
    path = tmp_path / "probe.csv"
    write_tracker_wide(path, robot.tracker, d)
    _with_copies(path, [4])
    with pytest.raises(iwr.MeasurementFileError, match=r"probe.csv: 1 repeated pose\(s\)"):
        read_tracker_data(path, robot.tracker)


def test_a_registration_beyond_any_setup_is_refused_by_name():
    """Issue 26: a registration x of 1e300 gave a bounds error about "parameter 58"."""
    with pytest.raises(ValueError, match=r"registration: entry 0 is 1e\+300, beyond any tracker "
                       r"setup \(\|value\| <= 100000"):
        iwr.Robot.default().with_tracker(registration=(1e300, 0, 0, 0, 0, 0),
                                         reflectors=REFLECTORS)


def test_what_is_no_regular_file_is_refused_without_reading(robot, data, tmp_path):
    """Issue 26: a named pipe as data, readings or robot blocked iwr calibrate for ever;
    /dev/zero as tracker data read 1 GB before it was refused."""
    fifo = tmp_path / "pipe.csv"
    os.mkfifo(fifo)  # nobody writes it: a read would block
    with pytest.raises(iwr.MeasurementFileError, match=r"pipe.csv: a named pipe \(FIFO\), not a "
                       "regular file"):
        read_tracker_data(fifo, robot.tracker)
    pts, rd = tmp_path / "points.csv", tmp_path / "readings.csv"
    write_tracker_long(pts, rd, robot.tracker, data)
    with pytest.raises(iwr.MeasurementFileError, match=r"pipe.csv: a named pipe"):
        read_tracker_data(pts, robot.tracker, readings=fifo)
    with pytest.raises(iwr.RobotFileError, match=r"pipe.csv: a named pipe"):
        iwr.Robot.from_toml(fifo)
    with pytest.raises(iwr.MeasurementFileError, match=r"/dev/zero: a device, not a regular"):
        read_tracker_data("/dev/zero", robot.tracker)


def test_a_data_file_beyond_the_memory_available_is_refused_before_reading(
        robot, tmp_path, monkeypatch):
    import iwr.measurements as meas

    monkeypatch.setattr(meas, "available_memory", lambda: 1_000_000_000)  # 1 GB free
    big = tmp_path / "big.csv"
    with open(big, "wb") as fh:
        fh.truncate(20_000_000)  # 20 MB of holes: its size, without writing it
    with pytest.raises(iwr.MeasurementFileError,
                       match=r"big.csv: 20.0 MB; the 1,000 MB of memory available process data "
                       r"files up to 10.0 MB \(calibrating takes about 100 times"):
        read_tracker_data(big, robot.tracker)
    with pytest.raises(iwr.MeasurementFileError, match=r"big.csv: 20.0 MB; the 1,000 MB"):
        iwr.Measurements.from_csv(big)
    assert meas.data_file_limit()[0] == 10_000_000


def _in_degrees(path, columns) -> None:
    """Rewrite ``columns`` of the wide CSV at ``path`` in degrees, as a user's export would."""
    lines = path.read_text().splitlines()
    header = next(k for k, ln in enumerate(lines) if not ln.startswith("#"))
    names = lines[header].split(",")
    for k in range(header + 1, len(lines)):
        values = lines[k].split(",")
        for c in columns:
            values[names.index(c)] = repr(math.degrees(float(values[names.index(c)])))
        lines[k] = ",".join(values)
    path.write_text("\n".join(lines) + "\n")


def test_probe_angles_in_degrees_are_refused_by_column(tmp_path):
    # They were read as radians, and the registration guess failed on a 114 mm RMS with "check
    # units" and no column named.
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, probe=(0, 0, 60, 0, 0, 0))
    d, _ = iwr.simulate(robot, 10, seed=4)
    path = tmp_path / "probe.csv"
    write_tracker_wide(path, robot.tracker, d)
    _in_degrees(path, ["probe_alpha_rad", "probe_beta_rad", "probe_gamma_rad"])
    with pytest.raises(iwr.MeasurementFileError,
                       match=r"probe.csv, line \d+, column probe_\w+_rad: .* looks like degrees"):
        read_tracker_data(path, robot.tracker)


def test_revolute_joints_in_degrees_are_refused_by_column(robot, data, tmp_path):
    # Tracker data's joint readings were never checked against the robot's limits: q3 in degrees
    # went on to a registration guess that failed with an RMS of metres.
    path = tmp_path / "points.csv"
    write_tracker_wide(path, robot.tracker, data)
    _in_degrees(path, ["q3_rad"])
    kind = iwr.kinds.of(data)
    read = kind.read(path, robot)  # the file alone cannot tell: the robot's limits can
    with pytest.raises(iwr.MeasurementFileError,
                       match=r"points.csv: column q3_rad: joint 3's readings look like degrees"):
        kind.check(robot, read)
    write_tracker_wide(path, robot.tracker, data)
    kind.check(robot, kind.read(path, robot))  # in radians: accepted
    outside = kind.read(path, robot)
    outside.legs[2, 4] = robot.leg_stroke[4, 1] + 50.0
    with pytest.raises(iwr.MeasurementFileError, match=r"1 unreachable pose.*leg 5 reading"):
        kind.check(robot, outside)
