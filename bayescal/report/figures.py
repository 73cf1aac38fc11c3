"""Figures without pyplot: no global backend switch, no figure registry.

Library code draws on :class:`matplotlib.figure.Figure` objects directly, so
writing a report or a plot neither calls ``matplotlib.use`` nor leaves figures
open in a user's pyplot session (architecture, section 1: importing or
calling bayescal never changes a user's global state).
"""

from __future__ import annotations

import base64
import io

__all__ = ["subplots", "colours", "png_base64", "rank_histograms", "save_figure"]


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


def save_figure(fig, path, dpi: int = 110) -> None:
    """Write the figure to ``path`` atomically, in the format its suffix names (``.png``, ``.pdf``, ...)."""
    from bayescal.io.outputs import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=str(path).rsplit(".", 1)[-1])


def rank_histograms(counts, n_sims: int, p_values, title: str):
    """Simulation-based calibration's rank histograms (Talts et al. 2018), a panel per quantity.

    ``counts``: a DataFrame of rank counts, a row per bin and a column per quantity, from
    ``n_sims`` simulated datasets; ``p_values``: the uniformity p-value per column.  Each
    panel shades the 99 % band of one bin's count under uniform ranks (binomial).
    """
    import numpy as np
    from scipy import stats

    bins, n = counts.shape
    cols = min(6, n)
    rows = int(np.ceil(n / cols))
    fig, axes = subplots(rows, cols, figsize=(2.2 * cols, 1.7 * rows), squeeze=False, sharey=True)
    lo, hi = stats.binom.ppf([0.005, 0.995], n_sims, 1 / bins)
    for ax, name in zip(axes.ravel(), counts.columns, strict=False):
        ax.axhspan(lo, hi, color="0.85", lw=0)
        ax.bar(np.arange(bins), counts[name], width=1.0, color="C0", alpha=0.8)
        ax.set_title(f"{name}\np={p_values[name]:.2g}", fontsize=7)
        ax.set_xticks([])
        ax.tick_params(labelsize=6)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return fig
