"""Calibration report: one self-contained HTML file (figures embedded), plus JSON and Markdown.

Built from a fit directory (``posterior.nc``, ``summary.json``, ``lsq.csv``),
so a report can be made at any time from what a fit wrote.  Every number in
the tables is taken from ``summary.json`` (tested), the figures from the
posterior draws.  Contents (issue 6):

* verdict of the diagnostics, with a visible warning when the fit failed;
* coefficients in the papers' form ``DN = A0 + A1 L + ...`` at the reference
  setting with 95 % intervals, beside the least-squares table (coefficients,
  R^2, SSE, RMSE; seed 000 Table 1);
* response curves per channel with 95 % credible and predictive bands, the
  data (censored points marked) and the least-squares lines; residuals;
* an uncertainty budget of inverted radiance (sphere scale, calibration
  parameters, measurement noise) at a few DN levels;
* derived-setting and inversion examples;
* trace plots of the gains.
"""

from __future__ import annotations

import base64
import html
import os
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.inference import registry as backends
from bayescal.io.fit_folder import POSTERIOR, SUMMARY, FitFolder
from bayescal.io.outputs import atomic_path, write_json_atomic, write_text_atomic
from bayescal.io.summary import FitSummary
from bayescal.model import kinds
from bayescal.model.components import Saturation
from bayescal.model.setting import Setting
from bayescal.posterior.calibration import Calibration
from bayescal.prediction.invert import invert, radiance_draws
from bayescal.prediction.readings import predict
from bayescal.report.figures import colours as colour_cycle
from bayescal.report.figures import png_base64, subplots
from bayescal.report.page import image, page, table, verdict
from bayescal.report.text import fmt, markdown_table

__all__ = ["write_report", "uncertainty_budget"]

BUDGET_FRACTIONS = (0.05, 0.25, 0.5, 0.75)  # of full scale


def uncertainty_budget(cal: Calibration, fractions=BUDGET_FRACTIONS, seed: int = 0) -> pd.DataFrame:
    """Variance shares of inverted radiance at the reference setting (one pixel).

    Three nested inversions of the same DN: parameters only (coefficients
    relative to the sphere, no noise), plus the sphere's common scale
    (absolute coefficients), plus the reading's noise.  Their variance
    differences are the shares of calibration parameters, sphere and noise.
    """
    ref = Setting(cal.reference.exposure_s, cal.reference.gain, cal.reference.tdi_stages)
    z = np.random.default_rng(np.random.SeedSequence([seed, 0xB0D6])).standard_normal(cal.n_draws)
    rows = []
    for ch in cal.channels:
        dark = float(np.median(cal.dark_dn(ch, ref)))
        for frac in fractions:
            dn = np.array([dark + frac * (cal.full_scale - dark)])
            params = radiance_draws(cal, ch, dn, ref, relative=True)[0]
            sphere = radiance_draws(cal, ch, dn, ref)[0]
            full = radiance_draws(cal, ch, dn, ref, prnu=cal.prnu, z=z)[0]
            v_p, v_s, v_f = np.var(params), np.var(sphere), np.var(full)
            total = max(v_f, v_s, v_p)
            rows.append(
                {
                    "channel": ch,
                    "dn": float(dn[0]),
                    "radiance_median": float(np.median(full)),
                    "rel_sd_total": float(np.sqrt(total) / np.median(full)),
                    "share_parameters": float(v_p / total),
                    "share_sphere": float(max(v_s - v_p, 0.0) / total),
                    "share_noise": float(max(v_f - v_s, 0.0) / total),
                }
            )
    return pd.DataFrame(rows)


#: the report's figures, by name: with ``figures=True`` each is also written as ``<report>-<name>.png``
FIGURES = ("coefficients", "response", "residuals", "misfit", "budget", "trace", "rank")


def figure_paths(out: str | os.PathLike) -> list[Path]:
    """Where :func:`write_report` with ``figures=True`` writes each figure, beside the HTML ``out``."""
    out = Path(out)
    return [out.with_name(f"{out.stem}-{name}.png") for name in FIGURES]


