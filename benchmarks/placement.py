"""The C++ objectives' time over many arrangements of the same machine code (issue 24, item 4).

On a Zen 3 the same instructions of the AVX2 tracker objective ran 2-3 % apart from one build to
the next, and the leg objective, whose source neither build changed, 3 % slower in both
(BENCHMARKS.md, twenty-fifth round): where the linker puts each function relative to the others
(its offset within a 64-byte fetch window, which functions share cache sets and branch-predictor
entries) moves the time. One build a side therefore cannot resolve a change of 1-3 %. This script
measures a distribution instead of a point:

1. each source tree (``--source NAME=DIR``, e.g. main and a git worktree of a branch) is built
   once, the core library (``libiwr_core.a``, Release, the project's own flags) plus
   ``-ffunction-sections`` so that every function is a section of its own;
2. ``benchmarks/objective_time.cpp`` (this folder's, the same driver for every source) is linked
   against it ``--arrangements`` times with GNU gold's ``--section-ordering-file``: arrangement 0
   is the linker's default order, arrangement k > 0 every ``.text`` section in an order shuffled
   with seed k. The instructions are the same in every arrangement (the objective's bits too:
   the driver's check line is compared), only their addresses differ;
3. the binaries run in turn, ``--repeats`` passes over all of them, each pass in a new shuffled
   order (seeded), so that a neighbour's load or a clock change hits every arrangement alike; each
   run is ``objective_time VARIANT ROUNDS PROBLEMS``, and a binary's time is its minimum over the
   passes;
4. the table gives, per source and problem, the median and the range over the arrangements, and
   the median's fraction of the floor (the flops of bench_regression.py at the peak of the
   variant's instruction set, measured with separate multiplies and adds by the installed iwr).

Two sources compare by their medians: a difference inside both ranges is what the arrangement
alone moves. ``--plot FILE.png`` draws each arrangement's time.

The problems (``--problems``, default: made in ``--work`` with the installed iwr): the leg problem
(``iwr.simulate(Robot.default(), 100, seed=1)``), the tracker point problem and the same weighted
by the noise (bench_regression.py's ``--objectives``), saved as problem files.

Usage (Linux, GCC or Clang with GNU gold, ``ld.gold``; CMake and Ninja from the test extra's
environment; the installed iwr only makes the problems and measures the peak)::

    cd /tmp && python /path/to/benchmarks/placement.py --source main=/path/to/iwr \\
        --source new=/path/to/worktree --arrangements 12 --variant avx2
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _load import OtherLoad  # benchmarks/ is on sys.path when this script runs
from bench_regression import FLOPS, N, cpu_name

HERE = Path(__file__).resolve().parent
DRIVER = HERE / "objective_time.cpp"
PROBLEMS = ("leg", "tracker", "tracker weighted")
_SECTION = re.compile(r"\]\s+(\.text\.\S+)")


def fail(message: str) -> None:
    print(f"placement.py: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def run(cmd: list[str], what: str, cwd: Path | None = None) -> str:
    """``cmd``'s standard output; its error output and exit status named on failure."""
    p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    if p.returncode != 0:
        fail(f"{what} failed (exit {p.returncode}): {' '.join(cmd)}\n{p.stdout[-2000:]}"
             f"{p.stderr[-2000:]}")
    return p.stdout


def eigen_include() -> str:
    """Eigen's headers: cmeel-eigen's in this interpreter's environment, or the system's."""
    for entry in sys.path:
        candidate = Path(entry) / "cmeel.prefix" / "include" / "eigen3"
        if (candidate / "Eigen").is_dir():
            return str(candidate)
    for candidate in (Path("/usr/include/eigen3"), Path("/usr/local/include/eigen3")):
        if (candidate / "Eigen").is_dir():
            return str(candidate)
    fail("Eigen's headers not found (pip install cmeel-eigen, or the system's libeigen3-dev)")
    raise AssertionError


def make_problems(folder: Path) -> list[Path]:
    """The three problems of the table, saved as problem files in ``folder``."""
    from bench_regression import tracker_setup

    import iwr
    from iwr.tracker import TrackerNoise, TrackerProblem, simulate_tracker

    robot = iwr.Robot.default()
    data, _ = iwr.simulate(robot, n_poses=N, seed=1)
    setup = tracker_setup()
    td, _ = simulate_tracker(robot, setup, N, seed=1)
    readings = iwr.Noise(legs=0.002, joint_lengths=0.005, joint_angles=5e-6)
    made = {"leg": iwr.Problem(robot, data),
            "tracker": TrackerProblem(robot, setup, td),
            "tracker weighted": TrackerProblem(robot, setup, td,
                                               noise=(readings, TrackerNoise.leica()))}
    paths = []
    for name in PROBLEMS:
        path = folder / (name.replace(" ", "_") + ".iwrp")
        made[name].save(path)
        paths.append(path)
    return paths


