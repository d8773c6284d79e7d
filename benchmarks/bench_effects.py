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

Then tracker data (issue 23: ``cpp/src/effects_tracker.cpp``): the point objective of 100 poses
of three reflectors, and of a probe (``iwr.effects.tracker.simulate``, seed 1, payloads none and
the 80 kg head), on 800 random vectors within the bounds of the problem with effects: the
geometry alone (``iwr.tracker.TrackerProblem``: the SIMD kernels) against the objective with
effects (``iwr.effects.tracker.TrackerEffectProblem``'s C++ cost: forward kinematics with the
effects by Newton's method, scalar), the active variant only (the objective with effects has
none).

``--reference PATH/_core....so``: also times the geometric objectives (leg data, tracker points)
of another build of the compiled core (e.g. main's, before the change) on the same vectors, and
checks that its costs are the same bits, and the leg objective with effects' too: the geometry
alone neither slower nor different.

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
    d = np.load(npz, allow_pickle=True)
    geometry = ref.Geometry(str(d["joint_types"]), d["dh"], d["base"], d["platform"],
                            d["offsets"])
    obj = ref.Objective(geometry, d["q"], d["poses"], d["legs"])
    effects = ref.EffectObjective(geometry, list(d["effects"]), d["q"], d["poses"], d["legs"],
                                  d["payload"], d["temperatures"])
    tracker = ref.TrackerObjective(geometry, "points", d["registration"], d["reflectors"],
                                   np.zeros(6), 100.0, d["tq"], d["tlegs"], d["tpoints"],
                                   np.zeros(d["dh"].size + 42), d["home"])
    out = {"effects_costs": effects.cost_batch(d["XE"], 1)}
    for variant in d["variants"]:
        ref._select_kernel(str(variant))
        out[f"{variant}_costs"] = obj.cost_batch(d["X"], 1)
        out[f"{variant}_us"] = per_eval_us(lambda A: obj.cost_batch(A, 1), d["X"], repeat)
        out[f"{variant}_tracker_costs"] = tracker.cost_batch(d["XT"], 1)
        out[f"{variant}_tracker_us"] = per_eval_us(lambda A: tracker.cost_batch(A, 1), d["XT"],
                                                   repeat)
    np.savez(npz + ".out.npz", **out)


def reference_times(so: str, robot: Any, m: Any, X: np.ndarray, repeat: int,
                    variants: list[str], both: Any, XE: np.ndarray, tracker: Any,
                    XT: np.ndarray) -> dict[str, Any]:
    """The reference build's costs and times: the geometric leg objective on ``X``, the leg
    objective with ``both``'s effects on ``XE``, the geometric point objective of ``tracker``
    (its problem) on ``XT``."""
    from iwr.problem import effect_inputs

    inputs = effect_inputs(both, m)
    tm, setup = tracker.measurements, tracker.setup
    with tempfile.TemporaryDirectory() as tmp:
        npz = os.path.join(tmp, "data.npz")
        effects = np.empty(len(inputs["effects"]), dtype=object)
        effects[:] = inputs["effects"]
        np.savez(npz, joint_types=robot.joint_types, dh=robot.dh, base=robot.base_joints,
                 platform=robot.platform_joints, offsets=robot.leg_offsets, q=m.q,
                 poses=m.poses, legs=m.legs, X=X, variants=variants, effects=effects,
                 payload=inputs["payload"], temperatures=inputs["temperatures"], XE=XE,
                 registration=setup.registration, reflectors=setup.reflectors, tq=tm.q,
                 tlegs=tm.legs, tpoints=tm.tracker_points(setup), home=robot.home_pose, XT=XT)
        subprocess.run([sys.executable, __file__, "--worker", npz, so, "--repeat", str(repeat)],
                       check=True)
        with np.load(npz + ".out.npz") as f:
            return dict(f)


def tracker_problems(robot: Any, kind: str) -> tuple[dict[str, Any], np.ndarray]:
    """The point (probe) problems of 100 simulated poses with and without the effects, and 800
    random vectors within the bounds of the problem with both effects."""
    from iwr.effects import api
    from iwr.effects import tracker as et
    from iwr.tracker.api import tracker_problem

    registration = (2000.0, -150.0, 300.0, 1.5, 0.01, -0.02)
    instrument = (robot.with_tracker(registration=registration, reflectors=[
        (120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]) if kind == "points"
        else robot.with_tracker(registration=registration, probe=(10.0, -5.0, 60.0, 0.1, 0, 0.2)))
    comp, thermal = api.realistic(robot)
    both = instrument.with_effects(comp, thermal)
    data, _ = et.simulate(both, 100, seed=1)
    problems = {"geometry alone": tracker_problem(instrument, data)[0],
                "compliance + thermal": et.effect_tracker_problem(both, data)[0],
                "compliance": et.effect_tracker_problem(instrument.with_effects(comp), data)[0],
                "thermal": et.effect_tracker_problem(instrument.with_effects(thermal), data)[0]}
    full = problems["compliance + thermal"]
    X = np.random.default_rng(0).uniform(full.lower, full.upper, (800, full.n_params))
    return problems, X


def tracker_columns(X: np.ndarray, name: str, ng: int) -> np.ndarray:
    """The columns of ``X`` (geometric 58, compliance 6, alpha 1, setup) a problem takes."""
    keep = {"geometry alone": [], "compliance + thermal": list(range(ng, ng + 7)),
            "compliance": list(range(ng, ng + 6)), "thermal": [ng + 6]}[name]
    return np.hstack([X[:, :ng], X[:, keep], X[:, ng + 7:]])


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
    tracker = {kind: tracker_problems(robot, kind) for kind in ("points", "probe")}
    reference = None
    if args.reference:  # first, alone: its process and ours do not overlap
        problems_t, XT = tracker["points"]
        reference = reference_times(
            args.reference, robot, m, cols["geometry alone"], args.repeat,
            _core._supported_kernels(), both, X, problems_t["geometry alone"],
            tracker_columns(XT, "geometry alone", robot.n_params))
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
            if reference is not None:
                pt, XT = tracker["points"]
                XG = tracker_columns(XT, "geometry alone", robot.n_params)
                times["tracker"] = per_eval_us(
                    lambda A, p=pt["geometry alone"]: p.cost_batch(A, workers=1), XG, args.repeat)
                times["tracker reference"] = float(reference[f"{variant}_tracker_us"])
                times["tracker same bits"] = np.array_equal(
                    reference[f"{variant}_tracker_costs"],
                    pt["geometry alone"].cost_batch(XG, workers=1))
            rows.append((variant, times))
    _core._select_kernel(initial)
    with OtherLoad() as tload:
        trows = []
        for kind, (tp, XT) in tracker.items():
            times = {name: per_eval_us(
                lambda A, p=p: p.cost_batch(A, workers=1),
                tracker_columns(XT, name, robot.n_params), args.repeat)
                for name, p in tp.items()}
            trows.append((kind, times))
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
    if reference is not None:
        same = np.array_equal(reference["effects_costs"],
                              problems["compliance + thermal"].cost_batch(X, workers=1))
        print()
        print(f"the leg objective with effects, this build against the reference: "
              f"{'the same bits' if same else 'DIFFERENT COSTS'}")
        print()
        print("| variant | tracker points, geometry alone | reference build | same bits |")
        print("|---|---|---|---|")
        for variant, t in rows:
            print(f"| {variant} | {t['tracker']:.3f} | {t['tracker reference']:.3f} | "
                  f"{'yes' if t['tracker same bits'] else 'NO'} |")
    other = "?" if tload.cores is None else f"{tload.cores:.2f}"
    print()
    print(f"tracker data, N = 100 poses, cost_batch of 800 vectors, one thread, CPU time per "
          f"evaluation (us), minimum of {args.repeat}, variant {initial}; other processes: "
          f"{other} cores")
    print()
    print("| data | geometry alone (SIMD) | compliance + thermal | ratio | compliance | thermal |")
    print("|---|---|---|---|---|---|")
    for kind, t in trows:
        g, b = t["geometry alone"], t["compliance + thermal"]
        print(f"| {kind} | {g:.3f} | {b:.3f} | {b / g:.1f}x | {t['compliance']:.3f} "
              f"| {t['thermal']:.3f} |")


if __name__ == "__main__":
    main()
