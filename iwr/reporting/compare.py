"""The report of ``iwr compare`` (:func:`iwr.compare_methods`): ``report.html`` (self-contained),
``report.md`` with its PNG figures, ``runs.csv``, ``summary.csv`` and ``results.json``."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_write_text, jsonable
from ..experiments.harness import COLUMNS
from ..robot import Robot
from .figures import method_colors, new_figure, png_bytes
from .html import Page, provenance, write_page
from .tables import Table, fmt, markdown_table, split_columns

__all__ = ["write_report", "summary_table"]

_BOUNDS = {"near": "default", "bad": "paper"}
_RUN_COLUMNS = [c for c in COLUMNS if c not in ("key", "options", "robot", "notes")]
_fmt = fmt


def summary_table(summary: list[dict[str, Any]]) -> Table:
    """The summary table: one row per (scenario, method)."""
    head = [
        "scenario", "method", "success", "at floor", "median cost (mm^2)", "cost range",
        "noise floor", "validation RMS (mm)", "tool position RMS (mm)",
        "param. error, identifiable part: lengths (mm) / angles (mrad)",
        "raw param. error: lengths (mm) / angles (mrad)", "evaluations (median / max)",
        "wall time (s)",
    ]
    rows = []
    for s in summary:
        rows.append([
            s["scenario"],
            s["method"],
            f"{s['successes']}/{s['runs']}",
            f"{s['at_floor']}/{s['runs']}",
            _fmt(s["median_cost"]),
            f"{_fmt(s['min_cost'], 2)} .. {_fmt(s['max_cost'], 2)}",
            _fmt(s["median_noise_floor"]),
            _fmt(s["median_val_rms"]),
            _fmt(s["median_tool_position_rms"]),
            f"{_fmt(s['median_param_error_length'])} / "
            f"{_fmt(1e3 * s['median_param_error_angle'])}",
            f"{_fmt(s['median_raw_error_length'])} / {_fmt(1e3 * s['median_raw_error_angle'])}",
            f"{_fmt(int(round(s['median_nfev'])))} / {s['max_nfev']}"
            + ("" if s["all_within_budget"] else " (over budget!)"),
            _fmt(s["median_wall_time"], 2),
        ])
    return head, rows


def _plot_convergence(comp: Any, scenario: str) -> bytes:
    names = comp.settings["methods"]
    colors = method_colors(names)
    runs = [r for r in comp.runs if r["scenario"] == scenario]
    fig = new_figure(8.0, 5.0)
    ax = fig.add_subplot()
    for method in names:
        for i, r in enumerate(x for x in runs if x["method"] == method):
            n = np.asarray(r["history_nfev"], dtype=float)
            b = np.asarray(r["history_best"], dtype=float)
            if not _history_is_eq10(r):
                # Its own objective (the efficient estimator's chi-square statistic): not on this
                # axis. Its eq. (10) cost at its result, one marker.
                n = np.array([float(r.get("nfev", n[-1] if n.size else math.nan))])
                b = np.array([float(r.get("cost", math.nan))])
                ok = (n > 0) & np.isfinite(b) & (b > 0)
                if ok.any():
                    ax.plot(n[ok], b[ok], "D", color=colors[method], ms=6, mfc="none",
                            label=(f"{method}: eq. (10) at its result (its objective is "
                                   "another)") if i == 0 else None)
                continue
            ok = (n > 0) & np.isfinite(b) & (b > 0)
            if not ok.any():
                continue
            ax.step(n[ok], b[ok], where="post", color=colors[method], lw=1.3, alpha=0.85,
                    label=method if i == 0 else None)
            ax.plot(n[ok][-1], b[ok][-1], "o", color=colors[method], ms=4)
    floors = [r["noise_floor"] for r in runs]
    thresholds = [r["floor_threshold"] for r in runs]
    if floors and np.median(floors) > 0:
        ax.axhline(float(np.median(floors)), color="k", ls="--", lw=1,
                   label="noise floor (cost of the truth)")
    if thresholds:
        ax.axhline(float(np.median(thresholds)), color="0.5", ls=":", lw=1,
                   label="success threshold")
    ax.axvline(comp.settings["budget"], color="0.7", lw=1)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("objective evaluations (a Jacobian counts as one)")
    ax.set_ylabel(f"best cost so far, {_kind(comp.settings)['cost_label']} (mm$^2$)")
    ax.set_title(f"Best cost against evaluations, scenario '{scenario}' "
                 f"({len(comp.settings['seeds'])} seeds, one line each)")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return png_bytes(fig)


def _history_is_eq10(run: dict[str, Any]) -> bool:
    """Whether a run's convergence history is eq. (10)'s cost (``history_objective``; for a run
    without it, whether its last value is the run's eq. (10) cost at the result). The efficient
    estimator records its chi-square statistic (about 200 where eq. (10) is 0.08)."""
    if "history_objective" in run:
        return run["history_objective"] == "eq10"
    # A run of an older iwr: the last value is eq. (10)'s at the result, or another objective.
    best = np.asarray(run.get("history_best", []), dtype=float)
    cost = float(run.get("cost", math.nan))
    if not best.size or not (np.isfinite(best[-1]) and math.isfinite(cost)):
        return True  # nothing to tell: drawn as it is (nothing finite is drawn)
    return bool(abs(best[-1] - cost) <= 1e-6 * max(abs(cost), 1e-12) + 1e-12)


def _plot_parameters(comp: Any, scenario: str, robot: Robot) -> bytes:
    names = comp.settings["methods"]
    colors = method_colors(names)
    seed = comp.settings["seeds"][0]
    runs = {r["method"]: r for r in comp.runs if r["scenario"] == scenario and r["seed"] == seed}
    lower, upper = robot.default_bounds(_BOUNDS[scenario])
    half = 0.5 * (upper - lower)
    n = robot.n_params  # the robot's parameters (a set-up's, if any, are not on this scale)
    ncol = min(len(names), 3)
    nrow = math.ceil(len(names) / ncol)
    fig = new_figure(4.0 * ncol, 3.9 * nrow)
    lim = 1.6
    for k, method in enumerate(names):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        r = runs.get(method)
        if r is None or r["status"] != "ok":
            ax.set_title(f"{method}: failed" if r is not None else method, fontsize=10)
            continue
        t = np.asarray(r["truth"])[:n] / half
        x = np.asarray(r["x"])[:n] / half
        un = np.asarray(r["unidentifiable"], dtype=bool)[:n]
        xc = np.clip(x, -lim, lim)
        out = np.abs(x) > lim
        ax.plot([-1, 1], [-1, 1], color="0.6", lw=1)
        ax.scatter(t[~un & ~out], xc[~un & ~out], s=14, color=colors[method],
                   label="identifiable one by one")
        ax.scatter(t[un & ~out], xc[un & ~out], s=22, facecolors="none", edgecolors="k",
                   linewidths=0.9, label="in an unidentifiable combination")
        if out.any():
            ax.scatter(t[out], xc[out], s=30, marker="^", color="0.3",
                       label=f"off the plot ({int(out.sum())})")
        ax.set_xlim(-1.1, 1.1)
        ax.set_ylim(-lim - 0.1, lim + 0.1)
        ax.set_title(f"{method}: cost {r['cost']:.3g}", fontsize=10)
        ax.set_xlabel("true error / bound")
        ax.set_ylabel("recovered error / bound")
        ax.grid(True, alpha=0.3)
        if k == 0:
            ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"Recovered against true parameters, scenario '{scenario}', seed {seed} "
                 f"(each of the robot's {n} parameters divided by its bound)", fontsize=11)
    fig.tight_layout()
    return png_bytes(fig)


def _plot_metrics(comp: Any) -> bytes:
    names = comp.settings["methods"]
    colors = method_colors(names)
    scenarios = list(comp.settings["scenarios"])
    fig = new_figure(4.2 * len(scenarios), 6.5)
    for j, scenario in enumerate(scenarios):
        for i, (key, label) in enumerate([("cost", "final cost (mm$^2$)"),
                                          ("val_rms", "validation RMS (mm)")]):
            ax = fig.add_subplot(2, len(scenarios), i * len(scenarios) + j + 1)
            missing = plotted = 0  # runs without the figure (a failed run's is nan), with it
            for k, method in enumerate(names):
                vals = [r[key] for r in comp.runs
                        if r["scenario"] == scenario and r["method"] == method]
                ok = [r["success"] for r in comp.runs
                      if r["scenario"] == scenario and r["method"] == method]
                for v, s in zip(vals, ok, strict=True):
                    if not np.isfinite(v):
                        missing += 1
                        continue
                    ax.plot(k, max(v, 1e-30), "o" if s else "x", color=colors[method], ms=6)
                    plotted += 1
            if key == "cost":
                fl = [r["noise_floor"] for r in comp.runs if r["scenario"] == scenario]
                if fl and np.median(fl) > 0:
                    ax.axhline(float(np.median(fl)), color="k", ls="--", lw=1)
            else:
                nv = [r["val_rms_nominal"] for r in comp.runs
                      if r["scenario"] == scenario and np.isfinite(r["val_rms_nominal"])]
                if nv:
                    ax.axhline(float(np.median(nv)), color="0.5", ls=":", lw=1)
            # Log scales; an axis without a run's value (every run failed) says so and stays
            # linear (a log axis of nothing but nan raised a ValueError: no report was written).
            if plotted:
                ax.set_yscale("log")
            else:
                ax.text(0.5, 0.5, "no run has a value", transform=ax.transAxes, ha="center",
                        va="center", fontsize=9, color="0.4")
            ax.set_xticks(range(len(names)), names)
            ax.set_xlim(-0.5, len(names) - 0.5)
            note = f" ({missing} without a value)" if missing else ""
            ax.set_title(f"{scenario}: {label}{note}", fontsize=10)
            ax.grid(True, axis="y", alpha=0.3)
    fig.suptitle("Per run: o success (the method's), x not; dashed: noise floor; dotted: the "
                 "nominal robot's validation RMS", fontsize=9)
    fig.tight_layout()
    return png_bytes(fig)


def _figures(comp: Any, robot: Robot) -> list[tuple[str, str, bytes]]:
    """(file name, caption, PNG bytes) of every figure."""
    out = []
    for scenario in comp.settings["scenarios"]:
        out.append((f"convergence_{scenario}.png",
                    f"Best cost against evaluations, scenario '{scenario}' (the paper's Fig. 5, "
                    "extended to every method), log scales", _plot_convergence(comp, scenario)))
    for scenario in comp.settings["scenarios"]:
        out.append((f"parameters_{scenario}.png",
                    f"Recovered against true parameters, scenario '{scenario}'; hollow: parameters "
                    "in an unidentifiable combination", _plot_parameters(comp, scenario, robot)))
    out.append(("metrics.png", "Final cost and validation RMS of every run",
                _plot_metrics(comp)))
    return out


def _kind(settings: dict[str, Any]) -> dict[str, Any]:
    """What the comparison's kind of data measures (``settings["kind"]``: the kind's
    :attr:`iwr.kinds.MeasurementKind.experiment_text` and its names)."""
    return dict(settings["kind"])


def _noise_text(noise: dict[str, Any]) -> str:
    """The settings' noise model in words: ``legs 0.002, joint_lengths 0.005, ...`` and, for an
    instrument's pair, ``readings: ...; tracker: distance 0.005, ...`` (the top ``legs`` is the
    readings' own, not said twice)."""
    def fields(d: dict[str, Any]) -> str:
        return ", ".join(f"{k} {float(v):g}" for k, v in d.items())

    if "readings" in noise:
        return "; ".join(f"{k}: {fields(v)}" for k, v in noise.items() if isinstance(v, dict))
    return fields(noise)


