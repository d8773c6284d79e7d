"""Ctrl-C at any moment of the commands' start-up: one line, exit status 130, never a traceback.

The console scripts import iwr (NumPy, SciPy, the compiled module) before the command's own
handler of KeyboardInterrupt runs; a SIGINT there printed a traceback, or "the compiled module
iwr._core is missing" when it fell in the module's initialisation (issue 26). Each command runs as
a user's would (the installed script, SIGINT back to its default as in a terminal: a background
job starts with it ignored), with Python's import-time log on (PYTHONPROFILEIMPORTTIME) so that
the signal is sent at chosen moments of the start-up: after the k-th import following Python's
own start-up (the module site), from the first of iwr's modules to the command's entry module, and
at delays after the first; and at a string ``exec`` after the command took over (the case that
ended ``python -m iwr`` by the signal, exit -2, after its message). (Before iwr's first module,
SIGINT is Python's: in its first milliseconds it kills the process silently, status 130 in a
shell; in site, a traceback.)
"""

from __future__ import annotations

import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
ROBOT, DATA = str(EXAMPLES / "iwr.toml"), str(EXAMPLES / "iwr_example.csv")


def _find(name: str) -> str:
    cand = Path(sys.executable).parent / name
    exe = str(cand) if cand.exists() else shutil.which(name)
    if exe is None:
        pytest.fail(f"{name} is not installed: `pip install .` puts it next to python")
    return exe


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _module(line: str) -> str | None:
    """The module an import-time log line names (None for another line)."""
    if not line.startswith("import time:"):
        return None
    return line.rsplit("|", 1)[-1].strip()


class _Run:
    """A command started with the import-time log on; its stderr read line by line."""

    def __init__(self, cmd: list[str], cwd: Path, preexec=_default_sigint) -> None:
        env = {**os.environ, "PYTHONPROFILEIMPORTTIME": "1"}
        self.proc = subprocess.Popen(  # noqa: PLW1509 (SIGINT to its default: see module doc)
            cmd, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
            stderr=subprocess.PIPE, text=True, preexec_fn=preexec)
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.seen: list[str] = []
        self.out: list[str] = []
        threading.Thread(target=self._read, args=(self.proc.stderr, self.lines.put),
                         daemon=True).start()
        self._out = threading.Thread(target=self._read, args=(self.proc.stdout, self.out.append),
                                     daemon=True)
        self._out.start()

    @staticmethod
    def _read(stream, put) -> None:
        for line in stream:
            put(line)
        put(None)

    def until(self, stop) -> bool:
        """Reads stderr until ``stop(module)`` is true for an import line; False at its end."""
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=1)
            except queue.Empty:
                continue
            if line is None:
                return False
            self.seen.append(line)
            m = _module(line)
            if m is not None and stop(m):
                return True
        pytest.fail("no output for 120 s")

    def finish(self) -> tuple[int, str, str]:
        """Exit status, stderr without the import log, stdout."""
        code = self.proc.wait(timeout=120)
        while self.until(lambda m: False):
            pass
        self._out.join(timeout=10)
        for stream in (self.proc.stdout, self.proc.stderr):
            stream.close()
        err = "".join(line for line in self.seen if _module(line) is None)
        return code, err, "".join(s for s in self.out if s is not None)


def _imports_of_startup(cmd: list[str], entry: str, cwd: Path) -> tuple[int, int]:
    """How many modules the command imports after Python's own start-up (the module site) up to
    the first of iwr's and up to its entry module."""
    run = _Run(cmd, cwd)
    assert run.until(lambda m: m == "site"), "no import-time log"
    names: list[str] = []

    def stop(m: str) -> bool:
        names.append(m)
        return m == entry

    assert run.until(stop), f"{entry} was not imported"
    run.proc.kill()
    run.finish()
    first = next(k for k, m in enumerate(names, 1) if m == "iwr" or m.startswith("iwr."))
    return first, len(names)


def _after(k: int, entry: str):
    """A stop for :meth:`_Run.until`: the k-th import, or the entry module if it comes first."""
    count = 0

    def stop(m: str) -> bool:
        nonlocal count
        count += 1
        return count >= k or m == entry

    return stop


