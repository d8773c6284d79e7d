"""Outputs a calibration engineer acts on: what a report says of a result identified elsewhere
(``iwr report`` of an ``iwr-calibrate`` run), the status a calibration file records."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile

import numpy as np
import pytest

import iwr
from iwr.calibration import STOPPED_CAUSE, from_result
from iwr.reporting.calibration import render

NOISE = iwr.Noise.realistic()


def test_a_stopped_run_whose_fit_test_passes_says_it_did_not_converge():
    """The chi-square test minimises to first order around the point it is given, so it passes
    at a DE run's best point after two generations (weighted cost 4.5e6 against 385 at the
    linearised minimum): its verdict said "the model fits the data" of a run far from the
    solution. A stopped run's passing verdict now begins with STOPPED_FIT, for DE and for the
    efficient estimator's iteration limit; a converged run's does not."""
    from iwr.result import STOPPED_FIT

    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 60, seed=4, noise=NOISE)
    de = iwr.identify(robot, data, "de", generations=2, polish=False, noise=NOISE, seed=1)
    assert de.status == "stopped" and not de.success and de.fun > 1e5
    assert de.fit.fit_ok and de.fit.verdict.startswith(STOPPED_FIT + "the model fits the data")
    eff = iwr.identify(robot, data, noise=NOISE, max_evaluations=2)
    assert eff.status == "stopped" and eff.fit.fit_ok
    assert eff.verdict == eff.fit.verdict and eff.verdict.startswith(STOPPED_FIT)
    done = iwr.identify(robot, data, noise=NOISE)
    assert done.success and done.fit.verdict.startswith("the model fits the data")
    # A weighted engine run (iwr-calibrate --noise) is tested by iwr report (_weighted_fit):
    # stopped at its generation limit near the minimum, its passing verdict says so too.
    weighted = iwr.identify(robot, data, "lm", noise=NOISE)
    engine = iwr.IdentificationResult(**dict(weighted))
    engine.update(fit=None, success=False, status="stopped",
                  message="the maximum number of generations (30) was reached",
                  settings={**weighted.settings, "weighting": "the noise model"})
    fit = from_result(robot, data, engine).result.fit
    assert fit.fit_ok and fit.verdict.startswith(STOPPED_FIT + "the model fits"), fit.verdict


def test_a_stopped_run_that_does_not_fit_says_to_run_it_longer_first(capsys):
    """A weighted DE run that its last generation stopped far from the solution: the report
    said "the model does not fit the data" and nothing else (the fit test and the outlier test
    of its best point blame the model and clean poses: on a simulated ballbar run of 30
    generations, 2 clean poses named). Its first cause is now that the run did not converge, and
    the method line says so; a converged result that does not fit keeps the old words."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 20, seed=3, noise=NOISE)
    job = iwr.identify(robot, data, "lm", noise=NOISE,
                       active=iwr.identifiability(robot, data).active)
    stopped = iwr.IdentificationResult(**dict(job))
    stopped.update(fit=None, success=False, status="stopped", fun=50 * job.fun,
                   message="the maximum number of generations (30) was reached",
                   settings={**job.settings, "weighting": "the noise model"})
    cal = from_result(robot, data, stopped)
    assert cal.fit_ok is False and cal.result.fit.causes[0] == STOPPED_CAUSE
    report = render(cal)
    assert report.status_text() == ("not converged (status stopped), and its best point does not "
                                    "fit the data")
    text = report.text()
    assert "run it to convergence" in text
    assert ("VERDICT: NOT CONVERGED, AND ITS BEST POINT DOES NOT FIT THE DATA; the accuracy "
            "figures above are not a calibration") in text
    assert report.verdict()[0].startswith("Not converged, and its best point does not fit")
    from iwr.cli.calibrate import _exit_code

    capsys.readouterr()
    assert _exit_code(cal, "iwr report", converged=False) == 3  # the fit failed: exit 3
    assert "iwr report: not converged, and its best point does not fit the data (run it longer " \
        "first) (exit 3)" in capsys.readouterr().err
    converged = iwr.IdentificationResult(**dict(stopped))
    converged.update(success=True, status="converged", message="converged")
    cal = from_result(robot, data, converged)
    assert cal.fit_ok is False and STOPPED_CAUSE not in cal.result.fit.causes
    report = render(cal)
    assert report.status_text() == "the model does not fit the data"
    assert "VERDICT: THE MODEL DOES NOT FIT THE DATA" in report.text()


