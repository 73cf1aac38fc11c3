"""NUTS (numpyro) over a compiled program: the reference backend.

All chains run in one jitted, vmapped program built once per model
structure, with the data as an argument (DESIGN.md section 4: a naive
``MCMC.run`` re-traces and recompiles on each call).  Chains start near the
MAP, jittered; progress is reported from inside the program by a host
callback, so a progress bar costs no recompilation.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer.hmc import hmc

from ..data import ModelData
from ..spec import InferenceSpec
from .program import Program

__all__ = ["NutsDraws", "run_nuts"]


class NutsDraws(NamedTuple):
    """Unconstrained draws ``(chain, draw, dim)`` and per-draw sampler statistics."""

    z: np.ndarray
    diverging: np.ndarray
    num_steps: np.ndarray
    accept_prob: np.ndarray
    energy: np.ndarray
    step_size: np.ndarray


_PROGRESS: list = []  # the active progress callback (host side); empty when silent
_EVERY = 50


def _report(i):
    if _PROGRESS and _PROGRESS[-1] is not None:
        _PROGRESS[-1](int(np.max(i)) + 1)


@lru_cache(maxsize=32)
def _compiled(program: Program, settings: tuple):
    """``run(keys, z0s, data)``: all chains, init + warmup + draws, one compilation."""
    dense, target, depth, warmup, draws = settings

    def chain(key, w0, data, center, chol):
        def potential(w):
            return program.potential(center + chol @ w, data)

        init_kernel, sample_kernel = hmc(potential_fn=potential, algo="NUTS")
        state = init_kernel(
            w0,
            num_warmup=warmup,
            step_size=0.5,
            dense_mass=dense,
            target_accept_prob=target,
            max_tree_depth=depth,
            rng_key=key,
        )

        def tick(i):
            jax.lax.cond(i % _EVERY == _EVERY - 1, lambda: jax.debug.callback(_report, i), lambda: None)

        def warm(s, i):
            tick(i)
            return sample_kernel(s), None

        def draw(s, i):
            tick(i + warmup)
            s = sample_kernel(s)
            return s, (center + chol @ s.z, s.diverging, s.num_steps, s.accept_prob, s.energy, s.adapt_state.step_size)

        state, _ = jax.lax.scan(warm, state, jnp.arange(warmup))
        _, out = jax.lax.scan(draw, state, jnp.arange(draws))
        return out

    return jax.jit(jax.vmap(chain, in_axes=(0, 0, None, None, None)))


def run_nuts(
    program: Program,
    data: ModelData,
    start: jax.Array,
    cov: np.ndarray,
    settings: InferenceSpec,
    seed: int,
    progress=None,
) -> NutsDraws:
    """Run ``settings.chains`` NUTS chains from ``start`` (jittered) and return the draws.

    The posterior's scales span many orders of magnitude (row precisions
    ~1e7 in scaled units next to O(1) prior scales), so windowed adaptation
    from an identity metric saturates the tree depth, and numpyro's
    shrinkage of the adapted metric toward ``1e-3 I`` would undo a seeded
    one.  NUTS therefore runs on ``w`` with ``z = start + L w``,
    ``L L^T = cov`` (the Laplace covariance at the mode), where the
    posterior is close to isotropic; the adapted mass matrix absorbs what
    remains.

    Parameters
    ----------
    progress : callable, optional
        ``progress(iterations_done)``, called every 50 iterations (warmup
        included) from the running program.
    """
    key = jax.random.PRNGKey(seed)
    k_jit, k_chains = jax.random.split(key)
    n = settings.chains
    jitter = jax.random.uniform(k_jit, (n, start.size), minval=-1.0, maxval=1.0)
    chol = jnp.asarray(np.linalg.cholesky(np.asarray(cov)))
    run = _compiled(
        program, (settings.dense_mass, settings.target_accept, settings.max_tree_depth, settings.warmup, settings.draws)
    )
    _PROGRESS.append(progress)
    try:
        out = jax.device_get(run(jax.random.split(k_chains, n), 0.5 * jitter, data, jnp.asarray(start), chol))
    finally:
        _PROGRESS.pop()
    return NutsDraws(*(np.asarray(a) for a in out))
