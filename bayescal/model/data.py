"""From a validated table and a spec to the scaled arrays a model consumes.

Everything the model sees is dimensionless and O(1): DN is divided by full
scale, the effective stimulus ``x = L t M g / (t_ref M_ref g_ref)`` (the
radiance that would give the same signal at the reference setting; seeds 000
section 5.3 and 002 eq. 11) by its largest value, exposure by its largest
value (docs/architecture.md, section 5).  Only shapes enter the compiled model, so
datasets of one shape share one compilation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from bayescal.errors import TableError
from bayescal.io.checks import require_spread
from bayescal.io.table import MeasurementTable
from bayescal.model.components.noise import QUANTISATION_DN2
from bayescal.model.spec import ModelSpec

__all__ = ["ModelData", "Layout", "prepare", "effective_stimulus", "check_levels_per_channel"]


class ModelData(NamedTuple):
    """Scaled per-row arrays, float64 NumPy (a JAX pytree: passed to the compiled model as an argument,
    so every dataset of one shape shares one compilation)."""

    y: np.ndarray  # dn_mean / full scale
    u: np.ndarray  # effective stimulus / x_scale (0 for dark rows)
    t: np.ndarray  # exposure / t_scale
    g_rel: np.ndarray  # gain / reference gain
    channel: np.ndarray  # int channel index
    gset: np.ndarray  # int gain-setting index
    fset: np.ndarray  # int index of the gain among the illuminated gains (setting factors)
    eset: np.ndarray  # int exposure-setting index
    mset: np.ndarray  # int TDI-setting index
    level: np.ndarray  # int level index; dark rows -> n_levels
    level_sigma: np.ndarray  # (n_levels,) relative sd of each level's reading
    var_meas: np.ndarray  # measured per-pixel variance / full scale^2 (1 if absent)
    n_avg: np.ndarray  # n_frames * n_pixels
    censored: np.ndarray  # bool, right-censored at the threshold
    threshold: np.ndarray  # scalar, censoring threshold / full scale
    temp: np.ndarray  # temperature - dark.temperature_ref_c (degC; 0 without a temperature model)
    time: np.ndarray  # time_s / the run's duration (0 without a drift model): 0 at the start of the run
    keep: np.ndarray  # bool, the row's reading enters the likelihood (False: held out, predicted only)
    charge: np.ndarray  # scalar: 1 where the nonlinearity is the charge's (before the gain), 0 the output's
    extra: dict = {}  # per-row inputs of the optional effects (Effect.inputs), by name


@dataclass(frozen=True)
class Layout:
    """Static structure and scales of a prepared dataset."""

    channels: tuple[str, ...]
    gain_values: tuple[float, ...]
    exposure_values: tuple[float, ...]  # measured with illumination
    tdi_values: tuple[float, ...]  # measured with illumination
    lit_gain_values: tuple[float, ...]  # measured with illumination
    levels: tuple[str, ...]
    x_scale: float
    t_scale: float
    dn_scale: float
    n_rows: int
    unit: str

    @property
    def shape_key(self) -> tuple[int, ...]:
        """The sizes that determine the compiled model's shapes."""
        return (
            self.n_rows,
            len(self.channels),
            len(self.gain_values),
            len(self.lit_gain_values),
            len(self.exposure_values),
            len(self.tdi_values),
            len(self.levels),
        )

    def setting_values(self, kind: str) -> tuple[float, ...]:
        """Values of a setting kind (``gain``, ``exposure``, ``tdi``) measured with illumination, sorted."""
        return {"gain": self.lit_gain_values, "exposure": self.exposure_values, "tdi": self.tdi_values}[kind]


def effective_stimulus(
    stimulus: np.ndarray, exposure_s: np.ndarray, gain: np.ndarray, tdi: np.ndarray, spec: ModelSpec
) -> np.ndarray:
    """Stimulus scaled to the reference setting: ``L t M g / (t_ref M_ref g_ref)``."""
    ref = spec.reference
    return stimulus * (exposure_s * tdi * gain) / (ref.exposure_s * ref.tdi_stages * ref.gain)