def write_report(
    fit_dir: str | os.PathLike, out: str | os.PathLike | None = None, seed: int = 0, figures: bool = False
) -> Path:
    """Write ``report.html`` (self-contained), ``report.json`` and ``report.md``; returns the HTML path.

    ``out`` defaults to ``FIT_DIR/report.html``; JSON and Markdown go beside it, and with ``figures``
    each figure as a PNG (:func:`figure_paths`: ``report-response.png``, ...; the chains' trace and rank
    plots only for a backend with chains), for a lab's own documents.
    """
    from bayescal.io.outputs import writing_as

    with writing_as("report"):  # a report's files replace a report's, never another product added to a fit
        return _write_report(Path(fit_dir), out, seed, figures)


def _write_report(fit_dir: Path, out: str | os.PathLike | None, seed: int, figures: bool) -> Path:
    out = Path(out) if out is not None else fit_dir / "report.html"
    folder = FitFolder.at(fit_dir, "`bayescal report`", needs=(SUMMARY, POSTERIOR))
    summary = folder.summary  # checked: every key the report reads is there
    if summary.model_kind != kinds.CALIBRATION:  # another model kind reports itself (bayescal.model.kinds)
        return kinds.get(summary.model_kind).write_report(folder, out, seed)
    if figures:  # before any drawing: a file of the user's is never replaced
        from bayescal.io.outputs import check_output_file

        check_output_file(*figure_paths(out))
    cal = Calibration.load(folder)  # the posterior opened once: the figures below read the same tree
    tree = folder.posterior
    frame = folder.measurements.rename(columns={cal.stimulus: "stimulus"})
    lsq = pd.DataFrame(summary.lsq)
    coef = _coefficient_table(summary)
    lsq_ref = _lsq_at_reference(lsq, cal, summary)
    budget = uncertainty_budget(cal, seed=seed)
    examples = _examples(cal, seed)
    drawn = {
        "coefficients": _fig_coefficients(coef),
        "response": _fig_response(cal, frame, lsq),
        "residuals": _fig_residuals(cal, frame),
        "misfit": _fig_misfit(summary.diagnostics.get("misfit"), summary.diagnostics.get("holdout")),
        "budget": _fig_budget(budget),
    } | _fig_chains(tree, summary.backend)
    data = {
        "status": summary.status,
        "verdict": summary.diagnostics["verdict"],
        "backend": summary.backend,
        "seed": summary.seed,
        "model": summary.model,
        "stimulus_unit": summary.stimulus_unit,
        "diagnostics": summary.diagnostics,
        "coefficients": coef.to_dict("records"),
        "lsq_at_reference": lsq_ref.to_dict("records"),
        "uncertainty_budget": budget.to_dict("records"),
        "derived_settings": examples["predict"].to_dict("records"),
        "inversion": examples["invert"].to_dict("records"),
    }
    write_json_atomic(out.with_suffix(".json"), data)
    write_text_atomic(out.with_suffix(".md"), _markdown(data, coef, lsq_ref, budget, examples))
    write_text_atomic(out, _html(data, coef, lsq_ref, budget, examples, drawn))
    if figures:
        for name, path in zip(FIGURES, figure_paths(out), strict=True):
            if name in drawn:
                with atomic_path(path) as tmp:
                    tmp.write_bytes(base64.b64decode(drawn[name]))
    return out


# ----------------------------------------------------------------- tables
def _coefficient_table(summary: FitSummary) -> pd.DataFrame:
    params = {p["parameter"]: p for p in summary.parameters}
    rows = []
    for r in summary.comparison_at_reference:
        name = f"A_abs[{r['channel']}, {r['coefficient'][1:]}]"
        p = params.get(name, {})
        rel = params.get(f"A_rel[{r['channel']}, {r['coefficient'][1:]}]", {})
        rows.append(
            {
                "channel": r["channel"],
                "coefficient": r["coefficient"],
                "mean": p.get("mean"),
                "q2.5": p.get("q2.5"),
                "q97.5": p.get("q97.5"),
                "rel_mean": rel.get("mean"),
                "rel_q2.5": rel.get("q2.5"),
                "rel_q97.5": rel.get("q97.5"),
                "lsq": r.get("lsq"),
                "lsq_lo": r.get("lsq_lo"),
                "lsq_hi": r.get("lsq_hi"),
            }
        )
    return pd.DataFrame(rows)