def _definitions(settings: dict[str, Any]) -> list[str]:
    n = settings["n_poses"]
    kind = _kind(settings)
    tested = settings["noise"]["legs"] > 0 and kind["chi2_fit_test"]
    return [
        f"Robot {settings['robot']} ({settings['n_params']} error parameters), {n} measurement "
        f"poses per identification, noise {_noise_text(settings['noise'])} (mm, rad), seeds "
        f"{settings['seeds']}, evaluation budget {settings['budget']} per run (a Jacobian counts "
        "as one evaluation). Seed k is iwr study's cell of error draw k and seed 0 (the "
        "harness's streams, docs/compare.md): runs.csv's seed column is that draw.",
        f"Data: {kind['description']} measured in {kind['frame']} ({kind['name']} data).",
        *(f"Scenario '{k}': {v}." for k, v in settings["scenarios"].items()),
        f"Cost: {kind['cost']}, re-evaluated at the returned point. Noise floor: the cost of the "
        "true parameters on the same noisy data.",
        "Success: the method's own verdict (result.success): it converged, its result is "
        "finite and its fit is sane (iwr.estimation.fit_check: no identified error beyond 10 "
        "times the searched bounds modulo the unidentifiable directions"
        + (" and, as every run here is given the scenario's noise model, the chi-square test of "
           "the fit)." if tested else
           "; the data have no leg noise, so no noise model and no chi-square test)."
           if settings["noise"]["legs"] <= 0 else
           "; no chi-square test of this objective on these data: the efficient estimator's "
           "own fit test only)."),
        f"At floor: cost <= (1 + {settings['success_rtol']}) x noise floor + n x "
        f"({settings['success_atol']} mm)^2 (n the readings), i.e. within "
        f"{100 * settings['success_rtol']:.0f}% of the noise floor or "
        f"{1e3 * settings['success_atol']:.3g} um RMS of the readings, whatever the method says.",
        f"Validation RMS: {kind['readings']}, at {settings['n_validation']} fresh poses of the "
        "actual robot; the nominal robot's is given for scale.",
        f"Tool position RMS: {kind['tool']}; position of the platform frame's origin (mm).",
        *([kind["gauge"]] if kind.get("gauge") else []),
        *_de_text(settings),
        _parameter_error_text(kind.get("parameters")),
        "Medians over seeds; a run without a figure (failed, or no forward kinematics at its "
        "result) counts as the worst, inf, in the medians of the costs and errors. Wall times "
        "depend on the machine and its load; everything else is the same for the same seeds.",
    ]


