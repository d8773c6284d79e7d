"""``iwr export`` (iwr.export): every file read back by an implementation that is not iwr's model:
the genhexkins numbers by a few lines of inverse kinematics written from genhexkins's definition
(strut length = |p + R platform - base|, R = Rz(C) Ry(B) Rx(A) of the pose words in degrees),
the URDF by yourdfpy's forward kinematics."""

from __future__ import annotations

import csv
import json
import math
import re

import numpy as np
import pytest
import yourdfpy

import iwr
from iwr.cli import main
from iwr.export import carriage_urdf, genhexkins_hal, hexapod_dict, link_names
from iwr.transforms import pose_from_matrix, pose_matrix

N_POSES = 100
TOL_MM = 1e-9


@pytest.fixture(scope="module")
def calibrated():
    """A nominal IWR, a random error vector within the default bounds, the calibrated robot."""
    nominal = iwr.Robot.default()
    lo, hi = nominal.default_bounds()
    x = np.random.default_rng(25).uniform(lo, hi)
    return nominal, x, nominal.with_errors(x)


def _read_hal(text: str) -> tuple[np.ndarray, np.ndarray]:
    """base (6, 3) and platform (6, 3) from the ``setp genhexkins...`` lines, each set once."""
    base, plat = np.full((6, 3), np.nan), np.full((6, 3), np.nan)
    seen = set()
    for line in text.splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        m = re.fullmatch(r"setp genhexkins\.(base|platform)\.([0-5])\.([xyz]) (\S+)", line)
        assert m, line
        assert m.group(0) not in seen
        seen.add(m.group(0))
        which = base if m.group(1) == "base" else plat
        which[int(m.group(2)), "xyz".index(m.group(3))] = float(m.group(4))
    assert len(seen) == 36
    return base, plat


def _rpy_deg(a: float, b: float, c: float) -> np.ndarray:
    """genhexkins's rotation (pmRpyMatConvert): Rz(C) Ry(B) Rx(A), angles in degrees."""
    a, b, c = (math.radians(v) for v in (a, b, c))
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _genhex_inverse(base: np.ndarray, plat: np.ndarray, xyzabc: np.ndarray) -> np.ndarray:
    """genhexKinematicsInverse without screw-lead correction: the six strut lengths."""
    r = _rpy_deg(*xyzabc[3:])
    return np.linalg.norm(xyzabc[:3] + plat @ r.T - base, axis=1)


def _random_poses(robot, rng, n):
    lo, hi = robot.home_pose - robot.workspace, robot.home_pose + robot.workspace
    return rng.uniform(lo, hi, size=(n, 6))


def test_genhexkins_leg_lengths_equal_iwr_model(calibrated):
    nominal, x, cal = calibrated
    base, plat = _read_hal(genhexkins_hal(cal, "calibrated.toml"))
    rng = np.random.default_rng(7)
    poses4 = _random_poses(nominal, rng, N_POSES)  # {5} in {4}
    q = rng.uniform(nominal.joint_limits[:, 0], nominal.joint_limits[:, 1],
                    size=(N_POSES, nominal.n_joints))
    # iwr's calibrated model on the whole robot: the nominal robot with the errors x, the
    # platform pose in {0} through the calibrated carriage.
    t04 = np.array([nominal.carriage_transform(qk, x) for qk in q])
    poses0 = pose_from_matrix(t04 @ pose_matrix(poses4))
    lengths_iwr = iwr.predict_legs(nominal, x, q, poses0) + cal.leg_offsets
    worst = 0.0
    for p, want in zip(poses4, lengths_iwr, strict=True):
        words = np.array([*p[:3], *np.degrees([p[5], p[4], p[3]])])  # X Y Z A B C
        worst = max(worst, float(np.max(np.abs(_genhex_inverse(base, plat, words) - want))))
    assert worst < TOL_MM
    # and the numbers are the calibrated ones (not a model that happens to agree)
    assert np.array_equal(base, cal.base_joints)
    assert np.array_equal(plat, cal.platform_joints)


