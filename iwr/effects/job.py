"""The calibration job with effects, and the diagnosis of a geometric fit (issue 23, items 2-4 on
the job side; docs/effects.md).

- :func:`accuracy`: :func:`iwr.accuracy` of a robot with effects, the tool pose by the forward
  kinematics under each pose's load and temperature (:func:`iwr.effects.api.forward_kinematics`).
- :func:`check_job`: the data :func:`iwr.calibrate` models the effects on.
- :func:`diagnose`: whether the residuals of a geometric-only fit correlate with the leg forces
  or the carriage joints' loads (the payload columns) or the temperatures (the temperature
  columns: the legs' expansion, and the slides' with the machine's ``T_C``), by the F test of
  the residuals' regression on them beside the geometry, and the effect to switch on;
  :func:`problem_diagnosis` the same on an instrument's objective (tracker and ballbar data),
  every kind's candidate effects :func:`candidates`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import special

from . import parameter_names as effect_names
from .builtin import LegCompliance
from .model import split

__all__ = ["Candidates", "Diagnosis", "EffectTest", "accuracy", "candidates", "check_job",
           "diagnose", "effect_tests", "problem_diagnosis", "regression_tests",
           "DIAGNOSIS_ALPHA"]

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
    regression (its unit), a first guess of its size. ``p`` = 0 (``testable`` False): the
    effect's regressors add nothing to the geometry's and the other effects' at these data
    (e.g. a slide's compliance under one payload), so the data cannot test it: not named,
    whatever the residuals (``statistic`` nan, p-value 1)."""

    effect: str
    regressors: str
    statistic: float
    dof: tuple[int, int]
    p_value: float
    alpha: float
    estimate: np.ndarray
    unit: str
    #: Per coefficient, when they differ in unit (the carriage's joints): name and unit.
    names: tuple[str, ...] = ()
    units: tuple[str, ...] = ()
    #: The share of its regressors' variation beyond the geometry that the other effects do
    #: not share (:func:`_own_share`): the power its test keeps beside them.
    own: float = 1.0
    #: For an effect of a closed test's group (:data:`LOADS`): whether the group's joint test
    #: rejected (the effect can be named only then); None outside a group.
    closed: bool | None = None

    @property
    def significant(self) -> bool:
        return bool(self.testable and self.p_value < self.alpha and self.closed is not False)

    @property
    def testable(self) -> bool:
        """Whether the effect adds a direction of its own to the regression (``p`` >= 1)."""
        return self.dof[0] >= 1

    def line(self) -> str:
        if not self.testable:
            return (f"{self.effect} ({self.regressors}): cannot be tested with these data: its "
                    "regressors add nothing to what the geometry and the other effects "
                    "describe (0 degrees of freedom of its own; docs/effects.md, the design "
                    "rule)")
        head = (f"{self.effect} ({self.regressors}): F = {self.statistic:.4g} with "
                f"({self.dof[0]}, {self.dof[1]}) degrees of freedom, p-value "
                f"{self.p_value:.3g} against {self.alpha:.3g}: ")
        if self.effect == "loads":  # the joint test of the two compliances: no coefficient
            return head + ("the residuals CORRELATE" if self.significant else
                           "no correlation found") + " (the closed test's first step)"
        est = ", ".join(f"{v:.3g}" for v in self.estimate) + f" {self.unit}"
        if self.names:
            est = ", ".join(f"{n} {v:.3g} {u}" for n, v, u in zip(
                self.names, self.estimate, self.units, strict=True))
        weak = (f"; the other effects share {1.0 - self.own:.0%} of its change beyond the "
                "geometry, so only a large one shows" if self.own < 0.5 else "")
        verdict = ("the residuals CORRELATE" if self.significant else
                   "not named: the loads together show nothing" if self.closed is False
                   and self.p_value < self.alpha else "no correlation found")
        return head + verdict + f" (regression coefficient {est}{weak})"


#: The effects of the loads, tested first together and then each (a closed test,
#: :func:`effect_tests`): much of the carriage's compliance pattern is what six free leg
#: compliances also make (76-92 % of it on pose and ballbar data), so that each alone, given the
#: other, shows only when large, while the two together show the loads.
LOADS = ("compliance", "carriage_compliance")

#: What the residuals of each kind are (:attr:`Diagnosis.residuals`), as the diagnosis names
#: what each effect changes.
_WHAT = {"leg": "leg readings", "point": "reflector points", "probe-point": "probe's points",
         "distance": "bar distances"}
