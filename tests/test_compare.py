"""``iwr.compare_methods`` and ``iwr compare``: the report builds and holds every figure and table,
the numbers are consistent and reproducible, bad arguments are refused by name."""

from __future__ import annotations

import argparse
import base64
import csv
import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest

import iwr
from iwr.cli import main as cli_main
from iwr.cli.compare import add_compare_parser, run_compare
from iwr.experiments import compare as cmp
from iwr.experiments.harness import Scenario, unidentifiable_mask
from iwr.methods import METHODS
from iwr.reporting.figures import method_colors

SEEDS = [0, 1]
FIGURES = ["convergence_near.png", "convergence_bad.png", "parameters_near.png",
           "parameters_bad.png", "metrics.png"]


BUDGET = 310  # not a whole number of DE generations: DE's last one is partial


def small_methods() -> list[str]:
    return [m for m in ("lm", "crs2", "bobyqa", "de", "de:jso") if m.partition(":")[0] in METHODS]


def small_run(out, **kw):
    # DE evaluates its initial population whole (10 D = 580 by default, 773 for jSO): small
    # populations keep it within the budget. jSO plans its schedule over the budget.
    options = ({"de": {"population_size": 20}, "de:jso": {"population_size": 30}}
               if "de" in METHODS else {})
    args = dict(n_poses=20, seeds=SEEDS, methods=small_methods(), budget=BUDGET, start="both",
                out=out, n_validation=20, progress=False, method_options=options)
    args.update(kw)
    return iwr.compare_methods(**args)


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    return small_run(out), out


def test_every_file_is_written(report):
    comp, out = report
    for name in ["report.html", "report.md", "runs.csv", "summary.csv", "results.json", *FIGURES]:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
        assert comp.files[name] == out / name
    for name in FIGURES:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_html_is_self_contained_with_every_figure_and_table(report):
    comp, out = report
    page = (out / "report.html").read_text(encoding="utf-8")
    for name in FIGURES:
        b64 = base64.b64encode((out / name).read_bytes()).decode("ascii")
        assert f"data:image/png;base64,{b64}" in page, name
    # no external resources
    assert not re.search(r'src="(?!data:)', page)
    assert "<link" not in page
    # the summary table: one row per (scenario, method), and the table of every run
    n_methods = len(small_methods())
    # (summary, figures, every run: the last in parts led by scenario, method, seed, each a
    # table that fits the page, every column in one of them)
    every_run = page[page.index("<h2>Every run</h2>"):]
    parts = every_run.count("<table>")
    assert page.count("<table>") == 2 + parts
    heads = re.findall(r"<tr>((?:<th>[^<]*</th>)+)</tr>", every_run)
    cols = [c for h in heads[:parts] for c in re.findall(r"<th>([^<]*)</th>", h)]
    assert all(re.findall(r"<th>([^<]*)</th>", h)[:3] == ["scenario", "method", "seed"]
               for h in heads[:parts])
    assert {"cost", "nfev", "success", "wall_time"} <= set(cols)
    for scenario in ("near", "bad"):
        for method in small_methods():
            assert f"<td>{scenario}</td><td>{method}</td>" in page
    assert len(comp.summary) == 2 * n_methods


def test_markdown_has_the_table_and_links_to_every_figure(report):
    comp, out = report
    md = (out / "report.md").read_text(encoding="utf-8")
    assert comp.summary_markdown() in md
    links = set(re.findall(r"\]\(([^)]+\.png)\)", md))
    assert links == set(FIGURES)
    for name in links:
        assert (out / name).is_file()


