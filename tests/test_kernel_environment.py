"""IWR_KERNEL: the objective's SIMD variant chosen from the environment by every front end
(``import iwr``, ``iwr``, ``iwr-calibrate``, ``iwr-engine``), refused by name when this CPU cannot
run it, named by ``--version`` and recorded in the reports' provenance."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

import iwr
from iwr import _core
from iwr.problem_file import engine_result
from iwr.reporting.html import Page, provenance

SUPPORTED = _core._supported_kernels()
WIDEST = SUPPORTED[-1]
BIN = Path(sys.executable).parent


def _env(value: str | None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "IWR_KERNEL"}
    if value is not None:
        env["IWR_KERNEL"] = value
    return env


def _run(args: list[str], value: str | None, **kw) -> subprocess.CompletedProcess[str]:
    # From a folder outside the repository: the installed package, not the source folder.
    return subprocess.run(args, capture_output=True, text=True, env=_env(value),
                          cwd=tempfile.gettempdir(), timeout=120, check=False, **kw)


@pytest.fixture
def restore_kernel():
    before = _core._active_kernel()
    yield
    _core._select_kernel(before)


@pytest.mark.parametrize("value", [None, "", "auto", *SUPPORTED])
def test_import_iwr_runs_the_variant_iwr_kernel_names(value: str | None) -> None:
    proc = _run([sys.executable, "-c", "import iwr; print(iwr._core._active_kernel())"], value)
    assert proc.returncode == 0, proc.stderr
    want = WIDEST if value in (None, "", "auto") else value
    assert proc.stdout.strip() == want


@pytest.mark.parametrize("value, shown", [("sse9", "sse9"), ("AVX2", "AVX2"), (" avx2", " avx2"),
                                          ("a\nb", "a\\x0ab"), ("\udcff", "\\xff")])
def test_import_iwr_refuses_an_unknown_variant_by_name(value: str, shown: str) -> None:
    # ("\udcff": the byte 0xff, as Python passes an undecodable byte to the environment)
    proc = _run([sys.executable, "-c", "import iwr"], value)
    assert proc.returncode == 1
    last = proc.stderr.strip().splitlines()[-1]
    assert last == (f"ImportError: iwr: environment variable IWR_KERNEL='{shown}': not a kernel "
                    f"variant; expected one this CPU runs ({', '.join(SUPPORTED)}) or auto")


def test_a_process_with_a_commands_argv_runs_the_variant_too() -> None:
    """Dask's spawned workers of `iwr study` carry the command's argv: importing iwr there
    applies IWR_KERNEL as anywhere (a bad value is left to the command's main, which refused it
    before any worker started)."""
    code = ("import sys; sys.argv[0] = '/somewhere/bin/iwr'; import iwr; "
            "print(iwr._core._active_kernel())")
    proc = _run([sys.executable, "-c", code], "baseline")
    assert proc.returncode == 0 and proc.stdout.strip() == "baseline", proc.stderr
    proc = _run([sys.executable, "-c", code], "sse9")
    assert proc.returncode == 0 and proc.stdout.strip() == WIDEST, proc.stderr


@pytest.mark.parametrize("prog", ["iwr", "iwr-calibrate", "iwr-engine"])
def test_the_commands_name_the_variant_and_refuse_a_bad_one_in_one_line(prog: str) -> None:
    exe = str(BIN / prog)
    for value in [None, *SUPPORTED]:
        proc = _run([exe, "--version"], value)
        assert proc.returncode == 0, proc.stderr
        want = WIDEST if value is None else value
        assert proc.stdout.strip() == (f"{prog} {iwr.__version__} (kernel {want}; this CPU runs "
                                       f"{', '.join(SUPPORTED)})")
    proc = _run([exe, "--version"], "sse9")
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"{prog}: error: environment variable IWR_KERNEL='sse9': not a "
                               "kernel variant; expected one this CPU runs"), lines[0]
    # Help is shown whatever the variable holds, and names it.
    proc = _run([exe, "--help"], "sse9")
    assert proc.returncode == 0 and "IWR_KERNEL" in proc.stdout, proc.stderr


def test_python_m_iwr_refuses_a_bad_variant_in_one_line() -> None:
    proc = _run([sys.executable, "-m", "iwr", "--version"], "avx9")
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"iwr: error: environment variable IWR_KERNEL='avx9': not a kernel variant; expected one "
        f"this CPU runs ({', '.join(SUPPORTED)}) or auto (see 'iwr --help')"]


def test_the_engine_runs_the_variant_it_is_given(tmp_path: Path, restore_kernel) -> None:
    """iwr-engine under IWR_KERNEL=baseline ends bit for bit where iwr.identify does on the
    baseline kernel (and under the widest variant, where the widest does): the variable reaches
    the computation, not only --version."""
    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, 12, seed=3)
    problem = tmp_path / "run.iwrp"
    iwr.Problem(robot, m).save(problem)
    settings = {"population_size": 24, "seed": 5, "F": 0.7, "CR": 0.9}
    results = {}
    for kernel in dict.fromkeys(["baseline", WIDEST]):
        ckpt = tmp_path / f"{kernel}.ckpt"
        proc = _run([str(BIN / "iwr-engine"), str(problem), "--population-size", "24", "--seed",
                     "5", "--F", "0.7", "--CR", "0.9", "--generations", "300", "--threads", "1",
                     "--checkpoint", str(ckpt), "--quiet"], kernel)
        assert proc.returncode == 0, proc.stderr
        got = engine_result(ckpt, problem)
        _core._select_kernel(kernel)
        ref = iwr.identify(robot, m, method="de", strategy="rand1bin", generations=300,
                           workers=1, polish=False, progress=False, **settings)
        np.testing.assert_array_equal(got.x, ref.x)
        np.testing.assert_array_equal(got.history["best"], ref.history["best"])
        results[kernel] = got
    if len(results) == 2:  # the baseline rounds differently: another path for the same seed
        assert not np.array_equal(results["baseline"].history["best"],
                                  results[WIDEST].history["best"])


def test_provenance_records_the_variant(restore_kernel) -> None:
    for kernel in SUPPORTED:
        _core._select_kernel(kernel)
        prov = provenance()
        assert prov["kernel"] == kernel
        html = Page("t").provenance(prov).render()
        assert f"<td>SIMD kernel (IWR_KERNEL)</td><td>{kernel}</td>" in html
    # A provenance written before the variant was recorded still renders.
    old = {k: v for k, v in provenance().items() if k != "kernel"}
    assert "<td>not recorded</td>" in Page("t").provenance(old).render()


def test_an_interrupted_run_resumes_with_its_variant(tmp_path: Path) -> None:
    """The engine's resume command of a run started under IWR_KERNEL=baseline carries it: pasted
    into a shell, it ends bit for bit where the uninterrupted run does."""
    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, 12, seed=3)
    problem = tmp_path / "run.iwrp"
    iwr.Problem(robot, m).save(problem)
    common = [str(problem), "--population-size", "24", "--seed", "5", "--threads", "1", "--quiet"]
    whole = _run([str(BIN / "iwr-engine"), *common, "--generations", "3000", "--checkpoint",
                  str(tmp_path / "whole.ckpt")], "baseline")
    assert whole.returncode == 0, whole.stderr
    ckpt = tmp_path / "cut.ckpt"
    proc = subprocess.Popen([str(BIN / "iwr-engine"), *common, "--generations", "3000",
                             "--checkpoint", str(ckpt), "--checkpoint-every", "50"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env("baseline"), cwd=tmp_path)
    deadline = time.monotonic() + 60
    while not ckpt.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    proc.send_signal(signal.SIGTERM)
    err = proc.communicate(timeout=60)[1]
    if proc.returncode == 0:
        pytest.skip("the run ended before the signal")  # a machine much faster than this one
    assert proc.returncode == 128 + signal.SIGTERM, err
    hint = engine_result(ckpt, problem).message.split("continue with: ", 1)[1].strip()
    assert hint.startswith("IWR_KERNEL=baseline iwr-engine "), hint
    resumed = subprocess.run(["bash", "-c", hint.replace("iwr-engine", str(BIN / "iwr-engine"), 1)],
                             capture_output=True, text=True, env=_env(None), cwd=tmp_path,
                             timeout=120, check=False)
    assert resumed.returncode == 0, resumed.stderr
    a, b = engine_result(ckpt, problem), engine_result(tmp_path / "whole.ckpt", problem)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history["best"], b.history["best"])
