"""The thermal expansion of the carriage's slides as a candidate effect of the diagnosis of a
geometric calibration (issue 23 item 4, docs/effects.md "Diagnosis of a geometric calibration";
iwr.effects.job.candidates): tested when the data have the machine's temperature (T_C) and the
robot prismatic joints, named alone with its coefficient near the truth, its suggested table
read back as a robot file; not tested on the legs' temperatures only. The regressors against
central differences and noise-free truth: tests/test_effects_ballbar_diagnosis.py (every kind);
the rates over seeds: the docs' tables (benchmarks/effects_diagnosis.py)."""

from __future__ import annotations

import numpy as np
import pytest

import iwr
from iwr.effects import api
from iwr.effects.carriage_thermal import CarriageThermal
from iwr.effects.job import candidates, diagnose
from iwr.measurements import Measurements


def test_slides_named_alone_and_the_table_read_back(tmp_path):
    """Pose data (60 poses, iwr.Noise.realistic(), a day's drift of the machine's temperature
    as simulate draws it) whose slides grow by 11.5 ppm/K, a geometric fit by the efficient
    estimator: the diagnosis names the slides' expansion alone, its coefficient near 11.5 (sd
    about 1.7 ppm/K over seeds), the report's line in ppm/K, and the suggested
    ``[effects.carriage_thermal]`` table makes a robot file that reads back with the IWR's
    slides."""
    plain = iwr.Robot.default()
    noise = iwr.Noise.realistic()
    truth = plain.with_effects(CarriageThermal(11.5, 20.0, identify=True))
    rng = np.random.default_rng(5)
    lo, hi = plain.default_bounds()
    x = np.concatenate([lo + (hi - lo) * rng.random(plain.n_params), [0.0]])
    data, _ = api.simulate(truth, 60, seed=5, noise=noise, x=x)
    assert data.temperatures.shape == (60, 1) and data.payload is None
    res = iwr.identify(plain, data, "efficient", noise=noise)
    d = diagnose(plain, data, res.x, active=res.active, noise=noise)
    assert d.suggested == ["carriage_thermal"], [t.line() for t in d.tests]
    test = {t.effect: t for t in d.tests}
    assert list(test) == ["thermal", "carriage_thermal"]
    slides = test["carriage_thermal"]
    assert slides.dof[0] == 1 and slides.unit == "ppm/K"
    assert slides.estimate[0] == pytest.approx(11.5, abs=4.0)
    assert "ppm/K" in slides.line() and "slide reading times machine temperature" in slides.line()
    assert d.lines()[0].startswith(
        "diagnosis: the residuals of the geometric model correlate with the slides' travel "
        "times the machine's temperature; switch on [effects.carriage_thermal]")
    # The two thermal effects read one temperature column, yet their patterns stay apart: the
    # legs' expansion shares about 2 % of the slides' change beyond the geometry on pose data
    # (docs: 0.92 .. 0.997 kept over 500 seeds), and with two one-column effects the share each
    # keeps is the same (one minus their squared correlation beyond the geometry).
    assert slides.own > 0.9 and test["thermal"].own == pytest.approx(slides.own, rel=1e-9)
    assert d.to_dict()["tests"][1]["own_share"] == pytest.approx(slides.own)
    path = tmp_path / "robot.toml"
    plain.to_toml(path)
    path.write_text(path.read_text() + "\n" + d.suggestion() + "\n")
    back = iwr.Robot.from_toml(path).effects
    assert [e.name for e in back] == ["carriage_thermal"]
    assert back[0].joints == (1, 2) and back[0].identify and back[0].reference == 20.0


def test_not_tested_without_the_machines_temperature():
    """The slides' expansion reads the machine's temperature (T_C): data with the legs'
    temperatures only (T1_C .. T6_C) do not test it, and the assumptions say why; with T_C it
    is a candidate, one coefficient shared by the prismatic joints 1 and 2 (the effect's
    default), about the data's mean temperature."""
    plain = iwr.Robot.default()
    data, _ = iwr.simulate(plain, 12, seed=1)
    temps = np.linspace(17.0, 25.0, 12)
    legs = Measurements(data.q, data.poses, data.legs, joint_types=data.joint_types,
                        temperatures=temps[:, None] + np.arange(6) * 0.1)
    cands = candidates(plain, legs)
    assert [e.name for e in cands.effects] == ["thermal"]
    assert any("slides' expansion (joints 1 and 2) is not tested" in a and "T_C" in a
               for a in cands.assumptions), cands.assumptions
    machine = Measurements(data.q, data.poses, data.legs, joint_types=data.joint_types,
                           temperatures=temps)
    cands = candidates(plain, machine)
    assert [e.name for e in cands.effects] == ["thermal", "carriage_thermal"]
    slides = cands.effects[1]
    assert slides.joints == (1, 2) and not slides.per_joint and slides.identify
    assert slides.reference == pytest.approx(21.0) and slides.values() == pytest.approx([0.0])
    assert not any("slides" in a for a in cands.assumptions)
