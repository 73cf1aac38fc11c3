"""The self-contained HTML page every bayescal report is: one style, tables, embedded figures.

Reports of a fit, of per-pixel maps, of a fleet and of a film calibration all build their body
from :func:`table`, :func:`image` and :func:`verdict` and wrap it with :func:`page`, so they look
alike and a browser test can check every one the same way (the page records how many of its
images decoded in ``body[data-images]``).
"""

from __future__ import annotations

import html

import pandas as pd

from bayescal.report.text import table_rows

__all__ = ["page", "table", "image", "verdict", "escape"]

escape = html.escape

_CSS = """
body{font-family:system-ui,sans-serif;max-width:1500px;margin:1.5em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:.5em 0 1.5em;font-size:13px}
td,th{border:1px solid #ccc;padding:3px 7px;text-align:right}th{background:#f2f2f2}
.ok{background:#e7f6e7;border:2px solid #3a3;padding:.6em}
.failed{background:#fde8e8;border:3px solid #c00;padding:.8em;font-size:1.3em;font-weight:bold}
img{max-width:100%}
"""

_CHECK_IMAGES = """
<script>
window.addEventListener('load', function () {
  var imgs = document.images, good = 0;
  for (var i = 0; i < imgs.length; i++) { if (imgs[i].complete && imgs[i].naturalWidth > 0) good++; }
  document.body.setAttribute('data-images', good + '/' + imgs.length);
});
</script>
"""


def page(title: str, body: str) -> str:
    """A complete HTML document: ``title`` (escaped here) and ``body`` (HTML)."""
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>bayescal report: {escape(title)}</title><style>{_CSS}</style></head>
<body>
{body}
{_CHECK_IMAGES}
</body></html>
"""


def table(df: pd.DataFrame) -> str:
    """A DataFrame as an HTML table (numbers to 5 significant digits)."""
    head, rows = table_rows(df)
    th = "".join(f"<th>{escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def image(png_base64: str, alt: str) -> str:
    """An embedded PNG figure."""
    return f'<img alt="{escape(alt)}" src="data:image/png;base64,{png_base64}">'


def verdict(ok: bool, problems, passed: str) -> str:
    """The verdict box: green with ``passed``, or a red FAILED banner listing the problems."""
    if ok:
        return f'<div class="ok" id="verdict">{escape(passed)}</div>'
    items = "".join(f"<li>{escape(p)}</li>" for p in problems)
    return f'<div class="failed" id="verdict">FIT FAILED. Do not use these numbers.<ul>{items}</ul></div>'
