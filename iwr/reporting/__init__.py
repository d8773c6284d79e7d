"""Reports: figures (bare :class:`matplotlib.figure.Figure`, :mod:`.figures`), tables
(:mod:`.tables`), self-contained HTML pages with provenance (:mod:`.html`), and the reports of
``iwr calibrate`` (:mod:`.calibration`), ``iwr compare`` (:mod:`.compare`) and ``iwr study``
(:mod:`.study`). Markdown beside each HTML report, for terminals and diffs."""

from __future__ import annotations

__all__: list[str] = []
