"""A self-contained HTML page for per-pixel maps: the maps, their uncertainty, histograms, defects.

Large sensors are shown block-averaged to at most ``MAX_SIDE`` pixels a side
(defects by block maximum, so one hot pixel still shows); the histograms use
every pixel of the store, read chunk by chunk.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from bayescal.io.outputs import write_text_atomic
from bayescal.report.figures import png_base64, subplots
from bayescal.report.page import escape, image, page, table
from bayescal.report.text import markdown_table

__all__ = ["maps_report"]

MAX_SIDE = 512
_TITLES = {
    "relative_gain": "relative gain (PRNU)",
    "offset_dn": "offset, DN (DSNU)",
    "dark_current_dn_s": "dark current, DN/s",
}


def _shown(da, how: str = "mean") -> np.ndarray:
    """Block-reduce a (y, x) map to at most MAX_SIDE a side."""
    h, w = da.shape
    f = max(1, int(np.ceil(max(h, w) / MAX_SIDE)))
    if f == 1:
        return np.asarray(da)
    c = da.coarsen(y=f, x=f, boundary="trim")
    return np.asarray(c.max() if how == "max" else c.mean())


def _histogram(da, bins: np.ndarray) -> np.ndarray:
    """Counts of every finite value, chunk by chunk (never the whole map in memory at once)."""
    counts = np.zeros(bins.size - 1)
    step = max(1, (1 << 22) // max(da.shape[1], 1))
    for r in range(0, da.shape[0], step):
        v = np.asarray(da[r : r + step]).ravel()
        counts += np.histogram(v[np.isfinite(v)], bins=bins)[0]
    return counts


def _channel_views(ds) -> list[tuple[str, Any, dict]]:
    """``[(channel, its pixels' maps, its population attributes)]`` (a mosaic: each colour's first plane)."""
    from bayescal.io.cfa import planes
    from bayescal.maps.metadata import channel_attrs

    channels = list(ds.attrs.get("channels", ["M"]))
    step, layout = planes(ds.attrs.get("cfa") or None, channels[0])
    seen = {}
    for name, dy, dx in layout:
        if name not in seen:
            seen[name] = (name, ds.isel(y=slice(dy, None, step), x=slice(dx, None, step)), channel_attrs(ds, name))
    return list(seen.values())


def maps_report(ds, out: str | os.PathLike) -> Path:
    """Write ``maps_report.html`` for the maps ``ds`` into directory ``out`` (atomically)."""
    out = Path(out)
    names = [n for n in _TITLES if n in ds]
    figs = []
    fig, axes = subplots(2, len(names), figsize=(4.2 * len(names), 7.2), squeeze=False)
    for j, name in enumerate(names):
        for i, (var, label) in enumerate(((name, _TITLES[name]), (f"u_random_{name}", "posterior sd"))):
            img = _shown(ds[var])
            lo, hi = np.nanpercentile(img, [0.5, 99.5])
            im = axes[i, j].imshow(img, vmin=lo, vmax=hi, cmap="viridis" if i == 0 else "magma")
            axes[i, j].set_title(label if i else _TITLES[name], fontsize=10)
            axes[i, j].set_xticks([])
            axes[i, j].set_yticks([])
            fig.colorbar(im, ax=axes[i, j], fraction=0.046, pad=0.04)
    fig.tight_layout()
    figs.append(("Maps and their per-pixel uncertainty (block means for display)", png_base64(fig)))

    views = _channel_views(ds)
    fig, axes = subplots(len(views), len(names), figsize=(4.2 * len(names), 3.4 * len(views)), squeeze=False)
    for i, (channel, sub, attrs) in enumerate(views):
        params = list(attrs["parameters"])
        for j, name in enumerate(names):
            sd = attrs[f"spread_{name}"]
            mu = attrs["population_mean"][params.index(name)]
            bins = np.linspace(mu - 6 * sd, mu + 6 * sd, 121)
            counts = _histogram(sub[name], bins)
            centres = 0.5 * (bins[1:] + bins[:-1])
            ax = axes[i, j]
            ax.semilogy(centres, np.maximum(counts, 0.5), drawstyle="steps-mid", label="posterior means (shrunk)")
            lsq = _histogram(sub[f"lsq_{name}"], bins)
            ax.semilogy(
                centres, np.maximum(lsq, 0.5), drawstyle="steps-mid", alpha=0.6, label="least squares (noisier)"
            )
            normal = (
                counts.sum()
                * (bins[1] - bins[0])
                * np.exp(-0.5 * ((centres - mu) / sd) ** 2)
                / (sd * np.sqrt(2 * np.pi))
            )
            ax.semilogy(centres, normal, "--", label=f"population N({mu:.4g}, {sd:.3g}$^2$)")
            ax.set_ylim(0.5, None)
            ax.set_xlabel(_TITLES[name] + (f", channel {channel}" if len(views) > 1 else ""), fontsize=9)
            ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.2))
    fig.tight_layout()
    figs.append(("Histograms of every pixel against the fitted population (log scale)", png_base64(fig)))

    defect = _shown(ds["defect"], how="max")
    fig, ax = subplots(figsize=(5.0, 4.4))
    from matplotlib.colors import BoundaryNorm, ListedColormap

    palette = ["#f2f2f2", "#d62728", "#1f1f1f", "#ff7f0e", "#2ca02c", "#1f77b4"]
    cmap = ListedColormap(palette)
    im = ax.imshow(defect, cmap=cmap, norm=BoundaryNorm(np.arange(-0.5, 6), cmap.N), interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    cb = fig.colorbar(im, ax=ax, ticks=range(6))
    cb.ax.set_yticklabels(ds["defect"].attrs["flag_meanings"].split())
    figs.append(("Defect classes (block maximum for display)", png_base64(fig)))

    codes = ds["defect"].attrs["flag_meanings"].split()
    full = np.bincount(np.asarray(ds["defect"]).ravel().astype(np.int64), minlength=len(codes))
    rows = []
    for channel, _, attrs in views:
        for n in attrs["parameters"]:
            lo, hi = attrs[f"spread_{n}_95"]
            rows.append((channel, f"spread of {n}", attrs[f"spread_{n}"], lo, hi))
        rows.append((channel, "defect fraction", attrs["population_weights"][1], np.nan, np.nan))
        rows.append((channel, "noisy fraction", attrs["noisy_fraction"], np.nan, np.nan))
    population = pd.DataFrame(rows, columns=["channel", "quantity", "value", "95 % low", "95 % high"])
    defects = pd.DataFrame({"class": codes, "pixels": full})
    body = [
        "<h1>Per-pixel calibration maps</h1>",
        f"<p>{ds.sizes['y']} x {ds.sizes['x']} pixels from "
        f"<code>{escape(str(ds.attrs.get('stacks', '')))}</code>; "
        f"bayescal {escape(str(ds.attrs.get('bayescal_version', '')))}. The relative gain's systematic "
        f"(all-pixel) standard uncertainty is {views[0][2]['u_systematic_relative_gain']:.2e}.</p>",
        "<h2>Population</h2>",
        table(population),
        "<h2>Defects</h2>",
        table(defects),
    ]
    for caption, png in figs:
        body.append(f"<figure>{image(png, caption)}<figcaption>{escape(caption)}</figcaption></figure>")
    write_text_atomic(out / "maps_report.html", page("per-pixel maps", "\n".join(body)))
    write_text_atomic(
        out / "maps_report.md",
        "# Per-pixel maps\n\n" + markdown_table(population) + "\n\n" + markdown_table(defects) + "\n",
    )
    return out / "maps_report.html"
