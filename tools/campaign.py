"""The reliability campaign of issue 26: bad inputs, signals, limits, concurrency, degenerate data.

Each class runs a bounded number of cases and counts them: refused with a message naming the file
(or argument), accepted, and defects. Serious: a crash (a signal, "internal error"), a Python
traceback, a hang, a memory blow-up, a half-written output, an input overwritten, "success" (exit
0) for a degenerate result, a resumed run that differs from the uninterrupted one. Minor: a refusal
whose message does not name the file, line, key or argument at fault.

Usage (from outside the repository root, with iwr installed; nice it on a shared machine):

    nice -n 15 python tools/campaign.py CLASS [--cases N] [--seed S] [--keep DIR]

CLASS: toml, csv, binary, signals, fsize, concurrent, fork, degenerate, or all. The C++ readers'
sanitizer fuzzing is benchmarks/fuzz_binary_io.sh; the engine's kill-and-resume is
benchmarks/kill_campaign.py.

Last run (2026-11-25, branch harden2, 2 cores shared, nice -n 15; after the fixes it led to):
  toml 200 (--cases 200): 182 refused naming the file, 18 accepted, 0 defects (119 s)
  csv 250 (50 each: pose, tracker wide, tracker long, its readings, target list): 215 refused
      naming the file, 35 accepted, 0 defects (167 s)
  binary 200 (problem files through iwr-calibrate, checkpoints through --export): 199 refused
      naming the file, 1 accepted, 0 defects (215 s)
  signals 100 + 50 (SIGINT/SIGTERM/SIGKILL during iwr calibrate, half in its report's write, and
      iwr-calibrate with resume): 0 half-written folders, resumed runs bit-identical; a SIGINT in
      CPython's own start-up (the site module, before any of iwr's code) still prints Python's
      traceback (1 case)
  fsize 14 (RLIMIT_FSIZE 200 B to 60 kB): 12 refused naming the file, 2 fit, 0 defects
  concurrent 16: 0 defects (1 before .NAME.launch.lock)
  fork 240: 0 hangs, the child's costs equal
  degenerate 18 (pose, points, probe: copies, 1-10 poses, carriage still): none calibrated;
      exit code, success and verdict agree
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

import iwr
from iwr.cli import main as iwr_main
from iwr.cli.calibrate_exe import main as launcher_main

REPO = Path(__file__).resolve().parents[1]
EX = REPO / "examples"
BIN = Path(sys.executable).parent
TIMEOUT = 120  # s for one in-process case: beyond, a hang
REFUSED = "refused, message names it"


class Tally:
    def __init__(self, name: str) -> None:
        self.name = name
        self.counts: collections.Counter[str] = collections.Counter()
        self.defects: list[tuple[str, str, str]] = []  # (severity, case, detail)

    def ok(self, what: str) -> None:
        self.counts[what] += 1

    def serious(self, case: str, detail: str) -> None:
        self.counts["SERIOUS"] += 1
        self.defects.append(("serious", case, detail[-600:]))

    def minor(self, case: str, detail: str) -> None:
        self.counts["minor"] += 1
        self.defects.append(("minor", case, detail[-600:]))

    def report(self) -> dict:
        n = sum(self.counts.values())
        print(f"\n== {self.name}: {n} cases: " + ", ".join(f"{k} {v}" for k, v in
                                                       sorted(self.counts.items())))
        for sev, case, detail in self.defects[:40]:
            print(f"  [{sev}] {case}: {detail}")
        return {"class": self.name, "cases": n, **self.counts}


class _Alarm(Exception):
    pass


def _on_alarm(signum, frame):
    raise _Alarm


def run_in_process(entry: Callable[[list[str]], int], argv: list[str]
                   ) -> tuple[int | None, str, str]:
    """Runs a command's main in this process: (exit code or None, stderr, what escaped)."""
    err, out = io.StringIO(), io.StringIO()
    escaped = ""
    code: int | None = None
    signal.signal(signal.SIGALRM, _on_alarm)
    signal.alarm(TIMEOUT)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            code = entry(argv)
    except _Alarm:
        escaped = f"hang: more than {TIMEOUT} s"
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 2
    except BaseException as exc:  # noqa: BLE001 - a traceback from the command line
        escaped = f"{type(exc).__name__}: {exc}"
    finally:
        signal.alarm(0)
    return code, err.getvalue(), escaped


