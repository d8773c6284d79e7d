"""Differential evolution on any problem's ``cost_batch``, polished by Levenberg-Marquardt: DE
for the kinds whose problems have no engine of their own (tracker and ballbar data)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult

from ..result import IdentificationResult
from .de import _STATUS, differential_evolution
from .lm import levenberg_marquardt
from .reduced import ReducedProblem

__all__ = ["de_on_batch"]


def de_on_batch(reduced: ReducedProblem, *, max_evaluations: int | None, seed: int | None,
                 callback: Callable[..., Any] | None, progress: bool | None,
                 polish: bool = True, **options: Any) -> Any:
    """DE (any strategy) on the problem's ``cost_batch`` (one Python call per generation; the
    tracker's and the ballbar's evaluate the population in C++ across threads), polished by LM
    (``polish=False``: DE alone). :func:`iwr.methods.de.de_method` is wired to the pose
    objective's own engine; the other kinds' problems run DE through this."""
    start = time.perf_counter()
    box = np.column_stack([reduced.lower, reduced.upper])
    if max_evaluations is not None:
        options["max_evaluations"] = int(max_evaluations)
    if callback is not None:
        user = callback

        def callback(res: Any) -> Any:  # the user sees full vectors, as from every method
            return user(OptimizeResult(x=reduced.full(res.x), fun=res.fun,
                                       nfev=res.get("nfev", 0), nit=res.get("nit", 0)))
    raw = differential_evolution(reduced.cost_batch, box, seed=seed, callback=callback,
                                 progress=progress, **options)
    x = reduced.full(raw.x)
    fun, nfev = float(raw.fun), int(raw.nfev)
    success, status = bool(raw.success), _STATUS.get(str(raw.reason), "failed")
    message = str(raw.message)
    interrupted = status in ("interrupted", "callback")
    if polish and not interrupted:
        lm = levenberg_marquardt(ReducedProblem(reduced.problem, reduced.active, x),
                                 progress=progress)
        nfev += int(lm.nfev)
        success, status = bool(lm.success), str(lm.status)
        message = f"{message}; polished by Levenberg-Marquardt: {lm.message}"
        if lm.fun <= fun:
            x, fun = lm.x, float(lm.fun)
    return IdentificationResult(x=x, fun=fun, nfev=nfev, nit=int(raw.get("nit", 0)),
                                success=success, status=status, message=message,
                                history={k: np.asarray(v) for k, v in raw.history.items()},
                                wall_time=time.perf_counter() - start,
                                settings={**dict(raw.get("settings") or {}),
                                          "polish": bool(polish), "objective": "cost_batch"})