def test_csv_and_json_hold_every_run(report):
    comp, out = report
    n = 2 * len(SEEDS) * len(small_methods())
    with open(out / "runs.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == n == len(comp.runs)
    assert {"cost", "val_rms", "param_error_length", "raw_error_length", "nfev",
            "wall_time", "at_floor", "success"} <= set(rows[0])
    for row, run in zip(rows, comp.runs, strict=True):
        assert float(row["cost"]) == run["cost"]
        assert int(row["nfev"]) == run["nfev"]
    with open(out / "summary.csv", newline="") as fh:
        assert len(list(csv.DictReader(fh))) == len(comp.summary)
    data = json.loads((out / "results.json").read_text(encoding="utf-8"))
    assert data["format"] == "iwr-compare" and len(data["runs"]) == n
    assert data["settings"]["budget"] == BUDGET
    assert len(data["parameter_names"]) == 58


def test_numbers_are_consistent(report):
    comp, _ = report
    robot = iwr.Robot.default()
    ang = robot.angle_parameters
    for r in comp.runs:
        x, truth = np.array(r["x"]), np.array(r["truth"])
        assert r["nfev"] <= BUDGET and r["within_budget"]
        assert r["at_floor"] == (r["cost"] <= r["floor_threshold"])
        assert r["raw_error_length"] == pytest.approx(
            math.sqrt(np.mean((x - truth)[~ang] ** 2)), rel=1e-12)
        assert r["raw_error_angle"] == pytest.approx(
            math.sqrt(np.mean((x - truth)[ang] ** 2)), rel=1e-12)
        assert r["rms_fit"] == pytest.approx(math.sqrt(r["cost"] / (6 * 20)), rel=1e-12)
        assert np.array(r["history_best"])[-1] >= r["cost"] * (1 - 1e-9) or r["method"] == "lm"
        assert 0 < sum(r["unidentifiable"]) < 58
    # The summary counts the method's own success and, beside it, the runs at the floor.
    for s in comp.summary:
        rs = [r for r in comp.runs if (r["scenario"], r["method"]) == (s["scenario"], s["method"])]
        assert s["runs"] == len(rs) > 0
        assert s["successes"] == sum(r["success"] for r in rs)
        assert s["at_floor"] == sum(r["at_floor"] for r in rs)
    # The bad start is near the bounds, on the side opposite to the truth.
    for r in comp.runs:
        if r["scenario"] == "bad":
            x0, truth = np.array(r["x0"]), np.array(r["truth"])
            assert np.all(np.abs(x0) == pytest.approx(0.45)) and np.all(x0 * truth <= 0)
    # Levenberg-Marquardt reaches the noise floor from the near start, and calibrates the robot.
    for r in comp.runs:
        if r["method"] == "lm" and r["scenario"] == "near":
            assert r["at_floor"]
            assert r["val_rms"] < 0.1 * r["val_rms_nominal"]




def test_de_variants_run_under_their_labels(report):
    """'de:jso' is identify(method="de", strategy="jso") with the budget as max_evaluations (jSO's
    schedule runs to it), labelled 'de:jso' everywhere; 'de' is the paper's rand1bin."""
    comp, out = report
    assert comp.settings["methods"] == small_methods()
    opts = comp.settings["method_options"]
    assert opts["de:jso"] == {"max_evaluations": BUDGET, "polish": False, "strategy": "jso",
                              "population_size": 30}
    assert "strategy" not in opts["de"]
    de = comp.settings["de_settings"]
    assert de["de"]["strategy"] == "rand1bin" and de["de"]["population_size"] == 20
    assert de["de:jso"]["strategy"] == "jso" and de["de:jso"]["min_population_size"] == 4
    # The label in every table and file
    labels = {r["method"] for r in comp.runs}
    assert {"de", "de:jso"} <= labels
    with open(out / "runs.csv", newline="") as fh:
        assert {row["method"] for row in csv.DictReader(fh)} == labels
    with open(out / "summary.csv", newline="") as fh:
        assert {row["method"] for row in csv.DictReader(fh)} == labels
    data = json.loads((out / "results.json").read_text(encoding="utf-8"))
    assert data["settings"]["methods"] == small_methods()
    assert "| near | de:jso |" in (out / "report.md").read_text(encoding="utf-8")
    page = (out / "report.html").read_text(encoding="utf-8")
    assert "<td>bad</td><td>de:jso</td>" in page and "de:jso: jso, NP 30 reduced" in page
    colors = method_colors(small_methods())
    assert len(set(colors.values())) == len(colors)
    # The same numbers as identify called directly
    robot = iwr.Robot.default()
    (r,) = [r for r in comp.runs if r["method"] == "de:jso" and r["scenario"] == "bad"
            and r["seed"] == SEEDS[1]]
    sc = Scenario(20, iwr.Noise.realistic(), draw=SEEDS[1], validation_poses=20,
                  kind="bad").build(robot)
    res = iwr.identify(robot, sc.data, "de", strategy="jso", population_size=30,
                       max_evaluations=BUDGET, bounds="paper", x0=sc.x0, seed=sc.method_seed,
                       polish=False, progress=False)
    assert res.fun == r["cost"] and res.x.tolist() == r["x"]
    assert res.settings["max_evaluations"] == BUDGET and res.settings["polish"] is False


def test_de_respects_the_budget(report):
    """Every DE run spends exactly the budget (no target is set) and never more, although the
    budget is not a whole number of generations; the report has no over-budget mark."""
    comp, out = report
    for r in comp.runs:
        if r["method"].partition(":")[0] == "de":
            assert r["nfev"] == BUDGET and r["within_budget"], (r["method"], r["nfev"])
            assert r["history_nfev"][-1] == BUDGET
    assert all(s["all_within_budget"] for s in comp.summary)
    assert "over budget" not in (out / "report.md").read_text(encoding="utf-8")


def test_default_methods():
    names = cmp.default_methods()
    expected = [m for m in cmp.DEFAULT_METHODS if m.partition(":")[0] in METHODS]
    assert names[: len(expected)] == expected and set(METHODS) <= set(names)
    # Noise-free data: nothing to weigh the efficient estimator by.
    assert cmp.default_methods(iwr.Noise()) == [m for m in names if m != "efficient"]
    assert cmp.default_methods(iwr.Noise.realistic()) == names
    if "de" in METHODS:
        assert cmp.split_method("de:lshade") == ("de", {"strategy": "lshade"})
        assert cmp.split_method("de") == ("de", {})


def test_same_seeds_same_numbers(report, tmp_path):
    """The same seeds give the same numbers bit for bit, wall times apart: Levenberg-Marquardt
    included (its Jacobian gets a guard column against SciPy's MINPACK reading past its buffer,
    see iwr.methods.lm._guard_column, which made it differ from run to run)."""
    comp, out = report
    again = small_run(tmp_path)
    for a, b in zip(comp.runs, again.runs, strict=True):
        assert a.keys() == b.keys()
        for key in a:
            if key == "wall_time":
                continue
            assert a[key] == b[key] or (a[key] != a[key] and b[key] != b[key]), (a["method"], key)
    for name in FIGURES:
        assert (tmp_path / name).stat().st_size > 0, name


def test_a_comparison_run_is_a_study_cell(tmp_path):
    """Compare and study are two uses of one harness: seed k of a comparison is the study's
    error draw k, and the same settings give the same row, bit for bit."""
    comp = iwr.compare_methods(n_poses=15, seeds=[3], methods=["lm"], budget=200, start="near",
                               out=None, n_validation=10, progress=False)
    (r,) = comp.runs
    res = iwr.study(methods="lm", poses=[15], noise=0.02, draws=[3], seeds=[0],
                    budgets={"lm": [200]}, out=tmp_path, scheduler="synchronous", report=False,
                    validation_poses=10)
    (cell,) = res.rows
    for c in ("cost", "nfev", "val_rms", "val_max", "val_rms_nominal", "param_error_length",
              "param_error_angle", "tool_position_rms", "noise_floor", "at_floor", "success"):
        assert r[c] == cell[c], c
    assert r["key"] == cell["key"]
    assert comp.files == {}


def test_unidentifiable_mask_matches_finite_differences():
    """Against a null direction found by finite differences (not the analytic Jacobian). The
    step: at 1e-6 the differences' rounding (1e-8 of the largest singular value) lifted four of
    the six null directions over the rank threshold, and which parameters the other two touched
    turned on the kernel variant's last bits; at 1e-5 the gap is 8e-4 against 6e-9."""
    robot = iwr.Robot.default()
    m, truth = iwr.simulate(robot, n_poses=25, seed=4)
    problem = iwr.Problem(robot, m)
    h = 1e-5
    jac = np.column_stack([
        (problem.residuals(truth + h * e) - problem.residuals(truth - h * e)) / (2 * h)
        for e in np.eye(58)
    ])
    d = np.linalg.norm(jac, axis=0)
    _, s, vt = np.linalg.svd(jac / d)
    assert s[-1] < 1e-8 * s[0]
    rank = int(np.sum(s > 1e-8 * s[0]))
    assert s[rank] < 1e-4 * s[rank - 1]  # a clear gap
    fd = np.linalg.norm(vt[rank:].T, axis=1) > 1e-4
    mask = unidentifiable_mask(robot, m, truth)
    assert 0 < mask.sum() < 58
    np.testing.assert_array_equal(mask, fd)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"n_poses": 0}, "n_poses"),
        ({"n_poses": 8}, "n_poses: 8 poses are too few: the 52 identifiable parameters .* at "
                         "least 9 poses"),
        ({"budget": 1}, "budget"),
        ({"budget": 10.5}, "budget"),
        ({"seeds": []}, "seeds"),
        ({"seeds": [-1]}, "seeds"),
        ({"seeds": [1, 1]}, "seeds"),
        ({"methods": ["nope"]}, "methods"),
        ({"methods": []}, "methods"),
        ({"start": "worst"}, "start"),
        ({"noise": "loud"}, "noise"),
        ({"n_validation": 0}, "n_validation"),
        ({"success_rtol": -1}, "success_rtol"),
        ({"method_options": {"nope": {}}}, "method_options"),
        ({"methods": ["lm", "efficient"], "noise": "none"}, "methods: 'efficient' weighs"),
        ({"robot": "IWR"}, "robot"),
        ({"robot": iwr.Robot.default().with_tracker(registration=(0, 0, 0, 0, 0, 0),
                                                    reflectors=[(0, 0, 40)])},
         # a tracker robot is compared on its points: one reflector, 3 readings a pose
         r"n_poses: 10 poses are too few.*\(3 independent readings each, reflector points\)"),
    ],
)
def test_bad_arguments_name_the_argument(kwargs, name):
    args = dict(n_poses=10, seeds=[0], methods=["lm"], budget=50, out=None, progress=False)
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        iwr.compare_methods(**args)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"methods": ["de:nope"]}, "'de:nope': unknown DE strategy 'nope'"),
        ({"methods": ["lm:jso"]}, "'lm:jso'"),
        ({"methods": ["de", "de"]}, "duplicates"),
        ({"methods": ["de:jso"], "method_options": {"de:jso": {"strategy": "shade"}}},
         "'de:shade'"),
        ({"methods": ["de"], "method_options": {"de": {"strategy": "jso"}}}, "'de:jso'"),
        ({"methods": ["de"], "method_options": {"de:jso": {}}}, "method_options: 'de:jso'"),
        ({"methods": ["de:jso"], "method_options": {"de:jso": {"nope": 1}}}, "'de:jso'.*nope"),
        # the initial population alone would exceed the budget
        ({"methods": ["de:jso"], "budget": 500}, "'de:jso'.*773"),
        ({"methods": ["de"], "budget": 500}, "'de'.*580"),
        # an option's value, by the method's own checks, for every method
        ({"methods": ["lm"], "method_options": {"lm": {"max_evaluations": -5}}},
         "method_options: method 'lm': max_evaluations: -5"),
        ({"methods": ["crs2"], "method_options": {"crs2": {"max_evaluations": "abc"}}},
         "method_options: method 'crs2': max_evaluations: 'abc'"),
    ],
)
def test_bad_de_specs_are_refused(kwargs, match):
    args = dict(n_poses=10, seeds=[0], budget=5000, out=None, progress=False)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        iwr.compare_methods(**args)


