"""The robot TOML: written to be read by hand, with provenance, read back exactly; values beyond
any robot refused naming the key."""

from __future__ import annotations

import datetime
import sys

import numpy as np
import pytest

import iwr

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


@pytest.mark.parametrize("robot", [iwr.Robot.default(), iwr.Robot.hexapod()])
def test_round_trip_is_exact(tmp_path, robot):
    x = np.random.default_rng(1).uniform(-0.3, 0.3, robot.n_params)
    calibrated = robot.with_errors(x)
    calibrated.to_toml(tmp_path / "r.toml")
    back = iwr.Robot.from_toml(tmp_path / "r.toml")
    assert back == calibrated and back.provenance == {}
    for name in ("dh", "joint_limits", "base_joints", "platform_joints", "leg_offsets",
                 "leg_stroke", "home_pose", "workspace"):
        np.testing.assert_array_equal(getattr(back, name), getattr(calibrated, name), name)


def test_rows_of_numbers_on_one_line(tmp_path):
    robot = iwr.Robot.default()
    robot.to_toml(tmp_path / "r.toml")
    text = (tmp_path / "r.toml").read_text()
    lines = text.splitlines()
    assert "limits = [0.0, 2000.0]" in lines
    assert "leg_offsets = [600.0, 600.0, 600.0, 600.0, 600.0, 600.0]" in lines
    assert "leg_stroke = [0.0, 400.0]" in lines
    rows = [line for line in lines if line.startswith("    [")]
    assert len(rows) == 12 and all(line.count(",") == 3 for line in rows)  # a_i, b_i: 3 numbers
    assert len(lines) < 70  # one number per line took 150
    # what tomllib reads is what to_dict says
    assert iwr.Robot.from_dict(tomllib.loads(text)) == robot


def test_provenance_is_written_and_kept(tmp_path):
    robot = iwr.Robot.default()
    when = datetime.datetime(2026, 11, 23, 14, 0, tzinfo=datetime.timezone.utc)
    prov = {"date": when, "iwr_version": iwr.__version__, "method": "lm",
            "data": tmp_path / "my data.csv", "cost_mm2": np.float64(1.25e-4), "converged": True}
    robot.to_toml(tmp_path / "r.toml", provenance=prov)
    text = (tmp_path / "r.toml").read_text()
    assert "[provenance]" in text and 'method = "lm"' in text
    back = iwr.Robot.from_toml(tmp_path / "r.toml")
    assert back == robot  # not geometry
    assert back.provenance == {**prov, "data": str(tmp_path / "my data.csv"), "cost_mm2": 1.25e-4}
    # kept when written again
    back.to_toml(tmp_path / "again.toml")
    assert iwr.Robot.from_toml(tmp_path / "again.toml").provenance == back.provenance
    with pytest.raises(ValueError, match=r"provenance.result: list"):
        robot.to_toml(tmp_path / "bad.toml", provenance={"result": [1, 2]})


def _default_edited(tmp_path, old: str, new: str) -> None:
    """The default robot's file as r.toml, its first ``old`` replaced by ``new``."""
    iwr.Robot.default().to_toml(tmp_path / "r.toml")
    text = (tmp_path / "r.toml").read_text()
    assert old in text
    (tmp_path / "r.toml").write_text(text.replace(old, new, 1))


@pytest.mark.parametrize("old, new, key", [
    ("leg_offsets = [600.0,", "leg_offsets = [1e26,", r"hexapod.leg_offsets\[0\]: 1e\+26 mm"),
    ("d = 500.0", "d = 2e5", r"carriage.joints\[0\].d: 200000.0 mm"),
    ("theta = 0.0", "theta = 1e9", r"carriage.joints\[0\].theta: 1000000000.0 rad"),
    ("limits = [0.0, 2000.0]", "limits = [0.0, 1e300]", r"carriage.joints\[0\].limits\[1\]"),
])
def test_values_beyond_any_robot_are_refused_with_the_key(tmp_path, old, new, key):
    _default_edited(tmp_path, old, new)
    with pytest.raises(iwr.RobotFileError, match=rf"r.toml: {key}.*beyond any robot"):
        iwr.Robot.from_toml(tmp_path / "r.toml")


