"""Monte-Carlo check of the job's "not calibrated" verdict (iwr.calibration.judge): how often a
correct re-calibration is refused, and that a calibration that makes the robot worse still is.

For each seed and each kind of data (pose data in {0}; reflector points of a laser tracker,
examples/iwr_tracker.toml; a double ballbar in two set-ups, tests/_ballbar.py's), with the
noise model of the data (the efficient estimator):

- ``recalibration``: a robot with random errors (iwr.simulate) is calibrated on 40 poses (a
  ballbar: 150 readings), then the calibrated robot (its calibrated.toml) is calibrated again
  on as many FRESH poses of the same true robot, holding out a fraction 0.2 (8 validation poses;
  30 readings). Before and after are both at the noise level: the second job should not be
  refused.
- ``truth, N poses``: the nominal robot is the true one and the identification has only N
  poses with 3 times the noise (its noise model says so); 8 validation poses of normal noise
  (a ballbar: 30 readings). The calibration moves a correct robot by its estimation error:
  clearly worse after (1.5-7 times), which the job must refuse (or fail its fit test).

The old rule (after > 1.05 before, or not finite) and the new one (that, and the one-sided
paired t-test of the per-pose log ratios after/before at 1 %) are both read off each job
(``Judgement.beyond_ratio``, ``Judgement.worse``): the new rule refuses a subset of what the old
one refused, and the job's status is checked to be the new rule's. ``new@5%`` counts what the
new rule would refuse at a level of 5 %; ``sq-t``, ``diff-t`` and ``wilcox`` what the ratio
gate with another test at 1 % would refuse (a paired t-test of the squared errors, of the
errors, a Wilcoxon signed-rank test of the squared errors; scipy.stats), for the choice of the
test.

    python benchmarks/recalibration_verdict.py [SEEDS] [pose,points,ballbar]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

import iwr
from iwr.calibration import LEVEL, NOT_CALIBRATED, WORSE
from iwr.experiments.harness import noise_at
from iwr.tracker.analysis import calibrated_robot

NOISE = iwr.Noise.realistic()
ROOT = Path(__file__).resolve().parents[1]


#: Per kind: the poses of a calibration, the identification poses of the bad cases, and the
#: validation poses of the bad cases. Ballbar data need 150 readings (two bars: fewer are
#: degenerate), and a ballbar run holds out tens of readings (0.2 of 150: 30).
CASES = {"pose": (40, (14, 20), 8), "points": (40, (14, 20), 8), "ballbar": (150, (80, 100), 30)}
#: tests/_ballbar.py's two set-ups of a double ballbar.
BARS = {"A": {"platform_ball": [0.0, 0.0, -60.0], "fixed_ball": [800.0, -800.0, 1500.0],
              "range": [300.0, 700.0]},
        "B": {"platform_ball": [100.0, 50.0, -60.0], "fixed_ball": [900.0, -200.0, 2400.0],
              "range": [300.0, 700.0]}}


def robot_of(kind: str) -> iwr.Robot:
    if kind == "pose":
        return iwr.Robot.default()
    if kind == "ballbar":
        return iwr.Robot.default().with_instrument("ballbar", BARS)
    return iwr.Robot.from_toml(ROOT / "examples" / "iwr_tracker.toml")


def calibrated(robot: iwr.Robot, x: np.ndarray) -> iwr.Robot:
    """The calibrated robot of ``x``, as its calibrated.toml holds it."""
    if robot.tracker is not None:
        return calibrated_robot(robot, x)[0]
    n = robot.n_params
    if iwr.kinds.for_robot(robot).name == "ballbar":
        from iwr.ballbar.api import ballbar_setup

        setup = ballbar_setup(robot).with_parameters(x[n:])
        return robot.with_errors(x[:n]).with_instrument("ballbar", setup)
    return robot.with_errors(x)


def verdicts(cal: iwr.Calibration) -> dict[str, object]:
    """What the old rule, the new one (the job's status) and other tests say of a job."""
    from scipy import stats

    j = cal.judgement()
    new = cal.status == NOT_CALIBRATED
    # Before this change the job refused whatever it refuses now, and also every converged,
    # fitting job whose ratio was beyond WORSE (the new rule adds the test to that).
    old = new or (cal.success and j.beyond_ratio)
    if cal.success or (new and "did not improve" in str(cal.result.message)):
        assert new == j.worse, cal.result.message  # the job's status is the rule's
    b, a = cal.kind.per_pose_errors(cal.accuracy)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    # Refused for another reason (degenerate data), or judged by the ratio and a test.
    judged = cal.success or (new and "did not improve" in str(cal.result.message))
    other = new and not judged
    others = {
        "new@5%": j.p,
        "sq-t": stats.ttest_1samp(a**2 - b**2, 0, alternative="greater").pvalue,
        "diff-t": stats.ttest_1samp(a - b, 0, alternative="greater").pvalue,
        "wilcox": stats.wilcoxon(a**2 - b**2, alternative="greater").pvalue,
    }
    return {"old": old, "new": new, "ratio": j.ratio, "p": j.p, "status": cal.status,
            **{k: other or bool(judged and j.beyond_ratio and v < (0.05 if "5" in k else LEVEL))
               for k, v in others.items()}}


def run(kind: str, seed: int) -> dict[str, dict[str, object]]:
    robot = robot_of(kind)
    noise = iwr.kinds.for_robot(robot).experiment_noise(robot, NOISE)
    n_poses, few, n_held = CASES[kind]
    out = {}
    data, truth = iwr.simulate(robot, n_poses, seed=seed, noise=noise)
    first = iwr.calibrate(robot, data, noise=noise, seed=seed, progress=False)
    assert first.status == "converged", first.result.message
    # Fresh poses of the same true robot; the calibrated robot as its calibrated.toml.
    fresh, _ = iwr.simulate(robot, n_poses, seed=10_000 + seed, x=truth, noise=noise)
    again = iwr.calibrate(calibrated(robot, first.result.x), fresh, noise=noise,
                          validation_fraction=0.2, seed=seed, progress=False)
    out["recalibration"] = verdicts(again)
    # The nominal is the truth; a few noisy identification poses, 8 held-out ones.
    true_robot = calibrated(robot, truth)
    loud = iwr.kinds.for_robot(robot).experiment_noise(robot, noise_at(0.06))
    held, _ = iwr.simulate(robot, n_held, seed=50_000 + seed, x=truth, noise=noise)
    for n in few:
        ident, _ = iwr.simulate(robot, n, seed=40_000 + seed, x=truth, noise=loud)
        worse = iwr.calibrate(true_robot, ident, noise=loud, validation=held, seed=seed,
                              progress=False)
        out[f"truth, {n} poses"] = verdicts(worse)
    return out


def main() -> None:
    seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 20
    which = sys.argv[2].split(",") if len(sys.argv) > 2 else list(CASES)
    print(f"{seeds} seeds; 'not calibrated' by the old rule (after/before > {WORSE}) and by the "
          f"new (> {WORSE} and a one-sided paired t-test of the per-pose log(after/before), "
          f"p < {LEVEL}); 'fit failed': refused by the fit test (exit 3) before either")
    print(f"{'kind':7} {'case':17} {'seeds':>5} {'old':>4} {'new':>4} {'fit failed':>10} "
          f"{'new@5%':>6} {'sq-t':>4} {'diff-t':>6} {'wilcox':>6} "
          f"{'ratio med':>9} {'ratio max':>9} "
          f"{'p min':>7} {'p med':>7}  changed (after/before, p)")
    for kind in which:
        start = time.time()
        rows: dict[str, list[dict[str, object]]] = {}
        for s in range(seeds):
            for case, v in run(kind, s).items():
                rows.setdefault(case, []).append(v)
        for case, v in rows.items():
            def count(key: str, rows: list[dict[str, object]] = v) -> int:
                return sum(bool(r[key]) for r in rows)

            failed = sum(r["status"] == "failed" for r in v)
            ratio = np.array([r["ratio"] for r in v], dtype=float)
            p = np.array([r["p"] for r in v], dtype=float)
            changed = ", ".join(f"seed {i}: {r['ratio']:.2f}, {r['p']:.2g}"
                                for i, r in enumerate(v) if r["old"] != r["new"])
            print(f"{kind:7} {case:17} {len(v):5d} {count('old'):4d} {count('new'):4d} "
                  f"{failed:10d} {count('new@5%'):6d} {count('sq-t'):4d} "
                  f"{count('diff-t'):6d} {count('wilcox'):6d} "
                  f"{np.median(ratio):9.3f} {ratio.max():9.3f} {np.nanmin(p):7.2g} "
                  f"{np.nanmedian(p):7.2g}  {changed}", flush=True)
        print(f"  ({kind}: {time.time() - start:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
