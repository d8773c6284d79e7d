"""DE on ballbar data through ``iwr.identify``: the C++ ballbar objective (``BallbarProblem.cost``
and its threaded ``cost_batch``) against the NumPy path it replaced (each row's cost from
``BallbarProblem.residuals``, one row after the other), on the same data, seed and settings.

    python benchmarks/ballbar_de_speed.py [N_POSES] [GENERATIONS] [WORKERS]

Prints the wall time and evaluations per second of each path, the speed-up, and the two runs'
best costs (the same search to rounding: the C++ and NumPy residuals agree to ~1e-15 relative,
and DE's selection may part at a tie, so the costs are compared, not asserted equal).
"""

from __future__ import annotations

import sys
import time

import numpy as np

import iwr
from iwr.ballbar import BallbarNoise, BallbarProblem
from iwr.methods import run_method

SETUPS = {
    "A": {"platform_ball": [0.0, 0.0, -60.0], "fixed_ball": [800.0, -800.0, 1500.0],
          "range": [300.0, 700.0]},
    "B": {"platform_ball": [100.0, 50.0, -60.0], "fixed_ball": [900.0, -200.0, 2400.0],
          "range": [300.0, 700.0]},
}


class NumpyBallbarProblem(BallbarProblem):
    """The cost as it was before the C++ objective: the NumPy residuals, row by row."""

    def cost(self, x):  # type: ignore[no-untyped-def]
        r = self.residuals(x)
        return float(r @ r)

    def engine_objective(self):  # type: ignore[no-untyped-def]
        return None  # no C++ objective: DE calls cost_batch, row by row in NumPy


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 60
    generations = int(sys.argv[2]) if len(sys.argv) > 2 else 30
    workers = int(sys.argv[3]) if len(sys.argv) > 3 else 1
    robot = iwr.Robot.default().with_instrument("ballbar", SETUPS)
    noise = (iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6), BallbarNoise(0.001))
    data, _ = iwr.simulate(robot, n, seed=1, noise=noise)
    setup = robot.instruments["ballbar"]
    times = {}
    for name, cls in (("numpy (before)", NumpyBallbarProblem), ("C++ objective", BallbarProblem)):
        problem = cls(robot, setup, data)
        mask = np.ones(problem.n_params, dtype=bool)
        start = time.perf_counter()
        res = run_method(problem, "de", mask, np.zeros(problem.n_params), seed=3,
                         generations=generations, polish=False, progress=False,
                         workers=workers)
        wall = time.perf_counter() - start
        # The C++ objective: the engine on `workers` threads, no Python in the loop; the NumPy
        # one: the engine calls cost_batch once per generation (its rows one after the other).
        times[name] = wall
        print(f"{name:15s}: {wall:7.2f} s, {res.nfev} evaluations, {res.nfev / wall:9.0f} /s, "
              f"best cost {res.fun:.10e}")
    print(f"speed-up: {times['numpy (before)'] / times['C++ objective']:.1f}x "
          f"(N = {n} poses, {generations} generations, workers = {workers})")


if __name__ == "__main__":
    main()
