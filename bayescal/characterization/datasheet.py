"""The EMVA 1288 datasheet as one HTML page: the standard's plots with the posterior's bands drawn on them.

The standard (EMVA 1288 release 4.0, section 8 and its datasheet template) shows the photon transfer
curve, the sensitivity curve, the SNR curve, the linearity deviation and the dark signal against
exposure, each with the straight line of its point estimate.  Here each curve also carries the 95 %
band of its posterior (:func:`bayescal.characterization.emva1288.characterize`: the quartic photon
transfer and sensitivity curves whose small-signal slopes are K and R, the linearity's straight line,
the dark level's line in time, the SNR of the fitted K, QE and dark noise), so a reader sees where the
data leave the straight line and by how much more than the posterior allows.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from bayescal.characterization.emva1288 import QUANT, Characterization
from bayescal.characterization.pattern import pattern_images, pattern_sd_draws, profile, spectrogram
from bayescal.io.outputs import write_text_atomic
from bayescal.report.figures import png_base64, save_figure, subplots
from bayescal.report.page import escape, image, page, table

__all__ = ["write_datasheet", "write_datasheet_pdf", "write_curves", "snr_band"]

#: the posterior draws drawn into each band (a subset of the characterisation's 4000)
BAND_DRAWS = 1000
BAND = "#1f77b4"
STANDARD = "#d62728"


def _poly(powers, coef: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``sum_k b_k x^k`` for each draw's coefficients: ``(draws, len(x))``."""
    return sum(coef[:, [i]] * x[None, :] ** p for i, p in enumerate(powers))


def _band(ax, x: np.ndarray, values: np.ndarray, label: str) -> None:
    lo, mid, hi = np.quantile(values, [0.025, 0.5, 0.975], axis=0)
    ax.fill_between(x, lo, hi, color=BAND, alpha=0.25, lw=0, label=f"{label}: 95 % band")
    ax.plot(x, mid, color=BAND, lw=1.2, label=f"{label}: posterior median")


def _draws(res: Characterization, name: str) -> tuple[tuple[int, ...], np.ndarray] | None:
    found = res.curve_draws.get(name)
    if found is None:
        return None
    powers, coef = found
    return tuple(powers), np.asarray(coef)[:BAND_DRAWS]


def _figure(draw, res: Characterization) -> str:
    """One of the datasheet's plots (``draw(ax, res)``) as an embedded PNG."""
    fig, ax = subplots(figsize=(6.4, 4.2))
    draw(ax, res)
    return png_base64(fig)


def _fitted_curve(ax, res: Characterization, xs, ys, name: str, slope: float, label: str, axes: tuple) -> None:
    """A curve of the steps, its fit range (the standard's, up to 70 % of saturation), the posterior's band of
    the fitted polynomial ``name`` and the standard's straight line of ``slope`` through the origin."""
    r = res.ranges
    s = slice(r["index_sensitivity_min"], r["index_sensitivity_max"] + 1)
    ax.plot(xs, ys, "o", ms=3, color="0.55", label="steps")
    ax.plot(xs[s], ys[s], "o", ms=4, color="k", label="fit range (<= 70 % sat.)")
    x = np.linspace(0.0, float(xs[s].max()), 80)
    found = _draws(res, name)
    if found is not None:
        _band(ax, x, _poly(*found, x), "posterior")
    if np.isfinite(slope):
        ax.plot(x, slope * x, "--", color=STANDARD, label=label)
    ax.set(xlabel=axes[0], ylabel=axes[1], title=axes[2])
    ax.legend(fontsize=9)


def _photon_transfer(ax, res: Characterization) -> None:
    c, k = res.curves, res.standard["K"]
    axes = ("mean signal mu_y - mu_dark (DN)", "variance s2_y - s2_dark (DN^2)", "photon transfer")
    _fitted_curve(ax, res, c["signal"], c["var_signal"], "photon_transfer", k, f"standard: K = {k:.4g} DN/e-", axes)


def _sensitivity(ax, res: Characterization) -> None:
    c, resp = res.curves, res.standard["R"]
    axes = ("photons per pixel", "mean signal mu_y - mu_dark (DN)", "sensitivity")
    _fitted_curve(ax, res, c["photons"], c["signal"], "sensitivity", resp, f"standard: R = {resp:.4g} DN/photon", axes)


