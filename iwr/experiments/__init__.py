"""Simulated calibration experiments: one harness (:mod:`.harness`: scenario, cell, evaluation;
:mod:`.executors`: in this process or on Dask) and its two uses, :func:`compare_methods`
(``iwr compare``, :mod:`.compare`) and :func:`study` (``iwr study``, :mod:`.monte_carlo`)."""

from __future__ import annotations

from .compare import Comparison, compare_methods
from .harness import ArgumentError, Cell, Scenario, evaluate, noise_at
from .monte_carlo import StudyError, StudyResult, read_table, study

__all__ = [
    "ArgumentError",
    "Cell",
    "Comparison",
    "Scenario",
    "StudyError",
    "StudyResult",
    "compare_methods",
    "evaluate",
    "noise_at",
    "read_table",
    "study",
]
