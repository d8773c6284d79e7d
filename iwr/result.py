"""The one result type of every identification method, shaped like scipy.optimize.OptimizeResult,
and its JSON file (also written by ``iwr-calibrate``)."""

from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult

from ._io import atomic_write_text, jsonable

__all__ = ["FitTest", "IdentificationResult", "Outlier", "load_result", "ResultFileError",
           "STATUSES", "source_line"]

RESULT_FORMAT = "iwr-result"
RESULT_VERSION = 1

#: Why a method ended (``IdentificationResult.status``).
STATUSES = {
    "converged": "the method's own convergence test ended the run",
    "stopped": "a limit ended the run first (evaluation budget, generations, time)",
    "callback": "the callback asked to stop",
    "interrupted": "KeyboardInterrupt (Ctrl-C)",
    "failed": "the method failed, or its result is not finite",
    "not calibrated": "the method converged, but the data cannot identify the errors or the "
                      "result is worse than the nominal robot (iwr.reporting.calibration)",
}


#: How the verdict of a fit test at a point where the method was stopped begins
#: (:meth:`FitTest.stopped`).
STOPPED_FIT = "NOT CONVERGED (tested at the point the method stopped, to first order): "


@dataclass(frozen=True)
class FitTest:
    """The global test of the fit: does the weighted residual sum follow its chi-square law?

    Attributes
    ----------
    statistic : float
        Sum of the squared normalised corrections at the solution (``fun``).
    dof : int
        Degrees of freedom: readings - nuisance unknowns - identified parameters
        (``6 N - n_active`` for leg data: 6 closure equations per pose).
    p_value : float
        ``P(chi2(dof) >= statistic)``.
    alpha : float
        Significance level of the test.
    fit_ok : bool
        The statistic is within its law (``p_value >= alpha``), no identified error is beyond its
        plausible size and the outliers are few enough to be outliers.
    verdict : str
        One line for a report.
    causes : list of str
        What is wrong, with the likely causes, when ``fit_ok`` is False; notes otherwise.
    implausible : list of (str, float, float)
        Parameters beyond their plausible size: (name, value, limit), mm or rad.
    """

    statistic: float
    dof: int
    p_value: float
    alpha: float
    fit_ok: bool
    verdict: str
    causes: list[str] = field(default_factory=list)
    implausible: list[tuple[str, float, float]] = field(default_factory=list)

    def stopped(self) -> FitTest:
        """This test of a point where a limit stopped the method before it converged: the same
        test, a passing verdict saying so (the chi-square test minimises to first order around
        that point, so it may pass where the point is still far from the solution: "the model
        fits the data" of a DE run stopped after two generations). A failing one is left as it
        is: the job leads its causes with :data:`iwr.calibration.STOPPED_CAUSE`."""
        return replace(self, verdict=f"{STOPPED_FIT}{self.verdict}") if self.fit_ok else self

    @property
    def variance_factor(self) -> float:
        """``statistic / dof``: 1 on average when model, data and noise model agree."""
        return self.statistic / self.dof if self.dof > 0 else math.nan

    def to_dict(self) -> dict[str, Any]:
        """The test as a result file and a report's JSON hold it."""
        return {"statistic": self.statistic, "dof": self.dof, "p_value": self.p_value,
                "alpha": self.alpha, "fit_ok": self.fit_ok, "verdict": self.verdict,
                "causes": list(self.causes),
                "implausible": [{"parameter": n, "value": v, "limit": lim}
                                for n, v, lim in self.implausible]}

    def __str__(self) -> str:
        lines = [self.verdict]
        lines += [f"  - {c}" for c in self.causes]
        return "\n".join(lines)


