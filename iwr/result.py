"""The one result type of every identification method, shaped like scipy.optimize.OptimizeResult,
and its JSON file (also written by ``iwr-calibrate``)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult

from ._io import atomic_write_text, jsonable

__all__ = ["IdentificationResult", "load_result", "ResultFileError", "STATUSES"]

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


class ResultFileError(ValueError):
    """A result file is missing, malformed or of another format."""


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
        ``"callback"``, ``"interrupted"``, ``"failed"``).
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
        if status is None:
            status = "converged" if success else "stopped"
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
            "message": str(self.message),
            "wall_time": jsonable(float(self.wall_time), finite_only=True),
            "settings": jsonable(self.settings),
            "history": hist,
        }

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the result as JSON, atomically; :func:`load_result` reads it back."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=1) + "\n")

    def named(self) -> dict[str, float]:
        """The identified parameters by name."""
        return dict(zip(self.parameter_names, map(float, self.x), strict=True))


def _floats(value: Any, where: str) -> np.ndarray:
    """A JSON number or list of numbers, null read as NaN (a value that was not finite)."""
    try:
        arr = np.array(value, dtype=object)
        return np.where(arr == None, math.nan, arr).astype(float)  # noqa: E711 (elementwise)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: expected numbers, got {value!r:.60}") from None


def status_from_message(success: bool, message: str) -> str:
    """The status of a file, which keeps only ``success`` and ``message``."""
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


def load_result(path: str | os.PathLike[str]) -> IdentificationResult:
    """Read a result written by :meth:`IdentificationResult.save` or by ``iwr-calibrate``.

    A value written null (not finite) reads as NaN; such a result is never a success."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ResultFileError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ResultFileError(f"{path}: not a readable JSON result ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != RESULT_FORMAT:
        raise ResultFileError(f"{path}: not an iwr result (no 'format': '{RESULT_FORMAT}')")
    missing = [k for k in ("x", "fun", "nfev", "success", "message") if k not in data]
    if missing:
        raise ResultFileError(f"{path}: missing keys {missing}")
    try:
        x = _floats(data["x"], "x")
        fun = float(_floats(data["fun"], "fun"))
        wall = data.get("wall_time")
        success = bool(data["success"])
        message = str(data["message"])
        return IdentificationResult(
            x=x,
            fun=fun,
            nfev=int(data["nfev"]),
            nit=int(data.get("nit", 0)),
            success=success,
            status=status_from_message(success, message),
            message=message,
            method=str(data.get("method", "")),
            wall_time=math.nan if wall is None else float(wall),
            parameter_names=list(data.get("parameter_names", [])),
            settings=data.get("settings", {}),
            history={k: _floats(v, f"history.{k}") if k != "nfev" and k != "generation"
                     else np.asarray(v) for k, v in data.get("history", {}).items()},
        )
    except (TypeError, ValueError) as exc:
        raise ResultFileError(f"{path}: {exc}") from None
