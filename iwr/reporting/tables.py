"""Tables as Markdown and HTML, and the number format of the reports."""

from __future__ import annotations

import html
import math
from typing import Any

import numpy as np

__all__ = ["fmt", "markdown_table", "html_table", "split_columns", "Table"]

#: A table: the header and the rows, every cell already text.
Table = tuple[list[str], list[list[str]]]


def fmt(v: Any, digits: int = 3) -> str:
    """A value as short text: ``yes``/``no``, integers as they are, floats to ``digits``
    significant digits, nan as ``n/a``."""
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        if math.isnan(v):
            return "n/a"
        return f"{v:.{digits}g}"
    if v is None:
        return ""
    return str(v)


def markdown_table(table: Table) -> str:
    """A GitHub-flavoured Markdown table (ends with a newline)."""
    head, rows = table
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def html_table(table: Table, css_class: str = "") -> str:
    """An HTML table, every cell escaped."""
    head, rows = table
    cls = f' class="{html.escape(css_class)}"' if css_class else ""
    out = [f"<table{cls}>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    for r in rows:
        out.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>")
    out.append("</table>")
    return "\n".join(out)


def split_columns(table: Table, keys: list[int], width: int = 120) -> list[Table]:
    """A table too wide for a page as several, each with the ``keys`` columns (which name a row)
    then as many of the others, in order, as fit in ``width`` characters (a column takes its
    longest cell or header plus 3 for its padding and border): every cell on the page, none cut
    at its right edge."""
    head, rows = table

    def chars(j: int) -> int:
        return max([len(head[j])] + [len(r[j]) for r in rows]) + 3

    rest = [j for j in range(len(head)) if j not in keys]
    if sum(chars(j) for j in range(len(head))) <= width:
        return [table]
    base = sum(chars(j) for j in keys)
    out: list[Table] = []
    group: list[int] = []
    for j in rest:
        if group and base + sum(chars(i) for i in group) + chars(j) > width:
            out.append(_columns(table, list(keys) + group))
            group = []
        group.append(j)
    if group:
        out.append(_columns(table, list(keys) + group))
    return out


def _columns(table: Table, cols: list[int]) -> Table:
    head, rows = table
    return [head[j] for j in cols], [[r[j] for j in cols] for r in rows]
