"""Checks of measurement files: every bad row reported with its line, nothing silently dropped."""

from __future__ import annotations

import numpy as np
import pytest

import iwr


@pytest.fixture(scope="module")
def robot() -> iwr.Robot:
    return iwr.Robot.default()


@pytest.fixture(scope="module")
def data(robot):
    m, _ = iwr.simulate(robot, n_poses=30, seed=11, noise=iwr.Noise.realistic())
    return m


def write(tmp_path, m: iwr.Measurements) -> tuple:
    path = tmp_path / "data.csv"
    m.to_csv(path)
    lines = path.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("q1"))
    return path, lines, header  # data row k is on line header + 2 + k (1-based)


def test_good_file_keeps_every_row_and_its_line(tmp_path, data, robot):
    path, _, header = write(tmp_path, data)
    back = iwr.Measurements.from_csv(path, robot=robot)
    assert len(back) == len(data)
    np.testing.assert_array_equal(back.lines, header + 2 + np.arange(len(data)))
    assert back.where(4) == f"{path}, line {header + 6}"
    sub = back.subset([4, 7])
    assert sub.where(1) == f"{path}, line {header + 9}"


def test_every_bad_row_is_listed(tmp_path, data):
    path, lines, h = write(tmp_path, data)
    bad = lines.copy()
    for k, col, value in ((2, 10, "nan"), (5, 1, ""), (9, 15, "abc")):
        fields = bad[h + 1 + k].split(",")
        fields[col] = value
        bad[h + 1 + k] = ",".join(fields)
    bad[h + 1 + 12] = bad[h + 1 + 12].rsplit(",", 1)[0]
    path.write_text("\n".join(bad) + "\n")
    with pytest.raises(iwr.MeasurementFileError) as info:
        iwr.Measurements.from_csv(path)
    msg = str(info.value)
    lines_bad = [h + 2 + k for k in (2, 5, 9, 12)]
    assert f"line {lines_bad[0]}, column s1_mm: 'nan' is not finite" in msg
    assert "4 bad rows in all, none dropped" in msg
    assert f"lines {lines_bad[0]}, {lines_bad[1]}, {lines_bad[2]} and {lines_bad[3]}" in msg
    assert "\n" not in msg


def test_missing_column(tmp_path, data):
    path, lines, h = write(tmp_path, data)
    bad = [line.rsplit(",", 1)[0] if i >= h else line for i, line in enumerate(lines)]
    path.write_text("\n".join(bad) + "\n")
    with pytest.raises(iwr.MeasurementFileError, match=r"missing columns \['s6_mm'\]"):
        iwr.Measurements.from_csv(path)


def test_repeated_pose(tmp_path, data):
    path, lines, h = write(tmp_path, data)
    path.write_text("\n".join(lines + [lines[h + 1 + 3], lines[h + 1 + 7]]) + "\n")
    n = len(lines)
    with pytest.raises(iwr.MeasurementFileError,
                       match=rf"2 repeated pose\(s\): lines {h + 5} and {n + 1}; "
                             rf"lines {h + 9} and {n + 2}"):
        iwr.Measurements.from_csv(path)


def test_metres_are_recognised(tmp_path, data, robot):
    scale_q = np.array([1000.0, 1000.0, 1.0, 1.0])
    scale_p = np.array([1000.0, 1000.0, 1000.0, 1.0, 1.0, 1.0])
    everything = iwr.Measurements(data.q / scale_q, data.poses / scale_p, data.legs / 1000.0,
                                  joint_types="PPRR")
    path, _, _ = write(tmp_path, everything)
    with pytest.raises(iwr.MeasurementFileError, match="look like metres"):
        iwr.Measurements.from_csv(path)  # even without a robot
    legs_only = iwr.Measurements(data.q, data.poses, data.legs / 1000.0, joint_types="PPRR")
    path, _, _ = write(tmp_path, legs_only)
    iwr.Measurements.from_csv(path)  # plausible without a robot...
    with pytest.raises(iwr.MeasurementFileError, match="leg readings is below 5.*look like metres"):
        iwr.Measurements.from_csv(path, robot=robot)  # ...not for a robot with a 400 mm stroke
    joints = iwr.Measurements(data.q / scale_q, data.poses, data.legs, joint_types="PPRR")
    path, _, _ = write(tmp_path, joints)
    with pytest.raises(iwr.MeasurementFileError, match="prismatic joint readings.*metres"):
        iwr.Measurements.from_csv(path, robot=robot)