@dataclass(frozen=True)
class Outlier:
    """A pose whose readings fail the outlier test.

    Attributes
    ----------
    pose : int
        Row of the measurements.
    where : str
        ``"pose 17"`` or ``"data.csv, line 19"``.
    statistic : float
        The pose's test value ``v^T Q_vv^+ v`` (chi-square with ``dof`` degrees of freedom).
    dof : int
    p_value : float
    instrument : str
        The reading with the largest normalised residual (Baarda's w-test), e.g. ``"leg3"``,
        ``"q2"``, ``"position.x"``: the likeliest culprit under a single gross error.
    w : float
        Its w-test value (standard normal for a clean reading).
    removed : bool
        Whether the pose was left out of the final solution.
    confounded : tuple of str
        Other readings of the pose whose w-test value is as large (within 1 %): the data cannot
        tell them from ``instrument`` (for example ``q1``, the rail's prismatic joint along z0,
        against ``position.z``: moving the base up moves every leg as moving the platform down).
    data_set : str
        ``"identification"``, or ``"validation"`` for a held-out pose (tested at the identified
        parameters, :mod:`iwr.gross_errors`; ``removed``: left out of the accuracy figures).
    test : str
        ``"chi2"``: ``statistic`` is the pose's chi-square value under the noise model;
        ``"tau"``: without a noise model, its largest studentized residual (Pope's test, the
        noise estimated from the residuals; ``dof`` their redundancy; ``w`` studentized too).
    line : int or None
        The pose's line in its file (None for data not read from one), for messages.
    key : str or None
        A digest of the pose's readings and measurements (:func:`pose_key`): what a result file
        records so that ``iwr report`` leaves out the poses the run left out, whatever the
        layout of the file it is given (comments, another format of the same data).
    """

    pose: int
    where: str
    statistic: float
    dof: int
    p_value: float
    instrument: str
    w: float
    removed: bool
    confounded: tuple[str, ...] = ()
    data_set: str = "identification"
    test: str = "chi2"
    line: int | None = None
    key: str | None = None

    def __str__(self) -> str:
        held = self.data_set == "validation"
        what = (("left out of the accuracy figures" if held else "removed") if self.removed
                else "kept")
        alt = f" or {', '.join(self.confounded)}, indistinguishable" if self.confounded else ""
        head = f"{self.where}" + (" (held-out pose)" if held else "")
        if self.test == "tau":
            value = (f"largest studentized residual {self.statistic:.1f} (no noise model: "
                     f"Pope's test, {self.dof} dof, p = {self.p_value:.2g})")
        else:
            value = f"chi2 {self.statistic:.1f} ({self.dof} dof, p = {self.p_value:.2g})"
        return (f"{head}: {value}; largest normalised residual {self.instrument} "
                f"(w = {self.w:+.1f}{alt}); {what}")


def source_line(data: Any, k: int) -> int | None:
    """The file line of pose ``k`` of ``data`` (any kind's data keep ``lines``), else None."""
    return None if data.lines is None else int(data.lines[k])


def pose_keys(data: Any) -> list[str]:
    """A digest of each pose of ``data``: its row of readings and measurements
    (:meth:`iwr.kinds.MeasurementKind.rows`, NaN where nothing was seen), the same for the same
    values in any file layout."""
    import hashlib

    from . import kinds

    rows = np.ascontiguousarray(kinds.of(data).rows(data), dtype="<f8")
    rows = np.where(np.isnan(rows), np.nan, rows + 0.0)  # one NaN, and -0.0 as 0.0
    return [hashlib.sha256(r.tobytes()).hexdigest()[:16] for r in rows]


def pose_key(data: Any, k: int) -> str:
    """:func:`pose_keys` of pose ``k``."""
    return pose_keys(data)[k]


class ResultFileError(ValueError):
    """A result file is missing, malformed or of another format."""


