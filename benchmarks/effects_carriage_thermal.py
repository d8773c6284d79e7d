"""The thermal expansion of the carriage's slides (issue 23 item 1, docs/effects.md "The carriage's
slides"): what the IWR's data identify of it, what leaving it out costs, and what DE's hot path
pays for it.

1. Monte Carlo (``--seeds``, default 10): per seed a true IWR with random geometric errors
   (within the default bounds), steel legs (11.5 ppm/K, given) and slides whose scales expand
   by a shared coefficient of 11.5 +- 2 ppm/K (uniform), calibration poses at a day's
   temperatures (20 - 3 .. + 5 C; ``--scale`` scales the spreads), every instrument's noise
   (``iwr.Noise.realistic()``); two
   calibrations by the efficient estimator: the model of main (the legs' expansion only) and
   the extended one (the slides' coefficient identified too). Each is judged on 50 fresh poses
   at 14 .. 30 C: the tool position (200 mm along z of {5}) that its forward kinematics gives
   from the true, noise-free readings against the truth; and the extended model's predicted
   tool accuracy there (its covariance).
2. The hot path: ``cost_batch`` of the C++ objectives with effects (pose data, tracker points)
   on 650 random vectors within the bounds at N = 100 poses, one thread, the least CPU time per
   evaluation over ``--repeat`` runs: the legs' expansion alone against it with the slides'.

Usage::

    python benchmarks/effects_carriage_thermal.py [--seeds 10] [--poses 80] [--repeat 7]
        [--scale 1] [--skip-monte-carlo]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from bench_effects import per_eval_us  # noqa: E402  (benchmarks/ is on sys.path)
from tqdm import tqdm  # noqa: E402

import iwr  # noqa: E402
from iwr.effects import api  # noqa: E402
from iwr.effects.builtin import LegThermal  # noqa: E402
from iwr.effects.carriage_thermal import CarriageThermal  # noqa: E402
from iwr.effects.study import _predicted, _tool_rms  # noqa: E402

TOOL = np.array([0.0, 0.0, 200.0])


def trial(seed: int, n_poses: int, n_fresh: int, scale: float = 1.0) -> dict[str, float]:
    robot = iwr.Robot.default()
    legs = LegThermal(11.5, 20.0)
    main_model = robot.with_effects(legs)
    model = robot.with_effects(legs, CarriageThermal(11.5, 20.0, identify=True))
    rng = np.random.default_rng(seed)
    lo, hi = robot.default_bounds()
    x_true = np.concatenate([lo + (hi - lo) * rng.random(robot.n_params),
                             [2.0 * (2.0 * rng.random() - 1.0)]])
    t_cal = 20.0 + scale * (-3.0 + 8.0 * rng.random(n_poses))
    t_new = 20.0 + scale * (-6.0 + 16.0 * rng.random(n_fresh))
    seeds = rng.integers(2**31, size=2)
    noise = iwr.Noise.realistic()
    data, _ = api.simulate(model, n_poses, seed=int(seeds[0]), x=x_true, noise=noise,
                           temperatures=t_cal)
    fresh, _ = api.simulate(model, n_fresh, seed=int(seeds[1]), x=x_true, temperatures=t_new)
    truth = fresh.poses
    base = iwr.identify(main_model, data, "efficient", noise=noise)
    ext = iwr.identify(model, data, "efficient", noise=noise)
    return {"main_fit_ok": float(base.fit_ok), "main_p": float(base.fit.p_value),
            "main_tool": _tool_rms(main_model, base.x, fresh, truth, TOOL),
            "main_predicted": _predicted(main_model, fresh, base, TOOL),
            "ext_fit_ok": float(ext.fit_ok), "ext_p": float(ext.fit.p_value),
            "ext_tool": _tool_rms(model, ext.x, fresh, truth, TOOL),
            "ext_predicted": _predicted(model, fresh, ext, TOOL),
            "alpha_error": float(ext.x[-1] - x_true[-1]), "alpha_sd": float(ext.std[-1])}


def monte_carlo(seeds: int, n_poses: int, n_fresh: int, scale: float) -> None:
    start = time.time()
    runs = [trial(s, n_poses, n_fresh, scale) for s in tqdm(range(seeds), file=sys.stderr)]
    col = {k: np.array([r[k] for r in runs]) for k in runs[0]}
    print(f"IWR, {n_poses} calibration poses at 20 + {scale:g} (-3 .. +5) C, {n_fresh} fresh "
          f"poses at 20 + {scale:g} (-6 .. +10) C, iwr.Noise.realistic(), {seeds} seeds "
          f"({time.time() - start:.0f} s)")
    for name, key in (("legs' expansion only (main's model)", "main"),
                      ("legs' and slides' expansion", "ext")):
        tool, pred = col[f"{key}_tool"], col[f"{key}_predicted"]
        print(f"{name}: fit test passed {int(col[f'{key}_fit_ok'].sum())}/{seeds} (median p "
              f"{np.median(col[f'{key}_p']):.2g}); tool position RMS on the fresh poses: mean "
              f"{1e3 * tool.mean():.1f} um (predicted {1e3 * pred.mean():.1f}); actual / "
              f"predicted, RMS over the seeds {math.sqrt(np.mean(tool**2) / np.mean(pred**2)):.2f},"
              f" per seed median {np.median(tool / pred):.2f} ({(tool / pred).min():.2f} .. "
              f"{(tool / pred).max():.2f})")
    ratio = col["main_tool"] / col["ext_tool"]
    print(f"main's / extended tool error per seed: median {np.median(ratio):.2f} "
          f"({ratio.min():.2f} .. {ratio.max():.2f}); RMS over the seeds "
          f"{math.sqrt(np.mean(col['main_tool']**2) / np.mean(col['ext_tool']**2)):.2f}")
    z = col["alpha_error"] / col["alpha_sd"]
    print(f"carriage.alpha: error RMS {math.sqrt(np.mean(col['alpha_error']**2)):.2f} ppm/K, "
          f"sd mean {col['alpha_sd'].mean():.2f} ppm/K, error / sd RMS "
          f"{math.sqrt(np.mean(z**2)):.2f}")


def hot_path(repeat: int) -> None:
    from iwr.effects import tracker as et
    from iwr.effects.tracker_study import PAYLOADS

    robot = iwr.Robot.default()
    legs = LegThermal(11.5, 20.0, identify=True)
    both = robot.with_effects(legs, CarriageThermal(11.5, 20.0, identify=True))
    data, _ = api.simulate(both, 100, seed=1)
    rng = np.random.default_rng(2)
    for name, r in (("legs' expansion", robot.with_effects(legs)), ("legs' and slides'", both)):
        p = iwr.Problem(r, data)
        X = p.lower + (p.upper - p.lower) * rng.random((650, p.n_params))
        us = per_eval_us(lambda X, p=p: p.cost_batch(X, workers=1), X, repeat)
        print(f"pose data, N = 100, {name}: {us:.1f} us per evaluation")
    tracker_robot = _tracker_robot()
    comp, therm = api.realistic(tracker_robot)
    for name, effects in (("legs' compliance and expansion", (comp, therm)),
                          ("with the slides' expansion", (comp, therm, CarriageThermal(
                              11.5, 20.0, identify=True)))):
        r = tracker_robot.with_effects(*effects)
        tdata, _ = et.simulate(r, 100, seed=1, payloads=PAYLOADS)
        problem, _ = et.effect_tracker_problem(r, tdata)
        X = problem.lower + (problem.upper - problem.lower) * rng.random((200, problem.n_params))
        us = per_eval_us(lambda X, p=problem: p.cost_batch(X, workers=1), X, repeat)
        print(f"tracker points, N = 100, {name}: {us:.1f} us per evaluation")


def _tracker_robot() -> iwr.Robot:
    """The default IWR measured by three reflectors (as the tests' robot_measured_by)."""
    return iwr.Robot.default().with_tracker(
        registration=(2000.0, -150.0, 300.0, 1.5, 0.01, -0.02), reflectors=[
            (120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--poses", type=int, default=80)
    ap.add_argument("--fresh", type=int, default=50)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--scale", type=float, default=1.0,
                    help="the temperatures' spread about 20 C scaled by this factor")
    ap.add_argument("--skip-monte-carlo", action="store_true")
    a = ap.parse_args()
    if not a.skip_monte_carlo:
        monte_carlo(a.seeds, a.poses, a.fresh, a.scale)
    if a.repeat > 0:
        hot_path(a.repeat)


if __name__ == "__main__":
    main()
