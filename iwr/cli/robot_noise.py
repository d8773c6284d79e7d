"""The instruments' noise model of the command line: what ``--noise`` means for a robot's data
(:func:`option_noise`, the one reading of ``iwr simulate``, ``iwr calibrate``, ``iwr compare`` and
``iwr-calibrate``), and a robot file's ``[noise]`` and ``[tracker.noise]`` tables (docs/data.md)
as the commands use them when ``--noise`` is not given."""

from __future__ import annotations

from typing import Any

from ._base import UsageError, load_robot


def noise_source(robot: Any, path: str) -> str:
    """Where the noise model of ``robot`` (read from ``path``) comes from, for the printed
    lines and the report's settings."""
    return f"{path} [noise]" + (" and [tracker.noise]" if robot.tracker is not None else "")


def calibration_noise(path: str) -> tuple[Any, str]:
    """``(noise, source)`` for ``iwr calibrate ROBOT.toml DATA.csv`` without ``--noise``: the
    file's noise model (what ``iwr.identify``'s ``noise=`` takes) and where it comes from, or
    ``(None, "")`` when the file has none. The efficient estimator closes every loop through the
    legs: a file whose leg noise is 0 is refused, as ``--noise legs=0`` is."""
    robot = load_robot(path)
    noise = robot.noise_model
    if noise is None:
        return None, ""
    readings = noise[0] if isinstance(noise, tuple) else noise
    if readings is None or readings.legs <= 0:
        raise UsageError(
            f"{path}: [noise] legs = {0.0 if readings is None else readings.legs!r}: the leg "
            "sensors' noise must be > 0 for the efficient estimator (it closes every loop "
            "through the legs); fix the file, or give --noise (--noise none: eq. (10))")
    return noise, noise_source(robot, path)


OPTION_HELP = (
    "'realistic' (iwr.Noise.realistic()), 'none', or KEY=SIGMA,... over legs, joint_lengths, "
    "joint_angles, position, orientation (mm, rad), e.g. 'legs=0.002,joint_lengths=0.005'. Pose "
    "data: each the sd of its reading (omitted: 0). Tracker and ballbar data (they measure no "
    "pose in {0}): legs and joint_* the readings' sds, and position the instrument's noise level, "
    "its realistic noise (TrackerNoise.leica(), the bar's 1 um) x position / 0.02; without "
    "position the instrument keeps its own noise (the robot file's [tracker.noise], else the "
    "realistic one); orientation is not used")


def option_noise(noise: Any, robot: Any) -> Any:
    """What ``--noise`` (an :class:`iwr.Noise` from :func:`iwr.cli._base.noise_spec`) means for
    ``robot``'s data, in the form its kind takes: the one reading of ``iwr simulate``, ``iwr
    calibrate``, ``iwr compare`` and ``iwr-calibrate`` (they read it two ways before: simulate and
    calibrate dropped ``position`` on tracker and ballbar data, compare refused noisy readings
    without it).

    Pose data: the :class:`iwr.Noise` as it is, each field its reading's sd. An instrument that
    measures no pose in {0} (a laser tracker, a ballbar): the legs' and joints' sds are the
    readings', and ``position`` is the instrument's noise level, as in ``iwr study``
    (:meth:`iwr.kinds.MeasurementKind.experiment_noise`: its realistic noise scaled by
    ``position / 0.02``, so ``realistic`` is the realistic instrument and ``none`` an exact one);
    with readings' noise and no ``position`` the instrument keeps its own noise, the robot
    file's (``[tracker.noise]``) if it has one, else its realistic one
    (:meth:`~iwr.kinds.MeasurementKind.reading_noise`): a user who gives their sensors' noise is
    not asked for the instrument's, and one who gives ``position`` has it used. ``orientation``
    is not used there. Anything but an :class:`iwr.Noise` (``estimate``, a pair) as it is."""
    from ..kinds import for_robot
    from ..noise import Noise

    if not isinstance(noise, Noise):
        return noise
    kind = for_robot(robot)
    if noise.position > 0 or noise.is_zero:
        return kind.experiment_noise(robot, noise)
    model = kind.reading_noise(noise)
    own = robot.noise_model
    if isinstance(model, tuple) and isinstance(own, tuple) and own[1] is not None:
        model = (model[0], own[1])  # the file's instrument table
    return model


def simulation_noise(noise: Any, robot: Any, path: str | None) -> tuple[Any, str | None]:
    """``(noise, source)`` for ``iwr simulate`` and ``iwr compare``, in the form the robot's kind
    takes: ``--noise`` when given (:func:`option_noise`; source None), else the robot file's
    noise model (source: the file and table), else ``iwr.Noise.realistic()`` (source None)."""
    from ..kinds import for_robot
    from ..noise import Noise

    if noise is not None:
        return option_noise(noise, robot), None
    if path is not None and robot.noise_model is not None:
        return for_robot(robot).reading_noise(robot.noise_model), noise_source(robot, path)
    return option_noise(Noise.realistic(), robot), None


def describe(noise: Any) -> str:
    """A noise model in one line: ``legs 0.002, ...`` (``iwr.Noise``), and for a robot with a
    tracker ``...; tracker distance 0.005, ...`` (a ballbar's ``ballbar distance``);
    ``estimate`` as is."""
    import dataclasses

    if isinstance(noise, str):
        return "estimated from the data (variance components)" if noise == "estimate" else noise
    from ..tracker.simulate import TrackerNoise

    parts = noise if isinstance(noise, tuple) else (noise,)
    return "; ".join(
        # the instrument's own noise named after it: "tracker ", "ballbar "
        (type(p).__name__.removesuffix("Noise").lower() + " " if i else "")
        + ", ".join(f"{k} {v:g}" for k, v in dataclasses.asdict(p).items())
        + (" (TrackerNoise.leica())" if i and p == TrackerNoise.leica() else "")
        for i, p in enumerate(parts) if p is not None)