def test_too_few_identification_poses_are_not_called_a_model_that_does_not_fit():
    """Most poses held out (``--validation-fraction 0.9``): 5 identification poses, no
    redundancy for the fit test. The job says "not calibrated: degenerate data ... measure more
    poses" (exit 5), and the summary's last line said "VERDICT: THE MODEL DOES NOT FIT THE DATA",
    which sends an engineer looking for a missing effect; it now says what the job says."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 50, seed=3, noise=NOISE)
    cal = iwr.calibrate(robot, data, "lm", noise=NOISE, validation_fraction=0.9, seed=0,
                        progress=False)
    assert cal.status == "not calibrated" and "degenerate data" in str(cal.result.message)
    assert cal.fit_ok is False
    text = render(cal).text()
    assert "VERDICT: NOT CALIBRATED (degenerate data); the accuracy figures above are not a " \
        "calibration" in text, text
    assert "VERDICT: THE MODEL DOES NOT FIT THE DATA" not in text


def test_every_kind_says_which_parameters_are_angles_with_effects(kind_case):
    """The pose kind's angle mask left out the effects' parameters (58 for a layout of 65): `iwr
    compare` and `iwr study` of a robot with effects on pose data stopped with an internal
    IndexError. Every kind's mask has the layout of x: the robot's, the effects', the set-up's."""
    from iwr.effects import api
    from iwr.effects import parameter_names as effect_names
    from iwr.experiments.compare import compare_methods

    for name in ("pose", "points", "ballbar"):
        case = kind_case(name, n_poses=1)
        robot = case.robot.with_effects(*api.realistic(case.robot))
        mask = case.kind.angle_parameters(robot)
        n_eff = len(effect_names(robot.effects))
        assert mask.shape == (case.kind.n_params(robot) + n_eff,)
        assert not mask[robot.n_params: robot.n_params + n_eff].any()
        assert (mask[:robot.n_params] == robot.angle_parameters).all()
    robot = iwr.Robot.default()
    robot = robot.with_effects(*api.realistic(robot))
    comp = compare_methods(robot, 16, seeds=[0], methods=["lm"], budget=200, start="near",
                           out=None, n_validation=5, progress=False)
    row = comp.runs[0]
    assert row["status"] != "failed", row.get("message")
    assert np.isfinite(row["raw_error_length"]) and np.isfinite(row["raw_error_angle"])


def test_compare_takes_a_ballbar_robot_files_noise_as_calibrate_does(kind_case, tmp_path,
                                                                    monkeypatch):
    """`iwr compare --robot BALLBAR.toml` with a [noise] table (a ballbar's: position 0) passed
    the file's iwr.Noise on, read as an experiment's level: the bar exact, and every efficient
    run refused ("BallbarNoise.distance: 0"). The file's model is now the one iwr calibrate and
    iwr simulate take: the readings' noise and the bar's default."""
    from iwr.ballbar import BallbarNoise
    from iwr.cli import compare as cli_compare
    from iwr.cli import main as cli_main

    robot = kind_case("ballbar", n_poses=1).robot.with_noise(
        iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6))
    robot.to_toml(tmp_path / "robot.toml")
    seen = {}

    def fake(**kwargs):
        seen.update(kwargs)
        raise KeyboardInterrupt  # the run itself is not this test's

    monkeypatch.setattr(cli_compare, "compare_methods", fake)
    cli_main(["compare", "--robot", str(tmp_path / "robot.toml"), "--poses", "60",
              "--methods", "efficient", "--no-progress", "-o", str(tmp_path / "c")])
    readings, bar = seen["noise"]
    assert readings.legs == 0.002 and bar == BallbarNoise()


def test_export_refuses_an_unverified_calibration_as_legs_does(kind_case, tmp_path, capsys):
    """`iwr export` wrote a controller's files (genhexkins.hal, the leg corrections) from a
    calibration whose fit failed, silently; `iwr legs` refuses it. Now the same rule, and after
    a ballbar calibration the same note on the frames it does not determine."""
    from iwr.cli import main as cli_main

    failed = iwr.Robot.default()
    failed.provenance = {"method": "lm", "status": "failed fit test",
                         "status_detail": "THE MODEL DOES NOT FIT THE DATA"}
    failed.to_toml(tmp_path / "failed.toml")
    capsys.readouterr()
    assert cli_main(["export", str(tmp_path / "failed.toml"), "-o", str(tmp_path / "e")]) == 1
    assert "records status 'failed fit test'" in capsys.readouterr().err
    assert not (tmp_path / "e").exists()
    assert cli_main(["export", str(tmp_path / "failed.toml"), "-o", str(tmp_path / "e"),
                     "--allow-unverified"]) == 0
    assert "used because --allow-unverified was given" in capsys.readouterr().out
    assert (tmp_path / "e" / "genhexkins.hal").is_file()
    ballbar = kind_case("ballbar", n_poses=1).robot
    ballbar.provenance = {"method": "lm", "status": "success"}
    ballbar.to_toml(tmp_path / "ballbar.toml")
    assert cli_main(["export", str(tmp_path / "ballbar.toml"), "-o", str(tmp_path / "b")]) == 0
    assert "determine neither the world frame {0} nor the platform frame {5}" \
        in capsys.readouterr().out


def test_poses_of_weight_zero_count_in_no_figure():
    """docs/data.md: weight 0 for a pose's six legs leaves it out and keeps its row visible. The
    job left such poses out of the fit but kept them in its sets, so the accuracy was taken over
    them: 11 of 100 poses at weight 0, one leg 5 mm off in each, gave a calibrated position
    error of 1.79 mm rms with nothing held out (0.036 mm without them), with exit 0 and no word.
    They are now out of every set and figure, counted in the report, and ``iwr report`` of the
    run (``from_result`` on the whole file) leaves them out alike."""
    robot = iwr.Robot.default()
    clean, _ = iwr.simulate(robot, 60, seed=8, noise=NOISE)
    w = np.ones((60, 6))
    w[10:21] = 0.0
    legs = clean.legs.copy()
    legs[10:21, 3] += 5.0
    data = iwr.Measurements(clean.q, clean.poses, legs, joint_types=robot.joint_types,
                            weights=w)
    cal = iwr.calibrate(robot, data, "lm", validation_fraction=0.0, seed=1)
    assert cal.weightless == 11 and len(cal.identification) == 49
    assert cal.accuracy.calibrated.summary()["position_mm"]["max"] < 0.2
    said = "49 poses for identification (11 more with weight 0 for every reading, left out)"
    assert said in render(cal).markdown([])
    again = from_result(robot, data, cal.result)
    assert again.weightless == 11 and len(again.identification) == 49
    a = cal.accuracy.calibrated.summary()["position_mm"]
    b = again.accuracy.calibrated.summary()["position_mm"]
    assert a == pytest.approx(b, rel=1e-9, abs=1e-12), (a, b)
    # A validation set's such poses (none of them in the identification set): out of the
    # accuracy figures, with a note.
    held = iwr.calibrate(robot, clean.subset(np.arange(30, 60)), "lm",
                         validation=data.subset(np.arange(30)), seed=1)
    assert len(held.validation) == 19
    assert any("11 pose(s) of the validation data have weight 0" in n for n in held.notes)
    assert not any("also in the data" in n for n in held.notes)
    # And with a split: the weight-0 poses are out before it, so both parts count.
    split = iwr.calibrate(robot, data, "lm", validation_fraction=0.5, seed=3)
    assert (len(split.identification), len(split.validation), split.weightless) == (25, 24, 11)
    assert all((np.asarray(s.weights) > 0).any(axis=1).all()
               for s in (split.identification, split.validation))


def test_a_validation_set_must_be_held_out():
    """``--validation`` naming the data file itself was taken, and its accuracy was reported as
    on "100 held out for validation" poses (a QA run). Every validation pose among the data:
    refused, by the job and by ``iwr report``'s ``from_result``; some: a note says how many."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 40, seed=9, noise=NOISE)
    first = data.subset(np.arange(30))
    with pytest.raises(ValueError, match="every one of its poses is also in the data"):
        iwr.calibrate(robot, data, "lm", validation=data.subset(np.arange(5, 12)))
    cal = iwr.calibrate(robot, first, "lm", validation=data.subset(np.arange(25, 40)))
    assert any("5 of the 15 validation poses are also in the data" in n for n in cal.notes)
    with pytest.raises(ValueError, match="every one of its poses is also in the data"):
        from_result(robot, first, cal.result, validation=first)


def test_a_tracker_recalibration_is_not_judged_against_a_flattered_nominal():
    """The "before" of tracker data was the nominal robot in a registration fitted to the
    validation poses themselves, which flatters it: re-calibrating a calibrated robot on its own
    data (errors found: 0) was judged "not calibrated" (exit 5, and ``iwr legs`` refused it) in
    10 of 12 seeds, its after/before 1.05-1.21. "Before" is now in the registration guess the
    identification started from; the same re-calibration gives after/before 1.000 (12 of 12)."""
    from pathlib import Path

    from iwr.tracker.analysis import calibrated_robot

    robot = iwr.Robot.from_toml(Path(__file__).resolve().parents[1] / "examples"
                                / "iwr_tracker.toml")
    noise = iwr.kinds.for_robot(robot).experiment_noise(robot, NOISE)
    data, _ = iwr.simulate(robot, 40, seed=1, noise=noise)
    first = iwr.calibrate(robot, data, seed=1, progress=False)
    assert first.status == "converged" and first.held_out
    again = iwr.calibrate(calibrated_robot(robot, first.result.x)[0], data, seed=1,
                          progress=False)
    before, after, _, _ = again.improvement()
    assert again.status == "converged", again.result.message
    assert after == pytest.approx(before, rel=1e-6)


def test_a_report_of_a_job_result_file_gives_the_jobs_figures(tmp_path):
    """``iwr report`` of an ``iwr calibrate`` run read "50 for identification, none held out"
    where the run held 10 out, and called the 6 parameters the run held at nominal "identified,
    but not identifiable: arbitrary" (a QA run): the result file kept neither the split nor the
    active parameters. It keeps both now, and the report of the file gives the job's sets,
    figures and parameter statuses."""
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 50, seed=2, noise=NOISE)
    cal = iwr.calibrate(robot, data, noise=NOISE, seed=4)
    assert cal.held_out and len(cal.validation) == 10
    cal.result.save(tmp_path / "result.json")
    loaded = iwr.load_result(tmp_path / "result.json")
    np.testing.assert_array_equal(loaded.active, cal.result.active)
    again = from_result(robot, data, loaded)
    assert again.held_out
    assert iwr.result.pose_keys(again.validation) == iwr.result.pose_keys(cal.validation)
    assert iwr.result.pose_keys(again.identification) == iwr.result.pose_keys(cal.identification)
    a = cal.accuracy.calibrated.summary()["position_mm"]
    b = again.accuracy.calibrated.summary()["position_mm"]
    assert a == pytest.approx(b, rel=1e-9, abs=1e-12), (a, b)
    status = [r["status"] for r in render(cal).parameter_rows()]
    assert [r["status"] for r in render(again).parameter_rows()] == status
    assert status.count("held at nominal (not identifiable)") == 6
    # A run whose split had no seed: not made again, and said so.
    unseeded = iwr.calibrate(robot, data, "lm", seed=None)
    assert unseeded.result.settings["validation_split"]["seed"] is None
    plain = from_result(robot, data, unseeded.result)
    assert not plain.held_out and any("without a seed" in n for n in plain.notes)
    # A run that held out a file of its own: the report says to give it.
    held = iwr.calibrate(robot, data.subset(np.arange(40)), "lm",
                         validation=data.subset(np.arange(40, 50)))
    other = from_result(robot, data.subset(np.arange(40)), held.result)
    assert not other.held_out
    assert any("give it (--validation)" in n for n in other.notes)


