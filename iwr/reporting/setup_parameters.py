"""What the reports of the kinds with setup parameters share: the parameters identified beside
the robot's (a tracker's registration and offsets, a ballbar's balls and offsets), their rows
with standard deviations and status, and the null directions in words."""

from __future__ import annotations

from typing import Any

import numpy as np

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

    @property
    def n_robot(self) -> int:
        return self.robot.n_params

    @property
    def parameter_names(self) -> list[str]:
        return self.robot.parameter_names + self.setup.parameter_names

    def _std(self) -> np.ndarray | None:
        unc = self.uncertainty
        if unc is None:
            return None
        std = np.asarray(unc.std, dtype=float)
        return std if std.shape == (len(self.parameter_names),) else None

    def parameter_rows(self) -> list[dict[str, Any]]:
        active = self.result.get("active")
        n = len(self.parameter_names)
        active = np.ones(n, bool) if active is None else np.asarray(active, dtype=bool)
        left_out = set(self.identifiability.left_out) if self.identifiability is not None else set()
        std = self._std()
        angles = np.concatenate([self.robot.angle_parameters, self.setup.angle_parameters])
        x = np.asarray(self.result.x, dtype=float)
        rows = []
        for i, name in enumerate(self.parameter_names):
            if not active[i]:
                status = ("held (null direction: not identifiable)" if name in left_out
                          else "held fixed")
            elif name in left_out:
                status = "identified, but on a null direction: arbitrary"
            else:
                status = "identified"
            sd = None if std is None or not np.isfinite(std[i]) else float(std[i])
            rows.append({"name": name, "value": float(x[i]), "std": sd,
                         "unit": "rad" if angles[i] else "mm", "status": status})
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