def test_values_beyond_any_robot_are_refused_in_python():
    r = iwr.Robot.default()
    with pytest.raises(ValueError, match=r"leg_offsets: entry \(2,\) is 1e\+26 mm, beyond"):
        iwr.Robot(r.joint_types, r.dh, r.joint_limits, r.base_joints, r.platform_joints,
                  [600, 600, 1e26, 600, 600, 600], r.leg_stroke)


def test_deeply_nested_or_huge_files_are_refused(tmp_path):
    path = tmp_path / "r.toml"
    path.write_text("a = " + "[" * 30_000 + "]" * 30_000 + "\n")
    with pytest.raises(iwr.RobotFileError, match="nested too deeply"):
        iwr.Robot.from_toml(path)
    path.write_text("# padding\n" * 200_000)
    with pytest.raises(iwr.RobotFileError, match="larger than 256 kB"):
        iwr.Robot.from_toml(path)


@pytest.mark.parametrize("text, line", [
    ("[provenance]\nk" + ".k" * 3000 + " = 1\n", 2),  # tomllib: minutes at 50,000 parts
    ("name = 'x'\n[" + ".".join(["k"] * 3000) + "]\n", 2),
    ("a = {b" + '."c.d"' * 20 + " = 1}\n", 1),
    ("# x.y\n[[a . b . 'c' . d . e . f . g . h . i . j . k . l . m . n . o . p . q]]\n", 2),
])
def test_long_dotted_keys_are_refused_before_parsing(tmp_path, text, line):
    path = tmp_path / "r.toml"
    path.write_text(text)
    with pytest.raises(iwr.RobotFileError,
                       match=rf"r.toml, line {line}: a dotted key or table header of more "
                             "than 16 "):
        iwr.Robot.from_toml(path)


def test_dots_in_values_strings_and_comments_are_not_key_parts(tmp_path):
    dots = "." * 40
    iwr.Robot.default().to_toml(tmp_path / "r.toml", provenance={"note": f"a{dots}b", "x": 1.5})
    text = (tmp_path / "r.toml").read_text()
    head = f"# {dots}\n" + "name = '''\n" + dots + "\n'''\n"
    text = head + text.replace("name = ", "# name = ", 1)
    (tmp_path / "r.toml").write_text(text + f'[tracker]\nnoise.distance = 0.01\n"{dots}" = 1\n')
    # Past the scan: the only complaint is the unknown key, not the dots.
    with pytest.raises(iwr.RobotFileError, match=r"r.toml: tracker: unknown key\(s\) \.{40};"):
        iwr.Robot.from_toml(tmp_path / "r.toml")


def _hexapod_changed(change) -> dict:
    d = iwr.Robot.default().to_dict()
    change(d["hexapod"])
    return d


def _copy_leg(h):
    h["base_joints"][3] = list(h["base_joints"][2])
    h["platform_joints"][3] = list(h["platform_joints"][2])


def _on_a_line(key):
    def change(h):
        h[key] = [[100.0 * k, 50.0 * k, 0.0] for k in range(6)]
    return change


@pytest.mark.parametrize("change, match", [
    (lambda h: h.update(leg_offsets=[600.0, 600.0, -600.0, 600.0, 600.0, 600.0]),
     r"hexapod.leg_offsets\[2\]: -600 mm .* makes leg 3 -600 mm long at its shortest"),
    (lambda h: h.update(leg_offsets=[50.0] * 6, leg_stroke=[-100.0, 300.0]),
     r"hexapod.leg_offsets\[0\]: 50 mm with hexapod.leg_stroke's lower -100 mm"),
    (_copy_leg, r"legs 3 and 4 join the same points .* a copied row"),
    (_on_a_line("base_joints"), r"hexapod.base_joints: the six joints lie on one line"),
    (_on_a_line("platform_joints"), r"hexapod.platform_joints: the six joints lie on one line"),
    (lambda h: h.update(platform_joints=[[0.0, 0.0, 0.0]] * 6),
     r"hexapod.platform_joints: the six joints lie on one line or coincide"),
])
def test_a_hexapod_without_physical_sense_is_refused_by_key(change, match):
    # Before, a negative offset was taken and the job failed in the forward kinematics ("pose
    # 0: leg 1 has length -372.569 mm"), a zero one in iwr simulate ("only 0 of 60 random poses
    # were reachable"); coinciding or collinear joints were taken as they were.
    with pytest.raises(ValueError, match=match):
        iwr.Robot.from_dict(_hexapod_changed(change))