def test_a_report_of_a_tracker_run_with_gross_errors_gives_the_jobs_before(tmp_path):
    """The job's "before" is the nominal robot in the registration guess of its identification
    poses before the screen; ``from_result`` took the guess after leaving the run's gross errors
    out, so ``iwr report`` of a run with a typo said 7.71 mm where the job said 7.79 (the
    review's case: one reflector 8 mm off in two poses)."""
    from pathlib import Path

    robot = iwr.Robot.from_toml(Path(__file__).resolve().parents[1] / "examples"
                                / "iwr_tracker.toml")
    noise = iwr.kinds.for_robot(robot).experiment_noise(robot, NOISE)
    data, _ = iwr.simulate(robot, 40, seed=5, noise=noise)
    data.points[[4, 9], 0, 0] += 8.0
    cal = iwr.calibrate(robot, data, seed=0, progress=False)
    assert any(o.removed for o in cal.result.left_out)
    cal.result.save(tmp_path / "result.json")
    again = from_result(robot, data, iwr.load_result(tmp_path / "result.json"))
    for which in ("nominal", "calibrated"):
        a = getattr(cal.accuracy, which).summary()["position_mm"]
        b = getattr(again.accuracy, which).summary()["position_mm"]
        assert a == pytest.approx(b, rel=1e-9, abs=1e-12), (which, a, b)


