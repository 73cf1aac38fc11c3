"""NUTS (numpyro) over a compiled program: the reference backend.

One chain is the package's one NUTS program
(:func:`bayescal.inference.transitions.chain_program`: init, warmup and draws in a
single ``lax.scan`` pair) built once per model structure, with the data as an
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

import threading
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from bayescal._config import computes
from bayescal.inference.chains import attempt_seed, map_chains, progress_channel, with_retries
from bayescal.inference.laplace import covariance_factor
from bayescal.inference.program import Program, ProgramData
from bayescal.inference.transitions import Chain, chain_program
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
    datas: Sequence[ProgramData],
    starts: Sequence[jax.Array | np.ndarray],
    covs: Sequence[np.ndarray],
    settings: InferenceSpec,
    seeds: Sequence[int],
    done: Callable[[int], None] | None = None,
    *,
    iterations: Callable[[int], None] | None = None,
) -> list[NutsDraws]:
    """:func:`run_nuts` for many datasets of one structure: one compiled chain program, every
    (dataset, chain) pair queued on one thread pool, so all cores stay busy.

    Dataset ``i`` gets exactly the chains ``run_nuts(..., seed=seeds[i])`` would.
    Datasets whose chains diverged are run once more at
    ``settings.retry_target_accept`` (their ``first_divergences`` says so).
    ``done(n)`` is called as datasets finish; ``iterations(k)`` every 50 iterations of the
    slowest chain (warmup included).
    """
    with progress_channel(iterations, settings.chains * len(datas)) as run:
        return _run_many(run, program, datas, starts, covs, settings, seeds, done)


def _run_many(run_number, program, datas, starts, covs, settings, seeds, done) -> list[NutsDraws]:
    """Every dataset's chains, the datasets whose chains diverged rerun by the one retry loop
    (:func:`bayescal.inference.chains.with_retries`)."""

    def attempt(items, target: float, k: int) -> list[NutsDraws]:
        at = replace(settings, target_accept=target)
        pick = lambda xs: [xs[i] for i in items]
        seeds_k = [attempt_seed(seeds[i], k) for i in items]
        return _chains(
            run_number, program, pick(datas), pick(starts), pick(covs), at, seeds_k, done if k == 0 else None
        )

    def divergences(out: NutsDraws) -> tuple[int, int]:
        return int(out.diverging.sum()), int(out.diverging.size)

    policy = (settings.target_accept, settings.retry_target_accept)
    return [
        r.out._replace(first_divergences=r.first_divergences, rerun_at=r.rerun_at)
        for r in with_retries(attempt, len(datas), *policy, divergences)
    ]


def _chains(run_number, program, datas, starts, covs, settings, seeds, done) -> list[NutsDraws]:
    """One attempt: every (dataset, chain) pair on the chains' thread pool, one compiled chain program."""
    n = settings.chains
    run = chain_program(
        program.potential,
        Chain(settings.warmup, settings.draws, "windowed", settings.dense_mass, settings.max_tree_depth),
    )
    target = np.float64(settings.target_accept)
    jobs: list[tuple] = []
    for data, start, cov, seed in zip(datas, starts, covs, seeds, strict=True):
        k_jit, k_chains = jax.random.split(jax.random.PRNGKey(seed))
        jitter = jax.random.uniform(k_jit, (n, np.size(start)), minval=-1.0, maxval=1.0)
        keys = jax.random.split(k_chains, n)
        chol = jnp.asarray(covariance_factor(np.asarray(cov)))
        center = jnp.asarray(start)
        first = len(jobs)
        # with the Laplace covariance as the metric, the posterior is about unit scale: a first step of 0.5
        jobs += [
            (run_number, first + c, keys[c], 0.5 * jitter[c], 0.5, None, target, data, center, chol) for c in range(n)
        ]

    finished, lock = [0] * len(datas), threading.Lock()

    def one(j):
        out = jax.device_get(run(*jobs[j]))
        if done is not None:
            with lock:
                finished[j // n] += 1
                if finished[j // n] == n:
                    done(sum(f == n for f in finished))
        return out

    chains = map_chains(one, len(jobs))

    def stacked(i: int) -> NutsDraws:  # dataset i's chains: (chain, draw, ...) of each output
        per = chains[i * n : (i + 1) * n]
        z, diverging, steps, accept, energy, step = (
            np.stack([np.asarray(getattr(c, k)) for c in per])
            for k in ("x", "diverging", "num_steps", "accept_prob", "energy", "step_size")
        )
        return NutsDraws(z, diverging, steps, accept, energy, step)

    return [stacked(i) for i in range(len(datas))]
