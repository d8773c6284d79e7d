"""Differential evolution on the IWR calibration (NP = 600, N = 100 poses, the paper's DE/rand/1/bin
with F = 0.9, CR = 1): iwr's engine against SciPy's and pygmo's on the same objective, and the wall
time of the paper's full run (60000 generations, 36 million evaluations).

The three run the same objective, ``iwr.Problem`` on the same simulated data, through the Python
API:
- iwr: ``iwr.identify(robot, data, method="de", population_size=600, F=0.9, CR=1.0, ...)``; the
  engine and the objective are C++, no Python in the loop, ``workers`` threads.
- SciPy: ``scipy.optimize.differential_evolution(strategy="rand1bin", popsize=10, mutation=0.9,
  recombination=1.0, updating="deferred", vectorized=True, polish=False, tol=0)``, the function
  being ``Problem.cost_batch`` on the transposed population (so SciPy also evaluates on ``workers``
  threads). SciPy's population is popsize x D = 10 x 58 = 580 (600 / 58 rounded); generation rates
  are therefore also given per evaluation.
- pygmo: ``pygmo.de(variant=7, F=0.9, CR=1.0, ftol=0, xtol=0)`` (rand/1/bin) on a pygmo problem
  whose ``fitness`` calls ``Problem.cost``. pygmo's ``de`` evaluates one individual at a time and
  has no batch (bfe) interface, so its run is single-threaded; the problem also defines
  ``batch_fitness`` (``Problem.cost_batch``), which ``de`` does not use.
Generation rates are measured as (G2 - G1) / (t(G2) - t(G1)) from two runs of G1 and G2 generations,
which cancels the set-up (problem construction, initial population) out of every library's figure.
Ratios come from the same invocation of this script, one after the other. Runs are timed in wall
time; "cores obtained" (process CPU time / wall time) shows contention from other processes, and
"other processes" the CPU the rest of the machine used meanwhile (from /proc/stat).

Usage::

    python benchmarks/bench_de.py [--quick] [--no-full] [--out benchmarks/results]

``--no-full`` skips the measured full paper run (about 17 s on 2 threads, 22 s on 1 thread on the
2-core machine of BENCHMARKS.md). The projection from generations G1..G2 is pessimistic: a run
speeds up as its population contracts (fewer mutant components leave the bounds and need repair),
so the measured full run also prints its own rate over windows of generations.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import scipy  # noqa: E402
from _load import OtherLoad  # noqa: E402
from scipy.optimize import differential_evolution as scipy_de  # noqa: E402

import iwr  # noqa: E402
from iwr import _core  # noqa: E402

NP, N, F, CR = 600, 100, 0.9, 1.0
PAPER_GENERATIONS = 60000


def problem() -> tuple[iwr.Robot, iwr.Measurements, iwr.Problem]:
    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, n_poses=N, seed=1)
    return robot, data, iwr.Problem(robot, data)


def timed(fn) -> tuple[float, float]:
    """Wall time and process CPU time of fn()."""
    w0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w0, time.process_time() - c0


def rate(run, g1: int, g2: int, repeats: int) -> dict:
    """Generations per second from runs of g1 and g2 generations (median of `repeats` pairs)."""
    rates, cores = [], []
    with OtherLoad() as other:
        for _ in range(repeats):
            w1, c1 = timed(lambda: run(g1))
            w2, c2 = timed(lambda: run(g2))
            rates.append((g2 - g1) / max(w2 - w1, 1e-9))
            cores.append((c2 - c1) / max(w2 - w1, 1e-9))
    return {
        "gen_per_s": float(np.median(rates)),
        "cores": float(np.median(cores)),
        "all": rates,
        "other_processes_cores": other.cores,
    }


def iwr_runner(robot, data, workers: int):
    def run(generations: int):
        return iwr.identify(
            robot,
            data,
            method="de",
            population_size=NP,
            F=F,
            CR=CR,
            generations=generations,
            seed=1,
            workers=workers,
            polish=False,
            progress=False,
        )

    return run


def scipy_runner(p: iwr.Problem, workers: int):
    popsize = round(NP / p.n_params)

    def run(generations: int):
        return scipy_de(
            lambda X: p.cost_batch(X.T, workers=workers),
            list(zip(p.lower, p.upper, strict=True)),
            strategy="rand1bin",
            popsize=popsize,
            mutation=F,
            recombination=CR,
            maxiter=generations,
            tol=0,
            atol=0,
            polish=False,
            updating="deferred",
            vectorized=True,
            init="random",
            rng=1,
        )

    return run, popsize * p.n_params


def pygmo_runner(p: iwr.Problem):
    import pygmo

    class IWRProblem:
        """The IWR calibration as a pygmo problem (a user-defined problem)."""

        def fitness(self, x):
            return [p.cost(x)]

        def batch_fitness(self, dvs):  # pygmo's de does not use it; see the module docstring
            return p.cost_batch(np.reshape(dvs, (-1, p.n_params)), workers=1)

        def get_bounds(self):
            return (list(p.lower), list(p.upper))

        def get_name(self):
            return "IWR calibration, eq. (10)"

    prob = pygmo.problem(IWRProblem())

    def run(generations: int):
        pop = pygmo.population(prob, size=NP, seed=1)
        algo = pygmo.algorithm(
            pygmo.de(gen=generations, F=F, CR=CR, variant=7, ftol=0, xtol=0, seed=1)
        )
        return algo.evolve(pop)

    return run, pygmo.__version__


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="shorter runs (a smoke test)")
    ap.add_argument("--no-full", action="store_true", help="skip the measured full paper run")
    ap.add_argument("--repeats", type=int, default=None)
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = ap.parse_args()
    repeats = args.repeats or (1 if args.quick else 3)
    args.out.mkdir(parents=True, exist_ok=True)
    robot, data, p = problem()
    print(
        f"iwr {iwr.__version__}, kernel {_core._active_kernel()}, SciPy {scipy.__version__}, "
        f"load average {os.getloadavg()[0]:.2f}"
    )

    results: dict = {"load_average_at_start": os.getloadavg()[0]}
    iwr_g = (200, 1200) if args.quick else (500, 3500)
    for w in (1, 2):
        results[f"iwr_{w}"] = rate(iwr_runner(robot, data, w), *iwr_g, repeats)
    sc_g = (5, 25) if args.quick else (10, 60)
    for w in (1, 2):
        run, sc_np = scipy_runner(p, w)
        results[f"scipy_{w}"] = {**rate(run, *sc_g, repeats), "NP": sc_np}
    try:
        run, version = pygmo_runner(p)
        pg_g = (2, 6) if args.quick else (5, 25)
        results["pygmo_1"] = {**rate(run, *pg_g, repeats), "NP": NP, "version": version}
    except ImportError:
        print("pygmo is not installed (pip install pygmo): skipped")

    rows = []
    for key, label, np_ in [
        ("iwr_1", "iwr, 1 thread", NP),
        ("iwr_2", "iwr, 2 threads", NP),
        ("scipy_1", "SciPy, cost_batch on 1 thread", None),
        ("scipy_2", "SciPy, cost_batch on 2 threads", None),
        ("pygmo_1", "pygmo de, Problem.cost (serial)", NP),
    ]:
        if key not in results:
            continue
        r = results[key]
        size = np_ or r["NP"]
        us = 1e6 / (r["gen_per_s"] * size)
        rows.append((label, r["gen_per_s"], size, us, r["cores"], r["other_processes_cores"], key))
    print(
        "\n| run | generations/s | NP | us per individual | iwr (same threads) is faster by |"
        " cores obtained | other processes (cores) |"
    )
    print("|---|---|---|---|---|---|---|")
    for label, gps, size, us, cores, others, key in rows:
        threads = key.split("_")[1]
        mine = results[f"iwr_{threads}"]
        ratio = mine["gen_per_s"] / gps
        per_eval = (mine["gen_per_s"] * NP) / (gps * size)
        vs = (
            ""
            if key.startswith("iwr")
            else f"{ratio:.1f}x per generation, {per_eval:.1f}x per evaluation"
        )
        oth = "?" if others is None else f"{others:.2f}"
        print(f"| {label} | {gps:.1f} | {size} | {us:.2f} | {vs} | {cores:.2f} | {oth} |")
    s2 = results["iwr_2"]["gen_per_s"] / results["iwr_1"]["gen_per_s"]
    results["speedup_2_threads"] = s2
    print(f"\niwr: 2 threads are {s2:.2f}x as fast as 1")
    # Each library at its best on this machine (pygmo's de has a single serial mode).
    best_iwr = max(results["iwr_1"]["gen_per_s"], results["iwr_2"]["gen_per_s"])
    for lib, keys in [("SciPy", ("scipy_1", "scipy_2")), ("pygmo", ("pygmo_1",))]:
        have = [results[k]["gen_per_s"] for k in keys if k in results]
        if have:
            results[f"best_vs_{lib.lower()}"] = best_iwr / max(have)
            print(
                f"iwr at its best ({best_iwr:.1f} gen/s) / {lib} at its best ({max(have):.1f} "
                f"gen/s): {best_iwr / max(have):.1f}x per generation"
            )

    # Where the time goes: the objective alone at NP = 600 (cost_batch) against the DE generation.
    X = np.random.default_rng(0).uniform(p.lower, p.upper, (NP, p.n_params))
    for w in (1, 2):
        p.cost_batch(X, workers=w)
        t = min(timed(lambda w=w: p.cost_batch(X, workers=w))[0] for _ in range(20))
        gen = 1 / results[f"iwr_{w}"]["gen_per_s"]
        results[f"cost_batch_{w}"] = t
        print(
            f"{w} thread(s): one generation {gen * 1e3:.3f} ms, of which the objective alone "
            f"(Problem.cost_batch of 600) {t * 1e3:.3f} ms; the DE loop adds "
            f"{(gen - t) / NP * 1e6:.3f} us per individual"
        )

    print(f"\nthe paper's full run (NP = {NP}, {PAPER_GENERATIONS} generations, N = {N}):")
    for w in (1, 2):
        proj = PAPER_GENERATIONS / results[f"iwr_{w}"]["gen_per_s"]
        results[f"paper_projected_{w}"] = proj
        print(f"  projected, {w} thread(s): {proj:.1f} s")
    if not args.no_full:
        for w in (2, 1):
            proj = results[f"paper_projected_{w}"]
            if proj > 300:
                print(f"  {w} thread(s): projected over 5 minutes, not measured")
                continue
            res = None

            def full(w=w):
                nonlocal res
                res = iwr_runner(robot, data, w)(PAPER_GENERATIONS)

            with OtherLoad() as other:
                wall, cpu = timed(full)
            results[f"paper_measured_{w}"] = {
                "wall": wall,
                "cores": cpu / wall,
                "other_processes_cores": other.cores,
                "best": res.fun,
                "nfev": res.nfev,
            }
            print(
                f"  measured, {w} thread(s): {wall:.1f} s wall ({cpu / wall:.2f} cores obtained, "
                f"other processes {other}),"
                f" best cost {res.fun:.3e} after {res.nfev} evaluations"
            )
            g, el = np.asarray(res.history["generation"]), np.asarray(res.history["elapsed"])
            windows = [(0, 3500), (3500, 20000), (20000, 40000), (40000, PAPER_GENERATIONS)]
            rates = [float((g[b] - g[a]) / (el[b] - el[a])) for a, b in windows if b < len(g)]
            results[f"paper_measured_{w}"]["gen_per_s_windows"] = dict(
                zip([f"{a}-{b}" for a, b in windows], rates, strict=False)
            )
            print(
                "    generations/s over generations "
                + ", ".join(f"{a}-{b}: {r:.0f}" for (a, b), r in zip(windows, rates, strict=False))
            )
    results["load_average_at_end"] = os.getloadavg()[0]
    print(f"\nload average at end: {results['load_average_at_end']:.2f}")
    (args.out / "de.json").write_text(json.dumps(results, indent=1))
    print(f"wrote {args.out / 'de.json'}")


if __name__ == "__main__":
    main()