def _lsq_at_reference(lsq: pd.DataFrame, cal: Calibration, summary: FitSummary) -> pd.DataFrame:
    if lsq.empty:
        return lsq
    ref = cal.reference
    at = lsq[np.isclose(lsq["exposure_s"], ref.exposure_s) & np.isclose(lsq["gain"], ref.gain)]
    keep = ["channel", "order", "n"] + [c for c in lsq.columns if c.startswith("A") and not c.endswith("_se")]
    return at[keep + ["r2", "sse", "rmse"]].reset_index(drop=True)


def _examples(cal: Calibration, seed: int) -> dict[str, pd.DataFrame]:
    ref = Setting(cal.reference.exposure_s, cal.reference.gain, cal.reference.tdi_stages)
    longer = Setting(cal.reference.exposure_s * 2.5, cal.reference.gain, cal.reference.tdi_stages)
    preds = []
    for ch in cal.channels:  # a scene that reads about 40 % of full scale at the longer exposure, per channel
        dark = float(np.median(cal.dark_dn(ch, ref)))
        target = dark + 0.4 * (cal.full_scale - dark) / 2.5
        stim = float(np.nanmedian(invert(cal, np.array([target]), ch, ref, seed=seed).to_frame()["median"]))
        preds.append(predict(cal, [stim if np.isfinite(stim) and stim > 0 else 1.0], longer, [ch], seed=seed))
    pred = pd.concat(preds, ignore_index=True)
    rows = []
    for ch in cal.channels:
        dark = float(np.median(cal.dark_dn(ch, ref)))
        dns = np.round([dark + 0.1 * (cal.full_scale - dark), dark + 0.5 * (cal.full_scale - dark), cal.full_scale])
        rows.append(invert(cal, dns, ch, ref, seed=seed).to_frame())
    return {"predict": pred, "invert": pd.concat(rows, ignore_index=True)}


# ---------------------------------------------------------------- figures
def _png(fig) -> str:
    return png_base64(fig)


def _settings(frame: pd.DataFrame) -> list[tuple[float, float, float]]:
    lit = frame[frame["stimulus"] > 0]
    tdi = lit["tdi_stages"] if "tdi_stages" in lit else pd.Series(1.0, index=lit.index)
    return sorted(set(zip(lit["exposure_s"], lit["gain"], tdi, strict=True)))


