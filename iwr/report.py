"""The calibration report: what ``iwr calibrate`` prints and writes (Markdown, PNG, JSON)."""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._io import atomic_write_bytes, atomic_write_text
from .accuracy import Accuracy
from .measurements import Measurements
from .problem import Problem, predict_legs
from .result import IdentificationResult
from .robot import Robot

__all__ = ["Calibration", "leg_residual_stats", "jacobian_rank"]


def leg_residual_stats(robot: Robot, errors: Any, data: Measurements) -> dict[str, np.ndarray]:
    """Per-leg statistics of the unweighted residuals ``predicted - measured`` (mm).

    Returns ``{"rms": (6,), "max": (6,), "mean": (6,)}`` (``max`` of the absolute value).
    """
    r = predict_legs(robot, errors, data.q, data.poses) - data.legs
    return {
        "mean": r.mean(axis=0),
        "rms": np.sqrt(np.mean(r**2, axis=0)),
        "max": np.abs(r).max(axis=0),
    }


def jacobian_rank(problem: Problem, x: Any, rtol: float = 1e-9) -> tuple[int, float]:
    """Numerical rank and condition number of the identification Jacobian at ``x``.

    The columns are scaled to unit norm first, so that millimetres and radians compare; singular
    values below ``rtol`` times the largest count as zero. A basic figure: ``iwr.identifiability``
    (where installed) says which combinations are not identifiable.
    """
    jac = problem.jacobian(x)
    norms = np.linalg.norm(jac, axis=0)
    norms[norms == 0] = 1.0
    s = np.linalg.svd(jac / norms, compute_uv=False)
    rank = int(np.sum(s > rtol * s[0]))
    cond = float(s[0] / s[rank - 1]) if rank else math.inf
    return rank, cond