def _de_text(settings: dict[str, Any]) -> list[str]:
    """One line on the DE runs' settings, when there are any."""
    de = settings.get("de_settings") or {}
    if not de:
        return []
    parts = []
    for spec, st in de.items():
        np_text = f"NP {st['population_size']}"
        if st.get("min_population_size"):
            np_text += f" reduced linearly to {st['min_population_size']} over the budget"
        parts.append(f"{spec}: {st['strategy']}, {np_text}, F {st['F']:g}, CR {st['CR']:g}"
                     + (" (initial values, adapted)" if st["strategy"] not in
                        ("rand1bin", "best1bin") else ""))
    return ["Differential evolution, without polish (DE never exceeds the budget: its last "
            "generation may evaluate only part of the population): " + "; ".join(parts) + "."]


def _parameter_error_text(what: str | None = None) -> str:
    what = what or ("x minus the parameter vector nearest to x that predicts exactly the "
                    "truth's readings at the validation poses (the yardstick of what is "
                    "identifiable), projected onto the identifiable directions")
    return (
        f"Parameter error, identifiable part: {what}; the part of the error that "
        "readings can see. RMS over lengths (mm) and over angles (mrad in the tables). Raw: "
        "x - truth as it is. Unidentifiable combinations cost nothing, so a method may land "
        "anywhere along them: raw errors there say nothing about the method."
    )