def test_json_holds_the_same_numbers_and_offsets(calibrated):
    _, _, cal = calibrated
    doc = json.loads(json.dumps(hexapod_dict(cal)))
    base, plat = _read_hal(genhexkins_hal(cal))
    assert doc["units"] == {"length": "mm", "angle": "rad"}
    assert "{4}" in doc["frames"] and "{5}" in doc["frames"]
    for j, leg in enumerate(doc["legs"]):
        assert leg["leg"] == j + 1
        assert leg["base_joint"] == base[j].tolist()
        assert leg["platform_joint"] == plat[j].tolist()
        assert leg["leg_offset"] == float(cal.leg_offsets[j])


def test_urdf_forward_kinematics_by_yourdfpy_equals_iwr(calibrated, tmp_path):
    nominal, x, cal = calibrated
    path = tmp_path / "carriage.urdf"
    path.write_text(carriage_urdf(cal, "calibrated.toml"))
    urdf = yourdfpy.URDF.load(str(path), load_meshes=False, build_collision_scene_graph=False)
    assert set(urdf.link_map) == set(link_names(cal))
    rng = np.random.default_rng(11)
    worst_p = worst_r = 0.0
    for _ in range(N_POSES):
        q = rng.uniform(nominal.joint_limits[:, 0], nominal.joint_limits[:, 1])
        urdf.update_cfg({f"joint{i + 1}": q[i] / 1000.0 if t == "P" else q[i]
                         for i, t in enumerate(nominal.joint_types)})
        t = urdf.get_transform("hexapod_base", "base_link")
        want = nominal.carriage_transform(q, x)
        worst_p = max(worst_p, float(np.max(np.abs(1000.0 * t[:3, 3] - want[:3, 3]))))
        worst_r = max(worst_r, float(np.max(np.abs(t[:3, :3] - want[:3, :3]))))
        leg = urdf.get_transform("leg3_base_joint", "base_link")[:3, 3] * 1000.0
        worst_p = max(worst_p, float(np.max(np.abs(
            leg - (want[:3, :3] @ cal.base_joints[2] + want[:3, 3])))))
    assert worst_p < TOL_MM
    assert worst_r < 1e-12


def test_urdf_joint_limits_in_urdf_units(calibrated, tmp_path):
    _, _, cal = calibrated
    (tmp_path / "c.urdf").write_text(carriage_urdf(cal))
    urdf = yourdfpy.URDF.load(str(tmp_path / "c.urdf"), load_meshes=False)
    for i, t in enumerate(cal.joint_types):
        joint = urdf.joint_map[f"joint{i + 1}"]
        scale = 1000.0 if t == "P" else 1.0
        assert joint.type == ("prismatic" if t == "P" else "revolute")
        assert joint.limit.lower == pytest.approx(cal.joint_limits[i, 0] / scale, abs=1e-15)
        assert joint.limit.upper == pytest.approx(cal.joint_limits[i, 1] / scale, abs=1e-15)


def _export_with_nominal(calibrated, tmp_path, grid: int):
    """``iwr export calibrated.toml --nominal robot.toml --grid GRID`` of the fixture's robots
    into tmp_path/exp; the folder."""
    nominal, _, cal = calibrated
    nominal.to_toml(tmp_path / "robot.toml")
    cal.to_toml(tmp_path / "calibrated.toml")
    out = tmp_path / "exp"
    assert main(["export", str(tmp_path / "calibrated.toml"), "-o", str(out), "--nominal",
                 str(tmp_path / "robot.toml"), "--grid", str(grid)]) == 0
    return out