def judge(t: Tally, case: str, code: int | None, err: str, escaped: str,
          names: list[str]) -> None:
    """Classify one run of a command on a bad input named by ``names`` (file names/args)."""
    if escaped:
        t.serious(case, "traceback/hang: " + escaped)
    elif "internal error" in err or "Traceback" in err:
        t.serious(case, "internal error: " + err)
    elif code in (1, 2):
        if any(n in err for n in names):
            t.ok(REFUSED)
        else:
            t.minor(case, "message does not name the input: " + err)
    elif code in (0, 3, 4, 5, 6):
        t.ok(f"accepted (exit {code})")
    else:
        t.serious(case, f"exit {code}: {err}")


# -- mutations of text files ---------------------------------------------------------------------

BAD_TOKENS = ["", "nan", "inf", "-inf", "1e308", "-1e400", "abc", "0x10", "1_000", " ", "\uff11",
              "\x00", "1e-320", "99999999999999999999", '"', "1,5", "--1", "+", "1e", "NaN",
              "true", "[]", "{}", "1.0.0", "-0", "\u00a0"]


def mutate_lines(text: str, rng: random.Random, sep: str = ",") -> tuple[str, str]:
    lines = text.splitlines(keepends=True)
    k = rng.randrange(len(lines))
    op = rng.choice(["truncate", "token", "token", "token", "delete", "duplicate", "bytes",
                     "swap-header", "drop-field", "extra-field", "long-field", "crlf-bom",
                     "empty", "header-only", "repeat-all"])
    if op == "truncate":
        return text[: rng.randrange(len(text))], op
    if op == "delete":
        del lines[k]
    elif op == "duplicate":
        lines.insert(k, lines[k])
    elif op == "bytes":
        b = lines[k].encode()
        i = rng.randrange(len(b) + 1)
        bad = bytes(rng.randrange(128, 256) for _ in range(3))
        return (b"".join(x.encode() for x in lines[:k]) + b[:i] + bad + b[i:]
                + b"".join(x.encode() for x in lines[k + 1:])).decode("latin-1"), op
    elif op in ("token", "drop-field", "extra-field", "long-field", "swap-header"):
        if op == "swap-header":
            k = next((j for j, s in enumerate(lines) if not s.startswith(("#", "//"))), 0)
        f = lines[k].rstrip("\r\n").split(sep)
        i = rng.randrange(len(f))
        if op == "token":
            f[i] = rng.choice(BAD_TOKENS)
        elif op == "drop-field":
            del f[i]
        elif op == "extra-field":
            f.insert(i, "1.0")
        elif op == "long-field":
            f[i] = "1" * 1_000_000
        else:
            j = rng.randrange(len(f))
            f[i], f[j] = f[j], f[i]
        lines[k] = sep.join(f) + "\n"
    elif op == "crlf-bom":
        return "\ufeff" + text.replace("\n", "\r\n"), op
    elif op == "empty":
        return "", op
    elif op == "header-only":
        return "".join(s for s in lines if s.startswith("#")) + next(
            s for s in lines if not s.startswith("#")), op
    elif op == "repeat-all":
        body = [s for s in lines if not s.startswith(("#", "//"))]
        return "".join(lines) + "".join(body[1:]), op
    return "".join(lines), op


