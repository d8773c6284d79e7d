"""Where a lower layer calls up: registered hooks, imported by their dotted name on first use.

The package's layers (``tools/layers.py``: data, problems, solvers, public functions, the
calibration job, experiments, reports, command line) import only downwards. A few conveniences
of a lower layer need a higher one: ``Problem.save`` writes the problem file whose reader builds
problems; ``iwr.compare_methods(out=...)`` and ``iwr.study(report=True)`` write their reports.
They reach it through this table, as :func:`iwr.kinds.register` reaches a kind's implementation
(``"iwr.kinds.pose:PoseKind"``): the table names every upward call in one place, and nothing is
imported before it is used.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["HOOKS", "hook"]

#: Hook name -> ``"module:attribute"``.
HOOKS: dict[str, str] = {
    # iwr.Problem and iwr.tracker.TrackerProblem: .save() and .load()
    "save_problem": "iwr.problem_file:save_problem",
    "load_problem": "iwr.problem_file:load_problem",
    # iwr.problem_file.load_problem: a file of tracker data with effects (issue 23)
    "tracker_effect_problem": "iwr.effects.tracker:TrackerEffectProblem",
    # iwr.ballbar.BallbarProblem.from_file_fields: a file of ballbar data with effects (issue 23)
    "ballbar_effect_problem": "iwr.ballbar.effects:BallbarEffectProblem",
    # iwr.ballbar.BallbarMeasurements.to_csv()
    "write_ballbar": "iwr.ballbar.files:write_ballbar",
    # iwr.compare_methods(out=...) and Comparison.summary_markdown()
    "compare_report": "iwr.reporting.compare:write_report",
    "compare_summary_table": "iwr.reporting.compare:summary_table",
    "markdown_table": "iwr.reporting.tables:markdown_table",
    # iwr.fit_test's check of data that cannot identify the robot (iwr.calibrate's rule)
    "degenerate_data": "iwr.analysis.identifiability:degenerate_data",
    # iwr.kinds.MeasurementKind.calibrated_robot: a robot with effects, their values written in
    "apply_effects": "iwr.effects.api:apply",
    # iwr.study(report=True)
    "study_report": "iwr.reporting.study:report",
}


def hook(name: str) -> Any:
    """The object registered as ``name`` in :data:`HOOKS`, its module imported now."""
    try:
        spec = HOOKS[name]
    except KeyError:
        raise KeyError(f"hook {name!r}: not registered (known: {', '.join(sorted(HOOKS))})"
                       ) from None
    module, _, attribute = spec.partition(":")
    return getattr(importlib.import_module(module), attribute)


def lazy_package(package: str, names: dict[str, str], submodules: tuple[str, ...] = ()
                 ) -> tuple[Any, Any]:
    """``(__getattr__, __dir__)`` for a package whose public names are imported on first use
    (PEP 562): ``names`` maps each to its submodule (``".api"``), ``submodules`` lists those
    reachable as attributes (``package.api``) before anything imported them. Importing one
    submodule (``iwr.robot`` imports ``iwr.tracker.setup``) then runs nothing of the others."""
    module = importlib.import_module(package)

    def __getattr__(name: str) -> Any:
        if name in names:
            value = getattr(importlib.import_module(names[name], package), name)
        elif name in submodules:
            value = importlib.import_module(f".{name}", package)
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        setattr(module, name, value)
        return value

    def __dir__() -> list[str]:
        return sorted(set(vars(module)) | set(names) | set(submodules))

    return __getattr__, __dir__
