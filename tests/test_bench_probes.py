"""The machine probes of the benchmarks (``iwr._core._bench``): each answers with a plausible
figure in about the time it is given, and never hangs (the benchmarks print them beside every
table: BENCHMARKS.md)."""

from __future__ import annotations

import math
import os
import platform
import time

import pytest

from iwr import _core


def _cores_here() -> int:
    """The CPUs this process may run on (affinity and cpusets, which os.cpu_count ignores)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def test_the_core_round_trip_is_a_plausible_time_or_nan_without_a_second_core():
    probe = _core._bench.measure_core_round_trip_ns
    t0 = time.perf_counter()
    # 0.2 s of batches of 256 round trips (25 us each when both threads have a core): on a
    # loaded machine (CI runs the tests beside a build) some batch still finds both on a core,
    # and the probe keeps the least.
    ns = probe(0.2)
    elapsed = time.perf_counter() - t0
    if _cores_here() >= 2:
        # A cache line between two cores: tens to hundreds of ns on real hardware; 1 ms would be
        # a thread that waited for a core (the probe takes the least batch, so not that either).
        assert math.isfinite(ns) and 1.0 < ns < 1e6, ns
    else:  # one CPU to run on: no second core to measure
        assert math.isnan(ns)
    # A hang guard, not a speed: the probe gives up on a round trip unanswered for a second.
    assert elapsed < 60.0, elapsed


@pytest.mark.parametrize("seconds", [-1.0, math.nan, math.inf, 1e9])
def test_the_round_trip_refuses_a_budget_it_could_not_keep(seconds):
    with pytest.raises(ValueError, match="seconds"):
        _core._bench.measure_core_round_trip_ns(seconds)


def test_the_peak_and_clock_probes_answer():
    if platform.machine().lower() in ("x86_64", "amd64"):
        assert _core._bench.measure_clock_ghz(0.01) > 0.1
        assert _core._bench.measure_peak_gflops("sse2", False, 0.01) > 0.1
    else:  # the probes exist for x86-64 only
        assert _core._bench.measure_clock_ghz(0.01) == 0.0
        with pytest.raises(ValueError, match="x86-64"):
            _core._bench.measure_peak_gflops("sse2", False, 0.01)