def _fig_response(cal: Calibration, frame: pd.DataFrame, lsq: pd.DataFrame) -> str:
    """Response curves per channel (top) and, below them, everything relative to the posterior median:
    the 95 % credible and predictive bands, the readings and least squares, in DN, where the bands a
    full-scale plot cannot show are visible.  Nothing is drawn past full scale."""
    chans = list(cal.channels)
    fig, axes = subplots(2, len(chans), figsize=(4.6 * len(chans), 7.0), squeeze=False, height_ratios=(3, 2))
    rng = np.random.default_rng(0)
    n_avg = float(np.median(frame.get("n_frames", 1) * frame.get("n_pixels", 1)))
    colours = colour_cycle()
    full = cal.full_scale
    for ax, rel, ch in zip(axes[0], axes[1], chans, strict=True):
        for k, (t, g, m) in enumerate(_settings(frame)):
            col = colours[k % len(colours)]
            rows = frame[(frame.channel == ch) & np.isclose(frame.exposure_s, t) & np.isclose(frame.gain, g)]
            rows = rows[rows["stimulus"] > 0]
            if rows.empty:
                continue
            s = Setting(t, g, m)
            grid = np.linspace(0, rows["stimulus"].max() * 1.05, 60)
            mean = cal.clipped_dn(ch, grid, s, relative=True)
            pred = cal.sample_dn(ch, grid, s, rng, n_avg=n_avg, relative=True)
            lo, hi = np.quantile(mean, [0.025, 0.975], axis=0)
            plo, phi = np.quantile(pred, [0.025, 0.975], axis=0)
            med = np.median(mean, axis=0)
            below = med < full  # relative panel: only where the curve is below full scale
            ax.fill_between(grid, plo, phi, color=col, alpha=0.12, lw=0)
            ax.fill_between(grid, lo, hi, color=col, alpha=0.35, lw=0)
            ax.plot(grid, med, color=col, lw=1.2, label=f"{t:g} s, gain {g:g}")
            # relative to the median the credible band is a fill and the predictive one its two edges, dotted:
            # two fills of one colour could not be told apart where the settings overlap
            for edge in (plo - med, phi - med):
                rel.plot(grid[below], edge[below], ls=":", color=col, lw=1.1)
            rel.fill_between(grid[below], (lo - med)[below], (hi - med)[below], color=col, alpha=0.4, lw=0)
            cens = rows["dn_mean"] >= cal.saturation_dn
            ax.plot(rows["stimulus"][~cens], rows["dn_mean"][~cens], "o", color=col, ms=3.5)
            ax.plot(rows["stimulus"][cens], rows["dn_mean"][cens], "x", color="k", ms=6, mew=1.5)
            at = np.interp(rows["stimulus"][~cens], grid, med)
            rel.plot(rows["stimulus"][~cens], rows["dn_mean"][~cens] - at, "o", color=col, ms=3)
            fitrow = lsq[(lsq.channel == ch) & np.isclose(lsq.exposure_s, t) & np.isclose(lsq.gain, g)]
            if len(fitrow):
                r = fitrow[fitrow.order == fitrow.order.max()].iloc[0]
                a = [r[f"A{i}"] for i in range(int(r.order) + 1)]
                line = np.polyval(a[::-1], grid)
                keep = line <= full  # a least-squares polynomial knows no full scale: drawn only below it
                ax.plot(grid[keep], line[keep], ls=(0, (4, 2)), color="0.15", lw=1.1, alpha=0.85)
                rel.plot(grid[keep & below], (line - med)[keep & below], ls=(0, (4, 2)), color=col, lw=1.2)
        ax.axhline(full, color="0.5", lw=0.6)
        ax.set_ylim(0, full * 1.06)
        ax.set(title=f"channel {ch}", xlabel=f"{cal.stimulus} ({cal.unit})", ylabel="mean DN")
        rel.axhline(0.0, color="0.5", lw=0.6)
        rel.set(xlabel=f"{cal.stimulus} ({cal.unit})", ylabel="DN minus the posterior median")
    handles, labels = axes[0][0].get_legend_handles_labels()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles += [
        Patch(color="0.3", alpha=0.4, lw=0),
        Patch(color="0.3", alpha=0.12, lw=0),
        Line2D([], [], ls=":", color="0.3", lw=1.1),
        Line2D([], [], ls=(0, (4, 2)), color="0.15", lw=1.1),
        Line2D([], [], ls="", marker="x", color="k", mew=1.5),
    ]
    labels += [
        "95 % credible band (the curve)",
        "95 % predictive band (a reading), top",
        "95 % predictive band, bottom",
        "least squares (below full scale)",
        "clipped reading (censored)",
    ]
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 4), fontsize=10, frameon=False)
    fig.suptitle(
        f"top: posterior median and bands, readings and least squares, up to full scale ({full:g} DN)\n"
        "bottom: the same relative to the posterior median, in DN (readings of one sphere level share its "
        "reading's error, which the bands at a nominal radiance leave out)",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.12, 1, 0.93))
    return _png(fig)


def _fig_residuals(cal: Calibration, frame: pd.DataFrame) -> str:
    """Residuals in predictive sds (a band of +-2 is what the model allows), one colour per setting.

    Each row is predicted as the fit saw it: at its sphere level's reading times that level's fitted
    error (per draw), so the residuals are the ones the misfit checks judge."""
    hidden = 0
    chans = list(cal.channels)
    fig, axes = subplots(1, len(chans), figsize=(4.6 * len(chans), 3.4), squeeze=False, sharey=True)
    rng = np.random.default_rng(1)
    colours = colour_cycle()
    settings = _settings(frame)
    for ax, ch in zip(axes[0], chans, strict=True):
        ax.axhspan(-2, 2, color="0.85", lw=0)
        ax.axhline(0, color="0.5", lw=0.6)
        for k, (t, g, m) in enumerate(settings):
            rows = frame[
                (frame.channel == ch)
                & np.isclose(frame.exposure_s, t)
                & np.isclose(frame.gain, g)
                & (frame["stimulus"] > 0)
                & (frame.dn_mean < cal.saturation_dn)
            ]
            if rows.empty:
                continue
            s = Setting(t, g, m)
            n_avg = (rows.get("n_frames", 1) * rows.get("n_pixels", 1)).to_numpy(dtype=float)
            stim = rows["stimulus"].to_numpy()
            delivered = cal.delivered(stim, rows["level"] if "level" in rows else [""] * len(rows))
            pred = cal.sample_dn(ch, delivered, s, rng, n_avg=float(np.median(n_avg)), relative=True, per_draw=True)
            sd = np.std(pred, axis=0)
            resid = rows["dn_mean"].to_numpy() - np.median(pred, axis=0)
            z = np.divide(resid, sd, out=np.full_like(resid, np.nan), where=sd > 0)
            # a row every draw predicts at full scale has no spread to scale by: it is clipped, left out as such
            near = _partly_clipped(cal, ch, delivered, s, sd) | ~(sd > 0)
            hidden += int(near.sum())
            label = f"{t:g} s, gain {g:g}" + (f", TDI {m:g}" if m != 1 else "")
            ax.plot(stim[~near], z[~near], "o", ms=3.5, color=colours[k % len(colours)], label=label)
        ax.set(title=f"channel {ch}", xlabel=f"{cal.stimulus} ({cal.unit})")
    if hidden:
        fig.suptitle(
            f"{hidden} row(s) within reach of full scale left out: their partial clipping is bracketed by the fit's "
            "likelihood, not predicted by a single reading",
            fontsize=10,
        )
    axes[0][0].set_ylabel("(data - model) / predictive sd")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 6), fontsize=10, frameon=False)
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    return _png(fig)


