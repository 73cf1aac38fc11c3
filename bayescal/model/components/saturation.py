"""Saturation: clipped means are censored, partially clipped means bracketed (or modelled).

Physics: outputs clip at 2^bits - 1 (seed 000 section 5.3 drops the clipped
red point at gain 4 by hand; seed 002 10-bit 0..1023).  A region whose mean
approaches full scale holds some clipped pixels: with pixel spread sigma
(temporal noise and PRNU), the expected mean is ``E[min(Y, fs)] = mu + sigma
(a Phi(-a) - phi(a))``, ``a = (fs - mu) / sigma`` (for Gaussian pixel
values, :meth:`Saturation.clipped_mean`).  Rows at or above the threshold
contribute ``P(mean >= threshold)``.  A single reading is clipped to
``0..fs`` by the ADC (:meth:`Saturation.adc`).

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

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from bayescal.model.components.base import Component

__all__ = ["Saturation", "SaturationSpec"]


@dataclass(frozen=True)
class SaturationSpec:
    """Clipping at full scale 2^bits - 1 (seed 000 drops a clipped red point by hand).

    With ``censor`` on, rows whose mean reads at or above full scale minus
    ``margin_dn`` are right-censored.  A row whose pixels partly clip reads
    below its unclipped mean by a loss that depends on the pixels' spread
    (:mod:`bayescal.model.components.saturation`).  With ``partial = "window"`` (the
    default) the loss is bracketed: between that of the temporal noise alone
    and that at a generous ``prnu_bound`` (three times the typical 1 %).  With
    ``partial = "model"`` it is computed at the ``prnu`` fraction (state the
    camera's, e.g. from ``bayescal characterize``), or, with ``learn_prnu``,
    at a fraction learned from the rows near full scale (log-normal prior of
    median ``prnu`` and log-sd ``prnu_log_sd``).  On the validation bench a
    3 % PRNU stated as 1 % under-covered A0/A1 at 0.85 with ``"model"``; the
    learned fraction read ~2.6 %, but the near-clipped rows, which fit the
    Gaussian tail of the pixel values to ~0.1 DN, put a sharp wall on it where
    NUTS left a divergent transition after its retry in 4 of 20 clean fits.
    """

    censor: bool = True
    margin_dn: float = 0.5
    prnu: float = 0.01
    learn_prnu: bool = False
    prnu_log_sd: float = 1.0
    partial: Literal["window", "model"] = "window"
    prnu_bound: float = 0.03


@dataclass(frozen=True)
class Saturation(Component):
    """Likelihood of the row means, with or without clipping."""

    section = "saturation"
    role = "observation"
    sites = {"prnu": ()}
    reported = {"prnu": ()}

    spec: SaturationSpec

    # ------------------------------------------------------------------ physics
    @staticmethod
    def clipped_mean(mu, sigma, full_scale=1.0, xp=np):
        """Expected value of ``min(Y, full_scale)`` for ``Y ~ Normal(mu, sigma)``; stable in both tails."""
        if xp is np:
            from scipy.special import ndtr
        else:
            from bayescal.model.normal import ndtr
        a = (full_scale - mu) / sigma
        return mu + sigma * (a * ndtr(-a) - xp.exp(-0.5 * a * a) / math.sqrt(2.0 * math.pi))

    @staticmethod
    def unclipped_fraction(mu, sigma, full_scale=1.0, xp=np):
        """``P(Y < full_scale)`` for ``Y ~ Normal(mu, sigma)``: the share of pixels a clipped region keeps."""
        if xp is np:
            from scipy.special import ndtr
        else:
            from bayescal.model.normal import ndtr
        return ndtr((full_scale - mu) / sigma)

    @staticmethod
    def loss(mean, pixel_variance, prnu, signal, full_scale=1.0, xp=np):
        """How far a region mean falls below ``mean`` when its pixels, spread by their temporal variance
        and a PRNU fraction ``prnu`` of the ``signal``, clip one by one at ``full_scale``:
        ``mean - E[min(Y, fs)]`` (:meth:`clipped_mean`)."""
        return mean - Saturation.clipped_mean(mean, xp.sqrt(pixel_variance + (prnu * signal) ** 2), full_scale, xp)

    @staticmethod
    def adc(reading, full_scale, xp=np, integer: bool = False):
        """What the ADC outputs for an analogue ``reading``: clipped to ``0..full_scale`` (rounded to
        whole codes for a single reading, ``integer``)."""
        return xp.clip(xp.round(reading) if integer else reading, 0.0, full_scale)

    # ----------------------------------------------------------------- sampling
    @property
    def learned(self) -> bool:
        """Whether the PRNU fraction is a parameter (clipping modelled, a nonzero prior median)."""
        return self.spec.censor and self.spec.partial == "model" and self.spec.learn_prnu and self.spec.prnu > 0

    def prnu(self):
        """The PRNU fraction: sampled (site ``prnu``) or the spec's fixed value."""
        if not self.learned:
            return self.spec.prnu
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        return numpyro.sample("prnu", dist.LogNormal(jnp.log(self.spec.prnu), self.spec.prnu_log_sd))

    def observe(self, data, mean, signal, var_pix_nominal, var_mean) -> None:
        """Register the observation site ``obs``.

        The pixel spread of the clipping correction uses the *nominal* (or
        measured) pixel variance, not sampled noise parameters: otherwise an
        absurd pixel noise could bend the mean curve and fit the data.
        Rows with ``data.keep`` false are predicted but left out of the
        likelihood (the leave-one-setting-out check, :mod:`bayescal.fitting.holdout`).
        """
        import jax.numpy as jnp
        import numpyro
        import numpyro.distributions as dist

        from bayescal.model.components.likelihoods import CensoredNormal, ClipWindowNormal

        if not self.spec.censor:
            scale = numpyro.deterministic("row_sd", jnp.sqrt(var_mean))
            numpyro.deterministic("row_mean", mean)
            with numpyro.handlers.mask(mask=data.keep):
                numpyro.sample("obs", dist.Normal(mean, scale), obs=data.y)
            return
        if self.spec.partial == "window":
            lo = self.loss(mean, var_pix_nominal, 0.0, signal, xp=jnp)
            hi = jnp.maximum(self.loss(mean, var_pix_nominal, self.spec.prnu_bound, signal, xp=jnp), lo)
            obs = ClipWindowNormal(mean, jnp.sqrt(var_mean), lo, hi, data.threshold, data.censored)
            numpyro.deterministic("row_mean", obs.mean)
            numpyro.deterministic("row_sd", obs.sd)
            with numpyro.handlers.mask(mask=data.keep):
                numpyro.sample("obs", obs, obs=data.y)
            return
        loc = numpyro.deterministic("row_mean", mean - self.loss(mean, var_pix_nominal, self.prnu(), signal, xp=jnp))
        scale = numpyro.deterministic("row_sd", jnp.sqrt(var_mean))
        with numpyro.handlers.mask(mask=data.keep):
            numpyro.sample("obs", CensoredNormal(loc, scale, data.threshold, data.censored), obs=data.y)

    # ---------------------------------------------------------------- reporting
    def describe(self) -> str:
        return "saturation: censored" if self.spec.censor else "saturation: not modelled"

    def physical(self, draws, ctx) -> dict:
        """The PRNU fraction, where learned."""
        return {"prnu": draws["prnu"]} if "prnu" in draws else {}
