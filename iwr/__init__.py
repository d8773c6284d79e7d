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
from importlib import metadata as _metadata

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

from .accuracy import Accuracy, PoseErrors, accuracy, pose_errors
from .experiments.compare import Comparison, compare_methods
from .experiments.study import StudyError, StudyResult, study
from .forward import ForwardKinematicsError, forward_kinematics
from .identifiability import (
    IdentifiabilityReport,
    NullDirection,
    ParameterError,
    identifiability,
    parameter_error,
)
from .measurements import MeasurementFileError, Measurements
from .methods import IdentificationResult, ReducedProblem, ResultFileError, identify, load_result
from .methods.de import differential_evolution
from .planning import PosePlan, plan_poses, read_plan
from .problem import Problem, predict_legs
from .robot import Robot, RobotFileError
from .simulate import Noise, UnreachableError, simulate
from .uncertainty import Uncertainty, uncertainty

# The version is written once, in pyproject.toml; the installed package's metadata carries it.
__version__ = _metadata.version("iwr")


__all__ = [
    "Accuracy",
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
