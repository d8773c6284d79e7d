"""Two builds of iwr side by side, alternated in one run, every kernel variant and thread count:
the leg objective per evaluation (and its fraction of the floating-point floor of the variant's own
instruction set), `cost_batch` of a DE population, and DE's generations per second (issue 24).

Each build runs in its own Python process (``--python NAME=PATH``, e.g. the interpreter of a
virtualenv with that build installed), started once and kept; the parent sends each process one
measurement at a time and alternates the builds (old, new, new, old, ...), so that a neighbour's
load or a clock change hits both alike. The machine may be shared: every table is printed with the
load average and the CPU other processes used meanwhile (from /proc/stat), and the core-to-core
round trip at its start and end (``_bench.measure_core_round_trip_ns``, in the first build that
has it): on a virtual machine the host may move the two vCPUs between dies from one minute to the
next, and DE's own work on two threads moves with it (BENCHMARKS.md, twenty-ninth round).

What is timed (per build, per kernel variant forced with ``iwr._core._select_kernel``):

- objective: ``Problem.cost_batch(X, workers=1)`` on 600 random vectors within the default bounds
  (one DE population), N = 100 poses (``iwr.simulate(Robot.default(), 100, seed=1)``), in thread CPU
  time, divided by 600; the minimum over at least ``--repeat`` (default 15) repetitions, taken in
  rounds over every variant (and objective) for at least ``--seconds`` (default 20 s), the builds
  alternated, a call during which the thread was switched out taken again (``spread()`` says
  why: a variant's repetitions in a row made the tables bimodal on a shared machine). "of the
  floor": N x 370 flops (issue 24's floor: the kernel's count before the carriage was folded; it
  does 328 since) at the peak of one core measured with the same instruction set and separate
  multiplies and adds (``_bench.measure_peak_gflops``), divided by the time. ``--objectives`` adds
  the weighted leg objective (a weight per leg reading: 376 flops a pose), the whitened one
  (``noise=Noise.realistic()``: 406), the tracker point objective (``TrackerProblem``, K = 3
  reflectors, N = 100 poses of ``simulate_tracker``, seed 1: FLOPS_TRACKER a pose, see there) and
  the same weighted by the readings' and the tracker's noise (``noise=(Noise(...),
  TrackerNoise.leica())``: FLOPS_TRACKER + 81); a build without one of them (``aa02662`` has
  neither the weights nor the tracker) prints "n/a".
- batch: ``Problem.cost_batch(X, workers=T)`` of the same 600 vectors on T threads, wall time, the
  minimum: what one DE generation's objective costs on T threads.
- DE: ``iwr.identify(method="de", population_size=600, F=0.9, CR=1, seed=1, workers=T,
  polish=False)``; generations/s = (G2 - G1) / (t(G2) - t(G1)) from runs of G1 and G2
  generations (wall time; the set-up cancels), the best of ``--de-repeat`` pairs. "DE's own" is the
  time per generation minus the batch time on the same threads: trial generation, bound repairs,
  selection, the log, the thread hand-overs, the reduced-to-full mapping.
- ``--scaling``: DE's time per generation against one ``cost_batch`` of its trials, on 1 and 2
  threads (``scaling_table``); ``--data tracker`` or ``--data ballbar`` runs it on the tracker
  point objective (K = 3, as ``--objectives``') or the ballbar's distances (two set-ups) instead
  of the leg objective: ``iwr.identify(method="de")`` on that kind's data, ``cost_batch`` of 600
  vectors within the bounds of the problem it runs on.

Usage::

    cd /tmp && python /path/to/benchmarks/bench_regression.py \\
        --python old=/work/venvs/perf-old/bin/python --python new=/work/venvs/perf/bin/python

With one ``--python`` (or none: this interpreter) it measures one build. ``--quick``: a smoke test.
``--fresh-copies``: each build's extension module is first copied to new pages (the same bytes,
``fresh_copy``); the same installed build has run one objective 35 % slower in one copy of its
pages than in another, so compare builds over several runs made so, not one.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from _load import _machine_busy  # benchmarks/ is on sys.path when this script runs

try:
    import resource

    def _switches() -> int:
        """Context switches of the calling thread so far (Linux; 0 elsewhere)."""
        r = resource.getrusage(resource.RUSAGE_THREAD)
        return r.ru_nvcsw + r.ru_nivcsw
except (ImportError, AttributeError):  # no RUSAGE_THREAD
    def _switches() -> int:
        return 0

# Untimed calls of cost_batch on more than one thread before a group of timed ones. After a pause
# (the other builds' and cells' turns) Linux may wake the pool's worker on the CPU of the thread
# that woke it (wake_affine), where it shares that CPU with the caller until the load balancer
# moves it: on the Zen 5 the first 1-48 calls (up to 10 ms) then took a single thread's time, in
# some rounds all five timed calls, so that the "like for like" figure read 0.53x (2026-11-29,
# thirty-third round). A DE run's generations follow each other with the threads running.
WARM_S = 0.03

# A timed call during which the thread was switched out runs slower by the refill of the caches
# and predictors (on the development machine 0.2 us an evaluation per switch at N = 100, about
# 20 %): such a call is taken again, up to this many times.
UNSWITCHED_TRIES = 5
COPIES = 3  # each objective's problem built this many times (Worker._objectives)

NP, N = 600, 100
# Issue 24's floor: 37,000 flops at N = 100, the count of the kernel when the issue was filed (the
# carriage joint by joint); the folded kernel does 328 (bench_objective.py's count). Kept, so that
# the fractions compare with the and with earlier rounds.
FLOPS_PER_POSE = 370
# The tracker point objective (K = 3), per pose, counted from tracker_kernel_body.inl (an FMA is 2
# flops) with the chord iterations of this data set (an instrumented copy of the kernel, per block
# of 8 poses over the 600 vectors: 4.11 residual evaluations of 91 flops, 3.11 steps of 199, 1.60
# refinements of 228), the set-up (108), the rotation at the end (54), the carriage (120) and the
# three points (45 each): 1775. Kept as the fixed measure of the work, as FLOPS_PER_POSE: since
# the nineteenth round the chord no longer forms the rotation (27 multiply-adds a pose fewer).
FLOPS_TRACKER = 1775
# flops a pose of each objective of --objectives
# (the weighted tracker: the 9 x 9 lower-triangular whitening of a pose's residuals, 45 multiplies
# and 36 adds, as the whitened leg objective's 6 x 6 adds 36.)
#: --data ballbar's two set-ups (tests/conftest.py's).
BALLBAR_SETUPS = {
    "A": {"platform_ball": [0, 0, -60], "fixed_ball": [800, -800, 1500], "range": [300, 700]},
    "B": {"platform_ball": [100, 50, -60], "fixed_ball": [900, -200, 2400], "range": [300, 700]}}
#: The tracker set-up of --objectives and --data tracker (bench_fixed_cost.py's --data tracker
#: too): the tracker 2 m from the robot, three reflectors on the platform.
TRACKER_REGISTRATION = (2000.0, 0.0, 0.0, math.pi / 2, 0.0, 0.0)
TRACKER_REFLECTORS = [(120.0, 0.0, 40.0), (-60.0, 104.0, 40.0), (-60.0, -104.0, 40.0)]
FLOPS = {"leg": FLOPS_PER_POSE, "weighted": FLOPS_PER_POSE + 6, "whitened": FLOPS_PER_POSE + 36,
         "tracker": FLOPS_TRACKER, "tracker weighted": FLOPS_TRACKER + 81}


def tracker_setup():
    """The benchmarks' TrackerSetup (ImportError in a build without iwr.tracker)."""
    from iwr.tracker import TrackerSetup

    return TrackerSetup(TRACKER_REGISTRATION, reflectors=TRACKER_REFLECTORS)


