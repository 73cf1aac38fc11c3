"""Saturation: clipped means are censored, partially clipped means bracketed (or modelled).

Physics: outputs clip at 2^bits - 1 (seed 000 section 5.3 drops the clipped
red point at gain 4 by hand; seed 002 10-bit 0..1023).  A region whose mean
approaches full scale holds some clipped pixels: with pixel spread sigma
(temporal noise and PRNU), the expected mean is ``E[min(Y, fs)] = mu + sigma
(a Phi(-a) - phi(a))``, ``a = (fs - mu) / sigma`` (for Gaussian pixel
values).  Rows at or above the threshold contribute ``P(mean >= threshold)``.

How much a row loses to clipping depends on the spread of its pixels, which
a region-mean table does not measure.  ``saturation.partial`` says how that
is handled:

- ``"window"`` (default): the loss lies between the loss of the temporal
  noise alone (no PRNU) and the loss at a generous ``prnu_bound``, uniformly;
  the reading is the unclipped mean, minus that loss, plus noise, so its
  density is ``[Phi((y + L_hi - mu) / s) - Phi((y + L_lo - mu) / s)] /
  (L_hi - L_lo)``: the Normal density wherever the window is narrow (every
  row well below full scale), a flat window where it is wide.
- ``"model"``: the loss at the spec's ``prnu`` (or a learned one, site
  ``prnu``, ``learn_prnu``): exact when the PRNU is known and the pixel values
  Gaussian; on the validation bench a 3 % PRNU stated as 1 % under-covered
  A0/A1 at 0.85, and a learned one put a sharp wall in the posterior where
  NUTS diverged.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import jax.scipy.stats.norm as jnorm
import numpyro
import numpyro.distributions as dist
from jax.scipy.special import log_ndtr, ndtr
from numpyro.distributions import constraints

from bayescal.model.spec import SaturationSpec

__all__ = ["Saturation", "CensoredNormal", "ClipWindowNormal", "clipped_mean"]


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


def _log_ndtr_diff(a: jnp.ndarray, b: jnp.ndarray) -> jnp.ndarray:
    """``log(Phi(b) - Phi(a))`` for ``b > a``, accurate in both tails."""
    upper = a > 0  # both in the upper tail: Phi(b) - Phi(a) = Phi(-a) - Phi(-b)
    hi = jnp.where(upper, -a, b)
    lo = jnp.where(upper, -b, a)
    log_hi, log_lo = log_ndtr(hi), log_ndtr(lo)
    return log_hi + jnp.log1p(-jnp.exp(jnp.minimum(log_lo - log_hi, -1e-300)))


class ClipWindowNormal(dist.Distribution):
    """A reading ``Y* - loss`` with ``Y* ~ Normal(loc, scale)`` and ``loss ~ Uniform(lo, hi)``; right-censored
    at ``threshold`` where ``censored`` is true (then ``P(reading >= threshold)``, the window folded into the
    scale)."""

    arg_constraints = {"loc": constraints.real, "scale": constraints.positive}
    support = constraints.real
    #: windows narrower than this fraction of the noise sd are evaluated as the Normal density
    NARROW = 1e-3

    def __init__(self, loc, scale, lo, hi, threshold, censored, *, validate_args=None):
        self.loc, self.scale, self.lo, self.hi = loc, scale, lo, hi
        self.threshold, self.censored = threshold, censored
        batch_shape = jnp.broadcast_shapes(jnp.shape(loc), jnp.shape(scale), jnp.shape(censored))
        super().__init__(batch_shape=batch_shape, validate_args=validate_args)

    @property
    def mean(self):
        """Expected reading (before censoring)."""
        return self.loc - 0.5 * (self.lo + self.hi)

    @property
    def sd(self):
        """Standard deviation of the reading: noise and the window's uniform spread."""
        return jnp.sqrt(self.scale**2 + (self.hi - self.lo) ** 2 / 12.0)

    def sample(self, key, sample_shape=()):
        """Draw a reading; censored-range draws are reported at the threshold."""
        import jax

        k1, k2 = jax.random.split(key)
        shape = sample_shape + self.batch_shape
        loss = self.lo + (self.hi - self.lo) * jax.random.uniform(k1, shape)
        draw = self.loc - loss + self.scale * jax.random.normal(k2, shape)
        return jnp.where(draw >= self.threshold, jnp.maximum(draw, self.threshold), draw)

    def log_prob(self, value):
        """Window density for observed rows, ``log P(reading >= threshold)`` for censored rows."""
        w = self.hi - self.lo
        narrow = w < self.NARROW * self.scale
        w_safe = jnp.where(narrow, self.scale, w)
        a = (value + self.lo - self.loc) / self.scale
        b = (value + self.lo + w_safe - self.loc) / self.scale
        window = _log_ndtr_diff(a, b) - jnp.log(w_safe)
        normal = jnorm.logpdf(value, self.mean, self.scale)
        log_obs = jnp.where(narrow, normal, window)
        log_sf = jnorm.logcdf((self.mean - self.threshold) / self.sd)
        return jnp.where(self.censored, log_sf, log_obs)


