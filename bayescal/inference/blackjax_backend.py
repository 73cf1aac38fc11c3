"""NUTS from BlackJAX with its window adaptation: a second NUTS implementation.

It runs on the same compiled potential and in the same Laplace-whitened coordinates as
the numpyro backend (:mod:`.nuts`: ``z = mode + L w`` with ``L L' = cov``), so the two
differ only in their NUTS and adaptation code: BlackJAX's Stan-style window adaptation
(step size by dual averaging, a diagonal mass matrix from growing windows) and its
multinomial NUTS.  One chain is one jitted program (warmup and draws) built once per
model structure, with the data as an argument; chains run on a thread pool.  This module
is the whole backend: it registers itself under ``blackjax`` when imported
(:mod:`bayescal.inference.registry`).  ``benchmarks/fit_speed.py`` runs it beside numpyro's NUTS.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from bayescal._config import computes
from bayescal.errors import optional
from bayescal.inference.chains import map_chains, progress_channel, report
from bayescal.inference.diagnostics import Diagnostics, mcmc_diagnostics
from bayescal.inference.laplace import LaplaceResult, covariance_factor
from bayescal.inference.program import Program
from bayescal.inference.registry import SHIPPED, Draws, OneByOne, Progress, Sampled, Stage, Tuned, register
from bayescal.inference.samplers import chains_dataset

__all__ = ["BlackjaxNutsBackend", "run_blackjax"]


_EVERY = 50


@lru_cache(maxsize=16)
def _compiled(program: Program, settings: tuple):
    """``run(run_number, index, key, w0, data, center, chol)``: one chain's warmup and draws, compiled once
    (progress is reported every 50 draws to the run's channel, the warmup as one step)."""
    blackjax = optional("blackjax", "the blackjax backend")
    import jax
    import jax.numpy as jnp

    target, depth, warmup, draws = settings

    def chain(run, index, key, w0, data, center, chol):
        def logdensity(w):
            return -program.potential(center + chol @ w, data)

        k_warm, k_draw = jax.random.split(key)
        adapt = blackjax.window_adaptation(
            blackjax.nuts, logdensity, target_acceptance_rate=target, max_num_doublings=depth
        )
        (state, parameters), _ = adapt.run(k_warm, w0, num_steps=warmup)
        step = blackjax.nuts(logdensity, **parameters).step  # step size, mass matrix and the depth limit

        def draw(s, xs):
            i, k = xs
            jax.lax.cond(i % _EVERY == _EVERY - 1, lambda: jax.debug.callback(report, run, index, i), lambda: None)
            s, info = step(k, s)
            stats = (info.is_divergent, info.num_integration_steps, info.acceptance_rate, info.energy)
            return s, (center + chol @ s.position,) + stats

        _, out = jax.lax.scan(draw, state, (jnp.arange(draws), jax.random.split(k_draw, draws)))
        return out

    return jax.jit(chain)


@computes
def run_blackjax(program: Program, data, start, cov, settings, seed: int, progress: Callable | None = None) -> Draws:
    """``settings.chains`` chains from ``start`` (jittered as the numpyro backend's are);
    ``progress(iterations_done)`` with the warmup counted once it is over."""
    import jax
    import jax.numpy as jnp

    n = settings.chains
    run = _compiled(program, (settings.target_accept, settings.max_tree_depth, settings.warmup, settings.draws))
    k_jit, k_chains = jax.random.split(jax.random.PRNGKey(seed))
    jitter = 0.5 * jax.random.uniform(k_jit, (n, np.size(start)), minval=-1.0, maxval=1.0)
    keys = jax.random.split(k_chains, n)
    chol = jnp.asarray(covariance_factor(np.asarray(cov)))
    center = jnp.asarray(start)

    with progress_channel(progress, n, settings.warmup) as number:
        chains = map_chains(lambda c: jax.device_get(run(number, c, keys[c], jitter[c], data, center, chol)), n)
    z, diverging, steps, accept, energy = (np.stack([np.asarray(c[k]) for c in chains]) for k in range(5))
    stats = {"diverging": diverging, "tree_steps": steps, "accept_prob": accept, "energy": energy}
    return Draws(z, int(diverging.sum()), stats)


@dataclass(frozen=True)
class BlackjaxNutsBackend(OneByOne):
    """BlackJAX NUTS with window adaptation, in Laplace-whitened coordinates."""

    name: str = "blackjax"
    batched: bool = SHIPPED["blackjax"].batched

    def sample(
        self, model: Sampled, program: Program, mode: LaplaceResult, seed: int, progress: Progress | None, stage: Stage
    ) -> Draws:
        inf = model.spec.inference
        stage(f"sampling: BlackJAX NUTS, {inf.chains} chains x ({inf.warmup} warmup + {inf.draws} draws)")
        return run_blackjax(program, model.data, mode.mode, mode.cov, inf, seed, progress)

    def verdict(
        self, draws: Draws, posterior: Mapping[str, np.ndarray], spec: Tuned, mode: LaplaceResult
    ) -> Diagnostics:
        return mcmc_diagnostics(chains_dataset(posterior), draws.divergences, spec.inference, draws.extra)


register(BlackjaxNutsBackend())