def test_out_that_is_a_file_is_refused(tmp_path):
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(ValueError, match="out"):
        iwr.compare_methods(n_poses=10, seeds=[0], methods=["lm"], out=f, progress=False)


def test_command_line(tmp_path, capsys):
    out = tmp_path / "cli"
    code = cli_main(["compare", "--poses", "12", "--seeds", "0", "--methods", "lm,crs2",
                     "--budget", "100", "--start", "near", "--validation-poses", "10",
                     "-o", str(out), "--no-progress"])
    text = capsys.readouterr().out
    assert code == 0
    assert "| near | lm |" in text and "| near | crs2 |" in text
    assert (out / "report.html").is_file() and (out / "convergence_near.png").is_file()
    assert not (out / "convergence_bad.png").exists()


@pytest.mark.parametrize(
    "argv, name",
    [
        (["--budget", "0"], "--budget: 0; expected an integer >= 2"),
        (["--seeds", "a,b"], "--seeds: 'a,b'"),
        (["--seeds", "1,1"], "--seeds: [1, 1] has duplicates"),
        (["--methods", "nope"], "--methods: 'nope' is not registered"),
        (["--methods", "lm,de:nope"], "--methods: 'de:nope'"),
        (["--poses", "3"], "--poses: 3 poses are too few"),
        (["--validation-poses", "0"], "--validation-poses: 0"),
    ],
)
def test_a_bad_option_value_is_a_usage_error_naming_the_option(argv, name, capsys):
    """As in every command: exit 2, the option named as the command line spells it (the
    library's ArgumentError names its argument: n_poses, n_validation, ...)."""
    assert cli_main(["compare", *argv, "--no-progress", "-o",
                     "/nonexistent-dir-never-written"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"iwr: error: {name}"), err
    assert "(see 'iwr compare --help')" in err
    assert "Traceback" not in err and err.count("\n") == 1


def test_a_missing_robot_file_is_an_input_error(capsys):
    assert cli_main(["compare", "--robot", "/nonexistent/robot.toml", "--no-progress", "-o",
                     "/nonexistent-dir-never-written"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("iwr compare: error:") and "robot.toml" in err
    assert "Traceback" not in err and err.count("\n") == 1


def test_a_bad_noise_is_a_usage_error_as_in_every_command(capsys):
    """--noise is parsed as iwr simulate and iwr calibrate parse it (iwr.cli._base.noise_spec):
    a bad spec is a usage error, exit 2, naming the option and the value."""
    for command in ("compare", "simulate"):
        assert cli_main([command, "--noise", "legs=x", "-o",
                         "/nonexistent-dir-never-written"]) == 2
        err = capsys.readouterr().err
        assert err == (f"iwr: error: argument --noise: legs='x' is not a number (see 'iwr "
                       f"{command} --help')\n")


def test_subcommand_wiring():
    parser = argparse.ArgumentParser(prog="iwr")
    sub = parser.add_subparsers(dest="command")
    add_compare_parser(sub)
    args = parser.parse_args(["compare", "--budget", "5", "--start", "bad"])
    assert args.func is run_compare and args.budget == 5 and args.start == "bad"


def test_python_dash_m_help(tmp_path):
    # cwd: not the repository root, whose source folder has no compiled module
    proc = subprocess.run([sys.executable, "-m", "iwr", "compare", "--help"], capture_output=True,
                          text=True, timeout=60, cwd=tmp_path)
    assert proc.returncode == 0 and "--budget" in proc.stdout
    assert "Warning" not in proc.stderr


def test_parameter_error_is_iwr_parameter_error(report):
    comp, out = report
    robot = iwr.Robot.default()
    r = comp.runs[0]
    # the scenario is rebuilt from the same seed streams the comparison used
    sc = Scenario(20, iwr.Noise.realistic(), draw=r["seed"], validation_poses=20,
                  kind=r["scenario"]).build(robot)
    np.testing.assert_array_equal(sc.truth, r["truth"])
    pe = iwr.parameter_error(robot, sc.validation, np.array(r["x"]), sc.truth)
    # The same computation on the same inputs, but BLAS may sum in another order with more threads.
    assert r["param_error_length"] == pytest.approx(pe.rms_length, rel=1e-9)
    assert r["param_error_angle"] == pytest.approx(pe.rms_angle, rel=1e-9)
    assert "iwr.parameter_error" in (out / "report.md").read_text(encoding="utf-8")


def test_dask_executor_gives_the_same_rows():
    """The harness's executors: the same comparison in this process and on a local Dask cluster
    gives the same rows, bit for bit (wall times apart)."""
    distributed = pytest.importorskip("distributed")
    args = dict(n_poses=12, seeds=[0, 1], methods=["lm", "crs2"], budget=150, start="both",
                out=None, n_validation=10, progress=False)
    here = iwr.compare_methods(**args)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=":0") as cluster, \
            distributed.Client(cluster) as client:
        there = iwr.compare_methods(**args, scheduler=client)
    assert len(here.runs) == len(there.runs) == 8
    for a, b in zip(here.runs, there.runs, strict=True):
        assert a.keys() == b.keys()
        for key in a:
            if key == "wall_time":
                continue
            same = a[key] == b[key] or (a[key] != a[key] and b[key] != b[key])
            if key.startswith("param_error"):  # an SVD: its last bit may change with the process
                same = same or math.isclose(a[key], b[key], rel_tol=1e-12)
            assert same, (a["method"], key, a[key], b[key])


def test_command_line_takes_the_robot_files_noise_model(tmp_path, capsys):
    # As iwr simulate: without --noise, the --robot file's [noise] table; --noise overrides it.
    noise = iwr.Noise(legs=0.004, joint_lengths=0.006, joint_angles=7e-6, position=0.03,
                      orientation=3e-5)
    iwr.Robot.default().with_noise(noise).to_toml(tmp_path / "bench.toml")
    argv = ["compare", "--robot", str(tmp_path / "bench.toml"), "--poses", "12", "--seeds", "0",
            "--methods", "lm", "--budget", "100", "--start", "near", "--validation-poses", "10",
            "--no-progress"]
    assert cli_main([*argv, "-o", str(tmp_path / "a")]) == 0
    text = capsys.readouterr().out
    assert "noise model: legs 0.004, joint_lengths 0.006" in text
    assert f"(from {tmp_path / 'bench.toml'} [noise])" in text
    settings = json.loads((tmp_path / "a" / "results.json").read_text())["settings"]
    assert settings["noise"]["legs"] == 0.004 and settings["noise"]["position"] == 0.03
    assert cli_main([*argv, "--noise", "none", "-o", str(tmp_path / "b")]) == 0
    # The model used is printed, whatever gives it.
    assert "noise model: legs 0, joint_lengths 0, joint_angles 0, position 0, orientation 0 " \
        "(from --noise)" in capsys.readouterr().out
    settings = json.loads((tmp_path / "b" / "results.json").read_text())["settings"]
    assert settings["noise"]["legs"] == 0.0


def test_metrics_figure_of_a_scenario_where_every_run_failed(monkeypatch) -> None:
    # A comparison whose every run of a scenario failed (LM alone from the 'bad' start on a
    # tracker robot, seed 0: no validation figures, nan) raised matplotlib's "Data cannot be
    # log-scaled" from the metrics figure, and no report was written. The axis now says so.
    from types import SimpleNamespace

    from iwr.reporting import compare as report_compare
    from iwr.reporting.compare import _plot_metrics

    runs = [
        {"scenario": "near", "method": "lm", "success": True, "cost": 0.236, "val_rms": 0.0048,
         "val_rms_nominal": 3.85, "noise_floor": 0.25},
        {"scenario": "bad", "method": "lm", "success": False, "cost": 7.8e8,
         "val_rms": math.nan, "val_rms_nominal": math.nan, "noise_floor": 0.25},
    ]
    comp = SimpleNamespace(settings={"methods": ["lm"], "scenarios": ["near", "bad"]}, runs=runs)
    figures = []
    real = report_compare.png_bytes
    monkeypatch.setattr(report_compare, "png_bytes", lambda fig: figures.append(fig) or real(fig))
    png = _plot_metrics(comp)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    axes = {ax.get_title(): ax for ax in figures[0].axes}
    bad = axes["bad: validation RMS (mm) (1 without a value)"]
    assert bad.get_yscale() == "linear"
    assert [t.get_text() for t in bad.texts] == ["no run has a value"]
    # The failed run's cost is a value: plotted (an x), on a log axis.
    assert axes["bad: final cost (mm$^2$)"].get_yscale() == "log"
    near = axes["near: validation RMS (mm)"]
    assert near.get_yscale() == "log" and not near.texts


def test_a_row_s_medians_are_over_the_same_runs():
    """A run whose model has no forward kinematics at its result has no tool position (nan):
    its median was taken over the other runs alone, so one row showed one good run's 0.0245 mm
    beside a validation RMS of 47 mm over both (an outside check). A run without a figure now
    counts as the worst (inf) in every median of a cost or an error; wall time and evaluations
    stay medians of the runs that have them."""
    from iwr.experiments.compare import _summarise
    from iwr.reporting.study import _stats

    def run(cost, val, tool, wall):
        r = {"scenario": "bad", "method": "lm", "cost": cost, "success": False,
             "at_floor": False, "noise_floor": 0.06, "val_rms": val, "val_rms_nominal": 90.0,
             "param_error_length": 1.0, "param_error_angle": 1e-3, "raw_error_length": 2.0,
             "raw_error_angle": 2e-3, "tool_position_rms": tool,
             "tool_position_rms_nominal": 80.0, "nfev": 10, "within_budget": True,
             "status": "ok", "wall_time": wall}
        return r

    runs = [run(0.03, 0.05, 0.0245, 1.0), run(1.4e5, 94.7, math.nan, math.nan),
            run(7e4, 47.4, 30.0, 3.0)]
    row = _summarise(runs, ["bad"], ["lm"])[0]
    assert row["median_tool_position_rms"] == 30.0  # of (0.0245, 30, inf), not (0.0245, 30)
    assert row["median_val_rms"] == 47.4 and row["median_cost"] == 7e4
    assert row["median_wall_time"] == 2.0  # of the runs that have one
    two = _summarise(runs[:2], ["bad"], ["lm"])[0]
    assert two["median_tool_position_rms"] == math.inf
    # The nominal model's figures are no run's: a start without them is no worse run.
    runs[1]["tool_position_rms_nominal"] = math.nan
    assert _summarise(runs, ["bad"], ["lm"])[0]["median_tool_position_rms_nominal"] == 80.0
    # No stand-in for inf: a huge finite value stays itself.
    from iwr.experiments.harness import percentiles_worst

    np.testing.assert_array_equal(percentiles_worst([1e308, math.nan], [0, 50, 100]),
                                  [1e308, math.inf, math.inf])
    np.testing.assert_array_equal(percentiles_worst([1.0, 2.0, math.nan], [0, 25, 50, 75]),
                                  [1.0, 1.5, 2.0, math.inf])
    # The study's cells alike: median and quartiles over every run.
    assert _stats([0.0245, math.nan, 30.0]) == (30.0, pytest.approx(15.01225), math.inf, 3)
    assert _stats([math.nan, math.nan]) == (math.inf, math.inf, math.inf, 2)
