"""iwr.study: a real Dask cluster loses a worker mid-study; the table matches a one-process run.

The crash is deterministic: a test method, registered in every worker by a plugin, creates a marker
file on its first execution anywhere and kills its worker process with ``os._exit`` (no Python
cleanup, as a machine that dies). Every execution of the method also leaves a file, so the tests
count executions: a finished cell is never computed again by a later run of the study (within
one run Dask computes a task at least once, not exactly once).
"""

from __future__ import annotations

import hashlib
import importlib
import json
import math
import os
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import iwr
from iwr.cli import main as cli_main
from iwr.cli import study as study_cli
from iwr.experiments.harness import Cell, noise_at, robot_hash
from iwr.experiments.monte_carlo import TIMING_COLUMNS, StudyError, make_grid, read_table

distributed = pytest.importorskip("distributed")
cloudpickle = pytest.importorskip("cloudpickle")  # a dependency of distributed, used by name here
# The module (the package's attribute iwr.identify is the function).
identify_module = importlib.import_module("iwr.methods")

CRASH = "test-crash-once"


def crash_once(problem: Any, *, marker: str, log: str, **kwargs: Any) -> Any:
    """Levenberg-Marquardt; but the first execution anywhere kills its process."""
    Path(log, uuid.uuid4().hex).touch()
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        pass
    else:
        os.close(fd)
        os._exit(17)  # a worker that dies: no exception, no cleanup
    return identify_module.METHODS["lm"](problem, **kwargs)


class RegisterCrashMethod(distributed.WorkerPlugin):
    """Registers the test method in each worker process, restarted ones included."""

    def setup(self, worker: Any) -> None:
        identify_module.METHODS[CRASH] = crash_once


# Workers import iwr but not this file: send the method and the plugin by value.
cloudpickle.register_pickle_by_value(sys.modules[__name__])


def main(argv: list[str]) -> int:
    """``iwr study ARGS``."""
    return cli_main(["study", *argv])


def executions(log: Path) -> int:
    return len(list(log.iterdir()))


def assert_same_table(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> None:
    """Same cells, settings, status and figures, bit for bit; timings apart, and the parameter
    errors to 1e-12 relative: they come from an SVD (LAPACK through NumPy's BLAS), whose last bit
    may change with the process (BLAS threads, alignment) though its input does not."""
    assert [r["key"] for r in a] == [r["key"] for r in b]
    for ra, rb in zip(a, b, strict=True):
        assert ra.keys() == rb.keys()
        for c in ra:
            if c in TIMING_COLUMNS:
                continue
            x, y = ra[c], rb[c]
            same = x == y or (isinstance(x, float) and math.isnan(x) and math.isnan(y))
            if c.startswith("param_error"):
                same = same or math.isclose(x, y, rel_tol=1e-12, abs_tol=0.0)
            assert same, (c, x, y, ra)


@pytest.fixture(scope="module")
def cluster():
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0"
    ) as c:
        yield c