def write_report(comp: Any, out: str | Path, robot: Robot) -> dict[str, Path]:
    """Write ``report.html``, ``report.md``, the PNG figures, ``runs.csv``, ``summary.csv`` and
    ``results.json`` into ``out`` (created if needed), each atomically."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files: dict[str, Path] = {}
    figures = _figures(comp, robot)
    for name, _, png in figures:
        from .._io import atomic_write_bytes

        atomic_write_bytes(out / name, png)
        files[name] = out / name

    # CSV: one row per run (the harness's columns), one per (scenario, method).
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(_RUN_COLUMNS)
    for r in comp.runs:
        w.writerow([_csv_value(r.get(c)) for c in _RUN_COLUMNS])
    atomic_write_text(out / "runs.csv", buf.getvalue())
    files["runs.csv"] = out / "runs.csv"
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    cols = list(comp.summary[0]) if comp.summary else []
    w.writerow(cols)
    for s in comp.summary:
        w.writerow([_csv_value(s[c]) for c in cols])
    atomic_write_text(out / "summary.csv", buf.getvalue())
    files["summary.csv"] = out / "summary.csv"

    prov = provenance(comp.settings.get("inputs"))
    data = {
        "format": "iwr-compare",
        "version": 2,
        "settings": comp.settings,
        "provenance": prov,
        "parameter_names": _kind(comp.settings)["parameter_names"],
        "summary": comp.summary,
        "runs": comp.runs,
    }
    atomic_write_text(out / "results.json",
                      json.dumps(jsonable(data, finite_only=True), indent=1) + "\n")
    files["results.json"] = out / "results.json"

    table = summary_table(comp.summary)
    defs = _definitions(comp.settings)
    title = "iwr compare: identification methods on one objective, one budget"
    # Markdown, with the PNGs beside it.
    md = [f"# {title}", ""]
    md += ["## Summary", "", markdown_table(table)]
    md += [f"- {d}" for d in defs]
    md += ["", "## Figures", ""]
    md += ["| figure | file |", "|---|---|"]
    md += [f"| {cap} | [{name}]({name}) |" for name, cap, _ in figures]
    md += [""]
    for name, cap, _ in figures:
        md += [f"![{cap}]({name})", ""]
    md += ["Raw numbers: `runs.csv` (one row per run), `summary.csv`, `results.json` (everything, "
           "with the recovered parameters and the convergence histories).", ""]
    kernel = f", kernel {prov['kernel']}" if prov.get("kernel") else ""
    md += ["## Provenance", "", f"iwr {prov['iwr_version']}{kernel}, {prov['date']}: "
           f"`{' '.join(prov['command'])}`", ""]
    atomic_write_text(out / "report.md", "\n".join(md))
    files["report.md"] = out / "report.md"

    # HTML, self-contained: the PNGs embedded as base64; summary first.
    runs_table = ([c for c in _RUN_COLUMNS if c != "message"],
                  [[_fmt(r.get(c)) for c in _RUN_COLUMNS if c != "message"] for r in comp.runs])
    page = Page(title)
    page.heading("Summary")
    page.verdict(_verdict(comp), "good" if _best_at_floor(comp) else "fair")
    page.table(table)
    page.heading("Settings and definitions").items(defs)
    page.heading("Figures")
    page.table((["figure", "file"], [[cap, name] for name, cap, _ in figures]))
    for name, cap, png in figures:
        page.figure(png, cap, name)
    page.heading("Every run")
    # Too many columns for a page: in parts, each led by the columns that name the run.
    names = runs_table[0]
    keys = [names.index(c) for c in ("scenario", "method", "seed") if c in names]
    for part in split_columns(runs_table, keys):
        page.table(part)
    page.paragraph("Raw numbers: runs.csv, summary.csv, results.json beside this page.", "muted")
    page.provenance(prov)
    files["report.html"] = write_page(page, out / "report.html")
    return files


def _at_floor(comp: Any) -> dict[str, list[str]]:
    """Per scenario, the methods that reached the noise floor on every run."""
    return {sc: [s["method"] for s in comp.summary
                 if s["scenario"] == sc and s["at_floor"] == s["runs"]]
            for sc in comp.settings["scenarios"]}


def _best_at_floor(comp: Any) -> bool:
    return all(_at_floor(comp).values())


def _verdict(comp: Any) -> str:
    n = len(comp.settings["seeds"])
    parts = [f"{sc}: {', '.join(ms) if ms else 'none'}" for sc, ms in _at_floor(comp).items()]
    return (f"At the noise floor on every run ({n} seed(s)) within {comp.settings['budget']} "
            f"evaluations, by scenario: {'; '.join(parts)}.")


def _csv_value(v: Any) -> Any:
    if isinstance(v, float):
        return repr(v)
    return "" if v is None else v
