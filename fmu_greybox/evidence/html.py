"""Pieces of the self-contained HTML reports: page shell, tables, embedded figures.

Every report is one file: figures are embedded as base64 PNGs, the style sheet is inline and
there is no script, so a report can be mailed, filed with a test campaign or opened offline.
"""

from __future__ import annotations

import html
from collections.abc import Iterable, Sequence
from pathlib import Path

import matplotlib.pyplot as plt

from fmu_greybox.atomic import atomic_write
from fmu_greybox.evidence.render import png_base64, resolve

STYLE = (
    "body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222;}"
    "table{border-collapse:collapse;margin:1em 0;}"
    "td,th{border:1px solid #bbb;padding:4px 8px;text-align:left;font-size:90%;}"
    "th{background:#eee;}"
    ".verdict{background:#f4f4f4;padding:0.5em 1em;border-left:4px solid #555;}"
    "img{max-width:100%;}code{font-size:85%;word-break:break-all;}"
    ".pass{color:#fff;background:#1a7f37;padding:0 6px;font-weight:bold;}"
    ".fail{color:#fff;background:#c62828;padding:0 6px;font-weight:bold;}"
    ".undecided{color:#000;background:#f2c94c;padding:0 6px;font-weight:bold;}"
    ".verdict li{margin:0.3em 0;}"
    ".summary{border:2px solid #555;padding:0.3em 1em;margin:1em 0;}"
    ".summary h2{margin:0.3em 0;}.summary p{margin:0.4em 0;}"
    ".thin{color:#7a5b00;background:#fff3cd;border:1px solid #c9a227;padding:0 4px;}"
    ".notes li{margin:0.3em 0;font-size:90%;}"
    "a.term{color:inherit;text-decoration:underline dotted;}"
    "dt{font-weight:bold;margin-top:0.5em;}"
)


class Html(str):
    """Text that is already HTML: :func:`table` puts it in a cell or header unescaped."""


def cell_html(value: object) -> str:
    """A value as HTML: an :class:`Html` as it is, anything else escaped."""
    return value if isinstance(value, Html) else escape(value)


def escape(value: object) -> str:
    """HTML-escaped text of any value."""
    return html.escape(str(value))


def page(title: str, sections: Iterable[str]) -> str:
    """A whole HTML document.

    Parameters
    ----------
    title : str
        Title and first heading.
    sections : iterable of str
        HTML fragments, in order (their figures rendered aside are put in place:
        :func:`~fmu_greybox.evidence.render.resolve`).
    """
    text = "\n".join(
        [
            "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
            f"<title>{escape(title)}</title><style>{STYLE}</style></head><body>",
            f"<h1>{escape(title)}</h1>",
            *sections,
            "</body></html>",
        ]
    )
    return resolve(text)


def verdict(lines: Sequence[str], heading: str = "Verdict") -> str:
    """The verdict box: one list item per line."""
    body = "".join(f"<li>{escape(line)}</li>" for line in lines)
    return f"<div class='verdict'><h2>{escape(heading)}</h2><ul>{body}</ul></div>"


def table(header: Sequence[str], rows: Iterable[Sequence[object]], raw: bool = False) -> str:
    """A table; cells and headers are escaped unless ``raw`` or :class:`Html`.

    Parameters
    ----------
    header : sequence of str
    rows : iterable of sequences, each as long as ``header``
    raw : bool
        Cells are already HTML.
    """
    cell = str if raw else cell_html
    parts = ["<table><tr>", *(f"<th>{cell_html(h)}</th>" for h in header), "</tr>"]
    for row in rows:
        parts.append("<tr>" + "".join(f"<td>{cell(c)}</td>" for c in row) + "</tr>")
    parts.append("</table>")
    return "".join(parts)


def notes_list(notes: Sequence[str], prefix: str = "note") -> str:
    """Numbered notes under a table (HTML fragments), each with the anchor ``#PREFIX-N`` a cell
    links to (:func:`note_link`); empty without notes."""
    if not notes:
        return ""
    items = "".join(f"<li id='{prefix}-{n}'>{note}</li>" for n, note in enumerate(notes, 1))
    return f"<ol class='notes'>{items}</ol>"


def note_link(number: int, prefix: str = "note") -> str:
    """A cell's link to its note under the table (:func:`notes_list`)."""
    return f"<a href='#{prefix}-{number}'>note {number}</a>"


def figure(title: str, fig: plt.Figure, caption: str = "") -> str:
    """A titled figure embedded as PNG (the figure is closed)."""
    data = png_base64(fig)
    note = f"<p>{escape(caption)}</p>" if caption else ""
    return (
        f"<h2>{escape(title)}</h2>{note}"
        f"<img alt='{escape(title)}' src='data:image/png;base64,{data}'>"
    )


def fmt(value: float | None, digits: int = 3, unit: str = "") -> str:
    """A number in ``digits`` significant figures (blank for ``None``)."""
    if value is None:
        return ""
    text = f"{value:.{digits}g}"
    return f"{text} {unit}".strip()


def percent(fraction: float | None) -> str:
    """A signed percentage of a fraction (blank for ``None``)."""
    return "" if fraction is None else f"{100 * fraction:+.1f} %"


def write_page(html_text: str, path: str | Path) -> None:
    """Write a page atomically (an earlier page stays whole until the new one is complete)."""
    with atomic_write(Path(path)) as f:
        f.write(html_text)