def toml_cases(rng: random.Random, n: int, base: str) -> list[tuple[str, str]]:
    special = [
        ("dotted key 17 parts", base + "\n[provenance]\n" + ".".join(["a"] * 17) + " = 1\n"),
        ("dotted key 5000 parts", base + "\n[provenance]\n" + ".".join(["a"] * 5000) + " = 1\n"),
        ("dotted key 16 parts", base + "\n[provenance]\n" + ".".join(["a"] * 16) + " = 1\n"),
        ("header 17 deep", base + "\n[" + ".".join(["t"] * 17) + "]\nx = 1\n"),
        ("header 3000 deep", base + "\n[" + ".".join(["t"] * 3000) + "]\nx = 1\n"),
        ("array header 50 deep", base + "\n[[" + ".".join(["t"] * 50) + "]]\nx = 1\n"),
        ("string 300 kB", base + '\n[provenance]\nnote = "' + "x" * 300_000 + '"\n'),
        ("string 200 kB", base + '\n[provenance]\nnote = "' + "x" * 200_000 + '"\n'),
        ("nested arrays 1000", base + "\n[provenance]\nv = " + "[" * 1000 + "]" * 1000 + "\n"),
        ("inline tables 500", base + "\n[provenance]\nv = " + "{a=" * 500 + "1" + "}" * 500
         + "\n"),
        ("20000 keys", base + "\n[provenance]\n" + "".join(f"k{i} = {i}\n"
                                                          for i in range(20000))),
        ("binary garbage", "".join(chr(rng.randrange(256)) for _ in range(2000))),
        ("empty", ""),
        ("duplicate table", base + "\n" + base),
    ]
    out = list(special)
    lines = base.splitlines()
    value_lines = [i for i, s in enumerate(lines) if "=" in s and not s.lstrip().startswith("#")]
    bad_values = ['"text"', "inf", "nan", "-inf", "1e400", "-1", "0", "[]", "[1, 2]", "{}",
                  "true", "1e-320", "99999999999", '[[1,2,3],[4,5,6]]', '"1.0"', "[nan]",
                  "1979-05-27", "0x7fffffffffffffff", "[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]"]
    while len(out) < n:
        r = rng.random()
        if r < 0.55:
            i = rng.choice(value_lines)
            key = lines[i].split("=", 1)[0]
            mod = list(lines)
            mod[i] = f"{key}= {rng.choice(bad_values)}"
            out.append((f"line {i + 1} value", "\n".join(mod) + "\n"))
        elif r < 0.65:
            mod = list(lines)
            del mod[rng.choice(value_lines)]
            out.append(("key removed", "\n".join(mod) + "\n"))
        elif r < 0.72:
            mod = list(lines)
            i = rng.choice(value_lines)
            mod.insert(i, "unknwn_key = 1")
            out.append(("unknown key", "\n".join(mod) + "\n"))
        else:
            text, op = mutate_lines(base, rng, sep="=")
            out.append((op, text))
    return out[:n]


def run_toml(args: argparse.Namespace, work: Path) -> dict:
    t = Tally("toml")
    rng = random.Random(args.seed)
    base = (EX / "iwr.toml").read_text()
    data = str(EX / "iwr_example.csv")
    for k, (what, text) in enumerate(toml_cases(rng, args.cases, base)):
        p = work / f"robot{k}.toml"
        p.write_text(text, encoding="utf-8", errors="surrogateescape")
        t0 = time.monotonic()
        code, err, esc = run_in_process(iwr_main, ["analyze", str(p), data])
        if time.monotonic() - t0 > 20:
            t.serious(f"toml {k} {what}", f"took {time.monotonic() - t0:.0f} s")
        judge(t, f"toml {k} {what}", code, err, esc, [p.name])
        p.unlink()
    return t.report()


# -- CSV of each kind ----------------------------------------------------------------------------

def _targets(path: Path, data) -> None:
    lines = ["// target list written by the campaign", "// Units: mm"]
    for k in range(len(data)):
        for i in range(data.n_reflectors):
            p = data.points[k, i]
            if np.isnan(p).any():
                continue
            lines.append(" ".join(["Robot", "Cal", f"P{k + 1}_R{i + 1}",
                                   *(repr(float(v)) for v in p)]))
    path.write_text("\n".join(lines) + "\n")