def _partly_clipped(cal: Calibration, channel: str, stimulus, setting, sd) -> np.ndarray:
    """Rows whose pixels would partly clip: the clipping loss at the fit's widest pixel spread
    (``prnu_bound``) exceeds half the predictive sd (``stimulus`` per draw)."""
    expected = cal.reading(channel, stimulus, setting, relative=True, per_draw=True)
    mean, signal = np.median(expected.mean, axis=0), np.maximum(np.median(expected.signal, axis=0), 0.0)
    loss = Saturation.loss(mean, cal.pixel_var(signal, setting), cal.prnu_bound, signal, cal.full_scale)
    return loss > 0.5 * sd


def _fig_coefficients(coef: pd.DataFrame) -> str:
    """Each coefficient at the reference setting, a panel per channel (row) and coefficient (column), each on
    its own scale: the posterior's 95 % interval against the sphere's scale (comparable with least squares)
    and with that scale's doubt included, beside the least-squares estimate and its 95 % confidence
    interval."""
    names = list(dict.fromkeys(coef["coefficient"]))
    channels = list(dict.fromkeys(coef["channel"]))
    fig, axes = subplots(
        len(channels), len(names), figsize=(3.2 * len(names), 1.05 * len(channels) + 1.0), squeeze=False
    )
    marks = (
        ("rel_mean", "rel_q2.5", "rel_q97.5", "C0", "Bayes, against the sphere's scale"),
        ("mean", "q2.5", "q97.5", "C2", "Bayes, absolute (the sphere scale's doubt in)"),
        ("lsq", "lsq_lo", "lsq_hi", "k", "least squares"),
    )
    for row, channel in zip(axes, channels, strict=True):
        for ax, name in zip(row, names, strict=True):
            at = coef[(coef["channel"] == channel) & (coef["coefficient"] == name)].iloc[0]
            for k, (mid, lo, hi, colour, label) in enumerate(marks):
                m, low, high = (float(at[c]) if at[c] is not None else np.nan for c in (mid, lo, hi))
                ax.errorbar(
                    [m], [-k], xerr=[[m - low], [high - m]], fmt="o", ms=4, color=colour, capsize=2, label=label
                )
            ax.set(yticks=[], ylim=(-2.6, 0.6))
            ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4))
            ax.tick_params(axis="x", labelsize=8)
            if channel == channels[0]:
                ax.set_title(name)
            if name == names[0]:
                ax.set_ylabel(f"channel {channel}")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    return _png(fig)