def test_degrees_are_recognised(tmp_path, data):
    poses = data.poses.copy()
    poses[6, 4] = 85.0
    path, _, h = write(tmp_path, iwr.Measurements(data.q, poses, data.legs, joint_types="PPRR"))
    with pytest.raises(iwr.MeasurementFileError, match=rf"line {h + 8}: angles must be in radians"):
        iwr.Measurements.from_csv(path)


def test_unreachable_poses(tmp_path, data, robot):
    legs, q = data.legs.copy(), data.q.copy()
    legs[4, 2] = 480.0  # stroke 0..400 mm
    q[8, 3] = 2.0  # joint 4 limits +-60 degrees
    legs[8, 0] = -50.0
    path, _, h = write(tmp_path, iwr.Measurements(q, data.poses, legs, joint_types="PPRR"))
    iwr.Measurements.from_csv(path)  # only the robot knows its limits
    with pytest.raises(iwr.MeasurementFileError) as info:
        iwr.Measurements.from_csv(path, robot=robot)
    msg = str(info.value)
    assert f"2 unreachable pose(s) for robot 'IWR' (lines {h + 6} and {h + 10}" in msg
    assert f"line {h + 6}: leg 3 reading 480 mm is outside the stroke [0, 400]" in msg


def test_a_platform_beyond_the_hexapods_reach_is_unreachable(tmp_path, data, robot):
    """Issue 26: x_mm = 99999.9 (within the 1e5 mm limit of any value) was taken, and reported
    only after the identification, at another line."""
    poses = data.poses.copy()
    poses[3, 0] = 99999.9
    path, _, h = write(tmp_path, iwr.Measurements(data.q, poses, data.legs, joint_types="PPRR"))
    with pytest.raises(iwr.MeasurementFileError,
                       match=rf"1 unreachable pose\(s\) for robot 'IWR' \(line {h + 5}; "
                       rf"nothing dropped\); first: line {h + 5}: the measured platform position "
                       r"is \d{5,6}(\.\d+)? mm from the hexapod's base, "
                       r"beyond its reach \(1650 mm"):
        iwr.Measurements.from_csv(path, robot=robot)
    # Every simulated pose is well within it (the slack covers any error of the robot).
    iwr.Measurements.from_csv(write(tmp_path, data)[0], robot=robot)


def test_noise_just_outside_the_stroke_is_tolerated(tmp_path, data, robot):
    legs = data.legs.copy()
    legs[0, 0] = -0.01
    path, _, _ = write(tmp_path, iwr.Measurements(data.q, data.poses, legs, joint_types="PPRR"))
    assert len(iwr.Measurements.from_csv(path, robot=robot)) == len(data)


def test_joint_types_must_match_the_robot(tmp_path, data):
    path, _, _ = write(tmp_path, data)
    with pytest.raises(iwr.MeasurementFileError, match="joint types 'PPRR'.*'hexapod', ''"):
        iwr.Measurements.from_csv(path, robot=iwr.Robot.hexapod())


def test_weights_are_read(tmp_path, data, robot):
    w = np.linspace(0.5, 2.0, len(data) * 6).reshape(len(data), 6)
    m = iwr.Measurements(data.q, data.poses, data.legs, joint_types="PPRR", weights=w)
    path, lines, h = write(tmp_path, m)
    assert lines[h].endswith(",w1,w2,w3,w4,w5,w6")
    # Relative weights, stored divided by the largest.
    np.testing.assert_array_equal(iwr.Measurements.from_csv(path, robot=robot).weights,
                                  w / 2.0)


@pytest.mark.parametrize("weights, match", [
    (-1.0, r"weights: row 0, column 0 is negative \(-1.0\)"),
    (np.inf, r"weights: row 0, column 0 is inf; every value must be finite"),
    (np.nan, r"weights: row 0, column 0 is nan"),
])
def test_weights_are_checked(data, weights, match):
    w = np.ones((len(data), 6))
    w[0, 0] = weights
    with pytest.raises(ValueError, match=match):
        iwr.Measurements(data.q, data.poses, data.legs, joint_types="PPRR", weights=w)


