"""The diagnosis of a geometric calibration on double-ballbar data, and the carriage's compliance
among the effects diagnosed on every kind (issue 23, docs/effects.md, "Diagnosis of a geometric
calibration"; iwr/ballbar/diagnosis.py, iwr.effects.job.candidates): the regressors are the
exact derivative of the residuals in each effect's parameters where it is zero (central
differences; noise-free data at the true geometry give back every effect's true size), the
right effect named on noisy data, none on clean data, an effect the data cannot test said so,
and the ballbar job's report carries the section. One fixed seed per case: the false-alarm
rate and the power over seeds are measured in the docs' tables
(benchmarks/effects_diagnosis_instruments.py, benchmarks/effects_diagnosis.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from _ballbar import NOISE, READINGS, ballbar_robot

import iwr
from iwr import kinds
from iwr.ballbar import BallbarMeasurements
from iwr.ballbar import effects as be
from iwr.effects import api, tracker_study
from iwr.effects import tracker as et
from iwr.effects.builtin import LegCompliance, LegThermal
from iwr.effects.carriage_thermal import CarriageThermal
from iwr.effects.job import candidates, diagnose, effect_tests
from iwr.effects.model import predicted_readings
from iwr.effects.tracker_diagnosis import candidate_effects
from iwr.reporting.calibration import render


def _plain(kind: str) -> iwr.Robot:
    robot = iwr.Robot.default()
    if kind == "ballbar":
        return ballbar_robot(base=robot)
    if kind == "points":
        return robot.with_tracker(registration=(2000.0, -150.0, 300.0, 1.5, 0.01, -0.02),
                                  reflectors=[(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0),
                                              (-60.0, -104.0, 40.0)])
    return robot


def _truth(plain: iwr.Robot, on: tuple[str, ...], scale: float = 1.0) -> iwr.Robot:
    """``plain`` with the legs' compliance (0.01 um/N), the legs' expansion (11.5 ppm/K about
    20 C), the carriage's compliance (``realistic(carriage=True)``'s joints and values) and the
    slides' expansion (11.5 ppm/K about 20 C, shared by joints 1 and 2), each at ``scale`` times
    its realistic value when named in ``on``, else 0."""
    comp, _, carriage = api.realistic(plain, carriage=True)
    cc = carriage.values() if "carriage_compliance" in on else np.zeros(carriage.values().size)
    return plain.with_effects(
        LegCompliance(comp.platform_mass, comp.platform_centre, comp.gravity,
                      0.01 * scale if "compliance" in on else 0.0),
        LegThermal(11.5 * scale if "thermal" in on else 0.0, 20.0, identify=True),
        carriage.with_values(scale * cc),
        CarriageThermal(11.5 * scale if "carriage_thermal" in on else 0.0, 20.0, identify=True))


def _simulate(plain, on, n, seed, noise=None, temperatures=None, scale=1.0):
    """Data of ``plain``'s kind from :func:`_truth` (geometric errors and set-up drawn within
    their bounds, the effects' corrections 0) under the study's three payloads; ``(data, x)``
    with ``x`` the truth's geometric errors then set-up (the geometric fit's layout)."""
    truthbot = _truth(plain, on, scale)
    rng = np.random.default_rng(seed)
    lo, hi = plain.default_bounds()
    xg = lo + (hi - lo) * rng.random(plain.n_params)
    ne = 8 + len(truthbot.effects[2].values())
    if plain.instruments.get("ballbar") is not None:
        lo_s, hi_s = be._setup(plain).default_bounds()
        xs = lo_s + (hi_s - lo_s) * rng.random(lo_s.size)
        data, _ = be.simulate(truthbot, n, seed=seed, x=np.concatenate([xg, np.zeros(ne), xs]),
                              noise=noise, payloads=tracker_study.PAYLOADS,
                              temperatures=temperatures)
    elif plain.tracker is not None:
        lo_s, hi_s = plain.tracker.default_bounds()
        xs = lo_s + (hi_s - lo_s) * rng.random(lo_s.size)
        data, _ = et.simulate(truthbot, n, seed=seed, x=np.concatenate([xg, np.zeros(ne), xs]),
                              noise=noise, payloads=tracker_study.PAYLOADS,
                              temperatures=temperatures)
    else:
        xs = np.zeros(0)
        data, _ = api.simulate(truthbot, n, seed=seed, x=np.concatenate([xg, np.zeros(ne)]),
                               noise=noise, payloads=tracker_study.PAYLOADS,
                               temperatures=temperatures)
    return data, np.concatenate([xg, xs])


@pytest.mark.parametrize("kind,n", [("pose", 30), ("points", 25), ("ballbar", 110)])
def test_regressors_are_the_exact_derivative_of_the_residuals(kind, n):
    """Noise-free data with every effect on (a tenth of its realistic size; the temperatures'
    mean at the reference, 20 C), the diagnosis at the true geometry: the residuals are minus
    the effects' change of the readings, which the regressors must reproduce to first order, so
    that each coefficient is the effect's true size (0.01 um/N per leg, 11.5 ppm/K the legs'
    and the slides', the carriage's joints' 0.005 um/N (slides) and 0.02 urad/(N m) (joint 4),
    all times 0.1). The rest is the second order: at the realistic size it moves a slide's
    coefficient on tracker data (weakly determined by three payloads) by 4 %, at a tenth by
    0.4 %. And the columns of the carriage's compliance and of the slides' expansion against
    central differences of the residuals of the objective with the candidate effects."""
    plain = _plain(kind)
    data, x = _simulate(plain, ("compliance", "thermal", "carriage_compliance",
                                "carriage_thermal"), n, seed=11,
                        temperatures=np.linspace(16.0, 24.0, n), scale=0.1)
    d = kinds.of(data).diagnose(plain, data, x)
    est = {t.effect: t for t in d.tests}
    carriage = api.realistic(plain, carriage=True)[2]
    assert est["carriage_compliance"].names == tuple(
        p.removesuffix(".compliance") for p in carriage.parameter_names())
    np.testing.assert_allclose(est["compliance"].estimate, 0.001, rtol=1e-2)
    np.testing.assert_allclose(est["thermal"].estimate, 1.15, rtol=1e-2)
    np.testing.assert_allclose(est["carriage_compliance"].estimate, 0.1 * carriage.values(),
                               rtol=1e-2)
    np.testing.assert_allclose(est["carriage_thermal"].estimate, 1.15, rtol=1e-2)
    assert est["carriage_thermal"].unit == "ppm/K"
    # The carriage's and the slides' columns: central differences of the residuals in their
    # parameters.
    geometric = plain.with_effects()
    cands = (candidate_effects(plain, data, x) if kind == "points"
             else candidates(plain, data))
    probe = geometric.with_effects(*cands.effects)
    ng = plain.n_params
    names = [e.name for e in probe.effects]
    assert names[-1] == "carriage_thermal"  # the data's T_C, the IWR's slides
    at = names.index("carriage_compliance")
    first = ng + sum(len(e.parameter_names()) for e in probe.effects[:at])
    k = len(carriage.values())
    if kind == "pose":
        xf = np.concatenate([x, np.zeros(8 + k)])

        def residuals(v):
            return (predicted_readings(probe, v, data.q, data.poses, data, derivatives=True)[0]
                    - data.legs).reshape(-1)

        jac = predicted_readings(probe, xf, data.q, data.poses, data,
                                 derivatives=True)[1].reshape(-1, xf.size)
    else:
        problem = (be.BallbarEffectProblem(probe, be._setup(geometric), data) if kind ==
                   "ballbar" else et.TrackerEffectProblem(probe, geometric.tracker, data))
        xf = np.concatenate([x[:ng], np.zeros(8 + k), x[ng:]])
        residuals = problem.residuals
        jac = problem.jacobian(xf)
    # urad/(N m) or um/N: micrometres of change; the slides' (the last effect's) ppm/K: a 2 m
    # slide at 4 K from the mean moves by 0.8 um
    for j, step in [(j, 1e-3) for j in range(first, first + k)] + [(first + k, 1e-1)]:
        h = np.zeros(xf.size)
        h[j] = step
        fd = (residuals(xf + h) - residuals(xf - h)) / (2 * step)
        np.testing.assert_allclose(jac[:, j], fd, atol=1e-6 * np.abs(fd).max())
        assert np.abs(fd).max() > 1e-3  # a column that moves


#: A carriage as stiff as an industrial arm's main axis (docs/effects.md, "Realistic
#: magnitudes": 1e7 N m/rad, 0.1 urad/(N m)): five times the realistic carriage's compliance,
#: which ballbar and pose data of a few hundred poses notice only in part of the data sets
#: (the docs' table of the diagnosis's power).
SOFT = 5.0


@pytest.fixture(scope="module")
def soft_carriage():
    """Ballbar data (160 poses in set-ups A and B, every instrument's noise: legs 2 um, joints
    5 um and 5 urad, bar 1 um) of a carriage of :data:`SOFT` times the realistic compliance."""
    plain = _plain("ballbar")
    data, _ = _simulate(plain, ("carriage_compliance",), 160, seed=3, noise=NOISE, scale=SOFT)
    return plain, data


@pytest.mark.parametrize("effect", ["carriage_compliance", "compliance", None])
def test_ballbar_diagnosis_names_the_effect_the_data_carry(effect, soft_carriage):
    """Ballbar data (160 poses) with one effect (the legs' compliance at its realistic size,
    the carriage's at :data:`SOFT` times it) and the payload and temperature columns,
    calibrated geometric-only by the efficient estimator with the true noise model: the
    diagnosis names that effect and not the others (the carriage's compliance and the legs'
    told apart), its coefficient near the truth; clean data name none."""
    plain, data = soft_carriage
    if effect != "carriage_compliance":
        data, _ = _simulate(plain, (effect,) if effect else (), 160, seed=3, noise=NOISE)
    res = iwr.identify(plain, data, "efficient", noise=NOISE, outliers="off")
    d = kinds.of(data).diagnose(plain, data, res.x, active=res.active, noise=NOISE)
    assert d.residuals == "distance" and d.weighting == "whitened by the noise model"
    assert d.suggested == ([effect] if effect else []), [t.line() for t in d.tests]
    assert "bar distances" in d.describe() and "leg length" not in d.describe()
    # gravity the effects' own, in {0}: the assumption says so
    assert "m/s^2 in {0} (the effects' own: a ballbar has no registration" in d.assumptions[0]
    test = {t.effect: t for t in d.tests}
    assert {e: t.dof[0] for e, t in test.items()} == {
        "compliance": 6, "thermal": 1, "carriage_compliance": 1, "carriage_thermal": 1}
    if effect == "compliance":  # the mean of six: its sd about 0.003 um/N at 160 poses
        assert test["compliance"].estimate.mean() == pytest.approx(0.01, abs=0.006)
    elif effect == "carriage_compliance":
        assert test["carriage_compliance"].estimate[0] == pytest.approx(0.02 * SOFT, rel=0.3)


@pytest.mark.parametrize("kind,n,scale", [("pose", 60, SOFT), ("points", 50, 1.0)])
def test_carriage_compliance_named_on_pose_and_tracker_data(kind, n, scale, tmp_path):
    """The carriage's compliance in noisy data (on pose data joint 4 at :data:`SOFT` times the
    realistic 0.02 urad/(N m); on points all four joints at the realistic values, the
    tracker's gravity through the registration loading the slides too), a geometric fit by the
    efficient estimator: the diagnosis names it alone and suggests an
    ``[effects.carriage_compliance]`` table the robot file reads back."""
    plain = _plain(kind)
    noise = (iwr.Noise.realistic() if kind == "pose"
             else (READINGS, iwr.tracker.TrackerNoise.leica()))
    data, _ = _simulate(plain, ("carriage_compliance",), n, seed=4, noise=noise, scale=scale)
    res = iwr.identify(plain, data, "efficient", noise=noise, outliers="off")
    d = kinds.of(data).diagnose(plain, data, res.x, active=res.active, noise=noise)
    assert d.suggested == ["carriage_compliance"], [t.line() for t in d.tests]
    carriage = api.realistic(plain, carriage=True)[2]
    test = next(t for t in d.tests if t.effect == "carriage_compliance")
    # joint 4's: the revolute joint that turns the hexapod in gravity
    assert test.estimate[-1] == pytest.approx(scale * carriage.values()[-1], rel=0.3)
    assert "switch on [effects.carriage_compliance]" in d.lines()[0]
    # How much of the carriage's change beyond the geometry the other effects share: on pose
    # data the legs' six compliances mimic most of joint 4's turn (its test keeps a tenth of
    # its power, and the report says so); on points the joints' patterns stand apart.
    if kind == "pose":
        assert test.own < 0.3 and "so only a large one shows" in test.line()
    else:
        assert test.own > 0.5 and "share" not in test.line()
    path = tmp_path / "robot.toml"
    plain.to_toml(path)
    path.write_text(path.read_text() + "\n" + d.suggestion() + "\n")
    back = iwr.Robot.from_toml(path).effects
    assert [e.name for e in back] == ["carriage_compliance"]
    assert back[0].joints == carriage.joints


def test_ballbar_job_reports_the_diagnosis(soft_carriage):
    """iwr.calibrate with a geometric robot on ballbar data with load columns (the efficient
    estimator with the noise model, a fifth of the poses held out; no outlier screening, which
    the carriage's misfit would keep busy): the diagnosis names the
    carriage's compliance, and the report (text, HTML, Markdown, summary.json) has the
    "Diagnosis" section; the same data without the columns get none (and no note)."""
    plain, data = soft_carriage
    cal = iwr.calibrate(plain, data, noise=NOISE, seed=1, outliers="off")
    assert cal.diagnosis is not None
    assert cal.diagnosis.weighting == "whitened by the noise model"
    assert cal.diagnosis.suggested == ["carriage_compliance"], cal.diagnosis.lines()
    report = render(cal)
    md = report.markdown([])
    assert "## Diagnosis: loads and temperatures" in md
    assert "distance residuals (whitened by the noise model)" in md
    assert "[effects.carriage_compliance]" in md
    # the fit test's causes are the ballbar's, not the tracker's, and said once in the verdict
    assert "length offset far from their nominal values" in md, md
    assert "tracker frame" not in md and "Likely causes: the weighted" not in md
    assert "Diagnosis: loads and temperatures" in report.html().render()
    assert "switch on [effects.carriage_compliance]" in report.summary()
    summary = json.loads(json.dumps(report.to_dict(), allow_nan=False))
    assert summary["diagnosis"]["suggested"] == ["carriage_compliance"]
    assert not any("no diagnosis" in n for n in cal.notes), cal.notes
    bare = BallbarMeasurements(data.q, data.legs, data.setup, data.distance,
                               joint_types=data.joint_types)
    assert kinds.of(bare).diagnose(plain, bare, cal.result.x) is None
    cal = iwr.calibrate(plain, bare, "lm")
    assert cal.diagnosis is None and not any("diagnosis" in n for n in cal.notes)


def test_an_effect_the_data_cannot_test_is_said_so():
    """An effect whose regressors lie in the span of the geometry's (and the others'): no
    degree of freedom of its own, so it is not tested (never named, whatever the residuals),
    the level is shared among the others, and the report says it cannot be tested rather than
    that no correlation was found."""
    rng = np.random.default_rng(0)
    a = rng.normal(size=(60, 5))
    z_in = a[:, :2] @ rng.normal(size=(2, 1))  # in the geometry's span
    z_out = rng.normal(size=(60, 6))
    r = a @ rng.normal(size=5) + 3.0 * z_in[:, 0] + 0.1 * rng.normal(size=60)
    d = effect_tests(r, a, {"carriage_compliance": z_in, "compliance": z_out}, np.arange(60),
                     exact=True, alpha=0.01, weighting="unweighted", assumptions=[], table=[])
    carriage, legs = d.tests
    assert not carriage.testable and carriage.dof[0] == 0 and math.isnan(carriage.statistic)
    assert not carriage.significant and carriage.p_value == 1.0 and carriage.own == 0.0
    assert legs.testable and legs.alpha == pytest.approx(0.01)  # the one tested: the whole level
    assert d.untestable == ["carriage_compliance"] and d.suggested == []
    assert "cannot be tested with these data" in carriage.line()
    assert "no correlation" not in carriage.line()
    assert "gravity loads (payload): cannot be tested with these data" in d.lines()[0]
    assert d.to_dict()["tests"][0]["F"] is None  # valid JSON: no NaN
    json.dumps(d.to_dict(), allow_nan=False)


def test_the_pose_regressors_are_the_leg_forces_and_lengths():
    """On pose data the regressors of the legs' compliance and expansion, now the derivative of
    the predicted readings with the candidate effects, are what they stand for: leg j's force
    (1e-3 f, um/N) and its length times the temperature's departure from the mean (1e-6 D dT):
    the statics and the geometry computed directly (iwr.effects.model.leg_state)."""
    from iwr.effects.model import leg_state

    plain = _plain("pose")
    data, x = _simulate(plain, (), 20, seed=2, temperatures=np.linspace(17.0, 25.0, 20))
    cands = candidates(plain, data)
    probe = plain.with_effects(*cands.effects)
    ne = sum(len(e.parameter_names()) for e in probe.effects)
    _, jac = predicted_readings(probe, np.concatenate([x, np.zeros(ne)]), data.q, data.poses,
                                data, derivatives=True)
    state = leg_state(plain.with_effects(cands.effects[0]), x, data.q, data.poses, data,
                      {"forces"})
    ng = plain.n_params
    np.testing.assert_allclose(-jac[:, :, ng: ng + 6], 1e-3 * state.forces[:, :, None]
                               * np.eye(6), atol=1e-12)
    temps = np.broadcast_to(data.temperatures, (20, 6))
    thermal = next(i for i, e in enumerate(probe.effects) if e.name == "thermal")
    col = ng + sum(len(e.parameter_names()) for e in probe.effects[:thermal])
    np.testing.assert_allclose(-jac[:, :, col], 1e-6 * state.lengths * (temps - temps.mean()),
                               rtol=1e-9, atol=1e-12)
    assert diagnose(plain, data, x) is not None
