"""What the non-geometric effects cost on DE's hot path (issue 23, item 2).

DE's population evaluation, ``cost_batch`` of the leg objective on 650 random vectors within the
bounds (one DE generation at NP = 10 D for the IWR with both effects), N = 100 poses
(``iwr.effects.api.simulate``, seed 1), one thread, for every SIMD variant of the geometric kernel
this CPU runs (``iwr._core._select_kernel``): the geometry alone (``iwr.Problem`` of the robot
without effects: the SIMD kernels) against the objective with effects (``cpp/src/effects.cpp``:
the legs' compliance under the load, from the hexapod's statics, and their thermal growth;
portable scalar code, the same on every variant), and each effect alone. The minimum over
``--repeat`` repetitions of the calling thread's CPU time per evaluation (one thread: the batch
runs in the calling thread; on a shared machine the wall time of a batch that is preempted counts
the time it waited, its CPU time does not), with the other processes' load
(``_load.OtherLoad``).

``--reference PATH/_core....so``: also times the geometric objective of another build of the
compiled core (e.g. main's, before the effects) on the same vectors, and checks that its costs
are the same bits: the geometry alone neither slower nor different.

Usage::

    python benchmarks/bench_effects.py [--repeat 30] [--reference /path/to/_core.cpython-*.so]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import math  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
from _load import OtherLoad  # noqa: E402

# iwr is imported in main(): the --worker process loads another build's _core alone.


def per_eval_us(fn: Any, X: np.ndarray, repeat: int) -> float:
    """The least CPU time of this thread per evaluation (one thread: the batch runs in the calling
    thread), so that a batch preempted on a shared machine is not counted for the time it
    waited."""
    fn(X[:8])  # warm-up
    best = math.inf
    for _ in range(repeat):
        t = time.thread_time()
        fn(X)
        best = min(best, (time.thread_time() - t) / X.shape[0] * 1e6)
    return best


def reference_worker(npz: str, so: str, repeat: int) -> None:
    """In its own process (two builds of _core cannot share one: pybind11 registers their types
    once): the geometric objective of the build ``so`` on the arrays of ``npz``, per variant its
    costs and CPU time per evaluation, into ``npz``.out.npz."""
    spec = importlib.util.spec_from_file_location("_core", so)
    assert spec is not None and spec.loader is not None
    ref = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ref)
    d = np.load(npz)
    obj = ref.Objective(ref.Geometry(str(d["joint_types"]), d["dh"], d["base"], d["platform"],
                                     d["offsets"]), d["q"], d["poses"], d["legs"])
    out = {}
    for variant in d["variants"]:
        ref._select_kernel(str(variant))
        out[f"{variant}_costs"] = obj.cost_batch(d["X"], 1)
        out[f"{variant}_us"] = per_eval_us(lambda A: obj.cost_batch(A, 1), d["X"], repeat)
    np.savez(npz + ".out.npz", **out)


def reference_times(so: str, robot: Any, m: Any, X: np.ndarray, repeat: int,
                    variants: list[str]) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        npz = os.path.join(tmp, "data.npz")
        np.savez(npz, joint_types=robot.joint_types, dh=robot.dh, base=robot.base_joints,
                 platform=robot.platform_joints, offsets=robot.leg_offsets, q=m.q,
                 poses=m.poses, legs=m.legs, X=X, variants=variants)
        subprocess.run([sys.executable, __file__, "--worker", npz, so, "--repeat", str(repeat)],
                       check=True)
        with np.load(npz + ".out.npz") as f:
            return dict(f)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=30)
    ap.add_argument("--reference", help="another build's _core module (.so) to compare with")
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        reference_worker(*args.worker, args.repeat)
        return
    import iwr
    from iwr import _core
    from iwr.effects import api

    robot = iwr.Robot.default()
    comp, thermal = api.realistic(robot)
    both = robot.with_effects(comp, thermal)
    m, _ = api.simulate(both, 100, seed=1)
    problems = {
        "geometry alone": iwr.Problem(robot, m),
        "compliance + thermal": iwr.Problem(both, m),
        "compliance": iwr.Problem(robot.with_effects(comp), m),
        "thermal": iwr.Problem(robot.with_effects(thermal), m),
    }
    rng = np.random.default_rng(0)
    full = problems["compliance + thermal"]
    X = rng.uniform(full.lower, full.upper, (650, full.n_params))  # NP = 10 D
    cols = {name: X[:, : p.n_params] if name != "thermal" else np.hstack(
        [X[:, : robot.n_params], X[:, -1:]]) for name, p in problems.items()}
    reference = None
    if args.reference:  # first, alone: its process and ours do not overlap
        reference = reference_times(args.reference, robot, m, cols["geometry alone"],
                                    args.repeat, _core._supported_kernels())
    rows = []
    initial = _core._active_kernel()
    with OtherLoad() as load:
        for variant in _core._supported_kernels():
            _core._select_kernel(variant)
            times = {name: per_eval_us(lambda A, p=p: p.cost_batch(A, workers=1), cols[name],
                                       args.repeat) for name, p in problems.items()}
            if reference is not None:
                times["reference"] = float(reference[f"{variant}_us"])
                times["same bits"] = np.array_equal(
                    reference[f"{variant}_costs"],
                    problems["geometry alone"].cost_batch(cols["geometry alone"], workers=1))
            rows.append((variant, times))
    _core._select_kernel(initial)
    other = "?" if load.cores is None else f"{load.cores:.2f}"
    print(f"N = 100 poses, cost_batch of {X.shape[0]} vectors, one thread, CPU time per "
          f"evaluation (us), minimum of {args.repeat}; other processes: {other} cores")
    print()
    head = "| variant | geometry alone | compliance + thermal | ratio | compliance | thermal |"
    line = "|---|---|---|---|---|---|"
    if reference is not None:
        head += " reference build, geometry | same bits |"
        line += "---|---|"
    print(head)
    print(line)
    for variant, t in rows:
        g, b = t["geometry alone"], t["compliance + thermal"]
        row = (f"| {variant} | {g:.3f} | {b:.3f} | {b / g:.1f}x | {t['compliance']:.3f} "
               f"| {t['thermal']:.3f} |")
        if reference is not None:
            row += f" {t['reference']:.3f} | {'yes' if t['same bits'] else 'NO'} |"
        print(row)


if __name__ == "__main__":
    main()