def test_worker_dies_mid_study_and_table_matches_one_process(
    cluster: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    marker, log = tmp_path / "crashed", tmp_path / "log"
    log.mkdir()
    grid = dict(
        methods=["lm", CRASH], poses=[16, 24], noise=[0.0, 0.02], draws=1, seeds=[0, 1],
        options={CRASH: {"marker": str(marker), "log": str(log)}}, validation_poses=20,
        report=False,
    )
    n_cells = 2 * 2 * 2 * 1 * 2
    with distributed.Client(cluster) as client:
        client.register_plugin(RegisterCrashMethod())
        pids_before = set(client.run(os.getpid).values())
        monkeypatch.setitem(identify_module.METHODS, CRASH, crash_once)
        res = iwr.study(**grid, out=tmp_path / "dask", scheduler=client)
        pids_after = set(client.run(os.getpid).values())
    assert marker.exists(), "the crash never happened"
    assert pids_before - pids_after, "no worker process died"
    # Every cell of the crashing method ran, one of them twice (the killed attempt). Dask runs a
    # task at least once, not exactly once: a finished cell whose row had not been fetched when
    # its worker died is computed again, and under load a task moved to a restarted worker can
    # start there and again elsewhere (both seen with a busy machine). The cells are
    # deterministic, so the table is the same (below); only the count may be higher.
    on_dask = executions(log)
    assert on_dask >= n_cells // 2 + 1
    assert res.executed == n_cells and res.reused == 0 and res.failed == 0
    rows = read_table(tmp_path / "dask")
    assert len(rows) == n_cells and all(r["status"] == "ok" for r in rows)
    assert len(list((tmp_path / "dask" / "runs").glob("*.json"))) == n_cells

    # The same study in this process (the marker exists now: nothing crashes).
    one = iwr.study(**grid, out=tmp_path / "one", scheduler="synchronous")
    assert executions(log) == on_dask + n_cells // 2  # in this process: each cell once
    assert_same_table(rows, one.rows)
    # Both methods are LM on the same data: the crash lost nothing and changed nothing.
    lm = [r for r in rows if r["method"] == "lm"]
    crashed = [r for r in rows if r["method"] == CRASH]
    assert_same_table(
        [{**r, "method": "", "options": "", "key": ""} for r in lm],
        [{**r, "method": "", "options": "", "key": ""} for r in crashed],
    )

    # Started again: nothing is computed again, on the cluster or in this process.
    again = iwr.study(**grid, out=tmp_path / "dask", scheduler=cluster.scheduler_address)
    assert (again.executed, again.reused) == (0, n_cells)
    assert executions(log) == on_dask + n_cells // 2
    assert_same_table(rows, again.rows)
    # A larger grid (one more seed), sent to the cluster by address, computes only its new cells.
    bigger = iwr.study(**{**grid, "seeds": [0, 1, 2]}, out=tmp_path / "dask",
                       scheduler=cluster.scheduler_address)
    assert (bigger.executed, bigger.reused) == (n_cells // 2, n_cells)
    assert executions(log) >= on_dask + n_cells // 2 + n_cells // 4
    assert len(bigger.rows) == 3 * n_cells // 2


def logged_lm(problem: Any, *, log: str, **kwargs: Any) -> Any:
    """Levenberg-Marquardt, leaving a file per execution."""
    Path(log, uuid.uuid4().hex).touch()
    return identify_module.METHODS["lm"](problem, **kwargs)


class RegisterLoggedMethod(distributed.WorkerPlugin):
    def setup(self, worker: Any) -> None:
        identify_module.METHODS["test-logged-lm"] = logged_lm


def test_a_result_lost_with_its_worker_is_waited_for_not_failed(
    cluster: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The executor's race: a cell finished on a worker that dies before this process fetched
    its row is computed again elsewhere; waiting for that is not a failure of the cell (it was,
    after ``connect_timeout`` seconds, which a loaded machine exceeded). Here the first row's
    callback holds this process until the crash, so the rows finished meanwhile on the worker
    that dies are lost, and the timeout is 0.1 s."""
    from iwr.experiments.executors import run_dask
    from iwr.experiments.harness import canonical

    marker, log, crash_log = tmp_path / "crashed", tmp_path / "log", tmp_path / "crash-log"
    log.mkdir()
    crash_log.mkdir()
    robot = iwr.Robot.default()
    rh = robot_hash(robot)
    cells = [Cell("test-logged-lm", canonical({"log": str(log)}), None, 60, 0.02, 0, s, 0, 10, rh)
             for s in range(8)]
    cells += [Cell(CRASH, canonical({"marker": str(marker), "log": str(crash_log)}), None, 60,
                   0.02, 0, s, 0, 10, rh) for s in range(2)]
    rows: list[dict[str, Any]] = []

    def on_done(row: dict[str, Any]) -> None:
        if not rows:
            for _ in range(600):  # until the worker has crashed (60 s at most)
                if marker.exists():
                    break
                time.sleep(0.1)
        rows.append(row)

    monkeypatch.setitem(identify_module.METHODS, CRASH, crash_once)
    monkeypatch.setitem(identify_module.METHODS, "test-logged-lm", logged_lm)
    with distributed.Client(cluster) as client:
        client.register_plugin(RegisterCrashMethod())
        client.register_plugin(RegisterLoggedMethod())
        failures = run_dask(cells, robot, on_done, {"workers": 1}, scheduler=client,
                            connect_timeout=0.1)
    assert marker.exists()
    assert failures == [] and len(rows) == len(cells)
    assert all(r["status"] == "ok" for r in rows)
    assert executions(log) >= 8


def test_lost_result_file_is_recomputed_and_figures_make_sense(tmp_path: Path) -> None:
    res = iwr.study(methods="lm", poses=[12, 24], noise=[0.0, 0.01, 0.02], draws=2, seeds=1,
                    out=tmp_path, scheduler="synchronous", validation_poses=20)
    assert len(res.rows) == 12 and res.executed == 12
    runs = sorted((tmp_path / "runs").glob("*.json"))
    runs[3].unlink()
    again = iwr.study(methods="lm", poses=[12, 24], noise=[0.0, 0.01, 0.02], draws=2, seeds=1,
                      out=tmp_path, scheduler="synchronous", validation_poses=20, report=False)
    assert (again.executed, again.reused) == (1, 11)
    by = {(r["noise"], r["n_poses"], r["draw"]): r for r in res.rows}
    for (level, _n, _draw), r in by.items():
        # Before calibration: the errors (+-0.5 mm, +-0.5 degree) move the legs by millimetres.
        assert r["val_rms_nominal"] > 1.0
        if level == 0:
            assert r["val_rms"] < 1e-6 and r["cost"] < 1e-12  # the paper's noise-free case
        else:
            assert 1e-4 < r["val_rms"] < 0.5
            assert r["rms_fit"] < 10 * level  # the fit explains the data down to the noise
    for n in (12, 24):
        for draw in (0, 1):
            # Common random numbers: the same poses and noise shape at both levels, so the error
            # of the identification (first order in the noise) doubles with the noise.
            ratio = by[(0.02, n, draw)]["val_rms"] / by[(0.01, n, draw)]["val_rms"]
            assert ratio == pytest.approx(2.0, rel=0.02)
    # Figures and summary.
    for name in ("accuracy_vs_poses.png", "accuracy_vs_noise.png", "summary.md"):
        assert (tmp_path / name).stat().st_size > 0
    assert (tmp_path / "accuracy_vs_poses.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    text = (tmp_path / "summary.md").read_text()
    assert "lm, noise 0 mm: at the floor" in text


def test_deterministic_failure_is_recorded_not_retried(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A method registered from outside iwr (not dry-run before the study: a call may have side
    # effects) that fails the same way on every cell; LM's cells do not. (A budget below DE's
    # initial population, which did this before, and a bad option's value, population_size 3,
    # are refused before any cell runs.)
    from iwr.methods import METHODS

    def boom(problem, **_):
        raise ValueError("boom: no answer")

    monkeypatch.setitem(METHODS, "boom", boom)
    grid = dict(methods=["lm", "boom"], poses=[12], noise=0.0, draws=1, seeds=[0, 1],
                out=tmp_path, scheduler="synchronous", report=False, validation_poses=10)
    res = iwr.study(**grid)
    status = {(r["method"], r["seed"]): r for r in res.rows}
    for seed in (0, 1):
        assert status[("boom", seed)]["status"] == "failed"
        assert "ValueError: boom: no answer" in status[("boom", seed)]["message"]
        assert status[("lm", seed)]["status"] == "ok"
    assert res.failed == 2
    again = iwr.study(**grid)
    assert again.executed == 0 and again.failed == 2
    with pytest.raises(ValueError, match="options.lm.nope: not an option of method 'lm'"):
        iwr.study(**{**grid, "options": {"lm": {"nope": 1}}})
    with pytest.raises(ValueError, match="options.de.population_size: 3"):
        iwr.study(**{**grid, "methods": ["lm", "de"], "options": {"de": {"population_size": 3}}})


def test_rows_of_an_older_computation_are_computed_again(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A study made by a version whose cells computed their figures differently (an older
    # CELL_FORMAT): resumed by this one, no row of it is reused, and the table holds the new rows
    # alone (a tracker study resumed across the change of its nominal figures kept the old ones).
    grid = dict(methods="lm", poses=[12], noise=[0.0, 0.01], draws=1, seeds=1, out=tmp_path,
                scheduler="synchronous", validation_poses=10, report=False)
    from iwr.experiments import harness

    monkeypatch.setattr(harness, "CELL_FORMAT", harness.CELL_FORMAT - 1)
    old = iwr.study(**grid)
    assert (old.executed, old.reused) == (2, 0)
    for r in old.rows:  # what the older computation gave, marked so it can be told apart
        path = tmp_path / "runs" / f"{r['key']}.json"
        row = json.loads(path.read_text())
        path.write_text(json.dumps({**row, "val_rms_nominal": -1.0}))
    monkeypatch.undo()
    new = iwr.study(**grid)
    assert (new.executed, new.reused) == (2, 0)
    assert len(new.rows) == 2 and all(r["val_rms_nominal"] > 1.0 for r in new.rows)
    assert {r["key"] for r in new.rows}.isdisjoint(r["key"] for r in old.rows)
    again = iwr.study(**grid)
    assert (again.executed, again.reused) == (0, 2)


def test_keys_and_seeds() -> None:
    robot = iwr.Robot.default()
    rh = robot_hash(robot)
    cells = make_grid(["lm"], [10, 20], [0.0, 0.01], [0], [0, 1], {}, {"lm": {"workers": 4}},
                      7, 30, rh)
    assert len(cells) == 8 and len({c.key for c in cells}) == 8
    # The key is the hash of the cell's settings written as canonical JSON (computed here anew).
    c = cells[0]
    settings = {
        "format": 2, "method": "lm", "options": {}, "budget": None, "n_poses": 10, "noise": 0.0,
        "noise_model": "tracker position sd (mm), realistic proportions", "draw": 0, "seed": 0,
        "base_seed": 7, "validation_poses": 30, "robot": rh,
    }
    text = json.dumps(settings, sort_keys=True, separators=(",", ":"))
    assert c.key == hashlib.sha256(text.encode()).hexdigest()[:20]
    # Threads per identification change nothing but the speed: not part of the key.
    assert c == Cell("lm", "{}", None, 10, 0.0, 0, 0, 7, 30, rh)
    assert noise_at(0.02) == iwr.Noise.realistic()
    assert noise_at(0.0).is_zero
    assert noise_at(0.01).legs == pytest.approx(iwr.Noise.realistic().legs / 2)


def test_budget_axes(tmp_path: Path) -> None:
    robot = iwr.Robot.default()
    rh = robot_hash(robot)
    default = make_grid(["lm"], [10], [0.0], [0], [0], {"lm": (None, [5])}, {}, 0, 30, rh)[0]
    other = make_grid(["lm"], [10], [0.0], [0], [0], {"lm": ("max_nfev", [5])}, {}, 0, 30, rh)[0]
    plain = make_grid(["lm"], [10], [0.0], [0], [0], {}, {}, 0, 30, rh)[0]
    assert len({default.key, other.key, plain.key}) == 3
    # The default option is not part of the settings: keys stay those of earlier studies.
    assert "budget_option" not in default.settings and other.settings["budget_option"] == "max_nfev"
    res = iwr.study(methods=["lm"], poses=[12], noise=0.01, draws=1, seeds=1,
                    budgets={"lm.max_evaluations": [3, 1000]}, out=tmp_path,
                    scheduler="synchronous", report=False, validation_poses=10)
    a, b = res.rows
    assert (a["budget"], a["budget_option"], b["budget"]) == (3, "max_evaluations", 1000)
    assert a["nfev"] <= 3 < b["nfev"] and a["val_rms"] > b["val_rms"]
    with pytest.raises(ValueError, match="'nope' is not an option of method 'lm'"):
        iwr.study(methods="lm", budgets={"lm.nope": [3]}, scheduler="synchronous")
    with pytest.raises(ValueError, match="set by the budget axis too"):
        iwr.study(methods="lm", budgets={"lm": [3]}, options={"lm": {"max_evaluations": 9}},
                  scheduler="synchronous")


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="methods: 'nope'"):
        iwr.study(methods="nope", scheduler="synchronous")
    with pytest.raises(ValueError, match="poses: 0"):
        iwr.study(poses=[0], scheduler="synchronous")
    with pytest.raises(ValueError, match="poses: 8 poses are too few.*at least 9 poses"):
        iwr.study(poses=[20, 8], scheduler="synchronous")
    tracker = iwr.Robot.default().with_tracker(registration=(0, 0, 0, 0, 0, 0),
                                               reflectors=[(0, 0, 40)])
    # A tracker robot is studied on its points: one reflector gives 3 readings a pose.
    with pytest.raises(ValueError, match=r"poses: 10 poses are too few.*reflector points"):
        iwr.study(robot=tracker, poses=[10], scheduler="synchronous")
    with pytest.raises(ValueError, match="noise: -1.0"):
        iwr.study(noise=[-1.0], scheduler="synchronous")
    with pytest.raises(ValueError, match="workers: only for the local cluster"):
        iwr.study(workers=2, scheduler="tcp://127.0.0.1:1")
    with pytest.raises(StudyError, match="no such file"):
        read_table("/nonexistent/results.csv")
    # Refused before any cell runs (an outside check found both running every cell into a
    # failure, exit 0): a negative base seed, and a budget below DE's initial population.
    with pytest.raises(ValueError, match=r"base_seed: -1; expected an integer in \[0, 2\^64\)"):
        iwr.study(base_seed=-1, scheduler="synchronous")
    with pytest.raises(ValueError, match="budgets: de.max_evaluations = 100: max_evaluations: "
                                         "100; the initial population alone"):
        iwr.study(methods="de", budgets={"de.max_evaluations": [100, 5000]},
                  scheduler="synchronous")


def test_bad_table(tmp_path: Path) -> None:
    path = tmp_path / "results.csv"
    path.write_text("key,method,n_poses,noise\na,lm,12,0.0\nb,lm,x,0.0\n")
    with pytest.raises(StudyError, match=r"line 3: column 'n_poses': 'x' is not a valid value"):
        read_table(path)
    path.write_text("a,b\n1,2\n")
    with pytest.raises(StudyError, match="not a study table"):
        read_table(tmp_path)


def test_trend_rule() -> None:
    from iwr.reporting.study import _trend

    n = [10, 20, 40, 80]
    assert _trend(n, [1.0 / math.sqrt(x) for x in n], "N").startswith("keeps improving")
    assert "slope -0.50" in _trend(n, [1.0 / math.sqrt(x) for x in n], "N")
    flat = [1.0, 0.5, 0.48, 0.47]
    assert _trend(n, flat, "N").startswith("levels off from N = 20")
    assert _trend(n, [1e-12] * 4, "N").startswith("at the floor")


def run_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "iwr", "study", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def test_command_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    p = run_cli("--help", cwd=tmp_path)
    assert p.returncode == 0 and "--scheduler" in p.stdout and "--budget" in p.stdout
    assert p.stderr == ""
    p = run_cli("--poses", "ten", cwd=tmp_path)
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr.strip().splitlines() == [
        "iwr: error: argument --poses: 'ten': expected a comma-separated list of integers "
        "(see 'iwr study --help')"
    ]
    # A bad option's value: a usage error naming the option, exit 2, as in every command (the
    # library's ArgumentError names its argument: budgets, options, ...).
    for args, text in (
        (["--methods", "nope"], "--methods: 'nope'"),
        (["--option", "lm"], "--option: 'lm'; expected METHOD.NAME=VALUE"),
        (["--option", "nope.x=1"], "--option: method 'nope' is not one of the study's"),
        # An entry of --option as it is typed (it read "--option.lm.nope: ...").
        (["--methods", "lm", "--option", "lm.nope=1"],
         "--option lm.nope: not an option of method 'lm'"),
        (["--methods", "lm", "--option", "lm.max_evaluations=5", "--budget", "10"],
         "--option lm.max_evaluations: set by the budget axis too"),
        # an option's value, by the method's own checks, before any cell runs
        (["--methods", "lm", "--option", "lm.max_evaluations=-5"],
         "--option lm.max_evaluations: -5; expected an integer >= 2"),
        (["--methods", "lm", "--option", "lm.max_evaluations=abc"],
         "--option lm.max_evaluations: 'abc'; expected an integer >= 2"),
        (["--budget", "lm=5,x"], "--budget: "),
        (["--budget", "nope=5"], "--budget: method 'nope'"),
        (["--poses", "0"], "--poses: 0"),
        (["--poses", "20,3"], "--poses: 3 poses are too few: the 52 identifiable parameters"),
        (["--draws", "0"], "--draws: 0"),
        (["--validation-poses", "0"], "--validation-poses: 0"),
        (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1"], "--workers: only for the local"),
    ):
        assert main([*args, "--scheduler", "synchronous"] if "--scheduler" not in args
                    else args) == 2, args
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"iwr: error: {text}"), (args, err)
        assert err[0].endswith("(see 'iwr study --help')"), err
    # A missing folder is an input error: exit 1.
    assert main(["--report-only", "--out", str(tmp_path / "missing")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such file" in err[0] and err[0].startswith("iwr study: error:")
    p = run_cli("--methods", "lm", "--poses", "12,16", "--noise", "0.01", "--draws", "1",
                "--seeds", "2", "--out", "s", "--scheduler", "synchronous",
                "--validation-poses", "10", cwd=tmp_path)
    assert p.returncode == 0, p.stderr
    assert "4 cells (4 computed, 0 reused, 0 failed)" in p.stdout
    rows = read_table(tmp_path / "s")
    assert [(r["n_poses"], r["seed"]) for r in rows] == [(12, 0), (12, 1), (16, 0), (16, 1)]
    assert np.all(np.isfinite([r["val_rms"] for r in rows]))
    assert (tmp_path / "s" / "summary.md").exists()


def test_iwr_cli_has_study(tmp_path: Path) -> None:
    p = subprocess.run([sys.executable, "-m", "iwr", "study", "--help"], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and p.stdout.startswith("usage: iwr study") and "--debug" in p.stdout
    p = subprocess.run([sys.executable, "-m", "iwr", "study", "--methods", "nope", "--scheduler",
                        "synchronous", "--out", "s"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=120)
    lines = p.stderr.strip().splitlines()
    assert p.returncode == 2 and len(lines) == 1, p.stderr
    assert lines[0].startswith("iwr: error: --methods: 'nope'"), lines[0]


def test_add_study_parser_hook() -> None:
    import argparse

    parser = argparse.ArgumentParser(prog="iwr")
    sub = parser.add_subparsers(dest="command")
    study_cli.add_study_parser(sub)
    args = parser.parse_args(["study", "--poses", "10,20", "--budget", "lm=5,50"])
    assert args.func is study_cli.run_study
    assert args.poses == [10, 20] and args.budget == ["lm=5,50"]


def test_a_server_that_is_not_a_scheduler_fails_within_60_s(tmp_path: Path) -> None:
    """A plain HTTP server (silent after the handshake's bytes) and a server that answers with
    bytes Dask misreads as a frame length: a one-line message and exit 1 within 60 s, never a
    hang. Loopback only."""
    import http.server
    import socketserver
    import threading
    import time

    class Quiet(http.server.BaseHTTPRequestHandler):
        def log_message(self, *args: Any) -> None:
            pass

    class Banner(socketserver.BaseRequestHandler):
        def handle(self) -> None:
            self.request.sendall(b"SSH-2.0-OpenSSH_9.2p1 Debian-2\r\n" * 4)
            time.sleep(90)

    servers = [socketserver.ThreadingTCPServer(("127.0.0.1", 0), Quiet),
               socketserver.ThreadingTCPServer(("127.0.0.1", 0), Banner)]
    try:
        for srv in servers:
            srv.daemon_threads = True
            threading.Thread(target=srv.serve_forever, daemon=True).start()
            address = f"tcp://127.0.0.1:{srv.server_address[1]}"
            start = time.monotonic()
            p = run_cli("--scheduler", address, "--poses", "12", "--draws", "1", "--seeds", "1",
                        "--out", "s", cwd=tmp_path)
            elapsed = time.monotonic() - start
            lines = p.stderr.strip().splitlines()
            assert p.returncode == 1 and len(lines) == 1, p.stderr
            assert lines[0].startswith(f"iwr study: error: scheduler: {address!r}"), lines[0]
            assert "Dask scheduler" in lines[0]
            assert elapsed < 60, elapsed
    finally:
        for srv in servers:
            srv.shutdown()
            srv.server_close()


def test_an_exact_zero_is_drawn_below_every_positive_value(tmp_path: Path, monkeypatch) -> None:
    """A noise-free run's exact 0 on a log axis: drawn at a tenth of the row's smallest positive
    value, and said in the panel; a fixed 1e-16 put it above the others' round-off (1e-24)."""
    from iwr.reporting import study

    figures = []
    monkeypatch.setattr(study, "_save", lambda fig, path: figures.append(fig) or path)
    rows = [{"method": "lm", "budget": None, "noise": 0.0, "n_poses": n, "cost": c}
            for n, c in ((12, 0.0), (12, 0.0), (24, 1e-24), (24, 1e-24), (48, 3e-3), (48, 3e-3))]
    study._plot_vs(rows, ["cost"], "n_poses", "noise", tmp_path / "f.png", str, "N")
    (fig,) = figures
    ax = fig.axes[0]
    (line,) = ax.get_lines()
    np.testing.assert_allclose(line.get_ydata(), [1e-25, 1e-24, 3e-3])
    assert ax.get_ylabel() == "cost (0 drawn at 1e-25)"
    figures.clear()
    rows = [dict(r, cost=r["cost"] + 1.0) for r in rows]  # no zero: no note
    study._plot_vs(rows, ["cost"], "n_poses", "noise", tmp_path / "g.png", str, "N")
    assert figures[0].axes[0].get_ylabel() == "cost"