def snr_band(res: Characterization, photons: np.ndarray) -> np.ndarray:
    """The posterior's SNR at ``photons`` per pixel, per draw ``(draws, len(photons))``: the standard's
    model ``eta mu_p / sqrt(sigma_d^2 + sigma_q^2 / K^2 + eta mu_p)`` with ``eta`` = QE, ``sigma_d`` the
    dark noise in electrons and ``sigma_q^2 = 1/12 DN^2`` (EMVA 1288 release 4.0, eq. 15)."""
    qe = np.asarray(res.draws["QE"])[:BAND_DRAWS, None] / 100.0
    k = np.asarray(res.draws["K"])[:BAND_DRAWS, None]
    sigma_d = np.asarray(res.draws["sigma_d"])[:BAND_DRAWS, None]
    signal = qe * photons[None, :]
    return signal / np.sqrt(sigma_d**2 + QUANT / k**2 + signal)


def _snr(ax, res: Characterization) -> None:
    from matplotlib.ticker import LogLocator, NullFormatter

    c = res.curves
    saturation = float(res.standard.get("u_p_sat", np.inf))
    # lit and below saturation (a clipped step reads no noise: its SNR means nothing)
    lit = (c["photons"].to_numpy() > 0) & (c["photons"].to_numpy() <= saturation)
    photons = c["photons"].to_numpy()[lit]
    measured = c["signal"].to_numpy()[lit] / np.sqrt(np.maximum(c["s2_y"].to_numpy()[lit], 1e-12))
    ax.loglog(photons, measured, "o", ms=3, color="k", label="steps: (mu_y - mu_dark) / s_y")
    x = np.geomspace(photons.min(), photons.max(), 80)
    if all(name in res.draws for name in ("QE", "K", "sigma_d")):
        _band(ax, x, snr_band(res, x), "posterior")
    ax.loglog(x, np.sqrt(x), ":", color="0.4", label="ideal sensor (sqrt mu_p)")
    ax.set(xlabel="photons per pixel", ylabel="SNR", title="signal-to-noise ratio")
    for axis in (ax.xaxis, ax.yaxis):  # decades labelled, not every minor tick (their labels overlapped)
        axis.set_major_locator(LogLocator(base=10.0))
        axis.set_minor_formatter(NullFormatter())
    ax.legend(fontsize=9)


def _linearity(ax, res: Characterization) -> None:
    c, r = res.curves, res.ranges
    lo, hi = r["index_linearity_min"], r["index_linearity_max"] + 1
    x, y = c["photons"].to_numpy()[lo:hi], c["signal"].to_numpy()[lo:hi]
    a1, a0 = np.polyfit(x, y, 1, w=1.0 / y)
    line = a1 * x + a0
    found = _draws(res, "linearity")
    if found is not None:
        _band(ax, x, 100 * (_poly(*found, x) - line[None, :]) / line[None, :], "the line's posterior")
    ax.plot(x, 100 * (y - line) / line, "o-", ms=3, color="k", label="steps against the standard's line")
    ax.axhline(0, color=STANDARD, lw=0.8, ls="--", label="standard's line")
    ax.set(xlabel="photons per pixel", ylabel="deviation (%)", title="linearity (5-95 % of saturation)")
    ax.legend(fontsize=9)


def _dark(res: Characterization) -> str | None:
    found = _draws(res, "dark_mean")
    if found is None or res.dark is None:
        return None
    t, mean = res.dark["texp_s"].to_numpy(), res.dark["mean_dn"].to_numpy()
    fig, ax = subplots(figsize=(6.4, 4.2))
    ax.plot(t, mean, "o", ms=4, color="k", label="dark frames")
    x = np.linspace(0.0, float(t.max()), 60)
    _band(ax, x, _poly(*found, x), "posterior")
    slope, intercept = np.polyfit(t, mean, 1)
    ax.plot(x, intercept + slope * x, "--", color=STANDARD, label=f"least squares: {slope:.4g} DN/s")
    ax.set(xlabel="exposure time (s)", ylabel="mean dark level mu_dark (DN)", title="dark signal")
    ax.legend(fontsize=9)
    return png_base64(fig)