def test_the_before_panels_share_the_after_panels_units_for_a_calibrated_robot():
    """The accuracy figures' "before" panels are in mm and degrees (an uncalibrated robot's
    errors); for a robot already calibrated (a re-calibration) they said "0.0374 mm" beside the
    "after" panel's "44.9 um": now um and arcsec there too."""
    from iwr.reporting.figures import before_units

    assert before_units([17.0, 18.0], [0.8, 1.2]) == (("mm", 1.0), ("deg", 1.0))
    assert before_units([0.03, 0.05, np.nan], [0.002, 0.004]) == (("um", 1000.0),
                                                                 ("arcsec", 3600.0))
    assert before_units([0.03], None)[1] == ("deg", 1.0)
    assert before_units([np.nan])[0] == ("mm", 1.0)  # nothing to judge by: as before


def test_a_stopped_run_on_data_that_cannot_identify_the_robot_says_why_first():
    """A run stopped by its limit on eight poses: running longer would not help, and the
    first cause (the verdict's reason) is the data's, not "run it to convergence"."""
    from iwr.fit_test import CANNOT_IDENTIFY

    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 8, seed=3, noise=NOISE)
    job = iwr.identify(robot, data, "lm", noise=NOISE)
    assert not job.success and job.fit.verdict == CANNOT_IDENTIFY
    stopped = iwr.IdentificationResult(**dict(job))  # as a weighted iwr-calibrate run's
    stopped.update(fit=None, status="stopped",
                   message="the maximum number of generations (30) was reached",
                   settings={**job.settings, "weighting": "the noise model"})
    fit = from_result(robot, data, stopped).result.fit
    assert fit.verdict == CANNOT_IDENTIFY and STOPPED_CAUSE not in fit.causes, fit.causes
    assert fit.causes[0].startswith("degenerate data: the 8 distinct identification poses "
                                    "identify 48 of the 52 parameters"), fit.causes