def prepare(table: MeasurementTable, spec: ModelSpec) -> tuple[ModelData, Layout]:
    """Check the table against the spec and build the scaled model inputs.

    Raises
    ------
    TableError
        If a channel has too few distinct unsaturated levels for the response
        order, if every illuminated point of a channel is saturated, if the
        reference gain was never measured (per-setting dark), or if the noise
        model needs a column the table lacks.
    """
    df = table.frame
    if table.stimulus != spec.stimulus:
        raise TableError(
            f"the model '{spec.name}' expects a '{spec.stimulus}' column but the table has '{table.stimulus}'",
            column=table.stimulus,
        )
    dn_scale = spec.full_scale
    over = np.flatnonzero(df["dn_mean"].to_numpy() > dn_scale + 0.5)
    if over.size:
        raise TableError(
            f"dn_mean {df['dn_mean'].iloc[over[0]]:g} exceeds full scale {dn_scale:g} of a {spec.bits}-bit ADC; "
            "check the model's bit depth",
            row=int(over[0]) + 1,
            column="dn_mean",
        )
    dark = table.is_dark
    x = effective_stimulus(
        df["stimulus"].to_numpy(), df["exposure_s"].to_numpy(), df["gain"].to_numpy(), df["tdi_stages"].to_numpy(), spec
    )
    if not np.any(~dark):
        raise TableError("the table has only dark rows; expected illuminated rows too", column=table.stimulus)
    y = df["dn_mean"].to_numpy() / dn_scale
    threshold = (dn_scale - spec.saturation.margin_dn) / dn_scale
    saturated = y >= threshold
    censored = saturated & spec.saturation.censor
    check_levels_per_channel(df, dark, saturated, x, spec)

    channels = tuple(table.channels)
    ch_index = {c: i for i, c in enumerate(channels)}
    gains = tuple(sorted(set(df["gain"])))
    g_index = {g: i for i, g in enumerate(gains)}
    if spec.dark.gain_dependence == "per_setting" and spec.reference.gain not in g_index:
        raise TableError(
            f"the reference gain {spec.reference.gain:g} was never measured (gains {list(gains)}); "
            "per-setting offsets need it, or use dark.gain_dependence = 'proportional'",
            column="gain",
        )
    lit = df.loc[~dark, ["level", "stimulus"]].drop_duplicates("level").sort_values("stimulus")
    levels = tuple(lit["level"])
    l_index = {lv: i for i, lv in enumerate(levels)}
    level_idx = np.array([l_index.get(lv, len(levels)) for lv in df["level"]])
    level_sigma = np.full(len(levels), spec.sphere.per_level_rel)
    if "radiance_u_rel" in df:
        per = df.loc[~dark].groupby("level")["radiance_u_rel"].max()
        level_sigma = np.array([per[lv] for lv in levels])
    if spec.noise.kind == "measured" and "dn_var" not in df:
        raise TableError(
            "noise.kind = 'measured' needs a 'dn_var' column (per-pixel temporal variance, DN^2)", column="dn_var"
        )
    var_meas = _measured_variance(df, saturated, dn_scale) if "dn_var" in df else np.ones(len(df))
    temp = np.zeros(len(df))
    if spec.dark.temperature:
        temp = (
            _needed(df, "temperature_c", "dark.temperature", "sensor temperature, degC") - spec.dark.temperature_ref_c
        )

    # setting factors act on the stimulus: only settings seen with illumination get one (dark rows -> index 0)
    exposures = tuple(sorted(set(df.loc[~dark, "exposure_s"])))
    e_index = {t: i for i, t in enumerate(exposures)}
    stages = tuple(sorted(set(df.loc[~dark, "tdi_stages"])))
    m_index = {m: i for i, m in enumerate(stages)}
    lit_gains = tuple(sorted(set(df.loc[~dark, "gain"])))
    f_index = {g: i for i, g in enumerate(lit_gains)}
    time = np.zeros(len(df))
    if spec.dark.drift == "order":  # the rows as listed are the order of measurement
        time = np.arange(len(df), dtype=float) / max(len(df) - 1, 1)
    elif spec.dark.drift:
        t = _needed(df, "time_s", "dark.drift", "seconds since the start of the run, per row")
        time = (t - t.min()) / max(float(np.ptp(t)), 1e-12)
    x_scale = float(np.max(x))
    t_scale = float(df["exposure_s"].max())
    data = ModelData(
        y=np.asarray(y),
        u=np.asarray(x / x_scale),
        t=np.asarray(df["exposure_s"].to_numpy() / t_scale),
        g_rel=np.asarray(df["gain"].to_numpy() / spec.reference.gain),
        channel=np.asarray([ch_index[c] for c in df["channel"]], dtype=np.int32),
        gset=np.asarray([g_index[g] for g in df["gain"]], dtype=np.int32),
        fset=np.asarray([f_index.get(g, 0) for g in df["gain"]], dtype=np.int32),
        eset=np.asarray([e_index.get(t, 0) for t in df["exposure_s"]], dtype=np.int32),
        mset=np.asarray([m_index.get(m, 0) for m in df["tdi_stages"]], dtype=np.int32),
        level=np.asarray(level_idx, dtype=np.int32),
        level_sigma=np.asarray(level_sigma, dtype=float),
        var_meas=np.asarray(var_meas),
        n_avg=np.asarray((df["n_frames"] * df["n_pixels"]).to_numpy(), dtype=float),
        censored=np.asarray(censored, dtype=bool),
        threshold=np.asarray(threshold, dtype=float),
        temp=np.asarray(temp, dtype=float),
        time=np.asarray(time, dtype=float),
        keep=np.ones(len(df), dtype=bool),
        charge=np.asarray(1.0 if spec.response.nonlinearity_domain == "charge" else 0.0),
    )
    layout = Layout(
        channels=channels,
        gain_values=gains,
        exposure_values=exposures,
        tdi_values=stages,
        lit_gain_values=lit_gains,
        levels=levels,
        x_scale=x_scale,
        t_scale=t_scale,
        dn_scale=dn_scale,
        n_rows=len(df),
        unit=table.unit,
    )
    return data, layout


