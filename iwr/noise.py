"""The instruments' noise models: :class:`Noise` (the readings of the robot and a pose measured
in {0}) and :class:`TrackerNoise` (a laser tracker's, in its spherical coordinates). The lowest
layer of iwr: every other module may use them (docs/kinds.md)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

__all__ = ["MAX_SIGMA", "MIN_SIGMA", "Noise", "TrackerNoise", "check_sigmas"]

#: The smallest non-zero standard deviation of a noise model (mm, rad, mm per m): far below any
#: instrument's, and far above what breaks the weighting (1 / sigma^2 overflows near 1e-155).
MIN_SIGMA = 1e-9
#: The largest standard deviation of a noise model (mm, rad, mm per m): a tenth of a metre, or
#: radians by the hundred, is no instrument's noise but a wrong unit or a typo (``legs=1e9``), and
#: readings simulated with more leave every robot's range (|length| <= 1e5 mm).
MAX_SIGMA = 100.0


def check_sigmas(model: Any) -> None:
    """ValueError unless every field of the noise model ``model`` (a dataclass of standard
    deviations: :class:`Noise`, :class:`TrackerNoise`, a kind's own) is a finite number, 0 (no
    noise) or within :data:`MIN_SIGMA` .. :data:`MAX_SIGMA`; the message names the class, the
    field and its value."""
    for f in fields(model):
        v = getattr(model, f.name)
        where = f"{type(model).__name__}.{f.name}"
        if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v)
                                       and v >= 0):
            raise ValueError(f"{where}: {v!r}; expected a finite number >= 0")
        if 0 < v < MIN_SIGMA:
            raise ValueError(f"{where}: {v!r} is below any instrument's noise; expected 0 "
                             f"(none) or at least {MIN_SIGMA:g}")
        if v > MAX_SIGMA:
            raise ValueError(f"{where}: {v!r} is beyond any instrument's noise; expected at "
                             f"most {MAX_SIGMA:g} (mm, rad, mm per m)")


@dataclass(frozen=True)
class Noise:
    """Standard deviations of Gaussian measurement noise (mm and rad).

    Attributes
    ----------
    legs : float
        On each leg sensor reading (mm). Leg encoders: micrometres, e.g. 0.002.
    joint_lengths : float
        On each prismatic joint reading (mm).
    joint_angles : float
        On each revolute joint reading (rad).
    position : float
        On each coordinate of the measured platform position (mm). A laser tracker: tens of
        micrometres, e.g. 0.02.
    orientation : float
        On each axis of a small random rotation applied to the measured orientation (rad).
    """

    legs: float = 0.0
    joint_lengths: float = 0.0
    joint_angles: float = 0.0
    position: float = 0.0
    orientation: float = 0.0

    def __post_init__(self) -> None:
        check_sigmas(self)

    @classmethod
    def realistic(cls) -> Noise:
        """A laser tracker and good encoders: legs 2 um, joints 5 um and 5 urad, tracker 20 um
        and 20 urad."""
        return cls(legs=0.002, joint_lengths=0.005, joint_angles=5e-6, position=0.02,
                   orientation=2e-5)

    @property
    def is_zero(self) -> bool:
        return not any((self.legs, self.joint_lengths, self.joint_angles, self.position,
                        self.orientation))



@dataclass(frozen=True)
class TrackerNoise:
    """One-sigma noise of a laser tracker, in its spherical coordinates (mm, mm per m, rad).

    A measured point is off its true position by a radial error (along the line of sight, the
    distance meter's) of sigma ``distance + distance_per_m * d`` and a transverse error (across
    it, the angle encoders') of sigma ``transverse + transverse_per_m * d`` along each of the two
    directions across the line of sight, ``d`` the distance from the tracker (the origin of {T})
    in metres. Across the line of sight the error grows with the distance and dominates: the
    noise ellipsoid is long across, short along. A probe's orientation gets a small random
    rotation of sigma ``orientation`` (rad) about each axis.

    The defaults, :meth:`leica`, are half the maximum permissible errors (MPE, ISO 10360-10:2021
    Annex D) of Leica's laser tracker subsystem as its user manual states them (Leica Absolute
    Tracker AT500 user manual, section 2.8.2): ADM +-(10 um + 0.3 um/m), transverse +-(15 um +
    6 um/m); the manual says that typical results are half the MPE, read here as one sigma. The
    probe's 0.005 degree is half of the +-0.01 degree commonly quoted for 6-DOF probes.
    """

    distance: float = 0.005
    distance_per_m: float = 0.00015
    transverse: float = 0.0075
    transverse_per_m: float = 0.003
    orientation: float = math.radians(0.005)

    def __post_init__(self) -> None:
        check_sigmas(self)

    @classmethod
    def leica(cls) -> TrackerNoise:
        """The defaults: half the MPE of Leica's absolute tracker (see the class notes)."""
        return cls()

    @classmethod
    def none(cls) -> TrackerNoise:
        return cls(0.0, 0.0, 0.0, 0.0, 0.0)

    @property
    def is_zero(self) -> bool:
        return not any((self.distance, self.distance_per_m, self.transverse,
                        self.transverse_per_m, self.orientation))

    def sigmas(self, d_mm: Any) -> tuple[np.ndarray, np.ndarray]:
        """(radial, transverse) sigma (mm) at distances ``d_mm`` (mm) from the tracker."""
        d_m = np.asarray(d_mm, dtype=float) / 1000.0
        return (self.distance + self.distance_per_m * d_m,
                self.transverse + self.transverse_per_m * d_m)

    @staticmethod
    def basis(points: Any) -> np.ndarray:
        """Per point (..., 3) of {T}, the orthonormal rows (..., 3, 3) ``[e_r, e_1, e_2]``: the line
        of sight from the tracker (the origin of {T}) and the two directions across it (``e_1``
        perpendicular to ``e_r`` and to the axis least aligned with it): the principal axes of
        the point's noise."""
        p = np.asarray(points, dtype=float)
        d = np.linalg.norm(p, axis=-1, keepdims=True)
        er = p / np.where(d > 0, d, 1.0)
        helper = np.zeros_like(er)
        idx = np.argmin(np.abs(er), axis=-1)
        np.put_along_axis(helper, idx[..., None], 1.0, axis=-1)
        e1 = np.cross(er, helper)
        e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
        e2 = np.cross(er, e1)
        return np.stack([er, e1, e2], axis=-2)

    def whitening(self, points: Any) -> np.ndarray:
        """Per point (..., 3) of {T}, the 3x3 matrix ``W`` (..., 3, 3) with ``W^T W`` the inverse
        of the point's noise covariance (``W @ error`` has unit covariance): the rows of
        :meth:`basis` divided by the radial and transverse sigmas at the point's distance."""
        p = np.asarray(points, dtype=float)
        sr, st = self.sigmas(np.linalg.norm(p, axis=-1))
        if np.any(np.asarray(sr) <= 0) or np.any(np.asarray(st) <= 0):
            raise ValueError("tracker noise: the radial and the transverse sigma must be > 0 "
                             f"(distance {self.distance}, transverse {self.transverse}); a "
                             "tracker reading is never exact")
        scale = np.stack([1.0 / sr, 1.0 / st, 1.0 / st], axis=-1)
        return self.basis(p) * scale[..., :, None]

    def covariance(self, points: Any) -> np.ndarray:
        """Per point (..., 3) of {T}, its noise covariance (..., 3, 3) (mm^2): ``sigma_r^2`` along
        the line of sight, ``sigma_t^2`` across it; the law :meth:`perturb` draws from."""
        p = np.asarray(points, dtype=float)
        b = self.basis(p)
        sr, st = self.sigmas(np.linalg.norm(p, axis=-1))
        var = np.stack([np.square(sr), np.square(st), np.square(st)], axis=-1)
        return np.einsum("...ki,...k,...kj->...ij", b, var, b)

    def perturb(self, points: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Points (..., 3) in {T} with tracker noise; three standard normal draws per point
        (radial, then the two transverse directions of :meth:`basis`)."""
        p = np.asarray(points, dtype=float)
        z = rng.standard_normal(p.shape)
        b = self.basis(p)
        sr, st = self.sigmas(np.linalg.norm(p, axis=-1, keepdims=True))
        return (p + sr * z[..., :1] * b[..., 0, :]
                + st * (z[..., 1:2] * b[..., 1, :] + z[..., 2:3] * b[..., 2, :]))


def instrument_level(noise: Noise, instrument: str = "the instrument",
                     realistic: str = "its realistic noise") -> tuple[Noise, float]:
    """An experiment's noise level (an :class:`iwr.Noise`, e.g.
    :func:`iwr.experiments.harness.noise_at`) for an instrument that measures no pose in {0}: the
    leg and joint readings' noise (no position or orientation noise), and the level's
    ``position`` noise as a multiple of :meth:`Noise.realistic`'s, by which the instrument's own
    realistic noise is scaled.

    A level whose readings are noisy and whose ``position`` is 0 is refused (ValueError naming
    ``instrument``, e.g. "the bar", and ``realistic``, what ``position=0.02`` gives it): it would
    make the instrument exact beside noisy readings, which no instrument is (``iwr compare
    --noise legs=0.002`` on ballbar data made the bar exact without a word)."""
    readings = replace(noise, position=0.0, orientation=0.0)
    if noise.position == 0 and not readings.is_zero:
        given = ",".join(f"{f.name}={getattr(noise, f.name):g}" for f in fields(noise)
                         if getattr(noise, f.name))
        raise ValueError(
            f"noise: {given} without position: here position is the noise level of "
            f"{instrument} ({realistic} x position / 0.02; the readings' sds as given), and "
            f"position=0 would make {instrument} exact beside noisy readings; add "
            f"position=0.02 for {realistic} (or another level), give a pair (iwr.Noise, "
            f"{instrument}'s noise model), or 'none' for noise-free data")
    return readings, noise.position / Noise.realistic().position


def axis_whitening(points: Any, sigmas: Any) -> np.ndarray:
    """Per point (..., 3) of {T} with standard uncertainties ``sigmas`` (..., 3) along the x, y
    and z axes of {T} (tracker software's per-point uncertainties), the 3x3 ``W`` (..., 3, 3)
    with ``W^T W`` the inverse of ``diag(sigma_x^2, sigma_y^2, sigma_z^2)`` and its rows along the
    line of sight and across it, as :meth:`TrackerNoise.whitening`: ``W = L^-1 B`` with ``B``
    the rows of :meth:`TrackerNoise.basis` and ``L`` the Cholesky factor of ``B C B^T``, so that
    the first row is the distance's alone (with equal sigmas ``W = B / sigma``, as
    ``TrackerNoise(distance=sigma, transverse=sigma)`` gives)."""
    p = np.asarray(points, dtype=float)
    s = np.asarray(sigmas, dtype=float)
    if s.shape != p.shape or not np.all(np.isfinite(s) & (s > 0)):
        raise ValueError(f"sigmas: shape {s.shape} for points {p.shape}; every sigma finite and "
                         "> 0 expected")
    b = TrackerNoise.basis(p)
    cov = np.einsum("...ki,...i,...li->...kl", b, np.square(s), b)
    return np.linalg.solve(np.linalg.cholesky(cov), b)


def split_instrument_noise(noise: Any, instrument: type, data: str, example: str
                           ) -> tuple[Noise | None, Any]:
    """The readings' and the instrument's parts of ``noise`` for data of an instrument that
    measures no pose in {0} (``None``, an :class:`Noise` of the leg and joint readings, an
    ``instrument`` noise model, or a pair of both), as :func:`iwr.simulate` takes it. ``data``
    and ``example`` (the instrument's noise written out) are for the messages."""
    if noise is None:
        return None, None
    if isinstance(noise, instrument):
        return None, noise
    pair = (noise, None) if isinstance(noise, Noise) else noise
    if not (isinstance(pair, tuple) and len(pair) == 2
            and isinstance(pair[0], (Noise, type(None)))
            and isinstance(pair[1], (instrument, type(None)))):
        raise TypeError(f"noise: {noise!r}; for {data} expected None, an iwr.Noise (readings), "
                        f"a {instrument.__name__} or a pair (Noise, {instrument.__name__})")
    if pair[0] is not None and (pair[0].position or pair[0].orientation):
        raise ValueError("noise: an iwr.Noise with position or orientation noise describes a "
                         f"pose measured in {{0}}; for {data} give noise=(iwr.Noise(legs=..., "
                         f"joint_lengths=..., joint_angles=...), {example})")
    return pair


def split_noise(noise: Any) -> tuple[Noise | None, TrackerNoise | None]:
    """The readings' and the tracker's parts of ``noise`` for a robot with a tracker (``None``,
    an :class:`Noise` of the readings, a :class:`TrackerNoise`, or a pair of both), as
    :func:`iwr.simulate` takes it."""
    return split_instrument_noise(noise, TrackerNoise, "a robot with a tracker",
                                  "iwr.tracker.TrackerNoise.leica()")
