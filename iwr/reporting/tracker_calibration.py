"""The calibration report of laser-tracker data (docs/tracker.md): the report of
:mod:`iwr.reporting.calibration` with what belongs to tracker data (point residuals per
reflector, the registration and its change, the offsets, the null directions); the report the
tracker kinds name (:attr:`iwr.kinds.MeasurementKind.report`)."""

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

__all__ = ["TrackerCalibrationReport"]

def _nanstats(v: np.ndarray) -> dict[str, float]:
    v = np.asarray(v, dtype=float)
    v = v[np.isfinite(v)]
    if not v.size:
        return {"mean": math.nan, "rms": math.nan, "max": math.nan, "n": 0}
    return {"mean": float(v.mean()), "rms": float(math.sqrt(np.mean(v**2))),
            "max": float(v.max()), "n": int(v.size)}


def _fmt(v: float, spec: str) -> str:
    return format(v, spec) if math.isfinite(v) else "-"


#: What the effects are identified with on tracker data (issue 23), in the report's words.
_EFFECTS_OBJECTIVE = ("the point objective with the effects: forward kinematics under each "
                      "pose's load and temperature (the carriage's joints changed first when its "
                      "compliance is on, then the legs), gravity given in {T} and carried into "
                      "{0} by the identified registration; calibrated.toml's platform frame {5} "
                      "is the "
                      "one the measured points fix, the platform's centre of mass moved with it, "
                      "and the data's payload centres are read in that frame")


