"""A lamp whose colour changes with its level: each channel's stimulus off its reading by a smooth trend.

Physics: a lamp dimmed by its current cools, and its spectrum reddens as it dims: the sphere's radiance
reading (a broadband or one-band spectroradiometer) is right on the whole, but the red band receives
relatively more at the low levels and the blue band relatively less, a few per cent from the lowest level
to the highest, systematically, not at random.  In channel ``ch`` the stimulus of level ``L`` is then::

    x_eff = L exp(b_ch u(L)),   u(L) = log(L / L_mid) / log(L_max / L_min)

a factor on the effective stimulus, with ``u`` the level's position on the logarithm of the levels the
table measures (0 at their geometric middle ``L_mid``, where the channel reads its lamp as calibrated:
the per-channel scale error, ``sphere.channel_scale_rel``, is folded in apart).  A response polynomial per
channel takes it for a nonlinearity and bends its small-signal gain; the exposures tell them apart (a
nonlinearity follows the signal, the lamp's colour the level, whatever the exposure).  It is the bench's,
not the camera's: predictions leave it out.

Off by default (``[lamp_colour] enabled = true``); offered by the diagnosis, and screened on a fit that
passes, where three or more levels are measured at two or more exposures.  Prior: ``b_ch ~ Normal(0,
prior_rel)``, the change over the levels' range as a fraction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayescal.errors import SpecError
from bayescal.model.components.base import FactorEffect
from bayescal.model.components.channels import per_row

__all__ = ["LampColour", "LampColourSpec"]

#: its per-row input in ``ModelData.extra``: each row's position on the levels' log range (0 for dark rows)
INPUT = "lamp_colour.u"


@dataclass(frozen=True)
class LampColourSpec:
    """``[lamp_colour]``: each channel's stimulus trending with the lamp's level.

    ``enabled``: fit it.  ``prior_rel``: prior sd of each channel's change over the range of levels.
    """

    enabled: bool = False
    prior_rel: float = 0.03

    def __post_init__(self) -> None:
        if not self.prior_rel > 0:
            raise SpecError("lamp_colour.prior_rel must be > 0")


def level_position(stimulus: np.ndarray, low: float, high: float) -> np.ndarray:
    """``u(L) = log(L / sqrt(low high)) / log(high / low)`` for lit rows, 0 for dark ones."""
    stimulus = np.asarray(stimulus, dtype=float)
    lit = stimulus > 0
    span = np.log(high / low) if high > low else 1.0
    return np.where(lit, np.log(np.where(lit, stimulus, 1.0) / np.sqrt(low * high)) / span, 0.0)


@dataclass(frozen=True)
class LampColour(FactorEffect):
    """``exp(b_ch u(L))`` on the effective stimulus of every illuminated row of channel ``ch``."""

    section = "lamp_colour"
    spec_class = LampColourSpec
    sites = {"lamp_colour_w": ("channel",)}
    reported = {"lamp_colour_change": ("channel",)}

    spec: LampColourSpec
    n_channels: int
    low: float
    high: float

    @staticmethod
    def forward(change, u, xp=np):
        """The factor ``exp(b u)`` (1 at the levels' middle and for dark rows, ``u = 0``)."""
        return xp.exp(change * u)

    @classmethod
    def build(cls, section: LampColourSpec, spec, frame) -> LampColour | None:
        if not section.enabled:
            return None
        lit = frame.loc[frame["stimulus"].to_numpy() > 0, "stimulus"]
        return cls(section, frame["channel"].nunique(), float(lit.min()), float(lit.max()))

    @classmethod
    def candidates(cls, section: LampColourSpec, spec, frame) -> dict[str, dict]:
        """Offered where three or more levels are measured at two or more exposures (which tell the lamp's
        colour, a function of the level, from a nonlinearity, one of the signal)."""
        lit = frame["stimulus"].to_numpy() > 0
        if section.enabled or frame["channel"].nunique() < 2:
            return {}
        counts = frame.loc[lit].groupby("exposure_s")["stimulus"].nunique()
        if (counts >= 3).sum() < 2:
            return {}
        name = "a lamp whose colour changes with its level (each channel's stimulus trending over the levels)"
        return {name: {"lamp_colour": {"enabled": True}}}

    def inputs(self, frame) -> dict[str, np.ndarray]:
        return {INPUT: level_position(frame["stimulus"].to_numpy(dtype=float), self.low, self.high)}

    def sample(self, data):
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        prior = dist.Normal(0.0, self.spec.prior_rel).expand([self.n_channels]).to_event(1)
        change = numpyro.sample("lamp_colour_w", prior)
        return self.forward(change[data.channel], data.extra[INPUT], jnp)

    def describe(self) -> str:
        return f"lamp colour: each channel's stimulus trending over the levels (prior sd {self.spec.prior_rel:.0%})"

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        """Each channel's change from the lowest level to the highest, as a fraction (``exp(b) - 1``)."""
        return {"lamp_colour_change": np.expm1(np.asarray(draws["lamp_colour_w"], dtype=float))}

    @classmethod
    def truth(cls, params, rows, spec) -> np.ndarray:
        """``params``: ``change`` (one value or a table channel -> value: ``b``), ``low`` and ``high`` (the
        levels' range); ``rows`` carries each row's true ``stimulus``."""
        if set(params) - {"change", "low", "high"}:
            raise SpecError(f"[truth.effects.lamp_colour] keys {sorted(params)}; expected change, low, high")
        stimulus = rows["stimulus"].to_numpy(dtype=float)
        lit = stimulus[stimulus > 0]
        low = float(params.get("low", lit.min() if lit.size else 1.0))
        high = float(params.get("high", lit.max() if lit.size else 1.0))
        return cls.forward(per_row(params.get("change", 0.0), rows), level_position(stimulus, low, high))
