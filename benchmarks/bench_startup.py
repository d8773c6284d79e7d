"""How long short commands take to start, build against build (issue 24, item 3).

Each command runs in a fresh process of each build's interpreter, the builds alternated (the
order reversed every repetition); the figure is the process's CPU time (user + system, from
``os.wait4``), the minimum over ``--repeat``, with the wall time beside it. What is timed:

- ``import iwr``;
- ``iwr --help`` (the parser of every command);
- ``iwr.identify`` of a small problem, first call in the process (``import iwr``, simulate 30
  poses, Levenberg-Marquardt);
- ``iwr calibrate`` on the built-in example with ``IWR_EXAMPLE_QUICK=1`` (the whole job: LM, the
  report and its figures), in a fresh temporary folder;
- the heavy packages each of the first three loaded (``sys.modules`` at exit).

Usage::

    cd /tmp && python /path/to/benchmarks/bench_startup.py \\
        --python old=/work/venvs/perf-old/bin/python --python new=/work/venvs/perf/bin/python
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

HEAVY = ("scipy", "matplotlib", "nlopt", "tqdm", "threadpoolctl", "PIL", "importlib.metadata")

_REPORT = ("import sys; print('HEAVY', sorted({m for m in sys.modules for h in " + repr(HEAVY)
           + " if h != 'scipy' and (m == h or m.startswith(h + '.'))} | {'scipy.' + "
           "m.split('.')[1] for m in sys.modules if m.startswith('scipy.') and not "
           "m.split('.')[1].startswith('_')}))")

CASES = {
    "import iwr": "import iwr\n" + _REPORT,
    "iwr --help": ("import sys, io, contextlib\nimport iwr.cli\n"
                   "with contextlib.redirect_stdout(io.StringIO()):\n"
                   "    try:\n        iwr.cli.main(['--help'])\n"
                   "    except SystemExit:\n        pass\n"
                   + _REPORT),
    "first identify, N = 30": ("import iwr\nr = iwr.Robot.default()\n"
                               "d, _ = iwr.simulate(r, 30, seed=1)\n"
                               "res = iwr.identify(r, d, progress=False)\n" + _REPORT),
}


def run(python: str, code: str | None, argv: list[str] | None = None) -> tuple[float, str]:
    """(wall s, stdout) of one process, reaped before it returns."""
    env = dict(os.environ, IWR_EXAMPLE_QUICK="1", IWR_QUICK="1", OMP_NUM_THREADS="1",
               OPENBLAS_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [python, "-c", code] if code is not None else [python, "-m", "iwr", *(argv or [])]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                cwd=tmp, env=env)
        out, err = proc.communicate()
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            raise SystemExit(f"{cmd}: exit {proc.returncode}\n{err[-2000:]}")
    return wall, out


def cpu_of(python: str, code: str | None, argv: list[str] | None = None
           ) -> tuple[float, float, str]:
    """(CPU s, wall s, stdout): the child's user + system time, from RUSAGE_CHILDREN."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall, out = run(python, code, argv)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, wall, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--python", action="append", default=[], metavar="NAME=PATH")
    ap.add_argument("--repeat", type=int, default=7)
    args = ap.parse_args()
    builds = [tuple(s.split("=", 1)) for s in (args.python or [f"this={sys.executable}"])]
    cases: list[tuple[str, str | None, list[str] | None]] = [
        (name, code, None) for name, code in CASES.items()]
    cases.append(("iwr calibrate (example, quick)", None, ["calibrate", "--out", "out"]))
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at start; process CPU "
          f"time (user + system) and wall time, min of {args.repeat}, builds alternated")
    print("| command | " + " | ".join(f"{n}: CPU s | {n}: wall s" for n, _ in builds) + " |")
    print("|---|" + "---|---|" * len(builds))
    heavy: dict[tuple[str, str], str] = {}
    for name, code, argv in cases:
        res: dict[str, list[tuple[float, float]]] = {n: [] for n, _ in builds}
        for r in range(args.repeat):
            for n, py in (builds if r % 2 == 0 else builds[::-1]):
                cpu, wall, out = cpu_of(py, code, argv)
                res[n].append((cpu, wall))
                for line in out.splitlines():
                    if line.startswith("HEAVY"):
                        heavy[(name, n)] = line[6:]
        print(f"| {name} | " + " | ".join(
            f"{min(c for c, _ in res[n]):.3f} | {min(w for _, w in res[n]):.3f}"
            for n, _ in builds) + " |", flush=True)
    print(f"load average {os.getloadavg()[0]:.2f} at the end")
    print("\nheavy packages loaded:")
    for (name, n), mods in heavy.items():
        print(f"  {name}, {n}: {mods}")


if __name__ == "__main__":
    main()
