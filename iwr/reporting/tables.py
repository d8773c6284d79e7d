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


def split_columns(table: Table, keys: list[int], width: int = 12) -> list[Table]:
    """A table too wide for a page as several, each with the ``keys`` columns (which name a row)
    then at most ``width - len(keys)`` of the others, in order: every cell on the page, none cut at
    its right edge."""
    head, rows = table
    rest = [j for j in range(len(head)) if j not in keys]
    step = max(1, width - len(keys))
    if len(head) <= width:
        return [table]
    out: list[Table] = []
    for i in range(0, len(rest), step):
        cols = list(keys) + rest[i:i + step]
        out.append(([head[j] for j in cols], [[r[j] for j in cols] for r in rows]))
    return out