def run_csv(args: argparse.Namespace, work: Path) -> dict:
    t = Tally("csv")
    rng = random.Random(args.seed + 1)
    from iwr.tracker import read_tracker_data

    trobot = str(EX / "iwr_tracker.toml")
    setup = iwr.Robot.from_toml(trobot).tracker
    tdata = read_tracker_data(EX / "iwr_tracker_points.csv", setup)
    _targets(work / "targets.txt", tdata)
    kinds = {
        "pose": (str(EX / "iwr.toml"), (EX / "iwr_example.csv").read_text(), ",", []),
        "tracker wide": (trobot, (EX / "iwr_tracker_points.csv").read_text(), ",", []),
        "tracker long": (trobot, (EX / "iwr_tracker_points_long.csv").read_text(), ",",
                         ["--readings", str(EX / "iwr_tracker_readings.csv")]),
        "tracker readings": (trobot, (EX / "iwr_tracker_readings.csv").read_text(), ",",
                             ["--points"]),
        "target list": (trobot, (work / "targets.txt").read_text(), " ",
                        ["--readings", str(EX / "iwr_tracker_readings.csv"), "--target-names",
                         "P{pose}_R{reflector}"]),
    }
    per = max(1, args.cases // len(kinds))
    for kind, (robot, text, sep, extra) in kinds.items():
        for k in range(per):
            mutated, op = mutate_lines(text, rng, sep)
            p = work / f"data{k}.csv"
            p.write_text(mutated, encoding="utf-8", errors="surrogateescape")
            if kind == "tracker readings":  # the readings mutated, the points intact
                argv = ["analyze", robot, str(EX / "iwr_tracker_points_long.csv"),
                        "--readings", str(p)]
            else:
                argv = ["analyze", robot, str(p), *extra]
            code, err, esc = run_in_process(iwr_main, argv)
            judge(t, f"{kind} {k} {op}", code, err, esc, [p.name])
    return t.report()


# -- crafted and truncated binary files ----------------------------------------------------------

def run_binary(args: argparse.Namespace, work: Path) -> dict:
    t = Tally("binary")
    rng = random.Random(args.seed + 2)
    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, 12, seed=1)
    iwr.Problem(robot, m).save(work / "p.iwrp")
    subprocess.run([str(BIN / "iwr-engine"), str(work / "p.iwrp"), "--generations", "3",
                    "--population-size", "16", "--checkpoint", str(work / "c.ckpt"), "--quiet"],
                   check=True)
    good = {"problem": (work / "p.iwrp").read_bytes(), "checkpoint": (work / "c.ckpt").read_bytes()}
    for k in range(args.cases):
        kind = rng.choice(list(good))
        b = bytearray(good[kind])
        op = rng.choice(["truncate", "flip", "flip", "zero-run", "insert", "huge-count"])
        if op == "truncate":
            b = b[: rng.randrange(len(b))]
        elif op == "flip":
            for _ in range(rng.randint(1, 8)):
                b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        elif op == "zero-run":
            i = rng.randrange(len(b))
            b[i:i + 64] = bytes(len(b[i:i + 64]))
        elif op == "insert":
            i = rng.randrange(len(b))
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 32)))
        else:  # a length or count field set to a huge value (the header is checksummed)
            i = rng.randrange(8, max(9, min(len(b), 512)))
            b[i:i + 8] = (0xFFFFFFFFFFFF).to_bytes(8, "little")
        case = f"{kind} {k} {op}"
        if kind == "problem":
            p = work / f"m{k}.iwrp"
            p.write_bytes(bytes(b))
            out = work / f"m{k}.json"
            r = subprocess.run([str(BIN / "iwr-calibrate"), str(p), "--output", str(out),
                                "--generations", "2", "--population-size", "12", "--quiet"],
                               capture_output=True, text=True, timeout=TIMEOUT)
            if r.returncode < 0:
                t.serious(case, f"killed by signal {-r.returncode}: {r.stderr}")
            else:
                judge(t, case, r.returncode, r.stderr, "", [p.name])
        else:
            p = work / f"m{k}.ckpt"
            p.write_bytes(bytes(b))
            code, err, esc = run_in_process(launcher_main, [
                "--export", str(p), "--problem", str(work / "p.iwrp"),
                "--output", str(work / f"e{k}.json")])
            judge(t, case, code, err, esc, [p.name])
        for f in work.glob(f"[me]{k}.*"):
            f.unlink()
    return t.report()


# -- signals at random moments -------------------------------------------------------------------

def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def check_folder(out: Path) -> str | None:
    """None if the output folder is absent, complete and readable, or marked incomplete; else
    what is wrong (a half-written file, temporaries left in a folder said complete)."""
    if not out.exists():
        return None
    names = {p.name for p in out.iterdir()}
    if not names or "INCOMPLETE.txt" in names:  # nothing written, or said incomplete
        return None
    expected = {"calibrated.toml", "result.json", "summary.json", "report.md", "report.html"}
    extra = {n for n in names - expected if not n.endswith(".png")}
    if extra:
        return f"unexpected files in a folder not marked incomplete: {sorted(extra)}"
    if not expected <= names:
        return f"files missing in a folder not marked incomplete: {sorted(expected - names)}"
    try:
        iwr.load_result(out / "result.json")
        json.loads((out / "summary.json").read_text())
        iwr.Robot.from_toml(out / "calibrated.toml")
        if not (out / "report.html").read_text().rstrip().endswith("</html>"):
            return "report.html cut"
    except Exception as exc:  # noqa: BLE001
        return f"unreadable: {type(exc).__name__}: {exc}"
    return None