def _measured_variance(df, clipped: np.ndarray, dn_scale: float) -> np.ndarray:
    """The measured per-pixel temporal variance in scaled units.  A region held at full scale (or at 0)
    truly measures a variance of 0: its reading is censored, and its variance is taken as the
    quantisation's, the least a reading can carry.  Anywhere else a variance of 0 is not a measurement."""
    var = df["dn_var"].to_numpy(dtype=float)
    at_zero = df["dn_mean"].to_numpy() <= 0
    bad = np.flatnonzero((var <= 0) & ~clipped & ~at_zero)
    if bad.size:
        i = int(bad[0])
        raise TableError(
            f"a temporal variance of 0 in a region that is not clipped (dn_mean {df['dn_mean'].iloc[i]:g}, below "
            f"full scale {dn_scale:g}); only a region held at full scale or at 0 measures no temporal noise: "
            "expected the per-pixel temporal variance (DN^2, > 0)",
            row=i + 1,
            column="dn_var",
        )
    return np.where(var > 0, var, QUANTISATION_DN2) / dn_scale**2


def _needed(df, column: str, option: str, meaning: str) -> np.ndarray:
    """The values of a column that a spec option needs; a clear error when the table lacks it, or when
    it holds one value only (nothing in the table could inform the option: it would be fitted from its
    prior without a word)."""
    if column not in df:
        raise TableError(f"{option} = true needs a '{column}' column ({meaning})", column=column)
    values = df[column].to_numpy(dtype=float)
    require_spread(values, option, column)
    return values


def check_levels_per_channel(df, dark: np.ndarray, saturated: np.ndarray, x: np.ndarray, spec: ModelSpec) -> None:
    need = spec.response.order + 1
    for channel in dict.fromkeys(df["channel"]):
        mine = (df["channel"].to_numpy() == channel) & ~dark
        if mine.any() and np.all(saturated[mine]):
            row = int(np.flatnonzero(mine)[0]) + 1
            raise TableError(
                f"every illuminated point of channel '{channel}' is saturated (>= full scale); "
                "nothing constrains its gain",
                row=row,
                column="dn_mean",
            )
        readings = df["dn_mean"].to_numpy()[mine & ~saturated]
        if readings.size > 1 and np.ptp(readings) == 0:
            raise TableError(
                f"every unsaturated illuminated reading of channel '{channel}' is {readings[0]:g} DN: "
                "the channel does not respond to the stimulus (check the file or the camera)",
                row=int(np.flatnonzero(mine)[0]) + 1,
                column="dn_mean",
            )
        distinct = np.unique(np.round(x[mine & ~saturated], 12)).size
        if distinct < need:
            raise TableError(
                f"channel '{channel}' has {distinct} distinct unsaturated stimulus levels; a response of order "
                f"{spec.response.order} needs at least {need}",
                column=spec.stimulus,
            )