def test_cli_export_writes_every_file_and_the_table(calibrated, tmp_path, capsys):
    nominal, _, cal = calibrated
    out = _export_with_nominal(calibrated, tmp_path, 2)
    assert {p.name for p in out.iterdir()} == {"genhexkins.hal", "hexapod.json",
                                               "carriage.urdf", "leg_corrections.csv"}
    assert "64 poses" in capsys.readouterr().out
    text = (out / "leg_corrections.csv").read_text()
    assert "{5} in the hexapod base frame {4}" in text
    rows = list(csv.DictReader(line for line in text.splitlines() if not line.startswith("#")))
    assert len(rows) == 2 ** 6
    base_c, plat_c = _read_hal((out / "genhexkins.hal").read_text())
    base_n, plat_n = _read_hal(genhexkins_hal(nominal))
    worst = 0.0
    for row in rows:
        p = np.array([float(row[c]) for c in ("x_mm", "y_mm", "z_mm", "alpha_rad", "beta_rad",
                                              "gamma_rad")])
        words = np.array([*p[:3], *np.degrees([p[5], p[4], p[3]])])
        s_cal = _genhex_inverse(base_c, plat_c, words) - cal.leg_offsets
        s_nom = _genhex_inverse(base_n, plat_n, words) - nominal.leg_offsets
        ds = np.array([float(row[f"ds{j}_mm"]) for j in range(1, 7)])
        worst = max(worst, float(np.max(np.abs(ds - (s_cal - s_nom)))))
        inside = np.all((s_cal >= cal.leg_stroke[:, 0]) & (s_cal <= cal.leg_stroke[:, 1]))
        assert int(row["within_stroke"]) == int(inside)
    assert worst < TOL_MM
    # the corner poses of the grid are home_pose +- workspace
    first = [float(rows[0][c]) for c in ("x_mm", "z_mm", "gamma_rad")]
    assert first == pytest.approx([cal.home_pose[0] - cal.workspace[0],
                                   cal.home_pose[2] - cal.workspace[2],
                                   cal.home_pose[5] - cal.workspace[5]])


def test_cli_export_without_nominal_and_hexapod_only(tmp_path, capsys):
    iwr.Robot.hexapod().to_toml(tmp_path / "hexapod.toml")
    out = tmp_path / "exp"
    assert main(["export", str(tmp_path / "hexapod.toml"), "-o", str(out)]) == 0
    said = capsys.readouterr().out
    assert "no carriage.urdf" in said and "give --nominal" in said
    assert {p.name for p in out.iterdir()} == {"genhexkins.hal", "hexapod.json"}


def test_cli_export_refuses_a_nominal_of_another_robot(tmp_path, capsys):
    iwr.Robot.default().to_toml(tmp_path / "robot.toml")
    iwr.Robot.hexapod().to_toml(tmp_path / "hexapod.toml")
    code = main(["export", str(tmp_path / "robot.toml"), "--nominal",
                 str(tmp_path / "hexapod.toml"), "-o", str(tmp_path / "e")])
    assert code == 2
    assert "not the same robot" in capsys.readouterr().err
    assert main(["export", str(tmp_path / "robot.toml"), "--grid", "13", "-o",
                 str(tmp_path / "e")]) == 2


def test_cli_export_refuses_a_nominal_the_calibration_is_not_relative_to(calibrated, tmp_path,
                                                                         capsys):
    """A leg-correction table against the wrong nominal robot is a wrong command for every
    pose: a nominal with one leg offset 50 mm off (another robot of the same joints) gave
    corrections of 50 mm, and the calibrated robot itself given as its own nominal gave zeros.
    Both are refused, naming what differs; the nominal the calibration records passes, and a
    nominal within a calibration's reach of it (the controller's own model) gets a note."""
    from iwr.compensation import NominalMismatchError
    from iwr.export.hexapod import leg_corrections_csv
    from iwr.robot_fingerprint import geometry_fingerprint

    nominal, _, cal = calibrated
    nominal.to_toml(tmp_path / "robot.toml")
    cal.to_toml(tmp_path / "calibrated.toml", provenance={
        "status": "success", "method": "lm", "robot": "robot.toml",
        "nominal_geometry": geometry_fingerprint(nominal)})
    other = iwr.Robot.default()
    other.leg_offsets[0] += 50.0
    other.to_toml(tmp_path / "other.toml")
    near = iwr.Robot.default()
    near.leg_offsets[2] += 0.2
    near.to_toml(tmp_path / "near.toml")

    def export(nom: str) -> tuple[int, str, str]:
        code = main(["export", str(tmp_path / "calibrated.toml"), "--nominal",
                     str(tmp_path / nom), "-o", str(tmp_path / nom.replace(".", "_")),
                     "--grid", "2"])
        said = capsys.readouterr()
        return code, said.out, said.err

    code, _, err = export("other.toml")
    assert code == 2 and "not the nominal robot of" in err and "leg1.dl0 differs by" in err
    assert "calibrated from robot.toml" in err
    assert not (tmp_path / "other_toml").exists()  # refused before anything is written
    code, _, err = export("calibrated.toml")
    assert code == 2 and "every correction would be zero" in err
    code, out, _ = export("robot.toml")
    assert code == 0 and "note:" not in out
    code, out, _ = export("near.toml")
    assert code == 0 and "is not the robot file" in out
    # The library's table refuses too.
    loaded = iwr.Robot.from_toml(tmp_path / "calibrated.toml")
    with pytest.raises(NominalMismatchError, match=r"leg1\.dl0 differs by -(49|50)\.\d+ mm"):
        leg_corrections_csv(loaded, iwr.Robot.from_toml(tmp_path / "other.toml"), 2)