def test_a_hexapod_in_metres_is_refused_naming_the_file(tmp_path):
    robot = iwr.Robot.default()
    metres = iwr.Robot(robot.joint_types, robot.dh, robot.joint_limits, robot.base_joints / 1e3,
                       robot.platform_joints / 1e3, robot.leg_offsets / 1e3,
                       robot.leg_stroke / 1e3, home_pose=(0, 0, 0.75, 0, 0, 0),
                       workspace=(0.1, 0.1, 0.06, 0.1, 0.1, 0.1))
    metres.to_toml(tmp_path / "m.toml")
    with pytest.raises(iwr.RobotFileError,
                       match=r"m.toml: hexapod: every length .* below 5 mm .*\(largest "
                             r"hexapod.leg_offsets: 0.6\): these look like metres"):
        iwr.Robot.from_toml(tmp_path / "m.toml")


@pytest.mark.parametrize("robot", [iwr.Robot.default(), iwr.Robot.hexapod()])
def test_real_hexapods_pass_the_physical_checks(tmp_path, robot):
    # A calibrated robot (errors of up to a few mm) and the shipped examples read back.
    x = np.random.default_rng(3).uniform(-3.0, 3.0, robot.n_params)
    robot.with_errors(x).to_toml(tmp_path / "r.toml")
    iwr.Robot.from_toml(tmp_path / "r.toml")
    # A 3-3 design shares joint centres pairwise: distinct legs all the same.
    d = robot.to_dict()
    d["hexapod"]["base_joints"][1] = list(d["hexapod"]["base_joints"][0])
    iwr.Robot.from_dict(d)


@pytest.mark.parametrize("old, new, key, value", [
    ("alpha = 1.5707963267948966", "alpha = 90.0", r"carriage.joints\[0\].alpha \(joint 1\)", "90"),
    ("theta = 1.5707963267948966", "theta = -90", r"carriage.joints\[1\].theta \(joint 2\)",
     "-90"),
])
def test_dh_angles_in_degrees_are_refused_naming_file_row_and_value(tmp_path, old, new, key,
                                                                    value):
    """As the tracker's setup refuses an angle beyond 2 pi, written in degrees (alpha = 90 was read
    as 90 rad, a robot that no data fit)."""
    _default_edited(tmp_path, old, new)
    with pytest.raises(iwr.RobotFileError,
                       match=rf"r.toml: {key}: {value} is beyond \+-2 pi: DH angles are in "
                             rf"radians, and this looks like degrees \({value} deg = "):
        iwr.Robot.from_toml(tmp_path / "r.toml")


@pytest.mark.parametrize("old, new, message", [
    ("home_pose = [0.0, 0.0, 750.0, 0.0, 0.0, 0.0]",
     "home_pose = [0.0, 0.0, 750.0, 0.0, 0.0, 90.0]",
     r"home_pose: gamma 90 is beyond \+-2 pi: angles are in radians, and this looks like "
     r"degrees \(90 deg = 1\.5708 rad\)"),
    ("workspace = [120.0, 120.0, 80.0, 0.17453292519943295",
     "workspace = [120.0, 120.0, 80.0, 10.0", r"workspace: alpha 10 is beyond pi"),
    ("limits = [-1.5707963267948966, 1.5707963267948966]", "limits = [-90.0, 90.0]",
     r"joint_limits: joint 3 \(revolute\) limit 90 is beyond \+-2 pi: a revolute joint's "
     r"limits are in radians, and this looks like degrees"),
])
def test_pose_and_limit_angles_in_degrees_are_refused(tmp_path, old, new, message):
    """Only the DH angles were checked for degrees: home_pose's gamma = 90 made forward
    kinematics stall later, blamed on the data, and a revolute limit of 90 let iwr simulate
    write readings of 71 rad (an outside audit)."""
    _default_edited(tmp_path, old, new)
    with pytest.raises(iwr.RobotFileError, match=rf"r.toml: {message}"):
        iwr.Robot.from_toml(tmp_path / "r.toml")