class TrackerCalibrationReport(SetupParameters, CalibrationReport):
    """A calibration run on laser-tracker data (docs/tracker.md): the same report as for leg
    data, with what belongs to tracker data.

    ``identification``/``validation`` are :class:`iwr.tracker.TrackerMeasurements`, ``result.x``
    holds the robot's then the setup's parameters, ``accuracy`` is
    :func:`iwr.tracker.api.tracker_accuracy`'s (largest point distance per pose, and the angle of
    the best rigid rotation between predicted and measured points), ``identifiability`` a
    :class:`iwr.tracker.NullSpace`. ``start`` is the registration guess on the identification
    poses; ``sources["readings"]`` the robot's log of readings beside a long table.
    """

    _measured_also = ("the point residuals above are not a tool pose error: they also contain the "
                      "tracker's noise on the {where} poses")

    # -- numbers --------------------------------------------------------------------------------
    @property
    def setup(self) -> Any:
        return self.robot.tracker

    def _problem(self, data: Any) -> tuple[Any, np.ndarray]:
        """The problem of ``data`` and its "before" point: the nominal robot with the data's own
        registration guess (or, for data too few for one, with the identified setup)."""
        from ..tracker.registration import RegistrationError

        try:  # the kind's problem: with the effects, if any (issue 23)
            return self.kind.problem(self.robot, data)
        except RegistrationError:
            x = np.asarray(self.result.x, dtype=float)
            problem, _ = self.kind.problem(self.robot, data, x0=x)
            return problem, np.concatenate([np.zeros(self.n_robot), x[self.n_robot:]])

    def costs(self) -> dict[str, float]:
        """Sum of squared point residuals on the identification poses (mm^2), at the nominal
        robot with the registration guess and at the result."""
        problem, start = self._problem(self.identification)
        # Not result.fun: the efficient estimator's is its chi-square statistic.
        return {"nominal": problem.cost(start),
                "calibrated": problem.cost(np.asarray(self.result.x, dtype=float))}

    def point_labels(self) -> list[str]:
        s = self.setup
        if s.kind == "points":
            return [f"reflector {n}" for n in s.names]
        return ["probe origin"] + [f"probe {a} axis, {s.probe_length:g} mm out" for a in "xyz"]

    def point_distances(self, data: Any) -> dict[str, np.ndarray]:
        """Distances (mm) between predicted and measured points, (N, n_points), NaN where not
        seen: ``{"nominal": ..., "calibrated": ...}``."""
        problem, start = self._problem(data)
        meas = data.tracker_points(self.setup).reshape(len(data), -1, 3)
        out = {}
        for label, x in (("nominal", start), ("calibrated", np.asarray(self.result.x, float))):
            d = np.linalg.norm(problem.predicted_points(x) - meas, axis=2)
            out[label] = np.where(np.isnan(meas[:, :, 0]), np.nan, d)
        return out

    def residuals(self) -> dict[str, dict[str, Any]]:  # type: ignore[override]
        """Per point (reflector, or the probe's virtual points): seen and hidden counts and the
        statistics of the predicted-to-measured distance (mm), ``[set][nominal|calibrated]``."""
        sets = {"identification": self.identification}
        if self.held_out:
            sets["validation"] = self.validation
        out: dict[str, dict[str, Any]] = {}
        for name, data in sets.items():
            d = self.point_distances(data)
            seen = ~np.isnan(d["nominal"]) | ~np.isnan(d["calibrated"])
            out[name] = {
                "seen": seen.sum(axis=0).tolist(), "hidden": (~seen).sum(axis=0).tolist(),
                **{k: [_nanstats(v[:, i]) for i in range(v.shape[1])] for k, v in d.items()}}
        return out

    def hidden_text(self) -> str:
        """``N of M points not seen`` (reflector data), ``N of M probe poses not seen`` (a probe's
        pose is seen whole or not at all)."""
        hidden, total = self.hidden_counts()
        return f"{hidden} of {total} " + ("points" if self.setup.kind == "points"
                                          else "probe poses") + " not seen"

    def hidden_counts(self) -> tuple[int, int]:
        """(points not seen, points expected) over every pose of the run."""
        data = [self.identification] + ([self.validation] if self.held_out else [])
        hidden = sum(int((~m.seen).sum()) for m in data)
        total = sum(int(m.seen.size) for m in data)
        return hidden, total

    def registration_rows(self) -> list[tuple[str, np.ndarray]]:
        """``(label, pose)``: the nominal registration, the closed-form guess and the identified
        one, poses ``(x, y, z, alpha, beta, gamma)`` of {0} in {T} (mm, rad)."""
        from ..transforms import pose_from_matrix

        s = self.setup
        x = np.asarray(self.result.x, dtype=float)
        rows = [("nominal (robot file)", np.asarray(s.registration, dtype=float))]
        if self.guess is not None:
            rows.append(("closed-form guess (Kabsch)", np.asarray(self.guess.registration)))
        rows.append(("identified", pose_from_matrix(s.registration_matrix(x[self.n_robot:]))))
        return rows

    def registration_change(self) -> tuple[float, float, float, float]:
        """How far the identified registration is from the nominal and from the guess: distance
        (mm) and angle (degrees) of the relative transform, on {0}'s origin."""

        from ..transforms import pose_matrix, rotation_angle

        rows = dict(self.registration_rows())
        ident = pose_matrix(rows["identified"])
        out = []
        for key in ("nominal (robot file)", "closed-form guess (Kabsch)"):
            if key not in rows:
                out += [math.nan, math.nan]
                continue
            rel = np.linalg.solve(pose_matrix(rows[key]), ident)
            out += [float(np.linalg.norm(rel[:3, 3])),
                    float(np.degrees(rotation_angle(rel[:3, :3])))]
        return out[0], out[1], out[2], out[3]

    def offset_rows(self) -> list[list[str]]:
        """One row per reflector (or the probe): nominal position in {5}, identified offset and
        position, with standard deviations when known."""
        s = self.setup
        x = np.asarray(self.result.x, dtype=float)[self.n_robot:]
        std = self._std()
        sd = None if std is None else std[self.n_robot:]
        rows = []
        if s.kind == "points":
            for i, name in enumerate(s.names):
                off = x[6 + 3 * i: 9 + 3 * i]
                nom = s.reflectors[i]
                cell = ", ".join(f"{v:+.4f}" for v in off)
                if sd is not None and np.any(np.isfinite(sd[6 + 3 * i: 9 + 3 * i])):
                    cell += " (std " + ", ".join(f"{v:.2g}" if np.isfinite(v) else "held"
                                                 for v in sd[6 + 3 * i: 9 + 3 * i]) + ")"
                rows.append([f"reflector {name}", ", ".join(f"{v:.3f}" for v in nom), cell,
                             ", ".join(f"{v:.4f}" for v in nom + off),
                             f"{float(np.linalg.norm(off)):.4f}"])
        else:
            cal = s.with_parameters(x)
            off = x[6:12]
            rows.append(["probe position (mm)", ", ".join(f"{v:.3f}" for v in s.probe[:3]),
                         ", ".join(f"{v:+.4f}" for v in off[:3]),
                         ", ".join(f"{v:.4f}" for v in cal.probe[:3]),
                         f"{float(np.linalg.norm(off[:3])):.4f}"])
            rows.append(["probe orientation (deg)",
                         ", ".join(f"{math.degrees(v):.4f}" for v in s.probe[3:]),
                         ", ".join(f"{math.degrees(v):+.5f}" for v in off[3:]) + " (rotation "
                         "vector)", ", ".join(f"{math.degrees(v):.4f}" for v in cal.probe[3:]),
                         f"{math.degrees(float(np.linalg.norm(off[3:]))):.5f}"])
        return rows

    def _held(self) -> str:
        """With effects (issue 23): the parameters the objective determines, weakly, but the
        calibration held (:class:`iwr.effects.tracker.EffectNullSpace`'s ``held``)."""
        held = list(getattr(self.identifiability, "held", None) or [])
        if not held:
            return ""
        return (f"; {len(held)} more held: the directions of the platform frame {{5}} that "
                "only the loads' centres of mass fix, too weakly for noisy data "
                "(docs/effects.md, \"Tracker data\")")

    def null_sentence(self) -> str:
        ns = self.identifiability
        if ns is None:
            return ""
        held = self._held()
        return (f"Tracker data determine {ns.rank} of the {len(ns.parameter_names)} parameters: "
                f"{len(ns.left_out)} directions are null, because the registration absorbs a "
                "rigid motion of the whole robot that its own parameters can also make (a turn "
                "about the first joint's axis, a translation of the carriage), the tracker sees "
                "the platform only through the reflectors (moving the spherical joints and the "
                "reflectors together on the platform changes nothing measured), and leg data "
                "have six null directions of their own. One parameter per direction is held; "
                "the tool pose in the tracker frame does not depend on the choice "
                "(docs/tracker.md)." + (f" With the effects, {held.removeprefix('; ')}."
                                        if held else ""))

    def to_dict(self) -> dict[str, Any]:
        hidden, total = self.hidden_counts()
        reg = self.registration_rows()
        d_nom, a_nom, d_guess, a_guess = self.registration_change()
        return self._summary(self.setup.kind, {
            "cost_mm2": self.costs(), "point_residuals_mm": self.residuals(),
            "points_hidden": hidden, "points_expected": total,
            "registration": {label: pose.tolist() for label, pose in reg},
            "registration_change": {"from_nominal_mm": d_nom, "from_nominal_deg": a_nom,
                                    "from_guess_mm": d_guess, "from_guess_deg": a_guess}})

    # -- text -----------------------------------------------------------------------------------
    def _accuracy_line(self, label: str, e: Any) -> str:
        pos = _nanstats(e.position)
        ori = _nanstats(e.orientation)
        o = (f"orientation RMS {ori['rms']:.5f} deg ({ori['n']} poses)" if ori["n"]
             else "no orientation (fewer than 3 points per pose)")
        return (f"  {label:<36} position RMS {pos['rms']:.4f} mm, max {pos['max']:.4f} mm; {o}")

    def change_text(self) -> str:
        return self.improvement()[2]

    @property
    def guess(self) -> Any:
        """The closed-form registration guess the identification started from."""
        return self.start

    @property
    def readings_name(self) -> str:
        return str(self.sources.get("readings", ""))

    def summary(self) -> str:
        r = self.result
        acc = self.accuracy
        where = "held-out" if self.held_out else "identification (no poses held out)"
        hidden, total = self.hidden_counts()
        ns = self.identifiability
        d_nom, a_nom, d_guess, a_guess = self.registration_change()
        c = self.costs()
        lines = [
            f"method {r.get('method', '?')}: {int(r.nfev)} evaluations, "
            f"{float(r.get('wall_time', math.nan)):.2f} s, {self.status_text()} "
            f"({str(r.message).strip() if not self._fit_failed() else 'see the fit test below'})",
            f"cost (sum of squared point residuals, mm^2, {len(self.identification)} poses"
            f"{self.unused_included()}): "
            f"nominal robot + registration guess {c['nominal']:.6g} -> calibrated "
            f"{c['calibrated']:.6g}",
            self.hidden_text(),
            f"registration found: {_fmt(d_nom, '.4g')} mm and {_fmt(a_nom, '.4g')} deg from the "
            f"nominal, {_fmt(d_guess, '.4g')} mm and {_fmt(a_guess, '.4g')} deg from the "
            "closed-form guess",
        ]
        if ns is not None:
            lines.append(f"identifiability: rank {ns.rank} of {len(ns.parameter_names)}, "
                         f"{len(ns.left_out)} null directions (docs/tracker.md)" + self._held())
        lines += self.effect_lines()
        lines += [
            f"accuracy on {acc.n_poses} {where} poses: largest predicted-minus-measured point "
            "distance per pose, and the rotation between predicted and measured points:",
            self._accuracy_line("nominal robot + registration guess", acc.nominal),
            self._accuracy_line("calibrated", acc.calibrated),
        ]
        fit = self.fit_lines()
        if fit:
            lines += fit
        if self.diagnosis is not None:
            lines += self.diagnosis.lines()
        if self._fit_failed():
            lines.append(self.no_fit_verdict("the figures above"))
        lines.extend(self.notes)
        return "\n".join(lines)

    def _residual_rows(self) -> tuple[list[str], list[list[str]]]:
        res = self.residuals()
        head = ["point"]
        for s in res:
            head += [f"{s}: seen / hidden", f"{s}: RMS before (mm)", f"{s}: RMS after (mm)",
                     f"{s}: max after (mm)"]
        rows = []
        for i, label in enumerate(self.point_labels()):
            row = [label]
            for d in res.values():
                row += [f"{d['seen'][i]} / {d['hidden'][i]}",
                        _fmt(d["nominal"][i]["rms"], ".4f"),
                        _fmt(d["calibrated"][i]["rms"], ".5f"),
                        _fmt(d["calibrated"][i]["max"], ".5f")]
            rows.append(row)
        return head, rows

    def _registration_table(self) -> tuple[list[str], list[list[str]]]:
        head = ["registration ({0} in {T})", "x (mm)", "y (mm)", "z (mm)", "alpha (deg)",
                "beta (deg)", "gamma (deg)"]
        rows = [[label] + [f"{v:.3f}" for v in pose[:3]]
                + [f"{math.degrees(v):.4f}" for v in pose[3:]]
                for label, pose in self.registration_rows()]
        return head, rows

    def _registration_text(self) -> str:
        d_nom, a_nom, d_guess, a_guess = self.registration_change()
        return (f"The identified registration is {_fmt(d_nom, '.4g')} mm and "
                f"{_fmt(a_nom, '.4g')} degrees from the nominal one (the relative transform, at "
                f"{{0}}'s origin), and {_fmt(d_guess, '.4g')} mm and {_fmt(a_guess, '.4g')} "
                "degrees from the closed-form guess it started from. It is the registration "
                "paired with the identified robot: a turn of the whole robot about its first "
                "joint's axis, or a shift of the carriage, is shared between the two (the null "
                "directions below).")

    def html(self, figures: dict[str, bytes] | None = None) -> Page:
        figures = figures or {}
        r = self.result
        s = self.setup
        page = Page("Calibration report: laser-tracker data")
        hidden, total = self.hidden_counts()
        what = (f"points of {s.n_reflectors} reflector(s)" if s.kind == "points"
                else "6-DOF probe poses")
        page.paragraph(
            f"Robot {self.robot.name}{_src(self.robot_name)}, data{_src(self.data_name)}"
            + (f" with the readings{_src(self.readings_name)}" if self.readings_name else "")
            + f": {what} in the tracker frame {{T}}; {len(self.identification)} poses for "
            "identification, " + (f"{len(self.validation)} held out for validation; "
                                  if self.held_out else "none held out; ")
            + self.hidden_text() + ".", "muted")
        page.heading("Summary")
        text, grade = self.verdict()
        page.verdict(text, grade)
        head = ["robot", "point residual RMS (mm)", "point residual max (mm)",
                "rotation RMS (deg)", "rotation max (deg)"]
        rows = []
        for label, e in (("nominal + registration guess", self.accuracy.nominal),
                         ("calibrated", self.accuracy.calibrated)):
            p, o = _nanstats(e.position), _nanstats(e.orientation)
            rows.append([label, _fmt(p["rms"], ".4g"), _fmt(p["max"], ".4g"),
                         _fmt(o["rms"], ".4g"), _fmt(o["max"], ".4g")])
        page.table((head, rows), "num")
        if self.predicted is not None:
            page.paragraph(self.predicted_text())
        c = self.costs()
        page.paragraph(
            "Per pose: the largest distance between a predicted and a measured point, and the "
            "angle of the best rigid rotation between them (fewer than 3 points seen: none). "
            f"Cost (sum of squared point residuals, mm^2): nominal robot with the registration "
            f"guess {c['nominal']:.6g}, calibrated {c['calibrated']:.6g}. Method "
            f"{r.get('method', '?')}: {int(r.nfev)} evaluations, "
            f"{float(r.get('wall_time', math.nan)):.2f} s, {self.status_text()}"
            + (" (see the fit test)." if self._fit_failed()
               else f": {str(r.message).strip().rstrip('.')}."))
        self._fit_section(page, "Fit test")
        if self.diagnosis is not None:
            self._diagnosis_html(page)
        if "accuracy.png" in figures:
            page.figure(figures["accuracy.png"], "Point residuals per pose before and after "
                        "calibration", "accuracy.png")
        page.heading("Registration")
        page.table(self._registration_table(), "num")
        page.paragraph(self._registration_text())
        page.heading("Reflector offsets" if s.kind == "points" else "Probe offset")
        page.table((["", "nominal in {5}", "identified offset", "identified in {5}",
                     "offset size"], self.offset_rows()), "num")
        what = "the reflectors" if s.kind == "points" else "the probe"
        page.paragraph("Offsets in mm in the platform frame {5}"
                       + ("" if s.kind == "points" else " (the probe's rotation in degrees: "
                          "the offset as a rotation vector, the poses as Z-Y-X Euler angles)")
                       + f". A common rigid motion of {what} and the spherical joints is a null "
                       f"direction: only {what}' position relative to the joints is determined.")
        page.heading("Point residuals")
        page.table(self._residual_rows(), "num")
        if "residuals.png" in figures:
            page.figure(figures["residuals.png"], "Point residuals per "
                        + ("reflector" if s.kind == "points" else "probe point")
                        + " before and after calibration", "residuals.png")
        page.heading("Identified parameters")
        unc = self.uncertainty
        if unc is not None:
            page.paragraph(f"Standard deviations: {unc.describe()}.")
        page.table(self.parameter_table(), "params")
        self._effects_html(page, _EFFECTS_OBJECTIVE)
        ns = self.identifiability
        if ns is not None:
            page.heading("Identifiability")
            page.paragraph(self.null_sentence())
            page.pre(self.null_text())
        return self._html_tail(page, [
            "calibrated.toml: the calibrated robot with its calibrated [tracker] table",
            "result.json: the identification result (iwr.load_result)",
            "accuracy.json: the accuracy figures", "summary.json: the figures of this report",
            "report.md: this report as Markdown", *figures])

    def markdown(self, figures: list[str]) -> str:
        r = self.result
        c = self.costs()
        hidden, total = self.hidden_counts()

        def table(head: list[str], rows: list[list[str]]) -> list[str]:
            return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head),
                    *["| " + " | ".join(row) + " |" for row in rows]]

        md = ["# Calibration report: laser-tracker data", "", f"**{self.verdict()[0]}**", "",
              f"- Robot: `{self.robot.name}`{_src(self.robot_name)}",
              f"- Data{_src(self.data_name)}"
              + (f" + readings{_src(self.readings_name)}" if self.readings_name else "")
              + f": {self.setup.kind}, {len(self.identification)} poses for identification"
              + f"{self.left_out_text()}, "
              + (f"{len(self.validation)} held out" if self.held_out else "none held out")
              + "; " + self.hidden_text(),
              f"- Method: `{r.get('method', '?')}`, {int(r.nfev)} evaluations, "
              f"{self.status_text()}: {str(r.message).strip()}",
              f"- Cost (sum of squared point residuals, mm^2): nominal robot + registration guess "
              f"{c['nominal']:.6g}, calibrated {c['calibrated']:.6g}", "", "## Accuracy", "",
              "```", self.summary(), "```"]
        if self.predicted is not None:
            md += ["", self.predicted_text()]
        md += self._diagnosis_md()
        if "accuracy.png" in figures:
            md += ["", "![Point residuals per pose](accuracy.png)"]
        md += ["", "## Registration", "", *table(*self._registration_table()), "",
               self._registration_text(), "", "## Offsets", "",
               *table(["", "nominal in {5}", "identified offset", "identified in {5}",
                       "offset size"], self.offset_rows()),
               "", "## Point residuals", "", *table(*self._residual_rows())]
        if "residuals.png" in figures:
            md += ["", "![Point residuals per reflector](residuals.png)"]
        md += ["", "## Identified parameters", "",
               *table(*self.parameter_table())]
        md += self._effects_md()
        if self.identifiability is not None:
            md += ["", "## Identifiability", "", self.null_sentence(), "", "```",
                   self.null_text(), "```"]
        md += self._tail_md(["- `calibrated.toml`, `result.json`, `accuracy.json`, "
                             "`summary.json`, `report.html`"], figures)
        return "\n".join(md) + "\n"

    # -- figures --------------------------------------------------------------------------------
    def _plot_residuals(self) -> Any:
        data = self.validation if self.held_out else self.identification
        which = "validation" if self.held_out else "identification"
        d = self.point_distances(data)
        labels = (list(self.setup.names) if self.setup.kind == "points"
                  else ["origin", "x axis", "y axis", "z axis"])
        fig = new_figure(10, 4)
        axes = fig.subplots(1, 2)
        for ax, v, title, unit in ((axes[0], d["nominal"], "nominal robot + registration guess",
                                    "mm"),
                                   (axes[1], d["calibrated"] * 1000.0, "calibrated", "um")):
            cols = [v[:, i][np.isfinite(v[:, i])] for i in range(v.shape[1])]
            ax.boxplot(cols)
            ax.set_xticks(range(1, len(cols) + 1), labels)
            ax.set_xlabel("reflector" if self.setup.kind == "points" else
                          f"probe point (axis points {self.setup.probe_length:g} mm out)")
            ax.set_ylabel(f"distance ({unit})")
            ax.set_title(title)
            ax.set_ylim(bottom=0)
        fig.suptitle(f"Point residuals |predicted - measured| on {len(data)} {which} poses")
        fig.tight_layout()
        return fig

    def _plot_accuracy(self) -> Any:
        a = self.accuracy
        fig = new_figure(10, 6.5)
        axes = fig.subplots(2, 2)
        (pu, pf), (ou, of) = before_units(a.nominal.position, a.nominal.orientation)
        panels = [
            (axes[0, 0], np.asarray(a.nominal.position, dtype=float) * pf, pu,
             "largest point residual", "nominal + registration guess"),
            (axes[0, 1], a.calibrated.position * 1000.0, "um", "largest point residual",
             "calibrated"),
            (axes[1, 0], np.asarray(a.nominal.orientation, dtype=float) * of, ou, "rotation",
             "nominal + registration guess"),
            (axes[1, 1], a.calibrated.orientation * 3600.0, "arcsec", "rotation", "calibrated"),
        ]
        for ax, v, unit, what, title in panels:
            v = np.asarray(v, dtype=float)
            v = v[np.isfinite(v)]
            if v.size:
                histogram(ax, v, "C0" if "nominal" in title else "C2")
                ax.set_title(f"{title}: RMS {math.sqrt(np.mean(v**2)):.3g} {unit}")
            else:
                ax.text(0.5, 0.5, "no pose with 3 points seen", ha="center", va="center",
                        transform=ax.transAxes)
                ax.set_title(title)
            ax.set_xlabel(f"{what} ({unit})")
            ax.set_ylabel("poses")
        fig.suptitle(f"Point residuals per pose on {a.n_poses} "
                     f"{'validation' if self.held_out else 'identification'} poses")
        fig.tight_layout()
        return fig

    # -- files ----------------------------------------------------------------------------------
    def _write_files(self, out: Path, plots: bool) -> list[Path]:
        """``calibrated.toml`` (the calibrated robot with its calibrated ``[tracker]`` table),
        ``result.json``, ``accuracy.json``, ``summary.json``, the figures and the report
        (``report.html``, ``report.md``) into ``out``; returns the paths written."""
        # The same model with {5} moved to the frame the measured points fix (the data do not
        # fix {5}): a pose of {5} in {T} then means what a user measures (iwr legs); with
        # effects, their identified values and the platform's centre of mass moved with {5}.
        calibrated, extra = self.calibrated_file()
        written = [out / "calibrated.toml", out / "result.json", out / "accuracy.json"]
        calibrated.to_toml(written[0], provenance=self.file_provenance(**extra))
        self.result.save(written[1])
        atomic_write_text(written[2], json.dumps(jsonable(self.accuracy.to_dict(),
                                                          finite_only=True), indent=1) + "\n")
        return written + self._write_report(out, plots)
