"""emcee ensemble sampler over the same program: an independent cross-check.

Walkers start in a small ball drawn from the Laplace Gaussian; the log
density is the jitted program, vectorised over walkers (one call per step).
Runs in the whitened coordinates ``z = mode + L w``, where the posterior is
close to isotropic.
"""

from __future__ import annotations

import emcee
import jax
import jax.numpy as jnp
import numpy as np

from ..data import ModelData
from ..spec import InferenceSpec
from .program import Program

__all__ = ["run_emcee"]


def run_emcee(program: Program, data: ModelData, mode: np.ndarray, cov: np.ndarray, settings: InferenceSpec, seed: int):
    """Return ``(z_draws (walker, draw, dim), acceptance_fraction, autocorr_time)``."""
    dim = mode.size
    walkers = settings.emcee_walkers or max(4 * dim, 32)
    walkers += walkers % 2
    chol = np.linalg.cholesky(cov)
    center, chol_j = jnp.asarray(mode), jnp.asarray(chol)
    logp = jax.jit(jax.vmap(lambda w, d: -program.potential(center + chol_j @ w, d), in_axes=(0, None)))

    def log_prob(ws: np.ndarray) -> np.ndarray:
        out = np.asarray(logp(jnp.asarray(ws), data))
        return np.where(np.isfinite(out), out, -np.inf)

    rng = np.random.default_rng(seed)
    start = 0.5 * rng.standard_normal((walkers, dim))
    moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(walkers, dim, log_prob, vectorize=True, moves=moves)
    sampler.random_state = np.random.RandomState(seed).get_state()
    sampler.run_mcmc(start, settings.emcee_burn + settings.emcee_steps, progress=False)
    w = sampler.get_chain(discard=settings.emcee_burn)  # (draw, walker, dim)
    z = mode + np.einsum("dwk,jk->wdj", w, chol)
    tau = sampler.get_autocorr_time(discard=settings.emcee_burn, quiet=True)
    return z, float(np.mean(sampler.acceptance_fraction)), tau
