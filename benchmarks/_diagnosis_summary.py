"""What the two diagnosis Monte Carlo scripts (effects_diagnosis.py on pose data,
effects_diagnosis_instruments.py on tracker and ballbar data) print per seed and at the end."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from scipy import stats


def record(rows: list, seed: int, d: Any, fit: Any, effects: list[str], *extra: Any) -> None:
    """Append one seed's row (p-values, the effects named, whether the geometric fit test
    passed, each effect's own share) and print it; ``extra`` is printed before the fit test.
    The effects named are those whose own test rejects, and ``loads`` when only the two
    compliances' joint test does (the closed test, ``Diagnosis.loads_only``: the diagnosis then
    suggests both). The p-value ``p_loads`` is the joint test's."""
    p = {t.effect: t.p_value for t in d.tests}
    if d.loads is not None:
        p["loads"] = d.loads.p_value
    est = {t.effect: t.estimate for t in d.tests}
    own = {t.effect: t.own for t in d.tests}
    fit_ok = None if fit is None else fit.fit_ok
    named = [t.effect for t in d.tests if t.significant] + (["loads"] if d.loads_only else [])
    rows.append(([p.get(e, np.nan) for e in (*effects, "loads")], named, fit_ok,
                 [own.get(e, np.nan) for e in effects]))
    print(seed, " ".join(f"p_{e}={p.get(e, np.nan):.3g}" for e in (*effects, "loads")), named,
          *extra, "fit_ok", fit_ok, {e: np.round(v, 4).tolist() for e, v in est.items()},
          flush=True)


def summarise(rows: list, effects: list[str], head: str, clean: bool, t0: float) -> None:
    """The counts over the seeds, the own shares, and on clean data the p-values' uniformity."""
    named = [r[1] for r in rows]
    counts = ", ".join(f"{e} {sum(e in s for s in named)}" for e in (*effects, "loads"))
    print(f"{head}: named {counts}, any {sum(bool(s) for s in named)}, none "
          f"{sum(not s for s in named)}; fit failed {sum(r[2] is False for r in rows)}; "
          f"{time.time() - t0:.0f} s")
    share = np.array([r[3] for r in rows])
    print("own share (mean, min .. max over the seeds): " + ", ".join(
        f"{e} {np.mean(share[:, i]):.3f} ({np.min(share[:, i]):.3f} .. {np.max(share[:, i]):.3f})"
        for i, e in enumerate(effects) if not np.all(np.isnan(share[:, i]))))
    if clean:
        for i, effect in enumerate((*effects, "loads")):
            pv = np.array([r[0][i] for r in rows])
            if np.all(np.isnan(pv)):
                continue
            print(f"{effect}: KS p-value against U(0, 1) "
                  f"{stats.kstest(pv, 'uniform').pvalue:.3g}; fraction below 0.05 "
                  f"{np.mean(pv < 0.05):.3g}, below 0.005 {np.mean(pv < 0.005):.3g}")