@dataclass
class Calibration:
    """Everything a calibration run produced, for the summary and the report.

    Attributes
    ----------
    robot : Robot
        The nominal robot.
    identification, validation : Measurements
        The poses used for identification, and the held-out ones (``validation`` may be the
        identification set itself when nothing was held out: ``held_out`` is then False).
    result : IdentificationResult
    accuracy : Accuracy
        On the validation poses.
    """

    robot: Robot
    identification: Measurements
    validation: Measurements
    held_out: bool
    result: IdentificationResult
    accuracy: Accuracy
    data_name: str = ""
    robot_name: str = ""
    rank: tuple[int, float] | None = None
    parameter_table: list[dict[str, Any]] | None = None
    identifiability_text: str | None = None
    truth_accuracy: Accuracy | None = None
    notes: list[str] = field(default_factory=list)

    # -- numbers --------------------------------------------------------------------------------
    def costs(self) -> dict[str, float]:
        """Cost of eq. (10) on the identification poses, nominal and calibrated (mm^2)."""
        p = Problem(self.robot, self.identification)
        return {"nominal": p.cost(np.zeros(self.robot.n_params)), "calibrated": float(self.result.fun)}

    def residuals(self) -> dict[str, dict[str, dict[str, np.ndarray]]]:
        """Per-leg residual statistics, ``[set][nominal|calibrated]``."""
        sets = {"identification": self.identification}
        if self.held_out:
            sets["validation"] = self.validation
        zero = np.zeros(self.robot.n_params)
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
            "robot": self.robot_name or self.robot.name,
            "data": self.data_name,
            "n_identification": len(self.identification),
            "n_validation": len(self.validation) if self.held_out else 0,
            "method": self.result.get("method", ""),
            "nfev": int(self.result.nfev),
            "wall_time": float(self.result.get("wall_time", math.nan)),
            "cost": self.costs(),
            "leg_residuals_mm": res,
            "accuracy": self.accuracy.to_dict(),
            "accuracy_on": "validation poses" if self.held_out else "identification poses",
        }
        if self.truth_accuracy is not None:
            out["accuracy_with_true_errors"] = self.truth_accuracy.calibrated.summary()
        if self.rank is not None:
            out["jacobian_rank"] = {"rank": self.rank[0], "n_params": self.robot.n_params,
                                    "condition_number": self.rank[1]}
        return out

    # -- text -----------------------------------------------------------------------------------
    def summary(self) -> str:
        """The summary printed by ``iwr calibrate``."""
        r = self.result
        n_id, n_val = len(self.identification), len(self.validation)
        lines = [
            f"robot {self.robot.name!r} ({self.robot.joint_types or 'hexapod alone'}, "
            f"{self.robot.n_params} error parameters){_src(self.robot_name)}; "
            f"data{_src(self.data_name)}",
            f"poses: {n_id} for identification, "
            + (f"{n_val} held out for validation" if self.held_out else
               "none held out (accuracy below is on the identification poses: optimistic)"),
            f"method {r.get('method', '?')}: {int(r.nfev)} evaluations, "
            f"{float(r.get('wall_time', math.nan)):.2f} s, {'success' if r.success else 'FAILED'}"
            f" ({str(r.message).strip()})",
        ]
        c = self.costs()
        lines.append(
            f"cost (eq. 10, sum of squared leg residuals, mm^2, {n_id} poses): "
            f"nominal {c['nominal']:.4g} -> calibrated {c['calibrated']:.4g}"
        )
        lines.append("")
        lines.append("leg residuals, predicted - measured reading (mm):")
        lines.extend(self._residual_table())
        if self.rank is not None:
            rank, cond = self.rank
            lines.append("")
            lines.append(
                f"identifiability: the Jacobian has rank {rank} of {self.robot.n_params} "
                f"(unit-norm columns; condition number {cond:.3g}): "
                + (f"{self.robot.n_params - rank} combinations of parameters do not change any "
                   "leg reading; their values in the calibrated robot are arbitrary and harmless"
                   if rank < self.robot.n_params else "every parameter is identifiable")
            )
        if self.identifiability_text:
            lines.append("")
            lines.append(self.identifiability_text.rstrip())
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
        before = self.accuracy.nominal.summary()["position_mm"]["rms"]
        after = self.accuracy.calibrated.summary()["position_mm"]["rms"]
        if after > 0:
            lines.append(f"position RMS error {before:.4g} mm -> {after:.4g} mm "
                         f"({before / after:.1f} times smaller)")
        lines.extend(self.notes)
        return "\n".join(lines)

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
    def write(self, out_dir: str | Path, *, plots: bool = True) -> list[Path]:
        """Write the calibrated robot (TOML), the result (JSON), ``summary.json``, the report
        (Markdown) and its figures (PNG) into ``out_dir``; returns the paths written."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        written = []
        calibrated = out / "calibrated.toml"
        self.robot.with_errors(self.result.x).to_toml(calibrated)
        written.append(calibrated)
        result = out / "result.json"
        self.result.save(result)
        written.append(result)
        summary = out / "summary.json"
        atomic_write_text(summary, json.dumps(self.to_dict(), indent=1) + "\n")
        written.append(summary)
        figures = []
        if plots:
            figures = [self._plot_residuals(out / "residuals.png"),
                       self._plot_accuracy(out / "accuracy.png")]
            written.extend(figures)
        report = out / "report.md"
        atomic_write_text(report, self.markdown([f.name for f in figures]))
        written.append(report)
        return written

    def markdown(self, figures: list[str]) -> str:
        """The report as Markdown (figures referenced by file name)."""
        r = self.result
        c = self.costs()
        md = [
            "# Calibration report",
            "",
            f"- Robot: `{self.robot.name}`{_src(self.robot_name)}, joints "
            f"`{self.robot.joint_types or '-'}`, {self.robot.n_params} error parameters",
            f"- Data{_src(self.data_name)}: {len(self.identification)} poses for identification, "
            + (f"{len(self.validation)} held out for validation" if self.held_out
               else "none held out (accuracy is on the identification poses: optimistic)"),
            f"- Method: `{r.get('method', '?')}`, {int(r.nfev)} evaluations, "
            f"{float(r.get('wall_time', math.nan)):.2f} s, {'success' if r.success else 'failed'}: "
            f"{str(r.message).strip()}",
            f"- Cost (eq. 10, mm^2): nominal {c['nominal']:.6g}, calibrated {c['calibrated']:.6g}",
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
        if self.rank is not None:
            rank, cond = self.rank
            md.append(
                f"The identification Jacobian (unit-norm columns) has rank {rank} of "
                f"{self.robot.n_params}, condition number {cond:.3g}. "
                + (f"{self.robot.n_params - rank} combinations of parameters leave every leg "
                   "reading unchanged: individual values along them are arbitrary, and harmless "
                   "for accuracy." if rank < self.robot.n_params else "")
            )
            md.append("")
        if self.identifiability_text:
            md += ["```", self.identifiability_text.rstrip(), "```", ""]
        table = self.parameter_table or [
            {"name": n, "value": float(v), "unit": "rad" if a else "mm"}
            for n, v, a in zip(self.robot.parameter_names, self.result.x,
                               self.robot.angle_parameters, strict=True)
        ]
        cols = [k for k in table[0] if k != "name"]
        md.append("| parameter | " + " | ".join(cols) + " |")
        md.append("|---|" + "---|" * len(cols))
        for row in table:
            md.append(f"| {row['name']} | " + " | ".join(_fmt(row[k]) for k in cols) + " |")
        md += ["", "## Files", "",
               "- `calibrated.toml`: the calibrated robot (nominal geometry plus identified errors)",
               "- `result.json`: the identification result (`iwr.load_result`)",
               "- `summary.json`: the figures of this report"]
        md += [f"- `{f}`" for f in figures]
        if self.notes:
            md += ["", "## Notes", ""] + [f"- {n.strip()}" for n in self.notes]
        return "\n".join(md) + "\n"

    def _plot_residuals(self, path: Path) -> Path:
        data = self.validation if self.held_out else self.identification
        which = "validation" if self.held_out else "identification"
        zero = np.zeros(self.robot.n_params)
        before = predict_legs(self.robot, zero, data.q, data.poses) - data.legs
        after = predict_legs(self.robot, self.result.x, data.q, data.poses) - data.legs
        from matplotlib.figure import Figure

        fig = Figure(figsize=(10, 4))
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
        return _save(fig, path)

    def _plot_accuracy(self, path: Path) -> Path:
        from matplotlib.figure import Figure

        fig = Figure(figsize=(10, 6.5))
        axes = fig.subplots(2, 2)
        a = self.accuracy
        panels = [
            (axes[0, 0], a.nominal.position, "mm", "position error", "nominal robot"),
            (axes[0, 1], a.calibrated.position * 1000.0, "um", "position error",
             "calibrated robot"),
            (axes[1, 0], a.nominal.orientation, "deg", "orientation error", "nominal robot"),
            (axes[1, 1], a.calibrated.orientation * 3600.0, "arcsec", "orientation error",
             "calibrated robot"),
        ]
        for ax, v, unit, what, title in panels:
            ax.hist(v, bins=min(30, max(5, v.size // 3)), color="C0" if "nominal" in title else "C2")
            ax.set_xlabel(f"{what} ({unit})")
            ax.set_ylabel("poses")
            ax.set_title(f"{title}: RMS {math.sqrt(np.mean(v**2)):.3g} {unit}")
        fig.suptitle(f"Tool pose errors on {a.n_poses} "
                     f"{'validation' if self.held_out else 'identification'} poses")
        fig.tight_layout()
        return _save(fig, path)


def _src(name: str) -> str:
    return f" ({name})" if name else ""


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)


def _save(fig: Any, path: Path) -> Path:
    # A bare Figure (no pyplot): no GUI backend, no global state, nothing to close.
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    atomic_write_bytes(path, buf.getvalue())
    return path