def test_a_result_with_another_number_of_parameter_names_is_refused_with_the_counts():
    """``parameter_names`` one short of ``x`` (a hand-edited file): the error said "zip()
    argument 2 is longer than argument 1"."""
    from iwr import kinds
    from iwr.calibration import check_result

    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 20, seed=3, noise=NOISE)
    res = iwr.identify(robot, data, "lm")
    res.update(parameter_names=list(res.parameter_names)[:-1])
    with pytest.raises(ValueError, match=r"parameter_names has 57 names for the 58 values of x"):
        check_result(robot, kinds.of(data), res)


@pytest.mark.parametrize("weighted", [False, True], ids=["eq10", "weighted"])
def test_polish_of_an_unpolished_de_run_is_identifys_polish(weighted):
    """iwr-calibrate's DE run is not polished and stops at its generation limit ("not
    converged": iwr legs refuses its calibration file, and the README's long run ended there).
    iwr.calibration.polish refines it as iwr.identify(method="de") does: the same point, cost and
    status as the DE run polished in one call (same seed, generations and objective)."""
    from iwr.calibration import polish

    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 40, seed=6, noise=NOISE)
    noise = {"noise": NOISE} if weighted else {}
    run = iwr.identify(robot, data, "de", generations=40, seed=3, polish=False, **noise)
    assert run.status == "stopped" and not run.success
    once = iwr.identify(robot, data, "de", generations=40, seed=3, **noise)
    polished = polish(robot, data, run)
    assert polished.status == once.status == "converged" and polished.success
    np.testing.assert_allclose(polished.x, once.x, rtol=0, atol=1e-12)
    assert polished.fun == pytest.approx(once.fun, rel=1e-12)
    assert polished.settings["polish_result"]["fun_before"] == run.fun > polished.fun
    assert polished.nfev == once.nfev
    with pytest.raises(ValueError, match="polished already"):
        polish(robot, data, polished)
    with pytest.raises(ValueError, match=r"a result of 'lm': only a global search's"):
        polish(robot, data, iwr.identify(robot, data, "lm"))
    # Ctrl-C skipped the job's gross-error screen: resume first (a second review).
    interrupted = iwr.IdentificationResult(**dict(run))
    interrupted.update(status="interrupted")
    with pytest.raises(ValueError, match=r"the run was interrupted .*resume it, then polish"):
        polish(robot, data, interrupted)