def test_all_zero_weights_are_refused(tmp_path, data):
    with pytest.raises(ValueError, match="every weight is zero"):
        iwr.Measurements(data.q, data.poses, data.legs, joint_types="PPRR",
                         weights=np.zeros((len(data), 6)))
    m = iwr.Measurements(data.q, data.poses, data.legs, joint_types="PPRR",
                         weights=np.ones((len(data), 6)))
    path, lines, h = write(tmp_path, m)
    body = [",".join(line.split(",")[:-6] + ["0"] * 6) for line in lines[h + 1:]]
    path.write_text("\n".join(lines[: h + 1] + body) + "\n")
    with pytest.raises(iwr.MeasurementFileError, match=r"data.csv: weights: every weight is zero"):
        iwr.Measurements.from_csv(path)


@pytest.mark.parametrize("scale", [1e30, 5e-324])
def test_weight_scale_does_not_matter(data, scale):
    m = iwr.Measurements(data.q, data.poses, data.legs, joint_types="PPRR",
                         weights=np.full((len(data), 6), scale))
    assert np.array_equal(m.weights, np.ones((len(data), 6)))


@pytest.mark.parametrize("column, value, what", [
    (4, "1e308",
     r"column x_mm: 1e\+308 mm is beyond any robot or instrument \(\|value\| <= 100000 mm\)"),
    (10, "-2e5", r"column s1_mm: -200000.0 mm is beyond"),
    (0, "1e6", r"column q1_mm: 1000000.0 mm is beyond"),
    (2, "5000",
     r"column q3_rad: 5000.0 rad is beyond any robot or instrument \(\|value\| <= 1000 rad\)"),
])
def test_values_beyond_any_robot_are_refused_with_line_and_column(tmp_path, data, column, value,
                                                                   what):
    path, lines, h = write(tmp_path, data)
    fields = lines[h + 3].split(",")
    fields[column] = value
    lines[h + 3] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(iwr.MeasurementFileError, match=rf"line {h + 4}, {what}"):
        iwr.Measurements.from_csv(path)


def test_values_beyond_any_robot_are_refused_in_python(data):
    legs = data.legs.copy()
    legs[3, 2] = 1e308
    with pytest.raises(ValueError, match=r"legs: row 3, column 2: 1e\+308 mm is beyond"):
        iwr.Measurements(data.q, data.poses, legs, joint_types="PPRR")


# -- files as people have them --------------------------------------------------------------------


def test_byte_order_mark_is_accepted(tmp_path, data, robot):
    path, _, _ = write(tmp_path, data)
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())  # "CSV UTF-8" of a spreadsheet
    back = iwr.Measurements.from_csv(path, robot=robot)
    np.testing.assert_array_equal(back.legs, data.legs)
    # and a BOM right before the header, without the comment lines
    lines = path.read_text(encoding="utf-8-sig").splitlines()
    body = [line for line in lines if not line.startswith("#")]
    path.write_text("\ufeff" + "\n".join(body) + "\n", encoding="utf-8")
    assert len(iwr.Measurements.from_csv(path, robot=robot)) == len(data)


def test_files_not_in_utf8_are_named_by_line_and_what_to_do(tmp_path, data, robot):
    """A comment line in Latin-1 (a German spreadsheet's default), or Excel's "Unicode text"
    (UTF-16): the message was Python's codec error, naming no line (an outside audit)."""
    path, lines, _ = write(tmp_path, data)
    lines.insert(1, "# Messung von J\u00fcrgen")
    path.write_bytes(("\n".join(lines) + "\n").encode("latin-1"))
    with pytest.raises(iwr.MeasurementFileError,
                       match=r"data.csv, line 2: byte 0xfc is not UTF-8 text .*save it as "
                             r"\"CSV UTF-8\""):
        iwr.Measurements.from_csv(path, robot=robot)
    # The same with the byte order mark of "CSV UTF-8" before it (the offsets count after it).
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    with pytest.raises(iwr.MeasurementFileError, match=r"data.csv, line 2: byte 0xfc "):
        iwr.Measurements.from_csv(path, robot=robot)
    path.write_bytes(("\n".join(lines) + "\n").encode("utf-16"))
    with pytest.raises(iwr.MeasurementFileError, match=r"data.csv: a UTF-16 file"):
        iwr.Measurements.from_csv(path, robot=robot)
    path.write_bytes(("\n".join(lines) + "\n").encode("utf-8"))  # the same text in UTF-8
    assert len(iwr.Measurements.from_csv(path, robot=robot)) == len(data)


