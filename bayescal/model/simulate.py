"""Simulate calibration measurements of a camera with known truth.

The forward model is the measurement equation of docs/architecture.md, section 2, with
everything the real bench adds: the sphere's common scale error and per-level
errors shared across channels, read/shot/quantisation noise averaged over
frames and pixels, excess scatter, partial and full clipping at full scale
(each pixel clips separately; the region mean of partially clipped pixels is
computed in closed form), and integer quantisation of single readings.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy.special import ndtr
from scipy.stats import norm

from bayescal.errors import SpecError
from bayescal.io.design import Design, Truth
from bayescal.io.table import MeasurementTable
from bayescal.model.data import effective_stimulus
from bayescal.model.spec import ModelSpec

__all__ = ["simulate", "Simulation"]


@dataclass(frozen=True)
class Simulation:
    """A simulated table and the realised truth (sphere errors drawn for this dataset)."""

    table: MeasurementTable
    truth: Truth
    sphere_scale: float
    level_errors: dict[str, float]

    def true_coefficients(self, channel: str, relative: bool = False) -> np.ndarray:
        """True ``[A1..Ap]`` of a channel; ``relative`` gives them against the sphere's scale.

        The sphere reads ``L_nominal = L_true / s``, so relative to it
        ``A_rel[k] = A[k] * s^k``.
        """
        coef = np.asarray(self.truth.response[channel])
        if not relative:
            return coef
        return coef * self.sphere_scale ** np.arange(1, coef.size + 1)

    def reading(
        self,
        spec: ModelSpec,
        channel: str,
        stimulus,
        exposure_s: float,
        gain: float = 1.0,
        tdi_stages: float = 1.0,
        *,
        n_avg: float = 1.0,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Fresh readings of the true camera at true ``stimulus`` (new frames after the calibration).

        ``n_avg == 1``: one pixel, with read/shot noise, the excess scatter,
        the pixel's PRNU and integer quantisation.  ``n_avg > 1``: a region
        mean (PRNU averaged away, not quantised).  Clipped to ``[0, full scale]``.
        """
        stim = np.asarray(stimulus, dtype=float)
        t, g, m = (np.full(stim.shape, v, dtype=float) for v in (exposure_s, gain, tdi_stages))
        mu, signal, var_t = _camera(self.truth, spec, np.full(stim.shape, channel, dtype=object), stim, t, g, m)
        var = var_t / n_avg + self.truth.excess_dn**2
        if n_avg == 1:
            var = var + (self.truth.prnu * signal) ** 2
        out = mu + np.sqrt(var) * rng.standard_normal(stim.shape)
        if n_avg == 1:
            out = np.round(out)
        return np.clip(out, 0.0, spec.full_scale)


def simulate(spec: ModelSpec, design: Design, truth: Truth | None = None, seed: int = 0) -> Simulation:
    """Simulate a measurement table.

    Parameters
    ----------
    spec : ModelSpec
        Bit depth, stimulus kind and reference setting.
    design : Design
        What is measured.
    truth : Truth, optional
        The camera; defaults to ``design.truth``.
    seed : int
        Seed of every random draw (sphere errors, noise).
    """
    truth = truth or design.truth
    if truth is None:
        raise SpecError("simulate needs a truth: pass one or give the design a [truth] table")
    missing = [c for c in design.channels if c not in truth.response]
    if missing:
        raise SpecError(f"truth has no response for channel(s) {missing}")
    rng = np.random.default_rng(seed)
    scale = truth.sphere_scale
    if scale is None:
        scale = float(np.exp(truth.common_rel * rng.standard_normal()))
    level_err = truth.level_rel * rng.standard_normal(len(design.levels))
    rows = _rows(design)
    fs = spec.full_scale
    ch = rows["channel"].to_numpy()
    lvl = rows["level_index"].to_numpy()
    nominal = np.where(lvl >= 0, np.asarray(design.levels)[np.maximum(lvl, 0)], 0.0)
    true_stim = nominal * scale * (1.0 + np.where(lvl >= 0, level_err[np.maximum(lvl, 0)], 0.0))
    t, g, m, temp = (rows[k].to_numpy() for k in ("exposure_s", "gain", "tdi_stages", "temperature_c"))
    mu, signal, var_t = _camera(truth, spec, ch, true_stim, t, g, m, temp)
    n_avg = design.n_frames * design.n_pixels
    if n_avg == 1:
        reading = mu + np.sqrt(var_t + truth.excess_dn**2) * rng.standard_normal(mu.size)
        dn_mean = np.clip(np.round(reading), 0, fs)
    else:
        spread = np.sqrt(var_t + (truth.prnu * signal) ** 2)
        a = (fs - mu) / spread
        mean_clipped = mu + spread * (a * ndtr(-a) - norm.pdf(a))
        unclipped = ndtr(a)
        sd = np.sqrt(var_t * unclipped / n_avg + truth.excess_dn**2 * unclipped)
        dn_mean = np.clip(mean_clipped + sd * rng.standard_normal(mu.size), 0, fs)
    dof = max(design.n_frames - 1, 1) * design.n_pixels
    dn_var = var_t * rng.chisquare(dof, mu.size) / dof
    df = pd.DataFrame(
        {
            "channel": ch,
            spec.stimulus: nominal,
            "exposure_s": t,
            "gain": g,
            "tdi_stages": m,
            "level": np.where(lvl >= 0, [f"L{i + 1:02d}" for i in np.maximum(lvl, 0)], ""),
            **({"temperature_c": temp} if np.any(np.isfinite(temp)) else {}),
            "n_frames": design.n_frames,
            "n_pixels": design.n_pixels,
            "dn_mean": np.round(dn_mean, 3),
            "dn_var": np.round(np.maximum(dn_var, 1 / 12), 4),
        }
    )
    table = MeasurementTable.from_frame(df, source=f"simulate(seed={seed})")
    errors = {f"L{i + 1:02d}": float(e) for i, e in enumerate(level_err)}
    return Simulation(table=table, truth=truth, sphere_scale=scale, level_errors=errors)


