"""Cost of one evaluation of the objective of eq. (10): iwr's kernel against the floating-point
floor, a straightforward Eigen implementation and vectorised NumPy; population batches on 1 and 2
threads; scaling with the number of poses N, the population size NP and the number of threads.

What is timed
-------------
- iwr: ``Problem.cost_batch(X, workers=1)`` on NP = 600 random parameter vectors (within the
  default bounds, as DE draws them), once per compiled instruction-set variant of the kernel
  ("baseline" = x86-64 SSE2, "avx2", "avx512"; iwr uses the fastest this CPU runs). Divided by 600.
- Eigen: ``iwr._core._bench.EigenBaseline``, the formula as one would first write it in C++ with
  Eigen (per pose: the 4x4 DH product with a sine and cosine per joint, the six leg vectors of
  eq. (8) with fixed-size types), compiled with the same flags as the kernel (-O3, no -march).
- NumPy: this file's ``NumpyCost``, vectorised over poses (one vector at a time) and over the whole
  population at once; NumPy and its BLAS are held to one thread.
Each figure is the median of several repetitions. Single-thread figures are given in wall time and
in CPU time of the calling thread: the machine may be shared, and CPU time excludes time the thread
spent waiting for a core. Multi-thread figures are wall time; "cores obtained" = process CPU time /
wall time shows how many cores the run actually had. The thread pool's fixed cost per call (waking
the worker thread and waiting for it) is measured as cost_batch of 2 rows on 2 threads minus on 1.
After each table, "other processes meanwhile" is the CPU the rest of the machine used (in cores,
from /proc/stat): a figure measured beside a busy neighbour is not this code's.

The floor
---------
Flops per pose of iwr's kernel, counted from its source (``cpp/src/objective_kernel_body.inl``), for
the IWR's PPRR carriage, folded into per-evaluation constants (``carriage_folded``: every + - * /
sqrt counts 1, an FMA 2):
  rotation after the first revolute joint, S = s0 + c s1 + s s2: 9 x 2 FMAs              36
  R' = S Rz(q2): 3 rows x (2 multiplies + 2 FMAs)                                         18
  position p' = p0 + sum q_i z_i + c pc + s ps: 3 rows x 4 FMAs                           24
  platform pose in {4'}: p5 - p' (3), M = R'^T R5 (45), w = R'^T (p5 - p') (15)             63
  each leg: v = M b + (w - a) (21), |v|^2 (5), sqrt (1), - l0 - s (2), r^2, sum (2)  6 x 31 = 186
  lane sum                                                                                    1
  total                                                                                     328
(+1 per leg when weighted). Before the folding (issue 24's floor, 37,000 flops at N = 100, which
``bench_regression.py`` keeps) the chain joint by joint took 370: a prismatic prefix joint 6, a
revolute joint 54 (6 for the angle-sum cos/sin, 3 rows x 16 for T <- T A_i), in place of the 78
above; other carriages still run that chain (a generic prismatic joint after a revolute one
costs 49). The per-evaluation set-up (sin/cos of the 8 DH angles by a series, the prefix
rotation, the folded constants: several hundred flops, not counted here) is not counted.
The floor is N x 328 flops at the measured peak of one core with the same instruction set, with
separate multiplies and adds (the AVX2 and AVX-512 variants fuse the multiply-adds the kernel
writes as such, the same ones in both, so that they give the same bits; an FMA counts 2 flops);
the FMA peak is shown too.

Usage::

    python benchmarks/bench_objective.py [--quick] [--out benchmarks/results]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # NumPy on one thread: a per-core comparison

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from _load import OtherLoad  # noqa: E402

import iwr  # noqa: E402
from iwr import _core  # noqa: E402
from iwr._core import _bench  # noqa: E402

NP = 600
N = 100


# -- machine ---------------------------------------------------------------------------------------


def cpu_model() -> tuple[str, float | None]:
    name, mhz = platform.processor() or "unknown", None
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name") and name in ("unknown", "", "x86_64"):
                name = line.split(":", 1)[1].strip()
            if line.startswith("cpu MHz") and mhz is None:
                mhz = float(line.split(":", 1)[1])
    except OSError:
        pass
    return name, mhz


def load_average() -> float | None:
    try:
        return os.getloadavg()[0]
    except OSError:
        return None


def machine_info() -> dict:
    name, mhz = cpu_model()
    peaks = {}
    for isa in _core._supported_kernels():
        key = "sse2" if isa == "baseline" else isa
        peaks[isa] = {
            "mul_add": _bench.measure_peak_gflops(key, False, 0.3),
            "fma": None if key == "sse2" else _bench.measure_peak_gflops(key, True, 0.3),
        }
    return {
        "cpu": name,
        "cores": os.cpu_count(),
        "cpuinfo_mhz": mhz,
        "clock_ghz": _bench.measure_clock_ghz(0.3),
        "peak_gflops_per_core": peaks,
        "kernel_variants": _core._supported_kernels(),
        "kernel_in_use": _core._active_kernel(),
        "numpy": np.__version__,
        "python": platform.python_version(),
        "load_average_at_start": load_average(),
    }


def flops_per_pose(joint_types: str, weighted: bool) -> int:
    """Flops of the kernel per pose (see the module docstring): the IWR's PPRR folded, any other
    carriage joint by joint."""
    n_prefix = len(joint_types) - len(joint_types.lstrip("P"))
    if joint_types == "PPRR":  # the chain the kernel compiles in (kernel(): chain_is(pd, 2, 2))
        f = 36 + 18 + 3 * 2 * 4
    else:
        f = 6 * n_prefix
        for c in joint_types[n_prefix:]:
            f += 54 if c == "R" else 49
    return f + 63 + 6 * (31 + (1 if weighted else 0)) + 1


# -- the independent NumPy implementation ----------------------------------------------------------


class NumpyCost:
    """Eq. (10) in NumPy, vectorised over the rows of X and over the poses.

    Per data set: 0R5 of each pose (eq. 6). Per call: the DH matrices of eq. (1) for every (row,
    pose), their product (eq. 2), the leg vectors of eq. (8), their norms, the weighted squares.
    """

    def __init__(self, robot: iwr.Robot, m: iwr.Measurements) -> None:
        self.robot = robot
        a, b, g = m.poses[:, 3], m.poses[:, 4], m.poses[:, 5]
        ca, sa, cb, sb, cg, sg = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(g), np.sin(g)
        self.r5 = np.stack(
            [
                np.stack([ca * cb, ca * sb * sg - sa * cg, ca * sb * cg + sa * sg], -1),
                np.stack([sa * cb, sa * sb * sg + ca * cg, sa * sb * cg - ca * sg], -1),
                np.stack([-sb, cb * sg, cb * cg], -1),
            ],
            -2,
        )
        self.r5t = np.ascontiguousarray(self.r5.transpose(0, 2, 1))
        self.p5 = m.poses[:, :3]
        self.q = m.q
        self.legs = m.legs
        self.sqrtw = None if m.weights is None else np.sqrt(m.weights)

    def __call__(self, X: np.ndarray) -> np.ndarray:
        robot, X = self.robot, np.atleast_2d(X)
        nm, nj, n = X.shape[0], robot.n_joints, self.q.shape[0]
        dh = robot.dh + X[:, : 4 * nj].reshape(nm, nj, 4)
        t = np.broadcast_to(np.eye(4), (nm, n, 4, 4))
        for i in range(nj):
            alpha, aa, d, theta = (dh[:, i, c][:, None] for c in range(4))
            if robot.joint_types[i] == "P":
                d = d + self.q[None, :, i]
                theta = np.broadcast_to(theta, (nm, n))
            else:
                theta = theta + self.q[None, :, i]
                d = np.broadcast_to(d, (nm, n))
            ct, st = np.cos(theta), np.sin(theta)
            ca, sa = (
                np.broadcast_to(np.cos(alpha), (nm, n)),
                np.broadcast_to(np.sin(alpha), (nm, n)),
            )
            A = np.zeros((nm, n, 4, 4))
            A[..., 0, 0], A[..., 0, 1], A[..., 0, 2], A[..., 0, 3] = ct, -ca * st, sa * st, aa * ct
            A[..., 1, 0], A[..., 1, 1], A[..., 1, 2], A[..., 1, 3] = st, ca * ct, -sa * ct, aa * st
            A[..., 2, 1], A[..., 2, 2], A[..., 2, 3] = sa, ca, d
            A[..., 3, 3] = 1
            t = t @ A
        a = robot.base_joints + X[:, 4 * nj : 4 * nj + 18].reshape(nm, 6, 3)
        b = robot.platform_joints + X[:, 4 * nj + 18 : 4 * nj + 36].reshape(nm, 6, 3)
        l0 = robot.leg_offsets + X[:, 4 * nj + 36 :]
        leg = (
            self.p5[None, :, None, :]
            + b[:, None] @ self.r5t[None]  # (R5 b_j)^T = b_j^T R5^T
            - t[:, :, None, :3, 3]
            - a[:, None] @ t[:, :, :3, :3].transpose(0, 1, 3, 2)
        )
        r = np.sqrt(np.einsum("mnlc,mnlc->mnl", leg, leg)) - l0[:, None, :] - self.legs[None]
        if self.sqrtw is not None:
            r = r * self.sqrtw[None]
        return np.einsum("mnl,mnl->m", r, r)


# -- timing ----------------------------------------------------------------------------------------


def timed(fn, repeats: int) -> dict:
    """Median wall, thread-CPU and process-CPU times of fn() over `repeats` calls (one warm-up)."""
    fn()
    wall, cpu, proc = [], [], []
    for _ in range(repeats):
        w0, c0, p0 = time.perf_counter(), time.thread_time(), time.process_time()
        fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.thread_time() - c0)
        proc.append(time.process_time() - p0)
    return {
        "wall": statistics.median(wall),
        "cpu": statistics.median(cpu),
        "cores": statistics.median(p / w for p, w in zip(proc, wall, strict=True)),
        "wall_min": min(wall),
    }


def problem_for(n_poses: int, seed: int = 1) -> tuple[iwr.Problem, iwr.Measurements]:
    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, n_poses=n_poses, seed=seed)
    return iwr.Problem(robot, m), m


def population(p: iwr.Problem, size: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(p.lower, p.upper, (size, p.n_params))


def table(rows: list[list[str]], header: list[str]) -> str:
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(len(header))]
    line = "| " + " | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)) + " |"
    sep = "|" + "|".join("-" * (w + 2) for w in widths) + "|"
    body = [
        "| " + " | ".join(str(c).rjust(w) for c, w in zip(r, widths, strict=True)) + " |"
        for r in rows
    ]
    return "\n".join([line, sep, *body])


# -- the measurements ------------------------------------------------------------------------------


def per_evaluation(repeats: int, machine: dict) -> tuple[list[dict], str]:
    p, m = problem_for(N)
    X = population(p, NP)
    flops = N * flops_per_pose(p.robot.joint_types, False)
    eigen = _bench.EigenBaseline(p.robot._geometry, m.q, m.poses, m.legs)
    npc = NumpyCost(p.robot, m)
    ref = p.cost_batch(X, workers=1)
    for name, got in [("Eigen", eigen.cost_batch(X)), ("NumPy", npc(X))]:
        err = np.max(np.abs(got - ref) / ref)
        assert err < 1e-9, f"{name} disagrees with iwr: relative difference {err:.1e}"
    rows = []
    active = _core._active_kernel()
    try:
        for v in _core._supported_kernels():
            _core._select_kernel(v)
            t = timed(lambda: p.cost_batch(X, workers=1), repeats)
            rows.append({"name": f"iwr kernel, {v}", "isa": v, **t})
    finally:
        _core._select_kernel(active)
    rows.append(
        {
            "name": "Eigen, straightforward",
            "isa": "baseline",
            **timed(lambda: eigen.cost_batch(X), repeats),
        }
    )
    few = X[:60]
    t = timed(lambda: [npc(x) for x in few], max(3, repeats // 3))
    rows.append(
        {
            "name": "NumPy, one vector at a time",
            "isa": None,
            **{
                k: (v / len(few) * NP if k in ("wall", "cpu", "wall_min") else v)
                for k, v in t.items()
            },
        }
    )
    rows.append(
        {
            "name": "NumPy, whole population",
            "isa": None,
            **timed(lambda: npc(X), max(3, repeats // 3)),
        }
    )
    peaks = machine["peak_gflops_per_core"]
    best = peaks[machine["kernel_in_use"]]["mul_add"]
    eigen_us = next(r for r in rows if r["name"].startswith("Eigen"))["cpu"] / NP * 1e6
    out = []
    for r in rows:
        us_wall, us_cpu = r["wall"] / NP * 1e6, r["cpu"] / NP * 1e6
        gflops = flops / (us_cpu * 1e3)
        floor_us = flops / (best * 1e3)
        own = peaks[r["isa"]]["mul_add"] if r["isa"] else None
        out.append(
            {
                **r,
                "us_wall": us_wall,
                "us_cpu": us_cpu,
                "gflops": gflops,
                "floor_fraction": floor_us / us_cpu,
                "own_isa_fraction": None if own is None else flops / (own * 1e3) / us_cpu,
                "speedup_vs_eigen": eigen_us / us_cpu,
            }
        )
    text = table(
        [
            [
                r["name"],
                f"{r['us_wall']:.3f}",
                f"{r['us_cpu']:.3f}",
                f"{r['gflops']:.1f}",
                f"{100 * r['floor_fraction']:.1f}%",
                "" if r["own_isa_fraction"] is None else f"{100 * r['own_isa_fraction']:.0f}%",
                f"{r['speedup_vs_eigen']:.1f}x",
            ]
            for r in out
        ],
        [
            "N = 100, 1 thread",
            "us/eval (wall)",
            "us/eval (CPU)",
            "GFLOP/s",
            "of the floor",
            "of its ISA's peak",
            "vs Eigen",
        ],
    )
    floor = flops / (best * 1e3)
    text += (
        f"\nfloor: {flops} flops / {best:.1f} GFLOP/s ({machine['kernel_in_use']}, mul+add, one "
        f"core) = {floor:.3f} us; with FMA "
        f"{peaks[machine['kernel_in_use']]['fma'] or 0:.1f} GFLOP/s"
    )
    return out, text


def batches(repeats: int) -> tuple[list[dict], str]:
    p, _ = problem_for(N)
    X = population(p, NP)
    out = []
    for w in (1, 2):
        t = timed(lambda w=w: p.cost_batch(X, workers=w), repeats)
        out.append({"workers": w, **t, "us_per_eval": t["wall"] / NP * 1e6})
    s = out[0]["wall"] / out[1]["wall"]
    text = table(
        [
            [
                str(r["workers"]),
                f"{r['wall'] * 1e3:.3f}",
                f"{r['us_per_eval']:.3f}",
                f"{out[0]['wall'] / r['wall']:.2f}x",
                f"{r['cores']:.2f}",
            ]
            for r in out
        ],
        ["NP = 600, N = 100: threads", "ms/batch (wall)", "us/eval", "speed-up", "cores obtained"],
    )
    return out + [{"speedup_2_threads": s}], text


def scaling_n(repeats: int, quick: bool) -> dict:
    sizes = [8, 25, 100, 400] if quick else [8, 16, 32, 64, 100, 128, 256, 512, 1000, 2000]
    out = {"N": [], "iwr": [], "eigen": [], "numpy": []}
    for n in sizes:
        p, m = problem_for(n)
        X = population(p, 120)
        eigen = _bench.EigenBaseline(p.robot._geometry, m.q, m.poses, m.legs)
        npc = NumpyCost(p.robot, m)
        out["N"].append(n)
        t_iwr = timed(lambda p=p, X=X: p.cost_batch(X, workers=1), repeats)
        t_eigen = timed(lambda e=eigen, X=X: e.cost_batch(X[:30]), repeats)
        t_numpy = timed(lambda f=npc, X=X: f(X[:30]), 3)
        out["iwr"].append(t_iwr["cpu"] / 120 * 1e6)
        out["eigen"].append(t_eigen["cpu"] / 30 * 1e6)
        out["numpy"].append(t_numpy["cpu"] / 30 * 1e6)
    return out


def scaling_np(repeats: int, quick: bool) -> dict:
    p, _ = problem_for(N)
    sizes = [1, 8, 64, 600, 4096] if quick else [1, 2, 4, 8, 16, 32, 64, 128, 256, 600, 1024, 4096]
    out = {"NP": sizes, "1": [], "2": []}
    for w in (1, 2):
        for size in sizes:
            X = population(p, size)
            out[str(w)].append(timed(lambda w=w, X=X: p.cost_batch(X, workers=w), repeats)["wall"])
    return out


def scaling_threads(repeats: int) -> dict:
    """Wall time of one cost_batch call on 1-4 threads, for the DE's NP = 600 and a large batch
    (where the pool's fixed cost of waking its threads no longer counts)."""
    p, _ = problem_for(N)
    out = {"threads": [1, 2, 3, 4], "NP": [NP, 20000], "wall": {}, "cores": {}}
    for size in out["NP"]:
        X = population(p, size)
        walls, cores = [], []
        for w in out["threads"]:
            t = timed(lambda w=w, X=X: p.cost_batch(X, workers=w), repeats)
            walls.append(t["wall"])
            cores.append(t["cores"])
        out["wall"][str(size)], out["cores"][str(size)] = walls, cores
    return out


def pool_round_trip(repeats: int) -> dict:
    """The pool's fixed cost: cost_batch of 2 rows on 2 threads (one row each, waking the worker
    and waiting for it) against 1 thread (no hand-over)."""
    p, _ = problem_for(N)
    X = population(p, 2)
    t = {w: timed(lambda w=w: p.cost_batch(X, workers=w), repeats * 50)["wall"] for w in (1, 2)}
    return {"wall_1": t[1], "wall_2": t[2], "round_trip": t[2] - t[1]}


def plots(sn: dict, snp: dict, sth: dict, out: Path, floor_ns_per_pose: float) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    fig, ax = plt.subplots(figsize=(6, 4))
    for key, label in [
        ("iwr", "iwr kernel"),
        ("eigen", "Eigen, straightforward"),
        ("numpy", "NumPy, population-vectorised"),
    ]:
        ax.loglog(sn["N"], sn[key], "o-", label=label)
    ax.loglog(sn["N"], [n * floor_ns_per_pose * 1e-3 for n in sn["N"]], "k--", label="floor")
    ax.set_xlabel("poses N")
    ax.set_ylabel("time per evaluation (us, CPU)")
    ax.set_title("Cost of eq. (10), one thread")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    files.append(out / "objective_vs_N.png")
    fig.tight_layout()
    fig.savefig(files[-1], dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    for w in ("1", "2"):
        ax.loglog(
            snp["NP"],
            [t / n * 1e6 for t, n in zip(snp[w], snp["NP"], strict=True)],
            "o-",
            label=f"{w} thread{'s' if w != '1' else ''}",
        )
    ax.set_xlabel("population size NP (rows of one cost_batch call)")
    ax.set_ylabel("wall time per evaluation (us)")
    ax.set_title(f"Problem.cost_batch, N = {N}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    files.append(out / "objective_vs_NP.png")
    fig.tight_layout()
    fig.savefig(files[-1], dpi=120)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6, 4))
    for size in sth["NP"]:
        walls = sth["wall"][str(size)]
        ax.plot(sth["threads"], [walls[0] / w for w in walls], "o-", label=f"NP = {size}")
    ideal = [min(t, 2) for t in sth["threads"]]
    ax.plot(sth["threads"], ideal, "k--", label="linear up to 2 cores")
    ax.set_xlabel("threads (the machine has 2 cores)")
    ax.set_ylabel("speed-up over 1 thread (wall time)")
    ax.set_title(f"Problem.cost_batch, N = {N}")
    ax.set_xticks(sth["threads"])
    ax.grid(True, alpha=0.3)
    ax.legend()
    files.append(out / "objective_vs_threads.png")
    fig.tight_layout()
    fig.savefig(files[-1], dpi=120)
    plt.close(fig)
    return files


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument(
        "--quick", action="store_true", help="fewer sizes and repetitions (a smoke test)"
    )
    ap.add_argument("--repeats", type=int, default=None, help="repetitions per figure (median)")
    ap.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).parent / "results",
        help="directory of the plots and objective.json",
    )
    args = ap.parse_args()
    repeats = args.repeats or (3 if args.quick else 21)
    args.out.mkdir(parents=True, exist_ok=True)

    other: dict[str, float | None] = {}
    with OtherLoad() as o:
        machine = machine_info()
    other["machine"] = o.cores
    peaks = machine["peak_gflops_per_core"]
    print(
        f"machine: {machine['cpu']}, {machine['cores']} cores, "
        f"/proc/cpuinfo {machine['cpuinfo_mhz']}"
        f" MHz, measured clock {machine['clock_ghz']:.2f} GHz, load average "
        f"{machine['load_average_at_start']}"
    )
    print(
        "measured peak of one core, GFLOP/s (mul+add / FMA): "
        + ", ".join(
            f"{k} {v['mul_add']:.1f} / {v['fma'] or float('nan'):.1f}" for k, v in peaks.items()
        )
    )
    print(f"kernel variants: {machine['kernel_variants']}, in use: {machine['kernel_in_use']}\n")

    with OtherLoad() as o:
        per_eval, text = per_evaluation(repeats, machine)
    other["per_evaluation"] = o.cores
    print(f"{text}\nother processes meanwhile: {o}\n")
    with OtherLoad() as o:
        batch, text = batches(repeats)
    other["batches"] = o.cores
    print(f"{text}\nother processes meanwhile: {o}\n")
    with OtherLoad() as o:
        sn = scaling_n(max(3, repeats // 3), args.quick)
    other["scaling_N"] = o.cores
    print(
        table(
            [
                [str(n), f"{a:.3f}", f"{b:.3f}", f"{c:.1f}", f"{a / n * 1e3:.2f}"]
                for n, a, b, c in zip(sn["N"], sn["iwr"], sn["eigen"], sn["numpy"], strict=True)
            ],
            ["N", "iwr us/eval", "Eigen us/eval", "NumPy us/eval", "iwr ns/pose"],
        ),
        f"\nother processes meanwhile: {o}\n",
    )
    with OtherLoad() as o:
        snp = scaling_np(max(3, repeats // 3), args.quick)
    other["scaling_NP"] = o.cores
    print(
        table(
            [
                [str(n), f"{a / n * 1e6:.3f}", f"{b / n * 1e6:.3f}"]
                for n, a, b in zip(snp["NP"], snp["1"], snp["2"], strict=True)
            ],
            ["NP", "us/eval, 1 thread", "us/eval, 2 threads"],
        ),
        f"\nother processes meanwhile: {o}\n",
    )
    with OtherLoad() as o:
        sth = scaling_threads(repeats)
        rt = pool_round_trip(repeats)
    other["scaling_threads"] = o.cores
    print(
        table(
            [
                [
                    str(size),
                    str(t),
                    f"{size / w / 1e6:.2f}",
                    f"{sth['wall'][str(size)][0] / w:.2f}x",
                    f"{c:.2f}",
                ]
                for size in sth["NP"]
                for t, w, c in zip(
                    sth["threads"], sth["wall"][str(size)], sth["cores"][str(size)], strict=True
                )
            ],
            ["NP", "threads", "M evals/s", "speed-up", "cores obtained"],
        ),
    )
    print(
        f"thread pool round trip (cost_batch of 2 rows, 2 threads {rt['wall_2'] * 1e6:.1f} us "
        f"- 1 thread {rt['wall_1'] * 1e6:.1f} us): {rt['round_trip'] * 1e6:.1f} us per call\n"
        f"other processes meanwhile: {o}\n"
    )
    best = peaks[machine["kernel_in_use"]]["mul_add"]
    files = plots(sn, snp, sth, args.out, flops_per_pose("PPRR", False) / best)
    machine["load_average_at_end"] = load_average()
    (args.out / "objective.json").write_text(
        json.dumps(
            {
                "machine": machine,
                "per_evaluation": per_eval,
                "batches": batch,
                "scaling_N": sn,
                "scaling_NP": snp,
                "scaling_threads": sth,
                "pool_round_trip": rt,
                "other_processes_cores": other,
            },
            indent=1,
        )
    )
    print(f"load average at end: {machine['load_average_at_end']}")
    print("wrote " + ", ".join(str(f) for f in [*files, args.out / "objective.json"]))


if __name__ == "__main__":
    main()