@pytest.mark.parametrize("sep, name", [(";", "';'"), ("\t", "tab")])
def test_semicolon_and_tab_separated_files_are_read(tmp_path, data, robot, sep, name):
    path, lines, h = write(tmp_path, data)
    path.write_text("\n".join(line if line.startswith("#") else line.replace(",", sep)
                              for line in lines) + "\n")
    back = iwr.Measurements.from_csv(path, robot=robot)
    np.testing.assert_array_equal(back.poses, data.poses)
    # A bad header says which separator was read.
    lines2 = path.read_text().splitlines()
    lines2[h] = lines2[h].replace("s6_mm", "s7_mm")
    path.write_text("\n".join(lines2) + "\n")
    with pytest.raises(iwr.MeasurementFileError, match=rf"\(separator {name}\)"):
        iwr.Measurements.from_csv(path)


def test_decimal_commas_are_named(tmp_path, data):
    path, lines, h = write(tmp_path, data)
    out = []
    for line in lines:
        if line.startswith("#"):
            out.append(line)
        else:
            out.append(";".join(f.replace(".", ",") for f in line.split(",")))
    path.write_text("\n".join(out) + "\n")
    with pytest.raises(iwr.MeasurementFileError, match="a decimal comma"):
        iwr.Measurements.from_csv(path)


def test_columns_in_another_order_say_the_order_expected(tmp_path, data):
    path, lines, h = write(tmp_path, data)
    cols = lines[h].split(",")
    order = cols[4:] + cols[:4]  # the joints last
    rows = [",".join(np.array(line.split(","))[[cols.index(c) for c in order]])
            for line in lines[h:]]
    path.write_text("\n".join(rows) + "\n")
    with pytest.raises(iwr.MeasurementFileError) as info:
        iwr.Measurements.from_csv(path)
    msg = str(info.value)
    assert "Expected columns, in this order: " in msg
    assert "x_mm, y_mm, z_mm, alpha_rad, beta_rad, gamma_rad, s1_mm" in msg
    # all present, only swapped: said so
    swapped = cols.copy()
    swapped[4], swapped[5] = swapped[5], swapped[4]
    path.write_text("\n".join([",".join(swapped)] + lines[h + 1:]) + "\n")
    with pytest.raises(iwr.MeasurementFileError, match="all there but in another order"):
        iwr.Measurements.from_csv(path)



def test_a_huge_line_is_refused_before_it_is_split(tmp_path, data):
    path, lines, h = write(tmp_path, data)
    lines[h + 2] = ",".join(["1"] * 200_000)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(iwr.MeasurementFileError,
                       match=rf"line {h + 3}: 399,999 characters; a measurement row has at most"):
        iwr.Measurements.from_csv(path)
    path.write_text("x" * 20_000 + "\n")  # the header itself
    with pytest.raises(iwr.MeasurementFileError, match="line 1: 20,000 characters"):
        iwr.Measurements.from_csv(path)


@pytest.mark.parametrize("kind", ["pose", "probe"])
@pytest.mark.parametrize("q, match", [
    ("abc", "q: cannot be read as numbers"),
    (np.zeros((5, 3)), "joint_types: 'PPRR' does not describe 3 joints"),
    (np.full((5, 4), np.nan), "q: row 0, column 0 is nan"),
])
def test_joint_readings_are_checked_alike_for_every_kind_of_data(kind, q, match):
    """One reader of the joint readings for pose data and tracker data."""
    from iwr.tracker.data import TrackerMeasurements

    legs = np.full((5, 6), 1000.0)
    with pytest.raises(ValueError, match=match):
        if kind == "pose":
            iwr.Measurements(q, np.zeros((5, 6)), legs, joint_types="PPRR")
        else:
            TrackerMeasurements(q, legs, probe=np.zeros((5, 6)), joint_types="PPRR")



