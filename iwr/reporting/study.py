"""Figures and a Markdown summary of a study's table (:func:`iwr.study`).

Every figure shows the median over error draws x seeds and the interquartile band. The summary
checks the paper's closing claim (section 4: "if we increase the maximum generation number and add
more measured poses, then the identification accuracy will be improved") on the study's grid, with
an explicit rule for "levels off" (:data:`LEVEL_OFF`).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import textwrap
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_write_text
from ..experiments.harness import percentiles_worst
from .figures import PALETTE, new_figure, save_png
from .html import Page, provenance, write_page

__all__ = ["report", "LEVEL_OFF", "FLOOR"]

# A quantity "levels off" where doubling the number of poses (or the budget) improves its median
# by less than this fraction. For reference, an error that falls as 1/sqrt(N), as a least-squares
# estimate from noisy data does, improves by 1 - 1/sqrt(2) = 29 % per doubling.
LEVEL_OFF = 0.10
# Below this validation error (mm), a nanometre, a calibration is exact for any practical purpose
# (noise-free data: LM stops at about 1e-9 mm, where its Tikhonov term, not the data, decides).
FLOOR = 1e-6

_FIGURES = {
    "val_rms": "validation {readings_short} RMS error (mm)",
    "tool_position_rms": "tool position RMS error{tool_short} (mm)",
    "tool_orientation_rms": "tool orientation RMS error{tool_short} (degrees)",
    "param_error_length": "parameter error, identifiable part: RMS of lengths (mm)",
    "param_error_angle": "parameter error, identifiable part: RMS of angles (rad)",
}


def _kind_text(meta: dict[str, Any]) -> dict[str, str]:
    """What the study's kind of data measures (study.json's ``kind``: the kind's
    :attr:`iwr.kinds.MeasurementKind.experiment_text`); the pose kind's for a study written
    before kinds were recorded (only poses in {0} could be studied then). The kind's words of
    today fill what an older study.json lacks (its noise level's words)."""
    from .. import kinds

    recorded = meta.get("kind", {})
    try:
        current = kinds.named(str(recorded.get("name", "pose"))).experiment_text
    except ValueError:  # a kind not registered here
        current = kinds.named("pose").experiment_text
    return {**current, **recorded}


def _labels(meta: dict[str, Any]) -> dict[str, str]:
    """The figures' labels for the study's kind of data."""
    text = _kind_text(meta)
    return {k: v.format(**text) for k, v in _FIGURES.items()}


def _stats(values: Sequence[float], worst: bool = True) -> tuple[float, float, float, int]:
    """Median, quartiles and count of an error over a cell's runs, a run without the figure
    counted as the worst (:func:`iwr.experiments.harness.percentiles_worst`); ``worst`` False:
    over the runs that have it (the nominal model's figures: no figure is no worse run)."""
    if not worst:
        values = [v for v in values if not math.isnan(v)]
    if not len(values):
        return math.nan, math.nan, math.nan, 0
    q25, med, q75 = percentiles_worst(values, [25, 50, 75])
    return float(med), float(q25), float(q75), len(values)


def _budget_label(method: str, budget: int | None, names: dict[str, str]) -> str:
    if budget is None:
        return method
    return f"{method} {names.get(method, 'budget')}={budget}"


def _budget_names(rows: list[dict[str, Any]]) -> dict[str, str]:
    """The option that each method's budget sets, from the table."""
    return {r["method"]: r["budget_option"] for r in rows if r.get("budget_option")}


def _headline(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """For each method, the rows of its largest budget (the default counts as the largest)."""
    best: dict[str, Any] = {}
    for r in rows:
        b = r["budget"]
        cur = best.get(r["method"], "unset")
        if cur == "unset" or b is None or (cur is not None and b > cur):
            best[r["method"]] = b
    return [r for r in rows if r["budget"] == best[r["method"]]]


def _sorted_unique(values: Any) -> list[Any]:
    return sorted(set(values), key=lambda v: (v is None, v if v is not None else 0))


def _group(rows: list[dict[str, Any]], by: Sequence[str], value: str) -> dict[tuple, tuple]:
    groups: dict[tuple, list[float]] = defaultdict(list)
    for r in rows:
        groups[tuple(r[c] for c in by)].append(r[value])
    return {k: _stats(v) for k, v in groups.items()}


def _zero_level(values: Any) -> float:
    """Where an exact zero is drawn on a log axis: a tenth of the smallest positive finite value
    of the figure's row (1e-16 without one). A fixed 1e-16 drew a noise-free run's 0 above the
    round-off figures (1e-24 mm^2) of the others."""
    v = np.asarray([x for x in values if np.isfinite(x) and x > 0], dtype=float)
    return float(v.min()) / 10.0 if v.size else 1e-16


def _positive(y: np.ndarray, zero: float) -> np.ndarray:
    # Exact zeros drawn at `zero`, the bottom of the log axis; inf (at least half the runs
    # failed) not drawn.
    return np.where(np.isfinite(y), np.where(y > 0, y, zero), np.nan)


def _band_plot(ax: Any, x: Sequence[float], stats: Sequence[tuple], label: str, color: Any,
               zero: float) -> None:
    med = _positive(np.array([s[0] for s in stats]), zero)
    lo = _positive(np.array([s[1] for s in stats]), zero)
    hi = _positive(np.array([s[2] for s in stats]), zero)
    ax.plot(x, med, "o-", color=color, label=label, lw=1.5, ms=4)
    ax.fill_between(x, lo, hi, color=color, alpha=0.2, lw=0)


def _figure(n_rows: int, n_cols: int) -> tuple[Any, np.ndarray]:
    fig = new_figure(4.2 * n_cols, 3.3 * n_rows)
    axes = fig.subplots(n_rows, n_cols, squeeze=False, sharex=True)
    return fig, axes


def _save(fig: Any, path: Path) -> Path:
    fig.tight_layout()
    return save_png(fig, path, dpi=80)


def _colors(labels: Sequence[str]) -> dict[str, Any]:
    return {lab: PALETTE[i % len(PALETTE)] for i, lab in enumerate(labels)}


def _plot_vs(
    rows: list[dict[str, Any]], values: Sequence[str], xcol: str, panel_col: str, path: Path,
    panel_title: Any, xlabel: str, line_cols: Sequence[str] = ("method", "budget"),
    names: dict[str, str] | None = None, refs: list[dict[str, Any]] | None = None,
    ylabels: dict[str, str] | None = None,
) -> Path | None:
    """One row of panels per figure in ``values`` (those with finite data), one column per value
    of ``panel_col``; x = ``xcol``; one line (median) and band (interquartile) per ``line_cols``.
    ``refs``: rows of methods without this axis, drawn as dashed levels (their medians)."""
    values = [v for v in values if any(np.isfinite(r[v]) for r in rows)]
    if not values or len({r[xcol] for r in rows}) < 2:
        return None
    panels = _sorted_unique(r[panel_col] for r in rows)
    lines = _sorted_unique(tuple(r[c] for c in line_cols) for r in rows)
    labels = {ln: _line_label(line_cols, ln, names or {}) for ln in lines}
    colors = _colors(list(labels.values()))
    xs_all = _sorted_unique(r[xcol] for r in rows)
    fig, axes = _figure(len(values), len(panels))
    for i, value in enumerate(values):
        stats = _group(rows, (*line_cols, panel_col, xcol), value)
        zero = _zero_level([r[value] for r in [*rows, *(refs or [])]])
        drawn = [s for st in stats.values() for s in st[:3]]
        for j, p in enumerate(panels):
            ax = axes[i, j]
            for ln in lines:
                xs = [x for x in xs_all if (*ln, p, x) in stats]
                if xs:
                    _band_plot(ax, xs, [stats[(*ln, p, x)] for x in xs], labels[ln],
                               colors[labels[ln]], zero)
                for method in sorted({r["method"] for r in refs or []}):
                    med = _stats([r[value] for r in refs or [] if r["method"] == method
                                  and r[panel_col] == p
                                  and tuple(r[c] for c in line_cols) == ln])[0]
                    if np.isfinite(med):
                        drawn.append(med)
                        ax.axhline(med if med > 0 else zero, color=colors[labels[ln]], ls="--",
                                   lw=1, label=f"{method}, {labels[ln]}")
            if xcol == "noise" and any(x == 0 for x in xs_all):
                ax.set_xscale("symlog", linthresh=min(x for x in xs_all if x > 0))
            else:
                ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xticks(xs_all)
            ax.set_xticklabels([_tick(x) for x in xs_all], fontsize=7)
            ax.xaxis.set_minor_locator(_null_locator())
            ax.grid(True, which="major", alpha=0.3)
            if i == 0:
                ax.set_title(panel_title(p), fontsize=10)
            if i == len(values) - 1:
                ax.set_xlabel(xlabel)
        # Wrapped: a long label (the gauge's words) ran into the panel above and below.
        ylabel = (ylabels or {}).get(value, value)
        if any(d == 0 for d in drawn):  # in the label: a note in the panel covered the points
            ylabel += f" (0 drawn at {zero:.0e})"
        axes[i, 0].set_ylabel(textwrap.fill(ylabel, 38), fontsize=8)
    # One legend of every panel's lines (the first panel's alone left a method drawn only in
    # the others unlabelled, e.g. the efficient estimator beside noise 0).
    seen: dict[str, Any] = {}
    for ax in axes.flat:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            seen.setdefault(label, handle)
    axes[0, 0].legend(list(seen.values()), list(seen), fontsize=7)
    return _save(fig, path)


def _tick(x: float) -> str:
    """30000 -> '30000', 300000 -> '3e5', 1000000 -> '1e6', 0.02 -> '0.02'."""
    if float(x).is_integer() and abs(x) >= 1e5:
        m, e = f"{x:.6e}".split("e")
        return f"{float(m):g}e{int(e)}"
    return f"{x:g}"


def _null_locator() -> Any:
    from matplotlib.ticker import NullLocator

    return NullLocator()


def _line_label(cols: Sequence[str], values: tuple, names: dict[str, str]) -> str:
    d = dict(zip(cols, values, strict=True))
    if "method" in d:
        return _budget_label(d["method"], d.get("budget"), names)
    if list(d) == ["n_poses"]:
        return f"N = {d['n_poses']}"
    return ", ".join(f"{c}={v}" for c, v in d.items())


def _fmt(x: float) -> str:
    return "inf" if x == math.inf else "n/a" if not np.isfinite(x) else f"{x:.2e}"


def _cell(s: tuple) -> str:
    med, q25, q75, n = s
    return "n/a" if n == 0 else f"{_fmt(med)} [{_fmt(q25)}, {_fmt(q75)}]"


def _trend(xs: Sequence[int], meds: Sequence[float], what: str) -> str:
    """A sentence on whether the medians keep improving along ``xs`` and where they level off."""
    for x, m in zip(xs, meds, strict=True):
        if np.isfinite(m) and m < FLOOR:
            return (f"at the floor (< {FLOOR:g} mm) already at {what} = {x}: more cannot "
                    "improve it")
    gains = []
    for (x0, m0), (x1, m1) in itertools.pairwise(zip(xs, meds, strict=True)):
        if not (np.isfinite(m0) and np.isfinite(m1) and m0 > 0):
            return "not enough finite results"
        doublings = math.log2(x1 / x0)
        gains.append((x0, x1, 1.0 - (m1 / m0) ** (1.0 / doublings)))
    if not gains:
        return "only one value on this axis"
    slope = math.log(meds[-1] / meds[0]) / math.log(xs[-1] / xs[0])
    steps = ", ".join(f"{x0}->{x1}: {100 * g:+.0f} %" for x0, x1, g in gains)
    slow = [x0 for x0, _, g in gains if g < LEVEL_OFF]
    verdict = ("keeps improving over the whole range" if not slow else
               f"levels off from {what} = {slow[0]} (gain per doubling < {100 * LEVEL_OFF:.0f} %)")
    return f"{verdict}; log-log slope {slope:+.2f}; gain per doubling {steps}"


def report(out: str | os.PathLike[str]) -> list[Path]:
    """Write the figures and ``summary.md`` of the study in folder ``out``; their paths."""
    from ..experiments.monte_carlo import STUDY_FILE, read_table

    out = Path(out)
    rows_all = read_table(out)
    ok = [r for r in rows_all if r["status"] == "ok"]
    try:
        meta = json.loads((out / STUDY_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        meta = {}
    files: list[Path] = []
    labels = _labels(meta)
    head = _headline(ok)
    names = _budget_names(rows_all)
    text = _kind_text(meta)  # the kind's words for its noise level (an sd, or a scale)
    noise_title = lambda v: text["noise_panel"].format(level=v, ratio=v / 0.02)  # noqa: E731
    noise_axis = text["noise_axis"]
    poses_title = lambda v: f"N = {v} poses"  # noqa: E731
    figures = ("val_rms", "tool_position_rms", "tool_orientation_rms", "param_error_length")
    for xcol, pcol, title, xlabel, name in (
        ("n_poses", "noise", noise_title, "number of poses N", "accuracy_vs_poses.png"),
        ("noise", "n_poses", poses_title, noise_axis, "accuracy_vs_noise.png"),
    ):
        f = _plot_vs(head, figures, xcol, pcol, out / name, title, xlabel, names=names,
                     ylabels=labels)
        if f is not None:
            files.append(f)
    for m in sorted({r["method"] for r in ok if r["budget"] is not None}):
        rows_m = [r for r in ok if r["method"] == m and r["budget"] is not None]
        refs = [r for r in ok if r["budget"] is None and r["method"] != m]
        f = _plot_vs(rows_m, ("val_rms", "param_error_length"), "budget", "noise",
                     out / f"accuracy_vs_budget_{m}.png", noise_title,
                     f"{m}: {names.get(m, 'budget')}"
                     + (f" (dashed: {', '.join(sorted({r['method'] for r in refs}))})"
                        if refs else ""),
                     line_cols=("n_poses",), refs=refs, ylabels=labels)
        if f is not None:
            files.append(f)
    summary = out / "summary.md"
    text = _summary(rows_all, ok, head, meta, files, names)
    atomic_write_text(summary, text)
    files.append(summary)
    inputs = {"table": out / "results.csv"}
    if (out / STUDY_FILE).is_file():
        inputs["settings"] = out / STUDY_FILE
    files.append(write_page(_page(text, out, provenance(inputs)), out / "report.html"))
    return files


def _page(summary_md: str, out: Path, prov: dict[str, Any]) -> Page:
    """The summary (Markdown of :func:`_summary`: headings, paragraphs, tables, items, figures)
    as a self-contained HTML page, the figures embedded."""
    lines = summary_md.splitlines()
    page = Page("iwr study: summary")
    i = 0
    while i < len(lines):
        line = lines[i]
        if line.startswith("# "):
            pass  # the page's title
        elif line.startswith("## "):
            page.heading(line[3:])
        elif line.startswith("|"):
            block = []
            while i < len(lines) and lines[i].startswith("|"):
                block.append([c.strip() for c in lines[i].strip("|").split("|")])
                i += 1
            page.table((block[0], block[2:]))
            continue
        elif line.startswith("- "):
            items = []
            while i < len(lines) and lines[i].startswith("- "):
                items.append(lines[i][2:])
                i += 1
            page.items(items)
            continue
        elif line.startswith("!["):
            name = line[line.index("](") + 2:-1]
            page.figure((out / name).read_bytes(), name.removesuffix(".png").replace("_", " "),
                        name)
        elif line.strip():
            page.paragraph(line.replace("`", ""))
        i += 1
    page.provenance(prov)
    return page


def _summary(
    rows_all: list[dict[str, Any]], ok: list[dict[str, Any]], head: list[dict[str, Any]],
    meta: dict[str, Any], files: list[Path], names: dict[str, str],
) -> str:
    text = _kind_text(meta)
    short = text["readings_short"]
    n_vals = _sorted_unique(r.get("validation_poses") for r in rows_all)
    n_val = meta.get("validation_poses") or ", ".join(str(v) for v in n_vals if v is not None)
    lines = ["# Study summary", ""]
    lines.append(
        f"{len(rows_all)} cells: methods {sorted({r['method'] for r in rows_all})}, "
        f"poses {_sorted_unique(r['n_poses'] for r in rows_all)}, "
        f"noise levels {_sorted_unique(r['noise'] for r in rows_all)}"
        f"{text['noise_unit']}, "
        f"{len({r['draw'] for r in rows_all})} error draws x {len({r['seed'] for r in rows_all})} "
        f"seeds; {len(rows_all) - len(ok)} failed."
    )
    budgets = {m: _sorted_unique(r["budget"] for r in rows_all if r["method"] == m)
               for m in sorted({r["method"] for r in rows_all})}
    if any(b != [None] for b in budgets.values()):
        lines.append("Budgets: " + "; ".join(
            f"{m}: {names.get(m, 'budget')} = {', '.join(map(str, b))}"
            for m, b in budgets.items() if b != [None]) + ".")
    lines += [
        "",
        f"Validation error: RMS over {n_val} fresh, noise-free poses of the actual robot of the "
        f"{short} readings' error, {text['readings']}; median [25 %, 75 %] over error draws x "
        "seeds, a run without the figure (no forward kinematics at its result) counted as the "
        f"worst (inf). Noise level: {text['noise_level']}.",
        "",
    ]
    if text.get("gauge"):
        lines += [text["gauge"], ""]
    nominal = _stats([r["val_rms_nominal"] for r in ok], worst=False)
    if nominal[3]:
        lines += [f"Before calibration (nominal model): {_cell(nominal)} mm.", ""]
    for value, title in _labels(meta).items():
        if not any(np.isfinite(r[value]) for r in head):
            continue
        poses = _sorted_unique(r["n_poses"] for r in head)
        stats = _group(head, ("method", "budget", "noise", "n_poses"), value)
        lines += [f"## {title[0].upper()}{title[1:]}", ""]
        lines.append("| method | noise (mm) | " + " | ".join(f"N = {n}" for n in poses) + " |")
        lines.append("|---|---|" + "---|" * len(poses))
        for (m, b, lv) in sorted({k[:3] for k in stats}, key=lambda k: (k[0], k[2])):
            cells = [_cell(stats.get((m, b, lv, n), (math.nan, math.nan, math.nan, 0)))
                     for n in poses]
            lines.append(f"| {_budget_label(m, b, names)} | {lv:g} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["## The paper's claim: more poses and more generations improve the accuracy", "",
              f"Rule: a median that improves by less than {100 * LEVEL_OFF:.0f} % per doubling "
              "levels off (1/sqrt(N), the law of least squares on noisy data, gives 29 % per "
              f"doubling, a log-log slope of -0.5); below {FLOOR:g} mm a calibration is exact.", ""]
    stats = _group(head, ("method", "budget", "noise", "n_poses"), "val_rms")
    poses = _sorted_unique(r["n_poses"] for r in head)
    if len(poses) > 1:
        lines += [f"More poses (validation {short} RMS):", ""]
        for (m, b, lv) in sorted({k[:3] for k in stats}, key=lambda k: (k[0], k[2])):
            xs = [n for n in poses if (m, b, lv, n) in stats]
            meds = [stats[(m, b, lv, n)][0] for n in xs]
            label = _budget_label(m, b, names)
            lines.append(f"- {label}, noise {lv:g} mm: {_trend(xs, meds, 'N')}.")
        lines.append("")
    levels = [lv for lv in _sorted_unique(r["noise"] for r in head) if lv > 0]
    if len(levels) > 1:
        lines += [f"More noise (validation {short} RMS against the noise level, over the levels "
                  "> 0; a log-log slope of 1 means proportional to the noise):", ""]
        for (m, b) in sorted({k[:2] for k in stats}):
            parts = []
            for n in poses:
                meds = [stats[(m, b, lv, n)][0] for lv in levels if (m, b, lv, n) in stats]
                lvs = [lv for lv in levels if (m, b, lv, n) in stats]
                if len(lvs) > 1 and all(np.isfinite(meds)) and min(meds) > 0:
                    slope = math.log(meds[-1] / meds[0]) / math.log(lvs[-1] / lvs[0])
                    parts.append(f"N = {n}: slope {slope:.2f}, {meds[-1] / lvs[-1]:.3g} mm per mm")
            if parts:
                lines.append(f"- {_budget_label(m, b, names)}: " + "; ".join(parts) + ".")
        lines.append("")
    for m in sorted({r["method"] for r in ok if r["budget"] is not None}):
        rows_m = [r for r in ok if r["method"] == m and r["budget"] is not None]
        bs = _sorted_unique(r["budget"] for r in rows_m)
        if len(bs) < 2:
            continue
        name = names.get(m, "budget")
        st = _group(rows_m, ("noise", "n_poses", "budget"), "val_rms")
        lines += [f"More {name} ({m}, validation {short} RMS):", ""]
        for (lv, n) in sorted({k[:2] for k in st}):
            meds = [st[(lv, n, b)][0] for b in bs if (lv, n, b) in st]
            xs = [b for b in bs if (lv, n, b) in st]
            lines.append(f"- N = {n}, noise {lv:g} mm: {_trend(xs, meds, name)}.")
        lines.append("")
    failed = [r for r in rows_all if r["status"] != "ok"]
    if failed:
        lines += ["## Failed cells", ""]
        for r in failed[:20]:
            lines.append(f"- {r['method']}, N = {r['n_poses']}, noise {r['noise']:g}, "
                         f"draw {r['draw']}, seed {r['seed']}: {r['message']}")
        lines.append("")
    figs = [f for f in files if f.suffix == ".png"]
    if figs:
        lines += ["## Figures", ""] + [f"![{f.stem}]({f.name})" for f in figs] + [""]
    return "\n".join(lines)