def test_dh_angles_in_degrees_are_refused_in_python():
    r = iwr.Robot.default()
    for col, name in ((0, "alpha"), (3, "theta")):
        dh = r.dh.copy()
        dh[2, col] = 180.0
        with pytest.raises(ValueError, match=rf"dh: joint 3 \(row 2\) {name}: 180 is beyond "
                                             r"\+-2 pi.*\(180 deg = 3\.1416 rad\)"):
            iwr.Robot(r.joint_types, dh, r.joint_limits, r.base_joints, r.platform_joints,
                      r.leg_offsets, r.leg_stroke)
    dh = r.dh.copy()
    dh[:, [0, 3]] = [[2 * np.pi, -2 * np.pi]] * 4  # 2 pi itself is an angle in radians
    iwr.Robot(r.joint_types, dh, r.joint_limits, r.base_joints, r.platform_joints,
              r.leg_offsets, r.leg_stroke)


def test_built_in_robots_and_examples_have_dh_angles_in_radians():
    from pathlib import Path

    examples = Path(__file__).resolve().parents[1] / "examples"
    robots = [iwr.Robot.default(), iwr.Robot.hexapod()]
    robots += [iwr.Robot.from_toml(p) for p in sorted(examples.glob("*.toml"))]
    assert len(robots) >= 4
    for robot in robots:
        assert np.all(np.abs(robot.dh[:, [0, 3]]) <= 2 * np.pi), robot.name


def test_a_calibrated_angle_past_2_pi_is_the_same_rotation_within_it(tmp_path):
    """A nominal theta near 2 pi plus its identified error passes 2 pi: ``with_errors`` keeps the
    rotation, 2 pi nearer zero, so that the calibrated robot is written and read back."""
    r = iwr.Robot.default()
    dh = r.dh.copy()
    dh[2, 3] = 6.2
    near = iwr.Robot(r.joint_types, dh, r.joint_limits, r.base_joints, r.platform_joints,
                     r.leg_offsets, r.leg_stroke)
    x = np.zeros(r.n_params)
    x[11] = 0.2  # joint 3's dtheta
    calibrated = near.with_errors(x)
    assert calibrated.dh[2, 3] == pytest.approx(6.4 - 2 * np.pi)
    q = [100.0, 200.0, 0.3, -0.2]
    np.testing.assert_allclose(calibrated.carriage_transform(q), near.carriage_transform(q, x),
                               atol=1e-12)
    calibrated.to_toml(tmp_path / "c.toml")
    assert iwr.Robot.from_toml(tmp_path / "c.toml") == calibrated


def test_a_calibrated_angle_past_two_pi_is_the_same_robot_to_its_nominal():
    """A nominal theta near 2 pi (6.26) plus its error (0.05) passes 2 pi: with_errors keeps
    the same rotation within +-pi, and the errors implied against the nominal are the error
    again (they were -6.23 rad, which check_nominal refused as a geometry no calibration
    moves); a file with such an angle says both readings of it."""
    from iwr.compensation import check_nominal, implied_errors
    from iwr.robot_file import dh_degrees_problem

    base = iwr.Robot.default()
    x = np.zeros(base.n_params)
    x[4 * 2 + 3] = 6.26 - base.dh[2, 3]
    nominal = base.with_errors(x)
    assert nominal.dh[2, 3] == pytest.approx(6.26)
    x = np.zeros(nominal.n_params)
    x[4 * 2 + 3] = 0.05
    calibrated = nominal.with_errors(x)
    assert abs(calibrated.dh[2, 3]) <= np.pi
    np.testing.assert_allclose(implied_errors(nominal, calibrated), x, atol=1e-12)
    check_nominal(calibrated, nominal)
    assert "within +-pi: 0.1168146928" in dh_degrees_problem(6.4)
    assert "within +-pi" not in dh_degrees_problem(90.0)
