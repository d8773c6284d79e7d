"""The calibration job with effects, and the diagnosis of a geometric fit (issue 23, items 2-4 on
the job side; docs/effects.md).

- :func:`accuracy`: :func:`iwr.accuracy` of a robot with effects, the tool pose by the forward
  kinematics under each pose's load and temperature (:func:`iwr.effects.api.forward_kinematics`).
- :func:`check_job`: the data :func:`iwr.calibrate` models the effects on.
- :func:`diagnose`: whether the residuals of a geometric-only fit correlate with the leg forces
  (the payload columns) or the temperatures (the temperature columns), by the F test of the
  residuals' regression on them beside the geometry, and the effect to switch on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import special

from .builtin import LegCompliance
from .model import leg_state, split

__all__ = ["Diagnosis", "EffectTest", "accuracy", "check_job", "diagnose", "DIAGNOSIS_ALPHA"]

#: The probability that the diagnosis names an effect on data that have none (the family's level:
#: Bonferroni over the effects tested).
DIAGNOSIS_ALPHA = 0.01


def check_job(robot: Any, data: Any) -> None:
    """ValueError unless :func:`iwr.calibrate` models ``robot``'s effects on ``data``: a kind
    whose job models them (:attr:`iwr.kinds.MeasurementKind.models_effects`: pose data, tracker
    points and probe); every method that models them (:func:`iwr.identify` says which) runs in
    the job, with the gross-error screen (the kind's misclosures), the fit test, the
    uncertainty and the predicted accuracy with the effects."""
    from .. import kinds

    kind = kinds.of(data)
    if not kind.models_effects:
        names = ", ".join(e.name for e in robot.effects)
        modelled = [k.description for k in map(kinds.named, kinds.available())
                    if k.models_effects]
        raise ValueError(f"robot {robot.name!r} has effects on ({names}): the calibration job "
                         f"models them on {', '.join(modelled)} data, not on "
                         f"{kind.description} ({kind.name} data; docs/effects.md)")


# -- accuracy ---------------------------------------------------------------------------------

def accuracy(robot: Any, measurements: Any, x: Any, *, tool: Any = None,
             tolerance: float = 1e-9, max_iterations: int = 50) -> Any:
    """:func:`iwr.accuracy` of a robot with effects: for the nominal robot (``x`` = 0: the
    geometry and the effects' values of the robot file) and the calibrated one (``x``:
    geometric errors, then the effects' parameters), the platform pose by forward kinematics
    of the joint and leg readings under each pose's payload and temperature, against the
    measured pose. The geometric forward kinematics gives the start; Newton's method on the
    readings with the effects ends within ``tolerance`` mm of them."""
    from ..analysis.accuracy import Accuracy, PoseErrors, pose_errors
    from ..forward import ForwardKinematicsError
    from ..forward import forward_kinematics as geometric_forward
    from .api import forward_kinematics as effect_forward
    from .model import check_inputs

    check_inputs(robot, measurements)
    n_all = robot.n_params + sum(len(e.parameter_names()) for e in robot.effects)
    x = np.zeros(n_all) if x is None else np.asarray(x, dtype=float)
    split(robot, x)
    geometric = robot.with_effects()
    out = {}
    for label, xe in (("nominal", np.zeros(n_all)), ("calibrated", x)):
        try:
            guess = geometric_forward(geometric, xe[: robot.n_params], measurements.q,
                                      measurements.legs, tolerance=tolerance,
                                      max_iterations=max_iterations)
            poses = effect_forward(robot, xe, measurements.q, measurements.legs, measurements,
                                   guess, tolerance=tolerance, max_iterations=max_iterations)
        except (ForwardKinematicsError, RuntimeError) as exc:
            k = getattr(exc, "pose", None)
            where = measurements.where(k) if k is not None else "a pose"
            err = ForwardKinematicsError(f"forward kinematics with effects of the {label} robot "
                                         f"at {where}: {exc}")
            err.pose = k
            raise err from None
        pos, ori = pose_errors(poses, measurements.poses, tool)
        out[label] = PoseErrors(position=pos, orientation=ori, poses=poses)
    return Accuracy(nominal=out["nominal"], calibrated=out["calibrated"])


# -- the diagnosis of a geometric fit -----------------------------------------------------------

@dataclass(frozen=True)
class EffectTest:
    """The F test of one effect's regressors in the residuals of a geometric fit
    (:func:`diagnose`).

    ``statistic`` ``F = ((RSS0 - RSS1) / p) / (RSS1 / f)``: ``RSS1`` the residual sum of squares
    of the (whitened) residuals regressed on the geometry's Jacobian and every effect's
    regressors, ``RSS0`` without this effect's, ``p`` the rank they add, ``f`` the residuals
    less the rank of the whole; under the hypothesis that the effect is absent (whatever the
    others do), ``F ~ F(p, f)`` (linearised model, Gaussian noise with the covariance the
    whitening assumes up to a common factor). ``estimate``: the effect's coefficient(s) of the
    regression (its unit), a first guess of its size."""

    effect: str
    regressors: str
    statistic: float
    dof: tuple[int, int]
    p_value: float
    alpha: float
    estimate: np.ndarray
    unit: str

    @property
    def significant(self) -> bool:
        return bool(self.p_value < self.alpha)

    def line(self) -> str:
        est = ", ".join(f"{v:.3g}" for v in self.estimate)
        return (f"{self.effect} ({self.regressors}): F = {self.statistic:.4g} with "
                f"({self.dof[0]}, {self.dof[1]}) degrees of freedom, p-value "
                f"{self.p_value:.3g} against {self.alpha:.3g}: "
                + ("the residuals CORRELATE" if self.significant else "no correlation found")
                + f" (regression coefficient {est} {self.unit})")


@dataclass(frozen=True)
class Diagnosis:
    """Whether the residuals of a geometric-only fit correlate with the leg forces or the legs'
    temperatures (:func:`diagnose`), and the effects to switch on."""

    tests: list[EffectTest]
    alpha: float
    weighting: str
    assumptions: list[str] = field(default_factory=list)
    n_residuals: int = 0
    #: The statics the leg forces were computed with, as ``[effects.compliance]`` lines.
    statics: list[str] = field(default_factory=list)
    #: What the residuals are ("leg" on pose data, "point" on tracker data).
    residuals: str = "leg"

    @property
    def suggested(self) -> list[str]:
        """The effects whose test rejects their absence."""
        return [t.effect for t in self.tests if t.significant]

    def describe(self) -> str:
        """The test in one sentence, with its false-alarm rate."""
        return (f"the {self.n_residuals} {self.residuals} residuals ({self.weighting}) "
                "regressed on the geometry's Jacobian and each effect's change of the "
                "readings (leg forces from the statics of the payload columns; leg length "
                "times the temperature's "
                "departure from its mean); each effect's F test at "
                f"{self.alpha / max(len(self.tests), 1):.3g} (Bonferroni: data without any "
                f"effect name one with probability at most {self.alpha:g})")

    def suggestion(self) -> str:
        """The TOML tables to add to the robot file for the effects named (empty: none)."""
        out = []
        for t in self.tests:
            if not t.significant:
                continue
            if t.effect == "compliance":
                out += ["[effects.compliance]", "per_leg = true", *self.statics]
            elif t.effect == "thermal":
                out += ["[effects.thermal]", "identify = true",
                        "reference_C = 20.0                 # the temperature of the geometry"]
        return "\n".join(out)

    def lines(self) -> list[str]:
        """The diagnosis for the reports."""
        head = ("diagnosis: the residuals of the geometric model correlate with "
                + " and ".join({"compliance": "the leg forces (payload)",
                                "thermal": "the legs' temperatures"}[e] for e in self.suggested)
                + "; switch on " + ", ".join(f"[effects.{e}]" for e in self.suggested)
                + " in the robot file (docs/effects.md)") if self.suggested else (
            "diagnosis: the residuals of the geometric model correlate with none of the leg "
            "forces and temperatures tested (no effect to switch on)")
        return [head, f"  - {self.describe()}"] + [f"  - {t.line()}" for t in self.tests] + [
            f"  - {a}" for a in self.assumptions]

    def sentence(self) -> str:
        """The diagnosis's first line as a sentence (for a verdict)."""
        head = self.lines()[0].removeprefix("diagnosis: ")
        return head[:1].upper() + head[1:] + "."

    def to_dict(self) -> dict[str, Any]:
        return {"suggested": self.suggested, "alpha": self.alpha, "weighting": self.weighting,
                "tests": [{"effect": t.effect, "F": t.statistic, "dof": list(t.dof),
                           "p_value": t.p_value, "alpha": t.alpha,
                           "estimate": t.estimate.tolist(), "unit": t.unit}
                          for t in self.tests],
                "assumptions": list(self.assumptions), "statics": list(self.statics)}


def _statics(robot: Any) -> LegCompliance:
    """The loads' statics for the diagnosis: the robot's compliance table when it has one, else
    :func:`iwr.effects.api.realistic`'s (gravity opposite the hexapod's z axis at the middle of
    the carriage's joint ranges, a 120 kg platform)."""
    for e in robot.effects:
        if isinstance(e, LegCompliance):
            return e
    from .api import realistic

    return realistic(robot.with_effects())[0]


def _residual_ss(m: np.ndarray, r: np.ndarray) -> tuple[float, int, np.ndarray]:
    """The residual sum of squares of ``r`` regressed on the columns of ``m`` (scaled, so that
    units do not set the rank), the rank, and the coefficients (in ``m``'s units)."""
    if m.shape[1] == 0:
        return float(r @ r), 0, np.zeros(0)
    d = np.linalg.norm(m, axis=0)
    d = np.where(d > 0, d, 1.0)
    u, s, vt = np.linalg.svd(m / d, full_matrices=False)
    rank = int(np.sum(s > max(m.shape) * np.finfo(float).eps * 1e3 * (s[0] if s.size else 0)))
    proj = u[:, :rank].T @ r
    res = r - u[:, :rank] @ proj
    coef = (vt[:rank].T @ (proj / s[:rank])) / d
    return float(res @ res), rank, coef


def _cluster_wald(rest: np.ndarray, z: np.ndarray, r: np.ndarray, cluster: np.ndarray
                  ) -> tuple[float, int]:
    """The Wald test of ``z``'s coefficients in the regression of ``r`` on ``[rest, z]`` with
    the cluster-robust (per pose) covariance: ``(F, G - p)``, to be read against
    ``F(p, G - p)`` (G poses, p the rank of ``z`` beyond ``rest``). Without a noise model the
    leg residuals of one pose share the noise of its measured pose and joints: only the poses
    are independent. The residuals of each pose are corrected for its leverage (CR2, Bell and
    McCaffrey: ``(I - H_kk)^-1/2``) and the statistic scaled as Hotelling's T^2 (``W (G - p) /
    (p (G - 1))``), the small-sample corrections without which the test rejects too often with
    tens of poses and six regressors. By Frisch-Waugh-Lovell, ``z`` and ``r`` are first
    cleared of ``rest``."""
    def basis(m: np.ndarray) -> np.ndarray:
        d = np.linalg.norm(m, axis=0)
        u, s, _ = np.linalg.svd(m / np.where(d > 0, d, 1.0), full_matrices=False)
        return u[:, s > max(m.shape) * np.finfo(float).eps * 1e3 * (s[0] if s.size else 0)]

    u = basis(rest)
    zt = z - u @ (u.T @ z)
    rt = r - u @ (u.T @ r)
    dz = np.linalg.norm(zt, axis=0)
    zt = zt / np.where(dz > 0, dz, 1.0)
    bread = np.linalg.pinv(zt.T @ zt, rcond=1e-10, hermitian=True)
    beta = bread @ (zt.T @ rt)
    res = rt - zt @ beta  # the residuals of the whole regression
    full = np.hstack([u, basis(zt)])  # an orthonormal basis of [rest, z]
    groups = np.unique(cluster, return_inverse=True)[1]
    g = int(groups.max()) + 1
    scores = np.zeros((g, zt.shape[1]))
    for k in range(g):
        rows = groups == k
        h = full[rows] @ full[rows].T
        val, vec = np.linalg.eigh(np.eye(h.shape[0]) - h)
        adj = vec @ ((vec.T @ res[rows]) / np.sqrt(np.clip(val, 1e-12, None)))
        scores[k] = zt[rows].T @ adj
    cov = bread @ (scores.T @ scores) @ bread
    p = int(np.linalg.matrix_rank(zt.T @ zt, hermitian=True))
    wald = float(beta @ np.linalg.pinv(cov, rcond=1e-10, hermitian=True) @ beta)
    if g - p < 1:
        return math.nan, 0
    return wald * (g - p) / (p * (g - 1)), g - p


def diagnose(robot: Any, data: Any, x: Any, *, active: Any = None, noise: Any = None,
             alpha: float = DIAGNOSIS_ALPHA) -> Diagnosis | None:
    """Whether the leg residuals of a geometric fit ``x`` of ``robot`` (no effect on) to
    ``data`` correlate with the leg forces of the data's payloads or with the legs'
    temperatures: None when the data carry neither column.

    The residuals ``r`` (predicted minus measured leg readings at ``x``; whitened per pose by
    their covariance under ``noise`` when given, as the efficient estimator weighs them, else
    weighted by the data's leg weights) are regressed on the geometry's Jacobian (the
    ``active`` parameters) and the change of the readings each candidate effect would make:

    - **compliance** (payload columns): six columns, leg ``j``'s axial force ``f_kj`` (N) at
      each pose (statics of the platform and the payload, ``f = J^-T w``, at ``x``), times
      1e-3 (coefficient: the leg's compliance, um/N);
    - **thermal** (temperature columns): one column, ``1e-6 D_kj (T_kj - mean T)`` (``D`` the
      leg length; coefficient: the expansion coefficient, ppm/K).

    Each effect is tested by the F test of its columns given the geometry and the other
    effect's (:class:`EffectTest`), at ``alpha`` divided by the number tested, so that data
    with neither effect name one with probability at most ``alpha``. The leg forces need the
    gravity and the platform's mass and centre: the robot's ``[effects.compliance]`` table's
    when it has one, else the defaults of :func:`iwr.effects.api.realistic` (said in
    ``assumptions``)."""
    from ..implicit_loop import loop_jacobians, sigma_matrix
    from ..noise import Noise

    has_payload = getattr(data, "payload", None) is not None
    has_temps = getattr(data, "temperatures", None) is not None
    if not (has_payload or has_temps):
        return None
    geometric = robot.with_effects()
    x = np.asarray(x, dtype=float)[: robot.n_params]
    n = len(data)
    legs, jx, jy = loop_jacobians(geometric, x, data.q, data.poses)
    r = legs - data.legs
    mask = np.ones(robot.n_params, bool) if active is None else np.asarray(active, bool)[
        : robot.n_params]
    a = jx[:, :, mask]
    cols: dict[str, np.ndarray] = {}
    assumptions: list[str] = []
    table: list[str] = []
    if has_payload:
        statics = _statics(robot)
        probe = geometric.with_effects(statics)
        state = leg_state(probe, x, data.q, data.poses, data, {"forces"})
        cols["compliance"] = 1e-3 * state.forces[:, :, None] * np.eye(6)[None]
        g = ", ".join(f"{v:.6g}" for v in statics.gravity)
        c = ", ".join(f"{v:.6g}" for v in statics.platform_centre)
        table = [f"gravity_m_s2 = [{g}]        # gravity in {{0}}: check it",
                 f"platform_mass_kg = {statics.platform_mass:g}       # the platform's: give yours",
                 f"platform_centre_mm = [{c}]   # its centre of mass in {{5}}: give yours"]
        assumptions = [f"the leg forces assume gravity [{g}] m/s^2 in {{0}} and a platform of "
                       f"{statics.platform_mass:g} kg with its centre at [{c}] mm in {{5}} ("
                       + ("the robot's [effects.compliance]" if any(
                           isinstance(e, LegCompliance) for e in robot.effects) else
                          "iwr.effects.api.realistic's defaults: the robot file has no "
                          "[effects.compliance] table") + ")"]
    if has_temps:
        temps = np.broadcast_to(data.temperatures, (n, 6))
        lengths = leg_state(geometric, x, data.q, data.poses, data, frozenset()).lengths
        cols["thermal"] = (1e-6 * lengths * (temps - temps.mean()))[..., None]
    if isinstance(noise, Noise):
        sig = sigma_matrix(geometric, data, noise)
        cov = np.einsum("kij,kj,klj->kil", jy, sig[:, 6:] ** 2, jy)
        cov[:, np.arange(6), np.arange(6)] += sig[:, :6] ** 2
        chol = np.linalg.cholesky(cov)

        def whiten(v: np.ndarray) -> np.ndarray:
            return np.linalg.solve(chol, v)

        weighting = "whitened by the noise model"
        rows = np.ones((n, 6), bool)
    else:
        w = data.weights
        sw = np.ones((n, 6)) if w is None else np.sqrt(w)

        def whiten(v: np.ndarray) -> np.ndarray:
            return v * sw[..., None]

        weighting = "unweighted" if w is None else "weighted by the data's leg weights"
        rows = sw > 0
    rw = whiten(r[..., None])[..., 0][rows]
    cluster = np.broadcast_to(np.arange(n)[:, None], (n, 6))[rows]
    zw = {k: whiten(v)[rows] for k, v in cols.items()}
    return effect_tests(rw, whiten(a)[rows], zw, cluster, exact=isinstance(noise, Noise),
                        alpha=alpha, weighting=weighting, assumptions=assumptions, table=table)


#: Each effect's regressors and the unit of its coefficient, as the diagnosis names them.
_REGRESSORS = {"compliance": ("the six leg forces", "um/N"),
               "thermal": ("leg length times temperature", "ppm/K")}


def effect_tests(rw: np.ndarray, aw: np.ndarray, zw: dict[str, np.ndarray],
                 cluster: np.ndarray, *, exact: bool, alpha: float, weighting: str,
                 assumptions: list[str], table: list[str], residuals: str = "leg") -> Diagnosis:
    """The statistics of :func:`diagnose` (and of the tracker kinds' diagnosis,
    :func:`iwr.effects.tracker_diagnosis.diagnose`) once the residuals are built: ``rw`` the
    residuals that carry data (whitened, or weighted), ``aw`` (rows, n) the geometry's
    Jacobian in the active parameters, ``zw`` each candidate effect's regressors (rows, k), in
    the same rows and whitening, ``cluster`` the pose of each row. Each effect is tested given
    the geometry and the others, at ``alpha`` divided by the number tested: with ``exact``
    (whitened by a noise model) by the F test of the nested regressions, else by the
    cluster-robust (per pose) Wald test (:func:`_cluster_wald`)."""
    every = np.concatenate([aw] + list(zw.values()), axis=1)
    rss1, rank1, coef = _residual_ss(every, rw)
    f_dof = rw.size - rank1
    level = alpha / len(zw)
    tests = []
    start = aw.shape[1]
    for name, z in zw.items():
        others = [v for k, v in zw.items() if k != name]
        rest = np.concatenate([aw] + others, axis=1)
        rss0, rank0, _ = _residual_ss(rest, rw)
        p = rank1 - rank0
        dof = f_dof
        if p < 1 or f_dof < 1:
            stat, pv = math.nan, 1.0
        elif exact:
            # Whitened by the noise model: the exact F test of the nested regressions.
            stat = ((rss0 - rss1) / p) / (rss1 / f_dof)
            pv = float(special.fdtrc(p, f_dof, max(stat, 0.0)))
        else:
            stat, dof = _cluster_wald(rest, z, rw, cluster)
            pv = float(special.fdtrc(p, dof, max(stat, 0.0))) if dof >= 1 else 1.0
        k = list(zw).index(name)
        first = start + sum(v.shape[1] for v in list(zw.values())[:k])
        est = coef[first: first + z.shape[1]]
        what, unit = _REGRESSORS[name]
        tests.append(EffectTest(name, what, float(stat), (int(p), int(dof)), pv, level,
                                np.asarray(est, dtype=float), unit))
    return Diagnosis(tests, alpha, weighting, assumptions, int(rw.size), table, residuals)
