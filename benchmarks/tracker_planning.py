"""Planned against random poses for laser-tracker data (docs/tracker.md, "Uncertainty and pose
planning"): the criterion, and the tool accuracy after calibration.

    python benchmarks/tracker_planning.py [points|probe] [K] [SEEDS] [CANDIDATES]
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

import iwr
from iwr.analysis.identifiability import column_scale
from iwr.planning import _criterion, _tracker_problem, measure
from iwr.simulation import sample_poses
from iwr.tracker import TrackerNoise

REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
NOISE = (iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6), TrackerNoise.leica())


def main() -> None:
    kind = sys.argv[1] if len(sys.argv) > 1 else "points"
    k = int(sys.argv[2]) if len(sys.argv) > 2 else 25
    seeds = int(sys.argv[3]) if len(sys.argv) > 3 else 5
    m = int(sys.argv[4]) if len(sys.argv) > 4 else 500
    kw = {"reflectors": REFLECTORS} if kind == "points" else {"probe": (0, 0, 60, 0, 0, 0)}
    robot = iwr.Robot.default().with_tracker(registration=REGISTRATION, **kw)
    q, poses, legs = sample_poses(robot, m, np.random.default_rng(0))
    cand = iwr.Measurements(q, poses, legs, joint_types=robot.joint_types)
    problem, x = _tracker_problem(robot, cand, None)
    for crit in ("O1", "O3"):
        start = time.time()
        plan = iwr.plan_poses(robot, cand, k, criterion=crit, seed=0)
        jac = problem.jacobian(x)[:, plan.base_indices]
        js = (jac / column_scale(jac)).reshape(m, 3 * robot.tracker.n_points, -1)

        def value(idx: np.ndarray, crit: str = crit, js: np.ndarray = js) -> float:
            info = np.einsum("kij,kil->jl", js[idx], js[idx])
            return float(_criterion(np.linalg.eigvalsh(info), crit, len(idx)))

        rand = [value(np.random.default_rng(100 + s).choice(m, k, replace=False))
                for s in range(20)]
        print(f"{kind} K={k} {crit}: planned {plan.value:.4g}, random median "
              f"{np.median(rand):.4g}, best of 20 {max(rand):.4g} ({time.time() - start:.1f} s)")
    plan = iwr.plan_poses(robot, cand, k, criterion="O1", seed=0)
    rows = []
    for s in range(seeds):
        _, truth = iwr.simulate(robot, 1, seed=s)
        fresh, _ = iwr.simulate(robot, 50, seed=1000 + s, x=truth)
        out = []
        for idx in (plan.indices, np.random.default_rng(200 + s).choice(m, k, replace=False)):
            data = measure(robot, truth, cand.q[idx], cand.poses[idx], noise=NOISE, seed=300 + s)
            res = iwr.identify(robot, data, active="base")
            acc = iwr.accuracy(robot, fresh, res.x, truth=truth).calibrated
            out += [math.sqrt(np.mean(acc.position**2)), math.sqrt(np.mean(acc.orientation**2))]
        rows.append(out)
        print(f"truth {s}: planned {out[0]:.4g} mm, {out[1]:.4g} deg; random {out[2]:.4g} mm, "
              f"{out[3]:.4g} deg")
    r = np.array(rows)
    print(f"median position planned {np.median(r[:, 0]):.4g} mm, random {np.median(r[:, 2]):.4g} "
          f"mm; orientation planned {np.median(r[:, 1]):.4g} deg, random "
          f"{np.median(r[:, 3]):.4g} deg; planned better in position for "
          f"{int(np.sum(r[:, 0] < r[:, 2]))} of {len(r)}")


if __name__ == "__main__":
    main()