def test_a_tracker_calibrations_gauge_is_not_taken_for_another_robot():
    """Tracker data leave {0} to a gauge choice: a tracker calibration's base joints sit
    millimetres from the nominal ones (7.2 mm in z, seen), beyond the 10x-bounds size that
    refuses another robot after a pose-data calibration. Its recorded nominal passes; another
    nominal (or a file that records none) gets a note, not a refusal; the same difference after
    a pose-data calibration is refused; the calibrated robot itself is refused either way."""
    from iwr.compensation import NominalMismatchError, check_nominal
    from iwr.robot_fingerprint import geometry_fingerprint

    refl = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
    for tracker in (True, False):
        nominal = iwr.Robot.default()
        if tracker:
            nominal = nominal.with_tracker(registration=(2000, 0, 0, 1.5708, 0, 0),
                                           reflectors=refl)
        x = np.zeros(nominal.n_params)
        x[nominal.parameter_names.index("leg2.da_z")] = 7.2
        cal = nominal.with_errors(x)
        other = iwr.Robot.default()
        other.leg_offsets[0] += 0.3  # the controller's own model, say
        for recorded in (geometry_fingerprint(nominal), None):
            prov = {"status": "success", "method": "lm", "robot": "robot.toml"}
            if recorded:
                prov["nominal_geometry"] = recorded
            calibrated = iwr.Robot.from_dict({**cal.to_dict(), "provenance": prov})
            if recorded:
                assert check_nominal(calibrated, nominal) == ""
            if tracker:
                note = check_nominal(calibrated, other)
                assert "leg2.da_z differs by 7.2 mm" in note and "gauge allows" in note
            else:
                with pytest.raises(NominalMismatchError, match="leg2.da_z differs by 7.2 mm"):
                    check_nominal(calibrated, other)
            with pytest.raises(NominalMismatchError, match="every correction would be zero"):
                check_nominal(calibrated, calibrated)


def test_a_robot_with_effects_exports_them_and_says_what_holds_the_geometry_only(
        calibrated, tmp_path, capsys):
    """The effects are not dropped silently: hexapod.json records them, and the command says
    which files hold the geometry only (a controller's genhexkins has no compliance model)."""
    from iwr.effects.api import realistic

    _, _, cal = calibrated
    robot = cal.with_effects(*realistic(cal))
    d = hexapod_dict(robot)
    assert set(d["effects"]) == {e.name for e in robot.effects}
    assert "effects" not in hexapod_dict(cal)
    robot.to_toml(tmp_path / "r.toml")
    assert main(["export", str(tmp_path / "r.toml"), "--out", str(tmp_path / "x")]) == 0
    out = capsys.readouterr().out
    assert "hold the geometry only" in out and "hexapod.json records the effects" in out
    back = json.loads((tmp_path / "x" / "hexapod.json").read_text())
    assert back["effects"] == json.loads(json.dumps(d["effects"]))


