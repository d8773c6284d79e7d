"""The calibration report: what ``iwr calibrate`` prints and writes (Markdown, PNG, JSON)."""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import asdict, fields
from pathlib import Path
from typing import Any

import numpy as np

from .._io import atomic_write_bytes, atomic_write_text, jsonable, write_folder
from ..calibration import LEVEL, NOT_CALIBRATED, WORSE, Calibration, Judgement
from ..effects import parameter_names as effect_parameter_names
from ..fit_test import CANNOT_IDENTIFY, CHI2_CAUSE_HEAD
from ..kinds import reuse
from ..measurements import Measurements
from ..problem import Problem, predict_legs
from ..robot import Robot
from ..robot_fingerprint import fingerprint as robot_fingerprint
from .figures import before_units, histogram, new_figure, png_bytes
from .html import Page, provenance_table, write_page
from .tables import Table, markdown_table

__all__ = ["CalibrationReport", "leg_residual_stats", "render", "NOT_CALIBRATED", "OUTPUT_FILES"]

#: Every file :meth:`CalibrationReport.write` may write into its folder (any kind of data).
OUTPUT_FILES = ("calibrated.toml", "result.json", "accuracy.json", "summary.json",
                "residuals.png", "accuracy.png", "report.md", "report.html")


#: The settings table's label of a setting whose name alone is ambiguous (``summary.json`` keeps
#: the name).
_SETTING_LABELS = {"seed": "seed (validation split and stochastic methods)"}


def leg_residual_stats(robot: Robot, errors: Any, data: Measurements) -> dict[str, np.ndarray]:
    """Per-leg statistics of the unweighted residuals ``predicted - measured`` (mm).

    Returns ``{"rms": (6,), "max": (6,), "mean": (6,)}`` (``max`` of the absolute value).
    A robot with effects: ``errors`` holds the effects' parameters too, and the readings are
    predicted under each pose's load and temperature.
    """
    r = _predicted_legs(robot, errors, data) - data.legs
    return {
        "mean": r.mean(axis=0),
        "rms": np.sqrt(np.mean(r**2, axis=0)),
        "max": np.abs(r).max(axis=0),
    }


def _predicted_legs(robot: Robot, x: Any, data: Measurements) -> np.ndarray:
    """The leg readings predicted at ``data``'s poses: with the effects when the robot has some
    (issue 23: ``x`` then holds their parameters after the geometric errors)."""
    if robot.effects:
        from ..effects.model import predicted_readings

        return predicted_readings(robot, x, data.q, data.poses, data)
    return predict_legs(robot, x, data.q, data.poses)


def _n_all(robot: Robot) -> int:
    """The robot's geometric errors plus its effects' parameters."""
    return robot.n_params + len(effect_parameter_names(robot.effects))


def render(cal: Calibration) -> CalibrationReport:
    """The report of a calibration job: the class its kind names
    (:attr:`iwr.kinds.MeasurementKind.report`), sharing the job's problems."""
    import importlib

    if not cal.kind.report:
        raise TypeError(f"{cal.kind.name} data: no calibration report yet (the Python API "
                        "iwr.calibrate takes them; docs/kinds.md)")
    module, _, name = cal.kind.report.partition(":")
    cls = getattr(importlib.import_module(module), name)
    if not (isinstance(cls, type) and issubclass(cls, CalibrationReport)):
        raise TypeError(f"kind {cal.kind.name!r}: report {cal.kind.report!r} is not a "
                        "CalibrationReport")
    return cls(**{f.name: getattr(cal, f.name) for f in fields(Calibration)})


