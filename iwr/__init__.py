"""iwr: kinematic calibration of hybrid serial-parallel robots.

The IWR (Intersector Welding Robot) is a 4-DOF serial carriage carrying a 6-DOF Stewart hexapod.
iwr identifies its geometric error parameters from leg sensor readings at measured poses, by
Levenberg-Marquardt (the default), differential evolution (Wang, Wu & Handroos) and NLopt baselines
on the same objective (:mod:`iwr.methods`).
"""

from __future__ import annotations

# First: Ctrl-C while the iwr commands start exits 130 with one line, not a traceback.
from . import _startup  # noqa: F401

# isort: split
from typing import TYPE_CHECKING, Any

try:
    from . import _core  # noqa: F401  (the compiled module; checked first for a clear message)
except ImportError as _exc:  # pragma: no cover - exercised by a subprocess test
    import os as _os

    raise ImportError(
        f"iwr: the compiled module iwr._core is missing from {_os.path.dirname(__file__)}. "
        "This is probably the source folder of a repository checkout, found first because Python "
        "was started in the checkout: run Python from another folder to use the installed "
        "package, or install in place with pip install -e . (see README.md)"
    ) from _exc

# IWR_KERNEL, the objective's SIMD variant (docs/de.md, "Across machines"), for every process that
# imports iwr: also the workers a command starts (Dask's spawned processes carry the command's
# argv). A bad value is an ImportError, but in the commands, whose main reports it in one line with
# exit status 2 (_startup.command_kernel).
try:
    _core._select_kernel_from_environment()
except ValueError as _exc:
    if _startup._command() is None:
        raise ImportError(f"iwr: {_exc}") from None

# What every use needs (no module of iwr is named like a function here: tools/layers.py checks).
# None of these imports SciPy.
from .analysis.accuracy import Accuracy, PoseErrors, accuracy, pose_errors
from .analysis.identifiability import (
    IdentifiabilityReport,
    NullDirection,
    ParameterError,
    identifiability,
    parameter_error,
)
from .analysis.uncertainty import Uncertainty, uncertainty
from .forward import ForwardKinematicsError, forward_kinematics
from .measurements import MeasurementFileError, Measurements
from .problem import Problem, predict_legs
from .robot import Robot, RobotFileError
from .simulation import Noise, UnreachableError, simulate

# The rest is imported on first use (module __getattr__, PEP 562): the methods import SciPy's
# optimize, the experiments everything; a short command (``iwr --help``) pays for neither.
_LAZY = {
    "Calibration": ".calibration",
    "calibrate": ".calibration",
    "calibrated_robot": ".calibration",
    "Comparison": ".experiments.compare",
    "compare_methods": ".experiments.compare",
    "StudyError": ".experiments.monte_carlo",
    "StudyResult": ".experiments.monte_carlo",
    "study": ".experiments.monte_carlo",
    "IdentificationResult": ".methods",
    "ReducedProblem": ".methods",
    "ResultFileError": ".methods",
    "identify": ".methods",
    "load_result": ".methods",
    "differential_evolution": ".methods.de",
    "PosePlan": ".planning",
    "plan_poses": ".planning",
    "read_plan": ".planning",
}

if TYPE_CHECKING:  # the same names for type checkers (and for tools/layers.py's import graph)
    from .calibration import Calibration, calibrate, calibrated_robot
    from .experiments.compare import Comparison, compare_methods
    from .experiments.monte_carlo import StudyError, StudyResult, study
    from .methods import (
        IdentificationResult,
        ReducedProblem,
        ResultFileError,
        identify,
        load_result,
    )
    from .methods.de import differential_evolution
    from .planning import PosePlan, plan_poses, read_plan


def __getattr__(name: str) -> Any:
    """The lazily imported names of ``__all__``, and ``__version__``."""
    if name == "__version__":
        # The version is written once, in pyproject.toml; the installed package's metadata
        # carries it (importlib.metadata costs a short command some 30-70 ms: read when asked).
        from importlib import metadata

        value: Any = metadata.version("iwr")
    elif name in _LAZY:
        from importlib import import_module

        value = getattr(import_module(_LAZY[name], __name__), name)
    else:
        raise AttributeError(f"module 'iwr' has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


__all__ = [
    "Accuracy",
    "Calibration",
    "Comparison",
    "ForwardKinematicsError",
    "IdentifiabilityReport",
    "IdentificationResult",
    "MeasurementFileError",
    "Measurements",
    "Noise",
    "NullDirection",
    "ParameterError",
    "PoseErrors",
    "PosePlan",
    "Problem",
    "ReducedProblem",
    "ResultFileError",
    "Robot",
    "RobotFileError",
    "StudyError",
    "StudyResult",
    "Uncertainty",
    "UnreachableError",
    "__version__",
    "accuracy",
    "calibrate",
    "calibrated_robot",
    "compare_methods",
    "differential_evolution",
    "forward_kinematics",
    "identifiability",
    "identify",
    "load_result",
    "parameter_error",
    "plan_poses",
    "pose_errors",
    "predict_legs",
    "read_plan",
    "simulate",
    "study",
    "uncertainty",
]