#: the pattern images' units and what each is
PATTERNS = {"DSNU": ("DN", "dark mean image - its mean"), "PRNU": ("%", "(bright - dark) mean image, % of its mean")}


def _pattern_figure(res: Characterization, rows: int, cols: int, size: tuple[float, float]):
    """The set's pattern images, their posterior sds and a figure for them; None without image stacks."""
    images, sds = pattern_images(res.stack), pattern_sd_draws(res.stack, res.draws)
    if images is None or sds is None:
        return None
    fig, axes = subplots(rows, cols, figsize=size)
    fig.set_layout_engine("constrained")
    return images, sds, fig, axes


def _histograms(res: Characterization) -> str | None:
    """Each pattern image's histogram (log counts: the tails are the defective pixels) with the 95 % band of
    the counts a Gaussian pattern of the posterior's DSNU and PRNU would give (EMVA 1288 release 4.0, 8.3)."""
    found = _pattern_figure(res, 1, 2, (10.0, 4.0))
    if found is None:
        return None
    images, sds, fig, axes = found
    for ax, (name, pattern) in zip(axes, images.items(), strict=True):
        values = pattern.ravel()
        sd = sds[name][:BAND_DRAWS]
        half = max(float(np.abs(values).max()), 4.0 * float(np.median(sd)))
        edges = np.linspace(-half, half, 81)
        counts, _ = np.histogram(values, edges)
        centres = 0.5 * (edges[1:] + edges[:-1])
        ax.stairs(np.maximum(counts, 0.5), edges, color="k", label=f"{values.size} pixels")
        width = edges[1] - edges[0]
        expected = values.size * width * np.exp(-0.5 * (centres[None, :] / sd[:, None]) ** 2)
        expected /= np.sqrt(2.0 * np.pi) * sd[:, None]
        _band(ax, centres, expected, "Gaussian pattern of the posterior")
        far = int(np.count_nonzero(np.abs(values) > 5.0 * float(np.median(sd))))
        unit, what = PATTERNS[name]
        ax.set(yscale="log", ylim=(0.5, None), xlabel=f"{what} ({unit})", ylabel="pixels per bin")
        ax.set_title(f"{name}: {far} pixel(s) beyond 5 sd", fontsize=10)
        ax.legend(fontsize=7, loc="upper left")
    return png_base64(fig)


def _directions(res: Characterization, draw) -> str | None:
    """A 2 x 2 figure of the pattern images: per image (DSNU, PRNU) a horizontal and a vertical panel, each
    drawn by ``draw(ax, name, pattern, sd_draws, unit, horizontal)``; None without image stacks."""
    found = _pattern_figure(res, 2, 2, (10.0, 7.0))
    if found is None:
        return None
    images, sds, fig, axes = found
    for row, (name, pattern) in zip(axes, images.items(), strict=True):
        unit, _ = PATTERNS[name]
        for ax, horizontal in zip(row, (True, False), strict=True):
            draw(ax, name, pattern, sds[name], unit, horizontal)
            ax.set_title(f"{name}, {'horizontal' if horizontal else 'vertical'}", fontsize=10)
            ax.legend(fontsize=8)
    return png_base64(fig)


def _spectrograms(res: Characterization) -> str | None:
    """Horizontal and vertical spectrograms of each pattern image beside the posterior's white level: a
    peak above the band is a periodic pattern (column or row fixed-pattern noise)."""

    def draw(ax, name, pattern, sd, unit, horizontal):
        freq, amplitude = spectrogram(pattern, 1 if horizontal else 0)  # along each row, or each column
        lo, hi = np.quantile(sd, [0.025, 0.975])
        ax.plot(freq, amplitude, color="k", lw=0.9, label="spectrogram")
        ax.axhspan(lo, hi, color=BAND, alpha=0.25, lw=0, label="white pattern of the posterior: 95 % band")
        ax.axhline(float(np.median(sd)), color=BAND, lw=1.2, label="its posterior median")
        ax.set(yscale="log", xlabel="frequency (cycles/pixel)", ylabel=f"amplitude ({unit})")

    return _directions(res, draw)