# ---- the worker: one build, in its own process ---------------------------------------------------


class Worker:
    """Runs in the build's interpreter; answers one JSON request per line on stdin."""

    def __init__(self) -> None:
        for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")
        import numpy as np

        import iwr
        from iwr import _core

        self.np, self.iwr, self.core = np, iwr, _core
        self.robot = iwr.Robot.default()
        self.data, _ = iwr.simulate(self.robot, n_poses=N, seed=1)
        self.problem = iwr.Problem(self.robot, self.data)
        p = self.problem
        rng = np.random.default_rng(0)
        self.X = p.lower + (p.upper - p.lower) * rng.random((NP, p.n_params))
        self.default_kernel = _core._active_kernel()
        self.others: dict | None = None
        # The last objective timed: the first call after another one's runs 0.5 % slower at the
        # minimum and 2-4 % at the 10th percentile (code, data and predictors to reload).
        self.last: tuple | None = None
        self.turn: dict = {}  # per objective: the copy timed last
        self.kinds: dict = {}  # --data: per kind, (robot, data, problem DE runs on, its X)

    def kind(self, data: str) -> tuple:
        """``--data``'s robot, data, the problem ``iwr.identify(method="de")`` runs on (with
        effects off: the geometry's C++ objective) and NP random vectors within its bounds:
        "leg" (poses in {0}, the tables' default), "tracker" (the point objective of
        --objectives: K = 3 reflectors, ``simulate_tracker`` seed 1, the problem made from the
        registration guess as identify makes it) or "ballbar" (two set-ups, ``iwr.simulate``
        seed 1)."""
        if data in self.kinds:
            return self.kinds[data]
        np, iwr = self.np, self.iwr
        robot = self.robot
        if data == "leg":
            got = (robot, self.data, self.problem, self.X)
        else:
            if data == "tracker":
                from iwr.tracker import simulate_tracker
                from iwr.tracker.start import tracker_problem

                setup = tracker_setup()
                measured, _ = simulate_tracker(robot, setup, N, seed=1)
                robot = robot.with_tracker(setup=setup)
                problem, _ = tracker_problem(robot, measured)
            elif data == "ballbar":
                from iwr.ballbar.api import ballbar_problem

                robot = robot.with_instrument("ballbar", BALLBAR_SETUPS)
                measured, _ = iwr.simulate(robot, N, seed=1)
                problem, _ = ballbar_problem(robot, measured)
            else:
                raise ValueError(f"--data: {data!r}; expected leg, tracker or ballbar")
            rng = np.random.default_rng(0)
            X = problem.lower + (problem.upper - problem.lower) * rng.random((NP, problem.n_params))
            got = (robot, measured, problem, np.ascontiguousarray(X))
        self.kinds[data] = got
        return got

    def _objectives(self) -> dict:
        """Every objective of FLOPS as (its problem built COPIES times, X); None where this build
        has none. The copies lie at different addresses (a few kB of heap between them) and the
        timed calls take them in turn: a Problem's placement can make it 5 % slower for good
        (1 of 32 copies in a test), which one copy per process would keep for the whole run."""
        if self.others is not None:
            return self.others
        np, iwr = self.np, self.iwr
        robot, data = self.robot, self.data
        make: dict = {"leg": lambda: iwr.Problem(robot, data)}
        try:
            w = np.random.default_rng(5).uniform(0.5, 2.0, (N, 6))
            m = iwr.Measurements(data.q, data.poses, data.legs, joint_types=robot.joint_types,
                                 weights=w)
            iwr.Problem(robot, m)
            make["weighted"] = lambda: iwr.Problem(robot, m)
        except TypeError:  # no weights in this build
            make["weighted"] = None
        try:
            noisy, _ = iwr.simulate(robot, N, seed=1, noise=iwr.Noise.realistic())
            iwr.Problem(robot, noisy, noise=iwr.Noise.realistic())
            make["whitened"] = lambda: iwr.Problem(robot, noisy, noise=iwr.Noise.realistic())
        except (TypeError, AttributeError):
            make["whitened"] = None
        try:
            from iwr.tracker import TrackerProblem, simulate_tracker

            setup = tracker_setup()
            td, _ = simulate_tracker(robot, setup, N, seed=1)
            make["tracker"] = lambda: TrackerProblem(robot, setup, td)
        except ImportError:
            make["tracker"] = None
        try:  # the tracker point objective weighted by the readings' and the tracker's noise
            from iwr.tracker import TrackerNoise

            readings = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
            TrackerProblem(robot, setup, td, noise=(readings, TrackerNoise.leica()))
            make["tracker weighted"] = lambda: TrackerProblem(
                robot, setup, td, noise=(readings, TrackerNoise.leica()))
        except (ImportError, TypeError, AttributeError):
            make["tracker weighted"] = None
        out: dict = {}
        self.pads = []
        for k, f in make.items():
            if f is None:
                out[k] = None
                continue
            copies = []
            for i in range(COPIES):
                self.pads.append(np.empty(1 + 397 * (i + 1)))  # move the heap on
                copies.append(f())
            p = copies[0]
            rng = np.random.default_rng(0)
            X = p.lower + (p.upper - p.lower) * rng.random((NP, p.n_params))
            out[k] = (copies, np.ascontiguousarray(X))
        self.others = out
        return out

    def info(self) -> dict:
        import iwr

        bench = self.core._bench
        peaks = {}
        for isa in self.core._supported_kernels():
            key = "sse2" if isa == "baseline" else isa
            # the best of 5 short measurements: one of 0.3 s read 2-3 % low on a busy machine
            peaks[isa] = max(bench.measure_peak_gflops(key, False, 0.1) for _ in range(5))
        return {"version": iwr.__version__, "path": str(Path(iwr.__file__).parent),
                "kernels": self.core._supported_kernels(), "default_kernel": self.default_kernel,
                "peak_mul_add_gflops": peaks}

    def round_trip(self) -> float | None:
        """The core-to-core round trip (ns, ``_bench.measure_core_round_trip_ns``); None for a
        build without the probe (before the twenty-ninth round)."""
        probe = getattr(self.core._bench, "measure_core_round_trip_ns", None)
        return None if probe is None else probe(0.05)

    def objective(self, kernel: str, which: str = "leg") -> float | None:
        """One repetition: thread CPU time per evaluation (us), one thread; None when this build
        has no such objective."""
        got = self._objectives()[which]
        if got is None:
            return None
        copies, X = got
        self.turn[which] = (self.turn.get(which, -1) + 1) % len(copies)
        problem = copies[self.turn[which]]
        self.core._select_kernel(kernel)
        if self.last != (kernel, which):  # after another objective or variant: one call untimed
            problem.cost_batch(X, workers=1)
            self.last = (kernel, which)
        best = math.inf
        for _ in range(UNSWITCHED_TRIES):  # a call the scheduler interrupted is taken again
            s0 = _switches()
            t0 = time.thread_time()
            problem.cost_batch(X, workers=1)
            t = (time.thread_time() - t0) / NP * 1e6
            best = min(best, t)
            if _switches() == s0:
                return t
        return best

    def batch(self, kernel: str, threads: int, data: str = "leg") -> float:
        """One repetition: wall time of cost_batch of the population on `threads` (ms), on the
        problem of `data` (:meth:`kind`)."""
        return self.batches(kernel, threads, data, 1)[0]

    def batches(self, kernel: str, threads: int, data: str, count: int) -> list:
        """`count` repetitions of :meth:`batch` one after another, after WARM_S of untimed ones
        (the pool's threads running on their own CPUs, as between DE's generations)."""
        _, _, problem, X = self.kind(data)
        self.core._select_kernel(kernel)
        if threads > 1:
            t0 = time.perf_counter()
            while time.perf_counter() - t0 < WARM_S:
                problem.cost_batch(X, workers=threads)
        out = []
        for _ in range(count):
            t0 = time.perf_counter()
            problem.cost_batch(X, workers=threads)
            out.append((time.perf_counter() - t0) * 1e3)
        return out

    def de(self, kernel: str, threads: int, generations: int) -> dict:
        """One DE run: wall and process CPU time (s), and its result's bits (for determinism)."""
        self.core._select_kernel(kernel)
        w0, c0 = time.perf_counter(), time.process_time()
        res = self.iwr.identify(self.robot, self.data, method="de", population_size=NP, F=0.9,
                                CR=1.0, generations=generations, seed=1, workers=threads,
                                polish=False, progress=False)
        return {"wall": time.perf_counter() - w0, "cpu": time.process_time() - c0,
                "fun": float(res.fun).hex()}

    def de_generations(self, kernel: str, threads: int, generations: int,
                       data: str = "leg") -> dict:
        """One DE run on `data` (:meth:`kind`): the wall time of each generation (ms), from the
        run's own log (its ``elapsed`` column, taken in C++: no Python callback in the loop),
        and the result's bits."""
        robot, measured, _, _ = self.kind(data)
        self.core._select_kernel(kernel)
        res = self.iwr.identify(robot, measured, method="de", population_size=NP, F=0.9,
                                CR=1.0, generations=generations, seed=1, workers=threads,
                                polish=False, progress=False)
        e = self.np.asarray(res.history["elapsed"], dtype=float)
        return {"ms": (self.np.diff(e) * 1e3).tolist(), "fun": float(res.fun).hex()}

    def serve(self) -> None:
        out = sys.stdout
        for line in sys.stdin:
            req = json.loads(line)
            try:
                ans = getattr(self, req["op"])(*req.get("args", []))
            except Exception as e:  # reported to the parent, which stops
                ans = {"error": f"{type(e).__name__}: {e}"}
            finally:
                self.core._select_kernel(self.default_kernel)
            out.write(json.dumps(ans) + "\n")
            out.flush()


