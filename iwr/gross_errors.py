"""Gross errors in every pose, with or without a noise model (issue 22, item 3).

The efficient estimator tests its own identification poses (:mod:`iwr.estimation`, "Outliers").
This module tests what it does not: the **held-out (validation) poses**, at the identified
parameters, and the identification poses of every other method (eq. (10) and its analogue on
tracker data, weighted by a noise model or not). It works on the **linearised** problem at the
identified parameters ``x``: per pose ``k`` the misclosures ``r_k`` (predicted minus measured: the
six leg residuals of pose data, the point coordinates of tracker data), their derivatives ``A_k``
in the parameters and ``B_k`` in each reading (a gross error ``e`` in reading ``i`` moves ``r_k``
by ``B_k[:, i] e``), and their covariance ``C_k``: ``B_k Sigma_k B_k^T`` from a noise model, or
``sigma^2`` times the objective's own metric (unit, or ``1 / w`` for leg weights) with ``sigma``
unknown. The kind of the data gives them (:meth:`iwr.kinds.MeasurementKind.misclosures`).

Whitened by ``C_k = L_k L_k^T``, the identification poses give the normal matrix ``N = sum_k
A~_k^T A~_k``; a pose's residuals have the cofactor ``Q_k = I - A~_k N^+ A~_k^T`` when it is in the
fit, ``I + A~_k N^+ A~_k^T`` when it is not (a held-out pose: its residuals also carry the
uncertainty of ``x``).

- **With a noise model**: each pose's ``T_k = r~_k^T Q_k^+ r~_k``, chi-square with ``rank Q_k``
  degrees of freedom (the estimator's per-pose test), at ``alpha`` (default 0.001).
- **Without a noise model**: Pope's tau test. ``sigma`` is estimated from the identification
  residuals, ``s^2 = sum r~^T r~ / f`` (``f`` = residuals - rank), and each residual component is
  studentized, ``tau_j = r~_j / (s sqrt(q_jj))``: for an identification pose it follows the tau
  distribution with ``f`` degrees of freedom (``tau^2 / f ~ Beta(1/2, (f - 1) / 2)``: the residual
  is part of ``s``), for a held-out pose Student's t with ``f`` (independent of ``s``). A pose
  fails when its largest ``|tau_j|`` exceeds the critical value of ``1 - (1 - alpha)^(1/m_k)``
  (Sidak over its ``m_k`` components), so that a clean pose fails with probability ``alpha``.
  Why this and not a robust (Huber, Tukey) re-fit: the test has an exact null distribution under
  the model of the unweighted objective, so its false-alarm rate is stated, not tuned; it needs
  no scale guess (a robust loss needs one, the very thing that is unknown); and it is testable
  per component, so correlated noise within a pose (a measured pose's 3 position errors reach
  all six legs) does not inflate it as a per-pose statistic with an estimated sigma would (a
  per-pose F test assumes independent components; were the six residuals' noise in 3
  directions, ``2 chi2(3)`` against ``chi2(6)``, it would fail about 10 times its nominal 0.001:
  an estimate, not measured).

In both cases the reading to blame is the one with the largest Baarda w-test value ``w_i =
c~_i^T Q_k^{-1 or identity} r~_k / sqrt(...)`` over every reading of the pose (``c~_i`` the
whitened column ``B_k[:, i]``): the likeliest culprit under a single gross error (a leg, a joint,
a coordinate of the measured pose or point). :func:`screen` runs the test inside a calibration:
data snooping on the identification poses (the worst failing pose left out and the parameters
re-fitted by Levenberg-Marquardt from ``x``, one at a time) and the held-out poses tested at the
final parameters and left out of the accuracy figures. See ``docs/estimation.md``, "Gross errors
without a noise model, and in held-out poses".
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy import special

from . import kinds
from ._blas import single_thread
from .misclosures import Misclosures
from .noise import MIN_SIGMA
from .result import FitTest, Outlier, pose_key, pose_keys, source_line

__all__ = ["GrossErrors", "Misclosures", "NoRedundancy", "cut_to_used", "find_gross_errors",
           "fitted_poses", "screen"]


class NoRedundancy(ValueError):
    """The identification poses have no redundancy to test anything with."""


@dataclass(frozen=True)
class GrossErrors:
    """What :func:`find_gross_errors` found.

    Attributes
    ----------
    outliers : list of iwr.estimation.Outlier
        The failing poses, identification (``data_set="identification"``) then validation, each
        with its line, test value, p-value and the reading to blame. ``removed`` is False here
        (:func:`screen` sets it for what it leaves out).
    test : str
        ``"chi2"`` (a noise model) or ``"tau"`` (Pope's test, sigma from the residuals).
    alpha : float
        Probability that a clean pose fails (each pose's significance level).
    sigma : float
        The square root of the variance factor ``sum r~^T r~ / dof``: without a noise model the
        pooled sigma of the misclosures (the objective's units: mm for legs and points); with
        one, 1 when the noise model is right.
    dof : int
        Redundancy of the identification poses (residuals minus rank).
    n_tested : dict
        Poses tested per data set (``identification``, ``validation``).
    group_sigmas : tuple of float
        Without a noise model, the sigma estimated for each group of components
        (:attr:`Misclosures.groups`; one: all alike).
    """

    outliers: list[Any]
    test: str
    alpha: float
    sigma: float
    dof: int
    n_tested: dict[str, int] = field(default_factory=dict)
    group_sigmas: tuple[float, ...] = ()

    def describe(self) -> str:
        """The test in one sentence, with its false-alarm rate, for a report."""
        if self.test == "chi2":
            how = "each pose's chi-square test under the noise model"
        else:
            sig = (", ".join(f"{v:.3g}" for v in self.group_sigmas)
                   if len(self.group_sigmas) > 1 else f"{self.sigma:.3g}")
            what = (" (along, across the line of sight)" if len(self.group_sigmas) == 2 else "")
            how = (f"Pope's tau test on each residual, the noise estimated from the residuals "
                   f"(sigma {sig} mm{what}, {self.dof} degrees of freedom)")
        n = sum(self.n_tested.values())
        return (f"gross errors: {how}, at {self.alpha:g} per pose: a clean pose fails with "
                f"probability {self.alpha:g}, so about {self.alpha * n:.2g} of the {n} poses "
                "tested would fail on clean data (false alarms)")


def _studentize_crit(test: str, alpha0: float, f: int, in_fit: bool) -> float:
    """The critical |value| of one studentized residual at level ``alpha0`` (two-sided)."""
    if test == "tau" and in_fit:
        # tau^2 / f ~ Beta(1/2, (f - 1) / 2)
        return math.sqrt(f * float(special.betaincinv(0.5, (f - 1) / 2.0, 1.0 - alpha0)))
    return float(special.stdtrit(f, 1.0 - alpha0 / 2.0))


def _studentize_p(test: str, value: float, f: int, in_fit: bool) -> float:
    if test == "tau" and in_fit:
        return float(special.betaincc(0.5, (f - 1) / 2.0, min(value * value / f, 1.0)))
    return float(2.0 * special.stdtr(f, -abs(value)))


class _Whitened:
    """Per pose: the rows that carry data, and the misclosures, parameter derivatives and
    reading columns whitened by their covariance: by its Cholesky factor, one whitened
    component per row; or, when the covariance is singular (a probe's twelve point misclosures
    move as one rigid pose: rank 6), by its eigenvectors of non-zero variance, one component
    per direction the noise reaches (the misclosures have nothing in the others)."""

    #: A covariance whose smallest eigenvalue is below this fraction of its largest is singular
    #: (a probe's: 0.05 to 1 in its six directions, below 1e-15 in the others).
    SINGULAR = 1e-8

    def __init__(self, mis: Misclosures, k: int, active: np.ndarray) -> None:
        self.rows = np.isfinite(mis.r[k])
        c = mis.covariance(k, self.rows)
        vals, vecs = np.linalg.eigh(c)
        self.full_rank = bool(vals[0] > self.SINGULAR * vals[-1])
        if self.full_rank:
            chol = np.linalg.cholesky(c)

            def whiten(v: np.ndarray) -> np.ndarray:
                return np.linalg.solve(chol, v)
        else:
            keep = vals > self.SINGULAR * vals[-1]
            w = (vecs[:, keep] / np.sqrt(vals[keep])).T

            def whiten(v: np.ndarray) -> np.ndarray:
                return w @ v
        self.r = whiten(mis.r[k][self.rows])
        self.a = whiten(mis.a[k][self.rows][:, active])
        self.b = whiten(mis.b[k][self.rows])


def _normal_pinv(blocks: list[_Whitened]) -> tuple[np.ndarray, int]:
    """``N^+`` of the identification blocks (column-scaled, so mm and rad do not set the rank)
    and its rank."""
    n = sum(b.a.T @ b.a for b in blocks)
    d = np.sqrt(np.clip(np.diag(n), 0, None))
    d = np.where(d > 0, d, 1.0)
    ns = n / np.outer(d, d)
    with single_thread():
        u, s, vt = np.linalg.svd(ns)
    rank = int(np.sum(s > max(ns.shape) * np.finfo(float).eps * 1e3 * (s[0] if s.size else 0)))
    inv = (vt[:rank].T / s[:rank]) @ u[:, :rank].T
    return inv / np.outer(d, d), rank


def find_gross_errors(robot: Any, identification: Any, x: Any, noise: Any = None, *,
                      validation: Any = None, used: Any = None, active: Any = None,
                      alpha: float = 1e-3, test_identification: bool = True) -> GrossErrors:
    """Test every pose for a gross error at the identified parameters ``x``.

    Parameters
    ----------
    robot : Robot
        The nominal robot (with its tracker setup for tracker data).
    identification : Measurements or TrackerMeasurements
        The poses ``x`` was identified from (those of ``used``).
    x : array_like
        The identified parameters (the robot's, then the setup's).
    noise : noise model or None
        As :func:`iwr.simulate` takes it for this kind (an :class:`iwr.Noise`; for tracker data
        the pair ``(Noise, TrackerNoise)``); None: the noise level is estimated from the residuals
        (Pope's test).
    validation : same kind as ``identification``, optional
        Held-out poses, tested at ``x`` (they are not in the fit).
    used : array_like of bool, optional
        The identification poses in the fit (default all).
    active : array_like of bool, optional
        The identified parameters (default all): the others are not estimated, so they take no
        redundancy.
    alpha : float
        Probability that a clean pose fails its test.
    test_identification : bool
        False: only the held-out poses are tested (the efficient estimator tests its own).
    """

    if not (isinstance(alpha, (int, float)) and 0 < alpha < 1):
        raise ValueError(f"alpha: {alpha!r}; expected a number in (0, 1)")
    kind = kinds.of(identification)
    x = np.asarray(x, dtype=float)
    n = len(identification)
    used_mask = np.ones(n, dtype=bool) if used is None else np.asarray(used, dtype=bool)
    if used_mask.shape != (n,):
        raise ValueError(f"used: shape {used_mask.shape}; expected ({n},)")
    act = np.ones(x.size, dtype=bool) if active is None else np.asarray(active, dtype=bool)
    if act.shape != x.shape:
        raise ValueError(f"active: shape {act.shape}; expected {x.shape}")
    test = "tau" if noise is None else "chi2"
    mis = kind.misclosures(robot, identification, x, noise)
    rows = [k for k in np.flatnonzero(used_mask) if np.any(np.isfinite(mis.r[k]))]
    blocks = {int(k): _Whitened(mis, int(k), act) for k in rows}
    if test == "tau" and not all(b.full_rank for b in blocks.values()):
        raise ValueError(f"{kind.description} misclosures: a singular metric without a noise "
                         "model; Pope's test needs one variance per component (give a noise "
                         "model)")
    n_inv, rank = _normal_pinv(list(blocks.values()))
    m_total = sum(b.r.size for b in blocks.values())
    f = m_total - rank
    ssq = float(sum(b.r @ b.r for b in blocks.values()))
    if f < 1 or (test == "tau" and f < 2):
        raise NoRedundancy(f"no redundancy: {m_total} residuals for {rank} identifiable "
                           "parameters; the data cannot test themselves for gross errors "
                           "(measure more poses)")
    sigma = math.sqrt(ssq / f)
    # Without a noise model: one sigma per group of components (mis.groups), from the
    # identification residuals, s_g^2 = sum r~^2 / sum q_jj over the group (its redundancy f_g),
    # and, for the held-out poses, the scale of the identification poses' deleted
    # (leave-one-pose-out) residuals Q_kk^-1 r~_k: what a pose not in the fit looks like,
    # whatever the noise's correlation within a pose. s (the fit's own) is not that scale when
    # the readings' noise is correlated within a pose (a measured pose's error reaches all six
    # legs): the fit absorbs more of it than of independent noise, and the parameters' error at
    # a new pose is larger than s^2 N^+ says (measured: 3.5 times the nominal rate).
    ngroups = 1 if mis.groups is None else int(np.max(mis.groups)) + 1
    g_of = np.zeros(mis.r.shape[1], dtype=int) if mis.groups is None else mis.groups
    sums = np.zeros((4, ngroups))  # r~^2, q_jj, e^2 / (Q^-1)_jj, count
    if test == "tau":
        for b in blocks.values():
            qkk = np.eye(b.r.size) - b.a @ n_inv @ b.a.T
            with single_thread():
                qinv = np.linalg.pinv(qkk, rcond=1e-10, hermitian=True)
            e, d, g = qinv @ b.r, np.diag(qinv), g_of[b.rows]
            ok = d > 0
            np.add.at(sums[0], g, b.r**2)
            np.add.at(sums[1], g, np.diag(qkk))
            np.add.at(sums[2], g[ok], e[ok] ** 2 / d[ok])
            np.add.at(sums[3], g[ok], 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_fit = np.where(sums[1] > 0, np.sqrt(sums[0] / sums[1]), sigma)
        s_val = np.where(sums[3] > 0, np.sqrt(sums[2] / sums[3]), s_fit)
    f_group = np.maximum(np.round(sums[1]).astype(int), 2) if test == "tau" else None
    meat = (sum(b.a.T @ (b.a * s_fit[g_of[b.rows]][:, None] ** 2) for b in blocks.values())
            if test == "tau" else None)
    found: list[Outlier] = []

    def test_pose(w: _Whitened, k: int, data: Any, in_fit: bool, what: str) -> None:
        h = w.a @ n_inv @ w.a.T
        q = np.eye(w.r.size) - h if in_fit else np.eye(w.r.size) + h
        # w-test of each reading: in the fit c^T r / sqrt(c^T Q c) (Baarda, P = I in the
        # whitened space); held out c^T Q^-1 r / sqrt(c^T Q^-1 c) (r ~ N(0, Q)).
        with single_thread():
            qi = np.linalg.pinv(q, rcond=1e-10, hermitian=True)
        if in_fit:
            num, den = w.b.T @ w.r, np.einsum("ji,jl,li->i", w.b, q, w.b)
        else:
            num, den = w.b.T @ qi @ w.r, np.einsum("ji,jl,li->i", w.b, qi, w.b)
        ok = den > 1e-20 * max(float(np.max(den)), 1e-300)
        wt = np.where(ok, num / np.sqrt(np.where(ok, den, 1.0)), 0.0)
        if test == "chi2":
            stat = float(w.r @ qi @ w.r)
            dof = int(np.linalg.matrix_rank(q, tol=1e-10, hermitian=True)) if in_fit else w.r.size
            p = float(special.chdtrc(dof, stat))
            fails = p < alpha
        else:
            g = g_of[w.rows]
            s = (s_fit if in_fit else s_val)[g]
            tau = w.r / (s * np.sqrt(np.clip(np.diag(q), 1e-300, None)))
            # The readings' w-test with each group's variance d: the residuals' covariance of
            # the unweighted fit under diag(d) is D - H D - D H + A N^+ M N^+ A^T in the fit
            # (D + A N^+ M N^+ A^T held out), M = sum_l A_l^T D_l A_l; the statistic of a
            # reading's column c is c^T D^-1 r / sqrt(c^T D^-1 C D^-1 c).
            d = s_fit[g] ** 2
            v = w.a @ n_inv @ meat @ n_inv @ w.a.T
            cov = (np.diag(d) - h * d - d[:, None] * h + v) if in_fit else np.diag(d) + v
            pb = w.b / d[:, None]
            den = np.einsum("ji,jl,li->i", pb, cov, pb)
            ok = den > 1e-20 * max(float(np.max(den)), 1e-300)
            wt = np.where(ok, (pb.T @ w.r) / np.sqrt(np.where(ok, den, 1.0)), 0.0)
            m = tau.size
            a0 = 1.0 - (1.0 - alpha) ** (1.0 / m)  # Sidak over the pose's components
            j_max = int(np.argmax(np.abs(tau)))
            stat = float(abs(tau[j_max]))
            dof = int(f_group[g[j_max]])
            p1 = _studentize_p(test, stat, dof, in_fit)
            p = float(-np.expm1(m * np.log1p(-min(p1, 1.0 - 1e-16))))  # 1 - (1 - p1)^m
            crit = np.array([_studentize_crit(test, a0, int(f_group[gi]), in_fit) for gi in g])
            fails = bool(np.any(np.abs(tau) > crit))
        if not fails:
            return
        j = int(np.argmax(np.abs(wt)))
        alt = tuple(mis_names[i] for i in np.flatnonzero(np.abs(wt) >= 0.99 * abs(wt[j]))
                    if i != j)
        found.append(Outlier(int(k), data.where(int(k)), stat, dof, p, mis_names[j],
                             float(wt[j]), False, alt, data_set=what, test=test,
                             line=source_line(data, int(k)), key=pose_key(data, int(k))))

    mis_names = mis.names
    tested = {"identification": 0, "validation": 0}
    if test == "tau" and sigma < MIN_SIGMA:
        # The residuals are rounding (noise-free data, a simulation): no noise to scale a test
        # by, and nothing to find; a gross error would make sigma far larger than this.
        return GrossErrors(found, test, float(alpha), sigma, int(f), tested,
                           tuple(float(v) for v in s_fit))
    if test_identification:
        for k, w in blocks.items():
            test_pose(w, k, identification, True, "identification")
            tested["identification"] += 1
    if validation is not None and len(validation):
        vmis = kinds.of(validation).misclosures(robot, validation, x, noise)
        mis_names = vmis.names
        for k in range(len(validation)):
            if not np.any(np.isfinite(vmis.r[k])):
                continue
            test_pose(_Whitened(vmis, k, act), k, validation, False, "validation")
            tested["validation"] += 1
    return GrossErrors(found, test, float(alpha), sigma, int(f), tested,
                       tuple(float(v) for v in s_fit) if test == "tau" else ())


def _refit(robot: Any, data: Any, result: Any, noise: Any, options: dict[str, Any]) -> Any:
    """Levenberg-Marquardt on ``data`` from ``result.x`` with its active set (the objective of
    ``result``'s method: weighted by ``noise`` when given)."""
    from .methods import identify

    kw = dict(options)
    if noise is not None:
        kw["noise"] = noise
    return identify(robot, data, "lm", x0=result.x, active=result.active, progress=False,
                    **kw)


#: The efficient estimator's arrays of one row per identification pose (``result["used"]``).
_PER_POSE = ("used", "corrections", "residuals", "redundancy", "pose_statistic")


def cut_to_used(result: Any) -> None:
    """``result``'s per-pose arrays (:data:`_PER_POSE`) cut to the rows ``result["used"]`` holds
    (``used`` then all True), in place."""
    used = np.asarray(result["used"], dtype=bool)
    rows = np.flatnonzero(used)
    for name in _PER_POSE:
        value = result.get(name)
        if value is not None and np.ndim(value) >= 1 and len(value) == used.size:
            result[name] = np.asarray(value)[rows]


def fitted_poses(result: Any, identification: Any) -> Any:
    """The identification poses ``result`` was fitted to: without those the efficient
    estimator's own test left out of its fit (``result["used"]`` False), its per-pose arrays
    (``used``, ``corrections``, ``residuals``, ``redundancy``, ``pose_statistic``) cut to them in
    ``result``; ``identification`` itself for any other result. What the other methods' screen
    returns, so that a job's cost, residual, accuracy and diagnosis figures are over the poses
    fitted whatever the method (with nothing held out the accuracy was once over a 1 mm typo the
    fit had left out, and ``iwr report`` of the same run, which drops recorded outliers, said
    otherwise)."""
    used = result.get("used")
    if used is None or np.size(used) != len(identification) or np.all(used):
        return identification
    rows = np.flatnonzero(np.asarray(used, dtype=bool))
    cut_to_used(result)
    return kinds.of(identification).subset(identification, rows)


def screen(robot: Any, identification: Any, validation: Any, result: Any, noise: Any = None, *,
           held_out: bool = True, alpha: float = 1e-3, max_outlier_fraction: float = 0.2,
           **options: Any) -> tuple[Any, Any, Any]:
    """Gross errors in a calibration job: ``(result, identification, validation)`` after them.

    - The efficient estimator (``result.method == "efficient"``) has tested and snooped its
      identification poses: those it left out of its fit (``result["used"]``) are left out of
      the returned set, as the other methods' (its per-pose arrays cut to match: ``used`` is
      then all True); only the held-out poses are tested here, with the noise it used.
    - Any other method: data snooping with :func:`find_gross_errors` (the chi-square test with
      ``noise``, Pope's test without): while an identification pose fails, the worst (smallest
      p-value) is left out and the parameters re-fitted by
      Levenberg-Marquardt from the result (``options``, e.g. ``bounds``, go to
      :func:`iwr.identify`), at most ``max_outlier_fraction`` of the poses; then the held-out
      poses are tested at the final parameters.

    Every failing pose is appended to ``result["outliers"]`` (:class:`iwr.estimation.Outlier`,
    with its data set; ``pose`` is its row in the set given here, ``where`` its line);
    identification poses left out are out of the returned identification set, failing held-out
    poses out of the returned validation set (so the accuracy figures are not those of a
    typo). More failing identification poses than ``max_outlier_fraction`` is no longer a few
    gross errors: the fit is then reported as not fitting (``fit_ok`` False), nothing more
    removed; so with more than that fraction of the held-out poses failing (kept, then). An
    interrupted result is returned as is (the efficient estimator's without the poses its last
    completed solve left out).
    The test's description (:meth:`GrossErrors.describe`) goes to ``result["gross_errors"]``."""
    kind = kinds.of(identification)
    efficient = result.method == "efficient"
    n = len(identification)
    if efficient and np.all(np.isfinite(result.x)):  # an interrupted one's last solve too
        identification = fitted_poses(result, identification)
        if not held_out:
            validation = identification
    if result.interrupted or not np.all(np.isfinite(result.x)):
        return result, identification, validation
    if efficient:
        noise = noise if result.noise is None else result.noise
    elif isinstance(noise, str):
        noise = None  # "estimate" without the estimator: no model to test with
    cap = int(math.floor(max_outlier_fraction * n))
    keep = np.ones(n, dtype=bool)
    removed: list[Any] = []
    too_many = False
    current = result
    ident = identification

    def refit_kept(current: Any) -> tuple[Any, Any]:
        """The identification poses ``keep`` holds and LM's re-fit on them from ``current``."""
        ident = kind.subset(identification, np.flatnonzero(keep))
        refit = _refit(robot, ident, current, noise, options)
        refit["method"] = result.method or "lm"
        refit["nfev"] = int(current.nfev) + int(refit.nfev)
        return ident, refit

    while not efficient:
        try:
            found = find_gross_errors(robot, ident, current.x, noise,
                                      active=current.active, alpha=alpha)
        except NoRedundancy as exc:
            # Nothing to test with (the fit's own verdict says why the data do not suffice).
            result["gross_errors"] = f"gross errors: not tested ({exc})"
            return result, identification, validation
        if not found.outliers:
            break
        if len(removed) >= cap:
            too_many = True
            rows = np.flatnonzero(keep)
            removed += [replace(o, pose=int(rows[o.pose])) for o in found.outliers]
            break
        worst = min(found.outliers, key=lambda o: o.p_value)
        k = int(np.flatnonzero(keep)[worst.pose])
        keep[k] = False
        removed.append(replace(worst, pose=k, removed=True))
        ident, current = refit_kept(current)
        if current.interrupted:  # Ctrl-C: no further refit may lose it
            break
    if removed and not too_many and not current.interrupted:
        # A pose left out while the parameters were far from the solution (a global method's
        # unconverged result, whose misfit any pose can fail) may be clean: each is tested again
        # at the final parameters as a held-out pose and put back, with one re-fit, if it passes.
        gone = np.flatnonzero(~keep)
        try:
            again = find_gross_errors(robot, ident, current.x, noise,
                                      validation=kind.subset(identification, gone),
                                      active=current.active, alpha=alpha,
                                      test_identification=False)
            still = {int(gone[o.pose]) for o in again.outliers}
        except NoRedundancy:
            still = {int(k) for k in gone}
        back = [int(k) for k in gone if int(k) not in still]
        if back:
            keep[back] = True
            removed = [o for o in removed if o.pose not in back]
            ident, current = refit_kept(current)
    held = validation if held_out else None
    untested = ""
    try:
        final = find_gross_errors(robot, ident, current.x, noise, validation=held,
                                  used=current.used, active=current.active,
                                  alpha=alpha, test_identification=False)
    except NoRedundancy as exc:  # after removals: the held-out poses cannot be tested
        final, untested = None, f"gross errors: held-out poses not tested ({exc})"
    val_bad = [] if final is None else [replace(o, removed=True) for o in final.outliers]
    val_cap = int(math.floor(max_outlier_fraction * len(validation))) if held_out else 0
    val_too_many = len(val_bad) > val_cap and bool(val_bad)
    if val_too_many:
        # More than a few: the model or the noise model, not typos; kept, and the fit fails.
        val_bad = [replace(o, removed=False) for o in val_bad]
    elif val_bad:
        vkeep = np.ones(len(validation), dtype=bool)
        vkeep[[o.pose for o in val_bad]] = False
        validation = kinds.of(validation).subset(validation, np.flatnonzero(vkeep))
    if current is not result:
        n_rm = int(np.sum(~keep))
        what = (f"without the {n_rm} outlier pose(s)" if n_rm else "with every pose (those that "
                "failed at the method's own point pass at the solution)")
        first = str(result.message).strip().rstrip('.')
        if (result.fit is not None and not result.fit.fit_ok and current.fit is not None
                and current.fit.fit_ok):
            # The method's point failed its fit test because of the poses now removed: its
            # verdict ("THE MODEL DOES NOT FIT THE DATA: ...") is not the result's, which fits
            # (a calibration file said "success" beside it).
            first = (f"{result.method}: its point, fitted to every pose, failed the fit test "
                     f"({str(result.fit.verdict).split(':')[0].lower()})")
        current["message"] = (f"{first}; then Levenberg-Marquardt from its result {what}: "
                              f"{str(current.message).strip()}")
        current["settings"] = {**dict(result.settings),
                               "outlier_refit": "lm"}
        current["wall_time"] = float(result.wall_time) + float(current.wall_time)
    if not held_out:
        validation = ident
    outliers = list(current.outliers or []) if efficient else []
    current["outliers"] = outliers + removed + val_bad
    if final is None:
        current["gross_errors"] = untested
    else:
        current["gross_errors"] = _description(found if not efficient else final, final,
                                                   n_tested={"identification": n, "validation":
                                                             final.n_tested["validation"]})
    if too_many:
        _fail_fit(current, f"{len(removed)} poses fail the outlier test (more than "
                  f"{max_outlier_fraction:.0%} of {n}): not a few gross errors but a model or "
                  "noise model that does not fit")
    if val_too_many:
        _fail_fit(current, f"{len(val_bad)} of the {len(validation)} held-out poses fail the "
                  f"outlier test (more than {max_outlier_fraction:.0%}): not a few gross errors "
                  "but a model or noise model that does not fit the poses it was not fitted to")
    return current, ident, validation


def check_result(robot: Any, identification: Any, validation: Any, result: Any, *,
                 noise: Any = None, held_out: bool = True, alpha: float = 1e-3,
                 max_outlier_fraction: float = 0.2) -> tuple[Any, Any]:
    """Gross errors in a result identified elsewhere and never screened (``iwr report`` of an
    ``iwr-calibrate`` run): ``(result, validation)`` after them, ``result`` a copy. The tests of
    :func:`screen` (each pose's chi-square test under ``noise``, the noise model a weighted run
    recorded; without one Pope's tau test, the noise level estimated from the residuals), but
    nothing is re-fitted: an identification pose that fails is named and kept
    (``removed`` False), and the fit fails with the lines to check, since the result was fitted
    to it; a held-out pose that fails is left out of the returned validation set (the accuracy
    figures), unless more than ``max_outlier_fraction`` fail (then the fit fails too)."""
    result = copy.copy(result)
    if result.interrupted or not np.all(np.isfinite(result.x)):
        return result, validation
    try:
        found = find_gross_errors(robot, identification, result.x, noise,
                                  validation=validation if held_out else None,
                                  used=result.used, active=result.active, alpha=alpha)
    except NoRedundancy as exc:
        result["gross_errors"] = f"gross errors: not tested ({exc})"
        return result, validation
    ident_bad = [o for o in found.outliers if o.data_set != "validation"]
    val_bad = [o for o in found.outliers if o.data_set == "validation"]
    if held_out and val_bad and len(val_bad) <= math.floor(max_outlier_fraction
                                                          * len(validation)):
        vkeep = np.ones(len(validation), dtype=bool)
        vkeep[[o.pose for o in val_bad]] = False
        validation = kinds.of(validation).subset(validation, np.flatnonzero(vkeep))
        val_bad = [replace(o, removed=True) for o in val_bad]
    elif val_bad:
        _fail_fit(result, f"{len(val_bad)} of the {len(validation)} held-out poses fail the "
                  f"outlier test (more than {max_outlier_fraction:.0%}): not a few gross errors "
                  "but a model or noise model that does not fit the poses it was not fitted to")
    result["outliers"] = ident_bad + val_bad
    result["gross_errors"] = found.describe()
    if ident_bad:
        _fail_fit(result, f"{len(ident_bad)} identification pose(s) fail the outlier test and the "
                  "result was fitted to them (it was identified elsewhere, so nothing is "
                  "re-fitted here): check the lines named, correct or remove them, and identify "
                  "again")
    return result, validation


class LeftOutError(ValueError):
    """A result's record of the poses its run left out names poses these data do not have."""


def without_left_out(data: Any, result: Any, data_sets: tuple[str, ...] = (
        "identification", "validation"), *, required: bool = True) -> tuple[Any, list[str] | None]:
    """``data`` without the poses ``result`` records as left out (by the gross-error screen of
    the run that identified it: :attr:`IdentificationResult.left_out`) from the ``data_sets``
    named, found by their content (:attr:`Outlier.key`: the same pose in any layout of the
    file), and where they were in ``data`` (their ``where``, for a note); None, ``data``
    unchanged, when the record has no keys (a result written before they were recorded).
    :class:`LeftOutError` when ``required`` and a recorded pose is not in ``data`` (not the data
    of the run)."""
    gone = [o for o in result.left_out if o.data_set in data_sets]
    if not gone:
        return data, []
    if any(o.key is None for o in gone):
        return data, None
    keys = np.array(pose_keys(data))
    missing = [o for o in gone if o.key not in set(keys.tolist())]
    if missing and required:
        raise LeftOutError(
            f"the result left out {missing[0].where} ({missing[0].instrument}), which these data "
            "do not have: not the data it was identified from")
    drop = np.isin(keys, [o.key for o in gone])
    where = [data.where(int(k)) for k in np.flatnonzero(drop)]
    return kinds.of(data).subset(data, np.flatnonzero(~drop)), where


def _description(first: GrossErrors, final: GrossErrors, n_tested: dict[str, int]) -> str:
    """:meth:`GrossErrors.describe` with the counts of the whole screen."""
    return replace(final, test=first.test, sigma=first.sigma, dof=first.dof,
                   group_sigmas=first.group_sigmas, n_tested=n_tested).describe()


def _fail_fit(result: Any, cause: str) -> None:
    fit = result.fit
    if fit is None:
        fit = FitTest(math.nan, 0, math.nan, 1e-3, True, "", [], [])
    head = "THE MODEL DOES NOT FIT THE DATA: too many poses fail the outlier test"
    verdict = fit.verdict if not fit.fit_ok else head
    causes = (list(fit.causes) if not fit.fit_ok else []) + [cause]
    result["fit"] = replace(fit, fit_ok=False, verdict=verdict, causes=causes)
    if result.success:
        result.update(success=False, status="failed", message=f"{verdict}: {cause}")
