"""The problem every method solves: eq. (10) restricted to the active parameters."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..problem import Problem

__all__ = ["ReducedProblem", "active_mask"]


class ReducedProblem:
    """The problem restricted to the ``active`` parameters; the others are held at ``x0``.

    ``cost``, ``residuals``, ``jacobian`` and ``cost_batch`` take reduced vectors z (n_active);
    :meth:`full` maps one back to the full error vector. ``x0`` is also the starting point of the
    local methods.

    Parameters
    ----------
    problem : Problem
    active : ndarray of bool, shape (n_params,)
    x0 : ndarray, shape (n_params,)
    """

    def __init__(self, problem: Problem, active: Any, x0: Any) -> None:
        active = np.asarray(active, dtype=bool)
        x0 = np.array(x0, dtype=float)
        if active.shape != (problem.n_params,) or x0.shape != (problem.n_params,):
            raise ValueError(
                f"active, x0: shapes {active.shape}, {x0.shape}; expected ({problem.n_params},)"
            )
        self.problem = problem
        self.active = active
        self.index = np.flatnonzero(active)
        self.x0 = x0
        self.lower = problem.lower[self.index]
        self.upper = problem.upper[self.index]
        self.nfev = 0

    @property
    def n(self) -> int:
        """Number of active parameters."""
        return self.index.size

    @property
    def z0(self) -> np.ndarray:
        """The start, reduced."""
        return self.x0[self.index].copy()

    def full(self, z: Any) -> np.ndarray:
        x = self.x0.copy()
        x[self.index] = z
        return x

    def reduce(self, x: Any) -> np.ndarray:
        return np.asarray(x, dtype=float)[self.index]

    def cost(self, z: Any) -> float:
        self.nfev += 1
        return self.problem.cost(self.full(z))

    def residuals(self, z: Any) -> np.ndarray:
        self.nfev += 1
        return self.problem.residuals(self.full(z))

    def jacobian(self, z: Any) -> np.ndarray:
        return self.problem.jacobian(self.full(z))[:, self.index]

    def cost_batch(self, Z: Any, workers: int | None = None) -> np.ndarray:
        Z = np.atleast_2d(np.asarray(Z, dtype=float))
        X = np.broadcast_to(self.x0, (Z.shape[0], self.x0.size)).copy()
        X[:, self.index] = Z
        self.nfev += Z.shape[0]
        return self.problem.cost_batch(X, workers)

    def __repr__(self) -> str:
        return f"ReducedProblem({self.problem!r}, n_active={self.n})"


def active_mask(problem: Problem, active: Any) -> np.ndarray:
    """``active`` (None, a boolean mask, names or indices) as a boolean mask of the parameters."""
    n = problem.n_params
    if active is None:
        return np.ones(n, dtype=bool)
    arr = np.asarray(active)
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise ValueError(f"active: boolean mask of shape {arr.shape}; expected ({n},)")
        mask = arr.copy()
    else:
        mask = np.zeros(n, dtype=bool)
        names = problem.parameter_names
        for item in np.atleast_1d(arr).tolist():
            if isinstance(item, str):
                if item not in names:
                    raise ValueError(f"active: unknown parameter name {item!r}")
                mask[names.index(item)] = True
            elif isinstance(item, int) and 0 <= item < n:
                mask[item] = True
            else:
                raise ValueError(f"active: {item!r} is neither a parameter name nor an index < {n}")
    if not mask.any():
        raise ValueError("active: no parameter is active")
    return mask