def build(name: str, source: Path, work: Path, jobs: int) -> tuple[Path, Path]:
    """The core library of ``source`` with -ffunction-sections, and the driver's object compiled
    against its headers."""
    if not (source / "CMakeLists.txt").is_file():
        fail(f"--source {name}={source}: no CMakeLists.txt there")
    out = work / name
    run(["cmake", "-S", str(source), "-B", str(out), "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release",
         "-DIWR_BUILD_PYTHON=OFF", "-DIWR_BUILD_APPS=OFF", "-DIWR_BUILD_TESTS=OFF",
         "-DCMAKE_CXX_FLAGS=-ffunction-sections", f"-DPython_EXECUTABLE={sys.executable}"],
        f"configuring {name}")
    print(f"building {name} ({source}) in {out} ...", flush=True)
    run(["cmake", "--build", str(out), "--target", "iwr_core", "-j", str(jobs)], f"building {name}")
    driver = out / "objective_time.o"
    run([os.environ.get("CXX", "g++"), "-O2", "-std=c++17", "-ffunction-sections",
         f"-I{source / 'cpp' / 'include'}", "-isystem", eigen_include(), "-c", str(DRIVER),
         "-o", str(driver)], f"compiling {DRIVER.name} against {name}'s headers")
    return out / "libiwr_core.a", driver


def sections(*objects: Path) -> list[str]:
    """The distinct ``.text.*`` sections of ``objects`` (archives included), in order."""
    seen: dict[str, None] = {}
    for line in run(["readelf", "-SW", *map(str, objects)], "readelf").splitlines():
        m = _SECTION.search(line)
        if m:
            seen.setdefault(m.group(1))
    return list(seen)


def link(library: Path, driver: Path, order: list[str] | None, out: Path) -> Path:
    """The driver linked by gold, its ``.text`` sections in ``order`` (None: gold's own)."""
    cmd = [os.environ.get("CXX", "g++"), "-fuse-ld=gold"]
    if order is not None:
        listing = out.with_suffix(".order")
        listing.write_text("\n".join(order) + "\n")
        cmd.append(f"-Wl,--section-ordering-file={listing}")
    run(cmd + [str(driver), str(library), "-pthread", "-o", str(out)], f"linking {out.name}")
    return out