# ---- the parent: alternates the builds -----------------------------------------------------------


def fresh_copy(python: str) -> str:
    """Copies the extension module of the build at ``python`` to a new file over the old one (the
    same bytes, in new page-cache pages; atomic) and returns its path. Two virtualenvs holding
    byte-identical extensions ran the AVX2 leg objective 35 % apart until the slow one was copied
    so (BENCHMARKS.md, eighteenth round): a copy per run makes that spread show between runs
    instead of hiding in one build's column."""
    try:
        found = subprocess.run([python, "-c", "import iwr._core as c; print(c.__file__)"],
                               capture_output=True, text=True, cwd="/tmp")
    except OSError as exc:
        raise SystemExit(f"--fresh-copies: {python}: {exc}") from None
    if found.returncode != 0:
        last = (found.stderr.strip().splitlines() or ["no message"])[-1]
        raise SystemExit(f"--fresh-copies: {python} cannot import iwr._core: {last}")
    path = found.stdout.strip()
    tmp = path + ".fresh-copy"
    try:
        shutil.copyfile(path, tmp)
        shutil.copymode(path, tmp)
        os.replace(tmp, path)
    except OSError as exc:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise SystemExit(f"--fresh-copies: {path}: {exc}") from None
    return path


class Build:
    def __init__(self, name: str, python: str) -> None:
        self.name = name
        self.proc = subprocess.Popen([python, __file__, "--worker"], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True, cwd="/tmp")

    def ask(self, op: str, *args):
        assert self.proc.stdin and self.proc.stdout
        self.proc.stdin.write(json.dumps({"op": op, "args": list(args)}) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise SystemExit(f"{self.name}: the worker process ended")
        ans = json.loads(line)
        if isinstance(ans, dict) and "error" in ans:
            raise SystemExit(f"{self.name}: {op}{args}: {ans['error']}")
        return ans

    def close(self) -> None:
        if self.proc.stdin:
            self.proc.stdin.close()
        self.proc.wait()


def alternated(builds: list[Build], reps: int, op: str, *args) -> dict[str, list]:
    """reps answers per build, the order of the builds reversed every repetition."""
    out: dict[str, list] = {b.name: [] for b in builds}
    for r in range(reps):
        for b in builds if r % 2 == 0 else builds[::-1]:
            out[b.name].append(b.ask(op, *args))
    return out


def spread(builds: list[Build], cells: list[tuple], reps: int, seconds: float) -> dict:
    """The objective's time per evaluation for every cell (kernel, objective) and build, in
    rounds over the cells (the builds alternated within each visit, their order reversed every
    round) for at least `seconds` seconds and until every cell has `reps` repetitions. A cell is
    visited every s-th round, s its time per evaluation over the cheapest cell's (so far), so
    that each cell gets about the same time and the costly ones (the SSE2 tracker objective, 80x
    the cheapest) do not leave the others a handful of repetitions. Returns
    {cell: {build name: [times]}}.

    Why rounds rather than a cell's repetitions in a row: this machine's cores go through spells
    of 0.25-2 s in which code bound by latency (the kernels) runs 25-45 % slower while the clock
    and the multiply-add peak do not move (measured; BENCHMARKS.md, fifth round: most likely the
    host's other hardware thread on the same core). A cell's repetitions in a row take 20-100 ms
    and fall inside one spell, so the cell's minimum took the spell's state: the bimodal table.
    Spread over the whole table, every cell's minimum comes from outside the spells."""
    out: dict = {c: {b.name: [] for b in builds} for c in cells}
    cost: dict = {}
    stride = {c: 1 for c in cells}
    t0 = time.perf_counter()
    r = 0
    while (time.perf_counter() - t0 < seconds
           or any(len(v) < reps for per in out.values() for v in per.values())):
        k = r % len(cells)
        for c in cells[k:] + cells[:k]:
            if r % stride[c] and all(len(v) >= reps for v in out[c].values()):
                continue
            for name, v in alternated(builds if r % 2 == 0 else builds[::-1], 1,
                                      "objective", *c).items():
                out[c][name].extend(v)
                if v[0] is not None:
                    cost[c] = min(cost.get(c, math.inf), v[0])
        cheapest = min(cost.values(), default=1.0)
        stride = {c: max(1, round(cost.get(c, cheapest) / cheapest)) for c in cells}
        r += 1
    return out


def near_min(times: dict) -> str:
    """How many repetitions of each cell came within 2 % of its minimum (range over the cells):
    the minimum is a state the machine returned to, not a lucky call."""
    fr = [sum(t <= 1.02 * min(v) for t in v) / len(v)
          for cell in times.values() for v in cell.values() if v and None not in v]
    return f"{min(fr):.0%}-{max(fr):.0%}" if fr else "n/a"


class Load:
    """Load average and the CPU other processes used (cores), over a block of measurements; and
    the core-to-core round trip at its start and end (the first build with the probe), which on a
    virtual machine moves with where the host runs the two vCPUs: about 85 or about 350 ns on the
    Zen 5, switching within minutes, and a DE generation on two threads about 1.16x or 1.33x one
    ``cost_batch`` with it (BENCHMARKS.md, twenty-ninth round)."""

    def __init__(self, children: list[Build]) -> None:
        self.children = children
        self.trips: list[float] = []

    def _trip(self) -> None:
        for b in self.children:
            ns = b.ask("round_trip")
            if ns is not None:
                self.trips.append(ns)
                return

    @staticmethod
    def _busy() -> float | None:
        return _machine_busy()

    def _ours(self) -> float:
        tck = os.sysconf("SC_CLK_TCK")
        total = time.process_time()
        for b in self.children:
            try:
                f = Path(f"/proc/{b.proc.pid}/stat").read_text().rsplit(")", 1)[1].split()
                total += (int(f[11]) + int(f[12])) / tck  # utime, stime
            except OSError:
                pass
        return total

    def __enter__(self) -> Load:
        self._trip()
        self.t0, self.b0, self.o0 = time.perf_counter(), self._busy(), self._ours()
        return self

    def __exit__(self, *exc: object) -> None:
        wall = self.wall = time.perf_counter() - self.t0
        b1 = self._busy()
        self.cores = (None if b1 is None or self.b0 is None else
                      max(0.0, (b1 - self.b0 - (self._ours() - self.o0)) / wall))
        if exc[0] is None:
            self._trip()

    def __str__(self) -> str:
        la = os.getloadavg()[0]
        other = "unknown" if self.cores is None else f"{self.cores:.2f} cores"
        trip = ("" if not self.trips else
                ", core-to-core round trip " + " -> ".join(f"{t:.0f}" for t in self.trips) + " ns")
        return f"load average {la:.2f}, other processes meanwhile {other}{trip}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--python", action="append", default=[], metavar="NAME=PATH",
                    help="a build: a name and its Python interpreter (repeatable)")
    ap.add_argument("--repeat", type=int, default=15, help="objective repetitions (default 15)")
    ap.add_argument("--seconds", type=float, default=20.0,
                    help="each objective table's repetitions spread over at least this long "
                         "(default 20 s; see spread())")
    ap.add_argument("--de-repeat", type=int, default=3, help="DE run pairs (default 3)")
    ap.add_argument("--generations", default="100,600", help="G1,G2 of the DE rate")
    ap.add_argument("--kernels", default=None, help="variants, comma-separated (default: all)")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--no-de", action="store_true", help="skip DE")
    ap.add_argument("--objectives", action="store_true",
                    help="also the weighted, whitened and tracker objectives against their floors")
    ap.add_argument("--objectives-only", action="store_true",
                    help="the objectives' table alone (implies --objectives)")
    ap.add_argument("--scaling", action="store_true",
                    help="only DE per generation against cost_batch, 2 threads against 1, from "
                         "the minimum of each generation over --runs runs (scaling_table)")
    ap.add_argument("--runs", type=int, default=7, help="DE runs of --scaling (default 7)")
    ap.add_argument("--data", default="leg", choices=("leg", "tracker", "ballbar"),
                    help="--scaling's data: poses in {0} (default), the tracker's points (K = 3) "
                         "or the ballbar's distances")
    ap.add_argument("--quick", action="store_true", help="a smoke test")
    ap.add_argument("--fresh-copies", action="store_true",
                    help="first copy each build's extension module to new pages (the same bytes; "
                         "see fresh_copy): repeat the run to see the spread that placement adds")
    args = ap.parse_args()
    if args.runs < 1:
        ap.error(f"--runs: {args.runs}; at least 1")
    if args.worker:
        Worker().serve()
        return
    specs = args.python or [f"this={sys.executable}"]
    builds = []
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            ap.error(f"--python: {spec!r}; expected NAME=PATH")
        if args.fresh_copies:
            print(f"{name}: copied {fresh_copy(path)} to new pages (the same bytes)")
        builds.append(Build(name, path))
    reps = 3 if args.quick else args.repeat
    secs = 0.0 if args.quick else args.seconds
    de_reps = 1 if args.quick else args.de_repeat
    g1, g2 = (20, 70) if args.quick else tuple(int(g) for g in args.generations.split(","))
    threads = [int(t) for t in args.threads.split(",")]
    try:
        infos = {b.name: b.ask("info") for b in builds}
        ref = infos[builds[0].name]
        kernels = args.kernels.split(",") if args.kernels else ref["kernels"]
        print(f"cpu: {cpu_name()}, {os.cpu_count()} cores, {os.getloadavg()[0]:.2f} load average "
              "at start")
        print(f"this machine runs the {ref['default_kernel']} variant of the kernel (of "
              f"{', '.join(ref['kernels'])})")
        for b in builds:
            i = infos[b.name]
            print(f"  {b.name}: iwr {i['version']} from {i['path']}")
        peak = ref["peak_mul_add_gflops"]
        print("measured peak of one core, separate multiplies and adds (GFLOP/s): "
              + ", ".join(f"{k} {v:.1f}" for k, v in peak.items()))
        names = [b.name for b in builds]
        flops = FLOPS_PER_POSE * N
        if args.scaling:
            scaling_table(builds, kernels, threads, 2 if args.quick else args.runs,
                          60 if args.quick else 400, reps, secs, args.data)
            return

        print(f"\nleg objective, Problem.cost_batch(X, workers=1), {NP} vectors, N = {N}, "
              f"thread CPU time per evaluation, min of at least {reps} spread "
              f"over {secs:g} s:")
        hdr = "| variant | " + " | ".join(f"{n} (us) | {n}: of the floor" for n in names)
        if len(builds) == 2:
            hdr += f" | {names[1]} / {names[0]}"
        print(hdr + " |")
        print("|" + "---|" * (1 + 2 * len(names) + (len(builds) == 2)))
        summary: dict = {"objective": {}, "batch": {}, "de": {}}
        with Load(builds) as load:
            times = spread(builds, [(k,) for k in kernels], reps, secs)
            for k in kernels:
                best = {n: min(v) for n, v in times[(k,)].items()}
                summary["objective"][k] = best
                floor_us = flops / (peak[k] * 1e3)
                row = f"| {k} | " + " | ".join(
                    f"{best[n]:.3f} | {floor_us / best[n]:.0%}" for n in names)
                if len(builds) == 2:
                    row += f" | {best[names[1]] / best[names[0]]:.2f}x"
                print(row + " |", flush=True)
        print(f"floor: {flops} flops at the peak above; {load}")
        print(f"{len(times[(kernels[0],)][names[0]])} repetitions a cell over {load.wall:.0f} s; "
              f"within 2 % of the cell's minimum: {near_min(times)} of them")
        if args.objectives or args.objectives_only:
            objectives_table(builds, kernels, reps, peak, secs)
        if args.objectives_only:
            return

        print(f"\ncost_batch(X, workers=T) of the {NP} vectors, wall time, min of {reps}:")
        print("| variant | threads | " + " | ".join(f"{n} (ms)" for n in names) + " |")
        print("|---|---|" + "---|" * len(names))
        with Load(builds) as load:
            for k in kernels:
                for t in threads:
                    r = alternated(builds, reps, "batch", k, t)
                    best = {n: min(v) for n, v in r.items()}
                    summary["batch"][(k, t)] = best
                    print(f"| {k} | {t} | " + " | ".join(f"{best[n]:.3f}" for n in names) + " |",
                          flush=True)
        print(str(load))
        if args.no_de:
            return

        print(f"\nDE/rand/1/bin, NP {NP}, N {N}, iwr.identify(method='de', polish=False), "
              f"generations/s from runs of {g1} and {g2} generations (wall), best of {de_reps}; "
              "DE's own = time per generation - cost_batch on the same threads:")
        print("(1 thread also in process CPU time: ms/gen, and DE's own against the objective's "
              "CPU time above x 600)")
        print("| variant | threads | " + " | ".join(
            f"{n}: gen/s | {n}: ms/gen | {n}: DE's own | {n}: CPU ms/gen | {n}: DE's own (CPU)"
            for n in names) + " |")
        print("|---|---|" + "---|" * (5 * len(names)))
        bits: dict = {}
        with Load(builds) as load:
            for k in kernels:
                for t in threads:
                    rates: dict[str, list[float]] = {n: [] for n in names}
                    cpu: dict[str, list[float]] = {n: [] for n in names}
                    for _ in range(de_reps):
                        a = alternated(builds, 1, "de", k, t, g1)
                        b = alternated(builds[::-1], 1, "de", k, t, g2)
                        for n in names:
                            rates[n].append((g2 - g1) / max(b[n][0]["wall"] - a[n][0]["wall"],
                                                            1e-9))
                            cpu[n].append((b[n][0]["cpu"] - a[n][0]["cpu"]) / (g2 - g1) * 1e3)
                            bits.setdefault((n, k), set()).add(b[n][0]["fun"])
                    row = f"| {k} | {t} | "
                    cells = []
                    for n in names:
                        gps = max(rates[n])
                        ms = 1e3 / gps
                        own = ms - summary["batch"][(k, t)][n]
                        summary["de"][(k, t, n)] = gps
                        cell = (f"{gps:.0f} | {ms:.3f} | {own:.3f} ms "
                                f"({own / summary['batch'][(k, t)][n]:.0%})")
                        if t == 1:  # CPU time: robust to a neighbour's load on one thread
                            obj = summary["objective"][k][n] * NP / 1e3
                            c = min(cpu[n])
                            cell += f" | {c:.3f} | {(c - obj) / obj:.0%}"
                        else:
                            cell += " | | "
                        cells.append(cell)
                    print(row + " | ".join(cells) + " |", flush=True)
        print(str(load))
        for n in names:
            if 1 in threads and 2 in threads:
                ratio = [summary["de"][(k, 2, n)] / summary["de"][(k, 1, n)] for k in kernels]
                print(f"{n}: DE on 2 threads / on 1: "
                      + ", ".join(f"{k} {r:.2f}x" for k, r in zip(kernels, ratio, strict=True)))
            print(f"{n}: " + bits_verdict({k: v for (m, k), v in bits.items() if m == n}))
    finally:
        for b in builds:
            b.close()


