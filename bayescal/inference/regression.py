"""Flat-prior Bayesian regression by NUTS: the sampler checked against certified answers.

For ``y = f(beta, x) + e``, ``e ~ N(0, sigma^2)`` with ``sigma`` known and a
flat prior on ``beta``, the posterior of a *linear* model is exactly
``N(beta_hat, sigma^2 (X^T X)^-1)``: with ``sigma`` at the residual standard
deviation, its sds are the NIST StRD certified standard deviations.  For a
nonlinear model the certified sds are the linearisation at the optimum,
which the posterior matches to the extent the model is linear over the
posterior's width.  The chains run on the same compiled NUTS program as the
calibration models (:mod:`bayescal.inference.nuts`), whitened by the
least-squares covariance, so this is a direct test of that machinery on
ill-conditioned problems (Longley's collinear predictors, Filip-like
polynomials, Misra/MGH09/Eckerle4 curves).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache

import jax
import jax.numpy as jnp
import numpy as np

from bayescal._config import computes
from bayescal.inference.nls import nonlinear_lsq
from bayescal.inference.nuts import run_nuts
from bayescal.inference.program import Program, derivatives_of
from bayescal.model.spec import InferenceSpec

__all__ = ["RegressionPosterior", "regression_posterior", "linear_model"]


def linear_model(beta: jax.Array, design: jax.Array) -> jax.Array:
    """``design @ beta``: a linear model on a design matrix (columns are the predictors)."""
    return design @ beta


@dataclass(frozen=True)
class RegressionPosterior:
    """Posterior draws of ``beta`` and their diagnostics.

    Attributes
    ----------
    draws : ndarray (chain, draw, p)
    mean, sd : ndarray (p,)
    sigma : float
        The noise sd the posterior is conditioned on.
    divergences : int
    max_rhat, min_ess_bulk : float
    """

    draws: np.ndarray
    mean: np.ndarray
    sd: np.ndarray
    sigma: float
    divergences: int
    max_rhat: float
    min_ess_bulk: float


@lru_cache(maxsize=32)
def _program(model: Callable, p: int) -> Program:
    """A :class:`Program` whose latent vector is ``beta`` itself (flat prior: no transform)."""

    def potential(z, data):
        x, y, sigma = data
        r = (model(z, x) - y) / sigma
        return 0.5 * r @ r

    def loglik(z, data):
        x, y, sigma = data
        r = (model(z, x) - y) / sigma
        return -0.5 * r**2 - jnp.log(sigma) - 0.5 * jnp.log(2 * jnp.pi)

    return Program(
        model=model,
        z0=np.zeros(p),
        unravel=lambda z: {"beta": z},
        potential=computes(jax.jit(potential)),
        derivatives=computes(jax.jit(derivatives_of(potential))),
        constrain=computes(jax.jit(jax.vmap(lambda z, data: {"beta": z}, in_axes=(0, None)))),
        unconstrain=computes(jax.jit(lambda values, data: values["beta"])),
        loglik=computes(jax.jit(jax.vmap(loglik, in_axes=(0, None)))),
    )


@computes
def regression_posterior(
    model: Callable,
    x: np.ndarray,
    y: np.ndarray,
    start: np.ndarray,
    *,
    sigma: float | None = None,
    settings: InferenceSpec | None = None,
    seed: int = 0,
) -> RegressionPosterior:
    """NUTS draws of ``beta`` under a flat prior and Normal errors of known sd.

    Parameters
    ----------
    model : callable
        ``model(beta, x)``, JAX-traceable (the same object reuses the compilation);
        :func:`linear_model` for a design matrix.
    start : array
        Starting values for the least-squares search that centres and whitens the chains.
    sigma : float, optional
        Noise sd; default the least-squares residual sd ``sqrt(SSE / (n - p))``.
    """
    settings = settings or InferenceSpec()
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    lsq = nonlinear_lsq(model, x, y, start)
    s = float(lsq.rmse if sigma is None else sigma)
    cov = lsq.cov * (s / lsq.rmse) ** 2
    program = _program(model, lsq.coef.size)
    data = (jnp.asarray(x), jnp.asarray(y), jnp.asarray(s))
    out = run_nuts(program, data, jnp.asarray(lsq.coef), cov, settings, seed)
    import arviz_base
    import arviz_stats

    ds = arviz_base.convert_to_dataset({"beta": out.z})
    return RegressionPosterior(
        draws=out.z,
        mean=out.z.mean(axis=(0, 1)),
        sd=out.z.reshape(-1, out.z.shape[-1]).std(axis=0, ddof=1),
        sigma=s,
        divergences=int(out.diverging.sum()),
        max_rhat=float(np.max(arviz_stats.rhat(ds)["beta"])),
        min_ess_bulk=float(np.min(arviz_stats.ess(ds, method="bulk")["beta"])),
    )
