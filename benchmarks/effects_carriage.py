"""The carriage's compliance under load (issue 23, docs/effects.md "The carriage's joints"): what
the first-order model leaves out, and what the IWR's data identify of it.

1. First order: the joints' loads at the readings against the fixed point ``q* = q + c L(q*)``
   (loads at the deflected joints), on 200 simulated IWR poses (seed 1), joint 4 at the realistic
   compliance and at its bound: the largest deflection, its change of the legs, and the second
   order in both.
2. Identifiability: 60 simulated IWR poses (seed 4) with the realistic effects and the carriage's
   compliance (``iwr.effects.api.realistic(robot, carriage=True)``), one payload or two: the rank
   and the standard deviation of ``joint4.compliance`` at a leg noise of 1 um, from the Jacobian
   of eq. (10) at the nominal robot over the base parameters (``iwr.identifiability``).

Usage::

    python benchmarks/effects_carriage.py
"""

from __future__ import annotations

import numpy as np

import iwr
from iwr.effects import api, model
from iwr.effects.problem import EffectProblem
from iwr.problem import predict_legs
from iwr.transforms import pose_matrix


def second_order(robot: iwr.Robot) -> None:
    effects = api.realistic(robot, carriage=True)
    for c4 in (float(effects[2].values()[0]), effects[2].max_revolute):
        carriage = effects[2].with_values(np.array([c4]))
        r = robot.with_effects(effects[0], effects[1], carriage)
        n_e = len(iwr.effects.parameter_names(r.effects))
        m, _ = api.simulate(r, 200, seed=1, x=np.zeros(robot.n_params + n_e))
        xg = np.zeros(robot.n_params)
        moment, mass, _ = model.platform_moment(carriage, m, pose_matrix(m.poses))

        def deflected(q: np.ndarray, r: iwr.Robot = r, xg: np.ndarray = xg,
                      moment: np.ndarray = moment, mass: np.ndarray = mass,
                      carriage: object = carriage, reading: np.ndarray = m.q,
                      c4: float = c4) -> np.ndarray:
            """The readings plus joint 4's deflection under the loads at ``q``."""
            loads, _, _ = model.joint_loads(r, xg, q, moment, mass, carriage)
            out = reading.copy()
            out[:, 3] += c4 * 1e-9 * loads[:, 3]
            return out

        q1 = deflected(m.q)
        qs = q1.copy()
        for _ in range(50):
            qs = deflected(qs)
        geometric = robot.with_effects()
        l0, l1, ls = (predict_legs(geometric, None, q, m.poses) for q in (m.q, q1, qs))
        print(f"joint 4 at {c4} urad/(N m): deflection up to {np.abs(q1 - m.q).max() * 1e6:.1f} "
              f"urad, legs changed up to {np.abs(l1 - l0).max() * 1e3:.1f} um; second order "
              f"{np.abs(qs - q1).max() * 1e6:.4f} urad, legs {np.abs(ls - l1).max() * 1e3:.4f} um")


def identifiability(robot: iwr.Robot) -> None:
    r = robot.with_effects(*api.realistic(robot, carriage=True))
    for label, payloads in (("platform only", [[0.0, 0.0, 0.0, 0.0]]),
                            ("one 80 kg head", [[80.0, 50.0, 0.0, 150.0]]),
                            ("none and the head", None)):
        m, _ = api.simulate(r, 60, seed=4, payloads=payloads)
        report = iwr.identifiability(r, m)
        jac = EffectProblem(r, m).jacobian(np.zeros(len(report.parameter_names)))
        j = jac[:, report.active]
        cov = np.linalg.inv(j.T @ j) * 1e-3**2  # leg noise 1 um
        names = [n for n, a in zip(report.parameter_names, report.active, strict=True) if a]
        sd = np.sqrt(np.diag(cov))
        i = names.index("joint4.compliance") if "joint4.compliance" in names else None
        n_eff = len(report.parameter_names) - report.n_geometric
        print(f"{label}: rank {report.rank} ({report.geometric_rank} + "
              f"{report.rank - report.geometric_rank} of {n_eff}), inseparable "
              f"{[n for n, _ in report.inseparable]}, sd of joint4.compliance "
              + (f"{sd[i]:.2g} urad/(N m)" if i is not None else "-"))


def main() -> None:
    robot = iwr.Robot.default()
    second_order(robot)
    identifiability(robot)


if __name__ == "__main__":
    main()