def test_a_tracker_calibration_exports_its_registration_and_the_gravity_it_used(
        calibrated, tmp_path, capsys):
    """Tracker data do not fix {0}: the export gave a {0} that is a gauge choice and no way back
    to the tracker frame (the registration was in no file), and hexapod.json recorded the
    compliance's own gravity_m_s2, which tracker data do not use (0.155 mm of leg length off
    with a 120 kg platform: an outside check). The registration is now in hexapod.json and
    carriage.urdf (link tracker, read by yourdfpy), and the gravity is the tracker's carried into
    {0} by it: both checked here against the robot file's numbers by this file's own algebra."""
    from iwr.effects.api import realistic

    _, x, cal = calibrated
    reg = np.array([2000.0, 5.0, -2.0, 1.5708, 0.03, 0.02])
    robot = cal.with_tracker(registration=reg,
                             reflectors=[(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0),
                                         (-60.0, -104.0, 40.0)])
    robot = robot.with_effects(*realistic(robot))
    robot.to_toml(tmp_path / "r.toml")
    assert main(["export", str(tmp_path / "r.toml"), "--out", str(tmp_path / "x")]) == 0
    out = capsys.readouterr().out
    assert "tracker = {T}" in out and "gauge choice" in out and "--frame T" in out
    t_t0 = pose_matrix(reg)  # {0} in {T}: R = Rz(alpha) Ry(beta) Rx(gamma)
    d = json.loads((tmp_path / "x" / "hexapod.json").read_text())
    np.testing.assert_allclose(d["registration"]["T_T0"], t_t0, rtol=0, atol=1e-12)
    g_t = np.array([0.0, 0.0, -9.80665])  # a levelled tracker's, the setup's default
    np.testing.assert_allclose(d["effects"]["compliance"]["gravity_m_s2"], t_t0[:3, :3].T @ g_t,
                               rtol=0, atol=1e-12)
    assert "carried from the tracker's gravity" in d["effects_note"]
    urdf = yourdfpy.URDF.load(str(tmp_path / "x" / "carriage.urdf"), load_meshes=False,
                              build_collision_scene_graph=False)
    t = np.array(urdf.get_transform("tracker", "base_link"))  # {T} in {0}, m
    t[:3, 3] *= 1000.0
    np.testing.assert_allclose(t, np.linalg.inv(t_t0), rtol=0, atol=1e-9)
    for name in ("genhexkins.hal", "carriage.urdf"):
        assert "GEOMETRY ONLY" in (tmp_path / "x" / name).read_text()
    # Pose data fix {0}: no registration, no tracker link.
    assert "registration" not in hexapod_dict(cal)
    assert "tracker" not in link_names(cal)
    # A hexapod alone measured by a tracker: the registration in hexapod.json, no URDF to name.
    hexapod = iwr.Robot.hexapod().with_tracker(registration=reg,
                                               reflectors=[(120.0, 0.0, 40.0)])
    hexapod.to_toml(tmp_path / "h.toml")
    assert main(["export", str(tmp_path / "h.toml"), "--out", str(tmp_path / "h")]) == 0
    out = capsys.readouterr().out
    assert "registration in hexapod.json, as `iwr legs --frame T` does" in out
    assert "registration" in json.loads((tmp_path / "h" / "hexapod.json").read_text())


def test_the_export_folder_is_written_as_a_whole_and_over_its_own_files_only(calibrated,
                                                                             tmp_path, capsys):
    """An outside check found an export of calibration B beside A's leg_corrections.csv (B had
    no --nominal), genhexkins.hal written before hexapod.json failed, and a hand-made
    genhexkins.hal replaced without a word. The folder is now written as a whole
    (iwr._io.write_folder), and files of its names that iwr export did not write are refused."""
    nominal, _, cal = calibrated
    cal.to_toml(tmp_path / "cal.toml")
    nominal.to_toml(tmp_path / "nom.toml")
    out = tmp_path / "x"
    assert main(["export", str(tmp_path / "cal.toml"), "--nominal", str(tmp_path / "nom.toml"),
                 "--out", str(out), "--grid", "2"]) == 0
    assert (out / "leg_corrections.csv").exists()
    assert main(["export", str(tmp_path / "cal.toml"), "--out", str(out)]) == 0  # over its own
    assert sorted(p.name for p in out.iterdir()) == ["carriage.urdf", "genhexkins.hal",
                                                     "hexapod.json"]
    capsys.readouterr()
    hand = tmp_path / "hand"
    hand.mkdir()
    (hand / "genhexkins.hal").write_text("setp genhexkins.screw-lead 5.0  # my own\n")
    (hand / "hexapod.json").mkdir()
    assert main(["export", str(tmp_path / "cal.toml"), "--out", str(hand)]) == 2
    err = capsys.readouterr().err
    assert "genhexkins.hal, hexapod.json are not written by iwr export" in err
    assert (hand / "genhexkins.hal").read_text().endswith("# my own\n")
    assert sorted(p.name for p in hand.iterdir()) == ["genhexkins.hal", "hexapod.json"]


