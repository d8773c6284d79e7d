"""The diagnosis of a geometric calibration on laser-tracker data against the loads and
temperatures (issue 23, docs/effects.md, "Diagnosis of a geometric calibration"): how often it
names each effect.

For each seed: a simulated IWR with KIND's tracker set-up (``points``: three reflectors, one
hidden at 10 % of the poses; ``probe``), ``N_POSES`` (default 50) under the payloads of
:data:`iwr.effects.tracker_study.PAYLOADS` (none, 80 kg, 60 kg off-axis) and temperatures over a
day's drift, every instrument's noise (:func:`iwr.effects.tracker_study._noise`); the truth's
geometric errors and set-up uniform within their default bounds, and SCENARIO ``clean`` (leg
compliance 0 and expansion coefficient 0: the columns carry no effect), ``compliance``
(``iwr.effects.api.realistic``'s 0.01 um/N per leg +-30 %, coefficient 0) or ``thermal`` (steel's
11.5 ppm/K, compliance 0). Calibrated geometric-only, WEIGHTING ``noise`` (the efficient
estimator with the true noise model) or ``none`` (``lm``, unweighted); then the kind's diagnosis.
Prints each seed's p-values and named effects, the counts, and on clean data the
Kolmogorov-Smirnov test of the p-values against U(0, 1).

Usage::

    python benchmarks/effects_diagnosis_tracker.py KIND SCENARIO N_SEEDS WEIGHTING [N_POSES]
"""
from __future__ import annotations

import sys
import time

import numpy as np
from scipy import stats

import iwr
from iwr import kinds
from iwr.effects import api, tracker_study
from iwr.effects import tracker as et
from iwr.effects.builtin import LegCompliance, LegThermal

kind, scenario, nseeds, weighting = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
n_poses = int(sys.argv[5]) if len(sys.argv) > 5 else 50
plain = iwr.Robot.default()
registration = (2000.0, -150.0, 300.0, 1.5, 0.01, -0.02)
if kind == "points":
    plain = plain.with_tracker(registration=registration, reflectors=[
        (120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)])
else:
    plain = plain.with_tracker(registration=registration, probe=(10.0, -5.0, 60.0, 0.1, 0.0, 0.2))
comp, _ = api.realistic(plain)
c = comp.compliance[0] if scenario == "compliance" else 0.0
alpha = 11.5 if scenario == "thermal" else 0.0
truthbot = plain.with_effects(
    LegCompliance(comp.platform_mass, comp.platform_centre, comp.gravity, c, per_leg=True),
    LegThermal(alpha, 20.0, identify=True))
noise = tracker_study._noise()
setup = plain.tracker
rows = []
t0 = time.time()
for seed in range(nseeds):
    rng = np.random.default_rng(2000 + seed)
    lo_g, hi_g = plain.default_bounds()
    lo_s, hi_s = setup.default_bounds()
    dc = c * 0.3 * (2.0 * rng.random(6) - 1.0)  # +-30 % per leg (0 on clean and thermal data)
    truth = np.concatenate([lo_g + (hi_g - lo_g) * rng.random(plain.n_params), dc, [0.0],
                            lo_s + (hi_s - lo_s) * rng.random(setup.n_params)])
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
    p = {t.effect: t.p_value for t in d.tests}
    est = {t.effect: t.estimate for t in d.tests}
    rows.append((p["compliance"], p["thermal"], d.suggested, None if fit is None else fit.fit_ok))
    print(seed, f"p_c={p['compliance']:.3g} p_t={p['thermal']:.3g}", d.suggested,
          "dof", [t.dof for t in d.tests], "fit_ok", None if fit is None else fit.fit_ok,
          "est_c", np.round(est["compliance"], 4), "est_t", np.round(est["thermal"], 2),
          flush=True)
named = [r[2] for r in rows]
counts = ", ".join(f"{e} {sum(e in s for s in named)}" for e in ("compliance", "thermal"))
print(f"{kind} scenario {scenario} weighting {weighting} seeds {nseeds} poses {n_poses}: named "
      f"{counts}, none {sum(not s for s in named)}; fit failed "
      f"{sum(r[3] is False for r in rows)}; {time.time() - t0:.0f} s")
for i, effect in enumerate(("compliance", "thermal")):
    pv = np.array([r[i] for r in rows])
    if scenario == "clean":
        print(f"{effect}: KS p-value against U(0, 1) {stats.kstest(pv, 'uniform').pvalue:.3g}; "
              f"fraction below 0.05 {np.mean(pv < 0.05):.3g}, below 0.005 "
              f"{np.mean(pv < 0.005):.3g}")