@dataclass(frozen=True)
class Saturation:
    """Likelihood of the row means, with or without clipping."""

    spec: SaturationSpec

    @property
    def learned(self) -> bool:
        """Whether the PRNU fraction is a parameter (clipping modelled, a nonzero prior median)."""
        return self.spec.censor and self.spec.partial == "model" and self.spec.learn_prnu and self.spec.prnu > 0

    def prnu(self):
        """The PRNU fraction: sampled (site ``prnu``) or the spec's fixed value."""
        if not self.learned:
            return self.spec.prnu
        return numpyro.sample("prnu", dist.LogNormal(jnp.log(self.spec.prnu), self.spec.prnu_log_sd))

    def physical(self, draws: dict) -> dict:
        """The PRNU fraction, where learned."""
        return {"prnu": draws["prnu"]} if "prnu" in draws else {}

    def observe(self, data, mean: jnp.ndarray, signal: jnp.ndarray, var_pix_nominal, var_mean) -> None:
        """Register the observation site ``obs``.

        The pixel spread of the clipping correction uses the *nominal* (or
        measured) pixel variance, not sampled noise parameters: otherwise an
        absurd pixel noise could bend the mean curve and fit the data.
        Rows with ``data.keep`` false are predicted but left out of the
        likelihood (the leave-one-setting-out check, :mod:`bayescal.holdout`).
        """
        if not self.spec.censor:
            scale = numpyro.deterministic("row_sd", jnp.sqrt(var_mean))
            numpyro.deterministic("row_mean", mean)
            with numpyro.handlers.mask(mask=data.keep):
                numpyro.sample("obs", dist.Normal(mean, scale), obs=data.y)
            return
        if self.spec.partial == "window":
            temporal = jnp.sqrt(var_pix_nominal)
            widest = jnp.sqrt(var_pix_nominal + (self.spec.prnu_bound * signal) ** 2)
            lo = mean - clipped_mean(mean, temporal)
            hi = jnp.maximum(mean - clipped_mean(mean, widest), lo)
            obs = ClipWindowNormal(mean, jnp.sqrt(var_mean), lo, hi, data.threshold, data.censored)
            numpyro.deterministic("row_mean", obs.mean)
            numpyro.deterministic("row_sd", obs.sd)
            with numpyro.handlers.mask(mask=data.keep):
                numpyro.sample("obs", obs, obs=data.y)
            return
        spread = jnp.sqrt(var_pix_nominal + (self.prnu() * signal) ** 2)
        loc = numpyro.deterministic("row_mean", clipped_mean(mean, spread))
        scale = numpyro.deterministic("row_sd", jnp.sqrt(var_mean))
        with numpyro.handlers.mask(mask=data.keep):
            numpyro.sample("obs", CensoredNormal(loc, scale, data.threshold, data.censored), obs=data.y)
