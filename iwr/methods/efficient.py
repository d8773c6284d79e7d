"""The efficient estimator as a registered method (``"efficient"``):
:func:`iwr.estimation.efficient` behind the one method interface."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ..result import IdentificationResult
from ._run import INT32_MAX, check_budget
from .reduced import ReducedProblem


def efficient_method(
    problem: ReducedProblem,
    *,
    noise: Any = None,
    max_evaluations: int | None = None,
    seed: int | None = None,
    callback: Callable[..., Any] | None = None,
    progress: bool | None = None,
    **options: Any,
) -> IdentificationResult:
    """The implicit loop method on ``problem``'s robot and measurements, its active parameters
    and start: every instrument weighted by ``noise`` (an :class:`iwr.Noise`, or ``"estimate"``),
    which it needs. ``max_evaluations`` bounds the Levenberg-Marquardt iterations of each solve
    (``max_iterations``); ``seed`` and ``progress`` are accepted for the interface and unused (the
    method is deterministic and takes milliseconds). ``options``: those of
    :func:`iwr.estimation.efficient` (``estimate``, ``outliers``, ``fit_alpha``, ...)."""
    from ..estimation import efficient

    del seed, progress
    if noise is None:
        raise ValueError(
            "method 'efficient' weighs every instrument by its noise: give noise=iwr.Noise(...) "
            "(e.g. iwr.Noise.realistic()) or noise='estimate'; without a noise model use eq. "
            "(10), method='lm'"
        )
    if max_evaluations is not None:  # the C++ loop's max_iterations: an int
        options.setdefault("max_iterations", check_budget(max_evaluations, 1, INT32_MAX))
    p = problem.problem
    # The problem's bounds are the parameters' expected range: the plausibility test's yardstick.
    options.setdefault("bounds", (p.lower, p.upper))
    return efficient(p.robot, p.measurements, noise, x0=problem.x0, active=problem.active,
                     callback=callback, **options)


def efficient_on(robot: Any, measurements: Any, noise: Any, problem_of: Callable[[], Any], *,
                 noise_hint: str, x0: Any = None, active: Any = None, bounds: Any = None,
                 callback: Any = None, weighted: Any = None, max_evaluations: Any = None,
                 **options: Any) -> IdentificationResult:
    """:func:`iwr.identify`'s ``method="efficient"`` for a kind with its own identify (tracker and
    ballbar data, with or without effects): the argument checks they share (``noise_hint`` is
    how to give their noise model), ``active="base"`` left to the estimator (its own base
    parameters), another ``active`` resolved on ``problem_of()``'s parameters, then
    :func:`iwr.estimation.efficient`."""
    from ..estimation import efficient
    from .reduced import active_mask

    if noise is None:
        raise ValueError(f"method 'efficient' weighs every reading by its noise: give "
                         f"noise={noise_hint} or noise='estimate'")
    if weighted is False:
        raise ValueError("weighted=False: the efficient estimator always weighs by the noise")
    if max_evaluations is not None:  # the C++ loop's max_iterations: an int
        options.setdefault("max_iterations", check_budget(max_evaluations, 1, INT32_MAX))
    if isinstance(active, str) and active == "base":
        active = None
    if active is not None:
        active = active_mask(problem_of(), active)
    result = efficient(robot, measurements, noise, x0=x0, active=active, callback=callback,
                       bounds=bounds, **options)
    result.check_finite()
    return result
