"""Self-contained HTML reports: one file, the figures embedded as base64 PNG, no script, style or
font from elsewhere; and the provenance every report ends with."""

from __future__ import annotations

import base64
import datetime
import hashlib
import html
import os
import sys
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from .tables import Table, html_table

__all__ = ["Page", "provenance", "sha256_file", "iwr_version"]

_STYLE = (
    "body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;max-width:1150px;"
    "margin:2em auto;padding:0 1em;color:#1b1b1b;line-height:1.45}"
    "h1{font-size:1.6em;margin-bottom:0.2em}h2{border-bottom:1px solid #ccc;padding-bottom:2px;"
    "margin-top:1.8em}"
    "table{border-collapse:collapse;font-size:0.85em;margin:0.8em 0}"
    "td,th{border:1px solid #bbb;padding:3px 7px;text-align:right;vertical-align:top}"
    "th{background:#eee}td:first-child,td:nth-child(2){text-align:left}"
    "table.left td{text-align:left}table.params td:nth-child(5){text-align:left}"
    "table.num td:nth-child(2),table.params td:nth-child(2){text-align:right}"
    "th{text-align:center}"
    "figure{margin:1.2em 0}img{max-width:100%;height:auto}"
    "figcaption{font-size:0.9em;color:#333}"
    "pre{background:#f6f6f6;padding:0.6em;font-size:0.85em;white-space:pre-wrap;"
    "overflow-wrap:anywhere}"
    ".tw{overflow-x:auto;max-width:100%}"
    ".verdict{font-size:1.1em;padding:0.6em 0.9em;border-radius:4px;margin:0.8em 0}"
    ".good{background:#e3f4e1;border-left:5px solid #2e7d32}"
    ".fair{background:#fff4d6;border-left:5px solid #b7791f}"
    ".bad{background:#fbe3e3;border-left:5px solid #c62828}"
    ".muted{color:#555;font-size:0.9em}"
)


def iwr_version() -> str:
    """The installed package's version (its metadata: the one place the version is written)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("iwr")
    except PackageNotFoundError:  # pragma: no cover - a source tree that is not installed
        return "unknown"


def sha256_file(path: str | os.PathLike[str]) -> str:
    """The SHA-256 of a file's bytes, in hex."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def provenance_table(prov: Mapping[str, Any]) -> Table:
    """The provenance (:func:`provenance`) as the reports show it, HTML and Markdown alike."""
    rows = [
        ["iwr version", str(prov.get("iwr_version", ""))],
        ["SIMD kernel (IWR_KERNEL)", str(prov.get("kernel", "not recorded"))],
        ["Python", str(prov.get("python", ""))],
        ["command", " ".join(_quote(a) for a in prov.get("command", []))],
        ["date", str(prov.get("date", ""))],
    ]
    for label, f in prov.get("inputs", {}).items():
        rows.append([f"{label}: {f['path']}", f"SHA-256 {f['sha256']}"])
    return ["what", "value"], rows


def provenance(inputs: Mapping[str, str | os.PathLike[str] | None] | None = None,
               command: Sequence[str] | None = None) -> dict[str, Any]:
    """Where a report comes from: the iwr version, the objective's SIMD kernel variant of this
    process (``avx2`` and ``avx512`` give the same bits, ``baseline`` another path for the same
    seed; the environment variable IWR_KERNEL selects one), the command line, the date (UTC) and
    the SHA-256 of each input file (``{label: path}``; None: not a file, e.g. a built-in robot)."""
    from .. import _core

    files = {}
    for label, path in (inputs or {}).items():
        if path is None:
            continue
        files[label] = {"path": str(path), "sha256": sha256_file(path)}
    argv = list(sys.argv if command is None else command)
    if argv and argv[0].endswith(("__main__.py", "/iwr")):
        argv[0] = "iwr"
    return {
        "iwr_version": iwr_version(),
        "kernel": _core._active_kernel(),
        "python": sys.version.split()[0],
        "command": argv,
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"),
        "inputs": files,
    }


class Page:
    """An HTML page built section by section; :meth:`render` gives the text of one file."""

    def __init__(self, title: str) -> None:
        self.title = title
        self.parts: list[str] = [f"<h1>{html.escape(title)}</h1>"]

    def heading(self, text: str, level: int = 2) -> Page:
        self.parts.append(f"<h{level}>{html.escape(text)}</h{level}>")
        return self

    def paragraph(self, text: str, css_class: str = "") -> Page:
        cls = f' class="{css_class}"' if css_class else ""
        self.parts.append(f"<p{cls}>{html.escape(text)}</p>")
        return self

    def verdict(self, text: str, grade: str) -> Page:
        """A highlighted verdict; ``grade`` is ``good``, ``fair`` or ``bad``."""
        self.parts.append(f'<div class="verdict {grade}">{html.escape(text)}</div>')
        return self

    def items(self, texts: Iterable[str]) -> Page:
        self.parts.append("<ul>" + "".join(f"<li>{html.escape(t)}</li>" for t in texts) + "</ul>")
        return self

    def table(self, table: Table, css_class: str = "") -> Page:
        # In a box that scrolls sideways should a table still be wider than the page: never
        # cut at its right edge (a long line of text wraps, a <pre> too).
        self.parts.append('<div class="tw">' + html_table(table, css_class) + "</div>")
        return self

    def pre(self, text: str) -> Page:
        self.parts.append(f"<pre>{html.escape(text)}</pre>")
        return self

    def figure(self, png: bytes, caption: str, name: str = "") -> Page:
        b64 = base64.b64encode(png).decode("ascii")
        ident = f' id="{html.escape(name)}"' if name else ""
        label = f" ({html.escape(name)})" if name else ""
        self.parts.append(
            f'<figure{ident}><img alt="{html.escape(caption)}" '
            f'src="data:image/png;base64,{b64}"><figcaption>{html.escape(caption)}{label}'
            "</figcaption></figure>"
        )
        return self

    def provenance(self, prov: Mapping[str, Any]) -> Page:
        """The provenance section (:func:`provenance`)."""
        self.heading("Provenance")
        return self.table(provenance_table(prov), "left")

    def render(self) -> str:
        return "\n".join([
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            '<meta name="viewport" content="width=device-width, initial-scale=1">',
            f"<title>{html.escape(self.title)}</title>",
            f"<style>{_STYLE}</style></head><body>",
            *self.parts,
            "</body></html>",
            "",
        ])


def _quote(arg: str) -> str:
    import shlex

    return shlex.quote(str(arg))


def write_page(page: Page, path: str | os.PathLike[str]) -> Path:
    """Write the page atomically; returns the path."""
    from .._io import atomic_write_text

    atomic_write_text(path, page.render())
    return Path(path)
