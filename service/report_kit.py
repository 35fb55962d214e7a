"""The parts every HTML page graytrack writes is made of: a figure as an embedded PNG, the page's
CSS (once), table cells and rows, and the page around them.

``report.html`` (service/report.py) and ``history.html`` (service/batch/history_report.py) are
self-contained files (plots embedded as PNG data, no script, no external stylesheet) because they
are read on rigs without network access, served by the daemon under a CSP of ``default-src
'none'`` and mailed around as they are. One kit keeps them looking and behaving alike.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Iterable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator  # noqa: E402

PNG_DPI = 90
CSS = """body{font-family:system-ui,sans-serif;max-width:1150px;margin:2em auto;color:#222}
table{border-collapse:collapse;width:100%}
td,th{border:1px solid #ccc;padding:4px 6px;font-size:13px;vertical-align:top}
th{background:#f3f3f3;text-align:left}.big{font-size:20px}img{max-width:100%}.flag{color:#b00}
.note{color:#666}"""


def png(figure: plt.Figure) -> str:
    """``figure`` as base64 PNG data (the figure is closed: a page renders each once)."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=PNG_DPI, bbox_inches="tight")
    plt.close(figure)
    return base64.b64encode(buffer.getvalue()).decode("ascii")


def image(title: str, data: str) -> str:
    """An embedded PNG (from :func:`png`) under its heading."""
    return f'<h2>{html.escape(title)}</h2><img alt="{html.escape(title)}" src="data:image/png;base64,{data}">'


def cell(text: object, header: bool = False) -> str:
    """One table cell, its text escaped."""
    tag = "th" if header else "td"
    return f"<{tag}>{html.escape(str(text))}</{tag}>"


def table(header: Iterable[object] | None, rows: Iterable[Iterable[object]]) -> str:
    """A table of escaped text: a header row (when given), then one row per item."""
    head = "<tr>" + "".join(cell(text, header=True) for text in header) + "</tr>" if header is not None else ""
    body = "".join("<tr>" + "".join(cell(text) for text in row) + "</tr>" for row in rows)
    return f"<table>{head}{body}</table>"


def page(title: str, body: str) -> str:
    """The whole self-contained document: ``title`` (escaped) as its title and first heading."""
    title = html.escape(title)
    return (f'<!doctype html>\n<html lang="en"><head><meta charset="utf-8"><title>{title}</title>\n'
            f"<style>{CSS}</style></head><body>\n<h1>{title}</h1>\n{body}\n</body></html>\n")


def plain_log_axis(axis: "matplotlib.axis.Axis") -> None:
    """Ticks of a log axis as plain numbers (0.5, 1, 2, 4) rather than 4×10⁰: a reader compares
    them with figures printed as plain numbers in the text and the tables. Ticks at 1, 2, 3 and 5
    of each decade: at least two on any axis spanning a factor of two."""
    axis.set_major_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 3.0, 5.0)))
    axis.set_minor_locator(LogLocator(base=10.0, subs=(1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0)))
    axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))
    axis.set_minor_formatter(FuncFormatter(lambda value, _: ""))