def _interrupt_during_startup(cmd: list[str], entry: str, prog: str, cwd: Path,
                              started) -> None:
    first, total = _imports_of_startup(cmd, entry, cwd)
    assert total > 10  # the log works: NumPy alone is dozens
    moments = [(first + round(f * (total - first)), 0.0)
               for f in (0.0, 0.05, 0.2, 0.4, 0.6, 0.8, 0.95, 1.0)]
    moments += [(first, d) for d in (0.02, 0.1)]
    strict = 0
    for k, delay in moments:
        run = _Run(cmd, cwd)
        assert run.until(lambda m: m == "site")
        assert run.until(_after(k, entry)), f"the command ended before import {k} of {total}"
        time.sleep(delay)
        run.proc.send_signal(signal.SIGINT)
        code, err, out = run.finish()
        where = f"SIGINT after import {k} of {total} (+{delay} s) of start-up"
        assert "Traceback" not in err, f"{where}: {err}"
        # Exactly 130, never the signal's death (-2: see test_ctrl_c_in_a_string_exec_...).
        assert code == 130, f"{where}: exit {code}, {err}"
        if not started(out):  # the signal fell before the command's work: exactly one line
            assert err == f"\n{prog}: interrupted\n", f"{where}: {err!r}"
            strict += 1
    # Signals sent before the entry module was imported fall before any work.
    assert strict >= len(moments) - 2


def test_ctrl_c_during_iwr_calibrate_startup(tmp_path):
    cmd = [_find("iwr"), "calibrate", ROBOT, DATA, "--out", str(tmp_path / "out")]
    _interrupt_during_startup(cmd, "iwr.cli", "iwr", tmp_path, started=bool)


def test_ctrl_c_during_python_m_iwr_startup(tmp_path):
    cmd = [sys.executable, "-m", "iwr", "calibrate", ROBOT, DATA, "--out", str(tmp_path / "out")]
    _interrupt_during_startup(cmd, "iwr.cli", "iwr", tmp_path, started=bool)


def test_ctrl_c_during_iwr_calibrate_exe_startup(tmp_path):
    out = tmp_path / "r.json"
    cmd = [_find("iwr-calibrate"), ROBOT, DATA, "--output", str(out), "--generations", "100000",
           "--quiet"]

    def started(_stdout: str) -> bool:  # the launcher wrote the problem file: the engine may run
        return Path(str(out) + ".iwrp").exists()

    _interrupt_during_startup(cmd, "iwr.cli.calibrate_exe", "iwr-calibrate", tmp_path, started)


# Sends SIGINT to the process at the first string exec (collections.namedtuple, dataclasses) once
# the command's main has taken over Ctrl-C: the tracer runs as the exec'd code starts, and the
# handler's exception ends that code, as a Ctrl-C landing there does.
_SIGINT_IN_STRING_EXEC = """
import os, signal, sys

def _tracer(frame, event, arg):
    if event == "call" and frame.f_code.co_filename == "<string>":
        sys.settrace(None)
        os.write(2, b"SIGINT in a string exec\\n")
        os.kill(os.getpid(), signal.SIGINT)

def _hook(event, args):
    if (event == "exec" and getattr(args[0], "co_filename", "") == "<string>" and not _sent
            and "iwr.cli" in sys.modules
            and signal.getsignal(signal.SIGINT) is not sys.modules["iwr._startup"]._interrupted):
        _sent.append(True)
        sys.settrace(_tracer)

_sent = []
sys.addaudithook(_hook)
"""


@pytest.mark.parametrize("how", ["python -m iwr", "iwr"])
def test_ctrl_c_in_a_string_exec_after_startup_exits_130(tmp_path, how):
    """A Ctrl-C that ends a string ``exec`` after the command's main took over (the lazy imports
    of SciPy and Matplotlib run dozens, one per namedtuple): main prints one line and returns 130,
    and ``python -m iwr`` exits 130. With Python's own KeyboardInterrupt, CPython recorded it as
    unhandled and ``python -m`` died by the SIGINT after the message (exit -2), seen under load."""
    hook = tmp_path / "hook"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(_SIGINT_IN_STRING_EXEC)
    prefix = [sys.executable, "-m", "iwr"] if how.startswith("python") else [_find("iwr")]
    path = os.pathsep.join(p for p in (str(hook), os.environ.get("PYTHONPATH")) if p)
    r = subprocess.run([*prefix, "calibrate", ROBOT, DATA, "--out", str(tmp_path / "out")],
                       cwd=tmp_path, env={**os.environ, "PYTHONPATH": path},
                       capture_output=True, text=True, timeout=300,
                       preexec_fn=_default_sigint)  # noqa: PLW1509
    assert r.stderr.startswith("SIGINT in a string exec\n"), r.stderr  # the hook ran
    assert (r.returncode, r.stderr) == (130, "SIGINT in a string exec\n\niwr: interrupted\n")