def _fig_misfit(misfit: dict | None, holdout: dict | None = None) -> str:
    """The misfit checks (:mod:`bayescal.fitting.misfit`): residual sums per group of rows, each setting's rows
    left out and predicted by the rest (:mod:`bayescal.fitting.holdout`), and the excess scatter."""
    fig, (ax, hx, bx) = subplots(1, 3, figsize=(13, 3.6), gridspec_kw={"width_ratios": [4, 2, 1]})
    limits = (misfit or {}).get("thresholds", {"excess_ratio": 10.0, "group_z": 4.0})
    zmax, rmax = limits["group_z"], limits["excess_ratio"]
    groups = pd.DataFrame((misfit or {}).get("groups", []))
    if len(groups):
        short = {"exposure_s": "exposure", "tdi_stages": "TDI"}
        labels = [f"{short.get(r.column, r.column)} {r.value}" for r in groups.itertuples()]
        colors = ["C3" if abs(z) > zmax else "C0" for z in groups["z"]]
        ax.bar(range(len(groups)), groups["z"], color=colors)
        ax.set_xticks(range(len(groups)), labels, rotation=60, ha="right", fontsize=7)
        for level in (-zmax, zmax):
            ax.axhline(level, color="C3", lw=0.8, ls="--")
        ax.set(ylabel="sum of residuals / sqrt(n)  (sd)", title=f"residuals by group of rows (|z| > {zmax:g}: flagged)")
    held = pd.DataFrame((holdout or {}).get("groups", []))
    if len(held):
        held = held[np.isfinite(pd.to_numeric(held["z"], errors="coerce").to_numpy(dtype=float))]
        names = [
            g.replace("the illuminated ", "").replace("the dark rows at ", "dark ").replace(" rows", "")
            for g in held["group"]
        ]
        hx.bar(range(len(held)), held["z"], color=["C3" if abs(z) > zmax else "C0" for z in held["z"]])
        hx.set_xticks(range(len(held)), names, rotation=60, ha="right", fontsize=7)
        for level in (-zmax, zmax):
            hx.axhline(level, color="C3", lw=0.8, ls="--")
        hx.set(ylabel="(reading - predicted) / sd", title="left out, predicted by the rest")
    else:
        hx.set_axis_off()
    ratio = (misfit or {}).get("excess_ratio")
    if ratio is not None:
        bx.bar([0], [ratio], color="C3" if ratio > rmax else "C0")
        bx.axhline(rmax, color="C3", lw=0.8, ls="--")
        bx.set_xticks([0], ["excess / floor"])
        bx.set(title="excess scatter", ylabel="x noise floor")
    else:
        bx.set_axis_off()
    fig.tight_layout()
    return _png(fig)


def _fig_budget(budget: pd.DataFrame) -> str:
    fig, ax = subplots(figsize=(7.5, 3.2))
    labels = [f"{r.channel} {r.dn:.0f} DN" for r in budget.itertuples()]
    left = np.zeros(len(budget))
    for name, col in (("share_parameters", "C0"), ("share_sphere", "C1"), ("share_noise", "C2")):
        ax.barh(labels, budget[name], left=left, color=col, label=name.removeprefix("share_"))
        left += budget[name].to_numpy()
    ax.set(xlabel="share of inverted-radiance variance", xlim=(0, 1))
    ax.invert_yaxis()
    ax.legend(fontsize=10, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)  # beside the bars
    return _png(fig)


def _fig_chains(tree, backend: str) -> dict[str, str]:
    """arviz's trace-and-density and rank plots of the sphere-relative gains, for a backend with chains
    (for the others they say nothing)."""
    if not backends.chained(backend):
        return {}
    import arviz_plots as azp
    from matplotlib import pyplot as plt

    out = {}
    # a panel per channel (compact=False), the chains in colour: overlaid on one axis the channels' gains
    # (18-62 on the example) leave each chain's mixing too thin to see
    trace = lambda t, **kw: azp.plot_trace_dist(t, compact=False, **kw)  # noqa: E731
    for key, plot in (("trace", trace), ("rank", azp.plot_rank)):
        pc = plot(tree, var_names=["gain_rel"], backend="matplotlib")
        try:  # the colours are the chains (a panel per channel): say so
            pc.add_legend("chain", title="chain")
        except (ValueError, KeyError, TypeError, AttributeError):  # a plot with no colour per chain keeps none
            pass
        fig = pc.viz["figure"].item()
        out[key] = png_base64(fig)
        plt.close(fig)  # arviz draws through pyplot: leave a user's figure registry as it was
    return out


