"""Response: polynomial in the effective stimulus, linear gain times relative nonlinearity.

Physics: DN = g k L t M R (1 + nonlinearity) + dark (seeds 000 eq. 3-5, 002
eq. 5-6/11).  With ``v = G u`` the linear signal as a fraction of full scale,
``S = v (1 + sum_k eta_k p_k(v))`` (``p_k(0) = 0``, see :mod:`bayescal.basis`): the nonlinearity is a function of the
signal level (sense-node V/Q and ADC DN/V nonlinearity, seed 004), so pooling
it across colour channels is physically motivated.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist

from bayescal.model.basis import response_monomials, shifted_legendre_monomials
from bayescal.model.components.priors import scale_prior
from bayescal.model.spec import ResponseSpec

__all__ = ["Response"]

#: prior scale of the pooled nonlinearity's spread across channels
ETA_TAU_SD = 0.02
#: the "normal" gain prior's sd, in units of its median: nearly flat (linear-Gaussian when the response is linear)
NORMAL_GAIN_SD_FACTOR = 10.0


@dataclass(frozen=True)
class Response:
    """Per-channel gain and (optionally pooled) nonlinearity of order ``order``."""

    spec: ResponseSpec
    n_channels: int

    @property
    def n_terms(self) -> int:
        """Number of nonlinearity coefficients per channel."""
        return self.spec.order - 1

    def sample(self) -> tuple[jnp.ndarray, jnp.ndarray | None]:
        """Sample gains ``G`` (C,) and nonlinearity ``eta`` (C, order-1) or None."""
        c = self.n_channels
        if self.spec.gain_prior == "lognormal":
            log_median = float(np.log(self.spec.gain_prior_median))
            gain = numpyro.sample("G", dist.LogNormal(log_median, self.spec.gain_prior_log_sd).expand([c]).to_event(1))
        elif self.spec.gain_prior == "pooled":
            mu = numpyro.sample("logG_mu", dist.Normal(0.0, 2.0))
            tau = numpyro.sample("logG_tau", scale_prior(1.0))
            z = numpyro.sample("logG_z", dist.Normal(0.0, 1.0).expand([c]).to_event(1))
            gain = numpyro.deterministic("G", jnp.exp(mu + tau * z))
        else:
            median = self.spec.gain_prior_median
            gain = numpyro.sample("G", dist.Normal(median, NORMAL_GAIN_SD_FACTOR * median).expand([c]).to_event(1))
        if self.n_terms == 0:
            return gain, None
        k = self.n_terms
        if self.spec.pooled and c > 1:
            mu = numpyro.sample("eta_mu", dist.Normal(0.0, self.spec.nonlinearity_prior_sd).expand([k]).to_event(1))
            tau = numpyro.sample("eta_tau", scale_prior(ETA_TAU_SD).expand([k]).to_event(1))
            eta = numpyro.sample("eta", dist.Normal(mu, tau).expand([c, k]).to_event(2))
        else:
            eta = numpyro.sample("eta", dist.Normal(0.0, self.spec.nonlinearity_prior_sd).expand([c, k]).to_event(2))
        return gain, eta

    def signal(self, gain: jnp.ndarray, eta: jnp.ndarray | None, u: jnp.ndarray, channel: jnp.ndarray) -> jnp.ndarray:
        """Scaled signal ``S`` for scaled stimulus ``u`` of channel index ``channel``."""
        v = gain[channel] * u
        if eta is None:
            return v
        q = jnp.asarray(shifted_legendre_monomials(self.spec.order))
        coef = eta[channel] @ q  # (n, order): nonlinearity n(v) in monomials of v
        nl = jnp.zeros_like(v)
        for j in range(self.spec.order - 1, 0, -1):  # Horner; avoids d(v**0)/dv = 0 * inf at v = 0
            nl = (nl + coef[:, j]) * v
        return v * (1.0 + nl)

    def physical(self, draws: dict[str, np.ndarray], x_scale: float, dn_scale: float) -> dict[str, np.ndarray]:
        """Gain (DN per stimulus unit at the reference setting) and monomials A1..Ap (A0 = 0).

        These are relative to the sphere's scale (what the sphere's readings
        say); :mod:`bayescal.derived` folds in the common scale.
        """
        coef_u = response_monomials(draws["G"], draws.get("eta"), self.spec.order)
        coef = coef_u * dn_scale / x_scale ** np.arange(self.spec.order + 1)
        out = {"A_rel": coef, "gain_rel": coef[..., 1]}
        if "eta" in draws:
            out["nonlinearity"] = draws["eta"]
        return out
