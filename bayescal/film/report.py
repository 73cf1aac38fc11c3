"""The film calibration's report: each band's characteristic curve with its wedge, the posterior table.

One self-contained HTML page and ``report.json`` from a film fit directory (``bayescal report``
dispatches here on the fit's kind).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.film.posterior import FilmCalibration
from bayescal.io.fit_folder import SUMMARY, FitFolder
from bayescal.io.outputs import write_json_atomic, write_text_atomic
from bayescal.report.figures import colours, png_base64, subplots
from bayescal.report.page import escape, image, page, table, verdict

__all__ = ["write_film_report"]


def write_film_report(
    fit_dir: str | os.PathLike | FitFolder, out: str | os.PathLike | None = None, seed: int = 0
) -> Path:
    """Write ``report.html`` and ``report.json`` for a film fit directory (or the
    :class:`~bayescal.io.fit_folder.FitFolder` the report already holds); returns the HTML path."""
    folder = fit_dir if isinstance(fit_dir, FitFolder) else FitFolder.at(fit_dir, "`bayescal report`", (SUMMARY,))
    root = folder.root if folder.root is not None else folder.posterior_path.parent
    out = Path(out) if out is not None else root / "report.html"
    summary = folder.summary  # checked: the keys below are there
    tree = folder.posterior
    cal = FilmCalibration.load(folder.posterior_path, tree)
    frame = folder.measurements
    params = pd.DataFrame(summary.parameters)
    examples = _examples(cal, frame, seed)
    data = {
        "status": summary.status,
        "verdict": summary.diagnostics["verdict"],
        "backend": summary.backend,
        "seed": summary.seed,
        "parameters": summary.parameters,
        "inversion": examples.to_dict("records"),
    }
    write_json_atomic(out.with_suffix(".json"), data)
    d = summary.diagnostics
    body = f"""<h1>Film calibration report: {escape(summary.model["name"])}</h1>
<p>Backend <b>{escape(summary.backend)}</b>, seed {summary.seed}; bands {escape(", ".join(cal.channels))}.
Density against the band radiance of each wedge step (seed 003 eq. 10), with the characteristic curve
D = gamma lg L* + D0 (eq. 5-6): posterior median and 95 % band.</p>
{verdict(summary.status == "ok", d.get("problems", []), "Diagnostics passed for every band.")}
<h2>Characteristic curves</h2>
{image(_fig_curves(cal, frame), "characteristic curves")}
<h2>Posterior per band</h2>
{table(params)}
<h2>Inversion examples (band radiance, {escape(cal.unit)}; 95 % intervals)</h2>
{table(examples)}"""
    write_text_atomic(out, page(summary.model["name"], body))
    return out


def _examples(cal: FilmCalibration, frame: pd.DataFrame, seed: int) -> pd.DataFrame:
    """Each band's lowest, middle and highest wedge density inverted."""
    rows = []
    for band in cal.channels:
        dens = np.sort(frame.loc[frame["band"] == band, "density"].to_numpy(float))
        picks = dens[[0, dens.size // 2, -1]] if dens.size else dens
        rows.append(cal.invert(picks, band, seed=seed).to_frame())
    return pd.concat(rows, ignore_index=True).drop(columns=["bound"])


def _fig_curves(cal: FilmCalibration, frame: pd.DataFrame) -> str:
    fig, ax = subplots(1, 1, figsize=(7.5, 4.8))
    for band, colour in zip(cal.channels, colours(), strict=False):
        b = cal.band(band)
        lg_steps = np.log10(np.median(b["L_steps"], axis=0))
        dens = frame.loc[frame["band"] == band].sort_values("step")["density"].to_numpy(float)
        grid = np.linspace(lg_steps.min() - 0.1, lg_steps.max() + 0.1, 60)
        curves = b["D0"][:, None] + b["gamma"][:, None] * grid[None, :]
        lo, med, hi = np.quantile(curves, [0.025, 0.5, 0.975], axis=0)
        ax.fill_between(grid, lo, hi, color=colour, alpha=0.25, lw=0)
        ax.plot(grid, med, color=colour, lw=1.2, label=f"{band}")
        ax.plot(lg_steps, dens, "o", ms=4, color=colour)
    ax.set_xlabel("lg band radiance of the wedge step (mW sr^-1 cm^-2)")
    ax.set_ylabel("density")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False, title="band")
    return png_base64(fig)
