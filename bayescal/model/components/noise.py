"""Noise of a row's mean DN: read, shot, quantisation, averaging, excess scatter.

Physics: seed 000 eq. 3 (N2 read and quantisation noise, N3 photon shot
noise, zero-mean so averaging 20 frames suppresses them), seed 002 section
2.3 (quantisation), EMVA 1288 photon transfer ``var = K (mu - mu_dark) +
sigma_d^2``.  The conversion gain and read noise scale with the programmable
gain factor.  Quantisation adds 1/12 DN^2 per pixel reading.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist

from bayescal.model.spec import NoiseSpec

__all__ = ["Noise"]


@dataclass(frozen=True)
class Noise:
    """Per-pixel variance and variance of the row mean, in scaled units."""

    spec: NoiseSpec
    dn_scale: float

    def pixel_variance(self, data, signal: jnp.ndarray, read: float | jnp.ndarray, kconv) -> jnp.ndarray:
        """Per-pixel temporal variance ``(g r)^2 + K g S + 1/12`` (scaled units)."""
        quant = 1.0 / (12.0 * self.dn_scale**2)
        shot = kconv * data.g_rel * jnp.maximum(signal, 0.0) / self.dn_scale
        return (read * data.g_rel) ** 2 + shot + quant

    def nominal_pixel_variance(self, data, signal: jnp.ndarray) -> jnp.ndarray:
        """Per-pixel variance: measured ``dn_var``, or the spec's read noise and conversion gain."""
        if self.spec.kind == "measured":
            return data.var_meas
        return self.pixel_variance(data, signal, self.spec.read_noise_dn / self.dn_scale, self.spec.conversion_gain)

    def sample(self, data, signal: jnp.ndarray) -> jnp.ndarray:
        """Variance of each row's mean (scaled units), sampling the excess scatter if enabled.

        Read noise and conversion gain are fixed at the spec's photon-transfer
        values: a region mean over many frames and pixels carries almost no
        information about them (its temporal noise is ~0.1 DN), and leaving
        them free lets shot noise absorb multiplicative scatter.
        """
        var_mean = self.nominal_pixel_variance(data, signal) / data.n_avg
        if self.spec.excess_dn > 0:
            excess = numpyro.sample("excess", dist.HalfNormal(self.spec.excess_dn / self.dn_scale))
            var_mean = var_mean + excess**2
        return var_mean

    def physical(self, draws: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Excess scatter of a row mean (DN)."""
        out = {}
        if "excess" in draws:
            out["excess_dn"] = draws["excess"] * self.dn_scale
        return out
