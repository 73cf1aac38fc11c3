"""Figures without pyplot: no global backend switch, no figure registry.

Library code draws on :class:`matplotlib.figure.Figure` objects directly, so
writing a report or a plot neither calls ``matplotlib.use`` nor leaves figures
open in a user's pyplot session (architecture, section 1: importing or
calling bayescal never changes a user's global state).
"""

from __future__ import annotations

import base64
import io

__all__ = ["subplots", "colours", "png_base64"]


def subplots(*args, figsize: tuple[float, float], **kwargs):
    """A new :class:`~matplotlib.figure.Figure` and its axes, as ``pyplot.subplots`` returns them."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    return fig, fig.subplots(*args, **kwargs)


def colours() -> list[str]:
    """The colour cycle of the current matplotlib style."""
    import matplotlib

    return matplotlib.rcParams["axes.prop_cycle"].by_key()["color"]


def png_base64(fig, dpi: int = 110) -> str:
    """The figure as a base64 PNG (for a self-contained HTML page)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    return base64.b64encode(buf.getvalue()).decode("ascii")
