"""How much CPU other processes took while a benchmark ran (the machine may be shared).

``with OtherLoad() as o: ...`` then ``o.cores``: (busy time of the whole machine from /proc/stat
- the CPU time of this process and its ended children) / wall time, in cores. /proc/stat counts
clock ticks (10 ms), so the figure means something over blocks of a second or more. None where
/proc/stat does not exist.
"""

from __future__ import annotations

import os
import time


def _machine_busy() -> float | None:
    try:
        with open("/proc/stat") as f:
            v = [int(x) for x in f.readline().split()[1:]]
    except OSError:
        return None
    # user nice system idle iowait irq softirq steal ...: everything but idle and iowait
    return (sum(v[:8]) - v[3] - v[4]) / os.sysconf("SC_CLK_TCK")


def _own_cpu() -> float:
    """CPU seconds of this process and of its children that have ended (a benchmark that runs
    each build in a child process counts those as its own, not as other processes')."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class OtherLoad:
    cores: float | None = None

    def __enter__(self) -> OtherLoad:
        self._busy, self._own, self._wall = (
            _machine_busy(),
            _own_cpu(),
            time.perf_counter(),
        )
        return self

    def __exit__(self, *exc: object) -> None:
        wall = time.perf_counter() - self._wall
        busy = _machine_busy()
        if busy is not None and self._busy is not None and wall > 0:
            own = _own_cpu() - self._own
            self.cores = max(0.0, (busy - self._busy - own) / wall)

    def __str__(self) -> str:
        return "unknown" if self.cores is None else f"{self.cores:.2f} cores"
