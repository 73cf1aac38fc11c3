"""Saturation: clipped means are censored, partially clipped means modelled.

Physics: outputs clip at 2^bits - 1 (seed 000 section 5.3 drops the clipped
red point at gain 4 by hand; seed 002 10-bit 0..1023).  A region whose mean
approaches full scale holds some clipped pixels: with pixel spread sigma
(temporal noise and PRNU), the expected mean is ``E[min(Y, fs)] = mu + sigma
(a Phi(-a) - phi(a))``, ``a = (fs - mu) / sigma``.  Rows at or above the
threshold contribute ``P(mean >= threshold)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import jax.scipy.stats.norm as jnorm
import numpyro
import numpyro.distributions as dist
from jax.scipy.special import ndtr
from numpyro.distributions import constraints

from ..spec import SaturationSpec

__all__ = ["Saturation", "CensoredNormal", "clipped_mean"]


def clipped_mean(mu: jnp.ndarray, sigma: jnp.ndarray, full_scale: float = 1.0) -> jnp.ndarray:
    """Expected value of ``min(Y, full_scale)`` for ``Y ~ Normal(mu, sigma)``; stable in both tails."""
    a = (full_scale - mu) / sigma
    return mu + sigma * (a * ndtr(-a) - jnorm.pdf(a))


class CensoredNormal(dist.Distribution):
    """Normal likelihood with right-censoring at ``threshold`` where ``censored`` is true."""

    arg_constraints = {"loc": constraints.real, "scale": constraints.positive}
    support = constraints.real

    def __init__(self, loc, scale, threshold, censored, *, validate_args=None):
        self.loc, self.scale = loc, scale
        self.threshold, self.censored = threshold, censored
        batch_shape = jnp.broadcast_shapes(jnp.shape(loc), jnp.shape(scale), jnp.shape(censored))
        super().__init__(batch_shape=batch_shape, validate_args=validate_args)

    def sample(self, key, sample_shape=()):
        """Draw a mean reading; censored-range draws are reported at the threshold."""
        import jax

        eps = jax.random.normal(key, sample_shape + self.batch_shape)
        draw = self.loc + self.scale * eps
        return jnp.where(draw >= self.threshold, jnp.maximum(draw, self.threshold), draw)

    def log_prob(self, value):
        """log pdf for observed rows, ``log P(Y >= threshold)`` for censored rows."""
        log_pdf = jnorm.logpdf(value, self.loc, self.scale)
        log_sf = jnorm.logcdf((self.loc - self.threshold) / self.scale)
        return jnp.where(self.censored, log_sf, log_pdf)


@dataclass(frozen=True)
class Saturation:
    """Likelihood of the row means, with or without clipping."""

    spec: SaturationSpec

    def observe(self, data, mean: jnp.ndarray, signal: jnp.ndarray, var_pix_nominal, var_mean) -> None:
        """Register the observation site ``obs``.

        The pixel spread of the clipping correction uses the *nominal* (or
        measured) pixel variance, not sampled noise parameters: otherwise an
        absurd pixel noise could bend the mean curve and fit the data.
        """
        scale = jnp.sqrt(var_mean)
        numpyro.deterministic("row_sd", scale)
        if not self.spec.censor:
            numpyro.deterministic("row_mean", mean)
            numpyro.sample("obs", dist.Normal(mean, scale), obs=data.y)
            return
        spread = jnp.sqrt(var_pix_nominal + (self.spec.prnu * signal) ** 2)
        loc = numpyro.deterministic("row_mean", clipped_mean(mean, spread))
        numpyro.sample("obs", CensoredNormal(loc, scale, data.threshold, data.censored), obs=data.y)