def _camera(truth: Truth, spec: ModelSpec, ch, stimulus, t, g, m, temperature=None):
    """Expected DN, signal and per-pixel temporal variance of the true camera (docs/architecture.md, section 2)."""
    x = effective_stimulus(stimulus, t, g, m, spec)
    signal = np.array([np.polyval(np.r_[truth.response[c][::-1], 0.0], xi) for c, xi in zip(ch, x, strict=True)])
    g_rel = g / spec.reference.gain
    doubling = np.ones_like(t, dtype=float)
    if truth.dark_doubling_c is not None and temperature is not None:
        temp = np.where(np.isfinite(temperature), temperature, truth.temperature_ref_c)
        doubling = np.exp2((temp - truth.temperature_ref_c) / truth.dark_doubling_c)
    offset = _dark(truth, g, t * doubling, g_rel, spec) + np.array([truth.channel_offset.get(c, 0.0) for c in ch]) * (
        g_rel if truth.dark_proportional else 1.0
    )
    var_t = (truth.read_noise_dn * g_rel) ** 2 + truth.conversion_gain * g_rel * np.maximum(signal, 0) + 1 / 12
    return offset + signal, signal, var_t


def _rows(design: Design) -> pd.DataFrame:
    records = []
    for block in design.illuminated:
        levels = block.levels if block.levels is not None else range(len(design.levels))
        for temp in block.temperature_c or (np.nan,):
            for (t, g, m), i, c in _product(block.settings(), levels, design.channels):
                records.append((c, i, t, g, m, temp))
    for block in design.dark:
        for temp in block.temperature_c or (np.nan,):
            for (t, g, m), c in ((s, c) for s in block.settings() for c in design.channels):
                records.append((c, -1, t, g, m, temp))
    cols = ["channel", "level_index", "exposure_s", "gain", "tdi_stages", "temperature_c"]
    return pd.DataFrame(records, columns=cols)


def _product(settings, levels, channels):
    for s in settings:
        for i in levels:
            for c in channels:
                yield s, i, c


def _dark(truth: Truth, g: np.ndarray, t: np.ndarray, g_rel: np.ndarray, spec: ModelSpec) -> np.ndarray:
    if truth.dark_proportional:
        ref = spec.reference.gain
        off = truth.dark_offset.get(ref, next(iter(truth.dark_offset.values())))
        slope = truth.dark_slope.get(ref, 0.0)
        return (off + slope * t) * g_rel
    try:
        off = np.array([truth.dark_offset[gi] for gi in g])
    except KeyError as exc:
        raise SpecError(f"truth.dark_offset has no entry for gain {exc.args[0]:g}") from None
    slope = np.array([truth.dark_slope.get(gi, 0.0) for gi in g])
    return off + slope * t
