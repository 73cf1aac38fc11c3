"""emcee ensemble sampler over the same program: an independent cross-check.

Walkers start in a ball drawn in the whitened coordinates ``z = mode + L w``
(``L L^T`` the Laplace covariance), where the posterior is close to
isotropic; moves are differential evolution (80 %) and snooker (20 %).  The
log density is the program's jitted potential, vectorised over walkers (one
call per step) and compiled once per model structure.  The retained chain is
thinned to about ``10 000`` draws; the effective sample size is judged from
the integrated autocorrelation time of the unthinned chain.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayescal._config import computes
from bayescal.errors import optional
from bayescal.inference.program import Program, ProgramData
from bayescal.model.spec import InferenceSpec

__all__ = ["EmceeDraws", "run_emcee"]

_KEEP = 10_000


class EmceeDraws(NamedTuple):
    """Thinned draws ``(walker, draw, dim)`` and the chain's statistics."""

    z: np.ndarray
    acceptance: float
    autocorr_steps: float
    n_eff: float
    thin: int


@lru_cache(maxsize=32)
def _log_density(program: Program):
    def logp(w, data, center, chol):
        return -program.potential(center + chol @ w, data)

    return jax.jit(jax.vmap(logp, in_axes=(0, None, None, None)))


@computes
def run_emcee(
    program: Program,
    data: ProgramData,
    mode: np.ndarray,
    cov: np.ndarray,
    settings: InferenceSpec,
    seed: int,
    progress=None,
) -> EmceeDraws:
    """Run the ensemble from the Laplace ball and return thinned draws in ``z``.

    Parameters
    ----------
    progress : callable, optional
        ``progress(steps_done)``, called every 50 steps (burn-in included).
    """
    emcee = optional("emcee", "the emcee backend")
    dim = mode.size
    walkers = settings.emcee_walkers or max(4 * dim, 32)
    walkers += walkers % 2
    chol = np.linalg.cholesky(cov)
    center, chol_j = jnp.asarray(mode), jnp.asarray(chol)
    logp = _log_density(program)

    def log_prob(ws: np.ndarray) -> np.ndarray:
        out = np.asarray(logp(jnp.asarray(ws), data, center, chol_j))
        return np.where(np.isfinite(out), out, -np.inf)

    rng = np.random.default_rng(seed)
    start = 0.5 * rng.standard_normal((walkers, dim))
    moves = [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]
    sampler = emcee.EnsembleSampler(walkers, dim, log_prob, vectorize=True, moves=moves)
    sampler.random_state = np.random.RandomState(seed).get_state()
    total = settings.emcee_burn + settings.emcee_steps
    for i, _ in enumerate(sampler.sample(start, iterations=total), start=1):
        if progress is not None and (i % 50 == 0 or i == total):
            progress(i)
    tau = float(np.max(sampler.get_autocorr_time(discard=settings.emcee_burn, quiet=True)))
    thin = max(1, (walkers * settings.emcee_steps) // _KEEP)
    w = sampler.get_chain(discard=settings.emcee_burn, thin=thin)  # (draw, walker, dim)
    z = mode + np.einsum("dwk,jk->wdj", w, chol)
    n_eff = walkers * settings.emcee_steps / tau
    return EmceeDraws(z, float(np.mean(sampler.acceptance_fraction)), tau, n_eff, thin)
