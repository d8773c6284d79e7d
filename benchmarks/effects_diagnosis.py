"""The diagnosis of a geometric calibration against the loads and temperatures (issue 23,
docs/effects.md, "Diagnosis of a geometric calibration"): how often it names each effect.

For each seed: a simulated IWR data set (``N_POSES``, default 60; ``iwr.Noise.realistic()``) of
SCENARIO ``clean`` (geometry only), ``compliance`` (``iwr.effects.api.realistic``'s compliance,
values drawn within its bounds) or ``thermal`` (steel legs, coefficient drawn), with the payload
and temperature columns it lacks added (payloads none/80 kg alternating, temperatures uniform in
17 .. 25 C); calibrated geometric-only, WEIGHTING ``noise`` (the efficient estimator with the
true noise model) or ``none`` (``lm``, base parameters); then ``iwr.effects.job.diagnose``.
Prints each seed's p-values and named effects, the counts, and on clean data the
Kolmogorov-Smirnov test of the p-values against U(0, 1).

Usage::

    python benchmarks/effects_diagnosis.py SCENARIO N_SEEDS WEIGHTING [N_POSES]
"""
from __future__ import annotations

import sys
import time

import numpy as np
from scipy import stats

import iwr
from iwr.effects import api
from iwr.effects.builtin import LegThermal
from iwr.effects.job import diagnose
from iwr.measurements import Measurements

scenario, nseeds, weighting = sys.argv[1], int(sys.argv[2]), sys.argv[3]
n_poses = int(sys.argv[4]) if len(sys.argv) > 4 else 60
robot = iwr.Robot.default()
comp, _ = api.realistic(robot)
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
    else:
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
    p = {t.effect: t.p_value for t in d.tests}
    est = {t.effect: t.estimate for t in d.tests}
    rows.append((p["compliance"], p["thermal"], d.suggested, None if fit is None else fit.fit_ok))
    print(seed, f"p_c={p['compliance']:.3g} p_t={p['thermal']:.3g}", d.suggested,
          "fit_ok", None if fit is None else fit.fit_ok,
          "est_c", np.round(est["compliance"], 4), "est_t", np.round(est["thermal"], 2), flush=True)
pc = np.array([r[0] for r in rows])
pt = np.array([r[1] for r in rows])
named = [r[2] for r in rows]
print(f"scenario {scenario} weighting {weighting} seeds {nseeds} poses {n_poses}: "
      f"named compliance {sum('compliance' in s for s in named)}, thermal "
      f"{sum('thermal' in s for s in named)}, none {sum(not s for s in named)}; "
      f"fit failed {sum(r[3] is False for r in rows)}; {time.time()-t0:.0f} s")
if scenario == "clean":
    print("KS uniform p-values: compliance", stats.kstest(pc, "uniform").pvalue,
          "thermal", stats.kstest(pt, "uniform").pvalue)
    print("fraction p<0.05: compliance", np.mean(pc < 0.05), "thermal", np.mean(pt < 0.05))