def objectives_table(builds: list[Build], kernels: list[str], reps: int, peak: dict,
                     seconds: float) -> None:
    """Every objective of FLOPS on every variant: thread CPU time per evaluation and the fraction
    of its floor (FLOPS[objective] x N at the variant's measured peak)."""
    names = [b.name for b in builds]
    print(f"\nobjectives, cost_batch(X, workers=1), {NP} vectors, N = {N}, thread CPU time per "
          f"evaluation, min of at least {reps} spread over {seconds:g} s (floor: flops a pose x N "
          "at the variant's peak above):")
    hdr = "| variant | objective | flops a pose | " + " | ".join(
        f"{n} (us) | {n}: of the floor" for n in names)
    if len(builds) == 2:
        hdr += f" | {names[1]} / {names[0]}"
    print(hdr + " |")
    print("|" + "---|" * (3 + 2 * len(names) + (len(builds) == 2)))
    with Load(builds) as load:
        times = spread(builds, [(k, w) for k in kernels for w in FLOPS], reps, seconds)
        for k in kernels:
            for which, fl in FLOPS.items():
                best = {n: (None if None in v else min(v)) for n, v in times[(k, which)].items()}
                floor_us = fl * N / (peak[k] * 1e3)
                cells = [("n/a | n/a" if best[n] is None else
                          f"{best[n]:.3f} | {floor_us / best[n]:.0%}") for n in names]
                row = f"| {k} | {which} | {fl} | " + " | ".join(cells)
                if len(builds) == 2:
                    a, b = best[names[0]], best[names[1]]
                    row += " | n/a" if a is None or b is None else f" | {b / a:.2f}x"
                print(row + " |", flush=True)
    print(str(load))
    print(f"at least {reps} repetitions a cell over {load.wall:.0f} s; within 2 % of the cell's "
          f"minimum: {near_min(times)} of them")


