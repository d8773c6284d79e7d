"""The diagnosis of a geometric calibration against the loads and temperatures (issue 23,
docs/effects.md, "Diagnosis of a geometric calibration"): how often it names each effect.

For each seed: a simulated IWR data set (``N_POSES``, default 60; ``iwr.Noise.realistic()``) of
SCENARIO ``clean`` (geometry only), ``compliance`` (``iwr.effects.api.realistic``'s compliance,
values drawn within its bounds), ``thermal`` (steel legs, coefficient drawn), ``carriage``
(``realistic(carriage=True)``'s compliance of the loaded carriage joints +-30 %) or ``slides``
(the slides' scales expanding by a shared 11.5 +- 2 ppm/K times SCALE (default 1), the
machine's temperature over a day's drift about 20 C as ``iwr simulate`` draws it, 17 .. 25 C:
a SCALE of 0.5 is half the growth, as half the drift would make), with the payload
and temperature columns it lacks added (payloads none/80 kg alternating, temperatures uniform in
17 .. 25 C); calibrated geometric-only, WEIGHTING ``noise`` (the efficient estimator with the
true noise model) or ``none`` (``lm``, base parameters); then ``iwr.effects.job.diagnose``.
Prints each seed's p-values and named effects, the counts, and on clean data the
Kolmogorov-Smirnov test of the p-values against U(0, 1).

Usage::

    python benchmarks/effects_diagnosis.py SCENARIO N_SEEDS WEIGHTING [N_POSES [SCALE]]
"""
from __future__ import annotations

import sys
import time

import numpy as np
from _diagnosis_summary import record, summarise

import iwr
from iwr.effects import api
from iwr.effects.builtin import LegThermal
from iwr.effects.carriage_thermal import CarriageThermal
from iwr.effects.job import diagnose
from iwr.measurements import Measurements

scenario, nseeds, weighting = sys.argv[1], int(sys.argv[2]), sys.argv[3]
n_poses = int(sys.argv[4]) if len(sys.argv) > 4 else 60
scale = float(sys.argv[5]) if len(sys.argv) > 5 else 1.0
robot = iwr.Robot.default()
comp, _, carriage = api.realistic(robot, carriage=True)
EFFECTS = ("compliance", "thermal", "carriage_compliance", "carriage_thermal")
noise = iwr.Noise.realistic()
rows = []
t0 = time.time()
for seed in range(nseeds):
    rng = np.random.default_rng(1000 + seed)
    if scenario == "clean":
        m, _ = iwr.simulate(robot, n_poses, seed=seed, noise=noise)
    elif scenario == "compliance":
        truthbot = robot.with_effects(comp)
        m, _ = api.simulate(truthbot, n_poses, seed=seed, noise=noise)
    elif scenario == "carriage":  # the realistic compliance +-30 % per joint, not its bounds'
        truthbot = robot.with_effects(carriage)
        lo, hi = robot.default_bounds()
        cc = carriage.values()
        x = np.concatenate([lo + (hi - lo) * rng.random(robot.n_params),
                            cc * 0.3 * (2.0 * rng.random(cc.size) - 1.0)])
        m, _ = api.simulate(truthbot, n_poses, seed=seed, noise=noise, x=x,
                            payloads=api.DEFAULT_PAYLOADS)
    elif scenario == "slides":  # steel scales, 11.5 +- 2 ppm/K (shared), times the scale
        truthbot = robot.with_effects(CarriageThermal(11.5 * scale, 20.0, identify=True))
        lo, hi = robot.default_bounds()
        x = np.concatenate([lo + (hi - lo) * rng.random(robot.n_params),
                            [scale * 2.0 * (2.0 * rng.random() - 1.0)]])
        m, _ = api.simulate(truthbot, n_poses, seed=seed, noise=noise, x=x)
    else:
        assert scenario == "thermal", scenario
        truthbot = robot.with_effects(LegThermal(11.5, 20.0, identify=True))
        m, _ = api.simulate(truthbot, n_poses, seed=seed, noise=noise)
    n = len(m)
    pay = m.payload if m.payload is not None else api.DEFAULT_PAYLOADS[np.arange(n) % 2]
    temps = m.temperatures if m.temperatures is not None else 17 + 8 * rng.random(n)
    data = Measurements(m.q, m.poses, m.legs, joint_types=m.joint_types, payload=pay,
                        temperatures=temps)
    if weighting == "noise":
        res = iwr.identify(robot, data, "efficient", noise=noise)
        d = diagnose(robot, data, res.x, active=res.get("active"), noise=res.get("noise", noise))
        fit = res.get("fit")
    else:
        res = iwr.identify(robot, data, "lm", active="base")
        d = diagnose(robot, data, res.x, active=res.get("active"))
        fit = res.get("fit")
    record(rows, seed, d, fit, EFFECTS)
summarise(rows, EFFECTS, (f"scenario {scenario} weighting {weighting} seeds {nseeds} poses "
                          f"{n_poses} scale {scale:g}"), scenario == "clean", t0)
