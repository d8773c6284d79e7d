"""iwr.reporting: every HTML report (calibrate, report, compare, study) is one self-contained file
that a real browser opens with every image loaded and no console message.

The browser is Debian's chromium, headless (``.ci/run`` installs it). The page is a copy of the
report with a script added first in its head: it records error events (a resource that fails to
load, a script error) and, once the page has loaded, writes the number of images, those whose
``naturalWidth`` is 0 and the errors into the DOM, which ``--dump-dom`` prints. Console messages
come from chromium's own log on standard error.
"""

from __future__ import annotations

import html
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import pytest

import iwr

_CHECK = """<script>
window.__iwrErrors = [];
window.addEventListener("error", function (e) {
  var t = e.target || {};
  window.__iwrErrors.push(String(e.message || t.src || t.href || "error event"));
}, true);
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); })
                .map(function (i) { return i.alt || i.src.slice(0, 40); });
  var out = document.createElement("pre");
  out.id = "iwr-check";
  out.textContent = JSON.stringify({images: imgs.length, bad: bad, errors: window.__iwrErrors});
  document.body.appendChild(out);
});
</script>"""


def chromium() -> str:
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        if os.environ.get("CI") == "true":
            pytest.fail("chromium is not installed; CI must have it (.ci/run installs it)")
        pytest.skip("chromium is not installed (apt-get install chromium)")
    return path


def open_in_browser(report: Path, tmp: Path) -> dict[str, Any]:
    """Load ``report`` in headless chromium; the image check and the console messages."""
    page = report.read_text(encoding="utf-8")
    assert page.count("<head>") == 1
    checked = report.with_name(f".checked-{report.name}")
    checked.write_text(page.replace("<head>", "<head>" + _CHECK, 1), encoding="utf-8")
    proc = subprocess.run(
        [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
         f"--user-data-dir={tmp / 'chromium-profile'}", "--enable-logging=stderr", "--v=0",
         "--virtual-time-budget=10000", "--dump-dom", checked.resolve().as_uri()],
        capture_output=True, text=True, timeout=120,
    )
    checked.unlink()
    m = re.search(r'<pre id="iwr-check">(.*?)</pre>', proc.stdout, re.S)
    assert m, (proc.returncode, proc.stderr[-2000:])
    result = json.loads(html.unescape(m.group(1)))
    result["console"] = [ln for ln in proc.stderr.splitlines() if ":CONSOLE" in ln]
    return result


def assert_opens_cleanly(report: Path, tmp: Path, min_images: int) -> None:
    page = report.read_text(encoding="utf-8")
    # self-contained: nothing loaded from elsewhere
    assert not re.search(r'\bsrc="(?!data:)', page) and "<link" not in page
    assert "@import" not in page and "url(" not in page
    res = open_in_browser(report, tmp)
    assert res["images"] >= min_images, res
    assert res["bad"] == [], res
    assert res["errors"] == [], res
    assert res["console"] == [], res


def run_iwr(*args: str) -> subprocess.CompletedProcess[str]:
    environ = {k: v for k, v in os.environ.items() if not k.startswith("IWR_")}
    return subprocess.run([sys.executable, "-m", "iwr", *args], capture_output=True, text=True,
                          cwd=tempfile.gettempdir(), env=environ, timeout=600)


