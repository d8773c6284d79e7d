"""The figure convention of every report: a bare :class:`matplotlib.figure.Figure` with its own
Agg canvas (no pyplot, no global backend switch, nothing to close), saved as PNG with fixed
metadata so that the same numbers give the same bytes."""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .._io import atomic_write_bytes

__all__ = ["new_figure", "png_bytes", "save_png", "method_colors", "histogram", "PALETTE"]

#: Colours of lines and markers, in order (matplotlib's default cycle).
PALETTE = ["#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf"]
# The usual methods keep their colour in every report.
_FIXED_COLORS = {"lm": "#1f77b4", "de": "#d62728", "crs2": "#2ca02c", "bobyqa": "#ff7f0e",
                 "de:jso": "#9467bd"}


def new_figure(width: float, height: float, dpi: float = 100) -> Any:
    """A :class:`matplotlib.figure.Figure` of ``width`` x ``height`` inches with an Agg canvas."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def png_bytes(fig: Any, dpi: float | None = None) -> bytes:
    """The figure as PNG bytes (fixed metadata: the same figure gives the same bytes)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    return buf.getvalue()


def save_png(fig: Any, path: str | Path, dpi: float | None = None) -> Path:
    """Write the figure as PNG to ``path`` atomically; returns the path."""
    path = Path(path)
    atomic_write_bytes(path, png_bytes(fig, dpi))
    return path


def method_colors(names: Sequence[str]) -> dict[str, str]:
    """One colour per name, the same in every report for the usual methods."""
    others = [c for c in PALETTE if c not in _FIXED_COLORS.values()]
    out: dict[str, str] = {}
    k = 0
    for m in names:
        if m in _FIXED_COLORS:
            out[m] = _FIXED_COLORS[m]
        else:
            out[m] = others[k % len(others)]
            k += 1
    return out


def before_units(nominal_mm: Any, nominal_deg: Any = None
                 ) -> tuple[tuple[str, float], tuple[str, float]]:
    """The units of the accuracy figures' "before" panels, ``((position unit, factor from mm),
    (orientation unit, factor from degrees))``: mm and degrees, as an uncalibrated robot's
    errors are; um and arcsec, as the "after" panels', where the robot given is already that
    accurate (RMS below 1 mm, 0.1 degree: a robot calibrated before), so that the two panels of
    a re-calibration are read in one unit (they said 0.0374 mm beside 44.9 um)."""
    from ..kinds import finite_rms

    pos = ("um", 1000.0) if finite_rms(nominal_mm) < 1.0 else ("mm", 1.0)
    ori = (("arcsec", 3600.0) if nominal_deg is not None and finite_rms(nominal_deg) < 0.1
           else ("deg", 1.0))
    return pos, ori


def histogram(ax: Any, values: Any, color: str) -> None:
    """A histogram of ``values`` on ``ax`` whose axes stay readable: at most 6 ticks on the value
    axis, large or small values with a common power of ten (not "100000150000200000"), whole
    counts on the count axis (no half-pose steps)."""
    import numpy as np
    from matplotlib.ticker import MaxNLocator, ScalarFormatter

    v = np.asarray(values, dtype=float)
    ax.hist(v, bins=min(30, max(5, v.size // 3)), color=color)
    ax.xaxis.set_major_locator(MaxNLocator(nbins=6))
    # The power of ten as plain text ("1e5"): with useMathText every tick label goes through
    # matplotlib's mathtext parser, 0.15 s of CPU (7 %) of `iwr calibrate` on the example.
    fmt = ScalarFormatter(useMathText=False)
    fmt.set_powerlimits((-3, 4))
    ax.xaxis.set_major_formatter(fmt)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