def run_signals(args: argparse.Namespace, work: Path) -> dict:
    t = Tally("signals")
    rng = random.Random(args.seed + 3)
    robot, data = str(EX / "iwr.toml"), str(EX / "iwr_example.csv")
    calib = [str(BIN / "iwr"), "calibrate", robot, data, "--no-plots"]
    t0 = time.monotonic()
    subprocess.run([*calib, "--out", str(work / "ref")], capture_output=True, check=True)
    span = time.monotonic() - t0
    sigs = [signal.SIGINT, signal.SIGTERM, signal.SIGKILL]
    n_calib = args.cases // 2
    for k in range(n_calib):
        out = work / f"o{k}"
        if k % 3 == 0:  # an earlier complete run's folder: a kill must not leave a mix
            shutil.copytree(work / "ref", out)
        sig = sigs[k % 3]
        # half the signals in the last third of the run: the report's write
        delay = rng.uniform(0, span) if k % 2 else rng.uniform(0.6 * span, 1.1 * span)
        proc = subprocess.Popen([*calib, "--out", str(out)], stdout=subprocess.DEVNULL,
                                stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
        time.sleep(delay)
        proc.send_signal(sig)
        try:
            _, err = proc.communicate(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.kill()
            t.serious(f"iwr calibrate {sig.name} at {delay:.2f}s", "hang")
            continue
        case = f"iwr calibrate {sig.name} at {delay:.2f} s (exit {proc.returncode})"
        if "Traceback" in err:
            t.serious(case, err)
            continue
        bad = check_folder(out)
        if bad:
            t.serious(case, bad)
        else:
            t.ok(f"iwr calibrate: folder whole or marked ({sig.name})")
        shutil.rmtree(out, ignore_errors=True)

    # iwr-calibrate: stop it at random moments, resume until it ends, compare with a whole run
    opts = ["--generations", "300", "--population-size", "24", "--seed", "5",
            "--checkpoint-every", "20", "--quiet"]
    launcher = [str(BIN / "iwr-calibrate"), robot, data]
    subprocess.run([*launcher, "--output", str(work / "whole.json"), *opts], check=True,
                   capture_output=True)
    reference = iwr.load_result(work / "whole.json")
    runs = 0
    for k in range(args.cases - n_calib):
        res = work / "r.json"
        cmd = [*launcher, "--output", str(res), *opts]
        if Path(str(res) + ".ckpt").exists():
            cmd += ["--resume", str(res) + ".ckpt"]
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True, preexec_fn=_default_sigint)
        time.sleep(rng.uniform(0.0, 2.5))
        sig = sigs[k % 3]
        proc.send_signal(sig)
        try:
            _, err = proc.communicate(timeout=TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.kill()
            t.serious(f"iwr-calibrate {sig.name}", "hang")
            continue
        runs += 1
        case = f"iwr-calibrate {sig.name} (exit {proc.returncode})"
        if "Traceback" in err:
            t.serious(case, err)
        elif "in use by another" in err:  # the engine of a killed launcher still ending
            time.sleep(1)
            t.ok("iwr-calibrate: refused while the engine ends")
        else:
            t.ok(f"iwr-calibrate: stopped ({sig.name})")
        if proc.returncode == 0:
            if not _same_result(iwr.load_result(res), reference):
                t.serious(case, "the resumed run differs from the whole run")
            else:
                t.ok("iwr-calibrate: run ended, resumed bit-identical")
            for f in work.glob("r.json*"):
                f.unlink()
    # finish the last run and compare
    if Path(str(work / "r.json") + ".ckpt").exists():
        for _ in range(30):
            r = subprocess.run([*launcher, "--output", str(work / "r.json"), *opts, "--resume",
                                str(work / "r.json.ckpt")], capture_output=True, text=True)
            if "in use by another" not in r.stderr:
                break
            time.sleep(1)
        if r.returncode != 0 or not _same_result(iwr.load_result(work / "r.json"), reference):
            t.serious("iwr-calibrate last resume", f"exit {r.returncode} {r.stderr}")
        else:
            t.ok("iwr-calibrate: resumed bit-identical")
    left = [p.name for p in work.iterdir() if p.name.startswith(".") and
            not p.name.endswith(".lock")]
    if left:
        t.serious("temporary files", f"left: {left}")
    return t.report()


def _same_result(a, b) -> bool:
    return (np.array_equal(a.x, b.x) and a.fun == b.fun and (a.nfev, a.nit) == (b.nfev, b.nit))


# -- file-size limit -----------------------------------------------------------------------------

def run_fsize(args: argparse.Namespace, work: Path) -> dict:
    t = Tally("fsize")
    robot, data = str(EX / "iwr.toml"), str(EX / "iwr_example.csv")
    limits = [200, 2_000, 3_000, 8_000, 12_000, 20_000, 60_000]
    for k, lim in enumerate(limits[: max(1, args.cases // 2)]):
        def setlimit(lim=lim):
            _default_sigint()
            resource.setrlimit(resource.RLIMIT_FSIZE, (lim, lim))
        for cmd, name in (
                ([str(BIN / "iwr"), "calibrate", robot, data, "--no-plots", "--out",
                  str(work / f"o{k}")], f"o{k}"),
                ([str(BIN / "iwr-calibrate"), robot, data, "--generations", "50", "--output",
                  str(work / f"r{k}.json"), "--quiet"], f"r{k}.json")):
            r = subprocess.run(cmd, capture_output=True, text=True, preexec_fn=setlimit,
                               timeout=TIMEOUT)
            case = f"{Path(cmd[0]).name} RLIMIT_FSIZE {lim} B (exit {r.returncode})"
            if r.returncode < 0 or "Traceback" in r.stderr:
                t.serious(case, r.stderr)
            elif r.returncode == 0:
                t.ok("fits in the limit")
            elif name in r.stderr:
                t.ok(REFUSED)
            else:
                t.minor(case, r.stderr)
            if name.startswith("o"):
                bad = check_folder(work / name)
                if bad:
                    t.serious(case, bad)
    left = [p.name for p in work.iterdir() if p.name.startswith(".") and
            not p.name.endswith(".lock")]
    for d in work.glob("o*"):
        if (d / "INCOMPLETE.txt").exists():
            continue
        left += [f"{d.name}/{p.name}" for p in d.iterdir() if p.name.startswith(".")]
    if left:
        t.serious("temporary files", f"left: {left}")
    return t.report()


# -- concurrent runs on one output ---------------------------------------------------------------

def run_concurrent(args: argparse.Namespace, work: Path) -> dict:
    t = Tally("concurrent")
    rng = random.Random(args.seed + 4)
    robot = str(EX / "iwr.toml")
    full = (EX / "iwr_example.csv").read_text().splitlines(keepends=True)
    head = [s for s in full if s.startswith("#")]
    body = [s for s in full if not s.startswith("#")]
    # two different data files (the first 60 and the last 60 poses) so that a mix shows
    for name, rows in (("a.csv", body[1:61]), ("b.csv", body[-60:])):
        (work / name).write_text("".join(head + body[:1] + rows))
    for k in range(max(1, args.cases // 2)):
        out = work / f"o{k}"
        procs = []
        for name in ("a.csv", "b.csv"):
            procs.append(subprocess.Popen(
                [str(BIN / "iwr"), "calibrate", robot, str(work / name), "--no-plots", "--out",
                 str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True))
            time.sleep(rng.uniform(0, 0.8))
        errs = [p.communicate(timeout=TIMEOUT)[1] for p in procs]
        case = f"two iwr calibrate --out o{k}: exits {[p.returncode for p in procs]}"
        if any("Traceback" in e or "internal error" in e for e in errs):
            t.serious(case, " | ".join(errs))
            continue
        bad = check_folder(out)
        if bad:
            t.serious(case, bad)
            continue
        if (out / "INCOMPLETE.txt").exists():
            t.ok("marked incomplete")
            continue
        res = iwr.load_result(out / "result.json")
        data_file = Path(dict(res.get("settings") or {}).get("data_file", "?")).name
        summary = json.loads((out / "summary.json").read_text())
        if data_file not in json.dumps(summary.get("data")) or \
                data_file not in (out / "report.md").read_text():
            t.serious(case, f"files of two runs mixed: result from {data_file}")
        else:
            t.ok("one run's files, whole")
    # two iwr-calibrate on one --output: the second refused, the first's record kept (the first
    # is then stopped by SIGINT: its result must come from its own problem)
    from iwr.problem_file import read_problem

    for k in range(max(1, args.cases // 2)):
        out = work / f"r{k}.json"
        cmd = [str(BIN / "iwr-calibrate"), robot, str(work / "a.csv"), "--output", str(out),
               "--generations", "100000", "--population-size", "24", "--quiet"]
        first = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                 text=True, preexec_fn=_default_sigint)
        time.sleep(rng.uniform(0.0, 2.0))
        second = subprocess.run([*cmd[:2], str(work / "b.csv"), *cmd[3:]], capture_output=True,
                                text=True, timeout=TIMEOUT, preexec_fn=_default_sigint)
        time.sleep(1.0)
        first.send_signal(signal.SIGINT)
        _, err1 = first.communicate(timeout=TIMEOUT)
        case = f"two iwr-calibrate --output r{k}: exits {first.returncode}, {second.returncode}"
        sources = [p for _, p, _ in read_problem(str(out) + ".iwrp")["sources"]]
        if second.returncode == 0:
            t.serious(case, "both ran on one output")
        elif "Traceback" in second.stderr + err1:
            t.serious(case, second.stderr + err1)
        elif first.returncode not in (130, 0) or not any("a.csv" in p for p in sources):
            t.serious(case, f"the first run's record lost: sources {sources}, {err1}")
        else:
            try:
                iwr.load_result(out)
            except Exception as exc:  # noqa: BLE001
                t.serious(case, f"the first run's result: {exc}")
                continue
            if out.name in second.stderr or "in use" in second.stderr:
                t.ok("second refused, first kept its record and result")
            else:
                t.minor(case, second.stderr)
    return t.report()


# -- fork under load -----------------------------------------------------------------------------

def run_fork(args: argparse.Namespace, work: Path) -> dict:
    t = Tally("fork")
    import threading

    robot = iwr.Robot.default()
    m, _ = iwr.simulate(robot, 40, seed=1)
    problem = iwr.Problem(robot, m)
    pop = np.random.default_rng(0).uniform(-0.1, 0.1, (64, problem.n_params))
    expected = problem.cost_batch(pop)
    stop = threading.Event()

    def busy() -> None:
        while not stop.is_set():
            problem.cost_batch(pop)

    threads = [threading.Thread(target=busy, daemon=True) for _ in range(2)]
    for th in threads:
        th.start()
    try:
        for k in range(args.cases):
            time.sleep(random.Random(k).uniform(0, 0.01))
            pid = os.fork()
            if pid == 0:
                try:
                    ok = np.allclose(problem.cost_batch(pop), expected, rtol=1e-12)
                    os._exit(0 if ok else 3)
                except BaseException:  # noqa: BLE001
                    os._exit(4)
            deadline = time.monotonic() + 30
            while True:
                done, status = os.waitpid(pid, os.WNOHANG)
                if done:
                    break
                if time.monotonic() > deadline:
                    os.kill(pid, signal.SIGKILL)
                    os.waitpid(pid, 0)
                    status = -1
                    break
                time.sleep(0.01)
            if status == -1:
                t.serious(f"fork {k}", "child hung (30 s)")
            elif os.waitstatus_to_exitcode(status) != 0:
                t.serious(f"fork {k}", f"child exit {os.waitstatus_to_exitcode(status)}")
            else:
                t.ok("child computed the same costs")
    finally:
        stop.set()
        for th in threads:
            th.join()
    return t.report()


# -- degenerate data ------------------------------------------------------------------------------

def run_degenerate(args: argparse.Namespace, work: Path) -> dict:
    """Degenerate data of every kind through ``iwr calibrate``: exit code, ``success`` and the
    verdict must agree, and none may end calibrated (exit 0)."""
    t = Tally("degenerate")
    from iwr.planning import measure
    from iwr.tracker import write_tracker_wide

    pose_robot = iwr.Robot.from_toml(EX / "iwr.toml")
    pts_robot = iwr.Robot.from_toml(EX / "iwr_tracker.toml")
    probe_robot = pts_robot.with_tracker(registration=pts_robot.tracker.registration,
                                         probe=(0.0, 0.0, 60.0, 0.0, 0.0, 0.0))
    cases = []
    for kind, robot in (("pose", pose_robot), ("points", pts_robot), ("probe", probe_robot)):
        data, _ = iwr.simulate(robot, 60, seed=11)
        rp = work / f"{kind}.toml"
        robot.to_toml(rp)

        def sub(rows, data=data):
            return data.subset(np.asarray(rows))

        variants = {
            "2 poses copied 30 times": [0, 1] * 30,
            "1 pose": [0],
            "3 poses": [0, 1, 2],
            "6 poses": list(range(6)),
            "10 poses": list(range(10)),
        }
        for name, rows in variants.items():
            cases.append((kind, name, rp, sub(rows)))
        # rank-deficient: the carriage still, the platform moved a little about one pose (the
        # carriage's errors cannot be told from the hexapod's)
        data0, x = iwr.simulate(robot, 1, seed=12)
        rng = np.random.default_rng(12)
        poses0 = _poses(robot, x, data0)
        poses = poses0 + np.hstack([rng.uniform(-20, 20, (40, 3)),
                                    rng.uniform(-0.05, 0.05, (40, 3))])
        q = np.repeat(np.asarray(data0.q)[:1], 40, axis=0)
        cases.append((kind, "carriage still", rp, measure(robot, x, q, poses, seed=1)))
    for kind, name, rp, data in cases[: args.cases]:
        dp = work / f"{kind}-{name.replace(' ', '_')}.csv"
        if kind == "pose":
            data.to_csv(dp)
        else:
            write_tracker_wide(dp, iwr.Robot.from_toml(rp).tracker, data)
        out = work / f"out-{dp.stem}"
        code, err, esc = run_in_process(iwr_main, ["calibrate", str(rp), str(dp), "--no-plots",
                                                   "--out", str(out)])
        case = f"{kind}: {name} (exit {code})"
        print(f"  {case}: {' '.join(err.split())[:200]}", flush=True)
        if esc or "internal error" in err:
            t.serious(case, esc or err)
            continue
        if code in (1, 2):
            if dp.name in err or " --" in err:
                t.ok(REFUSED)
            else:
                t.minor(case, "message does not name the data file: " + err)
            continue
        res = iwr.load_result(out / "result.json")
        verdict = (out / "report.md").read_text()
        calibrated = "**Calibrated" in verdict
        if code == 0 or res.success or calibrated:
            if not (code == 0 and res.success and calibrated):
                t.serious(case, f"disagree: exit {code}, success {res.success}, "
                                f"verdict calibrated {calibrated}")
            else:
                t.serious(case, "degenerate data ended calibrated")
        else:
            t.ok(f"reported (exit {code}, not success)")
    return t.report()


def _poses(robot, x, data) -> np.ndarray:
    """The platform poses in {0} of simulated data of any kind (tracker data: by the actual
    robot's forward kinematics)."""
    if hasattr(data, "poses"):
        return np.asarray(data.poses)
    from iwr.forward import forward_kinematics

    return np.atleast_2d(forward_kinematics(robot, np.asarray(x)[:robot.n_params], data.q,
                                            data.legs))


CLASSES = {"toml": run_toml, "csv": run_csv, "binary": run_binary, "signals": run_signals,
           "fsize": run_fsize, "concurrent": run_concurrent, "fork": run_fork,
           "degenerate": run_degenerate}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cls", choices=[*CLASSES, "all"])
    ap.add_argument("--cases", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", metavar="DIR", help="work in DIR and keep it")
    args = ap.parse_args()
    signal.signal(signal.SIGINT, signal.default_int_handler)
    results = []
    for name in (CLASSES if args.cls == "all" else [args.cls]):
        with (contextlib.nullcontext(args.keep) if args.keep
              else tempfile.TemporaryDirectory()) as tmp:
            work = Path(tmp) / name
            work.mkdir(parents=True, exist_ok=True)
            t0 = time.monotonic()
            results.append(CLASSES[name](args, work))
            print(f"   ({time.monotonic() - t0:.0f} s)", flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"\npeak memory of the campaign process: {peak:.0f} MB")
    print(json.dumps(results))


if __name__ == "__main__":
    main()
