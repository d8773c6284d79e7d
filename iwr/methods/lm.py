"""Levenberg-Marquardt (MINPACK, through SciPy) on the exact Jacobian of eq. (10): the default
method (``iwr.identify(method="lm")``) and DE's polish."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult

from .._blas import single_thread
from ..result import IdentificationResult
from ._run import Monitor, Stop, check_budget
from .reduced import ReducedProblem

__all__ = ["levenberg_marquardt"]

#: Tikhonov weights of the first Levenberg-Marquardt solves, before the final ``regularization``.
_LM_CONTINUATION = (1e-4, 1e-8, 1e-12)
#: The final weight of ``regularization="auto"`` on a rank-deficient problem.
_AUTO_REGULARIZATION = 1e-16


def _rank_deficient(jac: np.ndarray, norms: np.ndarray, rtol: float = 1e-9) -> bool:
    """Is the column-scaled Jacobian numerically rank deficient, or not taller than wide?

    (MINPACK needs more residuals than parameters, and it gets one parameter more than the problem
    has, see _guard_column: a square Jacobian is regularised too.)"""
    if jac.shape[0] <= jac.shape[1]:
        return True
    with single_thread():
        s = np.linalg.svd(jac / np.where(norms > 0, norms, 1.0), compute_uv=False)
    return bool(s.size == 0 or s[-1] <= rtol * s[0])


def _guard_column(jac: np.ndarray) -> np.ndarray:
    """The Jacobian with a zero column appended, for SciPy's MINPACK.

    SciPy's C translation of MINPACK (seen with SciPy 1.17.1) has an off-by-one in ``qrfac``: when
    a column's norm is recomputed during column pivoting (which happens when it collapses, as in a
    rank-deficient or tightly regularised Jacobian), the norm takes one element too many, the first
    of the next column. For the last stored column that element lies past the end of MINPACK's
    buffer (valgrind: "Invalid read of size 8 ... 0 bytes after a block", in ``enorm`` from
    ``qrfac``): heap garbage, which made the same problem give different answers from one call to
    the next (74 or 80 evaluations, results differing from the 6th digit). A zero column is never
    recomputed (its norm is 0) and never pivoted away from the end, so no element past the buffer
    is read and the results are reproducible. This does not fix the off-by-one for the other
    columns (it reads a wrong but deterministic element, which only affects pivoting). The extra
    parameter has no effect on the residuals and a zero gradient, so its step is 0; but MINPACK
    now always sees a singular R, which changes its path (its Levenberg-Marquardt parameter search
    skips the Newton lower bound), not the solution it converges to.
    """
    return np.hstack([jac, np.zeros((jac.shape[0], 1))])


def levenberg_marquardt(
    problem: ReducedProblem,
    *,
    max_evaluations: int | None = None,
    seed: int | None = None,
    callback: Callable[[OptimizeResult], Any] | None = None,
    progress: bool | None = None,
    xtol: float = 1e-15,
    ftol: float = 1e-15,
    gtol: float = 1e-15,
    regularization: float | str = "auto",
) -> IdentificationResult:
    """Levenberg-Marquardt (MINPACK, through ``scipy.optimize.least_squares(method="lm")``) on the
    exact Jacobian of :meth:`iwr.Problem.jacobian`, from ``problem.x0``.

    Parameters
    ----------
    problem : ReducedProblem
        The active parameters, and the start ``x0`` (also the value of the inactive ones).
    max_evaluations : int, optional
        Evaluation budget: residual evaluations plus Jacobian evaluations (one each), respected
        exactly; default ``100 (n + 1)``.
    seed
        Accepted for a uniform interface, unused (the method is deterministic).
    callback : callable, optional
        ``callback(intermediate_result)`` after every residual evaluation, with an
        ``OptimizeResult`` of the best point so far (``x`` the full vector, ``fun``, ``nfev``,
        ``nit``). A truthy return or ``StopIteration`` stops the run, which returns that point.
    progress : bool, optional
        A tqdm bar of evaluations against the budget (default: when standard error is a terminal).
    xtol, ftol, gtol : float
        MINPACK's tolerances.
    regularization : float or "auto"
        Weight ``lambda`` of a Tikhonov term ``lambda sum_i (d_i (z_i - z0_i))^2`` added to the
        sum of squares, with ``d_i`` the norm of column i of the Jacobian at ``x0``: 0 disables
        it. Solved by continuation: weights 1e-4, 1e-8, 1e-12, then ``regularization``, each
        solve started from the previous answer. ``"auto"`` (default): 1e-16 when the column-scaled
        Jacobian at ``x0`` is rank deficient (a singular value below 1e-9 of the largest), else
        0, so that a full-rank problem (``active="base"``) gets the plain, unbiased solution. See
        the notes.

    Returns
    -------
    IdentificationResult
        ``success`` when MINPACK's last solve met a tolerance; ``history`` has the best cost
        after every evaluation. Ctrl-C returns the best point so far, ``status`` "interrupted".

    Notes
    -----
    Unbounded: the search bounds are not imposed, since a least-squares solution of a calibration
    should not be clipped.

    Not every parameter is identifiable (the Jacobian is rank deficient: 58 parameters, about 52
    identifiable directions). MINPACK copes with the singular normal equations through its
    damping, but the set of equally good solutions is curved, and without regularisation the
    iterates slide along it: from the nominal start, noise-free, the unregularised solver ends up
    to 10 mm away from the truth in unidentifiable combinations (at the same, zero, cost). The tiny
    Tikhonov term makes the problem full rank and picks, among the equally good solutions, the one
    nearest ``x0`` in the column-scaled metric (about 1 mm from the truth instead of 10 in the
    same test). Its bias on the identifiable part is of order ``lambda / s_min^2`` relative,
    with ``s_min`` ~ 1e-3 the smallest identifiable singular value of the column-scaled
    Jacobian: about 1e-10 relative at the default, far below any noise. (It also lets MINPACK
    run with fewer readings than parameters.) Hold the unidentifiable parameters fixed with
    ``active`` (the base parameters) for the unregularised answer.

    Starting far from the valley of equal-cost solutions, a single solve at a tiny weight crawls
    along it (thousands of evaluations from the bad start of ``iwr compare``); the continuation
    (weights 1e-4, 1e-8, 1e-12, then ``regularization``) gets there in about a hundred.
    """
    from scipy.optimize import least_squares

    auto = isinstance(regularization, str) and regularization == "auto"
    if not auto and not (isinstance(regularization, (int, float))
                         and not isinstance(regularization, bool)
                         and math.isfinite(regularization) and regularization >= 0):
        raise ValueError(
            f"regularization: {regularization!r}; expected 'auto' or a finite number >= 0"
        )
    reduced = problem
    n_res = reduced.problem.n_residuals
    if not auto and regularization == 0 and n_res <= reduced.n:
        raise ValueError(
            f"method 'lm': {n_res} residuals for {reduced.n} parameters; MINPACK's LM needs "
            "more residuals than parameters (one parameter more than the problem's is passed, "
            "see _guard_column): measure more poses, fix parameters with 'active', or use "
            "regularization > 0"
        )
    if max_evaluations is None:
        max_evaluations = 100 * (reduced.n + 1)
    max_evaluations = check_budget(max_evaluations, 2)
    # MINPACK's own limit on the residual evaluations of one solve (the budget above binds first
    # unless it is larger).
    minpack_nfev = 100 * (reduced.n + 1)

    z0 = reduced.z0
    start = time.perf_counter()
    mon = Monitor(reduced, "lm", max_evaluations, callback, progress, log_every=True)
    nit = 0

    # First evaluation: residuals and Jacobian at the start (the Jacobian scales the
    # regularisation); both are handed to MINPACK for its first call, so nothing is wasted.
    first: dict[str, Any] = {}
    weights = np.zeros(reduced.n)

    # MINPACK sees one more parameter than the problem has, last, whose Jacobian column is zero
    # (see _guard_column): z_ext = [z, guard].
    def fun(z_ext: np.ndarray) -> np.ndarray:
        z = z_ext[:-1]
        if "r" in first and np.array_equal(z, z0):
            r = first.pop("r")
        else:
            mon.spend()
            r = reduced.residuals(z)
        mon.observe(z, float(r @ r))
        if regularization:
            return np.concatenate([r, weights * (z - z0)])
        return r

    def jac(z_ext: np.ndarray) -> np.ndarray:
        z = z_ext[:-1]
        if "J" in first and np.array_equal(z, z0):
            j = first.pop("J")
        else:
            mon.spend()
            j = reduced.jacobian(z)
        if regularization:
            j = np.vstack([j, np.diag(weights)])
        return _guard_column(j)

    sol = None
    stages: list[float] = []
    # Continuation on the Tikhonov weight: a strongly regularised first solve finds the region
    # quickly; the later ones, each started from the previous answer, remove its bias. A single
    # solve at the final, tiny weight crawls along the curved valley of equally good solutions when
    # the start is far from it (thousands of evaluations from a bad start, instead of ~100).
    try:
        mon.spend()
        r_first, j_full = reduced.problem.residuals_and_jacobian(reduced.full(z0))
        first["r"], first["J"] = r_first, j_full[:, reduced.index]
        norms = np.linalg.norm(first["J"], axis=0)
        floor = 1e-12 * (norms.max() if norms.size and norms.max() > 0 else 1.0)
        if auto:
            regularization = _AUTO_REGULARIZATION if _rank_deficient(first["J"], norms) else 0.0
        stages = [float(regularization)]
        if regularization > 0:
            stages = [s for s in _LM_CONTINUATION if s > regularization] + stages
        z = np.append(z0, 0.0)
        for lam in stages:
            weights = math.sqrt(lam) * np.maximum(norms, floor)
            sol = least_squares(
                fun,
                z,
                jac=jac,
                method="lm",
                xtol=xtol,
                ftol=ftol,
                gtol=gtol,
                max_nfev=minpack_nfev,
                x_scale="jac",
            )
            z = sol.x
            nit += int(sol.nfev)
    except Stop:
        pass
    except KeyboardInterrupt:
        mon.interrupted()
    finally:
        mon.close()
    if sol is not None and not mon.status:
        x = reduced.full(sol.x[:-1])
        success = bool(sol.status > 0)
        status = "converged" if success else "stopped"
        # SciPy quotes option names in backticks (Markdown), which reports showed literally.
        message = str(sol.message).replace("`", "")
    else:
        x = mon.best_x()
        success = False
        status, message = mon.status, mon.message
    return IdentificationResult(
        x=x,
        fun=reduced.problem.cost(x),
        nfev=mon.nfev,
        nit=nit,
        success=success,
        status=status,
        message=message,
        history=mon.history(),
        wall_time=time.perf_counter() - start,
        settings={"max_evaluations": int(max_evaluations), "xtol": xtol, "ftol": ftol,
                  "gtol": gtol, "regularization": stages[-1] if stages else None,
                  "regularization_option": regularization if not auto else "auto"},
    )
