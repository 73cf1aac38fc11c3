"""Stray light: a stimulus that reaches the sensor in every illuminated frame and in no dark frame.

Physics: light that leaks past the sphere's port or its baffles, or an offset of the radiometer that
reads the sphere, adds a constant radiance ``s_ch`` to what every illuminated frame receives, in each
channel by its own spectrum, while the dark frames (shutter closed, lamp off) see none of it::

    x_eff = (L + s_ch) f_settings ...   =   L (1 + s_ch / L) f_settings ...

so it is a factor ``1 + s_ch / L`` on the effective stimulus of the lit rows: integrated over the exposure
and amplified by the gain like the signal, unlike a dark current (in every frame) or an offset.  Without
it, the response's offset cannot follow it (the darks fix the offset) and the leak goes into the sphere's
level errors, which then grow like ``s / L`` towards the lowest levels (+11 to +13.5 % at the lowest level,
11-27 prior sds, with every gain 3.5 % high, on leaks of a few per cent of the lowest level).

It is the bench's, not the camera's: predictions leave it out (no term).  Off by default (``[stray_light]
enabled = true``); the diagnosis offers it where the table has dark rows and three or more sphere levels.
Prior: ``s_ch ~ Normal(0, prior_rel L_min)``, ``L_min`` the lowest illuminated level (either sign: a
radiometer's zero offset reads low as often as high).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bayescal.errors import SpecError
from bayescal.model.components.base import FactorEffect
from bayescal.model.components.channels import per_row

__all__ = ["StrayLight", "StraySpec"]

#: its per-row input in ``ModelData.extra``: the row's stimulus as read (the table's units; 0 for dark rows)
INPUT = "stray_light.stimulus"


@dataclass(frozen=True)
class StraySpec:
    """``[stray_light]``: a stimulus ``s_ch`` added to every illuminated row, per channel.

    ``enabled``: fit it.  ``prior_rel``: prior sd of each channel's stray stimulus, as a fraction of the
    table's lowest illuminated level.
    """

    enabled: bool = False
    prior_rel: float = 0.25

    def __post_init__(self) -> None:
        if not self.prior_rel > 0:
            raise SpecError("stray_light.prior_rel must be > 0")


@dataclass(frozen=True)
class StrayLight(FactorEffect):
    """``1 + s_ch / L`` on the effective stimulus of every illuminated row of channel ``ch``."""

    section = "stray_light"
    spec_class = StraySpec
    sites = {"stray_w": ("channel",)}
    reported = {"stray_stimulus": ("channel",)}

    spec: StraySpec
    n_channels: int
    lowest: float  # the table's lowest illuminated stimulus (its units)

    @staticmethod
    def forward(stray, stimulus, xp=np):
        """The factor ``1 + s / L`` on a lit row's effective stimulus (1 for a dark row, ``L = 0``)."""
        lit = stimulus > 0
        return xp.where(lit, 1.0 + stray / xp.where(lit, stimulus, 1.0), 1.0)

    @classmethod
    def build(cls, section: StraySpec, spec, frame) -> StrayLight | None:
        if not section.enabled:
            return None
        lit = frame["stimulus"].to_numpy() > 0
        return cls(section, frame["channel"].nunique(), float(frame.loc[lit, "stimulus"].min()))

    @classmethod
    def candidates(cls, section: StraySpec, spec, frame) -> dict[str, dict]:
        """Offered where dark rows fix the offset and three or more levels show a stimulus offset's ``1 / L``."""
        stimulus = frame["stimulus"].to_numpy()
        if section.enabled or not (stimulus == 0).any() or np.unique(stimulus[stimulus > 0]).size < 3:
            return {}
        return {"stray light (a stimulus the dark frames do not see, per channel)": {"stray_light": {"enabled": True}}}

    def inputs(self, frame) -> dict[str, np.ndarray]:
        return {INPUT: frame["stimulus"].to_numpy(dtype=float)}

    def sample(self, data):
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        w = numpyro.sample("stray_w", dist.Normal(0.0, self.spec.prior_rel).expand([self.n_channels]).to_event(1))
        return self.forward(w[data.channel] * self.lowest, data.extra[INPUT], jnp)

    def describe(self) -> str:
        prior = f"prior sd {self.spec.prior_rel:.0%} of {self.lowest:g}"
        return f"stray light: a stimulus the darks do not see, per channel ({prior})"

    def physical(self, draws, ctx) -> dict[str, np.ndarray]:
        return {"stray_stimulus": np.asarray(draws["stray_w"], dtype=float) * self.lowest}

    @classmethod
    def truth(cls, params, rows, spec) -> np.ndarray:
        """``params``: ``stimulus``, one value or a table channel -> value (the table's stimulus units);
        ``rows`` carries each row's true ``stimulus``."""
        if set(params) - {"stimulus"}:
            raise SpecError(f"[truth.effects.stray_light] keys {sorted(params)}; expected ['stimulus']")
        return cls.forward(per_row(params.get("stimulus", 0.0), rows), rows["stimulus"].to_numpy(dtype=float))