def _profiles(res: Characterization) -> str | None:
    """Horizontal and vertical profiles of each pattern image (the mean of each column and of each row)
    beside the band a Gaussian white pattern of the posterior's DSNU and PRNU would give (its standard
    deviation over the pixels averaged): shading and column or row patterns stand out of it."""

    def draw(ax, name, pattern, sd, unit, horizontal):
        axis, across = (0, "column") if horizontal else (1, "row")  # the mean of each column, or each row
        values = profile(pattern, axis)
        lo, hi = 1.96 * np.quantile(sd, [0.025, 0.975]) / np.sqrt(pattern.shape[axis])
        ax.axhspan(-hi, hi, color=BAND, alpha=0.15, lw=0, label="white pattern of the posterior: 95 % of a mean")
        ax.axhspan(-lo, lo, color=BAND, alpha=0.2, lw=0)
        ax.plot(np.arange(values.size), values, color="k", lw=0.9, label=f"mean of each {across}")
        ax.set(xlabel=f"{across} (pixel)", ylabel=f"{name} ({unit})")

    return _directions(res, draw)


def write_datasheet(res: Characterization, out: str | os.PathLike) -> Path:
    """Write the datasheet page ``out`` (HTML, figures embedded; written atomically)."""
    out = Path(out)
    quantities = res.table.copy()
    undetermined = (
        "not determinable (no system gain K)" if res.module == "General" else "not determined (one dark exposure time)"
    )
    verdict = {True: "compatible", False: "NOT compatible", None: undetermined}[res.dark_current_compatible]
    figures = _figures(res)
    body = [
        "<h1>EMVA 1288 datasheet</h1>",
        f"<p>{escape(res.source)}: the standard's point estimates beside the posterior median and its 95 % "
        "interval; on each plot the standard's straight line (dashed) and the posterior's 95 % band.</p>",
    ]
    if res.problems:
        items = "".join(f"<li>{escape(p)}</li>" for p in res.problems)
        body.append(f'<div class="failed">IMPLAUSIBLE RESULTS<ul>{items}</ul></div>')
    change = res.ptc.get("change", float("nan"))
    if res.module == "General":
        body.append(
            '<div class="failed">EMVA 1288 RELEASE 4 LINEAR DOES NOT APPLY: the photon transfer curve is not straight '
            f"over its fit range (its slope changes by {change:+.0%} from the lower to the upper half), so K, QE and "
            "what needs them are not determinable; the General module's quantities are reported.</div>"
        )
    else:
        body.append(
            f"<p>EMVA 1288 Release 4 Linear applies: the photon transfer curve is straight over its fit range (its "
            f"slope changes by {change:+.1%} from the lower to the upper half).</p>"
        )
    for note in res.notes:
        body.append(f"<p><b>Note:</b> {escape(note)}</p>")
    body += [
        "<h2>Operating point</h2>",
        table(_operating(res.operating)),
        "<h2>Quantities</h2>",
        table(_shown(quantities)),
        f"<p>Dark current from the mean and from the variance: <b>{escape(verdict)}</b> (95 % interval of "
        "their difference).</p>",
    ]
    for title, png in figures:
        body.append(f"<h2>{escape(title)}</h2>{image(png, title)}")
    write_text_atomic(out, page("EMVA 1288 datasheet", "\n".join(body)))
    return out


def _figures(res: Characterization) -> list[tuple[str, str]]:
    """Every plot of the datasheet the set allows, as ``(title, PNG in base64)``."""
    figures = [
        ("Photon transfer", _figure(_photon_transfer, res)),
        ("Sensitivity", _figure(_sensitivity, res)),
        ("Signal-to-noise ratio", _figure(_snr, res)),
        ("Linearity", _figure(_linearity, res)),
    ]
    for title, png in (
        ("Dark signal", _dark(res)),
        ("Non-uniformity histograms", _histograms(res)),
        ("Non-uniformity spectrograms", _spectrograms(res)),
        ("Non-uniformity profiles", _profiles(res)),
    ):
        if png is not None:
            figures.append((title, png))
    return figures


