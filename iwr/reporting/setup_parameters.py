"""What the reports of the kinds with setup parameters share: the parameters identified beside
the robot's (a tracker's registration and offsets, a ballbar's balls and offsets), their rows
with standard deviations and status, and the null directions in words."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..robot_fingerprint import fingerprint as robot_fingerprint

__all__ = ["SetupParameters"]


class SetupParameters:
    """A mix-in of a :class:`iwr.reporting.calibration.CalibrationReport` whose kind identifies
    setup parameters (``self.setup``: the robot's set-up of the instrument, with
    ``parameter_names`` and ``angle_parameters``) and whose identifiability is a
    :class:`iwr.tracker.NullSpace`."""

    robot: Any
    result: Any
    identifiability: Any
    uncertainty: Any
    setup: Any

    def _summary(self, kind: str, figures: dict[str, Any]) -> dict[str, Any]:
        """``summary.json``: what every run says (robot, data, method, accuracy, parameters,
        identifiability, noise, fit), with the kind's own ``figures``."""
        from .._io import jsonable

        out: dict[str, Any] = {
            "format": "iwr-calibration-summary", "version": 1, "data_kind": kind,
            "robot": self.robot_name or self.robot.name, "data": self.data_name,  # type: ignore[attr-defined]
            "robot_model": robot_fingerprint(self.robot),  # type: ignore[attr-defined]
            "n_identification": len(self.identification),  # type: ignore[attr-defined]
            "n_validation": len(self.validation) if self.held_out else 0,  # type: ignore[attr-defined]
            "method": self.result.method, "nfev": int(self.result.nfev),
            "wall_time": float(self.result.wall_time),
            "accuracy": self.accuracy.to_dict(),  # type: ignore[attr-defined]
            "accuracy_on": ("validation poses" if self.held_out  # type: ignore[attr-defined]
                            else "identification poses"),
            **figures, "parameters": self.parameter_rows(),
        }
        if self.robot.effects:  # issue 23
            out["effects"] = self.effect_rows()  # type: ignore[attr-defined]
        ns = self.identifiability
        if ns is not None:
            out["identifiability"] = {"rank": int(ns.rank), "n_params": len(ns.parameter_names),
                                      "left_out": list(ns.left_out)}
        if self.diagnosis is not None:  # issue 23: a geometric fit against the loads
            out["diagnosis"] = self.diagnosis.to_dict()  # type: ignore[attr-defined]
        if self.uncertainty is not None:
            out["noise_sigma_mm"] = float(self.uncertainty.sigma)
            out["noise_sigma_source"] = self.uncertainty.source
        self._add_fit(out)  # type: ignore[attr-defined]
        return jsonable(out, finite_only=True)

    def parameter_table(self) -> tuple[list[str], list[list[str]]]:
        """The identified parameters as a table: head and rows."""
        return (["parameter", "value", "std", "unit", "status"],
                [[row["name"], f"{row['value']:.6g}",
                  "" if row["std"] is None else f"{row['std']:.3g}", row["unit"],
                  row["status"]] for row in self.parameter_rows()])

    @property
    def n_robot(self) -> int:
        """The robot's parameters in ``x``: its errors, then its effects' (issue 23)."""
        from ..effects import parameter_names as effect_names

        return self.robot.n_params + len(effect_names(self.robot.effects))

    @property
    def parameter_names(self) -> list[str]:
        from ..effects import parameter_names as effect_names

        return (self.robot.parameter_names + effect_names(self.robot.effects)
                + self.setup.parameter_names)

    def _std(self) -> np.ndarray | None:
        unc = self.uncertainty
        if unc is None:
            return None
        std = np.asarray(unc.std, dtype=float)
        return std if std.shape == (len(self.parameter_names),) else None

    def parameter_rows(self) -> list[dict[str, Any]]:
        active = self.result.active
        n = len(self.parameter_names)
        active = np.ones(n, bool) if active is None else np.asarray(active, dtype=bool)
        left_out = set(self.identifiability.left_out) if self.identifiability is not None else set()
        # With effects on tracker data (issue 23): the platform frame's weak directions.
        held = set(getattr(self.identifiability, "held", None) or [])
        std = self._std()
        from ..effects import parameter_names as effect_names

        n_effects = len(effect_names(self.robot.effects))
        angles = np.concatenate([self.robot.angle_parameters, np.zeros(n_effects, bool),
                                 self.setup.angle_parameters])
        # The effects' own units (issue 23: um/N, ppm/K), between the robot's and the setup's.
        units = {n: u for n, u in zip(effect_names(self.robot.effects),
                                      [u for e in self.robot.effects for u in e.units()],
                                      strict=True)}
        x = np.asarray(self.result.x, dtype=float)
        rows = []
        for i, name in enumerate(self.parameter_names):
            if not active[i]:
                status = ("held (null direction: not identifiable)" if name in left_out
                          else "held (the platform frame, fixed by the loads too weakly)"
                          if name in held else "held fixed")
            elif name in left_out:
                status = "identified, but on a null direction: arbitrary"
            else:
                status = "identified"
            sd = None if std is None or not np.isfinite(std[i]) else float(std[i])
            rows.append({"name": name, "value": float(x[i]), "std": sd,
                         "unit": units.get(name, "rad" if angles[i] else "mm"),
                         "status": status})
        return rows

    def null_text(self, terms: int = 4) -> str:
        """The null directions, one line each: the held parameter and the largest terms of its
        combination (in units of the column scaling, so that mm and rad compare)."""
        ns = self.identifiability
        lines = [f"rank {ns.rank} of {len(ns.parameter_names)}: {len(ns.left_out)} null "
                 "directions, each a combination of parameters that changes nothing measured"]
        for k, name in enumerate(ns.left_out):
            v = ns.vectors[:, k]
            scaled = np.abs(v * ns.scale)
            order = [int(i) for i in np.argsort(-scaled) if scaled[i] > 1e-6 * scaled.max()]
            shown = " ".join(f"{v[i]:+.3g} {ns.parameter_names[i]}" for i in order[:terms])
            more = f" (+{len(order) - terms} more)" if len(order) > terms else ""
            lines.append(f"  {name:<15} {shown}{more}")
        return "\n".join(lines)