def test_ignored_sigint_stays_ignored_during_startup(tmp_path):
    """A background job (SIGINT ignored) is not stopped by a SIGINT during the start-up."""
    run = _Run([_find("iwr"), "--version"], tmp_path, preexec=_ignore_sigint)
    assert run.until(lambda m: m.startswith("iwr"))
    run.proc.send_signal(signal.SIGINT)
    code, err, out = run.finish()
    assert (code, err) == (0, ""), err
    assert out.startswith("iwr ")


def test_a_program_importing_iwr_keeps_keyboard_interrupt(tmp_path):
    """Only the commands exit at once: a program that imports iwr gets KeyboardInterrupt."""
    code = ("import signal, iwr, iwr.cli\n"
            "assert signal.getsignal(signal.SIGINT) is signal.default_int_handler\n"
            "try:\n"
            "    signal.raise_signal(signal.SIGINT)\n"
            "except KeyboardInterrupt:\n"
            "    print('KeyboardInterrupt')\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                       text=True, timeout=120, preexec_fn=_default_sigint)  # noqa: PLW1509
    assert (r.returncode, r.stdout, r.stderr) == (0, "KeyboardInterrupt\n", "")


def test_ctrl_c_while_a_file_object_is_built_stays_a_ctrl_c(tmp_path, monkeypatch):
    """A Ctrl-C that lands inside ``os.fdopen`` (the file object already owns the descriptor and
    closes it as it fails) propagates as KeyboardInterrupt: open_regular must not close the
    descriptor a second time, which raised "Bad file descriptor" instead (seen as `iwr: error:
    ...iwr.toml: cannot read: Bad file descriptor`, exit 1, in a full-suite run)."""
    import os

    from iwr import _io

    path = tmp_path / "robot.toml"
    path.write_text("name = 'x'\n")

    def interrupted_fdopen(fd, *args, **kwargs):
        os.close(fd)  # what the failing file object does with the descriptor it owns
        raise KeyboardInterrupt

    monkeypatch.setattr(_io.os, "fdopen", interrupted_fdopen)
    with pytest.raises(KeyboardInterrupt):
        _io.open_regular(path)


def _raise_import_error_from_ctrl_c(*_args) -> None:
    """What a Ctrl-C in a pybind11 module's initialisation raises (SciPy and Matplotlib import
    some lazily, after the command took over): ImportError, caused by the KeyboardInterrupt."""
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as exc:
        raise ImportError("initialization failed") from exc


def test_ctrl_c_in_a_module_initialisation_is_an_interruption(monkeypatch, capsys):
    """Seen as `iwr: error: internal error: ImportError: initialization failed`, exit 1, for a
    SIGINT 0.355 s into `python -m iwr calibrate` under load."""
    import argparse

    import iwr.cli as cli

    def parser_with(command):
        parser = argparse.ArgumentParser()
        parser.set_defaults(func=command)
        return lambda: parser

    monkeypatch.setattr(cli, "build_parser", parser_with(_raise_import_error_from_ctrl_c))
    assert cli.main([]) == 130
    assert capsys.readouterr().err == "\niwr: interrupted\n"

    def broken(_args):  # an ImportError of its own stays an error
        raise ImportError("initialization failed")

    monkeypatch.setattr(cli, "build_parser", parser_with(broken))
    assert cli.main([]) == 1
    assert "internal error: ImportError: initialization failed" in capsys.readouterr().err


def test_iwr_calibrate_ctrl_c_in_a_module_initialisation_is_an_interruption(monkeypatch, capsys):
    from iwr.cli import calibrate_exe

    monkeypatch.setattr(calibrate_exe, "_main", _raise_import_error_from_ctrl_c)
    assert calibrate_exe.main([]) == 130
    assert capsys.readouterr().err == "\niwr-calibrate: interrupted\n"


def test_interrupted_by_follows_causes_and_contexts():
    from iwr._startup import interrupted_by

    assert interrupted_by(KeyboardInterrupt())
    a, b = ValueError("a"), RuntimeError("b")
    a.__context__, b.__context__ = b, a  # a cycle ends the walk
    assert not interrupted_by(a)
    c = OSError("c")
    c.__context__ = KeyboardInterrupt()
    assert interrupted_by(c)