def _cover(res: Characterization, size: tuple[float, float]):
    """The printable datasheet's first page: the source, the module, the operating point, the quantities."""
    fig, ax = subplots(figsize=size)
    ax.axis("off")
    module = "Release 4 Linear" if res.module == "Linear" else "Release 4 General (K not determinable)"
    fig.text(0.06, 0.96, "EMVA 1288 datasheet", fontsize=16, weight="bold")
    fig.text(0.06, 0.94, f"{res.source}  |  {module}", fontsize=8)
    for frame, box in (
        (_operating(res.operating), (0.06, 0.70, 0.88, 0.22)),
        (_shown(res.table).drop(columns=["note"]), (0.06, 0.05, 0.88, 0.6)),
    ):
        sub = fig.add_axes(box)
        sub.axis("off")
        table = sub.table(cellText=frame.to_numpy().tolist(), colLabels=list(frame.columns), loc="upper left")
        table.auto_set_font_size(False)
        table.set_fontsize(7)
    return fig


def write_datasheet_pdf(res: Characterization, out: str | os.PathLike) -> Path:
    """The datasheet in a printable form (PDF, A4, written atomically): a first page with the source, the
    module that applies, the operating point and the quantities, then one page per plot."""
    import base64
    import io

    import matplotlib.image as mpimg
    from matplotlib.backends.backend_pdf import PdfPages

    from bayescal.io.outputs import atomic_path

    out = Path(out)
    a4 = (8.27, 11.69)
    with atomic_path(out) as tmp, PdfPages(tmp) as pdf:
        pdf.savefig(_cover(res, a4))
        for title, png in _figures(res):
            image = mpimg.imread(io.BytesIO(base64.b64decode(png)), format="png")
            fig, ax = subplots(figsize=a4)
            ax.imshow(image)
            ax.axis("off")
            ax.set_title(title)
            pdf.savefig(fig)
    return out


def write_curves(res: Characterization, out: str | os.PathLike) -> Path:
    """The photon transfer, sensitivity and linearity plots of the datasheet side by side, with the same
    posterior bands (PNG, written atomically): ``photon_transfer.png`` beside the datasheet."""
    out = Path(out)
    fig, axes = subplots(1, 3, figsize=(18, 4.6))
    for ax, draw in zip(axes, (_photon_transfer, _sensitivity, _linearity), strict=True):
        draw(ax, res)
    fig.tight_layout()
    save_figure(fig, out)
    return out


def _operating(op: dict) -> pd.DataFrame:
    """The operating point as the datasheet's first table (what the set does not record, said so)."""

    def span(v, unit: str, fmt: str = ".4g") -> str:
        return f"{v[0]:{fmt}} to {v[1]:{fmt}} {unit}" if v[0] != v[1] else f"{v[0]:{fmt}} {unit}"

    rows = [
        ("bit depth", f"{op.get('bits', '')}"),
        (
            "pixels per image",
            "not recorded (a reduced table: the dark variance's posterior assumes 640 x 480)"
            if op.get("pixels_per_image") is None
            else f"{op['pixels_per_image']}",
        ),
        ("exposure time", span(op["exposure_s"], "s") if "exposure_s" in op else ""),
        ("photons per pixel", span(op["photons_per_pixel"], "") if "photons_per_pixel" in op else ""),
        ("bright steps", f"{op.get('bright_steps', '')}"),
        ("dark exposures", ", ".join(f"{t:.4g} s" for t in op.get("dark_exposures_s", []))),
        ("images per stack", f"{op.get('stack_images', 0) or 'no stacks'}"),
        ("wavelength, pixel size, gain", "not recorded in the set's files"),
    ]
    if "image_shape" in op:
        rows.insert(2, ("image shape", " x ".join(str(n) for n in op["image_shape"])))
    return pd.DataFrame(rows, columns=["item", "value"])


def _shown(q: pd.DataFrame) -> pd.DataFrame:
    def fmt(v) -> str:
        return "" if not np.isfinite(v) else f"{v:.4g}"

    return pd.DataFrame(
        {
            "quantity": q["quantity"],
            "unit": q["unit"],
            "standard": q["standard"].map(fmt),
            "posterior median": q["median"].map(fmt),
            "95 % interval": [
                "" if not np.isfinite(a) else f"[{a:.4g}, {b:.4g}]" for a, b in zip(q["q2.5"], q["q97.5"], strict=True)
            ],
            "note": q["note"],
        }
    )