class CalibrationReport(Calibration):
    """What a calibration job (:class:`iwr.calibration.Calibration`) prints and writes: the
    summary, ``calibrated.toml``, ``result.json``, ``summary.json``, the figures and the report
    (``report.html``, ``report.md``); a kind's report (:attr:`iwr.kinds.MeasurementKind.report`)
    subclasses it with what belongs to its data. Made by :func:`render`.

    The result's ``fit`` (:class:`iwr.estimation.FitTest`) and ``outliers``, when present, are
    reported: a fit that fails makes the verdict "the model does not fit the data".
    """

    # -- numbers --------------------------------------------------------------------------------
    def costs(self) -> dict[str, float]:
        """Cost of eq. (10) on the identification poses, nominal and calibrated (mm^2)."""
        if self.robot.effects:  # issue 23: eq. (10) with the effects
            from ..effects.problem import EffectProblem

            p: Any = EffectProblem(self.robot, self.identification)
        else:
            p = Problem(self.robot, self.identification)
        nominal = p.cost(np.zeros(_n_all(self.robot)))
        # Evaluated here, not read from the result: the fun of a noise-weighted objective (the
        # efficient estimator's, weighted LM's, a weighted iwr-calibrate run's) is its
        # chi-square statistic, and a result file does not keep eq. (10)'s cost beside it.
        return {"nominal": nominal, "calibrated": p.cost(np.asarray(self.result.x, dtype=float))}

    def unused_included(self) -> str:
        """``", the 1 pose the fit did not use included"``, or ``""``: the identification set
        holds poses the result did not use (``result["used"]`` False: the efficient estimator
        leaves its outliers out of its fit), and the cost and residual figures of the set
        include them. The job's screen takes such poses out of the set for every method
        (:func:`iwr.gross_errors.screen`); a calibration assembled otherwise says so here."""
        used = self.result.get("used")
        if used is None or np.size(used) != len(self.identification):
            return ""
        k = int(np.size(used) - np.count_nonzero(used))
        if k == 0:
            return ""
        return f", the {k} pose{'s' if k > 1 else ''} the fit did not use included"

    def left_out_text(self) -> str:
        """``" (1 more left out as gross error)"``, or ``""``: the identification poses the
        gross-error screen left out of the fit (``result.left_out``), which the identification
        count beside it does not include."""
        k = sum(1 for o in self.result.left_out if o.data_set == "identification")
        w = self.weightless
        parts = ([f"{k} more left out as gross error{'s' if k > 1 else ''}"] if k else []) + (
            [f"{w}{'' if k else ' more'} with weight 0 for every reading, left out"] if w else [])
        return f" ({', '.join(parts)})" if parts else ""

    def residuals(self) -> dict[str, dict[str, dict[str, np.ndarray]]]:
        """Per-leg residual statistics, ``[set][nominal|calibrated]``."""
        sets = {"identification": self.identification}
        if self.held_out:
            sets["validation"] = self.validation
        zero = np.zeros(_n_all(self.robot))
        return {
            name: {
                "nominal": leg_residual_stats(self.robot, zero, data),
                "calibrated": leg_residual_stats(self.robot, self.result.x, data),
            }
            for name, data in sets.items()
        }

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able summary (``summary.json``)."""
        res = {
            s: {m: {k: v.tolist() for k, v in st.items()} for m, st in d.items()}
            for s, d in self.residuals().items()
        }
        out: dict[str, Any] = {
            "format": "iwr-calibration-summary",
            "version": 1,
            "data_kind": "pose",  # every kind's summary names its kind (setup_parameters.py)
            "robot": self.robot_name or self.robot.name,
            "robot_model": robot_fingerprint(self.robot),
            "data": self.data_name,
            "n_identification": len(self.identification),
            "n_validation": len(self.validation) if self.held_out else 0,
            "n_weightless": self.weightless,  # weight 0 for every reading: in no set
            "method": self.result.method,
            "nfev": int(self.result.nfev),
            "wall_time": float(self.result.wall_time),
            "cost": self.costs(),
            "leg_residuals_mm": res,
            "accuracy": self.accuracy.to_dict(),
            "accuracy_on": "validation poses" if self.held_out else "identification poses",
        }
        if self.truth_accuracy is not None:
            out["accuracy_with_true_errors"] = self.truth_accuracy.calibrated.summary()
        rep = self.identifiability
        if rep is not None:
            out["identifiability"] = {
                "rank": int(rep.rank), "n_params": _n_all(self.robot),
                "condition_number": float(rep.condition_number),
                "left_out": list(rep.left_out),
            }
        out["parameters"] = self.parameter_rows()
        if self.robot.effects:
            out["effects"] = self.effect_rows()
        if self.diagnosis is not None:
            out["diagnosis"] = self.diagnosis.to_dict()
        if self.uncertainty is not None:
            out["noise_sigma_mm"] = float(self.uncertainty.sigma)
            out["noise_sigma_source"] = self.uncertainty.source
        if self.parameter_error is not None:
            pe = self.parameter_error
            out["parameter_error_vs_truth"] = {
                "rms_length_mm": float(pe.rms_length), "rms_angle_rad": float(pe.rms_angle),
                "max_abs_length_mm": float(pe.max_abs_length),
                "max_abs_angle_rad": float(pe.max_abs_angle),
            }
        self._add_fit(out)
        return jsonable(out, finite_only=True)

    # -- fit, outliers, prediction ----------------------------------------------------------------
    def _add_fit(self, out: dict[str, Any]) -> None:
        """The fit test, the outliers (identification and held-out poses), the gross-error
        test's description and the predicted accuracy, into a summary.json dict."""
        fit = self.result.fit
        if fit is not None:
            out["fit"] = fit.to_dict()
        if self.result.outliers is not None:
            out["outliers"] = [asdict(o) for o in self.result["outliers"]]
        if self.result.gross_errors:
            out["gross_errors"] = str(self.result["gross_errors"])
        if self.predicted is not None:
            pr = self.predicted
            out["predicted_accuracy"] = {
                "on": "validation poses" if self.held_out else "identification poses",
                "position_rms_mm": pr.position_rms, "position_95_mm": pr.position_95,
                "orientation_rms_deg": pr.orientation_rms,
                "orientation_95_deg": pr.orientation_95}

    def status_text(self) -> str:
        """``converged`` only for a success; otherwise what happened."""
        r = self.result
        if r.success:
            return "converged"
        if r.status == NOT_CALIBRATED:
            return NOT_CALIBRATED
        fit = r.fit
        if fit is not None and not fit.fit_ok:
            if r.status == "stopped":  # iwr.calibration.STOPPED_CAUSE: first run longer
                return "not converged (status stopped), and its best point does not fit the data"
            return "the model does not fit the data"
        return f"not converged (status {r.get('status', '?')})"

    def _fit_failed(self) -> bool:
        fit = self.result.fit
        return fit is not None and not fit.fit_ok

    def fit_lines(self) -> list[str]:
        """The fit test, the outliers and what was done with them, the predicted accuracy."""
        lines: list[str] = []
        fit = self.result.fit
        if fit is not None:
            head = "fit test: " + fit.verdict
            # Once: the verdict of a chi-square test already gives these (FitTest.verdict).
            if fit.dof > 0 and math.isfinite(fit.statistic) and "chi2 =" not in fit.verdict:
                head += (f" [statistic {fit.statistic:.4g}, dof {fit.dof}, "
                         f"p-value {fit.p_value:.3g}]")
            lines.append(head)
            lines += [f"  - {c}" for c in fit.causes]
        for c in self.result.variance_components or []:
            lines.append(
                f"noise of {c.name} estimated: {c.sigma:.3g} (+- {c.std:.2g}; start {c.start:.3g})"
                if c.identified else f"noise of {c.name}: not identified from the data, held at "
                f"{c.start:.3g}")
        outliers = self.result.outliers
        if outliers is not None:
            held = "" if self.held_out else " (no pose held out)"
            if not outliers:
                lines.append(f"outliers: none (every pose passes its test, the held-out ones "
                             f"too{held})")
            else:
                ident = [o for o in outliers if o.data_set != "validation"]
                n_rm = sum(o.removed for o in ident)
                n_val = len(outliers) - len(ident)
                lines.append(
                    f"outliers: {len(outliers)} pose(s) fail their test: {len(ident)} of the "
                    f"identification poses ({n_rm} removed from the solution, "
                    f"{len(ident) - n_rm} kept), {n_val} held out (left out of the accuracy "
                    "figures); check each line named:")
                lines += [f"  - {o}" for o in outliers]
            rate = self.result.gross_errors
            if rate:
                lines.append(f"  - {rate}")
        return lines

    def _fit_section(self, page: Page, title: str) -> None:
        """The fit lines as text that wraps (a <pre> of one long cause runs off the page): the
        top-level lines as paragraphs, their indented details as a list under each."""
        lines = self.fit_lines()
        if not lines:
            return
        page.heading(title)
        details: list[str] = []
        for line in lines + [""]:
            if line.startswith("  "):
                details.append(line.strip().removeprefix("- "))
                continue
            if details:
                page.items(details)
                details = []
            if line:
                page.paragraph(line)

    def predicted_line(self) -> str:
        pr = self.predicted
        if pr is None:
            return ""
        # Not in the table's columns: against the truth, while the measured figures also hold
        # the measurement noise of the poses.
        return (f"predicted by the estimator's covariance, against the truth (not comparable "
                f"with the measured figures above, which also hold the poses' measurement "
                f"noise): position RMS {pr.position_rms:.4f} mm (95 % {pr.position_95:.4f} mm), "
                f"orientation RMS {pr.orientation_rms:.5f} deg (95 % {pr.orientation_95:.5f} "
                "deg)")

    # What the measured figures next to the prediction hold besides the model's error.
    _measured_also = ("the measured figures above also contain the measurement noise of the "
                      "{where} poses")

    def predicted_text(self) -> str:
        """The efficient estimator's predicted tool accuracy as a sentence for the reports, beside
        the measured figures (HTML and Markdown alike)."""
        pr = self.predicted
        where = "validation" if self.held_out else "identification"
        return (f"Predicted by the estimator's covariance (against the truth, on the {where} "
                f"poses): tool position RMS {pr.position_rms:.4g} mm (95 %: "
                f"{pr.position_95:.4g} mm), orientation RMS {pr.orientation_rms:.4g} deg (95 %: "
                f"{pr.orientation_95:.4g} deg); "
                + self._measured_also.format(where=where) + ".")

    def parameter_rows(self) -> list[dict[str, Any]]:
        """One row per error parameter: name, value, std (None if not identified), unit, status."""
        active = self.result.active
        # A result read from a file does not record the active parameters: all of them then.
        active = np.ones(self.robot.n_params, bool) if active is None else np.asarray(active)
        left_out = set(self.identifiability.left_out) if self.identifiability is not None else set()
        std = self.uncertainty.std if self.uncertainty is not None else None
        rows = []
        # The geometric errors (a robot with effects: its effects' rows are effect_rows()).
        x = np.asarray(self.result.x, dtype=float)[: self.robot.n_params]
        for i, (name, value, angle) in enumerate(zip(
                self.robot.parameter_names, x, self.robot.angle_parameters, strict=True)):
            if not active[i]:
                status = "held at nominal (not identifiable)" if name in left_out else "held fixed"
            elif name in left_out:
                status = "identified, but not identifiable: arbitrary"
            else:
                status = "identified"
            sd = None if std is None or not np.isfinite(std[i]) else float(std[i])
            rows.append({"name": name, "value": float(value), "std": sd,
                         "unit": "rad" if angle else "mm", "status": status})
        return rows

    def effect_rows(self) -> list[dict[str, Any]]:
        """One row per effect parameter (issue 23): name, the robot file's value, the identified
        correction and value, unit, the plausible range of the value, and its status
        (identified, or inseparable from the geometry at these poses and loads and held at the
        file's value)."""
        rows: list[dict[str, Any]] = []
        x = np.asarray(self.result.x, dtype=float)[self.robot.n_params:]
        n = self.robot.n_params
        active = self.result.active
        active = np.ones(n + x.size, bool) if active is None else np.asarray(active, bool)
        rep = self.identifiability
        inseparable = dict(getattr(rep, "inseparable", []) or [])
        k = 0
        for e in self.robot.effects:
            lo, hi = e.bounds()
            for name, unit, value, low, high in zip(e.parameter_names(), e.units(), e.values(),
                                                    lo, hi, strict=True):
                if not active[n + k]:
                    status = ("held at the file's value: not separable from the geometry at "
                              "these poses and loads" if name in inseparable else "held fixed")
                elif name in inseparable:
                    status = "identified, but not separable from the geometry: arbitrary"
                else:
                    status = "identified"
                rows.append({"name": name, "effect": e.name, "file_value": float(value),
                             "correction": float(x[k]), "value": float(value + x[k]),
                             "unit": unit, "bounds": [float(value + low), float(value + high)],
                             "status": status})
                k += 1
        return rows

    def effect_lines(self) -> list[str]:
        """The effects' section of the summary (issue 23): what is on and the values."""
        if not self.robot.effects:
            return []
        lines = ["effects on: " + "; ".join(f"{e.name} ({e.description})"
                                            for e in self.robot.effects)]
        for r in self.effect_rows():
            lines.append(f"  {r['name']:17s} {r['value']:+10.4g} {r['unit']:5s} (file "
                         f"{r['file_value']:.4g}; plausible {r['bounds'][0]:.3g} .. "
                         f"{r['bounds'][1]:.3g}): {r['status']}")
        given = [e for e in self.robot.effects if not e.parameter_names()]
        for e in given:
            lines.append(f"  {e.name}: given, not identified ({e.to_dict()})")
        return lines

    # -- text -----------------------------------------------------------------------------------
    def summary(self) -> str:
        """The summary printed by ``iwr calibrate``."""
        r = self.result
        n_id, n_val = len(self.identification), len(self.validation)
        lines = [
            f"robot {self.robot.name!r} ({self.robot.joint_types or 'hexapod alone'}, "
            f"{self.robot.n_params} error parameters){_src(self.robot_name)}; "
            f"data{_src(self.data_name)}",
            f"poses: {n_id} for identification{self.left_out_text()}, "
            + (f"{n_val} held out for validation" if self.held_out else
               "none held out (accuracy below is on the identification poses: optimistic)"),
            f"method {r.get('method', '?')}: {int(r.nfev)} evaluations, "
            f"{float(r.get('wall_time', math.nan)):.2f} s, "
            f"{self.status_text()}"
            + (" (see the fit test below)" if self._fit_failed() else
               f" ({str(r.message).strip()})"),
        ]
        c = self.costs()
        lines.append(
            f"cost (eq. 10, sum of squared leg residuals, mm^2, {n_id} poses"
            f"{self.unused_included()}): "
            f"nominal {c['nominal']:.4g} -> calibrated {c['calibrated']:.4g}"
            + self._before_polish()
        )
        lines.append("")
        lines.append("leg residuals, predicted - measured reading (mm):")
        lines.extend(self._residual_table())
        lines.append("")
        lines.extend(self._identifiability_lines())
        lines.append("")
        on = "validation poses" if self.held_out else "identification poses (optimistic)"
        lines.append(
            f"accuracy on {self.accuracy.n_poses} {on}: tool pose from joint and leg readings "
            "(forward kinematics) against the measured pose"
        )
        lines.append(self.accuracy.table())
        if self.truth_accuracy is not None:
            t = self.truth_accuracy.calibrated.summary()
            lines.append(
                f"{'true errors':18}" + "".join(f"{t['position_mm'][k]:10.4f}"
                                                for k in ("mean", "rms", "max"))
                + "  " + "".join(f"{t['orientation_deg'][k]:10.5f}"
                                 for k in ("mean", "rms", "max"))
                + "   (the simulation's truth: the noise floor)"
            )
        if self.predicted is not None:
            lines.append(self.predicted_line())
        before = self.accuracy.nominal.summary()["position_mm"]["rms"]
        after = self.accuracy.calibrated.summary()["position_mm"]["rms"]
        if after > 0 and not self._fit_failed():
            worse = self.judgement().worse  # larger by more than the poses can tell?
            change = (f"{before / after:.1f} times smaller" if after < before else
                      f"WORSE, {after / before:.2f} times larger" if before > 0 and worse else
                      f"{after / before:.2f} times larger: unchanged (the verdict)"
                      if before > 0 else "")
            lines.append(f"position RMS error {before:.4g} mm -> {after:.4g} mm ({change})")
        fit = self.fit_lines()
        if fit:
            lines.append("")
            lines.extend(fit)
        if self.diagnosis is not None:
            lines.append("")
            lines.extend(self.diagnosis.lines())
        fit_test = r.fit
        if fit_test is not None and not fit_test.fit_ok:
            lines.append(self.no_fit_verdict("the accuracy figures above"))
        lines.extend(self.notes)
        return "\n".join(lines)

    def _before_polish(self) -> str:
        polish = dict(self.result.settings).get("polish_result")
        if isinstance(polish, dict) and "fun_before" in polish:
            return f" (before the Levenberg-Marquardt polish: {polish['fun_before']:.4g})"
        return ""

    def _identifiability_lines(self) -> list[str]:
        rep = self.identifiability
        if rep is None:
            return []
        n = _n_all(self.robot)
        lines = [
            f"identifiability at the starting point (iwr.identifiability, {rep.n_poses} poses): "
            f"rank {rep.rank} of {n}, condition number {rep.condition_number:.4g} (column-scaled "
            "Jacobian)"
        ]
        rows = self.parameter_rows()
        held = [r["name"] for r in rows if r["status"].startswith("held at nominal")]
        arbitrary = [r["name"] for r in rows if r["status"].startswith("identified, but")]
        if held:
            lines.append(f"  not identifiable from leg readings, held at nominal ({len(held)}): "
                         + ", ".join(held))
        if arbitrary:
            lines.append(f"  identified but not identifiable, values arbitrary ({len(arbitrary)}): "
                         + ", ".join(arbitrary))
        if rep.left_out:
            lines.append("  (their errors are absorbed by the others, with no effect on accuracy; "
                         "'iwr analyze' prints the combinations)")
        shown = [r for r in rows if r["status"] == "identified"]
        unc = self.uncertainty
        if unc is not None:
            lines.append(f"identified parameters, value +- standard deviation ({unc.describe()}):")
        else:
            lines.append("identified parameters (no standard deviations: see the notes):")
        cells = []
        for r in shown:
            sd = f" +- {r['std']:8.2e}" if r["std"] is not None else " " * 12
            cells.append(f"{r['name']:15s} {r['value']:+10.3e}{sd} {r['unit']:3s}")
        half = (len(cells) + 1) // 2
        for left, right in itertools.zip_longest(cells[:half], cells[half:], fillvalue=""):
            lines.append(f"  {left}   {right}".rstrip())
        lines.extend(self.effect_lines())
        if hasattr(rep, "inseparable"):  # with effects: separable from the geometry or not
            lines.append("  " + str(rep).splitlines()[-1])
        if self.parameter_error is not None:
            pe = self.parameter_error
            lines.append(
                "error of the identified parameters against the truth, modulo the unidentifiable "
                f"directions: RMS {pe.rms_length:.3g} mm (lengths), {pe.rms_angle:.3g} rad (angles)"
            )
        return lines

    def _residual_table(self) -> list[str]:
        res = self.residuals()
        head = f"{'':8}"
        sub = f"{'':8}"
        for name in res:
            head += f"{name + ' poses':^34}"
            sub += f"{'RMS before':>12}{'RMS after':>11}{'max after':>11}"
        rows = [head.rstrip(), sub]
        for j in range(6):
            row = f"leg {j + 1:<4}"
            for d in res.values():
                row += (f"{d['nominal']['rms'][j]:12.4f}{d['calibrated']['rms'][j]:11.5f}"
                        f"{d['calibrated']['max'][j]:11.5f}")
            rows.append(row)
        return rows

    # -- files ----------------------------------------------------------------------------------
    def write(self, out: str | Path, *, plots: bool = True) -> list[Path]:
        """Write the calibrated robot (TOML), the result (JSON), ``summary.json``, the report
        (``report.html``, self-contained, and ``report.md``) and its figures (PNG) into ``out``,
        as a whole (:func:`iwr._io.write_folder`: the files of an earlier run there are all
        replaced or removed); returns the paths written."""
        with reuse(self.problems):  # the job's problems, not built again
            return write_folder(out, lambda tmp: self._write_files(tmp, plots), OUTPUT_FILES)

    def text(self) -> str:
        """:meth:`summary`, with the job's problems (what a command prints)."""
        with reuse(self.problems):
            return self.summary()

    def _write_files(self, out: Path, plots: bool) -> list[Path]:
        written = []
        calibrated = out / "calibrated.toml"
        robot, extra = self.calibrated_file()
        robot.to_toml(calibrated, provenance=self.file_provenance(**extra))
        written.append(calibrated)
        result = out / "result.json"
        self.result.save(result)
        written.append(result)
        return written + self._write_report(out, plots)

    def file_provenance(self, **extra: Any) -> dict[str, Any]:
        """The ``[provenance]`` table of ``calibrated.toml``: what the file is (``status``,
        :data:`iwr.compensation.CALIBRATION_STATUSES`; ``iwr legs`` refuses any but
        ``success``), how it was made, and from what."""
        from ..compensation import calibration_status
        from ..robot_fingerprint import geometry_fingerprint

        r = self.result
        fit = r.fit
        prov: dict[str, Any] = {
            "status": calibration_status(r),
            "status_detail": " ".join(str(r.message).split()) or str(r.status),
            "fit_test": _fit_record(fit),
            "method": str(r.method),
            "robot": self.robot_name,
            # the nominal geometry the errors are relative to (iwr export --nominal checks it)
            "nominal_geometry": geometry_fingerprint(self.robot),
            "data": self.data_name,
            "cost_mm2": self.costs()["calibrated"],
        }
        if self.provenance is not None:
            prov["iwr_version"] = str(self.provenance.get("iwr_version", ""))
            prov["kernel"] = str(self.provenance.get("kernel", ""))
            prov["date"] = str(self.provenance.get("date", ""))
        prov.update(extra)
        return {k: v for k, v in prov.items() if v != ""}

    def _write_report(self, out: Path, plots: bool) -> list[Path]:
        """``summary.json``, the figures (PNG), ``report.md`` and ``report.html`` into ``out``
        (the part of :meth:`write` common to leg and tracker data); returns the paths written."""
        written = [out / "summary.json"]
        atomic_write_text(written[0], json.dumps(self.to_dict(), indent=1) + "\n")
        figures: dict[str, bytes] = {}
        if plots:
            figures = {"residuals.png": png_bytes(self._plot_residuals(), dpi=110),
                       "accuracy.png": png_bytes(self._plot_accuracy(), dpi=110)}
            for name, png in figures.items():
                atomic_write_bytes(out / name, png)
                written.append(out / name)
        atomic_write_text(out / "report.md", _no_raw_html(self.markdown(list(figures))))
        written.append(out / "report.md")
        written.append(write_page(self.html(figures), out / "report.html"))
        return written

    def verdict(self) -> tuple[str, str]:
        """One sentence on the outcome, and its grade (``good``, ``fair`` or ``bad``); with the
        diagnosis's suggestion when it names an effect (issue 23)."""
        text, grade = self._graded(self.judgement())
        d = self.diagnosis
        if d is not None and d.suggested and d.sentence() not in text:
            text += " " + d.sentence()
        return text, grade

    def no_fit_verdict(self, figures: str) -> str:
        """The summary's last line when the fit test failed: the model does not fit, or (a
        limit stopped the method before it converged, :data:`iwr.calibration.STOPPED_CAUSE`)
        its best point does not."""
        head = ("NOT CONVERGED, AND ITS BEST POINT DOES NOT FIT THE DATA"
                if self.result.status == "stopped" else "THE MODEL DOES NOT FIT THE DATA")
        if self.result.status == NOT_CALIBRATED:
            # Degenerate data or no redundancy: the fit test failed for want of readings, not
            # because the model misses something (it said "does not fit" while the job's exit
            # line said "degenerate data: measure more poses").
            why = str(self.result.message).removeprefix(f"{NOT_CALIBRATED}: ").split(":", 1)[0]
            head = f"NOT CALIBRATED ({why.strip().rstrip('.')})"
        return f"VERDICT: {head}; {figures} are not a calibration (causes listed above)"

    def _graded(self, j: Judgement) -> tuple[str, str]:
        """The verdict from the result's status and fit and the error before and after
        calibration (``j``, :func:`iwr.calibration.judge`: the job's rule)."""
        before, after, change, what = j.before, j.after, j.change, j.what
        r = self.result
        if r.interrupted:
            return (f"Interrupted: the best point so far, not a converged calibration; {change}.",
                    "bad")
        fit = r.fit
        # Data that cannot identify the robot: "not calibrated" (below), not a misfit.
        if fit is not None and not fit.fit_ok and fit.verdict != CANNOT_IDENTIFY:
            head = ("Not converged, and its best point does not fit the data: "
                    if r.status == "stopped" else "The model does not fit the data: ")
            causes = [c.rstrip(".") + "." for c in fit.causes]
            d = self.diagnosis
            if d is not None and d.suggested:
                # The diagnosis names what the geometric model lacks: it leads, in place of the
                # chi-square test's generic list of causes (whose figures the head gives).
                causes = [d.sentence()] + [c for c in causes if not c.startswith(CHI2_CAUSE_HEAD)]
            return (head + fit.verdict.removeprefix("THE MODEL DOES NOT FIT THE DATA: ") + ". "
                    + " ".join(c[:1].upper() + c[1:] for c in causes) + f" ({change}.)", "bad")
        if r.status == NOT_CALIBRATED:
            message = str(r.message).strip().rstrip(".").removeprefix(f"{NOT_CALIBRATED}: ")
            if message.startswith("the calibration did not improve"):
                return f"The calibration did not improve {what}: {change} ({j.evidence()}).", "bad"
            return f"Not calibrated: {message} ({change}).", "bad"
        if not r.success:
            return f"Not converged ({str(r.message).strip().rstrip('.')}); {change}.", "bad"
        if j.worse:
            return f"The calibration did not improve {what}: {change} ({j.evidence()}).", "bad"
        if j.beyond_ratio:  # larger after, but not by more than these poses can tell
            poses = "validation poses" if self.held_out else "poses"
            return (f"Unchanged within what {j.n} {poses} can tell: {change} "
                    f"({j.evidence()}, not significant at {LEVEL:.0%}): the robot given is "
                    "already about as accurate as these data tell (a robot calibrated "
                    "before?); more validation poses tell more.", "fair")
        ratio = before / after if after > 0 else math.inf
        if ratio >= 5:
            return f"Calibrated: {change}: {ratio:.3g} times smaller.", "good"
        if ratio >= WORSE:
            return (f"Improved, but only {ratio:.3g} times: {change}. Check the data and the "
                    "identifiability below.", "fair")
        return (f"Unchanged within {WORSE - 1:.0%}: {change}: the robot given is already as "
                "accurate as these data tell (a robot calibrated before?).", "fair")

    def html(self, figures: dict[str, bytes] | None = None) -> Page:
        """The report as one self-contained HTML page (figures embedded)."""
        figures = figures or {}
        r = self.result
        page = Page("Calibration report")
        page.paragraph(
            f"Robot {self.robot.name}{_src(self.robot_name)}, data{_src(self.data_name)}: "
            f"{len(self.identification)} poses for identification{self.left_out_text()}, "
            + (f"{len(self.validation)} held out for validation." if self.held_out else
               "none held out."), "muted")
        page.heading("Summary")
        text, grade = self.verdict()
        page.verdict(text, grade)
        rows = [("nominal", self.accuracy.nominal.summary()),
                ("calibrated", self.accuracy.calibrated.summary())]
        if self.truth_accuracy is not None:
            rows.append(("true errors (simulation)", self.truth_accuracy.calibrated.summary()))
        head = ["robot", "position RMS (mm)", "position max (mm)", "orientation RMS (deg)",
                "orientation max (deg)"]
        page.table((head, [[label, f"{s['position_mm']['rms']:.4g}",
                            f"{s['position_mm']['max']:.4g}",
                            f"{s['orientation_deg']['rms']:.4g}",
                            f"{s['orientation_deg']['max']:.4g}"] for label, s in rows]), "num")
        c = self.costs()
        page.paragraph(
            f"Tool pose by forward kinematics from the joint and leg readings against the measured "
            f"pose. Cost (eq. 10, mm^2{self.unused_included()}): nominal {c['nominal']:.6g}, "
            "calibrated "
            f"{c['calibrated']:.6g}{self._before_polish()}. Method {r.get('method', '?')}: "
            f"{int(r.nfev)} evaluations, {float(r.get('wall_time', math.nan)):.2f} s, "
            f"{self.status_text()}: "
            f"{str(r.message).strip().rstrip('.')}.")
        if self.predicted is not None:
            page.paragraph(self.predicted_text())
        self._fit_section(page, "Fit test and outliers")
        if self.diagnosis is not None:
            self._diagnosis_html(page)
        if "accuracy.png" in figures:
            page.figure(figures["accuracy.png"], "Tool pose errors before and after calibration",
                        "accuracy.png")
        page.heading("Identified parameters")
        unc = self.uncertainty
        if unc is not None:
            page.paragraph(f"Standard deviations: {unc.describe()}.")
        else:
            page.paragraph("No standard deviations (see the notes).")
        if self.parameter_error is not None:
            pe = self.parameter_error
            page.paragraph("Against the simulation's truth, modulo the unidentifiable "
                           f"directions: RMS error {pe.rms_length:.4g} mm over lengths, "
                           f"{pe.rms_angle:.4g} rad over angles.")
        page.table((["parameter", "value", "std", "unit", "status"],
                    [[row["name"], f"{row['value']:.6g}",
                      "" if row["std"] is None else f"{row['std']:.3g}", row["unit"],
                      row["status"]] for row in self.parameter_rows()]), "params")
        rep = self.identifiability
        if rep is not None:
            page.heading("Identifiability")
            page.paragraph(
                f"The leg readings at these poses determine {rep.rank} of the "
                f"{_n_all(self.robot)} parameters (rank of the column-scaled Jacobian; condition "
                f"number {rep.condition_number:.4g})."
                + (" Parameters left out are held at their nominal value: their errors are "
                   "absorbed by the others, without effect on the accuracy." if rep.left_out
                   else ""))
            page.pre(str(rep).rstrip())
        self._effects_html(page)
        page.heading("Leg residuals")
        res = self.residuals()
        head = ["leg"] + [f"{s} {w}" for s in res
                          for w in ("RMS before (mm)", "RMS after (mm)", "max after (mm)")]
        page.table((head, [[str(j + 1)] + [v for d in res.values() for v in (
            f"{d['nominal']['rms'][j]:.4f}", f"{d['calibrated']['rms'][j]:.5f}",
            f"{d['calibrated']['max'][j]:.5f}")] for j in range(6)]), "num")
        if "residuals.png" in figures:
            page.figure(figures["residuals.png"], "Leg residuals before and after calibration",
                        "residuals.png")
        return self._html_tail(page, [
            "calibrated.toml: the calibrated robot (nominal plus identified errors"
            + (", with the identified effects' values)" if self.robot.effects else ")"),
            "result.json: the identification result (iwr.load_result)",
            "summary.json: the figures of this report", "report.md: this report as Markdown",
            *figures])

    def _effects_md(self) -> list[str]:
        """The effects' section of the Markdown report (issue 23; none without effects)."""
        if not self.robot.effects:
            return []
        md = ["", "## Effects", "", *(f"- {ln.strip()}" for ln in self.effect_lines()[:1]),
              "", "| parameter | value | file value | unit | range | status |",
              "|---|---|---|---|---|---|"]
        return md + [f"| {r['name']} | {r['value']:.5g} | {r['file_value']:.5g} | {r['unit']} | "
                     f"{r['bounds'][0]:.3g} .. {r['bounds'][1]:.3g} | {r['status']} |"
                     for r in self.effect_rows()]

    def _effects_html(self, page: Page, objective: str = "eq. (10) with the effects") -> None:
        """The effects' section (issue 23): the identified values with units and bounds,
        identified on ``objective`` (the kind's words)."""
        if not self.robot.effects:
            return
        page.heading("Effects")
        page.paragraph("Non-geometric effects on: " + "; ".join(
            f"{e.name} ({e.description})" for e in self.robot.effects) + ". Identified with the "
            f"geometry ({objective}); calibrated.toml holds their values. The "
            "range is the plausible one of the robot file.")
        page.table((["parameter", "value", "file value", "unit", "range", "status"],
                    [[r["name"], f"{r['value']:.5g}", f"{r['file_value']:.5g}", r["unit"],
                      f"{r['bounds'][0]:.3g} .. {r['bounds'][1]:.3g}", r["status"]]
                     for r in self.effect_rows()]), "params")
        given = [e for e in self.robot.effects if not e.parameter_names()]
        if given:
            page.items([f"{e.name}: given, not identified: {e.to_dict()}" for e in given])

    def _diagnosis_html(self, page: Page) -> None:
        """The diagnosis of a geometric fit against the loads and temperatures (issue 23)."""
        d = self.diagnosis
        page.heading("Diagnosis: loads and temperatures")
        lines = d.lines()
        page.verdict(d.sentence(),
                     "bad" if d.suggested else "good")
        page.items([ln.strip().removeprefix("- ") for ln in lines[1:]])
        if d.suggested:
            page.paragraph("Add to the robot file and calibrate again:")
            page.pre(d.suggestion())

    def _diagnosis_md(self) -> list[str]:
        """The diagnosis's Markdown section (none without a diagnosis)."""
        d = self.diagnosis
        if d is None:
            return []
        md = ["", "## Diagnosis: loads and temperatures", "", "```", *d.lines(), "```"]
        if d.suggested:
            md += ["", "Add to the robot file and calibrate again:", "", "```toml",
                   d.suggestion(), "```"]
        return md

    def _html_tail(self, page: Page, files: list[str]) -> Page:
        """The end of the HTML report: settings, notes, the files written, provenance."""
        page.heading("Settings")
        page.table(self.settings_table(), "left")
        if self.notes:
            page.heading("Notes").items([n.strip() for n in self.notes])
        page.heading("Files")
        page.items(files)
        if self.provenance is not None:
            page.provenance(self.provenance)
        return page

    def settings_table(self) -> Table:
        """The job's settings and the method's result message: the HTML and Markdown reports'
        "Settings" section, for every kind."""
        return (["setting", "value"], [[_SETTING_LABELS.get(k, k), str(v)]
                                       for k, v in self.settings.items()]
                + [["result", str(self.result.message).strip()]])

    def _tail_md(self, files: list[str], figures: list[str]) -> list[str]:
        """The Markdown report's last sections, the same for every kind and in the HTML
        report's order (:meth:`_html_tail`): the settings, the notes, the files written
        (``files``, then the ``figures``), the provenance."""
        md = ["", "## Settings", "", markdown_table(self.settings_table()).rstrip("\n")]
        if self.notes:
            md += ["", "## Notes", ""] + [f"- {n.strip()}" for n in self.notes]
        md += ["", "## Files", "", *files, *[f"- `{f}`" for f in figures]]
        return md + self._provenance_md()

    def _provenance_md(self) -> list[str]:
        """The Markdown report's provenance section (none without provenance): the HTML
        report's table (:func:`iwr.reporting.html.provenance_table`)."""
        if self.provenance is None:
            return []
        return ["", "## Provenance", "",
                markdown_table(provenance_table(self.provenance)).rstrip("\n")]

    def markdown(self, figures: list[str]) -> str:
        """The report as Markdown (figures referenced by file name)."""
        r = self.result
        c = self.costs()
        md = [
            "# Calibration report",
            "",
            f"**{self.verdict()[0]}**",
            "",
            f"- Robot: `{self.robot.name}`{_src(self.robot_name)}, joints "
            f"`{self.robot.joint_types or '-'}`, {self.robot.n_params} error parameters",
            f"- Data{_src(self.data_name)}: {len(self.identification)} poses for identification"
            f"{self.left_out_text()}, "
            + (f"{len(self.validation)} held out for validation" if self.held_out
               else "none held out (accuracy is on the identification poses: optimistic)"),
            f"- Method: `{r.get('method', '?')}`, {int(r.nfev)} evaluations, "
            f"{float(r.get('wall_time', math.nan)):.2f} s, "
            f"{self.status_text()}: {str(r.message).strip()}",
            f"- Cost (eq. 10, mm^2{self.unused_included()}): nominal {c['nominal']:.6g}, "
            f"calibrated {c['calibrated']:.6g}"
            + self._before_polish(),
            "",
            "## Accuracy",
            "",
            "Tool pose computed by forward kinematics from the joint and leg readings, against the "
            "measured pose, on the "
            + ("validation poses (not used for identification)." if self.held_out
               else "identification poses (nothing was held out: an optimistic figure)."),
            "",
            "| robot | position mean (mm) | position RMS (mm) | position max (mm) "
            "| orientation mean (deg) | orientation RMS (deg) | orientation max (deg) |",
            "|---|---|---|---|---|---|---|",
        ]
        rows = [("nominal", self.accuracy.nominal.summary()),
                ("calibrated", self.accuracy.calibrated.summary())]
        if self.truth_accuracy is not None:
            rows.append(("true errors (simulation)", self.truth_accuracy.calibrated.summary()))
        for label, s in rows:
            p, o = s["position_mm"], s["orientation_deg"]
            md.append(f"| {label} | {p['mean']:.4f} | {p['rms']:.4f} | {p['max']:.4f} | "
                      f"{o['mean']:.5f} | {o['rms']:.5f} | {o['max']:.5f} |")
        if self.predicted is not None:
            md += ["", self.predicted_text()]
        fit_lines = self.fit_lines()
        if fit_lines:
            md += ["", "## Fit test and outliers", "", "```", *fit_lines, "```"]
        md += self._diagnosis_md()
        if "accuracy.png" in figures:
            md += ["", "![Tool pose errors before and after calibration](accuracy.png)"]
        md += ["", "## Leg residuals", "",
               "Predicted minus measured leg reading (mm), per leg.", ""]
        res = self.residuals()
        header = "| leg |" + "".join(
            f" {s} RMS before | {s} RMS after | {s} max after |" for s in res)
        md += [header, "|---|" + "---|---|---|" * len(res)]
        for j in range(6):
            md.append(f"| {j + 1} |" + "".join(
                f" {d['nominal']['rms'][j]:.4f} | {d['calibrated']['rms'][j]:.5f} | "
                f"{d['calibrated']['max'][j]:.5f} |" for d in res.values()))
        if "residuals.png" in figures:
            md += ["", "![Leg residuals before and after calibration](residuals.png)"]
        md += ["", "## Identified parameters", ""]
        rep = self.identifiability
        if rep is not None:
            md.append(
                f"The leg readings at these poses determine {rep.rank} of the "
                f"{_n_all(self.robot)} parameters (rank of the column-scaled Jacobian; condition "
                f"number {rep.condition_number:.4g}). "
                + ("Parameters left out are held at their nominal value: their errors are "
                   "absorbed by the others, without effect on the accuracy." if rep.left_out
                   else "")
            )
            md += ["", "```", str(rep).rstrip(), "```", ""]
        if self.uncertainty is not None:
            unc = self.uncertainty
            md += [f"Standard deviations: {unc.describe()}.", ""]
        if self.parameter_error is not None:
            pe = self.parameter_error
            md += [f"Against the simulation's truth, modulo the unidentifiable directions: RMS "
                   f"error {pe.rms_length:.4g} mm over lengths, {pe.rms_angle:.4g} rad over "
                   "angles.", ""]
        md += ["| parameter | value | std | unit | status |", "|---|---|---|---|---|"]
        for row in self.parameter_rows():
            sd = "" if row["std"] is None else f"{row['std']:.3g}"
            md.append(f"| {row['name']} | {row['value']:.6g} | {sd} | {row['unit']} | "
                      f"{row['status']} |")
        md += self._effects_md()
        md += self._tail_md([
            "- `calibrated.toml`: the calibrated robot (nominal plus identified errors"
            + (", with the identified effects' values)" if self.robot.effects else ")"),
            "- `result.json`: the identification result (`iwr.load_result`)",
            "- `summary.json`: the figures of this report"], figures)
        return "\n".join(md) + "\n"

    def _plot_residuals(self) -> Any:
        data = self.validation if self.held_out else self.identification
        which = "validation" if self.held_out else "identification"
        zero = np.zeros(_n_all(self.robot))
        before = _predicted_legs(self.robot, zero, data) - data.legs
        after = _predicted_legs(self.robot, self.result.x, data) - data.legs
        fig = new_figure(10, 4)
        axes = fig.subplots(1, 2)
        for ax, r, title in ((axes[0], before, "nominal robot"),
                             (axes[1], after * 1000.0, "calibrated robot")):
            ax.boxplot([r[:, j] for j in range(6)])
            ax.set_xticks(range(1, 7), [str(j) for j in range(1, 7)])
            ax.axhline(0.0, color="0.6", lw=0.8)
            ax.set_xlabel("leg")
            ax.set_title(title)
        axes[0].set_ylabel("residual (mm)")
        axes[1].set_ylabel("residual (um)")
        fig.suptitle(f"Leg residuals, predicted - measured, on {len(data)} {which} poses")
        fig.tight_layout()
        return fig

    def _plot_accuracy(self) -> Any:
        fig = new_figure(10, 6.5)
        axes = fig.subplots(2, 2)
        a = self.accuracy
        (pu, pf), (ou, of) = before_units(a.nominal.position, a.nominal.orientation)
        panels = [
            (axes[0, 0], a.nominal.position * pf, pu, "position error", "nominal robot"),
            (axes[0, 1], a.calibrated.position * 1000.0, "um", "position error",
             "calibrated robot"),
            (axes[1, 0], a.nominal.orientation * of, ou, "orientation error", "nominal robot"),
            (axes[1, 1], a.calibrated.orientation * 3600.0, "arcsec", "orientation error",
             "calibrated robot"),
        ]
        for ax, v, unit, what, title in panels:
            histogram(ax, v, "C0" if "nominal" in title else "C2")
            ax.set_xlabel(f"{what} ({unit})")
            ax.set_ylabel("poses")
            ax.set_title(f"{title}: RMS {math.sqrt(np.mean(v**2)):.3g} {unit}")
        fig.suptitle(f"Tool pose errors on {a.n_poses} "
                     f"{'validation' if self.held_out else 'identification'} poses")
        fig.tight_layout()
        return fig


def _no_raw_html(markdown: str) -> str:
    """``markdown`` with ``&``, ``<`` and ``>`` written as entities outside fenced code blocks:
    names and messages from the user's files (robot name, file names, reflector names) never
    become raw HTML in a Markdown viewer. The fences are found as a viewer finds them, so a
    name that closes one is escaped too. (Within a code span an entity shows as written.)"""
    out, fenced = [], False
    for line in markdown.split("\n"):
        if line.lstrip(" ").startswith("```") and len(line) - len(line.lstrip(" ")) <= 3:
            fenced = not fenced
        elif not fenced:
            line = line.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
        out.append(line)
    return "\n".join(out)


def _src(name: str) -> str:
    return f" ({name})" if name else ""


def _fit_record(fit: Any) -> str:
    """The ``fit_test`` of ``calibrated.toml``: "passed" of a stopped run's point says so (the
    test minimises to first order around it, so it passes far from the solution: a run
    stopped after 2 evaluations at 6089 mm^2 recorded "passed")."""
    from ..result import STOPPED_FIT

    if fit is None:
        return "not run"
    if not fit.fit_ok:
        return "failed"
    return ("passed at the point the method stopped (not converged)"
            if str(fit.verdict).startswith(STOPPED_FIT) else "passed")
