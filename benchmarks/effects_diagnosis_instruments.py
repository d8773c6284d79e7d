"""The diagnosis of a geometric calibration on an instrument's data (laser-tracker points or
probe, double ballbar) against the loads and temperatures (issue 23, docs/effects.md,
"Diagnosis of a geometric calibration"): how often it names each effect.

For each seed: a simulated IWR with KIND's instrument (``points``: three reflectors, one hidden
at 10 % of the poses; ``probe``; ``ballbar``: set-ups A and B of the tests, a 1 um bar),
``N_POSES`` (default 50) under the payloads of :data:`iwr.effects.tracker_study.PAYLOADS`
(none, 80 kg, 60 kg off-axis) and temperatures over a day's drift, every instrument's noise
(legs 2 um, joints 5 um and 5 urad, Leica's tracker or the bar's 1 um); the truth's geometric
errors and set-up uniform within their default bounds, and SCENARIO ``clean`` (every effect 0:
the columns carry none), ``compliance`` (``iwr.effects.api.realistic``'s 0.01 um/N per leg
+-30 %), ``thermal`` (steel's 11.5 ppm/K), ``carriage`` (``realistic(carriage=True)``'s
compliance of the loaded carriage joints, +-30 % per joint) or ``slides`` (the slides' scales
expanding by a shared 11.5 +- 2 ppm/K with the machine's temperature), the others 0. Calibrated
geometric-only, WEIGHTING ``noise`` (the efficient estimator with the true noise model) or
``none`` (``lm``, unweighted); then the kind's diagnosis. Prints each seed's p-values and
named effects, the counts, and on clean data the Kolmogorov-Smirnov test of each effect's
p-values against U(0, 1) and the number of data sets in which any effect is named.

Usage::

    python benchmarks/effects_diagnosis_instruments.py KIND SCENARIO N_SEEDS WEIGHTING [N_POSES]
"""
from __future__ import annotations

import sys
import time

import numpy as np
from _diagnosis_summary import record, summarise

import iwr
from iwr import kinds
from iwr.ballbar import BallbarNoise
from iwr.ballbar import effects as be
from iwr.effects import api, tracker_study
from iwr.effects import tracker as et
from iwr.effects.builtin import LegCompliance, LegThermal
from iwr.effects.carriage_thermal import CarriageThermal

EFFECTS = ("compliance", "thermal", "carriage_compliance", "carriage_thermal")
kind, scenario, nseeds, weighting = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
n_poses = int(sys.argv[5]) if len(sys.argv) > 5 else 50
plain = iwr.Robot.default()
registration = (2000.0, -150.0, 300.0, 1.5, 0.01, -0.02)
readings = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
if kind == "points":
    plain = plain.with_tracker(registration=registration, reflectors=[
        (120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)])
    noise = tracker_study._noise()
elif kind == "probe":
    plain = plain.with_tracker(registration=registration, probe=(10.0, -5.0, 60.0, 0.1, 0.0, 0.2))
    noise = tracker_study._noise()
else:
    assert kind == "ballbar", kind
    plain = plain.with_instrument("ballbar", {
        "A": {"platform_ball": [0, 0, -60], "fixed_ball": [800, -800, 1500], "range": [300, 700]},
        "B": {"platform_ball": [100, 50, -60], "fixed_ball": [900, -200, 2400],
              "range": [300, 700]}})
    noise = (readings, BallbarNoise(0.001))
comp, _, carriage = api.realistic(plain, carriage=True)
c = comp.compliance[0] if scenario == "compliance" else 0.0
alpha = 11.5 if scenario == "thermal" else 0.0
cc = carriage.values() if scenario == "carriage" else np.zeros(len(carriage.values()))
truthbot = plain.with_effects(
    LegCompliance(comp.platform_mass, comp.platform_centre, comp.gravity, c, per_leg=True),
    LegThermal(alpha, 20.0, identify=True), carriage.with_values(cc),
    CarriageThermal(11.5 if scenario == "slides" else 0.0, 20.0, identify=True))
setup = plain.tracker if kind != "ballbar" else be._setup(plain)
rows = []
t0 = time.time()
for seed in range(nseeds):
    rng = np.random.default_rng(2000 + seed)
    lo_g, hi_g = plain.default_bounds()
    lo_s, hi_s = setup.default_bounds()
    dc = c * 0.3 * (2.0 * rng.random(6) - 1.0)  # +-30 % per leg (0 unless compliance)
    dj = cc * 0.3 * (2.0 * rng.random(cc.size) - 1.0)  # +-30 % per joint (0 unless carriage)
    xg = lo_g + (hi_g - lo_g) * rng.random(plain.n_params)
    xs = lo_s + (hi_s - lo_s) * rng.random(setup.n_params)
    # the slides' 11.5 +- 2 ppm/K (drawn after the rest: the other scenarios' truths as before)
    da = 2.0 * (2.0 * rng.random() - 1.0) if scenario == "slides" else 0.0
    truth = np.concatenate([xg, dc, [0.0], dj, [da], xs])
    if kind == "ballbar":
        data, _ = be.simulate(truthbot, n_poses, seed=seed, x=truth, noise=noise,
                              payloads=tracker_study.PAYLOADS)
    else:
        data, _ = et.simulate(truthbot, n_poses, seed=seed, x=truth, noise=noise,
                              payloads=tracker_study.PAYLOADS,
                              hidden=0.1 if kind == "points" else 0.0)
    if weighting == "noise":
        res = iwr.identify(plain, data, "efficient", noise=noise, outliers="off")
        d = kinds.of(data).diagnose(plain, data, res.x, active=res.get("active"), noise=noise)
    else:
        res = iwr.identify(plain, data, "lm")
        d = kinds.of(data).diagnose(plain, data, res.x, active=res.get("active"))
    fit = res.get("fit")
    record(rows, seed, d, fit, EFFECTS, "dof", {t.effect: t.dof for t in d.tests})
summarise(rows, EFFECTS, (f"{kind} scenario {scenario} weighting {weighting} seeds {nseeds} "
                          f"poses {n_poses}"), scenario == "clean", t0)
