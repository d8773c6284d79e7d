"""The instruments' noise model of a robot file (its ``[noise]`` and ``[tracker.noise]`` tables,
docs/data.md) as ``iwr calibrate`` and ``iwr simulate`` use it when ``--noise`` is not given."""

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


def simulation_noise(noise: Any, robot: Any, path: str | None) -> tuple[Any, str | None]:
    """``(noise, source)`` for ``iwr simulate``: ``--noise`` when given (source None), else the
    robot file's noise model (source: the file and table), else ``iwr.Noise.realistic()``
    (source None)."""
    from ..noise import Noise

    if noise is not None:
        return noise, None
    if path is not None and robot.noise_model is not None:
        return robot.noise_model, noise_source(robot, path)
    return Noise.realistic(), None


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