def bits_verdict(bits: dict[str, set]) -> str:
    """What the best costs' bits (per variant: the set over thread counts and runs) say. Since the
    seventh round the variants with fused multiply-adds (AVX2, AVX-512) agree bit for bit and the
    SSE2 baseline only to rounding, so a DE run there may follow another trajectory; a build before
    it gives the same bits on every variant."""
    each = all(len(v) == 1 for v in bits.values())
    fused = [next(iter(v)) for k, v in bits.items() if k != "baseline" and len(v) == 1]
    text = f"the same best cost bits on every thread count (each variant): {each}"
    if len(fused) > 1:
        text += f"; avx2 and avx512 the same: {len(set(fused)) == 1}"
    if "baseline" in bits and fused:
        text += f"; the baseline the same as they: {bits['baseline'] == {fused[0]}}"
    return text


def scaling_table(builds: list[Build], kernels: list[str], threads: list[int], runs: int,
                  generations: int, reps: int, seconds: float, data: str = "leg") -> None:
    """DE's generation against one cost_batch, and 2 threads against 1, robust to neighbours.

    A generation takes 0.3-2 ms; the neighbours of a shared machine take a core now and then for
    a few ms. Each generation's wall time comes from the run's own log; over `runs` runs of the
    same seed (the same work generation by generation) the minimum of each generation is the
    generation undisturbed, and the median of these minima over generations 50.. is the
    figure (the first generations, with most mutants out of bounds, are slower). cost_batch of the
    600 vectors, `runs` calls one after another a round (the pool's threads awake, as between
    generations), rounds spread over `seconds`: the minimum over all, as the objective tables,
    and the generation's own statistic (:func:`like_for_like`), the median over rounds of each
    round's minimum: the ratio of a generation to it compares like with like (the minimum of
    hundreds of calls is lower: 1-3 % for the leg objective on the Zen 5, BENCHMARKS.md,
    thirtieth round). `data`: the kind of data (:meth:`Worker.kind`)."""
    names = [b.name for b in builds]
    print(f"\n{data} data: DE/rand/1/bin, NP {NP}, N {N}, iwr.identify(method='de', polish=False), "
          f"{generations} generations x {runs} runs: per generation the minimum over the runs, "
          "then the median over generations 50..; cost_batch(X, workers=T) of the 600 vectors, "
          f"wall time, {runs} calls one after another a round, rounds spread over {seconds:g} s: "
          "the minimum, and (like for like) the median over rounds of each round's minimum:")
    print("| variant | threads | " + " | ".join(
        f"{n}: ms/gen | {n}: cost_batch min (ms) | {n}: gen / min | {n}: cost_batch like for like "
        f"(ms) | {n}: gen / like for like" for n in names) + " |")
    print("|---|---|" + "---|" * (5 * len(names)))
    cells = [(k, t) for k in kernels for t in threads]
    gen: dict = {c: {n: [] for n in names} for c in cells}
    bits: dict = {n: {} for n in names}
    batch: dict = {c: {n: [] for n in names} for c in cells}
    with Load(builds) as load:
        for r in range(runs):
            for c in cells:
                for b in (builds if r % 2 == 0 else builds[::-1]):
                    a = b.ask("de_generations", c[0], c[1], generations, data)
                    gen[c][b.name].append(a["ms"])
                    bits[b.name].setdefault(c[0], set()).add(a["fun"])
        t0 = time.perf_counter()
        r = 0
        while r < reps or time.perf_counter() - t0 < seconds:
            for c in cells[r % len(cells):] + cells[:r % len(cells)]:
                for b in (builds if r % 2 == 0 else builds[::-1]):
                    batch[c][b.name].append(b.ask("batches", c[0], c[1], data, runs))
            r += 1
        per: dict = {}
        for c in cells:
            cellout = []
            for n in names:
                m = [min(g) for g in zip(*gen[c][n], strict=True)][50:]
                ms = sorted(m)[len(m) // 2]
                bt = min(min(g) for g in batch[c][n])
                bl = like_for_like(batch[c][n])
                per[(c, n)] = ms
                cellout.append(f"{ms:.3f} | {bt:.3f} | {ms / bt:.3f}x | {bl:.3f} | {ms / bl:.3f}x")
            print(f"| {c[0]} | {c[1]} | " + " | ".join(cellout) + " |", flush=True)
    print(str(load))
    for n in names:
        if 1 in threads and 2 in threads:
            print(f"{n}: generations/s on 2 threads / on 1: " + ", ".join(
                f"{k} {per[((k, 1), n)] / per[((k, 2), n)]:.2f}x" for k in kernels))
        print(f"{n}: " + bits_verdict(bits[n]))


def like_for_like(groups: list[list[float]]) -> float:
    """The statistic of a generation's time in :func:`scaling_table` applied to groups of
    cost_batch times (each `runs` calls one after another): the median of the groups' minima."""
    minima = sorted(min(g) for g in groups)
    return minima[len(minima) // 2]


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


if __name__ == "__main__":
    main()