@pytest.fixture(scope="module")
def sim(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim")
    proc = run_iwr("simulate", "--poses", "40", "--seed", "5", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    return out


def test_compare_page_opens_cleanly(tmp_path: Path) -> None:
    chromium()
    iwr.compare_methods(n_poses=15, seeds=[0], methods=["lm", "crs2"], budget=200, start="both",
                        out=tmp_path / "cmp", n_validation=10, progress=False)
    assert_opens_cleanly(tmp_path / "cmp" / "report.html", tmp_path, 5)


def test_study_page_opens_cleanly(tmp_path: Path) -> None:
    chromium()
    iwr.study(methods="lm", poses=[12, 16], noise=[0.0, 0.02], draws=1, seeds=1,
              out=tmp_path / "st", scheduler="synchronous", validation_poses=10)
    assert_opens_cleanly(tmp_path / "st" / "report.html", tmp_path, 2)


def test_a_broken_image_and_a_console_error_are_seen(tmp_path: Path) -> None:
    """The check itself: a page with an image that does not load and a script error fails."""
    chromium()
    bad = tmp_path / "bad.html"
    bad.write_text('<!DOCTYPE html><html><head><meta charset="utf-8"></head><body>'
                   '<img alt="missing" src="data:image/png;base64,AAAA">'
                   "<script>console.error('boom'); undefinedFunction();</script></body></html>")
    res = open_in_browser(bad, tmp_path)
    assert res["bad"] == ["missing"]
    assert res["errors"] and res["console"]


#: Each kind's report sections, in their order, and what its page says of the kind's own parts.
_SECTIONS = {
    "pose": (["Summary", "Identified parameters", "Identifiability", "Leg residuals",
              "Settings", "Provenance"], [], "# Calibration report"),
    "points": (["Summary", "Registration", "Reflector offsets", "Point residuals",
                "Identified parameters", "Identifiability", "Settings", "Provenance"],
               ["closed-form guess (Kabsch)", "16 null directions", "reflector 1", "reflector 3",
                "0 of 120 points not seen"], "# Calibration report: laser-tracker data"),
    "probe": (["Summary", "Registration", "Probe offset", "Point residuals",
               "Identified parameters", "Identifiability", "Settings", "Provenance"],
              ["closed-form guess (Kabsch)", "16 null directions", "probe origin",
               "probe orientation (deg)", "0 of 40 probe poses not seen"],
              "# Calibration report: laser-tracker data"),
    "ballbar": (["Summary", "Distance residuals per set-up", "Ball centres and length offsets",
                 "Identified parameters", "What a ballbar cannot see", "Settings", "Provenance"],
                ["16 null directions", "A: platform ball in {5}", "B: length offset"],
                "# Calibration report: double-ballbar"),
}


def test_calibration_and_report_pages_open_cleanly(kind: Any, tmp_path: Path) -> None:
    """Every kind's calibration, through the command line from its own files with realistic
    noise: the report's sections in order (the common ones and the kind's own), a good verdict,
    the page opens cleanly in a real browser (no console error, every image loads); then
    ``iwr report`` of that run, on the same files, opens cleanly too."""
    chromium()
    name = kind.name
    n = {"ballbar": 120}.get(name, 40)
    noise = kind.kind.experiment_noise(kind.robot, iwr.Noise.realistic())
    data, _ = iwr.simulate(kind.robot, n, seed=4, noise=noise)
    kind.robot.to_toml(tmp_path / "robot.toml")
    kind.kind.write(kind.robot, data, tmp_path / "data.csv")
    out = tmp_path / "cal"
    proc = run_iwr("calibrate", str(tmp_path / "robot.toml"), str(tmp_path / "data.csv"),
                   "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    page = (out / "report.html").read_text(encoding="utf-8")
    sections, says, title = _SECTIONS[name]
    order = [page.index(f"<h2>{h}</h2>") for h in sections]
    assert order == sorted(order)
    assert 'class="verdict good"' in page and iwr.__version__ in page
    for text in says:
        assert text in page, text
    # The settings' seed says what it seeds (the example's data have a seed of their own).
    assert "<td>seed (validation split and stochastic methods)</td>" in page
    if name != "pose":  # every parameter held by active="base" is held on a null direction
        assert "held fixed" not in page and page.count("held (null direction") == 16
    if name == "probe":  # a probe's pose is seen whole or not: counted as poses, not points
        assert "points not seen" not in page
    summary = json.loads((out / "summary.json").read_text())
    assert summary["data_kind"] == name and summary["fit"]["fit_ok"] is True
    md = (out / "report.md").read_text()
    assert md.startswith(title)
    for h in ("Files", "Notes", "Provenance"):  # the Markdown's tail is the page's
        assert (f"<h2>{h}</h2>" in page) == (f"\n## {h}\n" in md), h
    assert_opens_cleanly(out / "report.html", tmp_path, 2)
    rep = tmp_path / "rep"
    proc = run_iwr("report", str(out / "result.json"), str(tmp_path / "robot.toml"),
                   str(tmp_path / "data.csv"), "--out", str(rep))
    assert proc.returncode == 0, proc.stderr
    assert_opens_cleanly(rep / "report.html", tmp_path, 2)


def test_an_output_folder_is_written_as_a_whole(tmp_path):
    """Issue 26: a kill or a full disk while the report was written left a folder mixing two
    runs. write_folder makes the files elsewhere first; a failure leaves the earlier run whole."""
    from iwr._io import INCOMPLETE_MARKER, write_folder

    out = tmp_path / "out"

    def run(tag: str, names: list[str], fail_after: int | None = None):
        def write(tmp):
            paths = []
            for k, name in enumerate(names):
                if fail_after is not None and k == fail_after:
                    raise OSError(28, "No space left on device")
                (tmp / name).write_text(tag)
                paths.append(tmp / name)
            return paths
        return write_folder(out, write, owned=["a.txt", "b.txt", "c.png"])

    run("first", ["a.txt", "b.txt", "c.png"])
    (out / "user.txt").write_text("mine")
    with pytest.raises(OSError, match=r"out: cannot write the output: No space left on device"):
        run("second", ["a.txt", "b.txt"], fail_after=1)
    assert {p.name: p.read_text() for p in out.iterdir()} == {
        "a.txt": "first", "b.txt": "first", "c.png": "first", "user.txt": "mine"}
    written = run("third", ["a.txt", "b.txt"])  # without its figure: the old one goes
    assert [p.name for p in written] == ["a.txt", "b.txt"]
    assert {p.name: p.read_text() for p in out.iterdir()} == {
        "a.txt": "third", "b.txt": "third", "user.txt": "mine"}
    assert not (out / INCOMPLETE_MARKER).exists()
    # A writer killed while making its files left its temporary folder: removed by the next.
    dead = out / ".iwr-writing-999999999-x1y2"
    dead.mkdir()
    run("fourth", ["a.txt"])
    assert not dead.exists()


def test_atomic_write_removes_the_temporaries_of_killed_writers(tmp_path):
    """A writer killed (SIGKILL) between its temporary file and the rename left `.NAME.XXXX.tmp`
    for good (issue 26's campaign: iwr-calibrate killed while writing its problem file); the next
    write of NAME removes those of processes no longer running, and keeps a live one's."""
    import subprocess
    import sys

    from iwr._io import atomic_write_text

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    dead_pid = int(dead.stdout)
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        target = tmp_path / "r.json.iwrp"
        stale = tmp_path / f".r.json.iwrp.{dead_pid}.abc123.tmp"
        running = tmp_path / f".r.json.iwrp.{live.pid}.def456.tmp"
        other = tmp_path / ".other.iwrp.1.x.tmp"
        for p in (stale, running, other):
            p.write_text("partial")
        atomic_write_text(target, "whole")
        assert target.read_text() == "whole"
        assert not stale.exists()
        assert running.exists() and other.exists()
        assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
            [target.name, running.name, other.name])
    finally:
        live.kill()
        live.wait()


def test_effects_and_diagnosis_sections_open_cleanly(tmp_path: Path) -> None:
    """Issue 23: the report of a calibration with effects (its Effects section after the
    identifiability) and that of a geometric calibration of data with payloads (its Diagnosis
    section after the fit test, with the table to add) open cleanly."""
    from iwr.effects import api
    from iwr.reporting.calibration import render

    chromium()
    robot = iwr.Robot.default()
    with_effects = robot.with_effects(*api.realistic(robot))
    m, _ = api.simulate(with_effects, 60, seed=3, noise=iwr.Noise(legs=0.001))
    out = tmp_path / "effects"
    render(iwr.calibrate(with_effects, m, seed=1)).write(out)
    page = (out / "report.html").read_text(encoding="utf-8")
    order = [page.index(h) for h in ("<h2>Identifiability</h2>", "<h2>Effects</h2>",
                                     "<h2>Leg residuals</h2>")]
    assert order == sorted(order) and "um/N" in page and "ppm/K" in page
    assert_opens_cleanly(out / "report.html", tmp_path, 2)
    comp, _ = api.realistic(robot)
    m, _ = api.simulate(robot.with_effects(comp), 60, seed=3, noise=iwr.Noise.realistic())
    out = tmp_path / "diagnosis"
    render(iwr.calibrate(robot, m, noise=iwr.Noise.realistic(), seed=1)).write(out)
    page = (out / "report.html").read_text(encoding="utf-8")
    order = [page.index(h) for h in ("<h2>Fit test and outliers</h2>",
                                     "<h2>Diagnosis: loads and temperatures</h2>",
                                     "per_leg = true", "<h2>Identified parameters</h2>")]
    assert order == sorted(order)
    assert_opens_cleanly(out / "report.html", tmp_path, 2)


def test_the_notes_are_in_the_page_and_the_markdown_for_every_kind(kind: Any,
                                                                   tmp_path: Path) -> None:
    """A job's notes end both of its reports, whatever the kind (the tracker's Markdown report
    once left them out)."""
    import dataclasses

    from iwr.reporting.calibration import render

    n = {"ballbar": 120}.get(kind.name, 30)
    data, _ = iwr.simulate(kind.robot, n, seed=3)
    cal = iwr.calibrate(kind.robot, data, "lm", seed=1)
    cal = dataclasses.replace(cal, notes=[*cal.notes, "note: a note of this test"])
    render(cal).write(tmp_path, plots=False)
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "a note of this test" in page
    assert "\n## Notes\n" in md and "- note: a note of this test" in md
    # The page's settings and provenance tables are the Markdown's too (it had no settings,
    # and its provenance left out the Python version).
    import html
    import re

    assert "<h2>Settings</h2>" in page
    for section in ("Settings", "Provenance"):  # provenance: only from the command line
        if f"<h2>{section}</h2>" not in page:
            assert f"## {section}" not in md
            continue
        table = page.split(f"<h2>{section}</h2>", 1)[1].split("</table>", 1)[0]
        rows = re.findall(r"<tr>(.*?)</tr>", table, flags=re.S)[1:]
        assert rows, section
        for row in rows:
            cells = [html.unescape(c) for c in re.findall(r"<td>(.*?)</td>", row, flags=re.S)]
            assert "| " + " | ".join(cells) + " |" in md, (section, cells)
        assert f"\n## {section}\n" in md
