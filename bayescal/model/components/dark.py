"""Offset and dark signal: per gain setting (or proportional to gain), linear in exposure.

Physics: seed 000 section 5.1 (about 50 DN at gain step 1, over 450 DN at
step 4; nearly flat over 2.7-10 ms; channel colour barely matters), seed 002
section 4.1 (dark roughly linear in integration time) and eq. 12 (offset
scales with the video gain).  Channel offsets are partially pooled.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist

from bayescal.model.components.priors import scale_prior
from bayescal.model.spec import DarkSpec

__all__ = ["Dark"]

OFFSET_TAU_SD = 0.01


@dataclass(frozen=True)
class Dark:
    """Offset ``b0[channel, gain]`` plus ``b1[gain] * t`` (scaled units)."""

    spec: DarkSpec
    n_channels: int
    n_gains: int
    dn_scale: float = 1.0  # full scale (DN): the drift prior is stated in DN

    @property
    def proportional(self) -> bool:
        """Offset proportional to the gain factor (seed 002 eq. 12)."""
        return self.spec.gain_dependence == "proportional"

    def sample(self, data) -> jnp.ndarray:
        """Sample the offset parameters and return the per-row scaled offset."""
        c, g = self.n_channels, 1 if self.proportional else self.n_gains
        if self.spec.pooled and c > 1:
            mu = numpyro.sample(
                "b0_mu", dist.Normal(self.spec.offset_prior_mean, self.spec.offset_prior_sd).expand([g]).to_event(1)
            )
            tau = numpyro.sample("b0_tau", scale_prior(OFFSET_TAU_SD))
            b0 = numpyro.sample("b0", dist.Normal(mu, tau).expand([c, g]).to_event(2))
        else:
            b0 = numpyro.sample(
                "b0", dist.Normal(self.spec.offset_prior_mean, self.spec.offset_prior_sd).expand([c, g]).to_event(2)
            )
        if self.proportional:
            offset = b0[data.channel, 0] * data.g_rel
        else:
            offset = b0[data.channel, data.gset]
        if self.spec.exposure_slope:
            b1 = numpyro.sample("b1", dist.Normal(0.0, self.spec.slope_prior_sd).expand([g]).to_event(1))
            slope = b1[0] * data.g_rel if self.proportional else b1[data.gset]
            if self.spec.temperature:  # dark current doubles every T_d degC (seed 002)
                t_d = numpyro.sample("T_d", dist.LogNormal(jnp.log(self.spec.doubling_c), self.spec.doubling_rel_sd))
                slope = slope * jnp.exp2(data.temp / t_d)
            offset = offset + slope * data.t
        if self.spec.drift:  # a linear drift over the run, common to every channel and gain
            drift = numpyro.sample("drift", dist.Normal(0.0, self.spec.drift_prior_dn / self.dn_scale))
            offset = offset + drift * data.time
        return offset

    def offset_dn(
        self, draws: dict[str, np.ndarray], channel: int, gain: float, exposure_s: float, layout, ref_gain: float
    ) -> np.ndarray:
        """Offset in DN at one channel, gain factor and exposure, per draw."""
        if self.proportional:
            g_rel = gain / ref_gain
            off = draws["b0"][..., channel, 0] * g_rel
            if self.spec.exposure_slope:
                off = off + draws["b1"][..., 0] * g_rel * exposure_s / layout.t_scale
        else:
            gi = layout.gain_values.index(gain)
            off = draws["b0"][..., channel, gi]
            if self.spec.exposure_slope:
                off = off + draws["b1"][..., gi] * exposure_s / layout.t_scale
        return off * layout.dn_scale

    def physical(self, draws: dict[str, np.ndarray], layout) -> dict[str, np.ndarray]:
        """Dark offset in DN at zero exposure and its exposure slope in DN/s.

        Per (channel, gain setting) for per-setting offsets; at the reference
        gain (``*_ref``) for proportional ones.
        """
        b0 = draws["b0"] * layout.dn_scale
        slope = draws["b1"] * layout.dn_scale / layout.t_scale if self.spec.exposure_slope else None
        if self.proportional:
            out = {"dark_offset_ref": b0[..., 0]}
            if slope is not None:
                out["dark_slope_ref"] = slope[..., 0]
            return out | self._doubling(draws)
        out = {"dark_offset": b0}
        if slope is not None:
            out["dark_slope"] = slope
        return out | self._doubling(draws)

    def _doubling(self, draws: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        out = {"doubling_c": draws["T_d"]} if "T_d" in draws else {}
        if "drift" in draws:
            out["dark_drift_dn"] = draws["drift"] * self.dn_scale
        return out