def test_a_polish_keeps_the_bounds_the_run_searched_within():
    """A result of iwr.identify recorded no bounds (iwr-calibrate's did), so the polish of a DE
    run within the paper's bounds tested its fit against the default ones: an error of 8 degrees
    (within ten times the paper's 0.5 rad, beyond ten times the default 0.5 degree) made the
    polish "THE MODEL DOES NOT FIT THE DATA". Every method's result now records its bounds."""
    from iwr.calibration import polish

    robot = iwr.Robot.default()
    x = np.zeros(robot.n_params)
    x[robot.parameter_names.index("joint2.dalpha")] = np.radians(8.0)
    data, _ = iwr.simulate(robot, 40, seed=6, x=x, noise=NOISE)
    run = iwr.identify(robot, data, "de", bounds="paper", generations=20, seed=3, polish=False)
    assert run.settings["bounds"] == "paper"
    polished = polish(robot, data, run)
    assert polished.status == "converged" and polished.fit.fit_ok
    assert polished.settings["bounds"] == "paper"
    # A result file of before (no record) is polished within the default bounds: that fit fails.
    old = iwr.IdentificationResult(**dict(run))
    old.update(settings={k: v for k, v in dict(run.settings).items() if k != "bounds"})
    assert not polish(robot, data, old).fit.fit_ok
    # Custom bounds are recorded whole.
    lo, hi = robot.default_bounds("default")
    lm = iwr.identify(robot, data, "lm", bounds=(20 * lo, 20 * hi))
    assert lm.settings["bounds"] == "custom" and lm.fit.fit_ok
    np.testing.assert_array_equal(lm.settings["upper"], 20 * hi)


def test_the_polish_of_a_job_fits_its_identification_poses_only():
    """A job's DE run without polish (iwr calibrate --method de --no-polish) held poses out: the
    polish of iwr report refits on the identification poses alone, so that the held-out
    accuracy stays held out (on every pose of DATA it was a third too optimistic: the review)."""
    from iwr.calibration import polish

    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 40, seed=6, noise=NOISE)
    cal = iwr.calibrate(robot, data, "de", generations=10, seed=3, polish=False)
    assert cal.held_out and cal.status == "stopped"
    report = from_result(robot, data, cal.result, polish=True)
    assert report.result.success
    own = polish(robot, cal.identification, cal.result)
    np.testing.assert_array_equal(report.result.x, own.x)
    everything = polish(robot, data, cal.result)
    assert np.abs(everything.x - own.x).max() > 1e-6  # another fit: DATA holds the held-out


def test_iwr_report_polish_turns_a_de_run_into_a_usable_calibration(tmp_path):
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 40, seed=6, noise=NOISE)
    robot.to_toml(tmp_path / "robot.toml")
    data.to_csv(tmp_path / "data.csv")
    iwr.identify(robot, data, "de", generations=40, seed=3, polish=False).save(
        tmp_path / "run.json")
    env = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}

    def report(out: str, *more: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "iwr", "report", str(tmp_path / "run.json"),
                               str(tmp_path / "robot.toml"), str(tmp_path / "data.csv"), "--out",
                               str(tmp_path / out), "--no-plots", *more], capture_output=True,
                              text=True, cwd=tempfile.gettempdir(), env=env, timeout=600)

    plain = report("plain")
    assert plain.returncode == 0, plain.stderr
    status = iwr.Robot.from_toml(tmp_path / "plain" / "calibrated.toml").provenance["status"]
    assert status == "not converged"
    done = report("done", "--polish")
    assert done.returncode == 0, done.stderr
    assert "polished by Levenberg-Marquardt: converged" in done.stdout
    assert iwr.Robot.from_toml(tmp_path / "done" / "calibrated.toml").provenance[
        "status"] == "success"


def test_a_stopped_run_s_calibration_file_says_where_its_fit_was_tested(tmp_path):
    """calibrated.toml of a run stopped after 2 evaluations (cost 6089 mm^2) recorded
    fit_test = "passed" (an outside check); it now says the test was of the point where the
    method stopped. A converged run's says "passed"."""
    import tomllib

    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, 40, seed=6, noise=NOISE)
    for budget, want in ((2, "passed at the point the method stopped (not converged)"),
                         (None, "passed")):
        cal = iwr.calibrate(robot, data, "lm", max_evaluations=budget)
        render(cal).write(tmp_path / str(budget))
        prov = tomllib.loads((tmp_path / str(budget) / "calibrated.toml").read_text())
        assert prov["provenance"]["fit_test"] == want