# ----------------------------------------------------------------- output
def _markdown(data, coef, lsq_ref, budget, examples) -> str:
    d = data["diagnostics"]
    parts = [
        f"# Calibration report: {data['model']['name']}",
        "",
        f"**Status: {data['status']}** ({data['verdict']}); backend {data['backend']}, seed {data['seed']}; "
        f"divergences {d.get('divergences')}, max R-hat {fmt(d.get('max_rhat'))}, "
        f"min bulk ESS {fmt(d.get('min_ess_bulk'))}.",
        "",
        f"## Coefficients at the reference setting (DN = A0 + A1 L + ..., L in {data['stimulus_unit']})",
        "",
        markdown_table(coef),
        "",
        "## Least squares at the reference setting",
        "",
        markdown_table(lsq_ref),
        "",
        "## Uncertainty budget of inverted radiance (one pixel, reference setting)",
        "",
        markdown_table(budget),
        "",
        "## Derived setting (2.5 x reference exposure)",
        "",
        markdown_table(examples["predict"].drop(columns=["why"])),
        "",
        "## Inversion examples",
        "",
        markdown_table(examples["invert"]),
        "",
    ]
    return "\n".join(parts)


def _chains_section(figures: dict) -> str:
    if "trace" not in figures:
        return "<h2>Chains</h2><p>Laplace draws are independent draws from a Gaussian: no chains to compare.</p>"
    return (
        "<h2>Chains</h2><p>Sphere-relative gains: traces and densities per chain, and the rank plot "
        "(each chain's ranks should be uniform; arviz).</p>"
        + image(figures["trace"], "trace plots")
        + image(figures["rank"], "rank plots")
    )


def _diagnostics_row(backend: str, d: dict) -> dict:
    """The diagnostics that apply to the backend used (no divergences for a Laplace fit)."""
    misfit = d.get("misfit") or {}
    row: dict = {k: d.get(k) for k in backends.reports(backend)}
    if d.get("retried"):
        row["retried"] = d["retried"]
    row["largest |residual| (pred. sd)"] = d.get("max_abs_residual_z")
    if "excess_ratio" in misfit:
        row["excess scatter / noise floor"] = misfit["excess_ratio"]
    return row


def _html(data, coef, lsq_ref, budget, examples, figures) -> str:
    d = data["diagnostics"]
    banner = verdict(
        data["status"] == "ok",
        d.get("problems", []),
        "Diagnostics passed: the chains converged and the model fits its data to within their noise.",
    )
    img = lambda key, alt: image(figures[key], alt)  # noqa: E731
    diag = pd.DataFrame([_diagnostics_row(data["backend"], d)])
    body = f"""<h1>Calibration report: {html.escape(data["model"]["name"])}</h1>
<p>Backend <b>{data["backend"]}</b>, seed {data["seed"]}. The model:</p>
<ul class="components">{"".join(f"<li>{html.escape(c)}</li>" for c in data["model"]["components"])}</ul>
{banner}
<h2>Diagnostics</h2>
{table(diag)}
<h2>Coefficients at the reference setting</h2>
<p>DN = A0 + A1 L + ... with L in {html.escape(data["stimulus_unit"])}: posterior mean and 95 % interval
(absolute: the sphere's common scale uncertainty included; rel: against the sphere's own scale, comparable with
least squares), beside the least-squares estimate and its 95 % confidence interval.</p>
{table(coef)}
{img("coefficients", "coefficients: Bayes beside least squares")}
<h2>Least squares at the reference setting (seed 000 Table 1 form)</h2>
{table(lsq_ref)}
<h2>Response curves</h2>
{img("response", "response curves")}
<h2>Residuals</h2>
{img("residuals", "residuals")}
<h2>Does the model fit its data?</h2>
<p>Standardised residuals summed over each group of rows (gain step, exposure, TDI, channel, sphere level),
and the fitted excess scatter over the noise floor of a row mean. A group beyond 4 sd or an excess over 10
floors fails the fit: the model would otherwise absorb the misfit into its noise.</p>
{img("misfit", "misfit checks")}
<h2>Uncertainty budget of inverted radiance</h2>
<p>Share of the variance of radiance inverted from one pixel's reading at the reference setting.</p>
{img("budget", "uncertainty budget")}
{table(budget)}
<h2>Derived setting: 2.5 x the reference exposure</h2>
{table(examples["predict"].drop(columns=["why"]))}
<h2>Inversion examples (reference setting, one pixel)</h2>
{table(examples["invert"])}
{_chains_section(figures)}"""
    return page(data["model"]["name"], body)
