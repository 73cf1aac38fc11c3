"""Amplifier glow: a dark signal that grows with the square of the exposure, different in each channel.

Physics: a read-out amplifier that runs while the pixels integrate emits light, and the pixels
nearest it collect that light as a dark signal (the "amplifier glow" of dark frames, brightest in
the corner or the channel next to the amplifier).  Where the glow's rate itself grows over the
integration the dark signal grows faster than the exposure; its lowest-order form is::

    glow = c_ch t^2 g / g_ref

one coefficient ``c_ch`` per channel (DN/s^2 at the reference gain), scaling with the gain like a
signal, added to every reading, dark or lit.  A dark current linear in exposure
(:mod:`bayescal.model.components.dark`) misreads it as an offset and a slope; dark frames at three or
more exposures tell them apart.

Off by default (``[glow] enabled = true``).  Prior: ``c_ch ~ Normal(0, prior_sd)`` in fractions of full
scale at the table's longest exposure.  Specs written before it was an effect of its own
(``[dark] glow``) are read as ``[glow] enabled``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayescal.errors import SpecError
from bayescal.model.components.base import OffsetEffect
from bayescal.model.components.channels import ChannelDraws, per_row

__all__ = ["Glow", "GlowSpec", "GlowTerm"]


@dataclass(frozen=True)
class GlowSpec:
    """``[glow]``: a dark signal ``c_ch t^2 g / g_ref`` per channel.

    ``enabled``: fit it.  ``prior_sd``: prior sd of each channel's coefficient, as a fraction of full
    scale at the table's longest exposure.
    """

    enabled: bool = False
    prior_sd: float = 0.05

    def __post_init__(self) -> None:
        if not self.prior_sd > 0:
            raise SpecError("glow.prior_sd must be > 0")


@dataclass(frozen=True)
class Glow(OffsetEffect):
    """``c_ch t^2 g / g_ref`` DN added to every reading of channel ``ch``."""

    section = "glow"
    spec_class = GlowSpec
    renamed = {"dark.glow": "enabled"}
    sites = {"glow": ("channel",)}
    reported = {"dark_glow_dn_s2": ("channel",)}

    spec: GlowSpec
    n_channels: int
    dn_scale: float = 1.0  # full scale (DN): the model's rows are in its units, the effect's offset in DN

    @staticmethod
    def forward(coefficient, exposure_s, g_rel):
        """The DN ``c t^2 g_rel`` added to a reading (``c`` in DN/s^2 at the reference gain)."""
        return coefficient * exposure_s * exposure_s * g_rel

    @classmethod
    def build(cls, section: GlowSpec, spec, frame) -> Glow | None:
        if not section.enabled:
            return None
        return cls(section, frame["channel"].nunique(), spec.full_scale)

    @classmethod
    def candidates(cls, section: GlowSpec, spec, frame) -> dict[str, dict]:
        """Offered when the dark rows span three or more exposures (two fix the linear dark current)."""
        dark = frame["stimulus"].to_numpy() == 0
        if section.enabled or not spec.dark.exposure_slope or frame.loc[dark, "exposure_s"].nunique() < 3:
            return {}
        return {"amplifier glow (a dark signal in t^2, per channel)": {"glow": {"enabled": True}}}

    def sample(self, data):
        """The DN of every row: the coefficient is sampled in full scale per longest exposure squared
        (``data.t`` is the exposure over the table's longest, as the dark slope's)."""
        import numpyro
        import numpyro.distributions as dist

        prior = dist.Normal(0.0, self.spec.prior_sd).expand([self.n_channels]).to_event(1)
        coefficient = numpyro.sample("glow", prior)[data.channel] * self.dn_scale
        return self.forward(coefficient, data.t, data.g_rel)

    def describe(self) -> str:
        return "offset: amplifier glow (t^2, per channel)"

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        return {"dark_glow_dn_s2": draws["glow"] * ctx.layout.dn_scale / ctx.layout.t_scale**2}

    @classmethod
    def term(cls, section: GlowSpec, spec, draws, frame) -> GlowTerm | None:
        if "dark_glow_dn_s2" not in draws:
            return None
        return GlowTerm.from_draws(draws["dark_glow_dn_s2"], frame, spec.reference.gain)

    @classmethod
    def truth(cls, params, rows, spec) -> np.ndarray:
        """``params``: ``dn_s2``, one value or a table channel -> value (DN/s^2 at the reference gain)."""
        if set(params) - {"dn_s2"}:
            raise SpecError(f"[truth.effects.glow] keys {sorted(set(params) - {'dn_s2'})}; expected ['dn_s2']")
        g_rel = rows["gain"].to_numpy(dtype=float) / spec.reference.gain
        return cls.forward(per_row(params.get("dn_s2", 0.0), rows), rows["exposure_s"].to_numpy(dtype=float), g_rel)


@dataclass(frozen=True)
class GlowTerm(ChannelDraws):
    """The coefficients' posterior ``(S, C)`` (DN/s^2 at the reference gain) as predictions use them."""

    reference_gain: float

    def offset(self, channel, setting, n_draws: int) -> np.ndarray:
        """``c t^2 g / g_ref`` DN per draw at the setting."""
        return Glow.forward(self.of(channel, "amplifier glow"), setting.exposure_s, setting.gain / self.reference_gain)
