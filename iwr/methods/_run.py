"""What every method shares: the evaluation budget, the best point so far and its history, the
user's callback (SciPy's convention), the progress bar, and why the run ended."""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult

from .reduced import ReducedProblem

__all__ = ["INT32_MAX", "INT64_MAX", "Monitor", "Stop", "call_back", "check_budget", "int_arg",
           "show_progress"]

#: Evaluations between two progress-bar updates (tqdm's own throttling costs a clock read).
_BAR_EVERY = 64


class Stop(Exception):
    """Raised inside a method's objective wrapper to end the run; the monitor knows why."""


#: The largest values of the C++ integer types the methods' arguments are passed as (``int``, the
#: threads and sizes; ``int64``, the generation and evaluation counts): a larger Python integer
#: would fail pybind11's (or NLopt's) conversion with a dump of the signature, not naming it.
INT32_MAX = 2**31 - 1
INT64_MAX = 2**63 - 1


def int_arg(name: str, value: Any, minimum: int, maximum: int | None = None) -> int:
    """``value`` as an integer >= ``minimum`` (and <= ``maximum``, when given): a Python or NumPy
    integer, not a bool nor a float (2.5 or 3.0), else a ValueError naming ``name`` and the
    value."""
    expected = (f"an integer >= {minimum}" if maximum is None
                else f"an integer from {minimum} to {maximum}")
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name}: {value!r}; expected {expected}")
    if value < minimum or (maximum is not None and value > maximum):
        raise ValueError(f"{name}: {value}; expected {expected}")
    return int(value)


def check_budget(value: Any, minimum: int = 1, maximum: int | None = None) -> int:
    """``max_evaluations``, the budget every method takes, as an integer >= ``minimum`` (and
    <= ``maximum``: the range of the integer type a method passes it as)."""
    return int_arg("max_evaluations", value, minimum, maximum)


def show_progress(progress: bool | None) -> bool:
    """``progress=None``: a bar when standard error is a terminal."""
    return sys.stderr.isatty() if progress is None else bool(progress)


def call_back(callback: Callable[[OptimizeResult], Any], info: OptimizeResult) -> bool:
    """SciPy's convention: a truthy return (``np.True_`` included) or ``StopIteration`` stops."""
    try:
        return bool(callback(info))
    except StopIteration:
        return True


class Monitor:
    """Counts evaluations against ``max_evaluations``, keeps the best point seen and its history,
    calls ``callback(intermediate_result)`` after every evaluation (an ``OptimizeResult`` with the
    best point so far: ``x`` the full vector, ``fun``, ``nfev``, ``nit``), updates a tqdm bar of
    evaluations against the budget, and records why the run stopped.

    ``log_every``: a history entry after every evaluation (else after each improvement; either way
    the history is closed at the last evaluation by :meth:`history`).
    """

    def __init__(
        self,
        reduced: ReducedProblem,
        name: str,
        max_evaluations: int,
        callback: Callable[[OptimizeResult], Any] | None,
        progress: bool | None,
        *,
        log_every: bool = False,
    ) -> None:
        self.reduced = reduced
        self.max_evaluations = max_evaluations
        self.callback = callback
        self.log_every = log_every
        self.nfev = 0
        self.best_f = math.inf
        self.best_z: np.ndarray | None = None
        self._hist_nfev: list[int] = []
        self._hist_best: list[float] = []
        self.status = ""  # "" while running; else a key of result.STATUSES
        self.message = ""
        self._pending = 0
        self.bar = None
        if show_progress(progress):
            from tqdm import tqdm

            self.bar = tqdm(total=max_evaluations, desc=name, unit="eval", unit_scale=True,
                            leave=False, file=sys.stderr, dynamic_ncols=True)

    def stop(self, status: str, message: str) -> Stop:
        """Record why the run ends (the first reason wins) and return the exception to raise."""
        if not self.status:
            self.status, self.message = status, message
        return Stop()

    def interrupted(self) -> None:
        """Ctrl-C: the run ends with the best point so far."""
        self.stop("interrupted", "interrupted (Ctrl-C)")

    def spend(self) -> None:
        """Count one evaluation about to be made; raise :class:`Stop` when the budget is spent."""
        if self.nfev >= self.max_evaluations:
            raise self.stop(
                "stopped", f"evaluation budget exhausted (max_evaluations={self.max_evaluations})"
            )
        self.nfev += 1

    def observe(self, z: np.ndarray, f: float, nit: int | None = None) -> None:
        """Record the cost ``f`` at reduced point ``z`` (just evaluated); raise :class:`Stop` if
        the callback asks to stop."""
        improved = f < self.best_f  # NaN never is
        if improved:
            self.best_f = float(f)
            self.best_z = np.array(z, dtype=float)
        if improved or self.log_every:
            self._hist_nfev.append(self.nfev)
            self._hist_best.append(self.best_f)
        if self.bar is not None:
            self._pending += 1
            if self._pending >= _BAR_EVERY:
                self._flush()
        if self.callback is not None:
            info = OptimizeResult(
                x=self.best_x(), fun=self.best_f, nfev=self.nfev,
                nit=self.nfev if nit is None else nit,
            )
            if call_back(self.callback, info):
                raise self.stop("callback", "stopped by the callback")

    def best_x(self) -> np.ndarray:
        """The best full vector so far (the start before any finite evaluation)."""
        return self.reduced.full(self.best_z) if self.best_z is not None else self.reduced.x0.copy()

    def history(self) -> dict[str, np.ndarray]:
        nfev, best = list(self._hist_nfev), list(self._hist_best)
        if not nfev or nfev[-1] != self.nfev:
            # Close the curve at the last evaluation, so a plot shows where the run ended.
            nfev.append(self.nfev)
            best.append(self.best_f)
        return {"nfev": np.array(nfev, dtype=np.int64), "best": np.array(best)}

    def _flush(self) -> None:
        assert self.bar is not None
        self.bar.update(self._pending)
        self.bar.set_postfix_str(f"best {self.best_f:.4g}", refresh=False)
        self._pending = 0

    def close(self) -> None:
        if self.bar is not None:
            self._flush()
            self.bar.close()
            self.bar = None
