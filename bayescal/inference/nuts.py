"""NUTS (numpyro) over a compiled program: the reference backend.

One chain is one jitted program (init, warmup and draws in a single
``lax.scan`` pair) built once per model structure, with the data as an
argument (docs/architecture.md, section 4: a naive ``MCMC.run`` re-traces and recompiles
on each call).  Chains run concurrently on a thread pool: XLA releases the
GIL, so the chains use every core.  Chains are deliberately *not* vmapped: a
vmapped NUTS turns each tree-building ``cond`` into a ``select`` and runs
every chain's ``while`` loop to the longest chain's length, which measured
12-25x slower here.  Chains start near the MAP, jittered; progress is
reported from inside the program by a host callback, so a progress bar costs
no recompilation.
"""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from functools import lru_cache
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from numpyro.infer.hmc import hmc

from bayescal._config import computes
from bayescal.inference.chains import retry_target
from bayescal.inference.laplace import covariance_factor
from bayescal.inference.program import Program, ProgramData
from bayescal.model.spec import InferenceSpec

__all__ = ["NutsDraws", "run_nuts", "run_nuts_many"]


class NutsDraws(NamedTuple):
    """Unconstrained draws ``(chain, draw, dim)`` and per-draw sampler statistics."""

    z: np.ndarray
    diverging: np.ndarray
    num_steps: np.ndarray
    accept_prob: np.ndarray
    energy: np.ndarray
    step_size: np.ndarray
    #: divergent transitions of a first attempt that was rerun with smaller steps (0: no rerun)
    first_divergences: int = 0
    #: the target acceptance of the run these draws come from, when it was a rerun (0: none)
    rerun_at: float = 0.0


_EVERY = 50


class _Progress:
    """Host-side progress of concurrently running chains (reports the slowest chain)."""

    active: _Progress | None = None

    def __init__(self, callback, chains: int):
        self.callback, self.done, self.lock = callback, [0] * chains, threading.Lock()

    @staticmethod
    def report(chain, i):
        self = _Progress.active
        if self is None or self.callback is None:
            return
        with self.lock:
            self.done[int(chain)] = int(i) + 1
            slowest = min(self.done)
        self.callback(slowest)


@lru_cache(maxsize=32)
def _compiled(program: Program, settings: tuple):
    """``run(chain_index, key, w0, data, center, chol)``: one chain, init + warmup + draws."""
    dense, target, depth, warmup, draws = settings

    def chain(index, key, w0, data, center, chol):
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
            jax.lax.cond(i % _EVERY == _EVERY - 1, lambda: jax.debug.callback(_Progress.report, index, i), lambda: None)

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

    return jax.jit(chain)


@computes
def run_nuts(
    program: Program,
    data: ProgramData,
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
    return run_nuts_many(program, [data], [start], [cov], settings, [seed], iterations=progress)[0]


@computes
def run_nuts_many(
    program: Program,
    datas: list[ProgramData],
    starts: list[jax.Array],
    covs: list[np.ndarray],
    settings: InferenceSpec,
    seeds: list[int],
    done=None,
    *,
    iterations=None,
) -> list[NutsDraws]:
    """:func:`run_nuts` for many datasets of one structure: one compiled chain program, every
    (dataset, chain) pair queued on one thread pool, so all cores stay busy.

    Dataset ``i`` gets exactly the chains ``run_nuts(..., seed=seeds[i])`` would.
    Datasets whose chains diverged are run once more at
    ``settings.retry_target_accept`` (their ``first_divergences`` says so).
    ``done(n)`` is called as datasets finish; ``iterations(k)`` every 50 iterations of the
    slowest chain (warmup included).
    """
    _Progress.active = _Progress(iterations, settings.chains * len(datas)) if iterations is not None else None
    try:
        return _run_many(program, datas, starts, covs, settings, seeds, done)
    finally:
        _Progress.active = None


def _run_many(program, datas, starts, covs, settings, seeds, done) -> list[NutsDraws]:
    n = settings.chains
    run = _compiled(
        program, (settings.dense_mass, settings.target_accept, settings.max_tree_depth, settings.warmup, settings.draws)
    )
    jobs: list[tuple] = []
    for data, start, cov, seed in zip(datas, starts, covs, seeds, strict=True):
        k_jit, k_chains = jax.random.split(jax.random.PRNGKey(seed))
        jitter = jax.random.uniform(k_jit, (n, np.size(start)), minval=-1.0, maxval=1.0)
        keys = jax.random.split(k_chains, n)
        chol = jnp.asarray(covariance_factor(np.asarray(cov)))
        center = jnp.asarray(start)
        first = len(jobs)
        jobs += [(first + c, keys[c], 0.5 * jitter[c], data, center, chol) for c in range(n)]

    finished, lock = [0] * len(datas), threading.Lock()

    def one(j):
        out = jax.device_get(run(*jobs[j]))
        if done is not None:
            with lock:
                finished[j // n] += 1
                if finished[j // n] == n:
                    done(sum(f == n for f in finished))
        return out

    pool = ThreadPoolExecutor(max_workers=max(1, min(len(jobs), os.cpu_count() or 1)))
    try:
        chains = list(pool.map(one, range(len(jobs))))
    except BaseException:  # Ctrl-C: do not wait for the running chains (a chain cannot be interrupted)
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()

    def stacked(i: int) -> NutsDraws:  # dataset i's chains: (chain, draw, ...) of each output
        per = chains[i * n : (i + 1) * n]
        z, diverging, steps, accept, energy, step = (np.stack([np.asarray(c[k]) for c in per]) for k in range(6))
        return NutsDraws(z, diverging, steps, accept, energy, step)

    outs = [stacked(i) for i in range(len(datas))]
    # divergences: rerun those datasets with smaller steps (the one retry policy, inference.chains.retry_target);
    # the target depends on the settings alone, so every dataset that is rerun gets the same one
    policy = (settings.target_accept, settings.retry_target_accept)
    targets = {i: retry_target(*policy, float(o.diverging.mean())) for i, o in enumerate(outs)}
    again = [i for i, t in targets.items() if t is not None]
    if again:
        target = targets[again[0]]
        assert target is not None
        retry = replace(settings, target_accept=target, retry_target_accept=target)
        redo = _run_many(
            program,
            [datas[i] for i in again],
            [starts[i] for i in again],
            [covs[i] for i in again],
            retry,
            [seeds[i] for i in again],
            None,
        )
        for i, out in zip(again, redo, strict=True):
            first = outs[i].first_divergences or int(outs[i].diverging.sum())
            outs[i] = out._replace(first_divergences=first, rerun_at=out.rerun_at or target)
    return outs
