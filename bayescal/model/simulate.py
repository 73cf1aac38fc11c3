"""Simulate calibration measurements of a camera with known truth.

The forward model is the measurement equation of docs/architecture.md, section 2, composed by
its one skeleton (:func:`bayescal.model.equation.reading`) from the components' own forward
functions (the response's polynomial, the dark level, the noise, the sphere's and the effects'
factors and offsets, the ADC's clipping), with everything the real bench adds: the
sphere's common scale error and per-level errors shared across channels, read/shot/quantisation
noise averaged over frames and pixels, excess scatter, partial and full clipping at full scale
(each pixel clips separately; the region mean of partially clipped pixels is computed in closed
form), and integer quantisation of single readings.

Data from this simulator share the model's assumptions by construction: they test that the
inference recovers what the model says (simulation-based calibration), not that the model fits
real cameras; :mod:`bayescal.validation` holds the simulators written apart from the model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from bayescal.errors import SpecError
from bayescal.io.design import Design, Truth
from bayescal.io.table import MeasurementTable
from bayescal.model import observation
from bayescal.model.components import Dark, FactorEffect, Noise, NoiseEffect, OffsetEffect, Response, Sphere, effect
from bayescal.model.components.noise import QUANTISATION_DN2
from bayescal.model.data import effective_stimulus
from bayescal.model.equation import reading
from bayescal.model.spec import ModelSpec

__all__ = ["simulate", "Simulation"]


@dataclass(frozen=True)
class Simulation:
    """A simulated table and the realised truth (sphere errors drawn for this dataset).

    Examples
    --------
    >>> import bayescal as bc
    >>> sim = bc.simulate(bc.load_spec("seed000"), bc.load_design("seed000"), seed=1)
    >>> len(sim.table.frame), round(sim.sphere_scale, 4)  # the rows, and this campaign's drawn sphere error
    (192, 1.0104)
    """

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
        temperature_c: float | None = None,
        n_avg: float = 1.0,
        rng: np.random.Generator,
    ) -> np.ndarray:
        """Fresh readings of the true camera at true ``stimulus`` (new frames after the calibration).

        ``n_avg == 1``: one pixel, with read/shot noise, the excess scatter,
        the pixel's PRNU and integer quantisation.  ``n_avg > 1``: a region
        mean (PRNU averaged away, not quantised).  Clipped to ``[0, full scale]``.
        """
        stim = np.asarray(stimulus, dtype=float).ravel()
        rows = pd.DataFrame(
            {
                "channel": channel,
                "exposure_s": float(exposure_s),
                "gain": float(gain),
                "tdi_stages": float(tdi_stages),
                "temperature_c": np.nan if temperature_c is None else float(temperature_c),
            },
            index=range(stim.size),
        )
        expected, var_t, extra = _camera(self.truth, spec, rows, stim)
        single = n_avg == 1
        normals = rng.standard_normal(stim.size)
        prnu = self.truth.prnu if single else 0.0
        out = observation.draw(
            expected,
            var_t,
            normals,
            spec.full_scale,
            n_avg=n_avg,
            excess=self.truth.excess_dn,
            prnu=prnu,
            integer=single,
            extra=extra,
        )
        return out.reshape(np.shape(stimulus))


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

    Examples
    --------
    >>> import bayescal as bc
    >>> sim = bc.simulate(bc.load_spec("seed000"), bc.load_design("seed000"), seed=1)
    >>> len(sim.table), sorted(sim.table.frame["channel"].unique())
    (192, ['B', 'G', 'R'])
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
    true_stim = nominal * scale * Sphere.factor(np.where(lvl >= 0, level_err[np.maximum(lvl, 0)], 0.0))
    t, g, m, temp = (rows[k].to_numpy() for k in ("exposure_s", "gain", "tdi_stages", "temperature_c"))
    expected, var_t, extra = _camera(truth, spec, rows, true_stim)
    n_avg = design.n_frames * design.n_pixels
    single = n_avg == 1  # one pixel (the same one on every row: its PRNU is part of its response)
    normals = rng.standard_normal(len(rows))
    dn_mean = observation.draw(
        expected,
        var_t,
        normals,
        fs,
        n_avg=n_avg,
        excess=truth.excess_dn,
        integer=single,
        pixel_prnu=None if single else truth.prnu,  # a region mean: each pixel clips on its own
        extra=extra,
    )
    dof = max(design.n_frames - 1, 1) * design.n_pixels
    dn_var = var_t * rng.chisquare(dof, len(rows)) / dof
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
            "dn_var": np.round(np.maximum(dn_var, QUANTISATION_DN2), 4),
        }
    )
    conditions = ["channel", spec.stimulus, "exposure_s", "gain", "tdi_stages", "level"]
    repeat = (
        df.assign(temperature_c=temp)
        .fillna({"temperature_c": -999.0})
        .groupby([*conditions, "temperature_c"], sort=False)
        .cumcount()
    )
    if repeat.any():  # a design that measures a condition more than once: its repeats are numbered
        df["replicate"] = repeat.to_numpy(dtype=float)
    table = MeasurementTable.from_frame(df, source=f"simulate(seed={seed})")
    errors = {f"L{i + 1:02d}": float(e) for i, e in enumerate(level_err)}
    return Simulation(table=table, truth=truth, sphere_scale=scale, level_errors=errors)


def _camera(truth: Truth, spec: ModelSpec, rows: pd.DataFrame, stimulus: np.ndarray):
    """The expected reading (DN and signal), per-pixel temporal variance and the noise effects' variance
    (DN^2) of the true camera at every row (its
    channel, exposure, gain, TDI stages and temperature; docs/architecture.md, section 2)."""
    ch = rows["channel"].to_numpy()
    t, g, m = (rows[k].to_numpy(dtype=float) for k in ("exposure_s", "gain", "tdi_stages"))
    factor, added = _effects(truth, rows.assign(stimulus=stimulus), spec)
    order = max(len(v) for v in truth.response.values())
    coef = np.zeros((len(rows), order))
    for c, values in truth.response.items():
        coef[ch == c, : len(values)] = values
    g_rel = g / spec.reference.gain
    coef = Response(spec.response, len(truth.response)).coefficients_at(coef, g_rel)
    warm = 1.0
    if truth.dark_doubling_c is not None and "temperature_c" in rows:
        temp = rows["temperature_c"].to_numpy(dtype=float)
        warm = Dark.doubling(np.where(np.isfinite(temp), temp - truth.temperature_ref_c, 0.0), truth.dark_doubling_c)
    offset, slope = _dark(truth, g, spec)
    offset = offset + np.array([truth.channel_offset.get(c, 0.0) for c in ch])
    slope = slope + np.array([truth.channel_dark_slope.get(c, 0.0) for c in ch])
    dark = Dark.level(offset, slope, t, g_rel if truth.dark_proportional else 1.0, warm)
    u = effective_stimulus(stimulus, t, g, m, spec)
    expected = reading(u, (factor,), lambda x: Response.forward(coef, x), (dark, added))
    var_t = Noise.pixel_variance(truth.read_noise_dn, truth.conversion_gain, g_rel, expected.signal)
    return expected, var_t, _noise(truth, rows.assign(signal_dn=expected.signal), spec)


def _noise(truth: Truth, rows: pd.DataFrame, spec: ModelSpec) -> np.ndarray:
    """The variance (DN^2) the noise effects named in the truth add to every row (``rows`` with its true
    signal, ``signal_dn``)."""
    extra = np.zeros(len(rows))
    for section, params in truth.effects.items():
        cls = effect(section)
        if issubclass(cls, NoiseEffect):
            extra = extra + cls.truth(params, rows, spec)
    return extra


def _effects(truth: Truth, rows: pd.DataFrame, spec: ModelSpec) -> tuple[np.ndarray, np.ndarray]:
    """The optional effects named in the truth (``[truth.effects.<section>]``) at every row: the factor
    on the effective stimulus and the DN added to the reading."""
    factor, added = np.ones(len(rows)), np.zeros(len(rows))
    for section, params in truth.effects.items():
        try:
            cls = effect(section)
        except KeyError:
            raise SpecError(f"[truth.effects] names '{section}', which is not a registered effect") from None
        if issubclass(cls, OffsetEffect):
            added = added + cls.truth(params, rows, spec)
        elif issubclass(cls, FactorEffect):
            factor = factor * cls.truth(params, rows, spec)
    return factor, added


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


def _dark(truth: Truth, g: np.ndarray, spec: ModelSpec) -> tuple[np.ndarray, np.ndarray]:
    """The true dark offset and slope of every row (at the reference gain when proportional)."""
    if truth.dark_proportional:
        ref = spec.reference.gain
        off = truth.dark_offset.get(ref, next(iter(truth.dark_offset.values())))
        return np.full(g.shape, off), np.full(g.shape, truth.dark_slope.get(ref, 0.0))
    try:
        offsets = np.array([truth.dark_offset[gi] for gi in g])
    except KeyError as exc:
        raise SpecError(f"truth.dark_offset has no entry for gain {exc.args[0]:g}") from None
    return offsets, np.array([truth.dark_slope.get(gi, 0.0) for gi in g])
