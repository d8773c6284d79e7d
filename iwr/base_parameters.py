"""Which parameters to keep where some are exactly dependent (the null directions of a
column-scaled Jacobian), for every kind of data (pose, tracker, ballbar, with effects).

QR with column pivoting picks the best-conditioned subset, but between columns that are exactly
dependent (equal scaled norms: ``joint1.da`` and ``joint3.dd``, ``tracker.x`` and ``joint1.da``)
its choice falls to round-off, so it changes with the instruction set, the data's order or the
last bits of an objective's rounding, and with it the gauge a calibration file is written in.
Pose data go through the parameters in the order of :func:`preference` (:func:`ordered_base`,
:func:`iwr.identifiability`'s default); the null directions of tracker, ballbar and effects
problems keep QR's pivoting but break its ties by the same preference (:func:`pivoted_columns`,
:func:`left_out_directions`)."""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

import numpy as np

__all__ = ["candidate_order", "condition_number", "direction_text", "directions_of",
           "left_out_directions", "observability_indices", "ordered_base", "pivoted_columns",
           "preference", "report_lines"]

# The geometric parameters' names (an effect's, such as leg1.compliance, is neither).
_HEXAPOD = re.compile(r"leg\d+\.(d[ab]_[xyz]|dl0)$")
_CARRIAGE = re.compile(r"joint\d+\.d(alpha|a|d|theta)$")


def preference(names: Sequence[str]) -> np.ndarray:
    """Indices of ``names`` in order of preference for keeping: the hexapod's geometric
    parameters, then every other parameter but the carriage's geometric ones (a tracker's
    registration and reflectors or probe, a ballbar's set-up, effects), then the carriage's
    joints 1, 2, ... Each group in its own order (for pose data the order of
    :func:`iwr.identifiability`'s ordered rule). Where a null direction ties the carriage with
    the instrument's set-up, the carriage is left out: the registration found is the one paired
    with the nominal carriage base, and the same data give the same calibration file whatever
    the rounding."""
    hexapod = [i for i, n in enumerate(names) if _HEXAPOD.match(n)]
    carriage = [i for i, n in enumerate(names) if _CARRIAGE.match(n)]
    other = [i for i, n in enumerate(names) if not (_HEXAPOD.match(n) or _CARRIAGE.match(n))]
    return np.array(hexapod + other + carriage, dtype=int)


