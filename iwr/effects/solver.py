"""The efficient (implicit loop) estimator's solver in numpy, for readings models the C++ core
does not have (a robot with effects, docs/effects.md): the Levenberg-Marquardt method of
``solve_loop`` in ``cpp/src/implicit_loop.cpp`` on the per-pose normalised residuals, each pose's
nuisance corrections eliminated by the Schur complement, with the same steps, damping, stopping
rules and statistics at the solution (redundancy numbers, per-pose tests, covariance), vectorised
over the poses. A test runs it on the geometric model against the C++ solver.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["solve_in_stages", "solve_loop"]

#: ``model(x, corrections, jacobians) -> (r, jx, jy)``: the normalised residuals (N, nr) at
#: parameters ``x`` and corrections (N, ny), and, when ``jacobians``, their derivatives
#: (N, nr, n_params) and (N, nr, ny) (else None, None).
LoopModel = Callable[[np.ndarray, np.ndarray, bool], tuple[np.ndarray, Any, Any]]

_TINY = np.finfo(float).tiny


def solve_loop(model: LoopModel, x0: np.ndarray, active: list[int], corrections0: np.ndarray,
               rows: np.ndarray, free: np.ndarray, *, max_iterations: int = 200,
               ftol: float = 1e-12, xtol: float = 1e-12, gtol: float = 1e-12,
               initial_lambda: float = 1e-8, statistics: bool = True,
               callback: Callable[[int, np.ndarray, float], bool] | None = None
               ) -> dict[str, Any]:
    """Minimise the sum of the squared normalised residuals over the ``active`` parameters and
    the ``free`` corrections (column indices, the same at every pose; the others held at 0).
    ``rows``: the residual columns that carry a reading (the legs and the free corrections'
    priors). Returns the dictionary of ``_core.implicit_loop`` (``x``, ``corrections``,
    ``cost``, ``iterations``, ``nfev``, ``status``, ``message``, ``residuals``, ``redundancy``,
    ``pose_statistic``, ``pose_dof``, ``covariance``, ``reciprocal_condition``, ``dof``)."""
    act = np.asarray(active, dtype=int)
    p, m = act.size, free.size
    x = np.array(x0, dtype=float)
    corr = np.array(corrections0, dtype=float)
    n = corr.shape[0]

    def cost_at(xx: np.ndarray, cc: np.ndarray) -> float:
        r, _, _ = model(xx, cc, False)
        rl = r[:, rows]
        return float(np.sum(rl * rl))

    state: dict[str, Any] = {}

    def build(xx: np.ndarray, cc: np.ndarray) -> float:
        r, jx, jy = model(xx, cc, True)
        a = jx[:, rows][:, :, act]          # (N, nrow, p)
        b = jy[:, rows][:, :, free]         # (N, nrow, m)
        rl = r[:, rows]
        # Products as matmul (BLAS), not einsum: at N = 300 poses, 13 rows and 60 parameters
        # einsum's loops took most of an estimate's time.
        a2 = a.reshape(n * a.shape[1], p)
        at, bt = np.swapaxes(a, 1, 2), np.swapaxes(b, 1, 2)
        state.update(a=a, b=b, r=rl, u=a2.T @ a2, gx=a2.T @ rl.reshape(-1), w=at @ b,
                     v=bt @ b, gy=(bt @ rl[..., None])[..., 0])
        return float(np.sum(rl * rl))

    def schur() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """S = U - sum W V^-1 W^T, its right-hand side, V^-1 W^T and V^-1 gy."""
        if m == 0:
            return (state["u"].copy(), -state["gx"], np.zeros((n, 0, p)), np.zeros((n, 0)))
        vwt = np.linalg.solve(state["v"], np.swapaxes(state["w"], 1, 2))   # (N, m, p)
        vg = np.linalg.solve(state["v"], state["gy"][..., None])[..., 0]    # (N, m)
        w2 = np.swapaxes(state["w"], 0, 1).reshape(p, n * m)  # W stacked over the poses
        s = state["u"] - w2 @ vwt.reshape(n * m, p)
        rhs = -state["gx"] + w2 @ vg.reshape(-1)
        return s, rhs, vwt, vg

    nfev, it = 0, 0
    cost = build(x, corr)
    nfev += 2
    lam, nu = initial_lambda, 2.0
    status, message = 0, ""
    fresh, ready = True, False
    s0 = rhs0 = vwt = vg = du = None
    while True:
        if cost <= _TINY:
            status, message = 4, "the residuals are zero"
            break
        if it >= max_iterations:
            status, message = 0, f"iteration limit reached (max_iterations={max_iterations})"
            break
        if not fresh:
            cost = build(x, corr)
            nfev += 2
            fresh, ready = True, False
        gmax = float(np.max(np.abs(state["gx"]) / np.sqrt(
            np.maximum(np.diag(state["u"]), _TINY) * cost))) if p else 0.0
        if gmax <= gtol:
            status, message = 3, "the gradient is below gtol"
            break
        it += 1
        if not ready:
            s0, rhs0, vwt, vg = schur()
            dmax = float(np.max(np.diag(s0))) if p else 0.0
            du = np.maximum(np.diag(s0), 1e-12 * dmax)
            ready = True
        s = s0 + lam * np.diag(du)
        d = 1.0 / np.sqrt(np.maximum(np.diag(s), _TINY))
        dx = d * np.linalg.solve(d[:, None] * s * d[None, :], d * rhs0)
        dy = -vg - vwt @ dx
        vd = np.diagonal(state["v"], axis1=1, axis2=2)
        gd = float(state["gx"] @ dx + np.sum(state["gy"] * dy))
        ddd = float(np.sum(dx * dx * du))
        step2 = ddd + float(np.sum(dy * dy * vd))
        xn2 = float(np.sum(x[act] ** 2 * du) + np.sum(corr[:, free] ** 2 * vd))
        predicted = -gd + lam * ddd
        xt = x.copy()
        xt[act] += dx
        ct = corr.copy()
        ct[:, free] += dy
        ct_cost = (cost_at(xt, ct) if np.all(np.isfinite(xt)) and np.all(np.isfinite(ct))
                   else np.inf)
        nfev += 1
        actual = cost - ct_cost
        small = np.sqrt(step2) <= xtol * (np.sqrt(xn2) + xtol)
        if actual > 0 and np.isfinite(ct_cost):
            rho = actual / predicted if predicted > 0 else 0.0
            x, corr = xt, ct
            old, cost = cost, ct_cost
            fresh = False
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            if callback is not None and callback(it, x, cost):
                status, message = -1, "stopped by the callback"
                break
            if actual <= ftol * old:
                status, message = 1, "the cost changes by less than ftol"
                break
            if small:
                status, message = 2, "the step is below xtol"
                break
        else:
            if lam <= 1.0 and (predicted <= ftol * cost or small):
                status = 1 if predicted <= ftol * cost else 2
                message = ("the cost changes by less than ftol" if status == 1
                           else "the step is below xtol")
                break
            lam *= nu
            nu *= 2.0
            if lam > 1e16:
                status, message = -2, "no step lowers the cost (damping exhausted)"
                break
    if not fresh:
        cost = build(x, corr)
        nfev += 2
    out: dict[str, Any] = {"x": x, "corrections": corr, "cost": cost, "iterations": it,
                           "nfev": nfev, "status": status, "message": message}
    if statistics:
        out.update(_statistics(model, x, corr, rows, state, schur, p, n))
    return out


def _statistics(model: LoopModel, x: np.ndarray, corr: np.ndarray, rows: np.ndarray,
                state: dict[str, Any], schur: Any, p: int, n: int) -> dict[str, Any]:
    """Covariance, redundancy numbers and per-pose tests at the solution (as ``solve_loop``)."""
    s, _, vwt, _ = schur()
    cov = np.zeros((p, p))
    if p > 0:
        d = 1.0 / np.sqrt(np.maximum(np.diag(s), _TINY))
        ev, vec = np.linalg.eigh(d[:, None] * s * d[None, :])
        recip = max(ev[0], 0.0) / ev[-1] if ev[-1] > 0 else 0.0
        cut = ev[-1] * p * np.finfo(float).eps
        inv = np.where(ev > cut, 1.0 / np.where(ev > cut, ev, 1.0), 0.0)
        cov = d[:, None] * ((vec * inv) @ vec.T) * d[None, :]
    else:
        recip = 1.0
    r_all, _, _ = model(x, corr, False)
    a, b = state["a"], state["b"]
    nrow = rows.size
    if b.shape[2]:
        e = a - b @ vwt
        h = b @ np.linalg.inv(state["v"]) @ np.swapaxes(b, 1, 2)
    else:
        e, h = a, np.zeros((n, nrow, nrow))
    h = h + (e @ cov) @ np.swapaxes(e, 1, 2)
    q = np.eye(nrow) - h
    redundancy = np.zeros_like(r_all)
    redundancy[:, rows] = np.diagonal(q, axis1=1, axis2=2)
    ev, vec = np.linalg.eigh(q)
    proj = (np.swapaxes(vec, 1, 2) @ state["r"][..., None])[..., 0]
    keep = ev > 1e-8
    stat = np.sum(np.where(keep, proj**2 / np.where(keep, ev, 1.0), 0.0), axis=1)
    n_free = b.shape[2]
    return {"residuals": r_all, "redundancy": redundancy, "pose_statistic": stat,
            "pose_dof": keep.sum(axis=1).astype(int), "covariance": cov,
            "reciprocal_condition": float(recip), "dof": int(n * (nrow - n_free) - p)}


def solve_in_stages(make_model: Callable[[np.ndarray], LoopModel], x0: np.ndarray,
                    active: list[int], sigma: np.ndarray, corrections0: np.ndarray, *,
                    max_iterations: int = 200, callback: Any = None) -> dict[str, Any]:
    """:func:`solve_loop` as ``_core.implicit_loop`` runs it: ``make_model(sigma)`` the
    normalised residuals under the readings' standard deviations ``sigma`` (N, 6 + ny), the
    free corrections those with a sigma > 0 (the same at every pose). From a cold start (no
    correction given) first every non-leg reading exact (the weighted eq. (10), no nuisance
    unknowns) to ftol 1e-8, then the whole problem from there: far from the solution the
    corrections would otherwise take what the parameters should."""
    live = sigma[:, 6:] > 0
    free = np.flatnonzero(live[0])
    if np.any(live != live[0]):
        k = int(np.flatnonzero(np.any(live != live[0], axis=1))[0])
        raise ValueError(f"sigma: pose {k} has other exact readings than pose 0; the numpy "
                         "solver takes the same at every pose")
    rows = np.concatenate([np.arange(6), 6 + free])
    options = {"max_iterations": int(max_iterations), "callback": callback}
    corr = np.where(live, corrections0, 0.0)
    if not free.size or np.any(corr):
        return solve_loop(make_model(sigma), x0, active, corr, rows, free, **options)
    s1 = sigma.copy()
    s1[:, 6:] = 0.0
    r1 = solve_loop(make_model(s1), x0, active, corr, np.arange(6), np.zeros(0, dtype=int),
                    ftol=1e-8, statistics=False, **options)
    if r1["status"] == -1:  # stopped by the callback: the statistics of the full problem anyway
        out = solve_loop(make_model(sigma), r1["x"], active, corr, rows, free, max_iterations=0)
        out.update(status=-1, message=r1["message"])
    else:
        out = solve_loop(make_model(sigma), r1["x"], active, corr, rows, free, **options)
    out["iterations"] += r1["iterations"]
    out["nfev"] += r1["nfev"]
    return out