def test_a_bad_value_in_a_checked_column_is_named_by_line_and_column(tmp_path, data, robot):
    """A negative weight, a temperature in K and a negative payload mass were named by the
    array's 0-based row and column ("weights: row 3, column 5"), not the file's line and the
    column's name (a QA run)."""
    loaded = iwr.Measurements(data.q, data.poses, data.legs, joint_types=robot.joint_types,
                              weights=np.ones((len(data), 6)),
                              temperatures=np.full(len(data), 21.0),
                              payload=np.ones((len(data), 4)))
    for column, value, said in (("w6", "-1", r"is negative \(-1.0\); weights must be >= 0"),
                                ("T_C", "295.9", "is 295.9 degrees C; expected -60 .. 200"),
                                ("payload_kg", "-5", "is -5.0 kg; expected 0 <= mass"),
                                ("payload_y_mm", "1e9", "1000000000.0 mm is beyond any robot")):
        path, lines, header = write(tmp_path, loaded)
        names = lines[header].split(",")
        row = lines[header + 5].split(",")  # data row 4: line header + 6
        row[names.index(column)] = value
        lines[header + 5] = ",".join(row)
        path.write_text("\n".join(lines) + "\n")
        with pytest.raises(iwr.MeasurementFileError,
                           match=rf"data.csv, line {header + 6}, column {column}:? {said}"):
            iwr.Measurements.from_csv(path, robot=robot)


def test_revolute_joint_readings_in_degrees_are_named_by_column(tmp_path, data, robot):
    # Before, "98 unreachable pose(s) ... joint 3 reading 89.3 rad is outside the joint limits":
    # the unit was left for the user to guess.
    q = data.q.copy()
    q[:, 2] = np.degrees(q[:, 2])
    path, _, _ = write(tmp_path, iwr.Measurements(q, data.poses, data.legs, joint_types="PPRR"))
    with pytest.raises(iwr.MeasurementFileError,
                       match=r"data.csv: column q3_rad: joint 3's readings look like degrees"):
        iwr.Measurements.from_csv(path, robot=robot)


@pytest.mark.parametrize(
    "rows, error, match",
    [
        ([0.5, 1.7], ValueError, r"rows: entry 0 is 0\.5, not an integer index \(a float index is "
                                 r"not rounded\)"),
        (np.array([1.0, 2.0]), ValueError, r"rows: entry 0 is 1\.0, not an integer index"),
        ([1, 2.5], ValueError, r"rows: entry 1 is 2\.5, not an integer index"),
        ([1, "x"], ValueError, r"rows: entry 1 is 'x', not an integer index"),
        ([True, 1], ValueError, r"rows: entry 0 is True among integers"),
        ([True, False], ValueError, r"rows: a boolean mask of 2 values for 30 rows"),
        (np.ones(31, dtype=bool), ValueError, r"rows: a boolean mask of 31 values for 30 rows"),
        ([[0, 1]], ValueError, r"rows: shape \(1, 2\)"),
        (3, ValueError, r"rows: 3; expected row indices .* \(one row: \[3\]\)"),
        ([30], IndexError, r"rows: entry 0 is 30, beyond the 30 rows \(0 to 29"),
        ([0, -31], IndexError, r"rows: entry 1 is -31, beyond the 30 rows"),
        ([2**70], IndexError, rf"rows: entry 0 is {2**70}, beyond the 30 rows"),
    ],
)
def test_subset_refuses_what_is_not_rows(data, rows, error, match):
    """Fractional indices were truncated (``[0.5, 1.7]`` picked rows 0 and 1, silently); a mask of
    another length, an index beyond the rows or booleans mixed with integers are named too."""
    with pytest.raises(error, match=match):
        data.subset(rows)


def test_subset_takes_integers_masks_and_slices(data):
    mask = np.arange(len(data)) % 3 == 0
    for rows, expected in [([4, 7, -1], [4, 7, 29]), (np.array([2, 2], dtype=np.uint8), [2, 2]),
                           (range(3), [0, 1, 2]), ((5,), [5]), ([np.int64(6)], [6]),
                           (mask, np.flatnonzero(mask)), (mask.tolist(), np.flatnonzero(mask)),
                           (slice(10, 4, -2), [10, 8, 6]), (slice(None), np.arange(30))]:
        np.testing.assert_array_equal(data.subset(rows).legs, data.legs[expected])