def ordered_base(js: np.ndarray, s: np.ndarray, thr: float, rank: int,
                 order: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Indices of the kept and of the left-out columns of the column-scaled Jacobian ``js``
    (both sorted), going through the columns in ``order``; ``s`` its singular values, ``thr``
    the rank threshold on them, ``rank`` the number above it. None when the ordered passes do
    not find ``rank`` columns (the caller falls back to pivoting).

    Distance of each column (unit norm) from the span of the kept ones, by Gram-Schmidt applied
    twice (one pass loses orthogonality at round-off level). Two passes in order of preference:
    the first keeps only columns at distance >= 0.1 from the span (well away from it), so that
    a column that is *nearly* dependent (joint2.da is parallel to joint1.dd up to the angle
    errors, ~1e-3) cannot take the place of a clearly independent one; the second keeps whatever
    else is independent at all: dependent columns are at round-off distance (~1e-13),
    independent ones at least ~s_r, and the cut is their geometric midpoint."""
    n = js.shape[1]
    if not 0 < rank < n:
        return None
    cut = np.sqrt(max(thr, 1e-300) * s[rank - 1])
    # The columns' inner products are those of R in js = QR: the same distances with vectors of
    # n entries instead of one per residual (6 N), and each projection onto the kept ones as two
    # products with their basis (classical Gram-Schmidt, twice), not one per kept vector.
    cols = np.linalg.qr(js, mode="r")
    basis = np.zeros((n, cols.shape[0]))
    kept: list[int] = []
    for limit in (0.1, cut):
        for j in order:
            if j in kept:
                continue
            size = np.linalg.norm(cols[:, j])
            if size == 0:  # a parameter the data do not see at all: never a base one
                continue
            v = cols[:, j] / size
            b = basis[: len(kept)]
            for _ in range(2):
                v = v - b.T @ (b @ v)
            dist = np.linalg.norm(v)
            if dist > limit:
                basis[len(kept)] = v / dist
                kept.append(int(j))
    if len(kept) != rank:
        return None
    base = np.sort(np.array(kept, dtype=int))
    return base, np.setdiff1d(np.arange(n), base)


def pivoted_columns(v: np.ndarray, order: np.ndarray, rtol: float = 1e-6) -> np.ndarray:
    """The k columns of ``v`` (k x n: a null basis, or its columns of the candidates) that QR
    with column pivoting takes first (sorted): each step the column of the largest norm left
    after the chosen ones are projected out, but among columns within ``rtol`` of that norm the
    last in ``order`` (a permutation of the n columns: the one least preferred to keep), so that
    exactly dependent parameters, whose norms tie, are chosen by the rule and not by round-off.
    Norms further apart than ``rtol`` are chosen as QR would (a null basis from the SVD is
    accurate to about 1e-13, far inside the tolerance)."""
    r = np.array(v, dtype=float, copy=True)
    k, n = r.shape
    order = np.asarray(order, dtype=int)
    if not np.array_equal(np.sort(order), np.arange(n)):
        raise ValueError(f"order: not a permutation of the {n} columns")
    rank_of = np.empty(n, dtype=int)
    rank_of[order] = np.arange(n)
    chosen: list[int] = []
    for _ in range(k):
        norms = np.linalg.norm(r, axis=0)
        norms[chosen] = -1.0
        tied = np.flatnonzero(norms >= (1 - rtol) * norms.max())
        j = int(tied[np.argmax(rank_of[tied])])
        chosen.append(j)
        q = r[:, j] / norms[j]
        r -= np.outer(q, q @ r)
    return np.sort(np.array(chosen, dtype=int))


def candidate_order(names: Sequence[str], cand: np.ndarray) -> np.ndarray:
    """:func:`preference` restricted to the candidates ``cand`` (indices into ``names``), as
    positions in ``cand``: the ``order`` of :func:`pivoted_columns` on ``v[:, cand]``."""
    rank_of = np.empty(len(names), dtype=int)
    rank_of[preference(names)] = np.arange(len(names))
    return np.argsort(rank_of[np.asarray(cand, dtype=int)], kind="stable")


def left_out_directions(scaled: np.ndarray, physical: np.ndarray, names: Sequence[str],
                        cand: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One null direction per left-out parameter: ``(left, basis)``, ``left`` the k indices
    (sorted) of the parameters left out, ``basis`` (n x k) the null space re-expressed so that
    direction i moves parameter ``left[i]`` by 1 and the other left-out ones not at all
    (``basis[left]`` is the identity), in the units of ``physical``.

    ``scaled`` (k x n) spans the null space in the column-scaled metric (rows of the SVD's V^T,
    or any basis of them), ``physical`` (n x k) the same space in the parameters' units; the
    left-out parameters are QR's pivots among the candidates ``cand`` (sorted indices, default
    every parameter: :func:`pivoted_columns`), their ties broken by :func:`preference`. The
    tracker's gauge, the effects' and the ballbar's null spaces use it alike."""
    if cand is None:  # ``scaled`` itself (a column selection would copy it in another layout)
        left = pivoted_columns(scaled, preference(names))
    else:
        cand = np.asarray(cand, dtype=int)
        left = cand[pivoted_columns(scaled[:, cand], candidate_order(names, cand))]
    return left, directions_of(physical, left)


def directions_of(physical: np.ndarray, left: np.ndarray) -> np.ndarray:
    """The null space ``physical`` (n x k) re-expressed with one direction per left-out parameter
    ``left`` (k indices whose rows of ``physical`` are independent, as where the other
    parameters are a basis): direction i moves ``left[i]`` by 1 and the other left-out ones not
    at all (n x k)."""
    k = len(left)
    basis = physical @ np.linalg.solve(physical[left], np.eye(k))
    basis[left] = np.eye(k)
    return basis


def direction_text(v: np.ndarray, scale: np.ndarray, names: Sequence[str],
                   tol: float = 1e-6) -> str:
    """``"+1 joint1.dtheta -1 tracker.rz"``: the components of direction ``v`` (physical units)
    whose size in the column-scaled metric (``v * scale``) is above ``tol`` times the largest,
    largest first."""
    scaled = np.abs(v * scale)
    order = [int(i) for i in np.argsort(-scaled) if scaled[i] > tol * scaled.max()]
    return " ".join(f"{v[i]:+.4g} {names[i]}" for i in order)


def observability_indices(s: np.ndarray, n_poses: int) -> dict[str, float]:
    """O1..O4 from the nonzero singular values ``s`` (descending) of a scaled Jacobian.

    - O1 (Borm & Menq 1991): geometric mean of the singular values over sqrt(number of poses),
      ``(s_1 ... s_r)^(1/r) / sqrt(N)``: the volume of the error ellipsoid, as a root so it stays
      finite;
    - O2 (Driels & Pathre 1990): inverse condition number ``s_r / s_1``;
    - O3 (Nahvi, Hollerbach & Hayward 1994): minimum singular value ``s_r``;
    - O4 (Nahvi & Hollerbach 1996), noise amplification index: ``s_r^2 / s_1``.
    """
    if s.size == 0 or s[-1] <= 0:
        return {"O1": 0.0, "O2": 0.0, "O3": 0.0, "O4": 0.0}
    return {
        "O1": float(np.exp(np.mean(np.log(s))) / np.sqrt(max(n_poses, 1))),
        "O2": float(s[-1] / s[0]),
        "O3": float(s[-1]),
        "O4": float(s[-1] ** 2 / s[0]),
    }


def condition_number(s: np.ndarray, rank: int) -> float:
    """``s_1 / s_r`` of the column-scaled Jacobian's identifiable part (its ``rank`` largest
    singular values ``s``, descending); inf at rank 0."""
    return float(s[0] / s[rank - 1]) if rank else math.inf


def report_lines(s: np.ndarray, rank: int, threshold: float, n_poses: int,
                 rtol: float | None = None) -> list[str]:
    """The lines every identifiability report prints of a column-scaled Jacobian's singular
    values ``s`` (descending, all of them): the scaling, the rank, the singular values around
    it, the condition number and the observability indices (:func:`observability_indices`) of
    its identifiable part; for pose, tracker and ballbar data, with effects or not."""
    n = len(s)
    o = observability_indices(np.asarray(s[:rank]), n_poses)
    cond = condition_number(s, rank)
    return [
        "  Jacobian columns scaled to unit norm (unit-free; see docs/identifiability.md)",
        f"  rank {rank} of {n}: {n - rank} unidentifiable direction(s); threshold {threshold:.3g}"
        + (f" (= {rtol:.3g} x s_max)" if rtol is not None else ""),
        f"  singular values: max {s[0]:.4g}, smallest identifiable {s[rank - 1]:.4g}"
        + (f", largest unidentifiable {s[rank]:.3g}" if rank < n else ""),
        f"  condition number (identifiable part) {cond:.4g}",
        "  observability: " + "  ".join(f"{k} {v:.4g}" for k, v in o.items()),
    ]