def passes(args: argparse.Namespace, binaries: list[tuple[str, int, Path]], problems: list[Path],
           best: dict, checks: dict, rng: random.Random) -> None:
    """``--repeats`` passes over the binaries, each in a new shuffled order: per binary, the
    minimum of each problem's time and the check lines seen."""
    for r in range(args.repeats):
        order = list(binaries)
        rng.shuffle(order)
        for i, (name, k, exe) in enumerate(order, 1):
            out = run([str(exe), args.variant, str(args.rounds), *map(str, problems)],
                      f"running {exe.name}").split()
            # "<variant> t1 t2 ... us  check <hex>"
            if out[0] != args.variant:
                fail(f"{exe.name} ran the {out[0]!r} variant, not {args.variant!r} "
                     "(not supported by this CPU?)")
            times = [float(v) for v in out[1:1 + len(problems)]]
            prev = best.get((name, k))
            best[(name, k)] = (times if prev is None
                               else [min(a, b) for a, b in zip(prev, times, strict=True)])
            checks.setdefault((name, k), set()).add(out[-1])
            print(f"\rpass {r + 1}/{args.repeats}: {i}/{len(order)}", end="", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--source", action="append", default=[], metavar="NAME=DIR", required=True,
                    help="a source tree to build and measure (repeatable)")
    ap.add_argument("--arrangements", type=int, default=12,
                    help="arrangements a source (default 12; the first is the linker's default)")
    ap.add_argument("--variant", default="avx2", help="the kernel variant (baseline, avx2, avx512)")
    ap.add_argument("--repeats", type=int, default=3, help="passes over every binary (default 3)")
    ap.add_argument("--rounds", type=int, default=5,
                    help="objective_time's rounds a run (default 5: 100 calls of each problem)")
    ap.add_argument("--problems", nargs="+", type=Path, default=None,
                    help="problem files (default: the leg, tracker and weighted tracker problems)")
    ap.add_argument("--work", type=Path, default=Path("placement-work"),
                    help="folder for the builds and binaries (default ./placement-work)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="build jobs")
    ap.add_argument("--seed", type=int, default=0, help="seed of the passes' orders")
    ap.add_argument("--plot", type=Path, default=None, help="PNG of every arrangement's time")
    ap.add_argument("--json", type=Path, default=None, help="the raw times as JSON")
    args = ap.parse_args()
    if args.arrangements < 1 or args.repeats < 1 or args.rounds < 1:
        fail("--arrangements, --repeats and --rounds must be at least 1")
    if not (shutil.which("ld.gold") or shutil.which("gold")):
        fail("GNU gold (ld.gold) not found: it orders the sections (binutils)")
    for tool in ("cmake", "readelf"):
        if not shutil.which(tool):
            fail(f"{tool} not found")
    sources: dict[str, Path] = {}
    for item in args.source:
        name, sep, folder = item.partition("=")
        if not sep or not name or not folder:
            fail(f"--source {item!r}: expected NAME=DIR")
        if name in sources:
            fail(f"--source {item!r}: the name {name!r} is given twice")
        sources[name] = Path(folder).resolve()
    args.work.mkdir(parents=True, exist_ok=True)
    problems = args.problems or make_problems(args.work)
    labels = [p.stem for p in problems] if args.problems else list(PROBLEMS)
    for p in problems:
        if not p.is_file():
            fail(f"--problems: {p}: no such file")

    binaries: list[tuple[str, int, Path]] = []
    for name, folder in sources.items():
        library, driver = build(name, folder, args.work.resolve(), args.jobs)
        text = sections(driver, library)
        for k in range(args.arrangements):
            order = None
            if k:
                order = list(text)
                random.Random(k).shuffle(order)
            binaries.append((name, k, link(library, driver, order,
                                           args.work.resolve() / f"ot_{name}_{k}")))
    print(f"{len(binaries)} binaries, {len(text)} .text sections in the last; "
          f"{args.repeats} passes ...", flush=True)

    best: dict[tuple[str, int], list[float]] = {}
    checks: dict[tuple[str, int], set[str]] = {}
    rng = random.Random(args.seed)
    load = OtherLoad()
    with load:
        passes(args, binaries, problems, best, checks, rng)
    print()


    import iwr._core as core

    isa = "sse2" if args.variant == "baseline" else args.variant
    peak = max(core._bench.measure_peak_gflops(isa, False, 0.1) for _ in range(5))
    print(f"\n{cpu_name()}; kernel variant {args.variant}; peak {peak:.1f} GFLOP/s (separate "
          f"multiplies and adds); {args.arrangements} arrangements a source, the minimum of "
          f"{args.repeats} runs each ({args.rounds} x 20 calls of 600 vectors a run)\n")
    print("| source | problem | median (us) | range over the arrangements (us) | spread | "
          "default arrangement (us) | median: of the floor |")
    print("|---|---|---|---|---|---|---|")
    summary: dict = {}
    for name in sources:
        for j, label in enumerate(labels):
            ts = [best[(name, k)][j] for k in range(args.arrangements)]
            med = statistics.median(ts)
            # the floor of the benchmark's own problems only: another file's work is not known
            flops = None if args.problems else FLOPS.get(label)
            floor = f"{flops * N / (peak * 1e3) / med:.1%}" if flops else "n/a"
            summary[(name, label)] = ts
            print(f"| {name} | {label} | {med:.3f} | {min(ts):.3f}-{max(ts):.3f} | "
                  f"{(max(ts) - min(ts)) / med:.1%} | {ts[0]:.3f} | {floor} |")
    bits = {name: {c for (n, _), cs in checks.items() if n == name for c in cs}
            for name in sources}
    for name, cs in bits.items():
        print(f"{name}: check {'the same in every arrangement' if len(cs) == 1 else 'DIFFERS'}: "
              + ", ".join(sorted(cs)))
    if len(sources) > 1:
        same = len({c for cs in bits.values() for c in cs}) == 1
        print(f"the sources give {'the same' if same else 'different'} bits")
    print(f"other processes meanwhile: {load}; load average {os.getloadavg()[0]:.2f}")
    if args.json:
        args.json.write_text(json.dumps({
            "cpu": cpu_name(), "variant": args.variant, "peak_gflops": peak,
            "problems": labels, "time": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
            "us": {f"{n}/{label}": ts for (n, label), ts in summary.items()}}, indent=1))
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, len(labels), figsize=(4 * len(labels), 3.6), squeeze=False)
        for j, label in enumerate(labels):
            ax = axes[0][j]
            for i, name in enumerate(sources):
                ts = summary[(name, label)]
                ax.scatter([i + (k - len(ts) / 2) * 0.02 for k in range(len(ts))], ts, s=14,
                           label=name)
                ax.hlines(statistics.median(ts), i - 0.25, i + 0.25, color="k", lw=1)
            ax.set_xticks(range(len(sources)), list(sources))
            ax.set_title(label)
            ax.set_ylabel("us an evaluation (min of the runs)")
        fig.suptitle(f"{args.variant}: {args.arrangements} arrangements of the same code a "
                     f"source ({cpu_name()})", fontsize=9)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)
        print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