#: What a method or the calibration job may add to a result, beyond the fields every result has:
#: typed attributes that read None when absent (``res.fit is None``: no fit test), never a
#: dictionary read with ``.get()``. Name -> what it holds.
OPTIONAL_FIELDS: dict[str, str] = {
    "fit": ":class:`FitTest`: the fit test (the size check; chi-square with a noise model)",
    "outliers": "list of :class:`Outlier`: the poses that failed the outlier or gross-error "
                "tests, those left out with ``removed`` True",
    "gross_errors": "str: what the gross-error screen tested, and how",
    "covariance": "ndarray: the covariance of the active parameters (the efficient estimator)",
    "std": "ndarray: their standard deviations, NaN for those held fixed",
    "noise": "the noise model used, with the components estimated from the data",
    "variance_components": "list of :class:`iwr.estimation.VarianceComponent`",
    "predicted": ":class:`iwr.accuracy_prediction.PredictedAccuracy`: the tool accuracy the "
                 "covariance predicts",
    "cost_eq10": "float: eq. (10)'s cost at ``x``, for a method that minimised another "
                 "objective (``fun`` is then its own, e.g. a chi-square statistic)",
    "used": "ndarray of bool: the poses the estimate used",
    "verdict": "str: the fit test's verdict, one line",
    "solver_status": "str: the inner solver's own status",
    "corrections": "ndarray: the estimated corrections of every reading (NaN: pose not used)",
    "residuals": "ndarray: the normalised residuals of every reading",
    "redundancy": "ndarray: the redundancy numbers of every reading",
    "reading_names": "list of str: the readings of one pose, in the columns' order",
    "pose_statistic": "ndarray: each pose's chi-square value",
    "reason": "str: why DE stopped (``iwr.methods.de``)",
    "state": "DE's state, to resume it",
}


