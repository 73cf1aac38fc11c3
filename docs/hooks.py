"""mkdocs hook: the reStructuredText roles of the docstrings (``:class:`~bayescal.Fit` ``) shown as
code named by their last component, linked to the API reference where that name is public."""

from __future__ import annotations

import re

ROLE = re.compile(r":(?:class|func|meth|mod|data|attr|exc):<code>~?([\w.]+)</code>")


def _public() -> set[str]:
    import bayescal

    return set(bayescal.__all__)


def on_page_content(html: str, page, config, files) -> str:
    public = _public()
    api = "" if page.file.src_uri == "api.md" else "../" * page.url.count("/") + "api/"

    def name(m: re.Match) -> str:
        target = m.group(1).split(".")
        short = target[-1]
        if short in public and (target[0] != "bayescal" or len(target) >= 2):
            return f'<a href="{api}#bayescal.{short}"><code>{short}</code></a>'
        return f"<code>{short}</code>"

    return ROLE.sub(name, html)
