"""The calibration report of double-ballbar data (docs/ballbar.md): the report of
:mod:`iwr.reporting.calibration` with what belongs to a ballbar's distances (the residuals per
set-up, the identified ball centres and length offsets with their standard deviations, what a
ballbar cannot see); the report the ballbar kind names
(:attr:`iwr.kinds.MeasurementKind.report`)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_write_text, jsonable
from .calibration import CalibrationReport, _src
from .figures import before_units, histogram, new_figure
from .html import Page
from .setup_parameters import SetupParameters

__all__ = ["BallbarCalibrationReport"]

#: The set-up parameters of one bar, in the order of :class:`iwr.ballbar.BallbarSetup`.
_BALL_FIELDS = ("platform ball in {5}", "fixed ball in {0}")


def _stats(v: np.ndarray) -> dict[str, float]:
    v = np.asarray(v, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"n": 0, "mean": math.nan, "rms": math.nan, "max": math.nan}
    return {"n": int(v.size), "mean": float(v.mean()), "rms": float(math.sqrt(np.mean(v**2))),
            "max": float(np.max(np.abs(v)))}


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head),
            *["| " + " | ".join(row) + " |" for row in rows]]


class BallbarCalibrationReport(SetupParameters, CalibrationReport):
    """A calibration run on double-ballbar data (docs/ballbar.md).

    ``identification``/``validation`` are :class:`iwr.ballbar.BallbarMeasurements`,
    ``result.x`` holds the robot's then the set-ups' parameters (7 per set-up: the platform
    ball's correction in {5}, the fixed ball's in {0}, the length offset's), ``accuracy`` is
    :func:`iwr.ballbar.ballbar_accuracy`'s (each pose's absolute distance residual; a bar
    measures no orientation), ``identifiability`` a :class:`iwr.tracker.NullSpace`.
    """

    _measured_also = ("the distance residuals above are not a tool pose error: they also contain "
                      "the bar's noise on the {where} poses")

    # -- numbers --------------------------------------------------------------------------------
    @property
    def setup(self) -> Any:
        """The robot's ballbar set-ups (:class:`iwr.ballbar.BallbarSetup`)."""
        return self.robot.instruments["ballbar"]

    def _x(self) -> np.ndarray:
        return np.asarray(self.result.x, dtype=float)

    def _residuals_of(self, data: Any) -> dict[str, np.ndarray]:
        """Predicted minus measured bar readings (mm), unweighted, per pose:
        ``{"nominal": ..., "calibrated": ...}`` (NaN where forward kinematics fails)."""
        from .. import kinds

        # The kind's problem: with the robot's effects (issue 23) when it has them.
        problem, start = kinds.of(data).problem(self.robot, data)
        out = {}
        for label, x in (("nominal", start), ("calibrated", self._x())):
            out[label] = problem.predicted(x) - data.distance
        return out

    def costs(self) -> dict[str, float]:
        """Sum of squared distance residuals on the identification poses (mm^2), at the nominal
        robot and set-ups and at the result (unweighted: not ``result.fun``, which a noise model
        weights)."""
        r = self._residuals_of(self.identification)
        return {k: float(np.nansum(np.square(v))) for k, v in r.items()}

    def residuals(self) -> dict[str, dict[str, Any]]:  # type: ignore[override]
        """Per set-up: the poses and the statistics of the distance residual (mm), nominal and
        calibrated, ``[data set][set-up][nominal|calibrated]``."""
        sets = {"identification": self.identification}
        if self.held_out:
            sets["validation"] = self.validation
        out: dict[str, dict[str, Any]] = {}
        for name, data in sets.items():
            r = self._residuals_of(data)
            names = np.asarray(data.setup, dtype=str)
            out[name] = {bar: {"poses": int(np.sum(names == bar)),
                               **{k: _stats(v[names == bar]) for k, v in r.items()}}
                         for bar in self.setup.names if np.any(names == bar)}
        return out

    def ball_rows(self) -> list[list[str]]:
        """One row per set-up and ball (and its length offset): nominal, identified correction
        (with its standard deviation when known) and identified value (mm)."""
        s = self.setup
        nr = self.n_robot
        xs = self._x()[nr:].reshape(s.n_setups, 7)
        std = self._std()
        sd = None if std is None else std[nr:].reshape(s.n_setups, 7)
        p_cal, f_cal, o_cal = s.split(self._x()[nr:])

        def cell(values: np.ndarray, sigmas: Any) -> str:
            text = ", ".join(f"{v:+.4f}" for v in values)
            if sigmas is not None and np.any(np.isfinite(sigmas)):
                text += " (std " + ", ".join(f"{v:.2g}" if np.isfinite(v) else "held"
                                             for v in sigmas) + ")"
            return text

        rows = []
        for i, bar in enumerate(s.bars):
            for j, (label, nominal, cal) in enumerate(zip(
                    _BALL_FIELDS, (bar.platform_ball, bar.fixed_ball), (p_cal[i], f_cal[i]),
                    strict=True)):
                cols = slice(3 * j, 3 * j + 3)
                rows.append([f"{bar.name}: {label}", ", ".join(f"{v:.3f}" for v in nominal),
                             cell(xs[i, cols], None if sd is None else sd[i, cols]),
                             ", ".join(f"{v:.4f}" for v in cal)])
            rows.append([f"{bar.name}: length offset", f"{bar.offset:.4f}",
                         cell(xs[i, 6:7], None if sd is None else sd[i, 6:7]),
                         f"{o_cal[i]:.4f}"])
        return rows

    def null_sentence(self) -> str:
        ns = self.identifiability
        if ns is None:
            return ""
        return (f"Ballbar data determine {ns.rank} of the {len(ns.parameter_names)} parameters: "
                f"{len(ns.left_out)} directions are null, because a distance between a ball on "
                "the platform and a ball on the table does not change when the whole world "
                "moves rigidly (the robot and every fixed ball with it: the translations and "
                "the turn about the first joint's axis that the model can make), nor when the "
                "platform frame {5} moves rigidly on the platform (its joints and balls with "
                "it), beside the leg data's own null directions. One parameter per direction "
                "is held; predicted bar readings do not depend on the choice, and tool poses "
                "are determined modulo a rigid motion of {0} and one of {5}: register them by "
                "other means to use the robot in a world frame (docs/ballbar.md)."
                + self._effects_sentence(ns))

    @staticmethod
    def _effects_sentence(ns: Any) -> str:
        """What the effects (issue 23) add to the null directions: the directions only the
        loads fix, held too, and the effects' parameters the data cannot separate."""
        held, inseparable = getattr(ns, "held", []), getattr(ns, "inseparable", [])
        out = ""
        if held:
            out += (f" With the effects, {len(held)} more directions are fixed by the loads "
                    "alone, weakly (the world frame turned against gravity, {5} moved against "
                    "the loads' centres of mass): they are held as well (" + ", ".join(held)
                    + "; docs/effects.md).")
        if inseparable:
            names = ", ".join(n for n, _ in inseparable)
            out += (" Effect parameters these poses and loads cannot separate from the "
                    f"geometry, held at the robot file's value: {names} (measure with a second "
                    "payload).")
        return out

    def to_dict(self) -> dict[str, Any]:
        figures = {"cost_mm2": self.costs(), "distance_residuals_mm": self.residuals(),
                   "setups": self.setup.with_parameters(self._x()[self.n_robot:]).to_dict()}
        return self._summary("ballbar", figures)

    # -- text -----------------------------------------------------------------------------------
    def _method_text(self) -> str:
        r = self.result
        return (f"method {r.get('method', '?')}: {int(r.nfev)} evaluations, "
                f"{float(r.get('wall_time', math.nan)):.2f} s, {self.status_text()} ("
                + ("see the fit test below" if self._fit_failed()
                   else str(r.message).strip().rstrip(".")) + ")")

    def _residual_rows(self) -> tuple[list[str], list[list[str]]]:
        res = self.residuals()
        head = ["set-up"]
        for s in res:
            head += [f"{s}: poses", f"{s}: RMS before (mm)", f"{s}: RMS after (mm)",
                     f"{s}: max after (mm)"]
        rows = []
        for bar in self.setup.names:
            row = [bar]
            for d in res.values():
                if bar not in d:
                    row += ["0", "-", "-", "-"]
                    continue
                row += [str(d[bar]["poses"]), f"{d[bar]['nominal']['rms']:.4f}",
                        f"{d[bar]['calibrated']['rms']:.5f}",
                        f"{d[bar]['calibrated']['max']:.5f}"]
            rows.append(row)
        return head, rows

    def _accuracy_rows(self) -> list[list[str]]:
        rows = []
        for label, e in (("nominal robot and set-ups", self.accuracy.nominal),
                         ("calibrated", self.accuracy.calibrated)):
            st = _stats(e.position)
            rows.append([label, f"{st['rms']:.4g}", f"{st['max']:.4g}"])
        return rows

    def summary(self) -> str:
        c = self.costs()
        ns = self.identifiability
        where = ("held-out poses" if self.held_out else "identification poses (nothing held "
                 "out: optimistic)")
        lines = [
            f"robot {self.robot.name!r}{_src(self.robot_name)}; ballbar data{_src(self.data_name)}"
            f": {len(self.identification)} poses for identification in "
            f"{self.setup.n_setups} set-up(s){self.left_out_text()}, "
            + (f"{len(self.validation)} held out" if self.held_out else "none held out"),
            self._method_text(),
            f"cost (sum of squared distance residuals, mm^2, {len(self.identification)} poses): "
            f"nominal robot and set-ups {c['nominal']:.6g} -> calibrated {c['calibrated']:.6g}",
        ]
        if ns is not None:
            lines.append(f"identifiability: rank {ns.rank} of {len(ns.parameter_names)}, "
                         f"{len(ns.left_out)} null directions (what a ballbar cannot see: "
                         "docs/ballbar.md)")
        lines += ["", "distance residuals per set-up, predicted - measured reading (mm):"]
        for data_set, bars in self.residuals().items():
            lines.append(f"  {data_set} poses:")
            lines += [f"    {bar:<12} {d['poses']:5d} poses   RMS {d['nominal']['rms']:.4f} -> "
                      f"{d['calibrated']['rms']:.5f}, max after {d['calibrated']['max']:.5f}"
                      for bar, d in bars.items()]
        lines += ["", "ball centres and length offsets (mm): nominal | identified correction "
                  "(std) | identified"]
        lines += [f"  {r[0]:<32} {r[1]:>26} | {r[2]} | {r[3]}" for r in self.ball_rows()]
        lines += self.effect_lines()  # issue 23 (none without effects)
        lines += ["", f"accuracy on {self.accuracy.n_poses} {where}: each pose's "
                  "|predicted - measured| bar reading (mm):"]
        lines += [f"  {label:<28} RMS {rms} mm, max {mx} mm"
                  for label, rms, mx in self._accuracy_rows()]
        if self.predicted is not None:
            lines.append(self.predicted_line())
        fit = self.fit_lines()
        if fit:
            lines += [""] + fit
        if self.diagnosis is not None:  # issue 23: a geometric fit against the loads
            lines += self.diagnosis.lines()
        if self._fit_failed():
            lines.append(self.no_fit_verdict("the figures above"))
        lines.extend(self.notes)
        return "\n".join(lines)

    def predicted_line(self) -> str:
        """The efficient estimator's predicted accuracy: of the tool pose modulo what a ballbar
        cannot see (iwr.ballbar.estimation.ballbar_predicted_accuracy), not of the readings."""
        pr = self.predicted
        if pr is None:
            return ""
        where = "validation" if self.held_out else "identification"
        return (f"predicted by the estimator's covariance on the {where} poses: the tool pose "
                "against the truth modulo what a ballbar cannot see (the best rigid motions of "
                "{0} and {5} removed, docs/ballbar.md; not the bar readings above): position "
                f"RMS {pr.position_rms:.4g} mm (95 %: {pr.position_95:.4g} mm), orientation RMS "
                f"{pr.orientation_rms:.4g} deg (95 %: {pr.orientation_95:.4g} deg)")

    def predicted_text(self) -> str:
        line = self.predicted_line()
        return line[:1].upper() + line[1:] + "."

    def html(self, figures: dict[str, bytes] | None = None) -> Page:
        figures = figures or {}
        c = self.costs()
        page = Page("Calibration report: double-ballbar data")
        page.paragraph(
            f"Robot {self.robot.name}{_src(self.robot_name)}, data{_src(self.data_name)}: a "
            f"ballbar's distance per pose, {self.setup.n_setups} set-up(s) "
            f"({', '.join(self.setup.names)}); {len(self.identification)} poses for "
            "identification, " + (f"{len(self.validation)} held out for validation."
                                  if self.held_out else "none held out."), "muted")
        page.heading("Summary")
        page.verdict(*self.verdict())
        page.table((["robot", "distance residual RMS (mm)", "distance residual max (mm)"],
                    self._accuracy_rows()), "num")
        if self.predicted is not None:
            page.paragraph(self.predicted_text())
        page.paragraph(
            "Per pose: the absolute difference between the predicted and the measured bar "
            "reading (a bar measures no orientation), on the "
            + ("validation poses." if self.held_out else "identification poses (nothing held "
               "out: optimistic).")
            + f" Cost (sum of squared distance residuals, mm^2): nominal robot and set-ups "
            f"{c['nominal']:.6g}, calibrated {c['calibrated']:.6g}. " + self._method_text()
            .capitalize() + ".")
        self._fit_section(page, "Fit test")
        if self.diagnosis is not None:
            self._diagnosis_html(page)
        if "accuracy.png" in figures:
            page.figure(figures["accuracy.png"], "Distance residuals per pose before and after "
                        "calibration", "accuracy.png")
        page.heading("Distance residuals per set-up")
        page.table(self._residual_rows(), "num")
        if "residuals.png" in figures:
            page.figure(figures["residuals.png"], "Distance residuals per set-up before and "
                        "after calibration", "residuals.png")
        page.heading("Ball centres and length offsets")
        page.table((["", "nominal (mm)", "identified correction (mm)", "identified (mm)"],
                    self.ball_rows()), "num")
        page.paragraph("Each set-up's platform ball in the platform frame {5}, its fixed ball in "
                       "the world frame {0}, and the bar's length offset (reading minus centre "
                       "distance). A correction on a null direction (below) is held: 'held' in "
                       "place of its standard deviation.")
        page.heading("Identified parameters")
        if self.uncertainty is not None:
            page.paragraph(f"Standard deviations: {self.uncertainty.describe()}.")
        page.table(self.parameter_table(), "params")
        self._effects_html(page, "the bar's distances with the effects")
        if self.identifiability is not None:
            page.heading("What a ballbar cannot see")
            page.paragraph(self.null_sentence())
            page.pre(self.null_text())
        return self._html_tail(page, [
            "calibrated.toml: the calibrated robot with its calibrated [ballbar] set-ups",
            "result.json: the identification result (iwr.load_result)",
            "accuracy.json: the accuracy figures", "summary.json: the figures of this report",
            "report.md: this report as Markdown", *figures])

    def markdown(self, figures: list[str]) -> str:
        md = ["# Calibration report: double-ballbar data", "", f"**{self.verdict()[0]}**", "",
              f"- Robot: `{self.robot.name}`{_src(self.robot_name)}",
              f"- Data{_src(self.data_name)}: {len(self.identification)} poses for "
              f"identification in {self.setup.n_setups} set-up(s), "
              + (f"{len(self.validation)} held out" if self.held_out else "none held out"),
              f"- {self._method_text().capitalize()}", "", "## Summary", "", "```",
              self.summary(), "```"]
        if self.predicted is not None:
            md += ["", self.predicted_text()]
        md += self._diagnosis_md()
        if "accuracy.png" in figures:
            md += ["", "![Distance residuals per pose](accuracy.png)"]
        md += ["", "## Distance residuals per set-up", "", *_table(*self._residual_rows())]
        if "residuals.png" in figures:
            md += ["", "![Distance residuals per set-up](residuals.png)"]
        md += ["", "## Ball centres and length offsets", "",
               *_table(["", "nominal (mm)", "identified correction (mm)", "identified (mm)"],
                       self.ball_rows()),
               "", "## Identified parameters", "",
               *_table(*self.parameter_table())]
        md += self._effects_md()
        if self.identifiability is not None:
            md += ["", "## What a ballbar cannot see", "", self.null_sentence(), "", "```",
                   self.null_text(), "```"]
        md += self._tail_md(["- `calibrated.toml`, `result.json`, `accuracy.json`, "
                             "`summary.json`, `report.html`"], figures)
        return "\n".join(md) + "\n"

    # -- figures --------------------------------------------------------------------------------
    def _plot_residuals(self) -> Any:
        data = self.validation if self.held_out else self.identification
        which = "validation" if self.held_out else "identification"
        r = self._residuals_of(data)
        names = np.asarray(data.setup, dtype=str)
        bars = [b for b in self.setup.names if np.any(names == b)]
        fig = new_figure(10, 4)
        axes = fig.subplots(1, 2)
        for ax, v, title, unit in ((axes[0], r["nominal"], "nominal robot and set-ups", "mm"),
                                   (axes[1], r["calibrated"] * 1000.0, "calibrated", "um")):
            cols = [v[names == b][np.isfinite(v[names == b])] for b in bars]
            ax.boxplot(cols)
            ax.set_xticks(range(1, len(bars) + 1), bars)
            ax.axhline(0.0, color="0.6", lw=0.8)
            ax.set_xlabel("set-up")
            ax.set_ylabel(f"predicted - measured ({unit})")
            ax.set_title(title)
        fig.suptitle(f"Distance residuals per set-up on {len(data)} {which} poses")
        fig.tight_layout()
        return fig

    def _plot_accuracy(self) -> Any:
        a = self.accuracy
        fig = new_figure(10, 3.6)
        axes = fig.subplots(1, 2)
        (pu, pf), _ = before_units(a.nominal.position)
        for ax, v, unit, title, colour in (
                (axes[0], np.asarray(a.nominal.position, dtype=float) * pf, pu,
                 "nominal robot and set-ups", "C0"),
                (axes[1], a.calibrated.position * 1000.0, "um", "calibrated", "C2")):
            v = np.asarray(v, dtype=float)
            v = v[np.isfinite(v)]
            histogram(ax, v, colour)
            ax.set_title(f"{title}: RMS {math.sqrt(np.mean(v**2)):.3g} {unit}")
            ax.set_xlabel(f"|predicted - measured| ({unit})")
            ax.set_ylabel("poses")
        fig.suptitle(f"Distance residuals per pose on {a.n_poses} "
                     f"{'validation' if self.held_out else 'identification'} poses")
        fig.tight_layout()
        return fig

    # -- files ----------------------------------------------------------------------------------
    def _write_files(self, out: Path, plots: bool) -> list[Path]:
        """``calibrated.toml`` (the calibrated robot with its calibrated ``[ballbar]``
        set-ups), ``result.json``, ``accuracy.json``, ``summary.json``, the figures and the
        report into ``out``; returns the paths written."""
        calibrated, extra = self.calibrated_file()
        written = [out / "calibrated.toml", out / "result.json", out / "accuracy.json"]
        calibrated.to_toml(written[0], provenance=self.file_provenance(**extra))
        self.result.save(written[1])
        atomic_write_text(written[2], json.dumps(jsonable(self.accuracy.to_dict(),
                                                          finite_only=True), indent=1) + "\n")
        return written + self._write_report(out, plots)
