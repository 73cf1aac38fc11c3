"""Offset and dark signal: per gain setting (or proportional to gain), linear in exposure (the slope
shared by the channels, or each channel's own for a sensor read through several outputs).

Physics: seed 000 section 5.1 (about 50 DN at gain step 1, over 450 DN at step 4; nearly flat
over 2.7-10 ms; channel colour barely matters), seed 002 section 4.1 (dark roughly linear in
integration time, doubling every ~7 degC) and eq. 12 (offset scales with the video gain)::

    dark = (offset + slope t 2^((T - T_ref) / T_d)) g_factor + drift * time

:meth:`Dark.level` is that equation; the model, predictions and the simulator all call it.  It is the
first of the equation's offset terms; a dark signal that grows faster than the exposure (amplifier
glow) is an offset effect of its own (:mod:`bayescal.model.components.glow`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from bayescal.errors import SpecError
from bayescal.model.components.base import Component
from bayescal.model.components.priors import guide_inputs, pooled_normal, scale_prior

__all__ = ["Dark", "DarkSpec", "DarkTerm"]

OFFSET_TAU_SD = 0.01


@dataclass(frozen=True)
class DarkSpec:
    """Offset/dark signal: per gain setting, linear in exposure (seed 000 section 5.1).

    ``gain_dependence = "proportional"`` makes the offset scale with the gain
    factor instead (seed 002 eq. 12, DN = g (... + 28.72)), which also
    predicts unmeasured gains.  ``pooled`` partially pools the channel
    offsets (seed 000: channel colour barely matters for dark); off by
    default, see :class:`~bayescal.model.components.response.ResponseSpec`.

    ``temperature``: the dark current (the exposure slope) doubles every
    ``T_d`` degC, ``slope(T) = slope(T_ref) 2^((T - T_ref) / T_d)`` (seed 002:
    about 7 degC), with ``T_d`` log-normal around ``doubling_c`` (relative sd
    ``doubling_rel_sd``); the table needs a ``temperature_c`` column.

    ``drift``: the dark level drifts linearly over the measurement run (the
    sensor warming up): ``offset + d * time``, one drift ``d`` (DN over the
    whole run, prior Normal(0, ``drift_prior_dn``)) shared by every channel and
    gain; needs a ``time_s`` column.  Offsets then refer to the start of the
    run.  Without it a drift is absorbed by the dark slope and the setting
    factors, and ``A0`` is silently biased (validation benchmark).  The
    default, ``"auto"``, fits the drift whenever the table has ``time_s``;
    ``"order"`` fits it over the rows' order in the table, for a table that
    lists its rows as they were measured but has no ``time_s``.

    Priors (fractions of full scale): each offset Normal(``offset_prior_mean``,
    ``offset_prior_sd``), each dark slope (per longest exposure of the table)
    Normal(0, ``slope_prior_sd``).

    Attributes
    ----------
    exposure_slope : bool
        The dark level grows linearly with the exposure (the dark current); off for a camera whose dark
        frames were taken at one exposure, or whose dark current is subtracted on the chip.
    temperature_ref_c : float
        The temperature (degC) the dark current's doubling refers to: ``slope(T_ref)`` is reported.
    slope_per_channel : bool
        Each channel its own dark slope (a sensor read through several outputs, each amplifier with its
        own DN per electron, so one dark current reads as different DN/s per channel); off: one slope per
        gain, shared by every channel.
    """

    gain_dependence: Literal["per_setting", "proportional"] = "per_setting"
    exposure_slope: bool = True
    pooled: bool = False
    temperature: bool = False
    temperature_ref_c: float = 20.0
    doubling_c: float = 7.0
    doubling_rel_sd: float = 0.4
    offset_prior_mean: float = 0.05
    offset_prior_sd: float = 0.25
    slope_prior_sd: float = 0.05
    drift: Literal[True, False, "auto", "order"] = "auto"
    drift_prior_dn: float = 5.0
    slope_per_channel: bool = False


@dataclass(frozen=True)
class Dark(Component):
    """Offset ``b0[channel, gain]`` plus ``b1[gain] * t`` (scaled units)."""

    section = "dark"
    role = "offset"
    sites = {
        "b0": ("channel", "gain_setting"),
        "b1": ("gain_setting",),
        "b1_c": ("channel", "gain_setting"),
        "b0_mu": ("gain_setting",),
        "b0_tau": (),
        "b0_w": ("channel", "gain_setting"),
        "b0_mu_w": ("gain_setting",),
        "T_d": (),
        "drift": (),
    }
    reported = {
        "dark_offset": ("channel", "gain_setting"),
        "dark_offset_ref": ("channel",),
        "dark_slope": ("gain_setting",),
        "dark_slope_ref": (),
        "dark_slope_channel": ("channel", "gain_setting"),
        "dark_slope_channel_ref": ("channel",),
        "doubling_c": (),
        "dark_drift_dn": (),
    }

    spec: DarkSpec
    n_channels: int
    n_gains: int
    dn_scale: float = 1.0  # full scale (DN): the drift prior is stated in DN

    @property
    def proportional(self) -> bool:
        """Offset proportional to the gain factor (seed 002 eq. 12)."""
        return self.spec.gain_dependence == "proportional"

    # ------------------------------------------------------------------ physics
    @staticmethod
    def level(offset, slope, exposure, gain_factor=1.0, temperature_factor=1.0, drift=0.0, time=0.0):
        """Dark level ``(offset + slope t f_T) g_factor + drift time`` (any units, any array namespace).

        ``gain_factor`` is ``g / g_ref`` for an offset proportional to gain (else 1);
        ``temperature_factor`` the dark current's :meth:`doubling` factor.
        """
        return (offset + slope * (exposure * temperature_factor)) * gain_factor + drift * time

    @staticmethod
    def doubling(delta_c, doubling_c, xp=np):
        """The dark current's factor ``2^((T - T_ref) / T_d)`` at ``delta_c = T - T_ref`` degC."""
        return xp.exp2(delta_c / doubling_c)

    # ----------------------------------------------------------------- sampling
    @property
    def pools_offsets(self) -> bool:
        """The channels' offsets are pooled."""
        return self.spec.pooled and self.n_channels > 1

    def guides(self) -> dict[str, np.ndarray]:
        """Neutral guide of the pooled offsets (``ModelData.extra``; see :func:`pooled_normal`)."""
        if not self.pools_offsets:
            return {}
        return guide_inputs("b0", (self.n_channels, 1 if self.proportional else self.n_gains))

    def sample(self, data):
        """Sample the offset parameters and return the per-row scaled dark level."""
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        c, g = self.n_channels, 1 if self.proportional else self.n_gains
        if self.pools_offsets:
            tau = numpyro.sample("b0_tau", scale_prior(OFFSET_TAU_SD))
            b0 = pooled_normal("b0", self.spec.offset_prior_mean, self.spec.offset_prior_sd, tau, data, (c, g))
        else:
            prior = dist.Normal(self.spec.offset_prior_mean, self.spec.offset_prior_sd)
            b0 = numpyro.sample("b0", prior.expand([c, g]).to_event(2))
        column = 0 if self.proportional else data.gset
        gain_factor = data.g_rel if self.proportional else 1.0
        slope, warm = 0.0, 1.0
        if self.spec.exposure_slope and self.spec.slope_per_channel:
            b1c = numpyro.sample("b1_c", dist.Normal(0.0, self.spec.slope_prior_sd).expand([c, g]).to_event(2))
            slope = b1c[data.channel, column]
        elif self.spec.exposure_slope:
            b1 = numpyro.sample("b1", dist.Normal(0.0, self.spec.slope_prior_sd).expand([g]).to_event(1))
            slope = b1[column]
        if self.spec.exposure_slope:
            if self.spec.temperature:  # dark current doubles every T_d degC (seed 002)
                t_d = numpyro.sample("T_d", dist.LogNormal(jnp.log(self.spec.doubling_c), self.spec.doubling_rel_sd))
                warm = self.doubling(data.temp, t_d, jnp)
        drift = 0.0
        if self.spec.drift:  # a linear drift over the run, common to every channel and gain
            drift = numpyro.sample("drift", dist.Normal(0.0, self.spec.drift_prior_dn / self.dn_scale))
        return self.level(b0[data.channel, column], slope, data.t, gain_factor, warm, drift, data.time)

    # ---------------------------------------------------------------- reporting
    def describe(self) -> str:
        return (
            f"dark: {self.spec.gain_dependence}"
            + (", exposure slope" if self.spec.exposure_slope else "")
            + (" per channel" if self.spec.exposure_slope and self.spec.slope_per_channel else "")
            + (", doubling with temperature" if self.spec.temperature else "")
            + (", drift over the run" if self.spec.drift else "")
            + (" (row order)" if self.spec.drift == "order" else "")
        )

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        """Dark offset in DN at zero exposure and its exposure slope in DN/s.

        Per (channel, gain setting) for per-setting offsets; at the reference
        gain (``*_ref``) for proportional ones.
        """
        layout = ctx.layout
        b0 = draws["b0"] * layout.dn_scale
        site = "b1_c" if self.spec.slope_per_channel else "b1"
        slope = draws[site] * layout.dn_scale / layout.t_scale if self.spec.exposure_slope else None
        name = "dark_slope_channel" if self.spec.slope_per_channel else "dark_slope"
        if self.proportional:
            out = {"dark_offset_ref": b0[..., 0]}
            if slope is not None:
                out[name + "_ref"] = slope[..., 0]
        else:
            out = {"dark_offset": b0}
            if slope is not None:
                out[name] = slope
        if "T_d" in draws:
            out["doubling_c"] = draws["T_d"]
        if "drift" in draws:
            out["dark_drift_dn"] = draws["drift"] * self.dn_scale
        return out

    @staticmethod
    def term(
        spec: Any, draws: Mapping[str, np.ndarray], channels: tuple[str, ...], gains: tuple[float, ...]
    ) -> DarkTerm:
        """The dark level in a calibration's predictions, from the reported draws ``(chain, draw, ...)``
        (``spec``: the model spec; ``gains``: the gain of each fitted dark column)."""

        def flat(name: str) -> np.ndarray | None:
            if name not in draws:
                return None
            a = np.asarray(draws[name], dtype=float)
            return a.reshape((-1,) + a.shape[2:])

        proportional = spec.dark.gain_dependence == "proportional"
        suffix = "_ref" if proportional else ""
        offset = flat("dark_offset" + suffix)
        assert offset is not None, "a calibration's draws hold the dark offsets"
        if proportional:
            offset, gains = offset[..., None], (spec.reference.gain,)
        # shared: (S, G), or (S,) proportional; per channel: (S, C, G), or (S, C) proportional
        slope = flat("dark_slope" + suffix)
        if slope is None:
            slope = flat("dark_slope_channel" + suffix)
        if slope is None:
            slope = np.zeros((offset.shape[0], offset.shape[-1]))
        elif proportional:
            slope = slope[..., None]  # the one dark column, at the reference gain
        return DarkTerm(
            channels=channels,
            offset_dn=offset,
            slope_dn_s=slope,
            gains=tuple(gains),
            proportional=proportional,
            reference_gain=spec.reference.gain,
            temperature_ref_c=spec.dark.temperature_ref_c,
            doubling_c=flat("doubling_c"),
        )