#: What each effect's regressors stand for, in the diagnosis's description.
_MECHANISM = {
    "compliance": "the legs' compliance: the leg forces of the statics of the platform and the "
                  "payload columns",
    "thermal": "the legs' expansion: each leg's length times its temperature's departure from "
               "the data's mean",
    "carriage_compliance": "the carriage's compliance: each joint tested turned (or moved) by "
                           "the gravity load it carries",
    "carriage_thermal": "the slides' expansion: each prismatic joint's reading times the "
                        "machine's temperature's departure from the data's mean"}
#: How the report names what each effect correlates with.
_CAUSE = {"compliance": "the leg forces (payload)", "thermal": "the legs' temperatures",
          "carriage_compliance": "the carriage joints' gravity loads (payload)",
          "carriage_thermal": "the slides' travel times the machine's temperature",
          "loads": "the loads (payload) through the legs' or the carriage's compliance (these "
                   "data cannot tell which)"}


def _and(items: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return " and ".join(items) if len(items) < 3 else ", ".join(items[:-1]) + " and " + items[-1]


@dataclass(frozen=True)
class Diagnosis:
    """Whether the residuals of a geometric-only fit correlate with the leg forces, the legs'
    temperatures, the carriage joints' loads or the slides' travel times the machine's
    temperature (:func:`diagnose`), and the effects to switch on."""

    tests: list[EffectTest]
    alpha: float
    weighting: str
    assumptions: list[str] = field(default_factory=list)
    n_residuals: int = 0
    #: The statics the leg forces were computed with, as ``[effects.compliance]`` lines.
    statics: list[str] = field(default_factory=list)
    #: What the residuals are: "leg" on pose data, "point" ("probe-point") on tracker data,
    #: "distance" on ballbar data.
    residuals: str = "leg"
    #: The ``[effects.carriage_compliance]`` table's own lines (the joints, the hexapod).
    carriage: list[str] = field(default_factory=list)
    #: The ``[effects.carriage_thermal]`` table's joints line (the slides tested).
    slides: list[str] = field(default_factory=list)
    #: The joint test of the two compliances (:data:`LOADS`, effect ``"loads"``) when both are
    #: tested, else None.
    loads: EffectTest | None = None

    @property
    def loads_only(self) -> bool:
        """The loads' joint test rejects, yet neither compliance alone: the residuals follow
        the loads, and the data cannot tell the legs' compliance from the carriage's."""
        return bool(self.loads is not None and self.loads.significant and not any(
            t.significant for t in self.tests if t.effect in LOADS))

    @property
    def suggested(self) -> list[str]:
        """The effects whose test rejects their absence; both compliances when only their
        joint test does (:attr:`loads_only`: calibrated with both, the fit apportions the
        loads' change between them, with the uncertainty the data leave)."""
        return [t.effect for t in self.tests
                if t.significant or (self.loads_only and t.effect in LOADS)]

    @property
    def untestable(self) -> list[str]:
        """The effects these data cannot test (:attr:`EffectTest.testable`)."""
        return [t.effect for t in self.tests if not t.testable]

    def describe(self) -> str:
        """The test in one sentence, with its false-alarm rate."""
        what = _WHAT.get(self.residuals, f"{self.residuals} readings")
        ways = "; ".join(_MECHANISM[t.effect] for t in self.tests if t.effect in _MECHANISM)
        tested = max(sum(t.testable for t in self.tests), 1)
        closed = ("" if self.loads is None else
                  f"; the two compliances first together at {self.loads.alpha:.3g} (their two "
                  "shares), then each at the same level if that rejects (a closed test)")
        return (f"the {self.n_residuals} {self.residuals} residuals ({self.weighting}) "
                f"regressed on the geometry's Jacobian and on each effect's change of the "
                f"{what}, their derivative in the effect's parameters where it is zero ({ways}); "
                f"each effect's test at {self.alpha / tested:.3g} (Bonferroni over the {tested} "
                f"tested{closed}: data without any effect name one with probability at most "
                f"{self.alpha:g})")

    def suggestion(self) -> str:
        """The TOML tables to add to the robot file for the effects named (empty: none)."""
        out: list[str] = []
        named = self.suggested
        for t in self.tests:
            if t.effect not in named:
                continue
            if out:
                out.append("")
            if t.effect == "compliance":
                out += ["[effects.compliance]", "per_leg = true", *self.statics]
            elif t.effect == "thermal":
                out += ["[effects.thermal]", "identify = true",
                        "reference_C = 20.0                 # the temperature of the geometry"]
            elif t.effect == "carriage_compliance":
                out += ["[effects.carriage_compliance]", *self.carriage, *self.statics]
            elif t.effect == "carriage_thermal":
                out += ["[effects.carriage_thermal]", *self.slides, "identify = true",
                        "reference_C = 20.0                 # the temperature at which the "
                        "scales read true"]
        return "\n".join(out)

    def lines(self) -> list[str]:
        """The diagnosis for the reports."""
        named = self.suggested
        if named:
            causes = [_CAUSE[e] for e in named if not (self.loads_only and e in LOADS)]
            if self.loads_only:
                causes.insert(0, _CAUSE["loads"])
            head = ("diagnosis: the residuals of the geometric model correlate with "
                    + _and(causes) + "; switch on "
                    + ", ".join(f"[effects.{e}]" for e in named)
                    + " in the robot file (docs/effects.md)")
        else:
            tested = [_CAUSE[t.effect] for t in self.tests if t.testable]
            head = ("diagnosis: the residuals of the geometric model correlate with none of "
                    + (_and(tested) if tested else "the effects") + " tested"
                    + (" (no effect to switch on)" if tested else ""))
        if self.untestable:
            head += ("; " + _and([_CAUSE[e] for e in self.untestable])
                     + ": cannot be tested with these data")
        joint = [] if self.loads is None else [f"  - {self.loads.line()}"]
        return [head, f"  - {self.describe()}", *joint] + [
            f"  - {t.line()}" for t in self.tests] + [f"  - {a}" for a in self.assumptions]

    def sentence(self) -> str:
        """The diagnosis's first line as a sentence (for a verdict)."""
        head = self.lines()[0].removeprefix("diagnosis: ")
        return head[:1].upper() + head[1:] + "."

    def to_dict(self) -> dict[str, Any]:
        def one(t: EffectTest) -> dict[str, Any]:
            return {"effect": t.effect,
                    "F": t.statistic if math.isfinite(t.statistic) else None,
                    "dof": list(t.dof), "p_value": t.p_value, "alpha": t.alpha,
                    "own_share": t.own, "significant": t.significant,
                    "estimate": t.estimate.tolist(), "unit": t.unit,
                    **({"names": list(t.names), "units": list(t.units)} if t.names else {}),
                    **({"closed": t.closed} if t.closed is not None else {})}

        return {"suggested": self.suggested, "untestable": self.untestable, "alpha": self.alpha,
                "weighting": self.weighting, "residuals": self.residuals,
                "tests": [one(t) for t in self.tests],
                "loads": None if self.loads is None else one(self.loads),
                "loads_only": self.loads_only,
                "assumptions": list(self.assumptions), "statics": list(self.statics),
                "carriage": list(self.carriage), "slides": list(self.slides)}


def _statics(robot: Any) -> LegCompliance:
    """The loads' statics for the diagnosis: the robot's compliance table when it has one, else
    :func:`iwr.effects.api.realistic`'s (gravity opposite the hexapod's z axis at the middle of
    the carriage's joint ranges, a 120 kg platform)."""
    for e in robot.effects:
        if isinstance(e, LegCompliance):
            return e
    from .api import realistic

    return realistic(robot.with_effects())[0]


@dataclass(frozen=True)
class Candidates:
    """The effects a diagnosis tests (:func:`candidates`), each at zero, and what it says of
    them."""

    #: Switched on together on the geometric robot, at zero: the legs' compliance (per leg),
    #: the carriage's compliance (the joints that carry a load), the legs' expansion (one
    #: coefficient, about the data's mean temperature), the slides' expansion (one coefficient
    #: shared by the prismatic joints, about the data's mean machine temperature).
    effects: tuple[Any, ...]
    assumptions: list[str]
    #: The statics' lines of ``[effects.compliance]`` and ``[effects.carriage_compliance]``.
    statics: list[str]
    #: The ``[effects.carriage_compliance]`` table's own lines.
    carriage: list[str]
    #: The ``[effects.carriage_thermal]`` table's joints line.
    slides: list[str] = field(default_factory=list)


def candidates(robot: Any, data: Any, *, gravity_text: str | None = None,
               gravity_note: str = "# gravity in {0}: check it",
               load_gravity: Any = None) -> Candidates | None:
    """The candidate effects of a diagnosis of ``robot``'s geometry on ``data``: None when the
    data carry neither payload nor temperature columns. With payload columns, the legs'
    compliance, and the carriage's compliance for the carriage joints that carry a gravity load
    somewhere in their ranges under ``load_gravity`` (in {0}; default the statics' gravity;
    :func:`iwr.effects.api.loaded_joints`), none on a robot without such joints; with
    temperature columns, the legs' expansion, and with the machine's one temperature per pose
    (``T_C``; not the legs' ``T1_C .. T6_C``: said in the assumptions) the slides' expansion on
    a robot with prismatic carriage joints (one coefficient shared by them, about the data's
    mean temperature). The platform's mass and centre and gravity: the
    robot's ``[effects.compliance]`` table's when it has one, else
    :func:`iwr.effects.api.realistic`'s; the hexapod's mass and centre the robot's
    ``[effects.carriage_compliance]`` table's, else :data:`iwr.effects.api.REALISTIC_CARRIAGE`'s
    (said in the assumptions). ``gravity_text`` says where gravity comes from (default: the
    statics' own, in {0}), ``gravity_note`` the comment on the suggested table's gravity."""
    from .builtin import LegThermal
    from .carriage import CarriageCompliance
    from .carriage_thermal import CarriageThermal

    has_payload = getattr(data, "payload", None) is not None
    has_temps = getattr(data, "temperatures", None) is not None
    if not (has_payload or has_temps):
        return None
    geometric = robot.with_effects()
    effects: list[Any] = []
    assumptions: list[str] = []
    statics_lines: list[str] = []
    carriage: list[str] = []
    if has_payload:
        from .api import REALISTIC_CARRIAGE, loaded_joints

        statics = _statics(robot)
        g = ", ".join(f"{v:.6g}" for v in statics.gravity)
        c = ", ".join(f"{v:.6g}" for v in statics.platform_centre)
        statics_lines = [f"gravity_m_s2 = [{g}]        {gravity_note}",
                         f"platform_mass_kg = {statics.platform_mass:g}       # the platform's: "
                         "give yours",
                         f"platform_centre_mm = [{c}]   # its centre of mass in {{5}}: give yours"]
        source = ("the robot's [effects.compliance]" if any(
            isinstance(e, LegCompliance) for e in robot.effects) else
            "iwr.effects.api.realistic's defaults: the robot file has no [effects.compliance] "
            "table")
        where = f"gravity [{g}] m/s^2 in {{0}}" if gravity_text is None else gravity_text
        assumptions.append(f"the loads assume {where} and a platform of "
                           f"{statics.platform_mass:g} kg with its centre at [{c}] mm in {{5}} "
                           f"({source})")
        effects.append(LegCompliance(statics.platform_mass, statics.platform_centre,
                                     statics.gravity, 0.0, per_leg=True))
        joints = loaded_joints(geometric, statics.gravity if load_gravity is None
                               else load_gravity)
        if joints:
            own = next((e for e in robot.effects if isinstance(e, CarriageCompliance)), None)
            mass = REALISTIC_CARRIAGE["hexapod_mass"] if own is None else own.hexapod_mass
            centre = REALISTIC_CARRIAGE["hexapod_centre"] if own is None else own.hexapod_centre
            h = ", ".join(f"{v:.6g}" for v in centre)
            effects.append(CarriageCompliance(mass, centre, statics.platform_mass,
                                              statics.platform_centre, statics.gravity, joints,
                                              0.0))
            carriage = [f"joints = {joints}                       # those that carry a load",
                        f"hexapod_mass_kg = {mass:g}       # with what the last link carries: "
                        "give yours",
                        f"hexapod_centre_mm = [{h}]   # in its base joints' frame: give yours"]
            assumptions.append(
                f"the carriage's joint loads (joint{'s' if len(joints) > 1 else ''} "
                f"{_and([str(j) for j in joints])}: those that carry a gravity load in their "
                f"ranges) assume a hexapod of {mass:g} kg with its centre at [{h}] mm in its "
                "base joints' frame, with the platform and the payload above ("
                + ("the robot's [effects.carriage_compliance]" if own is not None else
                   "iwr.effects.api.REALISTIC_CARRIAGE: the robot file has no "
                   "[effects.carriage_compliance] table") + ")")
    slides: list[str] = []
    if has_temps:
        raw = np.asarray(data.temperatures, dtype=float)
        temps = np.broadcast_to(raw, (len(data), 6))
        effects.append(LegThermal(0.0, float(temps.mean()), identify=True))
        prismatic = [i + 1 for i, t in enumerate(geometric.joint_types) if t == "P"]
        machine = raw.ndim == 1 or raw.shape[1] == 1
        if prismatic and machine:
            # One coefficient shared by the slides, as the effect's default (per_joint false):
            # one degree of freedom, the most power for scales of one material.
            effects.append(CarriageThermal(0.0, float(raw.mean()), prismatic, identify=True))
            slides = [f"joints = {prismatic}                    # the slides tested"]
        elif prismatic:
            assumptions.append(
                "the slides' expansion (joint" + ("s " if len(prismatic) > 1 else " ")
                + _and([str(j) for j in prismatic]) + ") is not tested: it needs the machine's "
                "temperature at each pose (column T_C), and the data have the legs' only "
                "(T1_C .. T6_C)")
    return Candidates(tuple(effects), assumptions, statics_lines, carriage, slides)


def regression_tests(r: np.ndarray, jac: np.ndarray, geo: np.ndarray, first: int,
                     effects: Any, cands: Candidates, whitening: np.ndarray, rows: np.ndarray, *,
                     exact: bool, alpha: float, weighting: str, residuals: str) -> Diagnosis:
    """:func:`effect_tests` of the residuals ``r`` (N, m) of a geometric fit, the effects of
    ``cands`` at zero, and their exact Jacobian ``jac`` (N, m, n) in the parameters of the
    problem with those effects: the geometry's regressors its columns ``geo`` (the active
    geometric and set-up parameters), each effect's the negative of its columns from ``first``
    on, in the order of ``effects`` (``cands.effects`` bound to the robot; the residuals are
    predicted without the effect minus measured with it: ``-J_e c`` to first order, so that the
    coefficient estimates the effect's size ``c``). ``whitening`` (N, m', m): each pose's
    whitening (identity, weights, or the noise model's); ``rows`` (N, m'): the whitened rows
    that carry data. Each pose is a cluster."""
    cols: dict[str, np.ndarray] = {}
    labels: dict[str, tuple[str, str, tuple[str, ...], tuple[str, ...]]] = {}
    k = first
    for e in effects:
        p = len(e.parameter_names())
        cols[e.name] = -jac[:, :, k: k + p]
        k += p
        labels[e.name] = _label(e)

    def whiten(v: np.ndarray) -> np.ndarray:
        return np.einsum("kij,kj...->ki...", whitening, v)

    n = r.shape[0]
    cluster = np.broadcast_to(np.arange(n)[:, None], rows.shape)[rows]
    zw = {name: whiten(v)[rows] for name, v in cols.items()}
    return effect_tests(whiten(r)[rows], whiten(jac[:, :, geo])[rows], zw, cluster,
                        exact=exact, alpha=alpha, weighting=weighting,
                        assumptions=cands.assumptions, table=cands.statics,
                        residuals=residuals, labels=labels, carriage=cands.carriage,
                        slides=cands.slides)


def problem_diagnosis(problem: Any, data: Any, x: Any, n_geometric: int, cands: Candidates,
                      whitening: Any, *, active: Any, alpha: float, residuals: str
                      ) -> Diagnosis:
    """:func:`regression_tests` on an instrument's objective with the candidate effects (the
    tracker's points or probe, the ballbar's distances: :class:`iwr.effects.tracker.
    TrackerEffectProblem`, :class:`iwr.ballbar.effects.BallbarEffectProblem`; parameters the
    geometric errors, the effects', then the set-up's), at the geometric fit ``x`` (geometric
    errors, then the set-up's; ``active`` its identified ones) with the effects at zero: the
    residuals and their exact Jacobian there, each pose one cluster. ``whitening(problem, xf)``
    gives ``(W, rows, exact, weighting)`` (:func:`regression_tests`). ValueError at a pose
    whose forward kinematics fails."""
    ng = n_geometric
    ne = problem.n_params - ng - problem.setup.n_params
    ns = problem.setup.n_params
    x = np.asarray(x, dtype=float)
    if x.shape != (ng + ns,) or not np.all(np.isfinite(x)):
        raise ValueError(f"x: shape {x.shape}; expected {ng + ns} finite values (the robot's "
                         f"{ng} geometric errors, then the set-up's {ns})")
    mask = np.ones(ng + ns, bool) if active is None else np.asarray(active, bool)
    if mask.shape != (ng + ns,):
        raise ValueError(f"active: shape {mask.shape}; expected {ng + ns} flags")
    xf = np.concatenate([x[:ng], np.zeros(ne), x[ng:]])
    bad = problem.failures(xf)
    if bad:
        raise ValueError(f"{data.where(bad[0][0])}: {bad[0][1]} at the fit")
    r, jac = problem.residuals_and_jacobian(xf)
    n = len(data)
    m = r.size // n
    w, rows, exact, weighting = whitening(problem, xf)
    geo = np.concatenate([np.arange(ng), ng + ne + np.arange(ns)])[mask]
    return regression_tests(r.reshape(n, m), jac.reshape(n, m, -1), geo, ng,
                            problem.robot.effects, cands, w, rows,
                            exact=exact, alpha=alpha, weighting=weighting, residuals=residuals)


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


def _basis(m: np.ndarray) -> np.ndarray:
    """An orthonormal basis of the column space of ``m`` (scaled, so that units do not set the
    rank, at :func:`_residual_ss`'s threshold)."""
    d = np.linalg.norm(m, axis=0)
    u, s, _ = np.linalg.svd(m / np.where(d > 0, d, 1.0), full_matrices=False)
    return u[:, s > max(m.shape) * np.finfo(float).eps * 1e3 * (s[0] if s.size else 0)]


def _own_share(aw: np.ndarray, rest: np.ndarray, z: np.ndarray) -> float:
    """The share of ``z``'s variation beyond the geometry ``aw`` that is not also the other
    effects' (``rest``: the geometry and their regressors): per column ``|M_rest z|^2 /
    |M_aw z|^2`` (``M``: the residual maker), averaged over the columns that vary beyond the
    geometry. Its test's noncentrality is this share of what it would be without the others: 1
    when the effects' patterns are apart, near 0 when the others can mimic it."""
    ua, ur = _basis(aw), _basis(rest)
    za = z - ua @ (ua.T @ z)
    zr = z - ur @ (ur.T @ z)
    na = np.sum(za**2, axis=0)
    keep = na > 1e-18 * max(float(np.sum(z**2)), 1e-300)
    if not np.any(keep):
        return 0.0
    return float(np.mean(np.sum(zr**2, axis=0)[keep] / na[keep]))


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
    u = _basis(rest)
    zt = z - u @ (u.T @ z)
    rt = r - u @ (u.T @ r)
    dz = np.linalg.norm(zt, axis=0)
    zt = zt / np.where(dz > 0, dz, 1.0)
    bread = np.linalg.pinv(zt.T @ zt, rcond=1e-10, hermitian=True)
    beta = bread @ (zt.T @ rt)
    res = rt - zt @ beta  # the residuals of the whole regression
    full = np.hstack([u, _basis(zt)])  # an orthonormal basis of [rest, z]
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
    ``data`` correlate with the leg forces of the data's payloads, the carriage joints' loads
    or the legs' temperatures: None when the data carry neither payload nor temperature
    columns.

    The residuals ``r`` (predicted minus measured leg readings at ``x``; whitened per pose by
    their covariance under ``noise`` when given, as the efficient estimator weighs them, else
    weighted by the data's leg weights) are regressed on the geometry's Jacobian (the
    ``active`` parameters) and the change of the readings each candidate effect would make
    (:func:`candidates`), the derivative of the predicted readings in the effect's parameters
    where it is zero (:func:`iwr.effects.model.predicted_readings` with the effects):

    - **compliance** (payload columns): six columns, leg ``j``'s axial force ``f_kj`` (N) at
      each pose (statics of the platform and the payload, ``f = J^-T w``, at ``x``), times
      1e-3 (coefficient: the leg's compliance, um/N);
    - **thermal** (temperature columns): one column, ``1e-6 D_kj (T_kj - mean T)`` (``D`` the
      leg length; coefficient: the expansion coefficient, ppm/K);
    - **carriage_compliance** (payload columns, a carriage joint that carries a load): one
      column per such joint, the change of the legs at the measured pose when the joint turns
      (moves) by its gravity load (coefficient: its compliance, urad/(N m) or um/N);
    - **carriage_thermal** (the machine's temperature ``T_C``, a prismatic carriage joint): one
      column, the change of the legs when each slide moves by ``1e-6 (T_k - mean T) q_ki``
      (coefficient: the scales' expansion coefficient, ppm/K, shared by the slides).

    Each effect is tested by the F test of its columns given the geometry and the other
    effects' (:class:`EffectTest`), at ``alpha`` divided by the number tested (the two
    compliances as a closed test: together, then each, :func:`effect_tests`), so that data
    with no effect name one with probability at most ``alpha``. The loads need the gravity and
    the platform's mass and centre: the robot's ``[effects.compliance]`` table's when it has
    one, else the defaults of :func:`iwr.effects.api.realistic` (said in ``assumptions``)."""
    from ..implicit_loop import loop_jacobians, sigma_matrix
    from ..noise import Noise
    from .model import predicted_readings

    cands = candidates(robot, data)
    if cands is None:
        return None
    geometric = robot.with_effects()
    ng, n = robot.n_params, len(data)
    x = np.asarray(x, dtype=float)[:ng]
    probe = geometric.with_effects(*cands.effects)
    ne = len(effect_names(probe.effects))
    legs, jac = predicted_readings(probe, np.concatenate([x, np.zeros(ne)]), data.q,
                                   data.poses, data, derivatives=True)
    mask = np.ones(ng, bool) if active is None else np.asarray(active, bool)[:ng]
    if isinstance(noise, Noise):
        _, _, jy = loop_jacobians(geometric, x, data.q, data.poses)
        sig = sigma_matrix(geometric, data, noise)
        cov = np.einsum("kij,kj,klj->kil", jy, sig[:, 6:] ** 2, jy)
        cov[:, np.arange(6), np.arange(6)] += sig[:, :6] ** 2
        w = np.linalg.inv(np.linalg.cholesky(cov))
        weighting = "whitened by the noise model"
        rows = np.ones((n, 6), bool)
    else:
        sw = np.ones((n, 6)) if data.weights is None else np.sqrt(data.weights)
        w = sw[:, :, None] * np.eye(6)
        weighting = ("unweighted" if data.weights is None
                     else "weighted by the data's leg weights")
        rows = sw > 0
    return regression_tests(legs - data.legs, jac, np.flatnonzero(mask), ng, probe.effects,
                            cands, w, rows,
                            exact=isinstance(noise, Noise), alpha=alpha, weighting=weighting,
                            residuals="leg")


#: Each effect's regressors and the unit of its coefficient, as the diagnosis names them.
_REGRESSORS = {"compliance": ("the six leg forces", "um/N"),
               "thermal": ("leg length times temperature", "ppm/K"),
               "carriage_compliance": ("each loaded carriage joint's gravity load",
                                       "urad/(N m)"),
               "carriage_thermal": ("slide reading times machine temperature", "ppm/K"),
               "loads": ("the leg forces and the carriage joints' gravity loads together", "")}


def _label(effect: Any) -> tuple[str, str, tuple[str, ...], tuple[str, ...]]:
    """The regressors, the unit of ``effect``'s coefficients (:data:`_REGRESSORS`) and, for the
    carriage's (urad/(N m) for a revolute joint, um/N for a prismatic one), each coefficient's
    joint and unit."""
    what, unit = _REGRESSORS[effect.name]
    if effect.name != "carriage_compliance":
        return what, unit, (), ()
    joints = tuple(name.removesuffix(".compliance") for name in effect.parameter_names())
    units = tuple(effect.units())
    return (f"the gravity load of {_and(list(joints))}", " or ".join(dict.fromkeys(units)),
            joints, units)


def effect_tests(rw: np.ndarray, aw: np.ndarray, zw: dict[str, np.ndarray],
                 cluster: np.ndarray, *, exact: bool, alpha: float, weighting: str,
                 assumptions: list[str], table: list[str], residuals: str = "leg",
                 labels: dict[str, tuple[str, str, tuple[str, ...], tuple[str, ...]]]
                 | None = None,
                 carriage: list[str] | None = None,
                 slides: list[str] | None = None) -> Diagnosis:
    """The statistics of :func:`diagnose` (and of the tracker kinds' diagnosis,
    :func:`iwr.effects.tracker_diagnosis.diagnose`) once the residuals are built: ``rw`` the
    residuals that carry data (whitened, or weighted), ``aw`` (rows, n) the geometry's
    Jacobian in the active parameters, ``zw`` each candidate effect's regressors (rows, k), in
    the same rows and whitening, ``cluster`` the pose of each row. Each effect is tested given
    the geometry and the others, at ``alpha`` divided by the number tested: with ``exact``
    (whitened by a noise model), or one row per pose, by the F test of the nested regressions,
    else by the cluster-robust (per pose) Wald test (:func:`_cluster_wald`). An effect whose
    regressors add no rank to the others' is not tested (:attr:`EffectTest.testable`), and the
    level is divided among those that are. The two compliances (:data:`LOADS`), when both are
    tested, make a closed test: together first (:attr:`Diagnosis.loads`) at their two shares of
    the level, then each at that level, named only if the joint test rejects; when only the
    joint test does, the diagnosis names the loads and suggests both
    (:attr:`Diagnosis.loads_only`). ``labels``: each effect's regressors, unit and per
    coefficient names and units (:func:`_label`; default :data:`_REGRESSORS`'s); ``carriage``:
    the carriage table's lines (:attr:`Diagnosis.carriage`); ``slides``: the slides' table's
    (:attr:`Diagnosis.slides`)."""
    every = np.concatenate([aw] + list(zw.values()), axis=1)
    rss1, rank1, coef = _residual_ss(every, rw)
    f_dof = rw.size - rank1
    singletons = np.unique(cluster).size == cluster.size
    reduced = {}
    for name in zw:
        rest = np.concatenate([aw] + [v for k, v in zw.items() if k != name], axis=1)
        reduced[name] = (rest, *_residual_ss(rest, rw)[:2])
    level = alpha / max(sum(rank1 - r[2] >= 1 for r in reduced.values()), 1)

    def test(rest: np.ndarray, rss0: float, rank0: int, z: np.ndarray
             ) -> tuple[float, int, int, float]:
        """F, its degrees of freedom (p, f) and the p-value of ``z`` given ``rest``."""
        p = rank1 - rank0
        if p < 1 or f_dof < 1:
            return math.nan, p, f_dof, 1.0
        if exact or singletons:
            # Whitened by the noise model: the exact F test of the nested regressions. One
            # residual per pose (ballbar data): independent residuals, nothing for the cluster-
            # robust test to guard against but unequal variances (a factor of about 2 on a
            # ballbar), and with one row per cluster and most of the rows' degrees of freedom
            # spent on the geometry it rejected too often (docs/effects.md): the F test too.
            stat = ((rss0 - rss1) / p) / (rss1 / f_dof)
            return stat, p, f_dof, float(special.fdtrc(p, f_dof, max(stat, 0.0)))
        stat, dof = _cluster_wald(rest, z, rw, cluster)
        return stat, p, dof, float(special.fdtrc(p, dof, max(stat, 0.0))) if dof >= 1 else 1.0

    # The closed test of the loads (LOADS, when both are tested): their joint hypothesis at
    # their two Bonferroni shares, then each at that level, named only if the joint rejects.
    # Within the group the family-wise level is the group's share (closed testing, Marcus,
    # Peritz and Gabriel 1976), so that the whole stays within alpha.
    group = [n for n in LOADS if n in reduced and rank1 - reduced[n][2] >= 1]
    joint = None
    if len(group) == 2:
        rest = np.concatenate([aw] + [v for k, v in zw.items() if k not in group], axis=1)
        zg = np.concatenate([zw[n] for n in group], axis=1)
        stat, p, dof, pv = test(rest, *_residual_ss(rest, rw)[:2], zg)
        what, unit = _REGRESSORS["loads"]
        joint = EffectTest("loads", what, float(stat), (int(p), int(dof)), pv, 2 * level,
                           np.zeros(0), unit)
    tests = []
    start = aw.shape[1]
    for name, z in zw.items():
        rest, rss0, rank0 = reduced[name]
        stat, p, dof, pv = test(rest, rss0, rank0, z)
        k = list(zw).index(name)
        first = start + sum(v.shape[1] for v in list(zw.values())[:k])
        est = coef[first: first + z.shape[1]]
        what, unit, names, units = (labels or {}).get(name) or (*_REGRESSORS[name], (), ())
        own = _own_share(aw, rest, z) if p >= 1 else 0.0
        closed = None if joint is None or name not in group else joint.significant
        tests.append(EffectTest(name, what, float(stat), (int(p), int(dof)), pv,
                                level if closed is None else joint.alpha,
                                np.asarray(est, dtype=float), unit, names, units, own, closed))
    return Diagnosis(tests, alpha, weighting, assumptions, int(rw.size), table, residuals,
                     list(carriage or []), list(slides or []), joint)