def test_the_tables_interpolation_error_is_what_it_says(calibrated, tmp_path, capsys):
    """The table is read between its poses: an outside check interpolated it multilinearly and
    found a grid of 3 off by 25 um at most, more than the calibration's own error; the export
    now states that figure (and defaults to a grid of 5). Checked here by this file's own
    multilinear interpolation (the 2^6 corners' weights) of the file read back, at 300 random
    poses, against genhexkins's inverse kinematics of the exported numbers."""
    nominal, _, cal = calibrated
    out = _export_with_nominal(calibrated, tmp_path, 3)
    said = re.search(r"off the models by up to (\S+) um, (\S+) um RMS", capsys.readouterr().out)
    worst_said, rms_said = float(said.group(1)), float(said.group(2))
    text = (out / "leg_corrections.csv").read_text()
    assert f"by up to {said.group(1)} um ({said.group(2)} um RMS" in text
    table = np.loadtxt([line for line in text.splitlines() if not line.startswith("#")][1:],
                       delimiter=",")
    axes = [np.unique(table[:, k]) for k in range(6)]
    assert all(a.size == 3 for a in axes)
    ds = table[:, 18:24].reshape(3, 3, 3, 3, 3, 3, 6)  # the last coordinate varies fastest
    base_c, plat_c = _read_hal((out / "genhexkins.hal").read_text())
    base_n, plat_n = _read_hal(genhexkins_hal(nominal))
    rng = np.random.default_rng(5)
    errors = []
    for p in _random_poses(cal, rng, 300):
        cell = [max(min(int(np.searchsorted(a, v)) - 1, a.size - 2), 0)
                for a, v in zip(axes, p, strict=True)]
        t = [(v - a[c]) / (a[c + 1] - a[c]) for a, v, c in zip(axes, p, cell, strict=True)]
        got = np.zeros(6)
        for corner in np.ndindex(*[2] * 6):
            w = np.prod([tk if bit else 1 - tk for tk, bit in zip(t, corner, strict=True)])
            got += w * ds[tuple(c + b for c, b in zip(cell, corner, strict=True))]
        words = np.array([*p[:3], *np.degrees([p[5], p[4], p[3]])])
        exact = ((_genhex_inverse(base_c, plat_c, words) - cal.leg_offsets)
                 - (_genhex_inverse(base_n, plat_n, words) - nominal.leg_offsets))
        errors.append(np.abs(got - exact) * 1000.0)
    errors = np.array(errors)
    assert errors.max() <= 1.05 * worst_said  # 300 poses against the export's 2000
    assert np.sqrt(np.mean(errors**2)) == pytest.approx(rms_said, rel=0.25)
    assert errors.max() > 0.5 * worst_said


def test_a_one_pose_table_states_its_error_over_the_workspace(calibrated):
    """--grid 1: one correction for every pose; it said "off by 0 um" (a review), as nothing is
    interpolated. Its error is the models' own corrections' spread over the workspace."""
    from iwr.export import interpolation_error

    nominal, _, cal = calibrated
    worst, rms = interpolation_error(cal, nominal, 1)
    rng = np.random.default_rng(3)
    at = _random_poses(cal, rng, 500)
    exact = (iwr.export.hexapod_readings(cal, at) - iwr.export.hexapod_readings(nominal, at))
    home = (iwr.export.hexapod_readings(cal, cal.home_pose)
            - iwr.export.hexapod_readings(nominal, cal.home_pose))
    own = np.abs(exact - home)
    assert worst > 0 and own.max() <= 1.05 * worst
    assert np.sqrt(np.mean(own**2)) == pytest.approx(rms, rel=0.15)
    assert interpolation_error(cal, nominal, 5)[0] < worst