class IdentificationResult(OptimizeResult):
    """The outcome of an identification method (:func:`iwr.identify`), the same for every method.

    A :class:`scipy.optimize.OptimizeResult`: attributes are also items (``res.x``,
    ``res["x"]``), and a method may add its own (DE: ``reason``, ``state``).

    Attributes
    ----------
    x : ndarray
        The identified error parameters (all of them, fixed ones included).
    fun : float
        The cost of eq. (10) at ``x`` (mm^2).
    nfev, nit : int
        Objective evaluations (a Jacobian counts as one) and iterations or generations.
    success : bool
        True only when the method's convergence test ended the run *and* ``x`` and ``fun`` are
        finite (never for a result that is not).
    status : str
        Why the run ended: one of :data:`STATUSES` (``"converged"``, ``"stopped"``,
        ``"callback"``, ``"interrupted"``, ``"failed"``); not given, ``"converged"`` for a
        success, else read from ``message`` (:func:`status_from_message`: ``"stopped"`` unless
        it names an interruption, a callback, ...).
    message : str
        The same in words, with the method's details.
    interrupted : bool
        ``status == "interrupted"``: Ctrl-C ended the run, which returned its best point so far.
        A command line writes the result and exits with 130.
    method : str
    history : dict of ndarray
        The per-generation or per-evaluation log: at least ``nfev`` and ``best``.
    wall_time : float
        Seconds.
    parameter_names : list of str
    active : ndarray of bool or None
        The parameters that were identified (the others held at the start).
    settings : dict
        Every setting of the run, for the record.
    fit, outliers, gross_errors, covariance, ...
        What a method or the calibration job adds (:data:`OPTIONAL_FIELDS`), None when it did
        not; ``fit``, ``outliers`` and ``gross_errors`` are kept in the result file.
    fit_ok : bool or None
        The fit test's answer (``fit.fit_ok``), None without one.
    """

    def __init__(
        self,
        *,
        x: Any,
        fun: float,
        nfev: int,
        success: bool,
        message: str,
        nit: int = 0,
        status: str | None = None,
        method: str = "",
        history: dict[str, Any] | None = None,
        wall_time: float = math.nan,
        parameter_names: list[str] | None = None,
        active: Any = None,
        settings: dict[str, Any] | None = None,
        **extra: Any,
    ) -> None:
        if status is None:  # as a result file of an older iwr is read (its message says)
            status = status_from_message(bool(success), str(message))
        if status not in STATUSES:
            raise ValueError(f"status: {status!r}; expected one of {', '.join(STATUSES)}")
        super().__init__(
            x=np.asarray(x, dtype=float),
            fun=float(fun),
            nfev=int(nfev),
            nit=int(nit),
            success=bool(success) and status == "converged",
            status=status,
            message=str(message),
            method=str(method),
            history=dict(history or {}),
            wall_time=float(wall_time),
            parameter_names=list(parameter_names or []),
            active=None if active is None else np.asarray(active, dtype=bool),
            settings=dict(settings or {}),
            **extra,
        )
        self.check_finite()

    def __repr__(self) -> str:
        # SciPy's formatter fails on empty nested dicts (settings, history, at any depth): the
        # summary fields only, one per line as SciPy shows them.
        keys = ("method", "status", "success", "message", "fun", "nfev", "nit", "x")
        width = max(map(len, keys))
        return "\n".join(f"{k:>{width}}: {self[k]}" for k in keys if k in self)

    def __getattr__(self, name: str) -> Any:
        try:
            return self[name]
        except KeyError:
            if name in OPTIONAL_FIELDS:
                return None
            raise AttributeError(name) from None

    @property
    def fit_ok(self) -> bool | None:
        """The fit test's answer, None when there was none."""
        fit = self.fit
        return None if fit is None else bool(fit.fit_ok)

    @property
    def left_out(self) -> list[Outlier]:
        """The outliers left out of the solution or of the accuracy figures."""
        return [o for o in (self.outliers or []) if o.removed]

    @property
    def interrupted(self) -> bool:
        """Ctrl-C ended the run (``status == "interrupted"``)."""
        return self.status == "interrupted"

    def check_finite(self) -> None:
        """A result that is not finite is never a success: ``success`` False, status "failed"."""
        if math.isfinite(self.fun) and np.all(np.isfinite(self.x)):
            return
        note = ("the cost at the result is not finite" if np.all(np.isfinite(self.x))
                else "the parameters of the result are not finite")
        self["success"] = False
        if self.status in ("converged", "stopped"):
            self["status"] = "failed"
        if note not in self.message:
            self["message"] = f"{self.message}; {note}" if self.message else note

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dictionary (strict JSON: a value that is not finite is written null)."""
        hist = {k: jsonable(np.asarray(v), finite_only=True)
                for k, v in dict(self.get("history", {})).items()}
        fun = float(self.fun)
        return {
            "format": RESULT_FORMAT,
            "version": RESULT_VERSION,
            "method": self.method,
            "x": jsonable(np.asarray(self.x, dtype=float), finite_only=True),
            "parameter_names": list(self.parameter_names),
            "fun": fun if math.isfinite(fun) else None,
            "nfev": int(self.nfev),
            "nit": int(self.nit),
            "success": bool(self.success),
            "status": str(self.status),
            "message": str(self.message),
            "wall_time": jsonable(float(self.wall_time), finite_only=True),
            "settings": jsonable(self.settings),
            "history": hist,
            **({"fit": jsonable(self.fit.to_dict(), finite_only=True)}
               if self.fit is not None else {}),
            **({"outliers": [jsonable(asdict(o), finite_only=True) for o in self.outliers]}
               if self.outliers is not None else {}),
            **({"gross_errors": self.gross_errors} if isinstance(self.gross_errors, str)
               else {}),
            # which parameters were identified (the others held at their start): a report of
            # the file tells "held at nominal" from "identified, but arbitrary"
            **({"active": [bool(a) for a in np.asarray(self.active).ravel()]}
               if self.get("active") is not None else {}),
        }

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the result as JSON, atomically; :func:`load_result` reads it back."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=1) + "\n")

    def named(self) -> dict[str, float]:
        """The identified parameters by name."""
        return dict(zip(self.parameter_names, map(float, self.x), strict=True))


def _typed(value: Any, kind: str, where: str) -> Any:
    """A recorded value of the expected JSON type, else ValueError naming it: ``"int"``,
    ``"bool"``, ``"str"``, ``"float"`` (a number, or null for a value that was not finite),
    ``"int?"``/``"str?"`` (or null)."""
    if kind.endswith("?"):
        if value is None:
            return None
        kind = kind[:-1]
    ok = {"int": isinstance(value, int) and not isinstance(value, bool),
          "bool": isinstance(value, bool), "str": isinstance(value, str),
          "float": value is None or (isinstance(value, (int, float))
                                     and not isinstance(value, bool))}[kind]
    if not ok:
        expected = {"int": "an integer", "bool": "true or false", "str": "a string",
                    "float": "a number or null"}[kind]
        raise ValueError(f"{where}: expected {expected}, got {value!r:.40}")
    return math.nan if kind == "float" and value is None else value


def _active(data: dict[str, Any], n: int) -> np.ndarray | None:
    """The ``active`` mask a result file records (a bool per parameter), or None."""
    active = data.get("active")
    if active is None:
        return None
    if (not isinstance(active, list) or len(active) != n
            or not all(isinstance(a, bool) for a in active)):
        raise ValueError(f"active: expected {n} true/false values, one per parameter")
    return np.array(active, dtype=bool)


def _recorded(data: dict[str, Any]) -> dict[str, Any]:
    """The fit test, outliers and gross-error description a result file keeps, each value of
    its type (a bad one named)."""
    out: dict[str, Any] = {}
    fit = data.get("fit")
    if fit is not None:
        if not isinstance(fit, dict):
            raise ValueError(f"fit: expected an object, got {fit!r:.60}")
        causes = fit.get("causes", [])
        implausible = fit.get("implausible", [])
        if not isinstance(causes, list) or not isinstance(implausible, list):
            raise ValueError("fit.causes, fit.implausible: expected lists")
        out["fit"] = FitTest(
            statistic=float(_typed(fit["statistic"], "float", "fit.statistic")),
            dof=_typed(fit["dof"], "int", "fit.dof"),
            p_value=float(_typed(fit["p_value"], "float", "fit.p_value")),
            alpha=float(_typed(fit["alpha"], "float", "fit.alpha")),
            fit_ok=_typed(fit["fit_ok"], "bool", "fit.fit_ok"),
            verdict=_typed(fit["verdict"], "str", "fit.verdict"),
            causes=[_typed(c, "str", f"fit.causes[{i}]") for i, c in enumerate(causes)],
            implausible=[(_typed(d["parameter"], "str", f"fit.implausible[{i}].parameter"),
                          float(_typed(d["value"], "float", f"fit.implausible[{i}].value")),
                          float(_typed(d["limit"], "float", f"fit.implausible[{i}].limit")))
                         for i, d in enumerate(implausible)])
    outliers = data.get("outliers")
    if outliers is not None:
        if not isinstance(outliers, list):
            raise ValueError(f"outliers: expected a list, got {outliers!r:.60}")
        types = {"pose": "int", "where": "str", "statistic": "float", "dof": "int",
                 "p_value": "float", "instrument": "str", "w": "float", "removed": "bool",
                 "data_set": "str", "test": "str", "line": "int?", "key": "str?"}
        out["outliers"] = []
        for i, o in enumerate(outliers):
            if not isinstance(o, dict) or not set(types) | {"confounded"} >= set(o):
                raise ValueError(f"outliers[{i}]: expected an object with keys among "
                                 f"{sorted(set(types) | {'confounded'})}, got {o!r:.80}")
            missing = [k for k in ("pose", "where", "statistic", "dof", "p_value", "instrument",
                                   "w", "removed") if k not in o]
            if missing:
                raise ValueError(f"outliers[{i}]: missing {missing}")
            values = {k: _typed(o[k], t, f"outliers[{i}].{k}") for k, t in types.items()
                      if k in o}
            for k in ("statistic", "p_value", "w"):
                values[k] = float(values[k])
            if values.get("data_set", "identification") not in ("identification", "validation"):
                raise ValueError(f"outliers[{i}].data_set: {values['data_set']!r}; expected "
                                 "'identification' or 'validation'")
            if values.get("test", "chi2") not in ("chi2", "tau"):
                raise ValueError(f"outliers[{i}].test: {values['test']!r}; expected 'chi2' or "
                                 "'tau'")
            confounded = o.get("confounded", [])
            if not isinstance(confounded, list):
                raise ValueError(f"outliers[{i}].confounded: expected a list")
            values["confounded"] = tuple(_typed(c, "str", f"outliers[{i}].confounded")
                                         for c in confounded)
            out["outliers"].append(Outlier(**values))
    if "gross_errors" in data:
        out["gross_errors"] = _typed(data["gross_errors"], "str", "gross_errors")
    return out


def status_from_message(success: bool, message: str) -> str:
    """The status of a file that keeps only ``success`` and ``message`` (an older iwr's)."""
    if success:
        return "converged"
    text = message.lower()
    if text.startswith("not calibrated"):  # iwr.reporting.calibration.NOT_CALIBRATED
        return "not calibrated"
    if "not finite" in text:
        return "failed"
    if "interrupt" in text or "sigint" in text or "sigterm" in text:
        return "interrupted"
    if "callback" in text:
        return "callback"
    return "stopped"


#: The largest result file read (a result of 10^5 parameters with its history is a few MB).
MAX_RESULT_BYTES = 1 << 30


def _status(data: dict[str, Any], success: bool, message: str) -> str:
    """The status a result file records (since it records one), one of :data:`STATUSES`; else
    read from its message (:func:`status_from_message`: a file of an older iwr, which read a
    converged run whose model did not fit as "stopped"). ``success`` true is refused with a
    status other than "converged" (a success is a converged run, never a stopped or failed one:
    the file contradicts itself)."""
    if data.get("status") is None:
        return status_from_message(success, message)
    status = _typed(data["status"], "str", "status")
    if status not in STATUSES:
        raise ValueError(f"status: {status!r:.40}; expected one of {', '.join(STATUSES)}")
    if success and status != "converged":
        raise ValueError(f"success: true, but status {status!r}: only a converged run is a "
                         "success")
    return status


def _numbers(value: Any, where: str, kind: str = "float") -> list[Any]:
    """A recorded list of numbers (``kind`` "float": a number or null each, null read as NaN;
    "int": an integer each), flat, else ValueError naming the entry at fault."""
    if not isinstance(value, list):
        raise ValueError(f"{where}: expected a list of numbers, got {value!r:.60}")
    return [_typed(v, kind, f"{where}[{i}]") for i, v in enumerate(value)]


#: The settings a result file records that iwr reads back (``iwr report``), and their JSON type:
#: any other setting is kept as written, for the record.
SETTINGS_TYPES: dict[str, str] = {
    "data_fingerprint": "str?", "data_file": "str?", "robot_file": "str?", "weighting": "str?",
    "sources": "object?", "robot_model": "object?", "validation_split": "object?",
    "objective": "object?", "polish_result": "object?",
}


def _settings(data: dict[str, Any]) -> dict[str, Any]:
    """The ``settings`` object of a result file, the settings iwr reads of their type."""
    settings = data.get("settings")
    if settings is None:
        return {}
    if not isinstance(settings, dict):
        raise ValueError(f"settings: expected an object, got {settings!r:.60}")
    for key, kind in SETTINGS_TYPES.items():
        value = settings.get(key)
        if value is None:
            continue
        if kind == "object?":
            if not isinstance(value, dict):
                raise ValueError(f"settings.{key}: expected an object, got {value!r:.60}")
        else:
            _typed(value, kind, f"settings.{key}")
    for role, path in (settings.get("sources") or {}).items():
        _typed(path, "str?", f"settings.sources.{role}")
    return settings


def _history(data: dict[str, Any]) -> dict[str, np.ndarray]:
    """The ``history`` object of a result file: a list of numbers per key (integers for the
    evaluation and generation counts)."""
    history = data.get("history")
    if history is None:
        return {}
    if not isinstance(history, dict):
        raise ValueError(f"history: expected an object of lists of numbers, got {history!r:.60}")
    return {k: np.array(_numbers(v, f"history.{k}",
                                 "int" if k in ("nfev", "generation") else "float"),
                        dtype=int if k in ("nfev", "generation") else float)
            for k, v in history.items()}


def _parameters(data: dict[str, Any]) -> tuple[np.ndarray, list[str]]:
    """``x`` (a number or null per parameter, null read as NaN: a value that was not finite)
    and ``parameter_names`` (a string per parameter, or none recorded) of a result file."""
    names = data.get("parameter_names")
    names = [] if names is None else names
    if not isinstance(names, list):
        raise ValueError(f"parameter_names: expected a list of strings, got {names!r:.60}")
    names = [_typed(n, "str", f"parameter_names[{i}]") for i, n in enumerate(names)]
    if len(set(names)) < len(names):
        twice = next(n for i, n in enumerate(names) if n in names[:i])
        raise ValueError(f"parameter_names: {twice!r} is named twice")
    x = data["x"]
    if not isinstance(x, list):
        raise ValueError(f"x: expected a list of numbers, one per parameter, got {x!r:.60}")
    for i, v in enumerate(x):
        if v is not None and (not isinstance(v, (int, float)) or isinstance(v, bool)):
            what = f" ({names[i]})" if i < len(names) else ""
            raise ValueError(f"x[{i}]{what}: expected a number or null, got {v!r:.40}")
    if names and len(names) != len(x):
        raise ValueError(f"x: {len(x)} values, but parameter_names names {len(names)} "
                         "parameters")
    return np.array([math.nan if v is None else float(v) for v in x], dtype=float), names


def load_result(path: str | os.PathLike[str]) -> IdentificationResult:
    """Read a result written by :meth:`IdentificationResult.save` or by ``iwr-calibrate``.

    A value written null (not finite) reads as NaN; such a result is never a success."""
    from ._io import NotRegularFileError, open_regular

    path = Path(path)
    try:
        with open_regular(path) as fh:  # a named pipe or a device: refused, not read for ever
            raw = fh.read(MAX_RESULT_BYTES + 1)
        if len(raw) > MAX_RESULT_BYTES:
            raise ResultFileError(f"{path}: larger than {MAX_RESULT_BYTES >> 20} MB: not a "
                                  "result file")
        data = json.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise ResultFileError(f"{path}: no such file") from None
    except NotRegularFileError as exc:
        raise ResultFileError(str(exc)) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ResultFileError(f"{path}: not a readable JSON result ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != RESULT_FORMAT:
        raise ResultFileError(f"{path}: not an iwr result (no 'format': '{RESULT_FORMAT}')")
    missing = [k for k in ("x", "fun", "nfev", "success", "message") if k not in data]
    if missing:
        raise ResultFileError(f"{path}: missing keys {missing}")
    try:
        version = data.get("version", RESULT_VERSION)
        if _typed(version, "int", "version") > RESULT_VERSION or version < 1:
            raise ValueError(f"version: {version}; this iwr reads versions 1 to "
                             f"{RESULT_VERSION} (a newer iwr wrote it?)")
        x, names = _parameters(data)
        fun = float(_typed(data["fun"], "float", "fun"))
        success = _typed(data["success"], "bool", "success")
        message = _typed(data["message"], "str", "message")
        nfev = _typed(data["nfev"], "int", "nfev")
        nit = _typed(data.get("nit", 0), "int", "nit")
        for key, count in (("nfev", nfev), ("nit", nit)):
            if count < 0:
                raise ValueError(f"{key}: {count}; expected a count >= 0")
        return IdentificationResult(
            x=x,
            fun=fun,
            nfev=nfev,
            nit=nit,
            success=success,
            status=_status(data, success, message),
            message=message,
            method=_typed(data.get("method", ""), "str", "method"),
            wall_time=float(_typed(data.get("wall_time"), "float", "wall_time")),
            parameter_names=names,
            settings=_settings(data),
            active=_active(data, x.size),
            history=_history(data),
            **_recorded(data),
        )
    except KeyError as exc:
        raise ResultFileError(f"{path}: missing key {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ResultFileError(f"{path}: {exc}") from None
