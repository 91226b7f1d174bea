"""One self-contained HTML page: inline CSS and SVG, no script, no network (a CI artefact
that opens anywhere, offline)."""

from __future__ import annotations

from collections.abc import Sequence
from html import escape

__all__ = ["escape", "figure", "page", "table", "verdict"]

STYLE = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:2em auto;max-width:70em;
color:#222;padding:0 1em}
h1{font-size:1.5em}h2{font-size:1.2em;margin-top:1.6em}
table{border-collapse:collapse;margin:.6em 0}
th,td{border:1px solid #ccc;padding:.25em .6em;text-align:right}
th:first-child,td:first-child{text-align:left}
table.settings td,table.settings th{text-align:left}
.verdict{font-size:1.2em;font-weight:bold;padding:.4em .8em;display:inline-block;border-radius:4px}
.bad{background:#fde2e1;color:#8a1c14}.good{background:#e3f4e1;color:#1d5e17}
figure{margin:1em 0}figure svg{max-width:100%;height:auto}
footer{margin-top:2em;color:#666;font-size:.9em}
"""


def table(header: Sequence[str], rows: Sequence[Sequence[str]], cls: str = "") -> str:
    """An HTML table of text cells (escaped)."""
    head = "".join(f"<th>{escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{escape(str(c))}</td>" for c in row) + "</tr>" for row in rows
    )
    attr = f' class="{escape(cls)}"' if cls else ""
    return f"<table{attr}><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def verdict(text: str, bad: bool) -> str:
    return f'<p class="verdict {"bad" if bad else "good"}">{escape(text)}</p>'


def figure(svg: str, caption: str) -> str:
    return f"<figure>{svg}<figcaption>{escape(caption)}</figcaption></figure>"


def page(title: str, summary: Sequence[str], figures: Sequence[str], settings: str) -> str:
    """The page in the order people read it: summary, figures, settings and version."""
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        # how twincd recognises its own report before writing over it (twincd.io.atomic)
        '<meta name="generator" content="twincd">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        # nothing may be fetched: not even a favicon
        '<link rel="icon" href="data:,">',
        f"<title>{escape(title)}</title><style>{STYLE}</style></head><body>",
        f"<h1>{escape(title)}</h1>",
        '<section id="summary">',
        *summary,
        "</section>",
        '<section id="figures"><h2>Figures</h2>',
        *(figures or ["<p>No figures.</p>"]),
        "</section>",
        f'<section id="settings"><h2>Settings</h2>{settings}</section>',
        "</body></html>",
    ]
    return "\n".join(parts)
