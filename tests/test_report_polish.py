"""Report polish (issue 22, item 5): the convergence plot keeps eq. (10) on its axis, histogram
axes stay readable with large values, wide tables are split rather than cut at the page edge."""

from __future__ import annotations

import numpy as np

from iwr.reporting.compare import _history_is_eq10
from iwr.reporting.figures import histogram, new_figure
from iwr.reporting.tables import split_columns


def test_history_objective_decides_the_axis():
    assert _history_is_eq10({"history_objective": "eq10", "history_best": [200.0], "cost": 0.07})
    assert not _history_is_eq10({"history_objective": "own", "history_best": [0.07],
                                 "cost": 0.07})
    # Runs of an older iwr: told by the last value against eq. (10)'s cost at the result.
    assert _history_is_eq10({"history_best": [3.0, 0.0771], "cost": 0.0771})
    assert not _history_is_eq10({"history_best": [201.3], "cost": 0.0771})
    assert _history_is_eq10({"history_best": [], "cost": 0.0771})


def test_histogram_axes_readable_with_large_values():
    fig = new_figure(4, 3)
    ax = fig.add_subplot()
    histogram(ax, np.array([100000.0, 150000.0, 200000.0, 120000.0, 180000.0, 130000.0]), "C0")
    fig.canvas.draw()
    lo, hi = ax.get_xlim()
    shown = [t.get_text().replace("$\\mathdefault{", "").replace("}$", "")
             for t, v in zip(ax.get_xticklabels(), ax.get_xticks(), strict=True)
             if lo <= v <= hi and t.get_text()]
    assert 2 <= len(shown) <= 7, shown
    assert all(len(t) <= 6 for t in shown), shown  # not "100000150000200000"
    assert ax.xaxis.get_offset_text().get_text()  # the common power of ten
    counts = ax.get_yticks()
    assert np.allclose(counts, np.round(counts))  # whole poses


def test_wide_table_split_keeps_every_cell_and_the_keys():
    head = ["scenario", "method", "seed"] + [f"a_rather_long_column_{i}" for i in range(20)]
    rows = [["near", m, str(s)] + [f"{i * 1.2345:.4g}" for i in range(20)]
            for m in ("lm", "de") for s in (0, 1)]
    parts = split_columns((head, rows), [0, 1, 2], width=120)
    assert len(parts) > 1
    seen = []
    for h, r in parts:
        assert h[:3] == ["scenario", "method", "seed"]
        assert [x[:3] for x in r] == [x[:3] for x in rows]
        width = sum(max([len(h[j])] + [len(x[j]) for x in r]) + 3 for j in range(len(h)))
        assert width <= 120 or len(h) == 4
        seen += h[3:]
    assert seen == head[3:]
    narrow = (head[:5], [x[:5] for x in rows])
    assert split_columns(narrow, [0, 1, 2]) == [narrow]
