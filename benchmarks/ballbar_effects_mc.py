"""Monte-Carlo check of the effects on double-ballbar data (issue 23, docs/effects.md, "Ballbar
data"): the efficient estimator's actual against predicted tool accuracy, and the geometric-only
calibration's tool error.

    python benchmarks/ballbar_effects_mc.py [N] [SEEDS] [CARRIAGE] [FIRST_SEED]

Per seed (a new truth, set-ups and poses each): ``N`` noisy poses in set-ups A and B
(legs 2 um, prismatic joints 5 um, revolute joints 5 urad, bar 1 um) under three payloads
(none, 80 kg and 60 kg heads whose centres are not on one line with the platform's) at a day's
temperatures, the realistic effects (legs' compliance per leg, a shared expansion coefficient;
``CARRIAGE=1``: the carriage's compliance too), the efficient estimator on the base parameters;
on 50 fresh noise-free poses under other loads (40 and 120 kg) at 14 .. 30 C the tool position
error modulo the ballbar's gauge (``iwr.accuracy(..., truth=)``) against the prediction from the
estimator's covariance at those poses (``iwr.ballbar.effects.predicted_accuracy``); and the
geometric-only calibration (the robot without effects, the same readings) by the same
estimator: its fit test and its tool error. Prints a table and one JSON line.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

import iwr
from iwr.ballbar import BallbarMeasurements, BallbarNoise
from iwr.ballbar import effects as be
from iwr.effects import api
from iwr.effects.tracker_study import FRESH_PAYLOADS, PAYLOADS

BARS = {
    "A": {"platform_ball": [0.0, 0.0, -60.0], "fixed_ball": [800.0, -800.0, 1500.0],
          "range": [300.0, 700.0]},
    "B": {"platform_ball": [100.0, 50.0, -60.0], "fixed_ball": [900.0, -200.0, 2400.0],
          "range": [300.0, 700.0]},
}
NOISE = (iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6), BallbarNoise(0.001))


def rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


def trial(robot: iwr.Robot, n: int, seed: int) -> dict[str, float]:
    data, truth = be.simulate(robot, n, seed=seed, payloads=PAYLOADS, noise=NOISE)
    fresh, _ = be.simulate(robot, 50, seed=10_000 + seed, x=truth, payloads=FRESH_PAYLOADS,
                           temperatures=np.linspace(14.0, 30.0, 50))
    t0 = time.perf_counter()
    ext = iwr.identify(robot, data, "efficient", noise=NOISE)
    t_ext = time.perf_counter() - t0
    actual = rms(iwr.accuracy(robot, fresh, ext.x, truth=truth).calibrated.position)
    pred = be.predicted_accuracy(robot, fresh, ext.x, ext.covariance, ext.active, seed=seed)
    # The geometry alone: the same readings, no loads or temperatures modelled.
    plain = robot.with_effects()
    bare = BallbarMeasurements(data.q, data.legs, data.setup, data.distance,
                               joint_types=data.joint_types)
    geo = iwr.identify(plain, bare, "efficient", noise=NOISE)
    ng, ne = robot.n_params, len(iwr.effects.parameter_names(robot.effects))
    x_geo = np.concatenate([geo.x[:ng], -np.concatenate([e.values() for e in robot.effects]),
                            geo.x[ng:]])  # the effects switched off: their values cancelled
    geo_err = rms(iwr.accuracy(robot, fresh, x_geo, truth=truth).calibrated.position)
    return {"seed": seed, "success": bool(ext.success), "geo_success": bool(geo.success),
            "actual_um": 1e3 * actual, "predicted_um": 1e3 * pred.position_rms,
            "ratio": actual / pred.position_rms, "geometric_um": 1e3 * geo_err,
            "geo_over_ext": geo_err / actual, "seconds": t_ext,
            "alpha_err_sd": float((ext.x[ng + ne - 1] - truth[ng + ne - 1])
                                  / np.sqrt(ext.covariance[
                                      int(np.sum(ext.active[: ng + ne])) - 1,
                                      int(np.sum(ext.active[: ng + ne])) - 1]))
            if ext.active[ng + ne - 1] else float("nan")}


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 120
    seeds = int(sys.argv[2]) if len(sys.argv) > 2 else 10
    carriage = bool(int(sys.argv[3])) if len(sys.argv) > 3 else False
    first = int(sys.argv[4]) if len(sys.argv) > 4 else 1
    plain = iwr.Robot.default().with_instrument("ballbar", BARS)
    robot = plain.with_effects(*api.realistic(plain, carriage=carriage))
    rows = [trial(robot, n, s) for s in range(first, first + seeds)]
    print(f"{n} poses, {seeds} seeds, effects: {', '.join(e.name for e in robot.effects)}")
    print("seed  ok  actual um  predicted um  ratio  geometric um (fit ok)  geo/ext  alpha/sd  s")
    for r in rows:
        print(f"{r['seed']:4d}  {'y' if r['success'] else 'n'}  {r['actual_um']:9.2f}  "
              f"{r['predicted_um']:12.2f}  {r['ratio']:5.3f}  {r['geometric_um']:12.2f} "
              f"({'y' if r['geo_success'] else 'n'})  {r['geo_over_ext']:7.2f}  "
              f"{r['alpha_err_sd']:+8.2f}  {r['seconds']:.1f}")
    act = np.array([r["actual_um"] for r in rows])
    pre = np.array([r["predicted_um"] for r in rows])
    ratio = np.array([r["ratio"] for r in rows])
    summary = {
        "n_poses": n, "seeds": seeds, "carriage": carriage,
        "actual_rms_um": rms(act), "predicted_rms_um": rms(pre),
        "actual_over_predicted": rms(act) / rms(pre),
        "ratio_median": float(np.median(ratio)), "ratio_min": float(ratio.min()),
        "ratio_max": float(ratio.max()),
        "extended_fit_ok": int(sum(r["success"] for r in rows)),
        "geometric_fit_ok": int(sum(r["geo_success"] for r in rows)),
        "geometric_rms_um": rms(np.array([r["geometric_um"] for r in rows])),
        "geo_over_ext_median": float(np.median([r["geo_over_ext"] for r in rows])),
        "alpha_err_sd_rms": rms(np.array([r["alpha_err_sd"] for r in rows])),
    }
    print(json.dumps(summary))


if __name__ == "__main__":
    main()
