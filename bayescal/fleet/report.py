"""The fleet report: shrinkage, the population, drift per camera with the band ahead.

One self-contained HTML page (figures embedded) beside the fleet directory's tables.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.fleet.posterior import FleetFit
from bayescal.io.outputs import write_text_atomic
from bayescal.report.figures import colours, png_base64, subplots
from bayescal.report.page import escape, image, page, table, verdict

__all__ = ["write_fleet_report"]

#: cameras drawn in the drift figure
DRIFT_CAMERAS = 6
#: years ahead of the last campaign in the drift figure
AHEAD_YEARS = 2.0


def write_fleet_report(fleet: FleetFit, out: str | os.PathLike) -> Path:
    """Write the fleet report to ``out`` (HTML) and return its path."""
    figures = [
        ("Shrinkage: each camera's gain at its last campaign, fitted alone and with the fleet", _fig_shrinkage(fleet)),
        ("The population: a camera of the type never measured, beside the fleet's cameras", _fig_population(fleet)),
    ]
    if fleet.plan.drift:
        figures.append(("Drift: gain per camera over campaigns, with the predicted band ahead", _fig_drift(fleet)))
    d = fleet.draws.diagnostics
    status = "ok" if fleet.ok else "FAILED: " + "; ".join(fleet.problems)
    parts = [
        f"<h1>Fleet: {escape(fleet.spec.name)}</h1>",
        verdict(fleet.ok, fleet.problems, f"Status: {status}"),
        f"<p>{len(fleet.cameras)} cameras, {len(fleet.units)} units (camera x campaign), channels "
        f"{', '.join(fleet.channels)}; pooling <b>{fleet.plan.pooling}</b>; "
        f"drift {'on' if fleet.plan.drift else 'off'}. "
        f"Hierarchy by NUTS on its scales (every other quantity integrated out and drawn exactly): "
        f"{d['divergences']} divergences, R-hat {d['max_rhat']:.4f}, bulk ESS {d['min_ess_bulk']:.0f}, "
        f"tail ESS {d['min_ess_tail']:.0f}.</p>",
    ]
    if fleet.warnings:
        parts.append("<ul>" + "".join(f"<li>{escape(w)}</li>" for w in fleet.warnings) + "</ul>")
    for title, png in figures:
        parts.append(f"<h2>{escape(title)}</h2>{image(png, title)}")
    if fleet.plan.drift:
        parts += _drift_trust(fleet)
    parts.append("<h2>Population (hyperparameters)</h2>")
    parts.append(table(fleet.hyperparameters()))
    parts.append("<h2>Per unit: fleet beside alone</h2>")
    parts.append(table(_unit_table(fleet)))
    out = Path(out)
    write_text_atomic(out, page(f"fleet {fleet.spec.name}", "\n".join(parts)))
    return out


def _drift_trust(fleet: FleetFit) -> list[str]:
    """How well each camera's gain trend is known, absolute and against the fleet's common trend, and
    what the campaigns cannot tell apart (:meth:`FleetFit.drift_caveat`)."""
    rows = []
    for camera in fleet.cameras:
        absolute, relative = fleet.trend_sd(camera)
        rows.append(
            {
                "camera": camera,
                "trend sd, absolute (%/year)": 100 * absolute,
                "trend sd, against the fleet (%/year)": 100 * relative,
            }
        )
    caveats = [c for c in (fleet.drift_caveat(camera) for camera in fleet.cameras) if c]
    out = ["<h2>How well the drift is known</h2>", table(pd.DataFrame(rows))]
    if caveats:
        out.append(
            f"<p>For {len(caveats)} of {len(fleet.cameras)} cameras {escape(caveats[0].split(':')[0])}: "
            "their absolute drift probabilities carry the common trend's uncertainty (on independent fleets "
            "they overstate the risk); <code>fleet-query --drift-percent</code> also gives the probability "
            "against the fleet's common trend, which the campaigns measure.</p>"
        )
    return out


def _unit_table(fleet: FleetFit) -> pd.DataFrame:
    """Per unit: the gain with the fleet and alone on the same footing (against the campaign's sphere
    reading), the absolute gain (the sphere's scale folded in), and the offsets, every column labelled."""
    s = fleet.summary()
    names = {
        "camera": "camera",
        "campaign": "campaign",
        "channel": "channel",
        "gain_vs_sphere": "gain vs sphere, with the fleet",
        "gain_vs_sphere_lo": "2.5 %",
        "gain_vs_sphere_hi": "97.5 %",
        "gain_alone": "gain vs sphere, alone",
        "gain_alone_sd": "sd",
        "gain": "gain, absolute (sphere's scale folded in)",
        "gain_lo": "2.5 % ",
        "gain_hi": "97.5 % ",
        "offset": "offset DN, with the fleet",
        "offset_alone": "offset DN, alone",
        "offset_alone_sd": "sd ",
    }
    return s[[c for c in names if c in s]].rename(columns=names)


def _last_units(fleet: FleetFit) -> list[int]:
    return [int(np.flatnonzero(fleet.data.camera == m)[-1]) for m in range(len(fleet.cameras))]


def _fig_shrinkage(fleet: FleetFit) -> str:
    k = fleet.kinds.index("log_gain")
    obs = fleet._flat("theta_observed")  # (S, K, U, C), relative to each campaign's sphere reading
    n_ch = len(fleet.channels)
    fig, axes = subplots(1, n_ch, figsize=(4.2 * n_ch, 3.6), squeeze=False)
    last = _last_units(fleet)
    x = np.arange(len(last))
    for c, ax in enumerate(axes[0]):
        q = n_ch * k + c
        alone = np.exp(fleet.unit_mean[last, k, c])
        alone_sd = alone * np.sqrt(fleet.unit_cov[last, q, q])
        v = np.exp(obs[:, k, last, c] * fleet.data.scale[k] + fleet.data.center[k, c])
        lo, med, hi = np.quantile(v, [0.025, 0.5, 0.975], axis=0)
        ax.errorbar(x - 0.15, alone, yerr=1.96 * alone_sd, fmt="o", ms=3, color="0.5", label="alone")
        ax.errorbar(x + 0.15, med, yerr=[med - lo, hi - med], fmt="s", ms=3, color=colours()[0], label="with the fleet")
        ax.set_title(f"channel {fleet.channels[c]}")
        ax.set_xticks(x, [fleet.cameras[i] for i in range(len(last))], rotation=90, fontsize=7)
        ax.set_ylabel("gain A1 (DN per unit stimulus, sphere reading)")
    axes[0][0].legend(fontsize=8, loc="best")
    fig.tight_layout()
    return png_base64(fig)


def _fig_population(fleet: FleetFit) -> str:
    k = fleet.kinds.index("log_gain")
    n_ch = len(fleet.channels)
    fig, axes = subplots(1, n_ch, figsize=(4.2 * n_ch, 3.2), squeeze=False)
    last_date = None
    if fleet.origin is not None:
        last_date = fleet.origin + pd.Timedelta(days=float(fleet.data.years.max()) * 365.25)
    new = np.exp(fleet.at(None, last_date, seed=fleet.seed)[:, k, :]) if fleet.plan.pooling != "none" else None
    for c, ax in enumerate(axes[0]):
        if new is not None:
            ax.hist(new[:, c], bins=60, density=True, color=colours()[1], alpha=0.6, label="new camera (predictive)")
        for name in fleet.cameras:
            v = np.exp(fleet.at(name, last_date, seed=fleet.seed)[:, k, c])
            ax.axvline(np.median(v), color="0.3", lw=0.7)
        ax.set_title(f"channel {fleet.channels[c]}: absolute gain")
        ax.set_xlabel("gain A1")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    return png_base64(fig)


def _fig_drift(fleet: FleetFit) -> str:
    k = fleet.kinds.index("log_gain")
    c = len(fleet.channels) // 2
    cams = fleet.cameras[:DRIFT_CAMERAS]
    fig, axes = subplots(1, len(cams), figsize=(2.6 * len(cams), 3.0), squeeze=False, sharey=True)
    for ax, name in zip(axes[0], cams, strict=False):
        m = fleet.camera_index(name)
        units = np.flatnonzero(fleet.data.camera == m)
        years = fleet.data.years[units]
        ref = np.exp(fleet.unit_values()[:, units[0], k, c])
        base = np.median(ref)
        grid = np.linspace(years[0], years[-1] + AHEAD_YEARS, 25)
        quantiles = []
        for t in grid:
            date = fleet.origin + pd.Timedelta(days=float(t) * 365.25)
            v = np.exp(fleet.at(name, date, seed=fleet.seed)[:, k, c]) / base - 1.0
            quantiles.append(np.quantile(v, [0.025, 0.5, 0.975]))
        band = 100 * np.asarray(quantiles)
        ax.fill_between(grid, band[:, 0], band[:, 2], color=colours()[0], alpha=0.25, lw=0)
        ax.plot(grid, band[:, 1], color=colours()[0], lw=1)
        vals = np.exp(fleet.unit_values()[:, units, k, c]) / base - 1.0
        lo, med, hi = 100 * np.quantile(vals, [0.025, 0.5, 0.975], axis=0)
        ax.errorbar(years, med, yerr=[med - lo, hi - med], fmt="o", ms=3, color="k")
        ax.axvline(years[-1], color="0.6", ls=":", lw=0.8)
        ax.set_title(f"{name} ({fleet.channels[c]})", fontsize=9)
        ax.set_xlabel("years since the first campaign")
    axes[0][0].set_ylabel("gain change since its first campaign (%)")
    fig.tight_layout()
    return png_base64(fig)
