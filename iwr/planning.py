"""Pose planning: choose K of M candidate measurement poses to maximise an observability index.

The information that a set S of poses carries about the base parameters is
``M(S) = sum_{k in S} Js_k^T Js_k``, where ``Js_k`` is the 6-row block of pose k of the Jacobian,
restricted to the base parameters and column-scaled once for all candidates (so that the scaling
does not change with the subset). Its eigenvalues are the squared singular values of the stacked
Jacobian, so each observability index of :mod:`iwr.identifiability` is a function of them:
O1 (D-optimality: the geometric mean), O2 (inverse condition number), O3 (E-optimality: the
smallest), O4 (noise amplification, ``s_min^2 / s_max``).

The search is greedy (add the pose that raises the index most), then an exchange pass in the
manner of Fedorov (swap a chosen pose for an unchosen one while that raises the index), until no
swap helps. While the chosen poses cannot yet determine every base parameter (fewer than
``rank / 6`` poses), all indices are zero, so the greedy start maximises ``log det(M + eps I)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .identifiability import IdentifiabilityReport, column_scale, identifiability
from .measurements import Measurements
from .problem import Problem, predict_legs
from .robot import Robot
from .simulate import Noise, add_noise

__all__ = ["PosePlan", "plan_poses", "measure"]

CRITERIA = ("O1", "O2", "O3", "O4")


@dataclass
class PosePlan:
    """The poses chosen by :func:`plan_poses`.

    Attributes
    ----------
    indices : ndarray of int
        Rows of the candidates chosen, in the order the greedy pass added them (the exchange pass
        replaces in place).
    criterion : str
    value : float
        The index of the chosen set (with the candidates' fixed column scaling; O1 as the
        geometric mean of the singular values divided by sqrt(k)).
    greedy_value : float
        The index after the greedy pass, before exchanges.
    n_exchanges : int
    base_indices : ndarray of int
        The base parameters the information is computed for.
    measurements : Measurements
        The chosen candidate rows.
    """

    indices: np.ndarray
    criterion: str
    value: float
    greedy_value: float
    n_exchanges: int
    base_indices: np.ndarray
    measurements: Measurements

    def __str__(self) -> str:
        return (
            f"{len(self.indices)} poses chosen for {self.criterion}: {self.value:.4g} "
            f"(greedy {self.greedy_value:.4g}, {self.n_exchanges} exchange(s))"
        )


def _criterion(eig: np.ndarray, name: str, k: int) -> np.ndarray:
    """Index values from eigenvalues (..., r) of information matrices, ascending."""
    ev = np.clip(eig, 0.0, None)
    s = np.sqrt(ev)
    smin, smax = s[..., 0], s[..., -1]
    with np.errstate(divide="ignore", invalid="ignore"):
        if name == "O1":
            out = np.exp(np.mean(np.log(np.where(s > 0, s, 1e-300)), axis=-1)) / np.sqrt(k)
        elif name == "O2":
            out = smin / smax
        elif name == "O3":
            out = smin
        else:
            out = smin**2 / smax
    return np.nan_to_num(out)


def _as_candidates(robot: Robot, candidates: Any) -> Measurements:
    if isinstance(candidates, Measurements):
        return candidates
    try:
        q, poses = candidates
    except (TypeError, ValueError):
        raise TypeError(
            "candidates: expected an iwr.Measurements or a pair (q, poses)"
        ) from None
    poses = np.asarray(poses, dtype=float)
    q = np.asarray(q, dtype=float).reshape(len(poses), robot.n_joints)
    legs = predict_legs(robot, np.zeros(robot.n_params), q, poses)
    return Measurements(q, poses, legs, joint_types=robot.joint_types)


def plan_poses(
    robot: Robot,
    candidates: Any,
    n_poses: int,
    criterion: str = "O1",
    seed: int | None = None,
    *,
    x: Any = None,
    exchange: bool = True,
    max_passes: int = 20,
    report: IdentifiabilityReport | None = None,
) -> PosePlan:
    """Choose ``n_poses`` of the candidate poses that maximise an observability index.

    Parameters
    ----------
    robot : Robot
        The nominal robot.
    candidates : Measurements or (q, poses)
        M candidate poses: joint readings (M, n_joints) and platform poses in the world frame
        (M, 6). Leg readings, if any, are not used.
    n_poses : int
        Number of poses to choose, at least ``ceil(rank / 6)`` so the base parameters can be
        determined.
    criterion : {"O1", "O2", "O3", "O4"}
        The index to maximise (see :func:`iwr.identifiability`). O1 (D-optimal) is the usual
        choice; O3 and O4 guard the weakest direction.
    seed : int, optional
        Breaks ties between equally good candidates at random (reproducibly); ``None``: ties go
        to the lowest index.
    x : array_like, optional
        Where to linearise (default: the nominal robot).
    exchange : bool
        Follow the greedy pass with exchange passes.
    max_passes : int
        At most this many exchange passes over the chosen poses.
    report : IdentifiabilityReport, optional
        Identifiability of all candidates, if already computed (defines the base parameters).

    Returns
    -------
    PosePlan
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion: {criterion!r}; expected one of {', '.join(CRITERIA)}")
    cand = _as_candidates(robot, candidates)
    n_cand = len(cand)
    x = np.zeros(robot.n_params) if x is None else np.asarray(x, dtype=float)
    if report is None:
        report = identifiability(robot, cand, x)
    base = report.base_indices
    r = base.size
    k_min = -(-r // 6)
    if (isinstance(n_poses, bool) or not isinstance(n_poses, (int, np.integer))
            or not k_min <= n_poses <= n_cand):
        raise ValueError(
            f"n_poses: {n_poses!r}; expected an integer from {k_min} (to determine {r} base parameters from "
            f"6 readings per pose) to {n_cand} (the number of candidates)"
        )
    k = int(n_poses)
    jac = Problem(robot, cand).jacobian(x)[:, base]
    js = (jac / column_scale(jac)).reshape(n_cand, 6, r)
    info = np.einsum("kij,kil->kjl", js, js)  # per-pose information, (M, r, r)
    rng = np.random.default_rng(seed) if seed is not None else None
    eps = 1e-9 * float(np.trace(info.sum(axis=0))) / r

    def pick(values: np.ndarray, allowed: np.ndarray) -> int:
        vals = np.where(allowed, values, -np.inf)
        best = np.max(vals)
        ties = np.flatnonzero(vals >= best - 1e-12 * abs(best))
        return int(ties[0] if rng is None else rng.choice(ties))

    def logdets(base_info: np.ndarray) -> np.ndarray:
        """``log det(base_info + eps I + info[c])`` for every c, by the determinant lemma
        ``det(A + J^T J) = det(A) det(I + J A^-1 J^T)``: one Cholesky factor and one triangular
        solve for all candidates instead of M eigen-decompositions."""
        a = base_info + eps * np.eye(r)
        low = np.linalg.cholesky(a)
        b = np.linalg.solve(low, js.transpose(2, 1, 0).reshape(r, 6 * n_cand))  # L^-1 J^T
        b = b.reshape(r, 6, n_cand)
        g = np.einsum("ijc,ilc->cjl", b, b) + np.eye(6)
        return 2.0 * np.sum(np.log(np.diag(low))) + np.linalg.slogdet(g)[1]

    def scores(base_info: np.ndarray, size: int, name: str | None) -> np.ndarray:
        """Index of base_info + info[c] for every candidate c (name None: regularised logdet).
        O1 is a monotone function of log det at a fixed number of poses, so it is ranked by
        log det too."""
        if name is None or name == "O1":
            return logdets(base_info)
        out = np.empty(n_cand)
        for lo in range(0, n_cand, 256):  # chunks bound the memory (256 x r x r)
            ev = np.linalg.eigvalsh(base_info + info[lo : lo + 256])
            if name is None:
                out[lo : lo + 256] = np.sum(np.log(ev + eps), axis=-1)
            else:
                out[lo : lo + 256] = _criterion(ev, name, size)
        return out

    def value(mat: np.ndarray, size: int) -> float:
        return float(_criterion(np.linalg.eigvalsh(mat), criterion, size))

    chosen: list[int] = []
    total = np.zeros((r, r))
    free = np.ones(n_cand, dtype=bool)
    for step in range(k):
        name = criterion if step + 1 >= k_min else None
        sc = scores(total, step + 1, name)
        if name is not None and np.max(sc[free]) <= 0:  # still singular: keep filling by logdet
            sc = scores(total, step + 1, None)
        c = pick(sc, free)
        chosen.append(c)
        free[c] = False
        total = total + info[c]
    greedy_value = value(total, k)

    n_exchanges = 0
    if exchange:
        for _ in range(max_passes):
            improved = False
            for pos in range(k):
                without = total - info[chosen[pos]]
                sc = scores(without, k, criterion)
                c = pick(sc, free)
                now = sc[chosen[pos]]  # the current set's score on the same scale
                if sc[c] > now + 1e-9 * abs(now) + 1e-300:
                    free[chosen[pos]] = True
                    free[c] = False
                    chosen[pos] = c
                    total = without + info[c]
                    n_exchanges += 1
                    improved = True
            if not improved:
                break
    idx = np.array(chosen, dtype=int)
    return PosePlan(
        indices=idx,
        criterion=criterion,
        value=value(total, k),
        greedy_value=greedy_value,
        n_exchanges=n_exchanges,
        base_indices=base,
        measurements=cand.subset(idx),
    )


def measure(
    robot: Robot,
    x: Any,
    q: Any,
    poses: Any,
    noise: Noise | None = None,
    seed: int | np.random.Generator | None = None,
) -> Measurements:
    """Simulated readings at given poses: the actual robot (nominal + ``x``) at joint readings
    ``q`` and world platform poses ``poses``, with the noise model of :func:`iwr.simulate`.

    This is how a planned set of poses is measured in a simulation: the leg readings are those of
    the actual robot, then the joint readings, legs, position and orientation get their noise.
    """
    poses = np.asarray(poses, dtype=float)
    q = np.asarray(q, dtype=float).reshape(len(poses), robot.n_joints)
    legs = predict_legs(robot, np.asarray(x, dtype=float), q, poses)
    noise = noise if noise is not None else Noise()
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    return add_noise(robot, q, poses, legs, noise, rng)