@dataclass(frozen=True)
class DarkTerm:
    """The dark level's posterior as predictions use it (an
    :class:`~bayescal.model.components.base.OffsetTerm`): :meth:`Dark.level` per draw at a setting.

    ``offset_dn`` ``(S, C, G)`` and ``slope_dn_s`` ``(S, G)`` (``(S, C, G)``: a slope per channel) per dark
    column, whose gains are ``gains`` (one column at the reference gain, scaling with ``g / g_ref``, when
    ``proportional``); ``doubling_c`` ``(S,)`` the dark current's doubling temperature (None: no temperature law).
    """

    channels: tuple[str, ...]
    offset_dn: np.ndarray
    slope_dn_s: np.ndarray
    gains: tuple[float, ...]
    proportional: bool
    reference_gain: float
    temperature_ref_c: float = 20.0
    doubling_c: np.ndarray | None = None

    def column(self, gain: float) -> tuple[int, float]:
        """The dark column of a gain and the factor its offset scales by (a clear error for a gain with
        no dark calibration)."""
        if self.proportional:
            return 0, gain / self.gains[0]
        matches = np.flatnonzero(np.isclose(self.gains, gain))
        if matches.size == 0:
            raise SpecError(
                f"gain {gain:g} has no dark calibration: offsets are per gain setting "
                f"(dark.gain_dependence = 'per_setting'); calibrated gains: {list(self.gains)}"
            )
        return int(matches[0]), 1.0

    def offset(self, channel: str | None, setting: Any, n_draws: int) -> np.ndarray:
        """Dark level (DN) per draw at ``setting``; the dark current doubles every ``T_d`` degC away from
        the reference temperature when the calibration has that law and the setting a temperature."""
        c = self.channels.index(str(channel)) if channel is not None else 0
        column, gain_factor = self.column(setting.gain)
        warm = 1.0
        if self.doubling_c is not None and setting.temperature_c is not None:
            warm = Dark.doubling(setting.temperature_c - self.temperature_ref_c, self.doubling_c)
        offset = self.offset_dn[:, c, column]
        slope = self.slope_dn_s[:, c, column] if self.slope_dn_s.ndim == 3 else self.slope_dn_s[:, column]
        return Dark.level(offset, slope, setting.exposure_s, gain_factor, warm)

    def flags(self, setting: Any) -> list[str]:
        return []  # a gain with no dark column is an error (column), not an extrapolation
