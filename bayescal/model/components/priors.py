"""Shared prior shapes: the pooling scale's prior and the pooled latent's coordinates."""

from __future__ import annotations

import numpy as np

__all__ = ["scale_prior", "pooled_normal", "guide_inputs", "GUIDE_SITES"]

#: pooled sites drawn by :func:`pooled_normal`, each with its guide in ``ModelData.extra``
GUIDE_SITES = ("logG", "eta", "b0")


def scale_prior(scale: float):
    """Boundary-avoiding prior for a pooling scale: Gamma(2, 2/scale), mean ``scale``.

    A half-normal puts its mode at zero, where the joint density of a
    hierarchical model is unbounded (the funnel): MAP collapses there and
    NUTS diverges.  A Gamma(2) density vanishes at zero, keeping the mode
    interior (Chung et al. 2013, Psychometrika 78:685).
    """
    import numpyro.distributions as dist

    return dist.Gamma(2.0, 2.0 / scale)


def guide_inputs(site: str, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
    """The neutral guide of a pooled site (``ModelData.extra``): no data view, so
    :func:`pooled_normal` is the plain non-centred form until a fit sets a guide."""
    never = np.full(shape, np.inf)
    return {f"guide_{site}_center": np.zeros(shape), f"guide_{site}_spread": never, f"guide_{site}_marginal": never}


def pooled_normal(site: str, loc_mean, loc_sd, scale, data, shape: tuple[int, ...]):
    """Pooled values ``theta[c] ~ Normal(mu, scale)`` over the leading (channel) axis, their mean
    ``mu ~ Normal(loc_mean, loc_sd)`` (shape ``shape[1:]``), both drawn in coordinates whitened
    by their conditional posterior given the pooling sd ``scale``; returns ``theta``.

    The guide ``(c, s)`` in ``data.extra`` is what the data alone say of each ``theta`` (a mode
    and an sd: :func:`bayescal.inference.guide.guide_pooled` takes them from the unpooled
    model's Laplace fit).  With that Gaussian view of the data, given ``scale``:

    * ``mu`` is Normal with precision ``1/loc_sd^2 + sum_c 1/(scale^2 + s_c^2)`` and the
      matching precision-weighted mean of ``loc_mean`` and the ``c_c``;
    * ``theta_c`` given ``mu`` is Normal with precision ``1/v_c = 1/scale^2 + 1/s_c^2`` and
      mean ``v_c (mu/scale^2 + c_c/s_c^2)``;

    and ``mu``, ``theta`` are those means plus the sds times standard-normal coordinates.
    Where the data are strong beside the pooling sd (``s << scale``) this is the centred form,
    where they are weak (``s >> scale``) the non-centred one, and in between it interpolates,
    per value and per draw (the partially non-centred parametrisation of Papaspiliopoulos,
    Roberts & Skold 2007, Stat. Sci. 22:59): neither the funnel of the centred form at small
    ``scale`` nor the ridge of the non-centred one at large ``scale`` arises, and the mean's
    own funnel (its width follows ``scale / sqrt(C)``) is whitened too.  The model is unchanged:
    the priors of ``mu`` and ``theta`` and the Jacobian (the product of the sds) enter as a
    factor, so any guide gives the same posterior; only the geometry NUTS sees depends on it.

    Prior draws (``numpyro.infer.Predictive``, which ignores factors) are exact for the neutral
    guide (:func:`guide_inputs`: ``s`` infinite, so ``mu = loc_mean + loc_sd w_mu`` and
    ``theta = mu + scale w``).
    """
    import jax.numpy as jnp
    import numpyro
    import numpyro.distributions as dist

    center, spread = data.extra[f"guide_{site}_center"], data.extra[f"guide_{site}_spread"]
    marginal = data.extra[f"guide_{site}_marginal"]
    seen = jnp.isfinite(spread) & jnp.isfinite(marginal)
    var = scale**2 + jnp.where(seen, marginal, 0.0) ** 2  # the data's view of mu, per value
    weight = jnp.where(seen, 1.0 / var, 0.0)
    mu_precision = 1.0 / loc_sd**2 + jnp.sum(weight, axis=0)
    mu_sd = 1.0 / jnp.sqrt(mu_precision)
    mu_mean = (loc_mean / loc_sd**2 + jnp.sum(weight * jnp.where(seen, center, 0.0), axis=0)) / mu_precision
    std = dist.Normal(0.0, 1.0)
    w_mu = numpyro.sample(f"{site}_mu_w", std.expand(list(shape[1:])).to_event(len(shape) - 1))
    mu = numpyro.deterministic(f"{site}_mu", mu_mean + mu_sd * w_mu)

    data_precision = jnp.where(seen, 1.0 / jnp.where(seen, spread, 1.0) ** 2, 0.0)
    precision = 1.0 / scale**2 + data_precision
    sd = 1.0 / jnp.sqrt(precision)
    mean = (mu / scale**2 + data_precision * jnp.where(seen, center, 0.0)) / precision
    w = numpyro.sample(f"{site}_w", std.expand(list(shape)).to_event(len(shape)))
    theta = mean + sd * w
    correction = jnp.sum(dist.Normal(loc_mean, loc_sd).log_prob(mu) + jnp.log(mu_sd) - std.log_prob(w_mu)) + jnp.sum(
        dist.Normal(mu, scale).log_prob(theta) + jnp.log(sd) - std.log_prob(w)
    )
    numpyro.factor(f"{site}_pooled_prior", correction)
    return numpyro.deterministic(site, theta)
