"""The result of an identification, shaped like scipy.optimize.OptimizeResult, and its file."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult

from ._io import atomic_write_text, jsonable

__all__ = ["IdentificationResult", "load_result", "ResultFileError"]

RESULT_FORMAT = "iwr-result"
RESULT_VERSION = 1


class ResultFileError(ValueError):
    """A result file is missing, malformed or of another format."""


class IdentificationResult(OptimizeResult):
    """The outcome of :func:`iwr.identify`.

    Attributes
    ----------
    x : ndarray
        The identified error parameters (all of them, fixed ones included).
    fun : float
        The cost of eq. (10) at ``x``, evaluated afresh (mm^2).
    nfev, nit : int
        Objective evaluations (a Jacobian counts as one) and iterations or generations.
    success : bool
    message : str
    method : str
    history : dict of ndarray
        The per-generation or per-iteration log: at least ``nfev`` and ``best``.
    wall_time : float
        Seconds.
    parameter_names : list of str
    settings : dict
        Every setting of the run, for the record.
    """

    def to_dict(self) -> dict[str, Any]:
        """A JSON-able dictionary."""
        hist = {k: np.asarray(v).tolist() for k, v in dict(self.get("history", {})).items()}
        return {
            "format": RESULT_FORMAT,
            "version": RESULT_VERSION,
            "method": self.get("method", ""),
            "x": np.asarray(self.x, dtype=float).tolist(),
            "parameter_names": list(self.get("parameter_names", [])),
            "fun": float(self.fun),
            "nfev": int(self.nfev),
            "nit": int(self.get("nit", 0)),
            "success": bool(self.success),
            "message": str(self.message),
            "wall_time": float(self.get("wall_time", math.nan)),
            "settings": jsonable(self.get("settings", {})),
            "history": hist,
        }

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the result as JSON, atomically; :func:`load_result` reads it back."""
        atomic_write_text(path, json.dumps(self.to_dict(), indent=1) + "\n")

    def named(self) -> dict[str, float]:
        """The identified parameters by name."""
        return dict(zip(self.parameter_names, map(float, self.x), strict=True))


def load_result(path: str | os.PathLike[str]) -> IdentificationResult:
    """Read a result written by :meth:`IdentificationResult.save` or by ``iwr-calibrate``."""
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
    out = IdentificationResult(
        x=np.array(data["x"], dtype=float),
        fun=float(data["fun"]),
        nfev=int(data["nfev"]),
        nit=int(data.get("nit", 0)),
        success=bool(data["success"]),
        message=str(data["message"]),
        method=str(data.get("method", "")),
        wall_time=float(data.get("wall_time", math.nan)),
        parameter_names=list(data.get("parameter_names", [])),
        settings=data.get("settings", {}),
        history={k: np.asarray(v) for k, v in data.get("history", {}).items()},
    )
    return out
