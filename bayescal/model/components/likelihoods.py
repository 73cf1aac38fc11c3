"""The likelihoods of a row mean near full scale: right-censored and clip-window Normal (numpyro).

:class:`CensoredNormal` is a Normal whose readings at or above the threshold are censored
(``P(Y >= threshold)``); :class:`ClipWindowNormal` reads ``Y* - loss`` with the clipping loss
uniform in a window (:mod:`bayescal.model.components.saturation`), its density evaluated in log
space in both tails.
"""

from __future__ import annotations

import jax.numpy as jnp
import jax.scipy.stats.norm as jnorm
import numpyro.distributions as dist
from numpyro.distributions import constraints

from bayescal.model.normal import log_ndtr

__all__ = ["CensoredNormal", "ClipWindowNormal"]


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
        log_sf = log_ndtr((self.loc - self.threshold) / self.scale)
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
        log_sf = log_ndtr((self.mean - self.threshold) / self.sd)
        return jnp.where(self.censored, log_sf, log_obs)
